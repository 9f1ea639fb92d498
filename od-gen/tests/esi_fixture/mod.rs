//! A small hand-built dictionary shared by the EDS, ESI and SII tests: the identity, PDO and sync-manager
//! objects of the drive, plus one object of each kind the emitters treat specially (strings, DOMAIN,
//! `$NODEID` defaults, option lists, manufacturer objects, state-restricted writes).

#![allow(dead_code)]

use od_gen::model::{
    Access, DataType, Description, Device, Object, ObjectCode, PdoMapping, StorageKind, SubObject, Value,
    WriteCondition,
};

/// The `[device]` table of `firmware/device.toml` at the time of writing.
pub fn device() -> Device {
    Device {
        vendor_name: "Open Servo Drive Project".into(),
        vendor_id: 0x0000_0ACE,
        product_code: 0x0001_0001,
        revision: 0x0001_0000,
        serial_number: 0x1234_5678,
        device_name: "OSD-402".into(),
        hardware_version: "STM32F405 reference 1.0".into(),
        software_version: "0.1.0".into(),
        group_name: "Servo drives".into(),
        order_code: "OSD-402-24V-10A".into(),
        device_type: 0x0002_0192,
        node_id: 1,
        bit_rate_kbit: 1000,
        mailbox_out_start: 0x1000,
        mailbox_out_size: 128,
        mailbox_in_start: 0x1080,
        mailbox_in_size: 128,
        process_out_start: 0x1100,
        process_in_start: 0x1180,
        max_pdo_bytes_ethercat: 40,
        max_pdo_bytes_canopen: 8,
    }
}

/// A sub-object with the usual defaults (no PDO, no limits, RAM, always writable).
pub fn sub(sub: u8, name: &str, data_type: DataType, access: Access, default: Value) -> SubObject {
    SubObject {
        sub,
        name: name.into(),
        data_type,
        access,
        pdo: PdoMapping::No,
        default,
        min: None,
        max: None,
        values: None,
        length: None,
        unit: None,
        persistent: false,
        writable_in: WriteCondition::Always,
        storage: if access == Access::Const { StorageKind::Const } else { StorageKind::Ram },
        handle: None,
        description: None,
    }
}

/// A VAR object.
pub fn var(index: u16, name: &str, s: SubObject) -> Object {
    Object {
        index,
        name: name.into(),
        code: ObjectCode::Var,
        description: String::new(),
        source: "test".into(),
        note: None,
        subs: vec![SubObject { name: name.into(), ..s }],
    }
}

/// An ARRAY or RECORD object.
pub fn compound(index: u16, name: &str, code: ObjectCode, subs: Vec<SubObject>) -> Object {
    Object { index, name: name.into(), code, description: String::new(), source: "test".into(), note: None, subs }
}

fn pre_op(mut s: SubObject) -> SubObject {
    s.writable_in = WriteCondition::PreOperational;
    s.persistent = true;
    s
}

/// A PDO mapping record with 8 entries, `mapped` of them set by default.
pub fn mapping(index: u16, name: &str, mapped: &[u32]) -> Object {
    let mut subs = vec![pre_op(SubObject {
        min: Some(0),
        max: Some(8),
        ..sub(0, "Number of mapped objects", DataType::Unsigned8, Access::ReadWrite, Value::Int(mapped.len() as i128))
    })];
    for n in 1..=8u8 {
        let v = mapped.get(usize::from(n) - 1).copied().unwrap_or(0);
        subs.push(pre_op(sub(
            n,
            &format!("Mapped object {n}"),
            DataType::Unsigned32,
            Access::ReadWrite,
            Value::Int(v.into()),
        )));
    }
    compound(index, name, ObjectCode::Record, subs)
}

fn assign(index: u16, name: &str, pdo: u16) -> Object {
    compound(
        index,
        name,
        ObjectCode::Array,
        vec![
            pre_op(SubObject {
                min: Some(0),
                max: Some(1),
                ..sub(0, "Number of assigned PDOs", DataType::Unsigned8, Access::ReadWrite, Value::Int(1))
            }),
            pre_op(SubObject {
                min: Some(0x1600),
                max: Some(0x1A03),
                ..sub(1, "PDO 1", DataType::Unsigned16, Access::ReadWrite, Value::Int(pdo.into()))
            }),
        ],
    )
}

fn mappable(mut s: SubObject, pdo: PdoMapping) -> SubObject {
    s.pdo = pdo;
    s
}

