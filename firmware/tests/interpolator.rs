//! Tests of the cyclic-mode interpolator (`firmware::control::interpolator`): the 0x60C2 period, exact arrival at
//! the master's set-points, feedforward from the stream (constant velocity, constant acceleration, a jerk-limited
//! move against its analytic `f64` trajectory), offsets 0x60B0..0x60B2, CSV/CST linear interpolation, interpolation
//! disabled, missing set-points, and panic-freedom. Units: 4096 inc/rev, one tick = 400 us.
//!
//! The master sends set-point k at time k T; the drive sees it in the first tick at or after that time (push before
//! step). With one period of delay the output at time t follows the master trajectory at t - T.
//!
//! Each test states its bound; measured figures are printed (`--nocapture`).

use firmware::control::interpolator::{
    CyclicInterpolator, CyclicMode, CyclicOutput, CyclicSetpoint, InterpolationPeriod, PeriodError, SetpointStatus,
    DEFAULT_MAX_EXTRAPOLATED_PERIODS,
};
use firmware::control::trajectory::{Acceleration, MotionScale, Velocity};
use proptest::prelude::*;

const Q32: f64 = 4_294_967_296.0;
const Q40: f64 = 1_099_511_627_776.0;
const TICK_US: u64 = 400;

fn v_f(v: Velocity) -> f64 {
    v.to_bits() as f64 / Q32
}
fn a_f(a: Acceleration) -> f64 {
    a.to_bits() as f64 / Q40
}
fn fine(o: &CyclicOutput) -> f64 {
    o.position_fine as f64 / 65_536.0
}
fn csp(p: i32) -> CyclicSetpoint {
    CyclicSetpoint { target_position: p, ..CyclicSetpoint::default() }
}

/// Runs a CSP stream: `points[k]` is sent at time k T (None = lost). Returns the outputs of ticks 0..ticks.
fn run_stream(
    ip: &mut CyclicInterpolator,
    period_us: u64,
    points: &[Option<CyclicSetpoint>],
    ticks: usize,
) -> Vec<CyclicOutput> {
    let mut next = 0usize;
    let mut out = Vec::with_capacity(ticks);
    for n in 0..ticks as u64 {
        while next < points.len() && next as u64 * period_us <= n * TICK_US {
            if let Some(sp) = points[next] {
                ip.push(sp);
            }
            next += 1;
        }
        out.push(ip.step());
    }
    out
}

#[test]
fn period_from_0x60c2() {
    assert_eq!(InterpolationPeriod::from_0x60c2(0, -3), Ok(InterpolationPeriod::DISABLED));
    let ms = InterpolationPeriod::from_0x60c2(1, -3).unwrap();
    assert_eq!(ms.micros(), 1000);
    assert_eq!(ms.whole_ticks(), None); // 2.5 ticks
    assert_eq!(InterpolationPeriod::from_0x60c2(2, -3).unwrap().whole_ticks(), Some(5));
    assert_eq!(InterpolationPeriod::from_0x60c2(4, -4).unwrap().whole_ticks(), Some(1));
    assert_eq!(InterpolationPeriod::from_0x60c2(200, -6), Err(PeriodError::ShorterThanTick { micros: 200 }));
    assert_eq!(InterpolationPeriod::from_0x60c2(250, -6), Err(PeriodError::ShorterThanTick { micros: 250 }));
    assert_eq!(InterpolationPeriod::from_0x60c2(1, 0), Err(PeriodError::UnsupportedIndex(0)));
    assert_eq!(InterpolationPeriod::from_0x60c2(1, -7), Err(PeriodError::UnsupportedIndex(-7)));
    assert_eq!(InterpolationPeriod::from_0x60c2(255, -1).unwrap().micros(), 25_500_000);
    assert!(InterpolationPeriod::from_micros(25_500_001).is_err());
    assert!(!InterpolationPeriod::DISABLED.is_enabled());
}

