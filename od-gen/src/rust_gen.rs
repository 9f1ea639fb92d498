//! Emits `od_generated.rs`: the firmware's dictionary tables, built from the types of `firmware/src/od/entry.rs`.
//!
//! The file is `include!`d inside `pub mod generated { use super::entry::*; ... }` and holds:
//! - `ENTRIES`: one `Entry` per (index, sub-index), sorted, for binary search (architecture convention 7);
//! - `OBJECTS`: one `Object` per index, sorted (its entries found by index in `ENTRIES`);
//! - `NAMES`: the text of every object's and entry's name, each `Name` a place in it;
//! - `VALUE_BYTES` and `DEFAULT_VALUES`: the RAM value storage image with every default, little-endian
//!   (`DEFAULT_NONZERO_MASK` and `DEFAULT_NONZERO`: the same, sparse, as the image keeps it);
//! - `handles`: a typed `Handle<T>` per `handle` attribute, so that the control tiers never search;
//! - the device constants (identity, CANopen defaults, PDO limits, sync-manager layout).

use std::collections::BTreeMap;
use std::fmt::Write;

use crate::model::{
    Access, DataType, Description, ObjectCode, PdoMapping, StorageKind, SubObject, Value, WriteCondition,
};

/// Where one RAM entry lives in the value storage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RamSlot {
    /// Byte offset into the value storage.
    pub offset: u16,
    /// Capacity in bytes.
    pub len: u16,
}

/// The RAM value storage layout of a description.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Slot of every RAM entry, by (index, sub-index).
    pub slots: BTreeMap<(u16, u8), RamSlot>,
    /// Total size of the value storage in bytes.
    pub value_bytes: usize,
}

/// Capacity in bytes of a RAM entry: its type's size, or the declared length of a string or domain.
fn capacity(s: &SubObject) -> Option<usize> {
    s.data_type.fixed_size().or(s.length)
}

/// Lays out the RAM entries: each value naturally aligned to its size. Entries are placed by descending
/// alignment (8, 4, 2, then 1-byte values and strings), each group in (index, sub) order, so no padding is
/// ever needed.
pub fn ram_layout(d: &Description) -> Result<Layout, String> {
    let mut ram: Vec<(usize, u16, &SubObject)> = Vec::new();
    for o in &d.objects {
        for s in o.subs.iter().filter(|s| s.storage == StorageKind::Ram) {
            let align = s.data_type.fixed_size().unwrap_or(1);
            ram.push((align, o.index, s));
        }
    }
    // Stable sort keeps (index, sub) order inside each alignment group.
    ram.sort_by_key(|(align, _, _)| std::cmp::Reverse(*align));
    let mut slots = BTreeMap::new();
    let mut offset = 0usize;
    for (_, index, s) in ram {
        let len = capacity(s).ok_or_else(|| format!("0x{index:04X}:{:02X}: a RAM entry needs a length", s.sub))?;
        let (Ok(off16), Ok(len16)) = (u16::try_from(offset), u16::try_from(len)) else {
            return Err(format!("the RAM value storage outgrows 64 KiB at 0x{index:04X}:{:02X}", s.sub));
        };
        slots.insert((index, s.sub), RamSlot { offset: off16, len: len16 });
        offset += len;
    }
    Ok(Layout { slots, value_bytes: offset })
}

/// Little-endian bytes of `value` in a slot of `len` bytes (two's complement for negative integers; a
/// `$NODEID` default holds just its offset; strings zero-padded; no default is all zeros).
pub fn value_bytes(value: &Value, len: usize) -> Vec<u8> {
    let mut bytes = match value {
        Value::Int(v) | Value::NodeIdPlus(v) => v.to_le_bytes().to_vec(),
        Value::Text(t) => t.as_bytes().to_vec(),
        Value::None => Vec::new(),
    };
    bytes.resize(len, 0);
    bytes
}

fn object_code(c: ObjectCode) -> &'static str {
    match c {
        ObjectCode::Var => "ObjectCode::Var",
        ObjectCode::Array => "ObjectCode::Array",
        ObjectCode::Record => "ObjectCode::Record",
    }
}

