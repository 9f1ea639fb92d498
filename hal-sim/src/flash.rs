//! Simulated NOR flash with wear counts and power cuts, implementing `firmware::hal::flash::NorFlash`.
//!
//! What it models (RM0090 section 3.5 for the F405):
//! * Sector geometry, a program granularity (offset and length multiples of `write_size`), erased = 0xFF.
//! * NOR AND-semantics: programming can only clear bits; a program that would set a 0 bit back to 1 fails with
//!   `NotErased` and changes nothing.
//! * Per-sector erase counts (wear, including erases torn by a cut) and counters of writes (program and erase
//!   operations that reached the array, including the torn one; rejected calls are not counted) and of reads.
//! * Power cuts: [`SimFlash::cut_power_at_write`] makes the `k`-th write from now (0-based) the one during which
//!   the supply fails. That write is torn in a way chosen deterministically from the seed: not performed at all;
//!   performed on a random subset of bits (a program clears only some of the bits it should, an erase sets only
//!   some bits); or performed completely but reported as failed. From then on every operation fails with
//!   `PowerLoss` until [`SimFlash::power_on`].
//!
//! Everything is deterministic: the same operations with the same seeds give the same contents.

use firmware::flash_map::PARAMS_SECTOR_SIZE;
use firmware::hal::flash::{FlashError, Geometry, NorFlash};

/// How a cut write was torn (recorded for tests and diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tear {
    /// The write did not change the flash.
    None,
    /// Part of the bits changed.
    Partial,
    /// The write completed, but the supply failed before it was acknowledged.
    Complete,
}

/// A small deterministic generator (SplitMix64).
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator from `seed`.
    pub const fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// The next random byte.
    pub fn next_u8(&mut self) -> u8 {
        self.next_u64().to_le_bytes()[0]
    }
}

/// A pending power cut.
#[derive(Clone, Copy, Debug)]
struct Cut {
    /// Value of the write counter at which the cut write happens.
    at_write: u64,
    seed: u64,
}

/// A simulated NOR flash region.
#[derive(Clone, Debug)]
pub struct SimFlash {
    geometry: Geometry,
    data: Vec<u8>,
    erase_counts: Vec<u32>,
    writes: u64,
    reads: u64,
    powered: bool,
    cut: Option<Cut>,
    last_tear: Option<Tear>,
}

impl SimFlash {
    /// An erased flash of `sector_count` sectors of `sector_size` bytes, programmed in units of `write_size`.
    ///
    /// # Panics
    /// If the geometry is degenerate (zero sizes, or a sector size that is not a multiple of the write size).
    pub fn new(sector_size: u32, sector_count: u32, write_size: u32) -> Self {
        assert!(sector_size > 0 && sector_count > 0 && write_size > 0, "degenerate flash geometry");
        assert!(sector_size.is_multiple_of(write_size), "sector size must be a multiple of the write size");
        let geometry = Geometry { sector_size, sector_count, write_size };
        Self {
            geometry,
            data: vec![0xFF; geometry.capacity() as usize],
            erase_counts: vec![0; sector_count as usize],
            writes: 0,
            reads: 0,
            powered: true,
            cut: None,
            last_tear: None,
        }
    }

    /// The parameter-store region of the reference MCU: PARAMS_A and PARAMS_B of `memory.x`, programmed by word.
    pub fn params() -> Self {
        Self::new(PARAMS_SECTOR_SIZE, 2, 4)
    }

    /// The whole contents (for inspection).
    pub fn contents(&self) -> &[u8] {
        &self.data
    }

