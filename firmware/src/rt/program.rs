//! Program control on the board (issue 7): the application's side of a firmware update over the internal flash
//! (`board::boot`: slot A, slot B, BOOT_STATE), owned by tier 3 like the parameter store. Not in the QEMU image
//! (QEMU does not emulate the flash interface, `target-qemu.md`).
//!
//! * **Start-up** ([`start`]): the running image as the bootloader left it (`boot::loader::running_image`: the
//!   header of slot A, and whether the state log says it runs on trial), handed to
//!   [`ProgramControl::started`], so that 0x1F56 reports this image, and its version string shown in 0x100A
//!   (`boot::tables::show_software_version`).
//! * **Confirmation** ([`confirm_when_healthy`], tier 3): an image on trial confirms itself once the tiers have
//!   run for [`CONFIRM_AFTER_TICKS`] slow ticks (1 s) without a lost period and with the power stage disabled.
//!   "A successful start" is then more than reaching `main`: the clock, the parameter load, and tiers 1 and 2
//!   ran for a second. An image that faults or hangs before that is reverted by the bootloader at the next reset
//!   (`boot::loader`). The confirmation appends one record to BOOT_STATE (four word programs, about 64 us during
//!   which every flash fetch stalls): it runs inside `tier2::with_drive`, and only with the power stage
//!   disabled, so no PWM period with live outputs is lost to it.
//! * **Requests** ([`follow`]): after each fieldbus poll, a stop or start switches the dictionary's table
//!   ([`BOOTLOADER_TABLE`]: the reduced object set, device type 0x0000_012E), a reset (0x1F51 = 1 with a verified
//!   image, 0x1F51 = 2, leaving BOOT after an FoE download) resets the microcontroller: the bootloader swaps the
//!   pending image in.
//!
//! Flash timing: *clear* erases slot B's image area (three 128 KiB sectors, 1 to 2 s each, RM0090 / datasheet
//! t_ERASE128KB), a download programs it word by word; the core stalls on every flash fetch meanwhile, so tiers 1
//! and 2 stop for that time. Program control accepts these only with the power stage disabled (0x1F51 stop
//! requires it, E4 "prepare controller"), so the outputs are off throughout; a master's SDO timeout for the
//! clear must cover the erase (several seconds).

#[cfg(not(feature = "qemu"))]
use core::cell::RefCell;

use crate::board::boot::UpdateRegion;
use crate::boot::program::ProgramControl;
#[cfg(not(feature = "qemu"))]
use crate::{
    board::boot::update_flash,
    boot::loader::running_image,
    boot::program::Request,
    boot::tables::{show_software_version, APPLICATION_TABLE, BOOTLOADER_TABLE},
    boot::verify::DEVICE_TRUST,
    drive::Drive,
};

/// Program control over the board's update regions.
pub type BoardProgram = ProgramControl<UpdateRegion, UpdateRegion, UpdateRegion>;

/// Slow ticks (400 us) of healthy running before an image on trial confirms itself: 1 s.
pub const CONFIRM_AFTER_TICKS: u32 = 2_500;

/// Program control for the image that runs, or `None` if the update regions were already taken (only the
/// bootloader takes them, in another image). Call once at start-up, before tier 1 has the drive; `drive`'s
/// dictionary is switched to the application's table.
#[cfg(not(feature = "qemu"))]
pub(crate) fn start(drive: &mut Drive) -> Option<RefCell<BoardProgram>> {
    let mut flash = update_flash()?;
    let outcome = running_image(&mut flash.slot_a, &mut flash.state, &DEVICE_TRUST);
    let mut program = ProgramControl::new(flash, DEVICE_TRUST);
    program.started(outcome);
    drive.dictionary_mut().set_table(APPLICATION_TABLE);
    if let Some(header) = program.running() {
        show_software_version(drive.dictionary_mut(), header.version_str());
    }
    Some(RefCell::new(program))
}

/// Tier 3, every tick: confirms an image on trial once `healthy_ticks` slow ticks have passed without a lost
/// period (the caller counts them), with the power stage disabled, inside `tier2::with_drive`. Returns whether
/// the image is confirmed (or was never on trial). A failing confirmation (flash error, full log) is retried at
/// the next tick.
#[cfg(not(feature = "qemu"))]
pub(crate) fn confirm_when_healthy(program: &RefCell<BoardProgram>, healthy_ticks: u32) -> bool {
    let Ok(mut p) = program.try_borrow_mut() else { return false };
    if !p.on_trial() {
        return true;
    }
    if healthy_ticks < CONFIRM_AFTER_TICKS {
        return false;
    }
    super::tier2::with_drive(|drive| !drive.power_stage_enabled() && p.confirm().is_ok()).unwrap_or(false)
}

/// Acts on program control's request after a fieldbus poll (the CAN node's, the EtherCAT slave's), with the
/// drive (inside `tier2::with_drive`). Returns `true` when the request is a reset: the power stage is then already
/// in its safe state, and the caller resets ([`reset`]) once its answer has left (the SDO response to 0x1F51 is
/// still in the CAN controller's mailboxes at this point).
#[cfg(not(feature = "qemu"))]
#[must_use]
pub(crate) fn follow(program: &RefCell<BoardProgram>, drive: &mut Drive) -> bool {
    let request = program.try_borrow_mut().ok().and_then(|mut p| p.take_request());
    match request {
        Some(Request::Stop) => drive.dictionary_mut().set_table(BOOTLOADER_TABLE),
        Some(Request::Start) => drive.dictionary_mut().set_table(APPLICATION_TABLE),
        Some(Request::Reset) => {
            crate::board::safe_state();
            return true;
        }
        None => {}
    }
    false
}

/// The reset program control asked for: the bootloader runs next and swaps a pending image in.
#[cfg(not(feature = "qemu"))]
pub(crate) fn reset() -> ! {
    crate::board::safe_state();
    cortex_m::peripheral::SCB::sys_reset()
}
