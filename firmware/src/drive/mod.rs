//! The drive: ties the current loop, offset calibration, commutation, protection and the object dictionary together;
//! the tier-1 entry point [`Drive::fast_tick`] and the tier-2 hook [`Drive::slow_tick`].
//!
//! # Tiers (`shared/design/ARCHITECTURE.md`, "Data flow and timing tiers")
//! - [`Drive::fast_tick`], 25 kHz: measurements in, PWM command out. Protection step, ADC scaling, commutation
//!   angle, the d/q current loop ([`crate::control::current_loop`]) with the reference read from the dictionary by
//!   typed handle, and the slow-tick divider: it returns [`FastTick::slow_tick_due`] every
//!   [`crate::hal::power::SLOW_TICK_DIVIDER`]-th tick. On the target the runtime pends tier 2 when it is set; on
//!   the host the caller (the simulation) calls [`Drive::slow_tick`] directly. No searches, no divisions, no
//!   loops, no panics.
//! - [`Drive::slow_tick`], 2.5 kHz: publishes the actual values (0x30D1, 0x6077, 0x6078, 0x30D0, 0x6074, averaged
//!   values, DC link voltage, Hall pattern, index position) and re-reads the parameters tier 1 uses (current gains
//!   0x30A0, motor data 0x3001, limits 0x6072/0x6073) when they change. The motion issue adds the velocity and
//!   position loops here, with their output as the current demand ([`DemandSource::Internal`]).
//!
//! # Power-stage path (CiA 402 transitions 3 and 4, `shared/spec/cia402-device-control.md`)
//! [`Drive::switch_on`] (transition 3) reads the power-disabled parameters (encoder, pole pairs, Halls,
//! commutation method) and starts the current-offset calibration with the outputs at 50 % duty; the drive is
//! [`PowerState::SwitchedOn`] when it finishes. [`Drive::enable_operation`] (transition 4) starts the commutation
//! (Hall sector, or forced alignment) and the current loop. [`Drive::disable_operation`] (transition 5) and
//! [`Drive::shutdown`] (6/8) switch the outputs off. The CiA 402 state machine of the next issue calls these; a
//! fault latches [`PowerState::Fault`] with a typed [`DriveError`] until [`Drive::fault_reset`].
//! The outputs are `PwmCommand::OFF` in every state except calibration and operation enabled.
//!
//! # Ownership
//! The drive owns the [`Dictionary`] (table + value storage). The control tiers read and write it through the
//! generated typed handles (no search); SDO and PDO code reach it through [`Drive::dictionary`] and
//! [`Drive::dictionary_mut`]. One owner keeps the single-writer rule of each value visible: the drive writes the
//! actual values and derived objects (0x6075, 0x6076), everyone else the set-points and parameters.
//!
//! What tier 1 owns is one value, [`tier1::Tier1State`] (power-stage state, calibration, commutation, current
//! controller, limits in force, latches and sums, trip sample, divider), and what tier 2 decides for its current
//! reference another, [`tier1::DemandCommand`]; the power-stage requests above are `Tier1State` methods. These are
//! the shapes the tier split hands across (`docs/design/tier-ownership.md`); today the drive holds both, and the
//! tier-2 code still reads tier 1's fields directly.

pub mod calibration;
pub mod commutation;
pub mod hall_position;
pub mod objects;
pub mod protection;
pub mod scaling;
pub mod tier1;

use crate::control::angle::ElectricalAngle;
use crate::control::current_loop::{CurrentController, CurrentLoopConfig};
use crate::control::demand::{rated_torque_micro_nm, DemandScale};
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::control::pi::PiGains;
use crate::fault::emcy::InhibitTime;
use crate::fault::table::FaultId;
use crate::hal::power::{Measurements, PwmCommand};
use crate::motion::axis::{Axis, AxisInputs, AxisOutputs, CurrentDemand};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::power_state::{DriveError, PowerState};
use crate::sensors::hall::HallSector;
use crate::sensors::latch::PinLatches;
use crate::supervision::communication::LinkLoss;
use crate::supervision::{Supervision, SupervisionInputs};

use calibration::CalibrationConfig;
use commutation::{hall_offset_from_od, AlignmentConfig, Commutation, CommutationMethod, EncoderConfig};
use protection::Limits;
use scaling::ShuntOffsets;
use tier1::{DemandCommand, Tier1State};

