//! Velocity estimate from a low-pass filtered position difference (EPOS4's "low pass filter" estimation, S1
//! L564-575; control structure 0x3000:02 bits 7..4 = 1, S2 L3813-3850), and the first-order low-pass filter it
//! and the position controller's D part share.
//!
//! The estimate is count-based: the increments counted in one slow tick (S1 L650-652, "counting the number of
//! sensor edges per control cycle") pass a first-order low-pass `C(s) = 2 pi f / (s + 2 pi f)` (S1 L570-575) with
//! the cut-off f from 0x30A2:05 (Hz; all S1 examples use 395 Hz, L1222-1560). The filter is discretised with the
//! matched pole `a = exp(-2 pi f Ts)` (the step response equals the continuous one at the sample instants, for
//! every f up to the 1250 Hz Nyquist limit; the bilinear map would turn negative above 796 Hz):
//! `y <- y + (1 - a) (x - y)`. The coefficient is computed once ([`LowPass::from_cutoff_hz`]) with an
//! integer exponential, never per tick.
//!
//! Averaged positions (tier 1's 25 kHz samples): the difference of one position per slow tick carries up to one
//! count of quantisation per tick (36.6 rpm on the reference 4,096-count encoder), and at low speed its aliased
//! harmonics fall inside the velocity loop's bandwidth, so the loop drives the motor with them. Tier 1 sees the
//! encoder every 40 us; [`PositionSum`] adds its position every fast tick and latches the running sum (and the
//! position) at the fast tick that raises the slow tick, so a window is always the same ten samples whatever the
//! latency of tier 2. The difference of two consecutive window sums is ten times the displacement of the windows'
//! mean positions: the count edges crossed within a window interpolate the position, and the box average
//! attenuates the quantisation's fundamental at 100 rpm (6.8 kHz, 2.73 counts per window) about tenfold before
//! the 2.5 kHz sampling aliases it. [`LowPassVelocityEstimator::update_window`] uses it as the point difference
//! plus a correction of at most [`MAX_CORRECTION_COUNTS`] counts, so a window of another length (a missed slow
//! tick, a restart) degrades to the point difference instead of a spike. Measured on the reference plant with
//! bottom-clamped modulation, 100 rpm CSV step, seeds 1..8: tail speed ripple 0.36-0.38 rpm RMS and 1.1-1.3 rpm
//! peak against 0.83-0.88 and 2.2-2.4 with the point difference (`drive-tests`, `motion_cyclic::csv_small_step`).
//!
//! Counter wrap: positions are wrapping `i32` increments (the difference of two samples is exact while the axis
//! moves less than 2^31 increments per tick) and the raw encoder timer is a wrapping `u16` (exact below 2^15
//! increments per tick: 32768 x 2500 / 4096 x 60 = 1.2 M rpm on the reference encoder); [`CounterExtender`]
//! turns the timer into the `i32` position.

use super::position::Increments;
use super::velocity::{sat_i32, IncPerTick, SLOW_TICK_HZ, TWO_PI_Q32};
use crate::power::SLOW_TICK_DIVIDER;

/// Input clamp of the filters, `I16F16` bits: +-16384 inc/tick (2^30). The output stays within it (a convex
/// combination), so `x - y` fits 31 bits and `(x - y) * c` 62 bits.
const INPUT_LIMIT: i32 = 1 << 30;

/// `exp(-x)` in Q31 for `x` in Q32 (x clamped to [0, 16)). Range reduction by 2^8, a 7-term Taylor series in
/// Q62 and eight squarings; error below 2^-30 for x <= 4 (the filters need x <= pi). For conversions only.
///
/// Every value between the steps fits 64 bits (the bounds beside each step); only the products are 128 bits
/// wide, each of two 64-bit factors. The same steps in `u128` throughout gave the same results and took
/// 2.5 KB of flash at this crate's speed level (fully unrolled 128 by 128-bit products and divisions); this
/// form takes 1 KB (tests: `exp_neg_q31_equals_the_series_in_128_bits`).
#[must_use]
pub fn exp_neg_q31(x_q32: u64) -> u32 {
    const ONE: u64 = 1 << 62;
    // y = x / 256 in Q62: x_q32 * 2^30 / 2^8. x < 2^36 so y < 2^58 = 2^62 / 16.
    let y = x_q32.min((1 << 36) - 1) << 22;
    let mut term = ONE;
    let mut sum_pos = ONE;
    let mut sum_neg = 0u64;
    for k in 1..=7u64 {
        // term_k = term_{k-1} * y / k: term <= 2^62, y < 2^58: the product < 2^120, after the shift < 2^58.
        term = u64::try_from(mul_wide(term, y) >> 62).unwrap_or(u64::MAX).checked_div(k).unwrap_or(0);
        // The terms fall by 1/16 or more each: both sums stay below 2^62 + 2^59.
        if k & 1 == 1 {
            sum_neg = sum_neg.wrapping_add(term);
        } else {
            sum_pos = sum_pos.wrapping_add(term);
        }
    }
    // e^-y in (0.93, 1]: positive, at most 2^62. Squaring keeps it in (0, 1]: products <= 2^124, results <= 2^62.
    let mut r = sum_pos.saturating_sub(sum_neg);
    for _ in 0..8 {
        r = u64::try_from(mul_wide(r, r).wrapping_add(1 << 61) >> 62).unwrap_or(u64::MAX);
    }
    u32::try_from((r.wrapping_add(1 << 30)) >> 31).unwrap_or(u32::MAX)
}

