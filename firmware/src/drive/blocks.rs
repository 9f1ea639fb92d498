//! The blocks tier 2 and tier 1 hand each other (`docs/design/tier-ownership.md`): what the tier-2 drive asks of
//! the power stage ([`SetPoint`], [`Settings`]) and what tier 1 measured ([`Tier1Report`]).
//!
//! Plain values. On the host the simulation passes them between the tiers it runs one after the other; on the
//! target they cross through `crate::handoff` ([`Words`]: a [`SetPoint`] and the [`Settings`] in double buffers
//! tier 1 reads without waiting, the report in a sequence lock tier 1 writes without waiting), so every block
//! converts to and from 32-bit words, and the all-zero words decode to the safe block (power stage off, no
//! current, nothing measured).
//!
//! Each block carries a version its writer moves on with every change; the reader acknowledges the versions it
//! applied ([`Tier1Report::setpoint_version`], [`Tier1Report::settings_version`]). That is how tier 2 tells a request
//! tier 1 has not yet acted on from one it has, on the host and on the target alike.

use super::calibration::CalibrationConfig;
use super::commutation::{AlignmentConfig, CommutationMethod};
use super::encoder::EncoderConfig;
use super::scaling::ShuntOffsets;
use super::FastSignals;
use crate::control::angle::ElectricalAngle;
use crate::control::frames::{Abc, Amps, Dq, Volts};
use crate::control::pi::PiGains;
use crate::control::velocity_estimate::PositionWindow;
use crate::handoff::Words;
use crate::power_state::{CalibrationError, CommutationError, CommutationStage, DriveError, PowerState, Trip};
use crate::sensors::latch::{EdgeLatch, PinLatches, DIGITAL_INPUTS};
use crate::sensors::ssi::SsiFormat;
use fixed::types::{I1F31, I8F24};

/// The power-stage state tier 2 asks for (CiA 402 transitions 3-6, 8, 9, 15, as the drive's request methods
/// decide them). Tier 1 acts on it when [`PowerRequest::sequence`] moves on, in this order: a fault reset, a
/// switch-on (calibration), then the level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PowerRequest {
    /// The state to hold: `Off` switches the outputs off (a forced off included), `SwitchedOn` leaves operation
    /// enabled, `OperationEnabled` enables from switched on.
    pub level: PowerLevel,
    /// Moves on with each switch-on request (transition 3: a new current-offset calibration).
    pub switch_on: u8,
    /// Moves on with each fault-reset request (transition 15).
    pub fault_reset: u8,
    /// Moves on with every request of any kind: tier 1 acts once per value.
    pub sequence: u8,
}

/// Periods between the period after a slow tick's report ([`Tier1Report::period`]) and the one from which what the
/// loops decided in that slow tick applies ([`SetPoint::apply_from`]): tier 2 has the raising period and four
/// more to publish it, which covers its budget of 40 % of the slow period (`insn.tier2_total_max` of the QEMU
/// bench) and a tier-3 section holding its lock meanwhile. The QEMU bench measures the periods tier 2 took
/// (`count.setpoint_periods_late_max`), and its test holds them to this.
pub const LOOP_SETPOINT_DELAY_PERIODS: u32 = 4;

/// The level of a [`PowerRequest`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PowerLevel {
    /// Outputs off (transitions 6, 8, 9 and every forced off).
    #[default]
    Off,
    /// Calibrated, outputs off (transition 5 from operation enabled; what a switch-on leads to).
    SwitchedOn,
    /// Current loop running (transition 4).
    OperationEnabled,
    /// Operation enabled with the identification's current injection (`super::identification`): the d current
    /// [`SetPoint::i_d`] at the forced electrical angle carried in the bits of [`SetPoint::i_q`], q current 0.
    InjectCurrent,
    /// Operation enabled with the identification's voltage injection: open loop, the d and q voltages (mV, `i16`
    /// each, low and high half) carried in the bits of [`SetPoint::i_d`] at the forced angle in [`SetPoint::i_q`].
    InjectVoltage,
    /// Operation enabled with the identification's q-axis square wave, open loop: the d voltage (mV, `i16`, low
    /// half of the bits of [`SetPoint::i_d`]) and a q voltage of +-the amplitude (mV, high half) that tier 1
    /// reverses every second period; the angle in the bits of [`SetPoint::i_q`] (`super::tier1`).
    InjectSquareQ,
    /// As [`Self::InjectSquareQ`] with the square wave on d (added to the d voltage), q voltage 0.
    InjectSquareD,
}

impl PowerLevel {
    /// Whether the level is one of the identification's injections.
    #[must_use]
    pub const fn injects(self) -> bool {
        matches!(self, Self::InjectCurrent | Self::InjectVoltage | Self::InjectSquareQ | Self::InjectSquareD)
    }
}

