//! The SSI absolute encoder as the only sensor (issue 20 items 1 and 5, `drive-sim ssi`): the drive commissioned
//! over SDO for the plant's SSI sensor (0x3000:01 = 0x0000_0300, 0x3012:02/03/0A/0B), with the plant's Halls and
//! incremental encoder disconnected (Halls stuck at 000, encoder lines broken), so that nothing but the SSI frames
//! can commutate or position it.
//!
//! 1. Start-up commutation: «Enable operation» in PPM from rest at an arbitrary shaft angle; the drive's angle in
//!    the first period of the current loop against the plant's true electrical angle (`commutation_error_deg`).
//! 2. A move of [`MOVE_REVOLUTIONS`] revolutions in PPM on the SSI position alone (`move_error_inc`: 0x6064 against
//!    the target once bit 10 is set).
//! 3. Homing method 37 (the position where the axis stands becomes 0x30B0 + 0x607C = [`HOME_POSITION`]; IDX L912-930),
//!    then 0x1010 "save": 0x3012:0E carries the offset.
//! 4. A power cycle of the simulator: the drive is booted afresh from the parameter flash while the shaft is turned
//!    by hand by [`TURNED_WHILE_OFF_RAD`] (the sensor counts its turns without power, as a multi-turn encoder
//!    does); 0x6064 after the restart against the position before it plus the turn
//!    (`absolute_position_error_inc`), without homing.
//! 5. The sensor faults each raise their code (IDX L7276-7308): a data bit flipped in one frame (0x738D), the clock
//!    stuck in operation (0x738C), no sensor from the start (0x7391).

use core::f64::consts::TAU;

use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::{handles as h, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::store::{ParamStore, SAVE_SIGNATURE};

use crate::flash::SimFlash;
use crate::plant::PlantParams;
use crate::sim::{SimError, Simulation};

fn sim_error(e: SimError) -> String {
    e.to_string()
}

/// Revolutions of the PPM move.
pub const MOVE_REVOLUTIONS: i32 = 10;
/// 0x607C for the homing: 0x6064 after homing method 37.
pub const HOME_POSITION: i32 = 100_000;
/// How far the shaft is turned by hand while the drive is off, rad (3.3 revolutions).
pub const TURNED_WHILE_OFF_RAD: f64 = 3.3 * TAU;
/// The shaft's angle at the start, rad: not a whole number of anything.
pub const START_ANGLE_RAD: f64 = 7.0 * TAU + 2.345;

const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};

/// The scenario's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct SsiFigures {
    /// The drive's electrical angle in the first period of the current loop minus the plant's, degrees.
    pub commutation_error_deg: f64,
    /// |0x6064 - target| when the move reported target reached, increments.
    pub move_error_inc: i32,
    /// 0x6064 after the homing, increments.
    pub homed_position_inc: i32,
    /// 0x3012:0E after the homing, increments.
    pub saved_offset_inc: i32,
    /// 0x6064 before the power cycle, increments.
    pub position_before_inc: i32,
    /// 0x6064 after the power cycle, increments.
    pub position_after_inc: i32,
    /// 0x6064 after the power cycle minus (0x6064 before it + the turn by hand in increments), increments.
    pub absolute_position_error_inc: i64,
    /// 0x603F after a data bit was flipped in one frame.
    pub flipped_bit_code: u16,
    /// 0x603F after the clock stuck in operation.
    pub stuck_clock_code: u16,
    /// 0x603F when no sensor answers from the start.
    pub missing_sensor_code: u16,
}

/// The reference motor with a multi-turn SSI sensor (12 multi-turn, 12 single-turn bits, Gray, frame check) in
/// place of the encoder, its zero on the rotor's d axis (factory-aligned) at its multi-turn count 5.
pub fn reference_ssi_plant() -> PlantParams {
    PlantParams {
        ssi_single_turn_bits: 12,
        ssi_multi_turn_bits: 12,
        ssi_gray: true,
        ssi_frame_check: true,
        ssi_offset_counts: 5 * 4096,
        ..PlantParams::reference()
    }
}

