//! The gear and its user units on the reference plant (issue 20 item 3; IDX 0x3003 L4067-4158 and control
//! structure 0x3000:02 bit 12, IDX 0x3000:06 L3898-3939, PD4-E 0x6091 p.257; `firmware::motion::gear`): with a
//! gear of N motor revolutions per load revolution the master's positions count load increments (0x3000:05 =
//! 4,096 per load revolution), its velocities are load rpm, and 0x3003:03 limits the motor's speed. The reference
//! plant has no gear of its own: the drive's units are checked against the motor's true encoder count and speed,
//! which a real gear would divide by N at the load. Written over SDO as a master does, with the power stage off.
//!
//! Tolerances: positions within the position window 0x6067 (10 load inc, 50 motor inc at 5:1; measured 0 to 2
//! load inc after a move); velocities held by the velocity loop within 15 motor rpm (half the velocity window
//! 0x606D, as `polarity.rs`), 3 rpm at the load for 5:1 (15 / 5).

use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::AccessContext;
use firmware::od::generated::handles as h;
use firmware::od::store::{ParamStore, LOAD_SIGNATURE, SAVE_SIGNATURE};
use hal_sim::flash::SimFlash;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::{prepare_plant, Setup};
use hal_sim::sim::Simulation;

use super::master::{get_i32, home_here, ppm_move, BIT12, BIT4, ENABLE_OPERATION, PRE_OP};

/// 0x6067 default, (load) increments.
const POSITION_WINDOW_INC: i64 = 10;
/// Half the 0x606D default, motor rpm.
const MOTOR_RPM_TOLERANCE: f64 = 15.0;
/// Statusword bit 11, internal limit active.
const INTERNAL_LIMIT: u16 = 1 << 11;
/// 0x3000:02 bit 12, gear mounted.
const GEAR_MOUNTED: u32 = 1 << 12;

/// A write of the master, as an SDO download.
type Write<'a> = (u16, u8, &'a [u8]);

/// The commissioned reference drive, shut down («Ready to switch on», power stage off), `writes` made over SDO,
/// then enabled in `mode` through the controlword.
fn enabled_with(writes: &[Write<'_>], mode: i8) -> Simulation {
    let (mut sim, _) = prepare_plant(PlantParams::reference(), &Setup { seed: 4, ..Setup::default() }).expect("ready");
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, 0.0);
    sim.set_controlword(0x0006);
    sim.run_slow_ticks(10);
    let mut store = ParamStore::new(SimFlash::params());
    let ctx = AccessContext { power_stage_enabled: sim.drive.power_stage_enabled(), ..PRE_OP };
    for &(index, sub, data) in writes {
        sim.drive.sdo_write(index, sub, data, ctx, &mut store).expect("power stage off: accepted");
    }
    sim.enable_through_controlword(mode).expect("enabled");
    sim.run_slow_ticks(50);
    sim
}

/// 0x3000:02 with bit 12 set, from the default.
fn control_structure_with_gear() -> [u8; 4] {
    (Drive::new(DriveConfig::DEFAULT).dictionary().get(h::CONTROL_STRUCTURE) | GEAR_MOUNTED).to_le_bytes()
}

/// round(x p / q), half up: the conversion the drive must make.
fn rounded(x: i64, p: i64, q: i64) -> i64 {
    (2 * x * p + q).div_euclid(2 * q)
}

