//! The CiA 402 power state machine: states, transitions 0..16 and the actions of each.
//!
//! Sans-IO (ARCHITECTURE.md convention 1): [`StateMachine::step`] is called once per tier-2 period (2.5 kHz) with
//! the [`Inputs`] of that period and the time, and returns [`Outputs`]: the state, the transition completed in
//! this step (its CiA 402 number), the transition in progress, the power-stage and motion requests, the brake
//! request, the calibration start and the statusword.
//!
//! Transitions and actions (IDX Table 2-6 L416-449, E3 L434-468, Gamma L827-850; digest
//! `shared/spec/cia402-device-control.md` §1.2):
//!
//! | # | From -> To | Event | Action here |
//! |---|---|---|---|
//! | 0 | reset -> NRTSO | [`StateMachine::new`], [`StateMachine::reset`] | everything off |
//! | 1 | NRTSO -> SOD | [`Inputs::initialized`] | — |
//! | 2 | SOD -> RTSO | «Shutdown» | — |
//! | 3 | RTSO -> SO | «Switch on» or «Switch on & Enable» | power section on, [`Outputs::start_current_calibration`]; completes when [`Inputs::calibration_done`] |
//! | 4 | SO -> OE | «Enable operation» | controllers enabled, brake released (set-points held for the brake release delay) |
//! | 5 | OE -> SO | «Disable operation» | stop per 0x605C, then controllers disabled |
//! | 6 | SO -> RTSO | «Shutdown» | power section off |
//! | 7 | RTSO -> SOD | «Quick stop» or «Disable voltage» | — |
//! | 8 | OE -> RTSO | «Shutdown» | stop per 0x605B, then drive function and power section off |
//! | 9 | OE -> SOD | «Disable voltage» | stop per 0x605B (IDX L440), then off |
//! | 10 | SO -> SOD | «Quick stop» or «Disable voltage» | power section off |
//! | 11 | OE -> QSA | «Quick stop» | stop per 0x605A |
//! | 12 | QSA -> SOD | «Disable voltage», or the stop of 0x605A = 0..4 finished | drive function and power section off |
//! | 13 | any -> FRA | [`Inputs::fault`] raised (or a connection abort with 0x6007 = 1) | fault reaction per 0x605E (or at once off) |
//! | 14 | FRA -> Fault | the fault reaction finished | drive function and power section off |
//! | 15 | Fault -> SOD | «Fault reset» edge | refused while the fault is present ([`Outputs::fault_reset_refused`]) |
//! | 16 | QSA -> OE | «Enable operation» | only with 0x605A = 5..8, after the stop finished (Gamma L834) |
//!
//! Rules:
//! - One transition per step, and a command that changes the state is processed completely before the next one
//!   (IDX L424, L395; E3 L436-440; Gamma L848). Commands are levels: a controlword that asks for a further
//!   transition (e.g. `0x000F` in RTSO: 3, then 4) is acted on at the next step.
//! - Stops: transitions 5, 8, 9 with a ramp stay in OE while the ramp runs and complete when the motion layer
//!   reports standstill ([`Inputs::standstill`]) or the standstill timeout expires (IDX 0x30E0 L4827-4898: these
//!   transitions "are not performed until standstill"). Transition 11 enters QSA at once and ramps there; 13
//!   enters FRA at once and ramps there, 14 follows at standstill. Standstill is looked at from the step after the
//!   stop was requested, so the motion layer has seen the request. During a stop, commands wait; only a fault
//!   (13) preempts.
//! - Option codes are read when the stop starts and kept for it; the halt option 0x605D is read every step.
//! - Fault in a state without torque (or a critical fault, class "d", IDX L7030-7036): the drive function is off at
//!   once and 14 follows at the next step. A critical fault during a fault-reaction ramp ends the ramp at once.
//! - A holding brake (IDX 0x3158 L5091-5162; Gamma L848): released while the controllers hold the motor, engaged
//!   otherwise. After a ramp reaches standstill the power stays on for [`Config::brake_engage_delay`] with the
//!   brake engaging, then the transition completes; after transition 4 the set-points are held for
//!   [`Config::brake_release_delay`]. Immediate disables (option code 0, faults without a ramp) do not wait
//!   (Gamma L850: "in case of a fatal error ... remove the high power immediately").
//!
//! - Safe Torque Off ([`Inputs::safe_torque_off`]; EPOS4 AN ch. 9): the hardware has already removed the torque,
//!   so no stop can be performed and none is waited for. RTSO and every state with the power section on go to
//!   «Switch on disabled» at once by the transition «Disable voltage» takes from them (7 from RTSO, a calibration
//!   in progress included; 10 from SO; 9 from OE without the 0x605B ramp; 12 from QSA); a fault reaction ends its
//!   ramp at once (14). «Shutdown» (2) is refused while it lasts, so the drive stays in «Switch on disabled» and, once STO is
//!   released, is restarted only by the master's «Shutdown», «Switch on», «Enable operation» (no command held
//!   from before STO re-enables it: in «Switch on disabled» only «Shutdown» leads on). Faults and a fault reset
//!   (15) work as without STO.
//!
//! The invariant, tested by property: torque (power stage on and controllers enabled) is only allowed in OE, in
//! QSA while ramping or holding with 0x605A = 1..8, and in FRA while ramping with 0x605E = 1, 2; and Fault is
//! only left by transition 15 (or a reset, transition 0).

