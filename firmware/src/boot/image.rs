//! The firmware image format: a 128-byte header followed by the payload (the application's flash contents
//! from the start of slot A), as the update file carries it and as 0x1F50 / FoE deliver it.
//!
//! # Header (little-endian; offsets in the header)
//! ```text
//!   0  u32       magic "OSDI" (0x4944_534F)
//!   4  u16       format version (1)
//!   6  u16       header length (128)
//!   8  u32       hardware / product id the image is built for (must equal the drive's, [`HARDWARE_ID`])
//!  12  u32       firmware version (0x100A / 0x1018:03 of the new application)
//!  16  u32       software identification, the value 0x1F56:01 reports (IDX L3382-3412: bits 31..16
//!                application, bits 15..0 bootloader)
//!  20  u32       payload length in bytes (a multiple of 4, the F405 program granularity)
//!  24  u32       CRC-32 (IEEE 802.3) of the payload
//!  28  u32       load address (start of slot A, 0x0802_0000)
//!  32  [u8; 16]  version string (ASCII, NUL padded; what 0x100A reports)
//!  48  u32       security version (anti-rollback: an image below the drive's minimum is refused, see below)
//!  52  [u8; 12]  reserved, zero
//!  64  [u8; 64]  Ed25519 signature (RFC 8032, pure Ed25519) over header bytes 0..64 followed by the payload
//! ```
//! The signature covers every header field, so no field can be changed without the signing key; the CRC is
//! checked first so that a transfer error is reported as such (0x1F57 / FoE 0x800C "checksum wrong") and not
//! as a forged image.
//!
//! # Security version (anti-rollback)
//! The firmware version says what an image is; the security version says which older images it supersedes. The
//! drive keeps a minimum accepted security version in its update state ([`super::state`]), raised to an image's
//! security version when that image confirms itself, and refuses a signed image below it
//! ([`ImageError::Rollback`]): an old image with a known weakness cannot be loaded again once a fixed one ran.
//! Images that fix nothing security-relevant keep the security version of their predecessor, so a downgrade
//! to them stays possible.
//!
//! The field took 4 of the 16 reserved bytes, which format version 1 already required to be zero, so the format
//! version stays 1: every existing image reads as security version 0, exactly what it was before the field
//! existed, and an older firmware, which does not know the field, refuses an image with a non-zero one as a
//! malformed header instead of misreading it. Old images stay valid; no new meaning needs a new version number.
//!
//! # Where the header lives in a slot
//! The application is linked to run from the start of slot A (its vector table at 0x0802_0000, `memory.x`
//! region `FLASH`), so the payload is stored from offset 0 of a slot and the header in the last
//! [`HEADER_LEN`] bytes of the slot-A-sized image area ([`HEADER_OFFSET`]). The image therefore holds at most
//! [`MAX_PAYLOAD_LEN`] bytes of payload.

use crate::flash_map::{SLOT_A_END, SLOT_A_START};
use crate::hal::flash::FlashError;

/// Magic word at header offset 0: "OSDI" (open servo drive image).
pub const MAGIC: u32 = u32::from_le_bytes(*b"OSDI");
/// Header format version this firmware writes and accepts.
pub const FORMAT_VERSION: u16 = 1;
/// Length of the header in bytes.
pub const HEADER_LEN: u32 = 128;
/// Length of the signed part of the header (everything before the signature).
pub const SIGNED_HEADER_LEN: u32 = 64;
/// Length of an Ed25519 signature.
pub const SIGNATURE_LEN: usize = 64;
/// Length of the version string field.
pub const VERSION_STRING_LEN: usize = 16;
/// Hardware / product id of this drive (STM32F405 servo drive, board revision 1). An image for another
/// hardware is refused with [`ImageError::WrongHardware`] (FoE 0x800D "firmware does not fit for hardware").
pub const HARDWARE_ID: u32 = 0x0F40_5001;
/// Size of the image area of a slot: the size of slot A (slot B is one scratch sector larger).
pub const IMAGE_AREA_LEN: u32 = SLOT_A_END.saturating_sub(SLOT_A_START);
/// Offset of the header within a slot: the last [`HEADER_LEN`] bytes of the image area.
pub const HEADER_OFFSET: u32 = IMAGE_AREA_LEN.saturating_sub(HEADER_LEN);
/// Largest payload an image may carry.
pub const MAX_PAYLOAD_LEN: u32 = HEADER_OFFSET;
/// Largest image (header and payload) a download may carry.
pub const MAX_IMAGE_LEN: u32 = IMAGE_AREA_LEN;
/// Payload lengths are multiples of this (the F405 programs by 32-bit word, RM0090 section 3.5).
pub const PAYLOAD_ALIGN: u32 = 4;

