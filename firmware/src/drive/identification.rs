//! The electrical steps of the motor identification (PD4-E "auto setup", seed 003 p.25-27 and p.76-77; design
//! `shared/spec/control-and-protection.md` §5.2): a tier-2 sequencer, one [`ElectricalIdentification::step`] per
//! slow tick, that tells tier 1 which injection to run ([`Injection`]: a d current or open-loop d/q voltages at an
//! imposed electrical angle) and measures from tier 1's reports. The procedure around it (mode 0x6060 = -2, the
//! objects, the faults) is [`super::auto_setup`].
//!
//! Steps (each one a state of [`Step`]):
//! 1. Standstill: no current for 0.1 s; the encoder must not move by more than 1/500 turn (else IDX 0xFF20).
//! 2. Resistance: angle 0, d current at 30 % and 80 % of the nominal current, each held until the current loop has
//!    settled and averaged: `R = dV/dI` (the dead-time voltage, the same at both levels of one current sign,
//!    cancels), minus the reference power stage's switch on-resistance (10 mOhm in series with every phase: a
//!    board constant, [`IdentificationConfig::switch_resistance_ohm`]). A current that does not flow (every phase
//!    current of the held level is checked against its share, 1 and 1/2) is an open phase (0xFF13); a current the
//!    voltage limit stops short of the demand is the current limit (0xFF12).
//! 3. Inductance: open-loop square-wave voltage on d, then on q, around the d voltage that held the 80 % current
//!    (the rotor stays held on d). Each half period lasts three slow ticks; its three current samples lie inside
//!    it (tier 1 applies a set-point from the period after the report, the duties one period later), so over each
//!    half period `L (i2 - i0) = (V - V_x) 2h - R int(i)` with `int(i)` by Simpson's rule. Subtracting the negative
//!    half periods from the positive ones cancels the dead time and the bias `V_x`; the resistance term uses the
//!    R of step 2 (before the switch correction: the circuit's).
//! 4. Rotation: d current at the forced angle turning at one mechanical revolution per second (capped at half the
//!    maximum speed), somewhat more than one mechanical turn forward and back. From the constant-speed parts: the
//!    counting direction (the encoder's against the field's), counts per electrical turn by least squares (pole
//!    pairs = counts per turn / that; not an integer, or not 0x3001:03: 0xFF16), the commutation offset (forced
//!    angle minus encoder angle, averaged over both directions so that the friction lag cancels), the electrical
//!    angle at each index pulse, and the angle of each Hall H1 edge (each change must be to a neighbouring
//!    sector, and more of them must follow the field than run against it: else 0xFF16; a heavy rotor swings about
//!    the turning field and may cross an edge backwards). No encoder movement: 0xFF21; faster than the maximum
//!    speed: 0xFF22.
//!
//! The whole procedure has a timeout ([`IdentificationConfig::timeout_ticks`], 0xFF19).
//!
//! Units: the measurements are `f32` (tier 2 on the Cortex-M4F's FPU; `control/` stays float-free); angles are
//! `u32` turn bits as everywhere in the drive.

use super::blocks::Tier1Report;
use super::tuning::SQRT_3;
use crate::control::angle::ElectricalAngle;
use crate::control::frames::Amps;
use crate::fault::table::FaultId;
use crate::sensors::hall::HallSector;

/// The slow tick's period, seconds (2.5 kHz).
const SLOW_TICK_S: f32 = 0.0004;
/// Amps per `I16F16` bit.
const PER_BIT: f32 = 1.0 / 65_536.0;
/// One turn in `u32` turn bits, as `f32`.
const TURN: f32 = 4_294_967_296.0;

/// What the identification needs to know before it starts (from the dictionary, [`super::auto_setup`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IdentificationConfig {
    /// 0x3001:03, the pole pairs the measurement is checked against.
    pub pole_pairs: u8,
    /// Encoder counts per revolution (4 x 0x3010:01).
    pub counts_per_rev: u32,
    /// An encoder is the position sensor (0x3000:01): the identification needs one.
    pub encoder_present: bool,
    /// The encoder has an index (0x3010:02 bit 0).
    pub has_index: bool,
    /// Halls are fitted (0x3000:01 sensor 3).
    pub halls_present: bool,
    /// 0x3001:01, the nominal current (A): the test currents are fractions of it.
    pub nominal_current_a: f32,
    /// 0x3001:02, the output current limit (A): no test current exceeds it.
    pub current_limit_a: f32,
    /// 0x6080, the maximum motor speed (rpm).
    pub max_speed_rpm: f32,
    /// The power stage's switch on-resistance in series with each phase (ohm): 10 mOhm on the reference stage.
    pub switch_resistance_ohm: f32,
    /// Slow ticks the electrical steps may take in all.
    pub timeout_ticks: u32,
}

/// The reference power stage's switch on-resistance (`shared/design/ARCHITECTURE.md` "Inverter": 10 mOhm).
pub const REFERENCE_SWITCH_RESISTANCE_OHM: f32 = 0.010;

/// What tier 1 runs while the identification is in charge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Injection {
    /// The d current at the imposed angle (q current 0).
    Current {
        /// The imposed electrical angle.
        angle: ElectricalAngle,
        /// The d current.
        i_d: Amps,
    },
    /// Open-loop d and q voltages (mV) at the imposed angle.
    Voltage {
        /// The imposed electrical angle.
        angle: ElectricalAngle,
        /// d voltage, mV.
        v_d_mv: i16,
        /// q voltage, mV.
        v_q_mv: i16,
    },
    /// Open-loop d voltage and tier 1's square wave of +-`amplitude_mv` (two periods each way) on q, or on d
    /// (`on_d`).
    Square {
        /// The square wave is on d (else on q).
        on_d: bool,
        /// The imposed electrical angle.
        angle: ElectricalAngle,
        /// d voltage, mV.
        v_d_mv: i16,
        /// q amplitude, mV.
        amplitude_mv: i16,
    },
}

