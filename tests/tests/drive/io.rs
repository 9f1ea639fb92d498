//! Digital I/O on the reference plant through the whole drive: the holding-brake sequence of CiA 402 transitions
//! 4 and 5 with the plant's brake, a limit switch stopping the motor with its fault, and the touch probe latching
//! the encoder index.

use firmware::cia402::State;
use firmware::od::generated::handles as h;
use hal_sim::scenarios::motion::prepare_motion;
use hal_sim::sim::Simulation;

/// Periods of 40 us in `ms` milliseconds.
fn periods(ms: u64) -> u64 {
    ms * 25
}

/// Fits the plant's brake on output 1 (energised = released) and configures output 1 as the drive's holding
/// brake (0x3151:01 = 24) with the 0x3158 defaults (10 ms rise and fall).
fn fit_brake(sim: &mut Simulation) {
    sim.plant.params_mut().io.brake.output = Some(0);
    sim.drive.dictionary_mut().set(h::DIGITAL_OUTPUT_1_CONFIGURATION, 24);
}

/// Transition 5 with a brake: the motor is held by the controllers until the brake has engaged (0x3158:01), then
/// the power goes off; transition 4: the brake is released first and the set-points wait for 0x3158:02, so the
/// motor never runs against the brake and never drops a load.
#[test]
fn holding_brake_sequence() {
    let mut sim = prepare_motion(1, 1).expect("enabled in PPM");
    fit_brake(&mut sim);
    // The plant's brake was fitted engaged: the energised output releases it after its 10 ms.
    sim.run_slow_ticks(50);
    assert!(!sim.plant.brake_engaged(), "released while operation is enabled");
    // «Disable operation» (0x605C = 1: slow-down ramp; at standstill already).
    sim.set_controlword(0x0007);
    let mut engaged_at = None;
    let mut off_at = None;
    for k in 0..periods(40) {
        sim.step();
        if engaged_at.is_none() && sim.plant.brake_engaged() {
            engaged_at = Some(k);
        }
        if off_at.is_none() && !sim.command().enabled {
            off_at = Some(k);
        }
    }
    let (engaged, off) = (engaged_at.expect("brake engages"), off_at.expect("power goes off"));
    assert!(off >= engaged, "the power stays on until the brake holds: engaged {engaged}, off {off}");
    assert!(off <= engaged + periods(2), "and goes off right after: engaged {engaged}, off {off}");
    assert_eq!(sim.cia402_state(), State::SwitchedOn);
    assert_eq!(sim.drive.dictionary().get(h::BRAKE_STATE), 1);

    // «Enable operation»: the brake releases first; the drive holds the motor meanwhile (no motion against the
    // brake), then a new set-point moves it.
    let start = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    sim.drive.dictionary_mut().set(h::TARGET_POSITION, start + 4096);
    sim.set_controlword(0x000F);
    let mut released_at = None;
    for k in 0..periods(30) {
        sim.step();
        if released_at.is_none() && !sim.plant.brake_engaged() {
            released_at = Some(k);
        }
        if sim.plant.brake_engaged() {
            let now = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
            assert!((now - start).abs() <= 1, "no motion against the brake: {start} -> {now}");
        }
    }
    assert!(released_at.expect("brake releases") >= periods(10), "the plant's release delay");
    assert_eq!(sim.drive.dictionary().get(h::BRAKE_STATE), 0);
    sim.set_controlword(0x001F);
    sim.run(periods(400));
    let end = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    assert!((end - (start + 4096)).abs() <= 10, "the move ran after the release: {start} -> {end}");
}

/// A positive limit switch hit while moving in CSV: the limit-switch fault 0x8A81 (IDX), the drive stops and
/// ends in «Fault» with the outputs off. The fault is an event (IDX L7089-7090): the reset is accepted on the
/// switch, and the axis may then move off it, but not further into it.
#[test]
fn limit_switch_stops_and_faults() {
    let mut sim = prepare_motion(1, 9).expect("enabled in CSV");
    // The switch 2,000 counts ahead of the plant's present count (the plant's own coordinates).
    let count = plant_count(&sim);
    sim.plant.params_mut().io.set_positive_limit(Some(count + 2000));
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 300);
    let mut fault = None;
    for k in 0..2000 {
        sim.setpoint_received();
        sim.run_slow_ticks(1);
        if sim.cia402_state() == State::Fault {
            fault = Some(k);
            break;
        }
    }
    assert!(fault.is_some(), "reaches Fault; state {:?}", sim.cia402_state());
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x8A81);
    sim.step();
    assert!(!sim.command().enabled);
    // Reset on the switch, enable, and drive further into it: the fault again.
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(2);
    sim.set_controlword(0x0080);
    sim.run_slow_ticks(3);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled);
    sim.enable_through_controlword(9).expect("enabled on the switch");
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 100);
    sim.setpoint_received();
    let faulted = sim.run_until(periods(200), |s| s.cia402_state() == State::Fault);
    assert!(faulted.is_some(), "further into the switch: {:?}", sim.cia402_state());
    // Reset again and drive off the switch: no fault.
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(2);
    sim.set_controlword(0x0080);
    sim.run_slow_ticks(3);
    sim.enable_through_controlword(9).expect("enabled on the switch");
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, -100);
    for _ in 0..1000 {
        sim.setpoint_received();
        sim.run_slow_ticks(1);
    }
    assert_eq!(sim.cia402_state(), State::OperationEnabled, "moving off the switch is allowed");
    assert!(plant_count(&sim) < count + 2000, "off the switch");
}

