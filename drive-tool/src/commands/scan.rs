//! `scan` and `info`: the drives on the bus and what they are (identity 0x1018, device type 0x1000, names and
//! versions 0x1008/0x1009/0x100A, NMT state from the heartbeat or EtherCAT AL state with station address, alias
//! and SII name, CiA 402 state from 0x6041).

use std::time::Duration;

use serde_json::{json, Value as Json};

use crate::cia402::state_name;
use crate::context::Context;
use crate::value::{decode, Value};

/// What one drive told about itself.
struct Report {
    node: u8,
    fields: Vec<(&'static str, Json, String)>,
}

fn u32_of(cx: &mut Context, node: u8, index: u16, sub: u8) -> Result<u32, String> {
    let bytes = cx.link.upload(node, index, sub).map_err(|e| format!("0x{index:04X}:{sub:02X}: {e}"))?;
    match decode(0x0007, &bytes) {
        Ok(Value::Int(v)) => Ok(v as u32),
        _ => Err(format!("0x{index:04X}:{sub:02X}: {} bytes, not an UNSIGNED32", bytes.len())),
    }
}

fn text_of(cx: &mut Context, node: u8, index: u16) -> Result<String, String> {
    let bytes = cx.link.upload(node, index, 0).map_err(|e| format!("0x{index:04X}: {e}"))?;
    match decode(0x0009, &bytes) {
        Ok(Value::Text(t)) => Ok(t),
        _ => Err(format!("0x{index:04X}: not a string")),
    }
}

/// Reads what `scan` and `info` show of `node`; an object the drive does not have is shown as missing
/// (null in JSON) with the reason.
fn report(cx: &mut Context, node: u8, details: bool) -> Report {
    let mut fields = Vec::new();
    let hex = |name: &'static str, r: Result<u32, String>| match r {
        Ok(v) => (name, json!(v), format!("0x{v:08X}")),
        Err(e) => (name, Json::Null, format!("({e})")),
    };
    for (name, sub) in [("vendor_id", 1), ("product_code", 2), ("revision", 3), ("serial_number", 4)] {
        let r = u32_of(cx, node, 0x1018, sub);
        fields.push(hex(name, r));
    }
    let r = u32_of(cx, node, 0x1000, 0);
    fields.push(hex("device_type", r));
    for (name, index) in [("device_name", 0x1008), ("hardware_version", 0x1009), ("software_version", 0x100A)] {
        fields.push(match text_of(cx, node, index) {
            Ok(t) => (name, json!(t), t),
            Err(e) => (name, Json::Null, format!("({e})")),
        });
    }
    let key = cx.link.comm_state_key();
    fields.push(match cx.link.comm_state(node) {
        Some(s) => (key, json!(s), s),
        // A node that answers SDO is pre-operational or operational (CiA 301 Table 62: no SDO when stopped).
        None => (key, Json::Null, "pre-operational or operational (no heartbeat seen)".into()),
    });
    fields.extend(cx.link.describe(node));
    match cx.link.upload(node, 0x6041, 0).map_err(|e| e.to_string()).and_then(|b| decode(0x0006, &b)) {
        Ok(Value::Int(sw)) => {
            let sw = sw as u16;
            fields.push(("statusword", json!(sw), format!("0x{sw:04X}")));
            fields.push(("cia402", json!(state_name(sw)), state_name(sw).to_owned()));
        }
        other => {
            let why = match other {
                Err(e) => e,
                Ok(v) => format!("{v:?}"),
            };
            fields.push(("statusword", Json::Null, format!("({why})")));
            fields.push(("cia402", Json::Null, "(no CiA 402 state)".into()));
        }
    }
    if details {
        // `info` only: the error code with its text, the mode and the actual values (CiA 402-2 0x603F, 0x6061,
        // 0x6064, 0x606C).
        match cx.link.upload(node, 0x603F, 0).map_err(|e| e.to_string()).and_then(|b| decode(0x0006, &b)) {
            Ok(Value::Int(code)) => {
                let text = crate::commands::faults::code_text(code as u16);
                fields.push(("error_code", json!(code), format!("0x{code:04X} {text}")));
                fields.push(("error_code_text", json!(text), String::new()));
            }
            other => fields.push(("error_code", Json::Null, format!("({})", other.err().unwrap_or_default()))),
        }
        for (name, index, data_type) in
            [("mode", 0x6061, 0x0002), ("position", 0x6064, 0x0004), ("velocity", 0x606C, 0x0004)]
        {
            match cx.link.upload(node, index, 0).map_err(|e| e.to_string()).and_then(|b| decode(data_type, &b)) {
                Ok(Value::Int(v)) if name == "mode" => {
                    fields.push((name, json!(v as i64), format!("{v} ({})", mode_name(v))))
                }
                Ok(Value::Int(v)) => fields.push((name, json!(v as i64), v.to_string())),
                other => fields.push((name, Json::Null, format!("({})", other.err().unwrap_or_default()))),
            }
        }
    }
    Report { node, fields }
}

/// The name of a mode of operation (CiA 402-2 0x6060 values; -2 is this drive's motor identification).
fn mode_name(mode: i128) -> &'static str {
    match mode {
        0 => "no mode",
        1 => "profile position",
        3 => "profile velocity",
        4 => "profile torque",
        6 => "homing",
        7 => "interpolated position",
        8 => "cyclic synchronous position",
        9 => "cyclic synchronous velocity",
        10 => "cyclic synchronous torque",
        m if m < 0 => "manufacturer-specific",
        _ => "reserved",
    }
}

fn to_json(r: &Report) -> Json {
    let mut object = serde_json::Map::new();
    object.insert("node".into(), json!(r.node));
    for (name, value, _) in &r.fields {
        object.insert((*name).into(), value.clone());
    }
    Json::Object(object)
}

fn print_text(r: &Report) {
    say!("node {}", r.node);
    for (name, _, text) in r.fields.iter().filter(|(_, _, text)| !text.is_empty()) {
        say!("  {name:<17} {text}");
    }
}

/// `scan`: the drives the link finds (CANopen: every node-ID 1..=127 asked for 0x1018:01 at once; EtherCAT: the
/// SubDevices of the segment, by position) are described.
pub fn scan(cx: &mut Context, wait: Duration) -> Result<(), String> {
    let nodes = cx.link.scan(wait)?;
    let reports: Vec<Report> = nodes.iter().map(|&n| report(cx, n, false)).collect();
    if cx.json {
        cx.print_json(&Json::Array(reports.iter().map(to_json).collect()));
    } else if reports.is_empty() {
        say!("no drive answered");
    } else {
        for r in &reports {
            print_text(r);
        }
    }
    Ok(())
}

/// `info`: the description of the drive `--node`; fails when it does not answer.
pub fn info(cx: &mut Context) -> Result<(), String> {
    let node = cx.node;
    // The identity first: a drive that does not answer it is not there.
    u32_of(cx, node, 0x1018, 1).map_err(|e| format!("node {node}: {e}"))?;
    let r = report(cx, node, true);
    if cx.json {
        cx.print_json(&to_json(&r));
    } else {
        print_text(&r);
    }
    Ok(())
}