const OFF_MAGIC: usize = 0;
const OFF_VERSION: usize = 4;
const OFF_HEADER_LEN: usize = 6;
const OFF_HARDWARE: usize = 8;
const OFF_FW_VERSION: usize = 12;
const OFF_SOFTWARE_ID: usize = 16;
const OFF_PAYLOAD_LEN: usize = 20;
const OFF_PAYLOAD_CRC: usize = 24;
const OFF_LOAD_ADDRESS: usize = 28;
const OFF_VERSION_STRING: usize = 32;
const OFF_SECURITY_VERSION: usize = 48;
const OFF_RESERVED: usize = 52;
const OFF_SIGNATURE: usize = 64;
const RESERVED_LEN: usize = 12;

/// Why an image was refused. Every check of an untrusted image ends in one of these; nothing panics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageError {
    /// Fewer bytes than the header, or than the header's payload length, arrived.
    Truncated,
    /// More bytes than the header's payload length arrived.
    TrailingData,
    /// The magic word is not "OSDI": not an image of this format.
    BadMagic,
    /// A format version this firmware does not know.
    UnsupportedVersion(u16),
    /// Header length, reserved bytes or payload alignment are not as the format defines them.
    MalformedHeader,
    /// The image is built for another hardware.
    WrongHardware {
        /// This drive's id.
        expected: u32,
        /// The image's id.
        found: u32,
    },
    /// The image is not linked for slot A.
    WrongLoadAddress(u32),
    /// The payload does not fit the slot.
    Oversized {
        /// Payload length the header (or the transfer) claims.
        len: u32,
        /// Largest payload the slot takes.
        max: u32,
    },
    /// The payload's CRC-32 differs from the header's: a transfer or flash error.
    Crc {
        /// CRC-32 in the header.
        expected: u32,
        /// CRC-32 of the payload as read.
        computed: u32,
    },
    /// The Ed25519 signature does not verify with the trusted key (forged, altered, or another key).
    BadSignature,
    /// The image's security version is below the drive's minimum accepted one (anti-rollback, module docs).
    Rollback {
        /// The minimum security version in force.
        minimum: u32,
        /// The image's security version.
        found: u32,
    },
    /// Reading the image from flash failed.
    Flash(FlashError),
}

/// The parsed header of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageHeader {
    /// Hardware / product id the image is built for.
    pub hardware_id: u32,
    /// Firmware version.
    pub firmware_version: u32,
    /// The value 0x1F56:01 reports for this image.
    pub software_id: u32,
    /// Payload length in bytes.
    pub payload_len: u32,
    /// CRC-32 (IEEE 802.3) of the payload.
    pub payload_crc: u32,
    /// Address the payload is linked to run from (start of slot A).
    pub load_address: u32,
    /// Version string (ASCII, NUL padded).
    pub version_string: [u8; VERSION_STRING_LEN],
    /// Security version (anti-rollback, module docs); 0 for images from before the field.
    pub security_version: u32,
    /// Ed25519 signature over header bytes 0..64 and the payload.
    pub signature: [u8; SIGNATURE_LEN],
}

impl ImageHeader {
    /// A header for a payload of `payload_len` bytes with CRC `payload_crc`, unsigned (signature zero), security
    /// version 0.
    pub const fn new(
        hardware_id: u32,
        firmware_version: u32,
        software_id: u32,
        payload_len: u32,
        payload_crc: u32,
    ) -> Self {
        Self {
            hardware_id,
            firmware_version,
            software_id,
            payload_len,
            payload_crc,
            load_address: SLOT_A_START,
            version_string: [0; VERSION_STRING_LEN],
            security_version: 0,
            signature: [0; SIGNATURE_LEN],
        }
    }

    /// The header's bytes in the format above.
    pub fn to_bytes(&self) -> [u8; HEADER_LEN as usize] {
        let mut b = [0u8; HEADER_LEN as usize];
        put(&mut b, OFF_MAGIC, &MAGIC.to_le_bytes());
        put(&mut b, OFF_VERSION, &FORMAT_VERSION.to_le_bytes());
        put(&mut b, OFF_HEADER_LEN, &(HEADER_LEN as u16).to_le_bytes());
        put(&mut b, OFF_HARDWARE, &self.hardware_id.to_le_bytes());
        put(&mut b, OFF_FW_VERSION, &self.firmware_version.to_le_bytes());
        put(&mut b, OFF_SOFTWARE_ID, &self.software_id.to_le_bytes());
        put(&mut b, OFF_PAYLOAD_LEN, &self.payload_len.to_le_bytes());
        put(&mut b, OFF_PAYLOAD_CRC, &self.payload_crc.to_le_bytes());
        put(&mut b, OFF_LOAD_ADDRESS, &self.load_address.to_le_bytes());
        put(&mut b, OFF_VERSION_STRING, &self.version_string);
        put(&mut b, OFF_SECURITY_VERSION, &self.security_version.to_le_bytes());
        put(&mut b, OFF_SIGNATURE, &self.signature);
        b
    }

