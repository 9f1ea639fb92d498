//! Motor I2t on the reference plant (thermal time constant 0x3001:04 = 20 s, nominal current 3.2 A): a locked
//! rotor driven at twice the nominal current in CST reaches the I2t limit after the model's time, the drive then
//! holds the current at the nominal current and shows the warning (statusword bit 7, 0x3200:01 at 100 %), and the
//! CiA 402 state stays «Operation enabled» (a warning, not a fault).

use firmware::cia402::State;
use firmware::od::generated::handles as h;
use hal_sim::scenarios::motion::prepare_motion;

/// First-order thermal model of the seeds (`firmware::fault::i2t`): from cold, at k times the nominal current,
/// the limit comes after tau ln(k^2 / (k^2 - 1)). Tolerance 2 % (the issue's): the drive integrates the measured
/// q current (ADC noise, the current loop's settling) at 2.5 kHz.
#[test]
fn i2t_limits_a_locked_rotor_to_the_nominal_current() {
    let mut sim = prepare_motion(1, 10).expect("enabled in CST");
    sim.plant.lock_rotor(true);
    // The model starts cold here: commissioning ran at 0.5 A, which decayed during the enable sequence.
    let level0 = f64::from(sim.drive.dictionary().get(h::I2T_LEVEL_MOTOR));
    assert!(level0 <= 1.0, "cold start: {level0} %");
    sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 2000); // 2 x 3.2 A
    let reached = sim.run_until(25_000 * 10, |s| s.statusword() & (1 << 7) != 0).expect("the I2t warning comes");
    let t = reached as f64 * 40e-6;
    let expected = 20.0 * (4.0_f64 / 3.0).ln();
    println!("I2t limit after {t:.3} s, model {expected:.3} s");
    assert!((t - expected).abs() <= 0.02 * expected, "limit after {t:.3} s, model {expected:.3} s");
    // Held at the nominal current from then on, still enabled.
    sim.run(25_000);
    let iq = sim.plant.state().i_dq_a[1];
    assert!((iq - 3.2).abs() < 0.1, "held at the nominal current: {iq} A");
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
    assert_eq!(sim.drive.dictionary().get(h::I2T_LEVEL_MOTOR), 100);
    assert_eq!(sim.drive.dictionary().get(h::ERROR_CODE), 0, "a warning is not a fault");
}

/// At three times the nominal current the limit comes after tau ln(9/8) = 2.356 s (tolerance 2 %, as above);
/// then, at zero current, the level falls as x0 e^(-t/tau): after 10 s from 100 % to 60.7 %. Tolerance: 2 % of
/// the value plus the 1 % resolution of 0x3200:01 (an integer percent).
#[test]
fn i2t_at_three_times_nominal_and_the_cool_down_follow_the_model() {
    let mut sim = prepare_motion(2, 10).expect("enabled in CST");
    sim.plant.lock_rotor(true);
    sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 3000); // 3 x 3.2 A = 9.6 A, below the 10 A output limit
    let reached = sim.run_until(25_000 * 5, |s| s.statusword() & (1 << 7) != 0).expect("the I2t warning comes");
    let t = reached as f64 * 40e-6;
    let expected = 20.0 * (9.0_f64 / 8.0).ln();
    println!("I2t limit at 3 x nominal after {t:.3} s, model {expected:.3} s");
    assert!((t - expected).abs() <= 0.02 * expected, "limit after {t:.3} s, model {expected:.3} s");
    // Cool down from the limit with no current.
    sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 0);
    let start = f64::from(sim.drive.dictionary().get(h::I2T_LEVEL_MOTOR));
    sim.run(25_000 * 10);
    let level = f64::from(sim.drive.dictionary().get(h::I2T_LEVEL_MOTOR));
    let model = start * (-10.0_f64 / 20.0).exp();
    println!("I2t level after 10 s at zero current: {level} %, model {model:.1} % (from {start} %)");
    assert!((level - model).abs() <= 0.02 * model + 1.0, "cooled to {level} %, model {model:.1} %");
    assert_eq!(sim.statusword() & (1 << 7), 0, "the warning has gone below 95 %");
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
}
