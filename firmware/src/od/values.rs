//! The dictionary's value storage: one byte array holding every RAM entry, little-endian at its generated offset.
//!
//! od-gen lays the RAM entries out in `generated::DEFAULT_VALUES` (ARCHITECTURE convention 7); the control tiers
//! read and write hot values through typed [`Handle`]s without searching the table, the SDO path goes through
//! [`crate::od::access`], and the parameter store persists [`Values::bytes`]. Multi-byte values are
//! little-endian, the CiA 301 §7.1.3 transfer syntax, so the storage bytes are the SDO bytes.

use super::entry::{Entry, Handle, Storage};
use super::generated::{DEFAULT_NONZERO, DEFAULT_NONZERO_MASK, ENTRIES, VALUE_BYTES};

/// A Rust type a typed [`Handle`] can point at: the CiA 301 basic types BOOLEAN, INTEGER8..64 and
/// UNSIGNED8..64 (IDX 6.1.1, Table 6-56), stored little-endian.
pub trait Scalar: Copy + Default {
    /// Size of the value in the storage, in bytes.
    const SIZE: usize;
    /// Decodes a value from exactly [`Scalar::SIZE`] little-endian bytes; `None` for any other length.
    fn from_le(bytes: &[u8]) -> Option<Self>;
    /// Encodes the value into exactly [`Scalar::SIZE`] bytes; does nothing for any other length.
    fn to_le(self, out: &mut [u8]);
}

macro_rules! scalar_int {
    ($($t:ty),*) => {$(
        impl Scalar for $t {
            const SIZE: usize = core::mem::size_of::<$t>();
            fn from_le(bytes: &[u8]) -> Option<Self> {
                bytes.try_into().ok().map(<$t>::from_le_bytes)
            }
            fn to_le(self, out: &mut [u8]) {
                if out.len() == Self::SIZE {
                    out.copy_from_slice(&self.to_le_bytes());
                }
            }
        }
    )*};
}
scalar_int!(u8, u16, u32, u64, i8, i16, i32, i64);

impl Scalar for bool {
    const SIZE: usize = 1;
    /// CiA 301 BOOLEAN: any non-zero byte reads as true (writes through the access layer only store 0 or 1).
    fn from_le(bytes: &[u8]) -> Option<Self> {
        match bytes {
            [b] => Some(*b != 0),
            _ => None,
        }
    }
    fn to_le(self, out: &mut [u8]) {
        if let [b] = out {
            *b = u8::from(self);
        }
    }
}

/// The bytes of a RAM entry inside `bytes` (a value storage), or `None` when the entry is not in RAM or its slot
/// lies outside `bytes` (which a generated table never produces).
pub fn slot<'a>(bytes: &'a [u8], entry: &Entry) -> Option<&'a [u8]> {
    match entry.storage {
        Storage::Ram { offset, len, .. } => bytes.get(usize::from(offset)..)?.get(..usize::from(len)),
        Storage::Const(_) | Storage::Application => None,
    }
}

/// Mutable form of [`slot`].
pub fn slot_mut<'a>(bytes: &'a mut [u8], entry: &Entry) -> Option<&'a mut [u8]> {
    match entry.storage {
        Storage::Ram { offset, len, .. } => bytes.get_mut(usize::from(offset)..)?.get_mut(..usize::from(len)),
        Storage::Const(_) | Storage::Application => None,
    }
}

/// The value of a RAM entry of up to 8 bytes, read little-endian and zero-extended (`None` when it is not in RAM
/// or longer than 8 bytes). Used for mapping and assignment entries and node-ID-relative defaults.
pub fn unsigned(bytes: &[u8], entry: &Entry) -> Option<u64> {
    let raw = slot(bytes, entry)?;
    if raw.len() > 8 {
        return None;
    }
    let mut wide = [0u8; 8];
    wide.get_mut(..raw.len())?.copy_from_slice(raw);
    Some(u64::from_le_bytes(wide))
}

/// Stores the low bytes of `value` little-endian into a RAM entry of up to 8 bytes; `false` if it could not.
pub fn set_unsigned(bytes: &mut [u8], entry: &Entry, value: u64) -> bool {
    match slot_mut(bytes, entry) {
        Some(raw) if raw.len() <= 8 => match value.to_le_bytes().get(..raw.len()) {
            Some(low) => {
                raw.copy_from_slice(low);
                true
            }
            None => false,
        },
        _ => false,
    }
}

/// Reads the value of `handle` from a value storage's bytes ([`Values::get`], and the application objects, which
/// are handed the storage as bytes); a slot outside `bytes` reads as the type's default.
#[inline]
pub fn read_slot<T: Scalar>(bytes: &[u8], handle: Handle<T>) -> T {
    bytes.get(handle.offset()..).and_then(|rest| rest.get(..T::SIZE)).and_then(T::from_le).unwrap_or_default()
}

