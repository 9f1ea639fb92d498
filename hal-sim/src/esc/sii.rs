//! The SII EEPROM behind registers 0x0500..=0x050F (ESC datasheet section II "SII EEPROM interface";
//! ETG.1000.4 §6.4 and ETG.1000.6 §5.4 for the content).
//!
//! Commands complete at once: the busy bit (0x0502 bit 15) is never set, which SOEM, ethercrab and KickCAT all
//! accept (spec file, item 4). Reads return 8 bytes (status bit 6 "read 8 bytes" is set); a master that reads
//! only 4 bytes of 0x0508 simply ignores the rest.

use super::registers::{get_u16, get_u32, put_u16, reg};

/// Control/status bit 0: write enable.
pub const CTRL_WRITE_ENABLE: u16 = 0x0001;
/// Status bit 6: reads return 8 bytes.
pub const STATUS_READ_8: u16 = 0x0040;
/// Status bit 7: two address bytes (EEPROMs above 16 Kibit).
pub const STATUS_TWO_ADDRESS_BYTES: u16 = 0x0080;
/// Status bit 11: checksum error in the ESC configuration area.
pub const STATUS_CHECKSUM_ERROR: u16 = 0x0800;
/// Status bit 13: command error (unknown command or address out of range).
pub const STATUS_COMMAND_ERROR: u16 = 0x2000;
/// Status bit 14: write without write enable.
pub const STATUS_WRITE_ENABLE_ERROR: u16 = 0x4000;
/// Command field (bits 10..8): read.
pub const CMD_READ: u16 = 0x0100;
/// Command field: write.
pub const CMD_WRITE: u16 = 0x0200;
/// Command field: reload (0x0400 in the ESC datasheet; SOEM's `EC_ECMD_RELOAD` writes 0x0300, both accepted).
pub const CMD_RELOAD: u16 = 0x0400;

/// The EEPROM content and its access statistics.
#[derive(Clone, Debug, Default)]
pub struct SiiEeprom {
    /// The EEPROM image (byte `2w` and `2w + 1` hold word `w`, little-endian).
    pub image: Vec<u8>,
    /// Read commands executed.
    pub reads: u64,
    /// Write commands executed.
    pub writes: u64,
}

impl SiiEeprom {
    /// The idle value of the control/status register for this image.
    pub fn idle_status(&self) -> u16 {
        let mut s = STATUS_READ_8;
        if self.image.len() > 2048 {
            s |= STATUS_TWO_ADDRESS_BYTES;
        }
        if !self.config_crc_ok() {
            s |= STATUS_CHECKSUM_ERROR;
        }
        s
    }

    /// Whether word 7's low byte is the CRC-8 of words 0..=6 (ETG.1000.6 §5.4).
    pub fn config_crc_ok(&self) -> bool {
        match (self.image.get(..14), self.image.get(14)) {
            (Some(area), Some(&crc)) => crc8(area) == crc,
            _ => false,
        }
    }

    /// Word `w` of the image (0xFFFF past its end, like an erased EEPROM).
    pub fn word(&self, w: usize) -> u16 {
        match self.image.get(w * 2..w * 2 + 2) {
            Some(b) => u16::from_le_bytes([b[0], b[1]]),
            None => 0xFFFF,
        }
    }

    /// Executes the command the master wrote to 0x0502 (after the whole datagram, so a command written
    /// together with its address uses that address). Updates the registers. Returns true when a reload asks
    /// the ESC to load the configuration area again.
    pub fn execute(&mut self, regs: &mut [u8]) -> bool {
        let ctrl = get_u16(regs, reg::SII_CONTROL);
        let cmd = ctrl & 0x0700;
        if cmd == 0 {
            return false;
        }
        let mut status = self.idle_status();
        let addr = get_u32(regs, reg::SII_ADDRESS) as usize;
        let mut reload = false;
        match cmd {
            CMD_READ => {
                for k in 0..4 {
                    put_u16(regs, reg::SII_DATA + 2 * k as u16, self.word(addr + k));
                }
                self.reads += 1;
            }
            CMD_WRITE => {
                if ctrl & CTRL_WRITE_ENABLE == 0 {
                    status |= STATUS_WRITE_ENABLE_ERROR;
                } else if let Some(b) = self.image.get_mut(addr * 2..addr * 2 + 2) {
                    b.copy_from_slice(&regs[usize::from(reg::SII_DATA)..usize::from(reg::SII_DATA) + 2]);
                    self.writes += 1;
                } else {
                    status |= STATUS_COMMAND_ERROR;
                }
            }
            0x0300 | CMD_RELOAD => reload = true,
            _ => status |= STATUS_COMMAND_ERROR,
        }
        put_u16(regs, reg::SII_CONTROL, status);
        reload
    }
}

/// CRC-8 of the configuration area: polynomial x^8 + x^2 + x + 1, initial 0xFF (ETG.1000.6 §5.4).
pub fn crc8(bytes: &[u8]) -> u8 {
    let mut crc: u8 = 0xFF;
    for &b in bytes {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0x07 } else { crc << 1 };
        }
    }
    crc
}
