//! The object dictionary's attribute vocabulary, defined once for both sides of the contract: `od-gen` reads it
//! from the device description and writes it into the generated tables, the firmware's access layer
//! (`firmware::od::entry`) reads and writes values through it. The attributes follow CiA 301 and the IDX firmware
//! specification 6.1.1..6.1.4 (data types, object codes, access types, PDO flags).
//!
//! `no_std`, no dependencies, `const` everywhere: the generated `static` tables name these types directly.
#![cfg_attr(not(test), no_std)]

/// CiA 301 object code (IDX 6.1.2, Table 6-57).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ObjectCode {
    /// A single value at sub-index 0 (0x0007).
    Var,
    /// Sub 0 holds the element count; subs 1..N share one data type (0x0008).
    Array,
    /// Sub 0 holds the highest sub-index; entries may differ in type (0x0009).
    Record,
}

impl ObjectCode {
    /// The code as it appears on the wire (SDO information service) and in an EDS.
    #[must_use]
    pub const fn code(self) -> u8 {
        match self {
            Self::Var => 0x07,
            Self::Array => 0x08,
            Self::Record => 0x09,
        }
    }
}

/// CiA 301 basic data types (IDX 6.1.1, Table 6-56) plus DOMAIN for program data.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    /// 0x0001, one bit carried in one byte.
    Boolean,
    /// 0x0002.
    Integer8,
    /// 0x0003.
    Integer16,
    /// 0x0004.
    Integer32,
    /// 0x0015.
    Integer64,
    /// 0x0005.
    Unsigned8,
    /// 0x0006.
    Unsigned16,
    /// 0x0007.
    Unsigned32,
    /// 0x001B.
    Unsigned64,
    /// 0x0009, one octet per character.
    VisibleString,
    /// 0x000A, a sequence of octets.
    OctetString,
    /// 0x000F, an application-defined block of arbitrary length (program data 0x1F50).
    Domain,
}

impl DataType {
    /// The CiA 301 data-type index (used in the EDS `DataType` key and by the SDO information service).
    #[must_use]
    pub const fn code(self) -> u16 {
        match self {
            Self::Boolean => 0x0001,
            Self::Integer8 => 0x0002,
            Self::Integer16 => 0x0003,
            Self::Integer32 => 0x0004,
            Self::Integer64 => 0x0015,
            Self::Unsigned8 => 0x0005,
            Self::Unsigned16 => 0x0006,
            Self::Unsigned32 => 0x0007,
            Self::Unsigned64 => 0x001B,
            Self::VisibleString => 0x0009,
            Self::OctetString => 0x000A,
            Self::Domain => 0x000F,
        }
    }

    /// Size in bytes of a fixed-size type; `None` for strings and domains, whose size is per entry.
    #[must_use]
    pub const fn fixed_size(self) -> Option<usize> {
        match self {
            Self::Boolean | Self::Integer8 | Self::Unsigned8 => Some(1),
            Self::Integer16 | Self::Unsigned16 => Some(2),
            Self::Integer32 | Self::Unsigned32 => Some(4),
            Self::Integer64 | Self::Unsigned64 => Some(8),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }

    /// Inclusive value range of an integer type (BOOLEAN is 0..=1); `None` for strings and domains.
    #[must_use]
    pub const fn range(self) -> Option<(i128, i128)> {
        match self {
            Self::Boolean => Some((0, 1)),
            Self::Integer8 => Some((i8::MIN as i128, i8::MAX as i128)),
            Self::Integer16 => Some((i16::MIN as i128, i16::MAX as i128)),
            Self::Integer32 => Some((i32::MIN as i128, i32::MAX as i128)),
            Self::Integer64 => Some((i64::MIN as i128, i64::MAX as i128)),
            Self::Unsigned8 => Some((0, u8::MAX as i128)),
            Self::Unsigned16 => Some((0, u16::MAX as i128)),
            Self::Unsigned32 => Some((0, u32::MAX as i128)),
            Self::Unsigned64 => Some((0, u64::MAX as i128)),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }

    /// The name the description, the EDS comments and the object reference use (`UNSIGNED16`, ...).
    #[must_use]
    pub const fn cia_name(self) -> &'static str {
        match self {
            Self::Boolean => "BOOLEAN",
            Self::Integer8 => "INTEGER8",
            Self::Integer16 => "INTEGER16",
            Self::Integer32 => "INTEGER32",
            Self::Integer64 => "INTEGER64",
            Self::Unsigned8 => "UNSIGNED8",
            Self::Unsigned16 => "UNSIGNED16",
            Self::Unsigned32 => "UNSIGNED32",
            Self::Unsigned64 => "UNSIGNED64",
            Self::VisibleString => "VISIBLE_STRING",
            Self::OctetString => "OCTET_STRING",
            Self::Domain => "DOMAIN",
        }
    }

    /// Whether values of this type are two's-complement signed integers.
    #[must_use]
    pub const fn is_signed(self) -> bool {
        matches!(self, Self::Integer8 | Self::Integer16 | Self::Integer32 | Self::Integer64)
    }

    /// Whether this is an integer type (BOOLEAN included): the types `min`, `max` and `values` apply to.
    #[must_use]
    pub const fn is_integer(self) -> bool {
        self.range().is_some()
    }

    /// Length in bits of a PDO mapping entry for this type (BOOLEAN maps as 1 bit), or `None` for types that
    /// cannot be mapped (strings, domains).
    #[must_use]
    pub const fn pdo_bits(self) -> Option<u16> {
        match self {
            Self::Boolean => Some(1),
            Self::Integer8 | Self::Unsigned8 => Some(8),
            Self::Integer16 | Self::Unsigned16 => Some(16),
            Self::Integer32 | Self::Unsigned32 => Some(32),
            Self::Integer64 | Self::Unsigned64 => Some(64),
            Self::VisibleString | Self::OctetString | Self::Domain => None,
        }
    }
}

/// Access type (IDX 6.1.3, Table 6-58).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Access {
    /// Read only; the value may change at run time (actual values). `ro` in the description.
    ReadOnly,
    /// Write only. `wo`.
    WriteOnly,
    /// Read and write. `rw`.
    ReadWrite,
    /// Read only, and the value never changes. `const`.
    Const,
}

