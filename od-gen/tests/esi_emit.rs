//! Unit tests of the ETG.2000 ESI emitter and the default PDO layout on the fixture dictionary.

mod esi_fixture;

use od_gen::esi::{self, Direction};

/// A minimal XML well-formedness check: balanced start/end tags, quoted attributes, no bare `&` or `<` in
/// text. (The drive-tests package parses the real ESI with a full XML parser.)
fn check_well_formed(xml: &str) {
    let mut stack: Vec<String> = Vec::new();
    let mut rest = xml;
    while let Some(lt) = rest.find('<') {
        let text = &rest[..lt];
        for (i, _) in text.match_indices('&') {
            let ent = &text[i..];
            assert!(
                ["&amp;", "&lt;", "&gt;", "&quot;", "&apos;"].iter().any(|e| ent.starts_with(e)),
                "bare & in text near {:?}",
                &text[i..text.len().min(i + 20)]
            );
        }
        let gt = rest[lt..].find('>').expect("unclosed tag") + lt;
        let tag = &rest[lt + 1..gt];
        rest = &rest[gt + 1..];
        if tag.starts_with('?') || tag.starts_with("!--") {
            continue;
        }
        assert!(!tag.contains('<'), "'<' inside tag {tag:?}");
        assert_eq!(tag.matches('"').count() % 2, 0, "unbalanced quotes in {tag:?}");
        if let Some(name) = tag.strip_prefix('/') {
            assert_eq!(stack.pop().as_deref(), Some(name), "mismatched </{name}>");
        } else if !tag.ends_with('/') {
            stack.push(tag.split_whitespace().next().unwrap().to_string());
        }
    }
    assert!(stack.is_empty(), "unclosed elements {stack:?}");
}

/// The text of every `<tag>...</tag>` in order.
fn texts<'a>(xml: &'a str, tag: &str) -> Vec<&'a str> {
    let open = format!("<{tag}>");
    let close = format!("</{tag}>");
    xml.match_indices(&open)
        .map(|(i, _)| {
            let start = i + open.len();
            let end = xml[start..].find(&close).unwrap() + start;
            &xml[start..end]
        })
        .collect()
}

#[test]
fn esi_is_well_formed_and_deterministic() {
    let d = esi_fixture::description();
    let xml = esi::esi(&d);
    assert_eq!(xml, esi::esi(&d));
    check_well_formed(&xml);
    assert!(xml.starts_with("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"));
}

#[test]
fn texts_are_escaped() {
    let mut d = esi_fixture::description();
    d.device.vendor_name = "R&D <\"servo\"> 'lab'".into();
    d.objects[0].name = "A<B & C".into();
    let xml = esi::esi(&d);
    check_well_formed(&xml);
    assert!(xml.contains("<Name>R&amp;D &lt;&quot;servo&quot;&gt; &apos;lab&apos;</Name>"));
    assert!(xml.contains("<Name>A&lt;B &amp; C</Name>"));
}

#[test]
fn identity_and_profile() {
    let xml = esi::esi(&esi_fixture::description());
    assert!(xml.contains("<Id>#x00000ACE</Id>"));
    assert!(xml.contains("<Type ProductCode=\"#x00010001\" RevisionNo=\"#x00010000\">OSD-402-24V-10A</Type>"));
    assert!(xml.contains("<Name LcId=\"1033\">OSD-402</Name>"));
    assert!(xml.contains("<GroupType>Servo drives</GroupType>"));
    assert!(xml.contains("<ProfileNo>402</ProfileNo>"));
    assert!(xml.contains("<AddInfo>2</AddInfo>"));
}

