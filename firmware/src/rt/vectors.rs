//! The device part of the vector table: the tiers' handlers at their interrupts' positions
//! ([`crate::board::interrupt`]). cortex-m-rt (feature `device`) places `__INTERRUPTS` right after the 16 system
//! exceptions; `device.x` in this directory is the (empty) linker include that feature asks for.
//!
//! Every vector the firmware does not use goes to `DefaultHandler`, which `rt` overrides with a safe-state
//! handler: an unexpected interrupt switches the power stage off.

use crate::board::interrupt::{Interrupt, DEVICE_VECTORS};

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
    t[Interrupt::Adc as usize] = Vector(super::tier1::on_adc);
    t[Interrupt::Tier2 as usize] = Vector(super::tier2::on_interrupt);
    #[cfg(all(feature = "ethercat", not(feature = "qemu")))]
    {
        t[Interrupt::EscPdi as usize] = Vector(super::ethercat::on_pdi_irq);
        t[Interrupt::Sync0 as usize] = Vector(super::ethercat::on_sync0);
    }
    t
}

/// The device part of the vector table. Kept in the application by cortex-m-rt's `link.x` (`EXTERN(__INTERRUPTS)`,
/// `KEEP`), deliberately not `#[used]`: that would make the linker retain it, and with it the drive's tier
/// handlers, in every binary of the crate, the bootloader included (`src/bin/bootloader.x` has no device vectors).
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
pub static __INTERRUPTS: [Vector; DEVICE_VECTORS] = table();
