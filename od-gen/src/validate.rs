//! Checks the raw description and builds the validated [`Description`].
//!
//! Every mistake is reported, not just the first: each check pushes one line
//! `path: object 0x1600:03 'Mapped object 3': reason` and goes on. Checks that need a sound object (sub 0 against
//! the highest sub-index, PDO mappings against their targets) run only on objects whose own entries were
//! readable, so one mistake does not echo as several lines.
//!
//! The rules follow CiA 301 (object codes 7.4.3, data types 7.1, PDO mapping 7.4.8.x, sub 0 of ARRAY/RECORD
//! 7.4.3) and ETG.1000.6 for the sync-manager PDO assignment 0x1C12/0x1C13; the format is defined in the header
//! of `firmware/device.toml`.

use std::collections::BTreeMap;
use std::fmt::Display;

use crate::description::{RawAttrs, RawDevice, RawFile, RawObject, RawSub};
use crate::model::{
    Access, DataType, Description, Device, Object, ObjectCode, PdoMapping, StorageKind, SubObject, Value,
    WriteCondition,
};

/// The mistakes found so far, one formatted line each.
struct Report<'a> {
    path: &'a str,
    lines: Vec<String>,
}

impl Report<'_> {
    fn push(&mut self, at: &str, reason: impl Display) {
        self.lines.push(format!("{}: {}: {}", self.path, at, reason));
    }
}

/// Validates `raw` (read from `path`, which prefixes every report line) and builds the model.
/// On failure returns every mistake found, one line each.
pub fn validate(raw: &RawFile, path: &str) -> Result<Description, Vec<String>> {
    let mut r = Report { path, lines: Vec::new() };
    for key in raw.unknown.keys() {
        r.push("description", format_args!("unknown top-level key '{key}'"));
    }
    let device = match &raw.device {
        Some(d) => device(d, &mut r),
        None => {
            r.push("[device]", "missing [device] table");
            None
        }
    };
    let node_id = device.as_ref().map(|d| d.node_id);

    let mut objects: Vec<(Object, bool)> = Vec::new();
    for (i, o) in raw.objects.iter().enumerate() {
        if let Some(built) = object(o, i + 1, node_id, &mut r) {
            objects.push(built);
        }
    }
    // Stable sort: of two objects with one index, the one declared first stays first and the later one is named.
    objects.sort_by_key(|(o, _)| o.index);
    let mut unique: Vec<(Object, bool)> = Vec::with_capacity(objects.len());
    for (o, complete) in objects {
        match unique.last() {
            Some((prev, _)) if prev.index == o.index => {
                r.push(
                    &obj_at(o.index, &o.name),
                    format_args!("duplicate index (already declared as '{}')", prev.name),
                );
            }
            _ => unique.push((o, complete)),
        }
    }
    let complete: BTreeMap<u16, bool> = unique.iter().map(|(o, c)| (o.index, *c)).collect();
    let description =
        device.map(|device| Description { device, objects: unique.into_iter().map(|(o, _)| o).collect() });

    if let Some(d) = &description {
        device_consistency(d, &mut r);
        handles(d, &mut r);
        pdo_mappings(d, &complete, &mut r);
        pdo_assignments(d, &mut r);
    }
    match description {
        Some(d) if r.lines.is_empty() => Ok(d),
        _ => Err(r.lines),
    }
}

fn obj_at(index: u16, name: &str) -> String {
    format!("object 0x{index:04X} '{name}'")
}

fn sub_at(label: &str, sub: u8, name: &str) -> String {
    format!("object {label}:{sub:02X} '{name}'")
}

fn entry_at(index: u16, s: &SubObject) -> String {
    sub_at(&format!("0x{index:04X}"), s.sub, &s.name)
}

fn hex_or_dec(v: i128) -> String {
    if v >= 0 {
        format!("0x{v:04X}")
    } else {
        v.to_string()
    }
}

// ---------------------------------------------------------------------------------------------------------------
// [device]