#[test]
fn every_object_is_in_the_dictionary() {
    let d = esi_fixture::description();
    let xml = esi::esi(&d);
    let indices: Vec<String> = d.objects.iter().map(|o| format!("#x{:04X}", o.index)).collect();
    let declared: Vec<&str> = texts(&xml, "Index").into_iter().take(indices.len()).collect();
    assert_eq!(declared, indices, "objects in index order, before the PDO elements");
    // A VAR with its default, little endian; a record with one default per sub-item; restricted writes.
    assert!(xml.contains("<Index>#x1000</Index>"));
    assert!(xml.contains("<DefaultData>92010200</DefaultData>"));
    assert!(xml.contains("<SubItem><Name>Vendor ID</Name><Info><DefaultData>CE0A0000</DefaultData></Info></SubItem>"));
    assert!(xml.contains("<DefaultData>FBFFFFFF</DefaultData>"), "-5 as INT32");
    assert!(xml.contains("<DefaultData>01020000</DefaultData>"), "$NODEID+0x200 with node-ID 1");
    assert!(xml.contains("<DefaultData>4F53442D343032</DefaultData>"), "string default as its bytes");
    assert!(xml.contains("<Type>STRING(16)</Type>"));
    assert!(xml.contains("<Flags><Access>rw</Access><PdoMapping>R</PdoMapping></Flags>"));
    assert!(xml.contains("<Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags>"));
    assert!(xml.contains("<Access WriteRestrictions=\"PreOP\">rw</Access>"));
    assert!(xml.contains("<Name>DT1C12ARR</Name>"));
    for t in ["USINT", "UINT", "UDINT", "INT", "DINT", "DT1018", "DT1600"] {
        assert!(xml.contains(&format!("<Name>{t}</Name>")), "data type {t} declared");
    }
}

#[test]
fn default_pdo_layout() {
    let d = esi_fixture::description();
    assert_eq!(esi::assigned_pdos(&d, Direction::Rx), [0x1600]);
    assert_eq!(esi::assigned_pdos(&d, Direction::Tx), [0x1A00]);
    let rx = esi::pdos(&d, Direction::Rx);
    assert_eq!(rx.len(), 2);
    assert_eq!(rx[0].sync_manager, Some(2));
    assert_eq!(rx[1].sync_manager, None);
    assert!(!rx[0].fixed);
    let e = &rx[1].entries[1];
    assert_eq!((e.index, e.sub, e.bit_len, e.name.as_str()), (0x607A, 0, 32, "Target position"));
    assert_eq!(esi::process_image_bytes(&d, Direction::Rx), 2);
    assert_eq!(esi::process_image_bytes(&d, Direction::Tx), 7);
}

#[test]
fn sync_managers_pdos_mailbox_dc_eeprom() {
    let xml = esi::esi(&esi_fixture::description());
    assert!(
        xml.contains("<Sm DefaultSize=\"128\" StartAddress=\"#x1000\" ControlByte=\"#x26\" Enable=\"1\">MBoxOut</Sm>")
    );
    assert!(
        xml.contains("<Sm DefaultSize=\"128\" StartAddress=\"#x1080\" ControlByte=\"#x22\" Enable=\"1\">MBoxIn</Sm>")
    );
    assert!(
        xml.contains("<Sm DefaultSize=\"2\" StartAddress=\"#x1100\" ControlByte=\"#x64\" Enable=\"1\">Outputs</Sm>")
    );
    assert!(xml.contains("<Sm DefaultSize=\"7\" StartAddress=\"#x1180\" ControlByte=\"#x20\" Enable=\"1\">Inputs</Sm>"));
    assert_eq!(texts(&xml, "Fmmu"), ["Outputs", "Inputs", "MBoxState"]);
    assert!(xml.contains("<RxPdo Fixed=\"0\" Sm=\"2\">\n\t\t\t\t\t<Index>#x1600</Index>"));
    assert!(xml.contains("<RxPdo Fixed=\"0\">\n\t\t\t\t\t<Index>#x1601</Index>"));
    assert!(xml.contains("<TxPdo Fixed=\"0\" Sm=\"3\">\n\t\t\t\t\t<Index>#x1A00</Index>"));
    assert!(xml.contains("<Exclude>#x1601</Exclude>"), "one PDO per SM: the others are excluded");
    assert!(xml.contains(
        "<Entry><Index>#x6064</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Position actual value</Name><DataType>DINT</DataType></Entry>"
    ));
    assert!(xml.contains("<CoE SdoInfo=\"true\" PdoAssign=\"true\" PdoConfig=\"true\" CompleteAccess=\"true\"/>"));
    assert!(xml.contains("<FoE/>"));
    assert!(xml.contains("<AssignActivate>#x0300</AssignActivate>"));
    assert_eq!(texts(&xml, "Name").iter().filter(|n| ["FreeRun", "SM-Synchron", "DC"].contains(n)).count(), 3);
    assert!(xml.contains("<ByteSize>2048</ByteSize>"));
    assert!(xml.contains("<ConfigData>050C030EE8030000000000000000</ConfigData>"), "words 0..=6 of the SII");
    assert!(xml.contains("<BootStrap>0010800080108000</BootStrap>"));
}
