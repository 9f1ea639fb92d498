//! Position controller: PID with a low-pass filtered D part, back-calculation anti-windup, velocity and
//! acceleration feedforward, output a q-current demand (EPOS4 position regulation, S1 L688-760, Fig. 2-5 and
//! Fig. 2-9 L1020-1085; gains IDX 0x30A1, S2 L4447-4526; `shared/spec/control-and-protection.md` §1.5).
//!
//! # Structure
//! EPOS4's position controller drives the current controller directly, not through the velocity controller
//! (S1 Fig. 2-5 L688-700; the same in IDX S2 L1143-1178; 0x3000:02 bits 11..8 knows only "1 = PID",
//! S2 L3813-3850). That is [`PositionStructure::Pid`], the default. The seeds also describe a cascade, position
//! P feeding a PI velocity loop: EPOS4's dual-loop main loop (`w_ref = K_Main (theta_des - theta) + w_ff`,
//! S1 L9149-9156, gain 0x30AE:01 in 1/s) and Nanotec's S controller (S3 p.286). That is
//! [`PositionStructure::Cascade`] ([`CascadePositionController`]), selectable, not the default.
//!
//! # PID law (per slow tick, Ts = 0.4 ms, S1 L702)
//! ```text
//! e      = theta_ref - theta           (exact integer increments, wrapping i32)
//! d      = LPF_390.61(e[k] - e[k-1])   (filtered derivative, inc/tick)
//! xi_e   = xi + Ki*Ts * e
//! u      = Kp * e + xi_e + Kd * d + FFv * w_ref + FFa * a_ref
//! u_sat  = clamp(u, +-I_max);   xi <- xi_e + Kb (u_sat - u),  Kb = Ts/Tt, Tt = Td = Kd/Kp
//! ```
//! The friction feedforward `FFc * s` (0x30A1:06, [`PositionGains::with_friction_feedforward`]) is added to `u`
//! before the clamp, with `s` the sign of the demanded velocity while the demand moves, and at a standing demand
//! (`w_ref = a_ref = 0`) the sign of the error once `|e|` exceeds [`STANDSTILL_FRICTION_BAND_INC`], else 0.
//!
//! The tracking time Tt of the back-calculation (S1 L757-760 names only "the anti-windup method") is the
//! derivative time Td, the lower end of Astrom and Hagglund's Td <= Tt <= Ti: in a lasting saturation the
//! integrator settles at `u_sat - Kp e (1 - Tt/Ti)` instead of at the limit itself (Tt = Ti), so the output
//! leaves the limit as soon as the error shrinks (without D, Tt = Ts).
//! The D part acts on the error, as S1's `C_position(s) = K_P + K_I/s + K_D s / (1 + s/w_c)` (S1 L740-756) does;
//! with feedforward of the demanded velocity this damps the deviation from the path rather than the motion
//! itself. Its first-order low-pass has `w_c = 390.61 rad/s` ("set to 390.61 rad/s empirically", S1 L756),
//! discretised with the matched pole `exp(-w_c Ts)` = 0.85535 ([`super::velocity_estimate::LowPass`]), so the
//! time constant is 1/w_c = 2.560 ms at the sample instants.
//!
//! # D filter (the project's 0x30A1:07)
//! EPOS4 fixes `w_c`; here it is the object 0x30A1:07 ([`PositionGains::with_d_filter_cutoff`]), 390.61 rad/s by
//! default. Above `w_c` the D part gives no phase lead and acts as a further proportional gain. On a rigid load the
//! PID crosses over below it; on an elastic load the motor moves on its own inertia above the resonance, and the
//! PD that holds it there crosses over at several hundred rad/s, where a 390 rad/s filter leaves it no phase: the
//! loop rang at the current limit on a belt axis (`tests/tests/drive/auto_tune_belt.rs`). The auto-tuning raises
//! the cut-off for an elastic load (`firmware::drive::tuning`, "Position loop"). A change of the cut-off keeps the
//! filter's output ([`super::velocity_estimate::LowPass::retune`]).
//!
//! # Positions (convention 4 of `shared/design/ARCHITECTURE.md`)
//! Positions are [`Increments`], a wrapping `i32`, like the CiA 402 position objects (0x6062/0x6064/0x607A,
//! INTEGER32); the type is defined with the other units in [`super::units`] and re-exported here. The error
//! `theta_ref.wrapping_sub(theta)` is exact whenever the true distance is below 2^31 increments (524,288
//! revolutions at 4096 inc/rev), including across the +-2^31 wrap of both values; a plain `i64` would not remove
//! the wrap (the dictionary values are 32-bit) and costs twice the registers. The error is then clamped to +-2^24
//! increments (4096 revolutions, far beyond any following-error window, 0x6065) before the gains, so the products
//! stay within 2^55.
//!
//! # Gains (IDX 0x30A1; EPOS4 display units 1000 times larger, S1 L702-712, L730-739)
//! - 0x30A1:01 P [uA/rad] (S2 L4458-4470), 0x30A1:02 I [uA/(rad*s)] (S2 L4472-4484),
//!   0x30A1:03 D [uA*s/rad] (S2 L4486-4498), 0x30A1:04 FF velocity [uA*s/rad] (S2 L4500-4512),
//!   0x30A1:05 FF acceleration [uA*s^2/rad] (S2 L4514-4526).
//!
//! # Friction feedforward (the project's 0x30A1:06)
//! EPOS4 compensates only speed-proportional friction (FF velocity, S1 L728); the Coulomb part is left to the
//! integrator. On a motor whose Coulomb friction is large against what the PID's proportional part gives a few
//! increments off the target, that leaves two faults (`hal-sim/presets/small-gimbal.toml`: 12 mA of friction, and
//! `Kp` gives 0.44 mA per increment):
//! - while moving, the integrator holds the friction, so when the demand stops it still pushes forward and the
//!   motor stops past the target (2 to 3 increments of 16,384);
//! - at standstill the integrator has to swing through twice the friction before the motor comes back, 80 to
//!   100 ms.
//!
//! The feedforward carries the friction instead. While the demand moves it is the friction's own sign, so the
//! integrator holds none of it and has nothing to unwind. At a standing demand outside the band it cancels the
//! friction the motor must overcome to come back, so the PID moves it as if it had none; inside the band it is off
//! and the friction holds the motor. An overestimate by a fraction `x < 1` accelerates the approach by `x` times the
//! friction's deceleration, so the motor slides past the band's edge by at most `x` times the distance it came and
//! each swing is shorter than the one before: the hold converges for any estimate under twice the true friction.
//!
//! Cost per step: [`PositionController::step_with_torque`] (which [`PositionController::step`] calls) compiles to
//! 318 Thumb-2 instructions for thumbv7em (release, no loops, no calls, no division; 272 before the friction
//! feedforward, most of the difference register spills); [`CascadePositionController::step`] to 212. Counted in
//! the assembly of `cargo rustc --release -p drive-control --target thumbv7em-none-eabihf -- --emit asm`.

