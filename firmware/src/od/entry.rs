//! The shape of one dictionary entry, as od-gen emits it into the generated table.
//!
//! These types are the contract between `od-gen` (which writes `static` tables of them into OUT_DIR) and the
//! access layer (which reads and writes values through them). The attribute vocabulary (object code, data type,
//! access, PDO mapping, write condition; IDX firmware specification 6.1.1..6.1.4) is defined once, in the
//! `od-types` crate both sides use, and re-exported here; the entry's firmware-side shape (limits, storage,
//! handles) is defined here.

use core::marker::PhantomData;

pub use od_types::{Access, DataType, ObjectCode, PdoMapping, WriteCondition};

/// The value range a write must fall in (CiA 301 aborts 0x0609_0030..0x0609_0032 when it does not). 32-bit bounds:
/// no 64-bit entry of the dictionary has limits (od-gen refuses one whose bounds do not fit), and 12 bytes a range
/// instead of 24 keep the table's list small.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Limits {
    /// Any value the data type can hold.
    None,
    /// Inclusive range for a signed type.
    Signed {
        /// Lowest accepted value.
        min: i32,
        /// Highest accepted value.
        max: i32,
    },
    /// Inclusive range for an unsigned type.
    Unsigned {
        /// Lowest accepted value.
        min: u32,
        /// Highest accepted value.
        max: u32,
    },
    /// Only these values are accepted (option codes such as 0x605A); sorted ascending.
    OneOf(&'static [i32]),
}

/// Where an entry's value lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Storage {
    /// In the dictionary's value storage at this byte offset, with this capacity in bytes.
    Ram {
        /// Byte offset into the value storage.
        offset: u16,
        /// Capacity in bytes (the type size, or the maximum length of a string).
        len: u16,
        /// The default is the declared value plus the node-ID (CiA 301 `$NODEID+` defaults of COB-IDs). Only a
        /// RAM value has a default to add to; kept here, beside the tag's byte, it costs the entry no byte.
        node_id_relative: bool,
    },
    /// A constant in flash (device name, version strings, constant identity fields), [`ConstRef`].
    Const(ConstRef),
    /// Read and written by the application (program data 0x1F50, store/restore signatures 0x1010/0x1011):
    /// the access layer checks permissions and sizes, then hands the transfer to the application.
    Application,
}

impl Storage {
    /// The bytes of a constant entry, `None` for the others.
    #[must_use]
    pub const fn constant(self) -> Option<&'static [u8]> {
        match self {
            Self::Const(bytes) => Some(bytes.bytes()),
            Self::Ram { .. } | Self::Application => None,
        }
    }
}

/// The bytes of a constant entry ([`Storage::Const`]). A thin reference to the bytes' slice: 4 bytes instead of the
/// slice's 8, for 8 bytes of slice per constant; packed to 2 bytes, so that `Storage` is 6 bytes instead of 8 (12
/// with the slice) in each of the several hundred entries. Read once per transfer or PDO mapping, never per cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(Rust, packed(2))]
pub struct ConstRef(&'static &'static [u8]);

impl ConstRef {
    /// A constant holding `bytes`.
    pub const fn new(bytes: &'static &'static [u8]) -> Self {
        Self(bytes)
    }

    /// The constant's bytes.
    #[must_use]
    pub const fn bytes(self) -> &'static [u8] {
        self.0
    }
}

/// The name of an object or entry: its place in the generated text of every name, `NAMES` (od-gen writes each
/// name once, and a name that is part of another one not at all). Three bytes instead of a `&str`'s eight in each
/// entry and object. The CANopen image serves no names (build.rs sets `od_no_names`): there `NAMES` is empty
/// and a name takes no bytes at all, which makes an object 4 bytes instead of 8 and an entry 12 instead of 16.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg(not(od_no_names))]
pub struct Name([u8; 3]);

/// The name of an object or entry in an image that serves no names: always empty, no bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg(od_no_names)]
pub struct Name;

impl Name {
    /// The empty name.
    pub const EMPTY: Self = Self::new(0, 0);

    /// The `len` bytes at `offset` in `NAMES`. Only generated code and tests create names.
    #[cfg(not(od_no_names))]
    pub const fn new(offset: u16, len: u8) -> Self {
        let [lo, hi] = offset.to_le_bytes();
        Self([lo, hi, len])
    }

    /// The empty name, whatever the place (the image has no `NAMES` to point into).
    #[cfg(od_no_names)]
    pub const fn new(_offset: u16, _len: u8) -> Self {
        Self
    }

