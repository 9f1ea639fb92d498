//! ADC1/2/3 in triple injected-simultaneous mode, triggered by TIM1 CC4 at the PWM centre (RM0090 section 13).
//!
//! Each converter samples one phase shunt at the same instant (rank 1), then a slow quantity (rank 2):
//!
//! | converter | rank 1 (JDR1)        | rank 2 (JDR2)                 |
//! |-----------|----------------------|-------------------------------|
//! | ADC1      | phase A, PC0 (IN10)  | DC-bus voltage, PC3 (IN13)    |
//! | ADC2      | phase B, PC1 (IN11)  | power-stage temp., PC4 (IN14) |
//! | ADC3      | phase C, PC2 (IN12)  | motor temperature, PA3 (IN3)  |
//!
//! Both temperatures are linear sensors (0.5 V at 0 degC, 10 mV/K; `crate::sensors::temperature::temperature_ddegc`).
//! The motor's comes through the motor cable on PA3 (ADC123_IN3, free in the pin map of `super`), with a
//! pull-down on the board so that a missing sensor reads code 0 (tier 2 takes a code at a rail as "no sensor
//! connected", IDX L5476).
//!
//! ADCCLK = APB2 84 MHz / 4 = 21 MHz; 15-cycle sampling (0.71 us, inside the low-side conduction window of
//! `target-qemu.md`'s budget section) + 12 cycles = 1.29 us per rank. With JL = 1 the sequencer converts JSQ3
//! then JSQ4 and stores them in JDR1, JDR2 (RM0090 section 13.13.12). ADC1 (the master) raises JEOC when its
//! sequence ends, which is when all three have finished (same sequence length and sample times): that
//! interrupt (`ADC`, IRQ 18) is tier 1. Only ADC1 has the trigger (JEXTEN) and JEOCIE; the slaves follow it.

use super::reg::{base, Adc, ADC_CCR};
use crate::hal::power::AdcSamples;

/// ADC1 (master).
pub const ADC1: Adc = Adc(base::ADC1);
/// ADC2 (slave).
pub const ADC2: Adc = Adc(base::ADC2);
/// ADC3 (slave).
pub const ADC3: Adc = Adc(base::ADC3);

/// JEOC flag in SR.
const SR_JEOC: u32 = 1 << 2;
/// JSTRT flag in SR.
const SR_JSTRT: u32 = 1 << 3;

/// ADC3's input for the motor temperature sensor: ADC123_IN3 on PA3.
const MOTOR_TEMPERATURE_CHANNEL: u32 = 3;

/// JSQR for two injected conversions (JL = 1): `first` in JSQ3 [14:10], `second` in JSQ4 [19:15].
const fn jsqr(first: u32, second: u32) -> u32 {
    (1 << 20) | (first << 10) | (second << 15)
}

/// Configures the three converters and arms the injected trigger. Needs the ADC clocks and the analog pins
/// already set up (`super::init`).
pub fn init() {
    // ADCPRE [17:16] = 01 (PCLK2 / 4), MULTI [4:0] = 10101 (triple, injected simultaneous only).
    ADC_CCR.write((0b01 << 16) | 0b10101);
    // 15-cycle sampling (SMP = 001) on channels 10..14 (SMPR1, 3 bits each from channel 10 at bit 0) and on
    // channel 3 (SMPR2 [11:9]): the same sample time on every rank keeps the three sequences simultaneous.
    let smp = (0..5u32).fold(0, |acc, ch| acc | (0b001 << ch.wrapping_mul(3)));
    let smp_in3 = 0b001 << 9;
    for (adc, seq) in [(ADC1, jsqr(10, 13)), (ADC2, jsqr(11, 14)), (ADC3, jsqr(12, MOTOR_TEMPERATURE_CHANNEL))] {
        adc.smpr1().write(smp);
        adc.smpr2().write(smp_in3);
        adc.jsqr().write(seq);
        // SCAN (bit 8), 12-bit resolution.
        adc.cr1().write(1 << 8);
        adc.cr2().write(1); // ADON
    }
    // Master: JEOCIE (bit 7); JEXTSEL [19:16] = 0000 (TIM1_CC4), JEXTEN [21:20] = 01 (rising edge).
    ADC1.cr1().modify(0, 1 << 7);
    ADC1.cr2().write((0b01 << 20) | 1);
}

/// Reads the results of the sequence that just ended and acknowledges the interrupt (clears JEOC/JSTRT on the
/// master).
#[inline(always)]
pub fn read() -> AdcSamples {
    // JDR values are 12-bit right-aligned: the `as u16` keeps all of them.
    let samples = AdcSamples {
        phase_currents: [ADC1.jdr(0).read() as u16, ADC2.jdr(0).read() as u16, ADC3.jdr(0).read() as u16],
        bus_voltage: ADC1.jdr(1).read() as u16,
        temperature: ADC2.jdr(1).read() as u16,
        motor_temperature: ADC3.jdr(1).read() as u16,
    };
    ADC1.sr().write(!(SR_JEOC | SR_JSTRT));
    samples
}
