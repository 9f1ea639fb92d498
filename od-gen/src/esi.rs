//! EtherCAT slave information (ETG.2000 v1.0.9) emitter, and the default process-data layout that the ESI and
//! the SII image (`sii.rs`) both describe.
//!
//! Everything here is derived from the description: identity from `[device]` and 0x1018, sync managers from
//! `[device]`, PDOs from the default values of 0x1600.., 0x1A00.. and their assignment in 0x1C12/0x1C13. The
//! output is deterministic (no dates, sorted data types) and every text is XML-escaped.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crate::model::{Access, DataType, Description, Object, ObjectCode, PdoMapping, SubObject, Value, WriteCondition};
use crate::sii;

/// Direction of a PDO.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Receive PDO (master to drive), mapping objects 0x1600..=0x17FF, assignment 0x1C12, SM2.
    Rx,
    /// Transmit PDO (drive to master), mapping objects 0x1A00..=0x1BFF, assignment 0x1C13, SM3.
    Tx,
}

impl Direction {
    /// The range of mapping-object indices (CiA 301 §7.5.2.36/38).
    pub const fn mapping_range(self) -> std::ops::RangeInclusive<u16> {
        match self {
            Self::Rx => 0x1600..=0x17FF,
            Self::Tx => 0x1A00..=0x1BFF,
        }
    }

    /// The PDO assignment object of the process-data sync manager (ETG.1000.6 §5.6.7.4).
    pub const fn assign_index(self) -> u16 {
        match self {
            Self::Rx => 0x1C12,
            Self::Tx => 0x1C13,
        }
    }

    /// The sync manager that carries these PDOs (SM2 outputs, SM3 inputs).
    pub const fn sync_manager(self) -> u8 {
        match self {
            Self::Rx => 2,
            Self::Tx => 3,
        }
    }
}

/// One entry of a default PDO mapping (mapping value `index << 16 | sub << 8 | bits`, IDX L2194).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PdoEntryLayout {
    /// Mapped object index (0 for a gap).
    pub index: u16,
    /// Mapped sub-index.
    pub sub: u8,
    /// Length in bits.
    pub bit_len: u8,
    /// Name of the mapped entry (empty for a gap or an entry the dictionary does not declare).
    pub name: String,
    /// Data type of the mapped entry, if the dictionary declares it.
    pub data_type: Option<DataType>,
}

/// One PDO with its default mapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PdoLayout {
    /// Mapping object index (0x1600.., 0x1A00..).
    pub index: u16,
    /// Name of the mapping object.
    pub name: String,
    /// Sync manager the PDO is assigned to by default (0x1C12/0x1C13), if any.
    pub sync_manager: Option<u8>,
    /// Whether the mapping cannot be changed (sub 0 not writable).
    pub fixed: bool,
    /// Mapped entries in order.
    pub entries: Vec<PdoEntryLayout>,
}

impl PdoLayout {
    /// Total length of the mapped entries in bits.
    pub fn bit_len(&self) -> u32 {
        self.entries.iter().map(|e| u32::from(e.bit_len)).sum()
    }
}

fn int_default(s: &SubObject) -> Option<i128> {
    match s.default {
        Value::Int(v) => Some(v),
        _ => None,
    }
}

/// The PDOs indices assigned by default to the sync manager of `dir` (defaults of 0x1C12/0x1C13 subs
/// 1..=sub 0).
pub fn assigned_pdos(d: &Description, dir: Direction) -> Vec<u16> {
    let Some(obj) = d.object(dir.assign_index()) else {
        return Vec::new();
    };
    let count = obj.subs.iter().find(|s| s.sub == 0).and_then(int_default).unwrap_or(0);
    obj.subs
        .iter()
        .filter(|s| s.sub >= 1 && i128::from(s.sub) <= count)
        .filter_map(int_default)
        .filter_map(|v| u16::try_from(v).ok())
        .filter(|&v| v != 0)
        .collect()
}

