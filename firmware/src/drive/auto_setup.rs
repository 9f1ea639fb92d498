//! The motor identification as a drive procedure: PD4-E's "auto setup" operating mode (seed 003 p.25-27, p.76-77;
//! `shared/spec/cia402-device-control.md` L528-531). The master selects 0x6060 = -2 (0xFE), brings the drive to
//! «Operation enabled» and raises controlword bit 4; the drive runs the steps in tiers 1 and 2 while tier 3 keeps
//! serving the fieldbus, shows the step and the progress in 0x3204, writes the results into their objects and sets
//! statusword bit 12 ("aligned") when it finished successfully. A failure is a class-d fault with its IDX code
//! (0xFF12..0xFF22): the power stage goes off at once.
//!
//! Steps (0x3204:02): 1-4 the electrical identification ([`super::identification`]); 5 the commutation restarts
//! from what it found (Hall sector or forced alignment; the index applies the new offset); 6 the mechanical
//! experiment in FOC ([`super::mechanical_identification`]: torque constant into 0x3001:05, total inertia into
//! 0x30A3:05 and 0x3204:06, viscous friction into 0x30A3:04, Coulomb friction into 0x3204:05; skipped with
//! 0x3204:01 bit 0, which skips the two steps after it too); 7 the load's first resonance and anti-resonance
//! ([`super::resonance_identification`], into 0x3205:03/04, 0 for a rigid load; skipped with bit 2, which leaves
//! 0x3205:03/04 as they are); 8 the auto-tuning from the results ([`super::auto_tuning`], the gains
//! 0x30A0..0x30A3 for the stiffness 0x3205:02 and the resonance pair 0x3205:03/04; skipped with bit 1); then
//! done (9). The
//! results: 0x3002:01 R, :02 Lq, :03 Ld; 0x3010:02 bit 4 (the counting direction, toggled when the encoder
//! counts against the field), 0x3010:05 the electrical angle at the index (with an index), 0x301A:03 the Hall
//! offset (with Halls), 0x3204:04 the pole pairs measured. They are persistent objects: 0x1010 keeps them (the
//! procedure writes no flash itself).
//!
//! The procedure runs in the slow tick after the axis step, which in mode -2 runs no loops (the motion step it
//! replaces costs more); it sets tier 1's set-point itself ([`super::DemandSource::Identification`]).

use super::blocks::PowerLevel;
use super::identification::{
    ElectricalIdentification, ElectricalResult, IdentificationConfig, IdentificationError, IdentificationStatus,
    Injection, REFERENCE_SWITCH_RESISTANCE_OHM,
};
use super::mechanical_identification::{
    MechanicalConfig, MechanicalError, MechanicalIdentification, MechanicalResult, MechanicalSample, MechanicalStatus,
};
use super::resonance_identification::{
    ResonanceConfig, ResonanceError, ResonanceIdentification, ResonanceResult, ResonanceStatus,
};
use super::{DemandSource, Drive};
use crate::control::frames::{Amps, Volts};
use crate::fault::table::FaultId;
use crate::od::generated::handles as h;
use crate::power_state::PowerState;

/// Controlword bit 4: a rising edge starts the auto setup (PD4-E, seed 003 p.76).
const START_BIT: u16 = 1 << 4;
/// The whole procedure's timeout, slow ticks (20 s: the limit; IDX 0xFF19).
pub const TIMEOUT_TICKS: u32 = 50_000;
/// 0x3204:01 bit 0: skip the mechanical step.
const OPTION_SKIP_MECHANICAL: u16 = 1 << 0;
/// 0x3204:01 bit 1: skip the auto-tuning.
const OPTION_SKIP_TUNING: u16 = 1 << 1;
/// 0x3204:01 bit 2: skip the resonance step (it takes some 5 s; 0x3205:03/04 keep what a master wrote).
const OPTION_SKIP_RESONANCE: u16 = 1 << 2;
/// Slow ticks the restarted commutation may take to become valid (a forced alignment takes 0.5 s).
const COMMUTATION_TICKS: u32 = 5_000;

