//! The profile modes on the reference plant, driven through CiA 402 as a fieldbus master drives them: PPM
//! (0x6060 = 1) with the set-point handshake (controlword bits 4/5, statusword bits 10/12) and PVM (0x6060 = 3)
//! with halt (bit 8) and the speed bit (12). The master writes the controlword, 0x607A / 0x60FF and the profile
//! objects 0x6081 / 0x6083 / 0x6084 / 0x6086 into the dictionary between two slow ticks and reads the statusword
//! of each slow tick, as a PDO exchange once per slow tick would. `tests/tests/motion/profile.rs` asserts these
//! figures.
//!
//! # Time base
//! Everything is counted in slow ticks (400 us). Tick 0 is the slow tick that first sees the set-point (PPM: the
//! controlword with the rising bit 4; PVM: the new 0x60FF); its statusword already acknowledges it (bit 12).
//! The drive plans the profile before the next tick ([`COMMAND_LATENCY_TICKS`] = `L` = 1), and the generator
//! samples it once per tick from tick `L` on, so a profile of analytic duration `D` ticks
//! ([`planned_duration_ticks`], a whole number: the ceiling of the continuous time) has its last sample, exactly
//! on the target, at tick `L + D - 1`. A target-reached bit in that very tick is a delay of 0:
//! `target_reached_delay_ticks = first tick with bit 10 - (L + D - 1)`.
//!
//! The analytic duration is the firmware's own planner ([`planned_duration_ticks`]) fed with the dictionary's
//! profile objects converted exactly as the drive converts them (`ProfileObjects::profile_params` with the
//! encoder resolution 0x3000:05); [`PpmFigures::analytic_ticks_f64`] recomputes it independently in f64 from
//! the rpm and rpm/s values as a cross-check.

use firmware::cia402::State;
use firmware::control::trajectory::{
    planned_duration_ticks, planned_velocity_duration_ticks, MotionScale, ProfileObjects, ProfileParams, Velocity,
    COMMAND_LATENCY_TICKS, SLOW_TICK_HZ,
};
use firmware::od::generated::handles as h;
use firmware::power_state::PowerState;

use super::motion::{prepare_motion, INC_PER_REV};
use crate::sim::trace::Trace;
use crate::sim::{SimError, Simulation};

/// «Enable operation».
const ENABLE_OPERATION: u16 = 0x000F;
/// Controlword bit 4, new set-point.
const NEW_SET_POINT: u16 = 1 << 4;
/// Controlword bit 5, change set immediately.
const CHANGE_IMMEDIATELY: u16 = 1 << 5;
/// Controlword bit 8, halt.
const HALT: u16 = 1 << 8;
/// Statusword bit 10, target reached.
const TARGET_REACHED: u16 = 1 << 10;
/// Statusword bit 12 (PPM set-point acknowledge, PVM speed = 0).
const BIT12: u16 = 1 << 12;
/// Slow ticks of rest before the set-point (10 ms).
const REST_TICKS: u64 = 25;
/// Slow ticks recorded after the target was reached (100 ms).
const HOLD_TICKS: u64 = 250;
/// Budget beyond the analytic duration before a scenario gives up (1 s).
const SLACK_TICKS: u64 = 2_500;

/// Profile objects a master writes before a move: 0x6081, 0x6083, 0x6084 (0x6086 is a scenario argument).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Profile {
    /// 0x6081 profile velocity, rpm.
    pub velocity_rpm: u32,
    /// 0x6083 profile acceleration, rpm/s.
    pub acceleration_rpm_per_s: u32,
    /// 0x6084 profile deceleration, rpm/s.
    pub deceleration_rpm_per_s: u32,
}

impl Default for Profile {
    /// [`Profile::DEFAULT`].
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Profile {
    /// The dictionary defaults (`firmware/device.toml`): 1,000 rpm, 10,000 rpm/s both ways.
    pub const DEFAULT: Self =
        Self { velocity_rpm: 1000, acceleration_rpm_per_s: 10_000, deceleration_rpm_per_s: 10_000 };
    /// A fast profile: the reference motor's 5,000 rpm maximum, 20,000 rpm/s up, 30,000 rpm/s down. Braking from
    /// it returns 2.4 J, four times what the 470 uF bus holds below the 56 V trip; the drive's bus-voltage limiter
    /// (`firmware::drive::regeneration`) burns the rest in the winding, so the move keeps its profile.
    pub const FAST: Self = Self { velocity_rpm: 5000, acceleration_rpm_per_s: 20_000, deceleration_rpm_per_s: 30_000 };
}

/// One slow tick as the master sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    /// Slow tick, relative to the set-point (negative before it).
    tick: i64,
    /// 0x6062.
    demand: i32,
    /// 0x6064.
    actual: i32,
    /// 0x60F4.
    following_error: i32,
    /// 0x6041.
    statusword: u16,
    /// The demand velocity of the axis, rpm (exact, not rounded like 0x606B).
    demand_rpm: f64,
    /// 0x606C, rpm.
    velocity_rpm: i32,
    /// The plant's true speed, rpm.
    speed_rpm: f64,
    /// The plant's DC-bus voltage, V.
    bus_v: f64,
}

