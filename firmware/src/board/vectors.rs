//! The STM32F405's device interrupt vectors (RM0090 table 61, positions 0..=81) and the interrupt numbers the
//! runtime uses. cortex-m-rt (feature `device`) places `__INTERRUPTS` right after the 16 system exceptions;
//! `device.x` in this directory is the (empty) linker include that feature asks for.
//!
//! Every vector the firmware does not use goes to `DefaultHandler`, which `rt` overrides with a safe-state
//! handler: an unexpected interrupt switches the power stage off.

use cortex_m::interrupt::InterruptNumber;

/// Number of device vectors of the STM32F405/407 (the last is FPU, 81).
pub const DEVICE_VECTORS: usize = 82;

/// The interrupts the runtime enables.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Interrupt {
    /// ADC1/2/3 global interrupt: JEOC of ADC1, the end of the injected conversions. Tier 1.
    Adc = 18,
    /// TIM8 update / TIM13 global: both timers are unused on the reference board, so this vector serves as the
    /// software interrupt of the tier-2 executor (pended through NVIC STIR, never by hardware).
    Tier2 = 44,
    /// EXTI line 0: the ESC's SPI_IRQ on PB0 (`esc_spi`, feature `ethercat`). Tier-2 priority.
    EscPdi = 6,
    /// TIM3 global: the SYNC0 capture (`sync_timer`, feature `ethercat`). Tier-2 priority.
    Sync0 = 29,
}

// SAFETY: the discriminants are valid device interrupt numbers of the STM32F405 (below `DEVICE_VECTORS`).
unsafe impl InterruptNumber for Interrupt {
    #[inline(always)]
    fn number(self) -> u16 {
        self as u16
    }
}

/// One entry of the table: a handler address (Thumb bit set by the linker).
#[derive(Clone, Copy)]
#[repr(transparent)]
pub struct Vector(unsafe extern "C" fn());

extern "C" {
    /// cortex-m-rt's default handler (overridden by `rt`).
    fn DefaultHandler();
}

/// Handler of an interrupt position, `DefaultHandler` elsewhere. Evaluated at compile time: an index out of
/// range would be a build error, not a panic.
#[allow(clippy::indexing_slicing)]
const fn table() -> [Vector; DEVICE_VECTORS] {
    // Positions RM0090 marks reserved on the F405 stay DefaultHandler too: they can never fire.
    let mut t = [Vector(DefaultHandler); DEVICE_VECTORS];
    t[Interrupt::Adc as usize] = Vector(crate::rt::tier1::on_adc);
    t[Interrupt::Tier2 as usize] = Vector(crate::rt::tier2::on_interrupt);
    #[cfg(all(feature = "ethercat", not(feature = "qemu")))]
    {
        t[Interrupt::EscPdi as usize] = Vector(crate::rt::ethercat::on_pdi_irq);
        t[Interrupt::Sync0 as usize] = Vector(crate::rt::ethercat::on_sync0);
    }
    t
}

/// The device part of the vector table. Kept in the application by cortex-m-rt's `link.x` (`EXTERN(__INTERRUPTS)`,
/// `KEEP`), deliberately not `#[used]`: that would make the linker retain it, and with it the drive's tier
/// handlers, in every binary of the crate, the bootloader included (`src/bin/bootloader.x` has no device vectors).
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
pub static __INTERRUPTS: [Vector; DEVICE_VECTORS] = table();
