//! The shape of one dictionary entry, as od-gen emits it into the generated table.
//!
//! These types are the contract between `od-gen` (which writes `static` tables of them into OUT_DIR) and the
//! access layer (which reads and writes values through them). The attribute vocabulary follows the IDX
//! firmware specification 6.1.1..6.1.4 (data types, object codes, access types, PDO and backup flags).

use core::marker::PhantomData;

/// CiA 301 object code (IDX 6.1.2, Table 6-57).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ObjectCode {
    /// A single value at sub-index 0 (0x0007).
    Var,
    /// Sub 0 holds the element count; subs 1..N share one data type (0x0008).
    Array,
    /// Sub 0 holds the highest sub-index; entries may differ in type (0x0009).
    Record,
}

impl ObjectCode {
    /// The code as it appears on the wire (SDO information service) and in an EDS.
    pub const fn code(self) -> u8 {
        match self {
            Self::Var => 0x07,
            Self::Array => 0x08,
            Self::Record => 0x09,
        }
    }
}

/// CiA 301 basic data types (IDX 6.1.1, Table 6-56) plus DOMAIN for program data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataType {
    /// 0x0001, one bit carried in one byte.
    Boolean,
    /// 0x0002.
    Integer8,
    /// 0x0003.
    Integer16,
    /// 0x0004.
    Integer32,
    /// 0x0015.
    Integer64,
    /// 0x0005.
    Unsigned8,
    /// 0x0006.
    Unsigned16,
    /// 0x0007.
    Unsigned32,
    /// 0x001B.
    Unsigned64,
    /// 0x0009, one octet per character.
    VisibleString,
    /// 0x000A, a sequence of octets.
    OctetString,
    /// 0x000F, an application-defined block of arbitrary length (program data 0x1F50).
    Domain,
}

impl DataType {
    /// The CiA 301 data-type index (used in the EDS `DataType` key and by the SDO information service).
    pub const fn code(self) -> u16 {
        match self {
            Self::Boolean => 0x0001,
            Self::Integer8 => 0x0002,
            Self::Integer16 => 0x0003,
            Self::Integer32 => 0x0004,
            Self::Integer64 => 0x0015,
            Self::Unsigned8 => 0x0005,
            Self::Unsigned16 => 0x0006,
            Self::Unsigned32 => 0x0007,
            Self::Unsigned64 => 0x001B,
            Self::VisibleString => 0x0009,
            Self::OctetString => 0x000A,
            Self::Domain => 0x000F,
        }
    }

    /// Size in bytes of a fixed-size type; `None` for strings and domains, whose size is per entry.
    pub const fn fixed_size(self) -> Option<usize> {
        match self {
            Self::Boolean | Self::Integer8 | Self::Unsigned8 => Some(1),
            Self::Integer16 | Self::Unsigned16 => Some(2),
            Self::Integer32 | Self::Unsigned32 => Some(4),
            Self::Integer64 | Self::Unsigned64 => Some(8),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }

    /// Whether values of this type are two's-complement signed integers.
    pub const fn is_signed(self) -> bool {
        matches!(self, Self::Integer8 | Self::Integer16 | Self::Integer32 | Self::Integer64)
    }
}

/// Access type (IDX 6.1.3, Table 6-58).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Read only; the value may change at run time (actual values).
    ReadOnly,
    /// Write only.
    WriteOnly,
    /// Read and write.
    ReadWrite,
    /// Read only, and the value never changes.
    Const,
}

impl Access {
    /// Whether an SDO upload may read the entry.
    pub const fn readable(self) -> bool {
        !matches!(self, Self::WriteOnly)
    }

    /// Whether an SDO download may write the entry.
    pub const fn writable(self) -> bool {
        matches!(self, Self::WriteOnly | Self::ReadWrite)
    }
}

/// PDO mapping flag (IDX 6.1.4): the direction an entry may be mapped into.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PdoMapping {
    /// Not mappable.
    No,
    /// Mappable into a receive PDO (master to drive).
    Rx,
    /// Mappable into a transmit PDO (drive to master).
    Tx,
    /// Mappable in both directions.
    Both,
}

impl PdoMapping {
    /// Whether the entry may be mapped into a receive PDO.
    pub const fn rx(self) -> bool {
        matches!(self, Self::Rx | Self::Both)
    }

    /// Whether the entry may be mapped into a transmit PDO.
    pub const fn tx(self) -> bool {
        matches!(self, Self::Tx | Self::Both)
    }
}

/// When a writable entry accepts writes (IDX notes per object: PDO mappings only in Pre-Operational, axis
/// configuration only with the power stage disabled, restore defaults only in both).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteCondition {
    /// Whenever the entry is writable.
    Always,
    /// Only in the communication state Pre-Operational (NMT or EtherCAT ESM).
    PreOperational,
    /// Only while the power stage is disabled (CiA 402 states before "Operation enabled").
    PowerDisabled,
    /// Only in Pre-Operational with the power stage disabled.
    PreOperationalPowerDisabled,
}

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
    /// A constant in flash (device name, version strings, constant identity fields).
    Const(&'static [u8]),
    /// Read and written by the application (program data 0x1F50, store/restore signatures 0x1010/0x1011):
    /// the access layer checks permissions and sizes, then hands the transfer to the application.
    Application,
}

/// One sub-object of the dictionary. The generated table holds one per (index, sub-index), sorted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Object index.
    pub index: u16,
    /// Sub-index (0 for a VAR).
    pub sub: u8,
    /// Name of the sub-object (for a VAR, the object's name).
    pub name: &'static str,
    /// Object code of the object this entry belongs to.
    pub object_code: ObjectCode,
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
    /// Range for writes.
    pub limits: Limits,
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
    pub name: &'static str,
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
