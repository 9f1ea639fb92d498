//! The power path's state as tier 1 keeps it and tiers 2 and 3 act on it: the power-stage state ([`PowerState`]),
//! how well the electrical angle is known ([`CommutationStage`]), and why the outputs were switched off
//! ([`DriveError`] and its causes: [`Trip`], [`CalibrationError`], [`CommutationError`]).
//!
//! Plain values, below the drive, the motion modes and the supervision that all read them, so that none of those
//! has to import another for them (`shared/design/ARCHITECTURE.md`: the tiers exchange values, not objects).

use crate::fault::table::FaultId;

/// The power-stage state (the part of CiA 402 this issue needs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PowerState {
    /// Outputs off, not calibrated for this switch-on (CiA 402 switch on disabled / ready to switch on).
    Off,
    /// Transition 3 in progress: outputs at 50 % duty, offsets being measured.
    Calibrating,
    /// Calibrated, outputs off (CiA 402 switched on).
    SwitchedOn,
    /// Current loop running (CiA 402 operation enabled), including forced alignment.
    OperationEnabled,
    /// Outputs off after a fault, until [`crate::drive::Drive::fault_reset`].
    Fault(DriveError),
}

/// Why the drive is in [`PowerState::Fault`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveError {
    /// The current-offset calibration failed.
    Calibration(CalibrationError),
    /// The electrical angle could not be determined (invalid Hall state).
    Commutation(CommutationError),
    /// A tier-1 protection tripped.
    Protection(Trip),
    /// The current loop did not finish within its period; the runtime measured `cost` (its counter's units:
    /// cycles on the board, instructions under QEMU) against its budget.
    Overrun {
        /// The overrunning tick's cost.
        cost: u32,
    },
}

impl DriveError {
    /// The fault of the table this trip is reported as (`crate::fault::table`).
    #[must_use]
    pub const fn fault_id(self) -> FaultId {
        match self {
            Self::Calibration(_) => FaultId::CurrentOffsetCalibration,
            Self::Commutation(CommutationError::InvalidHallState(_)) => FaultId::HallInvalidState,
            Self::Commutation(CommutationError::SsiNoData) => FaultId::SsiSensor,
            Self::Commutation(CommutationError::SsiMissing) => FaultId::MissingCommutationSensor,
            Self::Commutation(CommutationError::SsiFrame) => FaultId::SsiFrame,
            Self::Protection(Trip::BreakInput) => FaultId::PowerStageProtection,
            Self::Protection(Trip::BusOverVoltage) => FaultId::DcBusOverVoltage,
            Self::Protection(Trip::BusUnderVoltage) => FaultId::DcBusUnderVoltage,
            Self::Protection(Trip::OverCurrent) => FaultId::OverCurrent,
            Self::Protection(Trip::PhaseSum) => FaultId::PhaseCurrentImplausible,
            Self::Overrun { .. } => FaultId::CurrentLoopOverrun,
        }
    }

    /// The detail value of the trip's snapshot: the overrunning tick's cost, the invalid Hall state, else 0.
    #[must_use]
    pub fn fault_detail(self) -> i32 {
        match self {
            Self::Overrun { cost } => i32::try_from(cost).unwrap_or(i32::MAX),
            Self::Commutation(CommutationError::InvalidHallState(h)) => i32::from(h),
            Self::Calibration(_) | Self::Protection(_) | Self::Commutation(_) => 0,
        }
    }
}

/// A condition that switched the power stage off.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trip {
    /// The hardware break input (over-current comparator) tripped.
    BreakInput,
    /// DC bus above the over-voltage limit.
    BusOverVoltage,
    /// DC bus below the under-voltage limit while switching.
    BusUnderVoltage,
    /// A phase current beyond the software over-current limit.
    OverCurrent,
    /// The phase currents do not sum to zero.
    PhaseSum,
}

/// Why a calibration failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibrationError {
    /// A channel's offset is outside the plausible window (broken amplifier, wrong reference, current flowing).
    OffsetOutOfRange {
        /// Channel 0..=2 (phases A, B, C).
        channel: u8,
        /// Its offset from mid-scale, in whole LSB (rounded towards minus infinity).
        deviation_lsb: i16,
    },
    /// A channel's samples spread more than the noise allows (motor moving, unstable amplifier).
    Unsteady {
        /// Channel 0..=2 (phases A, B, C).
        channel: u8,
        /// Max minus min code seen while averaging, in LSB.
        spread_lsb: u16,
    },
    /// Not enough valid samples within the timeout (codes at the rails).
    Timeout,
    /// The calibration was interrupted (break input, outputs switched off).
    Aborted,
}

/// Why the electrical angle cannot be determined.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommutationError {
    /// The Hall sensors report an impossible state (0 or 7, or bits above bit 2): spec §2.7 "Hall sensor error"
    /// 0xFF01 (wiring, supply, damage, noise).
    InvalidHallState(u8),
    /// The SSI sensor sent no data (every clocked bit at one level: clock stuck, sensor unpowered or gone) after
    /// it had sent valid frames: 0x738C "SSI sensor error" (IDX L7276).
    SsiNoData,
    /// No valid SSI frame since the commutation was built (the sensor configured as the commutation sensor is not
    /// there): 0x7391 "missing commutation sensor" (IDX L7300).
    SsiMissing,
    /// An SSI frame with a wrong start or stop bit, or whose position jumped farther than the shaft can move in one
    /// period (a corrupted data bit): 0x738D "SSI sensor frame error" (IDX L7284).
    SsiFrame,
}

/// How well the electrical angle is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommutationStage {
    /// Not started.
    Unknown,
    /// The identification procedure imposes the angle and the d/q injection (`crate::drive::identification`):
    /// only the encoder is tracked, as before a start. Next to [`Self::Unknown`] so that the commutation's one
    /// check for both stays a single compare.
    Injecting,
    /// From the centre of a Hall sector: within +-30 degrees electrical.
    HallSector,
    /// From a Hall edge: within a fraction of one tick's travel (plus the Hall sensors' placement tolerance).
    HallEdge,
    /// Forced alignment in progress (the angle is imposed, not measured).
    Aligning,
    /// Forced alignment done: within the friction-limited alignment error.
    Aligned,
    /// From the encoder index with a stored or learned offset: exact to one count.
    Indexed,
}

impl CommutationStage {
    /// The angle is good enough to run field-oriented control.
    #[must_use]
    pub const fn is_valid(self) -> bool {
        matches!(self, Self::HallSector | Self::HallEdge | Self::Aligned | Self::Indexed)
    }
}
