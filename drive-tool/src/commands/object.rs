//! `get` and `set`: objects by index or name, with type-aware parsing and display.

use std::collections::{BTreeMap, BTreeSet};

use serde_json::json;

use crate::context::Context;
use crate::eds::{Dictionary, Entry};
use crate::value::{decode, encode, type_name, Kind, Value};

/// `get OBJ... [--complete]`: reads each entry the specs name and prints `0xIIII:SS name = value`, or a JSON
/// list; with `complete` (EtherCAT), each object in one CoE complete access.
pub fn get(cx: &mut Context, specs: &[String], complete: bool) -> Result<(), String> {
    let mut entries = Vec::new();
    for spec in specs {
        entries.extend(cx.dict.resolve(spec)?.into_iter().cloned());
    }
    let read = if complete { complete_values(cx, &entries)? } else { BTreeMap::new() };
    let mut out = Vec::new();
    let mut failures = Vec::new();
    for entry in &entries {
        if !entry.access.readable() {
            failures.push(format!("{} ({}) is write-only", entry.address(), entry.full_name()));
            continue;
        }
        let value = match read.get(&(entry.index, entry.sub)) {
            Some(value) => value.clone(),
            None => cx.read_entry_of(cx.node, entry),
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

/// Values read, or why not, by (index, sub-index).
type ValuesRead = BTreeMap<(u16, u8), Result<Value, String>>;

/// The values of `entries` by one CoE complete access per object, by (index, sub-index); a VAR is read as usual.
fn complete_values(cx: &mut Context, entries: &[Entry]) -> Result<ValuesRead, String> {
    let node = cx.node;
    let indices: BTreeSet<u16> = entries.iter().map(|e| e.index).collect();
    let mut values = BTreeMap::new();
    for index in indices {
        // The offsets come from the whole object; the values kept are the entries asked for.
        let object: Vec<Entry> = cx.dict.object(index).into_iter().cloned().collect();
        if let [single] = object.as_slice() {
            // A VAR has no sub-indices to access completely: its one value, read as usual.
            values.insert((index, single.sub), cx.read_entry_of(node, single));
            continue;
        }
        let bytes = complete_upload(cx, index)?;
        for (entry, raw) in object.iter().zip(split_complete(&object, &bytes)?) {
            values.insert((index, entry.sub), decode(entry.data_type, raw));
        }
    }
    Ok(values)
}

#[cfg(target_os = "linux")]
fn complete_upload(cx: &mut Context, index: u16) -> Result<Vec<u8>, String> {
    let node = cx.node;
    let ecat = cx.link.ecat().ok_or("--complete is CoE complete access: it needs --ecat")?;
    ecat.upload_complete(node, index).map_err(|e| format!("drive {node} 0x{index:04X} (complete access): {e}"))
}

#[cfg(not(target_os = "linux"))]
fn complete_upload(_cx: &mut Context, _index: u16) -> Result<Vec<u8>, String> {
    Err("--complete is CoE complete access: it needs --ecat".into())
}

/// The value of each entry of `object` (all its sub-indices, in order) in the bytes of a complete access from
/// sub-index 0, packed as ETG.1000.6 §5.6.2.1.2 and the firmware's server do it: sub-index 0 as UNSIGNED8 padded
/// to 16 bits, then every sub-index's value in order. Objects with BOOLEAN (packed as bits), string or domain
/// entries are refused: their packing is not byte-aligned or has no fixed size.
fn split_complete<'b>(object: &[Entry], bytes: &'b [u8]) -> Result<Vec<&'b [u8]>, String> {
    let mut at = 0usize;
    let mut values = Vec::new();
    for entry in object {
        let len = match (entry.sub, Kind::of(entry.data_type)) {
            (0, _) => 2,
            (_, Some(Kind::Integer { bytes, .. })) => bytes,
            (_, Some(Kind::Real32)) => 4,
            (_, Some(Kind::Real64)) => 8,
            _ => {
                return Err(format!(
                    "{} is {}, which complete access does not pack by bytes; read it without --complete",
                    entry.address(),
                    type_name(entry.data_type)
                ))
            }
        };
        let raw = bytes
            .get(at..at + len)
            .ok_or_else(|| format!("the complete access gave {} bytes, {} needs more", bytes.len(), entry.address()))?;
        values.push(if entry.sub == 0 { &raw[..1] } else { raw });
        at += len;
    }
    Ok(values)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Proves the complete-access packing (ETG.1000.6 §5.6.2.1.2, sub-index 0 padded to 16 bits): 0x1C12 (sub 0
    /// UNSIGNED8, subs 1..4 UNSIGNED16) from 2 + 4 x 2 bytes, each value where the firmware's server puts it; one
    /// byte short is an error naming the entry that lacks it.
    #[test]
    fn complete_access_bytes_split_into_the_objects_entries() {
        let dict = Dictionary::project();
        let object: Vec<Entry> = dict.object(0x1C12).into_iter().cloned().collect();
        assert_eq!(object.len(), 5);
        let bytes = [2, 0, 0x00, 0x16, 0x01, 0x16, 0, 0, 0, 0];
        let values = split_complete(&object, &bytes).expect("split");
        assert_eq!(values, [&[2u8][..], &[0x00, 0x16], &[0x01, 0x16], &[0, 0], &[0, 0]]);
        let short = split_complete(&object, &bytes[..9]).expect_err("one byte short");
        assert!(short.contains("0x1C12:04"), "{short}");
    }

    /// Proves that an object with a string entry is refused for complete access with the entry and its type
    /// named, while the same object with numbers only (0x1018 as the EDS has it) is accepted.
    #[test]
    fn complete_access_refuses_entries_that_are_not_byte_packed() {
        let dict = Dictionary::project();
        let identity: Vec<Entry> = dict.object(0x1018).into_iter().cloned().collect();
        assert!(split_complete(&identity, &[4, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 4, 0, 0, 0]).is_ok());
        let mut with_text = identity.clone();
        with_text[1].data_type = 0x0009;
        let refused = split_complete(&with_text, &[0; 18]).expect_err("a VISIBLE_STRING");
        assert!(refused.contains("0x1018:01") && refused.contains("VISIBLE_STRING"), "{refused}");
    }
}
