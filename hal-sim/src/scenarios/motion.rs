//! Motion scenarios on the reference plant, driven through CiA 402 as a fieldbus master drives the drive: the
//! controlword and the targets are written into the dictionary, and in the cyclic modes a set-point is delivered
//! every master cycle (`Simulation::setpoint_received`, what the fieldbus layer calls at SYNC or the SM2 event).
//! `drive-sim csp` and `drive-sim csv-sweep` print these figures; `tests/tests/motion/cyclic.rs` asserts them.
//!
//! Every scenario starts from [`prepare_motion`]: the current-loop scenarios' preparation (offset calibration,
//! commissioning on the free shaft until the commutation is indexed), the rotor brought to rest, then «Shutdown»,
//! «Switch on», «Enable operation» in the scenario's mode through the controlword.

use core::f64::consts::PI;

use firmware::od::generated::handles as h;

use super::{prepare_plant, scenario_plant, Setup};
use crate::plant::{PlantParams, PERIOD_S};
use crate::sim::trace::Trace;
use crate::sim::{SimError, Simulation};

/// Increments per revolution of the reference encoder (1,024 lines, quadrature).
pub const INC_PER_REV: f64 = 4096.0;
/// PWM periods per slow tick.
const PERIODS_PER_SLOW_TICK: u64 = 10;

/// Builds the simulation of the scenario plant (the reference unless `drive-sim --plant` chose another:
/// [`scenario_plant`]), commissions it (see the module documentation) and enables it in `mode` (0x6060) through
/// the controlword, with the rotor at rest.
pub fn prepare_motion(seed: u64, mode: i8) -> Result<Simulation, SimError> {
    prepare_motion_on(scenario_plant(), seed, mode)
}

/// [`prepare_motion`] on the plant `params` (the drive's encoder objects follow its encoder,
/// [`Simulation::new`]).
pub fn prepare_motion_on(params: PlantParams, seed: u64, mode: i8) -> Result<Simulation, SimError> {
    let mut sim = prepare_plant_for_motion(params, seed)?;
    sim.enable_through_controlword(mode)?;
    Ok(sim)
}

/// [`prepare_motion_on`] up to the enabling: commissioned, the rotor at rest, the power stage off (where a master
/// writes the objects that are writable only then).
pub fn prepare_plant_for_motion(params: PlantParams, seed: u64) -> Result<Simulation, SimError> {
    let (mut sim, _) = prepare_plant(params, &Setup { seed, ..Setup::default() })?;
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, 0.0);
    sim.run(250);
    Ok(sim)
}

/// A jerk-limited point-to-point move as a master computes it: sin² acceleration ramps (the acceleration rises
/// and falls as `A sin²(pi t / T)`, so the jerk is bounded), a cruise at the peak velocity if the distance allows
/// one, and the mirror ramp down. Continuous time, f64, in increments and seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JerkLimitedMove {
    /// Start position, increments.
    pub start: f64,
    /// Distance (signed), increments.
    pub distance: f64,
    /// Peak velocity reached, inc/s (at most the requested one).
    pub peak_velocity: f64,
    /// Peak acceleration, inc/s².
    pub peak_acceleration: f64,
    /// Duration of each ramp, s.
    pub ramp_s: f64,
    /// Duration of the cruise, s.
    pub cruise_s: f64,
}

impl JerkLimitedMove {
    /// A move of `distance` increments from `start` with at most `max_velocity` inc/s and a peak acceleration of
    /// `peak_acceleration` inc/s² (the mean acceleration of a sin² ramp is half the peak).
    pub fn new(start: f64, distance: f64, max_velocity: f64, peak_acceleration: f64) -> Self {
        let mean = peak_acceleration / 2.0;
        let d = distance.abs();
        // Two ramps cover v² / mean; without room for them at full speed the peak velocity is lower.
        let v = max_velocity.min((d * mean).sqrt());
        let ramp_s = v / mean;
        let cruise_s = ((d - v * v / mean) / v).max(0.0);
        Self { start, distance, peak_velocity: v, peak_acceleration, ramp_s, cruise_s }
    }

