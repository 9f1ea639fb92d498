//! Tier 1's state and its 25 kHz step: what the current loop owns (power-stage state, offset calibration,
//! commutation, current controller, trip limits in force, position latches and sums, the trip sample, the
//! slow-tick divider, the period count) and the fast tick over it ([`Tier1State::fast_tick`]).
//!
//! Only tier 1 touches it. Tier 2 reaches it through blocks (`super::blocks`): tier 1 applies the [`Settings`]
//! and the [`SetPoint`] tier 2 published last ([`Tier1State::apply_settings`], [`Tier1State::apply_setpoint`]) at
//! the start of a period, and hands back a [`Tier1Report`] at every slow-tick boundary ([`Tier1State::report`]).
//! Tier 1 is the authority on its own state: it acts on a request when it reads it, from the state it is in
//! then (a request that no longer fits, such as a switch-on after a trip, is dropped, and the report says why).

use super::blocks::{PowerLevel, SetPoint, Settings, Tier1Report, SETPOINT_WORDS};
use super::calibration::{Calibration, CalibrationConfig, CalibrationStatus, CALIBRATION_COMMAND};
use super::commutation::{Commutation, CommutationMethod};
use super::hall_position::HallPosition;
use super::protection::Limits;
use super::scaling::{self, ShuntOffsets};
use super::{FastSignals, FastTick};
use crate::control::angle::ElectricalAngle;
use crate::control::current_loop::{foc_step, CurrentController, CurrentLoopConfig, FocInput};
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::control::transforms::{clarke, inverse_park, park};
use crate::control::trig::sin_cos;
use crate::control::velocity_estimate::PositionSum;
use crate::hal::power::{FeedbackSample, Measurements, PwmCommand, SLOW_TICK_DIVIDER};
use crate::power_state::{CommutationError, CommutationStage, DriveError, PowerState, Trip};
use crate::sensors::latch::PinLatches;
use crate::sensors::ssi::{SsiError, SsiFormat};

/// Increments an SSI position may differ from the motion's continuation in one period (the step to it against
/// the step before): two for the quantisation of the two steps and one for acceleration, which no drive reaches in
/// one 40 us period (150,000 rpm/s is 0.016 increments per period squared at 4,096 increments per revolution).
/// A corrupted frame that passes the frame check can move the angle by no more than this (1.8 degrees electrical
/// at 12 single-turn bits and 7 pole pairs).
pub const SSI_JUMP_TOLERANCE: u32 = 3;

/// Tier 1's state (module documentation).
#[derive(Clone, Debug)]
// `repr(C)` with the fields of every period first, the settings last.
#[repr(C)]
pub struct Tier1State {
    state: PowerState,
    divider: u32,
    /// Periods run since start (wrapping): the clock of [`SetPoint::apply_from`].
    period: u32,
    /// The last set-point applied: its q reference is the current loop's.
    setpoint: SetPoint,
    /// The last sample's break input (whether a trip's cause persists).
    last_break_input: bool,
    /// Tier-1 trip limits (from 0x3001:02).
    limits: Limits,
    offsets: ShuntOffsets,
    commutation: Commutation,
    controller: CurrentController,
    signals: FastSignals,
    /// Encoder positions at the input edges and the index.
    latches: PinLatches,
    /// Position counted from the Hall states (the main position without an encoder).
    hall_position: HallPosition,
    calibration: Calibration,
    /// What the fast tick that tripped measured (the fault's diagnosis data).
    trip_sample: FastSignals,
    /// Tier 1's encoder positions summed and latched per slow tick (the averaged velocity estimate).
    position_sum: PositionSum,
    /// Running sums (wrapping, `I16F16` bits) of the measured q current and the applied q voltage of every
    /// current-loop period ([`Tier1Report::q_sums`]).
    q_sums: [i32; 2],
    /// The settings in force: Hall mask, encoder presence, calibration; the source of the limits and the
    /// commutation.
    settings: Settings,
    /// The identification's q square wave ([`PowerLevel::InjectSquareQ`]).
    square: SquareWave,
    /// The SSI frame of the last period (reported to tier 2).
    ssi_frame: u32,
}