#[test]
fn constant_velocity_stream_gives_constant_feedforward() {
    for period_us in [1000u64, 2000, 1200, 400] {
        let period = InterpolationPeriod::from_micros(period_us as u32).unwrap();
        let step = 123i32; // inc per period
        let points: Vec<_> = (0..200).map(|k| Some(csp(1000 + step * (k + 1)))).collect();
        // Start already moving at the stream's velocity: seamless from the first tick.
        let v = Velocity::from_bits((f64::from(step) * TICK_US as f64 / period_us as f64 * Q32).round() as i64);
        let mut ip = CyclicInterpolator::new(CyclicMode::Position, period);
        ip.reset(1000, v);
        let out = run_stream(&mut ip, period_us, &points, (199 * period_us / TICK_US) as usize);
        let v_expect = f64::from(step) * TICK_US as f64 / period_us as f64;
        for (n, o) in out.iter().enumerate() {
            assert_eq!(o.acceleration, Acceleration::ZERO, "tick {n}");
            assert!((v_f(o.velocity) - v_expect).abs() < 1e-9, "tick {n}: {}", v_f(o.velocity));
            let x = 1000.0 + f64::from(step) * (n as u64 * TICK_US) as f64 / period_us as f64;
            assert!((fine(o) - x).abs() <= 1.0 / 65_536.0, "tick {n}: {} vs {x}", fine(o));
            if (n as u64 * TICK_US).is_multiple_of(period_us) {
                assert_eq!(o.position as f64, x, "exact at the boundary");
            }
            assert_eq!(o.status, SetpointStatus::Following);
        }
        // From rest: after two periods of warm-up the feedforward is constant too.
        let mut ip = CyclicInterpolator::new(CyclicMode::Position, period);
        ip.reset(1000, Velocity::ZERO);
        let points: Vec<_> = (0..200).map(|k| Some(csp(1000 + step * k))).collect();
        let out = run_stream(&mut ip, period_us, &points, (199 * period_us / TICK_US) as usize);
        // Velocity: three periods (the BDF2 slopes); acceleration: nine (the least-squares window).
        let warm = (3 * period_us).div_ceil(TICK_US) as usize;
        for o in &out[warm..] {
            assert!((v_f(o.velocity) - v_expect).abs() < 1e-9);
        }
        let warm = (9 * period_us).div_ceil(TICK_US) as usize;
        for o in &out[warm..] {
            assert_eq!(o.acceleration, Acceleration::ZERO);
        }
    }
}

#[test]
fn constant_acceleration_stream_gives_constant_acceleration() {
    // P_k = k² (inc): acceleration 2 inc per period², exactly reproduced by the BDF2 slopes and the cubic.
    let period_us = 2000u64; // 5 ticks
    let points: Vec<_> = (0..100).map(|k| Some(csp(k * k))).collect();
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(2000).unwrap());
    let out = run_stream(&mut ip, period_us, &points, 400);
    let a_expect = 2.0 / 25.0; // inc/tick²
    for (n, o) in out.iter().enumerate().skip(15) {
        // The acceleration feedforward (a 9-point least-squares fit) is exact once nine stream points exist.
        if n >= 40 {
            assert!((a_f(o.acceleration) - a_expect).abs() < 1e-9, "tick {n}");
        }
        // Lag of one period: x(t) = (t/T - 1)².
        let s = n as f64 / 5.0 - 1.0;
        assert!((fine(o) - s * s).abs() <= 1.0 / 65_536.0, "tick {n}");
        assert!((v_f(o.velocity) - 2.0 * s / 5.0).abs() < 1e-9);
    }
}

/// A sin² move from rest in f64: peak acceleration `a` (inc/s²), profile velocity `v` (inc/s), distance `d`.
/// Returns (x, v, a) at time t (s) and the total time.
struct Sin2Move {
    d: f64,
    vp: f64,
    tr: f64,
    tc: f64,
}