fn data_type(t: DataType) -> &'static str {
    match t {
        DataType::Boolean => "DataType::Boolean",
        DataType::Integer8 => "DataType::Integer8",
        DataType::Integer16 => "DataType::Integer16",
        DataType::Integer32 => "DataType::Integer32",
        DataType::Integer64 => "DataType::Integer64",
        DataType::Unsigned8 => "DataType::Unsigned8",
        DataType::Unsigned16 => "DataType::Unsigned16",
        DataType::Unsigned32 => "DataType::Unsigned32",
        DataType::Unsigned64 => "DataType::Unsigned64",
        DataType::VisibleString => "DataType::VisibleString",
        DataType::OctetString => "DataType::OctetString",
        DataType::Domain => "DataType::Domain",
    }
}

/// The Rust type a handle of this data type reads and writes.
pub fn rust_type(t: DataType) -> Option<&'static str> {
    Some(match t {
        DataType::Boolean => "bool",
        DataType::Integer8 => "i8",
        DataType::Integer16 => "i16",
        DataType::Integer32 => "i32",
        DataType::Integer64 => "i64",
        DataType::Unsigned8 => "u8",
        DataType::Unsigned16 => "u16",
        DataType::Unsigned32 => "u32",
        DataType::Unsigned64 => "u64",
        DataType::VisibleString | DataType::OctetString | DataType::Domain => return None,
    })
}

fn access(a: Access) -> &'static str {
    match a {
        Access::ReadOnly => "Access::ReadOnly",
        Access::WriteOnly => "Access::WriteOnly",
        Access::ReadWrite => "Access::ReadWrite",
        Access::Const => "Access::Const",
    }
}

fn pdo(p: PdoMapping) -> &'static str {
    match p {
        PdoMapping::No => "PdoMapping::No",
        PdoMapping::Rx => "PdoMapping::Rx",
        PdoMapping::Tx => "PdoMapping::Tx",
        PdoMapping::Both => "PdoMapping::Both",
    }
}

fn write_condition(w: WriteCondition) -> &'static str {
    match w {
        WriteCondition::Always => "WriteCondition::Always",
        WriteCondition::PreOperational => "WriteCondition::PreOperational",
        WriteCondition::PowerDisabled => "WriteCondition::PowerDisabled",
        WriteCondition::PreOperationalPowerDisabled => "WriteCondition::PreOperationalPowerDisabled",
    }
}

/// `Limits::...` for an entry: `OneOf` for `values`, `Signed`/`Unsigned` with the type's range filling in a
/// missing bound, `None` without bounds.
fn limits(s: &SubObject) -> String {
    if let Some(values) = &s.values {
        let list: Vec<String> = values.iter().map(i128::to_string).collect();
        return format!("Limits::OneOf(&[{}])", list.join(", "));
    }
    let (Some((lo, hi)), true) = (s.data_type.range(), s.min.is_some() || s.max.is_some()) else {
        return limits_none();
    };
    let (min, max) = (s.min.unwrap_or(lo), s.max.unwrap_or(hi));
    if s.data_type.is_signed() {
        format!("Limits::Signed {{ min: {min}, max: {max} }}")
    } else {
        format!("Limits::Unsigned {{ min: {min}, max: {max} }}")
    }
}

/// Whether the bounds of `s`'s limits fit the 32-bit fields of `Limits` (signed or unsigned as its type).
fn limits_fit(s: &SubObject) -> bool {
    if let Some(values) = &s.values {
        return values.iter().all(|v| i32::try_from(*v).is_ok());
    }
    let (Some((lo, hi)), true) = (s.data_type.range(), s.min.is_some() || s.max.is_some()) else {
        return true;
    };
    let (min, max) = (s.min.unwrap_or(lo), s.max.unwrap_or(hi));
    if s.data_type.is_signed() {
        i32::try_from(min).is_ok() && i32::try_from(max).is_ok()
    } else {
        u32::try_from(min).is_ok() && u32::try_from(max).is_ok()
    }
}

/// The entry without limits, position 0 of `LIMITS`.
fn limits_none() -> String {
    "Limits::None".to_string()
}

/// A byte-string literal: printable ASCII as is, everything else escaped.
fn byte_string(bytes: &[u8]) -> String {
    let mut out = String::from("b\"");
    for &b in bytes {
        match b {
            b'"' => out.push_str("\\\""),
            b'\\' => out.push_str("\\\\"),
            0x20..=0x7E => out.push(char::from(b)),
            _ => {
                let _ = write!(out, "\\x{b:02x}");
            }
        }
    }
    out.push('"');
    out
}

