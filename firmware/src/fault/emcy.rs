//! The emergency (EMCY) producer: the 8-byte CiA 301 emergency message, an inhibit time, and a bounded queue
//! that never loses the first fault of a burst and never loses one silently.
//!
//! Frame (CiA 301 EMCY; IDX Table 7-152 L7017-L7024; E3 L1262-L1280 for the EtherCAT emergency):
//!
//! | Byte | Content |
//! |---|---|
//! | 0-1 | error code, little-endian (the 0x603F value; 0x0000 = "error reset / no error") |
//! | 2 | error register 0x1001 at the moment of the event |
//! | 3 | manufacturer: the fault number ([`crate::fault::FaultId::number`]); 0 in an error reset |
//! | 4-7 | manufacturer: one measured value of the trip snapshot, INTEGER32 little-endian, the one the fault table's `emcy_field` names (e.g. the peak phase current in mA for an over-current, the bus voltage in mV for over-/under-voltage, the detector's detail value for a following error); for the overflow report, the number of messages lost (UNSIGNED32); 0 in an error reset |
//!
//! IDX leaves bytes 3-7 zero; E3's EtherCAT emergency puts "additional error information" there, which is what
//! this drive does (a field engineer sees the trip value on the bus analyser without an SDO read).
//!
//! Inhibit time (object 0x1015, UNSIGNED16 in 100 us units, device.toml; CiA 301): the minimum time between two
//! emergency messages; 0 sends each at once. Messages that arrive within the inhibit time wait in the queue and
//! leave, in order, one per inhibit interval. Time is the tier-2 [`Ticks`] (400 us), so the spacing is checked
//! exactly in 100 us units (one tick = 4 units) and a message leaves at the first poll at or after the interval.
//!
//! Queue (capacity `Q`): when full, the **oldest entries are kept** (the first fault of a burst is the root cause
//! and is never dropped); the newest are dropped and counted. The last slot is reserved for an overflow report,
//! an EMCY with the manufacturer code 0xFF90 (fault table [`crate::fault::FaultId::EmcyOverflow`]; CiA 301's
//! 0x8110 "CAN overrun" names the CAN controller, IDX L7071, so it is not reused) carrying the number lost. The
//! report takes its place in the order: after every message queued before the first loss, before every message
//! queued after the queue drained. So every message enqueued is either emitted or counted in an emitted report.
//!
//! Bus-agnostic: CANopen sends the bytes on the COB-ID of 0x1014 (0x80 + node-ID), CoE wraps them in a mailbox
//! emergency (ETG.1000.6), both outside this module.

use heapless::Deque;

use super::table::FaultId;
use crate::cia402::Ticks;

/// The "error reset / no error" code (CiA 301; IDX Table 7-153 0x0000).
pub const ERROR_RESET: u16 = 0x0000;

/// Default queue capacity of an [`EmcyProducer`].
pub const DEFAULT_QUEUE: usize = 16;

/// 100 us units per tier-2 tick (400 us).
const UNITS_PER_TICK: u64 = 4;

/// The EMCY inhibit time (object 0x1015) in 100 us units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct InhibitTime(pub u16);

impl InhibitTime {
    /// Whether `elapsed` tier-2 ticks (400 us each) are at least the inhibit time.
    pub fn elapsed(self, elapsed: Ticks) -> bool {
        u64::from(elapsed.0).saturating_mul(UNITS_PER_TICK) >= u64::from(self.0)
    }
}

/// Why bytes are not an EMCY frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum EmcyFrameError {
    /// An EMCY frame has exactly 8 bytes (CiA 301).
    Length(usize),
}

/// One emergency message (the parsed form of the 8-byte frame; ARCHITECTURE convention 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct EmcyMessage {
    /// Error code, bytes 0-1.
    pub code: u16,
    /// Error register, byte 2.
    pub register: u8,
    /// Manufacturer-specific bytes 3-7 (see the module documentation).
    pub manufacturer: [u8; 5],
}

impl EmcyMessage {
    /// A fault or warning message: its code, the register, its number and the snapshot value.
    pub fn fault(id: FaultId, register: u8, value: i32) -> Self {
        let [v0, v1, v2, v3] = value.to_le_bytes();
        Self { code: id.info().code, register, manufacturer: [id.number(), v0, v1, v2, v3] }
    }

    /// The "error reset / no error" message (code 0x0000) with the register after the reset.
    pub const fn error_reset(register: u8) -> Self {
        Self { code: ERROR_RESET, register, manufacturer: [0; 5] }
    }

    /// The overflow report: `lost` messages were dropped.
    pub fn overflow(register: u8, lost: u32) -> Self {
        let [v0, v1, v2, v3] = lost.to_le_bytes();
        let id = FaultId::EmcyOverflow;
        Self { code: id.info().code, register, manufacturer: [id.number(), v0, v1, v2, v3] }
    }

    /// The 8 bytes on the wire.
    pub fn to_bytes(&self) -> [u8; 8] {
        let [c0, c1] = self.code.to_le_bytes();
        let [m0, m1, m2, m3, m4] = self.manufacturer;
        [c0, c1, self.register, m0, m1, m2, m3, m4]
    }

    /// Parses 8 bytes (checked length).
    pub fn parse(bytes: &[u8]) -> Result<Self, EmcyFrameError> {
        match bytes {
            [c0, c1, register, m0, m1, m2, m3, m4] => Ok(Self {
                code: u16::from_le_bytes([*c0, *c1]),
                register: *register,
                manufacturer: [*m0, *m1, *m2, *m3, *m4],
            }),
            _ => Err(EmcyFrameError::Length(bytes.len())),
        }
    }

