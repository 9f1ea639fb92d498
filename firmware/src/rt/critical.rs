//! The `critical-section` implementation of both images (the crate's `set_impl!`): what embassy's executor, defmt's
//! RTT logger and the semihosting output use for their short exclusive sections.
//!
//! Before the runtime starts its tiers (and in the bootloader, which has none) a section masks every interrupt
//! (PRIMASK), as the single-core implementation of `cortex-m` does. Once [`tiers_running`] has been called, a section
//! raises BASEPRI to tier 2's priority instead: it keeps out tier 2, the interrupts that share its priority and
//! tier 3, and never tier 1, so no library's section delays the current loop (issue 16: nothing but a hand-off
//! primitive may hold tier 1 off).
//!
//! That is sound because tier 1 uses no critical section: it shares only the hand-off blocks (atomics) and raises
//! tier 2 through an atomic signal and embassy's atomic run queue (`signal::TickSignal`; on a core with atomics
//! embassy's wake path takes no critical section). Code that runs in tier 1 must keep it that way.

use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::register::{basepri, basepri_max, primask};

/// Set once the tiers run: sections use the tier-2 ceiling from then on.
static TIERS_RUNNING: AtomicBool = AtomicBool::new(false);

/// Switches critical sections to the tier-2 ceiling. Call once, from start-up, after the priorities are set and
/// before any interrupt of tier 2 or below is unmasked (no section is open then).
pub(crate) fn tiers_running() {
    TIERS_RUNNING.store(true, Ordering::SeqCst);
}

/// The restore state's flag for a BASEPRI section; the low four bits hold the previous BASEPRI's priority bits.
const CEILING: u8 = 0x80;
/// The restore state of a PRIMASK section entered with interrupts enabled (the other PRIMASK state is 0).
const PRIMASK_WAS_ENABLED: u8 = 0x01;

struct TierCeiling;
critical_section::set_impl!(TierCeiling);

// SAFETY: `acquire` excludes every context that takes a section (tiers 2 and 3 and the interrupts at tier 2's
// priority once the tiers run; every interrupt before) until the matching `release`, which restores exactly the state
// `acquire` found, so sections nest. Tier 1 takes none (module documentation).
// Out of line: one copy for every section in the image (inlined, both modes would be copied into each).
unsafe impl critical_section::Impl for TierCeiling {
    #[inline(never)]
    unsafe fn acquire() -> u8 {
        if TIERS_RUNNING.load(Ordering::Relaxed) {
            let previous = basepri::read();
            // Raises only: inside a section (or a higher ceiling) BASEPRI stays as it is.
            basepri_max::write(super::TIER2_PRIORITY);
            core::sync::atomic::compiler_fence(Ordering::SeqCst);
            CEILING | (previous >> 4)
        } else {
            let was_enabled = primask::read().is_active();
            cortex_m::interrupt::disable();
            core::sync::atomic::compiler_fence(Ordering::SeqCst);
            if was_enabled {
                PRIMASK_WAS_ENABLED
            } else {
                0
            }
        }
    }

    #[inline(never)]
    unsafe fn release(state: u8) {
        core::sync::atomic::compiler_fence(Ordering::SeqCst);
        if state & CEILING != 0 {
            // SAFETY: restores the BASEPRI `acquire` found (sections nest, so no enclosing ceiling is lowered).
            unsafe { basepri::write((state & 0x0F) << 4) };
        } else if state == PRIMASK_WAS_ENABLED {
            // SAFETY: interrupts were enabled when the matching `acquire` disabled them.
            unsafe { cortex_m::interrupt::enable() };
        }
    }
}
