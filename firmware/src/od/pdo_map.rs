//! PDO mapping (0x1600..0x17FF, 0x1A00..0x1BFF) and EtherCAT PDO assignment (0x1C12/0x1C13): decoding and
//! whole-object validation.
//!
//! A mapping entry is `index << 16 | sub << 8 | length in bits` (CiA 301 §7.4.7.1 Figure 70; object-dictionary.md
//! §6). Mappings change by the CiA 301 §7.5.2.36 procedure, which IDX repeats for EtherCAT (L2196-L2216; Gamma
//! L1875-L1883; comms-faults-bootloader.md §1.5): disable the mapping (sub 0 = 0), write entries 1..n, enable it
//! (sub 0 = n). The device checks each entry as it is written (CiA 301: abort 0x0602_0000 or 0x0604_0041 in
//! step 3) and the mapping as a whole when sub 0 is set (abort 0x0604_0042 in step 4), so a mapping whose sub 0 is
//! above 0 always holds valid entries. Assignments (ETG.1000.6 0x1C12/0x1C13; IDX L2978-L3055) follow the same
//! pattern: sub 0 = 0, entries, sub 0 = n.
//!
//! The access layer calls [`check_write`] before it stores a value; the EtherCAT and CANopen PDO code decode a
//! mapping with [`mapping`] and an assignment with [`assignment`].

use super::abort::SdoAbort;
use super::access::Table;
use super::entry::{DataType, Entry};
use super::values;

/// First RxPDO mapping object (CiA 301 §7.5.2.36).
pub const RX_MAPPING_FIRST: u16 = 0x1600;
/// Last RxPDO mapping object.
pub const RX_MAPPING_LAST: u16 = 0x17FF;
/// First TxPDO mapping object (CiA 301 §7.5.2.38).
pub const TX_MAPPING_FIRST: u16 = 0x1A00;
/// Last TxPDO mapping object.
pub const TX_MAPPING_LAST: u16 = 0x1BFF;
/// SyncManager 2 (process data outputs, RxPDOs) assignment (ETG.1000.6; IDX L2978).
pub const RX_ASSIGNMENT: u16 = 0x1C12;
/// SyncManager 3 (process data inputs, TxPDOs) assignment (ETG.1000.6; IDX L3020).
pub const TX_ASSIGNMENT: u16 = 0x1C13;

/// The direction of a PDO.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Receive PDO (master to drive, EtherCAT outputs).
    Rx,
    /// Transmit PDO (drive to master, EtherCAT inputs).
    Tx,
}

/// The direction of the PDO a mapping object describes, or `None` if `index` is no mapping object.
pub const fn mapping_direction(index: u16) -> Option<Direction> {
    match index {
        RX_MAPPING_FIRST..=RX_MAPPING_LAST => Some(Direction::Rx),
        TX_MAPPING_FIRST..=TX_MAPPING_LAST => Some(Direction::Tx),
        _ => None,
    }
}

/// The direction of the PDOs an assignment object lists, or `None` if `index` is no assignment object.
pub const fn assignment_direction(index: u16) -> Option<Direction> {
    match index {
        RX_ASSIGNMENT => Some(Direction::Rx),
        TX_ASSIGNMENT => Some(Direction::Tx),
        _ => None,
    }
}

/// The assignment object that lists PDOs of `direction`.
pub const fn assignment_index(direction: Direction) -> u16 {
    match direction {
        Direction::Rx => RX_ASSIGNMENT,
        Direction::Tx => TX_ASSIGNMENT,
    }
}

/// Bytes a PDO of `bits` occupies (rounded up to whole bytes).
pub const fn bytes_for_bits(bits: u32) -> u32 {
    bits.div_ceil(8)
}

/// One mapping entry as stored in a mapping object (CiA 301 §7.4.7.1 Figure 70).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MapEntry {
    /// Index of the mapped object (0x0001..0x0007 for a dummy entry, 0 for an EtherCAT gap).
    pub index: u16,
    /// Sub-index of the mapped object.
    pub sub: u8,
    /// Length of the mapped object in bits.
    pub bits: u8,
}

