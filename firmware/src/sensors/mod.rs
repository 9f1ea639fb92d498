//! What the sensors deliver, as plain values and the rules that update them: the Hall sectors, the position
//! latches of the digital inputs and the encoder index, the temperature channels. Below the drive, the motion
//! modes, the supervision and the I/O, which all read them (none of those imports another for them).

pub mod hall;
pub mod latch;
pub mod ssi;
pub mod temperature;
