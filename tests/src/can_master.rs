//! Running PyPI `canopen` (python-can's socketcand interface) against `drive-sim canopen` (issue 8, "What it must
//! show"): the pieces the CANopen real-master tests share. No network namespace: the simulator serves socketcand
//! on 127.0.0.1 (shared/spec/fieldbus-real-masters.md, "socketcand protocol as python-can speaks it").
//!
//! [`run`] starts `drive-sim canopen --port 0 <sim_args>` as a child, reads the port it prints first, runs
//! `python3 tests/canopen/<script> --port P --eds <generated EDS> <args>`, waits for the simulator to leave on its
//! own (`--idle-exit-ms` after the client left) or kills it at a time limit, and returns both sides' `key=value`
//! figures ([`RunOutput`], as for EtherCAT).

use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::real_master::{build_drive_sim, figures, root, RunOutput};

/// Longest a script may run before it is killed (the test then fails with what was printed).
pub const SCRIPT_LIMIT: Duration = Duration::from_secs(120);

/// How long drive-sim waits without a client frame before it reports and exits (longer than any pause of the
/// scripts: canopen's SDO timeout of 0.3 s twice, the 0.5 s of the reset burst).
pub const IDLE_EXIT_MS: u64 = 2_000;

/// Why the machine cannot run the tests, if it cannot: python3 or PyPI canopen missing (scripts/setup.sh
/// installs tests/python/requirements.txt).
pub fn cannot_run() -> Option<String> {
    crate::prerequisite::python_cannot_import("canopen, can", "canopen")
}

/// A temporary directory for one test's files (EDS, expectations, set-points), removed on drop.
#[derive(Debug)]
pub struct WorkDir(pub PathBuf);

impl WorkDir {
    /// `<tmp>/canopen-real-master-<pid>-<name>`, created.
    pub fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("canopen-real-master-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        Self(dir)
    }

    /// A path inside.
    pub fn join(&self, file: &str) -> PathBuf {
        self.0.join(file)
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Writes the EDS od-gen generates from firmware/device.toml (as tests/tests/eds_canopen.rs does) into `dir`.
pub fn write_eds(dir: &WorkDir) -> PathBuf {
    let description = od_gen::load(&root().join("firmware/device.toml")).expect("firmware/device.toml is valid");
    let path = dir.join("drive.eds");
    std::fs::write(&path, od_gen::eds::eds(&description)).expect("write the EDS");
    path
}

/// Kills the child if it is still running when dropped (a failed assertion must not leave it behind).
struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Runs `tests/canopen/<script> --port P --eds <eds> <script_args>` against `drive-sim canopen --port 0
/// <sim_args> --idle-exit-ms 2000 --seconds 150`; both sides' figures (the master's with `master_rc`).
pub fn run(script: &str, sim_args: &[&str], eds: &std::path::Path, script_args: &[String]) -> RunOutput {
    let drive_sim = build_drive_sim();
    // One run at a time: a master and a simulator per test, all at once, overload a 2-core CI host (and the
    // bad-frame test runs in real time).
    let _one_at_a_time = crate::real_master::one_run_at_a_time();
    let mut child = Command::new(&drive_sim)
        .arg("canopen")
        .args(["--port", "0", "--seconds", "150", "--idle-exit-ms", &IDLE_EXIT_MS.to_string()])
        .args(sim_args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start drive-sim canopen");
    let mut sim_out = BufReader::new(child.stdout.take().expect("drive-sim stdout"));
    let mut sim_err = child.stderr.take().expect("drive-sim stderr");
    let guard = ChildGuard(child);
    // The first line is `port=N` (hal-sim drive-sim canopen).
    let mut first = String::new();
    sim_out.read_line(&mut first).expect("read drive-sim's first line");
    let port = first
        .trim()
        .strip_prefix("port=")
        .unwrap_or_else(|| panic!("drive-sim printed {first:?} first, not port=N"))
        .to_owned();
    let mut master = Command::new("python3")
        .arg(root().join("tests/canopen").join(script))
        .args(["--port", &port, "--eds"])
        .arg(eds)
        .args(script_args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run python3");
    let mut m_out = master.stdout.take().expect("python stdout");
    let mut m_err = master.stderr.take().expect("python stderr");
    let reader = std::thread::spawn(move || {
        let (mut o, mut e) = (String::new(), String::new());
        let _ = m_out.read_to_string(&mut o);
        let _ = m_err.read_to_string(&mut e);
        (o, e)
    });
    let started = Instant::now();
    let status = loop {
        if let Some(s) = master.try_wait().expect("wait for python") {
            break Some(s);
        }
        if started.elapsed() > SCRIPT_LIMIT {
            let _ = master.kill();
            let _ = master.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let (m_stdout, m_stderr) = reader.join().expect("python output");
    // drive-sim leaves IDLE_EXIT_MS after the last client frame; give it a few seconds, then kill it.
    let mut guard = guard;
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline && matches!(guard.0.try_wait(), Ok(None)) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let sim_rc = match guard.0.try_wait() {
        Ok(Some(s)) => s.code().map_or("signal".to_owned(), |c| c.to_string()),
        _ => "killed".to_owned(),
    };
    drop(guard);
    let mut s_stdout = first.clone();
    let _ = sim_out.read_to_string(&mut s_stdout);
    let mut s_stderr = String::new();
    let _ = sim_err.read_to_string(&mut s_stderr);
    let mut master_figures = figures(&m_stdout);
    let master_rc = match status {
        Some(s) => s.code().map_or("signal".to_owned(), |c| c.to_string()),
        None => "timeout".to_owned(),
    };
    master_figures.insert("master_rc".into(), master_rc);
    master_figures.insert("sim_rc".into(), sim_rc);
    let text = format!(
        "--- {script}\n{m_stdout}{m_stderr}\n--- drive-sim canopen {}\n{s_stdout}{s_stderr}",
        sim_args.join(" ")
    );
    RunOutput { master: master_figures, sim: figures(&s_stdout), text }
}
