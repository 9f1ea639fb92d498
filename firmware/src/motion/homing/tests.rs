//! Homing against a kinematic test axis: the position follows the demand (exactly or with a first-order lag),
//! switches, index pulses and end stops sit at known physical positions, and every edge is latched at the exact
//! crossing of the continuous path. The expected references are written down per method from the CiA 402
//! definitions and the geometry (not from the catalogue in `methods.rs`), so a wrong edge, a wrong index or a wrong
//! direction fails.

use super::*;
use crate::cia402::Ticks;
use crate::sensors::latch::EdgeLatch;

const PITCH: i64 = 4096;
/// Controlword "enable operation" (0x000F), + bit 4, + bit 8.
const ENABLED: u16 = 0x000F;
const START: u16 = 0x001F;
const HALT: u16 = 0x0100;

/// The home switch layout in physical increments.
#[derive(Clone, Copy, Debug)]
enum Home {
    None,
    /// Active above the edge (positive home switch, methods 3, 4, 19, 20).
    Above(i64),
    /// Active below the edge (negative home switch, methods 5, 6, 21, 22).
    Below(i64),
    /// Active between the two edges (methods 7-14, 23-30).
    Band(i64, i64),
}

#[derive(Clone, Copy, Debug)]
struct Geometry {
    /// Negative limit switch: active below.
    negative_limit: Option<i64>,
    /// Positive limit switch: active above.
    positive_limit: Option<i64>,
    home: Home,
    /// Index pulses at `phase + n 4096`; `None`: no index.
    index_phase: Option<i64>,
    negative_stop: Option<i64>,
    positive_stop: Option<i64>,
}

const NLS: i64 = -20_000;
const PLS: i64 = 20_000;
const PHASE: i64 = 1234;
const EDGE: i64 = 3000;
const BAND: (i64, i64) = (2000, 10_000);
const STOP: i64 = 18_000;

fn geometry(home: Home) -> Geometry {
    Geometry {
        negative_limit: Some(NLS),
        positive_limit: Some(PLS),
        home,
        index_phase: Some(PHASE),
        negative_stop: None,
        positive_stop: None,
    }
}

fn stops() -> Geometry {
    Geometry {
        negative_limit: None,
        positive_limit: None,
        home: Home::None,
        index_phase: Some(PHASE),
        negative_stop: Some(-STOP),
        positive_stop: Some(STOP),
    }
}

/// A boundary of a switch: the switch needs `x > b` (`above`) or `x < b` there.
#[derive(Clone, Copy, Debug)]
struct Boundary {
    b: i64,
    above: bool,
}

impl Boundary {
    fn holds(self, x: f64) -> bool {
        if self.above {
            x > self.b as f64
        } else {
            x < self.b as f64
        }
    }
}

struct TestAxis {
    geo: Geometry,
    /// Physical position, increments.
    x: f64,
    /// Reported coordinates = physical + offset (the rereferences shift it).
    offset: i64,
    /// 0: follows the demand exactly; else the fraction of the error left after each tick.
    lag: f64,
    /// mA per increment of following error (the position loop pushing against a stop).
    current_per_inc: f64,
    /// mA per inc/tick² of demand acceleration.
    current_per_acc: f64,
    current_ma: i32,
    velocity: f64,
    negative_limit: SwitchEdges,
    positive_limit: SwitchEdges,
    home_switch: SwitchEdges,
    index: EdgeLatch,
    now: u32,
}

impl TestAxis {
    fn new(geo: Geometry, x: f64) -> Self {
        let mut axis = Self {
            geo,
            x,
            offset: 0,
            lag: 0.0,
            current_per_inc: 1.0,
            current_per_acc: 0.0,
            current_ma: 0,
            velocity: 0.0,
            negative_limit: SwitchEdges::default(),
            positive_limit: SwitchEdges::default(),
            home_switch: SwitchEdges::default(),
            index: EdgeLatch::default(),
            now: 0,
        };
        axis.negative_limit.active = axis.level(&axis.boundaries(0), x);
        axis.positive_limit.active = axis.level(&axis.boundaries(1), x);
        axis.home_switch.active = axis.level(&axis.boundaries(2), x);
        axis
    }