impl Sin2Move {
    fn new(d: f64, v: f64, a: f64) -> Self {
        let am = a / 2.0;
        let ramps = v * v / am;
        let vp = if d >= ramps { v } else { (d * am).sqrt() };
        let tr = vp / am;
        let tc = (d - vp * tr) / vp;
        Self { d, vp, tr, tc }
    }
    fn total(&self) -> f64 {
        2.0 * self.tr + self.tc
    }
    /// Ramp 0 -> vp over tr: shape functions.
    fn ramp(&self, tau: f64) -> (f64, f64, f64) {
        use std::f64::consts::PI;
        let u = tau / self.tr;
        let x = self.vp * self.tr * (u * u / 2.0 - (PI * u).sin().powi(2) / (2.0 * PI * PI));
        let v = self.vp * (u - (2.0 * PI * u).sin() / (2.0 * PI));
        let a = self.vp / self.tr * 2.0 * (PI * u).sin().powi(2);
        (x, v, a)
    }
    fn at(&self, t: f64) -> (f64, f64, f64) {
        if t <= 0.0 {
            (0.0, 0.0, 0.0)
        } else if t < self.tr {
            self.ramp(t)
        } else if t < self.tr + self.tc {
            (self.vp * self.tr / 2.0 + self.vp * (t - self.tr), self.vp, 0.0)
        } else if t < self.total() {
            let (x, v, a) = self.ramp(self.total() - t);
            (self.d - x, v, -a)
        } else {
            (self.d, 0.0, 0.0)
        }
    }
}

/// Runs the move as a 1 ms.. stream; returns the max errors of position (integer, fine), velocity FF (inc/tick) and
/// acceleration FF (inc/tick²) against the analytic trajectory one period earlier.
/// The jerk-limited move of the issue: 10 revolutions (40,960 inc) at up to 3,000 rpm and 20,000 rpm/s.
fn jerk_limited_figures(period_us: u64, move_: &Sin2Move) -> (f64, f64, f64, f64) {
    let t_period = period_us as f64 * 1e-6;
    let count = (move_.total() / t_period).ceil() as i64 + 3;
    let points: Vec<_> = (0..=count).map(|k| Some(csp(move_.at(k as f64 * t_period).0.round() as i32))).collect();
    let mut ip =
        CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(period_us as u32).unwrap());
    let ticks = ((count as u64 + 2) * period_us / TICK_US) as usize;
    let out = run_stream(&mut ip, period_us, &points, ticks);
    let (mut e_pos, mut e_fine, mut e_vel, mut e_acc) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let ts = TICK_US as f64 * 1e-6;
    for (n, o) in out.iter().enumerate() {
        let t = n as f64 * ts - t_period;
        let (x, v, a) = move_.at(t);
        e_pos = e_pos.max((o.position as f64 - x).abs());
        e_fine = e_fine.max((fine(o) - x).abs());
        e_vel = e_vel.max((v_f(o.velocity) - v * ts).abs());
        e_acc = e_acc.max((a_f(o.acceleration) - a * ts * ts).abs());
    }
    assert_eq!(out.last().unwrap().position, 40_960);
    (e_pos, e_fine, e_vel, e_acc)
}

#[test]
fn jerk_limited_move_is_reproduced() {
    let s = MotionScale::new(4096);
    let v = s.velocity_from_rpm(3000).to_inc_per_s() as f64;
    let a = s.acceleration_from_rpm_per_s(20_000).to_inc_per_s2() as f64;
    let m = Sin2Move::new(40_960.0, v, a);
    println!(
        "move: vp {:.1} inc/s ({:.0} rpm), ramp {:.4} s, total {:.4} s",
        m.vp,
        m.vp * 60.0 / 4096.0,
        m.tr,
        m.total()
    );
    // Also a longer move that reaches 3000 rpm and cruises.
    let long = Sin2Move::new(409_600.0, v, a);
    for period_us in [1000u64, 2000, 4000] {
        let (e_pos, e_fine, e_vel, e_acc) = jerk_limited_figures(period_us, &m);
        println!(
            "T = {period_us} us: max |position - x(t-T)| {e_pos:.3} inc (fine {e_fine:.3}), velocity FF {e_vel:.4} inc/tick \
             ({:.1} rpm), acceleration FF {e_acc:.4} inc/tick² ({:.0} rpm/s)",
            e_vel * 2500.0 * 60.0 / 4096.0,
            e_acc * 2500.0 * 2500.0 * 60.0 / 4096.0
        );
        // Bound: the master's integer rounding (0.5 inc) plus the output rounding (0.5 inc).
        assert!(e_pos <= 1.5, "position error {e_pos}");
        assert!(e_fine <= 0.75, "fine position error {e_fine}");
        // Velocity feedforward: the BDF2 rounding noise is <= 2 inc per period.
        assert!(e_vel <= 2.0 * TICK_US as f64 / period_us as f64 + 0.05, "velocity error {e_vel}");
        // Acceleration feedforward: the fit's lag of three periods times the peak jerk (pi A / Tr), plus 0.015
        // inc/tick² of rounding noise and fit bias (7 % of the peak 0.218 inc/tick²).
        let ts = TICK_US as f64 * 1e-6;
        let jerk = std::f64::consts::PI * (2.0 * m.vp / m.tr) / m.tr * ts * ts * ts; // inc/tick³
        let lag = 3.0 * period_us as f64 / TICK_US as f64;
        assert!(e_acc <= 0.015 + jerk * lag, "acceleration error {e_acc} (lag part {})", jerk * lag);
    }
    let long_fig = {
        let t_period = 1e-3;
        let count = (long.total() / t_period).ceil() as i64 + 3;
        let points: Vec<_> = (0..=count).map(|k| Some(csp(long.at(k as f64 * t_period).0.round() as i32))).collect();
        let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(1000).unwrap());
        let out = run_stream(&mut ip, 1000, &points, ((count as u64 + 2) * 1000 / TICK_US) as usize);
        let mut e: f64 = 0.0;
        for (n, o) in out.iter().enumerate() {
            e = e.max((fine(o) - long.at(n as f64 * 4e-4 - 1e-3).0).abs());
        }
        assert_eq!(out.last().unwrap().position, 409_600);
        e
    };
    println!("100 rev at 3000 rpm, T = 1 ms: max fine position error {long_fig:.3} inc");
    assert!(long_fig <= 0.75);
}

