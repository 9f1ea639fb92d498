//! drive-tool over EtherCAT (`--ecat IFACE`) against `drive-sim ethercat` (issue 22 item 1, "What it must show"):
//! each test runs in a private network namespace made with `unshare -Urn` (as the real-master tests do,
//! `drive_tests::real_master`): a veth pair `ecm0`/`ecs0`, the simulator on `ecs0`, and the built `drive-tool` on
//! `ecm0`, one command after the other as a user would type them; each command's output, error text and exit
//! status are kept for the checks.
//!
//! The simulator runs in lock-step with `--idle-cycle`: simulated time advances one 1 ms cycle per cyclic frame
//! (the tool sends none: it exchanges no process data) and per idle poll of the simulator, so the drive's state
//! machine and a move over SDO make progress between the tool's mailbox exchanges; every verdict is an object value
//! or a code, not a time, so the load of the machine changes only the wall time.
//!
//! When the machine cannot make a network namespace the tests fail under `CI=true` and are reported skips
//! elsewhere (`drive_tests::prerequisite`).

mod common;
use common::csv_rows;

use std::path::Path;
use std::process::Command;

use drive_tests::can_master::WorkDir;
use drive_tests::prerequisite;
use drive_tests::real_master::{build_drive_sim, cannot_make_namespace, one_run_at_a_time, root};
use firmware::fault::table::FaultId;
use serde_json::Value;

/// What one drive-tool command printed and how it ended.
#[derive(Debug)]
struct Step {
    ok: bool,
    out: String,
    err: String,
}

impl Step {
    /// The JSON it printed; panics with its text when it failed or printed none.
    fn json(&self) -> Value {
        assert!(self.ok, "the command failed:\n{}{}", self.out, self.err);
        serde_json::from_str(&self.out).unwrap_or_else(|e| panic!("no JSON ({e}):\n{}{}", self.out, self.err))
    }
}

/// One `'...'`-quoted shell word.
fn quoted(word: &str) -> String {
    format!("'{}'", word.replace('\'', r"'\''"))
}

/// Runs `drive-tool --ecat ecm0 <step>` for each of `steps` in turn against `drive-sim ethercat --iface ecs0
/// --lock-step --idle-cycle <sim_args>` in a fresh namespace; `None` (after printing why) when the machine cannot
/// make one. The wall time of the whole session is printed.
fn session(name: &str, sim_args: &[&str], steps: &[Vec<String>]) -> Option<Vec<Step>> {
    if prerequisite::skip(&format!("drive-tool ethercat {name}"), cannot_make_namespace()) {
        return None;
    }
    let drive_sim = build_drive_sim();
    let _one = one_run_at_a_time();
    let dir = WorkDir::new(&format!("drive-tool-ecat-{name}"));
    let tool = env!("CARGO_BIN_EXE_drive-tool");
    let mut script = format!(
        "set -u
ip link set lo up
ip link add ecm0 type veth peer name ecs0
ip link set ecm0 up
ip link set ecs0 up
timeout 300 {sim} ethercat --iface ecs0 --lock-step --idle-cycle {sim_args} --seconds 280 > {log} 2>&1 &
SIM=$!
sleep 0.3
",
        sim = quoted(&drive_sim.display().to_string()),
        sim_args = sim_args.iter().map(|a| quoted(a)).collect::<Vec<_>>().join(" "),
        log = quoted(&dir.join("sim.log").display().to_string()),
    );
    for (k, step) in steps.iter().enumerate() {
        let at = |ext: &str| quoted(&dir.join(&format!("{k}.{ext}")).display().to_string());
        if let [pause, seconds] = step.as_slice() {
            if pause == PAUSE {
                script.push_str(&format!("sleep {}; echo 0 > {}\n", quoted(seconds), at("rc")));
                continue;
            }
        }
        let args = step.iter().map(|a| quoted(a)).collect::<Vec<_>>().join(" ");
        script.push_str(&format!(
            "timeout 120 {} --ecat ecm0 {args} > {} 2> {}; echo $? > {}\n",
            quoted(tool),
            at("out"),
            at("err"),
            at("rc")
        ));
    }
    script.push_str("kill $SIM 2>/dev/null\nwait $SIM\n");
    let started = std::time::Instant::now();
    let run = Command::new("unshare").args(["-Urn", "sh", "-c", &script]).output().expect("run unshare");
    eprintln!("{name}: {} commands in {:.2} s wall time", steps.len(), started.elapsed().as_secs_f64());
    let read = |file: &Path| std::fs::read_to_string(file).unwrap_or_default();
    let sim_log = read(&dir.join("sim.log"));
    let outcome: Vec<Step> = (0..steps.len())
        .map(|k| Step {
            ok: read(&dir.join(&format!("{k}.rc"))).trim() == "0",
            out: read(&dir.join(&format!("{k}.out"))),
            err: read(&dir.join(&format!("{k}.err"))),
        })
        .collect();
    for (step, result) in steps.iter().zip(&outcome) {
        eprintln!("$ drive-tool --ecat ecm0 {}\n{}{}", step.join(" "), result.out, result.err);
    }
    assert!(
        outcome.iter().any(|s| s.ok),
        "no command succeeded; namespace: {}\ndrive-sim:\n{sim_log}",
        String::from_utf8_lossy(&run.stderr)
    );
    Some(outcome)
}