    fn boundaries(&self, switch: usize) -> Vec<Boundary> {
        match switch {
            0 => self.geo.negative_limit.map(|b| Boundary { b, above: false }).into_iter().collect(),
            1 => self.geo.positive_limit.map(|b| Boundary { b, above: true }).into_iter().collect(),
            _ => match self.geo.home {
                Home::None => vec![],
                Home::Above(e) => vec![Boundary { b: e, above: true }],
                Home::Below(e) => vec![Boundary { b: e, above: false }],
                Home::Band(lo, hi) => vec![Boundary { b: lo, above: true }, Boundary { b: hi, above: false }],
            },
        }
    }

    fn level(&self, boundaries: &[Boundary], x: f64) -> bool {
        !boundaries.is_empty() && boundaries.iter().all(|b| b.holds(x))
    }

    fn reported(&self, physical: i64) -> i32 {
        physical.wrapping_add(self.offset) as i32
    }

    fn feedback(&self) -> AxisFeedback {
        AxisFeedback {
            now: Ticks(self.now),
            position: self.reported(self.x.round() as i64),
            velocity: Velocity((self.velocity * 4_294_967_296.0) as i64),
            current_average_ma: self.current_ma,
            negative_limit: self.negative_limit,
            positive_limit: self.positive_limit,
            home_switch: self.home_switch,
            index: self.index,
        }
    }

    /// One tick toward the physical demand `target` (with demand acceleration `acc`, inc/tick²).
    fn advance(&mut self, target: f64, acc: f64) {
        let x0 = self.x;
        let mut x1 = if self.lag == 0.0 { target } else { target + (x0 - target) * self.lag };
        if let Some(s) = self.geo.positive_stop {
            x1 = x1.min(s as f64);
        }
        if let Some(s) = self.geo.negative_stop {
            x1 = x1.max(s as f64);
        }
        self.x = x1;
        self.velocity = x1 - x0;
        self.current_ma = ((target - x1) * self.current_per_inc + acc * self.current_per_acc) as i32;
        self.now = self.now.wrapping_add(1);
        for switch in 0..3 {
            let boundaries = self.boundaries(switch);
            let mut edges = match switch {
                0 => self.negative_limit,
                1 => self.positive_limit,
                _ => self.home_switch,
            };
            self.cross(&boundaries, &mut edges, x0, x1);
            match switch {
                0 => self.negative_limit = edges,
                1 => self.positive_limit = edges,
                _ => self.home_switch = edges,
            }
        }
        if let Some(phase) = self.geo.index_phase {
            let (lo, hi) = (x0.min(x1), x0.max(x1));
            let first = ((lo - phase as f64) / PITCH as f64).floor() as i64 - 1;
            let last = ((hi - phase as f64) / PITCH as f64).ceil() as i64 + 1;
            let mut crossed: Vec<i64> =
                (first..=last).map(|n| phase + n * PITCH).filter(|&p| (x0 < p as f64) != (x1 < p as f64)).collect();
            crossed.sort_by(|a, b| ((*a as f64 - x0).abs()).total_cmp(&(*b as f64 - x0).abs()));
            for p in crossed {
                self.index = EdgeLatch { count: self.index.count.wrapping_add(1), position: self.reported(p) };
            }
        }
    }

    /// Latches the edges of one switch crossed from `x0` to `x1`, in the order of the motion, at the boundary.
    fn cross(&self, boundaries: &[Boundary], edges: &mut SwitchEdges, x0: f64, x1: f64) {
        let mut crossed: Vec<Boundary> = boundaries.iter().copied().filter(|b| b.holds(x0) != b.holds(x1)).collect();
        crossed.sort_by(|a, b| ((a.b as f64 - x0).abs()).total_cmp(&(b.b as f64 - x0).abs()));
        let mut holds: Vec<bool> = boundaries.iter().map(|b| b.holds(x0)).collect();
        let mut level = !holds.is_empty() && holds.iter().all(|h| *h);
        for c in crossed {
            for (h, b) in holds.iter_mut().zip(boundaries) {
                if b.b == c.b {
                    *h = !*h;
                }
            }
            let now = holds.iter().all(|h| *h);
            if now != level {
                let latch = if now { &mut edges.activated } else { &mut edges.released };
                *latch = EdgeLatch { count: latch.count.wrapping_add(1), position: self.reported(c.b) };
                level = now;
            }
        }
        edges.active = level;
    }
}

fn q32(v: f64) -> i64 {
    (v * 4_294_967_296.0) as i64
}

fn q40(a: f64) -> i64 {
    (a * 1_099_511_627_776.0) as i64
}

