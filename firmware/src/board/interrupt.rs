//! The STM32F405's device interrupts the firmware uses, by their position in the vector table (RM0090 table 61,
//! positions 0..=81). Which handler sits at each position is the runtime's (`rt::vectors`).

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
