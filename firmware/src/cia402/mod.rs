//! The CiA 402 drive profile's device control: the power state machine, controlword decoding, statusword
//! encoding, the stop option codes and the modes of operation.
//!
//! Everything here is sans-IO (ARCHITECTURE.md convention 1): [`machine::StateMachine::step`] takes the inputs of
//! one 2.5 kHz tier-2 period and the time, and returns the state, the transition taken and the actions the drive
//! must carry out (power stage, stop ramp, brake, current-offset calibration) with the statusword. It never touches
//! the dictionary or the hardware; the drive layer copies 0x6040/0x6060/0x605A..0x605E/0x6007 in and
//! 0x6041/0x6061 out.
//!
//! Sources (`shared/spec/cia402-device-control.md` §1, with the seed lines it cites): states and statusword
//! patterns IDX L400-413 and Gamma L895-914; transitions 0..16 and their actions IDX L416-449 (E3 L434-468,
//! Gamma L827-850); controlword commands IDX L451-467 (E3 L469-488, Gamma L860-876); statusword bits
//! IDX L5566-5621 and Gamma L884-914; option codes IDX L5488-5705 and Gamma L916-1050; modes IDX L5707-5748,
//! Gamma L956-997.
//!
//! Module map:
//! - [`state`]: the eight states with their statusword patterns, and the transition numbers 0..16.
//! - [`controlword`]: command decoding (bit patterns, fault-reset edge, halt, operation-mode-specific bits).
//! - [`statusword`]: statusword encoding.
//! - [`options`]: typed option codes 0x605A..0x605E and 0x6007, with the fallback for values the dictionary
//!   would not have accepted.
//! - [`modes`]: modes of operation 0x6060 / display 0x6061 / supported drive modes 0x6502.
//! - [`machine`]: the state machine itself.

pub mod controlword;
pub mod machine;
pub mod modes;
pub mod options;
pub mod state;
pub mod statusword;

pub use controlword::{Command, CommandPattern, Controlword, OperationModeBits};
pub use machine::{
    Brake, Config, FaultClass, FaultInput, Inputs, ModeOutputs, Motion, Outputs, PowerStage, StateMachine,
    StatusInputs, Stop, StopThen,
};
pub use modes::{Mode, ModeSelector, ModeUpdate, SUPPORTED_DRIVE_MODES};
pub use options::{
    AbortConnectionOption, DisableOperationOption, FaultReactionOption, HaltOption, OptionCodes, QuickStopOption,
    ShutdownOption, StopRamp,
};
pub use state::{State, Transition};
pub use statusword::{StatusFlags, Statusword};

/// A time or a duration counted in tier-2 periods (2.5 kHz, 0.4 ms each; ARCHITECTURE.md "Data flow and timing
/// tiers"). As a time it is a free-running wrapping counter: elapsed times are taken with wrapping subtraction,
/// so durations up to 2^32 periods (about 20 days) are measured correctly across the wrap.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Ticks(pub u32);

impl Ticks {
    /// Tier-2 periods per second.
    pub const PER_SECOND: u32 = 2_500;

    /// The duration of `ms` milliseconds, rounded down to whole periods (2.5 periods per millisecond);
    /// saturates at `u32::MAX` periods.
    pub const fn from_millis(ms: u32) -> Self {
        // ms * 5 / 2 with saturation: ms * 2.5 periods.
        Self(ms.saturating_mul(5) >> 1)
    }

    /// Periods from `earlier` to `self`, across the counter's wrap.
    pub const fn since(self, earlier: Ticks) -> Ticks {
        Ticks(self.0.wrapping_sub(earlier.0))
    }
}
