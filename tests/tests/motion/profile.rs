//! The profile modes on the reference plant, driven through CiA 402 as a master drives them: PPM single moves
//! (trapezoidal and sin²), set of set-points, change on the fly; PVM reaching and holding a velocity, the speed
//! bit, halt and release.
//!
//! The figures come from `hal_sim::scenarios::profile` (its module documentation fixes the time base: tick 0 is the
//! slow tick that takes the set-point, the motion starts `L` = `COMMAND_LATENCY_TICKS` = 1 tick later, a profile of
//! `D` ticks has its last sample at tick `L + D - 1`, and a delay of 0 means the bit rises in that very tick). Gains, windows and profile objects are the dictionary defaults
//! unless a test says otherwise: 0x6067 = 10 inc, 0x6068 = 0 ms, 0x606D = 30 rpm, 0x606E = 0 ms, 0x606F = 10 rpm,
//! 0x6081 = 1,000 rpm, 0x6083 = 0x6084 = 10,000 rpm/s. The position window is the default; with a
//! 1-increment window the bound still holds (`ppm_bound_holds_with_a_one_increment_window`), only a 0-increment
//! window is beyond the plant (the last increment against 3 mNm of Coulomb friction takes the integral tens of
//! ticks after a sin² move).

use firmware::control::trajectory::COMMAND_LATENCY_TICKS;
use hal_sim::scenarios::profile::{self, PpmFigures, PpmSequenceFigures, Profile, PvmFigures, SPEED_RESOLUTION_RPM};

/// 0x6067 default, increments.
const POSITION_WINDOW_INC: i32 = 10;
/// The bound: statusword bit 10 no later than 2 slow ticks after the analytic profile time.
const DELAY_BOUND_TICKS: i64 = 2;
/// 0x606D default, rpm.
const VELOCITY_WINDOW_RPM: f64 = 30.0;
/// 0x606F default, rpm.
const VELOCITY_THRESHOLD_RPM: f64 = 40.0;

/// 5 revolutions at the default profile (trapezoidal 1,000 ticks), 40 revolutions at the reference motor's
/// 5,000 rpm maximum (20,000 / 30,000 rpm/s, both profile types reach it), and a short triangular move backwards.
const MOVES: [(i32, Profile); 3] = [(20_480, Profile::DEFAULT), (163_840, Profile::FAST), (-300, Profile::DEFAULT)];

/// The bus-voltage limiter's ceiling with the defaults (0x3202:04, where a braking q current reaches zero): the
/// bus must stay below it on every move, well under the 56 V trip. Measured: 29.6 V at 1,000 rpm, 52.3 to 52.7 V
/// braking from 5,000 rpm (the limiter's loss braking from 51 V holds it there).
const BUS_CEILING_V: f64 = 55.0;

/// The bounds of one PPM move.
///
/// - The set-point is acknowledged (bit 12) in the tick that sees bit 4 (the generator has room); the demand
///   starts moving `COMMAND_LATENCY_TICKS` (1) later (the drive plans the profile between the two ticks).
/// - `planned_duration_ticks` is the ceiling of the independent f64 duration (so the analytic time is the
///   profile's, not an artefact of the firmware's planner), and the demand arrives exactly at tick `L + D - 1`.
/// - Bit 10 rises between the end of the trajectory and 2 ticks later (issue), never earlier, and stays while
///   the axis holds: the position error stays inside the window (10 inc; measured 0 to 2 inc).
/// - Peak following error 0x60F4 <= 30 inc: the CSP bound, reused as a sanity check of the position loop
///   under the profile's feed-forward (measured 1 to 4 inc).
fn check_move(f: &PpmFigures, what: &str) {
    assert_eq!(f.ack_tick, 0, "{what}: {f:?}");
    assert_eq!(f.motion_start_tick, COMMAND_LATENCY_TICKS as i64, "{what}: {f:?}");
    let rounding = f.analytic_ticks as f64 - f.analytic_ticks_f64;
    assert!((0.0..1.0).contains(&rounding), "{what}: analytic time {f:?}");
    assert_eq!(f.trajectory_end_tick, profile::last_sample_tick(f.analytic_ticks), "{what}: {f:?}");
    assert!((0..=DELAY_BOUND_TICKS).contains(&f.target_reached_delay_ticks), "{what}: {f:?}");
    assert!(!f.bit10_early && f.bit10_stays, "{what}: {f:?}");
    assert!(f.final_error_inc.abs() <= POSITION_WINDOW_INC, "{what}: {f:?}");
    assert!(f.settled_error_max_inc <= POSITION_WINDOW_INC, "{what}: {f:?}");
    assert!(f.following_error_peak_inc <= 30, "{what}: {f:?}");
    assert!(f.bus_peak_v < BUS_CEILING_V, "{what}: the bus-voltage limiter holds the bus: {f:?}");
}

