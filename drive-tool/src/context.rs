//! What every command works with: the link, the dictionary, the node addressed and the output format; object
//! access that names the object and the reason when it fails.

use crate::eds::{Dictionary, Entry};
use crate::link::DriveLink;
use crate::sdo::SdoError;
use crate::value::{decode, Value};

/// The link, dictionary and options of one run.
pub struct Context {
    /// The fieldbus.
    pub link: Box<dyn DriveLink>,
    /// The dictionary (EDS).
    pub dict: Dictionary,
    /// The drive addressed (`--node`).
    pub node: u8,
    /// `--json`.
    pub json: bool,
}

impl Context {
    /// The context of a run.
    pub fn new(link: Box<dyn DriveLink>, dict: Dictionary, node: u8, json: bool) -> Self {
        Self { link, dict, node, json }
    }

    /// Uploads `entry` from `node` and decodes it with its type.
    pub fn read_entry_of(&mut self, node: u8, entry: &Entry) -> Result<Value, String> {
        let bytes = self.link.upload(node, entry.index, entry.sub).map_err(|e| access_error(node, entry, &e))?;
        decode(entry.data_type, &bytes)
            .map_err(|e| format!("node {node} {} ({}): {e}", entry.address(), entry.full_name()))
    }

    /// Uploads `index:sub` (which must be in the dictionary) from the addressed drive.
    pub fn read(&mut self, index: u16, sub: u8) -> Result<Value, String> {
        let entry = self.entry(index, sub)?;
        self.read_entry_of(self.node, &entry)
    }

    /// `index:sub` as an integer.
    pub fn read_int(&mut self, index: u16, sub: u8) -> Result<i128, String> {
        match self.read(index, sub)? {
            Value::Int(v) => Ok(v),
            Value::Bool(b) => Ok(i128::from(b)),
            other => Err(format!("0x{index:04X}:{sub:02X} is {other:?}, not an integer")),
        }
    }

    /// The statusword 0x6041.
    pub fn statusword(&mut self) -> Result<u16, String> {
        Ok(self.read_int(0x6041, 0)? as u16)
    }

    /// Downloads `bytes` to `entry` of the addressed drive.
    pub fn write_entry(&mut self, entry: &Entry, bytes: &[u8]) -> Result<(), String> {
        self.link.download(self.node, entry.index, entry.sub, bytes).map_err(|e| access_error(self.node, entry, &e))
    }

    /// Writes the integer `value` to `index:sub`, with the entry's type and limits checked.
    pub fn write_int(&mut self, index: u16, sub: u8, value: i128) -> Result<(), String> {
        let entry = self.entry(index, sub)?;
        let bytes = crate::value::encode(&entry, &value.to_string(), self.node)?;
        self.write_entry(&entry, &bytes)
    }

    /// The dictionary's entry `index:sub`, or an error saying the EDS lacks it.
    pub fn entry(&self, index: u16, sub: u8) -> Result<Entry, String> {
        self.dict.entry(index, sub).cloned().ok_or_else(|| format!("0x{index:04X}:{sub:02X} is not in the EDS"))
    }

    /// Prints `value` as pretty JSON.
    pub fn print_json(&self, value: &serde_json::Value) {
        say!("{}", serde_json::to_string_pretty(value).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}")));
    }
}

/// `node 1 0x6041:00 (Statusword): SDO abort 0x06010002: Attempt to write a read only object`.
pub fn access_error(node: u8, entry: &Entry, e: &SdoError) -> String {
    format!("node {node} {} ({}): {e}", entry.address(), entry.full_name())
}