/// A step that runs no command but lets the simulator idle for the seconds that follow it: in lock-step with
/// `--idle-cycle`, simulated time passes one cycle per idle poll, and a command that polls the mailbox without a
/// pause of a millisecond leaves it none (on a real drive time passes on its own).
const PAUSE: &str = "#pause";

fn args(words: &[&str]) -> Vec<String> {
    words.iter().map(|w| (*w).to_owned()).collect()
}

/// The device description the drive's dictionary is generated from.
fn device() -> od_gen::model::Device {
    od_gen::load(&root().join("firmware/device.toml")).expect("firmware/device.toml is valid").device
}

/// Proves (ETG.1000.6 §6.4 AL states, CiA 301 §7.5.2.24 identity; issue 22 "scan finds the drives"): `scan --json`
/// lists exactly one drive, at position 1 with station address 0x1000, in PRE-OP, with vendor ID, product code,
/// revision, device type, device name and software version as firmware/device.toml declares them and the CiA 402
/// state «Switch on disabled»; `info --station 0x1000` addresses the same drive; position 2 does not exist and is
/// named in the error; a write of the read-only statusword shows the drive's CoE abort 0x06010002 with its
/// CiA 301 text; `nmt start` (OP) is refused with the reason (no process data) rather than pretended; `get
/// --complete` of the identity 0x1018 and the PDO assignment 0x1C12 (one CoE complete access each, ETG.1000.6
/// §5.6.2.1.2) gives the values that sub-index by sub-index uploads give.
#[test]
fn ecat_scan_finds_the_drive_with_the_identity_of_device_toml() {
    let Some(steps) = session(
        "scan",
        &[],
        &[
            args(&["scan", "--json"]),
            args(&["info", "--station", "0x1000", "--json"]),
            args(&["get", "0x6041", "--node", "2"]),
            args(&["set", "0x6041", "1"]),
            args(&["nmt", "start"]),
            args(&["get", "--complete", "--json", "0x1018", "0x1C12"]),
            args(&["get", "--json", "0x1018", "0x1C12"]),
        ],
    ) else {
        return;
    };
    let d = device();
    let found = steps[0].json();
    let list = found.as_array().expect("a JSON list");
    assert_eq!(list.len(), 1, "{found}");
    let drive = &list[0];
    assert_eq!(drive["node"], 1, "{drive}");
    assert_eq!(drive["station"], 0x1000, "{drive}");
    assert_eq!(drive["al_state"], "PRE-OP", "{drive}");
    assert_eq!(drive["vendor_id"], u64::from(d.vendor_id), "{drive}");
    assert_eq!(drive["product_code"], u64::from(d.product_code), "{drive}");
    assert_eq!(drive["revision"], u64::from(d.revision), "{drive}");
    assert_eq!(drive["device_type"], u64::from(d.device_type), "{drive}");
    assert_eq!(drive["device_name"], d.device_name.as_str(), "{drive}");
    assert_eq!(drive["software_version"], d.software_version.as_str(), "{drive}");
    assert_eq!(drive["cia402"], "Switch on disabled", "{drive}");
    let info = steps[1].json();
    assert_eq!(info["node"], 1, "{info}");
    assert_eq!(info["vendor_id"], u64::from(d.vendor_id), "{info}");
    assert_eq!(info["error_code"], 0, "{info}");
    assert!(!steps[2].ok && steps[2].err.contains("no drive at position 2"), "{:?}", steps[2]);
    assert!(!steps[3].ok, "{:?}", steps[3]);
    assert!(
        steps[3].err.contains("SDO abort 0x06010002: Attempt to write a read only object"),
        "the abort's code and text: {}",
        steps[3].err
    );
    assert!(!steps[4].ok && steps[4].err.contains("process data"), "{:?}", steps[4]);
    let complete = steps[5].json();
    assert_eq!(complete, steps[6].json(), "complete access and single uploads agree");
    assert_eq!(complete.as_array().map(Vec::len), Some(5 + 5), "0x1018:00..04 and 0x1C12:00..04: {complete}");
}

