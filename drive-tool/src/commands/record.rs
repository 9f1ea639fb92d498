//! `record`: the drive's data recorder (0x3300..0x3302, issue 22 item 2; EPOS4's data recorder as the model)
//! configured, armed, triggered or waited for, and its recording uploaded by SDO block transfer and written as a
//! CSV file and an SVG plot.
//!
//! A channel is a current-loop variable by name ([`TIER1_VARIABLES`]: `0x3303SS00` in 0x3301) or any
//! TxPDO-mappable object by index or name (the tier-2 values: `0x606C` velocity actual, `0x606B` velocity demand,
//! `0x6064` position actual...). The drive refuses what it cannot record (0x0604_0041) and an arm it cannot carry
//! out (0x0604_0043); the tool shows its abort. `--no-wait` arms and returns (the machine is then moved by other
//! commands), `--fetch` waits for that recording and uploads it. The tool labels the columns from what the drive
//! holds in 0x3301, so a `--fetch` needs no channel list.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde_json::json;

use crate::context::Context;
use crate::plot::{Plot, Series};
use crate::value::parse_integer;

/// 0x3300 *Data recorder* and its sub-indices (device.toml).
const RECORDER: u16 = 0x3300;
const CONTROL: u8 = 1;
const STATE: u8 = 2;
const PERIOD: u8 = 3;
const SAMPLES: u8 = 4;
const PRECEDING: u8 = 5;
const MODE: u8 = 6;
const TRIGGER_CHANNEL: u8 = 7;
const THRESHOLD: u8 = 8;
const MASK: u8 = 9;
const RECORDED: u8 = 11;
/// 0x3301 *Data recorder variables*, 0x3302 *Data recorder buffer*.
const VARIABLES: u16 = 0x3301;
const BUFFER: u16 = 0x3302;
/// The index that names a current-loop variable in 0x3301.
const TIER1_INDEX: u16 = 0x3303;
/// The recorder's state 0x3300:02 when a recording is complete.
const COMPLETE: i128 = 3;
/// One current-loop period, s (25 kHz).
const PERIOD_S: f64 = 40e-6;

/// The current-loop variables: name, 0x3303 sub-index, unit, bytes a sample, signed.
pub const TIER1_VARIABLES: [(&str, u8, &str, usize, bool); 13] = [
    ("ia", 1, "mA", 2, true),
    ("ib", 2, "mA", 2, true),
    ("ic", 3, "mA", 2, true),
    ("id", 4, "mA", 2, true),
    ("iq", 5, "mA", 2, true),
    ("iq_ref", 6, "mA", 2, true),
    ("vd", 7, "mV", 4, true),
    ("vq", 8, "mV", 4, true),
    ("vbus", 9, "mV", 4, true),
    ("duty_a", 10, "ticks", 2, false),
    ("duty_b", 11, "ticks", 2, false),
    ("duty_c", 12, "ticks", 2, false),
    ("position", 13, "inc", 4, true),
];

/// Trigger modes (0x3300:06).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Trigger {
    /// At the first sample after arming.
    Immediate,
    /// The trigger channel rises through --level.
    Rising,
    /// The trigger channel falls through --level.
    Falling,
    /// Either edge through --level.
    Either,
    /// A bit of --mask becomes set.
    BitsSet,
    /// Every bit of --mask becomes clear.
    BitsCleared,
}

impl Trigger {
    const fn code(self) -> i128 {
        match self {
            Self::Immediate => 0,
            Self::Rising => 1,
            Self::Falling => 2,
            Self::Either => 3,
            Self::BitsSet => 4,
            Self::BitsCleared => 5,
        }
    }
}