/// The plant's encoder count now (what the index and the switches are placed in).
fn plant_count(sim: &Simulation) -> i64 {
    sim.plant.true_encoder_count()
}

/// Touch probe 1 on the encoder index, positive edge, continuous (0x60B8 = 0x0017): at 120 rpm each revolution
/// latches 0x60BA, counts 0x60D5, and consecutive latches are exactly 4,096 increments apart (the index is
/// captured by the encoder timer, so the position is exact at any speed).
#[test]
fn touch_probe_latches_the_index() {
    let mut sim = prepare_motion(1, 9).expect("enabled in CSV");
    sim.drive.dictionary_mut().set(h::TOUCH_PROBE_FUNCTION, 0x0017);
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 120);
    let mut latches = Vec::new();
    let mut last_count = sim.drive.dictionary().get(h::TOUCH_PROBE_1_POSITIVE_COUNTER);
    for _ in 0..(2500 * 2) {
        sim.setpoint_received();
        sim.run_slow_ticks(1);
        let d = sim.drive.dictionary();
        let c = d.get(h::TOUCH_PROBE_1_POSITIVE_COUNTER);
        if c != last_count {
            last_count = c;
            latches.push(d.get(h::TOUCH_PROBE_1_POSITIVE_VALUE));
            assert_ne!(d.get(h::TOUCH_PROBE_STATUS) & 0b11, 0b00, "enabled and stored");
        }
    }
    assert!(latches.len() >= 3, "two seconds at 120 rpm pass the index 4 times: {latches:?}");
    for pair in latches.windows(2) {
        assert_eq!(pair[1] - pair[0], 4096, "{latches:?}");
    }
    // The same position tier 1 latched and reported at the last slow tick (tier 1 may have latched the next
    // index since), in 0x6064's coordinates.
    let tier1 = sim.drive.report().latches.index.position.wrapping_add(sim.drive.axis().position_offset());
    assert_eq!(latches.last().copied(), Some(tier1));
}

/// A fault engages the holding brake (issue 5 "the holding brake engaged"): class "d" (power-stage
/// over-temperature) de-energises the brake output with the power stage, at once; class "f" (a limit switch)
/// after the quick-stop ramp. Either way the brake holds within its 10 ms (0x3158:01 and the plant's brake) of the
/// outputs going off, so a vertical axis never hangs on a disabled motor.
#[test]
fn a_fault_engages_the_holding_brake() {
    for class_d in [true, false] {
        let mut sim = prepare_motion(1, 9).expect("enabled in CSV");
        fit_brake(&mut sim);
        sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 300);
        for _ in 0..200 {
            sim.setpoint_received();
            sim.run_slow_ticks(1);
        }
        assert!(!sim.plant.brake_engaged(), "released while running");
        if class_d {
            sim.plant.set_power_stage_temperature(105.0);
        } else {
            let count = sim.plant.true_encoder_count();
            sim.plant.params_mut().io.set_positive_limit(Some(count - 1_000_000));
        }
        let (mut off_at, mut engaged_at) = (None, None);
        for k in 0..periods(500) {
            if k % 25 == 0 {
                sim.setpoint_received();
            }
            sim.step();
            if off_at.is_none() && !sim.command().enabled {
                off_at = Some(k);
            }
            if engaged_at.is_none() && sim.plant.brake_engaged() {
                engaged_at = Some(k);
            }
        }
        assert_eq!(sim.cia402_state(), State::Fault, "class d: {class_d}");
        let (off, engaged) = (off_at.expect("outputs off"), engaged_at.expect("brake engaged"));
        println!("class d: {class_d}: outputs off after {} ms, brake engaged after {} ms", off / 25, engaged / 25);
        assert!(
            engaged <= off + periods(12),
            "class d: {class_d}: brake engaged {} ms after the outputs went off",
            (engaged as f64 - off as f64) / 25.0
        );
    }
}
