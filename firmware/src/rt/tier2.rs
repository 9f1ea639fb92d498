//! Tier 2: the 2.5 kHz loops on an embassy `InterruptExecutor`, run from a spare interrupt vector
//! ([`Interrupt::Tier2`]) below tier 1's priority. Tier 1 raises [`SLOW_TICK`] every tenth period; the wake
//! enqueues the slow task and pends the executor's interrupt, which runs as soon as tier 1 returns.
//!
//! Tier 2 owns the drive ([`Drive`]): the slow loop, the EtherCAT cycle interrupts (tier 2's priority) and tier 3
//! reach it through [`with_drive`], inside a critical section, which once the tiers run raises BASEPRI to tier 2's
//! priority (`rt::critical`). It keeps out everything of that priority and below, and never tier 1. When a section ends, the blocks the drive changed go to tier 1
//! (`tier1::SETTINGS`, `tier1::SETPOINT`): every publication happens inside the lock, so the double buffers have
//! one writer at a time, and a request made in a section (a class-d forced off included) reaches tier 1 in the
//! first period that starts after it; what the loops decide in the slow tick, from the fixed period the
//! set-point names (`crate::drive::Drive`, "Hand-off timing").

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_executor::{InterruptExecutor, SendSpawner};

use super::app;
use super::figures::{count, record_max};
use super::signal::TickSignal;
use crate::board::counter;
use crate::board::interrupt::Interrupt;
use crate::drive::Drive;
use crate::recorder::Recorder;

/// Raised by tier 1 every `SLOW_TICK_DIVIDER` fast ticks. Writer: tier 1; waiter: the slow loop task.
pub static SLOW_TICK: TickSignal = TickSignal::new();
/// Slow ticks run. Writer: tier 2.
pub static SLOW_TICKS: AtomicU32 = AtomicU32::new(0);
/// Largest slow-tick cost seen, with the lock and the publications around it (counter units). Writer: tier 2.
pub static SLOW_TICK_MAX: AtomicU32 = AtomicU32::new(0);
/// Largest cost of the background step (parameter conversion, hardware supervision, actual values) run before
/// each slow tick, with the report taken over, the lock and the publications (counter units). Writer: tier 2.
pub static BACKGROUND_MAX: AtomicU32 = AtomicU32::new(0);
/// Slow ticks missed because the previous one had not finished (tier 2 overrun). Writer: tier 2.
pub static SLOW_MISSED: AtomicU32 = AtomicU32::new(0);
/// Largest whole tier-2 step of one slow period: the report taken, the background step, the slow tick and the
/// free-run cycle (counter units). Writer: tier 2.
pub static TIER2_TOTAL_MAX: AtomicU32 = AtomicU32::new(0);
/// Largest number of periods that started between the raise of a slow tick and the end of its slow tick (the
/// set-point published): 0 means it was published before the next period began. What the loops decided applies
/// from a fixed period (`crate::drive::blocks::LOOP_SETPOINT_DELAY_PERIODS`), the same on the host, so this must
/// not exceed that delay (the QEMU test holds it to it). Writer: tier 2.
pub static SETPOINT_PERIODS_LATE_MAX: AtomicU32 = AtomicU32::new(0);
/// The data recorder (`crate::recorder`): tier 2 gives it the object channels' values after each slow tick, tier 3
/// drains tier 1's ring into it ([`drain_recorder`]) and its SDO servers configure and upload it through the
/// application-objects port, all under the tier-2 lock. Placed at start-up with its sample memory
/// (`rt::RECORDER_BUFFER`).
pub static RECORDER: Tier2Slot<Recorder> = Tier2Slot::new();
/// Reports that could not be read whole ([`crate::handoff::Torn`]: tier 2 was held off for a whole slow period in
/// the middle of its copy); the drive then keeps the previous one. Writer: tier 2.
pub static REPORTS_TORN: AtomicU32 = AtomicU32::new(0);

/// A value tier 2 and tier 3 share, reached only through [`Tier2Slot::with`] (inside a critical section: the tier-2
/// ceiling).
pub struct Tier2Slot<T> {
    value: UnsafeCell<MaybeUninit<T>>,
    /// Set once the value is in place.
    ready: AtomicBool,
    /// Set while a section holds the value: a nested `with` on the same slot gets `None`.
    busy: AtomicBool,
}

// SAFETY: the value is reached only inside `with`, which runs in a critical section (`rt::critical`: nothing of tier
// 2's priority or below runs meanwhile, and tier 1 never touches a slot) and refuses a nested entry (`busy`); `place`
// writes it once, before `ready`.
unsafe impl<T: Send> Sync for Tier2Slot<T> {}

impl<T> Tier2Slot<T> {
    /// An empty slot.
    pub const fn new() -> Self {
        Self {
            value: UnsafeCell::new(MaybeUninit::uninit()),
            ready: AtomicBool::new(false),
            busy: AtomicBool::new(false),
        }
    }

    /// Places the value (once, at start-up; a second call does nothing).
    pub fn place(&self, value: T) {
        critical_section::with(|_| {
            if self.ready.load(Ordering::Relaxed) {
                return;
            }
            // SAFETY: inside the lock and not yet ready: nobody else reaches the cell.
            unsafe { (*self.value.get()).write(value) };
            self.ready.store(true, Ordering::Relaxed);
        });
    }

    /// Runs `f` on the value inside a critical section (the tier-2 ceiling once the tiers run). `None` before
    /// [`Self::place`], or when called from inside a section that already holds this slot.
    pub fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> Option<R> {
        self.with_or_none(|value| value.map(f))
    }