/// Tier 2 -> tier 1 at every change: the power request and the q-current reference, already converted
/// (the loops' demand, or target torque 0x6071 + offset 0x60B2 through the demand scale) and clamped, and the
/// period from which tier 1 applies it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SetPoint {
    /// Moves on with every change of this block.
    pub version: u32,
    /// The power-stage request.
    pub power: PowerRequest,
    /// The q-current reference.
    pub i_q: Amps,
    /// The d-current reference: zero, or negative while the bus-voltage limiter burns regenerated energy in the
    /// winding (`super::regeneration`).
    pub i_d: Amps,
    /// Tier 1's period number ([`Tier1Report::period`]) from which the block applies: a period already begun for
    /// a request to act on at once, a later one for what the loops decided in a slow tick, which on the target
    /// comes into force at a fixed phase of the slow period whatever time tier 2 took (`super::Drive`,
    /// "Hand-off timing").
    pub apply_from: u32,
}

/// How tier 1 builds and runs the commutation (the power-disabled objects, read by tier 2 at switch-on).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommutationSettings {
    /// Hall sectors, or forced alignment.
    pub method: CommutationMethod,
    /// The encoder and pole pairs.
    pub encoder: EncoderConfig,
    /// 0x301A:03.
    pub hall_offset: ElectricalAngle,
    /// The electrical angle at the index configured in 0x3010:05: wins over a learned one.
    pub configured_index_offset: Option<ElectricalAngle>,
    /// The construction-time default: used when neither a configured nor a learned one is known.
    pub default_index_offset: Option<ElectricalAngle>,
    /// 0x301A:01 bit 0: invert the Hall signals (`0b111`) or not (0).
    pub hall_mask: u8,
    /// 0x3000:01 sensor 1 is the incremental encoder; without it the Halls are the position sensor.
    pub encoder_present: bool,
}

impl Default for CommutationSettings {
    fn default() -> Self {
        Self {
            method: CommutationMethod::Hall,
            encoder: EncoderConfig::REFERENCE,
            hall_offset: ElectricalAngle::ZERO,
            configured_index_offset: None,
            default_index_offset: None,
            hall_mask: 0,
            encoder_present: true,
        }
    }
}

/// Tier 2 -> tier 1 when a parameter changes: everything tier 1 runs with that comes from the dictionary,
/// converted by tier 2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Moves on with every change of this block.
    pub version: u32,
    /// 0x3001:02 output current limit in mA (tier 1's trip limits follow from it).
    pub output_limit_ma: u32,
    /// The current controller's gains (0x30A0, converted).
    pub gains: PiGains,
    /// The offset calibration.
    pub calibration: CalibrationConfig,
    /// The commutation.
    pub commutation: CommutationSettings,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            version: 0,
            output_limit_ma: 0,
            gains: PiGains::ZERO,
            calibration: CalibrationConfig::DEFAULT,
            commutation: CommutationSettings::default(),
        }
    }
}

/// Tier 1 -> tier 2 at every slow-tick boundary (every tenth period): what tier 1 measured and decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tier1Report {
    /// The number of the period after the reporting one (tier 1's periods since start, wrapping): what a
    /// [`SetPoint::apply_from`] counts in.
    pub period: u32,
    /// The [`SetPoint::version`] tier 1 has applied.
    pub setpoint_version: u32,
    /// The [`Settings::version`] tier 1 has applied.
    pub settings_version: u32,
    /// The [`PowerRequest::sequence`] tier 1 has acted on.
    pub power_sequence: u8,
    /// The power-stage state at the end of the reporting period.
    pub power: PowerState,
    /// The reporting period's measurements and outputs.
    pub signals: FastSignals,
    /// What the period that tripped measured (the fault's diagnosis data).
    pub trip_sample: FastSignals,
    /// The last sample's break input (whether a trip's cause persists).
    pub break_input: bool,
    /// The encoder's position (counts; it stays put without an encoder, whose counter input tier 1 ignores).
    pub encoder_position: i32,
    /// The position counted from the Hall states.
    pub hall_position: i32,
    /// The encoder positions summed over the slow period that just ended.
    pub encoder_window: PositionWindow,
    /// The input edges and the index latched.
    pub latches: PinLatches,
    /// The commutation angle.
    pub angle: ElectricalAngle,
    /// How well the angle is known.
    pub stage: CommutationStage,
    /// The encoder counter at the last index pulse the commutation used.
    pub last_index_latch: Option<u16>,
    /// The electrical angle at the index in use (configured, learned or the default).
    pub index_offset: Option<ElectricalAngle>,
    /// The shunt offsets in use.
    pub offsets: ShuntOffsets,
    /// Running sums (wrapping, `I16F16` bits) of the measured q current and the applied q voltage over every
    /// current-loop period, never reset (two additions and no branch in tier 1): the difference of two reports
    /// over the periods between them is a slow tick's average, free of one period's noise (the motor
    /// identification's mechanical step, `super::auto_setup`).
    pub q_sums: [i32; 2],
    /// The SSI frame of the reporting period (0 without an SSI sensor): tier 2 reads the multi-turn position, the
    /// raw value objects and the special bits from it and checks it whole.
    pub ssi_frame: u32,
}

