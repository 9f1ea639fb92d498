//! Profile position mode (PPM, 0x6060 = 1): the CiA 402 layer on top of the
//! [`ProfileGenerator`]: the set-point handshake of controlword bit 4 / statusword bit 12, change set immediately
//! (bit 5), relative moves (bit 6), halt (bit 8), Nanotec's change on set-point (bit 9), and "target reached"
//! (bit 10) with the position window 0x6067/0x6068 (`shared/spec/cia402-device-control.md` §2.1, §6).
//! The motion itself (ramps, change on the fly, the one-deep buffer, the blend) is the generator's.
//!
//! # Set-point handshake (IDX Tables 3-15, 3-18 L640-674; E3 Tables 5-17, 5-20 L1510-1556; NT p.48-49 L223-225)
//! - A **rising edge of bit 4** arms a request. The request is *taken* (handed to the generator with 0x607A, bit 5,
//!   bit 6, bit 9 and the profile parameters of that tick) at the first step where the generator has room: at
//!   once when nothing is buffered, or, with bit 5 = 0 during a move whose buffer is full, as soon as the
//!   buffered move starts (the tick the buffer frees, NT "bit 12 goes back to 0 when another travel command can
//!   be buffered"). The request lapses when bit 4 falls before it was taken (NT: "if the buffer is full a new
//!   set-point is ignored"). A bit 4 already set when the mode is entered is no edge.
//! - **Bit 12** = "set-point taken and bit 4 still set" OR "the buffer holds a move": it rises in the step that
//!   takes the set-point, falls in the first step that sees bit 4 = 0 — unless the taken move waits in the
//!   buffer, then it stays set until the buffered move starts (IDX: "1 = the previous setpoint has been assumed
//!   and no additional setpoint may be accepted").
//! - A set-point the generator refuses (`MoveError::ZeroLimit`: profile velocity, acceleration or deceleration
//!   0) is **not acknowledged**: bit 12 stays 0, nothing moves, and the request is dropped — the master must give
//!   a new edge of bit 4 (NT p.48-49: "bit 12 is not set if the new target can't be reached within the limits").
//! - Bit 5 = 1 → [`ChangeMode::Immediately`]; bit 5 = 0 and bit 9 = 1 (Nanotec only, maxon: reserved) →
//!   [`ChangeMode::AfterCurrentNoStop`]; otherwise [`ChangeMode::AfterCurrent`] (the axis stops at each target).
//!   Bit 6 = 1: relative to the preceding target (NT 0x60F2 value 0, the generator's rule).
//!
//! # Target reached (bit 10)
//! - Position move, halt = 0: the generator has finished the move (demand = target, nothing buffered: IDX "the
//!   actual positioning is considered as completed as soon as the position demand value reaches the target
//!   position") AND the position actual value has been within ±0x6067 of the target for 0x6068 (E3 L6922-6987,
//!   "within the position window during the defined position window time"). The window time runs from the first
//!   tick the actual value is inside, even while the demand still moves, so the bit adds no delay beyond the
//!   window time to the end of the trajectory. Leaving the window clears the bit and restarts the time.
//!   0x6067 = 0xFFFFFFFF (`None`): the bit is set at the end of the trajectory (E3 L6932-6934).
//! - Halt = 1 (IDX Table 3-18 L666-674: "Halt = 1: velocity of axis is 0"): the halt ramp has ended and the
//!   velocity actual value is within the zero-speed threshold 0x606F.
//! - No position move of this mode (since entry, whatever the generator did before; after a halt that was
//!   released): the same "at rest" rule, so on entry at rest the bit is 1 at once.
//!
//! # Halt (bit 8) — choice where the seeds differ
//! While bit 8 = 1 the generator stops with the halt deceleration (0x605D → 0x6084 or 0x6085; maxon: always
//! 0x6084, IDX L645 "stop axis with profile deceleration") and new set-points wait (an edge of bit 4 stays armed
//! while bit 4 is held and is taken when the halt is released). Releasing the halt does **not** resume the
//! interrupted move: maxon's IDX/E3 tables describe only "execute or continue positioning" / "stop axis" and no
//! restart, whereas Gamma resumes "if possible" [GT L882] and Nanotec "restarts motion according to presets"
//! [NT p.47 L221]; we follow maxon (spec §1.6), the master issues a new set-point.
//!
//! # Entry
//! [`ProfilePosition::enter`] forgets every request and latches the controlword's bit 4. If the generator is not
//! at rest (a mode change in motion), the first step stops it with the profile deceleration 0x6084 (no PPM
//! set-point is active, so nothing is to be followed); a set-point taken meanwhile replaces the stop.
//!
//! Bit 13 (following error) belongs to the monitor and is left 0. IDX bit 15 (endless movement) and the software
//! position limit 0x607D (target clamping) are not handled here.

use super::{AxisFeedback, LoopDemand, ModeStatus, ModeStep, Windows};
use crate::cia402::controlword::Controlword;
use crate::cia402::Ticks;
use crate::control::trajectory::{Acceleration, ChangeMode, MoveAccepted, MoveError, ProfileGenerator, ProfileParams};
use crate::control::trajectory::{Setpoint, Velocity};

