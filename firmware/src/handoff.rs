//! Single-writer hand-offs between the timing tiers (`shared/design/ARCHITECTURE.md`, "Data flow and timing
//! tiers"): plain atomic words, no lock, no masked section, no `unsafe`, and host-testable.
//!
//! On one core a higher-priority context runs to completion whenever it preempts a lower one. The two directions
//! therefore need two shapes:
//!
//! - [`Command`]: the writer has the *lower* priority (tier 2 publishing set-points to tier 1), the reader the
//!   higher one and must never wait. A double buffer indexed by the publication count: the writer fills the slot
//!   the reader is not using and then publishes the count; the reader takes the slot of the count it loads. A
//!   writer preempted half-way has not published yet, so the reader sees the previous block whole. The count is
//!   the block's epoch: the reader applies a block once by comparing epochs.
//! - [`Report`]: the writer has the *higher* priority (tier 1 publishing measurements to tier 2) and may preempt
//!   the reader in the middle of its copy. A sequence lock: the count is odd while a write is under way and moves
//!   on with every write; the reader copies, and keeps the copy only if the count was even and unchanged around
//!   it. Its retries are bounded ([`Report::read`] returns [`Torn`] after [`Report::ATTEMPTS`]); the writer never
//!   waits.
//!
//! A block is any `Copy` value that converts to and from `N` words ([`Words`]). Each word is one 32-bit atomic
//! access (one `LDR`/`STR` on the Cortex-M4), so neither side ever sees half a word.

use core::marker::PhantomData;
use core::sync::atomic::{fence, AtomicU32, Ordering};

/// A block carried by a hand-off as `N` 32-bit words.
///
/// The all-zero words must decode to the safe block: before the first publication a [`Command`] reads as zeros
/// (for a command block: the power stage forced off, no demand).
pub trait Words<const N: usize>: Copy {
    /// The block as words.
    fn to_words(&self) -> [u32; N];
    /// The block from words written by [`Words::to_words`] (or all zeros).
    fn from_words(words: &[u32; N]) -> Self;
}

/// A block and the count of the publication it came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stamped<B> {
    /// Publications before and including this one (0: nothing published yet). Wraps after 2^32 publications
    /// (a [`Command`]) or 2^31 ([`Report`]): compare for equality, not order.
    pub epoch: u32,
    /// The block.
    pub block: B,
}

/// Tier 2 -> tier 1: a double buffer whose reader never waits (module documentation).
#[derive(Debug)]
pub struct Command<B, const N: usize> {
    slots: [[AtomicU32; N]; 2],
    /// The publication count; the front slot is `epoch & 1`.
    epoch: AtomicU32,
    block: PhantomData<B>,
}

impl<B: Words<N>, const N: usize> Default for Command<B, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<B: Words<N>, const N: usize> Command<B, N> {
    /// Nothing published: reads as the all-zero block (the safe one, see [`Words`]) with epoch 0.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            slots: [[const { AtomicU32::new(0) }; N], [const { AtomicU32::new(0) }; N]],
            epoch: AtomicU32::new(0),
            block: PhantomData,
        }
    }

    /// Publishes `block` (the writer: one context, of lower priority than the reader). Returns its epoch.
    pub fn publish(&self, block: &B) -> u32 {
        self.publish_observed(block, || {})
    }

    /// [`Self::publish`], calling `after_store` after each word is stored (the tests read at every such point).
    #[inline(always)]
    fn publish_observed(&self, block: &B, mut after_store: impl FnMut()) -> u32 {
        // Only this writer changes the epoch: a relaxed load reads its own last store.
        let next = self.epoch.load(Ordering::Relaxed).wrapping_add(1);
        let back = slot_of(&self.slots, next);
        for (cell, word) in back.iter().zip(block.to_words()) {
            cell.store(word, Ordering::Relaxed);
            after_store();
        }
        // The words are in place before the epoch that points at them.
        self.epoch.store(next, Ordering::Release);
        next
    }

    /// The last published block and its epoch (the reader: one context, of higher priority than the writer).
    /// Never waits.
    #[must_use]
    pub fn read(&self) -> Stamped<B> {
        let words = self.read_words();
        Stamped { epoch: words.epoch, block: B::from_words(&words.block) }
    }

    /// [`Self::read`] without the decoding: for a reader that takes some words as they are and decodes the rest
    /// only when they changed.
    #[must_use]
    pub fn read_words(&self) -> Stamped<[u32; N]> {
        let front = self.front();
        let mut words = [0u32; N];
        for (word, cell) in words.iter_mut().zip(front.block) {
            *word = cell.load(Ordering::Relaxed);
        }
        Stamped { epoch: front.epoch, block: words }
    }

    /// The cells of the last published block and its epoch, for a reader that loads the words itself: tier 1 loads
    /// the word that says when the block applies first and the others only when it does, written out rather than
    /// in a loop (`rt::app::fast_tick`). The cells hold that block while the reader runs (the writer, of lower
    /// priority, fills the other slot).
    #[must_use]
    pub fn front(&self) -> Stamped<&[AtomicU32; N]> {
        let epoch = self.epoch.load(Ordering::Acquire);
        Stamped { epoch, block: slot_of(&self.slots, epoch) }
    }

    /// The epoch of the last publication, without the block (for a reader that only checks for news).
    #[must_use]
    pub fn epoch(&self) -> u32 {
        self.epoch.load(Ordering::Acquire)
    }

    /// The cells of publication `epoch`, an epoch [`Self::epoch`] returned to this reader: what [`Self::front`]
    /// gives without loading the epoch (and its barrier) a second time. They hold that block while the reader
    /// runs (the writer, of lower priority, fills the other slot).
    #[must_use]
    pub fn block_of(&self, epoch: u32) -> &[AtomicU32; N] {
        slot_of(&self.slots, epoch)
    }
}

