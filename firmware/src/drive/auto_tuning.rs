//! The "auto tuning" object 0x3205 (`firmware/device.toml`): a master runs [`super::tuning::tune`] alone, from the
//! motor data objects, and the gains land in 0x30A0..0x30A3, where the drive takes them from as from any write
//! (the current gains at the next background step, `Drive::refresh_parameters`; the loops' at the next slow tick,
//! `Loops::refresh`). This is how a written 0x3002 takes effect.
//!
//! 0x3205:01 is served by the application ([`super::objects::DriveObjects`]): the write of 1 (the access layer has
//! checked that the power stage is off, device.toml `writable_in`; another value answers 0x0609_0030, "invalid
//! value for parameter") computes the gains from the dictionary's value storage and writes them there, all or
//! nothing. A plant or stiffness the tuning refuses
//! answers 0x0604_0043 "general parameter incompatibility" (CiA 301 §7.2.4.3.17 Table 22: the motor data written
//! before are incompatible with a design), nothing else changes but the reason in 0x3205:05.

use super::tuning::{tune, GainObject, PlantValue, Resonance, TunedGains, TuningError, TuningPlant, TuningRequest};
use crate::od::abort::SdoAbort;
use crate::od::entry::Handle;
use crate::od::generated::handles as h;
use crate::od::values::{read_slot, write_slot, Scalar};

/// 0x3205 *Auto tuning*.
pub const AUTO_TUNING: u16 = 0x3205;

/// The command value of 0x3205:01.
pub const RUN: u8 = 1;

/// 0x3205:05 after a successful run.
pub const RESULT_DONE: u8 = 1;

/// Reads a value from the dictionary's value storage (the type's default for a slot outside it). Out of line, as
/// [`set`]: one copy per type instead of one per object (flash, issue 17).
#[inline(never)]
fn get<T: Scalar>(values: &[u8], handle: Handle<T>) -> T {
    read_slot(values, handle)
}

/// Writes a value into the dictionary's value storage (no checks: the drive's own path, as `Dictionary::set`).
#[inline(never)]
fn set<T: Scalar>(values: &mut [u8], handle: Handle<T>, value: T) {
    write_slot(values, handle, value);
}

/// The plant as the motor data objects give it: 0x3002:01 (uOhm), :02 Lq and :03 Ld (uH, 0 = Lq), 0x3001:05 kt
/// (uNm/A), 0x30A3:05 inertia (0.001 g cm^2 = 1e-10 kg m^2), 0x30A3:04 viscous friction (0.001 uNm/rpm), 0x2200:01
/// bus voltage (0.1 V), 0x3001:01/02 nominal and peak current (mA), 0x3000:06 max speed (rpm), 0x3000:05
/// resolution, 0x3205:03/04 the load's resonance pair (0.1 Hz; either 0 = rigid), 0x3204:05 the identified Coulomb
/// friction (uNm; 0 before an identification, which leaves the friction feedforward 0x30A1:06 off).
#[must_use]
pub fn plant_from_objects(values: &[u8]) -> TuningPlant {
    let lq = get(values, h::MOTOR_PHASE_INDUCTANCE);
    let ld = match get(values, h::MOTOR_PHASE_INDUCTANCE_D) {
        0 => lq,
        ld => ld,
    };
    let resonance = get(values, h::AUTO_TUNING_RESONANCE);
    let anti_resonance = get(values, h::AUTO_TUNING_ANTI_RESONANCE);
    let resonance = (resonance != 0 && anti_resonance != 0).then(|| Resonance {
        resonance_hz: f32::from(resonance) * 0.1,
        anti_resonance_hz: f32::from(anti_resonance) * 0.1,
    });
    // 0.001 uNm/rpm = 1e-9 Nm/rpm = 1e-9 * 60 / (2 pi) Nm s/rad.
    let viscous = get(values, h::OBSERVER_FRICTION) as f32 * 1e-9 * 60.0 / (2.0 * core::f32::consts::PI);
    TuningPlant {
        resistance_ohm: get(values, h::MOTOR_PHASE_RESISTANCE) as f32 * 1e-6,
        ld_h: f32::from(ld) * 1e-6,
        lq_h: f32::from(lq) * 1e-6,
        torque_constant_nm_per_a: get(values, h::MOTOR_TORQUE_CONSTANT) as f32 * 1e-6,
        inertia_kg_m2: get(values, h::OBSERVER_INERTIA) as f32 * 1e-10,
        viscous_friction_nm_s_per_rad: viscous,
        coulomb_friction_nm: get(values, h::IDENTIFICATION_COULOMB_FRICTION) as f32 * 1e-6,
        bus_voltage_v: f32::from(get(values, h::POWER_SUPPLY_VOLTAGE)) * 0.1,
        nominal_current_a: get(values, h::MOTOR_NOMINAL_CURRENT) as f32 * 1e-3,
        peak_current_a: get(values, h::MOTOR_OUTPUT_CURRENT_LIMIT) as f32 * 1e-3,
        max_speed_rpm: get(values, h::MAX_SYSTEM_SPEED) as f32,
        counts_per_rev: get(values, h::MAIN_SENSOR_RESOLUTION),
        resonance,
    }
}

