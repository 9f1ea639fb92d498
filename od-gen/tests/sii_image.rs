//! Unit tests of the SII EEPROM image: the configuration-area CRC against real EEPROM dumps, the header
//! words, the category layout, and the decoder on both our image and a real one.

mod esi_fixture;

use od_gen::sii::{self, SmKind};

fn unhex(s: &str) -> Vec<u8> {
    let s: String = s.chars().filter(|c| !c.is_whitespace()).collect();
    (0..s.len()).step_by(2).map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap()).collect()
}

/// Words 0..=7 of three real EEPROM dumps kept in the ethercrab repository (`dumps/eeprom/ek1100.hex`,
/// `dumps/eeprom/el2889.hex`, `dumps/eeprom/akd.hex`): 14 configuration bytes, then the CRC in the low byte of
/// word 7 (0x46, 0xE2, 0x10).
const REAL_CONFIG_AREAS: [&str; 3] = [
    "000d 0000 0000 0000 0000 0000 0000 4600",
    "0401 0000 0000 ff00 0000 0000 0000 e200",
    "0900 0008 0000 0000 0000 0000 0000 1000",
];

#[test]
fn crc8_matches_real_eeproms() {
    for area in REAL_CONFIG_AREAS {
        let b = unhex(area);
        assert_eq!(sii::crc8(&b[..14]), b[14], "{area}");
        assert_eq!(b[15], 0, "{area}: high byte of word 7 is 0");
    }
}

/// A real image cut down to what the decoder reads: the header (words 0x00..=0x3F) and the GENERAL, FMMU,
/// SYNCM and first TXPDO of the Kollmorgen AKD dump in the ethercrab repository (`dumps/eeprom/akd.hex`,
/// categories at words 0x145, 0x157, 0x15B and 0x170), with the PDO category shortened to its first PDO.
fn akd_image() -> Vec<u8> {
    let mut b = unhex(concat!(
        "090000080000000000000000000010006a000000444b41000200000093008399",
        "000000000000000000180004001c000400180004001c00040e00000000000000",
    ));
    b.resize(0x7C, 0);
    b.extend(unhex("0f00 0100"));
    // GENERAL (30), 16 words.
    b.extend(unhex("1e00 1000 02050104010d0103000100050000030011000000000000000000000000000000"));
    // FMMU (40), 2 words.
    b.extend(unhex("2800 0200 010203ff"));
    // SYNCM (41), 16 words.
    b.extend(unhex("2900 1000 0018000426000101001c00042200010200110000240001034011000020000104"));
    // TXPDO (50), first PDO only (8 words): 0x1A00, 1 entry, SM 0xFF, name 8; entry 0x6041:00 name 9 UINT 16.
    b.extend(unhex("3200 0800 001a01ff00080000 4160000906100000"));
    b.extend(unhex("ffff"));
    b
}

#[test]
fn decoder_reads_a_real_image() {
    let info = sii::decode(&akd_image()).expect("a real image decodes");
    assert_eq!(info.vendor_id, 0x6A);
    assert_eq!(info.product_code, 0x0041_4B44);
    assert_eq!(info.revision, 2);
    assert_eq!(info.serial_number, 0x9983_0093);
    assert_eq!(info.standard_mailbox.receive_offset, 0x1800);
    assert_eq!(info.standard_mailbox.receive_size, 0x400);
    assert_eq!(info.standard_mailbox.send_offset, 0x1C00);
    assert_eq!(info.bootstrap_mailbox, info.standard_mailbox);
    assert_eq!(info.mailbox_protocols, 0x000E);
    assert_eq!(info.eeprom_bytes, 2048);
    assert_eq!(info.version, 1);
    let g = info.general.expect("GENERAL");
    assert_eq!((g.coe_details, g.foe_details, g.eoe_details, g.flags), (0x0D, 1, 3, 0x05));
    assert_eq!(g.physical_ports, 0x0011);
    assert_eq!(info.fmmus, [1, 2, 3, 0xFF]);
    assert_eq!(info.sync_managers.len(), 4);
    assert_eq!(info.sync_managers[0].start, 0x1800);
    assert_eq!(info.sync_managers[0].control, 0x26);
    assert_eq!(info.sync_managers[1].kind, SmKind::MailboxIn);
    assert_eq!(info.sync_managers[3].start, 0x1140);
    assert_eq!(info.tx_pdos.len(), 1);
    assert_eq!(info.tx_pdos[0].index, 0x1A00);
    assert_eq!(info.tx_pdos[0].sync_manager, 0xFF);
    assert_eq!(info.tx_pdos[0].entries[0].index, 0x6041);
    assert_eq!(info.tx_pdos[0].entries[0].bit_len, 16);
    assert_eq!(info.tx_pdos[0].entries[0].data_type, 0x06);
}

