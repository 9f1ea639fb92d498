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

use fixed::types::I16F16;

/// An electric current in amperes, `I16F16` (resolution 1/65536 A, range +-32768 A).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Amps(pub I16F16);

/// An electric potential difference in volts, `I16F16` (resolution 1/65536 V, range +-32768 V).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Volts(pub I16F16);

impl Amps {
    /// Zero current.
    pub const ZERO: Self = Self(I16F16::ZERO);

    /// From the raw `I16F16` bit pattern (units of 1/65536 A).
    #[must_use]
    pub const fn from_bits(bits: i32) -> Self {
        Self(I16F16::from_bits(bits))
    }

    /// The raw `I16F16` bit pattern (units of 1/65536 A).
    #[must_use]
    pub const fn to_bits(self) -> i32 {
        self.0.to_bits()
    }

    /// From milliamperes, the unit of the dictionary's current objects (IDX 0x30D0 current demand, 0x30D1 current
    /// actual: `shared/spec/control-and-protection.md` §1.1). Saturates at the `I16F16` range.
    #[must_use]
    pub fn from_milliamps(ma: i32) -> Self {
        Self(milli_to_i16f16(ma))
    }

    /// To milliamperes, rounded to nearest (ties away from zero).
    #[must_use]
    pub fn to_milliamps(self) -> i32 {
        i16f16_to_milli(self.0)
    }
}

impl Volts {
    /// Zero voltage.
    pub const ZERO: Self = Self(I16F16::ZERO);

    /// From the raw `I16F16` bit pattern (units of 1/65536 V).
    #[must_use]
    pub const fn from_bits(bits: i32) -> Self {
        Self(I16F16::from_bits(bits))
    }

    /// The raw `I16F16` bit pattern (units of 1/65536 V).
    #[must_use]
    pub const fn to_bits(self) -> i32 {
        self.0.to_bits()
    }

    /// From millivolts. Saturates at the `I16F16` range.
    #[must_use]
    pub fn from_millivolts(mv: i32) -> Self {
        Self(milli_to_i16f16(mv))
    }

    /// To millivolts, rounded to nearest (ties away from zero).
    #[must_use]
    pub fn to_millivolts(self) -> i32 {
        i16f16_to_milli(self.0)
    }
}

impl From<I16F16> for Amps {
    fn from(x: I16F16) -> Self {
        Self(x)
    }
}

impl From<Amps> for I16F16 {
    fn from(x: Amps) -> Self {
        x.0
    }
}

impl From<I16F16> for Volts {
    fn from(x: I16F16) -> Self {
        Self(x)
    }
}

impl From<Volts> for I16F16 {
    fn from(x: Volts) -> Self {
        x.0
    }
}

/// `milli / 1000` as `I16F16`, rounded to nearest, saturating. Not for the 25 kHz path (one 64-bit division).
fn milli_to_i16f16(milli: i32) -> I16F16 {
    // |milli| * 65536 < 2^47: no overflow in i64. The division rounds half away from zero.
    let scaled = i64::from(milli).wrapping_mul(65_536);
    let half = if scaled < 0 { -500 } else { 500 };
    let bits = scaled.wrapping_add(half).checked_div(1000).unwrap_or(0);
    I16F16::from_bits(saturate_i64_to_i32(bits))
}

/// `x * 1000` as an integer, rounded to nearest. |x| < 32768 so the result fits an i32.
fn i16f16_to_milli(x: I16F16) -> i32 {
    let scaled = i64::from(x.to_bits()).wrapping_mul(1000);
    let half = if scaled < 0 { -32_768 } else { 32_768 };
    // |scaled| < 2^41; the quotient is below 2^25 in magnitude.
    saturate_i64_to_i32(scaled.wrapping_add(half).checked_div(65_536).unwrap_or(0))
}

fn saturate_i64_to_i32(x: i64) -> i32 {
    i32::try_from(x).unwrap_or(if x < 0 { i32::MIN } else { i32::MAX })
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn milli_conversions_round_and_saturate() {
        assert_eq!(Amps::from_milliamps(1500).0, I16F16::from_num(1.5));
        assert_eq!(Amps::from_milliamps(-1).to_bits(), -66); // -65.536 rounds to -66
        assert_eq!(Amps::from_milliamps(i32::MAX).to_bits(), i32::MAX);
        assert_eq!(Amps::from_milliamps(i32::MIN).to_bits(), i32::MIN);
        assert_eq!(Volts::from_millivolts(24_000).to_millivolts(), 24_000);
        assert_eq!(Volts::from_bits(i32::MIN).to_millivolts(), -32_768_000);
        for mv in [-60_000, -1, 0, 1, 7, 999, 24_001] {
            assert_eq!(Volts::from_millivolts(mv).to_millivolts(), mv);
        }
    }
}
