//! Interpolation of the cyclic modes' master set-points (CSP, CSV, CST) onto the slow tick, with feedforward derived
//! from the set-point stream, the offsets 0x60B0..0x60B2 and a defined reaction to missing set-points
//! (`shared/spec/cia402-device-control.md` §2.5-§2.8, §8 item 4; `shared/spec/control-and-protection.md` §1.6, §1.8).
//!
//! # Period (0x60C2)
//! The master sends a set-point every interpolation period `T = value x 10^index s` (0x60C2:01, 0x60C2:02;
//! device.toml accepts indices -6..-3, this module -6..-1). Value 0 disables interpolation: each set-point is
//! applied in the next slow tick and held (IDX L6460-6510), without velocity feedforward (EPOS4: velocity FF in
//! CSP/CSV only with the interpolator active, S1 L762-768). The period must be at least one slow tick (400 us;
//! shorter is [`PeriodError::ShorterThanTick`]). It need **not** be a whole number of slow ticks: the common 1 ms
//! EtherCAT cycle is 2.5 ticks. Time is kept exactly in units of `gcd(T, 400 us)` (200 us for 1 ms), so the
//! interpolation runs on the true master time grid and a boundary that falls on a tick (every second one at 1 ms,
//! every one for 2 ms, 4 ms, ...) is hit exactly.
//!
//! # CSP: cubic Hermite with stream-derived slopes
//! With one period of delay the segment between set-points `P[k-1]` and `P[k]` is played during the period after
//! `P[k]` arrived, as the cubic Hermite polynomial through both points with the slopes `m` estimated from the
//! stream by the second-order backward difference `m[k] = (3 P[k] - 4 P[k-1] + P[k-2]) / 2` (per period). The slope
//! at `P[k]` ends one segment and starts the next, so position and velocity are continuous; the estimate is exact
//! for streams of constant acceleration, so a constant-velocity stream gives a constant velocity feedforward, and a
//! constant-acceleration stream is reproduced exactly. Positions are kept in Q8 increments. Once per period, at the
//! boundary, the segment's coefficients are formed (the cubic's in Q21, its derivative's already scaled by
//! tick/period, in Q34 inc/tick); every tick evaluates both by Horner's scheme at the fraction `u = s / T` of the
//! period (Q32, rounded: `s` in units of gcd(T, tick) times a reciprocal of the period computed in
//! [`CyclicInterpolator::new`], so no division happens per tick or per boundary). Nothing accumulates from tick to
//! tick, and at every period boundary `u = 0`: the position is exactly the master's integer set-point. Between
//! boundaries the position is within 2^-17 inc (the rounding of the Q16 output, plus 0.02 of its last place) plus
//! 2^-32 of the segment's largest slope per period (the fraction's resolution: 0.001 inc at 4 x 10^6 inc per
//! period). The velocity feedforward is the polynomial's derivative, within 1.5 x 2^-32 inc/tick plus 2^-32 of
//! its largest rate of change per period. `firmware/tests/interpolator.rs` checks both bounds against the exact
//! rational polynomial at periods from 400 us to 25.5 s.
//!
//! The acceleration feedforward is **not** the polynomial's second derivative: the master's set-points are
//! integers, and differentiating their rounding twice gives up to +-9 inc per period² (+-1.4 inc/tick² at 1 ms,
//! six times the 20,000 rpm/s of a brisk move, i.e. amperes of feedforward noise). It is the second derivative of
//! the least-squares quadratic through the last nine set-points (Savitzky-Golay), updated once per period as an
//! integer-weight dot product over the eight steps between them times `(tick / T)² / 462` (precomputed in
//! [`CyclicInterpolator::new`] to better than 2^-44; the result is within 2^-40 inc/tick² plus 2^-44 of itself
//! of the exact quotient): exact for constant acceleration, rounding noise about 0.007 inc/tick² rms at 1 ms,
//! delayed by three periods against the position demand (measured on the 10-revolution sin² move of
//! `firmware/tests/interpolator.rs`: max error 0.021 inc/tick² at 1 ms, 0.024 at 2 ms, 0.043 at 4 ms, against a
//! peak of 0.218). The velocity feedforward's rounding noise is at most 2 inc per period (0.70 inc/tick measured at
//! 1 ms), harmless through the velocity FF gain.
//! EPOS4 applies only velocity feedforward in CSP (S1 L762-768); the caller may do the same.
//!
//! # CSV and CST
//! The target velocity (0x60FF + 0x60B1) and the target torque (0x6071 + 0x60B2) are interpolated linearly between
//! set-points (IDX: "linear interpolation of velocity over 60C2h"), with one period of delay; CSV's acceleration
//! feedforward is the slope of that line, and its position output is the integral of the velocity samples
//! (trapezoid rule, Q33; the samples are within 2^-32 of the segment's change of the line, the fraction's resolution).
//!
//! # Arithmetic, envelope and cost
//! The state is `i64` (the CSV position integral `i128`), every operation exact or saturating on purpose, and no
//! division happens after [`CyclicInterpolator::new`] (five long divisions of the period with the 32-bit hardware
//! divide). Envelope: CSP positions within +-2^46 inc (0x607A + 0x60B0 stay within +-2^32; a reset position beyond
//! is clamped), so the slopes stay within +-2^49 inc per period and every intermediate sum fits `i64` exactly; the
//! cubic's coefficients are clamped to +-2^39 inc, not reached while consecutive end points differ by less than 2^34
//! inc; the velocity coefficients saturate at +-2^29 inc/tick (1.3 x 10^12 inc/s: beyond any encoder; 2^28
//! inc/tick is tested). Outside the envelope nothing panics and the boundary positions stay exact.
//!
//! Cost on the STM32F405 (thumbv7em, release, fat LTO), counted by QEMU `-icount` over all three modes, periods
//! from 400 us to 25.5 s, smooth, random and full-range streams with lost set-points: [`CyclicInterpolator::step`]
//! at most 676 instructions in CSP (a boundary tick, the first set-point and the Savitzky-Golay update included;
//! 227 on average), 384 in CSV, 178 in CST; [`CyclicInterpolator::push`] 31; entering the mode,
//! [`CyclicInterpolator::new`] 1,078 (about 400 for the five divisions, most of the rest clearing and copying the
//! 360-byte state) and [`CyclicInterpolator::reset`] 483.
//!
//! # Offsets
//! - 0x60B0 position offset (increments): added to 0x607A before interpolation (CSP).
//! - 0x60B1 velocity offset: CSP velocity feedforward (E3/GT; IDX ignores it in CSP: pass zero for that
//!   behaviour); CSV added to 0x60FF before interpolation.
//! - 0x60B2 torque offset (per mille of rated torque): CSP/CSV torque feedforward (output `torque`, held from one
//!   set-point to the next, 0 once the stream is lost and the interpolator holds); CST added to 0x6071 before
//!   interpolation.
//!
//! # Missing set-points
//! At each period boundary the interpolator consumes the set-point pushed since the previous boundary. If there
//! is none, it extrapolates with the last slope (CSP: the next point is `P + m`, constant velocity, zero
//! acceleration; CSV/CST: the last value is kept) for at most [`DEFAULT_MAX_EXTRAPOLATED_PERIODS`] = 1 consecutive
//! period by default (configurable, [`CyclicInterpolator::with_extrapolation_limit`]): one lost frame passes
//! unnoticed by the motion. At the next boundary still without a set-point it holds: CSP keeps the position reached
//! (velocity and acceleration feedforward 0), CSV ramps the velocity to 0 over one period, CST ramps the torque to 0
//! over one period, and the status reports [`SetpointStatus::Missing`] (IDX raises RPDO timeout 0x8250 after one
//! period, EPOS3 CSP interpolation error 0xFF13; which fault to raise is the fault layer's decision). A set-point
//! arriving later resumes the interpolation from the held point.

