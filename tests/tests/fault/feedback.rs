//! Encoder and Hall sensor supervision on the reference plant (`firmware::supervision::feedback`): each sensor
//! failure injected into the plant (`hal_sim::plant::faults`) while the drive runs CSV at 300 rpm through the
//! controlword, as a master drives it, reaches «Fault» with its code in 0x603F, error register bit 5 (device
//! profile: sensor errors, IDX L7064-L7070) and the outputs off, within the latency each test states; a healthy
//! drive raises none of these faults in 5 s at the max speed 0x6080 or through reversals, with the reference
//! plant's sensor noise.
//!
//! 300 rpm is 12.6 degrees electrical per ms (7 pole pairs): a Hall sector (60 degrees) every 4.8 ms, a turn
//! every 200 ms, 20.5 encoder counts per slow tick.

use core::f64::consts::PI;

use firmware::cia402::State;
use firmware::fault::FaultId;
use firmware::od::generated::handles as h;
use firmware::sensors::hall::HallSector;
use firmware::supervision::feedback::hall_distance;
use hal_sim::plant::faults::EncoderNoise;
use hal_sim::scenarios::motion::prepare_motion;
use hal_sim::sim::Simulation;

/// The faults of the feedback supervision.
const FEEDBACK_FAULTS: [FaultId; 4] =
    [FaultId::HallInvalidState, FaultId::HallEncoderMismatch, FaultId::EncoderIndexMissing, FaultId::EncoderSignalLoss];
/// PWM periods per slow tick and per master cycle (1 ms).
const SLOW_TICK: u64 = 10;
const MASTER_CYCLE: u64 = 25;

/// Runs up to `seconds` with a set-point every master cycle (1 ms), until `stop` holds after a period; the periods
/// run when it held.
fn run_cyclic(sim: &mut Simulation, seconds: f64, mut stop: impl FnMut(&Simulation) -> bool) -> Option<u64> {
    let periods = (seconds * 25_000.0).round() as u64;
    for k in 1..=periods {
        if sim.ticks().is_multiple_of(MASTER_CYCLE) {
            sim.setpoint_received();
        }
        sim.step();
        if stop(sim) {
            return Some(k);
        }
    }
    None
}

/// CSV at `rpm` (seed 1), settled for 0.2 s: the commutation is indexed and the speed steady.
fn csv_at(rpm: i32) -> Simulation {
    let mut sim = prepare_motion(1, 9).expect("enabled in CSV");
    let d = sim.drive.dictionary_mut();
    d.set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
    d.set(h::TARGET_VELOCITY, rpm);
    run_cyclic(&mut sim, 0.2, |_| false);
    let speed = sim.plant.state().speed_rpm;
    assert!((speed - f64::from(rpm)).abs() < 0.05 * f64::from(rpm.abs()), "running at {speed} rpm");
    sim
}

/// The feedback faults active now.
fn feedback_faults(sim: &Simulation) -> Vec<FaultId> {
    let faults = sim.drive.axis().faults();
    FEEDBACK_FAULTS.into_iter().filter(|&id| faults.is_active(id)).collect()
}

/// Runs until the outputs go off (at most `max_s`); the time it took, s.
fn time_until_off(sim: &mut Simulation, max_s: f64) -> f64 {
    let periods = run_cyclic(sim, max_s, |s| !s.command().enabled).expect("the outputs go off");
    periods as f64 * 40e-6
}

/// After a trip: «Fault» within 10 ms (the class-d reaction), `code` in 0x603F, bits 0 and 5 in 0x1001, the
/// outputs off, and `id` the only feedback fault.
fn assert_fault(sim: &mut Simulation, id: FaultId, code: u16) {
    run_cyclic(sim, 0.01, |s| s.cia402_state() == State::Fault).expect("reaches Fault");
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), code, "0x603F");
    let register = sim.drive.dictionary().get(h::ERROR_REGISTER);
    assert_eq!(register & 0x21, 0x21, "0x1001 = {register:#04x}: generic and device-profile bits");
    assert!(!sim.command().enabled, "outputs off");
    assert_eq!(feedback_faults(sim), [id]);
}