/// The slot of publication `epoch`: even epochs in slot 0, odd ones in slot 1.
fn slot_of<const N: usize>(slots: &[[AtomicU32; N]; 2], epoch: u32) -> &[AtomicU32; N] {
    if epoch & 1 == 0 {
        &slots[0]
    } else {
        &slots[1]
    }
}

/// A [`Report::read`] that found the writer at work on every attempt: the reader keeps its previous block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Torn;

/// Tier 1 -> tier 2: a sequence lock whose writer never waits (module documentation).
#[derive(Debug)]
pub struct Report<B, const N: usize> {
    words: [AtomicU32; N],
    /// Twice the publication count, plus one while a publication is being written.
    sequence: AtomicU32,
    block: PhantomData<B>,
}

impl<B: Words<N>, const N: usize> Default for Report<B, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<B: Words<N>, const N: usize> Report<B, N> {
    /// Copies a reader tries before it gives up with [`Torn`]. The writer publishes once per slow tick (every tenth
    /// period) and a copy takes a few dozen instructions, so a second attempt already succeeds unless the reader
    /// was held off for a whole slow tick in the middle of its copy.
    pub const ATTEMPTS: u32 = 3;

    /// Nothing published: reads as the all-zero block with epoch 0.
    #[must_use]
    pub const fn new() -> Self {
        Self { words: [const { AtomicU32::new(0) }; N], sequence: AtomicU32::new(0), block: PhantomData }
    }

    /// Publishes `block` (the writer: one context, of higher priority than the reader). Never waits. Returns its
    /// epoch.
    pub fn publish(&self, block: &B) -> u32 {
        // Only this writer changes the sequence: a relaxed load reads its own last store.
        let sequence = self.sequence.load(Ordering::Relaxed);
        self.sequence.store(sequence.wrapping_add(1), Ordering::Relaxed);
        // The odd sequence is visible before any word changes.
        fence(Ordering::Release);
        for (cell, word) in self.words.iter().zip(block.to_words()) {
            cell.store(word, Ordering::Relaxed);
        }
        let done = sequence.wrapping_add(2);
        self.sequence.store(done, Ordering::Release);
        done / 2
    }

    /// The last published block and its epoch, or [`Torn`] when every attempt overlapped a publication.
    pub fn read(&self) -> Result<Stamped<B>, Torn> {
        self.read_observed(|| {})
    }

    /// [`Self::read`], calling `after_load` after each word is loaded (the tests publish at every such point).
    #[inline(always)]
    fn read_observed(&self, mut after_load: impl FnMut()) -> Result<Stamped<B>, Torn> {
        for _ in 0..Self::ATTEMPTS {
            let before = self.sequence.load(Ordering::Acquire);
            if before & 1 == 1 {
                continue;
            }
            let mut words = [0u32; N];
            for (word, cell) in words.iter_mut().zip(&self.words) {
                *word = cell.load(Ordering::Relaxed);
                after_load();
            }
            // The words are read before the sequence is checked again.
            fence(Ordering::Acquire);
            if self.sequence.load(Ordering::Relaxed) == before {
                return Ok(Stamped { epoch: before / 2, block: B::from_words(&words) });
            }
        }
        Err(Torn)
    }
}

#[cfg(test)]
mod tests {
    use core::cell::Cell;

    use super::*;

    /// A block whose words all carry the same value: a torn read shows as words that differ.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    struct Uniform([u32; 4]);

    impl Uniform {
        fn of(v: u32) -> Self {
            Self([v; 4])
        }