/// Writes `value` to `index:sub` over SDO in pre-operational with the power disabled.
fn write(drive: &mut Drive, store: &mut ParamStore<SimFlash>, index: u16, sub: u8, value: &[u8]) -> Result<(), String> {
    drive
        .sdo_write(index, sub, value, PRE_OP, store)
        .map_err(|e: SdoAbort| format!("SDO write {index:#06x}:{sub}: {e:?}"))
}

/// Commissions the drive for the plant's SSI sensor as a user would over SDO: 0x3000:01 = SSI only, 0x3012:02
/// (data bits), :03 (Gray, frame check), :0B (all bits kept) and :0A, the commutation offset that brings the
/// sensor's zero to the rotor's d axis (`-ssi_offset_counts` modulo a revolution: what EPOS4 AN ch. 8.3 measures).
pub fn commission_ssi(drive: &mut Drive, store: &mut ParamStore<SimFlash>, p: &PlantParams) -> Result<(), String> {
    let (st, mt) = (p.ssi_single_turn_bits, p.ssi_multi_turn_bits);
    write(drive, store, 0x3000, 1, &0x0000_0300u32.to_le_bytes())?;
    write(drive, store, 0x3012, 2, &(mt << 16 | st << 8).to_le_bytes())?;
    let encoding = u16::from(p.ssi_gray) | u16::from(p.ssi_frame_check) << 8;
    write(drive, store, 0x3012, 3, &encoding.to_le_bytes())?;
    write(drive, store, 0x3012, 11, &(mt << 8 | st).to_le_bytes())?;
    let offset = (-p.ssi_offset_counts).rem_euclid(1i64 << st) as u32;
    write(drive, store, 0x3012, 10, &offset.to_le_bytes())
}

/// The simulation with the Halls and the encoder disconnected, the shaft at [`START_ANGLE_RAD`], the drive
/// commissioned for the SSI sensor.
pub fn ssi_simulation(p: &PlantParams, seed: u64, store: &mut ParamStore<SimFlash>) -> Result<Simulation, String> {
    let mut sim = Simulation::new(p.clone(), seed, DriveConfig::DEFAULT);
    let faults = sim.plant.faults_mut();
    faults.hall_stuck = Some(0b000);
    faults.encoder_wire_break = true;
    sim.plant.set_rotor_state(START_ANGLE_RAD, 0.0);
    commission_ssi(&mut sim.drive, store, p)?;
    Ok(sim)
}

fn position(sim: &Simulation) -> i32 {
    sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE)
}

/// Runs until statusword bit `bit` is set, at most `ticks` periods.
fn until_status_bit(sim: &mut Simulation, bit: u16, ticks: u64, what: &'static str) -> Result<(), String> {
    sim.run_until(ticks, |s| s.statusword() & (1 << bit) != 0 || s.drive.dictionary().get::<u16>(h::ERROR_CODE) != 0)
        .ok_or(format!("timed out waiting for {what}"))?;
    match sim.drive.dictionary().get::<u16>(h::ERROR_CODE) {
        0 => Ok(()),
        code => Err(format!("fault {code:#06x} while waiting for {what}")),
    }
}