    /// The whole contents, writable without NOR rules (to inject corruption or bit rot).
    pub fn contents_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }

    /// Fills the whole region with bytes from `seed` (garbage, as after a foreign firmware or bit rot).
    pub fn fill_random(&mut self, seed: u64) {
        let mut rng = SplitMix64::new(seed);
        for b in &mut self.data {
            *b = rng.next_u8();
        }
    }

    /// How often each sector has been erased (including erases torn by a power cut).
    pub fn erase_counts(&self) -> &[u32] {
        &self.erase_counts
    }

    /// Writes (programs and erases) that reached the array so far, including a torn one.
    pub fn write_count(&self) -> u64 {
        self.writes
    }

    /// Reads performed so far.
    pub fn read_count(&self) -> u64 {
        self.reads
    }

    /// Schedules a power cut during the `k`-th write from now (0-based): `k` writes complete, the next one is
    /// torn as chosen by `seed`, and everything after fails until [`SimFlash::power_on`].
    pub fn cut_power_at_write(&mut self, k: u64, seed: u64) {
        self.cut = Some(Cut { at_write: self.writes.saturating_add(k), seed });
    }

    /// Cuts the power now: every operation fails until [`SimFlash::power_on`].
    pub fn power_off(&mut self) {
        self.powered = false;
        self.cut = None;
    }

    /// Restores the supply (a reboot); cancels a pending cut.
    pub fn power_on(&mut self) {
        self.powered = true;
        self.cut = None;
    }

    /// Whether the supply is on.
    pub fn is_powered(&self) -> bool {
        self.powered
    }

    /// How the last cut write was torn, if a cut has happened.
    pub fn last_tear(&self) -> Option<Tear> {
        self.last_tear
    }

    fn range(&self, offset: u32, len: usize) -> Result<std::ops::Range<usize>, FlashError> {
        let start = offset as usize;
        let end = start.checked_add(len).ok_or(FlashError::OutOfBounds)?;
        if end > self.data.len() {
            return Err(FlashError::OutOfBounds);
        }
        Ok(start..end)
    }

    /// Counts a write; returns the cut's RNG if this write is the one torn by a power cut.
    fn begin_write(&mut self) -> Result<Option<SplitMix64>, FlashError> {
        if !self.powered {
            return Err(FlashError::PowerLoss);
        }
        let this = self.writes;
        self.writes += 1;
        match self.cut {
            Some(cut) if cut.at_write == this => {
                self.powered = false;
                self.cut = None;
                Ok(Some(SplitMix64::new(cut.seed ^ this.wrapping_mul(0xA076_1D64_78BD_642F))))
            }
            _ => Ok(None),
        }
    }

    fn pick_tear(&mut self, rng: &mut SplitMix64) -> Tear {
        let tear = match rng.next_u64() % 3 {
            0 => Tear::None,
            1 => Tear::Partial,
            _ => Tear::Complete,
        };
        self.last_tear = Some(tear);
        tear
    }
}

