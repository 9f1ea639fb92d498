//! The QEMU bench (feature `qemu`), run as the tier-3 task of the same runtime the board runs.
//!
//! 1. `insn.foc_step`: instructions of one `control::current_loop::foc_step` call (Clarke to SVPWM with the
//!    voltage limit and bus compensation), maximum over a fixed input set: 16 angles around the turn x {no
//!    current, a small error, demands that saturate the voltage limit either way, a low bus}, each twice so that
//!    the integrators are both fresh and wound up. TIM2 counts instructions (`board::counter`); an empty call of
//!    the same shape is subtracted.
//! 2. `insn.slow_tick_max`: the drive's whole slow tick (`Drive::slow_tick`: the CiA 402 axis with its state
//!    machine, mode, interpolation, loops, monitoring, faults and I/O), as tier 2 measures it, including the
//!    drive's lock and the publications of the blocks for tier 1: the maximum over every slow tick from start-up
//!    to the end of a cyclic synchronous position run (no slow tick runs before it: tier 1 runs only when the
//!    bench pends it), and then over each of CSV, PVM, PPM and homing (`insn.slow_tick_<mode>`, see
//!    `other_modes`); `insn.slow_tick_max` is the worst of them all. The
//!    ADC interrupt is pended from here (QEMU has no ADC), tier 1 runs the fast tick against the built-in plant
//!    (`board::plant`) with its shaft free (the motor's torque moves the reference inertia) and raises tier 2
//!    every tenth period. Through the controlword, as a master does: 0x6060 = 8 (CSP), 0x60C2 = 1 ms, 0x6040 =
//!    0x06, 0x07 (transition 3 with the current-offset calibration), 0x0F, each until 0x6041 shows the state;
//!    then a master cycle of 1 ms (`CYCLE_TICKS` periods) with a new 0x607A and `Drive::setpoint_received`
//!    every cycle: a move `A (1 - cos)` of `CSP_AMPLITUDE_INC` over `CSP_PERIOD_CYCLES` (one turn out and
//!    back, up to 754 rpm and 1.3 M inc/s², through the encoder index, Hall and input edges), `CSP_PERIODS`
//!    times, then a hold. So the slow ticks include set-point arrivals at both phases of the 2.5 slow ticks per
//!    cycle, every interpolation step in between, the transitions of the state machine, the hold, and the
//!    conversion of the motion parameters written before the first tick (0x6060, 0x60C2). The following error
//!    window 0x6065 stays at its default of 2,000 inc: the plant follows within about 13 inc
//!    (`csp.following_error_peak_inc`, 0x60F4 sampled once per cycle).
//! 3. `insn.fast_tick_max`: tier 1 measures every fast tick of the whole run the way it does on the board (the
//!    maximum is printed): the CSP run above (input and index edges latched), then, after «Disable voltage» with
//!    0x6040 = 0, the plant's speed profile on the direct power-stage path: switch-on with the current-offset
//!    calibration at standstill, then operation enabled with Hall commutation through the profile (both
//!    directions, up to 4,000 rpm) and a current demand that steps between small and saturating values. The
//!    slow ticks of this second part are not part of `insn.slow_tick_max` (its value is taken before).
//! 4. `insn.tier1_latency_max`, `insn.masked_max`, `fast_missed`, `slow_missed`: tier 1 at the real period, driven
//!    by the period timer (SysTick every 1,129 ticks of 168 MHz = 6,720 instructions, `board::period_timer`)
//!    instead of the bench: back to «Switch on disabled» with other motion parameters, then the CSP move of item 2
//!    again through the controlword (its start converts the parameters again, the longest background step) and
//!    the runs of CSV, PVM, PPM and homing of item 2 (so the profile generator's planning ticks are there), tier 3
//!    serving SDO requests through a CANopen node over the drive meanwhile ([`Tier3Load`]: uploads, and
//!    downloads that the background step converts). The latency is from the start of the period tier 1 runs in
//!    to its handler (to a SysTick tick); a period whose start passes while tier 1 is held off, with the next
//!    start already due, is lost (`fast_missed`), and tier 1 counts the periods it finds lost itself
//!    (`tier1::PERIODS_LOST`, which must agree). `insn.masked_max` is the longest wait past the entry cost.
//!    `insn.tier2_total_max` is the worst whole tier-2 step of a slow period in this part, tier 1's preemptions
//!    included.
//! 5. `insn.profile_plan_max`, `insn.profile_command_max` and `insn.profile_step_max`: the profile generator alone:
//!    planning a move and a velocity command (`ProfileGenerator::prepare`, run by the background step before the
//!    slow tick that takes them into force), giving them and a halt (in the slow tick), one sample.
//! 6. Checks the tiers and the drive (every period ran, tier 2 once per ten, nothing missed, no overrun, the CSP
//!    run reached operation enabled, followed without a fault or following-error bit, the profile part ended in
//!    operation enabled) and exits through semihosting: status 0, or 1 when a check failed.

use core::hint::black_box;
use core::sync::atomic::{compiler_fence, Ordering};

use cortex_m::peripheral::NVIC;
use micromath::F32Ext;

use super::{tier1, tier2};
use crate::drive::Drive;

use crate::board::period_timer::{self, PERIOD_INSTRUCTIONS};
use crate::board::plant::{self, Shaft, HOLD_TICKS, PROFILE_TICKS};
use crate::board::semihosting::{exit, print, EXIT_CHECK_FAILED, EXIT_OK};
use crate::board::{counter, interrupt::Interrupt};
use crate::cia402::{State, Statusword};
use crate::control::angle::ElectricalAngle;
use crate::control::current_loop::{foc_step, CurrentController, FocInput, FocOutput};
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::drive::DemandSource;
use crate::hal::power::SLOW_TICK_DIVIDER;
use crate::od::generated::handles as h;
use crate::power_state::PowerState;

/// Fast ticks of the profile part: the standstill hold (calibration) and one pass through the speed profile.
pub const FAST_TICKS: u32 = HOLD_TICKS + PROFILE_TICKS;
/// Current demand steps during the profile (mA), each held for `PROFILE_TICKS / 8` periods.
const DEMANDS_MA: [i32; 8] = [1_000, 3_000, -3_000, 10_000, 0, -10_000, 500, 6_000];

