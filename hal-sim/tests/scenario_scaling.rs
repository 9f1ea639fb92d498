//! How `drive-sim --plant` scales the CSV scenario (issue 18 item 1: "Scenario moves, steps and loads scale with
//! the plant's ratings ... so that each scenario means the same on every preset"): the velocity step of
//! `drive-sim csv-sweep` on each preset, its cap at half the maximum speed, and the sine sweep on a slow plant.
//! Each case states the exact step in whole rpm (0x60FF's unit) it expects.

use std::path::PathBuf;

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::{self, motion, PlantScale};

fn preset(name: &str) -> PlantParams {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("presets").join(name);
    PlantParams::from_toml_file(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn step_on(plant: PlantParams) -> f64 {
    scenarios::with_plant(plant, motion::csv_step_rpm)
}

/// The reference is its own scale: every factor exactly 1, the step the reference's 100 rpm.
#[test]
fn the_reference_plant_keeps_the_100_rpm_step() {
    let scale = PlantScale::of(&PlantParams::reference());
    assert_eq!(
        (scale.speed, scale.current, scale.torque, scale.inertia, scale.acceleration),
        (1.0, 1.0, 1.0, 1.0, 1.0)
    );
    assert_eq!(step_on(PlantParams::reference()), 100.0);
    assert_eq!(step_on(preset("reference.toml")), 100.0);
}

/// Small gimbal: kt 0.05 Nm/A x 1.5 A on 10 g cm^2 is 3.94 times the reference's acceleration (0.335 N m on
/// 176 g cm^2), above its speed scale (1,200 / 5,000): 394 rpm, under half its 1,200 rpm.
#[test]
fn the_small_gimbal_step_follows_its_acceleration_capability() {
    let scale = PlantScale::of(&preset("small-gimbal.toml"));
    assert!((scale.acceleration - 3.94).abs() < 0.005, "{scale:?}");
    assert_eq!(step_on(preset("small-gimbal.toml")), 394.0);
}

/// geared-36v: 1.2 N m on 3,200 g cm^2 at the motor shaft is 0.197 of the reference's acceleration, under its
/// speed scale (2,000 / 5,000): the step keeps the speed scale's 40 rpm.
#[test]
fn the_geared_step_follows_its_speed_scale() {
    let scale = PlantScale::of(&preset("geared-36v.toml"));
    assert!((scale.acceleration - 0.197).abs() < 0.001, "{scale:?}");
    assert_eq!(step_on(preset("geared-36v.toml")), 40.0);
}

/// nema23-48v: 0.84 N m on 360 g cm^2 is 1.226 of the reference's acceleration: 123 rpm (its speed scale gives 60).
#[test]
fn the_48_v_step_follows_its_acceleration_capability() {
    assert_eq!(step_on(preset("nema23-48v.toml")), 123.0);
}

/// A plant whose acceleration scale would put the step above half its maximum speed is held there: the gimbal
/// motor limited to 600 rpm steps to 300 rpm, not 394.
#[test]
fn the_step_is_at_most_half_the_maximum_speed() {
    let slow_gimbal = PlantParams { max_speed_rpm: 600.0, ..preset("small-gimbal.toml") };
    assert_eq!(step_on(slow_gimbal), 300.0);
}

/// The sine sweep keeps 600 +- 30 rpm on every preset (all run at 1,200 rpm or more) and on a 500 rpm plant comes
/// down to 250 +- 12.5 rpm, so that the sine stays under its 0x6080.
#[test]
fn the_sine_sweep_is_scaled_only_on_a_plant_slower_than_1200_rpm() {
    for name in ["reference.toml", "small-gimbal.toml", "geared-36v.toml", "nema23-48v.toml"] {
        assert_eq!(scenarios::with_plant(preset(name), motion::csv_sweep_rpm), (600.0, 30.0), "{name}");
    }
    let slow = PlantParams { max_speed_rpm: 500.0, ..PlantParams::reference() };
    assert_eq!(scenarios::with_plant(slow, motion::csv_sweep_rpm), (250.0, 12.5));
}
