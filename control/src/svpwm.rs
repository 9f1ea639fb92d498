//! Space-vector modulation with bus-voltage compensation, a circular voltage-vector limit and a duty clamp that
//! keeps the low-side shunt sampling window open.
//!
//! # Modulation
//! Bottom-clamped discontinuous modulation (DPWMMIN): the three phase voltages of the (alpha, beta) command are
//! shifted by a common offset so that the lowest one sits at compare value 0, its low switch on for the whole
//! period. The zero sequence is free (the star point floats: line voltages, hence currents, do not depend on it), so
//! this has the same linear range as centred SVPWM, up to a line-to-neutral amplitude of Vbus/sqrt(3) where the duty
//! span max - min reaches 100 %, and the same line voltages.
//!
//! Why not centred (min-max) SVPWM: a clamped leg has no switching edge, hence no dead-time error, and the other two
//! legs switch with narrower high pulses. The dead-time error of a leg whose current is within its PWM ripple
//! depends on the sign of that current at its edges, and that sign changes when a current step enlarges the ripple;
//! the integrators hold the error of before the step, and the difference disturbs the other axis for the periods
//! the loop needs to see it. Measured on the reference plant (0.5 us dead time), q step 0 -> 2 A at standstill with
//! phase A nearly unloaded: the d-axis peak is 0.9-2.5 % of the step over seeds 1..8 bottom-clamped against
//! 2.8-4.0 % centred (`drive-tests`, `current_loop::q_current_step_d_axis_within_3_percent`). The bottom rail also
//! keeps the low-side shunts (and the bootstrap supplies of the high-side drivers) on longer: the sampling window
//! only grows. One leg at a time does not switch, a third less switching loss.
//! Bus compensation: duty = v / Vbus, computed with one reciprocal of the measured bus voltage per call.
//!
//! # The voltage-vector limit ([`VoltageLimit`])
//! The command is limited to a circle (angle preserved) of radius `f * Vbus / sqrt(3)`, i.e. a line-to-line peak of
//! `f * Vbus` (amplitude-invariant Clarke: line-to-line amplitude = sqrt(3) x phase amplitude). EPOS4: "U_max
//! corresponds to the product of DC link supply voltage and maximum PWM duty cycle (90% for EPOS4)" (S1 L929-930,
//! digest §1.3), hence [`VoltageLimit::EPOS4`] = 900 permille (derived: the seed's model is a DC motor; for three
//! phases we read U as the line-to-line voltage, the voltage a winding pair sees). [`VoltageLimit::LINEAR`] = 1000
//! permille is the whole linear range. Beyond the limit the vector is scaled onto the circle, preserving its angle,
//! and the output reports `saturated`.
//!
//! # The duty clamp ([`DutyClamp`])
//! The ADC samples the low-side shunts at the PWM centre, where all low switches are on (`hal::power`). A phase's
//! low side is on for (1 - duty) of the 40 us period, centred on that sample, so a maximum compare value keeps a
//! minimum window. Default: 2.4 us (target-qemu.md gives 0.6 to 2.5 us for settling + sampling; 2.4 us covers the
//! reference inverter's 0.5 us dead time, about 1 us of ringing and the F405's injected conversion), which is a
//! maximum compare value of 3158 of 3360 (94.0 %). With the lowest phase at 0 the largest compare value is the duty
//! span, so the clamp only clips phases when the span itself exceeds the maximum (then the top phase sits at the
//! clamp and the lowest is clipped at 0); the 90 % EPOS4 limit (span <= 90 %) passes undistorted. [`Modulator::new`] caps the voltage limit at the clamp for that reason.
//!
//! # Arithmetic (Cortex-M4, no floating point, no 64-bit division)
//! - Reciprocal: `kn = (sqrt(3) / f) / Vbus`, the gain from volts to limit units, by one 32-bit `SDIV` per call
//!   (one instruction, 2 to 12 cycles on Cortex-M4; cheaper than a Newton step and exact every tick). The bus is
//!   quantised to 1/512 V (made odd, so never 0: at most +1/512 V), 1/7 of one ADC step of the reference bus sensing
//!   (12 bits over 60 V = 14.6 mV), so the quotient (Q20, precision better than 1e-4 above 10 V) carries the
//!   sensor's precision. The gain saturates at 0.5 limit per volt, i.e. the modulator treats a bus below
//!   2 sqrt(3)/f (3.85 V at f = 0.9) as that value; the drive is in undervoltage there. Per call rather than at
//!   2.5 kHz: with no braking chopper a 10 A regenerative current into the reference 470 uF raises the bus by
//!   21 V/ms, 8.5 V in one 0.4 ms slow period.
//! - Limit: each axis saturates at +-256 V (angle kept below that; the limit holds for any input). The vector is
//!   normalised (limit radius = 1, Q17), rotated (inverse Park in the current loop), and its |n|^2 taken in U16.16;
//!   above 1, the scale 1/|n| comes from a normalisation by `CLZ` to [0.25, 1), a linear first guess per octave and
//!   one Newton step (no division). The Newton step approaches from below, so the limited vector lies between
//!   99.92 % and 100 % of the limit radius (scale error <= 8.1e-4, plus the sin/cos gain error of 4e-5).
//! - Compare values: 32x32->64 products whose high word is the result (free shift), then min/max and one offset;
//!   at most 2.2 ticks of error per line voltage (0.07 % of the bus; test `svpwm_line_error_sweep`).

