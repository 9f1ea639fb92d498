//! The states of the CiA 402 power state machine and the numbered transitions between them.
//!
//! States and their statusword patterns: IDX L400-413 (Table 2-5), Gamma L895-914 (Table 6-3); digest
//! `shared/spec/cia402-device-control.md` §1.1. Transitions: IDX L416-449 (Table 2-6), E3 L434-468, digest §1.2.

use super::statusword::Statusword;

/// A state of the CiA 402 power state machine (IDX Table 2-5, L400-413).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum State {
    /// Drive initialising; drive function disabled. Statusword `x0xx 0000` (bit 5 = 0 per IDX).
    NotReadyToSwitchOn,
    /// Initialisation complete, parameters may be changed, drive function disabled, no fault. `x1xx 0000`.
    SwitchOnDisabled,
    /// Parameters may be changed, drive function disabled. `x01x 0001`.
    ReadyToSwitchOn,
    /// Drive function disabled, current-offset calibration done (IDX), power section on. `x01x 0011`.
    SwitchedOn,
    /// No fault, drive function enabled, power applied to the motor; set-points are processed (Gamma L848).
    /// `x01x 0111`.
    OperationEnabled,
    /// The quick stop function is executing; drive function enabled and powered. `x00x 0111`.
    QuickStopActive,
    /// A fault was detected and the fault reaction is executing. `x0xx 1111` (bit 5 = 0 per IDX).
    FaultReactionActive,
    /// Fault; drive function disabled; left only by a fault reset once the fault is removed (Gamma L850).
    /// `x0xx 1000` (bit 5 = 0 per IDX).
    Fault,
}

impl State {
    /// Every state, in the order of IDX Table 2-5.
    pub const ALL: [State; 8] = [
        State::NotReadyToSwitchOn,
        State::SwitchOnDisabled,
        State::ReadyToSwitchOn,
        State::SwitchedOn,
        State::OperationEnabled,
        State::QuickStopActive,
        State::FaultReactionActive,
        State::Fault,
    ];

    /// Statusword bits 0, 1, 2, 3, 5 and 6 that identify this state ([`Statusword::STATE_MASK`]). Bit 5 is 0
    /// where IDX fixes it and Gamma leaves it open (NRTSO, SOD, FRA, Fault), so both patterns are met (digest §1.1).
    pub const fn statusword_bits(self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 0x0000,
            State::SwitchOnDisabled => 0x0040,
            State::ReadyToSwitchOn => 0x0021,
            State::SwitchedOn => 0x0023,
            State::OperationEnabled => 0x0027,
            State::QuickStopActive => 0x0007,
            State::FaultReactionActive => 0x000F,
            State::Fault => 0x0008,
        }
    }

    /// The state a statusword reports, with the masks of the CiA 402 tables (Gamma Table 6-3, IDX Table 2-5):
    /// bits 0..3 and 6 for NRTSO, SOD, FRA and Fault, bits 0..3, 5 and 6 for the others. `None` for a pattern
    /// that is no state (e.g. `0x0001` with bit 5 clear).
    pub const fn from_statusword(sw: Statusword) -> Option<State> {
        let sw = sw.0;
        match sw & 0x004F {
            0x0000 => return Some(State::NotReadyToSwitchOn),
            0x0040 => return Some(State::SwitchOnDisabled),
            0x000F => return Some(State::FaultReactionActive),
            0x0008 => return Some(State::Fault),
            _ => {}
        }
        match sw & 0x006F {
            0x0021 => Some(State::ReadyToSwitchOn),
            0x0023 => Some(State::SwitchedOn),
            0x0027 => Some(State::OperationEnabled),
            0x0007 => Some(State::QuickStopActive),
            _ => None,
        }
    }

    /// Whether the state is one in which the drive function may be enabled (torque applied): operation enabled,
    /// quick stop active (IDX L410: "drive function is enabled and power is applied") and fault reaction active
    /// while the fault reaction ramps down (0x605E = 1, 2). Whether torque is actually applied in the state
    /// depends on the option code in force; see [`super::machine`].
    pub const fn may_apply_torque(self) -> bool {
        matches!(self, State::OperationEnabled | State::QuickStopActive | State::FaultReactionActive)
    }
}

