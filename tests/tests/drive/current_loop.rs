//! The current loop on the reference plant: step response, bandwidth, offset calibration, spinning motor under a
//! load step, and the drive's protection and calibration faults.
//!
//! Every figure comes from `hal_sim::scenarios`, the same code `drive-sim current-step` and `drive-sim
//! spinning` run, so the command line and the tests cannot disagree. The plant is the reference plant of
//! `shared/design/ARCHITECTURE.md` (noise, shunt offsets, dead time, bus dynamics); the gains are the dictionary
//! defaults of 0x30A0 (1,555,000 uV/A, 2,450,000 uV/(A ms): a 1.5 kHz crossover). The bounds are the issue's;
//! each test says why its tolerance is what it is.

use firmware::hal::power::PwmCommand;
use firmware::od::generated::handles as h;
use firmware::power_state::{CalibrationError, DriveError, PowerState, Trip};
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::{self, Setup, SpinConfig};
use hal_sim::sim::{SimError, Simulation};

/// q-axis step 0 -> 2 A at standstill, rotor locked, reference through target torque 0x6071 (625 per mille).
///
/// Bounds (issue): 10-90 % rise <= 200 us (a 1.5 kHz crossover with one period of transport delay gives about
/// 140 us: the bound is met with margin, not by luck); overshoot <= 10 %; steady-state error < 1 % of the step
/// (integral action: what remains is the measurement, 0.2 LSB of offset residual = 1.6 mA = 0.08 %, plus noise
/// averaged over the last millisecond). The figures use the plant's true current at the sample instants.
#[test]
fn q_current_step_at_standstill() {
    for seed in [1, 2] {
        let r = scenarios::current_step(&Setup { seed, ..Setup::default() }, 2.0).expect("scenario runs");
        let f = r.figures;
        assert!(f.rise_us <= 200.0, "seed {seed}: rise {f:?}");
        assert!(f.overshoot_pct <= 10.0, "seed {seed}: overshoot {f:?}");
        assert!(f.steady_error_pct < 1.0, "seed {seed}: steady-state error {f:?}");
        // The 3 % bound over seeds 1..8 is `q_current_step_d_axis_within_3_percent`.
        assert!(f.d_excursion_pct <= 3.0, "seed {seed}: d axis {f:?}");
        // The commutation was indexed before the step: the frame the loop works in is the rotor's.
        assert!(r.prepared.angle_error_deg.abs() < 1.0, "seed {seed}: angle error {:?}", r.prepared);
    }
}