/// Why a power-stage request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestError {
    /// The request is not allowed in the present state (e.g. enable before the calibration has finished).
    WrongState(PowerState),
}

/// Where the q-current reference comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DemandSource {
    /// Target torque 0x6071 + torque offset 0x60B2 (CST), read every fast tick.
    TargetTorque,
    /// A current set by tier 2 through [`Drive::set_current_demand`] (the velocity and position loops).
    Internal,
}

/// Construction-time configuration that has no dictionary object (yet).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriveConfig {
    /// Node-ID for the dictionary's node-relative defaults.
    pub node_id: u8,
    /// Offset calibration parameters.
    pub calibration: CalibrationConfig,
    /// Forced-alignment parameters, used when 0x3000:01 configures no Hall sensor.
    pub alignment: AlignmentConfig,
    /// The electrical angle at the encoder index, if known, for when 0x3010:05 does not give it (-1); without
    /// either the drive learns it at the first index pulse after a Hall edge or an alignment.
    pub index_offset: Option<ElectricalAngle>,
}

impl DriveConfig {
    /// Defaults for the reference drive at node 1.
    pub const DEFAULT: Self = Self {
        node_id: 1,
        calibration: CalibrationConfig::DEFAULT,
        alignment: AlignmentConfig::REFERENCE,
        index_offset: None,
    };
}

impl Default for DriveConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The result of one fast tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FastTick {
    /// The command for the next PWM period.
    pub pwm: PwmCommand,
    /// A slow tick is due now: the runtime pends tier 2 (target), or the caller runs [`Drive::slow_tick`] (host).
    pub slow_tick_due: bool,
}

/// What the last fast tick measured and commanded (for the slow tick, the simulation's traces and diagnostics).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FastSignals {
    /// Calibrated phase currents.
    pub i_abc: Abc<Amps>,
    /// Measured d/q currents (zero while the current loop is not running).
    pub i_dq: Dq<Amps>,
    /// The d/q current reference.
    pub i_ref: Dq<Amps>,
    /// The applied d/q voltage (after the limit).
    pub v_dq: Dq<Volts>,
    /// DC-bus voltage.
    pub v_bus: Volts,
    /// The voltage limit was active.
    pub saturated: bool,
    /// Torque demand in per mille (0x6074).
    pub torque_demand_permille: i16,
    /// Hall state after inversion (0x301A:02).
    pub hall: u8,
    /// Raw power-stage and motor temperature samples (for tier 2's thermal supervision).
    pub temperature_codes: [u16; 2],
}

/// Raw motor data and limits (0x3001:01/:02/:05, 0x6073, 0x6072) last converted into the demand scale.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct MotorSource {
    nominal_ma: u32,
    output_limit_ma: u32,
    max_current_permille: u16,
    max_torque_permille: u16,
    torque_constant: u32,
}

/// Raw 0x30A0 values last converted into gains.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct GainSource {
    p: u32,
    i: u32,
}

/// The drive. See the module documentation.
#[derive(Clone, Debug)]
// `repr(C)` with the tier-1 fields first: on the Cortex-M4 a load or store reaches 4 KiB from a base register in one
// instruction, so the fields the 25 kHz path touches sit at the start, ahead of the dictionary and tier 2's state
// (measured in the QEMU image: 608 -> 548 instructions in the worst fast tick).
#[repr(C)]
pub struct Drive {
    /// Tier 1's state: first, so that the 25 kHz path reaches its fields with short offsets from the drive's base.
    t1: Tier1State,
    /// Tier 2's decision for tier 1's current reference.
    demand: DemandCommand,
    /// The scale from the dictionary, before the I2t limit.
    base_scale: DemandScale,
    /// The I2t protection's current limit (tier 2).
    i2t_limit: Amps,
    config: DriveConfig,
    gain_source: GainSource,
    /// 50 Hz low-pass states (`I16F16` bits) of the q current and the bus voltage.
    i_q_average: i32,
    v_bus_average: i32,
    /// The machine's last power-stage request, to act on its changes.
    last_power_request: crate::cia402::PowerStage,
    /// Output pin levels from tier 2.
    output_pins: u8,
    /// Tier 2: the CiA 402 machine, the modes, the loops and the motion supervision.
    axis: Axis,
    dictionary: Dictionary,
    // Tier 2's background step only, after the dictionary: the slow tick reaches the dictionary and the axis
    // with short offsets from the drive's base (measured: 3,976 -> 4,044 instructions with these in between).
    /// The hardware detectors (temperatures, position sensors, stall, phases).
    supervision: Supervision,
    /// The thermal derating's current limit.
    thermal_limit: Amps,
    /// The motor data the demand scale was converted from (`None`: not yet).
    motor_source: Option<MotorSource>,
}