/// 0x3204:02 values.
pub mod step {
    /// No identification since start-up.
    pub const IDLE: u8 = 0;
    /// The commutation restarts from the identified offsets.
    pub const COMMUTATION: u8 = 5;
    /// The mechanical experiment (torque constant, inertia, friction).
    pub const MECHANICAL: u8 = 6;
    /// The load's resonance (frequency response of the drive train).
    pub const RESONANCE: u8 = 7;
    /// The auto-tuning of the gains.
    pub const TUNING: u8 = 8;
    /// Finished successfully.
    pub const DONE: u8 = 9;
    /// Failed (the fault tells why).
    pub const FAILED: u8 = 255;
}

/// Where the procedure is (one of them at a time: the sizes of the identifications' states differ, and the drive
/// holds one `Phase` for good, so boxing would only add the allocation the firmware does not have).
#[derive(Clone, Debug)]
#[allow(clippy::large_enum_variant)]
enum Phase {
    Idle,
    Electrical(ElectricalIdentification),
    Commutation { ticks: u32 },
    Mechanical(MechanicalIdentification),
    Resonance(ResonanceIdentification),
    Done,
    Failed,
}

/// The procedure's state (owned by the tier-2 drive).
#[derive(Clone, Debug)]
pub struct AutoSetup {
    phase: Phase,
    last_start_bit: bool,
    ticks: u32,
    /// The period and the q sums of the last report the mechanical step read (its samples are the averages
    /// between two reports).
    last_q_sums: Option<(u32, [i32; 2])>,
}

impl Default for AutoSetup {
    fn default() -> Self {
        Self { phase: Phase::Idle, last_start_bit: false, ticks: 0, last_q_sums: None }
    }
}

impl AutoSetup {
    /// Whether the procedure drives tier 1 now.
    #[must_use]
    pub const fn running(&self) -> bool {
        matches!(
            self.phase,
            Phase::Electrical(_) | Phase::Commutation { .. } | Phase::Mechanical(_) | Phase::Resonance(_)
        )
    }
}

