//! Motion: the cyclic modes, homing, the velocity observer and the profile modes against the plant.
//!
//! One test binary for the area; each module is one of its test files.

mod cyclic;
mod encoder_resolution;
mod gear;
mod homing;
mod master;
mod observer;
mod polarity;
mod profile;