/// Why the identification failed; each maps to one IDX code (seed 002 L7096-7110, L7516-7596).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IdentificationError {
    /// The voltage limit stopped the test current short of its demand (0xFF12); detail: the current reached, mA.
    CurrentLimit {
        /// Current reached, mA.
        reached_ma: i32,
    },
    /// The test current does not flow in a phase (0xFF13); detail: the phase, 1..=3.
    CurrentNotReached {
        /// 1 = A, 2 = B, 3 = C.
        phase: u8,
    },
    /// Pole pairs against the encoder's counts per turn: not an integer, or not 0x3001:03 (0xFF16); detail: the
    /// measured pole pairs x 100.
    PolePairs {
        /// Measured pole pairs x 100.
        measured_x100: i32,
    },
    /// An impossible Hall state or a Hall sequence against the field's rotation (0xFF16); detail: the state.
    HallSequence {
        /// The Hall state seen.
        state: u8,
    },
    /// No encoder to identify with (0xFF16); detail 0.
    NoEncoder,
    /// The identification took too long (0xFF19).
    Timeout,
    /// The encoder moved while no current flowed (0xFF20); detail: counts moved.
    Standstill {
        /// Counts moved.
        counts: i32,
    },
    /// The encoder did not follow the turning field (0xFF21: obstructed, or no encoder signal); detail: counts.
    NoMovement {
        /// Counts moved.
        counts: i32,
    },
    /// Faster than the maximum speed 0x6080 (0xFF22); detail: rpm.
    Overspeed {
        /// Speed, rpm.
        rpm: i32,
    },
}

impl IdentificationError {
    /// The fault this error raises.
    #[must_use]
    pub const fn fault(self) -> FaultId {
        match self {
            Self::CurrentLimit { .. } => FaultId::AutoTuningCurrentLimit,
            Self::CurrentNotReached { .. } => FaultId::AutoTuningIdentificationCurrent,
            Self::PolePairs { .. } | Self::HallSequence { .. } | Self::NoEncoder => FaultId::AutoTuningParameter,
            Self::Timeout => FaultId::AutoTuningTimeout,
            Self::Standstill { .. } => FaultId::AutoTuningStandstill,
            Self::NoMovement { .. } => FaultId::AutoTuningTorqueInvalid,
            Self::Overspeed { .. } => FaultId::AutoTuningMaxSpeed,
        }
    }

    /// The fault's detail (the measured value that failed).
    #[must_use]
    pub const fn detail(self) -> i32 {
        match self {
            Self::CurrentLimit { reached_ma } => reached_ma,
            Self::CurrentNotReached { phase } => phase as i32,
            Self::PolePairs { measured_x100 } => measured_x100,
            Self::HallSequence { state } => state as i32,
            Self::NoEncoder | Self::Timeout => 0,
            Self::Standstill { counts } | Self::NoMovement { counts } => counts,
            Self::Overspeed { rpm } => rpm,
        }
    }
}

/// What the electrical steps found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElectricalResult {
    /// Phase resistance (star equivalent), ohm, without the power stage's switches.
    pub resistance_ohm: f32,
    /// d inductance, H.
    pub ld_h: f32,
    /// q inductance, H.
    pub lq_h: f32,
    /// Pole pairs measured against the encoder (checked equal to 0x3001:03).
    pub pole_pairs: u8,
    /// The encoder counts against the field's positive direction: 0x3010:02 bit 4 must be toggled.
    pub encoder_reversed: bool,
    /// The electrical angle at the index pulse (with an index that was passed).
    pub index_angle: Option<ElectricalAngle>,
    /// The electrical angle of the H1 rising edge (with Halls).
    pub hall_offset: Option<ElectricalAngle>,
}

/// The sequencer's answer for one slow tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum IdentificationStatus {
    /// Still running: tier 1 runs this injection.
    Running(Injection),
    /// All electrical steps done.
    Done(ElectricalResult),
    /// Failed: the procedure raises the error's fault.
    Failed(IdentificationError),
}

/// The step in progress (0x3204:02 shows its number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// 1: standstill check.
    Standstill,
    /// 2: resistance.
    Resistance,
    /// 3: inductances.
    Inductance,
    /// 4: forced rotation.
    Rotation,
}

impl Step {
    /// The number 0x3204:02 shows.
    #[must_use]
    pub const fn number(self) -> u8 {
        match self {
            Self::Standstill => 1,
            Self::Resistance => 2,
            Self::Inductance => 3,
            Self::Rotation => 4,
        }
    }
}

/// Slow ticks of the standstill check (0.1 s).
const STANDSTILL_TICKS: u32 = 250;
/// Slow ticks a current level is ramped, then settles, then is averaged.
const RAMP_TICKS: u32 = 50;
const SETTLE_TICKS: u32 = 150;
const AVERAGE_TICKS: u32 = 250;
/// The two test currents as fractions of the nominal current.
const LEVELS: [f32; 2] = [0.3, 0.8];
/// Slow ticks per half period of the square wave, and the half periods skipped then measured per axis.
const HALF_TICKS: u32 = 3;
const SKIPPED_HALVES: u32 = 8;
const MEASURED_HALVES: u32 = 160;
/// The square wave's current swings, fractions of the nominal current. On q the swing adds +-sqrt(3)/2 of it to
/// phases B and C, which carry half the d bias (0.4 of the nominal current): kept well inside that, so that no
/// phase current nears zero, where the dead time's voltage error changes with the current (the assumption that
/// it cancels).
const D_SWING: f32 = 0.3;
/// The q square wave's current step per period, a fraction of the nominal current; its settling and measuring
/// times (slow ticks).
const Q_STEP: f32 = 0.15;
/// The square waves' bias plus amplitude stay within this share of the modulation's linear range `v_bus / sqrt 3`.
const SQUARE_LINEAR_SHARE: f32 = 0.9;
const SQUARE_SETTLE_TICKS: u32 = 25;
const SQUARE_MEASURE_TICKS: u32 = 250;
/// The PWM period, s (25 kHz).
const PWM_PERIOD_S: f32 = 0.00004;
/// Rotation: hold at angle 0, speed ramp, pause between the directions (slow ticks); the turns at full speed
/// beyond one mechanical turn; the settling skipped after the ramp before measuring.
const HOLD_TICKS: u32 = 500;
const SPEED_RAMP_TICKS: u32 = 250;
const PAUSE_TICKS: u32 = 250;
const SETTLE_AFTER_RAMP_TICKS: u32 = 250;