impl Drive {
    /// One slow tick of the auto setup (after the axis step). Out of line and cold: it runs only in mode -2,
    /// and inlined into [`Drive::slow_tick`] it would only grow that (flash, issue 17).
    #[inline(never)]
    #[cold]
    pub(super) fn run_auto_setup(&mut self) {
        let start_bit = self.dictionary.get(h::CONTROLWORD) & START_BIT != 0;
        let rising = start_bit && !self.auto_setup.last_start_bit;
        self.auto_setup.last_start_bit = start_bit;
        if !self.axis.auto_setup_active() || self.state() != PowerState::OperationEnabled {
            if self.auto_setup.running() {
                // Left the mode or the state: the identification stops where it is; the state machine's
                // transition has already taken the power stage where it goes. Another fault (a sensor's
                // supervision) ends it as failed.
                let failed = matches!(self.state(), PowerState::Fault(_)) || self.axis.faults().any_fault();
                self.auto_setup.phase = if failed { Phase::Failed } else { Phase::Idle };
                self.end_injection();
                self.dictionary.set(h::IDENTIFICATION_STEP, if failed { step::FAILED } else { step::IDLE });
            }
            return;
        }
        if rising && !self.auto_setup.running() {
            self.start_auto_setup();
        }
        if self.auto_setup.running() {
            self.auto_setup.ticks = self.auto_setup.ticks.saturating_add(1);
            let ms = self.auto_setup.ticks.saturating_mul(2) / 5;
            self.dictionary.set(h::IDENTIFICATION_DURATION, ms);
            if self.auto_setup.ticks > TIMEOUT_TICKS {
                self.fail_auto_setup(IdentificationError::Timeout);
                return;
            }
        }
        let report = self.report;
        match &mut self.auto_setup.phase {
            Phase::Electrical(identification) => {
                let status = identification.step(&report);
                let shown = identification.step_in_progress().number();
                let progress = identification.progress_per_mille();
                self.dictionary.set(h::IDENTIFICATION_STEP, shown);
                self.dictionary.set(h::IDENTIFICATION_PROGRESS, progress / 2);
                match status {
                    IdentificationStatus::Running(injection) => self.inject(injection),
                    IdentificationStatus::Done(result) => {
                        self.write_electrical_results(&result);
                        self.end_injection();
                        self.auto_setup.phase = Phase::Commutation { ticks: 0 };
                        self.dictionary.set(h::IDENTIFICATION_STEP, step::COMMUTATION);
                    }
                    IdentificationStatus::Failed(e) => self.fail_auto_setup(e),
                }
            }
            Phase::Commutation { ticks } => {
                *ticks = ticks.saturating_add(1);
                let waited = *ticks;
                // The commutation is valid once tier 1 runs with the new settings and has restarted.
                let settled = report.settings_version == self.settings.version && report.stage.is_valid();
                if settled {
                    if self.dictionary.get(h::IDENTIFICATION_OPTIONS) & OPTION_SKIP_MECHANICAL != 0 {
                        self.finish_auto_setup();
                    } else {
                        self.start_mechanical();
                    }
                } else if waited > COMMUTATION_TICKS {
                    self.fail_auto_setup(IdentificationError::Timeout);
                }
            }
            Phase::Mechanical(mechanical) => {
                let sample = averaged_sample(&mut self.auto_setup.last_q_sums, &report);
                let status = mechanical.step(&sample);
                let progress = 500u16.saturating_add(mechanical.progress_per_mille() / 5);
                self.dictionary.set(h::IDENTIFICATION_PROGRESS, progress.min(999));
                match status {
                    MechanicalStatus::Running { i_q_demand } => self.set_identification_current(i_q_demand),
                    MechanicalStatus::Done(result) => {
                        self.set_identification_current(Amps::ZERO);
                        self.write_mechanical_results(&result);
                        if self.dictionary.get(h::IDENTIFICATION_OPTIONS) & OPTION_SKIP_RESONANCE == 0 {
                            self.start_resonance();
                        } else {
                            self.tune_or_finish();
                        }
                    }
                    MechanicalStatus::Failed(e) => self.fail_mechanical(e),
                }
            }
            Phase::Resonance(resonance) => {
                let sample = averaged_sample(&mut self.auto_setup.last_q_sums, &report);
                let status = resonance.step(&sample);
                let progress = 700u16.saturating_add(resonance.progress_per_mille().saturating_mul(3) / 10);
                self.dictionary.set(h::IDENTIFICATION_PROGRESS, progress.min(999));
                match status {
                    ResonanceStatus::Running { i_q_demand } => self.set_identification_current(i_q_demand),
                    ResonanceStatus::Done(result) => {
                        self.set_identification_current(Amps::ZERO);
                        self.write_resonance_results(&result);
                        self.tune_or_finish();
                    }
                    ResonanceStatus::Failed(e) => self.fail_resonance(e),
                }
            }
            Phase::Idle | Phase::Done | Phase::Failed => {}
        }
    }

    fn start_auto_setup(&mut self) {
        let d = &self.dictionary;
        let commutation = &self.settings.commutation;
        let amps = |ma: u32| ma as f32 / 1000.0;
        let config = IdentificationConfig {
            pole_pairs: d.get(h::MOTOR_POLE_PAIRS),
            counts_per_rev: commutation.encoder.counts_per_rev,
            encoder_present: commutation.encoder_present,
            has_index: commutation.encoder.has_index,
            halls_present: commutation.method == super::commutation::CommutationMethod::Hall,
            nominal_current_a: amps(d.get(h::MOTOR_NOMINAL_CURRENT)),
            current_limit_a: amps(d.get(h::MOTOR_OUTPUT_CURRENT_LIMIT)),
            max_speed_rpm: d.get(h::MAX_MOTOR_SPEED) as f32,
            switch_resistance_ohm: REFERENCE_SWITCH_RESISTANCE_OHM,
            timeout_ticks: TIMEOUT_TICKS,
        };
        self.auto_setup.phase = Phase::Electrical(ElectricalIdentification::new(config));
        self.auto_setup.ticks = 0;
        self.axis.set_auto_setup_done(false);
        self.dictionary.set(h::IDENTIFICATION_PROGRESS, 0u16);
        self.dictionary.set(h::IDENTIFICATION_DURATION, 0u32);
    }

