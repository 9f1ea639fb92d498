//! Velocity controller (PI + velocity and acceleration feedforward, back-calculation anti-windup), gains in the
//! units of IDX object 0x30A2, and the slow-loop quantities shared by the motion-control modules.
//!
//! Control law (EPOS4 velocity regulation, S1 L484-560, Fig. 2-4 and Fig. 2-8; `shared/spec/control-and-protection.md`
//! §1.4), evaluated once per slow tick (Ts = 0.4 ms, S1 L520):
//!
//! ```text
//! e      = v_ref - v_meas                                  (inc/tick)
//! xi_e   = xi + Ki*Ts * e                                  (integral including this sample, backward Euler)
//! u      = Kp * e + xi_e + FFv * v_ref + FFa * a_ref       (A)
//! u_sat  = clamp(u, +-I_max)                               (I_max: nominal or output current limit, S1 L1011-1015)
//! xi    <- clamp(xi_e + Kb * (u_sat - u), +-32768 A)       (back-calculation, Kb = Ts / Tt)
//! ```
//!
//! Tracking time: S1 only says "an anti-windup algorithm" (L557-560). The current loop ([`super::pi`]) uses
//! Tt = Ti; there a lasting saturation leaves the integrator at the limit itself (the steady state of the update
//! gives `xi = u_sat`), which is harmless at 25 kHz but, with the velocity loop's Ti of tens of ms, leaves the
//! output on the limit for a good part of Ti after the error reverses (measured: 220 ms with the defaults). The
//! velocity loop therefore tracks in one tick by default (Tt = Ts, Kb = 1 - 2^-31; Astrom and Hagglund's
//! guideline Td <= Tt <= Ti has Td = 0 for a PI): in saturation `xi = u_sat - Kp e - FF` (+ Ki Ts e), so the
//! output leaves the limit as soon as the error shrinks, and the integral holds exactly what the limit allows.
//! [`VelocityGains::with_tracking_gain`] sets another Kb.
//!
//! # Representation (convention 4 of `shared/design/ARCHITECTURE.md`)
//! The unit types are defined in [`super::units`]; [`IncPerTick`] and [`IncPerTick2`] are re-exported here.
//! - Positions: [`super::position::Increments`], an exact wrapping `i32` count of the main sensor.
//! - Velocity: [`IncPerTick`], increments per slow tick (400 us) as `I16F16`. The count difference of one tick is
//!   the sensor's natural velocity, so the estimate needs no scaling, and integrating it back to a position is an
//!   addition. Range +-32768 inc/tick = +-82 M inc/s (1.2 M rpm at 4096 inc/rev, 4,688 rpm even for a 2^20
//!   inc/rev sensor); resolution 2^-16 inc/tick = 0.038 inc/s = 5.6e-4 rpm at 4096 inc/rev.
//! - Acceleration: [`IncPerTick2`], increments per tick squared as `I16F16`; resolution 2^-16 inc/tick^2 =
//!   95 inc/s^2 (1.4 rpm/s at 4096 inc/rev, a feedforward current of 77 uA on the reference plant).
//! - Current: [`Amps`] (`I16F16`, [`super::frames`]) at the interface; inside, sums and the integrator are `i64`
//!   in units of 2^-32 A (`I32F32`), so an integral gain of 1e-5 A per increment still integrates exactly.
//! - Gains: [`ScaledGain`], a 31-bit mantissa and a binary exponent fixed once at conversion, so that every gain of
//!   the U32 dictionary range keeps 30 significant bits whatever the sensor resolution (4096 inc/rev encoder or
//!   42 inc/rev Halls). Each product is one 32x32->64 multiply (SMULL) and one 64-bit shift.
//!
//! # Gains (IDX 0x30A2, S2 L4528-4591; EPOS4 display units are 1000 times larger, S1 L527-556)
//! - 0x30A2:01 P gain [uA*s/rad] (S2 L4537-4549): A per (rad/s).
//! - 0x30A2:02 I gain [uA/rad] (S2 L4551-4563): A per rad of integrated velocity error.
//! - 0x30A2:03 FF velocity gain [uA*s/rad] (S2 L4565-4577), optimum viscous friction / kt (S1 L770-790).
//! - 0x30A2:04 FF acceleration gain [uA*s^2/rad] (S2 L4579-4591), optimum J / kt (S1 L792-805).
//!
//! A velocity of v inc/tick is `v * 2 pi f_s / N` rad/s (f_s = 2500 Hz, N = increments per revolution), which the
//! conversion folds into the gains once ([`VelocityGains::from_idx_0x30a2`]); nothing divides per tick.
//!
//! Cost per step: [`VelocityController::step`] compiles to 174 Thumb-2 instructions for thumbv7em (release,
//! no loops, no calls, no division), so at most 174 executed.