/// A fault reset as a master sends it (rising edge of controlword bit 7), then a few slow ticks.
fn fault_reset(sim: &mut Simulation) {
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(2);
    sim.set_controlword(0x0080);
    sim.run_slow_ticks(3);
}

/// The electrical angle the rotor has turned through since `from` (unwrapped mechanical angles), degrees.
fn electrical_travel_deg(sim: &Simulation, from_theta_m: f64) -> f64 {
    (sim.plant.state().theta_m_rad - from_theta_m).abs() * 7.0 * 180.0 / PI
}

/// Halls stuck at 000 while enabled: tier 1 sees the invalid state in the first sample and switches the outputs
/// off in that fast tick (40 us); 0x603F = 0xFF05.
#[test]
fn invalid_hall_state_while_enabled_trips_in_the_fast_tick() {
    let mut sim = csv_at(300);
    sim.plant.faults_mut().hall_stuck = Some(0b000);
    let t = time_until_off(&mut sim, 0.01);
    assert!(t <= 40e-6 + 1e-9, "off after {t} s");
    assert_fault(&mut sim, FaultId::HallInvalidState, 0xFF05);
}

/// Halls stuck at 111 in «Switched on» (power stage on, no commutation, so tier 1 does not look): tier 2 reports
/// 0xFF05 after two slow ticks of the invalid state (0.8 ms, plus the machine's step into «Fault»: 1.2 ms here
/// is the bound). The cause persists: a fault reset is refused until the Halls read a valid state again, then
/// accepted.
#[test]
fn invalid_hall_state_while_switched_on_blocks_the_reset() {
    let mut sim = csv_at(300);
    sim.set_controlword(0x0007);
    run_cyclic(&mut sim, 0.2, |_| false);
    assert_eq!(sim.cia402_state(), State::SwitchedOn);
    sim.plant.faults_mut().hall_stuck = Some(0b111);
    let periods = run_cyclic(&mut sim, 0.01, |s| s.cia402_state() == State::Fault).expect("reaches Fault");
    assert!(periods <= 3 * SLOW_TICK, "Fault after {periods} periods");
    assert_fault(&mut sim, FaultId::HallInvalidState, 0xFF05);
    let snapshot = sim.drive.axis().faults().snapshot(FaultId::HallInvalidState).copied();
    assert_eq!(snapshot.map(|s| s.detail), Some(0b111), "the snapshot holds the Hall state");
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::Fault, "refused while the Halls read 111");
    sim.plant.faults_mut().hall_stuck = None;
    sim.run_slow_ticks(2);
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "accepted once valid");
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0);
}

/// Halls stuck at a valid state (101, sector 0): the encoder angle leaves that sector; 0x7122 once it is more than
/// the tolerance (23.2 degrees) beyond the sector's edge for three slow ticks. Bound: 90 degrees electrical of
/// travel (the rotor may have just entered sector 0: 60 + 23.2 degrees to go) plus four slow ticks (three ticks
/// of disagreement and the machine's), 7.1 + 1.6 ms at 300 rpm.
#[test]
fn stuck_valid_hall_state_is_a_mismatch() {
    let mut sim = csv_at(300);
    sim.plant.faults_mut().hall_stuck = Some(0b101);
    let t = time_until_off(&mut sim, 0.1);
    assert!(t <= 90.0 / 12_600.0 + 1.6e-3, "off after {:.2} ms", t * 1e3);
    println!("stuck Halls: mismatch after {:.2} ms", t * 1e3);
    assert_fault(&mut sim, FaultId::HallEncoderMismatch, 0x7122);
}