pub use super::units::Increments;

use super::frames::Amps;
use super::velocity::{
    back_calculation, clamp_term, gain_current_per_acceleration, gain_current_per_velocity, limit_q32, q32_to_amps,
    sat_i32, tracking_gain, IncPerTick, IncPerTick2, ScaledGain, VelocityController, SLOW_TICK_HZ, TWO_PI_Q32,
};
use super::velocity_estimate::LowPass;

/// The D filter cut-off of EPOS4's position PID, 390.61 rad/s (S1 L756), in mrad/s.
pub const D_FILTER_CUTOFF_MILLIRAD_PER_S: u32 = 390_610;

/// At a standing demand the friction feedforward pushes the motor back only while it is more than this many
/// increments off the target: within +-1 the friction holds it (module documentation, "Friction feedforward").
pub const STANDSTILL_FRICTION_BAND_INC: i32 = 1;

/// Error clamp before the gains: +-2^24 increments.
const ERROR_LIMIT: i32 = 1 << 24;
/// Clamp of the per-tick error difference before the shift to `I16F16`: +-2^14 inc/tick.
const DIFF_LIMIT: i32 = 1 << 14;

/// The position-control structure (0x3000:02 bits 11..8 = 1, PID, S2 L3813-3850, is EPOS4's only one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PositionStructure {
    /// PID + feedforward to the current loop (EPOS4, S1 Fig. 2-5). The default.
    #[default]
    Pid,
    /// Position P + velocity feedforward to a PI velocity loop (EPOS4 dual-loop main loop S1 L9149-9156,
    /// Nanotec S3 p.286).
    Cascade,
}

