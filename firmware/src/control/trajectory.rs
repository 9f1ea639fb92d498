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
//! # Planning (done once per command, never per tick)
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
//! divisions are most of it, and a planner in 64-bit formats with the rates' reciprocals taken when the
//! parameters change would need fewer.

use super::wide::{div_round_u, div_shl, isqrt, mul_shr, round_shr, sat_i32, sat_i64};
use crate::hal::power::{PWM_FREQUENCY_HZ, SLOW_TICK_DIVIDER};

/// Sampling frequency of the profile generator and the interpolator: the slow tick, 2500 Hz (EPOS4 Ts = 0.4 ms,
/// `shared/spec/control-and-protection.md` §8).
pub const SLOW_TICK_HZ: u32 = PWM_FREQUENCY_HZ / SLOW_TICK_DIVIDER;
/// The slow tick in microseconds: 400.
pub const SLOW_TICK_MICROS: u32 = 1_000_000 / SLOW_TICK_HZ;

/// 1.0 in Q32.
pub(crate) const ONE_Q32: i128 = 1 << 32;
/// 1.0 in Q60.
const ONE_Q60: i64 = 1 << 60;
/// 1.0 in Q62 (the segment fraction `u`).
const ONE_Q62: i128 = 1 << 62;
/// pi in Q60, rounded.
const PI_Q60: i128 = 3_622_009_729_038_561_421;
/// 1 / (2 pi²) in Q60, rounded.
const INV_2PI2_Q60: i128 = 58_407_685_746_735_358;
/// 1 / (2 pi) in Q60, rounded.
const INV_2PI_Q60: i128 = 183_493_156_455_125_077;
/// Horner coefficients of the sine's Taylor series, `1 / ((2k)(2k + 1))` in Q60 for k = 7..1 (terms up to x^15;
/// truncation error below (pi/2)^17 / 17! = 6e-12).
const SIN_TAYLOR_Q60: [i64; 7] = [
    5_490_102_402_889_748,
    7_390_522_465_428_506,
    10_481_104_587_334_973,
    16_012_798_675_095_097,
    27_450_512_014_448_738,
    57_646_075_230_342_349,
    192_153_584_101_141_163,
];
/// rpm -> inc/tick: 60 s/min * 2500 ticks/s.
const RPM_TICKS: u128 = 60 * SLOW_TICK_HZ as u128;
/// rpm/s -> inc/tick²: 60 s/min * 2500² ticks²/s².
const RPM_PER_S_TICKS2: u128 = 60 * (SLOW_TICK_HZ as u128) * (SLOW_TICK_HZ as u128);
/// How far (Q32 inc, 2^-8 inc) a start velocity may exceed what can be stopped within the distance before the
/// planner treats the move as an overshoot (stop and come back) rather than as a rounding residue.
const OVERSHOOT_TOLERANCE: i128 = 1 << 24;
/// A plan counts as complete this close (Q32 ticks, 2^-20 tick = 0.4 ns) before its analytic end, so that a
/// duration that is a whole number of ticks up to the rounding of the parameters takes exactly that many ticks.
/// The skipped motion is far below 2^-20 of one tick's travel.
const END_TOLERANCE: i128 = 1 << 12;
/// Segments of a plan: stop + ramp + cruise + ramp.
const MAX_SEGMENTS: usize = 4;

// ---------------------------------------------------------------------------------------------------------------
// Quantities
// ---------------------------------------------------------------------------------------------------------------

/// A velocity in increments per slow tick (400 us), Q32 (units of 2^-32 inc/tick).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Velocity(pub i64);

/// An acceleration in increments per slow tick squared, Q40 (units of 2^-40 inc/tick²).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Acceleration(pub i64);

impl Velocity {
    /// Zero velocity.
    pub const ZERO: Self = Self(0);
    /// Fraction bits of the representation.
    pub const FRAC_BITS: u32 = 32;

    /// From the raw Q32 bits (2^-32 inc/tick).
    #[must_use]
    pub const fn from_bits(bits: i64) -> Self {
        Self(bits)
    }

    /// The raw Q32 bits (2^-32 inc/tick).
    #[must_use]
    pub const fn to_bits(self) -> i64 {
        self.0
    }

    /// From whole increments per slow tick.
    #[must_use]
    pub const fn from_inc_per_tick(inc_per_tick: i32) -> Self {
        // |inc| < 2^31: the Q32 value stays below 2^63.
        Self((inc_per_tick as i64) << 32)
    }

    /// From increments per second, rounded toward zero, saturating. Divides: not for the slow tick.
    #[must_use]
    pub fn from_inc_per_s(inc_per_s: i64) -> Self {
        Self(sat_i64(div_shl(i128::from(inc_per_s), i128::from(SLOW_TICK_HZ), 32)))
    }

    /// To increments per second, rounded to nearest.
    #[must_use]
    pub fn to_inc_per_s(self) -> i64 {
        // |bits * 2500| < 2^75: no wrap in i128.
        sat_i64(round_shr(i128::from(self.0).wrapping_mul(i128::from(SLOW_TICK_HZ)), 32))
    }

    /// Increments per tick in Q16 (`I16F16` bits, the format of `control::velocity`), rounded, saturating.
    #[must_use]
    pub fn to_inc_per_tick_q16(self) -> i32 {
        sat_i32(round_shr(i128::from(self.0), 16))
    }

    fn wide(self) -> i128 {
        i128::from(self.0)
    }
}

impl Acceleration {
    /// Zero acceleration.
    pub const ZERO: Self = Self(0);
    /// Fraction bits of the representation.
    pub const FRAC_BITS: u32 = 40;
    /// The largest representable acceleration (about 8.4e6 inc/tick²): "no limit".
    pub const MAX: Self = Self(i64::MAX);

    /// From the raw Q40 bits (2^-40 inc/tick²).
    #[must_use]
    pub const fn from_bits(bits: i64) -> Self {
        Self(bits)
    }

    /// The raw Q40 bits (2^-40 inc/tick²).
    #[must_use]
    pub const fn to_bits(self) -> i64 {
        self.0
    }

    /// From increments per second squared, rounded toward zero, saturating. Divides: not for the slow tick.
    #[must_use]
    pub fn from_inc_per_s2(inc_per_s2: i64) -> Self {
        let ticks2 = i128::from(SLOW_TICK_HZ).wrapping_mul(i128::from(SLOW_TICK_HZ));
        Self(sat_i64(div_shl(i128::from(inc_per_s2), ticks2, 40)))
    }

