//! Tier-2 supervision of the drive's hardware and of the links to it: the detectors that need more than one
//! sample or more than one signal, and that the 25 kHz path cannot afford (ARCHITECTURE "Data flow and timing
//! tiers"; issue 5 "Detection, each in the tier where it belongs").
//!
//! [`crate::drive::Drive::background`] runs [`Supervision::step`] at 2.5 kHz, before the slow tick, with what the
//! last fast tick measured ([`SupervisionInputs`]). Each detector raises and clears its faults in the axis's
//! [`FaultManager`]; the CiA 402 machine takes them in the same slow tick.
//!
//! Module map (one detector per file):
//! - [`thermal`]: power-stage and motor temperature: 0x3201, the warning, the current derating, the trips.
//! - [`feedback`]: encoder and Hall sensors: invalid Hall state, Hall/encoder disagreement, index missing or
//!   displaced, encoder signal loss.
//! - [`direction`]: the motor turning away against the direction the loops drive it (main sensor direction error).
//! - [`stall`]: motor blocked (stall) supervision in the modes where the loops drive the motor.
//! - [`phases`]: motor phase open (a phase that carries no current while the others do).
//! - [`safe_torque_off`]: the STO state and the discrepancy of its two inputs (read by tier 2, stepped by
//!   `Drive::background` after the others).
//! - [`watchdog`]: the rule by which tier 3 feeds the independent watchdog (all three tiers ran).
//! - [`communication`]: the one interface through which the fieldbus layers report communication loss
//!   (heartbeat, RxPDO/SYNC timeout, EtherCAT watchdog, ...), and the process-data watchdog they share.

pub mod communication;
pub mod direction;
pub mod feedback;
pub mod phases;
pub mod safe_torque_off;
pub mod stall;
pub mod thermal;
pub mod watchdog;

use crate::cia402::{State, Ticks};
use crate::control::angle::ElectricalAngle;
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::control::trajectory::Velocity;
use crate::fault::snapshot::DiagnosisSnapshot;
use crate::fault::FaultManager;
use crate::od::access::Dictionary;
use crate::power_state::{CommutationStage, PowerState};

/// What the drive hands the supervision every slow tick: the last fast tick's measurements and the axis's state.
#[derive(Clone, Copy, Debug)]
pub struct SupervisionInputs {
    /// Tier-2 time.
    pub now: Ticks,
    /// The CiA 402 state.
    pub state: State,
    /// The power stage switches with the current loop running (CiA 402 «Operation enabled» with the outputs on).
    pub operation_enabled: bool,
    /// The power-stage state of the drive: [`PowerState::Calibrating`], [`PowerState::SwitchedOn`] and
    /// [`PowerState::OperationEnabled`] are the states in which the power stage is powered (also when the
    /// power stage is driven directly, without the controlword); entering [`PowerState::Calibrating`] (switch-on)
    /// may restart the encoder's position at 0 (`Drive::switch_on` re-reads the sensor configuration).
    pub power: PowerState,
    /// The velocity or position loops produce the current demand (PPM, PVM, HMM, CSP, CSV and the stops ramped
    /// on them; not CST, not disabled).
    pub loops_drive_motor: bool,
    /// Raw 12-bit power-stage temperature sample of the last fast tick.
    pub power_stage_temperature_code: u16,
    /// Raw 12-bit motor temperature sample of the last fast tick.
    pub motor_temperature_code: u16,
    /// Hall state after inversion (0x301A:02), bit 0 = H1.
    pub hall: u8,
    /// Halls are the configured commutation sensor (0x3000:01 / commutation method).
    pub halls_present: bool,
    /// An incremental encoder is configured (0x3000:01 sensor 1).
    pub encoder_present: bool,
    /// The encoder has an index channel (0x3010).
    pub encoder_has_index: bool,
    /// Encoder position (tier-1 count, wrapping increments; quadrature counts).
    pub encoder_position: i32,
    /// Encoder increments per mechanical turn (quadrature counts).
    pub encoder_counts_per_turn: u32,
    /// Motor pole pairs (0x3001:03).
    pub pole_pairs: u8,
    /// Index pulses latched since start-up (wrapping at 2^16; counted in every power state, like `index_position`).
    pub index_pulses: u32,
    /// Encoder position at the latest index pulse.
    pub index_position: i32,
    /// The electrical angle tier 1 commutates with.
    pub electrical_angle: ElectricalAngle,
    /// Electrical offset of the Hall sectors (0x301A / commutation configuration).
    pub hall_offset: ElectricalAngle,
    /// Commutation stage (valid angle or not).
    pub commutation: CommutationStage,
    /// Calibrated phase currents of the last fast tick.
    pub i_abc: Abc<Amps>,
    /// Measured d/q currents.
    pub i_dq: Dq<Amps>,
    /// d/q current reference.
    pub i_ref: Dq<Amps>,
    /// Applied d/q voltage.
    pub v_dq: Dq<Volts>,
    /// The voltage limit was active in the last fast tick.
    pub saturated: bool,
    /// DC-bus voltage.
    pub v_bus: Volts,
    /// The current limit in force before the thermal derating (0x6073/0x3001:02 with the I2t limit).
    pub current_limit: Amps,
    /// The axis's velocity estimate (increments per slow tick, Q32).
    pub velocity: Velocity,
    /// The axis's velocity estimate in rpm (for snapshots and thresholds in dictionary units).
    pub velocity_rpm: i32,
}

