//! Homing mode (HMM, 0x6060 = 6) on the scenario plant (the reference unless `drive-sim --plant` chose another),
//! driven through CiA 402 as a fieldbus master drives it, with the true reference computed from the plant's
//! geometry. `tests/tests/motion/homing.rs` asserts these figures.
//!
//! # Another plant
//! The numbers below are the reference plant's. On another plant ([`HomingConfig::new`]) the speeds (0x6099,
//! 0x609A and the positioning move) scale with its maximum speed ([`PlantScale::speed`]), the distances
//! (switch, band and index placement, the offset move 0x30B1, the search limit 0x30B3) with its revolutions
//! times the same factor ([`HomingConfig::distance_scale`]: a run keeps its timing), the current threshold
//! 0x30B2 with its peak current, and the end stop's stiffness with its peak torque at the output (the stop acts
//! on the load side, through the gear). The home error is still counted in the plant's encoder increments.
//!
//! # A run ([`homing_run_with`])
//! 1. [`prepare_motion_on`] (the reference plant, or its encoder replaced: [`HomingConfig::counts_per_rev`]) in
//!    PPM (0x6060 = 1); the master moves the axis to the start position of the run with a profile-position move
//!    (0x607A, controlword 0x0F then 0x1F, statusword bit 12 acknowledge, bit 10 target reached) while no switch
//!    is wired yet, so no limit switch is met on the way.
//! 2. 0x6060 = 6 (the controlword stays 0x0F); once 0x6061 shows 6 the switches (plant inputs 1-3: negative limit,
//!    positive limit, home switch, the 0x3142 defaults) and the end stop are placed around the standing axis, and
//!    the master writes 0x6098, 0x6099:01/02, 0x609A, 0x30B0, 0x607C, 0x30B1, 0x30B2, 0x30B3.
//! 3. Controlword 0x1F (bit 4 rising): the master reads the statusword every slow tick until bit 12 (homing
//!    attained) or bit 13 (homing error), then lets the axis stand for [`HomingConfig::settle_s`] ([`SETTLE_S`])
//!    and reads 0x6041, 0x6064, 0x6063 and 0x30D1:01.
//!
//! # Geometry (plant counts)
//! Positions are the plant's total encoder counts, the counts the switches and the index are defined in. The
//! drive's raw encoder position 0x6063 is the same count minus the count the plant showed at the drive's first
//! sample (its encoder starts at 0 there; 651 for the scenarios' start angle of 1 rad): [`encoder_offset`]
//! measures that difference from the counter sample the drive last took, before and after the run.
//! The encoder index is the quadrature state `n`, `n` a multiple of the counts per revolution (4,096 on the
//! reference plant, [`HomingConfig::counts_per_rev`]) (`PlantParams::index_count` = 0,
//! `sensors::index_entry`); it is latched as `n` in both directions. Each run is placed around one index `I`
//! (the one that puts the start nearest the axis after commissioning) with the approach direction `F` of the
//! method (CiA 402 figures, [`truth`]; written independently of the firmware's catalogue):
//! - **switch methods 1-14, 17-30**: the reference edge `E` lies [`INDEX_GAP_INC`] before `I` in `F`
//!   (`E = I - F * gap`), so the first index after `E` in `F` is `I`. A limit or half-axis switch is active on
//!   its side of `E`; a home band is [`BAND_WIDTH_INC`] wide and starts at `E` on its active side. The start is
//!   [`START_DISTANCE_INC`] below or above `E` ([`Start::Below`], [`Start::Above`]; for a band one of them lies
//!   inside the band), or beyond the far edge of the band ([`Start::Beyond`]). The true reference is `I` for the
//!   index methods and `E` for the edge methods.
//! - **33 / 34**: the start lies [`START_DISTANCE_INC`] before `I` in `F`; the true reference is `I`.
//! - **-1..-4**: a mechanical end stop ([`end_stop_load`]) in the search direction, at the middle of count
//!   `s = I - F * gap`; the true reference is `s` (the count the shaft shows while pushed against the stop) for -3
//!   and -4, `I` for -1 and -2. The start is on the free side: for -1/-2 between the stop and `I` (half the gap
//!   from `I`) or beyond `I`, for -3/-4 beyond the stop by [`START_DISTANCE_INC`].
//! - **35 / 37**: no switch; the true reference is the count the shaft stands on when homing starts.
//! - Limit switches that are not the reference are placed [`LIMIT_MARGIN_INC`] beyond every point of the run on
//!   each side (start, edge, band, index, home point): a band search reverses at the one ahead of its initial
//!   direction; no other search may reach them.
//!
//! # Switch edges and their true position
//! A switch is active on one side of a boundary `b` between counts `b - 1` and `b` (`Above { b }`,
//! `Below { b - 1 }`, `Band { lo, hi - 1 }` for the boundaries `lo`, `hi`); the true reference of an edge is `b`,
//! the position value the drive shows with the shaft exactly on the edge. The drive latches the count of the first
//! sample past the edge: `b` crossing it moving positive, `b - 1` moving negative (the count `b - 1` covers
//! `[b - 1, b)`), so the home error of an edge method is 0 with a positive and +1 with a negative approach: the
//! encoder's quantisation, within the +-1 increment bound. The inputs are sampled every PWM period (40 us) with
//! the count of the same sample, so the latched count is the first one past the edge as long as the axis moves
//! less than one count per sample: below 366 rpm at 4,096 inc/rev. The reference crossing happens at the
//! zero-search speed (30 rpm = 0.08 inc per sample), the search at [`SWITCH_SEARCH_RPM`] (300 rpm, 0.82 inc per
//! sample) only finds the switch and brakes beyond it; the index is latched in hardware (exact at any speed).
//!
//! # Home error
//! The drive's position value of the true reference point is `R - encoder offset + (0x6064 - 0x6063)` after
//! homing (the plant count `R` as a raw count, with the drive's position offset applied); it must equal the home
//! position `0x30B0 + 0x607C` minus the home offset move (0x30B1; for -1..-4 its magnitude away from the stop, the
//! firmware's documented choice; none for 35/37). The home error is the difference, in increments.
//!
//! # Simulated time
//! The runs are kept short for CI (two cores): switches within about one revolution of the start, switch search
//! 300 rpm, zero search 30 rpm, 0x609A = 20,000 rpm/s (154 inc of braking from the search speed), a gap of 300
//! inc from the edge to the index (0.15 s at the zero-search speed). A run takes 0.04-0.48 s of homing after about
//! 0.22 s of preparation (offset calibration, commissioning, the positioning move, 20 ms of settling); the matrix
//! (82 runs) simulates 40 s.

