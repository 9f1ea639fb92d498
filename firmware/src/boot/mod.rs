//! Firmware update: signed images, A/B slots, a power-fail-safe swap, trial boots with confirmation
//! (issue 7, phase 1: the foundations; 0x1F5x / FoE wiring and the bootloader binary come next).
//!
//! * [`image`]: the image format (header with magic, version, hardware id, firmware version, 0x1F56 software
//!   identification, payload length and CRC-32, Ed25519 signature) and its parsing.
//! * [`verify`]: streamed verification (CRC-32 and Ed25519 over header and payload) from bytes or from flash.
//! * [`keys`]: the trusted public key.
//! * [`state`]: the update state in BOOT_STATE, an append-only log of CRC-protected records.
//! * [`swap`]: the sector swap of slot A and slot B through the scratch sector.
//! * [`loader`]: the bootloader's decision at reset (verify, swap or resume, trial, revert).
//! * [`update`]: the application's side (download into slot B, activate, confirm).
//! * [`program`]: program control 0x1F50/0x1F51/0x1F56/0x1F57 and the FoE sink over [`update`] (phase 2).
//! * [`tables`]: the application's and the stopped program's dictionary tables.
//! * [`stored_comms`]: the bootloader fallback's node-ID and bit rate from the parameter store.
//!
//! # Flash use (`memory.x`)
//! Slot A (sectors 5-7, 3 x 128 KiB) runs the image; slot B (sectors 8-11) receives a download in its first
//! three sectors; its fourth is the scratch sector of the swap. BOOT_STATE (sector 4, 64 KiB) holds the log.
//! The image's payload starts at the slot start (the application's vector table at 0x0802_0000) and its
//! header sits in the last 128 bytes of the 384 KiB image area.
//!
//! # Lifecycle
//! clear (erase slot B) -> download -> finish (verify in slot B) -> activate (record Pending) -> reset: the
//! bootloader verifies slot B, swaps A and B sector by sector, verifies A, records Trial and starts the new
//! image -> the image confirms itself (record Confirmed). A reset before the confirmation swaps back (revert):
//! the previous image is gone only after the new one confirmed itself. Every step is a record, every record
//! is written after the flash work it describes, and every step can run again, so a power cut anywhere ends
//! in a boot of the old or the new image, never of a half image (`tests/tests/boot/power_cut.rs`).
//!
//! # Crates
//! * Ed25519: `ed25519-compact` (no_std, no alloc, streaming verification, feature `opt_size`). Measured on
//!   thumbv7em-none-eabihf, release, fat LTO, a binary doing one streamed verification: 18.6 KiB .text at
//!   opt-level 3 (15.4 KiB at opt-level "z"), 2 KiB .rodata; `ed25519-dalek` 2.2 (default features off,
//!   `hazmat` for `verify_stream`): 56 KiB at opt-level 3, 26 KiB at "z"; `ed25519-compact` without
//!   `opt_size`: 312 KiB. `salty` has no streaming verification of pure Ed25519 (only Ed25519ph).
//! * CRC: [`crc32`], CRC-32/ISO-HDLC (= IEEE 802.3) with a 16-entry table (the `crc` crate's 1 KiB table did
//!   not leave the bootloader room for its fallback's stored node-ID and bit rate).
//! * Swap: not embassy-boot. Its layout requirements would fit (ACTIVE and DFU with 128 KiB pages, DFU one
//!   page larger, a separate STATE partition), but (1) its bootloader does not verify anything at boot: the
//!   signature is checked only by the application's `FirmwareUpdater::verify_and_mark_updated`, over the
//!   SHA-512 digest of the DFU contents, while this drive must check header, hardware id, CRC and signature of
//!   the image it starts, at every boot, and refuse to run an unsigned one; (2) it has no image header (no
//!   hardware id, version, 0x1F56 identification) to check against; (3) it works on `embedded-storage`
//!   traits with its own partition types and pulls embassy-sync into the bootloader. The swap here is the same
//!   idea (page swap through one spare page, progress in a state partition) in ~150 lines over
//!   [`crate::hal::flash::NorFlash`].

pub mod crc32;
pub mod fallback;
pub mod image;
pub mod keys;
pub mod loader;
pub mod program;
#[cfg(not(target_os = "none"))]
pub mod sign;
pub mod state;
pub mod stored_comms;
pub mod swap;
pub mod tables;
pub mod update;
pub mod verify;
