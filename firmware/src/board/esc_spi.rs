//! The ESC chip on SPI1 (issue 6, item 2): the register-level byte bus ([`Spi1`], a
//! [`crate::ecat::spi_pdi::SpiBus`]) under the pure framing of [`crate::ecat::spi_pdi`], and the PDI interrupt
//! line (the ESC's SPI_IRQ, AL event) on EXTI0. An ET1100-class ESC (ET1100, AX58100) with PDI type 0x05; the
//! SII image od-gen builds sets its PDI configuration 0x0150 = 0x03: SPI mode 3, SPI_IRQ push-pull active low,
//! which is what this side is set up for.
//!
//! Pin map addition (see the table in [`super`]):
//!
//! | function                  | pin           | peripheral                          |
//! |---------------------------|---------------|-------------------------------------|
//! | ESC SPI_CLK               | PA5 (AF5)     | SPI1 SCK                            |
//! | ESC SPI_DO (MISO)         | PA6 (AF5)     | SPI1 MISO                           |
//! | ESC SPI_DI (MOSI)         | PA7 (AF5)     | SPI1 MOSI                           |
//! | ESC SPI_SEL (active low)  | PA4 (output)  | GPIOA BSRR (software chip select)   |
//! | ESC SPI_IRQ (active low)  | PB0 (input)   | EXTI0, falling edge                 |
//! | ESC SYNC0                 | PB5 (AF2)     | TIM3 CH2 capture (`sync_timer`)     |
//!
//! PA4..PA7 and PB0 are free on the reference board (the table in [`super`]); SPI1's other pin choices collide
//! (PB5 is SYNC0) or would take the debug port's PB3/PB4.
//!
//! **SPI clock**: SPI1 runs from APB2 (84 MHz) divided by 4: 21 MHz. The ET1100's SPI_CLK limit is 30 MHz
//! (ET1100 datasheet section III, SPI timing), and 21 MHz is what the AX58100 was found reliable at on this MCU's
//! SPI1 with the 3-byte address and wait-state byte (kubabuda/ecat_servo AX58100 benchmarks; 42 MHz was not).
//! The wait-state byte (381 ns at 21 MHz) covers the ESC's read time (240 ns), see [`crate::ecat::spi_pdi`].
//! A byte takes 0.38 us on the wire, about 0.5 us with the polled register access, so a 128-byte mailbox
//! window costs about 65 us.
//!
//! **Who uses the bus**: only code inside the tier-2 lock (`rt::ethercat`: tier 3's poll inside
//! `rt::tier2::with_drive`, the cycle in the PDI and SYNC0 interrupts, also inside it), so an access is never
//! interleaved with another. No DMA: see `rt::ethercat` for what that costs tier 2 and what is left to do.

use super::reg::{base, rcc, Gpio, Reg};
use crate::ecat::spi_pdi::SpiBus;

/// SPI1 (APB2, RM0090 memory map: 0x4001_3000).
const SPI1: usize = 0x4001_3000;
/// Control 1 (RM0090 section 28.5.1).
const SPI1_CR1: Reg = Reg::at(SPI1, 0x00);
/// Status: RXNE bit 0, TXE bit 1, BSY bit 7.
const SPI1_SR: Reg = Reg::at(SPI1, 0x08);
/// Data.
const SPI1_DR: Reg = Reg::at(SPI1, 0x0C);
/// GPIOA bit set/reset (RM0090 section 8.4.7): bits 0..15 set, 16..31 reset.
const GPIOA_BSRR: Reg = Reg::at(base::GPIOA, 0x18);
/// SYSCFG external interrupt configuration 1 (EXTI0..3 port selection; RM0090 section 9.2.3).
const SYSCFG_EXTICR1: Reg = Reg::at(0x4001_3800, 0x08);
/// EXTI (RM0090 section 12.3): interrupt mask, falling trigger, software trigger, pending.
const EXTI: usize = 0x4001_3C00;
const EXTI_IMR: Reg = Reg::at(EXTI, 0x00);
const EXTI_FTSR: Reg = Reg::at(EXTI, 0x0C);
const EXTI_SWIER: Reg = Reg::at(EXTI, 0x10);
const EXTI_PR: Reg = Reg::at(EXTI, 0x14);

/// The chip-select pin PA4.
const CS_PIN: u32 = 4;
/// The IRQ pin PB0 (EXTI line 0).
const IRQ_PIN: u32 = 0;
/// How many status polls a byte may take before the transfer is given up (a byte takes about 64 CPU cycles at
/// 21 MHz; the bound only keeps a dead SPI from hanging the caller with interrupts off).
const BYTE_POLL_LIMIT: u32 = 1_000;

