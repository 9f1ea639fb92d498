//! The CANopen write rules the dictionary cannot know, checked on an SDO download before the SDO server hands it
//! to the dictionary: they depend on the PDOs' valid bits, on the CAN frame size and on other objects.
//!
//! | Object | Rule | Abort |
//! |---|---|---|
//! | 0x14xx/0x18xx:01 COB-ID | bits 0..29 not changed while the PDO is valid and stays valid (CiA 301 §7.5.2.35/37) | 0x0609_0030 |
//! | | no 29-bit identifier (bit 29), no identifier above 0x7FF, none of the restricted ones (CiA 301 §7.3.5) for a valid PDO | 0x0609_0030 |
//! | | made valid only with a mapping that fits a CAN frame (8 bytes, IDX L2196) | 0x0604_0042 |
//! | 0x14xx/0x18xx:02 transmission type | RPDO 241..=253 and TPDO 241..=252 reserved or not supported | 0x0609_0030 |
//! | 0x18xx:03 inhibit time, 0x18xx:06 SYNC start value | not changed while the PDO is valid (CiA 301 §7.5.2.37) | 0x0609_0030 |
//! | 0x16xx/0x1Axx mapping | not changed while the PDO is valid (CiA 301 §7.5.2.36 step 1; CANopenNode answers 0x0601_0000) | 0x0601_0000 |
//! | | sub 0 = n: the n entries fit a CAN frame (CiA 301 §7.5.2.36 step 4) | 0x0604_0042 |
//! | 0x1016:xx consumer heartbeat | no second non-zero entry for the same producer (CiA 301 §7.5.2.20); bits 31..24 reserved 0 | 0x0604_0043 / 0x0609_0030 |
//! | 0x1005 COB-ID SYNC | an 11-bit identifier only: bit 30 (SYNC producer; the drive consumes SYNC only) and bit 29 (29-bit identifier) refused as CiA 301 §7.5.2.5 prescribes | 0x0609_0030 |
//! | 0x1019 SYNC counter overflow | not 1 (CiA 301 §7.5.2.22), and not changed while 0x1006 is not 0 | 0x0609_0030 / 0x0800_0022 |
//!
//! The objects concerned hold at most 4 bytes, which SDO clients send expedited (PyPI canopen, CANopenNode and
//! Lely do). A segmented or block download to one of them cannot be judged before its last frame, so it is
//! refused at once with 0x0601_0000 instead of being stored unchecked.
//!
//! The rules run only where the dictionary itself would accept the write in principle (the entry exists and is
//! writable in the present state), so that a write in the wrong state still gets the dictionary's 0x0800_0022.

use super::ids;
use super::pdo::{self, Transmission, COB_EXTENDED, COB_INVALID};
use crate::od::abort::SdoAbort;
use crate::od::access::{AccessContext, Dictionary};
use crate::od::entry::Access;
use crate::od::generated::MAX_PDO_BYTES_CANOPEN;
use crate::od::pdo_map::{self, Direction};

/// Whether downloads to `index` are checked here.
pub const fn is_guarded(index: u16) -> bool {
    pdo::pdo_of(index).is_some() || matches!(index, 0x1005 | 0x1016 | 0x1019)
}

/// Checks a download of `value` (the expedited data, little-endian, zero-extended; `None` for a segmented or
/// block download) to `index:sub` in `ctx`. See the module documentation for the rules.
pub fn check_download<const N: usize>(
    d: &Dictionary<N>,
    index: u16,
    sub: u8,
    value: Option<u32>,
    ctx: AccessContext,
) -> Result<(), SdoAbort> {
    if !is_guarded(index) {
        return Ok(());
    }
    let Ok(entry) = d.find(index, sub) else {
        return Ok(());
    };
    if !matches!(entry.access(), Access::ReadWrite | Access::WriteOnly) || !ctx.allows(entry.write_condition()) {
        return Ok(());
    }
    let value = value.ok_or(SdoAbort::UnsupportedAccess)?;
    if let Some((direction, n, mapping)) = pdo::pdo_of(index) {
        let valid = pdo::is_valid(d, direction, n);
        if mapping {
            return check_mapping(d, index, sub, value, valid);
        }
        return check_communication(d, direction, n, sub, value, valid);
    }
    match index {
        0x1005 if value > 0x7FF => Err(SdoAbort::InvalidValue),
        0x1016 => check_consumer(d, sub, value),
        0x1019 => {
            if value == 1 {
                Err(SdoAbort::InvalidValue)
            } else if ids::read_u32(d, 0x1006, 0) != 0 {
                Err(SdoAbort::DeviceState)
            } else {
                Ok(())
            }
        }
        _ => Ok(()),
    }
}

