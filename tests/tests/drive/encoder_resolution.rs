//! Encoder resolutions that are not powers of two (issue 18 item 2): 500, 1,000, 1,250 and 2,500-line encoders
//! (2,000, 4,000, 5,000 and 10,000 counts per revolution) beside the reference 1,024 lines (4,096 counts). The
//! plant counts any resolution into a 16-bit counter that wraps at 2^16, not at a revolution, with the index at
//! every multiple of the counts per revolution (`hal_sim::plant::sensors`); the drive is configured through
//! 0x3010:01 (`Simulation::new` writes the plant's lines there) and derives 0x3000:05 from it.

use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::{handles as h, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::store::{ParamStore, SAVE_SIGNATURE};
use firmware::power_state::CommutationStage;
use hal_sim::flash::SimFlash;
use hal_sim::plant::{Mechanics, PlantParams};
use hal_sim::scenarios::angle_error_deg;
use hal_sim::sim::Simulation;

/// The common non-power-of-two resolutions and the reference one, counts per revolution.
const RESOLUTIONS: [u32; 5] = [2_000, 4_000, 4_096, 5_000, 10_000];
/// Pole pairs of the reference motor.
const POLE_PAIRS: i64 = 7;

const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};

fn plant(counts_per_rev: u32) -> PlantParams {
    PlantParams { encoder_counts_per_rev: counts_per_rev, ..PlantParams::reference() }
}

fn rad_per_s(rpm: f64) -> f64 {
    rpm / 60.0 * 2.0 * core::f64::consts::PI
}

/// 0x3010:01 takes any line count of its range, 0x3000:05 (read-only) follows as 4 x lines at once and from the
/// stored value at boot; a line count out of range is refused with the precise abort (CiA 301 §7.2.4.3.17:
/// 0x0609_0032 below 16, 0x0609_0031 above 2,500,000) and changes nothing, and 0x3000:05 itself refuses a write
/// (0x0601_0002, read-only). With the Halls as the only position sensor it is 6 x pole pairs instead.
#[test]
fn main_sensor_resolution_follows_the_encoder_lines() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut drive = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    assert_eq!(drive.dictionary().get(h::MAIN_SENSOR_RESOLUTION), 4096, "reference 1,024 lines");
    for lines in [500_u32, 1_000, 1_250, 2_500, 16, 2_500_000, 1_024] {
        drive.sdo_write(0x3010, 1, &lines.to_le_bytes(), PRE_OP, &mut store).expect("in range");
        assert_eq!(drive.dictionary().get(h::MAIN_SENSOR_RESOLUTION), 4 * lines, "{lines} lines");
    }
    drive.sdo_write(0x3010, 1, &1_250_u32.to_le_bytes(), PRE_OP, &mut store).expect("1,250 lines");
    assert_eq!(drive.sdo_write(0x3010, 1, &15_u32.to_le_bytes(), PRE_OP, &mut store), Err(SdoAbort::ValueTooLow));
    assert_eq!(
        drive.sdo_write(0x3010, 1, &2_500_001_u32.to_le_bytes(), PRE_OP, &mut store),
        Err(SdoAbort::ValueTooHigh)
    );
    assert_eq!(drive.sdo_write(0x3000, 5, &4096_u32.to_le_bytes(), PRE_OP, &mut store), Err(SdoAbort::ReadOnly));
    assert_eq!(drive.dictionary().get(h::ENCODER_PULSES), 1_250, "refused writes change nothing");
    assert_eq!(drive.dictionary().get(h::MAIN_SENSOR_RESOLUTION), 5_000);
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let rebooted = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    assert_eq!(rebooted.dictionary().get(h::MAIN_SENSOR_RESOLUTION), 5_000, "derived from the stored lines at boot");
    // Without the encoder (0x3000:01 sensor 1 type 0, read-only: set as a configuration would) the Halls count:
    // 6 x 7 pole pairs = 42 increments per revolution, whatever 0x3010:01 holds.
    drive.dictionary_mut().set(h::SENSORS_CONFIGURATION, 0x0004_0000);
    drive.sdo_write(0x3010, 1, &2_500_u32.to_le_bytes(), PRE_OP, &mut store).expect("2,500 lines");
    assert_eq!(drive.dictionary().get(h::MAIN_SENSOR_RESOLUTION), 42, "Hall increments per revolution");
}

