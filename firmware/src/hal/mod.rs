//! Hardware abstraction: narrow traits and the plain data the tiers exchange with the hardware.
//! `hal-sim` implements them on the host, `board/` on the target.

pub mod can;
pub mod flash;
pub mod reset;
pub mod sto;
/// The power-stage contract of tier 1, defined in `drive-control` beside the current loop that consumes it.
pub use drive_control::power;
