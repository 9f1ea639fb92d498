//! Tier 1: the 25 kHz current loop as a raw interrupt handler (ADC JEOC, highest priority).
//!
//! Each period: read the measurements, call the pure fast tick, write the PWM command, account the cost, and
//! raise tier 2 when the fast tick says a slow tick is due (every `SLOW_TICK_DIVIDER`-th period). No allocation,
//! no logging, no locks, no panics.
//! The fast tick's own cost is measured with the board's cost counter (cycles on the board, instructions under
//! QEMU); the maximum is kept, and a tick over budget trips the drive (outputs off at once, fault 0xFF0B) and
//! latches [`OVERRUN`] for the diagnostics.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{compiler_fence, AtomicBool, AtomicU32, Ordering};

use cortex_m::peripheral::NVIC;

use super::app::{self, FastState};
use crate::board::counter;
use crate::board::vectors::Interrupt;
use crate::board::PowerStage;

/// Cost budget of one fast tick in counter units: half the 6,720-cycle period at 168 MHz, the rest is left to
/// the interrupt entry/exit and tiers 2 and 3.
pub const FAST_TICK_BUDGET: u32 = 3_360;

/// Largest fast-tick cost seen (counter units, overhead subtracted). Writer: tier 1.
pub static FAST_TICK_MAX: AtomicU32 = AtomicU32::new(0);
/// Fast ticks run. Writer: tier 1.
pub static FAST_TICKS: AtomicU32 = AtomicU32::new(0);
/// Latched when a fast tick exceeded `FAST_TICK_BUDGET`. Writer: tier 1 (sets only).
pub static OVERRUN: AtomicBool = AtomicBool::new(false);
/// Longest section with tier 1 masked ([`with_drive`]) entered from thread mode (tier 3), counter units, from
/// before the mask to after it. Writer: tier 3. [`masked_max`] gives the longest of all.
pub static MASKED_MAX_TIER3: AtomicU32 = AtomicU32::new(0);
/// The same for sections entered from an interrupt below tier 1: tier 2's executor and the EtherCAT cycle
/// interrupts, which share tier 2's priority and so never preempt one another. Writer: tier 2's priority (and
/// the QEMU bench, which resets both while tiers 1 and 2 are idle).
pub static MASKED_MAX_TIER2: AtomicU32 = AtomicU32::new(0);
/// Largest time from the period timer's wrap to tier 1's handler (QEMU bench, its SysTick handler).
/// Writer: tier 1.
pub static TIER1_LATENCY_MAX: AtomicU32 = AtomicU32::new(0);
/// Periods of the period timer in which tier 1 did not run (QEMU bench). Writer: tier 1.
pub static FAST_MISSED: AtomicU32 = AtomicU32::new(0);
/// Counter time of the start of the last period tier 1 ran in (QEMU bench). Writer: tier 1, and the bench
/// with the timer stopped.
pub static LAST_UPDATE: AtomicU32 = AtomicU32::new(0);

/// What tier 1 owns.
struct Tier1 {
    power: PowerStage,
    fast: FastState,
    overhead: u32,
}

/// Tier 1's state: written once by [`start`] before the ADC interrupt is unmasked (then `ready`), then used by the
/// ADC handler, and by [`with_drive`] with all interrupts masked.
///
/// `MaybeUninit` and a flag rather than an `Option`: `None` of the drive's type is not all zero bytes (a niche
/// in one of its enums), so an `Option` static would sit in `.data` with a 6 KiB initial image in flash; this one
/// is in `.bss`.
struct Slot {
    state: UnsafeCell<MaybeUninit<Tier1>>,
    ready: AtomicBool,
}

// SAFETY: see `Slot`: one writer before the interrupt is enabled; afterwards the ADC handler (which cannot preempt
// itself) and `with_drive`, which runs with interrupts disabled and so never overlaps the handler or itself.
unsafe impl Sync for Slot {}

