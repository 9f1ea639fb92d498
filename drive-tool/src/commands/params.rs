//! `params save FILE` and `params load FILE`: the drive's persistent parameters as a CiA 306 DCF and back, with
//! the differences shown before anything is written and 0x1010:01 "save" on request (CiA 301 §7.5.2.13).

use std::path::Path;

use serde_json::json;

use crate::context::Context;
use crate::dcf::{self, Commissioning};
use crate::eds::{parse_eds_integer, Dictionary, Entry};
use crate::project;
use crate::value::{encode, Value};

/// The signature "save" written to 0x1010:01 (CiA 301 §7.5.2.13: "s" "a" "v" "e", 0x65766173).
const SAVE_SIGNATURE: u32 = 0x6576_6173;

/// `params save FILE`.
pub fn save(cx: &mut Context, file: &Path) -> Result<(), String> {
    let node = cx.node;
    let wanted: Vec<Entry> = cx
        .dict
        .entries
        .iter()
        .filter(|e| e.access.readable() && (project::persistent(&cx.dict, e) || e.index == 0x1018))
        .cloned()
        .collect();
    let mut values = Vec::new();
    let mut skipped = Vec::new();
    for entry in wanted {
        match cx.read_entry_of(node, &entry) {
            Ok(v) => values.push((entry, v)),
            Err(e) => skipped.push(e),
        }
    }
    if values.iter().all(|(e, _)| e.index == 0x1018) {
        return Err(format!(
            "node {node}: no parameter could be read{}",
            skipped.first().map_or(String::new(), |e| format!(" ({e})"))
        ));
    }
    let serial = values.iter().find(|(e, _)| (e.index, e.sub) == (0x1018, 4)).and_then(|(_, v)| match v {
        Value::Int(s) => Some(*s as u32),
        _ => None,
    });
    let bit_rate = if project::is_project_device(&cx.dict) {
        cx.read_int(0x200A, 0).ok().and_then(dcf::bit_rate_kbit)
    } else {
        None
    };
    let file_name = file.file_name().map_or("drive.dcf".into(), |n| n.to_string_lossy().into_owned());
    let text =
        dcf::write(&cx.dict, &values, &Commissioning { node_id: node, bit_rate_kbit: bit_rate, serial, file_name });
    std::fs::write(file, text).map_err(|e| format!("{}: {e}", file.display()))?;
    for e in &skipped {
        eprintln!("drive-tool: warning: not saved: {e}");
    }
    let saved = values.iter().filter(|(e, _)| e.index != 0x1018).count();
    if cx.json {
        cx.print_json(&json!({ "file": file.display().to_string(), "parameters": saved, "skipped": skipped }));
    } else {
        say!("{saved} parameters of node {node} saved to {}", file.display());
    }
    Ok(())
}

/// Options of `params load`.
pub struct LoadOptions {
    /// Write 0x1010:01 "save" afterwards.
    pub store: bool,
    /// Accept a DCF of another device.
    pub force: bool,
    /// Show the differences only.
    pub dry_run: bool,
}

/// One parameter that differs.
struct Change {
    entry: Entry,
    old: String,
    new: String,
    bytes: Vec<u8>,
}

/// The identity values a DCF records for 0x1018:01/02: their ParameterValue, else `[DeviceInfo]`.
fn dcf_identity(dcf: &Dictionary, sub: u8) -> Option<u32> {
    let recorded = dcf.entry(0x1018, sub).and_then(|e| e.value.as_deref()).and_then(|v| parse_eds_integer(v, 0));
    recorded.map(|v| v as u32).or(match sub {
        1 => dcf.identity.vendor,
        _ => dcf.identity.product,
    })
}

/// A PDO mapping object (CiA 301 §7.5.2.36/.38: RPDO 0x1600..0x17FF, TPDO 0x1A00..0x1BFF).
fn is_pdo_mapping(index: u16) -> bool {
    matches!(index, 0x1600..=0x17FF | 0x1A00..=0x1BFF)
}

/// A PDO's COB-ID entry (sub-index 1 of 0x1400..0x15FF, 0x1800..0x19FF).
fn is_pdo_cob_id(index: u16, sub: u8) -> bool {
    sub == 1 && matches!(index, 0x1400..=0x15FF | 0x1800..=0x19FF)
}

