//! The runtime's measured figures (largest costs, counters). Each static has one writer (the writer table in
//! `rt/mod.rs`), so a load and a store suffice where a read-modify-write would cost an exclusive-access loop in
//! tier 1.

use core::sync::atomic::{AtomicU32, Ordering};

/// Raises `max` to `value` if `value` is larger (single writer).
#[inline(always)]
pub(crate) fn record_max(max: &AtomicU32, value: u32) {
    if value > max.load(Ordering::Relaxed) {
        max.store(value, Ordering::Relaxed);
    }
}

/// Adds `n` to `counter`, wrapping (single writer).
#[inline(always)]
pub(crate) fn count(counter: &AtomicU32, n: u32) {
    counter.store(counter.load(Ordering::Relaxed).wrapping_add(n), Ordering::Relaxed);
}
