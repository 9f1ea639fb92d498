//! The bootloader for the STM32F405 (issue 7, part 4): runs at every reset from the region BOOTLOADER
//! (0x0800_0000, 32 KiB, linked with `bootloader.x`), decides with [`firmware::boot::loader::boot`] over the
//! internal flash (`firmware::board::boot`): header, CRC-32 and Ed25519 signature of the image in slot A (and of
//! a pending one in slot B), the power-fail-safe swap or its resumption, the revert of an image that did not
//! confirm itself; then starts the verified application, or stays in the fallback when no valid image exists.
//!
//! * Clocks: the bootloader switches to 168 MHz at its start (`board::clock::init`: the check of a
//!   full slot took about 3-5 s at the 16 MHz HSI of reset) and puts the reset state back
//!   (`board::clock::restore_reset_state`) before it jumps, so the application's own clock set-up
//!   finds what it expects. Without a crystal (`init` fails) it runs on at the HSI and serves no CAN (bxCAN's bit
//!   timing assumes APB1 = 42 MHz). The `qemu` build changes no clock (QEMU models no RCC).
//! * A flash error during the decision ([`BootError::Flash`](firmware::boot::swap::BootError::Flash): on the board, a failing supply) resets the core:
//!   the next boot resumes from the last state record (`boot::swap`).
//! * Fallback (`stay_in_bootloader`): the IDX spec's bootloader state (L3345-3350: 0x1F51 reads 3 "no
//!   program", device type 0x0000012E, one interface) answers on CAN so that a new image can be loaded:
//!   [`firmware::boot::fallback::FallbackNode`] (SDO server of the reduced object set, program control over
//!   slot B) on bxCAN (`board::can::BxCan`), polled: receive, handle, send; the SDO timeout runs on
//!   the DWT cycle counter. One interface only, CAN: the ESC / EtherCAT stack does not fit the 32 KiB. Node-ID
//!   and bit rate are the saved 0x2000 and 0x2001 when the parameter store holds valid ones
//!   ([`firmware::boot::stored_comms`]: the record in force found as the application finds it, CRC, item
//!   structure, node-ID 1..=127, an offered bit-rate code), else the device defaults (node-ID 1, 1 Mbit/s); a
//!   stored rate the controller cannot time exactly from its 42 MHz (800 kbit/s, `hal::can`) falls back to
//!   1 Mbit/s as the application does. The boot-up message goes out first; an NMT reset, 0x1F51 = 1 with a
//!   verified image or 0x1F51 = 2 answers, waits until the transmit mailboxes are empty and resets: the next boot
//!   activates the image.
//!   **Size**: a package of its own so that it is built size-optimised by a per-package profile override (root
//!   `Cargo.toml`: `[profile.release.package.bootloader]` opt-level "z", with the link-time optimisation at that
//!   level; the firmware library it uses keeps the release settings of the drive image). The plain release build
//!   makes it: `cargo build --release -p bootloader --target thumbv7em-none-eabihf` (or the workspace-wide
//!   `cargo build --release --target thumbv7em-none-eabihf`, whose default members are the two images).
//!   28,864 bytes with the CAN service, 32,312 with defmt, 26,172 for QEMU, of the 32,768 (the linker script
//!   refuses an image that does not fit; `tests/tests/qemu_boot.rs` checks all three builds).
//!
//! With the `qemu` feature (QEMU's `netduinoplus2`): reports on semihosting stdout (`boot.*` lines and
//! `insn.boot_verify`, the instruction count of the header, CRC and signature check of slot A under
//! `-icount shift=0`), and the fallback exits with `EXIT_NO_VALID_IMAGE` (3) instead of waiting.
//! On the host this builds as a stub.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod target {
    use firmware::board::boot::{start_application, update_flash, StartError, UpdateFlash};
    use firmware::boot::image::ImageError;
    use firmware::boot::loader::{boot, Outcome};
    use firmware::boot::swap::BootError;
    use firmware::boot::verify::{Trust, DEVICE_TRUST};

    /// What images must satisfy: signed with the compiled-in key, for this hardware, fitting slot A (the same
    /// anchor the application's program control uses).
    const TRUST: Trust = DEVICE_TRUST;
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
        /// hardware, 106 load address, 107 oversized, 108 CRC, 109 signature, 110 flash, 111 security version),
        /// 2xx unusable vector table (200 stack pointer, 201 reset vector, 202 flash), 3xx update state (300 log
        /// full, 301 layout, 302 flash regions taken). Numbers, not `Debug` text: the formatting code would not fit the 32 KiB.
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
                    ImageError::Rollback { .. } => 111,
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

    impl Fallback {
        /// The reason as the fallback's 0x1F57 status sees it: an unusable vector table is an image of unknown
        /// format (status 2), an update state that cannot be kept a flash fault (status 5).
        #[cfg_attr(feature = "qemu", allow(dead_code))]
        fn image_error(&self) -> ImageError {
            match *self {
                Fallback::NoValidImage(e) => e,
                Fallback::Start(_) => ImageError::MalformedHeader,
                Fallback::State(_) | Fallback::NoFlash => ImageError::Flash(firmware::hal::flash::FlashError::Device),
            }
        }
    }

    #[cortex_m_rt::entry]
    fn main() -> ! {
        // 168 MHz for the verification. Without a crystal (HSE or PLL not ready) the HSI runs on, whatever
        // `init` left half done is undone, and the CAN service is skipped (its bit timing needs APB1 = 42 MHz).
        #[cfg(not(feature = "qemu"))]
        let clocked = match firmware::board::clock::init() {
            Ok(()) => true,
            Err(_) => {
                let _ = firmware::board::clock::restore_reset_state();
                false
            }
        };
        #[cfg(feature = "qemu")]
        let clocked = false;
        let Some(mut flash) = update_flash() else { stay_in_bootloader(Fallback::NoFlash, None, clocked) };
        let mut buf = [0u8; BUF_LEN];
        #[cfg(feature = "qemu")]
        qemu::measure_verify(&mut flash.slot_a, &TRUST, &mut buf);
        match boot(&mut flash, &TRUST, &mut buf) {
            Ok(Outcome::Run { header, trial, event }) => {
                // `trial` and `event` are the application's business (it confirms itself, `boot::update`).
                let _ = (trial, event);
                // The application's `clock::init` expects the reset state. Should the switch back not be
                // confirmed, the jump goes ahead all the same: `init` then reports its own clock error.
                #[cfg(not(feature = "qemu"))]
                let _ = firmware::board::clock::restore_reset_state();
                let error = start_application(&mut flash.slot_a, &header);
                stay_in_bootloader(Fallback::Start(error), Some(&mut flash), false)
            }
            Ok(Outcome::NoValidImage(e)) => stay_in_bootloader(Fallback::NoValidImage(e), Some(&mut flash), clocked),
            // The supply is failing (or the controller refused): start again, the log says where to resume.
            Err(BootError::Flash(_)) => cortex_m::peripheral::SCB::sys_reset(),
            Err(e) => stay_in_bootloader(Fallback::State(e), Some(&mut flash), clocked),
        }
    }

    /// The bootloader's fallback: no application runs; the CAN service answers so that a new image can be
    /// loaded (IDX L3345-3350), if the regions and the 168 MHz clock are there (`clocked`; after a failed jump
    /// the clock was already put back to the HSI, so the core only waits). Never returns.
    fn stay_in_bootloader(reason: Fallback, flash: Option<&mut UpdateFlash>, clocked: bool) -> ! {
        #[cfg(feature = "qemu")]
        {
            let _ = (flash, clocked);
            qemu::report_fallback(reason);
            // QEMU has no bxCAN: the run ends here, so that a test sees the bootloader in its fallback.
            firmware::board::semihosting::exit(firmware::board::semihosting::EXIT_NO_VALID_IMAGE);
        }
        #[cfg(not(feature = "qemu"))]
        if let (Some(flash), true) = (flash, clocked) {
            can_service::serve(reason.image_error(), flash);
        }
        #[allow(unreachable_code)]
        loop {
            core::hint::spin_loop();
        }
    }

    /// The fallback's CAN service on the board (module documentation).
    #[cfg(not(feature = "qemu"))]
    mod can_service {
        use cortex_m::peripheral::{DWT, SCB};
        use firmware::board::boot::UpdateFlash;
        use firmware::board::can::BxCan;
        use firmware::board::clock::SYSCLK_HZ;
        use firmware::board::flash::ParamFlash;
        use firmware::boot::fallback::FallbackNode;
        use firmware::boot::image::ImageError;
        use firmware::boot::stored_comms::stored_comms;
        use firmware::canopen::frame::{BitRate, CanBus, CanFrame};

        use super::TRUST;

        /// Core cycles per millisecond at 168 MHz.
        const CYCLES_PER_MS: u32 = SYSCLK_HZ / 1000;
        /// Polls of a full transmit side before a frame is given up (each poll is a register read and a few
        /// instructions: far more than the 8 ms one frame takes at 20 kbit/s, the slowest rate of 0x2001).
        const TX_POLLS: u32 = 2_000_000;

        /// Milliseconds from the DWT cycle counter, which wraps every 25.6 s at 168 MHz: each call adds the
        /// cycles since the previous one (read far more often than every 25 s: the longest step between two
        /// calls is the clear of slot B, three sector erases of at most 2 s each), carrying the remainder.
        struct Millis {
            last: u32,
            ms: u32,
            rest: u32,
        }

        impl Millis {
            fn now(&mut self) -> u32 {
                let cycles = DWT::cycle_count();
                let d = cycles.wrapping_sub(self.last);
                self.last = cycles;
                let rest = self.rest.saturating_add(d % CYCLES_PER_MS);
                let carry = u32::from(rest >= CYCLES_PER_MS);
                self.rest = rest.wrapping_sub(carry.wrapping_mul(CYCLES_PER_MS));
                self.ms = self.ms.wrapping_add(d / CYCLES_PER_MS).wrapping_add(carry);
                self.ms
            }
        }

        /// Sends `frame`, waiting (bounded) while all transmit mailboxes are full.
        fn send(can: &mut BxCan, frame: &CanFrame) {
            for _ in 0..TX_POLLS {
                if can.send(frame).is_ok() {
                    return;
                }
            }
        }

        /// Brings CAN up at the stored node-ID and bit rate (or the device defaults) and serves [`FallbackNode`]
        /// until a reset. Never returns.
        pub(super) fn serve(reason: ImageError, flash: &mut UpdateFlash) -> ! {
            if let Some(mut core) = cortex_m::Peripherals::take() {
                core.DCB.enable_trace();
                core.DWT.enable_cycle_counter();
            }
            let comms = ParamFlash::take().map(|mut params| stored_comms(&mut params)).unwrap_or_default();
            let rate = if BxCan::timing(comms.bit_rate).is_ok() { comms.bit_rate } else { BitRate::default() };
            // Without a transceiver or bus, leaving initialisation times out: try again until a bus is there.
            let mut can = loop {
                if let Ok(can) = BxCan::init(rate) {
                    break can;
                }
            };
            let mut node = FallbackNode::new(comms.node_id, TRUST, reason);
            let mut clock = Millis { last: DWT::cycle_count(), ms: 0, rest: 0 };
            send(&mut can, &node.boot_up());
            loop {
                let now = clock.now();
                if let Some(abort) = node.poll(now) {
                    send(&mut can, &abort);
                }
                let Some(frame) = can.receive() else { continue };
                let reply = node.handle(&frame, flash, now);
                if let Some(answer) = reply.frame {
                    send(&mut can, &answer);
                }
                if reply.reset {
                    // The answer leaves before the reset (bounded: an unacknowledged frame stays pending).
                    for _ in 0..TX_POLLS {
                        if can.tx_idle() {
                            break;
                        }
                    }
                    SCB::sys_reset();
                }
            }
        }
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
        "`bootloader` is a target image: build it with `cargo build --release -p bootloader --target \
         thumbv7em-none-eabihf`"
    );
}
