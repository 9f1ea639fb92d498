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
//! programmed, through [`app::sdo_write`] (inside `tier1::with_drive`, power stage disabled; see `board::flash`).
//! Until the mailbox/SDO task exists to take it over, the supervisor holds it, so nothing else reaches the flash.

use embassy_executor::{Executor, Spawner};

use super::app;
use super::signal::TickSignal;

/// Raised by tier 2 after every slow tick. Writer: tier 2; waiter: the tier-3 supervisor.
pub static TICK: TickSignal = TickSignal::new();

/// Runs the thread executor forever with the tier-3 tasks; `params` is the parameter store from boot.
pub(crate) fn run(params: Option<app::Params>) -> ! {
    let Some(executor) = cortex_m::singleton!(: Executor = Executor::new()) else {
        super::halt("tier 3: executor already running");
    };
    let Some(params) = cortex_m::singleton!(: Option<app::Params> = params) else {
        super::halt("tier 3: parameter store already placed");
    };
    executor.run(|spawner| spawn_tasks(spawner, params))
}

fn spawn_tasks(spawner: Spawner, params: &'static mut Option<app::Params>) {
    #[cfg(feature = "qemu")]
    let _ = params;
    #[cfg(not(feature = "qemu"))]
    match supervisor(params) {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 3: supervisor already spawned"),
    }
    #[cfg(feature = "qemu")]
    match super::bench::bench() {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 3: bench already spawned"),
    }
}

/// Watches the other tiers: logs their health once a second (2,500 slow ticks). Holds the parameter store until
/// the mailbox/SDO task takes it over.
#[cfg(not(feature = "qemu"))]
#[embassy_executor::task]
async fn supervisor(_params: &'static mut Option<app::Params>) {
    const REPORT_EVERY: u32 = 2_500;
    let mut seen = 0;
    let mut since_report = 0u32;
    // Tier-3 ticks since start (400 us each): the EtherCAT slave's millisecond clock.
    #[cfg(feature = "ethercat")]
    let mut ticks_total = 0u64;
    loop {
        let new = TICK.wait(&mut seen).await;
        since_report = since_report.wrapping_add(new);
        // The EtherCAT slave's tier-3 work, every tick, with the parameter store (`super::ethercat`).
        #[cfg(feature = "ethercat")]
        {
            ticks_total = ticks_total.wrapping_add(u64::from(new));
            let now_ms = ticks_total.wrapping_mul(2).checked_div(5).unwrap_or(0) as u32;
            super::ethercat::poll(_params, now_ms);
        }
        if since_report >= REPORT_EVERY {
            since_report = 0;
            crate::rt_info!(
                "alive: fast max {=u32} {=str}, overrun {=bool}, slow missed {=u32}",
                super::tier1::FAST_TICK_MAX.load(core::sync::atomic::Ordering::Relaxed),
                crate::board::counter::UNIT,
                super::tier1::OVERRUN.load(core::sync::atomic::Ordering::Relaxed),
                super::tier2::SLOW_MISSED.load(core::sync::atomic::Ordering::Relaxed)
            );
        }
    }
}
