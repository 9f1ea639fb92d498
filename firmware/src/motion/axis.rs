//! The axis: one tier-2 step (2.5 kHz) of the complete CiA 402 drive on top of the current loop.
//!
//! Order within a step (every input is the latest, every output goes out in the same step):
//! 1. parameters: converted before the step by [`Axis::refresh`] (compared raw, converted on change:
//!    [`MotionParams`], [`Loops`], [`Monitor`]);
//! 2. feedback: position actual = encoder position + home offset; velocity estimate ([`Loops::estimate`]);
//! 3. inputs: input functions with their latched edges ([`Io::inputs`]); the outputs (brake, ready) follow the
//!    machine in the same step ([`Io::outputs`]);
//! 4. supervision into the fault manager: faults of the power stage (latched by tier 1), following error,
//!    software position limits, limit switches;
//! 5. the CiA 402 machine ([`StateMachine`]) with the controlword (the quick-stop input acts as «Quick stop», the
//!    drive-enable input withdraws «Enable operation»), the fault inputs and the standstill of a running stop;
//! 6. the motion its outputs ask for: nothing (drive function off), hold, a stop ramp (the option codes' ramps on
//!    the shared trajectory generator, or the current limit on the velocity loop), or the active mode;
//! 7. limits (software position limits, speed) on the demand, then the loops: the q-current demand;
//! 8. the statusword with the mode's bits, and the actual and demand values into the dictionary.
//!
//! Power-stage requests go back to [`crate::drive::Drive`] as [`AxisOutputs`]; the drive carries them out on its
//! power stage (calibration, enable, disable) before the next fast tick.
//!
//! Cyclic torque (CST) runs in tier 1: the drive reads 0x6071 + 0x60B2 every current-loop period
//! ([`CurrentDemand::TargetTorque`]), so torque follows its target within the current-loop figures (40 us)
//! instead of one slow tick plus an interpolation period; 0x60C2 does not apply to CST (EPOS4 application notes
//! L4770-4771 advise 0 for CST anyway).

use super::cyclic::{cyclic_mode, Cyclic};
use super::homing::{Homing, HomingInput};
use super::loops::{velocity_of, Loops};
use super::monitor::{ticks_from_ms, Monitor};
use super::params::MotionParams;
use super::profile_position::{PpmInput, ProfilePosition};
use super::profile_velocity::{ProfileVelocity, PvmInput};
use super::torque_ramp::TorqueRamp;
use super::{AxisFeedback, LoopDemand, ModeStatus, ModeStep};
use crate::cia402::machine::{Config, Inputs, Motion, PowerStage, StateMachine, StatusInputs, Stop, StopThen};
use crate::cia402::{Controlword, Mode, State, StatusFlags, Statusword, StopRamp, Ticks, Transition};
use crate::control::demand::DemandScale;
use crate::control::frames::Amps;
use crate::control::interpolator::CyclicSetpoint;
use crate::control::trajectory::{Acceleration, ProfileGenerator, Setpoint, Velocity};
use crate::control::velocity::sat_i32;
use crate::control::velocity_estimate::PositionWindow;
use crate::fault::i2t::{I2tConfig, MotorI2t};
use crate::fault::snapshot::DiagnosisSnapshot;
use crate::fault::table::FaultId;
use crate::fault::FaultManager;
use crate::io::{InputState, Io};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::power_state::PowerState;
use crate::sensors::latch::{EdgeLatch, PinLatches};

/// What the drive hands the axis every slow tick.
#[derive(Clone, Copy, Debug)]
pub struct AxisInputs<'a> {
    /// Multi-turn encoder position (wrapping increments, tier 1's count).
    pub encoder_position: i32,
    /// Tier 1's last latched window of encoder positions (the averaged velocity estimate); `None` when the Hall
    /// sensors count the position (no encoder), then the estimate uses the position difference.
    pub encoder_window: Option<PositionWindow>,
    /// The measured q current of the last fast tick.
    pub current: Amps,
    /// The bus-voltage limiter held a braking q current back in the last slow tick (`drive::regeneration`): a stop
    /// ramp the motor cannot follow starts again from the actual motion.
    pub braking_limited: bool,
    /// What the winding carries: the magnitude of the measured d/q current, or an upper bound of it (the d current
    /// is not zero while the bus-voltage limiter brakes with losses: `drive::regeneration`).
    pub winding_current: Amps,
    /// The averaged q current, mA (0x30D1:01).
    pub current_average_ma: i32,
    /// Phase currents of the last fast tick, mA (fault snapshots).
    pub phase_currents_ma: [i32; 3],
    /// DC-bus voltage, mV (fault snapshots).
    pub bus_voltage_mv: i32,
    /// Input levels and the positions latched at their edges and at the index.
    pub pins: &'a PinLatches,
    /// The power stage's state.
    pub power: PowerState,
    /// The cause of the power stage's fault is still measured (bus still over-voltage, break input still set).
    pub power_fault_present: bool,
    /// Torque/current scaling and limits (0x3001, 0x6072, 0x6073).
    pub scale: &'a DemandScale,
}

/// Where the q-current reference comes from after this step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CurrentDemand {
    /// The drive function is off.
    Off,
    /// The loops' demand.
    Internal(Amps),
    /// CST: 0x6071 + 0x60B2, read by tier 1 every period.
    TargetTorque,
    /// Auto setup (0x6060 = -2): the motor identification sets tier 1's demand (`crate::drive::auto_setup`).
    Identification,
}

