//! The drive application for the STM32F405: brings the board up and runs the three timing tiers
//! (`firmware::rt`). Built with the `qemu` feature, the same image runs on QEMU's `netduinoplus2`, skips the
//! clock and peripheral set-up, feeds tier 1 from a built-in plant and reports instruction counts
//! (`cargo run --release -p drive-tests --bin qemu-bench`). On the host this builds as a stub.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    firmware::rt::run()
}

/// QEMU image: the bench's period timer drives tier 1 (`firmware::rt::tier1::on_period_timer`).
#[cfg(all(target_os = "none", feature = "qemu"))]
#[cortex_m_rt::exception]
fn SysTick() {
    firmware::rt::tier1::on_period_timer();
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "`drive` is the target image: build it with `cargo build -p firmware --release --target thumbv7em-none-eabihf`"
    );
}
