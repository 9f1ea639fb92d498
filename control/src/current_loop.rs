//! The field-oriented current controller: one call per 25 kHz PWM period (tier 1, `ARCHITECTURE.md`).
//!
//! ```text
//! i_abc -> Clarke -> Park(theta) -> PI d, PI q -> |v_dq| <= f Vbus / sqrt(3) -> inverse Park(theta)
//!       -> SVPWM with bus compensation -> duty clamp -> compare values
//!                    ^                         |
//!                    +--- u_sat (both axes) ---+  back-calculation anti-windup
//! ```
//!
//! - Current controller: digital PI with back-calculation anti-windup at Ts = 0.04 ms (EPOS4, S1 L440-482), one per
//!   axis, gains from IDX 0x30A0 ([`super::pi`]).
//! - Voltage limit: the d/q vector is scaled onto the circle of the EPOS4 limit U_max = 0.9 V_DC (S1 L929-930),
//!   preserving its angle; the limited vector (the one actually applied) feeds both integrators' back-calculation, so
//!   neither axis winds up while the other holds the vector on the limit. See [`super::svpwm`] for the units.
//! - The bus voltage is measured in the same interrupt and compensated in the same call (one division).
//!
//! The call is branch-free apart from the conditional moves of min/max and the limit's select (the square root of
//! the limit is computed every call and selected: one basic block lets LLVM keep every product a single 32x32->64
//! multiply); no loops, no table look-up but the sin/cos segments. Must not panic for any input (property test
//! `current_loop_never_panics`).
//!
//! Cost (Cortex-M4, release + LTO, rustc 1.95, QEMU instruction count with TIM2 at one count per instruction,
//! `shared/spec/target-qemu.md`): 183 instructions in `foc_step` itself, 191 measured around the call; the budget
//! is 200. The same for every input (branch-free).

use super::angle::ElectricalAngle;
use super::frames::{Abc, Amps, Dq, Volts};
use super::pi::{PiController, PiGains};
use super::svpwm::{DutyClamp, Modulator, VoltageLimit};
use super::transforms::{clarke_x4, rotate_hi_to_alpha_beta, rotate_hi_to_dq};
use super::trig::sin_cos;
use crate::power::PwmCommand;

/// Parameters of the current controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CurrentLoopConfig {
    /// d-axis PI gains.
    pub gains_d: PiGains,
    /// q-axis PI gains (EPOS4/IDX have one parameter set for both axes: 0x30A0, S2 L4410).
    pub gains_q: PiGains,
    /// Voltage-vector limit (default: EPOS4's 90 % of the bus).
    pub limit: VoltageLimit,
    /// Duty clamp for the shunt sampling window (default: 2.4 us low-side on-time).
    pub clamp: DutyClamp,
}

impl CurrentLoopConfig {
    /// The same gains on both axes from IDX 0x30A0:01 (uV/A) and 0x30A0:02 (uV/(A*ms)), EPOS4 limit, default clamp.
    #[must_use]
    pub fn from_idx_0x30a0(p_gain_uv_per_a: u32, i_gain_uv_per_a_ms: u32) -> Self {
        Self::with_gains(PiGains::from_idx_0x30a0(p_gain_uv_per_a, i_gain_uv_per_a_ms))
    }

    /// `gains` on both axes (already converted, e.g. by tier 2), EPOS4 limit, default clamp.
    #[must_use]
    pub const fn with_gains(gains: PiGains) -> Self {
        Self { gains_d: gains, gains_q: gains, limit: VoltageLimit::EPOS4, clamp: DutyClamp::DEFAULT }
    }
}

/// What the current loop reads each period.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FocInput {
    /// Calibrated phase currents (positive = into the motor).
    pub i_abc: Abc<Amps>,
    /// Electrical angle of the rotor d axis.
    pub angle: ElectricalAngle,
    /// Current demand in the rotor frame.
    pub i_ref: Dq<Amps>,
    /// Measured DC-bus voltage.
    pub v_bus: Volts,
}

/// What the current loop produces each period.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FocOutput {
    /// Compare values for the next period, phases A, B, C, in 0..=the clamp's maximum (<= `PWM_PERIOD_TICKS`).
    pub compare_ticks: Abc<u16>,
    /// Measured current in the rotor frame (for 0x30D1 "current actual" and the observers).
    pub i_dq: Dq<Amps>,
    /// The voltage applied (after the limit), rotor frame.
    pub v_dq: Dq<Volts>,
    /// The voltage limit was active this period.
    pub saturated: bool,
}