fn device(d: &RawDevice, r: &mut Report) -> Option<Device> {
    const AT: &str = "[device]";
    let errors_before = r.lines.len();
    for key in d.unknown.keys() {
        r.push(AT, format_args!("unknown key '{key}'"));
    }
    let mut text = |key: &str, v: &Option<String>| match v {
        Some(s) if !s.is_empty() => s.clone(),
        _ => {
            r.push(AT, format_args!("missing {key}"));
            String::new()
        }
    };
    let vendor_name = text("vendor_name", &d.vendor_name);
    let device_name = text("device_name", &d.device_name);
    let hardware_version = text("hardware_version", &d.hardware_version);
    let software_version = text("software_version", &d.software_version);
    let group_name = text("group_name", &d.group_name);
    let order_code = text("order_code", &d.order_code);

    let mut int = |key: &str, v: Option<i64>, lo: i64, hi: i64| -> i64 {
        match v {
            None => {
                r.push(AT, format_args!("missing {key}"));
                0
            }
            Some(x) if x < lo || x > hi => {
                r.push(AT, format_args!("{key} {x} is outside {lo}..={hi}"));
                0
            }
            Some(x) => x,
        }
    };
    const U16: i64 = u16::MAX as i64;
    const U32: i64 = u32::MAX as i64;
    let vendor_id = int("vendor_id", d.vendor_id, 0, U32) as u32;
    let product_code = int("product_code", d.product_code, 0, U32) as u32;
    let revision = int("revision", d.revision, 0, U32) as u32;
    let serial_number = int("serial_number", d.serial_number, 0, U32) as u32;
    let device_type = int("device_type", d.device_type, 0, U32) as u32;
    // CiA 301 7.5.2.x: node-IDs 1..127.
    let node_id = int("node_id", d.node_id, 1, 127) as u8;
    let bit_rate_kbit = int("bit_rate_kbit", d.bit_rate_kbit, 1, U16) as u16;
    let mailbox_out_start = int("mailbox_out_start", d.mailbox_out_start, 0, U16) as u16;
    let mailbox_out_size = int("mailbox_out_size", d.mailbox_out_size, 1, U16) as u16;
    let mailbox_in_start = int("mailbox_in_start", d.mailbox_in_start, 0, U16) as u16;
    let mailbox_in_size = int("mailbox_in_size", d.mailbox_in_size, 1, U16) as u16;
    let process_out_start = int("process_out_start", d.process_out_start, 0, U16) as u16;
    let process_in_start = int("process_in_start", d.process_in_start, 0, U16) as u16;
    let max_pdo_bytes_ethercat = int("max_pdo_bytes_ethercat", d.max_pdo_bytes_ethercat, 1, U16) as u16;
    let max_pdo_bytes_canopen = int("max_pdo_bytes_canopen", d.max_pdo_bytes_canopen, 1, 8) as u16;
    // CiA 301 bit-timing table (CiA 305 Table 1): the rates a CANopen device may be configured for.
    if d.bit_rate_kbit.is_some() && ![10, 20, 50, 125, 250, 500, 800, 1000].contains(&bit_rate_kbit) {
        r.push(AT, format_args!("bit_rate_kbit {bit_rate_kbit} is not a CiA 301 bit rate"));
    }
    if r.lines.len() != errors_before {
        return None;
    }
    Some(Device {
        vendor_name,
        vendor_id,
        product_code,
        revision,
        serial_number,
        device_name,
        hardware_version,
        software_version,
        group_name,
        order_code,
        device_type,
        node_id,
        bit_rate_kbit,
        mailbox_out_start,
        mailbox_out_size,
        mailbox_in_start,
        mailbox_in_size,
        process_out_start,
        process_in_start,
        max_pdo_bytes_ethercat,
        max_pdo_bytes_canopen,
    })
}

// ---------------------------------------------------------------------------------------------------------------
// Objects