/// IDX 0x3003 + 0x3000:02 bit 12, 5:1, PPM: a target of 0x6064 + 4,096 (one load revolution) turns the motor
/// 5 x 4,096 = 20,480 inc; 0x6064 and 0x6062 end at the target in load increments, the internal 0x6063 moved
/// 20,480 motor increments; 0x6091 reads 5:1, 0x3000:06 = 5,000 / 5 = 1,000 rpm.
#[test]
fn gear_through_0x3003_makes_0x607a_and_0x6064_count_load_increments() {
    let cs = control_structure_with_gear();
    let mut sim =
        enabled_with(&[(0x3003, 1, &5u32.to_le_bytes()), (0x3000, 2, &cs), (0x6081, 0, &200u32.to_le_bytes())], 1);
    let d = sim.drive.dictionary();
    assert_eq!(
        (d.get(h::GEAR_RATIO_MOTOR_REVOLUTIONS), d.get(h::GEAR_RATIO_SHAFT_REVOLUTIONS), d.get(h::MAX_SYSTEM_SPEED)),
        (5, 1, 1000)
    );
    let (start, start_internal) =
        (get_i32(&sim, h::POSITION_ACTUAL_VALUE), get_i32(&sim, h::POSITION_ACTUAL_INTERNAL_VALUE));
    let start_count = sim.plant.true_encoder_count();
    ppm_move(&mut sim, start + 4096, 10_000);
    assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - (start + 4096)).abs() <= 2, "0x6064 at the load target");
    assert_eq!(get_i32(&sim, h::POSITION_DEMAND_VALUE), start + 4096, "0x6062 at the target");
    let moved = sim.plant.true_encoder_count() - start_count;
    assert!((moved - 20_480).abs() <= 5 * POSITION_WINDOW_INC, "the motor moved {moved} inc");
    let internal = get_i32(&sim, h::POSITION_ACTUAL_INTERNAL_VALUE) - start_internal;
    assert!((internal - 20_480).abs() <= 5 * POSITION_WINDOW_INC, "0x6063 moved {internal}");
}

/// The same gear in CSP without interpolation (0x60C2 = 0): the master moves 0x607A by +1 load inc per set-point
/// (one per slow tick, 14.6 load rpm) for 1,024 set-points, then holds; the motor turns 5 x 1,024 = 5,120 inc
/// (within the position window, 50 motor inc) and 0x6064 ends on the last target (within 2 load inc).
#[test]
fn gear_through_0x3003_in_csp() {
    let cs = control_structure_with_gear();
    let mut sim = enabled_with(&[(0x3003, 1, &5u32.to_le_bytes()), (0x3000, 2, &cs)], 8);
    sim.drive.dictionary_mut().set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
    let start = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
    let start_count = sim.plant.true_encoder_count();
    for k in 1..=1_274_i64 {
        let target = start + k.min(1_024);
        sim.drive.dictionary_mut().set(h::TARGET_POSITION, i32::try_from(target).expect("in range"));
        sim.setpoint_received();
        sim.run_slow_ticks(1);
    }
    assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - (start + 1_024)).abs() <= 2, "0x6064 on the last target");
    let moved = sim.plant.true_encoder_count() - start_count;
    assert!((moved - 5_120).abs() <= 5 * POSITION_WINDOW_INC, "the motor moved {moved} inc");
}

/// PD4-E 0x6091 written alone (5:1) sets 0x3003:01/02 and bit 12 and acts as the same gear: PVM at 0x60FF = 100
/// load rpm turns the motor at 500 rpm; 0x606C and 0x606B read 100 rpm (within 3); 0x6064 advances by load
/// increments (1 s at 100 rpm: 1/6 x 100 x 4,096 / 60 x 6 = 6,827 load inc, a fifth of the motor's 34,133).
#[test]
fn gear_through_0x6091_acts_in_pvm_with_load_rpm() {
    let mut sim = enabled_with(&[(0x6091, 1, &5u32.to_le_bytes())], 3);
    let d = sim.drive.dictionary();
    assert_eq!(
        (
            d.get(h::GEAR_REDUCTION_NUMERATOR),
            d.get(h::GEAR_REDUCTION_DENOMINATOR),
            d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED
        ),
        (5, 1, GEAR_MOUNTED)
    );
    let start = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
    let start_count = sim.plant.true_encoder_count();
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 100);
    sim.run_slow_ticks(2_500);
    let speed = sim.plant.state().speed_rpm;
    assert!((speed - 500.0).abs() <= MOTOR_RPM_TOLERANCE, "the motor turns at {speed} rpm");
    for (handle, name) in [(h::VELOCITY_ACTUAL_VALUE, "0x606C"), (h::VELOCITY_DEMAND_VALUE, "0x606B")] {
        let shown = f64::from(sim.drive.dictionary().get(handle));
        assert!((shown - 100.0).abs() <= MOTOR_RPM_TOLERANCE / 5.0, "{name} = {shown}");
    }
    let motor = sim.plant.true_encoder_count() - start_count;
    let load = get_i32(&sim, h::POSITION_ACTUAL_VALUE) - start;
    assert!((load - motor / 5).abs() <= 2, "0x6064 moved {load} load inc for {motor} motor inc");
}

