//! Unit tests of the CiA 306 EDS emitter on the fixture dictionary.

mod esi_fixture;

use std::collections::BTreeMap;

/// Sections of an EDS as `header -> [(key, value)]`, checking the layout both readers rely on: sections
/// separated by exactly one blank line, `key=value` lines with a single `=`, no blank line inside a section.
fn sections(eds: &str) -> BTreeMap<String, Vec<(String, String)>> {
    assert!(eds.ends_with('\n') && !eds.ends_with("\n\n"), "the file ends with one line break");
    assert!(!eds.contains("\n\n\n"), "sections are separated by exactly one blank line");
    let mut out = BTreeMap::new();
    for block in eds.trim_end().split("\n\n") {
        let mut lines = block.lines();
        let header = lines.next().expect("a section has a header");
        assert!(header.starts_with('[') && header.ends_with(']'), "bad header {header:?}");
        let mut keys = Vec::new();
        for line in lines {
            let parts: Vec<&str> = line.split('=').collect();
            assert_eq!(parts.len(), 2, "line {line:?} in {header} must hold exactly one '='");
            assert!(!line.contains(';'), "line {line:?} would be cut by an inline comment");
            keys.push((parts[0].to_string(), parts[1].to_string()));
        }
        let name = header.trim_start_matches('[').trim_end_matches(']').to_string();
        assert!(out.insert(name.clone(), keys).is_none(), "duplicate section {name}");
    }
    out
}

fn get<'a>(s: &'a BTreeMap<String, Vec<(String, String)>>, section: &str, key: &str) -> Option<&'a str> {
    s.get(section)?.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

#[test]
fn eds_is_deterministic_and_has_the_header_sections() {
    let d = esi_fixture::description();
    let eds = od_gen::eds::eds(&d);
    assert_eq!(eds, od_gen::eds::eds(&d));
    let s = sections(&eds);
    assert_eq!(get(&s, "FileInfo", "CreationDate"), Some("01-01-2026"));
    assert_eq!(get(&s, "FileInfo", "CreationTime"), Some("12:00PM"));
    assert_eq!(get(&s, "FileInfo", "FileName"), Some("osd-402.eds"));
    assert_eq!(get(&s, "DeviceInfo", "VendorNumber"), Some("0x00000ACE"));
    assert_eq!(get(&s, "DeviceInfo", "ProductNumber"), Some("0x00010001"));
    assert_eq!(get(&s, "DeviceInfo", "RevisionNumber"), Some("0x00010000"));
    assert_eq!(get(&s, "DeviceInfo", "ProductName"), Some("OSD-402-24V-10A"));
    assert_eq!(get(&s, "DeviceInfo", "BaudRate_1000"), Some("1"));
    assert_eq!(get(&s, "DeviceInfo", "LSS_Supported"), Some("1"));
    assert_eq!(get(&s, "DeviceInfo", "NrOfRXPDO"), Some("2"));
    assert_eq!(get(&s, "DeviceInfo", "NrOfTXPDO"), Some("2"));
    for i in 1..=7 {
        assert_eq!(get(&s, "DummyUsage", &format!("Dummy{i:04}")), Some("0"));
    }
    let lines: usize = get(&s, "Comments", "Lines").unwrap().parse().unwrap();
    assert!(lines >= 2);
    assert!(get(&s, "Comments", &format!("Line{lines}")).is_some());
    assert!(get(&s, "Comments", "Line3").unwrap().contains("0x1600, 0x1601"), "pre-op-only objects are listed");
}

#[test]
fn object_lists_partition_the_dictionary() {
    let d = esi_fixture::description();
    let s = sections(&od_gen::eds::eds(&d));
    let list = |name: &str| -> Vec<String> {
        let n: usize = get(&s, name, "SupportedObjects").unwrap().parse().unwrap();
        (1..=n).map(|i| get(&s, name, &i.to_string()).unwrap().to_string()).collect()
    };
    assert_eq!(list("MandatoryObjects"), ["0x1000", "0x1001", "0x1018"]);
    assert_eq!(list("ManufacturerObjects"), ["0x2000", "0x2100"]);
    let optional = list("OptionalObjects");
    assert!(optional.contains(&"0x1600".to_string()) && optional.contains(&"0x607A".to_string()));
    assert_eq!(optional.len() + 5, d.objects.len());
}

