//! `drive-sim canopen`: simulated drives as CANopen nodes on one simulated CAN bus, served to python-can tools
//! (PyPI `canopen`) through the socketcand protocol on 127.0.0.1 (hal-sim `sim::canopen`, `can::socketcand`).
//!
//! ```text
//! drive-sim canopen --port N [--nodes K] [--bit-rate BPS] [--lock-step] [--sync-us N] [--seconds S]
//!                   [--idle-exit-ms N] [--seed N] [--no-image ID]... [--sto-open ID]... [--plant FILE]
//! ```
//! `--plant FILE` puts every node on the plant of a plant file (`hal_sim::plant::file`) with its motor data
//! written from the plant's ratings; without it, the reference plant.
//! `--port 0` picks a free port; the chosen one is printed as `port=N` before anything else, so a test can read
//! it. It runs until `--seconds` of wall time, or until `--idle-exit-ms` without a client frame once a client
//! had connected and left, and then prints its figures as `key=value` lines.
//!
//! `--no-image ID` (repeatable, 1..=K) erases slot A of node ID before its first boot: the bootloader finds no
//! valid image and serves its CAN fallback on that node-ID (boot-up, program control 0x1F50/0x1F51/0x1F56/0x1F57,
//! device type 0x0000012E), through which a master loads a signed image and starts it (issue 7, item 4).
//!
//! `--sto-open ID` (repeatable, 1..=K) de-energises both Safe Torque Off inputs of node ID's plant before its first
//! period, for the whole run: the drive starts with STO active (issue 19 item 1; EPOS4 AN ch. 9).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use hal_sim::can::socketcand::SocketcandServer;
use hal_sim::plant::PlantParams;
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner};

const USAGE: &str = "usage: drive-sim canopen --port N [--nodes K] [--bit-rate BPS] [--lock-step] [--sync-us N] \
                     [--seconds S] [--idle-exit-ms N] [--seed N] [--no-image ID]... [--sto-open ID]... [--plant FILE]";

struct Args {
    port: u16,
    config: CanopenConfig,
    seconds: Option<f64>,
    idle_exit_ms: Option<u64>,
    /// Node-IDs whose STO inputs are de-energised from power-up.
    sto_open: Vec<u8>,
    /// `--plant FILE`: every node's plant.
    plant: PlantParams,
}

fn parse(args: &[String]) -> Result<Args, String> {
    let mut out = Args {
        port: 0,
        config: CanopenConfig::default(),
        seconds: None,
        idle_exit_ms: None,
        sto_open: Vec::new(),
        plant: PlantParams::reference(),
    };
    let mut port = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().cloned().ok_or_else(|| format!("{name} needs a value\n{USAGE}"));
        match a.as_str() {
            "--port" => port = Some(value("--port")?.parse().map_err(|e| format!("--port: {e}"))?),
            "--nodes" => {
                let n: u8 = value("--nodes")?.parse().map_err(|e| format!("--nodes: {e}"))?;
                if !(1..=127).contains(&n) {
                    return Err(format!("--nodes {n}: 1..=127 (node-IDs 1..=K)"));
                }
                out.config.nodes = n;
            }
            "--bit-rate" => {
                out.config.bit_rate = value("--bit-rate")?.parse().map_err(|e| format!("--bit-rate: {e}"))?;
                if out.config.bit_rate == 0 || out.config.bit_rate > 1_000_000 {
                    return Err(format!("--bit-rate {}: 1..=1000000 bit/s", out.config.bit_rate));
                }
            }
            "--lock-step" => out.config.clock = CanClock::LockStep,
            "--sync-us" => {
                let us: u64 = value("--sync-us")?.parse().map_err(|e| format!("--sync-us: {e}"))?;
                if us == 0 {
                    return Err("--sync-us must be above 0".into());
                }
                out.config.sync_period_ns = us * 1_000;
            }
            "--seconds" => out.seconds = Some(value("--seconds")?.parse().map_err(|e| format!("--seconds: {e}"))?),
            "--idle-exit-ms" => {
                out.idle_exit_ms = Some(value("--idle-exit-ms")?.parse().map_err(|e| format!("--idle-exit-ms: {e}"))?);
            }
            "--plant" => {
                out.plant =
                    PlantParams::from_toml_file(std::path::Path::new(&value("--plant")?)).map_err(|e| e.to_string())?;
            }
            "--seed" => out.config.seed = value("--seed")?.parse().map_err(|e| format!("--seed: {e}"))?,
            "--no-image" => {
                let id: u8 = value("--no-image")?.parse().map_err(|e| format!("--no-image: {e}"))?;
                if !(1..=127).contains(&id) {
                    return Err(format!("--no-image {id}: a node-ID 1..=127"));
                }
                out.config = out.config.with_empty_slot(id);
            }
            "--sto-open" => {
                let id: u8 = value("--sto-open")?.parse().map_err(|e| format!("--sto-open: {e}"))?;
                if !(1..=127).contains(&id) {
                    return Err(format!("--sto-open {id}: a node-ID 1..=127"));
                }
                out.sto_open.push(id);
            }
            other => return Err(format!("unknown argument {other}\n{USAGE}")),
        }
    }
    out.port = port.ok_or_else(|| format!("--port is required\n{USAGE}"))?;
    if let Some(id) = (1..=127u8).find(|&id| out.config.empty_slot(id) && id > out.config.nodes) {
        return Err(format!("--no-image {id}: only node-IDs 1..={} are on the bus", out.config.nodes));
    }
    if let Some(id) = out.sto_open.iter().find(|&&id| id > out.config.nodes) {
        return Err(format!("--sto-open {id}: only node-IDs 1..={} are on the bus", out.config.nodes));
    }
    Ok(out)
}

