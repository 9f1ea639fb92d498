//! Running a real EtherCAT master against `drive-sim ethercat` (issue 6, "What it must show"): the pieces the
//! real-master tests share, whatever the master (SOEM through PyPI `pysoem`, ethercrab).
//!
//! Each run happens inside a private network namespace made with `unshare -Urn` (no root needed, nothing left
//! behind: shared/spec/fieldbus-real-masters.md, "What works here"): loopback up, a veth pair `ecm0`/`ecs0`, the
//! simulator on `ecs0` in the background, the master on `ecm0`, every step bounded in time. Both sides print
//! `key=value` lines; [`run_in_namespace`] returns them as two maps.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use firmware::od::access::{Dictionary, NoApplicationObjects};

/// The workspace root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

/// Why this machine cannot make a private network namespace, if it cannot (`unshare -Urn true` fails).
pub fn cannot_make_namespace() -> Option<String> {
    match Command::new("unshare").args(["-Urn", "true"]).output() {
        Ok(o) if o.status.success() => None,
        Ok(o) => Some(format!(
            "`unshare -Urn true` failed ({}): no user/network namespaces here",
            String::from_utf8_lossy(&o.stderr).trim()
        )),
        Err(e) => Some(format!("cannot run unshare: {e}")),
    }
}

/// Why the machine cannot run a SOEM (PyPI pysoem) test, if it cannot: no namespaces, or python3 cannot import
/// pysoem although `scripts/setup.sh` installs it.
pub fn cannot_run_soem() -> Option<String> {
    if let Some(why) = cannot_make_namespace() {
        return Some(why);
    }
    crate::prerequisite::python_cannot_import("pysoem", "pysoem")
}

/// Builds a binary or example target of the workspace in the dev profile (the artifacts `cargo test` already
/// built) and returns the path of its executable. `target` is cargo's selection, e.g.
/// `["-p", "hal-sim", "--bin", "drive-sim"]`; `name` is the executable's name.
pub fn build_executable(target: &[&str], name: &str) -> PathBuf {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(root())
        .arg("build")
        .args(target)
        .arg("--message-format=json-render-diagnostics")
        .output()
        .expect("run cargo build");
    assert!(out.status.success(), "cargo build {target:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    // One JSON message per line; the artifact line of the target names its executable.
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout
        .lines()
        .find(|l| l.contains("\"reason\":\"compiler-artifact\"") && l.contains("\"executable\":\"") && l.contains(name))
        .unwrap_or_else(|| panic!("cargo reported no executable for {name}"));
    let start = line.find("\"executable\":\"").expect("executable field") + "\"executable\":\"".len();
    let end = line[start..].find('"').expect("end of the path") + start;
    PathBuf::from(&line[start..end])
}

/// Builds `drive-sim` and returns its path.
pub fn build_drive_sim() -> PathBuf {
    build_executable(&["-p", "hal-sim", "--bin", "drive-sim"], "drive-sim")
}

/// `key=value` lines of `text` (the last value wins).
pub fn figures(text: &str) -> HashMap<String, String> {
    text.lines().filter_map(|l| l.split_once('=')).map(|(k, v)| (k.trim().to_owned(), v.trim().to_owned())).collect()
}

/// The shell script run inside the namespace: lo up, the veth pair, the simulator on ecs0 in the background
/// (after `sim_prefix`, e.g. a `chrt`),
/// the master command on ecm0 (its own arguments after `--iface ecm0`), then the simulator's exit report after a
/// `--- drive-sim` marker.
fn namespace_script(
    drive_sim: &Path,
    sim_log: &Path,
    sim_args: &str,
    master_command: &str,
    sim_prefix: &str,
) -> String {
    format!(
        "set -u
ip link set lo up
ip link add ecm0 type veth peer name ecs0
ip link set ecm0 up
ip link set ecs0 up
timeout 300 {sim_prefix}'{sim}' ethercat --iface ecs0 {sim_args} --seconds 280 --idle-exit-ms 1500 > '{log}' 2>&1 &
SIM=$!
sleep 0.3
timeout 250 {master_command}
echo master_rc=$?
wait $SIM
echo sim_rc=$?
echo '--- drive-sim'
cat '{log}'
",
        sim = drive_sim.display(),
        log = sim_log.display(),
    )
}

/// Serialises real-master runs within one test binary: the tests of a file run on parallel threads, and a
/// master plus a simulator per test, all at once, overload a 2-core CI host (a master then waits past its
/// receive timeout). Held for the whole run; a test that panicked while holding it does not block the others.
pub fn one_run_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static RUNS: std::sync::Mutex<()> = std::sync::Mutex::new(());
    RUNS.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// What one run printed: the master's figures (with `master_rc` and `sim_rc`), the simulator's figures, and the
/// whole text for failure messages.
#[derive(Debug)]
pub struct RunOutput {
    /// The master's `key=value` lines, `master_rc` (its exit status) and `sim_rc` (drive-sim's).
    pub master: HashMap<String, String>,
    /// drive-sim's `key=value` lines.
    pub sim: HashMap<String, String>,
    /// Everything printed, for failure messages.
    pub text: String,
}

impl RunOutput {
    /// The master's figure `key`; panics with the whole output when it is missing.
    pub fn master(&self, key: &str) -> &str {
        self.master.get(key).unwrap_or_else(|| panic!("no `{key}` from the master:\n{}", self.text))
    }

    /// drive-sim's figure `key`; panics with the whole output when it is missing.
    pub fn sim(&self, key: &str) -> &str {
        self.sim.get(key).unwrap_or_else(|| panic!("no `{key}` from drive-sim:\n{}", self.text))
    }

    /// The master's figure `key` as a number.
    pub fn master_num(&self, key: &str) -> f64 {
        self.master(key).parse().unwrap_or_else(|e| panic!("master `{key}`: {e}\n{}", self.text))
    }

    /// drive-sim's figure `key` as a number.
    pub fn sim_num(&self, key: &str) -> f64 {
        self.sim(key).parse().unwrap_or_else(|e| panic!("drive-sim `{key}`: {e}\n{}", self.text))
    }
}

/// Runs `master_command` (a shell command line; the script appends nothing, so it must name `--iface ecm0`
/// itself) against `drive-sim ethercat --iface ecs0 <sim_args>` in a fresh namespace. `name` keeps the temporary
/// directories of tests that run at the same time (same process) apart.
pub fn run_in_namespace(name: &str, sim_args: &str, master_command: &str) -> RunOutput {
    run_in_namespace_with(&build_drive_sim(), name, sim_args, master_command)
}

/// [`run_in_namespace`] with the `drive-sim` executable at `drive_sim` (e.g. a release build for a real-time
/// measurement).
pub fn run_in_namespace_with(drive_sim: &Path, name: &str, sim_args: &str, master_command: &str) -> RunOutput {
    run_in_namespace_at(drive_sim, name, sim_args, master_command, None)
}

/// The real-time priorities (SCHED_FIFO) of a real-time measurement: the master's threads above the simulator's
/// frame path, whose drive workers step one below it (`hal_sim::sim::host_priority`). A master on a real
/// machine runs its cycle at a real-time priority; at the normal policy both wait behind whatever else the
/// host runs, and the master skips cycles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RealTimePriorities {
    /// The master's (every thread of its process).
    pub master: u8,
    /// drive-sim's frame path (its drive workers run one below).
    pub simulator: u8,
}

