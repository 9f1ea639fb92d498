//! `drive-tool`: the command-line tool a machine builder commissions a drive with over CANopen or EtherCAT: finds the drives
//! (`scan`, `info`), reads and writes objects by index or name with their types (`get`, `set`), saves and
//! loads parameter sets as CiA 306 DCF files (`params`), reads the error history (`faults`, `fault reset`) and
//! makes a first move of an axis (`enable`, `disable`, `jog`, `move`), and records traces with the drive's data
//! recorder (`record`: CSV and SVG).
//!
//! Links: `--socketcand HOST:PORT` (the simulator, `drive-sim canopen`), `--can IFACE` (Linux SocketCAN) or
//! `--ecat IFACE` (EtherCAT through a raw socket: `drive-sim ethercat` on one end of a veth pair, or a real
//! segment; CoE SDO and FoE through the mailbox).
//! The dictionary is the project's EDS, embedded, or `--eds FILE`.

/// `println!` that does not panic when stdout is gone (`drive-tool list | head`): the output is lost, the
/// command finishes what it does on the drive (stopping half-way through a parameter load or a move would be
/// worse).
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

mod abort_text;
mod bus;
mod cia402;
mod commands;
mod context;
mod dcf;
#[cfg(target_os = "linux")]
mod ecat;
mod eds;
mod link;
/// The SVG line plots of `record`: hal-sim's dependency-free plot writer (`hal-sim/src/sim/plot.rs`), compiled
/// into this tool from its one source rather than pulling the simulator in as a dependency.
#[path = "../../hal-sim/src/sim/plot.rs"]
#[allow(dead_code, reason = "the tool draws plain line plots: no markers, log axis or reference lines")]
mod plot;
mod project;
mod sdo;
#[cfg(target_os = "linux")]
mod socketcan_if;
mod socketcand;
mod value;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};

use crate::context::Context;
use crate::eds::Dictionary;
use crate::link::{CanopenLink, DriveLink};

/// Commissioning tool for the drive over CANopen and EtherCAT.
#[derive(Parser, Debug)]
#[command(name = "drive-tool", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(flatten)]
    link: LinkArgs,
    #[command(subcommand)]
    command: Command,
}

