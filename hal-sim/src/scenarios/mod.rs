//! Scenarios on the reference plant and the figures they measure, apart from the harness that runs them
//! ([`crate::sim`]). `drive-sim` prints them and the tests of `drive-tests` (`tests/tests/drive/current_loop.rs`
//! and the other areas) assert on them, so the command line and the tests run the same code.
//!
//! This module holds the current-loop scenarios and the start every scenario shares; [`motion`] (CSP, CSV),
//! [`profile`] (PPM, PVM), [`regeneration`] (a quick stop from full speed against the bus), [`homing`], [`faults`] (the fault matrix) and [`duty_cycle`] hold the others.
//!
//! The plant is the reference unless a caller chose another for the scenarios it runs on its thread
//! ([`with_plant`], `drive-sim --plant FILE`); the drive is then configured for it as a commissioning engineer
//! would ([`Simulation::commission_motor_data`], which keeps them across a reboot of the drive), and the callers scale their moves, steps and loads with its ratings
//! ([`PlantScale`]).
//!
//! All scenarios start the same way ([`prepare`]): the scenario plant with chosen shunt offsets, the rotor at a
//! non-special angle, CiA 402 transition 3 (offset calibration) and 4 (enable), then a commissioning run on the
//! free shaft until the commutation is indexed (Hall start, Hall edge, index pulse with the learned offset), so the
//! current loop works in the true rotor frame. Figures are computed from the plant's true currents at the sample
//! instants (what the motor carries, free of ADC noise), except where a figure is about the drive's own estimate.

pub mod dual_loop;
pub mod duty_cycle;
pub mod faults;
pub mod homing;
pub mod identification;
pub mod motion;
pub mod profile;
pub mod regeneration;
pub mod ssi;

use core::f64::consts::PI;
use std::cell::RefCell;
use std::time::Instant;

use firmware::drive::DriveConfig;
use firmware::hal::power::PWM_FREQUENCY_HZ;

use crate::plant::{Mechanics, PlantParams, PERIOD_S};
use crate::sim::trace::Trace;
use crate::sim::{SimError, Simulation};

thread_local! {
    /// The plant the scenarios of this thread run on (`None`: the reference), set by [`with_plant`].
    static SCENARIO_PLANT: RefCell<Option<PlantParams>> = const { RefCell::new(None) };
}

/// Runs `f` with every scenario it starts on this thread built on `params` instead of the reference plant
/// (`drive-sim --plant FILE`); the previous choice is restored afterwards.
pub fn with_plant<R>(params: PlantParams, f: impl FnOnce() -> R) -> R {
    let previous = SCENARIO_PLANT.with(|p| p.replace(Some(params)));
    let result = f();
    SCENARIO_PLANT.with(|p| *p.borrow_mut() = previous);
    result
}

thread_local! {
    /// The parameters every scenario of this thread writes into its drive after the motor data (`None`: the
    /// dictionary's), set by [`with_parameters`].
    static SCENARIO_PARAMETERS: RefCell<Option<identification::Parameters>> = const { RefCell::new(None) };
}

/// Runs `f` with every scenario it starts on this thread commissioned with `parameters` after the motor data
/// (`drive-sim --auto-tune`: what an identification with its auto-tuning found on the same plant, as a master
/// writes a saved parameter set into the drive it starts); the previous choice is restored afterwards.
pub fn with_parameters<R>(parameters: identification::Parameters, f: impl FnOnce() -> R) -> R {
    let previous = SCENARIO_PARAMETERS.with(|p| p.replace(Some(parameters)));
    let result = f();
    SCENARIO_PARAMETERS.with(|p| *p.borrow_mut() = previous);
    result
}

/// Commissions the drive of `sim` for `params` as every scenario does: the plant's motor data
/// ([`Simulation::commission_motor_data`]), then the parameters of [`with_parameters`] if any.
///
/// # Panics
/// When the drive refuses one of those parameters (they come from the same drive's identification).
pub fn commission(sim: &mut Simulation, params: &PlantParams) {
    sim.commission_motor_data(params);
    SCENARIO_PARAMETERS.with(|p| {
        if let Some(parameters) = p.borrow().as_ref() {
            identification::commission(sim, parameters).unwrap_or_else(|e| panic!("{e}"));
        }
    });
}