impl Slot {
    /// The state, once [`start`] has placed it.
    ///
    /// # Safety
    /// The caller is the ADC handler or runs with interrupts disabled (see `Slot`), and holds no other reference
    /// obtained from this function.
    #[allow(clippy::mut_from_ref)]
    unsafe fn get(&self) -> Option<&mut Tier1> {
        // Relaxed: one core, and `start` sets the flag before it unmasks the ADC interrupt (with compiler fences).
        if !self.ready.load(Ordering::Relaxed) {
            return None;
        }
        // SAFETY: `ready` is set only after `start` wrote the state; exclusivity is the caller's contract.
        Some(unsafe { (*self.state.get()).assume_init_mut() })
    }
}

static TIER1: Slot = Slot { state: UnsafeCell::new(MaybeUninit::uninit()), ready: AtomicBool::new(false) };

/// Hands the power stage and the fast state to tier 1 and unmasks the ADC interrupt. Call once, from start-up,
/// with interrupts of tier 1 still masked.
pub(crate) fn start(power: PowerStage, fast: FastState) {
    let overhead = empty_call_cost();
    NVIC::mask(Interrupt::Adc);
    compiler_fence(Ordering::SeqCst);
    // SAFETY: the ADC interrupt is masked, so its handler (the slot's only other user) cannot run now; `start` runs
    // once, from start-up, before `with_drive` has anything to reach.
    unsafe { (*TIER1.state.get()).write(Tier1 { power, fast, overhead }) };
    TIER1.ready.store(true, Ordering::Relaxed);
    compiler_fence(Ordering::SeqCst);
    // SAFETY: the handler's state is in place; unmasking cannot break a critical section (none is held here).
    unsafe { NVIC::unmask(Interrupt::Adc) };
}

/// The ADC interrupt: one current-loop period.
///
/// # Safety
/// Only the vector table calls this (`board::vectors`): as the ADC handler it never preempts itself, and
/// `with_drive` keeps interrupts off while it holds the state.
pub unsafe extern "C" fn on_adc() {
    // SAFETY: see `# Safety`: no other reference to the slot is live while the handler runs.
    let Some(t) = (unsafe { TIER1.get() }) else {
        // An ADC interrupt before start-up finished: nothing to run; keep the power stage off.
        crate::board::safe_state();
        return;
    };
    let measurements = t.power.read();
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    let tick = app::fast_tick(&measurements, &mut t.fast);
    compiler_fence(Ordering::SeqCst);
    let cost = counter::now().wrapping_sub(start).saturating_sub(t.overhead);
    // A tick over budget cannot keep the 40 us period: the drive trips (outputs off with this very write).
    let pwm = if cost > FAST_TICK_BUDGET {
        OVERRUN.store(true, Ordering::Relaxed);
        t.fast.current_loop_overrun(cost)
    } else {
        tick.pwm
    };
    t.power.write(&pwm);

    if cost > FAST_TICK_MAX.load(Ordering::Relaxed) {
        FAST_TICK_MAX.store(cost, Ordering::Relaxed);
    }
    FAST_TICKS.store(FAST_TICKS.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
    if tick.slow_tick_due {
        super::tier2::SLOW_TICK.raise();
    }
}

/// Runs `f` on tier 1's drive with all interrupts disabled (tier 1 held off for its duration; a conversion that
/// ends meanwhile is served right after). For tier 2's slow tick and tier 3's commands. `None` before `start`.
///
/// This is the interim answer to the drive being one object with a tier-1 and a tier-2 entry point: keep `f` short
/// (its duration adds to tier 1's latency); the QEMU bench reports the slow tick's cost as `insn.slow_tick_max`
/// and the longest such section as `insn.masked_max` ([`masked_max`]).
pub fn with_drive<R>(f: impl FnOnce(&mut FastState) -> R) -> Option<R> {
    with_drive_timed(f, &MASKED_MAX_TIER3).map(|(r, _)| r)
}

/// [`with_drive`] for a caller at tier 2's priority or in tier 3 that also wants to know how long tier 1 was masked
/// (counter units, the two counter reads around the section included), which is recorded in `max`: the caller's
/// own maximum, [`MASKED_MAX_TIER2`] or [`MASKED_MAX_TIER3`], so that each has one writer.
pub fn with_drive_timed<R>(f: impl FnOnce(&mut FastState) -> R, max: &AtomicU32) -> Option<(R, u32)> {
    let start = counter::now();
    let result = cortex_m::interrupt::free(|_| {
        // SAFETY: interrupts are disabled, so the ADC handler cannot run, and no other `with_drive` is active (it
        // would have to be an interrupted one, and nothing interrupts this closure).
        unsafe { TIER1.get() }.map(|t| f(&mut t.fast))
    });
    let masked = counter::now().wrapping_sub(start);
    // Only the callers of one priority level write `max`, and they do not preempt one another.
    if masked > max.load(Ordering::Relaxed) {
        max.store(masked, Ordering::Relaxed);
    }
    result.map(|r| (r, masked))
}

/// The masked-section maximum of the calling context's priority level ([`MASKED_MAX_TIER3`] in thread mode,
/// [`MASKED_MAX_TIER2`] in an interrupt), for code that runs at either level.
pub fn masked_max_of_caller() -> &'static AtomicU32 {
    if cortex_m::peripheral::SCB::vect_active() == cortex_m::peripheral::scb::VectActive::ThreadMode {
        &MASKED_MAX_TIER3
    } else {
        &MASKED_MAX_TIER2
    }
}