/// A non-integer reduction, 359,424 : 875 (410.77...): PPM to 0x6064 + 10 load inc; the demand 0x6062 ends
/// exactly at the target and the internal demand 0x60FC exactly at round(target x 359,424 / 875) motor
/// increments (the conversion is absolute and exactly rounded), and 0x6064 reads the target (within 1 load inc =
/// 411 motor inc).
#[test]
fn non_integer_ratio_converts_exactly() {
    let cs = control_structure_with_gear();
    let writes: [Write<'_>; 3] =
        [(0x3003, 1, &359_424u32.to_le_bytes()), (0x3003, 2, &875u32.to_le_bytes()), (0x3000, 2, &cs)];
    let mut sim = enabled_with(&writes, 1);
    sim.drive.dictionary_mut().set(h::PROFILE_VELOCITY, 1u32);
    let target = get_i32(&sim, h::POSITION_ACTUAL_VALUE) + 10;
    ppm_move(&mut sim, target, 10_000);
    assert_eq!(get_i32(&sim, h::POSITION_DEMAND_VALUE), target, "0x6062");
    assert_eq!(get_i32(&sim, h::POSITION_DEMAND_INTERNAL_VALUE), rounded(target, 359_424, 875), "0x60FC");
    assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - target).abs() <= 1, "0x6064");
}

/// 5:1: the home offset 0x607C and the software limits 0x607D are load increments. Homing method 37 makes
/// 0x6064 read the home offset, 1,000 (within 2); a PPM target of 3,000 beyond 0x607D:02 = 1,500 ends at 1,500
/// (the motor moves 500 x 5 = 2,500 inc), at a profile velocity and acceleration in load rpm and rpm/s.
#[test]
fn home_offset_and_software_limits_count_load_increments() {
    let cs = control_structure_with_gear();
    let mut sim = enabled_with(&[(0x3003, 1, &5u32.to_le_bytes()), (0x3000, 2, &cs)], 6);
    home_here(&mut sim, 1_000);
    assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - 1_000).abs() <= 2, "0x6064 reads the home offset");
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::SOFTWARE_POSITION_LIMIT_MIN, -2_000);
        d.set(h::SOFTWARE_POSITION_LIMIT_MAX, 1_500);
        // 200 load rpm, 2,000 load rpm/s (1,000 rpm and 10,000 rpm/s at the motor): the axis stops at the limit
        // without overshooting it (an actual position beyond 0x607D is the software-limit fault, IDX 0x8A82).
        d.set(h::PROFILE_VELOCITY, 200u32);
        d.set(h::PROFILE_ACCELERATION, 2_000u32);
        d.set(h::PROFILE_DECELERATION, 2_000u32);
    }
    sim.set_controlword(ENABLE_OPERATION);
    sim.set_mode(1);
    sim.run_slow_ticks(10);
    let start_count = sim.plant.true_encoder_count();
    let start = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
    ppm_move(&mut sim, 3_000, 10_000);
    let position = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
    assert!((position - 1_500).abs() <= 2, "0x6064 = {position}, held at 0x607D:02");
    let moved = sim.plant.true_encoder_count() - start_count;
    assert!((moved - 5 * (1_500 - start)).abs() <= 5 * POSITION_WINDOW_INC, "the motor moved {moved}");
}

