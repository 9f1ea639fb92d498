//! The bootloader's part of the board (target only, issue 7): the internal flash as the three regions of an
//! update (slot A, slot B, BOOT_STATE of `memory.x`) for `boot::loader::boot`, and the start of the verified
//! application in slot A.
//!
//! # Flash
//! [`UpdateRegion`] is one region made of equal F405 sectors (RM0090 Table 5: sector 4 is 64 KiB, sectors 5-11
//! are 128 KiB). Reads are memory reads of the mapped flash; program and erase use the flash interface
//! sequences of [`super::flash`] (unlock, PSIZE x32, BSY, error flags, lock, cache reset). The same timing rule
//! holds: while a 128 KiB sector erases (1 to 2 s, datasheet) every flash fetch stalls, so these regions are
//! written only by the bootloader (no interrupts enabled, power stage never started) or, later, by the
//! application with its power stage disabled.
//!
//! # Start of the application
//! [`start_application`] reads the first two words of slot A (the application's vector table: initial stack
//! pointer, reset vector), checks that they point into RAM and into the verified payload, points VTOR at slot A
//! (ARMv7-M ARM B3.2.5), loads MSP and branches to the reset handler. The bootloader enables no interrupt and
//! no SysTick, changes no clock (the core stays on the 16 MHz HSI of reset, RM0090 section 6.2.2) and
//! leaves every peripheral as reset left it, so the application starts as from a reset.

use core::sync::atomic::{AtomicBool, Ordering};

use super::flash::{erase_absolute, program_absolute, sector_number};
use crate::boot::image::ImageHeader;
use crate::boot::swap::BootFlash;
use crate::flash_map::{
    BOOT_STATE_LEN, BOOT_STATE_START, CCMRAM_END, CCMRAM_START, FLASH_LEN, RAM_END, RAM_START, SLOT_A_START,
    SLOT_B_LEN, SLOT_B_START,
};
use crate::hal::flash::{FlashError, Geometry, NorFlash};

/// F405 sectors 5..11 (RM0090 Table 5): the sectors of both slots.
const SLOT_SECTOR: u32 = 0x2_0000;
/// Program granularity with PSIZE = x32 (RM0090 section 3.6.2).
const WORD: u32 = 4;

// The regions start on sector boundaries and are made of whole sectors of one size (`memory.x` comment).
const _: () = assert!(sector_number(SLOT_A_START).is_some() && FLASH_LEN.is_multiple_of(SLOT_SECTOR));
const _: () = assert!(sector_number(SLOT_B_START).is_some() && SLOT_B_LEN.is_multiple_of(SLOT_SECTOR));
const _: () = assert!(sector_number(BOOT_STATE_START).is_some() && BOOT_STATE_LEN == 0x1_0000);

/// One update region of the internal flash: `sector_count` F405 sectors of `sector_size` bytes from `start`.
#[derive(Debug)]
pub struct UpdateRegion {
    start: u32,
    geometry: Geometry,
}

/// The three regions as `boot::loader::boot` takes them.
pub type UpdateFlash = BootFlash<UpdateRegion, UpdateRegion, UpdateRegion>;

/// Set once the regions have been handed out.
static TAKEN: AtomicBool = AtomicBool::new(false);

/// Slot A, slot B and BOOT_STATE, the first time; `None` afterwards (one owner of these sectors).
pub fn update_flash() -> Option<UpdateFlash> {
    if TAKEN.compare_exchange(false, true, Ordering::AcqRel, Ordering::Acquire).is_err() {
        return None;
    }
    let region = |start: u32, len: u32, sector_size: u32| UpdateRegion {
        start,
        geometry: Geometry { sector_size, sector_count: len.checked_div(sector_size).unwrap_or(0), write_size: WORD },
    };
    Some(BootFlash {
        slot_a: region(SLOT_A_START, FLASH_LEN, SLOT_SECTOR),
        slot_b: region(SLOT_B_START, SLOT_B_LEN, SLOT_SECTOR),
        state: region(BOOT_STATE_START, BOOT_STATE_LEN, BOOT_STATE_LEN),
    })
}

impl UpdateRegion {
    /// The absolute address of `offset..offset + len`, if the range lies in the region.
    fn address(&self, offset: u32, len: usize) -> Result<u32, FlashError> {
        let len = u32::try_from(len).map_err(|_| FlashError::OutOfBounds)?;
        match offset.checked_add(len) {
            Some(end) if end <= self.geometry.capacity() => {
                self.start.checked_add(offset).ok_or(FlashError::OutOfBounds)
            }
            _ => Err(FlashError::OutOfBounds),
        }
    }

