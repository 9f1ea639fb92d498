//! The mechanical step of the motor identification (issue 18 item 3; step 5 of the auto setup, PD4-E seed 003
//! "Auto setup" p.25-27): with the commutation known and the d current held at zero, a speed-bounded relay
//! experiment measures the torque constant (flux linkage), the total inertia seen at the motor and the Coulomb
//! and viscous friction.
//!
//! # The experiment
//! 1. Probe: a q current of 1/16 of the test current limit, doubled every [`PROBE_TICKS`] until the speed reaches
//!    a quarter of the relay speed. The acceleration it took gives the current for the relay (a half cycle of
//!    about [`HALF_CYCLE_TARGET_TICKS`]), so that an unknown inertia (10 to 3,200 g cm^2 on the presets) gets a
//!    useful experiment. Where that current exceeds the test current limit, the relay speed comes down by the
//!    ratio instead (`slow_relay_to_limit`), so that a heavy load on a weak motor still gets its half cycles.
//!    No movement at the full test current: [`MechanicalError::Obstructed`] (IDX 0xFF21).
//! 2. Relay: +I until the speed reaches +w, -I until it reaches -w (w = half the max system speed, or less where
//!    the q voltage nears the bus's linear range), the reversal ramped over [`RAMP_TICKS`] so that an elastic
//!    coupling is excited less. The first three half cycles, and the first three after each lowering of the
//!    relay speed, rescale the current to a half cycle of [`HALF_CYCLE_TARGET_TICKS`]. A half cycle whose braking
//!    lifts the bus near the drive's bus-voltage limiter (0x3202:02, which would add d current and cut the braking
//!    current: `super::regeneration`) counts in no fit and lowers the relay speed by 3/4 (on the geared preset
//!    without a chopper from 1,000 to about 230 rpm). "Near" is 15/16 of the limiter's voltage, or half way to it
//!    from the bus at rest where the supply sits above 7/8 of it (a 48 V supply under the default 51 V); a bus that
//!    rests within 1/32 of it fails the step at once ([`MechanicalError::InvalidConfig`], IDX 0xFF16: 0x3202:02
//!    against the supply). The relay ends after [`MIN_HALF_CYCLES`] half cycles without such a reduction and
//!    [`MIN_RELAY_TICKS`].
//! 3. Stop: the current against the speed until it changes sign; then the solution, one part per slow tick over
//!    three ticks (no slow tick carries all of it), and the results.
//!
//! The speed never exceeds the max system speed ([`MechanicalError::SpeedLimit`], IDX 0xFF22), the whole step
//! never the configured timeout ([`MechanicalError::Timeout`], IDX 0xFF19). IDX codes: seed 002 L7516-7596.
//!
//! # Estimates (integer least squares, no floats)
//! - Torque constant: `v_q - R i_q = lambda p omega + u sign(i_q) + u0`, fitted over the relay's ticks with
//!   |i_q| above half the relay current, summed over each block of [`BLOCK_TICKS`] into one equation. A single
//!   tick's increment carries the encoder's quantization (+-1/2 count against 3.4 counts per tick at the relay
//!   speed of a 1,024-count encoder), and an error in the regressor pulls the fit's slope towards zero: kt came
//!   out 4.75 % low on such a motor (0.68 % at 4,096 counts); a block's sum has the error of one difference of
//!   the position. `u` takes the inverter's dead-time voltage, an error of R (|i_q| is
//!   constant) and the half-tick skew of a last-period v_q (the acceleration's sign is the current's); omega changes
//!   sign inside each half cycle, so lambda is separable. kt = 1.5 p lambda (amplitude-invariant dq, the plant's
//!   and the drive's convention).
//! - Mechanics: the position's second difference over two blocks of [`BLOCK_TICKS`], `D2 = x(j) - 2 x(j-1) +
//!   x(j-2)`, is exactly the acceleration weighted by a tent over the two blocks. With
//!   `J a = kt i_q - Tc sign(w) - B w`, the tent-weighted sums of i_q, sign(w) and w (the position increments)
//!   are the regressors of D2: three coefficients give J, Tc and B (kt from the first fit). The position is exact (no velocity
//!   differentiation), each block pair is one equation, and the relay makes current sign, speed sign and
//!   speed independent regressors. Only block pairs at a steady current demand count: while the current ramps,
//!   an elastic coupling winds up and the motor runs ahead of (or behind) the load by the twist's rate, which on
//!   the geared preset made the inertia 16 % too large; between the ramps the motor's mean acceleration is the
//!   whole drivetrain's, and the fit sees the total inertia. The run-up from rest to the first reversal counts in
//!   no fit: it drives alone, while every later half cycle brakes for about as long as it drives, and a gear with
//!   losses shows the motor `J_load / (eta N^2)` while it drives and `eta J_load / N^2` while the load drives it
//!   back (geared preset, 90 %: +10.4 % and -9.4 % of the total); a relay that brakes as much as it drives fits
//!   about their harmonic mean (-0.5 %), the run-up alone pulls it towards the driving one.
//!
//! - Plausibility: the even and the odd full relay cycles are two experiments, each fitted alone; their inertias
//!   must agree within a quarter of the whole fit's, and the Coulomb and viscous friction torques (at the relay
//!   speed) must be below the relay current's torque, which moved the shaft. Otherwise the step fails
//!   ([`MechanicalError::SampleMismatch`]) rather than write a value the loops would be tuned from. A relay that
//!   does not reach its speed in [`STALL_TICKS`] (a current below the breakaway torque: the probe's and the
//!   adaptation's accelerations include the friction's share) doubles its current, and blocks in which the shaft
//!   stood count in no fit (static friction is not `Tc sign(w)`).
//!
//! - Friction split: the relay's speed sweeps between its two reversals, so the fit separates the Coulomb term
//!   from the viscous one only as far as the friction it saw depends on the speed. On a servo axis at a fraction
//!   of its rated speed the Coulomb part dominates (reference plant: the fitted viscous torque at the relay's mean
//!   speed, 700 rpm, is 0.20 to 0.25 mNm against 2.9 mNm of Coulomb friction). Where the fit puts more than a
//!   quarter of the Coulomb friction into the viscous term at that speed ([`VISCOUS_SHARE_DIVISOR`]), in either
//!   sign, it has split a friction it did not resolve: on the geared preset, whose gear losses and backlash change
//!   with the relay's phase, seeds 1 to 6 gave B from -57 to +200 x the plant's (Coulomb 0.004 to 0.040 Nm), while
//!   the sum at the relay's mean speed stayed within 0.0287 to 0.0328 Nm. The drive then keeps that sum as Coulomb
//!   friction and B = 0: the velocity feed-forwards `B / kt` (0x30A1:04, 0x30A2:03) pushed the geared CSP 39 to 42
//!   increments off its path with the large B of seeds 4 and 6 (1.8 to 2.1 A of feed-forward at the move's
//!   980 rpm), 26 and 25 with B = 0.
//!
//! Each fit accumulates its normal equations in `i128` ([`Regression3`]) and is solved once at the end by
//! Cramer's rule on the equations scaled to 40 bits. Cost per slow tick: a few dozen 64-bit products; the solve
//! at the end, spread over three slow ticks: 3 x 4 determinants of the scaled equations (64 x 64-bit minors, one
//! 128-bit product per term) and a few divisions on the hardware divider ([`wide::div_shl`]).

