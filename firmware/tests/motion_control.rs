//! Tests of the slow-loop motion control (`firmware::control::{velocity, position, observer, velocity_estimate}`):
//! unit conversions against hand-computed values, anti-windup, the D filter's pole, panic-freedom over the full
//! input ranges, counter wrap, and closed loops on a simple `f64` rigid-body model of the reference plant of
//! `shared/design/ARCHITECTURE.md` (4096 inc/rev, kt 0.0335 Nm/A, J = 176 g cm^2, viscous 2e-6 Nm s/rad,
//! Coulomb 3 mNm, a first-order current loop of 1.5 kHz bandwidth, output applied one current period (40 us)
//! after the position sample). The full plant of `hal-sim` is used by the scenario tests elsewhere.
//!
//! Each test states its tolerance; the closed-loop figures are printed (`--nocapture`).

use std::f64::consts::{FRAC_1_SQRT_2, PI, TAU};

use firmware::control::frames::Amps;
use firmware::control::observer::{ObserverGains, VelocityObserver};
use firmware::control::position::{
    CascadePositionController, Increments, PositionController, PositionGains, D_FILTER_CUTOFF_MILLIRAD_PER_S,
    STANDSTILL_FRICTION_BAND_INC,
};
use firmware::control::velocity::{
    IncPerTick, IncPerTick2, ScaledGain, VelocityController, VelocityGains, SLOW_TICK_HZ,
};
use firmware::control::velocity_estimate::{exp_neg_q31, CounterExtender, LowPass, LowPassVelocityEstimator};
use fixed::types::I16F16;
use proptest::prelude::*;

const TS: f64 = 1.0 / SLOW_TICK_HZ as f64;
const N_ENC: u32 = 4096;
const N_HALL: u32 = 42;

/// A gain's real value in output LSB per input LSB.
fn g(x: ScaledGain) -> f64 {
    f64::from(x.mantissa()) / 2f64.powi(x.shift() as i32)
}
/// Relative closeness.
fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs()
}
fn amps(x: f64) -> Amps {
    Amps(I16F16::from_num(x))
}
fn af(a: Amps) -> f64 {
    a.0.to_num::<f64>()
}
fn vt(v: IncPerTick) -> f64 {
    v.0.to_num::<f64>()
}
/// rpm to inc/tick for `n` increments per revolution.
fn rpm_to_ipt(rpm: f64, n: u32) -> f64 {
    rpm / 60.0 * f64::from(n) * TS
}
fn ipt(x: f64) -> IncPerTick {
    IncPerTick(I16F16::from_num(x))
}
fn ipt2(x: f64) -> IncPerTick2 {
    IncPerTick2(I16F16::from_num(x))
}

// ------------------------------------------------------------------------------------------------------------
// Unit conversions (hand-computed: 2 pi f_s / N = 2 pi 2500 / 4096 = 3.834952 (rad/s) per (inc/tick);
// 2 pi / N = 1.5339808e-3 rad/inc; a gain G in A per (inc/tick) is G * 2^16 in 2^-32 A per 2^-16 inc/tick).
// ------------------------------------------------------------------------------------------------------------

#[test]
fn velocity_gains_from_idx_units() {
    // firmware/device.toml defaults of 0x30A2: 165,000 uA*s/rad, 10,400,000 uA/rad, 60 uA*s/rad, 525 uA*s^2/rad.
    let gains = VelocityGains::from_idx_0x30a2(165_000, 10_400_000, 60, 525, N_ENC);
    let s16 = 65_536.0;
    // Kp = 0.165 * 3.834952 = 0.6327671 A/(inc/tick).
    assert!(close(g(gains.kp()) / s16, 0.632_767_1, 1e-6), "{}", g(gains.kp()) / s16);
    // Ki Ts = 10.4 A/rad * 1.5339808e-3 rad/inc = 0.01595340 A per inc/tick per tick.
    assert!(close(g(gains.ki_ts()) / s16, 0.015_953_40, 1e-6));
    // FFv = 60e-6 * 3.834952 = 2.300971e-4.
    assert!(close(g(gains.ff_velocity()) / s16, 2.300_971e-4, 1e-6));
    // FFa = 525e-6 A s^2/rad * (2 pi 2500^2 / 4096 = 9587.380 rad/s^2 per inc/tick^2) = 5.033375.
    assert!(close(g(gains.ff_acceleration()) / s16, 5.033_375, 1e-6));
    // Kb defaults to tracking in one tick; the Tt = Ti alternative is Ki Ts / Kp = 10.4 / (0.165 * 2500) = 0.02521212.
    assert_eq!(gains.kb(), i32::MAX);
    let kb = VelocityGains::tracking_gain_ts_over_ti(165_000, 10_400_000);
    assert!(close(f64::from(kb) / 2f64.powi(31), 0.025_212_12, 1e-6));
    // IDX defaults (S2 L4537-4591): 60,000 and 1,200,000: Kp = 0.06 * 3.834952 = 0.2300971.
    let idx = VelocityGains::from_idx_0x30a2(60_000, 1_200_000, 2_000, 500, N_ENC);
    assert!(close(g(idx.kp()) / s16, 0.230_097_1, 1e-6));
    // Hall-only resolution 42: Kp = 0.165 * 2 pi 2500 / 42 = 61.70986.
    let hall = VelocityGains::from_idx_0x30a2(165_000, 0, 0, 0, N_HALL);
    assert!(close(g(hall.kp()) / s16, 61.709_86, 1e-6));
    // Every gain keeps 31 significant bits (or saturates).
    for x in [gains.kp(), gains.ki_ts(), gains.ff_velocity(), gains.ff_acceleration()] {
        assert!(x.mantissa() >= 1 << 30, "{x:?}");
    }
    // Absurd values saturate without panicking; Kp = 0 gives the largest tracking gain.
    let sat = VelocityGains::from_idx_0x30a2(u32::MAX, u32::MAX, u32::MAX, u32::MAX, 1);
    assert_eq!(sat.ff_acceleration().shift(), 0);
    assert_eq!(VelocityGains::tracking_gain_ts_over_ti(0, 1), i32::MAX);
    assert_eq!(VelocityGains::from_idx_0x30a2(1, 1, 1, 1, 0), VelocityGains::ZERO.with_tracking_gain(i32::MAX));
}

