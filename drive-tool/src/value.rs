//! Values of the dictionary's data types (CiA 301 §7.1.6, data type codes Table 44): text given on the command
//! line or in a DCF to the bytes an SDO download carries (little-endian), checked against the type's range and
//! the EDS limits before anything is sent, and uploaded bytes back to text and JSON.

use crate::eds::{parse_eds_integer, Entry};

/// The types drive-tool knows, by CiA 301 code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// BOOLEAN (0x0001).
    Boolean,
    /// INTEGERn / UNSIGNEDn: size in bytes and signedness.
    Integer {
        /// Bytes on the wire.
        bytes: usize,
        /// INTEGERn rather than UNSIGNEDn.
        signed: bool,
    },
    /// REAL32 (0x0008).
    Real32,
    /// REAL64 (0x0011).
    Real64,
    /// VISIBLE_STRING (0x0009).
    VisibleString,
    /// OCTET_STRING (0x000A) and DOMAIN (0x000F): bytes, shown as hex.
    Bytes,
}

impl Kind {
    /// The kind of CiA 301 data type `code`.
    pub fn of(code: u16) -> Option<Self> {
        let int = |bytes, signed| Self::Integer { bytes, signed };
        Some(match code {
            0x0001 => Self::Boolean,
            0x0002 => int(1, true),
            0x0003 => int(2, true),
            0x0004 => int(4, true),
            0x0005 => int(1, false),
            0x0006 => int(2, false),
            0x0007 => int(4, false),
            0x0008 => Self::Real32,
            0x0009 => Self::VisibleString,
            0x000A | 0x000F => Self::Bytes,
            0x0010 => int(3, true),
            0x0011 => Self::Real64,
            0x0012 => int(5, true),
            0x0013 => int(6, true),
            0x0014 => int(7, true),
            0x0015 => int(8, true),
            0x0016 => int(3, false),
            0x0018 => int(5, false),
            0x0019 => int(6, false),
            0x001A => int(7, false),
            0x001B => int(8, false),
            _ => return None,
        })
    }
}

/// The CiA 301 name of data type `code`.
pub fn type_name(code: u16) -> String {
    match code {
        0x0001 => "BOOLEAN".into(),
        0x0002 => "INTEGER8".into(),
        0x0003 => "INTEGER16".into(),
        0x0004 => "INTEGER32".into(),
        0x0005 => "UNSIGNED8".into(),
        0x0006 => "UNSIGNED16".into(),
        0x0007 => "UNSIGNED32".into(),
        0x0008 => "REAL32".into(),
        0x0009 => "VISIBLE_STRING".into(),
        0x000A => "OCTET_STRING".into(),
        0x000F => "DOMAIN".into(),
        0x0011 => "REAL64".into(),
        0x0015 => "INTEGER64".into(),
        0x001B => "UNSIGNED64".into(),
        other => format!("type 0x{other:04X}"),
    }
}

/// The inclusive range of an integer of `bytes` bytes.
fn integer_range(bytes: usize, signed: bool) -> (i128, i128) {
    let bits = 8 * bytes as u32;
    if signed {
        (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)
    } else {
        (0, (1i128 << bits) - 1)
    }
}

/// An integer from the command line: decimal, `0x` hex, `0b` binary, with `_` separators and a sign.
pub fn parse_integer(text: &str) -> Option<i128> {
    let t: String = text.trim().chars().filter(|&c| c != '_').collect();
    let (negative, digits) = match t.strip_prefix('-') {
        Some(d) => (true, d.to_owned()),
        None => (false, t.strip_prefix('+').unwrap_or(&t).to_owned()),
    };
    let lower = digits.to_ascii_lowercase();
    let magnitude = if let Some(hex) = lower.strip_prefix("0x") {
        i128::from_str_radix(hex, 16).ok()?
    } else if let Some(bin) = lower.strip_prefix("0b") {
        i128::from_str_radix(bin, 2).ok()?
    } else {
        lower.parse::<i128>().ok()?
    };
    Some(if negative { -magnitude } else { magnitude })
}

