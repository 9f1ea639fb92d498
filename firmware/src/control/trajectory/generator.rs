//! The profile generator: starts, buffers, blends and stops moves, samples the plan in force once per slow tick.

use super::params::{ProfileParams, ProfileType};
use super::plan::{
    mean_rate, plan_position, plan_stop, plan_velocity, twice_rate_distance, Limits, Plan, PlanKind, Setpoint, State,
};
use super::units::{Acceleration, Velocity};
use super::ONE_Q32;
use crate::control::wide::isqrt;

/// A plan counts as complete this close (Q32 ticks, 2^-20 tick = 0.4 ns) before its analytic end, so that a
/// duration that is a whole number of ticks up to the rounding of the parameters takes exactly that many ticks.
/// The skipped motion is far below 2^-20 of one tick's travel.
const END_TOLERANCE: i128 = 1 << 12;

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
        self.plan = Plan::endless(p, velocity.wide());
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

    /// Quick stop (0x6085, bounded by 0x60C5/0x60C6: [`super::ProfileObjects::quick_stop_deceleration`]): stops with a
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
