//! Last-resort handlers: panic, HardFault and unexpected interrupts. Each one first switches the power stage to
//! its safe state (TIM1 MOE off: all six switches off), then reports and stops:
//!
//! - QEMU image: message on semihosting stderr, then exit with a distinct status (`board::semihosting`).
//! - Board: defmt error message (with the `defmt` feature), then a system reset; the drive restarts with its
//!   outputs off and the fault visible in its start-up state.

use cortex_m_rt::{exception, ExceptionFrame};

use crate::board;

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    board::safe_state();
    #[cfg(feature = "qemu")]
    {
        board::semihosting::eprint(format_args!("panic: {info}\n"));
        board::semihosting::exit(board::semihosting::EXIT_PANIC);
    }
    #[cfg(not(feature = "qemu"))]
    {
        // The location only: formatting the message would pull `core::fmt` into every image, and the
        // bootloader (which shares this handler) must fit its 32 KiB sectors with defmt on too.
        #[cfg(feature = "defmt")]
        match info.location() {
            Some(at) => crate::rt_error!("panic at {=str}:{=u32}", at.file(), at.line()),
            None => crate::rt_error!("panic"),
        }
        #[cfg(not(feature = "defmt"))]
        let _ = info;
        cortex_m::peripheral::SCB::sys_reset()
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    board::safe_state();
    #[cfg(feature = "qemu")]
    {
        board::semihosting::eprint(format_args!("HardFault at pc {:#010x}\n", frame.pc()));
        board::semihosting::exit(board::semihosting::EXIT_HARD_FAULT);
    }
    #[cfg(not(feature = "qemu"))]
    {
        crate::rt_error!("HardFault at pc {=u32:#010x}", frame.pc());
        #[cfg(not(feature = "defmt"))]
        let _ = frame;
        cortex_m::peripheral::SCB::sys_reset()
    }
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    board::safe_state();
    #[cfg(feature = "qemu")]
    {
        board::semihosting::eprint(format_args!("unexpected interrupt {irqn}\n"));
        board::semihosting::exit(board::semihosting::EXIT_UNEXPECTED_INTERRUPT);
    }
    #[cfg(not(feature = "qemu"))]
    {
        crate::rt_error!("unexpected interrupt {=i16}", irqn);
        #[cfg(not(feature = "defmt"))]
        let _ = irqn;
        cortex_m::peripheral::SCB::sys_reset()
    }
}
