//! CRC-32 as in IEEE 802.3 (the catalogue's CRC-32/ISO-HDLC: reflected polynomial 0xEDB8_8320, start value and
//! final XOR 0xFFFF_FFFF; check value of "123456789": 0xCBF4_3926), the checksum of the image payload
//! ([`super::image`]), of the update-state records ([`super::state`]) and of the parameter store's records
//! ([`crate::od::store`], which the bootloader reads with [`super::stored_comms`]).
//!
//! Half a byte per table step: a 16-entry table (64 bytes) instead of the usual 256 entries (1 KiB), because the
//! bootloader, which computes it over a whole image at every start, has to fit 32 KiB (issue 19: the stored
//! node-ID and bit rate of its fallback needed the room). Two table steps per byte cost a few instructions per
//! byte more than one (QEMU `insn.boot_verify`), a small part of the check beside SHA-512.

/// The reflected IEEE 802.3 polynomial.
const POLYNOMIAL: u32 = 0xEDB8_8320;

/// The CRC of each 4-bit value (bits processed least significant first).
const NIBBLE_TABLE: [u32; 16] = {
    let mut table = [0u32; 16];
    let mut i = 0u32;
    while i < 16 {
        let mut c = i;
        let mut k = 0;
        while k < 4 {
            c = if c & 1 != 0 { (c >> 1) ^ POLYNOMIAL } else { c >> 1 };
            k += 1;
        }
        // In bounds: i < 16 = table length. Const evaluation would fail the build otherwise.
        #[allow(clippy::indexing_slicing)]
        {
            table[i as usize] = c;
        }
        i += 1;
    }
    table
};

/// A running CRC-32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Crc32(u32);

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// The CRC of no data.
    pub const fn new() -> Self {
        Self(0xFFFF_FFFF)
    }

    /// Feeds `data`.
    pub fn update(&mut self, data: &[u8]) {
        let mut crc = self.0;
        for byte in data {
            crc ^= u32::from(*byte);
            crc = (crc >> 4) ^ NIBBLE_TABLE.get((crc & 0xF) as usize).copied().unwrap_or(0);
            crc = (crc >> 4) ^ NIBBLE_TABLE.get((crc & 0xF) as usize).copied().unwrap_or(0);
        }
        self.0 = crc;
    }

    /// The CRC of everything fed so far.
    pub const fn finalize(self) -> u32 {
        !self.0
    }
}

/// The CRC-32 of `data` in one call.
pub fn checksum(data: &[u8]) -> u32 {
    let mut crc = Crc32::new();
    crc.update(data);
    crc.finalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_check_value_of_ieee_802_3() {
        assert_eq!(checksum(b"123456789"), 0xCBF4_3926);
        assert_eq!(checksum(b""), 0);
    }

    /// The same as the bitwise definition, fed whole or in pieces.
    #[test]
    fn equals_the_bitwise_definition() {
        let data: std::vec::Vec<u8> = (0..1000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        let bitwise = |d: &[u8]| {
            let mut c = 0xFFFF_FFFFu32;
            for b in d {
                c ^= u32::from(*b);
                for _ in 0..8 {
                    c = if c & 1 != 0 { (c >> 1) ^ POLYNOMIAL } else { c >> 1 };
                }
            }
            !c
        };
        for len in [0, 1, 3, 64, 999, 1000] {
            assert_eq!(checksum(&data[..len]), bitwise(&data[..len]), "{len}");
        }
        let mut split = Crc32::new();
        split.update(&data[..333]);
        split.update(&data[333..]);
        assert_eq!(split.finalize(), checksum(&data));
    }
}
