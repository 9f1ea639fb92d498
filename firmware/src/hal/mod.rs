//! Hardware abstraction: narrow traits and the plain data the tiers exchange with the hardware.
//! `hal-sim` implements them on the host, `board/` on the target.

pub mod can;
pub mod flash;
pub mod power;
