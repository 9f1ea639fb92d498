//! The rule for feeding the independent watchdog (issue 19 item 3): only when all three tiers have run since the
//! last feed, so that a tier that stops (an interrupt storm starving tier 2, a tier-3 task that never yields, tier
//! 1 no longer triggered) lets the watchdog reset the device. IDX 7.2.48 (L7490): 0xFF02 "cyclic monitoring has
//! detected an invalid device status"; the drive reports it at the next start (`Drive::report_reset`).
//!
//! Tier 3 asks, from its supervisor (so tier 3 ran), with the counts tier 1 and tier 2 keep of their own periods
//! (`rt::tier1::FAST_TICKS`, `rt::tier2::SLOW_TICKS`): each must have moved on since the last feed. The counters
//! already exist for the runtime's figures, so tier 1 pays nothing for the watchdog.

/// What the last feed saw of tiers 1 and 2.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TierLiveness {
    fast_ticks: u32,
    slow_ticks: u32,
}

impl TierLiveness {
    /// Starts from the counts as they are now: the first feed waits for both tiers to run once more.
    #[must_use]
    pub const fn new(fast_ticks: u32, slow_ticks: u32) -> Self {
        Self { fast_ticks, slow_ticks }
    }

    /// Whether to feed the watchdog now, the caller being tier 3: tier 1's period count and tier 2's slow-tick
    /// count have both moved on since the last feed (compared for equality: the counters wrap). Remembers them
    /// when it says yes; a no keeps the old counts, so a tier that ran once long ago does not count again.
    pub fn all_tiers_ran(&mut self, fast_ticks: u32, slow_ticks: u32) -> bool {
        let ran = fast_ticks != self.fast_ticks && slow_ticks != self.slow_ticks;
        if ran {
            *self = Self::new(fast_ticks, slow_ticks);
        }
        ran
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feeds_only_when_both_counters_moved_on() {
        let mut l = TierLiveness::new(100, 10);
        assert!(!l.all_tiers_ran(100, 10), "nothing ran");
        assert!(!l.all_tiers_ran(110, 10), "tier 2 stalled");
        assert!(!l.all_tiers_ran(100, 11), "tier 1 stalled");
        assert!(l.all_tiers_ran(110, 11));
        assert!(!l.all_tiers_ran(110, 11), "the same counts do not feed twice");
        assert!(l.all_tiers_ran(120, 12));
    }

    #[test]
    fn a_stalled_tier_never_feeds_even_when_the_other_runs_on() {
        let mut l = TierLiveness::new(0, 0);
        for fast in 1..1_000u32 {
            assert!(!l.all_tiers_ran(fast, 0), "tier 2 has not run since the start");
        }
        assert!(l.all_tiers_ran(1_000, 1));
    }

    #[test]
    fn the_counters_may_wrap() {
        let mut l = TierLiveness::new(u32::MAX, u32::MAX);
        assert!(l.all_tiers_ran(0, 0));
    }
}
