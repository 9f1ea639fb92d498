//! The SYNC consumer (CiA 301 §7.2.5): the COB-ID 0x1005, the counter with its overflow value 0x1019, and the
//! SYNC period supervision from 0x1006.
//!
//! **Length.** With 0x1019 = 0 a SYNC carries no data; with 0x1019 = 2..=240 it carries one counter byte (CiA 301
//! §7.2.5.2). A SYNC of another length is not processed and reported as [`LinkLoss::CanSyncLength`] (EMCY 0x8240
//! "unexpected SYNC data length"), once until a SYNC of the right length arrives.
//!
//! **Supervision.** With 0x1006 (us) not 0 and after the first SYNC, a gap of more than 1.5 periods (the margin
//! CANopenNode's SYNC timeout uses: a SYNC may jitter by half a period) is a lost SYNC: reported once as
//! [`LinkLoss::RxPdoTimeout`] (the drive's "RxPDO/SYNC timeout" 0x8250, reaction per 0x6007), restored by the next
//! SYNC. The SYNCs missed are counted ([`SyncConsumer::missed`]): at the next SYNC, the periods the gap spans
//! minus one, rounded to the nearest period.

use super::ids;
use crate::od::access::Dictionary;
use crate::supervision::communication::LinkLoss;

/// What a SYNC frame did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SyncEvent {
    /// A SYNC, with its counter when 0x1019 > 0; `restored` when it ended a reported loss.
    Sync {
        /// The counter byte.
        counter: Option<u8>,
        /// The SYNC supervision had reported a loss, which this SYNC ends.
        restored: bool,
    },
    /// A SYNC of the wrong length: not processed; `report` the first of a run (to be sent as EMCY 0x8240).
    BadLength {
        /// The loss to report (the first bad SYNC after a good one), else `None`.
        report: Option<LinkLoss>,
    },
}

/// The SYNC consumer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SyncConsumer {
    cob_id: u16,
    overflow: u8,
    period_us: u64,
    last_us: Option<u64>,
    lost: bool,
    bad_length: bool,
    received: u32,
    missed: u32,
}

impl SyncConsumer {
    /// Reads 0x1005, 0x1006 and 0x1019; restarts the supervision.
    pub fn configure<const N: usize>(&mut self, d: &Dictionary<N>) {
        *self = Self {
            cob_id: u16::try_from(ids::read_u32(d, 0x1005, 0) & 0x7FF).unwrap_or(ids::SYNC),
            overflow: ids::read(d, 0x1019, 0).and_then(|v| u8::try_from(v).ok()).unwrap_or(0),
            period_us: u64::from(ids::read_u32(d, 0x1006, 0)),
            received: self.received,
            missed: self.missed,
            ..Self::default()
        };
    }

    /// The SYNC COB-ID.
    pub const fn cob_id(&self) -> u16 {
        self.cob_id
    }

    /// SYNCs received (of the right length).
    pub const fn received(&self) -> u32 {
        self.received
    }

    /// SYNCs missed (see the module documentation).
    pub const fn missed(&self) -> u32 {
        self.missed
    }

    /// Forgets the last SYNC (leaving pre-operational/operational: supervision starts again at the next SYNC).
    pub fn disarm(&mut self) {
        self.last_us = None;
    }

    /// A frame on the SYNC COB-ID.
    #[inline]
    pub fn on_frame(&mut self, data: &[u8], now_us: u64) -> SyncEvent {
        let counter = match (self.overflow, data) {
            (0, []) => None,
            (2.., [c]) => Some(*c),
            _ => {
                let report = (!self.bad_length)
                    .then(|| LinkLoss::CanSyncLength { received: u8::try_from(data.len()).unwrap_or(u8::MAX) });
                self.bad_length = true;
                return SyncEvent::BadLength { report };
            }
        };
        self.bad_length = false;
        if let (Some(last), true) = (self.last_us, self.period_us > 0) {
            let gap = now_us.saturating_sub(last);
            let periods = gap.saturating_add(self.period_us / 2).checked_div(self.period_us).unwrap_or(1);
            self.missed = self.missed.saturating_add(u32::try_from(periods.saturating_sub(1)).unwrap_or(u32::MAX));
        }
        self.last_us = Some(now_us);
        self.received = self.received.wrapping_add(1);
        SyncEvent::Sync { counter, restored: core::mem::take(&mut self.lost) }
    }

    /// Tier 3: the supervision; `Some` once when the SYNC stopped.
    pub fn poll(&mut self, now_us: u64) -> Option<LinkLoss> {
        let last = self.last_us?;
        if self.period_us == 0 || self.lost {
            return None;
        }
        let limit = self.period_us.saturating_add(self.period_us / 2);
        if now_us.saturating_sub(last) > limit {
            self.lost = true;
            return Some(LinkLoss::RxPdoTimeout);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn length_counter_and_supervision() {
        let mut d = Dictionary::new(1);
        ids::write(&mut d, 0x1006, 0, 1000);
        let mut s = SyncConsumer::default();
        s.configure(&d);
        assert_eq!(s.poll(10_000), None, "not armed before the first SYNC");
        assert_eq!(s.on_frame(&[], 0), SyncEvent::Sync { counter: None, restored: false });
        assert!(matches!(s.on_frame(&[1], 100), SyncEvent::BadLength { report: Some(_) }));
        assert!(matches!(s.on_frame(&[1], 200), SyncEvent::BadLength { report: None }));
        assert_eq!(s.poll(1_500), None);
        assert_eq!(s.poll(1_501), Some(LinkLoss::RxPdoTimeout));
        assert_eq!(s.poll(5_000), None, "once");
        assert_eq!(s.on_frame(&[], 5_000), SyncEvent::Sync { counter: None, restored: true });
        assert_eq!(s.missed(), 4, "SYNCs at 1, 2, 3, 4 ms missing");
    }
}