use super::trajectory::{Acceleration, Velocity, SLOW_TICK_MICROS};
use super::wide::{sat_i32, sat_i64};

/// Consecutive periods without a set-point that are bridged by extrapolation before holding (one lost frame).
pub const DEFAULT_MAX_EXTRAPOLATED_PERIODS: u8 = 1;
/// Savitzky-Golay weights of the second derivative of a least-squares quadratic through 9 equally spaced points,
/// `w = [28, 7, -8, -17, -20, -17, -8, 7, 28]` oldest first (sum 0, first moment 0, second moment 462 * 2 / 2):
/// `a = sum(w_i P_i) / 462` per period². Applied to the eight steps `s_j = P_j - P_(j-1)` between the points, as
/// `sum(w_i P_i) = sum(W_j s_j)` with `W_j = -(w_0 + .. + w_(j-1))` (the weights sum to 0); antisymmetric.
const SG9_STEP: [i64; 8] = [-28, -35, -27, -10, 10, 27, 35, 28];
/// Denominator of the Savitzky-Golay weights.
const SG9_DEN: u32 = 462;
/// The longest interpolation period: 255 x 10^-1 s.
pub const MAX_PERIOD_MICROS: u32 = 25_500_000;

/// The interpolation time period (0x60C2), in microseconds; 0 = interpolation disabled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct InterpolationPeriod {
    micros: u32,
}

/// Why an interpolation period was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PeriodError {
    /// 0x60C2:02 outside -6..=-1.
    UnsupportedIndex(i8),
    /// Shorter than one slow tick (400 us): set-points would come faster than they can be used.
    ShorterThanTick {
        /// The period asked for.
        micros: u32,
    },
    /// Longer than [`MAX_PERIOD_MICROS`].
    TooLong {
        /// The period asked for.
        micros: u32,
    },
}

impl InterpolationPeriod {
    /// Interpolation disabled (0x60C2:01 = 0): set-points applied in the next tick and held.
    pub const DISABLED: Self = Self { micros: 0 };

    /// From 0x60C2:01 (value) and 0x60C2:02 (index): `value x 10^index s`. Value 0 disables interpolation.
    pub fn from_0x60c2(value: u8, index: i8) -> Result<Self, PeriodError> {
        let unit: u32 = match index {
            -6 => 1,
            -5 => 10,
            -4 => 100,
            -3 => 1_000,
            -2 => 10_000,
            -1 => 100_000,
            other => return Err(PeriodError::UnsupportedIndex(other)),
        };
        // value <= 255, unit <= 10^5: below 2^25.
        Self::from_micros(u32::from(value).saturating_mul(unit))
    }

    /// From a period in microseconds; 0 disables interpolation.
    pub fn from_micros(micros: u32) -> Result<Self, PeriodError> {
        if micros == 0 {
            Ok(Self::DISABLED)
        } else if micros < SLOW_TICK_MICROS {
            Err(PeriodError::ShorterThanTick { micros })
        } else if micros > MAX_PERIOD_MICROS {
            Err(PeriodError::TooLong { micros })
        } else {
            Ok(Self { micros })
        }
    }

    /// The period in microseconds (0 when disabled).
    #[must_use]
    pub const fn micros(&self) -> u32 {
        self.micros
    }

    /// Interpolation is active (0x60C2:01 != 0).
    #[must_use]
    pub const fn is_enabled(&self) -> bool {
        self.micros != 0
    }