/// Every PDO mapping object of direction `dir` with its default mapping, in index order.
pub fn pdos(d: &Description, dir: Direction) -> Vec<PdoLayout> {
    let assigned = assigned_pdos(d, dir);
    d.objects
        .iter()
        .filter(|o| dir.mapping_range().contains(&o.index))
        .map(|o| {
            let sub0 = o.subs.iter().find(|s| s.sub == 0);
            let count = sub0.and_then(int_default).unwrap_or(0);
            let fixed = sub0.is_none_or(|s| !matches!(s.access, Access::ReadWrite | Access::WriteOnly));
            let entries = o
                .subs
                .iter()
                .filter(|s| s.sub >= 1 && i128::from(s.sub) <= count)
                .filter_map(int_default)
                .map(|v| mapping_entry(d, v))
                .collect();
            PdoLayout {
                index: o.index,
                name: o.name.clone(),
                sync_manager: assigned.contains(&o.index).then_some(dir.sync_manager()),
                fixed,
                entries,
            }
        })
        .collect()
}

/// The default-assigned PDOs of `dir`, in assignment order.
pub fn assigned_pdo_layouts(d: &Description, dir: Direction) -> Vec<PdoLayout> {
    let all = pdos(d, dir);
    assigned_pdos(d, dir).iter().filter_map(|i| all.iter().find(|p| p.index == *i).cloned()).collect()
}

/// Size in bytes of the process image of `dir` with the default assignment.
pub fn process_image_bytes(d: &Description, dir: Direction) -> u16 {
    let bits: u32 = assigned_pdo_layouts(d, dir).iter().map(PdoLayout::bit_len).sum();
    u16::try_from(bits.div_ceil(8)).unwrap_or(u16::MAX)
}

fn mapping_entry(d: &Description, v: i128) -> PdoEntryLayout {
    // Mapping value layout: bits 31..16 index, 15..8 sub-index, 7..0 length (IDX L2194).
    let raw = (v as u64 & 0xFFFF_FFFF) as u32;
    let index = (raw >> 16) as u16;
    let sub = ((raw >> 8) & 0xFF) as u8;
    let bit_len = (raw & 0xFF) as u8;
    let entry = d.object(index).and_then(|o| {
        o.subs.iter().find(|s| s.sub == sub).map(|s| {
            let name = if o.code == ObjectCode::Var { o.name.clone() } else { s.name.clone() };
            (name, s.data_type)
        })
    });
    PdoEntryLayout {
        index,
        sub,
        bit_len,
        name: entry.as_ref().map(|e| e.0.clone()).unwrap_or_default(),
        data_type: entry.map(|e| e.1),
    }
}

/// The ETG.2000 base-type name of a data type (`UINT`, `STRING(32)`...); `len` is the capacity of strings.
pub fn etg_type_name(t: DataType, len: usize) -> String {
    match t {
        DataType::Boolean => "BOOL".into(),
        DataType::Integer8 => "SINT".into(),
        DataType::Integer16 => "INT".into(),
        DataType::Integer32 => "DINT".into(),
        DataType::Integer64 => "LINT".into(),
        DataType::Unsigned8 => "USINT".into(),
        DataType::Unsigned16 => "UINT".into(),
        DataType::Unsigned32 => "UDINT".into(),
        DataType::Unsigned64 => "ULINT".into(),
        DataType::VisibleString => format!("STRING({len})"),
        DataType::OctetString => format!("OCTET_STRING({len})"),
        DataType::Domain => "DOMAIN".into(),
    }
}

/// Capacity in bytes of a string or domain entry (declared length, else the default's length).
fn capacity(s: &SubObject) -> usize {
    s.length.unwrap_or(match &s.default {
        Value::Text(t) => t.len(),
        _ => 0,
    })
}

/// Size of an entry in bits (ETG.2000 `BitSize`): 1 for BOOL, the capacity for strings, 0 for DOMAIN.
pub fn bit_size(s: &SubObject) -> usize {
    match s.data_type {
        DataType::Boolean => 1,
        DataType::VisibleString | DataType::OctetString => capacity(s) * 8,
        DataType::Domain => 0,
        t => t.fixed_size().unwrap_or(0) * 8,
    }
}

fn type_name(s: &SubObject) -> String {
    etg_type_name(s.data_type, capacity(s))
}

/// The default value of an entry as the bytes the firmware holds (little endian; `$NODEID+x` resolved with
/// the default node-ID), or `None` when it has no default.
pub fn default_bytes(s: &SubObject, node_id: u8) -> Option<Vec<u8>> {
    let int = match &s.default {
        Value::None => return None,
        Value::Text(t) => return Some(t.as_bytes().to_vec()),
        Value::Int(v) => *v,
        Value::NodeIdPlus(off) => off + i128::from(node_id),
    };
    let size = s.data_type.fixed_size()?;
    Some(int.to_le_bytes().get(..size)?.to_vec())
}