impl Sample {
    fn bit10(&self) -> bool {
        self.statusword & TARGET_REACHED != 0
    }

    fn bit12(&self) -> bool {
        self.statusword & BIT12 != 0
    }
}

/// The master: the simulation, the slow-tick counter and the samples.
struct Master {
    sim: Simulation,
    tick: i64,
    samples: Vec<Sample>,
}

/// Velocity (Q32 inc/tick) in rpm.
fn rpm_of(v: Velocity) -> f64 {
    v.to_bits() as f64 / 4_294_967_296.0 * f64::from(SLOW_TICK_HZ) * 60.0 / INC_PER_REV
}

impl Master {
    /// The reference plant enabled in `mode` at rest with `profile` and 0x6086 = `profile_type` written.
    /// `window`: 0x6067 / 0x6068 to write (`None`: the dictionary's).
    fn new(
        seed: u64,
        mode: i8,
        profile_type: i16,
        profile: &Profile,
        window: Option<(u32, u16)>,
    ) -> Result<Self, SimError> {
        let mut sim = prepare_motion(seed, mode)?;
        let d = sim.drive.dictionary_mut();
        if let Some((inc, ms)) = window {
            d.set(h::POSITION_WINDOW, inc);
            d.set(h::POSITION_WINDOW_TIME, ms);
        }
        d.set(h::PROFILE_VELOCITY, profile.velocity_rpm);
        d.set(h::PROFILE_ACCELERATION, profile.acceleration_rpm_per_s);
        d.set(h::PROFILE_DECELERATION, profile.deceleration_rpm_per_s);
        d.set(h::MOTION_PROFILE_TYPE, profile_type);
        let mut m = Self { sim, tick: -(REST_TICKS as i64), samples: Vec::new() };
        m.run(REST_TICKS)?;
        Ok(m)
    }

    /// One slow tick: PWM periods until the axis has stepped, then the sample of that tick.
    fn tick(&mut self) -> Result<Sample, SimError> {
        let before = self.sim.drive.axis().now();
        let mut periods = 0;
        while self.sim.drive.axis().now() == before {
            self.sim.step();
            periods += 1;
            if periods > 100 {
                return Err(SimError::Timeout("a slow tick"));
            }
        }
        if let PowerState::Fault(e) = self.sim.drive.state() {
            return Err(SimError::Drive(e));
        }
        if self.sim.cia402_state() != State::OperationEnabled {
            return Err(SimError::Timeout("the motion: the CiA 402 machine left Operation enabled"));
        }
        let d = self.sim.drive.dictionary();
        let s = Sample {
            tick: self.tick,
            demand: d.get(h::POSITION_DEMAND_VALUE),
            actual: d.get(h::POSITION_ACTUAL_VALUE),
            following_error: d.get(h::FOLLOWING_ERROR_ACTUAL_VALUE),
            statusword: d.get(h::STATUSWORD),
            demand_rpm: rpm_of(self.sim.drive.axis().setpoint().velocity),
            velocity_rpm: d.get(h::VELOCITY_ACTUAL_VALUE),
            speed_rpm: self.sim.plant.state().speed_rpm,
            bus_v: self.sim.plant.state().bus_voltage_v,
        };
        self.samples.push(s);
        self.tick += 1;
        Ok(s)
    }

    fn run(&mut self, n: u64) -> Result<(), SimError> {
        for _ in 0..n {
            self.tick()?;
        }
        Ok(())
    }

    /// Ticks until `done` holds for a sample (that sample returned) or `max` ticks have passed.
    fn run_until(
        &mut self,
        max: u64,
        what: &'static str,
        mut done: impl FnMut(&Sample) -> bool,
    ) -> Result<Sample, SimError> {
        for _ in 0..max {
            let s = self.tick()?;
            if done(&s) {
                return Ok(s);
            }
        }
        Err(SimError::Timeout(what))
    }

    fn controlword(&mut self, cw: u16) {
        self.sim.set_controlword(cw);
    }

    fn last(&self) -> Sample {
        self.samples.last().copied().unwrap_or(Sample {
            tick: 0,
            demand: 0,
            actual: 0,
            following_error: 0,
            statusword: 0,
            demand_rpm: 0.0,
            velocity_rpm: 0,
            speed_rpm: 0.0,
            bus_v: 0.0,
        })
    }