/// The drive's values before the load, of every entry the DCF has a value for.
type Before = std::collections::BTreeMap<(u16, u8), (Entry, Vec<u8>)>;

/// `bytes` (a COB-ID) with bit 31 set: the PDO invalid (CiA 301 §7.5.2.35).
fn invalid(bytes: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    if let Some(top) = out.get_mut(3) {
        *top |= 0x80;
    }
    out
}

/// The writes that make the changes, in the order CiA 301 requires for PDOs (§7.5.2.35/.36, the mapping
/// procedure): a PDO whose mapping changes is made invalid first (COB-ID bit 31 in its communication
/// parameter, 0x1400+n / 0x1800+n sub-index 1), its mapping disabled (sub-index 0 = 0; the drive refuses both
/// while the PDO is valid or mapped, 0x0601_0000), the entries written, the count set (the DCF's, or the
/// drive's again), and the COB-ID written last. A COB-ID that changes while the PDO stays valid goes through the
/// invalid COB-ID (a valid PDO's COB-ID cannot change). Everything else in index order.
fn write_order(changes: &[Change], before: &Before) -> Vec<(Entry, Vec<u8>)> {
    let changed = |index: u16, sub: u8| changes.iter().find(|m| (m.entry.index, m.entry.sub) == (index, sub));
    let remapped: std::collections::BTreeSet<u16> =
        changes.iter().filter(|c| is_pdo_mapping(c.entry.index)).map(|c| c.entry.index).collect();
    let communication_of = |mapping: u16| mapping - 0x200;
    let mut writes = Vec::new();
    let mut done = std::collections::BTreeSet::new();
    let cob_id_write = |writes: &mut Vec<(Entry, Vec<u8>)>, entry: &Entry, bytes: &[u8]| {
        if bytes.len() == 4 && bytes[3] & 0x80 == 0 {
            writes.push((entry.clone(), invalid(bytes)));
        }
        writes.push((entry.clone(), bytes.to_vec()));
    };
    for c in changes {
        let (index, sub) = (c.entry.index, c.entry.sub);
        if is_pdo_cob_id(index, sub) && remapped.contains(&(index + 0x200)) {
            continue; // written at the end of its PDO's remapping
        }
        if !is_pdo_mapping(index) {
            if is_pdo_cob_id(index, sub) {
                cob_id_write(&mut writes, &c.entry, &c.bytes);
            } else {
                writes.push((c.entry.clone(), c.bytes.clone()));
            }
            continue;
        }
        if !done.insert(index) {
            continue;
        }
        let cob_id = before.get(&(communication_of(index), 1));
        if let Some((entry, old)) = cob_id {
            writes.push((entry.clone(), invalid(old)));
        }
        let count = before.get(&(index, 0));
        if let Some((entry, _)) = count {
            writes.push((entry.clone(), vec![0]));
        }
        for m in changes.iter().filter(|m| m.entry.index == index && m.entry.sub != 0) {
            writes.push((m.entry.clone(), m.bytes.clone()));
        }
        if let Some((entry, old)) = count {
            writes.push((entry.clone(), changed(index, 0).map_or(old.clone(), |m| m.bytes.clone())));
        }
        if let Some((entry, old)) = cob_id {
            let last = changed(communication_of(index), 1).map_or(old.clone(), |m| m.bytes.clone());
            cob_id_write(&mut writes, entry, &last);
        }
    }
    writes
}