/// What `record` is asked to do.
#[derive(Clone, Debug, clap::Args)]
pub struct RecordArgs {
    /// A channel (up to 8, repeat the option): a current-loop variable (ia, ib, ic, id, iq, iq_ref, vd, vq, vbus,
    /// duty_a, duty_b, duty_c, position) or an object by index or name (0x606C, "Velocity actual value")
    #[arg(long = "channel", short = 'c', value_name = "CH")]
    pub channels: Vec<String>,
    /// Current-loop periods between samples: 1 = 25 kHz, 10 = 2.5 kHz
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=25_000))]
    pub divider: u16,
    /// The sampling rate instead of a divider (25 kHz / rate, rounded to a whole divider)
    #[arg(long, value_name = "HZ", conflicts_with = "divider")]
    pub rate_hz: Option<f64>,
    /// Samples of the recording, those before the trigger included (0: as many as the drive's buffer holds)
    #[arg(long, value_name = "N", default_value_t = 1000)]
    pub samples: u32,
    /// Samples kept from before the trigger
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub pre: u32,
    /// The trigger
    #[arg(long, value_enum, default_value = "immediate")]
    pub trigger: Trigger,
    /// The channel whose value triggers (its place in the --channel list, from 1)
    #[arg(long, value_name = "K", default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=8))]
    pub trigger_channel: u8,
    /// Level of an edge trigger, in the trigger channel's unit (mA, mV, ticks, inc, or the object's)
    #[arg(long, value_name = "VALUE", default_value_t = 0, allow_hyphen_values = true)]
    pub level: i32,
    /// Bits of a bit trigger (0x... allowed)
    #[arg(long, value_name = "BITS", default_value = "0")]
    pub mask: String,
    /// Trigger at once after arming (0x3300:01 = 2), whatever the trigger
    #[arg(long)]
    pub trigger_now: bool,
    /// Arm and return: a later `record --fetch` waits for the recording and uploads it
    #[arg(long, conflicts_with = "fetch")]
    pub no_wait: bool,
    /// Wait for the recording armed earlier (`record --no-wait`) and upload it; no configuration is written
    #[arg(long)]
    pub fetch: bool,
    /// Longest wait for the recording to complete
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    pub timeout_s: f64,
    /// The CSV file written (time, then one column per channel)
    #[arg(long, value_name = "FILE", default_value = "record.csv")]
    pub csv: PathBuf,
    /// The SVG plot written (one panel per channel)
    #[arg(long, value_name = "FILE", default_value = "record.svg")]
    pub svg: PathBuf,
}

/// A channel as the recording holds it.
#[derive(Clone, Debug, PartialEq)]
struct Channel {
    /// Column name: the variable's, or the object's EDS name.
    name: String,
    /// 0x3301 value `0xIIIISS00`.
    code: u32,
    unit: String,
    bytes: usize,
    signed: bool,
}

/// The 0x3301 value of `spec`: a current-loop variable's name, or an object of the dictionary.
fn channel_code(cx: &Context, spec: &str) -> Result<u32, String> {
    if let Some((_, sub, ..)) = TIER1_VARIABLES.iter().find(|v| v.0.eq_ignore_ascii_case(spec.trim())) {
        return Ok(u32::from(TIER1_INDEX) << 16 | u32::from(*sub) << 8);
    }
    let entry = cx.dict.resolve_one(spec).map_err(|e| format!("--channel {spec}: {e}"))?;
    Ok(u32::from(entry.index) << 16 | u32::from(entry.sub) << 8)
}

/// How the recording holds the channel of 0x3301 value `code`: its name, unit and sample size.
fn channel_of(cx: &Context, code: u32) -> Result<Channel, String> {
    let index = (code >> 16) as u16;
    let sub = (code >> 8) as u8;
    if index == TIER1_INDEX {
        let (name, _, unit, bytes, signed) = TIER1_VARIABLES
            .iter()
            .find(|v| v.1 == sub)
            .ok_or_else(|| format!("0x3301 names current-loop variable {sub}, unknown to this tool"))?;
        return Ok(Channel {
            name: (*name).to_owned(),
            code,
            unit: (*unit).to_owned(),
            bytes: *bytes,
            signed: *signed,
        });
    }
    let entry = cx.entry(index, sub)?;
    // CiA 301 Table 44: BOOLEAN 0x01, INTEGER8/16/32 0x02..0x04, UNSIGNED8/16/32 0x05..0x07.
    let (bytes, signed) = match entry.data_type {
        0x01 | 0x05 | 0x06 => (2, false),
        0x02 | 0x03 => (2, true),
        0x04 => (4, true),
        0x07 => (4, false),
        other => return Err(format!("{} has type 0x{other:04X}, which the recorder does not record", entry.address())),
    };
    Ok(Channel { name: entry.name.clone(), code, unit: entry.address(), bytes, signed })
}

