//! The validated device description: what every emitter (Rust tables, EDS, ESI, SII, Markdown) reads.
//!
//! `description.rs` parses the TOML into raw records; `validate.rs` checks them and builds this model, with
//! `repeat` sub-objects expanded, objects sorted by index and sub-objects by sub-index. Emitters may rely on
//! every invariant `validate.rs` checks (unique indices, sub 0 present for ARRAY/RECORD, defaults within limits).

/// Identity and fieldbus facts of the device (`[device]` in the description).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Device {
    /// Vendor name (ESI `Vendor/Name`, EDS `VendorName`).
    pub vendor_name: String,
    /// Vendor ID (0x1018:01).
    pub vendor_id: u32,
    /// Product code (0x1018:02).
    pub product_code: u32,
    /// Revision number (0x1018:03).
    pub revision: u32,
    /// Serial number written into the SII (0x1018:04 is filled at run time).
    pub serial_number: u32,
    /// Device name (0x1008).
    pub device_name: String,
    /// Hardware version (0x1009).
    pub hardware_version: String,
    /// Software version (0x100A).
    pub software_version: String,
    /// ESI group name.
    pub group_name: String,
    /// Order code (EDS `ProductName`, ESI `Type`).
    pub order_code: String,
    /// Device type (0x1000).
    pub device_type: u32,
    /// Default CANopen node-ID.
    pub node_id: u8,
    /// Default CAN bit rate in kbit/s.
    pub bit_rate_kbit: u16,
    /// SM0 (mailbox master to slave) physical start address.
    pub mailbox_out_start: u16,
    /// SM0 size in bytes.
    pub mailbox_out_size: u16,
    /// SM1 (mailbox slave to master) physical start address.
    pub mailbox_in_start: u16,
    /// SM1 size in bytes.
    pub mailbox_in_size: u16,
    /// SM2 (process data outputs) physical start address.
    pub process_out_start: u16,
    /// SM3 (process data inputs) physical start address.
    pub process_in_start: u16,
    /// Longest PDO on EtherCAT, in bytes.
    pub max_pdo_bytes_ethercat: u16,
    /// Longest PDO on CANopen, in bytes.
    pub max_pdo_bytes_canopen: u16,
}

/// CiA 301 object code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ObjectCode {
    /// 0x07.
    Var,
    /// 0x08.
    Array,
    /// 0x09.
    Record,
}

/// CiA 301 data type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    /// 0x0001.
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
    /// 0x0009.
    VisibleString,
    /// 0x000A.
    OctetString,
    /// 0x000F.
    Domain,
}

impl DataType {
    /// CiA 301 data-type index.
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