/// Tier 1's q-axis square wave for the identification's Lq (`super::identification`, step 3): +A for two periods,
/// -A for two. A duty computed in period n applies during period n + 1, and a current sample is the average of
/// its period (the centre of a centred PWM), so the increment between the samples of periods n and n + 1 comes
/// from one voltage alone when the voltages computed in periods n - 1 and n are equal: the second period of each
/// half. Those increments are summed with the sign of their voltage (running totals, wrapping: tier 2 differences
/// two reports): `L = A T count / sum` with R, the dead time and the bias cancelling, and the half period (80 us)
/// short enough that the torque of the q current moves the rotor too little to matter (its voltage error grows
/// with the square of the half period).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SquareWave {
    /// Period within the 4-period cycle.
    tick: u8,
    /// The q current of the last sample.
    last: Amps,
    /// Sum of the signed increments (`I16F16` bits, wrapping).
    sum: i32,
    /// Increments summed (wrapping).
    count: u32,
}

impl Tier1State {
    /// Outputs off, not calibrated, running with `settings` (the tier-2 drive's first ones,
    /// `super::Drive::settings`).
    #[must_use]
    pub fn new(settings: &Settings) -> Self {
        let c = &settings.commutation;
        let mut t1 = Self {
            state: PowerState::Off,
            divider: SLOW_TICK_DIVIDER,
            period: 0,
            setpoint: SetPoint::default(),
            last_break_input: false,
            limits: Limits::new(settings.output_limit_ma),
            offsets: ShuntOffsets::NOMINAL,
            commutation: Commutation::new(
                c.method,
                c.encoder,
                c.hall_offset,
                c.configured_index_offset.or(c.default_index_offset),
            ),
            controller: CurrentController::new(CurrentLoopConfig::with_gains(settings.gains)),
            signals: FastSignals::default(),
            latches: PinLatches::default(),
            hall_position: HallPosition::default(),
            calibration: Calibration::new(settings.calibration),
            trip_sample: FastSignals::default(),
            position_sum: PositionSum::default(),
            q_sums: [0; 2],
            settings: *settings,
            square: SquareWave::default(),
            ssi_frame: 0,
        };
        t1.commutation.set_hall_only(!c.encoder_present);
        t1
    }

    /// Takes over the settings tier 2 published (at the start of a period, before the set-point). The limits and
    /// gains take effect now; the commutation is rebuilt only when its configuration changed (tier 2 changes it
    /// only at a switch-on, with the outputs off), else it keeps its angle and learned index offset.
    #[inline(never)]
    pub fn apply_settings(&mut self, settings: &Settings) {
        if settings.version == self.settings.version {
            return;
        }
        if settings.output_limit_ma != self.settings.output_limit_ma {
            self.limits = Limits::new(settings.output_limit_ma);
        }
        self.controller.set_gains(settings.gains, settings.gains);
        let c = &settings.commutation;
        let sensor_changed = c.encoder_present != self.settings.commutation.encoder_present;
        let same = !sensor_changed
            && self.commutation.encoder().config() == &c.encoder
            && self.commutation.method() == c.method
            && (self.commutation.hall_offset() == c.hall_offset || self.setpoint.power.level.injects());
        // A configured offset wins over a learned one, a learned one over the construction-time default.
        let index_offset = c.configured_index_offset.or(self.commutation.index_offset()).or(c.default_index_offset);
        if same {
            // The identification's Hall offset takes effect without a rebuild, which would restart the encoder's
            // position in operation (the supervision and the axis expect that only at a switch-on).
            self.commutation.set_hall_offset(c.hall_offset);
            self.commutation.set_index_offset(index_offset);
        } else {
            self.commutation = Commutation::new(c.method, c.encoder, c.hall_offset, index_offset);
            if self.state == PowerState::OperationEnabled && self.setpoint.power.level.injects() {
                // The identification publishes what it found while it still injects: the angle stays imposed.
                self.commutation.begin_injection();
            }
        }
        self.commutation.set_hall_only(!c.encoder_present);
        self.settings = *settings;
    }

