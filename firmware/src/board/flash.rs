//! The STM32F405's internal flash as the parameter store's [`NorFlash`]: sectors 2 and 3 (PARAMS_A, PARAMS_B of
//! `memory.x`, 16 KiB each), driven through the flash interface registers (RM0090 rev 19, section 3).
//!
//! - Reads are plain memory reads of the mapped flash (RM0090 section 3.5).
//! - Unlock: the key sequence 0x4567_0123, 0xCDEF_89AB written to FLASH_KEYR clears FLASH_CR.LOCK (section
//!   3.5.1); the driver locks FLASH_CR again (LOCK = 1) after every operation, failed ones included.
//! - Program (section 3.6.2): PSIZE = x32 (the parallelism allowed at 2.7..3.6 V, Table 11), PG = 1, one 32-bit
//!   write per word at its address, wait for BSY = 0 after each.
//! - Sector erase (section 3.6.3): SER = 1, SNB = sector number, STRT = 1, wait for BSY = 0.
//! - Errors (section 3.8, FLASH_SR): PGSERR, PGPERR, PGAERR, WRPERR and OPERR are cleared (write 1) before an
//!   operation and checked after it; any of them, a controller that stays locked, or BSY that never clears gives
//!   [`FlashError::Device`]. A program that would have to set a bit from 0 to 1 is refused with
//!   [`FlashError::NotErased`] before anything is written (the F405 would silently AND the bits).
//! - The ART data and instruction caches (FLASH_ACR DCEN/ICEN, enabled in `clock`) may hold the old contents of
//!   the range just written; they are reset after every program and erase (section 3.5.2: DCRST/ICRST with the
//!   caches disabled), so the store's read-back verification sees the flash, not the cache.
//!
//! # Timing and where it may run
//! While the controller programs or erases, every read of the flash stalls the bus (RM0090 section 3.5: single
//! bank), instruction fetches and vector fetches included: a 16 KiB sector erase takes up to 0.5 s at x32
//! (STM32F405 datasheet, flash characteristics), a word program about 16 us. The current loop cannot run meanwhile.
//! So the runtime programs and erases only from tier 3, inside `rt::tier2::with_drive` (tier 2 and every new
//! power-stage request wait; tier 1 stalls with the bus, and its lost-period supervision does not trip while its
//! outputs are off), and only with the power stage disabled: the parameter objects 0x1010/0x1011 are writable only in Pre-Operational with the power stage
//! disabled (device.toml `writable_in`; IDX L1702, Gamma L512) and the drive refuses them itself with 0x0800_0022
//! while its power stage is switched on (`drive::objects`). With the power stage disabled TIM1's MOE is 0, so the
//! gates stay off however long the bus stalls. Boot only reads.

use core::sync::atomic::{AtomicBool, Ordering};

use super::reg::{base, Reg};
use crate::flash_map::{PARAMS_SECTOR_SIZE, PARAMS_SLOTS};
use crate::hal::flash::{FlashError, Geometry, NorFlash};

/// Flash key register.
const KEYR: Reg = Reg::at(base::FLASH, 0x04);
/// Flash status register.
const SR: Reg = Reg::at(base::FLASH, 0x0C);
/// Flash control register.
const CR: Reg = Reg::at(base::FLASH, 0x10);
/// Flash access control register (latency, prefetch, caches).
const ACR: Reg = Reg::at(base::FLASH, 0x00);

/// FLASH_KEYR unlock sequence (RM0090 section 3.5.1).
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;

/// FLASH_SR bits (RM0090 section 3.9.4).
const SR_EOP: u32 = 1 << 0;
const SR_OPERR: u32 = 1 << 1;
const SR_WRPERR: u32 = 1 << 4;
const SR_PGAERR: u32 = 1 << 5;
const SR_PGPERR: u32 = 1 << 6;
const SR_PGSERR: u32 = 1 << 7;
const SR_BSY: u32 = 1 << 16;
const SR_ERRORS: u32 = SR_OPERR | SR_WRPERR | SR_PGAERR | SR_PGPERR | SR_PGSERR;

