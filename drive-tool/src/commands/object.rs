//! `get` and `set`: objects by index or name, with type-aware parsing and display.

use serde_json::json;

use crate::context::Context;
use crate::eds::{Dictionary, Entry};
use crate::value::{decode, encode, type_name, Value};

/// `get OBJ...`: reads each entry the specs name and prints `0xIIII:SS name = value`, or a JSON list.
pub fn get(cx: &mut Context, specs: &[String]) -> Result<(), String> {
    let mut entries = Vec::new();
    for spec in specs {
        entries.extend(cx.dict.resolve(spec)?.into_iter().cloned());
    }
    let mut out = Vec::new();
    let mut failures = Vec::new();
    for entry in &entries {
        if !entry.access.readable() {
            failures.push(format!("{} ({}) is write-only", entry.address(), entry.full_name()));
            continue;
        }
        match cx.read_entry_of(cx.node, entry) {
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