    /// The profile parameters exactly as the drive converts them from the dictionary (`motion::params`).
    fn profile_params(&self) -> Option<ProfileParams> {
        let d = self.sim.drive.dictionary();
        let objects = ProfileObjects {
            profile_velocity: d.get(h::PROFILE_VELOCITY),
            profile_acceleration: d.get(h::PROFILE_ACCELERATION),
            profile_deceleration: d.get(h::PROFILE_DECELERATION),
            quick_stop_deceleration: d.get(h::QUICK_STOP_DECELERATION),
            max_profile_velocity: d.get(h::MAX_PROFILE_VELOCITY),
            max_acceleration: d.get(h::MAX_ACCELERATION),
            max_deceleration: d.get(h::MAX_DECELERATION),
            motion_profile_type: d.get(h::MOTION_PROFILE_TYPE),
        };
        objects.profile_params(&MotionScale::new(d.get(h::MAIN_SENSOR_RESOLUTION).max(1))).ok()
    }

    /// `D` of a move from rest at `start` to `target`.
    fn planned(&self, start: i32, target: i32) -> Result<u64, SimError> {
        let p = self.profile_params().ok_or(SimError::Timeout("valid profile parameters"))?;
        planned_duration_ticks(i64::from(start), Velocity::ZERO, i64::from(target), &p)
            .ok_or(SimError::Timeout("valid profile parameters"))
    }

    /// The trace: one row per slow tick.
    fn trace(&self) -> Trace {
        let mut trace = Trace::new(&[
            "t_s",
            "demand_inc",
            "actual_inc",
            "following_error_inc",
            "statusword",
            "bit10",
            "bit12",
            "demand_rpm",
            "velocity_rpm",
            "speed_rpm",
        ]);
        for s in &self.samples {
            trace.push(&[
                s.tick as f64 / f64::from(SLOW_TICK_HZ),
                f64::from(s.demand),
                f64::from(s.actual),
                f64::from(s.following_error),
                f64::from(s.statusword),
                f64::from(u8::from(s.bit10())),
                f64::from(u8::from(s.bit12())),
                s.demand_rpm,
                f64::from(s.velocity_rpm),
                s.speed_rpm,
            ]);
        }
        trace
    }

    /// Samples from tick `from` (relative) on.
    fn since(&self, from: i64) -> impl Iterator<Item = &Sample> + '_ {
        self.samples.iter().filter(move |s| s.tick >= from)
    }

    /// A PPM set-point as a master sends it: 0x607A, bit 4 (with bit 5 when `immediately`) until bit 12 answers,
    /// then bit 4 cleared. Returns the tick whose statusword acknowledged it.
    fn ppm_set_point(&mut self, target: i32, immediately: bool) -> Result<i64, SimError> {
        self.sim.drive.dictionary_mut().set(h::TARGET_POSITION, target);
        let bit5 = if immediately { CHANGE_IMMEDIATELY } else { 0 };
        self.controlword(ENABLE_OPERATION | NEW_SET_POINT | bit5);
        // The acknowledge is the first tick whose statusword shows bit 12: the edge's own tick when the generator
        // has room (not usable for a third set-point while one waits in the buffer: bit 12 is already set then).
        let ack = self.run_until(50, "the set-point acknowledge (bit 12)", Sample::bit12)?;
        self.controlword(ENABLE_OPERATION);
        Ok(ack.tick)
    }
}

/// Independent check of the analytic duration: a trapezoidal or sin² profile from rest to rest, in f64 ticks
/// (not rounded up). The sin² ramp's mean acceleration is half the peak (= the profile object).
fn analytic_ticks_f64(profile_type: i16, distance: f64, p: &Profile, max_rpm: u32) -> f64 {
    let per_rpm = INC_PER_REV / 60.0;
    let shape = if profile_type == 1 { 0.5 } else { 1.0 };
    let v = f64::from(p.velocity_rpm.min(max_rpm)) * per_rpm;
    let a = f64::from(p.acceleration_rpm_per_s) * per_rpm * shape;
    let d = f64::from(p.deceleration_rpm_per_s) * per_rpm * shape;
    let s = distance.abs();
    // Peak velocity: the profile velocity, or lower when the two ramps do not fit (triangular).
    let vp = v.min((2.0 * s * a * d / (a + d)).sqrt());
    let ramps = vp * vp / (2.0 * a) + vp * vp / (2.0 * d);
    let t = vp / a + vp / d + if vp > 0.0 { (s - ramps) / vp } else { 0.0 };
    t * f64::from(SLOW_TICK_HZ)
}

// ---------------------------------------------------------------------------------------------------------------
// PPM
// ---------------------------------------------------------------------------------------------------------------

