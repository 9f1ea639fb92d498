//! The tier-1 protections on the reference plant: each condition switches the outputs off in the fast tick whose
//! sample shows it (the "disable power immediately" class), the machine reaches «Fault» with the IDX error code,
//! and a fault reset is refused while the cause is still measured.

use firmware::cia402::State;
use firmware::drive::protection::{BUS_OVER_VOLTAGE_MV, BUS_UNDER_VOLTAGE_MV};
use firmware::od::generated::handles as h;
use hal_sim::scenarios::motion::prepare_motion;
use hal_sim::sim::Simulation;

/// Runs until the drive switches the outputs off; the periods it took.
fn periods_until_off(sim: &mut Simulation, max: u64) -> Option<u64> {
    sim.run_until(max, |s| !s.command().enabled)
}

/// Runs slow ticks until the machine is in «Fault».
fn reach_fault(sim: &mut Simulation) {
    let reached = sim.run_until(250, |s| s.cia402_state() == State::Fault);
    assert!(reached.is_some(), "reaches Fault, state {:?}", sim.cia402_state());
}

/// Sends a fault reset (rising edge of bit 7) and runs a few slow ticks.
fn fault_reset(sim: &mut Simulation) {
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(2);
    sim.set_controlword(0x0080);
    sim.run_slow_ticks(3);
}

/// Over-voltage: the supply rises to 58 V (a wrong supply). The outputs go off in the period whose sample first
/// reads more than 56 V (the check is on the same sample; the 0.1 V tolerance covers the bus ADC's 14.6 mV steps
/// and its noise), 0x603F = 0x3210, and the reset is refused until the bus is back under 52 V.
#[test]
fn bus_over_voltage_trips_at_once() {
    let mut sim = prepare_motion(1, 8).expect("enabled");
    sim.plant.set_source_voltage(58.0);
    periods_until_off(&mut sim, 25_000).expect("trips");
    let seen_mv = f64::from(BUS_OVER_VOLTAGE_MV) / 1000.0;
    let measured = sim.tier1().signals().v_bus.to_millivolts();
    // The sample that tripped was the first one above the limit: the plant's bus at the sample is above it and
    // one period earlier it was not (the drive would have tripped then).
    assert!(f64::from(measured) / 1000.0 > seen_mv - 0.1, "tripped at {measured} mV");
    reach_fault(&mut sim);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x3210);
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::Fault, "refused while the bus is over-voltage");
    // The plant's supply cannot sink current: with the outputs off the capacitor keeps its charge until something
    // drains it (a bleeder on real hardware). Drain it here.
    sim.plant.set_source_voltage(24.0);
    sim.plant.set_bus_voltage(24.0);
    sim.run(25 * 10);
    fault_reset(&mut sim);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "accepted once the bus is back");
}

/// Under-voltage while switching: the supply (and the bus) sags to 7 V; 0x603F = 0x3220. With the outputs off the same sag is
/// no fault (the drive waits for its supply).
#[test]
fn bus_under_voltage_trips_only_while_switching() {
    let mut sim = prepare_motion(1, 8).expect("enabled");
    sim.set_controlword(0x0000);
    sim.run_slow_ticks(3);
    sim.plant.set_source_voltage(7.0);
    sim.plant.set_bus_voltage(7.0);
    sim.run(25 * 100);
    assert_eq!(sim.cia402_state(), State::SwitchOnDisabled, "no fault with the outputs off");
    sim.plant.set_source_voltage(24.0);
    sim.plant.set_bus_voltage(24.0);
    sim.run(25 * 100);
    sim.enable_through_controlword(8).expect("enabled again");
    // A sag: the supply drops and the capacitor with it.
    sim.plant.set_source_voltage(7.0);
    sim.plant.set_bus_voltage(7.0);
    periods_until_off(&mut sim, 25_000).expect("trips");
    let measured = sim.tier1().signals().v_bus.to_millivolts();
    assert!(measured < BUS_UNDER_VOLTAGE_MV + 100, "tripped at {measured} mV");
    reach_fault(&mut sim);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x3220);
}

/// A shunt channel drifts by 200 LSB (1.6 A) after the calibration: the phase currents no longer sum to zero;
/// 0x603F = 0x2330 within one period of the drift.
#[test]
fn shunt_drift_is_implausible() {
    let mut sim = prepare_motion(1, 8).expect("enabled");
    sim.plant.set_adc_offset(1, -200.0);
    let off = periods_until_off(&mut sim, 10).expect("trips");
    assert!(off <= 2, "off within the period that sampled the drift: {off}");
    reach_fault(&mut sim);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0x2330);
}
