//! The position and velocity loops of tier 2 with their gains taken from the dictionary (0x30A1, 0x30A2), and
//! the velocity estimate they close on (0x3000:02 bits 7..4: low-pass filter 0x30A2:05 or the observer 0x30A3).
//!
//! EPOS4's structure (S1 Fig. 2-5, `shared/spec/control-and-protection.md` §1.4-§1.6): in the position modes the
//! position PID with velocity and acceleration feedforward (and the project's friction feedforward 0x30A1:06,
//! `crate::control::position`) commands the current directly; in the velocity modes
//! the velocity PI with feedforward does. The active [`LoopDemand`] chooses which; torque demands bypass both.
//! When the demand changes kind (a mode change while enabled, a stop from CSP that runs on the velocity loop), the
//! newly active controller's integrator is preset with the last current, so the output does not jump (bumpless
//! transfer).
//!
//! In the dual loop (0x3000:02 main sensor 2, [`super::dual_loop`]; EPOS4 AN ch. 10) the position demands run
//! through the main loop instead ([`MainLoop`], 0x30AE): the load position's error, scheduled gain, plus the
//! demand's velocity, is the velocity loop's demand, and the velocity loop closes on the motor encoder as in the
//! velocity modes; the axis hands the loops the load position (in motor increments) as the position.
//!
//! Gains are converted when their dictionary values change ([`Loops::refresh`] compares the raw values, a few
//! loads and compares per tick), never per tick.

use super::LoopDemand;
use crate::control::demand::DemandScale;
use crate::control::dual_loop::{MainLoop, MainLoopGains};
use crate::control::frames::Amps;
use crate::control::observer::{ObserverGains, VelocityObserver};
use crate::control::position::{Increments, PositionController, PositionGains};
use crate::control::trajectory::Velocity;
use crate::control::velocity::{IncPerTick, IncPerTick2, VelocityController, VelocityGains};
use crate::control::velocity_estimate::{LowPassVelocityEstimator, PositionWindow};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// Where the velocity estimate comes from (0x3000:02 bits 7..4, S2 L3813-3850).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum VelocityEstimate {
    /// 1: the position difference per tick through the first-order low-pass of 0x30A2:05.
    #[default]
    LowPass,
    /// 2: EPOS4's observer (0x30A3).
    Observer,
}

impl VelocityEstimate {
    /// From 0x3000:02; anything but 2 in bits 7..4 is the low-pass estimate.
    #[must_use]
    pub const fn from_control_structure(raw: u32) -> Self {
        if (raw >> 4) & 0xF == 2 {
            Self::Observer
        } else {
            Self::LowPass
        }
    }
}

/// The raw dictionary values the loops are built from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct GainObjects {
    position: [u32; 7],
    velocity: [u32; 4],
    cutoff_hz: u32,
    observer: [u32; 5],
    torque_constant: u32,
    inc_per_rev: u32,
    structure: u32,
    /// 0x30AE:01..03 and the load scale they are converted with (0 / 0: no dual loop).
    main_loop: [u32; 3],
    load_scale: (i64, i64),
}

impl GainObjects {
    fn read(d: &Dictionary, load_scale: (i64, i64)) -> Self {
        Self {
            position: [
                d.get(h::POSITION_CONTROLLER_P_GAIN),
                d.get(h::POSITION_CONTROLLER_I_GAIN),
                d.get(h::POSITION_CONTROLLER_D_GAIN),
                d.get(h::POSITION_CONTROLLER_FF_VELOCITY_GAIN),
                d.get(h::POSITION_CONTROLLER_FF_ACCELERATION_GAIN),
                d.get(h::POSITION_CONTROLLER_FF_FRICTION),
                d.get(h::POSITION_CONTROLLER_D_FILTER_CUTOFF),
            ],
            velocity: [
                d.get(h::VELOCITY_CONTROLLER_P_GAIN),
                d.get(h::VELOCITY_CONTROLLER_I_GAIN),
                d.get(h::VELOCITY_CONTROLLER_FF_VELOCITY_GAIN),
                d.get(h::VELOCITY_CONTROLLER_FF_ACCELERATION_GAIN),
            ],
            cutoff_hz: d.get(h::VELOCITY_FILTER_CUTOFF),
            observer: [
                d.get(h::OBSERVER_POSITION_CORRECTION_GAIN),
                d.get(h::OBSERVER_VELOCITY_CORRECTION_GAIN),
                d.get(h::OBSERVER_LOAD_CORRECTION_GAIN),
                d.get(h::OBSERVER_FRICTION),
                d.get(h::OBSERVER_INERTIA),
            ],
            torque_constant: d.get(h::MOTOR_TORQUE_CONSTANT),
            inc_per_rev: d.get(h::MAIN_SENSOR_RESOLUTION),
            structure: d.get(h::CONTROL_STRUCTURE),
            main_loop: [
                d.get(h::DUAL_LOOP_GAIN_LOW),
                d.get(h::DUAL_LOOP_GAIN_HIGH),
                d.get(h::DUAL_LOOP_SCHEDULING_WEIGHT),
            ],
            load_scale,
        }
    }
}