/// XML text and attribute escaping.
pub fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if (c as u32) < 0x20 && c != '\n' && c != '\t' => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

fn access_xml(s: &SubObject) -> String {
    let a = match s.access {
        Access::ReadOnly | Access::Const => "ro",
        Access::WriteOnly => "wo",
        Access::ReadWrite => "rw",
    };
    let writable = matches!(s.access, Access::ReadWrite | Access::WriteOnly);
    let pre_op = matches!(s.writable_in, WriteCondition::PreOperational | WriteCondition::PreOperationalPowerDisabled);
    if writable && pre_op {
        format!("<Access WriteRestrictions=\"PreOP\">{a}</Access>")
    } else {
        format!("<Access>{a}</Access>")
    }
}

fn pdo_flag_xml(s: &SubObject) -> &'static str {
    match s.pdo {
        PdoMapping::No => "",
        PdoMapping::Rx => "<PdoMapping>R</PdoMapping>",
        PdoMapping::Tx => "<PdoMapping>T</PdoMapping>",
        PdoMapping::Both => "<PdoMapping>RT</PdoMapping>",
    }
}

/// Whether an ARRAY object can be described with an ETG `ArrayInfo` type: subs 1..=n consecutive, one
/// fixed-size type, the same access and PDO flag.
fn uniform_array(o: &Object) -> bool {
    let elems: Vec<&SubObject> = o.subs.iter().filter(|s| s.sub >= 1).collect();
    let Some(first) = elems.first() else {
        return false;
    };
    o.code == ObjectCode::Array
        && first.data_type.fixed_size().is_some()
        && elems.iter().enumerate().all(|(i, s)| {
            usize::from(s.sub) == i + 1
                && s.data_type == first.data_type
                && s.access == first.access
                && s.pdo == first.pdo
                && s.writable_in == first.writable_in
        })
}

/// Appends the `DataType` elements an ARRAY/RECORD object needs; returns the object's total bit size.
fn compound_types(o: &Object, types: &mut BTreeMap<String, String>) -> usize {
    let dt = format!("DT{:04X}", o.index);
    let mut body = String::new();
    let mut offset = 0usize;
    let sub_item = |body: &mut String, sub: Option<u8>, name: &str, ty: &str, bits: usize, offs: usize, flags: &str| {
        let _ = write!(body, "\t\t\t\t\t\t<SubItem>");
        if let Some(sub) = sub {
            let _ = write!(body, "<SubIdx>{sub}</SubIdx>");
        }
        let _ = writeln!(
            body,
            "<Name>{}</Name><Type>{}</Type><BitSize>{bits}</BitSize><BitOffs>{offs}</BitOffs><Flags>{flags}</Flags></SubItem>",
            xml_escape(name),
            xml_escape(ty)
        );
    };
    if let Some(sub0) = o.subs.iter().find(|s| s.sub == 0) {
        sub_item(&mut body, Some(0), &sub0.name, &type_name(sub0), 8, 0, &access_xml(sub0));
        types.entry("USINT".into()).or_insert_with(|| base_type("USINT", 8));
        offset = 16;
    }
    if uniform_array(o) {
        let elems: Vec<&SubObject> = o.subs.iter().filter(|s| s.sub >= 1).collect();
        if let Some(first) = elems.first() {
            let elem_bits = bit_size(first);
            let n = elems.len();
            let base = type_name(first);
            types.entry(base.clone()).or_insert_with(|| base_type(&base, elem_bits));
            let arr = format!("{dt}ARR");
            types.insert(
                arr.clone(),
                format!(
                    "\t\t\t\t\t<DataType>\n\t\t\t\t\t\t<Name>{arr}</Name>\n\t\t\t\t\t\t<BaseType>{}</BaseType>\n\t\t\t\t\t\t<BitSize>{}</BitSize>\n\t\t\t\t\t\t<ArrayInfo><LBound>1</LBound><Elements>{n}</Elements></ArrayInfo>\n\t\t\t\t\t</DataType>\n",
                    xml_escape(&base),
                    elem_bits * n
                ),
            );
            let flags = format!("{}{}", access_xml(first), pdo_flag_xml(first));
            sub_item(&mut body, None, "Elements", &arr, elem_bits * n, offset, &flags);
            offset += elem_bits * n;
        }
    } else {
        for s in o.subs.iter().filter(|s| s.sub >= 1) {
            let bits = bit_size(s);
            let ty = type_name(s);
            types.entry(ty.clone()).or_insert_with(|| base_type(&ty, bits));
            if bits >= 16 {
                offset = offset.next_multiple_of(16);
            }
            let flags = format!("{}{}", access_xml(s), pdo_flag_xml(s));
            sub_item(&mut body, Some(s.sub), &s.name, &ty, bits, offset, &flags);
            offset += bits;
        }
    }
    let total = offset.next_multiple_of(8);
    types.insert(
        dt.clone(),
        format!(
            "\t\t\t\t\t<DataType>\n\t\t\t\t\t\t<Name>{dt}</Name>\n\t\t\t\t\t\t<BitSize>{total}</BitSize>\n{body}\t\t\t\t\t</DataType>\n"
        ),
    );
    total
}