impl MapEntry {
    /// Decodes the UNSIGNED32 stored in a mapping sub-object.
    pub const fn from_raw(raw: u32) -> Self {
        let [bits, sub, index_low, index_high] = raw.to_le_bytes();
        Self { index: u16::from_le_bytes([index_low, index_high]), sub, bits }
    }

    /// The UNSIGNED32 to store in a mapping sub-object.
    pub const fn raw(self) -> u32 {
        let [index_low, index_high] = self.index.to_le_bytes();
        u32::from_le_bytes([self.bits, self.sub, index_low, index_high])
    }
}

/// What a mapping entry points at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapTarget {
    /// A dictionary entry; its value is copied into or out of the PDO.
    Object(&'static Entry),
    /// A dummy entry (CiA 301 §7.4.7.1: data-type indices 0x0001..0x0007) or an EtherCAT gap (index 0,
    /// ETG.1000.6; Gamma pads with 0x0000_0008, L586-L607): bits the receiver ignores and the sender sends as 0.
    Padding,
}

/// One resolved entry of an enabled mapping.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MappedItem {
    /// The mapped object or padding.
    pub target: MapTarget,
    /// Position of the first bit in the PDO (bit 0 = least significant bit of byte 0).
    pub bit_offset: u32,
    /// Length in bits.
    pub bits: u8,
}

/// Size in bits of a dummy entry: the data type with that index (CiA 301 §7.4.7.1; IDX 6.1.1 Table 6-56).
const fn dummy_bits(index: u16) -> Option<u8> {
    match index {
        0x0001 => Some(1),
        0x0002 | 0x0005 => Some(8),
        0x0003 | 0x0006 => Some(16),
        0x0004 | 0x0007 => Some(32),
        _ => None,
    }
}

/// Resolves one mapping entry for a PDO of `direction`, checking it as CiA 301 step 3 requires:
/// - the object must exist, else 0x0602_0000 (also for a missing sub-index: CiA 301 names only this code here);
/// - it must be mappable in this direction (the IDX PDO flag, 6.1.4), else 0x0604_0041;
/// - the stated length must equal the object's size, else 0x0604_0043 (zencan returns "general parameter
///   incompatibility" for a length it cannot map, `try_create_mapping_entry`; CANopenNode returns 0x0604_0041);
/// - dummy entries 0x0001..0x0007 must state their type's length, an EtherCAT gap (index 0, sub 0) any non-zero
///   length.
pub fn resolve(table: &Table, entry: MapEntry, direction: Direction) -> Result<MapTarget, SdoAbort> {
    if entry.sub == 0 {
        if entry.index == 0 {
            return if entry.bits == 0 { Err(SdoAbort::ParameterIncompatibility) } else { Ok(MapTarget::Padding) };
        }
        if let Some(bits) = dummy_bits(entry.index) {
            return if bits == entry.bits { Ok(MapTarget::Padding) } else { Err(SdoAbort::ParameterIncompatibility) };
        }
    }
    let object = table.find(entry.index, entry.sub).map_err(|_| SdoAbort::ObjectDoesNotExist)?;
    let mappable = match direction {
        Direction::Rx => object.pdo().rx(),
        Direction::Tx => object.pdo().tx(),
    };
    match object.bit_size() {
        Some(_) if !mappable => Err(SdoAbort::CannotBeMapped),
        None => Err(SdoAbort::CannotBeMapped),
        Some(bits) if bits == u16::from(entry.bits) => Ok(MapTarget::Object(object)),
        Some(_) => Err(SdoAbort::ParameterIncompatibility),
    }
}

/// The mapping entry stored at `index:sub`, if that sub-object exists and is an UNSIGNED32 in RAM.
fn stored_entry(table: &Table, bytes: &[u8], index: u16, sub: u8) -> Option<MapEntry> {
    let entry = table.find(index, sub).ok()?;
    if entry.data_type != DataType::Unsigned32 {
        return None;
    }
    let raw = u32::try_from(values::unsigned(bytes, entry)?).ok()?;
    Some(MapEntry::from_raw(raw))
}