use fixed::types::I16F16;

use super::frames::{Abc, AlphaBeta, Volts};
use super::transforms::{mul_hi, mul_hi_round};
use crate::power::{PWM_FREQUENCY_HZ, PWM_PERIOD_TICKS};

/// sqrt(3) in Q32 (round(sqrt(3) * 2^32)).
const SQRT3_Q32: u64 = 7_439_101_574;
/// Input saturation of the limit: +-256 V in `I16F16` bits (2^24).
const VOLTS_LIMIT_BITS: i32 = 1 << 24;
/// 1.0 in U16.16 (the |n|^2 threshold).
const ONE_Q16: u32 = 1 << 16;
/// The PWM period in nanoseconds (40,000 at 25 kHz).
const PERIOD_NS: u32 = 1_000_000_000 / PWM_FREQUENCY_HZ;

/// `n / d` in a `const fn`, 0 for `d == 0` (never the case at the call sites).
const fn const_div(n: u64, d: u64) -> u64 {
    match n.checked_div(d) {
        Some(q) => q,
        None => 0,
    }
}

/// Maximum compare value that keeps a minimum low-side on-time around the PWM centre for the shunt samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DutyClamp {
    max_compare: u16,
}

impl DutyClamp {
    /// Default minimum low-side on-time: 2.4 us (see the module documentation).
    pub const DEFAULT_MIN_LOW_SIDE_NS: u32 = 2_400;
    /// The default clamp: compare <= 3158 of 3360 (94.0 %), low side on for >= 2.4 us.
    pub const DEFAULT: Self = Self::from_min_low_side_ns(Self::DEFAULT_MIN_LOW_SIDE_NS);
    /// No clamp (compare up to `PWM_PERIOD_TICKS`): for tests of the modulation alone, or high-side current sensing.
    pub const NONE: Self = Self { max_compare: PWM_PERIOD_TICKS };

    /// The clamp that keeps the low side on for at least `ns` nanoseconds per period, centred on the sample:
    /// `max_compare = PWM_PERIOD_TICKS - ceil(ns * PWM_PERIOD_TICKS / 40,000 ns)`, never below half the period.
    #[must_use]
    pub const fn from_min_low_side_ns(ns: u32) -> Self {
        let period = PWM_PERIOD_TICKS as u32;
        // ns * period < 2^32 * 2^12: no overflow in u64.
        let low_ticks = (ns as u64).wrapping_mul(period as u64).div_ceil(PERIOD_NS as u64);
        let half = period / 2;
        let low_ticks = if low_ticks > half as u64 { half } else { low_ticks as u32 };
        // low_ticks <= period / 2: no wrap.
        Self { max_compare: period.wrapping_sub(low_ticks) as u16 }
    }