/// The fixture dictionary, objects sorted by index.
pub fn description() -> Description {
    let u8_ = DataType::Unsigned8;
    let u16_ = DataType::Unsigned16;
    let u32_ = DataType::Unsigned32;
    let mut objects = vec![
        var(0x1000, "Device type", sub(0, "", u32_, Access::ReadOnly, Value::Int(0x0002_0192))),
        var(0x1001, "Error register", mappable(sub(0, "", u8_, Access::ReadOnly, Value::Int(0)), PdoMapping::Tx)),
        var(
            0x1008,
            "Manufacturer device name",
            SubObject {
                length: Some(16),
                ..sub(0, "", DataType::VisibleString, Access::Const, Value::Text("OSD-402".into()))
            },
        ),
        compound(
            0x1018,
            "Identity object",
            ObjectCode::Record,
            vec![
                sub(0, "Highest sub-index supported", u8_, Access::Const, Value::Int(4)),
                sub(1, "Vendor ID", u32_, Access::Const, Value::Int(0x0ACE)),
                sub(2, "Product code", u32_, Access::Const, Value::Int(0x0001_0001)),
                sub(3, "Revision number", u32_, Access::Const, Value::Int(0x0001_0000)),
                sub(4, "Serial number", u32_, Access::ReadOnly, Value::Int(0)),
            ],
        ),
        compound(
            0x1400,
            "Receive PDO 1 parameter",
            ObjectCode::Record,
            vec![
                sub(0, "Highest sub-index supported", u8_, Access::Const, Value::Int(2)),
                sub(1, "COB-ID used by RxPDO", u32_, Access::ReadWrite, Value::NodeIdPlus(0x200)),
                sub(2, "Transmission type", u8_, Access::ReadWrite, Value::Int(255)),
            ],
        ),
        mapping(0x1600, "Receive PDO 1 mapping", &[0x6040_0010]),
        mapping(0x1601, "Receive PDO 2 mapping", &[0x6040_0010, 0x607A_0020]),
        mapping(0x1A00, "Transmit PDO 1 mapping", &[0x6041_0010, 0x6064_0020, 0x1001_0008]),
        mapping(0x1A01, "Transmit PDO 2 mapping", &[0x6041_0010]),
        assign(0x1C12, "Sync manager 2 PDO assignment", 0x1600),
        assign(0x1C13, "Sync manager 3 PDO assignment", 0x1A00),
        compound(
            0x1F50,
            "Program data",
            ObjectCode::Array,
            vec![
                sub(0, "Highest sub-index supported", u8_, Access::Const, Value::Int(1)),
                SubObject {
                    storage: StorageKind::Application,
                    ..sub(1, "Program data 1", DataType::Domain, Access::WriteOnly, Value::None)
                },
            ],
        ),
        var(
            0x2000,
            "Node-ID",
            SubObject { min: Some(1), max: Some(127), ..sub(0, "", u8_, Access::ReadWrite, Value::Int(1)) },
        ),
        var(
            0x2100,
            "Custom memory",
            SubObject {
                length: Some(4),
                ..sub(0, "", DataType::OctetString, Access::ReadWrite, Value::Text("AB=;".into()))
            },
        ),
        var(0x6040, "Controlword", mappable(sub(0, "", u16_, Access::ReadWrite, Value::Int(0)), PdoMapping::Rx)),
        var(0x6041, "Statusword", mappable(sub(0, "", u16_, Access::ReadOnly, Value::Int(0)), PdoMapping::Tx)),
        var(
            0x605A,
            "Quick stop option code",
            SubObject {
                values: Some(vec![0, 1, 2, 5, 6]),
                ..sub(0, "", DataType::Integer16, Access::ReadWrite, Value::Int(6))
            },
        ),
        var(
            0x6064,
            "Position actual value",
            mappable(sub(0, "", DataType::Integer32, Access::ReadOnly, Value::Int(0)), PdoMapping::Tx),
        ),
        var(
            0x607A,
            "Target position",
            mappable(
                SubObject {
                    min: Some(-1_000_000),
                    max: Some(1_000_000),
                    ..sub(0, "", DataType::Integer32, Access::ReadWrite, Value::Int(-5))
                },
                PdoMapping::Rx,
            ),
        ),
    ];
    objects.sort_by_key(|o| o.index);
    Description { device: device(), objects }
}
