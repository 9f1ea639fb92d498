//! `drive-sim`'s command line (clap): one subcommand per scenario with the options it takes, their help texts, and
//! the parsers that check a value and name its option when it is bad. `drive-sim --help` and `drive-sim SCENARIO
//! --help` print it all.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use hal_sim::plant::PlantParams;

use crate::canopen::CanopenArgs;

/// How `--plant FILE` scales each scenario: the long help of `--plant` ([`PLANT_HELP`]) and the end of `drive-sim
/// --help` ([`AFTER_HELP`]).
macro_rules! plant_help {
    () => {
        "Run on the plant of a TOML plant file (keys: PlantParams' fields; presets \
in hal-sim/presets/). The drive gets the plant's motor data (0x3001, 0x3010:01, 0x6073, 0x6080, 0x607F); the gains \
stay the reference-tuned ones unless --auto-tune, which first runs the identification with its auto-tuning \
(drive-sim identify) on the plant and commissions every drive of the scenario with the parameters it found (the \
identification measures the load's resonance pair into 0x3205:03/04, 0 for a rigid load, and the tuning takes the \
elastic design from it); --resonance F_R,F_AR (Hz) is a master's own pair instead, written into 0x3205:03/04 after \
the identification, followed by the auto-tuning 0x3205:01 = 1 again.

Scaling against the reference plant, so a scenario means the same on every plant: speeds, accelerations and \
distances in revolutions x max_speed_rpm / 5000 (a move keeps its timing; csp's acceleration at most what half \
the peak torque kt * peak_current_a gives the inertia at the motor shaft, which no preset reaches; csv-sweep's \
velocity step 100 rpm x the larger of max_speed_rpm / 5000 and the acceleration kt * peak_current_a / inertia at \
the motor shaft over the reference's, so that it asks at least the reference step's share of the peak current, at \
most half the max speed; its sine sweep stays 600 +- 30 rpm, on a plant slower than 1,200 rpm scaled to half its \
max speed); currents (steps, sweep bias and \
amplitude, spinning base and high current) x peak_current_a / 10; load torques (at the output) x kt * \
peak_current_a * gear_ratio * gear_efficiency / 0.335 N m. Scaled: current-step, spinning, csp, csv-sweep, ppm \
(moves and quick stops), duty-cycle (velocity steps x max_speed_rpm / 5000, load torques x the peak torque at the \
output / 0.335 N m, timing kept), homing (0x6099, 0x609A and the positioning move x max_speed_rpm / 5000; switch, \
band and index placement, 0x30B1 and 0x30B3 x encoder_counts_per_rev / 4096 x max_speed_rpm / 5000, so a run keeps \
its timing; 0x30B2 x peak_current_a / 10; the end stop's stiffness x the peak torque at the output, acting at the \
output). Not scaled (reference numbers, on the chosen plant): fault-matrix (its injections are the power stage's, \
which every preset shares), bench, and the servers, whose motion comes from the master."
    };
}

/// `--plant`'s long help.
const PLANT_HELP: &str = plant_help!();

/// The end of `drive-sim --help`: what `--plant` does.
const AFTER_HELP: &str = concat!("--plant FILE (every scenario and both servers). ", plant_help!());

/// Runs the firmware's drive against the simulated reference plant (or a plant file) and reports what it measured.
///
/// Each scenario prints a human-readable report, the paths of the CSV traces and SVG plots it wrote (under
/// out/SCENARIO/ of the current directory unless --out says otherwise), and as its last lines one key=value per
/// figure (the stable measurement interface). The long runs (homing, fault-matrix, duty-cycle, identify,
/// --auto-tune) show a progress bar on stderr when stderr is a terminal, never in a pipe or a CI log.
#[derive(Debug, Parser)]
#[command(name = "drive-sim", version, arg_required_else_help = true, after_long_help = AFTER_HELP)]
pub struct Cli {
    /// The scenario to run.
    #[command(subcommand)]
    pub command: Command,
}

