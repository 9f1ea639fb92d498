//! Links the bootloader into the region BOOTLOADER with its own script (`bootloader.x`). The flash map
//! `memory.x` that the script includes is put on the linker's search path by the firmware package's build script
//! (the single copy of the map).

use std::{env, fs, path::PathBuf};

fn main() {
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let out_dir = PathBuf::from(env::var("OUT_DIR").unwrap_or_default());
    let script = manifest_dir.join("bootloader.x");
    println!("cargo:rerun-if-changed={}", script.display());
    if let Err(e) = fs::copy(&script, out_dir.join("bootloader.x")) {
        eprintln!("cannot copy {}: {e}", script.display());
        std::process::exit(1);
    }
    println!("cargo:rustc-link-search={}", out_dir.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tbootloader.x");
    if env::var("CARGO_FEATURE_DEFMT").is_ok() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
