//! Profile velocity mode (PVM, 0x6060 = 3): the CiA 402 layer on top of the [`ProfileGenerator`]'s velocity
//! commands (`shared/spec/cia402-device-control.md` §2.2; IDX §3.4 L679-767, E3 §5.4 L1557-1680).
//!
//! # Command
//! The target velocity 0x60FF, bounded by ±0x607F, is followed every tick: the generator ramps to it with 0x6083
//! when speeding up and 0x6084 when slowing down (through zero when the sign changes), with the shape of 0x6086.
//! A change of the target or of the parameters replans from the current demand (change on the fly). IDX: "a new
//! target velocity is not assumed before the controlword is written": latching 0x60FF on controlword writes is
//! the caller's (this layer follows whatever `target_velocity` it is given).
//!
//! A command the generator refuses (`MoveError::ZeroLimit`: 0x607F, 0x6083 or 0x6084 is 0) cannot be followed,
//! so the axis stops with the halt deceleration instead of keeping its last velocity; the next change of the
//! target or of the parameters is tried again.
//!
//! # Halt (bit 8)
//! Bit 8 = 1 stops the axis with the halt deceleration (0x605D → 0x6084 or 0x6085; maxon: "stop axis",
//! IDX L735); releasing it **resumes** the target velocity with the profile ramp — the mode's command is the
//! velocity itself and IDX Table 3-22 L733-737 reads "0 = execute or continue motion" (also Gamma L882 "the
//! commanded motion will resume if possible", Nanotec p.47 L221 "on a transition from 1 to 0 the mo[tor ...]").
//!
//! # Statusword
//! - **Bit 10 target reached**: halt = 0: |velocity actual − target (bounded by 0x607F)| ≤ 0x606D for 0x606E
//!   (E3 L7074-7138, "within the velocity window during the velocity window time"; the time runs from the first
//!   tick inside and restarts when the target changes or the velocity leaves the window). Halt = 1: the halt
//!   ramp has ended and the speed is zero (bit 12), IDX Table 3-25 L756-764 "axis has velocity 0".
//! - **Bit 12 speed**: 1 when |velocity actual| ≤ velocity threshold 0x606F. Reading of the vendor texts: maxon
//!   (IDX Table 3-25 L756-764, E3 Table 5-27 L1672-1681) define "1 = speed is equal 0" without a threshold; the
//!   CiA 402 threshold 0x606F is only in Gamma [GT L2166-2172], whose sentence "when zero speed is reached,
//!   Statusword bit 12 is set to 0" contradicts maxon's polarity and is taken as a documentation error (spec
//!   §7.10; Gamma has no PVM). So: maxon polarity, Gamma's threshold, no threshold time (0x6070 is not
//!   implemented), evaluated on the velocity actual value.
//! - **Bit 13**: "not used" (IDX Table 3-24 L750-754); Nanotec's max slippage 0x60F8 is not supported → 0.
//! - Bit 11 "speed is limited to 0x607F" (IDX) is the axis's to assemble: [`ProfileVelocity::speed_limited`].

use super::profile_position::{speed_is_zero, WindowTimer};
use super::{AxisFeedback, LoopDemand, ModeStatus, ModeStep, Windows};
use crate::cia402::controlword::Controlword;
use crate::control::trajectory::{Acceleration, ProfileGenerator, ProfileParams, Velocity};

/// The inputs of one PVM step, in internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PvmInput {
    /// 0x6040 (bit 8 halt).
    pub controlword: Controlword,
    /// 0x60FF target velocity.
    pub target_velocity: Velocity,
    /// 0x6083, 0x6084, 0x6086 bounded by 0x607F (max_velocity), 0x60C5, 0x60C6.
    pub params: ProfileParams,
    /// Deceleration of a halt (0x605D: 0x6084 or 0x6085).
    pub halt_deceleration: Acceleration,
    /// Target-reached and speed-zero windows.
    pub windows: Windows,
}

/// The PVM state.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ProfileVelocity {
    /// Bit 8 has been applied to the generator.
    halted: bool,
    /// The (bounded target, parameters) last handed to the generator (`None`: nothing commanded in this mode
    /// since entry or since the halt).
    commanded: Option<(Velocity, ProfileParams)>,
    /// The last target velocity exceeded 0x607F.
    limited: bool,
    /// The target the window timer refers to.
    window_target: Velocity,
    /// Velocity window timer.
    window: WindowTimer,
}