        fn whole(&self) -> bool {
            self.0.iter().all(|&w| w == self.0[0])
        }
    }

    impl Words<4> for Uniform {
        fn to_words(&self) -> [u32; 4] {
            self.0
        }

        fn from_words(words: &[u32; 4]) -> Self {
            Self(*words)
        }
    }

    #[test]
    fn a_command_reads_as_the_zero_block_with_epoch_0_before_the_first_publication() {
        let command: Command<Uniform, 4> = Command::new();
        assert_eq!(command.read(), Stamped { epoch: 0, block: Uniform::of(0) });
    }

    #[test]
    fn each_publication_moves_the_commands_epoch_on_by_one_and_reads_back_whole() {
        let command: Command<Uniform, 4> = Command::new();
        for v in 1..=5 {
            assert_eq!(command.publish(&Uniform::of(v * 10)), v);
            assert_eq!(command.read(), Stamped { epoch: v, block: Uniform::of(v * 10) });
            assert_eq!(command.epoch(), v);
        }
    }

    /// The reader (tier 1) preempts the writer (tier 2) after every word it stores, over several publications:
    /// every read is a whole block, the previous publication's until the new one is published, never a mix.
    #[test]
    fn a_reader_preempting_the_writer_at_any_word_sees_the_previous_block_whole() {
        let command: Command<Uniform, 4> = Command::new();
        command.publish(&Uniform::of(1));
        for v in 2..6 {
            let reads = Cell::new(0);
            let epoch = command.publish_observed(&Uniform::of(v), || {
                let seen = command.read();
                assert!(seen.block.whole(), "torn read {seen:?}");
                assert_eq!(seen, Stamped { epoch: v - 1, block: Uniform::of(v - 1) });
                reads.set(reads.get() + 1);
            });
            assert_eq!(reads.get(), 4, "one read after each of the four words");
            assert_eq!(command.read(), Stamped { epoch, block: Uniform::of(v) });
        }
    }

    #[test]
    fn a_report_reads_as_the_zero_block_with_epoch_0_before_the_first_publication() {
        let report: Report<Uniform, 4> = Report::new();
        assert_eq!(report.read(), Ok(Stamped { epoch: 0, block: Uniform::of(0) }));
    }

    #[test]
    fn each_publication_moves_the_reports_epoch_on_by_one_and_reads_back_whole() {
        let report: Report<Uniform, 4> = Report::new();
        for v in 1..=5 {
            assert_eq!(report.publish(&Uniform::of(v)), v);
            assert_eq!(report.read(), Ok(Stamped { epoch: v, block: Uniform::of(v) }));
        }
    }

    /// The writer (tier 1) preempts the reader (tier 2) after the reader's k-th word, once: the reader's first copy
    /// is discarded and its second returns the new block whole, whatever k.
    #[test]
    fn a_writer_preempting_the_reader_at_any_word_makes_it_copy_again_and_return_the_new_block() {
        for k in 1..=4 {
            let report: Report<Uniform, 4> = Report::new();
            report.publish(&Uniform::of(7));
            let loads = Cell::new(0);
            let seen = report.read_observed(|| {
                loads.set(loads.get() + 1);
                if loads.get() == k {
                    report.publish(&Uniform::of(8));
                }
            });
            assert_eq!(seen, Ok(Stamped { epoch: 2, block: Uniform::of(8) }), "preempted after word {k}");
            assert_eq!(loads.get(), 8, "two whole copies");
        }
    }

    /// A writer that preempts every copy (the reader held off for more than a slow tick in each): after
    /// `ATTEMPTS` copies the reader gives up with `Torn` instead of returning a mixed block or waiting longer.
    #[test]
    fn a_reader_overlapped_on_every_attempt_gives_up_with_torn_after_the_bounded_attempts() {
        let report: Report<Uniform, 4> = Report::new();
        let next = Cell::new(1);
        let loads = Cell::new(0u32);
        let seen = report.read_observed(|| {
            loads.set(loads.get() + 1);
            report.publish(&Uniform::of(next.get()));
            next.set(next.get() + 1);
        });
        assert_eq!(seen, Err(Torn));
        assert_eq!(loads.get(), 4 * Report::<Uniform, 4>::ATTEMPTS);
    }

    /// A read that finds a write under way (odd sequence: possible only if the contract is broken, e.g. a reader
    /// of higher priority) does not copy at all and reports `Torn`.
    #[test]
    fn a_read_during_an_unfinished_write_reports_torn() {
        let report: Report<Uniform, 4> = Report::new();
        report.sequence.store(1, Ordering::Relaxed);
        assert_eq!(report.read(), Err(Torn));
    }
}