#[test]
fn velocity_units() {
    assert_eq!(IncPerTick::from_inc_per_s(2500), ipt(1.0));
    assert_eq!(IncPerTick::from_inc_per_s(-2500), ipt(-1.0));
    // 100 rpm at 4096 inc/rev = 6826.67 inc/s = 2.730667 inc/tick.
    assert!((vt(IncPerTick::from_inc_per_s(6827)) - 2.7308).abs() < 1e-4);
    assert_eq!(ipt(2.7308).to_inc_per_s(), 6827);
    assert_eq!(IncPerTick::from_inc_per_s(i32::MAX).to_bits(), i32::MAX);
}

#[test]
fn position_gains_from_idx_units() {
    // firmware/device.toml defaults of 0x30A1: 2,780,000 uA/rad, 35,000,000 uA/(rad s), 66,000 uA*s/rad, 60, 525.
    let p = PositionGains::from_idx_0x30a1(2_780_000, 35_000_000, 66_000, 60, 525, N_ENC);
    let s32 = 2f64.powi(32);
    // Kp = 2.78 * 1.5339808e-3 = 4.264467e-3 A/inc.
    assert!(close(g(p.kp()) / s32, 4.264_467e-3, 1e-6));
    // Ki Ts = 35 * 1.5339808e-3 / 2500 = 2.147573e-5 A/inc per tick.
    assert!(close(g(p.ki_ts()) / s32, 2.147_573e-5, 1e-6));
    // Kd = 0.066 * 3.834952 = 0.2531068 A/(inc/tick).
    assert!(close(g(p.kd()) / 65_536.0, 0.253_106_8, 1e-6));
    assert!(close(g(p.ff_acceleration()) / 65_536.0, 5.033_375, 1e-6));
    // Kb = Ts / Td = Kp / (Kd f_s) = 2.78 / (0.066 * 2500) = 0.01684848.
    assert!(close(f64::from(p.kb()) / 2f64.powi(31), 0.016_848_48, 1e-6));
    // Cascade gain: 100 /s -> 100 / 2500 = 0.04 inc/tick per inc.
    let c = CascadePositionController::new(100_000, VelocityController::default());
    assert!(close(g(c.kv()) / 65_536.0, 0.04, 1e-8));
}

/// 0x30A1:06 (`control::position`, "Friction feedforward"): with every other gain 0 the output is the friction
/// current alone: the demanded velocity's sign while the demand moves (whatever the error), at a standing demand
/// the error's sign beyond +-1 increment and nothing within it, nothing while a demand starts (acceleration only),
/// and nothing with 0x30A1:06 = 0. Tolerance: one 2^-16 A step (uA to 2^-32 A floors).
#[test]
fn friction_feedforward_follows_the_demand_and_at_standstill_the_error_beyond_the_band() {
    assert_eq!(STANDSTILL_FRICTION_BAND_INC, 1);
    let friction = PositionGains::from_idx_0x30a1(0, 0, 0, 0, 0, N_ENC).with_friction_feedforward(12_000);
    // (error in increments, demanded velocity inc/tick, demanded acceleration inc/tick^2, expected current A)
    let cases = [
        (0, 0.5, 0.0, 0.012),
        (5, -0.5, 0.0, -0.012),
        (-5, 0.5, -0.01, 0.012),
        (2, 0.0, 0.0, 0.012),
        (-2, 0.0, 0.0, -0.012),
        (1, 0.0, 0.0, 0.0),
        (-1, 0.0, 0.0, 0.0),
        (0, 0.0, 0.0, 0.0),
        (3, 0.0, 0.01, 0.0),
    ];
    for (e, w, a, expected) in cases {
        let mut c = PositionController::new(friction);
        let i = c.step(Increments(e), Increments(0), ipt(w), ipt2(a), amps(10.0));
        assert!((af(i) - expected).abs() <= 1.0 / 65_536.0, "e {e} w {w} a {a}: {} A, expected {expected}", af(i));
    }
    let mut off = PositionController::new(PositionGains::from_idx_0x30a1(0, 0, 0, 0, 0, N_ENC));
    assert_eq!(af(off.step(Increments(5), Increments(0), ipt(0.0), ipt2(0.0), amps(10.0))), 0.0);
}

/// The hold the friction feedforward gives (`control::position`, "Friction feedforward"): a PD whose proportional
/// part meets the model plant's 3 mNm Coulomb friction (89.6 mA) only 18 increments off, 10 increments from a
/// standing demand. Without the feedforward the friction holds the motor there; with the true friction and with
/// 1.8 times it (the convergence argument's bound is 2) the motor ends within +-1 increment after 100 ms and stays
/// for the last 40 ms (no limit cycle). Tolerance: the band itself.
#[test]
fn friction_feedforward_brings_a_stuck_motor_into_the_band_and_holds_it_there() {
    let true_friction_ua = (COULOMB / KT * 1e6) as u32;
    let hold = |ff_ua: u32| {
        let gains = PositionGains::from_idx_0x30a1(3_260_000, 0, 66_000, 0, 0, N_ENC).with_friction_feedforward(ff_ua);
        run_position(gains, &[(10, 0.0, 0.0); 250])
    };
    let stuck = hold(0);
    assert!(stuck.iter().all(|&e| e == 10), "without the feedforward the friction holds the motor: {stuck:?}");
    for ff in [true_friction_ua, true_friction_ua * 18 / 10] {
        let e = hold(ff);
        let tail = &e[150..];
        assert!(tail.iter().all(|&x| x.abs() <= 1 && x == tail[0]), "FF {ff} uA: the last 40 ms {tail:?}");
    }
}

