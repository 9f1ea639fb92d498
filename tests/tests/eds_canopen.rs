//! The CANopen EDS generated from `firmware/device.toml`, read by two independent third-party tools: PyPI
//! `canopen` must find every entry of the firmware's runtime dictionary (`firmware::od::generated::ENTRIES`)
//! with the same type, access and default, and nothing else; `eds-validate` (PyPI eds-utils) must accept it.
//! See `tests/python/check_eds.py` and `shared/spec/fieldbus-real-masters.md`.
//!
//! The Python packages come from `tests/python/requirements.txt` via `scripts/setup.sh`; without them this
//! test fails (it does not skip).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use firmware::od::entry::{Access, Storage};
use firmware::od::generated::{DEFAULT_VALUES, ENTRIES, OBJECTS};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn json_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// The firmware's runtime table as JSON: index, sub, object code, data type, access, PDO flag, node-ID
/// relativity and the default bytes (from `DEFAULT_VALUES` or the constant; `null` for application-served
/// entries).
fn entries_json(node_id: u8) -> String {
    let mut out = format!("{{\"node_id\": {node_id}, \"entries\": [\n");
    for (i, e) in ENTRIES.iter().enumerate() {
        let default = match e.storage {
            Storage::Ram { offset, len, .. } => {
                let (o, l) = (usize::from(offset), usize::from(len));
                let bytes = DEFAULT_VALUES.get(o..o + l).expect("RAM value inside DEFAULT_VALUES");
                Some(bytes.iter().map(|b| format!("{b:02x}")).collect::<String>())
            }
            Storage::Const(bytes) => Some(bytes.bytes().iter().map(|b| format!("{b:02x}")).collect()),
            Storage::Application => None,
        };
        let access = match e.access() {
            Access::ReadOnly => "ro",
            Access::WriteOnly => "wo",
            Access::ReadWrite => "rw",
            Access::Const => "const",
        };
        let _ = writeln!(
            out,
            "{{\"index\": {}, \"sub\": {}, \"name\": {}, \"object_code\": {}, \"data_type\": {}, \"access\": \"{access}\", \
             \"pdo\": {}, \"node_id_relative\": {}, \"default\": {}}}{}",
            e.index,
            e.sub,
            json_string(e.name.as_str()),
            OBJECTS.iter().find(|o| o.index == e.index).expect("the entry's object").object_code.code(),
            e.data_type.code(),
            e.pdo() != firmware::od::entry::PdoMapping::No,
            e.node_id_relative(),
            default.map_or("null".to_string(), |d| format!("\"{d}\"")),
            if i + 1 == ENTRIES.len() { "" } else { "," }
        );
    }
    out.push_str("]}\n");
    out
}

#[test]
fn canopen_and_eds_validate_accept_the_generated_eds() {
    let root = workspace();
    let description = od_gen::load(&root.join("firmware/device.toml")).expect("firmware/device.toml is valid");
    let eds = od_gen::eds::eds(&description);

    let dir = std::env::temp_dir().join(format!("drive-eds-canopen-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let eds_path = dir.join("drive.eds");
    let json_path = dir.join("entries.json");
    std::fs::write(&eds_path, &eds).expect("write EDS");
    std::fs::write(&json_path, entries_json(description.device.node_id)).expect("write entries");

    let script = root.join("tests/python/check_eds.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(&eds_path)
        .arg(&json_path)
        .output()
        .unwrap_or_else(|e| panic!("cannot run python3 {}: {e}. Run scripts/setup.sh", script.display()));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    match out.status.code() {
        Some(0) => {
            println!("{stdout}");
            // DRIVE_TEST_KEEP=1 keeps the EDS and the table for inspection.
            if std::env::var_os("DRIVE_TEST_KEEP").is_none() {
                let _ = std::fs::remove_dir_all(&dir);
            }
        }
        Some(3) => panic!("Python packages missing, run scripts/setup.sh:\n{stdout}{stderr}"),
        _ => panic!("the generated EDS ({}) failed the check:\n{stdout}{stderr}", eds_path.display()),
    }
}
