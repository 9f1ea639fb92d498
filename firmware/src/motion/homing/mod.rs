//! Homing mode (HMM, 0x6060 = 6): the sequencer of the 36 methods of 0x60E3 (`shared/spec/cia402-device-control.md`
//! §3; the method catalogue and its sources are in [`methods`]).
//!
//! A sans-IO state machine stepped once per slow tick with the axis feedback; every motion goes through the lent
//! [`ProfileGenerator`] (position control throughout: the demand is always [`LoopDemand::Position`]).
//!
//! # Controlword and statusword (IDX Tables 3-29/3-33 L816-857, E3 Tables 5-31/5-34 L1809-1846, GT L1242-1277)
//! - Bit 4 rising edge (with bit 8 = 0): start homing from scratch with the method of 0x6098, whatever state the
//!   procedure is in. A bit 4 already set when HMM is entered does not start (a rising edge is needed); a rising
//!   edge while bit 8 is set is ignored (bit 8 = 1 "stop axle", bit 8 = 0 "execute instruction of bit 4").
//! - Bit 4 falling while homing is in progress: stop with 0x609A; "interrupted" (NT p.62 L251: homing runs "until
//!   either the reference position is reached or bit 4 is reset to 0").
//! - Bit 8 (halt) while in progress: stop with the halt deceleration (0x605D); the procedure is abandoned, and only
//!   a new rising edge of bit 4 starts it again (from scratch). Releasing bit 8 alone does not resume.
//! - Bits 13/12/10: in progress 0/0/0; not started, interrupted or halted 0/0/1 once the axis stands (0/0/0 while it
//!   still brakes); attained 0/1/1 (the rereference is issued when the demand stands on the home point, so the
//!   home point is reached when homing is attained); error 1/0/1 once the axis stands (1/0/0 while it brakes: GT
//!   L1266-1277 "error, velocity ≠ 0"). "Stands" = the generator has finished its stop at zero velocity.
//!
//! # Sequences
//! Speeds: 0x6099:01 (switch search) to find a switch or end stop and for the home offset move, 0x6099:02 (zero
//! search) to approach and leave the reference edge and to find the index (IDX Table 3-27 L807: "the faster speed is
//! used to find the home switch and for the offset move, the slower speed is used to find the index pulse"). Every
//! ramp uses 0x609A (acceleration and deceleration), with a trapezoidal profile.
//!
//! - **Switch-edge methods (1-14, 17-30).** The reference is the edge `E` of the switch crossed in the approach
//!   direction `F` ([`methods::Method::approach`]). (1) *Search* at switch-search speed toward `E`: when the switch
//!   state tells on which side of `E` the axis is (limit and half-axis switches, or an active band switch), straight
//!   toward it; for a band switch that is inactive, in the method's initial direction, reversing once at the limit
//!   switch ahead (GT L1140-1166). A band switch entered at its other edge is crossed on toward `E`. (2) When `E` is
//!   crossed at search speed against `F`, the axis brakes beyond it and *approaches* `E` at zero-search speed in `F`;
//!   when it is crossed in `F` (the axis started on the far side), the axis brakes, *leaves* back across `E` at
//!   zero-search speed, and then approaches. So the reference crossing always happens at zero-search speed in `F`,
//!   and its latched position ([`SwitchEdges`]) — not where the axis stopped — is the reference of the edge
//!   methods. (3) Index methods continue in `F` at zero-search speed to the first index pulse beyond the edge: its
//!   latched position is the reference.
//! - **Index methods 33 / 34**: zero-search speed negative / positive to the next index pulse (E3 L1952-1971).
//! - **Current-threshold methods -1..-4** (E3 L1979-2035, IDX L912-930): switch-search speed toward the end stop until
//!   the averaged current 0x30D1:01 exceeds 0x30B2 in magnitude. The current is compared only once the search
//!   velocity has been held for 32 slow ticks (12.8 ms, four time constants of the 50 Hz average), so that the
//!   current of the acceleration ramp, still in the average when the ramp ends, is not taken for the stop. The
//!   demand is then set back to the actual position and the axis clears its loops' integral (the motor stops
//!   pushing: [`HomingStep::reset_loops`]), and that position is the reference; -1/-2 continue away from the stop
//!   at zero-search speed to the next index pulse, whose position is the reference.
//! - **35 / 37**: the actual position is the home point at once, no motion (E3 L1973-1977, IDX L905-910).
//!
//! # Home point and rereference
//! The home point is the reference plus the home offset move distance 0x30B1 (signed, in position coordinates).
//! *Design decision for -1..-4*: IDX defines 0x30B1 as "the distance to move away from a detected position" (L808),
//! and from an end stop only the way away from it is open, so there the magnitude of 0x30B1 is moved away from the
//! stop (negative for -1/-3, positive for -2/-4) whatever its sign; a zero offset is allowed (the home point is the
//! stop, or the index, itself, where the axis then rests without pushing). The axis moves to the home point at
//! switch-search speed; when the demand stands on it, the step returns [`Rereference`] `{ from: home point, to:
//! 0x30B0 + 0x607C }` and homing is attained (maxon: "This point will be used as reference for all further moves and
//! is set to Home Position", E3 L1855-1858).
//!
//! # Errors (statusword bit 13; the cause in [`Homing::error`])
//! An unsupported method; a zero speed or acceleration; a limit switch reached where the method cannot reverse
//! (any limit other than the referenced one in 1, 2, 17, 18, any limit in 3-6, 19-22, 33, 34, -1..-4, a limit
//! during the approach phases); both limit switches (band methods 7-14, 23-30); the switch edge, index pulse or
//! current threshold not found within 0x30B3 of demand travel. Travel is the path length of the demand since the
//! search for that signal began (the homing start for the switch or end stop, the reference edge for the index; a
//! reversal at a limit switch does not restart it), so a blocked axis is caught as well. The axis then stops with
//! 0x609A and holds. Limit switches are not watched during the home offset move (an offset of 0 on a limit switch
//! edge ends on the switch); the axis's own limit-switch supervision stays in charge there.