/// The scenarios, the two fieldbus servers and the completion scripts.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// q-current step 0 -> 2 A on a locked rotor, the closed-loop frequency response and the offset calibration:
    /// rise_us, overshoot_pct, steady_error_pct, bandwidth_hz, offset_residual_lsb.
    CurrentStep(CurrentLoopScenario),
    /// The current loop at 3,000 rpm under a q-current and load step: voltage limit, recovery, tracking.
    Spinning(CurrentLoopScenario),
    /// CiA 402 CSP: a 10-revolution jerk-limited move with set-points every 1 ms; following error and settling.
    Csp(CspScenario),
    /// The dual loop (EPOS4 AN ch. 10) on a plant with a load encoder: a CSP move of the load closed by the load
    /// encoder; load_following_error_peak_inc, load_settle_error_inc, motor_load_deviation_peak_deg, load_settle_time_s.
    DualLoop(DualLoopScenario),
    /// CiA 402 CSV: a 100 rpm velocity step and a sine sweep of the velocity loop (velocity_bandwidth_hz).
    CsvSweep(Scenario),
    /// CiA 402 PPM: moves (target reached against the analytic profile, up to 5,000 rpm) and quick stops against
    /// the bus, with the limiter alone and with a braking chopper.
    Ppm(Scenario),
    /// CiA 402 HMM: every homing method of 0x60E3 from both sides of its reference.
    Homing(Scenario),
    /// Every fault of the table injected where it matters; detection, 0x603F/0x1001/0x1003/EMCY, the reaction and
    /// the reset checked (the table of docs/fault-matrix.md).
    FaultMatrix(FaultMatrixScenario),
    /// 60 s of velocity steps at the current limit with regeneration and load steps, every protection armed: no
    /// false trips.
    DutyCycle(Scenario),
    /// The motor identification (0x6060 = -2) run by a master over SDO, its results against the plant's truth.
    Identify(IdentifyArgs),
    /// The SSI absolute encoder as the only sensor (default plant: the reference motor with a 12 + 12-bit
    /// multi-turn SSI sensor in place of the encoder, no Halls): start-up commutation, a move, homing 37, a power
    /// cycle; commutation_error_deg, absolute_position_error_inc, and the sensor faults' codes.
    Ssi(SsiArgs),
    /// Host speed: simulated seconds of drive time per wall-clock second (build with --release).
    Bench(BenchArgs),
    /// The drive as an EtherCAT slave on a network interface, for a real master (needs CAP_NET_RAW), until
    /// --seconds pass, the master falls silent for --idle-exit-ms, or the process is stopped.
    Ethercat(EthercatArgs),
    /// K drives (node-IDs 1..=K) on a simulated CAN bus, served to python-can tools through the socketcand protocol
    /// on 127.0.0.1:PORT; prints `port=N` first.
    Canopen(CanopenArgs),
    /// Prints a completion script for SHELL on stdout, e.g. `drive-sim completions bash >
    /// ~/.local/share/bash-completion/completions/drive-sim`.
    Completions {
        /// The shell the script is for.
        #[arg(value_name = "SHELL")]
        shell: clap_complete::Shell,
    },
}

/// `drive-sim ssi`: the plant (default `hal-sim/presets/reference-ssi.toml`'s, which must have an SSI sensor) and
/// the seed.
#[derive(Debug, Args)]
pub struct SsiArgs {
    /// The plant and the seed.
    #[command(flatten)]
    pub common: Common,
}

/// A plant file given with `--plant`: its path (for the report) and the plant it describes.
#[derive(Clone, Debug)]
pub struct PlantFile {
    /// The file as given.
    pub path: PathBuf,
    /// The plant read from it.
    pub params: PlantParams,
}

/// The plant and the noise seed, which every scenario and both servers take.
#[derive(Debug, Args)]
pub struct Common {
    /// A TOML plant file instead of the reference plant (keys: PlantParams' fields; presets in hal-sim/presets/).
    #[arg(long, value_name = "FILE", value_parser = parse_plant, long_help = PLANT_HELP)]
    pub plant: Option<PlantFile>,
    /// Seed of the plant's noise (canopen: node k's plant uses seed + k).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub seed: u64,
}