/// Writes the value of `handle` into a value storage's bytes without checks ([`Values::set`]); a slot outside
/// `bytes` is ignored.
#[inline]
pub fn write_slot<T: Scalar>(bytes: &mut [u8], handle: Handle<T>, value: T) {
    if let Some(slot) = bytes.get_mut(handle.offset()..).and_then(|rest| rest.get_mut(..T::SIZE)) {
        value.to_le(slot);
    }
}

/// The value storage of a dictionary: `N` bytes (by default the generated `VALUE_BYTES`) holding every RAM entry.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Values<const N: usize = VALUE_BYTES> {
    bytes: [u8; N],
}

/// The generated dictionary's defaults, `generated::DEFAULT_VALUES`, built from their sparse form (the mask of
/// the non-zero bytes and those bytes: a third of the flash). Run at boot and by every NMT reset of the CANopen
/// node (`canopen::ids::reset_communication_parameters`), inside tier 3's section of the drive's lock, which holds
/// tier 2 off: so the cost follows the non-zero bytes (about a quarter), not every byte. Each mask byte's set bits
/// are visited lowest first (`trailing_zeros`, then the lowest cleared); a chunk with no non-zero byte costs one
/// test. Visiting every bit of every byte made `Values::new` cost 19,760 instructions in QEMU against 6,634 with
/// the dense table, and in the QEMU bench the node's boot then held tier 2 off long enough for a set-point to be
/// published 5 periods after its raise.
pub fn default_values() -> [u8; VALUE_BYTES] {
    let mut out = [0u8; VALUE_BYTES];
    write_defaults(&mut out);
    out
}

/// Writes the non-zero default bytes into `out`, which must hold zeros ([`default_values`]).
fn write_defaults(out: &mut [u8; VALUE_BYTES]) {
    let mut nonzero = DEFAULT_NONZERO.iter();
    let mut chunk_start = 0usize;
    for &mask in &DEFAULT_NONZERO_MASK {
        let mut bits = u32::from(mask);
        while bits != 0 {
            let at = chunk_start.wrapping_add(bits.trailing_zeros() as usize);
            if let (Some(byte), Some(&value)) = (out.get_mut(at), nonzero.next()) {
                *byte = value;
            }
            // Clears the lowest set bit (`bits` is not zero here).
            bits &= bits.wrapping_sub(1);
        }
        chunk_start = chunk_start.wrapping_add(8);
    }
}

impl Values<VALUE_BYTES> {
    /// The generated dictionary's defaults ([`default_values`]), with `node_id` added to the
    /// node-ID-relative entries (CiA 301 `$NODEID+` defaults, e.g. PDO COB-IDs 0x200 + node-ID, IDX L2032-L2666).
    pub fn new(node_id: u8) -> Self {
        Self::defaults_for(&ENTRIES, node_id)
    }

    /// The generated dictionary's defaults with `node_id` added to the node-ID-relative entries among `entries`, a
    /// part of the generated table (the communication area a reset restores,
    /// `canopen::ids::reset_communication_parameters`), so the rest of the table costs nothing; a node-ID-relative
    /// entry outside `entries` keeps its declared base. Built in place: the storage is not copied once it holds the
    /// defaults.
    pub fn defaults_for(entries: &[Entry], node_id: u8) -> Self {
        let mut values = Self { bytes: [0; VALUE_BYTES] };
        write_defaults(&mut values.bytes);
        values.add_node_id(entries, node_id);
        values
    }
}

impl<const N: usize> Values<N> {
    /// Storage initialised from `defaults` (laid out for `entries`), adding `node_id` to every RAM entry of
    /// `entries` marked `node_id_relative` (wrapping in the entry's width, as a CAN-ID field never carries).
    pub fn from_defaults(defaults: [u8; N], entries: &[Entry], node_id: u8) -> Self {
        let mut values = Self { bytes: defaults };
        values.add_node_id(entries, node_id);
        values
    }

    /// Adds `node_id` to the value of every RAM entry of `entries` marked `node_id_relative` ([`Self::from_defaults`]).
    fn add_node_id(&mut self, entries: &[Entry], node_id: u8) {
        for entry in entries.iter().filter(|e| e.node_id_relative()) {
            if let Some(base) = unsigned(&self.bytes, entry) {
                // Wrapping on purpose: the default is an offset the generator checked to leave room for any
                // node-ID 1..127; wrapping keeps a corrupt table from panicking.
                set_unsigned(&mut self.bytes, entry, base.wrapping_add(u64::from(node_id)));
            }
        }
    }

    /// Storage holding exactly `bytes` (a restored parameter image, or a test fixture).
    pub const fn from_bytes(bytes: [u8; N]) -> Self {
        Self { bytes }
    }

    /// Reads a typed value; no search, no panic. A handle whose slot lies outside the storage (which generated
    /// handles never do) reads as the type's default.
    #[inline]
    pub fn get<T: Scalar>(&self, handle: Handle<T>) -> T {
        read_slot(&self.bytes, handle)
    }

    /// Writes a typed value without the SDO checks (limits, access, state): the control tiers' path for values
    /// they own (actual values, statusword). A slot outside the storage is ignored.
    #[inline]
    pub fn set<T: Scalar>(&mut self, handle: Handle<T>, value: T) {
        write_slot(&mut self.bytes, handle, value);
    }

