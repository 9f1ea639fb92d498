//! PyPI `canopen` (python-can's socketcand interface) with the generated EDS against `drive-sim canopen` (issue 8,
//! "What it must show"): the scripts under tests/canopen/ drive the simulated drives over the simulated CAN bus
//! (drive_tests::can_master starts the simulator, runs the script, collects both sides' figures).
//!
//! Lock-step clock except for the bad-frame test (it needs frames to land inside a reset, which lock-step never
//! lets happen). In lock-step a SYNC runs one SYNC period, an NMT or SDO request runs until the answer is out,
//! RPDOs and heartbeats run no time (hal-sim `sim::canopen`), so the verdicts do not depend on how busy the host is.
//!
//! Left out: the block download of 64 KiB to a domain, which needs the program-data object 0x1F50 that the
//! firmware-update work (issue 7) serves; the block downloads here go to 0x607A (4 bytes, one segment) since the
//! dictionary has no other writable object longer than 4 bytes.
//!
//! When python3 or PyPI canopen is missing (`scripts/setup.sh` installs them) each test fails under `CI=true` and
//! is a reported skip elsewhere (`drive_tests::prerequisite`).

use std::fmt::Write as _;
use std::path::PathBuf;

use drive_tests::can_master::{cannot_run, run, write_eds, WorkDir};
use drive_tests::real_master::RunOutput;
use firmware::boot::program::Interface;
use firmware::boot::tables::APPLICATION_TABLE;
use firmware::fault::FaultId;
use firmware::od::access::{Dictionary, NoApplicationObjects};
use firmware::od::entry::{Access, Entry};
use firmware::od::generated::handles;
use hal_sim::can::timing::frame_bits;
use hal_sim::scenarios::motion::JerkLimitedMove;
use hal_sim::sim::update::PowerOnObjects;

const INC_PER_REV: f64 = 4096.0;

/// Following-error bounds of the motion issue for the 10-revolution CSP move (tests/tests/motion/cyclic.rs,
/// canopen_node.rs): peak and RMS, increments.
const FE_PEAK_MAX: f64 = 30.0;
const FE_RMS_MAX: f64 = 8.0;

macro_rules! skip_unless_runnable {
    ($name:expr) => {
        if drive_tests::prerequisite::skip($name, cannot_run()) {
            return;
        }
    };
}

fn pass(out: &RunOutput) {
    assert_eq!(out.master("verdict"), "pass", "\n{}", out.text);
    assert_eq!(out.master("master_rc"), "0", "\n{}", out.text);
    assert_eq!(out.master("sim_rc"), "0", "drive-sim's exit status\n{}", out.text);
}

/// Proves (CiA 301 §7.2.8.2.1, §7.3.2): after an NMT reset node and a reset communication from canopen's
/// NmtMaster the boot-up message 0x701 [0x00] arrives; with 0x1017 = 10 ms the node's heartbeat reports each
/// state an NMT command moves it to (pre-operational 0x7F, operational 0x05, stopped 0x04, and back), every
/// heartbeat after the command's first with that state, 2..=3 of them in 30 SYNC periods of 1 ms, and canopen's
/// NmtMaster reads the same state from them; in stopped canopen's SDO upload gets no answer (its client raises
/// SdoCommunicationError after its timeout); back in pre-operational the upload answers with the device type.
#[test]
fn canopen_sees_the_boot_up_and_moves_the_node_through_the_nmt_states_by_its_heartbeat() {
    skip_unless_runnable!("canopen_sees_the_boot_up_and_moves_the_node_through_the_nmt_states_by_its_heartbeat");
    let dir = WorkDir::new("nmt");
    let eds = write_eds(&dir);
    let out = run("nmt.py", &["--lock-step"], &eds, &[]);
    pass(&out);
    assert_eq!(out.master("bootup_after_reset_node"), "701:00");
    assert_eq!(out.master("bootup_after_reset_comm"), "701:00");
    assert_eq!(out.master("heartbeat_time_ms"), "10");
    for (state, code) in [("PRE_OPERATIONAL", "7f"), ("OPERATIONAL", "05"), ("STOPPED", "04")] {
        assert_eq!(out.master(&format!("hb_{state}")), code, "heartbeat state after {state}\n{}", out.text);
        let n = out.master_num(&format!("hb_count_{state}"));
        assert!((2.0..=3.0).contains(&n), "{n} heartbeats after {state} (30 ms at 10 ms, the first left out)");
        assert_eq!(out.master(&format!("canopen_state_{state}")), state.replace("PRE_", "PRE-"));
    }
    assert_eq!(out.master("stopped_sdo"), "timeout", "no SDO in stopped");
    let device_type = format!("0x{:08x}", drive_tests::real_master::default_u32(&Dictionary::new(1), 0x1000, 0));
    assert_eq!(out.master("sdo_after_stopped"), device_type);
    assert_eq!(out.sim("node1_nmt"), "PreOperational");
    println!(
        "NMT: boot-up {} after reset node and reset communication; heartbeat states 7f/05/04 seen; stopped SDO \
         timed out; simulated {} s, {} master frames",
        out.master("bootup_after_reset_node"),
        out.sim("simulated_s"),
        out.sim("master_frames")
    );
}