    /// Total duration, s.
    pub fn duration_s(&self) -> f64 {
        2.0 * self.ramp_s + self.cruise_s
    }

    /// Position at time `t` (s), increments.
    pub fn position(&self, t: f64) -> f64 {
        let (tr, a) = (self.ramp_s, self.peak_acceleration);
        let sign = self.distance.signum();
        // Distance covered by one ramp from rest after time tau: integral of v(t) = a/2 (t - tr/(2pi) sin(2pi t/tr)).
        let ramp = |tau: f64| {
            let w = 2.0 * PI / tr;
            a / 2.0 * (tau * tau / 2.0 + ((w * tau).cos() - 1.0) / (w * w))
        };
        let ramp_distance = ramp(tr);
        let t = t.clamp(0.0, self.duration_s());
        let s = if t <= tr {
            ramp(t)
        } else if t <= tr + self.cruise_s {
            ramp_distance + self.peak_velocity * (t - tr)
        } else {
            let remaining = self.duration_s() - t;
            self.distance.abs() - ramp(remaining)
        };
        self.start + sign * s
    }

    /// Velocity at time `t` (s), inc/s.
    pub fn velocity(&self, t: f64) -> f64 {
        let (tr, a) = (self.ramp_s, self.peak_acceleration);
        // The derivative of the ramp's distance: a/2 (tau - sin(w tau) / w).
        let ramp = |tau: f64| {
            let w = 2.0 * PI / tr;
            a / 2.0 * (tau - (w * tau).sin() / w)
        };
        let v = if t <= 0.0 || t >= self.duration_s() {
            0.0
        } else if t <= tr {
            ramp(t)
        } else if t <= tr + self.cruise_s {
            self.peak_velocity
        } else {
            ramp(self.duration_s() - t)
        };
        self.distance.signum() * v
    }

    /// Acceleration at time `t` (s), inc/s²: `A sin²(pi tau / T)` on the ramps, 0 in the cruise and at rest.
    pub fn acceleration(&self, t: f64) -> f64 {
        let (tr, a) = (self.ramp_s, self.peak_acceleration);
        let ramp = |tau: f64| a * (PI * tau / tr).sin().powi(2);
        let acc = if t <= 0.0 || t >= self.duration_s() {
            0.0
        } else if t <= tr {
            ramp(t)
        } else if t <= tr + self.cruise_s {
            0.0
        } else {
            -ramp(self.duration_s() - t)
        };
        self.distance.signum() * acc
    }
}

/// The torque feedforward a master computes for a move from the machine's mechanical data (the plant's inertia
/// and friction as the machine builder knows them): `J alpha + B omega + T_c sign(omega)` at the motor shaft
/// (inertia and load friction reflected through the gear), in per mille of the drive's rated torque 0x6076, as it
/// sends it in the torque offset 0x60B2 (IDX L977, L6345).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TorqueFeedforward {
    /// Inertia at the motor shaft times the increment angle: N m per inc/s².
    nm_per_inc_s2: f64,
    /// Viscous friction, N m per inc/s.
    nm_per_inc_s: f64,
    /// Coulomb friction at the motor shaft, N m.
    coulomb_nm: f64,
    /// 0x6076 rated torque, N m.
    rated_nm: f64,
}

impl TorqueFeedforward {
    /// From the plant's mechanics, its encoder resolution and the drive's rated torque 0x6076 (uNm).
    pub fn new(params: &PlantParams, rated_torque_micro_nm: u32) -> Self {
        let rad_per_inc = 2.0 * PI / f64::from(params.encoder_counts_per_rev);
        let n = params.gear_ratio;
        Self {
            nm_per_inc_s2: params.total_inertia_kg_m2() * rad_per_inc,
            nm_per_inc_s: params.viscous_friction_nm_s_rad * rad_per_inc,
            coulomb_nm: params.coulomb_friction_nm + params.load_coulomb_friction_nm / (n * params.gear_efficiency),
            rated_nm: f64::from(rated_torque_micro_nm) * 1e-6,
        }
    }