use crate::control::frames::{Amps, Volts};
use crate::control::velocity::SLOW_TICK_HZ;
use crate::control::wide;

/// Ticks per block of the mechanical fit (3.2 ms at 2.5 kHz): long enough that the second difference of the
/// position is many counts, short enough for many equations per half cycle.
pub const BLOCK_TICKS: u32 = 8;
/// The viscous torque at the relay's mean speed may be at most the Coulomb friction over this, else the fit's
/// split of the friction is not kept (module documentation, "Friction split").
pub const VISCOUS_SHARE_DIVISOR: i64 = 4;
/// Ticks over which the speed for the relay and the limit is a position difference (3.2 ms).
pub const SPEED_TICKS: u32 = 8;
/// Ticks the probe holds one current level before it doubles it (100 ms).
pub const PROBE_TICKS: u32 = 250;
/// Doublings of the probe current: 1/16, 1/8, 1/4, 1/2, 1 of the test current limit.
const PROBE_LEVELS: u32 = 4;
/// The relay's half cycle the probe and the first half cycles aim the current at (250 ms, 625 ticks): long
/// against a coupling's period, so that its ringing after a reversal (whose mean acceleration over the half cycle
/// is its speed change over the whole) is small against the acceleration; on the unit tests' model of the geared
/// preset 100 ms gave a Coulomb friction 90 % off, 250 ms 35 %. The relay ends after about 2 to 3 s.
pub const HALF_CYCLE_TARGET_TICKS: u32 = 625;
/// Ticks of a full current reversal (+I to -I), 20 ms: longer than the period of a 60 Hz coupling resonance,
/// which a step would ring at full amplitude.
pub const RAMP_TICKS: u32 = 50;
/// Half cycles the relay runs at least.
pub const MIN_HALF_CYCLES: u16 = 6;
/// Ticks the relay runs at least (1 s).
pub const MIN_RELAY_TICKS: u32 = 2_500;
/// Ticks the relay runs at most (4 s): with fewer than [`MIN_FIT_HALF_CYCLES`] by then, the step times out.
pub const MAX_RELAY_TICKS: u32 = 10_000;
/// The first half cycles, each of which rescales the relay current; again after each lowering of the relay speed,
/// which would otherwise shorten the half cycles by the same factor (on the geared preset from 625 to 188 ticks, a
/// relay fundamental of 6.7 Hz near its 14 Hz anti-resonance, where the motor no longer moves with the load: the
/// inertia came out 7 to 10 % low).
const ADAPTED_HALF_CYCLES: u16 = 3;
/// Relay ticks without reaching the relay speed after which the current doubles (1 s, four target half cycles).
pub const STALL_TICKS: u32 = 4 * HALF_CYCLE_TARGET_TICKS;
/// The inertias of the even and the odd relay cycles may differ by 1/4 of the whole fit's.
const REPEAT_SPREAD_DIVISOR: u64 = 4;
/// Half cycles the fit needs at the least.
pub const MIN_FIT_HALF_CYCLES: u16 = 2;
/// The relay speed in per mille of the max system speed.
const RELAY_SPEED_PERMILLE: u64 = 500;
/// The q voltage at which the relay reverses whatever the speed, in 1/64 of the bus voltage: 29/64 = 0.45, 78 %
/// of the linear range of space-vector modulation (v_bus / sqrt 3), leaving the current loop its headroom.
const HEADROOM_PER_64: i64 = 29;
/// The least headroom between the bus at rest and the limiter's voltage, `limit >> this` (1/32: 1.59 V under the
/// default 51 V): with less, the identification refuses to start (IDX 0xFF16, the limiter's setting 0x3202:02
/// against the supply).
const MIN_REGENERATION_HEADROOM_SHIFT: u32 = 5;
/// Samples of the position history for the speed: the speed is the position difference over [`SPEED_TICKS`].
const HISTORY: usize = SPEED_TICKS as usize;

/// What the step needs to know (from 0x3001, 0x3002, 0x3010, 0x6080 and the procedure's own limits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MechanicalConfig {
    /// The largest q current the experiment may use (e.g. the motor's nominal current 0x3001:01).
    pub current_limit: Amps,
    /// Max system speed (0x6080 or the motor's max speed) in rpm: exceeding it ends the step (IDX 0xFF22); the
    /// relay runs at half of it.
    pub max_speed_rpm: u32,
    /// Encoder counts (increments) per motor revolution (4 x 0x3010:01).
    pub counts_per_rev: u32,
    /// Pole pairs (0x3001:03): only for the flux linkage result.
    pub pole_pairs: u8,
    /// Phase resistance in milliohm (the procedure's step 2): removes R i_q from v_q.
    pub phase_resistance_milliohm: u32,
    /// The step fails with [`MechanicalError::Timeout`] after this many slow ticks.
    pub timeout_ticks: u32,
    /// The bus voltage from which the drive's bus-voltage limiter may change the currents (0x3202:02, loss
    /// braking voltage; `Volts` of `i16::MAX` with the limiter off): from 15/16 of it (or half way to it from the
    /// bus at rest, `bus_high_voltage`), samples count in no fit and the relay speed is lowered, so that braking
    /// from it returns less energy than the bus takes.
    pub regeneration_limit: Volts,
}

/// One slow tick's measurements.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MechanicalSample {
    /// Multi-turn encoder position in increments (wrapping).
    pub position: i32,
    /// Measured q current, the average over the slow tick's periods: a single period's sample carries the
    /// shunts' noise into the mechanical fit (on the small gimbal +13 % inertia, against +2 % averaged).
    pub i_q: Amps,
    /// Applied q voltage, the average over the same periods (the last period's adds only noise).
    pub v_q: Volts,
    /// DC-bus voltage: the relay reverses early when v_q nears the bus's linear range, and lowers its speed when
    /// braking lifts the bus near the limiter ([`MechanicalConfig::regeneration_limit`]).
    pub v_bus: Volts,
}

/// What the step found. Units are those of the objects the results go into.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MechanicalResult {
    /// Torque constant in uNm/A (0x3001:05).
    pub torque_constant: u32,
    /// Flux linkage (peak phase flux) in uWb: kt / (1.5 p).
    pub flux_linkage_uwb: u32,
    /// Total inertia at the motor shaft in 0.001 g cm^2 (0x30A3:05).
    pub inertia: u32,
    /// Viscous friction at the motor shaft in 0.001 uNm/rpm (0x30A3:04).
    pub viscous_friction: u32,
    /// Coulomb friction at the motor shaft in uNm.
    pub coulomb_friction: u32,
    /// The q voltage per sign of the current that the torque-constant fit absorbed (inverter dead time, R error),
    /// in mV: a diagnostic.
    pub current_sign_voltage_mv: i32,
    /// The relay's current.
    pub relay_current: Amps,
    /// Relay half cycles completed.
    pub half_cycles: u16,
    /// The relay speed at the end (rpm): half the max system speed, or less where the bus could not take the
    /// braking energy.
    pub relay_speed_rpm: u32,
    /// Slow ticks the step took.
    pub ticks: u32,
}