/// The samples of `data`, row by row, each channel decoded with its size and sign.
fn decode_rows(data: &[u8], channels: &[Channel]) -> Result<Vec<Vec<i64>>, String> {
    let row: usize = channels.iter().map(|c| c.bytes).sum();
    if row == 0 || !data.len().is_multiple_of(row) {
        return Err(format!("the buffer holds {} bytes, not whole samples of {row}", data.len()));
    }
    Ok(data
        .chunks(row)
        .map(|sample| {
            let mut at = 0;
            channels
                .iter()
                .map(|c| {
                    let b = &sample[at..at + c.bytes];
                    at += c.bytes;
                    match (c.bytes, c.signed) {
                        (2, true) => i64::from(i16::from_le_bytes([b[0], b[1]])),
                        (2, false) => i64::from(u16::from_le_bytes([b[0], b[1]])),
                        (_, true) => i64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                        (_, false) => i64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    }
                })
                .collect()
        })
        .collect())
}

/// `record`: see the module documentation.
pub fn record(cx: &mut Context, args: &RecordArgs) -> Result<(), String> {
    if !args.fetch {
        configure_and_arm(cx, args)?;
        if args.no_wait {
            if cx.json {
                cx.print_json(&json!({ "armed": true }));
            } else {
                say!("recorder armed: `drive-tool record --fetch` uploads the recording once it is complete");
            }
            return Ok(());
        }
    }
    wait_complete(cx, Duration::from_secs_f64(args.timeout_s.max(0.0)))?;
    let count = cx.read_int(VARIABLES, 0)?;
    let mut channels = Vec::new();
    for k in 1..=count.clamp(0, 8) as u8 {
        let code = cx.read_int(VARIABLES, k)? as u32;
        channels.push(channel_of(cx, code)?);
    }
    let divider = cx.read_int(RECORDER, PERIOD)?.max(1);
    let pre = cx.read_int(RECORDER, PRECEDING)?;
    let recorded = cx.read_int(RECORDER, RECORDED)?;
    let data = cx
        .link
        .upload_bulk(cx.node, BUFFER, 0)
        .map_err(|e| format!("node {} 0x3302:00 (Data recorder buffer): {e}", cx.node))?;
    let rows = decode_rows(&data, &channels)?;
    if rows.len() as i128 != recorded {
        return Err(format!("0x3302 holds {} samples, 0x3300:0B says {recorded}", rows.len()));
    }
    let period_s = divider as f64 * PERIOD_S;
    write_csv(&args.csv, &channels, &rows, period_s)?;
    write_svg(&args.svg, &channels, &rows, period_s)?;
    if cx.json {
        let list: Vec<_> = channels
            .iter()
            .map(|c| json!({ "name": c.name, "code": format!("0x{:08X}", c.code), "unit": c.unit, "bytes": c.bytes }))
            .collect();
        cx.print_json(&json!({
            "samples": rows.len(), "preceding": pre, "period_s": period_s, "channels": list,
            "csv": args.csv.display().to_string(), "svg": args.svg.display().to_string(),
        }));
    } else {
        say!(
            "{} samples of {} channel(s) every {:.0} us ({} before the trigger) -> {}, {}",
            rows.len(),
            channels.len(),
            period_s * 1e6,
            pre,
            args.csv.display(),
            args.svg.display()
        );
    }
    Ok(())
}

/// Stops the recorder, writes the channels, sampling and trigger, and arms (then triggers, with --trigger-now).
fn configure_and_arm(cx: &mut Context, args: &RecordArgs) -> Result<(), String> {
    if args.channels.is_empty() || args.channels.len() > 8 {
        return Err(format!("give 1 to 8 --channel, not {}", args.channels.len()));
    }
    if usize::from(args.trigger_channel) > args.channels.len() {
        return Err(format!("--trigger-channel {} of {} channels", args.trigger_channel, args.channels.len()));
    }
    let codes = args.channels.iter().map(|c| channel_code(cx, c)).collect::<Result<Vec<u32>, String>>()?;
    let divider = match args.rate_hz {
        Some(hz) if hz > 0.0 && hz <= 25_000.0 => (25_000.0 / hz).round().clamp(1.0, 25_000.0) as u16,
        Some(hz) => return Err(format!("--rate-hz {hz}: from 1 to 25000")),
        None => args.divider,
    };
    let mask = parse_integer(&args.mask)
        .and_then(|m| u32::try_from(m).ok())
        .ok_or_else(|| format!("--mask {}: not a 32-bit unsigned value", args.mask))?;
    cx.write_int(RECORDER, CONTROL, 0)?;
    cx.write_int(VARIABLES, 0, 0)?;
    for (k, code) in codes.iter().enumerate() {
        cx.write_int(VARIABLES, k as u8 + 1, i128::from(*code))?;
    }
    cx.write_int(VARIABLES, 0, codes.len() as i128)?;
    cx.write_int(RECORDER, PERIOD, i128::from(divider))?;
    cx.write_int(RECORDER, SAMPLES, i128::from(args.samples))?;
    cx.write_int(RECORDER, PRECEDING, i128::from(args.pre))?;
    cx.write_int(RECORDER, MODE, args.trigger.code())?;
    cx.write_int(RECORDER, TRIGGER_CHANNEL, i128::from(args.trigger_channel))?;
    cx.write_int(RECORDER, THRESHOLD, i128::from(args.level))?;
    cx.write_int(RECORDER, MASK, i128::from(mask))?;
    cx.write_int(RECORDER, CONTROL, 1)?;
    if args.trigger_now {
        cx.write_int(RECORDER, CONTROL, 2)?;
    }
    Ok(())
}

