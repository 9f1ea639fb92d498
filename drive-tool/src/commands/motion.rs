//! `enable`, `disable`, `jog` (profile velocity mode) and `move` (profile position mode) by SDO: a first test of
//! a machine axis (CiA 402-2 §6.2 state machine, §9 PPM, §11 PVM).

use std::time::{Duration, Instant};

use serde_json::json;

use crate::cia402::*;
use crate::commands::faults::code_text;
use crate::context::Context;

/// How long a state change may take (the first enable of the drive includes its commutation start-up).
const STATE_TIMEOUT: Duration = Duration::from_secs(20);
/// Pause between two statusword polls.
const POLL: Duration = Duration::from_millis(5);

/// Why the drive stopped where it did: fault code and text, or STO.
fn reason(cx: &mut Context, sw: u16) -> String {
    if sw & SW_FAULT != 0 {
        let code = cx.read_int(0x603F, 0).map(|c| c as u16).unwrap_or(0);
        return format!(
            "; fault 0x{code:04X} {} (drive-tool fault reset clears it once the cause is gone)",
            code_text(code)
        );
    }
    if sw & SW_STO != 0 {
        return "; Safe Torque Off is active (statusword bit 14)".into();
    }
    String::new()
}

/// Writes `cw` and waits until the statusword shows `state`.
fn step(cx: &mut Context, cw: u16, state: &str) -> Result<u16, String> {
    cx.write_int(0x6040, 0, i128::from(cw))?;
    let deadline = Instant::now() + STATE_TIMEOUT;
    loop {
        let sw = cx.statusword()?;
        if state_name(sw) == state {
            return Ok(sw);
        }
        if sw & SW_FAULT != 0 || Instant::now() >= deadline {
            let why = reason(cx, sw);
            return Err(format!(
                "node {}: controlword 0x{cw:04X} left the drive in {} (statusword 0x{sw:04X}), not {state}{why}",
                cx.node,
                state_name(sw)
            ));
        }
        std::thread::sleep(POLL);
    }
}

/// Takes the drive to «Operation enabled» with `extra` controlword bits (mode-specific) in the last step.
pub fn enable(cx: &mut Context, extra: u16) -> Result<u16, String> {
    let sw = cx.statusword()?;
    if sw & SW_FAULT != 0 {
        let why = reason(cx, sw);
        return Err(format!("node {}: the drive is in {}{why}", cx.node, state_name(sw)));
    }
    if state_name(sw) == "Operation enabled" {
        cx.write_int(0x6040, 0, i128::from(CW_ENABLE_OPERATION | extra))?;
        return Ok(sw);
    }
    step(cx, CW_SHUTDOWN, "Ready to switch on")?;
    step(cx, CW_SWITCH_ON, "Switched on")?;
    step(cx, CW_ENABLE_OPERATION | extra, "Operation enabled")
}

/// «Shutdown»: the power stage off, to «Ready to switch on».
pub fn disable(cx: &mut Context) -> Result<u16, String> {
    step(cx, CW_SHUTDOWN, "Ready to switch on")
}

fn print_state(cx: &Context, sw: u16) {
    if cx.json {
        cx.print_json(&json!({ "node": cx.node, "statusword": sw, "cia402": state_name(sw) }));
    } else {
        say!("node {}: {} (statusword 0x{sw:04X})", cx.node, state_name(sw));
    }
}

/// `enable`.
pub fn enable_command(cx: &mut Context) -> Result<(), String> {
    let sw = enable(cx, 0)?;
    print_state(cx, sw);
    Ok(())
}

/// `disable`.
pub fn disable_command(cx: &mut Context) -> Result<(), String> {
    let sw = disable(cx)?;
    print_state(cx, sw);
    Ok(())
}

