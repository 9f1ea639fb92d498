//! The fault matrix (issue 5): every fault of the table injected on the reference plant where it matters, with its
//! code (0x603F), error register (0x1001), history entry (0x1003), EMCY, the state its reaction class leads to,
//! the stop performed, the time from the detection to the outputs off (at most one PWM period for class "d"),
//! and the reset rules (refused while a level cause persists, accepted after). `hal_sim::scenarios::faults` holds the
//! cases and the checks; `drive-sim fault-matrix` prints the same table.

use firmware::fault::{FaultId, ReactionClass, FAULT_COUNT};
use hal_sim::scenarios::faults::{cases, matrix_table, run_case};

/// The identification's faults that no physical failure of the reference plant produces: 0xFF12 (the bus
/// cannot drive the test current through the winding: no motor the drive supports), 0xFF15 (the mechanical step's
/// samples give no physical plant), 0xFF19 (the procedure's 20 s timeout), 0xFF22 (above the maximum speed during
/// the identification's slow movements). Their detection is tested in the firmware's unit tests
/// (`drive::identification`: 0xFF12, 0xFF19 and the mapping of 0xFF22; `drive::mechanical_identification`: 0xFF15,
/// 0xFF19, 0xFF22). The SSI absolute encoder's errors (0x738C, 0x738D, 0x7390, 0x7391) need a plant with an SSI
/// sensor and the drive configured for it (0x3000:01 = 0x300), which the matrix's reference setups are not: they are
/// injected on the SSI plant in `tests/tests/drive/ssi.rs` (stuck clock, flipped bit, no sensor, unreadable format)
/// and by `drive-sim ssi`.
const NOT_INJECTED: [FaultId; 8] = [
    FaultId::AutoTuningCurrentLimit,
    FaultId::AutoTuningSampleMismatch,
    FaultId::AutoTuningTimeout,
    FaultId::AutoTuningMaxSpeed,
    FaultId::SsiSensor,
    FaultId::SsiFrame,
    FaultId::MissingMainSensor,
    FaultId::MissingCommutationSensor,
];

#[test]
fn every_fault_of_the_table_has_a_case() {
    let covered: Vec<FaultId> = cases().iter().map(|c| c.fault).collect();
    for id in FaultId::ALL.into_iter().filter(|id| !NOT_INJECTED.contains(id)) {
        assert!(covered.contains(&id), "no matrix case for {id:?}");
    }
    // One case per fault, and the STO discrepancy once per input (EPOS4 AN ch. 9: two channels).
    assert_eq!(covered.len(), FAULT_COUNT - NOT_INJECTED.len() + 1, "one case per fault, two for the STO discrepancy");
    assert_eq!(covered.iter().filter(|&&id| id == FaultId::StoDiscrepancy).count(), 2);
}

#[test]
fn every_injected_fault_is_detected_reported_reacted_to_and_reset() {
    let outcomes: Vec<_> = cases().iter().map(|c| run_case(c, 1)).collect();
    println!("{}", matrix_table(&outcomes));
    let failed: Vec<String> =
        outcomes.iter().filter(|o| !o.passed()).map(|o| format!("{:?}: {}", o.fault, o.failures.join("; "))).collect();
    assert!(failed.is_empty(), "failed cases:\n{}", failed.join("\n"));
    // The table in the docs is the one the cases produce now (regenerate it with `drive-sim fault-matrix`).
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/fault-matrix.md")).expect("docs");
    assert!(
        doc.contains(&matrix_table(&outcomes)),
        "docs/fault-matrix.md is out of date: run `cargo run --release -p hal-sim --bin drive-sim -- fault-matrix` \
         and copy out/fault-matrix/fault-matrix.md into it"
    );
    // Class "d": the outputs are off within one PWM period of the detection.
    for o in outcomes.iter().filter(|o| o.reaction == ReactionClass::DisablePowerImmediately) {
        if let Some(p) = o.off_after_detect_periods {
            assert!(p <= 1, "{:?}: outputs off {p} periods after the detection", o.fault);
        }
    }
}