/// Polls 0x3300:02 until the recording is complete; an error when the recorder is idle (nothing armed) or the
/// time is up.
fn wait_complete(cx: &mut Context, timeout: Duration) -> Result<(), String> {
    let start = Instant::now();
    loop {
        match cx.read_int(RECORDER, STATE)? {
            COMPLETE => return Ok(()),
            0 => return Err("the recorder is idle: nothing armed (`record --channel ...` arms it)".into()),
            state if start.elapsed() >= timeout => {
                let what = if state == 1 { "waiting for its trigger" } else { "recording" };
                return Err(format!("the recorder is still {what} after {:.1} s", timeout.as_secs_f64()));
            }
            _ => std::thread::sleep(Duration::from_millis(2)),
        }
    }
}

/// `time_s` (from the first sample) and one column per channel, `name_unit`.
fn write_csv(path: &Path, channels: &[Channel], rows: &[Vec<i64>], period_s: f64) -> Result<(), String> {
    let mut text = String::from("time_s");
    for c in channels {
        text.push_str(&format!(",{}_{}", c.name.replace([' ', ','], "_"), c.unit.replace(':', "_")));
    }
    text.push('\n');
    for (k, row) in rows.iter().enumerate() {
        text.push_str(&format!("{:.6}", k as f64 * period_s));
        for v in row {
            text.push_str(&format!(",{v}"));
        }
        text.push('\n');
    }
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

/// One panel per channel, stacked, in one SVG file.
fn write_svg(path: &Path, channels: &[Channel], rows: &[Vec<i64>], period_s: f64) -> Result<(), String> {
    const PANEL_HEIGHT: usize = 540;
    let x: Vec<f64> = (0..rows.len()).map(|k| k as f64 * period_s * 1e3).collect();
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"960\" height=\"{}\">\n",
        PANEL_HEIGHT * channels.len().max(1)
    );
    for (k, c) in channels.iter().enumerate() {
        let y: Vec<f64> = rows.iter().map(|r| r[k] as f64).collect();
        let mut plot = Plot::new(&format!("data recorder: {}", c.name), "time (ms)", &c.unit);
        plot.series.push(Series::new(&c.name, &x, &y));
        svg.push_str(&format!("<g transform=\"translate(0,{})\">\n", k * PANEL_HEIGHT));
        svg.push_str(&plot.to_svg());
        svg.push_str("</g>\n");
    }
    svg.push_str("</svg>\n");
    std::fs::write(path, svg).map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(bytes: usize, signed: bool) -> Channel {
        Channel { name: "x".into(), code: 0, unit: "u".into(), bytes, signed }
    }

    /// A row of a 16-bit signed, a 16-bit unsigned and a 32-bit signed channel, packed as the drive packs them
    /// (little-endian, no padding).
    #[test]
    fn rows_decode_with_each_channel_size_and_sign() {
        let data = [0xFE, 0xFF, 0xFE, 0xFF, 0x00, 0x00, 0x01, 0x80, 0x05, 0x00, 0x01, 0x00, 0x10, 0x00, 0x00, 0x00];
        let rows = decode_rows(&data, &[channel(2, true), channel(2, false), channel(4, true)]).expect("two rows");
        assert_eq!(rows, vec![vec![-2, 65_534, -2_147_418_112], vec![5, 1, 16]]);
        assert!(decode_rows(&data[..7], &[channel(2, true)]).is_err(), "an odd byte count is no whole sample");
    }
}
