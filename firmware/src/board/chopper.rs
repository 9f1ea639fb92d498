//! The braking chopper's gate output: PB1, push-pull, high = the braking resistor conducts. The decision is tier 2's
//! (`drive::chopper`, after each background step); this module only drives the pin. Low from reset and from [`init`]
//! on, so the resistor never conducts before the drive decides it should.

#[cfg(not(feature = "qemu"))]
use super::reg::{base, Gpio};

/// PB1: free of every other function of the reference board (pin map in [`super`]).
#[cfg(not(feature = "qemu"))]
const PIN: u32 = 1;

/// Drives the pin low, then makes it a push-pull output (RM0090 section 8.4: BSRR first, so the pin never shows
/// the output register's reset level as a glitch).
pub fn init() {
    #[cfg(not(feature = "qemu"))]
    {
        let port = Gpio(base::GPIOB);
        port.bsrr().write(1 << (PIN + 16));
        let two = PIN * 2;
        port.moder().modify(0b11 << two, 0b01 << two);
    }
}

/// The gate for the next slow period.
#[inline]
pub fn set_gate(on: bool) {
    #[cfg(not(feature = "qemu"))]
    {
        let bit = if on { 1 << PIN } else { 1 << (PIN + 16) };
        Gpio(base::GPIOB).bsrr().write(bit);
    }
    #[cfg(feature = "qemu")]
    let _ = on;
}