use core::f64::consts::PI;

use firmware::od::generated::handles as h;

use super::motion::prepare_motion_on;
use super::{scenario_plant, PlantScale};
use crate::plant::{InputSource, PlantParams, PERIOD_S};
use crate::sim::{SimError, Simulation};

/// 0x6099:01 speed for switch search used by the runs, rpm.
pub const SWITCH_SEARCH_RPM: u32 = 300;
/// 0x6099:02 speed for zero search used by the runs, rpm.
pub const ZERO_SEARCH_RPM: u32 = 30;
/// 0x609A homing acceleration used by the runs, rpm/s.
pub const HOMING_ACCELERATION_RPM_S: u32 = 20_000;
/// 0x30B0 home position used by the runs, increments.
pub const HOME_POSITION_INC: i32 = 10_000;
/// 0x607C home offset used by the runs, increments (the home point takes 0x30B0 + 0x607C).
pub const HOME_OFFSET_INC: i32 = -3;
/// Magnitude of 0x30B1 (home offset move distance) used by the runs, increments.
pub const OFFSET_MOVE_INC: i32 = 250;
/// 0x30B2 current threshold used by the runs, mA: the dictionary default. The 20,000 rpm/s ramp takes 1.1 A on
/// the reference shaft, more than this, so the runs also prove that the end of the ramp is not taken for the stop.
pub const CURRENT_THRESHOLD_MA: u16 = 500;
/// 0x30B3 search distance limit used by the runs (three revolutions), increments.
pub const SEARCH_LIMIT_INC: u32 = 12_288;
/// Distance from the reference edge (or end stop) to the index pulse beyond it in the approach direction.
pub const INDEX_GAP_INC: i64 = 300;
/// Distance from the start to the reference edge.
pub const START_DISTANCE_INC: i64 = 800;
/// Width of a home band (methods 7-14, 23-30).
pub const BAND_WIDTH_INC: i64 = 1_600;
/// Distance of the limit switches beyond every point of a run.
pub const LIMIT_MARGIN_INC: i64 = 600;
/// Standing time after bit 12 or 13 before the final values are read, s.
pub const SETTLE_S: f64 = 0.02;
/// Stiffness of the end stop, N m/rad (7.7 N m per increment: 0.044 inc under the 10 A current limit).
pub const END_STOP_STIFFNESS_NM_PER_RAD: f64 = 5_000.0;
/// Damping ratio of the end stop on the shaft's inertia: heavily damped, so that the shaft does not rebound off
/// the stop (with a ratio of 1 it rebounded by a count, and the threshold was crossed while it did).
pub const END_STOP_DAMPING_RATIO: f64 = 4.0;

/// Increments per revolution of the reference encoder ([`HomingConfig::counts_per_rev`] sets another).
const CPR: i64 = 4096;
/// «Enable operation».
const ENABLE_OPERATION: u16 = 0x000F;
/// Controlword bit 4 (PPM new set-point, HMM start homing).
const BIT4: u16 = 1 << 4;
/// Statusword bits.
const TARGET_REACHED: u16 = 1 << 10;
const BIT12: u16 = 1 << 12;
const BIT13: u16 = 1 << 13;
/// Positioning move: 0x6081 rpm and 0x6083/0x6084 rpm/s.
const POSITIONING_RPM: u32 = 2_000;
const POSITIONING_RPM_S: u32 = 40_000;
/// Slow ticks a master waits for the positioning move and for the mode change before it gives up.
const POSITIONING_TIMEOUT_TICKS: u64 = 2_500;

