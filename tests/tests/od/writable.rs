//! No silent objects (issue 19): every object a master can write either refuses a change or is read by the
//! firmware. An entry that accepts a write and is then ignored misleads the master that wrote it.
//!
//! The walk goes over every writable sub-object of `firmware/device.toml` (the source of the generated dictionary)
//! and accepts it when one of these holds, checked in this order:
//! 1. it refuses every change: its value set is its default alone (0x60A8, 0x607B, ...), so a write of anything
//!    else aborts with 0x0609_0030 (checked through the SDO download path in
//!    `a_write_outside_a_single_value_set_aborts_with_the_invalid_value_code`);
//! 2. its typed handle (`od::generated::handles::NAME`) is used by firmware code outside the tests;
//! 3. its index, or the first index of its PDO range (0x1400, 0x1600, 0x1800, 0x1A00: reached as `base + n`),
//!    appears as a literal in firmware code outside comments and tests: the protocol objects (PDO parameters and
//!    mappings, SYNC, heartbeat, store/restore, program control) are consumed by index;
//! 4. it is one of [`EXCEPTIONS`], each with the reason the drive has nothing more to do with it (checked before
//!    rules 2 and 3, so that an exception is listed by its sub-index and not hidden by its object's index).
//!
//! Rules 2 and 3 read the source: they prove that something reads the object, not what it does with it; what each
//! object does is the business of its own tests (0x6087: `motion::cyclic`, 0x3000:04: `supervision::feedback`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use od_gen::model::{Access, Description, Value};

use crate::support::allowed;