/// The value of sub-index 0 of `index` (number of mapped objects or assigned PDOs), if it is in RAM.
pub fn count(table: &Table, bytes: &[u8], index: u16) -> Option<u8> {
    let entry = table.find(index, 0).ok()?;
    u8::try_from(values::unsigned(bytes, entry)?).ok()
}

/// Checks entries 1..=`count` of mapping object `index` as a whole (CiA 301 step 4) and returns the mapped length
/// in bits. A missing sub-object within 1..=count gives 0x0604_0042 (more objects than the PDO can hold, as
/// CANopenNode answers for a count above its maximum); an invalid entry gives its [`resolve`] code.
pub fn check_mapping(table: &Table, bytes: &[u8], index: u16, count: u8) -> Result<u32, SdoAbort> {
    let direction = mapping_direction(index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    let mut bits: u32 = 0;
    for sub in 1..=count {
        let entry = stored_entry(table, bytes, index, sub).ok_or(SdoAbort::PdoLengthExceeded)?;
        resolve(table, entry, direction)?;
        bits = bits.saturating_add(u32::from(entry.bits));
    }
    Ok(bits)
}

/// Length in bits of the enabled part of mapping `index` (entries 1..=sub 0), validated.
pub fn mapping_bits(table: &Table, bytes: &[u8], index: u16) -> Result<u32, SdoAbort> {
    let count = count(table, bytes, index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    check_mapping(table, bytes, index, count)
}

/// Decodes the enabled entries of mapping object `index` after validating them as a whole; the PDO code walks
/// the result to pack or unpack a PDO. Fails with the code [`check_mapping`] gives (a stored mapping can be
/// invalid only if it came from outside the access layer, e.g. an old parameter image).
pub fn mapping<'a>(table: &Table, bytes: &'a [u8], index: u16) -> Result<Mapping<'a>, SdoAbort> {
    let count = count(table, bytes, index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    let total_bits = check_mapping(table, bytes, index, count)?;
    let direction = mapping_direction(index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    Ok(Mapping { table: *table, bytes, index, direction, count, next_sub: 1, bit_offset: 0, total_bits })
}

/// The validated, enabled entries of one mapping object; an iterator of [`MappedItem`]s in PDO order.
#[derive(Clone, Debug)]
pub struct Mapping<'a> {
    table: Table,
    bytes: &'a [u8],
    index: u16,
    direction: Direction,
    count: u8,
    next_sub: u8,
    bit_offset: u32,
    total_bits: u32,
}

impl Mapping<'_> {
    /// Total mapped length in bits.
    pub const fn total_bits(&self) -> u32 {
        self.total_bits
    }

    /// Total mapped length in bytes (rounded up).
    pub const fn total_bytes(&self) -> u32 {
        bytes_for_bits(self.total_bits)
    }

    /// Number of mapped entries.
    pub const fn len(&self) -> u8 {
        self.count
    }

    /// Whether no entry is mapped (the PDO is disabled).
    pub const fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The PDO's direction.
    pub const fn direction(&self) -> Direction {
        self.direction
    }
}

impl Iterator for Mapping<'_> {
    type Item = MappedItem;

    fn next(&mut self) -> Option<MappedItem> {
        if self.next_sub == 0 || self.next_sub > self.count {
            return None;
        }
        let sub = self.next_sub;
        // Wraps to 0 after sub 255, which the check above treats as the end.
        self.next_sub = self.next_sub.wrapping_add(1);
        let entry = stored_entry(&self.table, self.bytes, self.index, sub)?;
        let target = resolve(&self.table, entry, self.direction).ok()?;
        let item = MappedItem { target, bit_offset: self.bit_offset, bits: entry.bits };
        self.bit_offset = self.bit_offset.saturating_add(u32::from(entry.bits));
        Some(item)
    }
}

