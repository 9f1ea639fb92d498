//! The object dictionary: access and abort codes, properties, the SDO server on CANopen and CoE, parameter persistence.
//!
//! One test binary for the area; each module is one of its test files.

mod access;
mod persistence;
mod properties;
mod sdo_coe;
mod sdo_server;
mod support;
mod writable;