use super::controlword::{Command, Controlword};
use super::modes::{Mode, ModeSelector, ModeUpdate};
use super::options::{AbortConnectionOption, OptionCodes, QuickStopOption, StopRamp};
use super::state::{State, Transition};
use super::statusword::{StatusFlags, Statusword};
use super::Ticks;

/// The class of a fault the fault handling raises (IDX L7030-7036, E3 L534-537).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FaultClass {
    /// Class "f": the fault reaction 0x605E decides how the drive stops.
    Reaction,
    /// Class "d": secure movement is impossible; the drive function is disabled at once whatever 0x605E says.
    Critical,
}

/// What the fault handling tells the machine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct FaultInput {
    /// A fault was raised in this step (an event; transition 13 from any state but FRA and Fault).
    pub raised: Option<FaultClass>,
    /// The cause of a fault is still present (a level); a fault reset is refused while it is set.
    pub present: bool,
}

/// Statusword bits that other layers own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct StatusInputs {
    /// Bit 7, a warning (fault handling).
    pub warning: bool,
    /// Bit 10, target reached (mode); replaced in QSA by "quick stop finished" (Gamma L912).
    pub target_reached: bool,
    /// Bit 11, internal limit active (control).
    pub internal_limit_active: bool,
    /// Bit 12, operation mode specific (mode).
    pub operation_mode_specific_12: bool,
    /// Bit 13, operation mode specific (mode).
    pub operation_mode_specific_13: bool,
    /// Bit 15, position referenced to home position (homing).
    pub position_referenced: bool,
}

/// The inputs of one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Inputs {
    /// 0x6040.
    pub controlword: Controlword,
    /// 0x6060 (any `i8`; 0 keeps the mode).
    pub modes_of_operation: i8,
    /// 0x605A..0x605E and 0x6007.
    pub options: OptionCodes,
    /// Fault raised / fault present.
    pub fault: FaultInput,
    /// A communication error of class "a" is present (heartbeat, RxPDO or SYNC timeout, EtherCAT link or
    /// watchdog), from its detection until the fieldbus layer sees the master again. 0x6007 decides the reaction:
    /// 1 a fault (present while this is set), 2 «Disable voltage», 3 «Quick stop» in place of the controlword.
    pub connection_lost: bool,
    /// Safe Torque Off is active: the hardware holds the power stage off (module documentation).
    pub safe_torque_off: bool,
    /// The drive has initialised (transition 1).
    pub initialized: bool,
    /// The current-offset calibration started by [`Outputs::start_current_calibration`] has finished
    /// successfully (a failure is a fault). The integration clears it when it starts a calibration.
    pub calibration_done: bool,
    /// The motor is at standstill (IDX 0x30E0 standstill window; or, with detection switched off, the stop
    /// trajectory has ended).
    pub standstill: bool,
    /// Statusword bit 9: the fieldbus controls the drive (NMT Operational, EtherCAT SafeOp/Op).
    pub remote: bool,
    /// The other layers' statusword bits.
    pub status: StatusInputs,
}

