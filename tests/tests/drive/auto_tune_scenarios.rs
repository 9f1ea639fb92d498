//! `drive-sim --auto-tune` on the reference plant: the identification with its auto-tuning (0x6060 = -2) run by a
//! master, its parameters written into the scenarios' drives (`scenarios::with_parameters`), against the hand-tuned
//! defaults (issue 18 "What it must show": the reference's figures with `--auto-tune` are no worse than with the
//! defaults by more than 10 %); and on the small-gimbal preset against the issue's own figures.
//!
//! Tolerance of each comparison: 10 % of the default's figure (the issue's), plus the figure's own resolution,
//! because the defaults' figures are small numbers a single quantum moves by more than 10 %: 0.1 percentage point
//! of overshoot (the current step's overshoot is 0.6 %, one 8 mA ADC step of a 2 A step is 0.4 %), one increment
//! of following error (the encoder's), 2 us of rise time (the 25 kHz sample's 40 us interpolated).
//!
//! The small gimbal (`hal-sim/presets/small-gimbal.toml`: 1.5 A peak, 10 g cm^2, 16,384 counts/rev) runs on the
//! reference power stage, whose current sensing (8 mA per ADC step, 2 LSB = 16 mA rms of noise per sample) is
//! coarse for it: at low frequency the current loop makes the measured current follow its reference, so the true
//! current carries the measurement's noise, and on 1e-6 kg m^2 with kt 0.05 Nm/A (kt / J 26 times the
//! reference's) that is a speed ripple of about 1.8 rpm RMS. `drive-sim csv-sweep`'s step on it is 394 rpm
//! (`motion::csv_step_rpm`: the reference's 100 rpm scaled by the acceleration capability, so that it asks the same
//! share of the peak current); a step scaled by the maximum speed alone (24 rpm) would measure that ripple, not
//! the loop. The CSP move's +-1 increment settle holds on the preset itself: the motor's 0.6 mNm of Coulomb
//! friction (12 mA) is met by the position PID's friction feedforward (0x30A1:06, `firmware::control::position`),
//! which the auto-tuning sets from the identified friction.

use hal_sim::plant::PlantParams;
use std::path::Path;

use hal_sim::scenarios::identification::{self, Outcome};
use hal_sim::scenarios::{self, motion, PlantScale, Setup, SWEEP_FREQUENCIES_HZ};

