//! Memory-mapped registers of the STM32F405, by address (RM0090 rev 19, section 2.3 "Memory map" and each
//! peripheral's register map). Only the registers the board uses are named here; bit positions are named where
//! they are used, next to the configuration they belong to.

/// One 32-bit peripheral register at a fixed address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reg(usize);

impl Reg {
    /// The register at `base + offset`.
    pub const fn at(base: usize, offset: usize) -> Self {
        Self(base.wrapping_add(offset))
    }

    /// Its address.
    pub const fn addr(self) -> usize {
        self.0
    }

    /// Volatile read.
    #[inline(always)]
    pub fn read(self) -> u32 {
        // SAFETY: every `Reg` is built from the addresses below, which are device registers of the STM32F405
        // (RM0090 memory map): aligned, always mapped, and reading them has no memory-safety effect.
        unsafe { core::ptr::read_volatile(self.0 as *const u32) }
    }

    /// Volatile write.
    #[inline(always)]
    pub fn write(self, value: u32) {
        // SAFETY: as for `read`; a register write changes peripheral state, never Rust-visible memory.
        unsafe { core::ptr::write_volatile(self.0 as *mut u32, value) }
    }

    /// Read-modify-write: clears the bits of `clear`, then sets the bits of `set`. Not atomic: callers use it
    /// only during initialisation or on registers that one tier owns.
    #[inline(always)]
    pub fn modify(self, clear: u32, set: u32) {
        self.write((self.read() & !clear) | set);
    }
}

/// Peripheral base addresses (RM0090 table 1).
pub mod base {
    /// TIM2 (APB1): the instruction/cycle counter under QEMU.
    pub const TIM2: usize = 0x4000_0000;
    /// TIM4 (APB1): the incremental encoder.
    pub const TIM4: usize = 0x4000_0800;
    /// Independent watchdog (APB1 address space, clocked by the LSI).
    pub const IWDG: usize = 0x4000_3000;
    /// PWR (APB1).
    pub const PWR: usize = 0x4000_7000;
    /// TIM1 (APB2): the power-stage PWM.
    pub const TIM1: usize = 0x4001_0000;
    /// ADC1 (APB2): master of the triple injected conversions.
    pub const ADC1: usize = 0x4001_2000;
    /// ADC2 (APB2).
    pub const ADC2: usize = 0x4001_2100;
    /// ADC3 (APB2).
    pub const ADC3: usize = 0x4001_2200;
    /// ADC common registers.
    pub const ADC_COMMON: usize = 0x4001_2300;
    /// GPIO port A (AHB1).
    pub const GPIOA: usize = 0x4002_0000;
    /// GPIO port B (AHB1).
    pub const GPIOB: usize = 0x4002_0400;
    /// GPIO port C (AHB1).
    pub const GPIOC: usize = 0x4002_0800;
    /// Reset and clock control (AHB1).
    pub const RCC: usize = 0x4002_3800;
    /// Flash interface (AHB1).
    pub const FLASH: usize = 0x4002_3C00;
}

/// RCC register offsets (RM0090 section 7.3.24).
pub mod rcc {
    use super::{base::RCC, Reg};
    /// Clock control.
    pub const CR: Reg = Reg::at(RCC, 0x00);
    /// PLL configuration.
    pub const PLLCFGR: Reg = Reg::at(RCC, 0x04);
    /// Clock configuration.
    pub const CFGR: Reg = Reg::at(RCC, 0x08);
    /// AHB1 peripheral clock enable.
    pub const AHB1ENR: Reg = Reg::at(RCC, 0x30);
    /// APB1 peripheral clock enable.
    pub const APB1ENR: Reg = Reg::at(RCC, 0x40);
    /// APB2 peripheral clock enable.
    pub const APB2ENR: Reg = Reg::at(RCC, 0x44);
    /// Clock control and status: the LSI and the reset flags (section 7.3.21).
    pub const CSR: Reg = Reg::at(RCC, 0x74);
}

/// Independent watchdog registers (RM0090 section 21.4).
pub mod iwdg {
    use super::{base::IWDG, Reg};
    /// Key: 0xCCCC starts, 0xAAAA reloads, 0x5555 unlocks PR and RLR.
    pub const KR: Reg = Reg::at(IWDG, 0x00);
    /// Prescaler of the LSI clock.
    pub const PR: Reg = Reg::at(IWDG, 0x04);
    /// Reload value (12 bits).
    pub const RLR: Reg = Reg::at(IWDG, 0x08);
    /// Status: PVU, RVU (an update of PR or RLR is in progress).
    pub const SR: Reg = Reg::at(IWDG, 0x0C);
}

/// Flash interface (RM0090 section 3.9).
pub mod flash {
    use super::{base::FLASH, Reg};
    /// Access control (wait states, caches, prefetch).
    pub const ACR: Reg = Reg::at(FLASH, 0x00);
}

/// Power controller (RM0090 section 5.4).
pub mod pwr {
    use super::{base::PWR, Reg};
    /// Power control (regulator voltage scale).
    pub const CR: Reg = Reg::at(PWR, 0x00);
}