    /// To increments per second squared, rounded to nearest.
    #[must_use]
    pub fn to_inc_per_s2(self) -> i64 {
        // |bits| * 2500² < 2^86: no wrap in i128.
        let ticks2 = i128::from(SLOW_TICK_HZ).wrapping_mul(i128::from(SLOW_TICK_HZ));
        sat_i64(round_shr(i128::from(self.0).wrapping_mul(ticks2), 40))
    }

    /// Increments per tick² in Q16 (`I16F16` bits, the format of `control::velocity`), rounded, saturating.
    #[must_use]
    pub fn to_inc_per_tick2_q16(self) -> i32 {
        sat_i32(round_shr(i128::from(self.0), 24))
    }

    fn wide(self) -> i128 {
        i128::from(self.0)
    }
}

/// Conversion between the dictionary's motion units and the internal ones, for a given sensor resolution
/// (increments per revolution: 4096 for the reference encoder, ARCHITECTURE.md "Reference plant").
///
/// The dictionary's velocity unit is rpm (0x60A9 default, device.toml 0x6081/0x607F/0x60FF/0x60B1) and its
/// acceleration unit rpm/s (0x60AA default, 0x6083..0x6085, 0x60C5, 0x60C6). `v [inc/tick] = rpm * N / (60 * 2500)`
/// and `a [inc/tick²] = rpm/s * N / (60 * 2500²)`. The factors carry 16 extra fraction bits, computed once in
/// [`MotionScale::new`]; each conversion is then one multiply and a shift (relative error below 2^-40 for
/// N >= 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotionScale {
    increments_per_revolution: u32,
    /// inc/tick Q48 per rpm.
    velocity_factor: u128,
    /// inc/tick² Q56 per rpm/s.
    acceleration_factor: u128,
    /// rpm Q96 per inc/tick Q0 (i.e. rpm per Q32 velocity bit, Q64... see `velocity_to_rpm`).
    rpm_factor: u128,
}

impl MotionScale {
    /// The scale for `increments_per_revolution` (0 is taken as 1). Divides: call when the sensor configuration
    /// changes, not per tick.
    #[must_use]
    pub fn new(increments_per_revolution: u32) -> Self {
        let n = u128::from(increments_per_revolution.max(1));
        // n < 2^32: n 2^48 < 2^80, n 2^56 < 2^88, 150,000 2^64 < 2^82: no overflow.
        let velocity_factor = div_round_u(n << 48, RPM_TICKS);
        let acceleration_factor = div_round_u(n << 56, RPM_PER_S_TICKS2);
        let rpm_factor = div_round_u(RPM_TICKS << 64, n);
        Self {
            increments_per_revolution: increments_per_revolution.max(1),
            velocity_factor,
            acceleration_factor,
            rpm_factor,
        }
    }

    /// Increments per revolution (at least 1).
    #[must_use]
    pub const fn increments_per_revolution(&self) -> u32 {
        self.increments_per_revolution
    }

    /// A velocity in rpm (0x6081, 0x607F, 0x60FF, 0x60B1) in internal units, rounded, saturating.
    #[must_use]
    pub fn velocity_from_rpm(&self, rpm: i64) -> Velocity {
        let factor = i128::try_from(self.velocity_factor).unwrap_or(i128::MAX);
        Velocity(sat_i64(round_shr(mul_shr(i128::from(rpm), factor, 0), 16)))
    }

    /// A velocity in rpm, rounded to nearest (e.g. for 0x606B velocity demand value).
    #[must_use]
    pub fn velocity_to_rpm(&self, velocity: Velocity) -> i64 {
        // v [Q32 inc/tick] * (150,000 / N) [Q64] = rpm in Q96.
        let factor = i128::try_from(self.rpm_factor).unwrap_or(i128::MAX);
        let rpm_q64 = mul_shr(velocity.wide(), factor, 32);
        sat_i64(round_shr(rpm_q64, 64))
    }

    /// An acceleration in rpm/s (0x6083..0x6085, 0x60C5, 0x60C6) in internal units, rounded, saturating at
    /// [`Acceleration::MAX`].
    #[must_use]
    pub fn acceleration_from_rpm_per_s(&self, rpm_per_s: u32) -> Acceleration {
        let factor = i128::try_from(self.acceleration_factor).unwrap_or(i128::MAX);
        Acceleration(sat_i64(round_shr(mul_shr(i128::from(rpm_per_s), factor, 0), 16)))
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Parameters
// ---------------------------------------------------------------------------------------------------------------

/// Motion profile type, object 0x6086.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ProfileType {
    /// 0: linear ramp (trapezoidal velocity profile).
    #[default]
    Trapezoidal,
    /// 1: sin² ramp (sinusoidal profile, EPOS3 L7440): jerk-limited, peak acceleration = the profile value.
    SinSquared,
}

impl ProfileType {
    /// Decodes 0x6086: 0 trapezoidal, 1 sin² (EPOS3). Nanotec's 3 (jerk-limited with separate jerk objects
    /// 0x60A4) and any other value are rejected.
    pub fn from_0x6086(raw: i16) -> Result<Self, ProfileError> {
        match raw {
            0 => Ok(Self::Trapezoidal),
            1 => Ok(Self::SinSquared),
            other => Err(ProfileError::UnsupportedProfileType(other)),
        }
    }

    /// The 0x6086 value.
    #[must_use]
    pub const fn to_0x6086(self) -> i16 {
        match self {
            Self::Trapezoidal => 0,
            Self::SinSquared => 1,
        }
    }
}

/// Errors converting dictionary profile objects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProfileError {
    /// 0x6086 holds a profile type this generator does not implement.
    UnsupportedProfileType(i16),
}

/// The raw dictionary objects that parameterise profile moves (units as in `firmware/device.toml`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProfileObjects {
    /// 0x6081 profile velocity, rpm.
    pub profile_velocity: u32,
    /// 0x6083 profile acceleration, rpm/s.
    pub profile_acceleration: u32,
    /// 0x6084 profile deceleration, rpm/s.
    pub profile_deceleration: u32,
    /// 0x6085 quick-stop deceleration, rpm/s.
    pub quick_stop_deceleration: u32,
    /// 0x607F max profile velocity, rpm: bounds 0x6081 and the PVM target velocity.
    pub max_profile_velocity: u32,
    /// 0x60C5 max acceleration, rpm/s: bounds every acceleration and deceleration of the profile modes
    /// (`shared/spec/control-and-protection.md` §3.5; not used in CSx).
    pub max_acceleration: u32,
    /// 0x60C6 max deceleration, rpm/s: bounds the decelerations.
    pub max_deceleration: u32,
    /// 0x6086 motion profile type.
    pub motion_profile_type: i16,
}