impl NorFlash for SimFlash {
    fn geometry(&self) -> Geometry {
        self.geometry
    }

    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), FlashError> {
        if !self.powered {
            return Err(FlashError::PowerLoss);
        }
        let range = self.range(offset, buf.len())?;
        self.reads += 1;
        buf.copy_from_slice(&self.data[range]);
        Ok(())
    }

    fn program(&mut self, offset: u32, data: &[u8]) -> Result<(), FlashError> {
        if !self.powered {
            return Err(FlashError::PowerLoss);
        }
        let range = self.range(offset, data.len())?;
        let ws = self.geometry.write_size as usize;
        if !(offset as usize).is_multiple_of(ws) || !data.len().is_multiple_of(ws) {
            return Err(FlashError::Misaligned);
        }
        let target = &self.data[range.clone()];
        if target.iter().zip(data).any(|(old, new)| new & !old != 0) {
            return Err(FlashError::NotErased);
        }
        let cut = self.begin_write()?;
        match cut {
            None => {
                for (old, new) in self.data[range].iter_mut().zip(data) {
                    *old &= new;
                }
                Ok(())
            }
            Some(mut rng) => {
                match self.pick_tear(&mut rng) {
                    Tear::None => {}
                    Tear::Complete => {
                        for (old, new) in self.data[range].iter_mut().zip(data) {
                            *old &= new;
                        }
                    }
                    Tear::Partial => {
                        for (old, new) in self.data[range].iter_mut().zip(data) {
                            // Clear only a random subset of the bits the program should clear.
                            let to_clear = *old & !new;
                            *old &= !(to_clear & rng.next_u8());
                        }
                    }
                }
                Err(FlashError::PowerLoss)
            }
        }
    }

    fn erase_sector(&mut self, sector: u32) -> Result<(), FlashError> {
        if !self.powered {
            return Err(FlashError::PowerLoss);
        }
        let start = self.geometry.sector_start(sector).ok_or(FlashError::OutOfBounds)?;
        let range = self.range(start, self.geometry.sector_size as usize)?;
        let cut = self.begin_write()?;
        match cut {
            None => {
                self.erase_counts[sector as usize] += 1;
                self.data[range].fill(0xFF);
                Ok(())
            }
            Some(mut rng) => {
                match self.pick_tear(&mut rng) {
                    Tear::None => {}
                    Tear::Complete => {
                        self.erase_counts[sector as usize] += 1;
                        self.data[range].fill(0xFF);
                    }
                    Tear::Partial => {
                        self.erase_counts[sector as usize] += 1;
                        for b in &mut self.data[range] {
                            *b |= rng.next_u8();
                        }
                    }
                }
                Err(FlashError::PowerLoss)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nor_semantics_and_alignment() {
        let mut f = SimFlash::new(64, 2, 4);
        assert_eq!(f.program(0, &[0x0F, 0xF0, 0xFF, 0x00]), Ok(()));
        assert_eq!(f.program(0, &[0x07, 0xF0, 0xFE, 0x00]), Ok(()), "clearing more bits is allowed");
        assert_eq!(f.program(0, &[0xFF, 0xF0, 0xFE, 0x00]), Err(FlashError::NotErased));
        assert_eq!(&f.contents()[..4], &[0x07, 0xF0, 0xFE, 0x00]);
        assert_eq!(f.program(2, &[0; 4]), Err(FlashError::Misaligned));
        assert_eq!(f.program(0, &[0; 3]), Err(FlashError::Misaligned));
        assert_eq!(f.program(128, &[0; 4]), Err(FlashError::OutOfBounds));
        assert_eq!(f.erase_sector(2), Err(FlashError::OutOfBounds));
        assert_eq!(f.erase_sector(0), Ok(()));
        assert!(f.contents()[..64].iter().all(|b| *b == 0xFF));
        assert_eq!(f.erase_counts(), &[1, 0]);
        // Rejected operations (misaligned, out of bounds, not erased) are not counted as writes.
        assert_eq!(f.write_count(), 3);
    }

    #[test]
    fn power_cut_stops_everything_until_power_on() {
        let mut f = SimFlash::new(64, 2, 4);
        f.cut_power_at_write(1, 7);
        assert_eq!(f.program(0, &[0; 4]), Ok(()));
        assert_eq!(f.program(4, &[0; 4]), Err(FlashError::PowerLoss));
        assert!(f.last_tear().is_some());
        let mut b = [0u8; 4];
        assert_eq!(f.read(0, &mut b), Err(FlashError::PowerLoss));
        assert_eq!(f.erase_sector(0), Err(FlashError::PowerLoss));
        f.power_on();
        assert_eq!(f.read(0, &mut b), Ok(()));
        assert_eq!(b, [0; 4]);
    }

    #[test]
    fn tears_are_deterministic_and_all_kinds_occur() {
        let mut kinds = Vec::new();
        for seed in 0..32 {
            let run = |seed| {
                let mut f = SimFlash::new(64, 2, 4);
                f.cut_power_at_write(0, seed);
                let _ = f.program(0, &[0x00; 64]);
                (f.contents().to_vec(), f.last_tear())
            };
            let (a, tear) = run(seed);
            assert_eq!((a, tear), run(seed));
            kinds.push(tear);
        }
        for k in [Tear::None, Tear::Partial, Tear::Complete] {
            assert!(kinds.contains(&Some(k)), "{k:?} never happened");
        }
    }
}
