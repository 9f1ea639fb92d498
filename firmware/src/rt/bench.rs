//! The QEMU bench (feature `qemu`), run as the tier-3 task of the same runtime the board runs.
//!
//! 1. `insn.foc_step`: instructions of one `control::current_loop::foc_step` call (Clarke to SVPWM with the
//!    voltage limit and bus compensation), maximum over a fixed input set: 16 angles around the turn x {no
//!    current, a small error, demands that saturate the voltage limit either way, a low bus}, each twice so that
//!    the integrators are both fresh and wound up. TIM2 counts instructions (`board::counter`); an empty call of
//!    the same shape is subtracted.
//! 2. `insn.fast_tick_max`: tier 1 runs the drive's whole fast tick for `FAST_TICKS` periods, the ADC interrupt
//!    pended from here (QEMU has no ADC) and the built-in plant (`board::plant`) closing the loop: switch-on with
//!    the current-offset calibration at standstill, then operation enabled with Hall commutation through the
//!    plant's speed profile (both directions, up to 4,000 rpm) and a current demand that steps between small and
//!    saturating values. Tier 1 measures every fast tick the way it does on the board; the maximum is printed.
//!    `insn.slow_tick_max` is tier 2's slow tick, including the critical section it runs in.
//! 3. Checks the tiers (every period ran, tier 2 once per ten, nothing missed, no overrun, the drive ended in
//!    operation enabled) and exits through semihosting: status 0, or 1 when a check failed.

use core::hint::black_box;
use core::sync::atomic::{compiler_fence, Ordering};

use cortex_m::peripheral::NVIC;

use super::{tier1, tier2};
use crate::board::plant::{HOLD_TICKS, PROFILE_TICKS};
use crate::board::semihosting::{exit, print, EXIT_CHECK_FAILED, EXIT_OK};
use crate::board::{counter, vectors::Interrupt};
use crate::control::angle::ElectricalAngle;
use crate::control::current_loop::{foc_step, CurrentController, FocInput, FocOutput};
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::drive::{DemandSource, PowerState};
use crate::hal::power::SLOW_TICK_DIVIDER;

/// Fast ticks run through tier 1: the standstill hold (calibration) and one pass through the speed profile.
pub const FAST_TICKS: u32 = HOLD_TICKS + PROFILE_TICKS;
/// Current demand steps during operation (mA), each held for `FAST_TICKS / 8` periods.
const DEMANDS_MA: [i32; 8] = [1_000, 3_000, -3_000, 10_000, 0, -10_000, 500, 6_000];

/// An empty call shaped like `foc_step` (output pointer, controller, input): the calibration.
/// Its body is an optimisation barrier only (no instructions): without it LLVM deletes the call altogether.
#[inline(never)]
fn empty_call(_controller: &mut CurrentController, _input: &FocInput, out: &mut FocOutput) {
    black_box(out);
}

/// Counter cost of one empty call between two counter readings.
fn empty_cost(controller: &mut CurrentController, input: &FocInput) -> u32 {
    let mut out = FocOutput::default();
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    empty_call(controller, input, &mut out);
    compiler_fence(Ordering::SeqCst);
    let end = counter::now();
    black_box(out);
    end.wrapping_sub(start)
}

/// Counter cost of one `foc_step` between two counter readings.
fn foc_cost(controller: &mut CurrentController, input: &FocInput) -> u32 {
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    let out = foc_step(controller, input);
    compiler_fence(Ordering::SeqCst);
    let end = counter::now();
    black_box(out);
    end.wrapping_sub(start)
}

fn abc_ma(a: i32, b: i32) -> Abc<Amps> {
    Abc::new(
        Amps::from_milliamps(a),
        Amps::from_milliamps(b),
        Amps::from_milliamps(0i32.wrapping_sub(a).wrapping_sub(b)),
    )
}