impl Default for ProfileObjects {
    /// The defaults of `firmware/device.toml`.
    fn default() -> Self {
        Self {
            profile_velocity: 1000,
            profile_acceleration: 10_000,
            profile_deceleration: 10_000,
            quick_stop_deceleration: 10_000,
            max_profile_velocity: 5000,
            max_acceleration: u32::MAX,
            max_deceleration: u32::MAX,
            motion_profile_type: 0,
        }
    }
}

impl ProfileObjects {
    /// The move parameters in internal units, with the limits applied: velocity = min(0x6081, 0x607F),
    /// acceleration = min(0x6083, 0x60C5), deceleration = min(0x6084, 0x60C5, 0x60C6). Call when an object
    /// changes, not per tick.
    pub fn profile_params(&self, scale: &MotionScale) -> Result<ProfileParams, ProfileError> {
        let profile_type = ProfileType::from_0x6086(self.motion_profile_type)?;
        Ok(ProfileParams {
            profile_type,
            velocity: scale.velocity_from_rpm(i64::from(self.profile_velocity.min(self.max_profile_velocity))),
            max_velocity: scale.velocity_from_rpm(i64::from(self.max_profile_velocity)),
            acceleration: scale.acceleration_from_rpm_per_s(self.profile_acceleration.min(self.max_acceleration)),
            deceleration: scale.acceleration_from_rpm_per_s(self.limit_deceleration(self.profile_deceleration)),
        })
    }

    /// The quick-stop deceleration min(0x6085, 0x60C5, 0x60C6) in internal units.
    #[must_use]
    pub fn quick_stop_deceleration(&self, scale: &MotionScale) -> Acceleration {
        scale.acceleration_from_rpm_per_s(self.limit_deceleration(self.quick_stop_deceleration))
    }

    fn limit_deceleration(&self, raw: u32) -> u32 {
        raw.min(self.max_acceleration).min(self.max_deceleration)
    }
}

/// The parameters of one profile move or velocity command, in internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProfileParams {
    /// Ramp shape (0x6086).
    pub profile_type: ProfileType,
    /// Peak velocity of a position move (0x6081, bounded by 0x607F); magnitude, negative values count as positive.
    pub velocity: Velocity,
    /// Bound of a PVM target velocity (0x607F).
    pub max_velocity: Velocity,
    /// Acceleration (0x6083, bounded by 0x60C5); for sin² the peak of the acceleration curve.
    pub acceleration: Acceleration,
    /// Deceleration (0x6084, bounded by 0x60C5 and 0x60C6); for sin² the peak.
    pub deceleration: Acceleration,
}

/// Internal limits of one plan: peak velocity (Q32), mean acceleration and deceleration (Q40), all > 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Limits {
    vmax: i128,
    acc: i128,
    dec: i128,
    shape: ProfileType,
}

impl Limits {
    /// `None` when the velocity or an acceleration is zero (the move could never end).
    fn new(vmax: Velocity, acc: Acceleration, dec: Acceleration, shape: ProfileType) -> Option<Self> {
        let vmax = vmax.wide().saturating_abs();
        let (acc, dec) = (acc.wide().saturating_abs(), dec.wide().saturating_abs());
        if vmax == 0 || acc == 0 || dec == 0 {
            return None;
        }
        Some(Self { vmax, acc: mean_rate(acc, shape), dec: mean_rate(dec, shape), shape })
    }

    fn from_params(params: &ProfileParams, velocity: Velocity) -> Option<Self> {
        Self::new(velocity, params.acceleration, params.deceleration, params.profile_type)
    }
}