/// The options of a simulated scenario: plant, seed, auto-tuning, output directory.
#[derive(Debug, Args)]
pub struct Scenario {
    /// The plant and the seed.
    #[command(flatten)]
    pub common: Common,
    /// Identify and auto-tune the drive on the plant first (identify's run on the same plant and seed), then run
    /// the scenario with every drive commissioned over SDO with the parameters found.
    #[arg(long)]
    pub auto_tune: bool,
    /// With --auto-tune: the load's resonance and anti-resonance (Hz, each in (0, 6553.5]) that the master
    /// writes into 0x3205:03/04 after the identification, followed by the auto-tuning 0x3205:01 = 1 again.
    #[arg(long, value_name = "F_R,F_AR", value_parser = parse_resonance, requires = "auto_tune")]
    pub resonance: Option<(f64, f64)>,
    /// Directory of the CSV traces and SVG plots [default: out/SCENARIO, the subcommand's name].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// current-step and spinning: a scenario and the current loop's gains.
#[derive(Debug, Args)]
pub struct CurrentLoopScenario {
    /// Plant, seed, auto-tuning, output directory.
    #[command(flatten)]
    pub scenario: Scenario,
    /// Keep 0x30A0's dictionary defaults (P 1555000 uV/A, I 2450000 uV/(A ms)), as without --gains.
    #[arg(long, conflicts_with = "gains")]
    pub default_gains: bool,
    /// 0x30A0 current-loop gains set at run time: P in uV/A, I in uV/(A ms).
    #[arg(long, value_name = "P,I", value_parser = parse_gains)]
    pub gains: Option<(u32, u32)>,
}

impl CurrentLoopScenario {
    /// The gains to set at run time, none for the dictionary's defaults.
    pub fn gains(&self) -> Option<(u32, u32)> {
        if self.default_gains {
            None
        } else {
            self.gains
        }
    }
}

/// csp: a scenario and the position loop's gains.
#[derive(Debug, Args)]
pub struct CspScenario {
    /// Plant, seed, auto-tuning, output directory.
    #[command(flatten)]
    pub scenario: Scenario,
    /// 0x30A1:01..05 position-loop gains set at run time (P, I, D, velocity and acceleration feed-forward, in
    /// 0x30A1's units).
    #[arg(long, value_name = "P,I,D,FFV,FFA", value_parser = parse_position_gains)]
    pub position_gains: Option<[u32; 5]>,
    /// The master sends the move's torque feedforward (J alpha + friction, per mille of 0x6076) in 0x60B2 each
    /// cycle, with 0x30A1:05 and :06 (the drive's own acceleration and friction feedforward) = 0.
    #[arg(long)]
    pub torque_feedforward: bool,
}

/// dual-loop: a scenario, the main loop's gains and the comparison without the load encoder.
#[derive(Debug, Args)]
pub struct DualLoopScenario {
    /// Plant (it needs a load encoder: load_encoder_counts_per_rev), seed, auto-tuning, output directory.
    #[command(flatten)]
    pub scenario: Scenario,
    /// 0x30AE:01..03 set before the move: K_Low and K_High in 0.001/s, the scheduling weight H in 0.001.
    #[arg(long, value_name = "K_LOW,K_HIGH,H", value_parser = parse_main_loop_gains)]
    pub main_loop_gains: Option<[u32; 3]>,
    /// The same move with the motor encoder alone closing the position loop (the default PID 0x30A1), for
    /// comparison: the load encoder is only measured.
    #[arg(long, conflicts_with = "main_loop_gains")]
    pub motor_encoder_only: bool,
}

/// fault-matrix: a scenario and the choice of cases.
#[derive(Debug, Args)]
pub struct FaultMatrixScenario {
    /// Plant, seed, auto-tuning, output directory.
    #[command(flatten)]
    pub scenario: Scenario,
    /// Only the cases whose fault name or injection contains TEXT (any case), e.g. one failure on its own.
    #[arg(long, value_name = "TEXT", value_parser = parse_lowercase)]
    pub only: Option<String>,
}

/// identify's options.
#[derive(Debug, Args)]
pub struct IdentifyArgs {
    /// The plant and the seed.
    #[command(flatten)]
    pub common: Common,
    /// The load's resonance and anti-resonance (Hz, each in (0, 6553.5]) that the master writes into
    /// 0x3205:03/04 after the identification, followed by the auto-tuning 0x3205:01 = 1 again.
    #[arg(long, value_name = "F_R,F_AR", value_parser = parse_resonance)]
    pub resonance: Option<(f64, f64)>,
}

/// bench's options.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// A TOML plant file instead of the reference plant (keys: PlantParams' fields; presets in hal-sim/presets/).
    #[arg(long, value_name = "FILE", value_parser = parse_plant)]
    pub plant: Option<PlantFile>,
    /// Simulated seconds of drive time to run.
    #[arg(long, value_name = "S", default_value_t = 2.0, value_parser = parse_seconds, allow_negative_numbers = true)]
    pub seconds: f64,
    /// Drives simulated side by side on one thread (1..=64); `sim_speed_ratio` is then each drive's.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub drives: u16,
}