    /// The feedforward for velocity `v` (inc/s) and acceleration `a` (inc/s²), per mille of rated torque, rounded
    /// and saturated to 0x60B2's INTEGER16.
    pub fn permille(&self, v: f64, a: f64) -> i16 {
        let friction = if v == 0.0 { 0.0 } else { self.coulomb_nm * v.signum() };
        let torque = self.nm_per_inc_s2 * a + self.nm_per_inc_s * v + friction;
        (torque / self.rated_nm * 1000.0).round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
    }
}

/// Configuration of the CSP scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CspConfig {
    /// Plant noise seed.
    pub seed: u64,
    /// Master cycle (= 0x60C2), in PWM periods of 40 us: 25 for 1 ms.
    pub cycle_periods: u64,
    /// Move distance, revolutions.
    pub revolutions: f64,
    /// Peak velocity, rpm.
    pub max_rpm: f64,
    /// Peak acceleration, rpm/s.
    pub peak_rpm_per_s: f64,
    /// Time the master keeps sending the final set-point after the move, s.
    pub hold_s: f64,
    /// 0x30A1:01..05 written before the move (`None`: the dictionary defaults).
    pub position_gains: Option<[u32; 5]>,
    /// The master sends a torque feedforward in 0x60B2 with each set-point ([`TorqueFeedforward`]; 0x60B1 stays
    /// 0: the drive derives the velocity feedforward from the set-points) and turns the drive's own acceleration
    /// and friction feedforward (0x30A1:05 and :06) off, which the master's replaces.
    pub torque_feedforward: bool,
}

impl Default for CspConfig {
    /// The motion issue's CSP case: 1 ms, 10 revolutions, up to 3,000 rpm and 20,000 rpm/s.
    fn default() -> Self {
        Self {
            seed: 1,
            cycle_periods: 25,
            revolutions: 10.0,
            max_rpm: 3000.0,
            peak_rpm_per_s: 20_000.0,
            hold_s: 0.1,
            position_gains: None,
            torque_feedforward: false,
        }
    }
}

impl CspConfig {
    /// The default move on the scenario plant, seeded with `seed`: its distance, speed and acceleration scaled by
    /// the plant's maximum speed ([`super::PlantScale`], `drive-sim --plant`'s scaling), so that it keeps its timing;
    /// the acceleration at most what [`CSP_ACCELERATION_TORQUE_SHARE`] of the peak torque gives the inertia at the
    /// motor shaft, so that the move stays one the motor can follow (the reference's asks 11 % of its peak torque,
    /// every preset's at most 22 %; a rigid load of 30 times the reference's rotor would ask 85 %).
    #[must_use]
    pub fn scaled_to_current_plant(seed: u64) -> Self {
        let speed = super::PlantScale::current_plant().speed;
        let peak_acceleration = super::peak_acceleration_rad_s2(&super::scenario_plant());
        let reachable_rpm_per_s = CSP_ACCELERATION_TORQUE_SHARE * peak_acceleration * 60.0 / core::f64::consts::TAU;
        let d = Self::default();
        Self {
            seed,
            revolutions: d.revolutions * speed,
            max_rpm: d.max_rpm * speed,
            peak_rpm_per_s: (d.peak_rpm_per_s * speed).min(reachable_rpm_per_s),
            ..d
        }
    }
}

/// The largest share of the peak torque (`kt * peak_current_a`) the scaled CSP move's acceleration asks of the
/// inertia at the motor shaft ([`CspConfig::scaled_to_current_plant`]).
pub const CSP_ACCELERATION_TORQUE_SHARE: f64 = 0.5;

/// Figures of the CSP scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CspFigures {
    /// Largest |0x60F4| from the first to the last set-point of the move, increments.
    pub following_error_peak_inc: f64,
    /// RMS of 0x60F4 over the same span, increments.
    pub following_error_rms_inc: f64,
    /// |0x6064 - target| 20 ms after the last set-point of the move, increments.
    pub settle_error_inc: f64,
    /// Largest |0x6064 - target| from 20 ms after the move to the end of the hold, increments.
    pub settle_error_max_inc: f64,
    /// Statusword bit 13 (following error) was seen set.
    pub following_error_bit_seen: bool,
    /// The peak velocity of the move, rpm.
    pub peak_rpm: f64,
    /// Duration of the move, s.
    pub move_s: f64,
}

