//! The units of the control code: one newtype per physical quantity, all defined here by one macro, with the
//! conversions between them (convention 4 of `shared/design/ARCHITECTURE.md`: a quantity is typed by its unit).
//!
//! # Why one macro
//! Each unit is a one-field newtype over its fixed-point representation with the same derives, a `ZERO` and a
//! constructor and accessor for the raw bits. Written out by hand per type, these had drifted apart (`Increments`
//! had neither `ZERO` nor accessors; only `Amps` and `Volts` converted with `From`) and took more lines than the
//! units' real content. `unit!` is the one way to define a unit: the declaration says what differs (repr,
//! resolution, order, accessor names) and the macro writes the rest, the same code as the hand-written versions
//! (`const fn`, `#[must_use]`), so the fast paths compile to the same instructions (the drive image built from the
//! hand-written types and from these is byte-identical). Operations peculiar to a unit (wrapping angle arithmetic,
//! conversions to and from the dictionary's units) are written below each definition.
//!
//! # Formats
//! - Current [`Amps`] and voltage [`Volts`]: `I16F16`; the range argument is in [`super::frames`].
//! - Velocity [`IncPerTick`] and acceleration [`IncPerTick2`] of the slow loops: increments of the position sensor
//!   per slow tick (400 us) and per tick squared, `I16F16`; the range argument is in [`super::velocity`].
//! - Position [`Increments`]: an exact, wrapping `i32` count, like the CiA 402 INTEGER32 position objects
//!   ([`super::position`]).
//! - Electrical angle [`ElectricalAngle`] and angle difference [`AngleDelta`]: a `u32` (`i32`) fraction of a turn,
//!   2^32 = one turn, wrapping.
//! - Profile velocity [`Velocity`] and acceleration [`Acceleration`] of the set-point generator: increments per
//!   tick in Q32 and per tick squared in Q40, `i64` ([`super::trajectory`]).
//!
//! A `fixed` representation (`I16F16`) is itself the quantity in the unit, so those units convert to and from it
//! with `From`; an integer representation is a count of LSBs of the stated resolution and converts only through
//! the named raw-bits functions, so that bits are never taken for whole units by accident. Quantities on a number
//! line derive `PartialOrd` and `Ord`; the electrical angle, a point on a circle, has no order and does not.
//!
//! The types are also re-exported where they were defined before this module existed (`frames::Amps`,
//! `velocity::IncPerTick`, `position::Increments`, `angle::ElectricalAngle`, `trajectory::Velocity`, ...), the paths
//! the rest of the firmware, the simulator and the generated dictionary code use.

use fixed::types::I16F16;

use super::velocity::{sat_i32, SLOW_TICK_HZ};
use super::wide::{self, div_shl, round_shr, sat_i64};