/// Proves (CiA 306 DCF over CoE; issue 22 "params save, change three parameters, params load restores them"):
/// after `params save`, three parameters changed with `set` (following error window 0x6065, profile velocity
/// 0x6081, profile acceleration 0x6083) are exactly the three changes `params load` lists, old -> new, and read back
/// with the saved values afterwards; a second load changes nothing.
#[test]
fn ecat_params_load_restores_exactly_the_three_changed_parameters() {
    let dir = WorkDir::new("drive-tool-ecat-params-file");
    let dcf = dir.join("drive.dcf").display().to_string();
    let objects = ["0x6065", "0x6081", "0x6083"];
    let mut plan = vec![args(&["get", "--json", objects[0], objects[1], objects[2]])];
    plan.push(args(&["params", "save", &dcf]));
    for (object, value) in [("0x6065", "555"), ("0x6081", "1234"), ("0x6083", "4321")] {
        plan.push(args(&["set", object, value]));
    }
    plan.push(args(&["params", "load", &dcf, "--json"]));
    plan.push(args(&["get", "--json", objects[0], objects[1], objects[2]]));
    plan.push(args(&["params", "load", &dcf, "--json"]));
    let Some(steps) = session("params", &[], &plan) else { return };
    let values =
        |v: Value| -> Vec<Value> { v.as_array().expect("a list").iter().map(|o| o["value"].clone()).collect() };
    let before = values(steps[0].json());
    assert!(steps[1].ok, "{:?}", steps[1]);
    assert!(steps[2..5].iter().all(|s| s.ok), "{:?}", &steps[2..5]);
    let load = steps[5].json();
    let changes = load["changes"].as_array().expect("changes");
    let addresses: Vec<&str> = changes.iter().map(|c| c["address"].as_str().expect("address")).collect();
    assert_eq!(addresses, ["0x6065:00", "0x6081:00", "0x6083:00"], "{load}");
    assert!(changes[0]["old"].as_str().expect("old").starts_with("555 "), "{load}");
    assert!(changes[0]["new"].as_str().expect("new").starts_with(&format!("{} ", before[0])), "{load}");
    assert_eq!(values(steps[6].json()), before);
    let again = steps[7].json();
    assert_eq!(again["changes"].as_array().map(Vec::len), Some(0), "{again}");
}

/// A signed image of 16 KiB payload, version `version` (text `text`), signed with `seed` (the simulated drive
/// trusts the development key, `hal_sim::sim::update::dev_seed`).
fn image_file(dir: &WorkDir, name: &str, version: u32, text: &str, seed: &[u8; 32]) -> String {
    use hal_sim::sim::update::{payload, signed_image};
    let image = signed_image(&payload(16 * 1024, version), version, text, firmware::boot::image::HARDWARE_ID, seed);
    let file = dir.join(name);
    std::fs::write(&file, image).expect("write the image");
    file.display().to_string()
}

/// Proves (issue 22 "update installs a new signed image and the version reads back"; E4 Table 4-29 FoE in BOOT):
/// `update IMAGE --json --ecat` takes the drive through INIT and BOOT, writes the image signed with the
/// development key by FoE, leaves BOOT and finds the restarted drive in PRE-OP: it runs the image's version
/// "0.2.0" in 0x100A (the factory image before), 0x1F56:01 holds the new application id with the bootloader's, the
/// program runs (0x1F51:01 = 1) and the flash status is 0; a later `get 0x100A` agrees.
#[test]
fn ecat_update_by_foe_installs_a_signed_image_and_the_new_version_reads_back() {
    use hal_sim::sim::update::{dev_seed, FACTORY_VERSION};
    let dir = WorkDir::new("drive-tool-ecat-update-file");
    let version = 0x0002_0000;
    let file = image_file(&dir, "new.img", version, "0.2.0", &dev_seed());
    let Some(steps) = session("update", &[], &[args(&["update", &file, "--json"]), args(&["get", "0x100A", "--json"])])
    else {
        return;
    };
    let report = steps[0].json();
    let bootloader = u64::from(firmware::boot::program::BOOTLOADER_ID);
    assert_eq!(report["method"], "FoE", "{report}");
    assert_eq!(report["version_after"], "0.2.0", "{report}");
    assert_eq!(report["image_version"], "0.2.0", "{report}");
    assert_eq!(report["software_id_before"], u64::from(FACTORY_VERSION & 0xFFFF_0000) | bootloader, "{report}");
    assert_eq!(report["software_id_after"], u64::from(version & 0xFFFF_0000) | bootloader, "{report}");
    assert_eq!(report["program_state"], 1, "{report}");
    assert_eq!(report["flash_status"], "flash status 0 (no error)", "{report}");
    assert_ne!(report["version_before"], report["version_after"], "{report}");
    assert_eq!(steps[1].json()[0]["value"], "0.2.0", "the drive answers with its new firmware");
}