/// Runs the CSP scenario; the figures and a trace per slow tick (time, master target, demand, actual, following
/// error, velocity, q current).
pub fn csp(config: &CspConfig) -> Result<(CspFigures, Trace), SimError> {
    let mut sim = prepare_motion_on(super::scenario_plant(), config.seed, 8)?;
    if let Some([p, i, d, fv, fa]) = config.position_gains {
        let dict = sim.drive.dictionary_mut();
        dict.set(h::POSITION_CONTROLLER_P_GAIN, p);
        dict.set(h::POSITION_CONTROLLER_I_GAIN, i);
        dict.set(h::POSITION_CONTROLLER_D_GAIN, d);
        dict.set(h::POSITION_CONTROLLER_FF_VELOCITY_GAIN, fv);
        dict.set(h::POSITION_CONTROLLER_FF_ACCELERATION_GAIN, fa);
    }
    if config.torque_feedforward {
        // The master's feedforward replaces the drive's acceleration and friction feedforward (both J alpha and
        // the Coulomb friction: kept, they would count twice; measured: peak 4 inc instead of 2 for J alpha).
        let d = sim.drive.dictionary_mut();
        d.set(h::POSITION_CONTROLLER_FF_ACCELERATION_GAIN, 0u32);
        d.set(h::POSITION_CONTROLLER_FF_FRICTION, 0u32);
    }
    let cycle_us = (config.cycle_periods as f64 * PERIOD_S * 1e6).round() as u32;
    // 0x60C2 = the master cycle in ms or 100 us units.
    let (value, index) = if cycle_us.is_multiple_of(1000) { (cycle_us / 1000, -3) } else { (cycle_us / 100, -4) };
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::INTERPOLATION_TIME_PERIOD_VALUE, u8::try_from(value).unwrap_or(u8::MAX));
        d.set(h::INTERPOLATION_TIME_INDEX, index);
    }
    let start = f64::from(sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE));
    let inc_per_rev = plant_inc_per_rev(&sim);
    let inc_per_s_per_rpm = inc_per_rev / 60.0;
    let mv = JerkLimitedMove::new(
        start,
        config.revolutions * inc_per_rev,
        config.max_rpm * inc_per_s_per_rpm,
        config.peak_rpm_per_s * inc_per_s_per_rpm,
    );
    let target = (start + mv.distance).round();
    let cycle_s = config.cycle_periods as f64 * PERIOD_S;
    let feedforward = config
        .torque_feedforward
        .then(|| TorqueFeedforward::new(sim.plant.params(), sim.drive.dictionary().get(h::MOTOR_RATED_TORQUE)));
    let move_cycles = (mv.duration_s() / cycle_s).ceil() as u64;
    let hold_cycles = (config.hold_s / cycle_s).ceil() as u64;
    let mut trace = Trace::new(&[
        "t_s",
        "target_inc",
        "demand_inc",
        "actual_inc",
        "following_error_inc",
        "rpm",
        "iq_a",
        "iq_ref_a",
        "bus_v",
    ]);
    let (mut fe_peak, mut fe_sq, mut fe_n) = (0.0_f64, 0.0_f64, 0_u64);
    let mut bit13 = false;
    let mut settle_error = f64::NAN;
    let mut settle_max: f64 = 0.0;
    let settle_at = PERIOD_S * 500.0; // 20 ms
    let mut periods: u64 = 0;
    for cycle in 0..=move_cycles.saturating_add(hold_cycles) {
        let t = cycle as f64 * cycle_s;
        let master = mv.position(t).round();
        sim.drive.dictionary_mut().set(h::TARGET_POSITION, master as i32);
        if let Some(ff) = &feedforward {
            // The torque of the instant whose position goes with it (the drive holds it over the next segment).
            sim.drive.dictionary_mut().set(h::TORQUE_OFFSET, ff.permille(mv.velocity(t), mv.acceleration(t)));
        }
        sim.setpoint_received();
        for _ in 0..config.cycle_periods {
            sim.step();
            periods += 1;
            if !periods.is_multiple_of(PERIODS_PER_SLOW_TICK) {
                continue;
            }
            let d = sim.drive.dictionary();
            let sw = d.get(h::STATUSWORD);
            bit13 |= sw & (1 << 13) != 0;
            let fe = f64::from(d.get(h::FOLLOWING_ERROR_ACTUAL_VALUE));
            let actual = f64::from(d.get(h::POSITION_ACTUAL_VALUE));
            let now = sim.time_s();
            if cycle <= move_cycles {
                fe_peak = fe_peak.max(fe.abs());
                fe_sq += fe * fe;
                fe_n += 1;
            }
            let after_move = (cycle - move_cycles.min(cycle)) as f64 * cycle_s;
            if cycle > move_cycles && after_move >= settle_at {
                let e = (actual - target).abs();
                if settle_error.is_nan() {
                    settle_error = e;
                }
                settle_max = settle_max.max(e);
            }
            trace.push(&[
                now,
                master,
                f64::from(d.get(h::POSITION_DEMAND_VALUE)),
                actual,
                fe,
                f64::from(d.get(h::VELOCITY_ACTUAL_VALUE)),
                f64::from(sim.tier1().signals().i_dq.q.to_milliamps()) / 1000.0,
                f64::from(sim.tier1().signals().i_ref.q.to_milliamps()) / 1000.0,
                sim.plant.state().bus_voltage_v,
            ]);
        }
    }
    let figures = CspFigures {
        following_error_peak_inc: fe_peak,
        following_error_rms_inc: if fe_n > 0 { (fe_sq / fe_n as f64).sqrt() } else { f64::NAN },
        settle_error_inc: settle_error,
        settle_error_max_inc: settle_max,
        following_error_bit_seen: bit13,
        peak_rpm: mv.peak_velocity / inc_per_s_per_rpm,
        move_s: mv.duration_s(),
    };
    Ok((figures, trace))
}

