//! The independent watchdog (IWDG, RM0090 section 21) and the reset flags that tell, at the next start, whether it
//! reset the device (RCC_CSR, section 7.3.21). Issue 19 item 3; the feeding rule is `supervision::watchdog`.
//!
//! Timeout: the IWDG counts the LSI (32 kHz nominal, 17 to 47 kHz over the F405's range, datasheet table 35)
//! divided by 64 from [`RELOAD`] = 2,000: 4.0 s nominal, 2.7 s at the fastest LSI, 7.5 s at the slowest. The
//! shortest must exceed the longest time the core stalls on purpose: a 128 KiB sector erase, up to 2 s at x32
//! (datasheet t_ERASE128KB), during which no tier runs. Program control's *clear* erases three such sectors in a
//! row, so the flash driver feeds the watchdog before each erase (`board::flash`), and every erase has the whole
//! timeout to itself. Once started the IWDG runs until the next reset (a software reset stops it: the bootloader
//! runs without it).

use super::reg::{iwdg, rcc};
use crate::hal::reset::ResetCause;

/// KR: start the watchdog.
const KEY_START: u32 = 0xCCCC;
/// KR: reload the counter.
const KEY_RELOAD: u32 = 0xAAAA;
/// KR: unlock PR and RLR.
const KEY_UNLOCK: u32 = 0x5555;
/// PR = 4: LSI / 64.
const PRESCALER_DIV_64: u32 = 4;
/// Counter reload: 2,000 LSI/64 periods (module documentation).
const RELOAD: u32 = 2_000;
/// RCC_CSR.RMVF: clears the reset flags.
const CSR_RMVF: u32 = 1 << 24;
/// Polls of IWDG_SR before the start goes on without waiting for the prescaler and reload to be taken: the update
/// takes up to 5 LSI periods (156 us at 32 kHz), a few thousand polls; the values are taken in any case.
const UPDATE_POLLS: u32 = 100_000;

/// Reads why the device started and clears the flags, so that the next start reads its own cause. Call once,
/// first thing at start-up.
pub fn take_reset_cause() -> ResetCause {
    let cause = ResetCause::from_rcc_csr(rcc::CSR.read());
    rcc::CSR.modify(0, CSR_RMVF);
    cause
}

/// Starts the watchdog with the timeout of the module documentation (the hardware turns the LSI on). From here on
/// [`feed`] must run at least every 2.7 s.
pub fn start() {
    iwdg::KR.write(KEY_UNLOCK);
    iwdg::PR.write(PRESCALER_DIV_64);
    iwdg::RLR.write(RELOAD);
    let mut polls = 0;
    while iwdg::SR.read() != 0 && polls < UPDATE_POLLS {
        polls = polls.wrapping_add(1);
    }
    iwdg::KR.write(KEY_RELOAD);
    iwdg::KR.write(KEY_START);
}

/// Reloads the counter: tier 3 when every tier ran (`supervision::watchdog`), and the flash driver before a
/// sector erase. Does nothing before [`start`].
#[inline]
pub fn feed() {
    iwdg::KR.write(KEY_RELOAD);
}