const FAST: f64 = 8.0;
const SLOW: f64 = 0.75;
const ACC: f64 = 0.05;
const HALT_DEC: f64 = 0.2;
const HOME_POSITION: i32 = 100_000;

fn input(method: i8, offset: i32) -> HomingInput {
    HomingInput {
        controlword: Controlword(ENABLED),
        method,
        switch_search_speed: Velocity(q32(FAST)),
        zero_search_speed: Velocity(q32(SLOW)),
        acceleration: Acceleration(q40(ACC)),
        offset_move_distance: offset,
        home_position: HOME_POSITION,
        current_threshold_ma: 500,
        search_distance_limit: None,
        halt_deceleration: Acceleration(q40(HALT_DEC)),
    }
}

struct Run {
    axis: TestAxis,
    generator: ProfileGenerator,
    homing: Homing,
    input: HomingInput,
    rereferences: Vec<Rereference>,
    /// Status of every step, with whether the step rereferenced.
    statuses: Vec<(ModeStatus, bool)>,
    /// Demand path length, increments.
    travel: f64,
}

impl Run {
    fn new(geo: Geometry, start: f64, input: HomingInput) -> Self {
        let axis = TestAxis::new(geo, start);
        let mut generator = ProfileGenerator::new(start.round() as i64);
        let mut homing = Homing::new();
        homing.enter(Controlword(ENABLED), &mut generator, &axis.feedback());
        Self { axis, generator, homing, input, rereferences: vec![], statuses: vec![], travel: 0.0 }
    }

    fn tick(&mut self) -> HomingStep {
        let feedback = self.axis.feedback();
        let before = self.generator.setpoint();
        let step = self.homing.step(&self.input, &mut self.generator, &feedback);
        let LoopDemand::Position(setpoint) = step.mode.demand else { panic!("HMM demands a position") };
        assert_eq!(setpoint, self.generator.setpoint(), "the demand is the generator's latest sample");
        let mut target = setpoint.position_fine as f64 / 65_536.0;
        self.travel += (target - before.position_fine as f64 / 65_536.0).abs();
        if let Some(r) = step.rereference {
            let shift = i64::from(r.to) - i64::from(r.from);
            self.axis.offset += shift;
            target += shift as f64;
            let now = self.generator.setpoint();
            if now.velocity == Velocity::ZERO {
                self.generator.reset(now.position + shift);
            } else {
                self.generator.reset_moving(now.position + shift, now.velocity);
            }
            self.rereferences.push(r);
        }
        let acc = setpoint.acceleration.0 as f64 / 1_099_511_627_776.0;
        self.axis.advance(target - self.axis.offset as f64, acc);
        self.statuses.push((step.mode.status, step.rereference.is_some()));
        step
    }

    fn set_controlword(&mut self, cw: u16) {
        self.input.controlword = Controlword(cw);
    }

    /// Ticks until `done` holds after a step, at most `max` ticks; returns the ticks taken.
    fn until(&mut self, max: usize, mut done: impl FnMut(&Self, &HomingStep) -> bool) -> usize {
        for n in 1..=max {
            let step = self.tick();
            if done(self, &step) {
                return n;
            }
        }
        panic!("not done within {max} ticks: {:?} at x = {}", self.homing.phase, self.axis.x);
    }

    fn status(&self) -> ModeStatus {
        self.statuses.last().map(|s| s.0).unwrap_or_default()
    }

    /// Starts (bit 4 rising edge) and runs to the end of the procedure.
    fn home(&mut self) {
        self.set_controlword(START);
        self.until(400_000, |r, _| !r.homing.in_progress());
    }
}

fn index_after(edge: i64, positive: bool) -> i64 {
    // Brute force over the pulses, independent of the sequencer.
    let pulses = (-20..20).map(|n| PHASE + n * PITCH);
    if positive {
        pulses.filter(|&p| p > edge).min().unwrap()
    } else {
        pulses.filter(|&p| p < edge).max().unwrap()
    }
}

