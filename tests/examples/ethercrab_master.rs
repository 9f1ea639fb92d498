//! ethercrab (the pure-Rust EtherCAT master, crates.io 0.7.1) as a real master against `drive-sim ethercat`
//! (issue 6, "What it must show"). Run by `tests/tests/ecat_ethercrab.rs` inside a private network namespace
//! (veth pair `ecm0`/`ecs0`, the simulator in lock-step on `ecs0`, this master on `ecm0`), or by hand:
//!
//! ```text
//! ethercrab_master --iface NAME <scenario> [--cycle-us N] [--sync free|sm|dc] [--deadline-s S] [--slaves N]
//!                  [--realtime-s S]
//! scenarios: identity | objects | parameters | remap | csp | watchdog | line
//! ```
//!
//! It prints one `key=value` line per figure and as its last line `verdict=pass` or `verdict=fail <reason>`;
//! the exit status is 0 or 1. Every wait is bounded: ethercrab's own timeouts ([`timeouts`]) bound each frame,
//! mailbox and state change, every loop has a cycle limit, and a deadline thread ends the process with a failing
//! verdict if a run takes longer than `--deadline-s` (default 200 s) altogether.
//!
//! The expected values come from the firmware's dictionary (`firmware::od::access::Dictionary::new(1)`, the
//! defaults od-gen generates from `firmware/device.toml`), not from copies of them.

use std::time::Duration;

use ethercrab::error::{Error, MailboxError};
use ethercrab::std::tx_rx_task;
use ethercrab::{
    EtherCrabWireRead, EtherCrabWireSized, EtherCrabWireWrite, MainDevice, MainDeviceConfig, PduStorage, SubDeviceRef,
    Timeouts,
};

#[path = "ethercrab_master/line.rs"]
mod line;
#[path = "ethercrab_master/motion.rs"]
mod motion;
#[path = "ethercrab_master/objects.rs"]
mod objects;

/// Most SubDevices a group may hold (a power of two above 1, ethercrab's storage rule); the bus has one.
const MAX_SUBDEVICES: usize = 4;
/// Largest PDU payload (ethercrab's sizing helper for a full Ethernet frame).
const MAX_PDU_DATA: usize = PduStorage::element_size(1100);
/// Frames in flight at once.
const MAX_FRAMES: usize = 16;
/// Process image of the group, bytes (the drive's largest mapping: 4 PDOs of 12 x 32 bits each way fit twice).
const PDI_LEN: usize = 256;

/// ethercrab's frame storage: split once into the TX/RX handles and the PDU loop.
static PDU_STORAGE: PduStorage<MAX_FRAMES, MAX_PDU_DATA> = PduStorage::new();

/// The master as the scenarios use it.
type Master = MainDevice<'static>;

/// A failed check: the text is the verdict's reason.
type Outcome = Result<(), String>;

/// Prints one figure.
fn emit(key: &str, value: impl std::fmt::Display) {
    println!("{key}={value}");
}

/// An ethercrab error as a verdict reason.
fn err(what: &str) -> impl Fn(Error) -> String + '_ {
    move |e| format!("{what}: {e}")
}

/// How the process-data cycle is synchronised (0x1C32:01 / 0x1C33:01, ETG.1020 §6.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sync {
    /// Free run: 0x1C32:01 = 0, 0x1C33:01 = 0.
    FreeRun,
    /// SM-synchronous: 0x1C32:01 = 1 (SM2 event), 0x1C33:01 = 0x22 (synchronous with SM2).
    Sm,
    /// DC SYNC0: 0x1C32:01 = 0x1C33:01 = 2.
    Dc,
}

impl Sync {
    /// (0x1C32:01, 0x1C33:01).
    fn sync_types(self) -> (u16, u16) {
        match self {
            Sync::FreeRun => (0, 0),
            Sync::Sm => (1, 0x22),
            Sync::Dc => (2, 2),
        }
    }
}

