//! The EtherCAT ESI and SII image generated from `firmware/device.toml` against the dictionary they describe:
//! the ESI parses as XML (roxmltree) and its identity, sync managers and PDOs match the defaults of 0x1018,
//! 0x1600.., 0x1A00.., 0x1C12/0x1C13 and `[device]`; the SII decodes to the same identity, mailbox layout and
//! PDOs; ESI and SII agree with each other.
//!
//! The expected PDO content is recomputed here from the description's default values, independently of the
//! helpers od-gen uses to emit it.

use std::path::Path;

use od_gen::model::{DataType, Description, Value};
use od_gen::sii::{self, SmKind};
use roxmltree::{Document, Node};

fn description() -> Description {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/device.toml");
    od_gen::load(&path).expect("firmware/device.toml is valid")
}

fn int(d: &Description, index: u16, sub: u8) -> Option<i128> {
    match d.entry(index, sub)?.default {
        Value::Int(v) => Some(v),
        _ => None,
    }
}

/// ETG.2000 `#x1A00` or decimal.
fn num(s: &str) -> u64 {
    let s = s.trim();
    match s.strip_prefix("#x") {
        Some(h) => u64::from_str_radix(h, 16).unwrap_or_else(|_| panic!("bad hex {s}")),
        None => s.parse().unwrap_or_else(|_| panic!("bad number {s}")),
    }
}

fn child<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Node<'a, 'i> {
    n.children().find(|c| c.has_tag_name(name)).unwrap_or_else(|| panic!("<{}> has no <{name}>", n.tag_name().name()))
}

fn children<'a, 'i>(n: Node<'a, 'i>, name: &'a str) -> impl Iterator<Item = Node<'a, 'i>> + 'a {
    n.children().filter(move |c| c.has_tag_name(name))
}

fn text<'a>(n: Node<'a, '_>, name: &str) -> &'a str {
    child(n, name).text().unwrap_or("")
}

fn etg_name(t: DataType) -> &'static str {
    match t {
        DataType::Boolean => "BOOL",
        DataType::Integer8 => "SINT",
        DataType::Integer16 => "INT",
        DataType::Integer32 => "DINT",
        DataType::Integer64 => "LINT",
        DataType::Unsigned8 => "USINT",
        DataType::Unsigned16 => "UINT",
        DataType::Unsigned32 => "UDINT",
        DataType::Unsigned64 => "ULINT",
        _ => "",
    }
}

/// A PDO as the dictionary's defaults define it: (mapping index, assigned SM, [(index, sub, bits)]).
type Pdo = (u16, Option<u8>, Vec<(u16, u8, u8)>);

fn expected_pdos(d: &Description, range: std::ops::RangeInclusive<u16>, assign: u16, sm: u8) -> Vec<Pdo> {
    let n_assigned = int(d, assign, 0).unwrap_or(0);
    let assigned: Vec<u16> = (1..=n_assigned)
        .filter_map(|s| int(d, assign, u8::try_from(s).ok()?))
        .map(|v| u16::try_from(v).expect("PDO index"))
        .collect();
    d.objects
        .iter()
        .filter(|o| range.contains(&o.index))
        .map(|o| {
            let n = int(d, o.index, 0).unwrap_or(0);
            let entries = (1..=n)
                .map(|s| {
                    let v = u32::try_from(int(d, o.index, u8::try_from(s).unwrap()).unwrap()).unwrap();
                    ((v >> 16) as u16, (v >> 8) as u8, v as u8)
                })
                .collect();
            (o.index, assigned.contains(&o.index).then_some(sm), entries)
        })
        .collect()
}

fn esi_pdos(device: Node, tag: &str) -> Vec<Pdo> {
    children(device, tag)
        .map(|p| {
            let entries = children(p, "Entry")
                .map(|e| (num(text(e, "Index")) as u16, num(text(e, "SubIndex")) as u8, num(text(e, "BitLen")) as u8))
                .collect();
            (num(text(p, "Index")) as u16, p.attribute("Sm").map(|s| num(s) as u8), entries)
        })
        .collect()
}

