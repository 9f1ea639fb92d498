//! SDO abort codes: the reason an SDO transfer (CANopen SDO or EtherCAT CoE) failed.
//!
//! The codes and their meanings are CiA 301 v4.2 §7.2.4.3.17 Table 22 ("SDO abort codes"), repeated by ETG.1000.6
//! Table 41 for CoE and by the seeds (IDX Table 7-154, L7602-L7636; EPOS3 L1215-L1260); the union of the seeds'
//! tables is `shared/spec/comms-faults-bootloader.md` §3.9. The dictionary access layer returns these directly
//! (ARCHITECTURE convention 6), and the SDO servers put [`SdoAbort::code`] on the wire, little-endian.

/// One SDO abort code (CiA 301 Table 22, ETG.1000.6 Table 41). The discriminant is the code on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum SdoAbort {
    /// 0x0503_0000: toggle bit not alternated (segmented transfer).
    ToggleBit = 0x0503_0000,
    /// 0x0504_0000: SDO protocol timed out.
    Timeout = 0x0504_0000,
    /// 0x0504_0001: client/server command specifier not valid or unknown.
    CommandSpecifier = 0x0504_0001,
    /// 0x0504_0002: invalid block size (block mode only).
    InvalidBlockSize = 0x0504_0002,
    /// 0x0504_0003: invalid sequence number (block mode only).
    InvalidSequence = 0x0504_0003,
    /// 0x0504_0004: CRC error (block mode only).
    CrcError = 0x0504_0004,
    /// 0x0504_0005: out of memory.
    OutOfMemory = 0x0504_0005,
    /// 0x0601_0000: unsupported access to an object. Also returned when a PDO mapping entry is written while the
    /// mapping is enabled (sub-index 0 not 0), as CANopenNode does (`OD_write_PDO_mapping`, `ODR_UNSUPP_ACCESS`).
    UnsupportedAccess = 0x0601_0000,
    /// 0x0601_0001: attempt to read a write-only object.
    WriteOnly = 0x0601_0001,
    /// 0x0601_0002: attempt to write a read-only object.
    ReadOnly = 0x0601_0002,
    /// 0x0601_0003: sub-index cannot be written, SI0 must be 0 for write access (ETG.1000.6 complete access;
    /// IDX L7602-L7636).
    SubindexNotWritable = 0x0601_0003,
    /// 0x0601_0004: SDO complete access not supported for objects of variable length (ETG.1000.6; IDX).
    CompleteAccessUnsupported = 0x0601_0004,
    /// 0x0602_0000: object does not exist in the object dictionary.
    ObjectDoesNotExist = 0x0602_0000,
    /// 0x0604_0041: object cannot be mapped to the PDO.
    CannotBeMapped = 0x0604_0041,
    /// 0x0604_0042: the number and length of the objects to be mapped would exceed the PDO length.
    PdoLengthExceeded = 0x0604_0042,
    /// 0x0604_0043: general parameter incompatibility reason.
    ParameterIncompatibility = 0x0604_0043,
    /// 0x0604_0047: general internal incompatibility in the device.
    InternalIncompatibility = 0x0604_0047,
    /// 0x0606_0000: access failed due to a hardware error.
    HardwareError = 0x0606_0000,
    /// 0x0607_0010: data type does not match, length of service parameter does not match.
    LengthMismatch = 0x0607_0010,
    /// 0x0607_0012: data type does not match, length of service parameter too high.
    LengthTooHigh = 0x0607_0012,
    /// 0x0607_0013: data type does not match, length of service parameter too low.
    LengthTooLow = 0x0607_0013,
    /// 0x0609_0011: sub-index does not exist.
    SubindexDoesNotExist = 0x0609_0011,
    /// 0x0609_0030: invalid value for parameter (download only).
    InvalidValue = 0x0609_0030,
    /// 0x0609_0031: value of parameter written too high (download only).
    ValueTooHigh = 0x0609_0031,
    /// 0x0609_0032: value of parameter written too low (download only).
    ValueTooLow = 0x0609_0032,
    /// 0x0609_0036: maximum value is less than minimum value.
    MaxLessThanMin = 0x0609_0036,
    /// 0x060A_0023: resource not available: SDO connection.
    ResourceNotAvailable = 0x060A_0023,
    /// 0x0800_0000: general error.
    GeneralError = 0x0800_0000,
    /// 0x0800_0020: data cannot be transferred or stored to the application.
    CannotTransfer = 0x0800_0020,
    /// 0x0800_0021: data cannot be transferred or stored to the application because of local control.
    LocalControl = 0x0800_0021,
    /// 0x0800_0022: data cannot be transferred or stored to the application because of the present device state.
    DeviceState = 0x0800_0022,
    /// 0x0800_0023: object dictionary dynamic generation fails or no object dictionary is present.
    NoDictionary = 0x0800_0023,
    /// 0x0800_0024: no data available.
    NoData = 0x0800_0024,
}