    /// Copies the flash bytes at absolute `address` into `buf`.
    fn copy_out(address: u32, buf: &mut [u8]) {
        // SAFETY: callers pass a range inside this region (checked by `address`), always-mapped readable flash
        // (RM0090 Table 5). Only this driver programs the region, through `&mut self`, so nothing writes it while
        // the slice exists.
        let flash = unsafe { core::slice::from_raw_parts(address as usize as *const u8, buf.len()) };
        buf.copy_from_slice(flash);
    }
}

impl NorFlash for UpdateRegion {
    fn geometry(&self) -> Geometry {
        self.geometry
    }

    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), FlashError> {
        let address = self.address(offset, buf.len())?;
        Self::copy_out(address, buf);
        Ok(())
    }

    fn program(&mut self, offset: u32, data: &[u8]) -> Result<(), FlashError> {
        let address = self.address(offset, data.len())?;
        if !offset.is_multiple_of(WORD) || !data.len().is_multiple_of(WORD as usize) {
            return Err(FlashError::Misaligned);
        }
        // NOR rule first (the F405 would silently AND the bits): nothing is written if a bit would have to rise.
        let mut old = [0u8; WORD as usize];
        let mut at = address;
        for chunk in data.chunks_exact(WORD as usize) {
            Self::copy_out(at, &mut old);
            if old.iter().zip(chunk).any(|(o, n)| o & n != *n) {
                return Err(FlashError::NotErased);
            }
            at = at.wrapping_add(WORD);
        }
        program_absolute(address, data)
    }

    fn erase_sector(&mut self, sector: u32) -> Result<(), FlashError> {
        let offset = self.geometry.sector_start(sector).ok_or(FlashError::OutOfBounds)?;
        erase_absolute(self.start.checked_add(offset).ok_or(FlashError::OutOfBounds)?)
    }
}

/// Why a verified image was not started: its vector table does not describe a runnable image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StartError {
    /// The initial stack pointer (word 0) is not an 8-byte aligned address in RAM or CCM RAM (or its top).
    StackPointer(u32),
    /// The reset vector (word 1) is not a Thumb address inside the image's payload.
    ResetVector(u32),
    /// Slot A could not be read.
    Flash(FlashError),
}

/// Starts the application in slot A, whose image `header` `boot::loader::boot` has just verified (`Outcome::Run`):
/// VTOR = slot A, MSP = word 0 of its vector table, branch to word 1. Returns only if the vector table is not
/// usable ([`StartError`]); the bootloader then stays in its fallback.
pub fn start_application(slot_a: &mut UpdateRegion, header: &ImageHeader) -> StartError {
    let mut words = [0u8; 8];
    if let Err(e) = slot_a.read(0, &mut words) {
        return StartError::Flash(e);
    }
    let [s0, s1, s2, s3, r0, r1, r2, r3] = words;
    let sp = u32::from_le_bytes([s0, s1, s2, s3]);
    let reset = u32::from_le_bytes([r0, r1, r2, r3]);
    // Full descending stack: the initial SP may be the first address after the RAM (cortex-m-rt's default).
    let in_ram = |lo: u32, hi: u32| sp > lo && sp <= hi;
    if !sp.is_multiple_of(8) || !(in_ram(RAM_START, RAM_END) || in_ram(CCMRAM_START, CCMRAM_END)) {
        return StartError::StackPointer(sp);
    }
    let entry = reset & !1;
    let payload_end = slot_a.start.saturating_add(header.payload_len);
    if reset & 1 == 0 || entry < slot_a.start.saturating_add(8) || entry >= payload_end {
        return StartError::ResetVector(reset);
    }
    // SAFETY: the image in slot A passed the header, CRC and Ed25519 check against the compiled-in key, so it is
    // firmware this drive's key holder built for slot A; its first two words were just checked to be a stack
    // top in RAM and a Thumb entry point inside that image. VTOR takes the slot start (0x0802_0000, 128-byte
    // aligned as ARMv7-M B3.2.5 requires for the F405's 98 vectors). `bootstrap` selects MSP, loads it and
    // branches: the bootloader's own stack is abandoned, nothing of it is used again, and no interrupt is
    // enabled that could run bootloader code afterwards.
    unsafe {
        (*cortex_m::peripheral::SCB::PTR).vtor.write(slot_a.start);
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
        cortex_m::asm::bootstrap(sp as usize as *const u32, reset as usize as *const u32)
    }
}
