//! Firmware images and updates in the simulator: the image format and its checks, the update sequence, and power cuts
//! at every write.
//!
//! One test binary for the area; each module is one of its test files.

mod image;
mod power_cut;
mod rollback;
mod stored_comms;
mod support;
mod update;
