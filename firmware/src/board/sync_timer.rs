//! What the DC phase-locked loop ([`crate::ecat::sync_pll`]) needs of the hardware: TIM1's period trim and the
//! SYNC0 capture (issue 6, item 2). Nothing calls this yet: the SYNC0 line comes from an ESC chip, and no ESC chip
//! driver exists (no SPI ESC on the reference board so far). The intended use, from `rt` once it does:
//! [`init`] at start-up; in the SYNC0 interrupt (TIM3 capture, [`take_capture`]) build a
//! [`crate::ecat::sync_pll::Sync0Capture`], call [`crate::ecat::sync_pll::SyncPll::on_sync0`] and, when the trim
//! changed, refresh the DMA table from [`crate::ecat::sync_pll::SyncPll::fill_pattern`] ([`write_arr_table`]);
//! [`crate::ecat::sync_pll::SyncPll::supervise`] from the slow tier. No loop logic here.
//!
//! **Period trim**: TIM1 runs with ARPE = 1 (`pwm::init`), so a new ARR takes effect at the next update event.
//! [`set_arr`] writes one value (clamped to the loop's range); for the per-period dither the loop needs,
//! [`start_arr_stream`] lets DMA2 stream 5 channel 6 (TIM1_UP, RM0090 Table 43) copy a circular table into ARR
//! at every update event, without CPU time in the 25 kHz tier (which has no budget left). With RCR = 0 TIM1
//! updates twice per period (under- and overflow), so each period's value appears twice in the table
//! ([`ARR_TABLE_LEN`] = 2 x 64). TIM1's channel 4 (the ADC trigger) compares at `pwm::ADC_TRIGGER_COMPARE`,
//! below the shortest trimmed ARR, so the conversions start in every period whatever the trim.
//!
//! **SYNC0 capture**: TIM3 (APB1 timer clock 84 MHz, 11.9 ns) is reset once per PWM period by TIM1's TRGO
//! (MMS = 111, OC4REF: its rising edge is TIM1's channel-4 compare just after the period's centre, where the
//! currents are sampled; TIM3's ITR0 is TIM1_TRGO, RM0090 Table 93) and captures SYNC0 on PB5 (TIM3_CH2, AF2)
//! on the rising edge. So its capture is the time from the period's start to the pulse, with no interrupt
//! latency in it; the board doubles it into 168 MHz ticks, the loop's unit.
//!
//! Pin map addition (see the table in [`super`]): SYNC0 from the ESC on PB5 (AF2), TIM3 CH2.

use core::sync::atomic::AtomicU16;

use super::pwm::TIM1;
use super::reg::{base, rcc, Gpio, Reg, Tim};
use crate::ecat::sync_pll::{DITHER_LEN, NOMINAL_ARR};

/// TIM3 (RM0090 memory map: 0x4000_0400).
pub const TIM3: Tim = Tim(0x4000_0400);
/// Lowest and highest ARR the loop can ask for (+-498 ppm with the dither).
pub const ARR_RANGE: (u16, u16) = (NOMINAL_ARR - 2, NOMINAL_ARR + 2);
/// Entries of the DMA table: two update events per period, 64 periods.
pub const ARR_TABLE_LEN: usize = 2 * DITHER_LEN;

/// DMA2 (RM0090 memory map: 0x4002_6400), stream 5's registers (section 10.5: 0x10 + 0x18 x stream).
const DMA2: usize = 0x4002_6400;
const S5CR: Reg = Reg::at(DMA2, 0x10 + 0x18 * 5);
const S5NDTR: Reg = Reg::at(DMA2, 0x14 + 0x18 * 5);
const S5PAR: Reg = Reg::at(DMA2, 0x18 + 0x18 * 5);
const S5M0AR: Reg = Reg::at(DMA2, 0x1C + 0x18 * 5);