/// `text` as the bytes of `entry`'s type, or why not: the type's range, the EDS LowLimit/HighLimit, the syntax.
/// `node_id` resolves `$NODEID` in limits.
pub fn encode(entry: &Entry, text: &str, node_id: u8) -> Result<Vec<u8>, String> {
    let what = format!("{} ({}, {})", entry.address(), entry.full_name(), type_name(entry.data_type));
    let kind = Kind::of(entry.data_type).ok_or_else(|| format!("{what}: drive-tool cannot write this data type"))?;
    match kind {
        Kind::Boolean => match text.trim().to_ascii_lowercase().as_str() {
            "1" | "true" | "on" | "yes" => Ok(vec![1]),
            "0" | "false" | "off" | "no" => Ok(vec![0]),
            _ => Err(format!("{what}: `{text}` is not a boolean (true/false, 1/0, on/off)")),
        },
        Kind::Integer { bytes, signed } => {
            // A DCF may keep `$NODEID+0x180` in a ParameterValue (CiA 306 §4.6.3).
            let value = parse_integer(text)
                .or_else(|| parse_eds_integer(text, node_id))
                .ok_or_else(|| format!("{what}: `{text}` is not an integer (decimal, 0x hex or 0b binary)"))?;
            let (min, max) = integer_range(bytes, signed);
            if value < min || value > max {
                return Err(format!("{what}: {value} is out of the type's range {min}..={max}"));
            }
            let low = entry.low.as_deref().and_then(|l| parse_eds_integer(l, node_id));
            let high = entry.high.as_deref().and_then(|h| parse_eds_integer(h, node_id));
            // A limit pair with high below low describes nothing and is ignored; LowLimit = HighLimit is one value
            // (od-gen writes 0..0 for 0x1003:00, which accepts only 0, CiA 301 §7.5.2.5).
            if let (Some(low), Some(high)) = (low, high) {
                if low <= high && (value < low || value > high) {
                    return Err(format!("{what}: {value} is outside the EDS limits {low}..={high}"));
                }
            }
            let raw = if value < 0 { (value + (1i128 << (8 * bytes))) as u128 } else { value as u128 };
            Ok(raw.to_le_bytes()[..bytes].to_vec())
        }
        Kind::Real32 => {
            let v: f32 = text.trim().parse().map_err(|_| format!("{what}: `{text}` is not a number"))?;
            if !v.is_finite() {
                return Err(format!("{what}: {text} is not finite"));
            }
            Ok(v.to_le_bytes().to_vec())
        }
        Kind::Real64 => {
            let v: f64 = text.trim().parse().map_err(|_| format!("{what}: `{text}` is not a number"))?;
            Ok(v.to_le_bytes().to_vec())
        }
        Kind::VisibleString => {
            if let Some(c) = text.chars().find(|c| !(' '..='~').contains(c)) {
                return Err(format!("{what}: {c:?} is not a visible character (CiA 301 VISIBLE_STRING)"));
            }
            Ok(text.as_bytes().to_vec())
        }
        Kind::Bytes => parse_hex_bytes(text).ok_or_else(|| format!("{what}: `{text}` is not hex bytes (e.g. 01A2FF)")),
    }
}

/// `01A2FF`, `01 a2 ff` or `0x01A2FF` as bytes.
pub fn parse_hex_bytes(text: &str) -> Option<Vec<u8>> {
    let t: String = text.trim().trim_start_matches("0x").chars().filter(|c| !c.is_whitespace()).collect();
    if !t.len().is_multiple_of(2) {
        return None;
    }
    (0..t.len()).step_by(2).map(|k| u8::from_str_radix(t.get(k..k + 2)?, 16).ok()).collect()
}

/// A value decoded from the bytes of an upload.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// BOOLEAN.
    Bool(bool),
    /// Any integer type.
    Int(i128),
    /// REAL32/REAL64.
    Real(f64),
    /// VISIBLE_STRING.
    Text(String),
    /// OCTET_STRING/DOMAIN, and anything of a type drive-tool does not know.
    Bytes(Vec<u8>),
}

/// The value of `bytes` as `data_type`; `Err` when the length does not fit the type.
pub fn decode(data_type: u16, bytes: &[u8]) -> Result<Value, String> {
    let Some(kind) = Kind::of(data_type) else { return Ok(Value::Bytes(bytes.to_vec())) };
    match kind {
        Kind::Boolean => match bytes {
            [b] => Ok(Value::Bool(*b != 0)),
            _ => Err(format!("{} bytes for a BOOLEAN", bytes.len())),
        },
        Kind::Integer { bytes: n, signed } => {
            if bytes.len() != n {
                return Err(format!("{} bytes for a {}", bytes.len(), type_name(data_type)));
            }
            let mut raw = [0u8; 16];
            raw[..n].copy_from_slice(bytes);
            let mut v = u128::from_le_bytes(raw) as i128;
            if signed && v >= 1i128 << (8 * n - 1) {
                v -= 1i128 << (8 * n);
            }
            Ok(Value::Int(v))
        }
        Kind::Real32 => <[u8; 4]>::try_from(bytes)
            .map(|b| Value::Real(f64::from(f32::from_le_bytes(b))))
            .map_err(|_| format!("{} bytes for a REAL32", bytes.len())),
        Kind::Real64 => <[u8; 8]>::try_from(bytes)
            .map(|b| Value::Real(f64::from_le_bytes(b)))
            .map_err(|_| format!("{} bytes for a REAL64", bytes.len())),
        Kind::VisibleString => {
            // A fixed-capacity string may come with trailing NULs.
            let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
            Ok(Value::Text(String::from_utf8_lossy(&bytes[..end]).into_owned()))
        }
        Kind::Bytes => Ok(Value::Bytes(bytes.to_vec())),
    }
}

