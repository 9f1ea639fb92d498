//! Signing of images, for the host side only (the image tool `drive-image` and the tests): the firmware
//! verifies, it never signs, so this module is not built for the target.

use ed25519_compact::{KeyPair, Noise, Seed};

use super::crc32;
use super::image::{signed_header, ImageHeader};

/// The Ed25519 public key of a 32-byte secret seed (RFC 8032 section 5.1.5).
pub fn public_key(seed: &[u8; 32]) -> [u8; 32] {
    *KeyPair::from_seed(Seed::new(*seed)).pk
}

/// Completes `header` for `payload` (length, CRC-32) and signs header bytes 0..64 followed by the payload
/// with the key of `seed`. `noise` hedges the nonce (RFC 8032 nonces are deterministic; ed25519-compact's
/// streaming signer mixes in 16 bytes of noise, which must not repeat for one key: pass fresh random bytes).
/// Returns the image: the header bytes followed by the payload is what a download carries.
pub fn sign_image(header: &mut ImageHeader, payload: &[u8], seed: &[u8; 32], noise: [u8; 16]) {
    header.payload_len = u32::try_from(payload.len()).unwrap_or(u32::MAX);
    header.payload_crc = crc32::checksum(payload);
    let key = KeyPair::from_seed(Seed::new(*seed));
    let mut st = key.sk.sign_incremental(Noise::new(noise));
    let bytes = header.to_bytes();
    st.absorb(signed_header(&bytes));
    st.absorb(payload);
    header.signature = *st.sign();
}