/// Figures of a CSV velocity step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityStepFigures {
    /// Step size, rpm.
    pub step_rpm: f64,
    /// Overshoot of the true speed over the target, % of the step.
    pub overshoot_pct: f64,
    /// Time from the step until the true speed stays within 2 % of the step around the target, ms.
    pub settle_ms: f64,
    /// |mean speed - target| over the last 100 ms, % of the step.
    pub steady_error_pct: f64,
}

/// Velocity of the drive's demand (`Velocity`, Q32 increments per slow tick) in rpm.
fn demand_rpm(sim: &Simulation) -> f64 {
    let v = sim.drive.axis().setpoint().velocity.0 as f64 / 4_294_967_296.0;
    v * 2500.0 * 60.0 / plant_inc_per_rev(sim)
}

/// Encoder increments per motor revolution of the simulated plant ([`INC_PER_REV`] on the reference).
fn plant_inc_per_rev(sim: &Simulation) -> f64 {
    f64::from(sim.plant.params().encoder_counts_per_rev)
}

/// The velocity step of `drive-sim csv-sweep` on the reference plant, rpm.
pub const CSV_STEP_REFERENCE_RPM: f64 = 100.0;

/// The largest share of the plant's `max_speed_rpm` the scaled velocity step may reach ([`csv_step_rpm`]).
pub const CSV_STEP_MAX_SPEED_SHARE: f64 = 0.5;

