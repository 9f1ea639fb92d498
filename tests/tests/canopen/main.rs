//! The CANopen node in-process: NMT, SDO, PDOs, SYNC, heartbeat and EMCY against the simulated drive, and random
//! frames.
//!
//! One test binary for the area; each module is one of its test files.

mod bus_errors;
mod fuzz;
mod node;
mod sto;
mod watchdog;
