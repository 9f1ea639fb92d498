//! Node-ID, bit rate and COB-IDs: the IDX objects 0x2000 (node-ID) and 0x2001/0x200A (bit rate), the CiA 301
//! pre-defined connection set derived from the node-ID (CiA 301 §7.3.3; comms-faults-bootloader.md §2.2 table),
//! the restricted identifiers, and the reset of the communication parameters to their defaults.
//!
//! **When a new node-ID or bit rate takes effect.** IDX (L3474-L3556) makes 0x2000 and 0x2001 effective "after
//! save and restart". Here the node reads 0x2000 at every reset (NMT reset communication or reset node, and
//! power-on): from then on the new node-ID is used and every node-ID-relative default (`$NODEID+` in
//! device.toml: SDO, PDO, EMCY COB-IDs) is recomputed for it. The bit rate is the CAN controller's: the node
//! reports 0x2001 at a reset node ([`super::NodeEvent::Reset`]) and the runtime reprograms the controller; 0x200A
//! shows what the controller runs at ([`super::CanopenNode::poll`] copies [`CanBus::bit_rate`]).
//!
//! [`CanBus::bit_rate`]: super::frame::CanBus::bit_rate

use crate::od::access::Dictionary;
use crate::od::entry::{Access, Storage};
use crate::od::values::{self, Values};

/// The NMT command COB-ID.
pub const NMT: u16 = 0x000;
/// The default SYNC COB-ID (0x1005).
pub const SYNC: u16 = 0x080;
/// Base of the EMCY COB-ID (0x80 + node-ID, 0x1014).
pub const EMCY_BASE: u16 = 0x080;
/// Bases of the TPDO 1..4 COB-IDs (0x180/0x280/0x380/0x480 + node-ID).
pub const TPDO_BASE: [u16; 4] = [0x180, 0x280, 0x380, 0x480];
/// Bases of the RPDO 1..4 COB-IDs (0x200/0x300/0x400/0x500 + node-ID).
pub const RPDO_BASE: [u16; 4] = [0x200, 0x300, 0x400, 0x500];
/// Base of the SDO server's transmit COB-ID (server to client, 0x580 + node-ID).
pub const SDO_TX_BASE: u16 = 0x580;
/// Base of the SDO server's receive COB-ID (client to server, 0x600 + node-ID).
pub const SDO_RX_BASE: u16 = 0x600;
/// Base of the heartbeat and boot-up COB-ID (0x700 + node-ID).
pub const HEARTBEAT_BASE: u16 = 0x700;

/// The node-ID when 0x2000 holds none: device.toml `[device] node_id`.
pub const DEFAULT_NODE_ID: u8 = 1;

/// The node-ID object (IDX L3474-L3489).
pub const NODE_ID_OBJECT: u16 = 0x2000;
/// The bit-rate object (IDX L3490-L3510).
pub const BIT_RATE_OBJECT: u16 = 0x2001;
/// Store parameters (CiA 301 §7.5.2.13), and its sub-index "save manufacturer parameters".
pub const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1010:04, the manufacturer-specific parameters 0x2000..0x5FFF (0x2000 and 0x2001 among them).
pub const SAVE_MANUFACTURER: u8 = 4;
/// The signature "save" that 0x1010 takes, as written on the wire.
pub const SAVE_SIGNATURE: [u8; 4] = *b"save";
/// The bit-rate display (IDX L3548).
pub const BIT_RATE_DISPLAY: u16 = 0x200A;

/// Whether `id` is a node-ID (1..=127, CiA 301 §7.3.3; 0 addresses all nodes in NMT only).
pub const fn is_node_id(id: u8) -> bool {
    matches!(id, 1..=127)
}

/// `base + node_id`, the pre-defined connection set's COB-ID.
pub const fn cob_id(base: u16, node_id: u8) -> u16 {
    base.wrapping_add(node_id as u16)
}

/// Whether `id` is one of CiA 301's restricted CAN identifiers (CiA 301 §7.3.5 Table 72), which no PDO or
/// SYNC may use: 0x000, 0x001..0x07F, 0x101..0x180, 0x581..0x5FF, 0x601..0x67F, 0x6E0..0x6FF, 0x701..0x77F,
/// 0x780..0x7FF.
pub const fn is_restricted(id: u16) -> bool {
    matches!(id, 0x000..=0x07F | 0x101..=0x180 | 0x581..=0x5FF | 0x601..=0x67F | 0x6E0..=0x6FF | 0x701..=0x7FF)
}

/// The unsigned value at `index:sub` when it is in RAM (or a constant up to 8 bytes).
pub fn read<const N: usize>(d: &Dictionary<N>, index: u16, sub: u8) -> Option<u64> {
    let entry = d.find(index, sub).ok()?;
    // A copy: the entry is packed (`od::entry::Entry`), and the guard borrows the binding.
    let storage = entry.storage;
    match storage {
        Storage::Const(bytes) if bytes.bytes().len() <= 8 => {
            let mut wide = [0u8; 8];
            for (w, b) in wide.iter_mut().zip(bytes.bytes().iter()) {
                *w = *b;
            }
            Some(u64::from_le_bytes(wide))
        }
        _ => values::unsigned(d.values().bytes(), entry),
    }
}