/// Builds one object; `None` when it has no usable index or code. The flag says whether every sub-object could
/// be built (the object-level and cross-object checks need that).
fn object(o: &RawObject, ordinal: usize, node_id: Option<u8>, r: &mut Report) -> Option<(Object, bool)> {
    let name = o.name.clone().unwrap_or_default();
    let (label, index) = match o.index {
        Some(i) if (0..=0xFFFF).contains(&i) => (format!("0x{i:04X}"), Some(i as u16)),
        Some(i) if i < 0 => (i.to_string(), None),
        Some(i) => (format!("{i:#X}"), None),
        None => (format!("#{ordinal}"), None),
    };
    let at = format!("object {label} '{name}'");
    match (o.index, index) {
        (None, _) => r.push(&at, "missing index"),
        (Some(_), None) => r.push(&at, "index is outside 0x0000..0xFFFF"),
        (_, Some(0)) => r.push(&at, "index 0x0000 is not a valid object index"),
        (_, Some(0x0001..=0x0FFF)) => r.push(&at, "index lies in the data-type area 0x0001..0x0FFF"),
        _ => {}
    }
    if o.name.as_deref().is_none_or(str::is_empty) {
        r.push(&at, "missing name");
    }
    if o.description.as_deref().is_none_or(|s| s.trim().is_empty()) {
        r.push(&at, "missing description");
    }
    if o.source.as_deref().is_none_or(|s| s.trim().is_empty()) {
        r.push(&at, "missing source");
    }
    for key in o.attrs.unknown.keys() {
        r.push(&at, format_args!("unknown key '{key}'"));
    }
    let code = match o.code.as_deref() {
        Some("VAR") => Some(ObjectCode::Var),
        Some("ARRAY") => Some(ObjectCode::Array),
        Some("RECORD") => Some(ObjectCode::Record),
        Some(other) => {
            r.push(&at, format_args!("unknown code '{other}' (expected VAR, ARRAY or RECORD)"));
            None
        }
        None => {
            r.push(&at, "missing code");
            None
        }
    };

    let mut complete = true;
    let mut subs = Vec::new();
    match code {
        Some(ObjectCode::Var) => {
            if !o.subs.is_empty() {
                r.push(&at, "a VAR declares its value on the object itself, not in [[object.sub]]");
                complete = false;
                for (k, s) in o.subs.iter().enumerate() {
                    match s.sub {
                        Some(0) | None => {}
                        Some(n) => {
                            r.push(&raw_sub_at(&label, s, k), format_args!("a VAR has only sub-index 0, not {n}"))
                        }
                    }
                }
            }
            let entry_at = sub_at(&label, 0, &name);
            match entry(&entry_at, &o.attrs, o.attrs.default.as_ref(), &name, None, node_id, r) {
                Some(s) => subs.push(s),
                None => complete = false,
            }
        }
        Some(ObjectCode::Array | ObjectCode::Record) => {
            for key in o.attrs.set_keys() {
                r.push(&at, format_args!("'{key}' belongs in [[object.sub]] for an ARRAY or RECORD"));
            }
            for (k, s) in o.subs.iter().enumerate() {
                complete &= expand(&label, s, k, node_id, &mut subs, r);
            }
        }
        None => complete = false,
    }

    subs.sort_by_key(|s| s.sub);
    // Duplicate sub-indices: keep the first declaration, name the later one.
    let mut unique: Vec<SubObject> = Vec::with_capacity(subs.len());
    for s in subs {
        match unique.last() {
            Some(prev) if prev.sub == s.sub => {
                r.push(
                    &sub_at(&label, s.sub, &s.name),
                    format_args!("duplicate sub-index (already declared as '{}')", prev.name),
                );
                complete = false;
            }
            _ => unique.push(s),
        }
    }
    let subs = unique;

    if let (Some(code @ (ObjectCode::Array | ObjectCode::Record)), true) = (code, complete) {
        composite_checks(&at, &label, code, &subs, r);
    }
    Some((
        Object {
            index: index?,
            name,
            code: code?,
            description: o.description.clone().unwrap_or_default(),
            source: o.source.clone().unwrap_or_default(),
            note: o.note.clone(),
            subs,
        },
        complete,
    ))
}

fn raw_sub_at(label: &str, s: &RawSub, position: usize) -> String {
    let name = s.name.as_deref().unwrap_or_default();
    match s.sub {
        Some(n) if (0..=255).contains(&n) => sub_at(label, n as u8, name),
        _ => format!("object {label} sub #{} '{name}'", position + 1),
    }
}

/// Sub 0 of an ARRAY or RECORD, and the common element type of an ARRAY (CiA 301 7.4.3).
fn composite_checks(at: &str, label: &str, code: ObjectCode, subs: &[SubObject], r: &mut Report) {
    let Some(sub0) = subs.iter().find(|s| s.sub == 0) else {
        r.push(at, "missing sub 0 (an ARRAY or RECORD must declare it)");
        return;
    };
    let sub0_at = sub_at(label, 0, &sub0.name);
    if sub0.data_type != DataType::Unsigned8 {
        r.push(&sub0_at, format_args!("sub 0 must be UNSIGNED8, not {}", sub0.data_type.cia_name()));
    }
    let highest = subs.iter().map(|s| s.sub).max().unwrap_or(0);
    match sub0.default {
        // A writable sub 0 counts the entries in use (PDO mapping and assignment objects, 0x1003): it may be
        // below the highest sub-index, never above. Otherwise it is the highest sub-index itself.
        Value::Int(n) if sub0.access.writable() && n > i128::from(highest) => {
            r.push(&sub0_at, format_args!("sub 0 default {n} exceeds the highest sub-index {highest}"));
        }
        Value::Int(n) if !sub0.access.writable() && n != i128::from(highest) => {
            r.push(&sub0_at, format_args!("sub 0 default {n} is not the highest sub-index {highest}"));
        }
        Value::None => r.push(&sub0_at, "sub 0 needs a default (the highest sub-index)"),
        _ => {} // Consistent, or a wrong kind of default (already reported).
    }
    if code == ObjectCode::Array {
        let mut elements = subs.iter().filter(|s| s.sub >= 1);
        if let Some(first) = elements.next() {
            for s in elements.filter(|s| s.data_type != first.data_type) {
                r.push(
                    &sub_at(label, s.sub, &s.name),
                    format_args!(
                        "ARRAY element type {} differs from {} of sub {}",
                        s.data_type.cia_name(),
                        first.data_type.cia_name(),
                        first.sub
                    ),
                );
            }
        }
    }
}

