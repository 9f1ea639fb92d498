//! EPOS4's velocity observer ("digital disturbance observer", S2 L4593-4595; S1 L577-684): a model of the
//! rigid drive train predicts position, velocity and load torque from the applied current, and the newly
//! measured position corrects all three (control structure 0x3000:02 bits 7..4 = 2, S2 L3813-3850).
//!
//! Model and correction (S1 L627-645, digest §1.4 and §1.10; the sign of the load correction was lost in the OCR
//! and is the one that makes the observer stable, digest §7 row 27):
//!
//! ```text
//! prediction:  J dw/dt = k_m i - T - r w,   dtheta/dt = w
//!   w-     = w + Ts/J (k_m i - T - r w)
//!   theta- = theta + Ts (w + w-) / 2
//! correction, e = theta_meas - theta-:
//!   theta  = theta- + l_theta e
//!   w      = w-     + l_w e
//!   T      = T      - l_T e
//! ```
//!
//! The load torque is kept as the equivalent current `T / k_m` (A), so the prediction is a single product
//! `Ts^2 k_m N / (2 pi J) (i - T/k_m)` with no per-tick multiply by k_m. Units: position in increments (`I32F32`,
//! wrapping like the sensor count), velocity in inc/tick (`I32F32` internally, [`IncPerTick`] out), load in 2^-32 A.
//!
//! Parameters (IDX 0x30A3, S2 L4593-4670; EPOS4 display units S1 L586-620):
//! - 0x30A3:01 position correction gain l_theta: IDX prints "[%]" with default 868 while EPOS4 shows 0.4..0.95
//!   (S1 L1236, L1447); read as per mille (digest §7 row 4; `firmware/device.toml`).
//! - 0x30A3:02 velocity correction gain l_w (mHz) (S2 L4616-4628): the per-sample gain from a position error in
//!   rad to a velocity in rad/s is l_w [1/s] (S1 L641), so per tick in increments it is `l_w Ts`.
//! - 0x30A3:03 load correction gain l_T [uNm/rad] (S2 L4630-4642).
//! - 0x30A3:04 friction r [0.001 uNm/rpm] (S2 L4644-4656): r_SI = raw * 1e-9 * 60 / (2 pi) Nm s/rad
//!   (S1 L612: r_SI = 0.00003/pi * r[uNm/rpm]).
//! - 0x30A3:05 inertia J [0.001 g cm^2] (S2 L4658-4670): J_SI = raw * 1e-10 kg m^2.
//! - 0x3001:05 torque constant k_m [uNm/A] (S1 L586-590 uses it in the observer; `firmware/device.toml`).
//!
//! The position may come from the encoder or from the Hall sensors alone (42 steps per revolution on the
//! reference motor: 7 pole pairs x 6 states, like S1's Hall example L1433-1455): the observer works in the
//! increments of whatever sensor feeds it; only `inc_per_rev` changes.
//!
//! Cost per step: [`VelocityObserver::step`] compiles to 222 Thumb-2 instructions for thumbv7em (release,
//! no loops, no calls, no division).

use super::frames::Amps;
use super::position::Increments;
use super::velocity::{clamp_term, q32_to_amps, sat_i32, IncPerTick, ScaledGain, SLOW_TICK_HZ, TWO_PI_Q32};

/// Velocity state clamp, 2^-32 inc/tick: +-16384 inc/tick (2^46).
const VELOCITY_LIMIT: i64 = 1 << 46;
/// Largest l_theta, `I2F30` bits: just under 2 (beyond that the correction overshoots the measurement).
const L_THETA_MAX: i64 = (1 << 31) - 1;

