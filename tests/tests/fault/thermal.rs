//! Thermal supervision on the reference plant (`firmware::supervision::thermal`; control-and-protection.md §3.2,
//! IDX 0x3201 L5451-L5486): the power stage's warning and current derating from 90 degC, its trip at 100 degC
//! (0x4210) with the reset refused until it is back under 95 degC, the motor's trip above 125 degC or without a
//! sensor (0x4380) with the reset refused until it is under 120 degC, and no false trip at ambient.
//!
//! The temperatures are forced on the plant's thermal nodes (`Plant::set_power_stage_temperature`,
//! `Plant::set_winding_temperature`) every slow tick, since the nodes relax towards ambient on their own (the power
//! stage by about 1 K/s at 95 degC). The sensors are the plant's: 0.5 V + 10 mV/K on a 3.3 V 12-bit channel
//! (0.08 K per code) with 1 LSB rms noise, which the drive filters (median of three, 3.2 ms low-pass): the
//! temperatures it publishes are within 0.2 K of the forced ones.

use firmware::cia402::State;
use firmware::control::frames::Amps;
use firmware::fault::table::FaultId;
use firmware::od::generated::handles as h;
use hal_sim::scenarios::motion::prepare_motion;
use hal_sim::sim::Simulation;

/// Error-register 0x1001 bit 3, temperature (CiA 301; IDX L1580).
const REG_TEMPERATURE: u8 = 1 << 3;
/// Statusword bit 7, warning.
const SW_WARNING: u16 = 1 << 7;

/// Runs `slow_ticks` slow ticks with the power stage (and the winding, if given) held at the temperatures, degC.
fn hold(sim: &mut Simulation, stage_c: f64, winding_c: Option<f64>, slow_ticks: u64) {
    for _ in 0..slow_ticks {
        sim.plant.set_power_stage_temperature(stage_c);
        if let Some(w) = winding_c {
            sim.plant.set_winding_temperature(w);
        }
        sim.run_slow_ticks(1);
    }
}

/// Like [`hold`], until the outputs go off; the slow ticks it took.
fn hold_until_off(sim: &mut Simulation, stage_c: f64, winding_c: Option<f64>, max_slow_ticks: u64) -> Option<u64> {
    for k in 1..=max_slow_ticks {
        hold(sim, stage_c, winding_c, 1);
        if !sim.command().enabled {
            return Some(k);
        }
    }
    None
}

/// A fault reset as a master sends it (rising edge of controlword bit 7), then a few slow ticks.
fn fault_reset(sim: &mut Simulation, stage_c: f64, winding_c: Option<f64>) {
    sim.set_controlword(0x0000);
    hold(sim, stage_c, winding_c, 2);
    sim.set_controlword(0x0080);
    hold(sim, stage_c, winding_c, 3);
}

/// The plant's q current, A.
fn i_q(sim: &Simulation) -> f64 {
    sim.plant.state().i_dq_a[1]
}

fn amps(a: Amps) -> f64 {
    f64::from(a.to_bits()) / 65536.0
}

/// Drains the EMCY queue (inhibit time 0: everything queued leaves at once).
fn drain_emcy(sim: &mut Simulation) -> Vec<[u8; 8]> {
    let now = sim.drive.axis().now();
    std::iter::from_fn(|| sim.drive.axis_mut().faults_mut().poll_emcy(now)).collect()
}

/// At ambient (25 degC on both sensors) the drive publishes 25.0 degC within 0.5 K and never warns, derates or
/// trips: checked every slow tick over 0.4 s on three seeds, holding 3.2 A on a locked rotor (the tolerance is the
/// sensor's 0.08 K quantisation plus the filtered noise, with the winding's own heating of well under 0.1 K in
/// 0.4 s at the nominal current).
#[test]
fn no_false_trip_at_ambient() {
    for seed in [1, 2, 3] {
        let mut sim = prepare_motion(seed, 10).expect("enabled in CST");
        sim.plant.lock_rotor(true);
        sim.set_target_torque(1000);
        for _ in 0..1000 {
            sim.run_slow_ticks(1);
            let d = sim.drive.dictionary();
            let stage = d.get(h::POWER_STAGE_TEMPERATURE);
            let motor = d.get(h::MOTOR_TEMPERATURE);
            assert!((stage - 250).abs() <= 5, "seed {seed}: power stage {stage}");
            assert!((motor - 250).abs() <= 5, "seed {seed}: motor {motor}");
            assert_eq!(sim.statusword() & SW_WARNING, 0, "seed {seed}: no warning");
            assert_eq!(sim.cia402_state(), State::OperationEnabled, "seed {seed}");
            assert_eq!(sim.drive.supervision().thermal.derated_limit(), Amps::from_bits(i32::MAX), "seed {seed}");
        }
        assert!((i_q(&sim) - 3.2).abs() < 0.15, "seed {seed}: {} A", i_q(&sim));
    }
}