/// Proves (CiA 301 §7.3.2, §7.5.2.13/14; issue 19, "stored communication parameters are lost at every reset"):
/// with PyPI canopen, 0x1017 = 150, 0x1015 = 7, 0x1020:01 = 15,000 and 0x1800:05 = 200 saved with
/// `RemoteNode.store()` read back exactly after reset node and after reset communication, though they were changed
/// again without saving; the heartbeat runs every 150 ms after either reset (6 or 7 in one second of SYNCs at
/// 10 ms); 0x1010:02 "save communication parameters" alone keeps 0x1017 = 100 over a reset communication; after
/// 0x1011:02 "restore default parameters" the next reset communication brings every one back to its default, 0.
#[test]
fn saved_communication_parameters_come_back_after_reset_node_and_reset_communication() {
    skip_unless_runnable!("saved_communication_parameters_come_back_after_reset_node_and_reset_communication");
    let dir = WorkDir::new("stored");
    let eds = write_eds(&dir);
    let out = run("stored.py", &["--lock-step", "--sync-us", "10000"], &eds, &[]);
    pass(&out);
    let saved = [("heartbeat_ms", 150), ("emcy_inhibit", 7), ("verify_date", 15_000), ("tpdo1_event_timer", 200)];
    for reset in ["node", "comm"] {
        for (name, value) in saved {
            assert_eq!(out.master(&format!("{name}_after_{reset}")), value.to_string(), "{name} after reset {reset}");
        }
        let heartbeats = out.master_num(&format!("heartbeats_after_{reset}"));
        assert!((6.0..=7.0).contains(&heartbeats), "{heartbeats} heartbeats in 1 s after reset {reset}");
    }
    assert_eq!(out.master("hb_after_save_comm"), "100");
    for (name, _) in saved {
        assert_eq!(out.master(&format!("{name}_after_restore")), "0", "{name} after restoring the defaults");
    }
    println!(
        "stored communication parameters: back after reset node and reset communication, heartbeats {} and {} per \
         second; restored defaults after 0x1011:02",
        out.master("heartbeats_after_node"),
        out.master("heartbeats_after_comm")
    );
}

/// What the dictionary answers to an upload of `entry`: the value or the abort code. The application-served
/// entries (0x1010/0x1011 store and load, 0x100A and 0x1F5x program control) through the objects hal-sim's
/// CANopen runner serves at power-on ([`PowerOnObjects`]).
fn upload(d: &Dictionary, objects: &mut PowerOnObjects, entry: &Entry) -> Result<Vec<u8>, u32> {
    let mut buf = vec![0u8; 4096];
    objects
        .read_in(d, Interface::Canopen, entry.index, entry.sub, 0, &mut buf)
        .map(|r| buf[..r.len].to_vec())
        .map_err(|a| a.code())
}

/// Read-write entries in which the drive sets bits as it runs, compared by length: 0x60FE:01 bits 24/25 (holding
/// brake, ready/fault, read-only bits of the outputs, firmware/device.toml). Under CAN lock-step every SDO
/// request runs at least one slow tick, so the drive's slow tick has written them (under EtherCAT's PRE-OP
/// lock-step time stands still and they keep their defaults).
const SET_BY_THE_DRIVE: &[(u16, u8)] = &[(0x60FE, 1)];

/// `ro` and TxPDO-mappable entries that are nevertheless fixed while the drive stands (the rule of
/// tests/tests/ecat_soem_sdo.rs): compared byte for byte.
const FIXED_THOUGH_MAPPABLE: &[(u16, u8)] = &[(0x6502, 0), (0x6075, 0)];

/// Proves: every readable entry of the dictionary, uploaded by canopen's SDO client (expedited or segmented as
/// the server chooses), equals what `Dictionary::new(1)` holds after the node's boot (which sets 0x2000 to the
/// node-ID and the active fieldbus to CAN), by the rule of tests/tests/ecat_soem_sdo.rs: measured values (`ro`
/// and TxPDO-mappable, and [`SET_BY_THE_DRIVE`]) by length, abort answers by code, every other entry byte for
/// byte; the application-served entries (store/load 0x1010/0x1011, program control 0x100A and 0x1F5x) as the
/// drive's objects answer them.
#[test]
fn every_readable_object_uploads_through_canopen_as_the_dictionary_says() {
    skip_unless_runnable!("every_readable_object_uploads_through_canopen_as_the_dictionary_says");
    // The dictionary and application objects of the runner's drive at power-on (booted from an empty store,
    // the factory image running).
    let mut objects = PowerOnObjects::new();
    let mut d = Dictionary::with_table(APPLICATION_TABLE, objects.drive.dictionary().values().clone());
    // What the node's boot writes (firmware canopen `boot`, `reset`): the active fieldbus CAN, the node-ID.
    d.set(handles::ACTIVE_FIELDBUS, 1);
    let dir = WorkDir::new("objects");
    let eds = write_eds(&dir);
    let mut text = String::new();
    let (mut n, mut longer, mut by_len) = (0, 0, 0);
    for entry in d.table().entries().iter().filter(|e| e.access().readable()) {
        let expected = upload(&d, &mut objects, entry);
        let (rule, value, size) = match &expected {
            Err(code) => ("abort", format!("{code:08x}"), 0),
            Ok(v)
                if entry.access() == Access::ReadOnly
                    && entry.pdo().tx()
                    && !FIXED_THOUGH_MAPPABLE.contains(&(entry.index, entry.sub))
                    || SET_BY_THE_DRIVE.contains(&(entry.index, entry.sub)) =>
            {
                by_len += 1;
                ("len", v.iter().map(|b| format!("{b:02x}")).collect(), v.len())
            }
            Ok(v) => ("exact", v.iter().map(|b| format!("{b:02x}")).collect(), v.len()),
        };
        longer += usize::from(size > 4);
        writeln!(text, "{:04X} {:02X} {rule} {value} {size} {}", entry.index, entry.sub, entry.name).expect("write");
        n += 1;
    }
    assert!(n > 300, "{n} readable entries");
    let expect = dir.join("expect.txt");
    std::fs::write(&expect, text).expect("write the expectations");
    let out =
        run("sdo.py", &["--lock-step"], &eds, &["--part".into(), "objects".into(), "--expect".into(), path(&expect)]);
    pass(&out);
    println!(
        "canopen read {} entries: {} byte for byte, {} by length ({by_len} expected), {} aborts as expected, {} \
         longer than 4 bytes; script {} s",
        out.master("objects_read"),
        out.master("objects_exact"),
        out.master("objects_len"),
        out.master("objects_abort"),
        out.master("objects_longer_than_4"),
        out.master("script_s"),
    );
    assert_eq!(out.master("objects_mismatches"), "0", "{}\n{}", out.master("objects_mismatch_list"), out.text);
    assert_eq!(out.master("objects_read"), n.to_string());
    assert_eq!(out.master("objects_longer_than_4"), longer.to_string(), "segmented uploads");
}