#[test]
fn boundary_ticks_land_exactly_on_setpoints() {
    // 1 ms: every second boundary falls on a tick (t = 2 ms = 5 ticks).
    let points: Vec<_> = (0..50).map(|k| Some(csp((k * k * 37 - k * 1001) % 10_007))).collect();
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(1000).unwrap());
    let out = run_stream(&mut ip, 1000, &points, 100);
    for (n, o) in out.iter().enumerate() {
        let t = n as u64 * TICK_US;
        if t.is_multiple_of(1000) && t >= 1000 {
            let k = (t / 1000 - 1) as usize;
            assert_eq!(o.position, i64::from(points[k].unwrap().target_position), "tick {n}");
            assert_eq!(o.position_fine, i64::from(points[k].unwrap().target_position) << 16);
        }
    }
}

#[test]
fn missing_setpoints_extrapolate_then_hold() {
    assert_eq!(DEFAULT_MAX_EXTRAPOLATED_PERIODS, 1);
    let period_us = 1000u64;
    let period = InterpolationPeriod::from_micros(1000).unwrap();
    let all: Vec<_> = (0..60).map(|k| Some(csp(50 * k))).collect();
    let mut reference = CyclicInterpolator::new(CyclicMode::Position, period);
    let ref_out = run_stream(&mut reference, period_us, &all, 140);

    // One lost set-point (k = 10) is bridged exactly: the stream has constant velocity.
    let mut one = all.clone();
    one[10] = None;
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, period);
    let out = run_stream(&mut ip, period_us, &one, 140);
    let mut extrapolated = 0;
    for (n, (a, b)) in out.iter().zip(&ref_out).enumerate() {
        assert_eq!(a.position_fine, b.position_fine, "tick {n}");
        assert_eq!(a.velocity, b.velocity);
        assert!(!a.setpoint_missing());
        if a.status == (SetpointStatus::Extrapolating { periods: 1 }) {
            extrapolated += 1;
        }
    }
    assert!((2..=3).contains(&extrapolated), "{extrapolated} ticks extrapolated");

    // Two consecutive lost set-points (k = 20, 21): extrapolate one period, then hold and flag.
    let mut two = all.clone();
    two[20] = None;
    two[21] = None;
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, period);
    let out = run_stream(&mut ip, period_us, &two, 140);
    // Boundary 21 is at 21 ms = tick 52.5 -> first tick 53; the hold lasts until boundary 22 (tick 55).
    let hold_ticks: Vec<_> = out.iter().enumerate().filter(|(_, o)| o.setpoint_missing()).map(|(n, _)| n).collect();
    assert_eq!(hold_ticks, vec![53, 54]);
    // Held where the extrapolation ended: P_20 = 1000, reached at boundary 21 (the one-period lag).
    for &n in &hold_ticks {
        let o = out[n];
        assert_eq!(o.position_fine, 1000 << 16);
        assert_eq!(o.velocity, Velocity::ZERO);
        assert_eq!(o.acceleration, Acceleration::ZERO);
    }
    assert_eq!(out[51].status, SetpointStatus::Extrapolating { periods: 1 });
    assert_eq!(out[55].status, SetpointStatus::Following);
    // When the stream ends for good, the flag stays.
    let last = run_stream(&mut ip, period_us, &[], 10).last().copied().unwrap();
    assert!(last.setpoint_missing());
    println!("hold ticks {hold_ticks:?}, extrapolated ticks with one loss: {extrapolated}");

    // With a limit of 0 the first missing period holds at once.
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, period).with_extrapolation_limit(0);
    let out = run_stream(&mut ip, period_us, &one, 30);
    assert!(out[25].setpoint_missing());
}