/// Why a run could not be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunError {
    /// The simulation failed (preparation, positioning move, mode change).
    Sim(SimError),
    /// The 0x6098 value defines no method.
    UndefinedMethod(i8),
    /// The method cannot start there ([`starts`]).
    NoSuchStart(i8, Start),
}

impl From<SimError> for RunError {
    fn from(e: SimError) -> Self {
        Self::Sim(e)
    }
}

impl core::fmt::Display for RunError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Sim(e) => write!(f, "{e}"),
            Self::UndefinedMethod(m) => write!(f, "0x6098 = {m} defines no homing method"),
            Self::NoSuchStart(m, s) => write!(f, "method {m} has no start {s:?}"),
        }
    }
}

impl std::error::Error for RunError {}

/// What defines the reference of a method, as the CiA 402 figures draw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Family {
    /// The edge of a limit switch: the negative one (`negative`) or the positive one.
    Limit {
        /// The negative limit switch.
        negative: bool,
    },
    /// The only edge of a home switch active over the positive half axis (`active_positive`) or the negative one.
    HalfAxis {
        /// Active above its edge.
        active_positive: bool,
    },
    /// One edge of a home band, with the limit switch at which the search reverses.
    Band {
        /// The lower edge (else the upper one).
        lower_edge: bool,
        /// The search starts positive and reverses at the positive limit switch (7-10, 23-26); else negative.
        positive_limit: bool,
    },
    /// The next index pulse (33, 34).
    Index,
    /// A mechanical end stop in the positive (`positive`) or negative direction (-1..-4).
    EndStop {
        /// The stop is in the positive direction.
        positive: bool,
    },
    /// The actual position (35, 37).
    Here,
}

/// The reference of one method: family, approach direction and index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Truth {
    /// The 0x6098 value.
    pub method: i8,
    /// What defines the reference.
    pub family: Family,
    /// Sign of the approach direction `F`: the switch edge is referenced crossed moving in `F`, the index is the
    /// first one in `F` after it; for 33/34 the search direction, for -1..-4 away from the stop.
    pub approach: i64,
    /// The index pulse after the edge or stop is the reference.
    pub index: bool,
}

/// The CiA 402 definition of `method` (CiA 402-2 figures of methods 1-35, maxon's -1..-4 and 37), `None` for a
/// value that defines no method.
pub fn truth(method: i8) -> Option<Truth> {
    use Family::{Band, EndStop, HalfAxis, Here, Index, Limit};
    let (family, approach) = match method {
        1 | 17 => (Limit { negative: true }, 1),
        2 | 18 => (Limit { negative: false }, -1),
        3 | 19 => (HalfAxis { active_positive: true }, -1),
        4 | 20 => (HalfAxis { active_positive: true }, 1),
        5 | 21 => (HalfAxis { active_positive: false }, 1),
        6 | 22 => (HalfAxis { active_positive: false }, -1),
        7 | 23 => (Band { lower_edge: true, positive_limit: true }, -1),
        8 | 24 => (Band { lower_edge: true, positive_limit: true }, 1),
        9 | 25 => (Band { lower_edge: false, positive_limit: true }, -1),
        10 | 26 => (Band { lower_edge: false, positive_limit: true }, 1),
        11 | 27 => (Band { lower_edge: false, positive_limit: false }, 1),
        12 | 28 => (Band { lower_edge: false, positive_limit: false }, -1),
        13 | 29 => (Band { lower_edge: true, positive_limit: false }, 1),
        14 | 30 => (Band { lower_edge: true, positive_limit: false }, -1),
        33 => (Index, -1),
        34 => (Index, 1),
        35 | 37 => (Here, 1),
        -1 | -3 => (EndStop { positive: true }, -1),
        -2 | -4 => (EndStop { positive: false }, 1),
        _ => return None,
    };
    let index = matches!(method, 1..=14 | 33 | 34 | -1 | -2);
    Some(Truth { method, family, approach, index })
}

/// Where a run starts, relative to the reference edge (switch methods), the index (-1, -2) or the end stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Start {
    /// On the negative side.
    Below,
    /// On the positive side.
    Above,
    /// Band methods: outside the band beyond its other edge.
    Beyond,
}

/// The starts a method is run from in [`homing_matrix`]: both sides of the reference edge for the switch
/// methods (and beyond the band for the band methods), both sides of the index for -1/-2; the free side only for
/// 33/34, -3/-4; one start for 35/37.
pub fn starts(method: i8) -> &'static [Start] {
    match truth(method).map(|t| (t.family, t.approach)) {
        Some((Family::Limit { .. } | Family::HalfAxis { .. }, _)) => &[Start::Below, Start::Above],
        Some((Family::Band { .. }, _)) => &[Start::Below, Start::Above, Start::Beyond],
        Some((Family::EndStop { .. }, _)) if matches!(method, -1 | -2) => &[Start::Below, Start::Above],
        // 34 searches positive from below its index, 33 negative from above; -4 (stop negative) starts above its
        // stop, -3 below.
        Some((Family::Index, 1) | (Family::EndStop { .. }, -1)) => &[Start::Below],
        Some((Family::Index | Family::EndStop { .. }, _)) => &[Start::Above],
        Some((Family::Here, _)) => &[Start::Below],
        None => &[],
    }
}

