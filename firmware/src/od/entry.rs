//! The shape of one dictionary entry, as od-gen emits it into the generated table.
//!
//! These types are the contract between `od-gen` (which writes `static` tables of them into OUT_DIR) and the
//! access layer (which reads and writes values through them). The attribute vocabulary (object code, data type,
//! access, PDO mapping, write condition; IDX firmware specification 6.1.1..6.1.4) is defined once, in the
//! `od-types` crate both sides use, and re-exported here; the entry's firmware-side shape (limits, storage,
//! handles) is defined here.

use core::marker::PhantomData;

pub use od_types::{Access, DataType, ObjectCode, PdoMapping, WriteCondition};

/// The value range a write must fall in (CiA 301 aborts 0x0609_0030..0x0609_0032 when it does not).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Limits {
    /// Any value the data type can hold.
    None,
    /// Inclusive range for a signed type.
    Signed {
        /// Lowest accepted value.
        min: i64,
        /// Highest accepted value.
        max: i64,
    },
    /// Inclusive range for an unsigned type.
    Unsigned {
        /// Lowest accepted value.
        min: u64,
        /// Highest accepted value.
        max: u64,
    },
    /// Only these values are accepted (option codes such as 0x605A); sorted ascending.
    OneOf(&'static [i64]),
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
    },
    /// A constant in flash (device name, version strings, constant identity fields). A thin reference to the
    /// bytes' slice: 4 bytes instead of the slice's 8, which makes `Storage` 8 bytes instead of 12 in each of the
    /// several hundred entries, for 8 bytes of slice per constant.
    Const(&'static &'static [u8]),
    /// Read and written by the application (program data 0x1F50, store/restore signatures 0x1010/0x1011):
    /// the access layer checks permissions and sizes, then hands the transfer to the application.
    Application,
}

impl Storage {
    /// The bytes of a constant entry, `None` for the others.
    #[must_use]
    pub const fn constant(self) -> Option<&'static [u8]> {
        match self {
            Self::Const(bytes) => Some(*bytes),
            Self::Ram { .. } | Self::Application => None,
        }
    }
}

/// The name of an object or entry: its place in the generated text of every name, `NAMES` (od-gen writes each
/// name once, and a name that is part of another one not at all). Three bytes instead of a `&str`'s eight in each
/// entry and object; the CANopen image, which serves no names, has an empty `NAMES` and every name empty.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Name([u8; 3]);

impl Name {
    /// The empty name.
    pub const EMPTY: Self = Self::new(0, 0);

    /// The `len` bytes at `offset` in `NAMES`. Only generated code and tests create names.
    pub const fn new(offset: u16, len: u8) -> Self {
        let [lo, hi] = offset.to_le_bytes();
        Self([lo, hi, len])
    }

    /// The text, empty when it lies outside `NAMES` (never for a generated name).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        let [lo, hi, len] = self.0;
        let start = usize::from(u16::from_le_bytes([lo, hi]));
        super::generated::NAMES.get(start..start.saturating_add(usize::from(len))).unwrap_or("")
    }
}

impl core::fmt::Display for Name {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One sub-object of the dictionary. The generated table holds one per (index, sub-index), sorted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Object index.
    pub index: u16,
    /// Sub-index (0 for a VAR).
    pub sub: u8,
    /// Name of the sub-object (for a VAR, the object's name). The object code is the object's ([`Object`]).
    pub name: Name,
    /// Data type of the value.
    pub data_type: DataType,
    /// Access type.
    pub access: Access,
    /// PDO mapping direction.
    pub pdo: PdoMapping,
    /// Whether 0x1010 "save" stores the value (IDX Backup flag).
    pub persistent: bool,
    /// When writes are accepted.
    pub write_condition: WriteCondition,
    /// Range for writes. A reference: most entries share a few ranges, and a 4-byte pointer instead of the
    /// 24-byte enum in each of the several hundred entries saves about 8.5 KB of flash (56 to 36 bytes an entry;
    /// the thin [`Storage::Const`], the three-byte [`Name`] and the object code left to [`Object`] then 24).
    pub limits: &'static Limits,
    /// Where the value lives.
    pub storage: Storage,
    /// The default is the declared value plus the node-ID (CiA 301 `$NODEID+` defaults of COB-IDs).
    pub node_id_relative: bool,
}

impl Entry {
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

/// One object (index) of the dictionary: the header row of an ARRAY or RECORD, or a VAR.
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
    /// Position of the object's first entry in the entry table.
    pub first_entry: u16,
    /// Number of entries (sub-objects) the object has in the entry table.
    pub entry_count: u16,
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
