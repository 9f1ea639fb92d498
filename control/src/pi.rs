//! PI current controller with back-calculation anti-windup, gains in the units of IDX object 0x30A0.
//!
//! Control law (EPOS4: digital PI with back-calculation anti-windup, Ts = 0.04 ms, S1 L440-482; discretisation of
//! `shared/spec/control-and-protection.md` §1.10 with a backward-Euler integrator), evaluated once per 25 kHz tick:
//!
//! ```text
//! e      = clamp(i_ref - i, +-64 A)
//! xi_e   = xi + Ki*Ts * e                   (the integral including this sample)
//! u      = Kp * e + xi_e                    (unlimited output)
//! u_sat  = limit(u)                         (by the caller: the d/q voltage-vector limit)
//! xi    <- clamp(xi_e + Kb * (u_sat - u), +-4096 V)
//! ```
//!
//! Gains (`PiGains`, converted once from the dictionary, never per tick):
//! - 0x30A0:01 "Current controller P gain", UNSIGNED32, "given in [uV/A]" (S2 L4419-4421): Kp [V/A] = raw * 1e-6.
//! - 0x30A0:02 "Current controller I gain", UNSIGNED32, "given in [uV/(A*ms)]" (S2 L4433-4435):
//!   Ki [V/(A*s)] = raw * 1e-3, and per sample Ki*Ts [V/A] = raw * 1e-3 / 25,000 = raw * 4e-8.
//!   (EPOS4's display units are mV/A and mV/(A*ms), 1000 times smaller: S1 L463-466 and the digest's §1.3.)
//! - Kb, the back-calculation gain per sample, = Ts / Tt with the tracking time Tt = Ti = Kp / Ki by default, so
//!   `Kb = (Ki*Ts) / Kp`, in [0, 1) (`I1F31`). With this choice a saturated integrator settles where the output
//!   sits exactly on the limit (steady state of the update: `Ki*Ts*e = Kb*(u - u_sat)` gives `u - u_sat = Kp*e`,
//!   so `xi_e = u_sat`): it does not wind up.
//!
//! Formats: gains `I8F24` in [0, 64) (64 V/A is 0x30A0:01 = 64,000,000 uV/A, 30 times what the reference motor
//! needs for a 2 kHz current bandwidth; larger dictionary values saturate), error/current/voltage `I16F16`. Range
//! proof for the wrapping arithmetic: |e| <= 64 A and gains < 64 bound |Kp e| and |Ki Ts e| by 4096 V; |xi| <= 4096 V
//! bounds |xi_e| by 8192 V and |u| by 12288 V; the limit keeps `u_sat` on the same side of zero as `u` and no larger,
//! so |u_sat - u| <= |u| and, with Kb < 1, the sum before the integrator clamp stays within 8192 + 12288 = 20480 V
//! < 32768 V.

use fixed::types::{I16F16, I1F31, I8F24};

use super::frames::{Amps, Volts};
use super::transforms::mul_hi;
use crate::power::PWM_FREQUENCY_HZ;

/// Error clamp, `I16F16` bits: +-64 A (2^22), four times the reference shunt range.
const ERROR_LIMIT_BITS: i32 = 1 << 22;
/// Integrator clamp, `I16F16` bits: [-4096 V, 4096 V) (2^28, one SSAT), 68 times the largest bus (60 V).
const INTEGRAL_LIMIT_BITS: i32 = 1 << 28;
/// The largest gain, `I8F24` bits: 64 V/A - 2^-24 (2^30 - 1).
const GAIN_LIMIT_BITS: i32 = (1 << 30) - 1;

/// PI gains in the internal per-sample form (`I8F24`). Construct with [`PiGains::from_idx_0x30a0`] or
/// [`PiGains::new`]; both clamp to the ranges the controller's overflow proof needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PiGains {
    kp: I8F24,
    ki_ts: I8F24,
    kb: I1F31,
}

impl PiGains {
    /// All gains zero: output 0 V whatever the error.
    pub const ZERO: Self = Self { kp: I8F24::ZERO, ki_ts: I8F24::ZERO, kb: I1F31::ZERO };

