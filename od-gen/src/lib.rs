//! od-gen: validates the drive's device description and generates, into a build's OUT_DIR, the firmware's
//! dictionary tables, a CANopen EDS, an EtherCAT ESI file and SII EEPROM image, and an object reference.

use std::path::Path;

pub mod description;
pub mod eds;
pub mod esi;
pub mod markdown;
pub mod model;
pub mod rust_gen;
pub mod sii;
pub mod validate;

/// Reads and validates the description at `path`. On failure returns the report: one line per mistake,
/// `path: object 0x1600:03 'Mapped object 3': reason`.
pub fn load(path: &Path) -> Result<model::Description, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    load_str(&text, &path.display().to_string())
}

/// Validates description `text`; `path` names it in the report lines.
pub fn load_str(text: &str, path: &str) -> Result<model::Description, String> {
    let raw = description::parse(text).map_err(|e| format!("{path}: {}", e.trim_end().replace('\n', "\n    ")))?;
    validate::validate(&raw, path).map_err(|lines| lines.join("\n"))
}

/// Every generated file of a validated description, as (file name, contents), in a fixed order:
/// `od_generated.rs`, `object-reference.md`, `drive.eds`, `drive-esi.xml`, `drive-sii.bin`.
pub fn render(d: &model::Description) -> Result<Vec<(&'static str, Vec<u8>)>, String> {
    render_with_names(d, true)
}

/// [`render`], with the names in `od_generated.rs` or without them ([`rust_gen::rust_with_names`]); the other
/// files always name everything.
pub fn render_with_names(d: &model::Description, names: bool) -> Result<Vec<(&'static str, Vec<u8>)>, String> {
    Ok(vec![
        ("od_generated.rs", rust_gen::rust_with_names(d, names)?.into_bytes()),
        ("object-reference.md", markdown::markdown(d).into_bytes()),
        ("drive.eds", eds::eds(d).into_bytes()),
        ("drive-esi.xml", esi::esi(d).into_bytes()),
        ("drive-sii.bin", sii::sii(d)),
    ])
}

/// A hex dump of `bytes`, 16 per line with the offset and the printable ASCII, for reviewing binary output
/// (the SII image) in a diff.
pub fn hex_dump(bytes: &[u8]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for (row, chunk) in bytes.chunks(16).enumerate() {
        let hex: Vec<String> = chunk.iter().map(|b| format!("{b:02x}")).collect();
        let ascii: String =
            chunk.iter().map(|&b| if (0x20..0x7F).contains(&b) { char::from(b) } else { '.' }).collect();
        let _ = writeln!(out, "{:08x}  {:<47}  |{ascii}|", row * 16, hex.join(" "));
    }
    out
}

/// Reads `description`, validates it and writes every generated file into `out_dir` (files whose contents did
/// not change are left alone). On failure returns a report with one line per mistake (file, object, reason).
pub fn generate_all(description: &Path, out_dir: &Path) -> Result<(), String> {
    generate_all_with_names(description, out_dir, true)
}

/// [`generate_all`], with or without the names in the firmware's tables ([`rust_gen::rust_with_names`]).
pub fn generate_all_with_names(description: &Path, out_dir: &Path, names: bool) -> Result<(), String> {
    let d = load(description)?;
    for (name, contents) in render_with_names(&d, names)? {
        let path = out_dir.join(name);
        if std::fs::read(&path).ok().as_deref() != Some(contents.as_slice()) {
            std::fs::write(&path, contents).map_err(|e| format!("{}: cannot write: {e}", path.display()))?;
        }
    }
    Ok(())
}