/// The plant the scenarios of this thread run on: the one of [`with_plant`], else the reference.
pub fn scenario_plant() -> PlantParams {
    SCENARIO_PLANT.with(|p| p.borrow().clone()).unwrap_or_else(PlantParams::reference)
}

/// How a plant's ratings scale the scenarios' moves, steps and loads against the reference plant, so that each
/// scenario means the same on every plant (`drive-sim` help): speeds, accelerations and distances in revolutions
/// by the maximum speed (a move keeps its timing), currents by the peak current, load torques (at the output) by
/// the peak torque at the output `kt * I_peak * N * eta`, inertias by the inertia at the motor shaft.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantScale {
    /// `max_speed_rpm` over the reference's 5,000 rpm.
    pub speed: f64,
    /// `peak_current_a` over the reference's 10 A.
    pub current: f64,
    /// Peak torque at the output over the reference's 0.335 N m.
    pub torque: f64,
    /// Inertia at the motor shaft (rotor + load / N^2) over the reference's 176 g cm^2.
    pub inertia: f64,
    /// Acceleration the peak torque at the motor shaft (`kt * peak_current_a`) gives the inertia there, over the
    /// reference's (0.335 N m on 176 g cm^2): a velocity step this much larger asks the velocity loop for the same
    /// share of the peak current at the same bandwidth.
    pub acceleration: f64,
}

/// The acceleration the peak torque at the motor shaft (`kt * peak_current_a`) gives the inertia there, rad/s^2.
#[must_use]
pub fn peak_acceleration_rad_s2(params: &PlantParams) -> f64 {
    params.torque_constant_nm_per_a() * params.peak_current_a / params.total_inertia_kg_m2()
}

impl PlantScale {
    /// The scale of `params` (all 1 exactly for the reference plant).
    pub fn of(params: &PlantParams) -> Self {
        let r = PlantParams::reference();
        let peak_torque =
            |p: &PlantParams| p.torque_constant_nm_per_a() * p.peak_current_a * p.gear_ratio * p.gear_efficiency;
        Self {
            speed: params.max_speed_rpm / r.max_speed_rpm,
            current: params.peak_current_a / r.peak_current_a,
            torque: peak_torque(params) / peak_torque(&r),
            inertia: params.total_inertia_kg_m2() / r.total_inertia_kg_m2(),
            acceleration: peak_acceleration_rad_s2(params) / peak_acceleration_rad_s2(&r),
        }
    }

    /// The scale of the scenario plant ([`scenario_plant`]).
    pub fn current_plant() -> Self {
        Self::of(&scenario_plant())
    }
}

/// Gains of 0x30A0 used by the scenarios unless told otherwise: `None` keeps the dictionary defaults
/// (1,555,000 uV/A and 2,450,000 uV/(A ms), designed for a 1.5 kHz crossover).
pub type Gains = Option<(u32, u32)>;

/// Shared set-up of every scenario.
#[derive(Clone, Debug, PartialEq)]
pub struct Setup {
    /// Noise seed of the plant.
    pub seed: u64,
    /// Shunt offsets of the plant, LSB (phases A, B, C); the reference hardware allows up to +-50.
    pub offsets_lsb: [f64; 3],
    /// Current gains written to 0x30A0 before the scenario (`None`: dictionary defaults).
    pub gains: Gains,
    /// Mechanical angle the rotor starts at, rad.
    pub start_angle_rad: f64,
    /// q current of the commissioning run on the reference plant, A (scaled by [`PlantScale::current`] on another).
    pub commissioning_a: f64,
}

impl Default for Setup {
    fn default() -> Self {
        Self { seed: 1, offsets_lsb: [50.0, -50.0, 37.0], gains: None, start_angle_rad: 1.0, commissioning_a: 0.5 }
    }
}

/// What [`prepare`] measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prepared {
    /// Ticks the offset calibration took.
    pub calibration_ticks: u64,
    /// Largest |estimated - true| shunt offset over the three channels, LSB.
    pub offset_residual_lsb: f64,
    /// Estimated offsets, LSB from mid-scale.
    pub offsets_estimated_lsb: [f64; 3],
    /// Electrical angle error of the drive against the plant after commissioning, degrees.
    pub angle_error_deg: f64,
}