    /// Gains from the raw values of IDX 0x30A0 (S2 L4410-4445): `p_gain` = 0x30A0:01 in uV/A, `i_gain` = 0x30A0:02
    /// in uV/(A*ms); sample time Ts = 1 / `PWM_FREQUENCY_HZ` = 40 us (EPOS4 current loop, S1 L451). Kb defaults to
    /// Ts/Ti (see the module documentation). Call once when the dictionary changes, never per tick (it divides).
    #[must_use]
    pub fn from_idx_0x30a0(p_gain_uv_per_a: u32, i_gain_uv_per_a_ms: u32) -> Self {
        // Kp [Q24] = raw * 1e-6 * 2^24, rounded to nearest. raw * 2^24 < 2^56: no overflow in u64.
        let kp = div_round(u64::from(p_gain_uv_per_a) << 24, 1_000_000);
        // Ki*Ts [Q24] = raw * 1e-6 [V/(A*ms)] * 1e3 [ms/s] / f_pwm [1/s] * 2^24 = raw * 2^24 / (1000 * f_pwm).
        let ki_ts = div_round(u64::from(i_gain_uv_per_a_ms) << 24, 1000 * u64::from(PWM_FREQUENCY_HZ));
        let kp = I8F24::from_bits(saturate_gain(kp));
        let ki_ts = I8F24::from_bits(saturate_gain(ki_ts));
        Self::new(kp, ki_ts, Self::default_tracking_gain(kp, ki_ts))
    }

    /// Gains in the internal form: `kp` in V/A, `ki_ts` = Ki*Ts in V/A per sample, `kb` = Ts/Tt per sample
    /// (`I1F31`: at most 1 - 2^-31; a gain above 1 would overshoot the limit every sample). Negative values become
    /// 0; `kp` and `ki_ts` saturate just under 64 V/A.
    #[must_use]
    pub fn new(kp: I8F24, ki_ts: I8F24, kb: I1F31) -> Self {
        let limit = I8F24::from_bits(GAIN_LIMIT_BITS);
        Self { kp: kp.clamp(I8F24::ZERO, limit), ki_ts: ki_ts.clamp(I8F24::ZERO, limit), kb: kb.max(I1F31::ZERO) }
    }

    /// The same gains with another back-calculation gain Kb = Ts/Tt (negative values become 0).
    #[must_use]
    pub fn with_tracking_gain(self, kb: I1F31) -> Self {
        Self::new(self.kp, self.ki_ts, kb)
    }

    /// Kb = Ts / Ti = (Ki*Ts) / Kp, in [0, 1); the largest value (1 - 2^-31, tracking in one sample) when Kp is 0
    /// (pure integral control) or Ki*Ts >= Kp.
    #[must_use]
    pub fn default_tracking_gain(kp: I8F24, ki_ts: I8F24) -> I1F31 {
        let kp_bits = u64::try_from(kp.to_bits()).unwrap_or(0);
        let ki_bits = u64::try_from(ki_ts.to_bits()).unwrap_or(0);
        // ki_bits < 2^30: the shifted value < 2^61.
        let kb = if kp_bits == 0 { u64::MAX } else { div_round(ki_bits << 31, kp_bits) };
        I1F31::from_bits(i32::try_from(kb).unwrap_or(i32::MAX))
    }

    /// Proportional gain Kp in V/A.
    #[must_use]
    pub const fn kp(&self) -> I8F24 {
        self.kp
    }

    /// Integral gain per sample Ki*Ts in V/A.
    #[must_use]
    pub const fn ki_ts(&self) -> I8F24 {
        self.ki_ts
    }

    /// Back-calculation gain per sample Ts/Tt (dimensionless).
    #[must_use]
    pub const fn kb(&self) -> I1F31 {
        self.kb
    }
}

/// `n / d` rounded half up; `d > 0` at every call site (a zero divisor gives 0, never a panic).
fn div_round(n: u64, d: u64) -> u64 {
    n.saturating_add(d / 2).checked_div(d).unwrap_or(0)
}

/// A gain in Q24 bits saturated to just under 64 V/A.
fn saturate_gain(bits: u64) -> i32 {
    i32::try_from(bits.min(GAIN_LIMIT_BITS as u64)).unwrap_or(GAIN_LIMIT_BITS)
}

/// Output of [`PiController::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PiOutput {
    /// The limited output voltage.
    pub voltage: Volts,
    /// The limit was active this sample.
    pub saturated: bool,
}

/// One PI controller: gains and the integrator state (volts).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PiController {
    gains: PiGains,
    integral: I16F16,
}

impl PiController {
    /// A controller with an empty integrator.
    #[must_use]
    pub const fn new(gains: PiGains) -> Self {
        Self { gains, integral: I16F16::ZERO }
    }

    /// The gains.
    #[must_use]
    pub const fn gains(&self) -> PiGains {
        self.gains
    }

    /// Replaces the gains, keeping the integrator (a gain change from the dictionary is bumpless in `xi`).
    pub fn set_gains(&mut self, gains: PiGains) {
        self.gains = gains;
    }

    /// The integrator state xi.
    #[must_use]
    pub const fn integral(&self) -> Volts {
        Volts(self.integral)
    }

    /// Presets the integrator (bumpless start), saturated to +-4096 V.
    pub fn set_integral(&mut self, xi: Volts) {
        self.integral = I16F16::from_bits(xi.to_bits().clamp(-INTEGRAL_LIMIT_BITS, INTEGRAL_LIMIT_BITS - 1));
    }

