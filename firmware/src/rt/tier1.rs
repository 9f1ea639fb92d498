//! Tier 1: the 25 kHz current loop as a raw interrupt handler (ADC JEOC, highest priority).
//!
//! Tier 1 owns its state ([`crate::drive::tier1::Tier1State`]) alone: nothing else reaches it after [`start`].
//! Each period: read the measurements, take the blocks the tier-2 drive published since the last period
//! ([`SETTINGS`], [`SETPOINT`]: double buffers whose reader never waits), run the pure fast tick, write the PWM
//! command, account the cost, and at every `SLOW_TICK_DIVIDER`-th period publish the [`REPORT`] (a sequence lock
//! whose writer never waits) and raise tier 2. No allocation, no logging, no locks, no panics, and nothing below
//! it ever masks it (`rt` module documentation).
//! The fast tick's own cost is measured with the board's cost counter (cycles on the board, instructions under
//! QEMU); the maximum is kept, and a tick over budget trips the drive (outputs off at once, fault 0xFF0B) and
//! latches [`OVERRUN`] for the diagnostics. So does a lost period ([`PERIODS_LOST`]): tier 1 compares the time since
//! its last run with the period.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{compiler_fence, AtomicBool, AtomicU32, Ordering};

use cortex_m::peripheral::NVIC;

use super::app::{self, FastState};
use super::figures::{count, record_max};
use crate::board::counter;
use crate::board::interrupt::Interrupt;
use crate::board::PowerStage;
use crate::drive::blocks::{SetPoint, Settings, Tier1Report, REPORT_WORDS, SETPOINT_WORDS};
#[cfg(not(feature = "qemu"))]
use crate::hal::power::PWM_FREQUENCY_HZ;
use crate::handoff::{Command, Report};
use crate::recorder::ring::SampleRing;

/// Cost budget of one fast tick in counter units: half the 6,720-cycle period at 168 MHz, the rest is left to
/// the interrupt entry/exit and tiers 2 and 3.
pub const FAST_TICK_BUDGET: u32 = 3_360;

/// Largest fast-tick cost seen (counter units, overhead subtracted). Writer: tier 1.
pub static FAST_TICK_MAX: AtomicU32 = AtomicU32::new(0);
/// Periods since tier 1 started: the fast ticks run plus the periods found lost. Writer: tier 1.
pub static FAST_TICKS: AtomicU32 = AtomicU32::new(0);
/// Latched when a fast tick exceeded `FAST_TICK_BUDGET`. Writer: tier 1 (sets only).
pub static OVERRUN: AtomicBool = AtomicBool::new(false);
/// The set-point the tier-2 drive published last. Writer: `tier2::with_drive` (the drive's lock); reader: tier 1.
pub static SETPOINT: Command<SetPoint, SETPOINT_WORDS> = Command::new();
/// The settings the tier-2 drive published last. Writer: `tier2::with_drive`; reader: tier 1.
pub static SETTINGS: Command<Settings, 15> = Command::new();
/// Tier 1's report of the last slow-tick boundary. Writer: tier 1; reader: tier 2.
pub static REPORT: Report<Tier1Report, REPORT_WORDS> = Report::new();
/// Periods tier 1 found lost (the time since its last run was more than one and a half periods). Writer: tier 1.
pub static PERIODS_LOST: AtomicU32 = AtomicU32::new(0);
/// [`FAST_TICKS`] when the last slow tick was raised: tier 2 compares it with `FAST_TICKS` after its publication
/// (`tier2::SETPOINT_PERIODS_LATE_MAX`). Writer: tier 1.
pub static SLOW_TICK_RAISED_AT: AtomicU32 = AtomicU32::new(0);
/// Tier 1's periods come from the hardware, so a gap between two runs is a lost period. On from start-up on the
/// board; in the QEMU image only while the bench's period timer runs (in its pended part the bench itself pends
/// each period). Writer: start-up, then the QEMU bench with the timer stopped.
pub static PERIOD_SUPERVISED: AtomicBool = AtomicBool::new(false);
/// Largest cost of publishing the report (after the PWM write, every tenth period; counter units). Writer: tier 1.
pub static REPORT_MAX: AtomicU32 = AtomicU32::new(0);
/// Tier 1's copies of its values for the data recorder (`crate::recorder::ring`), one every period after the PWM
/// write while the recorder samples, counted in `FAST_TICK_MAX`. Writer: tier 1; reader: tier 3
/// (`tier2::drain_recorder`).
pub static RECORDER_RING: SampleRing = SampleRing::new();

