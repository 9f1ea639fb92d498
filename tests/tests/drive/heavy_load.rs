//! A heavy rigid load: the reference motor with 30 times its rotor's inertia on the shaft (1,364 g cm^2, 7.75
//! times the reference's 176), which `drive-sim --plant` scales no differently from the reference by its ratings
//! (same speed, current and torque). The reference's CSP move (3,000 rpm, 20,000 rpm/s) would ask 85 % of the
//! peak torque for its acceleration alone: following error peak 116 increments and 8 left after the move (seed 1,
//! against the issue's 3 degrees = 34 and +-1), a move the motor can hardly follow rather than a figure of the
//! tuning. The scaled move's acceleration is therefore at most what half the peak torque gives the inertia
//! (`hal_sim::scenarios::motion::CspConfig::scaled_to_current_plant`): 11,727 rpm/s here, none of the presets is
//! capped (the reference's move asks 11 % of its peak torque, geared-36v's 22 %).

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::identification::{self, Outcome};
use hal_sim::scenarios::{self, motion};

fn heavy() -> PlantParams {
    let r = PlantParams::reference();
    PlantParams { load_inertia_kg_m2: 30.0 * r.rotor_inertia_kg_m2, ..r }
}

fn scaled_config(plant: &PlantParams) -> motion::CspConfig {
    scenarios::with_plant(plant.clone(), || motion::CspConfig::scaled_to_current_plant(1))
}

/// The cap: half the peak torque (0.0335 Nm/A x 10 A) over 1,364 g cm^2 is 11,727 rpm/s (+-1 rpm/s); the
/// presets keep their speed-scaled acceleration (20,000 rpm/s x max_speed_rpm / 5,000).
#[test]
fn the_scaled_csp_move_asks_at_most_half_the_peak_torque_for_its_acceleration() {
    let capped = scaled_config(&heavy());
    let expected = 0.5 * 0.0335 * 10.0 / (31.0 * 4.4e-6) * 60.0 / std::f64::consts::TAU;
    assert!((capped.peak_rpm_per_s - expected).abs() < 1.0, "{} rpm/s", capped.peak_rpm_per_s);
    for name in ["reference", "small-gimbal", "geared-36v", "nema23-48v"] {
        let path = format!("{}/../hal-sim/presets/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        let p = PlantParams::from_toml_file(std::path::Path::new(&path)).expect("preset");
        let c = scaled_config(&p);
        let speed_scaled = 20_000.0 * p.max_speed_rpm / 5000.0;
        assert!((c.peak_rpm_per_s - speed_scaled).abs() < 1e-9, "{name}: {} rpm/s", c.peak_rpm_per_s);
    }
}

/// After `--auto-tune` (seeds 1 and 2) the capped move's following error peaks within 3 degrees of the motor
/// shaft (34.1 increments of 4,096) and ends within +-1 increment (measured 2 and 0).
#[test]
fn a_heavy_rigid_load_follows_the_scaled_csp_move_within_the_issue_bounds() {
    let plant = heavy();
    for seed in [1, 2] {
        let run = identification::identify(&plant, seed, |_| {});
        assert_eq!(run.outcome, Outcome::Done, "seed {seed}");
        let csp = scenarios::with_plant(plant.clone(), || {
            scenarios::with_parameters(run.parameters, || {
                motion::csp(&motion::CspConfig::scaled_to_current_plant(seed)).expect("csp").0
            })
        });
        assert!(csp.following_error_peak_inc <= 3.0 / 360.0 * 4096.0, "seed {seed}: {csp:?}");
        assert!(csp.settle_error_inc <= 1.0, "seed {seed}: {csp:?}");
    }
}