/// Sums of one linear fit `y = a + b x`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Fit {
    n: f32,
    x: f32,
    y: f32,
    xy: f32,
    xx: f32,
}

impl Fit {
    fn add(&mut self, x: f32, y: f32) {
        self.n += 1.0;
        self.x += x;
        self.y += y;
        self.xy += x * y;
        self.xx += x * x;
    }

    fn slope(&self) -> f32 {
        let den = self.n * self.xx - self.x * self.x;
        if den.abs() < f32::MIN_POSITIVE {
            0.0
        } else {
            (self.n * self.xy - self.x * self.y) / den
        }
    }
}

/// A circular mean of angles: the sum of each angle's difference to the first one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct AngleMean {
    first: Option<u32>,
    sum: i64,
    n: i64,
}

/// Out of line: three means (offset, index, Hall edges) each inline them otherwise (flash, issue 17).
impl AngleMean {
    #[inline(never)]
    fn add(&mut self, angle: u32) {
        let first = *self.first.get_or_insert(angle);
        self.sum = self.sum.wrapping_add(i64::from(angle.wrapping_sub(first).cast_signed()));
        self.n = self.n.wrapping_add(1);
    }

    #[inline(never)]
    fn mean(&self) -> Option<u32> {
        let first = self.first?;
        let mean = self.sum.checked_div(self.n)?;
        // |mean| < 2^31: each term is an i32.
        Some(first.wrapping_add(mean as i32 as u32))
    }
}

/// The rotation's phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Turn {
    Hold,
    Forward,
    Pause,
    Backward,
}

/// The electrical identification (module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct ElectricalIdentification {
    config: IdentificationConfig,
    step: Step,
    /// Slow ticks in the present step (or sub-step).
    t: u32,
    /// Slow ticks since the start.
    total: u32,
    // Standstill.
    position_start: i32,
    // Resistance.
    level: usize,
    sum_i: f32,
    sum_v: f32,
    sum_abc: [f32; 3],
    sum_sat: u32,
    level_i: [f32; 2],
    level_v: [f32; 2],
    resistance_circuit: f32,
    // Inductance.
    axis_q: bool,
    bias_mv: i16,
    amplitude_mv: i16,
    half: u32,
    samples: [f32; 3],
    sum_up_di: f32,
    sum_up_int: f32,
    sum_down_di: f32,
    sum_down_int: f32,
    ld: f32,
    lq: f32,
    square_start: (i32, u32),
    square_on_q: bool,
    square_ld: f32,
    // Rotation.
    turn: Turn,
    /// The imposed angle, turn bits (wrapping).
    angle: u32,
    /// Its speed now, turn bits per slow tick.
    speed: i64,
    top_speed: i64,
    /// Slow ticks at top speed per direction.
    cruise_ticks: u32,
    rotation_current: Amps,
    direction: i32,
    move_start: i32,
    last_position: i32,
    counts_fit: Fit,
    fit_origin_position: i32,
    fit_turns: f32,
    moved_turns: f32,
    angle_per_count: u32,
    /// The step (or sub-step) was entered at this tick: `t` restarts from 0 at the next one.
    entered: bool,
    offsets: AngleMean,
    last_hall: u8,
    hall_edges: AngleMean,
    /// Hall transitions with the field's rotation, and against it (the rotor swinging about the field).
    hall_along: u16,
    hall_against: u16,
    index_count: u16,
    index_angles: AngleMean,
    max_speed_counts: i32,
}

impl ElectricalIdentification {
    /// A new identification, starting with the standstill check.
    #[must_use]
    pub fn new(config: IdentificationConfig) -> Self {
        let pp = f32::from(config.pole_pairs.max(1));
        // One mechanical revolution per second, at most half the maximum speed.
        let rev_per_s = (config.max_speed_rpm / 120.0).clamp(0.05, 1.0);
        let top_speed = (pp * rev_per_s * SLOW_TICK_S * TURN) as i64;
        // One mechanical turn and a quarter at top speed, after the settling.
        let cruise_s = 1.25 / rev_per_s;
        let cruise_ticks = (cruise_s / SLOW_TICK_S) as u32;
        let rotation_current =
            Amps::from_bits((config.nominal_current_a.min(config.current_limit_a) * 0.8 / PER_BIT) as i32);
        // The speed limit in counts per slow tick.
        let max_speed_counts =
            (config.max_speed_rpm / 60.0 * config.counts_per_rev as f32 * SLOW_TICK_S).max(1.0) as i32;
        Self {
            config,
            step: Step::Standstill,
            t: 0,
            total: 0,
            position_start: 0,
            level: 0,
            sum_i: 0.0,
            sum_v: 0.0,
            sum_abc: [0.0; 3],
            sum_sat: 0,
            level_i: [0.0; 2],
            level_v: [0.0; 2],
            resistance_circuit: 0.0,
            axis_q: false,
            bias_mv: 0,
            amplitude_mv: 0,
            half: 0,
            samples: [0.0; 3],
            sum_up_di: 0.0,
            sum_up_int: 0.0,
            sum_down_di: 0.0,
            sum_down_int: 0.0,
            ld: 0.0,
            lq: 0.0,
            square_start: (0, 0),
            square_on_q: false,
            square_ld: 0.0,
            turn: Turn::Hold,
            angle: 0,
            speed: 0,
            top_speed,
            cruise_ticks,
            rotation_current,
            direction: 1,
            move_start: 0,
            last_position: 0,
            counts_fit: Fit::default(),
            fit_origin_position: 0,
            fit_turns: 0.0,
            moved_turns: 0.0,
            angle_per_count: super::encoder::EncoderConfig {
                counts_per_rev: config.counts_per_rev,
                pole_pairs: config.pole_pairs,
                inverted: false,
                has_index: false,
            }
            .angle_per_count(),
            entered: false,
            offsets: AngleMean::default(),
            last_hall: 0,
            hall_edges: AngleMean::default(),
            hall_along: 0,
            hall_against: 0,
            index_count: 0,
            index_angles: AngleMean::default(),
            max_speed_counts,
        }
    }