#[test]
fn offsets_are_applied() {
    let s = MotionScale::new(4096);
    let vo = s.velocity_from_rpm(100);
    let points: Vec<_> = (0..20)
        .map(|k| {
            Some(CyclicSetpoint {
                target_position: 10 * k,
                position_offset: 5_000,
                velocity_offset: vo,
                torque_offset: -123,
                ..CyclicSetpoint::default()
            })
        })
        .collect();
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(2000).unwrap());
    ip.reset(5_000, Velocity::ZERO);
    let out = run_stream(&mut ip, 2000, &points, 80);
    for (n, o) in out.iter().enumerate().skip(15) {
        let x = 5_000.0 + 10.0 * (n as f64 / 5.0 - 1.0);
        assert!((fine(o) - x).abs() < 1e-4, "tick {n}");
        assert!((v_f(o.velocity) - (2.0 + v_f(vo))).abs() < 1e-9);
        assert_eq!(o.torque, -123);
    }
}

#[test]
fn csv_interpolates_velocity_linearly() {
    let period = InterpolationPeriod::from_micros(1000).unwrap();
    let mut ip = CyclicInterpolator::new(CyclicMode::Velocity, period);
    ip.reset(0, Velocity::ZERO);
    let vo = Velocity::from_inc_per_tick(1);
    let points: Vec<_> = (0..40)
        .map(|k| {
            Some(CyclicSetpoint {
                target_velocity: Velocity::from_inc_per_tick(k),
                velocity_offset: vo,
                torque_offset: 7,
                ..CyclicSetpoint::default()
            })
        })
        .collect();
    let out = run_stream(&mut ip, 1000, &points, 90);
    let mut integral = 0.0;
    let mut prev_v = 0.0;
    for (n, o) in out.iter().enumerate() {
        let t = n as f64 * 0.4; // ms
                                // Segment [V_{k-1}, V_k] during [kT, (k+1)T], V_k = k + 1 (with the offset); V_{-1} = 0 (reset).
        let expect = t;
        assert!((v_f(o.velocity) - expect).abs() < 1e-6, "tick {n}: {} vs {expect}", v_f(o.velocity));
        if n > 0 {
            assert!((a_f(o.acceleration) - 0.4).abs() < 1e-9, "slope 1 inc/tick per ms = 0.4 inc/tick²");
        }
        integral += (prev_v + v_f(o.velocity)) / 2.0;
        prev_v = v_f(o.velocity);
        assert!((fine(o) - integral).abs() < 1e-4);
        assert_eq!(o.torque, 7);
    }
    // Missing (the stream stops after 36 ms): keep the last velocity one period, then ramp to zero over a period
    // and flag.
    let more = run_stream(&mut ip, 1000, &[], 10);
    assert_eq!(more[0].velocity, Velocity::from_inc_per_tick(36));
    assert_eq!(more[2].velocity, Velocity::from_inc_per_tick(36));
    assert_eq!(more[0].status, SetpointStatus::Extrapolating { periods: 1 });
    assert!(more[9].setpoint_missing());
    assert_eq!(more[9].velocity, Velocity::ZERO);
}

