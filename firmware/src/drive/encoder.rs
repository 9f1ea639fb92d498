//! The incremental encoder as the drive sees it: its configuration from the dictionary (0x3010, 0x3001:03) and the
//! exact multi-turn position and electrical count built from the 16-bit hardware counter (see "How the angle is
//! built" in [`super::commutation`]: nothing is accumulated in a float or a rounded angle).

use crate::control::angle::AngleDelta;

/// Encoder parameters, from the dictionary when the power stage is switched on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderConfig {
    /// Counts (quadrature increments) per mechanical revolution: 4 x 0x3010:01, any value in 64..=10,000,000,
    /// power of two or not (2,000 / 4,000 / 5,000 / 10,000 for 500 / 1,000 / 1,250 / 2,500 lines). Nothing
    /// depends on it dividing the 16-bit counter's 2^16: the counter is only differenced, and the electrical count
    /// is kept in `[0, cpr)` by one conditional add or subtract of `cpr` per tick (no mask, no division in tier 1).
    pub counts_per_rev: u32,
    /// Pole pairs, 0x3001:03.
    pub pole_pairs: u8,
    /// Counting direction inverted, 0x3010:02 bit 4.
    pub inverted: bool,
    /// The encoder has an index channel, 0x3010:02 bit 0.
    pub has_index: bool,
}

impl EncoderConfig {
    /// The reference encoder and motor: 1,024 lines (4,096 counts) with index, 7 pole pairs.
    pub const REFERENCE: Self = Self { counts_per_rev: 4096, pole_pairs: 7, inverted: false, has_index: true };

    /// From 0x3010:01 (pulses per revolution), 0x3010:02 (type bits) and 0x3001:03 (pole pairs). Pulses are
    /// clamped to the dictionary's range 16..=2,500,000 and pole pairs to at least 1.
    #[must_use]
    pub fn from_od(pulses: u32, encoder_type: u16, pole_pairs: u8) -> Self {
        Self {
            counts_per_rev: pulses.clamp(16, 2_500_000).saturating_mul(4),
            pole_pairs: pole_pairs.max(1),
            inverted: encoder_type & 0x0010 != 0,
            has_index: encoder_type & 0x0001 != 0,
        }
    }

    /// Electrical angle per electrical count, `round(2^32 / cpr)` (exact for a power of two).
    #[must_use]
    pub fn angle_per_count(&self) -> u32 {
        let cpr = u64::from(self.counts_per_rev.max(1));
        u32::try_from(((1u64 << 32).saturating_add(cpr / 2)).checked_div(cpr).unwrap_or(0)).unwrap_or(u32::MAX)
    }
}

/// The incremental encoder as seen by the drive: exact multi-turn position and electrical count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoder {
    config: EncoderConfig,
    angle_per_count: u32,
    last_counter: u16,
    synced: bool,
    position: i32,
    electrical_count: u32,
    last_delta: i32,
}

impl Encoder {
    /// An encoder at position 0 and electrical count 0; the first [`Encoder::update`] only takes the counter's
    /// value as the start.
    #[must_use]
    pub fn new(config: EncoderConfig) -> Self {
        Self {
            config,
            angle_per_count: config.angle_per_count(),
            last_counter: 0,
            synced: false,
            position: 0,
            electrical_count: 0,
            last_delta: 0,
        }
    }

    /// The configuration.
    #[must_use]
    pub const fn config(&self) -> &EncoderConfig {
        &self.config
    }

    /// Signed counts from `from` to `to` of the 16-bit counter, in the drive's positive direction.
    #[inline(always)]
    fn counts_between(&self, from: u16, to: u16) -> i32 {
        // The counter wraps at 2^16: reinterpreting the wrapped difference as i16 gives the shortest motion.
        let d = i32::from(to.wrapping_sub(from) as i16);
        if self.config.inverted {
            d.wrapping_neg()
        } else {
            d
        }
    }

    /// `x` modulo the counts per revolution, for `x` already within one revolution of the range (one tick's motion);
    /// a slow path handles anything else.
    #[inline(always)]
    fn wrap_count(&self, x: i32) -> u32 {
        // cpr <= 10,000,000 < 2^31: the conversions are exact.
        let cpr = self.config.counts_per_rev as i32;
        if x < 0 {
            let y = x.wrapping_add(cpr);
            if y >= 0 {
                return y as u32;
            }
        } else if x < cpr {
            return x as u32;
        } else {
            let y = x.wrapping_sub(cpr);
            if y < cpr {
                return y as u32;
            }
        }
        x.checked_rem_euclid(cpr).unwrap_or(0) as u32
    }

    /// Electrical counts moved for `counts` mechanical counts, not reduced modulo cpr (|counts| <= 32,768 and
    /// pole pairs <= 255 keep it within 2^23).
    #[inline(always)]
    fn electrical_counts(&self, counts: i32) -> i32 {
        counts.wrapping_mul(i32::from(self.config.pole_pairs))
    }

    /// Takes a new counter value; returns the counts moved since the last one.
    #[inline]
    pub fn update(&mut self, counter: u16) -> i32 {
        if !self.synced {
            self.synced = true;
            self.last_counter = counter;
        }
        let delta = self.counts_between(self.last_counter, counter);
        self.last_counter = counter;
        // Wrapping on purpose: the position is a wrapping multi-turn count (CiA 402 position actual wraps too).
        self.position = self.position.wrapping_add(delta);
        // electrical_count < cpr < 2^24 and |delta * pp| < 2^23: the sum cannot wrap.
        let e = (self.electrical_count as i32).wrapping_add(self.electrical_counts(delta));
        self.electrical_count = self.wrap_count(e);
        self.last_delta = delta;
        delta
    }