    /// Parses the structure of a header from untrusted bytes (magic, format version, header length, reserved
    /// bytes, payload alignment). The fields are not yet checked against this drive: see [`ImageHeader::check`].
    pub fn parse(bytes: &[u8]) -> Result<Self, ImageError> {
        let b = bytes.get(..HEADER_LEN as usize).ok_or(ImageError::Truncated)?;
        if le_u32(b, OFF_MAGIC) != MAGIC {
            return Err(ImageError::BadMagic);
        }
        let version = le_u16(b, OFF_VERSION);
        if version != FORMAT_VERSION {
            return Err(ImageError::UnsupportedVersion(version));
        }
        let reserved_zero =
            b.get(OFF_RESERVED..OFF_RESERVED.saturating_add(RESERVED_LEN)).is_some_and(|r| r.iter().all(|x| *x == 0));
        let payload_len = le_u32(b, OFF_PAYLOAD_LEN);
        if u32::from(le_u16(b, OFF_HEADER_LEN)) != HEADER_LEN
            || !reserved_zero
            || !payload_len.is_multiple_of(PAYLOAD_ALIGN)
        {
            return Err(ImageError::MalformedHeader);
        }
        let mut version_string = [0u8; VERSION_STRING_LEN];
        copy_from(&mut version_string, b, OFF_VERSION_STRING);
        let mut signature = [0u8; SIGNATURE_LEN];
        copy_from(&mut signature, b, OFF_SIGNATURE);
        Ok(Self {
            hardware_id: le_u32(b, OFF_HARDWARE),
            firmware_version: le_u32(b, OFF_FW_VERSION),
            software_id: le_u32(b, OFF_SOFTWARE_ID),
            payload_len,
            payload_crc: le_u32(b, OFF_PAYLOAD_CRC),
            load_address: le_u32(b, OFF_LOAD_ADDRESS),
            version_string,
            security_version: le_u32(b, OFF_SECURITY_VERSION),
            signature,
        })
    }

    /// Checks the header against this drive: hardware id, load address, payload size for the slot.
    pub fn check(&self, hardware_id: u32, max_payload: u32) -> Result<(), ImageError> {
        if self.hardware_id != hardware_id {
            return Err(ImageError::WrongHardware { expected: hardware_id, found: self.hardware_id });
        }
        if self.load_address != SLOT_A_START {
            return Err(ImageError::WrongLoadAddress(self.load_address));
        }
        if self.payload_len > max_payload {
            return Err(ImageError::Oversized { len: self.payload_len, max: max_payload });
        }
        if self.payload_len == 0 {
            return Err(ImageError::Truncated);
        }
        Ok(())
    }

    /// Checks the security version against the drive's minimum accepted one (anti-rollback, module docs): equal
    /// or newer is accepted.
    pub const fn check_security_version(&self, minimum: u32) -> Result<(), ImageError> {
        if self.security_version < minimum {
            return Err(ImageError::Rollback { minimum, found: self.security_version });
        }
        Ok(())
    }

    /// Total length of the image (header and payload) the header announces.
    pub const fn image_len(&self) -> u32 {
        HEADER_LEN.saturating_add(self.payload_len)
    }

    /// The version string without its NUL padding.
    pub fn version_str(&self) -> &[u8] {
        let end = self.version_string.iter().position(|b| *b == 0).unwrap_or(VERSION_STRING_LEN);
        self.version_string.get(..end).unwrap_or(&[])
    }
}

/// The signed part of the header bytes (everything before the signature).
pub fn signed_header(header: &[u8; HEADER_LEN as usize]) -> &[u8] {
    header.get(..SIGNED_HEADER_LEN as usize).unwrap_or(&[])
}

fn le_u32(buf: &[u8], at: usize) -> u32 {
    buf.get(at..).and_then(|s| s.first_chunk::<4>()).map_or(0, |b| u32::from_le_bytes(*b))
}

fn le_u16(buf: &[u8], at: usize) -> u16 {
    buf.get(at..).and_then(|s| s.first_chunk::<2>()).map_or(0, |b| u16::from_le_bytes(*b))
}