    /// Size in bytes for fixed-size types.
    pub const fn fixed_size(self) -> Option<usize> {
        match self {
            Self::Boolean | Self::Integer8 | Self::Unsigned8 => Some(1),
            Self::Integer16 | Self::Unsigned16 => Some(2),
            Self::Integer32 | Self::Unsigned32 => Some(4),
            Self::Integer64 | Self::Unsigned64 => Some(8),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }

    /// Inclusive value range of an integer type (BOOLEAN is 0..=1); `None` for strings and domains.
    pub const fn range(self) -> Option<(i128, i128)> {
        match self {
            Self::Boolean => Some((0, 1)),
            Self::Integer8 => Some((i8::MIN as i128, i8::MAX as i128)),
            Self::Integer16 => Some((i16::MIN as i128, i16::MAX as i128)),
            Self::Integer32 => Some((i32::MIN as i128, i32::MAX as i128)),
            Self::Integer64 => Some((i64::MIN as i128, i64::MAX as i128)),
            Self::Unsigned8 => Some((0, u8::MAX as i128)),
            Self::Unsigned16 => Some((0, u16::MAX as i128)),
            Self::Unsigned32 => Some((0, u32::MAX as i128)),
            Self::Unsigned64 => Some((0, u64::MAX as i128)),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }

    /// The name the description, the EDS comments and the object reference use (`UNSIGNED16`, ...).
    pub const fn cia_name(self) -> &'static str {
        match self {
            Self::Boolean => "BOOLEAN",
            Self::Integer8 => "INTEGER8",
            Self::Integer16 => "INTEGER16",
            Self::Integer32 => "INTEGER32",
            Self::Integer64 => "INTEGER64",
            Self::Unsigned8 => "UNSIGNED8",
            Self::Unsigned16 => "UNSIGNED16",
            Self::Unsigned32 => "UNSIGNED32",
            Self::Unsigned64 => "UNSIGNED64",
            Self::VisibleString => "VISIBLE_STRING",
            Self::OctetString => "OCTET_STRING",
            Self::Domain => "DOMAIN",
        }
    }

    /// Whether values of this type are two's-complement signed integers.
    pub const fn is_signed(self) -> bool {
        matches!(self, Self::Integer8 | Self::Integer16 | Self::Integer32 | Self::Integer64)
    }

    /// Whether this is an integer type (BOOLEAN included): the types `min`, `max` and `values` apply to.
    pub const fn is_integer(self) -> bool {
        self.range().is_some()
    }

    /// Length in bits of a PDO mapping entry for this type (BOOLEAN maps as 1 bit), or `None` for types that
    /// cannot be mapped (strings, domains).
    pub const fn pdo_bits(self) -> Option<u16> {
        match self {
            Self::Boolean => Some(1),
            Self::Integer8 | Self::Unsigned8 => Some(8),
            Self::Integer16 | Self::Unsigned16 => Some(16),
            Self::Integer32 | Self::Unsigned32 => Some(32),
            Self::Integer64 | Self::Unsigned64 => Some(64),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }
}

/// Access type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Access {
    /// `ro`.
    ReadOnly,
    /// `wo`.
    WriteOnly,
    /// `rw`.
    ReadWrite,
    /// `const`.
    Const,
}

/// PDO mapping direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Pdo {
    /// Not mappable.
    No,
    /// RxPDO (master to drive).
    Rx,
    /// TxPDO (drive to master).
    Tx,
    /// Both directions.
    Both,
}

impl Access {
    /// Whether an SDO download may write the entry.
    pub const fn writable(self) -> bool {
        matches!(self, Self::WriteOnly | Self::ReadWrite)
    }

    /// The word the description uses (`ro`, `wo`, `rw`, `const`).
    pub const fn word(self) -> &'static str {
        match self {
            Self::ReadOnly => "ro",
            Self::WriteOnly => "wo",
            Self::ReadWrite => "rw",
            Self::Const => "const",
        }
    }
}

impl Pdo {
    /// Whether the entry may be mapped into a receive PDO.
    pub const fn rx(self) -> bool {
        matches!(self, Self::Rx | Self::Both)
    }

    /// Whether the entry may be mapped into a transmit PDO.
    pub const fn tx(self) -> bool {
        matches!(self, Self::Tx | Self::Both)
    }

    /// The word the description uses (`no`, `rx`, `tx`, `both`).
    pub const fn word(self) -> &'static str {
        match self {
            Self::No => "no",
            Self::Rx => "rx",
            Self::Tx => "tx",
            Self::Both => "both",
        }
    }
}

/// When writes are accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WriteCondition {
    /// `always`.
    Always,
    /// `pre-op`.
    PreOperational,
    /// `power-disabled`.
    PowerDisabled,
    /// `pre-op-power-disabled`.
    PreOperationalPowerDisabled,
}

impl WriteCondition {
    /// The word the description uses (`always`, `pre-op`, ...).
    pub const fn word(self) -> &'static str {
        match self {
            Self::Always => "always",
            Self::PreOperational => "pre-op",
            Self::PowerDisabled => "power-disabled",
            Self::PreOperationalPowerDisabled => "pre-op-power-disabled",
        }
    }
}

/// Where the value lives in the firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StorageKind {
    /// In RAM value storage.
    Ram,
    /// A constant in flash.
    Const,
    /// Served by the application.
    Application,
}

impl StorageKind {
    /// The word the description uses (`ram`, `const`, `application`).
    pub const fn word(self) -> &'static str {
        match self {
            Self::Ram => "ram",
            Self::Const => "const",
            Self::Application => "application",
        }
    }
}