    /// The step in progress.
    #[must_use]
    pub const fn step_in_progress(&self) -> Step {
        self.step
    }

    /// Progress of the electrical steps, per mille (by the planned ticks of each step).
    #[must_use]
    pub fn progress_per_mille(&self) -> u16 {
        let planned = STANDSTILL_TICKS as f32
            + 2.0 * (RAMP_TICKS + SETTLE_TICKS + AVERAGE_TICKS) as f32
            + ((SKIPPED_HALVES + MEASURED_HALVES) * HALF_TICKS + 2 * (SQUARE_SETTLE_TICKS + SQUARE_MEASURE_TICKS))
                as f32
            + (HOLD_TICKS + PAUSE_TICKS) as f32
            + 2.0 * (2.0 * SPEED_RAMP_TICKS as f32 + self.cruise_ticks as f32);
        ((self.total as f32 / planned * 1000.0) as u16).min(999)
    }

    /// One slow tick with tier 1's report of it.
    pub fn step(&mut self, report: &Tier1Report) -> IdentificationStatus {
        self.total = self.total.saturating_add(1);
        if self.total > self.config.timeout_ticks {
            return IdentificationStatus::Failed(IdentificationError::Timeout);
        }
        let status = match self.step {
            Step::Standstill => self.standstill(report),
            Step::Resistance => self.resistance(report),
            Step::Inductance => self.inductance(report),
            Step::Rotation => self.rotation(report),
        };
        if core::mem::take(&mut self.entered) {
            self.t = 0;
        } else {
            self.t = self.t.saturating_add(1);
        }
        status
    }

    /// Out of line, as the other outputs: each step returns them from several places (flash, issue 17).
    #[inline(never)]
    fn current(&self, i_d: f32) -> IdentificationStatus {
        IdentificationStatus::Running(Injection::Current {
            angle: ElectricalAngle(self.angle),
            i_d: Amps::from_bits((i_d / PER_BIT) as i32),
        })
    }

    /// Enters `step` (or the next sub-step of it): `t` counts from 0 at the next tick.
    fn next_step(&mut self, step: Step) {
        self.step = step;
        self.entered = true;
    }

    fn standstill(&mut self, r: &Tier1Report) -> IdentificationStatus {
        if !self.config.encoder_present {
            return IdentificationStatus::Failed(IdentificationError::NoEncoder);
        }
        if self.t == 0 {
            self.position_start = r.encoder_position;
        }
        let moved = r.encoder_position.wrapping_sub(self.position_start);
        let allowed = (self.config.counts_per_rev / 500).max(2);
        if moved.unsigned_abs() > allowed {
            return IdentificationStatus::Failed(IdentificationError::Standstill { counts: moved });
        }
        if self.t >= STANDSTILL_TICKS {
            self.next_step(Step::Resistance);
        }
        self.current(0.0)
    }

    fn level_current(&self, level: usize) -> f32 {
        let fraction = LEVELS.get(level).copied().unwrap_or(0.0);
        (self.config.nominal_current_a * fraction).min(self.config.current_limit_a * 0.8)
    }

    fn resistance(&mut self, r: &Tier1Report) -> IdentificationStatus {
        let target = self.level_current(self.level);
        let previous = if self.level == 0 { 0.0 } else { self.level_current(0) };
        let t = self.t;
        if t < RAMP_TICKS {
            let share = (t as f32 + 1.0) / RAMP_TICKS as f32;
            return self.current(previous + (target - previous) * share);
        }
        let s = &r.signals;
        if (RAMP_TICKS + SETTLE_TICKS..RAMP_TICKS + SETTLE_TICKS + AVERAGE_TICKS).contains(&t) {
            self.sum_i += s.i_dq.d.to_bits() as f32 * PER_BIT;
            self.sum_v += s.v_dq.d.to_bits() as f32 * PER_BIT;
            let abc = [s.i_abc.a, s.i_abc.b, s.i_abc.c];
            for (sum, i) in self.sum_abc.iter_mut().zip(abc) {
                *sum += (i.to_bits() as f32 * PER_BIT).abs();
            }
            self.sum_sat = self.sum_sat.saturating_add(u32::from(s.saturated));
        }
        if t < RAMP_TICKS + SETTLE_TICKS + AVERAGE_TICKS {
            return self.current(target);
        }
        let n = AVERAGE_TICKS as f32;
        let i = self.sum_i / n;
        // Angle 0: phase A carries the d current, B and C half of it each, back.
        for (phase, (sum, share)) in self.sum_abc.iter().zip([1.0f32, 0.5, 0.5]).enumerate() {
            if sum / n < 0.25 * share * target {
                return IdentificationStatus::Failed(IdentificationError::CurrentNotReached {
                    phase: (phase as u8).saturating_add(1),
                });
            }
        }
        if i < 0.9 * target {
            let reached_ma = (i * 1000.0) as i32;
            return IdentificationStatus::Failed(if self.sum_sat > 0 {
                IdentificationError::CurrentLimit { reached_ma }
            } else {
                IdentificationError::CurrentNotReached { phase: 0 }
            });
        }
        if let (Some(li), Some(lv)) = (self.level_i.get_mut(self.level), self.level_v.get_mut(self.level)) {
            *li = i;
            *lv = self.sum_v / n;
        }
        self.sum_i = 0.0;
        self.sum_v = 0.0;
        self.sum_abc = [0.0; 3];
        self.sum_sat = 0;
        if self.level == 0 {
            self.level = 1;
            self.next_step(Step::Resistance);
            return self.current(target);
        }
        let [i1, i2] = self.level_i;
        let [v1, v2] = self.level_v;
        self.resistance_circuit = (v2 - v1) / (i2 - i1);
        self.bias_mv = (v2 * 1000.0).clamp(-32_000.0, 32_000.0) as i16;
        self.amplitude_mv = self.amplitude_mv(D_SWING);
        self.next_step(Step::Inductance);
        self.inductance_output()
    }