fn path(p: &std::path::Path) -> String {
    p.to_str().expect("a UTF-8 path").to_owned()
}

/// Proves, with canopen's SDO client and hand-made frames: expedited upload and download; segmented upload
/// (0x1009, 23 bytes) and download (forced segmented); block upload (0x1009, 0x1008) and block download (0x607A)
/// with CRC, each value read back; the CiA 301 §7.2.4.3.17 abort codes: missing object 0x0602_0000, missing
/// sub-index 0x0609_0011, length too high 0x0607_0012 and too low 0x0607_0013, read-only 0x0601_0002, value
/// range 0x0609_0030 (a reserved transmission type), a mapping change of a valid PDO 0x0601_0000 (as
/// CANopenNode answers it) and in operational 0x0800_0022 (wrong state), toggle error 0x0503_0000, block CRC
/// error 0x0504_0004 (the value not stored), and the server timeout 0x0504_0000 1 s (the server's default) after
/// a segmented download was left alone, measured in simulated time between the initiate answer and the abort
/// (tolerance 1 ms: the server checks at every 400 us slow tick). Time passes in lock-step only with frames:
/// SYNCs carry it (1 ms each, unanswered in pre-operational). The node answers the device type after all this.
#[test]
fn sdo_transfers_of_every_kind_both_ways_and_the_abort_codes_through_canopen() {
    skip_unless_runnable!("sdo_transfers_of_every_kind_both_ways_and_the_abort_codes_through_canopen");
    let dir = WorkDir::new("transfers");
    let eds = write_eds(&dir);
    let out = run("sdo.py", &["--lock-step"], &eds, &["--part".into(), "transfers".into()]);
    pass(&out);
    let m = |k: &str| out.master(k).to_owned();
    assert_eq!(m("exp_upload_1000"), "0x00020192");
    assert_eq!(m("exp_download_1017"), "250");
    assert_eq!(m("seg_upload_1009"), "STM32F405 reference 1.0");
    assert_eq!(m("seg_download_607a"), "-123456");
    assert_eq!(m("block_upload_1009"), "STM32F405 reference 1.0");
    let mut name = [0u8; 64];
    let r = Dictionary::new(1).read(0x1008, 0, 0, &mut name, &mut NoApplicationObjects).expect("0x1008");
    assert_eq!(m("block_upload_1008"), String::from_utf8_lossy(&name[..r.len]));
    assert_eq!(m("block_download_607a"), "654321");
    for (case, code) in [
        ("abort_missing_object", 0x0602_0000u32),
        ("abort_missing_sub", 0x0609_0011),
        ("abort_wrong_size_long", 0x0607_0012),
        ("abort_wrong_size_short", 0x0607_0013),
        ("abort_read_only", 0x0601_0002),
        ("abort_value_range", 0x0609_0030),
        ("abort_mapping_of_valid_pdo", 0x0601_0000),
        ("abort_mapping_in_operational", 0x0800_0022),
        ("abort_toggle", 0x0503_0000),
        ("abort_block_crc", 0x0504_0004),
        ("abort_timeout", 0x0504_0000),
    ] {
        assert_eq!(m(case), format!("0x{code:08x}"), "{case}\n{}", out.text);
    }
    assert_eq!(&m("toggle_initiate_answer")[..2], "60", "segmented download initiated");
    assert_eq!(&m("block_initiate_answer")[..2], "a4", "block download initiated with CRC");
    assert_eq!(&m("block_segment_answer")[..4], "a201", "segment 1 acknowledged");
    assert_eq!(m("after_block_crc_607a"), "654321", "the value with the wrong CRC is not stored");
    let t = out.master_num("timeout_s");
    assert!((t - 1.0).abs() <= 0.001, "server timeout {t} s (1 s +- 1 ms)");
    assert_eq!(m("sdo_after_aborts"), "0x00020192");
    println!("SDO through canopen: all transfers and abort codes as expected; server timeout {t} s simulated");
}

/// The moves of the CSP tests, one per node: node 1 the 10-revolution jerk-limited move of the motion issue
/// (3,000 rpm asked, 2,449 rpm peak reached, 20,000 rpm/s peak acceleration), node 2 six revolutions back, node
/// 3 eight revolutions at 2,000 rpm and 15,000 rpm/s.
fn moves() -> [JerkLimitedMove; 3] {
    let per_rpm = INC_PER_REV / 60.0;
    [
        JerkLimitedMove::new(0.0, 10.0 * INC_PER_REV, 3000.0 * per_rpm, 20_000.0 * per_rpm),
        JerkLimitedMove::new(0.0, -6.0 * INC_PER_REV, 3000.0 * per_rpm, 20_000.0 * per_rpm),
        JerkLimitedMove::new(0.0, 8.0 * INC_PER_REV, 2000.0 * per_rpm, 15_000.0 * per_rpm),
    ]
}