impl FocOutput {
    /// The compare values as the power stage's command, outputs enabled (the caller decides whether to enable).
    #[must_use]
    pub const fn pwm_command(&self) -> PwmCommand {
        PwmCommand { duty: [self.compare_ticks.a, self.compare_ticks.b, self.compare_ticks.c], enabled: true }
    }
}

/// The d/q current controller: two PI states and the modulator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CurrentController {
    d: PiController,
    q: PiController,
    modulator: Modulator,
}

impl CurrentController {
    /// A controller with empty integrators.
    #[must_use]
    pub fn new(config: CurrentLoopConfig) -> Self {
        Self {
            d: PiController::new(config.gains_d),
            q: PiController::new(config.gains_q),
            modulator: Modulator::new(config.limit, config.clamp),
        }
    }

    /// Empties both integrators (on enable, after a fault).
    pub fn reset(&mut self) {
        self.d.reset();
        self.q.reset();
    }

    /// Replaces the gains (both integrators kept).
    pub fn set_gains(&mut self, d: PiGains, q: PiGains) {
        self.d.set_gains(d);
        self.q.set_gains(q);
    }

    /// The d-axis PI.
    #[must_use]
    pub const fn pi_d(&self) -> &PiController {
        &self.d
    }

    /// The q-axis PI.
    #[must_use]
    pub const fn pi_q(&self) -> &PiController {
        &self.q
    }

    /// The modulator (limit and clamp in effect).
    #[must_use]
    pub const fn modulator(&self) -> &Modulator {
        &self.modulator
    }

    /// One current-loop period: Clarke, Park, PI d/q, voltage-vector limit with back-calculation, inverse Park,
    /// SVPWM with bus compensation and the duty clamp.
    #[inline]
    pub fn step(&mut self, input: &FocInput) -> FocOutput {
        let mut out = FocOutput::default();
        self.step_into(input, &mut out);
        out
    }

    /// [`Self::step`] writing into `out`. Each result is stored as soon as it is known, which frees registers for
    /// the rest of the step (fewer stack spills on Cortex-M4 than building the output at the end).
    #[inline(always)]
    pub fn step_into(&mut self, input: &FocInput, out: &mut FocOutput) {
        let sc = sin_cos(input.angle);
        // Clarke times 4 (|4 alpha|, |4 beta| < 2^30) straight into the Park rotation: no overflow, no shifts.
        let (alpha4, beta4) = clarke_x4(input.i_abc);
        let (i_d, i_q) = rotate_hi_to_dq(alpha4, beta4, sc);
        let (i_d, i_q) = (Amps::from_bits(i_d), Amps::from_bits(i_q));
        out.i_dq = Dq { d: i_d, q: i_q };
        let e_d = PiController::error_x256(input.i_ref.d, i_d);
        let e_q = PiController::error_x256(input.i_ref.q, i_q);
        let (xi_d, u_d) = self.d.integrate_bits(e_d);
        let (xi_q, u_q) = self.q.integrate_bits(e_q);
        let gain = self.modulator.bus_gain(input.v_bus);
        // Limit in d/q (the vector magnitude is the same in both frames), inverse Park inside (|n| <= 2^24 bits:
        // the rotation cannot overflow).
        let lim = self.modulator.limit_vector(u_d, u_q, gain, |d, q| rotate_hi_to_alpha_beta(d, q, sc));
        out.v_dq = Dq { d: Volts::from_bits(lim.volts.0), q: Volts::from_bits(lim.volts.1) };
        out.saturated = lim.saturated;
        self.d.back_calculate_bits(xi_d, u_d, lim.volts.0);
        self.q.back_calculate_bits(xi_q, u_q, lim.volts.1);
        out.compare_ticks = self.modulator.compare_ticks(lim.normalised.0, lim.normalised.1).0;
    }
}

/// The current-loop step behind a stable, non-inlined symbol: what the QEMU bench measures and what the tier-1
/// interrupt may call. Same as [`CurrentController::step`].
#[inline(never)]
pub fn foc_step(controller: &mut CurrentController, input: &FocInput) -> FocOutput {
    controller.step(input)
}

/// [`foc_step`] writing into `output` (see [`CurrentController::step_into`]).
#[inline(never)]
pub fn foc_step_into(controller: &mut CurrentController, input: &FocInput, output: &mut FocOutput) {
    controller.step_into(input, output);
}
