//! `drive-sim --auto-tune` on the reference plant: the identification with its auto-tuning (0x6060 = -2) run by a
//! master, its parameters written into the scenarios' drives (`scenarios::with_parameters`), against the hand-tuned
//! defaults (issue 18 "What it must show": the reference's figures with `--auto-tune` are no worse than with the
//! defaults by more than 10 %).
//!
//! Tolerance of each comparison: 10 % of the default's figure (the issue's), plus the figure's own resolution,
//! because the defaults' figures are small numbers a single quantum moves by more than 10 %: 0.1 percentage point
//! of overshoot (the current step's overshoot is 0.6 %, one 8 mA ADC step of a 2 A step is 0.4 %), one increment
//! of following error (the encoder's), 2 us of rise time (the 25 kHz sample's 40 us interpolated).

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::identification::{self, Outcome};
use hal_sim::scenarios::{self, motion, Setup};

/// The parameters the identification and its auto-tuning leave on the reference plant.
fn auto_tuned() -> identification::Parameters {
    let run = identification::identify(&PlantParams::reference(), 1, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished");
    run.parameters
}

fn no_worse(name: &str, tuned: f64, default: f64, quantum: f64) {
    assert!(
        tuned <= default * 1.1 + quantum,
        "{name}: auto-tuned {tuned} against the defaults' {default} (+10 % + {quantum})"
    );
}

/// The current step (2 A, rotor locked): overshoot and rise time; the velocity step (100 rpm, CSV): overshoot;
/// CSP (10 revolutions up to 3,000 rpm): peak following error and the error 20 ms after the last set-point.
#[test]
fn auto_tuned_reference_is_no_worse_than_the_hand_tuned_defaults_by_10_percent() {
    let figures = || {
        let step = scenarios::current_step(&Setup::default(), 2.0).expect("current step").figures;
        let (velocity, _) = motion::csv_step(1, 100.0).expect("csv step");
        let (csp, _) = motion::csp(&motion::CspConfig::default()).expect("csp");
        (step, velocity, csp)
    };
    let (step_d, velocity_d, csp_d) = figures();
    let parameters = auto_tuned();
    assert!(parameters.values.len() == identification::IDENTIFIED_OBJECTS.len(), "every object read back");
    let (step_t, velocity_t, csp_t) = scenarios::with_parameters(parameters, figures);
    no_worse("current-step overshoot %", step_t.overshoot_pct, step_d.overshoot_pct, 0.1);
    no_worse("current-step rise us", step_t.rise_us, step_d.rise_us, 2.0);
    // The velocity step's overshoot, on one run, moves by more than 10 % with changes far below the loop's (over
    // seeds 1..4 the defaults give 5.2 to 6.1 %): compared as the mean over four seeds (plant noise and the
    // identification's own run both change with the seed).
    let mean_overshoot = |auto_tune: bool| {
        let runs = (1..=4u64).map(|seed| {
            let run = || motion::csv_step(seed, 100.0).expect("csv step").0.overshoot_pct;
            match auto_tune {
                true => {
                    let tuned = identification::identify(&PlantParams::reference(), seed, |_| {});
                    assert_eq!(tuned.outcome, Outcome::Done, "identification finished (seed {seed})");
                    scenarios::with_parameters(tuned.parameters, run)
                }
                false => run(),
            }
        });
        runs.sum::<f64>() / 4.0
    };
    let (default_mean, tuned_mean) = (mean_overshoot(false), mean_overshoot(true));
    no_worse("csv step overshoot %, mean of seeds 1..4", tuned_mean, default_mean, 0.1);
    assert!(
        velocity_t.overshoot_pct <= 15.0,
        "csv step overshoot {} % (issue: <= 15 %; the defaults' {} %)",
        velocity_t.overshoot_pct,
        velocity_d.overshoot_pct
    );
    no_worse("csp following error peak inc", csp_t.following_error_peak_inc, csp_d.following_error_peak_inc, 1.0);
    no_worse("csp settle error inc", csp_t.settle_error_inc, csp_d.settle_error_inc, 1.0);
}

/// The parameters reach the scenario's drive: the current gains it runs with are the tuned ones, not the
/// defaults (so the comparison above compares two tunings).
#[test]
fn auto_tuned_parameters_are_the_ones_the_scenario_drive_runs_with() {
    let parameters = auto_tuned();
    let written = |index: u16, sub: u8| {
        parameters
            .values
            .iter()
            .find(|(i, s, _)| (*i, *s) == (index, sub))
            .map(|(_, _, d)| d.iter().rev().fold(0u32, |v, b| v << 8 | u32::from(*b)))
            .expect("read back")
    };
    let p = written(0x30A0, 1);
    assert_ne!(p, 1_555_000, "the tuning computed its own current P gain");
    let (sim, _) =
        scenarios::with_parameters(parameters.clone(), || scenarios::prepare(&Setup::default())).expect("prepared");
    use firmware::od::generated::handles as h;
    assert_eq!(sim.drive.dictionary().get(h::CURRENT_CONTROLLER_P_GAIN), p);
    assert_eq!(sim.drive.dictionary().get(h::OBSERVER_INERTIA), written(0x30A3, 5));
}