/// Observer gains and model in the internal per-tick form. Construct with [`ObserverGains::from_idx_0x30a3`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ObserverGains {
    /// l_theta, `I2F30` bits.
    l_theta: i32,
    /// l_w Ts: 2^-32 inc/tick per 2^-16 inc of position error.
    l_omega: ScaledGain,
    /// l_T / k_m * 2pi/N: 2^-32 A per 2^-16 inc.
    l_load: ScaledGain,
    /// Ts^2 k_m N / (2 pi J): 2^-32 inc/tick per 2^-16 A (the `I16F16` current LSB).
    k_current: ScaledGain,
    /// r Ts / J: 2^-32 inc/tick per 2^-16 inc/tick.
    k_friction: ScaledGain,
}

impl ObserverGains {
    /// Gains from the raw values of IDX 0x30A3 subs 1-5 (S2 L4593-4670) and the torque constant 0x3001:05:
    /// `l_theta_permille`, `l_omega_mhz`, `l_load_unm_per_rad`, `friction` [0.001 uNm/rpm], `inertia`
    /// [0.001 g cm^2], `torque_constant` [uNm/A], for `inc_per_rev` increments per revolution of the sensor that
    /// feeds the observer. A zero inertia gives a model without dynamics (prediction = constant velocity); a zero
    /// torque constant disables the load correction. Call when the dictionary changes, never per tick.
    #[must_use]
    pub fn from_idx_0x30a3(
        l_theta_permille: u32,
        l_omega_mhz: u32,
        l_load_unm_per_rad: u32,
        friction: u32,
        inertia: u32,
        torque_constant: u32,
        inc_per_rev: u32,
    ) -> Self {
        let f = u128::from(SLOW_TICK_HZ);
        let n = u128::from(inc_per_rev);
        let l_theta = (i64::from(l_theta_permille) << 30).checked_div(1000).unwrap_or(0).min(L_THETA_MAX);
        Self {
            l_theta: i32::try_from(l_theta).unwrap_or(0),
            // raw * 1e-3 [1/s] / f_s, in 2^-32 per 2^-16: * 2^16.
            l_omega: ScaledGain::from_ratio(&[u128::from(l_omega_mhz), 1 << 16], &[1000, f]),
            // raw_lT / raw_km [A/rad] * 2pi / N [rad/inc], in 2^-32 A per 2^-16 inc: * 2^16.
            l_load: ScaledGain::from_ratio(
                &[u128::from(l_load_unm_per_rad), TWO_PI_Q32, 1 << 16],
                &[u128::from(torque_constant), n, 1 << 32],
            ),
            // km 1e-6 N / (f_s^2 2pi J 1e-10) [inc/tick per A], in 2^-32 per 2^-16: * 2^16.
            k_current: ScaledGain::from_ratio(
                &[u128::from(torque_constant), n, 10_000, 1 << 16, 1 << 32],
                &[f, f, TWO_PI_Q32, u128::from(inertia)],
            ),
            // r_SI Ts / J_SI = raw 1e-9 60/(2pi) / (f_s raw_J 1e-10) = raw 600 / (2pi f_s raw_J); * 2^16.
            k_friction: ScaledGain::from_ratio(
                &[u128::from(friction), 600, 1 << 16, 1 << 32],
                &[TWO_PI_Q32, f, u128::from(inertia)],
            ),
        }
    }

    /// l_theta in `I2F30` bits.
    #[must_use]
    pub const fn l_theta(&self) -> i32 {
        self.l_theta
    }

    /// l_w Ts (2^-32 inc/tick per 2^-16 inc).
    #[must_use]
    pub const fn l_omega(&self) -> ScaledGain {
        self.l_omega
    }

    /// l_T / k_m * 2pi/N (2^-32 A per 2^-16 inc).
    #[must_use]
    pub const fn l_load(&self) -> ScaledGain {
        self.l_load
    }

    /// Ts^2 k_m N / (2 pi J) (2^-32 inc/tick per 2^-16 A).
    #[must_use]
    pub const fn k_current(&self) -> ScaledGain {
        self.k_current
    }

    /// r Ts / J (2^-32 inc/tick per 2^-16 inc/tick).
    #[must_use]
    pub const fn k_friction(&self) -> ScaledGain {
        self.k_friction
    }
}