/// Which controller produced the last current.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
enum Active {
    #[default]
    None,
    Position,
    Velocity,
    Torque,
}

/// What the loops produced in one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoopOutput {
    /// The q-current demand.
    pub current: Amps,
    /// The controller's output was limited (statusword bit 11, internal limit active).
    pub saturated: bool,
    /// Position demand minus actual position (position control only, else 0), increments.
    pub following_error: i32,
}

/// The loops and the velocity estimate.
#[derive(Clone, Debug)]
pub struct Loops {
    objects: GainObjects,
    estimate: VelocityEstimate,
    low_pass: LowPassVelocityEstimator,
    observer: VelocityObserver,
    position: PositionController,
    velocity: VelocityController,
    /// The dual loop's main loop; it runs while [`Self::set_dual_loop`] says the position is the load's.
    main_loop: MainLoop,
    dual_loop: bool,
    /// The load position's fraction of a motor increment (`U0F16`), beyond the position the axis hands the step.
    load_fraction: u16,
    /// The dual loop's load scale (`super::dual_loop::LoadScale` as num/den; 0/0 without it).
    load_scale: (i64, i64),
    active: Active,
    last_current: Amps,
    velocity_estimate: IncPerTick,
    /// The torque feedforward of the next step, per mille of rated torque ([`Self::set_torque_feedforward`]).
    torque_permille: i32,
    /// The position sensor or its resolution changed: the estimators restart at the next position.
    restart_estimate: bool,
}