/// The placement of one run, in plant counts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geometry {
    /// Where the axis stands when homing starts.
    pub start: i64,
    /// The true reference.
    pub reference: i64,
    /// The index `I` the run is placed around.
    pub index: i64,
    /// The reference edge boundary `E` (switch methods) or the count `s` of the end stop.
    pub edge: Option<i64>,
    /// Negative limit switch: active below this boundary.
    pub negative_limit: Option<i64>,
    /// Positive limit switch: active at and above this boundary.
    pub positive_limit: Option<i64>,
    /// The home switch (input 3) as the plant wires it.
    pub home_switch: InputSource,
    /// The end stop: in the positive direction (`true`) and its position in counts (the middle of count `s`).
    pub end_stop: Option<(bool, f64)>,
}

/// The geometry of `truth` started from `start`, placed around the index `index`, with the signed home offset
/// move `displacement`; `None` when the method cannot start there (the stop side of an end stop, beyond a band
/// for a method without one).
pub fn geometry(truth: &Truth, start: Start, index: i64, displacement: i64) -> Option<Geometry> {
    geometry_scaled(truth, start, index, displacement, 1.0)
}

/// A reference distance in counts times `scale` ([`HomingConfig::distance_scale`]), at least one count.
fn scaled(counts: i64, scale: f64) -> i64 {
    ((counts as f64 * scale).round() as i64).max(1)
}

/// [`geometry`] with every distance of the placement (index gap, start distance, band width, limit margin, the
/// quarter turn of 35/37) times `scale`.
pub fn geometry_scaled(truth: &Truth, start: Start, index: i64, displacement: i64, scale: f64) -> Option<Geometry> {
    let f = truth.approach;
    let gap = scaled(INDEX_GAP_INC, scale);
    let d = scaled(START_DISTANCE_INC, scale);
    let band_width = scaled(BAND_WIDTH_INC, scale);
    let edge = index - f * gap;
    let mut g = Geometry {
        start: index,
        reference: if truth.index { index } else { edge },
        index,
        edge: Some(edge),
        negative_limit: None,
        positive_limit: None,
        home_switch: InputSource::Open,
        end_stop: None,
    };
    // Points the limit switches must stay clear of.
    let mut points = vec![edge, index];
    match truth.family {
        Family::Limit { negative } => {
            g.start = match start {
                Start::Below => edge - d,
                Start::Above => edge + d,
                Start::Beyond => return None,
            };
            if negative {
                g.negative_limit = Some(edge);
            } else {
                g.positive_limit = Some(edge);
            }
        }
        Family::HalfAxis { active_positive } => {
            g.start = match start {
                Start::Below => edge - d,
                Start::Above => edge + d,
                Start::Beyond => return None,
            };
            g.home_switch = if active_positive {
                InputSource::Above { position_counts: Some(edge) }
            } else {
                InputSource::Below { position_counts: Some(edge - 1) }
            };
        }
        Family::Band { lower_edge, .. } => {
            let (lo, hi, active) =
                if lower_edge { (edge, edge + band_width, 1) } else { (edge - band_width, edge, -1) };
            g.start = match start {
                Start::Below => edge - d,
                Start::Above => edge + d,
                Start::Beyond => edge + active * (band_width + d),
            };
            g.home_switch = InputSource::Band { from_counts: lo, to_counts: hi - 1 };
            points.extend([lo, hi]);
        }
        Family::Index => {
            let before_index = if f > 0 { Start::Below } else { Start::Above };
            if start != before_index {
                return None;
            }
            g.edge = None;
            g.reference = index;
            g.start = index - f * d;
        }
        Family::EndStop { positive } => {
            // The stop at `edge` is on the -F side; the index `I` at the gap on the F side of it.
            let free_side_of_index = if f > 0 { Start::Above } else { Start::Below };
            g.start = if truth.index && start == free_side_of_index {
                index + f * d
            } else if truth.index {
                index - f * gap / 2
            } else if start == free_side_of_index {
                edge + f * d
            } else {
                return None;
            };
            g.end_stop = Some((positive, edge as f64 + 0.5));
        }
        Family::Here => {
            g.edge = None;
            g.start = index + scaled(CPR / 4, scale);
            g.reference = g.start;
            points.clear();
        }
    }
    if matches!(truth.family, Family::Here) {
        return Some(g);
    }
    points.extend([g.start, g.reference + displacement]);
    let margin = scaled(LIMIT_MARGIN_INC, scale);
    let lo = points.iter().copied().min().unwrap_or(index) - margin;
    let hi = points.iter().copied().max().unwrap_or(index) + margin;
    g.negative_limit = g.negative_limit.or(Some(lo));
    g.positive_limit = g.positive_limit.or(Some(hi));
    Some(g)
}