    /// The period in slow ticks when it is a whole number of them (2 ms = 5 ticks), else `None` (1 ms = 2.5 ticks).
    #[must_use]
    pub fn whole_ticks(&self) -> Option<u32> {
        if self.micros != 0 && self.micros.checked_rem(SLOW_TICK_MICROS) == Some(0) {
            self.micros.checked_div(SLOW_TICK_MICROS)
        } else {
            None
        }
    }
}

/// The cyclic mode whose set-points are interpolated (0x6060 = 8, 9, 10).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum CyclicMode {
    /// Cyclic synchronous position (8): 0x607A + 0x60B0, cubic.
    #[default]
    Position,
    /// Cyclic synchronous velocity (9): 0x60FF + 0x60B1, linear.
    Velocity,
    /// Cyclic synchronous torque (10): 0x6071 + 0x60B2, linear.
    Torque,
}

/// One master set-point: the values latched from the RxPDO at a SYNC (velocities already converted from rpm with
/// `trajectory::MotionScale`, one multiply each). The mode picks the fields it uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CyclicSetpoint {
    /// 0x607A target position, increments (CSP).
    pub target_position: i32,
    /// 0x60FF target velocity (CSV).
    pub target_velocity: Velocity,
    /// 0x6071 target torque, per mille of rated torque (CST).
    pub target_torque: i16,
    /// 0x60B0 position offset, increments.
    pub position_offset: i32,
    /// 0x60B1 velocity offset.
    pub velocity_offset: Velocity,
    /// 0x60B2 torque offset, per mille of rated torque.
    pub torque_offset: i16,
}

/// Where the set-point stream stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SetpointStatus {
    /// No set-point since the reset: holding the reset state.
    #[default]
    Waiting,
    /// Following the master's set-points.
    Following,
    /// Set-points missing for this many consecutive periods, bridged by extrapolation.
    Extrapolating {
        /// Consecutive periods without a set-point (1..=limit).
        periods: u8,
    },
    /// Set-points missing beyond the extrapolation limit: holding (the "set-point missing" condition).
    Missing,
}

/// One interpolated sample per slow tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CyclicOutput {
    /// Position demand in increments, rounded to nearest (CSP: exact at each boundary on a tick; CSV: integral of
    /// the velocity; CST: the reset position).
    pub position: i64,
    /// The same position in Q16 increments.
    pub position_fine: i64,
    /// CSP: velocity feedforward (derivative of the interpolated position, plus 0x60B1); CSV: the interpolated
    /// velocity demand; CST: 0.
    pub velocity: Velocity,
    /// CSP: acceleration feedforward (second derivative); CSV: slope of the velocity; CST: 0.
    pub acceleration: Acceleration,
    /// CST: the interpolated torque demand; CSP/CSV: the torque feedforward 0x60B2. Per mille of rated torque.
    pub torque: i32,
    /// Stream status.
    pub status: SetpointStatus,
}

impl CyclicOutput {
    /// The "set-point missing" flag for fault handling: set while holding after the extrapolation limit.
    #[must_use]
    pub const fn setpoint_missing(&self) -> bool {
        matches!(self.status, SetpointStatus::Missing)
    }
}

/// What the next segment's end point comes from.
#[derive(Clone, Copy, Debug)]
enum Source {
    Setpoint(CyclicSetpoint),
    Extrapolate,
    Hold,
}

/// The interpolator of one cyclic mode. Call [`Self::push`] when a master set-point arrives (before
/// [`Self::step`] in that tick) and [`Self::step`] every slow tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CyclicInterpolator {
    mode: CyclicMode,
    period: InterpolationPeriod,
    max_extrapolated: u8,
    /// The period and the tick in units of gcd(period, tick): `1 <= tick_u <= 400`, `tick_u <= period_u < 2^25`.
    period_u: u32,
    tick_u: u32,
    /// `ceil(2^57 / period_u)`: the segment fraction `t_u / period_u` in Q32 is `(t_u recip_period) >> 25`.
    recip_period: u64,
    /// `tick / period` in Q63 (floor; at most 2^63).
    tick_per_period: u64,
    /// `period / tick` in Q32 (floor; below 2^57).
    period_per_tick: u64,
    /// `(tick / period)² / 462` in Q(63 + sg_shift) (floor; normalised to [2^54, 2^55) unless the period is one
    /// tick): the Savitzky-Golay scale.
    sg_scale: u64,
    sg_shift: u32,
    started: bool,
    /// Units since the start of the current segment, in [0, period_u).
    t_u: u32,
    /// CSP: positions in Q8 inc (`x_prev` the point before `x_a`), within +-2^54 (+-[`POSITION_LIMIT`] inc);
    /// slopes `2m` in Q8 inc per period, within +-2^57.
    x_prev: i64,
    x_a: i64,
    x_b: i64,
    m_a: i64,
    m_b: i64,
    /// CSP: twice the segment's displacement, `2 (p - x_a) = c1 u + c2 u² + c3 u³` in Q21 inc (`|c| <= 2^60`).
    c1: i64,
    c2: i64,
    c3: i64,
    /// CSP: the velocity `b1 + b2 u + b3 u²` in Q34 inc/tick (each saturated to `i64`).
    b1: i64,
    b2: i64,
    b3: i64,
    /// CSV: velocities Q32 inc/tick; CST: torque Q16 per mille.
    y_a: i64,
    y_b: i64,
    /// CSV: the slope of the velocity segment, Q40 inc/tick².
    y_slope: i64,
    /// CSV position integral, Q33 inc (sum of twice the trapezoid areas).
    integral: i128,
    last_velocity: i64,
    velocity_offset: i64,
    torque_offset: i32,
    /// CSP: the steps between the last nine end points (Q8 inc, each within +-2^55), oldest first, for the
    /// acceleration feedforward.
    steps: [i64; 8],
    /// CSP: acceleration feedforward of the current segment, Q40 inc/tick².
    accel_ff: i64,
    latched: Option<CyclicSetpoint>,
    overruns: u32,
    missing: u8,
    status: SetpointStatus,
    output: CyclicOutput,
}

