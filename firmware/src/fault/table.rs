//! The fault table: every fault and warning the drive can report, with its CiA 301/402 error code, its
//! error-register bits (0x1001), its reaction class, its latch policy, the kind of its cause and the tier that
//! detects it (ARCHITECTURE convention 6: "every fault has a stable code, an error-register bit and a reaction
//! class").
//!
//! Sources (`shared/spec/comms-faults-bootloader.md` §3, seed line references from the IDX firmware
//! specification, `shared/seeds/002_*.txt`):
//! - Codes: IDX Table 7-153 (IDX L7040-L7110) wherever IDX defines one, with the per-error detail sections
//!   (IDX L7116-L7620). Where IDX has no code, the CiA 402 (IEC 61800-7-201) device-profile code is used, marked
//!   **\[BG\]** (background knowledge, not in the seeds; verify against CiA 402-2 Annex) and, where another seed uses
//!   the same code for the same thing, that seed is cited as corroboration (Gamma L1060-L1075, PD4 p.109).
//!   Warnings and the EMCY overflow have manufacturer-specific codes (CiA 301 0xFF00..0xFFFF "device specific"),
//!   chosen from 0xFF80 up so that they never collide with IDX's 0xFF01..0xFF22. Safe Torque Off has no code in
//!   any seed (digest `control-and-protection.md` §3.9: "No seed specifies an STO-related error code"): its two
//!   rows take a block of their own from 0xFFA0 (device specific, clear of IDX's 0xFF01..0xFF22, the warnings'
//!   0xFF80.. and the EMCY overflow's 0xFF90), so that a master reading 0x603F tells "STO demanded" (0xFFA0) from
//!   "STO wiring faulty" (0xFFA1) without a vendor table.
//! - Error register: CiA 301 bit meanings as IDX L1570-L1595 lists them (0 generic, 1 current, 2 voltage,
//!   3 temperature, 4 communication, 5 device profile, 7 manufacturer/motion). The class bit follows IDX
//!   Table 7-153; **bit 0 (generic) is set for every fault as well**, because CiA 301 (object 1001h) asks for it "if any
//!   error condition is present" (the digest's design note in §3.1: IDX sets only the class bit; we follow CiA 301
//!   so that a master testing bit 0 sees every fault). Warnings set no bit: they are not errors (§3.6).
//! - Reaction classes: IDX L7030-L7036 (letters d, f, a), with warnings as the fourth (§3.6, E3 "fault signal
//!   only").

use crate::cia402::FaultClass;

/// CiA 301 error-register bit 0: generic error (IDX L1574).
pub const REG_GENERIC: u8 = 1 << 0;
/// CiA 301 error-register bit 1: current.
pub const REG_CURRENT: u8 = 1 << 1;
/// CiA 301 error-register bit 2: voltage.
pub const REG_VOLTAGE: u8 = 1 << 2;
/// CiA 301 error-register bit 3: temperature.
pub const REG_TEMPERATURE: u8 = 1 << 3;
/// CiA 301 error-register bit 4: communication error (overrun, error state).
pub const REG_COMMUNICATION: u8 = 1 << 4;
/// CiA 301 error-register bit 5: device-profile specific (IDX uses it for sensor errors, L7064-L7070).
pub const REG_PROFILE: u8 = 1 << 5;
/// CiA 301 error-register bit 6: reserved, always 0.
pub const REG_RESERVED: u8 = 1 << 6;
/// CiA 301 error-register bit 7: manufacturer specific (IDX: motion error, L7088-L7091).
pub const REG_MOTION: u8 = 1 << 7;