/// The plant's true electrical angle at the last sample minus the drive's angle, wrapped to [-180, 180) degrees.
pub fn angle_error_deg(sim: &Simulation) -> f64 {
    let truth = sim.plant.state_at_sample().theta_e_rad;
    let drive = f64::from(sim.tier1().commutation().angle().0) / 4_294_967_296.0 * 2.0 * PI;
    ((drive - truth) / (2.0 * PI) * 360.0 + 180.0).rem_euclid(360.0) - 180.0
}

/// Builds the simulation, calibrates, enables and commissions (see the module documentation). The shaft is free
/// and turning slowly at the end; the q reference is zero.
pub fn prepare(setup: &Setup) -> Result<(Simulation, Prepared), SimError> {
    prepare_plant(scenario_plant(), setup)
}

/// [`prepare`] on the plant `params` (its shunt offsets replaced by the setup's), the drive configured for it
/// ([`Simulation::commission_motor_data`]).
pub fn prepare_plant(mut params: PlantParams, setup: &Setup) -> Result<(Simulation, Prepared), SimError> {
    params.shunt_offset_lsb = setup.offsets_lsb;
    let mut sim = Simulation::new(params.clone(), setup.seed, DriveConfig::DEFAULT);
    commission(&mut sim, &params);
    sim.plant.set_rotor_state(setup.start_angle_rad, 0.0);
    if let Some((p, i)) = setup.gains {
        sim.set_current_gains(p, i);
    }
    sim.run(10);
    // The commissioning current is the reference plant's; another plant gets the same share of its peak current.
    let commissioning_a = setup.commissioning_a * PlantScale::of(&params).current;
    let calibration_ticks = sim.commission(commissioning_a)?;
    let (est, residual) = offsets_of(&sim, setup);
    let angle_error_deg = angle_error_deg(&sim);
    Ok((
        sim,
        Prepared { calibration_ticks, offset_residual_lsb: residual, offsets_estimated_lsb: est, angle_error_deg },
    ))
}

/// Only the offset calibration (CiA 402 transition 3) with the rotor at rest: the ticks it took, the estimated
/// offsets and the largest residual ([`Prepared::angle_error_deg`] is NaN: no commissioning).
pub fn offset_calibration(setup: &Setup) -> Result<Prepared, SimError> {
    let mut params = scenario_plant();
    params.shunt_offset_lsb = setup.offsets_lsb;
    let mut sim = Simulation::new(params.clone(), setup.seed, DriveConfig::DEFAULT);
    commission(&mut sim, &params);
    sim.run(10);
    let calibration_ticks = sim.switch_on()?;
    let (est, residual) = offsets_of(&sim, setup);
    Ok(Prepared {
        calibration_ticks,
        offset_residual_lsb: residual,
        offsets_estimated_lsb: est,
        angle_error_deg: f64::NAN,
    })
}

/// The drive's offset estimates (LSB from mid-scale) and the largest |estimate - true|.
fn offsets_of(sim: &Simulation, setup: &Setup) -> ([f64; 3], f64) {
    let mut est = [0.0; 3];
    let mut residual: f64 = 0.0;
    for (ch, e) in est.iter_mut().enumerate() {
        *e = f64::from(sim.tier1().offsets().deviation_lsb(ch).unwrap_or(f32::NAN));
        residual = residual.max((*e - setup.offsets_lsb[ch]).abs());
    }
    (est, residual)
}

/// Figures of a current step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFigures {
    /// Step size, A.
    pub step_a: f64,
    /// 10-90 % rise time, us.
    pub rise_us: f64,
    /// Overshoot over the final value, % of the step.
    pub overshoot_pct: f64,
    /// |final value - reference|, % of the step (final value: mean over the last millisecond of the window).
    pub steady_error_pct: f64,
    /// Largest |i_d| after the step, % of the step.
    pub d_excursion_pct: f64,
    /// Time from the step until the current stays within +-2 % of the step around the reference, us.
    pub settle_us: f64,
}

/// Time of the first crossing of `level` by `y` (linear interpolation between samples), in the units of `t`.
fn first_crossing(t: &[f64], y: &[f64], level: f64) -> f64 {
    for k in 1..y.len().min(t.len()) {
        let (a, b) = (y[k - 1] - level, y[k] - level);
        if a < 0.0 && b >= 0.0 {
            return t[k - 1] + (t[k] - t[k - 1]) * (-a) / (b - a);
        }
    }
    f64::NAN
}

