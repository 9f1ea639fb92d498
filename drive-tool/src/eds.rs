//! The object dictionary of a drive as its EDS (CiA 306) describes it: INI sections `[IIII]` for each object and
//! `[IIIIsubS]` for the sub-indices of an ARRAY or RECORD (hexadecimal), with ParameterName, DataType,
//! AccessType, DefaultValue, LowLimit, HighLimit and, in a DCF, ParameterValue (CiA 306 §4.6). The project's
//! EDS (od-gen's, from firmware/device.toml) is embedded as the default.

/// The project's EDS, generated at build time (build.rs).
pub const PROJECT_EDS: &str = include_str!(concat!(env!("OUT_DIR"), "/drive.eds"));

/// An INI file with its sections and keys in file order (a DCF is written back in the same order).
#[derive(Clone, Debug, Default)]
pub struct Ini {
    /// `(section name, [(key, value)])` in file order.
    pub sections: Vec<(String, Vec<(String, String)>)>,
}

impl Ini {
    /// Parses `text`; `;` starts a comment line.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut ini = Ini::default();
        for (n, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with(';') || line.starts_with('#') {
                continue;
            }
            if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                ini.sections.push((name.trim().to_owned(), Vec::new()));
            } else if let Some((key, value)) = line.split_once('=') {
                let Some((_, keys)) = ini.sections.last_mut() else {
                    return Err(format!("line {}: `{line}` before the first [section]", n + 1));
                };
                keys.push((key.trim().to_owned(), value.trim().to_owned()));
            } else {
                return Err(format!("line {}: `{line}` is neither a [section] nor key=value", n + 1));
            }
        }
        Ok(ini)
    }

    /// The value of `key` in `section` (both case-insensitive, as CiA 306 names are).
    pub fn get(&self, section: &str, key: &str) -> Option<&str> {
        self.sections
            .iter()
            .find(|(s, _)| s.eq_ignore_ascii_case(section))
            .and_then(|(_, keys)| keys.iter().find(|(k, _)| k.eq_ignore_ascii_case(key)))
            .map(|(_, v)| v.as_str())
    }

    /// The text of the file: sections in order, `key=value` lines, a blank line after each section.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        for (name, keys) in &self.sections {
            out.push_str(&format!("[{name}]\n"));
            for (k, v) in keys {
                out.push_str(&format!("{k}={v}\n"));
            }
            out.push('\n');
        }
        out
    }

    /// Sets `key` in `section`, replacing its value or appending the key (and the section).
    pub fn set(&mut self, section: &str, key: &str, value: String) {
        let index = match self.sections.iter().position(|(s, _)| s.eq_ignore_ascii_case(section)) {
            Some(i) => i,
            None => {
                self.sections.push((section.to_owned(), Vec::new()));
                self.sections.len() - 1
            }
        };
        let keys = &mut self.sections[index].1;
        match keys.iter_mut().find(|(k, _)| k.eq_ignore_ascii_case(key)) {
            Some((_, v)) => *v = value,
            None => keys.push((key.to_owned(), value)),
        }
    }
}

/// Access of an entry (CiA 306 AccessType).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// `ro`
    ReadOnly,
    /// `wo`
    WriteOnly,
    /// `rw`, `rwr`, `rww`
    ReadWrite,
    /// `const`
    Const,
}

impl Access {
    fn parse(text: &str) -> Option<Self> {
        Some(match text.to_ascii_lowercase().as_str() {
            "ro" => Self::ReadOnly,
            "wo" => Self::WriteOnly,
            "rw" | "rwr" | "rww" => Self::ReadWrite,
            "const" => Self::Const,
            _ => return None,
        })
    }

    /// Whether an SDO upload may read it.
    pub fn readable(self) -> bool {
        self != Self::WriteOnly
    }

    /// Whether an SDO download may write it.
    pub fn writable(self) -> bool {
        matches!(self, Self::WriteOnly | Self::ReadWrite)
    }

    /// The EDS word.
    pub fn word(self) -> &'static str {
        match self {
            Self::ReadOnly => "ro",
            Self::WriteOnly => "wo",
            Self::ReadWrite => "rw",
            Self::Const => "const",
        }
    }
}