/// Why the step failed; each maps to one IDX code (seed 002 L7096-7110).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MechanicalError {
    /// The speed exceeded the max system speed: IDX 0xFF22 "Auto tuning max system speed error".
    SpeedLimit,
    /// The step did not finish within the timeout, or the relay completed too few half cycles in
    /// [`MAX_RELAY_TICKS`]: IDX 0xFF19 "Auto tuning timeout error".
    Timeout,
    /// No movement at the full test current: IDX 0xFF21 "Auto tuning torque invalid error" (movement
    /// obstructed).
    Obstructed,
    /// The motor turned against the current, or the fit gave a non-physical plant (kt or inertia not positive,
    /// singular equations, a friction torque at or above the relay's), or the even and odd relay cycles
    /// disagree on the inertia: IDX 0xFF15 "Auto tuning sample mismatch error".
    SampleMismatch,
    /// A configuration value is zero: IDX 0xFF16 "Auto tuning parameter error".
    InvalidConfig,
}

impl MechanicalError {
    /// The IDX error code (seed 002 L7096-7110).
    #[must_use]
    pub const fn code(self) -> u16 {
        match self {
            Self::SpeedLimit => 0xFF22,
            Self::Timeout => 0xFF19,
            Self::Obstructed => 0xFF21,
            Self::SampleMismatch => 0xFF15,
            Self::InvalidConfig => 0xFF16,
        }
    }
}

/// The step's answer to one sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MechanicalStatus {
    /// Still running: apply this q current (d current zero) until the next slow tick.
    Running {
        /// The q current demand.
        i_q_demand: Amps,
    },
    /// Finished: the caller sets the q current to zero.
    Done(MechanicalResult),
    /// Failed: the caller switches the power stage off and raises the error's code.
    Failed(MechanicalError),
}

/// The experiment's phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Filling the position history (the motor at rest).
    Start { ticks: u32 },
    /// Probe current level `level` (0 = 1/16 of the limit), held for `ticks`; `start_speed` at its start.
    Probe { level: u32, ticks: u32, start_speed: i64 },
    /// Relay towards `direction` (+1/-1).
    Relay { direction: i64 },
    /// Braking against `direction`, the sign of the speed when the relay ended.
    Stop { direction: i64 },
    /// Solving, one part per slow tick (0: the torque-constant fit, 1 and 2: the mechanical fits of the even and
    /// the odd relay cycles, 3: the whole mechanical fit, 4: the results), so that no slow tick carries all of it.
    Solve(u8),
    /// Finished.
    Finished(MechanicalStatus),
}

/// Sums over one block of the mechanical fit: plain (`s0`) and ramp-weighted (`s1`, tick m = 1..8 weighted by m)
/// sums of the current (bits), the speed sign and the position increment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct BlockSums {
    s0: [i64; 3],
    s1: [i64; 3],
    /// The block's position difference (counts).
    travel: i64,
    /// The current demand changed in the block or the tick before it, or the bus was near the limiter's voltage,
    /// or the shaft stood.
    ramping: bool,
    /// Ticks of the block without a position change.
    standing: u8,
}

impl BlockSums {
    /// The rising half of the tent (weights 2m - 1): this block is the first of the pair. Out of line, as
    /// [`Self::falling`]: the pair's three regressors would inline each three times (flash, issue 17).
    #[inline(never)]
    fn rising(&self, k: usize) -> i64 {
        let (s0, s1) = (get(&self.s0, k), get(&self.s1, k));
        s1.saturating_mul(2).saturating_sub(s0)
    }

    /// The falling half of the tent (weights 2N - 2m + 1): this block is the second of the pair.
    #[inline(never)]
    fn falling(&self, k: usize) -> i64 {
        let (s0, s1) = (get(&self.s0, k), get(&self.s1, k));
        let n = i64::from(BLOCK_TICKS);
        s0.saturating_mul(n.saturating_mul(2).saturating_add(1)).saturating_sub(s1.saturating_mul(2))
    }
}

/// `a b`, saturated: the 64-bit overflow-checked product is some 20 instructions, once here instead of at each
/// use (flash, issue 17).
#[inline(never)]
fn sat_mul(a: i64, b: i64) -> i64 {
    a.saturating_mul(b)
}

fn get(a: &[i64; 3], k: usize) -> i64 {
    a.get(k).copied().unwrap_or(0)
}

/// The mechanical identification. See the module documentation.
#[derive(Clone, Debug)]
pub struct MechanicalIdentification {
    config: MechanicalConfig,
    phase: Phase,
    /// Slow ticks since the start.
    ticks: u32,
    /// The max system speed in counts per [`SPEED_TICKS`].
    speed_limit: i64,
    /// The relay speed in counts per [`SPEED_TICKS`].
    relay_speed: i64,
    /// Position history (ring) for the speed over [`SPEED_TICKS`].
    history: [i32; HISTORY],
    history_at: usize,
    last_position: i32,
    /// The relay current in bits (1/65536 A), from the probe.
    relay_current: i64,
    /// The q current demand in bits, ramped in the relay.
    demand: i64,
    /// The demand of the tick before (for the mechanical fit's steady blocks).
    previous_demand: i64,
    relay_ticks: u32,
    half_cycles: u16,
    /// Half cycles since the relay speed was last lowered.
    clean_half_cycles: u16,
    /// The bus reached [`Self::bus_high_voltage`] since the last reversal.
    bus_high: bool,
    /// The bus voltage from which samples count in no fit (module documentation, "The experiment" 2).
    bus_high_voltage: Volts,
    /// Relay tick and speed at the last reversal (the relay's start at first).
    half_start: (u32, i64),
    /// Ticks into the current block and its sums; the previous complete block.
    block_tick: u32,
    block: BlockSums,
    previous_block: Option<BlockSums>,
    block_start: i32,
    electrical: Regression3,
    /// The electrical fit's sums over the current block: increments, current signs, ticks, `v_q - R i_q`.
    electrical_block: [i64; 4],
    /// The mechanical fit's equations of the even and the odd full relay cycles: each is an experiment of its
    /// own, their inertias must agree (the plausibility check), and their sum is the fit.
    mechanical: [Regression3; 2],
    electrical_solution: Option<Solution3>,
    /// The solutions of the two halves and of the whole.
    mechanical_solution: [Option<Solution3>; 3],
    /// The highest progress shown, per mille.
    progress: u16,
}

