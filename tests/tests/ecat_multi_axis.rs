//! Sixteen simulated drives on one EtherCAT line with real masters (issue 21 item 2, "What it must show"):
//! `drive-sim ethercat --slaves 16 --lock-step` on one end of a veth pair (sixteen emulated ESCs in a line, each
//! with its own drive and plant, ESC oscillator error spread over +-100 ppm and port-to-port delay:
//! `hal_sim::sim::ethercat_line`), SOEM through PyPI `pysoem` (`tests/ecat/soem_multi.py`) or ethercrab
//! (`tests/examples/ethercrab_master.rs` scenario `line`) on the other, inside a private network namespace
//! ([`drive_tests::real_master`]).
//!
//! Each master brings up all sixteen drives, configures DC with SYNC0 on every one, reaches OP, enables every
//! drive in CSP and runs one coordinated move (the motion issue's CSP case, on all drives at once) for 10,000
//! cycles at 1 ms and at 200 us. Checked, with the reasons:
//! - no cycle with a wrong working counter (the LRW's counter is 3 per drive, ETG.1000.4 §5.4: 48);
//! - every drive in «Operation enabled» (when the move starts and, for SOEM, at the end);
//! - each drive's following error within the single-drive bounds of the existing real-master CSP tests
//!   (`ecat_real_masters.rs`, `ecat_ethercrab.rs`: peak <= 30 inc, RMS <= 8 inc over the move, bit 13 never,
//!   within +-1 inc of the target after it);
//! - SYNC0 of all drives within 1 us of each other: the masters read 0x0990 (the next SYNC0 pulse, in each
//!   drive's system time) of every drive and find one value; drive-sim measures the instants (simulated time) of
//!   every cycle's SYNC0 pulses across the drives and reports the largest spread;
//! - the propagation delays the master measured (0x0928 read back) equal the line's port-to-port delays summed,
//!   within 10 ns (the masters' integer arithmetic), and the serial numbers are the sixteen distinct ones.
//!
//! Prerequisites as the other real-master tests: a test fails under `CI=true` and is a reported skip elsewhere
//! when the machine cannot make a namespace (or, for SOEM, python3 cannot import pysoem).
//!
//! The real-time measurement (issue 21: the largest N at 1 ms with 0 lost frames over 60 s) is the ignored test
//! [`real_time_largest_line_at_1ms_without_a_lost_frame`], see its documentation for the command.

use std::path::PathBuf;
use std::sync::OnceLock;

use drive_tests::prerequisite;
use drive_tests::real_master::{self, cannot_make_namespace, cannot_run_soem, root, RunOutput};
use hal_sim::sim::ethercat_line::hop_ns;

/// Drives on the line.
const SLAVES: usize = 16;

/// The ethercrab master example, built once per test process.
fn ethercrab() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        real_master::build_executable(&["-p", "drive-tests", "--example", "ethercrab_master"], "ethercrab_master")
    })
}

/// The propagation delay of slave `k` from slave 0: the port-to-port delays of the slaves before it.
fn expected_delay(k: usize) -> u64 {
    (0..k).map(hop_ns).sum()
}

/// A comma-separated list of numbers.
fn list(text: &str) -> Vec<f64> {
    text.split(',').map(|v| v.trim().parse().unwrap_or(f64::NAN)).collect()
}

