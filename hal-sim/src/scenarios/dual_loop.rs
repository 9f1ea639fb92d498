//! The dual loop on a plant with a load encoder (`drive-sim dual-loop --plant FILE`; EPOS4 AN ch. 10): a CSP move
//! of the load, the master's set-points in its position units (the load encoder's increments in the dual loop's
//! configuration, the gear being in effect; motor increments without it), closed either by the
//! load encoder (the dual loop: 0x3000:01 = 0x00040201, 0x3000:02 = 0x04021111, 0x3020:01 and the gear ratio
//! 0x3003:01/02 from the plant, written over SDO with the power stage off) or, for comparison, by the motor
//! encoder alone (the default PID 0x30A1).
//!
//! Figures, measured on the plant (the load encoder's count and the true angles):
//! - `load_following_error_peak_inc`: the largest |load target - load position| during the move, load-encoder
//!   increments (the master's set-point converted to the load through the gear and the two resolutions);
//! - `load_settle_error_inc`: the largest |load target - load position| over the last [`SETTLE_WINDOW_S`] of the
//!   hold after the move, load-encoder increments;
//! - `load_settle_time_s`: from the end of the move to the last instant the load was more than [`SETTLE_BAND_INC`]
//!   off its target (0 when it never left the band after the move; none when it is outside at the end of the
//!   hold). The hold is long enough to show the end of the settling, not only its start: on geared-36v the load
//!   rings at a few hertz after the move and then stands on its Coulomb friction (45 mNm at the output) until the
//!   velocity loop's integral has built the breakaway current, which takes 0.3 to 0.8 s depending on where the
//!   ringing left it;
//! - `motor_load_deviation_peak_deg`: the largest |motor angle / gear ratio - load angle| over the run, degrees
//!   at the load (backlash plus the coupling's twist).

use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::handles as h;
use firmware::od::store::ParamStore;
use firmware::power_state::PowerState;

use super::motion::{prepare_plant_for_motion, JerkLimitedMove};
use crate::flash::SimFlash;
use crate::plant::{PlantParams, PERIOD_S};
use crate::sim::trace::Trace;
use crate::sim::{SimError, Simulation};

/// The end of the hold over which the settle error is taken, s.
pub const SETTLE_WINDOW_S: f64 = 0.1;
/// The band of `load_settle_time_s`, load increments: issue 20's +-2.
pub const SETTLE_BAND_INC: f64 = 2.0;
/// PWM periods per slow tick.
const PERIODS_PER_SLOW_TICK: u64 = 10;

/// Configuration of the dual-loop scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DualLoopConfig {
    /// Plant noise seed.
    pub seed: u64,
    /// The load encoder closes the position loop (the dual loop); `false`: the motor encoder alone.
    pub dual_loop: bool,
    /// Master cycle (= 0x60C2), PWM periods of 40 us: 25 for 1 ms.
    pub cycle_periods: u64,
    /// Move of the load, degrees.
    pub load_degrees: f64,
    /// Peak motor velocity, rpm.
    pub max_rpm: f64,
    /// Peak motor acceleration, rpm/s.
    pub peak_rpm_per_s: f64,
    /// Time the master keeps sending the final set-point after the move, s.
    pub hold_s: f64,
    /// 0x30AE:01..03 written before the move (`None`: the dictionary defaults).
    pub main_loop_gains: Option<[u32; 3]>,
}

impl Default for DualLoopConfig {
    /// A quarter turn of the load at 1 ms set-points, up to 1,000 rpm and 10,000 rpm/s at the motor, held 1.5 s
    /// (module documentation: the settling ends 0.3 to 0.8 s after the move on geared-36v).
    fn default() -> Self {
        Self {
            seed: 1,
            dual_loop: true,
            cycle_periods: 25,
            load_degrees: 90.0,
            max_rpm: 1000.0,
            peak_rpm_per_s: 10_000.0,
            hold_s: 1.5,
            main_loop_gains: None,
        }
    }
}

/// Figures of the dual-loop scenario (module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DualLoopFigures {
    /// Largest |load target - load| during the move, load increments.
    pub load_following_error_peak_inc: f64,
    /// Largest |load target - load| over the last [`SETTLE_WINDOW_S`] of the hold, load increments.
    pub load_settle_error_inc: f64,
    /// Largest |motor angle / gear - load angle| over the run, degrees at the load.
    pub motor_load_deviation_peak_deg: f64,
    /// The gear's backlash, load increments (the plant's), for comparison.
    pub backlash_inc: f64,
    /// Largest |0x60F4| during the move, in the master's position units (the drive's own following error; load
    /// encoder increments in the dual loop).
    pub drive_following_error_peak_inc: f64,
    /// Duration of the move, s.
    pub move_s: f64,
    /// From the end of the move to the last instant the load was outside +-[`SETTLE_BAND_INC`], s; `None` when it
    /// is outside at the end of the hold.
    pub load_settle_time_s: Option<f64>,
}