/// ethercat's options.
#[derive(Debug, Args)]
pub struct EthercatArgs {
    /// The plant and the seed.
    #[command(flatten)]
    pub common: Common,
    /// The network interface to serve on (one end of a veth pair, or a real port).
    #[arg(long, value_name = "NAME", required = true)]
    pub iface: String,
    /// Simulated time advances by --cycle-us per cyclic frame (LRW/LRD/LWR) instead of with the wall clock.
    #[arg(long)]
    pub lock_step: bool,
    /// The cycle, microseconds: simulated time per cyclic frame in lock-step.
    #[arg(long, value_name = "N", default_value_t = 1_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub cycle_us: u64,
    /// The ESC's local clock this many ppm off the master's (-1000..=1000).
    #[arg(long, value_name = "X", default_value_t = 0.0, value_parser = parse_ppm, allow_negative_numbers = true)]
    pub clock_error_ppm: f64,
    /// The drive's oscillator this many ppm off the master's time (-1000..=1000): the DC PLL's work.
    #[arg(long, value_name = "X", default_value_t = 0.0, value_parser = parse_ppm, allow_negative_numbers = true)]
    pub drive_clock_error_ppm: f64,
    /// Stop after S seconds of wall-clock time (without it, run until stopped).
    #[arg(long, value_name = "S", value_parser = parse_seconds, allow_negative_numbers = true)]
    pub seconds: Option<f64>,
    /// Stop once the master has sent no frame for N ms after its first.
    #[arg(long, value_name = "N")]
    pub idle_exit_ms: Option<u64>,
    /// Record every frame received and sent into FILE (classic pcap).
    #[arg(long, value_name = "FILE")]
    pub pcap: Option<PathBuf>,
    /// In lock-step, an idle poll (no frame within the poll interval) also runs one cycle, so a quiet master lets
    /// simulated time pass (the process-data watchdog).
    #[arg(long)]
    pub idle_cycle: bool,
    /// Both Safe Torque Off inputs de-energised from power-up, for the whole run.
    #[arg(long)]
    pub sto_open: bool,
    /// N drives in a line on the interface (1..=64), each with its own ESC, firmware and plant (issue 21).
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub slaves: u16,
    /// With --slaves above 1: each ESC's clock also runs its own deterministic share of +-X ppm (0..=500).
    #[arg(long, value_name = "X", default_value_t = 100.0, value_parser = parse_spread_ppm)]
    pub clock_spread_ppm: f64,
    /// With --slaves: slave K (0 = next to the master) gets plant FILE instead of --plant's; repeatable.
    #[arg(long, value_name = "K=FILE", value_parser = parse_plant_for)]
    pub plant_for: Vec<(u16, PlantFile)>,
    /// Write the drive's own trace to FILE (one drive only): every current-loop period
    /// `period,iq_ma,iq_ref_ma,iq_plant_ma` (tier 1's measured q current and its reference, rounded to mA, and the
    /// plant's true q current): the reference for a recording of the drive's data recorder (`drive-tool record`).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["slaves", "plant_for"])]
    pub trace: Option<PathBuf>,
}

/// `--clock-spread-ppm`: 0..=500 ppm.
fn parse_spread_ppm(text: &str) -> Result<f64, String> {
    let v: f64 = text.parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() && (0.0..=500.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{text} is outside 0..=500 ppm"))
    }
}

/// `--plant-for K=FILE`.
fn parse_plant_for(text: &str) -> Result<(u16, PlantFile), String> {
    let (k, file) = text.split_once('=').ok_or_else(|| format!("{text}: expected K=FILE"))?;
    let k: u16 = k.trim().parse().map_err(|e| format!("slave {k}: {e}"))?;
    Ok((k, parse_plant(file)?))
}

/// `--plant FILE`: reads and checks the plant file.
fn parse_plant(text: &str) -> Result<PlantFile, String> {
    let path = PathBuf::from(text);
    let params = PlantParams::from_toml_file(&path).map_err(|e| e.to_string())?;
    Ok(PlantFile { path, params })
}

/// Two numbers separated by a comma, each parsed by `parse`.
fn pair<T>(text: &str, what: &str, parse: impl Fn(&str) -> Option<T>) -> Result<(T, T), String> {
    let (a, b) = text.split_once(',').ok_or_else(|| format!("{what}: two values separated by a comma"))?;
    match (parse(a.trim()), parse(b.trim())) {
        (Some(a), Some(b)) => Ok((a, b)),
        _ => Err(format!("{what}: two values separated by a comma")),
    }
}

/// `--gains P,I`: the current loop's gains (uV/A, uV/(A ms)).
pub fn parse_gains(text: &str) -> Result<(u32, u32), String> {
    pair(text, "P,I in uV/A and uV/(A ms), unsigned integers", |x| x.parse().ok())
}

/// The largest resonance 0x3205:03/04 hold: 65535 x 0.1 Hz.
const RESONANCE_MAX_HZ: f64 = 6553.5;