impl MechanicalIdentification {
    /// A step at its start; the first [`Self::step`] takes the rest position.
    #[must_use]
    pub fn new(config: &MechanicalConfig) -> Self {
        // counts per SPEED_TICKS at n rpm: n cpr SPEED_TICKS / (60 f).
        let per_block = |rpm: u64| -> i64 {
            let num = rpm.saturating_mul(u64::from(config.counts_per_rev)).saturating_mul(u64::from(SPEED_TICKS));
            let den = 60u64.saturating_mul(u64::from(SLOW_TICK_HZ));
            i64::try_from(num.checked_div(den).unwrap_or(0)).unwrap_or(i64::MAX)
        };
        let max_rpm = u64::from(config.max_speed_rpm);
        let relay_rpm = max_rpm.saturating_mul(RELAY_SPEED_PERMILLE).checked_div(1000).unwrap_or(0);
        Self {
            config: *config,
            phase: Phase::Start { ticks: 0 },
            ticks: 0,
            speed_limit: per_block(max_rpm),
            relay_speed: per_block(relay_rpm),
            history: [0; HISTORY],
            history_at: 0,
            last_position: 0,
            relay_current: 0,
            demand: 0,
            previous_demand: 0,
            relay_ticks: 0,
            half_cycles: 0,
            clean_half_cycles: 0,
            bus_high: false,
            bus_high_voltage: Volts::from_bits(i32::MAX),
            half_start: (0, 0),
            block_tick: 0,
            block: BlockSums::default(),
            previous_block: None,
            block_start: 0,
            electrical: Regression3::default(),
            electrical_block: [0; 4],
            mechanical: [Regression3::default(); 2],
            electrical_solution: None,
            mechanical_solution: [None; 3],
            progress: 0,
        }
    }

    /// Progress of the step in per mille: probe 0..100, relay 100..900, stop 900, solving 950, finished 1,000;
    /// never falling (a lowered relay speed restarts the count of half cycles, not the progress shown).
    #[must_use]
    pub const fn progress_per_mille(&self) -> u16 {
        self.progress
    }

    /// The progress by the phase now.
    fn phase_progress(&self) -> u16 {
        match self.phase {
            Phase::Start { .. } => 0,
            Phase::Probe { level, .. } => u16::try_from(level.saturating_mul(20)).unwrap_or(100).min(100),
            Phase::Relay { .. } => {
                let by_ticks = u64::from(self.relay_ticks).saturating_mul(800).checked_div(u64::from(MIN_RELAY_TICKS));
                let by_cycles =
                    u64::from(self.clean_half_cycles).saturating_mul(800).checked_div(u64::from(MIN_HALF_CYCLES));
                let (by_ticks, by_cycles) = (by_ticks.unwrap_or(800), by_cycles.unwrap_or(800));
                u16::try_from(by_ticks.min(by_cycles).min(800)).unwrap_or(800).saturating_add(100)
            }
            Phase::Stop { .. } => 900,
            Phase::Solve(_) => 950,
            Phase::Finished(_) => 1000,
        }
    }

    /// One slow tick: takes the sample, returns the current to apply or the outcome (repeated once finished).
    pub fn step(&mut self, sample: &MechanicalSample) -> MechanicalStatus {
        if let Phase::Finished(status) = self.phase {
            return status;
        }
        let status = self.advance(sample);
        self.progress = self.progress.max(self.phase_progress());
        if !matches!(status, MechanicalStatus::Running { .. }) {
            self.phase = Phase::Finished(status);
        }
        status
    }

    fn advance(&mut self, sample: &MechanicalSample) -> MechanicalStatus {
        let c = &self.config;
        if c.current_limit <= Amps::ZERO
            || c.regeneration_limit <= Volts::ZERO
            || self.speed_limit < 4
            || c.counts_per_rev == 0
            || c.pole_pairs == 0
        {
            return MechanicalStatus::Failed(MechanicalError::InvalidConfig);
        }
        self.ticks = self.ticks.saturating_add(1);
        if self.ticks > c.timeout_ticks {
            return MechanicalStatus::Failed(MechanicalError::Timeout);
        }
        let position = sample.position;
        if let Phase::Start { ticks: 0 } = self.phase {
            self.history = [position; HISTORY];
            self.last_position = position;
        }
        let increment = i64::from(position.wrapping_sub(self.last_position));
        self.last_position = position;
        let slot = self.history.get_mut(self.history_at);
        let speed = slot.map_or(0, |old| {
            let speed = i64::from(position.wrapping_sub(*old));
            *old = position;
            speed
        });
        self.history_at = self.history_at.wrapping_add(1).checked_rem(HISTORY).unwrap_or(0);
        if speed.abs() > self.speed_limit {
            return MechanicalStatus::Failed(MechanicalError::SpeedLimit);
        }
        // The q voltage near the linear range counts as the relay speed reached.
        let headroom = i64::from(sample.v_q.to_bits()).abs().saturating_mul(64)
            >= i64::from(sample.v_bus.to_bits()).saturating_mul(HEADROOM_PER_64);
        match self.phase {
            Phase::Start { ticks } => {
                self.phase = if ticks.saturating_add(1) >= SPEED_TICKS {
                    // The bus at rest: the last of the start's ticks, with no current since the step began.
                    match bus_high_voltage(sample.v_bus, self.config.regeneration_limit) {
                        Some(voltage) => self.bus_high_voltage = voltage,
                        None => return MechanicalStatus::Failed(MechanicalError::InvalidConfig),
                    }
                    Phase::Probe { level: 0, ticks: 0, start_speed: speed }
                } else {
                    Phase::Start { ticks: ticks.saturating_add(1) }
                };
                self.demand = 0;
            }
            Phase::Probe { level, ticks, start_speed } => {
                if let Some(error) = self.probe(level, ticks, start_speed, speed, headroom) {
                    return MechanicalStatus::Failed(error);
                }
            }
            Phase::Relay { direction } => {
                self.record(sample, increment, position);
                self.relay(direction, speed, headroom);
            }
            Phase::Stop { direction } => {
                self.record(sample, increment, position);
                if sat_mul(speed, direction) <= 0 {
                    self.demand = 0;
                    if self.half_cycles < MIN_FIT_HALF_CYCLES {
                        return MechanicalStatus::Failed(MechanicalError::Timeout);
                    }
                    self.phase = Phase::Solve(0);
                } else {
                    self.ramp_towards(sat_mul(direction.saturating_neg(), self.relay_current));
                }
            }
            Phase::Solve(part) => {
                if let Some(status) = self.solve(part) {
                    return status;
                }
            }
            Phase::Finished(status) => return status,
        }
        MechanicalStatus::Running { i_q_demand: Amps::from_bits(wide::sat_i32(i128::from(self.demand))) }
    }

    /// One probe tick at `level`; sets the relay up when the speed is reached.
    fn probe(
        &mut self,
        level: u32,
        ticks: u32,
        start_speed: i64,
        speed: i64,
        headroom: bool,
    ) -> Option<MechanicalError> {
        let limit = i64::from(self.config.current_limit.to_bits());
        let current = limit >> PROBE_LEVELS.saturating_sub(level);
        let ticks = ticks.saturating_add(1);
        let gained = speed.saturating_sub(start_speed);
        let probe_speed = (self.relay_speed / 4).max(2);
        if speed <= probe_speed.saturating_neg() {
            // Turning against a positive current: the commutation or the direction is wrong.
            return Some(MechanicalError::SampleMismatch);
        }
        let reached = speed >= probe_speed || headroom;
        let last_level = level >= PROBE_LEVELS;
        if reached || (ticks >= PROBE_TICKS && last_level && gained >= i64::from(SPEED_TICKS)) {
            // Acceleration a_p = gained / ticks (counts per block per tick) at `current`; the relay wants
            // a_r = 2 w / T: I = current a_r / a_p = current 2 w ticks / (T gained).
            let wanted = relay_current_for(current, self.relay_speed, ticks, gained.max(1)).unwrap_or(limit);
            self.slow_relay_to_limit(wanted, limit);
            self.relay_current = wanted.max(limit >> (PROBE_LEVELS.saturating_add(1))).min(limit);
            self.phase = Phase::Relay { direction: 1 };
            self.half_start = (0, speed);
            self.block_start = self.last_position;
            self.demand = current;
            return None;
        }
        if ticks >= PROBE_TICKS {
            if last_level {
                return Some(MechanicalError::Obstructed);
            }
            self.phase = Phase::Probe { level: level.saturating_add(1), ticks: 0, start_speed: speed };
            self.demand = limit >> PROBE_LEVELS.saturating_sub(level.saturating_add(1));
        } else {
            self.phase = Phase::Probe { level, ticks, start_speed };
            self.demand = current;
        }
        None
    }