/// The fast case runs at the reference motor's full speed (issue: no longer held to 2,500 rpm by the bus): the
/// plant's peak speed is 5,000 rpm within the velocity loop's ripple (measured 5,003 to 5,015 rpm), and braking
/// from it does not trip the drive on over-voltage (`check_move` bounds the bus).
#[test]
fn ppm_fast_case_runs_at_5000_rpm_and_brakes_without_an_over_voltage_trip() {
    for profile_type in [0, 1] {
        let (f, _) = profile::ppm_move(1, profile_type, 163_840, &Profile::FAST).expect("no trip");
        check_move(&f, &format!("type {profile_type}"));
        assert!((4_990.0..=5_050.0).contains(&f.peak_speed_rpm), "{f:?}");
        assert!(f.bus_peak_v > 45.0, "the braking did lift the bus (the limiter had work to do): {f:?}");
    }
}

/// Trapezoidal PPM moves (0x6086 = 0) on three seeds. Measured: delay 0 on every move and seed (bit 10 in the
/// very tick the demand arrives), final error 0 inc, peak following error 3 to 4 inc.
#[test]
fn ppm_trapezoidal_move_reaches_the_target_within_two_ticks_of_the_profile() {
    for seed in 1..=3 {
        for (distance, p) in MOVES {
            let (f, trace) = profile::ppm_move(seed, 0, distance, &p).expect("scenario runs");
            check_move(&f, &format!("seed {seed} trapezoidal {distance}"));
            assert!(!trace.is_empty());
        }
    }
}

/// sin² PPM moves (0x6086 = 1): the ramps take twice as long (the objects are the peak acceleration). Same
/// bounds. Measured: delay 0, final error 0 inc, peak following error 1 to 2 inc.
#[test]
fn ppm_sin2_move_reaches_the_target_within_two_ticks_of_the_profile() {
    for seed in 1..=3 {
        for (distance, p) in MOVES {
            let (f, _) = profile::ppm_move(seed, 1, distance, &p).expect("scenario runs");
            check_move(&f, &format!("seed {seed} sin² {distance}"));
        }
    }
}

/// The default 10-increment window is generous for this plant: with 0x6067 = 1 inc the same bound holds
/// (measured delay 0 on seeds 1..4, both profile types; the axis is within 1 inc when the demand arrives). After
/// the 30,000 rpm/s stop of the fast trapezoidal move the axis settles through +-2 inc against the Coulomb
/// friction, so bit 10 may drop out of a 1-inc window for a few ticks there (and the settling error reaches 3 inc:
/// the loops' output applies in the middle of the slow period, as on the target); it stays set after the others.
#[test]
fn ppm_bound_holds_with_a_one_increment_window() {
    for profile_type in [0, 1] {
        for (distance, p) in MOVES {
            let (f, _) = profile::ppm_move_windowed(2, profile_type, distance, &p, 1, 0).expect("scenario runs");
            let what = format!("type {profile_type} {distance}");
            assert!((0..=DELAY_BOUND_TICKS).contains(&f.target_reached_delay_ticks), "{what}: {f:?}");
            assert!(f.final_error_inc.abs() <= 1, "{what}: {f:?}");
            let hard_stop = profile_type == 0 && p == Profile::FAST;
            assert!(f.bit10_stays || hard_stop, "{what}: {f:?}");
            // The hard stop rings through one increment more: measured 3.
            let settle_bound = if hard_stop { 3 } else { 2 };
            assert!(f.settled_error_max_inc <= settle_bound, "{what}: {f:?}");
        }
    }
}

/// The bounds common to both sequences: in order, bit 10 only at the end and within 2 ticks of the analytic
/// end, the final position inside the window.
fn check_sequence(f: &PpmSequenceFigures, what: &str) {
    assert!(f.ack_ticks[0] == 0 && f.ack_ticks[1] > 0, "{what}: {f:?}");
    assert!(f.demand_in_order, "{what}: the demand goes to the first target, then to the second: {f:?}");
    assert!(f.first_target_tick < f.trajectory_end_tick, "{what}: {f:?}");
    assert!(!f.bit10_early, "{what}: bit 10 only at the final target: {f:?}");
    assert!((0..=DELAY_BOUND_TICKS).contains(&f.target_reached_delay_ticks), "{what}: {f:?}");
    assert!(f.final_error_inc.abs() <= POSITION_WINDOW_INC, "{what}: {f:?}");
    assert!(f.following_error_peak_inc <= 30, "{what}: {f:?}");
}