/// How to reach the drives and what dictionary to use.
#[derive(Args, Debug)]
struct LinkArgs {
    /// The simulator (or a socketcand daemon): `drive-sim canopen --port N` serves it on 127.0.0.1:N.
    #[arg(long, global = true, value_name = "HOST:PORT")]
    socketcand: Option<String>,
    /// The socketcand bus to open.
    #[arg(long, global = true, value_name = "BUS", default_value = "can0")]
    socketcand_bus: String,
    /// A Linux SocketCAN interface (can0, vcan0, ...).
    #[arg(long, global = true, value_name = "IFACE")]
    can: Option<String>,
    /// An EtherCAT segment through a raw socket on this interface (root or CAP_NET_RAW): the drives are
    /// addressed by position (`--node 1` is the first) or `--station`.
    #[arg(long, global = true, value_name = "IFACE")]
    ecat: Option<String>,
    /// Node-ID of the drive (CANopen), or its position on the segment, 1 for the first (EtherCAT).
    #[arg(long, short, global = true, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=127))]
    node: u8,
    /// EtherCAT: the drive with this configured station address or alias (the tool assigns 0x1000 to the first
    /// drive, 0x1001 to the second, ...) instead of `--node`.
    #[arg(long, global = true, value_name = "ADDR", value_parser = parse_station)]
    station: Option<u16>,
    /// The drive's EDS (or a DCF) instead of the project's embedded EDS.
    #[arg(long, global = true, value_name = "FILE")]
    eds: Option<PathBuf>,
    /// How long to wait for each SDO answer, ms.
    #[arg(
        long,
        global = true,
        value_name = "MS",
        default_value_t = 1000,
        value_parser = clap::value_parser!(u64).range(1..=60_000)
    )]
    sdo_timeout_ms: u64,
    /// Transfer every object by SDO block transfer (CiA 301 §7.2.4.3.9..16, with CRC) instead of expedited
    /// and segmented transfers.
    #[arg(long, global = true)]
    sdo_block: bool,
    /// Print JSON for a script instead of text.
    #[arg(long, global = true)]
    json: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Find the drives on the bus (node-IDs 1..127): identity, firmware version, NMT and CiA 402 state.
    Scan {
        /// How long to wait for answers to the scan's requests, ms.
        #[arg(long, value_name = "MS", default_value_t = 300)]
        wait_ms: u64,
    },
    /// Identity, versions and state of one drive (`--node`).
    Info,
    /// List the dictionary (the EDS, no drive needed): index:sub, name, type, access, default, whether 0x1010
    /// saves it.
    List {
        /// Only entries whose name or index contains this text (case-insensitive).
        #[arg(value_name = "FILTER")]
        filter: Option<String>,
    },
    /// Read objects: `0x6041`, `0x1018:01`, or a name from the EDS (`statusword`); an object with
    /// sub-indices is read whole.
    Get {
        /// Objects to read.
        #[arg(required = true, value_name = "OBJ")]
        objects: Vec<String>,
        /// EtherCAT: read each whole object in one CoE complete access (ETG.1000.6 §5.6.2.1.2) instead of sub-index
        /// by sub-index; give whole objects (`0x1018`).
        #[arg(long)]
        complete: bool,
    },
    /// Write one object; the value is checked against its type and EDS limits before anything is sent.
    Set {
        /// The object: `0x6060`, `0x3001:02`, or a name.
        #[arg(value_name = "OBJ")]
        object: String,
        /// The value: integers decimal, 0x hex or 0b binary; true/false; a REAL32 as 1.5; a string as it is;
        /// OCTET_STRING/DOMAIN as hex.
        #[arg(value_name = "VALUE", allow_hyphen_values = true)]
        value: String,
    },
    /// Change the NMT state: start (OPERATIONAL), stop, preop, reset (the node restarts with its stored
    /// parameters) or reset-comm; a reset waits for the boot-up.
    Nmt {
        /// The command.
        #[arg(value_enum)]
        command: crate::link::StateCommand,
        /// To every node (node-ID 0 in the NMT frame) rather than `--node`.
        #[arg(long)]
        all: bool,
    },
    /// Save or load the drive's parameters as a CiA 306 DCF.
    #[command(subcommand)]
    Params(ParamsCommand),
    /// The error history 0x1003 with the fault table's texts, the error code 0x603F and register 0x1001.
    Faults,
    /// Act on the drive's fault state.
    #[command(subcommand)]
    Fault(FaultCommand),
    /// Take the drive to «Operation enabled» (CiA 402: Shutdown, Switch on, Enable operation).
    Enable,
    /// Take the power stage off: «Shutdown» (to «Ready to switch on»).
    Disable,
    /// Turn the axis in profile velocity mode (0x6060 = 3) for a while, then halt and disable.
    Jog {
        /// Target velocity 0x60FF, in the drive's velocity unit (rpm here).
        #[arg(long, allow_hyphen_values = true)]
        velocity: i32,
        /// How long to turn, seconds.
        #[arg(long, default_value_t = 1.0)]
        seconds: f64,
    },
    /// Move the axis in profile position mode (0x6060 = 1) and wait for target reached (statusword bit 10).
    Move {
        /// Target position 0x607A, in the drive's position unit (increments here).
        #[arg(value_name = "TARGET", allow_hyphen_values = true)]
        target: i32,
        /// The target is relative to the present target (controlword bit 6).
        #[arg(long)]
        relative: bool,
        /// Profile velocity 0x6081 for this move (rpm here); the drive's setting when left out.
        #[arg(long)]
        velocity: Option<u32>,
        /// Longest wait for target reached, seconds.
        #[arg(long, default_value_t = 30.0)]
        timeout_s: f64,
        /// Leave the drive enabled after the move (it is disabled otherwise).
        #[arg(long)]
        stay_enabled: bool,
    },
    /// Identify the motor (0x6060 = -2: resistance, inductances, torque constant, pole pairs, commutation,
    /// inertia, friction, the load's resonance) and tune the gains, following the drive's progress; report what it
    /// found.
    Identify {
        /// Give up after this long, seconds.
        #[arg(long, default_value_t = 120.0)]
        timeout_s: f64,
        /// Pause between two progress polls, ms.
        #[arg(long, default_value_t = 20)]
        poll_ms: u64,
        /// Afterwards write "save" to 0x1010:01 so that the drive keeps what it found.
        #[arg(long)]
        store: bool,
    },
    /// Compute the gains from the motor data as it stands (0x3205:01 = 1), power stage off.
    Tune {
        /// Velocity/position crossover in per mille of the reference's (0x3205:02).
        #[arg(long, value_name = "PERMILLE")]
        stiffness: Option<u16>,
    },
    /// Layer setting services (CiA 305) for drives without a node-ID.
    #[command(subcommand)]
    Lss(LssCommand),
    /// The data recorder (0x3300..0x3302): configure up to 8 channels, the sampling divider and the trigger with
    /// its preceding samples, arm, wait for the recording, upload it by SDO block transfer and write a CSV file
    /// and an SVG plot; `--no-wait` arms only, `--fetch` uploads a recording armed earlier.
    Record(commands::record::RecordArgs),
    /// Install a signed firmware image and read the new version back after the restart. CANopen: program control
    /// (0x1F51 stop/clear, 0x1F50 block download with its CRC, start); a refusal shows the SDO abort and flash
    /// status 0x1F57. EtherCAT: FoE in BOOT (INIT, BOOT, FoE write, INIT); a refusal shows the FoE error code and
    /// the drive's text. The old firmware keeps running after a refusal.
    Update {
        /// The signed image (`drive-image pack`).
        #[arg(value_name = "IMAGE")]
        image: PathBuf,
        /// CANopen: download and verify only; do not start it (0x1F51:01 = 1 later starts it).
        #[arg(long)]
        no_start: bool,
    },
    /// Print the shell completion script (e.g. `drive-tool completions bash > /etc/bash_completion.d/drive-tool`).
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
}