/// The tick of the last sample of a profile of `analytic` ticks started by a command at tick 0: `L + D - 1`.
#[must_use]
pub fn last_sample_tick(analytic: u64) -> i64 {
    i64::try_from(COMMAND_LATENCY_TICKS.saturating_add(analytic)).unwrap_or(i64::MAX).saturating_sub(1)
}

/// Figures of one absolute PPM move from rest (see the module documentation for the time base).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PpmFigures {
    /// 0x6086: 0 trapezoidal, 1 sin².
    pub profile_type: i16,
    /// 0x607A written, increments (start + distance).
    pub target_inc: i32,
    /// Analytic profile duration `D` in slow ticks, from `planned_duration_ticks` with the drive's conversion.
    pub analytic_ticks: u64,
    /// The same duration computed independently in f64 from the rpm / rpm/s objects (not rounded up).
    pub analytic_ticks_f64: f64,
    /// Tick of the acknowledge (bit 12) relative to the tick that first saw bit 4: 0 when taken at once.
    pub ack_tick: i64,
    /// First tick with a non-zero demand velocity (expected `L` = [`COMMAND_LATENCY_TICKS`]).
    pub motion_start_tick: i64,
    /// First tick whose demand 0x6062 is the target with zero demand velocity (expected `L + D - 1`).
    pub trajectory_end_tick: i64,
    /// First tick after the acknowledge with statusword bit 10 set.
    pub target_reached_tick: i64,
    /// `target_reached_tick - (L + D - 1)`: slow ticks bit 10 lags the end of the analytic profile (the issue's
    /// key).
    pub target_reached_delay_ticks: i64,
    /// Bit 10 was seen set between the acknowledge and `target_reached_tick` (it must not be).
    pub bit10_early: bool,
    /// Bit 10 stayed set for the 100 ms recorded after it rose.
    pub bit10_stays: bool,
    /// |0x6064 - target| when bit 10 rose, increments.
    pub reached_error_inc: i32,
    /// 0x6064 - target 100 ms after bit 10 rose, increments.
    pub final_error_inc: i32,
    /// Largest |0x6064 - target| over those 100 ms, increments.
    pub settled_error_max_inc: i32,
    /// Largest |0x60F4| from the acknowledge to the end of the record, increments.
    pub following_error_peak_inc: i32,
    /// Largest |plant speed| during the move, rpm.
    pub peak_speed_rpm: f64,
    /// Highest DC-bus voltage of the plant from the acknowledge to the end of the record, V (sampled once per slow
    /// tick).
    pub bus_peak_v: f64,
}

/// One absolute PPM move of `distance` increments from rest on the reference plant (0x6060 = 1), with 0x6086 =
/// `profile_type` and `profile`; position window 0x6067/0x6068 as in the dictionary (defaults 10 inc, 0 ms).
/// Returns the figures and a trace per slow tick (t, 0x6062, 0x6064, 0x60F4, 0x6041 and its bits 10/12, demand
/// velocity, 0x606C, true speed).
pub fn ppm_move(
    seed: u64,
    profile_type: i16,
    distance: i32,
    profile: &Profile,
) -> Result<(PpmFigures, Trace), SimError> {
    ppm_move_inner(seed, profile_type, distance, profile, None)
}

/// [`ppm_move`] with the position window 0x6067 = `window_inc` and the window time 0x6068 = `window_ms` written
/// before the move (how much bit 10 depends on the window).
pub fn ppm_move_windowed(
    seed: u64,
    profile_type: i16,
    distance: i32,
    profile: &Profile,
    window_inc: u32,
    window_ms: u16,
) -> Result<(PpmFigures, Trace), SimError> {
    ppm_move_inner(seed, profile_type, distance, profile, Some((window_inc, window_ms)))
}