    /// One relay tick: reverses at the relay speed, ends after enough half cycles.
    fn relay(&mut self, direction: i64, speed: i64, headroom: bool) {
        self.relay_ticks = self.relay_ticks.saturating_add(1);
        let enough = self.clean_half_cycles >= MIN_HALF_CYCLES && self.relay_ticks >= MIN_RELAY_TICKS;
        if enough || self.relay_ticks >= MAX_RELAY_TICKS {
            let moving = if speed < 0 { -1 } else { 1 };
            self.phase = Phase::Stop { direction: moving };
            self.ramp_towards(sat_mul(self.relay_current, moving.saturating_neg()));
            return;
        }
        let along = sat_mul(speed, direction);
        let reached = along >= self.relay_speed || (headroom && along > 0);
        if !reached && self.relay_ticks.saturating_sub(self.half_start.0) > STALL_TICKS {
            // The relay speed not reached in four target half cycles: the current does not overcome the friction
            // (the shaft sticks) or is far too small for the inertia. Doubled, up to the limit, every
            // [`STALL_TICKS`]; a stuck shaft adds nothing to the fits (blocks with a standing tick count in none).
            let limit = i64::from(self.config.current_limit.to_bits());
            self.relay_current = self.relay_current.saturating_mul(2).min(limit);
            self.half_start.0 = self.relay_ticks;
        }
        let direction = if reached {
            self.half_cycles = self.half_cycles.saturating_add(1);
            if self.clean_half_cycles < ADAPTED_HALF_CYCLES {
                self.adapt_relay_current(speed);
            }
            self.half_start = (self.relay_ticks, speed);
            if self.bus_high {
                // The braking half returned more energy than the bus holds below the limiter: a lower speed
                // (kinetic energy 9/16) for the next ones, down to 1/16 of the max system speed.
                self.relay_speed =
                    self.relay_speed.saturating_mul(3).checked_div(4).unwrap_or(0).max(self.speed_limit / 16);
                self.clean_half_cycles = 0;
                self.bus_high = false;
            } else {
                self.clean_half_cycles = self.clean_half_cycles.saturating_add(1);
            }
            direction.saturating_neg()
        } else {
            direction
        };
        self.phase = Phase::Relay { direction };
        self.ramp_towards(sat_mul(direction, self.relay_current));
    }

    /// Scales the relay current by the half cycle's acceleration against the one wanted (2 w per
    /// [`HALF_CYCLE_TARGET_TICKS`]): the probe's estimate is rough where friction or an elastic load (the motor
    /// first turns alone through the backlash) falsify its short acceleration. At most a factor 2 per half cycle.
    fn adapt_relay_current(&mut self, speed: i64) {
        let (start_tick, start_speed) = self.half_start;
        let current = self.relay_current;
        let ticks = self.relay_ticks.saturating_sub(start_tick);
        let gained = speed.saturating_sub(start_speed).saturating_abs().max(1);
        let wanted = relay_current_for(current, self.relay_speed, ticks, gained).unwrap_or(current);
        let limit = i64::from(self.config.current_limit.to_bits());
        let wanted = wanted.max(current / 2).min(current.saturating_mul(2));
        self.slow_relay_to_limit(wanted, limit);
        self.relay_current = wanted.max(limit >> PROBE_LEVELS.saturating_add(1)).min(limit);
    }

    /// Where the current a half cycle of [`HALF_CYCLE_TARGET_TICKS`] wants exceeds the test current limit, lowers the
    /// relay speed by their ratio (down to 1/16 of the max system speed, the bus limiter's floor), so that the half
    /// cycles at the limit keep their length. A heavy load on a weak motor otherwise reverses every second or more
    /// and the relay ends after [`MAX_RELAY_TICKS`] with too few half cycles for its two fits: a 5-pole-pair
    /// motor of 0.039 Nm/A and 1.24 A on 1,787 g cm^2 ran 2 half cycles in 4.7 s at 1,575 rpm, and its inertia fit
    /// came out negative (IDX 0xFF15).
    fn slow_relay_to_limit(&mut self, wanted: i64, limit: i64) {
        if wanted > limit && limit > 0 {
            let slower =
                wide::div_shl(i128::from(self.relay_speed).wrapping_mul(i128::from(limit)), i128::from(wanted), 0);
            self.relay_speed = wide::sat_i64(slower).max(self.speed_limit / 16).max(2);
        }
    }

    /// Moves the demand towards `target` by at most a [`RAMP_TICKS`]-th of a full reversal. The bounds here and in
    /// the relay current's are ordered (a positive limit and rate) and taken with max/min: `clamp` would assert
    /// their order with a formatted panic (flash in the images that print panics, issue 17).
    fn ramp_towards(&mut self, target: i64) {
        let rate = self.relay_current.saturating_mul(2).checked_div(i64::from(RAMP_TICKS)).unwrap_or(0);
        let rate = rate.max(1);
        let change = target.saturating_sub(self.demand).max(rate.saturating_neg()).min(rate);
        self.demand = self.demand.saturating_add(change);
    }

