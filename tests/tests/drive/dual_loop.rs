//! The dual loop (issue 20 item 2; EPOS4 AN ch. 10): the load encoder (sensor 2, 0x3020) closes the position loop
//! through the gear ratio 0x3003, the velocity loop stays on the motor encoder. Its configuration is refused as a
//! whole when it cannot work (0x0604_0043), the geared-36v plant settles on the load encoder where the motor
//! encoder alone misses by the backlash, and `drive-sim dual-loop` prints its figures and writes its plot.

use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::{handles as h, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::store::ParamStore;
use hal_sim::flash::SimFlash;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios;
use hal_sim::scenarios::dual_loop::{self, DualLoopConfig, DualLoopError, DualLoopFigures};
use hal_sim::scenarios::identification::{self, Outcome};
use std::path::{Path, PathBuf};
use std::process::Command;

const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};

/// 0x3000:01 encoder + load encoder (sensor 2 type 2) + Halls.
const WITH_LOAD_ENCODER: u32 = 0x0004_0201;
/// 0x3000:02 dual loop: main sensor 2 (bits 19..16) on the gear output (bits 27..26 = 1), gear, PID, PI low-pass.
const DUAL_LOOP: u32 = 0x0402_1111;

fn geared_preset() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../hal-sim/presets/geared-36v.toml")
}

fn write(drive: &mut Drive, store: &mut ParamStore<SimFlash>, index: u16, sub: u8, value: u32) -> Result<(), SdoAbort> {
    drive.sdo_write(index, sub, &value.to_le_bytes(), PRE_OP, store)
}

