//! Signal traces: named columns of `f64` samples, written as CSV.

use std::fmt::Write as _;
use std::io;
use std::path::Path;

/// A table of samples: one row per recorded instant, one column per named signal.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trace {
    columns: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Trace {
    /// An empty trace with these column names (the first is usually the time).
    pub fn new(columns: &[&str]) -> Self {
        Self { columns: columns.iter().map(|c| (*c).to_owned()).collect(), rows: Vec::new() }
    }

    /// Appends one row; missing values are NaN, extra values are dropped.
    pub fn push(&mut self, row: &[f64]) {
        let mut r: Vec<f64> = row.iter().copied().take(self.columns.len()).collect();
        r.resize(self.columns.len(), f64::NAN);
        self.rows.push(r);
    }

    /// Column names.
    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// No rows recorded.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// All values of the column called `name` (`None` if there is no such column).
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let k = self.columns.iter().position(|c| c == name)?;
        Some(self.rows.iter().map(|r| r.get(k).copied().unwrap_or(f64::NAN)).collect())
    }

    /// The trace as CSV text: a header line, then one line per row (full `f64` precision, shortest form).
    pub fn to_csv(&self) -> String {
        let mut s = self.columns.join(",");
        s.push('\n');
        for row in &self.rows {
            for (k, v) in row.iter().enumerate() {
                if k > 0 {
                    s.push(',');
                }
                let _ = write!(s, "{v}");
            }
            s.push('\n');
        }
        s
    }

    /// Writes [`Trace::to_csv`] to `path`, creating its directory.
    pub fn write_csv(&self, path: &Path) -> io::Result<()> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(path, self.to_csv())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_layout() {
        let mut t = Trace::new(&["t", "x"]);
        t.push(&[0.0, 1.5]);
        t.push(&[1.0]);
        assert_eq!(t.to_csv(), "t,x\n0,1.5\n1,NaN\n");
        assert_eq!(t.column("x").map(|c| c.len()), Some(2));
        assert!(t.column("y").is_none());
    }
}
