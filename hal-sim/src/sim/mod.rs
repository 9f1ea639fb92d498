//! The firmware's drive running against the simulated plant: the runner ([`Simulation`]), the fieldbus runners
//! ([`canopen`], [`ethercat`]), the update regions ([`update`]), and the trace (CSV) and plot (SVG) writers used by
//! `drive-sim` and by the scenario tests of `drive-tests`. The scenarios themselves are [`crate::scenarios`].
//!
//! The loop is the hardware's (`firmware::hal::power`, `crate::plant` timeline): `plant.step(previous command)`
//! simulates one PWM period and returns its centre sample; tier 1 ([`Tier1State`]) takes the blocks the drive
//! changed and computes the command for the next period; when it reports a slow tick due, its report goes to the
//! drive and the drive's background step and slow tick run before the next period. The hand-offs have the
//! target's timing (`docs/design/tier-ownership.md`, section 5): a block the drive changed in a call between two
//! steps (tier 3 on the target) is first seen by the next period's fast tick, a set-point the loops decided in slow
//! tick k from the period it names (`firmware::drive::Drive`, "Hand-off timing"), as on the target; the report the
//! slow tick reads is the one of the period that raised it.

pub mod canopen;
pub mod current_trace;
pub mod ethercat;
pub mod ethercat_line;
pub mod host_priority;
pub mod plot;
pub mod trace;
pub mod update;

use firmware::cia402::State;
use firmware::drive::blocks::SetPoint;
use firmware::drive::tier1::Tier1State;
use firmware::drive::{Drive, DriveConfig};
use firmware::hal::power::{Measurements, PwmCommand, SLOW_TICK_DIVIDER};
use firmware::od::generated::handles as h;
use firmware::power_state::{CommutationStage, DriveError, PowerState};
use firmware::recorder::ring::SampleRing;
use firmware::recorder::Recorder;
use std::sync::atomic::AtomicU16;

use crate::plant::{Plant, PlantParams, PERIOD_S};

/// Why a simulation step sequence did not reach its goal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimError {
    /// The drive latched a fault.
    Drive(DriveError),
    /// A power-stage request was refused in this state.
    Refused(PowerState),
    /// A goal was not reached within its time budget.
    Timeout(&'static str),
}

impl core::fmt::Display for SimError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Drive(e) => write!(f, "drive fault: {e:?}"),
            Self::Refused(s) => write!(f, "request refused in state {s:?}"),
            Self::Timeout(what) => write!(f, "timed out waiting for {what}"),
        }
    }
}

impl std::error::Error for SimError {}

/// The plant and the drive, stepped together.
#[derive(Debug)]
pub struct Simulation {
    /// The simulated motor, inverter and sensors.
    pub plant: Plant,
    /// The firmware's drive (tier 2).
    pub drive: Drive,
    /// Tier 1's state: only [`Self::step`] changes it.
    tier1: Tier1State,
    /// The set-point the drive published last and tier 1 has not yet applied (it applies from a later period:
    /// `SetPoint::apply_from`), as the target's double buffer holds it.
    published: Option<SetPoint>,
    cmd: PwmCommand,
    measurements: Measurements,
    ticks: u64,
    /// The plant whose motor data [`Self::commission_motor_data`] wrote, written again into a rebooted drive.
    motor_data: Option<PlantParams>,
    /// The data recorder, owned beside the drive as the target's runtime owns it (`firmware::rt::tier2::RECORDER`):
    /// the SDO servers reach it through `firmware::recorder::objects::RecorderObjects`. It records once
    /// [`Self::attach_recorder`] gave it sample memory.
    pub recorder: Recorder,
    /// Tier 1's copies for the recorder, pushed every period after the fast tick as on the target.
    recorder_ring: Box<SampleRing>,
    /// The recorder's sample memory once [`Self::attach_recorder`] gave it one (kept across a reboot).
    recorder_buffer: Option<&'static [AtomicU16]>,
}