/// The mean acceleration of a ramp whose peak is `peak` (half of it for sin²), at least one LSB.
fn mean_rate(peak: i128, shape: ProfileType) -> i128 {
    match shape {
        ProfileType::Trapezoidal => peak,
        ProfileType::SinSquared => (peak >> 1).max(1),
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Output
// ---------------------------------------------------------------------------------------------------------------

/// One sample of the profile, produced every slow tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Setpoint {
    /// Position demand in increments, rounded to nearest (exact at the target), i.e. 0x6062.
    pub position: i64,
    /// The same position in Q16 increments (2^-16 inc), floor of the internal value, for sub-increment use.
    pub position_fine: i64,
    /// Velocity demand (feedforward for the velocity/position loop; 0x606B after conversion to rpm).
    pub velocity: Velocity,
    /// Acceleration demand (feedforward).
    pub acceleration: Acceleration,
}

impl Setpoint {
    /// The position as the CiA 402 INTEGER32 (0x6062), wrapping like the sensor count.
    #[must_use]
    pub const fn position_i32(&self) -> i32 {
        self.position as i32
    }
}

/// Position, velocity and acceleration at one instant, full precision: Q32 inc, Q32 inc/tick, Q40 inc/tick².
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct State {
    p: i128,
    v: i128,
    a: i128,
}

impl State {
    fn setpoint(&self) -> Setpoint {
        Setpoint {
            position: sat_i64(round_shr(self.p, 32)),
            position_fine: sat_i64(self.p >> 16),
            velocity: Velocity(sat_i64(self.v)),
            acceleration: Acceleration(sat_i64(self.a)),
        }
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Segments and plans
// ---------------------------------------------------------------------------------------------------------------

/// One ramp or cruise: velocity from `v0` to `v0 + dv` over `duration`, shaped linear or sin².
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Segment {
    /// Q32 ticks from the plan's origin.
    start: i128,
    /// Q32 ticks, > 0.
    duration: i128,
    /// Q32 inc.
    p0: i128,
    /// Q32 inc/tick.
    v0: i128,
    /// Q32 inc/tick.
    dv: i128,
    /// `dv * duration`, Q32 inc.
    area: i128,
    /// The mean acceleration, Q40 inc/tick², signed like `dv`: the ramp's rate (its duration is `|dv| / rate`,
    /// so `dv / duration` is the rate up to the rounding of the duration), 0 for a cruise.
    accel: i128,
    shape: ProfileType,
}

impl Segment {
    /// A ramp from `v0` to `v1` over `duration` at the mean rate `rate` (Q40, > 0; 0 for a cruise).
    fn new(start: i128, duration: i128, p0: i128, v0: i128, v1: i128, rate: i128, shape: ProfileType) -> Self {
        let dv = v1.saturating_sub(v0);
        let accel = rate.saturating_mul(dv.signum());
        Self { start, duration, p0, v0, dv, area: mul_shr(dv, duration, 32), accel, shape }
    }

    fn end(&self) -> i128 {
        self.start.saturating_add(self.duration)
    }

    fn v1(&self) -> i128 {
        self.v0.saturating_add(self.dv)
    }

    /// The state `tau` (Q32 ticks, clamped to [0, duration]) after the segment's start.
    ///
    /// With `u = tau / duration` and `K = dv * duration`:
    /// - linear: `p = p0 + v0 tau + K u²/2`, `v = v0 + dv u`, `a = dv / duration`;
    /// - sin²: `p = p0 + v0 tau + K (u²/2 - sin²(pi u) / (2 pi²))`, `v = v0 + dv (u - sin(2 pi u) / (2 pi))`,
    ///   `a = (dv / duration) 2 sin²(pi u)`.
    ///
    /// At `u = 1` both give `p0 + (v0 + v1) duration / 2` (the sine terms vanish exactly).
    fn eval(&self, tau: i128) -> State {
        let tau = tau.clamp(0, self.duration);
        let pv = self.p0.saturating_add(mul_shr(self.v0, tau, 32));
        if self.dv == 0 {
            return State { p: pv, v: self.v0, a: 0 };
        }
        // u = tau / duration in Q62: the shape terms are then exact to ~2^-62 of the segment's area, so the exact
        // v0 tau term and the shape term never disagree by a visible amount (monotonic samples near a slow end).
        let u = if tau >= self.duration { ONE_Q62 } else { div_shl(tau, self.duration, 62) };
        let half_u2 = mul_shr(u, u, 63); // Q62, u <= 2^62
        let (g, vs, a_shape) = match self.shape {
            ProfileType::Trapezoidal => (half_u2, u, ONE_Q62),
            // At the ends the sines are exactly zero (`sin_pi_q60` and `sin_2pi_q60` return 0 there): the end state
            // of every planned segment is taken here without evaluating them.
            ProfileType::SinSquared if u == ONE_Q62 => (half_u2, u, 0),
            ProfileType::SinSquared => {
                let s1 = i128::from(sin_pi_q60(u));
                let sin2 = mul_shr(s1, s1, 60); // sin²(pi u), Q60
                let s2 = i128::from(sin_2pi_q60(u));
                (
                    half_u2.saturating_sub(mul_shr(sin2, INV_2PI2_Q60, 58)),
                    u.saturating_sub(mul_shr(s2, INV_2PI_Q60, 58)),
                    sin2 << 3, // 2 sin², Q62
                )
            }
        };
        State {
            p: pv.saturating_add(mul_shr(self.area, g, 62)),
            v: self.v0.saturating_add(mul_shr(self.dv, vs, 62)),
            a: mul_shr(self.accel, a_shape, 62),
        }
    }
}

/// What a plan does once its segments are over.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum PlanKind {
    /// At rest, nothing planned.
    #[default]
    Idle,
    /// A position move to `target` (increments).
    Position { target: i64 },
    /// A velocity command: the end velocity is kept forever.
    Velocity,
    /// A halt or quick stop: at rest at the end.
    Stop,
}

/// A planned motion: segments from the plan's origin, then the end state (continued at `end_velocity`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Plan {
    segments: [Segment; MAX_SEGMENTS],
    len: usize,
    /// Q32 ticks until the end state.
    duration: i128,
    /// Q32 inc at `duration` (the exact target for position moves and stops).
    end_position: i128,
    /// Q32 inc/tick after `duration`.
    end_velocity: i128,
    /// The residual (`end_position` minus where the segments end) over `duration`, Q32 inc/tick: the rate at which
    /// the residual is spread over the plan.
    residual_rate: i128,
    /// Sign of the final approach to a resting end (the clamp against passing the target), 0 for none.
    approach: i128,
    kind: PlanKind,
    limits: Option<Limits>,
}

impl Plan {
    fn rest(position: i128) -> Self {
        Self {
            segments: [Segment::default(); MAX_SEGMENTS],
            len: 0,
            duration: 0,
            end_position: position,
            end_velocity: 0,
            residual_rate: 0,
            approach: 0,
            kind: PlanKind::Idle,
            limits: None,
        }
    }

    fn eval(&self, t: i128) -> State {
        if t >= self.duration {
            let tau = t.saturating_sub(self.duration);
            return State {
                p: self.end_position.saturating_add(mul_shr(self.end_velocity, tau, 32)),
                v: self.end_velocity,
                a: 0,
            };
        }
        let last = self.len.saturating_sub(1);
        for (i, seg) in self.segments.iter().take(self.len).enumerate() {
            if t < seg.end() {
                let mut st = seg.eval(t.saturating_sub(seg.start));
                if self.residual_rate != 0 {
                    // `residual_rate t` is `residual t / duration` up to the rate's rounding (less than one Q32
                    // LSB per tick of the plan): a multiply per sample instead of a division.
                    st.p = st.p.saturating_add(mul_shr(self.residual_rate, t.max(0), 32));
                    st.v = st.v.saturating_add(self.residual_rate);
                }
                if i == last && self.approach > 0 {
                    st.p = st.p.min(self.end_position);
                } else if i == last && self.approach < 0 {
                    st.p = st.p.max(self.end_position);
                }
                return st;
            }
        }
        State { p: self.end_position, v: self.end_velocity, a: 0 }
    }
}

/// Appends segments, tracking the time, position and velocity at the end of the last one.
struct Builder {
    segments: [Segment; MAX_SEGMENTS],
    len: usize,
    t: i128,
    p: i128,
    v: i128,
    shape: ProfileType,
}

impl Builder {
    fn new(p: i128, v: i128, shape: ProfileType) -> Self {
        Self { segments: [Segment::default(); MAX_SEGMENTS], len: 0, t: 0, p, v, shape }
    }

    /// Ramps to `v1` at the mean rate `rate` (Q40, > 0).
    fn ramp_to(&mut self, v1: i128, rate: i128) {
        let duration = ramp_duration(v1.saturating_sub(self.v).saturating_abs(), rate);
        self.ramp_over(v1, rate, duration);
    }

    /// Ramps to `v1` at the mean rate `rate` over `duration`, the [`ramp_duration`] of the step (computed once by
    /// the caller that needed it before).
    fn ramp_over(&mut self, v1: i128, rate: i128, duration: i128) {
        if v1 == self.v {
            return;
        }
        if duration <= 0 {
            // A velocity step far below one LSB of time: take it at once.
            self.v = v1;
            return;
        }
        self.push(Segment::new(self.t, duration, self.p, self.v, v1, rate, self.shape));
    }

    /// Holds the current velocity for `duration` (Q32 ticks).
    fn cruise(&mut self, duration: i128) {
        if duration > 0 && self.v != 0 {
            self.push(Segment::new(self.t, duration, self.p, self.v, self.v, 0, ProfileType::Trapezoidal));
        }
    }

    fn push(&mut self, seg: Segment) {
        let end = seg.eval(seg.duration);
        if let Some(slot) = self.segments.get_mut(self.len) {
            *slot = seg;
            self.len = self.len.saturating_add(1);
            self.t = seg.end();
            self.p = end.p;
        }
        // No free slot cannot happen (at most four segments per plan); the velocity still follows the command and
        // the residual correction takes the position to the end state.
        self.v = seg.v1();
    }

    fn finish(self, kind: PlanKind, end_position: i128, end_velocity: i128, limits: Option<Limits>) -> Plan {
        let residual = end_position.saturating_sub(self.p);
        let duration = self.t;
        let residual_rate = if duration > 0 { div_shl(residual, duration, 32) } else { 0 };
        let approach = match self.segments.get(self.len.saturating_sub(1)) {
            Some(last) if self.len > 0 && end_velocity == 0 => last.v0.signum(),
            _ => 0,
        };
        Plan {
            segments: self.segments,
            len: self.len,
            duration,
            end_position,
            end_velocity,
            residual_rate,
            approach,
            kind,
            limits,
        }
    }
}

/// Time to change the velocity by `dv` (Q32, >= 0) at the mean rate `rate` (Q40): Q32 ticks.
fn ramp_duration(dv: i128, rate: i128) -> i128 {
    div_shl(dv, rate.max(1), 40)
}

/// The duration of a ramp from `v0` to `v1` and the position of its end relative to its start, exactly as the
/// segment evaluates it.
fn ramp_distance(v0: i128, v1: i128, rate: i128, shape: ProfileType) -> (i128, i128) {
    let duration = ramp_duration(v1.saturating_sub(v0).saturating_abs(), rate);
    if duration <= 0 {
        return (duration, 0);
    }
    (duration, Segment::new(0, duration, 0, v0, v1, rate, shape).eval(duration).p)
}

/// `2 * rate * distance` in Q64 (inc²/tick²): rate Q40, distance Q32.
fn twice_rate_distance(rate: i128, distance: i128) -> i128 {
    mul_shr(rate, distance, 7)
}

/// Plans a position move from (`p0`, `v0`) to `target` (Q32 inc), arriving with `end_velocity` (signed, in the
/// direction of the move; 0 for a normal move).
fn plan_position(p0: i128, v0: i128, target: i128, target_inc: i64, end_velocity: i128, lim: Limits) -> Plan {
    let mut b = Builder::new(p0, v0, lim.shape);
    // Two passes at most: a stop (moving away, or overshoot) makes the second pass start at rest.
    for _ in 0..2 {
        let d = target.saturating_sub(b.p);
        let s = if d != 0 { d.signum() } else { b.v.signum() };
        if s == 0 {
            break;
        }
        // Normalised to the direction of the target: s = +-1, so the products are sign flips.
        let dn = d.saturating_mul(s);
        let u0 = b.v.saturating_mul(s);
        let wn = end_velocity.saturating_mul(s).clamp(0, lim.vmax);
        if u0 < 0 {
            b.ramp_to(0, lim.dec);
            continue;
        }
        let u0_sq = mul_shr(u0, u0, 0);
        let wn_sq = mul_shr(wn, wn, 0);
        if u0 > wn {
            // Distance needed to slow from u0 to wn: (u0² - wn²) / 2d, Q32.
            let excess = u0_sq.saturating_sub(wn_sq);
            let needed = div_shl(excess, lim.dec.saturating_mul(2), 8);
            if needed > dn.saturating_add(OVERSHOOT_TOLERANCE) {
                if wn == 0 {
                    // Cannot stop before the target: stop past it, then come back (reversal).
                    b.ramp_to(0, lim.dec);
                    continue;
                }
                // Continuing move: arrive faster than wn, decelerating all the way.
                let w2 = isqrt(u0_sq.saturating_sub(twice_rate_distance(lim.dec, dn)));
                b.ramp_to(w2.saturating_mul(s), lim.dec);
                break;
            }
        } else if u0 < wn {
            let room = twice_rate_distance(lim.acc, dn);
            if wn_sq.saturating_sub(u0_sq) > room {
                // Too short to reach the end velocity: accelerate all the way.
                let w2 = isqrt(u0_sq.saturating_add(room));
                b.ramp_to(w2.saturating_mul(s), lim.acc);
                break;
            }
        }
        // Peak velocity: (vp² - u0²)/2a + (vp² - wn²)/2d = dn  =>  vp² = 2 dn h + u0² (1 - r) + wn² r,
        // r = a / (a + d), h = d r.
        let vp = if u0 >= lim.vmax {
            lim.vmax
        } else {
            let r = div_shl(lim.acc, lim.acc.saturating_add(lim.dec), 32).clamp(0, ONE_Q32);
            let h = mul_shr(lim.dec, r, 32);
            let vp_sq = twice_rate_distance(h, dn)
                .saturating_add(mul_shr(u0_sq, ONE_Q32.saturating_sub(r), 32))
                .saturating_add(mul_shr(wn_sq, r, 32));
            isqrt(vp_sq).min(lim.vmax)
        };
        let rate = if vp >= u0 { lim.acc } else { lim.dec };
        b.ramp_to(vp.saturating_mul(s), rate);
        let (last_duration, last) = ramp_distance(vp, wn, lim.dec, lim.shape);
        let cruise = target.saturating_sub(b.p).saturating_mul(s).saturating_sub(last);
        if cruise > 0 && vp > 0 {
            b.cruise(div_shl(cruise, vp, 32));
        }
        // b.v is vp s here (the ramp and the cruise end there): the last ramp is the one just measured.
        b.ramp_over(wn.saturating_mul(s), lim.dec, last_duration);
        break;
    }
    let end_velocity = b.v;
    b.finish(PlanKind::Position { target: target_inc }, target, end_velocity, Some(lim))
}

/// Plans a velocity command from (`p0`, `v0`) to `target` (Q32 inc/tick): stop first if the sign changes, ramp up
/// with the acceleration and down with the deceleration, then keep the velocity.
fn plan_velocity(p0: i128, v0: i128, target: i128, lim: Limits) -> Plan {
    let mut b = Builder::new(p0, v0, lim.shape);
    if v0 != 0 && target != 0 && v0.signum() != target.signum() {
        b.ramp_to(0, lim.dec);
    }
    let rate = if target.saturating_abs() >= b.v.saturating_abs() { lim.acc } else { lim.dec };
    b.ramp_to(target, rate);
    let (p, v) = (b.p, b.v);
    b.finish(PlanKind::Velocity, p, v, Some(lim))
}

/// Plans a stop from (`p0`, `v0`) with the mean deceleration `dec`, ending at rest on a whole increment.
fn plan_stop(p0: i128, v0: i128, dec: i128, shape: ProfileType) -> Plan {
    let mut b = Builder::new(p0, v0, shape);
    b.ramp_to(0, dec.max(1));
    let end = round_shr(b.p, 32).saturating_mul(ONE_Q32);
    b.finish(PlanKind::Stop, end, 0, None)
}

// ---------------------------------------------------------------------------------------------------------------
// Generator
// ---------------------------------------------------------------------------------------------------------------

/// When a new position set-point takes effect (PPM controlword bits 5 and, Nanotec, 9:
/// `shared/spec/cia402-device-control.md` §2.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ChangeMode {
    /// Bit 5 = 1, change set immediately: abort the current move (and the buffer), start the new one now from the
    /// current position and velocity (change on the fly).
    Immediately,
    /// Bit 5 = 0: finish the current move (stop at its target), then start the new one.
    #[default]
    AfterCurrent,
    /// Bit 5 = 0 with NT bit 9 "change on set-point": keep moving through the current target and continue into the
    /// new move without stopping, when the new target lies further in the same direction.
    AfterCurrentNoStop,
}

