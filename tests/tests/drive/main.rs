//! The drive against the simulated power stage and plant: the current loop, the CiA 402 sequence, commutation, I/O and
//! parameters.
//!
//! One test binary for the area; each module is one of its test files.

mod auto_tune_48v;
mod auto_tune_belt;
mod auto_tune_geared;
mod auto_tune_geared_duty_cycle;
mod auto_tune_scenarios;
mod auto_tuning;
mod cia402;
mod coarse_encoder;
mod commutation;
mod current_loop;
mod dual_loop;
mod encoder_resolution;
mod heavy_load;
mod identification;
mod identification_robustness;
mod io;
mod mechanical_identification;
mod parameters;
mod recorder;
mod regeneration;
mod resonance_identification;
mod sensor_configuration;
mod ssi;
