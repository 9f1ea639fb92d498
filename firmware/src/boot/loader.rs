//! What the bootloader does at every reset, as pure logic over the flash regions: read the state log, verify,
//! perform or resume a swap, revert an image that did not confirm itself, and say which image to start.
//!
//! | state at reset | action |
//! |---|---|
//! | Idle | verify slot A, run it |
//! | Pending | verify slot B and its security version against the log's minimum; valid: activation swap, verify A, record Trial, run A on trial; invalid or older: record Rejected, run A |
//! | Swapping (activate) | resume the swap, then as after an activation |
//! | Trial (did not confirm) | verify slot B (the previous image); valid: revert swap, record Reverted, run A; invalid: record Confirmed (no fallback exists), run A |
//! | Swapping (revert) | resume the swap, record Reverted, run A |
//!
//! The security-version check at Pending repeats the application's (`update::Download`) as a defence in depth: a
//! Pending record written by anything but a download that passed it does not activate an older image. It uses the
//! log's minimum alone, which the activation wrote before the Pending record (`state` module documentation).
//!
//! After an activation, an image in slot A that fails verification (a flash fault while copying) is reverted
//! at once. If slot A holds no valid image at the end, the outcome is [`Outcome::NoValidImage`]: the bootloader
//! stays active and waits for a new image on the fieldbus (IDX L3345-3350: 0x1F51 reads 3 "no program").

use super::image::{ImageError, ImageHeader, HEADER_LEN, HEADER_OFFSET};
use super::state::{self, BootState, Direction, Record, RecordKind};
use super::swap::{BootError, BootFlash};
use super::verify::{verify_in_flash, Trust};
use crate::hal::flash::NorFlash;

/// What happened to the images during this boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BootEvent {
    /// Nothing: the confirmed image starts.
    Normal,
    /// A pending image was activated and starts on trial.
    Activated,
    /// An image that did not confirm itself was swapped back out; the previous image starts.
    Reverted,
    /// The pending image failed verification and was not activated; the running image starts.
    Rejected(ImageError),
    /// The image on trial did not confirm itself, but there is no valid previous image to go back to: it is
    /// kept (and counts as confirmed) rather than leaving the drive without firmware.
    KeptWithoutFallback,
}

/// The bootloader's decision.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Start the verified image in slot A.
    Run {
        /// Its header.
        header: ImageHeader,
        /// `true`: the image must confirm itself (`update::confirm`) or it is reverted at the next reset.
        trial: bool,
        /// What happened during this boot.
        event: BootEvent,
    },
    /// Slot A holds no valid image: stay in the bootloader.
    NoValidImage(ImageError),
}

/// The reset procedure. `buf` is the copy and verification buffer (a multiple of the write size; 1-4 KiB).
/// A [`BootError::Flash`] means the supply failed midway: the next boot resumes where this one stopped.
pub fn boot<A: NorFlash, B: NorFlash, S: NorFlash>(
    flash: &mut BootFlash<A, B, S>,
    trust: &Trust,
    buf: &mut [u8],
) -> Result<Outcome, BootError> {
    flash.slot_sectors()?;
    let scan = state::scan(&mut flash.state)?;
    match scan.state {
        BootState::Idle => run_a(flash, trust, buf, false, BootEvent::Normal),
        BootState::Pending { image_crc } => match verify_in_flash(&mut flash.slot_b, HEADER_OFFSET, trust, buf)
            .and_then(|h| h.check_security_version(scan.floor))
        {
            Ok(()) => {
                flash.swap(Direction::Activate, image_crc, None, buf)?;
                after_activation(flash, trust, buf, image_crc)
            }
            Err(ImageError::Flash(e)) => Err(BootError::Flash(e)),
            Err(e) => {
                state::append(&mut flash.state, Record::new(RecordKind::Rejected, image_crc))?;
                run_a(flash, trust, buf, false, BootEvent::Rejected(e))
            }
        },
        BootState::Swapping { direction, sector, phase, image_crc } => {
            flash.swap(direction, image_crc, Some((sector, phase)), buf)?;
            match direction {
                Direction::Activate => after_activation(flash, trust, buf, image_crc),
                Direction::Revert => after_revert(flash, trust, buf, image_crc),
            }
        }
        BootState::Trial { image_crc } => revert(flash, trust, buf, image_crc),
    }
}