    /// The largest compare value the modulator writes.
    #[must_use]
    pub const fn max_compare(self) -> u16 {
        self.max_compare
    }
}

impl Default for DutyClamp {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A circular voltage-vector limit: line-to-line peak <= `permille` / 1000 of the bus (see the module docs), with
/// the constants the modulator needs precomputed (once, not per tick).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VoltageLimit {
    permille: u16,
    /// `round(sqrt(3) / f * 2^29)` (< 2^31); divided by the bus in 1/512 V it gives the gain volts -> limit units,
    /// Q20.
    kn_dividend: i32,
    /// Limit radius in compare ticks, `f * T / sqrt(3)`, Q18 (alpha -> phase A).
    radius_q18: i32,
    /// `f * T / 2` = radius x sqrt(3)/2, Q18 (beta -> phases B and C).
    beta_q18: i32,
}

impl VoltageLimit {
    /// EPOS4: maximum PWM duty 90 %, U_max = 0.9 V_DC (S1 L929-930).
    pub const EPOS4: Self = Self::from_permille_of_bus(900);
    /// The whole linear range of SVPWM: line-to-neutral amplitude Vbus/sqrt(3).
    pub const LINEAR: Self = Self::from_permille_of_bus(1000);

    /// Line-to-line peak limited to `permille` / 1000 of the bus, saturated to [500, 1000].
    #[must_use]
    pub const fn from_permille_of_bus(permille: u16) -> Self {
        let p = if permille < 500 {
            500
        } else if permille > 1000 {
            1000
        } else {
            permille
        } as u64;
        let t = PWM_PERIOD_TICKS as u64;
        // sqrt(3)/f * 2^29 = SQRT3_Q32 * 1000 / (8 p): <= 1.86e9 < 2^31 for p >= 500.
        let kn_dividend = const_div(SQRT3_Q32.wrapping_mul(1000).wrapping_add(p.wrapping_mul(4)), p.wrapping_mul(8));
        // f * T / sqrt(3) in Q18 = p * (T * 2^50 / SQRT3_Q32) / 1000; T * 2^50 < 2^62.
        let radius = p.wrapping_mul((t << 50) / SQRT3_Q32).wrapping_add(500) / 1000;
        let beta = p.wrapping_mul(t << 18).wrapping_add(1000) / 2000;
        Self { permille: p as u16, kn_dividend: kn_dividend as i32, radius_q18: radius as i32, beta_q18: beta as i32 }
    }

    /// The limit as permille of the bus (line-to-line peak).
    #[must_use]
    pub const fn permille_of_bus(self) -> u16 {
        self.permille
    }

    /// The limit radius (line-to-neutral amplitude) at a bus voltage: `f * Vbus / sqrt(3)` (the exact value, without
    /// the modulator's bus quantisation). Not for the 25 kHz path.
    #[must_use]
    pub fn radius(self, v_bus: Volts) -> Volts {
        // f / sqrt(3) = permille / (1000 sqrt(3)) in Q32 (about 2.2e9 for 900 permille): u128 once, off the hot path.
        let k = (u128::from(self.permille) << 64).checked_div(1000 * u128::from(SQRT3_Q32)).unwrap_or(0);
        let k = i64::try_from(k).unwrap_or(0);
        // I16F16 x Q32 -> Q48 in i64 (< 2^63); >> 32 -> I16F16.
        let v = i64::from(v_bus.to_bits().max(0)).wrapping_mul(k) >> 32;
        Volts::from_bits(i32::try_from(v).unwrap_or(i32::MAX))
    }
}

/// The gain from volts to limit units (limit radius = 1.0), `kn` in Q20 (< 2^19, at most 0.5 limit per volt),
/// times 2^12 (< 2^31), for one bus voltage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BusGain(i32);