/// Position-PID gains in the internal per-tick form. Construct with [`PositionGains::from_idx_0x30a1`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct PositionGains {
    /// Kp: 2^-32 A per increment.
    kp: ScaledGain,
    /// Ki*Ts: 2^-32 A per increment, per tick.
    ki_ts: ScaledGain,
    /// Kd: 2^-32 A per 2^-16 inc/tick of filtered error rate.
    kd: ScaledGain,
    /// FF velocity: 2^-32 A per 2^-16 inc/tick.
    ff_velocity: ScaledGain,
    /// FF acceleration: 2^-32 A per 2^-16 inc/tick^2.
    ff_acceleration: ScaledGain,
    /// Kb = Ts/Tt, `I1F31` bits.
    kb: i32,
    /// FF friction: the Coulomb friction's current, 2^-32 A.
    ff_friction: i64,
    /// The D part's low-pass (its coefficient only; 0x30A1:07).
    d_filter: LowPass,
}

impl PositionGains {
    /// Gains from the raw values of IDX 0x30A1 subs 1-5 (S2 L4447-4526): `p` [uA/rad], `i` [uA/(rad*s)],
    /// `d` [uA*s/rad], `ff_velocity` [uA*s/rad], `ff_acceleration` [uA*s^2/rad], for `inc_per_rev` increments per
    /// revolution (0x3000:05). Kb = Ts/Td = Kp/(Kd f_s), at most 1 - 2^-31. Call when the dictionary changes,
    /// never per tick.
    #[must_use]
    pub fn from_idx_0x30a1(p: u32, i: u32, d: u32, ff_velocity: u32, ff_acceleration: u32, inc_per_rev: u32) -> Self {
        let n = u128::from(inc_per_rev);
        Self {
            // raw * 1e-6 [A/rad] * 2pi / N [rad/inc] in 2^-32 A per inc.
            kp: ScaledGain::from_ratio(&[u128::from(p), TWO_PI_Q32], &[n, 1_000_000]),
            // raw * 1e-6 [A/(rad s)] * 2pi / N / f_s per tick.
            ki_ts: ScaledGain::from_ratio(&[u128::from(i), TWO_PI_Q32], &[n, 1_000_000, u128::from(SLOW_TICK_HZ)]),
            kd: gain_current_per_velocity(d, inc_per_rev),
            ff_velocity: gain_current_per_velocity(ff_velocity, inc_per_rev),
            ff_acceleration: gain_current_per_acceleration(ff_acceleration, inc_per_rev),
            kb: tracking_gain(p, d),
            ff_friction: 0,
            d_filter: LowPass::from_cutoff_millirad_per_s(D_FILTER_CUTOFF_MILLIRAD_PER_S),
        }
    }

    /// The same gains with the friction feedforward `ua` in uA (0x30A1:06, module documentation).
    #[must_use]
    pub fn with_friction_feedforward(self, ua: u32) -> Self {
        // ua * 1e-6 A in 2^-32 A: below 2^52, within the term clamp.
        let ff_friction = clamp_term(((i64::from(ua)) << 32) / 1_000_000);
        Self { ff_friction, ..self }
    }

    /// The same gains with the D part's low-pass at `millirad_per_s` (0x30A1:07; EPOS4's is
    /// [`D_FILTER_CUTOFF_MILLIRAD_PER_S`], module documentation "D filter").
    #[must_use]
    pub fn with_d_filter_cutoff(self, millirad_per_s: u32) -> Self {
        Self { d_filter: LowPass::from_cutoff_millirad_per_s(millirad_per_s), ..self }
    }

    /// The same gains with another back-calculation gain Kb = Ts/Tt in `I1F31` bits (negative values become 0).
    #[must_use]
    pub fn with_tracking_gain(self, kb_bits: i32) -> Self {
        Self { kb: kb_bits.max(0), ..self }
    }

    /// Kp (2^-32 A per increment).
    #[must_use]
    pub const fn kp(&self) -> ScaledGain {
        self.kp
    }

    /// Ki*Ts (2^-32 A per increment, per tick).
    #[must_use]
    pub const fn ki_ts(&self) -> ScaledGain {
        self.ki_ts
    }

    /// Kd (2^-32 A per 2^-16 inc/tick).
    #[must_use]
    pub const fn kd(&self) -> ScaledGain {
        self.kd
    }

