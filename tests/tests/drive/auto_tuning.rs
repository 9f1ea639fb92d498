//! 0x3002 takes effect through the auto-tuning object 0x3205 (issue 18 "What it must show": "0x3002 ... take
//! effect; a test shows each"; `firmware::drive::auto_tuning`, design in `firmware::drive::tuning`).
//!
//! * Motor data written to 0x3002 (rw with the power stage off, device.toml) change nothing by themselves; the
//!   command 0x3205:01 = 1 computes the gains from them and the current gains the drive hands tier 1 are the new
//!   ones: for the small-gimbal winding (2.8 ohm, 1.5 mH) Kp/L and Ki/R are the 1.53 kHz crossover of the design.
//! * Refusals are precise and change nothing: the command while the power stage is on 0x0800_0022 (CiA 301
//!   Table 22), a value other than 1 0x0609_0030, motor data no design can serve 0x0604_0043 with the reason in
//!   0x3205:05, a stiffness outside 100..1500 0x0609_0031, a zero resistance 0x0609_0032.

use firmware::control::pi::PiGains;
use firmware::drive::tier1::Tier1State;
use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::{handles as h, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::store::ParamStore;
use hal_sim::flash::SimFlash;

const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};
const OP_ENABLED: AccessContext =
    AccessContext { comm_state: CommState::Operational, power_stage_enabled: true, ..PRE_OP };

/// The small-gimbal winding (`hal-sim/presets/small-gimbal.toml`): 2.8 ohm = 2,800,000 uOhm, 1.5 mH = 1,500 uH.
const R_UOHM: u32 = 2_800_000;
const L_UH: u16 = 1_500;
/// The design's current crossover (firmware::drive::tuning: 68 deg phase margin behind one 40 us period).
const CROSSOVER_RAD_S: f64 = (90.0 - 68.0) * core::f64::consts::PI / 180.0 / 40e-6;

fn drive() -> (Drive, ParamStore<SimFlash>) {
    (Drive::new(DriveConfig::DEFAULT), ParamStore::new(SimFlash::params()))
}

fn current_gains(drive: &Drive) -> (u32, u32) {
    let d = drive.dictionary();
    (d.get(h::CURRENT_CONTROLLER_P_GAIN), d.get(h::CURRENT_CONTROLLER_I_GAIN))
}

#[test]
fn written_motor_data_retune_the_current_gains_the_drive_uses() {
    let (mut drive, mut store) = drive();
    let defaults = current_gains(&drive);
    drive.sdo_write(0x3002, 1, &R_UOHM.to_le_bytes(), PRE_OP, &mut store).expect("0x3002:01");
    drive.sdo_write(0x3002, 2, &L_UH.to_le_bytes(), PRE_OP, &mut store).expect("0x3002:02");
    drive.background();
    // The motor data alone leave the gains in force (0x30A0 stays what the master set).
    assert_eq!(current_gains(&drive), defaults);
    assert_eq!(drive.settings().gains, PiGains::from_idx_0x30a0(defaults.0, defaults.1));

    drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store).expect("0x3205:01 = 1");
    assert_eq!(drive.dictionary().get(h::AUTO_TUNING_RESULT), 1);
    let (p, i) = current_gains(&drive);
    // Kp = L wc, Ki = R wc (zero on the winding pole): each within 0.1 % (rounding to the object units).
    let wc_from_p = f64::from(p) * 1e-6 / (f64::from(L_UH) * 1e-6);
    let wc_from_i = f64::from(i) * 1e-3 / (f64::from(R_UOHM) * 1e-6);
    for wc in [wc_from_p, wc_from_i] {
        assert!((wc / CROSSOVER_RAD_S - 1.0).abs() < 1e-3, "crossover {wc} rad/s");
    }
    // The drive hands tier 1 the new gains at its next background step, and tier 1's controllers run with them.
    drive.background();
    let expected = PiGains::from_idx_0x30a0(p, i);
    assert_ne!(expected, PiGains::from_idx_0x30a0(defaults.0, defaults.1));
    assert_eq!(drive.settings().gains, expected);
    let tier1 = Tier1State::new(drive.settings());
    assert_eq!(tier1.controller().pi_q().gains(), expected);
    assert_eq!(tier1.controller().pi_d().gains(), expected);
}

/// The Coulomb friction in 0x3204:05 (the identification's, or a master's commissioning value) becomes the position
/// PID's friction feedforward at the next auto-tuning: 0x30A1:06 = Tc / kt in uA, with the default kt (0x3001:05 =
/// 33,500 uNm/A) 600 uNm gives 17,910 uA (rounded). Before any identification 0x3204:05 is 0 and so is 0x30A1:06.
#[test]
fn the_identified_coulomb_friction_becomes_the_friction_feedforward() {
    let (mut drive, mut store) = drive();
    drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store).expect("0x3205:01 = 1");
    assert_eq!(drive.dictionary().get(h::POSITION_CONTROLLER_FF_FRICTION), 0);
    drive.sdo_write(0x3204, 5, &600u32.to_le_bytes(), PRE_OP, &mut store).expect("0x3204:05");
    assert_eq!(drive.dictionary().get(h::POSITION_CONTROLLER_FF_FRICTION), 0, "a friction alone changes no gain");
    drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store).expect("0x3205:01 = 1");
    assert_eq!(drive.dictionary().get(h::MOTOR_TORQUE_CONSTANT), 33_500);
    assert_eq!(drive.dictionary().get(h::POSITION_CONTROLLER_FF_FRICTION), 17_910);
    let mut buf = [0u8; 4];
    drive.sdo_read(0x30A1, 6, 0, &mut buf, &mut store).expect("0x30A1:06 upload");
    assert_eq!(u32::from_le_bytes(buf), 17_910);
}

