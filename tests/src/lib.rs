//! Shared helpers of the host-run firmware tests.

pub mod ecat_master;
pub mod qemu;
