//! Tier 2: the 2.5 kHz loops on an embassy `InterruptExecutor`, run from a spare interrupt vector
//! ([`Interrupt::Tier2`]) below tier 1's priority. Tier 1 raises [`SLOW_TICK`] every tenth period; the wake
//! enqueues the slow task and pends the executor's interrupt, which runs as soon as tier 1 returns.

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_executor::{InterruptExecutor, SendSpawner};

use super::app;
use super::signal::TickSignal;
use crate::board::vectors::Interrupt;

/// Raised by tier 1 every `SLOW_TICK_DIVIDER` fast ticks. Writer: tier 1; waiter: the slow loop task.
pub static SLOW_TICK: TickSignal = TickSignal::new();
/// Slow ticks run. Writer: tier 2.
pub static SLOW_TICKS: AtomicU32 = AtomicU32::new(0);
/// Largest slow-tick cost seen, including the critical section around it (counter units). Writer: tier 2.
pub static SLOW_TICK_MAX: AtomicU32 = AtomicU32::new(0);
/// Largest cost of the background step (parameter conversion, hardware supervision, actual values) run before
/// each slow tick, including its critical section (counter units). Writer: tier 2.
pub static BACKGROUND_MAX: AtomicU32 = AtomicU32::new(0);
/// Slow ticks missed because the previous one had not finished (tier 2 overrun). Writer: tier 2.
pub static SLOW_MISSED: AtomicU32 = AtomicU32::new(0);

static EXECUTOR: InterruptExecutor = InterruptExecutor::new();

/// The executor's interrupt vector.
///
/// # Safety
/// Only the vector table calls this (`board::vectors`), on the interrupt `start` registered the executor on.
pub unsafe extern "C" fn on_interrupt() {
    // SAFETY: see `# Safety`.
    unsafe { EXECUTOR.on_interrupt() }
}

/// Starts the executor on [`Interrupt::Tier2`] (unmasking it) and spawns the slow loop. Call once, from
/// start-up, after the interrupt's priority is set.
pub(crate) fn start() -> SendSpawner {
    let spawner = EXECUTOR.start(Interrupt::Tier2);
    match slow_loop() {
        Ok(token) => spawner.spawn(token),
        Err(_) => super::halt("tier 2: slow loop already spawned"),
    }
    spawner
}

/// The 2.5 kHz loop: waits for tier 1's tick, runs the slow tick, hands over to tier 3.
#[embassy_executor::task]
async fn slow_loop() {
    // Ticks raised before this task first ran are not missed ones: start counting from now.
    let mut seen = SLOW_TICK.raised();
    loop {
        let new = SLOW_TICK.wait(&mut seen).await;
        if new > 1 {
            let missed = new.wrapping_sub(1);
            SLOW_MISSED.store(SLOW_MISSED.load(Ordering::Relaxed).wrapping_add(missed), Ordering::Relaxed);
            // The loops lost their period: a fault (0xFF0B), not only a counter.
            let _ = super::tier1::with_drive_timed(
                |drive| drive.motion_loop_overrun(missed),
                &super::tier1::MASKED_MAX_TIER2,
            );
        }
        let cost = super::tier1::with_drive_timed(app::background, &super::tier1::MASKED_MAX_TIER2)
            .map_or(0, |(_, cost)| cost);
        if cost > BACKGROUND_MAX.load(Ordering::Relaxed) {
            BACKGROUND_MAX.store(cost, Ordering::Relaxed);
        }
        let cost =
            super::tier1::with_drive_timed(app::slow_tick, &super::tier1::MASKED_MAX_TIER2).map_or(0, |(_, cost)| cost);
        if cost > SLOW_TICK_MAX.load(Ordering::Relaxed) {
            SLOW_TICK_MAX.store(cost, Ordering::Relaxed);
        }
        // The free-run process-data cycle (EtherCAT, feature `ethercat`): after the slow tick, as the other cycle
        // sources run between slow ticks.
        #[cfg(all(feature = "ethercat", not(feature = "qemu")))]
        super::ethercat::free_run_tick();
        SLOW_TICKS.store(SLOW_TICKS.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
        super::tier3::TICK.raise();
    }
}
