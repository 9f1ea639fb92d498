//! Generation from `tests/fixtures/valid.toml`, a small description that uses every form of the format.
//!
//! The generated Rust is kept as a golden file (`tests/fixtures/valid.od_generated.rs`, rewritten by
//! `UPDATE_SNAPSHOTS=1`) and compiled right here against the firmware's own `entry.rs`, so the tables' shape is
//! checked by the compiler and their contents by the tests below, without building the firmware.

mod common;

use std::path::PathBuf;

use od_gen::model::{DataType, Value};

#[path = "../../firmware/src/od/entry.rs"]
// `od_no_names` is the firmware's cfg (its build.rs): unset here, so names are kept as on the host.
#[allow(dead_code, unexpected_cfgs)]
mod entry;

#[allow(dead_code, missing_docs, clippy::all)]
mod generated {
    use super::entry::*;
    include!("fixtures/valid.od_generated.rs");
}

use entry::{Limits, Storage};
use generated::{handles, DEFAULT_NONZERO, DEFAULT_NONZERO_MASK, DEFAULT_VALUES, ENTRIES, LIMITS, NAMES, OBJECTS};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

fn description() -> od_gen::model::Description {
    od_gen::load(&fixture("valid.toml")).unwrap_or_else(|report| panic!("{report}"))
}

#[test]
fn golden_rust_tables_are_current() {
    let rust = od_gen::rust_gen::rust(&description()).expect("generation");
    assert!(rust.starts_with("// @generated"));
    if let Err(e) = common::check(&fixture("valid.od_generated.rs"), &rust) {
        panic!("{e}\nRun UPDATE_SNAPSHOTS=1 cargo test -p od-gen to accept the change.");
    }
}

#[test]
fn model_is_sorted_expanded_and_resolved() {
    let d = description();
    let indices: Vec<u16> = d.objects.iter().map(|o| o.index).collect();
    let mut sorted = indices.clone();
    sorted.sort_unstable();
    assert_eq!(indices, sorted);
    let mapping = d.object(0x1600).expect("0x1600");
    let names: Vec<&str> = mapping.subs.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(
        names,
        ["Number of mapped objects", "Mapped object 1", "Mapped object 2", "Mapped object 3", "Mapped object 4"]
    );
    assert_eq!(d.entry(0x1600, 2).map(|s| &s.default), Some(&Value::Int(0x6060_0008)));
    assert_eq!(d.entry(0x1400, 1).map(|s| &s.default), Some(&Value::NodeIdPlus(0x200)));
    assert_eq!(d.entry(0x2100, 0).map(|s| &s.default), Some(&Value::Int(1)));
    assert_eq!(d.entry(0x605A, 0).and_then(|s| s.values.clone()), Some(vec![0, 1, 2, 5, 6]));
    assert_eq!(d.entry(0x1F50, 1).map(|s| s.data_type), Some(DataType::Domain));
}

#[test]
fn entries_are_sorted_and_belong_to_their_objects() {
    assert!(ENTRIES.windows(2).all(|w| (w[0].index, w[0].sub) < (w[1].index, w[1].sub)));
    assert!(OBJECTS.windows(2).all(|w| w[0].index < w[1].index));
    // Every entry belongs to an object, and every object has entries up to its highest sub-index.
    assert!(ENTRIES.iter().all(|e| OBJECTS.iter().any(|o| o.index == e.index)));
    for o in &OBJECTS {
        let subs = ENTRIES.iter().filter(|e| e.index == o.index).map(|e| e.sub);
        assert_eq!(subs.max(), Some(o.max_sub), "0x{:04X}", o.index);
    }
}

fn entry(index: u16, sub: u8) -> &'static entry::Entry {
    ENTRIES.iter().find(|e| e.index == index && e.sub == sub).expect("entry")
}

/// The limits the entry at (index, sub) names by its position in `LIMITS`.
fn limits(index: u16, sub: u8) -> Limits {
    LIMITS[usize::from(entry(index, sub).limits.0)]
}

#[test]
fn limits_storage_and_node_id_defaults() {
    assert_eq!(limits(0x605A, 0), Limits::OneOf(&[0, 1, 2, 5, 6]));
    // Only `min` given: the type's maximum fills in.
    assert_eq!(limits(0x6060, 0), Limits::Signed { min: -1, max: 127 });
    assert_eq!(limits(0x1400, 2), Limits::Unsigned { min: 0, max: 255 });
    assert_eq!(limits(0x6040, 0), Limits::None);
    assert_eq!(entry(0x1008, 0).storage.constant(), Some(&b"FIX-1"[..]));
    assert_eq!(entry(0x1018, 1).storage.constant(), Some(&[0xCE, 0x0A, 0x00, 0x00][..]));
    assert_eq!(entry(0x1400, 1).storage.constant(), None);
    assert_eq!(entry(0x1F50, 1).storage, Storage::Application);
    assert!(entry(0x1400, 1).node_id_relative());
    assert!(!entry(0x1400, 2).node_id_relative());
}