fn base_type(name: &str, bits: usize) -> String {
    format!(
        "\t\t\t\t\t<DataType>\n\t\t\t\t\t\t<Name>{}</Name>\n\t\t\t\t\t\t<BitSize>{bits}</BitSize>\n\t\t\t\t\t</DataType>\n",
        xml_escape(name)
    )
}

fn object_xml(o: &Object, node_id: u8, types: &mut BTreeMap<String, String>) -> String {
    let mut x = String::new();
    let _ = writeln!(x, "\t\t\t\t\t<Object>");
    let _ = writeln!(x, "\t\t\t\t\t\t<Index>#x{:04X}</Index>", o.index);
    let _ = writeln!(x, "\t\t\t\t\t\t<Name>{}</Name>", xml_escape(&o.name));
    match o.code {
        ObjectCode::Var => {
            let Some(s) = o.subs.first() else {
                return String::new();
            };
            let ty = type_name(s);
            let bits = bit_size(s);
            types.entry(ty.clone()).or_insert_with(|| base_type(&ty, bits));
            let _ = writeln!(x, "\t\t\t\t\t\t<Type>{}</Type>", xml_escape(&ty));
            let _ = writeln!(x, "\t\t\t\t\t\t<BitSize>{bits}</BitSize>");
            if let Some(b) = default_bytes(s, node_id) {
                let _ = writeln!(x, "\t\t\t\t\t\t<Info><DefaultData>{}</DefaultData></Info>", hex(&b));
            }
            let _ = writeln!(x, "\t\t\t\t\t\t<Flags>{}{}</Flags>", access_xml(s), pdo_flag_xml(s));
        }
        ObjectCode::Array | ObjectCode::Record => {
            let bits = compound_types(o, types);
            let _ = writeln!(x, "\t\t\t\t\t\t<Type>DT{:04X}</Type>", o.index);
            let _ = writeln!(x, "\t\t\t\t\t\t<BitSize>{bits}</BitSize>");
            let _ = writeln!(x, "\t\t\t\t\t\t<Info>");
            for s in &o.subs {
                let _ = write!(x, "\t\t\t\t\t\t\t<SubItem><Name>{}</Name>", xml_escape(&s.name));
                if let Some(b) = default_bytes(s, node_id) {
                    let _ = write!(x, "<Info><DefaultData>{}</DefaultData></Info>", hex(&b));
                }
                let _ = writeln!(x, "</SubItem>");
            }
            let _ = writeln!(x, "\t\t\t\t\t\t</Info>");
            let sub0 = o.subs.iter().find(|s| s.sub == 0);
            let flags = sub0.map(access_xml).unwrap_or_else(|| "<Access>ro</Access>".into());
            let _ = writeln!(x, "\t\t\t\t\t\t<Flags>{flags}</Flags>");
        }
    }
    let _ = writeln!(x, "\t\t\t\t\t</Object>");
    x
}

