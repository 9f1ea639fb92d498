//! Tests that need something outside the project (a Python package, user and network namespaces): what they do
//! when the machine lacks it (issue 15).
//!
//! `scripts/setup.sh` installs every prerequisite, so a missing one is a broken set-up, not a reason to pass:
//! under `CI=true` (set by CI) the test fails with a message naming what is missing. Outside CI a developer may
//! run the suite without them: the test is skipped, says so on stderr, and is recorded in the skip report
//! ([`skip_report_path`]) that `scripts/test-all.sh` prints after the test summary, so that no skip goes unseen.

use std::io::Write as _;
use std::path::PathBuf;
use std::process::Command;

/// What a test does about a prerequisite.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Everything is there: run.
    Run,
    /// Missing, outside CI: skip and report the reason.
    Skip(String),
    /// Missing under CI: fail with this message.
    Fail(String),
}

/// The decision for the test `test`, given what is missing (`None`: nothing) and whether this is a CI run.
pub fn verdict(test: &str, missing: Option<String>, ci: bool) -> Verdict {
    match missing {
        None => Verdict::Run,
        Some(why) if ci => Verdict::Fail(format!(
            "{test}: a prerequisite is missing under CI=true, where every test must run: {why} \
             (scripts/setup.sh installs it)"
        )),
        Some(why) => Verdict::Skip(why),
    }
}

/// Why python3 cannot run `import <modules>` (`modules` as Python writes them, e.g. `"canopen, can"`), if it
/// cannot: the last line of Python's error (the exception, not the traceback above it), naming `package` as what
/// `scripts/setup.sh` installs from tests/python/requirements.txt.
pub fn python_cannot_import(modules: &str, package: &str) -> Option<String> {
    match Command::new("python3").args(["-c", &format!("import {modules}")]).output() {
        Ok(o) if o.status.success() => None,
        Ok(o) => Some(format!(
            "python3 cannot import {package} (scripts/setup.sh installs tests/python/requirements.txt): {}",
            String::from_utf8_lossy(&o.stderr).trim().lines().last().unwrap_or_default()
        )),
        Err(e) => Some(format!("cannot run python3 ({e}); run scripts/setup.sh")),
    }
}

/// Whether this is a CI run: `CI` set to anything but empty, `false` or `0` (CI sets `CI=true`).
pub fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "false" | "0"))
}

/// The skip report: one line per skipped test, `<test>: <why>`, in the workspace's target directory
/// (`CARGO_TARGET_DIR` when set). `scripts/test-all.sh` clears it before the tests and prints it after them.
pub fn skip_report_path() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| crate::real_master::root().join("target"))
        .join("skipped-tests.txt")
}

/// Whether the test `test` must stop here because `missing` names an absent prerequisite: `false` when nothing is
/// missing; under CI a panic naming it; elsewhere `true` after printing `SKIPPED` and recording it in the skip
/// report.
#[must_use]
pub fn skip(test: &str, missing: Option<String>) -> bool {
    match verdict(test, missing, in_ci()) {
        Verdict::Run => false,
        Verdict::Fail(message) => panic!("{message}"),
        Verdict::Skip(why) => {
            // One line per skip in the report, whatever the reason's text.
            let why = why.lines().map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join(" | ");
            eprintln!("SKIPPED {test}: {why}");
            let path = skip_report_path();
            // Several test binaries append at once; one write per line keeps the lines whole.
            let appended = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .and_then(|mut file| file.write_all(format!("{test}: {why}\n").as_bytes()));
            if let Err(e) = appended {
                eprintln!("cannot record the skip in {}: {e}", path.display());
            }
            true
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_prerequisite_fails_under_ci_naming_it() {
        let why = "python3 cannot import pysoem".to_owned();
        match verdict("soem_csp", Some(why), true) {
            Verdict::Fail(message) => {
                assert!(message.contains("soem_csp"), "{message}");
                assert!(message.contains("pysoem"), "{message}");
                assert!(message.contains("CI=true"), "{message}");
            }
            other => panic!("expected a failure, got {other:?}"),
        }
    }

    #[test]
    fn a_missing_prerequisite_outside_ci_is_a_reported_skip() {
        assert_eq!(verdict("t", Some("no namespaces".into()), false), Verdict::Skip("no namespaces".into()));
    }

    #[test]
    fn nothing_missing_runs_in_and_outside_ci() {
        assert_eq!(verdict("t", None, true), Verdict::Run);
        assert_eq!(verdict("t", None, false), Verdict::Run);
    }
}
