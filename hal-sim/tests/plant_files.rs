//! Plant files (issue 18 item 1): the presets in `hal-sim/presets/` parse and are what they claim; a missing key
//! keeps the reference value; an unknown key and a bad value are errors naming the key and the file.

use std::path::PathBuf;

use hal_sim::plant::{PlantFileError, PlantParams};

fn preset(name: &str) -> PlantParams {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("presets").join(name);
    PlantParams::from_toml_file(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Relative closeness for values computed from a preset's data (kt from the flux linkage).
fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs()
}

/// The power stage of every preset is the reference one (issue 18 item 1: "shunt span, bus sensing, trip levels").
fn assert_reference_power_stage(p: &PlantParams) {
    let r = PlantParams::reference();
    assert_eq!(p.shunt_gain_lsb_per_a, r.shunt_gain_lsb_per_a, "shunt span");
    assert_eq!(p.shunt_offset_lsb, r.shunt_offset_lsb);
    assert_eq!(p.bus_gain_lsb_per_v, r.bus_gain_lsb_per_v, "bus sensing");
    assert_eq!(p.adc_reference_v, r.adc_reference_v);
    assert_eq!(p.break_current_a, r.break_current_a, "trip level");
    assert_eq!(p.bus_capacitance_f, r.bus_capacitance_f);
    assert_eq!(p.source_resistance_ohm, r.source_resistance_ohm);
    assert_eq!(p.chopper_resistance_ohm, r.chopper_resistance_ohm);
    assert_eq!(
        (p.dead_time_s, p.switch_resistance_ohm, p.diode_drop_v),
        (r.dead_time_s, r.switch_resistance_ohm, r.diode_drop_v)
    );
    assert_eq!(p.io, r.io, "the digital I/O is not in a plant file");
}

#[test]
fn reference_toml_equals_the_reference_plant_exactly() {
    assert_eq!(preset("reference.toml"), PlantParams::reference());
}

/// `drive-sim ssi`'s default plant is the preset's: the reference motor with a 12 + 12-bit Gray SSI sensor.
#[test]
fn reference_ssi_toml_equals_the_ssi_scenario_plant() {
    assert_eq!(preset("reference-ssi.toml"), hal_sim::scenarios::ssi::reference_ssi_plant());
}

/// An SSI sensor the drive cannot read is refused by name: 17 single-turn bits (the drive keeps at most 16), or 12
/// + 20 bits with the frame bits (34 clocked bits, over 32).
#[test]
fn an_ssi_sensor_out_of_range_is_refused_naming_its_key() {
    assert_names(&refused("ssi_single_turn_bits = 17"), "ssi_single_turn_bits");
    assert_names(&refused("ssi_single_turn_bits = 12\nssi_multi_turn_bits = 20"), "ssi_multi_turn_bits");
}

#[test]
fn the_reference_plant_written_as_a_file_reads_back_equal() {
    let text = PlantParams::reference().to_toml_string();
    assert_eq!(PlantParams::from_toml_str(&text, "written").unwrap(), PlantParams::reference());
}

#[test]
fn small_gimbal_preset_has_the_issue_ratings() {
    let p = preset("small-gimbal.toml");
    assert_eq!(p.source_voltage_v, 12.0);
    assert_eq!(p.pole_pairs, 11);
    assert_eq!(p.phase_resistance_ohm, 2.8);
    assert_eq!((p.ld_h, p.lq_h), (1.5e-3, 1.5e-3));
    assert!(close(p.torque_constant_nm_per_a(), 0.05, 1e-12), "kt {}", p.torque_constant_nm_per_a());
    assert_eq!(p.rotor_inertia_kg_m2, 10.0e-7, "10 g cm^2");
    assert_eq!(p.load_inertia_kg_m2, 0.0, "no load");
    assert_eq!(p.gear_ratio, 1.0);
    assert!(!p.coupling_is_compliant());
    assert_eq!(p.encoder_counts_per_rev, 16_384);
    assert_eq!((p.nominal_current_a, p.peak_current_a, p.max_speed_rpm), (0.6, 1.5, 1200.0));
    assert_reference_power_stage(&p);
}

#[test]
fn geared_36v_preset_has_the_issue_ratings() {
    let p = preset("geared-36v.toml");
    assert_eq!(p.source_voltage_v, 36.0);
    assert_eq!(p.pole_pairs, 5);
    assert_eq!(p.phase_resistance_ohm, 0.05);
    assert_eq!((p.ld_h, p.lq_h), (0.07e-3, 0.09e-3));
    assert!(close(p.torque_constant_nm_per_a(), 0.1, 1e-12), "kt {}", p.torque_constant_nm_per_a());
    assert_eq!(p.rotor_inertia_kg_m2, 200.0e-7, "200 g cm^2");
    assert_eq!((p.gear_ratio, p.gear_backlash_deg), (5.0, 0.3));
    let reflected_rotor = p.rotor_inertia_kg_m2 * p.gear_ratio * p.gear_ratio;
    assert!(close(p.load_inertia_kg_m2, 15.0 * reflected_rotor, 1e-12), "load 15 x the reflected rotor");
    assert!(p.coupling_is_compliant());
    // The file's stiffness is rounded to 4 decimals: 60 Hz within 0.01 Hz by the formula (the simulated
    // resonance is checked in tests/drivetrain.rs).
    assert!((p.coupling_resonance_hz() - 60.0).abs() < 0.01, "{} Hz", p.coupling_resonance_hz());
    // The anti-resonance, the load alone on the coupling: sqrt(66.6198 / 0.0075) / 2 pi = 15.0 Hz (60 / sqrt 16).
    assert!((p.coupling_anti_resonance_hz() - 15.0).abs() < 0.01, "{} Hz", p.coupling_anti_resonance_hz());
    assert_eq!(p.encoder_counts_per_rev, 5_000, "1,250 lines");
    assert_eq!((p.nominal_current_a, p.peak_current_a, p.max_speed_rpm), (5.0, 12.0, 2000.0));
    assert_reference_power_stage(&p);
}

/// The 48 V class preset: what its file's comment claims, on the reference power stage; its supply 3 V under the
/// bus-voltage limiter's default 51 V (0x3202:02), the case the identification's relay must run in.
#[test]
fn nema23_48v_preset_is_the_48_v_class_motor_it_claims() {
    let p = preset("nema23-48v.toml");
    assert_eq!(p.source_voltage_v, 48.0);
    assert_eq!(p.pole_pairs, 4);
    assert_eq!(p.phase_resistance_ohm, 0.3);
    assert_eq!((p.ld_h, p.lq_h), (0.5e-3, 0.5e-3));
    assert!(close(p.torque_constant_nm_per_a(), 0.07, 1e-12), "kt {}", p.torque_constant_nm_per_a());
    assert_eq!((p.rotor_inertia_kg_m2, p.load_inertia_kg_m2), (120.0e-7, 240.0e-7), "120 + 240 g cm^2");
    assert!(!p.coupling_is_compliant());
    assert_eq!(p.encoder_counts_per_rev, 4_000, "1,000 lines");
    assert_eq!((p.nominal_current_a, p.peak_current_a, p.max_speed_rpm), (6.0, 12.0, 3000.0));
    // The thermal rule of the other presets: the nominal current heats the winding by 100 K.
    let watts = 1.5 * p.phase_resistance_ohm * p.nominal_current_a * p.nominal_current_a;
    let rise = watts * (p.winding_to_housing_k_per_w + p.housing_to_ambient_k_per_w);
    assert!((rise - 100.0).abs() < 0.5, "{rise} K");
    assert_reference_power_stage(&p);
}

#[test]
fn a_missing_key_keeps_the_reference_value() {
    let p = PlantParams::from_toml_str("source_voltage_v = 12\npole_pairs = 4\n", "two-keys.toml").unwrap();
    let expected = PlantParams { source_voltage_v: 12.0, pole_pairs: 4, ..PlantParams::reference() };
    assert_eq!(p, expected, "an integer is taken for a float key");
}

fn refused(text: &str) -> PlantFileError {
    match PlantParams::from_toml_str(text, "bench/motor.toml") {
        Ok(p) => panic!("accepted {text:?}: {p:?}"),
        Err(e) => e,
    }
}

/// The error names the key and the file, in its fields and in its text.
fn assert_names(e: &PlantFileError, key: &str) {
    assert_eq!(e.file, "bench/motor.toml");
    assert_eq!(e.key.as_deref(), Some(key), "{e}");
    let text = e.to_string();
    assert!(text.contains("bench/motor.toml") && text.contains(&format!("`{key}`")), "{text}");
}

#[test]
fn an_unknown_key_is_refused_naming_key_and_file() {
    assert_names(&refused("phase_resistance_ohm = 0.3\nphase_resistence_ohm = 0.3\n"), "phase_resistence_ohm");
    // The digital I/O is not part of a plant file.
    assert_names(&refused("[io]\nbrake = true\n"), "io");
}

#[test]
fn a_value_of_the_wrong_type_is_refused_naming_key_and_file() {
    let e = refused("pole_pairs = \"seven\"\n");
    assert_names(&e, "pole_pairs");
    assert!(e.reason.contains("invalid type"), "{e}");
    assert_names(&refused("pole_pairs = -7\n"), "pole_pairs");
    assert_names(&refused("shunt_offset_lsb = [1.0, 2.0]\n"), "shunt_offset_lsb");
}

#[test]
fn a_value_out_of_its_physical_range_is_refused_naming_key_and_file() {
    for (text, key) in [
        ("phase_resistance_ohm = -0.26", "phase_resistance_ohm"),
        ("ld_h = 0", "ld_h"),
        ("rotor_inertia_kg_m2 = -1e-6", "rotor_inertia_kg_m2"),
        ("load_inertia_kg_m2 = -1e-6", "load_inertia_kg_m2"),
        ("pole_pairs = 0", "pole_pairs"),
        ("gear_efficiency = 1.2", "gear_efficiency"),
        ("gear_efficiency = 0", "gear_efficiency"),
        ("gear_ratio = 0", "gear_ratio"),
        ("coupling_stiffness_nm_per_rad = -5", "coupling_stiffness_nm_per_rad"),
        ("gear_backlash_deg = 0.3", "gear_backlash_deg"),
        ("coupling_stiffness_nm_per_rad = 10\nload_inertia_kg_m2 = 0", "load_inertia_kg_m2"),
        ("encoder_counts_per_rev = 1023", "encoder_counts_per_rev"),
        ("load_encoder_counts_per_rev = 6", "load_encoder_counts_per_rev"),
        ("peak_current_a = 1", "peak_current_a"),
        ("max_speed_rpm = nan", "max_speed_rpm"),
    ] {
        let e = refused(text);
        assert_names(&e, key);
    }
}

#[test]
fn a_syntax_error_names_the_file_and_line() {
    let e = refused("pole_pairs = = 7\n");
    assert_eq!(e.key, None);
    assert!(e.to_string().contains("bench/motor.toml") && e.reason.contains("line 1"), "{e}");
}

#[test]
fn a_missing_file_is_refused_naming_it() {
    let e = PlantParams::from_toml_file(std::path::Path::new("/nonexistent/plant.toml")).unwrap_err();
    assert!(e.to_string().contains("/nonexistent/plant.toml"), "{e}");
}
