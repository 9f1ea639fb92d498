//! drive-tool against `drive-sim canopen --lock-step` (issue 22 item 1, "What it must show"): the simulated
//! drives answer through socketcand on 127.0.0.1; each test starts its own simulator and runs the built
//! `drive-tool` binary as a user would. Lock-step: simulated time runs only for the tool's frames (each SDO
//! request runs until its answer is out), so the verdicts do not depend on the load of the machine; the
//! timeouts are generous wall-clock bounds only.

mod common;
use common::csv_rows;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

use drive_tests::can_master::WorkDir;
use drive_tests::real_master::{build_drive_sim, one_run_at_a_time, root};
use firmware::fault::table::FaultId;
use serde_json::Value;

/// A running `drive-sim canopen`, killed on drop.
struct Sim {
    child: Child,
    port: String,
}

impl Sim {
    /// `drive-sim canopen --port 0 --lock-step --nodes <nodes>`; its port is the first line it prints.
    fn start(nodes: u8) -> Self {
        Self::start_with(nodes, &[])
    }

    /// [`Sim::start`] with more arguments for drive-sim.
    fn start_with(nodes: u8, more: &[&str]) -> Self {
        let mut child = Command::new(build_drive_sim())
            .args(["canopen", "--port", "0", "--lock-step", "--seconds", "600", "--nodes", &nodes.to_string()])
            .args(more)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start drive-sim canopen");
        let mut first = String::new();
        BufReader::new(child.stdout.as_mut().expect("stdout")).read_line(&mut first).expect("drive-sim's first line");
        let port =
            first.trim().strip_prefix("port=").unwrap_or_else(|| panic!("drive-sim printed {first:?}")).to_owned();
        Self { child, port }
    }

    /// Runs `drive-tool --socketcand 127.0.0.1:<port> <args>`: exit success, stdout, stderr.
    fn tool(&self, args: &[&str]) -> (bool, String, String) {
        let out = Command::new(env!("CARGO_BIN_EXE_drive-tool"))
            .args(["--socketcand", &format!("127.0.0.1:{}", self.port)])
            .args(args)
            .output()
            .expect("run drive-tool");
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    }

    /// `drive-tool ... <args> --json`, which must succeed, parsed.
    fn json(&self, args: &[&str]) -> Value {
        let mut all = args.to_vec();
        all.push("--json");
        let (ok, out, err) = self.tool(&all);
        assert!(ok, "drive-tool {args:?} failed:\n{out}{err}");
        serde_json::from_str(&out).unwrap_or_else(|e| panic!("drive-tool {args:?} printed no JSON ({e}):\n{out}"))
    }

    /// `drive-tool ... <args>`, which must succeed.
    fn ok(&self, args: &[&str]) -> String {
        let (ok, out, err) = self.tool(args);
        assert!(ok, "drive-tool {args:?} failed:\n{out}{err}");
        out
    }