/// The d-axis bound: |i_d| <= 3 % of the step during the q step 0 -> 2 A (the plant's true d current after
/// the step, as in `q_current_step_at_standstill`), seeds 1..8; tolerance the 3 %, no margin added.
///
/// What is at stake, measured per period from the plant's pole voltages: at the scenario's locked angle the q axis
/// is within a degree of perpendicular to phase A, so phase A carries almost no current (-20 mA at 2 A) and its
/// dead-time error (0 or +1.25 % of the bus, 0.2 V along alpha, which is the d axis here) depends on the sign of
/// its current at its own switching edges, that is on the PWM ripple. The d integrator holds the error of before
/// the step; the step's large voltage enlarges the ripple and changes the error, and the difference acts on the d
/// axis for the periods the loop needs to see it. With centred SVPWM the peak was 2.8-4.0 % over seeds 1..8.
///
/// What meets it: bottom-clamped discontinuous modulation (`firmware::control::svpwm`, DPWMMIN: the lowest phase
/// at compare 0, no edge, no dead-time error; the same line voltages, foc_step and fast_tick counts). The d
/// integrator holds only -0.03 to -0.10 V before the step; the d peak is 0.9-2.5 % over seeds 1..8 (1.4-3.2 % over
/// seeds 9..24, seed 13 a slow L/R tail: the bound holds for these seeds, not for every seed; eight start angles x
/// seeds 1..2: +2 A 1.0-2.6 %, -2 A 1.6-2.6 %, against 1.7-3.6 % and 2.0-4.2 % centred), with rise 148 us,
/// overshoot 1.0 % and bandwidth 2.69 kHz. With zero dead time the floor is 0.9-1.5 % (noise).
///
/// Why it needed a second change: a more faithful current loop passes the count-based velocity estimate's
/// quantisation noise to the motor (centred SVPWM's dead-time dead zone had swallowed part of it: a -0.18 A demand
/// left the current at -0.013 A). With one position difference per slow tick (36.6 rpm per count, 2.73 counts per
/// tick at 100 rpm) the 100 rpm CSV step (`motion_cyclic::csv_small_step`) settled in 265-291 ms bottom-clamped
/// (bound 200 ms; tail ripple 0.85 rpm RMS, 2.44 rpm peak). The estimate now averages tier 1's ten encoder
/// samples per slow tick (`firmware::control::velocity_estimate::PositionSum`): settle 14-16 ms, tail ripple
/// 0.36-0.38 rpm RMS and 0.96-1.19 rpm peak, overshoot 7.2-9.2 % over seeds 1..8. The observer of 0x30A3 was
/// measured as the alternative and does not help here (tail 1.2-1.3 rpm RMS, 2.5-3.0 rpm peak, settle 241-297 ms),
/// nor do point differences over 2..8 slow ticks (peak 2.0-2.8 rpm: the aliased quantisation lies inside the loop's
/// bandwidth) or a 200 Hz filter cut-off (1.9-2.4 rpm peak).
///
/// Tried before for the current loop alone and not kept (worst d peak over seeds 1..8): other current gains of
/// 0x30A0 with centred SVPWM, P 1.0 to 2.6 V/A and I/P 0.5 to 3 x R/L: 3.2 % or more wherever rise <= 200 us and
/// overshoot <= 10 %; per-phase dead-time sign compensation of 42 ticks from the measured current (5.2 %), from
/// the reference (5.4 %), each with a ripple-aware edge-current model (4.1 to 4.7 %); a feed-forward of only the
/// ripple-removed error (2.4 % over seeds 1..16, but it raised the -2 A step at every start angle and took the
/// fast tick from 449 to 707 instructions, budget 600).
#[test]
fn q_current_step_d_axis_within_3_percent() {
    for seed in 1..=8 {
        let r = scenarios::current_step(&Setup { seed, ..Setup::default() }, 2.0).expect("scenario runs");
        assert!(r.figures.d_excursion_pct <= 3.0, "seed {seed}: {:?}", r.figures);
    }
}

/// Closed-loop -3 dB bandwidth >= 2 kHz, from a sine sweep of the q reference (2 A bias + 1 A sine, rotor locked).
///
/// The bias keeps the current from crossing zero, where the inverter dead time makes the loop nonlinear (see
/// `scenarios::bandwidth`); the bound needs the transport delay at or under one period, which the plant's timing
/// model enforces (duties computed from sample n act from the next PWM period). The gain at 2 kHz itself is also
/// checked, so the bound does not rest on the interpolation.
#[test]
fn closed_loop_current_bandwidth_at_least_2_khz() {
    let freqs = [200.0, 1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0, 4000.0];
    let r = scenarios::bandwidth(&Setup::default(), 2.0, 1.0, &freqs).expect("scenario runs");
    assert!(r.bandwidth_hz >= 2000.0, "{r:?}");
    let at_2k = r.points.iter().find(|p| p.freq_hz == 2000.0).expect("2 kHz point");
    assert!(at_2k.gain_db() >= -3.0103, "{at_2k:?}");
    // Low frequencies pass unattenuated (integral action): within 0.1 dB at 200 Hz.
    assert!(r.points[0].gain_db().abs() < 0.1, "{:?}", r.points[0]);
}

