//! The device description as written: serde records of the raw TOML, before any check.
//!
//! Every field is optional here so that a missing key becomes one line of the validation report (with the
//! object's index and name) rather than a parse failure that hides every other mistake. Keys the format does not
//! define are collected in `unknown` maps and reported too. The format itself is defined in the header of
//! `firmware/device.toml`.

use std::collections::BTreeMap;

use serde::Deserialize;

/// The whole file: `[device]` and the `[[object]]` list, in file order.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct RawFile {
    /// `[device]`.
    pub device: Option<RawDevice>,
    /// `[[object]]`, in file order.
    #[serde(default, rename = "object")]
    pub objects: Vec<RawObject>,
    /// Top-level keys the format does not define.
    #[serde(flatten)]
    pub unknown: BTreeMap<String, toml::Value>,
}

/// `[device]`: identity and fieldbus facts. Integers are kept as `i64` (TOML's integer) and range-checked by
/// validation.
#[derive(Clone, Debug, Default, Deserialize)]
#[allow(missing_docs)] // One field per key of `[device]`, documented in `model::Device`.
pub struct RawDevice {
    pub vendor_name: Option<String>,
    pub vendor_id: Option<i64>,
    pub product_code: Option<i64>,
    pub revision: Option<i64>,
    pub serial_number: Option<i64>,
    pub device_name: Option<String>,
    pub hardware_version: Option<String>,
    pub software_version: Option<String>,
    pub group_name: Option<String>,
    pub order_code: Option<String>,
    pub device_type: Option<i64>,
    pub node_id: Option<i64>,
    pub bit_rate_kbit: Option<i64>,
    pub mailbox_out_start: Option<i64>,
    pub mailbox_out_size: Option<i64>,
    pub mailbox_in_start: Option<i64>,
    pub mailbox_in_size: Option<i64>,
    pub process_out_start: Option<i64>,
    pub process_in_start: Option<i64>,
    pub max_pdo_bytes_ethercat: Option<i64>,
    pub max_pdo_bytes_canopen: Option<i64>,
    /// Keys the format does not define.
    #[serde(flatten)]
    pub unknown: BTreeMap<String, toml::Value>,
}

/// One `[[object]]`.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct RawObject {
    /// `index`.
    pub index: Option<i64>,
    /// `name`.
    pub name: Option<String>,
    /// `code`: `VAR`, `ARRAY` or `RECORD`.
    pub code: Option<String>,
    /// `description`.
    pub description: Option<String>,
    /// `source`.
    pub source: Option<String>,
    /// `note`.
    pub note: Option<String>,
    /// `[[object.sub]]`, in file order.
    #[serde(default, rename = "sub")]
    pub subs: Vec<RawSub>,
    /// Value attributes written on the object itself (a VAR's value), plus unknown keys.
    #[serde(flatten)]
    pub attrs: RawAttrs,
}

/// One `[[object.sub]]`.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct RawSub {
    /// `sub`: the sub-index (the first one, with `repeat`).
    pub sub: Option<i64>,
    /// `repeat`: how many consecutive sub-indices this record declares.
    pub repeat: Option<i64>,
    /// `name`, where `{n}` stands for the repetition number.
    pub name: Option<String>,
    /// `description`.
    pub description: Option<String>,
    /// Value attributes, plus unknown keys.
    #[serde(flatten)]
    pub attrs: RawAttrs,
}

/// The value attributes shared by a VAR object and a sub-object.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct RawAttrs {
    /// `type`.
    #[serde(rename = "type")]
    pub data_type: Option<String>,
    /// `access`.
    pub access: Option<String>,
    /// `pdo`.
    pub pdo: Option<String>,
    /// `default`: integer, string, `$NODEID+...`, boolean (BOOLEAN only) or, with `repeat`, a list of these.
    pub default: Option<toml::Value>,
    /// `min`.
    pub min: Option<i64>,
    /// `max`.
    pub max: Option<i64>,
    /// `values`.
    pub values: Option<Vec<i64>>,
    /// `length`.
    pub length: Option<i64>,
    /// `unit`.
    pub unit: Option<String>,
    /// `persistent`.
    pub persistent: Option<bool>,
    /// `writable_in`.
    pub writable_in: Option<String>,
    /// `storage`.
    pub storage: Option<String>,
    /// `handle`.
    pub handle: Option<String>,
    /// Keys the format does not define.
    #[serde(flatten)]
    pub unknown: BTreeMap<String, toml::Value>,
}

impl RawAttrs {
    /// Names of the value attributes that are set (used to reject them on an ARRAY/RECORD object).
    pub fn set_keys(&self) -> Vec<&'static str> {
        let flags = [
            ("type", self.data_type.is_some()),
            ("access", self.access.is_some()),
            ("pdo", self.pdo.is_some()),
            ("default", self.default.is_some()),
            ("min", self.min.is_some()),
            ("max", self.max.is_some()),
            ("values", self.values.is_some()),
            ("length", self.length.is_some()),
            ("unit", self.unit.is_some()),
            ("persistent", self.persistent.is_some()),
            ("writable_in", self.writable_in.is_some()),
            ("storage", self.storage.is_some()),
            ("handle", self.handle.is_some()),
        ];
        flags.iter().filter(|(_, set)| *set).map(|(k, _)| *k).collect()
    }
}

/// Parses the TOML text. A syntax or type error (a string where an integer belongs, ...) is one message with
/// the line and column the `toml` crate reports.
pub fn parse(text: &str) -> Result<RawFile, String> {
    toml::from_str(text).map_err(|e| e.to_string())
}
