//! Tier 1's state and its 25 kHz step: what the current loop owns (power-stage state, offset calibration,
//! commutation, current controller, trip limits in force, position latches and sums, the trip sample, the
//! slow-tick divider) and the fast tick over it ([`Tier1State::fast_tick`]).
//!
//! The tier-2 drive ([`super::Drive`]) holds one and reaches it through the methods below; what tier 2 decides for
//! the current reference is the [`DemandCommand`]. These are the shapes of the hand-offs of the tier split
//! (`docs/design/tier-ownership.md`): the power-stage requests become a command tier 1 acts on in its next period,
//! and the demand command and the report of what tier 1 measured cross through `crate::handoff`. Until then the
//! drive calls them directly, and on the target the runtime runs both tiers on one drive.

use super::calibration::{Calibration, CalibrationConfig, CalibrationStatus, CALIBRATION_COMMAND};
use super::commutation::Commutation;
use super::hall_position::HallPosition;
use super::protection::Limits;
use super::scaling::{self, ShuntOffsets};
use super::{DemandSource, FastSignals, FastTick};
use crate::control::angle::ElectricalAngle;
use crate::control::current_loop::{foc_step, CurrentController, FocInput};
use crate::control::demand::DemandScale;
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::control::velocity_estimate::PositionSum;
use crate::hal::power::{FeedbackSample, Measurements, PwmCommand, SLOW_TICK_DIVIDER};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::power_state::{CommutationStage, DriveError, PowerState, Trip};
use crate::sensors::latch::PinLatches;

/// What tier 2 decides for tier 1's q-current reference: where it comes from, the loops' demand (already clamped
/// to the limit), and the torque-to-current scale with the protections' limits in force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DemandCommand {
    /// Where the q-current reference comes from.
    pub source: DemandSource,
    /// The loops' q-current demand, for [`DemandSource::Internal`].
    pub internal: Amps,
    /// Target torque to current, with the I2t and thermal limits applied.
    pub scale: DemandScale,
}

/// Tier 1's state (module documentation).
#[derive(Clone, Debug)]
// `repr(C)` with the fields of every period first: on the Cortex-M4 a load or store reaches 4 KiB from a base
// register in one instruction (the drive keeps this struct at its start for the same reason).
#[repr(C)]
pub struct Tier1State {
    pub(super) state: PowerState,
    pub(super) divider: u32,
    pub(super) hall_mask: u8,
    /// 0x3000:01 sensor 1 is the incremental encoder; without it the Halls are the position sensor.
    pub(super) encoder_present: bool,
    /// The last sample's break input (whether a trip's cause persists).
    pub(super) last_break_input: bool,
    /// Tier-1 trip limits (from 0x3001:02, converted in tier 2).
    pub(super) limits: Limits,
    pub(super) offsets: ShuntOffsets,
    pub(super) commutation: Commutation,
    pub(super) controller: CurrentController,
    pub(super) signals: FastSignals,
    /// Encoder positions at the input edges and the index (written by tier 1, read by tier 2).
    pub(super) latches: PinLatches,
    /// Position counted from the Hall states (the main position without an encoder).
    pub(super) hall_position: HallPosition,
    pub(super) calibration: Calibration,
    /// What the fast tick that tripped measured (the fault's diagnosis data).
    pub(super) trip_sample: FastSignals,
    /// Tier 1's encoder positions summed and latched per slow tick (the averaged velocity estimate).
    pub(super) position_sum: PositionSum,
}

impl Tier1State {
    /// Outputs off, not calibrated, with `commutation` and `controller` as the drive configured them.
    pub(super) fn new(calibration: CalibrationConfig, commutation: Commutation, controller: CurrentController) -> Self {
        Self {
            state: PowerState::Off,
            divider: SLOW_TICK_DIVIDER,
            hall_mask: 0,
            encoder_present: true,
            last_break_input: false,
            limits: Limits::default(),
            offsets: ShuntOffsets::NOMINAL,
            commutation,
            controller,
            signals: FastSignals::default(),
            latches: PinLatches::default(),
            hall_position: HallPosition::default(),
            calibration: Calibration::new(calibration),
            trip_sample: FastSignals::default(),
            position_sum: PositionSum::default(),
        }
    }

    /// One 25 kHz tick: protection, scaling, angle, current loop; the command for the next PWM period and whether a
    /// slow tick is due. Never panics; `PwmCommand::OFF` whenever the drive is not calibrating or enabled.
    #[inline]
    pub fn fast_tick(&mut self, m: &Measurements, demand: &DemandCommand, dictionary: &Dictionary) -> FastTick {
        // Counts down: one subtraction and one compare with zero.
        let slow_tick_due = self.divider <= 1;
        self.divider = if slow_tick_due { SLOW_TICK_DIVIDER } else { self.divider.wrapping_sub(1) };
        FastTick { pwm: self.fast_step(m, slow_tick_due, demand, dictionary), slow_tick_due }
    }

