//! Regeneration without an over-voltage trip (the bus-voltage limiter 0x3202 and the braking chopper 0x3203): a
//! quick stop of the reference load from 5,000 rpm, whose 2.4 J are four times what the 470 uF bus holds between
//! the 24 V supply and the 56 V trip (IDX 0x3210, `shared/spec/control-and-protection.md` §3.4).
//!
//! The figures come from `hal_sim::scenarios::regeneration::quick_stop` (PVM at 5,000 rpm, controlword «Quick
//! stop» 0x000B, 0x605A = 6, 0x6085 = 150,000 rpm/s: a 33 ms ramp at 8.2 A, up to 145 W of braking power, far more
//! than the winding absorbs at the 10 A limit, about 40 W). The bus is the plant's, sampled every PWM period.

use firmware::power_state::{DriveError, Trip};
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::regeneration::{quick_stop, ChopperRating};
use hal_sim::sim::SimError;

/// 0x6085 of these stops, rpm/s.
const HARD_QUICK_STOP: u32 = 150_000;
/// The limiter's ceiling with the defaults: 0x3202:04, where a braking q current reaches zero (the trip is 56 V).
const LIMITER_CEILING_V: f64 = 55.0;

/// With the limiter alone (the default, no chopper) the stop does not trip: the bus peaks below the limiter's
/// 55 V ceiling (measured 52.6 V), loss braking and the regenerative-current reduction both act, and the stop
/// takes longer than the 33 ms ramp because the bus, not the ramp, sets the braking (measured 59 ms). The axis
/// starts the ramp again from the actual motion whenever the limiter held the braking back, so the drive ends in
/// «Quick stop active» (0x605A = 6) without a following error (0x603F = 0). The winding pays for it (measured
/// +0.7 K on the plant).
#[test]
fn a_quick_stop_from_5000_rpm_with_the_limiter_alone_stays_below_the_trip() {
    for seed in [1, 2] {
        let (f, _) = quick_stop(seed, PlantParams::reference(), None, true, 5000, HARD_QUICK_STOP).expect("no trip");
        assert!(f.from_rpm > 4_950.0, "{f:?}");
        assert!(f.bus_peak_v < LIMITER_CEILING_V, "{f:?}");
        assert!(f.bus_peak_v > 50.0, "the bus did rise into the limiter's range: {f:?}");
        assert!(f.loss_braking_seen && f.regen_reduced_seen, "{f:?}");
        assert!(f.stop_ms > f.ramp_ms + 5.0, "the limiter stretches the stop: {f:?}");
        // Bound: the energy over what the winding takes at the limit, 2.4 J / 40 W = 60 ms, plus the ramp.
        assert!(f.stop_ms < 100.0, "{f:?}");
        assert_eq!(f.chopper_energy_j, 0.0);
        assert_eq!(f.final_state, firmware::cia402::State::QuickStopActive, "{f:?}");
        assert_eq!(f.error_code, 0, "no following error: {f:?}");
    }
}

/// The limiter is what saves the stop: with 0x3202:01 = 0 the same stop trips the drive on DC-bus over-voltage.
#[test]
fn without_the_limiter_the_same_stop_trips_on_over_voltage() {
    let err = quick_stop(1, PlantParams::reference(), None, false, 5000, HARD_QUICK_STOP).expect_err("it trips");
    assert!(matches!(err, SimError::Drive(DriveError::Protection(Trip::BusOverVoltage))), "{err}");
}

/// With a braking chopper (10 ohm, 50 W, 10 s) the resistor takes the energy: the stop is shorter than with the
/// limiter alone by more than 10 ms (measured 46 against 59 ms; not the ramp's 33 ms, because while the bus climbs
/// 3.6 V per slow period from 24 V at the start the limiter's look-ahead sees it past 53 V and holds the braking
/// back for a few periods before the chopper, on at 50 V, has caught it), the bus peaks near the chopper's
/// switch-on level (measured 51.2 V; bound 52 V, the limiter's loss braking level plus 1 V), and the resistor took
/// what the bus could not (measured 0.56 J).
#[test]
fn with_a_chopper_the_stop_follows_the_ramp_and_the_resistor_takes_the_energy() {
    let (limiter, _) = quick_stop(1, PlantParams::reference(), None, true, 5000, HARD_QUICK_STOP).expect("no trip");
    let (f, _) = quick_stop(
        1,
        PlantParams::reference_with_chopper(),
        Some(ChopperRating::REFERENCE),
        true,
        5000,
        HARD_QUICK_STOP,
    )
    .expect("no trip");
    assert!(f.stop_ms < limiter.stop_ms - 10.0, "chopper {f:?} against limiter {limiter:?}");
    assert!(f.bus_peak_v < 52.0, "{f:?}");
    assert!(f.chopper_energy_j > 0.3, "{f:?}");
    assert_eq!(f.error_code, 0, "{f:?}");
    assert!(!f.chopper_overload_seen, "{f:?}");
}

/// A resistor too small for the stop (1 W, 100 ms: 260 W overload it in the first slow period it conducts) is
/// switched off by its overload protection (0x3203:07 bit 1, warning 0x7113), and the limiter then holds the bus
/// below its ceiling: still no trip. The resistor took a third of what a sound one takes (measured 0.18 J against
/// 0.56 J), and the stop lies between the chopper's and the limiter's alone (measured 52.6 ms).
#[test]
fn an_overloaded_chopper_hands_the_bus_to_the_limiter_without_a_trip() {
    let small = ChopperRating { rated_power_w: 1.0, time_constant_s: 0.1 };
    let (limiter, _) = quick_stop(1, PlantParams::reference(), None, true, 5000, HARD_QUICK_STOP).expect("no trip");
    let (f, _) = quick_stop(1, PlantParams::reference_with_chopper(), Some(small), true, 5000, HARD_QUICK_STOP)
        .expect("no trip");
    assert!(f.chopper_overload_seen, "{f:?}");
    assert!(f.bus_peak_v < LIMITER_CEILING_V, "{f:?}");
    assert!(f.loss_braking_seen, "{f:?}");
    assert!(f.stop_ms <= limiter.stop_ms + 2.0, "{f:?} against {limiter:?}");
    assert!(f.chopper_energy_j < 0.3, "{f:?}");
    assert_eq!(f.error_code, 0, "a warning, not a fault: {f:?}");
}