/// Area of the index space an object belongs to (CiA 301 7.4.1, Table 43).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Area {
    /// 0x1000..0x1FFF: communication profile area.
    Communication,
    /// 0x2000..0x5FFF: manufacturer-specific profile area.
    Manufacturer,
    /// 0x6000..0x9FFF: standardised device profile area (CiA 402).
    DeviceProfile,
    /// 0xA000..0xFFFF: interface profile and reserved areas.
    Other,
}

impl Area {
    /// Every area, in index order.
    pub const ALL: [Area; 4] = [Area::Communication, Area::Manufacturer, Area::DeviceProfile, Area::Other];

    /// The area `index` lies in (indices below 0x1000 are counted as communication; validation rejects them).
    pub const fn of(index: u16) -> Self {
        match index {
            0x0000..=0x1FFF => Self::Communication,
            0x2000..=0x5FFF => Self::Manufacturer,
            0x6000..=0x9FFF => Self::DeviceProfile,
            _ => Self::Other,
        }
    }

    /// Human-readable title with the index range.
    pub const fn title(self) -> &'static str {
        match self {
            Self::Communication => "Communication profile area (0x1000..0x1FFF)",
            Self::Manufacturer => "Manufacturer-specific area (0x2000..0x5FFF)",
            Self::DeviceProfile => "Device profile area (0x6000..0x9FFF)",
            Self::Other => "Interface profile and reserved areas (0xA000..0xFFFF)",
        }
    }
}

/// A default value.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Value {
    /// An integer (also BOOLEAN 0/1).
    Int(i128),
    /// Text for VISIBLE_STRING / OCTET_STRING.
    Text(String),
    /// `$NODEID+offset`: the node-ID plus this offset.
    NodeIdPlus(i128),
    /// No default (DOMAIN, application-served entries).
    None,
}

/// One sub-object, after `repeat` expansion.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SubObject {
    /// Sub-index.
    pub sub: u8,
    /// Name (for a VAR, the object's name).
    pub name: String,
    /// Data type.
    pub data_type: DataType,
    /// Access type.
    pub access: Access,
    /// PDO mapping direction.
    pub pdo: Pdo,
    /// Default value.
    pub default: Value,
    /// Lowest value a write accepts.
    pub min: Option<i128>,
    /// Highest value a write accepts.
    pub max: Option<i128>,
    /// The only values a write accepts, sorted ascending.
    pub values: Option<Vec<i128>>,
    /// Capacity in bytes of a string (`None` for other types).
    pub length: Option<usize>,
    /// Unit text.
    pub unit: Option<String>,
    /// Stored by 0x1010 "save".
    pub persistent: bool,
    /// When writes are accepted.
    pub writable_in: WriteCondition,
    /// Where the value lives.
    pub storage: StorageKind,
    /// Name of the typed handle to generate, if any.
    pub handle: Option<String>,
    /// One-line description.
    pub description: Option<String>,
}

/// One object (index).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Object {
    /// Index.
    pub index: u16,
    /// Name.
    pub name: String,
    /// Object code.
    pub code: ObjectCode,
    /// One-line description.
    pub description: String,
    /// Where the object is defined (seed and line).
    pub source: String,
    /// Why a choice was made, where vendors disagree.
    pub note: Option<String>,
    /// Sub-objects sorted by sub-index; a VAR has exactly one, at sub 0.
    pub subs: Vec<SubObject>,
}

/// The whole validated description.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Description {
    /// Device facts.
    pub device: Device,
    /// Objects sorted by index.
    pub objects: Vec<Object>,
}

impl Description {
    /// The object at `index`, if declared.
    pub fn object(&self, index: u16) -> Option<&Object> {
        self.objects.binary_search_by_key(&index, |o| o.index).ok().and_then(|i| self.objects.get(i))
    }

    /// The sub-object at (`index`, `sub`), if declared.
    pub fn entry(&self, index: u16, sub: u8) -> Option<&SubObject> {
        self.object(index).and_then(|o| o.subs.iter().find(|s| s.sub == sub))
    }
}