impl Default for Inputs {
    fn default() -> Self {
        Self {
            controlword: Controlword(0),
            modes_of_operation: 0,
            options: OptionCodes::DEFAULT,
            fault: FaultInput::default(),
            connection_lost: false,
            safe_torque_off: false,
            initialized: false,
            calibration_done: false,
            standstill: false,
            remote: false,
            status: StatusInputs::default(),
        }
    }
}

/// The power-stage request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PowerStage {
    /// The power section is on (statusword bit 4, voltage enabled): during the calibration of transition 3, in SO
    /// (IDX transition 6 "disable power section"), and while the drive function is enabled.
    pub enabled: bool,
    /// The drive function is enabled: the current controller (and the velocity/position controllers the mode
    /// needs) drive the motor (IDX transition 4).
    pub controllers_enabled: bool,
}

impl PowerStage {
    /// Everything off.
    pub const OFF: Self = Self { enabled: false, controllers_enabled: false };
    /// Power section on, no torque.
    pub const SECTION_ON: Self = Self { enabled: true, controllers_enabled: false };
    /// Drive function enabled: torque may be applied.
    pub const DRIVING: Self = Self { enabled: true, controllers_enabled: true };

    /// Whether torque may be applied.
    pub const fn torque_allowed(self) -> bool {
        self.enabled && self.controllers_enabled
    }
}

/// What follows a stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StopThen {
    /// Disable the drive function (transitions 5, 8, 9, 12, 14).
    Disable,
    /// Stay in QSA, holding (0x605A = 5..8).
    StayInQuickStop,
    /// Stay in OE (halt).
    StayEnabled,
}

/// A stop the motion layer must carry out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Stop {
    /// The deceleration.
    pub ramp: StopRamp,
    /// What follows at standstill.
    pub then: StopThen,
}

/// What the motion layer (modes, trajectory, loops) must do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Motion {
    /// No torque: controllers off.
    Disabled,
    /// Process the set-points of the active mode (OE only; Gamma L848).
    Follow,
    /// Hold the motor at standstill, ignoring set-points (brake engaging or releasing, QSA after the stop).
    Hold,
    /// Decelerate to standstill and hold there; report [`Inputs::standstill`].
    Stop(Stop),
}

/// The holding-brake request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Brake {
    /// Engage (no torque, or the power is about to go off).
    Engaged,
    /// Release (the controllers hold the motor).
    Released,
}

/// The mode part of the outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ModeOutputs {
    /// The active mode.
    pub active: Mode,
    /// 0x6061 modes of operation display.
    pub display: i8,
    /// What became of the 0x6060 request.
    pub update: ModeUpdate,
}

/// The outputs of one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Outputs {
    /// The state after the step.
    pub state: State,
    /// The transition completed in this step.
    pub transition: Option<Transition>,
    /// The transition in progress (calibration of 3; the stop of 5, 8, 9; 12 after a quick stop that disables;
    /// 14 in FRA).
    pub pending: Option<Transition>,
    /// The power-stage request.
    pub power: PowerStage,
    /// The motion request.
    pub motion: Motion,
    /// The brake request.
    pub brake: Brake,
    /// Start the current-offset calibration (one step, at the start of transition 3).
    pub start_current_calibration: bool,
    /// A fault reset was received while the fault is present, and refused.
    pub fault_reset_refused: bool,
    /// The modes of operation.
    pub mode: ModeOutputs,
    /// 0x6041.
    pub statusword: Statusword,
}

/// Configuration without a dictionary object yet.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Config {
    /// Standstill is deemed reached this long after a stop started (IDX 0x30E0:03, default 1000 ms); `None`
    /// waits for standstill forever (0x30E0:03 = 65535).
    pub standstill_timeout: Option<Ticks>,
    /// Time for the holding brake to engage, with the motor held, before the power goes off (IDX 0x3158:01 rise
    /// time, default 10 ms with a brake); 0 without a brake.
    pub brake_engage_delay: Ticks,
    /// Time for the holding brake to release after transition 4 before set-points are followed (IDX 0x3158:02
    /// fall time); 0 without a brake.
    pub brake_release_delay: Ticks,
    /// The mode at start-up (`device.toml` 0x6060 default 1, PPM).
    pub initial_mode: Mode,
}