/// FLASH_CR bits (RM0090 section 3.9.5).
const CR_PG: u32 = 1 << 0;
const CR_SER: u32 = 1 << 1;
const CR_SNB_SHIFT: u32 = 3;
const CR_SNB_MASK: u32 = 0xF << CR_SNB_SHIFT;
const CR_PSIZE_X32: u32 = 0b10 << 8;
const CR_PSIZE_MASK: u32 = 0b11 << 8;
const CR_STRT: u32 = 1 << 16;
const CR_LOCK: u32 = 1 << 31;

/// FLASH_ACR bits (RM0090 section 3.9.1).
const ACR_ICEN: u32 = 1 << 9;
const ACR_DCEN: u32 = 1 << 10;
const ACR_ICRST: u32 = 1 << 11;
const ACR_DCRST: u32 = 1 << 12;

/// Polls of FLASH_SR.BSY before an operation counts as hung: far beyond the 2 s maximum of the largest erase
/// (a poll takes several cycles at 168 MHz).
const BUSY_POLLS: u32 = 1 << 30;

/// Program granularity with PSIZE = x32.
const WORD: u32 = 4;

/// Start of the main flash memory (RM0090 Table 5).
const FLASH_BASE: u32 = 0x0800_0000;

/// The F405 sector holding `address`, if it is the start of one: 4 x 16 KiB, 1 x 64 KiB, then 128 KiB sectors
/// (RM0090 Table 5).
pub(super) const fn sector_number(address: u32) -> Option<u32> {
    let Some(offset) = address.checked_sub(FLASH_BASE) else { return None };
    match offset {
        0x0_0000..=0x0_FFFF if offset % 0x4000 == 0 => Some(offset / 0x4000),
        0x1_0000 => Some(4),
        0x2_0000..=0xF_FFFF if offset % 0x2_0000 == 0 => Some((offset / 0x2_0000).wrapping_add(4)),
        _ => None,
    }
}

/// `n`, or an impossible sector number for `None` (which the assertion below rejects at build time).
const fn or_invalid(n: Option<u32>) -> u32 {
    match n {
        Some(n) => n,
        None => u32::MAX,
    }
}

/// The F405 sector numbers of the store's sectors 0 and 1.
const SECTORS: [u32; 2] = [or_invalid(sector_number(PARAMS_SLOTS[0])), or_invalid(sector_number(PARAMS_SLOTS[1]))];
// memory.x places the parameter store in sectors 2 and 3, the 16 KiB sectors after the bootloader.
const _: () = assert!(SECTORS[0] == 2 && SECTORS[1] == 3 && PARAMS_SECTOR_SIZE == 0x4000);

/// Set once the driver has been handed out.
static TAKEN: AtomicBool = AtomicBool::new(false);

/// The parameter sectors of the internal flash. One instance exists ([`ParamFlash::take`]); it owns FLASH_CR.
#[derive(Debug)]
pub struct ParamFlash {
    _owned: (),
}

impl ParamFlash {
    /// The driver, the first time; `None` afterwards.
    pub fn take() -> Option<Self> {
        match TAKEN.compare_exchange(false, true, Ordering::AcqRel, Ordering::Acquire) {
            Ok(_) => Some(Self { _owned: () }),
            Err(_) => None,
        }
    }

    /// The absolute address of region offset `offset`, and the bytes left in its sector.
    fn locate(offset: u32) -> Option<(u32, u32)> {
        let sector = offset / PARAMS_SECTOR_SIZE;
        let within = offset % PARAMS_SECTOR_SIZE;
        let start = *PARAMS_SLOTS.get(usize::try_from(sector).ok()?)?;
        Some((start.checked_add(within)?, PARAMS_SECTOR_SIZE.saturating_sub(within)))
    }

    /// Checks that `offset..offset + len` lies in the region.
    fn check_range(offset: u32, len: usize) -> Result<(), FlashError> {
        let len = u32::try_from(len).map_err(|_| FlashError::OutOfBounds)?;
        match offset.checked_add(len) {
            Some(end) if end <= PARAMS_SECTOR_SIZE.saturating_mul(2) => Ok(()),
            _ => Err(FlashError::OutOfBounds),
        }
    }

