//! The data recorder (issue 22 item 2; EPOS4's data recorder as the model): up to [`MAX_CHANNELS`] channels of
//! dictionary objects or current-loop variables, sampled at 25 kHz or a divider of it, a trigger on a value, an
//! edge or bits with preceding samples, and the recording read back as a DOMAIN by SDO (segmented or block on
//! CANopen, CoE on EtherCAT).
//!
//! # Objects (`firmware/device.toml`; the seeds name the recorder, EPOS4 L2657, but none of its objects)
//! - 0x3300 *Data recorder*: :01 control (0 stop, 1 arm, 2 trigger now), :02 state ([`RecorderState`]), :03
//!   sampling period in current-loop periods (1 = 25 kHz, 10 = 2.5 kHz), :04 number of samples (0 = as many as
//!   fit), :05 preceding samples, :06 trigger mode ([`trigger`]), :07 trigger channel, :08 threshold, :09 mask,
//!   :0A samples the buffer holds with the channels configured, :0B samples of the last recording.
//! - 0x3301 *Data recorder variables*: :00 number of channels, :01..:08 `0xIIIISS00` (index, sub-index) of each.
//!   A channel is a TxPDO-mappable integer or BOOLEAN of up to 32 bits (what a master may sample cyclically
//!   anyway), or a current-loop variable (0x3303, below); anything else is refused with 0x0604_0041 (CiA 301
//!   Table 22: "object cannot be mapped"). A value of up to 16 bits takes 2 bytes a sample, a wider one 4.
//! - 0x3302 *Data recorder buffer*: DOMAIN, the last complete recording, oldest sample first, each sample the
//!   channels in order, little-endian, no padding (a tool labels them from 0x3301 and the objects' types).
//! - 0x3303 is no object but names the current-loop variables in a channel entry (`0x3303SS00`): SS = 1..3 phase
//!   currents A, B, C, 4 d current, 5 q current, 6 q reference (mA, 16 bits), 7 d voltage, 8 q voltage, 9 bus
//!   voltage (mV, 32 bits), 10..12 duties A, B, C (compare ticks, 16 bits), 13 encoder position (inc, 32 bits).
//!
//! Every entry is served here ([`objects`]): the recorder owns its configuration. Every write either acts or
//! refuses: ranges and option codes by the dictionary's limits (0x0609_0030..32) before it comes here, any
//! configuration write while armed or recording with 0x0800_0022 (CiA 301 Table 22: "because of the present
//! device state"), an arm whose configuration cannot be recorded (no channel, a trigger channel beyond the
//! channels, more samples than the buffer holds, as many preceding samples as samples, no buffer) with
//! 0x0604_0043 ("general parameter incompatibility"), a trigger-now outside the waiting state with 0x0800_0022,
//! and a buffer read while the recorder samples into it with 0x0800_0022 (idle without a recording, the buffer
//! reads empty).
//!
//! # Tiers and owner
//! Tier 1 pays a fixed cost whatever is recorded: while the recorder samples, a copy of its published values into
//! [`ring::SampleRing`] every period after the PWM write (one load otherwise). Tier 2 takes the object channels' values once a slow period after its set-point is published
//! ([`Recorder::take_objects`]: at 25 kHz they repeat over the ten samples of a slow period, they change at 2.5 kHz
//! at most). Tier 3 drains the ring ([`Recorder::drain`], a few snapshots per section so that it holds tier 2 off
//! briefly): it picks the channels, converts the units, runs the trigger and stores the samples, so the cost per
//! channel falls in neither loop's step. The ring is deep enough for tier 3 to fall behind by
//! [`ring::RING_SLOTS`] periods; beyond that samples are lost and counted ([`Recorder::lost`]). A sample row never straddles the end of the
//! buffer (its capacity is a whole number of rows), so the drain checks the wrap once a sample, not once a channel.
//!
//! The recorder belongs to the runtime, not to the dictionary: on the target `rt::tier2::RECORDER` (tier 2's
//! drain and tier 3's SDO servers, under the tier-2 lock), on the host the simulation's. The SDO servers reach it
//! through the application-objects port ([`objects::RecorderObjects`]), as they reach the parameter store and
//! program control. Its sample memory is RAM the owner gives it ([`Recorder::attach`]): on the target 64 KiB of
//! SRAM (`rt::RECORDER_BUFFER_HALVES`), on the host a leaked allocation of the same size.