    /// The text, empty when it lies outside `NAMES` (never for a generated name).
    #[cfg(not(od_no_names))]
    #[must_use]
    pub fn as_str(self) -> &'static str {
        let [lo, hi, len] = self.0;
        let start = usize::from(u16::from_le_bytes([lo, hi]));
        super::generated::NAMES.get(start..start.saturating_add(usize::from(len))).unwrap_or("")
    }

    /// The text: always empty in an image without names.
    #[cfg(od_no_names)]
    #[must_use]
    pub fn as_str(self) -> &'static str {
        ""
    }
}

impl core::fmt::Display for Name {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Which [`Limits`] an entry has: its position in the table's list of limits (od-gen's `LIMITS`, where 0 is
/// [`Limits::None`]; [`crate::od::access::Table`]). One byte instead of a 4-byte reference in each of the several
/// hundred entries: the dictionary has a few dozen distinct ranges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LimitsRef(pub u8);

impl LimitsRef {
    /// No limits: position 0 of every list of limits holds [`Limits::None`].
    pub const NONE: Self = Self(0);
}

/// The access type, PDO mapping direction, write condition and backup flag of an entry (IDX 6.1.3, 6.1.4; device.toml
/// `access`, `pdo`, `writable_in`, `persistent`), packed into one byte: bits 0-1 the access type, 2-3 the PDO
/// mapping, 4-5 the write condition, bit 6 the backup flag, bit 7 zero. As four bytes they made an entry 16 bytes
/// in the CAN image instead of 12 (about 2.2 KB over the several hundred entries); each attribute is read once per
/// transfer, PDO mapping or save, never per cycle, and its masks cost a few instructions.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Attributes(u8);

impl Attributes {
    const PDO_SHIFT: u32 = 2;
    const WRITE_CONDITION_SHIFT: u32 = 4;
    const PERSISTENT: u8 = 1 << 6;

    /// The attributes of an entry. Only generated code and tests create them.
    #[must_use]
    pub const fn new(access: Access, pdo: PdoMapping, persistent: bool, write_condition: WriteCondition) -> Self {
        Self(0).with_access(access).with_pdo(pdo).with_persistent(persistent).with_write_condition(write_condition)
    }

    /// Access type.
    #[must_use]
    pub const fn access(self) -> Access {
        match self.0 & 0b11 {
            0 => Access::ReadOnly,
            1 => Access::WriteOnly,
            2 => Access::ReadWrite,
            _ => Access::Const,
        }
    }

    /// PDO mapping direction.
    #[must_use]
    pub const fn pdo(self) -> PdoMapping {
        match (self.0 >> Self::PDO_SHIFT) & 0b11 {
            0 => PdoMapping::No,
            1 => PdoMapping::Rx,
            2 => PdoMapping::Tx,
            _ => PdoMapping::Both,
        }
    }

    /// When writes are accepted.
    #[must_use]
    pub const fn write_condition(self) -> WriteCondition {
        match (self.0 >> Self::WRITE_CONDITION_SHIFT) & 0b11 {
            0 => WriteCondition::Always,
            1 => WriteCondition::PreOperational,
            2 => WriteCondition::PowerDisabled,
            _ => WriteCondition::PreOperationalPowerDisabled,
        }
    }

    /// Whether 0x1010 "save" stores the value (IDX Backup flag).
    #[must_use]
    pub const fn persistent(self) -> bool {
        self.0 & Self::PERSISTENT != 0
    }

    /// The same attributes with another access type.
    #[must_use]
    pub const fn with_access(self, access: Access) -> Self {
        let bits = match access {
            Access::ReadOnly => 0,
            Access::WriteOnly => 1,
            Access::ReadWrite => 2,
            Access::Const => 3,
        };
        Self((self.0 & !0b11) | bits)
    }

    /// The same attributes with another PDO mapping direction.
    #[must_use]
    pub const fn with_pdo(self, pdo: PdoMapping) -> Self {
        let bits: u8 = match pdo {
            PdoMapping::No => 0,
            PdoMapping::Rx => 1,
            PdoMapping::Tx => 2,
            PdoMapping::Both => 3,
        };
        Self((self.0 & !(0b11 << Self::PDO_SHIFT)) | (bits << Self::PDO_SHIFT))
    }