impl Config {
    /// 1000 ms standstill timeout, no brake (the dictionary assumes none, `device.toml` note on 0x605B), PPM.
    pub const DEFAULT: Self = Self {
        standstill_timeout: Some(Ticks::from_millis(1000)),
        brake_engage_delay: Ticks(0),
        brake_release_delay: Ticks(0),
        initial_mode: Mode::ProfilePosition,
    };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What completes a ramp.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Completion {
    /// This transition (5, 8, 9, 12, 14).
    Transition(Transition),
    /// Stay in QSA, holding (0x605A = 5..8).
    HoldInQuickStop,
}

/// Where the machine is within its state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Phase {
    /// Nothing in progress.
    Steady,
    /// RTSO: transition 3 in progress, calibration running.
    Calibrating,
    /// OE after transition 4: the brake releases, set-points held.
    ReleasingBrake { since: Ticks },
    /// OE (5, 8, 9), QSA (11) or FRA (13): decelerating.
    Ramping { stop: Stop, since: Ticks, completion: Completion },
    /// At standstill, power held while the brake engages; then `completes`.
    EngagingBrake { since: Ticks, completes: Transition },
    /// QSA after a stop with 0x605A = 5..8: holding, waiting for «Enable operation» or «Disable voltage».
    QuickStopHold,
    /// QSA with 0x605A = 0 or FRA without a ramp: drive function off; `completes` at the next step.
    PowerOff { completes: Transition },
}

/// The CiA 402 state machine.
#[derive(Clone, Debug)]
pub struct StateMachine {
    config: Config,
    state: State,
    phase: Phase,
    previous_controlword: Controlword,
    modes: ModeSelector,
}

impl StateMachine {
    /// A machine in NRTSO (transition 0).
    pub const fn new(config: Config) -> Self {
        Self {
            config,
            state: State::NotReadyToSwitchOn,
            phase: Phase::Steady,
            previous_controlword: Controlword(0),
            modes: ModeSelector::new(config.initial_mode),
        }
    }

    /// Transition 0: back to NRTSO with everything off and the initial mode (reset, E3 transition 19 node reset).
    pub fn reset(&mut self) -> Transition {
        self.state = State::NotReadyToSwitchOn;
        self.phase = Phase::Steady;
        self.modes = ModeSelector::new(self.config.initial_mode);
        Transition::T0
    }

    /// The present state.
    pub const fn state(&self) -> State {
        self.state
    }

    /// The active mode of operation.
    pub const fn active_mode(&self) -> Mode {
        self.modes.active()
    }

    /// The configuration.
    pub const fn config(&self) -> Config {
        self.config
    }

    /// Replaces the configuration (the brake delays and the standstill timeout follow their objects); a stop or
    /// brake phase in progress keeps the times it started with only as far as they are measured from its start.
    pub fn set_config(&mut self, config: Config) {
        self.config = config;
    }

    /// The power-stage request of the present state.
    pub const fn power(&self) -> PowerStage {
        match self.state {
            State::NotReadyToSwitchOn | State::SwitchOnDisabled | State::Fault => PowerStage::OFF,
            State::ReadyToSwitchOn => match self.phase {
                Phase::Calibrating => PowerStage::SECTION_ON,
                _ => PowerStage::OFF,
            },
            State::SwitchedOn => PowerStage::SECTION_ON,
            State::OperationEnabled => match self.phase {
                Phase::PowerOff { .. } => PowerStage::OFF,
                _ => PowerStage::DRIVING,
            },
            State::QuickStopActive | State::FaultReactionActive => match self.phase {
                Phase::Ramping { .. } | Phase::EngagingBrake { .. } | Phase::QuickStopHold => PowerStage::DRIVING,
                _ => PowerStage::OFF,
            },
        }
    }