pub use super::units::{IncPerTick, IncPerTick2};

use super::frames::Amps;
use crate::power::{PWM_FREQUENCY_HZ, SLOW_TICK_DIVIDER};

/// Sampling frequency of the velocity and position loops in Hz: 2500 (EPOS4 Ts = 0.4 ms, S1 L520, L702).
pub const SLOW_TICK_HZ: u32 = PWM_FREQUENCY_HZ / SLOW_TICK_DIVIDER;

/// 2 pi in Q32, rounded: 26,986,075,409 / 2^32 = 6.283185307 (relative error 2e-12).
pub(crate) const TWO_PI_Q32: u128 = 26_986_075_409;

/// Saturates an `i64` to the `i32` range.
#[inline(always)]
pub fn sat_i32(x: i64) -> i32 {
    // Constant bounds in order: clamp cannot panic.
    x.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

/// A non-negative gain `mantissa * 2^-shift` (output LSB per input LSB), fixed once at conversion so that the
/// mantissa has 31 significant bits (or is as large as a shift of 0 allows). Applying it is one 32x32->64 multiply
/// and one arithmetic shift (floor).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ScaledGain {
    mantissa: i32,
    shift: u32,
}

impl ScaledGain {
    /// The zero gain.
    pub const ZERO: Self = Self { mantissa: 0, shift: 0 };

    /// The gain `product(num) / product(den)` in output LSB per input LSB, rounded to 31 significant bits. A zero or
    /// overflowing denominator gives [`Self::ZERO`]; a gain of 2^31 or more, or a numerator beyond 2^128,
    /// saturates at 2^31 - 1. For conversions only (it divides in 128 bits, up to 63 times).
    /// Never inlined: a conversion runs seldom, and inlined at each constant call site its 63-step search in
    /// 128-bit arithmetic was unrolled into every copy.
    #[must_use]
    #[inline(never)]
    pub fn from_ratio(num: &[u128], den: &[u128]) -> Self {
        let Some(d) = den.iter().try_fold(1u128, |acc, &x| acc.checked_mul(x)) else {
            return Self::ZERO;
        };
        if d == 0 {
            return Self::ZERO;
        }
        let Some(n) = num.iter().try_fold(1u128, |acc, &x| acc.checked_mul(x)) else {
            return Self { mantissa: i32::MAX, shift: 0 };
        };
        if n == 0 {
            return Self::ZERO;
        }
        // The largest shift whose rounded mantissa stays below 2^31 (q grows with s, so the first from the top).
        for s in (0..=62u32).rev() {
            let Some(ns) = n.checked_mul(1u128 << s) else { continue };
            let q = ns.saturating_add(d / 2).checked_div(d).unwrap_or(0);
            if let Ok(m) = i32::try_from(q) {
                return Self { mantissa: m, shift: s };
            }
        }
        Self { mantissa: i32::MAX, shift: 0 }
    }

    /// The mantissa (the gain is `mantissa * 2^-shift`).
    #[must_use]
    pub const fn mantissa(&self) -> i32 {
        self.mantissa
    }

    /// The binary exponent, 0..=62.
    #[must_use]
    pub const fn shift(&self) -> u32 {
        self.shift
    }