#[test]
fn cst_interpolates_torque_linearly() {
    let mut ip = CyclicInterpolator::new(CyclicMode::Torque, InterpolationPeriod::from_micros(2000).unwrap());
    ip.reset(77, Velocity::ZERO);
    let points: Vec<_> = (0..10)
        .map(|k| {
            Some(CyclicSetpoint { target_torque: (100 * k) as i16, torque_offset: 10, ..CyclicSetpoint::default() })
        })
        .collect();
    let out = run_stream(&mut ip, 2000, &points, 50);
    for (n, o) in out.iter().enumerate() {
        // Segment [Q_{k-1}, Q_k] during [kT, (k+1)T]: Q_k = 100 k + 10, Q_{-1} = 0.
        let s = n as f64 / 5.0;
        let expect = if s < 1.0 { 10.0 * s } else { 100.0 * (s - 1.0) + 10.0 };
        assert!((f64::from(o.torque) - expect).abs() <= 0.5, "tick {n}: {} vs {expect}", o.torque);
        assert_eq!(o.position, 77);
        assert_eq!(o.velocity, Velocity::ZERO);
    }
}

#[test]
fn disabled_interpolation_applies_next_tick_and_holds() {
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::DISABLED);
    ip.reset(3, Velocity::ZERO);
    assert_eq!(ip.step().position, 3);
    assert_eq!(ip.step().status, SetpointStatus::Waiting);
    ip.push(CyclicSetpoint { target_position: 500, position_offset: 1, ..CyclicSetpoint::default() });
    let o = ip.step();
    assert_eq!(o.position, 501);
    assert_eq!(o.velocity, Velocity::ZERO);
    for _ in 0..10 {
        let o = ip.step();
        assert_eq!(o.position, 501);
        assert!(!o.setpoint_missing());
    }
}

#[test]
fn waiting_until_the_first_setpoint() {
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(1000).unwrap());
    ip.reset(-42, Velocity::ZERO);
    for _ in 0..5 {
        let o = ip.step();
        assert_eq!(o.position, -42);
        assert_eq!(o.status, SetpointStatus::Waiting);
        assert!(!o.setpoint_missing());
    }
}

/// The segment `j` of the documented polynomial (played from boundary j, ending at `P_j`), `p[-1] = p[-2] = p[-3]
/// = x0` (reset at rest at x0): `(x_a, M_a, k2, k3, sum of the Savitzky-Golay products)`, exact.
fn segment(points: &[i64], x0: i64, j: usize) -> (i128, i128, i128, i128, i128) {
    let at = |i: isize| -> i128 {
        if i < 0 {
            i128::from(x0)
        } else {
            i128::from(points[i as usize])
        }
    };
    let j = j as isize;
    let (xb, xa, xp, xq) = (at(j), at(j - 1), at(j - 2), at(j - 3));
    let mb = 3 * xb - 4 * xa + xp;
    let ma = if j == 0 { 0 } else { 3 * xa - 4 * xp + xq };
    let d = xb - xa;
    let w = [28i128, 7, -8, -17, -20, -17, -8, 7, 28];
    let sg: i128 = (0..9).map(|i| w[i] * at(j - 8 + i as isize)).sum();
    (xa, ma, 6 * d - 2 * ma - mb, -4 * d + ma + mb, sg)
}

/// The documented polynomial at `s` master microseconds into segment `j`, exactly up to the final f64 division:
/// (position, velocity in inc/tick, Savitzky-Golay acceleration in inc/tick²).
fn reference(points: &[i64], x0: i64, period_us: i64, j: usize, s: i64) -> (f64, f64, f64) {
    let (xa, ma, k2, k3, sg) = segment(points, x0, j);
    let (t, s) = (i128::from(period_us), i128::from(s));
    // 2 T³ (p - x_a) = M_a s T² + k2 s² T + k3 s³.
    let num = ma * s * t * t + k2 * s * s * t + k3 * s * s * s;
    let x = xa as f64 + num as f64 / (2 * t * t * t) as f64;
    let dnum = ma * t * t + 2 * k2 * s * t + 3 * k3 * s * s;
    let v = dnum as f64 / (2 * t * t * t) as f64 * TICK_US as f64;
    let a = sg as f64 / 462.0 * (TICK_US as f64 / period_us as f64).powi(2);
    (x, v, a)
}