    /// The value of one object as `get --json` gives it.
    fn get(&self, object: &str) -> Value {
        self.json(&["get", object])[0]["value"].clone()
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The device description the drive's dictionary is generated from.
fn device() -> od_gen::model::Device {
    od_gen::load(&root().join("firmware/device.toml")).expect("firmware/device.toml is valid").device
}

/// Proves (CiA 301 §7.5.2.24 identity object; issue 22 "scan finds the drives"): `scan --json` against
/// `--nodes 2` lists exactly node-IDs 1 and 2, each with vendor ID, product code and revision 0x1018:01..03,
/// device type 0x1000, device name 0x1008 and software version 0x100A as firmware/device.toml declares them,
/// and the CiA 402 state «Switch on disabled» of a drive nobody enabled.
#[test]
fn scan_finds_both_drives_with_the_identity_of_device_toml() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(2);
    let d = device();
    let found = sim.json(&["scan"]);
    let list = found.as_array().expect("a JSON list");
    assert_eq!(list.iter().map(|n| n["node"].as_u64().expect("node")).collect::<Vec<_>>(), vec![1, 2], "{found}");
    for drive in list {
        assert_eq!(drive["vendor_id"], u64::from(d.vendor_id), "{drive}");
        assert_eq!(drive["product_code"], u64::from(d.product_code), "{drive}");
        assert_eq!(drive["revision"], u64::from(d.revision), "{drive}");
        assert_eq!(drive["device_type"], u64::from(d.device_type), "{drive}");
        assert_eq!(drive["device_name"], d.device_name.as_str(), "{drive}");
        assert_eq!(drive["software_version"], d.software_version.as_str(), "{drive}");
        assert_eq!(drive["cia402"], "Switch on disabled", "{drive}");
    }
    let info = sim.json(&["info", "--node", "2"]);
    assert_eq!(info["node"], 2);
    assert_eq!(info["vendor_id"], u64::from(d.vendor_id));
    assert_eq!(info["error_code"], 0, "no fault: {info}");
    assert_eq!(info["position"], 0, "a drive that never moved: {info}");
}

/// Proves (issue 7's bootloader fallback seen by a tool): with slot A of node 2 erased (`--no-image 2`), `scan`
/// still lists node 2, by the fallback's identity, with the fallback's device type (0x0000012E, firmware
/// `boot::tables::BOOTLOADER_DEVICE_TYPE`) and no CiA 402 state (the fallback has no 0x6041), next to the
/// application on node 1.
#[test]
fn scan_lists_a_drive_in_its_bootloader_fallback_without_a_cia402_state() {
    let _one = one_run_at_a_time();
    let sim = Sim::start_with(2, &["--no-image", "2"]);
    let found = sim.json(&["scan"]);
    let list = found.as_array().expect("a JSON list");
    assert_eq!(list.len(), 2, "{found}");
    assert_eq!(list[0]["cia402"], "Switch on disabled", "{found}");
    assert_eq!(list[1]["node"], 2, "{found}");
    assert_eq!(list[1]["device_type"], u64::from(firmware::boot::tables::BOOTLOADER_DEVICE_TYPE), "{found}");
    assert_eq!(list[1]["vendor_id"], u64::from(device().vendor_id), "{found}");
    assert!(list[1]["cia402"].is_null(), "{found}");
}

/// Proves (CiA 301 §7.2.4.3: expedited download and upload; §7.2.4.3.17 abort): `set` of the following error
/// window 0x6065 (UNSIGNED32) by name reads back by index; a write of the read-only statusword fails with the
/// drive's abort 0x06010002 and its CiA 301 text; a value out of UNSIGNED16's range for the controlword, a mode
/// of operation 0x6060 outside device.toml's list and a word for an integer are refused by the tool with the
/// reason before it opens the bus; a segmented upload (0x1009, 23 characters) reads the whole string.
#[test]
fn get_and_set_round_trip_and_an_abort_shows_its_code_and_text() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    sim.ok(&["set", "following error window", "777"]);
    assert_eq!(sim.get("0x6065:00"), 777);
    sim.ok(&["set", "0x60FF", "-300"]);
    assert_eq!(sim.get("target velocity"), -300, "INTEGER32 sign");
    let (ok, _, err) = sim.tool(&["set", "0x6041", "5"]);
    assert!(!ok);
    assert!(err.contains("0x06010002") && err.contains("Attempt to write a read only object"), "{err}");
    let (ok, _, err) = sim.tool(&["set", "controlword", "65536"]);
    assert!(!ok);
    assert!(err.contains("0..=65535"), "{err}");
    // Refused before the bus is opened: against a port where nothing listens the answer is still the value's.
    let refused = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_drive-tool"))
            .args(["--socketcand", "127.0.0.1:1"])
            .args(args)
            .output()
            .expect("run drive-tool");
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    assert!(refused(&["set", "0x6040", "70000"]).contains("out of the type's range 0..=65535"));
    assert!(refused(&["set", "0x6060", "2"]).contains("not one of the values the drive accepts"), "device.toml values");
    assert!(refused(&["set", "0x6065", "fast"]).contains("is not an integer"));
    assert!(refused(&["set", "0x6040", "7"]).contains("cannot connect"), "a good value goes to the link");
    assert_eq!(sim.get("0x1009"), device().hardware_version.as_str(), "segmented upload");
}

/// Proves (CiA 301 §7.2.4.3.9..16, block transfers with CRC; the drive's server checks the CRC and aborts
/// 0x05040004 on a mismatch): `--sdo-block` writes 0x6065 by block download and reads it back by block upload,
/// and reads the 23-character 0x1009 whole; the DCF `params save --sdo-block` writes is the one the
/// expedited/segmented transfers write.
#[test]
fn block_transfers_write_and_read_what_the_other_transfers_do() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    sim.ok(&["--sdo-block", "set", "0x6065", "98765"]);
    assert_eq!(sim.json(&["--sdo-block", "get", "0x6065"])[0]["value"], 98765);
    assert_eq!(sim.get("0x6065"), 98765, "read by an expedited upload");
    assert_eq!(sim.json(&["--sdo-block", "get", "0x1009"])[0]["value"], device().hardware_version.as_str());
    let dir = WorkDir::new("drive-tool-block");
    let (block, plain) = (dir.join("block.dcf"), dir.join("plain.dcf"));
    sim.ok(&["--sdo-block", "params", "save", block.to_str().expect("utf-8")]);
    sim.ok(&["params", "save", plain.to_str().expect("utf-8")]);
    let values = |p: &std::path::Path| -> Vec<String> {
        std::fs::read_to_string(p)
            .expect("DCF")
            .lines()
            .filter(|l| l.starts_with("ParameterValue="))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(values(&block), values(&plain));
    assert!(values(&block).len() > 100, "the parameters are there");
}