    /// Whether `counter` continues the motion of the last update within `tolerance` counts: the step to it differs
    /// from the last step by at most `tolerance` (no shaft changes its speed by more than a count per period; a
    /// position from a corrupted absolute-encoder frame jumps). Always true before the first update.
    #[inline(always)]
    #[must_use]
    pub fn continues(&self, counter: u16, tolerance: u32) -> bool {
        let step = self.counts_between(self.last_counter, counter);
        !self.synced || step.wrapping_sub(self.last_delta).unsigned_abs() <= tolerance
    }

    /// Whether the encoder has taken a first value.
    #[must_use]
    pub const fn synced(&self) -> bool {
        self.synced
    }

    /// The counter value of the last update.
    #[must_use]
    pub const fn last_counter(&self) -> u16 {
        self.last_counter
    }

    /// Multi-turn position in increments (wrapping), relative to where the encoder started.
    #[must_use]
    pub const fn position(&self) -> i32 {
        self.position
    }

    /// The multi-turn position at an earlier counter value (an index latch), going back from the last update.
    #[must_use]
    pub fn position_at(&self, counter: u16) -> i32 {
        self.position.wrapping_sub(self.counts_between(counter, self.last_counter))
    }

    /// Counts moved in the last update.
    #[must_use]
    pub const fn last_delta(&self) -> i32 {
        self.last_delta
    }

    /// The electrical count now, in `[0, cpr)`.
    #[must_use]
    pub const fn electrical_count(&self) -> u32 {
        self.electrical_count
    }

    /// The electrical count at an earlier counter value (an index latch), going back from the last update.
    #[must_use]
    pub fn electrical_count_at(&self, counter: u16) -> u32 {
        let back = self.electrical_counts(self.counts_between(counter, self.last_counter));
        self.wrap_count((self.electrical_count as i32).wrapping_sub(back))
    }

    /// The electrical angle of an electrical count, before the commutation offset.
    #[inline(always)]
    #[must_use]
    pub const fn raw_angle(&self, electrical_count: u32) -> u32 {
        // Wrapping on purpose: the integer part of the product is whole electrical turns.
        electrical_count.wrapping_mul(self.angle_per_count)
    }

    /// Half of the electrical angle moved in the last update (the midpoint between the last two samples).
    pub(super) fn half_last_step(&self) -> AngleDelta {
        let step = i64::from(self.electrical_counts(self.last_delta)).wrapping_mul(i64::from(self.angle_per_count));
        // One tick moves less than half an electrical turn in any sane case; truncation to i32 wraps like an angle.
        AngleDelta((step / 2) as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::angle::ElectricalAngle;

    const DEG: f64 = 4_294_967_296.0 / 360.0;

    fn deg(a: ElectricalAngle) -> f64 {
        f64::from(a.0) / DEG
    }

    #[test]
    fn encoder_counts_to_electrical_angle() {
        for (cpr_pulses, pp) in
            [(1024u32, 7u8), (1024, 1), (500, 4), (2048, 12), (16, 1), (1000, 255), (1250, 7), (2500, 7)]
        {
            let cfg = EncoderConfig::from_od(cpr_pulses, 0x0001, pp);
            let cpr = i64::from(cfg.counts_per_rev);
            let mut enc = Encoder::new(cfg);
            let mut counter = 65_500u16;
            assert_eq!(enc.update(counter), 0, "the first sample only syncs");
            let mut total: i64 = 0;
            // Forward and backward in steps that wrap the 16-bit counter and the revolution.
            for step in [1i32, 37, 1000, -3000, 12_345, -32_000, 7, 30_000, 30_000, -5] {
                counter = counter.wrapping_add(step as u16);
                total += i64::from(step);
                assert_eq!(enc.update(counter), step);
                assert_eq!(i64::from(enc.position()), total);
                let e_counts = (total * i64::from(pp)).rem_euclid(cpr);
                assert_eq!(i64::from(enc.electrical_count()), e_counts, "cpr {cpr} pp {pp}");
                let want = e_counts as f64 / cpr as f64 * 360.0;
                let got = deg(ElectricalAngle(enc.raw_angle(enc.electrical_count())));
                let err = (got - want + 180.0).rem_euclid(360.0) - 180.0;
                assert!(err.abs() < 1e-3, "cpr {cpr} pp {pp} total {total}: {got} vs {want}");
            }
        }
        // Reference encoder: exact, 7 * 2^20 turn bits per count.
        let mut enc = Encoder::new(EncoderConfig::REFERENCE);
        enc.update(0);
        enc.update(585);
        assert_eq!(enc.raw_angle(enc.electrical_count()), 585u32.wrapping_mul(7 << 20));
        // Inverted direction counts down.
        let mut inv = Encoder::new(EncoderConfig { inverted: true, ..EncoderConfig::REFERENCE });
        inv.update(100);
        assert_eq!(inv.update(90), 10);
        assert_eq!(inv.electrical_count(), 70);
    }
}
