//! Property tests of the fixed-point control core (`firmware::control`) against `f64` references.
//!
//! Each test states its bound. Inputs cover the whole representable range where the function accepts it (no panic,
//! outputs in range) and the physical range where an accuracy bound applies (the reference plant of
//! `shared/design/ARCHITECTURE.md`: +-16.5 A shunt range, bus up to 60 V).

use std::f64::consts::{PI, TAU};

use firmware::control::angle::ElectricalAngle;
use firmware::control::current_loop::{foc_step, CurrentController, CurrentLoopConfig, FocInput};
use firmware::control::frames::{Abc, AlphaBeta, Amps, Dq, Volts};
use firmware::control::pi::{PiController, PiGains};
use firmware::control::svpwm::{DutyClamp, Modulator, VoltageLimit};
use firmware::control::transforms::{clarke, inverse_clarke, inverse_park, park};
use firmware::control::trig::{cos, sin, sin_cos};
use firmware::hal::power::PWM_PERIOD_TICKS;
use fixed::types::{I16F16, I1F31, I8F24};
use proptest::prelude::*;

const T: f64 = PWM_PERIOD_TICKS as f64;

fn amps(x: f64) -> Amps {
    Amps(I16F16::from_num(x))
}
fn volts(x: f64) -> Volts {
    Volts(I16F16::from_num(x))
}
fn f(x: I16F16) -> f64 {
    x.to_num::<f64>()
}
fn angle_rad(a: ElectricalAngle) -> f64 {
    f64::from(a.0) / 4_294_967_296.0 * TAU
}
/// The bus voltage the modulator works with: quantised to 1/512 V and made odd (at most +1/512 V), saturated to
/// [2 sqrt(3)/f V, 128 V) by the gain clamp (`svpwm`).
fn effective_bus(v: Volts, permille: u16) -> f64 {
    let q9 = f64::from((v.to_bits() >> 7).clamp(0, 65_535) | 1) / 512.0;
    q9.max(2.0 * 3f64.sqrt() / (f64::from(permille) / 1000.0))
}

fn angle_of(rad: f64) -> ElectricalAngle {
    ElectricalAngle((rad.rem_euclid(TAU) / TAU * 4_294_967_296.0) as u64 as u32)
}

/// Stated bound of `trig`: |error| <= 4.0e-5 over the whole u32 turn.
const TRIG_BOUND: f64 = 4.0e-5;