/// GPIO port registers (RM0090 section 8.4).
#[derive(Clone, Copy, Debug)]
pub struct Gpio(pub usize);

impl Gpio {
    /// Mode (input, output, alternate function, analog), 2 bits per pin.
    pub const fn moder(self) -> Reg {
        Reg::at(self.0, 0x00)
    }
    /// Output speed, 2 bits per pin.
    pub const fn ospeedr(self) -> Reg {
        Reg::at(self.0, 0x08)
    }
    /// Pull-up/pull-down, 2 bits per pin.
    pub const fn pupdr(self) -> Reg {
        Reg::at(self.0, 0x0C)
    }
    /// Input data.
    pub const fn idr(self) -> Reg {
        Reg::at(self.0, 0x10)
    }
    /// Bit set/reset: writing bit n sets pin n, bit n + 16 resets it (atomic, no read-modify-write).
    pub const fn bsrr(self) -> Reg {
        Reg::at(self.0, 0x18)
    }
    /// Alternate function, pins 0..=7 (4 bits per pin).
    pub const fn afrl(self) -> Reg {
        Reg::at(self.0, 0x20)
    }
    /// Alternate function, pins 8..=15 (4 bits per pin).
    pub const fn afrh(self) -> Reg {
        Reg::at(self.0, 0x24)
    }
}

/// Timer registers; TIM1 has all of them, the general-purpose timers a subset (RM0090 sections 17.4, 18.4).
#[derive(Clone, Copy, Debug)]
pub struct Tim(pub usize);

impl Tim {
    /// Control 1 (counter enable, direction, centre-aligned mode, ARR preload).
    pub const fn cr1(self) -> Reg {
        Reg::at(self.0, 0x00)
    }
    /// Control 2 (master mode, idle states).
    pub const fn cr2(self) -> Reg {
        Reg::at(self.0, 0x04)
    }
    /// Slave mode control (encoder mode).
    pub const fn smcr(self) -> Reg {
        Reg::at(self.0, 0x08)
    }
    /// DMA/interrupt enable.
    pub const fn dier(self) -> Reg {
        Reg::at(self.0, 0x0C)
    }
    /// Status (rc_w0 flags).
    pub const fn sr(self) -> Reg {
        Reg::at(self.0, 0x10)
    }
    /// Event generation.
    pub const fn egr(self) -> Reg {
        Reg::at(self.0, 0x14)
    }
    /// Capture/compare mode 1 (channels 1, 2).
    pub const fn ccmr1(self) -> Reg {
        Reg::at(self.0, 0x18)
    }
    /// Capture/compare mode 2 (channels 3, 4).
    pub const fn ccmr2(self) -> Reg {
        Reg::at(self.0, 0x1C)
    }
    /// Capture/compare enable.
    pub const fn ccer(self) -> Reg {
        Reg::at(self.0, 0x20)
    }
    /// Counter.
    pub const fn cnt(self) -> Reg {
        Reg::at(self.0, 0x24)
    }
    /// Prescaler.
    pub const fn psc(self) -> Reg {
        Reg::at(self.0, 0x28)
    }
    /// Auto-reload.
    pub const fn arr(self) -> Reg {
        Reg::at(self.0, 0x2C)
    }
    /// Repetition counter (TIM1/TIM8 only).
    pub const fn rcr(self) -> Reg {
        Reg::at(self.0, 0x30)
    }
    /// Capture/compare 1..=4 (`n` = 0..=3).
    pub const fn ccr(self, n: usize) -> Reg {
        Reg::at(self.0, 0x34_usize.wrapping_add(n.wrapping_mul(4)))
    }
    /// Break and dead-time (TIM1/TIM8 only).
    pub const fn bdtr(self) -> Reg {
        Reg::at(self.0, 0x44)
    }
}

/// ADC registers of one converter (RM0090 section 13.13).
#[derive(Clone, Copy, Debug)]
pub struct Adc(pub usize);

impl Adc {
    /// Status (rc_w0 flags).
    pub const fn sr(self) -> Reg {
        Reg::at(self.0, 0x00)
    }
    /// Control 1 (scan, interrupt enables, resolution).
    pub const fn cr1(self) -> Reg {
        Reg::at(self.0, 0x04)
    }
    /// Control 2 (ADON, injected trigger selection and edge).
    pub const fn cr2(self) -> Reg {
        Reg::at(self.0, 0x08)
    }
    /// Sample time, channels 10..=18.
    pub const fn smpr1(self) -> Reg {
        Reg::at(self.0, 0x0C)
    }
    /// Sample time, channels 0..=9.
    pub const fn smpr2(self) -> Reg {
        Reg::at(self.0, 0x10)
    }
    /// Injected sequence.
    pub const fn jsqr(self) -> Reg {
        Reg::at(self.0, 0x38)
    }
    /// Injected data 1..=4 (`n` = 0..=3).
    pub const fn jdr(self, n: usize) -> Reg {
        Reg::at(self.0, 0x3C_usize.wrapping_add(n.wrapping_mul(4)))
    }
}

/// ADC common control register (RM0090 section 13.13.16).
pub const ADC_CCR: Reg = Reg::at(base::ADC_COMMON, 0x04);