/// Set of set-points (bit 5 = 0): the second set-point, sent half way through the first move, is acknowledged
/// and held in the buffer (bit 12 stays set after bit 4 falls, until the first move ends); the axis stops at the
/// first target and then moves on, forwards (2 then 4 revolutions) and back (2 then 0.5 revolutions).
///
/// "Stops": the sampled demand velocity near the first target is at most one tick of deceleration (0x6084 x
/// 400 us = 4 rpm; the continuous profile is at rest there, a sample may fall just after the buffered move
/// started), and the true speed of the plant falls below the velocity threshold 0x606F (10 rpm) at a position
/// within the position window of the first target. The chain lasts `ceil(T1 + T2)` (the buffered move starts at
/// the first one's continuous end). Measured: demand velocity 0 (trapezoidal) and 0.009 rpm (sin²), plant speed
/// 0 to 2.2 rpm, stop position within 1 inc of the first target, delay 0.
#[test]
fn ppm_set_of_set_points_stops_at_each_target_in_order() {
    for seed in [1, 2] {
        for profile_type in [0, 1] {
            for (first, second) in [(8192, 16_384), (8192, 2048)] {
                let (f, _) = profile::ppm_set_of_set_points(seed, profile_type, first, second, &Profile::default())
                    .expect("scenario runs");
                let what = format!("seed {seed} type {profile_type} {first} -> {second}");
                check_sequence(&f, &what);
                assert!(f.second_held_in_buffer, "{what}: {f:?}");
                assert!(f.demand_rpm_near_first <= 4.0, "{what}: the demand stops at the first target {f:?}");
                assert!(f.speed_near_first_rpm <= VELOCITY_THRESHOLD_RPM, "{what}: the axis stops {f:?}");
                assert!(f.stop_error_inc.abs() <= POSITION_WINDOW_INC, "{what}: where it stops {f:?}");
                assert_eq!(f.trajectory_end_tick, profile::last_sample_tick(f.analytic_ticks), "{what}: {f:?}");
            }
        }
    }
}

/// Change on the fly (bit 5 = 1): the second target (4 revolutions), sent half way to the first (2 revolutions),
/// replaces it at once; the axis passes the first target at the profile velocity and never stops before the
/// end. The change comes while cruising, so the blended move lasts as long as a direct move to the second
/// target: it ends at `D(start, t2) - 1`, one tick later allowed (the replanned remainder is rounded in Q32: with
/// sin² it ends one tick after the direct move's 1,100 ticks, measured). Bounds: no sample at rest before the
/// end, demand >= 99 % and plant >= 90 % of 0x6081 around the first target (a stop would take them to 0).
/// Measured: demand 1,000 rpm, plant 996 to 998 rpm, delay 0 (trapezoidal) and 1 (sin²).
#[test]
fn ppm_change_on_the_fly_goes_to_the_new_target_without_stopping() {
    for seed in [1, 2] {
        for profile_type in [0, 1] {
            let (f, _) = profile::ppm_change_on_the_fly(seed, profile_type, 8192, 16_384, &Profile::default())
                .expect("scenario runs");
            let what = format!("seed {seed} type {profile_type}");
            check_sequence(&f, &what);
            assert!(!f.second_held_in_buffer, "{what}: taken at once, not buffered: {f:?}");
            assert_eq!(f.demand_stops_before_end, 0, "{what}: {f:?}");
            assert!(f.demand_rpm_near_first >= 990.0, "{what}: {f:?}");
            assert!(f.speed_near_first_rpm >= 900.0, "{what}: {f:?}");
            let end = profile::last_sample_tick(f.analytic_ticks);
            assert!((end..=end + 1).contains(&f.trajectory_end_tick), "{what}: {f:?}");
        }
    }
}

/// Seeds and targets of the PVM tests: the default profile (10,000 rpm/s both ways), up and down in speed,
/// both directions.
fn pvm_runs() -> Vec<(u64, PvmFigures)> {
    let mut runs = Vec::new();
    for seed in 1..=3 {
        for rpm in [1000, -2000, 100] {
            let (f, trace) = profile::pvm(seed, rpm).expect("scenario runs");
            assert!(!trace.is_empty());
            runs.push((seed, f));
        }
    }
    runs
}

