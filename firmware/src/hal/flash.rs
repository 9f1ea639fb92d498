//! NOR flash: the narrow interface the parameter store (and later the boot-state code) writes through.
//!
//! One implementation covers one *region* of the flash map in `memory.x` (for the parameter store: PARAMS_A and
//! PARAMS_B, two 16 KiB sectors). Offsets are relative to the start of the region and the region is made of
//! `sector_count` sectors of `sector_size` bytes each; every region of the F405 map is built from sectors of one
//! size (RM0090 section 3.3), so a uniform geometry is enough. The board implementation maps sector `i` to its
//! absolute address (`crate::flash_map::PARAMS_SLOTS`); `hal-sim` provides a simulated one with power cuts.
//!
//! NOR semantics (RM0090 section 3.5): an erased byte reads 0xFF; programming can only clear bits (1 -> 0); only an
//! erase of a whole sector sets bits again. The F405 programs by word when the supply is 2.7..3.6 V (PSIZE = x32),
//! so the write granularity is 4 bytes: offsets and lengths passed to [`NorFlash::program`] are multiples of it.

/// What went wrong in a flash operation. Small and `Copy`, so it travels up unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// The range lies (partly) outside the region, or the sector number does not exist.
    OutOfBounds,
    /// A program offset or length is not a multiple of the write granularity.
    Misaligned,
    /// A program would have to set a bit from 0 to 1, which only an erase can do.
    NotErased,
    /// The supply failed (or is failing) during the operation; the touched range is in an unknown state.
    PowerLoss,
    /// The controller reported an error (RM0090 FLASH_SR: PGAERR, PGPERR, PGSERR, WRPERR, OPERR).
    Device,
}

/// Geometry of a flash region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Geometry {
    /// Size of one erase sector in bytes.
    pub sector_size: u32,
    /// Number of sectors in the region.
    pub sector_count: u32,
    /// Program granularity in bytes: offsets and lengths of a program are multiples of it (4 on the F405).
    pub write_size: u32,
}

impl Geometry {
    /// Offset of the first byte of `sector` in the region, or `None` if the sector does not exist.
    pub const fn sector_start(&self, sector: u32) -> Option<u32> {
        if sector >= self.sector_count {
            return None;
        }
        sector.checked_mul(self.sector_size)
    }

    /// Total size of the region in bytes (saturating; real regions are far below 4 GiB).
    pub const fn capacity(&self) -> u32 {
        self.sector_size.saturating_mul(self.sector_count)
    }
}

/// A region of NOR flash with uniform erase sectors.
///
/// Implementations must not touch bytes outside the range of the call, and must leave a failed program or
/// erase reported as an error (a torn operation may leave the range partly written; callers protect
/// themselves with checksums and commit words, see `od::store`).
pub trait NorFlash {
    /// The geometry of the region.
    fn geometry(&self) -> Geometry;

    /// Reads `buf.len()` bytes starting at `offset`. Reads have no alignment requirement.
    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), FlashError>;

    /// Programs `data` at `offset`. Both the offset and the length must be multiples of
    /// [`Geometry::write_size`]. Programming only clears bits: a byte becomes `old & new`, and an
    /// implementation reports [`FlashError::NotErased`] instead if some bit would have to go from 0 to 1.
    fn program(&mut self, offset: u32, data: &[u8]) -> Result<(), FlashError>;

    /// Erases sector `sector` (every byte reads 0xFF afterwards).
    fn erase_sector(&mut self, sector: u32) -> Result<(), FlashError>;
}
