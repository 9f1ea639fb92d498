//! The profile generator: starts, buffers, blends and stops moves, samples the plan in force once per slow tick.
//!
//! # When a command takes effect
//! Planning a move costs several thousand instructions on the Cortex-M4 (`insn.profile_plan_max`), more than the
//! slow tick may spend (`insn.slow_tick_max`). So a move or velocity command given before step `n` is not planned
//! inside a step: its origin is the sample of step `n` (the motion in progress goes on for that step), it is
//! planned from that sample by [`ProfileGenerator::prepare`], which the drive runs in tier 2's background step
//! before the next slow tick, and it is in force from step `n + 1`, whose sample is the new plan one tick after
//! its origin. One slow tick (400 us) of latency between the tick that takes a set-point and the first tick that
//! moves towards it; the set-point is still acknowledged in the tick that takes it. A step that finds the command
//! not yet planned (no `prepare` ran, as in a bare host loop) plans it itself, with the same result, so the output
//! never depends on whether `prepare` ran. A buffered move is planned the same way ahead of the end of the move
//! before it. Halt and quick stop act at once (a stop is one ramp: one division).

use super::params::{ProfileParams, ProfileType};
use super::plan::{
    mean_rate, plan_position, plan_stop, plan_velocity, twice_rate_distance, Limits, Plan, PlanKind, Setpoint, State,
};
use super::units::{Acceleration, Velocity};
use super::ONE_Q32;
use crate::wide::isqrt;

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
    /// Change on set-point: the move before it is to pass its target towards this one
    /// ([`CommandKind::Blend`]), given once that move is in force.
    blend: bool,
}

/// What a command asks for, planned from its origin (the state after the step that followed it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum CommandKind {
    /// A position move to `target` (absolute increments).
    Move { target: i64, limits: Limits },
    /// A velocity command: ramp to `velocity` (Q32 inc/tick, already within the limits), then keep it.
    Velocity { velocity: i128, limits: Limits },
    /// The position move in force, to `current`, replanned to pass its target towards the buffered `next`.
    Blend { current: i64, next: i64, next_limits: Limits },
}

/// A command given, waiting to take effect (module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Command {
    kind: CommandKind,
    /// The step after the command was given has run: the generator's state is the command's origin.
    origin_set: bool,
}

/// What the spare plan of [`Plans`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Spare {
    /// Nothing planned ahead.
    Empty,
    /// The plan of the command waiting to take effect.
    Command,
    /// The command waiting was planned and changes nothing (a blend the next move cannot continue from).
    CommandKeeps,
    /// The buffered move, from the end of the plan in force.
    Pending,
}

/// The plan in force and a spare one planned ahead: taking the spare into force flips an index, so a step never
/// copies a plan (several hundred bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Plans {
    a: Plan,
    b: Plan,
    /// `b` is in force, `a` the spare.
    b_in_force: bool,
    spare: Spare,
}

impl Plans {
    fn new(plan: Plan) -> Self {
        Self { a: plan, b: plan, b_in_force: false, spare: Spare::Empty }
    }

    fn in_force(&self) -> &Plan {
        if self.b_in_force {
            &self.b
        } else {
            &self.a
        }
    }

    fn in_force_mut(&mut self) -> &mut Plan {
        if self.b_in_force {
            &mut self.b
        } else {
            &mut self.a
        }
    }

    fn spare_mut(&mut self) -> &mut Plan {
        if self.b_in_force {
            &mut self.a
        } else {
            &mut self.b
        }
    }

    /// Puts the spare plan in force.
    fn take_spare(&mut self) {
        self.b_in_force = !self.b_in_force;
        self.spare = Spare::Empty;
    }
}