fn pdo_xml(out: &mut String, d: &Description, dir: Direction) {
    let tag = match dir {
        Direction::Rx => "RxPdo",
        Direction::Tx => "TxPdo",
    };
    let all = pdos(d, dir);
    // With a single assignment entry (0x1C12/0x1C13 highest sub-index 1) the PDOs exclude each other.
    let exclusive = d.object(dir.assign_index()).is_some_and(|o| o.subs.iter().map(|s| s.sub).max() == Some(1));
    for p in &all {
        let mut attrs = format!(" Fixed=\"{}\"", if p.fixed { "1" } else { "0" });
        if let Some(sm) = p.sync_manager {
            let _ = write!(attrs, " Sm=\"{sm}\"");
        }
        let _ = writeln!(out, "\t\t\t\t<{tag}{attrs}>");
        let _ = writeln!(out, "\t\t\t\t\t<Index>#x{:04X}</Index>", p.index);
        let _ = writeln!(out, "\t\t\t\t\t<Name>{}</Name>", xml_escape(&p.name));
        if exclusive {
            for other in all.iter().filter(|o| o.index != p.index) {
                let _ = writeln!(out, "\t\t\t\t\t<Exclude>#x{:04X}</Exclude>", other.index);
            }
        }
        for e in &p.entries {
            if e.index == 0 || e.data_type.is_none() {
                // A gap in the mapping (CiA 301 dummy entry or padding).
                let _ = writeln!(
                    out,
                    "\t\t\t\t\t<Entry><Index>#x{:04X}</Index><SubIndex>{}</SubIndex><BitLen>{}</BitLen></Entry>",
                    e.index, e.sub, e.bit_len
                );
                continue;
            }
            let ty = e.data_type.map(|t| etg_type_name(t, usize::from(e.bit_len / 8))).unwrap_or_default();
            let _ = writeln!(
                out,
                "\t\t\t\t\t<Entry><Index>#x{:04X}</Index><SubIndex>{}</SubIndex><BitLen>{}</BitLen><Name>{}</Name><DataType>{}</DataType></Entry>",
                e.index,
                e.sub,
                e.bit_len,
                xml_escape(&e.name),
                xml_escape(&ty)
            );
        }
        let _ = writeln!(out, "\t\t\t\t</{tag}>");
    }
}