    /// The same attributes with another write condition.
    #[must_use]
    pub const fn with_write_condition(self, write_condition: WriteCondition) -> Self {
        let bits: u8 = match write_condition {
            WriteCondition::Always => 0,
            WriteCondition::PreOperational => 1,
            WriteCondition::PowerDisabled => 2,
            WriteCondition::PreOperationalPowerDisabled => 3,
        };
        Self((self.0 & !(0b11 << Self::WRITE_CONDITION_SHIFT)) | (bits << Self::WRITE_CONDITION_SHIFT))
    }

    /// The same attributes with the backup flag set or cleared.
    #[must_use]
    pub const fn with_persistent(self, persistent: bool) -> Self {
        if persistent {
            Self(self.0 | Self::PERSISTENT)
        } else {
            Self(self.0 & !Self::PERSISTENT)
        }
    }
}

impl core::fmt::Debug for Attributes {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Attributes")
            .field("access", &self.access())
            .field("pdo", &self.pdo())
            .field("persistent", &self.persistent())
            .field("write_condition", &self.write_condition())
            .finish()
    }
}

/// One sub-object of the dictionary. The generated table holds one per (index, sub-index), sorted. Packed to 2
/// bytes: 12 bytes in an image without names (where the name takes none, [`Name`]), 16 with them (12 and 15
/// bytes of fields); the access layer reads entries on no fast path, and the Cortex-M4 loads a word from any
/// half-word address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(Rust, packed(2))]
pub struct Entry {
    /// Object index.
    pub index: u16,
    /// Sub-index (0 for a VAR).
    pub sub: u8,
    /// Name of the sub-object (for a VAR, the object's name). The object code is the object's ([`Object`]).
    pub name: Name,
    /// Data type of the value.
    pub data_type: DataType,
    /// Access type, PDO mapping, write condition and backup flag, one byte ([`Entry::access`], [`Entry::pdo`],
    /// [`Entry::write_condition`], [`Entry::persistent`]).
    pub attributes: Attributes,
    /// Range for writes: a position in the table's list of limits (most entries share a few ranges; the 24-byte
    /// enum in each entry took about 8.5 KB, a 4-byte reference to it 2 KB).
    pub limits: LimitsRef,
    /// Where the value lives.
    pub storage: Storage,
}

impl Entry {
    /// Access type.
    #[must_use]
    pub const fn access(&self) -> Access {
        self.attributes.access()
    }

    /// PDO mapping direction.
    #[must_use]
    pub const fn pdo(&self) -> PdoMapping {
        self.attributes.pdo()
    }

    /// When writes are accepted.
    #[must_use]
    pub const fn write_condition(&self) -> WriteCondition {
        self.attributes.write_condition()
    }

    /// Whether 0x1010 "save" stores the value (IDX Backup flag).
    #[must_use]
    pub const fn persistent(&self) -> bool {
        self.attributes.persistent()
    }

    /// Whether the default is the declared value plus the node-ID (CiA 301 `$NODEID+` defaults of COB-IDs): a
    /// mark of RAM storage ([`Storage::Ram`]).
    #[must_use]
    pub const fn node_id_relative(&self) -> bool {
        matches!(self.storage, Storage::Ram { node_id_relative: true, .. })
    }

    /// The limits this entry names in the generated list (`LIMITS`), as the generated table's entries mean them;
    /// [`Limits::None`] for a position outside it. A hand-made table's entries name positions in the table's own
    /// list ([`crate::od::access::Table::limits_of`]).
    #[must_use]
    pub fn generated_limits(&self) -> &'static Limits {
        super::generated::LIMITS.get(usize::from(self.limits.0)).unwrap_or(&Limits::None)
    }

    /// Size of the value in bits as a PDO mapping entry states it, or `None` for types that cannot be mapped.
    pub const fn bit_size(&self) -> Option<u16> {
        match self.data_type.fixed_size() {
            Some(1) if matches!(self.data_type, DataType::Boolean) => Some(1),
            // Fixed sizes are 1..=8 bytes, so the shift cannot overflow.
            Some(n) => Some((n as u16) << 3),
            None => None,
        }
    }
}

/// One object (index) of the dictionary: the header row of an ARRAY or RECORD, or a VAR. 4 bytes in an image
/// without names, 8 with them. Its entries are found by their index ([`crate::od::access::Table::entries_of`], a
/// binary search of the sorted entries), so the object keeps no position or count of them (4 bytes more each).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Object {
    /// Object index.
    pub index: u16,
    /// Name of the object.
    pub name: Name,
    /// VAR, ARRAY or RECORD.
    pub object_code: ObjectCode,
    /// Highest sub-index declared for the object.
    pub max_sub: u8,
}

