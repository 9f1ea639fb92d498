//! Fieldbus memory management units (ESC datasheet section I "FMMU", registers 0x0600 + 16n; ETG.1000.4 §6.6).
//!
//! An FMMU maps a range of the 32-bit logical address space, bit-exact, onto physical memory: logical bits
//! `start * 8 + start_bit ..= (start + length - 1) * 8 + stop_bit` go to physical bits from
//! `physical * 8 + physical_bit` on. Read FMMUs serve LRD/LRW reads, write FMMUs LWR/LRW writes; a read and a
//! write FMMU may map the same logical range (the usual SOEM/ethercrab LRW layout uses distinct ranges, KickCAT
//! LRD/LWR).

/// One decoded FMMU entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Fmmu {
    /// Logical start address (+0x0, u32).
    pub logical_start: u32,
    /// Length in bytes (+0x4, u16), counting the partial first and last bytes.
    pub length: u16,
    /// Logical start bit (+0x6, 0..=7).
    pub start_bit: u8,
    /// Logical stop bit (+0x7, 0..=7).
    pub stop_bit: u8,
    /// Physical start address (+0x8, u16).
    pub physical_start: u16,
    /// Physical start bit (+0xA, 0..=7).
    pub physical_bit: u8,
    /// Type (+0xB): bit 0 read, bit 1 write.
    pub kind: u8,
    /// Activate (+0xC): bit 0.
    pub active: bool,
}

impl Fmmu {
    /// Decodes the 16 register bytes of one FMMU.
    pub fn decode(b: &[u8]) -> Self {
        let g = |i: usize| b.get(i).copied().unwrap_or(0);
        Self {
            logical_start: u32::from_le_bytes([g(0), g(1), g(2), g(3)]),
            length: u16::from_le_bytes([g(4), g(5)]),
            start_bit: g(6) & 7,
            stop_bit: g(7) & 7,
            physical_start: u16::from_le_bytes([g(8), g(9)]),
            physical_bit: g(0xA) & 7,
            kind: g(0xB) & 3,
            active: g(0xC) & 1 != 0,
        }
    }

    /// Active read FMMU.
    pub fn reads(&self) -> bool {
        self.active && self.length > 0 && self.kind & 1 != 0
    }

    /// Active write FMMU.
    pub fn writes(&self) -> bool {
        self.active && self.length > 0 && self.kind & 2 != 0
    }

    /// First and last (inclusive) logical bit, as absolute bit numbers.
    fn logical_bits(&self) -> (u64, u64) {
        let first = u64::from(self.logical_start) * 8 + u64::from(self.start_bit);
        let last = (u64::from(self.logical_start) + u64::from(self.length) - 1) * 8 + u64::from(self.stop_bit);
        (first, last)
    }

    /// Calls `f(logical_bit_in_byte, physical_byte, physical_bit)` for each bit of logical byte `addr` this FMMU
    /// maps (at most 8 calls). A byte-aligned FMMU maps whole bytes; the callback still sees each bit so that
    /// one code path serves both.
    pub fn map_byte(&self, addr: u64, mut f: impl FnMut(u8, u16, u8)) {
        if self.length == 0 {
            return;
        }
        let (first, last) = self.logical_bits();
        if last < first {
            return;
        }
        let phys0 = u64::from(self.physical_start) * 8 + u64::from(self.physical_bit);
        for bit in 0..8u8 {
            let g = addr * 8 + u64::from(bit);
            if g < first || g > last {
                continue;
            }
            let p = phys0 + (g - first);
            if let Ok(byte) = u16::try_from(p / 8) {
                f(bit, byte, (p % 8) as u8);
            }
        }
    }

    /// Whether this FMMU maps any bit of the logical byte range `[addr, addr + len)`.
    pub fn overlaps(&self, addr: u64, len: u64) -> bool {
        if self.length == 0 || len == 0 {
            return false;
        }
        let (first, last) = self.logical_bits();
        let lo = addr * 8;
        let hi = (addr + len) * 8 - 1;
        first <= hi && lo <= last
    }
}
