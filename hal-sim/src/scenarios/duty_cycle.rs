//! The "no false trips" duty cycle (issue 5): 60 s of a machine's work on the scenario plant (the reference
//! unless `drive-sim --plant` chose another) with every protection armed, the reference sensor noise, and nothing
//! that should trip.
//!
//! The numbers below are the reference plant's; on another plant the velocity steps scale with its maximum speed
//! and the load torques with its peak torque at the output ([`PlantScale`]: `speed`, `torque`), so that each step
//! is the same share of the plant's ratings: an acceleration at its current limit, a braking that feeds its
//! kinetic energy back, a load of up to 30 % of its peak torque. The timing (0.6 s steps, 1.7 s loads) is kept.
//!
//! The master runs CSV with set-points every 1 ms. Every 0.6 s the target velocity steps through 2,000, 0,
//! -2,000, 0, 1,500, -1,500, 2,000, -500 rpm (the reversals brake at the current limit, with the bus-voltage limiter 0x3202 on as by default: it acts only when the bus passes 51 V) (a step is an acceleration at the current limit: the velocity loop saturates
//! at 0x3001:02 = 10 A for about 10 ms), each deceleration feeds the motor's energy back into the bus (no braking
//! chopper on the reference supply), and a load torque of up to 30 % of the peak torque is switched on and off
//! every 1.7 s, out of phase with the velocity steps. The load resists the motion (a machining or conveying
//! load, `J dw/dt = T_motor - T_load` with `T_load` of the speed's sign): an overhauling load (a vertical axis
//! lowering) regenerates without end and, with a supply that cannot take the energy back and no braking resistor,
//! must end in the bus over-voltage trip, which is right, not a false trip. The RMS current stays below the
//! nominal current, so the motor I2t has no reason to limit; the bus rises on each braking but stays below the
//! 56 V trip.
//!
//! Every EMCY the drive sends is read each slow tick: a fault's is a false trip, a warning's a warning. The
//! figures are what `drive-sim duty-cycle` prints and `tests/tests/fault/duty_cycle.rs` asserts (both zero).

use firmware::fault::{EmcyMessage, FaultId};
use firmware::od::generated::handles as h;

use super::motion::prepare_motion;
use super::PlantScale;
use crate::sim::trace::Trace;
use crate::sim::SimError;

/// Length of the duty cycle, s.
pub const DURATION_S: f64 = 60.0;
/// Target velocities on the reference plant, rpm, one every [`STEP_PERIOD_S`] (x [`PlantScale::speed`]).
const VELOCITY_STEPS_RPM: [i32; 8] = [2_000, 0, -2_000, 0, 1_500, -1_500, 2_000, -500];
/// Time between two velocity steps, s.
const STEP_PERIOD_S: f64 = 0.6;
/// Load torque magnitudes on the reference plant, Nm, one every [`LOAD_PERIOD_S`] (the peak torque is 0.335 Nm;
/// x [`PlantScale::torque`], at the output); the sign follows the speed so that the load resists the motion.
const LOAD_STEPS_NM: [f64; 4] = [0.1, 0.0, 0.05, 0.0];
/// Time between two load steps, s.
const LOAD_PERIOD_S: f64 = 1.7;
/// PWM periods per master cycle (1 ms) and per slow tick.
const PERIODS_PER_CYCLE: u64 = 25;
const PERIODS_PER_SLOW_TICK: u64 = 10;

/// What the duty cycle measured.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DutyCycleFigures {
    /// Faults raised (each one a false trip).
    pub false_trips: u32,
    /// Warnings raised.
    pub warnings: u32,
    /// Velocity steps commanded.
    pub moves: u32,
    /// Largest |q current| measured, A.
    pub peak_current_a: f64,
    /// Largest motor speed, rpm.
    pub peak_speed_rpm: f64,
    /// Lowest and highest DC-bus voltage, V.
    pub bus_min_v: f64,
    /// Highest DC-bus voltage, V.
    pub bus_max_v: f64,
    /// RMS q current over the cycle, A.
    pub rms_current_a: f64,
    /// Every fault or warning seen, with its time.
    pub events: Vec<String>,
}