/// The physical reference of each method in the test geometry, from the CiA 402 definitions: the edge (limit
/// switch edge, the one edge of a half-axis home switch, the lower or upper edge of a band), and for index methods
/// the first index beyond it on the named side.
fn expected_reference(method: i8, start: f64) -> i64 {
    let (lo, hi) = BAND;
    let (left, right) = (false, true);
    match method {
        1 => index_after(NLS, right),
        2 => index_after(PLS, left),
        3 => index_after(EDGE, left),
        4 => index_after(EDGE, right),
        5 => index_after(EDGE, right),
        6 => index_after(EDGE, left),
        7 => index_after(lo, left),
        8 => index_after(lo, right),
        9 => index_after(hi, left),
        10 => index_after(hi, right),
        11 => index_after(hi, right),
        12 => index_after(hi, left),
        13 => index_after(lo, right),
        14 => index_after(lo, left),
        17 => NLS,
        18 => PLS,
        19..=22 => EDGE,
        23 | 24 | 29 | 30 => lo,
        25..=28 => hi,
        33 => index_after(start.round() as i64, left),
        34 => index_after(start.round() as i64, right),
        35 | 37 => start.round() as i64,
        -1 => index_after(STOP, left),
        -2 => index_after(-STOP, right),
        -3 => STOP,
        -4 => -STOP,
        _ => unreachable!(),
    }
}

/// The test geometry and the start positions (physical) of a method: on each side of the reference, and on the
/// switch where that matters.
fn scenarios(method: i8) -> (Geometry, Vec<f64>) {
    let (lo, hi) = BAND;
    match method {
        1 | 17 => (geometry(Home::None), vec![0.0, -5000.0, (NLS - 300) as f64]),
        2 | 18 => (geometry(Home::None), vec![0.0, 5000.0, (PLS + 300) as f64]),
        3 | 4 | 19 | 20 => (geometry(Home::Above(EDGE)), vec![-5000.0, 2800.0, 3300.0, 9000.0]),
        5 | 6 | 21 | 22 => (geometry(Home::Below(EDGE)), vec![-5000.0, 2800.0, 3300.0, 9000.0]),
        7..=14 | 23..=30 => (
            geometry(Home::Band(lo, hi)),
            vec![
                -8000.0,
                (lo - 150) as f64,
                6000.0,
                (lo + 150) as f64,
                (hi + 150) as f64,
                15_000.0,
                20_200.0,
                -20_200.0,
            ],
        ),
        33 | 34 => (geometry(Home::None), vec![3000.5, -7000.25, 1234.0 + 100.0]),
        35 | 37 => (geometry(Home::None), vec![777.4, -3210.6]),
        -4..=-1 => (stops(), vec![0.0, 17_000.0, -17_000.0, STOP as f64, -STOP as f64]),
        _ => unreachable!(),
    }
}

/// Homes `method` from `start` and checks the reference, the statusword bits before, at and after the end, and the
/// final position.
fn check_method(method: i8, geo: Geometry, start: f64, offset: i32, lag: f64) {
    let mut run = Run::new(geo, start, input(method, offset));
    run.axis.lag = lag;
    run.home();
    let what = format!("method {method} from {start} offset {offset} lag {lag}");
    assert_eq!(run.homing.error(), None, "{what}");
    assert_eq!(run.rereferences.len(), 1, "{what}");
    let r = run.rereferences[0];
    let reference = expected_reference(method, start);
    let offset = i64::from(offset);
    let home_point = match method {
        // Away from the end stop whatever the sign (module docs).
        -1 | -3 => reference - offset.abs(),
        -2 | -4 => reference + offset.abs(),
        35 | 37 => reference,
        _ => reference + offset,
    };
    // The test axis latches every edge exactly on its (integer) boundary, so the reference is exact here; the
    // required accuracy on a real axis is ±1 increment.
    assert_eq!(i64::from(r.from), home_point, "{what}");
    assert_eq!(r.to, HOME_POSITION, "{what}");
    // In progress (0/0/0) until the step that attains; attained 0/1/1 from there.
    let attained_at = run.statuses.iter().position(|s| s.1).unwrap();
    for (n, (s, _)) in run.statuses.iter().enumerate().take(attained_at) {
        if method != 35 && method != 37 {
            assert_eq!(*s, ModeStatus::default(), "{what}: tick {n} before attained");
        }
    }
    let attained = ModeStatus { target_reached: true, bit12: true, bit13: false };
    assert_eq!(run.statuses[attained_at].0, attained, "{what}");
    assert!(run.homing.attained(), "{what}");
    // Stays attained, at the home position in the new coordinates.
    for _ in 0..50 {
        run.tick();
        assert_eq!(run.status(), attained, "{what}");
    }
    let position = run.axis.feedback().position;
    if method != 35 && method != 37 {
        assert!((position - HOME_POSITION).abs() <= 1, "{what}: ends at {position}");
        assert!((run.axis.x - home_point as f64).abs() <= 1.0, "{what}: physical {}", run.axis.x);
    }
}

