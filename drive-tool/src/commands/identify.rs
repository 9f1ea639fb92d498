//! `identify` and `tune`: the drive's own motor identification and auto-tuning (the any-motor procedure,
//! `firmware::drive::auto_setup`, `auto_tuning`) started and followed over the bus.
//!
//! `identify`: 0x6060 = -2 (motor identification), «Shutdown», «Switch on», «Enable operation», then controlword
//! bit 4 starts it; the tool follows 0x3204:02 (step) and :03 (progress, per mille) until the statusword shows
//! bit 12 (done) or a fault (0x603F with its text), takes the power stage off and reports what the drive found:
//! resistance and inductances 0x3002, torque constant 0x3001:05, pole pairs 0x3204:04, friction 0x3204:05,
//! inertia 0x3204:06, the load's resonance pair 0x3205:03/04, and the gains the auto-tuning wrote (0x30A0..0x30A2).
//! `--store` then writes "save" to 0x1010:01.
//!
//! `tune [--stiffness PERMILLE]`: 0x3205:02 and 0x3205:01 = 1 with the power stage off: the gains from the motor
//! data as it stands (identified or entered), reported the same way; a refusal shows 0x3205:05's reason.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use serde_json::{json, Value as Json};

use crate::cia402::*;
use crate::commands::faults::code_text;
use crate::commands::motion;
use crate::context::Context;

/// The identification's steps, as 0x3204:02 counts them (device.toml).
const STEP_NAMES: [&str; 10] = [
    "not started",
    "standstill",
    "resistance",
    "inductance",
    "pole pairs and encoder",
    "commutation",
    "mechanics",
    "resonance",
    "tuning",
    "done",
];
/// Controlword bit 4: starts the identification in mode -2 (device.toml 0x6060).
const CW_START: u16 = 1 << 4;

/// One reported value: name, object, scale to the unit, unit.
const REPORT: [(&str, u16, u8, f64, &str); 12] = [
    ("resistance", 0x3002, 1, 1e-6, "ohm"),
    ("lq", 0x3002, 2, 1e-6, "H"),
    ("ld", 0x3002, 3, 1e-6, "H"),
    ("torque_constant", 0x3001, 5, 1e-6, "N m/A"),
    ("pole_pairs", 0x3204, 4, 1.0, ""),
    ("coulomb_friction", 0x3204, 5, 1e-6, "N m"),
    ("inertia", 0x3204, 6, 1e-10, "kg m^2"),
    ("resonance", 0x3205, 3, 0.1, "Hz"),
    ("anti_resonance", 0x3205, 4, 0.1, "Hz"),
    ("current_p_gain", 0x30A0, 1, 1.0, "0x30A0:01"),
    ("velocity_p_gain", 0x30A2, 1, 1.0, "0x30A2:01"),
    ("position_p_gain", 0x30A1, 1, 1.0, "0x30A1:01"),
];

fn report(cx: &mut Context, what: &str, extra: Json) -> Result<(), String> {
    let mut values = serde_json::Map::new();
    let mut lines = Vec::new();
    for (name, index, sub, scale, unit) in REPORT {
        let raw = cx.read_int(index, sub)?;
        let value = raw as f64 * scale;
        values.insert(name.into(), json!(value));
        lines.push(format!("  {name:<18} {value:.6} {unit}"));
    }
    if cx.json {
        let mut all = json!({ "node": cx.node });
        if let (Some(map), Some(more)) = (all.as_object_mut(), extra.as_object()) {
            map.extend(more.clone());
            map.extend(values);
        }
        cx.print_json(&all);
    } else {
        say!("node {}: {what}", cx.node);
        for line in lines {
            say!("{line}");
        }
    }
    Ok(())
}

/// `identify [--timeout-s S] [--poll-ms MS] [--store]`.
pub fn identify(cx: &mut Context, timeout: Duration, poll: Duration, store: bool) -> Result<(), String> {
    cx.write_int(0x6060, 0, -2)?;
    motion::enable(cx, 0)?;
    cx.write_int(0x6040, 0, i128::from(CW_ENABLE_OPERATION | CW_START))?;
    let started = Instant::now();
    let bar = (!cx.json && std::io::stderr().is_terminal()).then(|| {
        let bar = indicatif::ProgressBar::new(1000);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg:>28} {wide_bar} {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let mut last_step = 0;
    let outcome = loop {
        let step = cx.read_int(0x3204, 2)? as usize;
        if let Some(bar) = &bar {
            let name = STEP_NAMES.get(step).copied().unwrap_or("failed");
            bar.set_message(format!("step {step}: {name}"));
            bar.set_position(cx.read_int(0x3204, 3)?.clamp(0, 1000) as u64);
        }
        last_step = if step == 0 { last_step } else { step };
        let sw = cx.statusword()?;
        if sw & SW_FAULT != 0 {
            let code = cx.read_int(0x603F, 0)? as u16;
            break Err(format!(
                "node {}: the identification stopped in step {last_step} ({}) with fault 0x{code:04X} {}; the power \
                 stage is off",
                cx.node,
                STEP_NAMES.get(last_step).copied().unwrap_or("?"),
                code_text(code)
            ));
        }
        if sw & SW_SETPOINT_ACK != 0 {
            break Ok(());
        }
        if started.elapsed() > timeout {
            break Err(format!(
                "node {}: the identification did not end within {timeout:?} (step {last_step})",
                cx.node
            ));
        }
        std::thread::sleep(poll);
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    if outcome.is_err() {
        // A timeout leaves the power stage on: take it off. After a fault it is off already.
        let _ = cx.write_int(0x6040, 0, i128::from(CW_SHUTDOWN));
        return outcome;
    }
    motion::disable(cx)?;
    let seconds = f64::from(cx.read_int(0x3204, 7)? as i32) * 1e-3;
    if store {
        let node = cx.node;
        cx.link.download(node, 0x1010, 1, b"save").map_err(|e| format!("node {node} 0x1010:01 \"save\": {e}"))?;
    }
    report(cx, "identified, gains tuned", json!({ "identify_ms": seconds * 1e3, "stored": store }))
}

/// `tune [--stiffness PERMILLE]`.
pub fn tune(cx: &mut Context, stiffness: Option<u16>) -> Result<(), String> {
    let sw = cx.statusword()?;
    if matches!(state_name(sw), "Operation enabled" | "Quick stop active") {
        return Err(format!("node {}: take the power stage off first (drive-tool disable)", cx.node));
    }
    if let Some(permille) = stiffness {
        cx.write_int(0x3205, 2, i128::from(permille))?;
    }
    let written = cx.write_int(0x3205, 1, 1);
    let result = cx.read_int(0x3205, 5)?;
    if let Err(e) = written {
        return Err(format!("{e}; 0x3205:05 = {result} (device.toml names the reason)"));
    }
    report(cx, "gains tuned", json!({ "result": result }))
}