    /// Adds the tick to the fits (relay and stop).
    fn record(&mut self, sample: &MechanicalSample, increment: i64, position: i32) {
        let i_q = i64::from(sample.i_q.to_bits());
        // Near the limiter's voltage the drive may add d current and cut the braking q current (0x3202): such
        // ticks count in neither fit, and the half cycle lowers the relay speed.
        if sample.v_bus >= self.bus_high_voltage {
            self.bus_high = true;
        }
        let excluded = self.bus_high;
        // The mechanical fit takes the measured current, the slow tick's average (`Tier1Report::q_sums`): the loop
        // does not hold a small demand exactly (on the small gimbal with the reference gains the true current of a
        // 26 mA relay fell to 8-20 mA while braking, and the demand as regressor made the inertia 75 % too large;
        // with the current loop tuned first, +10 %), and a single period's current carries the sensing noise
        // (2 LSB rms = 16 mA, as large as the gimbal's relay current), which biases the slope towards zero (+13 to
        // +16 % inertia on the gimbal).
        // Torque constant: ticks with a settled current sign (measured |i_q| above half the relay current, where
        // the dead-time voltage is a function of the sign alone; by the demand's sign, which includes the braking
        // ticks whose current fell short, the gimbal's kt was 1.8 % off instead of 0.7 %).
        if !excluded && i_q.saturating_mul(2).abs() >= self.relay_current {
            let resistance_drop = sat_mul(i64::from(self.config.phase_resistance_milliohm), i_q) / 1000;
            let y = i64::from(sample.v_q.to_bits()).saturating_sub(resistance_drop);
            for (sum, x) in self.electrical_block.iter_mut().zip([increment, i_q.signum(), 1, y]) {
                *sum = sum.saturating_add(x);
            }
        }
        // Mechanics: block sums, one equation per pair of complete blocks at a steady current demand.
        // The run-up from rest (half cycle 0) drives alone: through a gear with losses its inertia is not the
        // average of driving and braking that the relay's later half cycles give (module documentation).
        self.block.ramping |= excluded || self.half_cycles == 0 || self.demand != self.previous_demand;
        self.block.standing = self.block.standing.saturating_add(u8::from(increment == 0));
        self.previous_demand = self.demand;
        self.block_tick = self.block_tick.saturating_add(1);
        let m = i64::from(self.block_tick);
        let values = [i_q, increment.signum(), increment];
        for (k, x) in values.iter().enumerate() {
            if let (Some(s0), Some(s1)) = (self.block.s0.get_mut(k), self.block.s1.get_mut(k)) {
                *s0 = s0.saturating_add(*x);
                *s1 = s1.saturating_add(sat_mul(*x, m));
            }
        }
        if self.block_tick >= BLOCK_TICKS {
            self.flush_electrical_block();
            self.block.travel = i64::from(position.wrapping_sub(self.block_start));
            // A block with two or more standing ticks leaves the fit: the shaft stuck (static friction holds any
            // torque below the breakaway, which the sign(w) model cannot express; such blocks made the small
            // gimbal's inertia 34 times too large with 2.5 times its Coulomb friction, and those where it sticks
            // or breaks away up to 70 % too large with 5 times). A single standing tick at a reversal stays: on
            // the geared axis (few counts per tick) leaving those blocks out made the inertia up to 15 % off.
            self.block.ramping |= self.block.standing >= 2;
            self.block_start = position;
            if let Some(previous) = self.previous_block.filter(|p| !p.ramping && !self.block.ramping) {
                let x = [0, 1, 2].map(|k| previous.rising(k).saturating_add(self.block.falling(k)));
                let repeat = usize::from(self.half_cycles / 2 % 2 == 1);
                if let Some(fit) = self.mechanical.get_mut(repeat) {
                    fit.add(x, self.block.travel.saturating_sub(previous.travel));
                }
            }
            self.previous_block = Some(self.block);
            self.block = BlockSums::default();
            self.block_tick = 0;
        }
    }

    /// The current block's electrical sums as one equation of the torque-constant fit (module documentation).
    fn flush_electrical_block(&mut self) {
        let [increments, signs, ticks, y] = core::mem::take(&mut self.electrical_block);
        if ticks > 0 {
            self.electrical.add([increments, signs, ticks], y);
        }
    }

    /// One part of the solution; the outcome after the last.
    fn solve(&mut self, part: u8) -> Option<MechanicalStatus> {
        let mismatch = Some(MechanicalStatus::Failed(MechanicalError::SampleMismatch));
        match part {
            0 => {
                self.flush_electrical_block();
                self.electrical_solution = self.electrical.solve();
                if self.electrical_solution.is_none() {
                    return mismatch;
                }
            }
            1..=3 => {
                // Part 1 and 2 the halves, part 3 the whole (the sum of their normal equations).
                let k = usize::from(part.saturating_sub(1));
                let [even, odd] = &self.mechanical;
                let solution = self.mechanical.get(k).map_or_else(|| even.plus(odd), |fit| *fit).solve();
                if let Some(slot) = self.mechanical_solution.get_mut(k) {
                    *slot = solution;
                }
                if solution.is_none() {
                    return mismatch;
                }
            }
            _ => {
                return Some(match self.results() {
                    Some(result) => MechanicalStatus::Done(result),
                    None => MechanicalStatus::Failed(MechanicalError::SampleMismatch),
                });
            }
        }
        self.phase = Phase::Solve(part.saturating_add(1));
        None
    }

    fn results(&self) -> Option<MechanicalResult> {
        let cpr = u64::from(self.config.counts_per_rev);
        let f = u64::from(SLOW_TICK_HZ);
        let el = self.electrical_solution?;
        // Coefficient 0: V bits per count/tick, one count/tick being 2 pi f / cpr rad/s: lambda p = c cpr /
        // (65536 2 pi f) V s/rad; kt = 1.5 lambda p, in uNm/A: c cpr 1.5e6 / (65536 2 pi f)
        // = c cpr 750,000 113 / (65536 355 f) (pi ~ 355/113, 8e-8).
        let kt = el.scaled(0, cpr.saturating_mul(750_000 * 113), f.saturating_mul(65_536 * 355))?;
        let kt = u64::try_from(kt).ok().filter(|&k| k > 0)?;
        let flux = kt.saturating_mul(2).checked_div(3u64.saturating_mul(u64::from(self.config.pole_pairs)))?;
        // Coefficient 1: V bits per sign of i_q.
        let sign_voltage = el.scaled(1, 1000, 65_536)?;
        let [even, odd, me] = self.mechanical_solution;
        let me = me?;
        // D2 = b0 W_i + b1 W_s + b2 W_p: b0 = cpr kt / (4 pi J f^2 65536) (i in bits, kt in Nm/A, J in kg m^2),
        // b1 = -cpr Tc / (4 pi J f^2), b2 = -B / (2 J f).
        // J in 0.001 g cm^2 (1e-10 kg m^2): cpr kt_u 1e4 / (4 pi f^2 65536 b0) = cpr kt_u 113 / ((f^2 / 1e4) 1420 65536 b0).
        let f2_per_1e4 = f.saturating_mul(f).checked_div(10_000)?;
        let (mul, div) = (cpr.saturating_mul(kt).saturating_mul(113), f2_per_1e4.saturating_mul(1420 * 65_536));
        let inertia = me.inverse_scaled(0, mul, div)?;
        let inertia = u64::try_from(inertia).ok().filter(|&j| j > 0)?;
        // Plausibility (a wrong value is worse than none: the loops are tuned from it): the even and the odd
        // cycles, two experiments, agree on the inertia within 1/REPEAT_SPREAD_DIVISOR of it.
        let spread = even?.inverse_scaled(0, mul, div)?.abs_diff(odd?.inverse_scaled(0, mul, div)?);
        if spread.saturating_mul(REPEAT_SPREAD_DIVISOR) > inertia {
            return None;
        }
        // Tc = -b1 / b0 kt / 65536 (uNm); B = -b2 / b0 cpr kt / (2 pi f 65536) Nm s/rad per Nm/A, in 0.001 uNm/rpm
        // (x 2 pi / 60 x 1e9, and kt_u = 1e6 kt): -b2 / b0 cpr kt_u / (60 f 65536 / 1000) with the 2 pi cancelled.
        let coulomb = me.ratio(1, 0, kt, 65_536)?.saturating_neg();
        let viscous = me.ratio(2, 0, cpr.saturating_mul(kt), f.saturating_mul(60 * 65_536 / 1000))?.saturating_neg();
        let relay_speed_rpm = u32::try_from(
            u64::try_from(self.relay_speed)
                .unwrap_or(0)
                .saturating_mul(60)
                .saturating_mul(f)
                .checked_div(cpr.saturating_mul(u64::from(SPEED_TICKS)))
                .unwrap_or(0),
        )
        .unwrap_or(u32::MAX);
        // The relay moved, so its torque exceeded the Coulomb friction and, at the relay speed, the viscous
        // friction: a fit that says otherwise (in either sign) explained the data with the wrong terms. In uNm
        // times 65,536: the current is in bits.
        let relay_torque = sat_mul(i64::try_from(kt).unwrap_or(i64::MAX), self.relay_current);
        let viscous_torque = sat_mul(sat_mul(viscous.saturating_abs(), i64::from(relay_speed_rpm)), 65);
        if sat_mul(coulomb.saturating_abs(), 65_536).max(viscous_torque) >= relay_torque {
            return None;
        }
        let (coulomb, viscous) = split_friction(coulomb, viscous, relay_speed_rpm);
        let clamp_u32 = |x: i64| u32::try_from(x.max(0)).unwrap_or(u32::MAX);
        Some(MechanicalResult {
            torque_constant: u32::try_from(kt).unwrap_or(u32::MAX),
            flux_linkage_uwb: u32::try_from(flux).unwrap_or(u32::MAX),
            inertia: u32::try_from(inertia).unwrap_or(u32::MAX),
            viscous_friction: clamp_u32(viscous),
            coulomb_friction: clamp_u32(coulomb),
            current_sign_voltage_mv: i32::try_from(sign_voltage).unwrap_or(0),
            relay_current: Amps::from_bits(wide::sat_i32(i128::from(self.relay_current))),
            half_cycles: self.half_cycles,
            relay_speed_rpm,
            ticks: self.ticks,
        })
    }
}