/// The inputs of one PPM step, in internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PpmInput {
    /// 0x6040 (bits 4 new set-point, 5 change set immediately, 6 relative, 8 halt, 9 change on set-point).
    pub controlword: Controlword,
    /// 0x607A target position, increments.
    pub target_position: i32,
    /// 0x6081, 0x6083, 0x6084, 0x6086 bounded by 0x607F, 0x60C5, 0x60C6.
    pub params: ProfileParams,
    /// Deceleration of a halt (0x605D: 0x6084 or 0x6085).
    pub halt_deceleration: Acceleration,
    /// Target-reached windows.
    pub windows: Windows,
}

/// "Inside a window for the window time" (0x6067/0x6068, 0x606D/0x606E): the time runs from the first tick
/// inside; once reached it stays reached while inside, so the wrap of the tick counter never clears it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub(crate) struct WindowTimer {
    since: Option<Ticks>,
    reached: bool,
}

impl WindowTimer {
    /// Outside, no time counted.
    pub(crate) const fn new() -> Self {
        Self { since: None, reached: false }
    }

    /// Restarts the time (a new target).
    pub(crate) fn reset(&mut self) {
        *self = Self::default();
    }

    /// Feeds this tick's comparison; returns whether the value has been inside for at least `time`.
    pub(crate) fn update(&mut self, inside: bool, now: Ticks, time: Ticks) -> bool {
        if !inside {
            self.reset();
            return false;
        }
        if !self.reached {
            let since = *self.since.get_or_insert(now);
            self.reached = now.since(since) >= time;
        }
        self.reached
    }
}

/// "Speed is zero": |velocity| within the threshold 0x606F (magnitudes, saturating).
pub(crate) fn speed_is_zero(velocity: Velocity, threshold: Velocity) -> bool {
    velocity.to_bits().unsigned_abs() <= threshold.to_bits().unsigned_abs()
}

/// The PPM state (set-point handshake, target-reached timing).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ProfilePosition {
    /// Bit 4 of the previous step (edge detection).
    previous_bit4: bool,
    /// A rising edge of bit 4 not yet taken (bit 4 still set).
    request: bool,
    /// A set-point was taken since bit 4 last rose (bit 12 until bit 4 falls).
    acknowledged: bool,
    /// Bit 8 has been applied to the generator.
    halted: bool,
    /// The motion found on entry is still to be stopped (first step).
    stop_on_entry: bool,
    /// A set-point has been taken since entry (before, the generator's target is another mode's).
    has_move: bool,
    /// The target the window timer refers to (`None`: no position move).
    window_target: Option<i64>,
    /// Position window timer.
    window: WindowTimer,
}

