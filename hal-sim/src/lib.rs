//! Host simulation of the drive's hardware: the motor and power-stage plant, sensors, flash with power cuts,
//! and the fieldbus transports; and the `drive-sim` command that runs the firmware against them.

pub mod can;
pub mod esc;
pub mod flash;
pub mod plant;
pub mod sim;
