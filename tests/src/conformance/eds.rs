//! The shipped EDS (`docs/generated/drive.eds`) read as a conformance tool reads it (CiA 306 §4.6): one entry per
//! variable, with the data type, access type, PDO mapping and default value the file states, so the suite checks
//! the device against its file and not against the dictionary it was generated from.

use std::collections::BTreeMap;
use std::path::Path;

/// One variable of the EDS (a VAR object, or a sub-index of an ARRAY or RECORD).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EdsEntry {
    /// Object index.
    pub index: u16,
    /// Sub-index (0 for a VAR).
    pub sub: u8,
    /// ParameterName.
    pub name: String,
    /// DataType (CiA 301 §7.4.7.1 index of the type).
    pub data_type: u16,
    /// AccessType, lower case (`ro`, `wo`, `rw`, `rwr`, `rww`, `const`).
    pub access: String,
    /// PDOMapping.
    pub pdo_mapping: bool,
    /// DefaultValue as written (may hold `$NODEID+`).
    pub default: Option<String>,
}

impl EdsEntry {
    /// The size in bytes of a fixed-size data type (CiA 301 §7.4.7.1 Table 44), `None` for strings and domains.
    #[must_use]
    pub fn fixed_size(&self) -> Option<usize> {
        match self.data_type {
            0x0001 | 0x0002 | 0x0005 => Some(1),
            0x0003 | 0x0006 => Some(2),
            0x0010 | 0x0016 => Some(3),
            0x0004 | 0x0007 | 0x0008 => Some(4),
            0x0011 | 0x0015 | 0x001B => Some(8),
            _ => None,
        }
    }

    /// Whether a master may read it.
    #[must_use]
    pub fn readable(&self) -> bool {
        self.access != "wo"
    }

    /// Whether a master may never write it.
    #[must_use]
    pub fn read_only(&self) -> bool {
        matches!(self.access.as_str(), "ro" | "const")
    }

    /// The default value for a device with `node_id`, when the file gives one as a number.
    #[must_use]
    pub fn default_for(&self, node_id: u8) -> Option<u64> {
        let text = self.default.as_deref()?.trim();
        let (base, text) = match text.strip_prefix("$NODEID+") {
            Some(rest) => (u64::from(node_id), rest),
            None => (0, text),
        };
        parse_number(text).map(|v| v.wrapping_add(base))
    }
}

/// An EDS: its sections as written, and its variables.
#[derive(Debug, Clone)]
pub struct Eds {
    /// Section name (as in the file, upper case for indices) to its keys and values.
    pub sections: BTreeMap<String, BTreeMap<String, String>>,
    /// Every variable, in index and sub-index order.
    pub entries: Vec<EdsEntry>,
}