/// A numbered transition of the CiA 402 state machine (IDX Table 2-6, L416-449). The EPOS3-only transitions
/// 17..21 (Refresh, Measure Init, fault in enabled state, node reset; E3 L434-468) are not used: the current-offset
/// calibration is done on transition 3 as IDX does, and a fault from any state is transition 13.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Transition {
    /// Start/reset -> NRTSO: initialise drive.
    T0,
    /// NRTSO -> SOD: drive initialised successfully; activate communication.
    T1,
    /// SOD -> RTSO: «Shutdown».
    T2,
    /// RTSO -> SO: «Switch on»; initialise the current sensor, current-offset calibration.
    T3,
    /// SO -> OE: «Enable operation»; enable the drive function (current controller and, if needed, position or
    /// velocity controller).
    T4,
    /// OE -> SO: «Disable operation»; stop per 0x605C, disable the drive function.
    T5,
    /// SO -> RTSO: «Shutdown»; disable the power section.
    T6,
    /// RTSO -> SOD: «Quick stop» or «Disable voltage».
    T7,
    /// OE -> RTSO: «Shutdown»; stop per 0x605B, disable drive function and power section.
    T8,
    /// OE -> SOD: «Disable voltage»; stop per 0x605B (IDX L440, sic: the shutdown option code), disable drive
    /// function and power section.
    T9,
    /// SO -> SOD: «Quick stop» or «Disable voltage».
    T10,
    /// OE -> QSA: «Quick stop»; stop per 0x605A.
    T11,
    /// QSA -> SOD: «Disable voltage», or the quick stop completed with 0x605A = 0..4 (Gamma Table 6-7, L999-1019);
    /// disable drive function and power section.
    T12,
    /// Any state -> FRA: a fault has occurred; start the fault reaction.
    T13,
    /// FRA -> Fault: the fault reaction is completed; disable drive function and power section.
    T14,
    /// Fault -> SOD: «Fault reset»; reset the fault condition if no fault is present.
    T15,
    /// QSA -> OE: «Enable operation»; only with 0x605A = 5..8 (Gamma L834).
    T16,
}

impl Transition {
    /// Every transition, by number.
    pub const ALL: [Transition; 17] = [
        Transition::T0,
        Transition::T1,
        Transition::T2,
        Transition::T3,
        Transition::T4,
        Transition::T5,
        Transition::T6,
        Transition::T7,
        Transition::T8,
        Transition::T9,
        Transition::T10,
        Transition::T11,
        Transition::T12,
        Transition::T13,
        Transition::T14,
        Transition::T15,
        Transition::T16,
    ];

    /// The CiA 402 number of the transition.
    pub const fn number(self) -> u8 {
        match self {
            Transition::T0 => 0,
            Transition::T1 => 1,
            Transition::T2 => 2,
            Transition::T3 => 3,
            Transition::T4 => 4,
            Transition::T5 => 5,
            Transition::T6 => 6,
            Transition::T7 => 7,
            Transition::T8 => 8,
            Transition::T9 => 9,
            Transition::T10 => 10,
            Transition::T11 => 11,
            Transition::T12 => 12,
            Transition::T13 => 13,
            Transition::T14 => 14,
            Transition::T15 => 15,
            Transition::T16 => 16,
        }
    }

    /// The state the transition leads to.
    pub const fn target(self) -> State {
        match self {
            Transition::T0 => State::NotReadyToSwitchOn,
            Transition::T1 | Transition::T7 | Transition::T9 | Transition::T10 | Transition::T12 => {
                State::SwitchOnDisabled
            }
            Transition::T15 => State::SwitchOnDisabled,
            Transition::T2 | Transition::T6 | Transition::T8 => State::ReadyToSwitchOn,
            Transition::T3 | Transition::T5 => State::SwitchedOn,
            Transition::T4 | Transition::T16 => State::OperationEnabled,
            Transition::T11 => State::QuickStopActive,
            Transition::T13 => State::FaultReactionActive,
            Transition::T14 => State::Fault,
        }
    }

    /// The state the transition starts from; `None` for 0 (reset, from anywhere) and 13 (a fault, from any state
    /// but FRA and Fault).
    pub const fn source(self) -> Option<State> {
        match self {
            Transition::T0 | Transition::T13 => None,
            Transition::T1 => Some(State::NotReadyToSwitchOn),
            Transition::T2 => Some(State::SwitchOnDisabled),
            Transition::T3 | Transition::T7 => Some(State::ReadyToSwitchOn),
            Transition::T4 | Transition::T6 | Transition::T10 => Some(State::SwitchedOn),
            Transition::T5 | Transition::T8 | Transition::T9 | Transition::T11 => Some(State::OperationEnabled),
            Transition::T12 | Transition::T16 => Some(State::QuickStopActive),
            Transition::T14 => Some(State::FaultReactionActive),
            Transition::T15 => Some(State::Fault),
        }
    }
}
