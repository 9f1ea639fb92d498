//! The sector swap between slot A and slot B through the scratch sector (the last sector of slot B, which is
//! one 128 KiB sector larger than slot A for this purpose, `memory.x`).
//!
//! For every sector i of slot A, three steps, each followed by a state record (`state::Phase`):
//! 1. erase S, copy `A[i]` to S -> `Saved`
//! 2. erase `A[i]`, copy `B[i]` to `A[i]` -> `Installed`
//! 3. erase `B[i]`, copy S to `B[i]` -> `Done`
//!
//! Each step only writes a sector whose contents are also held elsewhere (`A[i]` in S after step 1, the old
//! S contents are not needed after step 3) and reads only sectors it does not write, so a step interrupted by
//! a power cut is simply run again from the last record: the swap resumes, whatever the tear. The same swap
//! run again exchanges the slots back (the revert). Chunks that read all 0xFF are not programmed (an erased
//! sector already holds them), which keeps the write count of a small image low.

use super::state::{self, Direction, Phase, Record, StateError};
use crate::hal::flash::{FlashError, NorFlash};

/// The three flash regions of an update: slot A (running image), slot B (download target and old image;
/// one sector more than slot A, the last one is the scratch sector) and BOOT_STATE.
#[derive(Debug)]
pub struct BootFlash<A, B, S> {
    /// Slot A (`memory.x` FLASH, sectors 5-7).
    pub slot_a: A,
    /// Slot B (`memory.x` SLOT_B, sectors 8-11).
    pub slot_b: B,
    /// BOOT_STATE (sector 4).
    pub state: S,
}

/// Why the bootloader or the updater could not go on (the image checks have their own error).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BootError {
    /// A flash operation failed (on the target: the supply is failing; the next boot resumes).
    Flash(FlashError),
    /// The state log has no free slot although a swap is in progress (more torn records than `RESERVE`).
    StateFull,
    /// The regions do not have the layout of `memory.x` (slot B one sector larger than A, equal sectors).
    Geometry,
}

impl From<FlashError> for BootError {
    fn from(e: FlashError) -> Self {
        Self::Flash(e)
    }
}

impl From<StateError> for BootError {
    fn from(e: StateError) -> Self {
        match e {
            StateError::Flash(f) => Self::Flash(f),
            StateError::Full => Self::StateFull,
        }
    }
}

impl<A: NorFlash, B: NorFlash, S: NorFlash> BootFlash<A, B, S> {
    /// Number of sectors in slot A; checks the geometry.
    pub fn slot_sectors(&self) -> Result<u32, BootError> {
        let a = self.slot_a.geometry();
        let b = self.slot_b.geometry();
        if a.sector_size != b.sector_size || b.sector_count != a.sector_count.saturating_add(1) || a.sector_count == 0 {
            return Err(BootError::Geometry);
        }
        Ok(a.sector_count)
    }

    /// Runs (or resumes after `resume`, the last finished step) the swap in `direction`.
    pub fn swap(
        &mut self,
        direction: Direction,
        image_crc: u32,
        resume: Option<(u8, Phase)>,
        buf: &mut [u8],
    ) -> Result<(), BootError> {
        let n = self.slot_sectors()?;
        let scratch = n;
        let (mut sector, mut done_phase) = match resume {
            None => (0u32, None),
            Some((s, Phase::Done)) => (u32::from(s).saturating_add(1), None),
            Some((s, p)) => (u32::from(s), Some(p)),
        };
        let size = self.slot_a.geometry().sector_size;
        while sector < n {
            let at = sector.saturating_mul(size);
            let tag = u8::try_from(sector).map_err(|_| BootError::Geometry)?;
            if done_phase.is_none() {
                self.slot_b.erase_sector(scratch)?;
                copy_between(&mut self.slot_a, at, &mut self.slot_b, scratch.saturating_mul(size), size, buf)?;
                state::append(&mut self.state, Record::step(direction, tag, Phase::Saved, image_crc))?;
            }
            if done_phase.is_none_or(|p| p < Phase::Installed) {
                self.slot_a.erase_sector(sector)?;
                copy_between(&mut self.slot_b, at, &mut self.slot_a, at, size, buf)?;
                state::append(&mut self.state, Record::step(direction, tag, Phase::Installed, image_crc))?;
            }
            self.slot_b.erase_sector(sector)?;
            copy_within(&mut self.slot_b, scratch.saturating_mul(size), at, size, buf)?;
            state::append(&mut self.state, Record::step(direction, tag, Phase::Done, image_crc))?;
            sector = sector.saturating_add(1);
            done_phase = None;
        }
        Ok(())
    }
}

/// The usable part of `buf`: a whole number of write units.
fn chunk_len(buf: &[u8], write_size: u32) -> Result<usize, FlashError> {
    let ws = write_size.max(1) as usize;
    let n = buf.len().checked_div(ws).unwrap_or(0).saturating_mul(ws);
    if n == 0 {
        return Err(FlashError::Misaligned);
    }
    Ok(n)
}

fn copy_between<F: NorFlash, G: NorFlash>(
    src: &mut F,
    from: u32,
    dst: &mut G,
    to: u32,
    len: u32,
    buf: &mut [u8],
) -> Result<(), FlashError> {
    let n = chunk_len(buf, dst.geometry().write_size)?;
    let mut done = 0u32;
    while done < len {
        let k = n.min(len.saturating_sub(done) as usize);
        let chunk = buf.get_mut(..k).ok_or(FlashError::OutOfBounds)?;
        src.read(from.saturating_add(done), chunk)?;
        if chunk.iter().any(|b| *b != 0xFF) {
            dst.program(to.saturating_add(done), chunk)?;
        }
        done = done.saturating_add(k as u32);
    }
    Ok(())
}

fn copy_within<F: NorFlash>(f: &mut F, from: u32, to: u32, len: u32, buf: &mut [u8]) -> Result<(), FlashError> {
    let n = chunk_len(buf, f.geometry().write_size)?;
    let mut done = 0u32;
    while done < len {
        let k = n.min(len.saturating_sub(done) as usize);
        let chunk = buf.get_mut(..k).ok_or(FlashError::OutOfBounds)?;
        f.read(from.saturating_add(done), chunk)?;
        if chunk.iter().any(|b| *b != 0xFF) {
            f.program(to.saturating_add(done), chunk)?;
        }
        done = done.saturating_add(k as u32);
    }
    Ok(())
}
