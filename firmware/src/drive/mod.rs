//! The drive: ties the current loop, offset calibration, commutation, protection and the object dictionary together;
//! the tier-1 step [`tier1::Tier1State::fast_tick`] and the tier-2 hooks [`Drive::background`] and
//! [`Drive::slow_tick`].
//!
//! # Tiers (`shared/design/ARCHITECTURE.md`, "Data flow and timing tiers")
//! - [`tier1::Tier1State::fast_tick`], 25 kHz: measurements in, PWM command out. Protection step, ADC scaling,
//!   commutation angle, the d/q current loop ([`crate::control::current_loop`]) with the q reference of the last
//!   [`SetPoint`], and the slow-tick divider: it returns [`FastTick::slow_tick_due`] every
//!   [`crate::hal::power::SLOW_TICK_DIVIDER`]-th tick. On the target the runtime then publishes tier 1's report
//!   and pends tier 2; on the host the simulation hands the report over and calls [`Drive::background`] and
//!   [`Drive::slow_tick`] directly. No searches, no divisions, no loops, no panics.
//! - [`Drive::slow_tick`], 2.5 kHz: publishes the actual values (0x30D1, 0x6077, 0x6078, 0x30D0, 0x6074, averaged
//!   values, DC link voltage, Hall pattern, index position) and re-reads the parameters tier 1 uses (current gains
//!   0x30A0, motor data 0x3001, limits 0x6072/0x6073) when they change. The motion issue adds the velocity and
//!   position loops here, with their output as the current demand ([`DemandSource::Internal`]). In CST the drive
//!   converts target torque 0x6071 + offset 0x60B2 into the q reference at every set-point event
//!   ([`Drive::setpoint_received`]) and every slow tick: a torque written to 0x6071 reaches the current loop in
//!   the first period after its set-point event, and at the latest one slow tick plus one period after the write.
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
//! # Tiers own their state (`docs/design/tier-ownership.md`)
//! [`Drive`] is tier 2's: the dictionary, the axis, the supervision, the parameter conversion. What tier 1 owns
//! is [`tier1::Tier1State`] (power-stage state, calibration, commutation, current controller, limits in force,
//! latches and sums, trip sample, divider, period count), and only tier 1 touches it. They exchange blocks
//! ([`blocks`]): the drive keeps a [`SetPoint`] (power request, q-current reference already converted) and the
//! [`Settings`] (limits, gains, calibration, commutation) and moves their versions on when it changes them;
//! whoever runs the tiers hands the changed blocks to tier 1 ([`Drive::take_setpoint`], [`Drive::take_settings`])
//! and tier 1's [`Tier1Report`] back to the drive at every slow-tick boundary ([`Drive::receive_report`]).
//! The power-stage requests are therefore predictions until tier 1 acknowledges them: [`Drive::state`] is the
//! reported state, or the one a request not yet acted on will lead to.
//!
//! # Hand-off timing
//! A set-point changed by a request, a set-point event or a forced off applies from the first period after its
//! publication ([`SetPoint::apply_from`] is a period already begun). What the tier-2 steps decide for the loops
//! ([`Drive::background`] and [`Drive::slow_tick`] with the loops' demand in force) applies from a fixed period
//! instead: [`blocks::LOOP_SETPOINT_DELAY_PERIODS`] periods after the one following the report's period, that is the
//! middle of the slow period. On the target tier 2 publishes it anywhere from the raising period to a few periods
//! later (how long the background step, the slow tick and a tier-3 section holding the lock take); the fixed
//! period hides that spread from the loops, and the host simulation, which runs tier 2 at once, applies it in
//! the same period as the target. Off requests and the CST torque (the master's value, not a loop's output) are
//! not held back.

pub mod auto_setup;
pub mod auto_tuning;
pub mod blocks;
pub mod calibration;
pub mod chopper;
pub mod commutation;
pub mod encoder;
mod fieldbus;
pub mod gear_ratio;
pub mod hall_position;
pub mod identification;
pub mod mechanical_identification;
pub mod objects;
pub mod protection;
pub mod regeneration;
pub mod resonance_identification;
pub mod scaling;
pub mod ssi_position;
pub mod tier1;
pub mod tuning;

use crate::control::angle::ElectricalAngle;
use crate::control::demand::{rated_torque_micro_nm, DemandScale};
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::control::pi::PiGains;
use crate::fault::emcy::InhibitTime;
use crate::fault::table::FaultId;
use crate::hal::power::PwmCommand;
use crate::hal::reset::ResetCause;
use crate::hal::sto::StoInputs;
use crate::motion::axis::{Axis, AxisInputs, AxisOutputs, CurrentDemand};
use crate::motion::dual_loop::{self, LoadFeedback};
use crate::motion::polarity::Polarity;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::power_state::{CommutationError, CommutationStage, DriveError, PowerState};
use crate::sensors::hall::HallSector;
use crate::sensors::latch::PinLatches;
use crate::sensors::ssi::SsiFormat;
use crate::supervision::communication::LinkLoss;
use crate::supervision::{Supervision, SupervisionInputs};

use blocks::{CommutationSettings, PowerLevel, PowerRequest, SetPoint, Settings, Tier1Report};
use calibration::CalibrationConfig;
use chopper::BrakingChopper;
use commutation::{hall_offset_from_od, AlignmentConfig, CommutationMethod};
use encoder::EncoderConfig;
use regeneration::BusVoltageLimiter;
use scaling::ShuntOffsets;

/// Why a power-stage request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestError {
    /// The request is not allowed in the present state (e.g. enable before the calibration has finished).
    WrongState(PowerState),
}