fn ppm_move_inner(
    seed: u64,
    profile_type: i16,
    distance: i32,
    profile: &Profile,
    window: Option<(u32, u16)>,
) -> Result<(PpmFigures, Trace), SimError> {
    let mut m = Master::new(seed, 1, profile_type, profile, window)?;
    let start = m.last().demand;
    let target = start.wrapping_add(distance);
    let analytic = m.planned(start, target)?;
    let max_rpm = m.sim.drive.dictionary().get(h::MAX_PROFILE_VELOCITY);
    let analytic_f64 = analytic_ticks_f64(profile_type, f64::from(distance), profile, max_rpm);

    let ack = m.ppm_set_point(target, false)?;
    let budget = analytic.saturating_add(SLACK_TICKS);
    let reached = m.run_until(budget, "PPM target reached (bit 10)", Sample::bit10)?;
    m.run(HOLD_TICKS)?;

    let end_tick = m.since(0).find(|s| s.demand == target && s.demand_rpm == 0.0).map_or(i64::MAX, |s| s.tick);
    let start_tick = m.since(0).find(|s| s.demand_rpm != 0.0).map_or(i64::MAX, |s| s.tick);
    let hold: Vec<&Sample> = m.since(reached.tick).collect();
    let figures = PpmFigures {
        profile_type,
        target_inc: target,
        analytic_ticks: analytic,
        analytic_ticks_f64: analytic_f64,
        ack_tick: ack,
        motion_start_tick: start_tick,
        trajectory_end_tick: end_tick,
        target_reached_tick: reached.tick,
        target_reached_delay_ticks: reached.tick - last_sample_tick(analytic),
        bit10_early: m.since(ack).any(|s| s.tick < reached.tick && s.bit10()),
        bit10_stays: hold.iter().all(|s| s.bit10()),
        reached_error_inc: (reached.actual.wrapping_sub(target)).abs(),
        final_error_inc: m.last().actual.wrapping_sub(target),
        settled_error_max_inc: hold.iter().map(|s| s.actual.wrapping_sub(target).abs()).max().unwrap_or(0),
        following_error_peak_inc: m.since(ack).map(|s| s.following_error.abs()).max().unwrap_or(0),
        peak_speed_rpm: m.since(ack).map(|s| s.speed_rpm.abs()).fold(0.0, f64::max),
        bus_peak_v: m.since(ack).map(|s| s.bus_v).fold(0.0, f64::max),
    };
    Ok((figures, m.trace()))
}

/// Figures of a pair of PPM set-points (set of set-points or change on the fly).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PpmSequenceFigures {
    /// The two absolute targets 0x607A, in the order sent.
    pub targets: [i32; 2],
    /// Ticks of the two acknowledges (bit 12), relative to the first set-point.
    pub ack_ticks: [i64; 2],
    /// The first move's demand position when the second set-point was acknowledged, increments.
    pub demand_at_second_inc: i32,
    /// Bit 12 stayed set from the second acknowledge until the demand reached the first target (after bit 4
    /// fell): the set-point waited in the buffer.
    pub second_held_in_buffer: bool,
    /// First tick whose demand 0x6062 reached (or passed) the first target.
    pub first_target_tick: i64,
    /// Smallest |demand velocity| within 10 ms around `first_target_tick`, rpm (0: the demand stops there).
    pub demand_rpm_near_first: f64,
    /// Smallest |plant speed| within 10 ms around `first_target_tick`, rpm.
    pub speed_near_first_rpm: f64,
    /// 0x6064 - first target at the tick of that smallest speed, increments (where the axis stopped, if it did).
    pub stop_error_inc: i32,
    /// Ticks between the start of the first motion (tick `L`) and the end of the last trajectory where the demand
    /// velocity was zero.
    pub demand_stops_before_end: u32,
    /// The demand went from the start to the first target, then from there to the second, each leg monotonic
    /// and inside its span (no overshoot, nothing out of order).
    pub demand_in_order: bool,
    /// First tick whose demand is the last target at rest (end of the last trajectory; expected `L + D - 1`).
    pub trajectory_end_tick: i64,
    /// Analytic duration of the sequence, whole ticks. Set of set-points: `ceil(T1 + T2)` of the two moves from
    /// rest to rest (f64, independent of the firmware: the buffered move starts at the first one's continuous
    /// end); change on the fly: `planned_duration_ticks(start, t2)` (the change comes while cruising, so the
    /// blended move lasts as long as a direct move to the second target).
    pub analytic_ticks: u64,
    /// The same in continuous ticks (f64, not rounded up).
    pub analytic_ticks_f64: f64,
    /// First tick with bit 10 after the second acknowledge.
    pub target_reached_tick: i64,
    /// `target_reached_tick - (L + analytic_ticks - 1)`.
    pub target_reached_delay_ticks: i64,
    /// Bit 10 was seen set between the first acknowledge and `target_reached_tick`.
    pub bit10_early: bool,
    /// 0x6064 - last target 100 ms after bit 10 rose, increments.
    pub final_error_inc: i32,
    /// Largest |0x60F4| over the sequence, increments.
    pub following_error_peak_inc: i32,
}

