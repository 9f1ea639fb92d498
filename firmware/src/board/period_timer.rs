//! The QEMU bench's period timer (feature `qemu`): the SysTick timer on the core clock, standing in for the
//! board's PWM timer and ADC (which QEMU does not model) so that tier 1 runs at the real period whatever the lower
//! tiers do, as it does on the board.
//!
//! QEMU's `netduinoplus2` clocks SysTick (CLKSOURCE = processor clock) at 168 MHz of virtual time, and under
//! `-icount shift=0` one instruction takes 1 ns (`shared/spec/target-qemu.md`): one tick is 1000/168 = 5.95
//! instructions, and the 6,720-cycle PWM period of the board is 1,129 ticks (6,720.2 instructions). The STM32
//! timers of QEMU's model cannot serve here: their update alarm is set at twice the elapsed virtual time (the
//! model adds the current time to an absolute deadline), so a periodic update interrupt fires only near reset.
//!
//! SysTick counts down from its reload value and wraps at the period's start, so `reload - current` read in the
//! handler is the time since the period began: the interrupt's latency, to one tick.

use super::reg::Reg;

/// SysTick control and status (ARMv7-M ARM B3.3.3): ENABLE, TICKINT, CLKSOURCE.
const SYST_CSR: Reg = Reg::at(0xE000_E010, 0x00);
/// SysTick reload value.
const SYST_RVR: Reg = Reg::at(0xE000_E010, 0x04);
/// SysTick current value.
const SYST_CVR: Reg = Reg::at(0xE000_E010, 0x08);

/// SysTick ticks per second under QEMU (the core clock of `netduinoplus2`).
pub const TICK_HZ: u32 = 168_000_000;
/// Ticks of one current-loop period (40 us at 168 MHz: 6,720 cycles).
pub const PERIOD_TICKS: u32 = 1_129;
/// One period in instructions under QEMU: [`PERIOD_TICKS`] rounded down (6,720; the board's 6,720 cycles to a tick).
pub const PERIOD_INSTRUCTIONS: u32 = ticks_to_instructions(PERIOD_TICKS);

/// Instructions (ns under `-icount shift=0`) of `ticks` SysTick ticks, rounded down.
#[must_use]
pub const fn ticks_to_instructions(ticks: u32) -> u32 {
    // ticks < 2^32: the product < 2^62 fits the u64, and the quotient (< 6 x ticks) a u32 for ticks < 2^29.
    let ns = (ticks as u64).wrapping_mul(1_000_000_000);
    match ns.checked_div(TICK_HZ as u64) {
        Some(q) => q as u32,
        None => 0,
    }
}

/// Starts SysTick with a wrap (and its exception) every [`PERIOD_TICKS`]. The exception's priority is the caller's.
pub fn start() {
    SYST_CSR.write(0);
    SYST_RVR.write(PERIOD_TICKS - 1);
    SYST_CVR.write(0);
    SYST_CSR.write(0b111); // CLKSOURCE = core clock, TICKINT, ENABLE
}

/// Stops the timer and its exception.
pub fn stop() {
    SYST_CSR.write(0);
}

/// Ticks since the period began (the last wrap).
#[inline(always)]
pub fn ticks_since_wrap() -> u32 {
    SYST_RVR.read().wrapping_sub(SYST_CVR.read())
}
