//! Runs the project's conformance suites (issue 21, item 3) and prints every case and each suite's summary line,
//! `canopen_cases=N passed=P failed=F skipped=S` and `ecat_cases=...`. Exits 1 when a case failed.
//!
//! `cargo run --release -p drive-tests --bin conformance`

use std::process::ExitCode;

fn main() -> ExitCode {
    let reports = [drive_tests::conformance::canopen::run(), drive_tests::conformance::ethercat::run()];
    let mut failed = 0;
    for report in &reports {
        print!("{}", report.render());
        failed += report.failed();
    }
    if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