#[test]
fn observer_gains_from_idx_units() {
    // firmware/device.toml defaults of 0x30A3 and 0x3001:05.
    let o = ObserverGains::from_idx_0x30a3(650, 369_465, 27_000, 209, 176_000, 33_500, N_ENC);
    assert!(close(f64::from(o.l_theta()) / 2f64.powi(30), 0.65, 1e-8));
    // l_w Ts = 369.465 / 2500 = 0.147786 inc/tick per inc (2^-32 per 2^-16: x 2^16).
    assert!(close(g(o.l_omega()) / 65_536.0, 0.147_786, 1e-6));
    // l_T / k_m * 2pi/N = 0.027 / 0.0335 * 1.5339808e-3 = 1.236343e-3 A/inc.
    assert!(close(g(o.l_load()) / 65_536.0, 1.236_343e-3, 1e-6));
    // Ts^2 k_m N / (2 pi J) = 0.0335 * 4096 / (2500^2 * 2 pi * 1.76e-5) = 0.1985328 inc/tick per A per tick.
    assert!(close(g(o.k_current()) / 65_536.0, 0.198_532_8, 1e-6));
    // r = 209e-9 Nm/rpm * 60 / (2 pi) = 1.995803e-6 Nm s/rad; r Ts / J = 1.995803e-6 / (2500 * 1.76e-5) = 4.535916e-5.
    assert!(close(g(o.k_friction()) / 65_536.0, 4.535_916e-5, 1e-6));
    // IDX default 868 per mille.
    let idx = ObserverGains::from_idx_0x30a3(868, 500_000, 200_000, 3_000, 300_000, 33_500, N_ENC);
    assert!(close(f64::from(idx.l_theta()) / 2f64.powi(30), 0.868, 1e-8));
    // Degenerate parameters: no panic, zero gains.
    let z = ObserverGains::from_idx_0x30a3(u32::MAX, 0, 5, 5, 0, 0, 0);
    assert_eq!(z.k_current(), ScaledGain::ZERO);
    assert_eq!(z.l_load(), ScaledGain::ZERO);
}

#[test]
fn low_pass_coefficients() {
    // exp(-x) against f64 over the filters' range.
    for i in 0..=400u64 {
        let x = i as f64 * 0.01;
        let q = exp_neg_q31((x * 2f64.powi(32)) as u64);
        assert!((f64::from(q) / 2f64.powi(31) - (-x).exp()).abs() < 2e-9, "x = {x}");
    }
    // 395 Hz (0x30A2:05 default): c = 1 - exp(-2 pi 395 / 2500) = 1 - exp(-0.9927433) = 0.6294413.
    let c = f64::from(LowPass::from_cutoff_hz(395).coefficient()) / 2f64.powi(31);
    assert!((c - 0.629_441_3).abs() < 1e-7, "{c}");
    // D filter 390.61 rad/s: c = 1 - exp(-0.156244) = 0.1446495.
    let d = LowPass::from_cutoff_millirad_per_s(D_FILTER_CUTOFF_MILLIRAD_PER_S);
    assert!((f64::from(d.coefficient()) / 2f64.powi(31) - 0.144_649_5).abs() < 1e-7);
    assert_eq!(LowPass::from_cutoff_hz(0).coefficient(), 0);
    // Error feedback: the mean output equals the mean input even with a tiny coefficient (1 Hz: c = 2.5e-3).
    let mut f = LowPass::from_cutoff_hz(1);
    let mut sum = 0i64;
    for k in 0..200_000 {
        let y = f.step(if k % 3 == 0 { 1 << 16 } else { 0 });
        if k >= 100_000 {
            sum += i64::from(y);
        }
    }
    let mean = sum as f64 / 100_000.0 / 65_536.0;
    assert!((mean - 1.0 / 3.0).abs() < 1e-4, "{mean}");
}

// ------------------------------------------------------------------------------------------------------------
// Anti-windup and the D filter
// ------------------------------------------------------------------------------------------------------------

#[test]
fn velocity_anti_windup_recovers_at_once() {
    let gains = VelocityGains::from_idx_0x30a2(165_000, 10_400_000, 0, 0, N_ENC);
    let limit = amps(3.0);
    let run = |gains: VelocityGains| {
        let mut c = VelocityController::new(gains);
        // 10 s at the limit: demand 1000 rpm, motor stalled.
        for _ in 0..25_000 {
            assert_eq!(c.step(ipt(rpm_to_ipt(1000.0, N_ENC)), IncPerTick::ZERO, IncPerTick2::ZERO, limit), limit);
        }
        assert!(c.saturated());
        // The motor overshoots by 10 rpm: the demand must leave the limit and reverse within a few ticks.
        let v = ipt(rpm_to_ipt(1000.0, N_ENC));
        let over = ipt(rpm_to_ipt(1010.0, N_ENC));
        (0..2500).map(|_| af(c.step(v, over, IncPerTick2::ZERO, limit))).position(|i| i < 0.0)
    };
    // Default tracking (Tt = Ts): the integrator sat at the limit minus Kp * 1000 rpm (3 - 17.3 A), so the output
    // reverses on the first tick after the error does. Bound: within 1 tick.
    let with = run(gains).expect("recovers");
    assert!(with <= 1, "back-calculation: output reversed after {with} ticks");
    // Tt = Ti (the current loop's choice): the integrator sits at the limit; it unwinds with the small error.
    let slow = run(gains.with_tracking_gain(VelocityGains::tracking_gain_ts_over_ti(165_000, 10_400_000)));
    println!("velocity anti-windup: output reverses after {with} ticks (Tt = Ts), {slow:?} ticks (Tt = Ti)");
    // Without anti-windup the integrator ran to its clamp: no recovery within 1 s.
    let without = run(gains.with_tracking_gain(0));
    assert!(without.is_none(), "a wound-up integrator takes long: {without:?}");
}