/// Writes every gain of `g` into 0x30A0..0x30A3 and the dual loop's main loop 0x30AE:01..03.
pub fn write_gains(values: &mut [u8], g: &TunedGains) {
    set(values, h::CURRENT_CONTROLLER_P_GAIN, g.current.p_uv_per_a);
    set(values, h::CURRENT_CONTROLLER_I_GAIN, g.current.i_uv_per_a_ms);
    set(values, h::POSITION_CONTROLLER_P_GAIN, g.position.p_ua_per_rad);
    set(values, h::POSITION_CONTROLLER_I_GAIN, g.position.i_ua_per_rad_s);
    set(values, h::POSITION_CONTROLLER_D_GAIN, g.position.d_ua_s_per_rad);
    set(values, h::POSITION_CONTROLLER_FF_VELOCITY_GAIN, g.position.ff_velocity_ua_s_per_rad);
    set(values, h::POSITION_CONTROLLER_FF_ACCELERATION_GAIN, g.position.ff_acceleration_ua_s2_per_rad);
    set(values, h::POSITION_CONTROLLER_FF_FRICTION, g.position.ff_friction_ua);
    set(values, h::POSITION_CONTROLLER_D_FILTER_CUTOFF, g.position.d_filter_cutoff_mrad_per_s);
    set(values, h::VELOCITY_CONTROLLER_P_GAIN, g.velocity.p_ua_s_per_rad);
    set(values, h::VELOCITY_CONTROLLER_I_GAIN, g.velocity.i_ua_per_rad);
    set(values, h::VELOCITY_CONTROLLER_FF_VELOCITY_GAIN, g.velocity.ff_velocity_ua_s_per_rad);
    set(values, h::VELOCITY_CONTROLLER_FF_ACCELERATION_GAIN, g.velocity.ff_acceleration_ua_s2_per_rad);
    set(values, h::VELOCITY_FILTER_CUTOFF, g.velocity.filter_cutoff_hz);
    set(values, h::OBSERVER_POSITION_CORRECTION_GAIN, g.observer.position_correction_permille);
    set(values, h::OBSERVER_VELOCITY_CORRECTION_GAIN, g.observer.velocity_correction_mhz);
    set(values, h::OBSERVER_LOAD_CORRECTION_GAIN, g.observer.load_correction_unm_per_rad);
    set(values, h::OBSERVER_FRICTION, g.observer.friction);
    set(values, h::OBSERVER_INERTIA, g.observer.inertia);
    set(values, h::DUAL_LOOP_GAIN_LOW, g.main_loop.k_low);
    set(values, h::DUAL_LOOP_GAIN_HIGH, g.main_loop.k_high);
    set(values, h::DUAL_LOOP_SCHEDULING_WEIGHT, g.main_loop.weight);
}

/// 0x3205:05 for a refusal (device.toml): 16 + plant value, 32 stiffness, 48 + gain object (each code < 16).
#[must_use]
pub const fn result_code(error: TuningError) -> u8 {
    match error {
        TuningError::Plant(v) => 0x10 | plant_value_code(v),
        TuningError::Stiffness => 32,
        TuningError::GainRange(o) => 0x30 | gain_object_code(o),
    }
}

const fn plant_value_code(v: PlantValue) -> u8 {
    match v {
        PlantValue::Resistance => 0,
        PlantValue::Ld => 1,
        PlantValue::Lq => 2,
        PlantValue::TorqueConstant => 3,
        PlantValue::Inertia => 4,
        PlantValue::ViscousFriction => 5,
        PlantValue::CoulombFriction => 6,
        PlantValue::BusVoltage => 7,
        PlantValue::NominalCurrent => 8,
        PlantValue::PeakCurrent => 9,
        PlantValue::MaxSpeed => 10,
        PlantValue::CountsPerRev => 11,
        PlantValue::Resonance => 12,
    }
}

const fn gain_object_code(o: GainObject) -> u8 {
    match o {
        GainObject::CurrentP => 0,
        GainObject::CurrentI => 1,
        GainObject::PositionP => 2,
        GainObject::PositionD => 3,
        GainObject::FeedForwardVelocity => 4,
        GainObject::FeedForwardAcceleration => 5,
        GainObject::VelocityP => 6,
        GainObject::VelocityI => 7,
        GainObject::ObserverLoad => 8,
        GainObject::ObserverFriction => 9,
        GainObject::ObserverInertia => 10,
        GainObject::FeedForwardFriction => 11,
    }
}

/// The command `data` written to 0x3205:01 on the value storage `values`: 1 tunes from the motor data and the
/// stiffness 0x3205:02, writes the gains and 0x3205:05 = 1; or, refused, 0x3205:05 = the reason and 0x0604_0043.
///
/// # Errors
/// [`SdoAbort::InvalidValue`] for a command other than 1 (nothing changes), [`SdoAbort::ParameterIncompatibility`]
/// when [`tune`] refuses the motor data or the stiffness.
pub fn run(data: &[u8], values: &mut [u8]) -> Result<(), SdoAbort> {
    if data != [RUN] {
        return Err(SdoAbort::InvalidValue);
    }
    let request = TuningRequest { stiffness_permille: get(values, h::AUTO_TUNING_STIFFNESS) };
    match tune(&plant_from_objects(values), &request) {
        Ok(gains) => {
            write_gains(values, &gains);
            set(values, h::AUTO_TUNING_RESULT, RESULT_DONE);
            Ok(())
        }
        Err(e) => {
            set(values, h::AUTO_TUNING_RESULT, result_code(e));
            Err(SdoAbort::ParameterIncompatibility)
        }
    }
}
