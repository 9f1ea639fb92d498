//! The profile modes' motion quantities and their conversion from the dictionary's units: [`Velocity`] (Q32
//! inc/tick) and [`Acceleration`] (Q40 inc/tick²), defined with the other units in [`crate::units`] and
//! re-exported here, and [`MotionScale`] (rpm and rpm/s for a sensor resolution).

pub use crate::units::{Acceleration, Velocity};

use super::SLOW_TICK_HZ;
use crate::wide::{div_round_u, mul_shr, round_shr, sat_i64};

/// rpm -> inc/tick: 60 s/min * 2500 ticks/s.
const RPM_TICKS: u128 = 60 * SLOW_TICK_HZ as u128;
/// rpm/s -> inc/tick²: 60 s/min * 2500² ticks²/s².
const RPM_PER_S_TICKS2: u128 = 60 * (SLOW_TICK_HZ as u128) * (SLOW_TICK_HZ as u128);

// The planner's 128-bit view of the raw bits (the conversions are in `control::units`).
impl Velocity {
    pub(super) fn wide(self) -> i128 {
        i128::from(self.0)
    }
}

impl Acceleration {
    pub(super) fn wide(self) -> i128 {
        i128::from(self.0)
    }
}

/// Conversion between the dictionary's motion units and the internal ones, for a given sensor resolution
/// (increments per revolution: 4096 for the reference encoder, ARCHITECTURE.md "Reference plant").
///
/// The dictionary's velocity unit is rpm (0x60A9 default, device.toml 0x6081/0x607F/0x60FF/0x60B1) and its
/// acceleration unit rpm/s (0x60AA default, 0x6083..0x6085, 0x60C5, 0x60C6). `v [inc/tick] = rpm * N / (60 * 2500)`
/// and `a [inc/tick²] = rpm/s * N / (60 * 2500²)`. The factors carry 16 extra fraction bits, computed once in
/// [`MotionScale::new`]; each conversion is then one multiply and a shift (relative error below 2^-40 for
/// N >= 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotionScale {
    increments_per_revolution: u32,
    /// inc/tick Q48 per rpm.
    velocity_factor: u128,
    /// inc/tick² Q56 per rpm/s.
    acceleration_factor: u128,
    /// rpm Q96 per inc/tick Q0 (i.e. rpm per Q32 velocity bit, Q64... see `velocity_to_rpm`).
    rpm_factor: u128,
}

impl MotionScale {
    /// The scale for `increments_per_revolution` (0 is taken as 1). Divides: call when the sensor configuration
    /// changes, not per tick.
    #[must_use]
    pub fn new(increments_per_revolution: u32) -> Self {
        Self::geared(increments_per_revolution, 1, 1)
    }

    /// The scale of the load behind a gear of `numerator` motor revolutions per `denominator` load revolutions
    /// (IDX 0x3003): rpm and rpm/s of the load, `increments_per_revolution x numerator / denominator` motor
    /// increments per load revolution, exact for any ratio (the factors divide once, in 128 bits). Zeros are taken
    /// as 1.
    #[must_use]
    pub fn geared(increments_per_revolution: u32, numerator: u32, denominator: u32) -> Self {
        if numerator == denominator {
            // No gear: the constant divisors (the common case, and the cheap one at run time: a conversion at a
            // master's start-up stays within tier 2's budget).
            let n = u128::from(increments_per_revolution.max(1));
            return Self {
                increments_per_revolution: increments_per_revolution.max(1),
                velocity_factor: div_round_u(n << 48, RPM_TICKS),
                acceleration_factor: div_round_u(n << 56, RPM_PER_S_TICKS2),
                rpm_factor: div_round_u(RPM_TICKS << 64, n),
            };
        }
        let (num, den) = (u128::from(numerator.max(1)), u128::from(denominator.max(1)));
        // Increments per load revolution as n num / den: n num < 2^64; n num 2^56 < 2^120, 150,000 den 2^64 < 2^114.
        let n = u128::from(increments_per_revolution.max(1)).saturating_mul(num);
        let velocity_factor = div_round_u(n << 48, RPM_TICKS.saturating_mul(den));
        let acceleration_factor = div_round_u(n << 56, RPM_PER_S_TICKS2.saturating_mul(den));
        let rpm_factor = div_round_u((RPM_TICKS.saturating_mul(den)) << 64, n);
        Self {
            increments_per_revolution: increments_per_revolution.max(1),
            velocity_factor,
            acceleration_factor,
            rpm_factor,
        }
    }