impl Eds {
    /// Reads the EDS at `path`.
    ///
    /// # Errors
    /// The file cannot be read, or a section of an object misses a key CiA 306 requires.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text)
    }

    /// Parses an EDS text.
    ///
    /// # Errors
    /// A section of an object misses a key CiA 306 requires, or holds a number that does not parse.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut sections: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
        let mut current: Option<String> = None;
        for line in text.lines() {
            let line = line.trim();
            if line.is_empty() || line.starts_with(';') {
                continue;
            }
            if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                let name = name.to_ascii_uppercase();
                sections.entry(name.clone()).or_default();
                current = Some(name);
            } else if let (Some(section), Some((key, value))) = (&current, line.split_once('=')) {
                sections
                    .get_mut(section)
                    .expect("the current section exists")
                    .insert(key.trim().to_ascii_lowercase(), value.trim().to_string());
            }
        }
        let mut entries = Vec::new();
        for (name, keys) in &sections {
            let (index, sub) = match object_section(name) {
                Some(at) => at,
                None => continue,
            };
            // An ARRAY or RECORD section (SubNumber) lists its subs in sections of their own.
            if sub.is_none() && keys.contains_key("subnumber") {
                continue;
            }
            let get = |k: &str| keys.get(k).ok_or_else(|| format!("[{name}] has no {k}"));
            let data_type = parse_number(get("datatype")?).ok_or_else(|| format!("[{name}] DataType"))?;
            entries.push(EdsEntry {
                index,
                sub: sub.unwrap_or(0),
                name: get("parametername")?.clone(),
                data_type: u16::try_from(data_type).map_err(|_| format!("[{name}] DataType"))?,
                access: get("accesstype")?.to_ascii_lowercase(),
                pdo_mapping: keys.get("pdomapping").is_some_and(|v| v == "1"),
                default: keys.get("defaultvalue").cloned(),
            });
        }
        entries.sort_by_key(|e| (e.index, e.sub));
        Ok(Self { sections, entries })
    }

    /// The EDS the project ships (`docs/generated/drive.eds`), read once.
    ///
    /// # Panics
    /// If the file cannot be read or parsed (a checkout without its generated files).
    pub fn shipped() -> &'static Self {
        static EDS: std::sync::OnceLock<Eds> = std::sync::OnceLock::new();
        EDS.get_or_init(|| {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/generated/drive.eds");
            Self::load(&path).expect("the shipped EDS reads")
        })
    }

    /// The variable at `index:sub`.
    #[must_use]
    pub fn entry(&self, index: u16, sub: u8) -> Option<&EdsEntry> {
        self.entries.iter().find(|e| e.index == index && e.sub == sub)
    }

    /// Whether the file describes an object at `index`.
    #[must_use]
    pub fn has_object(&self, index: u16) -> bool {
        self.entries.iter().any(|e| e.index == index)
    }

    /// A key of the `[DeviceInfo]` section, as a number.
    #[must_use]
    pub fn device_info_number(&self, key: &str) -> Option<u64> {
        self.sections.get("DEVICEINFO")?.get(&key.to_ascii_lowercase()).and_then(|v| parse_number(v))
    }
}

/// `1018` -> (0x1018, None); `1018SUB2` -> (0x1018, Some(2)); anything else -> None.
fn object_section(name: &str) -> Option<(u16, Option<u8>)> {
    let (index, sub) = match name.split_once("SUB") {
        Some((i, s)) => (i, Some(u8::from_str_radix(s, 16).ok()?)),
        None => (name, None),
    };
    if index.len() != 4 {
        return None;
    }
    Some((u16::from_str_radix(index, 16).ok()?, sub))
}

/// A CiA 306 number: `0x` hexadecimal, `0` octal, decimal otherwise; negative decimals as two's complement.
fn parse_number(text: &str) -> Option<u64> {
    let t = text.trim();
    if let Some(hex) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        u64::from_str_radix(hex, 16).ok()
    } else if let Some(neg) = t.strip_prefix('-') {
        neg.parse::<i64>().ok().map(|v| v.wrapping_neg() as u64)
    } else if t.len() > 1 && t.starts_with('0') {
        u64::from_str_radix(&t[1..], 8).ok()
    } else {
        t.parse().ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sections_subs_and_node_id_defaults_parse_as_cia_306_writes_them() {
        let eds = Eds::parse(
            "[DeviceInfo]\nVendorNumber=0x00000ACE\n[1018]\nParameterName=Identity\nObjectType=0x9\nSubNumber=2\n\
             [1018sub0]\nParameterName=n\nDataType=0x0005\nAccessType=const\nDefaultValue=1\n\
             [1018sub1]\nParameterName=Vendor-ID\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x0ACE\n\
             [1014]\nParameterName=COB-ID EMCY\nDataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+0x80\nPDOMapping=0\n",
        )
        .unwrap();
        assert_eq!(eds.entries.len(), 3);
        assert_eq!(eds.entry(0x1018, 1).unwrap().default_for(5), Some(0x0ACE));
        assert_eq!(eds.entry(0x1014, 0).unwrap().default_for(5), Some(0x85));
        assert_eq!(eds.entry(0x1018, 0).unwrap().fixed_size(), Some(1));
        assert!(eds.entry(0x1018, 0).unwrap().read_only());
        assert_eq!(eds.device_info_number("VendorNumber"), Some(0xACE));
        assert_eq!(parse_number("010"), Some(8));
        assert_eq!(parse_number("-1"), Some(u64::MAX));
    }
}
