//! The conformance suites in CI (issue 21, item 3): every case of each suite passes, and every skip says why.
//! The cases, their clauses and expected answers are in `drive_tests::conformance`.

use drive_tests::conformance::{self, Verdict};

/// Proves: the drive answers every case of the CANopen suite (CiA 301 groups: EDS/OD, SDO, NMT, heartbeat, SYNC,
/// EMCY, PDO, store/restore) as the clause named by the case prescribes.
#[test]
fn canopen_conformance_suite_passes_every_case() {
    let report = conformance::canopen::run();
    println!("{}", report.render());
    assert!(report.total() >= 40, "the suite has its cases: {}", report.summary());
    assert!(
        report.cases.iter().all(|c| !matches!(c.verdict, Verdict::Skipped(why) if why.trim().is_empty())),
        "every skip names why"
    );
    assert_eq!(report.failed(), 0, "{}", report.render());
}

/// Proves: the drive answers every case of the EtherCAT suite (ESM transitions and AL status codes, the watchdog
/// and its recovery, mailbox counter/repeat/errors, CoE SDO, SDO information, complete access, emergencies, the
/// SII and ESI against the device, 0x1C32/0x1C33, 0x6502) as the clause named by the case prescribes.
#[test]
fn ethercat_conformance_suite_passes_every_case() {
    let report = conformance::ethercat::run();
    println!("{}", report.render());
    assert!(report.total() >= 25, "the suite has its cases: {}", report.summary());
    assert!(
        report.cases.iter().all(|c| !matches!(c.verdict, Verdict::Skipped(why) if why.trim().is_empty())),
        "every skip names why"
    );
    assert_eq!(report.failed(), 0, "{}", report.render());
}