/// Position over many revolutions both ways, exact: the shaft is driven (ideal dynamometer, power stage off: the
/// encoder is tracked in every state) 20 revolutions forward at 3,000 rpm, 35 back at 2,000 rpm, and stopped.
/// The 16-bit counter wraps many times (up to 550,000 counts at 10,000 counts/rev) at a resolution that does not
/// divide 2^16. Tolerance 0 counts: the drive's position moved exactly as the plant's count (net -15 revolutions
/// plus the start's fraction), its electrical count is exactly position x pole pairs modulo the counts per
/// revolution, and every index latch lies exactly one revolution from the previous one (+cpr forward, -cpr back)
/// at the plant's index count.
#[test]
fn position_and_index_are_exact_over_many_revolutions_both_ways() {
    for cpr in RESOLUTIONS {
        let mut sim = Simulation::new(plant(cpr), 3, DriveConfig::DEFAULT);
        sim.plant.set_rotor_state(1.0, 0.0);
        sim.run(5);
        let encoder = |s: &Simulation| *s.tier1().commutation().encoder();
        let start_position = i64::from(encoder(&sim).position());
        let start_count = sim.plant.true_encoder_count();
        let mut latches: Vec<(i64, i64)> = Vec::new();
        let mut last_latch = sim.tier1().latches().index;
        for (rpm, revolutions) in [(3_000.0, 20.0), (-2_000.0, 35.0)] {
            sim.plant.set_mechanics(Mechanics::Driven { speed_rad_s: rad_per_s(rpm) });
            let periods = (revolutions / (f64::abs(rpm) / 60.0) * 25_000.0).round() as u64;
            for _ in 0..periods {
                sim.step();
                let latch = sim.tier1().latches().index;
                if latch.count != last_latch.count {
                    last_latch = latch;
                    // The drive's position of the latch in plant counts: the index state entered.
                    let at = i64::from(latch.position) - start_position + start_count;
                    latches.push((at, rpm.signum() as i64));
                }
            }
        }
        sim.plant.set_mechanics(Mechanics::Locked);
        sim.run(3);
        let enc = encoder(&sim);
        let moved = i64::from(enc.position()) - start_position;
        let true_moved = sim.plant.true_encoder_count() - start_count;
        assert_eq!(moved, true_moved, "cpr {cpr}: position moved exactly as the shaft");
        // 10,000 periods at 3,000 rpm and 26,250 at 2,000 rpm: exactly 15 turns net, at rest on the start angle.
        assert_eq!(moved, -15 * i64::from(cpr), "cpr {cpr}: true revolutions x counts per revolution");
        let electrical = (i64::from(enc.position()) * POLE_PAIRS).rem_euclid(i64::from(cpr));
        assert_eq!(i64::from(enc.electrical_count()), electrical, "cpr {cpr}: electrical count");
        // 20 index pulses forward (one per revolution), 35 back; the turn-around passes the last one again.
        assert!(latches.len() >= 54, "cpr {cpr}: {} index latches", latches.len());
        for &(at, _) in &latches {
            assert_eq!(at.rem_euclid(i64::from(cpr)), 0, "cpr {cpr}: index latched at count {at}");
        }
        for w in latches.windows(2) {
            let (step, dir) = (w[1].0 - w[0].0, w[1].1);
            if dir == w[0].1 {
                assert_eq!(step, dir * i64::from(cpr), "cpr {cpr}: index latches one revolution apart");
            } else {
                assert!(step == 0 || step == dir * i64::from(cpr), "cpr {cpr}: turn-around {step}");
            }
        }
        println!("cpr {cpr}: moved {moved} counts, {} index latches", latches.len());
    }
}