/// Offsets of up to 50 LSB per channel are calibrated away to within 2 LSB (issue bound).
///
/// 256 samples of 2 LSB rms noise give a standard deviation of 0.125 LSB; the 2 LSB bound is 16 sigma, so the
/// check is deterministic in practice for every seed (and the plant is deterministic per seed anyway). The extreme
/// corners (+-50 on every channel) and mixed signs are covered.
#[test]
fn offsets_up_to_50_lsb_are_calibrated_away() {
    let cases = [[50.0, 50.0, 50.0], [-50.0, -50.0, -50.0], [50.0, -50.0, 0.0], [-13.0, 37.0, -49.5], [0.0; 3]];
    for (k, offsets) in cases.into_iter().enumerate() {
        let setup = Setup { seed: 10 + k as u64, offsets_lsb: offsets, ..Setup::default() };
        let p = scenarios::offset_calibration(&setup).expect("calibration succeeds");
        assert!(p.offset_residual_lsb <= 2.0, "offsets {offsets:?}: {p:?}");
        // Bounded: settling (50 ticks) plus 256 samples, nothing rejected on a plant at rest.
        assert_eq!(p.calibration_ticks, 306, "offsets {offsets:?}");
    }
}

/// Spinning at 3,000 rpm on the free shaft: a load step of 0.25 N m together with a q step 0.2 -> 8 A (the speed
/// stays near 3,000 rpm), and back after 10 ms.
///
/// At 3,000 rpm the back-EMF is 7 V of the 12.5 V the voltage limit (0.9 x 24 V / sqrt(3)) allows, so the step's
/// proportional demand drives the loop into the limit; the test checks that it does (else it would test nothing),
/// and then: recovery from the limit into a +-5 % band within 1 ms (issue bound); overshoot <= 10 % of the step
/// (a wound-up integrator would overshoot and recover late); mean tracking error over the second half of each
/// phase <= 2 % of the step (steady tracking at speed: the loop has no speed-voltage decoupling, so the cross
/// coupling is rejected by the integrators).
#[test]
fn current_loop_tracks_at_3000_rpm_under_a_load_step() {
    let cfg = SpinConfig::default();
    let r = scenarios::spinning(&Setup::default(), &cfg).expect("scenario runs");
    for (name, f) in [("up", r.up), ("down", r.down)] {
        assert!((f.speed_rpm - 3000.0).abs() < 0.03 * 3000.0, "{name}: speed {f:?}");
        assert!(f.recovery_us <= 1000.0, "{name}: recovery {f:?}");
        assert!(f.settle_us <= 1000.0, "{name}: settling {f:?}");
        assert!(f.overshoot_pct <= 10.0, "{name}: overshoot (windup) {f:?}");
        assert!(f.tracking_error_pct <= 2.0, "{name}: tracking {f:?}");
    }
    assert!(r.up.saturated_us >= 80.0, "the step must reach the voltage limit: {:?}", r.up);
}

/// The hardware break input switches the outputs off in the same tick and latches a fault until reset.
#[test]
fn break_input_switches_the_outputs_off() {
    let (mut sim, _) = scenarios::prepare(&Setup::default()).expect("prepared");
    sim.plant.lock_rotor(true);
    sim.set_q_reference(2.0);
    sim.run(50);
    assert!(sim.command().enabled);
    sim.plant.force_break();
    sim.step();
    assert_eq!(*sim.command(), PwmCommand::OFF);
    let tripped = PowerState::Fault(DriveError::Protection(Trip::BreakInput));
    assert_eq!(sim.tier1().state(), tripped, "tier 1 trips in the same period");
    sim.run(10);
    assert_eq!(*sim.command(), PwmCommand::OFF, "latched");
    assert_eq!(sim.drive.state(), tripped, "the drive has the report of the next slow-tick boundary");
    sim.drive.fault_reset();
    assert_eq!(sim.drive.state(), PowerState::Off);
    assert!(sim.drive.enable_operation().is_err(), "enable needs a new switch-on (calibration)");
}

/// An implausible offset (a broken amplifier: 120 LSB off) fails the switch-on with a typed calibration error and
/// leaves the outputs off; the calibration ends within its bounded number of ticks.
#[test]
fn implausible_offset_fails_the_switch_on() {
    let mut params = PlantParams::reference();
    params.shunt_offset_lsb = [0.0, 120.0, 0.0];
    let mut sim = Simulation::new(params, 3, firmware::drive::DriveConfig::DEFAULT);
    let err = sim.switch_on().expect_err("must fail");
    match err {
        SimError::Drive(DriveError::Calibration(CalibrationError::OffsetOutOfRange { channel: 1, deviation_lsb })) => {
            assert!((119..=120).contains(&deviation_lsb), "{deviation_lsb}");
        }
        other => panic!("unexpected {other:?}"),
    }
    sim.run(5);
    assert_eq!(*sim.command(), PwmCommand::OFF);
}