/// `velocity` bounded by ±`max` (the magnitude of 0x607F).
fn bounded(velocity: Velocity, max: Velocity) -> Velocity {
    let max = max.to_bits().saturating_abs();
    // Max/min on the ordered bounds: `clamp` would keep its formatted panic for them (flash, issue 17).
    Velocity::from_bits(velocity.to_bits().max(max.saturating_neg()).min(max))
}

impl ProfileVelocity {
    /// A mode at rest.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            halted: false,
            commanded: None,
            limited: false,
            window_target: Velocity::ZERO,
            window: WindowTimer::new(),
        }
    }

    /// Called when PVM becomes the followed mode; `generator` already stands at the demand the axis continues from.
    /// The first step commands the target velocity (or the halt) from there.
    pub fn enter(&mut self, controlword: Controlword, generator: &mut ProfileGenerator, feedback: &AxisFeedback) {
        let _ = (controlword, feedback);
        *self = Self::new();
        let _ = generator.take_buffered_started();
    }

    /// The last target velocity 0x60FF was beyond ±0x607F and is followed at the bound (IDX statusword bit 11
    /// in PVM, "speed is limited to max profile velocity").
    #[must_use]
    pub const fn speed_limited(&self) -> bool {
        self.limited
    }

    /// One slow tick.
    pub fn step(&mut self, input: &PvmInput, generator: &mut ProfileGenerator, feedback: &AxisFeedback) -> ModeStep {
        let target = bounded(input.target_velocity, input.params.max_velocity);
        self.limited = target != input.target_velocity;

        if input.controlword.halt() {
            if !self.halted {
                generator.halt(input.halt_deceleration);
                self.halted = true;
                self.commanded = None;
            }
        } else {
            // Released (or never halted): follow the target; after a halt this resumes it.
            self.halted = false;
            let command = (target, input.params);
            if self.commanded != Some(command) {
                self.commanded = Some(command);
                if generator.set_velocity_target(target, &input.params).is_err() {
                    generator.halt(input.halt_deceleration);
                }
            }
        }

        let setpoint = generator.step();

        let speed_zero = speed_is_zero(feedback.velocity, input.windows.velocity_threshold);
        let target_reached = if self.halted {
            self.window.reset();
            generator.is_done() && speed_zero
        } else {
            if target != self.window_target {
                self.window_target = target;
                self.window.reset();
            }
            let error = feedback.velocity.to_bits().saturating_sub(target.to_bits()).unsigned_abs();
            let inside = error <= input.windows.velocity_window.to_bits().unsigned_abs();
            self.window.update(inside, feedback.now, input.windows.velocity_window_time)
        };
        ModeStep {
            demand: LoopDemand::Velocity { velocity: setpoint.velocity, acceleration: setpoint.acceleration },
            status: ModeStatus { target_reached, bit12: speed_zero, bit13: false },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::Ticks;
    use crate::control::trajectory::{
        planned_velocity_duration_ticks, MotionScale, ProfileObjects, ProfileType, Setpoint,
    };

    const HALT: u16 = Controlword::HALT;

    fn cw(bits: u16) -> Controlword {
        Controlword(0x000F | bits)
    }

    /// 1/8 inc/tick² up, 1/4 down; 0x607F = 16 inc/tick: a ramp from 0 to 8 inc/tick takes exactly 64 ticks.
    fn binary_params() -> ProfileParams {
        ProfileParams {
            profile_type: ProfileType::Trapezoidal,
            velocity: Velocity::from_inc_per_tick(8),
            max_velocity: Velocity::from_inc_per_tick(16),
            acceleration: Acceleration::from_bits(1 << 37),
            deceleration: Acceleration::from_bits(1 << 38),
        }
    }

    fn dictionary_params(profile: ProfileType) -> ProfileParams {
        let objects = ProfileObjects { motion_profile_type: profile.to_0x6086(), ..ProfileObjects::default() };
        objects.profile_params(&MotionScale::new(4096)).unwrap()
    }

    fn inc_per_tick(v: i32) -> Velocity {
        Velocity::from_inc_per_tick(v)
    }

    fn windows(window: Velocity, time: u32, threshold: Velocity) -> Windows {
        Windows {
            position_window: None,
            position_window_time: Ticks(0),
            velocity_window: window,
            velocity_window_time: Ticks(time),
            velocity_threshold: threshold,
        }
    }

    fn input(bits: u16, target: Velocity, params: ProfileParams, windows: Windows) -> PvmInput {
        PvmInput {
            controlword: cw(bits),
            target_velocity: target,
            params,
            halt_deceleration: Acceleration::from_bits(1 << 39),
            windows,
        }
    }

    #[derive(Clone, Copy)]
    enum Plant {
        /// Velocity actual = the demand of the previous tick.
        Delay,
        /// First-order lag: the actual velocity moves 1/8 of the remaining error per tick.
        Lag,
    }

    struct Rig {
        pvm: ProfileVelocity,
        generator: ProfileGenerator,
        plant: Plant,
        now: u32,
        velocity: Velocity,
        log: Vec<(Setpoint, ModeStatus)>,
        actual: Vec<Velocity>,
    }

    impl Rig {
        fn new(plant: Plant, controlword: u16) -> Self {
            let mut generator = ProfileGenerator::new(0);
            let mut pvm = ProfileVelocity::new();
            pvm.enter(cw(controlword), &mut generator, &AxisFeedback::default());
            Self { pvm, generator, plant, now: 0, velocity: Velocity::ZERO, log: Vec::new(), actual: Vec::new() }
        }

        fn tick(&mut self, input: &PvmInput) -> ModeStatus {
            let feedback = AxisFeedback { now: Ticks(self.now), velocity: self.velocity, ..AxisFeedback::default() };
            self.actual.push(self.velocity);
            let step = self.pvm.step(input, &mut self.generator, &feedback);
            let LoopDemand::Velocity { velocity, acceleration } = step.demand else { panic!("PVM demands a velocity") };
            let sp = self.generator.setpoint();
            assert_eq!((velocity, acceleration), (sp.velocity, sp.acceleration));
            self.velocity = match self.plant {
                Plant::Delay => velocity,
                Plant::Lag => {
                    Velocity::from_bits(self.velocity.to_bits() + (velocity.to_bits() - self.velocity.to_bits()) / 8)
                }
            };
            self.now += 1;
            self.log.push((sp, step.status));
            step.status
        }

        fn next_index(&self) -> usize {
            self.log.len()
        }

        fn run(&mut self, input: &PvmInput, ticks: usize) {
            for _ in 0..ticks {
                self.tick(input);
            }
        }

        fn first(&self, from: usize, f: impl Fn(&ModeStatus) -> bool) -> Option<usize> {
            (from..self.log.len()).find(|&i| f(&self.log[i].1))
        }
    }

    /// Steps between the tick that takes a command and the first step of its motion.
    const LATENCY: usize = crate::control::trajectory::COMMAND_LATENCY_TICKS as usize;

    fn ticks(from: Velocity, to: Velocity, p: &ProfileParams) -> usize {
        planned_velocity_duration_ticks(from, to, p).unwrap() as usize
    }

    #[test]
    fn ramps_to_the_target_and_reports_target_reached_at_the_end_of_the_ramp() {
        for profile in [ProfileType::Trapezoidal, ProfileType::SinSquared] {
            let p = dictionary_params(profile);
            let target = MotionScale::new(4096).velocity_from_rpm(-1500);
            let w = windows(Velocity::ZERO, 0, Velocity::ZERO);
            let d = LATENCY + ticks(Velocity::ZERO, target, &p);
            let mut rig = Rig::new(Plant::Delay, 0);
            rig.run(&input(0, target, p, w), d + 20);
            // The generator lands exactly on the target at step LATENCY + D - 1; the delayed axis one tick later.
            assert_eq!(rig.log[d - 1].0.velocity, target);
            assert_ne!(rig.log[d - 2].0.velocity, target);
            assert_eq!(rig.first(0, |s| s.target_reached), Some(d), "{profile:?}");
            assert!(rig.log[d..].iter().all(|(sp, s)| s.target_reached && sp.velocity == target));
        }
    }

    #[test]
    fn velocity_window_sets_bit10_when_inside_not_at_the_end_of_the_ramp() {
        // Window 1 inc/tick around 8: the delayed actual is inside from the step after the demand reaches 7.
        let p = binary_params();
        let w = windows(inc_per_tick(1), 0, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, inc_per_tick(8), p, w), 80);
        let to_7 = ticks(Velocity::ZERO, inc_per_tick(7), &p);
        assert_eq!(to_7, 56);
        assert_eq!(rig.first(0, |s| s.target_reached), Some(LATENCY + to_7));
    }

    #[test]
    fn velocity_window_time_delays_target_reached_by_exactly_the_window_time() {
        let p = binary_params();
        let w = windows(Velocity::ZERO, 40, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, inc_per_tick(8), p, w), 200);
        assert_eq!(rig.first(0, |s| s.target_reached), Some(LATENCY + 64 + 40));
        // A first-order lag: inside the window (0.5 inc/tick) from some tick on, bit 10 exactly 40 ticks later.
        let w = windows(Velocity::from_bits(1 << 31), 40, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Lag, 0);
        rig.run(&input(0, inc_per_tick(8), p, w), 300);
        let inside = |v: Velocity| (v.to_bits() - inc_per_tick(8).to_bits()).abs() <= 1 << 31;
        let entered = (0..rig.actual.len()).rev().take_while(|&i| inside(rig.actual[i])).last().unwrap();
        assert!(entered > LATENCY + 64, "the lag keeps the actual outside past the end of the ramp");
        assert_eq!(rig.first(0, |s| s.target_reached), Some(entered + 40));
    }

    #[test]
    fn speed_zero_bit_at_rest_and_while_moving() {
        let p = binary_params();
        // Threshold 1 inc/tick: the delayed actual exceeds it from the step after the demand passes 1.
        let w = windows(Velocity::ZERO, 0, inc_per_tick(1));
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, Velocity::ZERO, p, w), 5);
        assert!(rig.log.iter().all(|(_, s)| s.bit12 && s.target_reached && !s.bit13));
        let k = rig.next_index();
        rig.run(&input(0, inc_per_tick(8), p, w), 100);
        // Demand at step k + LATENCY + n is (n + 1)/8: above 1 from n = 8; the actual one step later.
        let above = k + LATENCY + 9;
        assert_eq!(rig.first(k, |s| !s.bit12), Some(above));
        assert!(rig.log[k..above].iter().all(|(_, s)| s.bit12));
        assert!(rig.log[above..].iter().all(|(_, s)| !s.bit12));
        // Back to zero with 1/4 inc/tick²: 32 ticks; demand 8 - (n + 1)/4 is 1 at n = 27, the actual one step later.
        let k = rig.next_index();
        rig.run(&input(0, Velocity::ZERO, p, w), 60);
        assert_eq!(rig.first(k, |s| s.bit12), Some(k + LATENCY + 28));
        assert_eq!(rig.first(k, |s| s.target_reached), Some(k + LATENCY + 32));
        assert!(rig.log.iter().all(|(_, s)| !s.bit13));
    }

    #[test]
    fn halt_stops_with_the_halt_deceleration_and_release_resumes_the_target_velocity() {
        let p = binary_params();
        let w = windows(Velocity::ZERO, 0, Velocity::ZERO);
        let target = inc_per_tick(8);
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, target, p, w), 100);
        // Halt deceleration 1/2 inc/tick² (not the profile's 1/4): 16 ticks to rest.
        let h = rig.next_index();
        rig.run(&input(HALT, target, p, w), 40);
        assert_eq!(rig.log[h + 15].0.velocity, Velocity::ZERO);
        assert_ne!(rig.log[h + 14].0.velocity, Velocity::ZERO);
        assert!(rig.log[h..h + 16].iter().all(|(_, s)| !s.target_reached && !s.bit12), "decelerating");
        assert_eq!(rig.first(h, |s| s.target_reached), Some(h + 16));
        assert!(rig.log[h + 16..].iter().all(|(_, s)| s.target_reached && s.bit12));
        // Release: ramps back up to the target with the profile acceleration; bit 10 again at the target.
        let r = rig.next_index();
        rig.run(&input(0, target, p, w), 100);
        assert_eq!(rig.log[r + LATENCY + 63].0.velocity, target);
        assert!(!rig.log[r].1.target_reached);
        assert_eq!(rig.first(r, |s| s.target_reached), Some(r + LATENCY + 64));
        assert_eq!(rig.first(r, |s| !s.bit12), Some(r + LATENCY + 1));
    }

    #[test]
    fn target_change_during_the_ramp_replans_from_the_current_velocity() {
        let p = binary_params();
        let w = windows(Velocity::ZERO, 0, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, inc_per_tick(8), p, w), 20);
        // The new target's origin: the sample of the step that takes it, the ramp to +8 one tick further on.
        let v = Velocity::from_bits(20 << 29);
        assert_eq!(rig.generator.setpoint().velocity, Velocity::from_bits(19 << 29), "19/8 inc/tick");
        // Reverse: down through 0 with the deceleration, then up to -4 with the acceleration.
        let d = ticks(v, inc_per_tick(-4), &p);
        assert_eq!(d, 10 + 32);
        let k = rig.next_index();
        rig.run(&input(0, inc_per_tick(-4), p, w), 60);
        assert_eq!(rig.log[k].0.velocity, v, "the tick that takes the target still follows the ramp to +8");
        assert!(rig.log[k + LATENCY].0.velocity < v, "no further acceleration toward +8");
        assert_eq!(rig.log[k + LATENCY + d - 1].0.velocity, inc_per_tick(-4));
        assert_eq!(rig.first(0, |s| s.target_reached), Some(k + LATENCY + d));
    }

    #[test]
    fn target_beyond_max_profile_velocity_is_clamped() {
        let p = binary_params();
        let w = windows(Velocity::ZERO, 0, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, inc_per_tick(-100), p, w), 200);
        assert!(rig.pvm.speed_limited());
        // 0 -> -16 at 1/8 inc/tick²: 128 ticks; target reached against the bound.
        assert_eq!(rig.log[LATENCY + 127].0.velocity, inc_per_tick(-16));
        assert_eq!(rig.first(0, |s| s.target_reached), Some(LATENCY + 128));
        assert!(rig.log.iter().all(|(sp, _)| sp.velocity >= inc_per_tick(-16)));
        rig.tick(&input(0, inc_per_tick(-16), p, w));
        assert!(!rig.pvm.speed_limited());
    }

    #[test]
    fn entry_with_halt_set_stays_at_rest_until_released() {
        let p = binary_params();
        let w = windows(Velocity::ZERO, 0, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Delay, HALT);
        rig.run(&input(HALT, inc_per_tick(8), p, w), 10);
        assert!(rig.log.iter().all(|(sp, s)| sp.velocity == Velocity::ZERO && s.target_reached && s.bit12));
        let r = rig.next_index();
        rig.run(&input(0, inc_per_tick(8), p, w), 80);
        assert_eq!(rig.first(r, |s| s.target_reached), Some(r + LATENCY + 64));
    }

    #[test]
    fn refused_command_stops_the_axis_instead_of_keeping_the_old_velocity() {
        let p = binary_params();
        let w = windows(Velocity::ZERO, 0, Velocity::ZERO);
        let mut rig = Rig::new(Plant::Delay, 0);
        rig.run(&input(0, inc_per_tick(8), p, w), 100);
        let zero_accel = ProfileParams { acceleration: Acceleration::ZERO, ..p };
        let k = rig.next_index();
        rig.run(&input(0, inc_per_tick(4), zero_accel, w), 40);
        // Halt deceleration 1/2 inc/tick²: 16 ticks.
        assert_eq!(rig.log[k + 15].0.velocity, Velocity::ZERO);
        assert!(rig.log[k + 16..].iter().all(|(sp, s)| sp.velocity == Velocity::ZERO && !s.target_reached && s.bit12));
        // Valid parameters again: ramps to the target.
        let r = rig.next_index();
        rig.run(&input(0, inc_per_tick(4), p, w), 40);
        assert_eq!(rig.first(r, |s| s.target_reached), Some(r + LATENCY + 32));
    }
}