/// The encoder's A/B lines break: the counter stops while the Halls keep turning; 0x7380 at the second Hall
/// sector passed without a count. Bound: 180 degrees electrical of true travel from the break (the rest of the
/// sector the break falls in, two more sectors) plus one slow tick (the rotor speeds up: the velocity loop sees
/// no motion). The mismatch the stopped angle shows meanwhile is left to this check (0x603F names the root
/// cause). The level cause blocks a reset while the encoder does not count; once repaired, the coasting rotor
/// shows encoder and Halls agreeing again and the reset is accepted.
#[test]
fn encoder_wire_break_is_a_signal_loss() {
    let mut sim = csv_at(300);
    let theta0 = sim.plant.state().theta_m_rad;
    sim.plant.faults_mut().encoder_wire_break = true;
    let t = time_until_off(&mut sim, 0.1);
    let travel = electrical_travel_deg(&sim, theta0);
    let rpm = sim.plant.state().speed_rpm;
    // One slow tick at the speed reached: rpm / 60 x 7 x 360 degrees per s x 0.4 ms.
    let tick_travel = rpm.abs() / 60.0 * 7.0 * 360.0 * 0.4e-3;
    println!("wire break: off after {:.2} ms, {travel:.0} degrees electrical, at {rpm:.0} rpm", t * 1e3);
    assert!(travel <= 180.0 + tick_travel, "{travel} degrees electrical");
    assert_fault(&mut sim, FaultId::EncoderSignalLoss, 0x7380);
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::Fault, "refused while the encoder is lost");
    sim.plant.faults_mut().encoder_wire_break = false;
    // Coasting: two sectors with counts clear the cause (the rotor still turns at hundreds of rpm).
    sim.run_slow_ticks(50);
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "accepted once encoder and Halls agree");
}

/// The index line breaks: 0x7320 when the shaft is 1.5 turns (6,144 counts) beyond the last index pulse, within
/// one slow tick (20.5 counts at 300 rpm) plus the machine's step (another 21 counts).
#[test]
fn lost_index_is_reported_after_one_and_a_half_turns() {
    let mut sim = csv_at(300);
    // The last index pulse: the last whole turn of the true count (the plant's index is at count 0).
    let counts = |s: &Simulation| s.plant.state().theta_m_rad / (2.0 * PI) * 4096.0;
    let last_index = (counts(&sim) / 4096.0).floor() * 4096.0;
    sim.plant.faults_mut().index_lost = true;
    time_until_off(&mut sim, 0.6);
    let beyond = counts(&sim) - last_index;
    println!("index lost: off {beyond:.0} counts beyond the last index");
    assert!(beyond > 6144.0 && beyond <= 6144.0 + 2.0 * 20.5, "{beyond} counts");
    assert_fault(&mut sim, FaultId::EncoderIndexMissing, 0x7320);
    // An event: the reset is accepted at once (the next report comes after another 1.5 turns).
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled);
}

/// A noise burst adds 8 counts (1 per period for 8 periods: 4.9 degrees electrical, inside every other
/// tolerance): the next index pulse lies 8 counts off a whole turn; 0x7320 at that pulse (within one turn plus
/// two slow ticks), with the count error in the snapshot.
#[test]
fn noise_burst_displaces_the_index() {
    let mut sim = csv_at(300);
    let theta0 = sim.plant.state().theta_m_rad;
    sim.plant.faults_mut().encoder_noise = Some(EncoderNoise { counts_per_period: 1, periods_left: 8 });
    time_until_off(&mut sim, 0.3);
    let turns = (sim.plant.state().theta_m_rad - theta0) / (2.0 * PI);
    assert!(turns <= 1.0 + 2.0 * 20.5 / 4096.0, "off after {turns} turns");
    assert_fault(&mut sim, FaultId::EncoderIndexMissing, 0x7320);
    let snapshot = sim.drive.axis().faults().snapshot(FaultId::EncoderIndexMissing).copied();
    assert_eq!(snapshot.map(|s| s.detail), Some(8), "the index is 8 counts late");
}

/// A large noise burst (4 counts per period for 50 periods: 200 counts, 123 degrees electrical) shifts the
/// commutation angle out of the Hall sector: 0x7122 within the burst (2 ms) plus four slow ticks.
#[test]
fn large_noise_burst_is_a_mismatch() {
    let mut sim = csv_at(300);
    sim.plant.faults_mut().encoder_noise = Some(EncoderNoise { counts_per_period: 4, periods_left: 50 });
    let t = time_until_off(&mut sim, 0.1);
    println!("noise burst: mismatch after {:.2} ms", t * 1e3);
    assert!(t <= 2e-3 + 1.6e-3, "off after {:.2} ms", t * 1e3);
    assert_fault(&mut sim, FaultId::HallEncoderMismatch, 0x7122);
}