fn after_activation<A: NorFlash, B: NorFlash, S: NorFlash>(
    flash: &mut BootFlash<A, B, S>,
    trust: &Trust,
    buf: &mut [u8],
    image_crc: u32,
) -> Result<Outcome, BootError> {
    match verify_in_flash(&mut flash.slot_a, HEADER_OFFSET, trust, buf) {
        Ok(header) => {
            state::append(&mut flash.state, Record::new(RecordKind::Trial, image_crc))?;
            Ok(Outcome::Run { header, trial: true, event: BootEvent::Activated })
        }
        Err(ImageError::Flash(e)) => Err(BootError::Flash(e)),
        Err(_) => revert(flash, trust, buf, image_crc),
    }
}

fn revert<A: NorFlash, B: NorFlash, S: NorFlash>(
    flash: &mut BootFlash<A, B, S>,
    trust: &Trust,
    buf: &mut [u8],
    image_crc: u32,
) -> Result<Outcome, BootError> {
    match verify_in_flash(&mut flash.slot_b, HEADER_OFFSET, trust, buf) {
        Ok(_) => {}
        Err(ImageError::Flash(e)) => return Err(BootError::Flash(e)),
        Err(_) => {
            state::append(&mut flash.state, Record::new(RecordKind::Confirmed, image_crc))?;
            return run_a(flash, trust, buf, false, BootEvent::KeptWithoutFallback);
        }
    }
    flash.swap(Direction::Revert, image_crc, None, buf)?;
    after_revert(flash, trust, buf, image_crc)
}

fn after_revert<A: NorFlash, B: NorFlash, S: NorFlash>(
    flash: &mut BootFlash<A, B, S>,
    trust: &Trust,
    buf: &mut [u8],
    image_crc: u32,
) -> Result<Outcome, BootError> {
    state::append(&mut flash.state, Record::new(RecordKind::Reverted, image_crc))?;
    run_a(flash, trust, buf, false, BootEvent::Reverted)
}

fn run_a<A: NorFlash, B: NorFlash, S: NorFlash>(
    flash: &mut BootFlash<A, B, S>,
    trust: &Trust,
    buf: &mut [u8],
    trial: bool,
    event: BootEvent,
) -> Result<Outcome, BootError> {
    match verify_in_flash(&mut flash.slot_a, HEADER_OFFSET, trust, buf) {
        Ok(header) => Ok(Outcome::Run { header, trial, event }),
        Err(ImageError::Flash(e)) => Err(BootError::Flash(e)),
        Err(e) => Ok(Outcome::NoValidImage(e)),
    }
}

/// The bootloader's decision as the started application finds it, without verifying again (the bootloader did,
/// a moment ago, or the application would not run): the header of the image in slot A, checked against `trust`
/// (structure, hardware id, slot size), and whether the state log says it runs on trial. The platform hands this
/// to program control ([`super::program::ProgramControl::started`]) at start-up, so that 0x1F56, 0x100A and the
/// confirmation ([`super::update::confirm`]) refer to the image that runs. The event is
/// [`BootEvent::Normal`]: what the bootloader did during the reset is in the state log, not known here.
pub fn running_image<A: NorFlash, S: NorFlash>(slot_a: &mut A, state_flash: &mut S, trust: &Trust) -> Outcome {
    let mut bytes = [0u8; HEADER_LEN as usize];
    let header = slot_a
        .read(HEADER_OFFSET, &mut bytes)
        .map_err(ImageError::Flash)
        .and_then(|()| ImageHeader::parse(&bytes))
        .and_then(|h| h.check(trust.hardware_id, trust.max_payload).map(|()| h));
    match header {
        Ok(header) => {
            let trial = matches!(state::scan(state_flash).map(|s| s.state), Ok(BootState::Trial { .. }));
            Outcome::Run { header, trial, event: BootEvent::Normal }
        }
        Err(e) => Outcome::NoValidImage(e),
    }
}