    /// Runs `f` inside a critical section with the value, or with `None` before [`Self::place`] or when called
    /// from inside a section that already holds this slot.
    pub fn with_or_none<R>(&self, f: impl FnOnce(Option<&mut T>) -> R) -> R {
        critical_section::with(|_| {
            if !self.ready.load(Ordering::Relaxed) || self.busy.swap(true, Ordering::Relaxed) {
                return f(None);
            }
            // SAFETY: see `Sync` above: inside the lock, placed, and not held by an enclosing section.
            let result = f(Some(unsafe { (*self.value.get()).assume_init_mut() }));
            self.busy.store(false, Ordering::Relaxed);
            result
        })
    }
}

impl<T> Default for Tier2Slot<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// The drive, tier 2's.
static DRIVE: Tier2Slot<Drive> = Tier2Slot::new();

/// Places the drive and publishes its first blocks. Call once from start-up, before tier 1 starts.
pub(crate) fn place_drive(drive: Drive) {
    DRIVE.place(drive);
    let _ = with_drive(|_| ());
}

/// Runs `f` on the drive inside the tier-2 lock, then hands the blocks it changed to tier 1 (module
/// documentation). `None` before start-up placed the drive, or when nested inside another `with_drive`.
pub fn with_drive<R>(f: impl FnOnce(&mut Drive) -> R) -> Option<R> {
    DRIVE.with(|drive| {
        let result = f(drive);
        publish_blocks(drive);
        result
    })
}

/// Hands the blocks the drive changed to tier 1 (settings first). One copy for every caller of [`with_drive`].
#[inline(never)]
fn publish_blocks(drive: &mut Drive) {
    if let Some(settings) = drive.take_settings() {
        super::tier1::SETTINGS.publish(&settings);
    }
    if let Some(setpoint) = drive.take_setpoint() {
        super::tier1::SETPOINT.publish(&setpoint);
    }
}

/// Gives the drive tier 1's report of the slow-tick boundary that raised this tick, or counts a torn read (the
/// drive then keeps the previous report).
#[inline(never)]
fn take_report(drive: &mut Drive) {
    match super::tier1::REPORT.read() {
        Ok(report) => drive.receive_report(&report.block),
        Err(_) => count(&REPORTS_TORN, 1),
    }
}

/// The recorder's object channels from the drive's dictionary (a few loads: the drain runs in tier 3).
#[inline(never)]
fn record_objects(drive: &mut Drive) {
    let _ = RECORDER.with(|recorder| recorder.take_objects(drive.dictionary().values().bytes()));
}

/// Snapshots of tier 1's ring the recorder's drain takes per section: with 8 channels about 1,500 instructions
/// (`insn.recorder_drain_8ch` is ten of them), the longest tier 3 holds tier 2 off for it.
const DRAIN_SNAPSHOTS_PER_SECTION: u32 = 4;

/// Tier 3: drains tier 1's ring (`tier1::RECORDER_RING`) into the recorder, [`DRAIN_SNAPSHOTS_PER_SECTION`] at a
/// time under the tier-2 lock, until it is empty.
pub fn drain_recorder() {
    let ring = &super::tier1::RECORDER_RING;
    while RECORDER.with(|recorder| recorder.drain(ring, DRAIN_SNAPSHOTS_PER_SECTION)) == Some(true) {}
}

/// [`with_drive`] timed in counter units (the section and the publications).
fn with_drive_timed<R>(f: impl FnOnce(&mut Drive) -> R, max: &AtomicU32) -> Option<R> {
    let start = counter::now();
    let result = with_drive(f);
    record_max(max, counter::now().wrapping_sub(start));
    result
}

static EXECUTOR: InterruptExecutor = InterruptExecutor::new();

/// The executor's interrupt vector.
///
/// # Safety
/// Only the vector table calls this (`rt::vectors`), on the interrupt `start` registered the executor on.
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
        let start = counter::now();
        if new > 1 {
            let missed = new.wrapping_sub(1);
            count(&SLOW_MISSED, missed);
            // The loops lost their period: a fault (0xFF0B), not only a counter.
            let _ = with_drive(|drive| drive.motion_loop_overrun(missed));
        }
        // The report of the period that raised this tick (tier 1 published it before the raise); both steps read it.
        // The STO inputs and the load encoder are read here, in tier 2, for the same period: the hardware already
        // gates the bridge, the drive only has to follow within the slow period (`supervision::safe_torque_off`).
        let _ = with_drive_timed(
            |drive| {
                take_report(drive);
                drive.set_sto_inputs(crate::board::sto::read());
                drive.set_load_encoder_count(crate::board::load_encoder::read());
                app::background(drive);
            },
            &BACKGROUND_MAX,
        );
        let _ = with_drive_timed(app::slow_tick, &SLOW_TICK_MAX);
        let raised_at = super::tier1::SLOW_TICK_RAISED_AT.load(Ordering::Relaxed);
        record_max(
            &SETPOINT_PERIODS_LATE_MAX,
            super::tier1::FAST_TICKS.load(Ordering::Relaxed).wrapping_sub(raised_at),
        );
        // The master's positions and velocities of this slow tick in its units (polarity, gear), once the set-point
        // is out; before the recorder and the process data read them.
        let _ = with_drive(crate::drive::Drive::publish_master_values);
        // The data recorder's object channels of this slow period: after the set-point is published.
        let _ = with_drive(record_objects);
        // The free-run process-data cycle (EtherCAT, feature `ethercat`): after the slow tick, as the other cycle
        // sources run between slow ticks.
        #[cfg(all(feature = "ethercat", not(feature = "qemu")))]
        super::ethercat::free_run_tick();
        record_max(&TIER2_TOTAL_MAX, counter::now().wrapping_sub(start));
        count(&SLOW_TICKS, 1);
        super::tier3::TICK.raise();
    }
}