#[test]
fn trig_max_error() {
    // A deterministic sweep of 2^22 angles (every 1024th turn value, offset so that it is not aligned with the
    // table) plus every table node and interval midpoint.
    let mut worst: f64 = 0.0;
    let mut check = |turn: u32| {
        let a = ElectricalAngle(turn);
        let x = angle_rad(a);
        let sc = sin_cos(a);
        let es = (sc.sin.to_num::<f64>() - x.sin()).abs();
        let ec = (sc.cos.to_num::<f64>() - x.cos()).abs();
        assert_eq!(sc.sin, sin(a));
        assert_eq!(sc.cos, cos(a));
        worst = worst.max(es).max(ec);
    };
    for k in 0u32..(1 << 22) {
        check((k << 10) | 0x1A5);
    }
    for k in 0u32..512 {
        check(k << 23);
    }
    eprintln!("trig: worst |error| {worst:e} (bound {TRIG_BOUND:e})");
    assert!(worst <= TRIG_BOUND, "worst sin/cos error {worst:e}");
    assert!(worst > 3.0e-5, "the sweep should find the interpolation error, {worst:e}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    #[test]
    fn trig_error_any_angle(turn in any::<u32>()) {
        let a = ElectricalAngle(turn);
        let x = angle_rad(a);
        let sc = sin_cos(a);
        prop_assert!((sc.sin.to_num::<f64>() - x.sin()).abs() <= TRIG_BOUND);
        prop_assert!((sc.cos.to_num::<f64>() - x.cos()).abs() <= TRIG_BOUND);
    }

    /// Clarke on any three currents within +-2048 A: within 3 LSB (46 uA) of the f64 amplitude-invariant
    /// transform with the zero sequence removed; no panic for any input at all.
    #[test]
    fn clarke_matches_f64(a in -2048.0..2048.0f64, b in -2048.0..2048.0f64, c in -2048.0..2048.0f64,
                          raw in any::<[i32; 3]>()) {
        let got = clarke(Abc::new(amps(a), amps(b), amps(c)));
        let (a, b, c) = (f(amps(a).0), f(amps(b).0), f(amps(c).0));
        let alpha = (2.0 * a - b - c) / 3.0;
        let beta = (b - c) / 3f64.sqrt();
        let lsb = 1.0 / 65536.0;
        prop_assert!((f(got.alpha.0) - alpha).abs() <= 3.0 * lsb, "alpha {} vs {}", f(got.alpha.0), alpha);
        prop_assert!((f(got.beta.0) - beta).abs() <= 3.0 * lsb, "beta {} vs {}", f(got.beta.0), beta);
        let _ = clarke(Abc::new(Amps::from_bits(raw[0]), Amps::from_bits(raw[1]), Amps::from_bits(raw[2])));
    }

    /// Park and inverse Park of vectors up to 1000 A against f64 at the exact angle: error <= 4.0e-5 x |v| (the
    /// trig bound) x sqrt(2) + 2 LSB. Round trip Park -> inverse Park returns the vector within 2 x that.
    #[test]
    fn park_round_trip(mag in 0.0..1000.0f64, th in 0.0..TAU, turn in any::<u32>()) {
        let v = AlphaBeta::new(amps(mag * th.cos()), amps(mag * th.sin()));
        let a = ElectricalAngle(turn);
        let x = angle_rad(a);
        let sc = sin_cos(a);
        let dq = park(v, sc);
        let (va, vb) = (f(v.alpha.0), f(v.beta.0));
        let d = va * x.cos() + vb * x.sin();
        let q = -va * x.sin() + vb * x.cos();
        let bound = TRIG_BOUND * 2f64.sqrt() * mag + 2.0 / 65536.0;
        prop_assert!((f(dq.d.0) - d).abs() <= bound && (f(dq.q.0) - q).abs() <= bound);
        let back = inverse_park(dq, sc);
        prop_assert!((f(back.alpha.0) - va).abs() <= 2.0 * bound + 2.0 / 65536.0);
        prop_assert!((f(back.beta.0) - vb).abs() <= 2.0 * bound + 2.0 / 65536.0);
    }

    /// Balanced phase currents of the reference plant (|i| <= 16.5 A): Clarke then Park gives the f64 d/q current
    /// within 1 mA (trig bound x 16.5 A + rounding).
    #[test]
    fn clarke_park_on_balanced_currents(mag in 0.0..16.5f64, th in 0.0..TAU, turn in any::<u32>()) {
        let i = Abc::new(
            amps(mag * th.cos()),
            amps(mag * (th - TAU / 3.0).cos()),
            amps(mag * (th + TAU / 3.0).cos()),
        );
        let a = ElectricalAngle(turn);
        let dq = park(clarke(i), sin_cos(a));
        let x = angle_rad(a);
        prop_assert!((f(dq.d.0) - mag * (th - x).cos()).abs() <= 1e-3);
        prop_assert!((f(dq.q.0) - mag * (th - x).sin()).abs() <= 1e-3);
    }

    /// Inverse Clarke returns to the phases (balanced input): within 2 LSB.
    #[test]
    fn inverse_clarke_round_trip(mag in 0.0..100.0f64, th in 0.0..TAU) {
        let i = Abc::new(
            amps(mag * th.cos()),
            amps(mag * (th - TAU / 3.0).cos()),
            amps(mag * (th + TAU / 3.0).cos()),
        );
        let back: Abc<Amps> = inverse_clarke(clarke(i));
        let lsb = 4.0 / 65536.0;
        prop_assert!((f(back.a.0) - f(i.a.0)).abs() <= lsb);
        prop_assert!((f(back.b.0) - f(i.b.0)).abs() <= lsb);
        prop_assert!((f(back.c.0) - f(i.c.0)).abs() <= lsb);
    }
}

/// The line voltages a set of compare values produces on a bus (duty x Vbus per phase).
fn line_voltages(c: Abc<u16>, v_bus: f64) -> [f64; 3] {
    let (a, b, c) = (f64::from(c.a) / T * v_bus, f64::from(c.b) / T * v_bus, f64::from(c.c) / T * v_bus);
    [a - b, b - c, c - a]
}

/// The line voltages of a commanded stator vector (amplitude-invariant: phase = inverse Clarke).
fn commanded_lines(alpha: f64, beta: f64) -> [f64; 3] {
    let a = alpha;
    let b = -alpha / 2.0 + 3f64.sqrt() / 2.0 * beta;
    let c = -alpha / 2.0 - 3f64.sqrt() / 2.0 * beta;
    [a - b, b - c, c - a]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    /// Issue requirement: "SVPWM produces the commanded line voltages within 1 % in the linear range". Linear range
    /// = line-to-neutral amplitude up to Vbus/sqrt(3) (no duty clamp); bus 10..60 V. Bound: 1 % of the commanded
    /// line-to-line amplitude, or 2.5 timer ticks (0.074 % of the bus: the compare values are whole ticks and the
    /// chain rounds three times) where that is larger, i.e. below 7.5 % of the linear range.
    /// `svpwm_line_error_sweep` measures the worst case (2.2 ticks).
    #[test]
    fn svpwm_line_voltages_linear_range(frac in 0.0..0.9995f64, th in 0.0..TAU, v_bus in 10.0..60.0f64) {
        let m = Modulator::new(VoltageLimit::LINEAR, DutyClamp::NONE);
        let r = frac * v_bus / 3f64.sqrt();
        let v = AlphaBeta::new(volts(r * th.cos()), volts(r * th.sin()));
        let bus = volts(v_bus);
        let out = m.modulate(v, bus);
        prop_assert!(!out.saturated);
        let got = line_voltages(out.compare_ticks, f(bus.0));
        let want = commanded_lines(f(v.alpha.0), f(v.beta.0));
        let bound = (0.01 * 3f64.sqrt() * r).max(2.5 * f(bus.0) / T);
        for k in 0..3 {
            prop_assert!((got[k] - want[k]).abs() <= bound, "line {k}: {} vs {}", got[k], want[k]);
        }
    }

    /// With the default duty clamp (94 %), the EPOS4 90 % limit is still fully linear: the clamp only moves the
    /// common mode. Same bound as above, up to the 90 % radius.
    #[test]
    fn svpwm_default_clamp_keeps_epos4_range_linear(frac in 0.0..0.999f64, th in 0.0..TAU, v_bus in 10.0..60.0f64) {
        let m = Modulator::default();
        let r = frac * 0.9 * v_bus / 3f64.sqrt();
        let v = AlphaBeta::new(volts(r * th.cos()), volts(r * th.sin()));
        let bus = volts(v_bus);
        let out = m.modulate(v, bus);
        prop_assert!(!out.saturated);
        let max = out.compare_ticks.a.max(out.compare_ticks.b).max(out.compare_ticks.c);
        prop_assert!(max <= DutyClamp::DEFAULT.max_compare());
        let got = line_voltages(out.compare_ticks, f(bus.0));
        let want = commanded_lines(f(v.alpha.0), f(v.beta.0));
        let bound = (0.01 * 3f64.sqrt() * r).max(2.5 * f(bus.0) / T);
        for k in 0..3 {
            prop_assert!((got[k] - want[k]).abs() <= bound);
        }
    }

    /// "... and saturates gracefully beyond it": a command beyond the limit radius comes out on the radius (to
    /// within 0.1 %, never above it by more than 1e-4 relative plus a tick's worth), at the commanded angle (within
    /// 2 mrad), flagged. (The angle is kept while each axis is within the modulator's +-256 V input range.)
    #[test]
    fn svpwm_saturates_onto_the_circle(frac in 1.002..1000.0f64, th in 0.0..TAU, v_bus in 10.0..60.0f64,
                                        permille in 500u16..=1000) {
        let limit = VoltageLimit::from_permille_of_bus(permille);
        let m = Modulator::new(limit, DutyClamp::NONE);
        let bus = volts(v_bus);
        let radius = f64::from(permille) / 1000.0 * effective_bus(bus, permille) / 3f64.sqrt();
        let r = (frac * radius).min(250.0);
        prop_assume!(r > 1.002 * radius);
        let v = AlphaBeta::new(volts(r * th.cos()), volts(r * th.sin()));
        let out = m.modulate(v, bus);
        prop_assert!(out.saturated);
        // Back from the line voltages to (alpha, beta): alpha = (2 vab + vbc) / 3, beta = vbc / sqrt(3).
        let l = line_voltages(out.compare_ticks, f(bus.0));
        let alpha = (2.0 * l[0] + l[1]) / 3.0;
        let beta = l[1] / 3f64.sqrt();
        let got_r = alpha.hypot(beta);
        let tick = v_bus / T;
        prop_assert!(got_r <= radius * 1.0001 + 1.5 * tick && got_r >= radius * 0.999 - 1.5 * tick, "{got_r} vs {radius}");
        let d_angle = (beta.atan2(alpha) - th + PI).rem_euclid(TAU) - PI;
        prop_assert!(d_angle.abs() <= 2e-3 + 1.5 * tick / radius, "angle off by {d_angle}");
        // The applied vector reported in volts is the same one.
        let applied = m.limited(v, bus);
        let applied_r = f(applied.alpha.0).hypot(f(applied.beta.0));
        prop_assert!(applied_r <= radius * 1.0001 && applied_r >= radius * 0.999, "{applied_r} vs {radius}");
    }

    /// Any input at all: no panic, compare values within 0..=max compare of the clamp.
    #[test]
    fn svpwm_total(alpha in any::<i32>(), beta in any::<i32>(), bus in any::<i32>(), ns in 0u32..30_000) {
        let clamp = DutyClamp::from_min_low_side_ns(ns);
        for limit in [VoltageLimit::EPOS4, VoltageLimit::LINEAR] {
            let m = Modulator::new(limit, clamp);
            let out = m.modulate(AlphaBeta::new(Volts::from_bits(alpha), Volts::from_bits(beta)), Volts::from_bits(bus));
            for c in [out.compare_ticks.a, out.compare_ticks.b, out.compare_ticks.c] {
                prop_assert!(c <= clamp.max_compare());
            }
        }
    }
}

/// A deterministic sweep of the linear range (amplitudes 1 % .. 99.9 % of Vbus/sqrt(3), 720 angles, 24 V and 48 V):
/// the worst line-voltage error in timer ticks, and relative to the amplitude above 10 % of the range.
#[test]
fn svpwm_line_error_sweep() {
    let m = Modulator::new(VoltageLimit::LINEAR, DutyClamp::NONE);
    let (mut worst_ticks, mut worst_rel): (f64, f64) = (0.0, 0.0);
    for v_bus in [24.0, 48.0] {
        let bus = volts(v_bus);
        for step in 1..=999 {
            let frac = f64::from(step) / 1000.0;
            let r = frac * v_bus / 3f64.sqrt();
            for a in 0..720 {
                let th = f64::from(a) / 720.0 * TAU;
                let v = AlphaBeta::new(volts(r * th.cos()), volts(r * th.sin()));
                let got = line_voltages(m.modulate(v, bus).compare_ticks, f(bus.0));
                let want = commanded_lines(f(v.alpha.0), f(v.beta.0));
                for k in 0..3 {
                    let e = (got[k] - want[k]).abs();
                    worst_ticks = worst_ticks.max(e / f(bus.0) * T);
                    if frac >= 0.1 {
                        worst_rel = worst_rel.max(e / (3f64.sqrt() * r));
                    }
                }
            }
        }
    }
    eprintln!("svpwm: worst line error {worst_ticks:.2} ticks; above 10 % of the range {:.3} %", worst_rel * 100.0);
    assert!(worst_ticks <= 2.5 && worst_rel <= 0.01);
}

/// The PI of the reference plant's current loop (0x30A0:01 = 2,073,000 uV/A, 0x30A0:02 = 3,267,000 uV/(A ms):
/// 2 kHz bandwidth on 0.165 mH / 0.26 ohm).
fn plant_gains() -> PiGains {
    PiGains::from_idx_0x30a0(2_073_000, 3_267_000)
}

#[test]
fn pi_does_not_wind_up_and_recovers() {
    // Error of +10 A for 2 s (50,000 samples) against a 10 V limit: the output sits on the limit and the
    // integrator settles at the limit instead of growing (back-calculation, Tt = Ti).
    let limit = volts(10.0);
    let mut pi = PiController::new(plant_gains());
    for _ in 0..50_000 {
        let out = pi.step(amps(10.0), Amps::ZERO, limit);
        assert_eq!(out.voltage, limit);
        assert!(out.saturated);
    }
    let xi = f(pi.integral().0);
    // Steady state of the backward-Euler form: xi + Ki Ts e = u_sat, so xi = 10 V - 1.3068 V.
    assert!((xi - (10.0 - 0.130_68 * 10.0)).abs() < 0.01, "integral {xi}");
    // The error reverses: the output must leave the limit at once (no stored windup to unwind).
    let out = pi.step(Amps::ZERO, amps(1.0), limit);
    assert!(!out.saturated && f(out.voltage.0) < 10.0, "{out:?}");

    // Without anti-windup (Kb = 0) the same history drives the integrator into its +-4096 V clamp, and recovery
    // takes thousands of samples: the comparison the back-calculation is for.
    let mut plain = PiController::new(plant_gains().with_tracking_gain(I1F31::ZERO));
    for _ in 0..50_000 {
        plain.step(amps(10.0), Amps::ZERO, limit);
    }
    assert!(f(plain.integral().0) > 4000.0);
    let mut n = 0;
    while plain.step(Amps::ZERO, amps(1.0), limit).saturated {
        n += 1;
    }
    assert!(n > 1000, "{n}");
}

#[test]
fn pi_tracks_without_saturation() {
    // Constant error, no limit reached: u = Kp e + xi, xi grows by Ki Ts e per sample.
    let mut pi = PiController::new(PiGains::new(I8F24::from_num(2), I8F24::from_num(0.125), I1F31::from_num(0.0625)));
    let out = pi.step(amps(1.0), Amps::ZERO, volts(100.0));
    assert!((f(out.voltage.0) - 2.125).abs() < 1e-4);
    let out = pi.step(amps(1.0), Amps::ZERO, volts(100.0));
    assert!((f(out.voltage.0) - 2.25).abs() < 1e-4);
    assert!((f(pi.integral().0) - 0.25).abs() < 1e-4);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2048))]

    /// The scalar PI never panics, never leaves its limit, and its integrator stays in +-4096 V, for any gains,
    /// inputs and limits.
    #[test]
    fn pi_total(kp in any::<i32>(), ki in any::<i32>(), kb in any::<i32>(),
                steps in proptest::collection::vec((any::<i32>(), any::<i32>(), any::<i32>()), 1..50)) {
        let gains = PiGains::new(I8F24::from_bits(kp), I8F24::from_bits(ki), I1F31::from_bits(kb));
        let mut pi = PiController::new(gains);
        for (r, m, l) in steps {
            let out = pi.step(Amps::from_bits(r), Amps::from_bits(m), Volts::from_bits(l));
            let l = i64::from(l.max(0));
            prop_assert!(i64::from(out.voltage.to_bits()).abs() <= l);
            prop_assert!(pi.integral().to_bits().abs() <= 1 << 28);
        }
    }

    /// The whole current-loop step: never panics for any input; the compare values respect the clamp; the applied
    /// d/q voltage never exceeds the EPOS4 limit 0.9 Vbus / sqrt(3) (bus saturated to [3.85 V, 128 V) inside) by
    /// more than the trig gain error (1e-4 relative).
    #[test]
    fn current_loop_never_panics(raw in any::<[i32; 6]>(), turn in any::<u32>(), bus in any::<i32>(),
                                 p in any::<u32>(), i in any::<u32>(), n in 1usize..20) {
        let mut c = CurrentController::new(CurrentLoopConfig::from_idx_0x30a0(p, i));
        let input = FocInput {
            i_abc: Abc::new(Amps::from_bits(raw[0]), Amps::from_bits(raw[1]), Amps::from_bits(raw[2])),
            angle: ElectricalAngle(turn),
            i_ref: Dq::new(Amps::from_bits(raw[3]), Amps::from_bits(raw[4])),
            v_bus: Volts::from_bits(bus),
        };
        let radius = 0.9 * effective_bus(Volts::from_bits(bus), 900) / 3f64.sqrt();
        for _ in 0..n {
            let out = foc_step(&mut c, &input);
            let max = out.compare_ticks.a.max(out.compare_ticks.b).max(out.compare_ticks.c);
            prop_assert!(max <= DutyClamp::DEFAULT.max_compare());
            let applied = f(out.v_dq.d.0).hypot(f(out.v_dq.q.0));
            prop_assert!(applied <= radius * 1.0001 + 1e-4, "{applied} > {radius}");
            prop_assert!(out.saturated || applied <= radius * 1.0001);
        }
    }

    /// With the voltage limit active, the applied vector is on the EPOS4 circle (99.9 % .. 100 % of it) and the
    /// compare values reproduce it through the bus: line voltages within 1 % of those of v_dq rotated by the angle.
    #[test]
    fn current_loop_limits_at_90_percent(turn in any::<u32>(), v_bus in 10.0..60.0f64, iq in 5.0..30.0f64,
                                         id in -30.0..30.0f64) {
        let mut c = CurrentController::new(CurrentLoopConfig::from_idx_0x30a0(2_073_000, 3_267_000));
        let input = FocInput {
            i_abc: Abc::new(Amps::ZERO, Amps::ZERO, Amps::ZERO),
            angle: ElectricalAngle(turn),
            i_ref: Dq::new(amps(id), amps(iq)),
            v_bus: volts(v_bus),
        };
        // Kp e alone exceeds the limit for these errors at these buses only sometimes; a few samples of integral
        // action make sure it does.
        let mut out = foc_step(&mut c, &input);
        for _ in 0..200 {
            out = foc_step(&mut c, &input);
        }
        let bus = f(volts(v_bus).0);
        let radius = 0.9 * effective_bus(volts(v_bus), 900) / 3f64.sqrt();
        prop_assert!(out.saturated);
        let (vd, vq) = (f(out.v_dq.d.0), f(out.v_dq.q.0));
        let applied = vd.hypot(vq);
        prop_assert!(applied <= radius * 1.0001 && applied >= radius * 0.999, "{applied} vs {radius}");
        let x = angle_rad(input.angle);
        let (alpha, beta) = (vd * x.cos() - vq * x.sin(), vd * x.sin() + vq * x.cos());
        let got = line_voltages(out.compare_ticks, bus);
        let want = commanded_lines(alpha, beta);
        for k in 0..3 {
            prop_assert!((got[k] - want[k]).abs() <= 0.01 * 3f64.sqrt() * radius, "line {k}: {} vs {}", got[k], want[k]);
        }
    }
}