impl Default for Tier1Report {
    fn default() -> Self {
        Self {
            period: 0,
            setpoint_version: 0,
            settings_version: 0,
            power_sequence: 0,
            power: PowerState::Off,
            signals: FastSignals::default(),
            trip_sample: FastSignals::default(),
            break_input: false,
            encoder_position: 0,
            hall_position: 0,
            encoder_window: PositionWindow::default(),
            latches: PinLatches::default(),
            angle: ElectricalAngle::ZERO,
            stage: CommutationStage::Unknown,
            last_index_latch: None,
            index_offset: None,
            offsets: ShuntOffsets::NOMINAL,
            q_sums: [0; 2],
            ssi_frame: 0,
        }
    }
}

// -------------------------------------------------------------------------------------------------------------
// Words
// -------------------------------------------------------------------------------------------------------------

/// Fills words in order (a word past the end is dropped: the sizes below are checked by the round-trip tests).
struct Put<const N: usize> {
    words: [u32; N],
    at: usize,
}

impl<const N: usize> Put<N> {
    const fn new() -> Self {
        Self { words: [0; N], at: 0 }
    }

    fn word(&mut self, word: u32) -> &mut Self {
        if let Some(slot) = self.words.get_mut(self.at) {
            *slot = word;
        }
        self.at = self.at.wrapping_add(1);
        self
    }

    fn int(&mut self, value: i32) -> &mut Self {
        self.word(value.cast_unsigned())
    }
}

/// Takes words in order (a word past the end reads 0).
struct Take<'a, const N: usize> {
    words: &'a [u32; N],
    at: usize,
}

impl<'a, const N: usize> Take<'a, N> {
    const fn new(words: &'a [u32; N]) -> Self {
        Self { words, at: 0 }
    }

    fn word(&mut self) -> u32 {
        let word = self.words.get(self.at).copied().unwrap_or(0);
        self.at = self.at.wrapping_add(1);
        word
    }

    fn int(&mut self) -> i32 {
        self.word().cast_signed()
    }
}

/// Byte `n` (0..=3) of `word`.
const fn byte(word: u32, n: u32) -> u8 {
    (word >> (n.wrapping_mul(8) & 31)) as u8
}

/// The low half of `word`.
const fn low_half(word: u32) -> u16 {
    word as u16
}

/// The high half of `word`.
const fn high_half(word: u32) -> u16 {
    (word >> 16) as u16
}

/// Two halves as one word.
const fn halves(low: u16, high: u16) -> u32 {
    (low as u32) | ((high as u32) << 16)
}

impl SetPoint {
    /// The power request as its word in the block.
    #[must_use]
    pub const fn power_word(&self) -> u32 {
        let p = &self.power;
        let level = match p.level {
            PowerLevel::Off => 0,
            PowerLevel::SwitchedOn => 1,
            PowerLevel::OperationEnabled => 2,
            PowerLevel::InjectCurrent => 3,
            PowerLevel::InjectVoltage => 4,
            PowerLevel::InjectSquareQ => 5,
            PowerLevel::InjectSquareD => 6,
        };
        u32::from_le_bytes([level, p.switch_on, p.fault_reset, p.sequence])
    }
}

/// Words of a [`SetPoint`].
pub const SETPOINT_WORDS: usize = 5;

impl Words<SETPOINT_WORDS> for SetPoint {
    fn to_words(&self) -> [u32; SETPOINT_WORDS] {
        [
            self.version,
            self.power_word(),
            self.i_q.to_bits().cast_unsigned(),
            self.i_d.to_bits().cast_unsigned(),
            self.apply_from,
        ]
    }