impl Drive {
    /// A drive with the generated dictionary's defaults, outputs off. [`Drive::boot`] starts from the stored
    /// parameters instead.
    #[must_use]
    pub fn new(config: DriveConfig) -> Self {
        Self::with_dictionary(config, Dictionary::new(config.node_id))
    }

    /// A drive over `dictionary` (the defaults with the stored parameters applied, see [`objects`]), outputs off.
    #[must_use]
    pub fn with_dictionary(config: DriveConfig, dictionary: Dictionary) -> Self {
        let gain_source = GainSource {
            p: dictionary.get(h::CURRENT_CONTROLLER_P_GAIN),
            i: dictionary.get(h::CURRENT_CONTROLLER_I_GAIN),
        };
        let mut drive = Self {
            t1: Tier1State::new(
                config.calibration,
                Commutation::new(
                    CommutationMethod::Hall,
                    EncoderConfig::REFERENCE,
                    ElectricalAngle::ZERO,
                    config.index_offset,
                ),
                CurrentController::new(CurrentLoopConfig::from_idx_0x30a0(gain_source.p, gain_source.i)),
            ),
            demand: DemandCommand {
                source: DemandSource::TargetTorque,
                internal: Amps::ZERO,
                scale: DemandScale::reference(),
            },
            config,
            gain_source,
            motor_source: None,
            base_scale: DemandScale::reference(),
            i2t_limit: Amps::from_bits(i32::MAX),
            i_q_average: 0,
            v_bus_average: 0,
            axis: Axis::new(&dictionary),
            supervision: Supervision::new(&dictionary),
            thermal_limit: Amps::from_bits(i32::MAX),
            last_power_request: crate::cia402::PowerStage::OFF,
            output_pins: 0,
            dictionary,
        };
        drive.configure_commutation();
        drive.refresh_parameters();
        drive
    }

    // ---------------------------------------------------------------------------------------------------------
    // Tier 1
    // ---------------------------------------------------------------------------------------------------------

    /// One 25 kHz tick ([`Tier1State::fast_tick`]): protection, scaling, angle, current loop; the command for the
    /// next PWM period and whether a slow tick is due. Never panics; `PwmCommand::OFF` whenever the drive is not
    /// calibrating or enabled.
    #[inline]
    pub fn fast_tick(&mut self, m: &Measurements) -> FastTick {
        self.t1.fast_tick(m, &self.demand, &self.dictionary)
    }

    // ---------------------------------------------------------------------------------------------------------
    // Tier 2
    // ---------------------------------------------------------------------------------------------------------

    /// Converts the parameters that changed since the last call into the units the tiers use (current gains
    /// 0x30A0, motor data and limits, and the axis's motion parameters, gains, monitoring limits and brake
    /// timing), applies the I2t current limit, and publishes the actual values (0x6077, 0x6078, 0x30D1, 0x30D2,
    /// 0x6079, 0x3200:01, ...). Tier 2 runs it before each [`Self::slow_tick`] (its cost is reported separately: it compares the
    /// raw values every time, and converts, with 64- and 128-bit arithmetic, only what changed).
    pub fn background(&mut self) {
        self.refresh_parameters();
        self.publish_actual_values();
        self.axis.refresh(&mut self.dictionary);
        // 0x1015 EMCY inhibit time (CiA 301), taken over when it changes.
        let inhibit = InhibitTime(self.dictionary.get(h::INHIBIT_TIME_EMCY));
        if inhibit != self.axis.faults().emcy().inhibit_time() {
            self.axis.faults_mut().emcy_mut().set_inhibit_time(inhibit);
        }
        self.supervision.refresh(&self.dictionary);
        let inputs = self.supervision_inputs();
        let supervised = self.supervision.step(&inputs, self.axis.faults_mut(), &mut self.dictionary);
        // The I2t protection's and the thermal derating's current limits (applied one slow tick after the models
        // decided them: far inside the winding's and the heat sink's thermal time constants).
        let i2t_limit = Amps::from_milliamps(i32::try_from(self.axis.i2t_current_limit_ma()).unwrap_or(i32::MAX));
        if i2t_limit != self.i2t_limit || supervised.current_limit != self.thermal_limit {
            self.i2t_limit = i2t_limit;
            self.thermal_limit = supervised.current_limit;
            self.demand.scale = self.limited_scale(self.base_scale);
        }
    }

