//! 0x3000:01 sensors configuration (issue 18 "0x3000:01 (sensor configuration, saved) ... take effect"): written
//! over SDO with the power stage off, it selects what the drive builds its commutation and position from: the
//! encoder and the Halls (Hall start, encoder position), the encoder only (forced alignment at enable), the Halls
//! only (Hall commutation, the Halls count the position). Any other combination aborts; 0x1010 saves it and the
//! next boot runs with it.

use firmware::drive::commutation::CommutationMethod;
use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::{handles as h, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::store::{ParamStore, SAVE_SIGNATURE};
use firmware::power_state::{CommutationStage, PowerState};
use hal_sim::flash::SimFlash;
use hal_sim::plant::PlantParams;
use hal_sim::sim::Simulation;

const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};
const ENABLED: AccessContext = AccessContext { power_stage_enabled: true, ..PRE_OP };

/// Encoder (sensor 1 type 1) + Halls (sensor 3 type 4): the default.
const ENCODER_AND_HALLS: u32 = 0x0004_0001;
/// Encoder only.
const ENCODER_ONLY: u32 = 0x0000_0001;
/// Halls only.
const HALLS_ONLY: u32 = 0x0004_0000;

fn write_sensors(
    drive: &mut Drive,
    value: u32,
    ctx: AccessContext,
    store: &mut ParamStore<SimFlash>,
) -> Result<(), SdoAbort> {
    drive.sdo_write(0x3000, 1, &value.to_le_bytes(), ctx, store)
}

/// Each supported value is accepted with the power stage off and its derived objects follow at once: 0x3000:03
/// (commutation sensors, bits 7..4 = 3 Halls, 3..0 = 1 encoder: 0x31, 0x01, 0x30) and 0x3000:05 (4,096 inc/rev
/// from the 1,024-line encoder, or 6 x 7 pole pairs = 42 Hall increments). Every other combination aborts with
/// 0x0609_0030 (CiA 301 §7.2.4.3.17, "invalid value": none, SSI 0x03 as sensor 1, Halls as sensor 2, encoder as
/// sensor 3); a write with the power stage on aborts with 0x0800_0022 (device state). A refused write changes
/// nothing.
#[test]
fn supported_combinations_are_accepted_and_others_refused() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut drive = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    for (value, commutation_sensors, resolution) in
        [(ENCODER_ONLY, 0x01, 4096), (HALLS_ONLY, 0x30, 42), (ENCODER_AND_HALLS, 0x31, 4096)]
    {
        write_sensors(&mut drive, value, PRE_OP, &mut store).expect("supported");
        let d = drive.dictionary();
        assert_eq!(d.get(h::SENSORS_CONFIGURATION), value);
        assert_eq!(d.get(h::COMMUTATION_SENSORS), commutation_sensors, "0x3000:03 for {value:#010x}");
        assert_eq!(d.get(h::MAIN_SENSOR_RESOLUTION), resolution, "0x3000:05 for {value:#010x}");
    }
    for refused in [0x0000_0000, 0x0000_0003, 0x0004_0003, 0x0000_0401, 0x0001_0000, 0x0104_0001] {
        assert_eq!(
            write_sensors(&mut drive, refused, PRE_OP, &mut store),
            Err(SdoAbort::InvalidValue),
            "{refused:#010x}"
        );
    }
    assert_eq!(write_sensors(&mut drive, HALLS_ONLY, ENABLED, &mut store), Err(SdoAbort::DeviceState));
    assert_eq!(drive.dictionary().get(h::SENSORS_CONFIGURATION), ENCODER_AND_HALLS, "refused writes change nothing");
    assert_eq!(drive.dictionary().get(h::COMMUTATION_SENSORS), 0x31);
}