/// Two absolute set-points `start + first` then `start + second`; the second is sent when the demand has covered
/// half of the first distance. `immediately = false`: set of set-points (bit 5 = 0, buffered);
/// `immediately = true`: change on the fly (bit 5 = 1).
fn ppm_pair(
    seed: u64,
    profile_type: i16,
    first: i32,
    second: i32,
    profile: &Profile,
    immediately: bool,
) -> Result<(PpmSequenceFigures, Trace), SimError> {
    let mut m = Master::new(seed, 1, profile_type, profile, None)?;
    let start = m.last().demand;
    let targets = [start.wrapping_add(first), start.wrapping_add(second)];
    let max_rpm = m.sim.drive.dictionary().get(h::MAX_PROFILE_VELOCITY);
    let continuous = |from: i32, to: i32| analytic_ticks_f64(profile_type, f64::from(to - from), profile, max_rpm);
    let (analytic, analytic_f64) = if immediately {
        (m.planned(start, targets[1])?, continuous(start, targets[1]))
    } else {
        // The buffered move continues from the first one's exact end (the generator carries the time past the
        // end into it), so the chain lasts ceil(T1 + T2), not ceil(T1) + ceil(T2).
        let t = continuous(start, targets[0]) + continuous(targets[0], targets[1]);
        ((t - 1e-6).ceil() as u64, t)
    };
    let ack1 = m.ppm_set_point(targets[0], false)?;
    let half = start.wrapping_add(first / 2);
    let dir = first.signum();
    m.run_until(analytic, "the first move's half way", |s| (s.demand.wrapping_sub(half)) * dir >= 0)?;
    let ack2 = m.ppm_set_point(targets[1], immediately)?;
    let demand_at_second = m.last().demand;
    let budget = analytic.saturating_add(SLACK_TICKS);
    let reached = m.run_until(budget, "PPM target reached (bit 10)", Sample::bit10)?;
    m.run(HOLD_TICKS)?;

    let first_tick = m.since(0).find(|s| s.demand.wrapping_sub(targets[0]) * dir >= 0).map_or(i64::MAX, |s| s.tick);
    let near: Vec<&Sample> = m.since(0).filter(|s| (s.tick - first_tick).abs() <= 25).collect();
    let slowest = near.iter().min_by(|a, b| a.speed_rpm.abs().total_cmp(&b.speed_rpm.abs())).copied();
    let end_tick = m.since(0).find(|s| s.demand == targets[1] && s.demand_rpm == 0.0).map_or(i64::MAX, |s| s.tick);
    let motion_start = i64::try_from(COMMAND_LATENCY_TICKS).unwrap_or(i64::MAX);
    let moving: Vec<&Sample> = m.since(motion_start).filter(|s| s.tick < end_tick).collect();
    // One leg: every demand between `from` and `to`, monotonic towards `to`.
    let leg = |samples: &[&Sample], from: i32, to: i32| {
        let (lo, hi) = (from.min(to), from.max(to));
        let dir = (to - from).signum();
        samples.iter().all(|s| (lo..=hi).contains(&s.demand))
            && samples.windows(2).all(|w| (w[1].demand - w[0].demand) * dir >= 0)
    };
    let split = moving.partition_point(|s| s.tick < first_tick);
    let in_order = first_tick < end_tick
        && leg(&moving[..split], start, targets[0])
        && leg(&moving[split..], targets[0], targets[1]);
    let figures = PpmSequenceFigures {
        targets,
        ack_ticks: [ack1, ack2],
        demand_at_second_inc: demand_at_second,
        second_held_in_buffer: m.since(ack2).filter(|s| s.tick <= first_tick).all(Sample::bit12),
        first_target_tick: first_tick,
        demand_rpm_near_first: near.iter().map(|s| s.demand_rpm.abs()).fold(f64::INFINITY, f64::min),
        speed_near_first_rpm: slowest.map_or(f64::NAN, |s| s.speed_rpm.abs()),
        stop_error_inc: slowest.map_or(i32::MAX, |s| s.actual.wrapping_sub(targets[0])),
        demand_stops_before_end: moving.iter().filter(|s| s.demand_rpm == 0.0).count() as u32,
        demand_in_order: in_order,
        trajectory_end_tick: end_tick,
        analytic_ticks: analytic,
        analytic_ticks_f64: analytic_f64,
        target_reached_tick: reached.tick,
        target_reached_delay_ticks: reached.tick - last_sample_tick(analytic),
        bit10_early: m.since(ack1).any(|s| s.tick < reached.tick && s.bit10()),
        final_error_inc: m.last().actual.wrapping_sub(targets[1]),
        following_error_peak_inc: m.since(0).map(|s| s.following_error.abs()).max().unwrap_or(0),
    };
    Ok((figures, m.trace()))
}

/// Set of set-points (bit 5 = 0): the first target `start + first`; when the demand is half way there, the
/// second `start + second` is sent and waits in the buffer; the axis stops at the first target, then moves on.
pub fn ppm_set_of_set_points(
    seed: u64,
    profile_type: i16,
    first: i32,
    second: i32,
    profile: &Profile,
) -> Result<(PpmSequenceFigures, Trace), SimError> {
    ppm_pair(seed, profile_type, first, second, profile, false)
}