/// Runs the scenario with the arguments after `canopen`.
pub fn run(args: &[String]) -> Result<(), String> {
    let args = parse(args)?;
    let addr = SocketAddr::from(([127, 0, 0, 1], args.port));
    let mut server = SocketcandServer::bind(addr).map_err(|e| format!("listen on {addr}: {e}"))?;
    let local = server.local_addr().map_err(|e| e.to_string())?;
    println!("port={}", local.port());
    println!(
        "drive-sim canopen: {} drive(s), node-IDs 1..={}, {} bit/s, {} clock{}; socketcand on {local}",
        args.config.nodes,
        args.config.nodes,
        args.config.bit_rate,
        match args.config.clock {
            CanClock::LockStep => "lock-step",
            CanClock::RealTime => "real-time",
        },
        if args.config.clock == CanClock::LockStep {
            format!(" ({} us per SYNC)", args.config.sync_period_ns / 1_000)
        } else {
            String::new()
        },
    );
    println!("  python: can.Bus(interface='socketcand', host='127.0.0.1', port={}, channel='can0')", local.port());
    let mut runner = CanopenRunner::with_plant(args.config, &args.plant);
    for d in runner.drives.iter().filter(|d| d.in_fallback()) {
        println!("  node {}: slot A holds no valid image ({:?}): bootloader fallback", d.node.node_id(), d.last_boot);
    }
    for &id in &args.sto_open {
        if let Some(d) = runner.drive_mut(id) {
            d.sim.plant.set_sto_inputs(firmware::hal::sto::StoInputs::DEMANDED);
            println!("  node {id}: STO-IN1 and STO-IN2 de-energised (Safe Torque Off active from power-up)");
        }
    }
    // The nodes boot before anyone connects (their boot-up messages go nowhere, as on a bus without a master).
    runner.run_for(2_000_000);
    let started = Instant::now();
    let limit = args.seconds.map(Duration::from_secs_f64);
    let idle_exit = args.idle_exit_ms.map(Duration::from_millis);
    let mut last_activity = Instant::now();
    let mut seen_client = false;
    let mut last_frames = 0;
    runner
        .serve(&mut server, Duration::from_micros(200), |r| {
            if r.stats().master_frames != last_frames {
                last_frames = r.stats().master_frames;
                last_activity = Instant::now();
                seen_client = true;
            }
            limit.is_some_and(|l| started.elapsed() >= l)
                || idle_exit.is_some_and(|i| seen_client && last_activity.elapsed() >= i)
        })
        .map_err(|e| e.to_string())?;
    report(&runner, &server);
    Ok(())
}

fn report(runner: &CanopenRunner, server: &SocketcandServer) {
    let bus = runner.bus.stats();
    let s = runner.stats();
    let srv = server.stats();
    println!("simulated_s={:.6}", runner.now_ns() as f64 * 1e-9);
    println!("bus_frames={}", bus.frames);
    println!("bus_load_pct={:.2}", runner.bus.load() * 100.0);
    println!("bus_error_frames={}", bus.error_frames);
    println!("master_frames={}", s.master_frames);
    println!("master_syncs={}", s.master_syncs);
    println!("frames_to_master={}", s.frames_to_master);
    println!("quiet_limit_hits={}", s.quiet_limit_hits);
    println!("lag_events={}", s.lag_events);
    println!("clients_accepted={}", srv.clients_accepted);
    println!("client_elements_refused={}", srv.refused);
    for d in &runner.drives {
        let id = d.node.node_id();
        // What runs on the node's port at the end: the application or the bootloader's fallback (issue 7).
        println!("node{id}_running={}", if d.in_fallback() { "fallback" } else { "application" });
        println!("node{id}_fallback_frames={}", d.fallback_frames());
        println!("node{id}_sw_id=0x{:08x}", d.program.software_identification());
        let c = d.node.counters();
        println!("node{id}_nmt={:?}", d.node.state());
        println!("node{id}_cia402={:?}", d.sim.cia402_state());
        println!("node{id}_syncs={}", c.syncs);
        println!("node{id}_syncs_missed={}", c.syncs_missed);
        println!("node{id}_ignored={}", c.ignored);
        println!("node{id}_tx_dropped={}", c.tx_dropped);
        println!("node{id}_fe_samples={}", d.following_error.samples);
        println!("node{id}_fe_peak_inc={}", d.following_error.peak_inc);
        println!("node{id}_fe_rms_inc={:.3}", d.following_error.rms_inc());
        println!(
            "node{id}_error_code=0x{:04x}",
            d.sim.drive.dictionary().get::<u16>(firmware::od::generated::handles::ERROR_CODE)
        );
    }
}