/// Expands one `[[object.sub]]` (with `repeat`) into `out`; returns whether every sub-object could be built.
fn expand(
    label: &str,
    s: &RawSub,
    position: usize,
    node_id: Option<u8>,
    out: &mut Vec<SubObject>,
    r: &mut Report,
) -> bool {
    let at = raw_sub_at(label, s, position);
    for key in s.attrs.unknown.keys() {
        r.push(&at, format_args!("unknown key '{key}'"));
    }
    let name = s.name.clone().unwrap_or_default();
    if name.is_empty() {
        r.push(&at, "missing name");
    }
    let first = match s.sub {
        None => {
            r.push(&at, "missing sub");
            return false;
        }
        Some(n) if !(0..=255).contains(&n) => {
            r.push(&at, format_args!("sub-index {n} is outside 0..=255"));
            return false;
        }
        Some(n) => n,
    };
    let repeat = s.repeat.unwrap_or(1);
    if repeat < 1 {
        r.push(&at, format_args!("repeat {repeat} must be at least 1"));
        return false;
    }
    if first + repeat - 1 > 255 {
        r.push(&at, format_args!("repeat {repeat} from sub {first} runs past sub 255"));
        return false;
    }
    let list = match &s.attrs.default {
        Some(toml::Value::Array(list)) => {
            if s.repeat.is_none() {
                r.push(&at, "a list default needs `repeat`");
                return false;
            }
            if list.len() as i64 != repeat {
                r.push(&at, format_args!("default lists {} values but repeat is {repeat}", list.len()));
                return false;
            }
            Some(list)
        }
        _ => None,
    };
    let mut ok = true;
    for n in 0..repeat {
        let sub = (first + n) as u8;
        let name = if s.repeat.is_some() { name.replace("{n}", &(n + 1).to_string()) } else { name.clone() };
        let default = match list {
            Some(list) => list.get(n as usize),
            None => s.attrs.default.as_ref(),
        };
        match entry(&sub_at(label, sub, &name), &s.attrs, default, &name, s.description.as_deref(), node_id, r) {
            Some(mut e) => {
                e.sub = sub;
                if s.repeat.is_some() {
                    e.handle = e.handle.map(|h| h.replace("{n}", &(n + 1).to_string()));
                }
                out.push(e);
            }
            None => ok = false,
        }
    }
    ok
}

/// Parses `0x1A`, `-5`, `1_000` (the integer forms TOML allows, for the text after `$NODEID+`).
fn parse_int(text: &str) -> Option<i128> {
    let t = text.trim().replace('_', "");
    let (negative, t) = match t.strip_prefix('-') {
        Some(rest) => (true, rest.to_string()),
        None => (false, t.strip_prefix('+').unwrap_or(&t).to_string()),
    };
    let v = if let Some(hex) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        i128::from_str_radix(hex, 16).ok()?
    } else {
        t.parse::<i128>().ok()?
    };
    Some(if negative { -v } else { v })
}

fn range_text(t: DataType) -> String {
    match t.range() {
        Some((lo, hi)) => format!("the {} range {lo}..={hi}", t.cia_name()),
        None => t.cia_name().to_string(),
    }
}