impl RealTimePriorities {
    /// Master 30, drive-sim 20 (workers 19): both below 50, the priority of the kernel's threaded interrupt
    /// handlers, so that the network path under them is never starved.
    pub const MEASUREMENT: Self = Self { master: 30, simulator: 20 };

    /// Whether this host lets the tests raise a process to SCHED_FIFO (root or CAP_SYS_NICE; the priority is
    /// set outside the namespace, where the privilege counts, and inherited inside it).
    pub fn permitted() -> bool {
        Command::new("chrt").args(["-f", "1", "true"]).output().is_ok_and(|o| o.status.success())
    }
}

/// [`run_in_namespace_with`] with the master at `priorities.master` and drive-sim at `priorities.simulator`
/// (SCHED_FIFO; the caller checks [`RealTimePriorities::permitted`]).
pub fn run_in_namespace_at_real_time_priority(
    drive_sim: &Path,
    name: &str,
    sim_args: &str,
    master_command: &str,
    priorities: RealTimePriorities,
) -> RunOutput {
    run_in_namespace_at(drive_sim, name, sim_args, master_command, Some(priorities))
}

fn run_in_namespace_at(
    drive_sim: &Path,
    name: &str,
    sim_args: &str,
    master_command: &str,
    priorities: Option<RealTimePriorities>,
) -> RunOutput {
    let _one_at_a_time = one_run_at_a_time();
    let dir = std::env::temp_dir().join(format!("ecat-real-masters-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let sim_log = dir.join("drive-sim.log");
    // Raising the priority needs the host's privilege, so the whole namespace starts at the master's; inside
    // it drive-sim is lowered to its own, which needs none (sched(7)).
    let sim_prefix = priorities.map(|p| format!("chrt -f {} ", p.simulator)).unwrap_or_default();
    let script = namespace_script(drive_sim, &sim_log, sim_args, master_command, &sim_prefix);
    let mut command = match priorities {
        Some(p) => {
            let mut c = Command::new("chrt");
            c.args(["-f", &p.master.to_string(), "unshare"]);
            c
        }
        None => Command::new("unshare"),
    };
    let out = command.args(["-Urn", "sh", "-c", &script]).output().expect("run unshare");
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    let _ = std::fs::remove_dir_all(&dir);
    // The master's lines and both exit statuses come first; the simulator's log after the marker.
    let (master_part, sim_part) = text.split_once("--- drive-sim").unwrap_or((&text, ""));
    RunOutput { master: figures(master_part), sim: figures(sim_part), text: text.clone() }
}

/// A u32 of the default dictionary (shorter entries zero-extended).
pub fn default_u32(d: &Dictionary, index: u16, sub: u8) -> u32 {
    let mut b = [0u8; 4];
    let r = d.read(index, sub, 0, &mut b, &mut NoApplicationObjects).expect("default value");
    u32::from_le_bytes(b) & (u32::MAX >> (32 - 8 * r.total_len.min(4) as u32))
}

/// Bytes of the process image the default assignment `assign` (0x1C12 or 0x1C13) maps.
pub fn default_image_bytes(d: &Dictionary, assign: u16) -> u32 {
    let pdos = default_u32(d, assign, 0);
    let bits: u32 = (1..=pdos)
        .map(|k| default_u32(d, assign, k as u8) as u16)
        .map(|pdo| (1..=default_u32(d, pdo, 0)).map(|k| default_u32(d, pdo, k as u8) & 0xFF).sum::<u32>())
        .sum();
    bits.div_ceil(8)
}