/// Writable entries the drive keeps and never reads (index, sub; `None` for every sub), and why.
const EXCEPTIONS: [(u16, Option<u8>, &str); 4] = [
    (0x1020, None, "CiA 301 verify configuration: stored as written, for the configuration tool that stamped it"),
    (0x210C, None, "custom persistent memory (IDX): the user's own words, kept in the parameter store"),
    (
        0x1C32,
        Some(8),
        "ETG.1020 get cycle time: masters write it while starting up; the drive measures its cycle all the time \
         (0x1C32:03, :05, :06, :0B, :0C are always current), so the command has nothing to start or stop",
    ),
    (0x1C33, Some(8), "ETG.1020 get cycle time of the inputs: as 0x1C32:08"),
];

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The firmware's code, file by file, without comments and without the test modules at the end of a file.
fn firmware_code() -> BTreeMap<PathBuf, String> {
    fn walk(dir: &Path, out: &mut BTreeMap<PathBuf, String>) {
        for entry in std::fs::read_dir(dir).expect("firmware/src readable") {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                walk(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let text = std::fs::read_to_string(&path).expect("source readable");
                let text = text.split("#[cfg(test)]\nmod tests").next().unwrap_or("");
                let code: Vec<&str> =
                    text.lines().map(|l| l.split("//").next().unwrap_or("")).filter(|l| !l.trim().is_empty()).collect();
                out.insert(path, code.join("\n"));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(&repo().join("firmware/src"), &mut out);
    out
}

/// Whether `code` holds `needle` not followed by an identifier character (so `h::MAX_TORQUE` does not count as
/// a use of `h::MAX`).
fn mentions(code: &str, needle: &str) -> bool {
    code.match_indices(needle).any(|(at, _)| {
        code[at + needle.len()..].chars().next().is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '_'))
    })
}

/// The first index of a range of protocol objects the firmware reaches by arithmetic from that index (CiA 301 PDO
/// parameters and mappings: `base + n`), or the index itself.
fn group_base(index: u16) -> u16 {
    match index {
        0x1400..=0x15FF => 0x1400,
        0x1600..=0x17FF => 0x1600,
        0x1800..=0x19FF => 0x1800,
        0x1A00..=0x1BFF => 0x1A00,
        _ => index,
    }
}

fn description() -> Description {
    od_gen::load(&repo().join("firmware/device.toml")).expect("the device description is valid")
}

fn writable(access: Access) -> bool {
    matches!(access, Access::ReadWrite | Access::WriteOnly)
}

/// The walk of the module documentation. Fails with the list of every writable entry no rule accepts.
#[test]
fn every_writable_object_refuses_a_change_or_is_read_by_the_firmware() {
    let d = description();
    let code = firmware_code();
    let all: String = code.values().cloned().collect::<Vec<_>>().join("\n");
    let mut silent = Vec::new();
    let mut counts = [0usize; 4];
    for o in &d.objects {
        for s in o.subs.iter().filter(|s| writable(s.access)) {
            let single = s.values.as_ref().is_some_and(|v| v.len() == 1);
            let handle = s.handle.as_ref().is_some_and(|n| mentions(&all, &format!("::{}", n.to_uppercase())));
            let literal = [o.index, group_base(o.index)]
                .iter()
                .flat_map(|i| [format!("0x{i:04X}"), format!("0x{i:04x}")])
                .any(|hex| mentions(&all, &hex));
            let excepted = EXCEPTIONS.iter().any(|(index, sub, _)| *index == o.index && sub.is_none_or(|n| n == s.sub));
            match (single, excepted, handle, literal) {
                (true, ..) => counts[0] += 1,
                (_, true, ..) => counts[3] += 1,
                (_, _, true, _) => counts[1] += 1,
                (.., true) => counts[2] += 1,
                _ => silent.push(format!("0x{:04X}:{:02X} {} (handle {:?})", o.index, s.sub, s.name, s.handle)),
            }
        }
    }
    println!(
        "writable sub-objects: {} refuse every change, {} read through their handle, {} read by index, {} excepted",
        counts[0], counts[1], counts[2], counts[3]
    );
    assert!(silent.is_empty(), "writable objects nothing reads:\n{}", silent.join("\n"));
    // The exceptions are still writable objects of the dictionary (a stale row would hide nothing).
    for (index, sub, why) in EXCEPTIONS {
        let o = d.object(index).unwrap_or_else(|| panic!("exception 0x{index:04X} ({why}) is not in the dictionary"));
        let listed = |s: &&od_gen::model::SubObject| sub.is_none_or(|n| n == s.sub);
        assert!(o.subs.iter().filter(listed).any(|s| writable(s.access)), "exception 0x{index:04X} is not writable");
    }
}

/// Rule 1 through the SDO download path (`Dictionary::write`, in a context where every write condition is met):
/// every writable entry whose value set is its default alone refuses another value with 0x0609_0030 (CiA 301
/// "invalid value for parameter") and keeps its value.
#[test]
fn a_write_outside_a_single_value_set_aborts_with_the_invalid_value_code() {
    use firmware::od::abort::SdoAbort;
    use firmware::od::access::{Dictionary, NoApplicationObjects};
    let d = description();
    let mut dict = Dictionary::new(1);
    let mut checked = 0;
    for o in &d.objects {
        for s in o.subs.iter().filter(|s| writable(s.access)) {
            let Some([only]) = s.values.as_deref() else { continue };
            let what = format!("0x{:04X}:{:02X} {}", o.index, s.sub, s.name);
            assert_eq!(s.default, Value::Int(*only), "{what}: the one value is the default");
            let size = s.data_type.fixed_size().expect("a single-value entry has a fixed size");
            let other = if *only == 0 { 1i128 } else { 0 };
            let mut before = [0u8; 8];
            let _ = dict.read(o.index, s.sub, 0, &mut before, &mut NoApplicationObjects).expect("readable");
            let result = dict.write(o.index, s.sub, &other.to_le_bytes()[..size], allowed(), &mut NoApplicationObjects);
            assert_eq!(result, Err(SdoAbort::InvalidValue), "{what}");
            let mut after = [0u8; 8];
            let _ = dict.read(o.index, s.sub, 0, &mut after, &mut NoApplicationObjects).expect("readable");
            assert_eq!(after, before, "{what}: unchanged");
            checked += 1;
        }
    }
    println!("{checked} single-value entries refuse another value");
    assert!(checked > 0, "the walk found no single-value entry");
}
