//! The option codes that choose how the drive stops: 0x605A quick stop, 0x605B shutdown, 0x605C disable
//! operation, 0x605D halt, 0x605E fault reaction, and 0x6007 abort connection (all INTEGER16).
//!
//! Values (digest `shared/spec/cia402-device-control.md` §1.6): 0x605A Gamma Table 6-7 L999-1019 (IDX L5623-5640
//! supports 6 only; Nanotec 0..2); 0x605B/0x605C IDX L5642-5680 and E3 L6678-6725; 0x605D Gamma Table 6-8
//! L1021-1036 and Nanotec p.236; 0x605E IDX L5682-5705 and E3 L6750-6795; 0x6007 IDX L5488-5510 and E3 L6553-6580.
//! The dictionary (`firmware/device.toml`) restricts each object to a subset; the types here cover every value the
//! seeds define (plus the CiA 402 "voltage limit" values 4 and 8 of 0x605A and 4 of 0x605D, which the seeds mark
//! reserved **[std, not in seeds]**), so that the machine is complete whatever the dictionary allows.
//!
//! A value no type accepts (reserved, or a dictionary bypassed) never makes the machine fail: it is read as the
//! object's default in `device.toml` ([`OptionCodes::DEFAULT`]), and [`OptionCodes`] users can see it with each
//! type's `from_raw`.

/// How a stop brings the motor to standstill (the "slow down on ..." of the option-code tables).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StopRamp {
    /// The slow-down ramp: the deceleration of the active mode (Gamma L1004; maxon: profile deceleration
    /// 0x6084, also in the cyclic modes, IDX L968, L1040).
    SlowDown,
    /// The quick-stop ramp: quick stop deceleration 0x6085.
    QuickStop,
    /// Decelerate at the current limit.
    CurrentLimit,
    /// Decelerate at the voltage limit **[std, not in seeds]**.
    VoltageLimit,
}

/// 0x605A quick stop option code: the action of transition 11 and whether QSA is left on its own afterwards.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum QuickStopOption {
    /// 0: disable the drive function at once (Gamma "disabled drive function", Nanotec "immediate stop"); the
    /// drive then goes to SOD.
    DisableDriveFunction,
    /// 1..4: slow down with the ramp, then transit into SOD (transition 12).
    RampThenDisable(StopRamp),
    /// 5..8: slow down with the ramp and stay in QSA (IDX's only value is 6); «Enable operation» returns to OE
    /// (transition 16).
    RampThenStay(StopRamp),
}

impl QuickStopOption {
    /// The value, or `None` for a reserved one (negative, 9 and above).
    pub const fn from_raw(raw: i16) -> Option<Self> {
        Some(match raw {
            0 => Self::DisableDriveFunction,
            1 => Self::RampThenDisable(StopRamp::SlowDown),
            2 => Self::RampThenDisable(StopRamp::QuickStop),
            3 => Self::RampThenDisable(StopRamp::CurrentLimit),
            4 => Self::RampThenDisable(StopRamp::VoltageLimit),
            5 => Self::RampThenStay(StopRamp::SlowDown),
            6 => Self::RampThenStay(StopRamp::QuickStop),
            7 => Self::RampThenStay(StopRamp::CurrentLimit),
            8 => Self::RampThenStay(StopRamp::VoltageLimit),
            _ => return None,
        })
    }

    /// The ramp, or `None` when the drive function is disabled at once.
    pub const fn ramp(self) -> Option<StopRamp> {
        match self {
            Self::DisableDriveFunction => None,
            Self::RampThenDisable(r) | Self::RampThenStay(r) => Some(r),
        }
    }

    /// Whether the drive stays in QSA after the stop (values 5..8; Gamma L834, L912).
    pub const fn stays_in_quick_stop(self) -> bool {
        matches!(self, Self::RampThenStay(_))
    }
}

/// 0x605B shutdown option code: the action of transitions 8 and 9 (IDX L440: transition 9 uses it too).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ShutdownOption {
    /// 0: disable the drive function (switch off the power stage; the motor coasts).
    DisableDriveFunction,
    /// 1: slow down with the slow-down ramp, then disable the drive function.
    SlowDownThenDisable,
}