/// The command line.
#[derive(Debug)]
pub struct Args {
    /// Network interface (`--iface`).
    iface: String,
    /// Scenario name.
    scenario: String,
    /// Master cycle, us (`--cycle-us`; the simulator's `--cycle-us` must say the same).
    cycle_us: u64,
    /// Synchronisation (`--sync`).
    sync: Sync,
    /// Whole-run deadline, s.
    deadline_s: u64,
    /// SubDevices on the bus (`--slaves`, default 1; scenario `line` brings them all up).
    slaves: usize,
    /// Scenario `line` against a real-time simulator (`--realtime-s S`): the cycles run for S seconds, each one
    /// paced to the wall clock, and the lost and late frames are counted instead of failing the run.
    realtime_s: Option<f64>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        iface: String::new(),
        scenario: String::new(),
        cycle_us: 1_000,
        sync: Sync::Sm,
        deadline_s: 200,
        slaves: 1,
        realtime_s: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match a.as_str() {
            "--iface" => args.iface = value("--iface")?,
            "--cycle-us" => args.cycle_us = value("--cycle-us")?.parse().map_err(|e| format!("--cycle-us: {e}"))?,
            "--deadline-s" => {
                args.deadline_s = value("--deadline-s")?.parse().map_err(|e| format!("--deadline-s: {e}"))?
            }
            "--realtime-s" => {
                args.realtime_s = Some(value("--realtime-s")?.parse().map_err(|e| format!("--realtime-s: {e}"))?)
            }
            "--slaves" => args.slaves = value("--slaves")?.parse().map_err(|e| format!("--slaves: {e}"))?,
            "--sync" => {
                args.sync = match value("--sync")?.as_str() {
                    "free" => Sync::FreeRun,
                    "sm" => Sync::Sm,
                    "dc" => Sync::Dc,
                    other => return Err(format!("--sync free|sm|dc, got {other}")),
                }
            }
            s if !s.starts_with("--") && args.scenario.is_empty() => args.scenario = s.to_owned(),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if args.iface.is_empty() || args.scenario.is_empty() {
        return Err("usage: ethercrab_master --iface NAME <identity|objects|parameters|remap|csp|watchdog|line> \
                    [--cycle-us N] [--sync free|sm|dc] [--deadline-s S] [--slaves N] [--realtime-s S]"
            .to_owned());
    }
    if args.cycle_us == 0 || args.cycle_us > 100_000 {
        return Err(format!("--cycle-us {} out of 1..=100000", args.cycle_us));
    }
    Ok(args)
}

/// ethercrab's timeouts for a lock-step simulator on a veth pair: every frame is answered at once, so the
/// defaults (30 ms a PDU) leave room for a loaded 2-core machine; state changes get 5 s (the drive answers in
/// one poll), mailbox answers 1 s.
fn timeouts() -> Timeouts {
    Timeouts {
        state_transition: Duration::from_secs(5),
        pdu: Duration::from_millis(100),
        eeprom: Duration::from_millis(50),
        wait_loop_delay: Duration::from_millis(0),
        mailbox_echo: Duration::from_millis(500),
        mailbox_response: Duration::from_millis(1_000),
    }
}

/// Raw bytes of an SDO upload: ethercrab hands the payload of an expedited, normal or segmented upload to
/// [`EtherCrabWireRead::unpack_from_slice`] as it came (its `sdo_read::<T>` with a type that takes any length),
/// so the length the drive announced is checked too.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Raw(pub Vec<u8>);

impl EtherCrabWireRead for Raw {
    fn unpack_from_slice(buf: &[u8]) -> Result<Self, ethercrab_wire::WireError> {
        Ok(Raw(buf.to_vec()))
    }
}

impl EtherCrabWireSized for Raw {
    /// The largest value ethercrab may collect (the drive's longest string is far shorter).
    const PACKED_LEN: usize = 1024;
    type Buffer = [u8; 1024];
    fn buffer() -> Self::Buffer {
        [0; 1024]
    }
}

/// The CoE abort code of a failed SDO transfer (ethercrab's `MailboxError::Aborted`), or the error as text.
fn abort_code(e: &Error) -> Result<u32, String> {
    match e {
        Error::Mailbox(MailboxError::Aborted { code, .. }) => Ok(u32::from(*code)),
        other => Err(format!("not an SDO abort: {other}")),
    }
}

/// An SDO upload of `index:sub` as raw bytes.
async fn upload<S>(sd: &SubDeviceRef<'_, S>, index: u16, sub: u8) -> Result<Vec<u8>, Error>
where
    S: std::ops::Deref<Target = ethercrab::SubDevice>,
{
    sd.sdo_read::<Raw>(index, sub).await.map(|r| r.0)
}

/// An SDO download (expedited: ethercrab 0.7.1 writes at most 4 bytes).
async fn download<S, T>(sd: &SubDeviceRef<'_, S>, index: u16, sub: u8, value: T) -> Result<(), Error>
where
    S: std::ops::Deref<Target = ethercrab::SubDevice>,
    T: EtherCrabWireWrite,
{
    sd.sdo_write(index, sub, value).await
}

/// Starts ethercrab's std raw-socket TX/RX task on `iface` on its own thread (an `async_io` executor) and returns
/// the master. `dc_iterations` is ethercrab's static drift compensation during init (its default 10,000 frames).
fn start_master(iface: &str, dc_iterations: u32) -> Result<Master, String> {
    let (tx, rx, pdu_loop) = PDU_STORAGE.try_split().map_err(|_| "PDU storage split twice".to_owned())?;
    let task = tx_rx_task(iface, tx, rx).map_err(|e| format!("open raw socket on {iface}: {e}"))?;
    std::thread::Builder::new()
        .name("tx-rx".into())
        .spawn(move || {
            if let Err(e) = async_io::block_on(task) {
                eprintln!("tx/rx task ended: {e}");
            }
        })
        .map_err(|e| format!("spawn the tx/rx thread: {e}"))?;
    Ok(MainDevice::new(
        pdu_loop,
        timeouts(),
        MainDeviceConfig { dc_static_sync_iterations: dc_iterations, ..MainDeviceConfig::default() },
    ))
}

/// Ends the process with a failing verdict after `seconds`: nothing a slave does can make the run hang.
fn arm_deadline(seconds: u64) {
    std::thread::spawn(move || {
        std::thread::sleep(Duration::from_secs(seconds));
        println!("verdict=fail deadline: the run took longer than {seconds} s");
        std::process::exit(1);
    });
}

/// Waits until the SubDevice answers a broadcast read (the simulator may still be starting: the namespace script
/// gives it 0.3 s, which a loaded machine can exceed), at most 50 tries of one PDU timeout each.
async fn wait_for_bus(master: &'static Master, slaves: usize) -> Outcome {
    let slaves = u16::try_from(slaves).map_err(|_| "--slaves too large")?;
    let mut last = String::new();
    for attempt in 1..=50u32 {
        // ESC type register (0x0000): every SubDevice adds 1 to the working counter.
        match ethercrab::Command::brd(0x0000).with_wkc(slaves).receive::<u8>(master).await {
            Ok(_) => {
                emit("bus_attempts", attempt);
                return Ok(());
            }
            Err(e) => last = e.to_string(),
        }
        async_io::Timer::after(Duration::from_millis(100)).await;
    }
    Err(format!("no SubDevice answered a BRD in 50 tries: {last}"))
}

fn run(args: &Args) -> Outcome {
    // DC static drift compensation only where DC is used (it costs 10,000 frames).
    let dc_iterations = if args.sync == Sync::Dc { 10_000 } else { 0 };
    let master: &'static Master = Box::leak(Box::new(start_master(&args.iface, dc_iterations)?));
    async_io::block_on(async {
        wait_for_bus(master, args.slaves).await?;
        match args.scenario.as_str() {
            "identity" => objects::identity(master).await,
            "objects" => objects::read_all(master).await,
            "parameters" => objects::parameters(master).await,
            "remap" => motion::remap_csv(master, args).await,
            "csp" => motion::csp(master, args).await,
            "watchdog" => motion::watchdog(master, args).await,
            "line" => line::line(master, args).await,
            other => Err(format!("unknown scenario {other}")),
        }
    })
}

fn main() -> std::process::ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            println!("verdict=fail {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    arm_deadline(args.deadline_s);
    let started = std::time::Instant::now();
    let outcome = run(&args);
    emit("run_s", format!("{:.3}", started.elapsed().as_secs_f64()));
    match outcome {
        Ok(()) => {
            println!("verdict=pass");
            std::process::ExitCode::SUCCESS
        }
        Err(reason) => {
            println!("verdict=fail {reason}");
            std::process::ExitCode::FAILURE
        }
    }
}