/// One sub-index of the dictionary.
#[derive(Clone, Debug)]
pub struct Entry {
    /// Object index.
    pub index: u16,
    /// Sub-index (0 for a VAR).
    pub sub: u8,
    /// The entry's ParameterName (the object's for a VAR).
    pub name: String,
    /// The object's ParameterName.
    pub object_name: String,
    /// CiA 301 data type code (Table 44).
    pub data_type: u16,
    /// AccessType.
    pub access: Access,
    /// DefaultValue as written in the EDS.
    pub default: Option<String>,
    /// LowLimit, if any.
    pub low: Option<String>,
    /// HighLimit, if any.
    pub high: Option<String>,
    /// ParameterValue (DCF), if any.
    pub value: Option<String>,
    /// The INI section the entry is described in.
    pub section: String,
}

impl Entry {
    /// `0xIIII:SS`.
    pub fn address(&self) -> String {
        format!("0x{:04X}:{:02X}", self.index, self.sub)
    }

    /// `Object name / entry name`, or the name alone for a VAR.
    pub fn full_name(&self) -> String {
        if self.section.contains("sub") {
            format!("{} / {}", self.object_name, self.name)
        } else {
            self.name.clone()
        }
    }
}

/// Identity of a device as its EDS/DCF `[DeviceInfo]` gives it (CiA 306 §4.5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct DeviceIdentity {
    /// VendorNumber (0x1018:01).
    pub vendor: Option<u32>,
    /// ProductNumber (0x1018:02).
    pub product: Option<u32>,
    /// RevisionNumber (0x1018:03).
    pub revision: Option<u32>,
}

/// A dictionary read from an EDS or DCF.
#[derive(Clone, Debug)]
pub struct Dictionary {
    /// The file as parsed (written back for a DCF).
    pub ini: Ini,
    /// Every entry, sorted by index and sub-index.
    pub entries: Vec<Entry>,
    /// `[DeviceInfo]` identity.
    pub identity: DeviceIdentity,
}

/// An integer as CiA 306 writes them: decimal, `0x` hex, or `$NODEID+...` with the node-ID given.
pub fn parse_eds_integer(text: &str, node_id: u8) -> Option<i128> {
    let t = text.trim();
    let (base, rest) = if let Some(rest) = strip_prefix_ignore_case(t, "$NODEID") {
        (i128::from(node_id), rest.trim_start_matches(|c: char| c == '+' || c.is_whitespace()))
    } else {
        (0, t)
    };
    if rest.is_empty() {
        return Some(base);
    }
    let (negative, digits) = match rest.strip_prefix('-') {
        Some(d) => (true, d),
        None => (false, rest),
    };
    let magnitude = match strip_prefix_ignore_case(digits, "0x") {
        Some(hex) => i128::from_str_radix(hex, 16).ok()?,
        None => digits.parse::<i128>().ok()?,
    };
    Some(base + if negative { -magnitude } else { magnitude })
}

fn strip_prefix_ignore_case<'a>(text: &'a str, prefix: &str) -> Option<&'a str> {
    (text.len() >= prefix.len() && text[..prefix.len()].eq_ignore_ascii_case(prefix)).then(|| &text[prefix.len()..])
}

impl Dictionary {
    /// The project's dictionary (the embedded EDS).
    pub fn project() -> Self {
        // The embedded EDS is od-gen's output, checked by this crate's tests.
        Self::parse(PROJECT_EDS).unwrap_or_else(|e| panic!("the embedded EDS does not parse: {e}"))
    }