#[test]
fn position_anti_windup_recovers_at_once() {
    let gains = PositionGains::from_idx_0x30a1(2_780_000, 35_000_000, 66_000, 0, 0, N_ENC);
    let limit = amps(3.0);
    let mut c = PositionController::new(gains);
    // 10 s blocked 2000 inc short of the target.
    for _ in 0..25_000 {
        assert_eq!(c.step(Increments(2000), Increments(0), IncPerTick::ZERO, IncPerTick2::ZERO, limit), limit);
    }
    // The axis passes the target by 20 increments (a jump: the D part kicks negative too).
    let mut ticks = None;
    for k in 0..2500 {
        let i = c.step(Increments(2000), Increments(2020), IncPerTick::ZERO, IncPerTick2::ZERO, limit);
        if af(i) < 0.0 && ticks.is_none() {
            ticks = Some(k);
        }
    }
    assert!(ticks.is_some_and(|t| t <= 1), "{ticks:?}");
    let mut c2 = PositionController::new(gains);
    for _ in 0..25_000 {
        c2.step(Increments(2000), Increments(0), IncPerTick::ZERO, IncPerTick2::ZERO, limit);
    }
    // The integrator settled where the update is stationary: Ki Ts e = Kb (u - u_sat), Kb = Ts/Td, so
    // xi = u_sat - Kp e - Ki Ts e + Ki Td e (Td = Kd/Kp = 0.066/2.78 s) = -3.02 A, not at the limit.
    let e = 2000.0 * TAU / 4096.0;
    let td = 0.066 / 2.78;
    let xi = 3.0 - 2.78 * e - 35.0 * TS * e + 35.0 * td * e;
    assert!((af(c2.integral()) - xi).abs() < 0.01, "{} vs {xi}", af(c2.integral()));
}

#[test]
fn d_filter_time_constant() {
    // Only Kd = 1 A s/rad; a position ramp of 1 inc/tick starting at tick 0: the D output rises as
    // 1 - exp(-t / tau), tau = 1 / 390.61 rad/s = 2.560 ms (S1 L756). Bound: within 2 %.
    let gains = PositionGains::from_idx_0x30a1(0, 0, 1_000_000, 0, 0, N_ENC);
    let mut c = PositionController::new(gains);
    let big = amps(1000.0);
    let final_value = 1.0 * TAU * 2500.0 / 4096.0; // Kd * 1 inc/tick in rad/s = 3.834952 A
    let mut prev = (0.0, 0.0);
    let mut tau = None;
    for k in 0..200i32 {
        let i = af(c.step(Increments(k), Increments(0), IncPerTick::ZERO, IncPerTick2::ZERO, big));
        let t = f64::from(k) * TS;
        let y = i / final_value;
        if tau.is_none() && y >= 1.0 - (-1.0f64).exp() {
            let (t0, y0) = prev;
            tau = Some(t0 + (t - t0) * ((1.0 - (-1.0f64).exp()) - y0) / (y - y0));
        }
        prev = (t, y);
        if k > 100 {
            assert!((y - 1.0).abs() < 1e-4, "final value {y}");
        }
    }
    let tau = tau.expect("crosses 63 %");
    println!("D filter: tau = {:.4} ms (1/390.61 = 2.5601 ms)", tau * 1e3);
    assert!(close(tau, 1.0 / 390.61, 0.02), "{tau}");
}

/// 0x30A1:07 (`PositionGains::with_d_filter_cutoff`): the D part's time constant follows the object, 1 / 1,903.4
/// rad/s = 0.525 ms for the elastic design's cut-off (the matched pole of a first-order filter at the 2.5 kHz tick;
/// measured on the same ramp as `d_filter_time_constant`, within 2 % plus half a tick, as the crossing is
/// interpolated between ticks 0.4 ms apart against a 0.5 ms time constant).
#[test]
fn d_filter_cutoff_object_sets_the_time_constant() {
    let gains = PositionGains::from_idx_0x30a1(0, 0, 1_000_000, 0, 0, N_ENC).with_d_filter_cutoff(1_903_400);
    let mut c = PositionController::new(gains);
    let big = amps(1000.0);
    let final_value = 1.0 * TAU * 2500.0 / 4096.0;
    let mut prev = (0.0, 0.0);
    let mut tau = None;
    for k in 0..40i32 {
        let y = af(c.step(Increments(k), Increments(0), IncPerTick::ZERO, IncPerTick2::ZERO, big)) / final_value;
        let t = f64::from(k) * TS;
        if tau.is_none() && y >= 1.0 - (-1.0f64).exp() {
            let (t0, y0) = prev;
            tau = Some(t0 + (t - t0) * ((1.0 - (-1.0f64).exp()) - y0) / (y - y0));
        }
        prev = (t, y);
    }
    let tau = tau.expect("crosses 63 %");
    assert!((tau - 1.0 / 1903.4).abs() < 0.02 / 1903.4 + TS / 2.0, "{tau}");
    assert!(tau < 1.0 / 1000.0, "faster than EPOS4's 2.56 ms: {tau}");
}

/// A new cut-off taken while the D part holds a value keeps that value (`LowPass::retune`): new gains with
/// another cut-off do not jump the current demand; only the rate at which the D part follows changes.
#[test]
fn changing_the_d_filter_cutoff_keeps_the_d_part_output() {
    let gains = PositionGains::from_idx_0x30a1(0, 0, 1_000_000, 0, 0, N_ENC);
    let mut c = PositionController::new(gains);
    let big = amps(1000.0);
    for k in 0..10i32 {
        c.step(Increments(k), Increments(0), IncPerTick::ZERO, IncPerTick2::ZERO, big);
    }
    let held = c.d_filter().output();
    c.set_gains(gains.with_d_filter_cutoff(1_903_400));
    assert_eq!(c.d_filter().output(), held, "output kept");
    let elastic = firmware::control::velocity_estimate::LowPass::from_cutoff_millirad_per_s(1_903_400);
    assert_eq!(c.d_filter().coefficient(), elastic.coefficient(), "the new cut-off's coefficient");
}

