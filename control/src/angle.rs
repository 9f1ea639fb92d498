//! The electrical angle as a wrapping fixed-point fraction of a turn: [`ElectricalAngle`] (`u32`, 2^32 = one turn)
//! and the signed difference [`AngleDelta`], with their wrapping arithmetic.
//!
//! Both are defined with the other units in [`super::units`] (where the representation is argued) and re-exported
//! here, the path the current loop, the sensors and the benches use. Conversion from encoder counts and pole pairs
//! lives with the drive (`drive/`).

pub use super::units::{AngleDelta, ElectricalAngle};
