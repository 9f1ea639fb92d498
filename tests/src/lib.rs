//! Shared helpers of the host-run firmware tests.

pub mod can_master;
pub mod conformance;
pub mod ecat_master;
pub mod prerequisite;
pub mod qemu;
pub mod real_master;