// ------------------------------------------------------------------------------------------------------------
// Counter wrap
// ------------------------------------------------------------------------------------------------------------

#[test]
fn counter_wrap() {
    // 16-bit timer: forwards and backwards across 0xFFFF/0.
    let mut x = CounterExtender::new(65_530, Increments(i32::MAX - 3));
    assert_eq!(x.update(4), Increments(i32::MAX.wrapping_add(7)));
    assert_eq!(x.update(65_535), Increments(i32::MAX.wrapping_add(2)));
    // 32-bit position across i32::MAX: the velocity estimate sees +7 inc/tick throughout.
    let mut est = LowPassVelocityEstimator::new(395);
    let mut p = i32::MAX - 700;
    let mut v = IncPerTick::ZERO;
    for _ in 0..200 {
        v = est.update(Increments(p));
        p = p.wrapping_add(7);
    }
    assert!(p < 0, "wrapped");
    assert_eq!(v, ipt(7.0));
    // Backwards across i32::MIN.
    let mut est = LowPassVelocityEstimator::new(395);
    let mut p = i32::MIN + 300;
    for _ in 0..200 {
        v = est.update(Increments(p));
        p = p.wrapping_sub(5);
    }
    assert_eq!(v, ipt(-5.0));
    // The position controller's error and D part across the wrap: reference and position both near i32::MAX.
    let gains = PositionGains::from_idx_0x30a1(2_780_000, 0, 66_000, 0, 0, N_ENC);
    let mut a = PositionController::new(gains);
    let mut b = PositionController::new(gains);
    for k in 0..100i32 {
        let off = i32::MAX - 50;
        let ia = a.step(
            Increments(off.wrapping_add(k * 3)),
            Increments(off.wrapping_add(k * 3 - 10)),
            IncPerTick::ZERO,
            IncPerTick2::ZERO,
            amps(10.0),
        );
        let ib = b.step(Increments(k * 3), Increments(k * 3 - 10), IncPerTick::ZERO, IncPerTick2::ZERO, amps(10.0));
        assert_eq!(ia, ib);
        assert_eq!(a.following_error(), 10);
    }
    // The observer across the wrap.
    let og = ObserverGains::from_idx_0x30a3(650, 369_465, 27_000, 209, 176_000, 33_500, N_ENC);
    let mut o = VelocityObserver::new(og);
    let mut p = i32::MAX - 2000;
    o.reset(Increments(p));
    for _ in 0..2000 {
        p = p.wrapping_add(9);
        o.step(Increments(p), amps(0.0));
    }
    assert!((vt(o.velocity()) - 9.0).abs() < 0.01, "{}", vt(o.velocity()));
    assert!((o.position().0.wrapping_sub(p)).abs() <= 1);
}

// ------------------------------------------------------------------------------------------------------------
// No panic for any input
// ------------------------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn no_panic_any_input(
        raw in proptest::array::uniform5(any::<u32>()),
        n in any::<u32>(),
        cut in any::<u32>(),
        inputs in proptest::collection::vec((any::<i32>(), any::<i32>(), any::<i32>(), any::<i32>(), any::<i32>()), 1..8),
    ) {
        let [p, i, d, fv, fa] = raw;
        let vg = VelocityGains::from_idx_0x30a2(p, i, fv, fa, n);
        let pg = PositionGains::from_idx_0x30a1(p, i, d, fv, fa, n);
        let og = ObserverGains::from_idx_0x30a3(p, i, d, fv, fa, cut, n);
        let mut vc = VelocityController::new(vg);
        let mut pc = PositionController::new(pg);
        let mut cc = CascadePositionController::new(cut, VelocityController::new(vg));
        let mut ob = VelocityObserver::new(og);
        let mut est = LowPassVelocityEstimator::new(cut);
        let mut ext = CounterExtender::default();
        let mut lp = LowPass::from_cutoff_millirad_per_s(cut);
        for (a, b, c, dd, l) in inputs {
            let lim = Amps::from_bits(l);
            let bound = l.max(0);
            let u = vc.step(IncPerTick::from_bits(a), IncPerTick::from_bits(b), IncPerTick2::from_bits(c), lim);
            prop_assert!(u.to_bits().abs() <= bound);
            let u = pc.step(Increments(a), Increments(b), IncPerTick::from_bits(c), IncPerTick2::from_bits(dd), lim);
            prop_assert!(u.to_bits().abs() <= bound);
            let u = cc.step(Increments(a), Increments(b), IncPerTick::from_bits(c), IncPerTick::from_bits(dd),
                IncPerTick2::from_bits(l), lim);
            prop_assert!(u.to_bits().abs() <= bound);
            ob.step(Increments(a), Amps::from_bits(b));
            let _ = ob.load_current();
            est.update(Increments(c));
            ext.update(dd as u16);
            lp.step(a);
            let _ = IncPerTick::from_inc_per_s(a).to_inc_per_s();
        }
    }

    #[test]
    fn exp_any_input(x in any::<u64>()) {
        let q = exp_neg_q31(x);
        prop_assert!(q <= 1 << 31);
    }
}

// ------------------------------------------------------------------------------------------------------------
// Closed loops on a simple f64 model of the reference plant
// ------------------------------------------------------------------------------------------------------------

/// The reference plant as a rigid body: J dw/dt = kt i - b w - Tc sgn(w), current loop first order at 1.5 kHz.
struct Plant {
    theta: f64,
    omega: f64,
    current: f64,
}

const J: f64 = 176e-7;
const KT: f64 = 0.0335;
const VISCOUS: f64 = 2e-6;
const COULOMB: f64 = 3e-3;
const TAU_I: f64 = 1.0 / (TAU * 1500.0);
/// Integration sub-steps per 40 us current period.
const SUB: usize = 8;

