//! Polarity 0x607E on the reference plant (issue 18 "0x607E (polarity) take effect"; Glentek Gamma L1656-1672,
//! Nanotec PD4-E p.250 L627; `firmware::motion::polarity`): bit 7 multiplies the position values exchanged with
//! the master by -1 (PPM, CSP, home offset, software limits, 0x6064/0x6062/0x60F4), bit 6 the velocity values
//! (PVM, CSV, 0x606C/0x606B), and bit 6 the torques (CST, 0x6077; 0x60B2 takes bit 7 in CSP); the motor's own
//! direction is the plant's true encoder count. Written over SDO as a master does, with the power stage off.
//!
//! Tolerances: the position window 0x6067 (10 inc) for positions after a move (measured 0 to 1 inc), and 15 rpm
//! for velocities held by the velocity loop (half the velocity window 0x606D; measured within 0.5 rpm).

use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::AccessContext;
use firmware::od::generated::handles as h;
use firmware::od::store::{ParamStore, SAVE_SIGNATURE};
use hal_sim::flash::SimFlash;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::{prepare_plant, Setup};
use hal_sim::sim::Simulation;

use super::master::{get_i32, home_here, ppm_move, ENABLE_OPERATION, PRE_OP};

/// 0x6067 default, increments.
const POSITION_WINDOW_INC: i64 = 10;
/// Half the 0x606D default, rpm.
const VELOCITY_TOLERANCE_RPM: f64 = 15.0;

/// The commissioned reference drive, shut down («Ready to switch on», power stage off), 0x607E = `polarity`
/// written over SDO, then enabled in `mode` through the controlword.
fn enabled_with(polarity: u8, mode: i8) -> Simulation {
    let (mut sim, _) = prepare_plant(PlantParams::reference(), &Setup { seed: 4, ..Setup::default() }).expect("ready");
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, 0.0);
    sim.set_controlword(0x0006);
    sim.run_slow_ticks(10);
    let mut store = ParamStore::new(SimFlash::params());
    let ctx = AccessContext { power_stage_enabled: sim.drive.power_stage_enabled(), ..PRE_OP };
    sim.drive.sdo_write(0x607E, 0, &[polarity], ctx, &mut store).expect("power stage off: accepted");
    sim.enable_through_controlword(mode).expect("enabled");
    sim.run_slow_ticks(50);
    sim
}

/// PPM, one revolution forwards in the master's coordinates (target = 0x6064 + 4,096): 0x6064 and the demand
/// 0x6062 end at the target in every case; the motor turns +4,096 inc with 0x607E = 0 and 0x40 (bit 6 is not a
/// position bit) and -4,096 inc with 0x80 and 0xC0; the internal value 0x6063 keeps the motor's direction.
#[test]
fn ppm_target_and_actual_position_follow_bit_7() {
    for (polarity, motor_sign) in [(0x00_u8, 1_i64), (0x40, 1), (0x80, -1), (0xC0, -1)] {
        let mut sim = enabled_with(polarity, 1);
        let (start, start_internal) =
            (get_i32(&sim, h::POSITION_ACTUAL_VALUE), get_i32(&sim, h::POSITION_ACTUAL_INTERNAL_VALUE));
        let start_count = sim.plant.true_encoder_count();
        ppm_move(&mut sim, start + 4096, 5000);
        let what = format!("0x607E = {polarity:#04x}");
        assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - (start + 4096)).abs() <= POSITION_WINDOW_INC, "{what}");
        assert_eq!(get_i32(&sim, h::POSITION_DEMAND_VALUE), start + 4096, "{what}: 0x6062 at the target");
        let moved = sim.plant.true_encoder_count() - start_count;
        assert!((moved - motor_sign * 4096).abs() <= POSITION_WINDOW_INC, "{what}: the motor moved {moved} inc");
        let internal = get_i32(&sim, h::POSITION_ACTUAL_INTERNAL_VALUE) - start_internal;
        assert!((internal - motor_sign * 4096).abs() <= POSITION_WINDOW_INC, "{what}: 0x6063 moved {internal}");
        assert!(get_i32(&sim, h::FOLLOWING_ERROR_ACTUAL_VALUE).abs() <= POSITION_WINDOW_INC, "{what}: 0x60F4");
    }
}