/// A vector after the circular limit, `I16F16` bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Limited {
    /// The limited vector in volts.
    pub volts: (i32, i32),
    /// The limited vector in limit units, Q14 (radius 1.0 = 16384), after the rotation.
    pub normalised: (i32, i32),
    /// The limit was active.
    pub saturated: bool,
}

/// First guesses `y0 = a - b m'` for 1/sqrt(m'), Q30 `[a, b]`, indexed by the parity of the leading-zero count:
/// even, m' in [0.5, 1): a = 1.785, b = 0.805 (chosen to minimise the error after one Newton step, 8.05e-4);
/// odd, m' in [0.25, 0.5): the same line for 2m', times sqrt(2): a = 1.785 sqrt(2), b = 2 x 0.805 sqrt(2).
static FIRST_GUESS_Q30: [[u32; 2]; 2] = [[1_916_629_156, 864_362_168], [2_710_522_946, 2_444_785_402]];

/// 1/sqrt(x) for x in [1, 2^15] given as U16.16 bits, as Q31 bits, always below 2^31 (tested). CLZ normalisation
/// to m' in [0.25, 1) (U0.32), a linear first guess per octave, one Newton step. Relative error <= 8.1e-4, always
/// low (Newton's step for 1/sqrt lands below the root from any start). Any other nonzero x gives a meaningless
/// value without panicking (the caller discards it: computing it unconditionally keeps the step branch-free).
#[inline(always)]
fn inv_sqrt_q16(x: u32) -> i32 {
    // x != 0: lz <= 31. For x >= 2^16 (the meaningful domain), lz <= 15 and the final shift is 0..=7.
    let lz = x.leading_zeros();
    let even = lz & !1;
    // m in [2^30, 2^32): m' = m / 2^32 in [0.5, 1) for an even lz, [0.25, 0.5) for an odd one.
    let m = x.wrapping_shl(even);
    // The index is 0 or 1: the fallback compiles away.
    let [a, b] = FIRST_GUESS_Q30.get((lz & 1) as usize).copied().unwrap_or([0, 0]);
    let hi = |p: u32, q: u32| (u64::from(p).wrapping_mul(u64::from(q)) >> 32) as u32;
    // y0 = a - b m', Q30 in (0.98, 1.96): b m' < a in both octaves, so no wrap.
    let y0 = a.wrapping_sub(hi(b, m));
    // Newton for 1/sqrt: y1 = y0 (3 - m' y0^2) / 2. y0^2 in Q28 (< 3.9); m' y0^2 in Q28, within (0.95, 1.05);
    // (3 - m' y0^2) / 2 in Q31, within (0.97, 1.03); y1 in Q29, in (1, 2).
    let y0_sq = hi(y0, y0);
    let t = hi(m, y0_sq);
    let w = (3u32 << 28).wrapping_sub(t) << 2;
    let y1 = hi(y0, w);
    // 1/sqrt(x) = 1/sqrt(m') 2^(even/2 - 8), returned in Q31 (the form the caller scales with): Q29 >> 6 leaves
    // 23 significant bits (relative precision 2^-22), and the left shift by even/2 <= 7 stays below 2^31 because
    // the root is below 1. (Shifting right by 6 - even/2 instead would need a negative shift for even/2 = 7.)
    ((y1 >> 6) as i32).wrapping_shl(lz >> 1)
}

/// The Modulator: voltage limit, bus compensation, SVPWM and the duty clamp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Modulator {
    limit: VoltageLimit,
    clamp: DutyClamp,
}

/// Compare values for one period and whether the command was limited.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Modulated {
    /// Compare values of phases A, B, C in timer ticks, 0..=`PWM_PERIOD_TICKS` (high-side on-time).
    pub compare_ticks: Abc<u16>,
    /// The command was outside the voltage limit (scaled onto it) or the duty span exceeded the clamp (clipped).
    pub saturated: bool,
}