/// `jog --velocity V --seconds S`: PVM at V for S seconds, then halt (controlword bit 8, the profile
/// deceleration), wait for standstill and disable.
pub fn jog(cx: &mut Context, velocity: i32, seconds: f64) -> Result<(), String> {
    if !(0.0..=3600.0).contains(&seconds) {
        return Err(format!("--seconds {seconds}: 0..=3600"));
    }
    cx.write_int(0x6060, 0, 3)?;
    cx.write_int(0x60FF, 0, i128::from(velocity))?;
    enable(cx, 0)?;
    let until = Instant::now() + Duration::from_secs_f64(seconds);
    let mut peak = 0i128;
    while Instant::now() < until {
        let sw = cx.statusword()?;
        if sw & SW_FAULT != 0 {
            let why = reason(cx, sw);
            return Err(format!("node {}: fault while jogging{why}", cx.node));
        }
        let v = cx.read_int(0x606C, 0)?;
        if v.abs() > peak.abs() {
            peak = v;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    cx.write_int(0x6040, 0, i128::from(CW_ENABLE_OPERATION | CW_HALT))?;
    let deadline = Instant::now() + STATE_TIMEOUT;
    loop {
        let sw = cx.statusword()?;
        // PVM: bit 10 with halt set means the axis stands (CiA 402-2 §11.2, statusword bit 10 "target reached").
        if sw & SW_TARGET_REACHED != 0 || Instant::now() >= deadline || sw & SW_FAULT != 0 {
            break;
        }
        std::thread::sleep(POLL);
    }
    let after = cx.read_int(0x606C, 0)?;
    cx.write_int(0x60FF, 0, 0)?;
    let sw = disable(cx)?;
    if cx.json {
        cx.print_json(&json!({
            "node": cx.node, "velocity_peak": peak as i64, "velocity_after_halt": after as i64,
            "cia402": state_name(sw),
        }));
    } else {
        say!(
            "node {}: jogged at {velocity} for {seconds} s: velocity actual peak {peak}, after halt {after}; {}",
            cx.node,
            state_name(sw)
        );
    }
    Ok(())
}

/// Arguments of `move`.
pub struct MoveArgs {
    /// Target 0x607A.
    pub target: i32,
    /// Relative to the present target.
    pub relative: bool,
    /// Profile velocity 0x6081.
    pub velocity: Option<u32>,
    /// Longest wait for target reached, s.
    pub timeout_s: f64,
    /// Stay in «Operation enabled» afterwards.
    pub stay_enabled: bool,
}

/// `move TARGET`: PPM single set-point (CiA 402-2 §9.2: new set-point bit 4 up, set-point acknowledge bit 12,
/// bit 4 down), then target reached (bit 10) within the timeout; prints the position actual value 0x6064.
pub fn move_to(cx: &mut Context, args: MoveArgs) -> Result<(), String> {
    if !(0.0..=3600.0).contains(&args.timeout_s) {
        return Err(format!("--timeout-s {}: 0..=3600", args.timeout_s));
    }
    cx.write_int(0x6060, 0, 1)?;
    if let Some(v) = args.velocity {
        cx.write_int(0x6081, 0, i128::from(v))?;
    }
    cx.write_int(0x607A, 0, i128::from(args.target))?;
    let mode_bits = if args.relative { CW_RELATIVE } else { 0 };
    enable(cx, mode_bits)?;
    let started = Instant::now();
    cx.write_int(0x6040, 0, i128::from(CW_ENABLE_OPERATION | mode_bits | CW_NEW_SETPOINT | CW_CHANGE_IMMEDIATELY))?;
    let deadline = started + Duration::from_secs_f64(args.timeout_s);
    let wait = |cx: &mut Context, what: &str, done: &dyn Fn(u16) -> bool| -> Result<u16, String> {
        loop {
            let sw = cx.statusword()?;
            if done(sw) {
                return Ok(sw);
            }
            if sw & SW_FAULT != 0 || state_name(sw) != "Operation enabled" {
                let why = reason(cx, sw);
                return Err(format!("node {}: {} while waiting for {what}{why}", cx.node, state_name(sw)));
            }
            if Instant::now() >= deadline {
                let pos = cx.read_int(0x6064, 0).unwrap_or_default();
                return Err(format!(
                    "node {}: no {what} within {} s (statusword 0x{sw:04X}, position actual {pos})",
                    cx.node, args.timeout_s
                ));
            }
            std::thread::sleep(POLL);
        }
    };
    wait(cx, "set-point acknowledge (statusword bit 12)", &|sw| sw & SW_SETPOINT_ACK != 0)?;
    cx.write_int(0x6040, 0, i128::from(CW_ENABLE_OPERATION | mode_bits))?;
    let sw =
        wait(cx, "target reached (statusword bit 10)", &|sw| sw & SW_TARGET_REACHED != 0 && sw & SW_SETPOINT_ACK == 0)?;
    let elapsed = started.elapsed().as_secs_f64();
    let position = cx.read_int(0x6064, 0)?;
    let demand = cx.read_int(0x607A, 0)?;
    let sw = if args.stay_enabled { sw } else { disable(cx)? };
    if cx.json {
        cx.print_json(&json!({
            "node": cx.node, "target": demand as i64, "position": position as i64, "seconds": elapsed,
            "cia402": state_name(sw),
        }));
    } else {
        say!(
            "node {}: target {demand} reached in {elapsed:.2} s; position actual {position}; {}",
            cx.node,
            state_name(sw)
        );
    }
    Ok(())
}