/// Builds one sub-object from its attributes; `None` when its type or access is missing or unknown.
fn entry(
    at: &str,
    a: &RawAttrs,
    default: Option<&toml::Value>,
    name: &str,
    description: Option<&str>,
    node_id: Option<u8>,
    r: &mut Report,
) -> Option<SubObject> {
    let data_type = match a.data_type.as_deref() {
        None => {
            r.push(at, "missing type");
            None
        }
        Some(word) => {
            let t = [
                DataType::Boolean,
                DataType::Integer8,
                DataType::Integer16,
                DataType::Integer32,
                DataType::Integer64,
                DataType::Unsigned8,
                DataType::Unsigned16,
                DataType::Unsigned32,
                DataType::Unsigned64,
                DataType::VisibleString,
                DataType::OctetString,
                DataType::Domain,
            ]
            .into_iter()
            .find(|t| t.cia_name() == word);
            if t.is_none() {
                r.push(at, format_args!("unknown type '{word}'"));
            }
            t
        }
    };
    let access = match a.access.as_deref() {
        None => {
            r.push(at, "missing access");
            None
        }
        Some("ro") => Some(Access::ReadOnly),
        Some("wo") => Some(Access::WriteOnly),
        Some("rw") => Some(Access::ReadWrite),
        Some("const") => Some(Access::Const),
        Some(word) => {
            r.push(at, format_args!("unknown access '{word}' (expected ro, wo, rw or const)"));
            None
        }
    };
    let pdo = match a.pdo.as_deref() {
        None | Some("no") => PdoMapping::No,
        Some("rx") => PdoMapping::Rx,
        Some("tx") => PdoMapping::Tx,
        Some("both") => PdoMapping::Both,
        Some(word) => {
            r.push(at, format_args!("unknown pdo '{word}' (expected no, rx, tx or both)"));
            PdoMapping::No
        }
    };
    let writable_in = match a.writable_in.as_deref() {
        None | Some("always") => WriteCondition::Always,
        Some("pre-op") => WriteCondition::PreOperational,
        Some("power-disabled") => WriteCondition::PowerDisabled,
        Some("pre-op-power-disabled") => WriteCondition::PreOperationalPowerDisabled,
        Some(word) => {
            r.push(
                at,
                format_args!(
                    "unknown writable_in '{word}' (expected always, pre-op, power-disabled or pre-op-power-disabled)"
                ),
            );
            WriteCondition::Always
        }
    };
    let storage = match a.storage.as_deref() {
        None => None,
        Some("ram") => Some(StorageKind::Ram),
        Some("const") => Some(StorageKind::Const),
        Some("application") => Some(StorageKind::Application),
        Some(word) => {
            r.push(at, format_args!("unknown storage '{word}' (expected ram, const or application)"));
            return None;
        }
    };
    let (data_type, access) = (data_type?, access?);
    let storage = storage.unwrap_or(if access == Access::Const { StorageKind::Const } else { StorageKind::Ram });
    let type_name = data_type.cia_name();
    let is_string = matches!(data_type, DataType::VisibleString | DataType::OctetString);
    let range = data_type.range();

    // Length of strings and domains.
    let length = match a.length {
        Some(_) if data_type.is_integer() => {
            r.push(at, "length applies only to VISIBLE_STRING, OCTET_STRING and DOMAIN");
            None
        }
        Some(n) if !(1..=i64::from(u16::MAX)).contains(&n) => {
            r.push(at, format_args!("length {n} is outside 1..=65535"));
            None
        }
        Some(n) => Some(n as usize),
        None => {
            if is_string {
                r.push(at, format_args!("{type_name} needs `length` (its capacity in bytes)"));
            } else if data_type == DataType::Domain && storage != StorageKind::Application {
                r.push(at, format_args!("DOMAIN in {} storage needs `length`", storage.word()));
            }
            None
        }
    };

    // The default value.
    let value = match default {
        None => Value::None,
        Some(_) if data_type == DataType::Domain => {
            r.push(at, "DOMAIN takes no default");
            Value::None
        }
        Some(toml::Value::Integer(v)) if data_type.is_integer() => Value::Int(i128::from(*v)),
        Some(toml::Value::Boolean(b)) if data_type == DataType::Boolean => Value::Int(i128::from(*b)),
        Some(toml::Value::String(s)) if s.starts_with("$NODEID") => {
            let offset =
                s.strip_prefix("$NODEID").and_then(|rest| if rest.is_empty() { Some(0) } else { parse_int(rest) });
            match offset {
                None => {
                    r.push(at, format_args!("cannot read default '{s}' (expected $NODEID+<integer>)"));
                    Value::None
                }
                Some(_) if !data_type.is_integer() => {
                    r.push(at, format_args!("a $NODEID default needs an integer type, not {type_name}"));
                    Value::None
                }
                Some(off) => Value::NodeIdPlus(off),
            }
        }
        Some(toml::Value::String(s)) if is_string => Value::Text(s.clone()),
        Some(other) => {
            let expected = if is_string { "a string" } else { "an integer" };
            r.push(at, format_args!("default {other} must be {expected} for {type_name}"));
            Value::None
        }
    };

    // min, max and values apply to integers only.
    let in_range = |v: i128| range.is_none_or(|(lo, hi)| lo <= v && v <= hi);
    let (min, max) = (a.min.map(i128::from), a.max.map(i128::from));
    if !data_type.is_integer() && (min.is_some() || max.is_some()) {
        r.push(at, format_args!("min/max apply only to integer types, not {type_name}"));
    }
    if !data_type.is_integer() && a.values.is_some() {
        r.push(at, format_args!("values apply only to integer types, not {type_name}"));
    }
    if data_type.is_integer() {
        for (key, bound) in [("min", min), ("max", max)] {
            if let Some(b) = bound.filter(|b| !in_range(*b)) {
                r.push(at, format_args!("{key} {b} is outside {}", range_text(data_type)));
            }
        }
    }
    if let (Some(lo), Some(hi)) = (min, max) {
        if lo > hi {
            r.push(at, format_args!("min {lo} is greater than max {hi}"));
        }
    }
    let values = a.values.as_ref().map(|v| {
        let mut v: Vec<i128> = v.iter().map(|x| i128::from(*x)).collect();
        v.sort_unstable();
        v.dedup();
        v
    });
    if let Some(list) = &values {
        if list.is_empty() {
            r.push(at, "values is empty");
        }
        if data_type.is_integer() {
            for v in list.iter().filter(|v| !in_range(**v)) {
                r.push(at, format_args!("value {v} in values is outside {}", range_text(data_type)));
            }
        }
        if min.is_some() || max.is_some() {
            r.push(at, "values and min/max exclude each other; use one");
        }
    }

    // The default against the type range, min/max and values.
    let check_int = |r: &mut Report, v: i128, shown: &str| {
        if !in_range(v) {
            r.push(at, format_args!("default {shown} is outside {}", range_text(data_type)));
        } else if min.is_some_and(|lo| v < lo) || max.is_some_and(|hi| v > hi) {
            let bound = |b: Option<i128>| b.map(|b| b.to_string()).unwrap_or_default();
            r.push(at, format_args!("default {shown} is outside min..max {}..={}", bound(min), bound(max)));
        } else if let Some(list) = values.as_ref().filter(|l| !l.is_empty() && !l.contains(&v)) {
            r.push(at, format_args!("default {shown} is not one of values {list:?}"));
        }
    };
    match &value {
        Value::Int(v) => check_int(r, *v, &v.to_string()),
        Value::NodeIdPlus(off) => {
            if let Some(id) = node_id {
                check_int(r, off + i128::from(id), &format!("$NODEID+{off:#X} (node-ID {id})"));
            }
            if storage != StorageKind::Ram {
                r.push(at, format_args!("a $NODEID default needs storage ram, not {}", storage.word()));
            }
        }
        Value::Text(s) => {
            if let Some(n) = length.filter(|n| s.len() > *n) {
                r.push(at, format_args!("default is {} bytes, longer than length {n}", s.len()));
            }
        }
        Value::None => {}
    }

    // PDO mapping, persistence and storage.
    if pdo != PdoMapping::No && data_type.pdo_bits().is_none() {
        r.push(at, format_args!("{type_name} cannot be PDO-mapped (pdo = \"{}\")", pdo.word()));
    }
    let persistent = a.persistent.unwrap_or(false);
    if persistent && access != Access::ReadWrite {
        r.push(at, format_args!("persistent on a {} entry (only rw values are saved)", access.word()));
    } else if persistent && storage == StorageKind::Application {
        r.push(at, "persistent on application storage (the application saves its own values)");
    }
    if access == Access::Const && storage != StorageKind::Const {
        r.push(at, format_args!("access const needs storage const, not {}", storage.word()));
    }
    if storage == StorageKind::Const && access.writable() {
        r.push(at, format_args!("storage const cannot hold a writable ({}) entry", access.word()));
    }
    if storage == StorageKind::Const && matches!(value, Value::None) && default.is_none() {
        r.push(at, "storage const needs a default");
    }

    // Typed handle.
    if let Some(h) = &a.handle {
        // A repeated sub-object names its handles with `{n}` (1-based), like its name.
        if !is_snake_case(&h.replace("{n}", "1")) {
            r.push(at, format_args!("handle '{h}' is not a snake_case identifier"));
        }
        if storage != StorageKind::Ram {
            r.push(at, format_args!("handle '{h}' needs storage ram, not {}", storage.word()));
        }
        if data_type.fixed_size().is_none() {
            r.push(at, format_args!("handle '{h}' needs a fixed-size type, not {type_name}"));
        }
    }

    Some(SubObject {
        sub: 0,
        name: name.to_string(),
        data_type,
        access,
        pdo,
        default: value,
        min,
        max,
        values,
        length: if is_string || data_type == DataType::Domain { length } else { None },
        unit: a.unit.clone(),
        persistent,
        writable_in,
        storage,
        handle: a.handle.clone(),
        description: description.map(str::to_string),
    })
}