impl Loops {
    /// Loops with the gains of `d`.
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut loops = Self {
            objects: GainObjects::default(),
            estimate: VelocityEstimate::LowPass,
            low_pass: LowPassVelocityEstimator::new(0),
            observer: VelocityObserver::new(ObserverGains::default()),
            position: PositionController::new(PositionGains::default()),
            velocity: VelocityController::new(VelocityGains::ZERO),
            main_loop: MainLoop::new(MainLoopGains::default()),
            dual_loop: false,
            load_fraction: 0,
            load_scale: (0, 0),
            active: Active::None,
            last_current: Amps::ZERO,
            velocity_estimate: IncPerTick::ZERO,
            torque_permille: 0,
            restart_estimate: true,
        };
        loops.refresh(d);
        loops
    }

    /// Re-reads 0x30A1, 0x30A2, 0x30A3, 0x3000:02/:05 and 0x3001:05 and converts them when they changed.
    pub fn refresh(&mut self, d: &Dictionary) {
        let o = GainObjects::read(d, self.load_scale);
        if o == self.objects {
            return;
        }
        let n = o.inc_per_rev.max(1);
        let [pp, pi, pd, pfv, pfa, pfc, d_cutoff] = o.position;
        self.position.set_gains(
            PositionGains::from_idx_0x30a1(pp, pi, pd, pfv, pfa, n)
                .with_friction_feedforward(pfc)
                .with_d_filter_cutoff(d_cutoff),
        );
        let [vp, vi, vfv, vfa] = o.velocity;
        self.velocity.set_gains(VelocityGains::from_idx_0x30a2(vp, vi, vfv, vfa, n));
        if o.cutoff_hz != self.objects.cutoff_hz || self.objects == GainObjects::default() {
            self.low_pass = LowPassVelocityEstimator::new(o.cutoff_hz);
        }
        let [lt, lw, ll, fr, j] = o.observer;
        self.observer.set_gains(ObserverGains::from_idx_0x30a3(lt, lw, ll, fr, j, o.torque_constant, n));
        let [k_low, k_high, weight] = o.main_loop;
        let (num, den) = o.load_scale;
        let (num, den) = (u64::try_from(num).unwrap_or(1), u64::try_from(den).unwrap_or(1));
        self.main_loop = MainLoop::new(MainLoopGains::from_idx_0x30ae(k_low, k_high, weight, num, den));
        let estimate = VelocityEstimate::from_control_structure(o.structure);
        if o.inc_per_rev != self.objects.inc_per_rev || estimate != self.estimate {
            self.restart_estimate = true;
        }
        self.estimate = estimate;
        self.objects = o;
    }

    /// Updates the velocity estimate with the position of this tick, tier 1's window of encoder positions (if the
    /// encoder is the position sensor) and the q current applied during the last one (the observer's model input);
    /// returns it. Only the configured estimator runs; a change of 0x3000:02 restarts it from the present position.
    /// The low-pass estimate uses the window's averaged displacement when there is one
    /// ([`LowPassVelocityEstimator::update_window`]), else the position difference; the observer corrects with the
    /// position.
    pub fn estimate(&mut self, position: i32, window: Option<PositionWindow>, current: Amps) -> IncPerTick {
        if core::mem::take(&mut self.restart_estimate) {
            self.reset_estimate(position);
        }
        self.velocity_estimate = match (self.estimate, window) {
            (VelocityEstimate::LowPass, Some(w)) => self.low_pass.update_window(w),
            (VelocityEstimate::LowPass, None) => self.low_pass.update(Increments(position)),
            (VelocityEstimate::Observer, _) => self.observer.step(Increments(position), current),
        };
        self.velocity_estimate
    }

    /// The position sensor changed (its coordinates jump): the estimators restart at the next position.
    pub fn restart_estimate(&mut self) {
        self.restart_estimate = true;
    }

    /// Restarts the estimators at `position` (sensor change, re-enable).
    pub fn reset_estimate(&mut self, position: i32) {
        self.low_pass.reset();
        self.observer.reset(Increments(position));
        self.velocity_estimate = IncPerTick::ZERO;
    }

    /// The last velocity estimate.
    #[must_use]
    pub const fn velocity_estimate(&self) -> IncPerTick {
        self.velocity_estimate
    }

    /// The estimate source in use.
    #[must_use]
    pub const fn estimate_source(&self) -> VelocityEstimate {
        self.estimate
    }

    /// The position the axis hands [`Self::step`] is the load's (the dual loop's main sensor): position demands
    /// run through the main loop and the velocity loop.
    /// `fraction` is the load position's fraction of a motor increment beyond that position (`U0F16`).
    pub fn set_dual_loop(&mut self, on: bool, fraction: u16) {
        self.dual_loop = on;
        self.load_fraction = fraction;
    }

    /// The dual loop's load scale (taken with the sensor configuration): the main loop's gain scheduling counts
    /// load increments through it (converted at the next [`Self::refresh`]).
    pub fn set_load_scale(&mut self, scale: Option<super::dual_loop::LoadScale>) {
        self.load_scale = scale.map_or((0, 0), |s| (s.num, s.den));
    }

    /// Clears the controllers (drive function disabled).
    pub fn reset(&mut self) {
        self.position.reset();
        self.velocity.reset();
        self.active = Active::None;
        self.last_current = Amps::ZERO;
    }

    /// The position coordinates changed (homing, at standstill): the PID's state is the error, which does not
    /// change; the estimators restart from `position`, the actual position in the new coordinates.
    pub fn rereference(&mut self, position: i32) {
        self.reset_estimate(position);
    }

    /// The torque feedforward for the next [`Self::step`] only, per mille of rated torque: the torque offset 0x60B2
    /// of CSP and CSV (IDX L977, L6345), set by the cyclic modes before each step. Taken by the step, so every
    /// other activity runs without it and needs no bookkeeping to end it.
    pub fn set_torque_feedforward(&mut self, permille: i32) {
        self.torque_permille = permille;
    }

    /// One tick: the current for `demand` at the actual `position`, limited to `limit`. The torque feedforward
    /// ([`Self::set_torque_feedforward`]) is converted through the demand scale as CST converts 0x60B2 (clamped
    /// to +-0x6072, then to the current limit) and added to the position or velocity controller's output before
    /// `limit`, so that the limit bounds the sum and the back-calculation keeps the integrator from winding
    /// against it; torque demands ignore it (CST adds 0x60B2 to 0x6071 before the interpolation).
    pub fn step(&mut self, demand: &LoopDemand, position: i32, limit: Amps, scale: &DemandScale) -> LoopOutput {
        let feedforward = core::mem::take(&mut self.torque_permille);
        // One conversion serves the torque demand and the feedforward (flash: the demand scale is inlined).
        let permille = if let LoopDemand::Torque { permille } = *demand { permille } else { feedforward };
        let torque = if permille == 0 {
            Amps::ZERO
        } else {
            let clamped = i16::try_from(permille).unwrap_or(if permille < 0 { i16::MIN } else { i16::MAX });
            scale.torque_to_current(clamped, 0).1
        };
        let (current, saturated, following_error, active) = match *demand {
            LoopDemand::Position(sp) if self.dual_loop => self.step_dual_loop(&sp, position, torque, limit),
            LoopDemand::Position(sp) => {
                if self.active != Active::Position {
                    self.position.reset();
                    self.position.set_integral(self.last_current);
                }
                let w = IncPerTick::from_bits(sp.velocity.to_inc_per_tick_q16());
                let a = IncPerTick2::from_bits(sp.acceleration.to_inc_per_tick2_q16());
                let i = self.position.step_with_torque(
                    Increments(sp.position_i32()),
                    Increments(position),
                    w,
                    a,
                    torque,
                    limit,
                );
                (i, self.position.saturated(), self.position.following_error(), Active::Position)
            }
            LoopDemand::Velocity { velocity, acceleration } => {
                if self.active != Active::Velocity {
                    self.velocity.reset();
                    self.velocity.set_integral(self.last_current);
                }
                let w = IncPerTick::from_bits(velocity.to_inc_per_tick_q16());
                let a = IncPerTick2::from_bits(acceleration.to_inc_per_tick2_q16());
                let i = self.velocity.step_with_torque(w, self.velocity_estimate, a, torque, limit);
                (i, self.velocity.saturated(), 0, Active::Velocity)
            }
            LoopDemand::Torque { .. } => {
                let i = torque;
                let l = limit.to_bits().max(0);
                // max/min as `Drive::clamp_internal_demand` (no formatted panic for the bounds' order).
                let bits = i.to_bits().max(l.wrapping_neg()).min(l);
                (Amps::from_bits(bits), bits != i.to_bits(), 0, Active::Torque)
            }
        };
        self.active = active;
        self.last_current = current;
        LoopOutput { current, saturated, following_error }
    }

    /// The dual loop's step (EPOS4 AN ch. 10.3/10.4): the main loop turns the load position's error into the
    /// velocity demand of the velocity loop, which closes on the motor encoder's estimate with the demand's
    /// acceleration as feedforward. The velocity controller is the one of the velocity modes, preset bumplessly
    /// when the position control begins.
    #[inline(never)]
    fn step_dual_loop(
        &mut self,
        sp: &crate::control::trajectory::Setpoint,
        load_position: i32,
        torque: Amps,
        limit: Amps,
    ) -> (Amps, bool, i32, Active) {
        if self.active != Active::Position {
            self.velocity.reset();
            self.velocity.set_integral(self.last_current);
        }
        let w_ref = IncPerTick::from_bits(sp.velocity.to_inc_per_tick_q16());
        let a = IncPerTick2::from_bits(sp.acceleration.to_inc_per_tick2_q16());
        let w =
            self.main_loop.step(Increments(sp.position_i32()), Increments(load_position), self.load_fraction, w_ref);
        let i = self.velocity.step_with_torque(w, self.velocity_estimate, a, torque, limit);
        (i, self.velocity.saturated(), self.main_loop.following_error(), Active::Position)
    }
}