    /// The transition in progress.
    pub const fn pending(&self) -> Option<Transition> {
        match self.phase {
            Phase::Calibrating => Some(Transition::T3),
            Phase::Ramping { completion: Completion::Transition(t), .. }
            | Phase::EngagingBrake { completes: t, .. }
            | Phase::PowerOff { completes: t } => Some(t),
            _ => None,
        }
    }

    /// One tier-2 step.
    pub fn step(&mut self, inputs: &Inputs, now: Ticks) -> Outputs {
        let cw = inputs.controlword;
        let previous = core::mem::replace(&mut self.previous_controlword, cw);
        let options = inputs.options;
        let abort = options.abort_connection();
        let comm_fault = inputs.connection_lost && abort == AbortConnectionOption::Fault;
        let raised = match inputs.fault.raised {
            Some(class) => Some(class),
            None if comm_fault => Some(FaultClass::Reaction),
            None => None,
        };
        let fault_present = inputs.fault.present || comm_fault || raised.is_some();

        // The mode first, with the stop status at the start of the step.
        let may_change = self.mode_change_allowed();
        let mode_update = self.modes.update(inputs.modes_of_operation, may_change);

        let mut start_current_calibration = false;
        let mut fault_reset_refused = false;

        let transition = match (raised, self.state) {
            (Some(FaultClass::Critical), State::FaultReactionActive) => {
                // A critical fault ends a fault-reaction ramp at once.
                self.phase = Phase::PowerOff { completes: Transition::T14 };
                None
            }
            (None, state) if inputs.safe_torque_off && (state == State::ReadyToSwitchOn || self.power().enabled) => {
                self.torque_off(now)
            }
            (Some(_), State::FaultReactionActive | State::Fault) | (None, _) => {
                let mut command = cw.command(previous, self.state);
                if inputs.connection_lost {
                    match abort {
                        AbortConnectionOption::Fault => {}
                        AbortConnectionOption::DisableVoltage => command = Command::DisableVoltage,
                        AbortConnectionOption::QuickStop => command = Command::QuickStop,
                    }
                }
                self.advance(
                    command,
                    inputs,
                    now,
                    fault_present,
                    &mut start_current_calibration,
                    &mut fault_reset_refused,
                )
            }
            (Some(class), _) => Some(self.enter_fault_reaction(class, &options, now)),
        };

        let power = self.power();
        let motion = self.motion(cw, &options, power);
        let brake = match self.phase {
            Phase::EngagingBrake { .. } => Brake::Engaged,
            _ if power.torque_allowed() => Brake::Released,
            _ => Brake::Engaged,
        };
        let target_reached = match self.state {
            State::QuickStopActive => matches!(self.phase, Phase::QuickStopHold),
            _ => inputs.status.target_reached,
        };
        let flags = StatusFlags {
            voltage_enabled: power.enabled,
            warning: inputs.status.warning,
            remote: inputs.remote,
            target_reached,
            internal_limit_active: inputs.status.internal_limit_active,
            operation_mode_specific_12: inputs.status.operation_mode_specific_12,
            operation_mode_specific_13: inputs.status.operation_mode_specific_13,
            safe_torque_off: inputs.safe_torque_off,
            position_referenced: inputs.status.position_referenced,
        };
        Outputs {
            state: self.state,
            transition,
            pending: self.pending(),
            power,
            motion,
            brake,
            start_current_calibration,
            fault_reset_refused,
            mode: ModeOutputs { active: self.modes.active(), display: self.modes.display(), update: mode_update },
            statusword: Statusword::encode(self.state, flags),
        }
    }

    /// Whether a mode change may take effect: not while a stop runs (see [`super::modes`]).
    const fn mode_change_allowed(&self) -> bool {
        !matches!(self.state, State::QuickStopActive | State::FaultReactionActive)
            && !matches!(self.phase, Phase::Ramping { .. } | Phase::EngagingBrake { .. })
    }