/// `--resonance F_R,F_AR`: two frequencies in (0, 6553.5] Hz (0x3205:03/04 hold 0.1 Hz in 16 bits).
pub fn parse_resonance(text: &str) -> Result<(f64, f64), String> {
    let what = "F_R,F_AR: two frequencies in (0, 6553.5] Hz";
    let hz = |x: &str| x.parse::<f64>().ok().filter(|f| *f > 0.0 && *f <= RESONANCE_MAX_HZ);
    pair(text, what, hz)
}

/// `--position-gains P,I,D,FFV,FFA`: five unsigned integers (0x30A1:01..05).
pub fn parse_position_gains(text: &str) -> Result<[u32; 5], String> {
    let what = "P,I,D,FFV,FFA: five unsigned integers (0x30A1:01..05)";
    let values: Vec<u32> =
        text.split(',').map(|x| x.trim().parse()).collect::<Result<_, _>>().map_err(|e| format!("{what}: {e}"))?;
    let count = values.len();
    values.try_into().map_err(|_| format!("{what}, got {count}"))
}

/// `--main-loop-gains K_LOW,K_HIGH,H`: three unsigned integers (0x30AE:01..03).
pub fn parse_main_loop_gains(text: &str) -> Result<[u32; 3], String> {
    let what = "K_LOW,K_HIGH,H: three unsigned integers (0x30AE:01..03)";
    let values: Vec<u32> =
        text.split(',').map(|x| x.trim().parse()).collect::<Result<_, _>>().map_err(|e| format!("{what}: {e}"))?;
    let count = values.len();
    values.try_into().map_err(|_| format!("{what}, got {count}"))
}

/// `--seconds S`: a finite, non-negative duration.
pub fn parse_seconds(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(s) if s.is_finite() && s >= 0.0 => Ok(s),
        Ok(_) => Err("seconds: finite and not negative".to_owned()),
        Err(e) => Err(e.to_string()),
    }
}

/// The largest clock error drive-sim simulates, ppm either way.
const PPM_MAX: f64 = 1_000.0;

/// `--clock-error-ppm X`, `--drive-clock-error-ppm X`: -1000..=1000 ppm.
pub fn parse_ppm(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x.is_finite() && x.abs() <= PPM_MAX => Ok(x),
        Ok(_) => Err("out of range (-1000..=1000 ppm)".to_owned()),
        Err(e) => Err(e.to_string()),
    }
}

/// `--only TEXT`: matched without regard to case.
fn parse_lowercase(text: &str) -> Result<String, String> {
    Ok(text.to_lowercase())
}

#[cfg(test)]
mod tests {
    use clap::error::ErrorKind;
    use clap::Parser;

    use super::{parse_gains, parse_position_gains, parse_resonance, Cli, Command};

    /// A preset as the command lines give it (`hal-sim/presets/...` from the workspace root).
    const GEARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/presets/geared-36v.toml");