/// What the drive must do after this step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisOutputs {
    /// The machine's power-stage request.
    pub power: PowerStage,
    /// Start the current-offset calibration (transition 3).
    pub start_calibration: bool,
    /// Transition 15 completed: clear the power stage's fault latch.
    pub fault_reset: bool,
    /// The current demand.
    pub demand: CurrentDemand,
    /// Output pin levels (bit n = output n+1).
    pub output_pins: u8,
    /// The machine's state.
    pub state: State,
}

/// What the axis is doing with the motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Activity {
    /// Drive function off.
    Idle,
    /// Holding position.
    Holding,
    /// Following the set-points of this mode.
    Following(Mode),
    /// Carrying out a stop of the machine.
    Stopping { stop: Stop, on_current_limit: bool },
}

/// The axis. See the module documentation.
#[derive(Clone, Debug)]
// `repr(C)` with what every slow tick touches first and the large, rarely reached state (the fault manager's
// slots, the homing and profile modes, the I2t model) last: the step reaches its fields with short offsets
// (measured in the QEMU image).
#[repr(C)]
pub struct Axis {
    machine: StateMachine,
    params: MotionParams,
    loops: Loops,
    monitor: Monitor,
    io: Io,
    generator: ProfileGenerator,
    cyclic: Cyclic,
    now: Ticks,
    /// Position actual value minus encoder position (set by homing).
    offset: i32,
    /// The dual loop's main sensor: the load position in motor increments ([`Self::set_main_sensor_position`]).
    main_sensor: Option<i32>,
    activity: Activity,
    /// The demand of the last step (for continuity across mode changes and stops).
    last_setpoint: Setpoint,
    mode_status: ModeStatus,
    following_error_exceeded: bool,
    internal_limit: bool,
    referenced: bool,
    standstill: bool,
    remote: bool,
    drive_fault_seen: bool,
    previous_controlword: Controlword,
    last_position: i32,
    /// The negative and positive limit switch were active while driving in the last step (so that only a new
    /// contact, or motion further into the switch, is an error).
    limit_seen: [bool; 2],
    faults: FaultManager,
    homing: Homing,
    ppm: ProfilePosition,
    pvm: ProfileVelocity,
    /// Motor I2t (0x3200:01), with its configuration from 0x3001 and the raw values it was built from.
    i2t: MotorI2t,
    /// The torque ramp of a CST stop with the slow-down ramp (set when such a stop starts).
    torque_ramp: Option<TorqueRamp>,
    /// 0x30D3:01's filter state: the velocity estimate through a first-order 5 Hz low-pass ([`average_velocity`]).
    velocity_average: Velocity,
    i2t_config: I2tConfig,
    i2t_objects: (u32, u32, u16),
    i2t_warning: bool,
    i2t_current_limit_ma: u32,
    /// The auto setup finished successfully (statusword bit 12 in 0x6060 = -2, PD4-E "aligned").
    auto_setup_done: bool,
    /// The last step's position demand, position and velocity, for [`Axis::publish_master_values`].
    shown: (i32, i32, Velocity),
}