/// Writes the set-point table for `period_us` (one line per SYNC of the longest move, one column per move).
fn write_setpoints(dir: &WorkDir, period_us: u64) -> PathBuf {
    let moves = moves();
    let t = period_us as f64 * 1e-6;
    let steps = moves.iter().map(|m| (m.duration_s() / t).ceil() as usize).max().expect("moves") + 2;
    let mut text = String::new();
    for s in 0..steps {
        let line: Vec<String> = moves.iter().map(|m| format!("{}", m.position(s as f64 * t).round() as i64)).collect();
        writeln!(text, "{}", line.join(" ")).expect("write");
    }
    let p = dir.join(&format!("setpoints-{period_us}.txt"));
    std::fs::write(&p, text).expect("write the set-points");
    p
}

/// Proves: canopen's PDO API (`read`, `clear`, `add_variable`, `trans_type`, `enabled`, `save`) configures RPDO 1
/// = controlword + target position and TPDO 1 = statusword + position actual, TPDO 2 = following error, TPDO 3 =
/// the sensor positions 0x60E4:01/02 (sensor 1 following 0x6064, sensor 2 0 without a load encoder), all
/// synchronous (read back through `read`); then CSP driven by SYNC at 1 ms: the drive enabled through the
/// controlword in the RPDO (seen in the TPDO statusword within 100 SYNCs), the 10-revolution move (2,449 rpm peak)
/// followed with the following error from the TPDO 0x60F4 peak <= 30 inc and RMS <= 8 inc over the move, and the
/// runner's own 0x60F4 figures within the same bounds; statusword bit 13 never set; the target reached within
/// +-1 inc; every TPDO within its SYNC period; no SYNC lost by the node's count.
#[test]
fn pdos_configured_through_canopen_then_csp_at_1_ms_follows_the_move_within_the_bounds() {
    skip_unless_runnable!("pdos_configured_through_canopen_then_csp_at_1_ms_follows_the_move_within_the_bounds");
    let dir = WorkDir::new("csp");
    let eds = write_eds(&dir);
    let sp = write_setpoints(&dir, 1000);
    let out = run(
        "csp.py",
        &["--lock-step", "--sync-us", "1000"],
        &eds,
        &["--setpoints".into(), path(&sp), "--tpdo-fe".into(), "--tpdo-sensors".into()],
    );
    pass(&out);
    assert_eq!(out.master("tpdo1_map_1"), "6041:00/16 6064:00/32");
    // Issue 20 item 2: TPDO 3 = the sensor positions 0x60E4:01/02. Sensor 1 is the motor encoder's count, 0x6064
    // without homing: equal, or one slow tick's travel apart (67 increments at the move's 2,449 rpm) where the
    // SYNC falls between their publications. The reference plant has no load encoder: sensor 2 reads 0.
    assert_eq!(out.master("tpdo3_map_1"), "60e4:01/32 60e4:02/32");
    let diff = out.master_num("sensor1_position_diff_max_1");
    assert!(diff <= 68.0, "0x60E4:01 against 0x6064: {diff}");
    assert_eq!(out.master("sensor2_values_1"), "0", "0x60E4:02 without a load encoder");
    assert_eq!(out.master("rpdo1_map_1"), "6040:00/16 607a:00/32");
    assert_eq!(out.master("tpdo1_type_1"), "1");
    assert_eq!(out.master("tpdo2_enabled_1"), "1");
    let enabled = out.master_num("enabled_at_1");
    assert!(enabled < 100.0, "enabled after {enabled} SYNCs");
    let (peak, rms) = (out.master_num("fe_peak_1"), out.master_num("fe_rms_1"));
    let samples = out.master_num("fe_samples_1");
    let duration = moves()[0].duration_s();
    assert!(samples >= (duration * 1000.0).floor() - 3.0, "sampled over the move ({samples})");
    assert!(peak <= FE_PEAK_MAX && rms <= FE_RMS_MAX, "TPDO 0x60F4: peak {peak} inc, RMS {rms} inc");
    let (sim_peak, sim_rms) = (out.sim_num("node1_fe_peak_inc"), out.sim_num("node1_fe_rms_inc"));
    assert!(sim_peak <= FE_PEAK_MAX && sim_rms <= FE_RMS_MAX, "runner: peak {sim_peak} inc, RMS {sim_rms} inc");
    assert_eq!(out.master("bit13_1"), "0", "following error bit never set");
    assert_eq!(out.master("distance_1"), "40960");
    assert!(out.master_num("final_error_1").abs() <= 1.0, "target reached: {}", out.master("final_error_1"));
    assert_eq!(out.master("late_cycles"), "0");
    assert_eq!(out.sim("node1_syncs_missed"), "0");
    assert_eq!(out.sim("node1_syncs"), out.master("cycles"), "every SYNC counted");
    assert_eq!(out.sim("node1_tx_dropped"), "0");
    assert_eq!(out.sim("node1_cia402"), "OperationEnabled");
    println!(
        "CSP over CAN with canopen at 1 ms: enabled after {enabled} SYNCs; TPDO following error peak {peak} inc, \
         RMS {rms} inc ({samples} SYNCs); runner peak {sim_peak} inc, RMS {sim_rms} inc; final error {} inc; bus \
         load {} %; {} cycles in {} s of wall time",
        out.master("final_error_1"),
        out.sim("bus_load_pct"),
        out.master("cycles"),
        out.master("script_s"),
    );
}