/// Step figures from a trace of time (us, 0 = the sample that first used the new reference), the reference, the
/// q and d currents; `from` and `to` are the values before and after the step.
pub fn step_figures(t_us: &[f64], i_q: &[f64], i_d: &[f64], from: f64, to: f64) -> StepFigures {
    let step = to - from;
    let after: Vec<usize> = (0..t_us.len()).filter(|&k| t_us[k] >= 0.0).collect();
    let (ta, qa): (Vec<f64>, Vec<f64>) = after.iter().map(|&k| (t_us[k], (i_q[k] - from) / step)).unzip();
    let t_end = ta.last().copied().unwrap_or(0.0);
    let tail: Vec<f64> = ta.iter().zip(&qa).filter(|(t, _)| **t >= t_end - 1000.0).map(|(_, q)| *q).collect();
    let final_norm = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
    let t10 = first_crossing(&ta, &qa, 0.1);
    let t90 = first_crossing(&ta, &qa, 0.9);
    let peak = qa.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let d_max = after.iter().map(|&k| i_d[k].abs()).fold(0.0, f64::max);
    let settle = ta.iter().zip(&qa).rev().find(|(_, q)| (**q - 1.0).abs() > 0.02).map_or(0.0, |(t, _)| *t);
    StepFigures {
        step_a: step,
        rise_us: t90 - t10,
        overshoot_pct: ((peak - final_norm) * 100.0).max(0.0),
        steady_error_pct: (final_norm - 1.0).abs() * 100.0,
        d_excursion_pct: d_max / step.abs() * 100.0,
        settle_us: settle,
    }
}

/// The trace columns of the step and spinning scenarios.
pub const STEP_COLUMNS: [&str; 11] = [
    "t_us",
    "iq_ref_a",
    "iq_a",
    "id_a",
    "iq_measured_a",
    "id_measured_a",
    "vq_v",
    "vd_v",
    "saturated",
    "speed_rpm",
    "bus_v",
];

/// Appends one row of [`STEP_COLUMNS`] for the last period.
fn record(trace: &mut Trace, sim: &Simulation, t0_ticks: u64) {
    let st = sim.plant.state_at_sample();
    let s = sim.tier1().signals();
    let t_us = (sim.ticks() as f64 - t0_ticks as f64) * PERIOD_S * 1e6;
    trace.push(&[
        t_us,
        s.i_ref.q.0.to_num(),
        st.i_dq_a[1],
        st.i_dq_a[0],
        s.i_dq.q.0.to_num(),
        s.i_dq.d.0.to_num(),
        s.v_dq.q.0.to_num(),
        s.v_dq.d.0.to_num(),
        f64::from(u8::from(s.saturated)),
        st.speed_rpm,
        st.bus_voltage_v,
    ]);
}

/// Locks the rotor where it is and runs `ticks` periods at zero current.
fn lock_and_settle(sim: &mut Simulation, ticks: u64) {
    sim.plant.lock_rotor(true);
    sim.set_q_reference(0.0);
    sim.run(ticks);
}

/// Result of [`current_step`].
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// Set-up figures.
    pub prepared: Prepared,
    /// Step figures.
    pub figures: StepFigures,
    /// The trace ([`STEP_COLUMNS`]), from 0.2 ms before the step.
    pub trace: Trace,
}

/// q-current step `0 -> step_a` at standstill with the rotor locked, through target torque 0x6071; records 4 ms.
pub fn current_step(setup: &Setup, step_a: f64) -> Result<StepReport, SimError> {
    let (mut sim, prepared) = prepare(setup)?;
    lock_and_settle(&mut sim, 200);
    let mut trace = Trace::new(&STEP_COLUMNS);
    // The step is written before tick t0 runs; that tick's sample is t = 0.
    let t0 = sim.ticks() + 5 + 1;
    for _ in 0..5 {
        sim.step();
        record(&mut trace, &sim, t0);
    }
    sim.set_q_reference(step_a);
    for _ in 0..100 {
        sim.step();
        record(&mut trace, &sim, t0);
    }
    let col = |n: &str| trace.column(n).unwrap_or_default();
    let figures = step_figures(&col("t_us"), &col("iq_a"), &col("id_a"), 0.0, step_a);
    Ok(StepReport { prepared, figures, trace })
}

/// One point of a frequency response.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrequencyPoint {
    /// Frequency, Hz.
    pub freq_hz: f64,
    /// |I_q / I_ref| at that frequency.
    pub gain: f64,
    /// Phase of I_q / I_ref, degrees.
    pub phase_deg: f64,
}