    /// Copies flash bytes at absolute `address` into `buf`.
    fn copy_out(address: u32, buf: &mut [u8]) {
        // SAFETY: callers pass an address range inside PARAMS_A/PARAMS_B (checked against the region above), which
        // is always-mapped, readable flash (RM0090 Table 5). Only this driver writes it, through `&mut self`, so no
        // program or erase runs while the slice exists.
        let flash = unsafe { core::slice::from_raw_parts(address as usize as *const u8, buf.len()) };
        buf.copy_from_slice(flash);
    }

    /// Reads the word at absolute `address` (4-aligned).
    fn word_at(address: u32) -> u32 {
        let mut word = [0u8; 4];
        Self::copy_out(address, &mut word);
        u32::from_le_bytes(word)
    }
}

/// The little-endian word of a 4-byte chunk.
fn word_of(chunk: &[u8]) -> u32 {
    chunk.first_chunk::<4>().map_or(u32::MAX, |b| u32::from_le_bytes(*b))
}

/// Waits for BSY = 0; `false` if it never clears.
fn wait_idle() -> bool {
    let mut polls = 0u32;
    while SR.read() & SR_BSY != 0 {
        if polls >= BUSY_POLLS {
            return false;
        }
        polls = polls.wrapping_add(1);
    }
    true
}

/// Unlocks FLASH_CR for one operation: waits for a previous one, clears stale error flags, writes the keys.
fn unlock() -> Result<(), FlashError> {
    if !wait_idle() {
        return Err(FlashError::Device);
    }
    SR.write(SR_ERRORS | SR_EOP);
    if CR.read() & CR_LOCK != 0 {
        KEYR.write(KEY1);
        KEYR.write(KEY2);
    }
    if CR.read() & CR_LOCK != 0 {
        return Err(FlashError::Device);
    }
    Ok(())
}

/// Ends an operation: PG/SER off, FLASH_CR locked, caches reset; the error flags give the result.
fn finish(completed: bool) -> Result<(), FlashError> {
    let errors = SR.read() & SR_ERRORS;
    SR.write(errors | SR_EOP);
    CR.modify(CR_PG | CR_SER | CR_SNB_MASK, 0);
    CR.modify(0, CR_LOCK);
    reset_caches();
    if completed && errors == 0 {
        Ok(())
    } else {
        Err(FlashError::Device)
    }
}

/// Resets the ART caches, which may hold the old contents of a range just programmed or erased (RM0090
/// section 3.5.2: reset only while disabled).
fn reset_caches() {
    let enabled = ACR.read() & (ACR_ICEN | ACR_DCEN);
    ACR.modify(ACR_ICEN | ACR_DCEN, 0);
    ACR.modify(0, ACR_ICRST | ACR_DCRST);
    ACR.modify(ACR_ICRST | ACR_DCRST, 0);
    ACR.modify(0, enabled);
}

