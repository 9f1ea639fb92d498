//! Decoding of the controlword 0x6040.
//!
//! Device-control commands from bits 0..3 and 7 (IDX Table 2-7 L451-467; E3 Table 3-6 L469-488; Gamma Table 6-2
//! L860-876; digest `shared/spec/cia402-device-control.md` §1.3), halt bit 8 and the operation-mode-specific bits
//! (IDX Table 6-116 L5526-5564; Gamma L882; digest §1.4).
//!
//! The command tables give bit 7 as 0 for every command but «Fault reset», which is the 0 -> 1 edge of bit 7 with
//! the other bits don't-care. A steady bit 7 = 1 (a master that has not yet cleared it after a reset) is treated
//! as don't-care here, so that «Disable voltage» and «Quick stop» are never ignored because of it.

use super::state::State;

/// The controlword 0x6040 as received.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Controlword(pub u16);

/// The device-control bit pattern of bits 0..3 (IDX Table 2-7), before it is given a meaning by the state: the
/// same bits mean «Switch on» in RTSO and «Disable operation» in OE, and «Switch on & Enable operation» in RTSO
/// and «Enable operation» in SO and QSA. Every 4-bit value falls in exactly one pattern, checked in this order:
/// bit 1 = 0 «Disable voltage» (`xx0x`), bit 2 = 0 «Quick stop» (`x01x`), bit 0 = 0 «Shutdown» (`x110`),
/// bit 3 = 0 `0111`, else `1111`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CommandPattern {
    /// `xx0x`: «Disable voltage» (transitions 7, 9, 10, 12).
    DisableVoltage,
    /// `x01x`: «Quick stop» (transitions 7, 10, 11; IDX lists only 11, E3 and Gamma 7, 10, 11; the transition
    /// table of all three has 7 and 10 on «Quick stop or Disable voltage»).
    QuickStop,
    /// `x110`: «Shutdown» (transitions 2, 6, 8).
    Shutdown,
    /// `0111`: «Switch on» (3) or «Disable operation» (5).
    SwitchOn,
    /// `1111`: «Switch on & Enable operation» (3 then 4) or «Enable operation» (4, 16).
    SwitchOnEnable,
}

impl CommandPattern {
    /// Every pattern.
    pub const ALL: [CommandPattern; 5] = [
        CommandPattern::DisableVoltage,
        CommandPattern::QuickStop,
        CommandPattern::Shutdown,
        CommandPattern::SwitchOn,
        CommandPattern::SwitchOnEnable,
    ];
}

/// A device-control command, as the current state gives the bit pattern its meaning (IDX Table 2-7).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Command {
    /// «Shutdown» `0xxx x110`: transitions 2, 6, 8.
    Shutdown,
    /// «Switch on» `0xxx 0111` (outside OE): transition 3.
    SwitchOn,
    /// «Switch on & Enable operation» `0xxx 1111` (outside SO, OE, QSA): transition 3, then 4 automatically.
    SwitchOnAndEnableOperation,
    /// «Disable voltage» `0xxx xx0x`: transitions 7, 9, 10, 12.
    DisableVoltage,
    /// «Quick stop» `0xxx x01x`: transitions 7, 10, 11.
    QuickStop,
    /// «Disable operation» `0xxx 0111` (in OE): transition 5.
    DisableOperation,
    /// «Enable operation» `0xxx 1111` (in SO, OE, QSA): transitions 4, 16.
    EnableOperation,
    /// «Fault reset»: the 0 -> 1 edge of bit 7, in Fault: transition 15.
    FaultReset,
}

/// The operation-mode-specific controlword bits (IDX Table 6-116, Gamma L882, digest §1.4). Their meaning
/// belongs to the active mode: PPM new set-point (4), change set immediately (5), abs/rel (6), endless movement
/// (15, IDX); HMM homing operation start (4); Nanotec "change on set-point" (9); reserved in CSP/CSV/CST.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct OperationModeBits {
    /// Bit 4.
    pub bit4: bool,
    /// Bit 5.
    pub bit5: bool,
    /// Bit 6.
    pub bit6: bool,
    /// Bit 9.
    pub bit9: bool,
    /// Bit 15 (IDX PPM: endless movement; reserved elsewhere).
    pub bit15: bool,
}

