//! Shared helpers of the dictionary access tests (`od_access.rs`, `od_properties.rs`): contexts, an application
//! stand-in for the entries the firmware serves itself, and oracles that restate the access rules of
//! `firmware::od::access` (CiA 301 §7.2.4.3, Table 22) independently of the implementation.
#![allow(dead_code)]

use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, ApplicationObjects, CommState, Dictionary, ReadOutcome};
use firmware::od::entry::{DataType, Entry, Limits, Storage};
use firmware::od::generated::{self, ENTRIES, MAX_PDO_BYTES_CANOPEN, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::pdo_map;

/// The EtherCAT PDO length limit (IDX L2196), as the access context carries it.
pub fn ethercat_limit() -> u16 {
    u16::try_from(MAX_PDO_BYTES_ETHERCAT).expect("limit fits u16")
}

/// The CANopen PDO length limit (IDX L2196).
pub fn canopen_limit() -> u16 {
    u16::try_from(MAX_PDO_BYTES_CANOPEN).expect("limit fits u16")
}

/// A context in which every write condition is met: Pre-Operational, power stage disabled, EtherCAT limit.
pub fn allowed() -> AccessContext {
    AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: ethercat_limit() }
}

/// A context in which only `WriteCondition::Always` entries accept writes: Operational, power stage enabled.
pub fn forbidden() -> AccessContext {
    AccessContext { comm_state: CommState::Operational, power_stage_enabled: true, max_pdo_bytes: ethercat_limit() }
}

/// The generated dictionary with the device's default node-ID.
pub fn dictionary() -> Dictionary {
    Dictionary::new(generated::DEFAULT_NODE_ID)
}

/// Stands in for the drive's persistence and bootloader code: accepts every write and records it, reads
/// fixed-size values as 1 (CiA 301 §7.5.2.13: 0x1010/0x1011 read 1 when the device saves on command).
#[derive(Default, Debug)]
pub struct TestApp {
    /// (index, sub, offset, data, complete) of every write received.
    pub writes: Vec<(u16, u8, usize, Vec<u8>, bool)>,
    /// Number of aborts received.
    pub aborts: usize,
}

impl ApplicationObjects for TestApp {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        let mut value = vec![0u8; entry.data_type.fixed_size().ok_or(SdoAbort::NoData)?];
        if let Some(first) = value.first_mut() {
            *first = 1;
        }
        let rest = value.get(offset..).unwrap_or(&[]);
        let len = rest.len().min(buf.len());
        buf[..len].copy_from_slice(&rest[..len]);
        Ok(ReadOutcome { len, total_len: value.len() })
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        _values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        self.writes.push((entry.index, entry.sub, offset, data.to_vec(), complete));
        Ok(())
    }

    fn abort(&mut self, _entry: &'static Entry) {
        self.aborts += 1;
    }
}

/// The bytes a full read of `entry` must return (a VISIBLE_STRING up to its first NUL).
pub fn expected_read<const N: usize>(dict: &Dictionary<N>, entry: &'static Entry) -> Vec<u8> {
    let value = match entry.storage {
        Storage::Const(bytes) => bytes.bytes().to_vec(),
        Storage::Ram { .. } => dict.values().raw(entry).expect("RAM entry has a slot").to_vec(),
        Storage::Application => {
            let mut value = vec![0u8; entry.data_type.fixed_size().unwrap_or(0)];
            if let Some(first) = value.first_mut() {
                *first = 1;
            }
            value
        }
    };
    if entry.data_type == DataType::VisibleString {
        let end = value.iter().position(|b| *b == 0).unwrap_or(value.len());
        value[..end].to_vec()
    } else {
        value
    }
}

/// Reads the whole value of `entry`.
pub fn read_all<const N: usize>(dict: &Dictionary<N>, entry: &'static Entry) -> Result<Vec<u8>, SdoAbort> {
    let mut buf = vec![0u8; 4096];
    let outcome = dict.read_entry(entry, 0, &mut buf, &mut TestApp::default())?;
    assert_eq!(outcome.len, outcome.total_len, "{:04X}:{:02X} fits the buffer", entry.index, entry.sub);
    Ok(buf[..outcome.len].to_vec())
}

