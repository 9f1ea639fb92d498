//! Regeneration: a quick stop from full speed against the DC bus, with the bus-voltage limiter (0x3202) alone or
//! with a braking chopper (0x3203).
//!
//! The drive runs PVM (0x6060 = 3) up to the speed asked, then the master sends «Quick stop» (controlword bit 2
//! low, 0x000B); the quick stop option code 0x605A keeps its default 6 (stop on the quick-stop ramp 0x6085 and stay
//! in «Quick stop active»). The scenario records the plant's true bus voltage in every PWM period (the peak is what
//! the over-voltage trip would see; the drive's ADC adds 1 LSB of noise, 15 mV), the time to standstill against
//! the ramp's, and what the braking resistor took.

use firmware::cia402::State;
use firmware::drive::chopper::STATE_OVERLOADED;
use firmware::drive::regeneration::{STATE_LOSS_BRAKING, STATE_REGEN_REDUCED};
use firmware::od::generated::handles as h;
use firmware::power_state::PowerState;

use super::{prepare_plant, Setup};
use crate::plant::PlantParams;
use crate::sim::trace::Trace;
use crate::sim::{SimError, Simulation};

/// «Enable operation».
const ENABLE_OPERATION: u16 = 0x000F;
/// «Quick stop» from «Operation enabled» (CiA 402 transition 11: bit 2 low, bits 0 and 1 high).
const QUICK_STOP: u16 = 0x000B;
/// Below this |speed| the motor counts as stopped, rpm.
const STOPPED_RPM: f64 = 10.0;
/// PWM periods per trace row (one per slow tick).
const TRACE_EVERY: u64 = 10;

/// The braking resistor's rating as the master writes it into 0x3203 (the plant's resistance goes to :01).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChopperRating {
    /// 0x3203:02, W.
    pub rated_power_w: f64,
    /// 0x3203:03, s.
    pub time_constant_s: f64,
}

impl ChopperRating {
    /// A 50 W braking resistor with a 10 s thermal time constant (the chopper preset's).
    pub const REFERENCE: Self = Self { rated_power_w: 50.0, time_constant_s: 10.0 };
}

/// What a quick stop showed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuickStopFigures {
    /// The plant's speed when the quick stop was sent, rpm.
    pub from_rpm: f64,
    /// 0x6085 in force, rpm/s.
    pub quick_stop_deceleration_rpm_per_s: u32,
    /// `from_rpm / 0x6085`: the ramp's length, ms.
    pub ramp_ms: f64,
    /// From the quick stop to |speed| < 10 rpm, ms.
    pub stop_ms: f64,
    /// The highest bus voltage of the plant from the quick stop to 100 ms after standstill, V (every PWM period).
    pub bus_peak_v: f64,
    /// The bus before the quick stop, V.
    pub bus_before_v: f64,
    /// Energy the braking resistor took during the stop, J (0 without a chopper).
    pub chopper_energy_j: f64,
    /// 0x3202:06 showed loss braking at some slow tick.
    pub loss_braking_seen: bool,
    /// 0x3202:06 showed the regenerative current reduced at some slow tick.
    pub regen_reduced_seen: bool,
    /// 0x3203:07 showed the chopper switched off by its overload protection at some slow tick.
    pub chopper_overload_seen: bool,
    /// The CiA 402 state 100 ms after standstill.
    pub final_state: State,
    /// 0x603F then (0: no fault; a stop the limiter stretched must not end in a following error 0x8611).
    pub error_code: u16,
    /// The winding's temperature rise over the stop, K (the plant's: what loss braking costs the motor).
    pub winding_rise_k: f64,
}