/// The full 128-bit product of two 64-bit values (cannot overflow).
fn mul_wide(a: u64, b: u64) -> u128 {
    u128::from(a).wrapping_mul(u128::from(b))
}

/// A first-order low-pass filter `y <- y + c (x - y)`, `c = 1 - exp(-w Ts)` in `I1F31`, on `I16F16` samples, with
/// the rounding remainder carried to the next sample (first-order error feedback): the mean output equals the
/// mean input exactly, without the dead band a plain rounded update has at small c.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct LowPass {
    /// 1 - a in `I1F31` bits, 0..=2^31 - 1.
    c: i32,
    /// Output, `I16F16` bits, within +-2^30.
    y: i32,
    /// Carried remainder, 0..2^31 (units of 2^-47).
    rem: i64,
}

impl LowPass {
    /// A filter with cut-off `w` = `millirad_per_s` / 1000 rad/s at the slow tick (2500 Hz), output 0.
    #[must_use]
    pub fn from_cutoff_millirad_per_s(millirad_per_s: u32) -> Self {
        // x = w Ts in Q32 = mrad/s * 2^32 / (1000 * 2500); < 2^32 * 2^32 / 2.5e6 < 2^43 before the clamp.
        let x = (u64::from(millirad_per_s) << 32).checked_div(1000 * u64::from(SLOW_TICK_HZ)).unwrap_or(0);
        Self::from_exponent(x)
    }

    /// A filter with cut-off `hz` (0x30A2:05) at the slow tick, output 0.
    #[must_use]
    pub fn from_cutoff_hz(hz: u32) -> Self {
        // x = 2 pi f / f_s in Q32; f < 2^32, 2pi < 2^35: the product < 2^67 in u128.
        let x = (u128::from(hz).wrapping_mul(TWO_PI_Q32)).checked_div(u128::from(SLOW_TICK_HZ)).unwrap_or(0);
        Self::from_exponent(u64::try_from(x).unwrap_or(u64::MAX))
    }

    fn from_exponent(x_q32: u64) -> Self {
        let a = exp_neg_q31(x_q32);
        let c = (1u32 << 31).saturating_sub(a);
        Self { c: i32::try_from(c).unwrap_or(i32::MAX), y: 0, rem: 0 }
    }

    /// The coefficient c = 1 - exp(-w Ts) in `I1F31` bits.
    #[must_use]
    pub const fn coefficient(&self) -> i32 {
        self.c
    }

    /// The output, `I16F16` bits.
    #[must_use]
    pub const fn output(&self) -> i32 {
        self.y
    }

    /// Takes the coefficient of `other` (another cut-off), keeping this filter's output and remainder.
    pub fn retune(&mut self, other: &Self) {
        self.c = other.c;
    }

    /// Sets the output (and clears the remainder), clamped to the input range.
    pub fn preset(&mut self, y: i32) {
        self.y = y.clamp(-INPUT_LIMIT, INPUT_LIMIT);
        self.rem = 0;
    }