/// The load torque of an end stop at `stop_counts` (positive: blocks motion above it, else below), N m, for
/// `Plant::set_load_profile`: a stiff one-sided spring-damper ([`END_STOP_STIFFNESS_NM_PER_RAD`],
/// [`END_STOP_DAMPING_RATIO`] on the shaft's inertia `j`) that only pushes the shaft out of the stop. On a plant
/// with a gear, `counts_per_rev` is the counts per output revolution, `j` the inertia at the output and the
/// stiffness [`END_STOP_STIFFNESS_NM_PER_RAD`] x [`PlantScale::torque`] (`end_stop_load_scaled`). Beyond the
/// stop by `x` rad at `w` rad/s: `max(0, k x + c w)`. The plant holds the load over each stretch of its shaft
/// (with a load profile, one integration segment of at most 5 us): with `w_n = sqrt(k / j)` = 16,900 rad/s,
/// `w_n h` = 0.08 and `2 zeta w_n h` = 0.7, well inside the stability of that explicit step.
pub fn end_stop_load(
    positive: bool,
    stop_counts: f64,
    counts_per_rev: f64,
    j: f64,
) -> impl FnMut(f64, f64, f64) -> f64 + Send {
    end_stop_load_scaled(positive, stop_counts, counts_per_rev, j, 1.0)
}

/// [`end_stop_load`] with the stiffness times `torque_scale` (the plant's peak torque at the output over the
/// reference's), so the stop yields the same share of a count under the current limit.
pub fn end_stop_load_scaled(
    positive: bool,
    stop_counts: f64,
    counts_per_rev: f64,
    j: f64,
    torque_scale: f64,
) -> impl FnMut(f64, f64, f64) -> f64 + Send {
    let k = END_STOP_STIFFNESS_NM_PER_RAD * torque_scale;
    let c = 2.0 * END_STOP_DAMPING_RATIO * (k * j).sqrt();
    let stop_rad = stop_counts / counts_per_rev * 2.0 * PI;
    move |_t, theta, omega| {
        if positive && theta > stop_rad {
            (k * (theta - stop_rad) + c * omega).max(0.0)
        } else if !positive && theta < stop_rad {
            (k * (theta - stop_rad) + c * omega).min(0.0)
        } else {
            0.0
        }
    }
}

/// One homing run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingConfig {
    /// Plant noise seed.
    pub seed: u64,
    /// 0x6098.
    pub method: i8,
    /// Where the run starts.
    pub start: Start,
    /// 0x6099:01, rpm.
    pub switch_search_rpm: u32,
    /// 0x6099:02, rpm.
    pub zero_search_rpm: u32,
    /// 0x609A, rpm/s.
    pub acceleration_rpm_s: u32,
    /// 0x30B0, increments.
    pub home_position_inc: i32,
    /// 0x607C, increments.
    pub home_offset_inc: i32,
    /// 0x30B1, increments. `None`: [`OFFSET_MOVE_INC`] in the approach direction (switch and index methods) or
    /// positive (end stops: the firmware moves its magnitude away from the stop whatever the sign).
    pub offset_move_inc: Option<i32>,
    /// 0x30B2, mA.
    pub current_threshold_ma: u16,
    /// 0x6073 max current, per mille of the rated current (`None`: the default, 10 A).
    pub max_current_permille: Option<u16>,
    /// 0x30B3, increments (0: no limit).
    pub search_limit_inc: u32,
    /// Leave the reference switch (or the end stop) out of the plant: the search cannot find it.
    pub missing_reference: bool,
    /// Simulated time from the start of homing until the run gives up, s.
    pub timeout_s: f64,
    /// Standing time after bit 12 or 13 before the final values are read, s.
    pub settle_s: f64,
    /// The plant's encoder counts per revolution (the drive's 0x3010:01 follows, [`Simulation::new`]); the
    /// scenario plant's (the reference 4,096). The switches and the index gap are placed in counts, within one
    /// revolution of 2,000 on the reference.
    pub counts_per_rev: u32,
    /// Plant counts per reference count of the placement distances ([`geometry_scaled`]): the scenario plant's
    /// revolutions (counts per revolution / 4,096) times [`PlantScale::speed`]; 1 on the reference plant.
    pub distance_scale: f64,
}

impl HomingConfig {
    /// The matrix's settings for `method` from `start`, scaled to the scenario plant (module documentation,
    /// "Another plant"; the reference values on the reference plant).
    pub fn new(seed: u64, method: i8, start: Start) -> Self {
        let plant = scenario_plant();
        let sc = PlantScale::of(&plant);
        let speed = |x: u32| ((f64::from(x) * sc.speed).round() as u32).max(1);
        let distance_scale = sc.speed * f64::from(plant.encoder_counts_per_rev) / CPR as f64;
        Self {
            seed,
            method,
            start,
            switch_search_rpm: speed(SWITCH_SEARCH_RPM),
            zero_search_rpm: speed(ZERO_SEARCH_RPM),
            acceleration_rpm_s: speed(HOMING_ACCELERATION_RPM_S),
            home_position_inc: HOME_POSITION_INC,
            home_offset_inc: HOME_OFFSET_INC,
            offset_move_inc: None,
            current_threshold_ma: (f64::from(CURRENT_THRESHOLD_MA) * sc.current).round().clamp(1.0, 65_535.0) as u16,
            max_current_permille: None,
            search_limit_inc: scaled(i64::from(SEARCH_LIMIT_INC), distance_scale) as u32,
            missing_reference: false,
            timeout_s: 3.0,
            settle_s: SETTLE_S,
            counts_per_rev: plant.encoder_counts_per_rev,
            distance_scale,
        }
    }
}

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Outcome {
    /// Statusword bit 12 (homing attained).
    Attained,
    /// Statusword bit 13 (homing error).
    Error,
    /// Neither within the time budget.
    Timeout,
}

