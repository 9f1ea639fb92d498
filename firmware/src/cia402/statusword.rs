//! Encoding of the statusword 0x6041.
//!
//! Bit map (IDX Table 6-117 L5566-5621; Gamma Figure 6-3 and text L884-914; E3 L6612-6676; digest
//! `shared/spec/cia402-device-control.md` §1.5):
//!
//! | Bit | Meaning | Source of the value here |
//! |---|---|---|
//! | 0, 1, 2, 3, 5, 6 | ready to switch on, switched on, operation enabled, fault, quick stop, switch on disabled | the state ([`State::statusword_bits`]) |
//! | 4 | voltage enabled: the power stage is on (IDX "power stage on", Gamma "high voltage applied") | the machine's power-stage output |
//! | 7 | warning (not a fault; the state is unchanged; cause in 0x603F) | input from the fault handling |
//! | 8 | reserved, 0 (IDX; E3 "offset current measured" and Nanotec SYNC are not used) | always 0 |
//! | 9 | remote (IDX: NMT Operational; E3: ESM SafeOp/Op) | input from the fieldbus |
//! | 10 | target reached (mode specific); in QSA with 0x605A = 5..8, 1 once the quick stop finished and the drive halted (Gamma L912) | input from the mode, overridden in QSA |
//! | 11 | internal limit active (I2t, current, velocity limits) | input |
//! | 12, 13 | operation mode specific | input from the mode |
//! | 14 | manufacturer specific: Safe Torque Off active, the hardware holds the power stage off (IDX reserved; E3 "refresh cycle of power stage" not used; the STO state Gamma shows in 0x2002 bit 0, GT L2101) | input from the fault handling |
//! | 15 | manufacturer specific: position referenced to home position (IDX L5589-5593, E3 same) | input from homing |

use super::state::State;

/// The statusword 0x6041.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Statusword(pub u16);

/// The statusword bits that are not the state's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct StatusFlags {
    /// Bit 4: the power stage is on.
    pub voltage_enabled: bool,
    /// Bit 7: a warning is present.
    pub warning: bool,
    /// Bit 9: the fieldbus controls the drive (NMT Operational / EtherCAT SafeOp or Op).
    pub remote: bool,
    /// Bit 10: target reached (mode specific).
    pub target_reached: bool,
    /// Bit 11: an internal limit is active.
    pub internal_limit_active: bool,
    /// Bit 12: operation mode specific (PPM set-point acknowledge, PVM speed = 0, HMM homing attained, CSx drive
    /// follows the command value).
    pub operation_mode_specific_12: bool,
    /// Bit 13: operation mode specific (PPM/CSP following error, HMM homing error).
    pub operation_mode_specific_13: bool,
    /// Bit 14: Safe Torque Off is active (manufacturer specific).
    pub safe_torque_off: bool,
    /// Bit 15: position referenced to home position (manufacturer specific, IDX/E3).
    pub position_referenced: bool,
}

impl Statusword {
    /// Bits 0..3, 5, 6: the state ([`State::statusword_bits`]).
    pub const STATE_MASK: u16 = 0x006F;
    /// Bit 0, ready to switch on.
    pub const READY_TO_SWITCH_ON: u16 = 0x0001;
    /// Bit 1, switched on.
    pub const SWITCHED_ON: u16 = 0x0002;
    /// Bit 2, operation enabled.
    pub const OPERATION_ENABLED: u16 = 0x0004;
    /// Bit 3, fault.
    pub const FAULT: u16 = 0x0008;
    /// Bit 4, voltage enabled.
    pub const VOLTAGE_ENABLED: u16 = 0x0010;
    /// Bit 5, quick stop (0 = the drive is reacting to a quick stop request, Gamma L910).
    pub const QUICK_STOP: u16 = 0x0020;
    /// Bit 6, switch on disabled.
    pub const SWITCH_ON_DISABLED: u16 = 0x0040;
    /// Bit 7, warning.
    pub const WARNING: u16 = 0x0080;
    /// Bit 9, remote.
    pub const REMOTE: u16 = 0x0200;
    /// Bit 10, target reached.
    pub const TARGET_REACHED: u16 = 0x0400;
    /// Bit 11, internal limit active.
    pub const INTERNAL_LIMIT_ACTIVE: u16 = 0x0800;
    /// Bit 12, operation mode specific.
    pub const OMS_12: u16 = 0x1000;
    /// Bit 13, operation mode specific.
    pub const OMS_13: u16 = 0x2000;
    /// Bit 14, Safe Torque Off active (manufacturer specific).
    pub const SAFE_TORQUE_OFF: u16 = 0x4000;
    /// Bit 15, position referenced to home position.
    pub const POSITION_REFERENCED: u16 = 0x8000;