#[test]
fn esi_matches_the_dictionary() {
    let d = description();
    let dev = &d.device;
    let xml = od_gen::esi::esi(&d);
    let doc = Document::parse(&xml).expect("the ESI is well-formed XML");
    let root = doc.root_element();
    assert!(root.has_tag_name("EtherCATInfo"));

    // Identity: [device] and the defaults of 0x1018 agree with the ESI.
    let vendor = child(root, "Vendor");
    assert_eq!(num(text(vendor, "Id")), u64::from(dev.vendor_id));
    assert_eq!(int(&d, 0x1018, 1), Some(dev.vendor_id.into()));
    assert_eq!(int(&d, 0x1018, 2), Some(dev.product_code.into()));
    assert_eq!(int(&d, 0x1018, 3), Some(dev.revision.into()));
    let devices = child(child(root, "Descriptions"), "Devices");
    let device = child(devices, "Device");
    let ty = child(device, "Type");
    assert_eq!(num(ty.attribute("ProductCode").unwrap()), u64::from(dev.product_code));
    assert_eq!(num(ty.attribute("RevisionNo").unwrap()), u64::from(dev.revision));
    assert_eq!(ty.text(), Some(dev.order_code.as_str()));
    assert_eq!(text(device, "Name"), dev.device_name);
    assert_eq!(text(device, "GroupType"), dev.group_name);

    // The whole dictionary, every object with its index, in order.
    let dict = child(child(device, "Profile"), "Dictionary");
    assert_eq!(num(text(child(child(device, "Profile"), "ChannelInfo"), "ProfileNo")), 402);
    let objects: Vec<u16> = children(child(dict, "Objects"), "Object").map(|o| num(text(o, "Index")) as u16).collect();
    let declared: Vec<u16> = d.objects.iter().map(|o| o.index).collect();
    assert_eq!(objects, declared);
    let types: Vec<&str> = children(child(dict, "DataTypes"), "DataType").map(|t| text(t, "Name")).collect();
    for o in children(child(dict, "Objects"), "Object") {
        assert!(types.contains(&text(o, "Type")), "type {} of {} is declared", text(o, "Type"), text(o, "Index"));
    }

    // PDOs: every mapping object, its default entries, Sm only on the default-assigned ones.
    let rx = expected_pdos(&d, 0x1600..=0x17FF, 0x1C12, 2);
    let tx = expected_pdos(&d, 0x1A00..=0x1BFF, 0x1C13, 3);
    assert!(rx.iter().any(|p| p.1 == Some(2)) && tx.iter().any(|p| p.1 == Some(3)), "something is assigned");
    assert_eq!(esi_pdos(device, "RxPdo"), rx);
    assert_eq!(esi_pdos(device, "TxPdo"), tx);
    for p in children(device, "RxPdo").chain(children(device, "TxPdo")) {
        for e in children(p, "Entry") {
            let (index, sub) = (num(text(e, "Index")) as u16, num(text(e, "SubIndex")) as u8);
            let entry = d.entry(index, sub).unwrap_or_else(|| panic!("mapped 0x{index:04X}:{sub} exists"));
            assert_eq!(text(e, "DataType"), etg_name(entry.data_type), "0x{index:04X}:{sub}");
            assert_eq!(u16::from(num(text(e, "BitLen")) as u8), entry.data_type.pdo_bits().unwrap());
        }
    }

    // Sync managers: mailboxes from [device], process data sized by the assigned PDOs.
    let bytes = |pdos: &[Pdo]| -> u64 {
        let bits: u64 = pdos.iter().filter(|p| p.1.is_some()).flat_map(|p| &p.2).map(|e| u64::from(e.2)).sum();
        bits.div_ceil(8)
    };
    let sms: Vec<(String, u64, u64, u64)> = children(device, "Sm")
        .map(|s| {
            (
                s.text().unwrap_or("").to_string(),
                num(s.attribute("StartAddress").unwrap()),
                num(s.attribute("DefaultSize").unwrap()),
                num(s.attribute("ControlByte").unwrap()),
            )
        })
        .collect();
    assert_eq!(
        sms,
        [
            ("MBoxOut".into(), dev.mailbox_out_start.into(), dev.mailbox_out_size.into(), 0x26),
            ("MBoxIn".into(), dev.mailbox_in_start.into(), dev.mailbox_in_size.into(), 0x22),
            ("Outputs".into(), dev.process_out_start.into(), bytes(&rx), 0x64),
            ("Inputs".into(), dev.process_in_start.into(), bytes(&tx), 0x20),
        ]
    );
    assert!(bytes(&rx) <= u64::from(dev.max_pdo_bytes_ethercat) && bytes(&tx) <= u64::from(dev.max_pdo_bytes_ethercat));
    let mailbox = child(device, "Mailbox");
    child(mailbox, "CoE");
    child(mailbox, "FoE");
    let modes: Vec<(&str, u64)> =
        children(child(device, "Dc"), "OpMode").map(|m| (text(m, "Name"), num(text(m, "AssignActivate")))).collect();
    assert!(modes.contains(&("DC", 0x0300)) && modes.len() == 3, "{modes:?}");
}