/// Proves issue 20 ("Real masters: the ... PyPI canopen tests map and use the new objects (SSI position ...) in
/// PDOs"): on the reference motor with an SSI absolute encoder in place of the incremental one
/// (`hal-sim/presets/reference-ssi.toml`: 12 + 12 bits, Gray, its zero at multi-turn count 5), canopen writes
/// 0x3000:01 = 0x00000300 (the SSI sensor alone, IDX 0x3000:01 sensor 2 type 3; read back exactly) and maps the SSI
/// position raw value 0x3012:09 into TPDO 4 (read back as `3012:09/32`), then drives the 10-revolution CSP move
/// at 1 ms commutated and positioned by the SSI sensor alone. Without homing 0x6064 is the sensor's absolute
/// position (0x3012:0E = 0), so 0x3012:09 equals 0x6064 modulo 2^24 at every SYNC, or one slow tick's travel
/// apart (67 increments at the move's 2,449 rpm, as 0x60E4:01 in the test above) where the SYNC falls between
/// their publications; the raw value spans the move's 40,960 increments (within that travel); the target is
/// reached within +-1 inc.
#[test]
fn canopen_maps_the_ssi_position_into_a_tpdo_and_drives_csp_on_the_ssi_sensor_alone() {
    skip_unless_runnable!("canopen_maps_the_ssi_position_into_a_tpdo_and_drives_csp_on_the_ssi_sensor_alone");
    let dir = WorkDir::new("csp-ssi");
    let eds = write_eds(&dir);
    let sp = write_setpoints(&dir, 1000);
    let plant = concat!(env!("CARGO_MANIFEST_DIR"), "/../hal-sim/presets/reference-ssi.toml");
    let out = run(
        "csp.py",
        &["--lock-step", "--sync-us", "1000", "--plant", plant],
        &eds,
        &["--setpoints".into(), path(&sp), "--ssi".into()],
    );
    pass(&out);
    assert_eq!(out.master("sensors_configuration_1"), "0x00000300");
    assert_eq!(out.master("tpdo4_map_1"), "3012:09/32");
    let diff = out.master_num("ssi_position_diff_max_1");
    assert!(diff <= 68.0, "0x3012:09 against 0x6064: {diff}");
    let span = out.master_num("ssi_raw_span_1");
    assert!((span - 40_960.0).abs() <= 68.0, "0x3012:09 over the move: {span}");
    assert_eq!(out.master("distance_1"), "40960");
    assert!(out.master_num("final_error_1").abs() <= 1.0, "target reached: {}", out.master("final_error_1"));
    assert_eq!(out.sim("node1_cia402"), "OperationEnabled");
}

/// Proves: with the drive in CSP after the move, 0x1016:01 supervising the master (node 127) at 50 ms and the
/// master's heartbeat sent every 20 SYNCs, stopping that heartbeat while SYNCs and set-points go on makes the
/// drive carry out the 0x6007 reaction (default: quick stop, statusword «Quick stop active») within 50..=80 SYNCs
/// of the heartbeat's stop (the 50 ms consumer time counts from the last heartbeat, sent up to 19 SYNCs before
/// the stop, plus one SYNC and one poll); 0x603F = 0x8130 (heartbeat error, CiA 301 Table 26); one EMCY on
/// 0x81 with code 0x8130, the error register's generic and communication bits (CiA 301 §7.5.2.2) and the fault's
/// number, and the silent producer's node-ID in bytes 4..7; the drive's own heartbeat (0x1017 = 20 ms) on 0x701
/// with the operational state 0x05.
#[test]
fn the_masters_heartbeat_stops_and_the_drive_reacts_with_0x6007_emcy_and_its_own_heartbeat() {
    skip_unless_runnable!("the_masters_heartbeat_stops_and_the_drive_reacts_with_0x6007_emcy_and_its_own_heartbeat");
    let dir = WorkDir::new("heartbeat");
    let eds = write_eds(&dir);
    let sp = write_setpoints(&dir, 1000);
    let out = run(
        "csp.py",
        &["--lock-step", "--sync-us", "1000"],
        &eds,
        &["--setpoints".into(), path(&sp), "--hb-every".into(), "20".into(), "--hb-loss".into()],
    );
    pass(&out);
    let after = out.master_num("hb_loss_reaction_syncs_after_last_hb");
    assert!(after > 50.0 && after <= 53.0, "quick stop {after} SYNCs (ms) after the last heartbeat\n{}", out.text);
    assert_eq!(u16::from_str_radix(&out.master("hb_loss_statusword")[2..], 16).expect("hex") & 0x6F, 0x07);
    assert_eq!(out.sim("node1_cia402"), "QuickStopActive");
    assert_eq!(out.master("error_code_603f"), "0x8130");
    assert_eq!(out.sim("node1_error_code"), "0x8130");
    assert_eq!(out.master("emcy_count"), "1", "one EMCY\n{}", out.text);
    let emcy = out.master("emcy_8130");
    let bytes: Vec<u8> = (0..8).map(|k| u8::from_str_radix(&emcy[2 * k..2 * k + 2], 16).expect("hex")).collect();
    assert_eq!(u16::from_le_bytes([bytes[0], bytes[1]]), FaultId::HeartbeatLost.info().code);
    assert_eq!(bytes[2] & 0x11, 0x11, "error register: generic and communication bits");
    assert_eq!(bytes[3], FaultId::HeartbeatLost.number());
    assert_eq!(&bytes[4..8], &127i32.to_le_bytes(), "the silent producer's node-ID");
    assert_eq!(out.master("drive_heartbeat_states"), "05");
    assert!(out.master_num("drive_heartbeats") >= 3.0, "the drive's heartbeats every 20 ms");
    assert_eq!(out.sim("node1_syncs_missed"), "0");
    println!(
        "heartbeat loss: quick stop {after} SYNCs of 1 ms after the master's last heartbeat (consumer 50 ms); EMCY \
         {emcy}; 0x603F {}",
        out.master("error_code_603f")
    );
}