    /// FF velocity (2^-32 A per 2^-16 inc/tick).
    #[must_use]
    pub const fn ff_velocity(&self) -> ScaledGain {
        self.ff_velocity
    }

    /// FF acceleration (2^-32 A per 2^-16 inc/tick^2).
    #[must_use]
    pub const fn ff_acceleration(&self) -> ScaledGain {
        self.ff_acceleration
    }

    /// Kb in `I1F31` bits.
    #[must_use]
    pub const fn kb(&self) -> i32 {
        self.kb
    }
}

/// EPOS4's position PID with filtered D, anti-windup and feedforward, output a current demand (S1 L688-760).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PositionController {
    gains: PositionGains,
    /// Integrator, 2^-32 A.
    integral: i64,
    /// D filter of the per-tick error difference (390.61 rad/s).
    d_filter: LowPass,
    /// Last (unclamped, wrapping) error, for the difference; `None` after a reset.
    last_error: Option<i32>,
    /// Last following error (wrapping difference), for monitoring (0x60F4).
    following_error: i32,
    saturated: bool,
}

impl PositionController {
    /// A controller with empty integrator and D filter.
    #[must_use]
    pub fn new(gains: PositionGains) -> Self {
        Self {
            gains,
            integral: 0,
            // The gains' D filter: its cut-off, with output 0.
            d_filter: gains.d_filter,
            last_error: None,
            following_error: 0,
            saturated: false,
        }
    }

    /// The gains.
    #[must_use]
    pub const fn gains(&self) -> PositionGains {
        self.gains
    }

    /// Replaces the gains, keeping the states (the D filter's output too, under its new cut-off).
    pub fn set_gains(&mut self, gains: PositionGains) {
        self.gains = gains;
        self.d_filter.retune(&gains.d_filter);
    }

    /// Empties the integrator and the D filter (on enable).
    pub fn reset(&mut self) {
        self.integral = 0;
        self.d_filter.preset(0);
        self.last_error = None;
        self.saturated = false;
    }

    /// Presets the integrator (bumpless transfer).
    pub fn set_integral(&mut self, current: Amps) {
        self.integral = i64::from(current.to_bits()) << 16;
    }

    /// The integrator's current (floor).
    #[must_use]
    pub fn integral(&self) -> Amps {
        q32_to_amps(self.integral)
    }

    /// The D filter (its coefficient is 1 - exp(-390.61 rad/s * 0.4 ms)).
    #[must_use]
    pub const fn d_filter(&self) -> &LowPass {
        &self.d_filter
    }

    /// The following error of the last step, `theta_ref - theta` in increments (0x60F4).
    #[must_use]
    pub const fn following_error(&self) -> i32 {
        self.following_error
    }

    /// The limit was active in the last step.
    #[must_use]
    pub const fn saturated(&self) -> bool {
        self.saturated
    }

    /// One slow tick: the current demand for the position demand `theta_ref`, the measured position `theta`, the
    /// demanded velocity `w_ref` and acceleration `a_ref` (feedforward; zero where S1 L762-768 disables them),
    /// limited to `+-limit` (a negative limit counts as 0).
    pub fn step(
        &mut self,
        theta_ref: Increments,
        theta: Increments,
        w_ref: IncPerTick,
        a_ref: IncPerTick2,
        limit: Amps,
    ) -> Amps {
        self.step_with_torque(theta_ref, theta, w_ref, a_ref, Amps::ZERO, limit)
    }

