//! `cargo run --release -p drive-tests --bin qemu-bench`: builds the target image with the `qemu` feature, runs it
//! under QEMU with `-icount shift=0` and prints what it measured (`insn.<name>=<count>`: instructions, exact and
//! repeatable: `foc_step`, `fast_tick_max`, `slow_tick_max` of a CSP run; see `firmware/src/rt/bench.rs`), the
//! image's own `source.*`/`count.*`/`csp.*` lines and its size. Exits non-zero if the image failed (a check in
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
    eprint!("{}", run.stderr);
    match run.status {
        Some(0) => ExitCode::SUCCESS,
        status => {
            eprintln!("qemu-bench: the image exited with {status:?}");
            ExitCode::FAILURE
        }
    }
}
