//! The project's own conformance suites (issue 21, item 3), modelled on the groups of the CiA and ETG test
//! tools: each case names the clause it checks and the exact answer expected, runs on a fresh device, and ends
//! passed, failed (with what was seen instead) or skipped (with why a device of this kind need not support it).
//!
//! `cargo run -p drive-tests --bin conformance` prints every case and the summary line of each suite
//! (`canopen_cases=N passed=P failed=F skipped=S`, `ecat_cases=...`); `tests/tests/conformance.rs` runs the suites in CI and
//! fails on any failed case.

/// `case!(id, clause, expect, check)`: one [`Case`] of a suite's table.
macro_rules! case {
    ($id:literal, $clause:literal, $expect:literal, $run:ident) => {
        $crate::conformance::Case { id: $id, clause: $clause, expect: $expect, run: $run }
    };
}

pub mod canopen;
pub mod eds;
pub mod ethercat;

use std::panic::{catch_unwind, AssertUnwindSafe};

/// A case's result: `Err` says what was seen instead of the expected answer.
pub type Outcome = Result<(), String>;

/// One conformance case on a device of type `R`.
pub struct Case<R> {
    /// Short identifier, group and number (`SDO-05`).
    pub id: &'static str,
    /// The clause checked (`CiA 301 §7.2.4.3.17 Table 22`).
    pub clause: &'static str,
    /// The exact answer expected, as a person reads it.
    pub expect: &'static str,
    /// The check, on a fresh device.
    pub run: fn(&mut R) -> Outcome,
}

/// A case the suite does not run, and why.
pub struct Skip {
    /// Identifier, as a case's.
    pub id: &'static str,
    /// The clause the tool would check.
    pub clause: &'static str,
    /// Why a device of this kind need not support it.
    pub why: &'static str,
}

/// How one case ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// The device answered as expected.
    Passed,
    /// What the device did instead (or the panic message of a check that could not go on).
    Failed(String),
    /// Not run, and why.
    Skipped(&'static str),
}

/// One line of a suite's report.
#[derive(Debug, Clone)]
pub struct CaseReport {
    /// The case's identifier.
    pub id: &'static str,
    /// The clause checked.
    pub clause: &'static str,
    /// The expected answer.
    pub expect: &'static str,
    /// How it ended.
    pub verdict: Verdict,
}

/// A suite's cases and their verdicts.
#[derive(Debug, Clone)]
pub struct SuiteReport {
    /// The suite's key in the summary line (`canopen`).
    pub name: &'static str,
    /// Every case, run or skipped, in the suite's order.
    pub cases: Vec<CaseReport>,
}

impl SuiteReport {
    /// Cases run or skipped.
    #[must_use]
    pub fn total(&self) -> usize {
        self.cases.len()
    }

    /// Cases with the given verdict kind.
    fn count(&self, f: impl Fn(&Verdict) -> bool) -> usize {
        self.cases.iter().filter(|c| f(&c.verdict)).count()
    }

    /// Cases passed.
    #[must_use]
    pub fn passed(&self) -> usize {
        self.count(|v| matches!(v, Verdict::Passed))
    }

    /// Cases failed.
    #[must_use]
    pub fn failed(&self) -> usize {
        self.count(|v| matches!(v, Verdict::Failed(_)))
    }

    /// Cases skipped.
    #[must_use]
    pub fn skipped(&self) -> usize {
        self.count(|v| matches!(v, Verdict::Skipped(_)))
    }

    /// The summary line: `<name>_cases=N passed=P failed=F skipped=S`.
    #[must_use]
    pub fn summary(&self) -> String {
        format!(
            "{}_cases={} passed={} failed={} skipped={}",
            self.name,
            self.total(),
            self.passed(),
            self.failed(),
            self.skipped()
        )
    }

    /// Every case as one line (`pass`, `FAIL` or `skip`, identifier, clause, expected answer, and what was seen
    /// or why skipped), then the summary line.
    #[must_use]
    pub fn render(&self) -> String {
        let mut out = String::new();
        for c in &self.cases {
            let (tag, extra) = match &c.verdict {
                Verdict::Passed => ("pass", String::new()),
                Verdict::Failed(seen) => ("FAIL", format!("\n        seen: {seen}")),
                Verdict::Skipped(why) => ("skip", format!("\n        why: {why}")),
            };
            out.push_str(&format!("{tag}  {:<8} {}: {}{extra}\n", c.id, c.clause, c.expect));
        }
        out.push_str(&self.summary());
        out.push('\n');
        out
    }
}

/// Runs every case on a device of its own from `fresh`, then lists the skips.
///
/// A check that panics (a device answering so far off that the check cannot go on) fails its case; the suite goes
/// on with the next.
pub fn run_suite<R>(name: &'static str, cases: &[Case<R>], skips: &[Skip], fresh: impl Fn() -> R) -> SuiteReport {
    let mut reports = Vec::with_capacity(cases.len() + skips.len());
    for case in cases {
        let verdict = match catch_unwind(AssertUnwindSafe(|| {
            let mut device = fresh();
            (case.run)(&mut device)
        })) {
            Ok(Ok(())) => Verdict::Passed,
            Ok(Err(seen)) => Verdict::Failed(seen),
            Err(panic) => Verdict::Failed(format!(
                "the check stopped: {}",
                panic
                    .downcast_ref::<String>()
                    .map(String::as_str)
                    .or_else(|| panic.downcast_ref::<&str>().copied())
                    .unwrap_or("(no message)")
            )),
        };
        reports.push(CaseReport { id: case.id, clause: case.clause, expect: case.expect, verdict });
    }
    for s in skips {
        reports.push(CaseReport { id: s.id, clause: s.clause, expect: "not run", verdict: Verdict::Skipped(s.why) });
    }
    SuiteReport { name, cases: reports }
}

/// `Ok` when `seen == expected`, else what was seen against what was expected, with `what`.
///
/// # Errors
/// The mismatch, as text.
pub fn expect_eq<T: PartialEq + std::fmt::Debug>(what: &str, seen: T, expected: T) -> Outcome {
    if seen == expected {
        Ok(())
    } else {
        Err(format!("{what}: {seen:?}, expected {expected:?}"))
    }
}

/// `Ok` when `condition` holds, else `what`.
///
/// # Errors
/// `what`, when the condition does not hold.
pub fn expect_that(condition: bool, what: impl FnOnce() -> String) -> Outcome {
    if condition {
        Ok(())
    } else {
        Err(what())
    }
}