/// The checks both masters share (see the module documentation).
fn check_line(out: &RunOutput, cycle_us: u64) {
    let text = &out.text;
    println!(
        "{SLAVES} drives, {cycle_us} us: following error peak {} inc, RMS {} inc (worst drive); SYNC0 spread {} ns \
         (simulated), 0x0990 spread {} ns; drive-sim {} s wall",
        out.master("fe_peak_inc_max"),
        out.master("fe_rms_inc_max"),
        out.sim("sync0_spread_max_ns"),
        out.master("sync0_start_spread_ns"),
        out.sim("wall_s"),
    );
    assert_eq!(out.master("verdict"), "pass", "the master's verdict\n{text}");
    assert_eq!(out.master("master_rc"), "0", "\n{text}");
    assert_eq!(out.master("sim_rc"), "0", "drive-sim's exit status\n{text}");
    assert_eq!(out.sim("slaves"), SLAVES.to_string());
    assert_eq!(out.sim("dropped_frames"), "0");
    // Working counters: 3 per drive for the LRW, every cycle.
    assert_eq!(out.master("expected_wkc"), (3 * SLAVES).to_string(), "ETG.1000.4: +1 read, +2 write per drive");
    // Every drive enabled in CSP before the move (the move starts once all show «Operation enabled»).
    assert!(out.master_num("enabled_at_cycle") >= 0.0, "every drive enabled\n{text}");
    assert_eq!(out.master("enabled_at_end"), SLAVES.to_string(), "every drive in «Operation enabled» at the end");
    // The single-drive bounds, for each drive.
    let peaks = list(out.master("fe_peak_inc_each"));
    let rms = list(out.master("fe_rms_inc_each"));
    assert_eq!((peaks.len(), rms.len()), (SLAVES, SLAVES), "a figure per drive");
    for (k, (p, r)) in peaks.iter().zip(&rms).enumerate() {
        assert!(*p <= 30.0, "drive {k}: following error peak {p} inc > 30\n{text}");
        assert!(*r <= 8.0, "drive {k}: following error RMS {r} inc > 8\n{text}");
    }
    assert!(out.master_num("end_error_inc_max") <= 1.0, "every drive at its target +-1 inc\n{text}");
    // SYNC0: one start time in every drive's system time (the masters' reads of 0x0990), and the pulses within
    // 1 us of each other in simulated time over every cycle (drive-sim).
    assert_eq!(out.master("sync0_start_spread_ns"), "0", "0x0990 of every drive");
    let spread = out.sim_num("sync0_spread_max_ns");
    assert!(spread <= 1_000.0, "SYNC0 pulses {spread} ns apart\n{text}");
    // Every pulse sampled: each cycle's pulses were one pulse on all drives (SOEM starts SYNC0 100 ms after
    // dc_sync, ethercrab 10 cycles after its alignment frames: at least 9,000 of the 10,000 cycles).
    assert_eq!(out.sim("sync0_samples"), out.sim("sync0_pulses_min"), "a SYNC0 sample per pulse\n{text}");
    assert!(out.sim_num("sync0_samples") >= 9_000.0, "SYNC0 over the cycles\n{text}");
    assert!(out.sim_num("system_time_spread_ns") <= 1_000.0, "system times at the end\n{text}");
    assert_eq!(out.sim("sync0_missed_total"), "0");
    assert_eq!(out.sim("sm_event_missed_total"), "0", "0x1C32:0B of every drive (drive-sim)");
    assert_eq!(out.master("sdo_sm_event_missed_total"), "0", "0x1C32:0B of every drive over SDO");
    assert_eq!(out.sim("state_reached_all"), "OP");
    // The propagation delays the master measured from the port receive times (0x0900..0x090F) and wrote to 0x0928.
    let delays = list(out.master("system_delay_ns_each"));
    assert_eq!(delays.len(), SLAVES);
    for (k, d) in delays.iter().enumerate() {
        let e = expected_delay(k) as f64;
        assert!((d - e).abs() <= 10.0, "drive {k}: delay {d} ns, the line has {e} ns\n{text}");
    }
}

/// SOEM: `soem_multi.py` against 16 drives at `cycle_us`.
fn soem_line(name: &str, cycle_us: u64) {
    if prerequisite::skip(name, cannot_run_soem()) {
        return;
    }
    let dir = root().join("tests/ecat");
    let command = format!(
        "sh -c \"cd '{}' && python3 soem_multi.py --iface ecm0 --slaves {SLAVES} --cycle-ns {} --cycles 10000\"",
        dir.display(),
        cycle_us * 1_000
    );
    let sim_args = format!("--slaves {SLAVES} --lock-step --cycle-us {cycle_us}");
    let out = real_master::run_in_namespace(name, &sim_args, &command);
    check_line(&out, cycle_us);
    assert_eq!(out.master("slaves_found"), SLAVES.to_string());
    assert_eq!(out.master("identities"), "1", "one drive type");
    let serials: Vec<String> = (1..=SLAVES).map(|k| k.to_string()).collect();
    assert_eq!(out.master("serials_sii"), serials.join(","), "SII words 0x0E/0x0F");
    assert_eq!(out.master("serials_sdo"), serials.join(","), "0x1018:04");
    assert_eq!(out.master("dc_slaves"), "1", "config_dc found the clocks");
    assert_eq!(out.master("states_after_cycles"), "OP");
    assert_eq!(out.master("bit13_seen"), "0");
    assert_eq!(out.master("wkc_errors"), "0");
    // Every cycle of the move sampled (but its first two, as the single-drive script does).
    let expected = (out.master_num("move_s") / (cycle_us as f64 * 1e-6)).floor();
    assert!((out.master_num("fe_samples") - expected).abs() <= 2.0, "following-error samples\n{}", out.text);
}

