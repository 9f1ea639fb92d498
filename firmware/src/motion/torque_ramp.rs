//! The slow-down ramp of cyclic synchronous torque mode (CST, 0x6060 = 10): a stop "with the slow-down ramp"
//! (0x605B or 0x605C = 1, 0x605A = 1 or 5, 0x605E = 1) takes the torque demand from its present value to zero at
//! the torque slope 0x6087, in per mille of the rated torque per second. In the torque modes of CiA 402 the
//! slow-down ramp is a torque ramp, not a speed ramp: the drive does not command a speed in CST, so it lets the
//! torque fall at the configured rate and ends the stop when none is left (the motor then runs free, as it would
//! in CST with 0x6071 = 0). The quick-stop ramp (0x605A = 2 or 6, the default) still stops the motor with the
//! quick stop deceleration 0x6085: a quick stop must bring the axis to standstill.

use crate::control::trajectory::SLOW_TICK_HZ;

/// The torque demand of a CST slow-down stop, per mille of the rated torque in Q16 (fractions of a per mille per
/// tick keep slow slopes exact).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TorqueRamp {
    permille_q16: i64,
    step_q16: i64,
}

impl TorqueRamp {
    /// A ramp from `from_permille` (0x6074, the torque demand in force) to zero at `slope` (0x6087, per mille
    /// per second; 0 counts as 1).
    #[must_use]
    pub fn new(from_permille: i32, slope: u32) -> Self {
        // slope / 2,500 per tick in Q16: at least one Q16 LSB, so every ramp ends.
        let step = (u64::from(slope.max(1)) << 16).checked_div(u64::from(SLOW_TICK_HZ)).unwrap_or(1);
        Self { permille_q16: i64::from(from_permille) << 16, step_q16: i64::try_from(step.max(1)).unwrap_or(i64::MAX) }
    }

    /// One slow tick: the demand moves towards zero by one step; the demand for this tick, per mille, rounded
    /// toward zero.
    pub fn step(&mut self) -> i32 {
        let p = self.permille_q16;
        self.permille_q16 =
            if p > 0 { p.saturating_sub(self.step_q16).max(0) } else { p.saturating_add(self.step_q16).min(0) };
        // Toward zero, as the division truncates.
        let whole = self.permille_q16.checked_div(1 << 16).unwrap_or(0);
        i32::try_from(whole).unwrap_or(if whole < 0 { i32::MIN } else { i32::MAX })
    }

    /// No torque is left: the stop is complete.
    #[must_use]
    pub const fn done(&self) -> bool {
        self.permille_q16 == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 0x6087 = 100,000 per mille/s (the default) is 40 per mille per tick: 1,000 per mille falls to 0 in 25 ticks
    /// (10 ms), linearly, and the stop ends with it.
    #[test]
    fn the_default_slope_takes_the_rated_torque_away_in_ten_milliseconds() {
        let mut r = TorqueRamp::new(1000, 100_000);
        let samples: Vec<i32> = (0..25).map(|_| r.step()).collect();
        assert_eq!(samples[0], 960);
        assert_eq!(samples[12], 480);
        assert_eq!(samples[24], 0);
        assert!(samples.windows(2).all(|w| w[0] - w[1] == 40));
        assert!(r.done());
        assert_eq!(r.step(), 0);
    }

    /// A negative torque rises to zero; a slope below one per mille per tick still ends exactly at zero.
    #[test]
    fn negative_torque_and_slow_slopes_end_exactly_at_zero() {
        let mut r = TorqueRamp::new(-3, 1_000); // 0.4 per mille per tick: 8 ticks.
        let samples: Vec<i32> = (0..8).map(|_| r.step()).collect();
        assert_eq!(samples, vec![-2, -2, -1, -1, -1, 0, 0, 0]);
        assert!(r.done());
        let mut r = TorqueRamp::new(0, 1);
        assert!(r.done());
        assert_eq!(r.step(), 0);
    }

    /// The largest slope (1.7 million per mille per tick) ends any torque the drive can demand in one tick, and
    /// the largest start in about 1,250 ticks; the smallest slope (0 counts as 1 per mille/s) still moves.
    #[test]
    fn extreme_slopes_end_at_zero_or_keep_moving() {
        let mut r = TorqueRamp::new(i32::from(i16::MAX), u32::MAX);
        assert_eq!(r.step(), 0);
        assert!(r.done());
        let mut r = TorqueRamp::new(i32::MAX, u32::MAX);
        let mut ticks = 0;
        while !r.done() && ticks < 2_000 {
            r.step();
            ticks += 1;
        }
        assert_eq!(ticks, 1_250);
        let mut r = TorqueRamp::new(i32::MIN, 0);
        let before = r.permille_q16;
        r.step();
        assert!(r.permille_q16 > before && r.permille_q16 < 0);
    }
}
