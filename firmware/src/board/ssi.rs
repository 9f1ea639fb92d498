//! The SSI absolute encoder on SPI3 as the SSI master (RM0090 section 28, SPI; section 10, DMA), the frame's
//! format and checks being [`crate::sensors::ssi`]'s.
//!
//! Pins: SSI clock on PB3 (SPI3_SCK, AF6), SSI data on PB4 (SPI3_MISO, AF6, pull-up), through an RS-422
//! transceiver; MOSI is not connected (the master only receives). PB3/PB4 are free on the reference board (JTAG's
//! TDO/NJTRST, unused with SWD).
//!
//! SPI3 (APB1, 42 MHz) is a master with the clock idle high (CPOL = 1) sampling on the first, falling edge of each
//! clock (CPHA = 0): the first falling edge latches the position in the sensor and samples the line before the
//! sensor drives it (the start bit: high when the sensor is ready); each rising edge shifts the next data bit out,
//! read at the following falling edge. 16-bit frames, two per SSI frame (32 clocks; the clocks after the frame's
//! last bit read the sensor's monoflop level, low, and are shifted out). The data rate 0x3012:01 selects the
//! highest rate of 42 MHz / 2^(n+1) not above it (656 kbit/s for the default 500 kHz range's 400..2,000 kbit/s:
//! 1,312 or 656).
//!
//! Timing: tier 1 starts a transfer in each period, right after the ADC sample at the PWM centre, and takes its
//! result in the next period: the position used in period n was latched at the centre of period n - 1 (the
//! sampling delay the simulator's sensor models, one period). DMA1 stream 0 channel 0 (SPI3_RX, RM0090 table 42)
//! moves the two halves into [`RX`]; a transfer the DMA has not completed by the next period is a frame not
//! sampled: [`frame`] returns 0, which the frame check takes as no data (0x738C).
//!
//! The port is set up at start-up from the stored configuration ([`init`], from `rt`): a change of 0x3000:01 or
//! 0x3012 takes effect on the board at the next start (the dictionary's power-disabled objects).

use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use super::reg::{base, rcc, Gpio, Reg};

/// SPI3 (APB1, RM0090 memory map: 0x4000_3C00).
const SPI3: usize = 0x4000_3C00;
/// SPI3 control 1.
const SPI3_CR1: Reg = Reg::at(SPI3, 0x00);
/// SPI3 control 2.
const SPI3_CR2: Reg = Reg::at(SPI3, 0x04);
/// SPI3 status.
const SPI3_SR: Reg = Reg::at(SPI3, 0x08);
/// SPI3 data.
const SPI3_DR: Reg = Reg::at(SPI3, 0x0C);
/// DMA1 (AHB1).
const DMA1: usize = 0x4002_6000;
/// DMA1 low interrupt flag clear (streams 0..3).
const DMA1_LIFCR: Reg = Reg::at(DMA1, 0x08);
/// DMA1 stream 0 configuration.
const DMA1_S0CR: Reg = Reg::at(DMA1, 0x10);
/// DMA1 stream 0 number of data items.
const DMA1_S0NDTR: Reg = Reg::at(DMA1, 0x14);
/// DMA1 stream 0 peripheral address.
const DMA1_S0PAR: Reg = Reg::at(DMA1, 0x18);
/// DMA1 stream 0 memory address.
const DMA1_S0M0AR: Reg = Reg::at(DMA1, 0x1C);
/// Stream 0's flags in LIFCR: FEIF0, DMEIF0, TEIF0, HTIF0, TCIF0.
const STREAM0_FLAGS: u32 = 0b11_1101;
/// CR1: CPOL (1), MSTR (2), SSI (8) and SSM (9): software slave select; DFF (11): 16-bit frames; CPHA = 0.
const CR1_CONFIG: u32 = (1 << 1) | (1 << 2) | (1 << 8) | (1 << 9) | (1 << 11);
/// CR1 SPE.
const CR1_SPE: u32 = 1 << 6;
/// SR TXE.
const SR_TXE: u32 = 1 << 1;
/// Polls of TXE before the second half is written anyway (TXE sets within a few bus cycles of the first).
const TXE_POLL_LIMIT: u32 = 32;
/// DMA stream configuration: channel 0, 16-bit memory and peripheral sizes, memory increment, peripheral to memory.
const S0CR_CONFIG: u32 = (0b01 << 13) | (0b01 << 11) | (1 << 10);
/// SPI3's kernel clock, kHz (APB1).
const PCLK_KHZ: u32 = 42_000;