/// Commutation with a Hall start and the index (learned offset), as the reference test
/// `commutation::hall_start_edge_and_index_refinement` checks it on 4,096 counts: within +-30.5 degrees at the
/// start, 3 degrees after the first Hall edge, and once indexed within one count of electrical angle (the
/// quantisation: 360 x 7 / cpr degrees, 0.62 at 4,096, 1.26 at 2,000) plus the 0.38 degrees the reference test
/// allows for the learned offset (1.0 degree at 4,096 as there). Measured errors are printed.
#[test]
fn hall_start_then_index_alignment_at_every_resolution() {
    for cpr in RESOLUTIONS {
        let count_deg = 360.0 * POLE_PAIRS as f64 / f64::from(cpr);
        let indexed_tolerance = count_deg + 0.38;
        for start in [0.3, 2.5, 4.0] {
            let mut sim = Simulation::new(plant(cpr), 7, DriveConfig::DEFAULT);
            sim.plant.set_rotor_state(start, 0.0);
            sim.run(5);
            sim.switch_on().expect("calibrated");
            sim.enable().expect("enabled");
            sim.set_q_reference(0.5);
            sim.step();
            assert_eq!(sim.tier1().commutation().stage(), CommutationStage::HallSector);
            assert!(angle_error_deg(&sim).abs() <= 30.5, "cpr {cpr} start {start}: {}", angle_error_deg(&sim));
            sim.run_until(25_000, |s| s.tier1().commutation().stage() != CommutationStage::HallSector).expect("edge");
            let edge = angle_error_deg(&sim);
            assert!(edge.abs() <= 3.0, "cpr {cpr} start {start}: after the edge {edge}");
            sim.run_until(25_000, |s| s.tier1().commutation().stage() == CommutationStage::Indexed).expect("index");
            let mut worst: f64 = 0.0;
            for _ in 0..500 {
                sim.step();
                worst = worst.max(angle_error_deg(&sim).abs());
            }
            assert!(worst <= indexed_tolerance, "cpr {cpr} start {start}: indexed {worst} > {indexed_tolerance}");
            println!(
                "cpr {cpr} start {start}: edge {edge:.2}, indexed worst {worst:.3} (tolerance {indexed_tolerance:.2})"
            );
        }
    }
}

/// The velocity estimate at a constant speed (shaft driven, power stage off) in the units of 0x3000:05: 0x606C
/// within 2 rpm of the speed, 0x6069 (inc/s) within one rpm's worth (cpr / 60 inc/s) of it, as the 4,096-count
/// test `cyclic::velocity_sensor_and_averaged_velocity_are_the_estimate` allows. Means over the last 100 slow
/// ticks of 0.3 s (the estimate ripples by a count per slow tick), at 600 and -1,500 rpm.
#[test]
fn velocity_estimate_at_constant_speed_at_every_resolution() {
    for cpr in RESOLUTIONS {
        for rpm in [600.0, -1_500.0] {
            let mut sim = Simulation::new(plant(cpr), 5, DriveConfig::DEFAULT);
            sim.plant.set_rotor_state(1.0, 0.0);
            sim.plant.set_mechanics(Mechanics::Driven { speed_rad_s: rad_per_s(rpm) });
            let (mut rpm_sum, mut inc_per_s_sum, mut n) = (0_i64, 0_i64, 0_i64);
            for period in 0..7_500u32 {
                sim.step();
                if period >= 6_500 && period % 10 == 0 {
                    let d = sim.drive.dictionary();
                    rpm_sum += i64::from(d.get(h::VELOCITY_ACTUAL_VALUE));
                    inc_per_s_sum += i64::from(d.get(h::VELOCITY_SENSOR_ACTUAL_VALUE));
                    n += 1;
                }
            }
            let mean_rpm = rpm_sum as f64 / n as f64;
            let mean_inc_per_s = inc_per_s_sum as f64 / n as f64;
            let want_inc_per_s = rpm * f64::from(cpr) / 60.0;
            assert!((mean_rpm - rpm).abs() <= 2.0, "cpr {cpr}: 0x606C mean {mean_rpm} at {rpm} rpm");
            assert!(
                (mean_inc_per_s - want_inc_per_s).abs() <= f64::from(cpr) / 60.0,
                "cpr {cpr}: 0x6069 mean {mean_inc_per_s}, expected {want_inc_per_s}"
            );
            println!("cpr {cpr} {rpm} rpm: 0x606C mean {mean_rpm:.2} rpm, 0x6069 mean {mean_inc_per_s:.0} inc/s");
        }
    }
}
