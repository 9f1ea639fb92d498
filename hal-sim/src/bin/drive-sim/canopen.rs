//! `drive-sim canopen`: simulated drives as CANopen nodes on one simulated CAN bus, served to python-can tools
//! (PyPI `canopen`) through the socketcand protocol on 127.0.0.1 (hal-sim `sim::canopen`, `can::socketcand`).
//!
//! `drive-sim canopen --help` lists the options.
//!
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

use crate::cli::{parse_seconds, Common};

/// canopen's options.
#[derive(Debug, clap::Args)]
pub struct CanopenArgs {
    /// The plant and the seed (drive k uses seed + k).
    #[command(flatten)]
    pub common: Common,
    /// The TCP port of the socketcand server on 127.0.0.1; 0 picks a free one (printed as `port=N` first).
    #[arg(long, value_name = "N", required = true)]
    pub port: u16,
    /// Drives on the bus, node-IDs 1..=K.
    #[arg(long, value_name = "K", default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=127))]
    pub nodes: u8,
    /// The bus's bit rate, bit/s (1..=1000000): frame times and the bus load.
    #[arg(long, value_name = "BPS", default_value_t = 1_000_000,
          value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub bit_rate: u32,
    /// Simulated time advances by --sync-us per SYNC of the master instead of with the wall clock.
    #[arg(long)]
    pub lock_step: bool,
    /// The SYNC period in lock-step, microseconds.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub sync_us: Option<u64>,
    /// Stop after S seconds of wall-clock time (without it, run until stopped).
    #[arg(long, value_name = "S", value_parser = parse_seconds, allow_negative_numbers = true)]
    pub seconds: Option<f64>,
    /// Stop once a client that had connected sent no frame for N ms.
    #[arg(long, value_name = "N")]
    pub idle_exit_ms: Option<u64>,
    /// Erase slot A of node ID before its first boot: its bootloader serves the CAN fallback (repeatable).
    #[arg(long, value_name = "ID", value_parser = clap::value_parser!(u8).range(1..=127))]
    pub no_image: Vec<u8>,
    /// De-energise both Safe Torque Off inputs of node ID from power-up, for the whole run (repeatable).
    #[arg(long, value_name = "ID", value_parser = clap::value_parser!(u8).range(1..=127))]
    pub sto_open: Vec<u8>,
    /// Start the drive in slot SLOT without a node-ID (0x2000 = 0xFF saved, as from a factory): it waits silent
    /// until an LSS master (CiA 305) gives it one (repeatable).
    #[arg(long, value_name = "SLOT", value_parser = clap::value_parser!(u8).range(1..=127))]
    pub unconfigured: Vec<u8>,
    /// Write node 1's own trace to FILE: every current-loop period `period,iq_ma,iq_ref_ma,iq_plant_ma` (tier 1's
    /// measured q current and its reference, rounded to mA, and the plant's true q current): the reference for a
    /// recording of the drive's data recorder (`drive-tool record`).
    #[arg(long, value_name = "FILE")]
    pub trace: Option<std::path::PathBuf>,
}

impl CanopenArgs {
    /// The runner's settings; an error names a node-ID option that points past the bus.
    pub fn config(&self) -> Result<CanopenConfig, String> {
        let mut config = CanopenConfig {
            nodes: self.nodes,
            bit_rate: self.bit_rate,
            seed: self.common.seed,
            ..CanopenConfig::default()
        };
        if self.lock_step {
            config.clock = CanClock::LockStep;
        }
        if let Some(us) = self.sync_us {
            config.sync_period_ns = us.saturating_mul(1_000);
        }
        let options =
            [("--no-image", &self.no_image), ("--sto-open", &self.sto_open), ("--unconfigured", &self.unconfigured)];
        for (option, ids) in options {
            if let Some(id) = ids.iter().find(|&&id| id > self.nodes) {
                return Err(format!("{option} {id}: only node-IDs 1..={} are on the bus", self.nodes));
            }
        }
        for &id in &self.no_image {
            config = config.with_empty_slot(id);
        }
        for &slot in &self.unconfigured {
            config = config.with_unconfigured(slot);
        }
        Ok(config)
    }
}

/// Serves the drives of `config` (from [`CanopenArgs::config`]) as `args` say.
pub fn run(args: &CanopenArgs, config: CanopenConfig) -> Result<(), String> {
    let plant = args.common.plant.as_ref().map_or_else(PlantParams::reference, |p| p.params.clone());
    let addr = SocketAddr::from(([127, 0, 0, 1], args.port));
    let mut server = SocketcandServer::bind(addr).map_err(|e| format!("listen on {addr}: {e}"))?;
    let local = server.local_addr().map_err(|e| e.to_string())?;
    println!("port={}", local.port());
    println!(
        "drive-sim canopen: {} drive(s), node-IDs 1..={}, {} bit/s, {} clock{}; socketcand on {local}",
        config.nodes,
        config.nodes,
        config.bit_rate,
        match config.clock {
            CanClock::LockStep => "lock-step",
            CanClock::RealTime => "real-time",
        },
        if config.clock == CanClock::LockStep {
            format!(" ({} us per SYNC)", config.sync_period_ns / 1_000)
        } else {
            String::new()
        },
    );
    println!("  python: can.Bus(interface='socketcand', host='127.0.0.1', port={}, channel='can0')", local.port());
    let mut runner = CanopenRunner::with_plant(config, &plant);
    for d in runner.drives.iter().filter(|d| d.in_fallback()) {
        println!("  node {}: slot A holds no valid image ({:?}): bootloader fallback", d.node.node_id(), d.last_boot);
    }
    if let (Some(path), Some(d)) = (&args.trace, runner.drive_mut(1)) {
        d.trace = Some(hal_sim::sim::current_trace::CurrentTrace::create(path)?);
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
    println!("bus_bit_rate={}", runner.bus.bit_rate());
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