/// What a run measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingResult {
    /// 0x6098.
    pub method: i8,
    /// Where it started.
    pub start: Start,
    /// The placement (plant counts).
    pub geometry: Geometry,
    /// How it ended.
    pub outcome: Outcome,
    /// 0x6041 before homing was started.
    pub statusword_before: u16,
    /// 0x6041 after standing for [`HomingConfig::settle_s`].
    pub statusword: u16,
    /// 0x30D1:01 (averaged q current) after settling, mA.
    pub current_average_ma: i32,
    /// The drive's position value of the true reference point after homing, `R - encoder offset + 0x6064 -
    /// 0x6063`.
    pub drive_reference_inc: i64,
    /// The value the reference point must have: 0x30B0 + 0x607C minus the home offset move.
    pub expected_reference_inc: i64,
    /// `drive_reference_inc - expected_reference_inc` (meaningful when attained).
    pub home_error_inc: i64,
    /// 0x6064 after settling.
    pub position_inc: i32,
    /// 0x6064 - (0x30B0 + 0x607C) after settling: where the axis stands against the home point.
    pub position_error_inc: i64,
    /// The plant count minus the drive's raw encoder position at the start of the run ([`encoder_offset`]).
    pub encoder_offset_inc: i64,
    /// Change of [`encoder_offset`] over the run (0: the drive followed every count).
    pub encoder_drift_inc: i64,
    /// The plant count where the axis stands at the end.
    pub stopped_at_inc: i64,
    /// Simulated time from controlword 0x1F to bit 12 or 13, s.
    pub homing_s: f64,
    /// Simulated time of the whole run (preparation included), s.
    pub simulated_s: f64,
}

impl HomingResult {
    /// Attained, within +-1 increment of the true reference, statusword 13/12/10 = 0/1/1 and bit 15 set.
    pub fn passed(&self) -> bool {
        let sw = self.statusword;
        self.outcome == Outcome::Attained
            && self.home_error_inc.abs() <= 1
            && sw & (BIT13 | BIT12 | TARGET_REACHED | 1 << 15) == BIT12 | TARGET_REACHED | 1 << 15
    }
}

/// The plant count minus the drive's raw encoder position, at the sample the drive last took: the count the
/// plant showed when the drive's encoder started (it counts from 0).
pub fn encoder_offset(sim: &Simulation) -> i64 {
    let now = sim.plant.true_encoder_count();
    // The 16-bit counter of the last sample, extended around the count now (the shaft moves far less than
    // 32,768 counts in one period).
    let counter = sim.measurements().feedback.encoder_count;
    let sampled = now + i64::from(counter.wrapping_sub(now as u16) as i16);
    sampled - i64::from(sim.tier1().commutation().encoder().position())
}

/// 0x6064 - 0x6063: the drive's position offset.
fn position_offset(sim: &Simulation) -> i64 {
    let d = sim.drive.dictionary();
    i64::from(d.get(h::POSITION_ACTUAL_VALUE).wrapping_sub(d.get(h::POSITION_ACTUAL_INTERNAL_VALUE)))
}

/// Runs slow ticks until `done` holds for the statusword (checked after each) or `max` ticks passed.
fn ticks_until(sim: &mut Simulation, max: u64, mut done: impl FnMut(&Simulation) -> bool) -> Option<u64> {
    for k in 1..=max {
        sim.run_slow_ticks(1);
        if done(sim) {
            return Some(k);
        }
    }
    None
}

/// The master moves the axis to plant count `count` in PPM (absolute move, at the positioning speeds times
/// `speed_scale`) and waits for target reached.
fn position_axis(sim: &mut Simulation, count: i64, speed_scale: f64) -> Result<(), SimError> {
    let target = count - encoder_offset(sim) + position_offset(sim);
    let speed = |x: u32| ((f64::from(x) * speed_scale).round() as u32).max(1);
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::PROFILE_VELOCITY, speed(POSITIONING_RPM));
        d.set(h::PROFILE_ACCELERATION, speed(POSITIONING_RPM_S));
        d.set(h::PROFILE_DECELERATION, speed(POSITIONING_RPM_S));
        d.set(h::TARGET_POSITION, i32::try_from(target).unwrap_or(i32::MAX));
    }
    sim.set_controlword(ENABLE_OPERATION);
    sim.run_slow_ticks(2);
    sim.set_controlword(ENABLE_OPERATION | BIT4);
    ticks_until(sim, 50, |s| s.statusword() & BIT12 != 0).ok_or(SimError::Timeout("the set-point acknowledge"))?;
    sim.set_controlword(ENABLE_OPERATION);
    ticks_until(sim, POSITIONING_TIMEOUT_TICKS, |s| {
        s.statusword() & TARGET_REACHED != 0 && i64::from(s.drive.dictionary().get(h::POSITION_DEMAND_VALUE)) == target
    })
    .ok_or(SimError::Timeout("the positioning move"))?;
    // Let the position loop settle (about 10 ms).
    sim.run_slow_ticks(25);
    Ok(())
}

