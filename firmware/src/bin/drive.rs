//! The drive application for the STM32F405. On the host this builds as a stub that says how to build it.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;

    #[entry]
    fn main() -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    #[panic_handler]
    fn panic(_info: &core::panic::PanicInfo) -> ! {
        // A panic is a bug; the power stage is left off because PWM outputs are never enabled before the
        // runtime starts. The real runtime (rt/) replaces this with a safe-state handler.
        loop {
            cortex_m::asm::udf();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("`drive` is the target image: build it with `cargo build -p firmware --release --target thumbv7em-none-eabihf`");
}
