//! Verification of an image: header checks, CRC-32 of the payload, Ed25519 signature; streamed, so a 384 KiB
//! image in flash is checked through a small buffer without a RAM copy.
//!
//! Ed25519 (RFC 8032 section 5.1.7) hashes SHA-512(R || A || M); `ed25519-compact`'s incremental verifier
//! absorbs M (here: header bytes 0..64, then the payload) chunk by chunk. The CRC is computed in the same pass
//! and compared first, so that a damaged image is reported as [`ImageError::Crc`] and only an intact but
//! unauthentic one as [`ImageError::BadSignature`].

use ed25519_compact::{PublicKey, Signature, VerifyingState};

use super::crc32::Crc32;
use super::image::{signed_header, ImageError, ImageHeader, HEADER_LEN};
use crate::hal::flash::NorFlash;

/// What the verifier needs to know about the drive: the trusted key, its hardware id, the slot size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trust {
    /// The Ed25519 public key images must be signed with.
    pub public_key: [u8; 32],
    /// This drive's hardware id ([`super::image::HARDWARE_ID`] on the target).
    pub hardware_id: u32,
    /// The largest payload the slot takes ([`super::image::MAX_PAYLOAD_LEN`]).
    pub max_payload: u32,
}

/// This drive's trust anchor, the same in the bootloader and the application: the compiled-in key
/// ([`super::keys::DEV_PUBLIC_KEY`]), the hardware id of the reference board, and slot A's payload capacity.
pub const DEVICE_TRUST: Trust = Trust {
    public_key: super::keys::DEV_PUBLIC_KEY,
    hardware_id: super::image::HARDWARE_ID,
    max_payload: super::image::MAX_PAYLOAD_LEN,
};

/// A streaming check of one image: created from its header, fed the payload in order, then finished.
pub struct ImageCheck {
    header: ImageHeader,
    crc: Crc32,
    signature: VerifyingState,
    remaining: u32,
}

impl ImageCheck {
    /// Parses and checks `header_bytes` against `trust` and starts the CRC and the signature check.
    pub fn new(header_bytes: &[u8; HEADER_LEN as usize], trust: &Trust) -> Result<Self, ImageError> {
        let header = ImageHeader::parse(header_bytes)?;
        header.check(trust.hardware_id, trust.max_payload)?;
        let key = PublicKey::new(trust.public_key);
        // A signature whose S is not canonical, or whose R is not a point, is refused here already.
        let mut signature =
            key.verify_incremental(&Signature::new(header.signature)).map_err(|_| ImageError::BadSignature)?;
        signature.absorb(signed_header(header_bytes));
        Ok(Self { header, crc: Crc32::new(), signature, remaining: header.payload_len })
    }

    /// The checked header.
    pub fn header(&self) -> &ImageHeader {
        &self.header
    }

    /// Payload bytes still expected.
    pub fn remaining(&self) -> u32 {
        self.remaining
    }

    /// Feeds the next payload bytes. More bytes than the header announces: [`ImageError::TrailingData`].
    pub fn update(&mut self, chunk: &[u8]) -> Result<(), ImageError> {
        let n = u32::try_from(chunk.len()).map_err(|_| ImageError::TrailingData)?;
        self.remaining = self.remaining.checked_sub(n).ok_or(ImageError::TrailingData)?;
        self.crc.update(chunk);
        self.signature.absorb(chunk);
        Ok(())
    }

    /// Completes the check: all payload bytes seen, CRC equal, signature valid.
    pub fn finish(self) -> Result<ImageHeader, ImageError> {
        if self.remaining != 0 {
            return Err(ImageError::Truncated);
        }
        let computed = self.crc.finalize();
        if computed != self.header.payload_crc {
            return Err(ImageError::Crc { expected: self.header.payload_crc, computed });
        }
        // Through an opaque function pointer: the verifier (scalar reduction, double scalar multiplication) stays
        // one out-of-line function as its crate optimised it (for size; root Cargo.toml). Inlined here it would be
        // optimised again at this crate's level and grow the bootloader past its 32 KiB region.
        let verify: fn(&VerifyingState) -> Result<(), ed25519_compact::Error> = VerifyingState::verify;
        core::hint::black_box(verify)(&self.signature).map_err(|_| ImageError::BadSignature)?;
        Ok(self.header)
    }
}