/// CR1: CPHA (0) and CPOL (1) = mode 3, MSTR (2), BR [5:3] = 001 (fPCLK / 4), SSI (8) and SSM (9): software
/// chip select, 8-bit frames, MSB first.
const CR1_CONFIG: u32 = (1 << 0) | (1 << 1) | (1 << 2) | (0b001 << 3) | (1 << 8) | (1 << 9);
/// CR1 SPE: SPI enable.
const CR1_SPE: u32 = 1 << 6;

/// SPI1 with the ESC on it: the byte bus of [`crate::ecat::spi_pdi::SpiEsc`]. Exists once ([`init`]).
#[derive(Debug)]
pub struct Spi1 {
    /// Bytes that timed out (a dead bus): counted, never a hang or a panic. Read for the diagnostics.
    pub timeouts: u32,
}

/// Sets SPI1, its pins, the chip select (high: deselected) and the IRQ pin with EXTI0 on the falling edge (its
/// NVIC entry stays masked until `rt` enables it). Call once at start-up, after `clock::init`.
pub fn init() -> Spi1 {
    rcc::AHB1ENR.modify(0, 0b11); // GPIOA, GPIOB
    rcc::APB2ENR.modify(0, (1 << 12) | (1 << 14)); // SPI1, SYSCFG
    let _ = rcc::APB2ENR.read(); // the enable takes effect after a bus cycle (RM0090 6.3.10 note)

    let a = Gpio(base::GPIOA);
    // Chip select first driven high, then made an output: no glitch low on the ESC's SPI_SEL.
    GPIOA_BSRR.write(1 << CS_PIN);
    a.moder().modify(0b11 << (2 * CS_PIN), 0b01 << (2 * CS_PIN));
    a.ospeedr().modify(0b11 << (2 * CS_PIN), 0b10 << (2 * CS_PIN));
    for n in [5u32, 6, 7] {
        let (two, four) = (n.wrapping_mul(2), n.wrapping_mul(4));
        a.moder().modify(0b11 << two, 0b10 << two);
        a.ospeedr().modify(0b11 << two, 0b10 << two); // fast: clean edges at 21 MHz
        a.afrl().modify(0xF << four, 5 << four); // AF5: SPI1
    }
    let b = Gpio(base::GPIOB);
    b.moder().modify(0b11 << (2 * IRQ_PIN), 0); // input
    b.pupdr().modify(0b11 << (2 * IRQ_PIN), 0b01 << (2 * IRQ_PIN)); // pull-up: inactive while the ESC boots

    SPI1_CR1.write(CR1_CONFIG);
    SPI1_CR1.write(CR1_CONFIG | CR1_SPE);

    SYSCFG_EXTICR1.modify(0xF, 0b0001); // EXTI0 from port B
    EXTI_FTSR.modify(0, 1 << IRQ_PIN);
    EXTI_PR.write(1 << IRQ_PIN); // rc_w1: a stale edge from the ESC's start-up is dropped
    EXTI_IMR.modify(0, 1 << IRQ_PIN);
    Spi1 { timeouts: 0 }
}

/// Acknowledges the PDI interrupt (EXTI0 pending bit). Call first in its handler.
pub fn acknowledge_irq() {
    EXTI_PR.write(1 << IRQ_PIN);
}

/// The ESC's SPI_IRQ is asserted (low): an unmasked AL event is pending.
pub fn irq_active() -> bool {
    Gpio(base::GPIOB).idr().read() & (1 << IRQ_PIN) == 0
}

/// Raises EXTI0 by software: for an IRQ line that went low while nothing listened (edge-triggered EXTI would
/// never see it again).
pub fn pend_irq() {
    EXTI_SWIER.write(1 << IRQ_PIN);
}

/// Waits until `bit` of SPI1's status is set, at most [`BYTE_POLL_LIMIT`] polls.
fn wait_status(bit: u32) -> bool {
    for _ in 0..BYTE_POLL_LIMIT {
        if SPI1_SR.read() & bit != 0 {
            return true;
        }
    }
    false
}

impl SpiBus for Spi1 {
    fn select(&mut self) {
        GPIOA_BSRR.write(1 << (CS_PIN + 16));
    }

    fn transfer(&mut self, mosi: u8) -> u8 {
        if !wait_status(1 << 1) {
            self.timeouts = self.timeouts.wrapping_add(1);
            return 0xFF;
        }
        SPI1_DR.write(u32::from(mosi));
        if !wait_status(1 << 0) {
            self.timeouts = self.timeouts.wrapping_add(1);
            return 0xFF;
        }
        (SPI1_DR.read() & 0xFF) as u8
    }

    fn deselect(&mut self) {
        // RXNE of the last byte is set when its last bit is sampled; BSY clears with the last clock edge.
        for _ in 0..BYTE_POLL_LIMIT {
            if SPI1_SR.read() & (1 << 7) == 0 {
                break;
            }
        }
        GPIOA_BSRR.write(1 << CS_PIN);
    }
}