    /// Empties the integrator.
    pub fn reset(&mut self) {
        self.integral = I16F16::ZERO;
    }

    /// The clamped control error `clamp(reference - measured, +-64 A)` in `I16F16` bits, times 2^8 (QSUB, SSAT,
    /// LSL): in that form each gain product below is the high word of one 32x32->64 multiply (SMMUL/SMMLA), with no
    /// shift. |e| <= 2^22 bits, so the doubled-8-times value stays below 2^30.
    #[inline(always)]
    pub(crate) fn error_x256(reference: Amps, measured: Amps) -> i32 {
        let e = reference.to_bits().saturating_sub(measured.to_bits()).clamp(-ERROR_LIMIT_BITS, ERROR_LIMIT_BITS - 1);
        e << 8
    }

    /// The integrator's error term and the unlimited output, `I16F16` bits, for an error from
    /// [`Self::error_x256`]: returns `(xi + Ki*Ts e, Kp e + xi + Ki*Ts e)`. The integral includes the current sample
    /// (backward Euler), so that only two values per axis live across the voltage limit (fewer spills).
    #[inline(always)]
    pub(crate) fn integrate_bits(&self, e_x256: i32) -> (i32, i32) {
        // (e 2^8) x K (I8F24) = e K 2^32 in Q16: the high word is K e in I16F16 (floored, SMMLA). |K e| < 2^28 bits
        // (4096 V) for both gains, |xi| <= 2^28: |xi_e| < 2^29, |u| < 1.5 2^29. No wrap.
        let xi_e = mul_hi(e_x256, self.gains.ki_ts.to_bits()).wrapping_add(self.integral.to_bits());
        let u = mul_hi(e_x256, self.gains.kp.to_bits()).wrapping_add(xi_e);
        (xi_e, u)
    }

    /// The back-calculation: `xi = clamp(xi_e + Kb (u_sat - u), +-4096 V)`, with `(xi_e, u)` from
    /// [`Self::integrate_bits`] and `u_sat` = `u` after the limit (same sign, no larger in magnitude).
    #[inline(always)]
    pub(crate) fn back_calculate_bits(&mut self, xi_e: i32, u: i32, u_sat: i32) {
        // |u_sat - u| <= |u| < 1.5 2^29, so twice that fits; (2 w) x Kb (I1F31) has Kb w in its high word (floored).
        // |xi_e| < 2^29: the sum stays within +-2.5 2^29.
        let windup_x2 = u_sat.wrapping_sub(u) << 1;
        let xi = xi_e.wrapping_add(mul_hi(windup_x2, self.gains.kb.to_bits()));
        self.integral = I16F16::from_bits(xi.clamp(-INTEGRAL_LIMIT_BITS, INTEGRAL_LIMIT_BITS - 1));
    }

    /// One sample of a scalar PI with a symmetric output limit `+-limit` (a negative limit counts as 0).
    /// The current loop limits the d/q vector instead (`current_loop`); this form serves tests and simpler loops.
    pub fn step(&mut self, reference: Amps, measured: Amps, limit: Volts) -> PiOutput {
        let e = Self::error_x256(reference, measured);
        let (xi_e, u) = self.integrate_bits(e);
        let l = limit.to_bits().max(0);
        // max/min rather than clamp: never panics, whatever `l` is.
        let u_sat = u.max(l.wrapping_neg()).min(l);
        self.back_calculate_bits(xi_e, u, u_sat);
        PiOutput { voltage: Volts::from_bits(u_sat), saturated: u_sat != u }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn idx_units_convert() {
        // 0x30A0:01 = 2,073,000 uV/A = 2.073 V/A; 0x30A0:02 = 3,267,000 uV/(A ms) = 3267 V/(A s) -> 0.13068 V/A.
        let g = PiGains::from_idx_0x30a0(2_073_000, 3_267_000);
        assert!((g.kp().to_num::<f64>() - 2.073).abs() < 1e-7);
        assert!((g.ki_ts().to_num::<f64>() - 0.130_68).abs() < 1e-7);
        assert!((g.kb().to_num::<f64>() - 0.130_68 / 2.073).abs() < 1e-6);
        assert_eq!(PiGains::from_idx_0x30a0(1000, 1_000_000_000).kb(), I1F31::MAX);
        // Saturation of absurd dictionary values, and Kp = 0.
        let g = PiGains::from_idx_0x30a0(u32::MAX, u32::MAX);
        assert_eq!(g.kp().to_bits(), GAIN_LIMIT_BITS);
        assert_eq!(g.ki_ts().to_bits(), GAIN_LIMIT_BITS);
        assert_eq!(PiGains::from_idx_0x30a0(0, 1000).kb(), I1F31::MAX);
    }
}
