//! A tick signal from a higher-priority tier to the one task of a lower tier that waits for it, without locks.
//!
//! Single producer (an interrupt handler), single consumer (one embassy task, for the whole run). The consumer
//! stores its waker once, before it publishes it (`registered`, release); the producer reads the waker only after
//! seeing it published (acquire), and the waker is never written again. Embassy task wakers stay valid for the
//! task's lifetime, so the producer's wake is a few loads and stores: no critical section, no allocation.

use core::cell::UnsafeCell;
use core::future::{poll_fn, Future};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use core::task::{Poll, Waker};

/// Counts ticks raised by the producer and wakes the consumer.
pub struct TickSignal {
    raised: AtomicU32,
    registered: AtomicBool,
    waker: UnsafeCell<Option<Waker>>,
}

// SAFETY: `waker` is written once by the single consumer before `registered` is set (release) and only read after
// `registered` is seen set (acquire); `raised` is atomic. See the module docs for the single-producer,
// single-consumer contract.
unsafe impl Sync for TickSignal {}

impl Default for TickSignal {
    fn default() -> Self {
        Self::new()
    }
}

impl TickSignal {
    /// No ticks, no waiter.
    pub const fn new() -> Self {
        Self { raised: AtomicU32::new(0), registered: AtomicBool::new(false), waker: UnsafeCell::new(None) }
    }

    /// Producer: one more tick; wakes the consumer if it is registered. Call from one context only.
    #[inline(always)]
    pub fn raise(&self) {
        // Single producer: a load and a store instead of a read-modify-write loop.
        self.raised.store(self.raised.load(Ordering::Relaxed).wrapping_add(1), Ordering::Release);
        if self.registered.load(Ordering::Acquire) {
            // SAFETY: published and never written again (see the `Sync` impl).
            if let Some(waker) = unsafe { &*self.waker.get() } {
                waker.wake_by_ref();
            }
        }
    }

    /// Ticks raised so far (wrapping).
    pub fn raised(&self) -> u32 {
        self.raised.load(Ordering::Acquire)
    }

    /// Consumer: waits until a tick newer than `*seen` was raised; returns how many were raised since (more than 1
    /// means the consumer fell behind) and advances `*seen`. Only one task may ever call this on a signal.
    pub fn wait<'a>(&'a self, seen: &'a mut u32) -> impl Future<Output = u32> + 'a {
        poll_fn(move |cx| {
            self.register(cx.waker());
            let now = self.raised.load(Ordering::Acquire);
            let new = now.wrapping_sub(*seen);
            if new == 0 {
                Poll::Pending
            } else {
                *seen = now;
                Poll::Ready(new)
            }
        })
    }

    fn register(&self, waker: &Waker) {
        if !self.registered.load(Ordering::Acquire) {
            // SAFETY: only the single consumer gets here, and only before `registered` is set; the producer does not
            // read the slot until then.
            unsafe { *self.waker.get() = Some(waker.clone()) };
            self.registered.store(true, Ordering::Release);
        }
    }
}