/// Checks that a value stored in an assignment entry names a mapping object of `direction` that exists
/// (0 = unused is accepted by the caller); else 0x0609_0030.
fn check_assigned(table: &Table, mapping_index: u16, direction: Direction) -> Result<(), SdoAbort> {
    if mapping_direction(mapping_index) != Some(direction) || table.entries_of(mapping_index).is_empty() {
        return Err(SdoAbort::InvalidValue);
    }
    Ok(())
}

/// The PDO named by assignment entry `index:sub` (0 = unused), if that sub-object exists and fits a `u16`.
fn stored_assignment(table: &Table, bytes: &[u8], index: u16, sub: u8) -> Option<u16> {
    let entry = table.find(index, sub).ok()?;
    u16::try_from(values::unsigned(bytes, entry)?).ok()
}

/// Checks entries 1..=`count` of assignment object `index` as a whole and returns the total length in bits of
/// the PDOs they assign. `replacing` = (mapping index, bits) stands in for that mapping's stored length (used
/// while a mapping is being re-enabled). Entries must be 0 or name an existing mapping object of the assignment's
/// direction (else 0x0609_0030); a missing sub-object within 1..=count gives 0x0609_0031.
pub fn check_assignment(
    table: &Table,
    bytes: &[u8],
    index: u16,
    count: u8,
    replacing: Option<(u16, u32)>,
) -> Result<u32, SdoAbort> {
    let direction = assignment_direction(index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    let mut bits: u32 = 0;
    for sub in 1..=count {
        let pdo = stored_assignment(table, bytes, index, sub).ok_or(SdoAbort::ValueTooHigh)?;
        if pdo == 0 {
            continue;
        }
        check_assigned(table, pdo, direction)?;
        let pdo_bits = match replacing {
            Some((mapping_index, replaced)) if mapping_index == pdo => replaced,
            _ => mapping_bits(table, bytes, pdo)?,
        };
        bits = bits.saturating_add(pdo_bits);
    }
    Ok(bits)
}

/// The mapping objects assigned by assignment object `index` (entries 1..=sub 0, unused entries skipped).
pub fn assignment<'a>(table: &Table, bytes: &'a [u8], index: u16) -> Result<Assignment<'a>, SdoAbort> {
    assignment_direction(index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    let count = count(table, bytes, index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    Ok(Assignment { table: *table, bytes, index, count, next_sub: 1 })
}

/// The mapping objects an assignment lists; an iterator of mapping indices.
#[derive(Clone, Debug)]
pub struct Assignment<'a> {
    table: Table,
    bytes: &'a [u8],
    index: u16,
    count: u8,
    next_sub: u8,
}

impl Iterator for Assignment<'_> {
    type Item = u16;

    fn next(&mut self) -> Option<u16> {
        loop {
            if self.next_sub == 0 || self.next_sub > self.count {
                return None;
            }
            let sub = self.next_sub;
            self.next_sub = self.next_sub.wrapping_add(1);
            match stored_assignment(&self.table, self.bytes, self.index, sub)? {
                0 => continue,
                pdo => return Some(pdo),
            }
        }
    }
}