/// Proves (ETG.1000.5 FoE error request: code and text; IDX Table 7-155; `firmware::boot::program` refusals): an
/// image signed with another key is refused at the end of its FoE write with FoE error 0x8009 and the drive's text
/// "signature invalid", both in the tool's message with flash status 93, and the drive keeps running its
/// firmware (0x100A as before, back in PRE-OP).
#[test]
fn ecat_a_forged_image_is_refused_by_foe_with_the_code_and_the_reason_and_the_drive_runs_on() {
    let dir = WorkDir::new("drive-tool-ecat-forged-file");
    let file = image_file(&dir, "forged.img", 0x0003_0000, "0.3.0", &[7u8; 32]);
    let plan = [args(&["get", "0x100A", "--json"]), args(&["update", &file]), args(&["scan", "--json"])];
    let Some(steps) = session("forged", &[], &plan) else { return };
    let before = steps[0].json()[0]["value"].clone();
    assert!(!steps[1].ok, "a forged image is refused: {:?}", steps[1]);
    assert!(steps[1].err.contains("FoE error 0x8009 (not bootstrap): signature invalid"), "{}", steps[1].err);
    assert!(steps[1].err.contains("flash status 93 (signature invalid)"), "{}", steps[1].err);
    let after = steps[2].json();
    assert_eq!(after[0]["software_version"], before, "the old firmware runs on: {after}");
    assert_eq!(after[0]["al_state"], "PRE-OP", "{after}");
}

/// Proves (CiA 301 §7.5.2.5 error history, CiA 402 fault reset, over CoE; issue 22 "faults after an injected fault
/// shows its code and text"): a following error provoked over SDO (window 0x6065 = 1 increment, timeout 0x6066 =
/// 0, then a move) stops the move with the fault's code and name; `faults` shows 0x603F and the newest 0x1003
/// entry as the fault table's code and name of FollowingError with its error register bits, statusword bit 3
/// (fault) set; `fault
/// reset` leaves «Switch on disabled» with 0x603F = 0.
#[test]
fn ecat_faults_show_the_code_and_text_of_a_following_error_and_fault_reset_clears_it() {
    let plan = [
        args(&["set", "0x6065", "1"]),
        args(&["set", "0x6066", "0"]),
        args(&["move", "40000", "--timeout-s", "60"]),
        args(&["faults", "--json"]),
        args(&["fault", "reset", "--json"]),
    ];
    let Some(steps) = session("faults", &[], &plan) else { return };
    let fault = FaultId::FollowingError.info();
    assert!(steps[0].ok && steps[1].ok, "{:?}", &steps[..2]);
    assert!(!steps[2].ok, "the move must stop at the fault: {:?}", steps[2]);
    assert!(steps[2].err.contains(&format!("0x{:04X} {}", fault.code, fault.name)), "{}", steps[2].err);
    let faults = steps[3].json();
    assert_eq!(faults["error_code"], fault.code, "{faults}");
    assert_eq!(faults["error_code_text"], fault.name, "{faults}");
    assert_eq!(faults["history"][0]["code"], fault.code, "{faults}");
    assert_eq!(faults["history"][0]["text"], fault.name, "{faults}");
    assert_eq!(faults["history"][0]["register"], fault.register, "{faults}");
    // Simulated time runs only while the simulator idles, so `faults` may come before the quick stop of the fault
    // reaction ended: «Fault reaction active» or «Fault», statusword bit 3 (fault) either way (CiA 402-2 §6.2).
    assert_eq!(faults["statusword"].as_u64().expect("statusword") & 0x0008, 0x0008, "{faults}");
    assert!(matches!(faults["cia402"].as_str(), Some("Fault" | "Fault reaction active")), "{faults}");
    let reset = steps[4].json();
    assert_eq!(reset["cia402"], "Switch on disabled", "{reset}");
    assert_eq!(reset["error_code"], 0, "{reset}");
}