pub mod objects;
pub mod ring;

use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use crate::od::abort::SdoAbort;
use crate::od::access::Table;
use crate::od::entry::{DataType, Entry, Storage};
use ring::{SampleRing, RING_REACH, SAMPLE_WORDS};

/// 0x3300 *Data recorder*.
pub const RECORDER: u16 = 0x3300;
/// 0x3301 *Data recorder variables*.
pub const VARIABLES: u16 = 0x3301;
/// 0x3302 *Data recorder buffer*.
pub const BUFFER: u16 = 0x3302;
/// 0x3303: the index that names a current-loop variable in a channel entry (`0x3303SS00`, the variable's number
/// in SS). Not an object: the CAN image has no flash for thirteen more entries.
pub const TIER1_VARIABLES: u16 = 0x3303;
/// Channels at most.
pub const MAX_CHANNELS: usize = 8;

/// Sub-indices of 0x3300.
pub mod sub {
    /// Control: 0 stop, 1 arm, 2 trigger now.
    pub const CONTROL: u8 = 1;
    /// State ([`super::RecorderState`]).
    pub const STATE: u8 = 2;
    /// Sampling period, current-loop periods.
    pub const PERIOD: u8 = 3;
    /// Number of samples (0 = as many as fit).
    pub const SAMPLES: u8 = 4;
    /// Number of preceding samples.
    pub const PRECEDING: u8 = 5;
    /// Trigger mode ([`super::trigger`]).
    pub const MODE: u8 = 6;
    /// Trigger channel (1..=8).
    pub const TRIGGER_CHANNEL: u8 = 7;
    /// Trigger threshold.
    pub const THRESHOLD: u8 = 8;
    /// Trigger mask.
    pub const MASK: u8 = 9;
    /// Samples the buffer holds with the channels configured.
    pub const MAX_SAMPLES: u8 = 10;
    /// Samples of the last complete recording.
    pub const RECORDED: u8 = 11;
}

/// Trigger modes (0x3300:06), on the trigger channel's value `v` and the sample before it `p`.
pub mod trigger {
    /// At the first sample after arming.
    pub const IMMEDIATE: u8 = 0;
    /// `p < threshold <= v`.
    pub const RISING: u8 = 1;
    /// `p > threshold >= v`.
    pub const FALLING: u8 = 2;
    /// Rising or falling.
    pub const EITHER: u8 = 3;
    /// A bit of the mask set in `v` and none in `p`.
    pub const BITS_SET: u8 = 4;
    /// No bit of the mask set in `v`, one in `p`.
    pub const BITS_CLEARED: u8 = 5;
}

/// Control commands (0x3300:01).
const STOP: u32 = 0;
const ARM: u32 = 1;
const TRIGGER_NOW: u32 = 2;

/// The recorder's state (0x3300:02).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u8)]
pub enum RecorderState {
    /// Not sampling (after start-up or a stop).
    #[default]
    Idle = 0,
    /// Armed: sampling into the preceding samples, waiting for the trigger.
    Waiting = 1,
    /// Triggered: recording the samples after the trigger.
    Recording = 2,
    /// The recording is complete: 0x3302 holds it.
    Complete = 3,
}

/// A channel as the drain runs it, one byte: the snapshot word (bits 0..3), or [`PLAN_OBJECT`] for a dictionary
/// object; the conversion; [`PLAN_WIDE`] for 4 bytes a sample.
const PLAN_WORD: u8 = 0x0F;
const PLAN_OBJECT: u8 = 0x10;
const PLAN_MILLI: u8 = 0x20;
const PLAN_HIGH_HALF: u8 = 0x40;
const PLAN_WIDE: u8 = 0x80;