/// The tier hand-off of a CST torque (issue 16): 0x6071 written without a set-point event (an SDO download)
/// reaches tier 1's q reference within one slow tick plus one period (11 periods: the next slow tick converts it,
/// the period after it takes the set-point); with a set-point event (`Drive::setpoint_received`, as a SYNC or an
/// SM2 event calls it) it is in the very next period. Exact counts: the simulation applies the hand-offs with the
/// target's timing.
#[test]
fn a_target_torque_reaches_the_current_loop_within_one_slow_tick_and_one_period() {
    let (mut sim, _) = scenarios::prepare(&Setup::default()).expect("prepared");
    sim.plant.lock_rotor(true);
    sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 0);
    sim.run(20);
    let before = sim.tier1().setpoint().i_q;
    for start in 0..10u64 {
        // Every phase of the slow-tick grid.
        sim.run(1);
        let permille: i16 = if start % 2 == 0 { 400 } else { 150 };
        sim.drive.dictionary_mut().set(h::TARGET_TORQUE, permille);
        let reached = sim.run_until(100, |s| {
            s.tier1().setpoint().i_q != before && s.tier1().setpoint().i_q == s.drive.setpoint().i_q
        });
        let periods = reached.expect("the torque reached tier 1");
        assert!(periods <= 11, "phase {start}: {periods} periods, more than one slow tick plus one period");
        sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 0);
        sim.run(20);
    }
    sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 300);
    sim.drive.setpoint_received();
    assert_eq!(sim.run_until(5, |s| s.tier1().setpoint().i_q != before), Some(1), "a set-point event: next period");
}

/// The hand-off timing of the loops' set-point (issue 16, host timing = target timing): what the velocity loop
/// decides in a slow tick names the period `LOOP_SETPOINT_DELAY_PERIODS` (4) after the one following the raise
/// (`SetPoint::apply_from`), and tier 1 takes it in exactly that period, not one earlier, in every one of 50 slow
/// ticks of a CSV acceleration (each brings a new q reference). A request made between two periods (tier 3 on the
/// target), here a shutdown, acts in the very next period.
#[test]
fn a_loop_setpoint_applies_in_the_middle_of_the_slow_period_and_a_request_at_once() {
    use firmware::drive::blocks::LOOP_SETPOINT_DELAY_PERIODS as DELAY;
    let mut sim = hal_sim::scenarios::motion::prepare_motion(1, 9).expect("enabled in CSV");
    sim.drive.dictionary_mut().set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 1000);
    let mut checked = 0;
    // 50 slow ticks with a new set-point are well inside 1,000 slow ticks of an acceleration to 1,000 rpm.
    for _ in 0..10_000 {
        if checked == 50 {
            break;
        }
        let before = sim.drive.report().period;
        sim.setpoint_received();
        sim.step();
        if sim.drive.report().period == before {
            continue;
        }
        // A slow tick ran in this step: the report is of the period after the raising one.
        let raised = sim.drive.report().period;
        let wanted = *sim.drive.setpoint();
        if wanted.version == sim.tier1().setpoint().version {
            continue;
        }
        assert_eq!(wanted.apply_from, raised.wrapping_add(DELAY), "the period named");
        for k in 0..DELAY {
            sim.step();
            assert_ne!(sim.tier1().setpoint().version, wanted.version, "taken {k} periods after the raise's next");
        }
        sim.step();
        assert_eq!(*sim.tier1().setpoint(), wanted, "taken in the period named");
        checked += 1;
    }
    assert_eq!(checked, 50, "slow ticks with a new loop set-point");
    assert_eq!(sim.tier1().state(), PowerState::OperationEnabled);
    sim.drive.shutdown();
    sim.step();
    assert_eq!(sim.tier1().state(), PowerState::Off, "a request acts in the next period");
    assert!(!sim.command().enabled);
}