/// `drive-sim csv-sweep`'s velocity step on the scenario plant, whole rpm (0x60FF's unit): the reference's
/// [`CSV_STEP_REFERENCE_RPM`] scaled by the larger of the plant's speed scale ([`super::PlantScale::speed`]) and
/// its acceleration scale ([`super::PlantScale::acceleration`], peak torque over inertia at the motor shaft), at
/// most [`CSV_STEP_MAX_SPEED_SHARE`] of its maximum speed.
///
/// The reference's step is 2 % of its maximum speed and asks the velocity loop for 26 % of its peak current (with
/// the reference tuning); the scaled step keeps at least both shares, so that it is neither lost in the plant's
/// friction and encoder resolution (the speed share) nor in its current noise (the current share). Scaled by the
/// maximum speed alone, the small gimbal's step would be 24 rpm asking 1.5 % of its peak current: a step the size
/// of the reference power stage's current noise on that motor, which measures the noise (19 to 22 % "overshoot" of
/// the true speed, 11 to 13 % without the shunts' noise), not the loop. Scaled by the acceleration alone, the
/// geared preset's would be 20 rpm, which its friction holds 7 to 8 % short after 300 ms. The presets' steps:
/// reference 100, small-gimbal 394, geared-36v 40, nema23-48v 123 rpm.
#[must_use]
pub fn csv_step_rpm() -> f64 {
    let plant = super::scenario_plant();
    let scale = super::PlantScale::of(&plant);
    let scaled = CSV_STEP_REFERENCE_RPM * scale.speed.max(scale.acceleration);
    scaled.min(CSV_STEP_MAX_SPEED_SHARE * plant.max_speed_rpm).round().max(1.0)
}

/// CSV: a step of the target velocity from 0 to `step_rpm` (set-points every 1 ms, no interpolation), 300 ms, on
/// the scenarios' plant ([`csv_step_rpm`] is `drive-sim csv-sweep`'s step).
pub fn csv_step(seed: u64, step_rpm: f64) -> Result<(VelocityStepFigures, Trace), SimError> {
    csv_step_on(super::scenario_plant(), seed, step_rpm)
}

/// [`csv_step`] on the plant `params`.
pub fn csv_step_on(params: PlantParams, seed: u64, step_rpm: f64) -> Result<(VelocityStepFigures, Trace), SimError> {
    let mut sim = prepare_motion_on(params, seed, 9)?;
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
        d.set(h::TARGET_VELOCITY, step_rpm.round() as i32);
    }
    let mut trace = Trace::new(&["t_s", "target_rpm", "speed_rpm", "iq_a"]);
    let t0 = sim.time_s();
    let (mut peak, mut settle_from, mut tail, mut tail_n) = (0.0_f64, f64::NAN, 0.0, 0);
    let total = 0.3;
    let mut periods = 0_u64;
    while sim.time_s() - t0 < total {
        if periods.is_multiple_of(25) {
            sim.setpoint_received();
        }
        sim.step();
        periods += 1;
        let t = sim.time_s() - t0;
        let speed = sim.plant.state().speed_rpm;
        peak = peak.max(speed);
        let inside = (speed - step_rpm).abs() <= 0.02 * step_rpm.abs();
        if inside && settle_from.is_nan() {
            settle_from = t;
        } else if !inside {
            settle_from = f64::NAN;
        }
        if t > total - 0.1 {
            tail += speed;
            tail_n += 1;
        }
        if periods.is_multiple_of(PERIODS_PER_SLOW_TICK) {
            trace.push(&[t, step_rpm, speed, f64::from(sim.tier1().signals().i_dq.q.to_milliamps()) / 1000.0]);
        }
    }
    let mean = tail / f64::from(tail_n.max(1));
    Ok((
        VelocityStepFigures {
            step_rpm,
            overshoot_pct: ((peak - step_rpm) / step_rpm * 100.0).max(0.0),
            settle_ms: settle_from * 1e3,
            steady_error_pct: ((mean - step_rpm) / step_rpm * 100.0).abs(),
        },
        trace,
    ))
}

/// One point of the velocity-loop frequency response.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResponsePoint {
    /// Frequency, Hz.
    pub hz: f64,
    /// |speed / demand|, dB.
    pub gain_db: f64,
    /// Phase of speed against demand, degrees.
    pub phase_deg: f64,
}

/// Frequencies of the CSV sweep, Hz.
pub const CSV_SWEEP_HZ: [f64; 10] = [5.0, 10.0, 20.0, 40.0, 60.0, 80.0, 100.0, 130.0, 160.0, 200.0];