    /// Takes over the set-point tier 2 published (at the start of a period): the q-current reference, and the
    /// power request when its sequence moved on: a fault reset, then a switch-on, then the level, each from the
    /// state tier 1 is in now.
    pub fn apply_setpoint(&mut self, setpoint: &SetPoint) {
        let request = &setpoint.power;
        let last = self.setpoint.power;
        if request.sequence != last.sequence {
            if request.fault_reset != last.fault_reset {
                self.fault_reset();
            }
            if request.switch_on != last.switch_on && matches!(self.state, PowerState::Off | PowerState::SwitchedOn) {
                self.begin_calibration(self.settings.calibration);
            }
            match request.level {
                PowerLevel::Off => self.shutdown(),
                PowerLevel::SwitchedOn => {
                    if self.state == PowerState::OperationEnabled {
                        self.disable_operation();
                    }
                }
                PowerLevel::OperationEnabled => {
                    if self.state == PowerState::SwitchedOn {
                        self.enable_operation();
                    }
                    if self.commutation.stage() == CommutationStage::Injecting {
                        // The identification ended: the commutation starts again from its sensors (with what the
                        // identification found, once tier 2 has published it in the settings).
                        self.commutation.stop();
                        self.controller.reset();
                    }
                }
                PowerLevel::InjectCurrent
                | PowerLevel::InjectVoltage
                | PowerLevel::InjectSquareQ
                | PowerLevel::InjectSquareD => {
                    if self.state == PowerState::OperationEnabled {
                        self.commutation.begin_injection();
                    }
                }
            }
        }
        self.setpoint = *setpoint;
    }

    /// Whether a set-point that applies from period `apply_from` ([`SetPoint::apply_from`]) applies in the period
    /// about to run. Periods compare modulo 2^32, so a block from the last 2^31 periods counts as begun.
    #[inline]
    #[must_use]
    pub const fn setpoint_due(&self, apply_from: u32) -> bool {
        self.period.wrapping_sub(apply_from).cast_signed() >= 0
    }

    /// [`Self::apply_setpoint`] from the block's words (`super::blocks::SetPoint`'s `Words`): the version and the
    /// q reference are taken as they are, and the power request is decoded only when its word changed (every
    /// slow tick brings a new reference; a power request comes seldom). The caller checked
    /// [`Self::setpoint_due`].
    #[inline]
    pub fn apply_setpoint_words(&mut self, words: &[u32; SETPOINT_WORDS]) {
        let [version, power, i_q, i_d, apply_from] = *words;
        if power == self.setpoint.power_word() {
            self.setpoint.version = version;
            self.setpoint.i_q = Amps::from_bits(i_q.cast_signed());
            self.setpoint.i_d = Amps::from_bits(i_d.cast_signed());
            self.setpoint.apply_from = apply_from;
        } else {
            self.apply_setpoint(&<SetPoint as crate::handoff::Words<SETPOINT_WORDS>>::from_words(words));
        }
    }

    /// What tier 1 hands tier 2 at a slow-tick boundary.
    #[must_use]
    pub fn report(&self) -> Tier1Report {
        Tier1Report {
            period: self.period,
            setpoint_version: self.setpoint.version,
            settings_version: self.settings.version,
            power_sequence: self.setpoint.power.sequence,
            power: self.state,
            signals: self.signals,
            trip_sample: self.trip_sample,
            break_input: self.last_break_input,
            encoder_position: self.commutation.encoder().position(),
            hall_position: self.hall_position.position(),
            encoder_window: self.position_sum.latched(),
            latches: self.latches,
            angle: self.commutation.angle(),
            stage: self.commutation.stage(),
            last_index_latch: self.commutation.last_index_latch(),
            index_offset: self.commutation.index_offset(),
            offsets: self.offsets,
            q_sums: self.q_sums,
            ssi_frame: self.ssi_frame,
        }
    }