fn storage(s: &SubObject, slot: Option<RamSlot>) -> Result<String, String> {
    Ok(match s.storage {
        StorageKind::Ram => {
            let slot = slot.ok_or("RAM entry without a slot")?;
            let node_id_relative = matches!(s.default, Value::NodeIdPlus(_));
            format!(
                "Storage::Ram {{ offset: {}, len: {}, node_id_relative: {node_id_relative} }}",
                slot.offset, slot.len
            )
        }
        // `Storage::Const` holds a thin reference to the bytes' slice (`entry.rs` `ConstRef`).
        StorageKind::Const => {
            let bytes = match (&s.default, s.data_type.fixed_size()) {
                (Value::Text(t), _) => t.as_bytes().to_vec(),
                (v, Some(n)) => value_bytes(v, n),
                (_, None) => Vec::new(),
            };
            format!("Storage::Const(ConstRef::new(&({} as &[u8])))", byte_string(&bytes))
        }
        StorageKind::Application => "Storage::Application".to_string(),
    })
}

/// Where each name lies in the text of every name: its offset and length, by the name.
type NamePlaces<'a> = BTreeMap<&'a str, (u16, u8)>;

/// The text of every name (`NAMES`) and where each name lies in it: every distinct name once, the longest first,
/// and a name that is already part of the text not again.
fn name_text(d: &Description) -> Result<(String, NamePlaces<'_>), String> {
    let mut names: Vec<&str> = d
        .objects
        .iter()
        .flat_map(|o| std::iter::once(o.name.as_str()).chain(o.subs.iter().map(|s| s.name.as_str())))
        .filter(|n| !n.is_empty())
        .collect();
    names.sort_by(|a, b| b.len().cmp(&a.len()).then(a.cmp(b)));
    names.dedup();
    let mut text = String::new();
    let mut places = BTreeMap::new();
    for name in names {
        let at = text.find(name).unwrap_or_else(|| {
            text.push_str(name);
            text.len() - name.len()
        });
        let (Ok(offset), Ok(len)) = (u16::try_from(at), u8::try_from(name.len())) else {
            return Err(format!(
                "the name '{name}' does not fit a Name (longer than 255 bytes or past 64 KiB of names)"
            ));
        };
        places.insert(name, (offset, len));
    }
    Ok((text, places))
}

/// Renders `od_generated.rs` for `d`. Fails only when the tables outgrow their index types (64 Ki entries or
/// 64 KiB of RAM values).
pub fn rust(d: &Description) -> Result<String, String> {
    rust_with_names(d, true)
}