impl SupervisionInputs {
    /// The diagnosis data of a detection now, with the detector's own value in `detail`.
    #[must_use]
    pub fn snapshot(&self, detail: i32) -> DiagnosisSnapshot {
        DiagnosisSnapshot {
            phase_currents_ma: [self.i_abc.a.to_milliamps(), self.i_abc.b.to_milliamps(), self.i_abc.c.to_milliamps()],
            bus_voltage_mv: self.v_bus.to_millivolts(),
            position_inc: self.encoder_position,
            velocity_rpm: self.velocity_rpm,
            state: self.state,
            tick: self.now,
            detail,
            ..DiagnosisSnapshot::EMPTY
        }
    }
}

#[cfg(test)]
impl SupervisionInputs {
    /// The reference drive (4,096 counts per turn, 7 pole pairs, Halls and an indexed encoder, 10 A limit, 24 V bus)
    /// in «Operation enabled» with the loops driving the motor, at rest and without current: the base each
    /// detector's unit tests vary.
    pub(crate) fn reference_running() -> Self {
        Self {
            now: Ticks(0),
            state: State::OperationEnabled,
            operation_enabled: true,
            power: PowerState::OperationEnabled,
            loops_drive_motor: true,
            power_stage_temperature_code: 0,
            motor_temperature_code: 0,
            hall: 0b101,
            halls_present: true,
            encoder_present: true,
            encoder_has_index: true,
            encoder_position: 0,
            encoder_counts_per_turn: 4096,
            pole_pairs: 7,
            index_pulses: 0,
            index_position: 0,
            electrical_angle: ElectricalAngle::ZERO,
            hall_offset: ElectricalAngle::ZERO,
            commutation: CommutationStage::Indexed,
            i_abc: Abc::default(),
            i_dq: Dq::default(),
            i_ref: Dq::default(),
            v_dq: Dq::default(),
            saturated: false,
            v_bus: Volts::from_millivolts(24_000),
            current_limit: Amps::from_milliamps(10_000),
            velocity: Velocity::ZERO,
            velocity_rpm: 0,
        }
    }
}

/// What the supervision asks of the drive after a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SupervisionOutputs {
    /// Current limit of the thermal derating (`Amps::from_bits(i32::MAX)` when none applies).
    pub current_limit: Amps,
}

/// Every tier-2 hardware detector. See the module documentation.
#[derive(Clone, Debug)]
pub struct Supervision {
    /// Temperatures, warning, derating, trips.
    pub thermal: thermal::ThermalSupervision,
    /// Encoder and Hall sensors.
    pub feedback: feedback::FeedbackSupervision,
    /// Motor blocked.
    pub stall: stall::StallSupervision,
    /// Motor turning away against its torque.
    pub direction: direction::DirectionSupervision,
    /// Motor phase open.
    pub phases: phases::PhaseSupervision,
    /// Safe Torque Off state and input discrepancy.
    pub safe_torque_off: safe_torque_off::StoSupervision,
}

impl Supervision {
    /// The detectors over the parameters of `d`.
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        Self {
            thermal: thermal::ThermalSupervision::new(d),
            feedback: feedback::FeedbackSupervision::new(d),
            stall: stall::StallSupervision::new(d),
            direction: direction::DirectionSupervision::default(),
            phases: phases::PhaseSupervision::new(d),
            safe_torque_off: safe_torque_off::StoSupervision::default(),
        }
    }

    /// Re-reads the parameters that changed (run before each step, outside its budget).
    pub fn refresh(&mut self, d: &Dictionary) {
        self.thermal.refresh(d);
        self.feedback.refresh(d);
        self.stall.refresh(d);
        self.phases.refresh(d);
    }

    /// One slow tick of every detector; writes what they publish (0x3201) into `d`.
    pub fn step(
        &mut self,
        inputs: &SupervisionInputs,
        faults: &mut FaultManager,
        d: &mut Dictionary,
    ) -> SupervisionOutputs {
        let current_limit = self.thermal.step(inputs, faults, d);
        self.feedback.step(inputs, faults);
        self.stall.step(inputs, faults);
        let supervised = self.feedback.main_sensor_supervised();
        self.direction.step(inputs, supervised, self.stall.speed_threshold_rpm(), faults);
        self.phases.step(inputs, faults);
        SupervisionOutputs { current_limit }
    }
}