    /// One 25 kHz tick: protection, scaling, angle, current loop; the command for the next PWM period and whether a
    /// slow tick is due. Never panics; `PwmCommand::OFF` whenever the drive is not calibrating or enabled.
    #[inline]
    pub fn fast_tick(&mut self, m: &Measurements) -> FastTick {
        // Counts down: one subtraction and one compare with zero.
        let slow_tick_due = self.divider <= 1;
        self.divider = if slow_tick_due { SLOW_TICK_DIVIDER } else { self.divider.wrapping_sub(1) };
        self.period = self.period.wrapping_add(1);
        FastTick { pwm: self.fast_step(m, slow_tick_due), slow_tick_due }
    }

    #[inline(always)]
    fn fast_step(&mut self, m: &Measurements, slow_tick_due: bool) -> PwmCommand {
        // 1. Protection: acts before anything else, in every state (the current checks run with the loop below).
        if m.break_input {
            self.last_break_input = true;
            return self.trip(DriveError::Protection(Trip::BreakInput));
        }
        let v_bus = scaling::bus_voltage(m.adc.bus_voltage);
        // 2. Scaling and the position sensors (the encoder is tracked in every state).
        let mut feedback = FeedbackSample { hall: m.feedback.hall ^ self.settings.commutation.hall_mask, ..m.feedback };
        if !self.settings.commutation.encoder_present {
            // No incremental encoder configured: whatever the counter input shows is ignored. The SSI sensor gives
            // the position (its frame's 16-bit count stands in for the counter), or the Halls count it and give the
            // angle.
            feedback.index_latch = None;
            feedback.encoder_count = if let CommutationMethod::Absolute(ssi) = self.commutation.method() {
                match self.ssi_count(&ssi, feedback.ssi_frame) {
                    Ok(count) => count,
                    Err(e) => return self.trip(DriveError::Commutation(e)),
                }
            } else {
                self.hall_position.update(feedback.hall);
                0
            };
        }
        self.signals.v_bus = v_bus;
        self.signals.hall = feedback.hall;
        self.signals.temperature_codes = [m.adc.temperature, m.adc.motor_temperature];
        let angle = match self.commutation.update(&feedback) {
            Ok(a) => a,
            Err(e) => return self.trip(DriveError::Commutation(e)),
        };
        let encoder = self.commutation.encoder();
        // Every sample of the encoder feeds the velocity estimate's window average (velocity_estimate docs).
        self.position_sum.add(encoder.position(), slow_tick_due);
        self.latches.sample_inputs(feedback.digital_inputs, encoder.position());
        if let Some(latch) = feedback.index_latch {
            let at = encoder.position_at(latch);
            self.latches.latch_index(at);
        }
        // 3. The bus limits (with the phase-current limits in the current loop): over-voltage in every state,
        // under-voltage while the power stage switches. Checked here, after the sensors, so that the tracking
        // above never waits on it; the outputs of this period are still decided below.
        match self.state {
            PowerState::OperationEnabled => {
                if self.limits.bus_outside(v_bus, true) {
                    return self.trip_bus(v_bus);
                }
                self.run_current_loop(m, &feedback, angle, v_bus)
            }
            PowerState::Calibrating if self.limits.bus_outside(v_bus, true) => self.trip_bus(v_bus),
            // A latched fault keeps its first cause; over-voltage with the outputs off is a fault of its own.
            PowerState::Off | PowerState::SwitchedOn if self.limits.bus_outside(v_bus, false) => self.trip_bus(v_bus),
            PowerState::Fault(_) => {
                // The break input is not set here (it trips above): its cause has gone.
                self.last_break_input = false;
                PwmCommand::OFF
            }
            PowerState::Calibrating => match self.calibration.step(&m.adc) {
                CalibrationStatus::Running => CALIBRATION_COMMAND,
                CalibrationStatus::Done(offsets) => {
                    self.offsets = offsets;
                    self.state = PowerState::SwitchedOn;
                    PwmCommand::OFF
                }
                CalibrationStatus::Failed(e) => self.trip(DriveError::Calibration(e)),
            },
            PowerState::Off | PowerState::SwitchedOn => PwmCommand::OFF,
        }
    }