/// Bus time of one CSP cycle of `nodes` drives at `bit_rate` (ns): the SYNC (no data) and per node the RPDO
/// (controlword + target, 6 bytes) and TPDO 1 (statusword + position actual, 6 bytes), all-zero data (the
/// most stuff bits for these lengths within a few bits), intermission included (hal-sim `can::timing`).
fn bus_ns_per_cycle(nodes: u16, bit_rate: u64) -> u64 {
    let mut bits = u64::from(frame_bits(0x080, false, 0, &[]));
    for id in 1..=nodes {
        bits += u64::from(frame_bits(0x200 + id, false, 6, &[0; 6]));
        bits += u64::from(frame_bits(0x180 + id, false, 6, &[0; 6]));
    }
    bits * 1_000_000_000 / bit_rate
}

/// Proves (issue 8, several axes): three drives (node-IDs 1..3) on one bus at 1 Mbit/s, configured through
/// canopen's PDO API (RPDO 1 and TPDO 1 as above, no TPDO 2: the runner measures the following error), run CSP
/// together, each its own move, for SYNC periods of 2 ms, 1 ms, 800, 600, 500 and 400 us. A period keeps all
/// three within their bounds when every TPDO arrives in its own SYNC period, no node counts a missed SYNC, every
/// drive is enabled, reaches its target within +-1 inc, and its following error (the runner's, from 0x60F4 at
/// every slow tick) stays within peak 30 inc and RMS 8 inc. 1 ms must work; the shortest period that works is
/// printed with the bus figures of each and must be at least the bus time one cycle's frames take (SYNC + 3 x
/// (RPDO + TPDO)): no period shorter than that can carry them.
#[test]
fn three_axes_at_1_mbit_run_csp_together_and_the_shortest_sync_period_is_found() {
    skip_unless_runnable!("three_axes_at_1_mbit_run_csp_together_and_the_shortest_sync_period_is_found");
    let dir = WorkDir::new("axes");
    let eds = write_eds(&dir);
    let cycle_ns = bus_ns_per_cycle(3, 1_000_000);
    let mut working = Vec::new();
    for period_us in [2000u64, 1000, 800, 600, 500, 400] {
        let sp = write_setpoints(&dir, period_us);
        let us = period_us.to_string();
        let out = run(
            "csp.py",
            &["--lock-step", "--nodes", "3", "--bit-rate", "1000000", "--sync-us", &us],
            &eds,
            &[
                "--setpoints".into(),
                path(&sp),
                "--nodes".into(),
                "1,2,3".into(),
                "--sync-us".into(),
                us.clone(),
                "--enable-cycles".into(),
                (200_000 / period_us).to_string(),
                "--tpdo-wait-s".into(),
                "0.5".into(),
                "--max-late".into(),
                "4".into(),
            ],
        );
        pass(&out);
        let mut ok = out.master("late_cycles") == "0";
        let mut line = format!(
            "period {period_us:>4} us: bus load {:>6} % over {} s simulated, {} cycles, {} late;",
            out.sim("bus_load_pct"),
            out.sim("simulated_s"),
            out.master("cycles"),
            out.master("late_cycles")
        );
        for id in 1..=3 {
            let missed = out.sim(&format!("node{id}_syncs_missed"));
            let peak = out.sim_num(&format!("node{id}_fe_peak_inc"));
            let rms = out.sim_num(&format!("node{id}_fe_rms_inc"));
            let fin = out.master.get(&format!("final_error_{id}")).cloned().unwrap_or_else(|| "none".into());
            ok &= missed == "0"
                && out.master(&format!("enabled_at_{id}")) != "None"
                && fin.parse::<i64>().is_ok_and(|e| e.abs() <= 1)
                && peak <= FE_PEAK_MAX
                && rms <= FE_RMS_MAX
                && out.sim(&format!("node{id}_fe_samples")) != "0";
            let _ = write!(line, " node {id}: missed {missed}, FE peak {peak} RMS {rms}, final {fin};");
        }
        println!("{line} {}", if ok { "within bounds" } else { "NOT within bounds" });
        if ok {
            working.push(period_us);
        }
    }
    assert!(working.contains(&1000), "1 ms works: {working:?}");
    let shortest = *working.iter().min().expect("a working period");
    println!(
        "three axes at 1 Mbit/s: shortest SYNC period within bounds {shortest} us; one cycle's frames take {} us \
         of bus time",
        cycle_ns as f64 / 1000.0
    );
    assert!(shortest * 1000 >= cycle_ns, "{shortest} us is shorter than the bus time of a cycle ({cycle_ns} ns)");
    // Every period at least the shortest works too (no hole in the list).
    for p in [2000u64, 1000, 800, 600, 500, 400].into_iter().filter(|p| *p >= shortest) {
        assert!(working.contains(&p), "{p} us not within bounds though {shortest} us is: {working:?}");
    }
}

