//! Position feedback: the incremental encoder on TIM4 with the index captured in hardware, and the Hall sensors
//! on plain inputs (RM0090 section 18.3.16 "Encoder interface mode").
//!
//! Pins: encoder A/B on PB6/PB7 (TIM4_CH1/CH2, AF2), index on PB8 (TIM4_CH3, AF2); Halls H1/H2/H3 on
//! PC6/PC7/PC8 (inputs with pull-ups); digital inputs 1..4 on PC9..PC12 (inputs with pull-ups, levels as wired; PC0..PC4
//! are the analog inputs of `super::adc`).
//!
//! TIM4 counts in encoder mode 3 (both edges of both channels: 4 counts per line) over the full 16 bits.
//! Channel 3 is an input capture on the index's rising edge: the counter value at the index is latched in CCR3
//! by hardware, with no interrupt latency, and CC3IF says a new one is there (reading CCR3 clears it).

use super::reg::{base, Gpio, Tim};
use crate::hal::power::FeedbackSample;

/// TIM4.
pub const TIM4: Tim = Tim(base::TIM4);
/// Port of the Hall inputs.
const HALL_PORT: Gpio = Gpio(base::GPIOC);
/// Bit of H1 in the port's IDR (H2, H3 follow).
const HALL_SHIFT: u32 = 6;
/// Port of the digital inputs 1..4.
const INPUT_PORT: Gpio = Gpio(base::GPIOC);
/// Bit of digital input 1 in the port's IDR (inputs 2..4 follow): PC9.
const INPUT_SHIFT: u32 = 9;
/// CC3IF in SR.
const SR_CC3IF: u32 = 1 << 3;

/// Configures TIM4 as encoder counter with index capture and starts it. Needs the TIM4 clock and pins set up.
pub fn init() {
    let t = TIM4;
    t.cr1().write(0);
    // CC1S = 01 (IC1 on TI1), IC1F = 0011 (8 samples at f_CK_INT); same for channel 2.
    let input_filtered = 0b01 | (0b0011 << 4);
    t.ccmr1().write(input_filtered | (input_filtered << 8));
    // CC3S = 01 (IC3 on TI3), same filter.
    t.ccmr2().write(input_filtered);
    // CC3E (bit 8): capture enabled, rising edge; CC1/CC2 polarity non-inverted.
    t.ccer().write(1 << 8);
    // SMS = 011: encoder mode 3.
    t.smcr().write(0b011);
    t.arr().write(0xFFFF);
    t.cnt().write(0);
    t.sr().write(0);
    t.cr1().write(1);
}

/// Samples the encoder count, the index latch and the Halls.
#[inline(always)]
pub fn read() -> FeedbackSample {
    let t = TIM4;
    let index_latch = if t.sr().read() & SR_CC3IF != 0 { Some(t.ccr(2).read() as u16) } else { None };
    FeedbackSample {
        encoder_count: t.cnt().read() as u16,
        index_latch,
        hall: ((HALL_PORT.idr().read() >> HALL_SHIFT) & 0b111) as u8,
        digital_inputs: ((INPUT_PORT.idr().read() >> INPUT_SHIFT) & 0b1111) as u8,
        ssi_frame: super::ssi::frame(),
    }
}