/// A typed handle to a value in RAM storage, generated for the objects the control tiers read and write, so
/// that they never search the table. `T` is the Rust type of the value (`u16` for an UNSIGNED16, ...).
#[derive(Debug)]
pub struct Handle<T> {
    offset: u16,
    _type: PhantomData<T>,
}

impl<T> Clone for Handle<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Handle<T> {}

impl<T> Handle<T> {
    /// A handle to the value at `offset` in the value storage. Only generated code creates handles.
    pub const fn new(offset: u16) -> Self {
        Self { offset, _type: PhantomData }
    }

    /// Byte offset of the value in the value storage.
    pub const fn offset(self) -> usize {
        self.offset as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_entry_is_its_fields_packed_to_two_bytes() {
        // 12 bytes on the target without names, 16 with them: the node-ID mark sits beside the storage's tag, the
        // limits take a one-byte position and the four attributes one byte (flash: several hundred entries in
        // every image). A wider field or a new one fails here. The storage is its tag byte, the node-ID mark and a
        // thin pointer or two half-words.
        let storage = core::mem::size_of::<Storage>();
        assert_eq!(storage, 2 + core::mem::size_of::<&u8>());
        assert_eq!(core::mem::size_of::<LimitsRef>(), 1);
        assert_eq!(core::mem::size_of::<Attributes>(), 1);
        // index, sub, data type, attributes, limits: 6 bytes; then name and storage.
        let fields = 6 + core::mem::size_of::<Name>() + storage;
        assert_eq!(core::mem::size_of::<Entry>(), fields + fields % 2);
    }

    #[test]
    fn an_object_is_its_index_code_highest_sub_and_name() {
        // 4 bytes on the target without names, 8 with them (several hundred objects in every image): index, object
        // code and highest sub-index, then the name; a new field fails here.
        let fields = 4 + core::mem::size_of::<Name>();
        assert_eq!(core::mem::size_of::<Object>(), fields + fields % 2);
    }

    /// Every combination of the four attributes comes back from its byte as it went in (IDX 6.1.3, 6.1.4: each
    /// one an independent property of the entry), and bit 7 stays clear.
    #[test]
    fn attributes_keep_every_combination_apart() {
        let accesses = [Access::ReadOnly, Access::WriteOnly, Access::ReadWrite, Access::Const];
        let mappings = [PdoMapping::No, PdoMapping::Rx, PdoMapping::Tx, PdoMapping::Both];
        let conditions = [
            WriteCondition::Always,
            WriteCondition::PreOperational,
            WriteCondition::PowerDisabled,
            WriteCondition::PreOperationalPowerDisabled,
        ];
        let mut seen = std::vec::Vec::new();
        for access in accesses {
            for pdo in mappings {
                for condition in conditions {
                    for persistent in [false, true] {
                        let a = Attributes::new(access, pdo, persistent, condition);
                        assert_eq!(
                            (a.access(), a.pdo(), a.write_condition(), a.persistent()),
                            (access, pdo, condition, persistent)
                        );
                        assert_eq!(a.0 & 0x80, 0, "{a:?}");
                        seen.push(a.0);
                    }
                }
            }
        }
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), 128, "each combination has a byte of its own");
    }

    /// Changing one attribute leaves the other three as they were (the hand-made tables of the tests and the
    /// boot image's read-only copies rely on it).
    #[test]
    fn changing_one_attribute_keeps_the_others() {
        let a = Attributes::new(Access::ReadWrite, PdoMapping::Both, true, WriteCondition::PreOperationalPowerDisabled);
        let b = a.with_access(Access::ReadOnly);
        assert_eq!(
            (b.access(), b.pdo(), b.persistent(), b.write_condition()),
            (Access::ReadOnly, a.pdo(), true, a.write_condition())
        );
        let c = a.with_pdo(PdoMapping::No);
        assert_eq!(
            (c.access(), c.pdo(), c.persistent(), c.write_condition()),
            (a.access(), PdoMapping::No, true, a.write_condition())
        );
        let d = a.with_write_condition(WriteCondition::Always);
        assert_eq!(
            (d.access(), d.pdo(), d.persistent(), d.write_condition()),
            (a.access(), a.pdo(), true, WriteCondition::Always)
        );
        let e = a.with_persistent(false);
        assert_eq!(
            (e.access(), e.pdo(), e.persistent(), e.write_condition()),
            (a.access(), a.pdo(), false, a.write_condition())
        );
    }
}
