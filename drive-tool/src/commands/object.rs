//! `get` and `set`: objects by index or name, with type-aware parsing and display.

use serde_json::json;

use crate::context::Context;
use crate::eds::{Dictionary, Entry};
use crate::value::{decode, encode, type_name, Value};

/// `get OBJ... [--complete]`: reads each entry the specs name and prints `0xIIII:SS name = value`, or a JSON
/// list; with `complete` (EtherCAT), each object in one CoE complete access.
pub fn get(cx: &mut Context, specs: &[String], complete: bool) -> Result<(), String> {
    let mut entries = Vec::new();
    for spec in specs {
        entries.extend(cx.dict.resolve(spec)?.into_iter().cloned());
    }
    let mut read = if complete { complete_values(cx, &entries)? } else { Vec::new() }.into_iter();
    let mut out = Vec::new();
    let mut failures = Vec::new();
    for entry in &entries {
        if !entry.access.readable() {
            failures.push(format!("{} ({}) is write-only", entry.address(), entry.full_name()));
            continue;
        }
        let value = if complete {
            read.next().unwrap_or_else(|| Err("no value".into()))
        } else {
            cx.read_entry_of(cx.node, entry)
        };
        match value {
            Ok(value) => {
                if cx.json {
                    out.push(json!({
                        "index": entry.index, "sub": entry.sub, "address": entry.address(), "name": entry.full_name(),
                        "type": type_name(entry.data_type), "access": entry.access.word(), "default": entry.default,
                        "value": value.json(), "text": value.display(entry.data_type),
                    }));
                } else {
                    say!("{} {} = {}", entry.address(), entry.full_name(), value.display(entry.data_type));
                }
            }
            Err(e) => {
                if cx.json {
                    out.push(json!({ "index": entry.index, "sub": entry.sub, "address": entry.address(), "error": e }));
                }
                failures.push(e);
            }
        }
    }
    if cx.json {
        cx.print_json(&serde_json::Value::Array(out));
    }
    match failures.as_slice() {
        [] => Ok(()),
        [one] => Err(one.clone()),
        many => Err(many.join("\n")),
    }
}

/// The values of `entries` (readable ones, in order) by one CoE complete access per object (ETG.1000.6
/// §5.6.2.1.2, the packing the firmware's server uses: sub-index 0 as UNSIGNED8 padded to 16 bits, then every
/// sub-index's value in order). Objects with BOOLEAN (packed as bits), string or domain entries are refused: their
/// packing is not byte-aligned or has no fixed size.
fn complete_values(cx: &mut Context, entries: &[Entry]) -> Result<Vec<Result<Value, String>>, String> {
    #[cfg(target_os = "linux")]
    {
        let node = cx.node;
        let mut indices: Vec<u16> = entries.iter().map(|e| e.index).collect();
        indices.dedup();
        let mut values = Vec::new();
        for index in indices {
            // The offsets come from the whole object; the values shown are the entries asked for.
            let object: Vec<Entry> = cx.dict.object(index).into_iter().cloned().collect();
            if let [single] = object.as_slice() {
                // A VAR has no sub-indices to access completely: its one value, read as usual.
                if single.access.readable() {
                    values.push(cx.read_entry_of(node, single));
                }
                continue;
            }
            let ecat = cx.link.ecat().ok_or("--complete is CoE complete access: it needs --ecat")?;
            let bytes = ecat
                .upload_complete(node, index)
                .map_err(|e| format!("drive {node} 0x{index:04X} (complete access): {e}"))?;
            let mut at = 0usize;
            for entry in &object {
                let len = match (entry.sub, crate::value::Kind::of(entry.data_type)) {
                    (0, _) => 2,
                    (_, Some(crate::value::Kind::Integer { bytes, .. })) => bytes,
                    (_, Some(crate::value::Kind::Real32)) => 4,
                    (_, Some(crate::value::Kind::Real64)) => 8,
                    _ => {
                        return Err(format!(
                            "0x{index:04X}: {} is {}, which complete access does not pack by bytes; read it without \
                             --complete",
                            entry.address(),
                            type_name(entry.data_type)
                        ))
                    }
                };
                let raw = bytes.get(at..at + len).ok_or_else(|| {
                    format!(
                        "0x{index:04X}: the complete access gave {} bytes, {} needs more",
                        bytes.len(),
                        entry.address()
                    )
                })?;
                let raw = if entry.sub == 0 { &raw[..1] } else { raw };
                at += len;
                let asked = entries.iter().any(|e| e.index == index && e.sub == entry.sub);
                if asked && entry.access.readable() {
                    values.push(decode(entry.data_type, raw));
                }
            }
        }
        Ok(values)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (cx, entries);
        Err("--complete is CoE complete access: it needs --ecat".into())
    }
}

/// The entry `spec` names and the bytes of `text` for it: the type's range, the EDS limits and the drive's value
/// list checked. Needs no link, so that a bad value is refused before the bus is opened.
pub fn checked_value(dict: &Dictionary, node: u8, spec: &str, text: &str) -> Result<(Entry, Vec<u8>), String> {
    let entry = dict.resolve_one(spec)?.clone();
    // The access is not checked here: the drive has the last word (its abort code says why it refuses, e.g.
    // 0x0601_0002 for a read-only object), and an EDS may be older than the drive.
    let bytes = encode(&entry, text, node)?;
    if let Ok(Value::Int(v)) = decode(entry.data_type, &bytes) {
        crate::project::check_allowed(dict, &entry, v)?;
    }
    Ok((entry, bytes))
}

/// `set OBJ VALUE`: the value checked ([`checked_value`]), then written.
pub fn set(cx: &mut Context, spec: &str, text: &str) -> Result<(), String> {
    let (entry, bytes) = checked_value(&cx.dict, cx.node, spec, text)?;
    cx.write_entry(&entry, &bytes)?;
    if cx.json {
        cx.print_json(&json!({ "address": entry.address(), "name": entry.full_name(), "written": text }));
    } else {
        say!("{} {} := {text}", entry.address(), entry.full_name());
    }
    Ok(())
}