    /// Tier 1 runs `injection` from the next period.
    fn inject(&mut self, injection: Injection) {
        let (level, angle, word) = match injection {
            Injection::Current { angle, i_d } => (PowerLevel::InjectCurrent, angle.0, i_d.to_bits().cast_unsigned()),
            Injection::Voltage { angle, v_d_mv, v_q_mv } => (
                PowerLevel::InjectVoltage,
                angle.0,
                u32::from(v_d_mv.cast_unsigned()) | u32::from(v_q_mv.cast_unsigned()) << 16,
            ),
            Injection::Square { on_d, angle, v_d_mv, amplitude_mv } => (
                if on_d { PowerLevel::InjectSquareD } else { PowerLevel::InjectSquareQ },
                angle.0,
                u32::from(v_d_mv.cast_unsigned()) | u32::from(amplitude_mv.cast_unsigned()) << 16,
            ),
        };
        self.source = DemandSource::Identification;
        if self.setpoint.power.level != level {
            self.request(|p| p.level = level, PowerState::OperationEnabled);
        }
        let i_q = Amps::from_bits(angle.cast_signed());
        let i_d = Amps::from_bits(word.cast_signed());
        if i_q != self.setpoint.i_q || i_d != self.setpoint.i_d {
            self.setpoint.i_q = i_q;
            self.setpoint.i_d = i_d;
            self.setpoint_changed();
        }
    }

    /// Back to the plain current loop with zero current (the commutation restarts in tier 1).
    fn end_injection(&mut self) {
        self.setpoint.i_q = Amps::ZERO;
        self.setpoint.i_d = Amps::ZERO;
        if self.setpoint.power.level.injects() {
            self.request(|p| p.level = PowerLevel::OperationEnabled, PowerState::OperationEnabled);
        } else {
            self.setpoint_changed();
        }
    }

    fn write_electrical_results(&mut self, r: &ElectricalResult) {
        let d = &mut self.dictionary;
        let micro_ohm = (r.resistance_ohm * 1e6 + 0.5).clamp(1.0, u32::MAX as f32) as u32;
        let micro = |x: f32| (x * 1e6 + 0.5).clamp(1.0, f32::from(u16::MAX)) as u16;
        d.set(h::MOTOR_PHASE_RESISTANCE, micro_ohm);
        d.set(h::MOTOR_PHASE_INDUCTANCE, micro(r.lq_h));
        d.set(h::MOTOR_PHASE_INDUCTANCE_D, micro(r.ld_h));
        d.set(h::IDENTIFICATION_POLE_PAIRS, r.pole_pairs);
        if r.encoder_reversed {
            let encoder_type: u16 = d.get(h::ENCODER_TYPE);
            d.set(h::ENCODER_TYPE, encoder_type ^ 0x0010);
        }
        // 1/65536 electrical turn, rounded.
        let sixteenth = |a: u32| (a.wrapping_add(1 << 15) >> 16) as u16;
        if let Some(index) = r.index_angle {
            d.set(h::INDEX_COMMUTATION_OFFSET, i32::from(sixteenth(index.0)));
        }
        if let Some(hall) = r.hall_offset {
            d.set(h::HALL_COMMUTATION_OFFSET, sixteenth(hall.0));
        }
        // The commutation restarts with what was found (tier 1 keeps injecting until the level changes).
        self.configure_commutation();
    }