/// Runs CSV for `seconds` with the master's target velocity `rpm_at(t)` sent every 1 ms; stops early at the first
/// feedback fault or when the drive leaves «Operation enabled». The largest |speed|, bus voltage and distance of
/// the commutation angle from the centre of the Hall sector read in the same fast tick (degrees electrical; 30
/// is the sector's edge) seen, and the time run.
fn run_profile(sim: &mut Simulation, seconds: f64, rpm_at: impl Fn(f64) -> f64) -> (f64, f64, f64, f64) {
    let (mut speed, mut bus, mut off) = (0.0_f64, 0.0_f64, 0.0_f64);
    let t0 = sim.time_s();
    let periods = (seconds * 25_000.0).round() as u64;
    for k in 0..periods {
        if k.is_multiple_of(MASTER_CYCLE) {
            let target = rpm_at(k as f64 * 40e-6).round() as i32;
            sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, target);
            sim.setpoint_received();
        }
        sim.step();
        let state = sim.plant.state();
        speed = speed.max(state.speed_rpm.abs());
        bus = bus.max(state.bus_voltage_v);
        let sector = HallSector::from_state(sim.tier1().signals().hall).expect("a valid Hall state");
        let c = sim.tier1().commutation();
        let d = hall_distance(c.angle(), sector, c.hall_offset());
        off = off.max(f64::from(d.unsigned_abs()) / 4_294_967_296.0 * 360.0);
        if !feedback_faults(sim).is_empty() || sim.cia402_state() != State::OperationEnabled {
            break;
        }
    }
    (speed, bus, off, sim.time_s() - t0)
}

/// No false trip at the max speed: CSV ramped from 300 rpm to 0x6080 = 5,000 rpm at 10,000 rpm/s (as a master
/// would), then held there; 5 s in all, with the reference plant's ADC noise. No feedback fault, the drive stays
/// enabled, and the speed reaches 0x6080 within 2 % (the voltage limit: 24 V bus).
#[test]
fn no_false_trip_at_max_speed() {
    let mut sim = csv_at(300);
    let max = f64::from(sim.drive.dictionary().get(h::MAX_MOTOR_SPEED));
    assert_eq!(max, 5000.0);
    let (peak, _, off, t) = run_profile(&mut sim, 5.0, |t| (300.0 + 10_000.0 * t).min(max));
    println!("max speed: peak {peak:.0} rpm, angle up to {off:.1} degrees from the Hall sector's centre, {t:.3} s");
    assert_eq!(feedback_faults(&sim), []);
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
    assert!(peak >= 0.98 * max, "peak {peak} rpm");
    // The premise of the tolerance: the indexed angle lies in the Hall sector to one count (0.62 degrees).
    assert!(off <= 30.0 + 0.62, "{off} degrees from the centre");
}

/// No false trip through reversals: CSV following a 1 Hz sine of +-1,500 rpm for 5 s (ten reversals, each
/// through standstill, where the Halls may sit on an edge), with the reference plant's ADC noise. The amplitude
/// keeps the regenerated energy (0.2 J per stop) within the bus capacitor's range without a braking chopper.
#[test]
fn no_false_trip_through_reversals() {
    let mut sim = csv_at(300);
    let (peak, bus, off, t) = run_profile(&mut sim, 5.0, |t| 1500.0 * (2.0 * PI * t).sin());
    println!(
        "reversals: peak {peak:.0} rpm, bus up to {bus:.1} V, angle up to {off:.1} degrees from the centre, {t:.3} s"
    );
    assert_eq!(feedback_faults(&sim), []);
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
    assert!(peak >= 1400.0, "the profile was followed: peak {peak} rpm");
    assert!(off <= 30.0 + 0.62, "{off} degrees from the centre");
}