/// The trajectory generator of the profile modes: position moves (PPM, homing moves), velocity commands (PVM),
/// halt and quick stop, sampled once per slow tick by [`ProfileGenerator::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProfileGenerator {
    plans: Plans,
    /// Q32 ticks since the origin of the plan in force.
    elapsed: i128,
    /// A move or velocity command given and not yet in force.
    command: Option<Command>,
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
            plans: Plans::new(Plan::rest(p)),
            elapsed: 0,
            command: None,
            pending: None,
            state: State { p, v: 0, a: 0 },
            shape: ProfileType::Trapezoidal,
            started_buffered: false,
        }
    }

    /// Drops any motion and the buffer; at rest at `position` (e.g. entering Operation enabled: demand = actual).
    pub fn reset(&mut self, position: i64) {
        // In place: the plans are several hundred bytes each, and the axis resets the generator every slow tick
        // while the drive function is off.
        let p = q32(position);
        self.plans.in_force_mut().set_rest(p);
        self.plans.spare = Spare::Empty;
        self.elapsed = 0;
        self.command = None;
        self.pending = None;
        self.state = State { p, v: 0, a: 0 };
        self.started_buffered = false;
    }

    /// Drops any motion and the buffer; continues from `position` with `velocity` kept (e.g. taking over from a
    /// cyclic mode before a quick stop, so that the stop ramp starts from the actual motion).
    pub fn reset_moving(&mut self, position: i64, velocity: Velocity) {
        self.reset(position);
        let p = self.state.p;
        self.plans.in_force_mut().set_endless(p, velocity.wide());
        self.state.v = velocity.wide();
    }

    /// Starts or buffers a position move (PPM new set-point, 0x607A).
    ///
    /// `relative` (controlword bit 6): the target is added to the preceding target — the target of the move in
    /// progress or buffered, or after a halt, stop or velocity command the current demand position (NT 0x60F2
    /// value 0). The sum saturates. `change` selects when it takes effect ([`ChangeMode`]). While no position move
    /// is in progress (at rest, after a halt, in a velocity command) every mode starts at once: in force from the
    /// step after the next (module documentation).
    pub fn start_move(
        &mut self,
        target: i64,
        relative: bool,
        params: &ProfileParams,
        change: ChangeMode,
    ) -> Result<MoveAccepted, MoveError> {
        let limits = Limits::from_params(params, params.velocity).ok_or(MoveError::ZeroLimit)?;
        let busy = match self.command.map(|c| c.kind) {
            Some(CommandKind::Move { .. } | CommandKind::Blend { .. }) => true,
            Some(CommandKind::Velocity { .. }) => false,
            None => matches!(self.plan().kind, PlanKind::Position { .. }) && !self.plan_over(),
        };
        let reference = self.target().unwrap_or_else(|| self.setpoint().position);
        if change == ChangeMode::Immediately || !busy {
            let absolute = if relative { reference.saturating_add(target) } else { target };
            self.pending = None;
            self.give(CommandKind::Move { target: absolute, limits });
            return Ok(MoveAccepted::Started);
        }
        if self.pending.is_some() {
            return Err(MoveError::BufferFull);
        }
        let absolute = if relative { reference.saturating_add(target) } else { target };
        let blend = change == ChangeMode::AfterCurrentNoStop;
        self.pending = Some(PendingMove { target: absolute, limits, blend });
        // The blend replans the move in force; a move still waiting as a command is blended once it is in force.
        if blend && self.command.is_none() {
            self.give(CommandKind::Blend { current: reference, next: absolute, next_limits: limits });
        }
        Ok(MoveAccepted::Buffered)
    }

    /// Starts a velocity command (PVM target velocity 0x60FF, or a homing search): ramps to `velocity`, bounded
    /// by `params.max_velocity` (0x607F), with the acceleration when speeding up and the deceleration when slowing
    /// down (through zero when the sign changes), then keeps it. Clears the buffer. In force from the step after
    /// the next (module documentation).
    pub fn set_velocity_target(&mut self, velocity: Velocity, params: &ProfileParams) -> Result<(), MoveError> {
        let limits = Limits::from_params(params, params.max_velocity).ok_or(MoveError::ZeroLimit)?;
        let velocity = velocity.wide().clamp(limits.vmax.saturating_neg(), limits.vmax);
        self.pending = None;
        self.give(CommandKind::Velocity { velocity, limits });
        Ok(())
    }

    /// Halt (controlword bit 8): stops with `deceleration` (PPM/PVM: 0x6084; HMM: 0x609A) and the active profile
    /// shape, then holds the position (rounded to a whole increment). Clears the buffer and a command not yet in
    /// force; resuming after the halt is the caller's (re-issue the move). A deceleration of zero stops within one
    /// tick. Acts in this step.
    pub fn halt(&mut self, deceleration: Acceleration) {
        self.stop(deceleration, self.shape);
    }

    /// Quick stop (0x6085, bounded by 0x60C5/0x60C6: [`super::ProfileObjects::quick_stop_deceleration`]): stops with a
    /// linear ramp, the shortest stop for the deceleration, whatever the profile type, then holds the position.
    /// Clears the buffer and a command not yet in force. A deceleration of zero stops within one tick. Acts in this
    /// step.
    pub fn quick_stop(&mut self, deceleration: Acceleration) {
        self.stop(deceleration, ProfileType::Trapezoidal);
    }

    fn stop(&mut self, deceleration: Acceleration, shape: ProfileType) {
        let peak = match deceleration.wide().saturating_abs() {
            0 => Acceleration::MAX.wide(),
            d => d,
        };
        self.command = None;
        self.pending = None;
        self.plans.spare = Spare::Empty;
        let (p, v) = (self.state.p, self.state.v);
        plan_stop(self.plans.in_force_mut(), p, v, mean_rate(peak, shape), shape);
        self.elapsed = 0;
    }

    /// Gives a command; it replaces one not yet in force, and what was planned ahead no longer applies (the
    /// buffered move's plan included: the command changes the plan it would follow, or drops it).
    fn give(&mut self, kind: CommandKind) {
        self.command = Some(Command { kind, origin_set: false });
        self.plans.spare = Spare::Empty;
    }

    /// The plan in force.
    fn plan(&self) -> &Plan {
        self.plans.in_force()
    }

    /// Plans ahead what the next step needs, at most one plan per call: a command whose origin is set, else the
    /// buffered move (from the end of the plan in force). The drive calls it between slow ticks, outside the
    /// slow tick's budget; the samples are the same whether it runs or not (module documentation).
    pub fn prepare(&mut self) {
        if self.plans.spare != Spare::Empty {
            return;
        }
        match (self.command, self.pending) {
            (Some(command), _) if command.origin_set => self.plan_command(command.kind),
            (None, Some(next)) => self.plan_pending(next),
            _ => {}
        }
    }

    /// Plans the buffered move from the exact end state of the plan in force into the spare plan.
    fn plan_pending(&mut self, next: PendingMove) {
        let (p, v) = (self.plan().end_position, self.plan().end_velocity);
        plan_position(self.plans.spare_mut(), p, v, q32(next.target), next.target, 0, next.limits);
        self.plans.spare = Spare::Pending;
    }

    /// Plans a command from the present state into the spare plan.
    fn plan_command(&mut self, kind: CommandKind) {
        let (p, v) = (self.state.p, self.state.v);
        let spare = self.plans.spare_mut();
        match kind {
            CommandKind::Move { target, limits } => plan_position(spare, p, v, q32(target), target, 0, limits),
            CommandKind::Velocity { velocity, limits } => plan_velocity(spare, p, v, velocity, limits),
            CommandKind::Blend { current, next, next_limits } => {
                let Some((w, lim)) = self.blend_velocity(current, next, next_limits) else {
                    self.plans.spare = Spare::CommandKeeps;
                    return;
                };
                plan_position(self.plans.spare_mut(), p, v, q32(current), current, w, lim);
            }
        }
        self.plans.spare = Spare::Command;
    }

    /// The velocity (signed) and limits with which the move in force is replanned so that it passes its target
    /// (`current`) into the next move (`next`): the lower of both profile velocities, and no more than the next
    /// move can stop from within its own distance. `None` (keep the plan) when the next move goes the other way.
    fn blend_velocity(&self, current: i64, next: i64, next_limits: Limits) -> Option<(i128, Limits)> {
        let lim = self.plan().limits?;
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
            return None;
        }
        let stoppable = isqrt(twice_rate_distance(next_limits.dec, d_next.saturating_abs()));
        // Margin of 2^-16 + 1 LSB so that rounding never turns the continuation into a stop-and-reverse.
        let stoppable = stoppable.saturating_sub(stoppable >> 16).saturating_sub(1).max(0);
        let w = lim.vmax.min(next_limits.vmax).min(stoppable);
        if w <= 0 {
            return None;
        }
        Some((w.saturating_mul(dir), lim))
    }

    /// Puts a command whose origin is set in force (planning it now if [`Self::prepare`] has not).
    fn take_command(&mut self, command: Command) {
        if !matches!(self.plans.spare, Spare::Command | Spare::CommandKeeps) {
            self.plan_command(command.kind);
        }
        if self.plans.spare == Spare::Command {
            self.plans.take_spare();
            self.elapsed = 0;
            if let Some(limits) = self.plan().limits {
                self.shape = limits.shape;
            }
        }
        self.plans.spare = Spare::Empty;
        // A change on set-point buffered while its move was still a command: blend now that the move is in force.
        // Given inside this step, before its sample, which is therefore the blend's origin.
        if let (CommandKind::Move { target, .. }, Some(next)) = (command.kind, self.pending) {
            if next.blend {
                let kind = CommandKind::Blend { current: target, next: next.target, next_limits: next.limits };
                self.command = Some(Command { kind, origin_set: true });
            }
        }
    }

    /// Advances one slow tick and returns the new sample. Puts a command given before the previous step in force,
    /// starts the buffered move when the current one ends.
    pub fn step(&mut self) -> Setpoint {
        if let Some(command) = self.command.take() {
            if command.origin_set {
                self.take_command(command);
            } else {
                // This step's sample is the command's origin; it takes effect in the next step.
                self.command = Some(Command { origin_set: true, ..command });
            }
        }
        self.elapsed = self.elapsed.saturating_add(ONE_Q32);
        // A buffered move follows the move it was buffered behind, which may still wait as a command.
        let behind_command = matches!(self.command, Some(Command { kind: CommandKind::Move { .. }, .. }));
        if self.plan_over() && !behind_command {
            if let Some(next) = self.pending.take() {
                // A blend of the move that just ended comes too late: the buffered move continues from its end.
                self.command = None;
                // Continue from the exact end state; the time past the end carries into the new plan.
                let over = self.elapsed.saturating_sub(self.plan().duration);
                if self.plans.spare != Spare::Pending {
                    self.plan_pending(next);
                }
                self.plans.take_spare();
                self.shape = next.limits.shape;
                self.elapsed = over;
                self.started_buffered = true;
            }
        }
        if self.plan_over() {
            let plan = self.plans.in_force_mut();
            if plan.end_velocity == 0 {
                self.elapsed = plan.duration;
            } else {
                // Endless velocity: fold whole ticks into the end state (exact: Q32 velocity times an integer),
                // so that the products stay small however long it runs.
                self.elapsed = self.elapsed.max(plan.duration);
                let whole = self.elapsed.saturating_sub(plan.duration) >> 32;
                plan.end_position = plan.end_position.saturating_add(plan.end_velocity.saturating_mul(whole));
                plan.duration = plan.duration.saturating_add(whole.saturating_mul(ONE_Q32));
            }
        }
        self.state = self.plan().eval(self.elapsed);
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
        self.command.is_none() && self.plan_over() && self.pending.is_none()
    }

    /// The current plan has reached its end state (within [`END_TOLERANCE`]).
    fn plan_over(&self) -> bool {
        self.elapsed.saturating_add(END_TOLERANCE) >= self.plan().duration
    }

    /// The target of the position move in progress (or finished, or given and not yet in force), `None` for a stop
    /// or a velocity command.
    #[must_use]
    pub fn target(&self) -> Option<i64> {
        match self.command.map(|c| c.kind) {
            Some(CommandKind::Move { target, .. }) => return Some(target),
            Some(CommandKind::Velocity { .. }) => return None,
            Some(CommandKind::Blend { .. }) | None => {}
        }
        match self.plan().kind {
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
    let mut plan = Plan::rest(0);
    plan_position(&mut plan, q32(start), start_velocity.wide(), q32(target), target, 0, limits);
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
    let mut plan = Plan::rest(0);
    plan_velocity(&mut plan, 0, start_velocity.wide(), target, limits);
    Some(ceil_ticks(plan.duration))
}

fn q32(inc: i64) -> i128 {
    i128::from(inc).saturating_mul(ONE_Q32)
}

fn ceil_ticks(t: i128) -> u64 {
    let t = t.saturating_sub(END_TOLERANCE).max(0);
    u64::try_from(t.saturating_add(ONE_Q32 - 1) >> 32).unwrap_or(u64::MAX)
}
