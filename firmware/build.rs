//! Runs od-gen on the device description and hands the root `memory.x` to the linker for target builds.

use std::{env, fs, path::PathBuf};

#[path = "build_flash_map.rs"]
mod build_flash_map;

fn main() {
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let out_dir = PathBuf::from(env::var("OUT_DIR").unwrap_or_default());
    let description = manifest_dir.join("device.toml");
    println!("cargo:rerun-if-changed={}", description.display());

    // Object and entry names reach a master only through the CoE SDO information service: the CANopen image on
    // the target leaves them out (about 8 KB of strings); the host and the EtherCAT image keep them.
    let target = env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none");
    let names = !target || env::var("CARGO_FEATURE_ETHERCAT").is_ok();
    if let Err(report) = od_gen::generate_all_with_names(&description, &out_dir, names) {
        // Every mistake in the description, with file, object and reason; the build stops here.
        for line in report.lines() {
            println!("cargo:warning={line}");
        }
        eprintln!("{report}");
        std::process::exit(1);
    }

    // The single flash map lives at the workspace root; copy it where the linker looks for `memory.x`.
    let memory_x = manifest_dir.join("../memory.x");
    println!("cargo:rerun-if-changed={}", memory_x.display());
    // ...and turn its regions into `crate::flash_map` constants.
    println!("cargo:rerun-if-changed={}", manifest_dir.join("build_flash_map.rs").display());
    if let Err(e) = build_flash_map::generate(&memory_x, &out_dir) {
        eprintln!("{e}");
        std::process::exit(1);
    }
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        if let Err(e) = fs::copy(&memory_x, out_dir.join("memory.x")) {
            eprintln!("cannot copy {}: {e}", memory_x.display());
            std::process::exit(1);
        }
        // cortex-m-rt's `device` feature INCLUDEs device.x; the interrupt table itself is Rust (rt::vectors).
        let device_x = manifest_dir.join("src/rt/device.x");
        println!("cargo:rerun-if-changed={}", device_x.display());
        if let Err(e) = fs::copy(&device_x, out_dir.join("device.x")) {
            eprintln!("cannot copy {}: {e}", device_x.display());
            std::process::exit(1);
        }
        println!("cargo:rustc-link-search={}", out_dir.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        // The application links with cortex-m-rt's link.x into FLASH (slot A). The bootloader (package
        // `bootloader`) links with a script of its own into BOOTLOADER and finds memory.x on this search path.
        println!("cargo:rustc-link-arg-bin=drive=-Tlink.x");
        if env::var("CARGO_FEATURE_DEFMT").is_ok() {
            println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
        }
    }
}