fn check_all_starts(methods: &[i8]) {
    for &method in methods {
        let (geo, starts) = scenarios(method);
        for start in starts {
            for (offset, lag) in [(0, 0.0), (1500, 0.0), (-1700, 0.6)] {
                check_method(method, geo, start, offset, lag);
            }
        }
    }
}

#[test]
fn limit_switch_methods_1_2_17_18() {
    check_all_starts(&[1, 2, 17, 18]);
}

#[test]
fn half_axis_home_switch_methods_3_to_6_and_19_to_22() {
    check_all_starts(&[3, 4, 5, 6, 19, 20, 21, 22]);
}

#[test]
fn band_home_switch_index_methods_7_to_14() {
    check_all_starts(&[7, 8, 9, 10, 11, 12, 13, 14]);
}

#[test]
fn band_home_switch_edge_methods_23_to_30() {
    check_all_starts(&[23, 24, 25, 26, 27, 28, 29, 30]);
}

#[test]
fn index_methods_33_34() {
    check_all_starts(&[33, 34]);
}

#[test]
fn current_position_methods_35_37() {
    check_all_starts(&[35, 37]);
}

#[test]
fn end_stop_methods_minus_1_to_minus_4() {
    check_all_starts(&[-1, -2, -3, -4]);
}

#[test]
fn every_supported_method_is_covered() {
    for m in SUPPORTED_METHODS {
        let (_, starts) = scenarios(m);
        assert!(starts.len() >= 2, "method {m}");
        let _ = expected_reference(m, 0.0);
    }
}

#[test]
fn supported_methods_match_the_device_description() {
    let toml = include_str!("../../../device.toml");
    let list = |after: &str, key: &str| -> Vec<i8> {
        let at = toml.find(after).unwrap();
        let rest = &toml[at..];
        let line = rest.lines().find(|l| l.trim_start().starts_with(key)).unwrap();
        let inner = line.split('[').nth(1).unwrap().split(']').next().unwrap();
        inner.split(',').map(|v| v.trim().parse().unwrap()).collect()
    };
    let supported = list("index = 0x60E3", "default = [");
    assert_eq!(supported, SUPPORTED_METHODS.to_vec(), "0x60E3 in device.toml");
    let accepted = list("index = 0x6098", "values = [");
    let (mut a, mut s) = (accepted, SUPPORTED_METHODS.to_vec());
    a.sort_unstable();
    s.sort_unstable();
    assert_eq!(a, s, "0x6098 value list");
    let numbers: Vec<i8> = methods::METHODS.iter().map(|m| m.number).collect();
    assert_eq!(numbers, SUPPORTED_METHODS.to_vec());
    for m in [0, 15, 16, 31, 32, 36, 38, -5, i8::MIN, i8::MAX] {
        assert_eq!(methods::method(m), None, "{m}");
    }
}

#[test]
fn catalogue_mirror_symmetry() {
    // 11-14 are 7-10 mirrored (x -> -x): the lower edge becomes the upper one, both directions flip. Same for 2/1,
    // 5/3, 6/4 and the edge methods.
    use methods::{Direction as D, Layout, Reference as R};
    let flip = |m: Method| {
        let reference = match m.reference {
            R::SwitchEdge { switch, layout, active_side } => R::SwitchEdge {
                switch: match switch {
                    Switch::NegativeLimit => Switch::PositiveLimit,
                    Switch::PositiveLimit => Switch::NegativeLimit,
                    Switch::Home => Switch::Home,
                },
                layout: match layout {
                    Layout::Band { initial } => Layout::Band { initial: initial.reverse() },
                    l => l,
                },
                active_side: active_side.reverse(),
            },
            r => r,
        };
        (reference, m.approach.reverse(), m.index)
    };
    let get = |n: i8| methods::method(n).unwrap();
    for (a, b) in [(1, 2), (3, 5), (4, 6), (7, 11), (8, 12), (9, 13), (10, 14)] {
        for base in [0, 16] {
            let (a, b) = (get(a + base), get(b + base));
            assert_eq!(flip(a), (b.reference, b.approach, b.index), "{} vs {}", a.number, b.number);
        }
    }
    assert_eq!(get(33).approach, D::Negative);
    assert_eq!(get(34).approach, D::Positive);
}