impl Controlword {
    /// Bit 0, switch on.
    pub const SWITCH_ON: u16 = 0x0001;
    /// Bit 1, enable voltage.
    pub const ENABLE_VOLTAGE: u16 = 0x0002;
    /// Bit 2, quick stop (active low: 0 requests the quick stop).
    pub const QUICK_STOP: u16 = 0x0004;
    /// Bit 3, enable operation.
    pub const ENABLE_OPERATION: u16 = 0x0008;
    /// Bit 4, operation mode specific.
    pub const OMS_4: u16 = 0x0010;
    /// Bit 5, operation mode specific.
    pub const OMS_5: u16 = 0x0020;
    /// Bit 6, operation mode specific.
    pub const OMS_6: u16 = 0x0040;
    /// Bit 7, fault reset (rising edge).
    pub const FAULT_RESET: u16 = 0x0080;
    /// Bit 8, halt.
    pub const HALT: u16 = 0x0100;
    /// Bit 9, operation mode specific.
    pub const OMS_9: u16 = 0x0200;
    /// Bit 15, operation mode specific (IDX PPM endless movement).
    pub const OMS_15: u16 = 0x8000;

    /// Typical master values (E4 L7378-7379, L7394, L7851-7854): «Shutdown».
    pub const SHUTDOWN: Controlword = Controlword(0x0006);
    /// «Switch on».
    pub const SWITCH_ON_CMD: Controlword = Controlword(0x0007);
    /// «Switch on & Enable operation» / «Enable operation».
    pub const ENABLE_OPERATION_CMD: Controlword = Controlword(0x000F);
    /// «Disable operation» (the same bits as «Switch on»).
    pub const DISABLE_OPERATION_CMD: Controlword = Controlword(0x0007);
    /// «Disable voltage».
    pub const DISABLE_VOLTAGE: Controlword = Controlword(0x0000);
    /// «Quick stop».
    pub const QUICK_STOP_CMD: Controlword = Controlword(0x000B);

    /// The device-control bit pattern of bits 0..3.
    pub const fn pattern(self) -> CommandPattern {
        let cw = self.0;
        if cw & Self::ENABLE_VOLTAGE == 0 {
            CommandPattern::DisableVoltage
        } else if cw & Self::QUICK_STOP == 0 {
            CommandPattern::QuickStop
        } else if cw & Self::SWITCH_ON == 0 {
            CommandPattern::Shutdown
        } else if cw & Self::ENABLE_OPERATION == 0 {
            CommandPattern::SwitchOn
        } else {
            CommandPattern::SwitchOnEnable
        }
    }

    /// Whether bit 7 rose from `previous` to `self` (IDX/E3 "0 -> 1", Gamma "↑").
    pub const fn fault_reset_edge(self, previous: Controlword) -> bool {
        self.0 & Self::FAULT_RESET != 0 && previous.0 & Self::FAULT_RESET == 0
    }

    /// The command this controlword gives in `state`, `previous` being the controlword of the last step.
    ///
    /// Precedence: in Fault a rising edge of bit 7 is «Fault reset» whatever bits 0..3 say (IDX Table 2-7,
    /// "0xxx xxxx -> 1xxx xxxx"). Outside Fault a fault reset has no transition in any state, so bits 0..3 decide:
    /// a reset edge never masks a stop request. The pattern then takes its meaning from the state.
    pub const fn command(self, previous: Controlword, state: State) -> Command {
        if matches!(state, State::Fault) && self.fault_reset_edge(previous) {
            return Command::FaultReset;
        }
        match self.pattern() {
            CommandPattern::DisableVoltage => Command::DisableVoltage,
            CommandPattern::QuickStop => Command::QuickStop,
            CommandPattern::Shutdown => Command::Shutdown,
            CommandPattern::SwitchOn => match state {
                State::OperationEnabled => Command::DisableOperation,
                _ => Command::SwitchOn,
            },
            CommandPattern::SwitchOnEnable => match state {
                State::SwitchedOn | State::OperationEnabled | State::QuickStopActive => Command::EnableOperation,
                _ => Command::SwitchOnAndEnableOperation,
            },
        }
    }

