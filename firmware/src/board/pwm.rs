//! TIM1: three complementary, centre-aligned PWM pairs at 25 kHz with dead time and a hardware break input, plus
//! channel 4 as the ADC trigger at the PWM centre (RM0090 section 17, advanced-control timer).
//!
//! Pins (AF1): CH1/CH2/CH3 high sides on PA8/PA9/PA10, CH1N/CH2N/CH3N low sides on PB13/PB14/PB15, BKIN on PB12.
//!
//! - Counter: centre-aligned mode 1 (CMS = 01), PSC = 0, ARR = `PWM_PERIOD_TICKS`: 168 MHz / (2 x 3360) = 25 kHz.
//! - Channels 1..3: PWM mode 1 (high side on while CNT < CCRx), preload on (OCxPE), so a duty written by tier 1
//!   takes effect at the next update event. With RCR = 0 updates happen at both ends of the count; tier 1
//!   writes shortly after the centre (CNT = ARR) and the new duties load at the following underflow.
//! - Channel 4: compare at `ARR - 3` while counting down, i.e. just after the centre where all three low
//!   switches conduct: its CC4 event starts the injected ADC conversions (JEXTSEL = TIM1_CC4). `- 3` rather
//!   than `- 1`: the DC phase-locked loop trims ARR down to `3360 - 2` (`sync_timer`), and the compare must
//!   stay below it so that every period triggers the conversions (at most 5 ticks, 30 ns, after the centre).
//! - Dead time: `DEAD_TIME_TICKS` of t_DTS = 1/168 MHz (CKD = 00) = 0.5 us, `DTG[7] = 0` encoding.
//! - Break: BKE = 1, polarity `BREAK_ACTIVE_HIGH`. A break clears MOE in hardware within a few ns; AOE = 0 so only
//!   software re-enables the outputs. OSSI = OSSR = 1 with OISx = OISxN = 0: with MOE off every gate is driven to
//!   its inactive level (all six switches off) rather than left floating.
//! - LOCK level 1 freezes DTG, BKE, BKP, AOE and OISx after configuration; MOE stays writable.

use super::reg::{base, Tim};
use crate::hal::power::{PwmCommand, PWM_PERIOD_TICKS, TIMER_CLOCK_HZ};

/// TIM1.
pub const TIM1: Tim = Tim(base::TIM1);

/// Dead time in timer ticks: 0.5 us at 168 MHz.
pub const DEAD_TIME_TICKS: u32 = TIMER_CLOCK_HZ / 2_000_000;
const _: () = assert!(DEAD_TIME_TICKS == 84 && DEAD_TIME_TICKS <= 127, "DTG[7] = 0 encoding holds up to 127 ticks");

/// Level of BKIN (PB12) that trips the break: the over-current comparator pulls it low.
pub const BREAK_ACTIVE_HIGH: bool = false;

/// BDTR without MOE: dead time, OSSI (bit 10), OSSR (bit 11), BKE (bit 12), BKP (bit 13), LOCK = 1 (bits 9:8).
pub const BDTR_CONFIG: u32 =
    DEAD_TIME_TICKS | (1 << 8) | (1 << 10) | (1 << 11) | (1 << 12) | ((BREAK_ACTIVE_HIGH as u32) << 13);
/// Main output enable.
pub const BDTR_MOE: u32 = 1 << 15;
/// Break interrupt flag in SR (set by hardware when the break input trips).
pub const SR_BIF: u32 = 1 << 7;

/// Compare value of channel 4: just after the centre, counting down; below the shortest trimmed ARR
/// (`sync_timer::ARR_RANGE`).
pub const ADC_TRIGGER_COMPARE: u32 = PWM_PERIOD_TICKS as u32 - 3;
const _: () = assert!(ADC_TRIGGER_COMPARE < super::sync_timer::ARR_RANGE.0 as u32, "a trimmed period still triggers");

/// Configures TIM1 and starts its counter with the outputs off (MOE = 0). Needs the TIM1 clock and the pins
/// already set up (`super::init`).
pub fn init() {
    let t = TIM1;
    t.cr1().write(0); // stopped while configuring
    t.psc().write(0);
    t.arr().write(u32::from(PWM_PERIOD_TICKS));
    t.rcr().write(0);
    // OC1M = OC2M = 110 (PWM 1) with OCxPE; channel 3 likewise; channel 4 PWM 1 with preload (its CC4 event is
    // what matters, its pin is not enabled).
    let pwm1_preload = (0b110 << 4) | (1 << 3);
    t.ccmr1().write(pwm1_preload | (pwm1_preload << 8));
    t.ccmr2().write(pwm1_preload | (pwm1_preload << 8));
    for n in 0..3 {
        t.ccr(n).write(0);
    }
    t.ccr(3).write(ADC_TRIGGER_COMPARE);
    // CC1E, CC1NE, CC2E, CC2NE, CC3E, CC3NE; all active high.
    t.ccer().write((1 << 0) | (1 << 2) | (1 << 4) | (1 << 6) | (1 << 8) | (1 << 10));
    // OISx = OISxN = 0 (off when idle), MMS = 000.
    t.cr2().write(0);
    t.bdtr().write(BDTR_CONFIG);
    // Load PSC/ARR/CCR preloads now, then clear the flags that generated.
    t.egr().write(1);
    t.sr().write(0);
    // ARPE (bit 7), CMS = 01 (bits 6:5), CEN.
    t.cr1().write((1 << 7) | (0b01 << 5) | 1);
}

/// Clamps a compare value into 0..=`PWM_PERIOD_TICKS`.
#[inline(always)]
fn clamp(duty: u16) -> u32 {
    u32::from(duty.min(PWM_PERIOD_TICKS))
}

/// Writes a command: duties into the preload registers, then MOE. `PwmCommand::OFF` (enabled = false) clears MOE:
/// all six switches off at once, whatever the duties.
#[inline(always)]
pub fn write(cmd: &PwmCommand) {
    let t = TIM1;
    if cmd.enabled {
        let [a, b, c] = cmd.duty;
        t.ccr(0).write(clamp(a));
        t.ccr(1).write(clamp(b));
        t.ccr(2).write(clamp(c));
        t.bdtr().write(BDTR_CONFIG | BDTR_MOE);
    } else {
        disable();
    }
}

/// The safe state: MOE off. One store; usable from any context, including the panic and fault handlers.
#[inline(always)]
pub fn disable() {
    TIM1.bdtr().write(BDTR_CONFIG);
}

/// Whether the break input tripped since the last call (reads and clears BIF; a still-active input sets it again).
#[inline(always)]
pub fn take_break() -> bool {
    let t = TIM1;
    if t.sr().read() & SR_BIF != 0 {
        t.sr().write(!SR_BIF);
        true
    } else {
        false
    }
}
