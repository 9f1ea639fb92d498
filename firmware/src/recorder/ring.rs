//! Tier 1's part of the data recorder: a fixed copy of the values tier 1 has already computed and published in its
//! state (`FastSignals`, the PWM command, the encoder position) every period, into a small ring that tier 2 drains.
//!
//! The copy is the same thirteen words whatever the recorder records: no channel list, no branch on the
//! configuration, no conversion, so its cost in tier 1 is small and fixed; while the recorder does not sample,
//! tier 1 skips it after one load ([`SampleRing::enabled`], set by the drain). Tier 2 picks the
//! channels, converts the units and triggers ([`super::Recorder::drain`], in tier 3).
//!
//! One writer (tier 1, [`SampleRing::push`]), one reader (tier 3, [`SampleRing::slot_at`]): the writer fills a
//! slot, then moves the count on (release); the reader takes the count (acquire), copies the slots before it and
//! asks [`SampleRing::overwritten`] afterwards whether the writer came round to the oldest meanwhile. The ring holds
//! [`RING_SLOTS`] periods, so the drain (tier 3) loses samples only when it is held off that long (it then knows,
//! and counts them).

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use crate::drive::tier1::Tier1State;
use crate::hal::power::PwmCommand;

/// Words of one snapshot: thirteen used, the slot padded to a power of two so that tier 1 finds it with one shift.
pub const SAMPLE_WORDS: usize = 16;
/// Words of a snapshot tier 1 writes (the rest of the slot is padding).
pub const SNAPSHOT_WORDS: usize = 13;
/// Slots of the ring: a power of two (the slot is the count's low bits): 5.1 ms, 12.8 slow periods for tier 3 to
/// drain it in (8 KiB of RAM).
pub const RING_SLOTS: usize = 128;
/// Snapshots a reader may lag behind the writer and still read one (the writer starts on the oldest slot again
/// once it is [`RING_SLOTS`] behind).
pub const RING_REACH: u32 = RING_SLOTS as u32 - 1;

/// The words of a snapshot: words 0..9 in the order `FastSignals` holds them (phase currents A, B, C, d and q
/// current, d and q reference, d and q voltage, bus voltage: `I16F16` bits), so that tier 1 loads them in runs;
/// then the duties of phases A and B (A in the low half), C, and the encoder position.
pub mod word {
    /// Phase current A (`Amps` bits); B and C follow, then the d and q currents.
    pub const I_A: u8 = 0;
    /// Measured q current (`Amps` bits).
    pub const I_Q: u8 = 4;
    /// The q current reference (`Amps` bits).
    pub const I_REF_Q: u8 = 6;
    /// Applied d voltage (`Volts` bits); q follows.
    pub const V_D: u8 = 7;
    /// Bus voltage (`Volts` bits).
    pub const V_BUS: u8 = 9;
    /// Duties of phases A (low half) and B (high half), compare ticks.
    pub const DUTY_AB: u8 = 10;
    /// Duty of phase C, compare ticks.
    pub const DUTY_C: u8 = 11;
    /// Tier 1's encoder position (increments).
    pub const POSITION: u8 = 12;
}

/// A snapshot of tier 1's variables after one period (the words of [`word`]).
pub type Tier1Sample = [u32; SAMPLE_WORDS];

/// The ring (module documentation).
#[derive(Debug)]
pub struct SampleRing {
    slots: [[AtomicU32; SAMPLE_WORDS]; RING_SLOTS],
    /// Snapshots pushed so far (wrapping). Writer: tier 1.
    written: AtomicU32,
    /// Whether tier 1 copies at all: set while the recorder samples, so that tier 1 pays one load and a branch
    /// otherwise. Writer: tier 2 (the drain, [`Self::set_enabled`]).
    enabled: AtomicBool,
}