/// The whole-object checks a write of `value` to `entry` must pass before it is stored, for mapping and
/// assignment objects (every other entry passes). `bytes` is the value storage before the write;
/// `max_pdo_bytes` the bus's PDO length limit (IDX L2196: 8 bytes on CANopen, 40 on EtherCAT).
/// - mapping or assignment entry 1..n while sub 0 is not 0: 0x0601_0000 (CANopenNode `OD_write_PDO_mapping`);
/// - mapping entry: [`resolve`] (0 = empty entry is accepted);
/// - assignment entry: 0 or an existing mapping object of the right direction, else 0x0609_0030;
/// - mapping sub 0 = n > 0: [`check_mapping`]; total above the limit: 0x0604_0042, also when the mapping is
///   assigned and the assignment's total would exceed the limit;
/// - assignment sub 0 = n > 0: [`check_assignment`]; total above the limit: 0x0604_0042.
pub fn check_write(table: &Table, bytes: &[u8], entry: &Entry, value: u64, max_pdo_bytes: u16) -> Result<(), SdoAbort> {
    let limit = u32::from(max_pdo_bytes);
    if let Some(direction) = mapping_direction(entry.index) {
        if entry.sub == 0 {
            if entry.data_type != DataType::Unsigned8 {
                return Ok(());
            }
            let count = u8::try_from(value).map_err(|_| SdoAbort::ValueTooHigh)?;
            if count == 0 {
                return Ok(());
            }
            let bits = check_mapping(table, bytes, entry.index, count)?;
            if bytes_for_bits(bits) > limit {
                return Err(SdoAbort::PdoLengthExceeded);
            }
            let assignment = assignment_index(direction);
            if let Some(assigned) = self::count(table, bytes, assignment).filter(|n| *n > 0) {
                let is_assigned =
                    (1..=assigned).any(|sub| stored_assignment(table, bytes, assignment, sub) == Some(entry.index));
                if is_assigned {
                    let total = check_assignment(table, bytes, assignment, assigned, Some((entry.index, bits)))?;
                    if bytes_for_bits(total) > limit {
                        return Err(SdoAbort::PdoLengthExceeded);
                    }
                }
            }
            Ok(())
        } else {
            if entry.data_type != DataType::Unsigned32 {
                return Ok(());
            }
            if count(table, bytes, entry.index).unwrap_or(0) != 0 {
                return Err(SdoAbort::UnsupportedAccess);
            }
            let raw = u32::try_from(value).map_err(|_| SdoAbort::ValueTooHigh)?;
            if raw != 0 {
                resolve(table, MapEntry::from_raw(raw), direction)?;
            }
            Ok(())
        }
    } else if let Some(direction) = assignment_direction(entry.index) {
        if entry.sub == 0 {
            let count = u8::try_from(value).map_err(|_| SdoAbort::ValueTooHigh)?;
            if count == 0 {
                return Ok(());
            }
            let bits = check_assignment(table, bytes, entry.index, count, None)?;
            if bytes_for_bits(bits) > limit {
                return Err(SdoAbort::PdoLengthExceeded);
            }
            Ok(())
        } else {
            if count(table, bytes, entry.index).unwrap_or(0) != 0 {
                return Err(SdoAbort::UnsupportedAccess);
            }
            let pdo = u16::try_from(value).map_err(|_| SdoAbort::InvalidValue)?;
            if pdo != 0 {
                check_assigned(table, pdo, direction)?;
            }
            Ok(())
        }
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_entry_layout_matches_cia_301() {
        // 0x60400010 = 0x6040:00, 16 bit (object-dictionary.md §6).
        let entry = MapEntry::from_raw(0x6040_0010);
        assert_eq!(entry, MapEntry { index: 0x6040, sub: 0, bits: 16 });
        assert_eq!(entry.raw(), 0x6040_0010);
        assert_eq!(MapEntry::from_raw(0x60FE_0120), MapEntry { index: 0x60FE, sub: 1, bits: 32 });
    }

    #[test]
    fn directions() {
        assert_eq!(mapping_direction(0x1600), Some(Direction::Rx));
        assert_eq!(mapping_direction(0x17FF), Some(Direction::Rx));
        assert_eq!(mapping_direction(0x1A00), Some(Direction::Tx));
        assert_eq!(mapping_direction(0x1BFF), Some(Direction::Tx));
        assert_eq!(mapping_direction(0x1800), None);
        assert_eq!(assignment_direction(0x1C12), Some(Direction::Rx));
        assert_eq!(assignment_direction(0x1C13), Some(Direction::Tx));
        assert_eq!(assignment_direction(0x1C32), None);
        assert_eq!(bytes_for_bits(0), 0);
        assert_eq!(bytes_for_bits(1), 1);
        assert_eq!(bytes_for_bits(320), 40);
        assert_eq!(bytes_for_bits(321), 41);
    }
}