/// Proves (CiA 306 DCF; issue 22 "params save, change three parameters, params load restores them"): after
/// `params save`, three parameters changed with `set` (following error window 0x6065, profile velocity 0x6081,
/// profile acceleration 0x6083) are exactly the three changes `params load` lists, old -> new, and read back
/// with the saved values afterwards; a second load changes nothing.
#[test]
fn params_load_restores_exactly_the_three_changed_parameters() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let dir = WorkDir::new("drive-tool-params");
    let dcf = dir.join("drive.dcf");
    let dcf_arg = dcf.to_str().expect("utf-8 path");
    let before: Vec<Value> = ["0x6065", "0x6081", "0x6083"].iter().map(|o| sim.get(o)).collect();
    sim.ok(&["params", "save", dcf_arg]);
    for (object, value) in [("0x6065", "555"), ("0x6081", "1234"), ("0x6083", "4321")] {
        sim.ok(&["set", object, value]);
    }
    let load = sim.json(&["params", "load", dcf_arg]);
    let changes = load["changes"].as_array().expect("changes");
    let addresses: Vec<&str> = changes.iter().map(|c| c["address"].as_str().expect("address")).collect();
    assert_eq!(addresses, ["0x6065:00", "0x6081:00", "0x6083:00"], "{load}");
    assert!(changes[0]["old"].as_str().expect("old").starts_with("555 "), "{load}");
    assert!(changes[0]["new"].as_str().expect("new").starts_with(&format!("{} ", before[0])), "{load}");
    let after: Vec<Value> = ["0x6065", "0x6081", "0x6083"].iter().map(|o| sim.get(o)).collect();
    assert_eq!(after, before);
    let again = sim.json(&["params", "load", dcf_arg]);
    assert_eq!(again["changes"].as_array().map(Vec::len), Some(0), "{again}");
}

/// Proves (CiA 301 §7.5.2.13 store parameters, §7.2.8.3.1 node control): a value written with `set` alone is
/// back at its default after `nmt reset` (the reset node restarts the application with the stored
/// parameters, and the reset waits for the boot-up); loaded with `params load --store` (0x1010:01 "save") it
/// survives the reset. `nmt stop` silences SDO (the upload times out) and `nmt preop` brings it back.
#[test]
fn params_load_store_survives_a_reset_node_and_nmt_stop_silences_sdo() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let default = sim.get("0x6065");
    sim.ok(&["set", "0x6065", "777"]);
    sim.ok(&["nmt", "reset"]);
    assert_eq!(sim.get("0x6065"), default, "not stored: the default after the reset");
    let dir = WorkDir::new("drive-tool-store");
    let dcf = dir.join("drive.dcf");
    sim.ok(&["set", "0x6065", "777"]);
    sim.ok(&["params", "save", dcf.to_str().expect("utf-8")]);
    sim.ok(&["set", "0x6065", &default.to_string()]);
    let load = sim.json(&["params", "load", dcf.to_str().expect("utf-8"), "--store"]);
    assert_eq!(load["stored"], true, "{load}");
    sim.ok(&["nmt", "reset"]);
    assert_eq!(sim.get("0x6065"), 777, "stored by params load --store");
    sim.ok(&["nmt", "stop"]);
    let (ok, _, err) = sim.tool(&["get", "0x1000", "--sdo-timeout-ms", "500"]);
    assert!(!ok && err.contains("no SDO answer (timeout)"), "{err}");
    sim.ok(&["nmt", "preop"]);
    sim.ok(&["get", "0x1000"]);
}

