//! Output and exit through semihosting, for the QEMU image only (on a board without a debugger a semihosting
//! call faults, so this module exists only with the `qemu` feature).
//!
//! QEMU runs with `-semihosting-config enable=on,target=native`: [`print`] goes to QEMU's stdout, [`eprint`] to
//! its stderr, and [`exit`] ends QEMU with the given status (SYS_EXIT_EXTENDED, which QEMU honours for 32-bit
//! Arm too, so codes other than 0 and 1 reach the runner).

use core::fmt::{self, Write};

use cortex_m_semihosting::hio;

/// Exit status: the run passed.
pub const EXIT_OK: u32 = 0;
/// Exit status: a check in the image failed.
pub const EXIT_CHECK_FAILED: u32 = 1;
/// Exit status: panic.
pub const EXIT_PANIC: u32 = 101;
/// Exit status: HardFault.
pub const EXIT_HARD_FAULT: u32 = 102;
/// Exit status: an interrupt without a handler fired.
pub const EXIT_UNEXPECTED_INTERRUPT: u32 = 103;
/// Exit status of the bootloader image: no valid application image, the bootloader stays in its fallback
/// (`firmware/src/bin/bootloader.rs`).
pub const EXIT_NO_VALID_IMAGE: u32 = 3;

/// Writes to the host's stdout.
pub fn print(args: fmt::Arguments) {
    if let Ok(mut out) = hio::hstdout() {
        let _ = out.write_fmt(args);
    }
}

/// Writes to the host's stderr.
pub fn eprint(args: fmt::Arguments) {
    if let Ok(mut out) = hio::hstderr() {
        let _ = out.write_fmt(args);
    }
}

/// Ends the emulation with `status` as QEMU's exit status.
pub fn exit(status: u32) -> ! {
    /// ADP_Stopped_ApplicationExit (semihosting specification, "SYS_EXIT").
    const APPLICATION_EXIT: usize = 0x2_0026;
    /// SYS_EXIT_EXTENDED: takes a (reason, subcode) block.
    const SYS_EXIT_EXTENDED: usize = 0x20;
    let block = [APPLICATION_EXIT, status as usize];
    // SAFETY: a semihosting call with a valid parameter block; under QEMU it does not return.
    unsafe {
        cortex_m_semihosting::syscall(SYS_EXIT_EXTENDED, &block);
    }
    // A debugger that resumes us lands here: stay put.
    loop {
        cortex_m::asm::bkpt();
    }
}
