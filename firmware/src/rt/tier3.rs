//! Tier 3: thread mode, the embassy thread executor. Sleeps (WFE) whenever nothing is ready.
//!
//! On the board its supervisor task reports health once a second over defmt (when enabled); the
//! mailbox/SDO, NMT, heartbeat, EMCY and parameter tasks join it as they are written. In the QEMU image the
//! bench task runs here instead.

use embassy_executor::{Executor, Spawner};

use super::signal::TickSignal;

/// Raised by tier 2 after every slow tick. Writer: tier 2; waiter: the tier-3 supervisor.
pub static TICK: TickSignal = TickSignal::new();

/// Runs the thread executor forever with the tier-3 tasks.
pub(crate) fn run() -> ! {
    let Some(executor) = cortex_m::singleton!(: Executor = Executor::new()) else {
        super::halt("tier 3: executor already running");
    };
    executor.run(spawn_tasks)
}

fn spawn_tasks(spawner: Spawner) {
    #[cfg(not(feature = "qemu"))]
    match supervisor() {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 3: supervisor already spawned"),
    }
    #[cfg(feature = "qemu")]
    match super::bench::bench() {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 3: bench already spawned"),
    }
}

/// Watches the other tiers: logs their health once a second (2,500 slow ticks).
#[cfg(not(feature = "qemu"))]
#[embassy_executor::task]
async fn supervisor() {
    const REPORT_EVERY: u32 = 2_500;
    let mut seen = 0;
    let mut since_report = 0u32;
    loop {
        since_report = since_report.wrapping_add(TICK.wait(&mut seen).await);
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