/// How a position set-point was taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MoveAccepted {
    /// The move started now.
    Started,
    /// The move waits in the one-deep buffer until the current move ends.
    Buffered,
}

/// Why a command was refused (nothing changed; the CiA 402 layer does not acknowledge the set-point,
/// NT p.48-49: "bit 12 is not set if the new target can't be reached within the limits").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MoveError {
    /// The set-point buffer already holds a move.
    BufferFull,
    /// A velocity, acceleration or deceleration of zero: the move could never end.
    ZeroLimit,
}

/// A buffered move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PendingMove {
    target: i64,
    limits: Limits,
    blend: bool,
}

/// The trajectory generator of the profile modes: position moves (PPM, homing moves), velocity commands (PVM),
/// halt and quick stop, sampled once per slow tick by [`ProfileGenerator::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProfileGenerator {
    plan: Plan,
    /// Q32 ticks since the plan's origin.
    elapsed: i128,
    pending: Option<PendingMove>,
    state: State,
    shape: ProfileType,
    started_buffered: bool,
}

impl Default for ProfileGenerator {
    fn default() -> Self {
        Self::new(0)
    }
}

impl ProfileGenerator {
    /// At rest at `position` (increments).
    #[must_use]
    pub fn new(position: i64) -> Self {
        let p = i128::from(position).saturating_mul(ONE_Q32);
        Self {
            plan: Plan::rest(p),
            elapsed: 0,
            pending: None,
            state: State { p, v: 0, a: 0 },
            shape: ProfileType::Trapezoidal,
            started_buffered: false,
        }
    }