/// A quick stop of the plant `params` from `from_rpm` with 0x6085 = `deceleration_rpm_per_s`; `limiter` writes
/// 0x3202:01, `chopper` the resistor's rating (and the plant's resistance) into 0x3203. Fails with the drive's
/// error if it trips (an over-voltage trip is `SimError::Drive(Protection(BusOverVoltage))`).
pub fn quick_stop(
    seed: u64,
    params: PlantParams,
    chopper: Option<ChopperRating>,
    limiter: bool,
    from_rpm: i32,
    deceleration_rpm_per_s: u32,
) -> Result<(QuickStopFigures, Trace), SimError> {
    let resistance_ohm = params.chopper_resistance_ohm;
    let (mut sim, _) = prepare_plant(params, &Setup { seed, ..Setup::default() })?;
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, 0.0);
    sim.run(250);
    let d = sim.drive.dictionary_mut();
    d.set(h::BUS_LIMITER_ENABLE, u8::from(limiter));
    if let Some(rating) = chopper {
        d.set(h::CHOPPER_RESISTANCE, (resistance_ohm * 1000.0).round() as u32);
        d.set(h::CHOPPER_RATED_POWER, (rating.rated_power_w * 1000.0).round() as u32);
        d.set(h::CHOPPER_THERMAL_TIME_CONSTANT, (rating.time_constant_s * 1000.0).round() as u32);
    }
    d.set(h::QUICK_STOP_DECELERATION, deceleration_rpm_per_s);
    sim.enable_through_controlword(3)?;
    let mut trace = Trace::new(&["t_s", "speed_rpm", "bus_v", "i_d_a", "i_q_a", "limiter_state", "chopper_state"]);

    // Up to speed, and 100 ms there.
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, from_rpm);
    sim.set_controlword(ENABLE_OPERATION);
    let target = f64::from(from_rpm);
    run_periods(&mut sim, 50_000, &mut trace, |s| s.plant.state().speed_rpm >= 0.99 * target)?
        .ok_or(SimError::Timeout("the speed before the quick stop"))?;
    run_periods(&mut sim, 2_500, &mut trace, |_| false)?;
    let from = sim.plant.state().speed_rpm;
    let bus_before_v = sim.plant.state().bus_voltage_v;
    let energy_before = sim.plant.chopper_energy_j();
    let winding_before = sim.plant.state().winding_temp_c;

    sim.set_controlword(QUICK_STOP);
    let mut peak = bus_before_v;
    let mut seen = 0_u8;
    let mut chopper_seen = 0_u8;
    let periods = run_periods(&mut sim, 125_000, &mut trace, |s| {
        peak = peak.max(s.plant.state().bus_voltage_v);
        seen |= s.drive.dictionary().get(h::BUS_LIMITER_STATE);
        chopper_seen |= s.drive.dictionary().get(h::CHOPPER_STATE);
        s.plant.state().speed_rpm.abs() < STOPPED_RPM
    })?
    .ok_or(SimError::Timeout("standstill after the quick stop"))?;
    let stop_ms = periods as f64 * crate::plant::PERIOD_S * 1000.0;
    run_periods(&mut sim, 2_500, &mut trace, |s| {
        peak = peak.max(s.plant.state().bus_voltage_v);
        false
    })?;
    let figures = QuickStopFigures {
        from_rpm: from,
        quick_stop_deceleration_rpm_per_s: deceleration_rpm_per_s,
        ramp_ms: from / f64::from(deceleration_rpm_per_s.max(1)) * 1000.0,
        stop_ms,
        bus_peak_v: peak,
        bus_before_v,
        chopper_energy_j: sim.plant.chopper_energy_j() - energy_before,
        loss_braking_seen: seen & STATE_LOSS_BRAKING != 0,
        regen_reduced_seen: seen & STATE_REGEN_REDUCED != 0,
        chopper_overload_seen: chopper_seen & STATE_OVERLOADED != 0,
        final_state: sim.cia402_state(),
        error_code: sim.drive.dictionary().get(h::ERROR_CODE),
        winding_rise_k: sim.plant.state().winding_temp_c - winding_before,
    };
    Ok((figures, trace))
}

/// Runs PWM periods until `done` (checked after each) or `max` periods; a trip is an error. Returns the periods
/// run when `done` held, `None` when `max` ran out.
fn run_periods(
    sim: &mut Simulation,
    max: u64,
    trace: &mut Trace,
    mut done: impl FnMut(&Simulation) -> bool,
) -> Result<Option<u64>, SimError> {
    for n in 1..=max {
        sim.step();
        if let PowerState::Fault(e) = sim.drive.state() {
            return Err(SimError::Drive(e));
        }
        if sim.ticks().is_multiple_of(TRACE_EVERY) {
            let st = sim.plant.state();
            let d = sim.drive.dictionary();
            trace.push(&[
                st.time_s,
                st.speed_rpm,
                st.bus_voltage_v,
                st.i_dq_a[0],
                st.i_dq_a[1],
                f64::from(d.get(h::BUS_LIMITER_STATE)),
                f64::from(d.get(h::CHOPPER_STATE)),
            ]);
        }
        if done(sim) {
            return Ok(Some(n));
        }
    }
    Ok(None)
}