/// `params load FILE`.
pub fn load(cx: &mut Context, file: &Path, options: LoadOptions) -> Result<(), String> {
    let node = cx.node;
    let text = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let dcf = Dictionary::parse(&text).map_err(|e| format!("{}: {e}", file.display()))?;
    // CiA 306: a DCF belongs to one device; its identity must be the drive's (0x1018:01 vendor, :02 product).
    for (sub, what) in [(1u8, "vendor ID"), (2, "product code")] {
        let Some(expected) = dcf_identity(&dcf, sub) else { continue };
        let actual = cx.link.upload(node, 0x1018, sub).map_err(|e| format!("node {node} 0x1018:{sub:02X}: {e}"))?;
        let actual = match crate::value::decode(0x0007, &actual) {
            Ok(Value::Int(v)) => v as u32,
            _ => return Err(format!("node {node} 0x1018:{sub:02X}: not an UNSIGNED32")),
        };
        if actual != expected && !options.force {
            return Err(format!(
                "{} is for another device: its {what} is 0x{expected:08X}, node {node}'s 0x{actual:08X} \
                 (--force loads it anyway)",
                file.display()
            ));
        }
    }
    // The DCF's node-ID (CiA 306 [DeviceComissioning] NodeID): loaded onto another node, the drive keeps its own
    // node-ID (0x2000 on this project's drive), and the COB-IDs saved relative to the node-ID follow the drive's.
    let dcf_node = dcf.ini.get("DeviceComissioning", "NodeID").and_then(|n| parse_eds_integer(n, 0));
    let keep_node_id = project::is_project_device(&dcf) && dcf_node.is_some_and(|n| n != i128::from(node));
    let mut kept = Vec::new();
    // Every value is checked against its type before anything is read or written.
    let mut planned = Vec::new();
    for entry in dcf.entries.iter().filter(|e| e.value.is_some() && e.access.writable()) {
        if keep_node_id && (entry.index, entry.sub) == (0x2000, 0) {
            kept.push(format!(
                "{} {} kept: the DCF is node {}'s",
                entry.address(),
                entry.full_name(),
                dcf_node.unwrap_or(0)
            ));
            continue;
        }
        let text = entry.value.clone().unwrap_or_default();
        let bytes = encode(entry, &text, node).map_err(|e| format!("{}: {e}", file.display()))?;
        if let Ok(Value::Int(v)) = crate::value::decode(entry.data_type, &bytes) {
            project::check_allowed(&dcf, entry, v).map_err(|e| format!("{}: {e}", file.display()))?;
        }
        planned.push((entry.clone(), bytes));
    }
    let mut changes = Vec::new();
    let mut before = Before::new();
    for (entry, bytes) in planned {
        let current =
            cx.link.upload(node, entry.index, entry.sub).map_err(|e| crate::context::access_error(node, &entry, &e))?;
        before.insert((entry.index, entry.sub), (entry.clone(), current.clone()));
        if current != bytes {
            let show = |b: &[u8]| {
                crate::value::decode(entry.data_type, b)
                    .map_or_else(|_| crate::value::hex(b), |v| v.display(entry.data_type))
            };
            changes.push(Change { old: show(&current), new: show(&bytes), entry, bytes });
        }
    }
    let mut failures = Vec::new();
    if !options.dry_run {
        for (entry, bytes) in write_order(&changes, &before) {
            if let Err(e) = cx.link.download(node, entry.index, entry.sub, &bytes) {
                failures.push(crate::context::access_error(node, &entry, &e));
            }
        }
    }
    let stored = options.store && !options.dry_run && failures.is_empty();
    if stored {
        cx.link
            .download(node, 0x1010, 1, &SAVE_SIGNATURE.to_le_bytes())
            .map_err(|e| format!("node {node} 0x1010:01 (store parameters): {e}"))?;
    }
    if cx.json {
        let list: Vec<_> = changes
            .iter()
            .map(|c| json!({ "address": c.entry.address(), "name": c.entry.full_name(), "old": c.old, "new": c.new }))
            .collect();
        cx.print_json(&json!({
            "changes": list, "written": !options.dry_run, "stored": stored, "failures": failures, "kept": kept,
        }));
    } else {
        for c in &changes {
            say!("{} {}: {} -> {}", c.entry.address(), c.entry.full_name(), c.old, c.new);
        }
        for k in &kept {
            say!("{k}");
        }
        let verb = if options.dry_run { "would change" } else { "changed" };
        say!(
            "{} parameter(s) {verb} on node {node}{}",
            changes.len(),
            if stored { "; stored (0x1010:01)" } else { "" }
        );
    }
    match failures.as_slice() {
        [] => Ok(()),
        many => Err(format!("{} write(s) refused:\n{}", many.len(), many.join("\n"))),
    }
}