impl Simulation {
    /// A simulation of `params` (noise seeded with `seed`) and a drive with `config`. The drive is commissioned
    /// for the plant's encoder as a user would: 0x3010:01 holds its lines, `encoder_counts_per_rev / 4` (the
    /// dictionary default 1,024 for the reference plant), so any resolution the dictionary allows runs as the
    /// reference one does.
    pub fn new(params: PlantParams, seed: u64, config: DriveConfig) -> Self {
        let mut dictionary = firmware::od::access::Dictionary::new(config.node_id);
        dictionary.set(h::ENCODER_PULSES, params.encoder_counts_per_rev / 4);
        let drive = Drive::with_dictionary(config, dictionary);
        Self {
            plant: Plant::new(params, seed),
            tier1: Tier1State::new(drive.settings()),
            published: None,
            drive,
            cmd: PwmCommand::OFF,
            measurements: Measurements::default(),
            ticks: 0,
            motor_data: None,
            recorder: Recorder::new(),
            recorder_ring: Box::new(SampleRing::new()),
            recorder_buffer: None,
        }
    }

    /// Gives the data recorder sample memory of the target's size (`firmware::rt`'s 64 KiB), allocated once for
    /// this simulation and kept for its lifetime (leaked: the recorder holds a `'static` slice, as on the target).
    /// Simulations that do not record go without one.
    pub fn attach_recorder(&mut self) {
        const HALVES: usize = 32 * 1024;
        let buffer = *self
            .recorder_buffer
            .get_or_insert_with(|| Box::leak((0..HALVES).map(|_| AtomicU16::new(0)).collect::<Box<[AtomicU16]>>()));
        self.recorder.attach(buffer);
    }

    /// The reference plant and the default drive.
    pub fn reference(seed: u64) -> Self {
        Self::new(PlantParams::reference(), seed, DriveConfig::DEFAULT)
    }

    /// One PWM period: plant, fast tick, and the slow tick when due.
    #[inline]
    pub fn step(&mut self) {
        let m = self.plant.step(&self.cmd);
        // The blocks the drive changed since the last period, settings first (as tier 1 reads them on the target).
        if let Some(settings) = self.drive.take_settings() {
            self.tier1.apply_settings(&settings);
        }
        if let Some(setpoint) = self.drive.take_setpoint() {
            self.published = Some(setpoint);
        }
        if let Some(setpoint) = self.published.filter(|s| self.tier1.setpoint_due(s.apply_from)) {
            self.tier1.apply_setpoint(&setpoint);
            self.published = None;
        }
        let tick = self.tier1.fast_tick(&m);
        if self.recorder_ring.enabled() {
            self.recorder_ring.push(&self.tier1, &tick.pwm);
        }
        if tick.slow_tick_due {
            self.drive.receive_report(&self.tier1.report());
            // Tier 2 reads the STO inputs and the load encoder at the start of its slow period, as `rt::tier2` does on the target.
            self.drive.set_sto_inputs(self.plant.sto_inputs());
            // The load encoder's count (a 32-bit counter, as `board::load_encoder`'s TIM5; 0 without one).
            self.drive.set_load_encoder_count(self.plant.load_encoder_count().map_or(0, |count| count as u32));
            self.drive.background();
            self.drive.slow_tick();
            self.drive.publish_master_values();
            // The object channels after the slow tick, as `rt::tier2` takes them; the drain at once (tier 3's on the
            // target, within the ring's reach).
            self.recorder.take_objects(self.drive.dictionary().values().bytes());
            self.recorder.drain(&self.recorder_ring, u32::MAX);
            self.plant.set_digital_outputs(self.drive.output_pins());
            self.plant.set_chopper_gate(self.drive.chopper_gate());
        }
        self.cmd = tick.pwm;
        self.measurements = m;
        self.ticks = self.ticks.wrapping_add(1);
    }