    /// `scale` with the current limits of the protections in force: I2t and thermal derating.
    fn limited_scale(&self, scale: DemandScale) -> DemandScale {
        scale.limited_to(self.i2t_limit).limited_to(self.thermal_limit)
    }

    /// What the supervision reads: the last fast tick's measurements and the axis's state.
    fn supervision_inputs(&self) -> SupervisionInputs {
        let s = &self.t1.signals;
        let encoder = self.t1.commutation.encoder();
        SupervisionInputs {
            now: self.axis.now(),
            state: self.axis.state(),
            operation_enabled: self.t1.state == PowerState::OperationEnabled,
            power: self.t1.state,
            loops_drive_motor: self.t1.state == PowerState::OperationEnabled
                && self.demand.source == DemandSource::Internal,
            power_stage_temperature_code: s.temperature_codes[0],
            motor_temperature_code: s.temperature_codes[1],
            hall: s.hall,
            halls_present: self.t1.commutation.method() == CommutationMethod::Hall,
            encoder_present: self.t1.encoder_present,
            encoder_has_index: encoder.config().has_index,
            encoder_position: encoder.position(),
            encoder_counts_per_turn: encoder.config().counts_per_rev,
            pole_pairs: encoder.config().pole_pairs,
            // The latch counts every index pulse (the commutation only those while it runs): the same source as
            // `index_position`, so the feedback supervision sees the pulses in every state.
            index_pulses: u32::from(self.t1.latches.index.count),
            index_position: self.t1.latches.index.position,
            electrical_angle: self.t1.commutation.angle(),
            hall_offset: self.t1.commutation.hall_offset(),
            commutation: self.t1.commutation.stage(),
            i_abc: s.i_abc,
            i_dq: s.i_dq,
            i_ref: s.i_ref,
            v_dq: s.v_dq,
            saturated: s.saturated,
            v_bus: s.v_bus,
            // Before the thermal derating: the derating is relative to it and must not see its own output.
            current_limit: self.base_scale.limited_to(self.i2t_limit).current_limit(),
            velocity: self.axis.velocity(),
            velocity_rpm: self.dictionary.get(h::VELOCITY_ACTUAL_VALUE),
        }
    }

    /// The runtime measured a fast tick over its budget (the 40 us period cannot be kept): the power stage goes
    /// off now, as for any tier-1 trip (issue 5: "PWM/current-loop overrun" in tier 1), and the axis reports
    /// 0xFF0B with `cost` as its detail.
    #[cold]
    pub fn current_loop_overrun(&mut self, cost: u32) -> PwmCommand {
        self.t1.current_loop_overrun(cost)
    }

    /// The runtime found `missed` slow ticks that could not run because the previous one had not finished: the
    /// velocity and position loops lost their period, so the drive reports 0xFF0B (IDX L7500 "not enough
    /// resources for proper regulation"; detail = minus the ticks missed, to tell it from a current-loop overrun)
    /// and reacts as the table says.
    pub fn motion_loop_overrun(&mut self, missed: u32) {
        let detail = i32::try_from(missed).unwrap_or(i32::MAX).wrapping_neg();
        self.raise(FaultId::CurrentLoopOverrun, detail);
    }

    /// A firmware invariant did not hold (0x6180, IDX L7236); `detail` says which (documented where it is
    /// raised). The power stage goes off as the table's class "d" says.
    pub fn internal_error(&mut self, detail: i32) {
        self.raise(FaultId::InternalSoftware, detail);
    }

    /// A fieldbus layer lost its link (heartbeat, RxPDO/SYNC timeout, EtherCAT watchdog, wrong lengths): the
    /// communication fault of the table, with the reaction 0x6007 selects ([`crate::supervision::communication`]).
    pub fn communication_lost(&mut self, loss: LinkLoss) {
        self.raise(loss.fault(), loss.detail());
    }