/// PVM at 0x60FF = +300 rpm for 1 s: the motor turns at +300 rpm with 0x607E = 0 and 0x80 (bit 7 is not a
/// velocity bit), at -300 rpm with 0x40 and 0xC0; 0x606C and 0x606B read +300 rpm in every case. 0x6064 runs
/// with the motor unless bit 7 is set, against it when it is (the bits are independent: Gamma Table 9-2), so it
/// rises with 0x00 and 0xC0 and falls with 0x80 and 0x40.
#[test]
fn pvm_target_and_actual_velocity_follow_bit_6() {
    for (polarity, motor_sign, position_sign) in
        [(0x00_u8, 1.0, 1_i64), (0x80, 1.0, -1), (0x40, -1.0, -1), (0xC0, -1.0, 1)]
    {
        let mut sim = enabled_with(polarity, 3);
        let start = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
        sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 300);
        sim.run_slow_ticks(2_500);
        let what = format!("0x607E = {polarity:#04x}");
        let speed = sim.plant.state().speed_rpm;
        assert!((speed - motor_sign * 300.0).abs() <= VELOCITY_TOLERANCE_RPM, "{what}: the motor turns at {speed}");
        for (handle, name) in [(h::VELOCITY_ACTUAL_VALUE, "0x606C"), (h::VELOCITY_DEMAND_VALUE, "0x606B")] {
            let shown = f64::from(sim.drive.dictionary().get(handle));
            assert!((shown - 300.0).abs() <= VELOCITY_TOLERANCE_RPM, "{what}: {name} = {shown}");
        }
        let moved = get_i32(&sim, h::POSITION_ACTUAL_VALUE) - start;
        assert!(moved * position_sign > 4096, "{what}: 0x6064 moved {moved} inc");
    }
}

/// CSP without interpolation (0x60C2 = 0): the master moves 0x607A by +4 inc per set-point (one per slow tick,
/// 146 rpm) for 1,024 set-points, then holds. With 0x607E = 0x80 the motor turns -4,096 inc and 0x6064 ends on
/// the last target; with 0 it turns +4,096.
#[test]
fn csp_set_points_follow_bit_7() {
    for (polarity, motor_sign) in [(0x00_u8, 1_i64), (0x80, -1)] {
        let mut sim = enabled_with(polarity, 8);
        sim.drive.dictionary_mut().set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
        let start = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
        let start_count = sim.plant.true_encoder_count();
        for k in 1..=1_274_i64 {
            let target = start + 4 * k.min(1_024);
            sim.drive.dictionary_mut().set(h::TARGET_POSITION, i32::try_from(target).expect("in range"));
            sim.setpoint_received();
            sim.run_slow_ticks(1);
        }
        let what = format!("0x607E = {polarity:#04x}");
        assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - (start + 4096)).abs() <= POSITION_WINDOW_INC, "{what}");
        let moved = sim.plant.true_encoder_count() - start_count;
        assert!((moved - motor_sign * 4096).abs() <= POSITION_WINDOW_INC, "{what}: the motor moved {moved} inc");
    }
}

/// With 0x607E = 0x80, home offset 0x607C and the software limits 0x607D are the master's positions too:
/// homing method 37 (the actual position is home, IDX) makes 0x6064 read the home offset, 1,000 (within 2 inc:
/// the axis holding after the homing; measured 0); then a PPM target of 8,000 beyond 0x607D:02 = 3,000 is clamped to 3,000
/// (0x6064 ends there, the motor moves 2,000 inc backwards), and 0x607D:01 = -2,000 keeps its meaning too
/// (a target of -9,000 ends at -2,000: the motor moves 5,000 inc forwards).
#[test]
fn home_offset_and_software_limits_follow_bit_7() {
    let mut sim = enabled_with(0x80, 6);
    home_here(&mut sim, 1_000);
    assert!((get_i32(&sim, h::POSITION_ACTUAL_VALUE) - 1_000).abs() <= 2, "0x6064 reads the home offset");
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::SOFTWARE_POSITION_LIMIT_MIN, -2_000);
        d.set(h::SOFTWARE_POSITION_LIMIT_MAX, 3_000);
    }
    sim.set_controlword(ENABLE_OPERATION);
    sim.set_mode(1);
    sim.run_slow_ticks(10);
    for (target, end, motor_moves) in [(8_000_i64, 3_000_i64, -2_000_i64), (-9_000, -2_000, 5_000)] {
        let start_count = sim.plant.true_encoder_count();
        ppm_move(&mut sim, target, 5000);
        let position = get_i32(&sim, h::POSITION_ACTUAL_VALUE);
        assert!((position - end).abs() <= POSITION_WINDOW_INC, "target {target}: 0x6064 = {position}");
        let moved = sim.plant.true_encoder_count() - start_count;
        assert!((moved - motor_moves).abs() <= POSITION_WINDOW_INC, "target {target}: the motor moved {moved}");
    }
}