/// Proves (CiA 301 §7.5.2.35/.36, the PDO mapping procedure; the drive refuses a mapping entry while its PDO
/// is valid or mapped, 0x06010000, and a new COB-ID while the PDO is valid, 0x06090030): after TPDO 1 was
/// remapped (0x1A00:03) and moved to another COB-ID (0x1800:01) by hand in that order, and TPDO 2's COB-ID
/// changed, `params load` of the DCF saved before lists exactly those three changes and writes them without a
/// refusal: the three read back as saved.
#[test]
fn params_load_remaps_a_pdo_in_the_order_cia_301_requires() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let dir = WorkDir::new("drive-tool-pdo");
    let dcf = dir.join("drive.dcf");
    let dcf_arg = dcf.to_str().expect("utf-8");
    let saved: Vec<Value> = ["0x1800:01", "0x1801:01", "0x1A00:03"].iter().map(|o| sim.get(o)).collect();
    sim.ok(&["params", "save", dcf_arg]);
    let cob_id = saved[0].as_u64().expect("COB-ID");
    for (object, value) in [
        ("0x1800:01", format!("{}", cob_id | 0x8000_0000)),
        ("0x1A00:00", "0".into()),
        ("0x1A00:03", "0x60640020".into()),
        ("0x1A00:00", "3".into()),
        ("0x1800:01", format!("{}", (cob_id | 0x8000_0000) + 0x100)),
        ("0x1800:01", format!("{}", cob_id + 0x100)),
        ("0x1801:01", format!("{}", (saved[1].as_u64().expect("COB-ID") | 0x8000_0000) + 2)),
    ] {
        sim.ok(&["set", object, &value]);
    }
    let load = sim.json(&["params", "load", dcf_arg]);
    let addresses: Vec<&str> =
        load["changes"].as_array().expect("changes").iter().map(|c| c["address"].as_str().expect("address")).collect();
    assert_eq!(addresses, ["0x1800:01", "0x1801:01", "0x1A00:03"], "{load}");
    assert_eq!(load["failures"].as_array().map(Vec::len), Some(0), "{load}");
    let after: Vec<Value> = ["0x1800:01", "0x1801:01", "0x1A00:03"].iter().map(|o| sim.get(o)).collect();
    assert_eq!(after, saved);
}

/// Proves (CiA 306 §4.6.3, `$NODEID` in values): the DCF of node 1 (its following error window changed) loads
/// onto node 2 with exactly one change, 0x6065: the COB-IDs, saved relative to the node-ID, are node 2's own
/// already, and node 2 keeps its node-ID 0x2000 (the load says so).
#[test]
fn a_dcf_of_node_1_loads_onto_node_2_with_its_own_cob_ids_and_node_id() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(2);
    let dir = WorkDir::new("drive-tool-other-node");
    let dcf = dir.join("node1.dcf");
    let dcf_arg = dcf.to_str().expect("utf-8");
    sim.ok(&["set", "0x6065", "3333"]);
    sim.ok(&["params", "save", dcf_arg]);
    let cob_id_2 = sim.json(&["--node", "2", "get", "0x1800:01"])[0]["value"].clone();
    let load = sim.json(&["--node", "2", "params", "load", dcf_arg]);
    let addresses: Vec<&str> =
        load["changes"].as_array().expect("changes").iter().map(|c| c["address"].as_str().expect("address")).collect();
    assert_eq!(addresses, ["0x6065:00"], "{load}");
    assert!(load["kept"][0].as_str().is_some_and(|k| k.starts_with("0x2000:00")), "{load}");
    assert_eq!(sim.json(&["--node", "2", "get", "0x2000"])[0]["value"], 2);
    assert_eq!(sim.json(&["--node", "2", "get", "0x1800:01"])[0]["value"], cob_id_2);
    assert_eq!(sim.json(&["--node", "2", "get", "0x6065"])[0]["value"], 3333);
}

/// Proves (CiA 306 identity check): a DCF whose 0x1018:02 product code is not the drive's is refused with both
/// values named, and loads with `--force`.
#[test]
fn a_dcf_of_another_device_is_refused_unless_forced() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let dir = WorkDir::new("drive-tool-identity");
    let dcf = dir.join("drive.dcf");
    let dcf_arg = dcf.to_str().expect("utf-8 path");
    sim.ok(&["params", "save", dcf_arg]);
    let product = format!("0x{:08X}", device().product_code);
    let text = std::fs::read_to_string(&dcf).expect("the DCF");
    let section = text.find("[1018sub2]").expect("the product code's section");
    let other = format!(
        "{}{}",
        &text[..section],
        text[section..].replacen(&format!("ParameterValue={product}"), "ParameterValue=0x0BADBEEF", 1)
    );
    assert_ne!(other, text, "the DCF records the product code as {product}");
    std::fs::write(&dcf, other).expect("write");
    let (ok, _, err) = sim.tool(&["params", "load", dcf_arg]);
    assert!(!ok);
    assert!(err.contains("another device") && err.contains("0x0BADBEEF") && err.contains(&product), "{err}");
    sim.ok(&["params", "load", dcf_arg, "--force"]);
}