pub mod methods;
#[cfg(test)]
mod tests;

pub use methods::SUPPORTED_METHODS;
use methods::{Direction, Layout, Method, Reference, Switch};

use super::{AxisFeedback, LoopDemand, ModeStatus, ModeStep};
use crate::cia402::controlword::Controlword;
use crate::control::trajectory::{
    Acceleration, ChangeMode, ProfileGenerator, ProfileParams, ProfileType, Setpoint, Velocity,
};
use crate::sensors::latch::SwitchEdges;

/// Slow ticks the search velocity of an end-stop search is held before the averaged current 0x30D1:01 is
/// compared with 0x30B2: four time constants of its 50 Hz low-pass (8 ticks, `drive::Drive`), after which the
/// current of the acceleration ramp has decayed to e^-4 = 2 % in the average (12.8 ms).
const AVERAGE_SETTLE_TICKS: u16 = 32;

/// The inputs of one HMM step, in internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HomingInput {
    /// 0x6040 (bit 4 start homing, bit 8 halt).
    pub controlword: Controlword,
    /// 0x6098 homing method.
    pub method: i8,
    /// 0x6099:01 speed for switch search (magnitude).
    pub switch_search_speed: Velocity,
    /// 0x6099:02 speed for zero search (magnitude).
    pub zero_search_speed: Velocity,
    /// 0x609A homing acceleration (also the deceleration).
    pub acceleration: Acceleration,
    /// 0x30B1 home offset move distance, increments.
    pub offset_move_distance: i32,
    /// 0x30B0 + 0x607C: the position value of the home point, increments.
    pub home_position: i32,
    /// 0x30B2 current threshold for methods -1..-4, mA.
    pub current_threshold_ma: u32,
    /// 0x30B3 homing search distance limit, increments; `None` = no limit.
    pub search_distance_limit: Option<u32>,
    /// Deceleration of a halt (0x605D: 0x609A or 0x6085).
    pub halt_deceleration: Acceleration,
}

/// A change of the position reference: the position `from` (current coordinates) is `to` from the next tick on.
/// The caller shifts the position actual value, the generator and the loops by `to - from` before the next step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Rereference {
    /// A position in the coordinates used until now.
    pub from: i32,
    /// Its value in the new coordinates.
    pub to: i32,
}