#[test]
fn header_words_are_golden() {
    let image = sii::sii(&esi_fixture::description());
    // Words 0..=7: ESC configuration (PDI SPI 0x05, ESC config 0x0C, PDI config 0x03/0x0E, SYNC pulse 1000 x 10 ns)
    // and its CRC-8 (polynomial 0x07, initial 0xFF), 0xDC, computed by the function checked above.
    assert_eq!(image[..16], unhex("050c 030e e803 0000 0000 0000 0000 dc00")[..]);
    // Identity: vendor 0x00000ACE, product 0x00010001, revision 0x00010000, serial 0x12345678.
    assert_eq!(image[0x10..0x20], unhex("ce0a 0000 0100 0100 0000 0100 7856 3412")[..]);
    // Bootstrap and standard mailbox: 0x1000/128 out, 0x1080/128 in; protocols CoE | FoE.
    assert_eq!(image[0x28..0x3A], unhex("0010 8000 8010 8000 0010 8000 8010 8000 0c00")[..]);
    // Size: 2 KiB = 16 Kibit -> 15; version 1.
    assert_eq!(image[0x7C..0x80], unhex("0f00 0100")[..]);
    assert_eq!(image.len(), 2048);
    assert!(image[image.len() - 16..].iter().all(|&b| b == 0xFF));
}

#[test]
fn image_decodes_to_the_description() {
    let d = esi_fixture::description();
    let image = sii::sii(&d);
    assert_eq!(image, sii::sii(&d), "deterministic");
    let info = sii::decode(&image).expect("our image decodes");
    assert_eq!(info.esc_config, sii::ESC_CONFIG);
    assert_eq!(info.vendor_id, d.device.vendor_id);
    assert_eq!(info.product_code, d.device.product_code);
    assert_eq!(info.revision, d.device.revision);
    assert_eq!(info.serial_number, d.device.serial_number);
    assert_eq!(info.mailbox_protocols, sii::protocol::COE | sii::protocol::FOE);
    assert_eq!(info.eeprom_bytes, 2048);
    let g = info.general.as_ref().expect("GENERAL");
    assert_eq!(g.coe_details, 0x2F, "SDO, SDO info, PDO assign, PDO config, complete access");
    assert_eq!(g.foe_details, 1);
    assert_eq!(g.physical_ports, 0x0011);
    assert_eq!(g.name, "OSD-402");
    assert_eq!(g.order, "OSD-402-24V-10A");
    assert_eq!(g.group, "Servo drives");
    assert_eq!(info.fmmus, [1, 2, 3, 0xFF]);

    let sm = &info.sync_managers;
    assert_eq!(sm.len(), 4);
    assert_eq!((sm[0].start, sm[0].length, sm[0].control, sm[0].kind), (0x1000, 128, 0x26, SmKind::MailboxOut));
    assert_eq!((sm[1].start, sm[1].length, sm[1].control, sm[1].kind), (0x1080, 128, 0x22, SmKind::MailboxIn));
    // SM2: RxPDO 0x1600 = controlword (2 bytes); SM3: TxPDO 0x1A00 = statusword, position, error register (7).
    assert_eq!((sm[2].start, sm[2].length, sm[2].control, sm[2].enable), (0x1100, 2, 0x64, 1));
    assert_eq!((sm[3].start, sm[3].length, sm[3].control, sm[3].enable), (0x1180, 7, 0x20, 1));

    assert_eq!(info.rx_pdos.len(), 1, "only the default-assigned PDOs");
    assert_eq!(info.rx_pdos[0].index, 0x1600);
    assert_eq!(info.rx_pdos[0].sync_manager, 2);
    assert_eq!(info.rx_pdos[0].name, "Receive PDO 1 mapping");
    assert_eq!(info.rx_pdos[0].entries.len(), 1);
    assert_eq!(info.rx_pdos[0].entries[0].name, "Controlword");
    let tx = &info.tx_pdos[0];
    assert_eq!((tx.index, tx.sync_manager, tx.flags), (0x1A00, 3, 0));
    let entries: Vec<(u16, u8, u8, u8)> = tx.entries.iter().map(|e| (e.index, e.sub, e.data_type, e.bit_len)).collect();
    assert_eq!(entries, [(0x6041, 0, 0x06, 16), (0x6064, 0, 0x04, 32), (0x1001, 0, 0x05, 8)]);
}

#[test]
fn decoder_rejects_bad_images() {
    let d = esi_fixture::description();
    let mut image = sii::sii(&d);
    image[4] ^= 1;
    assert!(sii::decode(&image).unwrap_err().contains("CRC"));
    assert!(sii::decode(&[0; 10]).is_err());
    // A category whose length runs past the end.
    let mut short = sii::sii(&d)[..0x84].to_vec();
    short[0x80..0x84].copy_from_slice(&[0x0A, 0x00, 0x40, 0x00]);
    assert!(sii::decode(&short).is_err());
}