/// [`read`] narrowed to `u32` (0 when absent).
pub fn read_u32<const N: usize>(d: &Dictionary<N>, index: u16, sub: u8) -> u32 {
    read(d, index, sub).and_then(|v| u32::try_from(v).ok()).unwrap_or(0)
}

/// Writes an unsigned value to a RAM entry without the SDO checks (the node's own bookkeeping: 0x200A).
pub fn write<const N: usize>(d: &mut Dictionary<N>, index: u16, sub: u8, value: u64) -> bool {
    let Ok(entry) = d.find(index, sub) else {
        return false;
    };
    values::set_unsigned(d.values_mut().bytes_mut(), entry, value)
}

/// The node-ID 0x2000 asks for, if it is a valid one.
pub fn configured_node_id<const N: usize>(d: &Dictionary<N>) -> Option<u8> {
    read(d, NODE_ID_OBJECT, 0).and_then(|v| u8::try_from(v).ok()).filter(|id| is_node_id(*id))
}

/// The node-ID a start or reset takes from 0x2000: a valid node-ID, or [`super::lss::UNCONFIGURED`] when 0x2000
/// holds 0xFF (configured through LSS, CiA 305 §5); `None` for anything else.
pub fn startup_node_id<const N: usize>(d: &Dictionary<N>) -> Option<u8> {
    configured_node_id(d).or_else(|| {
        let unconfigured = super::lss::UNCONFIGURED;
        (read(d, NODE_ID_OBJECT, 0) == Some(u64::from(unconfigured))).then_some(unconfigured)
    })
}

/// Whether reset communication restores `index`: the communication profile area 0x1000..0x1FFF (CiA 301
/// §7.3.2.2.1) except the error history 0x1003, which records what happened and is cleared only by writing
/// 0x1003:00 = 0.
const fn restored_by_communication_reset(index: u16) -> bool {
    matches!(index, 0x1000..=0x1FFF) && index != 0x1003
}

/// Reset communication (CiA 301 §7.3.2.2.1): every writable RAM parameter of 0x1000..0x1FFF back to its default
/// for `node_id` (so the node-ID-relative COB-IDs follow a new node-ID). Read-only entries (actual values such as
/// the error register 0x1001, the serial number 0x1018:04) and application-served entries keep what they hold.
/// Runs at tier 3, inside the drive's lock, which holds tier 2 off: it builds the default storage once
/// (`VALUE_BYTES` on the stack) and visits only the entries of 0x1000..0x1FFF, found by binary search in the sorted
/// table (fewer than half of the entries), both for the node-ID-relative defaults and for the copy.
pub fn reset_communication_parameters(d: &mut Dictionary, node_id: u8) {
    let entries = d.table().entries();
    let first = entries.partition_point(|e| e.index < 0x1000);
    let end = entries.partition_point(|e| e.index <= 0x1FFF);
    let communication = entries.get(first..end).unwrap_or(&[]);
    let defaults = Values::defaults_for(communication, node_id);
    for entry in communication {
        let writable = matches!(entry.access(), Access::ReadWrite | Access::WriteOnly);
        let node_relative = entry.node_id_relative();
        if !restored_by_communication_reset(entry.index) || !(writable || node_relative) {
            continue;
        }
        if let (Some(src), Some(dst)) = (defaults.raw(entry), d.values_mut().raw_mut(entry)) {
            if src.len() == dst.len() {
                dst.copy_from_slice(src);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn restricted_identifiers_follow_cia_301() {
        for id in [0x000, 0x07F, 0x101, 0x180, 0x581, 0x5FF, 0x601, 0x67F, 0x6E0, 0x6FF, 0x701, 0x7FF] {
            assert!(is_restricted(id), "{id:03X}");
        }
        for id in [0x080, 0x100, 0x181, 0x1FF, 0x201, 0x580, 0x600, 0x680, 0x6DF, 0x700] {
            assert!(!is_restricted(id), "{id:03X}");
        }
    }

    #[test]
    fn communication_reset_recomputes_node_relative_cob_ids() {
        let mut d = Dictionary::new(1);
        assert_eq!(read_u32(&d, 0x1200, 1), 0x601);
        assert!(write(&mut d, 0x1017, 0, 500));
        reset_communication_parameters(&mut d, 9);
        assert_eq!(read_u32(&d, 0x1200, 1), 0x609);
        assert_eq!(read_u32(&d, 0x1200, 2), 0x589);
        assert_eq!(read_u32(&d, 0x1014, 0), 0x89);
        assert_eq!(read_u32(&d, 0x1400, 1), 0x209);
        assert_eq!(read_u32(&d, 0x1017, 0), 0, "producer heartbeat back to its default");
    }

    #[test]
    fn communication_reset_restores_up_to_the_area_end_and_keeps_the_application_area() {
        // CiA 301 §7.3.2.2.1: the whole of 0x1000..0x1FFF and nothing above it. 0x1C13:00 (default 3) is among the
        // area's last writable entries; 0x6083 (profile acceleration, default 10,000) lies just outside it.
        let mut d = Dictionary::new(1);
        assert!(write(&mut d, 0x1C13, 0, 0));
        assert!(write(&mut d, 0x6083, 0, 20_000));
        reset_communication_parameters(&mut d, 1);
        assert_eq!(read_u32(&d, 0x1C13, 0), 3, "0x1C13:00 back to its default");
        assert_eq!(read_u32(&d, 0x6083, 0), 20_000, "0x6083 keeps what was written");
    }
}