    /// The whole storage, for the parameter store.
    pub const fn bytes(&self) -> &[u8; N] {
        &self.bytes
    }

    /// The whole storage, mutable, for the parameter store (restoring a saved image).
    pub fn bytes_mut(&mut self) -> &mut [u8; N] {
        &mut self.bytes
    }

    /// The raw bytes of a RAM entry (`None` for constant and application entries).
    pub fn raw(&self, entry: &Entry) -> Option<&[u8]> {
        slot(&self.bytes, entry)
    }

    /// The raw bytes of a RAM entry, mutable, without any check (`None` for constant and application entries).
    pub fn raw_mut(&mut self, entry: &Entry) -> Option<&mut [u8]> {
        slot_mut(&mut self.bytes, entry)
    }

    /// Copies `data` into a RAM entry if it has exactly the entry's capacity; `false` otherwise. No checks.
    pub fn set_raw(&mut self, entry: &Entry, data: &[u8]) -> bool {
        match self.raw_mut(entry) {
            Some(raw) if raw.len() == data.len() => {
                raw.copy_from_slice(data);
                true
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::entry::{Access, Attributes, DataType, LimitsRef, Name, PdoMapping, WriteCondition};

    const fn ram(index: u16, data_type: DataType, offset: u16, len: u16, node_id_relative: bool) -> Entry {
        Entry {
            index,
            sub: 0,
            name: Name::EMPTY,
            data_type,
            attributes: Attributes::new(Access::ReadWrite, PdoMapping::No, false, WriteCondition::Always),
            limits: LimitsRef::NONE,
            storage: Storage::Ram { offset, len, node_id_relative },
        }
    }

    static ENTRIES: [Entry; 3] = [
        ram(0x1400, DataType::Unsigned32, 0, 4, true),
        ram(0x2000, DataType::Unsigned16, 4, 2, false),
        ram(0x2001, DataType::Unsigned8, 6, 1, true),
    ];

    #[test]
    fn sparse_defaults_rebuild_the_generated_storage_exactly() {
        // The image builds its defaults from the mask and the non-zero bytes; every byte must match the table.
        use crate::od::generated::DEFAULT_VALUES;
        assert_eq!(default_values(), DEFAULT_VALUES);
        assert!(DEFAULT_VALUES.iter().any(|&b| b != 0), "the table has non-zero defaults to rebuild");
        assert_eq!(DEFAULT_NONZERO.len(), DEFAULT_VALUES.iter().filter(|&&b| b != 0).count());
    }

    #[test]
    fn node_id_is_added_to_relative_defaults_only() {
        let defaults = [0x00, 0x02, 0x00, 0x00, 0x34, 0x12, 0xFF, 0];
        let values = Values::from_defaults(defaults, &ENTRIES, 5);
        assert_eq!(values.raw(&ENTRIES[0]), Some(&[0x05, 0x02, 0, 0][..]));
        assert_eq!(values.raw(&ENTRIES[1]), Some(&[0x34, 0x12][..]));
        // Wraps within the entry's width instead of panicking.
        assert_eq!(values.raw(&ENTRIES[2]), Some(&[0x04][..]));
    }

    #[test]
    fn typed_handles_read_and_write_little_endian() {
        let mut values = Values::from_bytes([0u8; 16]);
        values.set(Handle::<u32>::new(0), 0x1234_5678);
        assert_eq!(&values.bytes()[..4], &[0x78, 0x56, 0x34, 0x12]);
        assert_eq!(values.get(Handle::<u32>::new(0)), 0x1234_5678);
        values.set(Handle::<i16>::new(4), -2);
        assert_eq!(values.get(Handle::<i16>::new(4)), -2);
        values.set(Handle::<bool>::new(6), true);
        assert!(values.get(Handle::<bool>::new(6)));
        values.set(Handle::<i64>::new(8), i64::MIN);
        assert_eq!(values.get(Handle::<i64>::new(8)), i64::MIN);
    }

    #[test]
    fn handles_outside_the_storage_never_panic() {
        let mut values = Values::from_bytes([0xFFu8; 4]);
        assert_eq!(values.get(Handle::<u32>::new(2)), 0);
        assert_eq!(values.get(Handle::<u64>::new(0)), 0);
        assert_eq!(values.get(Handle::<u8>::new(u16::MAX)), 0);
        values.set(Handle::<u32>::new(1), 0);
        assert_eq!(values.bytes(), &[0xFF; 4]);
    }

    #[test]
    fn raw_access_respects_capacity() {
        let mut values = Values::from_bytes([0u8; 8]);
        assert!(values.set_raw(&ENTRIES[1], &[1, 2]));
        assert!(!values.set_raw(&ENTRIES[1], &[1, 2, 3]));
        assert_eq!(unsigned(values.bytes(), &ENTRIES[1]), Some(0x0201));
        // An entry whose slot lies past the end of the storage is simply absent.
        let far = ram(0x3000, DataType::Unsigned32, 6, 4, false);
        assert_eq!(values.raw(&far), None);
    }
}