/// Closed loop on an f64 model of the reference motor's electrical part at standstill (R = 0.26 ohm,
/// L = 0.165 mH, Ld = Lq, no back-EMF), one PWM period of transport delay, gains for a 1 kHz bandwidth
/// (Kp = L wc = 1.037 V/A, Ki = R wc = 1634 V/(A s)): a 3 A q-current step settles to within 1 % in 2 ms with at
/// most 20 % overshoot, and d stays near 0.
#[test]
fn current_loop_closes_on_an_rl_load() {
    let (r, l, ts): (f64, f64, f64) = (0.26, 0.165e-3, 40e-6);
    let mut c = CurrentController::new(CurrentLoopConfig::from_idx_0x30a0(1_037_000, 1_634_000));
    let theta = angle_of(1.0);
    let x = angle_rad(theta);
    let (mut i_alpha, mut i_beta) = (0.0f64, 0.0f64);
    let mut applied = (0.0f64, 0.0f64);
    let mut peak: f64 = 0.0;
    let mut last = (0.0, 0.0);
    for k in 0..50 * 25 {
        let ia = i_alpha;
        let ib = -i_alpha / 2.0 + 3f64.sqrt() / 2.0 * i_beta;
        let ic = -i_alpha / 2.0 - 3f64.sqrt() / 2.0 * i_beta;
        let out = foc_step(
            &mut c,
            &FocInput {
                i_abc: Abc::new(amps(ia), amps(ib), amps(ic)),
                angle: theta,
                i_ref: Dq::new(Amps::ZERO, amps(3.0)),
                v_bus: volts(24.0),
            },
        );
        // Transport delay: the voltage computed now is applied during the next period.
        let (va, vb) = applied;
        let l_ab = line_voltages(out.compare_ticks, 24.0);
        applied = ((2.0 * l_ab[0] + l_ab[1]) / 3.0, l_ab[1] / 3f64.sqrt());
        // Exact discretisation of di/dt = (v - R i) / L over one period.
        let a = (-r * ts / l).exp();
        i_alpha = i_alpha * a + va / r * (1.0 - a);
        i_beta = i_beta * a + vb / r * (1.0 - a);
        let iq = -i_alpha * x.sin() + i_beta * x.cos();
        let id = i_alpha * x.cos() + i_beta * x.sin();
        peak = peak.max(iq);
        if k > 50 {
            assert!(id.abs() < 0.3, "id {id} at {k}");
        }
        if k >= 50 {
            // 2 ms after the step.
            assert!((iq - 3.0).abs() < 0.03, "iq {iq} at {k}");
        }
        last = (id, iq);
    }
    assert!((last.1 - 3.0).abs() < 0.03, "iq {}", last.1);
    assert!(last.0.abs() < 0.03, "id {}", last.0);
    assert!(peak < 3.6, "overshoot {peak}");
}
