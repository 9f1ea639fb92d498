//! The CiA 301 pre-defined error field 0x1003: the error history, kept in the dictionary's value storage.
//!
//! Layout (device.toml 0x1003; IDX L1596-L1634; PD4 p.106-109): sub 0 "number of errors" (UNSIGNED8, rw), subs
//! 1..=capacity the entries (UNSIGNED32, ro), **newest at sub 1**, older ones shifting down; when the history is
//! full the oldest entry drops out. Writing 0 to sub 0 clears the history; other values are refused by the access
//! layer (device.toml `values = [0]`). The capacity is the object's highest sub-index in the generated dictionary
//! (8, from device.toml), read at run time, so a change in device.toml needs no change here.
//!
//! Entry layout (device.toml, after PD4 p.106 / L339): bits 15..0 the error code (as 0x603F), bits 23..16 the
//! error register at the trip (as 0x1001), bits 31..24 a running error number (wrapping 1..=255, 0 never used)
//! so that a reader can tell whether entries dropped out between two reads.
//!
//! "Write 0 clears": the access layer stores the 0 in sub 0 like any RAM value; [`after_sdo_write`] is the hook
//! the SDO server (or the drive's application-object path) calls after every successful download so that the
//! entries are zeroed as well. Even without the hook, [`push`] honours the count in sub 0, so a cleared history
//! restarts at one entry.

use crate::od::access::Dictionary;
use crate::od::values::Values;

/// Index of the pre-defined error field.
pub const INDEX: u16 = 0x1003;

/// One 0x1003 entry: the code, register and running number packed as device.toml describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct HistoryEntry {
    /// Error code (bits 15..0).
    pub code: u16,
    /// Error register at the trip (bits 23..16).
    pub register: u8,
    /// Running error number (bits 31..24).
    pub number: u8,
}

impl HistoryEntry {
    /// The UNSIGNED32 value stored in the dictionary.
    pub const fn to_u32(self) -> u32 {
        ((self.number as u32) << 24) | ((self.register as u32) << 16) | self.code as u32
    }

    /// The entry a stored UNSIGNED32 holds.
    pub const fn from_u32(raw: u32) -> Self {
        Self { code: raw as u16, register: (raw >> 16) as u8, number: (raw >> 24) as u8 }
    }
}

/// The number of entries the dictionary's 0x1003 holds (its highest sub-index; 0 if the object is missing).
pub fn capacity<const N: usize>(dict: &Dictionary<N>) -> u8 {
    dict.object(INDEX).map_or(0, |o| o.max_sub)
}

/// The number of entries stored (sub 0), never more than the capacity.
pub fn count<const N: usize>(dict: &Dictionary<N>) -> u8 {
    let stored = read(dict.values(), dict, 0).unwrap_or(0);
    // Sub 0 is one byte; a value beyond the capacity cannot be written through the access layer.
    u8::try_from(stored).unwrap_or(u8::MAX).min(capacity(dict))
}

/// The entry at position `n` (1 = newest), if stored.
pub fn entry<const N: usize>(dict: &Dictionary<N>, n: u8) -> Option<HistoryEntry> {
    if n == 0 || n > count(dict) {
        return None;
    }
    read(dict.values(), dict, n).map(HistoryEntry::from_u32)
}

/// The stored entries, newest first.
pub fn entries<const N: usize>(dict: &Dictionary<N>) -> impl Iterator<Item = HistoryEntry> + '_ {
    (1..=count(dict)).filter_map(move |n| entry(dict, n))
}

/// Adds `new` as the newest entry (sub 1), shifting the others down; the oldest drops out when the history is
/// full. Returns `false` if the dictionary has no 0x1003 (a test table), `true` otherwise.
pub fn push<const N: usize>(dict: &mut Dictionary<N>, new: HistoryEntry) -> bool {
    let capacity = capacity(dict);
    if capacity == 0 {
        return false;
    }
    let kept = count(dict).min(capacity.saturating_sub(1));
    // Shift from the oldest kept entry upwards so nothing is overwritten before it has moved.
    let mut n = kept;
    while n > 0 {
        if let Some(value) = read(dict.values(), dict, n) {
            write(dict, n.saturating_add(1), value);
        }
        n = n.saturating_sub(1);
    }
    write(dict, 1, new.to_u32());
    write(dict, 0, u32::from(kept.saturating_add(1)));
    true
}

/// Empties the history: sub 0 and every entry to 0.
pub fn clear<const N: usize>(dict: &mut Dictionary<N>) {
    let capacity = capacity(dict);
    for n in 0..=capacity {
        write(dict, n, 0);
    }
}

/// The hook for "writing 0 to 0x1003:00 clears the history" (CiA 301 object 1003h; IDX L1602-L1615): call it after
/// every successful SDO download with the index and sub-index written. It zeroes the entries when sub 0 of
/// 0x1003 was written (the access layer only lets 0 through) and does nothing for any other object.
pub fn after_sdo_write<const N: usize>(dict: &mut Dictionary<N>, index: u16, sub: u8) {
    if index == INDEX && sub == 0 && count(dict) == 0 {
        clear(dict);
    }
}

/// The zero-extended value of 0x1003:`sub`, if it is a RAM entry.
fn read<const N: usize>(values: &Values<N>, dict: &Dictionary<N>, sub: u8) -> Option<u32> {
    let entry = dict.find(INDEX, sub).ok()?;
    let raw = values.raw(entry)?;
    let mut wide = [0u8; 4];
    wide.get_mut(..raw.len())?.copy_from_slice(raw);
    Some(u32::from_le_bytes(wide))
}

/// Stores the low bytes of `value` into 0x1003:`sub` (ignored if it is not a RAM entry).
fn write<const N: usize>(dict: &mut Dictionary<N>, sub: u8, value: u32) {
    if let Ok(entry) = dict.find(INDEX, sub) {
        if let Some(raw) = dict.values_mut().raw_mut(entry) {
            if let Some(low) = value.to_le_bytes().get(..raw.len()) {
                raw.copy_from_slice(low);
            }
        }
    }
}