impl Access {
    /// Whether an SDO upload may read the entry.
    #[must_use]
    pub const fn readable(self) -> bool {
        !matches!(self, Self::WriteOnly)
    }

    /// Whether an SDO download may write the entry.
    #[must_use]
    pub const fn writable(self) -> bool {
        matches!(self, Self::WriteOnly | Self::ReadWrite)
    }

    /// The word the description uses (`ro`, `wo`, `rw`, `const`).
    #[must_use]
    pub const fn word(self) -> &'static str {
        match self {
            Self::ReadOnly => "ro",
            Self::WriteOnly => "wo",
            Self::ReadWrite => "rw",
            Self::Const => "const",
        }
    }
}

/// PDO mapping flag (IDX 6.1.4): the direction an entry may be mapped into.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PdoMapping {
    /// Not mappable.
    No,
    /// Mappable into a receive PDO (master to drive).
    Rx,
    /// Mappable into a transmit PDO (drive to master).
    Tx,
    /// Mappable in both directions.
    Both,
}

impl PdoMapping {
    /// Whether the entry may be mapped into a receive PDO.
    #[must_use]
    pub const fn rx(self) -> bool {
        matches!(self, Self::Rx | Self::Both)
    }

    /// Whether the entry may be mapped into a transmit PDO.
    #[must_use]
    pub const fn tx(self) -> bool {
        matches!(self, Self::Tx | Self::Both)
    }

    /// The word the description uses (`no`, `rx`, `tx`, `both`).
    #[must_use]
    pub const fn word(self) -> &'static str {
        match self {
            Self::No => "no",
            Self::Rx => "rx",
            Self::Tx => "tx",
            Self::Both => "both",
        }
    }
}

/// When a writable entry accepts writes (IDX notes per object: PDO mappings only in Pre-Operational, axis
/// configuration only with the power stage disabled, restore defaults only in both).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WriteCondition {
    /// Whenever the entry is writable. `always` in the description.
    Always,
    /// Only in the communication state Pre-Operational (NMT or EtherCAT ESM). `pre-op`.
    PreOperational,
    /// Only while the power stage is disabled (CiA 402 states before "Operation enabled"). `power-disabled`.
    PowerDisabled,
    /// Only in Pre-Operational with the power stage disabled. `pre-op-power-disabled`.
    PreOperationalPowerDisabled,
}

impl WriteCondition {
    /// The word the description uses (`always`, `pre-op`, ...).
    #[must_use]
    pub const fn word(self) -> &'static str {
        match self {
            Self::Always => "always",
            Self::PreOperational => "pre-op",
            Self::PowerDisabled => "power-disabled",
            Self::PreOperationalPowerDisabled => "pre-op-power-disabled",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every integer type's PDO bit length agrees with its size, and its range with its signedness.
    #[test]
    fn sizes_ranges_and_bits_agree() {
        use DataType::*;
        for t in [Boolean, Integer8, Integer16, Integer32, Integer64, Unsigned8, Unsigned16, Unsigned32, Unsigned64] {
            let size = t.fixed_size().expect("fixed size");
            let bits = t.pdo_bits().expect("mappable");
            assert!(bits == 1 && t == Boolean || usize::from(bits) == 8 * size, "{t:?}");
            let (min, _) = t.range().expect("integer");
            assert_eq!(min < 0, t.is_signed(), "{t:?}");
        }
        for t in [VisibleString, OctetString, Domain] {
            assert!(t.fixed_size().is_none() && t.pdo_bits().is_none() && !t.is_integer(), "{t:?}");
        }
    }
}
