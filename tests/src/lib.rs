//! Shared helpers of the host-run firmware tests.

pub mod can_master;
pub mod ecat_master;
pub mod qemu;
pub mod real_master;
