//! The "no false trip" duty cycle (issue 18 "What it must show", `hal_sim::scenarios::duty_cycle`) after
//! `--auto-tune` on the geared, elastic preset (`hal-sim/presets/geared-36v.toml`: 36 V, 5:1 gear with backlash,
//! load on a 60 Hz / 15 Hz coupling, the reference power stage: 470 uF, 56 V trip).
//!
//! Its reversals brake the rotor at the current limit while the load winds the coupling up and throws the rotor
//! back (to about 1,300 rpm from 850): the load's kinetic energy (about 1.1 J) is more than the bus holds between
//! 36 and 56 V (0.43 J), so the bus-voltage limiter 0x3202 must hold it (`firmware::drive::regeneration`, "The
//! current, not its reference", "Power, not current" and "Release"). Without its measured-current correction the
//! bus reached the 56 V trip (0x3210) at 36.6 s; with the correction dropped in one step when the bus left the
//! band, the velocity loop's full braking came back at 1,700 rpm and the bus reached 56.03 V at 36.6 s, the trip
//! again.
//!
//! Both tests share one run (seed 1): the identification and the 60 s cycle take most of this binary's time.

use firmware::drive::protection::BUS_OVER_VOLTAGE_MV;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios;
use hal_sim::scenarios::duty_cycle::{duty_cycle, DutyCycleFigures};
use hal_sim::scenarios::identification::{self, Outcome};
use std::path::Path;
use std::sync::OnceLock;

/// The margin the limiter keeps under the over-voltage trip on this cycle, V: more than the plant's integration
/// alone moved the peak by (seed 1: 55.4 V with the reference integrator against 56.03 V with the switching
/// intervals' before the limiter's factor followed the braking power and its correction was given back step by
/// step). Measured 1.51 V (seed 1), 1.41 to 1.57 V over seeds 1..3 with either integrator.
const BUS_MARGIN_V: f64 = 1.4;

/// The duty cycle (seed 1) with the gains the identification tuned on the geared preset, run once.
fn auto_tuned_geared_duty_cycle() -> &'static DutyCycleFigures {
    static RUN: OnceLock<DutyCycleFigures> = OnceLock::new();
    RUN.get_or_init(|| {
        let path = format!("{}/../hal-sim/presets/geared-36v.toml", env!("CARGO_MANIFEST_DIR"));
        let params = PlantParams::from_toml_file(Path::new(&path)).expect("geared preset");
        let run = identification::identify(&params, 1, |_| {});
        assert_eq!(run.outcome, Outcome::Done, "identification finished");
        let (f, _) = scenarios::with_plant(params, || {
            scenarios::with_parameters(run.parameters, || duty_cycle(1).expect("the duty cycle runs"))
        });
        f
    })
}

/// 60 s of the duty cycle with the gains the identification tuned (seed 1): no fault and no warning (exact, as
/// the reference plant's duty cycle), and the bus rose into the limiter's range (above its 51 V loss-braking
/// level; measured 54.5 V peak), so the limiter, not a quiet cycle, kept it below the trip.
#[test]
fn auto_tuned_geared_duty_cycle_raises_no_fault_and_no_warning() {
    let f = auto_tuned_geared_duty_cycle();
    assert_eq!(f.false_trips, 0, "false trips: {:?}", f.events);
    assert_eq!(f.warnings, 0, "warnings: {:?}", f.events);
    assert!(f.bus_max_v > 51.0, "regeneration reached the limiter: bus peak {:.1} V", f.bus_max_v);
    assert!(f.moves >= 100, "{} velocity steps", f.moves);
}

/// The limiter holds the bus at least [`BUS_MARGIN_V`] under the 0x3210 trip (IDX 0x3210; 56 V,
/// `BUS_OVER_VOLTAGE_MV`) through every braking of the cycle, the reversals where the coupling throws the rotor
/// faster than the braking began at included: the peak of the plant's bus, sampled every PWM period, at most
/// 54.6 V (measured 54.49 V; 56.03 V, the trip, when the limiter handed the braking current back in one step).
#[test]
fn auto_tuned_geared_duty_cycle_keeps_the_bus_1_4_v_under_the_over_voltage_trip() {
    let f = auto_tuned_geared_duty_cycle();
    let trip_v = f64::from(BUS_OVER_VOLTAGE_MV) / 1000.0;
    assert!(
        f.bus_max_v <= trip_v - BUS_MARGIN_V,
        "bus peak {:.2} V, {:.2} V under the {trip_v} V trip (at least {BUS_MARGIN_V} V): {:?}",
        f.bus_max_v,
        trip_v - f.bus_max_v,
        f.events
    );
}