    #[inline(always)]
    fn fast_step(
        &mut self,
        m: &Measurements,
        slow_tick_due: bool,
        demand: &DemandCommand,
        dictionary: &Dictionary,
    ) -> PwmCommand {
        // 1. Protection: acts before anything else, in every state (the current checks run with the loop below).
        if m.break_input {
            self.last_break_input = true;
            return self.trip(DriveError::Protection(Trip::BreakInput));
        }
        let v_bus = scaling::bus_voltage(m.adc.bus_voltage);
        // 2. Scaling and the position sensors (the encoder is tracked in every state).
        let mut feedback = FeedbackSample { hall: m.feedback.hall ^ self.hall_mask, ..m.feedback };
        if !self.encoder_present {
            // No encoder configured: the Halls count the position, whatever the counter input shows is ignored,
            // and the angle comes from the Halls.
            self.hall_position.update(feedback.hall);
            feedback.encoder_count = 0;
            feedback.index_latch = None;
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
                self.run_current_loop(m, &feedback, angle, v_bus, demand, dictionary)
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

    /// Operation enabled: commutation start or alignment, reference, FOC step.
    #[inline(always)]
    fn run_current_loop(
        &mut self,
        m: &Measurements,
        feedback: &FeedbackSample,
        mut angle: ElectricalAngle,
        v_bus: Volts,
        demand: &DemandCommand,
        dictionary: &Dictionary,
    ) -> PwmCommand {
        if self.commutation.stage() == CommutationStage::Unknown {
            if let Err(e) = self.commutation.start(feedback) {
                return self.trip(DriveError::Commutation(e));
            }
            angle = self.commutation.angle();
        }
        let i_ref = if let Some(align) = self.commutation.alignment_demand() {
            angle = align.angle;
            self.signals.torque_demand_permille = 0;
            Dq::new(align.i_d, align.i_q)
        } else if self.commutation.stage().is_valid() {
            let i_q = match demand.source {
                DemandSource::TargetTorque => {
                    let (permille, i_q) = demand
                        .scale
                        .torque_to_current(dictionary.get(h::TARGET_TORQUE), dictionary.get(h::TORQUE_OFFSET));
                    self.signals.torque_demand_permille = permille;
                    i_q
                }
                DemandSource::Internal => demand.internal,
            };
            Dq::new(Amps::ZERO, i_q)
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
        self.signals.saturated = out.saturated;
        out.pwm_command()
    }

    /// A bus trip; the tripping sample is what the fault snapshot reports.
    #[cold]
    #[inline(never)]
    fn trip_bus(&mut self, v_bus: Volts) -> PwmCommand {
        self.signals.v_bus = v_bus;
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

    /// The runtime measured a fast tick over its budget: a trip like any other of tier 1.
    #[cold]
    pub(super) fn current_loop_overrun(&mut self, cost: u32) -> PwmCommand {
        self.trip(DriveError::Overrun { cost })
    }

    // ---------------------------------------------------------------------------------------------------------
    // Power-stage requests (the drive checks the state first; the tier split makes these commands)
    // ---------------------------------------------------------------------------------------------------------

    /// Transition 3: the current-offset calibration starts (outputs at 50 % duty).
    pub(super) fn begin_calibration(&mut self, config: CalibrationConfig) {
        self.calibration = Calibration::new(config);
        self.state = PowerState::Calibrating;
    }

    /// Transition 4: the commutation starts from the next period's sensors, the current loop with empty
    /// integrators.
    pub(super) fn enable_operation(&mut self) {
        self.controller.reset();
        self.commutation.stop();
        self.state = PowerState::OperationEnabled;
    }

    /// Transition 5: outputs off, still calibrated.
    pub(super) fn disable_operation(&mut self) {
        if self.state == PowerState::OperationEnabled {
            self.state = PowerState::SwitchedOn;
        }
        self.commutation.stop();
        self.controller.reset();
    }

    /// Transitions 6/8/9: outputs off, calibration to be redone; a latched fault stays latched.
    pub(super) fn shutdown(&mut self) {
        if !matches!(self.state, PowerState::Fault(_)) {
            self.state = PowerState::Off;
        }
        self.commutation.stop();
        self.controller.reset();
    }

    /// Transition 15: a latched fault back to [`PowerState::Off`].
    pub(super) fn fault_reset(&mut self) {
        if matches!(self.state, PowerState::Fault(_)) {
            self.state = PowerState::Off;
        }
    }
}