/// How the drive reacts to a fault (IDX L7030-L7036; digest §3.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ReactionClass {
    /// IDX class "d": a secure movement is no longer possible; the power stage goes off at once, whatever the
    /// option codes say (CiA 402 [`FaultClass::Critical`]).
    DisablePowerImmediately,
    /// IDX class "f": the drive stops as the fault reaction option code 0x605E says (0 coast, 1 slow-down ramp,
    /// 2 quick-stop ramp; IDX L5690), then disables (CiA 402 [`FaultClass::Reaction`]).
    QuickStopThenDisable,
    /// IDX class "a": a communication error; the abort connection option code 0x6007 decides (IDX L5496: 1 fault,
    /// 2 disable voltage, 3 quick stop). The state machine takes it as `Inputs::connection_lost`, not as a
    /// [`FaultClass`].
    AbortConnection,
    /// Not a fault: statusword bit 7 "warning" and an EMCY, no state change (digest §3.6; Gamma L910;
    /// IDX L5584).
    Warning,
    /// Not a fault: the hardware holds the power stage off (Safe Torque Off, EPOS4 AN ch. 9, S1 L8741-8905). While
    /// it lasts the CiA 402 machine leaves every state with power for «Switch on disabled» and refuses «Shutdown»
    /// there (`cia402::Inputs::safe_torque_off`), statusword bit 14 shows it and 0x603F its code when no fault is
    /// active; an EMCY announces it. It clears itself when the inputs are energised again, enters neither 0x1001
    /// nor the error history, and a fault reset neither needs nor clears it: the drive is restarted only by the
    /// master's normal «Shutdown», «Switch on», «Enable operation».
    TorqueOff,
}

impl ReactionClass {
    /// The CiA 402 state machine's fault class for a fault of this class (`cia402::FaultInput::raised`), or
    /// `None` for classes the machine takes another way (communication errors: `connection_lost`; warnings:
    /// statusword bit 7).
    pub const fn machine_class(self) -> Option<FaultClass> {
        match self {
            Self::DisablePowerImmediately => Some(FaultClass::Critical),
            Self::QuickStopThenDisable => Some(FaultClass::Reaction),
            Self::AbortConnection | Self::Warning | Self::TorqueOff => None,
        }
    }

    /// Severity for choosing the error code 0x603F shows when several faults are active: higher is more severe.
    pub const fn severity(self) -> u8 {
        match self {
            Self::DisablePowerImmediately => 3,
            Self::QuickStopThenDisable => 2,
            Self::AbortConnection => 1,
            // The STO state is shown only while no fault is: a fault is what the master must act on first.
            Self::Warning | Self::TorqueOff => 0,
        }
    }

    /// Whether this is a warning rather than a fault.
    pub const fn is_warning(self) -> bool {
        matches!(self, Self::Warning)
    }

    /// Whether this is a fault (classes d, f, a): it latches, sets 0x1001 and enters the error history.
    pub const fn is_fault(self) -> bool {
        matches!(self, Self::DisablePowerImmediately | Self::QuickStopThenDisable | Self::AbortConnection)
    }
}

/// Whether an entry stays active after its cause has gone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LatchPolicy {
    /// Stays active until a fault reset (controlword bit 7 rising edge, CiA 402 transition 15) arrives after the
    /// cause has gone; a reset while the cause persists is refused (IDX L7156-L7176 "reset only when valid";
    /// digest §3.7 "fault reset conditions").
    Latching,
    /// Goes away by itself as soon as its cause goes (warnings; PD4 p.105 "bits are cleared automatically").
    SelfClearing,
}

/// What kind of condition raises an entry, which decides when its cause counts as gone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Cause {
    /// A condition that persists (a voltage out of range, a hot power stage, a lost heartbeat): present from
    /// the raise until the detector calls `FaultManager::clear_cause`.
    Level,
    /// A one-off event (an over-current sample, a loop overrun, a limit switch that "was/is active",
    /// IDX L7460-L7470): the cause is gone as soon as it is raised, so a fault reset is accepted at once.
    Event,
}

/// Where the condition is detected (ARCHITECTURE "Data flow and timing tiers").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Tier {
    /// The power stage's own protection (TIM1 break input, comparator), acted on by hardware and reported by
    /// tier 1.
    Hardware,
    /// Tier 1, 25 kHz current loop.
    CurrentLoop,
    /// Tier 2, 2.5 kHz: motion control, CiA 402, limit and fault supervision, PDO exchange.
    Supervision,
    /// Tier 3, thread mode: NMT, heartbeat, mailbox/SDO, EMCY, parameter storage.
    Background,
    /// Start-up, before the tiers run (parameter store load).
    Boot,
}

/// Which measured value of the trip snapshot an EMCY carries in its manufacturer bytes 4..7 (see
/// [`crate::fault::emcy`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SnapshotField {
    /// The phase current with the largest magnitude, mA.
    PeakPhaseCurrent,
    /// The sum of the three phase currents, mA (zero for a healthy star-connected motor).
    PhaseCurrentSum,
    /// The DC-bus voltage, mV.
    BusVoltage,
    /// The power-stage temperature, 0.1 degC.
    PowerStageTemperature,
    /// The motor I2t level, percent (IDX 0x3200).
    MotorI2tLevel,
    /// The actual position, increments.
    Position,
    /// The actual velocity, rpm.
    Velocity,
    /// The detector's own measurement ([`crate::fault::DiagnosisSnapshot::detail`]).
    Detail,
}

