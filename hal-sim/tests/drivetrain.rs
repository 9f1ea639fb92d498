//! The drivetrain of the plant (issue 18 item 1): gear ratio, backlash, the two-mass coupling and the load encoder,
//! simulated with the outputs off (the plant alone, no drive).

use core::f64::consts::PI;
use std::path::PathBuf;

use firmware::hal::power::PwmCommand;
use hal_sim::plant::sensors::encoder_count;
use hal_sim::plant::{Mechanics, Plant, PlantParams, PERIOD_S};

fn geared_36v() -> PlantParams {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("presets/geared-36v.toml");
    PlantParams::from_toml_file(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Reference plant without friction (motor and load), direct drive unless changed.
fn frictionless(p: PlantParams) -> PlantParams {
    PlantParams { coulomb_friction_nm: 0.0, viscous_friction_nm_s_rad: 0.0, load_coulomb_friction_nm: 0.0, ..p }
}

fn run(plant: &mut Plant, periods: u64) {
    for _ in 0..periods {
        plant.step(&PwmCommand::OFF);
    }
}

/// The free oscillation of the geared-36v coupling (both masses free, outputs off, the load released 0.01 rad
/// ahead of the motor's output) rings at the two-mass resonance, 60 Hz by the preset's design. The coupling alone is
/// measured: backlash, frictions and the gear's losses removed (each changes the response, none is the spring).
/// The frequency comes from the zero crossings of the twist over 0.25 s (15 cycles); tolerance 1 % (0.6 Hz): the
/// 5 % damping lowers the ringing by 0.13 %, the crossings' interpolation at 25 kHz is good to well below that.
#[test]
fn geared_36v_coupling_rings_at_its_60_hz_two_mass_resonance() {
    let p = PlantParams { gear_backlash_deg: 0.0, gear_efficiency: 1.0, ..frictionless(geared_36v()) };
    let ratio = p.gear_ratio;
    let mut plant = Plant::new(p, 1);
    plant.set_rotor_state(0.0, 0.0);
    plant.set_load_state(0.01, 0.0);
    let mut crossings = Vec::new();
    let mut last_twist = f64::NAN;
    for k in 0..(0.25 / PERIOD_S) as u64 {
        plant.step(&PwmCommand::OFF);
        let s = plant.state();
        let twist = s.theta_m_rad / ratio - s.load_angle_rad;
        if last_twist.is_finite() && (last_twist < 0.0) != (twist < 0.0) {
            let frac = last_twist / (last_twist - twist);
            crossings.push((k as f64 - 1.0 + frac) * PERIOD_S);
        }
        last_twist = twist;
    }
    assert!(crossings.len() >= 20, "{} crossings", crossings.len());
    let (first, last) = (crossings[0], crossings[crossings.len() - 1]);
    let f_hz = (crossings.len() - 1) as f64 / (2.0 * (last - first));
    assert!((f_hz - 60.0).abs() <= 0.6, "free two-mass resonance {f_hz:.3} Hz, expected 60 Hz +- 1 %");
}

/// Backlash: the motor's output turns through the dead band (the preset's 0.3 deg, starting in its middle) at a
/// constant speed; the load, held by nothing but its own friction, does not move until the output reaches the far
/// flank (0.15 deg): within 1e-12 rad, i.e. not at all. Past the flank it follows.
#[test]
fn backlash_leaves_the_load_still_while_the_motor_crosses_the_dead_band() {
    let p = geared_36v();
    let (ratio, half_gap) = (p.gear_ratio, 0.5 * p.gear_backlash_deg.to_radians());
    let mut plant = Plant::new(p, 1);
    plant.set_rotor_state(0.0, 0.0);
    let output_speed = 0.05; // rad/s at the output: the half gap (2.6 mrad) takes 52 ms
    plant.set_mechanics(Mechanics::Driven { speed_rad_s: output_speed * ratio });
    let mut in_band_periods = 0;
    for _ in 0..(0.2 / PERIOD_S) as u64 {
        plant.step(&PwmCommand::OFF);
        let s = plant.state();
        if s.theta_m_rad / ratio < 0.95 * half_gap {
            in_band_periods += 1;
            assert!(s.load_angle_rad.abs() < 1e-12, "load moved {} rad inside the dead band", s.load_angle_rad);
        }
    }
    assert!(in_band_periods > 1000, "the dead band lasted {in_band_periods} periods");
    let s = plant.state();
    let output = s.theta_m_rad / ratio;
    assert!(s.load_angle_rad > 0.5 * (output - half_gap), "past the flank the load follows: {} rad", s.load_angle_rad);
}

/// Rigid gear: the load turns `1 / ratio` of the motor (exactly: it is set from the motor), and the motor sees the
/// load inertia over `ratio^2` and the output's load torque over `ratio`. Reference plant without friction, 4:1,
/// coasting from 1,000 rpm against 0.01 N m at the output for 0.2 s (to 9 rad/s, still turning forward, the
/// back-EMF below the bus so no diode conducts): the speed falls by `T / (N J)` t with `J = J_rotor + J_load / 16`
/// (tolerance 1e-6 relative: RK4 on a constant deceleration is exact to rounding).
#[test]
fn rigid_gear_turns_the_load_by_the_motor_turns_over_the_ratio() {
    let p = PlantParams { gear_ratio: 4.0, ..frictionless(PlantParams::reference()) };
    let j = p.rotor_inertia_kg_m2 + p.load_inertia_kg_m2 / 16.0;
    assert_eq!(p.total_inertia_kg_m2(), j);
    let mut plant = Plant::new(p, 1);
    let w0 = PlantParams::rpm_to_rad_s(1000.0);
    plant.set_rotor_state(0.0, w0);
    plant.set_load_torque(0.01);
    let t = 0.2;
    run(&mut plant, (t / PERIOD_S).round() as u64);
    let s = plant.state();
    assert_eq!(s.load_angle_rad, s.theta_m_rad / 4.0);
    assert_eq!(s.load_speed_rad_s, s.omega_m_rad_s / 4.0);
    let expected = w0 - 0.01 / 4.0 / j * t;
    assert!(expected > 0.0);
    assert!((s.omega_m_rad_s - expected).abs() < 1e-6 * w0, "{} rad/s, expected {expected}", s.omega_m_rad_s);
    assert!(s.theta_m_rad / (2.0 * PI) > 1.0, "the motor turned {} turns", s.theta_m_rad / (2.0 * PI));
}

/// The load encoder counts the load's angle at its own resolution: rigid 5:1, 4,096 counts per output turn, the
/// motor driven 2.5 turns gives half an output turn = 2,048 counts (the floor of the true angle: 2,047 or 2,048);
/// on the compliant geared-36v the count is that of the load's (integrated) angle, not the motor's over the ratio.
/// Without one fitted there is none.
#[test]
fn load_encoder_counts_follow_the_load() {
    let p = PlantParams { gear_ratio: 5.0, load_encoder_counts_per_rev: 4096, ..PlantParams::reference() };
    let mut plant = Plant::new(p, 1);
    let motor_speed = 2.0 * PI * 10.0; // 10 turns/s: 2.5 turns in 0.25 s
    plant.set_mechanics(Mechanics::Driven { speed_rad_s: motor_speed });
    run(&mut plant, (0.25 / PERIOD_S).round() as u64);
    let count = plant.load_encoder_count().expect("a load encoder is fitted");
    assert!((2047..=2048).contains(&count), "load count {count}");

    let p = PlantParams { load_encoder_counts_per_rev: 20_000, ..geared_36v() };
    let mut plant = Plant::new(p, 1);
    plant.set_mechanics(Mechanics::Driven { speed_rad_s: 50.0 });
    run(&mut plant, 5000);
    let s = plant.state();
    assert_eq!(plant.load_encoder_count(), Some(encoder_count(s.load_angle_rad, 20_000, 0)));
    let geared_count = encoder_count(s.theta_m_rad / 5.0, 20_000, 0);
    assert_ne!(plant.load_encoder_count(), Some(geared_count), "the coupling twists and the backlash lags");

    assert_eq!(Plant::new(PlantParams::reference(), 1).load_encoder_count(), None);
}