impl Axis {
    /// An axis over the parameters of `d`, in «Not ready to switch on».
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        Self {
            machine: StateMachine::new(Config::DEFAULT),
            faults: FaultManager::new(),
            params: MotionParams::new(d),
            loops: Loops::new(d),
            monitor: Monitor::new(d),
            io: Io::new(),
            generator: ProfileGenerator::new(0),
            ppm: ProfilePosition::new(),
            pvm: ProfileVelocity::new(),
            homing: Homing::new(),
            cyclic: Cyclic::new(),
            now: Ticks(0),
            offset: 0,
            activity: Activity::Idle,
            last_setpoint: Setpoint::default(),
            mode_status: ModeStatus::default(),
            following_error_exceeded: false,
            internal_limit: false,
            referenced: false,
            standstill: false,
            remote: false,
            drive_fault_seen: false,
            auto_setup_done: false,
            shown: (0, 0, Velocity::ZERO),
            previous_controlword: Controlword(0),
            last_position: 0,
            main_sensor: None,
            limit_seen: [false; 2],
            i2t: MotorI2t::new(),
            velocity_average: Velocity::ZERO,
            torque_ramp: None,
            i2t_warning: false,
            i2t_current_limit_ma: u32::MAX,
            i2t_config: I2tConfig::from_od(
                d.get(h::MOTOR_NOMINAL_CURRENT),
                d.get(h::MOTOR_OUTPUT_CURRENT_LIMIT),
                d.get(h::MOTOR_THERMAL_TIME_CONSTANT),
            ),
            i2t_objects: (
                d.get(h::MOTOR_NOMINAL_CURRENT),
                d.get(h::MOTOR_OUTPUT_CURRENT_LIMIT),
                d.get(h::MOTOR_THERMAL_TIME_CONSTANT),
            ),
        }
    }

    /// The position sensor changed (encoder or Halls, 0x3000:01): its coordinates jump, so the velocity estimate
    /// restarts from the next position.
    pub fn position_sensor_changed(&mut self) {
        self.loops.restart_estimate();
    }

    /// Statusword bit 9: the fieldbus controls the drive (NMT operational, EtherCAT SafeOp/Op).
    pub fn set_remote(&mut self, remote: bool) {
        self.remote = remote;
    }

    /// A master set-point arrived (SYNC, SM2 event): latches 0x607A, 0x60FF, 0x6071 and the offsets for the
    /// cyclic modes' interpolation, in the axis's units (polarity 0x607E: positions by bit 7, the target velocity by
    /// bit 6, the velocity and torque offsets by the bit of the mode 0x6060 asks for, [`super::polarity`]; the gear:
    /// load increments to motor increments, load rpm through the geared scale, [`super::gear`]).
    pub fn setpoint_received(&mut self, d: &Dictionary) {
        let (scale, units) = (&self.params.scale, &self.params.units);
        let polarity = units.polarity;
        let torque = units.torque_polarity;
        let position_mode = d.get(h::MODES_OF_OPERATION) == Mode::CyclicSyncPosition.code();
        let (target_position, position_offset) = if units.positions_unchanged() {
            (d.get(h::TARGET_POSITION), d.get(h::POSITION_OFFSET))
        } else {
            (units.position_to_axis(d.get(h::TARGET_POSITION)), units.position_to_axis(d.get(h::POSITION_OFFSET)))
        };
        self.cyclic.push(CyclicSetpoint {
            target_position,
            target_velocity: scale.velocity_from_rpm(polarity.velocity_rpm(d.get(h::TARGET_VELOCITY))),
            target_torque: torque.torque(d.get(h::TARGET_TORQUE)),
            position_offset,
            velocity_offset: scale
                .velocity_from_rpm(polarity.velocity_offset_rpm(d.get(h::VELOCITY_OFFSET), position_mode)),
            torque_offset: torque.torque_offset(d.get(h::TORQUE_OFFSET), position_mode),
        });
    }

    /// The CiA 402 state.
    #[must_use]
    pub const fn state(&self) -> State {
        self.machine.state()
    }

    /// The fault manager (0x603F, 0x1001, 0x1003, EMCY).
    #[must_use]
    pub const fn faults(&self) -> &FaultManager {
        &self.faults
    }

    /// The fault manager, mutable (communication supervision, EMCY transmission).
    pub fn faults_mut(&mut self) -> &mut FaultManager {
        &mut self.faults
    }

    /// The velocity estimate of the last step.
    #[must_use]
    pub fn velocity(&self) -> Velocity {
        velocity_of(self.loops.velocity_estimate())
    }

    /// The demand of the last step.
    #[must_use]
    pub const fn setpoint(&self) -> &Setpoint {
        &self.last_setpoint
    }

    /// The dual loop's main sensor for the next step: the load position in motor increments (the coordinates of
    /// the encoder position, `motion::dual_loop`) with its fraction of an increment (`U0F16`, for the main loop),
    /// or `None` when the motor encoder is the main sensor. Set by the drive's background step before the step of
    /// the same slow period (both see the same tier-1 report).
    pub fn set_main_sensor_position(&mut self, load: Option<(i32, u16)>) {
        self.main_sensor = load.map(|(position, _)| position);
        self.loops.set_dual_loop(load.is_some(), load.map_or(0, |(_, fraction)| fraction));
    }

    /// The dual loop's load scale, taken with the sensor configuration at switch-on (`motion::dual_loop`).
    pub fn set_load_scale(&mut self, scale: Option<super::dual_loop::LoadScale>) {
        self.loops.set_load_scale(scale);
        self.params.set_main_sensor(scale);
    }

    /// Position actual value minus the encoder position.
    #[must_use]
    pub const fn position_offset(&self) -> i32 {
        self.offset
    }

    /// Sets the position offset (position actual value minus the encoder position): an absolute sensor's offset
    /// after a restart (`crate::drive::ssi_position`). The velocity estimate restarts from the next position.
    pub fn set_position_offset(&mut self, offset: i32) {
        self.offset = offset;
        self.loops.restart_estimate();
    }

    /// Slow ticks since start-up.
    #[must_use]
    pub const fn now(&self) -> Ticks {
        self.now
    }

    /// One slow tick. See the module documentation.
    pub fn step(&mut self, input: &AxisInputs<'_>, d: &mut Dictionary) -> AxisOutputs {
        self.now = Ticks(self.now.0.wrapping_add(1));
        let now = self.now;

        // 2. Feedback: the velocity from the motor encoder; the position from the main sensor, the load encoder in
        // the dual loop (EPOS4 AN ch. 10), else the motor encoder.
        let motor = input.encoder_position.wrapping_add(self.offset);
        let velocity = velocity_of(self.loops.estimate(motor, input.encoder_window, input.current));
        let position = match self.main_sensor {
            Some(load) => load.wrapping_add(self.offset),
            None => motor,
        };

        // 3. Inputs (the outputs follow the machine, below).
        let inputs = self.io.inputs(input.pins, self.offset, d);

        // 4. Supervision. Motor I2t (EPOS3 S0 L2455-2545): at its limit the current is limited to the nominal
        // current until the level falls below 95 %; a warning (0x3200:01 shows the level).
        let i2t = self.i2t.step(input.winding_current.to_milliamps(), &self.i2t_config);
        self.i2t_current_limit_ma = i2t.current_limit_ma;
        if i2t.limit_reached != self.i2t_warning {
            self.i2t_warning = i2t.limit_reached;
            if i2t.limit_reached {
                let snapshot = DiagnosisSnapshot {
                    motor_i2t_percent: i2t.level_percent,
                    position_inc: position,
                    state: self.machine.state(),
                    tick: now,
                    ..DiagnosisSnapshot::EMPTY
                };
                self.faults.raise(FaultId::MotorI2tLimit, snapshot, now);
            } else {
                self.faults.clear_cause(FaultId::MotorI2tLimit);
            }
        }
        self.supervise(input, &inputs, position, velocity);

        // 5. The machine.
        let raw_cw = Controlword(d.get(h::CONTROLWORD));
        if raw_cw.fault_reset_edge(self.previous_controlword) {
            // Refused (a cause persists) leaves the faults latched; the machine then refuses transition 15.
            let _ = self.faults.reset_request();
        }
        self.previous_controlword = raw_cw;
        let mut cw = raw_cw;
        if inputs.quick_stop {
            cw.0 &= !Controlword::QUICK_STOP;
        }
        if !inputs.drive_enable {
            cw.0 &= !Controlword::ENABLE_OPERATION;
        }
        let machine_in = Inputs {
            controlword: cw,
            modes_of_operation: d.get(h::MODES_OF_OPERATION),
            options: self.params.options,
            fault: self.faults.take_machine_input(),
            connection_lost: self.faults.connection_lost(),
            safe_torque_off: self.faults.safe_torque_off_active(),
            initialized: true,
            calibration_done: matches!(input.power, PowerState::SwitchedOn | PowerState::OperationEnabled),
            standstill: self.standstill,
            remote: self.remote,
            status: StatusInputs::default(),
        };
        let out = self.machine.step(&machine_in, now);
        let output_pins = self.io.outputs(out.brake, !self.faults.any_fault(), d);

        // 6. Motion.
        let feedback = AxisFeedback {
            now,
            position,
            velocity,
            current_average_ma: input.current_average_ma,
            negative_limit: inputs.negative_limit,
            positive_limit: inputs.positive_limit,
            home_switch: inputs.home_switch,
            index: EdgeLatch {
                count: input.pins.index.count,
                position: input.pins.index.position.wrapping_add(self.offset),
            },
        };
        let (step, position) = self.motion(out.motion, out.mode.active, cw, &feedback, input.braking_limited, d);

        // 7. Limits and loops.
        let demand = match step {
            None => CurrentDemand::Off,
            Some(_) if self.activity == Activity::Following(Mode::CyclicSyncTorque) => {
                self.internal_limit = false;
                CurrentDemand::TargetTorque
            }
            Some(_) if self.activity == Activity::Following(Mode::AutoSetup) => {
                self.internal_limit = false;
                self.loops.reset();
                CurrentDemand::Identification
            }
            Some(step) => CurrentDemand::Internal(self.run_loops(step, position, input.scale)),
        };
        if step.is_none() {
            self.loops.reset();
            self.internal_limit = false;
        }

        // 8. Status and actual values.
        self.mode_status = match (self.activity, step) {
            (Activity::Following(_), Some(s)) => s.status,
            (Activity::Stopping { stop: Stop { then: StopThen::StayEnabled, .. }, .. }, Some(s)) => s.status,
            _ => ModeStatus::default(),
        };
        // Bit 15 "position referenced": set by a successful homing, cleared while a new homing runs, kept after
        // leaving HMM (IDX L838-857). A homing that ends clears the touch probes' latches (IDX L6362: homing and
        // the touch probe cannot be used together).
        let referenced = self.homing.attained();
        if referenced && !self.referenced {
            self.io.clear_touch_probes(d);
        }
        self.referenced = referenced;
        self.publish(&out, position, velocity, d);
        AxisOutputs {
            power: out.power,
            start_calibration: out.start_current_calibration,
            fault_reset: out.transition == Some(Transition::T15),
            demand,
            output_pins,
            state: out.state,
        }
    }

    /// Whether the axis follows the auto setup mode (0x6060 = -2) in «Operation enabled».
    #[must_use]
    pub fn auto_setup_active(&self) -> bool {
        self.activity == Activity::Following(Mode::AutoSetup) && self.machine.state() == State::OperationEnabled
    }

    /// The auto setup finished successfully (statusword bit 12) or not (a new run started, or it failed).
    pub fn set_auto_setup_done(&mut self, done: bool) {
        self.auto_setup_done = done;
    }

    /// Publishes the velocity actual values beside 0x606C from the last step's estimate: 0x6069 (the estimate in
    /// increments per second, EPOS3 L7006) and 0x30D3:01 (0x606C through a 5 Hz low-pass, stepped here once per
    /// slow period). The drive runs it in the background step, outside the slow tick's budget.
    pub fn publish_velocity_actual_values(&mut self, d: &mut Dictionary) {
        let (velocity, polarity) = (self.velocity(), self.params.polarity);
        d.set(h::VELOCITY_SENSOR_ACTUAL_VALUE, polarity.shown_velocity(sat_i32(velocity.to_inc_per_s())));
        self.velocity_average = average_velocity(self.velocity_average, velocity);
        d.set(h::VELOCITY_ACTUAL_VALUE_AVERAGED, polarity.shown_velocity(self.params.rpm(self.velocity_average)));
    }

    /// Publishes the last step's positions and velocities in the master's units: 0x6062, 0x6064, 0x60F4 and the
    /// touch-probe positions through the polarity 0x607E and the gear (load increments, [`super::gear`]), 0x606B
    /// and 0x606C through the polarity and the geared scale (load rpm). The drive runs it after each step, once
    /// the step's set-point is out, in the same tier-2 period: the conversions (two exact multiplications each with
    /// a gear) are outside the step's time budget, and a process-data cycle after the period sees this step's
    /// values as before.
    #[inline(never)]
    pub fn publish_master_values(&self, d: &mut Dictionary) {
        let (demand, position, velocity) = self.shown;
        let units = &self.params.units;
        d.set(h::POSITION_DEMAND_VALUE, units.position_to_master(demand));
        d.set(h::POSITION_ACTUAL_VALUE, units.position_to_master(position));
        // The following error as the difference of the two master positions: with a gear it is then exactly what
        // the master computes from 0x6062 and 0x6064.
        let error = if units.positions_unchanged() {
            demand.wrapping_sub(position)
        } else {
            units.position_to_master(demand).wrapping_sub(units.position_to_master(position))
        };
        d.set(h::FOLLOWING_ERROR_ACTUAL_VALUE, error);
        let polarity = units.polarity;
        d.set(h::VELOCITY_DEMAND_VALUE, polarity.shown_velocity(self.params.rpm(self.last_setpoint.velocity)));
        d.set(h::VELOCITY_ACTUAL_VALUE, polarity.shown_velocity(self.params.rpm(velocity)));
        self.io.publish_probe_positions(units, d);
    }

    /// Plans the profile move, velocity command or buffered move the next step takes into force
    /// ([`ProfileGenerator::prepare`]); the drive runs it before each step, outside the step's time budget.
    pub fn prepare_motion(&mut self) {
        self.generator.prepare();
    }

    /// Converts the parameters that changed (motion parameters, gains, monitoring limits, brake timing); the
    /// drive runs it before each step, outside the step's time budget.
    pub fn refresh(&mut self, d: &mut Dictionary) {
        self.params.refresh(d);
        self.loops.refresh(d);
        if let Some(max_system_speed) = self.monitor.refresh(d, &self.params.scale, &self.params.units) {
            // 0x3000:06 (read-only, the drive its single writer): the speed limit at the load.
            d.set(h::MAX_SYSTEM_SPEED, max_system_speed);
        }
        self.refresh_machine_config(d);
        let i2t = (
            d.get(h::MOTOR_NOMINAL_CURRENT),
            d.get(h::MOTOR_OUTPUT_CURRENT_LIMIT),
            d.get(h::MOTOR_THERMAL_TIME_CONSTANT),
        );
        if i2t != self.i2t_objects {
            self.i2t_objects = i2t;
            self.i2t_config = I2tConfig::from_od(i2t.0, i2t.1, i2t.2);
        }
        d.set(h::I2T_LEVEL_MOTOR, self.i2t.level_percent());
    }

    /// The motor current limit of the I2t protection, mA: the output current limit 0x3001:02, or the nominal
    /// current 0x3001:01 while the I2t level is at its limit (the drive applies it before the next step).
    #[must_use]
    pub const fn i2t_current_limit_ma(&self) -> u32 {
        self.i2t_current_limit_ma
    }

    /// Standstill timeout 0x30E0:03 and the brake delays 0x3158 (only with a brake output configured).
    fn refresh_machine_config(&mut self, d: &Dictionary) {
        let timeout = d.get(h::STANDSTILL_WINDOW_TIMEOUT);
        let brake = self.io.brake_present();
        let config = Config {
            standstill_timeout: (timeout != u16::MAX).then(|| ticks_from_ms(u32::from(timeout))),
            brake_engage_delay: if brake { ticks_from_ms(u32::from(d.get(h::BRAKE_RISE_TIME))) } else { Ticks(0) },
            brake_release_delay: if brake { ticks_from_ms(u32::from(d.get(h::BRAKE_FALL_TIME))) } else { Ticks(0) },
            initial_mode: Config::DEFAULT.initial_mode,
        };
        if config != self.machine.config() {
            self.machine.set_config(config);
        }
    }

    /// Raises and clears the faults the axis detects.
    fn supervise(&mut self, input: &AxisInputs<'_>, inputs: &InputState, position: i32, velocity: Velocity) {
        // The diagnosis data, built only when something is raised (the rpm conversion is 128-bit).
        let scale = self.params.scale;
        let (state, now) = (self.machine.state(), self.now);
        let snapshot = |detail: i32| DiagnosisSnapshot {
            phase_currents_ma: input.phase_currents_ma,
            bus_voltage_mv: input.bus_voltage_mv,
            position_inc: position,
            velocity_rpm: i32::try_from(scale.velocity_to_rpm(velocity)).unwrap_or(i32::MAX),
            state,
            tick: now,
            detail,
            ..DiagnosisSnapshot::EMPTY
        };
        // The power stage latched a fault in tier 1 (the outputs are already off). It is raised once; its cause
        // is cleared when the power stage no longer measures it, so a fault reset is refused until then.
        match input.power {
            PowerState::Fault(e) => {
                let id = e.fault_id();
                if !self.drive_fault_seen {
                    self.drive_fault_seen = true;
                    self.faults.raise(id, snapshot(e.fault_detail()), self.now);
                }
                if !input.power_fault_present {
                    self.faults.clear_cause(id);
                }
            }
            _ => self.drive_fault_seen = false,
        }
        let driving = self.machine.power().torque_allowed();
        let homing = self.activity == Activity::Following(Mode::Homing);
        if self.following_error_exceeded && driving {
            let fe = self.fe();
            self.faults.raise(FaultId::FollowingError, snapshot(fe), self.now);
        }
        let outside = self.monitor.outside_limits(position);
        if outside && driving && !homing {
            self.faults.raise(FaultId::SoftwarePositionLimit, snapshot(0), self.now);
        } else if !outside {
            self.faults.clear_cause(FaultId::SoftwarePositionLimit);
        }
        // A limit switch is an error when it is reached while driving, or when the drive moves further into it
        // (IDX L7089-7090: an event, reset at once); moving off the switch after the reset is allowed.
        // Functions 24/25 (limit switches without error) raise nothing; the homing methods use them.
        let demand = self.last_setpoint.velocity.0;
        let limits = [
            (inputs.negative_limit_error, demand < 0, FaultId::NegativeLimitSwitch),
            (inputs.positive_limit_error, demand > 0, FaultId::PositiveLimitSwitch),
        ];
        for ((switch, into, id), seen) in limits.into_iter().zip(self.limit_seen.iter_mut()) {
            if switch && driving && !homing && (!*seen || into) {
                self.faults.raise(id, snapshot(0), self.now);
            }
            *seen = switch;
        }
    }

    fn fe(&self) -> i32 {
        self.last_setpoint.position_i32().wrapping_sub(self.last_position)
    }

    /// Step 6: the motion for the machine's request; `None` when the drive function is off. Returns the position
    /// actual value in the coordinates after the step (homing may move them). `braking_limited`:
    /// [`AxisInputs::braking_limited`].
    fn motion(
        &mut self,
        motion: Motion,
        mode: Mode,
        cw: Controlword,
        fb: &AxisFeedback,
        braking_limited: bool,
        d: &Dictionary,
    ) -> (Option<ModeStep>, i32) {
        // Bit 11 is recomputed every step: the mode (target clamped, speed limited) and the loops set it.
        self.internal_limit = false;
        match motion {
            Motion::Disabled => {
                self.activity = Activity::Idle;
                self.generator.reset(i64::from(fb.position));
                self.last_setpoint = Setpoint { position: i64::from(fb.position), ..Setpoint::default() };
                self.standstill = true;
                (None, fb.position)
            }
            Motion::Hold => {
                if self.activity != Activity::Holding {
                    self.take_over_generator(fb.position);
                    if self.activity != Activity::Idle {
                        let hold = self.generator.setpoint().position;
                        self.generator.reset(hold);
                    }
                    self.activity = Activity::Holding;
                }
                let sp = self.generator.step();
                (Some(position_step(sp)), fb.position)
            }
            Motion::Stop(stop) if stop.then == StopThen::StayEnabled && mode.halt_applies() => {
                // Halt in PPM/PVM/HMM: the mode stops by itself (controlword bit 8) and keeps its status bits.
                self.follow(mode, cw, fb, d)
            }
            Motion::Stop(stop) => {
                let started = matches!(self.activity, Activity::Stopping { stop: s, .. } if s == stop);
                if !started {
                    // CST's slow-down ramp is the torque slope 0x6087 (`torque_ramp`), from the torque demand 0x6074.
                    let cst = self.activity == Activity::Following(Mode::CyclicSyncTorque);
                    self.torque_ramp = (cst && stop.ramp == StopRamp::SlowDown)
                        .then(|| TorqueRamp::new(i32::from(d.get(h::TORQUE_DEMAND_VALUE)), d.get(h::TORQUE_SLOPE)));
                    let on_current_limit = if self.torque_ramp.is_some() {
                        // The generator stays where the demand is, for whatever follows the stop.
                        self.take_over_generator(fb.position);
                        false
                    } else {
                        self.begin_stop(stop, fb)
                    };
                    self.activity = Activity::Stopping { stop, on_current_limit };
                }
                if let Some(ramp) = &mut self.torque_ramp {
                    let permille = ramp.step();
                    self.standstill = ramp.done();
                    let step = ModeStep { demand: LoopDemand::Torque { permille }, status: ModeStatus::default() };
                    return (Some(step), fb.position);
                }
                let on_current_limit = matches!(self.activity, Activity::Stopping { on_current_limit: true, .. });
                let standstill = self.monitor.standstill(fb.velocity, fb.now);
                if on_current_limit {
                    self.standstill = standstill;
                    // Hold where the motor stopped once it has.
                    if standstill {
                        self.generator.reset(i64::from(fb.position));
                        self.activity = Activity::Stopping { stop, on_current_limit: false };
                    }
                    let step = ModeStep {
                        demand: LoopDemand::Velocity { velocity: Velocity::ZERO, acceleration: Acceleration::ZERO },
                        status: ModeStatus::default(),
                    };
                    return (Some(step), fb.position);
                }
                if braking_limited && !self.generator.is_done() {
                    // The bus-voltage limiter could not give the braking the ramp asks for (no chopper, or not
                    // enough): the ramp starts again from the actual motion, as a drive's DC-link limiter stretches
                    // its ramp-down, instead of running ahead into a following error the bus forbids correcting.
                    self.generator.reset_moving(i64::from(fb.position), fb.velocity);
                    let _ = self.begin_stop(stop, fb);
                }
                let sp = self.generator.step();
                self.standstill = self.generator.is_done() && standstill;
                (Some(position_step(sp)), fb.position)
            }
            Motion::Follow => self.follow(mode, cw, fb, d),
        }
    }

    /// Makes the shared trajectory generator continue from the present demand before a new activity uses it: at
    /// the actual `position` when the drive function was off, from the last demand (position and velocity) when
    /// the loops followed something else (a cyclic mode, a current-limit stop); untouched when it already drove
    /// the demand.
    fn take_over_generator(&mut self, position: i32) {
        if self.activity == Activity::Idle {
            self.generator.reset(i64::from(position));
        } else if !uses_generator(self.activity) {
            self.generator.reset_moving(self.last_setpoint.position, self.last_setpoint.velocity);
        }
    }

    /// Starts a stop ramp from the present demand; `true` when it runs on the current limit instead.
    fn begin_stop(&mut self, stop: Stop, fb: &AxisFeedback) -> bool {
        self.take_over_generator(fb.position);
        let shaped = stop.then == StopThen::StayEnabled;
        let deceleration = match stop.ramp {
            StopRamp::SlowDown => match self.activity {
                Activity::Following(Mode::Homing) => self.params.homing_acceleration,
                _ => self.params.profile.deceleration,
            },
            StopRamp::QuickStop => self.params.quick_stop_deceleration,
            StopRamp::CurrentLimit | StopRamp::VoltageLimit => return true,
        };
        if shaped {
            self.generator.halt(deceleration);
        } else {
            self.generator.quick_stop(deceleration);
        }
        false
    }

    /// Follows the active mode, entering it first when it changed.
    fn follow(&mut self, mode: Mode, cw: Controlword, fb: &AxisFeedback, d: &Dictionary) -> (Option<ModeStep>, i32) {
        // A new interpolation period (0x60C2 written while following) restarts the interpolation from the demand.
        let period_changed = mode.is_cyclic() && self.cyclic.period() != self.params.period;
        if self.activity != Activity::Following(mode) || period_changed {
            if period_changed {
                self.activity = Activity::Holding;
                self.generator.reset_moving(self.last_setpoint.position, self.last_setpoint.velocity);
            }
            self.enter(mode, cw, fb);
        }
        let p = &self.params;
        let halt_deceleration = match p.options.halt().ramp() {
            StopRamp::QuickStop => p.quick_stop_deceleration,
            StopRamp::SlowDown if mode == Mode::Homing => p.homing_acceleration,
            StopRamp::SlowDown => p.profile.deceleration,
            StopRamp::CurrentLimit | StopRamp::VoltageLimit => Acceleration::MAX,
        };
        let step = match mode {
            Mode::ProfilePosition => {
                let (target, clamped) = self.monitor.clamp_position(p.targets.position);
                self.internal_limit = clamped;
                let input = PpmInput {
                    controlword: cw,
                    target_position: target,
                    params: p.profile,
                    halt_deceleration,
                    windows: p.windows,
                };
                self.ppm.step(&input, &mut self.generator, fb)
            }
            Mode::ProfileVelocity => {
                let input = PvmInput {
                    controlword: cw,
                    target_velocity: p.targets.velocity,
                    params: p.profile,
                    halt_deceleration,
                    windows: p.windows,
                };
                let step = self.pvm.step(&input, &mut self.generator, fb);
                // IDX PVM bit 11: the target velocity is limited to 0x607F.
                self.internal_limit = self.pvm.speed_limited();
                step
            }
            Mode::Homing => {
                let limit = p.targets.search_distance_limit;
                let input = HomingInput {
                    controlword: cw,
                    method: d.get(h::HOMING_METHOD),
                    switch_search_speed: p.homing_switch_speed,
                    zero_search_speed: p.homing_zero_speed,
                    acceleration: p.homing_acceleration,
                    offset_move_distance: p.targets.home_offset_move_distance,
                    home_position: p.targets.home_position,
                    current_threshold_ma: u32::from(d.get(h::HOMING_CURRENT_THRESHOLD)),
                    search_distance_limit: (limit != 0).then_some(limit),
                    halt_deceleration,
                };
                let step = self.homing.step(&input, &mut self.generator, fb);
                if step.reset_loops {
                    // The end stop was found: the demand stands at the actual position; the integral wound up
                    // pushing against the stop goes too (the loops restart from zero current at the next step).
                    self.loops.reset();
                }
                if let Some(r) = step.rereference {
                    let delta = r.to.wrapping_sub(r.from);
                    self.offset = self.offset.wrapping_add(delta);
                    let demand = self.generator.setpoint().position.wrapping_add(i64::from(delta));
                    self.generator.reset(demand);
                    let position = fb.position.wrapping_add(delta);
                    self.loops.rereference(position);
                    let mut mode_step = step.mode;
                    if let LoopDemand::Position(sp) = &mut mode_step.demand {
                        sp.position = demand;
                        sp.position_fine = demand.wrapping_mul(1 << 16);
                    }
                    return (Some(mode_step), position);
                }
                step.mode
            }
            Mode::CyclicSyncPosition | Mode::CyclicSyncVelocity => self.cyclic.step(),
            Mode::CyclicSyncTorque => ModeStep {
                demand: LoopDemand::Torque { permille: 0 },
                status: ModeStatus { target_reached: false, bit12: true, bit13: false },
            },
            // The identification drives tier 1 itself; bit 12 is PD4-E's "aligned" (seed 003 p.76).
            Mode::AutoSetup => ModeStep {
                demand: LoopDemand::Torque { permille: 0 },
                status: ModeStatus { target_reached: self.auto_setup_done, bit12: self.auto_setup_done, bit13: false },
            },
        };
        // CSP and CSV: the torque offset 0x60B2 as the loops' torque feedforward for this step (IDX L977, L6345);
        // taken from the cyclic step of this call, so 0 for every other mode.
        self.loops.set_torque_feedforward(self.cyclic.take_torque_feedforward());
        (Some(step), fb.position)
    }

    /// Enters `mode` from the present activity: the generator (and the interpolator) continue from the last
    /// demand, or start at the actual position when the drive function was off.
    fn enter(&mut self, mode: Mode, cw: Controlword, fb: &AxisFeedback) {
        let from_rest = matches!(self.activity, Activity::Idle);
        self.take_over_generator(fb.position);
        let start = self.generator.setpoint();
        match mode {
            Mode::ProfilePosition => self.ppm.enter(cw, &mut self.generator, fb),
            Mode::ProfileVelocity => self.pvm.enter(cw, &mut self.generator, fb),
            Mode::Homing => self.homing.enter(cw, &mut self.generator, fb),
            Mode::CyclicSyncPosition | Mode::CyclicSyncVelocity | Mode::CyclicSyncTorque => {
                if let Some(m) = cyclic_mode(mode) {
                    let velocity = if from_rest { Velocity::ZERO } else { start.velocity };
                    self.cyclic.enter(m, self.params.period, start.position_i32(), velocity);
                }
            }
            Mode::AutoSetup => {}
        }
        self.activity = Activity::Following(mode);
    }

    /// Step 7: limits on the demand, then the loops.
    fn run_loops(&mut self, step: ModeStep, position: i32, scale: &DemandScale) -> Amps {
        let homing = self.activity == Activity::Following(Mode::Homing);
        let mut demand = step.demand;
        let mut clamped = false;
        match &mut demand {
            LoopDemand::Position(sp) if !homing => {
                let (p, c) = self.monitor.clamp_position_from(sp.position_i32(), self.last_setpoint.position_i32());
                if c {
                    // Held at the software limit: no feedforward of the motion the limit refused.
                    sp.position = i64::from(p);
                    sp.velocity = Velocity::ZERO;
                    sp.acceleration = Acceleration::ZERO;
                    self.loops.set_torque_feedforward(0);
                }
                clamped = c;
            }
            LoopDemand::Velocity { velocity, .. } => {
                let (v, c) = self.monitor.clamp_velocity(*velocity);
                *velocity = v;
                clamped = c;
            }
            _ => {}
        }
        let out = self.loops.step(&demand, position, scale.current_limit(), scale);
        if let LoopDemand::Position(sp) = demand {
            self.last_setpoint = sp;
        } else if let LoopDemand::Velocity { velocity, acceleration } = demand {
            // The position demand follows the actual position under velocity control.
            self.last_setpoint = Setpoint { position: i64::from(position), position_fine: 0, velocity, acceleration };
        }
        self.last_position = position;
        let supervised = matches!(demand, LoopDemand::Position(_)) && !homing;
        self.following_error_exceeded =
            self.monitor.following_error(out.following_error, supervised, self.now).exceeded;
        self.internal_limit |= clamped || out.saturated;
        out.current
    }

    /// Step 8: statusword, modes display, actual and demand values.
    fn publish(
        &mut self,
        out: &crate::cia402::machine::Outputs,
        position: i32,
        velocity: Velocity,
        d: &mut Dictionary,
    ) {
        let mode = out.mode.active;
        let s = self.mode_status;
        let bit13 = match mode {
            Mode::ProfilePosition | Mode::CyclicSyncPosition => self.following_error_exceeded,
            _ => s.bit13,
        };
        let target_reached = if out.state == State::QuickStopActive {
            out.statusword.0 & Statusword::TARGET_REACHED != 0
        } else {
            s.target_reached
        };
        let flags = StatusFlags {
            voltage_enabled: out.power.enabled,
            warning: self.faults.warning_active(),
            remote: self.remote,
            target_reached,
            internal_limit_active: self.internal_limit,
            operation_mode_specific_12: s.bit12,
            operation_mode_specific_13: bit13,
            safe_torque_off: self.faults.safe_torque_off_active(),
            position_referenced: self.referenced,
        };
        d.set(h::STATUSWORD, Statusword::encode(out.state, flags).0);
        d.set(h::MODES_OF_OPERATION_DISPLAY, out.mode.display);
        // The internal values keep the motor's increments and direction; the master's follow after the slow tick
        // ([`Self::publish_master_values`]).
        let demand = self.last_setpoint.position_i32();
        d.set(h::POSITION_DEMAND_INTERNAL_VALUE, demand);
        d.set(h::POSITION_ACTUAL_INTERNAL_VALUE, position.wrapping_sub(self.offset));
        self.shown = (demand, position, velocity);
        self.faults.publish(d);
    }
}

