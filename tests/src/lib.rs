//! Shared helpers of the host-run firmware tests.

pub mod ecat_master;
pub mod qemu;
pub mod real_master;