    /// The motion request for the state after the step.
    fn motion(&self, cw: Controlword, options: &OptionCodes, power: PowerStage) -> Motion {
        if !power.torque_allowed() {
            return Motion::Disabled;
        }
        match self.phase {
            Phase::Ramping { stop, .. } => Motion::Stop(stop),
            Phase::ReleasingBrake { .. } | Phase::EngagingBrake { .. } | Phase::QuickStopHold => Motion::Hold,
            Phase::Steady if matches!(self.state, State::OperationEnabled) => {
                if cw.halt() && self.modes.active().halt_applies() {
                    Motion::Stop(Stop { ramp: options.halt().ramp(), then: StopThen::StayEnabled })
                } else {
                    Motion::Follow
                }
            }
            _ => Motion::Disabled,
        }
    }

    /// Completes `t`: the state becomes its target.
    fn enter(&mut self, t: Transition, now: Ticks) -> Option<Transition> {
        self.state = t.target();
        self.phase = match t {
            Transition::T4 if self.config.brake_release_delay.0 > 0 => Phase::ReleasingBrake { since: now },
            _ => Phase::Steady,
        };
        Some(t)
    }

    /// Starts transition 5, 8 or 9 from OE: at once without a ramp, else ramp first.
    fn begin_stop(&mut self, t: Transition, ramp: Option<StopRamp>, now: Ticks) -> Option<Transition> {
        match ramp {
            None => self.enter(t, now),
            Some(ramp) => {
                self.phase = Phase::Ramping {
                    stop: Stop { ramp, then: StopThen::Disable },
                    since: now,
                    completion: Completion::Transition(t),
                };
                None
            }
        }
    }

    /// At standstill: engage the brake first if there is one, then complete `t`.
    fn complete_stop(&mut self, t: Transition, now: Ticks) -> Option<Transition> {
        if self.config.brake_engage_delay.0 > 0 {
            self.phase = Phase::EngagingBrake { since: now, completes: t };
            None
        } else {
            self.enter(t, now)
        }
    }

    /// Transition 11 from OE.
    fn begin_quick_stop(&mut self, option: QuickStopOption, now: Ticks) -> Transition {
        self.state = State::QuickStopActive;
        self.phase = match option {
            QuickStopOption::DisableDriveFunction => Phase::PowerOff { completes: Transition::T12 },
            QuickStopOption::RampThenDisable(ramp) => Phase::Ramping {
                stop: Stop { ramp, then: StopThen::Disable },
                since: now,
                completion: Completion::Transition(Transition::T12),
            },
            QuickStopOption::RampThenStay(ramp) => Phase::Ramping {
                stop: Stop { ramp, then: StopThen::StayInQuickStop },
                since: now,
                completion: Completion::HoldInQuickStop,
            },
        };
        Transition::T11
    }

    /// Transition 13: the fault reaction. A ramp only if torque was applied and the fault is of class "f" with
    /// 0x605E = 1, 2; otherwise the drive function goes off at once.
    fn enter_fault_reaction(&mut self, class: FaultClass, options: &OptionCodes, now: Ticks) -> Transition {
        let ramp = match class {
            FaultClass::Reaction if self.power().torque_allowed() => options.fault_reaction().ramp(),
            _ => None,
        };
        self.state = State::FaultReactionActive;
        self.phase = match ramp {
            None => Phase::PowerOff { completes: Transition::T14 },
            Some(ramp) => Phase::Ramping {
                stop: Stop { ramp, then: StopThen::Disable },
                since: now,
                completion: Completion::Transition(Transition::T14),
            },
        };
        Transition::T13
    }

    /// Safe Torque Off in RTSO or a state with the power section on: to «Switch on disabled» at once, by the transition
    /// «Disable voltage» takes from the state, without a stop (the torque is already gone); a fault reaction ends
    /// at the next step (14).
    fn torque_off(&mut self, now: Ticks) -> Option<Transition> {
        match self.state {
            State::ReadyToSwitchOn => self.enter(Transition::T7, now),
            State::SwitchedOn => self.enter(Transition::T10, now),
            State::OperationEnabled => self.enter(Transition::T9, now),
            State::QuickStopActive => self.enter(Transition::T12, now),
            State::FaultReactionActive => {
                self.phase = Phase::PowerOff { completes: Transition::T14 };
                None
            }
            // No power section on in these states (`Self::power`).
            State::NotReadyToSwitchOn | State::SwitchOnDisabled | State::Fault => None,
        }
    }

