//! The CiA 402 machine wired into the drive, on the reference plant: the power stage follows the machine's
//! state, stops run on the motor, faults switch the outputs off and are reset only through transition 15.
//!
//! The machine's transition table and option codes are proven on the machine alone (`cia402_table.rs`,
//! `cia402_options.rs`, `cia402_properties.rs`); these tests prove the integration: that what the machine decides
//! is what the power stage does.

use firmware::cia402::State;
use firmware::od::generated::handles as h;
use firmware::power_state::PowerState;
use hal_sim::scenarios::motion::prepare_motion;
use hal_sim::sim::Simulation;

/// Whether the last command switched the outputs on.
fn outputs_on(sim: &Simulation) -> bool {
    sim.command().enabled
}

/// Torque only in «Operation enabled» and the stopping states: after «Disable voltage» from OE the outputs go off
/// at the next slow tick (0x605B = 0: no ramp), «Shutdown» from SO switches the power section off, and the
/// calibration of transition 3 is the only time the outputs are on outside the enabled states (50 % duty).
#[test]
fn outputs_follow_the_state() {
    let mut sim = prepare_motion(1, 8).expect("enabled in CSP");
    assert!(outputs_on(&sim));
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(2);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled);
    assert!(!outputs_on(&sim));
    assert_eq!(sim.drive.state(), PowerState::Off);
    // In SOD nothing switches the outputs on, whatever the master writes into the targets.
    sim.drive.dictionary_mut().set(h::TARGET_POSITION, 100_000);
    sim.setpoint_received();
    sim.run_slow_ticks(20);
    assert!(!outputs_on(&sim));
    // Back up: transition 3 calibrates again, then SO (outputs off), then OE.
    sim.set_controlword(0x0006);
    sim.run_slow_ticks(2);
    assert_eq!(sim.cia402_state(), State::ReadyToSwitchOn);
    sim.set_controlword(0x0007);
    sim.run_slow_ticks(1);
    assert_eq!(sim.drive.state(), PowerState::Calibrating);
    sim.run_slow_ticks(200);
    assert_eq!(sim.cia402_state(), State::SwitchedOn);
    assert!(!outputs_on(&sim));
    sim.set_controlword(0x0006);
    sim.run_slow_ticks(2);
    assert_eq!(sim.cia402_state(), State::ReadyToSwitchOn);
    assert_eq!(sim.drive.state(), PowerState::Off);
}

/// Quick stop (0x605A = 6, IDX default: quick-stop ramp, stay in QSA) while CSV runs at 1,000 rpm: the motor
/// decelerates with 0x6085 and holds; «Enable operation» returns to OE (transition 16). The stop time is the
/// ramp's: 1,000 rpm at 10,000 rpm/s = 100 ms (bound 130 ms: the velocity loop's lag and the standstill window).
#[test]
fn quick_stop_ramps_down_and_holds() {
    let mut sim = prepare_motion(1, 9).expect("enabled in CSV");
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 1000);
    for _ in 0..750 {
        sim.setpoint_received();
        sim.run_slow_ticks(1);
    }
    let speed = sim.plant.state().speed_rpm;
    assert!((speed - 1000.0).abs() < 20.0, "running at {speed} rpm");
    sim.set_controlword(0x000B);
    sim.run_slow_ticks(1);
    assert_eq!(sim.cia402_state(), State::QuickStopActive);
    let stopped = sim.run_until(25_000, |s| s.plant.state().speed_rpm.abs() < 5.0).expect("stops");
    let stop_ms = stopped as f64 * 0.04;
    assert!((90.0..=130.0).contains(&stop_ms), "stop took {stop_ms} ms");
    sim.run_slow_ticks(100);
    assert_eq!(sim.cia402_state(), State::QuickStopActive);
    assert!(outputs_on(&sim), "holding with torque after the stop (0x605A = 6)");
    let held = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    sim.run_slow_ticks(250);
    let now = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    assert!((now - held).abs() <= 2, "holds position: {held} -> {now}");
    assert_ne!(sim.statusword() & (1 << 10), 0, "bit 10 in QSA: quick stop finished");
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 0);
    sim.set_controlword(0x000F);
    sim.run_slow_ticks(2);
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
}

/// A power-stage fault (the hardware break input) switches the outputs off in the same fast tick, the machine
/// reaches «Fault» with 0x603F set, a fault reset while the cause persists is refused, and after it the drive
/// comes back only through the normal transitions (2, 3 with a new calibration, 4).
#[test]
fn fault_switches_off_and_resets_through_transition_15() {
    let mut sim = prepare_motion(1, 8).expect("enabled in CSP");
    sim.plant.force_break();
    sim.run_until(10, |s| s.measurements().break_input).expect("the break input is reported");
    assert!(!outputs_on(&sim), "off in the tick the break input was seen");
    sim.run_slow_ticks(3);
    assert_eq!(sim.cia402_state(), State::Fault);
    assert_ne!(sim.drive.dictionary().get(h::ERROR_CODE), 0);
    assert_ne!(sim.statusword() & 0x0008, 0, "statusword fault bit");
    // Fault reset (rising edge of bit 7), then the enable sequence.
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(2);
    sim.set_controlword(0x0080);
    sim.run_slow_ticks(3);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0);
    assert!(!outputs_on(&sim));
    sim.enable_through_controlword(8).expect("re-enabled through 2, 3, 4");
    assert!(outputs_on(&sim));
}

/// A following error beyond 0x6065 raises the fault and the drive stops (0x605E = 2, quick-stop ramp) and ends
/// in «Fault» with 0x603F = 0x8611 (IDX).
#[test]
fn following_error_faults() {
    let mut sim = prepare_motion(1, 8).expect("enabled in CSP");
    sim.drive.dictionary_mut().set(h::FOLLOWING_ERROR_WINDOW, 200);
    // A set-point 1,000 increments away at once (a broken master): the error exceeds the window.
    let here = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    sim.drive.dictionary_mut().set(h::TARGET_POSITION, here + 1000);
    sim.setpoint_received();
    let faulted = sim.run_until(25_000, |s| s.cia402_state() == State::Fault);
    assert!(faulted.is_some(), "reaches Fault, state {:?}", sim.cia402_state());
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x8611);
    // The slow tick that completed transition 14 switched the power stage off for the next period.
    sim.step();
    assert!(!outputs_on(&sim));
}
