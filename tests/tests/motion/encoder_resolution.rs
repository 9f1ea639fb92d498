//! Motion on encoders whose resolution is not a power of two (issue 18 item 2): a CSV velocity step and homing on
//! the index, on the reference plant with its encoder replaced (`PlantParams::encoder_counts_per_rev`; the drive's
//! 0x3010:01 follows through `Simulation::new`, and 0x3000:05, the unit of every rpm and rpm/s object, from it).

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::homing::{self, HomingConfig};
use hal_sim::scenarios::motion;

const SEED: u64 = 1;

fn plant(counts_per_rev: u32) -> PlantParams {
    PlantParams { encoder_counts_per_rev: counts_per_rev, ..PlantParams::reference() }
}

/// CSV on a 1,250-line encoder (5,000 counts/rev): the 100 rpm step meets the reference bounds of
/// `cyclic::csv_small_step` (at most 10 % overshoot, within 2 % in the steady state, settled within 200 ms). With
/// 0x3000:05 left at 4,096 the drive would run 100 rpm of 4,096 counts, 82 rpm of this shaft (18 % error), and
/// its loop gains (SI units over 0x3000:05) would be 18 % off.
#[test]
fn csv_step_on_a_5000_count_encoder() {
    let (f, _) = motion::csv_step_on(plant(5_000), SEED, 100.0).expect("scenario runs");
    assert!(f.overshoot_pct <= 10.0, "{f:?}");
    assert!(f.steady_error_pct <= 2.0, "{f:?}");
    assert!(f.settle_ms.is_finite() && f.settle_ms < 200.0, "settles within 2 %: {f:?}");
    println!("5,000 counts/rev: {f:?}");
}

/// Homing on the index at 2,000, 4,000, 5,000 and 10,000 counts/rev: method 34 (index, positive), 33 (index,
/// negative) and 1 (negative limit switch, then the index) land on the plant's index state, which lies at a
/// multiple of the counts per revolution that does not divide 2^16. Tolerance as the reference matrix
/// (`homing.rs`): the home error within +-1 increment (the index is latched by the counter: 0 expected), the
/// statusword bits 13/12/10/15 = 0/1/1/1, and the drive followed every count (encoder drift 0).
#[test]
fn index_homing_lands_on_the_index_at_every_resolution() {
    for cpr in [2_000, 4_000, 5_000, 10_000] {
        for method in [34, 33, 1] {
            let start = homing::starts(method)[0];
            let cfg = HomingConfig { counts_per_rev: cpr, ..HomingConfig::new(SEED, method, start) };
            let r = homing::homing_run_with(&cfg).expect("runs");
            assert!(r.passed(), "cpr {cpr} method {method}: {r:?}");
            assert_eq!(r.home_error_inc, 0, "cpr {cpr} method {method}: on the index state: {r:?}");
            assert_eq!(r.geometry.reference.rem_euclid(i64::from(cpr)), 0, "the reference is an index: {r:?}");
            assert_eq!(r.encoder_drift_inc, 0, "cpr {cpr} method {method}: {r:?}");
            println!("cpr {cpr} method {method}: attained in {:.3} s, home error 0", r.homing_s);
        }
    }
}