    /// The link of an earlier [`Self::communication_lost`] is back: the fault's cause has gone, so a fault reset is
    /// accepted from now on (the fault itself stays until then).
    pub fn communication_restored(&mut self, loss: LinkLoss) {
        self.axis.faults_mut().clear_cause(loss.fault());
    }

    /// The next EMCY frame to send (CiA 301, 8 bytes; [`crate::fault::emcy`]), respecting the inhibit time
    /// 0x1015. The fieldbus layers call it from tier 3 and send it on their bus (CANopen: COB-ID 0x1014; CoE:
    /// a mailbox emergency).
    pub fn poll_emcy(&mut self) -> Option<[u8; 8]> {
        let now = self.axis.now();
        self.axis.faults_mut().poll_emcy(now)
    }

    /// Raises a fault found while booting (the parameter store), with `detail`.
    pub(crate) fn raise_boot_fault(&mut self, id: FaultId, detail: i32) {
        self.raise(id, detail);
    }

    /// Raises `id` with a snapshot of what the drive measures now. A fault of class "d" raised from outside the
    /// tiers' own steps (the runtime, a fieldbus layer) switches the outputs off here and now, not at the next slow
    /// tick: the class means "a secure movement is no longer possible" (IDX L7030).
    fn raise(&mut self, id: FaultId, detail: i32) {
        let snapshot = self.supervision_inputs().snapshot(detail);
        let now = self.axis.now();
        self.axis.faults_mut().raise(id, snapshot, now);
        if id.info().reaction == crate::fault::table::ReactionClass::DisablePowerImmediately {
            self.shutdown();
        }
    }

    /// The hardware detectors (temperatures, position sensors, stall, phases).
    #[must_use]
    pub const fn supervision(&self) -> &Supervision {
        &self.supervision
    }

    /// The 2.5 kHz hook: updates the averages and runs the CiA 402 axis (state machine, modes, loops, monitoring)
    /// with the parameters [`Self::background`] converted. Called after every
    /// [`crate::hal::power::SLOW_TICK_DIVIDER`]-th fast tick (see [`FastTick::slow_tick_due`]).
    pub fn slow_tick(&mut self) {
        self.update_averages();
        // A fault reports what the tripping tick measured, not what came after.
        let fault = match self.t1.state {
            PowerState::Fault(e) => Some(e),
            _ => None,
        };
        let s = if fault.is_some() { self.t1.trip_sample } else { self.t1.signals };
        let power_fault_present = match fault {
            Some(DriveError::Protection(t)) => {
                protection::cause_present(t, self.t1.last_break_input, self.t1.signals.v_bus.to_millivolts())
            }
            // Tier 1 keeps sampling the Halls in «Fault»: the invalid state persists while they still read it.
            Some(DriveError::Commutation(_)) => HallSector::from_state(self.t1.signals.hall).is_err(),
            _ => false,
        };
        let input = AxisInputs {
            encoder_position: if self.t1.encoder_present {
                self.t1.commutation.encoder().position()
            } else {
                self.t1.hall_position.position()
            },
            encoder_window: self.t1.encoder_present.then(|| self.t1.position_sum.latched()),
            current: s.i_dq.q,
            current_average_ma: Amps::from_bits(self.i_q_average).to_milliamps(),
            phase_currents_ma: [s.i_abc.a.to_milliamps(), s.i_abc.b.to_milliamps(), s.i_abc.c.to_milliamps()],
            bus_voltage_mv: s.v_bus.to_millivolts(),
            pins: &self.t1.latches,
            power: self.t1.state,
            power_fault_present,
            scale: &self.demand.scale,
        };
        let out = self.axis.step(&input, &mut self.dictionary);
        self.apply(&out);
    }