    /// Drops any motion and the buffer; at rest at `position` (e.g. entering Operation enabled: demand = actual).
    pub fn reset(&mut self, position: i64) {
        *self = Self { shape: self.shape, ..Self::new(position) };
    }

    /// Drops any motion and the buffer; continues from `position` with `velocity` kept (e.g. taking over from a
    /// cyclic mode before a quick stop, so that the stop ramp starts from the actual motion).
    pub fn reset_moving(&mut self, position: i64, velocity: Velocity) {
        self.reset(position);
        let p = self.state.p;
        self.plan = Plan { end_velocity: velocity.wide(), kind: PlanKind::Velocity, ..Plan::rest(p) };
        self.state.v = velocity.wide();
    }

    /// Starts or buffers a position move (PPM new set-point, 0x607A).
    ///
    /// `relative` (controlword bit 6): the target is added to the preceding target — the target of the move in
    /// progress or buffered, or after a halt, stop or velocity command the current demand position (NT 0x60F2
    /// value 0). The sum saturates. `change` selects when it takes effect ([`ChangeMode`]). While no position move
    /// is in progress (at rest, after a halt, in a velocity command) every mode starts at once.
    pub fn start_move(
        &mut self,
        target: i64,
        relative: bool,
        params: &ProfileParams,
        change: ChangeMode,
    ) -> Result<MoveAccepted, MoveError> {
        let limits = Limits::from_params(params, params.velocity).ok_or(MoveError::ZeroLimit)?;
        let busy = matches!(self.plan.kind, PlanKind::Position { .. }) && !self.plan_over();
        if change == ChangeMode::Immediately || !busy {
            let reference = match self.plan.kind {
                PlanKind::Position { target } => target,
                _ => self.setpoint().position,
            };
            let absolute = if relative { reference.saturating_add(target) } else { target };
            self.pending = None;
            self.shape = limits.shape;
            self.plan = plan_position(self.state.p, self.state.v, q32(absolute), absolute, 0, limits);
            self.elapsed = 0;
            return Ok(MoveAccepted::Started);
        }
        if self.pending.is_some() {
            return Err(MoveError::BufferFull);
        }
        let current = match self.plan.kind {
            PlanKind::Position { target } => target,
            _ => self.setpoint().position,
        };
        let absolute = if relative { current.saturating_add(target) } else { target };
        let blend = change == ChangeMode::AfterCurrentNoStop;
        self.pending = Some(PendingMove { target: absolute, limits, blend });
        if blend {
            self.replan_for_blend(current, absolute, limits);
        }
        Ok(MoveAccepted::Buffered)
    }