/// The stable identity of a fault or warning. The discriminant is the row of [`FAULT_TABLE`] and the fault
/// number the EMCY carries in manufacturer byte 3; it never changes once released (new faults are appended).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum FaultId {
    /// Software over-current: a calibrated phase current beyond the peak limit in one sample.
    OverCurrent = 0,
    /// The power stage's hardware over-current protection (break input) has switched the outputs off.
    PowerStageProtection = 1,
    /// The current loop did not finish within its 40 us period.
    CurrentLoopOverrun = 2,
    /// The three phase currents do not sum to zero: a shunt, amplifier or ADC fault, or an earth fault.
    PhaseCurrentImplausible = 3,
    /// The current-offset calibration at switch-on failed (offset out of range or noisy).
    CurrentOffsetCalibration = 4,
    /// DC-bus over-voltage (typically regeneration).
    DcBusOverVoltage = 5,
    /// DC-bus under-voltage.
    DcBusUnderVoltage = 6,
    /// Warning: the motor I2t model has reached its limit; the current is limited to the nominal current.
    MotorI2tLimit = 7,
    /// The motor temperature sensor reads above 0x3201:04 (125 degC), or no sensor is connected (IDX L5476-L5486).
    MotorThermalOverload = 8,
    /// Warning: the power stage is close to its temperature limit.
    PowerStageTemperatureHigh = 9,
    /// Power-stage over-temperature.
    PowerStageOverTemperature = 10,
    /// The incremental encoder's signals are lost or inconsistent (sensor breach).
    EncoderSignalLoss = 11,
    /// The encoder index was not found where it was expected (position no longer valid).
    EncoderIndexMissing = 12,
    /// The Hall sensors show an impossible state (000 or 111).
    HallInvalidState = 13,
    /// The Hall sensors and the encoder disagree on the electrical angle.
    HallEncoderMismatch = 14,
    /// The following error exceeded the window 0x6065.
    FollowingError = 15,
    /// The commanded or actual position left the software position limits 0x607D.
    SoftwarePositionLimit = 16,
    /// The negative limit switch was or is active.
    NegativeLimitSwitch = 17,
    /// The positive limit switch was or is active.
    PositiveLimitSwitch = 18,
    /// Stall / standstill supervision: the motor does not move although it should (or moves although it
    /// should stand still).
    MotorBlocked = 19,
    /// A supervised heartbeat (0x1016) or the node guarding timed out.
    HeartbeatLost = 20,
    /// No RxPDO (or no SYNC) arrived within the expected period in a cyclic mode.
    RxPdoTimeout = 21,
    /// EtherCAT link lost or sync-manager watchdog expired while operational.
    EthercatWatchdog = 22,
    /// A received PDO was shorter than its mapping.
    PdoLength = 23,
    /// EtherCAT synchronisation error: the cycle time is invalid or sync events were missed (0x1C32:20).
    EthercatSyncError = 24,
    /// CANopen SYNC with an unexpected data length.
    CanSyncLength = 25,
    /// The parameter store was corrupt at boot; defaults were loaded.
    ParameterStoreCorrupt = 26,
    /// An internal software error (an invariant the firmware checks did not hold).
    InternalSoftware = 27,
    /// Warning: the EMCY queue overflowed and messages were lost (reported by the EMCY producer itself).
    EmcyOverflow = 28,
    /// A motor phase carries no current while the others do (a broken motor lead or winding).
    MotorPhaseOpen = 29,
    /// The CAN controller is error passive.
    CanErrorPassive = 30,
    /// The CAN controller is bus-off.
    CanBusOff = 31,
    /// Received CAN frames were lost (the controller's receive FIFO overflowed).
    CanRxOverrun = 32,
    /// The independent watchdog reset the device: some tier stopped running (reported at the next start).
    WatchdogReset = 33,
    /// Safe Torque Off: an STO input is not energised, the hardware holds the power stage off (EPOS4 AN ch. 9).
    SafeTorqueOff = 34,
    /// The two STO inputs disagreed for longer than the discrepancy time: a channel or its wiring has failed.
    StoDiscrepancy = 35,
    /// Warning: the braking resistor's thermal model reached its limit; the chopper is off until it has cooled.
    ChopperOverload = 36,
    /// The CAN controller is back on the bus after a bus-off (reported once, as an event).
    CanBusOffRecovered = 37,
    /// Motor identification: the voltage limit stopped a test current short of its demand (IDX 0xFF12).
    AutoTuningCurrentLimit = 38,
    /// Motor identification: a test current does not flow (an open phase; IDX 0xFF13).
    AutoTuningIdentificationCurrent = 39,
    /// Motor identification: a measured parameter contradicts the configuration (pole pairs against the encoder,
    /// Hall sequence) or the configuration does not allow it (no encoder; IDX 0xFF16).
    AutoTuningParameter = 40,
    /// Motor identification: the procedure did not finish in time (IDX 0xFF19).
    AutoTuningTimeout = 41,
    /// Motor identification: the motor moved before the test (IDX 0xFF20).
    AutoTuningStandstill = 42,
    /// Motor identification: the rotor did not follow (movement obstructed, or no encoder signal; IDX 0xFF21).
    AutoTuningTorqueInvalid = 43,
    /// Motor identification: the maximum speed 0x6080 was exceeded (IDX 0xFF22).
    AutoTuningMaxSpeed = 44,
    /// Motor identification: the mechanical step's samples gave no physical plant (IDX 0xFF15).
    AutoTuningSampleMismatch = 45,
    /// The SSI absolute encoder sent no data (clock stuck, sensor unpowered or disconnected; IDX 0x738C).
    SsiSensor = 46,
    /// An SSI frame failed its check: start or stop bit, or a position jump no motion explains (IDX 0x738D).
    SsiFrame = 47,
    /// The configured main sensor cannot be used (the SSI format in 0x3012 is not one the drive reads; IDX 0x7390).
    MissingMainSensor = 48,
    /// The configured commutation sensor never answered (no valid SSI frame since the start; IDX 0x7391).
    MissingCommutationSensor = 49,
    /// The motor turned away against the direction it was driven (sensor polarity, sensor or motor wiring wrong;
    /// IDX 0x7392).
    MainSensorDirection = 50,
}