/// The plan of the 0x3303 variable `sub` (module documentation), or `None`.
const fn tier1_variable(sub: u8) -> Option<u8> {
    Some(match sub {
        // Currents (mA, 16 bits): words 0..4, the q reference word 6.
        1..=5 => sub.wrapping_sub(1) | PLAN_MILLI,
        6 => ring::word::I_REF_Q | PLAN_MILLI,
        // Voltages (mV, 32 bits): words 7..9.
        7..=9 => sub | PLAN_MILLI | PLAN_WIDE,
        10 => ring::word::DUTY_AB,
        11 => ring::word::DUTY_AB | PLAN_HIGH_HALF,
        12 => ring::word::DUTY_C,
        13 => ring::word::POSITION | PLAN_WIDE,
        _ => return None,
    })
}

/// What a 0x3301 value `0xIIIISS00` names: the plan byte and, for an object, its entry; 0x0604_0041 when it cannot
/// be recorded (module documentation).
fn channel(value: u32) -> Result<(u8, Option<&'static Entry>), SdoAbort> {
    let [_, sub, index_lo, index_hi] = value.to_le_bytes();
    let index = u16::from_le_bytes([index_lo, index_hi]);
    if index == TIER1_VARIABLES {
        return tier1_variable(sub).map(|plan| (plan, None)).ok_or(SdoAbort::CannotBeMapped);
    }
    let entry = Table::GENERATED.find(index, sub).map_err(|_| SdoAbort::CannotBeMapped)?;
    let size = entry.data_type.fixed_size().unwrap_or(0);
    let integer = entry.data_type.is_integer() || entry.data_type == DataType::Boolean;
    let stored = !matches!(entry.storage, Storage::Application);
    if !(entry.access().readable() && entry.pdo().tx() && integer && stored && (1..=4).contains(&size)) {
        return Err(SdoAbort::CannotBeMapped);
    }
    Ok((if size > 2 { PLAN_OBJECT | PLAN_WIDE } else { PLAN_OBJECT }, Some(entry)))
}

/// The value of a RAM or constant entry (up to 4 bytes, sign-extended for signed types) from the value storage.
fn entry_value(entry: &Entry, values: &[u8]) -> i32 {
    let bytes = match entry.storage {
        Storage::Ram { offset, len, .. } => {
            let start = usize::from(offset);
            values.get(start..start.saturating_add(usize::from(len))).unwrap_or_default()
        }
        Storage::Const(bytes) => bytes.bytes(),
        Storage::Application => &[],
    };
    let mut word = [0u8; 4];
    let n = bytes.len().min(4);
    if let (Some(to), Some(from)) = (word.get_mut(..n), bytes.get(..n)) {
        to.copy_from_slice(from);
    }
    let raw = u32::from_le_bytes(word);
    // Sign extension of a narrower signed value: shift it to the top and back.
    let unused = 32u32.saturating_sub(8u32.saturating_mul(n as u32));
    if entry.data_type.is_signed() && unused > 0 && unused < 32 {
        (raw << unused).cast_signed() >> unused
    } else {
        raw.cast_signed()
    }
}

/// The value of one channel of snapshot `words` (`objects`: this drain's values of the object channels): currents
/// and voltages from `I16F16` bits to mA or mV rounded half up (one multiply and a shift: this runs for every
/// channel of every sample; a current's 16 bits saturate at +-32.767 A, beyond the drive's 0x3001:02 range).
#[inline(always)]
fn value_of(plan: u8, words: &[AtomicU32; SAMPLE_WORDS], object: i32) -> i32 {
    if plan & PLAN_OBJECT != 0 {
        return object;
    }
    let raw = words.get(usize::from(plan & PLAN_WORD)).map_or(0, |w| w.load(Ordering::Relaxed));
    if plan & PLAN_MILLI != 0 {
        let milli = (i64::from(raw.cast_signed()).wrapping_mul(1000).wrapping_add(1 << 15) >> 16) as i32;
        if plan & PLAN_WIDE == 0 {
            return milli.clamp(i32::from(i16::MIN), i32::from(i16::MAX));
        }
        return milli;
    }
    if plan & PLAN_HIGH_HALF != 0 {
        return (raw >> 16).cast_signed();
    }
    raw.cast_signed()
}