/// Why the scenario did not run to its end.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DualLoopError {
    /// The plant has no load encoder.
    NoLoadEncoder,
    /// The drive refused a dual-loop object with this abort.
    Refused(SdoAbort),
    /// The simulation failed (a fault, a timeout).
    Sim(SimError),
}

impl From<SimError> for DualLoopError {
    fn from(e: SimError) -> Self {
        Self::Sim(e)
    }
}

impl core::fmt::Display for DualLoopError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NoLoadEncoder => {
                write!(f, "the plant has no load encoder (load_encoder_counts_per_rev = 0): the dual loop needs one")
            }
            Self::Refused(abort) => write!(f, "the drive refused the dual loop's objects: {abort:?}"),
            Self::Sim(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DualLoopError {}

/// Writes the dual loop's objects as a master would, over SDO with the power stage off, and checks the drive took
/// them.
pub fn configure_dual_loop(sim: &mut Simulation, gains: Option<[u32; 3]>) -> Result<(), SdoAbort> {
    let params = sim.plant.params().clone();
    let mut store = ParamStore::new(SimFlash::params());
    let ctx = AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 8 };
    let ratio = params.gear_ratio;
    // The plant's ratio as a fraction (5.0 = 5/1; a non-integer ratio in thousandths).
    let (num, den) = if ratio.fract() == 0.0 { (ratio as u32, 1u32) } else { ((ratio * 1000.0).round() as u32, 1000) };
    let mut writes: Vec<(u16, u8, Vec<u8>)> = vec![
        (0x3020, 1, (params.load_encoder_counts_per_rev / 4).to_le_bytes().to_vec()),
        (0x3003, 1, num.to_le_bytes().to_vec()),
        (0x3003, 2, den.to_le_bytes().to_vec()),
        (0x3000, 1, 0x0004_0201u32.to_le_bytes().to_vec()),
        (0x3000, 2, 0x0402_1111u32.to_le_bytes().to_vec()),
    ];
    if let Some(g) = gains {
        for (sub, value) in (1u8..).zip(g) {
            writes.push((0x30AE, sub, value.to_le_bytes().to_vec()));
        }
    }
    for (index, sub, data) in writes {
        sim.drive.sdo_write(index, sub, &data, ctx, &mut store)?;
    }
    Ok(())
}