    /// Reads the EDS or DCF `text`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let ini = Ini::parse(text)?;
        let mut entries = Vec::new();
        for (section, _) in &ini.sections {
            let Some(index) = object_index(section) else { continue };
            let object_name = ini.get(section, "ParameterName").unwrap_or("").to_owned();
            let object_type = ini.get(section, "ObjectType").and_then(|t| parse_eds_integer(t, 0)).unwrap_or(7);
            if object_type == 7 {
                entries.push(entry(&ini, section, index, 0, &object_name)?);
            }
        }
        for (section, _) in &ini.sections {
            let Some((index, sub)) = sub_section(section) else { continue };
            let object_name = ini.get(&format!("{index:04X}"), "ParameterName").unwrap_or("").to_owned();
            entries.push(entry(&ini, section, index, sub, &object_name)?);
        }
        entries.sort_by_key(|e| (e.index, e.sub));
        let number = |key| ini.get("DeviceInfo", key).and_then(|v| parse_eds_integer(v, 0)).map(|v| v as u32);
        let identity = DeviceIdentity {
            vendor: number("VendorNumber"),
            product: number("ProductNumber"),
            revision: number("RevisionNumber"),
        };
        if entries.is_empty() {
            return Err("no object sections ([1000], [6040], ...): not an EDS".into());
        }
        Ok(Self { ini, entries, identity })
    }

    /// The entry at `index:sub`.
    pub fn entry(&self, index: u16, sub: u8) -> Option<&Entry> {
        self.entries.iter().find(|e| e.index == index && e.sub == sub)
    }

    /// The entries of object `index`.
    pub fn object(&self, index: u16) -> Vec<&Entry> {
        self.entries.iter().filter(|e| e.index == index).collect()
    }

    /// The entries `spec` names: `0x6040`, `6040`, `0x6040:00`, `0x3001:02` (index and sub-index hexadecimal), an
    /// entry's or object's ParameterName (case-insensitive), or `Object name:Entry name`.
    pub fn resolve(&self, spec: &str) -> Result<Vec<&Entry>, String> {
        let spec = spec.trim();
        if let Some((index, sub)) = parse_address(spec) {
            let found: Vec<&Entry> = match sub {
                Some(sub) => self.entry(index, sub).into_iter().collect(),
                None => self.object(index),
            };
            if found.is_empty() {
                return Err(match sub {
                    Some(sub) if !self.object(index).is_empty() => {
                        format!("object 0x{index:04X} has no sub-index 0x{sub:02X} in the EDS")
                    }
                    _ => format!("object 0x{index:04X} is not in the EDS"),
                });
            }
            return Ok(found);
        }
        let by_name: Vec<&Entry> = self.entries.iter().filter(|e| e.name.eq_ignore_ascii_case(spec)).collect();
        let objects: Vec<u16> = {
            let mut v: Vec<u16> =
                self.entries.iter().filter(|e| e.object_name.eq_ignore_ascii_case(spec)).map(|e| e.index).collect();
            v.dedup();
            v
        };
        match (by_name.len(), objects.as_slice()) {
            (1, _) => return Ok(by_name),
            (0, [index]) => return Ok(self.object(*index)),
            (0, []) => {}
            _ => {
                let mut list: Vec<String> =
                    by_name.iter().map(|e| format!("{} ({})", e.address(), e.full_name())).collect();
                list.extend(objects.iter().map(|i| format!("0x{i:04X}")));
                return Err(format!("`{spec}` names several entries: {}; give the index:sub", list.join(", ")));
            }
        }
        if let Some((object, name)) = spec.rsplit_once(':') {
            let found: Vec<&Entry> = self
                .entries
                .iter()
                .filter(|e| {
                    e.object_name.eq_ignore_ascii_case(object.trim()) && e.name.eq_ignore_ascii_case(name.trim())
                })
                .collect();
            if found.len() == 1 {
                return Ok(found);
            }
        }
        Err(format!("`{spec}` is neither an index (0x6040, 0x6040:00) nor a name in the EDS"))
    }

    /// The single entry `spec` names (a VAR, or an explicit sub-index).
    pub fn resolve_one(&self, spec: &str) -> Result<&Entry, String> {
        let found = self.resolve(spec)?;
        match found.as_slice() {
            [one] => Ok(one),
            many => Err(format!(
                "`{spec}` is object 0x{:04X} with sub-indices {}; name one, e.g. 0x{:04X}:{:02X}",
                many[0].index,
                many.iter().map(|e| format!("{:02X}", e.sub)).collect::<Vec<_>>().join(", "),
                many[0].index,
                many.get(1).map_or(0, |e| e.sub)
            )),
        }
    }
}