    /// Step 6: the mechanical experiment in FOC with the commutation now known (d current 0).
    fn start_mechanical(&mut self) {
        let d = &self.dictionary;
        // The relay brakes on every reversal: below the limiter's loss-braking voltage it keeps its data (the
        // module drops the half cycles that lift the bus near it); with the limiter off nothing bounds it here
        // (the over-voltage trip still does).
        let regeneration_limit = if d.get(h::BUS_LIMITER_ENABLE) == 0 {
            Volts::from_bits(i32::MAX)
        } else {
            Volts::from_millivolts(i32::try_from(d.get(h::BUS_LIMITER_LOSS_BRAKING_VOLTAGE)).unwrap_or(i32::MAX))
        };
        let config = MechanicalConfig {
            current_limit: Amps::from_milliamps(i32::try_from(d.get(h::MOTOR_NOMINAL_CURRENT)).unwrap_or(i32::MAX)),
            max_speed_rpm: d.get(h::MAX_MOTOR_SPEED),
            counts_per_rev: self.settings.commutation.encoder.counts_per_rev,
            pole_pairs: d.get(h::MOTOR_POLE_PAIRS),
            // 0x3002:01 is in uOhm.
            phase_resistance_milliohm: d.get(h::MOTOR_PHASE_RESISTANCE).saturating_add(500) / 1000,
            timeout_ticks: TIMEOUT_TICKS.saturating_sub(self.auto_setup.ticks),
            regeneration_limit,
        };
        self.auto_setup.phase = Phase::Mechanical(MechanicalIdentification::new(&config));
        self.auto_setup.last_q_sums = None;
        self.dictionary.set(h::IDENTIFICATION_STEP, step::MECHANICAL);
    }

    /// Step 7: the load's resonance, with the inertia and torque constant step 6 wrote (0x30A3:05, 0x3001:05).
    fn start_resonance(&mut self) {
        let d = &self.dictionary;
        let config = ResonanceConfig {
            current_limit: Amps::from_milliamps(i32::try_from(d.get(h::MOTOR_NOMINAL_CURRENT)).unwrap_or(i32::MAX)),
            max_speed_rpm: d.get(h::MAX_MOTOR_SPEED),
            counts_per_rev: self.settings.commutation.encoder.counts_per_rev,
            inertia: d.get(h::OBSERVER_INERTIA),
            torque_constant: d.get(h::MOTOR_TORQUE_CONSTANT),
            coulomb_friction: d.get(h::IDENTIFICATION_COULOMB_FRICTION),
            timeout_ticks: TIMEOUT_TICKS.saturating_sub(self.auto_setup.ticks),
        };
        self.auto_setup.phase = Phase::Resonance(ResonanceIdentification::new(&config));
        self.auto_setup.last_q_sums = None;
        self.dictionary.set(h::IDENTIFICATION_STEP, step::RESONANCE);
    }

    /// The resonance pair for the auto-tuning (0 and 0: rigid).
    fn write_resonance_results(&mut self, r: &ResonanceResult) {
        self.dictionary.set(h::AUTO_TUNING_RESONANCE, r.resonance_dhz);
        self.dictionary.set(h::AUTO_TUNING_ANTI_RESONANCE, r.anti_resonance_dhz);
    }

    fn fail_resonance(&mut self, error: ResonanceError) {
        let fault = match error {
            ResonanceError::SpeedLimit => FaultId::AutoTuningMaxSpeed,
            ResonanceError::Timeout => FaultId::AutoTuningTimeout,
            ResonanceError::InvalidConfig => FaultId::AutoTuningParameter,
        };
        self.end_with_fault(fault, i32::from(error.code()));
    }

    /// Step 8 unless 0x3204:01 bit 1 skips it.
    fn tune_or_finish(&mut self) {
        if self.dictionary.get(h::IDENTIFICATION_OPTIONS) & OPTION_SKIP_TUNING == 0 {
            self.tune_from_results();
        } else {
            self.finish_auto_setup();
        }
    }

    /// The q current of the mechanical step, through the loops' path: the current limits and the bus-voltage
    /// limiter (which brakes with d current when the relay's reversals regenerate) act on it as on the loops'.
    fn set_identification_current(&mut self, i_q: Amps) {
        self.source = DemandSource::Internal;
        self.internal = i_q;
        self.clamp_internal_demand();
        self.update_demand();
    }

