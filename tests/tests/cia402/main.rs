//! The CiA 402 device control: the state machine's table, the modes, the option codes and the properties that hold for
//! any input.
//!
//! One test binary for the area; each module is one of its test files.

mod modes;
mod options;
mod properties;
mod support;
mod table;