/// The value of a fixed-size integer or BOOLEAN written as `data` (little-endian, sign-extended for signed
/// types); `None` when `data` does not have the type's size.
pub fn decode(data_type: DataType, data: &[u8]) -> Option<i128> {
    let size = data_type.fixed_size()?;
    if data.len() != size {
        return None;
    }
    let mut wide = if data_type.is_signed() && data[size - 1] & 0x80 != 0 { [0xFF; 16] } else { [0; 16] };
    wide[..size].copy_from_slice(data);
    Some(i128::from_le_bytes(wide))
}

/// Encodes `value` little-endian in `size` bytes.
pub fn encode(value: i128, size: usize) -> Vec<u8> {
    value.to_le_bytes()[..size].to_vec()
}

/// Range of values the data type can hold.
pub fn type_range(data_type: DataType) -> Option<(i128, i128)> {
    let size = data_type.fixed_size()?;
    if data_type == DataType::Boolean {
        return Some((0, 255));
    }
    let bits = u32::try_from(size * 8).expect("small");
    Some(if data_type.is_signed() {
        (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)
    } else {
        (0, (1i128 << bits) - 1)
    })
}

/// Whether `value` passes the entry's limits, and the abort code if not (CiA 301 Table 22).
pub fn limits_verdict(entry: &Entry, value: i128) -> Result<(), SdoAbort> {
    if entry.data_type == DataType::Boolean && value > 1 {
        return Err(SdoAbort::InvalidValue);
    }
    match *entry.generated_limits() {
        Limits::None => Ok(()),
        Limits::Signed { min, max } => range_verdict(value, i128::from(min), i128::from(max)),
        Limits::Unsigned { min, max } => range_verdict(value, i128::from(min), i128::from(max)),
        Limits::OneOf(list) => {
            if list.iter().any(|v| i128::from(*v) == value) {
                Ok(())
            } else {
                Err(SdoAbort::InvalidValue)
            }
        }
    }
}

fn range_verdict(value: i128, min: i128, max: i128) -> Result<(), SdoAbort> {
    if value < min {
        Err(SdoAbort::ValueTooLow)
    } else if value > max {
        Err(SdoAbort::ValueTooHigh)
    } else {
        Ok(())
    }
}

/// Whether `entry` belongs to a PDO mapping or assignment object, whose writes the whole-object rules judge.
pub fn is_pdo_configuration(entry: &Entry) -> bool {
    pdo_map::mapping_direction(entry.index).is_some() || pdo_map::assignment_direction(entry.index).is_some()
}

/// The outcome a write of `data` to `index:sub` must have by the per-entry rules, or `None` when the outcome
/// depends on the whole object (PDO mapping/assignment) or on the application (application entries pass the
/// checks and then answer for themselves).
pub fn oracle<const N: usize>(
    dict: &Dictionary<N>,
    index: u16,
    sub: u8,
    data: &[u8],
    ctx: AccessContext,
) -> Option<Result<(), SdoAbort>> {
    let entry = match dict.find(index, sub) {
        Ok(entry) => entry,
        Err(_) if dict.table().entries().iter().any(|e| e.index == index) => {
            return Some(Err(SdoAbort::SubindexDoesNotExist))
        }
        Err(_) => return Some(Err(SdoAbort::ObjectDoesNotExist)),
    };
    if !entry.access().writable() || matches!(entry.storage, Storage::Const(_)) {
        return Some(Err(SdoAbort::ReadOnly));
    }
    if !ctx.allows(entry.write_condition()) {
        return Some(Err(SdoAbort::DeviceState));
    }
    let length = match (entry.data_type.fixed_size(), entry.storage) {
        (Some(size), _) if data.len() < size => Err(SdoAbort::LengthTooLow),
        (Some(size), _) if data.len() > size => Err(SdoAbort::LengthTooHigh),
        (None, Storage::Ram { len, .. }) if data.len() > usize::from(len) => Err(SdoAbort::LengthTooHigh),
        (None, Storage::Ram { len, .. })
            if entry.data_type == DataType::OctetString && data.len() < usize::from(len) =>
        {
            Err(SdoAbort::LengthTooLow)
        }
        _ => Ok(()),
    };
    if length.is_err() {
        return Some(length);
    }
    if let Some(value) = decode(entry.data_type, data) {
        if let Err(abort) = limits_verdict(entry, value) {
            return Some(Err(abort));
        }
    }
    if is_pdo_configuration(entry) || entry.storage == Storage::Application {
        return None;
    }
    Some(Ok(()))
}

/// Every generated entry (convenience for table tests).
pub fn entries() -> &'static [Entry] {
    &ENTRIES
}
