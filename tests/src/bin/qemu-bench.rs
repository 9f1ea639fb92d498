//! `cargo run --release -p drive-tests --bin qemu-bench`: builds the target image with the `qemu` feature, runs it
//! under QEMU with `-icount shift=0` and prints what it measured (`insn.<name>=<count>`: instructions, exact and
//! repeatable: `foc_step`, `fast_tick_max`, `slow_tick_max` of a CSP run, `ecat_cycle`, `can_sync`; see
//! `firmware/src/rt/bench.rs`; `boot_verify` from a second run through the bootloader, see below), the image's own `source.*`/`count.*`/`csp.*` lines and its size. Exits non-zero if the image failed (a check in
//! the image, e.g. a fault in the CSP run). How the image boots: `drive_tests::qemu`.

use std::process::ExitCode;

use drive_tests::qemu;

fn main() -> ExitCode {
    let (elf, run) = match qemu::build_and_run() {
        Ok(done) => done,
        Err(e) => {
            eprintln!("qemu-bench: {e}");
            return ExitCode::FAILURE;
        }
    };
    for (key, value) in &run.values {
        println!("{key}={value}");
    }
    match qemu::image_size(&elf) {
        Some(size) => println!("size.text={}\nsize.data={}\nsize.bss={}", size.text, size.data, size.bss),
        None => eprintln!("qemu-bench: no llvm-size (rustup component add llvm-tools) or arm-none-eabi-size"),
    }
    // The board images' text (issue 17: gated by tests/tests/qemu.rs).
    match qemu::variant_text_sizes() {
        Ok(sizes) => {
            for (name, text) in sizes {
                match text {
                    Some(text) => println!("size.text.{name}={text}"),
                    None => eprintln!("qemu-bench: no size tool for size.text.{name}"),
                }
            }
        }
        Err(e) => eprintln!("qemu-bench: image variants: {e}"),
    }
    eprint!("{}", run.stderr);
    // `insn.boot_verify` (issue 7): the bootloader's header, CRC and signature check of this image, signed with the
    // development key and started by the bootloader in QEMU; the bench image cannot hold a signed copy of itself.
    let boot_ok = match boot_verify(&elf) {
        Ok(lines) => {
            println!("{lines}");
            true
        }
        Err(e) => {
            eprintln!("qemu-bench: boot_verify: {e}");
            false
        }
    };
    if !boot_ok {
        return ExitCode::FAILURE;
    }
    match run.status {
        Some(0) => ExitCode::SUCCESS,
        status => {
            eprintln!("qemu-bench: the image exited with {status:?}");
            ExitCode::FAILURE
        }
    }
}

/// Builds the QEMU bootloader and `drive-image`, packs `elf` with the development key, boots it through the bootloader
/// and returns the `insn.boot_verify` line with the payload size it covers and the bootloader's size.
fn boot_verify(elf: &std::path::Path) -> Result<String, String> {
    let bins = qemu::build_target_bins(&[qemu::BOOTLOADER_BIN], &["qemu"]).map_err(|e| e.to_string())?;
    let tool = qemu::build_image_tool().map_err(|e| e.to_string())?;
    let image = qemu::pack_image(&tool, elf, "1.0.0").map_err(|e| e.to_string())?;
    let run =
        qemu::run_with_bootloader(&bins[0], &qemu::slot_a_contents(&image), "bench").map_err(|e| e.to_string())?;
    let count = run.insn("boot_verify").ok_or_else(|| format!("no insn.boot_verify (status {:?})", run.status))?;
    if run.status != Some(0) {
        return Err(format!("the image started by the bootloader exited with {:?}", run.status));
    }
    let payload = image.len().saturating_sub(firmware::boot::image::HEADER_LEN as usize);
    let size = std::fs::read(&bins[0]).ok().and_then(|b| qemu::flash_extent(&b)).map_or(0, |(lo, hi)| hi - lo);
    Ok(format!(
        "source.boot_verify=boot::verify::verify_in_flash of slot A in the bootloader (header, CRC-32, Ed25519)\n\
         insn.boot_verify={count}\ncount.boot_verify_payload_bytes={payload}\nsize.bootloader_qemu={size}"
    ))
}