impl ShutdownOption {
    /// The value, or `None` for a reserved one.
    pub const fn from_raw(raw: i16) -> Option<Self> {
        match raw {
            0 => Some(Self::DisableDriveFunction),
            1 => Some(Self::SlowDownThenDisable),
            _ => None,
        }
    }

    /// The ramp, or `None` when the drive function is disabled at once.
    pub const fn ramp(self) -> Option<StopRamp> {
        match self {
            Self::DisableDriveFunction => None,
            Self::SlowDownThenDisable => Some(StopRamp::SlowDown),
        }
    }
}

/// 0x605C disable operation option code: the action of transition 5.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DisableOperationOption {
    /// 0: disable the drive function (switch off the power stage).
    DisableDriveFunction,
    /// 1: slow down with the slow-down ramp, then disable the drive function.
    SlowDownThenDisable,
}

impl DisableOperationOption {
    /// The value, or `None` for a reserved one.
    pub const fn from_raw(raw: i16) -> Option<Self> {
        match raw {
            0 => Some(Self::DisableDriveFunction),
            1 => Some(Self::SlowDownThenDisable),
            _ => None,
        }
    }

    /// The ramp, or `None` when the drive function is disabled at once.
    pub const fn ramp(self) -> Option<StopRamp> {
        match self {
            Self::DisableDriveFunction => None,
            Self::SlowDownThenDisable => Some(StopRamp::SlowDown),
        }
    }
}

/// 0x605D halt option code: how controlword bit 8 stops the axis; the drive stays in OE (Gamma Table 6-8).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum HaltOption {
    /// 1..4: slow down with this ramp and stay in OE.
    Ramp(StopRamp),
}

impl HaltOption {
    /// The value, or `None` for a reserved one (0, negative, 5 and above).
    pub const fn from_raw(raw: i16) -> Option<Self> {
        Some(Self::Ramp(match raw {
            1 => StopRamp::SlowDown,
            2 => StopRamp::QuickStop,
            3 => StopRamp::CurrentLimit,
            4 => StopRamp::VoltageLimit,
            _ => return None,
        }))
    }

    /// The ramp.
    pub const fn ramp(self) -> StopRamp {
        match self {
            Self::Ramp(r) => r,
        }
    }
}

/// 0x605E fault reaction option code: the reaction to a fault of class "f" (IDX L7030-7036) in transition 13.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FaultReactionOption {
    /// 0: disable the drive function.
    DisableDriveFunction,
    /// 1: slow down with the slow-down ramp.
    SlowDown,
    /// 2: slow down with the quick-stop ramp.
    QuickStopRamp,
}

impl FaultReactionOption {
    /// The value, or `None` for a reserved one (E3's −1 "fault signal only" is not a reaction of this machine:
    /// the fault handling then raises no fault).
    pub const fn from_raw(raw: i16) -> Option<Self> {
        match raw {
            0 => Some(Self::DisableDriveFunction),
            1 => Some(Self::SlowDown),
            2 => Some(Self::QuickStopRamp),
            _ => None,
        }
    }

    /// The ramp, or `None` when the drive function is disabled at once.
    pub const fn ramp(self) -> Option<StopRamp> {
        match self {
            Self::DisableDriveFunction => None,
            Self::SlowDown => Some(StopRamp::SlowDown),
            Self::QuickStopRamp => Some(StopRamp::QuickStop),
        }
    }
}

/// 0x6007 abort connection option code: the reaction to a communication error of class "a" (heartbeat, RxPDO or
/// SYNC timeout, EtherCAT link or watchdog).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AbortConnectionOption {
    /// 1: a fault (transition 13, stopping per 0x605E). E3's 1 only signals; `device.toml` gives 1 the CiA 402
    /// meaning (its note on 0x6007).
    Fault,
    /// 2: the «Disable voltage» command.
    DisableVoltage,
    /// 3: the «Quick stop» command.
    QuickStop,
}

