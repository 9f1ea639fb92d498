//! The load encoder (sensor 2, 0x3020; the dual loop's main sensor, EPOS4 AN ch. 10): a second A/B encoder on
//! TIM5 in encoder mode (RM0090 section 18.3.16), read by tier 2 once per slow period.
//!
//! Pin map addition (see the table in [`super`]): load encoder A/B on PA0/PA1 (TIM5_CH1/CH2, AF2). TIM5 is one of
//! the two 32-bit timers: the count wraps after 2^32 increments, so the drive needs no extension of a 16-bit count
//! and a slow period can never see more than half a wrap. No index: the dual loop uses the load encoder
//! relatively (its position starts at the motor encoder's, `motion::dual_loop`).

use super::reg::Tim;
#[cfg(not(feature = "qemu"))]
use super::reg::{base, rcc, Gpio};

/// TIM5 (RM0090 memory map: 0x4000_0C00).
const TIM5: Tim = Tim(0x4000_0C00);

/// TIM5 clock, PA0/PA1 as TIM5_CH1/CH2, encoder mode 3 (4 counts per line) over the full 32 bits.
#[cfg(not(feature = "qemu"))]
pub fn init() {
    rcc::AHB1ENR.modify(0, 1); // GPIOA
    rcc::APB1ENR.modify(0, 1 << 3); // TIM5
    let _ = rcc::APB1ENR.read(); // the enable takes effect after a bus cycle (RM0090 6.3.10 note)
    let a = Gpio(base::GPIOA);
    a.moder().modify(0b1111, 0b1010); // PA0, PA1 alternate
    a.afrl().modify(0xFF, 0x22); // AF2: TIM5
    let t = TIM5;
    t.cr1().write(0);
    // CC1S = 01 (IC1 on TI1), IC1F = 0011 (8 samples), the same for channel 2 (as the motor encoder, `feedback`).
    let input_filtered = 0b01 | (0b0011 << 4);
    t.ccmr1().write(input_filtered | (input_filtered << 8));
    t.ccer().write(0);
    t.smcr().write(0b011); // SMS = 011: encoder mode 3
    t.arr().write(u32::MAX);
    t.cnt().write(0);
    t.cr1().write(1);
}

/// The load encoder's count now (increments, wrapping at 2^32).
#[inline(always)]
pub fn read() -> u32 {
    TIM5.cnt().read()
}