    /// `floor(x * gain)` in output LSB. |x * mantissa| < 2^62: never wraps.
    #[inline(always)]
    #[must_use]
    pub fn apply(self, x: i32) -> i64 {
        // shift <= 62 by construction; wrapping_shr only masks it.
        i64::from(x).wrapping_mul(i64::from(self.mantissa)).wrapping_shr(self.shift)
    }
}

/// Limit of one current term and of the integrator, in 2^-32 A: +-32768 A (2^47). Far beyond any real current, so
/// the clamp only guards the arithmetic: a sum of eight such terms stays below 2^50.
pub(crate) const TERM_LIMIT: i64 = 1 << 47;

/// Clamps a current term (2^-32 A) to +-[`TERM_LIMIT`].
#[inline(always)]
pub(crate) fn clamp_term(x: i64) -> i64 {
    x.clamp(-TERM_LIMIT, TERM_LIMIT)
}

/// A current limit in 2^-32 A from an [`Amps`] limit (negative counts as 0).
#[inline(always)]
pub(crate) fn limit_q32(limit: Amps) -> i64 {
    i64::from(limit.to_bits().max(0)) << 16
}

/// A current in 2^-32 A to [`Amps`], floor, saturating at the `I16F16` range.
#[inline(always)]
pub(crate) fn q32_to_amps(x: i64) -> Amps {
    Amps::from_bits(sat_i32(x >> 16))
}

/// Gain "current per velocity" in the velocity LSB: raw in uA*s/rad (0x30A2:01/03, 0x30A1:03/04) to 2^-32 A per
/// 2^-16 inc/tick: `raw * 1e-6 * 2pi * f_s / N * 2^16`.
pub(crate) fn gain_current_per_velocity(raw_ua_s_per_rad: u32, inc_per_rev: u32) -> ScaledGain {
    ScaledGain::from_ratio(
        &[u128::from(raw_ua_s_per_rad), TWO_PI_Q32, u128::from(SLOW_TICK_HZ), 1 << 16],
        &[u128::from(inc_per_rev), 1_000_000, 1 << 32],
    )
}

/// Gain "current per acceleration" in the acceleration LSB: raw in uA*s^2/rad (0x30A2:04, 0x30A1:05) to 2^-32 A
/// per 2^-16 inc/tick^2: `raw * 1e-6 * 2pi * f_s^2 / N * 2^16`.
pub(crate) fn gain_current_per_acceleration(raw_ua_s2_per_rad: u32, inc_per_rev: u32) -> ScaledGain {
    let f = u128::from(SLOW_TICK_HZ);
    ScaledGain::from_ratio(
        &[u128::from(raw_ua_s2_per_rad), TWO_PI_Q32, f, f, 1 << 16],
        &[u128::from(inc_per_rev), 1_000_000, 1 << 32],
    )
}

/// `raw_a / (raw_b * f_s)` as `I1F31` bits, the form of Kb = Ts/Tt for Tt = Ti (0x30A2: I [uA/rad] over
/// P [uA*s/rad]) or Tt = Td (0x30A1: P [uA/rad] over D [uA*s/rad]); the largest value (tracking in one tick)
/// when `raw_b` is 0 or the ratio reaches 1.
pub(crate) fn tracking_gain(raw_a: u32, raw_b: u32) -> i32 {
    let den = u64::from(raw_b).saturating_mul(u64::from(SLOW_TICK_HZ));
    if den == 0 {
        return i32::MAX;
    }
    let q = (u64::from(raw_a) << 31).saturating_add(den / 2).checked_div(den).unwrap_or(u64::MAX);
    i32::try_from(q).unwrap_or(i32::MAX)
}

/// The back-calculation term `Kb * (u_sat - u)` in 2^-32 A, with `kb` in `I1F31` bits.
#[inline(always)]
pub(crate) fn back_calculation(kb: i32, u_sat: i64, u: i64) -> i64 {
    // |u_sat - u| <= |u| < 2^51; in 2^-16 A it fits an i32 after saturation (only a 32768 A excess saturates,
    // and then the term still has the right sign). (w 2^16) (Kb 2^31) >> 15 = Kb w in 2^-32 A.
    let w = sat_i32(u_sat.wrapping_sub(u) >> 16);
    i64::from(w).wrapping_mul(i64::from(kb)) >> 15
}