/// Proves (CiA 306 read by another tool): the DCF `params save` writes imports in PyPI canopen
/// (`import_od`) with the drive's node-ID from `[DeviceComissioning]`, the drive's value of 0x6065 (changed
/// from its default first, so that a DefaultValue read would fail) as the object's value, and TPDO 1's COB-ID,
/// saved as `$NODEID+...`, as node 3's.
#[test]
fn the_saved_dcf_imports_in_pypi_canopen() {
    if drive_tests::prerequisite::skip("the_saved_dcf_imports_in_pypi_canopen", drive_tests::can_master::cannot_run()) {
        return;
    }
    let _one = one_run_at_a_time();
    let sim = Sim::start(3);
    let dir = WorkDir::new("drive-tool-pypi");
    let dcf = dir.join("drive.dcf");
    sim.ok(&["--node", "3", "set", "0x6065", "4242"]);
    sim.ok(&["--node", "3", "params", "save", dcf.to_str().expect("utf-8 path")]);
    let script = "import sys, canopen\nod = canopen.import_od(sys.argv[1])\n\
                  print(od.node_id, od[0x6065].value, od[0x1018][2].value, od[0x1800][1].value)";
    let out = Command::new("python3").args(["-c", script]).arg(&dcf).output().expect("run python3");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    let cob_id = sim.json(&["--node", "3", "get", "0x1800:01"])[0]["value"].clone();
    assert_eq!(text.trim(), format!("3 4242 {} {cob_id}", device().product_code), "node-ID, values, $NODEID COB-ID");
}

/// Proves (CiA 301 §7.5.2.5 error history, CiA 402 fault reset): a following error provoked over the bus (the
/// window 0x6065 set to 1 increment with timeout 0, then a move) stops the move with the fault's code and
/// name; `faults` shows 0x603F and the newest 0x1003 entry as the fault table's code and name of
/// FollowingError with the error register's bits; `fault reset` leaves «Switch on disabled» with 0x603F = 0.
#[test]
fn faults_show_the_code_and_text_of_a_following_error_and_fault_reset_clears_it() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let fault = FaultId::FollowingError.info();
    sim.ok(&["set", "0x6065", "1"]);
    sim.ok(&["set", "0x6066", "0"]);
    let (ok, _, err) = sim.tool(&["move", "40000", "--timeout-s", "120"]);
    assert!(!ok, "the move must stop at the fault");
    assert!(err.contains(&format!("0x{:04X} {}", fault.code, fault.name)), "{err}");
    let faults = sim.json(&["faults"]);
    assert_eq!(faults["error_code"], fault.code, "{faults}");
    assert_eq!(faults["error_code_text"], fault.name, "{faults}");
    assert_eq!(faults["history"][0]["code"], fault.code, "{faults}");
    assert_eq!(faults["history"][0]["text"], fault.name, "{faults}");
    assert_eq!(faults["history"][0]["register"], fault.register, "{faults}");
    assert_eq!(faults["cia402"], "Fault");
    let reset = sim.json(&["fault", "reset"]);
    assert_eq!(reset["cia402"], "Switch on disabled", "{reset}");
    assert_eq!(reset["error_code"], 0, "{reset}");
}

/// Proves (CiA 402-2 §9 profile position mode): `move 20000` enables the drive, gives the set-point and returns
/// when statusword bit 10 reports target reached, with the position actual value 0x6064 within the position
/// window 0x6067 of the target (the drive's own criterion for bit 10, read from the drive); a relative move of
/// -5000 then ends within the window of 15000.
#[test]
fn move_reaches_its_target() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let window = sim.get("0x6067").as_i64().expect("position window");
    let moved = sim.json(&["move", "20000", "--velocity", "1000", "--timeout-s", "120", "--stay-enabled"]);
    assert_eq!(moved["target"], 20000);
    let position = moved["position"].as_i64().expect("position");
    assert!((position - 20000).abs() <= window, "position {position}, window {window}: {moved}");
    assert_eq!(moved["cia402"], "Operation enabled");
    let back = sim.json(&["move", "-5000", "--relative", "--timeout-s", "120"]);
    let position = back["position"].as_i64().expect("position");
    assert!((position - 15000).abs() <= window, "position {position}, window {window}: {back}");
    assert_eq!(back["cia402"], "Ready to switch on", "disabled after the move");
}