/// Wires the switches and the end stop of `g` into the plant (`missing`: without the reference switch or stop).
fn place(sim: &mut Simulation, truth: &Truth, g: &Geometry, missing: bool) {
    // The stop acts at the output: its counts per output revolution and the inertia there.
    let params = sim.plant.params();
    let torque_scale = PlantScale::of(params).torque;
    let j = params.total_inertia_kg_m2() * params.gear_ratio * params.gear_ratio;
    let cpr = f64::from(params.encoder_counts_per_rev) * params.gear_ratio;
    let io = &mut sim.plant.params_mut().io;
    io.set_negative_limit(g.negative_limit.map(|b| b - 1));
    io.set_positive_limit(g.positive_limit);
    io.set_home_switch(g.home_switch);
    if missing {
        match truth.family {
            Family::Limit { negative: true } => io.set_negative_limit(None),
            Family::Limit { negative: false } => io.set_positive_limit(None),
            Family::HalfAxis { .. } | Family::Band { .. } => io.set_home_switch(InputSource::Open),
            Family::Index | Family::EndStop { .. } | Family::Here => {}
        }
    }
    match g.end_stop {
        Some((positive, at)) if !missing => {
            sim.plant.set_load_profile(Some(Box::new(end_stop_load_scaled(positive, at, cpr, j, torque_scale))));
        }
        _ => sim.plant.set_load_profile(None),
    }
}

/// The signed displacement of the home offset move the drive makes for `value` in 0x30B1.
fn displacement(truth: &Truth, value: i32) -> i64 {
    match truth.family {
        Family::EndStop { .. } => truth.approach * i64::from(value.unsigned_abs()),
        // 35/37 take the actual position as the home point at once, without an offset move.
        Family::Here => 0,
        _ => i64::from(value),
    }
}

/// Runs the matrix's settings for `method` from `start` (see [`HomingConfig::new`]).
pub fn homing_run(seed: u64, method: i8, start: Start) -> Result<HomingResult, RunError> {
    homing_run_with(&HomingConfig::new(seed, method, start))
}

/// One run (see the module documentation). Errors: the preparation, the positioning move or the mode change
/// failed, or the method and start have no geometry. A homing that ends in bit 13 or in no bit is a result
/// ([`Outcome`]), not an error.
pub fn homing_run_with(cfg: &HomingConfig) -> Result<HomingResult, RunError> {
    let truth = truth(cfg.method).ok_or(RunError::UndefinedMethod(cfg.method))?;
    let no_start = RunError::NoSuchStart(cfg.method, cfg.start);
    let offset_move_magnitude = scaled(i64::from(OFFSET_MOVE_INC), cfg.distance_scale) as i32;
    let offset_move = cfg.offset_move_inc.unwrap_or(match truth.family {
        Family::EndStop { .. } => offset_move_magnitude,
        _ if truth.approach > 0 => offset_move_magnitude,
        _ => -offset_move_magnitude,
    });
    let disp = displacement(&truth, offset_move);
    let plant = PlantParams { encoder_counts_per_rev: cfg.counts_per_rev, ..scenario_plant() };
    let speed_scale = PlantScale::of(&plant).speed;
    let mut sim = prepare_motion_on(plant, cfg.seed, 1)?;
    let cpr = i64::from(cfg.counts_per_rev);
    // The index that puts the start nearest the axis.
    let probe = geometry_scaled(&truth, cfg.start, 0, disp, cfg.distance_scale).ok_or(no_start)?;
    let enc_offset = encoder_offset(&sim);
    let here = sim.plant.true_encoder_count();
    let index = (here - probe.start + cpr / 2).div_euclid(cpr) * cpr;
    let mut g = geometry_scaled(&truth, cfg.start, index, disp, cfg.distance_scale).ok_or(no_start)?;
    position_axis(&mut sim, g.start, speed_scale)?;

    // HMM with the controlword at «Enable operation» (no bit 4), then the switches and the homing objects.
    sim.set_mode(6);
    ticks_until(&mut sim, 50, |s| s.drive.dictionary().get(h::MODES_OF_OPERATION_DISPLAY) == 6)
        .ok_or(SimError::Timeout("the mode change to HMM"))?;
    place(&mut sim, &truth, &g, cfg.missing_reference);
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::HOMING_METHOD, cfg.method);
        d.set(h::HOMING_SPEED_SWITCH_SEARCH, cfg.switch_search_rpm);
        d.set(h::HOMING_SPEED_ZERO_SEARCH, cfg.zero_search_rpm);
        d.set(h::HOMING_ACCELERATION, cfg.acceleration_rpm_s);
        d.set(h::HOME_POSITION, cfg.home_position_inc);
        d.set(h::HOME_OFFSET, cfg.home_offset_inc);
        d.set(h::HOME_OFFSET_MOVE_DISTANCE, offset_move);
        d.set(h::HOMING_CURRENT_THRESHOLD, cfg.current_threshold_ma);
        d.set(h::HOMING_SEARCH_DISTANCE_LIMIT, cfg.search_limit_inc);
        if let Some(permille) = cfg.max_current_permille {
            d.set(h::MAX_CURRENT, permille);
        }
    }
    sim.run_slow_ticks(5);
    if matches!(truth.family, Family::Here) {
        // The actual position is the reference: the count the shaft stands on now.
        g.start = sim.plant.true_encoder_count();
        g.reference = g.start;
    }

    // Start: bit 4 rising; the master watches bits 12 and 13 every slow tick.
    let statusword_before = sim.statusword();
    let t0 = sim.time_s();
    sim.set_controlword(ENABLE_OPERATION | BIT4);
    let max_ticks = (cfg.timeout_s / (10.0 * PERIOD_S)).ceil() as u64;
    let ended = ticks_until(&mut sim, max_ticks, |s| s.statusword() & (BIT12 | BIT13) != 0);
    let homing_s = sim.time_s() - t0;
    let sw = sim.statusword();
    let outcome = match ended {
        Some(_) if sw & BIT12 != 0 => Outcome::Attained,
        Some(_) => Outcome::Error,
        None => Outcome::Timeout,
    };
    sim.run((cfg.settle_s / PERIOD_S).round() as u64);

    let d = sim.drive.dictionary();
    let home_value = i64::from(cfg.home_position_inc.wrapping_add(cfg.home_offset_inc));
    let drive_reference = g.reference - enc_offset + position_offset(&sim);
    let expected = home_value - disp;
    let position = d.get(h::POSITION_ACTUAL_VALUE);
    Ok(HomingResult {
        method: cfg.method,
        start: cfg.start,
        geometry: g,
        outcome,
        statusword_before,
        statusword: d.get(h::STATUSWORD),
        current_average_ma: d.get(h::CURRENT_ACTUAL_VALUE_AVERAGED),
        drive_reference_inc: drive_reference,
        expected_reference_inc: expected,
        home_error_inc: drive_reference - expected,
        position_inc: position,
        position_error_inc: i64::from(position) - home_value,
        encoder_offset_inc: enc_offset,
        encoder_drift_inc: encoder_offset(&sim) - enc_offset,
        stopped_at_inc: sim.plant.true_encoder_count(),
        homing_s,
        simulated_s: sim.time_s(),
    })
}