impl Modulator {
    /// A modulator. The limit is capped so that its duty span (= permille) fits under the clamp, so that the clamp
    /// never clips a limited command.
    #[must_use]
    pub const fn new(limit: VoltageLimit, clamp: DutyClamp) -> Self {
        let span_permille = const_div((clamp.max_compare as u64).wrapping_mul(1000), PWM_PERIOD_TICKS as u64) as u16;
        let limit =
            if limit.permille > span_permille { VoltageLimit::from_permille_of_bus(span_permille) } else { limit };
        Self { limit, clamp }
    }

    /// The effective voltage limit (after the cap of [`Self::new`]).
    #[must_use]
    pub const fn limit(&self) -> VoltageLimit {
        self.limit
    }

    /// The duty clamp.
    #[must_use]
    pub const fn clamp(&self) -> DutyClamp {
        self.clamp
    }

    /// Volts -> limit units gain for this bus voltage: the one division of the tick (`SDIV`, see the module docs).
    #[inline(always)]
    pub(crate) fn bus_gain(&self, v_bus: Volts) -> BusGain {
        // Bus in 1/512 V, saturated to [0, 128 V) (one USAT), made odd so that it is never 0 (the fallback compiles
        // away): that moves it by at most 1/512 V, 1/7 of an ADC step. The dividend is below 2^31, so is the
        // quotient; it saturates at 2^19 - 1 (half a limit per volt), i.e. below 2 sqrt(3)/f V (3.85 V for f = 0.9)
        // the modulator acts as if the bus were there: the drive is in undervoltage anyway. The clamp is symmetric
        // (one SSAT) although the quotient is never negative: a [0, ..] clamp lets LLVM prove the sign, after which
        // it multiplies with UMULL + MLA instead of one SMULL. Times 2^12 (< 2^31) for the SMMUL of `limit_vector`.
        let q9 = (v_bus.to_bits() >> 7).clamp(0, 65_535) | 1;
        let kn = self.limit.kn_dividend.checked_div(q9).unwrap_or(0);
        BusGain(kn.clamp(-(1 << 19), (1 << 19) - 1) << 12)
    }

    /// Limits a vector (volts, `I16F16` bits, any value) to the circle of the voltage limit and rotates it by
    /// `rotate`.
    ///
    /// `rotate` maps the normalised vector in Q17 limit units to Q15 (the inverse Park rotation taking the high word
    /// of its Q30 products, or a plain `>> 2`; a rotation, so that the magnitude is kept). Rotation and scaling
    /// commute; rotating the unscaled vector first keeps every product of the chain a single SMULL, SMLAL, SMMUL or
    /// SMMULR on Cortex-M4.
    #[inline(always)]
    pub(crate) fn limit_vector(
        &self,
        x: i32,
        y: i32,
        gain: BusGain,
        rotate: impl Fn(i32, i32) -> (i32, i32),
    ) -> Limited {
        // +-256 V per axis (SSAT), four times the largest limit radius (0.9 x 128 V / sqrt(3) = 66.5 V). With the
        // gain below 0.5 limit per volt this keeps |n| below 128 limits, so |n|^2 fits 32 bits with no further
        // clamp, and the volts and the normalised vector stay consistent. Beyond 256 V on an axis (PI gains far
        // outside any real motor's) the direction is distorted, the limit still holds.
        let x = x.clamp(-VOLTS_LIMIT_BITS, VOLTS_LIMIT_BITS - 1);
        let y = y.clamp(-VOLTS_LIMIT_BITS, VOLTS_LIMIT_BITS - 1);
        // Twice the volts (no wrap): the form both the normalisation and the final scaling use.
        let (x2, y2) = (x << 1, y << 1);
        // (2 x) (kn 2^12) = x kn 2^13, Q16 x Q20 -> Q49: the high word is x kn in Q17 limit units (SMMUL), below
        // 2^24 (128 limits) in magnitude.
        let nx = mul_hi(x2, gain.0);
        let ny = mul_hi(y2, gain.0);
        // Rotate first and take the magnitude of the rotated vector (the same, to the rotation's gain error of 4e-5):
        // the data dependency makes the sin/cos registers free before the square root, which saves stack spills.
        let (rx, ry) = rotate(nx, ny);
        // |r|^2 in U16.16: r is Q15 with |r| <= 1.0001 sqrt(2) 2^22, so the sum of squares (Q30) is below
        // 2^45 x 1.0001, shifted by 14 below 2^32.
        let sq = i64::from(rx).wrapping_mul(i64::from(rx)).wrapping_add(i64::from(ry).wrapping_mul(i64::from(ry)));
        let sq = (sq >> 14) as u32;
        let saturated = sq > ONE_Q16;
        // Branch-free on purpose: the root is computed every time and selected, so the whole step is one basic block
        // (with a branch here LLVM lost track of the operand ranges and widened later products to 64x64 multiplies).
        // Scale in Q31; "1.0" is 2^31 - 1, made exact for the volts by the rounding below. (`| 1` only keeps the
        // input of the unused root nonzero.)
        let root = inv_sqrt_q16(sq | 1);
        let scale = if saturated { root } else { i32::MAX };
        // Volts: (2 v) x scale rounded (SMMULR); with scale = 2^31 - 1 the result is v exactly (v - v/2^31 + 1/2
        // rounds down to v, |v| <= 2^24). With scale <= 1 the magnitude never grows.
        // Limit units: Q15 x Q31 / 2^32 = Q14 (the scale's 2^31 is the halving).
        Limited {
            volts: (mul_hi_round(x2, scale), mul_hi_round(y2, scale)),
            normalised: (mul_hi_round(rx, scale), mul_hi_round(ry, scale)),
            saturated,
        }
    }