    /// [`Self::step`] with a torque feedforward `torque` (the master's torque offset 0x60B2 as a current, IDX L977:
    /// "optional torque feed forward input" of CSP) added to the PID's output before the limit, so that the limit
    /// bounds the sum and the back-calculation keeps the integrator from winding against it.
    pub fn step_with_torque(
        &mut self,
        theta_ref: Increments,
        theta: Increments,
        w_ref: IncPerTick,
        a_ref: IncPerTick2,
        torque: Amps,
        limit: Amps,
    ) -> Amps {
        let raw = theta_ref.wrapping_sub(theta);
        self.following_error = raw;
        // Difference of two wrapping errors: exact while |change per tick| < 2^31.
        let diff = match self.last_error {
            Some(last) => raw.wrapping_sub(last),
            None => 0,
        };
        self.last_error = Some(raw);
        let d = self.d_filter.step(diff.clamp(-DIFF_LIMIT, DIFF_LIMIT) << 16);
        let e = raw.clamp(-ERROR_LIMIT, ERROR_LIMIT);
        let g = &self.gains;
        // Every term within +-2^47 (2^-32 A), the integrator too: the sum stays within +-2^51.
        let xi_e = self.integral.wrapping_add(clamp_term(g.ki_ts.apply(e)));
        let u = clamp_term(g.kp.apply(e))
            .wrapping_add(xi_e)
            .wrapping_add(clamp_term(g.kd.apply(d)))
            .wrapping_add(clamp_term(g.ff_velocity.apply(w_ref.to_bits())))
            .wrapping_add(clamp_term(g.ff_acceleration.apply(a_ref.to_bits())))
            .wrapping_add(friction_feedforward(g.ff_friction, w_ref, a_ref, e))
            .wrapping_add(i64::from(torque.to_bits()) << 16);
        let l = limit_q32(limit);
        let u_sat = u.max(l.wrapping_neg()).min(l);
        self.saturated = u_sat != u;
        self.integral = clamp_term(xi_e.wrapping_add(back_calculation(g.kb, u_sat, u)));
        q32_to_amps(u_sat)
    }
}

/// The friction feedforward of one step (module documentation, "Friction feedforward"): `ff` with the sign of the
/// demanded velocity, or at a standing demand with the sign of the error `e` outside the band, else 0.
#[inline(always)]
fn friction_feedforward(ff: i64, w_ref: IncPerTick, a_ref: IncPerTick2, e: i32) -> i64 {
    let sign = match (w_ref.to_bits(), a_ref.to_bits()) {
        (0, 0) => {
            i32::from(e > STANDSTILL_FRICTION_BAND_INC).wrapping_sub(i32::from(e < -STANDSTILL_FRICTION_BAND_INC))
        }
        (w, _) => w.signum(),
    };
    ff.wrapping_mul(i64::from(sign))
}

/// The cascade structure ([`PositionStructure::Cascade`]): `w_cmd = Kv (theta_ref - theta) + w_ref`, then the PI
/// velocity controller with its feedforward (EPOS4 dual-loop main loop, S1 L9149-9156).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct CascadePositionController {
    /// Kv: 2^-16 inc/tick per increment.
    kv: ScaledGain,
    /// The inner velocity loop.
    pub velocity: VelocityController,
    following_error: i32,
}

impl CascadePositionController {
    /// Position gain `kv_milli_per_s` in 0.001/s (S1's 0x30AE:01 "main loop P gain" is in 1/s, and the raw
    /// dictionary values are 1000 times the display values, digest §7 row 3) around the velocity controller
    /// `velocity`.
    #[must_use]
    pub fn new(kv_milli_per_s: u32, velocity: VelocityController) -> Self {
        // Kv Ts in 2^-16 inc/tick per inc = raw * 1e-3 / f_s * 2^16.
        let kv = ScaledGain::from_ratio(&[u128::from(kv_milli_per_s), 1 << 16], &[1000, u128::from(SLOW_TICK_HZ)]);
        Self { kv, velocity, following_error: 0 }
    }

    /// The position gain (2^-16 inc/tick per increment).
    #[must_use]
    pub const fn kv(&self) -> ScaledGain {
        self.kv
    }

    /// The following error of the last step (increments).
    #[must_use]
    pub const fn following_error(&self) -> i32 {
        self.following_error
    }

    /// One slow tick: position error to a velocity command (plus `w_ref`), then the velocity loop with the
    /// estimated velocity `w_meas` and the acceleration feedforward `a_ref`, limited to `+-limit`.
    pub fn step(
        &mut self,
        theta_ref: Increments,
        theta: Increments,
        w_ref: IncPerTick,
        w_meas: IncPerTick,
        a_ref: IncPerTick2,
        limit: Amps,
    ) -> Amps {
        let raw = theta_ref.wrapping_sub(theta);
        self.following_error = raw;
        let e = raw.clamp(-ERROR_LIMIT, ERROR_LIMIT);
        // |Kv e| is clamped into the I16F16 velocity range before adding the feedforward.
        let w_cmd = sat_i32(self.kv.apply(e));
        let w_cmd = IncPerTick::from_bits(w_cmd.saturating_add(w_ref.to_bits()));
        self.velocity.step(w_cmd, w_meas, a_ref, limit)
    }
}