impl AbortConnectionOption {
    /// The value, or `None` for a reserved one (0 "no action" is not offered: a drive that lost its master
    /// must stop).
    pub const fn from_raw(raw: i16) -> Option<Self> {
        match raw {
            1 => Some(Self::Fault),
            2 => Some(Self::DisableVoltage),
            3 => Some(Self::QuickStop),
            _ => None,
        }
    }
}

/// The raw option codes as the dictionary holds them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct OptionCodes {
    /// 0x605A.
    pub quick_stop: i16,
    /// 0x605B.
    pub shutdown: i16,
    /// 0x605C.
    pub disable_operation: i16,
    /// 0x605D.
    pub halt: i16,
    /// 0x605E.
    pub fault_reaction: i16,
    /// 0x6007.
    pub abort_connection: i16,
}

impl OptionCodes {
    /// The defaults of `firmware/device.toml`: 0x605A = 6 (IDX), 0x605B = 0 (no brake), 0x605C = 1 (IDX, NT),
    /// 0x605D = 1 (Gamma), 0x605E = 2 (IDX, E3), 0x6007 = 3 (IDX, E3).
    pub const DEFAULT: Self =
        Self { quick_stop: 6, shutdown: 0, disable_operation: 1, halt: 1, fault_reaction: 2, abort_connection: 3 };

    /// 0x605A, or its default for a reserved value.
    pub const fn quick_stop(&self) -> QuickStopOption {
        match QuickStopOption::from_raw(self.quick_stop) {
            Some(v) => v,
            None => QuickStopOption::RampThenStay(StopRamp::QuickStop),
        }
    }

    /// 0x605B, or its default for a reserved value.
    pub const fn shutdown(&self) -> ShutdownOption {
        match ShutdownOption::from_raw(self.shutdown) {
            Some(v) => v,
            None => ShutdownOption::DisableDriveFunction,
        }
    }

    /// 0x605C, or its default for a reserved value.
    pub const fn disable_operation(&self) -> DisableOperationOption {
        match DisableOperationOption::from_raw(self.disable_operation) {
            Some(v) => v,
            None => DisableOperationOption::SlowDownThenDisable,
        }
    }

    /// 0x605D, or its default for a reserved value.
    pub const fn halt(&self) -> HaltOption {
        match HaltOption::from_raw(self.halt) {
            Some(v) => v,
            None => HaltOption::Ramp(StopRamp::SlowDown),
        }
    }

    /// 0x605E, or its default for a reserved value.
    pub const fn fault_reaction(&self) -> FaultReactionOption {
        match FaultReactionOption::from_raw(self.fault_reaction) {
            Some(v) => v,
            None => FaultReactionOption::QuickStopRamp,
        }
    }

    /// 0x6007, or its default for a reserved value.
    pub const fn abort_connection(&self) -> AbortConnectionOption {
        match AbortConnectionOption::from_raw(self.abort_connection) {
            Some(v) => v,
            None => AbortConnectionOption::QuickStop,
        }
    }
}

impl Default for OptionCodes {
    fn default() -> Self {
        Self::DEFAULT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_resolve_to_the_same_as_reserved_values() {
        let d = OptionCodes::DEFAULT;
        let bad = OptionCodes {
            quick_stop: 9,
            shutdown: -1,
            disable_operation: 2,
            halt: 0,
            fault_reaction: -1,
            abort_connection: 0,
        };
        assert_eq!(bad.quick_stop(), d.quick_stop());
        assert_eq!(bad.shutdown(), d.shutdown());
        assert_eq!(bad.disable_operation(), d.disable_operation());
        assert_eq!(bad.halt(), d.halt());
        assert_eq!(bad.fault_reaction(), d.fault_reaction());
        assert_eq!(bad.abort_connection(), d.abort_connection());
    }

    #[test]
    fn no_i16_panics() {
        for raw in i16::MIN..=i16::MAX {
            let _ = QuickStopOption::from_raw(raw);
            let _ = ShutdownOption::from_raw(raw);
            let _ = DisableOperationOption::from_raw(raw);
            let _ = HaltOption::from_raw(raw);
            let _ = FaultReactionOption::from_raw(raw);
            let _ = AbortConnectionOption::from_raw(raw);
        }
    }
}