// ---------------------------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------------------------

/// Runs until the error is reported and the axis stands; checks the bits on the way and returns the run.
fn run_to_error(mut run: Run, expected: HomingError) -> Run {
    run.set_controlword(START);
    run.until(400_000, |r, _| r.homing.error().is_some());
    assert_eq!(run.homing.error(), Some(expected));
    assert!(!run.homing.attained());
    // Error while braking: 1/0/0, then 1/0/1 standing, and it holds.
    let n = run.until(10_000, |r, _| r.status().target_reached);
    assert!(n < 200, "stops within the braking time, took {n} ticks");
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: true });
    let x = run.axis.x;
    for _ in 0..100 {
        run.tick();
    }
    assert_eq!(run.axis.x, x, "holds");
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: true });
    assert!(run.rereferences.is_empty());
    run
}

#[test]
fn missing_switch_with_a_distance_limit() {
    let mut geo = geometry(Home::None);
    geo.negative_limit = None;
    let mut i = input(17, 0);
    i.search_distance_limit = Some(30_000);
    let run = run_to_error(Run::new(geo, 0.0, i), HomingError::SwitchNotFound);
    // Stopped after 30,000 inc of demand travel plus the braking distance (v² / 2a = 640 inc).
    assert!(run.travel > 30_000.0 && run.travel < 30_000.0 + 700.0, "travel {}", run.travel);
    assert!((run.axis.x - (-30_000.0 - 640.0)).abs() < 20.0, "x {}", run.axis.x);
}

#[test]
fn missing_home_switch_hits_a_limit_where_it_cannot_reverse() {
    // Half-axis methods never reverse.
    let run = run_to_error(Run::new(geometry(Home::None), 0.0, input(4, 0)), HomingError::LimitSwitch);
    assert!(run.axis.x > PLS as f64);
    // Limit methods: the other limit switch (method 1 without index pulses: after the negative limit switch's
    // edge the index search runs into the positive one).
    let mut geo = geometry(Home::None);
    geo.index_phase = None;
    let run = run_to_error(Run::new(geo, 0.0, input(1, 0)), HomingError::LimitSwitch);
    assert!(run.axis.x > PLS as f64);
    // The index search of 33 runs into the negative limit switch.
    run_to_error(Run::new(geo, 0.0, input(33, 0)), HomingError::LimitSwitch);
}

#[test]
fn band_methods_reverse_once_then_both_limits_is_an_error() {
    for method in [7, 14, 25, 30] {
        let run = run_to_error(Run::new(geometry(Home::None), 0.0, input(method, 0)), HomingError::BothLimitSwitches);
        // Reached the first limit, reversed, ended at the second.
        let initial_positive = matches!(method, 7..=10 | 23..=26);
        if initial_positive {
            assert!(run.axis.x < NLS as f64, "method {method}");
        } else {
            assert!(run.axis.x > PLS as f64, "method {method}");
        }
    }
}

#[test]
fn index_not_found_within_the_distance_limit() {
    let mut geo = geometry(Home::None);
    geo.index_phase = None;
    let mut i = input(1, 0);
    i.search_distance_limit = Some(8000);
    let run = run_to_error(Run::new(geo, -15_000.0, i), HomingError::IndexNotFound);
    // The NLS edge was found, then 8,000 inc of index search.
    assert!(run.axis.x > (NLS + 7_900) as f64 && run.axis.x < (NLS + 8_100) as f64, "x {}", run.axis.x);
}

#[test]
fn current_threshold_never_reached() {
    // No end stop at all.
    let mut geo = stops();
    geo.positive_stop = None;
    let mut i = input(-3, 0);
    i.search_distance_limit = Some(25_000);
    run_to_error(Run::new(geo, 0.0, i), HomingError::EndStopNotFound);
    // A stop, but the threshold is above what the axis draws before the distance limit: the blocked axis does not
    // move, the demand does, and the demand's travel ends it.
    let mut i = input(-3, 0);
    i.current_threshold_ma = 50_000;
    i.search_distance_limit = Some(25_000);
    let run = run_to_error(Run::new(stops(), 0.0, i), HomingError::EndStopNotFound);
    assert_eq!(run.axis.x, STOP as f64);
}

