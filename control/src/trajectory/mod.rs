//! Set-point generation for the profile modes (PPM, PVM, HMM): trapezoidal and sin² velocity profiles, change on the
//! fly, a one-deep set-point buffer, halt and quick stop (`shared/spec/cia402-device-control.md` §2.1, §2.2, §1.6;
//! objects 0x6081, 0x6083..0x6086, 0x607F, 0x60C5, 0x60C6).
//!
//! # Profiles (0x6086, motion profile type)
//! - 0 = linear ramp (trapezoidal profile, all vendors, IDX L6114-6133): the acceleration is constant during a ramp.
//! - 1 = sin² ramp (sinusoidal profile, EPOS3 L7427-7440, Fig. 5-9 and 5-13): the acceleration follows
//!   `A sin²(pi t / T_r)`, so it starts and ends at zero and the jerk is bounded (`pi A / T_r` at most). The figures
//!   label the *peak* of the acceleration curve with the profile acceleration, so here `A` = 0x6083 (0x6084 when
//!   braking): a sin² ramp never exceeds the configured acceleration, and takes twice as long as the linear ramp
//!   for the same velocity change (its mean acceleration is `A / 2`).
//!
//! Both shapes cover the same distance in the same time for the same mean acceleration, so the planner works with
//! the mean acceleration (`A` linear, `A / 2` sin²) and the shape only enters the per-tick evaluation.
//!
//! # Planning (done once per command, never per tick, and never inside a step when the drive plans ahead)
//! A move is planned in continuous time as up to four segments, each a velocity ramp (or a cruise) with a start
//! time, a duration, a start position and velocity, all exact fixed-point values:
//!
//! ```text
//! [stop, if moving away from the target or unable to stop before it] [ramp to peak] [cruise] [ramp to end velocity]
//! ```
//!
//! The peak velocity is the profile velocity, or lower for a move too short to reach it (triangular): from
//! `(vp² - v0²) / 2a + (vp² - w²) / 2d = distance`. A move that starts at non-zero velocity (change on the fly)
//! first ramps from that velocity; if it moves away from the target, or cannot stop before it with the
//! deceleration, it stops (past the target) and comes back (reversal). The phase boundaries are not rounded to
//! whole ticks: each slow tick samples the continuous profile, so a move lasts `ceil(T)` ticks, `T` its analytic
//! duration ([`planned_duration_ticks`]).
//!
//! # Exact arrival (ARCHITECTURE.md conventions 4 and 10)
//! Every sample is computed in closed form from its segment's start (`p0 + v0 tau + area * g(tau/T)`), never by
//! accumulating increments, so nothing drifts. The segments' end points are those same closed forms, so
//! position and velocity are continuous across boundaries by construction. What remains between the end of the
//! last segment and the integer target (rounding of the square root and of the durations, a few 2^-32 inc in the
//! stated envelope) is removed by a linear correction spread over the whole move (at the residual's rate, so a
//! residual too small for one LSB of that rate is left to the end); from the last tick on the output is exactly
//! the target. In the final approach the position is clamped so that it never passes the target.
//!
//! # Representation
//! - Position: increments in Q32 (`i128`, units of 2^-32 inc) inside; the output [`Setpoint`] gives the position
//!   rounded to whole increments (exact at the target) and in Q16 for loops that want sub-increment resolution.
//!   The sub-increment part is needed because at low speed a tick advances by a fraction of an increment
//!   (1 rpm at 4096 inc/rev is 0.027 inc/tick); 32 fraction bits keep the closed forms exact to far below one
//!   increment even for products of long durations and high velocities, and `i128` leaves 2^95 increments of range.
//! - Velocity: [`Velocity`], increments per slow tick (400 us) in Q32 (`i64`): resolution 5.8e-7 inc/s, range
//!   +-2^31 inc/tick (25,000 rpm needs 2^31 only above 2^31 * 6 inc/rev).
//! - Acceleration: [`Acceleration`], increments per tick² in Q40 (`i64`): 1 rpm/s at 4096 inc/rev is 1.09e-5
//!   inc/tick² = 1.2e7 LSB; range +-2^23 inc/tick² (7.7e11 rpm/s at 4096 inc/rev, so even 0x60C5's "unlimited"
//!   default 2^32 - 1 rpm/s fits for sensors up to 2^20 inc/rev; beyond, values saturate).
//! - Time: slow ticks in Q32 (`i128`).
//! - Dictionary units (rpm, rpm/s; 0x60A9/0x60AA) are converted once, when a parameter changes, by
//!   [`MotionScale`] (one multiply and a shift each, no division).
//!
//! Products are formed with a 256-bit intermediate and saturate ([`super::wide`]: `mul_shr`, `div_shl`), so no
//! input panics.
//! Accuracy envelope (where the figures above hold): velocities up to 2^30 inc/tick, segment durations up to 2^40
//! ticks, positions within +-2^62 inc. Outside it the generator still never panics and still ends exactly on the
//! target when the move ends; only the smoothness of the samples degrades.
//!
//! # Cost (`insn.profile_plan_max`, `insn.profile_step_max` of the QEMU bench)
//! One sample: a segment evaluation, about ten multiply-shifts (operands below 2^64 in practice, so one 64x64-bit
//! product each) and one division in 32-bit digits ([`super::wide`]); a sin² ramp adds two Taylor-series sines
//! (7 multiply steps each, error below 1e-11). Planning a move: about five divisions, a square root and a few
//! dozen multiply-shifts. Up to about 2,100 instructions per sample and 8,400 per plan on the Cortex-M4; the
//! divisions are most of it. A plan does not fit the slow tick's budget beside the loops, so it is made between
//! two slow ticks ([`ProfileGenerator::prepare`], in tier 2's background step), and a new set-point moves the
//! axis from the slow tick after the one that takes it (the generator's "When a command takes effect").

mod generator;
mod params;
mod plan;
mod sine;
mod units;

pub use generator::{
    planned_duration_ticks, planned_velocity_duration_ticks, ChangeMode, MoveAccepted, MoveError, ProfileGenerator,
};
pub use params::{ProfileError, ProfileObjects, ProfileParams, ProfileType};
pub use plan::Setpoint;
pub use units::{Acceleration, MotionScale, Velocity};

use crate::power::{PWM_FREQUENCY_HZ, SLOW_TICK_DIVIDER};

/// Sampling frequency of the profile generator and the interpolator: the slow tick, 2500 Hz (EPOS4 Ts = 0.4 ms,
/// `shared/spec/control-and-protection.md` §8).
pub const SLOW_TICK_HZ: u32 = PWM_FREQUENCY_HZ / SLOW_TICK_DIVIDER;
/// The slow tick in microseconds: 400.
pub const SLOW_TICK_MICROS: u32 = 1_000_000 / SLOW_TICK_HZ;

/// Slow ticks from the tick that takes a move or velocity command (PPM set-point, PVM target velocity, a homing
/// phase's motion) to the first tick of its motion: the command is planned between the two
/// ([`ProfileGenerator::prepare`]). Halt and quick stop act in the tick that takes them.
pub const COMMAND_LATENCY_TICKS: u64 = 1;

/// 1.0 in Q32.
pub(crate) const ONE_Q32: i128 = 1 << 32;