/// Sets up the capture: TIM3 clock, PB5 as TIM3_CH2, TIM1's TRGO = OC4REF, TIM3 reset by it, input capture on
/// channel 2 with its interrupt enabled (the SYNC0 interrupt; the NVIC entry stays masked until `rt` enables it).
/// Needs TIM1 configured (`pwm::init`).
pub fn init() {
    rcc::AHB1ENR.modify(0, 1 << 1); // GPIOB
    rcc::APB1ENR.modify(0, 1 << 1); // TIM3
    let _ = rcc::APB1ENR.read(); // the enable takes effect after a bus cycle (RM0090 6.3.10 note)
    let b = Gpio(base::GPIOB);
    b.moder().modify(0b11 << 10, 0b10 << 10); // PB5 alternate
    b.afrl().modify(0xF << 20, 2 << 20); // AF2: TIM3
                                         // TIM1 CR2 MMS [6:4] = 111: TRGO = OC4REF.
    TIM1.cr2().modify(0b111 << 4, 0b111 << 4);
    let t = TIM3;
    t.cr1().write(0);
    t.psc().write(0);
    t.arr().write(0xFFFF);
    // SMS [2:0] = 100 reset mode, TS [6:4] = 000 ITR0 (TIM1_TRGO).
    t.smcr().write(0b100);
    // CC2S [9:8] = 01: IC2 on TI2, no filter, no prescaler.
    t.ccmr1().write(0b01 << 8);
    // CC2E (bit 4), rising edge (CC2P = CC2NP = 0).
    t.ccer().write(1 << 4);
    t.egr().write(1);
    t.sr().write(0);
    t.dier().write(1 << 2); // CC2IE
    t.cr1().write(1);
}

/// One SYNC0 capture as TIM3 holds it, in 168 MHz ticks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawCapture {
    /// From the period's start (TIM1's channel-4 compare after the centre) to the pulse.
    pub ticks: u16,
    /// TIM3's count when read, same unit: below `ticks` when a new period began between the pulse and the read,
    /// i.e. the pulse belongs to the period before the current one.
    pub ticks_now: u16,
    /// A second pulse came before the first was read (CC2OF): the earlier one is lost.
    pub overcapture: bool,
}

/// Takes the SYNC0 capture if one is pending (CC2IF), acknowledging it.
pub fn take_capture() -> Option<RawCapture> {
    let t = TIM3;
    let sr = t.sr().read();
    if sr & (1 << 2) == 0 {
        return None;
    }
    let captured = t.ccr(1).read(); // reading CCR2 clears CC2IF
    let now = t.cnt().read();
    let overcapture = sr & (1 << 10) != 0;
    if overcapture {
        t.sr().write(!(1 << 10));
    }
    let ticks = |v: u32| u16::try_from(v.wrapping_mul(2)).unwrap_or(u16::MAX);
    Some(RawCapture { ticks: ticks(captured), ticks_now: ticks(now), overcapture })
}

/// Writes TIM1's auto-reload (preloaded: from the next update event on), clamped to [`ARR_RANGE`] so that no
/// caller can detune the current loop further.
pub fn set_arr(arr: u16) {
    TIM1.arr().write(u32::from(arr.clamp(ARR_RANGE.0, ARR_RANGE.1)));
}

/// Copies the loop's 64-period pattern into the DMA table, each value twice (two update events per period),
/// clamped to [`ARR_RANGE`].
pub fn write_arr_table(table: &[AtomicU16; ARR_TABLE_LEN], pattern: &[u16; DITHER_LEN]) {
    use core::sync::atomic::Ordering::Relaxed;
    for (pair, arr) in table.chunks_exact(2).zip(pattern.iter()) {
        for slot in pair {
            slot.store((*arr).clamp(ARR_RANGE.0, ARR_RANGE.1), Relaxed);
        }
    }
}

/// Starts DMA2 stream 5 copying `table` into TIM1's ARR at every update event, circularly. `table` must be in
/// SRAM (DMA2 cannot reach the CCM): a plain `static` is. Enables the DMA2 clock and TIM1's update DMA request.
pub fn start_arr_stream(table: &'static [AtomicU16; ARR_TABLE_LEN]) {
    rcc::AHB1ENR.modify(0, 1 << 22); // DMA2EN
    let _ = rcc::AHB1ENR.read();
    S5CR.write(0); // EN = 0 before configuring
    while S5CR.read() & 1 != 0 {}
    S5PAR.write(TIM1.arr().addr() as u32);
    S5M0AR.write(table.as_ptr() as u32);
    S5NDTR.write(ARR_TABLE_LEN as u32);
    // CHSEL [27:25] = 6 (TIM1_UP), PL [17:16] = 11, MSIZE [14:13] = PSIZE [12:11] = 01 (half-word), MINC (10),
    // CIRC (8), DIR [7:6] = 01 (memory to peripheral), EN.
    S5CR.write((6 << 25) | (0b11 << 16) | (0b01 << 13) | (0b01 << 11) | (1 << 10) | (1 << 8) | (0b01 << 6) | 1);
    TIM1.dier().modify(0, 1 << 8); // UDE
}