impl Plant {
    fn new() -> Self {
        Self { theta: 0.0, omega: 0.0, current: 0.0 }
    }
    /// Advances one current period (40 us) with the current demand `i_ref` (A); returns the mean velocity.
    fn fast(&mut self, i_ref: f64) -> f64 {
        let dt = 40e-6 / SUB as f64;
        let mut sum = 0.0;
        for _ in 0..SUB {
            self.current += (i_ref - self.current) * (1.0 - (-dt / TAU_I).exp());
            let drive = KT * self.current - VISCOUS * self.omega;
            let torque = if self.omega.abs() > 1e-6 {
                drive - COULOMB * self.omega.signum()
            } else if drive.abs() <= COULOMB {
                0.0
            } else {
                drive - COULOMB * drive.signum()
            };
            let new = self.omega + torque / J * dt;
            // Friction cannot reverse the motion within a step.
            self.omega = if self.omega != 0.0 && new.signum() != self.omega.signum() && drive.abs() <= COULOMB {
                0.0
            } else {
                new
            };
            self.theta += self.omega * dt;
            sum += self.omega;
        }
        sum / SUB as f64
    }
    /// One slow tick: the first current period still uses the previous demand (the slow tick runs after the
    /// fast interrupt that sampled the position). Returns the mean velocity over the tick (rad/s).
    fn slow(&mut self, previous: f64, demand: f64) -> f64 {
        let mut sum = self.fast(previous);
        for _ in 1..10 {
            sum += self.fast(demand);
        }
        sum / 10.0
    }
    fn count(&self, n: u32) -> i32 {
        (self.theta / TAU * f64::from(n)).floor() as i64 as i32
    }
}

fn rad_s_to_rpm(w: f64) -> f64 {
    w * 60.0 / TAU
}

/// Which velocity estimate closes the loop.
#[derive(Clone, Copy)]
enum Estimate {
    LowPass(u32),
    Observer(ObserverGains),
}

/// A CSV run: the velocity controller with `gains` and `est` on a sensor of `n` inc/rev, following the demand
/// `v_ref(t)` in rpm for `ticks`; returns the plant's mean velocity per tick in rpm.
fn run_velocity(gains: VelocityGains, est: Estimate, n: u32, ticks: usize, v_ref: impl Fn(f64) -> f64) -> Vec<f64> {
    let mut plant = Plant::new();
    let mut c = VelocityController::new(gains);
    let mut lp = LowPassVelocityEstimator::new(match est {
        Estimate::LowPass(f) => f,
        Estimate::Observer(_) => 395,
    });
    let mut ob = VelocityObserver::new(match est {
        Estimate::Observer(o) => o,
        Estimate::LowPass(_) => ObserverGains::default(),
    });
    ob.reset(Increments(plant.count(n)));
    let limit = amps(10.0);
    let mut last = amps(0.0);
    let mut out = Vec::with_capacity(ticks);
    for k in 0..ticks {
        let pos = Increments(plant.count(n));
        let v_meas = match est {
            Estimate::LowPass(_) => lp.update(pos),
            Estimate::Observer(_) => ob.step(pos, last),
        };
        let r = ipt(rpm_to_ipt(v_ref(k as f64 * TS), n));
        let i = c.step(r, v_meas, IncPerTick2::ZERO, limit);
        out.push(rad_s_to_rpm(plant.slow(af(last), af(i))));
        last = i;
    }
    out
}

/// Proposed 0x30A2 defaults for a velocity-loop bandwidth of at least 100 Hz with the low-pass estimate
/// (`velocity_bandwidth`): Kp 0.2 A s/rad (crossover about Kp kt / J = 381 rad/s = 61 Hz), Ki 8 A/rad (PI corner
/// Ki/Kp = 40 rad/s), and the filter cut-off 0x30A2:05 at 250 Hz (395 Hz lets the 4096-inc quantisation through
/// at 0.2 A s/rad: the 100 rpm step then leaves the 2 % band now and then).
const PROPOSED_VELOCITY: (u32, u32) = (200_000, 8_000_000);
const PROPOSED_CUTOFF_HZ: u32 = 250;

fn proposed_velocity_gains(n: u32) -> VelocityGains {
    VelocityGains::from_idx_0x30a2(PROPOSED_VELOCITY.0, PROPOSED_VELOCITY.1, 60, 525, n)
}

#[test]
fn velocity_step_100_rpm() {
    // Bound: the plant's velocity (mean over each 0.4 ms tick) overshoots 100 rpm by at most 10 % and stays within
    // 2 % from the settling time on; settling within 100 ms.
    for (name, gains, cutoff, must) in [
        ("device.toml", VelocityGains::from_idx_0x30a2(165_000, 10_400_000, 60, 525, N_ENC), 395, false),
        ("proposed", proposed_velocity_gains(N_ENC), PROPOSED_CUTOFF_HZ, true),
    ] {
        let w = run_velocity(gains, Estimate::LowPass(cutoff), N_ENC, 2500, |_| 100.0);
        let peak = w.iter().copied().fold(f64::MIN, f64::max);
        let last_out = w.iter().rposition(|&x| (x - 100.0).abs() > 2.0).map_or(0, |k| k + 1);
        let ripple = w[last_out..].iter().map(|x| (x - 100.0).abs()).fold(0.0, f64::max);
        println!(
            "CSV step 100 rpm ({name}): overshoot {:.2} %, settled (2 %) after {:.1} ms, then max |error| {:.2} rpm",
            peak - 100.0,
            last_out as f64 * TS * 1e3,
            ripple
        );
        if must {
            assert!(peak <= 110.0, "{name}: overshoot {peak}");
            assert!(last_out as f64 * TS <= 0.1, "{name}: settles after {last_out} ticks");
        }
    }
}