#[test]
fn ram_values_are_aligned_disjoint_and_hold_the_defaults() {
    let mut slots: Vec<(usize, usize)> = Vec::new();
    for e in &ENTRIES {
        if let Storage::Ram { offset, len, .. } = e.storage {
            let (offset, len) = (usize::from(offset), usize::from(len));
            if let Some(size) = e.data_type.fixed_size() {
                assert_eq!(len, size);
                assert_eq!(offset % size, 0, "0x{:04X}:{:02X} misaligned", e.index, e.sub);
            }
            slots.push((offset, len));
        }
    }
    slots.sort_unstable();
    assert!(slots.windows(2).all(|w| w[0].0 + w[0].1 <= w[1].0));
    assert_eq!(slots.last().map(|(o, l)| o + l), Some(DEFAULT_VALUES.len()));

    let at = |offset: usize, len: usize| &DEFAULT_VALUES[offset..offset + len];
    assert_eq!(at(handles::MODES_OF_OPERATION.offset(), 1), [0xFF]);
    assert_eq!(at(handles::ENABLE_FLAG.offset(), 1), [1]);
    assert_eq!(at(handles::BIG_COUNTER.offset(), 8), 7u64.to_le_bytes());
    assert_eq!(at(handles::CONTROLWORD.offset(), 2), [0, 0]);
    // A $NODEID default holds just the offset.
    let Storage::Ram { offset, .. } = entry(0x1400, 1).storage else { panic!("0x1400:01 not in RAM") };
    assert_eq!(at(usize::from(offset), 4), 0x200u32.to_le_bytes());
}

#[test]
fn handles_have_the_rust_type_of_their_data_type() {
    let _: entry::Handle<u16> = handles::CONTROLWORD;
    let _: entry::Handle<u16> = handles::STATUSWORD;
    let _: entry::Handle<i8> = handles::MODES_OF_OPERATION;
    let _: entry::Handle<i32> = handles::POSITION_ACTUAL_VALUE;
    let _: entry::Handle<bool> = handles::ENABLE_FLAG;
    let _: entry::Handle<u64> = handles::BIG_COUNTER;
    assert_eq!(generated::VENDOR_ID, 0x0ACE);
    assert_eq!(generated::DEVICE_NAME, "FIX-1");
    assert_eq!(generated::MAX_PDO_BYTES_CANOPEN, 8);
    assert_eq!(generated::PROCESS_IN_START, 0x1180);
}

#[test]
fn object_reference_lists_every_entry_by_area() {
    let d = description();
    let md = od_gen::markdown::markdown(&d);
    assert!(md.starts_with("<!-- @generated"));
    for title in ["## Communication profile area", "## Manufacturer-specific area", "## Device profile area"] {
        assert!(md.contains(title), "missing {title}");
    }
    assert!(md.contains("| 0x1600:02 | Mapped object 2 | UNSIGNED32 | rw (pre-op) | no | 0x60600008 |"), "{md}");
    assert!(md.contains("| 0x1400:01 | COB-ID used by RxPDO 1 | UNSIGNED32 | rw | no | $NODEID+0x200 |"), "{md}");
    assert!(md.contains("one of 0, 1, 2, 5, 6"));
    assert!(md.contains("Note: A note \\| with a pipe"));
    let rows = md.lines().filter(|l| l.starts_with("| 0x") || l.starts_with("| **0x")).count();
    let composite = d.objects.iter().filter(|o| o.code != od_gen::model::ObjectCode::Var).count();
    let entries: usize = d.objects.iter().map(|o| o.subs.len()).sum();
    assert_eq!(rows, entries + composite);
}