/// One HMM step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HomingStep {
    /// Demand and statusword bits (10 target reached, 12 homing attained, 13 homing error).
    pub mode: ModeStep,
    /// Set when the home point is defined in this step.
    pub rereference: Option<Rereference>,
    /// Set when an end stop was found in this step: the demand went back to the actual position, and the caller
    /// clears the loops' integral, wound up pushing against the stop, so that the motor stops pushing.
    pub reset_loops: bool,
}

/// Why homing failed (statusword bit 13; E3 L1842: "for error cause read error code").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum HomingError {
    /// 0x6098 holds a method this drive does not implement (not in [`SUPPORTED_METHODS`]).
    UnsupportedMethod,
    /// A homing speed or the homing acceleration is zero: no motion could end.
    ZeroSpeedOrAcceleration,
    /// The reference switch edge was not found within the search distance limit.
    SwitchNotFound,
    /// The index pulse was not found within the search distance limit.
    IndexNotFound,
    /// The current threshold was not reached within the search distance limit.
    EndStopNotFound,
    /// A limit switch was reached where the method cannot reverse.
    LimitSwitch,
    /// Both limit switches were reached (band methods 7-14, 23-30).
    BothLimitSwitches,
}

/// Where the procedure is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Phase {
    /// Not started, interrupted (bit 4 fell) or halted: stopping or standing.
    #[default]
    Idle,
    /// Switch-search speed in `dir` toward the reference switch edge.
    Search { dir: Direction },
    /// Zero-search speed against the approach direction, back across the edge.
    Leave,
    /// Zero-search speed in the approach direction, to cross the edge.
    Approach,
    /// Switch-search speed toward the end stop.
    EndStop { toward: Direction },
    /// Zero-search speed in the approach direction to the next index pulse.
    Index,
    /// Moving to the home point (current coordinates).
    OffsetMove { home_point: i32 },
    /// Homing attained.
    Attained,
    /// Homing error, stopping or standing.
    Error(HomingError),
}

/// The latch counts seen at the previous step (a different count now = new edges).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Seen {
    negative_limit: (u16, u16),
    positive_limit: (u16, u16),
    home_switch: (u16, u16),
    index: u16,
}

/// The homing state.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Homing {
    phase: Phase,
    /// The method of the procedure in progress (latched at its start).
    method: Option<Method>,
    /// Controlword bit 4 at the previous step.
    bit4: bool,
    /// The position is referenced (statusword bit 15).
    referenced: bool,
    /// Stop a moving generator on the first step after [`Homing::enter`].
    stop_on_entry: bool,
    /// The band search has reversed at a limit switch.
    reversed: bool,
    /// Demand path length of the current search, increments.
    travel: u64,
    /// Steps the generator has held the search velocity of an end-stop search.
    cruise_ticks: u16,
    /// The end stop was found in this step ([`HomingStep::reset_loops`]).
    reset_loops: bool,
    /// Demand position at the previous step (generator coordinates).
    last_demand: i64,
    /// Position actual value at the previous step.
    last_position: i32,
    seen: Seen,
}

