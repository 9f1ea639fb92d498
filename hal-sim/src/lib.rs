//! Host simulation of the drive's hardware: the motor and power-stage plant, sensors, flash with power cuts,
//! and the fieldbus transports; the harness that runs the firmware against them ([`sim`]) and the scenarios it
//! runs ([`scenarios`]); and the `drive-sim` command.

pub mod can;
pub mod esc;
pub mod flash;
pub mod plant;
pub mod scenarios;
pub mod sim;