/// Where the q-current reference comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DemandSource {
    /// Target torque 0x6071 + torque offset 0x60B2 (CST), converted by tier 2 at every set-point event
    /// ([`Drive::setpoint_received`], [`Drive::target_torque_written`]) and every slow tick.
    TargetTorque,
    /// A current set by tier 2 through [`Drive::set_current_demand`] (the velocity and position loops).
    Internal,
    /// The motor identification sets tier 1's set-point itself (0x6060 = -2, [`auto_setup`]).
    Identification,
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
/// `repr(C)`: the data recorder's copy (`crate::recorder::ring`) takes the first ten words in this order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C)]
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
// `repr(C)` with the slow tick's fields first: on the Cortex-M4 a load or store reaches 4 KiB from a base register in
// one instruction, so the fields tier 2 touches every slow tick sit at the start, ahead of the background step's.
#[repr(C)]
pub struct Drive {
    /// Tier 1's last report.
    report: Tier1Report,
    /// What tier 2 asks of tier 1 now (power request, q-current reference).
    setpoint: SetPoint,
    /// The power state tier 1 will be in once it has acted on the pending request (while
    /// `setpoint.power.sequence` is ahead of the report's).
    predicted: PowerState,
    /// Where the q-current reference comes from.
    source: DemandSource,
    /// The loops' q-current demand, clamped to the limit ([`DemandSource::Internal`]).
    internal: Amps,
    /// Target torque to current, with the I2t and thermal limits applied.
    scale: DemandScale,
    /// The torque demand (0x6074) of the last conversion of 0x6071 and 0x60B2, and the value shown.
    torque_demand_permille: i16,
    shown_torque_demand: i16,
    /// The scale from the dictionary, before the I2t limit.
    base_scale: DemandScale,
    /// The I2t protection's current limit (tier 2).
    i2t_limit: Amps,
    /// 50 Hz low-pass states (`I16F16` bits) of the q current and the bus voltage.
    i_q_average: i32,
    v_bus_average: i32,
    /// The machine's last power-stage request, to act on its changes.
    last_power_request: crate::cia402::PowerStage,
    /// Output pin levels from tier 2.
    output_pins: u8,
    /// Tier 1's encoder carries the position (the incremental encoder or the SSI sensor); else the Halls count it.
    position_from_encoder: bool,
    /// Tier 2: the CiA 402 machine, the modes, the loops and the motion supervision.
    axis: Axis,
    dictionary: Dictionary,
    // The background step's own fields, after the dictionary.
    /// What tier 1 runs with from the dictionary (limits, gains, calibration, commutation).
    settings: Settings,
    /// The versions last handed to tier 1 ([`Drive::take_setpoint`], [`Drive::take_settings`]).
    setpoint_taken: u32,
    settings_taken: u32,
    config: DriveConfig,
    gain_source: GainSource,
    /// The hardware detectors (temperatures, position sensors, stall, phases).
    supervision: Supervision,
    /// The SSI sensor's absolute position across restarts and its whole-frame check.
    ssi_position: ssi_position::SsiPosition,
    /// The thermal derating's current limit.
    thermal_limit: Amps,
    /// The motor data the demand scale was converted from (`None`: not yet).
    motor_source: Option<MotorSource>,
    /// The DC-bus voltage limiter (0x3202) on the current reference.
    bus_limiter: BusVoltageLimiter,
    /// The braking chopper (0x3203).
    chopper: BrakingChopper,
    /// An event warning ([`FaultId::CanBusOffRecovered`]) was raised: it goes at the next background step.
    event_warning_shown: bool,
    /// The STO inputs tier 2 read for this slow period ([`Self::set_sto_inputs`]).
    sto_inputs: StoInputs,
    /// The motor identification procedure (0x6060 = -2).
    auto_setup: auto_setup::AutoSetup,
    /// 0x6091 and 0x3003 as last reconciled ([`gear_ratio`]).
    gear_ratio: gear_ratio::GearRatioSeen,
    /// The load encoder's count read at the start of this slow period ([`Self::set_load_encoder_count`]).
    load_count: u32,
    /// The dual loop's main sensor (`motion::dual_loop`), taken with the sensor configuration at switch-on.
    load_feedback: Option<LoadFeedback>,
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
        let gains = PiGains::from_idx_0x30a0(gain_source.p, gain_source.i);
        let mut drive = Self {
            report: Tier1Report::default(),
            setpoint: SetPoint::default(),
            predicted: PowerState::Off,
            source: DemandSource::TargetTorque,
            internal: Amps::ZERO,
            scale: DemandScale::reference(),
            torque_demand_permille: 0,
            shown_torque_demand: 0,
            settings: Settings {
                version: 1,
                output_limit_ma: 0,
                gains,
                calibration: config.calibration,
                commutation: CommutationSettings {
                    default_index_offset: config.index_offset,
                    ..CommutationSettings::default()
                },
            },
            setpoint_taken: 0,
            settings_taken: 0,
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
            position_from_encoder: true,
            ssi_position: ssi_position::SsiPosition::default(),
            bus_limiter: BusVoltageLimiter::default(),
            chopper: BrakingChopper::default(),
            event_warning_shown: false,
            sto_inputs: StoInputs::RELEASED,
            auto_setup: auto_setup::AutoSetup::default(),
            gear_ratio: gear_ratio::GearRatioSeen::new(&dictionary),
            load_count: 0,
            load_feedback: None,
            dictionary,
        };
        drive.gear_ratio.reconcile(&mut drive.dictionary);
        drive.configure_commutation();
        // The first call converts the motor data, and with it the demand.
        drive.refresh_parameters();
        drive
    }

    // ---------------------------------------------------------------------------------------------------------
    // The hand-offs with tier 1
    // ---------------------------------------------------------------------------------------------------------

    /// The set-point, when it changed since the last call: to be handed to tier 1 for its next period.
    pub fn take_setpoint(&mut self) -> Option<SetPoint> {
        (self.setpoint.version != self.setpoint_taken).then(|| {
            self.setpoint_taken = self.setpoint.version;
            self.setpoint
        })
    }

    /// The settings, when they changed since the last call: to be handed to tier 1 for its next period (before the
    /// set-point).
    pub fn take_settings(&mut self) -> Option<Settings> {
        (self.settings.version != self.settings_taken).then(|| {
            self.settings_taken = self.settings.version;
            self.settings
        })
    }

    /// The settings tier 1 starts with ([`Tier1State::new`](tier1::Tier1State::new)).
    #[must_use]
    pub const fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The set-point as it stands.
    #[must_use]
    pub const fn setpoint(&self) -> &SetPoint {
        &self.setpoint
    }

    /// Takes over tier 1's report of the slow-tick boundary: before [`Self::background`] and [`Self::slow_tick`].
    pub fn receive_report(&mut self, report: &Tier1Report) {
        self.report = *report;
    }

    /// Tier 1's last report.
    #[must_use]
    pub const fn report(&self) -> &Tier1Report {
        &self.report
    }

    /// A power-stage request: `change` edits the request, `predicted` is the state it leads to.
    fn request(&mut self, change: impl FnOnce(&mut PowerRequest), predicted: PowerState) {
        change(&mut self.setpoint.power);
        self.setpoint.power.sequence = self.setpoint.power.sequence.wrapping_add(1);
        self.predicted = predicted;
        self.setpoint_changed();
    }

    /// The set-point changed: a new version, applying from the period already begun (see "Hand-off timing").
    fn setpoint_changed(&mut self) {
        self.setpoint.version = self.setpoint.version.wrapping_add(1);
        self.setpoint.apply_from = self.report.period;
    }

    /// After a tier-2 step that began at set-point version `before`: a change the loops decided applies from the
    /// fixed period of the slow period (module documentation, "Hand-off timing").
    fn hold_loop_setpoint(&mut self, before: u32) {
        let loops = self.source == DemandSource::Internal && self.setpoint.power.level != PowerLevel::Off;
        if self.setpoint.version != before && loops {
            self.setpoint.apply_from = self.report.period.wrapping_add(blocks::LOOP_SETPOINT_DELAY_PERIODS);
        }
    }

    /// Settings changed by `change`: their version moves on if anything differs.
    fn change_settings(&mut self, change: impl FnOnce(&mut Settings)) {
        let mut settings = self.settings;
        change(&mut settings);
        if settings != self.settings {
            settings.version = self.settings.version.wrapping_add(1);
            self.settings = settings;
        }
    }

    /// Converts the demand into tier 1's q-current reference: the loops' demand, or target torque 0x6071 +
    /// offset 0x60B2 through the demand scale (CST).
    fn update_demand(&mut self) {
        let i_q = match self.source {
            DemandSource::TargetTorque => {
                let d = &self.dictionary;
                // CST: target torque and torque offset in the motor's direction (polarity 0x607E bit 6,
                // `motion::polarity`).
                let polarity = Polarity::from_0x607e(d.get(h::POLARITY));
                let (target, offset) =
                    (polarity.torque(d.get(h::TARGET_TORQUE)), polarity.torque(d.get(h::TORQUE_OFFSET)));
                let (permille, i_q) = self.scale.torque_to_current(target, offset);
                self.torque_demand_permille = permille;
                i_q
            }
            DemandSource::Internal => self.internal,
            // The identification's set-point is its own (angle and injection in the current words).
            DemandSource::Identification => return,
        };
        let i = if self.bus_limiter.active() {
            self.bus_limiter.limit(i_q, self.axis.velocity().to_bits())
        } else {
            Dq::new(Amps::ZERO, i_q)
        };
        if i.q != self.setpoint.i_q || i.d != self.setpoint.i_d {
            self.setpoint.i_q = i.q;
            self.setpoint.i_d = i.d;
            self.setpoint_changed();
        }
    }

    /// Target torque 0x6071 or torque offset 0x60B2 was written outside a set-point event (a host test standing in
    /// for a fieldbus that writes it every period): converts it now instead of at the next slow tick.
    pub fn target_torque_written(&mut self) {
        self.update_demand();
    }

    // ---------------------------------------------------------------------------------------------------------
    // Tier 2
    // ---------------------------------------------------------------------------------------------------------

    /// Converts the parameters that changed since the last call into the units the tiers use (current gains
    /// 0x30A0, motor data and limits, and the axis's motion parameters, gains, monitoring limits and brake
    /// timing), applies the I2t current limit, and publishes the actual values (0x6077, 0x6078, 0x30D1, 0x30D2,
    /// 0x6079, 0x3200:01, ...), and plans the profile command the next slow tick takes into force. Tier 2 runs it
    /// before each [`Self::slow_tick`] (its cost is reported separately: it compares the raw values every time,
    /// and converts, with 64- and 128-bit arithmetic, only what changed).
    pub fn background(&mut self) {
        let before = self.setpoint.version;
        if core::mem::take(&mut self.event_warning_shown) {
            self.axis.faults_mut().clear_cause(FaultId::CanBusOffRecovered);
        }
        self.refresh_parameters();
        self.publish_actual_values();
        if let CommutationMethod::Absolute(ssi) = self.settings.commutation.method {
            self.ssi_background(&ssi);
        }
        self.gear_ratio.reconcile(&mut self.dictionary);
        self.update_load_position();
        self.axis.refresh(&mut self.dictionary);
        self.axis.publish_velocity_actual_values(&mut self.dictionary);
        // 0x1015 EMCY inhibit time (CiA 301), taken over when it changes.
        let inhibit = InhibitTime(self.dictionary.get(h::INHIBIT_TIME_EMCY));
        if inhibit != self.axis.faults().emcy().inhibit_time() {
            self.axis.faults_mut().emcy_mut().set_inhibit_time(inhibit);
        }
        self.supervision.refresh(&self.dictionary);
        let inputs = self.supervision_inputs();
        let supervised = self.supervision.step(&inputs, self.axis.faults_mut(), &mut self.dictionary);
        self.supervision.safe_torque_off.step(self.sto_inputs, &inputs, self.axis.faults_mut());
        // The I2t protection's and the thermal derating's current limits (applied one slow tick after the models
        // decided them: far inside the winding's and the heat sink's thermal time constants).
        let i2t_limit = Amps::from_milliamps(i32::try_from(self.axis.i2t_current_limit_ma()).unwrap_or(i32::MAX));
        if i2t_limit != self.i2t_limit || supervised.current_limit != self.thermal_limit {
            self.i2t_limit = i2t_limit;
            self.thermal_limit = supervised.current_limit;
            self.apply_limits();
        }
        self.run_chopper();
        self.limit_bus_voltage();
        // Last, so that the plan starts from the parameters just converted: the profile generator's planning,
        // which does not fit the slow tick's budget (`control::trajectory` generator, "When a command takes
        // effect").
        self.axis.prepare_motion();
        self.hold_loop_setpoint(before);
    }

    /// The load encoder's count (sensor 2, 0x3020) for this slow period, read by tier 2 at its start (target:
    /// `board::load_encoder`, a 32-bit counter; host: the plant's load encoder), before [`Self::background`].
    pub fn set_load_encoder_count(&mut self, count: u32) {
        self.load_count = count;
    }

    /// Publishes 0x60E4:01/02 (the motor and load encoder counts) and, in the dual loop, hands the axis the load
    /// position in motor increments for this slow period's step.
    fn update_load_position(&mut self) {
        let motor = self.report.encoder_position;
        // `as`: the counter's bits as the INTEGER32 of 0x60E4:02 (it wraps like every position value).
        let load = self.load_count as i32;
        self.dictionary.set(h::POSITION_ACTUAL_VALUE_SENSOR_1, motor);
        self.dictionary.set(h::POSITION_ACTUAL_VALUE_SENSOR_2, load);
        let main = self.load_feedback.as_mut().map(|f| (f.update(self.load_count, motor), f.fraction()));
        self.axis.set_main_sensor_position(main);
    }

    /// The braking chopper's step on tier 1's last bus sample: its gate for this slow period
    /// ([`Self::chopper_gate`]), the resistor model (0x3203:06/07) and its overload warning.
    fn run_chopper(&mut self) {
        let v_bus = self.report.signals.v_bus;
        let step = self.chopper.step(&self.dictionary, v_bus);
        if step.overload_began || step.overload_ended {
            self.chopper_overload_changed(step.overload_began);
        }
        let d = &mut self.dictionary;
        d.set(h::CHOPPER_LOAD, self.chopper.load_percent());
        d.set(h::CHOPPER_STATE, self.chopper.state_bits());
    }

    /// The resistor's overload protection switched the chopper off (`began`) or let it on again: warning 0x7113
    /// with the resistor's load, or its cause gone.
    #[cold]
    #[inline(never)]
    fn chopper_overload_changed(&mut self, began: bool) {
        if began {
            self.raise(FaultId::ChopperOverload, i32::from(self.chopper.load_percent()));
        } else {
            self.axis.faults_mut().clear_cause(FaultId::ChopperOverload);
        }
    }

    /// The braking chopper's gate for this slow period: the board drives its output with it after each
    /// [`Self::background`] (the simulation switches the plant's resistor).
    #[must_use]
    pub const fn chopper_gate(&self) -> bool {
        self.chopper.gate()
    }

    /// The bus-voltage limiter's step on tier 1's last bus sample; the reference is converted again while it acts
    /// or when it has just stopped acting.
    fn limit_bus_voltage(&mut self) {
        let was_active = self.bus_limiter.active();
        self.bus_limiter.refresh(&self.dictionary);
        let signals = &self.report.signals;
        let velocity = self.axis.velocity().to_bits();
        self.bus_limiter.observe(signals.v_bus, signals.i_dq.q, self.scale.current_limit(), velocity);
        if was_active || self.bus_limiter.active() {
            self.dictionary.set(h::BUS_LIMITER_STATE, self.bus_limiter.state_bits());
            self.update_demand();
        }
    }

    /// The levels of the two Safe Torque Off inputs, read by tier 2 at the start of the slow period (target:
    /// `board::sto`; host: the plant's safety circuit), before [`Self::background`], which takes them: the STO
    /// state and the machine follow within that slow period ([`crate::supervision::safe_torque_off`]). The drive
    /// starts with both released, as a board without a safety circuit reads them.
    pub fn set_sto_inputs(&mut self, inputs: StoInputs) {
        self.sto_inputs = inputs;
    }

    /// The Safe Torque Off inputs last handed in ([`Self::set_sto_inputs`]).
    #[must_use]
    pub const fn sto_inputs(&self) -> StoInputs {
        self.sto_inputs
    }

    /// The demand scale with the current limits of the protections in force (I2t and thermal derating): the
    /// loops' demand is clamped to it and the reference converted again.
    fn apply_limits(&mut self) {
        self.scale = self.base_scale.limited_to(self.i2t_limit).limited_to(self.thermal_limit);
        self.clamp_internal_demand();
        self.update_demand();
    }

    /// What the supervision reads: the last fast tick's measurements and the axis's state.
    fn supervision_inputs(&self) -> SupervisionInputs {
        let r = &self.report;
        let s = &r.signals;
        let commutation = &self.settings.commutation;
        let power = self.state();
        SupervisionInputs {
            now: self.axis.now(),
            state: self.axis.state(),
            operation_enabled: power == PowerState::OperationEnabled,
            power,
            loops_drive_motor: power == PowerState::OperationEnabled && self.source == DemandSource::Internal,
            power_stage_temperature_code: s.temperature_codes[0],
            motor_temperature_code: s.temperature_codes[1],
            hall: s.hall,
            halls_present: commutation.method == CommutationMethod::Hall,
            encoder_present: commutation.encoder_present,
            encoder_has_index: commutation.encoder.has_index,
            encoder_position: r.encoder_position,
            encoder_counts_per_turn: commutation.encoder.counts_per_rev,
            pole_pairs: commutation.encoder.pole_pairs,
            // The latch counts every index pulse (the commutation only those while it runs): the same source as
            // `index_position`, so the feedback supervision sees the pulses in every state.
            index_pulses: u32::from(r.latches.index.count),
            index_position: r.latches.index.position,
            electrical_angle: r.angle,
            hall_offset: commutation.hall_offset,
            commutation: r.stage,
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
        if loss == LinkLoss::CanBusOff {
            // CiA 301's EMCY 0x8140 "recovered from bus off": an event, sent once; the warning it is stays for one
            // slow period (statusword bit 7) and goes at the next background step.
            self.raise(FaultId::CanBusOffRecovered, 0);
            self.event_warning_shown = true;
        }
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

    /// The cause of the reset this start follows, as the board read it before the tiers ran. A reset by the
    /// independent watchdog means a tier stopped running in the last run: it is a fault of this start (IDX 7.2.48
    /// 0xFF02 "Watchdog error": device disabled, reset with the controlword), in the error history and sent as an
    /// EMCY once the fieldbus is up. Every other cause is a normal start.
    pub fn report_reset(&mut self, cause: ResetCause) {
        if cause == ResetCause::IndependentWatchdog {
            self.raise(FaultId::WatchdogReset, 0);
        }
    }

    /// Raises `id` with a snapshot of what the drive measures now. A fault of class "d" raised from outside the
    /// tiers' own steps (the runtime, a fieldbus layer) switches the outputs off here and now, not at the next slow
    /// tick: the class means "a secure movement is no longer possible" (IDX L7030). The forced off reaches tier 1
    /// with the set-point published when the caller's section ends, so within one period.
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
        let before = self.setpoint.version;
        self.update_averages();
        // A fault reports what the tripping tick measured, not what came after.
        let power = self.state();
        let r = &self.report;
        let fault = match power {
            PowerState::Fault(e) => Some(e),
            _ => None,
        };
        let s = if fault.is_some() { r.trip_sample } else { r.signals };
        let power_fault_present = match fault {
            Some(DriveError::Protection(t)) => {
                protection::cause_present(t, r.break_input, r.signals.v_bus.to_millivolts())
            }
            // Tier 1 keeps sampling the Halls in «Fault»: the invalid state persists while they still read it. An
            // SSI frame error is checked again by tier 1 after the reset.
            Some(DriveError::Commutation(CommutationError::InvalidHallState(_))) => {
                HallSector::from_state(r.signals.hall).is_err()
            }
            _ => false,
        };
        let encoder_present = self.position_from_encoder;
        let input = AxisInputs {
            encoder_position: if encoder_present { r.encoder_position } else { r.hall_position },
            encoder_window: encoder_present.then_some(r.encoder_window),
            current: s.i_dq.q,
            winding_current: regeneration::current_magnitude_bound(s.i_dq),
            braking_limited: self.bus_limiter.braking_limited(),
            current_average_ma: Amps::from_bits(self.i_q_average).to_milliamps(),
            phase_currents_ma: [s.i_abc.a.to_milliamps(), s.i_abc.b.to_milliamps(), s.i_abc.c.to_milliamps()],
            bus_voltage_mv: s.v_bus.to_millivolts(),
            pins: &r.latches,
            power,
            power_fault_present,
            scale: &self.scale,
        };
        let out = self.axis.step(&input, &mut self.dictionary);
        self.apply(&out);
        if out.demand == CurrentDemand::Identification || self.auto_setup.running() {
            self.run_auto_setup();
        }
        self.hold_loop_setpoint(before);
    }

    /// Publishes the slow tick's positions and velocities in the master's units (0x6062, 0x6064, 0x60F4, 0x606B,
    /// 0x606C, 0x60BA..0x60BD: polarity 0x607E and the gear, `motion::gear`). Tier 2 runs it right after
    /// [`Self::slow_tick`], once the set-point is out (`rt::tier2`, the simulation likewise): the conversions stay
    /// out of the slow tick's budget and a process-data cycle after the period sees the values of its slow tick.
    pub fn publish_master_values(&mut self) {
        self.axis.publish_master_values(&mut self.dictionary);
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
                if !matches!(self.state(), PowerState::Off | PowerState::Fault(_)) {
                    self.shutdown();
                }
            } else if out.start_calibration {
                // Refused only in a fault or while calibrating: the machine then waits (and the fault is reported).
                let _ = self.switch_on();
            } else if out.power.controllers_enabled {
                if self.state() == PowerState::SwitchedOn {
                    let _ = self.enable_operation();
                }
            } else if self.state() == PowerState::OperationEnabled {
                self.disable_operation();
            }
        }
        match out.demand {
            CurrentDemand::Off => {}
            CurrentDemand::Internal(i) => {
                self.source = DemandSource::Internal;
                self.internal = i;
                self.clamp_internal_demand();
            }
            CurrentDemand::TargetTorque => self.source = DemandSource::TargetTorque,
            CurrentDemand::Identification => {
                if !self.auto_setup.running() && self.source == DemandSource::Identification {
                    // No identification running in mode -2: no current.
                    self.source = DemandSource::Internal;
                    self.internal = Amps::ZERO;
                }
            }
        }
        // One conversion for whatever the step changed (source, loops' demand, 0x6071).
        self.update_demand();
        self.output_pins = out.output_pins;
    }

    /// A master set-point arrived (CANopen SYNC with its RPDOs, EtherCAT SM2 event or SYNC0): the cyclic modes
    /// latch 0x607A, 0x60FF, 0x6071 and the offsets now.
    pub fn setpoint_received(&mut self) {
        self.axis.setpoint_received(&self.dictionary);
        // CST: the new target torque reaches tier 1 in its next period, not at the next slow tick.
        if self.source == DemandSource::TargetTorque {
            self.update_demand();
        }
    }

    /// Statusword bit 9 "remote" (the fieldbus layer: NMT operational, EtherCAT SafeOp/Op).
    pub fn set_remote(&mut self, remote: bool) {
        self.axis.set_remote(remote);
    }

    /// Converts 0x30A0 into gains when it changed, and the motor data into the demand scale.
    fn refresh_parameters(&mut self) {
        let d = &self.dictionary;
        let gains = GainSource { p: d.get(h::CURRENT_CONTROLLER_P_GAIN), i: d.get(h::CURRENT_CONTROLLER_I_GAIN) };
        if gains != self.gain_source {
            self.gain_source = gains;
            let g = PiGains::from_idx_0x30a0(gains.p, gains.i);
            self.change_settings(|s| s.gains = g);
        }
        let d = &self.dictionary;
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
        self.change_settings(|s| s.output_limit_ma = motor.output_limit_ma);
        let scale =
            DemandScale::from_od(nominal, motor.output_limit_ma, motor.max_current_permille, motor.max_torque_permille);
        self.base_scale = scale;
        // 0x6075 and 0x6076 are read-only copies derived from 0x3001 (single writer: the drive).
        let d = &mut self.dictionary;
        d.set(h::MOTOR_RATED_CURRENT, nominal);
        d.set(h::MOTOR_RATED_TORQUE, rated_torque_micro_nm(nominal, motor.torque_constant));
        // The protections' limits stay in force across the re-read (the thermal derating's would otherwise hold
        // only in the slow tick it changed).
        self.apply_limits();
    }

    /// Updates the 50 Hz averages of the q current and the bus voltage (0x30D1:01, 0x30D2:01, homing -1..-4).
    fn update_averages(&mut self) {
        let s = &self.report.signals;
        // First-order low-pass y += (x - y) / 8 at 2.5 kHz: cut-off 1/8 * 2500 / (2 pi) = 49.7 Hz, the 50 Hz of
        // IDX 0x30D1:01 / 0x30D2:01 (spec §1.3). |x|, |y| < 2^30: no wrap.
        self.i_q_average = self.i_q_average.wrapping_add(s.i_dq.q.to_bits().wrapping_sub(self.i_q_average) >> 3);
        self.v_bus_average = self.v_bus_average.wrapping_add(s.v_bus.to_bits().wrapping_sub(self.v_bus_average) >> 3);
    }

    /// Writes the actual values of the last fast tick and their averages into the dictionary (run by
    /// [`Self::background`] at the start of each slow period, so a TxPDO sampled in the slow tick carries them).
    fn publish_actual_values(&mut self) {
        let s = self.report.signals;
        let i_q = s.i_dq.q;
        let avg = Amps::from_bits(self.i_q_average);
        let d = &mut self.dictionary;
        d.set(h::CURRENT_ACTUAL_VALUE, i_q.to_milliamps());
        d.set(h::CURRENT_ACTUAL_VALUE_AVERAGED, avg.to_milliamps());
        d.set(h::CURRENT_DEMAND_VALUE, s.i_ref.q.to_milliamps());
        // 0x6074 follows the CST conversion while the current loop runs on it, and is 0 during an alignment.
        if self.report.power == PowerState::OperationEnabled {
            if self.report.stage == CommutationStage::Aligning {
                self.shown_torque_demand = 0;
            } else if self.report.stage.is_valid() && self.source == DemandSource::TargetTorque {
                self.shown_torque_demand = self.torque_demand_permille;
            }
        }
        let d = &mut self.dictionary;
        // The torques as the master sees them (polarity 0x607E bit 6, `motion::polarity`); the currents keep the
        // motor's sign.
        let polarity = Polarity::from_0x607e(d.get(h::POLARITY));
        d.set(h::TORQUE_DEMAND_VALUE, polarity.torque(self.shown_torque_demand));
        let permille = self.scale.current_to_permille(i_q);
        d.set(h::CURRENT_ACTUAL_VALUE_PER_MILLE, permille);
        d.set(h::TORQUE_ACTUAL_VALUE, polarity.torque(permille));
        d.set(h::TORQUE_ACTUAL_VALUE_AVERAGED, polarity.torque(self.scale.current_to_permille(avg)));
        let mv = Volts::from_bits(self.v_bus_average).to_millivolts().max(0);
        d.set(h::DC_LINK_CIRCUIT_VOLTAGE, mv.unsigned_abs());
        d.set(h::POWER_SUPPLY_VOLTAGE, u16::try_from(mv / 100).unwrap_or(u16::MAX));
        d.set(h::HALL_PATTERN, s.hall);
        if let Some(latch) = self.report.last_index_latch {
            d.set(h::ENCODER_INDEX_POSITION, u32::from(latch));
        }
    }

    // ---------------------------------------------------------------------------------------------------------
    // Power-stage requests (called by the CiA 402 state machine)
    // ---------------------------------------------------------------------------------------------------------

    /// CiA 402 transition 3 "switch on": reads the power-disabled parameters and asks tier 1 for the
    /// current-offset calibration (outputs at 50 % duty); the state becomes [`PowerState::SwitchedOn`] when it
    /// succeeds (within `CalibrationConfig::timeout_ticks`), or [`PowerState::Fault`] when it fails.
    pub fn switch_on(&mut self) -> Result<(), RequestError> {
        match self.state() {
            PowerState::Off | PowerState::SwitchedOn => {
                self.configure_commutation();
                self.refresh_parameters();
                self.request(
                    |p| {
                        p.switch_on = p.switch_on.wrapping_add(1);
                        p.level = PowerLevel::SwitchedOn;
                    },
                    PowerState::Calibrating,
                );
                Ok(())
            }
            other => Err(RequestError::WrongState(other)),
        }
    }

    /// CiA 402 transition 4 "enable operation": tier 1 starts the commutation (from its next period's sensors)
    /// and the current loop with empty integrators.
    pub fn enable_operation(&mut self) -> Result<(), RequestError> {
        match self.state() {
            PowerState::SwitchedOn => {
                self.request(|p| p.level = PowerLevel::OperationEnabled, PowerState::OperationEnabled);
                Ok(())
            }
            PowerState::OperationEnabled => Ok(()),
            other => Err(RequestError::WrongState(other)),
        }
    }

    /// CiA 402 transition 5 "disable operation": outputs off, stays calibrated.
    pub fn disable_operation(&mut self) {
        let predicted = match self.state() {
            PowerState::OperationEnabled => PowerState::SwitchedOn,
            other => other,
        };
        self.request(|p| p.level = PowerLevel::SwitchedOn, predicted);
    }

    /// CiA 402 transitions 6/8/9 "shutdown"/"disable voltage" and every forced off: outputs off, calibration to be
    /// redone at the next switch-on. A latched fault stays latched.
    pub fn shutdown(&mut self) {
        let predicted = match self.state() {
            PowerState::Fault(e) => PowerState::Fault(e),
            _ => PowerState::Off,
        };
        self.request(|p| p.level = PowerLevel::Off, predicted);
    }

    /// CiA 402 transition 15 "fault reset": back to [`PowerState::Off`]. An SSI sensor's absolute position takes
    /// its base again from the next report (tier 1's count may have jumped while the sensor was out).
    pub fn fault_reset(&mut self) {
        self.ssi_position.restart(self.settings.version);
        let predicted = match self.state() {
            PowerState::Fault(_) => PowerState::Off,
            other => other,
        };
        self.request(|p| p.fault_reset = p.fault_reset.wrapping_add(1), predicted);
    }

    /// Selects where the q-current reference comes from.
    pub fn set_demand_source(&mut self, source: DemandSource) {
        self.source = source;
        self.update_demand();
    }

    /// The q-current demand for [`DemandSource::Internal`] (tier 2's velocity/position loops), clamped to the
    /// current limit.
    pub fn set_current_demand(&mut self, i_q: Amps) {
        self.internal = i_q;
        self.clamp_internal_demand();
        self.update_demand();
    }

    /// Clamps the loops' demand to the current limit in force (max/min: `clamp` would assert the bounds' order with
    /// a formatted panic, flash in the images that print panics, issue 17; a limit is not negative).
    fn clamp_internal_demand(&mut self) {
        let limit = self.scale.current_limit().to_bits();
        self.internal = Amps::from_bits(self.internal.to_bits().max(limit.wrapping_neg()).min(limit));
    }

    /// Reads encoder, pole pairs and Hall objects (writable only with the power disabled) into the commutation
    /// settings; tier 1 rebuilds its commutation when they changed and keeps the encoder's position otherwise.
    fn configure_commutation(&mut self) {
        let d = &self.dictionary;
        let mut encoder =
            EncoderConfig::from_od(d.get(h::ENCODER_PULSES), d.get(h::ENCODER_TYPE), d.get(h::MOTOR_POLE_PAIRS));
        // 0x3000:01 (rw, saved, power-disabled; the dictionary accepts only the combinations below): bits 23..16
        // sensor 3 type, 4 = digital Hall sensor; bits 15..8 sensor 2, 3 = SSI; bits 7..0 sensor 1, 1 = incremental
        // encoder. Encoder + Halls: Hall start, encoder position; encoder only: forced alignment at enable; Halls
        // only: Hall commutation and the Halls count the position; SSI only: the absolute angle commutates from the
        // start and the SSI position is the main position (device.toml).
        let sensors = d.get(h::SENSORS_CONFIGURATION);
        let encoder_present = sensor_1_is_encoder(sensors);
        let method = if sensor_2_is_ssi(sensors) {
            match self.ssi_format() {
                Some(ssi) => {
                    encoder = EncoderConfig {
                        counts_per_rev: ssi.counts_per_rev(),
                        pole_pairs: encoder.pole_pairs,
                        inverted: ssi.inverted,
                        has_index: false,
                    };
                    CommutationMethod::Absolute(ssi)
                }
                None => {
                    self.ssi_format_unreadable();
                    return;
                }
            }
        } else if sensor_3_is_hall(sensors) {
            CommutationMethod::Hall
        } else {
            CommutationMethod::ForcedAlignment(self.config.alignment)
        };
        let d = &self.dictionary;
        let commutation = CommutationSettings {
            method,
            encoder,
            hall_offset: hall_offset_from_od(d.get(h::HALL_COMMUTATION_OFFSET)),
            // 0x3010:05, the electrical angle at the index (1/65536 turn as 0x301A:03; -1 = not known): a
            // configured one wins over a learned one (tier 1's) and over `DriveConfig::index_offset`.
            configured_index_offset: u16::try_from(d.get(h::INDEX_COMMUTATION_OFFSET)).ok().map(hall_offset_from_od),
            default_index_offset: self.config.index_offset,
            // 0x301A:01 bit 0: invert all Hall signals.
            hall_mask: if d.get(h::HALL_CONFIGURATION) & 1 != 0 { 0b111 } else { 0 },
            encoder_present,
        };
        let position_from_encoder = encoder_present || matches!(method, CommutationMethod::Absolute(_));
        if position_from_encoder != self.position_from_encoder {
            self.axis.position_sensor_changed();
        }
        self.position_from_encoder = position_from_encoder;
        // The dual loop's main sensor (0x3000:02, 0x3020, 0x3003): a valid configuration is all the dictionary
        // holds (`Drive::sdo_write` refuses the others); the conversion restarts from the motor position.
        let scale = dual_loop::configuration(&self.dictionary).ok().flatten();
        if scale != self.load_feedback.map(|f| f.scale()) {
            self.load_feedback = scale.map(LoadFeedback::new);
            self.axis.set_load_scale(scale);
        }
        self.change_settings(|s| s.commutation = commutation);
        // Tier 1 may build its commutation again with these settings (its position restarting at 0): the SSI
        // position's base is taken again from the first report of them (the same value when it did not).
        self.ssi_position.restart(self.settings.version);
        self.sync_sensor_objects();
    }

    /// IDX 0x7390 "missing main sensor: adapt the axis configuration": the configured SSI sensor's format (0x3012)
    /// cannot be read. The commutation in force stays (the fault keeps the power off).
    #[cold]
    #[inline(never)]
    fn ssi_format_unreadable(&mut self) {
        let detail = self.dictionary.get::<u32>(h::SSI_DATA_BITS).cast_signed();
        self.raise(FaultId::MissingMainSensor, detail);
    }

    /// The SSI format of 0x3012, or `None` when it is not one the drive reads.
    fn ssi_format(&self) -> Option<SsiFormat> {
        let d = &self.dictionary;
        SsiFormat::from_od(
            d.get(h::SSI_DATA_BITS),
            d.get(h::SSI_ENCODING),
            d.get(h::SSI_POSITION_BITS),
            d.get(h::SSI_COMMUTATION_OFFSET),
        )
        .ok()
    }

    /// The board's SSI port for the configuration the drive starts with: the clocked bits per frame and the data
    /// rate 0x3012:01; `None` without an SSI sensor.
    #[must_use]
    pub fn ssi_port(&self) -> Option<(u8, u32)> {
        match self.settings.commutation.method {
            CommutationMethod::Absolute(ssi) => {
                Some((ssi.frame_bits, u32::from(self.dictionary.get(h::SSI_DATA_RATE))))
            }
            _ => None,
        }
    }

    /// The background's SSI step ([`ssi_position`]): the raw-value objects of the reported frame, the absolute
    /// position's base once per commutation (the axis's offset becomes base + 0x3012:0E), the whole-frame check,
    /// and 0x3012:0E kept equal to what homing or a master made the offset.
    #[cold]
    #[inline(never)]
    fn ssi_background(&mut self, ssi: &SsiFormat) {
        let r = &self.report;
        let frame = r.ssi_frame;
        let faulted = matches!(r.power, PowerState::Fault(_));
        let verdict = self.ssi_position.report(ssi, frame, r.encoder_position, r.settings_version, faulted);
        if verdict != ssi_position::FrameVerdict::Ignored {
            let d = &mut self.dictionary;
            d.set(h::SSI_POSITION_RAW, ssi.position(frame));
            // At most 16 special bits (`SsiFormat::from_od`): the conversion is exact.
            d.set(h::SSI_SPECIAL_BITS, ssi.special(frame) as u16);
        }
        let saved: i32 = self.dictionary.get(h::SSI_POSITION_OFFSET);
        match verdict {
            ssi_position::FrameVerdict::Established { base } => {
                self.axis.set_position_offset(base.wrapping_add(saved));
                self.ssi_position.set_offset_applied(saved);
                return;
            }
            ssi_position::FrameVerdict::Inconsistent(difference) => {
                self.raise(FaultId::SsiFrame, difference);
                return;
            }
            ssi_position::FrameVerdict::Consistent | ssi_position::FrameVerdict::Ignored => {}
        }
        let Some(base) = self.ssi_position.base() else { return };
        if saved != self.ssi_position.offset_applied() {
            // A master wrote 0x3012:0E: the position follows it.
            self.axis.set_position_offset(base.wrapping_add(saved));
            self.ssi_position.set_offset_applied(saved);
        } else {
            // Homing moved the offset: 0x3012:0E keeps what 0x1010 is to save.
            let homed = self.axis.position_offset().wrapping_sub(base);
            if homed != saved {
                self.dictionary.set(h::SSI_POSITION_OFFSET, homed);
                self.ssi_position.set_offset_applied(homed);
            }
        }
    }

    /// Writes the objects derived from 0x3000:01 and the encoder: 0x3000:03 (commutation sensors: bits 7..4 = 3
    /// with the Halls, bits 3..0 = 1 with the encoder) and 0x3000:05 (below).
    pub(crate) fn sync_sensor_objects(&mut self) {
        let sensors = self.dictionary.get(h::SENSORS_CONFIGURATION);
        let absolute = if sensor_3_is_hall(sensors) {
            0x30
        } else if sensor_2_is_ssi(sensors) {
            0x20
        } else {
            0
        };
        let relative = u32::from(sensor_1_is_encoder(sensors));
        self.dictionary.set(h::COMMUTATION_SENSORS, absolute | relative);
        self.sync_main_sensor_resolution();
    }

    /// Writes 0x3000:05 (main sensor resolution, read-only: the drive is its single writer), the increments per
    /// revolution of the position sensor, which the motion units (rpm, rpm/s, the loop gains) convert with: with
    /// the encoder as sensor 1 (0x3000:01 bits 7..0 = 1), 4 x 0x3010:01; any resolution the dictionary allows is
    /// exact, power of two or not (16..=2,500,000 lines are 64..=10,000,000 increments, the range
    /// [`EncoderConfig::from_od`] clamps to). Without the encoder the Halls count the position, 6 x pole pairs
    /// increments per revolution ([`hall_position`], EPOS4 S1 L1433-1455).
    fn sync_main_sensor_resolution(&mut self) {
        let d = &self.dictionary;
        let pole_pairs = d.get(h::MOTOR_POLE_PAIRS);
        let sensors = d.get(h::SENSORS_CONFIGURATION);
        let counts = if sensor_1_is_encoder(sensors) {
            EncoderConfig::from_od(d.get(h::ENCODER_PULSES), 0, pole_pairs).counts_per_rev
        } else if sensor_2_is_ssi(sensors) {
            // The SSI position's increments per revolution as tier 1 counts them (2^single-turn position bits).
            self.ssi_format().map_or(0, |ssi| ssi.counts_per_rev())
        } else {
            u32::from(pole_pairs.max(1)).saturating_mul(6)
        };
        self.dictionary.set(h::MAIN_SENSOR_RESOLUTION, counts);
    }

    // ---------------------------------------------------------------------------------------------------------
    // Observation
    // ---------------------------------------------------------------------------------------------------------

    /// The power-stage state: tier 1's last report, or the state a request tier 1 has not yet acted on leads to.
    #[must_use]
    pub fn state(&self) -> PowerState {
        if self.report.power_sequence == self.setpoint.power.sequence {
            self.report.power
        } else {
            self.predicted
        }
    }

    /// The shunt offsets in use, as tier 1 last reported them.
    #[must_use]
    pub const fn offsets(&self) -> &ShuntOffsets {
        &self.report.offsets
    }

    /// What tier 1 measured and commanded in the period of its last report.
    #[must_use]
    pub const fn signals(&self) -> &FastSignals {
        &self.report.signals
    }

    /// The demand scale and limits in force.
    #[must_use]
    pub const fn demand_scale(&self) -> &DemandScale {
        &self.scale
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

    /// The input edges and index latched by tier 1, as last reported.
    #[must_use]
    pub const fn latches(&self) -> &PinLatches {
        &self.report.latches
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

/// 0x3000:01 bits 7..0, sensor 1 type: 1 = digital incremental encoder (0x3010).
const fn sensor_1_is_encoder(sensors: u32) -> bool {
    sensors & 0xFF == 1
}

/// 0x3000:01 bits 15..8, sensor 2 type: 3 = SSI absolute encoder (0x3012, IDX L3780).
const fn sensor_2_is_ssi(sensors: u32) -> bool {
    (sensors >> 8) & 0xFF == 3
}

/// 0x3000:01 bits 23..16, sensor 3 type: 4 = digital Hall sensor (0x301A).
const fn sensor_3_is_hall(sensors: u32) -> bool {
    (sensors >> 16) & 0xFF == 4
}