/// Amplitude and offset of the CSV sweep, rpm: small signal around a speed high enough that Coulomb friction does
/// not reverse (the loop's small-signal response, not its friction limit cycle). Not scaled with the plant, except
/// that a plant slower than 1,200 rpm gets both in proportion to its half maximum speed ([`csv_sweep_rpm`]), so
/// that the sine stays under 0x6080.
pub const CSV_SWEEP_OFFSET_RPM: f64 = 600.0;
/// Sine amplitude of the CSV sweep, rpm.
pub const CSV_SWEEP_AMPLITUDE_RPM: f64 = 30.0;

/// The CSV sweep's offset and amplitude on the scenario plant, rpm: [`CSV_SWEEP_OFFSET_RPM`] and
/// [`CSV_SWEEP_AMPLITUDE_RPM`], both scaled down together where the offset would exceed half the plant's maximum
/// speed.
#[must_use]
pub fn csv_sweep_rpm() -> (f64, f64) {
    let ratio = (0.5 * super::scenario_plant().max_speed_rpm / CSV_SWEEP_OFFSET_RPM).min(1.0);
    (CSV_SWEEP_OFFSET_RPM * ratio, CSV_SWEEP_AMPLITUDE_RPM * ratio)
}

/// Fits `a sin(wt) + b cos(wt)` to `y` at the samples `t`; returns (amplitude, phase in rad).
fn sine_fit(t: &[f64], y: &[f64], w: f64) -> (f64, f64) {
    let (mut s, mut c) = (0.0, 0.0);
    let n = t.len().min(y.len()) as f64;
    let mean = y.iter().sum::<f64>() / n;
    for (&tk, &yk) in t.iter().zip(y) {
        s += (yk - mean) * (w * tk).sin();
        c += (yk - mean) * (w * tk).cos();
    }
    let (a, b) = (2.0 * s / n, 2.0 * c / n);
    ((a * a + b * b).sqrt(), b.atan2(a))
}

/// CSV sweep: for each frequency, the target velocity is a sine of [`CSV_SWEEP_AMPLITUDE_RPM`] around
/// [`CSV_SWEEP_OFFSET_RPM`] ([`csv_sweep_rpm`] on a slow plant), written every slow tick (set-points at the slow tick, no interpolation, so the
/// demand itself carries the whole sine); the response is the plant's true speed against the drive's velocity
/// demand, fitted over whole periods after a settling time. Returns the points and the -3 dB bandwidth
/// (interpolated in log frequency between the points around it; NaN if the gain never falls below -3 dB).
pub fn csv_sweep(seed: u64) -> Result<(Vec<ResponsePoint>, f64), SimError> {
    let (offset_rpm, amplitude_rpm) = csv_sweep_rpm();
    let mut sim = prepare_motion_on(super::scenario_plant(), seed, 9)?;
    sim.drive.dictionary_mut().set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, offset_rpm.round() as i32);
    // Reach the offset speed first.
    for k in 0..(0.3 / PERIOD_S) as u64 {
        if k % PERIODS_PER_SLOW_TICK == 0 {
            sim.setpoint_received();
        }
        sim.step();
    }
    let mut points = Vec::new();
    for &hz in &CSV_SWEEP_HZ {
        let w = 2.0 * PI * hz;
        let settle_s = 0.05_f64.max(2.0 / hz);
        let measure_s = (8.0 / hz).max(0.1);
        let periods = ((settle_s + measure_s) / PERIOD_S) as u64;
        let t0 = sim.time_s();
        let (mut t, mut demand, mut speed) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..periods {
            if k % PERIODS_PER_SLOW_TICK == 0 {
                let now = sim.time_s() - t0;
                let rpm = offset_rpm + amplitude_rpm * (w * now).sin();
                // 0x60FF is whole rpm: the rounding (at most 0.5 rpm of a 30 rpm sine) is in the demand the fit
                // compares against, so it does not bias the gain.
                sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, rpm.round() as i32);
                sim.setpoint_received();
            }
            sim.step();
            let now = sim.time_s() - t0;
            if now >= settle_s && k % PERIODS_PER_SLOW_TICK == 0 {
                t.push(now);
                demand.push(demand_rpm(&sim));
                speed.push(sim.plant.state().speed_rpm);
            }
        }
        let (ad, pd) = sine_fit(&t, &demand, w);
        let (a_s, ps) = sine_fit(&t, &speed, w);
        let phase = ((ps - pd).to_degrees() + 540.0).rem_euclid(360.0) - 180.0;
        points.push(ResponsePoint { hz, gain_db: 20.0 * (a_s / ad).log10(), phase_deg: phase });
    }
    let bandwidth = bandwidth_hz(&points);
    Ok((points, bandwidth))
}