/// The velocity observer: gains and the three states.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct VelocityObserver {
    gains: ObserverGains,
    /// Position estimate, 2^-32 inc, wrapping (the integer part wraps with the sensor's `i32` count).
    theta: i64,
    /// Velocity estimate, 2^-32 inc/tick, within +-2^46.
    omega: i64,
    /// Load torque as an equivalent current, 2^-32 A, within +-2^47.
    load: i64,
}

impl VelocityObserver {
    /// An observer at rest at position 0; call [`Self::reset`] with the first measurement.
    #[must_use]
    pub const fn new(gains: ObserverGains) -> Self {
        Self { gains, theta: 0, omega: 0, load: 0 }
    }

    /// The gains.
    #[must_use]
    pub const fn gains(&self) -> ObserverGains {
        self.gains
    }

    /// Replaces the gains, keeping the states.
    pub fn set_gains(&mut self, gains: ObserverGains) {
        self.gains = gains;
    }

    /// Restarts at the measured position, at rest, with no load.
    pub fn reset(&mut self, position: Increments) {
        self.theta = i64::from(position.0) << 32;
        self.omega = 0;
        self.load = 0;
    }

    /// The velocity estimate.
    #[must_use]
    pub fn velocity(&self) -> IncPerTick {
        IncPerTick::from_bits(sat_i32(self.omega >> 16))
    }

    /// The integer part of the position estimate (floor).
    #[must_use]
    pub fn position(&self) -> Increments {
        Increments((self.theta >> 32) as i32)
    }

    /// The load-torque estimate as the equivalent q current (T / k_m).
    #[must_use]
    pub fn load_current(&self) -> Amps {
        q32_to_amps(self.load)
    }

    /// One slow tick: predict with the q current `current` applied during the tick that just ended (the demand
    /// of the previous step or the measured average), correct with the new measured `position`; returns the
    /// velocity estimate.
    pub fn step(&mut self, position: Increments, current: Amps) -> IncPerTick {
        let g = &self.gains;
        // Prediction. i - T/k_m in 2^-16 A (the load within +-2^47 gives +-2^31 after the shift: saturate).
        let drive = sat_i32(i64::from(current.to_bits()).wrapping_sub(self.load >> 16));
        let omega_q16 = sat_i32(self.omega >> 16);
        // |omega| <= 2^46 and each term is clamped to 2^47: |omega_pred| < 2^49 before its clamp.
        let omega_pred = self
            .omega
            .wrapping_add(clamp_term(g.k_current.apply(drive)))
            .wrapping_sub(clamp_term(g.k_friction.apply(omega_q16)))
            .clamp(-VELOCITY_LIMIT, VELOCITY_LIMIT);
        // theta + (w + w-)/2: |sum| <= 2^47, and the position wraps on purpose (mod 2^32 increments, like the
        // sensor count).
        let theta_pred = self.theta.wrapping_add(self.omega.wrapping_add(omega_pred) >> 1);
        // Correction. The wrapping difference is exact while |e| < 2^31 inc; in 2^-16 inc it saturates at
        // +-32768 inc, far beyond any real observer error.
        let e = sat_i32(((i64::from(position.0) << 32).wrapping_sub(theta_pred)) >> 16);
        // (e 2^16)(l 2^30) >> 14 = l e in 2^-32 inc; |.| < 2^61.
        let theta_corr = i64::from(e).wrapping_mul(i64::from(g.l_theta)) >> 14;
        self.theta = theta_pred.wrapping_add(theta_corr);
        self.omega = omega_pred.wrapping_add(clamp_term(g.l_omega.apply(e))).clamp(-VELOCITY_LIMIT, VELOCITY_LIMIT);
        self.load = clamp_term(self.load.wrapping_sub(clamp_term(g.l_load.apply(e))));
        self.velocity()
    }
}
