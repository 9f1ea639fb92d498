//! The mechanical step of the motor identification (`firmware::drive::mechanical_identification`, issue 18 item
//! 3) through the real plant: the drive commissioned on a preset of `hal-sim/presets/` with its known commutation
//! (the scenarios' commissioning run finds the index), the step's q-current demand through target torque 0x6071
//! each slow tick, its samples from what tier 1 measured and applied (averaged over the slow tick's ten periods)
//! and the position actual value 0x6064. The procedure that calls the step in operation mode -2 is another
//! module's; this test checks the step's figures against the plant's true values at the motor shaft (total
//! inertia: rotor + load / ratio^2; Coulomb friction: motor + load / ratio).
//!
//! Tolerances are the (kt 3 %, total inertia 5 % rigid, 10 % elastic); measured at this commit: reference
//! kt -0.75 %, inertia -0.74 %; small gimbal +0.71 %, +2.24 %; geared -0.44 %, +3.92 % (the relay lowered to
//! 230 rpm there: without a chopper the 36 V bus cannot take the braking energy from 1,000 rpm). Each run also
//! has to stay below the max system speed and within 5 s of the procedure's 20 s.

use std::path::Path;

use firmware::control::frames::{Amps, Volts};
use firmware::drive::mechanical_identification::{
    MechanicalConfig, MechanicalIdentification, MechanicalResult, MechanicalSample, MechanicalStatus,
};
use firmware::od::generated::handles as h;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::{self, Setup};

const PERIODS_PER_SLOW_TICK: usize = 10;

/// The plant's true values at the motor shaft: kt (Nm/A), total inertia (kg m^2), Coulomb friction (Nm).
fn truth(p: &PlantParams) -> (f64, f64, f64) {
    let ratio = p.gear_ratio;
    (
        p.torque_constant_nm_per_a(),
        p.rotor_inertia_kg_m2 + p.load_inertia_kg_m2 / (ratio * ratio),
        p.coulomb_friction_nm + p.load_coulomb_friction_nm / ratio,
    )
}

fn preset(name: &str) -> PlantParams {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../hal-sim/presets").join(name);
    PlantParams::from_toml_file(&path).expect("preset")
}

/// Runs the step on `params` with the motor's nominal current as its limit; the result, the simulated seconds
/// and the highest plant speed (rpm).
fn identify(params: &PlantParams) -> (MechanicalResult, f64, f64) {
    let (mut sim, prepared) = scenarios::prepare_plant(params.clone(), &Setup::default()).expect("commissioned");
    assert!(prepared.angle_error_deg.abs() < 5.0, "commutation known: {prepared:?}");
    // Let the commissioning run's motion stop (q current zero, friction).
    sim.run(12_500);
    let config = MechanicalConfig {
        current_limit: Amps::from_milliamps((params.nominal_current_a * 1000.0).round() as i32),
        max_speed_rpm: params.max_speed_rpm.round() as u32,
        counts_per_rev: params.encoder_counts_per_rev,
        pole_pairs: params.pole_pairs as u8,
        phase_resistance_milliohm: (params.phase_resistance_ohm * 1000.0).round() as u32,
        timeout_ticks: 12_500,
        regeneration_limit: Volts::from_millivolts(
            i32::try_from(sim.drive.dictionary().get(h::BUS_LIMITER_LOSS_BRAKING_VOLTAGE)).unwrap_or(i32::MAX),
        ),
    };
    let mut id = MechanicalIdentification::new(&config);
    let start = sim.time_s();
    let mut max_rpm: f64 = 0.0;
    loop {
        let (mut i_q, mut v_q) = (0i64, 0i64);
        for _ in 0..PERIODS_PER_SLOW_TICK {
            sim.step();
            let signals = sim.tier1().report().signals;
            i_q += i64::from(signals.i_dq.q.to_bits());
            v_q += i64::from(signals.v_dq.q.to_bits());
            max_rpm = max_rpm.max(sim.plant.state_at_sample().speed_rpm.abs());
        }
        let n = PERIODS_PER_SLOW_TICK as i64;
        let sample = MechanicalSample {
            position: sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE),
            i_q: Amps::from_bits((i_q / n) as i32),
            v_q: Volts::from_bits((v_q / n) as i32),
            v_bus: sim.drive.signals().v_bus,
        };
        match id.step(&sample) {
            MechanicalStatus::Running { i_q_demand } => sim.set_q_reference(f64::from(i_q_demand.to_milliamps()) / 1e3),
            MechanicalStatus::Done(result) => {
                sim.set_q_reference(0.0);
                return (result, sim.time_s() - start, max_rpm);
            }
            MechanicalStatus::Failed(error) => panic!(
                "identification failed: {error:?} ({:#06X}) at {:.3} s, progress {}, {sample:?}",
                error.code(),
                sim.time_s() - start,
                id.progress_per_mille()
            ),
        }
    }
}

fn error_pct(measured: f64, truth: f64) -> f64 {
    (measured - truth) / truth * 100.0
}

/// kt, inertia and Coulomb friction errors in percent, printed with the run's figures.
fn errors(name: &str) -> [f64; 3] {
    let params = preset(name);
    let (kt, inertia, coulomb) = truth(&params);
    let (r, seconds, max_rpm) = identify(&params);
    let e = [
        error_pct(f64::from(r.torque_constant) * 1e-6, kt),
        error_pct(f64::from(r.inertia) * 1e-10, inertia),
        error_pct(f64::from(r.coulomb_friction) * 1e-6, coulomb),
    ];
    println!(
        "{name}: kt_error_pct={:.2} inertia_error_pct={:.2} coulomb_error_pct={:.1} identify_s={seconds:.2} \
         max_rpm={max_rpm:.0} {r:?}",
        e[0], e[1], e[2]
    );
    assert!(seconds < 5.0, "{name}: {seconds} s of the procedure's 20 s");
    assert!(max_rpm < params.max_speed_rpm, "{name}: {max_rpm} rpm above the max system speed");
    e
}

/// Reference plant (`reference.toml`, rigid, 176 g cm^2, kt 0.0335 Nm/A): kt within 3 % and inertia within 5 %
/// (issue 18 "What it must show"). The plant has what the unit tests' model leaves out: the inverter's dead time
/// and diode drops, PWM delay, shunt noise and offsets, the current loop's own dynamics.
#[test]
fn reference_plant_kt_within_3_pct_inertia_within_5_pct() {
    let e = errors("reference.toml");
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
}

/// Small gimbal motor (`small-gimbal.toml`: rigid, 10 g cm^2, kt 0.05 Nm/A, 16,384 counts, 12 V): kt within 3 %,
/// inertia within 5 % (issue 18).
#[test]
fn small_gimbal_kt_within_3_pct_inertia_within_5_pct() {
    let e = errors("small-gimbal.toml");
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
}

/// Geared axis (`geared-36v.toml`: 5:1 gear with 0.3 deg backlash, 60 Hz coupling, 3,200 g cm^2 in all at the
/// motor, kt 0.1 Nm/A, 5,000 counts): kt within 3 %, total inertia within 10 % (issue 18, elastic).
#[test]
fn geared_axis_kt_within_3_pct_total_inertia_within_10_pct() {
    let e = errors("geared-36v.toml");
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 10.0, "inertia error {} %", e[1]);
}