/// IDX 0x3003:03 max gear input speed: with 5:1 and 0x3003:03 = 1,000 rpm, PVM at 0x60FF = 400 load rpm (2,000
/// motor rpm) holds the motor at 1,000 rpm with statusword bit 11 (internal limit); 0x606C reads 200 load rpm,
/// and 0x3000:06 = min(5,000, 1,000) / 5 = 200. Without bit 12 the same 0x3003:03 does not act (no gear: IDX
/// 0x3000:06 is the max motor speed).
#[test]
fn max_gear_input_speed_limits_the_motor() {
    let cs = control_structure_with_gear();
    let writes: [Write<'_>; 3] =
        [(0x3003, 1, &5u32.to_le_bytes()), (0x3003, 3, &1_000u32.to_le_bytes()), (0x3000, 2, &cs)];
    let mut sim = enabled_with(&writes, 3);
    assert_eq!(sim.drive.dictionary().get(h::MAX_SYSTEM_SPEED), 200, "0x3000:06");
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 400);
    sim.run_slow_ticks(2_500);
    let speed = sim.plant.state().speed_rpm;
    assert!((speed - 1_000.0).abs() <= MOTOR_RPM_TOLERANCE, "the motor turns at {speed} rpm");
    let shown = f64::from(sim.drive.dictionary().get(h::VELOCITY_ACTUAL_VALUE));
    assert!((shown - 200.0).abs() <= MOTOR_RPM_TOLERANCE / 5.0, "0x606C = {shown}");
    assert_ne!(sim.statusword() & INTERNAL_LIMIT, 0, "bit 11");

    let mut ungeared = enabled_with(&[(0x3003, 3, &1_000u32.to_le_bytes())], 3);
    assert_eq!(ungeared.drive.dictionary().get(h::MAX_SYSTEM_SPEED), 5_000, "0x3000:06 without a gear");
    ungeared.drive.dictionary_mut().set(h::TARGET_VELOCITY, 2_000);
    ungeared.run_slow_ticks(2_500);
    let speed = ungeared.plant.state().speed_rpm;
    assert!((speed - 2_000.0).abs() <= MOTOR_RPM_TOLERANCE, "no gear: the motor turns at {speed} rpm");
}

/// 0x3003:03 bounds the profile moves too: with 5:1 and 0x3003:03 = 1,000 rpm, a PPM move of 8,192 load inc at
/// 0x6081 = 400 load rpm (2,000 motor rpm) peaks at 1,000 motor rpm, 200 load rpm (within 30 rpm, the velocity
/// window 0x606D: a peak carries the velocity loop's overshoot at the end of the ramp; measured 1,021).
#[test]
fn max_gear_input_speed_bounds_profile_moves() {
    let cs = control_structure_with_gear();
    let writes: [Write<'_>; 4] = [
        (0x3003, 1, &5u32.to_le_bytes()),
        (0x3003, 3, &1_000u32.to_le_bytes()),
        (0x3000, 2, &cs),
        (0x6081, 0, &400u32.to_le_bytes()),
    ];
    let mut sim = enabled_with(&writes, 1);
    let target = get_i32(&sim, h::POSITION_ACTUAL_VALUE) + 8_192;
    sim.drive.dictionary_mut().set(h::TARGET_POSITION, i32::try_from(target).expect("in range"));
    sim.set_controlword(ENABLE_OPERATION | BIT4);
    let mut peak: f64 = 0.0;
    for _ in 0..5_000 {
        sim.run_slow_ticks(1);
        peak = peak.max(sim.plant.state().speed_rpm.abs());
        if sim.statusword() & BIT12 != 0 {
            sim.set_controlword(ENABLE_OPERATION);
        }
    }
    assert!((peak - 1_000.0).abs() <= 2.0 * MOTOR_RPM_TOLERANCE, "peak motor speed {peak} rpm");
    assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - target).abs() <= 2, "the move ends at the target");
}