/// Encoder only, written over SDO: the next enable aligns (CommutationStage::Aligning in the first period, then
/// Aligned), where the default starts from the Hall sector.
#[test]
fn encoder_only_aligns_at_enable() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut sim = Simulation::new(PlantParams::reference(), 3, DriveConfig::DEFAULT);
    sim.plant.set_rotor_state(1.0, 0.0);
    write_sensors(&mut sim.drive, ENCODER_ONLY, PRE_OP, &mut store).expect("encoder only");
    sim.switch_on().expect("calibrated");
    sim.enable().expect("enabled");
    sim.step();
    assert_eq!(sim.tier1().commutation().stage(), CommutationStage::Aligning);
    sim.run_until(13_000, |s| s.tier1().commutation().stage() != CommutationStage::Aligning).expect("aligned");
    assert_eq!(sim.tier1().commutation().stage(), CommutationStage::Aligned);
    assert_eq!(sim.drive.state(), PowerState::OperationEnabled);
}

/// Halls only, with the encoder's lines broken (the counter never moves): the motor runs on the Halls under
/// 0.5 A of q current (0.5 s, measured 12.4 revolutions on the free reference rotor), without a fault, and 0x6064 counts
/// Hall increments: 42 per revolution, within 2 increments of the plant's true rotation (one Hall state either
/// side, the position is published once per slow tick). With the default (encoder + Halls) the same broken
/// encoder counts nothing, so the position would stay still.
#[test]
fn halls_only_runs_without_the_encoder() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut sim = Simulation::new(PlantParams::reference(), 5, DriveConfig::DEFAULT);
    sim.plant.set_rotor_state(0.4, 0.0);
    sim.plant.faults_mut().encoder_wire_break = true;
    write_sensors(&mut sim.drive, HALLS_ONLY, PRE_OP, &mut store).expect("Halls only");
    sim.switch_on().expect("calibrated");
    sim.enable().expect("enabled");
    sim.run(10);
    let start_position = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    let start_theta = sim.plant.state().theta_m_rad;
    let encoder_count = |s: &Simulation| s.tier1().commutation().encoder().position();
    let start_count = encoder_count(&sim);
    sim.set_q_reference(0.5);
    sim.run(12_500);
    sim.set_q_reference(0.0);
    sim.run(10);
    assert_eq!(sim.drive.state(), PowerState::OperationEnabled, "no fault without the encoder");
    assert_eq!(encoder_count(&sim), start_count, "the drive's encoder count did not move");
    let turns = (sim.plant.state().theta_m_rad - start_theta) / core::f64::consts::TAU;
    assert!(turns > 1.0, "the motor turned: {turns} revolutions");
    let counted = f64::from(sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE).wrapping_sub(start_position));
    assert!((counted - 42.0 * turns).abs() <= 2.0, "0x6064 moved {counted} inc for {turns} revolutions");
}

/// 0x1010 saves 0x3000:01; the drive booted from the store runs with it (commutation method and encoder in the
/// settings tier 1 starts with, 0x3000:03 and 0x3000:05), and a rebooted encoder-only drive aligns at enable.
#[test]
fn sensor_configuration_is_saved_and_restored_at_boot() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut drive = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    write_sensors(&mut drive, HALLS_ONLY, PRE_OP, &mut store).expect("Halls only");
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let rebooted = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    let d = rebooted.dictionary();
    assert_eq!(d.get(h::SENSORS_CONFIGURATION), HALLS_ONLY, "restored");
    assert_eq!((d.get(h::COMMUTATION_SENSORS), d.get(h::MAIN_SENSOR_RESOLUTION)), (0x30, 42));
    let commutation = rebooted.settings().commutation;
    assert_eq!((commutation.method, commutation.encoder_present), (CommutationMethod::Hall, false));

    let mut drive = rebooted;
    write_sensors(&mut drive, ENCODER_ONLY, PRE_OP, &mut store).expect("encoder only");
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let mut sim = Simulation::new(PlantParams::reference(), 3, DriveConfig::DEFAULT);
    sim.plant.set_rotor_state(2.0, 0.0);
    sim.replace_drive(Drive::boot(DriveConfig::DEFAULT, &mut store).0);
    let commutation = sim.drive.settings().commutation;
    assert!(matches!(commutation.method, CommutationMethod::ForcedAlignment(_)), "{commutation:?}");
    assert!(commutation.encoder_present);
    sim.switch_on().expect("calibrated");
    sim.enable().expect("enabled");
    sim.step();
    assert_eq!(sim.tier1().commutation().stage(), CommutationStage::Aligning, "the restored value acts");
}