/// Verifies an image given as bytes (the update file: header then payload).
pub fn verify_bytes(image: &[u8], trust: &Trust) -> Result<ImageHeader, ImageError> {
    let header = image.first_chunk::<{ HEADER_LEN as usize }>().ok_or(ImageError::Truncated)?;
    let mut check = ImageCheck::new(header, trust)?;
    let payload = image.get(HEADER_LEN as usize..).unwrap_or(&[]);
    let want = check.remaining() as usize;
    if payload.len() < want {
        return Err(ImageError::Truncated);
    }
    check.update(payload)?;
    check.finish()
}

/// Verifies the image stored in a slot: the header at `header_offset`, the payload from offset 0, read through
/// `buf` (any non-empty size; 256 bytes to a few KiB are sensible).
pub fn verify_in_flash<F: NorFlash>(
    flash: &mut F,
    header_offset: u32,
    trust: &Trust,
    buf: &mut [u8],
) -> Result<ImageHeader, ImageError> {
    let mut header = [0u8; HEADER_LEN as usize];
    flash.read(header_offset, &mut header).map_err(ImageError::Flash)?;
    let mut check = ImageCheck::new(&header, trust)?;
    // The payload must not run into the header (the slot area is checked with `max_payload`).
    if check.remaining() > header_offset {
        return Err(ImageError::Oversized { len: check.remaining(), max: header_offset });
    }
    if buf.is_empty() {
        return Err(ImageError::Truncated);
    }
    let mut offset = 0u32;
    while check.remaining() > 0 {
        let n = buf.len().min(check.remaining() as usize);
        let chunk = buf.get_mut(..n).ok_or(ImageError::Truncated)?;
        flash.read(offset, chunk).map_err(ImageError::Flash)?;
        check.update(chunk)?;
        offset = offset.saturating_add(n as u32);
    }
    check.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc8032_test_vector_2_verifies_in_chunks() {
        // RFC 8032 section 7.1, TEST 2 (one-byte message 0x72).
        let pk = [
            0x3d, 0x40, 0x17, 0xc3, 0xe8, 0x43, 0x89, 0x5a, 0x92, 0xb7, 0x0a, 0xa7, 0x4d, 0x1b, 0x7e, 0xbc, 0x9c, 0x98,
            0x2c, 0xcf, 0x2e, 0xc4, 0x96, 0x8c, 0xc0, 0xcd, 0x55, 0xf1, 0x2a, 0xf4, 0x66, 0x0c,
        ];
        let sig = [
            0x92, 0xa0, 0x09, 0xa9, 0xf0, 0xd4, 0xca, 0xb8, 0x72, 0x0e, 0x82, 0x0b, 0x5f, 0x64, 0x25, 0x40, 0xa2, 0xb2,
            0x7b, 0x54, 0x16, 0x50, 0x3f, 0x8f, 0xb3, 0x76, 0x22, 0x23, 0xeb, 0xdb, 0x69, 0xda, 0x08, 0x5a, 0xc1, 0xe4,
            0x3e, 0x15, 0x99, 0x6e, 0x45, 0x8f, 0x36, 0x13, 0xd0, 0xf1, 0x1d, 0x8c, 0x38, 0x7b, 0x2e, 0xae, 0xb4, 0x30,
            0x2a, 0xee, 0xb0, 0x0d, 0x29, 0x16, 0x12, 0xbb, 0x0c, 0x00,
        ];
        let key = PublicKey::new(pk);
        let mut st = key.verify_incremental(&Signature::new(sig)).unwrap();
        st.absorb([0x72u8]);
        assert!(st.verify().is_ok());
        let mut st = key.verify_incremental(&Signature::new(sig)).unwrap();
        st.absorb([0x73u8]);
        assert!(st.verify().is_err());
    }
}