/// One current-loop period in counter units: cycles at 168 MHz on the board, the QEMU bench's instruction period.
#[cfg(not(feature = "qemu"))]
const PERIOD: u32 = crate::board::clock::SYSCLK_HZ / PWM_FREQUENCY_HZ;
#[cfg(feature = "qemu")]
const PERIOD: u32 = crate::board::period_timer::PERIOD_INSTRUCTIONS;

/// Largest time from the period timer's wrap to tier 1's handler (QEMU bench, its SysTick handler).
/// Writer: tier 1.
pub static TIER1_LATENCY_MAX: AtomicU32 = AtomicU32::new(0);
/// Smallest time from the period timer's wrap to tier 1's handler: the entry cost, which the longest wait past it
/// (`insn.masked_max` in the QEMU bench) is measured from. Writer: tier 1; the bench resets it with the timer
/// stopped.
#[cfg(feature = "qemu")]
pub static TIER1_LATENCY_MIN: AtomicU32 = AtomicU32::new(u32::MAX);
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
    /// The epochs of the last blocks taken from [`SETTINGS`] and [`SETPOINT`] (0: none yet).
    settings_epoch: u32,
    setpoint_epoch: u32,
    /// Counter time of the last run's start while the periods are supervised (lost-period detection).
    last_run: Option<u32>,
}

/// Tier 1's state: written once by [`start`] before the ADC interrupt is unmasked (then `ready`), then used by the
/// ADC handler alone.
///
/// `MaybeUninit` and a flag rather than an `Option`: `None` of the drive's type is not all zero bytes (a niche
/// in one of its enums), so an `Option` static would sit in `.data` with a 6 KiB initial image in flash; this one
/// is in `.bss`.
struct Slot {
    state: UnsafeCell<MaybeUninit<Tier1>>,
    ready: AtomicBool,
}

// SAFETY: see `Slot`: one writer before the interrupt is enabled; afterwards only the tier-1 handler, which cannot
// preempt itself (the ADC vector, and in the QEMU image the SysTick exception at the same priority).
unsafe impl Sync for Slot {}