/// Proves (CiA 402-2 §11 profile velocity mode, halt): `jog --velocity 300` turns the axis in the commanded
/// direction (the velocity actual value 0x606C seen above 0; how far it gets depends on the simulated time the
/// polls run in lock-step, so no level is asserted), and after the halt the velocity is within the velocity
/// window 0x606D, the drive's own criterion for bit 10; the drive is disabled afterwards.
#[test]
fn jog_turns_the_axis_the_commanded_way_and_halts_it() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let window = sim.get("0x606D").as_i64().expect("velocity window");
    for velocity in [300i64, -300] {
        let jog = sim.json(&["jog", "--velocity", &velocity.to_string(), "--seconds", "0.5"]);
        let peak = jog["velocity_peak"].as_i64().expect("peak");
        assert!(peak.signum() == velocity.signum(), "{jog}");
        assert!(jog["velocity_after_halt"].as_i64().expect("after").abs() <= window, "{jog}");
        assert_eq!(jog["cia402"], "Ready to switch on", "{jog}");
    }
}

/// Proves (the command line for people): every command has `--help`, and a bad option value is named.
#[test]
fn every_command_has_help_and_a_bad_value_is_named() {
    for command in
        ["scan", "info", "list", "get", "set", "params", "faults", "fault", "enable", "disable", "jog", "move"]
    {
        let out = Command::new(env!("CARGO_BIN_EXE_drive-tool")).args([command, "--help"]).output().expect("run");
        assert!(out.status.success(), "{command} --help");
        assert!(String::from_utf8_lossy(&out.stdout).contains("Usage: drive-tool"), "{command} --help");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_drive-tool")).args(["--node", "0", "scan"]).output().expect("run");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--node"));
    let out = Command::new(env!("CARGO_BIN_EXE_drive-tool")).args(["scan"]).output().expect("run");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--socketcand HOST:PORT"), "no link given");
}

/// A signed image of `len` payload bytes, version `version` ("0.2.0" style text `text`), signed with `seed`
/// (the simulated drives trust the development key, `hal_sim::sim::update::dev_seed`).
fn image_file(dir: &WorkDir, name: &str, version: u32, text: &str, seed: &[u8; 32]) -> String {
    use hal_sim::sim::update::{payload, signed_image};
    let image = signed_image(&payload(48 * 1024, version), version, text, firmware::boot::image::HARDWARE_ID, seed);
    let file = dir.join(name);
    std::fs::write(&file, image).expect("write the image");
    file.display().to_string()
}

/// Proves (issue 22 "update installs a new signed image and the version reads back"; IDX program control
/// 0x1F50..0x1F57): `update IMAGE --json` stops and clears the program, block-downloads a 48 KiB image signed with
/// the development key, starts it and waits for the boot-up; the drive then runs the image's version "0.2.0" in
/// 0x100A (it ran the factory image before), 0x1F56:01 holds the new application id (version's high word) with the
/// bootloader's, the program runs (0x1F51:01 = 1) and the flash status is 0.
#[test]
fn update_installs_a_signed_image_and_the_new_version_reads_back() {
    use hal_sim::sim::update::{dev_seed, FACTORY_VERSION};
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let dir = WorkDir::new("drive-tool-update");
    let version = 0x0002_0000;
    let file = image_file(&dir, "new.img", version, "0.2.0", &dev_seed());
    let report = sim.json(&["update", &file]);
    let bootloader = u64::from(firmware::boot::program::BOOTLOADER_ID);
    assert_eq!(report["version_after"], "0.2.0", "{report}");
    assert_eq!(report["image_version"], "0.2.0", "{report}");
    assert_eq!(report["software_id_before"], u64::from(FACTORY_VERSION & 0xFFFF_0000) | bootloader, "{report}");
    assert_eq!(report["software_id_after"], u64::from(version & 0xFFFF_0000) | bootloader, "{report}");
    assert_eq!(report["program_state"], 1, "{report}");
    assert_eq!(report["flash_status"], "flash status 0 (no error)", "{report}");
    assert_ne!(report["version_before"], report["version_after"], "{report}");
    assert_eq!(sim.get("0x100A"), "0.2.0", "the drive answers with its new firmware");
}