/// `[a-z][a-z0-9_]*`, without a trailing or doubled underscore.
fn is_snake_case(s: &str) -> bool {
    let mut chars = s.chars();
    chars.next().is_some_and(|c| c.is_ascii_lowercase())
        && chars.all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        && !s.ends_with('_')
        && !s.contains("__")
}

// ---------------------------------------------------------------------------------------------------------------
// Cross-object checks

/// 0x1000, 0x1008, 0x1009, 0x100A and 0x1018:01..03 must say what `[device]` says (every generated file takes
/// the identity from `[device]`, the firmware's table from the objects).
fn device_consistency(d: &Description, r: &mut Report) {
    let dev = &d.device;
    let ints: [(u16, u8, &str, u32); 4] = [
        (0x1000, 0, "device_type", dev.device_type),
        (0x1018, 1, "vendor_id", dev.vendor_id),
        (0x1018, 2, "product_code", dev.product_code),
        (0x1018, 3, "revision", dev.revision),
    ];
    for (index, sub, key, expected) in ints {
        if let Some(s) = d.entry(index, sub) {
            let at = entry_at(index, s);
            match &s.default {
                Value::Int(v) if *v == i128::from(expected) => {}
                Value::Int(v) => {
                    r.push(&at, format_args!("default 0x{v:08X} differs from [device] {key} 0x{expected:08X}"))
                }
                _ => r.push(&at, format_args!("default missing; [device] {key} is 0x{expected:08X}")),
            }
        }
    }
    let texts: [(u16, &str, &str); 3] = [
        (0x1008, "device_name", &dev.device_name),
        (0x1009, "hardware_version", &dev.hardware_version),
        (0x100A, "software_version", &dev.software_version),
    ];
    for (index, key, expected) in texts {
        if let Some(s) = d.entry(index, 0) {
            let at = entry_at(index, s);
            match &s.default {
                Value::Text(v) if v == expected => {}
                Value::Text(v) => r.push(&at, format_args!("default '{v}' differs from [device] {key} '{expected}'")),
                _ => r.push(&at, format_args!("default missing; [device] {key} is '{expected}'")),
            }
        }
    }
}