/// The bus voltage from which the relay's samples count in no fit, from the bus at rest `rest` and the limiter's
/// voltage `limit`: 15/16 of the limit, or half way from the rest to the limit where the bus rests above 7/8 of it
/// (a 48 V supply under the default 51 V: 49.5 V, where 15/16 lay under the supply itself and every sample left
/// the fit). `None` where the bus rests less than 1/32 of the limit under it ([`MIN_REGENERATION_HEADROOM_SHIFT`]):
/// the limiter would act on the first braking, and the relay could not keep a sample.
fn bus_high_voltage(rest: Volts, limit: Volts) -> Option<Volts> {
    let (rest, limit) = (rest.to_bits(), limit.to_bits());
    let headroom = limit.saturating_sub(rest);
    if headroom < limit >> MIN_REGENERATION_HEADROOM_SHIFT {
        return None;
    }
    // rest + headroom / 2 <= limit: no wrap.
    Some(Volts::from_bits(limit.wrapping_sub(limit >> 4).max(rest.wrapping_add(headroom >> 1))))
}

/// The fitted Coulomb (uNm) and viscous (0.001 uNm/rpm) friction as the drive keeps them (module documentation,
/// "Friction split"): as fitted while the viscous torque at the relay's mean speed (half `relay_speed_rpm`) is at
/// most a quarter of the Coulomb friction ([`VISCOUS_SHARE_DIVISOR`]), else `(Tc + B w_mean, 0)`: the friction the
/// relay saw, all of it Coulomb.
fn split_friction(coulomb: i64, viscous: i64, relay_speed_rpm: u32) -> (i64, i64) {
    // B [0.001 uNm/rpm] x w_mean [rpm] / 1000 = uNm.
    let viscous_torque = sat_mul(viscous, i64::from(relay_speed_rpm / 2)) / 1000;
    if sat_mul(viscous_torque.saturating_abs(), VISCOUS_SHARE_DIVISOR) > coulomb {
        (coulomb.saturating_add(viscous_torque), 0)
    } else {
        (coulomb, viscous)
    }
}

/// The relay current that gains the relay speed `w` in [`HALF_CYCLE_TARGET_TICKS`] where `current` gained `gained`
/// (at least 1) in `ticks`: `current 2 w ticks / (T gained)`; `None` beyond `i64`. The wrapping products are
/// exact: |current| <= 2^31 (a current's bits), |w| < 2^63 and ticks < 2^32 keep the numerator below 2^127, and
/// T < 2^32 with gained < 2^63 the denominator below 2^95. One function for the probe and the relay's
/// adaptation: 128-bit arithmetic inlined at both costs flash (issue 17).
#[inline(never)]
fn relay_current_for(current: i64, relay_speed: i64, ticks: u32, gained: i64) -> Option<i64> {
    let num = i128::from(current).wrapping_mul(2).wrapping_mul(i128::from(relay_speed)).wrapping_mul(i128::from(ticks));
    let den = i128::from(HALF_CYCLE_TARGET_TICKS).wrapping_mul(i128::from(gained));
    // The truncated quotient on the hardware divider (the library's 128-bit division is inlined in full).
    i64::try_from(wide::div_shl(num, den, 0)).ok()
}

/// Normal equations of a three-coefficient least-squares fit `y = b . x` (no constant unless one of `x` is 1),
/// accumulated in `i128`: each product of two `i64` fits, and 2^63 sums of them would be needed to overflow.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Regression3 {
    /// Sum of x x^T: (0,0), (0,1), (0,2), (1,1), (1,2), (2,2).
    xx: [i128; 6],
    /// Sum of x y.
    xy: [i128; 3],
    /// Sum of y y (for the scaling).
    yy: i128,
}

/// Index into [`Regression3::xx`] of the symmetric entry (j, k).
const fn sym(j: usize, k: usize) -> usize {
    let (a, b) = if j <= k { (j, k) } else { (k, j) };
    match (a, b) {
        (0, 0) => 0,
        (0, 1) => 1,
        (0, 2) => 2,
        (1, 1) => 3,
        (1, 2) => 4,
        _ => 5,
    }
}

/// The bits of the scaled normal equations: the products of three of them (the determinant) stay below 2^122.
pub const SCALED_BITS: u32 = 40;

/// A least-squares solution: coefficient j is `num[j] / det * 2^exp[j]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Solution3 {
    num: [i128; 3],
    det: i128,
    exp: [i32; 3],
}

impl Regression3 {
    /// The equations of both fits together.
    #[must_use]
    pub fn plus(&self, other: &Self) -> Self {
        let mut sum = *self;
        for (s, o) in sum.xx.iter_mut().zip(other.xx.iter()) {
            *s = s.wrapping_add(*o);
        }
        for (s, o) in sum.xy.iter_mut().zip(other.xy.iter()) {
            *s = s.wrapping_add(*o);
        }
        sum.yy = sum.yy.wrapping_add(other.yy);
        sum
    }

    /// Adds one equation. The sums wrap exactly as they would saturate: each product is below 2^126 and no
    /// experiment adds 2^63 equations (the type's note).
    pub fn add(&mut self, x: [i64; 3], y: i64) {
        let p = |a: i64, b: i64| i128::from(a).wrapping_mul(i128::from(b));
        for j in 0..3 {
            let xj = x.get(j).copied().unwrap_or(0);
            for k in j..3 {
                let xk = x.get(k).copied().unwrap_or(0);
                if let Some(s) = self.xx.get_mut(sym(j, k)) {
                    *s = s.wrapping_add(p(xj, xk));
                }
            }
            if let Some(s) = self.xy.get_mut(j) {
                *s = s.wrapping_add(p(xj, y));
            }
        }
        self.yy = self.yy.wrapping_add(p(y, y));
    }