/// Renders the ETG.2000 ESI XML of `d`.
pub fn esi(d: &Description) -> String {
    let dev = &d.device;
    let features = sii::MailboxFeatures::of(d);
    let group = xml_escape(&dev.group_name);
    let mut x = String::new();
    x.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    x.push_str("<!-- @generated by od-gen from firmware/device.toml. Do not edit. -->\n");
    x.push_str(
        "<EtherCATInfo xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" xsi:noNamespaceSchemaLocation=\"EtherCATInfo.xsd\" Version=\"1.6\">\n",
    );
    let _ = writeln!(
        x,
        "\t<Vendor>\n\t\t<Id>#x{:08X}</Id>\n\t\t<Name>{}</Name>\n\t</Vendor>",
        dev.vendor_id,
        xml_escape(&dev.vendor_name)
    );
    x.push_str("\t<Descriptions>\n");
    let _ = writeln!(x, "\t\t<Groups>\n\t\t\t<Group>\n\t\t\t\t<Type>{group}</Type>\n\t\t\t\t<Name LcId=\"1033\">{group}</Name>\n\t\t\t</Group>\n\t\t</Groups>");
    x.push_str("\t\t<Devices>\n\t\t\t<Device Physics=\"YY\">\n");
    let _ = writeln!(
        x,
        "\t\t\t\t<Type ProductCode=\"#x{:08X}\" RevisionNo=\"#x{:08X}\">{}</Type>",
        dev.product_code,
        dev.revision,
        xml_escape(&dev.order_code)
    );
    let _ = writeln!(x, "\t\t\t\t<Name LcId=\"1033\">{}</Name>", xml_escape(&dev.device_name));
    let _ = writeln!(x, "\t\t\t\t<GroupType>{group}</GroupType>");

    // Profile: CiA 402 channel and the whole dictionary.
    let mut types: BTreeMap<String, String> = BTreeMap::new();
    let objects: String = d.objects.iter().map(|o| object_xml(o, dev.node_id, &mut types)).collect();
    x.push_str("\t\t\t\t<Profile>\n");
    let _ = writeln!(
        x,
        "\t\t\t\t\t<ChannelInfo>\n\t\t\t\t\t\t<ProfileNo>{}</ProfileNo>\n\t\t\t\t\t\t<AddInfo>{}</AddInfo>\n\t\t\t\t\t</ChannelInfo>",
        dev.device_type & 0xFFFF,
        (dev.device_type >> 16) & 0xFF
    );
    x.push_str("\t\t\t\t\t<Dictionary>\n\t\t\t\t\t\t<DataTypes>\n");
    for body in types.values() {
        // Data types sit two levels deeper than the shared indentation of their bodies.
        for line in body.lines() {
            let _ = writeln!(x, "\t\t{line}");
        }
    }
    x.push_str("\t\t\t\t\t\t</DataTypes>\n\t\t\t\t\t\t<Objects>\n");
    for line in objects.lines() {
        let _ = writeln!(x, "\t\t{line}");
    }
    x.push_str("\t\t\t\t\t\t</Objects>\n\t\t\t\t\t</Dictionary>\n\t\t\t\t</Profile>\n");

    // FMMUs and sync managers (ETG.2000 §5.3.4, same layout as SII categories 40/41).
    x.push_str("\t\t\t\t<Fmmu>Outputs</Fmmu>\n\t\t\t\t<Fmmu>Inputs</Fmmu>\n\t\t\t\t<Fmmu>MBoxState</Fmmu>\n");
    for sm in sii::sync_managers(d) {
        let name = match sm.kind {
            sii::SmKind::MailboxOut => "MBoxOut",
            sii::SmKind::MailboxIn => "MBoxIn",
            sii::SmKind::Outputs => "Outputs",
            sii::SmKind::Inputs => "Inputs",
            sii::SmKind::Unused(_) => continue,
        };
        let _ = writeln!(
            x,
            "\t\t\t\t<Sm DefaultSize=\"{}\" StartAddress=\"#x{:04X}\" ControlByte=\"#x{:02X}\" Enable=\"{}\">{name}</Sm>",
            sm.length,
            sm.start,
            sm.control,
            u8::from(sm.enable & 1 == 1)
        );
    }
    pdo_xml(&mut x, d, Direction::Rx);
    pdo_xml(&mut x, d, Direction::Tx);

    // Mailbox protocols (ETG.2000 §5.3.6): CoE and FoE, as the SII announces them.
    let b = |v: bool| if v { "true" } else { "false" };
    let _ = writeln!(
        x,
        "\t\t\t\t<Mailbox>\n\t\t\t\t\t<CoE SdoInfo=\"{}\" PdoAssign=\"{}\" PdoConfig=\"{}\" CompleteAccess=\"{}\"/>",
        b(features.sdo_info),
        b(features.pdo_assign),
        b(features.pdo_config),
        b(features.complete_access)
    );
    if features.foe {
        x.push_str("\t\t\t\t\t<FoE/>\n");
    }
    x.push_str("\t\t\t\t</Mailbox>\n");

    // Synchronisation modes (0x1C32/0x1C33:01 = 0 free run, 1 SM2 event, 2 DC SYNC0).
    x.push_str("\t\t\t\t<Dc>\n");
    for (name, desc, activate, sync0) in [
        ("FreeRun", "Free Run", 0x0000u16, false),
        ("SM-Synchron", "SM-Synchron", 0x0000, false),
        ("DC", "DC-Synchron (SYNC0)", 0x0300, true),
    ] {
        let _ = write!(
            x,
            "\t\t\t\t\t<OpMode>\n\t\t\t\t\t\t<Name>{name}</Name>\n\t\t\t\t\t\t<Desc>{desc}</Desc>\n\t\t\t\t\t\t<AssignActivate>#x{activate:04X}</AssignActivate>\n"
        );
        if sync0 {
            x.push_str("\t\t\t\t\t\t<CycleTimeSync0 Factor=\"1\">0</CycleTimeSync0>\n\t\t\t\t\t\t<ShiftTimeSync0>0</ShiftTimeSync0>\n");
        }
        x.push_str("\t\t\t\t\t</OpMode>\n");
    }
    x.push_str("\t\t\t\t</Dc>\n");

    // EEPROM: size, ESC configuration words 0..6 and the bootstrap mailbox (SII words 0x14..0x17).
    let config: Vec<u8> = sii::ESC_CONFIG.iter().flat_map(|w| w.to_le_bytes()).collect();
    let boot: Vec<u8> = [dev.mailbox_out_start, dev.mailbox_out_size, dev.mailbox_in_start, dev.mailbox_in_size]
        .iter()
        .flat_map(|w| w.to_le_bytes())
        .collect();
    let _ = writeln!(
        x,
        "\t\t\t\t<Eeprom>\n\t\t\t\t\t<ByteSize>{}</ByteSize>\n\t\t\t\t\t<ConfigData>{}</ConfigData>\n\t\t\t\t\t<BootStrap>{}</BootStrap>\n\t\t\t\t</Eeprom>",
        sii::eeprom_byte_size(d),
        hex(&config),
        hex(&boot)
    );
    x.push_str("\t\t\t</Device>\n\t\t</Devices>\n\t</Descriptions>\n</EtherCATInfo>\n");
    x
}