/// The parameters the identification and its auto-tuning leave on the reference plant.
fn auto_tuned() -> identification::Parameters {
    let run = identification::identify(&PlantParams::reference(), 1, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished");
    run.parameters
}

fn no_worse(name: &str, tuned: f64, default: f64, quantum: f64) {
    assert!(
        tuned <= default * 1.1 + quantum,
        "{name}: auto-tuned {tuned} against the defaults' {default} (+10 % + {quantum})"
    );
}

/// The current step (2 A, rotor locked): overshoot and rise time; the velocity step (100 rpm, CSV): overshoot;
/// CSP (10 revolutions up to 3,000 rpm): peak following error and the error 20 ms after the last set-point.
#[test]
fn auto_tuned_reference_is_no_worse_than_the_hand_tuned_defaults_by_10_percent() {
    let figures = || {
        let step = scenarios::current_step(&Setup::default(), 2.0).expect("current step").figures;
        let (velocity, _) = motion::csv_step(1, 100.0).expect("csv step");
        let (csp, _) = motion::csp(&motion::CspConfig::default()).expect("csp");
        (step, velocity, csp)
    };
    let (step_d, velocity_d, csp_d) = figures();
    let parameters = auto_tuned();
    assert!(parameters.values.len() == identification::IDENTIFIED_OBJECTS.len(), "every object read back");
    let (step_t, velocity_t, csp_t) = scenarios::with_parameters(parameters, figures);
    no_worse("current-step overshoot %", step_t.overshoot_pct, step_d.overshoot_pct, 0.1);
    no_worse("current-step rise us", step_t.rise_us, step_d.rise_us, 2.0);
    // The velocity step's overshoot, on one run, moves by more than 10 % with changes far below the loop's (over
    // seeds 1..4 the defaults give 5.2 to 6.1 %): compared as the mean over four seeds (plant noise and the
    // identification's own run both change with the seed).
    let mean_overshoot = |auto_tune: bool| {
        let runs = (1..=4u64).map(|seed| {
            let run = || motion::csv_step(seed, 100.0).expect("csv step").0.overshoot_pct;
            match auto_tune {
                true => {
                    let tuned = identification::identify(&PlantParams::reference(), seed, |_| {});
                    assert_eq!(tuned.outcome, Outcome::Done, "identification finished (seed {seed})");
                    scenarios::with_parameters(tuned.parameters, run)
                }
                false => run(),
            }
        });
        runs.sum::<f64>() / 4.0
    };
    let (default_mean, tuned_mean) = (mean_overshoot(false), mean_overshoot(true));
    no_worse("csv step overshoot %, mean of seeds 1..4", tuned_mean, default_mean, 0.1);
    assert!(
        velocity_t.overshoot_pct <= 15.0,
        "csv step overshoot {} % (issue: <= 15 %; the defaults' {} %)",
        velocity_t.overshoot_pct,
        velocity_d.overshoot_pct
    );
    no_worse("csp following error peak inc", csp_t.following_error_peak_inc, csp_d.following_error_peak_inc, 1.0);
    no_worse("csp settle error inc", csp_t.settle_error_inc, csp_d.settle_error_inc, 1.0);
}

/// The parameters reach the scenario's drive: the current gains it runs with are the tuned ones, not the
/// defaults (so the comparison above compares two tunings).
#[test]
fn auto_tuned_parameters_are_the_ones_the_scenario_drive_runs_with() {
    let parameters = auto_tuned();
    let written = |index: u16, sub: u8| {
        parameters
            .values
            .iter()
            .find(|(i, s, _)| (*i, *s) == (index, sub))
            .map(|(_, _, d)| d.iter().rev().fold(0u32, |v, b| v << 8 | u32::from(*b)))
            .expect("read back")
    };
    let p = written(0x30A0, 1);
    assert_ne!(p, 1_555_000, "the tuning computed its own current P gain");
    let (sim, _) =
        scenarios::with_parameters(parameters.clone(), || scenarios::prepare(&Setup::default())).expect("prepared");
    use firmware::od::generated::handles as h;
    assert_eq!(sim.drive.dictionary().get(h::CURRENT_CONTROLLER_P_GAIN), p);
    assert_eq!(sim.drive.dictionary().get(h::OBSERVER_INERTIA), written(0x30A3, 5));
}

/// `hal-sim/presets/small-gimbal.toml`.
fn small_gimbal() -> PlantParams {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../hal-sim/presets/small-gimbal.toml");
    PlantParams::from_toml_file(&path).expect("preset")
}

/// The small gimbal without the shunts' noise (`shunt_noise_lsb_rms` = 0; the ADC's 8 mA step stays).
fn small_gimbal_without_shunt_noise() -> PlantParams {
    PlantParams { shunt_noise_lsb_rms: 0.0, ..small_gimbal() }
}

/// Runs `f` on `plant` with the parameters its own identification and auto-tuning (seed `seed`) found, as
/// `drive-sim --plant FILE --auto-tune --seed N` does.
fn on_auto_tuned<R>(plant: &PlantParams, seed: u64, f: impl FnOnce() -> R) -> R {
    let run = identification::identify(plant, seed, |_| {});
    assert_eq!(run.outcome, Outcome::Done, "identification finished (seed {seed})");
    scenarios::with_plant(plant.clone(), || scenarios::with_parameters(run.parameters, f))
}

/// `drive-sim csv-sweep`'s velocity step on the scenario plant (`motion::csv_step_rpm`): the figures and the RMS of
/// the true speed about its mean over the last 200 ms, rpm.
fn velocity_step(seed: u64) -> (motion::VelocityStepFigures, f64) {
    let (figures, trace) = motion::csv_step(seed, motion::csv_step_rpm()).expect("csv step");
    let speed = trace.column("speed_rpm").expect("speed column");
    let tail = speed.get(speed.len() / 3..).expect("300 ms of samples");
    let mean = tail.iter().sum::<f64>() / tail.len() as f64;
    let ripple = (tail.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / tail.len() as f64).sqrt();
    (figures, ripple)
}

/// `drive-sim csp`'s move on the scenario plant (10 revolutions, 3,000 rpm, 20,000 rpm/s, scaled by its maximum
/// speed).
fn csp_move(seed: u64) -> motion::CspFigures {
    motion::csp(&motion::CspConfig::scaled_to_current_plant(seed)).expect("csp").0
}

/// Three degrees of the motor shaft in increments of the small gimbal's 16,384-count encoder: 136.5.
const THREE_DEGREES_INC: f64 = 3.0 / 360.0 * 16_384.0;

/// Issue 18 "What it must show", small gimbal after `--auto-tune` (seed 1): the current step (0.3 A, the 2 A step
/// scaled by the peak current) overshoots at most 10 % and the closed loop's -3 dB bandwidth (0.3 A + 0.15 A
/// sine) is at least 1.5 kHz, and the CSP move's following error peaks at most 3 degrees of the motor shaft. Tolerances: the bounds
/// (measured 4.7 %, 2,770 Hz, 17 increments).
#[test]
fn auto_tuned_small_gimbal_meets_the_current_loop_and_following_error_figures() {
    let plant = small_gimbal();
    let (step, bandwidth, csp) = on_auto_tuned(&plant, 1, || {
        let current = PlantScale::current_plant().current;
        let step = scenarios::current_step(&Setup::default(), 2.0 * current).expect("current step").figures;
        let sweep = scenarios::bandwidth(&Setup::default(), 2.0 * current, 1.0 * current, &SWEEP_FREQUENCIES_HZ)
            .expect("current sweep");
        (step, sweep.bandwidth_hz, csp_move(1))
    });
    assert!(step.overshoot_pct <= 10.0, "current-step overshoot {} % (issue: <= 10 %)", step.overshoot_pct);
    assert!(bandwidth >= 1500.0, "current-loop bandwidth {bandwidth} Hz (issue: >= 1.5 kHz)");
    assert!(
        csp.following_error_peak_inc <= THREE_DEGREES_INC,
        "csp following error peak {} inc (issue: <= 3 deg = {THREE_DEGREES_INC} inc)",
        csp.following_error_peak_inc
    );
}

/// Issue 18 "no false trip in duty-cycle", small gimbal after `--auto-tune` (seed 1): 60 s of velocity steps at
/// the current limit, regeneration and load steps with every protection armed raise no fault. Tolerance: none
/// (a count). The reference defaults pass it on this preset too: it guards against a tuning that trips, it does
/// not tell the two apart.
#[test]
fn auto_tuned_small_gimbal_duty_cycle_has_no_false_trip() {
    let plant = small_gimbal();
    let (figures, _) = on_auto_tuned(&plant, 1, || hal_sim::scenarios::duty_cycle::duty_cycle(1).expect("duty cycle"));
    assert_eq!(figures.false_trips, 0, "{figures:?}");
}

/// Issue 18 "csv-sweep step overshoot <= 15 % with no sustained oscillation" on the small gimbal itself (with the
/// shunt noise), after its own `--auto-tune`, seeds 1..=3: the 394 rpm step's true speed peaks at most 15 % over
/// the target (measured 5.63, 4.43 and 4.71 %), and its ripple over the last 200 ms is at most 2 % of the step
/// RMS (measured 2.0, 2.1 and 1.6 rpm; the current noise's, module documentation). Tolerances: the 15 %; 2 %
/// of the step is 3.7 times the measured ripple, and a loop that oscillates (4 times the velocity P gain)
/// limit-cycles at 106 to 108 rpm RMS.
#[test]
fn auto_tuned_small_gimbal_meets_the_velocity_figure_with_the_current_noise() {
    for seed in 1..=3u64 {
        let (step, ripple) = on_auto_tuned(&small_gimbal(), seed, || velocity_step(seed));
        assert_eq!(step.step_rpm, 394.0, "the step scaled by the acceleration capability");
        assert!(
            step.overshoot_pct <= 15.0,
            "seed {seed}: csv step overshoot {} % (issue: <= 15 %)",
            step.overshoot_pct
        );
        assert!(
            ripple <= 0.02 * step.step_rpm,
            "seed {seed}: speed ripple {ripple} rpm RMS on the {} rpm step: a sustained oscillation",
            step.step_rpm
        );
    }
}

/// The CSP settle figure apart from the current sensing: on the small gimbal without the shunts' noise, after its
/// own `--auto-tune`, seeds 1..=3, the CSP move's position is within 2 increments of its target 20 ms after the
/// last set-point (measured 2, 2, 1). Without the noise the ADC's 8 mA step is not dithered: the identification's
/// kt comes out 2.7 to 3.0 % low and its friction 16 to 19 % low, and the friction feedforward's standstill
/// correction of that estimate leaves the motor one increment further than the issue's +-1, which
/// `auto_tuned_small_gimbal_csp_settles_within_1_increment_with_the_current_noise` asserts on the preset itself.
/// Tolerance: 2 increments, the undithered ADC step's one more than the issue's.
#[test]
fn auto_tuned_small_gimbal_without_the_shunt_noise_settles_within_2_increments() {
    let quiet = small_gimbal_without_shunt_noise();
    for seed in 1..=3u64 {
        let csp = on_auto_tuned(&quiet, seed, || csp_move(seed));
        assert!(
            csp.settle_error_inc <= 2.0,
            "seed {seed}: csp settle error {} inc without shunt noise (2 inc: the undithered ADC step)",
            csp.settle_error_inc
        );
    }
}

/// Issue 18 "csp ... settles within +-1 increment" on the small gimbal itself (with the shunt noise), after its own
/// `--auto-tune`, seeds 1..=3: 20 ms after the last set-point and until the end of the run (80 ms later) the
/// position is within +-1 increment of the target. Before the friction feedforward (0x30A1:06) the motor stopped
/// 2 to 3 increments past it on its Coulomb friction (`firmware::control::position`, "Friction feedforward").
/// Tolerance: the bound.
#[test]
fn auto_tuned_small_gimbal_csp_settles_within_1_increment_with_the_current_noise() {
    for seed in 1..=3u64 {
        let csp = on_auto_tuned(&small_gimbal(), seed, || csp_move(seed));
        println!("seed {seed}: {csp:?}");
        assert!(csp.settle_error_inc <= 1.0, "seed {seed}: settle error {} inc (issue: +-1)", csp.settle_error_inc);
        assert!(
            csp.settle_error_max_inc <= 1.0,
            "seed {seed}: left the +-1 band after settling: {} inc",
            csp.settle_error_max_inc
        );
    }
}