    /// The 16-bit count of an SSI frame, checked before it reaches the angle: the frame's start and stop bits and
    /// its constant-line test ([`SsiFormat::check`]), then the count must continue the motion within
    /// [`SSI_JUMP_TOLERANCE`] increments (a flipped data bit that passes the frame check moves the position by
    /// a jump no shaft makes in one period). A frame that fails is never used: the outputs go off, the frame is
    /// kept for the report. In «Fault» (outputs off, the first cause kept) a frame that passes the frame check is
    /// taken as it is, jump or not, so that the count follows the shaft again once the sensor is back (tier 2
    /// takes the absolute position's base again at the fault reset); a failing one leaves the count where it was.
    #[inline(never)]
    fn ssi_count(&mut self, ssi: &SsiFormat, frame: u32) -> Result<u16, CommutationError> {
        self.ssi_frame = frame;
        let encoder = self.commutation.encoder();
        let count = ssi.count16(frame);
        let checked = ssi.check(frame);
        if matches!(self.state, PowerState::Fault(_)) {
            return Ok(if checked.is_ok() { count } else { encoder.last_counter() });
        }
        let tolerance = SSI_JUMP_TOLERANCE << ssi.align_bits;
        Err(match checked {
            Ok(()) if encoder.continues(count, tolerance) => return Ok(count),
            Ok(()) => CommutationError::SsiFrame,
            Err(_) if !encoder.synced() => CommutationError::SsiMissing,
            Err(SsiError::NoData) => CommutationError::SsiNoData,
            Err(SsiError::Frame) => CommutationError::SsiFrame,
        })
    }

    /// Operation enabled: commutation start or alignment, reference, FOC step.
    #[inline(always)]
    fn run_current_loop(
        &mut self,
        m: &Measurements,
        feedback: &FeedbackSample,
        mut angle: ElectricalAngle,
        v_bus: Volts,
    ) -> PwmCommand {
        if self.commutation.stage() == CommutationStage::Unknown {
            if let Err(e) = self.commutation.start(feedback) {
                return self.trip(DriveError::Commutation(e));
            }
            angle = self.commutation.angle();
        }
        // A valid angle first: the normal path pays one compare; the alignment and the identification's injection
        // are the branches behind it.
        let i_ref = if self.commutation.stage().is_valid() {
            Dq::new(self.setpoint.i_d, self.setpoint.i_q)
        } else if let Some(align) = self.commutation.alignment_demand() {
            angle = align.angle;
            Dq::new(align.i_d, align.i_q)
        } else if self.commutation.stage() == CommutationStage::Injecting {
            return self.run_injection(m, v_bus);
        } else {
            // The alignment just finished this tick: the angle is valid from the next one; hold zero current.
            Dq::new(Amps::ZERO, Amps::ZERO)
        };
        let i_abc = scaling::phase_currents(&m.adc, &self.offsets);
        if self.limits.currents_outside(&i_abc) {
            return self.trip_currents(&i_abc);
        }
        let out = foc_step(&mut self.controller, &FocInput { i_abc, angle, i_ref, v_bus });
        self.signals.i_abc = i_abc;
        self.signals.i_dq = out.i_dq;
        self.signals.i_ref = i_ref;
        self.signals.v_dq = out.v_dq;
        let [i_q_sum, v_q_sum] = self.q_sums;
        self.q_sums = [i_q_sum.wrapping_add(out.i_dq.q.to_bits()), v_q_sum.wrapping_add(out.v_dq.q.to_bits())];
        self.signals.saturated = out.saturated;
        out.pwm_command()
    }