    fn from_words(words: &[u32; SETPOINT_WORDS]) -> Self {
        let [version, power, i_q, i_d, apply_from] = *words;
        let level = match byte(power, 0) {
            1 => PowerLevel::SwitchedOn,
            2 => PowerLevel::OperationEnabled,
            3 => PowerLevel::InjectCurrent,
            4 => PowerLevel::InjectVoltage,
            5 => PowerLevel::InjectSquareQ,
            6 => PowerLevel::InjectSquareD,
            // 0, and anything not written by `to_words`: the safe level.
            _ => PowerLevel::Off,
        };
        Self {
            version,
            power: PowerRequest {
                level,
                switch_on: byte(power, 1),
                fault_reset: byte(power, 2),
                sequence: byte(power, 3),
            },
            i_q: Amps::from_bits(i_q.cast_signed()),
            i_d: Amps::from_bits(i_d.cast_signed()),
            apply_from,
        }
    }
}

impl Words<15> for Settings {
    #[inline(never)]
    fn to_words(&self) -> [u32; 15] {
        let c = &self.commutation;
        let (forced, alignment) = match c.method {
            CommutationMethod::Hall | CommutationMethod::Absolute(_) => (false, None),
            CommutationMethod::ForcedAlignment(a) => (true, Some(a)),
        };
        let ssi = match c.method {
            CommutationMethod::Absolute(f) => Some(f),
            _ => None,
        };
        let flags = u32::from(forced)
            | u32::from(ssi.is_some()) << 1
            | u32::from(c.hall_mask) << 8
            | u32::from(c.encoder_present) << 16
            | u32::from(c.configured_index_offset.is_some()) << 17
            | u32::from(c.default_index_offset.is_some()) << 18
            | u32::from(c.encoder.inverted) << 19
            | u32::from(c.encoder.has_index) << 20
            | u32::from(c.encoder.pole_pairs) << 24;
        let mut a = alignment.unwrap_or(AlignmentConfig {
            current: Amps::ZERO,
            ramp_ticks: 0,
            hold_ticks: 0,
            damping_bits_per_count: 0,
        });
        if let Some(f) = ssi {
            // The SSI format travels in the alignment's words, which the absolute method does not use.
            let [first, second] = ssi_format_words(&f);
            a = AlignmentConfig {
                current: Amps::from_bits(first.cast_signed()),
                ramp_ticks: low_half(second),
                hold_ticks: high_half(second),
                damping_bits_per_count: f.commutation_offset.cast_signed(),
            };
        }
        let cal = &self.calibration;
        let mut put = Put::<15>::new();
        put.word(self.version)
            .word(self.output_limit_ma)
            .int(self.gains.kp().to_bits())
            .int(self.gains.ki_ts().to_bits())
            .int(self.gains.kb().to_bits())
            .word(halves(cal.settle_ticks, cal.window_lsb))
            .word(halves(cal.max_spread_lsb, cal.timeout_ticks))
            .word(flags)
            .int(a.current.to_bits())
            .word(halves(a.ramp_ticks, a.hold_ticks))
            .int(a.damping_bits_per_count)
            .word(c.encoder.counts_per_rev)
            .word(c.hall_offset.0)
            .word(c.configured_index_offset.map_or(0, |o| o.0))
            .word(c.default_index_offset.map_or(0, |o| o.0));
        put.words
    }

    #[inline(never)]
    fn from_words(words: &[u32; 15]) -> Self {
        let mut take = Take::new(words);
        let version = take.word();
        let output_limit_ma = take.word();
        let kp = I8F24::from_bits(take.int());
        let ki_ts = I8F24::from_bits(take.int());
        let kb = I1F31::from_bits(take.int());
        let cal_a = take.word();
        let cal_b = take.word();
        let flags = take.word();
        let current = Amps::from_bits(take.int());
        let ticks = take.word();
        let damping_bits_per_count = take.int();
        let counts_per_rev = take.word();
        let hall_offset = ElectricalAngle(take.word());
        let configured = ElectricalAngle(take.word());
        let default = ElectricalAngle(take.word());
        let bit = |n: u32| flags >> n & 1 == 1;
        let method = if bit(1) {
            CommutationMethod::Absolute(ssi_format_from_words(
                current.to_bits().cast_unsigned(),
                ticks,
                damping_bits_per_count.cast_unsigned(),
            ))
        } else if bit(0) {
            CommutationMethod::ForcedAlignment(AlignmentConfig {
                current,
                ramp_ticks: low_half(ticks),
                hold_ticks: high_half(ticks),
                damping_bits_per_count,
            })
        } else {
            CommutationMethod::Hall
        };
        Self {
            version,
            output_limit_ma,
            gains: PiGains::new(kp, ki_ts, kb),
            calibration: CalibrationConfig {
                settle_ticks: low_half(cal_a),
                window_lsb: high_half(cal_a),
                max_spread_lsb: low_half(cal_b),
                timeout_ticks: high_half(cal_b),
            },
            commutation: CommutationSettings {
                method,
                encoder: EncoderConfig {
                    counts_per_rev,
                    pole_pairs: byte(flags, 3),
                    inverted: bit(19),
                    has_index: bit(20),
                },
                hall_offset,
                configured_index_offset: bit(17).then_some(configured),
                default_index_offset: bit(18).then_some(default),
                hall_mask: byte(flags, 1),
                encoder_present: bit(16),
            },
        }
    }
}