    /// Solves by Cramer's rule on the equations scaled so that each diagonal entry (and y y) has at most
    /// [`SCALED_BITS`] bits (column j divided by 2^e_j: off-diagonal entries are bounded by the diagonal's by
    /// Cauchy-Schwarz). `None` for singular equations.
    #[must_use]
    pub fn solve(&self) -> Option<Solution3> {
        let e = [0, 1, 2].map(|j| scale_shift(self.xx.get(sym(j, j)).copied().unwrap_or(0)));
        let ey = scale_shift(self.yy);
        let ej = |j: usize| e.get(j).copied().unwrap_or(0);
        let m = |j: usize, k: usize| {
            scaled_entry(self.xx.get(sym(j, k)).copied().unwrap_or(0), ej(j).saturating_add(ej(k)))
        };
        let r = |j: usize| scaled_entry(self.xy.get(j).copied().unwrap_or(0), ej(j).saturating_add(ey));
        let a = [[m(0, 0), m(0, 1), m(0, 2)], [m(1, 0), m(1, 1), m(1, 2)], [m(2, 0), m(2, 1), m(2, 2)]];
        let rhs = [r(0), r(1), r(2)];
        let det = det3(&a);
        if det == 0 {
            return None;
        }
        let mut num = [0i128; 3];
        for (j, n) in num.iter_mut().enumerate() {
            let mut column = a;
            for (row, value) in column.iter_mut().zip(rhs.iter()) {
                if let Some(cell) = row.get_mut(j) {
                    *cell = *value;
                }
            }
            *n = det3(&column);
        }
        // The scaled system solves for b'_j = b_j 2^(e_j - e_y).
        let exp = [0, 1, 2].map(|j| i32::try_from(ey).unwrap_or(0).saturating_sub(i32::try_from(ej(j)).unwrap_or(0)));
        Some(Solution3 { num, det, exp })
    }
}

/// The shift of a column (or of y) that leaves its diagonal entry with at most [`SCALED_BITS`] bits.
fn scale_shift(v: i128) -> u32 {
    let bits = 128u32.saturating_sub(v.unsigned_abs().leading_zeros());
    bits.saturating_sub(SCALED_BITS).div_ceil(2)
}

/// A sum shifted right by `s` (rounded) and clamped to [`ENTRY_BOUND`]. Out of line: [`Regression3::solve`]
/// scales twelve entries, and the 128-bit shift and clamp inlined at each cost kilobytes of flash (issue 17).
#[inline(never)]
fn scaled_entry(v: i128, s: u32) -> i64 {
    let v = if s == 0 { v } else { wide::round_shr(v, s.min(126)) };
    i64::try_from(v.clamp(i128::from(-ENTRY_BOUND), i128::from(ENTRY_BOUND))).unwrap_or(0)
}

/// The largest magnitude of a scaled entry: 2^41 (the scaling leaves them at or below 2^40 plus rounding; the clamp
/// makes the bound hold whatever the sums).
const ENTRY_BOUND: i64 = 1 << 41;

/// The determinant of a 3x3 matrix of entries of at most [`ENTRY_BOUND`]: minors below 2^83, terms below 2^124, the
/// sum below 2^126, so the wrapping operations are exact (and cheap on the Cortex-M4: 64 x 64-bit products for the
/// minors, one 128-bit product per term).
#[inline(never)]
fn det3(a: &[[i64; 3]; 3]) -> i128 {
    let e = |r: usize, c: usize| i128::from(a.get(r).and_then(|row| row.get(c)).copied().unwrap_or(0));
    let minor = |r0: usize, r1: usize, c0: usize, c1: usize| {
        e(r0, c0).wrapping_mul(e(r1, c1)).wrapping_sub(e(r0, c1).wrapping_mul(e(r1, c0)))
    };
    let t0 = e(0, 0).wrapping_mul(minor(1, 2, 1, 2));
    let t1 = e(0, 1).wrapping_mul(minor(1, 2, 0, 2));
    let t2 = e(0, 2).wrapping_mul(minor(1, 2, 0, 1));
    t0.wrapping_sub(t1).wrapping_add(t2)
}

impl Solution3 {
    fn num(&self, j: usize) -> i128 {
        self.num.get(j).copied().unwrap_or(0)
    }

    fn exp(&self, j: usize) -> i32 {
        self.exp.get(j).copied().unwrap_or(0)
    }

    /// Coefficient j times `mul / div`, rounded.
    fn scaled(&self, j: usize, mul: u64, div: u64) -> Option<i64> {
        fraction(self.num(j), self.det, self.exp(j), mul, div)
    }

    /// `mul / (coefficient j div)`, rounded.
    fn inverse_scaled(&self, j: usize, mul: u64, div: u64) -> Option<i64> {
        fraction(self.det, self.num(j), self.exp(j).checked_neg()?, mul, div)
    }

    /// Coefficient j over coefficient k times `mul / div`, rounded.
    fn ratio(&self, j: usize, k: usize, mul: u64, div: u64) -> Option<i64> {
        fraction(self.num(j), self.num(k), self.exp(j).checked_sub(self.exp(k))?, mul, div)
    }
}

/// `num / den * 2^exp * mul / div`, rounded to nearest; `None` for a zero denominator, saturated to `i64`.
#[inline(never)]
fn fraction(num: i128, den: i128, exp: i32, mul: u64, div: u64) -> Option<i64> {
    if den == 0 || div == 0 {
        return None;
    }
    let (mut num, mut den) = if den < 0 { (num.checked_neg()?, den.checked_neg()?) } else { (num, den) };
    let mut exp = exp;
    // Both to at most 62 bits (precision 2^-61, far below the experiment's), the exponent keeping the value.
    let excess = |v: i128| 128u32.saturating_sub(v.unsigned_abs().leading_zeros()).saturating_sub(62);
    let sn = excess(num);
    num >>= sn;
    exp = exp.saturating_add(i32::try_from(sn).ok()?);
    let sd = excess(den);
    den >>= sd;
    exp = exp.saturating_sub(i32::try_from(sd).ok()?);
    if den == 0 {
        return None;
    }
    // |num| < 2^62, mul < 2^64: the product is below 2^126; so is den div. The wrapping products are exact (and
    // far smaller in flash than the overflow-checked ones, issue 17).
    let p = num.wrapping_mul(i128::from(mul));
    let mut q = den.wrapping_mul(i128::from(div));
    // One extra bit for the rounding.
    let s = if exp >= 0 {
        u32::try_from(exp).ok()?.saturating_add(1)
    } else {
        let back = u32::try_from(exp.checked_neg()?).ok()?;
        let room = q.leading_zeros().saturating_sub(2);
        let by_q = back.min(room);
        q <<= by_q;
        let by_p = back.saturating_sub(by_q);
        let p = if by_p >= 126 { 0 } else { p >> by_p };
        return Some(wide::sat_i64(wide::round_shr(wide::div_shl(p, q, 1), 1)));
    };
    Some(wide::sat_i64(wide::round_shr(wide::div_shl(p, q, s), 1)))
}

#[cfg(test)]
mod tests;