/// Proves issue 22's "`record` of a current step writes a CSV and an SVG whose trace matches the simulator's own
/// within 1 %" over EtherCAT (the recording uploaded by CoE segmented transfer, ETG.1000.6 §5.6.2): in CST
/// (0x6060 = 10, no interpolation 0x60C2:01 = 0) `record --no-wait` arms the data recorder (q current and its
/// reference at 25 kHz, 200 samples, 20 before the trigger: the reference rising through 100 mA); ten reads of its
/// state (each lets simulated time pass: `--idle-cycle`) show it waiting, 0x6071 = 600 makes the step, half a
/// second of idle lets the recording complete, and `record --fetch` uploads it into the CSV and the SVG.
///
/// The reference is `drive-sim ethercat --trace`, the simulator's own values every current-loop period, outside
/// the recorder's path. The recording's sample 20 is the trace's first period with the reference at 100 mA or
/// above (the trigger), and every sample matches the trace period for period: the reference exactly, the q current
/// within 1 % of the step (the same value rounded to the same mA, so a shift by one period or a lost sample would
/// show as the step's slope, far above 1 %).
#[test]
fn ecat_record_of_a_current_step_matches_the_simulators_own_trace() {
    let files = WorkDir::new("drive-tool-ecat-record-files");
    let (trace, csv, svg) = (files.join("trace.csv"), files.join("step.csv"), files.join("step.svg"));
    let path = |p: &Path| p.to_str().expect("utf-8").to_owned();
    let mut steps = vec![
        args(&["set", "0x60C2:01", "0"]),
        args(&["set", "0x6071", "0"]),
        args(&["set", "0x6060", "10"]),
        args(&["enable"]),
        args(&[
            "record",
            "--channel",
            "iq",
            "--channel",
            "iq_ref",
            "--samples",
            "200",
            "--pre",
            "20",
            "--trigger",
            "rising",
            "--trigger-channel",
            "2",
            "--level",
            "100",
            "--no-wait",
            "--json",
        ]),
    ];
    steps.extend((0..10).map(|_| args(&["get", "0x3300:02", "--json"])));
    steps.push(args(&["set", "0x6071", "600"]));
    // At least 7.2 ms of simulated time for the 180 samples after the trigger: `record --fetch` polls the
    // recorder's state through the mailbox and leaves the simulator few idle polls.
    steps.push(args(&[PAUSE, "0.5"]));
    steps.push(vec![
        "record".into(),
        "--fetch".into(),
        "--csv".into(),
        path(&csv),
        "--svg".into(),
        path(&svg),
        "--json".into(),
    ]);
    steps.push(args(&["disable"]));
    let Some(out) = session("record", &["--trace", &path(&trace)], &steps) else {
        return;
    };
    assert_eq!(out[4].json()["armed"], true, "{:?}", out[4]);
    for waiting in &out[5..15] {
        assert_eq!(waiting.json()[0]["value"], 1, "0x3300:02 = 1 waiting for the trigger: {waiting:?}");
    }
    let fetched = out[17].json();
    assert_eq!(fetched["samples"], 200, "{fetched}");
    assert_eq!(fetched["channels"][0]["name"], "iq", "{fetched}");

    let (header, recorded) = csv_rows(&csv);
    assert_eq!(header, "time_s,iq_mA,iq_ref_mA");
    assert_eq!(recorded.len(), 200);
    assert!((recorded[1][0] - 40e-6).abs() < 1e-9, "25 kHz: {:?}", &recorded[..2]);
    let svg_text = std::fs::read_to_string(&svg).expect("the SVG");
    assert!(svg_text.starts_with("<svg") && svg_text.matches("<polyline").count() >= 2, "two panels with a trace");

    let (_, own) = csv_rows(&trace);
    let trigger = own.iter().position(|r| r[2] >= 100.0).expect("the simulator saw the reference step");
    assert!(trigger >= 20, "20 periods before the step in the trace");
    let window = &own[trigger - 20..trigger + 180];
    let step_ma = window.iter().map(|t| t[2]).fold(0.0, f64::max);
    assert!(step_ma > 1_000.0, "a step of {step_ma} mA");
    let mut worst = 0.0f64;
    for (k, (r, t)) in recorded.iter().zip(window).enumerate() {
        assert_eq!(r[2], t[2], "sample {k}: reference {} mA recorded, {} mA in the simulator", r[2], t[2]);
        worst = worst.max((r[1] - t[1]).abs());
    }
    eprintln!("recorded against the simulator's own trace: worst {worst} mA of a {step_ma} mA step");
    assert!(worst <= 0.01 * step_ma, "recorded q current off the simulator's by {worst} mA (1 % of {step_ma})");
}