/// PVM reaches the target velocity and holds it within the velocity window.
///
/// - Bit 10 ("velocity within 0x606D for 0x606E") rises no later than 2 ticks after the end of the analytic
///   ramp (the PPM bound applied to PVM). It may rise earlier, by design: with 0x606E = 0 the window (30 rpm)
///   is entered 7.5 ticks before the end of a 4 rpm/tick ramp (measured 7 to 10 ticks early). At that tick the
///   true speed is within the window plus the estimate's resolution (one increment per tick, 36.6 rpm) of the
///   target.
/// - Holding (200 ms, from 50 ms after bit 10): the true speed stays within the window (measured peak deviation
///   1.7 to 2.4 rpm, RMS 0.70 to 0.87 rpm), bit 10 stays set, the mean error is below 1 rpm (the velocity
///   integral removes the friction error; measured <= 0.11 rpm).
#[test]
fn pvm_reaches_and_holds_the_target_velocity() {
    for (seed, f) in pvm_runs() {
        let what = format!("seed {seed} {} rpm", f.target_rpm);
        let target = f64::from(f.target_rpm);
        assert!(f.bit10_at_rest, "{what}: {f:?}");
        assert!(
            f.target_reached_tick <= profile::last_sample_tick(f.analytic_ticks) + DELAY_BOUND_TICKS,
            "{what}: {f:?}"
        );
        assert!((f.reached_speed_rpm - target).abs() <= VELOCITY_WINDOW_RPM + SPEED_RESOLUTION_RPM, "{what}: {f:?}");
        assert!(f.bit10_held, "{what}: {f:?}");
        assert!(f.ripple_peak_rpm <= VELOCITY_WINDOW_RPM, "{what}: {f:?}");
        assert!(f64::from(f.velocity_actual_peak_error_rpm) <= VELOCITY_WINDOW_RPM, "{what}: {f:?}");
        assert!(f.mean_error_rpm.abs() <= 1.0, "{what}: {f:?}");
    }
}

/// Bit 12 "speed = 0" (|0x606C| <= 0x606F): set at rest, clear while moving. The bit is evaluated on the
/// estimate, whose resolution is one increment per tick (36.6 rpm, 23 rpm after the 395 Hz filter), so the
/// comparison with the true speed has that margin: never set while |true speed| > 40 + 36.6 rpm, and the true
/// speed where it first falls (ramp up) and rises again (halt) is within it. The default threshold (40 rpm) lies
/// above one increment per tick, so the bit no longer drops at standstill (see the halt test); while a ramp
/// crosses the threshold it may still change a few times (5 instead of 3 changes per run measured; there is no
/// threshold time 0x6070), which the test records but does not bound.
#[test]
fn pvm_speed_zero_bit() {
    for (seed, f) in pvm_runs() {
        let what = format!("seed {seed} {} rpm", f.target_rpm);
        let margin = VELOCITY_THRESHOLD_RPM + SPEED_RESOLUTION_RPM;
        assert!(f.bit12_at_rest, "{what}: {f:?}");
        assert!(!f.bit12_while_moving, "{what}: {f:?}");
        assert!(f.bit12_fell_at_rpm.abs() <= margin, "{what}: {f:?}");
        assert!(f.bit12_rose_at_rpm.abs() <= margin, "{what}: {f:?}");
        assert!(f.bit12_toggles >= 3 && f.bit12_toggles % 2 == 1, "{what}: ends clear (moving): {f:?}");
    }
}

/// Halt (bit 8, 0x605D = 1: profile deceleration) stops the axis; releasing it resumes the target velocity.
///
/// - Bit 10 with halt ("velocity 0": the halt ramp has ended and |0x606C| <= 0x606F) within 2 ticks of the end
///   of the analytic halt ramp, with bit 12 set.
/// - Halted for 100 ms: the true speed stays below 0x606F and the position within the position window (the
///   halted PVM is on the velocity loop, nothing holds the position but the integral; measured drift <= 1 inc,
///   speed <= 6.4 rpm). Bit 12 stays set (the 40 rpm threshold is above the estimate's quantisation).
/// - Release: bit 10 again within the ramp's bound, the mean speed of the next 100 ms within 2 rpm of the target
///   (still includes the end of the ramp's settling; measured <= 0.72 rpm).
#[test]
fn pvm_halt_stops_and_release_resumes() {
    for (seed, f) in pvm_runs() {
        let what = format!("seed {seed} {} rpm", f.target_rpm);
        assert!(f.halt_ticks <= f.halt_analytic_ticks as i64 - 1 + DELAY_BOUND_TICKS, "{what}: {f:?}");
        assert!(f.halt_ticks >= f.halt_analytic_ticks as i64 - 1, "{what}: not before the ramp ends {f:?}");
        assert!(f.halt_bit12 && f.halt_speed_rpm.abs() <= VELOCITY_THRESHOLD_RPM, "{what}: {f:?}");
        assert!(f.halted_speed_max_rpm <= VELOCITY_THRESHOLD_RPM, "{what}: {f:?}");
        assert!(f.halted_drift_inc.abs() <= POSITION_WINDOW_INC, "{what}: {f:?}");
        assert_eq!(f.halted_bit12_clear_unexplained, 0, "{what}: {f:?}");
        assert_eq!(f.halted_bit12_clear_ticks, 0, "{what}: {f:?}");
        assert!(f.resume_ticks <= profile::last_sample_tick(f.analytic_ticks) + DELAY_BOUND_TICKS, "{what}: {f:?}");
        assert!((f.resumed_mean_rpm - f64::from(f.target_rpm)).abs() <= 2.0, "{what}: {f:?}");
    }
}