/// The configuration a master writes (0x3300:03..09, 0x3301), taken over by an arm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Config {
    /// 0x3301:01..08 as written.
    channels: [u32; MAX_CHANNELS],
    count: u8,
    period: u16,
    samples: u32,
    preceding: u32,
    mode: u8,
    trigger_channel: u8,
    threshold: i32,
    mask: u32,
}

/// The defaults of device.toml (0x3300:03 = 1, 0x3300:07 = 1, the rest 0).
const DEFAULT_CONFIG: Config = Config {
    channels: [0; MAX_CHANNELS],
    count: 0,
    period: 1,
    samples: 0,
    preceding: 0,
    mode: trigger::IMMEDIATE,
    trigger_channel: 1,
    threshold: 0,
    mask: 0,
};

/// The recorder (module documentation).
#[derive(Debug)]
pub struct Recorder {
    /// The sample memory: rows of half-words (a 32-bit value in two, low first), wrapping at `capacity`.
    buffer: &'static [AtomicU16],
    config: Config,
    state: RecorderState,
    /// The channels of the arm in force, as the drain runs them (the plan bytes), and the entries of those that
    /// are objects.
    plan: [u8; MAX_CHANNELS],
    objects: [Option<&'static Entry>; MAX_CHANNELS],
    /// The object channels' values of this slow period ([`Self::take_objects`]).
    object_values: [i32; MAX_CHANNELS],
    count: usize,
    /// Half-words of one sample, and of the stream (a whole number of samples).
    row_halves: u32,
    capacity: u32,
    /// Samples of a recording, and of them at most this many from before the trigger.
    length: u32,
    preceding: u32,
    /// Current-loop periods between samples, and the periods until the next sample.
    period: u32,
    countdown: u32,
    /// The trigger channel (0-based) and its value in the sample before (none right after arming).
    trigger_channel: usize,
    previous: Option<i32>,
    force: bool,
    /// Next half-word of the stream to write, samples written since arming.
    position: u32,
    written: u32,
    /// First half-word of the complete recording, and its samples (so far, while recording).
    start: u32,
    recorded: u32,
    /// The ring's next snapshot to read, unless `fresh` (just armed: the drain starts at the newest).
    next: u32,
    fresh: bool,
    /// Snapshots the ring had overwritten before the drain read them (since start-up).
    lost: u32,
}

impl Default for Recorder {
    fn default() -> Self {
        Self::new()
    }
}

impl Recorder {
    /// An idle recorder without a buffer (it refuses to arm until [`Self::attach`]).
    #[must_use]
    pub const fn new() -> Self {
        Self {
            buffer: &[],
            config: DEFAULT_CONFIG,
            state: RecorderState::Idle,
            plan: [0; MAX_CHANNELS],
            objects: [None; MAX_CHANNELS],
            object_values: [0; MAX_CHANNELS],
            count: 0,
            row_halves: 0,
            capacity: 0,
            length: 0,
            preceding: 0,
            period: 1,
            countdown: 1,
            trigger_channel: 0,
            previous: None,
            force: false,
            position: 0,
            written: 0,
            start: 0,
            recorded: 0,
            next: 0,
            fresh: true,
            lost: 0,
        }
    }

    /// Gives the recorder its sample memory (stops a recording in progress).
    pub fn attach(&mut self, buffer: &'static [AtomicU16]) {
        self.buffer = buffer;
        self.state = RecorderState::Idle;
    }

    /// Bytes of sample memory.
    #[must_use]
    pub fn buffer_bytes(&self) -> u32 {
        u32::try_from(self.buffer.len()).unwrap_or(u32::MAX / 2).saturating_mul(2)
    }

    /// The state (0x3300:02).
    #[must_use]
    pub const fn state(&self) -> RecorderState {
        self.state
    }

    /// Snapshots lost because tier 2 fell more than the ring behind (since start-up).
    #[must_use]
    pub const fn lost(&self) -> u32 {
        self.lost
    }

    /// Whether `index` is one of the recorder's objects.
    #[inline]
    #[must_use]
    pub const fn serves(index: u16) -> bool {
        matches!(index, RECORDER..=BUFFER)
    }

