//! Snapshot comparison shared by the integration tests.

use std::fs;
use std::path::Path;

/// Whether `UPDATE_SNAPSHOTS=1` asks the tests to rewrite their snapshots instead of comparing.
pub fn updating() -> bool {
    std::env::var("UPDATE_SNAPSHOTS").is_ok_and(|v| v == "1")
}

/// Compares `actual` with the snapshot at `path` (or rewrites it when updating). Returns a one-paragraph
/// summary of the difference: sizes, the number of differing lines and the first of them.
pub fn check(path: &Path, actual: &str) -> Result<(), String> {
    if updating() {
        if let Some(dir) = path.parent() {
            fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        if fs::read_to_string(path).ok().as_deref() != Some(actual) {
            fs::write(path, actual).map_err(|e| format!("{}: {e}", path.display()))?;
        }
        return Ok(());
    }
    let Ok(expected) = fs::read_to_string(path) else {
        return Err(format!("{}: missing snapshot ({} bytes generated)", path.display(), actual.len()));
    };
    if expected == actual {
        return Ok(());
    }
    let (old, new): (Vec<&str>, Vec<&str>) = (expected.lines().collect(), actual.lines().collect());
    // The changed region: everything between the longest common prefix and the longest common suffix.
    let prefix = old.iter().zip(&new).take_while(|(a, b)| a == b).count();
    let suffix = old[prefix..].iter().rev().zip(new[prefix..].iter().rev()).take_while(|(a, b)| a == b).count();
    let line = |lines: &[&str], i: usize| lines.get(i).copied().unwrap_or("<end of file>").to_string();
    Err(format!(
        "{}: differs from the generated output ({} -> {} lines); snapshot lines {}..{} became generated lines \
         {}..{}; first difference at line {}:\n  snapshot:  {}\n  generated: {}",
        path.display(),
        old.len(),
        new.len(),
        prefix + 1,
        old.len() - suffix,
        prefix + 1,
        new.len() - suffix,
        prefix + 1,
        line(&old, prefix),
        line(&new, prefix),
    ))
}