/// `IIII` (4 hex digits) as an object section name.
fn object_index(section: &str) -> Option<u16> {
    (section.len() == 4).then(|| u16::from_str_radix(section, 16).ok()).flatten()
}

/// `IIIIsubS` as a sub-index section name.
fn sub_section(section: &str) -> Option<(u16, u8)> {
    let lower = section.to_ascii_lowercase();
    let (index, sub) = lower.split_once("sub")?;
    Some((object_index(index)?, u8::from_str_radix(sub, 16).ok()?))
}

fn entry(ini: &Ini, section: &str, index: u16, sub: u8, object_name: &str) -> Result<Entry, String> {
    let get = |key| ini.get(section, key).map(str::to_owned);
    let data_type = get("DataType")
        .and_then(|t| parse_eds_integer(&t, 0))
        .and_then(|t| u16::try_from(t).ok())
        .ok_or_else(|| format!("[{section}]: no DataType"))?;
    let access_text = get("AccessType").ok_or_else(|| format!("[{section}]: no AccessType"))?;
    let access = Access::parse(&access_text).ok_or_else(|| format!("[{section}]: AccessType {access_text} unknown"))?;
    Ok(Entry {
        index,
        sub,
        name: get("ParameterName").unwrap_or_default(),
        object_name: object_name.to_owned(),
        data_type,
        access,
        default: get("DefaultValue"),
        low: get("LowLimit"),
        high: get("HighLimit"),
        value: get("ParameterValue"),
        section: section.to_owned(),
    })
}

/// `0x6040`, `6040`, `0x6040:00`, `6040:0A`, `0x6040sub0` → index and optional sub-index (both hexadecimal).
pub fn parse_address(spec: &str) -> Option<(u16, Option<u8>)> {
    let lower = spec.to_ascii_lowercase();
    let (index, sub) = match lower.split_once(':').or_else(|| lower.split_once("sub")) {
        Some((i, s)) => (i, Some(s)),
        None => (lower.as_str(), None),
    };
    let index = index.trim().trim_start_matches("0x");
    if index.is_empty() || index.len() > 4 || !index.chars().all(|c| c.is_ascii_hexdigit()) {
        return None;
    }
    let index = u16::from_str_radix(index, 16).ok()?;
    let sub = match sub {
        Some(s) => {
            let s = s.trim().trim_start_matches("0x");
            Some(u8::from_str_radix(s, 16).ok()?)
        }
        None => None,
    };
    Some((index, sub))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_eds_has_the_drives_objects() {
        let d = Dictionary::project();
        let cw = d.resolve_one("controlword").expect("by name");
        assert_eq!((cw.index, cw.sub, cw.data_type, cw.access), (0x6040, 0, 0x0006, Access::ReadWrite));
        assert_eq!(d.resolve_one("0x6040").expect("by index").index, 0x6040);
        assert_eq!(d.resolve_one("0x1018:01").expect("by index:sub").name, "Vendor ID");
        assert!(d.identity.vendor.is_some());
    }

    #[test]
    fn addresses_and_names_that_do_not_exist_are_refused_with_the_reason() {
        let d = Dictionary::project();
        assert!(d.resolve("0x1018:09").unwrap_err().contains("no sub-index 0x09"));
        assert!(d.resolve("0x5FFF").unwrap_err().contains("not in the EDS"));
        assert!(d.resolve("no such thing").unwrap_err().contains("neither"));
        assert!(d.resolve_one("0x1018").unwrap_err().contains("sub-indices"));
    }

    #[test]
    fn eds_integers_take_the_node_id() {
        assert_eq!(parse_eds_integer("$NODEID+0x180", 5), Some(0x185));
        assert_eq!(parse_eds_integer("-12", 0), Some(-12));
        assert_eq!(parse_eds_integer("0x000007D0", 0), Some(2000));
    }

    #[test]
    fn addresses_parse_in_every_spelling() {
        assert_eq!(parse_address("0x6040"), Some((0x6040, None)));
        assert_eq!(parse_address("0x3001:02"), Some((0x3001, Some(2))));
        assert_eq!(parse_address("1003sub0A"), Some((0x1003, Some(10))));
        assert_eq!(parse_address("Controlword"), None);
    }
}