impl Slot {
    /// The state, once [`start`] has placed it.
    ///
    /// # Safety
    /// The caller is the tier-1 handler (see `Slot`) and holds no other reference obtained from this function.
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

/// Hands the power stage and tier 1's state to tier 1 and unmasks the ADC interrupt. Call once, from start-up,
/// with interrupts of tier 1 still masked, after the drive's first blocks are published.
pub(crate) fn start(power: PowerStage, fast: FastState) {
    let overhead = empty_call_cost();
    NVIC::mask(Interrupt::Adc);
    compiler_fence(Ordering::SeqCst);
    PERIOD_SUPERVISED.store(cfg!(not(feature = "qemu")), Ordering::Relaxed);
    let t1 = Tier1 { power, fast, overhead, settings_epoch: 0, setpoint_epoch: 0, last_run: None };
    // SAFETY: the ADC interrupt is masked, so its handler (the slot's only other user) cannot run now; `start` runs
    // once, from start-up.
    unsafe { (*TIER1.state.get()).write(t1) };
    TIER1.ready.store(true, Ordering::Relaxed);
    compiler_fence(Ordering::SeqCst);
    // SAFETY: the handler's state is in place; unmasking cannot break a critical section (none is held here).
    unsafe { NVIC::unmask(Interrupt::Adc) };
}

/// The ADC interrupt: one current-loop period.
///
/// # Safety
/// Only the vector table calls this (`rt::vectors`): as the ADC handler it never preempts itself.
pub unsafe extern "C" fn on_adc() {
    // SAFETY: see `# Safety`: no other reference to the slot is live while the handler runs.
    let Some(t) = (unsafe { TIER1.get() }) else {
        // An ADC interrupt before start-up finished: nothing to run; keep the power stage off.
        crate::board::safe_state();
        return;
    };
    let measurements = t.power.read();
    // The measurements complete before the cost counter starts: without the barrier the compiler may compute part
    // of them (the QEMU image's simulated power stage) after the first counter read, inside the fast tick's cost.
    core::hint::black_box(&measurements);
    let start = counter::now();
    let lost = t.lost_periods(start);
    compiler_fence(Ordering::SeqCst);
    let tick = app::fast_tick(&measurements, &mut t.fast, &mut t.settings_epoch, &mut t.setpoint_epoch);
    compiler_fence(Ordering::SeqCst);
    let cost = counter::now().wrapping_sub(start).saturating_sub(t.overhead);
    // A tick over budget cannot keep the 40 us period, and a lost period left the PWM with stale duties: the
    // drive trips (outputs off with this very write).
    let pwm = if cost > FAST_TICK_BUDGET {
        OVERRUN.store(true, Ordering::Relaxed);
        t.fast.current_loop_overrun(cost)
    } else if lost > 0 && t.fast.outputs_switching() {
        OVERRUN.store(true, Ordering::Relaxed);
        // The detail: the periods lost, in period units times the budget's, so it reads as an overrun's cost.
        t.fast.current_loop_overrun(lost.saturating_mul(PERIOD))
    } else {
        tick.pwm
    };
    t.power.write(&pwm);
    // The data recorder's copy of what this period computed, while it samples (the same words whatever is
    // recorded): after the PWM write, so that it delays no output, and counted in the fast tick's cost, so that
    // `FAST_TICK_MAX` is tier 1's cost with the recorder; without it tier 1 pays one load here.
    let cost = if RECORDER_RING.enabled() {
        let before = counter::now();
        record(&RECORDER_RING, &t.fast, &pwm);
        cost.saturating_add(counter::now().wrapping_sub(before))
    } else {
        cost
    };
    record_max(&FAST_TICK_MAX, cost);
    // The periods, not the runs: a lost period still counts, so the PLL's period index (`rt::ethercat`) stays on
    // the timer's grid.
    count(&FAST_TICKS, lost.wrapping_add(1));
    if tick.slow_tick_due {
        // After the PWM write: the report is tier 2's, and costs this period's output nothing.
        let before = counter::now();
        REPORT.publish(&t.fast.report());
        let cost = counter::now().wrapping_sub(before);
        record_max(&REPORT_MAX, cost);
        SLOW_TICK_RAISED_AT.store(FAST_TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
        super::tier2::SLOW_TICK.raise();
    }
}

/// Words of [`crate::drive::FastSignals`] the recorder takes, from its start: the phase currents, the d/q
/// currents, the d/q references, the d/q voltages and the bus voltage (`recorder::ring::word` 0..9).
const SIGNAL_WORDS: usize = 10;

// The block copy below reads the signals as words: each of the ten `I16F16` values where `sample_words` takes it.
const _: () = {
    use crate::drive::FastSignals;
    use core::mem::{offset_of, size_of};
    assert!(size_of::<crate::control::frames::Amps>() == 4 && size_of::<crate::control::frames::Volts>() == 4);
    assert!(offset_of!(FastSignals, i_abc.a) == 0 && offset_of!(FastSignals, i_abc.b) == 4);
    assert!(offset_of!(FastSignals, i_abc.c) == 8 && offset_of!(FastSignals, i_dq.d) == 12);
    assert!(offset_of!(FastSignals, i_dq.q) == 16 && offset_of!(FastSignals, i_ref.d) == 20);
    assert!(offset_of!(FastSignals, i_ref.q) == 24 && offset_of!(FastSignals, v_dq.d) == 28);
    assert!(offset_of!(FastSignals, v_dq.q) == 32 && offset_of!(FastSignals, v_bus) == 36);
};

/// The data recorder's copy of this period's values into [`RECORDER_RING`]: the words of
/// `recorder::ring::sample_words` (what `SampleRing::push` stores). The ten signal words are one block copy
/// (multiple-register loads and stores, `ldm`/`stm`) instead of ten loads and ten single stores (the ring's atomic
/// stores are never merged).
/// The QEMU bench measures the same copy into a ring of its own (`insn.recorder_tier1_copy`).
#[inline(always)]
pub(crate) fn record(ring: &SampleRing, t1: &FastState, pwm: &crate::hal::power::PwmCommand) {
    let (n, slot) = ring.writer_slot();
    if let Some(slot) = slot {
        let [.., duty_ab, duty_c, position] = crate::recorder::ring::sample_words(t1, pwm);
        let from = core::ptr::from_ref(t1.signals()).cast::<[u32; SIGNAL_WORDS]>();
        let to = core::ptr::from_ref(slot).cast::<[u32; SIGNAL_WORDS]>().cast_mut();
        // SAFETY: `from`: the signals' first ten words are the ten `I16F16` values in `sample_words`' order (the
        // assertions above), read through a live reference; tier 1's state and the ring are distinct objects, so
        // the two do not overlap. `to`: the slot's first ten cells, `AtomicU32` (the
        // size and alignment of `u32`, interior mutability), so a plain write through a pointer to them is
        // allowed. Tier 1 is the ring's only writer and no reader runs while it does: the reader is tier 3, on
        // the same core, which tier 1 preempts; it takes a slot only below the count `commit` publishes (release)
        // and asks `overwritten` after its copy whether this writer came round to it meanwhile.
        unsafe { core::ptr::copy_nonoverlapping(from, to, 1) };
        let tail = slot.get(SIGNAL_WORDS..SIGNAL_WORDS + 3);
        if let Some([ab, c, p]) = tail {
            ab.store(duty_ab, Ordering::Relaxed);
            c.store(duty_c, Ordering::Relaxed);
            p.store(position, Ordering::Relaxed);
        }
    }
    ring.commit(n);
}

/// Periods between two period starts `elapsed` counter units apart, less one: the periods skipped (the elapsed time
/// rounded to whole periods, so that the jitter of either start does not count).
fn periods_skipped(elapsed: u32) -> u32 {
    elapsed.saturating_add(PERIOD / 2).checked_div(PERIOD).unwrap_or(1).saturating_sub(1)
}

impl Tier1 {
    /// Periods lost since the last run started (0 for the first supervised run, or with the supervision off): the time
    /// between the two starts, rounded to whole periods, less one. Counts them in [`PERIODS_LOST`].
    fn lost_periods(&mut self, now: u32) -> u32 {
        if !PERIOD_SUPERVISED.load(Ordering::Relaxed) {
            self.last_run = None;
            return 0;
        }
        let Some(last) = self.last_run.replace(now) else { return 0 };
        let lost = periods_skipped(now.wrapping_sub(last));
        if lost > 0 {
            PERIODS_LOST.store(PERIODS_LOST.load(Ordering::Relaxed).saturating_add(lost), Ordering::Relaxed);
        }
        lost
    }
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
    // The two starts are whole periods apart, to a tick.
    let missed = periods_skipped(elapsed);
    if missed > 0 {
        FAST_MISSED.store(FAST_MISSED.load(Ordering::Relaxed).saturating_add(missed), Ordering::Relaxed);
    }
    record_max(&TIER1_LATENCY_MAX, latency);
    if latency < TIER1_LATENCY_MIN.load(Ordering::Relaxed) {
        TIER1_LATENCY_MIN.store(latency, Ordering::Relaxed);
    }
    // SAFETY: this runs in the SysTick exception (checked above), which has tier 1's priority (`rt::run`), so the
    // contract of `on_adc` holds here as in the ADC vector.
    unsafe { on_adc() }
}

/// An empty call with the fast tick's shape (result pointer, measurements, state), for calibration. Its body is an
/// optimisation barrier only (no instructions): without it LLVM deletes the call altogether.
#[inline(never)]
fn empty(
    _: &crate::hal::power::Measurements,
    _: &mut u32,
    _: &mut u32,
    _: &mut u32,
    out: &mut core::mem::MaybeUninit<crate::drive::FastTick>,
) {
    core::hint::black_box(out);
}

/// Cost of calling an empty function the way [`on_adc`] calls the fast tick, with the two counter reads: the
/// overhead subtracted from each measurement.
pub fn empty_call_cost() -> u32 {
    let m = core::hint::black_box(crate::hal::power::Measurements::default());
    let (mut s, mut a, mut b) = (0u32, 0u32, 0u32);
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    let mut out = core::mem::MaybeUninit::uninit();
    empty(&m, &mut s, &mut a, &mut b, &mut out);
    compiler_fence(Ordering::SeqCst);
    counter::now().wrapping_sub(start)
}