/// Random streams (smooth with random acceleration, and jerky) at periods with a non-dyadic tick/period ratio and
/// very long ones, against the exact polynomial: the fixed-point evaluation stays within its stated precision.
/// Position (Q16): 0.5 for the output rounding, 0.05 for the Horner steps, plus the fraction's error (below
/// 2^-32 of the period) times the segment's slope. Velocity (Q32 inc/tick): 1.5 for the rounding of the
/// coefficients and the Horner steps, plus the fraction's error times the derivative. Acceleration (Q40): 1 plus
/// 2^-44 relative (the precomputed scale).
#[test]
fn fixed_point_matches_the_exact_polynomial() {
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let (mut worst_x, mut worst_v, mut worst_a) = (0.0f64, 0.0f64, 0.0f64);
    for period_us in [400i64, 480, 600, 1000, 1100, 2000, 3000, 123_457, 999_999, 25_500_000] {
        for trial in 0..6 {
            let jerky = trial % 2 == 1;
            let x0 = (rnd() % 2_000_001) as i64 - 1_000_000;
            let mut x = x0;
            let mut v = 0i64;
            let scale = [1i64, 100, 10_000][trial / 2];
            let points: Vec<i64> = (0..24)
                .map(|_| {
                    if jerky {
                        x += (rnd() % 2001) as i64 - 1000;
                    } else {
                        v += (rnd() % 21) as i64 - 10;
                        x += v * scale / 10;
                    }
                    x
                })
                .collect();
            let sps: Vec<_> = points.iter().map(|&p| Some(csp(p as i32))).collect();
            let period = InterpolationPeriod::from_micros(period_us as u32).unwrap();
            let mut ip = CyclicInterpolator::new(CyclicMode::Position, period);
            ip.reset(x0, Velocity::ZERO);
            // At most 200 ticks per period are checked: the first 100 and the last 100.
            let ticks = (points.len() as u64 * period_us as u64 / TICK_US) as usize;
            let mut next = 0usize;
            for n in 0..ticks {
                let t = n as i64 * TICK_US as i64;
                while next < sps.len() && next as i64 * period_us <= t {
                    ip.push(sps[next].unwrap());
                    next += 1;
                }
                let o = ip.step();
                let (j, s) = ((t / period_us) as usize, t % period_us);
                if j >= points.len() || (s / TICK_US as i64 > 100 && (period_us - s) / TICK_US as i64 > 100) {
                    continue;
                }
                let (xr, vr, ar) = reference(&points, x0, period_us, j, s);
                // The fraction u = s / T is within 2^-32 of its value: bounds from the largest slope dp/du (inc)
                // and dv/du (inc/tick) over the segment.
                let (xa, ma, k2, k3, _) = segment(&points, x0, j);
                let slope = (ma.abs() + 2 * k2.abs() + 3 * k3.abs()) as f64 / 2.0;
                let dv_du = (k2.abs() + 3 * k3.abs()) as f64 * TICK_US as f64 / period_us as f64;
                let ex = (fine(&o) - xr).abs() * 65_536.0;
                let bound_x = 0.55 + slope * 65_536.0 / 4_294_967_296.0;
                assert!(ex <= bound_x, "T {period_us} trial {trial} tick {n}: {ex} > {bound_x} Q16");
                let ev = (v_f(o.velocity) - vr).abs() * Q32;
                let bound_v = 1.5 + dv_du;
                assert!(ev <= bound_v, "T {period_us} trial {trial} tick {n}: velocity {ev} > {bound_v} Q32");
                let ea = (a_f(o.acceleration) - ar).abs() * Q40;
                let bound_a = 1.0 + ar.abs() * Q40 / 17_592_186_044_416.0;
                assert!(ea <= bound_a, "T {period_us} trial {trial} tick {n}: acceleration {ea} > {bound_a} Q40");
                worst_x = worst_x.max(ex);
                worst_v = worst_v.max(ev);
                worst_a = worst_a.max(ea);
                if s == 0 {
                    assert_eq!(i128::from(o.position_fine), xa << 16, "exact at the boundary");
                }
            }
        }
    }
    println!("worst |position - exact| {worst_x:.3} Q16, velocity {worst_v:.3} Q32, acceleration {worst_a:.3} Q40");
}