/// The longest section with tier 1 masked so far, from any tier (`insn.masked_max` in the QEMU bench).
pub fn masked_max() -> u32 {
    MASKED_MAX_TIER2.load(Ordering::Relaxed).max(MASKED_MAX_TIER3.load(Ordering::Relaxed))
}

/// The QEMU bench's period timer (SysTick, `board::period_timer`): one current-loop period at the real rate.
/// Reads the time since the period began first (`insn.tier1_latency_max`, to one SysTick tick), counts the
/// periods that passed without a tier-1 run (`fast_missed`: the period starts between this run's and the last
/// one's, less one), then runs the period as the ADC interrupt does on the board.
///
/// Called from the drive image's SysTick exception (`src/bin/drive.rs`): defined there, not here, so that the
/// bootloader, which links this library with SysTick in its exception table, does not pull in tier 1. Does
/// nothing when called from anywhere else (it checks the active exception).
#[cfg(feature = "qemu")]
pub fn on_period_timer() {
    use crate::board::period_timer;
    use cortex_m::peripheral::scb::{Exception, VectActive};
    if cortex_m::peripheral::SCB::vect_active() != VectActive::Exception(Exception::SysTick) {
        return;
    }
    let since = period_timer::ticks_since_wrap();
    let now = counter::now();
    let latency = period_timer::ticks_to_instructions(since);
    let start = now.wrapping_sub(latency);
    let elapsed = start.wrapping_sub(LAST_UPDATE.load(Ordering::Relaxed));
    LAST_UPDATE.store(start, Ordering::Relaxed);
    // Period starts since the last run, rounded (the two starts are whole periods apart, to a tick).
    let period = period_timer::PERIOD_INSTRUCTIONS;
    let periods = elapsed.saturating_add(period / 2).checked_div(period).unwrap_or(1);
    if periods > 1 {
        FAST_MISSED
            .store(FAST_MISSED.load(Ordering::Relaxed).saturating_add(periods.wrapping_sub(1)), Ordering::Relaxed);
    }
    if latency > TIER1_LATENCY_MAX.load(Ordering::Relaxed) {
        TIER1_LATENCY_MAX.store(latency, Ordering::Relaxed);
    }
    // SAFETY: this runs in the SysTick exception (checked above), which has tier 1's priority (`rt::run`), so the
    // contract of `on_adc` holds here as in the ADC vector.
    unsafe { on_adc() }
}

/// An empty call with the fast tick's shape (result pointer, measurements, state), for calibration. Its body is an
/// optimisation barrier only (no instructions): without it LLVM deletes the call altogether.
#[inline(never)]
fn empty(_: &crate::hal::power::Measurements, _: &mut u32, out: &mut core::mem::MaybeUninit<crate::drive::FastTick>) {
    core::hint::black_box(out);
}

/// Cost of calling an empty function the way [`on_adc`] calls the fast tick, with the two counter reads: the
/// overhead subtracted from each measurement.
pub fn empty_call_cost() -> u32 {
    let m = core::hint::black_box(crate::hal::power::Measurements::default());
    let mut s = 0u32;
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    let mut out = core::mem::MaybeUninit::uninit();
    empty(&m, &mut s, &mut out);
    compiler_fence(Ordering::SeqCst);
    counter::now().wrapping_sub(start)
}