impl CyclicInterpolator {
    /// An interpolator for `mode` with `period`, at rest at position 0.
    #[must_use]
    pub fn new(mode: CyclicMode, period: InterpolationPeriod) -> Self {
        let micros = period.micros().clamp(SLOW_TICK_MICROS, MAX_PERIOD_MICROS);
        let unit = gcd(micros, SLOW_TICK_MICROS).max(1);
        // 1 <= tick_u <= period_u <= 25,500,000 < 2^25.
        let period_u = micros.checked_div(unit).unwrap_or(1).max(1);
        let tick_u = SLOW_TICK_MICROS.checked_div(unit).unwrap_or(1).clamp(1, period_u);
        // The constants of the period, by long division (no 64-bit division routine).
        // ceil(2^57 / P), at most 2^57.
        let (q, r) = div_u64(1 << 57, period_u);
        let recip_period = if r == 0 { q } else { q.wrapping_add(1) };
        // floor(K 2^63 / P) in two steps: K 2^32 < 2^41, then the remainder (< 2^25) times 2^31. K <= P: at most
        // 2^63.
        let (q1, r1) = div_u64(u64::from(tick_u) << 32, period_u);
        let tick_per_period = (q1 << 31).wrapping_add(div_u64(u64::from(r1) << 31, period_u).0);
        // P 2^32 < 2^57.
        let period_per_tick = div_u64(u64::from(period_u) << 32, tick_u).0;
        // kp² / 2^(63 - z) < 2^63 with the largest such z <= 63 (kp² <= 2^126): full precision at long periods.
        let kp2 = u128::from(tick_per_period).wrapping_mul(u128::from(tick_per_period));
        let sg_shift = u64::try_from(kp2 >> 63).unwrap_or(u64::MAX).leading_zeros().saturating_sub(1).min(63);
        let kp2 = u64::try_from(kp2 >> 63u32.wrapping_sub(sg_shift)).unwrap_or(u64::MAX);
        let sg_scale = div_u64(kp2, SG9_DEN).0;
        // The state `reset(0, Velocity::ZERO)` gives (all zero but the constants; checked by a test), built in
        // place: no copy of the whole state.
        Self {
            mode,
            period,
            max_extrapolated: DEFAULT_MAX_EXTRAPOLATED_PERIODS,
            period_u,
            tick_u,
            recip_period,
            tick_per_period,
            period_per_tick,
            sg_scale,
            sg_shift,
            started: false,
            t_u: 0,
            x_prev: 0,
            x_a: 0,
            x_b: 0,
            m_a: 0,
            m_b: 0,
            c1: 0,
            c2: 0,
            c3: 0,
            b1: 0,
            b2: 0,
            b3: 0,
            y_a: 0,
            y_b: 0,
            y_slope: 0,
            integral: 0,
            last_velocity: 0,
            velocity_offset: 0,
            torque_offset: 0,
            steps: [0; 8],
            accel_ff: 0,
            latched: None,
            overruns: 0,
            missing: 0,
            status: SetpointStatus::Waiting,
            output: CyclicOutput::default(),
        }
    }

    /// The same with another limit of extrapolated periods (0 = hold at the first missing set-point).
    #[must_use]
    pub fn with_extrapolation_limit(mut self, periods: u8) -> Self {
        self.max_extrapolated = periods;
        self
    }

    /// The mode.
    #[must_use]
    pub const fn mode(&self) -> CyclicMode {
        self.mode
    }

    /// The interpolation period.
    #[must_use]
    pub const fn period(&self) -> InterpolationPeriod {
        self.period
    }

    /// Restarts from `position` moving at `velocity` (entering the mode: demand = actual, cf. the EPOS3
    /// re-enable fix, spec §2.5), waiting for the first set-point; the first set-point starts the period clock.
    pub fn reset(&mut self, position: i64, velocity: Velocity) {
        let x = q8(position);
        // 2m in Q8: 2 v [Q32 inc/tick] * period/tick [Q32], shifted by 32 + 32 - 8 - 1 = 55, rounded; clamped to
        // the slope envelope.
        let m2 = round_shr_clamp(mul_wide(velocity.to_bits(), self.period_per_tick), 55, SLOPE_LIMIT);
        // As if the stream had been moving at `velocity`: the previous points lie one slope per period behind.
        let m = m2 >> 1;
        // |x| <= 2^54, |m| <= 2^56: no overflow before the clamps.
        self.x_b = x;
        self.x_a = clamp_q8(x.wrapping_sub(m));
        self.x_prev = clamp_q8(self.x_a.wrapping_sub(m));
        self.m_a = m2;
        self.m_b = m2;
        self.steps = [m.clamp(-STEP_LIMIT, STEP_LIMIT); 8];
        self.accel_ff = 0;
        self.y_a = match self.mode {
            CyclicMode::Velocity => velocity.to_bits(),
            _ => 0,
        };
        self.y_b = self.y_a;
        // |x| <= 2^54: x 2^25 fits i128.
        self.integral = i128::from(x) << 25;
        self.last_velocity = self.y_a;
        self.velocity_offset = 0;
        self.torque_offset = 0;
        self.started = false;
        self.t_u = 0;
        self.latched = None;
        self.missing = 0;
        self.status = SetpointStatus::Waiting;
        self.prepare();
        self.output = CyclicOutput {
            position,
            position_fine: sat_i64(i128::from(position) << 16),
            velocity: if self.mode == CyclicMode::Velocity { velocity } else { Velocity::ZERO },
            acceleration: Acceleration::ZERO,
            torque: 0,
            status: SetpointStatus::Waiting,
        };
    }

