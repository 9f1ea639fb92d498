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

pub use od_types::{Access, DataType, ObjectCode, PdoMapping, WriteCondition};

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
    pub pdo: PdoMapping,
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
