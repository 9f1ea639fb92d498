//! The application's side of an update: receive an image into slot B, verify it, mark it for activation at
//! the next reset, and confirm the running image after a successful start.
//!
//! The sequence follows program control (IDX L3343-3381, L3350-3352): *clear* (0x1F51 = 3) erases the image
//! area of slot B, the download (0x1F50:01 segments, or FoE data packets) writes it chunk by chunk at
//! increasing offsets, *finish* verifies header, CRC and signature in flash, and *activate* (0x1F51 = 1
//! "start program" / FoE end of file) records the image as pending; the bootloader swaps it in at the next
//! reset ([`super::loader`]). A download outside that sequence is refused with [`UpdateError::Sequence`]
//! (0x1F57 code 66 "authentication sequence error"). Wiring to 0x1F5x and FoE is the next phase.
//!
//! While an image runs on trial, slot B holds the previous image, the only way back: a new download is refused
//! ([`UpdateError::NotConfirmed`]) until the running image has confirmed itself.
//!
//! Anti-rollback ([`super::state`], "The minimum security version"): *clear* takes the minimum accepted security
//! version in force, the header of the download is checked against it as soon as it is complete, the verified
//! image again, and *activate* writes the minimum into the log before the Pending record; *confirm* raises it to
//! the confirmed image's security version. An image below it is refused with [`ImageError::Rollback`].

use super::image::{ImageError, ImageHeader, HEADER_LEN, HEADER_OFFSET, IMAGE_AREA_LEN, MAX_IMAGE_LEN};
use super::state::{self, BootState, Record, RecordKind, StateError};
use super::verify::{verify_in_flash, Trust};
use crate::hal::flash::{FlashError, NorFlash};

/// Bytes gathered before one program of slot B (a multiple of the write size and of [`HEADER_LEN`]'s
/// alignment). 256 bytes: 37 segments of a segmented SDO, under half a 1 KiB-mailbox FoE packet.
pub const STAGE_LEN: usize = 256;

/// Why an update step was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateError {
    /// The step is out of the clear -> download -> finish -> activate sequence (0x1F57 code 66).
    Sequence,
    /// An image runs on trial: slot B holds the only fallback and may not be overwritten yet.
    NotConfirmed,
    /// Data arrived at another offset than the next expected one.
    OutOfOrder {
        /// The offset expected.
        expected: u32,
    },
    /// The image was refused.
    Image(ImageError),
    /// Slot B or the state flash failed.
    Flash(FlashError),
    /// The state log is full and may not be erased now.
    StateFull,
}

impl From<FlashError> for UpdateError {
    fn from(e: FlashError) -> Self {
        Self::Flash(e)
    }
}

impl From<StateError> for UpdateError {
    fn from(e: StateError) -> Self {
        match e {
            StateError::Flash(f) => Self::Flash(f),
            StateError::Full => Self::StateFull,
        }
    }
}

/// Where a download stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// No download; `clear` first.
    Idle,
    /// Slot B is erased; the download may start at offset 0.
    Cleared,
    /// Receiving; `received` bytes so far.
    Receiving,
    /// The image in slot B is complete and verified.
    Verified(ImageHeader),
    /// The download failed with this error; `clear` to start again.
    Failed(ImageError),
    /// The image is pending: it becomes active at the next reset.
    Activated(ImageHeader),
}

/// A download into slot B.
#[derive(Clone, Debug)]
pub struct Download {
    phase: Phase,
    received: u32,
    expected: Option<u32>,
    stage: [u8; STAGE_LEN],
    stage_len: usize,
    stage_start: u32,
    /// The minimum accepted security version, fixed by `clear`.
    minimum: u32,
}

impl Default for Download {
    fn default() -> Self {
        Self::new()
    }
}

impl Download {
    /// No download in progress.
    pub const fn new() -> Self {
        Self {
            phase: Phase::Idle,
            received: 0,
            expected: None,
            stage: [0xFF; STAGE_LEN],
            stage_len: 0,
            stage_start: 0,
            minimum: 0,
        }
    }

    /// Where the download stands.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Bytes received so far.
    pub fn received(&self) -> u32 {
        self.received
    }

    /// The minimum accepted security version this download is checked against (set by `clear`).
    pub fn minimum_security_version(&self) -> u32 {
        self.minimum
    }