    /// The channels configured now (0x3301): their plans and entries, the half-words of a sample, and whether
    /// every one of them can be recorded.
    fn configured(&self) -> ([u8; MAX_CHANNELS], [Option<&'static Entry>; MAX_CHANNELS], u32, bool) {
        let count = usize::from(self.config.count).min(MAX_CHANNELS);
        let (mut plans, mut entries) = ([0u8; MAX_CHANNELS], [None; MAX_CHANNELS]);
        let mut halves = 0u32;
        let mut all_valid = count > 0;
        for ((plan, entry), value) in plans.iter_mut().zip(entries.iter_mut()).zip(&self.config.channels).take(count) {
            match channel(*value) {
                Ok((p, e)) => {
                    (*plan, *entry) = (p, e);
                    halves = halves.saturating_add(if p & PLAN_WIDE != 0 { 2 } else { 1 });
                }
                Err(_) => all_valid = false,
            }
        }
        (plans, entries, halves, all_valid)
    }

    /// Samples that fit for rows of `row_halves` half-words.
    fn capacity_rows(&self, row_halves: u32) -> u32 {
        u32::try_from(self.buffer.len()).unwrap_or(u32::MAX).checked_div(row_halves).unwrap_or(0)
    }

    /// 0x3300:01.
    fn command(&mut self, command: u32) -> Result<(), SdoAbort> {
        match command {
            STOP => {
                self.state = RecorderState::Idle;
                Ok(())
            }
            ARM => self.arm(),
            TRIGGER_NOW if self.state == RecorderState::Waiting => {
                self.force = true;
                Ok(())
            }
            TRIGGER_NOW => Err(SdoAbort::DeviceState),
            _ => Err(SdoAbort::InvalidValue),
        }
    }

    /// Arms with the configuration in force (0x0604_0043 when it cannot be recorded).
    fn arm(&mut self) -> Result<(), SdoAbort> {
        let (plans, entries, row_halves, all_valid) = self.configured();
        let rows = self.capacity_rows(row_halves);
        let c = self.config;
        let length = if c.samples == 0 { rows } else { c.samples };
        let count = usize::from(c.count);
        let trigger_channel = usize::from(c.trigger_channel);
        if !all_valid || length == 0 || length > rows || c.preceding >= length || trigger_channel > count {
            return Err(SdoAbort::ParameterIncompatibility);
        }
        self.plan = plans;
        self.objects = entries;
        self.count = count;
        self.row_halves = row_halves;
        self.capacity = rows.saturating_mul(row_halves);
        self.length = length;
        self.preceding = c.preceding;
        self.period = u32::from(c.period).max(1);
        self.countdown = 1;
        self.trigger_channel = trigger_channel.saturating_sub(1);
        self.previous = None;
        self.force = false;
        self.position = 0;
        self.written = 0;
        self.recorded = 0;
        self.fresh = true;
        self.state = RecorderState::Waiting;
        Ok(())
    }

    // -----------------------------------------------------------------------------------------------------
    // Sampling (tier 2, once per slow period)
    // -----------------------------------------------------------------------------------------------------

    /// Tier 2, once a slow period: the values of the object channels from the dictionary's value storage `values`
    /// (they change at 2.5 kHz at most, so every sample of the slow period takes them; a few loads, so that the
    /// drain itself needs no dictionary and can run in tier 3).
    pub fn take_objects(&mut self, values: &[u8]) {
        if !matches!(self.state, RecorderState::Waiting | RecorderState::Recording) {
            return;
        }
        for (value, entry) in self.object_values.iter_mut().zip(&self.objects).take(self.count) {
            if let Some(entry) = entry {
                *value = entry_value(entry, values);
            }
        }
    }

    /// Takes up to `limit` of the snapshots tier 1 pushed since the last call: while armed or recording, every
    /// `period`-th becomes a sample of the configured channels, and the trigger runs on it. Whether snapshots are
    /// left (the caller drains again, after letting others run: tier 3 keeps its sections short, see `rt::tier3`).
    #[inline(never)]
    pub fn drain(&mut self, ring: &SampleRing, limit: u32) -> bool {
        let written = ring.written();
        let sampling = matches!(self.state, RecorderState::Waiting | RecorderState::Recording);
        // Tier 1 copies only while the recorder samples (from its next period on).
        ring.set_enabled(sampling);
        if !sampling {
            self.next = written;
            return false;
        }
        // Just armed: from the next snapshot tier 1 copies on. Fallen behind the ring: from the oldest it holds.
        let mut next = if self.fresh { written } else { self.next };
        if written.wrapping_sub(next) > RING_REACH {
            self.lost = self.lost.wrapping_add(written.wrapping_sub(RING_REACH).wrapping_sub(next));
            next = written.wrapping_sub(RING_REACH);
        }
        self.fresh = false;
        let objects = self.object_values;
        let first = next;
        let end = if written.wrapping_sub(next) > limit { next.wrapping_add(limit) } else { written };
        while next != end && self.state != RecorderState::Complete {
            let Some(words) = ring.slot_at(next) else { break };
            next = next.wrapping_add(1);
            self.countdown = self.countdown.wrapping_sub(1);
            if self.countdown == 0 {
                self.countdown = self.period;
                self.sample(words, &objects);
            }
        }
        // A slot the writer reached while it was read: the samples from it on may mix two periods.
        if ring.overwritten(first) {
            self.lost = self.lost.wrapping_add(1);
        }
        self.next = next;
        next != written && self.state != RecorderState::Complete
    }

    /// Stores one sample of the snapshot `words` and runs the trigger.
    #[inline(always)]
    fn sample(&mut self, words: &[AtomicU32; SAMPLE_WORDS], objects: &[i32; MAX_CHANNELS]) {
        let at = self.position as usize;
        let Some(row) = self.buffer.get(at..at.saturating_add(self.row_halves as usize)) else { return };
        let mut halves = row.iter();
        for (plan, object) in self.plan.iter().zip(objects).take(self.count) {
            let value = value_of(*plan, words, *object).cast_unsigned();
            if let Some(h) = halves.next() {
                h.store(value as u16, Ordering::Relaxed);
            }
            if *plan & PLAN_WIDE != 0 {
                if let Some(h) = halves.next() {
                    h.store((value >> 16) as u16, Ordering::Relaxed);
                }
            }
        }
        let next = self.position.wrapping_add(self.row_halves);
        self.position = if next >= self.capacity { 0 } else { next };
        self.written = self.written.wrapping_add(1);
        let plan = self.plan.get(self.trigger_channel).copied().unwrap_or(0);
        let trigger_value = value_of(plan, words, objects.get(self.trigger_channel).copied().unwrap_or(0));
        if self.state == RecorderState::Waiting && self.triggered(trigger_value) {
            // The trigger's sample is the first after the preceding ones.
            self.recorded = self.preceding.min(self.written.wrapping_sub(1));
            self.state = RecorderState::Recording;
        }
        if self.state == RecorderState::Recording {
            self.recorded = self.recorded.wrapping_add(1);
            if self.recorded >= self.length {
                let halves = self.recorded.wrapping_mul(self.row_halves);
                let cap = self.capacity;
                self.start = self.position.wrapping_add(cap).wrapping_sub(halves).checked_rem(cap).unwrap_or(0);
                self.state = RecorderState::Complete;
            }
        }
        self.previous = Some(trigger_value);
    }

    /// Whether the trigger fires on `value` (0x3300:06..:09, or a trigger-now).
    fn triggered(&self, value: i32) -> bool {
        let c = &self.config;
        if self.force || c.mode == trigger::IMMEDIATE {
            return true;
        }
        let Some(p) = self.previous else { return false };
        let t = c.threshold;
        let rising = p < t && value >= t;
        let falling = p > t && value <= t;
        let now = value.cast_unsigned() & c.mask != 0;
        let before = p.cast_unsigned() & c.mask != 0;
        match c.mode {
            trigger::RISING => rising,
            trigger::FALLING => falling,
            trigger::EITHER => rising || falling,
            trigger::BITS_SET => now && !before,
            trigger::BITS_CLEARED => !now && before,
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests;