/// Runs the scenario on `params`; the figures and a trace per slow tick.
pub fn dual_loop(params: PlantParams, config: &DualLoopConfig) -> Result<(DualLoopFigures, Trace), DualLoopError> {
    if params.load_encoder_counts_per_rev == 0 {
        return Err(DualLoopError::NoLoadEncoder);
    }
    let mut sim = prepare_plant_for_motion(params, config.seed)?;
    if config.dual_loop {
        configure_dual_loop(&mut sim, config.main_loop_gains).map_err(DualLoopError::Refused)?;
    }
    sim.enable_through_controlword(8)?;
    let p = sim.plant.params().clone();
    let motor_inc_per_rev = f64::from(p.encoder_counts_per_rev);
    let load_inc_per_rev = f64::from(p.load_encoder_counts_per_rev);
    // The master's units. The dual loop's configuration sets the gear in effect (0x3000:02 bit 12 with 0x3003) with
    // the load encoder as main sensor, so its positions count the load encoder's increments and its speeds are load
    // rpm (`firmware::motion::gear`, `UserUnits::with_main_sensor`); the motor-encoder run keeps motor increments
    // and motor rpm. `user_per_load_rev` is the master's position units per load revolution either way.
    let user_per_load_rev =
        if config.dual_loop { load_inc_per_rev } else { (p.gear_ratio * motor_inc_per_rev).round() };
    // Load-encoder increments per master position unit.
    let load_per_user = load_inc_per_rev / user_per_load_rev;
    let cycle_us = (config.cycle_periods as f64 * PERIOD_S * 1e6).round() as u32;
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::INTERPOLATION_TIME_PERIOD_VALUE, u8::try_from(cycle_us / 1000).unwrap_or(1));
        d.set(h::INTERPOLATION_TIME_INDEX, -3i8);
    }
    let start = f64::from(sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE));
    let load_start = sim.plant.load_encoder_count().unwrap_or(0) as f64;
    // The distance in the master's units, a whole number of them that is a whole number of load increments too, so
    // that the target is exact on both sides (a master unit is a whole number of motor increments with an integer
    // gear).
    let exact_step = exact_user_step(user_per_load_rev as u64, u64::from(p.load_encoder_counts_per_rev));
    let distance = (config.load_degrees / 360.0 * user_per_load_rev / exact_step).round() * exact_step;
    // Master units per second per motor rpm.
    let inc_per_s_per_rpm = user_per_load_rev / p.gear_ratio / 60.0;
    let mv = JerkLimitedMove::new(
        start,
        distance.round(),
        config.max_rpm * inc_per_s_per_rpm,
        config.peak_rpm_per_s * inc_per_s_per_rpm,
    );
    let cycle_s = config.cycle_periods as f64 * PERIOD_S;
    let move_cycles = (mv.duration_s() / cycle_s).ceil() as u64;
    let hold_cycles = (config.hold_s / cycle_s).ceil() as u64;
    let settle_from = move_cycles + hold_cycles - (SETTLE_WINDOW_S / cycle_s).ceil() as u64;
    let mut trace = Trace::new(&[
        "t_s",
        "load_target_inc",
        "load_inc",
        "load_following_error_inc",
        "motor_load_deviation_deg",
        "following_error_inc",
        "iq_a",
    ]);
    let (mut fe_peak, mut settle, mut deviation_peak, mut drive_fe_peak) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
    let mut periods: u64 = 0;
    // The last slow tick after the move with the load outside the band, s after the move's end.
    let mut last_outside_s: Option<f64> = None;
    let move_end_s = move_cycles as f64 * cycle_s;
    for cycle in 0..=move_cycles + hold_cycles {
        let t = cycle as f64 * cycle_s;
        let master = mv.position(t).round();
        sim.drive.dictionary_mut().set(h::TARGET_POSITION, master as i32);
        sim.setpoint_received();
        let load_target = load_start + (master - start) * load_per_user;
        for _ in 0..config.cycle_periods {
            sim.step();
            periods += 1;
            if !periods.is_multiple_of(PERIODS_PER_SLOW_TICK) {
                continue;
            }
            if let PowerState::Fault(e) = sim.drive.state() {
                return Err(SimError::Drive(e).into());
            }
            let load = sim.plant.load_encoder_count().unwrap_or(0) as f64;
            let error = load_target - load;
            let s = sim.plant.state();
            let deviation = (s.theta_m_rad / p.gear_ratio - s.load_angle_rad).to_degrees();
            deviation_peak = deviation_peak.max(deviation.abs());
            let fe = f64::from(sim.drive.dictionary().get(h::FOLLOWING_ERROR_ACTUAL_VALUE));
            if cycle <= move_cycles {
                fe_peak = fe_peak.max(error.abs());
                drive_fe_peak = drive_fe_peak.max(fe.abs());
            }
            if cycle >= settle_from {
                settle = settle.max(error.abs());
            }
            if cycle > move_cycles && error.abs() > SETTLE_BAND_INC {
                last_outside_s = Some(periods as f64 * PERIOD_S - move_end_s);
            }
            trace.push(&[
                sim.time_s(),
                load_target,
                load,
                error,
                deviation,
                fe,
                f64::from(sim.tier1().signals().i_dq.q.to_milliamps()) / 1000.0,
            ]);
        }
    }
    let figures = DualLoopFigures {
        load_following_error_peak_inc: fe_peak,
        load_settle_error_inc: settle,
        motor_load_deviation_peak_deg: deviation_peak,
        backlash_inc: p.gear_backlash_deg / 360.0 * load_inc_per_rev,
        drive_following_error_peak_inc: drive_fe_peak,
        move_s: mv.duration_s(),
        load_settle_time_s: if settle > SETTLE_BAND_INC { None } else { Some(last_outside_s.unwrap_or(0.0).max(0.0)) },
    };
    Ok((figures, trace))
}

/// The smallest number of master units that is a whole number of load increments: `user / gcd(user, load)` for
/// `user` master units and `load` load-encoder increments per load revolution.
fn exact_user_step(user_per_load_rev: u64, load_inc_per_rev: u64) -> f64 {
    let (mut a, mut b) = (user_per_load_rev.max(1), load_inc_per_rev.max(1));
    while b != 0 {
        (a, b) = (b, a % b);
    }
    (user_per_load_rev.max(1) / a) as f64
}