    /// Carries out the axis's requests on the power stage. Requests are acted on when they change; outside
    /// «Switch on disabled» (and «Not ready to switch on») the power-stage state is also held to the request
    /// every step, so a power stage driven directly through [`Self::switch_on`] and friends (commissioning
    /// without a fieldbus master, the current-loop tests) keeps working until the controlword takes over.
    fn apply(&mut self, out: &AxisOutputs) {
        use crate::cia402::State;
        if out.fault_reset {
            self.fault_reset();
        }
        let changed = out.power != self.last_power_request || out.start_calibration;
        let enforce = !matches!(out.state, State::SwitchOnDisabled | State::NotReadyToSwitchOn);
        self.last_power_request = out.power;
        if changed || enforce {
            if !out.power.enabled {
                if !matches!(self.t1.state, PowerState::Off | PowerState::Fault(_)) {
                    self.shutdown();
                }
            } else if out.start_calibration {
                // Refused only in a fault or while calibrating: the machine then waits (and the fault is reported).
                let _ = self.switch_on();
            } else if out.power.controllers_enabled {
                if self.t1.state == PowerState::SwitchedOn {
                    let _ = self.enable_operation();
                }
            } else if self.t1.state == PowerState::OperationEnabled {
                self.disable_operation();
            }
        }
        match out.demand {
            CurrentDemand::Off => {}
            CurrentDemand::Internal(i) => {
                self.demand.source = DemandSource::Internal;
                self.set_current_demand(i);
            }
            CurrentDemand::TargetTorque => self.demand.source = DemandSource::TargetTorque,
        }
        self.output_pins = out.output_pins;
    }

    /// A master set-point arrived (CANopen SYNC with its RPDOs, EtherCAT SM2 event or SYNC0): the cyclic modes
    /// latch 0x607A, 0x60FF, 0x6071 and the offsets now.
    pub fn setpoint_received(&mut self) {
        self.axis.setpoint_received(&self.dictionary);
    }

    /// Statusword bit 9 "remote" (the fieldbus layer: NMT operational, EtherCAT SafeOp/Op).
    pub fn set_remote(&mut self, remote: bool) {
        self.axis.set_remote(remote);
    }

    /// Converts 0x30A0 into gains when it changed, and the motor data into the demand scale.
    fn refresh_parameters(&mut self) {
        let d = &mut self.dictionary;
        let gains = GainSource { p: d.get(h::CURRENT_CONTROLLER_P_GAIN), i: d.get(h::CURRENT_CONTROLLER_I_GAIN) };
        if gains != self.gain_source {
            self.gain_source = gains;
            let g = PiGains::from_idx_0x30a0(gains.p, gains.i);
            self.t1.controller.set_gains(g, g);
        }
        let motor = MotorSource {
            nominal_ma: d.get(h::MOTOR_NOMINAL_CURRENT),
            output_limit_ma: d.get(h::MOTOR_OUTPUT_CURRENT_LIMIT),
            max_current_permille: d.get(h::MAX_CURRENT),
            max_torque_permille: d.get(h::MAX_TORQUE),
            torque_constant: d.get(h::MOTOR_TORQUE_CONSTANT),
        };
        // The conversion divides in 64 bits: only when a value changed (tier 2 runs this every slow tick).
        if self.motor_source == Some(motor) {
            return;
        }
        self.motor_source = Some(motor);
        let nominal = motor.nominal_ma;
        self.t1.limits = Limits::new(motor.output_limit_ma);
        let scale =
            DemandScale::from_od(nominal, motor.output_limit_ma, motor.max_current_permille, motor.max_torque_permille);
        self.base_scale = scale;
        // 0x6075 and 0x6076 are read-only copies derived from 0x3001 (single writer: the drive).
        d.set(h::MOTOR_RATED_CURRENT, nominal);
        d.set(h::MOTOR_RATED_TORQUE, rated_torque_micro_nm(nominal, motor.torque_constant));
        // The protections' limits stay in force across the re-read (the thermal derating's would otherwise hold
        // only in the slow tick it changed).
        self.demand.scale = self.limited_scale(scale);
    }

    /// Updates the 50 Hz averages of the q current and the bus voltage (0x30D1:01, 0x30D2:01, homing -1..-4).
    fn update_averages(&mut self) {
        let s = &self.t1.signals;
        // First-order low-pass y += (x - y) / 8 at 2.5 kHz: cut-off 1/8 * 2500 / (2 pi) = 49.7 Hz, the 50 Hz of
        // IDX 0x30D1:01 / 0x30D2:01 (spec §1.3). |x|, |y| < 2^30: no wrap.
        self.i_q_average = self.i_q_average.wrapping_add(s.i_dq.q.to_bits().wrapping_sub(self.i_q_average) >> 3);
        self.v_bus_average = self.v_bus_average.wrapping_add(s.v_bus.to_bits().wrapping_sub(self.v_bus_average) >> 3);
    }