    /// Increments per revolution (at least 1).
    #[must_use]
    pub const fn increments_per_revolution(&self) -> u32 {
        self.increments_per_revolution
    }

    /// A velocity in rpm (0x6081, 0x607F, 0x60FF, 0x60B1) in internal units, rounded, saturating.
    #[must_use]
    pub fn velocity_from_rpm(&self, rpm: i64) -> Velocity {
        let factor = i128::try_from(self.velocity_factor).unwrap_or(i128::MAX);
        Velocity(sat_i64(round_shr(mul_shr(i128::from(rpm), factor, 0), 16)))
    }

    /// A velocity in rpm, rounded to nearest (e.g. for 0x606B velocity demand value).
    #[must_use]
    pub fn velocity_to_rpm(&self, velocity: Velocity) -> i64 {
        // v [Q32 inc/tick] * (150,000 / N) [Q64] = rpm in Q96.
        let factor = i128::try_from(self.rpm_factor).unwrap_or(i128::MAX);
        let rpm_q64 = mul_shr(velocity.wide(), factor, 32);
        sat_i64(round_shr(rpm_q64, 64))
    }

    /// An acceleration in rpm/s (0x6083..0x6085, 0x60C5, 0x60C6) in internal units, rounded, saturating at
    /// [`Acceleration::MAX`].
    #[must_use]
    pub fn acceleration_from_rpm_per_s(&self, rpm_per_s: u32) -> Acceleration {
        let factor = i128::try_from(self.acceleration_factor).unwrap_or(i128::MAX);
        Acceleration(sat_i64(round_shr(mul_shr(i128::from(rpm_per_s), factor, 0), 16)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_units() {
        let s = MotionScale::new(4096);
        // 3000 rpm = 204,800 inc/s = 81.92 inc/tick.
        assert_eq!(s.velocity_from_rpm(3000).to_inc_per_s(), 204_800);
        assert_eq!(s.velocity_to_rpm(s.velocity_from_rpm(-2999)), -2999);
        // 20,000 rpm/s = 1,365,333.3 inc/s².
        assert_eq!(s.acceleration_from_rpm_per_s(20_000).to_inc_per_s2(), 1_365_333);
        // 0x60C5's default 2^32 - 1 rpm/s is 46,912 inc/tick² at 4096 inc/rev: representable.
        assert_eq!(s.acceleration_from_rpm_per_s(u32::MAX).to_bits() >> 40, 46_912);
        assert_eq!(MotionScale::new(u32::MAX).acceleration_from_rpm_per_s(u32::MAX), Acceleration::MAX);
    }

    /// A 5:1 gear (IDX 0x3003): 600 load rpm is 3000 motor rpm; 359424/875 (non-integer) stays exact to rounding.
    #[test]
    fn geared_scale_counts_load_revolutions() {
        let s = MotionScale::geared(4096, 5, 1);
        assert_eq!(s.velocity_from_rpm(600), MotionScale::new(4096).velocity_from_rpm(3000));
        assert_eq!(s.velocity_to_rpm(MotionScale::new(4096).velocity_from_rpm(-3000)), -600);
        assert_eq!(s.acceleration_from_rpm_per_s(4000), MotionScale::new(4096).acceleration_from_rpm_per_s(20_000));
        let odd = MotionScale::geared(4096, 359_424, 875);
        // 10 load rpm = 10 x 4096 x 359424 / 875 / 150,000 inc/tick = 112.1796... inc/tick.
        let v = odd.velocity_from_rpm(10).to_bits() as f64 / 2f64.powi(32);
        assert!((v - 10.0 * 4096.0 * 359_424.0 / 875.0 / 150_000.0).abs() < 1e-6, "{v}");
        assert_eq!(odd.velocity_to_rpm(odd.velocity_from_rpm(-7)), -7);
    }
}
