//! A coarse encoder on a slow, high-resistance motor (the closed-loop stepper class): 24 V, 3 pole pairs,
//! R 8 ohm, L 6 mH, kt 0.15 Nm/A, 500 g cm^2, 10 mNm of friction, 0.8 / 2 A, 1,000 rpm, and a 256-line encoder
//! (1,024 counts/rev). One count per slow tick is 146 rpm, 4.6 times the CSV step of 32 rpm
//! (`motion::csv_step_rpm`: 100 rpm x the acceleration capability, 0.315 of the reference's): the velocity
//! estimate moves in steps, and a loop whose P gain turns one of them into more than the nominal current
//! limit-cycles on them (`firmware::drive::tuning`, "Velocity loop", coarse encoder).
//!
//! Tolerances: the issue's (CSV overshoot 15 %, CSP peak 3 degrees = 8.5 increments, +-1 after the move). "No
//! sustained oscillation": the true speed's RMS about its straight-line fit over the step's last 200 ms (the
//! softer loop still rises there) at most 10 % of the step: measured 0.52 and 0.54 rpm of 32 (overshoot 0 %, 7 %
//! short after 300 ms; the speed sampled every slow tick moves with the encoder's counts); before the
//! coarse-encoder cap the then 20 rpm step limit-cycled at 4.33 rpm RMS.

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::identification::{self, Outcome, ISSUE_BOUNDS_RIGID_PCT};
use hal_sim::scenarios::{self, motion};

/// The motor of the module documentation.
fn stepper_class() -> PlantParams {
    PlantParams {
        source_voltage_v: 24.0,
        pole_pairs: 3,
        phase_resistance_ohm: 8.0,
        ld_h: 0.006,
        lq_h: 0.006,
        flux_linkage_wb: 0.15 / 4.5,
        rotor_inertia_kg_m2: 5.0e-5,
        load_inertia_kg_m2: 0.0,
        coulomb_friction_nm: 0.01,
        viscous_friction_nm_s_rad: 1.0e-5,
        nominal_current_a: 0.8,
        peak_current_a: 2.0,
        max_speed_rpm: 1000.0,
        winding_to_housing_k_per_w: 2.6,
        housing_to_ambient_k_per_w: 10.4,
        encoder_counts_per_rev: 1024,
        ..PlantParams::reference()
    }
}

fn on_auto_tuned<R>(plant: &PlantParams, seed: u64, f: impl FnOnce() -> R) -> R {
    let run = identification::identify(plant, seed, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished (seed {seed})");
    scenarios::with_plant(plant.clone(), || scenarios::with_parameters(run.parameters, f))
}

/// The CSV step (seeds 1 and 2) overshoots at most 15 % and does not oscillate (module documentation); the CSP
/// move stays within 3 degrees and ends within +-1 increment.
#[test]
fn a_256_line_encoder_gives_a_velocity_step_without_a_limit_cycle() {
    let plant = stepper_class();
    for seed in [1, 2] {
        let (step, ripple, csp) = on_auto_tuned(&plant, seed, || {
            let (step, trace) = motion::csv_step(seed, motion::csv_step_rpm()).expect("csv step");
            let speed = trace.column("speed_rpm").expect("speed column");
            let time = trace.column("t_s").expect("time column");
            let from = speed.len() / 3;
            let (t, v) = (time.get(from..).expect("samples"), speed.get(from..).expect("samples"));
            let n = t.len() as f64;
            let (mt, mv) = (t.iter().sum::<f64>() / n, v.iter().sum::<f64>() / n);
            let slope = t.iter().zip(v).map(|(a, b)| (a - mt) * (b - mv)).sum::<f64>()
                / t.iter().map(|a| (a - mt) * (a - mt)).sum::<f64>();
            let residual = t.iter().zip(v).map(|(a, b)| b - (mv + slope * (a - mt)));
            let ripple = (residual.map(|r| r * r).sum::<f64>() / n).sqrt();
            let csp = motion::csp(&motion::CspConfig::scaled_to_current_plant(seed)).expect("csp").0;
            (step, ripple, csp)
        });
        assert!(step.overshoot_pct <= 15.0, "seed {seed}: {step:?}");
        assert!(ripple <= 0.1 * step.step_rpm, "seed {seed}: ripple {ripple} rpm on {} rpm", step.step_rpm);
        assert!(csp.following_error_peak_inc <= 3.0 / 360.0 * 1024.0, "seed {seed}: {csp:?}");
        assert!(csp.settle_error_inc <= 1.0, "seed {seed}: {csp:?}");
    }
}

/// The identification on this motor (seed 1) within the issue's bounds: R, Lq and kt within 3 %, Ld within 5 %,
/// the inertia within 5 % (rigid). Two things broke them here before: the torque-constant fit over single ticks
/// took the 1,024-count increments' quantization (kt -4.75 %, inertia -4.28 %), and the inductance step's square
/// wave (18 V for its current step, against 13.9 V of linear range at 24 V) was clipped on d where the bias adds
/// (Lq -16.05 %). Measured now: R +0.11 %, Ld -0.13 %, Lq -0.37 %, kt -0.31 %, inertia within 2 %.
#[test]
fn the_stepper_class_motor_identifies_within_the_issue_bounds() {
    let plant = stepper_class();
    let run = identification::identify(&plant, 1, |_| {});
    assert_eq!(run.outcome, Outcome::Done);
    let outside = run.errors_outside(&plant, ISSUE_BOUNDS_RIGID_PCT);
    assert!(outside.is_empty(), "{}", outside.join(", "));
}