    /// Latches a master set-point; it is consumed at the next period boundary. A second set-point within the same
    /// period replaces the first (counted in [`Self::overruns`]).
    pub fn push(&mut self, setpoint: CyclicSetpoint) {
        if self.latched.is_some() {
            self.overruns = self.overruns.saturating_add(1);
        }
        self.latched = Some(setpoint);
    }

    /// Set-points replaced before they were used (two within one period).
    #[must_use]
    pub const fn overruns(&self) -> u32 {
        self.overruns
    }

    /// The latest output.
    #[must_use]
    pub const fn output(&self) -> CyclicOutput {
        self.output
    }

    /// Advances one slow tick and returns the sample for it.
    pub fn step(&mut self) -> CyclicOutput {
        if !self.period.is_enabled() {
            return self.step_direct();
        }
        if !self.started {
            if self.latched.is_none() {
                return self.output;
            }
            self.started = true;
            self.t_u = 0;
            self.boundary();
        } else {
            // t_u < period_u < 2^25 and tick_u <= 400: no overflow.
            self.t_u = self.t_u.wrapping_add(self.tick_u);
            // The period is at least one tick: at most one boundary per tick.
            if self.t_u >= self.period_u {
                self.t_u = self.t_u.wrapping_sub(self.period_u);
                self.boundary();
            }
        }
        self.output = self.evaluate();
        self.output
    }

    /// Interpolation disabled: the latest set-point applies from this tick on.
    fn step_direct(&mut self) -> CyclicOutput {
        if let Some(sp) = self.latched.take() {
            self.status = SetpointStatus::Following;
            self.advance(Source::Setpoint(sp));
            // Jump: the segment degenerates to its end point.
            self.x_a = self.x_b;
            self.x_prev = self.x_b;
            self.m_a = 0;
            self.m_b = 0;
            self.y_a = self.y_b;
            self.prepare();
        }
        self.t_u = 0;
        self.output = self.evaluate();
        // No feedforward without interpolation (S1 L762-768), except the offsets.
        if self.mode == CyclicMode::Position {
            self.output.velocity = Velocity(self.velocity_offset);
            self.output.acceleration = Acceleration::ZERO;
        }
        self.output
    }

    /// A period boundary: the next segment ends at the latched set-point, an extrapolated one, or the hold point.
    fn boundary(&mut self) {
        let source = match self.latched.take() {
            Some(sp) => {
                self.missing = 0;
                self.status = SetpointStatus::Following;
                Source::Setpoint(sp)
            }
            None => {
                self.missing = self.missing.saturating_add(1);
                if self.missing <= self.max_extrapolated {
                    self.status = SetpointStatus::Extrapolating { periods: self.missing };
                    Source::Extrapolate
                } else {
                    self.status = SetpointStatus::Missing;
                    Source::Hold
                }
            }
        };
        self.advance(source);
        self.prepare();
    }

    /// The next segment's end points.
    fn advance(&mut self, source: Source) {
        match self.mode {
            CyclicMode::Position => {
                let x_prev = self.x_a;
                self.x_a = self.x_b;
                self.m_a = self.m_b;
                match source {
                    Source::Setpoint(sp) => {
                        // |p| <= 2^32: exact in Q8.
                        let p = i64::from(sp.target_position).wrapping_add(i64::from(sp.position_offset));
                        self.x_b = q8(p);
                        // BDF2: 2m = 3 x_b - 4 x_a + x_prev; positions within +-2^54, so |2m| <= 2^57: exact.
                        self.m_b = self.x_b.wrapping_mul(3).wrapping_sub(self.x_a.wrapping_mul(4)).wrapping_add(x_prev);
                        self.velocity_offset = sp.velocity_offset.to_bits();
                        self.torque_offset = i32::from(sp.torque_offset);
                    }
                    Source::Extrapolate => {
                        // Constant velocity: x_b = x_a + m, slope unchanged (|x_a + m| <= 2^54 + 2^56: exact).
                        self.x_b = clamp_q8(self.x_a.wrapping_add(self.m_a >> 1));
                        self.m_b = self.m_a;
                    }
                    Source::Hold => {
                        self.x_b = self.x_a;
                        self.m_a = 0;
                        self.m_b = 0;
                        self.velocity_offset = 0;
                        self.torque_offset = 0;
                    }
                }
                self.x_prev = x_prev;
                // The new step, |x_b - x_a| <= 2^55.
                let [_, s1, s2, s3, s4, s5, s6, s7] = self.steps;
                self.steps = [s1, s2, s3, s4, s5, s6, s7, self.x_b.wrapping_sub(self.x_a)];
                self.accel_ff = if matches!(source, Source::Hold) { 0 } else { self.stream_acceleration() };
            }
            CyclicMode::Velocity => {
                self.y_a = self.y_b;
                match source {
                    Source::Setpoint(sp) => {
                        self.y_b = sp.target_velocity.to_bits().saturating_add(sp.velocity_offset.to_bits());
                        self.torque_offset = i32::from(sp.torque_offset);
                    }
                    Source::Extrapolate => {}
                    Source::Hold => {
                        self.y_b = 0;
                        self.torque_offset = 0;
                    }
                }
            }
            CyclicMode::Torque => {
                self.y_a = self.y_b;
                match source {
                    Source::Setpoint(sp) => {
                        // |t| < 2^16: exact in Q16.
                        let t = i64::from(sp.target_torque).wrapping_add(i64::from(sp.torque_offset));
                        self.y_b = t << 16;
                    }
                    Source::Extrapolate => {}
                    Source::Hold => self.y_b = 0,
                }
            }
        }
    }