/// Closed-loop gain |w/w_ref| at `f` Hz around 1000 rpm with a 20 rpm sine (small signal, away from the Coulomb
/// friction's sign change), from the Fourier coefficient over whole periods after a settling time.
fn closed_loop_gain(gains: VelocityGains, est: Estimate, f: f64) -> f64 {
    let settle = 0.1;
    let periods = (0.2 * f).ceil().max(4.0);
    let total = settle + periods / f;
    let ticks = (total / TS).ceil() as usize;
    let amp = 20.0;
    let w = run_velocity(gains, est, N_ENC, ticks, |t| 1000.0 + amp * (TAU * f * t).sin());
    let (mut re, mut im, mut m) = (0.0, 0.0, 0.0);
    for (k, x) in w.iter().enumerate() {
        // The plant's value for tick k is its mean over [k Ts, (k+1) Ts]: compare with the sine at the midpoint,
        // corrected for the averaging (sinc) of a tick.
        let t = (k as f64 + 0.5) * TS;
        if t < settle || t > settle + periods / f {
            continue;
        }
        re += (x - 1000.0) * (TAU * f * t).sin();
        im += (x - 1000.0) * (TAU * f * t).cos();
        m += 1.0;
    }
    let sinc = (PI * f * TS).sin() / (PI * f * TS);
    2.0 * (re * re + im * im).sqrt() / m / amp / sinc
}

#[test]
fn velocity_bandwidth() {
    // Bound: |w / w_ref| >= -3 dB (0.7071) at every frequency up to 100 Hz with the proposed gains.
    let freqs = [10.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0, 150.0, 200.0, 250.0, 300.0];
    for (name, gains, cutoff, must) in [
        ("device.toml", VelocityGains::from_idx_0x30a2(165_000, 10_400_000, 60, 525, N_ENC), 395, false),
        ("proposed", proposed_velocity_gains(N_ENC), PROPOSED_CUTOFF_HZ, true),
    ] {
        let mags: Vec<f64> = freqs.iter().map(|&f| closed_loop_gain(gains, Estimate::LowPass(cutoff), f)).collect();
        let bw = freqs.iter().zip(&mags).find(|(_, &m)| m < FRAC_1_SQRT_2).map_or(f64::INFINITY, |(&f, _)| f);
        println!(
            "velocity loop ({name}): |T| = {:?}; first below -3 dB at {bw} Hz",
            mags.iter().map(|m| (m * 1000.0).round() / 1000.0).collect::<Vec<_>>()
        );
        if must {
            assert!(bw > 100.0, "{name}: bandwidth below 100 Hz ({mags:?})");
        }
    }
}

/// Observer gains for the Hall-only test, 0x30A3 raw values tuned on this model for 42 counts/rev: l_theta 0.1,
/// l_w 8 Hz, l_T 0.5 mNm/rad (the observer must filter the count rate, 210 Hz at 300 rpm; S1's Hall example,
/// L1447-1454, uses 0.399 / 68 Hz / 67.8 mNm/rad with twice our inertia and its own plant).
fn hall_observer() -> ObserverGains {
    ObserverGains::from_idx_0x30a3(100, 8_000, 500, 209, 176_000, 33_500, N_HALL)
}

#[test]
fn hall_only_300_rpm_observer_beats_low_pass() {
    // Halls alone: 42 counts/rev (7 pole pairs x 6 states), 300 rpm = 0.084 counts per tick. Same PI gains for
    // both estimates (the IDX default P, 0.06 A s/rad, and I 1 A/rad); the low-pass estimate at the best of
    // 5, 10 and 20 Hz (at 395 Hz the loop does not hold 300 rpm at all). Bound: the observer's velocity ripple
    // (RMS of the plant velocity about its mean, over 1 s after 1 s settling) is lower, and its mean within 2 %.
    let gains = VelocityGains::from_idx_0x30a2(60_000, 1_000_000, 60, 0, N_HALL);
    let ripple = |est| {
        let w = run_velocity(gains, est, N_HALL, 5000, |_| 300.0);
        let tail = &w[2500..];
        let mean = tail.iter().sum::<f64>() / tail.len() as f64;
        let rms = (tail.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / tail.len() as f64).sqrt();
        (mean, rms)
    };
    let mut best = (0, f64::MAX, f64::MAX);
    for hz in [5, 10, 20] {
        let (m, r) = ripple(Estimate::LowPass(hz));
        println!("Hall only, 300 rpm: low-pass {hz} Hz mean {m:.1} rpm ripple {r:.2} rpm rms");
        if r < best.2 {
            best = (hz, m, r);
        }
    }
    let (hz, _, r_lp) = best;
    let (m_ob, r_ob) = ripple(Estimate::Observer(hall_observer()));
    println!(
        "Hall only, 300 rpm: observer mean {m_ob:.1} rpm ripple {r_ob:.2} rpm rms; ratio to the best low-pass \
         ({hz} Hz) {:.2}",
        r_ob / r_lp
    );
    assert!((m_ob - 300.0).abs() < 6.0, "observer mean {m_ob}");
    assert!(r_ob < r_lp, "observer {r_ob} vs low-pass {r_lp}");
}

/// A CSP run of the PID position controller on the encoder, following the integer position profile `profile`
/// (increments per tick, with the velocity and acceleration feedforward of the same profile); returns the
/// following errors in increments.
fn run_position(gains: PositionGains, profile: &[(i32, f64, f64)]) -> Vec<i32> {
    let mut plant = Plant::new();
    let mut c = PositionController::new(gains);
    let limit = amps(10.0);
    let mut last = amps(0.0);
    let mut errs = Vec::with_capacity(profile.len());
    for &(p, v, a) in profile {
        let i = c.step(Increments(p), Increments(plant.count(N_ENC)), ipt(v), ipt2(a), limit);
        errs.push(c.following_error());
        plant.slow(af(last), af(i));
        last = i;
    }
    errs
}