    /// `n` periods.
    pub fn run(&mut self, n: u64) {
        for _ in 0..n {
            self.step();
        }
    }

    /// Steps until `done` holds (checked after each period) or `max_ticks` have passed; the ticks taken.
    pub fn run_until(&mut self, max_ticks: u64, mut done: impl FnMut(&Self) -> bool) -> Option<u64> {
        for k in 1..=max_ticks {
            self.step();
            if done(self) {
                return Some(k);
            }
        }
        None
    }

    /// Periods simulated so far.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// Simulated time, in s.
    pub fn time_s(&self) -> f64 {
        self.ticks as f64 * PERIOD_S
    }

    /// The last period's measurements (what the drive saw).
    pub fn measurements(&self) -> &Measurements {
        &self.measurements
    }

    /// The command the drive wrote for the next period.
    pub fn command(&self) -> &PwmCommand {
        &self.cmd
    }

    /// The runtime found the last fast tick over its budget (`cost` in its counter's units): the drive trips and
    /// the outputs go off with the next period, as `rt::tier1` does on the target.
    pub fn inject_current_loop_overrun(&mut self, cost: u32) {
        self.cmd = self.tier1.current_loop_overrun(cost);
    }

    /// Tier 1's state now (the drive sees it through the report of each slow-tick boundary).
    pub fn tier1(&self) -> &Tier1State {
        &self.tier1
    }

    /// Replaces the drive, as a reset does on the board: tier 1 starts afresh with the new drive's settings.
    pub fn replace_drive(&mut self, drive: Drive) {
        self.tier1 = Tier1State::new(drive.settings());
        self.published = None;
        self.drive = drive;
        // The microcontroller restarts: a new recorder over the same memory.
        self.recorder = Recorder::new();
        if let Some(buffer) = self.recorder_buffer {
            self.recorder.attach(buffer);
        }
        if let Some(params) = self.motor_data.take() {
            self.commission_motor_data(&params);
        }
    }

    /// Configures the drive for the plant `params` from its ratings, as a commissioning engineer would before the
    /// first enable, and again after every [`Self::replace_drive`] (a reboot): motor data 0x3001 (nominal current,
    /// output current limit = the peak current capped at the object's 12 A, pole pairs, winding thermal time
    /// constant, torque constant), 0x3002 (phase resistance in uOhm, Lq and Ld: the auto-tuning 0x3205 reads them;
    /// the gains do not change until it runs), the encoder 0x3010:01 (lines = counts / 4), the highest current 0x6073 (peak over nominal, per mille), and the speeds 0x6080 (max
    /// motor speed) and 0x607F (max profile velocity). The gains stay the dictionary's, tuned for the reference
    /// plant (auto-tuning is issue 18 items 3-5). For the reference plant every value equals the dictionary
    /// default, so nothing changes.
    pub fn commission_motor_data(&mut self, params: &PlantParams) {
        let milli = |a: f64| (a * 1000.0).round().clamp(1.0, f64::from(u32::MAX)) as u32;
        let per_mille = (params.peak_current_a / params.nominal_current_a * 1000.0).round().clamp(1.0, 65_535.0);
        let max_rpm = params.max_speed_rpm.round().clamp(1.0, 25_000.0) as u32;
        let d = self.drive.dictionary_mut();
        d.set(h::MOTOR_NOMINAL_CURRENT, milli(params.nominal_current_a));
        d.set(h::MOTOR_OUTPUT_CURRENT_LIMIT, milli(params.peak_current_a).min(12_000));
        d.set(h::MOTOR_POLE_PAIRS, u8::try_from(params.pole_pairs).unwrap_or(u8::MAX));
        d.set(
            h::MOTOR_THERMAL_TIME_CONSTANT,
            (params.winding_time_constant_s * 10.0).round().clamp(1.0, 5400.0) as u16,
        );
        d.set(h::MOTOR_TORQUE_CONSTANT, (params.torque_constant_nm_per_a() * 1e6).round().clamp(1.0, 1e7) as u32);
        d.set(
            h::MOTOR_PHASE_RESISTANCE,
            (params.phase_resistance_ohm * 1e6).round().clamp(1.0, f64::from(u32::MAX)) as u32,
        );
        d.set(h::MOTOR_PHASE_INDUCTANCE_D, (params.ld_h * 1e6).round().clamp(1.0, 65_535.0) as u16);
        d.set(h::MOTOR_PHASE_INDUCTANCE, (params.lq_h * 1e6).round().clamp(1.0, 65_535.0) as u16);
        d.set(h::ENCODER_PULSES, params.encoder_counts_per_rev / 4);
        d.set(h::MAX_CURRENT, per_mille as u16);
        d.set(h::MAX_MOTOR_SPEED, max_rpm);
        d.set(h::MAX_PROFILE_VELOCITY, max_rpm);
        self.motor_data = Some(params.clone());
    }