/// What [`homing_matrix`] measured.
#[derive(Clone, Debug, PartialEq)]
pub struct HomingMatrix {
    /// Methods run.
    pub methods_tested: usize,
    /// Methods whose every run [`HomingResult::passed`].
    pub methods_passed: usize,
    /// Largest |home error| over all runs, increments (`i64::MAX` if a run did not attain).
    pub home_error_max_inc: i64,
    /// Every run.
    pub rows: Vec<HomingResult>,
}

/// Every method of `methods` from each of its [`starts`].
pub fn homing_matrix_of(seed: u64, methods: &[i8]) -> Result<HomingMatrix, RunError> {
    homing_matrix_of_with_progress(seed, methods, &mut |_, _| {})
}

/// [`homing_matrix_of`], telling `progress(done, total)` how many of its runs (one per method and start) are
/// finished, before the first and after each (for a progress bar: `drive-sim homing` on a terminal). The
/// observer only reads the count; the runs and their figures are the same with any observer.
pub fn homing_matrix_of_with_progress(
    seed: u64,
    methods: &[i8],
    progress: &mut dyn FnMut(u64, u64),
) -> Result<HomingMatrix, RunError> {
    let total = methods.iter().map(|&method| starts(method).len() as u64).sum();
    let mut done = 0;
    progress(done, total);
    let mut m = HomingMatrix { methods_tested: 0, methods_passed: 0, home_error_max_inc: 0, rows: Vec::new() };
    for &method in methods {
        let mut all = !starts(method).is_empty();
        for &start in starts(method) {
            let r = homing_run(seed, method, start)?;
            done += 1;
            progress(done, total);
            all &= r.passed();
            m.home_error_max_inc = m.home_error_max_inc.max(match r.outcome {
                Outcome::Attained => r.home_error_inc.abs(),
                _ => i64::MAX,
            });
            m.rows.push(r);
        }
        m.methods_tested += 1;
        m.methods_passed += usize::from(all);
    }
    Ok(m)
}

/// Every supported method (0x60E3, `firmware::motion::homing::SUPPORTED_METHODS`) from each of its [`starts`].
pub fn homing_matrix(seed: u64) -> Result<HomingMatrix, RunError> {
    homing_matrix_with_progress(seed, &mut |_, _| {})
}

/// [`homing_matrix`] with the progress observer of [`homing_matrix_of_with_progress`].
pub fn homing_matrix_with_progress(seed: u64, progress: &mut dyn FnMut(u64, u64)) -> Result<HomingMatrix, RunError> {
    homing_matrix_of_with_progress(seed, &firmware::motion::homing::SUPPORTED_METHODS, progress)
}