/// Proves (IDX L3413-3473 flash status; `firmware::boot::program` refusals): an image signed with another key is
/// refused at the end of its download with SDO abort 0x08000020 and flash status 93 "signature invalid", both in
/// the tool's message, and the drive keeps running its firmware; a file that is no image is refused before the bus
/// is touched, naming the file.
#[test]
fn a_forged_image_is_refused_with_the_abort_and_the_flash_status_and_the_drive_runs_on() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let dir = WorkDir::new("drive-tool-forged");
    let before = sim.get("0x100A");
    let file = image_file(&dir, "forged.img", 0x0003_0000, "0.3.0", &[7u8; 32]);
    let (ok, out, err) = sim.tool(&["update", &file]);
    assert!(!ok, "a forged image is refused:\n{out}{err}");
    assert!(err.contains("0x08000020"), "the SDO abort: {err}");
    assert!(err.contains("flash status 93 (signature invalid)"), "the flash status: {err}");
    assert_eq!(sim.get("0x100A"), before, "the old firmware runs on");
    let junk = dir.join("junk.bin");
    std::fs::write(&junk, b"not an image").expect("write");
    let (ok, _, err) = sim.tool(&["update", &junk.display().to_string()]);
    assert!(!ok && err.contains("not a signed drive image") && err.contains("junk.bin"), "{err}");
}

/// Proves (CiA 305 §6.3, §6.7; issue 21 item 4 with the project's own tool): `lss assign --from 10 --json`
/// against three drives started without a node-ID finds each by fastscan (the identity of device.toml, three
/// different serial numbers), gives them 10, 11, 12, stores them and sees each boot; no unconfigured drive is left;
/// after an NMT reset node to all, `scan` finds exactly 10, 11 and 12.
#[test]
fn lss_assign_gives_unconfigured_drives_node_ids_that_survive_a_reset() {
    let _one = one_run_at_a_time();
    let sim = Sim::start_with(3, &["--unconfigured", "1", "--unconfigured", "2", "--unconfigured", "3"]);
    let d = device();
    assert_eq!(sim.json(&["scan"]).as_array().map(Vec::len), Some(0), "no node-ID, no answer");
    let report = sim.json(&["lss", "assign", "--from", "10"]);
    let assigned = report["assigned"].as_array().expect("a list");
    assert_eq!(assigned.iter().map(|a| a["node"].as_u64().unwrap()).collect::<Vec<_>>(), [10, 11, 12], "{report}");
    let mut serials: Vec<u64> = assigned.iter().map(|a| a["serial"].as_u64().unwrap()).collect();
    serials.sort_unstable();
    serials.dedup();
    assert_eq!(serials.len(), 3, "three drives, three serials: {report}");
    for a in assigned {
        assert_eq!(a["vendor_id"], u64::from(d.vendor_id), "{a}");
        assert_eq!(a["product_code"], u64::from(d.product_code), "{a}");
        assert_eq!((a["stored"].as_bool(), a["booted"].as_bool()), (Some(true), Some(true)), "{a}");
    }
    assert_eq!(report["unconfigured_left"], false, "{report}");
    sim.ok(&["nmt", "reset", "--all"]);
    let found = sim.json(&["scan"]);
    let nodes: Vec<u64> = found.as_array().expect("a list").iter().map(|n| n["node"].as_u64().unwrap()).collect();
    assert_eq!(nodes, [10, 11, 12], "after reset node: {found}");
}

/// Proves (issue 22 "identify / tune running the any-motor procedure with progress and a report"; issue 18's
/// bounds): `identify --json` against the reference plant runs the drive's identification (0x6060 = -2) to its
/// end and reports resistance and torque constant within 3 % of the plant's (R at its reference temperature,
/// kt = 3/2 p psi), the total inertia within 5 %, the pole pairs exactly, a rigid load (no resonance pair) and the
/// tuned gains; the power stage is off afterwards. `tune --stiffness 800` then lowers the velocity P gain
/// (the crossover scales with the stiffness) and leaves the current loop's as it was. The tolerances are the
/// issue's: the identification's own scenario meets them with margin (drive-sim identify: R -0.31 %, kt -0.76 %,
/// inertia -0.64 %).
#[test]
fn identify_reports_the_reference_motor_and_tune_follows_the_stiffness() {
    let _one = one_run_at_a_time();
    let sim = Sim::start(1);
    let plant = hal_sim::plant::PlantParams::reference();
    let report = sim.json(&["identify", "--poll-ms", "0"]);
    let value = |key: &str| report[key].as_f64().unwrap_or_else(|| panic!("{key} in {report}"));
    let within = |key: &str, truth: f64, pct: f64| {
        let error = (value(key) - truth) / truth * 100.0;
        assert!(error.abs() <= pct, "{key}: {} against {truth}, {error:.2} % (bound {pct} %)", value(key));
    };
    within("resistance", plant.phase_resistance_ohm, 3.0);
    within("torque_constant", 1.5 * f64::from(plant.pole_pairs) * plant.flux_linkage_wb, 3.0);
    within("inertia", plant.total_inertia_kg_m2(), 5.0);
    assert_eq!(value("pole_pairs"), f64::from(plant.pole_pairs));
    assert_eq!((value("resonance"), value("anti_resonance")), (0.0, 0.0), "a rigid load");
    assert!(value("velocity_p_gain") > 0.0 && value("current_p_gain") > 0.0, "{report}");
    assert_eq!(sim.json(&["info"])["cia402"], "Ready to switch on", "power stage off after the identification");
    let tuned = sim.json(&["tune", "--stiffness", "800"]);
    let v_before = value("velocity_p_gain");
    let v_after = tuned["velocity_p_gain"].as_f64().expect("velocity_p_gain");
    assert!(v_after < 0.9 * v_before, "velocity P {v_before} -> {v_after} at stiffness 800");
    assert_eq!(tuned["current_p_gain"], report["current_p_gain"], "the current loop does not follow the stiffness");
    assert_eq!(tuned["result"], 1, "0x3205:05 = 1 gains written");
}