/// The first -3 dB crossing of the gain, interpolated in log frequency.
pub fn bandwidth_hz(points: &[ResponsePoint]) -> f64 {
    for pair in points.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        if a.gain_db >= -3.0 && b.gain_db < -3.0 {
            let f = (-3.0 - a.gain_db) / (b.gain_db - a.gain_db);
            return (a.hz.ln() + f * (b.hz.ln() - a.hz.ln())).exp();
        }
    }
    f64::NAN
}

/// Figures of a velocity hold with the Hall sensors as the only position sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HallVelocityFigures {
    /// Mean true speed over the measurement, rpm.
    pub mean_rpm: f64,
    /// RMS deviation of the true speed from its mean, rpm.
    pub ripple_rms_rpm: f64,
    /// Peak-to-peak of the true speed, rpm.
    pub ripple_pp_rpm: f64,
}

/// CSV at `rpm` with the Hall sensors as the only position sensor (0x3000:01 without the encoder, 0x3000:05 = 42
/// Hall increments per revolution: 7 pole pairs x 6 states), the velocity estimated by the observer (0x3000:02
/// bits 7..4 = 2) or the low-pass filter (= 1). After commissioning with the encoder the drive is switched off,
/// reconfigured and enabled again through the controlword; the speed is measured after 0.5 s for 1 s (the
/// plant's true speed every slow tick).
pub fn hall_only_velocity(seed: u64, rpm: f64, observer: bool) -> Result<HallVelocityFigures, SimError> {
    let mut sim = prepare_motion(seed, 9)?;
    sim.set_controlword(0x0006);
    sim.run_slow_ticks(3);
    {
        let d = sim.drive.dictionary_mut();
        // No encoder: the drive counts the Halls, 0x3000:05 = 6 x 7 pole pairs = 42 from the switch-on.
        d.set(h::SENSORS_CONFIGURATION, 0x0004_0000);
        d.set(h::CONTROL_STRUCTURE, if observer { 0x0001_0121 } else { 0x0001_0111 });
        // Gains for Hall feedback, after EPOS4's tuned Hall-only case (S1 Tab 2-17 L1433-1455: a 7-pole-pair
        // motor like the reference one, with twice its inertia): K_P 0.139 A s/rad and K_I 10.5 A/rad scaled to
        // the reference inertia (176 g cm^2 against 368), observer l_theta 0.399, l_omega 68 Hz, l_T scaled the
        // same way; the model's inertia and friction are the reference plant's.
        d.set(h::VELOCITY_CONTROLLER_P_GAIN, 66_000);
        d.set(h::VELOCITY_CONTROLLER_I_GAIN, 5_000_000);
        d.set(h::OBSERVER_POSITION_CORRECTION_GAIN, 399);
        d.set(h::OBSERVER_VELOCITY_CORRECTION_GAIN, 68_056);
        d.set(h::OBSERVER_LOAD_CORRECTION_GAIN, 32_400);
        d.set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
        d.set(h::TARGET_VELOCITY, rpm.round() as i32);
    }
    sim.enable_through_controlword(9)?;
    let (mut n, mut sum, mut sum_sq, mut lo, mut hi) = (0_u32, 0.0, 0.0, f64::MAX, f64::MIN);
    for k in 0..(1.5 * 2500.0) as u32 {
        sim.setpoint_received();
        sim.run_slow_ticks(1);
        if k >= 1250 {
            let v = sim.plant.state().speed_rpm;
            n += 1;
            sum += v;
            sum_sq += v * v;
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let mean = sum / f64::from(n);
    let var = (sum_sq / f64::from(n) - mean * mean).max(0.0);
    Ok(HallVelocityFigures { mean_rpm: mean, ripple_rms_rpm: var.sqrt(), ripple_pp_rpm: hi - lo })
}