/// Velocity-controller gains in the internal per-tick form. Construct with [`VelocityGains::from_idx_0x30a2`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct VelocityGains {
    /// Kp: 2^-32 A per 2^-16 inc/tick.
    pub(crate) kp: ScaledGain,
    /// Ki*Ts: 2^-32 A per 2^-16 inc/tick, per tick.
    pub(crate) ki_ts: ScaledGain,
    /// FF velocity: 2^-32 A per 2^-16 inc/tick.
    pub(crate) ff_velocity: ScaledGain,
    /// FF acceleration: 2^-32 A per 2^-16 inc/tick^2.
    pub(crate) ff_acceleration: ScaledGain,
    /// Kb = Ts / Tt, `I1F31` bits, 0..=2^31 - 1.
    pub(crate) kb: i32,
}

impl VelocityGains {
    /// All gains zero (the output is always 0 A).
    pub const ZERO: Self = Self {
        kp: ScaledGain::ZERO,
        ki_ts: ScaledGain::ZERO,
        ff_velocity: ScaledGain::ZERO,
        ff_acceleration: ScaledGain::ZERO,
        kb: 0,
    };

    /// Gains from the raw values of IDX 0x30A2 subs 1-4 (S2 L4528-4591): `p` [uA*s/rad], `i` [uA/rad],
    /// `ff_velocity` [uA*s/rad], `ff_acceleration` [uA*s^2/rad], for a position sensor of `inc_per_rev`
    /// increments per revolution (0x3000:05; 42 for the reference motor's Halls alone: 7 pole pairs x 6 states,
    /// as in S1's Hall example L1433-1455). Kb defaults to 1 - 2^-31 (Tt = Ts, see the module documentation).
    /// Call when the dictionary changes, never per tick.
    #[must_use]
    pub fn from_idx_0x30a2(p: u32, i: u32, ff_velocity: u32, ff_acceleration: u32, inc_per_rev: u32) -> Self {
        Self {
            kp: gain_current_per_velocity(p, inc_per_rev),
            // Ki*Ts per 2^-16 inc/tick: raw * 1e-6 [A/rad] * 2pi / N [rad/inc] * 2^-16 [inc] in 2^-32 A.
            ki_ts: ScaledGain::from_ratio(
                &[u128::from(i), TWO_PI_Q32, 1 << 16],
                &[u128::from(inc_per_rev), 1_000_000, 1 << 32],
            ),
            ff_velocity: gain_current_per_velocity(ff_velocity, inc_per_rev),
            ff_acceleration: gain_current_per_acceleration(ff_acceleration, inc_per_rev),
            kb: i32::MAX,
        }
    }

    /// Kb = Ts/Ti = Ki*Ts/Kp in `I1F31` bits for the raw 0x30A2 gains (the current loop's choice, [`super::pi`]),
    /// for [`Self::with_tracking_gain`].
    #[must_use]
    pub fn tracking_gain_ts_over_ti(p: u32, i: u32) -> i32 {
        tracking_gain(i, p)
    }

    /// The same gains with another back-calculation gain Kb = Ts/Tt in `I1F31` bits (negative values become 0).
    #[must_use]
    pub fn with_tracking_gain(self, kb_bits: i32) -> Self {
        Self { kb: kb_bits.max(0), ..self }
    }

    /// Kp as a [`ScaledGain`] (2^-32 A per 2^-16 inc/tick).
    #[must_use]
    pub const fn kp(&self) -> ScaledGain {
        self.kp
    }

    /// Ki*Ts as a [`ScaledGain`] (2^-32 A per 2^-16 inc/tick, per tick).
    #[must_use]
    pub const fn ki_ts(&self) -> ScaledGain {
        self.ki_ts
    }

    /// The velocity feedforward gain (2^-32 A per 2^-16 inc/tick).
    #[must_use]
    pub const fn ff_velocity(&self) -> ScaledGain {
        self.ff_velocity
    }

