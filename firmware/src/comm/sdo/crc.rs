//! The CRC of SDO block transfers: CiA 301 §7.2.4.3.16 ("CRC calculation algorithm to support block
//! transfer") specifies the CCITT polynomial x^16 + x^12 + x^5 + 1 (0x1021) with start value 0, bits processed
//! most significant first, no final XOR (the "CRC-16/XMODEM" parameter set; check value 0x31C3 for
//! "123456789"). It covers the data bytes of the transfer only, and goes on the wire little-endian in the end
//! frames (bytes 1..2).

/// A running CRC-16 (CiA 301 §7.2.4.3.16).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Crc16(u16);

impl Crc16 {
    /// The CRC of no data (start value 0).
    pub const fn new() -> Self {
        Self(0)
    }

    /// Feeds `data`.
    pub fn update(&mut self, data: &[u8]) {
        let mut crc = self.0;
        for byte in data {
            crc ^= u16::from(*byte) << 8;
            for _ in 0..8 {
                crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
            }
        }
        self.0 = crc;
    }

    /// The CRC of everything fed so far.
    pub const fn value(self) -> u16 {
        self.0
    }

    /// The CRC of `data` in one call.
    pub fn of(data: &[u8]) -> u16 {
        let mut crc = Self::new();
        crc.update(data);
        crc.value()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value_of_the_ccitt_xmodem_parameters() {
        // The standard check value of CRC-16 poly 0x1021, init 0, no reflection, no final XOR.
        assert_eq!(Crc16::of(b"123456789"), 0x31C3);
        assert_eq!(Crc16::of(b""), 0);
        let mut split = Crc16::new();
        split.update(b"1234");
        split.update(b"56789");
        assert_eq!(split.value(), 0x31C3);
    }
}