/// Number of rows in [`FAULT_TABLE`].
pub const FAULT_COUNT: usize = 51;

/// One row of the fault table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaultInfo {
    /// The fault this row describes.
    pub id: FaultId,
    /// CiA 301/402 error code: 0x603F, the low word of a 0x1003 entry, EMCY bytes 0-1.
    pub code: u16,
    /// Error-register bits (0x1001) the fault sets while it is active; 0 for warnings.
    pub register: u8,
    /// How the drive reacts.
    pub reaction: ReactionClass,
    /// Whether it stays active until a fault reset.
    pub latch: LatchPolicy,
    /// Level or event.
    pub cause: Cause,
    /// The tier that detects it.
    pub tier: Tier,
    /// The measured value its EMCY carries in bytes 4..7.
    pub emcy_field: SnapshotField,
    /// Short name (object reference, logs, tools). Host builds only: the image never reads it, and with
    /// [`FaultInfo::source`] it was about 4 KB of every image's flash (pointers and text).
    #[cfg(not(target_os = "none"))]
    pub name: &'static str,
    /// Where the code comes from (host builds only, as [`FaultInfo::name`]).
    #[cfg(not(target_os = "none"))]
    pub source: &'static str,
}

impl FaultId {
    /// Every fault in table order.
    pub const ALL: [FaultId; FAULT_COUNT] = [
        Self::OverCurrent,
        Self::PowerStageProtection,
        Self::CurrentLoopOverrun,
        Self::PhaseCurrentImplausible,
        Self::CurrentOffsetCalibration,
        Self::DcBusOverVoltage,
        Self::DcBusUnderVoltage,
        Self::MotorI2tLimit,
        Self::MotorThermalOverload,
        Self::PowerStageTemperatureHigh,
        Self::PowerStageOverTemperature,
        Self::EncoderSignalLoss,
        Self::EncoderIndexMissing,
        Self::HallInvalidState,
        Self::HallEncoderMismatch,
        Self::FollowingError,
        Self::SoftwarePositionLimit,
        Self::NegativeLimitSwitch,
        Self::PositiveLimitSwitch,
        Self::MotorBlocked,
        Self::HeartbeatLost,
        Self::RxPdoTimeout,
        Self::EthercatWatchdog,
        Self::PdoLength,
        Self::EthercatSyncError,
        Self::CanSyncLength,
        Self::ParameterStoreCorrupt,
        Self::InternalSoftware,
        Self::EmcyOverflow,
        Self::MotorPhaseOpen,
        Self::CanErrorPassive,
        Self::CanBusOff,
        Self::CanRxOverrun,
        Self::WatchdogReset,
        Self::SafeTorqueOff,
        Self::StoDiscrepancy,
        Self::ChopperOverload,
        Self::CanBusOffRecovered,
        Self::AutoTuningCurrentLimit,
        Self::AutoTuningIdentificationCurrent,
        Self::AutoTuningParameter,
        Self::AutoTuningTimeout,
        Self::AutoTuningStandstill,
        Self::AutoTuningTorqueInvalid,
        Self::AutoTuningMaxSpeed,
        Self::AutoTuningSampleMismatch,
        Self::SsiSensor,
        Self::SsiFrame,
        Self::MissingMainSensor,
        Self::MissingCommutationSensor,
        Self::MainSensorDirection,
    ];