impl NorFlash for ParamFlash {
    fn geometry(&self) -> Geometry {
        Geometry { sector_size: PARAMS_SECTOR_SIZE, sector_count: 2, write_size: WORD }
    }

    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), FlashError> {
        Self::check_range(offset, buf.len())?;
        let mut at = offset;
        let mut rest = buf;
        while !rest.is_empty() {
            let (address, room) = Self::locate(at).ok_or(FlashError::OutOfBounds)?;
            let n = rest.len().min(usize::try_from(room).map_err(|_| FlashError::OutOfBounds)?);
            let (now, later) = rest.split_at_mut(n);
            Self::copy_out(address, now);
            at = at.saturating_add(u32::try_from(n).map_err(|_| FlashError::OutOfBounds)?);
            rest = later;
        }
        Ok(())
    }

    fn program(&mut self, offset: u32, data: &[u8]) -> Result<(), FlashError> {
        Self::check_range(offset, data.len())?;
        if !offset.is_multiple_of(WORD) || !data.len().is_multiple_of(WORD as usize) {
            return Err(FlashError::Misaligned);
        }
        // NOR rule first, over the whole range: nothing is written if any bit would have to rise.
        let mut at = offset;
        for chunk in data.chunks_exact(WORD as usize) {
            let (address, _) = Self::locate(at).ok_or(FlashError::OutOfBounds)?;
            let new = word_of(chunk);
            if Self::word_at(address) & new != new {
                return Err(FlashError::NotErased);
            }
            at = at.saturating_add(WORD);
        }
        unlock()?;
        CR.modify(CR_PSIZE_MASK | CR_SER | CR_SNB_MASK, CR_PSIZE_X32 | CR_PG);
        let mut at = offset;
        let mut completed = true;
        for chunk in data.chunks_exact(WORD as usize) {
            let Some((address, _)) = Self::locate(at) else {
                completed = false;
                break;
            };
            // With PG set, a 32-bit write to a flash address programs it (RM0090 section 3.6.2).
            // SAFETY: `address` is a word-aligned address inside PARAMS_A/PARAMS_B (range and alignment checked
            // above), mapped flash that no Rust reference points into (reads copy out through short-lived slices
            // under `&mut self`); the write only starts the controller's programming of that word.
            unsafe { core::ptr::write_volatile(address as usize as *mut u32, word_of(chunk)) };
            if !wait_idle() || SR.read() & SR_ERRORS != 0 {
                completed = false;
                break;
            }
            at = at.saturating_add(WORD);
        }
        finish(completed)
    }

    fn erase_sector(&mut self, sector: u32) -> Result<(), FlashError> {
        let number = *SECTORS
            .get(usize::try_from(sector).map_err(|_| FlashError::OutOfBounds)?)
            .ok_or(FlashError::OutOfBounds)?;
        unlock()?;
        CR.modify(CR_PSIZE_MASK | CR_PG | CR_SNB_MASK, CR_PSIZE_X32 | CR_SER | (number << CR_SNB_SHIFT));
        CR.modify(0, CR_STRT);
        let completed = wait_idle();
        finish(completed)
    }
}

/// Programs `data` (whole words) at the absolute flash `address` (word-aligned): the same sequence as
/// [`ParamFlash`]'s program, for the update regions of `board::boot`. The caller owns the range and has checked
/// it, its alignment and the NOR rule (no bit rises); nothing here reads the range.
pub(super) fn program_absolute(address: u32, data: &[u8]) -> Result<(), FlashError> {
    if !address.is_multiple_of(WORD) || !data.len().is_multiple_of(WORD as usize) {
        return Err(FlashError::Misaligned);
    }
    unlock()?;
    CR.modify(CR_PSIZE_MASK | CR_SER | CR_SNB_MASK, CR_PSIZE_X32 | CR_PG);
    let mut at = address;
    let mut completed = true;
    for chunk in data.chunks_exact(WORD as usize) {
        // SAFETY: `at` is a word-aligned flash address inside a region the caller owns (`board::boot` checks the
        // range against its region), mapped flash no Rust reference points into; with PG set the write only
        // starts the controller's programming of that word (RM0090 section 3.6.2).
        unsafe { core::ptr::write_volatile(at as usize as *mut u32, word_of(chunk)) };
        if !wait_idle() || SR.read() & SR_ERRORS != 0 {
            completed = false;
            break;
        }
        at = at.wrapping_add(WORD);
    }
    finish(completed)
}

/// Erases the F405 sector that starts at the absolute `address` (RM0090 section 3.6.3); an address that is not
/// the start of a sector is refused with [`FlashError::OutOfBounds`].
pub(super) fn erase_absolute(address: u32) -> Result<(), FlashError> {
    let number = sector_number(address).ok_or(FlashError::OutOfBounds)?;
    unlock()?;
    // The erase stalls every tier for up to 2 s (128 KiB): it gets the watchdog's whole timeout to itself
    // (`board::watchdog`; a write without effect while the watchdog is not running, as in the bootloader).
    super::watchdog::feed();
    CR.modify(CR_PSIZE_MASK | CR_PG | CR_SNB_MASK, CR_PSIZE_X32 | CR_SER | (number << CR_SNB_SHIFT));
    CR.modify(0, CR_STRT);
    let completed = wait_idle();
    finish(completed)
}