    /// Replans the move in progress so that it passes its target (`current`) with the velocity the next move
    /// (`next`) can continue with: the lower of both profile velocities, and no more than the next move can stop
    /// from within its own distance; zero if the next move goes the other way.
    fn replan_for_blend(&mut self, current: i64, next: i64, next_limits: Limits) {
        let Some(lim) = self.plan.limits else { return };
        let cur_q = q32(current);
        let dir = {
            let d = cur_q.saturating_sub(self.state.p);
            if d != 0 {
                d.signum()
            } else {
                self.state.v.signum()
            }
        };
        let d_next = q32(next).saturating_sub(cur_q);
        if dir == 0 || d_next.signum() != dir {
            return;
        }
        let stoppable = isqrt(twice_rate_distance(next_limits.dec, d_next.saturating_abs()));
        // Margin of 2^-16 + 1 LSB so that rounding never turns the continuation into a stop-and-reverse.
        let stoppable = stoppable.saturating_sub(stoppable >> 16).saturating_sub(1).max(0);
        let w = lim.vmax.min(next_limits.vmax).min(stoppable);
        if w <= 0 {
            return;
        }
        self.plan = plan_position(self.state.p, self.state.v, cur_q, current, w.saturating_mul(dir), lim);
        self.elapsed = 0;
    }

    /// Starts a velocity command (PVM target velocity 0x60FF, or a homing search): ramps to `velocity`, bounded
    /// by `params.max_velocity` (0x607F), with the acceleration when speeding up and the deceleration when slowing
    /// down (through zero when the sign changes), then keeps it. Clears the buffer.
    pub fn set_velocity_target(&mut self, velocity: Velocity, params: &ProfileParams) -> Result<(), MoveError> {
        let limits = Limits::from_params(params, params.max_velocity).ok_or(MoveError::ZeroLimit)?;
        let target = velocity.wide().clamp(limits.vmax.saturating_neg(), limits.vmax);
        self.pending = None;
        self.shape = limits.shape;
        self.plan = plan_velocity(self.state.p, self.state.v, target, limits);
        self.elapsed = 0;
        Ok(())
    }

    /// Halt (controlword bit 8): stops with `deceleration` (PPM/PVM: 0x6084; HMM: 0x609A) and the active profile
    /// shape, then holds the position (rounded to a whole increment). Clears the buffer; resuming after the halt is
    /// the caller's (re-issue the move). A deceleration of zero stops within one tick.
    pub fn halt(&mut self, deceleration: Acceleration) {
        self.stop(deceleration, self.shape);
    }

    /// Quick stop (0x6085, bounded by 0x60C5/0x60C6: [`ProfileObjects::quick_stop_deceleration`]): stops with a
    /// linear ramp, the shortest stop for the deceleration, whatever the profile type, then holds the position.
    /// Clears the buffer. A deceleration of zero stops within one tick.
    pub fn quick_stop(&mut self, deceleration: Acceleration) {
        self.stop(deceleration, ProfileType::Trapezoidal);
    }

    fn stop(&mut self, deceleration: Acceleration, shape: ProfileType) {
        let peak = match deceleration.wide().saturating_abs() {
            0 => Acceleration::MAX.wide(),
            d => d,
        };
        self.pending = None;
        self.plan = plan_stop(self.state.p, self.state.v, mean_rate(peak, shape), shape);
        self.elapsed = 0;
    }

    /// Advances one slow tick and returns the new sample. Starts the buffered move when the current one ends.
    pub fn step(&mut self) -> Setpoint {
        self.elapsed = self.elapsed.saturating_add(ONE_Q32);
        if self.plan_over() {
            if let Some(next) = self.pending.take() {
                // Continue from the exact end state; the time past the end carries into the new plan.
                let over = self.elapsed.saturating_sub(self.plan.duration);
                let (p, v) = (self.plan.end_position, self.plan.end_velocity);
                self.shape = next.limits.shape;
                self.plan = plan_position(p, v, q32(next.target), next.target, 0, next.limits);
                self.elapsed = over;
                self.started_buffered = true;
            }
        }
        if self.plan_over() {
            if self.plan.end_velocity == 0 {
                self.elapsed = self.plan.duration;
            } else {
                // Endless velocity: fold whole ticks into the end state (exact: Q32 velocity times an integer),
                // so that the products stay small however long it runs.
                self.elapsed = self.elapsed.max(self.plan.duration);
                let whole = self.elapsed.saturating_sub(self.plan.duration) >> 32;
                self.plan.end_position =
                    self.plan.end_position.saturating_add(self.plan.end_velocity.saturating_mul(whole));
                self.plan.duration = self.plan.duration.saturating_add(whole.saturating_mul(ONE_Q32));
            }
        }
        self.state = self.plan.eval(self.elapsed);
        self.state.setpoint()
    }

    /// The latest sample (the state after the last [`Self::step`], or the reset state).
    #[must_use]
    pub fn setpoint(&self) -> Setpoint {
        self.state.setpoint()
    }

    /// The command is complete and nothing is buffered: a position move stands exactly on its target, a stop is
    /// at rest, a velocity command has reached its velocity. PPM/PVM statusword bit 10 "target reached" when no
    /// position window is configured (E3 L6922-6987: window 2^32 - 1 = "end of trajectory").
    #[must_use]
    pub fn is_done(&self) -> bool {
        self.plan_over() && self.pending.is_none()
    }

    /// The current plan has reached its end state (within [`END_TOLERANCE`]).
    fn plan_over(&self) -> bool {
        self.elapsed.saturating_add(END_TOLERANCE) >= self.plan.duration
    }

    /// The target of the position move in progress (or finished), `None` for a stop or a velocity command.
    #[must_use]
    pub fn target(&self) -> Option<i64> {
        match self.plan.kind {
            PlanKind::Position { target } => Some(target),
            _ => None,
        }
    }

    /// The set-point buffer is free (a further [`ChangeMode::AfterCurrent`] move would be accepted). For the PPM
    /// set-point acknowledge, statusword bit 12 (NT p.48-49).
    #[must_use]
    pub fn buffer_free(&self) -> bool {
        self.pending.is_none()
    }

    /// Whether the buffered move started since the last call (clears the flag).
    pub fn take_buffered_started(&mut self) -> bool {
        core::mem::take(&mut self.started_buffered)
    }

