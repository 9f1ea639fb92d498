//! Tier 3: thread mode, the embassy thread executor. Sleeps (WFE) whenever nothing is ready.
//!
//! With the feature `ethercat` the supervisor also runs the EtherCAT slave's poll every tick and lends it the
//! parameter store (`rt::ethercat`).
//!
//! On the board its supervisor task reports health once a second over defmt (when enabled); the
//! mailbox/SDO, NMT, heartbeat, EMCY and parameter tasks join it as they are written. In the QEMU image the
//! bench task runs here instead.
//!
//! Tier 3 owns the parameter store ([`app::Params`]) after boot: the only place the parameter flash is erased or
//! programmed, through [`app::sdo_write`] (inside `tier2::with_drive`, power stage disabled; see `board::flash`).
//! Until the mailbox/SDO task exists to take it over, the supervisor holds it, so nothing else reaches the flash.

use core::cell::RefCell;

use embassy_executor::{Executor, Spawner};

use super::app;
use super::program::BoardProgram;
use super::signal::TickSignal;

/// Raised by tier 2 after every slow tick. Writer: tier 2; waiter: the tier-3 supervisor.
pub static TICK: TickSignal = TickSignal::new();

/// Program control for the running image (`None` in the QEMU image).
pub(crate) type Program = Option<RefCell<BoardProgram>>;

/// The CANopen node (`None` in the QEMU image, or when CAN did not come up).
#[cfg(not(feature = "qemu"))]
pub(crate) type Can = Option<super::canopen::Canopen>;
/// The CANopen node: none in the QEMU image (no bxCAN).
#[cfg(feature = "qemu")]
pub(crate) type Can = Option<core::convert::Infallible>;

/// Runs the thread executor forever with the tier-3 tasks; `params` is the parameter store from boot, `program`
/// program control of the running image, `can` the CANopen node.
pub(crate) fn run(params: Option<app::Params>, program: Program, can: Can) -> ! {
    let Some(executor) = cortex_m::singleton!(: Executor = Executor::new()) else {
        super::halt("tier 3: executor already running");
    };
    let Some(params) = cortex_m::singleton!(: Option<app::Params> = params) else {
        super::halt("tier 3: parameter store already placed");
    };
    let Some(program) = cortex_m::singleton!(: Program = program) else {
        super::halt("tier 3: program control already placed");
    };
    let Some(can) = cortex_m::singleton!(: Can = can) else {
        super::halt("tier 3: CAN node already placed");
    };
    executor.run(|spawner| spawn_tasks(spawner, params, program, can))
}

fn spawn_tasks(
    spawner: Spawner,
    params: &'static mut Option<app::Params>,
    program: &'static Program,
    can: &'static mut Can,
) {
    #[cfg(feature = "qemu")]
    let _ = (params, program, can);
    #[cfg(not(feature = "qemu"))]
    match supervisor(params, program, can) {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 3: supervisor already spawned"),
    }
    #[cfg(feature = "qemu")]
    match super::bench::bench() {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 3: bench already spawned"),
    }
}

/// Watches the other tiers: feeds the independent watchdog when all three ran (`supervision::watchdog`), logs
/// their health once a second (2,500 slow ticks), and confirms an image on trial
/// once they have run healthily for a second (`program::confirm_when_healthy`). Holds the parameter store and
/// program control, which the EtherCAT slave's poll borrows (feature `ethercat`).
#[cfg(not(feature = "qemu"))]
#[embassy_executor::task]
async fn supervisor(params: &'static mut Option<app::Params>, program: &'static Program, can: &'static mut Can) {
    use core::sync::atomic::Ordering;
    const REPORT_EVERY: u32 = 2_500;
    let mut seen = 0;
    let mut since_report = 0u32;
    // Slow ticks since the last lost period (tier-1 overrun or tier-2 miss): the confirmation's evidence.
    let mut healthy_ticks = 0u32;
    let mut missed_before = super::tier2::SLOW_MISSED.load(Ordering::Relaxed);
    let mut confirmed = program.is_none();
    let mut ticks_total = 0u64;
    let mut liveness = crate::supervision::watchdog::TierLiveness::new(
        super::tier1::FAST_TICKS.load(Ordering::Relaxed),
        super::tier2::SLOW_TICKS.load(Ordering::Relaxed),
    );
    loop {
        let new = TICK.wait(&mut seen).await;
        // Tier 3 runs here; the watchdog is fed only if tiers 1 and 2 ran since the last feed as well.
        if liveness.all_tiers_ran(
            super::tier1::FAST_TICKS.load(Ordering::Relaxed),
            super::tier2::SLOW_TICKS.load(Ordering::Relaxed),
        ) {
            crate::board::watchdog::feed();
        }
        since_report = since_report.wrapping_add(new);
        let missed = super::tier2::SLOW_MISSED.load(Ordering::Relaxed);
        healthy_ticks = if missed != missed_before || super::tier1::OVERRUN.load(Ordering::Relaxed) {
            0
        } else {
            healthy_ticks.saturating_add(new)
        };
        missed_before = missed;
        if !confirmed {
            if let Some(p) = program {
                confirmed = super::program::confirm_when_healthy(p, healthy_ticks);
                if confirmed {
                    crate::rt_info!("image confirmed after {=u32} healthy slow ticks", healthy_ticks);
                }
            }
        }
        // The data recorder's samples of the slow periods since the last tick (tier 1's ring holds 12.8 of them).
        super::tier2::drain_recorder();
        ticks_total = ticks_total.wrapping_add(u64::from(new));
        // The fieldbuses' tier-3 work, every tick, with the parameter store and program control.
        if let Some(can) = can.as_mut() {
            super::canopen::poll(can, params, program.as_ref(), ticks_total.wrapping_mul(400));
        }
        #[cfg(feature = "ethercat")]
        {
            let now_ms = ticks_total.wrapping_mul(2).checked_div(5).unwrap_or(0) as u32;
            super::ethercat::poll(params, program.as_ref(), now_ms);
        }
        if since_report >= REPORT_EVERY {
            since_report = 0;
            crate::rt_info!(
                "alive: fast max {=u32} {=str}, overrun {=bool}, slow missed {=u32}, stack {=u32} of {=u32} bytes",
                super::tier1::FAST_TICK_MAX.load(Ordering::Relaxed),
                crate::board::counter::UNIT,
                super::tier1::OVERRUN.load(Ordering::Relaxed),
                super::tier2::SLOW_MISSED.load(Ordering::Relaxed),
                super::stack::high_water(),
                super::stack::size()
            );
        }
    }
}