/// One step of 0x30D3:01's first-order low-pass at the slow tick: `y += (x - y) k`, `k` = 823 / 2^16 = 2 pi 5 Hz /
/// 2,500 Hz, a 5.0 Hz cut-off (IDX L4804 "velocity actual value averaged").
fn average_velocity(average: Velocity, velocity: Velocity) -> Velocity {
    /// `k` in Q16.
    const K_Q16: i64 = 823;
    let (y, x) = (average.to_bits(), velocity.to_bits());
    // Saturates only for a difference above 2^53 (2^21 inc per tick), far beyond any sensor.
    Velocity::from_bits(y.saturating_add(x.saturating_sub(y).saturating_mul(K_Q16) >> 16))
}

/// Whether the activity's demand comes from the shared trajectory generator (so it is already continuous).
const fn uses_generator(activity: Activity) -> bool {
    matches!(
        activity,
        Activity::Holding
            | Activity::Stopping { on_current_limit: false, .. }
            | Activity::Following(Mode::ProfilePosition | Mode::ProfileVelocity | Mode::Homing)
    )
}

/// A position demand with no mode bits.
const fn position_step(sp: Setpoint) -> ModeStep {
    ModeStep {
        demand: LoopDemand::Position(sp),
        status: ModeStatus { target_reached: false, bit12: false, bit13: false },
    }
}