/// CSP: 0x6060 value.
const MODE_CSP: i8 = 8;
/// The master cycle, PWM periods (25 x 40 us = 1 ms, = 0x60C2).
const CYCLE_TICKS: u32 = 25;
/// The move: amplitude (increments; the target swings over twice that), period (master cycles) and repetitions.
const CSP_AMPLITUDE_INC: f32 = 2048.0;
const CSP_PERIOD_CYCLES: u32 = 250;
const CSP_PERIODS: u32 = 2;
/// Cycles of the final hold (set-points keep coming at the start position).
const CSP_HOLD_CYCLES: u32 = 50;
/// The other modes after the CSP run, each from operation enabled on the free shaft: (name, 0x6060, PWM periods).
/// CSV and PVM at `MODES_RPM`, PPM a move of `PPM_DISTANCE_INC`, homing method 34 (index pulse, positive) at
/// `MODES_RPM` until it ends.
const MODES_RPM: i32 = 600;
const PPM_DISTANCE_INC: i32 = 8_192;
const MODE_PERIODS: u32 = 5_000;
/// The homing's run (0x609A = 10,000 rpm/s): the ramp, up to one turn to the index, the stop and the way back.
const HOMING_PERIODS: u32 = 25_000;
/// Longest wait for a state of the CiA 402 machine, PWM periods (the calibration of transition 3 takes about
/// 310).
const STATE_TIMEOUT_TICKS: u32 = 2_000;

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
    let Some(mut controller) = tier2::with_drive(|d| *crate::drive::tier1::Tier1State::new(d.settings()).controller())
    else {
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

/// Tier 3's work while the period timer drives tier 1: a CANopen node over the drive (pre-operational) serving
/// SDO requests from a software bus, as the CAN task does: uploads of the statusword 0x6041 and, every fourth
/// exchange, a download of profile acceleration 0x6083 with a new value, which the next background step converts
/// (the axis's motion parameters).
struct Tier3Load {
    node: crate::canopen::CanopenNode,
    exchanges: u32,
    /// Answers that were not the expected SDO response (upload of 2 bytes, download acknowledged).
    wrong_answers: u32,
}

impl Tier3Load {
    const NODE: u8 = 1;

    /// The node booted into pre-operational over the drive, or `None` if it did not boot.
    fn new() -> Option<Self> {
        use crate::canopen::{CanopenNode, NodeEvent};
        use crate::od::access::NoApplicationObjects;
        let mut node = CanopenNode::new(Self::NODE);
        let booted = tier2::with_drive(|d| {
            let mut app = NoApplicationObjects;
            matches!(node.process(d, &mut app, 0), Some(NodeEvent::Reset { .. }))
                && node.process(d, &mut app, 0) == Some(NodeEvent::Booted)
        });
        while node.transmit().is_some() {}
        (booted == Some(true)).then_some(Self { node, exchanges: 0, wrong_answers: 0 })
    }

    /// One SDO request through the node (inside the drive's lock, as the CAN task's poll), and its answer.
    fn exchange(&mut self) {
        use crate::canopen::frame::CanFrame;
        use crate::od::access::NoApplicationObjects;
        let download = self.exchanges % 4 == 3;
        let acceleration = 10_000u32.wrapping_add(self.exchanges % 8).to_le_bytes();
        let request = if download {
            [0x23, 0x83, 0x60, 0x00, acceleration[0], acceleration[1], acceleration[2], acceleration[3]]
        } else {
            [0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0]
        };
        let Some(frame) = CanFrame::new(0x600 + u16::from(Self::NODE), &request) else { return };
        let now_us = u64::from(self.exchanges).wrapping_mul(400);
        let node = &mut self.node;
        let _ = tier2::with_drive(|d| {
            let mut app = NoApplicationObjects;
            node.handle_frame(&frame, d, &mut app, now_us);
            let _ = node.process(d, &mut app, now_us);
        });
        let expected = if download { 0x60 } else { 0x4B };
        let answered = node
            .transmit()
            .is_some_and(|f| f.id() == 0x580 + u16::from(Self::NODE) && f.data().first() == Some(&expected));
        while node.transmit().is_some() {}
        self.wrong_answers = self.wrong_answers.wrapping_add(u32::from(!answered));
        self.exchanges = self.exchanges.wrapping_add(1);
    }
}

/// Runs the periods of the bench: by pending the ADC interrupt `n` times (tier 1 runs each time; tier 2 after every
/// tenth), or, once the period timer drives tier 1 ([`Periods::timed`]), by letting `n` periods of time pass while
/// tier 3 (this task) serves SDO requests through a CANopen node over the drive ([`Tier3Load`]). Counts the
/// periods.
struct Periods {
    pended: u32,
    /// The counter time the timed periods run up to (`None`: periods are pended).
    timed_until: Option<u32>,
    /// Tier 3's work during timed periods.
    load: Option<Tier3Load>,
}

impl Periods {
    /// Periods pended by the bench.
    const fn pended() -> Self {
        Self { pended: 0, timed_until: None, load: None }
    }

    /// Periods driven by the period timer, from counter time `start`, with tier 3 doing `load` meanwhile.
    const fn timed(start: u32, load: Option<Tier3Load>) -> Self {
        Self { pended: 0, timed_until: Some(start), load }
    }

    fn run(&mut self, n: u32) {
        match self.timed_until {
            None => {
                for _ in 0..n {
                    // Tier 1 preempts right here; tier 2 tail-chains after it when a slow tick is due.
                    NVIC::pend(Interrupt::Adc);
                    cortex_m::asm::dsb();
                    cortex_m::asm::isb();
                    // Tier 3's work: the data recorder's drain.
                    tier2::drain_recorder();
                }
            }
            Some(until) => {
                let until = until.wrapping_add(n.wrapping_mul(PERIOD_INSTRUCTIONS));
                // Wrapping counter: the difference stays below 2^31 for any wait of this bench.
                while (until.wrapping_sub(counter::now()) as i32) > 0 {
                    tier2::drain_recorder();
                    match self.load.as_mut() {
                        Some(load) => load.exchange(),
                        None => {
                            black_box(tier2::with_drive(|d| d.dictionary().get(h::STATUSWORD)));
                        }
                    }
                }
                self.timed_until = Some(until);
            }
        }
        self.pended = self.pended.wrapping_add(n);
    }

    /// Runs periods until `done` holds for the drive, at most `limit`; whether it did.
    fn run_until(&mut self, limit: u32, mut done: impl FnMut(&mut Drive) -> bool) -> bool {
        for _ in 0..limit {
            if tier2::with_drive(&mut done).unwrap_or(false) {
                return true;
            }
            self.run(1);
        }
        tier2::with_drive(&mut done).unwrap_or(false)
    }
}

fn state() -> Option<PowerState> {
    tier2::with_drive(|d| d.state())
}

/// The CiA 402 state 0x6041 shows.
fn statusword_state(d: &Drive) -> Option<State> {
    Statusword(d.dictionary().get(h::STATUSWORD)).state()
}

/// Writes the controlword and runs until the statusword shows `state`.
fn command(periods: &mut Periods, controlword: u16, state: State) -> bool {
    let _ = tier2::with_drive(|d| d.dictionary_mut().set(h::CONTROLWORD, controlword));
    periods.run_until(STATE_TIMEOUT_TICKS, |d| statusword_state(d) == Some(state))
}

/// What the CSP run saw.
#[derive(Default)]
struct CspRun {
    enabled: bool,
    setpoints: u32,
    following_error_peak: u32,
    fault_seen: bool,
    bit13_seen: bool,
    follows_seen: bool,
    stayed_enabled: bool,
}

/// The CSP run (see the module documentation).
fn csp(periods: &mut Periods) -> CspRun {
    let mut run = CspRun::default();
    let _ = tier2::with_drive(|d| {
        let dict = d.dictionary_mut();
        dict.set(h::MODES_OF_OPERATION, MODE_CSP);
        dict.set(h::INTERPOLATION_TIME_PERIOD_VALUE, 1);
        dict.set(h::INTERPOLATION_TIME_INDEX, -3);
    });
    run.enabled = command(periods, 0x06, State::ReadyToSwitchOn)
        && command(periods, 0x07, State::SwitchedOn)
        && command(periods, 0x0F, State::OperationEnabled);
    if !run.enabled {
        return run;
    }
    let start = tier2::with_drive(|d| d.dictionary().get(h::POSITION_ACTUAL_VALUE)).unwrap_or(0);
    let cycles = CSP_PERIOD_CYCLES.saturating_mul(CSP_PERIODS).saturating_add(CSP_HOLD_CYCLES);
    let omega = core::f32::consts::TAU / CSP_PERIOD_CYCLES as f32;
    for k in 0..cycles {
        let excursion = if k < CSP_PERIOD_CYCLES.saturating_mul(CSP_PERIODS) {
            (CSP_AMPLITUDE_INC * (1.0 - (omega * k as f32).cos())) as i32
        } else {
            0
        };
        let _ = tier2::with_drive(|d| {
            d.dictionary_mut().set(h::TARGET_POSITION, start.wrapping_add(excursion));
            d.setpoint_received();
        });
        run.setpoints = run.setpoints.wrapping_add(1);
        periods.run(CYCLE_TICKS);
        let (sw, fe) = tier2::with_drive(|d| {
            (d.dictionary().get(h::STATUSWORD), d.dictionary().get(h::FOLLOWING_ERROR_ACTUAL_VALUE))
        })
        .unwrap_or((Statusword::FAULT, i32::MAX));
        run.following_error_peak = run.following_error_peak.max(fe.unsigned_abs());
        run.fault_seen |= sw & Statusword::FAULT != 0;
        run.bit13_seen |= sw & Statusword::OMS_13 != 0;
        run.follows_seen |= sw & Statusword::OMS_12 != 0;
    }
    run.stayed_enabled = tier2::with_drive(|d| statusword_state(d)) == Some(Some(State::OperationEnabled));
    run
}

/// The slow tick's worst case in one mode: 0x6060 = `mode` from operation enabled, `setup` on the drive, then
/// `periods_in_mode` periods, with `every_cycle` run every master cycle (the cyclic modes' set-points). Whether the
/// drive stayed without a fault, and the slow tick's maximum over the run (tiers 1 and 2 are idle between the
/// bench's periods, so the bench resets the maximum).
fn slow_tick_in_mode(
    periods: &mut Periods,
    mode: i8,
    periods_in_mode: u32,
    setup: impl FnOnce(&mut Drive),
    mut every_cycle: impl FnMut(&mut Drive),
) -> (bool, u32) {
    tier2::SLOW_TICK_MAX.store(0, Ordering::Relaxed);
    let _ = tier2::with_drive(|d| {
        d.dictionary_mut().set(h::MODES_OF_OPERATION, mode);
        setup(d);
    });
    for _ in 0..periods_in_mode / CYCLE_TICKS {
        let _ = tier2::with_drive(&mut every_cycle);
        periods.run(CYCLE_TICKS);
    }
    let sw = tier2::with_drive(|d| d.dictionary().get(h::STATUSWORD)).unwrap_or(Statusword::FAULT);
    (sw & Statusword::FAULT == 0, tier2::SLOW_TICK_MAX.load(Ordering::Relaxed))
}

/// The slow tick in CSV, PVM, PPM and homing after the CSP run (see the constants): the maximum per mode, and
/// whether every mode ran without a fault and the homing ended (statusword bit 12), as the line to print.
fn other_modes(periods: &mut Periods) -> ([(&'static str, u32); 4], bool, ModesCheck) {
    let (csv_ok, csv) = slow_tick_in_mode(
        periods,
        9,
        MODE_PERIODS,
        |d| d.dictionary_mut().set(h::TARGET_VELOCITY, MODES_RPM),
        |d| d.setpoint_received(),
    );
    let (pvm_ok, pvm) = slow_tick_in_mode(
        periods,
        3,
        MODE_PERIODS,
        |d| d.dictionary_mut().set(h::TARGET_VELOCITY, MODES_RPM.wrapping_neg()),
        |_| {},
    );
    let mut started = false;
    let (ppm_ok, ppm) = slow_tick_in_mode(
        periods,
        1,
        MODE_PERIODS,
        |d| {
            let here = d.dictionary().get(h::POSITION_ACTUAL_VALUE);
            let dict = d.dictionary_mut();
            dict.set(h::PROFILE_VELOCITY, MODES_RPM.unsigned_abs());
            dict.set(h::TARGET_POSITION, here.wrapping_add(PPM_DISTANCE_INC));
        },
        // Controlword bit 4 rising once the mode is shown, then back (the set-point handshake).
        |d| {
            let shown = d.dictionary().get(h::MODES_OF_OPERATION_DISPLAY) == 1;
            let cw = if shown && !started { 0x1F } else { 0x0F };
            started |= shown;
            d.dictionary_mut().set(h::CONTROLWORD, cw);
        },
    );
    let mut homing_started = false;
    let (homing_ok, homing) = slow_tick_in_mode(
        periods,
        6,
        HOMING_PERIODS,
        |d| {
            let dict = d.dictionary_mut();
            dict.set(h::CONTROLWORD, 0x0F);
            dict.set(h::HOMING_METHOD, 34i8);
            dict.set(h::HOMING_SPEED_SWITCH_SEARCH, MODES_RPM.unsigned_abs());
            dict.set(h::HOMING_SPEED_ZERO_SEARCH, MODES_RPM.unsigned_abs());
            dict.set(h::HOMING_ACCELERATION, 10_000u32);
        },
        |d| {
            let shown = d.dictionary().get(h::MODES_OF_OPERATION_DISPLAY) == 6;
            if shown && !homing_started {
                d.dictionary_mut().set(h::CONTROLWORD, 0x1F);
                homing_started = true;
            }
        },
    );
    let homed = tier2::with_drive(|d| d.dictionary().get(h::STATUSWORD) & Statusword::OMS_12 != 0) == Some(true);
    let _ = tier2::with_drive(|d| d.dictionary_mut().set(h::CONTROLWORD, 0x0F));
    (
        [("csv", csv), ("pvm", pvm), ("ppm", ppm), ("homing", homing)],
        csv_ok && pvm_ok && ppm_ok && homing_ok && homed,
        ModesCheck { csv_ok, pvm_ok, ppm_ok, homing_ok, homed },
    )
}

/// Which of the other modes ran without a fault, and whether the homing ended.
struct ModesCheck {
    csv_ok: bool,
    pvm_ok: bool,
    ppm_ok: bool,
    homing_ok: bool,
    homed: bool,
}

impl ModesCheck {
    fn print(&self, key: &str) {
        let ModesCheck { csv_ok, pvm_ok, ppm_ok, homing_ok, homed } = self;
        print(format_args!(
            "check.{key}=csv {csv_ok} pvm {pvm_ok} ppm {ppm_ok} homing {homing_ok}, homing ended {homed}\n"
        ));
    }
}

/// The bench task.
#[embassy_executor::task]
pub async fn bench() {
    let foc = foc_step_max();
    print(format_args!("source.foc_step=control::current_loop::foc_step\n"));
    print(format_args!("insn.foc_step={foc}\n"));

    // The data recorder records 8 channels at 25 kHz through the whole bench, both parts (a trigger that never
    // fires keeps it sampling): fast_tick_max, slow_tick_max, tier2_total_max and the other figures are taken
    // with it.
    let recorder_armed = arm_recorder(&RECORDER_CHANNELS, 1);
    let fast_before = tier1::FAST_TICKS.load(Ordering::Relaxed);
    let mut periods = Periods::pended();

    // CSP through the controlword on the free shaft: every slow tick so far is part of it.
    plant::select(Shaft::Free);
    let csp = csp(&mut periods);
    let slow_csp = tier2::SLOW_TICK_MAX.load(Ordering::Relaxed);
    let background_csp = tier2::BACKGROUND_MAX.load(Ordering::Relaxed);
    let csp_slow_ticks = tier2::SLOW_TICKS.load(Ordering::Relaxed);
    let (modes, modes_ok, modes_check) = other_modes(&mut periods);
    let background_max = tier2::BACKGROUND_MAX.load(Ordering::Relaxed);
    modes_check.print("modes_without_fault");
    let slow_max = modes.iter().fold(slow_csp, |max, (_, m)| max.max(*m));

    // «Disable voltage», then the speed profile on the direct power-stage path. Switch on: the offset calibration
    // runs at standstill during the plant's hold, which starts with the selection.
    plant::select(Shaft::Profile);
    let profile_start = periods.pended;
    let _ = tier2::with_drive(|d| d.dictionary_mut().set(h::CONTROLWORD, 0));
    let disabled = periods.run_until(HOLD_TICKS / 4, |d| {
        d.state() == PowerState::Off && statusword_state(d) == Some(State::SwitchOnDisabled)
    });
    let switched = tier2::with_drive(|d| d.switch_on().is_ok()).unwrap_or(false);
    let calibrated = periods.run_until(HOLD_TICKS.saturating_sub(periods.pended.wrapping_sub(profile_start)), |d| {
        d.state() == PowerState::SwitchedOn
    });
    // The rest of the hold, then the profile.
    let held = periods.pended.wrapping_sub(profile_start);
    periods.run(HOLD_TICKS.saturating_sub(held));
    let enabled = tier2::with_drive(|d| {
        d.set_demand_source(DemandSource::Internal);
        d.set_current_demand(Amps::ZERO);
        d.enable_operation().is_ok()
    })
    .unwrap_or(false);
    let step = PROFILE_TICKS.checked_div(DEMANDS_MA.len() as u32).unwrap_or(0);
    for ma in DEMANDS_MA {
        let _ = tier2::with_drive(|d| d.set_current_demand(Amps::from_milliamps(ma)));
        periods.run(step);
    }
    periods.run(PROFILE_TICKS.saturating_sub(step.saturating_mul(DEMANDS_MA.len() as u32)));
    let final_state = state();

    // The EtherCAT process-data cycle on the drive as it is now (operation enabled): measured with tier 1 held off.
    let ecat = tier2::with_drive(ecat_cycle_max).flatten();
    // One CANopen SYNC with its RPDO and TPDOs on a node of its own over the same drive, likewise.
    let can = tier2::with_drive(can_sync_max).flatten();
    // The DC phase-locked loop's work per SYNC0 pulse, and the refresh of its 64-period ARR pattern.
    let (pll_pulse, pll_pattern) = sync_pll_max();

    let fast = tier1::FAST_TICKS.load(Ordering::Relaxed).wrapping_sub(fast_before);
    let slow = tier2::SLOW_TICKS.load(Ordering::Relaxed);
    print(format_args!(
        "source.fast_tick=rt::app::fast_tick: the blocks taken from tier 2 when new, then \
         drive::tier1::Tier1State::fast_tick, plus the data recorder's copy of its values after the PWM write \
         (8 channels recorded at 25 kHz all along)\n"
    ));
    print(format_args!("insn.fast_tick_max={}\n", tier1::FAST_TICK_MAX.load(Ordering::Relaxed)));
    print(format_args!(
        "source.slow_tick=drive::Drive::slow_tick, the worst over CSP (0x60C2 = 1 ms), CSV, PVM, PPM and homing \
         (method 34), with the lock and the publications\n"
    ));
    print(format_args!("insn.slow_tick_max={slow_max}\ninsn.slow_tick_csp={slow_csp}\n"));
    let (plan_max, command_max, step_max) = profile_generator_max();
    print(format_args!(
        "source.profile_plan_max=control::trajectory::ProfileGenerator::prepare: planning a move and a velocity \
         command from the step after they were given (tier 2's background step, outside the slow tick); both \
         profile types\ninsn.profile_plan_max={plan_max}\n"
    ));
    print(format_args!(
        "source.profile_command_max=control::trajectory::ProfileGenerator: start_move, set_velocity_target (taken \
         for the next step), halt (planned at once), as the slow tick calls them; both profile types\n\
         insn.profile_command_max={command_max}\n"
    ));
    print(format_args!(
        "source.profile_step_max=control::trajectory::ProfileGenerator::step over a move and a velocity ramp\n\
         insn.profile_step_max={step_max}\n"
    ));
    for (name, max) in modes {
        print(format_args!("insn.slow_tick_{name}={max}\n"));
    }
    print(format_args!(
        "source.background=drive::Drive::background (parameter conversion, hardware supervision, actual values, \
         the profile generator's planning), with the report taken, the lock and the publications: in CSP \
         (background_csp) and the worst over all five modes (background_max)\n"
    ));
    print(format_args!("insn.background_csp={background_csp}\ninsn.background_max={background_max}\n"));
    print(format_args!(
        "source.ecat_cycle=ecat: SM2 window read, ProcessDataLayout::unpack_outputs, Drive::setpoint_received, \
         SyncCounters::sm_event, pack_inputs, SM3 window write (default PDO mapping)\n"
    ));
    print(format_args!("insn.ecat_cycle={}\n", ecat.unwrap_or(0)));
    print(format_args!(
        "source.can_sync=canopen: CanopenNode::handle_frame of one RPDO (synchronous: buffered), then of the SYNC \
         (4 TPDOs packed and queued, the RPDO unpacked, Drive::setpoint_received; default mappings, all valid, \
         type 1, operational)\n"
    ));
    let can_parts = can.map_or((0, 0), |c| (c.rpdo, c.sync));
    print(format_args!("insn.can_sync={}\n", can.map_or(0, |c| c.total)));
    print(format_args!("count.can_sync_rpdo_part={}\ncount.can_sync_sync_part={}\n", can_parts.0, can_parts.1));
    print(format_args!(
        "source.sync_pll=ecat::sync_pll: SyncPll::on_sync0 (phase detector, PI filter, lock detection; 1 ms cycle, \
         locked with a drifting phase)\n"
    ));
    print(format_args!("insn.sync_pll={pll_pulse}\n"));
    print(format_args!("source.sync_pll_pattern=ecat::sync_pll: SyncPll::fill_pattern (64 ARR values)\n"));
    print(format_args!("insn.sync_pll_pattern={pll_pattern}\n"));
    print(format_args!("count.fast_ticks={fast}\ncount.slow_ticks={slow}\n"));
    print(format_args!("count.csp_slow_ticks={csp_slow_ticks}\ncount.csp_setpoints={}\n", csp.setpoints));
    print(format_args!("csp.following_error_peak_inc={}\n", csp.following_error_peak));
    print(format_args!("drive.final_state={final_state:?}\n"));

    // The figures the checks below are about, before the timer-driven part adds its own.
    let slow_missed = tier2::SLOW_MISSED.load(Ordering::Relaxed);
    let overrun = tier1::OVERRUN.load(Ordering::Relaxed);
    let timed = timed_phase();
    let recording = tier2::RECORDER.with(|r| r.state());
    let lost = tier2::RECORDER.with(|r| r.lost()).unwrap_or(u32::MAX);
    // The recorder's drain of a slow period (ten snapshots) with one channel and with eight at 25 kHz, after the
    // timed part: their difference over 7 channels x 10 samples is the cost of a channel per sample; tier 1's copy
    // does not depend on the channels.
    let drain_1 = recorder_drain_cost(RECORDER_CHANNELS.get(..1).unwrap_or_default());
    let drain_8 = recorder_drain_cost(&RECORDER_CHANNELS);
    let recorder_ok = recorder_armed && drain_1.is_some() && drain_8.is_some();
    let (drain_1, drain_8) = (drain_1.unwrap_or(0), drain_8.unwrap_or(0));
    let per_channel = drain_8.saturating_sub(drain_1).div_ceil(7 * SLOW_TICK_DIVIDER);
    let copy = recorder_copy_cost();
    print(format_args!(
        "source.tier1_latency_max=tier 1 driven by SysTick every {PERIOD_INSTRUCTIONS} instructions through the CSP \
         move and the CSV, PVM, PPM and homing runs again, tier 3 serving SDO requests: from the period's start to \
         the handler, to a tick (6 instructions)\n"
    ));
    print(format_args!("insn.tier1_latency_max={}\n", timed.latency_max));
    print(format_args!(
        "source.masked_max=the longest wait of tier 1 past its own entry cost during the timer-driven part \
         (tier1_latency_max less the smallest latency): every section that holds tier 1 off and overlaps a period \
         start shows here\n"
    ));
    print(format_args!("insn.masked_max={}\n", timed.masked_max));
    print(format_args!("fast_missed={}\nslow_missed={}\n", timed.fast_missed, timed.slow_missed));
    print(format_args!("count.periods_lost_seen_by_tier1={}\n", timed.periods_lost));
    print(format_args!(
        "source.tier2_total_max=rt::tier2::slow_loop: the report taken, Drive::background, Drive::slow_tick, with \
         the lock and the publications, during the timer-driven part (preemptions by tier 1 included)\n"
    ));
    print(format_args!("insn.tier2_total_max={}\n", timed.tier2_total_max));
    print(format_args!(
        "source.setpoint_periods_late_max=rt::tier2::slow_loop: periods started between the raise of a slow tick and \
         the publication of its set-point, during the timer-driven part (0: published before the next period \
         starts); what the loops decide applies from the period LOOP_SETPOINT_DELAY_PERIODS after that one, so this \
         must not exceed it\n"
    ));
    print(format_args!("count.setpoint_periods_late_max={}\n", timed.setpoint_periods_late_max));
    print(format_args!(
        "source.report_publish=rt::tier1: Tier1State::report and its publication, every tenth period after the \
         PWM write\n"
    ));
    print(format_args!("insn.report_publish_max={}\n", tier1::REPORT_MAX.load(Ordering::Relaxed)));
    print(format_args!(
        "source.recorder=recorder: tier 1's fixed copy of its values into the ring, inside the fast tick \
         (recorder_tier1_copy, the same whatever is recorded, so 0 more per channel in tier 1), tier 3's drain of \
         a slow period (10 samples at 25 kHz) with one channel and with eight (recorder_drain_1ch, \
         recorder_drain_8ch, sections of 4 snapshots under the tier-2 lock), and their difference per channel and \
         sample (recorder_per_channel); 8 channels (6 currents, bus voltage, 0x6064) recorded at 25 kHz through \
         both parts of the bench, tier 3 draining\n"
    ));
    print(format_args!(
        "insn.recorder_tier1_copy={copy}\ninsn.recorder_drain_1ch={drain_1}\ninsn.recorder_drain_8ch={drain_8}\n\
         insn.recorder_per_channel={per_channel}\ncount.recorder_lost={lost}\n"
    ));
    print(format_args!("count.timed_periods={}\ncount.timed_fast_ticks={}\n", timed.periods, timed.fast_ticks));
    print(format_args!("count.timed_tier3_sdo_exchanges={}\n", timed.sdo_exchanges));
    // After the timed part, so that its phase against the period timer stays what it was without this item.
    let (resonance_step, resonance_estimate) = resonance_step_max();
    print(format_args!(
        "source.resonance_step_max=drive::resonance_identification::ResonanceIdentification::step (the auto \
         setup's step 7, mode -2, in the slow tick in place of the loops), every tick of a whole sweep on a rigid \
         shaft; and find_resonance on a two-mass response (the sweep's last tick runs it)\n\
         insn.resonance_step_max={resonance_step}\ninsn.resonance_estimate={resonance_estimate}\n"
    ));
    // Last, after every part: the deepest the stack has been since start-up (tier 3's bench task with tiers 2
    // and 1 preempting it), against the room between `.bss` and the top of the SRAM.
    let (stack_used, stack_size) = (super::stack::high_water(), super::stack::size());
    print(format_args!(
        "source.stack_used_max=rt::stack: the stack's high-water mark since start-up (the pattern painted at \
         start-up, found untouched below it) and stack_size, the SRAM between the end of .bss and the stack's top\n\
         bytes.stack_used_max={stack_used}\nbytes.stack_size={stack_size}\n"
    ));

    let mut ok = true;
    let mut check = |cond: bool, what: &str| {
        if !cond {
            print(format_args!("check failed: {what}\n"));
            ok = false;
        }
    };
    check(csp.enabled, "CSP: the controlword reached operation enabled");
    check(csp.follows_seen, "CSP: statusword bit 12 (drive follows the command value) was set");
    check(!csp.fault_seen && !csp.bit13_seen, "CSP: no fault and no following error");
    check(csp.stayed_enabled, "CSP: the drive stayed in operation enabled");
    check(modes_ok, "CSV, PVM, PPM and homing ran without a fault, and the homing ended");
    check(disabled, "disable voltage switched the power stage off");
    check(switched && calibrated, "switch-on calibrated the current offsets during the hold");
    check(enabled, "operation enabled");
    check(final_state == Some(PowerState::OperationEnabled), "the drive stayed in operation enabled");
    check(fast == periods.pended, "every pended ADC interrupt ran tier 1 once");
    check(slow == periods.pended / SLOW_TICK_DIVIDER, "tier 2 ran once per ten fast ticks");
    check(slow_missed == 0, "tier 2 missed no slow tick");
    check(!overrun, "no fast-tick overrun");
    check(timed.fast_ticks > 0, "the period timer drove tier 1");
    check(
        timed.motion_ok,
        "under the period timer CSP reached operation enabled and CSV, PVM, PPM and homing ran without a fault",
    );
    check(timed.periods_lost == timed.fast_missed, "tier 1 saw the periods the timer lost");
    check(
        timed.tier3_booted && timed.sdo_exchanges > 1_000 && timed.sdo_wrong_answers == 0,
        "tier 3 served SDO requests through its CANopen node all along the timed part, each answered",
    );
    check(recorder_ok, "the data recorder armed with 8 channels, then with 1 and 8 again");
    check(
        recording == Some(crate::recorder::RecorderState::Waiting) && lost == 0,
        "the data recorder was still sampling (waiting for its trigger) after both parts, no snapshot lost",
    );
    check(
        stack_used.saturating_add(STACK_HEADROOM) <= stack_size,
        "the stack stayed STACK_HEADROOM (8 KiB) or more above the statics",
    );
    check(ecat.is_some(), "the default PDO mapping compiles and the process-data cycle ran");
    check(
        can.is_some_and(|c| c.complete),
        "CANopen: the node booted, went operational, took every RPDO, and every SYNC queued 4 TPDOs",
    );
    exit(if ok { EXIT_OK } else { EXIT_CHECK_FAILED });
}

/// Room the stack must keep between its deepest point and `.bss` in the bench: the bench does not reach every
/// path of the board image (the EtherCAT slave, a CANopen SDO block transfer), whose frames may go deeper.
const STACK_HEADROOM: u32 = 8 * 1024;

/// The recorder's channels in the bench: the six currents of 0x3303, the bus voltage, the position actual value.
const RECORDER_CHANNELS: [u32; 8] =
    [0x3303_0100, 0x3303_0200, 0x3303_0300, 0x3303_0400, 0x3303_0500, 0x3303_0600, 0x3303_0900, 0x6064_0000];

/// Stops the recorder and arms it with `channels` every `period` current-loop periods (1: 25 kHz), as many
/// samples as fit and a trigger that never fires (the first channel rising through i32::MAX), through the
/// dictionary and the recorder's port as an SDO download would; whether every write was accepted.
fn arm_recorder(channels: &[u32], period: u16) -> bool {
    use crate::od::access::{AccessContext, CommState, NoApplicationObjects};
    use crate::recorder::objects::RecorderObjects;
    use crate::recorder::{sub, trigger, RECORDER, VARIABLES};
    let ctx = AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 8 };
    tier2::with_drive(|d| {
        tier2::RECORDER.with(|recorder| {
            let mut none = NoApplicationObjects;
            let mut port = RecorderObjects::new(recorder, &mut none);
            let dict = d.dictionary_mut();
            let mut write = |index: u16, s: u8, data: &[u8]| dict.write(index, s, data, ctx, &mut port).is_ok();
            let mut ok = write(RECORDER, sub::CONTROL, &[0]) && write(VARIABLES, 0, &[0]);
            for (k, c) in channels.iter().enumerate() {
                ok &= write(VARIABLES, (k as u8).wrapping_add(1), &c.to_le_bytes());
            }
            ok && write(VARIABLES, 0, &[channels.len() as u8])
                && write(RECORDER, sub::PERIOD, &period.to_le_bytes())
                && write(RECORDER, sub::SAMPLES, &0u32.to_le_bytes())
                && write(RECORDER, sub::MODE, &[trigger::RISING])
                && write(RECORDER, sub::TRIGGER_CHANNEL, &[1])
                && write(RECORDER, sub::THRESHOLD, &i32::MAX.to_le_bytes())
                && write(RECORDER, sub::CONTROL, &[1])
        })
    })
    .flatten()
    .unwrap_or(false)
}

/// The recorder armed with `channels` at 25 kHz, then the cost of draining ten fresh snapshots (one slow period)
/// in tier 3's sections ([`tier2::drain_recorder`]), the least over three slow periods; `None` if the arm failed.
fn recorder_drain_cost(channels: &[u32]) -> Option<u32> {
    if !arm_recorder(channels, 1) {
        return None;
    }
    // The first drain after arming switches tier 1's copy on.
    tier2::drain_recorder();
    let mut least = u32::MAX;
    for _ in 0..3 {
        // Ten periods pended without a drain between them (tier 1 copies, tier 2 takes the objects), then one.
        for _ in 0..SLOW_TICK_DIVIDER {
            NVIC::pend(Interrupt::Adc);
            cortex_m::asm::dsb();
            cortex_m::asm::isb();
        }
        let start = counter::now();
        tier2::drain_recorder();
        least = least.min(counter::now().wrapping_sub(start));
    }
    Some(least)
}

/// Tier 1's copy for the recorder alone (`tier1::record` into a ring of its own,
/// from a tier-1 state of the drive's settings), the least of a few runs less an empty measurement.
fn recorder_copy_cost() -> u32 {
    use crate::hal::power::PwmCommand;
    use crate::recorder::ring::SampleRing;
    static RING: SampleRing = SampleRing::new();
    let Some(t1) = tier2::with_drive(|d| crate::drive::tier1::Tier1State::new(d.settings())) else {
        return u32::MAX;
    };
    let pwm = black_box(PwmCommand { duty: [1, 2, 3], enabled: true });
    RING.set_enabled(true);
    let measure = |push: bool| {
        let start = counter::now();
        core::sync::atomic::compiler_fence(Ordering::SeqCst);
        if push {
            super::tier1::record(&RING, black_box(&t1), &pwm);
        }
        core::sync::atomic::compiler_fence(Ordering::SeqCst);
        counter::now().wrapping_sub(start)
    };
    let overhead = (0..4).map(|_| measure(false)).min().unwrap_or(0);
    (0..4).map(|_| measure(true)).min().unwrap_or(0).saturating_sub(overhead)
}

/// What the timer-driven part measured.
struct TimedRun {
    /// Tier 3's CANopen node booted, its SDO exchanges, and the answers that were wrong.
    tier3_booted: bool,
    sdo_exchanges: u32,
    sdo_wrong_answers: u32,
    latency_max: u32,
    masked_max: u32,
    periods_lost: u32,
    tier2_total_max: u32,
    setpoint_periods_late_max: u32,
    fast_missed: u32,
    slow_missed: u32,
    periods: u32,
    fast_ticks: u32,
    /// The CSP move reached operation enabled, and CSV, PVM, PPM and homing ran without a fault, under the timer.
    motion_ok: bool,
}

/// Tier 1 at the real period (SysTick, `board::period_timer`) while tier 2 runs the CSP move of the first part
/// again (from «Switch on disabled» through the controlword, on the free shaft) and tier 3 (this task) serves SDO
/// requests through a CANopen node over the drive between the set-points ([`Tier3Load`]): the latency of tier 1,
/// its longest wait, the periods and slow ticks lost, tier 2's whole step.
fn timed_phase() -> TimedRun {
    plant::select(Shaft::Free);
    let _ = tier2::with_drive(|d| {
        d.set_current_demand(Amps::ZERO);
        d.dictionary_mut().set(h::CONTROLWORD, 0);
    });
    tier1::TIER1_LATENCY_MAX.store(0, Ordering::Relaxed);
    tier1::TIER1_LATENCY_MIN.store(u32::MAX, Ordering::Relaxed);
    tier2::TIER2_TOTAL_MAX.store(0, Ordering::Relaxed);
    tier2::SETPOINT_PERIODS_LATE_MAX.store(0, Ordering::Relaxed);
    let lost_before = tier1::PERIODS_LOST.load(Ordering::Relaxed);
    tier1::FAST_MISSED.store(0, Ordering::Relaxed);
    let slow_missed_before = tier2::SLOW_MISSED.load(Ordering::Relaxed);
    let fast_before = tier1::FAST_TICKS.load(Ordering::Relaxed);
    let start = counter::now();
    tier1::LAST_UPDATE.store(start, Ordering::Relaxed);
    // Tier 1 supervises its own periods while the timer drives it (a lost one would trip the drive).
    tier1::PERIOD_SUPERVISED.store(true, Ordering::Relaxed);
    period_timer::start();
    let load = Tier3Load::new();
    let booted = load.is_some();
    let mut periods = Periods::timed(start, load);
    // Back to «Switch on disabled» first (the first part ended on the direct power-stage path), with other motion
    // parameters converted, so that the CSP start converts its own again as a master's start-up does (the
    // longest background step: `insn.background_max`).
    let _ = tier2::with_drive(|d| {
        d.dictionary_mut().set(h::MODES_OF_OPERATION, 0i8);
        d.dictionary_mut().set(h::INTERPOLATION_TIME_PERIOD_VALUE, 2);
    });
    let disabled = periods.run_until(STATE_TIMEOUT_TICKS, |d| statusword_state(d) == Some(State::SwitchOnDisabled));
    periods.run(2 * SLOW_TICK_DIVIDER);
    let run = csp(&mut periods);
    // Then the profile modes and CSV, so that the whole tier-2 step is measured with the profile generator's
    // planning ticks as well (their slow ticks alone are measured in the first part, without tier 1's preemptions).
    let (_, modes_ok, modes_check) = other_modes(&mut periods);
    modes_check.print("timed_modes_without_fault");
    period_timer::stop();
    let (exchanges, wrong_answers) = periods.load.as_ref().map_or((0, 0), |l| (l.exchanges, l.wrong_answers));
    tier1::PERIOD_SUPERVISED.store(false, Ordering::Relaxed);
    let latency_max = tier1::TIER1_LATENCY_MAX.load(Ordering::Relaxed);
    TimedRun {
        latency_max,
        masked_max: latency_max.saturating_sub(tier1::TIER1_LATENCY_MIN.load(Ordering::Relaxed)),
        periods_lost: tier1::PERIODS_LOST.load(Ordering::Relaxed).wrapping_sub(lost_before),
        tier2_total_max: tier2::TIER2_TOTAL_MAX.load(Ordering::Relaxed),
        setpoint_periods_late_max: tier2::SETPOINT_PERIODS_LATE_MAX.load(Ordering::Relaxed),
        fast_missed: tier1::FAST_MISSED.load(Ordering::Relaxed),
        slow_missed: tier2::SLOW_MISSED.load(Ordering::Relaxed).wrapping_sub(slow_missed_before),
        periods: periods.pended,
        fast_ticks: tier1::FAST_TICKS.load(Ordering::Relaxed).wrapping_sub(fast_before),
        motion_ok: disabled && run.enabled && modes_ok,
        tier3_booted: booted,
        sdo_exchanges: exchanges,
        sdo_wrong_answers: wrong_answers,
    }
}

/// The largest cost of [`crate::ecat::sync_pll::SyncPll::on_sync0`] over 64 pulses of a 1 ms cycle whose phase
/// drifts by one tick per pulse (the loop keeps correcting), and of one `fill_pattern` (counter units, overhead
/// of the counter reads subtracted).
fn sync_pll_max() -> (u32, u32) {
    use crate::ecat::sync_pll::{Sync0Capture, SyncPll, DITHER_LEN};
    let mut pll = SyncPll::new();
    let _ = pll.start(1_000_000);
    let overhead = {
        let start = counter::now();
        compiler_fence(Ordering::SeqCst);
        counter::now().wrapping_sub(start)
    };
    let mut max = 0;
    let mut period: u32 = 0;
    for k in 0..64u16 {
        let capture = Sync0Capture { period, ticks: 3_300u16.wrapping_add(k) };
        let start = counter::now();
        compiler_fence(Ordering::SeqCst);
        black_box(pll.on_sync0(black_box(capture)));
        compiler_fence(Ordering::SeqCst);
        max = max.max(counter::now().wrapping_sub(start).saturating_sub(overhead));
        period = period.wrapping_add(25);
    }
    let mut pattern = [0u16; DITHER_LEN];
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    pll.fill_pattern(black_box(&mut pattern));
    compiler_fence(Ordering::SeqCst);
    let fill = counter::now().wrapping_sub(start).saturating_sub(overhead);
    black_box(&pattern);
    (max, fill)
}

/// An ESC that is plain memory (registers and process RAM), for counting the process-data cycle's own work: the
/// real PDI access (SPI to the ESC chip) is the board driver's and costs bus time, not instructions.
struct MemoryEsc {
    memory: [u8; MEMORY_ESC_BYTES],
}

/// Registers and the process RAM up to the default SM2/SM3 windows.
const MEMORY_ESC_BYTES: usize = 0x1200;
/// Start of SM2 (outputs) and SM3 (inputs) of the drive's SII.
const SM2_START: u16 = 0x1100;
const SM3_START: u16 = 0x1180;

impl crate::ecat::esc::Esc for MemoryEsc {
    fn read(&mut self, address: u16, buf: &mut [u8]) {
        let start = usize::from(address);
        if let Some(src) = self.memory.get(start..start.saturating_add(buf.len())) {
            buf.copy_from_slice(src);
        }
    }
    fn write(&mut self, address: u16, data: &[u8]) {
        let start = usize::from(address);
        if let Some(dst) = self.memory.get_mut(start..start.saturating_add(data.len())) {
            dst.copy_from_slice(data);
        }
    }
}

/// The largest cost of the per-cycle process-data path over a few cycles (counter units, overhead of the
/// counter reads subtracted): what `ecat::slave::EthercatSlave::cycle` does in OP with the default mapping.
/// `None` if the default mapping does not compile.
fn ecat_cycle_max(drive: &mut Drive) -> Option<u32> {
    use crate::ecat::esc::Esc as _;
    use crate::ecat::process_data::ProcessDataLayout;
    use crate::ecat::sync::{SyncCounters, SyncMode, Synchronisation};
    let layout = ProcessDataLayout::from_dictionary(drive.dictionary()).ok()?;
    let mut esc = MemoryEsc { memory: [0; MEMORY_ESC_BYTES] };
    let sync =
        Synchronisation { mode: SyncMode::SmSynchronous, cycle_ns: 1_000_000, sync0_cycle_ns: 0, current_periods: 25 };
    let mut counters = SyncCounters::new(&sync, 4);
    let (mut outputs, mut inputs) = ([0u8; 40], [0u8; 40]);
    let out_len = usize::from(layout.output_bytes).min(outputs.len());
    let in_len = usize::from(layout.input_bytes).min(inputs.len());
    // The master's outputs: an all-zero image (the copy's cost does not depend on the values; this runs after
    // the bench's checks of the drive's state, so the values written do not disturb them).
    let overhead = {
        let start = counter::now();
        compiler_fence(Ordering::SeqCst);
        counter::now().wrapping_sub(start)
    };
    let mut max = 0;
    for k in 0..8u32 {
        let start = counter::now();
        compiler_fence(Ordering::SeqCst);
        let out = outputs.get_mut(..out_len).unwrap_or(&mut []);
        esc.read(SM2_START, out);
        counters.sm_event(k.wrapping_mul(1_000_000));
        layout.unpack_outputs(out, drive.dictionary_mut());
        drive.setpoint_received();
        let inp = inputs.get_mut(..in_len).unwrap_or(&mut []);
        layout.pack_inputs(drive.dictionary(), inp);
        esc.write(SM3_START, inp);
        compiler_fence(Ordering::SeqCst);
        let cost = counter::now().wrapping_sub(start).saturating_sub(overhead);
        max = max.max(cost);
    }
    black_box(&inputs);
    Some(max)
}

/// What [`can_sync_max`] measured (counter units, overhead subtracted): the largest SYNC cycle, and its two parts.
#[derive(Clone, Copy)]
struct CanSync {
    /// `handle_frame` of the RPDO plus that of the SYNC, the largest over the cycles.
    total: u32,
    /// The RPDO's part of the largest cycle.
    rpdo: u32,
    /// The SYNC's part of the largest cycle.
    sync: u32,
    /// Every SYNC queued the four TPDOs, no RPDO was ignored, nothing was dropped.
    complete: bool,
}

/// The CANopen SYNC path (issue 8, `insn.can_sync` <= 1,500) as the CAN receive interrupt would run it
/// (`canopen` module documentation, tier 2): a node with node-ID 1 over the bench's drive, its default mappings
/// made valid (the TPDOs 2..4 ship not valid) and synchronous (RPDO type 1: applied at the next SYNC; TPDO
/// type 1: sent at every SYNC), written between the power-on reset and the boot as a runtime with stored
/// communication parameters does; NMT start. Then 8 cycles, each one RPDO (RPDO 1..4 in turn, 8 bytes) and one
/// SYNC without counter through `CanopenNode::handle_frame`; the frames queued are taken out between cycles
/// (tier 3's work, not measured). `None` if the node did not reach operational.
fn can_sync_max(drive: &mut Drive) -> Option<CanSync> {
    use crate::canopen::frame::CanFrame;
    use crate::canopen::nmt::NmtState;
    use crate::canopen::pdo::{comm_index, COB_NO_RTR, PDO_COUNT};
    use crate::canopen::{ids, CanopenNode, NodeEvent};
    use crate::od::access::NoApplicationObjects;
    use crate::od::pdo_map::Direction;
    const NODE: u8 = 1;
    let mut app = NoApplicationObjects;
    let mut node = CanopenNode::new(NODE);
    if !matches!(node.process(drive, &mut app, 0), Some(NodeEvent::Reset { .. })) {
        return None;
    }
    let mut configured = true;
    for (n, base) in ids::TPDO_BASE.iter().enumerate().take(PDO_COUNT) {
        let d = drive.dictionary_mut();
        configured &= ids::write(d, comm_index(Direction::Rx, n), 2, 1);
        let cob = u64::from(ids::cob_id(*base, NODE)) | u64::from(COB_NO_RTR);
        configured &= ids::write(d, comm_index(Direction::Tx, n), 1, cob);
        configured &= ids::write(d, comm_index(Direction::Tx, n), 2, 1);
    }
    if !configured || node.process(drive, &mut app, 0) != Some(NodeEvent::Booted) {
        return None;
    }
    node.handle_frame(&CanFrame::new(ids::NMT, &[0x01, NODE])?, drive, &mut app, 0);
    if node.state() != NmtState::Operational {
        return None;
    }
    while node.transmit().is_some() {}
    let sync = CanFrame::new(ids::SYNC, &[])?;
    let overhead = counter::read_overhead();
    let mut best = CanSync { total: 0, rpdo: 0, sync: 0, complete: true };
    for k in 0..8u32 {
        let base = ids::RPDO_BASE.get(k as usize % PDO_COUNT).copied().unwrap_or(0x200);
        let rpdo = CanFrame::new(ids::cob_id(base, NODE), &[0; 8])?;
        let now_us = u64::from(k.wrapping_add(1)).wrapping_mul(1_000);
        let before = node.counters();
        let t0 = counter::now();
        compiler_fence(Ordering::SeqCst);
        node.handle_frame(black_box(&rpdo), drive, &mut app, now_us);
        compiler_fence(Ordering::SeqCst);
        let t1 = counter::now();
        compiler_fence(Ordering::SeqCst);
        node.handle_frame(black_box(&sync), drive, &mut app, now_us);
        compiler_fence(Ordering::SeqCst);
        let t2 = counter::now();
        let rpdo_cost = t1.wrapping_sub(t0).saturating_sub(overhead);
        let sync_cost = t2.wrapping_sub(t1).saturating_sub(overhead);
        let total = rpdo_cost.saturating_add(sync_cost);
        if total > best.total {
            best = CanSync { total, rpdo: rpdo_cost, sync: sync_cost, complete: best.complete };
        }
        let mut tpdos = 0u32;
        while let Some(frame) = node.transmit() {
            tpdos = tpdos.wrapping_add(u32::from(ids::TPDO_BASE.iter().any(|b| frame.id() == ids::cob_id(*b, NODE))));
        }
        let counters = node.counters();
        best.complete &= tpdos == 4
            && counters.syncs == before.syncs.wrapping_add(1)
            && counters.ignored == before.ignored
            && counters.tx_dropped == 0;
    }
    Some(best)
}

/// The auto setup's resonance step alone (counter units): the longest `step` over a whole sweep on a rigid shaft
/// (the geared preset's inertia and torque constant; the position the double integral of the demand), and
/// `find_resonance` on the normalized response the geared preset gave (a dip and a peak, so both parabolas run).
fn resonance_step_max() -> (u32, u32) {
    use crate::drive::mechanical_identification::MechanicalSample;
    use crate::drive::resonance_identification::{
        find_resonance, ResonanceConfig, ResonanceIdentification, ResonanceStatus, PERIODS,
    };
    /// |G|^2 of the geared preset's sweep (drive-sim identify), rounded.
    const GEARED_RESPONSE: [f32; 30] = [
        0.77, 0.67, 0.57, 0.45, 0.31, 0.16, 0.04, 0.005, 0.2, 0.87, 2.6, 6.7, 15.6, 34.7, 79.2, 193.1, 586.0, 2888.0,
        12688.0, 1866.0, 1146.0, 744.0, 583.0, 458.0, 384.0, 349.0, 333.0, 332.0, 336.0, 332.0,
    ];
    let config = ResonanceConfig {
        current_limit: Amps::from_milliamps(5_000),
        max_speed_rpm: 2_000,
        counts_per_rev: 5_000,
        inertia: 3_200_000,
        torque_constant: 100_000,
        coulomb_friction: 20_000,
        timeout_ticks: 50_000,
    };
    let mut step = ResonanceIdentification::new(&config);
    // Rigid shaft: 0.1 Nm/A / 3.2e-4 kg m^2, in counts per tick^2 per A: 312.5 rad/s^2 x 5000 / 2 pi / 2500^2.
    let (mut position, mut speed, mut i_q) = (0.0f32, 0.0f32, 0.0f32);
    let mut step_max = 0u32;
    loop {
        speed += i_q * 0.039_8;
        position += speed;
        let sample = MechanicalSample {
            position: position as i32,
            i_q: Amps::from_bits((i_q * 65_536.0) as i32),
            ..MechanicalSample::default()
        };
        let start = counter::now();
        compiler_fence(Ordering::SeqCst);
        let status = black_box(step.step(black_box(&sample)));
        compiler_fence(Ordering::SeqCst);
        step_max = step_max.max(counter::now().wrapping_sub(start));
        match status {
            ResonanceStatus::Running { i_q_demand } => i_q = i_q_demand.to_bits() as f32 / 65_536.0,
            ResonanceStatus::Done(_) | ResonanceStatus::Failed(_) => break,
        }
    }
    let start = counter::now();
    compiler_fence(Ordering::SeqCst);
    black_box(find_resonance(black_box(&PERIODS), black_box(&GEARED_RESPONSE)));
    compiler_fence(Ordering::SeqCst);
    (step_max, counter::now().wrapping_sub(start))
}

/// The profile generator alone (`control::trajectory::ProfileGenerator`), both profile types (0x6086 = 0, 1) at
/// 4096 inc/rev: the longest planning call over a position move of `PPM_DISTANCE_INC` from rest, a velocity
/// command to `MODES_RPM` and a halt from it, and the longest `step` over the move and the velocity ramp (counter
/// units; these are the parts of the profile modes' slow tick that `insn.slow_tick_<mode>` shows on top of the
/// loops).
/// The profile generator's costs: (planning, in `prepare`; a command or stop as the slow tick gives it; one step).
fn profile_generator_max() -> (u32, u32, u32) {
    use crate::control::trajectory::{ChangeMode, MotionScale, ProfileGenerator, ProfileObjects};
    let scale = MotionScale::new(4096);
    let timed = |f: &mut dyn FnMut()| {
        let start = counter::now();
        compiler_fence(Ordering::SeqCst);
        f();
        compiler_fence(Ordering::SeqCst);
        counter::now().wrapping_sub(start)
    };
    let (mut plan_max, mut command_max, mut step_max) = (0u32, 0u32, 0u32);
    for motion_profile_type in [0i16, 1] {
        let objects = ProfileObjects {
            motion_profile_type,
            profile_velocity: MODES_RPM.unsigned_abs(),
            ..ProfileObjects::default()
        };
        let Ok(params) = objects.profile_params(&scale) else { continue };
        let velocity = scale.velocity_from_rpm(i64::from(MODES_RPM));
        let mut generator = black_box(ProfileGenerator::new(0));
        command_max = command_max.max(timed(&mut || {
            let _ =
                black_box(generator.start_move(i64::from(PPM_DISTANCE_INC), false, &params, ChangeMode::Immediately));
        }));
        // Each step, with the planning between steps as tier 2's background step runs it.
        while !generator.is_done() {
            step_max = step_max.max(timed(&mut || {
                black_box(generator.step());
            }));
            plan_max = plan_max.max(timed(&mut || generator.prepare()));
        }
        command_max = command_max.max(timed(&mut || {
            let _ = black_box(generator.set_velocity_target(velocity, &params));
        }));
        while !generator.is_done() {
            step_max = step_max.max(timed(&mut || {
                black_box(generator.step());
            }));
            plan_max = plan_max.max(timed(&mut || generator.prepare()));
        }
        command_max = command_max.max(timed(&mut || generator.halt(params.deceleration)));
    }
    (plan_max, command_max, step_max)
}
