//! The node-ID and CAN bit rate of the bootloader's fallback ([`super::fallback`]) from the parameter store
//! (issue 19 item 4): the drive's saved 0x2000 *Node-ID* (IDX L3474-3489) and 0x2001 *CAN bit rate* (IDX
//! L3490-3510, codes of IDX Table 6-88), so that a drive without a valid application answers where its bus
//! expects it, not only at the device defaults (node-ID 1, 1 Mbit/s).
//!
//! A lean reader of the record format that [`crate::od::store`] writes (format table there): the bootloader has
//! neither the dictionary nor room for the store's writer. It finds the record in force exactly as
//! [`crate::od::store::ParamStore::current`] does (both sectors; magic, format version, commit word, bounds,
//! CRC-32 over payload and header, and the item structure: exactly the counted items filling exactly the
//! payload; then the newer sequence number, wrapping), so the bootloader and the application never disagree
//! about which record counts. From it, the values apply as [`crate::od::store::ParamStore::load`] applies them:
//! only if the record holds the manufacturer group (0x2000-0x5FFF, stored bit 2; a 0x1011 restore leaves it out)
//! and only items of 0x2000:00 / 0x2001:00 with the length of their UNSIGNED8 entry. Each is then checked as
//! the application checks it at start-up (`rt::canopen::start`): a node-ID 1..=127 (CiA 301 §7.5.2), a bit-rate
//! code the drive offers ([`BitRate::from_code`]). Anything else (no record, torn or corrupt records, a value out
//! of range) gives that value's device default. The CRC is the image verifier's CRC-32 ([`super::crc32`], the
//! same IEEE 802.3 checksum as the store's own table), so the bootloader carries one implementation, not two.

use super::crc32::Crc32;
use crate::canopen::frame::BitRate;
use crate::canopen::ids::{is_node_id, BIT_RATE_OBJECT, DEFAULT_NODE_ID, NODE_ID_OBJECT};
use crate::hal::flash::NorFlash;
use crate::od::store::{
    sequence_newer, Group, CRC_HEADER_LEN, ITEM_HEADER_LEN, OFF_COMMIT, OFF_CRC, OFF_ITEM_COUNT, OFF_MAGIC,
    OFF_PAYLOAD_LEN, OFF_SEQUENCE, OFF_STORED, OFF_VERSION, RECORD_COMMIT, RECORD_HEADER_LEN, RECORD_MAGIC,
    RECORD_VERSION,
};

/// Bytes read per flash read while checking the CRC.
const READ_CHUNK: usize = 64;

/// Where the fallback answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FallbackComms {
    /// The node-ID (1..=127).
    pub node_id: u8,
    /// The bit rate.
    pub bit_rate: BitRate,
}

impl Default for FallbackComms {
    /// The device defaults (device.toml `[device] node_id`, `bit_rate_kbit`).
    fn default() -> Self {
        Self { node_id: DEFAULT_NODE_ID, bit_rate: BitRate::default() }
    }
}

/// What a valid record holds for the fallback: its sequence number and the raw values it stores.
#[derive(Clone, Copy, Debug)]
struct Found {
    sequence: u32,
    node_id: Option<u8>,
    bit_rate_code: Option<u8>,
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    b.get(at..).and_then(|s| s.first_chunk::<4>()).map_or(0, |w| u32::from_le_bytes(*w))
}

/// The record in the sector starting at `base` (`sector_size` bytes), if it is valid (module documentation).
fn record<F: NorFlash>(flash: &mut F, base: u32, sector_size: u32) -> Option<Found> {
    let mut header = [0u8; RECORD_HEADER_LEN as usize];
    flash.read(base, &mut header).ok()?;
    let payload_len = le_u32(&header, OFF_PAYLOAD_LEN);
    let items = le_u32(&header, OFF_ITEM_COUNT);
    let version = header.get(OFF_VERSION..).and_then(|s| s.first_chunk::<2>()).map(|v| u16::from_le_bytes(*v));
    if le_u32(&header, OFF_MAGIC) != RECORD_MAGIC
        || version != Some(RECORD_VERSION)
        || le_u32(&header, OFF_COMMIT) != RECORD_COMMIT
        || payload_len > sector_size.saturating_sub(RECORD_HEADER_LEN)
        || items > payload_len / ITEM_HEADER_LEN
    {
        return None;
    }
    let start = base.checked_add(RECORD_HEADER_LEN)?;
    let end = start.checked_add(payload_len)?;
    let mut crc = Crc32::new();
    let mut chunk = [0u8; READ_CHUNK];
    let mut at = start;
    while at < end {
        let buf = chunk.get_mut(..(end.saturating_sub(at) as usize).min(READ_CHUNK))?;
        flash.read(at, buf).ok()?;
        crc.update(buf);
        at = at.saturating_add(buf.len() as u32);
    }
    crc.update(header.get(..CRC_HEADER_LEN)?);
    if crc.finalize() != le_u32(&header, OFF_CRC) {
        return None;
    }
    let manufacturer = header.get(OFF_STORED).is_some_and(|s| s & Group::Manufacturer.bit() != 0);
    let mut found = Found { sequence: le_u32(&header, OFF_SEQUENCE), node_id: None, bit_rate_code: None };
    let mut next = start;
    for _ in 0..items {
        let mut item = [0u8; ITEM_HEADER_LEN as usize + 1];
        let data = next.checked_add(ITEM_HEADER_LEN).filter(|d| *d <= end)?;
        // The item header and the first value byte (the value may be empty: read past it only inside the sector).
        let want = if data < end { item.len() } else { ITEM_HEADER_LEN as usize };
        flash.read(next, item.get_mut(..want)?).ok()?;
        let [i0, i1, sub, l0, l1, value] = item;
        let len = u16::from_le_bytes([l0, l1]);
        next = data.checked_add(u32::from(len)).filter(|a| *a <= end)?;
        if manufacturer && sub == 0 && len == 1 {
            match u16::from_le_bytes([i0, i1]) {
                NODE_ID_OBJECT => found.node_id = Some(value),
                BIT_RATE_OBJECT => found.bit_rate_code = Some(value),
                _ => {}
            }
        }
    }
    (next == end).then_some(found)
}

/// The fallback's node-ID and bit rate from the parameter store in `flash` (its sectors 0 and 1, as
/// [`crate::od::store::ParamStore`] uses them); the device defaults for whatever is not validly stored.
pub fn stored_comms<F: NorFlash>(flash: &mut F) -> FallbackComms {
    let size = flash.geometry().sector_size;
    let a = record(flash, 0, size);
    let b = if flash.geometry().sector_count >= 2 { record(flash, size, size) } else { None };
    let newest = match (a, b) {
        (Some(a), Some(b)) => Some(if sequence_newer(b.sequence, a.sequence) { b } else { a }),
        (a, b) => a.or(b),
    };
    let defaults = FallbackComms::default();
    let Some(found) = newest else { return defaults };
    FallbackComms {
        node_id: found.node_id.filter(|id| is_node_id(*id)).unwrap_or(defaults.node_id),
        bit_rate: found.bit_rate_code.and_then(BitRate::from_code).unwrap_or(defaults.bit_rate),
    }
}