    /// *Clear program*: withdraws a pending image and erases the image area of slot B (the scratch sector is
    /// left alone: the bootloader erases it before use). `slot_a_version` is the security version of the
    /// confirmed image in slot A (`None` without a valid one, in the bootloader's fallback): with the log it makes
    /// the minimum the download is checked against ([`state::minimum_security_version`]).
    pub fn clear<B: NorFlash, S: NorFlash>(
        &mut self,
        slot_b: &mut B,
        state_flash: &mut S,
        slot_a_version: Option<u32>,
    ) -> Result<(), UpdateError> {
        *self = Self::new();
        let scan = state::scan(state_flash)?;
        self.minimum = state::minimum_security_version(&scan, slot_a_version);
        match scan.state {
            BootState::Idle => {}
            BootState::Pending { image_crc } => {
                state::append(state_flash, Record::new(RecordKind::Cancelled, image_crc))?;
            }
            BootState::Trial { .. } | BootState::Swapping { .. } => return Err(UpdateError::NotConfirmed),
        }
        let g = slot_b.geometry();
        let mut sector = 0u32;
        while g.sector_start(sector).is_some_and(|start| start < IMAGE_AREA_LEN) {
            slot_b.erase_sector(sector)?;
            sector = sector.saturating_add(1);
        }
        self.phase = Phase::Cleared;
        Ok(())
    }

    /// Abandons the download (SDO abort, FoE error); `clear` is needed before the next one.
    pub fn abort(&mut self) {
        *self = Self::new();
    }

    /// The next `data` of the image at `offset` (offsets increase without gaps, as 0x1F50 segments and FoE
    /// packets arrive). The header is checked as soon as it is complete, so a wrong image is refused early.
    pub fn write<B: NorFlash>(
        &mut self,
        slot_b: &mut B,
        offset: u32,
        data: &[u8],
        trust: &Trust,
    ) -> Result<(), UpdateError> {
        match self.phase {
            Phase::Cleared if offset == 0 => self.phase = Phase::Receiving,
            Phase::Receiving => {}
            Phase::Cleared => return Err(UpdateError::OutOfOrder { expected: 0 }),
            _ => return Err(UpdateError::Sequence),
        }
        if offset != self.received {
            return Err(UpdateError::OutOfOrder { expected: self.received });
        }
        let r = self.write_inner(slot_b, data, trust);
        if let Err(UpdateError::Image(e)) = r {
            self.phase = Phase::Failed(e);
        }
        r
    }

    fn write_inner<B: NorFlash>(&mut self, slot_b: &mut B, data: &[u8], trust: &Trust) -> Result<(), UpdateError> {
        let len = u32::try_from(data.len()).unwrap_or(u32::MAX);
        let total = self.received.saturating_add(len);
        match self.expected {
            Some(expected) if total > expected => return Err(UpdateError::Image(ImageError::TrailingData)),
            _ if total > MAX_IMAGE_LEN || total.saturating_sub(HEADER_LEN) > trust.max_payload => {
                return Err(UpdateError::Image(ImageError::Oversized {
                    len: total.saturating_sub(HEADER_LEN),
                    max: trust.max_payload,
                }));
            }
            _ => {}
        }
        let mut rest = data;
        while !rest.is_empty() {
            let to_header =
                if self.received < HEADER_LEN { HEADER_LEN.saturating_sub(self.received) } else { u32::MAX };
            let room = STAGE_LEN.saturating_sub(self.stage_len);
            let n = rest.len().min(room).min(to_header as usize);
            let (now, later) = rest.split_at_checked(n).ok_or(UpdateError::Sequence)?;
            let end = self.stage_len.saturating_add(n);
            self.stage.get_mut(self.stage_len..end).ok_or(UpdateError::Sequence)?.copy_from_slice(now);
            self.stage_len = end;
            self.received = self.received.saturating_add(n as u32);
            rest = later;
            if self.received == HEADER_LEN && self.expected.is_none() {
                let header = ImageHeader::parse(&self.stage).map_err(UpdateError::Image)?;
                header.check(trust.hardware_id, trust.max_payload).map_err(UpdateError::Image)?;
                header.check_security_version(self.minimum).map_err(UpdateError::Image)?;
                self.expected = Some(header.image_len());
                self.flush(slot_b)?;
            } else if self.stage_len == STAGE_LEN {
                self.flush(slot_b)?;
            }
        }
        Ok(())
    }