/// An SSI format's fields in two words: multi-turn, single-turn and special bits and the flags (Gray, frame
/// check, inverted); the position bits kept, the alignment shift and the clocked bits.
fn ssi_format_words(f: &SsiFormat) -> [u32; 2] {
    let flags = u8::from(f.gray) | u8::from(f.frame_check) << 1 | u8::from(f.inverted) << 2;
    [
        u32::from_le_bytes([f.multi_turn_bits, f.single_turn_bits, f.special_bits, flags]),
        u32::from_le_bytes([f.multi_turn_position_bits, f.single_turn_position_bits, f.align_bits, f.frame_bits]),
    ]
}

/// [`ssi_format_words`] back, with the commutation offset.
fn ssi_format_from_words(first: u32, second: u32, commutation_offset: u32) -> SsiFormat {
    let [multi_turn_bits, single_turn_bits, special_bits, flags] = first.to_le_bytes();
    let [multi_turn_position_bits, single_turn_position_bits, align_bits, frame_bits] = second.to_le_bytes();
    SsiFormat {
        frame_bits,
        multi_turn_bits,
        single_turn_bits,
        special_bits,
        multi_turn_position_bits,
        single_turn_position_bits,
        gray: flags & 1 != 0,
        frame_check: flags & 2 != 0,
        inverted: flags & 4 != 0,
        align_bits,
        commutation_offset,
    }
}

/// Words of a [`FastSignals`].
const SIGNAL_WORDS: usize = 12;

fn put_signals<const N: usize>(put: &mut Put<N>, s: &FastSignals) {
    put.int(s.i_abc.a.to_bits())
        .int(s.i_abc.b.to_bits())
        .int(s.i_abc.c.to_bits())
        .int(s.i_dq.d.to_bits())
        .int(s.i_dq.q.to_bits())
        .int(s.i_ref.d.to_bits())
        .int(s.i_ref.q.to_bits())
        .int(s.v_dq.d.to_bits())
        .int(s.v_dq.q.to_bits())
        .int(s.v_bus.to_bits())
        .word(u32::from(s.saturated) | u32::from(s.hall) << 8);
    put.word(halves(s.temperature_codes[0], s.temperature_codes[1]));
}

fn take_signals<const N: usize>(take: &mut Take<'_, N>) -> FastSignals {
    let amps = |take: &mut Take<'_, N>| Amps::from_bits(take.int());
    let volts = |take: &mut Take<'_, N>| Volts::from_bits(take.int());
    let i_abc = Abc { a: amps(take), b: amps(take), c: amps(take) };
    let i_dq = Dq::new(amps(take), amps(take));
    let i_ref = Dq::new(amps(take), amps(take));
    let v_dq = Dq::new(volts(take), volts(take));
    let v_bus = volts(take);
    let packed = take.word();
    let temperatures = take.word();
    FastSignals {
        i_abc,
        i_dq,
        i_ref,
        v_dq,
        v_bus,
        saturated: packed & 1 == 1,
        hall: byte(packed, 1),
        temperature_codes: [low_half(temperatures), high_half(temperatures)],
    }
}

/// The power state as two words: tag, error kind, cause and channel bytes, and a payload.
fn power_words(power: PowerState) -> [u32; 2] {
    let (tag, kind, cause, channel, payload) = match power {
        PowerState::Off => (0, 0, 0, 0, 0),
        PowerState::Calibrating => (1, 0, 0, 0, 0),
        PowerState::SwitchedOn => (2, 0, 0, 0, 0),
        PowerState::OperationEnabled => (3, 0, 0, 0, 0),
        PowerState::Fault(error) => match error {
            DriveError::Calibration(e) => match e {
                CalibrationError::OffsetOutOfRange { channel, deviation_lsb } => {
                    (4, 0, 0, channel, u32::from(deviation_lsb.cast_unsigned()))
                }
                CalibrationError::Unsteady { channel, spread_lsb } => (4, 0, 1, channel, u32::from(spread_lsb)),
                CalibrationError::Timeout => (4, 0, 2, 0, 0),
                CalibrationError::Aborted => (4, 0, 3, 0, 0),
            },
            DriveError::Commutation(CommutationError::InvalidHallState(hall)) => (4, 1, hall, 0, 0),
            DriveError::Commutation(CommutationError::SsiNoData) => (4, 1, 0, 1, 0),
            DriveError::Commutation(CommutationError::SsiMissing) => (4, 1, 0, 2, 0),
            DriveError::Commutation(CommutationError::SsiFrame) => (4, 1, 0, 3, 0),
            DriveError::Protection(trip) => {
                let cause = match trip {
                    Trip::BreakInput => 0,
                    Trip::BusOverVoltage => 1,
                    Trip::BusUnderVoltage => 2,
                    Trip::OverCurrent => 3,
                    Trip::PhaseSum => 4,
                };
                (4, 2, cause, 0, 0)
            }
            DriveError::Overrun { cost } => (4, 3, 0, 0, cost),
        },
    };
    [u32::from_le_bytes([tag, kind, cause, channel]), payload]
}