impl Value {
    /// For people: integers in decimal with the hex of unsigned ones beside, strings as they are, bytes in hex.
    pub fn display(&self, data_type: u16) -> String {
        match self {
            Self::Bool(b) => b.to_string(),
            Self::Int(v) => match Kind::of(data_type) {
                Some(Kind::Integer { bytes, signed: false }) => format!("{v} (0x{v:0width$X})", width = 2 * bytes),
                _ => v.to_string(),
            },
            Self::Real(v) => v.to_string(),
            Self::Text(s) => s.clone(),
            Self::Bytes(b) => hex(b),
        }
    }

    /// As a DCF ParameterValue (CiA 306: integers decimal or 0x hex, strings as text, DOMAIN as hex).
    pub fn dcf_text(&self, data_type: u16) -> String {
        match self {
            Self::Bool(b) => u8::from(*b).to_string(),
            Self::Int(v) => match Kind::of(data_type) {
                Some(Kind::Integer { bytes, signed: false }) => format!("0x{v:0width$X}", width = 2 * bytes),
                _ => v.to_string(),
            },
            Self::Real(v) => v.to_string(),
            Self::Text(s) => s.clone(),
            Self::Bytes(b) => hex(b),
        }
    }

    /// As JSON: numbers, booleans and strings; bytes as a hex string.
    pub fn json(&self) -> serde_json::Value {
        match self {
            Self::Bool(b) => serde_json::Value::Bool(*b),
            Self::Int(v) => i64::try_from(*v)
                .map(serde_json::Value::from)
                .or_else(|_| u64::try_from(*v).map(serde_json::Value::from))
                .unwrap_or_else(|_| serde_json::Value::String(v.to_string())),
            Self::Real(v) => serde_json::Value::from(*v),
            Self::Text(s) => serde_json::Value::String(s.clone()),
            Self::Bytes(b) => serde_json::Value::String(hex(b)),
        }
    }
}

/// Bytes as upper-case hex without separators.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eds::Dictionary;

    fn entry(spec: &str) -> Entry {
        Dictionary::project().resolve_one(spec).expect("in the EDS").clone()
    }

    #[test]
    fn integers_of_every_width_encode_little_endian_and_round_trip() {
        let target = entry("0x607A"); // INTEGER32
        assert_eq!(encode(&target, "-2", 1), Ok(vec![0xFE, 0xFF, 0xFF, 0xFF]));
        assert_eq!(encode(&target, "0x10", 1), Ok(vec![0x10, 0, 0, 0]));
        assert_eq!(decode(0x0004, &[0xFE, 0xFF, 0xFF, 0xFF]), Ok(Value::Int(-2)));
        assert_eq!(decode(0x0006, &[0x37, 0x02]), Ok(Value::Int(0x0237)));
        assert_eq!(decode(0x0002, &[0x80]), Ok(Value::Int(-128)));
    }

    #[test]
    fn out_of_range_and_wrongly_typed_values_are_refused_with_the_reason() {
        let cw = entry("0x6040"); // UNSIGNED16
        assert!(encode(&cw, "65536", 1).unwrap_err().contains("out of the type's range 0..=65535"));
        assert!(encode(&cw, "-1", 1).unwrap_err().contains("out of the type's range"));
        assert!(encode(&cw, "fast", 1).unwrap_err().contains("is not an integer"));
        assert_eq!(encode(&entry("0x1800:01"), "$NODEID+0x40000180", 5), Ok(0x4000_0185u32.to_le_bytes().to_vec()));
        let mode = entry("0x6060"); // INTEGER8
        assert!(encode(&mode, "200", 1).unwrap_err().contains("-128..=127"));
        assert!(
            encode(&entry("0x1003:00"), "3", 1).unwrap_err().contains("EDS limits 0..=0"),
            "only 0 clears the history"
        );
    }

    #[test]
    fn strings_booleans_reals_and_domains() {
        let mut e = entry("0x1008");
        assert_eq!(encode(&e, "OSD", 1), Ok(b"OSD".to_vec()));
        assert!(encode(&e, "tab\there", 1).is_err());
        e.data_type = 0x0001;
        assert_eq!(encode(&e, "true", 1), Ok(vec![1]));
        e.data_type = 0x0008;
        assert_eq!(encode(&e, "1.5", 1), Ok(1.5f32.to_le_bytes().to_vec()));
        e.data_type = 0x000F;
        assert_eq!(encode(&e, "01a2FF", 1), Ok(vec![1, 0xA2, 0xFF]));
        assert_eq!(decode(0x000F, &[1, 0xA2]).map(|v| v.display(0x000F)), Ok("01A2".into()));
    }
}
