//! The public key images must be signed with, compiled into the bootloader and the application.
//!
//! Written by `drive-image keygen --rust firmware/src/boot/keys.rs` from `keys/dev-signing-key.pub`
//! (a test checks that they match). This is the DEVELOPMENT key: its secret half is in the repository
//! (`keys/dev-signing-key.secret`) so that tests can sign; a production build replaces this file with the
//! public key of a key kept offline.

/// Ed25519 public key of the development signing key (`keys/dev-signing-key.pub`).
#[rustfmt::skip]
pub const DEV_PUBLIC_KEY: [u8; 32] = [
    0x04, 0x49, 0xc9, 0x08, 0xd3, 0x6d, 0xf7, 0x13, 0xfe, 0xed, 0xd6, 0x9f, 0x3c, 0x1c, 0xb4, 0x88,
    0x09, 0xbb, 0x39, 0x77, 0x6a, 0x1c, 0xf9, 0x91, 0x5f, 0x66, 0xc3, 0xc1, 0xc2, 0x1a, 0xeb, 0xbd,
];