    /// The current segment's polynomial coefficients, once per segment (no division: the period's reciprocals
    /// are constants of [`Self::new`]).
    fn prepare(&mut self) {
        match self.mode {
            CyclicMode::Position => {
                // 2 (p - x_a) = M_a u + (6D - 2M_a - M_b) u² + (-4D + M_a + M_b) u³, u = s / T. |D| <= 2^55 and
                // |M| <= 2^57: |k2| < 2^60, |k3| < 2^59, exact; then clamped to the envelope +-2^47.
                let d = self.x_b.wrapping_sub(self.x_a);
                let (ma, mb) = (self.m_a, self.m_b);
                let k1 = ma.clamp(-COEF_LIMIT, COEF_LIMIT);
                let k2 =
                    d.wrapping_mul(6).wrapping_sub(ma.wrapping_mul(2)).wrapping_sub(mb).clamp(-COEF_LIMIT, COEF_LIMIT);
                let k3 = ma.wrapping_add(mb).wrapping_sub(d.wrapping_mul(4)).clamp(-COEF_LIMIT, COEF_LIMIT);
                // |k| <= 2^47: k 2^13 <= 2^60.
                self.c1 = k1 << COEF_SHIFT;
                self.c2 = k2 << COEF_SHIFT;
                self.c3 = k3 << COEF_SHIFT;
                // The derivative (M_a + 2 k2 u + 3 k3 u²) / 2 [Q8 inc/period] times tick/period [Q63]: the shift
                // 8 + 63 + 1 - 34 = 38 gives Q34 inc/tick, rounded, saturated. |2 k2|, |3 k3| < 2^49.
                let kp = self.tick_per_period;
                let shift = 8 + 63 + 1 - (32 + VEL_EXTRA_BITS);
                self.b1 = round_shr_clamp(mul_wide(k1, kp), shift, i64::MAX);
                self.b2 = round_shr_clamp(mul_wide(k2.wrapping_mul(2), kp), shift, i64::MAX);
                self.b3 = round_shr_clamp(mul_wide(k3.wrapping_mul(3), kp), shift, i64::MAX);
            }
            CyclicMode::Velocity => {
                // dy [Q32 inc/tick per period] * tick/period [Q63] -> Q40 inc/tick²: shift 32 + 63 - 40 = 55.
                let dy = self.y_b.saturating_sub(self.y_a);
                self.y_slope = shr_clamp(mul_wide(dy, self.tick_per_period), 55, i64::MAX);
            }
            CyclicMode::Torque => {}
        }
    }

    /// The stream's acceleration: second derivative of the least-squares quadratic through the last nine end
    /// points (Savitzky-Golay), Q40 inc/tick². Exact for constant acceleration; centred four periods behind the
    /// newest point (three behind the position demand).
    fn stream_acceleration(&self) -> i64 {
        // sum(W_j s_j) with W antisymmetric (W_(9-j) = -W_j): four products. |s| <= 2^55 and the |W| sum to
        // 200 < 2^8: the sum stays below 2^63 and the wrapping operations are exact.
        let [s1, s2, s3, s4, s5, s6, s7, s8] = self.steps;
        let [_, _, _, _, w5, w6, w7, w8] = SG9_STEP;
        let sum = s8
            .wrapping_sub(s1)
            .wrapping_mul(w8)
            .wrapping_add(s7.wrapping_sub(s2).wrapping_mul(w7))
            .wrapping_add(s6.wrapping_sub(s3).wrapping_mul(w6))
            .wrapping_add(s5.wrapping_sub(s4).wrapping_mul(w5));
        // sum / 462 [Q8 inc/period²] * (tick/period)² -> Q40: sum * sg_scale [Q(63 + z)] >> (8 + 63 + z - 40);
        // |sum sg_scale| < 2^63 2^55.
        shr_clamp(mul_wide(sum, self.sg_scale), 31u32.wrapping_add(self.sg_shift), i64::MAX)
    }

    /// The segment fraction `u = t_u / period_u` in Q32, rounded to nearest (within half a unit of the last place
    /// plus `t_u / 2^25` of one, i.e. below one unit): `recip = ceil(2^57 / P)`, `u = (t_u recip + 2^24) >> 25`.
    /// Exactly 0 at the boundary.
    fn fraction(&self) -> u32 {
        // t_u < P and recip <= 2^57 / P + 1: the product is below 2^57 + P, no wrap; the quotient is below 2^32 + 1
        // (2^32 itself, possible for P > 2^16, saturates to the largest fraction).
        let q = u64::from(self.t_u).wrapping_mul(self.recip_period).wrapping_add(1 << 24) >> 25;
        u32::try_from(q).unwrap_or(u32::MAX)
    }