    /// The fault number in byte 3.
    pub const fn fault_number(&self) -> u8 {
        self.manufacturer[0]
    }

    /// Bytes 4..7 as a little-endian 32-bit value (the snapshot value, or the count lost in an overflow report).
    pub const fn value(&self) -> u32 {
        let [_, a, b, c, d] = self.manufacturer;
        u32::from_le_bytes([a, b, c, d])
    }

    /// Whether this is an overflow report.
    pub fn is_overflow(&self) -> bool {
        self.code == FaultId::EmcyOverflow.info().code && self.fault_number() == FaultId::EmcyOverflow.number()
    }
}

/// A queue slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pending {
    Message(EmcyMessage),
    Overflow { register: u8, lost: u32 },
}

/// Counters for diagnosis and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct EmcyStats {
    /// Messages offered to the queue.
    pub enqueued: u32,
    /// Messages (not reports) emitted.
    pub emitted: u32,
    /// Messages lost to overflow (each counted in a report, emitted or still queued).
    pub lost: u32,
    /// Overflow reports emitted.
    pub overflow_reports: u32,
}

/// The EMCY producer: queue, inhibit time, overflow accounting. Sans-IO: [`EmcyProducer::poll`] returns the next
/// frame to send, if one may be sent at `now`.
#[derive(Clone, Debug)]
pub struct EmcyProducer<const Q: usize = DEFAULT_QUEUE> {
    queue: Deque<Pending, Q>,
    inhibit: InhibitTime,
    last_sent: Option<Ticks>,
    stats: EmcyStats,
}

impl<const Q: usize> Default for EmcyProducer<Q> {
    fn default() -> Self {
        Self::new(InhibitTime(0))
    }
}

impl<const Q: usize> EmcyProducer<Q> {
    /// An empty producer. `Q` must be at least 2 (one message and the overflow slot); with less, every message is
    /// counted as lost and only reports are sent.
    pub const fn new(inhibit: InhibitTime) -> Self {
        Self {
            queue: Deque::new(),
            inhibit,
            last_sent: None,
            stats: EmcyStats { enqueued: 0, emitted: 0, lost: 0, overflow_reports: 0 },
        }
    }

    /// Sets the inhibit time (after a write to 0x1015); applies from the next poll.
    pub fn set_inhibit_time(&mut self, inhibit: InhibitTime) {
        self.inhibit = inhibit;
    }

    /// The inhibit time.
    pub const fn inhibit_time(&self) -> InhibitTime {
        self.inhibit
    }

    /// Counters.
    pub const fn stats(&self) -> EmcyStats {
        self.stats
    }

    /// Entries waiting (messages and reports).
    pub fn pending(&self) -> usize {
        self.queue.len()
    }

    /// Whether nothing is waiting.
    pub fn is_idle(&self) -> bool {
        self.queue.is_empty()
    }

    /// Queues a message. Never fails: when the queue is full the message is counted in an overflow report.
    pub fn push(&mut self, message: EmcyMessage) {
        self.stats.enqueued = self.stats.enqueued.saturating_add(1);
        let len = self.queue.len();
        // A message may use every slot but the last, which is kept for the overflow report.
        if len.saturating_add(1) < Q && self.queue.push_back(Pending::Message(message)).is_ok() {
            return;
        }
        self.stats.lost = self.stats.lost.saturating_add(1);
        match self.queue.back_mut() {
            // A report at the tail already: it takes this one too (the queue is in overflow).
            Some(Pending::Overflow { lost, .. }) => *lost = lost.saturating_add(1),
            _ => {
                let report = Pending::Overflow { register: message.register, lost: 1 };
                if let Err(report) = self.queue.push_back(report) {
                    // Only reachable with Q < 2 or a full queue without a report at its tail, which `push` never
                    // produces: turn the newest message into a report of itself and this one, so that the count
                    // stays exact.
                    self.replace_tail_with_report(report);
                }
            }
        }
    }

    /// Fallback of [`EmcyProducer::push`]: makes the tail a report covering what it held.
    fn replace_tail_with_report(&mut self, report: Pending) {
        let Pending::Overflow { register, lost } = report else { return };
        match self.queue.back_mut() {
            Some(tail @ Pending::Message(_)) => {
                self.stats.lost = self.stats.lost.saturating_add(1);
                *tail = Pending::Overflow { register, lost: lost.saturating_add(1) };
            }
            Some(Pending::Overflow { lost: tail_lost, .. }) => *tail_lost = tail_lost.saturating_add(lost),
            // Q == 0: nothing can ever be queued; the loss is in the stats only.
            None => {}
        }
    }

    /// The next frame to send at `now`, if the inhibit time since the previous one has passed (CiA 301 0x1015).
    pub fn poll(&mut self, now: Ticks) -> Option<[u8; 8]> {
        if let Some(last) = self.last_sent {
            if !self.inhibit.elapsed(now.since(last)) {
                return None;
            }
            if self.queue.is_empty() {
                // The inhibit interval is over and nothing waits: forget the time, so that a counter wrap after
                // a long quiet period can never delay the next message.
                self.last_sent = None;
            }
        }
        let message = match self.queue.pop_front()? {
            Pending::Message(message) => {
                self.stats.emitted = self.stats.emitted.saturating_add(1);
                message
            }
            Pending::Overflow { register, lost } => {
                self.stats.overflow_reports = self.stats.overflow_reports.saturating_add(1);
                EmcyMessage::overflow(register, lost)
            }
        };
        self.last_sent = Some(now);
        Some(message.to_bytes())
    }
}