impl Homing {
    /// Not homed.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            phase: Phase::Idle,
            method: None,
            bit4: false,
            referenced: false,
            stop_on_entry: false,
            reversed: false,
            travel: 0,
            cruise_ticks: 0,
            reset_loops: false,
            last_demand: 0,
            last_position: 0,
            seen: Seen { negative_limit: (0, 0), positive_limit: (0, 0), home_switch: (0, 0), index: 0 },
        }
    }

    /// Called when HMM becomes the followed mode; `generator` already stands at the demand the axis continues from.
    ///
    /// Clears the procedure (not started: bits 13/12 = 0) and remembers the level of bit 4, so that only a rising
    /// edge starts homing. The position reference ([`Self::attained`], bit 15) is kept: the coordinates have not
    /// changed. A generator still moving is stopped with 0x609A on the first step.
    pub fn enter(&mut self, controlword: Controlword, generator: &mut ProfileGenerator, feedback: &AxisFeedback) {
        *self = Self {
            referenced: self.referenced,
            bit4: controlword.operation_mode_bits().bit4,
            stop_on_entry: true,
            last_demand: generator.setpoint().position,
            ..Self::new()
        };
        self.remember(feedback);
    }

    /// The position is referenced to the home position: the latest homing was attained and no homing has been
    /// started since (statusword bit 15 "position referenced to home position", IDX Table 3-32; kept after HMM is
    /// left).
    #[must_use]
    pub const fn attained(&self) -> bool {
        self.referenced
    }

    /// Homing is in progress (a search or the offset move): statusword 13/12/10 = 0/0/0. Software position limits
    /// are inactive meanwhile (IDX L5971).
    #[must_use]
    pub const fn in_progress(&self) -> bool {
        matches!(
            self.phase,
            Phase::Search { .. }
                | Phase::Leave
                | Phase::Approach
                | Phase::EndStop { .. }
                | Phase::Index
                | Phase::OffsetMove { .. }
        )
    }

    /// The cause of a homing error (statusword bit 13), `None` when there is none.
    #[must_use]
    pub const fn error(&self) -> Option<HomingError> {
        match self.phase {
            Phase::Error(e) => Some(e),
            _ => None,
        }
    }

    /// One slow tick.
    pub fn step(
        &mut self,
        input: &HomingInput,
        generator: &mut ProfileGenerator,
        feedback: &AxisFeedback,
    ) -> HomingStep {
        let bit4 = input.controlword.operation_mode_bits().bit4;
        let halt = input.controlword.halt();
        let rising = bit4 && !self.bit4;
        let falling = !bit4 && self.bit4;
        self.bit4 = bit4;
        let motion = self.motion(feedback, generator);

        if core::mem::take(&mut self.stop_on_entry) {
            stop(generator, input.acceleration);
        }
        if self.in_progress() {
            if halt {
                generator.halt(input.halt_deceleration);
                self.phase = Phase::Idle;
            } else if falling {
                generator.halt(input.acceleration);
                self.phase = Phase::Idle;
            }
        }

        let mut rereference = None;
        if rising && !halt {
            rereference = self.start(input, generator, feedback);
        } else {
            self.search(input, generator, feedback, motion);
        }

        let setpoint = generator.step();
        let moved = setpoint.position.wrapping_sub(self.last_demand).unsigned_abs();
        self.travel = self.travel.saturating_add(moved);
        self.last_demand = setpoint.position;
        if let Phase::OffsetMove { home_point } = self.phase {
            if generator.is_done() {
                rereference = Some(Rereference { from: home_point, to: input.home_position });
                self.referenced = true;
                self.phase = Phase::Attained;
            }
        }
        self.remember(feedback);
        if let Some(r) = rereference {
            // Keep the remembered positions in the coordinates of the next step.
            let shift = r.to.wrapping_sub(r.from);
            self.last_position = self.last_position.wrapping_add(shift);
            self.last_demand = self.last_demand.wrapping_add(i64::from(shift));
        }

        let standing = at_rest(generator);
        let status = match self.phase {
            Phase::Idle => ModeStatus { target_reached: standing, bit12: false, bit13: false },
            Phase::Attained => ModeStatus { target_reached: standing, bit12: true, bit13: false },
            Phase::Error(_) => ModeStatus { target_reached: standing, bit12: false, bit13: true },
            _ => ModeStatus::default(),
        };
        let reset_loops = core::mem::take(&mut self.reset_loops);
        HomingStep { mode: ModeStep { demand: LoopDemand::Position(setpoint), status }, rereference, reset_loops }
    }

    /// Starts the procedure (bit 4 rising edge).
    fn start(
        &mut self,
        input: &HomingInput,
        generator: &mut ProfileGenerator,
        feedback: &AxisFeedback,
    ) -> Option<Rereference> {
        self.referenced = false;
        self.reversed = false;
        self.travel = 0;
        self.method = methods::method(input.method);
        let Some(m) = self.method else {
            self.fail(HomingError::UnsupportedMethod, input, generator);
            return None;
        };
        match m.reference {
            Reference::ActualPosition => {
                stop(generator, input.acceleration);
                self.referenced = true;
                self.phase = Phase::Attained;
                return Some(Rereference { from: feedback.position, to: input.home_position });
            }
            Reference::Index => self.begin(Phase::Index, m.approach, input.zero_search_speed, input, generator),
            Reference::EndStop { toward } => {
                self.begin(Phase::EndStop { toward }, toward, input.switch_search_speed, input, generator);
            }
            Reference::SwitchEdge { switch, layout, active_side } => {
                let active = switch_edges(feedback, switch).active;
                let dir = match layout {
                    Layout::Band { initial } if !active => initial,
                    // The switch state tells the side of `E`: the "before" side (from which moving in `F` crosses
                    // it) is the active one when the switch is active against `F`.
                    _ if active == (active_side == m.approach.reverse()) => m.approach,
                    _ => m.approach.reverse(),
                };
                self.begin(Phase::Search { dir }, dir, input.switch_search_speed, input, generator);
            }
        }
        None
    }

    /// The search logic of one step (nothing outside a search).
    fn search(
        &mut self,
        input: &HomingInput,
        generator: &mut ProfileGenerator,
        feedback: &AxisFeedback,
        motion: Option<Direction>,
    ) {
        let Some(m) = self.method else { return };
        let (f, slow, fast) = (m.approach, input.zero_search_speed, input.switch_search_speed);
        let signal = match m.reference {
            Reference::SwitchEdge { switch, .. } => Some(switch),
            _ => None,
        };
        // Per phase: the direction of the commanded motion, and the errors for a limit switch ahead and for the
        // distance limit.
        let (heading, limit_error, not_found) = match self.phase {
            Phase::Search { dir } => {
                if let Some((crossed, _)) = self.edge_crossing(feedback, m, motion, None) {
                    if crossed == f {
                        self.begin(Phase::Leave, f.reverse(), slow, input, generator);
                    } else {
                        self.begin(Phase::Approach, f, slow, input, generator);
                    }
                    return;
                }
                let band = matches!(m.reference, Reference::SwitchEdge { layout: Layout::Band { .. }, .. });
                if band && !self.reversed && limit_ahead(feedback, dir, signal) {
                    // Reverse once at the limit switch; the travel keeps counting.
                    self.reversed = true;
                    let travel = self.travel;
                    self.begin(Phase::Search { dir: dir.reverse() }, dir.reverse(), fast, input, generator);
                    self.travel = travel;
                    return;
                }
                let limit_error = if self.reversed { HomingError::BothLimitSwitches } else { HomingError::LimitSwitch };
                (dir, limit_error, HomingError::SwitchNotFound)
            }
            Phase::Leave => {
                if self.edge_crossing(feedback, m, motion, Some(f.reverse())).is_some() {
                    self.begin(Phase::Approach, f, slow, input, generator);
                    return;
                }
                (f.reverse(), HomingError::LimitSwitch, HomingError::SwitchNotFound)
            }
            Phase::Approach => {
                if let Some((_, edge)) = self.edge_crossing(feedback, m, motion, Some(f)) {
                    if !m.index {
                        self.begin_offset_move(edge, m, input, generator);
                    } else if feedback.index.count != self.seen.index && beyond(feedback.index.position, edge, f) {
                        // The index pulse came in the same tick, after the edge.
                        self.begin_offset_move(feedback.index.position, m, input, generator);
                    } else {
                        self.phase = Phase::Index;
                        self.travel = 0;
                    }
                    return;
                }
                (f, HomingError::LimitSwitch, HomingError::SwitchNotFound)
            }
            Phase::Index => {
                if feedback.index.count != self.seen.index {
                    self.begin_offset_move(feedback.index.position, m, input, generator);
                    return;
                }
                (f, HomingError::LimitSwitch, HomingError::IndexNotFound)
            }
            Phase::EndStop { toward } => {
                // Only once the search velocity has been held for AVERAGE_SETTLE_TICKS: the acceleration ramp's
                // current is not the stop, and the average still carries it when the ramp ends.
                self.cruise_ticks = if generator.is_done() { self.cruise_ticks.saturating_add(1) } else { 0 };
                let cruising = self.cruise_ticks >= AVERAGE_SETTLE_TICKS;
                if cruising && feedback.current_average_ma.unsigned_abs() > input.current_threshold_ma {
                    let stop_position = feedback.position;
                    // Stop pushing: the demand goes back to where the axis is blocked, the loops' integral to 0.
                    generator.reset(demand_of(generator.setpoint(), stop_position));
                    self.reset_loops = true;
                    if m.index {
                        self.begin(Phase::Index, f, slow, input, generator);
                    } else {
                        self.begin_offset_move(stop_position, m, input, generator);
                    }
                    return;
                }
                (toward, HomingError::LimitSwitch, HomingError::EndStopNotFound)
            }
            Phase::Idle | Phase::OffsetMove { .. } | Phase::Attained | Phase::Error(_) => return,
        };
        if limit_ahead(feedback, heading, signal) {
            self.fail(limit_error, input, generator);
        } else if input.search_distance_limit.is_some_and(|limit| self.travel > u64::from(limit)) {
            self.fail(not_found, input, generator);
        }
    }

    /// Enters `phase` with a velocity command of `speed` in `dir`; a new search: the travel restarts.
    fn begin(
        &mut self,
        phase: Phase,
        dir: Direction,
        speed: Velocity,
        input: &HomingInput,
        generator: &mut ProfileGenerator,
    ) {
        let magnitude = speed.0.saturating_abs();
        let velocity = Velocity(match dir {
            Direction::Positive => magnitude,
            Direction::Negative => magnitude.wrapping_neg(),
        });
        self.travel = 0;
        self.cruise_ticks = 0;
        match generator.set_velocity_target(velocity, &params(speed, input.acceleration)) {
            Ok(()) => self.phase = phase,
            Err(_) => self.fail(HomingError::ZeroSpeedOrAcceleration, input, generator),
        }
    }

    /// The reference is found at `reference` (current coordinates): move to the home point.
    fn begin_offset_move(&mut self, reference: i32, m: Method, input: &HomingInput, generator: &mut ProfileGenerator) {
        let offset = match m.reference {
            // Away from the end stop (the approach direction), whatever the sign (design decision, module docs).
            Reference::EndStop { .. } => {
                let magnitude = i32::try_from(input.offset_move_distance.unsigned_abs()).unwrap_or(i32::MAX);
                match m.approach {
                    Direction::Positive => magnitude,
                    Direction::Negative => magnitude.wrapping_neg(),
                }
            }
            _ => input.offset_move_distance,
        };
        // Positions wrap like 0x6064.
        let home_point = reference.wrapping_add(offset);
        let target = demand_of(generator.setpoint(), home_point);
        let moved = generator.start_move(
            target,
            false,
            &params(input.switch_search_speed, input.acceleration),
            ChangeMode::Immediately,
        );
        match moved {
            Ok(_) => self.phase = Phase::OffsetMove { home_point },
            Err(_) => self.fail(HomingError::ZeroSpeedOrAcceleration, input, generator),
        }
    }

    fn fail(&mut self, error: HomingError, input: &HomingInput, generator: &mut ProfileGenerator) {
        stop(generator, input.acceleration);
        self.phase = Phase::Error(error);
    }

    /// A new crossing of the method's reference edge `E` (in direction `want`, or either): the crossing direction
    /// and the latched position.
    ///
    /// For a limit or half-axis switch (one edge) the kind of transition gives the direction: activation = moving
    /// toward the active side. A band switch has two edges with the same kinds of transitions, so the direction of
    /// motion tells which edge was crossed: activation moving `d` = the edge active on its `d` side.
    fn edge_crossing(
        &self,
        feedback: &AxisFeedback,
        m: Method,
        motion: Option<Direction>,
        want: Option<Direction>,
    ) -> Option<(Direction, i32)> {
        let Reference::SwitchEdge { switch, layout, active_side } = m.reference else { return None };
        let edges = switch_edges(feedback, switch);
        let (seen_activated, seen_released) = match switch {
            Switch::NegativeLimit => self.seen.negative_limit,
            Switch::PositiveLimit => self.seen.positive_limit,
            Switch::Home => self.seen.home_switch,
        };
        let activated = (true, edges.activated, seen_activated);
        let released = (false, edges.released, seen_released);
        // Both kinds in one tick (bounce): the one that left the switch in its present state counts.
        let ordered = if edges.active { [released, activated] } else { [activated, released] };
        let mut found = None;
        for (activation, latch, seen) in ordered {
            if latch.count == seen {
                continue;
            }
            let crossed = match layout {
                Layout::Band { .. } => {
                    let Some(d) = motion else { continue };
                    let edge_side = if activation { d } else { d.reverse() };
                    if edge_side != active_side {
                        continue;
                    }
                    d
                }
                Layout::Limit | Layout::HalfAxis if activation => active_side,
                Layout::Limit | Layout::HalfAxis => active_side.reverse(),
            };
            if want.is_none_or(|w| w == crossed) {
                found = Some((crossed, latch.position));
            }
        }
        found
    }

    /// The direction the axis moved since the previous step (the demand's when the position did not change).
    fn motion(&self, feedback: &AxisFeedback, generator: &ProfileGenerator) -> Option<Direction> {
        let moved = feedback.position.wrapping_sub(self.last_position);
        let velocity = generator.setpoint().velocity.0;
        if moved > 0 || (moved == 0 && velocity > 0) {
            Some(Direction::Positive)
        } else if moved < 0 || velocity < 0 {
            Some(Direction::Negative)
        } else {
            None
        }
    }

    fn remember(&mut self, feedback: &AxisFeedback) {
        let counts = |s: &SwitchEdges| (s.activated.count, s.released.count);
        self.seen = Seen {
            negative_limit: counts(&feedback.negative_limit),
            positive_limit: counts(&feedback.positive_limit),
            home_switch: counts(&feedback.home_switch),
            index: feedback.index.count,
        };
        self.last_position = feedback.position;
    }
}