/// The objects' rules: 0x3003:01/02/04 and 0x6091 are written only with the power stage off (0x0800_0022, as
/// every `power-disabled` entry), 0x3003:03 also while enabled (IDX); a zero numerator or denominator is below
/// the range 1..2^32-1 (0x0609_0032, value too low) and changes nothing; 0x3003:04 takes bit 0 only (0x0609_0030).
#[test]
fn gear_writes_are_checked() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut drive = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    let enabled = AccessContext { power_stage_enabled: true, ..PRE_OP };
    for (index, sub) in [(0x3003, 1), (0x3003, 2), (0x3003, 4), (0x6091, 1), (0x6091, 2)] {
        assert_eq!(
            drive.sdo_write(index, sub, &1u32.to_le_bytes(), enabled, &mut store),
            Err(SdoAbort::DeviceState),
            "{index:04X}:{sub}"
        );
    }
    drive.sdo_write(0x3003, 3, &2_000u32.to_le_bytes(), enabled, &mut store).expect("0x3003:03 while enabled");
    for (index, sub) in [(0x3003, 1), (0x3003, 2), (0x6091, 1), (0x6091, 2)] {
        assert_eq!(
            drive.sdo_write(index, sub, &0u32.to_le_bytes(), PRE_OP, &mut store),
            Err(SdoAbort::ValueTooLow),
            "{index:04X}:{sub} = 0"
        );
    }
    let d = drive.dictionary();
    assert_eq!((d.get(h::GEAR_REDUCTION_NUMERATOR), d.get(h::GEAR_REDUCTION_DENOMINATOR)), (1, 1), "unchanged");
    assert_eq!(drive.sdo_write(0x3003, 4, &2u32.to_le_bytes(), PRE_OP, &mut store), Err(SdoAbort::InvalidValue));
}

/// 0x3003 and bit 12 are saved by 0x1010 and restored at boot like other persistent entries (0x6091 follows them:
/// it reads 7:2 after the boot); 0x1011 (restore defaults) brings back no gear at the next boot (1:1).
#[test]
fn gear_is_saved_and_restored() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut drive = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    drive.sdo_write(0x6091, 1, &7u32.to_le_bytes(), PRE_OP, &mut store).expect("0x6091:01");
    drive.sdo_write(0x6091, 2, &2u32.to_le_bytes(), PRE_OP, &mut store).expect("0x6091:02");
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let rebooted = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    let d = rebooted.dictionary();
    assert_eq!(
        (
            d.get(h::GEAR_REDUCTION_NUMERATOR),
            d.get(h::GEAR_REDUCTION_DENOMINATOR),
            d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED,
            d.get(h::GEAR_RATIO_MOTOR_REVOLUTIONS),
            d.get(h::GEAR_RATIO_SHAFT_REVOLUTIONS)
        ),
        (7, 2, GEAR_MOUNTED, 7, 2)
    );
    let mut drive = rebooted;
    drive.sdo_write(0x1011, 1, &LOAD_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("restore defaults");
    let defaults = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    let d = defaults.dictionary();
    assert_eq!(
        (d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED, d.get(h::GEAR_RATIO_MOTOR_REVOLUTIONS)),
        (0, 1),
        "no gear after 0x1011"
    );
}

/// Polarity 0x607E = 0xC0 reverses position, velocity and torque together (`firmware::motion::polarity`: torques
/// take bit 6): in CST with 0x6071 = +100 per mille the motor turns backwards (its true speed below -100 rpm
/// after 0.4 s), while the master reads a positive torque 0x6077 (> 50 per mille), a positive 0x606C and a rising
/// 0x6064; with 0x607E = 0 the same torque turns the motor forwards with the same readings.
#[test]
fn polarity_0xc0_reverses_position_velocity_and_torque_together() {
    for (polarity, motor_sign) in [(0x00_u8, 1.0), (0xC0, -1.0)] {
        let mut sim = enabled_with(&[(0x607E, 0, &[polarity])], 10);
        let start = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
        sim.set_target_torque(100);
        sim.run_slow_ticks(1_000);
        let what = format!("0x607E = {polarity:#04x}");
        let speed = sim.plant.state().speed_rpm;
        assert!(speed * motor_sign > 100.0, "{what}: the motor turns at {speed} rpm");
        let d = sim.drive.dictionary();
        let (torque, velocity) = (d.get(h::TORQUE_ACTUAL_VALUE), d.get(h::VELOCITY_ACTUAL_VALUE));
        assert!(torque > 50, "{what}: 0x6077 = {torque}");
        assert!(velocity > 100, "{what}: 0x606C = {velocity}");
        assert!(get_i32(&sim, h::POSITION_ACTUAL_VALUE) - start > 4096, "{what}: 0x6064 rises");
        assert!(d.get(h::TORQUE_DEMAND_VALUE) == 100, "{what}: 0x6074 = {}", d.get(h::TORQUE_DEMAND_VALUE));
    }
}