/// ethercrab: scenario `line` against 16 drives at `cycle_us`.
fn ethercrab_line(name: &str, cycle_us: u64) {
    if prerequisite::skip(name, cannot_make_namespace()) {
        return;
    }
    let command =
        format!("'{}' --iface ecm0 line --slaves {SLAVES} --sync dc --cycle-us {cycle_us}", ethercrab().display());
    let sim_args = format!("--slaves {SLAVES} --lock-step --cycle-us {cycle_us}");
    let out = real_master::run_in_namespace(name, &sim_args, &command);
    check_line(&out, cycle_us);
    assert_eq!(out.master("subdevices_found"), SLAVES.to_string());
    assert_eq!(out.master("identities"), "1", "one drive type");
    let serials: Vec<String> = (1..=SLAVES).map(|k| k.to_string()).collect();
    assert_eq!(out.master("serials"), serials.join(","), "SII serial = 0x1018:04");
    assert_eq!(out.master("move_peak_rpm"), "2449", "the motion issue's CSP move");
    assert_eq!(out.master("motion_wkc_errors"), "0");
    assert_eq!(out.master("bit13_drives"), "0");
    assert_eq!(out.master("fe_samples"), out.master("move_cycles"), "every cycle of the move sampled");
}

#[test]
fn soem_brings_up_16_drives_in_dc_and_runs_a_coordinated_csp_move_at_1ms_within_the_single_drive_bounds() {
    soem_line("soem-line-1ms", 1_000);
}

#[test]
fn soem_brings_up_16_drives_in_dc_and_runs_a_coordinated_csp_move_at_200us_within_the_single_drive_bounds() {
    soem_line("soem-line-200us", 200);
}

#[test]
fn ethercrab_brings_up_16_drives_in_dc_and_runs_a_coordinated_csp_move_at_1ms_within_the_single_drive_bounds() {
    ethercrab_line("ethercrab-line-1ms", 1_000);
}

#[test]
fn ethercrab_brings_up_16_drives_in_dc_and_runs_a_coordinated_csp_move_at_200us_within_the_single_drive_bounds() {
    ethercrab_line("ethercrab-line-200us", 200);
}