    fn write_mechanical_results(&mut self, r: &MechanicalResult) {
        let d = &mut self.dictionary;
        d.set(h::MOTOR_TORQUE_CONSTANT, r.torque_constant.max(1));
        d.set(h::OBSERVER_INERTIA, r.inertia);
        d.set(h::OBSERVER_FRICTION, r.viscous_friction);
        d.set(h::IDENTIFICATION_TOTAL_INERTIA, r.inertia);
        d.set(h::IDENTIFICATION_COULOMB_FRICTION, r.coulomb_friction);
    }

    /// Step 8: the auto-tuning from the identified plant and the requested stiffness 0x3205:02
    /// ([`super::auto_tuning`]): the gains 0x30A0..0x30A3 are written and taken into force by the next background
    /// step as any write of them. A plant the tuning refuses fails the procedure with 0xFF16 (its reason, as
    /// 0x3205:05 shows it, in the detail).
    fn tune_from_results(&mut self) {
        self.dictionary.set(h::IDENTIFICATION_STEP, step::TUNING);
        let values = self.dictionary.values_mut().bytes_mut();
        match super::auto_tuning::run(&[super::auto_tuning::RUN], values) {
            Ok(()) => self.finish_auto_setup(),
            Err(_) => {
                let reason = i32::from(self.dictionary.get(h::AUTO_TUNING_RESULT));
                self.end_with_fault(FaultId::AutoTuningParameter, reason);
            }
        }
    }

    fn fail_mechanical(&mut self, error: MechanicalError) {
        let fault = match error {
            MechanicalError::SpeedLimit => FaultId::AutoTuningMaxSpeed,
            MechanicalError::Timeout => FaultId::AutoTuningTimeout,
            MechanicalError::Obstructed => FaultId::AutoTuningTorqueInvalid,
            MechanicalError::SampleMismatch => FaultId::AutoTuningSampleMismatch,
            MechanicalError::InvalidConfig => FaultId::AutoTuningParameter,
        };
        self.end_with_fault(fault, i32::from(error.code()));
    }

    fn finish_auto_setup(&mut self) {
        self.auto_setup.phase = Phase::Done;
        self.axis.set_auto_setup_done(true);
        self.dictionary.set(h::IDENTIFICATION_STEP, step::DONE);
        self.dictionary.set(h::IDENTIFICATION_PROGRESS, 1000u16);
    }

    fn fail_auto_setup(&mut self, error: IdentificationError) {
        self.end_with_fault(error.fault(), error.detail());
    }

    /// Every way the procedure fails: step 255, no current demanded, and the fault raised (class d: `raise`
    /// switches the power stage off at once).
    fn end_with_fault(&mut self, fault: FaultId, detail: i32) {
        self.auto_setup.phase = Phase::Failed;
        self.dictionary.set(h::IDENTIFICATION_STEP, step::FAILED);
        self.setpoint.i_q = Amps::ZERO;
        self.setpoint.i_d = Amps::ZERO;
        self.raise(fault, detail);
    }
}

/// The sample of the mechanical and resonance steps: the q current and voltage averaged over the periods since
/// the last report (one slow tick); the first tick, without a report before it, takes the last period's values.
/// Out of line: both steps' arms would inline it (flash, issue 17).
#[inline(never)]
fn averaged_sample(last_q_sums: &mut Option<(u32, [i32; 2])>, report: &super::blocks::Tier1Report) -> MechanicalSample {
    let s = &report.signals;
    let periods = last_q_sums.map_or(0, |(period, _)| report.period.wrapping_sub(period));
    let average = |k: usize, last: i32| {
        let previous = last_q_sums.and_then(|(_, sums)| sums.get(k).copied());
        let now = report.q_sums.get(k).copied().unwrap_or(0);
        // No previous report, or no period between the two (a division by zero): the last period's.
        previous.and_then(|p| now.wrapping_sub(p).checked_div(i32::try_from(periods).ok()?)).unwrap_or(last)
    };
    let sample = MechanicalSample {
        position: report.encoder_position,
        i_q: Amps::from_bits(average(0, s.i_dq.q.to_bits())),
        v_q: Volts::from_bits(average(1, s.v_dq.q.to_bits())),
        v_bus: s.v_bus,
    };
    *last_q_sums = Some((report.period, report.q_sums));
    sample
}