    /// The identification's injection (`super::identification`, [`PowerLevel::InjectCurrent`] and
    /// [`PowerLevel::InjectVoltage`]): the angle is the one tier 2 imposes, carried in the bits of the set-point's
    /// q reference; the d current through the current controller, or the d/q voltages open loop through the
    /// modulator (the integrators are emptied so that a later current step starts without a stale voltage).
    /// Protection as on the normal path. Off the normal path: it runs only during the identification.
    #[cold]
    #[inline(never)]
    fn run_injection(&mut self, m: &Measurements, v_bus: Volts) -> PwmCommand {
        let angle = ElectricalAngle(self.setpoint.i_q.to_bits().cast_unsigned());
        let i_abc = scaling::phase_currents(&m.adc, &self.offsets);
        if self.limits.currents_outside(&i_abc) {
            return self.trip_currents(&i_abc);
        }
        self.signals.i_abc = i_abc;
        let level = self.setpoint.power.level;
        if level != PowerLevel::InjectCurrent {
            let packed = self.setpoint.i_d.to_bits().cast_unsigned();
            let volts = |half: u32| Volts::from_millivolts(i32::from((half & 0xFFFF) as u16 as i16));
            let mut v_dq = Dq::new(volts(packed), volts(packed >> 16));
            let sc = sin_cos(angle);
            let i_dq = park(clarke(i_abc), sc);
            self.signals.i_ref = match level {
                PowerLevel::InjectSquareQ => {
                    v_dq.q = self.square.step(i_dq.q, v_dq.q);
                    self.square.totals()
                }
                PowerLevel::InjectSquareD => {
                    let swing = self.square.step(i_dq.d, v_dq.q);
                    v_dq = Dq::new(Volts::from_bits(v_dq.d.to_bits().wrapping_add(swing.to_bits())), Volts::ZERO);
                    self.square.totals()
                }
                _ => Dq::default(),
            };
            let modulator = self.controller.modulator();
            let modulated = modulator.modulate(inverse_park(v_dq, sc), v_bus);
            let mut c = modulated.compare_ticks;
            if level != PowerLevel::InjectVoltage {
                // Centred instead of bottom-clamped: with the lowest phase held at 0, the sign of the square wave
                // would choose which leg stops switching (at angle 0, B or C), and the dead time would add to the
                // amplitude in both halves; centred, every leg switches in both halves and the dead time's error
                // follows the currents alone, which the symmetric increments cancel.
                let high = c.a.max(c.b).max(c.c);
                let low = c.a.min(c.b).min(c.c);
                let lift = modulator.clamp().max_compare().saturating_sub(high).saturating_sub(low) / 2;
                c = Abc { a: c.a.saturating_add(lift), b: c.b.saturating_add(lift), c: c.c.saturating_add(lift) };
            }
            self.controller.reset();
            self.signals.i_dq = i_dq;
            self.signals.v_dq = v_dq;
            self.signals.saturated = modulated.saturated;
            return PwmCommand { duty: [c.a, c.b, c.c], enabled: true };
        }
        let i_ref = Dq::new(self.setpoint.i_d, Amps::ZERO);
        let out = foc_step(&mut self.controller, &FocInput { i_abc, angle, i_ref, v_bus });
        self.signals.i_dq = out.i_dq;
        self.signals.i_ref = i_ref;
        self.signals.v_dq = out.v_dq;
        self.signals.saturated = out.saturated;
        out.pwm_command()
    }

    /// A bus trip; the tripping sample is what the fault snapshot reports (`fast_step` has put `v_bus` in the
    /// signals the trip sample copies).
    #[cold]
    #[inline(never)]
    fn trip_bus(&mut self, v_bus: Volts) -> PwmCommand {
        let trip = self.limits.bus_trip(v_bus);
        self.trip(DriveError::Protection(trip))
    }

    /// A current trip; the tripping sample is what the fault snapshot reports.
    #[cold]
    #[inline(never)]
    fn trip_currents(&mut self, i_abc: &Abc<Amps>) -> PwmCommand {
        self.signals.i_abc = *i_abc;
        let trip = self.limits.current_trip(i_abc);
        self.trip(DriveError::Protection(trip))
    }

    /// Latches a fault and switches the outputs off.
    #[cold]
    fn trip(&mut self, error: DriveError) -> PwmCommand {
        self.state = PowerState::Fault(error);
        self.trip_sample = self.signals;
        self.commutation.stop();
        self.controller.reset();
        self.signals.i_ref = Dq::default();
        PwmCommand::OFF
    }

    /// The runtime measured a fast tick over its budget, or found a period lost: a trip like any other of tier 1
    /// (outputs off with the returned command; the axis reports 0xFF0B with `cost` as its detail).
    #[cold]
    pub fn current_loop_overrun(&mut self, cost: u32) -> PwmCommand {
        self.trip(DriveError::Overrun { cost })
    }

