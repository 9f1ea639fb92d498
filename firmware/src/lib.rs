//! Servo-drive firmware: a fixed-point field-oriented current loop at 25 kHz, velocity and position loops at
//! 2.5 kHz, the CiA 402 drive profile, and an object dictionary generated at build time from
//! `firmware/device.toml`, served over EtherCAT (CoE) and CANopen.
//!
//! The library is `no_std` and holds the firmware's logic, pure and host-testable; only `board/` and `rt/`
//! (target-only) touch registers. See `shared/design/ARCHITECTURE.md` for the tiers and conventions.
#![cfg_attr(not(test), no_std)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects
    )
)]

#[cfg(target_os = "none")]
pub mod board;
pub mod boot;
pub mod canopen;
pub mod cia402;
pub mod comm;
/// The control math: the `drive-control` crate (built for speed while this crate is built for size).
pub use drive_control as control;
pub mod drive;
pub mod ecat;
pub mod fault;
pub mod flash_map;
pub mod hal;
pub mod handoff;
pub mod io;
pub mod motion;
pub mod od;
pub mod power_state;
pub mod recorder;
#[cfg(target_os = "none")]
pub mod rt;
pub mod sensors;
pub mod supervision;