    /// The square wave's amplitude for a current swing of at most `swing` x the nominal current (the steady
    /// state's, `V / R`; less within a half period), at least 20 mV.
    fn amplitude_mv(&self, swing: f32) -> i16 {
        let amplitude = swing * self.resistance_circuit * self.config.nominal_current_a;
        (amplitude * 1000.0).clamp(20.0, 8_000.0) as i16
    }

    #[inline(never)]
    fn inductance_output(&self) -> IdentificationStatus {
        let positive = self.half.is_multiple_of(2);
        let swing = if positive { self.amplitude_mv } else { self.amplitude_mv.wrapping_neg() };
        IdentificationStatus::Running(Injection::Voltage {
            angle: ElectricalAngle(self.angle),
            v_d_mv: self.bias_mv.saturating_add(swing),
            v_q_mv: 0,
        })
    }

    fn inductance(&mut self, r: &Tier1Report) -> IdentificationStatus {
        if self.axis_q {
            return self.square_wave(r);
        }
        // The sample belongs to the half period output before this tick (module documentation, step 3).
        let s = &r.signals;
        let i = s.i_dq.d.to_bits() as f32 * PER_BIT;
        let k = self.t % HALF_TICKS;
        if let Some(slot) = self.samples.get_mut(k as usize) {
            *slot = i;
        }
        if k.saturating_add(1) < HALF_TICKS {
            return self.inductance_output();
        }
        // Three samples of the half period that is ending: it is done.
        if self.half >= SKIPPED_HALVES {
            let [i0, i1, i2] = self.samples;
            // Simpson's rule over the two sample spacings of one slow tick each.
            let integral = SLOW_TICK_S / 3.0 * (i0 + 4.0 * i1 + i2);
            if self.half.is_multiple_of(2) {
                self.sum_up_di += i2 - i0;
                self.sum_up_int += integral;
            } else {
                self.sum_down_di += i2 - i0;
                self.sum_down_int += integral;
            }
        }
        self.half = self.half.saturating_add(1);
        if self.half < SKIPPED_HALVES + MEASURED_HALVES {
            return self.inductance_output();
        }
        let pairs = (MEASURED_HALVES / 2) as f32;
        let swing = 2.0 * f32::from(self.amplitude_mv) / 1000.0;
        let window = 2.0 * SLOW_TICK_S;
        let di = self.sum_up_di - self.sum_down_di;
        let l = (swing * window * pairs - self.resistance_circuit * (self.sum_up_int - self.sum_down_int)) / di;
        self.sum_up_di = 0.0;
        self.sum_up_int = 0.0;
        self.sum_down_di = 0.0;
        self.sum_down_int = 0.0;
        self.half = 0;
        self.ld = l;
        self.axis_q = true;
        // The q square wave: a current step of Q_STEP x the nominal current per period (with Lq near Ld), within
        // SQUARE_LINEAR_SHARE of the modulation's linear range above the d bias: a square wave on d clipped where
        // the bias adds to it reads a wrong Ld for the ratio below (a 6 mH, 8 ohm motor at 24 V: Lq -16 %; at 48 V,
        // unclipped, +0.1 %).
        let amplitude = Q_STEP * self.config.nominal_current_a * l / PWM_PERIOD_S;
        let linear_mv = r.signals.v_bus.to_bits() as f32 * PER_BIT * 1000.0 / SQRT_3 * SQUARE_LINEAR_SHARE;
        let headroom_mv = linear_mv - f32::from(self.bias_mv).abs();
        self.amplitude_mv = (amplitude * 1000.0).min(headroom_mv).clamp(20.0, 12_000.0) as i16;
        self.next_step(Step::Inductance);
        self.square_output()
    }

    #[inline(never)]
    fn square_output(&self) -> IdentificationStatus {
        IdentificationStatus::Running(Injection::Square {
            on_d: !self.square_on_q,
            angle: ElectricalAngle(self.angle),
            v_d_mv: self.bias_mv,
            amplitude_mv: self.amplitude_mv,
        })
    }

    /// Lq from tier 1's square wave: its running totals (in the report's current reference while it runs) taken
    /// after a settling time and again after the measuring time.
    fn square_wave(&mut self, r: &Tier1Report) -> IdentificationStatus {
        let totals = (r.signals.i_ref.d.to_bits(), r.signals.i_ref.q.to_bits().cast_unsigned());
        if self.t == SQUARE_SETTLE_TICKS {
            self.square_start = totals;
        }
        if self.t < SQUARE_SETTLE_TICKS + SQUARE_MEASURE_TICKS {
            return self.square_output();
        }
        let sum = totals.0.wrapping_sub(self.square_start.0) as f32 * PER_BIT;
        let count = totals.1.wrapping_sub(self.square_start.1) as f32;
        let amplitude = f32::from(self.amplitude_mv) / 1000.0;
        let l = if sum > 0.0 { amplitude * PWM_PERIOD_S * count / sum } else { 0.0 };
        if !self.square_on_q {
            // The fast square wave on d against the slow one: the dead time's share (phase currents whose PWM
            // ripple reaches zero) is the same on both axes, at the same bias; the ratio removes it from Lq.
            self.square_ld = l;
            self.square_on_q = true;
            self.next_step(Step::Inductance);
            return self.square_output();
        }
        self.lq = if self.square_ld > 0.0 { l * self.ld / self.square_ld } else { l };
        self.next_step(Step::Rotation);
        self.current(self.rotation_current_a())
    }

