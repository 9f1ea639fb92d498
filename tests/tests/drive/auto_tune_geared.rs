//! `drive-sim --auto-tune` on the geared, elastic preset (`hal-sim/presets/geared-36v.toml`: 5:1 gear with
//! 0.3 deg backlash, load 15 x the reflected rotor on a coupling, resonance 60 Hz, anti-resonance 15 Hz,
//! 5,000 counts/rev): the identification with the resonance pair its own step 7 measures into 0x3205:03/04, its
//! auto-tuning's elastic design (`firmware::drive::tuning`, "Position loop"), and the scenarios of issue 18 "What
//! it must show" on that plant, scaled as `drive-sim --plant` scales them.
//!
//! The CSP bounds are the issue's; the others the figure reached (seed 1) plus a tolerance stated at the
//! assertion.

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::identification::{self, Outcome};
use hal_sim::scenarios::{self, motion, PlantScale, Setup};
use std::path::Path;

fn geared() -> PlantParams {
    let path = format!("{}/../hal-sim/presets/geared-36v.toml", env!("CARGO_MANIFEST_DIR"));
    PlantParams::from_toml_file(Path::new(&path)).expect("geared preset")
}

/// The whole identification (with its resonance step: 59.3 Hz / 14.2 Hz measured on seed 1) and its tuning.
fn auto_tuned(params: &PlantParams) -> identification::Parameters {
    let run = identification::identify(params, 1, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished");
    run.parameters
}

/// CSP (4 revolutions up to 1,200 rpm x 0.4, jerk-limited, 1 ms set-points), the figures: following error
/// peak <= 3 deg of the motor shaft (41.7 increments at 5,000 counts/rev; reached 19) and within +-1 increment 20 ms
/// after the last set-point (reached 1); rms <= 11 (the largest of seeds 1..6 before the friction feedforward
/// 0x30A1:06, `drive-sim csp --plant ... --auto-tune --seed N`: peak 23 to 26, rms 8.0 to 10.0, 0 to 1 left; +10 %
/// for the seed's identified inertia and resonance pair the gains come from; with it 18 to 22, 7.2 to 8.9, 0 to 1).
/// The elastic design's `Kp` (`firmware::drive::tuning`, "Position loop": the servo twice as stiff as the
/// coupling) makes these; the former rule (`Kp` at 0.54 x the anti-resonance) gave 115 to 190 / 25 to 34 left, so
/// the bounds fail without it. The velocity step (100 rpm x 0.4):
/// overshoot <= 15 % (the issue's). The current step: overshoot <= 10 % (the issue's).
#[test]
fn auto_tuned_geared_axis_follows_csp_within_3_degrees_and_settles_within_1_increment() {
    let params = geared();
    let parameters = auto_tuned(&params);
    let (csp, velocity, step) = scenarios::with_plant(params, || {
        scenarios::with_parameters(parameters, || {
            let sc = PlantScale::current_plant();
            let (csp, _) = motion::csp(&motion::CspConfig::scaled_to_current_plant(1)).expect("csp");
            let (velocity, _) = motion::csv_step(1, motion::csv_step_rpm()).expect("csv step");
            let step = scenarios::current_step(&Setup::default(), 2.0 * sc.current).expect("current step").figures;
            (csp, velocity, step)
        })
    });
    let three_degrees_inc = 3.0 / 360.0 * 5000.0;
    assert!(csp.following_error_peak_inc <= three_degrees_inc, "csp peak {} inc", csp.following_error_peak_inc);
    assert!(csp.following_error_rms_inc <= 10.0 * 1.1, "csp rms {} inc", csp.following_error_rms_inc);
    assert!(csp.settle_error_inc <= 1.0, "csp settle {} inc", csp.settle_error_inc);
    assert!(velocity.overshoot_pct <= 15.0, "csv step overshoot {} %", velocity.overshoot_pct);
    assert!(step.overshoot_pct <= 10.0, "current step overshoot {} %", step.overshoot_pct);
}

/// Seed 4 of the geared preset, whose relay fit put 175 x the plant's viscous friction and 43 % of its Coulomb
/// friction into the split (`firmware::drive::mechanical_identification`, "Friction split"): kept, its velocity
/// feed-forward (1.8 A at the move's 980 rpm) held the CSP 39 increments off its path and 5 from the target; with
/// the split folded into Coulomb friction the 3 deg (41.7 increments; reached 26) and +-1 increment
/// (reached 0) hold, as on seed 1. 0x30A1:04 (the velocity feed-forward `B / kt`) is 0.
#[test]
fn an_unresolved_friction_split_leaves_no_velocity_feed_forward_and_seed_4_follows_csp_within_3_degrees() {
    let params = geared();
    let run = identification::identify(&params, 4, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished");
    let ff_velocity = run.parameters.values.iter().find(|(index, sub, _)| *index == 0x30A1 && *sub == 4);
    assert_eq!(ff_velocity.map(|(_, _, data)| data.as_slice()), Some(&[0u8, 0, 0, 0][..]), "0x30A1:04");
    let csp = scenarios::with_plant(params, || {
        scenarios::with_parameters(run.parameters, || {
            motion::csp(&motion::CspConfig::scaled_to_current_plant(4)).expect("csp").0
        })
    });
    let three_degrees_inc = 3.0 / 360.0 * 5000.0;
    assert!(csp.following_error_peak_inc <= three_degrees_inc, "csp peak {} inc", csp.following_error_peak_inc);
    assert!(csp.settle_error_inc <= 1.0, "csp settle {} inc", csp.settle_error_inc);
}