#[test]
fn end_stop_ignores_the_acceleration_current() {
    // The ramp alone draws 0.05 * 20,000 = 1,000 mA > 500 mA; the stop is still found where it is.
    for start in [0.0, STOP as f64] {
        let mut run = Run::new(stops(), start, input(-3, 300));
        run.axis.current_per_acc = 20_000.0;
        run.home();
        assert_eq!(run.rereferences, vec![Rereference { from: (STOP - 300) as i32, to: HOME_POSITION }]);
    }
}

#[test]
fn end_stop_with_zero_offset_rests_at_the_stop_without_pushing() {
    let mut run = Run::new(stops(), 0.0, input(-4, 0));
    run.home();
    assert_eq!(run.rereferences, vec![Rereference { from: -STOP as i32, to: HOME_POSITION }]);
    for _ in 0..100 {
        run.tick();
    }
    assert!(run.axis.current_ma.abs() < 5, "current {}", run.axis.current_ma);
    assert_eq!(run.axis.feedback().position, HOME_POSITION);
}

#[test]
fn unsupported_method_is_a_homing_error_without_motion() {
    for m in [0, 15, 16, 31, 32, 36, 38, -5] {
        let mut run = Run::new(geometry(Home::None), 0.0, input(m, 0));
        run.set_controlword(START);
        run.tick();
        assert_eq!(run.homing.error(), Some(HomingError::UnsupportedMethod), "{m}");
        assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: true }, "{m}");
        for _ in 0..10 {
            run.tick();
        }
        assert_eq!(run.axis.x, 0.0);
    }
}

#[test]
fn zero_speed_is_a_homing_error() {
    let mut i = input(34, 0);
    i.zero_search_speed = Velocity::ZERO;
    run_to_error(Run::new(geometry(Home::None), 0.0, i), HomingError::ZeroSpeedOrAcceleration);
    let mut i = input(17, 0);
    i.acceleration = Acceleration(0);
    run_to_error(Run::new(geometry(Home::None), 0.0, i), HomingError::ZeroSpeedOrAcceleration);
}

// ---------------------------------------------------------------------------------------------------------------
// Controlword
// ---------------------------------------------------------------------------------------------------------------

#[test]
fn halt_stops_with_the_halt_deceleration_and_a_new_rising_edge_restarts() {
    let mut run = Run::new(geometry(Home::Band(BAND.0, BAND.1)), -8000.0, input(8, 500));
    run.set_controlword(START);
    // Cruise at search speed.
    run.until(1000, |r, _| r.axis.velocity > FAST - 0.01);
    run.set_controlword(START | HALT);
    let from = run.axis.x;
    let n = run.until(1000, |r, _| r.status().target_reached);
    // v / a = 8 / 0.2 = 40 ticks, v² / 2a = 160 inc; 0/0/0 while braking.
    assert!((39..=42).contains(&n), "{n} ticks");
    assert!((run.axis.x - from - 160.0).abs() < 10.0, "braked over {}", run.axis.x - from);
    assert!(run.statuses.iter().rev().skip(1).take(n - 1).all(|s| s.0 == ModeStatus::default()));
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: false });
    assert!(!run.homing.in_progress());
    // Releasing the halt does not resume.
    run.set_controlword(START);
    let x = run.axis.x;
    for _ in 0..500 {
        run.tick();
    }
    assert_eq!(run.axis.x, x);
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: false });
    // A rising edge while halted is ignored.
    run.set_controlword(ENABLED | HALT);
    run.tick();
    run.set_controlword(START | HALT);
    run.tick();
    assert!(!run.homing.in_progress());
    // A new rising edge with bit 8 = 0 starts again from scratch and finds the right reference.
    run.set_controlword(ENABLED);
    run.tick();
    run.home();
    let expected = index_after(BAND.0, true) + 500;
    assert_eq!(run.rereferences, vec![Rereference { from: expected as i32, to: HOME_POSITION }]);
}

#[test]
fn bit4_falling_interrupts_and_a_rising_edge_restarts() {
    let mut run = Run::new(geometry(Home::None), 0.0, input(1, 0));
    run.set_controlword(START);
    run.until(1000, |r, _| r.axis.velocity < -FAST + 0.01);
    run.set_controlword(ENABLED);
    let n = run.until(1000, |r, _| r.status().target_reached);
    // Stops with 0x609A: v / a = 160 ticks.
    assert!((159..=162).contains(&n), "{n} ticks");
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: false });
    let x = run.axis.x;
    for _ in 0..100 {
        run.tick();
    }
    assert_eq!(run.axis.x, x);
    run.home();
    assert_eq!(run.rereferences, vec![Rereference { from: index_after(NLS, true) as i32, to: HOME_POSITION }]);
    // After attained, bit 4 falling changes nothing.
    run.set_controlword(ENABLED);
    run.tick();
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: true, bit13: false });
}