/// Change on the fly (bit 5 = 1): the first target `start + first`; when the demand is half way there, the
/// second `start + second` replaces it at once; the axis goes to the second target without stopping.
pub fn ppm_change_on_the_fly(
    seed: u64,
    profile_type: i16,
    first: i32,
    second: i32,
    profile: &Profile,
) -> Result<(PpmSequenceFigures, Trace), SimError> {
    ppm_pair(seed, profile_type, first, second, profile, true)
}

// ---------------------------------------------------------------------------------------------------------------
// PVM
// ---------------------------------------------------------------------------------------------------------------

/// One increment per slow tick in rpm at 4,096 inc/rev (36.6 rpm): the resolution of the position difference the
/// velocity actual value 0x606C is estimated from, hence the margin of any comparison of the estimate-based bits
/// (10, 12) with the true speed.
pub const SPEED_RESOLUTION_RPM: f64 = SLOW_TICK_HZ as f64 * 60.0 / INC_PER_REV;

/// Figures of the PVM scenario (velocity window 0x606D / 0x606E, threshold 0x606F as in the dictionary:
/// defaults 30 rpm, 0 ms, 10 rpm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PvmFigures {
    /// 0x60FF, rpm.
    pub target_rpm: i32,
    /// Analytic duration of the ramp from rest (`planned_velocity_duration_ticks`), slow ticks.
    pub analytic_ticks: u64,
    /// First tick with bit 10 after the target was written (tick 0 = the tick that first saw 0x60FF; the ramp
    /// ends at `L + D - 1`).
    pub target_reached_tick: i64,
    /// True speed at that tick, rpm.
    pub reached_speed_rpm: f64,
    /// Bit 12 set on every tick of the 10 ms at rest before the target.
    pub bit12_at_rest: bool,
    /// Bit 10 set at rest before the target (target 0 reached).
    pub bit10_at_rest: bool,
    /// True speed of the plant at the first tick with bit 12 clear (start of the ramp), rpm.
    pub bit12_fell_at_rpm: f64,
    /// True speed of the plant at the first tick with bit 12 set again after the halt, rpm.
    pub bit12_rose_at_rpm: f64,
    /// Changes of bit 12 from the target write to the end: 3 for a clean bit (falls, rises at the halt, falls
    /// again), more when it chatters near the threshold (the estimate's quantisation, no threshold time 0x6070).
    pub bit12_toggles: u32,
    /// Bit 12 was seen set while |true speed| exceeded 0x606F by more than [`SPEED_RESOLUTION_RPM`].
    pub bit12_while_moving: bool,
    /// Mean true speed minus target over the hold (200 ms, starting 50 ms after bit 10), rpm.
    pub mean_error_rpm: f64,
    /// RMS of (true speed - target) over the hold, rpm.
    pub ripple_rms_rpm: f64,
    /// Largest |true speed - target| over the hold, rpm.
    pub ripple_peak_rpm: f64,
    /// Largest |0x606C - target| over the hold (what bit 10 sees), rpm.
    pub velocity_actual_peak_error_rpm: i32,
    /// Bit 10 stayed set over the hold.
    pub bit10_held: bool,
    /// Analytic duration of the halt ramp (0x605D = 1: 0x6084), slow ticks.
    pub halt_analytic_ticks: u64,
    /// First tick with bit 10 (halt: "velocity 0") counted from the first tick that saw bit 8 (`D - 1` when it
    /// comes with the end of the halt ramp).
    pub halt_ticks: i64,
    /// Bit 12 at that tick.
    pub halt_bit12: bool,
    /// Ticks with bit 12 clear over the 100 ms halted after bit 10 (250 ticks).
    pub halted_bit12_clear_ticks: u32,
    /// Of those, ticks whose 0x6064 equals the previous tick's: a clear bit not explained by a one-increment
    /// step of the encoder (a single increment in one tick reads 36.6 rpm, 23 rpm after the 395 Hz low-pass of
    /// the estimate, above the 10 rpm threshold).
    pub halted_bit12_clear_unexplained: u32,
    /// True speed at that tick, rpm.
    pub halt_speed_rpm: f64,
    /// Largest |true speed| over 100 ms halted after bit 10, rpm.
    pub halted_speed_max_rpm: f64,
    /// Position change over those 100 ms, increments.
    pub halted_drift_inc: i32,
    /// First tick with bit 10 again counted from the first tick that saw bit 8 cleared (the ramp ends at
    /// `L + D - 1`).
    pub resume_ticks: i64,
    /// Mean true speed over 100 ms after the resumed target was reached, rpm.
    pub resumed_mean_rpm: f64,
}