    /// One sample: input `x` (`I16F16` bits, clamped to +-2^30), returns the new output.
    #[inline(always)]
    pub fn step(&mut self, x: i32) -> i32 {
        let x = x.clamp(-INPUT_LIMIT, INPUT_LIMIT);
        // |x - y| <= 2^31, c < 2^31: |acc| < 2^62 + 2^31.
        let acc = i64::from(x).wrapping_sub(i64::from(self.y)).wrapping_mul(i64::from(self.c)).wrapping_add(self.rem);
        let dy = acc >> 31;
        self.rem = acc.wrapping_sub(dy << 31);
        // y + c (x - y) lies between y and x: within +-2^30.
        self.y = sat_i32(i64::from(self.y).wrapping_add(dy));
        self.y
    }
}

/// Extends a wrapping 16-bit encoder timer to a wrapping `i32` position (the timer of [`crate::power`]'s
/// `FeedbackSample::encoder_count`). Exact while the timer moves less than 2^15 counts between two calls.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct CounterExtender {
    last: u16,
    position: i32,
}

impl CounterExtender {
    /// Starts at `count` with the position `position`.
    #[must_use]
    pub const fn new(count: u16, position: Increments) -> Self {
        Self { last: count, position: position.0 }
    }

    /// Adds the signed difference since the last call (wrapping, on purpose: the `i32` position wraps like the
    /// CiA 402 position actual value 0x6064, INTEGER32).
    pub fn update(&mut self, count: u16) -> Increments {
        let delta = count.wrapping_sub(self.last) as i16;
        self.last = count;
        self.position = self.position.wrapping_add(i32::from(delta));
        Increments(self.position)
    }
}

/// Fast ticks per window of [`PositionSum`] (one slow tick), as `i32`.
const WINDOW_SAMPLES: i32 = SLOW_TICK_DIVIDER as i32;

/// 2^16 / [`WINDOW_SAMPLES`], rounded: the window sums' difference to counts per tick in `I16F16`.
const TENTH_Q16: i32 = 6554;

/// Largest difference, in counts per slow tick, between the window-averaged displacement and the point difference
/// that [`LowPassVelocityEstimator::update_window`] accepts. In steady motion the two differ by the quantisation,
/// under one count; the averaged displacement lags by 0.45 tick, so an acceleration of A counts per tick² adds
/// 0.45 A (the bench's CSP move, 1.3 M inc/s², is 0.21 counts per tick²).
pub const MAX_CORRECTION_COUNTS: i32 = 4;

/// One window of [`PositionSum`]: the running sum and the position, latched at the fast tick that raises a slow
/// tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct PositionWindow {
    /// The wrapping sum of every fast tick's position up to and including the latching one.
    pub sum: i32,
    /// The position at the latching fast tick.
    pub position: i32,
}

/// Tier 1's part of the averaged estimate (see the module documentation): adds the position every fast tick and
/// latches the sum at the slow tick's boundary. Wrapping on purpose: only differences of sums are used, exact while
/// the true difference of two window sums fits 31 bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct PositionSum {
    running: i32,
    latched: PositionWindow,
}

impl PositionSum {
    /// One fast tick with its `position`; `boundary` is the tick that raises the slow tick (its sample is the last
    /// of the window).
    #[inline(always)]
    pub fn add(&mut self, position: i32, boundary: bool) {
        self.running = self.running.wrapping_add(position);
        if boundary {
            self.latched = PositionWindow { sum: self.running, position };
        }
    }

    /// The window latched last.
    #[must_use]
    pub const fn latched(&self) -> PositionWindow {
        self.latched
    }
}

/// Velocity from the low-pass filtered difference of the position per slow tick (S1 L564-575). `update` compiles
/// to 53 Thumb-2 instructions for thumbv7em (release, no calls, no division).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct LowPassVelocityEstimator {
    filter: LowPass,
    last: Option<i32>,
    /// The last window of [`Self::update_window`] (valid when `windows` >= 1).
    last_window: PositionWindow,
    /// The last difference of two window sums (valid when `windows` >= 2).
    last_window_sum: i32,
    /// Windows seen since the last restart, up to 2.
    windows: u8,
}

impl LowPassVelocityEstimator {
    /// An estimator with the cut-off `hz` of 0x30A2:05 (1..=1250 Hz in `firmware/device.toml`; 0 gives a filter
    /// that never moves, values beyond Nyquist behave as 1250 Hz and above, down to c = 1 - exp(-2pi f/f_s)).
    #[must_use]
    pub fn new(cutoff_hz: u32) -> Self {
        Self {
            filter: LowPass::from_cutoff_hz(cutoff_hz),
            last: None,
            last_window: PositionWindow { sum: 0, position: 0 },
            last_window_sum: 0,
            windows: 0,
        }
    }