/// Proves, through socketcand in real time: an SDO request of 5 bytes and NMT commands of 3 and 1 bytes are
/// ignored (no answer; the node was not stopped); frames on unknown COB-IDs (nobody's, another node's SDO, node
/// 0's SDO, LSS, a TPDO's, 0x7FF) get nothing; SDO segments and block requests with no transfer in progress
/// answer abort 0x0504_0001 (command specifier not valid), a wrong toggle in a segmented upload 0x0503_0000; in
/// stopped an SDO request, an RPDO and a SYNC get nothing; an NMT reset node followed, in the same write, by 20
/// SDO requests back to back: exactly one boot-up, some requests unanswered (those during the reset, counted by
/// the new node as ignored), every answer correct and after the boot-up; after every case canopen's upload of
/// 0x1000 answers the device type.
#[test]
fn bad_frames_through_socketcand_get_no_answer_or_the_right_abort_and_the_node_answers_after() {
    skip_unless_runnable!("bad_frames_through_socketcand_get_no_answer_or_the_right_abort_and_the_node_answers_after");
    let dir = WorkDir::new("bad");
    let eds = write_eds(&dir);
    let out = run("bad_frames.py", &[], &eds, &[]);
    pass(&out);
    let device_type = format!("0x{:08x}", drive_tests::real_master::default_u32(&Dictionary::new(1), 0x1000, 0));
    for case in ["start", "sdo_dlc5", "nmt_wrong_dlc", "unknown_cob_ids", "sequence_errors", "stopped", "reset"] {
        assert_eq!(out.master(&format!("after_{case}")), device_type, "after {case}");
    }
    assert_eq!(out.master("sdo_dlc5_answer"), "none");
    assert_eq!(out.master("unknown_cob_id_frames_from_node"), "0");
    for case in ["upload_segment_idle", "download_segment_idle", "block_upload_start_idle", "block_download_end_idle"] {
        assert_eq!(out.master(&format!("{case}_abort")), "0x05040001", "{case}");
    }
    assert_eq!(&out.master("seg_upload_initiate_answer")[..2], "41", "segmented upload of 0x1009 initiated");
    assert_eq!(out.master("upload_toggle_abort"), "0x05030000");
    assert_eq!(out.master("stopped_sdo_answer"), "none");
    assert_eq!(out.master("stopped_rpdo_frames"), "0");
    assert_eq!(out.master("stopped_sync_frames"), "0");
    assert_eq!(out.master("burst_bootups"), "1");
    let (sent, answers) = (out.master_num("burst_sent"), out.master_num("burst_answers"));
    assert!(answers >= 1.0 && answers < sent, "{answers} of {sent} answered");
    assert_eq!(out.master("burst_answers_after_bootup"), out.master("burst_answers"), "answers only after the boot");
    assert_eq!(out.master("burst_answers_wrong"), "0");
    // The restarted node counts what it ignored since its power-on: the requests during its initialisation.
    let ignored = out.sim_num("node1_ignored");
    assert!(ignored >= 1.0 && ignored + answers <= sent, "ignored {ignored}, answered {answers} of {sent}");
    assert_eq!(out.sim("client_elements_refused"), "0");
    assert_eq!(out.sim("clients_accepted"), "2");
    println!(
        "bad frames: reset burst of {sent} SDO requests: {answers} answered after the boot-up, {ignored} ignored \
         during the reset; wall {} s",
        out.master("script_s")
    );
}

/// Proves (issue 8: "a block download of at least 64 KiB to a domain object with its CRC checked"; issue 7: the
/// update over CANopen): PyPI canopen stops and clears the program (0x1F51:01 = 0, 3), writes a 96 KiB signed
/// image into the program-data domain 0x1F50:01 by SDO block download (canopen sends the block CRC, the drive's
/// server checks it: a mismatch would abort with 0x0504_0004 and the transfer would fail), starts it (0x1F51:01 =
/// 1: the drive resets without answering); the boot-up follows and 0x1F56:01 and 0x100A report the new image,
/// the program runs (0x1F51:01 = 1) and the flash status 0x1F57:01 is 0 (no error).
#[test]
fn a_96_kib_signed_image_goes_in_by_block_download_with_its_crc_and_runs_after_the_start() {
    skip_unless_runnable!("a_96_kib_signed_image_goes_in_by_block_download_with_its_crc_and_runs_after_the_start");
    use firmware::boot::program::BOOTLOADER_ID;
    use hal_sim::sim::update::{dev_seed, payload, signed_image, FACTORY_VERSION};
    let dir = WorkDir::new("update");
    let eds = write_eds(&dir);
    let version = 0x0002_0000;
    let image =
        signed_image(&payload(96 * 1024, version), version, "0.2.0", firmware::boot::image::HARDWARE_ID, &dev_seed());
    let file = dir.join("image.bin");
    std::fs::write(&file, &image).expect("write the image");
    let out = run("update.py", &["--lock-step"], &eds, &["--image".into(), path(&file)]);
    pass(&out);
    assert!(out.master_num("image_bytes") >= 65_536.0, "at least 64 KiB");
    // 0x1F56:01 (IDX L3382-3412): the application's software id in the high word, the bootloader's in the low.
    let sw_id = |version: u32| format!("0x{:08x}", version & 0xFFFF_0000 | u32::from(BOOTLOADER_ID));
    assert_eq!(out.master("sw_id_before"), sw_id(FACTORY_VERSION));
    assert_eq!(out.master("program_state_stopped"), "0", "stopped before the download");
    assert_eq!(out.master("flash_status_after_download"), "0", "the image was accepted");
    assert_eq!(out.master("start_answered"), "0", "the start resets the drive without an answer");
    assert_eq!(out.master("bootup_after_start"), "1");
    assert_eq!(out.master("sw_id_after"), sw_id(version));
    assert_eq!(out.master("version_after"), "0.2.0");
    assert_eq!(out.master("program_state_after"), "1", "the new program runs");
    assert_eq!(out.master("flash_status_after"), "0");
    println!(
        "canopen block download of {} bytes: {} s wall, simulated {} s in all; 0x1F56 {} -> {}",
        out.master("image_bytes"),
        out.master("block_download_s"),
        out.sim("simulated_s"),
        out.master("sw_id_before"),
        out.master("sw_id_after")
    );
}