/// Runs the duty cycle with noise `seed` on the scenario plant, scaled to its ratings.
pub fn duty_cycle(seed: u64) -> Result<(DutyCycleFigures, Trace), SimError> {
    duty_cycle_with_progress(seed, &mut |_, _| {})
}

/// Tier-1 periods between two calls of [`duty_cycle_with_progress`]'s `progress` (0.1 s of simulated time).
const PROGRESS_PERIODS: u64 = 2_500;

/// [`duty_cycle`], telling `progress(done, total)` how many of the run's tier-1 periods have passed, every
/// 2,500 periods (0.1 s) and at the end (for a progress bar: `drive-sim duty-cycle` on a terminal). The
/// observer only reads the count; the run and its figures are the same with any observer.
pub fn duty_cycle_with_progress(
    seed: u64,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<(DutyCycleFigures, Trace), SimError> {
    let scale = PlantScale::current_plant();
    let mut sim = prepare_motion(seed, 9)?;
    let _ = std::iter::from_fn(|| sim.drive.poll_emcy()).count();
    let mut trace = Trace::new(&["t_s", "target_rpm", "speed_rpm", "iq_a", "bus_v", "i2t_pct"]);
    let mut f = DutyCycleFigures { bus_min_v: f64::INFINITY, bus_max_v: 0.0, ..DutyCycleFigures::default() };
    let periods = (DURATION_S / crate::plant::PERIOD_S).round() as u64;
    let (mut target, mut step_index, mut load_index, mut load) = (0, 0usize, 0usize, 0.0);
    let mut square_sum = 0.0;
    for k in 0..periods {
        if k.is_multiple_of(PROGRESS_PERIODS) {
            progress(k, periods);
        }
        let t = k as f64 * crate::plant::PERIOD_S;
        if t >= step_index as f64 * STEP_PERIOD_S {
            let reference_rpm = VELOCITY_STEPS_RPM[step_index % VELOCITY_STEPS_RPM.len()];
            target = (f64::from(reference_rpm) * scale.speed).round() as i32;
            sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, target);
            step_index += 1;
            f.moves += 1;
        }
        if t >= load_index as f64 * LOAD_PERIOD_S + LOAD_PERIOD_S / 2.0 {
            load = LOAD_STEPS_NM[load_index % LOAD_STEPS_NM.len()] * scale.torque;
            load_index += 1;
        }
        // The load resists the motion: its sign follows the speed (a reversal never turns it into a drive).
        sim.plant.set_load_torque(load * sim.plant.state().speed_rpm.signum());
        if k.is_multiple_of(PERIODS_PER_CYCLE) {
            sim.setpoint_received();
        }
        sim.step();
        let state = sim.plant.state();
        let iq = f64::from(sim.tier1().signals().i_dq.q.to_milliamps()) / 1000.0;
        square_sum += iq * iq;
        f.peak_current_a = f.peak_current_a.max(iq.abs());
        f.peak_speed_rpm = f.peak_speed_rpm.max(state.speed_rpm.abs());
        f.bus_min_v = f.bus_min_v.min(state.bus_voltage_v);
        f.bus_max_v = f.bus_max_v.max(state.bus_voltage_v);
        if k.is_multiple_of(PERIODS_PER_SLOW_TICK) {
            while let Some(frame) = sim.drive.poll_emcy() {
                let Ok(m) = EmcyMessage::parse(&frame) else { continue };
                let Some(id) = FaultId::from_number(m.fault_number()).filter(|_| m.code != 0) else { continue };
                if id.info().reaction.is_warning() {
                    f.warnings += 1;
                } else {
                    f.false_trips += 1;
                }
                f.events.push(format!("{:.3} s: {} ({:#06X}), value {}", t, id.info().name, m.code, m.value()));
            }
        }
        if k.is_multiple_of(PERIODS_PER_CYCLE * 4) {
            let i2t = sim.drive.dictionary().get(h::I2T_LEVEL_MOTOR);
            trace.push(&[t, f64::from(target), state.speed_rpm, iq, state.bus_voltage_v, f64::from(i2t)]);
        }
    }
    f.rms_current_a = (square_sum / periods as f64).sqrt();
    progress(periods, periods);
    Ok((f, trace))
}