    fn rotation_current_a(&self) -> f32 {
        self.rotation_current.to_bits() as f32 * PER_BIT
    }

    /// The electrical angle the encoder shows at `position` (counts), in the field's direction, without the
    /// commutation offset.
    #[inline(never)]
    fn encoder_angle(&self, position: i32) -> u32 {
        let counts = position.wrapping_mul(self.direction).cast_unsigned();
        counts.wrapping_mul(u32::from(self.config.pole_pairs.max(1))).wrapping_mul(self.angle_per_count)
    }

    fn rotation(&mut self, r: &Tier1Report) -> IdentificationStatus {
        let p = r.encoder_position;
        let dp = p.wrapping_sub(self.last_position);
        let first = self.t == 0 && self.turn == Turn::Hold;
        self.last_position = p;
        if !first && dp.unsigned_abs() > self.max_speed_counts.unsigned_abs() {
            let rpm = dp as f32 / self.config.counts_per_rev.max(1) as f32 / SLOW_TICK_S * 60.0;
            return IdentificationStatus::Failed(IdentificationError::Overspeed { rpm: rpm as i32 });
        }
        let current = self.rotation_current_a();
        match self.turn {
            Turn::Hold => {
                if self.t >= HOLD_TICKS {
                    self.turn = Turn::Forward;
                    self.move_start = p;
                    self.fit_origin_position = p;
                    self.moved_turns = 0.0;
                    self.next_step(Step::Rotation);
                }
                self.last_hall = r.signals.hall;
                self.index_count = r.latches.index.count;
                self.current(current)
            }
            Turn::Pause => {
                if self.t >= PAUSE_TICKS {
                    self.turn = Turn::Backward;
                    self.move_start = p;
                    self.moved_turns = 0.0;
                    self.next_step(Step::Rotation);
                }
                self.last_hall = r.signals.hall;
                self.index_count = r.latches.index.count;
                self.current(current)
            }
            Turn::Forward | Turn::Backward => self.turning(r, dp),
        }
    }

    fn turning(&mut self, r: &Tier1Report, dp: i32) -> IdentificationStatus {
        let p = r.encoder_position;
        let sign: i64 = if self.turn == Turn::Forward { 1 } else { -1 };
        let t = self.t;
        let cruise_end = SPEED_RAMP_TICKS.saturating_add(SETTLE_AFTER_RAMP_TICKS).saturating_add(self.cruise_ticks);
        let end = cruise_end.saturating_add(SPEED_RAMP_TICKS);
        let profile = if t < SPEED_RAMP_TICKS {
            t as f32 / SPEED_RAMP_TICKS as f32
        } else if t < cruise_end {
            1.0
        } else {
            end.saturating_sub(t) as f32 / SPEED_RAMP_TICKS as f32
        };
        let speed = ((self.top_speed as f32 * profile) as i64).saturating_mul(sign);
        let measuring = t >= SPEED_RAMP_TICKS.saturating_add(SETTLE_AFTER_RAMP_TICKS) && t < cruise_end;
        if measuring {
            let moved = p.wrapping_sub(self.move_start);
            let expected =
                self.moved_turns * self.config.counts_per_rev as f32 / f32::from(self.config.pole_pairs.max(1));
            if (moved.unsigned_abs() as f32) < expected * 0.25 {
                return IdentificationStatus::Failed(IdentificationError::NoMovement { counts: moved });
            }
            if self.turn == Turn::Forward && t == SPEED_RAMP_TICKS.saturating_add(SETTLE_AFTER_RAMP_TICKS) {
                self.direction = if moved >= 0 { 1 } else { -1 };
            }
            self.counts_fit.add(self.fit_turns, p.wrapping_sub(self.fit_origin_position) as f32);
            let encoder = self.encoder_angle(p);
            self.offsets.add(self.angle.wrapping_sub(encoder));
            if r.latches.index.count != self.index_count && self.config.has_index {
                self.index_angles.add(self.encoder_angle(r.latches.index.position));
            }
            if self.config.halls_present {
                if let Err(e) = self.hall_edge(r.signals.hall, p, dp, sign > 0) {
                    return IdentificationStatus::Failed(e);
                }
            }
        }
        self.index_count = r.latches.index.count;
        self.last_hall = r.signals.hall;
        self.angle = self.angle.wrapping_add(speed as i32 as u32);
        let turns = speed as f32 / TURN;
        self.fit_turns += turns;
        self.moved_turns += turns.abs();
        if t < end {
            return self.current(self.rotation_current_a());
        }
        if self.turn == Turn::Forward {
            self.turn = Turn::Pause;
            self.next_step(Step::Rotation);
            return self.current(self.rotation_current_a());
        }
        self.finish()
    }

    /// A Hall sample while turning: each change must be to a neighbouring sector, and the changes must follow the
    /// field on the whole (checked in [`Self::finish`]); an H1 edge gives the Hall offset (before the commutation
    /// offset is added). A change against the field is allowed: a heavy rotor swings about the turning field (the
    /// d current holds it like a spring, and little friction damps it), so it can cross an edge backwards and again
    /// forwards; a sensor wired in the wrong order changes against the field at every edge.
    fn hall_edge(&mut self, hall: u8, p: i32, dp: i32, forward: bool) -> Result<(), IdentificationError> {
        let sector = HallSector::from_state(hall).map_err(|_| IdentificationError::HallSequence { state: hall })?;
        let last = self.last_hall;
        if hall == last {
            return Ok(());
        }
        let previous = HallSector::from_state(last).map_err(|_| IdentificationError::HallSequence { state: last })?;
        let moving_forward = if sector == previous.next() {
            true
        } else if sector == previous.previous() {
            false
        } else {
            return Err(IdentificationError::HallSequence { state: hall });
        };
        if moving_forward == forward {
            self.hall_along = self.hall_along.saturating_add(1);
        } else {
            self.hall_against = self.hall_against.saturating_add(1);
        }
        if (hall ^ last) & 1 != 0 {
            // The edge lay between the two samples: their midpoint.
            let now = self.encoder_angle(p);
            let before = self.encoder_angle(p.wrapping_sub(dp));
            let mid = before.wrapping_add((now.wrapping_sub(before).cast_signed() / 2).cast_unsigned());
            let rising = hall & 1 != 0;
            // H1 rises at the offset moving forward (and falls there moving back); its other edge is half a turn on.
            let edge = if rising == moving_forward { mid } else { mid.wrapping_sub(1 << 31) };
            self.hall_edges.add(edge);
        }
        Ok(())
    }

