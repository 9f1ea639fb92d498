//! Shared helpers of the host-run firmware tests.