/// A velocity of the loops' form ([`IncPerTick`]) in the trajectory generator's form.
#[must_use]
pub fn velocity_of(v: IncPerTick) -> Velocity {
    Velocity::from_bits(i64::from(v.to_bits()) << 16)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::trajectory::{Acceleration, Setpoint};

    fn dict() -> Dictionary {
        Dictionary::new(1)
    }

    #[test]
    fn control_structure_selects_the_estimate() {
        assert_eq!(VelocityEstimate::from_control_structure(0x0001_0111), VelocityEstimate::LowPass);
        assert_eq!(VelocityEstimate::from_control_structure(0x0001_0121), VelocityEstimate::Observer);
    }

    /// 0x30A1:07 acts (an object that accepts a write acts on it): a write reaches the position PID's D filter at
    /// the next refresh, as the coefficient of a first-order low-pass at the new cut-off.
    #[test]
    fn d_filter_cutoff_object_reaches_the_position_pid() {
        use crate::control::velocity_estimate::LowPass;
        use crate::od::generated::handles as h;
        let mut d = dict();
        let mut loops = Loops::new(&d);
        let epos4 = LowPass::from_cutoff_millirad_per_s(390_610).coefficient();
        assert_eq!(loops.position.d_filter().coefficient(), epos4, "the default: EPOS4's 390.61 rad/s");
        d.set(h::POSITION_CONTROLLER_D_FILTER_CUTOFF, 1_903_400);
        loops.refresh(&d);
        let elastic = LowPass::from_cutoff_millirad_per_s(1_903_400).coefficient();
        assert_eq!(loops.position.d_filter().coefficient(), elastic);
    }

    #[test]
    fn position_error_gives_restoring_current_and_following_error() {
        let d = dict();
        let mut loops = Loops::new(&d);
        let sp = Setpoint { position: 100, ..Setpoint::default() };
        let out = loops.step(&LoopDemand::Position(sp), 0, Amps::from_milliamps(10_000), &DemandScale::reference());
        assert_eq!(out.following_error, 100);
        assert!(out.current > Amps::ZERO);
        let out = loops.step(&LoopDemand::Position(sp), 200, Amps::from_milliamps(10_000), &DemandScale::reference());
        assert_eq!(out.following_error, -100);
        assert!(out.current < Amps::ZERO);
    }

    #[test]
    fn switching_to_velocity_control_is_bumpless() {
        let d = dict();
        let mut loops = Loops::new(&d);
        let sp = Setpoint { position: 40, ..Setpoint::default() };
        let limit = Amps::from_milliamps(10_000);
        let scale = DemandScale::reference();
        let before = loops.step(&LoopDemand::Position(sp), 0, limit, &scale).current;
        let v = LoopDemand::Velocity { velocity: Velocity::ZERO, acceleration: Acceleration::ZERO };
        let after = loops.step(&v, 0, limit, &scale).current;
        // Zero velocity error: the velocity PI outputs its preset integral (plus one I step of zero).
        assert_eq!(after, before);
    }

    /// IDX L977/L6345, EPOS3 L7733: 0x60B2 is a torque feedforward in CSP and CSV. With no velocity error and an
    /// empty integrator the velocity controller's output is exactly the offset's conversion (200 per mille of the
    /// 3.2 A rated current = 640 mA, the demand scale's rounding), for the one step it was set for: the next step
    /// without it is back at 0 A (the loops take it, so no other activity inherits it).
    #[test]
    fn torque_feedforward_adds_its_conversion_for_one_step() {
        let d = dict();
        let mut loops = Loops::new(&d);
        let scale = DemandScale::reference();
        let limit = Amps::from_milliamps(10_000);
        let hold = LoopDemand::Velocity { velocity: Velocity::ZERO, acceleration: Acceleration::ZERO };
        assert_eq!(loops.step(&hold, 0, limit, &scale).current, Amps::ZERO);
        loops.set_torque_feedforward(200);
        let out = loops.step(&hold, 0, limit, &scale);
        assert_eq!(out.current, scale.torque_to_current(200, 0).1);
        assert_eq!(out.current.to_milliamps(), 640);
        assert!(!out.saturated);
        assert_eq!(loops.step(&hold, 0, limit, &scale).current, Amps::ZERO, "taken by the step it was set for");
        // On the position controller likewise (zero error, empty integrator), negative.
        let sp = Setpoint { position: 0, ..Setpoint::default() };
        loops.reset();
        loops.set_torque_feedforward(-200);
        assert_eq!(loops.step(&LoopDemand::Position(sp), 0, limit, &scale).current.to_milliamps(), -640);
        // A torque demand (CST) ignores it: 0x60B2 is already in 0x6071 + 0x60B2.
        loops.set_torque_feedforward(200);
        assert_eq!(loops.step(&LoopDemand::Torque { permille: 0 }, 0, limit, &scale).current, Amps::ZERO);
    }

    /// The offset is limited as CST's torque is (0x6072 = 100 per mille: 320 mA however large the offset), and
    /// the sum with the controller's output by the current limit, inside the controller: in a lasting saturation
    /// (1 inc/tick of velocity error against a 2 A limit, 640 mA of feedforward) the back-calculation leaves the
    /// integrator what the limit leaves the controller, `limit - feedforward - Kp e - FFv v` (+ Ki Ts e), so once
    /// the error and the offset are gone the output is that integral, far below the limit. A feedforward added
    /// after the limit instead would leave 640 mA more in the integrator. Tolerance: two integral steps of
    /// Ki Ts e (7.7 mA each at 0x30A2:02 = 5 A/rad, 4096 inc/rev) and 1 mA of rounding.
    #[test]
    fn torque_feedforward_is_limited_and_does_not_wind_the_integrator() {
        let d = dict();
        let limit = Amps::from_milliamps(10_000);
        let hold = LoopDemand::Velocity { velocity: Velocity::ZERO, acceleration: Acceleration::ZERO };
        let capped = DemandScale::from_od(3200, 10_000, 3125, 100);
        let mut loops = Loops::new(&d);
        loops.set_torque_feedforward(500);
        assert_eq!(loops.step(&hold, 0, limit, &capped).current, capped.torque_to_current(100, 0).1);
        assert_eq!(loops.step(&hold, 0, limit, &capped).current, Amps::ZERO);

        let scale = DemandScale::reference();
        let limit = Amps::from_milliamps(2_000);
        let moving = LoopDemand::Velocity { velocity: Velocity::from_bits(1 << 32), acceleration: Acceleration::ZERO };
        // One step from rest without feedforward: Kp e + FFv v + Ki Ts e.
        let first = Loops::new(&d).step(&moving, 0, limit, &scale).current.to_milliamps();
        let mut loops = Loops::new(&d);
        for _ in 0..2_000 {
            loops.set_torque_feedforward(200);
            let _ = loops.step(&moving, 0, limit, &scale);
        }
        loops.set_torque_feedforward(200);
        let out = loops.step(&moving, 0, limit, &scale);
        assert!(out.saturated && out.current == limit, "the sum is held at the limit: {out:?}");
        let released = loops.step(&hold, 0, limit, &scale).current.to_milliamps();
        let expected = 2_000 - 640 - first;
        assert!((released - expected).abs() <= 2 * 8 + 1, "released at {released} mA, expected {expected} mA");
    }

    #[test]
    fn torque_demand_is_limited() {
        let d = dict();
        let mut loops = Loops::new(&d);
        let scale = DemandScale::reference();
        let out = loops.step(&LoopDemand::Torque { permille: 1000 }, 0, Amps::from_milliamps(1_000), &scale);
        assert_eq!(out.current, Amps::from_milliamps(1_000));
        assert!(out.saturated);
        let out = loops.step(&LoopDemand::Torque { permille: -100 }, 0, Amps::from_milliamps(1_000), &scale);
        assert!(!out.saturated);
        // 100 per mille of the 3.2 A rated current.
        assert!((out.current.to_milliamps() + 320).abs() <= 1, "{:?}", out.current);
    }
}