/// Proves (issue 19 item 1; the field trap of ros2_canopen#421, a CiA 402 start-up blocked by a de-energised STO
/// input): with PyPI canopen against `drive-sim canopen --lock-step --sto-open 1` (both STO inputs de-energised
/// from power-up), after a reset node the boot-up 0x701 [0x00] arrives followed by an EMCY 0xFFA0; in
/// PRE-OPERATIONAL SDO reads 0x1000 (the device type), the statusword 0x4040 («Switch on disabled», bit 14 Safe
/// Torque Off), 0x603F = 0xFFA0 and 0x1001 = 0; after NMT Start the heartbeat reports OPERATIONAL (0x05); and
/// «Shutdown», «Switch on», «Enable operation» written by SDO each leave the statusword at 0x4240 (bit 9 remote in
/// OPERATIONAL): enabling is refused with the reason visible.
#[test]
fn canopen_with_sto_low_at_power_up_reaches_operational_and_enabling_is_refused() {
    skip_unless_runnable!("canopen_with_sto_low_at_power_up_reaches_operational_and_enabling_is_refused");
    let dir = WorkDir::new("sto");
    let eds = write_eds(&dir);
    let out = run("sto.py", &["--lock-step", "--sto-open", "1"], &eds, &[]);
    pass(&out);
    assert_eq!(out.master("bootup"), "701:00");
    let code = FaultId::SafeTorqueOff.info().code;
    assert!(
        out.master("emcy_codes").split(' ').any(|c| c == format!("{code:04x}")),
        "EMCY {code:04x} after the boot-up\n{}",
        out.text
    );
    let device_type = format!("0x{:08x}", drive_tests::real_master::default_u32(&Dictionary::new(1), 0x1000, 0));
    assert_eq!(out.master("device_type"), device_type);
    assert_eq!(out.master("statusword_preop"), "0x4040");
    assert_eq!(out.master("error_code_preop"), format!("0x{code:04x}"));
    assert_eq!(out.master("error_register_preop"), "0x00");
    assert_eq!(out.master("hb_after_start"), "05", "heartbeat OPERATIONAL\n{}", out.text);
    for cw in ["0006", "0007", "000f"] {
        assert_eq!(out.master(&format!("statusword_after_{cw}")), "0x4240", "after controlword {cw}\n{}", out.text);
    }
    assert_eq!(out.master("error_code_end"), format!("0x{code:04x}"));
    assert_eq!(out.sim("node1_nmt"), "Operational");
}

/// Proves (CiA 305 §6.3, §6.7; issue 21, item 4): PyPI canopen's LSS master finds three drives that start without
/// a node-ID (`drive-sim canopen --unconfigured 1..3`, 0x2000 = 0xFF as from a factory) one by one with its
/// fastscan, each with the identity of device.toml and its own serial number (the factory value + slot - 1),
/// configures node-IDs 5, 6 and 7 and stores them; each boots with its node-ID when switched back to waiting; a
/// fourth fastscan finds nobody; after an NMT reset node to all, the three restart from their parameter stores and
/// boot as 5, 6 and 7, and each answers SDO with its serial number; then (§6.4.3) each is given 250 kbit/s and
/// the master activates it for all with a 5 ms switch delay: each answers SDO at the new rate with 0x200A = 3.
#[test]
fn pypi_canopen_lss_master_assigns_node_ids_5_6_7_to_three_unconfigured_drives() {
    skip_unless_runnable!("pypi_canopen_lss_master_assigns_node_ids_5_6_7_to_three_unconfigured_drives");
    let dir = WorkDir::new("lss");
    let eds = write_eds(&dir);
    let sim_args = ["--lock-step", "--nodes", "3", "--unconfigured", "1", "--unconfigured", "2", "--unconfigured", "3"];
    let out = run("lss.py", &sim_args, &eds, &[]);
    pass(&out);
    let d = Dictionary::new(1);
    let id = |sub| drive_tests::real_master::default_u32(&d, 0x1018, sub);
    let mut serials = Vec::new();
    for node in [5, 6, 7] {
        assert_eq!(out.master(&format!("configured_{node}")), "True");
        assert_eq!(out.master(&format!("bootup_{node}")), "True");
        let found: Vec<u32> = out
            .master(&format!("fastscan_{node}"))
            .split(':')
            .map(|p| u32::from_str_radix(p, 16).expect("hex"))
            .collect();
        assert_eq!(found[..3], [id(1), id(2), id(3)], "vendor, product, revision found for {node}");
        assert_eq!(
            out.master(&format!("serial_{node}")),
            format!("{:08x}", found[3]),
            "node {node} is the drive found"
        );
        serials.push(found[3]);
    }
    serials.sort_unstable();
    let base = id(4);
    assert_eq!(serials, [base, base + 1, base + 2], "the three drives' serial numbers");
    assert_eq!(out.master("fastscan_after"), "False");
    assert_eq!(out.master("booted_after_reset"), "5,6,7");
    for node in [5, 6, 7] {
        // CiA 305 §6.4.3: 250 kbit/s (0x200A code 3) in use after the activation, answered at that rate.
        assert_eq!(out.master(&format!("bit_rate_code_{node}")), "3", "0x200A of node {node}");
    }
    assert_eq!(out.sim("bus_bit_rate"), "250000", "the simulated bus after every drive switched");
    println!("LSS: fastscan assigned 5, 6, 7 (serials {serials:08x?}); all three booted with them after reset node");
}