impl SdoAbort {
    /// Every abort code, in ascending order of its value (for tables and tests).
    pub const ALL: [SdoAbort; 33] = [
        Self::ToggleBit,
        Self::Timeout,
        Self::CommandSpecifier,
        Self::InvalidBlockSize,
        Self::InvalidSequence,
        Self::CrcError,
        Self::OutOfMemory,
        Self::UnsupportedAccess,
        Self::WriteOnly,
        Self::ReadOnly,
        Self::SubindexNotWritable,
        Self::CompleteAccessUnsupported,
        Self::ObjectDoesNotExist,
        Self::CannotBeMapped,
        Self::PdoLengthExceeded,
        Self::ParameterIncompatibility,
        Self::InternalIncompatibility,
        Self::HardwareError,
        Self::LengthMismatch,
        Self::LengthTooHigh,
        Self::LengthTooLow,
        Self::SubindexDoesNotExist,
        Self::InvalidValue,
        Self::ValueTooHigh,
        Self::ValueTooLow,
        Self::MaxLessThanMin,
        Self::ResourceNotAvailable,
        Self::GeneralError,
        Self::CannotTransfer,
        Self::LocalControl,
        Self::DeviceState,
        Self::NoDictionary,
        Self::NoData,
    ];

    /// The 32-bit abort code as it goes on the wire (CiA 301 §7.2.4.3.17: bytes 4..7 of the abort frame,
    /// little-endian).
    pub const fn code(self) -> u32 {
        self as u32
    }

    /// The abort for a code received from the wire, or `None` for a code CiA 301 / ETG.1000.6 does not define
    /// (for example the maxon-specific codes 0x0F00_FFxx, which this firmware never sends).
    pub const fn from_code(code: u32) -> Option<Self> {
        Some(match code {
            0x0503_0000 => Self::ToggleBit,
            0x0504_0000 => Self::Timeout,
            0x0504_0001 => Self::CommandSpecifier,
            0x0504_0002 => Self::InvalidBlockSize,
            0x0504_0003 => Self::InvalidSequence,
            0x0504_0004 => Self::CrcError,
            0x0504_0005 => Self::OutOfMemory,
            0x0601_0000 => Self::UnsupportedAccess,
            0x0601_0001 => Self::WriteOnly,
            0x0601_0002 => Self::ReadOnly,
            0x0601_0003 => Self::SubindexNotWritable,
            0x0601_0004 => Self::CompleteAccessUnsupported,
            0x0602_0000 => Self::ObjectDoesNotExist,
            0x0604_0041 => Self::CannotBeMapped,
            0x0604_0042 => Self::PdoLengthExceeded,
            0x0604_0043 => Self::ParameterIncompatibility,
            0x0604_0047 => Self::InternalIncompatibility,
            0x0606_0000 => Self::HardwareError,
            0x0607_0010 => Self::LengthMismatch,
            0x0607_0012 => Self::LengthTooHigh,
            0x0607_0013 => Self::LengthTooLow,
            0x0609_0011 => Self::SubindexDoesNotExist,
            0x0609_0030 => Self::InvalidValue,
            0x0609_0031 => Self::ValueTooHigh,
            0x0609_0032 => Self::ValueTooLow,
            0x0609_0036 => Self::MaxLessThanMin,
            0x060A_0023 => Self::ResourceNotAvailable,
            0x0800_0000 => Self::GeneralError,
            0x0800_0020 => Self::CannotTransfer,
            0x0800_0021 => Self::LocalControl,
            0x0800_0022 => Self::DeviceState,
            0x0800_0023 => Self::NoDictionary,
            0x0800_0024 => Self::NoData,
            _ => return None,
        })
    }
}

impl From<SdoAbort> for u32 {
    fn from(abort: SdoAbort) -> u32 {
        abort.code()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_are_sorted() {
        let mut previous = 0;
        for abort in SdoAbort::ALL {
            assert!(abort.code() > previous, "{abort:?} out of order");
            previous = abort.code();
            assert_eq!(SdoAbort::from_code(abort.code()), Some(abort));
        }
    }

    #[test]
    fn wire_values_match_cia_301_table_22() {
        // Golden values from CiA 301 Table 22 (and comms-faults-bootloader.md §3.9).
        assert_eq!(SdoAbort::ToggleBit.code(), 0x0503_0000);
        assert_eq!(SdoAbort::WriteOnly.code(), 0x0601_0001);
        assert_eq!(SdoAbort::ReadOnly.code(), 0x0601_0002);
        assert_eq!(SdoAbort::ObjectDoesNotExist.code(), 0x0602_0000);
        assert_eq!(SdoAbort::PdoLengthExceeded.code(), 0x0604_0042);
        assert_eq!(SdoAbort::LengthTooHigh.code(), 0x0607_0012);
        assert_eq!(SdoAbort::SubindexDoesNotExist.code(), 0x0609_0011);
        assert_eq!(SdoAbort::DeviceState.code(), 0x0800_0022);
        assert_eq!(SdoAbort::NoData.code(), 0x0800_0024);
    }

    #[test]
    fn unknown_codes_decode_to_none() {
        assert_eq!(SdoAbort::from_code(0), None);
        assert_eq!(SdoAbort::from_code(0x0F00_FFC0), None);
        assert_eq!(SdoAbort::from_code(0x0609_0033), None);
    }
}