/// `insn.foc_step`: the maximum over the input set, with the drive's own controller configuration.
fn foc_step_max() -> u32 {
    let Some(mut controller) = tier1::with_drive(|d| *d.controller()) else {
        return u32::MAX;
    };
    let probe = FocInput::default();
    let overhead = (0..4).map(|_| empty_cost(&mut controller, &probe)).min().unwrap_or(0);
    let cases = [
        // (i_a, i_b) mA, (i_d, i_q) demand mA, bus mV
        ((0, 0), (0, 0), 24_000),
        ((400, -250), (0, 500), 24_000),
        ((-300, 700), (0, 10_000), 24_000),
        ((900, -100), (-2_000, -10_000), 24_000),
        ((2_500, 1_200), (0, 8_000), 12_000),
    ];
    let mut max = 0;
    for k in 0..16u32 {
        let angle = ElectricalAngle::from_turn_bits(k.wrapping_mul(1 << 28).wrapping_add(0x0123_4567));
        for ((a, b), (d, q), bus) in cases {
            let input = black_box(FocInput {
                i_abc: abc_ma(a, b),
                angle,
                i_ref: Dq::new(Amps::from_milliamps(d), Amps::from_milliamps(q)),
                v_bus: Volts::from_millivolts(bus),
            });
            for _ in 0..2 {
                max = max.max(foc_cost(&mut controller, &input).saturating_sub(overhead));
            }
        }
    }
    max
}

/// Runs `n` tier-1 periods.
fn run_ticks(n: u32) {
    for _ in 0..n {
        // Tier 1 preempts right here; tier 2 tail-chains after it when a slow tick is due.
        NVIC::pend(Interrupt::Adc);
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
    }
}

fn state() -> Option<PowerState> {
    tier1::with_drive(|d| d.state())
}

/// The bench task.
#[embassy_executor::task]
pub async fn bench() {
    let foc = foc_step_max();
    print(format_args!("source.foc_step=control::current_loop::foc_step\n"));
    print(format_args!("insn.foc_step={foc}\n"));

    let fast_before = tier1::FAST_TICKS.load(Ordering::Relaxed);
    // Switch on: the offset calibration runs at standstill during the plant's hold.
    let switched = tier1::with_drive(|d| d.switch_on().is_ok()).unwrap_or(false);
    let mut ran = 0;
    while ran < HOLD_TICKS && state() != Some(PowerState::SwitchedOn) {
        run_ticks(1);
        ran = ran.wrapping_add(1);
    }
    run_ticks(HOLD_TICKS.saturating_sub(ran));
    let calibrated = state() == Some(PowerState::SwitchedOn);
    let enabled = tier1::with_drive(|d| {
        d.set_demand_source(DemandSource::Internal);
        d.set_current_demand(Amps::ZERO);
        d.enable_operation().is_ok()
    })
    .unwrap_or(false);
    let step = PROFILE_TICKS.checked_div(DEMANDS_MA.len() as u32).unwrap_or(0);
    for ma in DEMANDS_MA {
        let _ = tier1::with_drive(|d| d.set_current_demand(Amps::from_milliamps(ma)));
        run_ticks(step);
    }
    run_ticks(PROFILE_TICKS.saturating_sub(step.saturating_mul(DEMANDS_MA.len() as u32)));
    let final_state = state();

    let fast = tier1::FAST_TICKS.load(Ordering::Relaxed).wrapping_sub(fast_before);
    let slow = tier2::SLOW_TICKS.load(Ordering::Relaxed);
    print(format_args!("source.fast_tick=drive::Drive::fast_tick\n"));
    print(format_args!("insn.fast_tick_max={}\n", tier1::FAST_TICK_MAX.load(Ordering::Relaxed)));
    print(format_args!("insn.slow_tick_max={}\n", tier2::SLOW_TICK_MAX.load(Ordering::Relaxed)));
    print(format_args!("count.fast_ticks={fast}\ncount.slow_ticks={slow}\n"));
    print(format_args!("drive.final_state={final_state:?}\n"));

    let mut ok = true;
    let mut check = |cond: bool, what: &str| {
        if !cond {
            print(format_args!("check failed: {what}\n"));
            ok = false;
        }
    };
    check(switched && calibrated, "switch-on calibrated the current offsets during the hold");
    check(enabled, "operation enabled");
    check(final_state == Some(PowerState::OperationEnabled), "the drive stayed in operation enabled");
    check(fast == FAST_TICKS, "every pended ADC interrupt ran tier 1 once");
    check(slow == FAST_TICKS / SLOW_TICK_DIVIDER, "tier 2 ran once per ten fast ticks");
    check(tier2::SLOW_MISSED.load(Ordering::Relaxed) == 0, "tier 2 missed no slow tick");
    check(!tier1::OVERRUN.load(Ordering::Relaxed), "no fast-tick overrun");
    exit(if ok { EXIT_OK } else { EXIT_CHECK_FAILED });
}