/// The object's rules: 0x00, 0x40, 0x80 and 0xC0 are accepted with the power stage off; any other bit aborts
/// with 0x0609_0030 (CiA 301 "invalid value"); a write with the power stage on aborts with 0x0800_0022 (device
/// state), so no value changes sign while the loops run; 0x1010 saves it and the next boot restores it. IDX's
/// own inversion, 0x3000:04 bit 0, stays refused with 0x0609_0030 (device.toml gives the reason).
#[test]
fn polarity_is_written_with_the_power_stage_off_and_saved() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut drive = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    for value in [0x00_u8, 0x40, 0x80, 0xC0] {
        drive.sdo_write(0x607E, 0, &[value], PRE_OP, &mut store).expect("accepted");
        assert_eq!(drive.dictionary().get(h::POLARITY), value);
    }
    for value in [0x01_u8, 0x20, 0x3F, 0xFF] {
        assert_eq!(
            drive.sdo_write(0x607E, 0, &[value], PRE_OP, &mut store),
            Err(SdoAbort::InvalidValue),
            "{value:#04x}"
        );
    }
    let enabled = AccessContext { power_stage_enabled: true, ..PRE_OP };
    assert_eq!(drive.sdo_write(0x607E, 0, &[0x00], enabled, &mut store), Err(SdoAbort::DeviceState));
    assert_eq!(drive.dictionary().get(h::POLARITY), 0xC0, "refused writes change nothing");
    assert_eq!(drive.sdo_write(0x3000, 4, &1_u32.to_le_bytes(), PRE_OP, &mut store), Err(SdoAbort::InvalidValue));
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let rebooted = Drive::boot(DriveConfig::DEFAULT, &mut store).0;
    assert_eq!(rebooted.dictionary().get(h::POLARITY), 0xC0, "restored at boot");
}

/// `firmware::motion::polarity` (issue 20 item 3): the torque offset 0x60B2 takes bit 7 where it is CSP's torque
/// feedforward, as the velocity offset 0x60B1 does there (the position command's acceleration feed-forward). On the
/// locked rotor holding its position in CSP (0x607A = 0x6064 every 1 ms, so the position error and the integral
/// stay put), 0x60B2 = 200 per mille moves the q reference by +640 mA (200 per mille of 3.2 A, exact in I16F16
/// bits) with 0x607E = 0 and 0x40 (bit 6 is not CSP's bit), by -640 mA with 0x80 and 0xC0.
#[test]
fn torque_offset_in_csp_follows_bit_7() {
    use firmware::control::demand::DemandScale;
    let expected = DemandScale::reference().torque_to_current(200, 0).1.to_bits();
    for (polarity, sign) in [(0x00u8, 1), (0x40, 1), (0x80, -1), (0xC0, -1)] {
        let mut sim = enabled_with(polarity, 8);
        sim.plant.lock_rotor(true);
        let cycles = |sim: &mut Simulation, n: usize| {
            for _ in 0..n {
                let held = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
                sim.drive.dictionary_mut().set(h::TARGET_POSITION, held);
                sim.setpoint_received();
                sim.run(25);
            }
        };
        cycles(&mut sim, 20);
        let before = sim.tier1().signals().i_ref.q.to_bits();
        sim.drive.dictionary_mut().set(h::TORQUE_OFFSET, 200i16);
        cycles(&mut sim, 5);
        let after = sim.tier1().signals().i_ref.q.to_bits();
        assert_eq!(after - before, sign * expected, "0x607E = {polarity:#04x}: {} 640 mA", sign * 640);
    }
}