/// Proves issue 22's "`record` of a current step writes a CSV and an SVG whose trace matches the simulator's own
/// within 1 %": in CST (0x6060 = 10, no interpolation 0x60C2:01 = 0) `record --no-wait` arms the data recorder
/// (q current and its reference at 25 kHz, 200 samples, 20 before the trigger: the reference rising through
/// 100 mA); the master polls the recorder's state until more than the 20 preceding samples have passed (each
/// request runs simulated time in lock-step; it stays waiting: no trigger before the step), 0x6071 = 600 (60 % of
/// the rated torque) makes the step, and `record --fetch` uploads the recording by SDO block transfer into the CSV
/// and the SVG.
///
/// The reference: `drive-sim canopen --trace` writes the simulator's own values every current-loop period (tier
/// 1's q current and reference as the simulation's state holds them, and the plant's true q current), outside the
/// firmware's recorder path (no ring, no drain, no dictionary, no SDO). The recording's sample 20 is the trace's
/// first period with the reference at 100 mA or above (the trigger), and every recorded sample matches the trace
/// period for period: the reference exactly, the q current within 1 % of the step (it is the same value rounded
/// to the same mA, so a shift by one period or a lost sample would show as the step's slope, far above 1 %).
/// The plant's true q current is printed, not checked: on the free, accelerating shaft the drive's measured q
/// current differs from it by what the measurement and the angle estimate differ (about 15 % here), which is the
/// drive's, not the recorder's; tests/tests/drive/recorder.rs checks a recording against the plant on a locked
/// rotor (within 1 % of the step).
#[test]
fn record_of_a_current_step_matches_the_simulators_own_trace() {
    let _one = one_run_at_a_time();
    let dir = WorkDir::new("drive-tool-record");
    let trace = dir.join("trace.csv");
    let sim = Sim::start_with(1, &["--trace", trace.to_str().expect("utf-8")]);
    sim.ok(&["set", "0x60C2:01", "0"]);
    sim.ok(&["set", "0x6071", "0"]);
    sim.ok(&["set", "0x6060", "10"]);
    sim.ok(&["enable"]);
    let args = ["record", "--channel", "iq", "--channel", "iq_ref", "--samples", "200", "--pre", "20"];
    let armed = sim
        .json(&[&args[..], &["--trigger", "rising", "--trigger-channel", "2", "--level", "100", "--no-wait"]].concat());
    assert_eq!(armed["armed"], true, "{armed}");
    for _ in 0..10 {
        assert_eq!(sim.get("0x3300:02"), 1, "waiting for the trigger");
    }
    sim.ok(&["set", "0x6071", "600"]);
    let (csv, svg) = (dir.join("step.csv"), dir.join("step.svg"));
    let out =
        sim.json(&["record", "--fetch", "--csv", csv.to_str().expect("utf-8"), "--svg", svg.to_str().expect("utf-8")]);
    sim.ok(&["disable"]);
    assert_eq!(out["samples"], 200, "{out}");
    assert_eq!(out["channels"][0]["name"], "iq", "{out}");

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
    let (mut worst, mut square_sum) = (0.0f64, 0.0f64);
    for (k, (r, t)) in recorded.iter().zip(window).enumerate() {
        assert_eq!(r[2], t[2], "sample {k}: reference {} mA recorded, {} mA in the simulator", r[2], t[2]);
        worst = worst.max((r[1] - t[1]).abs());
        square_sum += (r[1] - t[3]).powi(2);
    }
    let rms = (square_sum / 200.0).sqrt();
    eprintln!("recorded against the simulator: worst {worst} mA; against the plant's true current: rms {rms:.1} mA");
    assert!(worst <= 0.01 * step_ma, "recorded q current off the simulator's by {worst} mA (1 % of {step_ma})");
}
