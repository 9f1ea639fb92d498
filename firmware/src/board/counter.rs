//! The cost counter: what tier 1 and the QEMU bench read before and after a call.
//!
//! - On the board: the DWT cycle counter (CYCCNT, 1 per core cycle at 168 MHz), enabled through DEMCR.TRCENA
//!   (ARMv7-M ARM, C1.8).
//! - Under QEMU (`qemu` feature): TIM2 with PSC = 0 and ARR = 0xFFFF_FFFF. With `-icount shift=0` QEMU advances
//!   virtual time by 1 ns per instruction and clocks its STM32 timer model at 1 GHz, so CNT counts executed
//!   instructions exactly (QEMU models no DWT cycle counter: CYCCNT reads 0). See `shared/spec/target-qemu.md`.
//!
//! Either way [`now`] is one load from a device register and the difference of two readings, wrapping, is the
//! cost of what ran in between plus the cost of one reading ([`read_overhead`] measures that).

use super::reg::Reg;

#[cfg(feature = "qemu")]
mod imp {
    use super::super::reg::{base, Tim};
    use super::Reg;

    const TIM2: Tim = Tim(base::TIM2);
    /// TIM2 CNT.
    pub const COUNTER: Reg = TIM2.cnt();

    pub fn init() {
        let t = TIM2;
        t.cr1().write(0);
        t.psc().write(0);
        t.arr().write(u32::MAX);
        t.egr().write(1); // load PSC/ARR
        t.cnt().write(0);
        t.cr1().write(1);
    }
}

#[cfg(not(feature = "qemu"))]
mod imp {
    use super::Reg;

    /// DWT CYCCNT.
    pub const COUNTER: Reg = Reg::at(0xE000_1000, 0x04);
    const DWT_CTRL: Reg = Reg::at(0xE000_1000, 0x00);
    const DEMCR: Reg = Reg::at(0xE000_EDFC, 0x00);

    pub fn init() {
        DEMCR.modify(0, 1 << 24); // TRCENA
        COUNTER.write(0);
        DWT_CTRL.modify(0, 1); // CYCCNTENA
    }
}

/// Unit of [`now`]: "instructions" under QEMU, "cycles" on the board.
pub const UNIT: &str = if cfg!(feature = "qemu") { "instructions" } else { "cycles" };

/// Starts the counter. Call once during start-up.
pub fn init() {
    imp::init();
}

/// The counter's current value.
#[inline(always)]
pub fn now() -> u32 {
    let counter: Reg = imp::COUNTER;
    counter.read()
}

/// What two back-to-back readings differ by: subtract it from every measurement.
#[inline(never)]
pub fn read_overhead() -> u32 {
    let start = now();
    now().wrapping_sub(start)
}
