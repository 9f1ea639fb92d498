//! The microcontroller's 96-bit unique device ID (RM0090 rev 19 §39.1, base 0x1FFF_7A10): the board's serial
//! number, 0x1018:04. Each drive needs its own, so that an LSS master (CiA 305 fastscan) and a configuration tool
//! tell drives on one bus apart; the factory value of device.toml would be the same on every board.

use super::reg::Reg;

/// Base of the unique device ID (three words).
const UNIQUE_ID_BASE: usize = 0x1FFF_7A10;

/// The 96 bits folded into 32 by the image's CRC-32 (every bit of the ID reaches every bit of the serial: the ID
/// differs between chips mostly in the wafer coordinates of its first word).
pub fn serial_number() -> u32 {
    let mut bytes = [0u8; 12];
    for (i, chunk) in bytes.chunks_exact_mut(4).enumerate() {
        chunk.copy_from_slice(&Reg::at(UNIQUE_ID_BASE, i.wrapping_mul(4)).read().to_le_bytes());
    }
    crate::od::store::crc32(&bytes)
}