/// A master's resonance pair in 0x3205:03/04 (an elastic load) moves the position PID's D filter 0x30A1:07 at the
/// next auto-tuning from EPOS4's 390.61 rad/s to 4 x the stiffness's crossover: 1,903,400 mrad/s at 0x3205:02 =
/// 1000 (`firmware::drive::tuning`, "Position loop"); 0 / 0 (rigid) takes it back. Uploaded over SDO.
#[test]
fn an_elastic_load_raises_the_position_d_filter_and_a_rigid_one_restores_it() {
    let (mut drive, mut store) = drive();
    let d_filter = |drive: &mut firmware::drive::Drive, store: &mut _| {
        let mut buf = [0u8; 4];
        drive.sdo_read(0x30A1, 7, 0, &mut buf, store).expect("0x30A1:07 upload");
        u32::from_le_bytes(buf)
    };
    assert_eq!(d_filter(&mut drive, &mut store), 390_610, "the default: EPOS4's");
    // The object's range: 10 rad/s up to the slow tick's Nyquist frequency, 7,853.981 rad/s (SDO abort codes
    // 0609 0032 / 0609 0031).
    let too_low = drive.sdo_write(0x30A1, 7, &9_999u32.to_le_bytes(), PRE_OP, &mut store);
    assert_eq!(too_low, Err(SdoAbort::ValueTooLow));
    let too_high = drive.sdo_write(0x30A1, 7, &7_853_982u32.to_le_bytes(), PRE_OP, &mut store);
    assert_eq!(too_high, Err(SdoAbort::ValueTooHigh));
    drive.sdo_write(0x3205, 3, &800u16.to_le_bytes(), PRE_OP, &mut store).expect("0x3205:03 = 80 Hz");
    drive.sdo_write(0x3205, 4, &241u16.to_le_bytes(), PRE_OP, &mut store).expect("0x3205:04 = 24.1 Hz");
    drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store).expect("0x3205:01 = 1");
    assert_eq!(d_filter(&mut drive, &mut store), 1_903_400);
    drive.sdo_write(0x3205, 3, &0u16.to_le_bytes(), PRE_OP, &mut store).expect("0x3205:03 = 0");
    drive.sdo_write(0x3205, 4, &0u16.to_le_bytes(), PRE_OP, &mut store).expect("0x3205:04 = 0");
    drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store).expect("0x3205:01 = 1");
    assert_eq!(d_filter(&mut drive, &mut store), 390_610);
}

#[test]
fn auto_tuning_refusals_are_precise_and_change_nothing() {
    let (mut drive, mut store) = drive();
    let before = drive.dictionary().values().clone();
    let mut write =
        |index: u16, sub: u8, data: &[u8], ctx: AccessContext| drive.sdo_write(index, sub, data, ctx, &mut store);
    // Power stage on: neither the motor data nor the command (device.toml writable_in = power-disabled).
    assert_eq!(write(0x3205, 1, &[1], OP_ENABLED), Err(SdoAbort::DeviceState));
    assert_eq!(write(0x3002, 1, &R_UOHM.to_le_bytes(), OP_ENABLED), Err(SdoAbort::DeviceState));
    // Only 1 is a command; the stiffness and the resistance have their ranges.
    assert_eq!(write(0x3205, 1, &[2], PRE_OP), Err(SdoAbort::InvalidValue));
    assert_eq!(write(0x3205, 2, &1501u16.to_le_bytes(), PRE_OP), Err(SdoAbort::ValueTooHigh));
    assert_eq!(write(0x3002, 1, &0u32.to_le_bytes(), PRE_OP), Err(SdoAbort::ValueTooLow));
    assert_eq!(drive.dictionary().values(), &before);
    // 65.535 mH needs Kp = 629 V/A, beyond the current PI's 64 V/A: refused, the reason 0x30 (0x30A0:01) shown.
    drive.sdo_write(0x3002, 2, &u16::MAX.to_le_bytes(), PRE_OP, &mut store).expect("0x3002:02");
    let gains = current_gains(&drive);
    assert_eq!(drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(drive.dictionary().get(h::AUTO_TUNING_RESULT), 0x30);
    assert_eq!(current_gains(&drive), gains);
    // An elastic load's pair inverted (anti-resonance above the resonance): reason 0x1C (plant value 12).
    drive.sdo_write(0x3002, 2, &L_UH.to_le_bytes(), PRE_OP, &mut store).expect("0x3002:02");
    drive.sdo_write(0x3205, 3, &150u16.to_le_bytes(), PRE_OP, &mut store).expect("resonance 15 Hz");
    drive.sdo_write(0x3205, 4, &600u16.to_le_bytes(), PRE_OP, &mut store).expect("anti-resonance 60 Hz");
    assert_eq!(drive.sdo_write(0x3205, 1, &[1], PRE_OP, &mut store), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(drive.dictionary().get(h::AUTO_TUNING_RESULT), 0x1C);
    assert_eq!(current_gains(&drive), gains);
    // The command is write-only.
    let mut buf = [0u8; 1];
    assert_eq!(drive.sdo_read(0x3205, 1, 0, &mut buf, &mut store).err(), Some(SdoAbort::WriteOnly));
}