    fn finish(&mut self) -> IdentificationStatus {
        let counts_per_turn = self.counts_fit.slope().abs();
        let cpr = self.config.counts_per_rev as f32;
        let measured = if counts_per_turn > 0.0 { cpr / counts_per_turn } else { 0.0 };
        let rounded = (measured + 0.5) as i32;
        let configured = i32::from(self.config.pole_pairs);
        if (measured - rounded as f32).abs() > 0.1 || rounded != configured {
            return IdentificationStatus::Failed(IdentificationError::PolePairs {
                measured_x100: (measured * 100.0) as i32,
            });
        }
        if self.config.halls_present && self.hall_along <= self.hall_against {
            return IdentificationStatus::Failed(IdentificationError::HallSequence { state: self.last_hall });
        }
        let Some(offset) = self.offsets.mean() else {
            return IdentificationStatus::Failed(IdentificationError::NoMovement { counts: 0 });
        };
        IdentificationStatus::Done(ElectricalResult {
            resistance_ohm: self.resistance_circuit - self.config.switch_resistance_ohm,
            ld_h: self.ld,
            lq_h: self.lq,
            pole_pairs: self.config.pole_pairs,
            encoder_reversed: self.direction < 0,
            index_angle: self.index_angles.mean().map(|a| ElectricalAngle(a.wrapping_add(offset))),
            hall_offset: self.hall_edges.mean().map(|a| ElectricalAngle(a.wrapping_add(offset))),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::frames::{Abc, Dq, Volts};

    const CONFIG: IdentificationConfig = IdentificationConfig {
        pole_pairs: 7,
        counts_per_rev: 4096,
        encoder_present: true,
        has_index: true,
        halls_present: true,
        nominal_current_a: 3.2,
        current_limit_a: 10.0,
        max_speed_rpm: 5000.0,
        switch_resistance_ohm: REFERENCE_SWITCH_RESISTANCE_OHM,
        timeout_ticks: 50_000,
    };

    fn amps(a: f32) -> Amps {
        Amps::from_bits((a * 65_536.0) as i32)
    }

    /// A report of a drive holding `i_d` at angle 0 (phase A carries it, B and C half each, back) with `v_d`.
    fn holding(i_d: f32, v_d: f32, saturated: bool) -> Tier1Report {
        let mut r = Tier1Report::default();
        r.signals.i_dq = Dq::new(amps(i_d), Amps::ZERO);
        r.signals.i_abc = Abc { a: amps(i_d), b: amps(-i_d / 2.0), c: amps(-i_d / 2.0) };
        r.signals.v_dq = Dq::new(Volts::from_bits((v_d * 65_536.0) as i32), Volts::ZERO);
        r.signals.saturated = saturated;
        r
    }

    fn demand(status: IdentificationStatus) -> f32 {
        match status {
            IdentificationStatus::Running(Injection::Current { i_d, .. }) => i_d.to_bits() as f32 / 65_536.0,
            other => panic!("expected a current injection, got {other:?}"),
        }
    }

    /// The Hall states of a field turning forward from `start`, `n` sectors on.
    fn hall_states_forward(start: u8, n: usize) -> std::vec::Vec<u8> {
        let mut sector = HallSector::from_state(start).expect("a valid state");
        (0..n)
            .map(|_| {
                sector = sector.next();
                sector.state()
            })
            .collect()
    }

    /// A heavy rotor swings about the turning field and crosses a Hall edge backwards, then forwards again: both
    /// changes are to a neighbouring sector and are accepted, counted against and along the field.
    #[test]
    fn a_rotor_swinging_back_over_a_hall_edge_is_no_sequence_error() {
        let mut id = ElectricalIdentification::new(CONFIG);
        let forward = hall_states_forward(1, 3);
        id.last_hall = 1;
        for (k, &state) in forward.iter().enumerate() {
            assert_eq!(id.hall_edge(state, 100 * k as i32, 10, true), Ok(()));
            id.last_hall = state;
        }
        let back = HallSector::from_state(id.last_hall).expect("valid").previous().state();
        assert_eq!(id.hall_edge(back, 290, -10, true), Ok(()), "swung back over the edge");
        id.last_hall = back;
        let again = HallSector::from_state(back).expect("valid").next().state();
        assert_eq!(id.hall_edge(again, 300, 10, true), Ok(()), "and forwards again");
        assert_eq!((id.hall_along, id.hall_against), (4, 1));
    }

    /// IDX 0xFF16: a change across two sectors is no rotor movement (a wiring or sensor fault).
    #[test]
    fn a_hall_change_across_two_sectors_is_a_sequence_error() {
        let mut id = ElectricalIdentification::new(CONFIG);
        let two_on = hall_states_forward(1, 2)[1];
        id.last_hall = 1;
        assert_eq!(id.hall_edge(two_on, 0, 10, true), Err(IdentificationError::HallSequence { state: two_on }));
    }

    /// IDX 0xFF16: Halls whose changes run against the field on the whole (wired in the wrong order) fail the
    /// rotation at its end, though the pole pairs (4,096 counts per turn over 7 x 585.14) fit.
    #[test]
    fn halls_changing_against_the_field_on_the_whole_fail_the_rotation() {
        let fitted = |along: u16, against: u16| {
            let mut id = ElectricalIdentification::new(CONFIG);
            for k in 0..10 {
                let turns = k as f32;
                id.counts_fit.add(turns, turns * 4096.0 / 7.0);
            }
            id.offsets.add(0);
            id.last_hall = 5;
            (id.hall_along, id.hall_against) = (along, against);
            id.finish()
        };
        assert_eq!(fitted(3, 40), IdentificationStatus::Failed(IdentificationError::HallSequence { state: 5 }));
        assert_eq!(fitted(20, 20), IdentificationStatus::Failed(IdentificationError::HallSequence { state: 5 }));
        assert!(matches!(fitted(40, 3), IdentificationStatus::Done(_)), "a swing on a forward sequence passes");
    }

    /// IDX 0xFF19: the identification ends at its timeout, whatever step it is in.
    #[test]
    fn the_timeout_ends_the_identification() {
        let mut id = ElectricalIdentification::new(IdentificationConfig { timeout_ticks: 10, ..CONFIG });
        for _ in 0..10 {
            assert!(matches!(id.step(&holding(0.0, 0.0, false)), IdentificationStatus::Running(_)));
        }
        assert_eq!(id.step(&holding(0.0, 0.0, false)), IdentificationStatus::Failed(IdentificationError::Timeout));
        assert_eq!(IdentificationError::Timeout.fault().info().code, 0xFF19);
    }

    /// IDX 0xFF20: an encoder that moves by more than 1/500 turn (8 counts of 4,096) before any current flows.
    #[test]
    fn a_moving_motor_fails_the_standstill_check() {
        let mut id = ElectricalIdentification::new(CONFIG);
        let mut r = holding(0.0, 0.0, false);
        assert_eq!(demand(id.step(&r)), 0.0);
        r.encoder_position = 8;
        assert_eq!(demand(id.step(&r)), 0.0, "8 counts are allowed");
        r.encoder_position = 9;
        let status = id.step(&r);
        assert_eq!(status, IdentificationStatus::Failed(IdentificationError::Standstill { counts: 9 }));
        assert_eq!(IdentificationError::Standstill { counts: 9 }.fault().info().code, 0xFF20);
    }

    /// Runs the standstill check and the first level's ramp and settling with `report`, then its averaging;
    /// returns the status after it.
    fn first_level(id: &mut ElectricalIdentification, report: &Tier1Report) -> IdentificationStatus {
        let mut status = id.step(report);
        for _ in 0..(STANDSTILL_TICKS + RAMP_TICKS + SETTLE_TICKS + AVERAGE_TICKS + 2) {
            status = id.step(report);
            if !matches!(status, IdentificationStatus::Running(_)) {
                break;
            }
        }
        status
    }

    /// IDX 0xFF12: the voltage limit (saturated) holds the current at 0.5625 A, 59 % of the 30 % level's 0.96 A.
    #[test]
    fn a_current_the_voltage_limit_stops_is_the_current_limit_error() {
        let mut id = ElectricalIdentification::new(CONFIG);
        let status = first_level(&mut id, &holding(0.5625, 20.0, true));
        assert_eq!(status, IdentificationStatus::Failed(IdentificationError::CurrentLimit { reached_ma: 562 }));
        assert_eq!(IdentificationError::CurrentLimit { reached_ma: 0 }.fault().info().code, 0xFF12);
    }

    /// IDX 0xFF13: phase B carries nothing (open) while A and C do.
    #[test]
    fn a_phase_without_current_is_the_identification_current_error() {
        let mut id = ElectricalIdentification::new(CONFIG);
        let mut r = holding(0.96, 0.5, false);
        r.signals.i_abc.b = Amps::ZERO;
        let status = first_level(&mut id, &r);
        assert_eq!(status, IdentificationStatus::Failed(IdentificationError::CurrentNotReached { phase: 2 }));
        assert_eq!(IdentificationError::CurrentNotReached { phase: 2 }.fault().info().code, 0xFF13);
    }

    /// The two levels (30 % and 80 % of 3.2 A) with a dead-time voltage of 0.4 V on top of 0.27 ohm: R = dV/dI less
    /// the switches' 10 mOhm, the dead time cancelled.
    #[test]
    fn the_resistance_is_the_slope_between_the_two_levels() {
        let mut id = ElectricalIdentification::new(CONFIG);
        let circuit = 0.27f32;
        let mut status =
            IdentificationStatus::Running(Injection::Current { angle: ElectricalAngle::ZERO, i_d: Amps::ZERO });
        for _ in 0..5_000 {
            let i = match status {
                IdentificationStatus::Running(Injection::Current { i_d, .. }) => i_d.to_bits() as f32 / 65_536.0,
                _ => break,
            };
            status = id.step(&holding(i, circuit * i + 0.4, false));
        }
        assert_eq!(id.step_in_progress(), Step::Inductance);
        assert!((id.resistance_circuit - circuit).abs() < 1e-3, "{}", id.resistance_circuit);
    }

    /// Each error raises its IDX code (seed 002 L7096-7110).
    #[test]
    fn each_error_has_its_idx_code() {
        let codes = [
            (IdentificationError::CurrentLimit { reached_ma: 1 }, 0xFF12),
            (IdentificationError::CurrentNotReached { phase: 1 }, 0xFF13),
            (IdentificationError::PolePairs { measured_x100: 500 }, 0xFF16),
            (IdentificationError::HallSequence { state: 7 }, 0xFF16),
            (IdentificationError::NoEncoder, 0xFF16),
            (IdentificationError::Timeout, 0xFF19),
            (IdentificationError::Standstill { counts: 9 }, 0xFF20),
            (IdentificationError::NoMovement { counts: 0 }, 0xFF21),
            (IdentificationError::Overspeed { rpm: 6000 }, 0xFF22),
        ];
        for (error, code) in codes {
            assert_eq!(error.fault().info().code, code, "{error:?}");
        }
    }
}