impl ProfilePosition {
    /// A mode with no set-point.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            previous_bit4: false,
            request: false,
            acknowledged: false,
            halted: false,
            stop_on_entry: false,
            has_move: false,
            window_target: None,
            window: WindowTimer::new(),
        }
    }

    /// Called when PPM becomes the followed mode (operation enabled, or a mode change), with the controlword of
    /// that tick; `generator` already stands at the demand the axis continues from.
    ///
    /// Bit 4 as it is now counts as the previous level (a bit 4 already set starts nothing). If the generator
    /// is moving, the first step stops it with the profile deceleration.
    pub fn enter(&mut self, controlword: Controlword, generator: &mut ProfileGenerator, feedback: &AxisFeedback) {
        let _ = feedback;
        let moving = !generator.is_done() || generator.setpoint().velocity != Velocity::ZERO;
        *self = Self {
            previous_bit4: controlword.operation_mode_bits().bit4,
            stop_on_entry: moving,
            window_target: generator.target(),
            ..Self::new()
        };
        // Consume a stale flag so that it is not mistaken for a move of this mode.
        let _ = generator.take_buffered_started();
    }

    /// Whether a rising edge of bit 4 waits to be taken (buffer full or halt active).
    #[must_use]
    pub const fn request_pending(&self) -> bool {
        self.request
    }

    /// One slow tick.
    pub fn step(&mut self, input: &PpmInput, generator: &mut ProfileGenerator, feedback: &AxisFeedback) -> ModeStep {
        let bits = input.controlword.operation_mode_bits();
        let halt = input.controlword.halt();

        // Bit 4: a rising edge arms a request; a low level ends the acknowledge and drops an untaken request.
        if !bits.bit4 {
            self.request = false;
            self.acknowledged = false;
        } else if !self.previous_bit4 {
            self.request = true;
        }
        self.previous_bit4 = bits.bit4;

        if core::mem::take(&mut self.stop_on_entry) && !halt {
            generator.halt(input.params.deceleration);
        }
        if halt {
            if !self.halted {
                generator.halt(input.halt_deceleration);
                self.halted = true;
            }
        } else {
            // Releasing the halt does not resume the interrupted move (maxon; see the module docs).
            self.halted = false;
            self.take_request(input, generator);
        }

        let setpoint: Setpoint = generator.step();

        if generator.take_buffered_started() {
            // The buffered move has started: the buffer has room again, so a waiting request is taken now
            // (it goes into the buffer behind the move just started, without changing this tick's sample).
            self.window.reset();
            if !self.halted {
                self.take_request(input, generator);
            }
        }

        let status = ModeStatus {
            target_reached: self.target_reached(&input.windows, generator, feedback),
            bit12: self.acknowledged || !generator.buffer_free(),
            bit13: false,
        };
        ModeStep { demand: LoopDemand::Position(setpoint), status }
    }

    /// Hands a waiting request to the generator.
    fn take_request(&mut self, input: &PpmInput, generator: &mut ProfileGenerator) {
        if !self.request {
            return;
        }
        let bits = input.controlword.operation_mode_bits();
        let change = if bits.bit5 {
            ChangeMode::Immediately
        } else if bits.bit9 {
            ChangeMode::AfterCurrentNoStop
        } else {
            ChangeMode::AfterCurrent
        };
        match generator.start_move(i64::from(input.target_position), bits.bit6, &input.params, change) {
            Ok(accepted) => {
                self.request = false;
                self.acknowledged = true;
                self.has_move = true;
                if accepted == MoveAccepted::Started {
                    self.window.reset();
                }
            }
            // Stays armed while bit 4 is held; taken when the buffered move starts.
            Err(MoveError::BufferFull) => {}
            // Not acknowledged; a new edge of bit 4 is needed.
            Err(MoveError::ZeroLimit) => self.request = false,
        }
    }

    /// Statusword bit 10 after this tick's generator step.
    fn target_reached(&mut self, windows: &Windows, generator: &ProfileGenerator, feedback: &AxisFeedback) -> bool {
        let target = generator.target();
        if target != self.window_target {
            self.window_target = target;
            self.window.reset();
        }
        let target = match target {
            Some(target) if self.has_move && !self.halted => target,
            // Halted, or no position move of this mode: "velocity of axis is 0".
            _ => {
                self.window.reset();
                return generator.is_done() && speed_is_zero(feedback.velocity, windows.velocity_threshold);
            }
        };
        let Some(window) = windows.position_window else {
            // 0x6067 = 0xFFFFFFFF: end of the trajectory (E3 L6932-6934).
            return generator.is_done();
        };
        // Positions wrap like 0x6064: compare in the 32-bit circle (the truncation is the wrap).
        let error = (target as i32).wrapping_sub(feedback.position).unsigned_abs();
        let settled = self.window.update(error <= window, feedback.now, windows.position_window_time);
        settled && generator.is_done()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::trajectory::{
        planned_duration_ticks, MotionScale, ProfileObjects, ProfileParams, ProfileType, Velocity,
    };

    const NEW_SET_POINT: u16 = Controlword::OMS_4;
    const IMMEDIATELY: u16 = Controlword::OMS_5;
    const RELATIVE: u16 = Controlword::OMS_6;
    const HALT: u16 = Controlword::HALT;
    const CHANGE_ON_SET_POINT: u16 = Controlword::OMS_9;

    /// «Enable operation» plus the given mode bits.
    fn cw(bits: u16) -> Controlword {
        Controlword(0x000F | bits)
    }

    /// Dictionary-derived parameters (device.toml defaults: 1000 rpm, 10,000 rpm/s, 4096 inc/rev): durations are
    /// fractional numbers of ticks.
    fn dictionary_params(profile: ProfileType) -> ProfileParams {
        let objects = ProfileObjects { motion_profile_type: profile.to_0x6086(), ..ProfileObjects::default() };
        objects.profile_params(&MotionScale::new(4096)).unwrap()
    }

    /// Binary parameters: 8 inc/tick, 1/8 inc/tick² — ramps of exactly 64 ticks and 256 inc, so a move of
    /// 1024 inc lasts exactly 64 + 64 + 64 = 192 ticks and chains of moves add up exactly.
    fn binary_params() -> ProfileParams {
        ProfileParams {
            profile_type: ProfileType::Trapezoidal,
            velocity: Velocity::from_inc_per_tick(8),
            max_velocity: Velocity::from_inc_per_tick(16),
            acceleration: Acceleration::from_bits(1 << 37),
            deceleration: Acceleration::from_bits(1 << 37),
        }
    }

    /// At the profile velocity up to the generator's residual correction (a few LSB of 2^-32 inc/tick).
    fn cruising(v: Velocity, profile: Velocity) -> bool {
        (v.to_bits() - profile.to_bits()).abs() < 1 << 12
    }

    fn windows(window: Option<u32>, time: u32) -> Windows {
        Windows {
            position_window: window,
            position_window_time: Ticks(time),
            velocity_window: Velocity::ZERO,
            velocity_window_time: Ticks(0),
            velocity_threshold: Velocity::from_bits(1 << 20),
        }
    }

    fn input(bits: u16, target: i32, params: ProfileParams, windows: Windows) -> PpmInput {
        PpmInput {
            controlword: cw(bits),
            target_position: target,
            params,
            halt_deceleration: params.deceleration,
            windows,
        }
    }

    /// How the actual values follow the demand.
    #[derive(Clone, Copy)]
    enum Plant {
        /// Actual = the demand of the previous tick (one tick of transport delay, exact).
        Delay,
        /// First-order lag: the actual position moves 1/4 of the remaining error per tick.
        Lag,
    }

    /// The mode, its generator and a kinematic axis, stepped one slow tick at a time.
    struct Rig {
        ppm: ProfilePosition,
        generator: ProfileGenerator,
        plant: Plant,
        now: u32,
        position: i32,
        velocity: Velocity,
        /// Each step's demand and status.
        log: Vec<(Setpoint, ModeStatus)>,
        /// Each step's feedback position.
        actual: Vec<i32>,
    }

    impl Rig {
        fn new(plant: Plant, start: i32, controlword: u16) -> Self {
            let mut generator = ProfileGenerator::new(i64::from(start));
            let mut ppm = ProfilePosition::new();
            let feedback = AxisFeedback { position: start, ..AxisFeedback::default() };
            ppm.enter(cw(controlword), &mut generator, &feedback);
            Self {
                ppm,
                generator,
                plant,
                now: 0,
                position: start,
                velocity: Velocity::ZERO,
                log: Vec::new(),
                actual: Vec::new(),
            }
        }

        fn feedback(&self) -> AxisFeedback {
            AxisFeedback {
                now: Ticks(self.now),
                position: self.position,
                velocity: self.velocity,
                ..AxisFeedback::default()
            }
        }

        /// One tick; returns its step index (= `log` index) and status.
        fn tick(&mut self, input: &PpmInput) -> ModeStatus {
            let feedback = self.feedback();
            self.actual.push(feedback.position);
            let step = self.ppm.step(input, &mut self.generator, &feedback);
            let LoopDemand::Position(sp) = step.demand else { panic!("PPM must demand a position") };
            match self.plant {
                Plant::Delay => {
                    self.position = sp.position_i32();
                    self.velocity = sp.velocity;
                }
                Plant::Lag => {
                    let error = sp.position_i32() - self.position;
                    self.position += error / 4;
                    self.velocity = Velocity::from_inc_per_tick(error / 4);
                }
            }
            self.now += 1;
            self.log.push((sp, step.status));
            step.status
        }

        /// The index the next tick will get.
        fn next_index(&self) -> usize {
            self.log.len()
        }

        fn run(&mut self, input: &PpmInput, ticks: usize) {
            for _ in 0..ticks {
                self.tick(input);
            }
        }

        /// First log index at or after `from` whose bit 10 is set.
        fn first_reached(&self, from: usize) -> Option<usize> {
            (from..self.log.len()).find(|&i| self.log[i].1.target_reached)
        }

        /// The step at which bit 10 must rise for a move to `target` whose last generator step is `done`: `done`
        /// itself, or, if the feedback enters ±`window` for good only later, that step plus the window `time`.
        /// (The axis lags one tick, but its position is the demand rounded to whole increments, which usually
        /// equals the target one tick before the generator's exact end.)
        fn expected_reached(&self, target: i32, window: u32, time: usize, done: usize) -> usize {
            let inside = |i: usize| self.actual[i].wrapping_sub(target).unsigned_abs() <= window;
            let entered = (0..self.actual.len()).rev().take_while(|&i| inside(i)).last().unwrap();
            done.max(entered + time)
        }
    }

    /// Steps between the tick that takes a command and the first step of its motion.
    const LATENCY: usize = crate::control::trajectory::COMMAND_LATENCY_TICKS as usize;

    #[test]
    fn entry_at_rest_reports_target_reached_and_a_held_bit4_starts_nothing() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 100, NEW_SET_POINT);
        let held = input(NEW_SET_POINT, 5000, p, w);
        for _ in 0..20 {
            let s = rig.tick(&held);
            assert!(s.target_reached && !s.bit12 && !s.bit13);
        }
        assert_eq!(rig.position, 100);
        assert_eq!(rig.generator.target(), None);
        assert_eq!(rig.generator.setpoint().position, 100);
        // Bit 4 low then high again: now it is an edge.
        rig.tick(&input(0, 5000, p, w));
        let s = rig.tick(&held);
        assert!(s.bit12 && !s.target_reached);
        assert_eq!(rig.generator.target(), Some(5000));
    }

    #[test]
    fn entry_after_another_modes_move_is_at_rest_at_once_whatever_the_window_time() {
        // The generator finished a move of another mode (target 300); the axis stands 2 inc off it.
        let p = binary_params();
        let w = windows(Some(0), 50);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.generator.start_move(300, false, &p, ChangeMode::AfterCurrent).unwrap();
        while !rig.generator.is_done() {
            rig.generator.step();
        }
        rig.position = 298;
        let feedback = rig.feedback();
        rig.ppm.enter(cw(0), &mut rig.generator, &feedback);
        let s = rig.tick(&input(0, 0, p, w));
        assert!(s.target_reached && !s.bit12);
        assert_eq!(rig.log[0].0.position, 300, "holds the demand it found");
    }

    #[test]
    fn single_set_point_handshake_timeline_absolute() {
        let p = dictionary_params(ProfileType::Trapezoidal);
        let w = windows(Some(0), 0);
        let target = 10_000;
        let duration = planned_duration_ticks(0, Velocity::ZERO, i64::from(target), &p).unwrap() as usize;
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.run(&input(0, target, p, w), 3);
        // Tick k: bit 4 rises -> bit 12 rises in the same tick; the move starts in the next one.
        let k = rig.next_index();
        let s = rig.tick(&input(NEW_SET_POINT, target, p, w));
        assert!(s.bit12 && !s.target_reached);
        assert_eq!(rig.log[k].0, Setpoint::default(), "the tick that takes the set-point holds");
        // Bit 4 held: bit 12 stays; the master clears bit 4 at k + 4: bit 12 falls in that tick.
        for _ in 0..3 {
            assert!(rig.tick(&input(NEW_SET_POINT, target, p, w)).bit12);
        }
        assert!(rig.log[k + LATENCY].0.velocity > Velocity::ZERO, "the next sample moves");
        assert!(!rig.tick(&input(0, target, p, w)).bit12);
        rig.run(&input(0, target, p, w), duration + 10);
        // Generator done at step k + LATENCY + duration - 1; the delayed axis arrives one tick later.
        let done = k + LATENCY + duration - 1;
        assert_eq!((rig.log[done].0.position, rig.log[done].0.velocity), (i64::from(target), Velocity::ZERO));
        assert_ne!(rig.log[done - 1].0.velocity, Velocity::ZERO);
        let reached = rig.first_reached(k).unwrap();
        assert_eq!(reached, rig.expected_reached(target, 0, 0, done));
        assert!(reached <= done + 1);
        assert!(rig.log[k + LATENCY + duration..].iter().all(|(_, s)| s.target_reached && !s.bit12));
    }

    #[test]
    fn relative_set_points_add_to_the_previous_target() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 1000, 0);
        // Relative +1024 from rest at 1000 (no previous target: relative to the demand).
        let k = rig.next_index();
        rig.tick(&input(NEW_SET_POINT | RELATIVE, 1024, p, w));
        rig.run(&input(RELATIVE, 1024, p, w), 200);
        // Done at k + LATENCY + 191; the delayed axis (demand rounded to whole increments) is at 2024 already then.
        assert_eq!(rig.first_reached(k), Some(k + LATENCY + 191));
        assert_eq!(rig.expected_reached(2024, 0, 0, k + LATENCY + 191), k + LATENCY + 191);
        assert_eq!(rig.position, 2024);
        // Relative -2048 from the target 2024; then absolute 0.
        let k = rig.next_index();
        rig.tick(&input(NEW_SET_POINT | RELATIVE, -2048, p, w));
        let d = planned_duration_ticks(2024, Velocity::ZERO, -24, &p).unwrap() as usize;
        assert_eq!(d, 128 + (2048 - 512) / 8);
        rig.run(&input(RELATIVE, -2048, p, w), d + 10);
        assert_eq!(rig.first_reached(k), Some(k + LATENCY + d - 1));
        assert_eq!(rig.position, -24);
        let k = rig.next_index();
        rig.tick(&input(NEW_SET_POINT, 0, p, w));
        rig.run(&input(0, 0, p, w), 100);
        let d = planned_duration_ticks(-24, Velocity::ZERO, 0, &p).unwrap() as usize;
        let reached = rig.first_reached(k).unwrap();
        assert_eq!(reached, rig.expected_reached(0, 0, 0, k + LATENCY + d - 1));
        assert!(reached <= k + LATENCY + d);
        assert_eq!(rig.position, 0);
    }

    #[test]
    fn change_set_immediately_goes_on_to_the_new_target_without_stopping() {
        let p = dictionary_params(ProfileType::Trapezoidal);
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.tick(&input(NEW_SET_POINT, 20_000, p, w));
        rig.run(&input(0, 20_000, p, w), 299);
        // Mid-move (cruising at the profile velocity): a new, further target with bit 5.
        let before = rig.generator.setpoint();
        assert!(cruising(before.velocity, p.velocity));
        let mut reference = rig.generator;
        reference.start_move(40_000, false, &p, ChangeMode::Immediately).unwrap();
        // The new plan starts from the sample of the next step (cruising, one tick further on).
        let origin = reference.step();
        let mut expected = LATENCY;
        while !reference.is_done() {
            reference.step();
            expected += 1;
        }
        let analytic = planned_duration_ticks(origin.position, origin.velocity, 40_000, &p).unwrap() as usize;
        assert!(expected.abs_diff(LATENCY + analytic) <= 1, "{expected} vs {analytic}");
        let k = rig.next_index();
        let s = rig.tick(&input(NEW_SET_POINT | IMMEDIATELY, 40_000, p, w));
        assert!(s.bit12 && !s.target_reached);
        assert_eq!(rig.generator.target(), Some(40_000));
        rig.run(&input(IMMEDIATELY, 40_000, p, w), expected + 10);
        // No stop in between: the demand velocity stays at the profile velocity until the final ramp.
        let moving = &rig.log[LATENCY..k + expected - 1];
        assert!(moving.iter().all(|(sp, s)| sp.velocity > Velocity::ZERO && !s.target_reached));
        assert!(rig.log[k..k + 100].iter().all(|(sp, _)| cruising(sp.velocity, p.velocity)));
        let reached = rig.first_reached(k).unwrap();
        assert_eq!(reached, rig.expected_reached(40_000, 0, 0, k + expected - 1));
        assert!(reached <= k + expected);
        assert_eq!(rig.position, 40_000);
    }

    #[test]
    fn set_of_set_points_buffers_one_holds_bit12_and_takes_the_third_when_space() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        // SP1 at k: starts at once; bit 12 falls with bit 4.
        let k = rig.next_index();
        assert!(rig.tick(&input(NEW_SET_POINT, 1024, p, w)).bit12);
        assert!(!rig.tick(&input(0, 1024, p, w)).bit12);
        rig.run(&input(0, 1024, p, w), 20);
        // SP2 (relative +1024 -> 2048) during the move: buffered; bit 12 stays after bit 4 falls.
        let s = rig.tick(&input(NEW_SET_POINT | RELATIVE, 1024, p, w));
        assert!(s.bit12 && !rig.generator.buffer_free());
        assert!(rig.tick(&input(RELATIVE, 1024, p, w)).bit12);
        rig.run(&input(0, 0, p, w), 10);
        // SP3 (absolute 3072): an edge while the buffer is full is not taken; bit 4 held.
        let third = input(NEW_SET_POINT, 3072, p, w);
        let s = rig.tick(&third);
        assert!(s.bit12 && rig.ppm.request_pending());
        assert_eq!(rig.generator.target(), Some(1024));
        // SP1 ends at step k + LATENCY + 191 (exactly on its target, at rest); SP2 starts in that step and SP3
        // is taken into the freed buffer in the same step, so bit 12 never drops.
        while rig.next_index() < k + LATENCY + 192 {
            let s = rig.tick(&third);
            assert!(s.bit12 && !s.target_reached);
        }
        assert!(!rig.ppm.request_pending());
        assert_eq!(rig.generator.target(), Some(2048));
        assert!(!rig.generator.buffer_free());
        let (sp, _) = rig.log[k + LATENCY + 191];
        assert_eq!((sp.position, sp.velocity), (1024, Velocity::ZERO), "stops at the first target");
        // The master clears bit 4: bit 12 stays while SP3 waits in the buffer, falls when SP3 starts.
        while rig.next_index() < k + LATENCY + 2 * 192 - 1 {
            assert!(rig.tick(&input(0, 3072, p, w)).bit12);
        }
        let s = rig.tick(&input(0, 3072, p, w));
        assert!(!s.bit12 && rig.generator.buffer_free());
        assert_eq!(rig.generator.target(), Some(3072));
        let (sp, _) = rig.log[k + LATENCY + 2 * 192 - 1];
        assert_eq!((sp.position, sp.velocity), (2048, Velocity::ZERO), "stops at the second target");
        rig.run(&input(0, 3072, p, w), 250);
        // In order, each a full stop-to-stop move; target reached only at the very end.
        assert_eq!(rig.first_reached(k), Some(k + LATENCY + 3 * 192 - 1));
        assert_eq!(rig.position, 3072);
        assert!(rig.log[k..].windows(2).all(|pair| pair[1].0.position >= pair[0].0.position));
    }

    #[test]
    fn change_on_set_point_bit9_passes_the_first_target_without_stopping() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        let k = rig.next_index();
        rig.tick(&input(NEW_SET_POINT, 1024, p, w));
        rig.run(&input(0, 1024, p, w), 30);
        assert!(rig.tick(&input(NEW_SET_POINT | CHANGE_ON_SET_POINT, 4096, p, w)).bit12);
        rig.run(&input(CHANGE_ON_SET_POINT, 4096, p, w), 700);
        let end = rig.first_reached(k).unwrap();
        assert_eq!(rig.position, 4096);
        // Never at rest between start and the final target; at 1024 still at the profile velocity.
        assert!(rig.log[k + LATENCY..end - 1].iter().all(|(sp, _)| sp.velocity > Velocity::ZERO));
        let at_first = rig.log[k..].iter().find(|(sp, _)| sp.position >= 1024).unwrap().0;
        assert_eq!(at_first.velocity, p.velocity);
        // Blended: 4096 inc at 8 inc/tick with one ramp up and one down = 64 + 448 + 64 = 576 ticks, exactly.
        assert_eq!(end, k + LATENCY + 575);
        // Without bit 9 the pair stops at 1024: 192 ticks, then 3072 inc in 64 + 320 + 64 = 448 ticks: 640.
        let mut stop = Rig::new(Plant::Delay, 0, 0);
        stop.tick(&input(NEW_SET_POINT, 1024, p, w));
        stop.run(&input(0, 1024, p, w), 30);
        stop.tick(&input(NEW_SET_POINT, 4096, p, w));
        stop.run(&input(0, 4096, p, w), 700);
        assert_eq!(stop.first_reached(0), Some(LATENCY + 639));
        assert_eq!(stop.log[LATENCY + 191].0.velocity, Velocity::ZERO);
    }

    #[test]
    fn position_window_time_counts_from_entering_the_window() {
        let p = binary_params();
        let mut rig = Rig::new(Plant::Lag, 0, 0);
        let w = windows(Some(10), 25);
        rig.tick(&input(NEW_SET_POINT, 1024, p, w));
        rig.run(&input(0, 1024, p, w), 400);
        // The lagging axis enters the window (|1024 - actual| <= 10) at some step and stays; the bit rises exactly
        // 25 ticks later, or when the trajectory ends (step LATENCY + 191) if that is later, and never before.
        let entered = (0..rig.actual.len()).rev().take_while(|&i| (1024 - rig.actual[i]).abs() <= 10).last().unwrap();
        assert!(entered > 100 && (1024 - rig.actual[entered - 1]).abs() > 10);
        assert_eq!(rig.first_reached(0), Some((entered + 25).max(LATENCY + 191)));
        assert!(entered + 25 > LATENCY + 191, "the window time decides here");
        // A disturbance out of the window clears the bit at once and restarts the time.
        assert!(rig.log.last().unwrap().1.target_reached);
        rig.position = 1024 + 11;
        let out = rig.next_index();
        assert!(!rig.tick(&input(0, 1024, p, w)).target_reached);
        rig.position = 1024;
        rig.run(&input(0, 1024, p, w), 40);
        assert_eq!(rig.first_reached(out), Some(out + 1 + 25));
    }

    #[test]
    fn window_time_runs_during_the_final_approach_and_adds_no_delay_beyond_it() {
        // A wide window: the delayed axis is inside well before the generator finishes, so the bit comes with
        // the end of the trajectory (plus the delay), not window time later.
        let p = binary_params();
        let w = windows(Some(200), 10);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.tick(&input(NEW_SET_POINT, 1024, p, w));
        rig.run(&input(0, 1024, p, w), 300);
        assert_eq!(rig.first_reached(0), Some(LATENCY + 191), "done at step 192, inside the window since long before");
    }

    /// Bit 10 timing of a single move, the set-point taken at step 0 so that the generator's last step is
    /// `LATENCY + D - 1` (`D` = `planned_duration_ticks`): window off → exactly that step; window 0 (± 0 inc)
    /// and window 3 with time 0 or 12 → as [`Rig::expected_reached`] and never later than `LATENCY + D + time`
    /// (one tick of lag).
    fn move_timing(profile: ProfileType, target: i32) {
        let p = dictionary_params(profile);
        let d = LATENCY + planned_duration_ticks(0, Velocity::ZERO, i64::from(target), &p).unwrap() as usize;
        for (window, time) in [(None, 7), (Some(0), 0), (Some(0), 12), (Some(3), 0), (Some(3), 12)] {
            let w = windows(window, time);
            let mut rig = Rig::new(Plant::Delay, 0, 0);
            rig.tick(&input(NEW_SET_POINT, target, p, w));
            rig.run(&input(0, target, p, w), d + 40);
            assert_eq!(rig.log[d - 1].0.position, i64::from(target));
            assert_ne!(rig.log[d - 2].0.velocity, Velocity::ZERO);
            let reached = rig.first_reached(0).unwrap();
            let time = time as usize;
            match window {
                None => assert_eq!(reached, d - 1, "{profile:?} {target}"),
                Some(window) => {
                    let expected = rig.expected_reached(target, window, time, d - 1);
                    assert_eq!(reached, expected, "{profile:?} {target} {window} {time}");
                    assert!(reached <= d + time, "{profile:?} {target} {window} {time}");
                    assert!(reached + 1 >= d, "never before the end of the trajectory");
                }
            }
            assert_eq!(rig.position, target);
        }
    }

    #[test]
    fn trapezoidal_move_timing_matches_the_planned_duration() {
        move_timing(ProfileType::Trapezoidal, 10_000);
        move_timing(ProfileType::Trapezoidal, -300); // triangular
    }

    #[test]
    fn sin2_move_timing_matches_the_planned_duration() {
        move_timing(ProfileType::SinSquared, 10_000);
        move_timing(ProfileType::SinSquared, -300);
    }

    #[test]
    fn coarse_last_step_shows_the_one_tick_lag_and_nothing_more() {
        // 8 inc/tick² ramps of one tick: the last demand step is 4 inc, so the delayed axis is on the target one
        // tick after the generator's end, and bit 10 (window 0, time 0) rises exactly then.
        let p = ProfileParams {
            acceleration: Acceleration::from_bits(8 << 40),
            deceleration: Acceleration::from_bits(8 << 40),
            ..binary_params()
        };
        let w = windows(Some(0), 0);
        let d = planned_duration_ticks(0, Velocity::ZERO, 1024, &p).unwrap() as usize;
        assert_eq!(d, 1 + (1024 - 8) / 8 + 1);
        let d = LATENCY + d;
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.tick(&input(NEW_SET_POINT, 1024, p, w));
        rig.run(&input(0, 1024, p, w), d + 5);
        assert_eq!(rig.log[d - 1].0.position, 1024);
        assert_eq!(rig.actual[d - 1], 1020);
        assert_eq!(rig.first_reached(0), Some(d));
    }

    #[test]
    fn halt_stops_sets_bit10_at_standstill_does_not_resume_and_a_new_set_point_moves_again() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.tick(&input(NEW_SET_POINT, 8192, p, w));
        rig.run(&input(0, 8192, p, w), 99);
        // Cruising at 8 inc/tick; halt with a deceleration of 1/4 inc/tick²: 32 ticks to rest.
        let mut halted = input(HALT, 8192, p, w);
        halted.halt_deceleration = Acceleration::from_bits(1 << 38);
        let h = rig.next_index();
        for _ in 0..32 {
            let s = rig.tick(&halted);
            assert!(!s.target_reached, "decelerating");
        }
        assert_eq!(rig.log[h + 31].0.velocity, Velocity::ZERO);
        assert_ne!(rig.log[h + 30].0.velocity, Velocity::ZERO);
        // The delayed axis has velocity 0 one tick after the ramp ends.
        assert!(rig.tick(&halted).target_reached);
        let rest = rig.position;
        assert!(rest < 8192);
        // A set-point edge while halted is held (bit 12 = 0, no motion) ...
        let s = rig.tick(&input(HALT | NEW_SET_POINT, 8192, p, w));
        assert!(!s.bit12 && s.target_reached && rig.ppm.request_pending());
        // ... and dropped when bit 4 falls before the release.
        rig.tick(&input(HALT, 8192, p, w));
        assert!(!rig.ppm.request_pending());
        // Release: no resume, bit 10 stays (at rest, no move).
        for _ in 0..300 {
            let s = rig.tick(&input(0, 8192, p, w));
            assert!(s.target_reached && !s.bit12);
        }
        assert_eq!(rig.position, rest);
        // A new set-point after the halt moves to the target.
        let k = rig.next_index();
        assert!(rig.tick(&input(NEW_SET_POINT, 8192, p, w)).bit12);
        let d = planned_duration_ticks(i64::from(rest), Velocity::ZERO, 8192, &p).unwrap() as usize;
        // At rest at 664 (the halt came after 99 ticks of motion: the first tick took the set-point).
        assert_eq!(rest, 664);
        assert_eq!(d, 128 + (8192 - 664 - 512) / 8);
        rig.run(&input(0, 8192, p, w), d + 10);
        assert_eq!(rig.first_reached(k), Some(k + LATENCY + d - 1));
        assert_eq!(rig.position, 8192);
    }

    #[test]
    fn a_set_point_held_through_the_halt_is_taken_on_release() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.run(&input(HALT, 1024, p, w), 3);
        assert!(!rig.tick(&input(HALT | NEW_SET_POINT, 1024, p, w)).bit12);
        rig.run(&input(HALT | NEW_SET_POINT, 1024, p, w), 5);
        assert_eq!(rig.position, 0);
        let k = rig.next_index();
        assert!(rig.tick(&input(NEW_SET_POINT, 1024, p, w)).bit12);
        rig.run(&input(0, 1024, p, w), 200);
        assert_eq!(rig.first_reached(k), Some(k + LATENCY + 191));
    }

    #[test]
    fn refused_set_point_is_not_acknowledged_and_needs_a_new_edge() {
        let good = binary_params();
        let zero = ProfileParams { velocity: Velocity::ZERO, ..good };
        let w = windows(Some(0), 0);
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        for _ in 0..5 {
            let s = rig.tick(&input(NEW_SET_POINT, 1024, zero, w));
            assert!(!s.bit12 && s.target_reached);
        }
        // Valid parameters while bit 4 is still held: still nothing (the request was dropped).
        rig.run(&input(NEW_SET_POINT, 1024, good, w), 5);
        assert_eq!((rig.position, rig.generator.target()), (0, None));
        rig.tick(&input(0, 1024, good, w));
        let k = rig.next_index();
        assert!(rig.tick(&input(NEW_SET_POINT, 1024, good, w)).bit12);
        rig.run(&input(0, 1024, good, w), 200);
        assert_eq!(rig.first_reached(k), Some(k + LATENCY + 191));
    }

    #[test]
    fn entry_in_motion_stops_with_the_profile_deceleration() {
        let p = binary_params();
        let w = windows(Some(0), 0);
        let mut generator = ProfileGenerator::new(0);
        generator.set_velocity_target(Velocity::from_inc_per_tick(8), &p).unwrap();
        for _ in 0..100 {
            generator.step();
        }
        let mut rig = Rig::new(Plant::Delay, 0, 0);
        rig.generator = generator;
        rig.position = generator.setpoint().position_i32();
        rig.velocity = generator.setpoint().velocity;
        let feedback = rig.feedback();
        rig.ppm.enter(cw(0), &mut rig.generator, &feedback);
        // 8 inc/tick at 1/8 inc/tick²: 64 ticks; bit 10 once the delayed axis is at rest.
        rig.run(&input(0, 0, p, w), 70);
        assert_eq!(rig.log[63].0.velocity, Velocity::ZERO);
        assert_ne!(rig.log[62].0.velocity, Velocity::ZERO);
        assert_eq!(rig.first_reached(0), Some(64));
    }

    #[test]
    fn window_timer_survives_the_tick_counter_wrap() {
        let mut t = WindowTimer::default();
        assert!(!t.update(true, Ticks(u32::MAX - 1), Ticks(3)));
        assert!(!t.update(true, Ticks(0), Ticks(3)));
        assert!(t.update(true, Ticks(1), Ticks(3)));
        // Long after (the counter has lapped): still reached.
        assert!(t.update(true, Ticks(u32::MAX - 5), Ticks(3)));
        assert!(!t.update(false, Ticks(0), Ticks(3)));
    }
}