#[test]
fn bit4_set_on_entry_needs_a_rising_edge() {
    let axis = TestAxis::new(geometry(Home::None), 0.0);
    let mut run = Run::new(geometry(Home::None), 0.0, input(34, 0));
    run.homing.enter(Controlword(START), &mut run.generator, &axis.feedback());
    run.set_controlword(START);
    for _ in 0..100 {
        run.tick();
    }
    assert_eq!(run.axis.x, 0.0);
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: false });
    run.set_controlword(ENABLED);
    run.tick();
    run.home();
    assert_eq!(run.rereferences.len(), 1);
}

#[test]
fn a_new_start_after_attained_homes_again_and_enter_keeps_the_reference() {
    let mut run = Run::new(geometry(Home::None), 500.0, input(34, 0));
    run.home();
    assert!(run.homing.attained());
    // Coordinates now: home position at the index 1234.
    let fb = run.axis.feedback();
    run.homing.enter(Controlword(ENABLED), &mut run.generator, &fb);
    assert!(run.homing.attained(), "bit 15 kept across enter");
    run.set_controlword(ENABLED);
    run.tick();
    assert_eq!(run.status(), ModeStatus { target_reached: true, bit12: false, bit13: false });
    // Restart: 34 from the index itself finds the next one, 4096 further.
    run.set_controlword(START);
    run.tick();
    assert!(!run.homing.attained() && run.homing.in_progress());
    run.until(100_000, |r, _| !r.homing.in_progress());
    let second = run.rereferences[1];
    assert_eq!(second, Rereference { from: HOME_POSITION + 4096, to: HOME_POSITION });
    assert!((run.axis.x - (PHASE + PITCH) as f64).abs() < 1e-6);
}

#[test]
fn entering_while_moving_stops_the_generator() {
    let mut run = Run::new(geometry(Home::None), 0.0, input(34, 0));
    let params = params(Velocity(q32(FAST)), Acceleration(q40(ACC)));
    run.generator.set_velocity_target(Velocity(q32(FAST)), &params).unwrap();
    for _ in 0..200 {
        run.generator.step();
    }
    let fb = run.axis.feedback();
    run.homing.enter(Controlword(ENABLED), &mut run.generator, &fb);
    let n = run.until(1000, |r, _| r.status().target_reached);
    assert!((159..=162).contains(&n), "{n}");
}

#[test]
fn positions_wrap_like_0x6064() {
    // Reported coordinates near i32::MAX: the index found by 34 lies beyond the wrap.
    let mut run = Run::new(geometry(Home::None), 0.0, input(34, 0));
    let offset = i64::from(i32::MAX) - 500;
    run.axis.offset = offset;
    run.generator.reset(offset);
    let fb = run.axis.feedback();
    run.homing.enter(Controlword(ENABLED), &mut run.generator, &fb);
    run.home();
    let expected = (PHASE + offset) as i32; // wraps negative
    assert!(expected < 0);
    assert_eq!(run.rereferences, vec![Rereference { from: expected, to: HOME_POSITION }]);
    assert!((run.axis.x - PHASE as f64).abs() < 1e-6);
}

#[test]
fn reference_edge_is_crossed_at_zero_search_speed() {
    // The latched edge used by the edge methods is crossed slowly in the approach direction: record the axis
    // velocity at every home-switch edge of method 24 started on the far side (right of the band).
    let mut run = Run::new(geometry(Home::Band(BAND.0, BAND.1)), 15_000.0, input(24, 0));
    run.set_controlword(START);
    let mut last = run.axis.home_switch.activated.count;
    let mut crossings = vec![];
    run.until(400_000, |r, _| {
        if r.axis.home_switch.activated.count != last {
            last = r.axis.home_switch.activated.count;
            crossings.push((r.axis.home_switch.activated.position, r.axis.velocity));
        }
        !r.homing.in_progress()
    });
    let (position, velocity) = *crossings.last().unwrap();
    assert_eq!(i64::from(position), BAND.0);
    assert!(velocity > 0.0 && velocity <= SLOW + 1e-9, "velocity {velocity}");
}
