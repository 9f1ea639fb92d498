//! Typed quantities and reference frames of the current loop (`shared/design/ARCHITECTURE.md`, convention 4).
//!
//! Currents and voltages are `I16F16` (signed, 16 integer and 16 fraction bits):
//! - currents: the reference plant's shunts span +-16.5 A (ARCHITECTURE.md, reference plant); I16F16 gives a
//!   resolution of 15.3 uA (1/65536 A), 270 times finer than one 12-bit ADC step (8.06 mA), and headroom to
//!   +-32768 A so that sums of three phases and d/q errors never need more than a saturating add;
//! - voltages: the bus is at most about 60 V (12-bit bus sensing with 60 V full scale); I16F16 resolves 15.3 uV.
//!
//! The frames are plain generic newtypes: `Abc<Amps>` (phase currents), `AlphaBeta<Volts>` (stator frame),
//! `Dq<Amps>` (rotor frame), and `Abc<u16>` for per-phase compare values (field names carry the unit).
//!
//! [`Amps`] and [`Volts`] are defined with the other units in [`super::units`] and re-exported here.

pub use super::units::{Amps, Volts};

/// Three phase quantities (phases A, B, C): the natural frame of the inverter and the shunts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Abc<T> {
    /// Phase A.
    pub a: T,
    /// Phase B.
    pub b: T,
    /// Phase C.
    pub c: T,
}

/// The stationary two-axis frame (Clarke transform, amplitude-invariant): alpha along phase A.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct AlphaBeta<T> {
    /// Alpha axis (aligned with phase A).
    pub alpha: T,
    /// Beta axis (90 electrical degrees ahead of alpha).
    pub beta: T,
}

/// The rotor frame (Park transform): d along the rotor flux, q 90 electrical degrees ahead (torque-producing).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Dq<T> {
    /// Direct axis.
    pub d: T,
    /// Quadrature axis.
    pub q: T,
}

impl<T> Abc<T> {
    /// The three phases in a row.
    pub const fn new(a: T, b: T, c: T) -> Self {
        Self { a, b, c }
    }
}

impl<T> AlphaBeta<T> {
    /// Both axes.
    pub const fn new(alpha: T, beta: T) -> Self {
        Self { alpha, beta }
    }
}

impl<T> Dq<T> {
    /// Both axes.
    pub const fn new(d: T, q: T) -> Self {
        Self { d, q }
    }
}