fn power_from_words(head: u32, payload: u32) -> PowerState {
    let cause = byte(head, 2);
    let channel = byte(head, 3);
    let error = match byte(head, 1) {
        0 => DriveError::Calibration(match cause {
            0 => CalibrationError::OffsetOutOfRange { channel, deviation_lsb: low_half(payload).cast_signed() },
            1 => CalibrationError::Unsteady { channel, spread_lsb: low_half(payload) },
            2 => CalibrationError::Timeout,
            _ => CalibrationError::Aborted,
        }),
        1 => DriveError::Commutation(match channel {
            1 => CommutationError::SsiNoData,
            2 => CommutationError::SsiMissing,
            3 => CommutationError::SsiFrame,
            _ => CommutationError::InvalidHallState(cause),
        }),
        2 => DriveError::Protection(match cause {
            0 => Trip::BreakInput,
            1 => Trip::BusOverVoltage,
            2 => Trip::BusUnderVoltage,
            3 => Trip::OverCurrent,
            _ => Trip::PhaseSum,
        }),
        _ => DriveError::Overrun { cost: payload },
    };
    match byte(head, 0) {
        1 => PowerState::Calibrating,
        2 => PowerState::SwitchedOn,
        3 => PowerState::OperationEnabled,
        4 => PowerState::Fault(error),
        _ => PowerState::Off,
    }
}

fn stage_byte(stage: CommutationStage) -> u32 {
    match stage {
        CommutationStage::Unknown => 0,
        CommutationStage::HallSector => 1,
        CommutationStage::HallEdge => 2,
        CommutationStage::Aligning => 3,
        CommutationStage::Aligned => 4,
        CommutationStage::Indexed => 5,
        CommutationStage::Injecting => 6,
    }
}

fn stage_from_byte(value: u8) -> CommutationStage {
    match value {
        1 => CommutationStage::HallSector,
        2 => CommutationStage::HallEdge,
        3 => CommutationStage::Aligning,
        4 => CommutationStage::Aligned,
        5 => CommutationStage::Indexed,
        6 => CommutationStage::Injecting,
        _ => CommutationStage::Unknown,
    }
}

/// Words of a [`Tier1Report`].
pub const REPORT_WORDS: usize = 4 + 2 + 2 * SIGNAL_WORDS + 4 + 1 + 2 * (2 * DIGITAL_INPUTS + 1) + 3 + 3 + 2 + 1;

impl Words<REPORT_WORDS> for Tier1Report {
    #[inline(never)]
    fn to_words(&self) -> [u32; REPORT_WORDS] {
        let mut put = Put::<REPORT_WORDS>::new();
        let flags = u32::from(self.power_sequence)
            | u32::from(self.break_input) << 8
            | u32::from(self.last_index_latch.is_some()) << 9
            | u32::from(self.index_offset.is_some()) << 10
            | stage_byte(self.stage) << 16;
        let [head, payload] = power_words(self.power);
        put.word(self.period)
            .word(self.setpoint_version)
            .word(self.settings_version)
            .word(flags)
            .word(head)
            .word(payload);
        put_signals(&mut put, &self.signals);
        put_signals(&mut put, &self.trip_sample);
        put.int(self.encoder_position)
            .int(self.hall_position)
            .int(self.encoder_window.sum)
            .int(self.encoder_window.position)
            .word(u32::from(self.latches.levels));
        let l = &self.latches;
        for latch in l.rising.iter().chain(&l.falling).chain(core::iter::once(&l.index)) {
            put.word(u32::from(latch.count)).int(latch.position);
        }
        put.word(self.angle.0)
            .word(u32::from(self.last_index_latch.unwrap_or(0)))
            .word(self.index_offset.map_or(0, |o| o.0));
        for offset in self.offsets.q8 {
            put.int(offset);
        }
        put.int(self.q_sums[0]).int(self.q_sums[1]).word(self.ssi_frame);
        put.words
    }