fn check_mapping<const N: usize>(
    d: &Dictionary<N>,
    index: u16,
    sub: u8,
    value: u32,
    valid: bool,
) -> Result<(), SdoAbort> {
    if valid {
        return Err(SdoAbort::UnsupportedAccess);
    }
    if sub == 0 && value > 0 {
        let count = u8::try_from(value).map_err(|_| SdoAbort::ValueTooHigh)?;
        let bits = pdo_map::check_mapping(d.table(), d.values().bytes(), index, count)?;
        if usize::try_from(pdo_map::bytes_for_bits(bits)).unwrap_or(usize::MAX) > MAX_PDO_BYTES_CANOPEN {
            return Err(SdoAbort::PdoLengthExceeded);
        }
    }
    Ok(())
}

fn check_communication<const N: usize>(
    d: &Dictionary<N>,
    direction: Direction,
    n: usize,
    sub: u8,
    value: u32,
    valid: bool,
) -> Result<(), SdoAbort> {
    match (direction, sub) {
        (_, 1) => {
            let old = ids::read_u32(d, pdo::comm_index(direction, n), 1);
            let becomes_valid = value & COB_INVALID == 0;
            if value & COB_EXTENDED != 0 {
                return Err(SdoAbort::InvalidValue);
            }
            if becomes_valid {
                let id = value & 0x1FFF_FFFF;
                if id > u32::from(super::frame::MAX_ID) || ids::is_restricted(u16::try_from(id).unwrap_or(0)) {
                    return Err(SdoAbort::InvalidValue);
                }
                if valid && (value ^ old) & 0x3FFF_FFFF != 0 {
                    return Err(SdoAbort::InvalidValue);
                }
                if !valid {
                    let bits = pdo_map::mapping_bits(d.table(), d.values().bytes(), pdo::mapping_index(direction, n))?;
                    if usize::try_from(pdo_map::bytes_for_bits(bits)).unwrap_or(usize::MAX) > MAX_PDO_BYTES_CANOPEN {
                        return Err(SdoAbort::PdoLengthExceeded);
                    }
                }
            }
            Ok(())
        }
        (_, 2) => {
            let code = u8::try_from(value).map_err(|_| SdoAbort::ValueTooHigh)?;
            Transmission::from_code(code, direction).map(|_| ()).ok_or(SdoAbort::InvalidValue)
        }
        (Direction::Tx, 3 | 6) if valid => Err(SdoAbort::InvalidValue),
        _ => Ok(()),
    }
}

fn check_consumer<const N: usize>(d: &Dictionary<N>, sub: u8, value: u32) -> Result<(), SdoAbort> {
    if value & 0xFF00_0000 != 0 {
        return Err(SdoAbort::InvalidValue);
    }
    let node = value.wrapping_shr(16) & 0xFF;
    if node == 0 || value & 0xFFFF == 0 {
        return Ok(());
    }
    let count = ids::read(d, 0x1016, 0).and_then(|v| u8::try_from(v).ok()).unwrap_or(0);
    for other in (1..=count).filter(|s| *s != sub) {
        let entry = ids::read_u32(d, 0x1016, other);
        if entry & 0xFFFF != 0 && entry.wrapping_shr(16) & 0xFF == node {
            return Err(SdoAbort::ParameterIncompatibility);
        }
    }
    Ok(())
}