/// A jerk-limited (S-curve) move of `dist` increments with maximum velocity `vmax` inc/s, acceleration `amax`
/// inc/s^2 and jerk `jmax` inc/s^3, sampled per tick as (exact integer position, velocity inc/tick, acceleration
/// inc/tick^2), followed by 0.2 s at rest. Integrated in f64 on a fine grid; the position is rounded per tick.
fn s_curve(dist: f64, vmax: f64, amax: f64, jmax: f64) -> Vec<(i32, f64, f64)> {
    let dt = TS / 100.0;
    let (mut x, mut v, mut a) = (0.0f64, 0.0f64, 0.0f64);
    let mut out = Vec::new();
    let mut k = 0usize;
    loop {
        // Decide the target acceleration: accelerate, cruise or brake (braking distance with jerk limits).
        let remaining = dist - x;
        let t_a = a.abs() / jmax;
        let v_after = v + a * t_a / 2.0; // velocity once the acceleration is ramped to zero
        let brake_dist = {
            // distance to stop from v_after with trapezoidal acceleration profile (approx., conservative)
            let t_j = amax / jmax;
            let vv = v_after.max(0.0);
            if vv <= amax * t_j {
                let tj = (vv / jmax).sqrt();
                2.0 * vv * tj / 2.0 + (v + v_after) / 2.0 * t_a
            } else {
                vv * (vv / amax + t_j) / 2.0 + (v + v_after) / 2.0 * t_a
            }
        };
        let a_target = if remaining <= brake_dist + v.abs() * dt * 2.0 {
            -amax
        } else if v_after < vmax {
            amax
        } else {
            0.0
        };
        let da = (a_target - a).clamp(-jmax * dt, jmax * dt);
        a += da;
        if v + a * dt < 0.0 && a < 0.0 {
            a = 0.0;
            v = 0.0;
        }
        v = (v + a * dt).max(0.0);
        x += v * dt;
        k += 1;
        if k.is_multiple_of(100) {
            out.push((x.round() as i32, v * TS, a * TS * TS));
            if (v == 0.0 && remaining < 1.0) || out.len() > 50_000 {
                break;
            }
        }
    }
    let end = dist.round() as i32;
    for _ in 0..500 {
        out.push((end, 0.0, 0.0));
    }
    out
}

#[test]
fn position_tracking_with_feedforward() {
    // A constant-velocity ramp of 1000 rpm (68.27 inc/tick) after a 100 ms jerk-limited start. Bound: with the
    // velocity and acceleration feedforward (optimum J/kt, S1 L792-805) the following error on the ramp stays
    // within +-20 increments; without feedforward it is larger.
    let pg = |ffv, ffa| PositionGains::from_idx_0x30a1(2_780_000, 35_000_000, 66_000, ffv, ffa, N_ENC);
    let profile = s_curve(40_960.0, 1000.0 / 60.0 * 4096.0, 1.0e6, 5.0e7);
    let with = run_position(pg(60, 525), &profile);
    let without = run_position(pg(0, 0), &profile);
    let peak = |e: &[i32]| e.iter().map(|x| x.abs()).max().unwrap_or(0);
    let rms = |e: &[i32]| (e.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>() / e.len() as f64).sqrt();
    println!(
        "10-rev move at 1000 rpm: with FF peak {} inc rms {:.2} inc; without FF peak {} inc rms {:.2} inc",
        peak(&with),
        rms(&with),
        peak(&without),
        rms(&without)
    );
    assert!(peak(&with) <= 20, "{}", peak(&with));
    assert!(peak(&with) < peak(&without));
    assert_eq!(*with.last().unwrap_or(&1), 0, "at rest on the target");
}

#[test]
fn csp_10_rev_3000_rpm() {
    // The CSP case: 10 revolutions, 3000 rpm, 20,000 rpm/s, jerk-limited (jerk 1e6 rpm/s^2 assumed).
    // Bound (the issue's): peak following error <= 30 inc and RMS <= 8 inc.
    let n = f64::from(N_ENC);
    let profile = s_curve(10.0 * n, 3000.0 / 60.0 * n, 20_000.0 / 60.0 * n, 1.0e6 / 60.0 * n);
    let gains = PositionGains::from_idx_0x30a1(2_780_000, 35_000_000, 66_000, 60, 525, N_ENC);
    let e = run_position(gains, &profile);
    let peak = e.iter().map(|x| x.abs()).max().unwrap_or(0);
    let rms = (e.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>() / e.len() as f64).sqrt();
    println!("CSP 10 rev / 3000 rpm / 20,000 rpm/s: peak {peak} inc, rms {rms:.2} inc over {} ticks", e.len());
    assert!(peak <= 30 && rms <= 8.0, "peak {peak} rms {rms}");
}

#[test]
fn cascade_structure_tracks() {
    // The selectable cascade: Kv 200 /s around the proposed velocity loop, encoder feedback (low-pass 395 Hz).
    let mut plant = Plant::new();
    let mut c = CascadePositionController::new(200_000, VelocityController::new(proposed_velocity_gains(N_ENC)));
    let mut est = LowPassVelocityEstimator::new(PROPOSED_CUTOFF_HZ);
    let profile = s_curve(8192.0, 1000.0 / 60.0 * 4096.0, 1.0e6, 5.0e7);
    let mut last = amps(0.0);
    let mut peak = 0;
    for &(p, v, a) in &profile {
        let pos = Increments(plant.count(N_ENC));
        let w = est.update(pos);
        let i = c.step(Increments(p), pos, ipt(v), w, ipt2(a), amps(10.0));
        peak = peak.max(c.following_error().abs());
        plant.slow(af(last), af(i));
        last = i;
    }
    println!("cascade: peak following error {peak} inc, final {}", c.following_error());
    assert!(peak <= 60, "{peak}");
    assert!(c.following_error().abs() <= 2);
}