/// A hot power stage: from 90 degC a warning (statusword bit 7, EMCY 0xFF81, no state change) and the derating.
/// A locked rotor asked for 8 A in CST gets 8 A at ambient, 6.6 A at 95 degC and 3.88 A at 99 degC (the curve:
/// 10 A at 90 degC down to the 3.2 A nominal current at 100 degC), and 8 A again once the stage is back under
/// 85 degC (warning hysteresis 5 K). The demand above the limit is what makes the limit visible; that the limit
/// settles (rather than ratcheting down to the floor) shows the derating is not fed its own output.
///
/// Tolerances: the drive's limit within 0.08 A of the curve: the curve falls 0.68 A/K and the drive works in the
/// 0.1 K steps of 0x3201:01, so one step is 0.068 A (the filtered sensor noise, about 0.015 K rms, decides
/// between neighbouring steps); the plant's current within 0.15 A of the limit (the current loop's ripple and the
/// shunt ADC's noise at 8 A).
#[test]
fn hot_power_stage_warns_and_derates_the_current() {
    let mut sim = prepare_motion(1, 10).expect("enabled in CST");
    sim.plant.lock_rotor(true);
    sim.set_target_torque(2500); // 2.5 x 3.2 A = 8 A
    hold(&mut sim, 25.0, None, 100);
    assert!((i_q(&sim) - 8.0).abs() < 0.15, "8 A at ambient: {} A", i_q(&sim));
    drain_emcy(&mut sim);

    hold(&mut sim, 95.0, None, 100);
    assert_ne!(sim.statusword() & SW_WARNING, 0, "warning bit 7");
    assert!(sim.drive.axis().faults().is_active(FaultId::PowerStageTemperatureHigh));
    assert_eq!(sim.cia402_state(), State::OperationEnabled, "a warning, not a fault");
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0);
    let emcy = drain_emcy(&mut sim);
    assert!(emcy.iter().any(|f| u16::from_le_bytes([f[0], f[1]]) == 0xFF81), "warning EMCY: {emcy:x?}");
    let published = sim.drive.dictionary().get(h::POWER_STAGE_TEMPERATURE);
    assert!((published - 950).abs() <= 2, "0x3201:01 = {published}");
    let limit = amps(sim.drive.supervision().thermal.derated_limit());
    println!("95 degC: limit {limit:.3} A, current {:.3} A", i_q(&sim));
    assert!((limit - 6.6).abs() < 0.08, "limit at 95 degC: {limit} A");
    assert!((i_q(&sim) - 6.6).abs() < 0.15, "current at 95 degC: {} A", i_q(&sim));

    hold(&mut sim, 99.0, None, 100);
    let limit = amps(sim.drive.supervision().thermal.derated_limit());
    println!("99 degC: limit {limit:.3} A, current {:.3} A", i_q(&sim));
    assert!((limit - 3.88).abs() < 0.08, "limit at 99 degC: {limit} A");
    assert!((i_q(&sim) - 3.88).abs() < 0.15, "current at 99 degC: {} A", i_q(&sim));
    assert_eq!(sim.cia402_state(), State::OperationEnabled);

    // Back to 87 degC: the derating is gone, the warning stays (hysteresis); at 84 degC it goes too.
    hold(&mut sim, 87.0, None, 100);
    assert!((i_q(&sim) - 8.0).abs() < 0.15, "8 A again: {} A", i_q(&sim));
    assert_ne!(sim.statusword() & SW_WARNING, 0, "warning held down to 85 degC");
    hold(&mut sim, 84.0, None, 100);
    assert_eq!(sim.statusword() & SW_WARNING, 0, "warning gone under 85 degC");
    assert!(!sim.drive.axis().faults().is_active(FaultId::PowerStageTemperatureHigh));
}

