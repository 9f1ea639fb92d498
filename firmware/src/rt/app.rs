//! The glue between the runtime and the pure library: what tier 1 and tier 2 call, and their state; the boot path
//! that loads the stored parameters before the drive exists; tier 3's SDO access to the drive.
//!
//! Tier 1 runs [`Tier1State::fast_tick`] (protection, scaling, commutation angle,
//! `control::current_loop::foc_step`) on the state it owns, after taking the blocks the drive published; tier 2
//! runs [`Drive::background`] and [`Drive::slow_tick`] on the [`Drive`], which tier 2 and tier 3 reach through
//! `tier2::with_drive` (a lock up to tier 2's priority that never masks tier 1; see `rt` module docs).
//!
//! # Parameters
//! [`boot`] runs at start-up, before tier 1 gets the drive: it reads the parameter sectors (PARAMS_A/PARAMS_B,
//! [`ParamFlash`]) and builds the drive from the defaults with the stored record applied ([`Drive::boot`], the same
//! path the host tests and `drive-sim` use). Boot only reads the flash. The store then belongs to tier 3, which
//! erases and programs only through [`sdo_write`] (0x1010 "save", 0x1011 "load"): inside `tier2::with_drive`, with
//! the power stage disabled and no request pending that would switch it on (see `board::flash` for why).

use core::sync::atomic::Ordering;

use crate::board::flash::ParamFlash;
use crate::drive::blocks::Settings;
use crate::drive::objects::BootReport;
use crate::drive::tier1::Tier1State;
use crate::drive::{Drive, DriveConfig, FastTick};
use crate::hal::power::Measurements;
use crate::handoff::Words;
use crate::od::abort::SdoAbort;
use crate::od::access::AccessContext;
use crate::od::store::ParamStore;

/// Everything tier 1 keeps between periods.
pub type FastState = Tier1State;

/// The parameter store on the board's flash (owned by tier 3 after boot).
pub type Params = ParamStore<ParamFlash>;

/// What start-up hands to the tiers.
#[derive(Debug)]
pub struct Boot {
    /// The drive, outputs off: to tier 1.
    pub drive: Drive,
    /// The parameter store: to tier 3 (`None` in the QEMU image, or if the flash driver was already taken).
    pub params: Option<Params>,
    /// What the parameter load found (`None` when nothing was loaded).
    pub report: Option<BootReport>,
}

/// The drive as it starts: defaults, then the parameters stored in flash, then the drive built from those values
/// (outputs off, not calibrated).
pub fn boot() -> Boot {
    let config = DriveConfig::default();
    // QEMU's netduinoplus2 does not emulate the flash interface (FLASH_KEYR/SR/CR, target-qemu.md), so the QEMU
    // image neither loads nor saves parameters: it boots with the defaults, which also keeps its instruction
    // counts independent of any flash contents.
    #[cfg(feature = "qemu")]
    let params: Option<Params> = None;
    #[cfg(not(feature = "qemu"))]
    let params = ParamFlash::take().map(ParamStore::new);
    match params {
        Some(mut params) => {
            let (drive, report) = Drive::boot(config, &mut params);
            Boot { drive, params: Some(params), report: Some(report) }
        }
        None => Boot { drive: Drive::new(config), params: None, report: None },
    }
}

/// An SDO download of a whole value from tier 3, through the drive's application objects: 0x1010 "save" and
/// 0x1011 "load" erase and program the parameter flash here. Runs inside `tier2::with_drive`: the drive's
/// power-stage state (with the requests tier 1 has not yet acted on) is checked in the same section (0x0800_0022
/// while it is switched on), and no new request can be made until the flash work is done, so the power stage stays
/// off while the flash stalls the core (tier 1 then loses periods with its outputs off, which it does not count as
/// a fault). 0x0800_0022 as well before tier 2 has the drive.
pub fn sdo_write(params: &mut Params, index: u16, sub: u8, data: &[u8], ctx: AccessContext) -> Result<(), SdoAbort> {
    super::tier2::with_drive(|drive| drive.sdo_write(index, sub, data, ctx, params))
        .unwrap_or(Err(SdoAbort::DeviceState))
}

/// One current-loop period: the blocks the drive published since the last period (settings first), then the fast
/// tick. Not inlined: tier 1 measures exactly this call. `settings_epoch` and `setpoint_epoch` are the epochs of
/// the blocks taken last; a block is decoded only when its epoch moved on (one load and a compare otherwise).
#[inline(never)]
pub fn fast_tick(
    m: &Measurements,
    t1: &mut Tier1State,
    settings_epoch: &mut u32,
    setpoint_epoch: &mut u32,
) -> FastTick {
    // Each epoch is loaded once: its block is the one of that epoch (`Command::block_of`), as `front` would give
    // with a second load and barrier.
    let epoch = super::tier1::SETTINGS.epoch();
    if epoch != *settings_epoch {
        // The words loaded straight into the decoder's input: `Command::read` zeroes an array, loads the words in a
        // loop and copies them again into its result, about 100 instructions more in the period that takes new
        // settings, tier 1's longest (the room the data recorder's copy below takes).
        let words = super::tier1::SETTINGS.block_of(epoch).each_ref().map(|cell| cell.load(Ordering::Relaxed));
        *settings_epoch = epoch;
        t1.apply_settings(&<Settings as Words<15>>::from_words(&words));
    }
    let epoch = super::tier1::SETPOINT.epoch();
    if epoch != *setpoint_epoch {
        // The words of `SetPoint::to_words`. A block for a later period stays unread (its epoch not taken) until
        // that period: read again then.
        let [version, power, i_q, i_d, apply_from] = super::tier1::SETPOINT.block_of(epoch);
        let apply_from = apply_from.load(Ordering::Relaxed);
        if t1.setpoint_due(apply_from) {
            *setpoint_epoch = epoch;
            let (version, power, i_q, i_d) = (
                version.load(Ordering::Relaxed),
                power.load(Ordering::Relaxed),
                i_q.load(Ordering::Relaxed),
                i_d.load(Ordering::Relaxed),
            );
            t1.apply_setpoint_words(&[version, power, i_q, i_d, apply_from]);
        }
    }
    t1.fast_tick(m)
}

/// One velocity/position-loop period. Not inlined: tier 2 measures exactly this call.
#[inline(never)]
pub fn slow_tick(drive: &mut Drive) {
    drive.slow_tick();
}

/// The parameter conversion tier 2 runs before each slow tick (measured separately), and the braking chopper's
/// gate it decided.
#[inline(never)]
pub fn background(drive: &mut Drive) {
    drive.background();
    crate::board::chopper::set_gate(drive.chopper_gate());
}