#[derive(Subcommand, Debug)]
enum ParamsCommand {
    /// Upload every readable, persistent parameter and write them as a DCF.
    Save {
        /// The DCF to write.
        file: PathBuf,
    },
    /// Read a DCF, show what differs from the drive (old -> new) and write the changed values.
    Load {
        /// The DCF to read.
        file: PathBuf,
        /// Afterwards write "save" to 0x1010:01 so that the drive keeps the values over a restart.
        #[arg(long)]
        store: bool,
        /// Load a DCF made for another device (0x1018 vendor/product differ).
        #[arg(long)]
        force: bool,
        /// Show the differences only; write nothing.
        #[arg(long)]
        dry_run: bool,
    },
}

#[derive(Subcommand, Debug)]
enum LssCommand {
    /// Find the drives without a node-ID one by one (LSS fastscan) and give them FIRST, FIRST+1, ...; each is
    /// stored and boots with its node-ID.
    Assign {
        /// The first node-ID to give.
        #[arg(long, value_name = "FIRST", value_parser = clap::value_parser!(u8).range(1..=127))]
        from: u8,
        /// At most this many drives (all that answer when left out).
        #[arg(long, value_name = "N")]
        count: Option<u8>,
        /// Do not store the node-IDs: they are lost at the drives' next restart.
        #[arg(long)]
        no_store: bool,
        /// How long to wait for an LSS answer, ms (a fastscan probe nobody answers costs this much).
        #[arg(long, value_name = "MS", default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
        wait_ms: u64,
    },
}

