//! The bootloader for the STM32F405 (issue 7, part 4): runs at every reset from the region BOOTLOADER
//! (0x0800_0000, 32 KiB, linked with `bootloader.x`), decides with [`firmware::boot::loader::boot`] over the
//! internal flash (`firmware::board::boot`): header, CRC-32 and Ed25519 signature of the image in slot A (and of
//! a pending one in slot B), the power-fail-safe swap or its resumption, the revert of an image that did not
//! confirm itself; then starts the verified application, or stays in the fallback when no valid image exists.
//!
//! * Clocks: none are changed; the bootloader runs on the 16 MHz HSI of reset, so the application's own clock
//!   set-up finds the reset state it expects.
//! * A flash error during the decision ([`BootError::Flash`](firmware::boot::swap::BootError::Flash): on the board, a failing supply) resets the core:
//!   the next boot resumes from the last state record (`boot::swap`).
//! * Fallback (`stay_in_bootloader`): the IDX spec's bootloader state (L3345-3350: 0x1F51 reads 3 "no
//!   program", device type 0x0000012E, one interface) must answer on the fieldbus so that a new image can be
//!   loaded. The bootloader does not link the ESC (SPI) or bxCAN drivers yet, so `serve_fieldbus` is the hook where that
//!   service plugs in and nothing answers yet.
//!
//! With the `qemu` feature (QEMU's `netduinoplus2`): reports on semihosting stdout (`boot.*` lines and
//! `insn.boot_verify`, the instruction count of the header, CRC and signature check of slot A under
//! `-icount shift=0`), and the fallback exits with `EXIT_NO_VALID_IMAGE` (3) instead of waiting.
//! On the host this builds as a stub.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod target {
    use firmware::board::boot::{start_application, update_flash, StartError};
    use firmware::boot::image::{ImageError, HARDWARE_ID, MAX_PAYLOAD_LEN};
    use firmware::boot::keys::DEV_PUBLIC_KEY;
    use firmware::boot::loader::{boot, Outcome};
    use firmware::boot::swap::BootError;
    use firmware::boot::verify::Trust;

    /// What images must satisfy: signed with the compiled-in key, for this hardware, fitting slot A.
    const TRUST: Trust = Trust { public_key: DEV_PUBLIC_KEY, hardware_id: HARDWARE_ID, max_payload: MAX_PAYLOAD_LEN };
    /// Copy and verification buffer: a whole number of flash words; 2 KiB keeps the stack small and the flash
    /// reads few.
    const BUF_LEN: usize = 2048;

    /// Why the bootloader stays active.
    pub(crate) enum Fallback {
        /// Slot A holds no valid image.
        NoValidImage(ImageError),
        /// Slot A's image verified but its vector table is unusable.
        Start(StartError),
        /// The update state cannot be kept (state log full, region layout).
        State(BootError),
        /// The flash regions were already taken (cannot happen: `main` takes them once).
        NoFlash,
    }

    impl Fallback {
        /// The reason as one number for the QEMU report (`boot.fallback=`): 1xx no valid image (`ImageError`:
        /// 100 truncated, 101 trailing data, 102 bad magic, 103 format version, 104 malformed header, 105 wrong
        /// hardware, 106 load address, 107 oversized, 108 CRC, 109 signature, 110 flash), 2xx unusable vector
        /// table (200 stack pointer, 201 reset vector, 202 flash), 3xx update state (300 log full, 301 layout,
        /// 302 flash regions taken). Numbers, not `Debug` text: the formatting code would not fit the 32 KiB.
        #[cfg_attr(not(feature = "qemu"), allow(dead_code))]
        pub(crate) fn code(&self) -> u32 {
            match *self {
                Fallback::NoValidImage(e) => match e {
                    ImageError::Truncated => 100,
                    ImageError::TrailingData => 101,
                    ImageError::BadMagic => 102,
                    ImageError::UnsupportedVersion(_) => 103,
                    ImageError::MalformedHeader => 104,
                    ImageError::WrongHardware { .. } => 105,
                    ImageError::WrongLoadAddress(_) => 106,
                    ImageError::Oversized { .. } => 107,
                    ImageError::Crc { .. } => 108,
                    ImageError::BadSignature => 109,
                    ImageError::Flash(_) => 110,
                },
                Fallback::Start(StartError::StackPointer(_)) => 200,
                Fallback::Start(StartError::ResetVector(_)) => 201,
                Fallback::Start(StartError::Flash(_)) => 202,
                Fallback::State(BootError::StateFull) => 300,
                Fallback::State(_) => 301,
                Fallback::NoFlash => 302,
            }
        }
    }

    #[cortex_m_rt::entry]
    fn main() -> ! {
        let Some(mut flash) = update_flash() else { stay_in_bootloader(Fallback::NoFlash) };
        let mut buf = [0u8; BUF_LEN];
        #[cfg(feature = "qemu")]
        qemu::measure_verify(&mut flash.slot_a, &TRUST, &mut buf);
        match boot(&mut flash, &TRUST, &mut buf) {
            Ok(Outcome::Run { header, trial, event }) => {
                // `trial` and `event` are the application's business (it confirms itself, `boot::update`).
                let _ = (trial, event);
                let error = start_application(&mut flash.slot_a, &header);
                stay_in_bootloader(Fallback::Start(error))
            }
            Ok(Outcome::NoValidImage(e)) => stay_in_bootloader(Fallback::NoValidImage(e)),
            // The supply is failing (or the controller refused): start again, the log says where to resume.
            Err(BootError::Flash(_)) => cortex_m::peripheral::SCB::sys_reset(),
            Err(e) => stay_in_bootloader(Fallback::State(e)),
        }
    }

    /// The bootloader's fallback: no application runs; the fieldbus service answers so that a new image can be
    /// loaded (IDX L3345-3350). Never returns.
    fn stay_in_bootloader(reason: Fallback) -> ! {
        #[cfg(feature = "qemu")]
        qemu::report_fallback(reason);
        #[cfg(not(feature = "qemu"))]
        let _ = reason;
        loop {
            serve_fieldbus();
        }
    }

    /// Hook of the bootloader's fieldbus service: where the ESC (EtherCAT: BOOT state, FoE) or CAN driver of
    /// the reduced object set (0x1F51 = 3 "no program", 0x1000 = 0x0000012E) is polled and a received image is
    /// written to slot B through `boot::update`. The reference board's bootloader has no such driver yet:
    /// nothing answers, the core only waits. Under QEMU (no fieldbus either) the run ends here with
    /// `EXIT_NO_VALID_IMAGE`, so that a test sees the bootloader in its fallback.
    fn serve_fieldbus() {
        #[cfg(feature = "qemu")]
        firmware::board::semihosting::exit(firmware::board::semihosting::EXIT_NO_VALID_IMAGE);
        #[cfg(not(feature = "qemu"))]
        core::hint::spin_loop();
    }

    /// The QEMU report: `key=value` lines on semihosting stdout, as few and as plain as possible (the 32 KiB
    /// hold the semihosting build's panic formatting too).
    #[cfg(feature = "qemu")]
    mod qemu {
        use core::hint::black_box;
        use core::sync::atomic::{compiler_fence, Ordering};

        use firmware::board::boot::UpdateRegion;
        use firmware::board::counter;
        use firmware::board::semihosting::print;
        use firmware::boot::image::HEADER_OFFSET;
        use firmware::boot::verify::{verify_in_flash, Trust};

        use super::Fallback;

        /// `insn.boot_verify`: instructions of one `verify_in_flash` of slot A (header checks, CRC-32 and Ed25519
        /// over header and payload, through the bootloader's 2 KiB buffer), TIM2 under `-icount shift=0`, the
        /// cost of the counter reads subtracted. Run once before the real decision, which repeats the same check.
        pub(crate) fn measure_verify(slot_a: &mut UpdateRegion, trust: &Trust, buf: &mut [u8]) {
            counter::init();
            let overhead = counter::read_overhead();
            let start = counter::now();
            compiler_fence(Ordering::SeqCst);
            let verdict = verify_in_flash(slot_a, HEADER_OFFSET, black_box(trust), buf);
            compiler_fence(Ordering::SeqCst);
            let cost = counter::now().wrapping_sub(start).saturating_sub(overhead);
            black_box(verdict.is_ok());
            print(format_args!("insn.boot_verify={cost}\n"));
        }

        /// `boot.fallback=` the reason's [`Fallback::code`].
        pub(crate) fn report_fallback(reason: Fallback) {
            print(format_args!("boot.fallback={}\n", reason.code()));
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "`bootloader` is a target image: build it with `cargo build -p firmware --release --target \
         thumbv7em-none-eabihf --bin bootloader`"
    );
}