/// 0x3000:02 = dual loop needs sensor 2 in 0x3000:01 (EPOS4 AN ch. 10: the main sensor is the load encoder); without
/// it the write aborts with 0x0604_0043 (CiA 301 Table 22, general parameter incompatibility) and 0x3000:02 keeps
/// its value. Once configured, taking the load encoder out of 0x3000:01 is refused the same way.
#[test]
fn dual_loop_without_the_load_encoder_is_refused() {
    let mut drive = Drive::new(DriveConfig::DEFAULT);
    let mut store = ParamStore::new(SimFlash::params());
    assert_eq!(write(&mut drive, &mut store, 0x3000, 2, DUAL_LOOP), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(drive.dictionary().get(h::CONTROL_STRUCTURE), 0x0001_0111, "nothing changed");
    assert_eq!(write(&mut drive, &mut store, 0x3000, 1, WITH_LOAD_ENCODER), Ok(()));
    assert_eq!(write(&mut drive, &mut store, 0x3000, 2, DUAL_LOOP), Ok(()));
    assert_eq!(write(&mut drive, &mut store, 0x3000, 1, 0x0004_0001), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(drive.dictionary().get(h::SENSORS_CONFIGURATION), WITH_LOAD_ENCODER, "nothing changed");
    // Main sensor 2 without its mounting position is no structure this drive offers: 0x0609_0030 (value range).
    assert_eq!(write(&mut drive, &mut store, 0x3000, 2, 0x0002_1111), Err(SdoAbort::InvalidValue));
}

/// EPOS3 L6343: gear ratio x auxiliary resolution / main resolution must lie in 2^-11..2^15 (EPOS3's 0xFF0F, the
/// gear scaling factor error). With the reference encoder (4,096 inc/rev): a 2,500,000-line load encoder
/// (10^7 inc/rev) at 1:1 is 4,096 / 10^7 = 0.00041 < 2^-11 = 0.00049, refused when the dual loop is selected; a
/// gear of 40,000:1 on a 16-line load encoder (64 inc/rev) is 2,560,000 > 2^15, refused when the gear is written.
/// Each refusal is 0x0604_0043 and leaves the objects as they were; 5:1 with 5,000 lines (1.024) is taken.
#[test]
fn gear_scaling_factor_out_of_range_is_refused() {
    let mut drive = Drive::new(DriveConfig::DEFAULT);
    let mut store = ParamStore::new(SimFlash::params());
    assert_eq!(drive.dictionary().get(h::MAIN_SENSOR_RESOLUTION), 4096);
    assert_eq!(write(&mut drive, &mut store, 0x3000, 1, WITH_LOAD_ENCODER), Ok(()));
    assert_eq!(write(&mut drive, &mut store, 0x3020, 1, 2_500_000), Ok(()), "no dual loop yet: taken");
    assert_eq!(write(&mut drive, &mut store, 0x3000, 2, DUAL_LOOP), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(drive.dictionary().get(h::CONTROL_STRUCTURE), 0x0001_0111);
    assert_eq!(write(&mut drive, &mut store, 0x3020, 1, 16), Ok(()));
    assert_eq!(write(&mut drive, &mut store, 0x3000, 2, DUAL_LOOP), Ok(()), "4,096 / 64 = 64: in range");
    assert_eq!(write(&mut drive, &mut store, 0x3003, 1, 40_000), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(drive.dictionary().get(h::GEAR_REDUCTION_NUMERATOR), 1, "nothing changed");
    assert_eq!(write(&mut drive, &mut store, 0x3020, 1, 5_000), Ok(()));
    assert_eq!(write(&mut drive, &mut store, 0x3003, 1, 5), Ok(()), "5 x 4,096 / 20,000 = 1.024");
}

/// The auto-tuned drive on `params` (identification on `seed`, as `drive-sim --auto-tune --seed`): every gain,
/// the main loop's 0x30AE:01..03 included, comes from the identification's auto-tuning.
fn identify(params: &PlantParams, seed: u64) -> identification::IdentifyRun {
    let run = identification::identify(params, seed, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished on seed {seed}");
    run
}

fn run_tuned(params: &PlantParams, run: &identification::IdentifyRun, seed: u64, dual: bool) -> DualLoopFigures {
    let config = DualLoopConfig { dual_loop: dual, seed, ..DualLoopConfig::default() };
    scenarios::with_parameters(run.parameters.clone(), || dual_loop::dual_loop(params.clone(), &config))
        .expect("dual-loop run")
        .0
}

/// An identified object's value as the identification read it back (little-endian, up to 4 bytes).
fn identified(run: &identification::IdentifyRun, index: u16, sub: u8) -> u32 {
    let (_, _, data) = run
        .parameters
        .values
        .iter()
        .find(|(i, s, _)| (*i, *s) == (index, sub))
        .unwrap_or_else(|| panic!("0x{index:04X}:{sub:02X} identified"));
    data.iter().rev().fold(0u32, |acc, b| (acc << 8) | u32::from(*b))
}

/// Issue 20 item 2 "What it must show": on geared-36v (5:1, 0.3 deg backlash = 33.3 increments of its 40,000-count
/// load encoder, coupling at 60 Hz), a 90 deg CSP move of the load at 1 ms set-points, on each of the seeds 1, 2, 3.
/// With the load encoder closing the loop (the master's set-points in the load encoder's increments, its main
/// sensor's) and the main loop's gains from the auto-tuning, the load settles within +-2 load increments over the
/// last 100 ms of the 1.5 s hold (reached: 0, 2, 1, within the band from 0.75, 0.49 and 0.20 s after the move: the
/// load rings, then stands on its friction until the velocity integral breaks it away); with the motor encoder
/// alone it stays outside the band (reached: 42, 46, 43: the motor stands within +-1 of its own target, held by
/// the position PID's friction feedforward, and the load wherever the backlash and the coupling left it, which the
/// motor encoder cannot see), asserted as outside +-2 and within the load's play against the motor between the
/// start and the end of the run: the backlash (33.3 load increments), the coupling's twist under the load's
/// Coulomb friction on either side of it (2 x 0.045 Nm / 66.6 Nm/rad = 8.6), the motor's +-1 increment at the
/// start and at the end (2 x 1.6 load increments) and the load encoder's own increment (1), 46.1 in all. (Before
/// the elastic design's D filter, `firmware::drive::tuning`, the load ended 37, 32 and 18 off; that bound counted
/// the twist and the motor's increment once, 39.2, which the load's start on the other side of the band exceeds.)
/// The following error peak (376 to
/// 387 load increments, the coupling's twist under the move's acceleration) and the motor/load deviation (1.96 deg)
/// are bounded by what a stable run reaches plus 20 % (an unstable loop rings far beyond them).
#[test]
fn load_encoder_settles_the_load_on_each_seed_where_the_motor_encoder_misses_by_the_backlash() {
    let params = PlantParams::from_toml_file(&geared_preset()).expect("geared preset");
    for seed in [1, 2, 3] {
        let run = identify(&params, seed);
        let dual = run_tuned(&params, &run, seed, true);
        assert!(
            dual.load_settle_error_inc <= 2.0,
            "seed {seed}: dual loop settle {} load inc",
            dual.load_settle_error_inc
        );
        assert!(dual.load_settle_time_s.is_some(), "seed {seed}: a settle time ({dual:?})");
        assert!(
            dual.load_following_error_peak_inc <= 387.0 * 1.2,
            "seed {seed}: peak {}",
            dual.load_following_error_peak_inc
        );
        assert!(
            dual.motor_load_deviation_peak_deg <= 1.96 * 1.2,
            "seed {seed}: deviation {}",
            dual.motor_load_deviation_peak_deg
        );
        let motor = run_tuned(&params, &run, seed, false);
        let backlash = motor.backlash_inc;
        assert!((backlash - 33.33).abs() < 0.01, "0.3 deg of 40,000 inc/rev");
        let load_inc_per_rad = f64::from(params.load_encoder_counts_per_rev) / core::f64::consts::TAU;
        let twist = params.load_coulomb_friction_nm / params.coupling_stiffness_nm_per_rad * load_inc_per_rad;
        let motor_increment = f64::from(params.load_encoder_counts_per_rev)
            / (params.gear_ratio * f64::from(params.encoder_counts_per_rev));
        let play = backlash + 2.0 * twist + 2.0 * motor_increment + 1.0;
        assert!((play - 46.13).abs() < 0.01, "backlash, twists, the motor's increments, the load's: {play} load inc");
        assert!(
            motor.load_settle_error_inc > 2.0 && motor.load_settle_error_inc <= play,
            "seed {seed}: motor encoder alone misses by {} load inc, the load's play is {play}",
            motor.load_settle_error_inc
        );
    }
}

/// The auto-tuning's main loop (firmware/src/drive/tuning.rs, "Dual loop's main loop"; EPOS4 AN ch. 10.4) against
/// the plant it identified on geared-36v: K_High (0x30AE:02) = 2 pi f_ar / 1.85 with the anti-resonance f_ar the
/// identification measured (0x3205:04), within 0.1 % (the object's rounding); K_Low (0x30AE:01) = 5 K_High
/// (EPOS4 UC1's ratio, Tab. 10-94) and H (0x30AE:03) = 17. Against the hand-set defaults (0x30AE's dictionary
/// values): the defaults schedule down to a third of K_High at a small error, the tuning up to five times it; and
/// the defaults' K_High lies above the anti-resonance's bound w_ar / 1.85, the tuned one on it.
#[test]
fn tuned_main_loop_gains_follow_the_identified_anti_resonance_not_the_defaults() {
    let params = PlantParams::from_toml_file(&geared_preset()).expect("geared preset");
    let run = identify(&params, 1);
    let k_low = f64::from(identified(&run, 0x30AE, 1));
    let k_high = f64::from(identified(&run, 0x30AE, 2));
    let weight = identified(&run, 0x30AE, 3);
    let anti_resonance = f64::from(identified(&run, 0x3205, 4)) * 0.1 * 2.0 * std::f64::consts::PI;
    assert!(anti_resonance > 0.0, "the identification measured the coupling's anti-resonance");
    let bound = anti_resonance / 1.85 * 1e3;
    assert!((k_high - bound).abs() <= bound * 1e-3, "K_High {k_high}, w_ar {anti_resonance} rad/s");
    assert!((k_low - 5.0 * k_high).abs() <= 5.0, "K_Low {k_low} = 5 K_High {k_high}");
    assert_eq!(weight, 17_000);
    let defaults = Drive::new(DriveConfig::DEFAULT);
    let d = defaults.dictionary();
    let (default_low, default_high) =
        (f64::from(d.get(h::DUAL_LOOP_GAIN_LOW)), f64::from(d.get(h::DUAL_LOOP_GAIN_HIGH)));
    assert!(
        default_low < default_high && k_low > k_high,
        "defaults {default_low}/{default_high}, tuned {k_low}/{k_high}"
    );
    assert!(default_high > bound, "the defaults' K_High {default_high} is above w_ar / 1.85 = {bound}");
}

/// A variant of geared-36v written through the plant file's keys (`hal-sim/src/plant/file.rs`): the preset's file
/// with `key = value` in place of the key's line.
fn geared_variant(key: &str, value: &str) -> PlantParams {
    let text = std::fs::read_to_string(geared_preset()).expect("geared preset");
    let mut replaced = false;
    let variant: String = text
        .lines()
        .map(|line| {
            if line.starts_with(&format!("{key} =")) {
                replaced = true;
                format!("{key} = {value}\n")
            } else {
                format!("{line}\n")
            }
        })
        .collect();
    assert!(replaced, "{key} in the preset");
    let path = std::env::temp_dir().join(format!("geared-{key}-{}.toml", std::process::id()));
    std::fs::write(&path, variant).expect("variant written");
    let params = PlantParams::from_toml_file(&path).expect("variant plant");
    let _ = std::fs::remove_file(&path);
    params
}

/// The tuning follows the plant, not the preset: geared-36v with a 7:1 gear (the coupling's resonance and the
/// reflected inertia change with it) and with half the load inertia (the anti-resonance rises by sqrt 2), each
/// identified and auto-tuned on seed 1, settles within +-2 load increments over the end of the 1.5 s hold as the
/// preset does (reached: 2 and 2, the load standing on its friction at the band's edge, within the band from 0.23
/// and 0.18 s after the move).
#[test]
fn tuned_dual_loop_settles_with_another_gear_ratio_or_load_inertia() {
    for (key, value) in [("gear_ratio", "7.0"), ("load_inertia_kg_m2", "0.00375")] {
        let params = geared_variant(key, value);
        let run = identify(&params, 1);
        let dual = run_tuned(&params, &run, 1, true);
        assert!(
            dual.load_settle_error_inc <= 2.0,
            "{key} = {value}: settle {} load inc ({dual:?})",
            dual.load_settle_error_inc
        );
    }
}

/// A plant without a load encoder cannot run the dual loop: the scenario says so instead of running.
#[test]
fn dual_loop_needs_a_plant_with_a_load_encoder() {
    let config = DualLoopConfig::default();
    assert_eq!(dual_loop::dual_loop(PlantParams::reference(), &config).err(), Some(DualLoopError::NoLoadEncoder));
}

/// `drive-sim dual-loop --plant geared-36v.toml` prints the three figures the issue names as `key=value` lines and
/// writes the trace and its SVG plot; on the reference plant (no load encoder) it fails with the reason.
#[test]
fn drive_sim_dual_loop_prints_the_figures_and_writes_the_plot() {
    let drive_sim = drive_tests::real_master::build_drive_sim();
    let out = std::env::temp_dir().join(format!("dual-loop-{}", std::process::id()));
    let run = Command::new(&drive_sim)
        .args(["dual-loop", "--plant"])
        .arg(geared_preset())
        .arg("--out")
        .arg(&out)
        .output()
        .expect("drive-sim runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "drive-sim dual-loop failed: {stdout}{}", String::from_utf8_lossy(&run.stderr));
    let figures = drive_tests::real_master::figures(&stdout);
    for key in ["load_following_error_peak_inc", "load_settle_error_inc", "motor_load_deviation_peak_deg"] {
        let value = figures.get(key).unwrap_or_else(|| panic!("{key} missing: {stdout}"));
        let x: f64 = value.parse().unwrap_or_else(|e| panic!("{key}={value}: {e}"));
        assert!(x.is_finite() && x >= 0.0, "{key}={value}");
    }
    let svg = std::fs::read_to_string(Path::new(&out).join("dual-loop.svg")).expect("the plot");
    assert!(svg.starts_with("<svg") || svg.starts_with("<?xml"), "an SVG");
    assert!(svg.contains("load following error"), "the plot shows the load's following error");
    let _ = std::fs::remove_dir_all(&out);
    let refused =
        Command::new(&drive_sim).args(["dual-loop", "--out"]).arg(std::env::temp_dir()).output().expect("runs");
    assert!(!refused.status.success(), "the reference plant has no load encoder");
    assert!(String::from_utf8_lossy(&refused.stderr).contains("no load encoder"));
}