impl FrequencyPoint {
    /// Gain in dB.
    pub fn gain_db(&self) -> f64 {
        20.0 * self.gain.log10()
    }
}

/// Result of [`bandwidth`].
#[derive(Clone, Debug, PartialEq)]
pub struct SweepReport {
    /// The measured points.
    pub points: Vec<FrequencyPoint>,
    /// The -3 dB closed-loop bandwidth, Hz (log-linear interpolation between the points around the first
    /// crossing); infinite if the gain never fell below -3 dB in the sweep.
    pub bandwidth_hz: f64,
    /// Largest gain seen (resonance peak), dB.
    pub peak_db: f64,
}

/// The default sweep frequencies, Hz.
pub const SWEEP_FREQUENCIES_HZ: [f64; 18] = [
    100.0, 200.0, 400.0, 700.0, 1000.0, 1200.0, 1400.0, 1600.0, 1800.0, 2000.0, 2200.0, 2400.0, 2700.0, 3000.0, 3500.0,
    4000.0, 5000.0, 6000.0,
];

/// Closed-loop small-signal current bandwidth: the rotor locked, a q reference `bias_a + amplitude_a sin(2 pi f t)`
/// at each frequency (through 0x6071, so the per-mille quantisation is part of the reference), and the fundamental
/// of the plant's true i_q against the fundamental of the reference the drive actually used, by correlation over
/// whole periods after a settling time.
///
/// The bias keeps the current away from zero: through a zero crossing the inverter's dead time (0.5 us, a voltage
/// error of `sgn(i) x 1.25 %` of the bus, the voltage of 1.1 A in the reference winding) makes the loop nonlinear
/// and the "gain" would depend on the amplitude (a 1 A sine around zero droops by about 2 dB already at 700 Hz);
/// with a bias it is a constant disturbance that the integrator removes, and the response is the linear one.
pub fn bandwidth(setup: &Setup, bias_a: f64, amplitude_a: f64, freqs_hz: &[f64]) -> Result<SweepReport, SimError> {
    let (mut sim, _) = prepare(setup)?;
    lock_and_settle(&mut sim, 100);
    sim.set_q_reference(bias_a);
    sim.run(100);
    let fs = f64::from(PWM_FREQUENCY_HZ);
    let mut points = Vec::with_capacity(freqs_hz.len());
    for &f in freqs_hz {
        let w = 2.0 * PI * f / fs;
        let settle = (fs * 0.002).max(3.0 * fs / f).round() as u64;
        // Whole periods, at least 10 and at least 8 ms.
        let periods = (f * 0.008).ceil().max(10.0);
        let n = (periods * fs / f).round() as u64;
        let (mut ry, mut iy, mut rr, mut ir) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..settle + n {
            let phase = w * k as f64;
            sim.set_q_reference(bias_a + amplitude_a * phase.sin());
            sim.step();
            if k >= settle {
                let r: f64 = sim.tier1().signals().i_ref.q.0.to_num();
                let y = sim.plant.state_at_sample().i_dq_a[1];
                let (s, c) = phase.sin_cos();
                ry += y * c;
                iy -= y * s;
                rr += r * c;
                ir -= r * s;
            }
        }
        // H = Y / R in complex arithmetic.
        let den = rr * rr + ir * ir;
        let (hr, hi) = ((ry * rr + iy * ir) / den, (iy * rr - ry * ir) / den);
        points.push(FrequencyPoint { freq_hz: f, gain: hr.hypot(hi), phase_deg: hi.atan2(hr).to_degrees() });
    }
    let limit_db = -3.0103;
    let mut bandwidth_hz = f64::INFINITY;
    for pair in points.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        if a.gain_db() >= limit_db && b.gain_db() < limit_db {
            let x = (limit_db - a.gain_db()) / (b.gain_db() - a.gain_db());
            bandwidth_hz = (a.freq_hz.ln() + x * (b.freq_hz.ln() - a.freq_hz.ln())).exp();
            break;
        }
    }
    let peak_db = points.iter().map(FrequencyPoint::gain_db).fold(f64::NEG_INFINITY, f64::max);
    Ok(SweepReport { points, bandwidth_hz, peak_db })
}

