//! The two Safe Torque Off inputs as tier 2 reads them (EPOS4 AN ch. 9, S1 L8741-8905; digest
//! `control-and-protection.md` §3.9): plain data between the board (`board::sto` on the target, the plant's
//! safety circuit in `hal-sim`) and the drive (`Drive::set_sto_inputs`).
//!
//! The inputs do not reach the power stage through the firmware: on the board each one gates the supply of the
//! gate drivers, so a de-energised input stops the switching of the output transistors whatever the firmware
//! commands (S1 Tab. 9-87: the power stage is active only with both inputs energised). The firmware reads them
//! back to know the state, report it and keep the CiA 402 machine where it belongs.

/// The levels of STO-IN1 and STO-IN2: `true` = energised (> 4.5 V, S1 Tab. 9-85), the power stage may switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct StoInputs {
    /// STO-IN1 energised.
    pub channel_1: bool,
    /// STO-IN2 energised.
    pub channel_2: bool,
}

impl StoInputs {
    /// Both inputs energised (safety circuit closed, or the "STO idle connector" fitted, S1 L8741-8780).
    pub const RELEASED: Self = Self { channel_1: true, channel_2: true };
    /// Both inputs de-energised: STO demanded.
    pub const DEMANDED: Self = Self { channel_1: false, channel_2: false };

    /// Whether the power stage may switch: both inputs energised (S1 Tab. 9-87).
    #[must_use]
    pub const fn torque_permitted(self) -> bool {
        self.channel_1 && self.channel_2
    }

    /// Whether the two inputs disagree (one channel demands STO, the other does not).
    #[must_use]
    pub const fn disagree(self) -> bool {
        self.channel_1 != self.channel_2
    }

    /// The levels as bits (bit 0 STO-IN1, bit 1 STO-IN2; 1 = energised): the detail a trip snapshot and its EMCY
    /// carry.
    #[must_use]
    pub const fn bits(self) -> u8 {
        (self.channel_1 as u8) | ((self.channel_2 as u8) << 1)
    }
}

impl Default for StoInputs {
    /// [`Self::RELEASED`]: what a board without a safety circuit wired reads (idle connector).
    fn default() -> Self {
        Self::RELEASED
    }
}