    /// Bit 8, halt: interrupt the commanded motion as 0x605D says, stay in OE (Gamma L882; IDX: PPM, PVM, HMM).
    pub const fn halt(self) -> bool {
        self.0 & Self::HALT != 0
    }

    /// The operation-mode-specific bits 4, 5, 6, 9 and 15.
    pub const fn operation_mode_bits(self) -> OperationModeBits {
        OperationModeBits {
            bit4: self.0 & Self::OMS_4 != 0,
            bit5: self.0 & Self::OMS_5 != 0,
            bit6: self.0 & Self::OMS_6 != 0,
            bit9: self.0 & Self::OMS_9 != 0,
            bit15: self.0 & Self::OMS_15 != 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_low_nibble_has_one_pattern_as_the_idx_table_says() {
        // IDX Table 2-7: Shutdown 0xxx x110, Switch on 0xxx x111 (0111 with bit 3 = 0), Switch on & Enable
        // 0xxx 1111, Disable voltage 0xxx xx0x, Quick stop 0xxx x01x.
        for nibble in 0u16..16 {
            let expected = if nibble & 0b0010 == 0 {
                CommandPattern::DisableVoltage
            } else if nibble & 0b0110 == 0b0010 {
                CommandPattern::QuickStop
            } else if nibble & 0b0111 == 0b0110 {
                CommandPattern::Shutdown
            } else if nibble == 0b0111 {
                CommandPattern::SwitchOn
            } else {
                assert_eq!(nibble, 0b1111);
                CommandPattern::SwitchOnEnable
            };
            // Bits 4..15 do not change the pattern.
            for high in [0x0000u16, 0x0070, 0x0080, 0x0100, 0x0200, 0xFF70] {
                assert_eq!(Controlword(nibble | high).pattern(), expected, "cw {:#06x}", nibble | high);
            }
        }
    }

    #[test]
    fn fault_reset_is_an_edge_and_only_in_fault() {
        let prev = Controlword(0x0000);
        let now = Controlword(0x0080);
        assert_eq!(now.command(prev, State::Fault), Command::FaultReset);
        assert_eq!(now.command(now, State::Fault), Command::DisableVoltage);
        assert_eq!(now.command(prev, State::OperationEnabled), Command::DisableVoltage);
        assert_eq!(Controlword(0x008F).command(Controlword(0x000F), State::OperationEnabled), Command::EnableOperation);
    }

    #[test]
    fn shared_patterns_take_their_meaning_from_the_state() {
        let p = Controlword(0);
        assert_eq!(Controlword(0x07).command(p, State::ReadyToSwitchOn), Command::SwitchOn);
        assert_eq!(Controlword(0x07).command(p, State::OperationEnabled), Command::DisableOperation);
        assert_eq!(Controlword(0x0F).command(p, State::ReadyToSwitchOn), Command::SwitchOnAndEnableOperation);
        assert_eq!(Controlword(0x0F).command(p, State::SwitchedOn), Command::EnableOperation);
        assert_eq!(Controlword(0x0F).command(p, State::QuickStopActive), Command::EnableOperation);
    }

    #[test]
    fn halt_and_mode_bits() {
        let cw = Controlword(0x837F);
        assert!(cw.halt());
        let b = cw.operation_mode_bits();
        assert!(b.bit4 && b.bit5 && b.bit6 && b.bit9 && b.bit15);
        assert_eq!(Controlword(0x000F).operation_mode_bits(), OperationModeBits::default());
    }
}
