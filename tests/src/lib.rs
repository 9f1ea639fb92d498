//! Shared helpers of the host-run firmware tests.

pub mod qemu;
