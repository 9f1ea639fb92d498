//! The simulator's own trace of tier 1's q current (`drive-sim canopen --trace FILE`, `drive-sim ethercat --trace
//! FILE`): one CSV line every current-loop period, written as the simulation runs. It is the reference a recording
//! of the drive's data recorder is checked against (`drive-tool record`), so it reads the simulation's state
//! directly: no ring, no drain, no dictionary, no fieldbus.

use std::fs::File;
use std::io::{BufWriter, Write as _};
use std::path::Path;

use super::Simulation;

/// The CSV's header: the period, tier 1's measured q current and its reference (rounded to mA as the recorder
/// rounds them), and the plant's true q current at the sample (mA, one decimal).
pub const HEADER: &str = "period,iq_ma,iq_ref_ma,iq_plant_ma";

/// An open trace file.
#[derive(Debug)]
pub struct CurrentTrace {
    out: BufWriter<File>,
}

impl CurrentTrace {
    /// Creates `path` and writes the header; the error names the file.
    pub fn create(path: &Path) -> Result<Self, String> {
        let file = File::create(path).map_err(|e| format!("--trace {}: {e}", path.display()))?;
        let mut out = BufWriter::new(file);
        writeln!(out, "{HEADER}").map_err(|e| format!("--trace {}: {e}", path.display()))?;
        Ok(Self { out })
    }

    /// The line of the period `sim` has just run; `flush` (every slow tick) leaves the file whole if the simulator
    /// is killed. A write error ends nothing: the trace is a by-product of the run.
    pub fn record(&mut self, sim: &Simulation, flush: bool) {
        let s = sim.tier1().signals();
        let true_ma = sim.plant.state_at_sample().i_dq_a[1] * 1000.0;
        let _ =
            writeln!(self.out, "{},{},{},{true_ma:.1}", sim.ticks(), s.i_dq.q.to_milliamps(), s.i_ref.q.to_milliamps());
        if flush {
            let _ = self.out.flush();
        }
    }
}