    /// Whether the ramp that started at `since` has finished.
    fn ramp_finished(&self, inputs: &Inputs, since: Ticks, now: Ticks) -> bool {
        inputs.standstill
            || match self.config.standstill_timeout {
                Some(timeout) => now.since(since) >= timeout,
                None => false,
            }
    }

    /// The state logic for one step without a new fault.
    fn advance(
        &mut self,
        command: Command,
        inputs: &Inputs,
        now: Ticks,
        fault_present: bool,
        start_current_calibration: &mut bool,
        fault_reset_refused: &mut bool,
    ) -> Option<Transition> {
        let options = &inputs.options;
        match self.phase {
            // Work in progress first: commands wait until it is done.
            Phase::Calibrating => {
                return if inputs.calibration_done { self.enter(Transition::T3, now) } else { None };
            }
            Phase::Ramping { since, completion, .. } => {
                if !self.ramp_finished(inputs, since, now) {
                    return None;
                }
                return match completion {
                    Completion::Transition(t) => self.complete_stop(t, now),
                    Completion::HoldInQuickStop => {
                        self.phase = Phase::QuickStopHold;
                        None
                    }
                };
            }
            Phase::EngagingBrake { since, completes } => {
                return if now.since(since) >= self.config.brake_engage_delay {
                    self.enter(completes, now)
                } else {
                    None
                };
            }
            Phase::PowerOff { completes } => return self.enter(completes, now),
            Phase::ReleasingBrake { since } => {
                if now.since(since) >= self.config.brake_release_delay {
                    self.phase = Phase::Steady;
                }
            }
            Phase::Steady | Phase::QuickStopHold => {}
        }
        match self.state {
            State::NotReadyToSwitchOn => {
                if inputs.initialized {
                    self.enter(Transition::T1, now)
                } else {
                    None
                }
            }
            State::SwitchOnDisabled => match command {
                // Refused while Safe Torque Off is active: the drive shows why in statusword bit 14 and 0x603F.
                Command::Shutdown if !inputs.safe_torque_off => self.enter(Transition::T2, now),
                _ => None,
            },
            State::ReadyToSwitchOn => match command {
                Command::SwitchOn | Command::SwitchOnAndEnableOperation => {
                    self.phase = Phase::Calibrating;
                    *start_current_calibration = true;
                    None
                }
                Command::DisableVoltage | Command::QuickStop => self.enter(Transition::T7, now),
                _ => None,
            },
            State::SwitchedOn => match command {
                Command::Shutdown => self.enter(Transition::T6, now),
                Command::EnableOperation => self.enter(Transition::T4, now),
                Command::DisableVoltage | Command::QuickStop => self.enter(Transition::T10, now),
                _ => None,
            },
            State::OperationEnabled => match command {
                Command::DisableOperation => self.begin_stop(Transition::T5, options.disable_operation().ramp(), now),
                Command::Shutdown => self.begin_stop(Transition::T8, options.shutdown().ramp(), now),
                Command::DisableVoltage => self.begin_stop(Transition::T9, options.shutdown().ramp(), now),
                Command::QuickStop => Some(self.begin_quick_stop(options.quick_stop(), now)),
                _ => None,
            },
            State::QuickStopActive => match (self.phase, command) {
                (Phase::QuickStopHold, Command::EnableOperation) => self.enter(Transition::T16, now),
                (Phase::QuickStopHold, Command::DisableVoltage) => self.complete_stop(Transition::T12, now),
                // Not reached (QSA is always ramping, holding or powering off); leave it safely.
                (Phase::Steady, _) => self.enter(Transition::T12, now),
                _ => None,
            },
            // Not reached (FRA is always ramping or powering off); finish the reaction.
            State::FaultReactionActive => self.enter(Transition::T14, now),
            State::Fault => match command {
                Command::FaultReset if fault_present => {
                    *fault_reset_refused = true;
                    None
                }
                Command::FaultReset => self.enter(Transition::T15, now),
                _ => None,
            },
        }
    }
}