/// The profile of a homing motion at `speed` with 0x609A.
fn params(speed: Velocity, acceleration: Acceleration) -> ProfileParams {
    let speed = Velocity(speed.0.saturating_abs());
    ProfileParams {
        profile_type: ProfileType::Trapezoidal,
        velocity: speed,
        max_velocity: speed,
        acceleration,
        deceleration: acceleration,
    }
}

fn switch_edges(feedback: &AxisFeedback, switch: Switch) -> SwitchEdges {
    match switch {
        Switch::NegativeLimit => feedback.negative_limit,
        Switch::PositiveLimit => feedback.positive_limit,
        Switch::Home => feedback.home_switch,
    }
}

/// The limit switch in direction `dir` is active (and is not the method's own reference switch).
fn limit_ahead(feedback: &AxisFeedback, dir: Direction, signal: Option<Switch>) -> bool {
    match dir {
        Direction::Negative => feedback.negative_limit.active && signal != Some(Switch::NegativeLimit),
        Direction::Positive => feedback.positive_limit.active && signal != Some(Switch::PositiveLimit),
    }
}

/// `position` lies strictly beyond `edge` in direction `dir` (wrapping difference).
fn beyond(position: i32, edge: i32, dir: Direction) -> bool {
    let d = position.wrapping_sub(edge);
    match dir {
        Direction::Positive => d > 0,
        Direction::Negative => d < 0,
    }
}

/// A position of the axis (i32, wrapping like 0x6064) as a generator position: the one nearest the demand.
fn demand_of(setpoint: Setpoint, position: i32) -> i64 {
    setpoint.position.wrapping_add(i64::from(position.wrapping_sub(setpoint.position_i32())))
}

/// The generator has finished a stop or move and stands (velocity 0).
fn at_rest(generator: &ProfileGenerator) -> bool {
    generator.is_done() && generator.setpoint().velocity == Velocity::ZERO
}

/// Stops a generator that is not standing.
fn stop(generator: &mut ProfileGenerator, deceleration: Acceleration) {
    if !at_rest(generator) {
        generator.halt(deceleration);
    }
}
