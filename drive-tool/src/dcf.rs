//! CiA 306 device configuration files: the EDS with each saved entry's ParameterValue and a
//! `[DeviceComissioning]` section (node-ID, bit rate, network), as PyPI canopen's `import_od` reads them.

use crate::eds::{Dictionary, Entry};
use crate::value::Value;

/// What a DCF records besides the values.
pub struct Commissioning {
    /// The drive's node-ID.
    pub node_id: u8,
    /// The bit rate in kbit/s, when known.
    pub bit_rate_kbit: Option<u32>,
    /// The drive's serial number 0x1018:04, when read.
    pub serial: Option<u32>,
    /// The DCF's own file name.
    pub file_name: String,
}

/// The DCF text: `dict`'s EDS with ParameterValue set for `values` and the commissioning section.
pub fn write(dict: &Dictionary, values: &[(Entry, Value)], c: &Commissioning) -> String {
    let mut ini = dict.ini.clone();
    let eds_name = ini.get("FileInfo", "FileName").unwrap_or("").to_owned();
    ini.set("FileInfo", "FileName", c.file_name.clone());
    ini.set("FileInfo", "LastEDS", eds_name);
    ini.set("FileInfo", "ModifiedBy", "drive-tool".into());
    for (entry, value) in values {
        ini.set(&entry.section, "ParameterValue", parameter_value(entry, value, c.node_id));
    }
    ini.set("DeviceComissioning", "NodeID", c.node_id.to_string());
    ini.set("DeviceComissioning", "NodeName", format!("node{}", c.node_id));
    if let Some(kbit) = c.bit_rate_kbit {
        ini.set("DeviceComissioning", "Baudrate", kbit.to_string());
    }
    ini.set("DeviceComissioning", "NetNumber", "1".into());
    ini.set("DeviceComissioning", "NetworkName", "CANopen".into());
    ini.set("DeviceComissioning", "CANopenManager", "0".into());
    ini.set("DeviceComissioning", "LSS_SerialNumber", format!("0x{:08X}", c.serial.unwrap_or(0)));
    ini.to_text()
}

/// The ParameterValue of `value`: relative to the node-ID (`$NODEID+0x180`, CiA 306 §4.6.3) where the EDS
/// default is (the COB-IDs), so that the file loads onto a drive with another node-ID with its own
/// identifiers; as it is otherwise.
pub fn parameter_value(entry: &Entry, value: &Value, node_id: u8) -> String {
    let relative = entry.default.as_deref().is_some_and(|d| d.trim().to_ascii_uppercase().starts_with("$NODEID"));
    match value {
        Value::Int(v) if relative && *v >= i128::from(node_id) => format!("$NODEID+0x{:X}", v - i128::from(node_id)),
        _ => value.dcf_text(entry.data_type),
    }
}

/// The kbit/s of a CiA 305 bit timing index (0x2001/0x200A here: 0 = 1 Mbit/s, 1 = 800k, 2 = 500k, ...).
pub fn bit_rate_kbit(code: i128) -> Option<u32> {
    Some(match code {
        0 => 1000,
        1 => 800,
        2 => 500,
        3 => 250,
        4 => 125,
        6 => 50,
        7 => 20,
        8 => 10,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dcf_carries_the_values_and_the_commissioning() {
        let d = Dictionary::project();
        let e = d.entry(0x6065, 0).expect("entry").clone();
        let text = write(
            &d,
            &[(e, Value::Int(1234))],
            &Commissioning { node_id: 3, bit_rate_kbit: Some(1000), serial: Some(7), file_name: "x.dcf".into() },
        );
        let back = Dictionary::parse(&text).expect("a DCF is an EDS too");
        assert_eq!(back.entry(0x6065, 0).and_then(|e| e.value.clone()).as_deref(), Some("0x000004D2"));
        assert_eq!(back.ini.get("DeviceComissioning", "NodeID"), Some("3"));
        assert_eq!(back.ini.get("FileInfo", "FileName"), Some("x.dcf"));
        let cob_id = d.entry(0x1800, 1).expect("TPDO 1 COB-ID");
        assert_eq!(parameter_value(cob_id, &Value::Int(0x4000_0183), 3), "$NODEID+0x40000180");
    }
}