    /// Whether the plant's rotor is locked (a stop cannot be seen in the speed then).
    pub fn plant_locked(&self) -> bool {
        self.plant.mechanics() == crate::plant::Mechanics::Locked
    }

    /// Writes target torque 0x6071 (per mille of rated torque) into the dictionary, as an RxPDO would.
    pub fn set_target_torque(&mut self, permille: i16) {
        self.drive.dictionary_mut().set(h::TARGET_TORQUE, permille);
        // A master that writes 0x6071 every period sends a set-point with it: converted now, in the next period.
        self.drive.target_torque_written();
    }

    /// Sets a q-current reference in amperes through 0x6071, rounded to one per mille of the nominal current
    /// 0x3001:01 (3.2 mA for the reference motor).
    pub fn set_q_reference(&mut self, amps: f64) {
        let nominal_a = f64::from(self.drive.dictionary().get(h::MOTOR_NOMINAL_CURRENT).max(1)) / 1000.0;
        let permille = (amps / nominal_a * 1000.0).round().clamp(f64::from(i16::MIN), f64::from(i16::MAX));
        self.set_target_torque(permille as i16);
    }

    /// Writes the current controller gains 0x30A0:01 (uV/A) and :02 (uV/(A ms)); they take effect at the next
    /// slow tick.
    pub fn set_current_gains(&mut self, p_uv_per_a: u32, i_uv_per_a_ms: u32) {
        let d = self.drive.dictionary_mut();
        d.set(h::CURRENT_CONTROLLER_P_GAIN, p_uv_per_a);
        d.set(h::CURRENT_CONTROLLER_I_GAIN, i_uv_per_a_ms);
    }

    fn fault(&self) -> Option<DriveError> {
        match self.drive.state() {
            PowerState::Fault(e) => Some(e),
            _ => None,
        }
    }

    /// Transition 3: switch on and run the offset calibration to its end; the ticks it took.
    pub fn switch_on(&mut self) -> Result<u64, SimError> {
        self.drive.switch_on().map_err(|firmware::drive::RequestError::WrongState(s)| SimError::Refused(s))?;
        // Tier 1 calibrates; the count is its periods. The drive learns the result at the next slow-tick boundary,
        // which the run then waits for, so that the next request sees the switched-on state.
        let ticks = self
            .run_until(2_000, |s| s.tier1.state() != PowerState::Calibrating)
            .ok_or(SimError::Timeout("the offset calibration"))?;
        self.run_until(u64::from(firmware::hal::power::SLOW_TICK_DIVIDER), |s| s.drive.state() == s.tier1.state())
            .ok_or(SimError::Timeout("the report of the offset calibration"))?;
        match self.drive.state() {
            PowerState::SwitchedOn => Ok(ticks),
            PowerState::Fault(e) => Err(SimError::Drive(e)),
            other => Err(SimError::Refused(other)),
        }
    }

