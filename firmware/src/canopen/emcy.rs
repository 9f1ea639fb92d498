//! The EMCY producer on CAN (CiA 301 §7.2.7): the drive's emergency messages ([`FieldbusDevice::poll_emcy`], 8 bytes,
//! inhibit time 0x1015 applied by the drive's queue, `fault/emcy.rs`) sent on the COB-ID of 0x1014
//! (0x80 + node-ID; bit 31 set = EMCY not valid, then nothing is sent).
//!
//! EMCY is produced in pre-operational and operational only (CiA 301 Table 88); in stopped and initialisation
//! the messages wait in the drive's queue (bounded; an overflow is reported there) and leave in order once the
//! node is allowed to send again. A message is taken from the drive only when the transmit queue has room, so
//! none is lost here.

use super::frame::CanFrame;
use super::ids;
use super::pdo::FrameSink;
use crate::comm::device::FieldbusDevice;
use crate::od::access::Dictionary;

/// Messages one poll sends at most (the rest wait in the drive's queue).
pub const EMCY_PER_POLL: usize = 4;

/// The EMCY producer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EmcyProducer {
    cob_id: u16,
    valid: bool,
    sent: u32,
}

impl EmcyProducer {
    /// Reads 0x1014.
    pub fn configure<const N: usize>(&mut self, d: &Dictionary<N>) {
        let raw = ids::read_u32(d, 0x1014, 0);
        self.valid = raw & (1 << 31) == 0;
        self.cob_id = u16::try_from(raw & 0x7FF).unwrap_or(0);
    }

    /// The EMCY COB-ID.
    pub const fn cob_id(&self) -> u16 {
        self.cob_id
    }

    /// Messages sent.
    pub const fn sent(&self) -> u32 {
        self.sent
    }

    /// Tier 3 (pre-operational and operational): moves up to [`EMCY_PER_POLL`] messages from the drive to the
    /// transmit queue while it has room.
    pub fn poll<D: FieldbusDevice + ?Sized, S: FrameSink + ?Sized>(&mut self, drive: &mut D, sink: &mut S) {
        if !self.valid {
            return;
        }
        for _ in 0..EMCY_PER_POLL {
            if sink.room() == 0 {
                return;
            }
            let Some(bytes) = drive.poll_emcy() else {
                return;
            };
            if let Some(frame) = CanFrame::new(self.cob_id, &bytes) {
                if sink.push(frame) {
                    self.sent = self.sent.wrapping_add(1);
                }
            }
        }
    }
}