    /// `drive-sim` followed by the words of `line` (no quoting: the lines below have no spaces in their values).
    fn parse(line: &str) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(std::iter::once("drive-sim").chain(line.split_whitespace()))
    }

    /// The command lines the test suite, the scripts and the documentation run drive-sim with today, each with
    /// where it comes from; every one must still parse after the move to clap.
    const EXISTING_LINES: &[(&str, &str)] = &[
        // README.md "Checks" table, the figures of each scenario, and the servers' examples.
        ("README.md", "current-step"),
        ("README.md", "spinning"),
        ("README.md", "csp"),
        ("README.md", "csp --torque-feedforward"),
        ("tests/tests/canopen_real_master.rs LSS", "canopen --port 0 --lock-step --nodes 3 --unconfigured 1 --unconfigured 2 --unconfigured 3"),
        ("drive-tool/tests/simulator.rs record", "canopen --port 0 --lock-step --seconds 600 --nodes 1 --trace out/trace.csv"),
        ("README.md", concat!("dual-loop --plant ", env!("CARGO_MANIFEST_DIR"), "/presets/geared-36v.toml --auto-tune")),
        ("README.md", "dual-loop --motor-encoder-only"),
        ("tests/tests/drive/dual_loop.rs", "dual-loop --main-loop-gains 20000,60000,10000"),
        ("README.md", "csv-sweep"),
        ("README.md", "ppm"),
        ("README.md", "homing"),
        ("README.md", "fault-matrix"),
        ("README.md", "identify"),
        ("README.md", "duty-cycle"),
        ("README.md", "bench"),
        ("README.md running a master by hand", "ethercat --iface ecs0 --lock-step --cycle-us 1000"),
        ("README.md CANopen", "canopen --port 29536 --nodes 3"),
        ("README.md bootloader fallback", "canopen --port 29536 --no-image 1"),
        // tests/src/real_master.rs namespace_script: `ethercat --iface ecs0 {sim_args} --seconds 280
        // --idle-exit-ms 1500`, with the sim_args of the real-master tests.
        ("tests/tests/ecat_ethercrab.rs run", "ethercat --iface ecs0 --lock-step --cycle-us 1000 --seconds 280 --idle-exit-ms 1500"),
        (
            "tests/tests/ecat_ethercrab.rs cyclic (dc)",
            "ethercat --iface ecs0 --lock-step --cycle-us 500 --clock-error-ppm 100 --seconds 280 --idle-exit-ms 1500",
        ),
        (
            "tests/tests/ecat_ethercrab.rs watchdog, ecat_real_masters.rs watchdog",
            "ethercat --iface ecs0 --lock-step --cycle-us 1000 --idle-cycle --seconds 280 --idle-exit-ms 1500",
        ),
        (
            "tests/tests/ecat_real_masters.rs sm-sync, boot_real_master.rs",
            "ethercat --iface ecs0 --lock-step --cycle-us 1000 --pcap /tmp/x/frames.pcap --seconds 280 --idle-exit-ms 1500",
        ),
        (
            "tests/tests/ecat_real_masters.rs csp_move (sync 2)",
            "ethercat --iface ecs0 --lock-step --cycle-us 1000 --clock-error-ppm 100 --seconds 280 --idle-exit-ms 1500",
        ),
        (
            "tests/tests/ecat_real_masters.rs soem-sto",
            "ethercat --iface ecs0 --lock-step --cycle-us 1000 --sto-open --seconds 280 --idle-exit-ms 1500",
        ),
        // tests/tests/ecat_multi_axis.rs: the lock-step line and the real-time measurement.
        (
            "tests/tests/ecat_multi_axis.rs line",
            "ethercat --iface ecs0 --slaves 16 --lock-step --cycle-us 200 --seconds 280 --idle-exit-ms 1500",
        ),
        ("tests/tests/ecat_multi_axis.rs real time", "ethercat --iface ecs0 --slaves 4 --seconds 280 --idle-exit-ms 1500"),
        (
            "ethercat line every option",
            concat!(
                "ethercat --iface ecs0 --slaves 3 --clock-spread-ppm 50 --plant-for 2=",
                env!("CARGO_MANIFEST_DIR"),
                "/presets/small-gimbal.toml --seconds 1"
            ),
        ),
        // tests/src/can_master.rs run: `canopen --port 0 --seconds 150 --idle-exit-ms 2000 {sim_args}`.
        ("tests/tests/canopen_real_master.rs bad_frames", "canopen --port 0 --seconds 150 --idle-exit-ms 2000"),
        ("tests/tests/canopen_real_master.rs nmt, sdo, update", "canopen --port 0 --seconds 150 --idle-exit-ms 2000 --lock-step"),
        (
            "tests/tests/canopen_real_master.rs stored",
            "canopen --port 0 --seconds 150 --idle-exit-ms 2000 --lock-step --sync-us 10000",
        ),
        ("tests/tests/canopen_real_master.rs sto", "canopen --port 0 --seconds 150 --idle-exit-ms 2000 --lock-step --sto-open 1"),
        ("tests/tests/boot_fallback.rs", "canopen --port 0 --seconds 150 --idle-exit-ms 2000 --no-image 1 --lock-step"),
        // drive-tool/tests/simulator.rs (on main since drive-tool's merge) Sim::start and start_with.
        ("drive-tool/tests/simulator.rs Sim::start", "canopen --port 0 --lock-step --seconds 600 --nodes 2"),
        (
            "drive-tool/tests/simulator.rs Sim::start_with",
            "canopen --port 0 --lock-step --seconds 600 --nodes 2 --no-image 2",
        ),
        // The tuning's documented runs (firmware/src/drive/tuning.rs, tests/tests/drive/auto_tune_geared.rs,
        // resonance_identification.rs) and docs/fault-matrix.md.
        ("firmware/src/drive/tuning.rs", concat!("csp --plant ", env!("CARGO_MANIFEST_DIR"), "/presets/geared-36v.toml --auto-tune --resonance 60,15")),
        ("tests/tests/drive/auto_tune_geared.rs", concat!("csp --plant ", env!("CARGO_MANIFEST_DIR"), "/presets/geared-36v.toml --auto-tune --seed 3")),
        ("tests/tests/drive/resonance_identification.rs", concat!("csv-sweep --plant ", env!("CARGO_MANIFEST_DIR"), "/presets/geared-36v.toml --auto-tune")),
        ("docs/fault-matrix.md", "fault-matrix --seed 1"),
        // The options of the former hand-written parser on the scenarios that use them.
        ("current-step gains", "current-step --seed 2 --gains 1555000,2450000 --out /tmp/x"),
        ("current-step default gains", "spinning --default-gains"),
        ("csp position gains", "csp --position-gains 1,2,3,4,5"),
        ("fault-matrix --only", "fault-matrix --only over-voltage"),
        ("bench --seconds", "bench --seconds 5"),
        ("identify --resonance", "identify --resonance 60,15 --seed 2"),
        (
            "ethercat every option",
            "ethercat --iface ecs0 --drive-clock-error-ppm -50 --clock-error-ppm -100 --sto-open --seed 3 --seconds 1",
        ),
        ("canopen every option", "canopen --port 0 --nodes 3 --bit-rate 500000 --sto-open 2 --sto-open 3 --seed 4"),
    ];

    #[test]
    fn every_command_line_in_use_still_parses() {
        for (place, line) in EXISTING_LINES {
            if let Err(e) = parse(line) {
                panic!("`drive-sim {line}` ({place}) no longer parses:\n{e}");
            }
        }
    }

    /// The values reach the scenario's arguments as the former parser gave them: the pair options, the repeated
    /// node-IDs, the clock errors with their sign, `--only` in lower case, `--plant` read.
    #[test]
    fn the_values_of_a_command_line_reach_the_scenario() {
        let Ok(Cli { command: Command::CurrentStep(a) }) = parse("current-step --gains 10,20 --seed 7") else {
            panic!("current-step");
        };
        assert_eq!((a.gains(), a.scenario.common.seed, a.scenario.out.as_deref()), (Some((10, 20)), 7, None));
        let Ok(Cli { command: Command::Canopen(c) }) = parse("canopen --port 0 --nodes 3 --sto-open 1 --sto-open 3")
        else {
            panic!("canopen");
        };
        assert_eq!((c.port, c.nodes, c.sto_open.as_slice(), c.common.seed), (0, 3, &[1, 3][..], 1));
        let Ok(Cli { command: Command::Ethercat(e) }) =
            parse("ethercat --iface ecs0 --clock-error-ppm -100 --drive-clock-error-ppm 25.5")
        else {
            panic!("ethercat");
        };
        assert_eq!((e.clock_error_ppm, e.drive_clock_error_ppm, e.cycle_us, e.sto_open), (-100.0, 25.5, 1_000, false));
        let Ok(Cli { command: Command::FaultMatrix(f) }) = parse("fault-matrix --only Over-Voltage") else {
            panic!("fault-matrix");
        };
        assert_eq!(f.only.as_deref(), Some("over-voltage"));
        let line = format!("csp --plant {GEARED} --auto-tune --resonance 60,15 --position-gains 1,2,3,4,5");
        let Ok(Cli { command: Command::Csp(c) }) = parse(&line) else { panic!("csp") };
        let plant = c.scenario.common.plant.expect("--plant read");
        assert_eq!(plant.params.gear_ratio, 5.0, "the geared preset's 5:1 gear");
        assert_eq!((c.scenario.resonance, c.position_gains), (Some((60.0, 15.0)), Some([1, 2, 3, 4, 5])));
    }

    /// An option of another scenario is refused by name (clap's UnknownArgument), `--default-gains` conflicts with
    /// `--gains`, `--resonance` needs `--auto-tune` outside identify.
    #[test]
    fn options_are_accepted_only_by_the_scenarios_that_use_them() {
        for (line, option) in [
            ("csp --gains 1,2", "--gains"),
            ("homing --only x", "--only"),
            ("bench --seed 2", "--seed"),
            ("identify --auto-tune", "--auto-tune"),
            ("identify --out /tmp", "--out"),
            ("canopen --port 0 --iface ecs0", "--iface"),
            ("ethercat --iface ecs0 --port 5", "--port"),
            ("fault-matrix --lock-step", "--lock-step"),
        ] {
            let e = parse(line).err().unwrap_or_else(|| panic!("`{line}` parsed"));
            assert_eq!(e.kind(), ErrorKind::UnknownArgument, "{line}: {e}");
            assert!(e.to_string().contains(option), "{line}: {e}");
        }
        let e = parse("current-step --default-gains --gains 1,2").expect_err("conflict");
        assert_eq!(e.kind(), ErrorKind::ArgumentConflict, "{e}");
        let e = parse("dual-loop --motor-encoder-only --main-loop-gains 1,2,3").expect_err("conflict");
        assert_eq!(e.kind(), ErrorKind::ArgumentConflict, "no main loop without the load encoder: {e}");
        let e = parse("csv-sweep --resonance 60,15").expect_err("--resonance without --auto-tune");
        assert_eq!(e.kind(), ErrorKind::MissingRequiredArgument, "{e}");
        assert!(parse("ethercat --lock-step").is_err(), "--iface is required");
        assert!(parse("canopen --lock-step").is_err(), "--port is required");
    }

    /// A bad value is refused with clap's ValueValidation error naming the option.
    #[test]
    fn a_bad_value_is_refused_naming_its_option() {
        for (line, option) in [
            ("current-step --gains 1", "--gains"),
            ("current-step --gains 1,-2", "--gains"),
            ("csp --position-gains 1,2,3,4", "--position-gains"),
            ("dual-loop --main-loop-gains 1,2", "--main-loop-gains"),
            ("ppm --seed x", "--seed"),
            ("csp --auto-tune --resonance 0,15", "--resonance"),
            ("identify --resonance 60,7000", "--resonance"),
            ("bench --seconds -1", "--seconds"),
            ("bench --seconds nan", "--seconds"),
            ("ethercat --iface ecs0 --cycle-us 0", "--cycle-us"),
            ("ethercat --iface ecs0 --clock-error-ppm 1001", "--clock-error-ppm"),
            ("ethercat --iface ecs0 --drive-clock-error-ppm inf", "--drive-clock-error-ppm"),
            ("ethercat --iface ecs0 --slaves 0", "--slaves"),
            ("ethercat --iface ecs0 --slaves 65", "--slaves"),
            ("ethercat --iface ecs0 --clock-spread-ppm 501", "--clock-spread-ppm"),
            ("ethercat --iface ecs0 --plant-for 1", "--plant-for"),
            ("canopen --port 70000", "--port"),
            ("canopen --port 0 --nodes 0", "--nodes"),
            ("canopen --port 0 --nodes 128", "--nodes"),
            ("canopen --port 0 --bit-rate 2000000", "--bit-rate"),
            ("canopen --port 0 --sync-us 0", "--sync-us"),
            ("canopen --port 0 --sto-open 0", "--sto-open"),
            ("canopen --port 0 --no-image 200", "--no-image"),
            ("homing --plant /nonexistent/plant.toml", "--plant"),
        ] {
            let e = parse(line).err().unwrap_or_else(|| panic!("`{line}` parsed"));
            assert_eq!(e.kind(), ErrorKind::ValueValidation, "{line}: {e}");
            assert!(e.to_string().contains(option), "{line}: {e}");
        }
    }

    /// A node-ID past the bus (`--nodes`) is named with its option, as the former parser did.
    #[test]
    fn a_node_id_past_the_bus_is_refused_naming_its_option() {
        let Ok(Cli { command: Command::Canopen(c) }) = parse("canopen --port 0 --nodes 2 --sto-open 3") else {
            panic!("canopen");
        };
        assert_eq!(c.config().err().as_deref(), Some("--sto-open 3: only node-IDs 1..=2 are on the bus"));
        let Ok(Cli { command: Command::Canopen(c) }) = parse("canopen --port 0 --no-image 2") else { panic!() };
        assert_eq!(c.config().err().as_deref(), Some("--no-image 2: only node-IDs 1..=1 are on the bus"));
        let Ok(Cli { command: Command::Canopen(c) }) = parse("canopen --port 0 --nodes 2 --no-image 2") else {
            panic!()
        };
        let config = c.config().expect("node 2 is on the bus");
        assert!(config.empty_slot(2) && !config.empty_slot(1));
    }

    /// The pair parsers: both values, in range; anything else refused.
    #[test]
    fn the_pair_parsers_take_two_values_in_range() {
        assert_eq!(parse_gains("1555000, 2450000"), Ok((1_555_000, 2_450_000)));
        assert!(parse_gains("1555000").is_err() && parse_gains("1,2,3").is_err() && parse_gains("a,2").is_err());
        assert_eq!(parse_resonance("60,15"), Ok((60.0, 15.0)));
        assert_eq!(parse_resonance("6553.5,0.1"), Ok((6553.5, 0.1)), "0x3205:03/04's 16 bits of 0.1 Hz");
        assert!(parse_resonance("6553.6,15").is_err() && parse_resonance("-1,15").is_err());
        assert_eq!(parse_position_gains("1,2,3,4,5"), Ok([1, 2, 3, 4, 5]));
        assert!(parse_position_gains("1,2,3,4,5,6").is_err());
    }
}