    /// Transition 4: enable operation (the commutation starts at the next period).
    pub fn enable(&mut self) -> Result<(), SimError> {
        self.drive.enable_operation().map_err(|firmware::drive::RequestError::WrongState(s)| SimError::Refused(s))
    }

    // -----------------------------------------------------------------------------------------------------------
    // CiA 402 through the dictionary, as a fieldbus master drives it
    // -----------------------------------------------------------------------------------------------------------

    /// Writes the controlword 0x6040.
    pub fn set_controlword(&mut self, controlword: u16) {
        self.drive.dictionary_mut().set(h::CONTROLWORD, controlword);
    }

    /// The statusword 0x6041 of the last slow tick.
    pub fn statusword(&self) -> u16 {
        self.drive.dictionary().get(h::STATUSWORD)
    }

    /// The CiA 402 state.
    pub fn cia402_state(&self) -> State {
        self.drive.axis().state()
    }

    /// Writes modes of operation 0x6060.
    pub fn set_mode(&mut self, mode: i8) {
        self.drive.dictionary_mut().set(h::MODES_OF_OPERATION, mode);
    }

    /// Runs `n` slow ticks (10 PWM periods each).
    pub fn run_slow_ticks(&mut self, n: u64) {
        self.run(n.saturating_mul(10));
    }

    /// The fieldbus delivered a set-point (SYNC / SM2 event): the cyclic modes latch the targets now.
    pub fn setpoint_received(&mut self) {
        self.drive.setpoint_received();
    }

    /// Runs until the CiA 402 state is `state` (checked after each period) or `max_ticks` passed.
    fn run_until_state(&mut self, state: State, max_ticks: u64, what: &'static str) -> Result<u64, SimError> {
        let reached = self.run_until(max_ticks, |s| s.fault().is_some() || s.cia402_state() == state);
        if let Some(e) = self.fault() {
            return Err(SimError::Drive(e));
        }
        reached.ok_or(SimError::Timeout(what))
    }

    /// «Shutdown», «Switch on» (offset calibration), «Enable operation» in `mode`, as a master does; returns the
    /// PWM periods it took.
    pub fn enable_through_controlword(&mut self, mode: i8) -> Result<u64, SimError> {
        self.set_mode(mode);
        self.set_controlword(0x0006);
        let a = self.run_until_state(State::ReadyToSwitchOn, 100, "ready to switch on")?;
        self.set_controlword(0x0007);
        let b = self.run_until_state(State::SwitchedOn, 3_000, "switched on (offset calibration)")?;
        self.set_controlword(0x000F);
        let c = self.run_until_state(State::OperationEnabled, 100, "operation enabled")?;
        // The slow tick that reached the state asked tier 1 to enable: it does so in the period the set-point
        // names (the loops' hand-off period), which then drives the motor.
        let d = self
            .run_until(u64::from(SLOW_TICK_DIVIDER), |s| s.tier1.state() == PowerState::OperationEnabled)
            .ok_or(SimError::Timeout("tier 1 enabled"))?;
        Ok(a.saturating_add(b).saturating_add(c).saturating_add(d))
    }

    /// Commissioning on a free shaft: switch on (calibration), enable, drive `amps` of q current until the
    /// commutation is indexed (Hall start, first Hall edge, first index pulse: within one revolution), then zero
    /// current. The rotor keeps whatever speed it reached; scenarios lock or set it afterwards. Returns the ticks
    /// the offset calibration took.
    pub fn commission(&mut self, amps: f64) -> Result<u64, SimError> {
        let calibration_ticks = self.switch_on()?;
        self.enable()?;
        self.set_q_reference(amps);
        let indexed = self
            .run_until(25_000, |s| s.fault().is_some() || s.tier1().commutation().stage() == CommutationStage::Indexed);
        if let Some(e) = self.fault() {
            return Err(SimError::Drive(e));
        }
        indexed.ok_or(SimError::Timeout("the encoder index"))?;
        self.set_q_reference(0.0);
        Ok(calibration_ticks)
    }
}