impl SampleRing {
    /// An empty ring.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            slots: [const { [const { AtomicU32::new(0) }; SAMPLE_WORDS] }; RING_SLOTS],
            written: AtomicU32::new(0),
            enabled: AtomicBool::new(false),
        }
    }

    /// Tier 1, every period after the command is decided: copies `t1`'s published values and `pwm` into the next
    /// slot. A fixed sequence of loads and stores (thirteen stores and the count), never a branch on what is recorded.
    /// The target's tier 1 stores the same words with `rt::tier1`'s block copy ([`Self::writer_slot`],
    /// [`Self::commit`]); this one stores them word by word (host tests and tools).
    #[inline(always)]
    pub fn push(&self, t1: &Tier1State, pwm: &PwmCommand) {
        let (n, slot) = self.writer_slot();
        if let Some(slot) = slot {
            for (to, from) in slot.iter().zip(sample_words(t1, pwm)) {
                to.store(from, Ordering::Relaxed);
            }
        }
        self.commit(n);
    }

    /// The writer's next snapshot number and its slot (tier 1 alone: it is the only writer of the count).
    #[inline(always)]
    #[must_use]
    pub fn writer_slot(&self) -> (u32, Option<&[AtomicU32; SAMPLE_WORDS]>) {
        let n = self.written.load(Ordering::Relaxed);
        // The mask keeps the index within the array: the bounds check folds away (never `None`).
        (n, self.slots.get(n as usize & (RING_SLOTS - 1)))
    }

    /// The writer has filled the slot of snapshot `n`: readers may take it.
    #[inline(always)]
    pub fn commit(&self, n: u32) {
        // Release: the slot's words before the count that makes them readable.
        self.written.store(n.wrapping_add(1), Ordering::Release);
    }

    /// Stores a snapshot given word by word (tests and tools; tier 1 uses [`Self::push`]).
    pub fn push_sample(&self, sample: &Tier1Sample) {
        let n = self.written.load(Ordering::Relaxed);
        if let Some(slot) = self.slot_at(n) {
            for (to, from) in slot.iter().zip(sample) {
                to.store(*from, Ordering::Relaxed);
            }
        }
        self.written.store(n.wrapping_add(1), Ordering::Release);
    }

    /// Whether tier 1 copies ([`Self::push`] only when it does; tier 1 asks first).
    #[inline(always)]
    #[must_use]
    pub fn enabled(&self) -> bool {
        self.enabled.load(Ordering::Relaxed)
    }

    /// The drain: whether tier 1 copies from its next period on.
    pub fn set_enabled(&self, enabled: bool) {
        self.enabled.store(enabled, Ordering::Relaxed);
    }

    /// Snapshots pushed so far (wrapping).
    #[must_use]
    pub fn written(&self) -> u32 {
        self.written.load(Ordering::Acquire)
    }

    /// The slot of snapshot `n`, without a check: for a reader that checked the range of its snapshots against
    /// one [`Self::written`] and asks [`Self::overwritten`] afterwards.
    #[inline(always)]
    #[must_use]
    pub fn slot_at(&self, n: u32) -> Option<&[AtomicU32; SAMPLE_WORDS]> {
        self.slots.get(n as usize & (RING_SLOTS - 1))
    }

    /// Whether the writer has started on the slot of snapshot `n` again (its next write begins once `written` =
    /// `n` + [`RING_SLOTS`]).
    #[must_use]
    pub fn overwritten(&self, n: u32) -> bool {
        self.written().wrapping_sub(n) >= RING_SLOTS as u32
    }

    /// A copy of snapshot `n`, or `None` when it is not written yet or was overwritten (tests and diagnostics).
    #[must_use]
    pub fn read(&self, n: u32) -> Option<Tier1Sample> {
        if self.written().wrapping_sub(n).wrapping_sub(1) >= RING_REACH {
            return None;
        }
        let slot = self.slot_at(n)?;
        let sample = core::array::from_fn(|w| slot.get(w).map_or(0, |x| x.load(Ordering::Relaxed)));
        (!self.overwritten(n)).then_some(sample)
    }
}

/// The words of one snapshot ([`word`]) from `t1`'s published values and `pwm`: the signals in the order
/// `FastSignals` holds them (so that they load in runs), the duties, the encoder position.
#[inline(always)]
#[must_use]
pub fn sample_words(t1: &Tier1State, pwm: &PwmCommand) -> [u32; SNAPSHOT_WORDS] {
    let s = t1.signals();
    let [duty_a, duty_b, duty_c] = pwm.duty;
    let bits = |x: i32| x.cast_unsigned();
    [
        bits(s.i_abc.a.to_bits()),
        bits(s.i_abc.b.to_bits()),
        bits(s.i_abc.c.to_bits()),
        bits(s.i_dq.d.to_bits()),
        bits(s.i_dq.q.to_bits()),
        bits(s.i_ref.d.to_bits()),
        bits(s.i_ref.q.to_bits()),
        bits(s.v_dq.d.to_bits()),
        bits(s.v_dq.q.to_bits()),
        bits(s.v_bus.to_bits()),
        u32::from(duty_a) | (u32::from(duty_b) << 16),
        u32::from(duty_c),
        bits(t1.commutation().encoder().position()),
    ]
}

impl Default for SampleRing {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::DriveConfig;

    /// The ring keeps the last [`RING_REACH`] snapshots readable in order; older ones read as overwritten, newer
    /// ones as not yet written.
    #[test]
    fn snapshots_read_back_in_order_until_the_writer_comes_round() {
        let drive = crate::drive::Drive::new(DriveConfig::DEFAULT);
        let t1 = Tier1State::new(drive.settings());
        let ring = SampleRing::new();
        assert!(!ring.enabled(), "no copy before the recorder enables it");
        ring.set_enabled(true);
        assert_eq!(ring.read(0), None, "nothing written yet");
        for k in 0..40u16 {
            ring.push(&t1, &PwmCommand { duty: [k, k + 1000, k + 2000], enabled: true });
        }
        assert_eq!(ring.written(), 40);
        for k in 0..40u32 {
            let s = ring.read(k).expect("within reach");
            assert_eq!(s[word::DUTY_AB as usize], k | ((k + 1000) << 16), "snapshot {k}");
            assert_eq!(s[word::DUTY_C as usize], k + 2000, "snapshot {k}");
        }
        assert_eq!(ring.read(40), None, "not yet written");
        for k in 40..200u16 {
            ring.push(&t1, &PwmCommand { duty: [k, k + 1000, k + 2000], enabled: true });
        }
        assert_eq!(ring.read(200 - RING_REACH - 1), None, "overwritten once the writer came round");
        assert!(ring.read(200 - RING_REACH).is_some(), "the oldest within reach");
    }
}