    /// The sample at `t_u` within the current segment.
    fn evaluate(&mut self) -> CyclicOutput {
        let status = self.status;
        let u = self.fraction();
        match self.mode {
            CyclicMode::Position => {
                // Horner in Q21: |c| <= 2^60 each and mul_frac never grows a value, so every partial sum stays below
                // 3 2^60 and the wrapping additions are exact.
                let h = mul_frac(self.c3, u).wrapping_add(self.c2);
                let h = mul_frac(h, u).wrapping_add(self.c1);
                let h = mul_frac(h, u);
                // Twice the displacement in Q21 -> Q16: shift by 6, rounded; |delta| < 2^56 and |x_a 2^8| <= 2^62:
                // the sum fits. Exactly x_a at u = 0.
                let fine = (self.x_a << 8).wrapping_add(h.wrapping_add(1 << 5) >> 6);
                // Velocity in Q34, saturating (only beyond 2^29 inc/tick).
                let v = mul_frac(mul_frac(self.b3, u).saturating_add(self.b2), u).saturating_add(self.b1);
                let v = v.saturating_add(1 << (VEL_EXTRA_BITS - 1)) >> VEL_EXTRA_BITS;
                CyclicOutput {
                    position: fine.wrapping_add(1 << 15) >> 16,
                    position_fine: fine,
                    velocity: Velocity(v.saturating_add(self.velocity_offset)),
                    acceleration: Acceleration(self.accel_ff),
                    torque: self.torque_offset,
                    status,
                }
            }
            CyclicMode::Velocity => {
                let dy = self.y_b.saturating_sub(self.y_a);
                let v = self.y_a.saturating_add(mul_frac(dy, u));
                // Trapezoid rule, exact for the piecewise-linear velocity: Q33 += v_prev + v.
                self.integral =
                    self.integral.saturating_add(i128::from(self.last_velocity)).saturating_add(i128::from(v));
                self.last_velocity = v;
                CyclicOutput {
                    position: sat_i64(self.integral.saturating_add(1 << 32) >> 33),
                    position_fine: sat_i64(self.integral >> 17),
                    velocity: Velocity(v),
                    acceleration: Acceleration(self.y_slope),
                    torque: self.torque_offset,
                    status,
                }
            }
            CyclicMode::Torque => {
                // |y| < 2^33: no overflow.
                let q = self.y_a.wrapping_add(mul_frac(self.y_b.wrapping_sub(self.y_a), u));
                CyclicOutput {
                    position: self.output.position,
                    position_fine: self.output.position_fine,
                    velocity: Velocity::ZERO,
                    acceleration: Acceleration::ZERO,
                    torque: sat_i32(i128::from(q.wrapping_add(1 << 15) >> 16)),
                    status,
                }
            }
        }
    }
}

/// The envelope of CSP positions: +-2^46 inc (+-2^54 in Q8; set-points and offsets are `i32`, so their sum is
/// within +-2^32).
const POSITION_LIMIT: i64 = 1 << 46;
/// The envelope of the slopes `2m` (Q8 inc per period): +-2^57, what positions within the envelope give.
const SLOPE_LIMIT: i64 = 1 << 57;
/// The envelope of one step between end points (Q8): +-2^55.
const STEP_LIMIT: i64 = 1 << 55;
/// Fraction bits added to the CSP position coefficients (Q8 + 13 = Q21).
const COEF_SHIFT: u32 = 13;
/// The envelope of the CSP coefficients `M_a`, `k2`, `k3`: +-2^47 in Q8 (2^39 inc).
const COEF_LIMIT: i64 = 1 << 47;
/// Fraction bits of the CSP velocity coefficients beyond Q32 (their range is then +-2^29 inc/tick).
const VEL_EXTRA_BITS: u32 = 2;

/// A position in Q8 inc, clamped to +-[`POSITION_LIMIT`] (then the shift is exact).
fn q8(position: i64) -> i64 {
    position.clamp(-POSITION_LIMIT, POSITION_LIMIT) << 8
}

/// A Q8 position clamped to the envelope.
fn clamp_q8(x: i64) -> i64 {
    x.clamp(-(POSITION_LIMIT << 8), POSITION_LIMIT << 8)
}

/// `a b`, exact: `|a b| < 2^63 2^64 = 2^127`.
fn mul_wide(a: i64, b: u64) -> i128 {
    i128::from(a).wrapping_mul(i128::from(b))
}

/// `floor(x / 2^s)` clamped to +-`limit`; `s < 128`.
fn shr_clamp(x: i128, s: u32, limit: i64) -> i64 {
    sat_i64(x.wrapping_shr(s)).clamp(limit.wrapping_neg(), limit)
}

/// `x / 2^s` rounded to nearest (ties up), clamped to +-`limit`; `1 <= s < 127`.
fn round_shr_clamp(x: i128, s: u32, limit: i64) -> i64 {
    shr_clamp(x.saturating_add(1i128.wrapping_shl(s.wrapping_sub(1))), s, limit)
}

/// `a u / 2^32` for a Q32 fraction `u` in [0, 1), rounded to nearest (ties up); 0 for `u = 0`, and
/// `|result| <= |a|`.
fn mul_frac(a: i64, u: u32) -> i64 {
    // a = hi 2^32 + lo with hi = a >> 32 (|hi| <= 2^31) and 0 <= lo < 2^32: a u / 2^32 = hi u + lo u / 2^32.
    // |hi u| < 2^63 and lo u + 2^31 <= (2^32 - 1)² + 2^31 < 2^64: nothing wraps; the sum is the rounded result,
    // of magnitude at most |a|, so the wrapping addition does not wrap either.
    let hi = (a >> 32).wrapping_mul(i64::from(u));
    let lo = u64::from(a as u32).wrapping_mul(u64::from(u)).wrapping_add(1 << 31) >> 32;
    hi.wrapping_add(lo as i64)
}