#[derive(Subcommand, Debug)]
enum FaultCommand {
    /// Fault reset: controlword bit 7 rising edge, then the state it leaves.
    Reset,
}

/// `--station 0x1001` or `--station 4097`.
fn parse_station(text: &str) -> Result<u16, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse(),
    };
    parsed.map_err(|e| format!("{text}: a station address 0..=0xFFFF ({e})"))
}

fn open_link(args: &LinkArgs) -> Result<Box<dyn DriveLink>, String> {
    let timeout = Duration::from_millis(args.sdo_timeout_ms);
    let block = args.sdo_block;
    let given = [args.socketcand.is_some(), args.can.is_some(), args.ecat.is_some()].iter().filter(|&&g| g).count();
    if given > 1 {
        return Err("--socketcand, --can and --ecat: give one link, not several".into());
    }
    if args.sdo_block && args.ecat.is_some() {
        return Err(
            "--sdo-block: CoE has no block transfer (ETG.1000.6); over EtherCAT large values go segmented".into()
        );
    }
    if args.station.is_some() && args.ecat.is_none() {
        return Err("--station addresses an EtherCAT drive (with --ecat IFACE); on CANopen give --node".into());
    }
    match (&args.socketcand, &args.can, &args.ecat) {
        (Some(address), _, _) => {
            let bus = socketcand::Socketcand::connect(address, &args.socketcand_bus)?;
            Ok(Box::new(CanopenLink::new(Box::new(bus), timeout, block)))
        }
        (None, Some(iface), _) => open_socketcan(iface, timeout, block),
        (None, None, Some(iface)) => open_ecat(iface, timeout),
        (None, None, None) => Err("no link: give --socketcand HOST:PORT (the simulator), --can IFACE (SocketCAN) \
                                   or --ecat IFACE (EtherCAT)"
            .into()),
    }
}

/// How long `--ecat` waits for a first answer on the segment (a simulator that is still starting).
const ECAT_FIRST_ANSWER: Duration = Duration::from_secs(2);

#[cfg(target_os = "linux")]
fn open_ecat(iface: &str, timeout: Duration) -> Result<Box<dyn DriveLink>, String> {
    Ok(Box::new(ecat::EcatLink::open(iface, timeout, ECAT_FIRST_ANSWER)?))
}

#[cfg(not(target_os = "linux"))]
fn open_ecat(iface: &str, _timeout: Duration) -> Result<Box<dyn DriveLink>, String> {
    let _ = ECAT_FIRST_ANSWER;
    Err(format!("--ecat {iface}: the raw-socket EtherCAT link exists on Linux only"))
}

#[cfg(target_os = "linux")]
fn open_socketcan(iface: &str, timeout: Duration, block: bool) -> Result<Box<dyn DriveLink>, String> {
    let bus = socketcan_if::SocketCan::open(iface)?;
    Ok(Box::new(CanopenLink::new(Box::new(bus), timeout, block)))
}

#[cfg(not(target_os = "linux"))]
fn open_socketcan(iface: &str, _timeout: Duration, _block: bool) -> Result<Box<dyn DriveLink>, String> {
    Err(format!("--can {iface}: SocketCAN exists on Linux only"))
}

/// The position of the EtherCAT drive with station address (or alias) `station`.
#[cfg(target_os = "linux")]
fn station_position(link: &mut dyn DriveLink, station: u16) -> Result<u8, String> {
    match link.ecat() {
        Some(ecat) => ecat.position_of_station(station),
        None => Err("--station needs --ecat".into()),
    }
}

#[cfg(not(target_os = "linux"))]
fn station_position(_link: &mut dyn DriveLink, _station: u16) -> Result<u8, String> {
    Err("--station needs --ecat".into())
}

fn dictionary(args: &LinkArgs) -> Result<Dictionary, String> {
    match &args.eds {
        None => Ok(Dictionary::project()),
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|e| format!("--eds {}: {e}", path.display()))?;
            Dictionary::parse(&text).map_err(|e| format!("--eds {}: {e}", path.display()))
        }
    }
}

