//! The flash map as constants, generated at build time from the root `memory.x` (the single source of the
//! numbers; `firmware/build_flash_map.rs` reads its `MEMORY` block). For every region `NAME` there are
//! `NAME_START`, `NAME_LEN` and `NAME_END`; below are the names the firmware uses.

#[allow(clippy::all)]
mod generated {
    include!(concat!(env!("OUT_DIR"), "/flash_map.rs"));
}
pub use generated::*;

/// Size of one parameter-store sector (PARAMS_A and PARAMS_B are one erase sector each, of equal size).
pub const PARAMS_SECTOR_SIZE: u32 = PARAMS_A_LEN;
/// Absolute start addresses of the parameter store's ping-pong sectors, in store sector order (0 = A, 1 = B).
pub const PARAMS_SLOTS: [u32; 2] = [PARAMS_A_START, PARAMS_B_START];
/// Start of application slot A (memory.x region `FLASH`, the running image).
pub const SLOT_A_START: u32 = FLASH_START;
/// First address after application slot A.
pub const SLOT_A_END: u32 = FLASH_END;

// The build script checks PARAMS_A and PARAMS_B have the same length; the sectors must not overlap.
const _: () = assert!(PARAMS_A_END <= PARAMS_B_START || PARAMS_B_END <= PARAMS_A_START);