    // ---------------------------------------------------------------------------------------------------------
    // Power-stage transitions (from `apply_setpoint`)
    // ---------------------------------------------------------------------------------------------------------

    /// Transition 3: the current-offset calibration starts (outputs at 50 % duty).
    fn begin_calibration(&mut self, config: CalibrationConfig) {
        self.calibration = Calibration::new(config);
        self.state = PowerState::Calibrating;
    }

    /// Transition 4: the commutation starts from the next period's sensors, the current loop with empty
    /// integrators.
    fn enable_operation(&mut self) {
        self.controller.reset();
        self.commutation.stop();
        self.state = PowerState::OperationEnabled;
    }

    /// Transition 5: outputs off, still calibrated.
    fn disable_operation(&mut self) {
        if self.state == PowerState::OperationEnabled {
            self.state = PowerState::SwitchedOn;
        }
        self.commutation.stop();
        self.controller.reset();
    }

    /// Transitions 6/8/9: outputs off, calibration to be redone; a latched fault stays latched.
    fn shutdown(&mut self) {
        if !matches!(self.state, PowerState::Fault(_)) {
            self.state = PowerState::Off;
        }
        self.commutation.stop();
        self.controller.reset();
    }

    /// Transition 15: a latched fault back to [`PowerState::Off`].
    fn fault_reset(&mut self) {
        if matches!(self.state, PowerState::Fault(_)) {
            self.state = PowerState::Off;
        }
    }
}

impl SquareWave {
    /// The running totals as they travel in the report's current reference, unused during an injection: the sum
    /// of the signed increments (d) and their count (q).
    fn totals(&self) -> Dq<Amps> {
        Dq::new(Amps::from_bits(self.sum), Amps::from_bits(self.count.cast_signed()))
    }

    /// One period with the q current `i_q` sampled: the q voltage to apply (+-`amplitude`).
    fn step(&mut self, i_q: Amps, amplitude: Volts) -> Volts {
        let tick = self.tick;
        // The increment since the last sample came from one voltage when this is the first period of a half
        // (the two periods before computed the same voltage): the half before, whose sign is the opposite.
        if tick == 0 || tick == 2 {
            let step = i_q.to_bits().wrapping_sub(self.last.to_bits());
            self.sum = if tick == 0 { self.sum.wrapping_sub(step) } else { self.sum.wrapping_add(step) };
            self.count = self.count.wrapping_add(1);
        }
        self.last = i_q;
        self.tick = (tick.wrapping_add(1)) & 3;
        if tick < 2 {
            amplitude
        } else {
            Volts::from_bits(amplitude.to_bits().wrapping_neg())
        }
    }
}

impl Tier1State {
    /// The outputs switch now (calibration at 50 % duty, or the current loop): a lost period leaves them with
    /// stale duties.
    #[must_use]
    pub const fn outputs_switching(&self) -> bool {
        matches!(self.state, PowerState::Calibrating | PowerState::OperationEnabled)
    }

    /// The power-stage state now.
    #[must_use]
    pub const fn state(&self) -> PowerState {
        self.state
    }

    /// The shunt offsets in use (nominal until the first successful calibration).
    #[must_use]
    pub const fn offsets(&self) -> &ShuntOffsets {
        &self.offsets
    }

    /// The commutation.
    #[must_use]
    pub const fn commutation(&self) -> &Commutation {
        &self.commutation
    }

    /// The current controller.
    #[must_use]
    pub const fn controller(&self) -> &CurrentController {
        &self.controller
    }

    /// What the last fast tick measured and commanded.
    #[must_use]
    pub const fn signals(&self) -> &FastSignals {
        &self.signals
    }

    /// The input edges and the index latched.
    #[must_use]
    pub const fn latches(&self) -> &PinLatches {
        &self.latches
    }

    /// The set-point in force.
    #[must_use]
    pub const fn setpoint(&self) -> &SetPoint {
        &self.setpoint
    }

    /// The settings in force.
    #[must_use]
    pub const fn settings(&self) -> &Settings {
        &self.settings
    }
}