    /// Compare values from an (alpha, beta) vector in limit units (Q14, |n| <= 1.0001): inverse Clarke in
    /// ticks, the bottom clamp (lowest phase at 0), the duty clamp. Returns the ticks and whether a phase was clipped.
    #[inline(always)]
    pub(crate) fn compare_ticks(&self, n_alpha: i32, n_beta: i32) -> (Abc<u16>, bool) {
        // Q14 x Q18 = Q32: the rounded high word of each product is in whole ticks (SMMULR, error <= 1/2 tick each;
        // with the halving of va and the normalisation, <= 2.2 ticks per line voltage measured). |v| <= ~1940 ticks.
        let va = mul_hi_round(n_alpha, self.limit.radius_q18);
        let half = va >> 1;
        let beta = mul_hi_round(n_beta, self.limit.beta_q18);
        let vb = beta.wrapping_sub(half);
        let vc = beta.wrapping_add(half).wrapping_neg();
        let max = va.max(vb).max(vc);
        let min = va.min(vb).min(vc);
        let top = i32::from(self.clamp.max_compare);
        // Bottom clamp (DPWMMIN, see the module docs): the lowest phase at compare 0, its low switch on all period.
        // Only when the span exceeds the clamp does the top phase decide (it sits at the clamp, the lowest phase is
        // clipped at 0). Small values: no wrap.
        let offset = min.wrapping_neg().min(top.wrapping_sub(max));
        // <= top by construction; below 0 only when the span exceeds the clamp (clip).
        let duty = |v: i32| v.wrapping_add(offset).max(0) as u16;
        let clipped = max.wrapping_sub(min) > top;
        (Abc { a: duty(va), b: duty(vb), c: duty(vc) }, clipped)
    }

    /// Modulates a stator-frame voltage command at the measured bus voltage: circular limit (angle preserved),
    /// bus compensation, SVPWM, duty clamp. Never panics; any input gives compare values in 0..=max compare.
    #[must_use]
    pub fn modulate(&self, v: AlphaBeta<Volts>, v_bus: Volts) -> Modulated {
        let gain = self.bus_gain(v_bus);
        let lim = self.limit_vector(v.alpha.to_bits(), v.beta.to_bits(), gain, |x, y| (x >> 2, y >> 2));
        let (compare_ticks, clipped) = self.compare_ticks(lim.normalised.0, lim.normalised.1);
        Modulated { compare_ticks, saturated: lim.saturated || clipped }
    }