/// `(n / d, n % d)` for `1 <= d < 2^25` by long division in 7-bit digits with the 32-bit hardware divide (the
/// remainder times 2^7 stays below 2^32); `d = 0` gives (0, 0).
fn div_u64(n: u64, d: u32) -> (u64, u32) {
    if d == 0 || d >= 1 << 25 {
        return (0, 0);
    }
    let (mut q, mut r) = (0u64, 0u32);
    // Bit 63 alone, then nine digits of seven bits.
    let mut shift = 63u32;
    loop {
        // r < d < 2^25: r 2^7 + digit < 2^32.
        r = (r << 7) | ((n >> shift) as u32 & 0x7F);
        let digit = r.checked_div(d).unwrap_or(0);
        r = r.wrapping_sub(digit.wrapping_mul(d));
        q = (q << 7) | u64::from(digit);
        if shift == 0 {
            return (q, r);
        }
        shift = shift.saturating_sub(7);
    }
}

/// Greatest common divisor (Euclid; at most ~46 steps for `u32`).
fn gcd(mut a: u32, mut b: u32) -> u32 {
    while b != 0 {
        let r = a.checked_rem(b).unwrap_or(0);
        a = b;
        b = r;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift).
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
    }

    const PERIODS: [u32; 12] = [400, 480, 500, 600, 800, 1000, 1100, 1200, 2000, 123_457, 999_999, 25_500_000];

    #[test]
    fn new_is_the_reset_state() {
        for mode in [CyclicMode::Position, CyclicMode::Velocity, CyclicMode::Torque] {
            for micros in PERIODS.into_iter().chain([0]) {
                let ip = CyclicInterpolator::new(mode, InterpolationPeriod::from_micros(micros).unwrap());
                let mut reset = ip;
                reset.reset(0, Velocity::ZERO);
                assert_eq!(ip, reset, "{mode:?} {micros}");
            }
        }
    }

    #[test]
    fn period_constants_are_exact() {
        let mut periods: Vec<u32> = PERIODS.to_vec();
        periods.extend((400..3000).step_by(7));
        periods.extend([MAX_PERIOD_MICROS - 1, 16_777_216, 33_333, 401, 999_983]);
        for micros in periods {
            let ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(micros).unwrap());
            let (p, k) = (u128::from(ip.period_u), u128::from(ip.tick_u));
            assert_eq!(p * 400, k * u128::from(micros), "{micros}: the units");
            assert_eq!(u128::from(ip.recip_period), (1u128 << 57).div_ceil(p));
            assert_eq!(u128::from(ip.tick_per_period), (k << 63) / p);
            assert_eq!(u128::from(ip.period_per_tick), (p << 32) / k);
            let kp2 = u128::from(ip.tick_per_period).pow(2) >> (63 - ip.sg_shift);
            assert_eq!(u128::from(ip.sg_scale), kp2 / 462);
            assert!(ip.sg_scale < 1 << 55, "{micros}");
            assert!(k == p || ip.sg_scale >= 1 << 53, "{micros}: normalised");
            // The fraction is s / P rounded, within one unit of the last place.
            let mut ip = ip;
            let count = ip.period_u.min(5000);
            for s in (0..count).chain(ip.period_u.saturating_sub(5)..ip.period_u) {
                ip.t_u = s;
                let exact = (f64::from(s) / f64::from(ip.period_u)) * 4_294_967_296.0;
                assert!((f64::from(ip.fraction()) - exact).abs() <= 1.0, "{micros}: s {s}");
            }
            ip.t_u = 0;
            assert_eq!(ip.fraction(), 0);
        }
    }

    #[test]
    fn long_division_matches() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for _ in 0..20_000 {
            let n = rng.next() >> (rng.next() % 64);
            let d = (rng.next() % (1 << 25)).max(1) as u32 >> (rng.next() % 25);
            let d = d.max(1);
            assert_eq!(div_u64(n, d), (n / u64::from(d), (n % u64::from(d)) as u32), "{n} / {d}");
        }
        assert_eq!(div_u64(u64::MAX, 1), (u64::MAX, 0));
        assert_eq!(div_u64(u64::MAX, (1 << 25) - 1), (u64::MAX / ((1 << 25) - 1), (u64::MAX % ((1 << 25) - 1)) as u32));
        assert_eq!(div_u64(5, 0), (0, 0));
    }

    #[test]
    fn fraction_product_is_rounded() {
        let mut rng = Rng(0x1234_5678_9abc_def1);
        let specials = [i64::MIN, i64::MAX, -1, 0, 1, 1 << 60, -(1 << 60)];
        for i in 0..50_000 {
            let a = match specials.get(i) {
                Some(&a) => a,
                None => (rng.next() as i64) >> (rng.next() % 64),
            };
            let u = if i % 7 == 0 { u32::MAX } else { rng.next() as u32 };
            let exact = (i128::from(a) * i128::from(u) + (1 << 31)) >> 32;
            assert_eq!(i128::from(mul_frac(a, u)), exact, "{a} * {u}");
            assert!(mul_frac(a, u).unsigned_abs() <= a.unsigned_abs());
            assert_eq!(mul_frac(a, 0), 0);
        }
    }

    #[test]
    fn savitzky_golay_step_weights() {
        // From the point weights: W_j = -(w_0 + .. + w_(j-1)); antisymmetric.
        let w: [i64; 9] = [28, 7, -8, -17, -20, -17, -8, 7, 28];
        let mut prefix = 0;
        for (j, &big_w) in SG9_STEP.iter().enumerate() {
            prefix += w[j];
            assert_eq!(big_w, -prefix);
            assert_eq!(SG9_STEP[7 - j], -big_w);
        }
        assert_eq!(w.iter().sum::<i64>(), 0);
        // A parabola x_i = i² (second derivative 2) gives 2 * 462.
        let steps: Vec<i64> = (1..9).map(|i| i * i - (i - 1) * (i - 1)).collect();
        let sum: i64 = steps.iter().zip(SG9_STEP).map(|(s, w)| s * w).sum();
        assert_eq!(sum, 2 * i64::from(SG9_DEN));
    }
}