fn put(buf: &mut [u8], at: usize, bytes: &[u8]) {
    if let Some(dst) = at.checked_add(bytes.len()).and_then(|end| buf.get_mut(at..end)) {
        dst.copy_from_slice(bytes);
    }
}

fn copy_from(dst: &mut [u8], src: &[u8], at: usize) {
    if let Some(s) = at.checked_add(dst.len()).and_then(|end| src.get(at..end)) {
        dst.copy_from_slice(s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> ImageHeader {
        let mut h = ImageHeader::new(HARDWARE_ID, 0x0102_0003, 0x0002_0001, 1024, 0xDEAD_BEEF);
        h.version_string[..5].copy_from_slice(b"1.2.3");
        h.security_version = 0x0000_0102;
        h.signature = [0x5A; SIGNATURE_LEN];
        h
    }

    #[test]
    fn header_round_trips_through_its_bytes() {
        let h = header();
        let b = h.to_bytes();
        assert_eq!(&b[..4], b"OSDI");
        assert_eq!(&b[48..52], &[0x02, 0x01, 0, 0], "security version at offset 48, little-endian");
        assert_eq!(ImageHeader::parse(&b), Ok(h));
        assert_eq!(h.version_str(), b"1.2.3");
        assert_eq!(h.check(HARDWARE_ID, MAX_PAYLOAD_LEN), Ok(()));
    }

    #[test]
    fn every_structural_refusal_is_typed() {
        let b = header().to_bytes();
        assert_eq!(ImageHeader::parse(&b[..127]), Err(ImageError::Truncated));
        let mut x = b;
        x[0] ^= 1;
        assert_eq!(ImageHeader::parse(&x), Err(ImageError::BadMagic));
        let mut x = b;
        x[4] = 2;
        assert_eq!(ImageHeader::parse(&x), Err(ImageError::UnsupportedVersion(2)));
        let mut x = b;
        x[6] = 64;
        assert_eq!(ImageHeader::parse(&x), Err(ImageError::MalformedHeader));
        let mut x = b;
        x[52] = 1; // first reserved byte after the security version
        assert_eq!(ImageHeader::parse(&x), Err(ImageError::MalformedHeader));
        let mut x = b;
        x[63] = 1; // last reserved byte
        assert_eq!(ImageHeader::parse(&x), Err(ImageError::MalformedHeader));
        let mut x = b;
        x[20] = 3; // payload length 1027: not word aligned
        x[21] = 4;
        assert_eq!(ImageHeader::parse(&x), Err(ImageError::MalformedHeader));
        let h = header();
        assert_eq!(h.check(7, MAX_PAYLOAD_LEN), Err(ImageError::WrongHardware { expected: 7, found: HARDWARE_ID }));
        assert_eq!(h.check(HARDWARE_ID, 1020), Err(ImageError::Oversized { len: 1024, max: 1020 }));
        let mut moved = h;
        moved.load_address = 0x0808_0000;
        assert_eq!(moved.check(HARDWARE_ID, MAX_PAYLOAD_LEN), Err(ImageError::WrongLoadAddress(0x0808_0000)));
    }

    /// Anti-rollback: an image at the minimum security version or above is accepted, one below is refused with
    /// both versions; a header of the format before the field (bytes 48..52 zero) reads as security version 0.
    #[test]
    fn the_security_version_is_checked_against_the_minimum() {
        let h = header();
        assert_eq!(h.check_security_version(0x0102), Ok(()), "equal");
        assert_eq!(h.check_security_version(0x0101), Ok(()), "newer");
        assert_eq!(h.check_security_version(0x0103), Err(ImageError::Rollback { minimum: 0x0103, found: 0x0102 }));
        let mut old = h;
        old.security_version = 0;
        assert_eq!(ImageHeader::parse(&old.to_bytes()).map(|p| p.security_version), Ok(0));
    }

    #[test]
    fn the_header_sits_at_the_end_of_the_slot_a_area() {
        assert_eq!(IMAGE_AREA_LEN, 384 * 1024);
        assert_eq!(HEADER_OFFSET, 384 * 1024 - 128);
        assert!(HEADER_OFFSET.is_multiple_of(PAYLOAD_ALIGN));
    }

    #[test]
    fn parsing_arbitrary_bytes_never_panics() {
        let mut seed = 0x1234_5678_u32;
        for len in 0..300usize {
            let bytes: std::vec::Vec<u8> = (0..len)
                .map(|_| {
                    seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (seed >> 24) as u8
                })
                .collect();
            let _ = ImageHeader::parse(&bytes).map(|h| h.check(HARDWARE_ID, MAX_PAYLOAD_LEN));
        }
    }
}