/// Handle names become constants in one module: they must be unique.
fn handles(d: &Description, r: &mut Report) {
    let mut seen: BTreeMap<&str, String> = BTreeMap::new();
    for o in &d.objects {
        for s in &o.subs {
            if let Some(h) = &s.handle {
                let at = entry_at(o.index, s);
                match seen.get(h.as_str()) {
                    Some(first) => r.push(&at, format_args!("handle '{h}' is also used by {first}")),
                    None => {
                        seen.insert(h, at);
                    }
                }
            }
        }
    }
}

/// Whether `index` is a receive (Some(true)) or transmit (Some(false)) PDO mapping object (CiA 301 7.5.2.36,
/// 7.5.2.38).
fn mapping_direction(index: u16) -> Option<bool> {
    match index {
        0x1600..=0x17FF => Some(true),
        0x1A00..=0x1BFF => Some(false),
        _ => None,
    }
}

/// Default PDO mappings (CiA 301 7.5.2.36/38): each mapped entry exists, is mappable in the PDO's direction
/// and has its type's bit length; the whole mapping fits the longest PDO of both fieldbuses (the same defaults
/// serve EtherCAT and CANopen).
fn pdo_mappings(d: &Description, complete: &BTreeMap<u16, bool>, r: &mut Report) {
    for o in &d.objects {
        let Some(rx) = mapping_direction(o.index) else { continue };
        if o.code == ObjectCode::Var || complete.get(&o.index) != Some(&true) {
            continue;
        }
        let Some(Value::Int(count)) = o.subs.first().filter(|s| s.sub == 0).map(|s| &s.default) else { continue };
        // A count above the highest sub-index is already reported against sub 0.
        let highest = o.subs.last().map_or(0, |s| s.sub);
        let mut bits: u32 = 0;
        for k in 1..=(*count).clamp(0, i128::from(highest)) as u8 {
            let Some(s) = o.subs.iter().find(|s| s.sub == k) else {
                r.push(
                    &obj_at(o.index, &o.name),
                    format_args!("sub 0 default counts {count} mapped objects but sub {k} is not declared"),
                );
                continue;
            };
            let at = entry_at(o.index, s);
            let Value::Int(v) = s.default else {
                r.push(&at, "a mapping entry counted by sub 0 needs an integer default");
                continue;
            };
            let (index, sub, len) = ((v >> 16) as u16, (v >> 8) as u8, v as u8);
            let target = format!("0x{index:04X}:{sub:02X}");
            if v == 0 {
                r.push(&at, "maps nothing (0) although sub 0 counts it");
                continue;
            }
            bits += u32::from(len);
            // Index 0 is an EtherCAT gap; 0x0001..0x0007 are CANopen dummy entries of that data type.
            if index == 0 {
                continue;
            }
            if (0x0001..=0x0007).contains(&index) {
                let dummy_bits = [1, 8, 16, 32, 8, 16, 32][usize::from(index - 1)];
                if sub != 0 || len != dummy_bits {
                    r.push(&at, format_args!("dummy mapping {target} must be sub 0 with {dummy_bits} bits"));
                }
                continue;
            }
            let Some(e) = d.entry(index, sub) else {
                r.push(&at, format_args!("maps {target}, which is not declared"));
                continue;
            };
            let name = &e.name;
            let Some(type_bits) = e.data_type.pdo_bits() else {
                r.push(
                    &at,
                    format_args!("maps {target} '{name}', which is not PDO-mappable ({})", e.data_type.cia_name()),
                );
                continue;
            };
            if e.pdo == PdoMapping::No {
                r.push(&at, format_args!("maps {target} '{name}', which is not PDO-mappable (pdo = \"no\")"));
            } else if rx && !e.pdo.rx() {
                r.push(
                    &at,
                    format_args!("maps {target} '{name}' into a receive PDO, but its pdo is \"{}\"", e.pdo.word()),
                );
            } else if !rx && !e.pdo.tx() {
                r.push(
                    &at,
                    format_args!("maps {target} '{name}' into a transmit PDO, but its pdo is \"{}\"", e.pdo.word()),
                );
            }
            if u16::from(len) != type_bits {
                r.push(
                    &at,
                    format_args!(
                        "maps {target} '{name}' with {len} bits, but {} takes {type_bits}",
                        e.data_type.cia_name()
                    ),
                );
            }
        }
        let bytes = bits.div_ceil(8);
        let dev = &d.device;
        let exceeded: Vec<String> = [
            ("max_pdo_bytes_ethercat", dev.max_pdo_bytes_ethercat),
            ("max_pdo_bytes_canopen", dev.max_pdo_bytes_canopen),
        ]
        .iter()
        .filter(|(_, limit)| bytes > u32::from(*limit))
        .map(|(key, limit)| format!("{key} ({limit})"))
        .collect();
        if !exceeded.is_empty() {
            r.push(
                &obj_at(o.index, &o.name),
                format_args!("default mapping is {bytes} bytes, longer than {}", exceeded.join(" and ")),
            );
        }
    }
}