fn run(cli: Cli) -> Result<(), String> {
    if let Command::Completions { shell } = cli.command {
        clap_complete::generate(
            shell,
            &mut <Cli as clap::CommandFactory>::command(),
            "drive-tool",
            &mut std::io::stdout(),
        );
        return Ok(());
    }
    let dict = dictionary(&cli.link)?;
    if let Command::List { filter } = &cli.command {
        return commands::list::list(&dict, filter.as_deref(), cli.link.json);
    }
    // A value to write is checked before the bus is opened: nothing is sent for a value the drive would refuse.
    if let Command::Set { object, value } = &cli.command {
        commands::object::checked_value(&dict, cli.link.node, object, value)?;
    }
    let mut link = open_link(&cli.link)?;
    let node = match cli.link.station {
        Some(station) => station_position(link.as_mut(), station)?,
        None => cli.link.node,
    };
    let mut cx = Context::new(link, dict, node, cli.link.json);
    match cli.command {
        Command::Scan { wait_ms } => commands::scan::scan(&mut cx, Duration::from_millis(wait_ms)),
        Command::Info => commands::scan::info(&mut cx),
        Command::List { .. } | Command::Completions { .. } => Ok(()),
        Command::Get { objects, complete } => commands::object::get(&mut cx, &objects, complete),
        Command::Set { object, value } => commands::object::set(&mut cx, &object, &value),
        Command::Params(ParamsCommand::Save { file }) => commands::params::save(&mut cx, &file),
        Command::Params(ParamsCommand::Load { file, store, force, dry_run }) => {
            commands::params::load(&mut cx, &file, commands::params::LoadOptions { store, force, dry_run })
        }
        Command::Nmt { command, all } => commands::nmt::nmt(&mut cx, command, all),
        Command::Faults => commands::faults::faults(&mut cx),
        Command::Fault(FaultCommand::Reset) => commands::faults::reset(&mut cx),
        Command::Enable => commands::motion::enable_command(&mut cx),
        Command::Disable => commands::motion::disable_command(&mut cx),
        Command::Jog { velocity, seconds } => commands::motion::jog(&mut cx, velocity, seconds),
        Command::Identify { timeout_s, poll_ms, store } => {
            if !(1.0..=3600.0).contains(&timeout_s) {
                return Err(format!("--timeout-s {timeout_s}: 1..=3600"));
            }
            commands::identify::identify(
                &mut cx,
                Duration::from_secs_f64(timeout_s),
                Duration::from_millis(poll_ms),
                store,
            )
        }
        Command::Tune { stiffness } => commands::identify::tune(&mut cx, stiffness),
        Command::Lss(LssCommand::Assign { from, count, no_store, wait_ms }) => {
            commands::lss::assign(&mut cx, from, count, !no_store, Duration::from_millis(wait_ms))
        }
        Command::Record(args) => commands::record::record(&mut cx, &args),
        Command::Update { image, no_start } => commands::update::update(&mut cx, &image, !no_start),
        Command::Move { target, relative, velocity, timeout_s, stay_enabled } => commands::motion::move_to(
            &mut cx,
            commands::motion::MoveArgs { target, relative, velocity, timeout_s, stay_enabled },
        ),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("drive-tool: error: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn completions_know_the_commands_and_options() {
        let mut script = Vec::new();
        clap_complete::generate(clap_complete::Shell::Bash, &mut Cli::command(), "drive-tool", &mut script);
        let script = String::from_utf8(script).expect("text");
        for word in ["scan", "params", "--socketcand", "--sdo-block"] {
            assert!(script.contains(word), "{word}");
        }
    }

    #[test]
    fn a_bad_option_is_named() {
        let err = Cli::try_parse_from(["drive-tool", "get", "0x6041", "--node", "200"]).unwrap_err().to_string();
        assert!(err.contains("--node"), "{err}");
    }
}
