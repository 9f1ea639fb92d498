//! What the project's own dictionary tables (the firmware's host build, generated from device.toml) add to an
//! EDS for a drive of this project: which entries 0x1010 saves, and the value lists of option codes, which a
//! CiA 306 EDS cannot express (it has LowLimit/HighLimit only).

use firmware::od::access::Table;
use firmware::od::entry::Limits;

use crate::eds::{Access, Dictionary, Entry};

/// Whether `entry` is a parameter the drive keeps with 0x1010 "save". For the project's own device (the
/// dictionary's vendor and product are the project's) the firmware's dictionary table says so entry by entry
/// (device.toml `persistent`); an EDS does not carry the flag, so for another device every read-write entry
/// outside the store/restore commands (0x1010, 0x1011) is taken.
pub fn persistent(dict: &Dictionary, entry: &Entry) -> bool {
    if is_project_device(dict) {
        return firmware::od::access::Table::GENERATED.find(entry.index, entry.sub).is_ok_and(|e| e.persistent());
    }
    entry.access == Access::ReadWrite && !matches!(entry.index, 0x1010 | 0x1011) && entry.data_type != 0x000F
}

/// Whether `dict` describes this project's drive (vendor and product of its `[DeviceInfo]`).
pub fn is_project_device(dict: &Dictionary) -> bool {
    let project = Dictionary::project().identity;
    dict.identity.vendor == project.vendor && dict.identity.product == project.product
}

/// The only values `entry` accepts, for a drive of this project (device.toml `values`, e.g. 0x6060's modes).
pub fn allowed_values(dict: &Dictionary, entry: &Entry) -> Option<&'static [i32]> {
    if !is_project_device(dict) {
        return None;
    }
    match Table::GENERATED.find(entry.index, entry.sub).ok()?.generated_limits() {
        Limits::OneOf(values) => Some(values),
        _ => None,
    }
}

/// `value` checked against [`allowed_values`]: the refusal names the accepted values.
pub fn check_allowed(dict: &Dictionary, entry: &Entry, value: i128) -> Result<(), String> {
    match allowed_values(dict, entry) {
        Some(values) if !values.iter().any(|&v| i128::from(v) == value) => Err(format!(
            "{} ({}): {value} is not one of the values the drive accepts: {}",
            entry.address(),
            entry.full_name(),
            values.iter().map(i32::to_string).collect::<Vec<_>>().join(", ")
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_project_flags_decide_persistence() {
        let d = Dictionary::project();
        assert!(persistent(&d, d.entry(0x6065, 0).expect("following error window")), "device.toml: persistent");
        assert!(!persistent(&d, d.entry(0x6040, 0).expect("controlword")), "the controlword is not a parameter");
    }

    #[test]
    fn option_codes_accept_only_their_values() {
        let d = Dictionary::project();
        let mode = d.entry(0x6060, 0).expect("modes of operation");
        assert!(check_allowed(&d, mode, 1).is_ok());
        let err = check_allowed(&d, mode, 2).unwrap_err();
        assert!(err.contains("not one of the values") && err.contains("1, 3"), "{err}");
        assert!(check_allowed(&d, d.entry(0x6065, 0).expect("window"), 12345).is_ok(), "a range, not a list");
    }
}
