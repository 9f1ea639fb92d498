//! The electrical angle as a wrapping fixed-point fraction of a turn.
//!
//! Representation: a `u32` where 2^32 is one full electrical turn (360 degrees), so one LSB is 2^-32 turn
//! (8.4e-8 degrees). Addition and subtraction wrap modulo one turn for free (`wrapping_add`), which is exactly the
//! arithmetic of an angle. A `u32` rather than a `u16` because angle integration (speed x 40 us) at low speed needs
//! the finer resolution, and because the conversion from the reference encoder is exact in both: 4,096 counts per
//! mechanical turn and 7 pole pairs (ARCHITECTURE.md, reference plant) give 7 * 2^20 LSB per count.
//!
//! Conversion from encoder counts and pole pairs lives with the drive (`drive/`); this module only supplies the
//! wrapping arithmetic.

/// An electrical angle: `u32` fraction of a turn, 2^32 = one turn, wrapping.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ElectricalAngle(pub u32);

/// A signed difference of two angles or an angle increment: `i32` fraction of a turn, 2^32 = one turn, so the
/// range is [-1/2, +1/2) turn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct AngleDelta(pub i32);

impl ElectricalAngle {
    /// Zero (the d axis aligned with phase A).
    pub const ZERO: Self = Self(0);
    /// A quarter turn (90 electrical degrees).
    pub const QUARTER_TURN: Self = Self(1 << 30);
    /// A half turn (180 electrical degrees).
    pub const HALF_TURN: Self = Self(1 << 31);

    /// From the raw turn fraction (2^32 = one turn).
    #[must_use]
    pub const fn from_turn_bits(bits: u32) -> Self {
        Self(bits)
    }

    /// The raw turn fraction (2^32 = one turn).
    #[must_use]
    pub const fn turn_bits(self) -> u32 {
        self.0
    }

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

impl AngleDelta {
    /// No change.
    pub const ZERO: Self = Self(0);

    /// From the raw signed turn fraction (2^32 = one turn).
    #[must_use]
    pub const fn from_turn_bits(bits: i32) -> Self {
        Self(bits)
    }

    /// The raw signed turn fraction (2^32 = one turn).
    #[must_use]
    pub const fn turn_bits(self) -> i32 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