#[test]
fn sii_decodes_to_the_dictionary_and_agrees_with_the_esi() {
    let d = description();
    let dev = &d.device;
    let image = od_gen::sii::sii(&d);
    let info = sii::decode(&image).expect("the SII decodes");

    assert_eq!((info.vendor_id, info.product_code, info.revision), (dev.vendor_id, dev.product_code, dev.revision));
    assert_eq!(info.serial_number, dev.serial_number);
    let mb = info.standard_mailbox;
    assert_eq!(
        (mb.receive_offset, mb.receive_size, mb.send_offset, mb.send_size),
        (dev.mailbox_out_start, dev.mailbox_out_size, dev.mailbox_in_start, dev.mailbox_in_size)
    );
    assert_eq!(info.bootstrap_mailbox, mb);
    assert_eq!(info.mailbox_protocols, sii::protocol::COE | sii::protocol::FOE);
    assert_eq!(info.version, 1);
    assert_eq!(info.eeprom_bytes, image.len());

    // PDOs: only the default-assigned ones, with the same entries the dictionary maps.
    let rx: Vec<Pdo> = expected_pdos(&d, 0x1600..=0x17FF, 0x1C12, 2).into_iter().filter(|p| p.1.is_some()).collect();
    let tx: Vec<Pdo> = expected_pdos(&d, 0x1A00..=0x1BFF, 0x1C13, 3).into_iter().filter(|p| p.1.is_some()).collect();
    let sii_pdos = |pdos: &[sii::SiiPdo]| -> Vec<Pdo> {
        pdos.iter()
            .map(|p| (p.index, Some(p.sync_manager), p.entries.iter().map(|e| (e.index, e.sub, e.bit_len)).collect()))
            .collect()
    };
    assert_eq!(sii_pdos(&info.rx_pdos), rx);
    assert_eq!(sii_pdos(&info.tx_pdos), tx);
    for e in info.rx_pdos.iter().chain(&info.tx_pdos).flat_map(|p| &p.entries) {
        let entry = d.entry(e.index, e.sub).expect("mapped entry exists");
        assert_eq!(u16::from(e.data_type), entry.data_type.code(), "0x{:04X}:{}", e.index, e.sub);
    }

    // ESI and SII agree: names, sync managers, configuration data, EEPROM size, CoE details.
    let xml = od_gen::esi::esi(&d);
    let doc = Document::parse(&xml).expect("XML");
    let device = child(child(child(doc.root_element(), "Descriptions"), "Devices"), "Device");
    let general = info.general.as_ref().expect("GENERAL category");
    assert_eq!(general.name, text(device, "Name"));
    assert_eq!(Some(general.order.as_str()), child(device, "Type").text());
    assert_eq!(general.group, text(device, "GroupType"));
    let esi_sms: Vec<(u64, u64, u64, u64)> = children(device, "Sm")
        .map(|s| {
            let a = |k| num(s.attribute(k).unwrap());
            (a("StartAddress"), a("DefaultSize"), a("ControlByte"), a("Enable"))
        })
        .collect();
    let sii_sms: Vec<(u64, u64, u64, u64)> = info
        .sync_managers
        .iter()
        .map(|s| (s.start.into(), s.length.into(), s.control.into(), u64::from(s.enable & 1)))
        .collect();
    assert_eq!(esi_sms, sii_sms);
    let kinds: Vec<SmKind> = info.sync_managers.iter().map(|s| s.kind).collect();
    assert_eq!(kinds, [SmKind::MailboxOut, SmKind::MailboxIn, SmKind::Outputs, SmKind::Inputs]);
    let fmmus: Vec<&str> = children(device, "Fmmu").filter_map(|f| f.text()).collect();
    assert_eq!(fmmus, ["Outputs", "Inputs", "MBoxState"]);
    assert_eq!(info.fmmus[..3], [1, 2, 3]);

    let eeprom = child(device, "Eeprom");
    assert_eq!(num(text(eeprom, "ByteSize")) as usize, image.len());
    let config = text(eeprom, "ConfigData");
    let config_bytes: Vec<u8> =
        (0..config.len()).step_by(2).map(|i| u8::from_str_radix(&config[i..i + 2], 16).unwrap()).collect();
    assert_eq!(config_bytes, image[..14]);
    assert_eq!(image[14], sii::crc8(&image[..14]));

    let coe = child(child(device, "Mailbox"), "CoE");
    let flag = |k: &str| coe.attribute(k) == Some("true");
    let details = general.coe_details;
    assert_eq!(details & 0x01, 0x01, "SDO");
    assert_eq!(details & 0x02 != 0, flag("SdoInfo"));
    assert_eq!(details & 0x04 != 0, flag("PdoAssign"));
    assert_eq!(details & 0x08 != 0, flag("PdoConfig"));
    assert_eq!(details & 0x20 != 0, flag("CompleteAccess"));
    assert_eq!(general.foe_details & 1 == 1, children(child(device, "Mailbox"), "FoE").count() == 1);
}