/// Defines a unit newtype `pub struct $name(pub $repr)`: the shared derives (`Clone, Copy, Debug, Default,
/// PartialEq, Eq, Hash`; give `#[derive(PartialOrd, Ord)]` among the attributes for an ordered quantity), the
/// constant `ZERO` (documented by the attributes before `ZERO;`) and the raw-bits constructor and accessor under the
/// given names, `#[must_use] const fn`, documented with the resolution `$lsb`.
///
/// - `bits(fixed $bits): from / to, lsb "..."`: the repr is a `fixed` type whose bits are `$bits`; adds `From`
///   both ways between the unit and its repr.
/// - `bits(integer): from / to, lsb "..."`: the repr is the raw integer itself.
macro_rules! unit {
    (
        $(#[$attr:meta])*
        pub struct $name:ident(pub $repr:ty);
        bits(fixed $bits:ty): $from:ident / $to:ident, lsb $lsb:literal;
        $(#[$zero_attr:meta])*
        ZERO;
    ) => {
        unit!(@type $(#[$attr])* $name($repr));

        impl $name {
            $(#[$zero_attr])*
            pub const ZERO: Self = Self(<$repr>::ZERO);

            #[doc = concat!("From the raw `", stringify!($repr), "` bits (units of ", $lsb, ").")]
            #[must_use]
            pub const fn $from(bits: $bits) -> Self {
                Self(<$repr>::from_bits(bits))
            }

            #[doc = concat!("The raw `", stringify!($repr), "` bits (units of ", $lsb, ").")]
            #[must_use]
            pub const fn $to(self) -> $bits {
                self.0.to_bits()
            }
        }

        impl From<$repr> for $name {
            fn from(x: $repr) -> Self {
                Self(x)
            }
        }

        impl From<$name> for $repr {
            fn from(x: $name) -> Self {
                x.0
            }
        }
    };
    (
        $(#[$attr:meta])*
        pub struct $name:ident(pub $repr:ty);
        bits(integer): $from:ident / $to:ident, lsb $lsb:literal;
        $(#[$zero_attr:meta])*
        ZERO;
    ) => {
        unit!(@type $(#[$attr])* $name($repr));

        impl $name {
            $(#[$zero_attr])*
            pub const ZERO: Self = Self(0);

            #[doc = concat!("From the raw `", stringify!($repr), "` bits (units of ", $lsb, ").")]
            #[must_use]
            pub const fn $from(bits: $repr) -> Self {
                Self(bits)
            }

            #[doc = concat!("The raw `", stringify!($repr), "` bits (units of ", $lsb, ").")]
            #[must_use]
            pub const fn $to(self) -> $repr {
                self.0
            }
        }
    };
    (@type $(#[$attr:meta])* $name:ident($repr:ty)) => {
        $(#[$attr])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
        pub struct $name(pub $repr);
    };
}

// ---------------------------------------------------------------------------------------------------------------
// Current loop: currents and voltages.

unit! {
    /// An electric current in amperes, `I16F16` (resolution 1/65536 A, range +-32768 A).
    #[derive(PartialOrd, Ord)]
    pub struct Amps(pub I16F16);
    bits(fixed i32): from_bits / to_bits, lsb "1/65536 A";
    /// Zero current.
    ZERO;
}

unit! {
    /// An electric potential difference in volts, `I16F16` (resolution 1/65536 V, range +-32768 V).
    #[derive(PartialOrd, Ord)]
    pub struct Volts(pub I16F16);
    bits(fixed i32): from_bits / to_bits, lsb "1/65536 V";
    /// Zero voltage.
    ZERO;
}

impl Amps {
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

// ---------------------------------------------------------------------------------------------------------------
// Electrical angle.

unit! {
    /// An electrical angle: `u32` fraction of a turn, 2^32 = one turn, wrapping.
    ///
    /// One LSB is 2^-32 turn (8.4e-8 degrees). Addition and subtraction wrap modulo one turn for free
    /// (`wrapping_add`), which is exactly the arithmetic of an angle. A `u32` rather than a `u16` because angle
    /// integration (speed x 40 us) at low speed needs the finer resolution, and because the conversion from the
    /// reference encoder is exact in both: 4,096 counts per mechanical turn and 7 pole pairs (ARCHITECTURE.md,
    /// reference plant) give 7 * 2^20 LSB per count. Conversion from encoder counts and pole pairs lives with the
    /// drive (`drive/`); here is only the wrapping arithmetic.
    pub struct ElectricalAngle(pub u32);
    bits(integer): from_turn_bits / turn_bits, lsb "2^-32 turn, 2^32 = one turn";
    /// Zero (the d axis aligned with phase A).
    ZERO;
}

unit! {
    /// A signed difference of two angles or an angle increment: `i32` fraction of a turn, 2^32 = one turn, so the
    /// range is [-1/2, +1/2) turn.
    #[derive(PartialOrd, Ord)]
    pub struct AngleDelta(pub i32);
    bits(integer): from_turn_bits / turn_bits, lsb "2^-32 turn, 2^32 = one turn";
    /// No change.
    ZERO;
}

impl ElectricalAngle {
    /// A quarter turn (90 electrical degrees).
    pub const QUARTER_TURN: Self = Self(1 << 30);
    /// A half turn (180 electrical degrees).
    pub const HALF_TURN: Self = Self(1 << 31);

    /// The electrical angle of a mechanical angle, both as `u32` fractions of a turn: electrical = pole pairs x
    /// mechanical, modulo one turn. The wrapping multiplication is exact, not an approximation: the integer part of
    /// the product (whole electrical turns) is what the modulo discards.
    #[must_use]
    pub const fn from_mechanical_turn_bits(mechanical: u32, pole_pairs: u8) -> Self {
        Self(mechanical.wrapping_mul(pole_pairs as u32))
    }

    /// This angle advanced by `delta`, wrapping modulo one turn.
    #[must_use]
    pub const fn wrapping_add(self, delta: AngleDelta) -> Self {
        Self(self.0.wrapping_add_signed(delta.0))
    }

    /// This angle moved back by `delta`, wrapping modulo one turn.
    #[must_use]
    pub const fn wrapping_sub(self, delta: AngleDelta) -> Self {
        // Two's complement: subtracting the bit pattern is the same as adding its negation, modulo 2^32.
        Self(self.0.wrapping_sub(delta.0 as u32))
    }

    /// The shortest signed difference `self - other`, in [-1/2, +1/2) turn.
    #[must_use]
    pub const fn difference(self, other: Self) -> AngleDelta {
        // Reinterpreting the wrapped u32 difference as i32 picks the representative nearest to zero.
        AngleDelta(self.0.wrapping_sub(other.0) as i32)
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Slow loops (velocity and position control): position, velocity, acceleration.

unit! {
    /// A position in increments of the main sensor: an exact, wrapping `i32` (CiA 402 INTEGER32 positions).
    #[derive(PartialOrd, Ord)]
    pub struct Increments(pub i32);
    bits(integer): from_bits / to_bits, lsb "one increment";
    /// Position zero.
    ZERO;
}

unit! {
    /// A velocity in increments of the position sensor per slow tick (400 us), `I16F16`.
    #[derive(PartialOrd, Ord)]
    pub struct IncPerTick(pub I16F16);
    bits(fixed i32): from_bits / to_bits, lsb "2^-16 inc/tick";
    /// Zero velocity.
    ZERO;
}

unit! {
    /// An acceleration in increments of the position sensor per slow tick squared, `I16F16`.
    #[derive(PartialOrd, Ord)]
    pub struct IncPerTick2(pub I16F16);
    bits(fixed i32): from_bits / to_bits, lsb "2^-16 inc/tick^2";
    /// Zero acceleration.
    ZERO;
}

impl Increments {
    /// The wrapping difference `self - other`: exact while the true distance is below 2^31 increments.
    #[must_use]
    pub const fn wrapping_sub(self, other: Self) -> i32 {
        self.0.wrapping_sub(other.0)
    }
}

impl IncPerTick {
    /// From increments per second, rounded to nearest, saturating. Not for the slow tick (one division).
    #[must_use]
    pub fn from_inc_per_s(inc_per_s: i32) -> Self {
        let scaled = i64::from(inc_per_s).wrapping_mul(65_536); // |.| < 2^47
        let f = i64::from(SLOW_TICK_HZ);
        let half_f = i64::from(SLOW_TICK_HZ >> 1);
        let half = if scaled < 0 { half_f.wrapping_neg() } else { half_f };
        Self::from_bits(sat_i32(scaled.wrapping_add(half).checked_div(f).unwrap_or(0)))
    }

    /// To increments per second, rounded to nearest.
    #[must_use]
    pub fn to_inc_per_s(self) -> i32 {
        // |bits * 2500| < 2^43; the quotient fits an i32 for |v| < 32768 inc/tick (82 M inc/s).
        let scaled = i64::from(self.to_bits()).wrapping_mul(i64::from(SLOW_TICK_HZ));
        sat_i32(scaled.wrapping_add(1 << 15) >> 16)
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Profile modes (set-point generator): velocity and acceleration with the range of a whole move.

unit! {
    /// A velocity in increments per slow tick (400 us), Q32 (units of 2^-32 inc/tick).
    #[derive(PartialOrd, Ord)]
    pub struct Velocity(pub i64);
    bits(integer): from_bits / to_bits, lsb "2^-32 inc/tick, Q32";
    /// Zero velocity.
    ZERO;
}

unit! {
    /// An acceleration in increments per slow tick squared, Q40 (units of 2^-40 inc/tick²).
    #[derive(PartialOrd, Ord)]
    pub struct Acceleration(pub i64);
    bits(integer): from_bits / to_bits, lsb "2^-40 inc/tick², Q40";
    /// Zero acceleration.
    ZERO;
}

impl Velocity {
    /// Fraction bits of the representation.
    pub const FRAC_BITS: u32 = 32;

    /// From whole increments per slow tick.
    #[must_use]
    pub const fn from_inc_per_tick(inc_per_tick: i32) -> Self {
        // |inc| < 2^31: the Q32 value stays below 2^63.
        Self((inc_per_tick as i64) << 32)
    }

    /// From increments per second, rounded toward zero, saturating. Divides: not for the slow tick.
    #[must_use]
    pub fn from_inc_per_s(inc_per_s: i64) -> Self {
        Self(sat_i64(div_shl(i128::from(inc_per_s), i128::from(SLOW_TICK_HZ), 32)))
    }

    /// To increments per second, rounded to nearest.
    #[must_use]
    pub fn to_inc_per_s(self) -> i64 {
        // |bits * 2500| < 2^75: no wrap in i128.
        sat_i64(round_shr(i128::from(self.0).wrapping_mul(i128::from(SLOW_TICK_HZ)), 32))
    }

    /// Increments per tick in Q16 (`I16F16` bits, the format of [`IncPerTick`]), rounded, saturating.
    #[must_use]
    pub fn to_inc_per_tick_q16(self) -> i32 {
        wide::sat_i32(round_shr(i128::from(self.0), 16))
    }
}

impl Acceleration {
    /// Fraction bits of the representation.
    pub const FRAC_BITS: u32 = 40;
    /// The largest representable acceleration (about 8.4e6 inc/tick²): "no limit".
    pub const MAX: Self = Self(i64::MAX);

    /// From increments per second squared, rounded toward zero, saturating. Divides: not for the slow tick.
    #[must_use]
    pub fn from_inc_per_s2(inc_per_s2: i64) -> Self {
        let ticks2 = i128::from(SLOW_TICK_HZ).wrapping_mul(i128::from(SLOW_TICK_HZ));
        Self(sat_i64(div_shl(i128::from(inc_per_s2), ticks2, 40)))
    }

    /// To increments per second squared, rounded to nearest.
    #[must_use]
    pub fn to_inc_per_s2(self) -> i64 {
        // |bits| * 2500² < 2^86: no wrap in i128.
        let ticks2 = i128::from(SLOW_TICK_HZ).wrapping_mul(i128::from(SLOW_TICK_HZ));
        sat_i64(round_shr(i128::from(self.0).wrapping_mul(ticks2), 40))
    }

    /// Increments per tick² in Q16 (`I16F16` bits, the format of [`IncPerTick2`]), rounded, saturating.
    #[must_use]
    pub fn to_inc_per_tick2_q16(self) -> i32 {
        wide::sat_i32(round_shr(i128::from(self.0), 24))
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

    #[test]
    fn wraps_modulo_one_turn() {
        let a = ElectricalAngle(u32::MAX - 9);
        assert_eq!(a.wrapping_add(AngleDelta(20)), ElectricalAngle(10));
        assert_eq!(ElectricalAngle(10).wrapping_sub(AngleDelta(20)), ElectricalAngle(u32::MAX - 9));
        assert_eq!(ElectricalAngle(10).difference(a), AngleDelta(20));
        assert_eq!(a.difference(ElectricalAngle(10)), AngleDelta(-20));
        assert_eq!(ElectricalAngle::HALF_TURN.difference(ElectricalAngle::ZERO), AngleDelta(i32::MIN));
    }

    #[test]
    fn mechanical_to_electrical_is_exact() {
        // Reference encoder: 4096 counts per turn = 2^20 turn bits per count; 7 pole pairs.
        let per_count = 1u32 << 20;
        for count in [0u32, 1, 585, 4095] {
            let e = ElectricalAngle::from_mechanical_turn_bits(count.wrapping_mul(per_count), 7);
            assert_eq!(u64::from(e.0), (u64::from(count) * 7 * (1 << 20)) % (1 << 32));
        }
    }

    #[test]
    fn macro_accessors_round_trip() {
        // The generated ZERO and raw-bits functions of each format.
        assert_eq!(Amps::from_bits(-3).to_bits(), -3);
        assert_eq!(I16F16::from(Volts::from_bits(65_536)), I16F16::ONE);
        assert_eq!(IncPerTick::from(I16F16::ONE).to_bits(), 1 << 16);
        assert_eq!(IncPerTick2::ZERO, IncPerTick2::default());
        assert_eq!(Increments::from_bits(-7).to_bits(), -7);
        assert_eq!(ElectricalAngle::from_turn_bits(5).turn_bits(), 5);
        assert_eq!(AngleDelta::ZERO.turn_bits(), 0);
        assert_eq!(Velocity::from_inc_per_tick(3).to_bits(), 3 << 32);
        assert_eq!(Acceleration::from_bits(1).to_bits(), 1);
        assert!(Increments(-1) < Increments::ZERO);
    }
}