    #[inline(never)]
    fn from_words(words: &[u32; REPORT_WORDS]) -> Self {
        let mut take = Take::new(words);
        let period = take.word();
        let setpoint_version = take.word();
        let settings_version = take.word();
        let flags = take.word();
        let head = take.word();
        let payload = take.word();
        let signals = take_signals(&mut take);
        let trip_sample = take_signals(&mut take);
        let encoder_position = take.int();
        let hall_position = take.int();
        let encoder_window = PositionWindow { sum: take.int(), position: take.int() };
        let levels = byte(take.word(), 0);
        let edge = |take: &mut Take<'_, REPORT_WORDS>| EdgeLatch { count: low_half(take.word()), position: take.int() };
        let rising = core::array::from_fn(|_| edge(&mut take));
        let falling = core::array::from_fn(|_| edge(&mut take));
        let index = edge(&mut take);
        let angle = ElectricalAngle(take.word());
        let last_index_latch = low_half(take.word());
        let index_offset = ElectricalAngle(take.word());
        let offsets = ShuntOffsets { q8: core::array::from_fn(|_| take.int()) };
        let q_sums = [take.int(), take.int()];
        let ssi_frame = take.word();
        let bit = |n: u32| flags >> n & 1 == 1;
        Self {
            period,
            setpoint_version,
            settings_version,
            power_sequence: byte(flags, 0),
            power: power_from_words(head, payload),
            signals,
            trip_sample,
            break_input: bit(8),
            encoder_position,
            hall_position,
            encoder_window,
            latches: PinLatches { levels, rising, falling, index },
            angle,
            stage: stage_from_byte(byte(flags, 2)),
            last_index_latch: bit(9).then_some(last_index_latch),
            index_offset: bit(10).then_some(index_offset),
            offsets,
            q_sums,
            ssi_frame,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip<B: Words<N> + PartialEq + core::fmt::Debug, const N: usize>(block: B) {
        assert_eq!(B::from_words(&block.to_words()), block);
    }

    fn signals(seed: i32) -> FastSignals {
        FastSignals {
            i_abc: Abc { a: Amps::from_bits(seed), b: Amps::from_bits(-seed), c: Amps::from_bits(seed * 3) },
            i_dq: Dq::new(Amps::from_bits(seed + 1), Amps::from_bits(-seed - 2)),
            i_ref: Dq::new(Amps::from_bits(7), Amps::from_bits(i32::MIN)),
            v_dq: Dq::new(Volts::from_bits(i32::MAX), Volts::from_bits(-5)),
            v_bus: Volts::from_bits(48 << 16),
            saturated: true,
            hall: 0b101,
            temperature_codes: [4095, 17],
        }
    }

    #[test]
    fn zero_words_decode_to_the_safe_blocks() {
        assert_eq!(SetPoint::from_words(&[0; SETPOINT_WORDS]), SetPoint::default());
        let settings = Settings::from_words(&[0; 15]);
        assert_eq!(settings.commutation.method, CommutationMethod::Hall);
        assert_eq!(settings.version, 0);
        let report = Tier1Report::from_words(&[0; REPORT_WORDS]);
        assert_eq!(report.power, PowerState::Off);
        assert_eq!(report.stage, CommutationStage::Unknown);
    }

    #[test]
    fn a_set_point_survives_its_words() {
        round_trip(SetPoint {
            version: u32::MAX,
            power: PowerRequest { level: PowerLevel::OperationEnabled, switch_on: 255, fault_reset: 3, sequence: 9 },
            i_q: Amps::from_bits(-123_456),
            i_d: Amps::from_bits(-654_321),
            apply_from: u32::MAX,
        });
        for level in
            [PowerLevel::InjectCurrent, PowerLevel::InjectVoltage, PowerLevel::InjectSquareQ, PowerLevel::InjectSquareD]
        {
            round_trip(SetPoint {
                version: 2,
                power: PowerRequest { level, switch_on: 1, fault_reset: 0, sequence: 3 },
                i_q: Amps::from_bits(-1),
                i_d: Amps::from_bits(0x7FFF_8001),
                apply_from: 5,
            });
        }
        round_trip(SetPoint {
            version: 1,
            power: PowerRequest { level: PowerLevel::SwitchedOn, ..PowerRequest::default() },
            i_q: Amps::ZERO,
            i_d: Amps::ZERO,
            apply_from: 17,
        });
    }

    #[test]
    fn settings_survive_their_words() {
        let gains = PiGains::from_idx_0x30a0(1_234_567, 98_765);
        round_trip(Settings {
            version: 77,
            output_limit_ma: 10_000,
            gains,
            calibration: CalibrationConfig {
                settle_ticks: 50,
                window_lsb: 100,
                max_spread_lsb: 48,
                timeout_ticks: 625,
            },
            commutation: CommutationSettings {
                method: CommutationMethod::ForcedAlignment(AlignmentConfig {
                    current: Amps::from_bits(-3 << 16),
                    ramp_ticks: 1000,
                    hold_ticks: 65535,
                    damping_bits_per_count: -42,
                }),
                encoder: EncoderConfig {
                    counts_per_rev: 10_000_000,
                    pole_pairs: 255,
                    inverted: true,
                    has_index: false,
                },
                hall_offset: ElectricalAngle(0xDEAD_BEEF),
                configured_index_offset: Some(ElectricalAngle(0)),
                default_index_offset: None,
                hall_mask: 0b111,
                encoder_present: false,
            },
        });
        round_trip(Settings {
            commutation: CommutationSettings {
                default_index_offset: Some(ElectricalAngle(u32::MAX)),
                ..CommutationSettings::default()
            },
            ..Settings::default()
        });
        // The SSI absolute method's format travels in the alignment's words.
        for ssi in [
            SsiFormat { commutation_offset: u32::MAX, ..SsiFormat::REFERENCE },
            SsiFormat { gray: false, frame_check: false, inverted: true, align_bits: 4, ..SsiFormat::REFERENCE },
        ] {
            round_trip(Settings {
                commutation: CommutationSettings {
                    method: CommutationMethod::Absolute(ssi),
                    encoder_present: false,
                    ..CommutationSettings::default()
                },
                ..Settings::default()
            });
        }
    }

    #[test]
    fn every_power_state_survives_the_report() {
        let states = [
            PowerState::Off,
            PowerState::Calibrating,
            PowerState::SwitchedOn,
            PowerState::OperationEnabled,
            PowerState::Fault(DriveError::Calibration(CalibrationError::OffsetOutOfRange {
                channel: 2,
                deviation_lsb: -300,
            })),
            PowerState::Fault(DriveError::Calibration(CalibrationError::Unsteady { channel: 1, spread_lsb: 60_000 })),
            PowerState::Fault(DriveError::Calibration(CalibrationError::Timeout)),
            PowerState::Fault(DriveError::Calibration(CalibrationError::Aborted)),
            PowerState::Fault(DriveError::Commutation(CommutationError::InvalidHallState(7))),
            PowerState::Fault(DriveError::Commutation(CommutationError::SsiNoData)),
            PowerState::Fault(DriveError::Commutation(CommutationError::SsiMissing)),
            PowerState::Fault(DriveError::Commutation(CommutationError::SsiFrame)),
            PowerState::Fault(DriveError::Protection(Trip::BreakInput)),
            PowerState::Fault(DriveError::Protection(Trip::BusOverVoltage)),
            PowerState::Fault(DriveError::Protection(Trip::BusUnderVoltage)),
            PowerState::Fault(DriveError::Protection(Trip::OverCurrent)),
            PowerState::Fault(DriveError::Protection(Trip::PhaseSum)),
            PowerState::Fault(DriveError::Overrun { cost: u32::MAX }),
        ];
        for power in states {
            round_trip(Tier1Report { power, ..Tier1Report::default() });
        }
        round_trip(Tier1Report { ssi_frame: 0xDEAD_BEEF, ..Tier1Report::default() });
    }

    #[test]
    fn a_full_report_survives_its_words() {
        let edge = |n: i32| EdgeLatch { count: u16::try_from(n).unwrap_or(0), position: -n * 1000 };
        round_trip(Tier1Report {
            period: 0xFFFF_FFF0,
            setpoint_version: 5,
            settings_version: 6,
            power_sequence: 200,
            power: PowerState::OperationEnabled,
            signals: signals(1 << 16),
            trip_sample: signals(-77),
            break_input: true,
            encoder_position: i32::MIN,
            hall_position: -12,
            encoder_window: PositionWindow { sum: i32::MAX, position: -1 },
            latches: PinLatches {
                levels: 0b1010,
                rising: [edge(1), edge(2), edge(3), edge(4)],
                falling: [edge(5), edge(6), edge(7), edge(8)],
                index: edge(65_535),
            },
            angle: ElectricalAngle(0x8000_0000),
            stage: CommutationStage::Indexed,
            last_index_latch: Some(0),
            index_offset: Some(ElectricalAngle(12_345)),
            offsets: ShuntOffsets { q8: [524_288, -1, i32::MAX] },
            q_sums: [i32::MIN, 123_456],
            ssi_frame: 0x0280_0001,
        });
        for stage in [
            CommutationStage::HallSector,
            CommutationStage::HallEdge,
            CommutationStage::Aligning,
            CommutationStage::Aligned,
            CommutationStage::Injecting,
        ] {
            round_trip(Tier1Report { stage, ..Tier1Report::default() });
        }
    }
}
