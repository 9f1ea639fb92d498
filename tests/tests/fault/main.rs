//! Fault handling: the fault table, the manager, EMCYs, the protections (I2t, thermal, power stage, feedback, stall and
//! phase loss), the fault matrix and the duty cycle.
//!
//! One test binary for the area; each module is one of its test files.

mod duty_cycle;
mod emcy;
mod feedback;
mod i2t;
mod manager;
mod matrix;
mod power_stage;
mod stall_phase;
mod table;
mod thermal;
mod watchdog;