/// The sweep as a trace: frequency, gain, gain in dB, phase.
pub fn sweep_trace(report: &SweepReport) -> Trace {
    let mut t = Trace::new(&["freq_hz", "gain", "gain_db", "phase_deg"]);
    for p in &report.points {
        t.push(&[p.freq_hz, p.gain, p.gain_db(), p.phase_deg]);
    }
    t
}

/// Parameters of the spinning-motor scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpinConfig {
    /// Speed before the step, rpm.
    pub speed_rpm: f64,
    /// q current before the step (about what friction takes), A.
    pub base_a: f64,
    /// q current after the step, A.
    pub high_a: f64,
    /// Load torque applied at the step, N m (removed at the step back).
    pub load_nm: f64,
    /// Duration of each phase, ms.
    pub phase_ms: f64,
    /// Tracking band after settling, fraction of the step.
    pub band: f64,
}

impl Default for SpinConfig {
    /// 3,000 rpm, 0.2 A -> 8 A with a 0.25 N m load step (8 A x 33.5 mNm/A = 0.268 N m: the speed stays near
    /// 3,000 rpm), 10 ms per phase, +-5 % band.
    fn default() -> Self {
        Self { speed_rpm: 3000.0, base_a: 0.2, high_a: 8.0, load_nm: 0.25, phase_ms: 10.0, band: 0.05 }
    }
}

/// Figures of one step of the spinning scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpinStepFigures {
    /// Speed at the step, rpm.
    pub speed_rpm: f64,
    /// Step size, A.
    pub step_a: f64,
    /// Time the voltage limit was active after the step, us.
    pub saturated_us: f64,
    /// Time from the end of the saturation until the current stays within the band, us (0 if it already was).
    pub recovery_us: f64,
    /// Time from the step until the current stays within the band, us.
    pub settle_us: f64,
    /// Overshoot beyond the new reference, % of the step.
    pub overshoot_pct: f64,
    /// Mean |i_q - reference| over the second half of the phase, % of the step.
    pub tracking_error_pct: f64,
    /// Largest |i_d| after the step, A.
    pub d_peak_a: f64,
}

/// Result of [`spinning`].
#[derive(Clone, Debug, PartialEq)]
pub struct SpinReport {
    /// Set-up figures.
    pub prepared: Prepared,
    /// The step up (with the load step).
    pub up: SpinStepFigures,
    /// The step back down (load removed).
    pub down: SpinStepFigures,
    /// The trace ([`STEP_COLUMNS`]), t = 0 at the step up.
    pub trace: Trace,
}

/// Figures of one spinning step from the rows of `trace` with `t_start <= t < t_end` (t = 0.. after the step).
fn spin_figures(trace: &Trace, t_start: f64, t_end: f64, from: f64, to: f64, band: f64) -> SpinStepFigures {
    let col = |n: &str| trace.column(n).unwrap_or_default();
    let (t, q, d, sat, rpm) = (col("t_us"), col("iq_a"), col("id_a"), col("saturated"), col("speed_rpm"));
    let idx: Vec<usize> = (0..t.len()).filter(|&k| t[k] >= t_start && t[k] < t_end).collect();
    let step = to - from;
    let rel = |k: usize| (q[k] - to) / step;
    let dt = PERIOD_S * 1e6;
    let saturated_us = idx.iter().filter(|&&k| sat[k] > 0.5).count() as f64 * dt;
    let last_sat = idx.iter().rev().find(|&&k| sat[k] > 0.5).map(|&k| t[k] - t_start);
    let last_out = idx.iter().rev().find(|&&k| rel(k).abs() > band).map(|&k| t[k] - t_start);
    let settle_us = last_out.map_or(0.0, |x| x + dt);
    let recovery_us = match (last_sat, last_out) {
        (Some(s), Some(o)) => (o + dt - (s + dt)).max(0.0),
        _ => 0.0,
    };
    let overshoot_pct = idx.iter().map(|&k| rel(k) * 100.0).fold(0.0, f64::max);
    let t_half = t_start + (t_end - t_start) / 2.0;
    let late: Vec<f64> = idx.iter().filter(|&&k| t[k] >= t_half).map(|&k| rel(k).abs() * 100.0).collect();
    let tracking_error_pct = late.iter().sum::<f64>() / late.len().max(1) as f64;
    let d_peak_a = idx.iter().map(|&k| d[k].abs()).fold(0.0, f64::max);
    let speed_rpm = idx.first().map_or(f64::NAN, |&k| rpm[k]);
    SpinStepFigures {
        speed_rpm,
        step_a: step,
        saturated_us,
        recovery_us,
        settle_us,
        overshoot_pct,
        tracking_error_pct,
        d_peak_a,
    }
}