/// The envelope of the velocity feedforward reaches 2^28 inc/tick (0.67 x 10^12 inc/s): a constant-velocity stream
/// at that speed (one step of 2^28 inc per 400 us period) gives it exactly, and set-points at the ends of the i32
/// range with offsets land exactly at the boundaries.
#[test]
fn envelope_extremes() {
    let period = InterpolationPeriod::from_micros(400).unwrap();
    let step = 1i64 << 28;
    let start = i64::from(i32::MIN) + 1000;
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, period);
    ip.reset(start, Velocity::from_bits(step << 32));
    for k in 1..15 {
        let p = start + k * step;
        ip.push(csp(p as i32));
        let o = ip.step();
        assert_eq!(o.position, p - step, "one period late");
        assert_eq!(o.velocity, Velocity::from_bits(step << 32));
        assert_eq!(o.acceleration, Acceleration::ZERO);
    }
    // The extremes of 0x607A + 0x60B0 (+-2^32), alternating: exact at every boundary, no panic between.
    let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(1000).unwrap());
    let extremes = [(i32::MAX, i32::MAX), (i32::MIN, i32::MIN), (i32::MAX, i32::MIN), (i32::MIN, i32::MAX)];
    let points: Vec<_> = (0..40)
        .map(|k| {
            let (p, o) = extremes[k % 4];
            Some(CyclicSetpoint { target_position: p, position_offset: o, ..CyclicSetpoint::default() })
        })
        .collect();
    let out = run_stream(&mut ip, 1000, &points, 100);
    for (n, o) in out.iter().enumerate() {
        let t = n as u64 * TICK_US;
        if t.is_multiple_of(1000) && t >= 1000 {
            let sp = points[(t / 1000 - 1) as usize].unwrap();
            let expect = i64::from(sp.target_position) + i64::from(sp.position_offset);
            assert_eq!(o.position, expect, "tick {n}");
            assert_eq!(o.position_fine, expect << 16);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// Random integer streams at random periods: no panic, and every boundary that falls on a tick lands exactly on
    /// the set-point (one period late).
    #[test]
    fn random_streams_exact_at_boundaries(
        period_us in prop::sample::select(vec![400u64, 500, 800, 1000, 1200, 2000, 3000, 4000, 10_000]),
        steps in proptest::collection::vec(-3000i32..3000, 2..60),
        start in -1_000_000i32..1_000_000,
        offset in -1000i32..1000,
    ) {
        let mut p = start;
        let points: Vec<_> = steps.iter().map(|d| { p += d; Some(CyclicSetpoint { target_position: p, position_offset: offset, ..CyclicSetpoint::default() }) }).collect();
        let mut ip = CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::from_micros(period_us as u32).unwrap());
        ip.reset(i64::from(start), Velocity::ZERO);
        let ticks = ((points.len() as u64 + 1) * period_us / TICK_US) as usize;
        let out = run_stream(&mut ip, period_us, &points, ticks);
        for (n, o) in out.iter().enumerate() {
            let t = n as u64 * TICK_US;
            if t.is_multiple_of(period_us) && t >= period_us {
                let k = (t / period_us - 1) as usize;
                if k < points.len() {
                    let sp = points[k].unwrap();
                    prop_assert_eq!(o.position, i64::from(sp.target_position + sp.position_offset));
                }
            }
        }
    }

    /// Any values at all, any mode and period, lost set-points: no panic.
    #[test]
    fn no_panic_any_input(
        mode in prop::sample::select(vec![CyclicMode::Position, CyclicMode::Velocity, CyclicMode::Torque]),
        micros in prop_oneof![Just(0u32), 400u32..=25_500_000],
        reset in (any::<i64>(), any::<i64>()),
        sps in proptest::collection::vec((any::<bool>(), any::<i32>(), any::<i64>(), any::<i16>(), any::<i32>(), any::<i64>(), any::<i16>()), 1..20),
        limit in any::<u8>(),
    ) {
        let period = InterpolationPeriod::from_micros(micros).unwrap();
        let mut ip = CyclicInterpolator::new(mode, period).with_extrapolation_limit(limit);
        ip.reset(reset.0, Velocity::from_bits(reset.1));
        for (present, p, v, q, po, vo, qo) in sps {
            if present {
                ip.push(CyclicSetpoint {
                    target_position: p, target_velocity: Velocity::from_bits(v), target_torque: q,
                    position_offset: po, velocity_offset: Velocity::from_bits(vo), torque_offset: qo,
                });
            }
            for _ in 0..7 {
                ip.step();
            }
        }
    }
}
