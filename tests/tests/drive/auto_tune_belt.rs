//! Open (run with `--ignored`): the auto-tuned CSP on a light motor driving its load through a lightly damped belt.
//!
//! The plant: the reference motor (kt 0.0335 Nm/A, rotor 44 g cm^2, 4,096 counts/rev, 24 V) on a 3:1 belt to a
//! load of 10 times its reflected rotor inertia, the belt's stiffness putting the free two-mass resonance at 80 Hz
//! (anti-resonance 24.1 Hz), 5 % damping, 20 mNm of load friction. The identification gets it right (seed 1: kt
//! -1.7 %, inertia -2.0 %, resonance 82.7 Hz, anti-resonance 24.1 Hz), but the position PID the auto-tuning
//! designs from it (`firmware::drive::tuning`, "Position loop": `Kp` crossing over at 1.4 times the
//! anti-resonance on the whole inertia) rings at the current limit: `drive-sim csp --auto-tune` on this plant
//! written as a file gives a following-error peak of 1,712 to 1,745 increments and 341 to 349 left after the move
//! (seeds 1 to 3; the issue's bounds are 3 degrees = 34 increments and +-1).
//!
//! What was measured (none of it on `main`):
//! - The design's `Kp` puts the proportional crossover on the motor's own inertia at 1.4 times the resonance; with
//!   `Kd`'s fixed 390.61 rad/s filter and the 2.5 kHz loop's delay that loop has no phase left above the resonance.
//!   On the geared-36v preset the same design holds only through its friction: with half of it the CSP peaks at
//!   40 to 47 increments and leaves 10; with none, 142 and 23.
//! - A sweep of this belt's family (resonance 40 to 120 Hz, load 3 to 20 times, damping 2 to 15 %) with `Kp`
//!   set by hand: on this motor a damping of 5 % or less above 60 Hz needs the proportional crossover on the
//!   motor's own inertia under about 350 rad/s (`Kp` 15 A/rad here: peak 16, settle 0).
//! - Capping `Kp` so that the PD on the motor's own inertia keeps a damping of 0.9 cures the family at 15 %
//!   damping (80 to 120 Hz: from 471 to 1,456 increments of peak to 4 to 21) and leaves geared-36v unchanged,
//!   but not 2 or 5 % (this belt: 440 to 462 / 207 to 220). Its 84 bytes did not fit in the EtherCAT + defmt
//!   image's flash budget in this stop.
//! - A notch on the PID's current demand at the identified resonance (Q 1.5) makes this belt settle (peak 9 to 10,
//!   settle 0 to 1, also at 60 and 120 Hz with 2 %), but takes the phase geared-36v's loop needs at its crossover:
//!   its peak rose from 18 to 91 and 199 increments (Q 3: 42 / 26 on seed 1).
//!
//! A design that holds on both needs the loop's phase near and above the resonance, not only `Kp`: a notch with a
//! `Kp` rule that does not lean on friction, or a velocity-loop cascade for elastic loads.

use hal_sim::plant::PlantParams;
use hal_sim::scenarios::identification::{self, Outcome};
use hal_sim::scenarios::{self, motion};

/// The reference motor on the belt described in the module documentation, with the coupling's damping ratio
/// `zeta`.
fn belt(zeta: f64) -> PlantParams {
    let r = PlantParams::reference();
    let n = 3.0;
    let rotor_at_output = r.rotor_inertia_kg_m2 * n * n;
    let load = 10.0 * rotor_at_output;
    let compliance = 1.0 / load + 1.0 / rotor_at_output;
    let w_r = std::f64::consts::TAU * 80.0;
    PlantParams {
        gear_ratio: n,
        gear_efficiency: 0.95,
        load_inertia_kg_m2: load,
        coupling_stiffness_nm_per_rad: w_r * w_r / compliance,
        coupling_damping_nm_s_per_rad: 2.0 * zeta * w_r / compliance,
        load_coulomb_friction_nm: 0.02,
        ..r
    }
}

/// Issue 18's CSP figures after `--auto-tune` on the 5 %-damped belt, seeds 1 to 3: following error peak at most
/// 3 degrees of the motor shaft (34.1 increments of 4,096) and within +-1 increment 20 ms after the move.
#[test]
#[ignore = "open: the auto-tuned position PID rings on a lightly damped 80 Hz belt (module documentation)"]
fn auto_tuned_csp_on_a_lightly_damped_belt_meets_the_issue_figures() {
    let plant = belt(0.05);
    for seed in 1..=3 {
        let run = identification::identify(&plant, seed, |_| {});
        assert_eq!(run.outcome, Outcome::Done, "seed {seed}");
        let csp = scenarios::with_plant(plant.clone(), || {
            scenarios::with_parameters(run.parameters, || {
                motion::csp(&motion::CspConfig::scaled_to_current_plant(seed)).expect("csp").0
            })
        });
        assert!(csp.following_error_peak_inc <= 3.0 / 360.0 * 4096.0, "seed {seed}: {csp:?}");
        assert!(csp.settle_error_inc <= 1.0, "seed {seed}: {csp:?}");
    }
}