/// Over 100 degC: 0x4210, error register bit 3 (and bit 0), outputs off, «Fault»; within 20 ms of the step from
/// 95 to 101 degC (the filter crosses 100 degC after about 15 slow ticks, 6 ms). A fault reset is refused at
/// 97 degC (back under the limit but not under limit - 5 K) and accepted at 94 degC.
#[test]
fn power_stage_over_temperature_trips_and_resets_only_when_cool() {
    let mut sim = prepare_motion(2, 10).expect("enabled in CST");
    sim.plant.lock_rotor(true);
    sim.set_target_torque(500);
    hold(&mut sim, 95.0, None, 50);
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
    let ticks = hold_until_off(&mut sim, 101.0, None, 50).expect("trips");
    println!("power stage: outputs off {ticks} slow ticks after 101 degC");
    hold(&mut sim, 101.0, None, 3);
    assert_eq!(sim.cia402_state(), State::Fault);
    let d = sim.drive.dictionary();
    assert_eq!(d.get(h::ERROR_CODE), 0x4210);
    assert_eq!(d.get(h::ERROR_REGISTER) & (REG_TEMPERATURE | 1), REG_TEMPERATURE | 1);
    let snap = *sim.drive.axis().faults().snapshot(FaultId::PowerStageOverTemperature).expect("snapshot");
    assert!((1001..=1010).contains(&snap.power_stage_temperature_ddegc), "{snap:?}");

    fault_reset(&mut sim, 97.0, None);
    hold(&mut sim, 97.0, None, 50);
    fault_reset(&mut sim, 97.0, None);
    assert_eq!(sim.cia402_state(), State::Fault, "refused at 97 degC");
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x4210);

    hold(&mut sim, 94.0, None, 50);
    fault_reset(&mut sim, 94.0, None);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "accepted at 94 degC");
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_REGISTER) & REG_TEMPERATURE, 0);
}

/// The winding over 125 degC: 0x4380, the EMCY carrying the motor temperature (0.1 degC, bytes 4..7) and the
/// snapshot the power-stage temperature; the reset is refused at 122 degC and accepted at 118 degC.
#[test]
fn motor_over_temperature_trips_above_125_degc() {
    let mut sim = prepare_motion(3, 10).expect("enabled in CST");
    hold(&mut sim, 25.0, Some(124.0), 100);
    assert_eq!(sim.cia402_state(), State::OperationEnabled, "no trip at 124 degC");
    let published = sim.drive.dictionary().get(h::MOTOR_TEMPERATURE);
    assert!((published - 1240).abs() <= 2, "0x3201:02 = {published}");
    drain_emcy(&mut sim);
    hold_until_off(&mut sim, 25.0, Some(127.0), 50).expect("trips");
    hold(&mut sim, 25.0, Some(127.0), 3);
    assert_eq!(sim.cia402_state(), State::Fault);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x4380);
    assert_ne!(sim.drive.dictionary().get(h::ERROR_REGISTER) & REG_TEMPERATURE, 0);
    let emcy = drain_emcy(&mut sim);
    let frame = emcy.iter().find(|f| u16::from_le_bytes([f[0], f[1]]) == 0x4380).expect("EMCY 0x4380");
    let detail = i32::from_le_bytes([frame[4], frame[5], frame[6], frame[7]]);
    assert!((1251..=1270).contains(&detail), "motor temperature in the EMCY: {detail}");
    let snap = *sim.drive.axis().faults().snapshot(FaultId::MotorThermalOverload).expect("snapshot");
    assert!((snap.power_stage_temperature_ddegc - 250).abs() <= 5, "{snap:?}");

    hold(&mut sim, 25.0, Some(122.0), 50);
    fault_reset(&mut sim, 25.0, Some(122.0));
    assert_eq!(sim.cia402_state(), State::Fault, "refused at 122 degC");
    hold(&mut sim, 25.0, Some(118.0), 50);
    fault_reset(&mut sim, 25.0, Some(118.0));
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "accepted at 118 degC");
}

/// No motor sensor: the channel reads code 0 (open sensor, the pull-down) or 4095 (shorted to the supply):
/// 0x4380 within 20 ms (the rail must hold 10 ms), the reset refused while the sensor is missing and accepted
/// once it reads 25 degC again.
#[test]
fn missing_motor_sensor_trips() {
    for (seed, code) in [(4, 0u16), (5, 4095)] {
        let mut sim = prepare_motion(seed, 10).expect("enabled in CST");
        hold(&mut sim, 25.0, None, 10);
        sim.plant.faults_mut().motor_temperature_code_stuck = Some(code);
        let ticks = hold_until_off(&mut sim, 25.0, None, 50).expect("trips");
        println!("code {code}: outputs off {ticks} slow ticks after the sensor was lost");
        hold(&mut sim, 25.0, None, 3);
        assert_eq!(sim.cia402_state(), State::Fault, "code {code}");
        assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x4380, "code {code}");
        hold(&mut sim, 25.0, None, 50);
        fault_reset(&mut sim, 25.0, None);
        assert_eq!(sim.cia402_state(), State::Fault, "code {code}: refused without a sensor");
        sim.plant.faults_mut().motor_temperature_code_stuck = None;
        hold(&mut sim, 25.0, None, 50);
        fault_reset(&mut sim, 25.0, None);
        assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "code {code}: accepted with the sensor back");
    }
}