    /// Whole slow ticks until the current command is complete (0 when done; the buffered move not included).
    #[must_use]
    pub fn remaining_ticks(&self) -> u64 {
        ceil_ticks(self.plan.duration.saturating_sub(self.elapsed))
    }

    /// The active profile shape (that of the last command; a halt uses it).
    #[must_use]
    pub const fn profile_type(&self) -> ProfileType {
        self.shape
    }
}

/// The duration of a position move, in whole slow ticks: the number of [`ProfileGenerator::step`] calls after
/// which [`ProfileGenerator::is_done`] holds and the output equals the target, i.e. `ceil(T / 400 us)` of the
/// analytic profile time `T` of the planned profile (start position and velocity as given). `None` for a zero
/// velocity or acceleration.
#[must_use]
pub fn planned_duration_ticks(
    start: i64,
    start_velocity: Velocity,
    target: i64,
    params: &ProfileParams,
) -> Option<u64> {
    let limits = Limits::from_params(params, params.velocity)?;
    let plan = plan_position(q32(start), start_velocity.wide(), q32(target), target, 0, limits);
    Some(ceil_ticks(plan.duration))
}

/// The duration of a velocity command (PVM) in whole slow ticks, as [`planned_duration_ticks`].
#[must_use]
pub fn planned_velocity_duration_ticks(
    start_velocity: Velocity,
    target: Velocity,
    params: &ProfileParams,
) -> Option<u64> {
    let limits = Limits::from_params(params, params.max_velocity)?;
    let target = target.wide().clamp(limits.vmax.saturating_neg(), limits.vmax);
    let plan = plan_velocity(0, start_velocity.wide(), target, limits);
    Some(ceil_ticks(plan.duration))
}

fn q32(inc: i64) -> i128 {
    i128::from(inc).saturating_mul(ONE_Q32)
}

fn ceil_ticks(t: i128) -> u64 {
    let t = t.saturating_sub(END_TOLERANCE).max(0);
    u64::try_from(t.saturating_add(ONE_Q32 - 1) >> 32).unwrap_or(u64::MAX)
}

// ---------------------------------------------------------------------------------------------------------------
// Arithmetic
// ---------------------------------------------------------------------------------------------------------------

/// sin(pi w) for `w` in Q62 within [0, 1] (clamped), in Q60 (>= 0). Exactly 0 at w = 0 and w = 1.
fn sin_pi_q60(w: i128) -> i64 {
    let w = w.clamp(0, ONE_Q62);
    let m = w.min(ONE_Q62.saturating_sub(w)); // [0, 1/2]: sin(pi w) = sin(pi (1 - w))
                                              // x = pi m <= pi/2 < 2^61 in Q60.
    let x = i64::try_from(mul_shr(PI_Q60, m, 62)).unwrap_or(0);
    let x2 = mul_q60(x, x); // <= 2.47 in Q60 < 2^62
    let mut t = ONE_Q60;
    for c in SIN_TAYLOR_Q60 {
        // t stays within [0.5, 1]: every product is below 2^123 before the shift.
        t = ONE_Q60.wrapping_sub(mul_q60(mul_q60(x2, t), c));
    }
    mul_q60(x, t)
}

/// sin(2 pi u) for `u` in Q62 within [0, 1], in Q60 (signed).
fn sin_2pi_q60(u: i128) -> i64 {
    let w = u.clamp(0, ONE_Q62).saturating_mul(2);
    if w <= ONE_Q62 {
        sin_pi_q60(w)
    } else {
        sin_pi_q60(w.saturating_sub(ONE_Q62)).wrapping_neg()
    }
}

/// `(a * b) >> 60` for Q60 values below 2^62 in magnitude (the product is below 2^124: no wrap).
#[inline(always)]
fn mul_q60(a: i64, b: i64) -> i64 {
    let p = i128::from(a).wrapping_mul(i128::from(b)) >> 60;
    i64::try_from(p).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sine_matches_f64() {
        let mut worst = 0.0f64;
        for k in 0..=4096i128 {
            let u = (k << 62) / 4096;
            let x = k as f64 / 4096.0;
            let e1 = (sin_pi_q60(u) as f64 / (1u64 << 60) as f64 - (std::f64::consts::PI * x).sin()).abs();
            let e2 = (sin_2pi_q60(u) as f64 / (1u64 << 60) as f64 - (std::f64::consts::TAU * x).sin()).abs();
            worst = worst.max(e1).max(e2);
        }
        assert!(worst < 1e-11, "worst {worst}");
        assert_eq!(sin_pi_q60(0), 0);
        assert_eq!(sin_pi_q60(ONE_Q62), 0);
        assert_eq!(sin_2pi_q60(ONE_Q62 / 2), 0);
    }

    #[test]
    fn constants_match_f64() {
        let q60 = (1u64 << 60) as f64;
        assert!((PI_Q60 as f64 / q60 - std::f64::consts::PI).abs() < 1e-15);
        assert!((INV_2PI2_Q60 as f64 / q60 - 1.0 / (2.0 * std::f64::consts::PI.powi(2))).abs() < 1e-16);
        assert!((INV_2PI_Q60 as f64 / q60 - 1.0 / std::f64::consts::TAU).abs() < 1e-16);
        for (c, k) in SIN_TAYLOR_Q60.iter().zip([7.0f64, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0]) {
            assert!((*c as f64 / q60 - 1.0 / ((2.0 * k) * (2.0 * k + 1.0))).abs() < 1e-16);
        }
    }

    #[test]
    fn scale_units() {
        let s = MotionScale::new(4096);
        // 3000 rpm = 204,800 inc/s = 81.92 inc/tick.
        assert_eq!(s.velocity_from_rpm(3000).to_inc_per_s(), 204_800);
        assert_eq!(s.velocity_to_rpm(s.velocity_from_rpm(-2999)), -2999);
        // 20,000 rpm/s = 1,365,333.3 inc/s².
        assert_eq!(s.acceleration_from_rpm_per_s(20_000).to_inc_per_s2(), 1_365_333);
        // 0x60C5's default 2^32 - 1 rpm/s is 46,912 inc/tick² at 4096 inc/rev: representable.
        assert_eq!(s.acceleration_from_rpm_per_s(u32::MAX).to_bits() >> 40, 46_912);
        assert_eq!(MotionScale::new(u32::MAX).acceleration_from_rpm_per_s(u32::MAX), Acceleration::MAX);
    }
}