    /// Programs the staged bytes (padded with 0xFF to the write size) where they belong in slot B: header bytes
    /// at [`HEADER_OFFSET`], payload bytes from offset 0.
    fn flush<B: NorFlash>(&mut self, slot_b: &mut B) -> Result<(), UpdateError> {
        if self.stage_len == 0 {
            return Ok(());
        }
        let ws = slot_b.geometry().write_size.max(1) as usize;
        let padded = self.stage_len.div_ceil(ws).saturating_mul(ws).min(STAGE_LEN);
        if let Some(pad) = self.stage.get_mut(self.stage_len..padded) {
            pad.fill(0xFF);
        }
        let at = if self.stage_start < HEADER_LEN {
            HEADER_OFFSET.saturating_add(self.stage_start)
        } else {
            self.stage_start.saturating_sub(HEADER_LEN)
        };
        slot_b.program(at, self.stage.get(..padded).ok_or(UpdateError::Sequence)?)?;
        self.stage_start = self.stage_start.saturating_add(self.stage_len as u32);
        self.stage_len = 0;
        self.stage.fill(0xFF);
        Ok(())
    }

    /// The last data arrived: writes what is staged and verifies the whole image in slot B.
    pub fn finish<B: NorFlash>(
        &mut self,
        slot_b: &mut B,
        trust: &Trust,
        buf: &mut [u8],
    ) -> Result<ImageHeader, UpdateError> {
        if self.phase != Phase::Receiving {
            return Err(UpdateError::Sequence);
        }
        self.flush(slot_b)?;
        let result = match self.expected {
            Some(expected) if expected == self.received => verify_in_flash(slot_b, HEADER_OFFSET, trust, buf)
                .and_then(|h| h.check_security_version(self.minimum).map(|()| h)),
            _ => Err(ImageError::Truncated),
        };
        match result {
            Ok(header) => {
                self.phase = Phase::Verified(header);
                Ok(header)
            }
            Err(ImageError::Flash(e)) => Err(UpdateError::Flash(e)),
            Err(e) => {
                self.phase = Phase::Failed(e);
                Err(UpdateError::Image(e))
            }
        }
    }

    /// *Start program*: records the verified image as pending; the bootloader activates it at the next reset.
    /// The minimum security version goes into the log first (a compaction may just have erased it, and the
    /// bootloader checks the pending image against the log alone: `state` module documentation).
    pub fn activate<S: NorFlash>(&mut self, state_flash: &mut S) -> Result<(), UpdateError> {
        let Phase::Verified(header) = self.phase else {
            return Err(UpdateError::Sequence);
        };
        let scan = state::ensure_room(state_flash)?;
        if scan.state != BootState::Idle {
            return Err(UpdateError::NotConfirmed);
        }
        let minimum = self.minimum.max(scan.floor);
        if let Err(e) = header.check_security_version(minimum) {
            self.phase = Phase::Failed(e);
            return Err(UpdateError::Image(e));
        }
        if scan.floor < minimum {
            state::append(state_flash, Record::floor(minimum))?;
        }
        state::append(state_flash, Record::new(RecordKind::Pending, header.payload_crc))?;
        self.phase = Phase::Activated(header);
        Ok(())
    }
}

/// Called by a new image after a successful start: ends its trial, so it is no longer reverted at a reset
/// (and the previous image in slot B is no longer a way back), and raises the minimum accepted security version
/// to the image's `security_version`: `Confirmed` first, then `Floor` (why this order: `state` module
/// documentation). Returns `true` if a trial ended, `false` if the image was confirmed already.
pub fn confirm<S: NorFlash>(state_flash: &mut S, security_version: u32) -> Result<bool, UpdateError> {
    let scan = state::scan(state_flash)?;
    match scan.state {
        BootState::Trial { image_crc } => {
            state::append(state_flash, Record::new(RecordKind::Confirmed, image_crc))?;
            if security_version > scan.floor {
                state::append(state_flash, Record::floor(security_version))?;
            }
            Ok(true)
        }
        BootState::Idle | BootState::Pending { .. } => Ok(false),
        BootState::Swapping { .. } => Err(UpdateError::Sequence),
    }
}