    /// Writes the actual values of the last fast tick and their averages into the dictionary (run by
    /// [`Self::background`] at the start of each slow period, so a TxPDO sampled in the slow tick carries them).
    fn publish_actual_values(&mut self) {
        let s = self.t1.signals;
        let i_q = s.i_dq.q;
        let avg = Amps::from_bits(self.i_q_average);
        let d = &mut self.dictionary;
        d.set(h::CURRENT_ACTUAL_VALUE, i_q.to_milliamps());
        d.set(h::CURRENT_ACTUAL_VALUE_AVERAGED, avg.to_milliamps());
        d.set(h::CURRENT_DEMAND_VALUE, s.i_ref.q.to_milliamps());
        d.set(h::TORQUE_DEMAND_VALUE, s.torque_demand_permille);
        let permille = self.demand.scale.current_to_permille(i_q);
        d.set(h::CURRENT_ACTUAL_VALUE_PER_MILLE, permille);
        d.set(h::TORQUE_ACTUAL_VALUE, permille);
        d.set(h::TORQUE_ACTUAL_VALUE_AVERAGED, self.demand.scale.current_to_permille(avg));
        let mv = Volts::from_bits(self.v_bus_average).to_millivolts().max(0);
        d.set(h::DC_LINK_CIRCUIT_VOLTAGE, mv.unsigned_abs());
        d.set(h::POWER_SUPPLY_VOLTAGE, u16::try_from(mv / 100).unwrap_or(u16::MAX));
        d.set(h::HALL_PATTERN, s.hall);
        if let Some(latch) = self.t1.commutation.last_index_latch() {
            d.set(h::ENCODER_INDEX_POSITION, u32::from(latch));
        }
    }

    // ---------------------------------------------------------------------------------------------------------
    // Power-stage requests (called by the CiA 402 state machine)
    // ---------------------------------------------------------------------------------------------------------

    /// CiA 402 transition 3 "switch on": reads the power-disabled parameters and starts the current-offset
    /// calibration (outputs at 50 % duty); the state becomes [`PowerState::SwitchedOn`] when it succeeds (within
    /// `CalibrationConfig::timeout_ticks`), or [`PowerState::Fault`] when it fails.
    pub fn switch_on(&mut self) -> Result<(), RequestError> {
        match self.t1.state {
            PowerState::Off | PowerState::SwitchedOn => {
                self.configure_commutation();
                self.refresh_parameters();
                self.t1.begin_calibration(self.config.calibration);
                Ok(())
            }
            other => Err(RequestError::WrongState(other)),
        }
    }

    /// CiA 402 transition 4 "enable operation": starts the commutation (from the next fast tick's sensors) and the
    /// current loop with empty integrators.
    pub fn enable_operation(&mut self) -> Result<(), RequestError> {
        match self.t1.state {
            PowerState::SwitchedOn => {
                self.t1.enable_operation();
                Ok(())
            }
            PowerState::OperationEnabled => Ok(()),
            other => Err(RequestError::WrongState(other)),
        }
    }

    /// CiA 402 transition 5 "disable operation": outputs off, stays calibrated.
    pub fn disable_operation(&mut self) {
        self.t1.disable_operation();
    }

    /// CiA 402 transitions 6/8/9 "shutdown"/"disable voltage": outputs off, calibration to be redone at the next
    /// switch-on. A latched fault stays latched.
    pub fn shutdown(&mut self) {
        self.t1.shutdown();
    }

    /// CiA 402 transition 15 "fault reset": back to [`PowerState::Off`].
    pub fn fault_reset(&mut self) {
        self.t1.fault_reset();
    }

    /// Selects where the q-current reference comes from.
    pub fn set_demand_source(&mut self, source: DemandSource) {
        self.demand.source = source;
    }

    /// The q-current demand for [`DemandSource::Internal`] (tier 2's velocity/position loops), clamped to the
    /// current limit.
    pub fn set_current_demand(&mut self, i_q: Amps) {
        let limit = self.demand.scale.current_limit().to_bits();
        self.demand.internal = Amps::from_bits(i_q.to_bits().clamp(limit.wrapping_neg(), limit));
    }