#[test]
fn generate_all_writes_every_file() {
    let out = std::env::temp_dir().join(format!("od-gen-test-{}", std::process::id()));
    std::fs::create_dir_all(&out).expect("temp dir");
    od_gen::generate_all(&fixture("valid.toml"), &out).expect("generate_all");
    for name in ["od_generated.rs", "object-reference.md", "drive.eds", "drive-esi.xml", "drive-sii.bin"] {
        assert!(out.join(name).exists(), "{name} not written");
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn errors_stop_generation_with_the_full_report() {
    let out = std::env::temp_dir().join(format!("od-gen-test-err-{}", std::process::id()));
    let report = od_gen::generate_all(&fixture("errors/every_mistake_reported.toml"), &out).expect_err("must fail");
    // Without the shared header there is no [device] either: five mistakes in all.
    assert_eq!(report.lines().count(), 5, "{report}");
    assert!(!out.exists());
}

/// Every object and entry finds its own name in `NAMES`, which holds each distinct name once at most (the
/// description repeats "Highest sub-index supported" and others).
#[test]
fn names_are_places_in_the_name_text() {
    let d = description();
    for (o, object) in d.objects.iter().zip(&OBJECTS) {
        assert_eq!(object.name.as_str(), o.name, "0x{:04X}", o.index);
        for s in &o.subs {
            assert_eq!(entry(o.index, s.sub).name.as_str(), s.name, "0x{:04X}:{:02X}", o.index, s.sub);
        }
    }
    let mut distinct: Vec<&str> = d
        .objects
        .iter()
        .flat_map(|o| std::iter::once(&o.name).chain(o.subs.iter().map(|s| &s.name)))
        .map(String::as_str)
        .collect();
    distinct.sort_unstable();
    distinct.dedup();
    assert!(NAMES.len() <= distinct.iter().map(|n| n.len()).sum::<usize>(), "a name written twice");
    assert!(NAMES.len() < d.objects.iter().flat_map(|o| &o.subs).map(|s| s.name.len()).sum::<usize>());
}

/// Without names (the firmware's CANopen image on the target, which serves no names), every object and entry of
/// the generated tables has an empty name, the name text is empty, and nothing else differs.
#[test]
fn tables_without_names_differ_only_in_the_names() {
    let with = od_gen::rust_gen::rust(&description()).expect("generation");
    let without = od_gen::rust_gen::rust_with_names(&description(), false).expect("generation");
    // Every `Name::new(offset, len)` emptied, and the text of `NAMES` too.
    let mut emptied = String::new();
    let mut rest = with.as_str();
    while let Some(at) = rest.find("Name::new(") {
        emptied.push_str(&rest[..at]);
        emptied.push_str("Name::EMPTY");
        let tail = &rest[at..];
        rest = &tail[tail.find(')').expect("a closing parenthesis") + 1..];
    }
    emptied.push_str(rest);
    let names_line = format!("pub static NAMES: &str = {NAMES:?};");
    assert!(emptied.contains(&names_line), "the name text as generated");
    let emptied = emptied.replace(&names_line, "pub static NAMES: &str = \"\";");
    assert_ne!(with, without, "the description has names");
    assert_eq!(emptied, without);
}

#[test]
fn sparse_defaults_hold_every_non_zero_byte_in_order() {
    // The image's defaults are the mask of the non-zero bytes and those bytes (firmware `od::values`).
    let mut rebuilt = vec![0u8; DEFAULT_VALUES.len()];
    let mut nonzero = DEFAULT_NONZERO.iter();
    for (i, byte) in rebuilt.iter_mut().enumerate() {
        if (DEFAULT_NONZERO_MASK[i / 8] >> (i % 8)) & 1 == 1 {
            *byte = *nonzero.next().expect("a byte for every bit of the mask");
        }
    }
    assert_eq!(rebuilt, DEFAULT_VALUES);
    assert_eq!(nonzero.next(), None, "no byte without its bit");
    assert_eq!(DEFAULT_NONZERO_MASK.len(), DEFAULT_VALUES.len().div_ceil(8));
}

#[test]
fn limits_beyond_the_32_bit_bounds_are_refused() {
    // `Limits` holds 32-bit bounds; a wider bound (or a listed value) must stop the build, not be cut.
    let mut d = description();
    let object = d.objects.iter_mut().find(|o| o.index == 0x6060).expect("0x6060 in the fixture");
    object.subs[0].max = Some(i128::from(i32::MAX) + 1);
    let report = od_gen::rust_gen::rust(&d).expect_err("a bound past i32::MAX");
    assert_eq!(report, "0x6060:00: limits beyond the 32-bit bounds of Limits");
    let mut d = description();
    let object = d.objects.iter_mut().find(|o| o.index == 0x605A).expect("0x605A in the fixture");
    object.subs[0].values = Some(vec![0, 1 << 40]);
    let report = od_gen::rust_gen::rust(&d).expect_err("a listed value past i32");
    assert_eq!(report, "0x605A:00: limits beyond the 32-bit bounds of Limits");
}
