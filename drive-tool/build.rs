//! Generates the project's EDS from firmware/device.toml (od-gen) into OUT_DIR; `eds.rs` embeds it as the
//! dictionary drive-tool uses without `--eds`.

use std::{env, fs, path::PathBuf};

fn main() {
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let out_dir = PathBuf::from(env::var("OUT_DIR").unwrap_or_default());
    let description = manifest_dir.join("../firmware/device.toml");
    println!("cargo:rerun-if-changed={}", description.display());
    let eds = match od_gen::load(&description) {
        Ok(d) => od_gen::eds::eds(&d),
        Err(report) => {
            eprintln!("{report}");
            std::process::exit(1);
        }
    };
    if let Err(e) = fs::write(out_dir.join("drive.eds"), eds) {
        eprintln!("cannot write the EDS: {e}");
        std::process::exit(1);
    }
}