/// Real time (issue 21: "the largest N at 1 ms with 0 lost frames over 60 s"): `drive-sim ethercat --slaves N` in
/// real time (each frame answered on its own thread from the ESCs as they stand, the drives stepped towards the
/// wall clock on two worker threads: `hal_sim::sim::ethercat_line`, "Real time"), and the ethercrab master
/// (scenario `line --realtime-s 60`: DC with SYNC0 on every drive, OP, every drive enabled in CSP and moving, then
/// held; each frame sent when ethercrab's `next_cycle_wait` says, half a cycle after SYNC0). The master counts
/// a frame **lost** when it is not answered within its 1 ms cycle (late or never) or with a wrong working
/// counter, and counts separately the cycles in which its own thread woke more than half a cycle late (the
/// master's miss, not the simulator's). N runs 1, 2, 4, 6, 8, 12, 16; the largest N is the last of the unbroken
/// series that lost no frame in a cycle whose master woke on time (`lost_frames_master_on_time`) with drive-sim
/// never behind the wall clock (`lag_events_total`) and every drive in OP throughout (`not_op_frames`); it also
/// prints the largest N with no frame lost at all (`realtime_largest_n_no_frame_lost_at_all`); the test prints every run's figures (lost, late, unanswered, the master's late
/// wake-ups, drive-sim's answer times, the frames after which a drive was out of OP) and
/// `realtime_largest_n=N`, and fails below 4 (the issue's floor).
///
/// drive-sim is the release build (what runs a machine; the build takes a few minutes the first time), the
/// master the dev build of the example. Where the host permits it, both run at real-time priorities, the master
/// above drive-sim's frame path and that above its drive workers (`real_master::RealTimePriorities`), as a
/// master's cycle runs on a real machine; the test prints which. The verdict depends on the host's load, which is why it is not part of
/// the default run. Run it on a quiet machine (`REALTIME_SECONDS` shortens the runs):
///
/// ```text
/// cargo test -p drive-tests --test ecat_multi_axis -- --ignored --nocapture real_time
/// ```
#[test]
#[ignore = "a 60 s real-time measurement per N, load-dependent: run by hand (see the documentation)"]
fn real_time_largest_line_at_1ms_without_a_lost_frame() {
    if prerequisite::skip("real_time_largest_line_at_1ms_without_a_lost_frame", cannot_make_namespace()) {
        return;
    }
    let seconds: f64 = std::env::var("REALTIME_SECONDS").ok().and_then(|s| s.parse().ok()).unwrap_or(60.0);
    // The release build: real time is about the simulator's speed, and the release build is what runs a machine.
    let drive_sim = real_master::build_executable(&["-p", "hal-sim", "--bin", "drive-sim", "--release"], "drive-sim");
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("load average before the runs: {}", load.trim());
    let priorities =
        real_master::RealTimePriorities::permitted().then_some(real_master::RealTimePriorities::MEASUREMENT);
    match priorities {
        Some(p) => {
            println!("real-time priorities: master SCHED_FIFO {}, drive-sim SCHED_FIFO {}", p.master, p.simulator)
        }
        None => println!("real-time priorities: refused by this host (no CAP_SYS_NICE), the normal policy"),
    }
    let mut largest = 0;
    let mut holding = true;
    let mut largest_strict = 0;
    let mut holding_strict = true;
    for n in [1usize, 2, 4, 6, 8, 12, 16] {
        let command = format!(
            "'{}' --iface ecm0 line --slaves {n} --sync dc --cycle-us 1000 --realtime-s {seconds}",
            ethercrab().display()
        );
        let (name, sim_args) = (format!("realtime-{n}"), format!("--slaves {n}"));
        let out = match priorities {
            Some(p) => real_master::run_in_namespace_at_real_time_priority(&drive_sim, &name, &sim_args, &command, p),
            None => real_master::run_in_namespace_with(&drive_sim, &name, &sim_args, &command),
        };
        let m = |k: &str| out.master.get(k).cloned().unwrap_or_else(|| "none".into());
        let s = |k: &str| out.sim.get(k).cloned().unwrap_or_else(|| "none".into());
        println!(
            "N={n}: frames={} lost_frames={} (master on time {}, master woke late {}) late={} unanswered={} \
             wrong_wkc={} answer_max_us={} master_late_wakeups={} master_wake_late_max_us={} cycles_skipped={} \
             not_op_frames={} first_not_op_frame={} | drive-sim: answer_max_us={} answers_over_100us={} \
             answers_over_1ms={} lag_events={} sm_event_missed_total={} output_overflows_total={} \
             outputs_held_max={} simulated_s={} wall_s={}",
            m("realtime_frames"),
            m("lost_frames"),
            m("lost_frames_master_on_time"),
            m("lost_frames_master_woke_late"),
            m("late_frames"),
            m("unanswered_frames"),
            m("wrong_wkc_frames"),
            m("answer_max_us"),
            m("master_late_wakeups"),
            m("master_wake_late_max_us"),
            m("cycles_skipped"),
            m("not_op_frames"),
            m("first_not_op_frame"),
            s("answer_max_us"),
            s("answers_over_100us"),
            s("answers_over_1ms"),
            s("lag_events_total"),
            s("sm_event_missed_total"),
            s("output_overflows_total"),
            s("outputs_held_max"),
            s("simulated_s"),
            s("wall_s"),
        );
        if m("realtime_frames") == "none" {
            println!("N={n}: the master did not reach the real-time phase:\n{}", out.text);
        }
        // Every drive in OP throughout (the master saw no frame with a drive out of OP) is part of holding.
        let held = m("lost_frames_master_on_time") == "0" && s("lag_events_total") == "0" && m("not_op_frames") == "0";
        if held && holding {
            largest = n;
        }
        // The strict reading: no frame lost at all, whoever woke late.
        if held && m("lost_frames") == "0" && holding_strict {
            largest_strict = n;
        }
        holding_strict &= held && m("lost_frames") == "0";
        // Every N is run for its figures; the largest N counts only while every smaller one held too.
        holding &= held;
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("load average after the runs: {}", load.trim());
    println!("realtime_largest_n={largest}");
    println!("realtime_largest_n_no_frame_lost_at_all={largest_strict}");
    assert!(largest >= 4, "the largest line that holds 1 ms in real time: {largest} drives");
}