    /// Reads encoder, pole pairs and Hall objects (writable only with the power disabled) into the commutation.
    /// Keeps the encoder's position when nothing changed.
    fn configure_commutation(&mut self) {
        let d = &self.dictionary;
        let encoder =
            EncoderConfig::from_od(d.get(h::ENCODER_PULSES), d.get(h::ENCODER_TYPE), d.get(h::MOTOR_POLE_PAIRS));
        // 0x3000:01 bits 23..16: sensor 3 type, 4 = digital Hall sensor; bits 7..0: sensor 1, 1 = incremental
        // encoder (device.toml).
        let sensors = d.get(h::SENSORS_CONFIGURATION);
        let encoder_present = sensors & 0xFF == 1;
        let sensor_changed = encoder_present != self.t1.encoder_present;
        self.t1.encoder_present = encoder_present;
        if sensor_changed {
            self.axis.position_sensor_changed();
        }
        let method = if (sensors >> 16) & 0xFF == 4 {
            CommutationMethod::Hall
        } else {
            CommutationMethod::ForcedAlignment(self.config.alignment)
        };
        // 0x301A:01 bit 0: invert all Hall signals.
        self.t1.hall_mask = if d.get(h::HALL_CONFIGURATION) & 1 != 0 { 0b111 } else { 0 };
        let hall_offset = hall_offset_from_od(d.get(h::HALL_COMMUTATION_OFFSET));
        let same = !sensor_changed
            && self.t1.commutation.encoder().config() == &encoder
            && self.t1.commutation.method() == method
            && self.t1.commutation.hall_offset() == hall_offset;
        // 0x3010:05, the electrical angle at the index (1/65536 turn as 0x301A:03; -1 = not known): a configured
        // one wins over a learned one and over `DriveConfig::index_offset`.
        let configured = u16::try_from(d.get(h::INDEX_COMMUTATION_OFFSET)).ok().map(hall_offset_from_od);
        let index_offset = configured.or(self.t1.commutation.index_offset()).or(self.config.index_offset);
        if same {
            self.t1.commutation.set_index_offset(index_offset);
        } else {
            self.t1.commutation = Commutation::new(method, encoder, hall_offset, index_offset);
        }
        self.t1.commutation.set_hall_only(!self.t1.encoder_present);
    }

    // ---------------------------------------------------------------------------------------------------------
    // Observation
    // ---------------------------------------------------------------------------------------------------------

    /// The power-stage state.
    #[must_use]
    pub const fn state(&self) -> PowerState {
        self.t1.state
    }

    /// The shunt offsets in use (nominal until the first successful calibration).
    #[must_use]
    pub const fn offsets(&self) -> &ShuntOffsets {
        &self.t1.offsets
    }

    /// The commutation state.
    #[must_use]
    pub const fn commutation(&self) -> &Commutation {
        &self.t1.commutation
    }

    /// The current controller.
    #[must_use]
    pub const fn controller(&self) -> &CurrentController {
        &self.t1.controller
    }

    /// What the last fast tick measured and commanded.
    #[must_use]
    pub const fn signals(&self) -> &FastSignals {
        &self.t1.signals
    }

    /// The demand scale and limits in force.
    #[must_use]
    pub const fn demand_scale(&self) -> &DemandScale {
        &self.demand.scale
    }

    /// Tier 2: the CiA 402 machine, the modes, loops, supervision and faults.
    #[must_use]
    pub const fn axis(&self) -> &Axis {
        &self.axis
    }

    /// Tier 2, mutable (fault supervision inputs of the fieldbuses).
    pub fn axis_mut(&mut self) -> &mut Axis {
        &mut self.axis
    }

    /// The input edges and index latched by tier 1.
    #[must_use]
    pub const fn latches(&self) -> &PinLatches {
        &self.t1.latches
    }

    /// Output pin levels (bit n = output n+1), set by tier 2.
    #[must_use]
    pub const fn output_pins(&self) -> u8 {
        self.output_pins
    }

    /// The dictionary.
    #[must_use]
    pub const fn dictionary(&self) -> &Dictionary {
        &self.dictionary
    }

    /// The dictionary, mutable (SDO/PDO writes, test set-points). Parameters tier 1 uses take effect at the next
    /// slow tick (gains, limits) or the next switch-on (power-disabled objects).
    pub fn dictionary_mut(&mut self) -> &mut Dictionary {
        &mut self.dictionary
    }
}
