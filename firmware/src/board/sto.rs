//! The two Safe Torque Off inputs as the microcontroller reads them back (EPOS4 AN ch. 9, S1 L8741-8905).
//!
//! On the reference board each STO input, optically isolated (S1 Tab. 9-85), switches the supply of the gate
//! drivers: de-energised, the output transistors cannot switch, whatever TIM1 drives on the gate pins. That is the
//! safety function, and no register of this module is in it. A second opto-coupler per input reports its level to
//! a GPIO, read here by tier 2 once per slow period ([`read`]; `rt::tier2`), never by tier 1:
//!
//! | input   | pin  | level                                 |
//! |---------|------|---------------------------------------|
//! | STO-IN1 | PB10 | high = energised (torque permitted)   |
//! | STO-IN2 | PB11 | high = energised (torque permitted)   |
//!
//! PB10/PB11 are free in the pin map of [`super`] (PB12..PB15 are TIM1's break and low sides, PB5..PB8 SYNC0 and
//! the encoder, PB0 the ESC's IRQ) and five-volt tolerant. Pull-downs: an open opto-coupler output or a missing
//! feedback line reads "de-energised", the state the hardware is then most likely in, so the firmware never shows
//! torque permitted while it is not.
//!
//! QEMU's `netduinoplus2` has no safety circuit: the `qemu` image reads both inputs energised ([`read`] returns a
//! constant there, so its instruction counts measure the drive, not a GPIO model).

use crate::hal::sto::StoInputs;

#[cfg(not(feature = "qemu"))]
use super::reg::{base, Gpio};

/// The port of both feedback pins.
#[cfg(not(feature = "qemu"))]
const PORT: Gpio = Gpio(base::GPIOB);
/// STO-IN1's feedback pin: PB10.
#[cfg(not(feature = "qemu"))]
const PIN_CHANNEL_1: u32 = 10;
/// STO-IN2's feedback pin: PB11.
#[cfg(not(feature = "qemu"))]
const PIN_CHANNEL_2: u32 = 11;

/// PB10 and PB11 as inputs with pull-downs (module documentation). Needs the GPIOB clock.
#[cfg(not(feature = "qemu"))]
pub fn init() {
    let two_bits = |pin: u32| 0b11 << pin.wrapping_mul(2);
    let mask = two_bits(PIN_CHANNEL_1) | two_bits(PIN_CHANNEL_2);
    // MODER 00 = input; PUPDR 10 = pull-down (RM0090 sections 8.4.1, 8.4.4).
    PORT.moder().modify(mask, 0);
    let pull_down = (0b10 << PIN_CHANNEL_1.wrapping_mul(2)) | (0b10 << PIN_CHANNEL_2.wrapping_mul(2));
    PORT.pupdr().modify(mask, pull_down);
}

/// The levels of STO-IN1 and STO-IN2 now.
#[inline(always)]
pub fn read() -> StoInputs {
    #[cfg(not(feature = "qemu"))]
    {
        let idr = PORT.idr().read();
        StoInputs { channel_1: idr & (1 << PIN_CHANNEL_1) != 0, channel_2: idr & (1 << PIN_CHANNEL_2) != 0 }
    }
    #[cfg(feature = "qemu")]
    {
        StoInputs::RELEASED
    }
}