    /// The stable fault number (the table row; EMCY manufacturer byte 3).
    pub const fn number(self) -> u8 {
        self as u8
    }

    /// The fault with this number, if there is one.
    pub fn from_number(number: u8) -> Option<Self> {
        Self::ALL.get(usize::from(number)).copied()
    }

    /// The table row of this fault.
    pub fn info(self) -> &'static FaultInfo {
        // The table has one row per id in discriminant order (checked by the tests), so `get` always finds it;
        // the fallback only keeps this function free of panics.
        FAULT_TABLE.get(usize::from(self.number())).unwrap_or(&FALLBACK)
    }

    /// The row of the fault whose error code is `code`, if any.
    pub fn from_code(code: u16) -> Option<Self> {
        FAULT_TABLE.iter().find(|row| row.code == code).map(|row| row.id)
    }
}

/// Returned by [`FaultId::info`] should the table ever lack a row (tests prove it does not).
static FALLBACK: FaultInfo = row(
    FaultId::InternalSoftware,
    0x6180,
    REG_GENERIC,
    ReactionClass::DisablePowerImmediately,
    Cause::Event,
    Tier::Background,
    SnapshotField::Detail,
    "Internal software error",
    "IDX L7061, L7236",
);

/// A fault row; warnings use [`warning`]. Latching follows from the class: faults latch, warnings and the STO
/// state clear themselves.
#[allow(clippy::too_many_arguments)]
const fn row(
    id: FaultId,
    code: u16,
    register: u8,
    reaction: ReactionClass,
    cause: Cause,
    tier: Tier,
    emcy_field: SnapshotField,
    name: &'static str,
    source: &'static str,
) -> FaultInfo {
    let latch = if reaction.is_fault() { LatchPolicy::Latching } else { LatchPolicy::SelfClearing };
    // The image keeps no text of the table ([`FaultInfo::name`]).
    #[cfg(target_os = "none")]
    let _ = (name, source);
    FaultInfo {
        id,
        code,
        register,
        reaction,
        latch,
        cause,
        tier,
        emcy_field,
        #[cfg(not(target_os = "none"))]
        name,
        #[cfg(not(target_os = "none"))]
        source,
    }
}

/// A warning row: no error-register bit, self-clearing.
const fn warning(
    id: FaultId,
    code: u16,
    cause: Cause,
    tier: Tier,
    emcy_field: SnapshotField,
    name: &'static str,
    source: &'static str,
) -> FaultInfo {
    row(id, code, 0, ReactionClass::Warning, cause, tier, emcy_field, name, source)
}

use Cause::{Event, Level};
use ReactionClass::{AbortConnection as A, DisablePowerImmediately as D, QuickStopThenDisable as F};
use SnapshotField as S;