    /// The voltage actually applied for a command (after the limit), in volts: for telemetry and tests.
    #[must_use]
    pub fn limited(&self, v: AlphaBeta<Volts>, v_bus: Volts) -> AlphaBeta<Volts> {
        let lim = self.limit_vector(v.alpha.to_bits(), v.beta.to_bits(), self.bus_gain(v_bus), |x, y| (x >> 2, y >> 2));
        AlphaBeta { alpha: Volts(I16F16::from_bits(lim.volts.0)), beta: Volts(I16F16::from_bits(lim.volts.1)) }
    }
}

impl Default for Modulator {
    /// EPOS4's 90 % limit with the default duty clamp.
    fn default() -> Self {
        Self::new(VoltageLimit::EPOS4, DutyClamp::DEFAULT)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constants() {
        assert_eq!(DutyClamp::DEFAULT.max_compare(), 3158);
        assert_eq!(DutyClamp::from_min_low_side_ns(0).max_compare(), 3360);
        assert_eq!(DutyClamp::from_min_low_side_ns(u32::MAX).max_compare(), 1680);
        let l = VoltageLimit::EPOS4;
        let f = 0.9;
        let close = |got: i64, want: f64| (got as f64 - want).abs() <= 1.0;
        assert!(close(l.kn_dividend.into(), 3f64.sqrt() / f * 2f64.powi(29)));
        assert!(close(l.radius_q18.into(), f * 3360.0 / 3f64.sqrt() * 2f64.powi(18)));
        assert!(close(l.beta_q18.into(), f * 3360.0 / 2.0 * 2f64.powi(18)));
        assert_eq!(Modulator::default().limit().permille_of_bus(), 900);
        assert_eq!(Modulator::new(VoltageLimit::LINEAR, DutyClamp::DEFAULT).limit().permille_of_bus(), 939);
    }

    /// The lowest phase sits at compare 0 whatever the command's angle (no edge, no dead-time error on that leg),
    /// a zero command switches no leg, and the top phase stays under the duty clamp.
    #[test]
    fn lowest_phase_is_clamped_to_the_bottom_rail() {
        let m = Modulator::default();
        let volts = |x: f64| Volts(I16F16::from_num(x));
        let bus = volts(24.0);
        let zero = m.modulate(AlphaBeta::new(Volts::ZERO, Volts::ZERO), bus);
        assert_eq!(zero.compare_ticks, Abc { a: 0, b: 0, c: 0 });
        assert!(!zero.saturated);
        for k in 0..24 {
            let (s, c) = (f64::from(k) * core::f64::consts::TAU / 24.0).sin_cos();
            let v = AlphaBeta::new(volts(10.0 * c), volts(10.0 * s));
            let t = m.modulate(v, bus).compare_ticks;
            let (lo, hi) = (t.a.min(t.b).min(t.c), t.a.max(t.b).max(t.c));
            assert_eq!(lo, 0, "{k}: {t:?}");
            // 10 V amplitude at 24 V: a span of 1.5 to sqrt(3) x 10 V, 2100 to 2425 ticks.
            assert!((2090..=2435).contains(&hi), "{k}: {t:?}");
        }
    }

    #[test]
    fn inv_sqrt_bound_over_the_whole_domain() {
        let mut worst = 0f64;
        let mut x = ONE_Q16;
        while x <= 1 << 31 {
            let root = inv_sqrt_q16(x);
            assert!(root > 0, "x={x} root={root}");
            let got = f64::from(root) / f64::from(1u32 << 31);
            let want = 1.0 / (f64::from(x) / 65536.0).sqrt();
            let rel = got / want - 1.0;
            assert!(rel <= 1e-8, "x={x} rel={rel}");
            worst = worst.max(-rel);
            if x == 1 << 31 {
                break;
            }
            x = x.saturating_add(x / 4099 + 1).min(1 << 31);
        }
        assert!(worst <= 8.1e-4, "worst {worst}");
        assert!(worst >= 7e-4, "the sweep should reach the worst case, {worst}");
    }
}
