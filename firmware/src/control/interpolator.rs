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
//! constant-acceleration stream is reproduced exactly. Positions are kept in Q8 increments and the polynomial is
//! evaluated as one exact rational expression per tick (no accumulation): at every period boundary the position is
//! exactly the master's integer set-point. The velocity feedforward is the polynomial's derivative.
//!
//! The acceleration feedforward is **not** the polynomial's second derivative: the master's set-points are
//! integers, and differentiating their rounding twice gives up to +-9 inc per period² (+-1.4 inc/tick² at 1 ms,
//! six times the 20,000 rpm/s of a brisk move, i.e. amperes of feedforward noise). It is the second derivative of
//! the least-squares quadratic through the last nine set-points (Savitzky-Golay), updated once per period: exact for
//! constant acceleration, rounding noise about 0.007 inc/tick² rms at 1 ms, delayed by three periods against the
//! position demand (measured on the 10-revolution sin² move of `firmware/tests/interpolator.rs`: max error 0.021
//! inc/tick² at 1 ms, 0.024 at 2 ms, 0.043 at 4 ms, against a peak of 0.218). The velocity feedforward's rounding
//! noise is at most 2 inc per period (0.70 inc/tick measured at 1 ms), harmless through the velocity FF gain.
//! EPOS4 applies only velocity feedforward in CSP (S1 L762-768); the caller may do the same.
//!
//! # CSV and CST
//! The target velocity (0x60FF + 0x60B1) and the target torque (0x6071 + 0x60B2) are interpolated linearly between
//! set-points (IDX: "linear interpolation of velocity over 60C2h"), with one period of delay; CSV's acceleration
//! feedforward is the slope of that line, and its position output is the exact integral of the velocity (Q33).
//!
//! # Offsets
//! - 0x60B0 position offset (increments): added to 0x607A before interpolation (CSP).
//! - 0x60B1 velocity offset: CSP velocity feedforward (E3/GT; IDX ignores it in CSP: pass zero for that
//!   behaviour); CSV added to 0x60FF before interpolation.
//! - 0x60B2 torque offset (per mille of rated torque): CSP/CSV torque feedforward (output `torque`); CST added to
//!   0x6071 before interpolation.
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

use super::trajectory::{div_shl, mul_shr, round_shr, sat_i32, sat_i64, Acceleration, Velocity, SLOW_TICK_MICROS};