/// The fault table, one row per [`FaultId`] in discriminant order.
pub static FAULT_TABLE: [FaultInfo; FAULT_COUNT] = [
    row(
        FaultId::OverCurrent,
        0x2310,
        REG_GENERIC | REG_CURRENT,
        D,
        Event,
        Tier::CurrentLoop,
        S::PeakPhaseCurrent,
        "Over-current",
        "IDX L7045, L7140",
    ),
    row(
        FaultId::PowerStageProtection,
        0x2320,
        REG_GENERIC | REG_CURRENT,
        D,
        Level,
        Tier::Hardware,
        S::PeakPhaseCurrent,
        "Power stage protection",
        "IDX L7046, L7148",
    ),
    row(
        FaultId::CurrentLoopOverrun,
        0xFF0B,
        REG_GENERIC,
        D,
        Event,
        Tier::CurrentLoop,
        S::Detail,
        "Current loop overrun",
        "IDX L7094, L7500 (system peak overloaded: not enough resources for proper regulation)",
    ),
    row(
        FaultId::PhaseCurrentImplausible,
        0x2330,
        REG_GENERIC | REG_CURRENT,
        D,
        Event,
        Tier::CurrentLoop,
        S::PhaseCurrentSum,
        "Phase current sum implausible",
        "[BG] CiA 402 0x2330 earth leakage (sum of phase currents); no IDX code",
    ),
    row(
        FaultId::CurrentOffsetCalibration,
        0x5210,
        REG_GENERIC | REG_CURRENT,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Current offset calibration failed",
        "[BG] CiA 402 0x5210 measurement circuit; no IDX code",
    ),
    row(
        FaultId::DcBusOverVoltage,
        0x3210,
        REG_GENERIC | REG_VOLTAGE,
        D,
        Level,
        Tier::CurrentLoop,
        S::BusVoltage,
        "DC bus over-voltage",
        "IDX L7047, L7156",
    ),
    row(
        FaultId::DcBusUnderVoltage,
        0x3220,
        REG_GENERIC | REG_VOLTAGE,
        D,
        Level,
        Tier::CurrentLoop,
        S::BusVoltage,
        "DC bus under-voltage",
        "IDX L7048, L7164",
    ),
    warning(
        FaultId::MotorI2tLimit,
        0xFF80,
        Level,
        Tier::Supervision,
        S::MotorI2tLevel,
        "Motor I2t limit active",
        "manufacturer code; IDX limits the current without an error (L5573-L5578, 0x3200 L5428)",
    ),
    row(
        FaultId::MotorThermalOverload,
        0x4380,
        REG_GENERIC | REG_TEMPERATURE,
        D,
        Level,
        Tier::Supervision,
        S::Detail,
        "Motor thermal overload",
        "IDX L7050, L7180, L5476",
    ),
    warning(
        FaultId::PowerStageTemperatureHigh,
        0xFF81,
        Level,
        Tier::Supervision,
        S::PowerStageTemperature,
        "Power stage temperature high",
        "manufacturer code; warning before IDX 0x4210 (Gamma L910: temperature limit is a warning)",
    ),
    row(
        FaultId::PowerStageOverTemperature,
        0x4210,
        REG_GENERIC | REG_TEMPERATURE,
        D,
        Level,
        Tier::Supervision,
        S::PowerStageTemperature,
        "Power stage over-temperature",
        "IDX L7049, L7172",
    ),
    row(
        FaultId::EncoderSignalLoss,
        0x7380,
        REG_GENERIC | REG_PROFILE,
        D,
        Level,
        Tier::Supervision,
        S::Position,
        "Encoder signal loss",
        "IDX L7065, L7268 (position sensor breach)",
    ),
    row(
        FaultId::EncoderIndexMissing,
        0x7320,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Position,
        "Encoder index missing",
        "IDX L7064, L7260 (position sensor error); E3 L523-L660 names index errors",
    ),
    row(
        FaultId::HallInvalidState,
        0xFF05,
        REG_GENERIC | REG_PROFILE,
        D,
        Level,
        Tier::Supervision,
        S::Detail,
        "Hall sensor invalid state",
        "Gamma L1071 (FF05h invalid Hall state); no IDX code",
    ),
    row(
        FaultId::HallEncoderMismatch,
        0x7122,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Hall and encoder angle mismatch",
        "Gamma L1068 (7122h commutation init); [BG] CiA 402 0x7122 commutation malfunction; no IDX code",
    ),
    row(
        FaultId::FollowingError,
        0x8611,
        REG_GENERIC | REG_MOTION,
        F,
        Event,
        Tier::Supervision,
        S::Detail,
        "Following error",
        "IDX L7088, L7452",
    ),
    row(
        FaultId::SoftwarePositionLimit,
        0x8A82,
        REG_GENERIC | REG_MOTION,
        F,
        Event,
        Tier::Supervision,
        S::Position,
        "Software position limit",
        "IDX L7091, L7476",
    ),
    row(
        FaultId::NegativeLimitSwitch,
        0x8A80,
        REG_GENERIC | REG_MOTION,
        F,
        Event,
        Tier::Supervision,
        S::Position,
        "Negative limit switch",
        "IDX L7089, L7460",
    ),
    row(
        FaultId::PositiveLimitSwitch,
        0x8A81,
        REG_GENERIC | REG_MOTION,
        F,
        Event,
        Tier::Supervision,
        S::Position,
        "Positive limit switch",
        "IDX L7090, L7468",
    ),
    row(
        FaultId::MotorBlocked,
        0x7121,
        REG_GENERIC | REG_MOTION,
        F,
        Event,
        Tier::Supervision,
        S::Velocity,
        "Motor blocked (stall/standstill supervision)",
        "PD4 p.109 (7121h); [BG] CiA 402 0x7121 motor blocked; no IDX code",
    ),
    row(
        FaultId::HeartbeatLost,
        0x8130,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Level,
        Tier::Background,
        S::Detail,
        "Heartbeat lost",
        "IDX L7074, L7340",
    ),
    row(
        FaultId::RxPdoTimeout,
        0x8250,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Level,
        Tier::Supervision,
        S::Detail,
        "RxPDO/SYNC timeout",
        "IDX L7085, L7428",
    ),
    row(
        FaultId::EthercatWatchdog,
        0x8180,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Level,
        Tier::Background,
        S::Detail,
        "EtherCAT link lost / watchdog",
        "IDX L7076, L7356",
    ),
    row(
        FaultId::PdoLength,
        0x8210,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Event,
        Tier::Background,
        S::Detail,
        "PDO length error",
        "IDX L7084, L7420",
    ),
    row(
        FaultId::EthercatSyncError,
        0x8184,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Event,
        Tier::Supervision,
        S::Detail,
        "EtherCAT sync/cycle time error",
        "IDX L7080, L7388",
    ),
    row(
        FaultId::CanSyncLength,
        0x8240,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Event,
        Tier::Background,
        S::Detail,
        "SYNC length error",
        "[BG] CiA 301 0x8240 unexpected SYNC data length; no IDX code",
    ),
    row(
        FaultId::ParameterStoreCorrupt,
        0x6380,
        REG_GENERIC,
        D,
        Event,
        Tier::Boot,
        S::Detail,
        "Parameter store corrupt",
        "IDX L7063, L7252",
    ),
    row(
        FaultId::InternalSoftware,
        0x6180,
        REG_GENERIC,
        D,
        Event,
        Tier::Background,
        S::Detail,
        "Internal software error",
        "IDX L7061, L7236",
    ),
    warning(
        FaultId::EmcyOverflow,
        0xFF90,
        Event,
        Tier::Background,
        S::Detail,
        "EMCY queue overflow",
        "manufacturer code; CiA 301 0x8110 is the CAN controller's overrun (IDX L7071), not this queue",
    ),
    row(
        FaultId::MotorPhaseOpen,
        0x7120,
        REG_GENERIC | REG_CURRENT,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Motor phase open",
        "[BG] CiA 402 0x7120 motor; no IDX code (IDX L7138-L7152 name winding faults only as over-current causes)",
    ),
    row(
        FaultId::CanErrorPassive,
        0x8120,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Level,
        Tier::Background,
        S::Detail,
        "CAN passive mode error",
        "IDX L7073, L7332",
    ),
    row(
        FaultId::CanBusOff,
        0x81FD,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Level,
        Tier::Background,
        S::Detail,
        "CAN bus turned off",
        "IDX L7081, L7396",
    ),
    row(
        FaultId::CanRxOverrun,
        0x8110,
        REG_GENERIC | REG_COMMUNICATION,
        A,
        Event,
        Tier::Background,
        S::Detail,
        "CAN overrun error (object lost)",
        "IDX L7071, L7316",
    ),
    row(
        FaultId::WatchdogReset,
        0xFF02,
        REG_GENERIC,
        D,
        Event,
        Tier::Boot,
        S::Detail,
        "Watchdog error",
        "IDX L7093, L7490 (7.2.48): the independent watchdog reset the device; reported at the next start",
    ),
    // No error-register bit: STO is a state the safety circuit demands, not an error of the drive (the manager
    // keeps it out of 0x1001 and 0x1003).
    row(
        FaultId::SafeTorqueOff,
        0xFFA0,
        0,
        ReactionClass::TorqueOff,
        Level,
        Tier::Supervision,
        S::Detail,
        "Safe torque off active",
        // No seed gives an STO code (module documentation); the state is Gamma's 0x2002 bit 0 (GT L2101).
        "manufacturer code; EPOS4 AN ch. 9 (S1 L8741-8905)",
    ),
    row(
        FaultId::StoDiscrepancy,
        0xFFA1,
        REG_GENERIC,
        D,
        Level,
        Tier::Supervision,
        S::Detail,
        "STO inputs discrepancy",
        // Both inputs carry one demand (S1 Tab. 9-87); the discrepancy time is `supervision::safe_torque_off`'s.
        "manufacturer code; EPOS4 AN ch. 9 Tab. 9-87 (S1 L8890-8905)",
    ),
    warning(
        FaultId::ChopperOverload,
        0x7113,
        Level,
        Tier::Supervision,
        S::Detail,
        "Braking chopper overload",
        "CiA 402 error code 7113h (brake chopper protective circuit); no seed has a chopper; the bus-voltage limiter \
         0x3202 keeps the bus below the trip while the chopper is off",
    ),
    warning(
        FaultId::CanBusOffRecovered,
        0x8140,
        Event,
        Tier::Background,
        S::Detail,
        "Recovered from bus off",
        "CiA 301 EMCY error code 8140h: the node rejoined the bus; the bus-off fault 0x81FD stays until a fault reset",
    ),
    // Motor identification (`drive::auto_setup`): IDX Table 7-153's auto-tuning codes, register 0010 0000b
    // (profile) plus the generic bit, class d. Events: the procedure ended, a fault reset is accepted at once.
    row(
        FaultId::AutoTuningCurrentLimit,
        0xFF12,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning current limit error",
        "IDX L7096, L7514 (7.2.51)",
    ),
    row(
        FaultId::AutoTuningIdentificationCurrent,
        0xFF13,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning identification current error",
        "IDX L7097, L7522 (7.2.52); EPOS3's 0xFF13 (interpolation) is not used: this drive follows IDX",
    ),
    row(
        FaultId::AutoTuningParameter,
        0xFF16,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning parameter error",
        "IDX L7104, L7546 (7.2.55)",
    ),
    row(
        FaultId::AutoTuningTimeout,
        0xFF19,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning timeout error",
        "IDX L7107, L7570 (7.2.58)",
    ),
    row(
        FaultId::AutoTuningStandstill,
        0xFF20,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning standstill error",
        "IDX L7108, L7578 (7.2.59)",
    ),
    row(
        FaultId::AutoTuningTorqueInvalid,
        0xFF21,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning torque invalid error",
        "IDX L7109, L7586 (7.2.60)",
    ),
    row(
        FaultId::AutoTuningMaxSpeed,
        0xFF22,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning max system speed error",
        "IDX L7110, L7594 (7.2.61)",
    ),
    row(
        FaultId::AutoTuningSampleMismatch,
        0xFF15,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Auto tuning sample mismatch error",
        "IDX L7103, L7538 (7.2.54)",
    ),
    row(
        FaultId::SsiSensor,
        0x738C,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::CurrentLoop,
        S::Position,
        "SSI sensor error",
        "IDX L7066, L7276 (7.2.21)",
    ),
    row(
        FaultId::SsiFrame,
        0x738D,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::CurrentLoop,
        S::Position,
        "SSI sensor frame error",
        "IDX L7067, L7284 (7.2.22)",
    ),
    row(
        FaultId::MissingMainSensor,
        0x7390,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Detail,
        "Missing main sensor error",
        "IDX L7068, L7292 (7.2.23)",
    ),
    row(
        FaultId::MissingCommutationSensor,
        0x7391,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::CurrentLoop,
        S::Detail,
        "Missing commutation sensor error",
        "IDX L7069, L7300 (7.2.24)",
    ),
    row(
        FaultId::MainSensorDirection,
        0x7392,
        REG_GENERIC | REG_PROFILE,
        D,
        Event,
        Tier::Supervision,
        S::Velocity,
        "Main sensor direction error",
        "IDX L7070, L7306 (7.2.25); EPOS3 0xFF11 (S0 L1160)",
    ),
];
