//! Snapshot of the generated files of the real description: `docs/generated/` holds the EDS, the ESI, the SII
//! image (as a hex dump) and the object reference generated from `firmware/device.toml`; this test regenerates
//! them and fails with a summary of each difference. `UPDATE_SNAPSHOTS=1 cargo test -p od-gen` rewrites them.
//!
//! Every file `od_gen::render` produces is covered except `od_generated.rs` (which the firmware build compiles);
//! binary files get a `.hex` dump. An emitter that still returns nothing has no snapshot yet.

mod common;

use std::path::PathBuf;

#[test]
fn generated_files_match_docs_generated() {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let root = manifest.parent().unwrap_or(&manifest);
    let description = od_gen::load(&root.join("firmware/device.toml")).unwrap_or_else(|report| panic!("{report}"));
    let files = od_gen::render(&description).unwrap_or_else(|e| panic!("{e}"));
    let mut failures = Vec::new();
    for (name, contents) in files {
        if name == "od_generated.rs" || contents.is_empty() {
            continue;
        }
        let (snapshot, text) = match name.strip_suffix(".bin") {
            Some(stem) => (format!("{stem}.hex"), od_gen::hex_dump(&contents)),
            None => (name.to_string(), String::from_utf8_lossy(&contents).into_owned()),
        };
        if let Err(e) = common::check(&root.join("docs/generated").join(snapshot), &text) {
            failures.push(e);
        }
    }
    assert!(
        failures.is_empty(),
        "{}\n\nThe generated output of firmware/device.toml changed. If the change is intended, run\n  \
         UPDATE_SNAPSHOTS=1 cargo test -p od-gen\nand commit docs/generated/.",
        failures.join("\n\n")
    );
}