/// Consecutive periods without a set-point that are bridged by extrapolation before holding (one lost frame).
pub const DEFAULT_MAX_EXTRAPOLATED_PERIODS: u8 = 1;
/// Savitzky-Golay weights of the second derivative of a least-squares quadratic through 9 equally spaced points,
/// oldest first (sum 0, first moment 0, second moment 462 * 2 / 2): `a = sum(c_i P_i) / 462` per period².
const SG9_ACCEL: [i128; 9] = [28, 7, -8, -17, -20, -17, -8, 7, 28];
/// Denominator of [`SG9_ACCEL`].
const SG9_DEN: i128 = 462;
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
    /// The period and the tick in units of gcd(period, tick).
    period_u: i128,
    tick_u: i128,
    started: bool,
    /// Units since the start of the current segment, in [0, period_u).
    t_u: i128,
    /// CSP: positions in Q8 inc (`x_prev` the point before `x_a`), slopes `2m` in Q8 inc per period.
    x_prev: i128,
    x_a: i128,
    x_b: i128,
    m_a: i128,
    m_b: i128,
    /// CSV: velocities Q32 inc/tick; CST: torque Q16 per mille.
    y_a: i128,
    y_b: i128,
    /// CSV position integral, Q33 inc (sum of twice the trapezoid areas).
    integral: i128,
    last_velocity: i128,
    velocity_offset: i128,
    torque_offset: i32,
    /// CSP: the last nine end points (Q8 inc), oldest first, for the acceleration feedforward.
    history: [i128; 9],
    /// CSP: acceleration feedforward of the current segment, Q40 inc/tick².
    accel_ff: i128,
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
        let unit = i128::from(gcd(period.micros().max(SLOW_TICK_MICROS), SLOW_TICK_MICROS).max(1));
        let mut s = Self {
            mode,
            period,
            max_extrapolated: DEFAULT_MAX_EXTRAPOLATED_PERIODS,
            period_u: i128::from(period.micros().max(SLOW_TICK_MICROS)).checked_div(unit).unwrap_or(1),
            tick_u: i128::from(SLOW_TICK_MICROS).checked_div(unit).unwrap_or(1),
            started: false,
            t_u: 0,
            x_prev: 0,
            x_a: 0,
            x_b: 0,
            m_a: 0,
            m_b: 0,
            y_a: 0,
            y_b: 0,
            integral: 0,
            last_velocity: 0,
            velocity_offset: 0,
            torque_offset: 0,
            history: [0; 9],
            accel_ff: 0,
            latched: None,
            overruns: 0,
            missing: 0,
            status: SetpointStatus::Waiting,
            output: CyclicOutput::default(),
        };
        s.reset(0, Velocity::ZERO);
        s
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
        let x = i128::from(position).saturating_mul(1 << 8);
        // 2m in Q8: 2 v [Q32 inc/tick] * period/tick, shifted by 24.
        let per_period =
            mul_shr(i128::from(velocity.to_bits()), self.period_u, 0).checked_div(self.tick_u).unwrap_or(0);
        let m2 = round_shr(per_period, 23);
        // As if the stream had been moving at `velocity`: the previous points lie one slope per period behind.
        let m = m2 >> 1;
        self.x_b = x;
        self.x_a = x.saturating_sub(m);
        self.x_prev = self.x_a.saturating_sub(m);
        self.m_a = m2;
        self.m_b = m2;
        let mut back = x;
        for slot in self.history.iter_mut().rev() {
            *slot = back;
            back = back.saturating_sub(m);
        }
        self.accel_ff = 0;
        self.y_a = match self.mode {
            CyclicMode::Velocity => i128::from(velocity.to_bits()),
            _ => 0,
        };
        self.y_b = self.y_a;
        self.integral = x.saturating_mul(1 << 25);
        self.last_velocity = self.y_a;
        self.velocity_offset = 0;
        self.torque_offset = 0;
        self.started = false;
        self.t_u = 0;
        self.latched = None;
        self.missing = 0;
        self.status = SetpointStatus::Waiting;
        self.output = CyclicOutput {
            position,
            position_fine: sat_i64(i128::from(position).saturating_mul(1 << 16)),
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
            self.t_u = self.t_u.saturating_add(self.tick_u);
            // The period is at least one tick: at most one boundary per tick.
            if self.t_u >= self.period_u {
                self.t_u = self.t_u.saturating_sub(self.period_u);
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
        }
        self.t_u = 0;
        self.output = self.evaluate();
        // No feedforward without interpolation (S1 L762-768), except the offsets.
        if self.mode == CyclicMode::Position {
            self.output.velocity = Velocity(sat_i64(self.velocity_offset));
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
    }

    fn advance(&mut self, source: Source) {
        match self.mode {
            CyclicMode::Position => {
                let x_prev = self.x_a;
                self.x_a = self.x_b;
                self.m_a = self.m_b;
                match source {
                    Source::Setpoint(sp) => {
                        let p = i128::from(sp.target_position).saturating_add(i128::from(sp.position_offset));
                        self.x_b = p.saturating_mul(1 << 8);
                        // BDF2: 2m = 3 x_b - 4 x_a + x_prev.
                        self.m_b = self
                            .x_b
                            .saturating_mul(3)
                            .saturating_sub(self.x_a.saturating_mul(4))
                            .saturating_add(x_prev);
                        self.velocity_offset = i128::from(sp.velocity_offset.to_bits());
                        self.torque_offset = i32::from(sp.torque_offset);
                    }
                    Source::Extrapolate => {
                        // Constant velocity: x_b = x_a + m, slope unchanged.
                        self.x_b = self.x_a.saturating_add(self.m_a >> 1);
                        self.m_b = self.m_a;
                    }
                    Source::Hold => {
                        self.x_b = self.x_a;
                        self.m_a = 0;
                        self.m_b = 0;
                        self.velocity_offset = 0;
                    }
                }
                self.x_prev = x_prev;
                self.history.rotate_left(1);
                if let Some(newest) = self.history.last_mut() {
                    *newest = self.x_b;
                }
                self.accel_ff = if matches!(source, Source::Hold) { 0 } else { self.stream_acceleration() };
            }
            CyclicMode::Velocity => {
                self.y_a = self.y_b;
                match source {
                    Source::Setpoint(sp) => {
                        self.y_b = i128::from(sp.target_velocity.to_bits())
                            .saturating_add(i128::from(sp.velocity_offset.to_bits()));
                        self.torque_offset = i32::from(sp.torque_offset);
                    }
                    Source::Extrapolate => {}
                    Source::Hold => self.y_b = 0,
                }
            }
            CyclicMode::Torque => {
                self.y_a = self.y_b;
                match source {
                    Source::Setpoint(sp) => {
                        let t = i128::from(sp.target_torque).saturating_add(i128::from(sp.torque_offset));
                        self.y_b = t.saturating_mul(1 << 16);
                    }
                    Source::Extrapolate => {}
                    Source::Hold => self.y_b = 0,
                }
            }
        }
    }

    /// The stream's acceleration: second derivative of the least-squares quadratic through the last nine end
    /// points (Savitzky-Golay), Q40 inc/tick². Exact for constant acceleration; centred four periods behind the
    /// newest point (three behind the position demand).
    fn stream_acceleration(&self) -> i128 {
        let sum = self.history.iter().zip(SG9_ACCEL).fold(0i128, |acc, (x, c)| acc.saturating_add(x.saturating_mul(c)));
        // sum / 462 [Q8 inc/period²] * (tick/period)² -> Q40 inc/tick².
        let tick2 = self.tick_u.saturating_mul(self.tick_u);
        let den = SG9_DEN.saturating_mul(self.period_u).saturating_mul(self.period_u);
        div_shl(sum.saturating_mul(tick2), den, 32)
    }

    /// The sample at `t_u` within the current segment.
    fn evaluate(&mut self) -> CyclicOutput {
        let status = self.status;
        let sigma = self.t_u;
        let t = self.period_u;
        match self.mode {
            CyclicMode::Position => {
                // 2 T³ (p - x_a) = M_a s T² + (6D - 2M_a - M_b) s² T + (-4D + M_a + M_b) s³, s = sigma.
                let d = self.x_b.saturating_sub(self.x_a);
                let c1 = self.m_a.saturating_mul(t.saturating_mul(t));
                let k2 = d.saturating_mul(6).saturating_sub(self.m_a.saturating_mul(2)).saturating_sub(self.m_b);
                let k3 = d.saturating_mul(-4).saturating_add(self.m_a).saturating_add(self.m_b);
                let c2 = k2.saturating_mul(t);
                let den = t.saturating_mul(t).saturating_mul(t).saturating_mul(2);
                let s2 = sigma.saturating_mul(sigma);
                let num = c1
                    .saturating_mul(sigma)
                    .saturating_add(c2.saturating_mul(s2))
                    .saturating_add(k3.saturating_mul(s2.saturating_mul(sigma)));
                // dnum/ds.
                let dnum = c1
                    .saturating_add(c2.saturating_mul(sigma).saturating_mul(2))
                    .saturating_add(k3.saturating_mul(s2).saturating_mul(3));
                let fine = self.x_a.saturating_mul(1 << 8).saturating_add(div_shl(num, den, 8)); // Q16
                let tick = self.tick_u;
                let v = div_shl(dnum.saturating_mul(tick), den, 24); // Q8 per unit -> Q32 per tick
                CyclicOutput {
                    position: sat_i64(round_shr(fine, 16)),
                    position_fine: sat_i64(fine),
                    velocity: Velocity(sat_i64(v.saturating_add(self.velocity_offset))),
                    acceleration: Acceleration(sat_i64(self.accel_ff)),
                    torque: self.torque_offset,
                    status,
                }
            }
            CyclicMode::Velocity => {
                let dy = self.y_b.saturating_sub(self.y_a);
                let v = self.y_a.saturating_add(dy.saturating_mul(sigma).checked_div(t).unwrap_or(0));
                let a = div_shl(dy.saturating_mul(self.tick_u), t, 8); // Q32 per tick per tick -> Q40
                                                                       // Trapezoid rule, exact for the piecewise-linear velocity: Q33 += v_prev + v.
                self.integral = self.integral.saturating_add(self.last_velocity).saturating_add(v);
                self.last_velocity = v;
                CyclicOutput {
                    position: sat_i64(round_shr(self.integral, 33)),
                    position_fine: sat_i64(self.integral >> 17),
                    velocity: Velocity(sat_i64(v)),
                    acceleration: Acceleration(sat_i64(a)),
                    torque: self.torque_offset,
                    status,
                }
            }
            CyclicMode::Torque => {
                let dy = self.y_b.saturating_sub(self.y_a);
                let q = self.y_a.saturating_add(dy.saturating_mul(sigma).checked_div(t).unwrap_or(0));
                CyclicOutput {
                    position: self.output.position,
                    position_fine: self.output.position_fine,
                    velocity: Velocity::ZERO,
                    acceleration: Acceleration::ZERO,
                    torque: sat_i32(round_shr(q, 16)),
                    status,
                }
            }
        }
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