/// PVM (0x6060 = 3) on the reference plant with the default profile objects: 10 ms at rest, 0x60FF =
/// `target_rpm`, reached and held 250 ms, halt (bit 8) to standstill, 100 ms halted, release and resume.
pub fn pvm(seed: u64, target_rpm: i32) -> Result<(PvmFigures, Trace), SimError> {
    let mut m = Master::new(seed, 3, 0, &Profile::default(), None)?;
    let threshold = f64::from(m.sim.drive.dictionary().get(h::VELOCITY_THRESHOLD));
    let rest: Vec<Sample> = m.samples.clone();
    let params = m.profile_params().ok_or(SimError::Timeout("valid profile parameters"))?;
    let scale = MotionScale::new(m.sim.drive.dictionary().get(h::MAIN_SENSOR_RESOLUTION).max(1));
    let v_target = scale.velocity_from_rpm(i64::from(target_rpm));
    let analytic = planned_velocity_duration_ticks(Velocity::ZERO, v_target, &params).unwrap_or(u64::MAX);
    let halt_analytic = planned_velocity_duration_ticks(v_target, Velocity::ZERO, &params).unwrap_or(u64::MAX);
    let target = f64::from(target_rpm);

    // The master writes 0x60FF with the controlword (IDX: a new target velocity is taken with the controlword).
    m.sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, target_rpm);
    m.controlword(ENABLE_OPERATION);
    // Bit 10 falls at once (the velocity is outside the window); the first tick it is set again is the reach.
    let reached = m.run_until(analytic.saturating_add(SLACK_TICKS), "PVM target reached", Sample::bit10)?;
    let settle = 125; // 50 ms
    m.run(settle + 500)?;
    let hold: Vec<Sample> = m.since(reached.tick + settle as i64).copied().collect();
    let errors: Vec<f64> = hold.iter().map(|s| s.speed_rpm - target).collect();
    let n = errors.len().max(1) as f64;

    // Halt.
    m.controlword(ENABLE_OPERATION | HALT);
    let halt_from = m.tick;
    let halted =
        m.run_until(halt_analytic.saturating_add(SLACK_TICKS), "PVM halt standstill (bit 10)", Sample::bit10)?;
    m.run(250)?;
    let after_halt: Vec<Sample> = m.since(halted.tick).copied().collect();

    // Release.
    m.controlword(ENABLE_OPERATION);
    let release_from = m.tick;
    let resumed = m.run_until(analytic.saturating_add(SLACK_TICKS), "PVM resumed target (bit 10)", Sample::bit10)?;
    m.run(250)?;
    let resumed_hold: Vec<Sample> = m.since(resumed.tick).copied().collect();

    let moving_fast = |s: &Sample| s.speed_rpm.abs() > threshold + SPEED_RESOLUTION_RPM;
    let from_target: Vec<&Sample> = m.since(0).collect();
    let figures = PvmFigures {
        target_rpm,
        analytic_ticks: analytic,
        target_reached_tick: reached.tick,
        reached_speed_rpm: reached.speed_rpm,
        bit12_at_rest: rest.iter().all(Sample::bit12),
        bit10_at_rest: rest.last().is_some_and(Sample::bit10),
        bit12_fell_at_rpm: m.since(0).find(|s| !s.bit12()).map_or(f64::NAN, |s| s.speed_rpm),
        bit12_rose_at_rpm: m.since(halt_from).find(|s| s.bit12()).map_or(f64::NAN, |s| s.speed_rpm),
        bit12_toggles: from_target.windows(2).filter(|w| w[0].bit12() != w[1].bit12()).count() as u32,
        bit12_while_moving: m.since(0).any(|s| moving_fast(s) && s.bit12()),
        mean_error_rpm: errors.iter().sum::<f64>() / n,
        ripple_rms_rpm: (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        ripple_peak_rpm: errors.iter().map(|e| e.abs()).fold(0.0, f64::max),
        velocity_actual_peak_error_rpm: hold.iter().map(|s| (s.velocity_rpm - target_rpm).abs()).max().unwrap_or(0),
        bit10_held: hold.iter().all(Sample::bit10),
        halt_analytic_ticks: halt_analytic,
        halt_ticks: halted.tick - halt_from,
        halt_bit12: halted.bit12(),
        halted_bit12_clear_ticks: after_halt.iter().filter(|s| !s.bit12()).count() as u32,
        halted_bit12_clear_unexplained: after_halt
            .windows(2)
            .filter(|w| !w[1].bit12() && w[1].actual == w[0].actual)
            .count() as u32,
        halt_speed_rpm: halted.speed_rpm,
        halted_speed_max_rpm: after_halt.iter().map(|s| s.speed_rpm.abs()).fold(0.0, f64::max),
        halted_drift_inc: after_halt.last().map_or(0, |s| s.actual.wrapping_sub(halted.actual)),
        resume_ticks: resumed.tick - release_from,
        resumed_mean_rpm: resumed_hold.iter().map(|s| s.speed_rpm).sum::<f64>() / resumed_hold.len().max(1) as f64,
    };
    Ok((figures, m.trace()))
}