#[test]
fn every_object_and_sub_object_has_its_section() {
    let d = esi_fixture::description();
    let s = sections(&od_gen::eds::eds(&d));
    for o in &d.objects {
        let header = format!("{:04X}", o.index);
        assert_eq!(get(&s, &header, "ParameterName"), Some(o.name.as_str()), "{header}");
        match o.code {
            od_gen::model::ObjectCode::Var => {
                assert_eq!(get(&s, &header, "ObjectType"), Some("0x7"));
                let t = format!("0x{:04X}", o.subs[0].data_type.code());
                assert_eq!(get(&s, &header, "DataType"), Some(t.as_str()));
            }
            code => {
                let c = if code == od_gen::model::ObjectCode::Array { "0x8" } else { "0x9" };
                assert_eq!(get(&s, &header, "ObjectType"), Some(c));
                let n = o.subs.len().to_string();
                assert_eq!(get(&s, &header, "SubNumber"), Some(n.as_str()));
                for sub in &o.subs {
                    let h = format!("{:04X}sub{:X}", o.index, sub.sub);
                    assert_eq!(get(&s, &h, "ParameterName"), Some(sub.name.as_str()), "{h}");
                    let t = format!("0x{:04X}", sub.data_type.code());
                    assert_eq!(get(&s, &h, "DataType"), Some(t.as_str()), "{h}");
                }
            }
        }
    }
}

#[test]
fn values_are_written_as_cia_306_wants() {
    let d = esi_fixture::description();
    let s = sections(&od_gen::eds::eds(&d));
    // Unsigned 32-bit values with all eight digits: eds-validate parses mapping entries by position.
    assert_eq!(get(&s, "1000", "DefaultValue"), Some("0x00020192"));
    assert_eq!(get(&s, "1600sub1", "DefaultValue"), Some("0x60400010"));
    assert_eq!(get(&s, "1600sub2", "DefaultValue"), Some("0x00000000"));
    assert_eq!(get(&s, "1600sub0", "DefaultValue"), Some("1"));
    assert_eq!(get(&s, "1600sub0", "LowLimit"), Some("0"));
    assert_eq!(get(&s, "1600sub0", "HighLimit"), Some("8"));
    // State-restricted writes are plain rw on CANopen.
    assert_eq!(get(&s, "1600sub1", "AccessType"), Some("rw"));
    assert_eq!(get(&s, "1018sub1", "AccessType"), Some("const"));
    assert_eq!(get(&s, "6041", "AccessType"), Some("ro"));
    assert_eq!(get(&s, "6041", "PDOMapping"), Some("1"));
    assert_eq!(get(&s, "605A", "PDOMapping"), Some("0"));
    // Node-relative defaults.
    assert_eq!(get(&s, "1400sub1", "DefaultValue"), Some("$NODEID+0x200"));
    // Signed values and limits in decimal; an option list becomes its lowest and highest value.
    assert_eq!(get(&s, "607A", "DefaultValue"), Some("-5"));
    assert_eq!(get(&s, "607A", "LowLimit"), Some("-1000000"));
    assert_eq!(get(&s, "605A", "LowLimit"), Some("0"));
    assert_eq!(get(&s, "605A", "HighLimit"), Some("6"));
    // Strings as text, octet strings as hex bytes.
    assert_eq!(get(&s, "1008", "DefaultValue"), Some("OSD-402"));
    assert_eq!(get(&s, "1008", "DataType"), Some("0x0009"));
    assert_eq!(get(&s, "2100", "DefaultValue"), Some("41 42 3D 3B"));
    // DOMAIN: a VAR of type 0x000F without default value.
    assert_eq!(get(&s, "1F50sub1", "DataType"), Some("0x000F"));
    assert_eq!(get(&s, "1F50sub1", "AccessType"), Some("wo"));
    assert_eq!(get(&s, "1F50sub1", "DefaultValue"), None);
}

#[test]
fn texts_are_made_safe_for_ini_readers() {
    let mut d = esi_fixture::description();
    d.objects[0].name = "Device = type; main\nline".into();
    d.objects[0].subs[0].name = d.objects[0].name.clone();
    let s = sections(&od_gen::eds::eds(&d));
    assert_eq!(get(&s, "1000", "ParameterName"), Some("Device - type, main line"));
}
