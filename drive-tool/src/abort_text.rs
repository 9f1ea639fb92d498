//! The CiA 301 text of an SDO abort code (v4.2 §7.2.4.3.17 Table 22). The codes are the firmware's own
//! [`SdoAbort`] list, matched exhaustively, so a code the firmware adds cannot lack its text here.

use firmware::od::abort::SdoAbort;

/// The text of abort code `code`; codes CiA 301 does not define are named as such.
pub fn abort_text(code: u32) -> &'static str {
    let Some(abort) = SdoAbort::from_code(code) else {
        return "abort code not defined by CiA 301";
    };
    match abort {
        SdoAbort::ToggleBit => "Toggle bit not alternated",
        SdoAbort::Timeout => "SDO protocol timed out",
        SdoAbort::CommandSpecifier => "Client/server command specifier not valid or unknown",
        SdoAbort::InvalidBlockSize => "Invalid block size (block mode only)",
        SdoAbort::InvalidSequence => "Invalid sequence number (block mode only)",
        SdoAbort::CrcError => "CRC error (block mode only)",
        SdoAbort::OutOfMemory => "Out of memory",
        SdoAbort::UnsupportedAccess => "Unsupported access to an object",
        SdoAbort::WriteOnly => "Attempt to read a write only object",
        SdoAbort::ReadOnly => "Attempt to write a read only object",
        SdoAbort::SubindexNotWritable => "Sub-index cannot be written, SI0 must be 0 for write access",
        SdoAbort::CompleteAccessUnsupported => "SDO complete access not supported for objects of variable length",
        SdoAbort::ObjectDoesNotExist => "Object does not exist in the object dictionary",
        SdoAbort::CannotBeMapped => "Object cannot be mapped to the PDO",
        SdoAbort::PdoLengthExceeded => "The number and length of the objects to be mapped would exceed PDO length",
        SdoAbort::ParameterIncompatibility => "General parameter incompatibility reason",
        SdoAbort::InternalIncompatibility => "General internal incompatibility in the device",
        SdoAbort::HardwareError => "Access failed due to a hardware error",
        SdoAbort::LengthMismatch => "Data type does not match, length of service parameter does not match",
        SdoAbort::LengthTooHigh => "Data type does not match, length of service parameter too high",
        SdoAbort::LengthTooLow => "Data type does not match, length of service parameter too low",
        SdoAbort::SubindexDoesNotExist => "Sub-index does not exist",
        SdoAbort::InvalidValue => "Invalid value for parameter (download only)",
        SdoAbort::ValueTooHigh => "Value of parameter written too high (download only)",
        SdoAbort::ValueTooLow => "Value of parameter written too low (download only)",
        SdoAbort::MaxLessThanMin => "Maximum value is less than minimum value",
        SdoAbort::ResourceNotAvailable => "Resource not available: SDO connection",
        SdoAbort::GeneralError => "General error",
        SdoAbort::CannotTransfer => "Data cannot be transferred or stored to the application",
        SdoAbort::LocalControl => "Data cannot be transferred or stored to the application because of local control",
        SdoAbort::DeviceState => {
            "Data cannot be transferred or stored to the application because of the present device state"
        }
        SdoAbort::NoDictionary => "Object dictionary dynamic generation fails or no object dictionary is present",
        SdoAbort::NoData => "No data available",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_firmware_code_has_a_text_and_unknown_codes_say_so() {
        assert_eq!(abort_text(0x0601_0002), "Attempt to write a read only object");
        assert_eq!(abort_text(0x0609_0011), "Sub-index does not exist");
        for abort in SdoAbort::ALL {
            assert_ne!(abort_text(abort.code()), abort_text(0x0F00_FFFF), "{abort:?}");
        }
    }
}
