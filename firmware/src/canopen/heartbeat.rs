//! Heartbeat (CiA 301 §7.2.8.3.2): the producer 0x1017 and the consumers 0x1016.
//!
//! **Producer.** With 0x1017 = t ms (0 = off) the node sends its NMT state code (one byte; E4 Table 5-54) on
//! 0x700 + node-ID every t ms, the first one t ms after the boot-up message or after 0x1017 changed; in
//! pre-operational, operational and stopped (CiA 301 Table 88).
//!
//! **Consumers.** Each 0x1016 entry (bits 23..16 producer node-ID, bits 15..0 time in ms; 0 = off; IDX
//! L1749-L1784, EPOS4 L3598-L3610) supervises one producer. The first heartbeat arms it (E4: "monitoring starts
//! after the first heartbeat received"); when no heartbeat follows within the time, the loss is reported once as
//! [`LinkLoss::HeartbeatLost`] (0x8130, the drive reacts per 0x6007), and the next heartbeat reports it restored,
//! so that a fault reset is accepted (IDX L7345-L7350 names NMT reset communication as the recovery, which also
//! restores: [`super::CanopenNode`]).

use super::frame::CanFrame;
use super::ids;
use crate::od::access::Dictionary;
use crate::supervision::communication::LinkLoss;

/// Consumer entries supported (the dictionary's 0x1016 has 2; more are ignored).
pub const MAX_CONSUMERS: usize = 4;

/// One supervised producer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Consumer {
    node: u8,
    timeout_us: u64,
    last_us: Option<u64>,
    lost: bool,
}

/// A change of a consumer's supervision.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum HeartbeatEvent {
    /// The producer's heartbeat timed out.
    Lost(LinkLoss),
    /// A heartbeat arrived after a loss.
    Restored(LinkLoss),
}

/// The heartbeat producer and consumers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Heartbeat {
    period_us: u64,
    next_us: Option<u64>,
    consumers: [Consumer; MAX_CONSUMERS],
}

impl Heartbeat {
    /// Reads 0x1017 and 0x1016 at `now_us`: the producer's next heartbeat is one period away; consumers whose
    /// entry did not change keep their supervision, changed ones wait for their first heartbeat.
    pub fn configure<const N: usize>(&mut self, d: &Dictionary<N>, now_us: u64) {
        let period_us = ids::read(d, 0x1017, 0).unwrap_or(0).saturating_mul(1000);
        if period_us != self.period_us || self.next_us.is_none() {
            self.period_us = period_us;
            self.next_us = (period_us > 0).then(|| now_us.saturating_add(period_us));
        }
        let count = ids::read(d, 0x1016, 0).and_then(|v| usize::try_from(v).ok()).unwrap_or(0);
        for (k, consumer) in self.consumers.iter_mut().enumerate() {
            let sub = u8::try_from(k.saturating_add(1)).unwrap_or(u8::MAX);
            let raw = if k < count { ids::read_u32(d, 0x1016, sub) } else { 0 };
            let node = u8::try_from(raw.wrapping_shr(16) & 0xFF).unwrap_or(0);
            let timeout_us = u64::from(raw & 0xFFFF).saturating_mul(1000);
            if node != consumer.node || timeout_us != consumer.timeout_us {
                *consumer = Consumer { node, timeout_us, last_us: None, lost: false };
            }
        }
    }

    /// Restarts the producer's period from `now_us` (after the boot-up message).
    pub fn restart(&mut self, now_us: u64) {
        self.next_us = (self.period_us > 0).then(|| now_us.saturating_add(self.period_us));
    }

    /// The producer's frame when due at `now_us`: the state code on 0x700 + `node_id`.
    pub fn produce(&mut self, now_us: u64, node_id: u8, state_code: u8) -> Option<CanFrame> {
        let next = self.next_us?;
        if now_us < next {
            return None;
        }
        // The next one a period after this one was due, but never in the past (after a long pause).
        let following = next.saturating_add(self.period_us);
        self.next_us = Some(if following <= now_us { now_us.saturating_add(self.period_us) } else { following });
        CanFrame::new(ids::cob_id(ids::HEARTBEAT_BASE, node_id), &[state_code])
    }

    /// A heartbeat (or boot-up) frame from `node` at `now_us`.
    pub fn on_heartbeat(&mut self, node: u8, now_us: u64) -> Option<HeartbeatEvent> {
        let mut event = None;
        for c in self.consumers.iter_mut().filter(|c| c.node == node && c.timeout_us > 0) {
            c.last_us = Some(now_us);
            if core::mem::take(&mut c.lost) {
                event = Some(HeartbeatEvent::Restored(LinkLoss::HeartbeatLost { node }));
            }
        }
        event
    }

    /// Tier 3: the first consumer whose producer timed out at `now_us` (each loss reported once).
    pub fn poll(&mut self, now_us: u64) -> Option<HeartbeatEvent> {
        for c in &mut self.consumers {
            if let (Some(last), false, true) = (c.last_us, c.lost, c.timeout_us > 0) {
                if now_us.saturating_sub(last) > c.timeout_us {
                    c.lost = true;
                    return Some(HeartbeatEvent::Lost(LinkLoss::HeartbeatLost { node: c.node }));
                }
            }
        }
        None
    }

    /// The losses reported and not yet restored (for a communication reset, which restores them).
    pub fn take_lost(&mut self) -> impl Iterator<Item = LinkLoss> + '_ {
        self.consumers.iter_mut().filter(|c| c.lost).map(|c| {
            c.lost = false;
            LinkLoss::HeartbeatLost { node: c.node }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn producer_period_and_consumer_timeout() {
        let mut d = Dictionary::new(3);
        ids::write(&mut d, 0x1017, 0, 100);
        ids::write(&mut d, 0x1016, 1, 0x0005_00C8);
        let mut h = Heartbeat::default();
        h.configure(&d, 0);
        assert_eq!(h.produce(99_999, 3, 0x7F), None);
        let f = h.produce(100_000, 3, 0x7F).unwrap();
        assert_eq!((f.id(), f.data()), (0x703, &[0x7Fu8][..]));
        assert_eq!(h.produce(150_000, 3, 0x7F), None);
        assert!(h.produce(200_000, 3, 0x7F).is_some());
        assert_eq!(h.poll(10_000_000), None, "not armed before the first heartbeat");
        assert_eq!(h.on_heartbeat(5, 0), None);
        assert_eq!(h.poll(200_000), None);
        assert_eq!(h.poll(200_001), Some(HeartbeatEvent::Lost(LinkLoss::HeartbeatLost { node: 5 })));
        assert_eq!(h.poll(900_000), None, "once");
        assert_eq!(h.on_heartbeat(5, 900_000), Some(HeartbeatEvent::Restored(LinkLoss::HeartbeatLost { node: 5 })));
    }
}
