//! The glue between the runtime and the pure library: what tier 1 and tier 2 call, and their state.
//!
//! Tier 1 runs [`Drive::fast_tick`] (protection, scaling, commutation angle, `control::current_loop::foc_step`);
//! tier 2 runs [`Drive::slow_tick`]. Both take the one [`Drive`]: tier 1 owns it, and tier 2 and 3 reach it only
//! through `tier1::with_drive`, which holds tier 1 off for the duration (see `rt` module docs).

use crate::drive::{Drive, DriveConfig, FastTick};
use crate::hal::power::Measurements;

/// Everything tier 1 keeps between periods.
pub type FastState = Drive;

/// The drive as it starts: outputs off, not calibrated.
pub fn new_drive() -> Drive {
    Drive::new(DriveConfig::default())
}

/// One current-loop period. Not inlined: tier 1 measures exactly this call.
#[inline(never)]
pub fn fast_tick(m: &Measurements, drive: &mut Drive) -> FastTick {
    drive.fast_tick(m)
}

/// One velocity/position-loop period.
#[inline(never)]
pub fn slow_tick(drive: &mut Drive) {
    drive.slow_tick();
}