/// [`rust`], with the objects' and entries' names, or with every name empty (`names` false): an image that serves
/// no names (the CANopen image: only the CoE SDO information service sends them) then leaves the strings out of
/// flash.
pub fn rust_with_names(d: &Description, names: bool) -> Result<String, String> {
    let (text, places) = if names { name_text(d)? } else { (String::new(), BTreeMap::new()) };
    let name = |n: &str| match places.get(n) {
        Some((offset, len)) => format!("Name::new({offset}, {len})"),
        None => "Name::EMPTY".to_string(),
    };
    let layout = ram_layout(d)?;
    let entry_count: usize = d.objects.iter().map(|o| o.subs.len()).sum();
    let mut out = String::new();
    let w = &mut out;
    let _ = writeln!(w, "// @generated by od-gen from the device description. Do not edit: edit device.toml.");
    let _ = writeln!(
        w,
        "// {} objects, {entry_count} entries, {} bytes of RAM values.",
        d.objects.len(),
        layout.value_bytes
    );
    let _ = writeln!(w);

    // Every distinct range once, `Limits::None` first (`LimitsRef::NONE`); an entry names its range by position.
    let mut ranges = vec![limits_none()];
    for o in &d.objects {
        if let Some(s) = o.subs.iter().find(|s| !limits_fit(s)) {
            return Err(format!("0x{:04X}:{:02X}: limits beyond the 32-bit bounds of Limits", o.index, s.sub));
        }
    }
    for s in d.objects.iter().flat_map(|o| o.subs.iter()) {
        let range = limits(s);
        if !ranges.contains(&range) {
            ranges.push(range);
        }
    }
    if ranges.len() > usize::from(u8::MAX) + 1 {
        return Err(format!("{} distinct limits do not fit the u8 positions of LimitsRef", ranges.len()));
    }
    let range_of = |s: &SubObject| ranges.iter().position(|r| *r == limits(s)).unwrap_or(0);
    let _ = writeln!(w, "/// Every distinct range of the entries' limits; `Entry::limits` is a position here.");
    let _ = writeln!(w, "pub static LIMITS: [Limits; {}] = [", ranges.len());
    for range in &ranges {
        let _ = writeln!(w, "    {range},");
    }
    let _ = writeln!(w, "];\n");

    let _ = writeln!(w, "/// Every entry of the dictionary, sorted by (index, sub-index).");
    let _ = writeln!(w, "pub static ENTRIES: [Entry; {entry_count}] = [");
    for o in &d.objects {
        for s in &o.subs {
            let _ = writeln!(
                w,
                "    Entry {{ index: 0x{:04X}, sub: 0x{:02X}, name: {}, data_type: {}, attributes: Attributes::new({}, {}, \
                 {}, {}), limits: LimitsRef({}), storage: {} }},",
                o.index,
                s.sub,
                name(&s.name),
                data_type(s.data_type),
                access(s.access),
                pdo(s.pdo),
                s.persistent,
                write_condition(s.writable_in),
                range_of(s),
                storage(s, layout.slots.get(&(o.index, s.sub)).copied())
                    .map_err(|e| format!("0x{:04X}:{:02X}: {e}", o.index, s.sub))?,
            );
        }
    }
    let _ = writeln!(w, "];\n");

    let _ = writeln!(w, "/// Every object of the dictionary, sorted by index (its entries: `Table::entries_of`).");
    let _ = writeln!(w, "pub static OBJECTS: [Object; {}] = [", d.objects.len());
    for o in &d.objects {
        let max_sub = o.subs.iter().map(|s| s.sub).max().unwrap_or(0);
        let _ = writeln!(
            w,
            "    Object {{ index: 0x{:04X}, name: {}, object_code: {}, max_sub: {max_sub} }},",
            o.index,
            name(&o.name),
            object_code(o.code),
        );
    }
    let _ = writeln!(w, "];\n");

    let _ = writeln!(w, "/// The text of every name; each `Name` of `ENTRIES` and `OBJECTS` is a place in it.");
    let _ = writeln!(w, "pub static NAMES: &str = {text:?};\n");

    let mut image = vec![0u8; layout.value_bytes];
    for o in &d.objects {
        for s in &o.subs {
            if let Some(slot) = layout.slots.get(&(o.index, s.sub)) {
                let start = usize::from(slot.offset);
                let end = start + usize::from(slot.len);
                if let Some(dst) = image.get_mut(start..end) {
                    dst.copy_from_slice(&value_bytes(&s.default, usize::from(slot.len)));
                }
            }
        }
    }
    let _ = writeln!(w, "/// Size of the RAM value storage in bytes.");
    let _ = writeln!(w, "pub const VALUE_BYTES: usize = {};\n", layout.value_bytes);
    let _ = writeln!(
        w,
        "/// The value storage with every default (little-endian; `$NODEID` defaults hold just the offset)."
    );
    let _ = writeln!(w, "pub static DEFAULT_VALUES: [u8; VALUE_BYTES] = [");
    for (row, chunk) in image.chunks(16).enumerate() {
        let bytes: Vec<String> = chunk.iter().map(|b| format!("0x{b:02X}")).collect();
        let _ = writeln!(w, "    {}, // {:#06x}", bytes.join(", "), row * 16);
    }
    let _ = writeln!(w, "];\n");

    // The image keeps its defaults sparse: most of the storage is zero (unset limits, counters, mappings).
    let mut mask = vec![0u8; image.len().div_ceil(8)];
    let mut nonzero = Vec::new();
    for (i, &b) in image.iter().enumerate() {
        if b != 0 {
            if let Some(m) = mask.get_mut(i / 8) {
                *m |= 1 << (i % 8);
            }
            nonzero.push(b);
        }
    }
    let _ = writeln!(
        w,
        "/// Which bytes of `DEFAULT_VALUES` are not zero: bit `i % 8` of byte `i / 8` for byte `i`. With\n\
         /// `DEFAULT_NONZERO` the image's form of the defaults (`od::values::default_values`), a third of the size."
    );
    let _ = writeln!(w, "pub static DEFAULT_NONZERO_MASK: [u8; {}] = [", mask.len());
    for (row, chunk) in mask.chunks(16).enumerate() {
        let bytes: Vec<String> = chunk.iter().map(|b| format!("0x{b:02X}")).collect();
        let _ = writeln!(w, "    {}, // {:#06x}", bytes.join(", "), row * 16 * 8);
    }
    let _ = writeln!(w, "];\n");
    let _ = writeln!(w, "/// The bytes of `DEFAULT_VALUES` that are not zero, in order.");
    let _ = writeln!(w, "pub static DEFAULT_NONZERO: [u8; {}] = [", nonzero.len());
    for chunk in nonzero.chunks(16) {
        let bytes: Vec<String> = chunk.iter().map(|b| format!("0x{b:02X}")).collect();
        let _ = writeln!(w, "    {},", bytes.join(", "));
    }
    let _ = writeln!(w, "];\n");

    let _ = writeln!(w, "/// Typed handles to the values the control tiers read and write without a table search.");
    let _ = writeln!(w, "pub mod handles {{");
    let _ = writeln!(w, "    #[allow(unused_imports)]");
    let _ = writeln!(w, "    use super::*;");
    for o in &d.objects {
        for s in &o.subs {
            let (Some(h), Some(slot), Some(ty)) =
                (&s.handle, layout.slots.get(&(o.index, s.sub)), rust_type(s.data_type))
            else {
                continue;
            };
            let _ = writeln!(w, "    /// 0x{:04X}:{:02X} {}", o.index, s.sub, s.name);
            let _ = writeln!(w, "    pub const {}: Handle<{ty}> = Handle::new({});", h.to_uppercase(), slot.offset);
        }
    }
    let _ = writeln!(w, "}}\n");

    let dev = &d.device;
    let consts: [(&str, &str, String); 20] = [
        ("VENDOR_ID", "u32", format!("0x{:08X}", dev.vendor_id)),
        ("PRODUCT_CODE", "u32", format!("0x{:08X}", dev.product_code)),
        ("REVISION", "u32", format!("0x{:08X}", dev.revision)),
        ("SERIAL_NUMBER", "u32", format!("0x{:08X}", dev.serial_number)),
        ("DEVICE_TYPE", "u32", format!("0x{:08X}", dev.device_type)),
        ("VENDOR_NAME", "&str", format!("{:?}", dev.vendor_name)),
        ("DEVICE_NAME", "&str", format!("{:?}", dev.device_name)),
        ("HARDWARE_VERSION", "&str", format!("{:?}", dev.hardware_version)),
        ("SOFTWARE_VERSION", "&str", format!("{:?}", dev.software_version)),
        ("ORDER_CODE", "&str", format!("{:?}", dev.order_code)),
        ("DEFAULT_NODE_ID", "u8", dev.node_id.to_string()),
        ("DEFAULT_BIT_RATE_KBIT", "u16", dev.bit_rate_kbit.to_string()),
        ("MAX_PDO_BYTES_ETHERCAT", "usize", dev.max_pdo_bytes_ethercat.to_string()),
        ("MAX_PDO_BYTES_CANOPEN", "usize", dev.max_pdo_bytes_canopen.to_string()),
        ("MAILBOX_OUT_START", "u16", format!("0x{:04X}", dev.mailbox_out_start)),
        ("MAILBOX_OUT_SIZE", "u16", dev.mailbox_out_size.to_string()),
        ("MAILBOX_IN_START", "u16", format!("0x{:04X}", dev.mailbox_in_start)),
        ("MAILBOX_IN_SIZE", "u16", dev.mailbox_in_size.to_string()),
        ("PROCESS_OUT_START", "u16", format!("0x{:04X}", dev.process_out_start)),
        ("PROCESS_IN_START", "u16", format!("0x{:04X}", dev.process_in_start)),
    ];
    let _ = writeln!(w, "// Device facts from [device].");
    for (name, ty, value) in consts {
        let _ = writeln!(w, "pub const {name}: {ty} = {value};");
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_bytes_are_little_endian_and_padded() {
        assert_eq!(value_bytes(&Value::Int(0x1234), 2), [0x34, 0x12]);
        assert_eq!(value_bytes(&Value::Int(-2), 4), [0xFE, 0xFF, 0xFF, 0xFF]);
        assert_eq!(value_bytes(&Value::NodeIdPlus(0x180), 4), [0x80, 0x01, 0, 0]);
        assert_eq!(value_bytes(&Value::Text("ab".into()), 4), [b'a', b'b', 0, 0]);
        assert_eq!(value_bytes(&Value::None, 3), [0, 0, 0]);
    }

    #[test]
    fn byte_strings_escape_what_is_not_printable() {
        assert_eq!(byte_string(b"OSD \"1\"\\\n"), "b\"OSD \\\"1\\\"\\\\\\x0a\"");
    }
}