/// The whole scenario (module documentation) on plant `p` with noise seed `seed`.
pub fn run(p: &PlantParams, seed: u64) -> Result<SsiFigures, String> {
    let mut store = ParamStore::new(SimFlash::params());
    let mut sim = ssi_simulation(p, seed, &mut store)?;
    // 1. Start-up commutation, in the first period the current loop runs.
    sim.enable_through_controlword(1).map_err(sim_error)?;
    let commutation_error_deg = super::angle_error_deg(&sim);
    // 2. A move on the SSI position alone.
    let resolution = 1i32 << p.ssi_single_turn_bits;
    let target = position(&sim).wrapping_add(MOVE_REVOLUTIONS * resolution);
    sim.drive.dictionary_mut().set(h::TARGET_POSITION, target);
    sim.set_controlword(0x003F);
    sim.run(250);
    sim.set_controlword(0x000F);
    until_status_bit(&mut sim, 10, 5 * 25_000, "target reached")?;
    sim.run(2_500);
    let move_error_inc = position(&sim).wrapping_sub(target).abs();
    // 3. Homing method 37 where the axis stands, then save.
    sim.drive.dictionary_mut().set(h::HOMING_METHOD, 37i8);
    sim.drive.dictionary_mut().set(h::HOME_OFFSET, HOME_POSITION);
    sim.set_mode(6);
    sim.run(250);
    sim.set_controlword(0x001F);
    until_status_bit(&mut sim, 12, 25_000, "homing attained")?;
    sim.set_controlword(0x000F);
    sim.run(250);
    let homed_position_inc = position(&sim);
    let saved_offset_inc = sim.drive.dictionary().get(h::SSI_POSITION_OFFSET);
    sim.set_controlword(0x0006);
    sim.run(2_500);
    write(&mut sim.drive, &mut store, 0x1010, 1, &SAVE_SIGNATURE.to_le_bytes())?;
    let position_before_inc = position(&sim);
    // 4. Power cycle, the shaft turned by hand meanwhile.
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta + TURNED_WHILE_OFF_RAD, 0.0);
    sim.replace_drive(Drive::boot(DriveConfig::DEFAULT, &mut store).0);
    sim.run(2_500);
    let position_after_inc = position(&sim);
    // The sensor's increments between the two shaft angles (each angle's count is the floor of its increments).
    let count = |theta: f64| (theta / TAU * f64::from(resolution)).floor() as i64;
    let turned_inc = count(theta + TURNED_WHILE_OFF_RAD) - count(theta);
    let absolute_position_error_inc = i64::from(position_after_inc) - (i64::from(position_before_inc) + turned_inc);
    // 5. The sensor faults.
    let (flipped_bit_code, stuck_clock_code, missing_sensor_code) = fault_codes(p, seed)?;
    Ok(SsiFigures {
        commutation_error_deg,
        move_error_inc,
        homed_position_inc,
        saved_offset_inc,
        position_before_inc,
        position_after_inc,
        absolute_position_error_inc,
        flipped_bit_code,
        stuck_clock_code,
        missing_sensor_code,
    })
}

/// 0x603F after each sensor fault, injected into an enabled drive (the flipped bit and the stuck clock) or from
/// the start (no sensor, at the switch-on that builds the commutation for it): single-turn bit 8 flipped in one
/// frame; the clock stuck; no sensor answering.
pub fn fault_codes(p: &PlantParams, seed: u64) -> Result<(u16, u16, u16), String> {
    let code = |sim: &Simulation| sim.drive.dictionary().get::<u16>(h::ERROR_CODE);
    let mut store = ParamStore::new(SimFlash::params());
    let mut flipped = ssi_simulation(p, seed, &mut store)?;
    flipped.enable_through_controlword(1).map_err(sim_error)?;
    flipped.run(100);
    // A single-turn bit flipped in the frame the drive reads next: bit 8 of the 12 single-turn bits.
    flipped.plant.faults_mut().ssi_flip_bit_once = Some(1 + 8);
    flipped.run(50);
    let mut stuck = ssi_simulation(p, seed, &mut store)?;
    stuck.enable_through_controlword(1).map_err(sim_error)?;
    stuck.run(100);
    stuck.plant.faults_mut().ssi_clock_stuck = true;
    stuck.run(50);
    let mut missing = ssi_simulation(p, seed, &mut store)?;
    missing.plant.faults_mut().ssi_missing = true;
    // The SSI configuration is taken at the switch-on: tier 1's commutation is built for the sensor then.
    missing.set_mode(1);
    missing.set_controlword(0x0006);
    missing.run(250);
    missing.set_controlword(0x0007);
    missing.run(3_000);
    Ok((code(&flipped), code(&stuck), code(&missing)))
}