    /// Forgets the last position: the next sample sets the reference and gives the current estimate unchanged.
    pub fn reset(&mut self) {
        self.last = None;
        self.windows = 0;
        self.filter.preset(0);
    }

    /// The filter (coefficient and output).
    #[must_use]
    pub const fn filter(&self) -> &LowPass {
        &self.filter
    }

    /// One slow tick with the wrapping `i32` position; returns the filtered velocity. The first call after
    /// [`Self::new`] or [`Self::reset`] counts as no motion.
    pub fn update(&mut self, position: Increments) -> IncPerTick {
        let delta = match self.last {
            // Wrapping difference: exact while |true difference| < 2^31 increments per tick.
            Some(last) => position.0.wrapping_sub(last),
            None => 0,
        };
        self.last = Some(position.0);
        // Clamp to +-16384 inc/tick before the shift to I16F16 (2^14 << 16 = 2^30).
        let x = delta.clamp(-(1 << 14), 1 << 14) << 16;
        IncPerTick::from_bits(self.filter.step(x))
    }

    /// One slow tick with the window tier 1 latched ([`PositionSum`]); returns the filtered velocity. The input is
    /// the difference of the windows' positions plus the correction to the difference of their mean positions,
    /// clamped to [`MAX_CORRECTION_COUNTS`]. The first call after [`Self::new`] or [`Self::reset`] counts as no
    /// motion, the second uses the point difference alone. Switching between it and [`Self::update`] needs a
    /// [`Self::reset`] (the axis restarts its estimate when the position sensor changes).
    pub fn update_window(&mut self, window: PositionWindow) -> IncPerTick {
        // Wrapping differences: exact while the true values fit 31 bits.
        let point = window.position.wrapping_sub(self.last_window.position);
        let sum = window.sum.wrapping_sub(self.last_window.sum);
        // Both sums cover ten samples: their difference is ten times the mean positions' displacement.
        let correction = sum.wrapping_sub(self.last_window_sum).wrapping_sub(point.wrapping_mul(WINDOW_SAMPLES));
        let (point, correction) = match self.windows {
            0 => (0, 0),
            1 => (point, 0),
            _ => (point, correction),
        };
        let limit = MAX_CORRECTION_COUNTS.wrapping_mul(WINDOW_SAMPLES);
        // / 10 in I16F16: x 6554 (2^16 / 10 = 6553.6, 0.006 % high: under 0.0003 counts at the limit).
        // |correction| <= 400: the product fits easily.
        let correction = correction.clamp(limit.wrapping_neg(), limit).wrapping_mul(TENTH_Q16);
        self.last_window = window;
        self.last_window_sum = sum;
        self.windows = if self.windows == 0 { 1 } else { 2 };
        // Clamp to +-16384 inc/tick before the shift to I16F16 (2^14 << 16 = 2^30); the sum stays within 2^31.
        let x = (point.clamp(-(1 << 14), 1 << 14) << 16).wrapping_add(correction);
        IncPerTick::from_bits(self.filter.step(x))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The series of [`exp_neg_q31`] with every value in `u128`, as it was written before its values were shown
    /// to fit 64 bits.
    fn exp_neg_q31_in_128_bits(x_q32: u64) -> u32 {
        let y = u128::from(x_q32.min((1 << 36) - 1)) << 22;
        let (mut term, mut sum_pos, mut sum_neg) = (1u128 << 62, 1u128 << 62, 0u128);
        for k in 1..=7u128 {
            term = ((term * y) >> 62) / k;
            if k & 1 == 1 {
                sum_neg += term;
            } else {
                sum_pos += term;
            }
        }
        let mut r = sum_pos.saturating_sub(sum_neg);
        for _ in 0..8 {
            r = (r * r + (1 << 61)) >> 62;
        }
        u32::try_from((r + (1 << 30)) >> 31).unwrap_or(u32::MAX)
    }

    /// The 64-bit steps give the 128-bit series' result to the bit: every input below 2^20 (up to 0.00024, where
    /// the low bits matter most), the filters' cut-offs 0..=100,000 Hz and 0..=10,000,000 mrad/s as the
    /// conversions form them, a pseudo-random sweep over every magnitude up to 2^40, and the clamp's edges.
    #[test]
    fn exp_neg_q31_equals_the_series_in_128_bits() {
        let check = |x: u64| assert_eq!(exp_neg_q31(x), exp_neg_q31_in_128_bits(x), "x = {x:#x}");
        (0..1u64 << 20).for_each(check);
        for hz in 0..=100_000u32 {
            let x = (u128::from(hz) * TWO_PI_Q32) / u128::from(SLOW_TICK_HZ);
            check(u64::try_from(x).unwrap_or(u64::MAX));
        }
        for mrad in (0..=10_000_000u32).step_by(7) {
            check((u64::from(mrad) << 32) / (1000 * u64::from(SLOW_TICK_HZ)));
        }
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..1_000_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            check(s >> (24 + (s & 15)));
        }
        [(1 << 36) - 2, (1 << 36) - 1, 1 << 36, 1 << 40, u64::MAX].into_iter().for_each(check);
    }