/// The two received halves, written by the DMA.
static RX: [AtomicU16; 2] = [const { AtomicU16::new(0) }; 2];
/// Bits clocked per frame (0: no SSI sensor configured, [`frame`] returns 0 and starts nothing).
static FRAME_BITS: AtomicU32 = AtomicU32::new(0);

/// Sets up SPI3, its pins and the DMA for frames of `frame_bits` (1..=32) at `rate_kbit`, and starts the first
/// transfer. Call once at start-up, when the stored configuration has an SSI sensor.
pub fn init(frame_bits: u8, rate_kbit: u32) {
    rcc::AHB1ENR.modify(0, (1 << 1) | (1 << 21)); // GPIOB, DMA1
    rcc::APB1ENR.modify(0, 1 << 15); // SPI3
    let _ = rcc::APB1ENR.read(); // the enable takes effect after a bus cycle (RM0090 6.3.10 note)
    let b = Gpio(base::GPIOB);
    for n in [3u32, 4] {
        let (two, four) = (n.wrapping_mul(2), n.wrapping_mul(4));
        b.moder().modify(0b11 << two, 0b10 << two);
        b.afrl().modify(0xF << four, 6 << four); // AF6: SPI3
    }
    // Data line pulled up: a receiver with no sensor behind it reads ones (a constant line: no data).
    b.pupdr().modify(0b11 << 8, 0b01 << 8);
    // The highest rate not above the configured one: 42 MHz / 2^(n+1), n = 0..=7.
    let mut divider = 0u32;
    while divider < 7 && (PCLK_KHZ >> divider.wrapping_add(1)) > rate_kbit {
        divider = divider.wrapping_add(1);
    }
    SPI3_CR1.write(CR1_CONFIG | (divider << 3));
    SPI3_CR2.write(1); // RXDMAEN
    SPI3_CR1.write(CR1_CONFIG | (divider << 3) | CR1_SPE);
    DMA1_S0CR.write(0);
    DMA1_S0PAR.write(SPI3_DR.addr() as u32);
    DMA1_S0CR.write(S0CR_CONFIG);
    FRAME_BITS.store(u32::from(frame_bits.clamp(1, 32)), Ordering::Relaxed);
    start();
}

/// Starts a transfer of two halves: the DMA armed for them, then the clocks (a dummy word written twice).
#[inline(always)]
fn start() {
    DMA1_S0CR.write(S0CR_CONFIG);
    DMA1_LIFCR.write(STREAM0_FLAGS);
    DMA1_S0NDTR.write(2);
    DMA1_S0M0AR.write(RX.as_ptr() as u32);
    DMA1_S0CR.write(S0CR_CONFIG | 1);
    SPI3_DR.write(0xFFFF);
    for _ in 0..TXE_POLL_LIMIT {
        if SPI3_SR.read() & SR_TXE != 0 {
            break;
        }
    }
    SPI3_DR.write(0xFFFF);
}

/// The frame of the transfer started in the last period, right-aligned (0 when it did not complete, or without an
/// SSI sensor), and the next transfer started.
#[inline(always)]
pub fn frame() -> u32 {
    let bits = FRAME_BITS.load(Ordering::Relaxed);
    if bits == 0 {
        return 0;
    }
    let [high, low] = &RX;
    let raw = if DMA1_S0NDTR.read() == 0 {
        u32::from(high.load(Ordering::Relaxed)) << 16 | u32::from(low.load(Ordering::Relaxed))
    } else {
        0
    };
    start();
    raw >> 32u32.wrapping_sub(bits)
}