    /// The statusword for `state` with `flags`. Always inlined: two callers per slow tick, and a few bit operations
    /// on flags that are mostly constants there.
    #[inline(always)]
    pub const fn encode(state: State, flags: StatusFlags) -> Statusword {
        let mut sw = state.statusword_bits();
        if flags.voltage_enabled {
            sw |= Self::VOLTAGE_ENABLED;
        }
        if flags.warning {
            sw |= Self::WARNING;
        }
        if flags.remote {
            sw |= Self::REMOTE;
        }
        if flags.target_reached {
            sw |= Self::TARGET_REACHED;
        }
        if flags.internal_limit_active {
            sw |= Self::INTERNAL_LIMIT_ACTIVE;
        }
        if flags.operation_mode_specific_12 {
            sw |= Self::OMS_12;
        }
        if flags.operation_mode_specific_13 {
            sw |= Self::OMS_13;
        }
        if flags.safe_torque_off {
            sw |= Self::SAFE_TORQUE_OFF;
        }
        if flags.position_referenced {
            sw |= Self::POSITION_REFERENCED;
        }
        Statusword(sw)
    }

    /// The state this statusword reports ([`State::from_statusword`]).
    pub const fn state(self) -> Option<State> {
        State::from_statusword(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_patterns_match_idx_and_gamma_tables() {
        // (state, IDX Table 2-5 pattern with mask) — IDX L403-410: x00x 0000, x10x 0000, x01x 0001, x01x 0011,
        // x01x 0111, x00x 0111, x00x 1111, x00x 1000 (bits 6, 5 and 3..0 significant).
        let idx = [
            (State::NotReadyToSwitchOn, 0x00),
            (State::SwitchOnDisabled, 0x40),
            (State::ReadyToSwitchOn, 0x21),
            (State::SwitchedOn, 0x23),
            (State::OperationEnabled, 0x27),
            (State::QuickStopActive, 0x07),
            (State::FaultReactionActive, 0x0F),
            (State::Fault, 0x08),
        ];
        for (state, pattern) in idx {
            let sw = Statusword::encode(state, StatusFlags::default());
            assert_eq!(sw.0 & 0x6F, pattern, "{state:?}");
            assert_eq!(sw.state(), Some(state));
            // Every other flag set: the state still decodes the same.
            let all = StatusFlags {
                voltage_enabled: true,
                warning: true,
                remote: true,
                target_reached: true,
                internal_limit_active: true,
                operation_mode_specific_12: true,
                operation_mode_specific_13: true,
                safe_torque_off: true,
                position_referenced: true,
            };
            let sw = Statusword::encode(state, all);
            assert_eq!(sw.state(), Some(state));
            assert_eq!(sw.0 & !0x006F, 0xFE90, "{state:?}");
        }
    }

    #[test]
    fn nanotec_auto_setup_expectations() {
        // NT p.26-27 L179-181: switched on shows bits 9, 5, 4, 1, 0; operation enabled adds bit 2.
        let flags = StatusFlags { voltage_enabled: true, remote: true, ..StatusFlags::default() };
        assert_eq!(Statusword::encode(State::SwitchedOn, flags).0, 0x0233);
        assert_eq!(Statusword::encode(State::OperationEnabled, flags).0, 0x0237);
    }
}