    /// Runs `ticks` slow ticks of a constant `counts_per_fast_tick` (real, quantised by floor as an encoder
    /// counts) through both estimates with a 1250 Hz cut-off; returns the largest deviation of each from the true
    /// velocity, counts per slow tick, after the first 20 ticks.
    fn worst_errors(counts_per_fast_tick: f64, ticks: u32) -> (f64, f64) {
        let (mut point, mut window) = (LowPassVelocityEstimator::new(1250), LowPassVelocityEstimator::new(1250));
        let mut sum = PositionSum::default();
        let (mut worst_point, mut worst_window) = (0f64, 0f64);
        let truth = counts_per_fast_tick * 10.0;
        for k in 0..ticks * 10 {
            let position = (f64::from(k) * counts_per_fast_tick + 0.3).floor() as i32;
            sum.add(position, k % 10 == 9);
            if k % 10 == 9 {
                let p = point.update(Increments(position)).0.to_num::<f64>();
                let w = window.update_window(sum.latched()).0.to_num::<f64>();
                if k / 10 >= 20 {
                    worst_point = worst_point.max((p - truth).abs());
                    worst_window = worst_window.max((w - truth).abs());
                }
            }
        }
        (worst_point, worst_window)
    }

    /// At 100 rpm on 4,096 counts (0.273 counts per fast tick, 2.73 per slow tick), through the 1250 Hz filter
    /// (almost none of its smoothing), the window average's worst quantisation error is at most half the point
    /// difference's: the averaging itself removes it, not the filter.
    #[test]
    fn window_average_reduces_the_quantisation_error() {
        let (point, window) = worst_errors(0.273, 400);
        assert!(window <= 0.5 * point, "point {point}, window {window}");
    }

    /// A constant velocity is estimated without bias: the mean of the window estimate equals the true velocity.
    #[test]
    fn window_estimate_is_unbiased_and_starts_at_rest() {
        let mut e = LowPassVelocityEstimator::new(395);
        let mut sum = PositionSum::default();
        let mut total = 0f64;
        for k in 0..2000i32 {
            let position = k.wrapping_mul(3).wrapping_add(i32::MAX - 1000); // wraps on the way
            sum.add(position, k % 10 == 9);
            if k % 10 == 9 {
                let v = e.update_window(sum.latched()).0.to_num::<f64>();
                if k == 9 {
                    assert_eq!(v, 0.0, "the first window counts as no motion");
                }
                if k >= 1000 {
                    total += v;
                }
            }
        }
        let mean = total / 100.0;
        assert!((mean - 30.0).abs() < 1e-3, "mean {mean} counts per slow tick");
    }

    /// A window of another length (a missed slow tick) moves the estimate at most by the correction limit from the
    /// point difference, never by the size of the position.
    #[test]
    fn a_missed_window_is_bounded_by_the_correction_limit() {
        let mut e = LowPassVelocityEstimator::new(1250);
        let mut sum = PositionSum::default();
        let mut last = 0f64;
        for k in 0..400i32 {
            let position = 1_000_000i32.wrapping_add(k.wrapping_mul(2));
            // The slow tick at k = 199 is missed: the next window holds twenty samples.
            sum.add(position, k % 10 == 9);
            if k % 10 == 9 && k != 199 {
                last = e.update_window(sum.latched()).0.to_num::<f64>();
                if k == 209 {
                    // The point difference spans two ticks (40 counts): 40 + at most 4 counts of correction, and the
                    // 1250 Hz filter (c = 0.957) lags the jump from 20 by 4.3 % of it, under 1 count.
                    assert!((last - 40.0).abs() <= 5.0, "estimate {last}");
                }
            }
        }
        assert!((last - 20.0).abs() < 0.01, "recovers: {last}");
    }
}