/// Default sync-manager PDO assignments (ETG.1000.6 5.6.7.4.x: 0x1C12 for SM2 outputs = RxPDOs, 0x1C13 for SM3
/// inputs = TxPDOs): every assigned index must be a declared mapping object of the right direction.
fn pdo_assignments(d: &Description, r: &mut Report) {
    for (index, rx) in [(0x1C12u16, true), (0x1C13u16, false)] {
        let Some(o) = d.object(index) else { continue };
        let Some(Value::Int(count)) = o.subs.first().filter(|s| s.sub == 0).map(|s| &s.default) else { continue };
        let highest = o.subs.last().map_or(0, |s| s.sub);
        for k in 1..=(*count).clamp(0, i128::from(highest)) as u8 {
            let Some(s) = o.subs.iter().find(|s| s.sub == k) else {
                r.push(
                    &obj_at(o.index, &o.name),
                    format_args!("sub 0 default counts {count} assigned PDOs but sub {k} is not declared"),
                );
                continue;
            };
            let at = entry_at(o.index, s);
            let Value::Int(v) = s.default else {
                r.push(&at, "an assignment counted by sub 0 needs an integer default");
                continue;
            };
            let (kind, range) = if rx { ("receive", "0x1600..0x17FF") } else { ("transmit", "0x1A00..0x1BFF") };
            let target = u16::try_from(v).ok();
            if target.and_then(mapping_direction) != Some(rx) {
                r.push(
                    &at,
                    format_args!("assigns {}, which is not a {kind} PDO mapping object ({range})", hex_or_dec(v)),
                );
            } else if target.and_then(|t| d.object(t)).is_none() {
                r.push(&at, format_args!("assigns 0x{v:04X}, which is not declared"));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_node_id_offsets() {
        assert_eq!(parse_int("+0x180"), Some(0x180));
        assert_eq!(parse_int("+384"), Some(384));
        assert_eq!(parse_int("-1"), Some(-1));
        assert_eq!(parse_int("+0x1_80"), Some(0x180));
        assert_eq!(parse_int("+x"), None);
    }

    #[test]
    fn snake_case_names() {
        assert!(is_snake_case("controlword"));
        assert!(is_snake_case("target_position_2"));
        assert!(!is_snake_case("Controlword"));
        assert!(!is_snake_case("_x"));
        assert!(!is_snake_case("x_"));
        assert!(!is_snake_case("a__b"));
        assert!(!is_snake_case("2x"));
        assert!(!is_snake_case(""));
    }
}