    /// The acceleration feedforward gain (2^-32 A per 2^-16 inc/tick^2).
    #[must_use]
    pub const fn ff_acceleration(&self) -> ScaledGain {
        self.ff_acceleration
    }

    /// Kb = Ts/Tt in `I1F31` bits.
    #[must_use]
    pub const fn kb(&self) -> i32 {
        self.kb
    }
}

/// The PI velocity controller with feedforward (EPOS4, S1 L484-560): gains and the integrator.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct VelocityController {
    gains: VelocityGains,
    /// Integrator, 2^-32 A, within +-[`TERM_LIMIT`].
    integral: i64,
    saturated: bool,
}

impl VelocityController {
    /// A controller with an empty integrator.
    #[must_use]
    pub const fn new(gains: VelocityGains) -> Self {
        Self { gains, integral: 0, saturated: false }
    }

    /// The gains.
    #[must_use]
    pub const fn gains(&self) -> VelocityGains {
        self.gains
    }

    /// Replaces the gains, keeping the integrator (bumpless in the integral part).
    pub fn set_gains(&mut self, gains: VelocityGains) {
        self.gains = gains;
    }

    /// Empties the integrator (on enable).
    pub fn reset(&mut self) {
        self.integral = 0;
        self.saturated = false;
    }

    /// The integrator's current, floor to [`Amps`].
    #[must_use]
    pub fn integral(&self) -> Amps {
        q32_to_amps(self.integral)
    }

    /// Presets the integrator (bumpless transfer from another mode), e.g. to the present current demand.
    pub fn set_integral(&mut self, current: Amps) {
        self.integral = i64::from(current.to_bits()) << 16;
    }

    /// The limit was active in the last step.
    #[must_use]
    pub const fn saturated(&self) -> bool {
        self.saturated
    }

    /// One slow tick: the q-current demand for the velocity demand `v_ref`, the estimated velocity `v_meas`
    /// ([`super::velocity_estimate`] or [`super::observer`]) and the demanded acceleration `a_ref` (feedforward
    /// only; pass [`IncPerTick2::ZERO`] where S1 L762-768 says acceleration feedforward is off, CSP and CSV),
    /// limited to `+-limit` (a negative limit counts as 0).
    pub fn step(&mut self, v_ref: IncPerTick, v_meas: IncPerTick, a_ref: IncPerTick2, limit: Amps) -> Amps {
        self.step_with_torque(v_ref, v_meas, a_ref, Amps::ZERO, limit)
    }

    /// [`Self::step`] with a torque feedforward `torque` (the master's torque offset 0x60B2 as a current, IDX L977)
    /// added to the controller's output before the limit, so that the limit bounds the sum and the
    /// back-calculation keeps the integrator from winding against it: in saturation it holds
    /// `u_sat - Kp e - FF - torque` (+ Ki Ts e), what the limit leaves the controller.
    pub fn step_with_torque(
        &mut self,
        v_ref: IncPerTick,
        v_meas: IncPerTick,
        a_ref: IncPerTick2,
        torque: Amps,
        limit: Amps,
    ) -> Amps {
        let g = &self.gains;
        let e = v_ref.to_bits().saturating_sub(v_meas.to_bits());
        // Each term within +-2^47, the integrator too: the sum stays within +-2^50 (no wrap).
        let xi_e = self.integral.wrapping_add(clamp_term(g.ki_ts.apply(e)));
        // The torque feedforward is an I16F16 current: within +-2^47 in 2^-32 A.
        let ff = clamp_term(g.ff_velocity.apply(v_ref.to_bits()))
            .wrapping_add(clamp_term(g.ff_acceleration.apply(a_ref.to_bits())))
            .wrapping_add(i64::from(torque.to_bits()) << 16);
        let u = clamp_term(g.kp.apply(e)).wrapping_add(xi_e).wrapping_add(ff);
        let l = limit_q32(limit);
        let u_sat = u.max(l.wrapping_neg()).min(l);
        self.saturated = u_sat != u;
        self.integral = clamp_term(xi_e.wrapping_add(back_calculation(g.kb, u_sat, u)));
        q32_to_amps(u_sat)
    }
}
