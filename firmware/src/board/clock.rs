//! Clock tree: 8 MHz HSE crystal, main PLL to SYSCLK = 168 MHz (RM0090 section 6.3).
//!
//! | clock            | value   | how                                         |
//! |------------------|---------|---------------------------------------------|
//! | VCO              | 336 MHz | HSE / PLLM (8) x PLLN (336)                 |
//! | SYSCLK, HCLK     | 168 MHz | VCO / PLLP (2), AHB prescaler 1             |
//! | PLL48CK          | 48 MHz  | VCO / PLLQ (7), for USB if ever used        |
//! | APB2, its timers | 84 MHz, 168 MHz | PPRE2 = /2; timers run at 2 x APB2 (TIM1: `TIMER_CLOCK_HZ`) |
//! | APB1, its timers | 42 MHz, 84 MHz  | PPRE1 = /4                          |
//!
//! Flash needs 5 wait states at 168 MHz and 2.7..3.6 V (RM0090 table 10). QEMU does not model the RCC (its
//! ready bits read 0), so the `qemu` build never calls this.

use super::reg::{flash, pwr, rcc};
use crate::hal::power::TIMER_CLOCK_HZ;

/// Crystal frequency of the reference board.
pub const HSE_HZ: u32 = 8_000_000;
/// System clock after [`init`].
pub const SYSCLK_HZ: u32 = 168_000_000;

const PLLM: u32 = 8;
const PLLN: u32 = 336;
const PLLP: u32 = 2;
const PLLQ: u32 = 7;

// The PLL settings must produce the clock the PWM arithmetic assumes (APB2 timer clock = SYSCLK here).
const _: () = assert!(HSE_HZ / PLLM * PLLN / PLLP == SYSCLK_HZ);
const _: () = assert!(SYSCLK_HZ == TIMER_CLOCK_HZ);
const _: () = assert!(HSE_HZ / PLLM * PLLN / PLLQ == 48_000_000);

/// Polls of a ready flag before giving up (a few ms at the 16 MHz HSI that runs during start-up).
const READY_POLLS: u32 = 100_000;

/// A clock source did not become ready: the crystal or the PLL is broken. The drive must not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClockError {
    /// HSERDY never set.
    Hse,
    /// PLLRDY never set.
    Pll,
    /// The switch to the PLL was not confirmed in SWS.
    Switch,
}

fn wait(mut ready: impl FnMut() -> bool) -> bool {
    for _ in 0..READY_POLLS {
        if ready() {
            return true;
        }
    }
    false
}

/// Starts the HSE and the PLL and switches SYSCLK to 168 MHz. Bounded: every wait gives up after
/// `READY_POLLS` polls and returns the failing stage.
pub fn init() -> Result<(), ClockError> {
    // Power interface clock, regulator voltage scale 1 (needed above 144 MHz).
    rcc::APB1ENR.modify(0, 1 << 28);
    pwr::CR.modify(0, 1 << 14);

    // HSEON (bit 16), wait for HSERDY (bit 17).
    rcc::CR.modify(0, 1 << 16);
    if !wait(|| rcc::CR.read() & (1 << 17) != 0) {
        return Err(ClockError::Hse);
    }

    // PLLM [5:0], PLLN [14:6], PLLP [17:16] (00 = /2), PLLSRC = HSE (bit 22), PLLQ [27:24].
    rcc::PLLCFGR.write(PLLM | (PLLN << 6) | (((PLLP / 2) - 1) << 16) | (1 << 22) | (PLLQ << 24));
    // PLLON (bit 24), wait for PLLRDY (bit 25).
    rcc::CR.modify(0, 1 << 24);
    if !wait(|| rcc::CR.read() & (1 << 25) != 0) {
        return Err(ClockError::Pll);
    }

    // 5 wait states, prefetch (bit 8), instruction cache (bit 9), data cache (bit 10) before speeding up.
    flash::ACR.write(5 | (1 << 8) | (1 << 9) | (1 << 10));

    // HPRE = /1, PPRE1 [12:10] = 101 (/4), PPRE2 [15:13] = 100 (/2), then SW [1:0] = 10 (PLL).
    rcc::CFGR.modify(0xFCF0, (0b101 << 10) | (0b100 << 13));
    rcc::CFGR.modify(0b11, 0b10);
    // SWS [3:2] = 10 confirms the switch.
    if !wait(|| rcc::CFGR.read() & (0b11 << 2) == 0b10 << 2) {
        return Err(ClockError::Switch);
    }
    Ok(())
}

/// Puts the clock tree back into its reset state (RM0090 §6.3: RCC_CR, RCC_PLLCFGR and RCC_CFGR reset values;
/// §3.5.1: FLASH_ACR), so that software started afterwards finds what a reset leaves: the bootloader runs at
/// 168 MHz ([`init`]) and calls this before it jumps to the application, whose own [`init`] expects the reset
/// state (it programs the PLL, which must be off, and relies on the HSI running SYSCLK).
///
/// Order (RM0090 §6.3.3, §6.3.1, §3.5.1): SYSCLK back to the HSI (which stays on from reset) and wait until SWS
/// confirms it; only then are the prescalers reset, the PLL and the HSE switched off (neither clocks anything
/// any more), and last, at 16 MHz, the flash wait states dropped (fewer wait states before the clock is slow
/// would break instruction fetches) and the caches reset while they are disabled. Bounded like [`init`]: a
/// switch that is not confirmed leaves the rest untouched and returns [`ClockError::Switch`].
pub fn restore_reset_state() -> Result<(), ClockError> {
    // HSION (bit 0) is set from reset and never cleared by `init`; wait for HSIRDY (bit 1) all the same.
    rcc::CR.modify(0, 1);
    if !wait(|| rcc::CR.read() & (1 << 1) != 0) {
        return Err(ClockError::Switch);
    }
    // SW [1:0] = 00 (HSI), SWS [3:2] = 00 confirms it.
    rcc::CFGR.modify(0b11, 0);
    if !wait(|| rcc::CFGR.read() & (0b11 << 2) == 0) {
        return Err(ClockError::Switch);
    }
    // CFGR reset value 0: AHB and APB prescalers /1, MCO settings off.
    rcc::CFGR.write(0);
    // PLLON (bit 24) and HSEON (bit 16) off, wait for PLLRDY (bit 25) to clear; PLLCFGR reset value.
    rcc::CR.modify((1 << 24) | (1 << 16), 0);
    let _ = wait(|| rcc::CR.read() & (1 << 25) == 0);
    rcc::PLLCFGR.write(0x2400_3010);
    // Power interface clock off again (PWREN, bit 28 of APB1ENR, reset 0; the regulator scale stays at its
    // reset value, scale 1).
    rcc::APB1ENR.modify(1 << 28, 0);
    // Flash: 0 wait states, prefetch and caches off, then both caches reset (ICRST bit 11, DCRST bit 12: only
    // allowed while they are disabled), then the reset value 0.
    flash::ACR.write(0);
    flash::ACR.write((1 << 11) | (1 << 12));
    flash::ACR.write(0);
    Ok(())
}