/// The motor spinning at `speed_rpm` on the free shaft (set with the plant's rotor-state hook after
/// commissioning), q current `base_a`; then a load step together with a current step to `high_a` that drives the
/// current loop into the voltage limit (the proportional part alone asks for more than the 0.9 Vbus circle), and
/// after `phase_ms` the step back. Measures saturation time, recovery, overshoot (windup would show as overshoot
/// and a slow recovery) and tracking.
pub fn spinning(setup: &Setup, cfg: &SpinConfig) -> Result<SpinReport, SimError> {
    let (mut sim, prepared) = prepare(setup)?;
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_mechanics(Mechanics::Free);
    sim.plant.set_rotor_state(theta, PlantParams::rpm_to_rad_s(cfg.speed_rpm));
    sim.set_q_reference(cfg.base_a);
    // 5 ms for the current loop to take up the back-EMF that appeared with the speed, then the speed is set again
    // (it sagged by a few rpm during that transient) so the step happens at the stated speed.
    sim.run(125);
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, PlantParams::rpm_to_rad_s(cfg.speed_rpm));
    let mut trace = Trace::new(&STEP_COLUMNS);
    let phase_ticks = (cfg.phase_ms * 1e-3 / PERIOD_S).round() as u64;
    let t0 = sim.ticks() + 25 + 1;
    for _ in 0..25 {
        sim.step();
        record(&mut trace, &sim, t0);
    }
    sim.plant.set_load_torque(cfg.load_nm);
    sim.set_q_reference(cfg.high_a);
    for _ in 0..phase_ticks {
        sim.step();
        record(&mut trace, &sim, t0);
    }
    sim.plant.set_load_torque(0.0);
    sim.set_q_reference(cfg.base_a);
    for _ in 0..phase_ticks {
        sim.step();
        record(&mut trace, &sim, t0);
    }
    let t_phase = phase_ticks as f64 * PERIOD_S * 1e6;
    let up = spin_figures(&trace, 0.0, t_phase, cfg.base_a, cfg.high_a, cfg.band);
    let down = spin_figures(&trace, t_phase, 2.0 * t_phase, cfg.high_a, cfg.base_a, cfg.band);
    Ok(SpinReport { prepared, up, down, trace })
}

/// Result of [`bench()`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BenchFigures {
    /// Drives simulated side by side.
    pub drives: usize,
    /// Simulated time of each drive, s.
    pub simulated_s: f64,
    /// Wall-clock time, s.
    pub wall_s: f64,
    /// Simulated seconds of each drive per wall-clock second (with one drive, the simulator's speed; with N, how
    /// far ahead of real time N drives run on one thread).
    pub sim_speed_ratio: f64,
}

/// Host speed: after commissioning, `seconds` of drive time (25,000 fast ticks per second, each with the plant
/// step, the fast tick and every 10th the slow tick) with the current loop running on the free shaft under a
/// 1 A q current and a load that holds the speed, on each of `drives` drives (their noise seeded one apart),
/// stepped in turn one period each on this thread as a machine's axes advance together. Only the timed run is
/// counted.
pub fn bench(seconds: f64, drives: usize) -> Result<BenchFigures, SimError> {
    let drives = drives.max(1);
    let mut sims = Vec::with_capacity(drives);
    for n in 0..drives {
        let setup = Setup { seed: Setup::default().seed.wrapping_add(n as u64), ..Setup::default() };
        let (mut sim, _) = prepare(&setup)?;
        sim.set_q_reference(1.0);
        sim.plant.set_load_torque(0.03);
        sims.push(sim);
    }
    let ticks = (seconds * f64::from(PWM_FREQUENCY_HZ)).round() as u64;
    let start = Instant::now();
    for _ in 0..ticks {
        for sim in sims.iter_mut() {
            sim.step();
        }
    }
    let wall_s = start.elapsed().as_secs_f64();
    let simulated_s = ticks as f64 * PERIOD_S;
    Ok(BenchFigures { drives, simulated_s, wall_s, sim_speed_ratio: simulated_s / wall_s.max(1e-12) })
}
