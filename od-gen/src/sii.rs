//! EtherCAT SII EEPROM image (ETG.1000.6 §5.4, ETG.2010) emitter and decoder.
//!
//! Layout of the image:
//! - words 0x00..=0x07: ESC configuration area ([`ESC_CONFIG`]) with its CRC-8 in the low byte of word 7;
//! - words 0x08..=0x0F: vendor ID, product code, revision, serial number (u32, low word first);
//! - words 0x14..=0x17 / 0x18..=0x1B: bootstrap / standard mailbox (receive offset, receive size, send offset,
//!   send size), both from `[device]`;
//! - word 0x1C: mailbox protocols (CoE 0x0004 | FoE 0x0008); word 0x3E: EEPROM size in Kibit - 1; word 0x3F:
//!   version 1;
//! - from word 0x40: categories STRINGS (10), GENERAL (30), FMMU (40), SYNCM (41), TXPDO (50), RXPDO (51), each
//!   `type, length in words, data`, closed by 0xFFFF; the rest of the EEPROM is 0xFF.
//!
//! The layouts of the category data were checked against real EEPROM dumps (a Kollmorgen AKD dump kept in the
//! ethercrab repository, `dumps/eeprom/akd.hex`) and the masters' readers.

use crate::esi::{self, Direction, PdoLayout};
use crate::model::{Access, Description};

/// ESC configuration words 0..=6 (ETG.1000.6 Table 16), loaded by the ESC into its registers at power-up:
/// - 0: PDI control 0x0140 = 0x05 (SPI slave), ESC configuration 0x0141 = 0x0C (DC SYNC out and latch in units on);
/// - 1: PDI configuration 0x0150 = 0x03 (SPI mode 3, IRQ push-pull active low), 0x0151 = 0x0E (SYNC0 output,
///   push-pull active high, mapped to the AL event register);
/// - 2: SYNC pulse length 0x0982 = 1000 x 10 ns = 10 us;
/// - 3: extended PDI configuration 0x0152 = 0; 4: configured station alias 0x0012 = 0; 5, 6: reserved.
pub const ESC_CONFIG: [u16; 7] = [0x0C05, 0x0E03, 0x03E8, 0x0000, 0x0000, 0x0000, 0x0000];

/// SII category types (ETG.1000.6 Table 19).
pub mod category {
    /// Strings.
    pub const STRINGS: u16 = 10;
    /// General.
    pub const GENERAL: u16 = 30;
    /// FMMU usage.
    pub const FMMU: u16 = 40;
    /// Sync managers.
    pub const SYNCM: u16 = 41;
    /// Transmit PDOs.
    pub const TXPDO: u16 = 50;
    /// Receive PDOs.
    pub const RXPDO: u16 = 51;
    /// End of the category list.
    pub const END: u16 = 0xFFFF;
}

/// Mailbox protocol bits of word 0x1C (ETG.1000.6 Table 18).
pub mod protocol {
    /// CAN application protocol over EtherCAT.
    pub const COE: u16 = 0x0004;
    /// File access over EtherCAT.
    pub const FOE: u16 = 0x0008;
}

/// Whether the firmware's CoE server answers the SDO information service (ETG.1000.6 §5.6.3): `firmware::ecat::coe`.
pub const SDO_INFO_SUPPORTED: bool = true;
/// Whether the firmware's CoE server accepts complete access (ETG.1000.6 §5.6.2.1.1: `firmware::comm::sdo::coe`).
/// SOEM reads the PDO assignment and mapping with it when the SII announces it.
pub const COMPLETE_ACCESS_SUPPORTED: bool = true;

/// The mailbox features the ESI (`Mailbox/CoE` attributes) and the SII (GENERAL CoE/FoE details, word 0x1C)
/// both announce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MailboxFeatures {
    /// SDO information service.
    pub sdo_info: bool,
    /// The master may write the PDO assignment (0x1C12/0x1C13 sub 1 writable).
    pub pdo_assign: bool,
    /// The master may write PDO mappings (0x1600/0x1A00 sub 0 writable).
    pub pdo_config: bool,
    /// SDO complete access.
    pub complete_access: bool,
    /// File access over EtherCAT (firmware download in BOOT).
    pub foe: bool,
}

fn writable(d: &Description, index: u16, sub: u8) -> bool {
    d.entry(index, sub).is_some_and(|s| matches!(s.access, Access::ReadWrite | Access::WriteOnly))
}

impl MailboxFeatures {
    /// The features of the drive described by `d`: PDO assignment and configuration follow the access of
    /// 0x1C12:01 and 0x1600:00; SDO information and complete access follow the firmware constants above.
    pub fn of(d: &Description) -> Self {
        Self {
            sdo_info: SDO_INFO_SUPPORTED,
            pdo_assign: writable(d, 0x1C12, 1) || writable(d, 0x1C13, 1),
            pdo_config: writable(d, 0x1600, 0) || writable(d, 0x1A00, 0),
            complete_access: COMPLETE_ACCESS_SUPPORTED,
            foe: true,
        }
    }

    /// GENERAL category byte 5 (ETG.2010 Table 5): bit 0 SDO, 1 SDO info, 2 PDO assign, 3 PDO configuration,
    /// 5 complete access. 0x0D for SDO + PDO assign + PDO configuration.
    pub const fn coe_details(&self) -> u8 {
        0x01 | (self.sdo_info as u8) << 1
            | (self.pdo_assign as u8) << 2
            | (self.pdo_config as u8) << 3
            | (self.complete_access as u8) << 5
    }

    /// Word 0x1C: mailbox protocols.
    pub const fn protocols(&self) -> u16 {
        protocol::COE | if self.foe { protocol::FOE } else { 0 }
    }
}

/// What a sync manager is used for (SII SYNCM byte 7, ETG.2010 Table 12).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SmKind {
    /// 1: mailbox master to slave (SM0).
    MailboxOut,
    /// 2: mailbox slave to master (SM1).
    MailboxIn,
    /// 3: process data outputs (SM2).
    Outputs,
    /// 4: process data inputs (SM3).
    Inputs,
    /// Anything else (0 = unused).
    Unused(u8),
}

impl SmKind {
    /// The SII code.
    pub const fn code(self) -> u8 {
        match self {
            Self::MailboxOut => 1,
            Self::MailboxIn => 2,
            Self::Outputs => 3,
            Self::Inputs => 4,
            Self::Unused(c) => c,
        }
    }

    /// The kind of an SII code.
    pub const fn from_code(c: u8) -> Self {
        match c {
            1 => Self::MailboxOut,
            2 => Self::MailboxIn,
            3 => Self::Outputs,
            4 => Self::Inputs,
            c => Self::Unused(c),
        }
    }
}

/// One sync manager as the SII SYNCM category and the ESI `Sm` element describe it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SyncManager {
    /// Physical start address.
    pub start: u16,
    /// Length in bytes.
    pub length: u16,
    /// Control register (0x0804): 0x26 mailbox write, 0x22 mailbox read, 0x64 buffered write with watchdog,
    /// 0x20 buffered read.
    pub control: u8,
    /// Enable byte (bit 0 enable).
    pub enable: u8,
    /// Use.
    pub kind: SmKind,
}

/// The four sync managers of the drive: the mailboxes from `[device]`, the process data at their start
/// addresses with the length of the default-assigned PDOs.
pub fn sync_managers(d: &Description) -> [SyncManager; 4] {
    let dev = &d.device;
    let out_len = esi::process_image_bytes(d, Direction::Rx);
    let in_len = esi::process_image_bytes(d, Direction::Tx);
    [
        SyncManager {
            start: dev.mailbox_out_start,
            length: dev.mailbox_out_size,
            control: 0x26,
            enable: 1,
            kind: SmKind::MailboxOut,
        },
        SyncManager {
            start: dev.mailbox_in_start,
            length: dev.mailbox_in_size,
            control: 0x22,
            enable: 1,
            kind: SmKind::MailboxIn,
        },
        SyncManager {
            start: dev.process_out_start,
            length: out_len,
            control: 0x64,
            enable: u8::from(out_len > 0),
            kind: SmKind::Outputs,
        },
        SyncManager {
            start: dev.process_in_start,
            length: in_len,
            control: 0x20,
            enable: u8::from(in_len > 0),
            kind: SmKind::Inputs,
        },
    ]
}

/// CRC-8 of the ESC configuration area (ETG.1000.6 §5.4: polynomial x^8 + x^2 + x + 1, initial value 0xFF,
/// no reflection, no final XOR), computed over bytes 0..=13.
pub fn crc8(bytes: &[u8]) -> u8 {
    let mut crc: u8 = 0xFF;
    for &b in bytes {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0x07 } else { crc << 1 };
        }
    }
    crc
}

/// The string table of the STRINGS category: index 1.. in order of first use, duplicates shared.
struct Strings(Vec<String>);

impl Strings {
    /// The 1-based index of `s`, adding it if new; 0 (no string) for an empty text or a full table.
    fn index(&mut self, s: &str) -> u8 {
        if s.is_empty() {
            return 0;
        }
        // A string is at most 255 bytes long; cut at a character boundary.
        let mut end = s.len().min(255);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        let s = &s[..end];
        if let Some(i) = self.0.iter().position(|x| x == s) {
            return u8::try_from(i + 1).unwrap_or(0);
        }
        if self.0.len() >= 255 {
            return 0;
        }
        self.0.push(s.to_string());
        u8::try_from(self.0.len()).unwrap_or(0)
    }

    fn bytes(&self) -> Vec<u8> {
        let mut b = vec![u8::try_from(self.0.len()).unwrap_or(u8::MAX)];
        for s in &self.0 {
            b.push(u8::try_from(s.len()).unwrap_or(u8::MAX));
            b.extend_from_slice(s.as_bytes());
        }
        b
    }
}

fn push_category(image: &mut Vec<u8>, kind: u16, mut data: Vec<u8>) {
    if data.len() % 2 == 1 {
        data.push(0);
    }
    image.extend_from_slice(&kind.to_le_bytes());
    image.extend_from_slice(&u16::try_from(data.len() / 2).unwrap_or(u16::MAX).to_le_bytes());
    image.extend_from_slice(&data);
}

fn pdo_category(pdos: &[PdoLayout], strings: &mut Strings) -> Vec<u8> {
    let mut data = Vec::new();
    for p in pdos {
        data.extend_from_slice(&p.index.to_le_bytes());
        data.push(u8::try_from(p.entries.len()).unwrap_or(u8::MAX));
        data.push(p.sync_manager.unwrap_or(0xFF));
        data.push(0); // DC sync unit
        data.push(strings.index(&p.name));
        // Flags (ETG.2010 Table 14): 0x0010 fixed content.
        let flags: u16 = if p.fixed { 0x0010 } else { 0 };
        data.extend_from_slice(&flags.to_le_bytes());
        for e in &p.entries {
            data.extend_from_slice(&e.index.to_le_bytes());
            data.push(e.sub);
            data.push(strings.index(&e.name));
            data.push(e.data_type.map(|t| (t.code() & 0xFF) as u8).unwrap_or(0));
            data.push(e.bit_len);
            data.extend_from_slice(&0u16.to_le_bytes());
        }
    }
    data
}

/// The image up to and including the end marker.
fn image_body(d: &Description) -> Vec<u8> {
    let dev = &d.device;
    let features = MailboxFeatures::of(d);
    let mut words = [0u16; 64];
    for (w, c) in words.iter_mut().zip(ESC_CONFIG) {
        *w = c;
    }
    let config: Vec<u8> = ESC_CONFIG.iter().flat_map(|w| w.to_le_bytes()).collect();
    words[0x07] = u16::from(crc8(&config));
    for (at, v) in [(0x08, dev.vendor_id), (0x0A, dev.product_code), (0x0C, dev.revision), (0x0E, dev.serial_number)] {
        words[at] = (v & 0xFFFF) as u16;
        words[at + 1] = (v >> 16) as u16;
    }
    let mailbox = [dev.mailbox_out_start, dev.mailbox_out_size, dev.mailbox_in_start, dev.mailbox_in_size];
    words[0x14..0x18].copy_from_slice(&mailbox);
    words[0x18..0x1C].copy_from_slice(&mailbox);
    words[0x1C] = features.protocols();
    words[0x3F] = 1;

    let mut strings = Strings(Vec::new());
    // The device name first: SOEM takes string 1 as the slave's name, whatever GENERAL's name index says.
    let name = strings.index(&dev.device_name);
    let group = strings.index(&dev.group_name);
    let order = strings.index(&dev.order_code);
    let tx = esi::assigned_pdo_layouts(d, Direction::Tx);
    let rx = esi::assigned_pdo_layouts(d, Direction::Rx);
    let tx_data = pdo_category(&tx, &mut strings);
    let rx_data = pdo_category(&rx, &mut strings);

    let mut general = vec![0u8; 32];
    general[0] = group;
    general[2] = order;
    general[3] = name;
    general[5] = features.coe_details();
    general[6] = u8::from(features.foe);
    // 0x0C..0x0D current on EBus: 0 mA (the drive has its own supply and MII ports).
    general[0x0E] = group;
    // 0x10..0x11 physical ports: ports 0 and 1 MII (1), ports 2 and 3 unused.
    general[0x10] = 0x11;

    let mut sm = Vec::new();
    for s in sync_managers(d) {
        sm.extend_from_slice(&s.start.to_le_bytes());
        sm.extend_from_slice(&s.length.to_le_bytes());
        sm.extend_from_slice(&[s.control, 0, s.enable, s.kind.code()]);
    }

    let mut image: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    push_category(&mut image, category::STRINGS, strings.bytes());
    push_category(&mut image, category::GENERAL, general);
    // FMMU 0 outputs, 1 inputs, 2 mailbox state; padding 0xFF (unused).
    push_category(&mut image, category::FMMU, vec![0x01, 0x02, 0x03, 0xFF]);
    push_category(&mut image, category::SYNCM, sm);
    if !tx_data.is_empty() {
        push_category(&mut image, category::TXPDO, tx_data);
    }
    if !rx_data.is_empty() {
        push_category(&mut image, category::RXPDO, rx_data);
    }
    image.extend_from_slice(&category::END.to_le_bytes());
    image
}

/// EEPROM size in bytes: 2 KiB (a 24C16), or the next power of two that holds the image.
pub fn eeprom_byte_size(d: &Description) -> usize {
    image_body(d).len().next_power_of_two().max(2048)
}

/// Builds the SII EEPROM image of `d`, padded with 0xFF to [`eeprom_byte_size`].
pub fn sii(d: &Description) -> Vec<u8> {
    let mut image = image_body(d);
    let size = image.len().next_power_of_two().max(2048);
    // Word 0x3E: EEPROM size in Kibit minus 1 (ETG.1000.6 Table 16).
    let kibit = u16::try_from(size * 8 / 1024).unwrap_or(u16::MAX).saturating_sub(1);
    if let Some(w) = image.get_mut(0x3E * 2..0x3E * 2 + 2) {
        w.copy_from_slice(&kibit.to_le_bytes());
    }
    image.resize(size, 0xFF);
    image
}

/// A mailbox layout (SII words 0x14..=0x17 or 0x18..=0x1B).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct MailboxLayout {
    /// Receive mailbox (master to slave, SM0) offset.
    pub receive_offset: u16,
    /// Receive mailbox size.
    pub receive_size: u16,
    /// Send mailbox (slave to master, SM1) offset.
    pub send_offset: u16,
    /// Send mailbox size.
    pub send_size: u16,
}

/// The GENERAL category, with its string indices resolved.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct General {
    /// Group type.
    pub group: String,
    /// Image name.
    pub image: String,
    /// Order code (ESI `Type`).
    pub order: String,
    /// Device name (ESI `Name`).
    pub name: String,
    /// CoE details byte.
    pub coe_details: u8,
    /// FoE details byte.
    pub foe_details: u8,
    /// EoE details byte.
    pub eoe_details: u8,
    /// Flags byte.
    pub flags: u8,
    /// Current consumption on EBus in mA.
    pub ebus_current_ma: i16,
    /// Physical ports, 4 bits per port.
    pub physical_ports: u16,
}

/// One entry of a PDO in the TXPDO/RXPDO category.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SiiPdoEntry {
    /// Mapped index.
    pub index: u16,
    /// Mapped sub-index.
    pub sub: u8,
    /// Name.
    pub name: String,
    /// CoE data type code (low byte).
    pub data_type: u8,
    /// Length in bits.
    pub bit_len: u8,
    /// Flags.
    pub flags: u16,
}

/// One PDO of the TXPDO/RXPDO category.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SiiPdo {
    /// PDO (mapping object) index.
    pub index: u16,
    /// Sync manager (0xFF: none).
    pub sync_manager: u8,
    /// DC sync unit.
    pub dc_sync: u8,
    /// Name.
    pub name: String,
    /// Flags.
    pub flags: u16,
    /// Entries.
    pub entries: Vec<SiiPdoEntry>,
}

/// What [`decode`] reads from an SII image.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct SiiInfo {
    /// Words 0..=6 of the ESC configuration area.
    pub esc_config: [u16; 7],
    /// Vendor ID (word 0x08).
    pub vendor_id: u32,
    /// Product code (word 0x0A).
    pub product_code: u32,
    /// Revision number (word 0x0C).
    pub revision: u32,
    /// Serial number (word 0x0E).
    pub serial_number: u32,
    /// Bootstrap mailbox (words 0x14..=0x17).
    pub bootstrap_mailbox: MailboxLayout,
    /// Standard mailbox (words 0x18..=0x1B).
    pub standard_mailbox: MailboxLayout,
    /// Mailbox protocols (word 0x1C).
    pub mailbox_protocols: u16,
    /// EEPROM size in bytes (from word 0x3E).
    pub eeprom_bytes: usize,
    /// Version (word 0x3F).
    pub version: u16,
    /// The STRINGS category (string `i` has SII index `i + 1`).
    pub strings: Vec<String>,
    /// The GENERAL category.
    pub general: Option<General>,
    /// FMMU usage bytes (padding 0xFF included).
    pub fmmus: Vec<u8>,
    /// Sync managers.
    pub sync_managers: Vec<SyncManager>,
    /// Transmit PDOs.
    pub tx_pdos: Vec<SiiPdo>,
    /// Receive PDOs.
    pub rx_pdos: Vec<SiiPdo>,
}

struct Reader<'a> {
    data: &'a [u8],
    at: usize,
    what: &'static str,
}

impl Reader<'_> {
    fn u8(&mut self) -> Result<u8, String> {
        let v =
            self.data.get(self.at).copied().ok_or_else(|| format!("{} truncated at byte {}", self.what, self.at))?;
        self.at += 1;
        Ok(v)
    }

    fn u16(&mut self) -> Result<u16, String> {
        Ok(u16::from_le_bytes([self.u8()?, self.u8()?]))
    }
}

fn word(image: &[u8], w: usize) -> Result<u16, String> {
    match image.get(w * 2..w * 2 + 2) {
        Some(b) => Ok(u16::from_le_bytes([b[0], b[1]])),
        None => Err(format!("image too short for word 0x{w:02X}")),
    }
}

fn dword(image: &[u8], w: usize) -> Result<u32, String> {
    Ok(u32::from(word(image, w)?) | u32::from(word(image, w + 1)?) << 16)
}

fn mailbox(image: &[u8], w: usize) -> Result<MailboxLayout, String> {
    Ok(MailboxLayout {
        receive_offset: word(image, w)?,
        receive_size: word(image, w + 1)?,
        send_offset: word(image, w + 2)?,
        send_size: word(image, w + 3)?,
    })
}

fn string_at(strings: &[String], idx: u8) -> String {
    if idx == 0 {
        return String::new();
    }
    strings.get(usize::from(idx) - 1).cloned().unwrap_or_default()
}

fn decode_pdos(data: &[u8], strings: &[String]) -> Result<Vec<SiiPdo>, String> {
    let mut r = Reader { data, at: 0, what: "PDO category" };
    let mut pdos = Vec::new();
    while r.at + 8 <= data.len() {
        let index = r.u16()?;
        let n = r.u8()?;
        let sync_manager = r.u8()?;
        let dc_sync = r.u8()?;
        let name = string_at(strings, r.u8()?);
        let flags = r.u16()?;
        let mut entries = Vec::new();
        for _ in 0..n {
            entries.push(SiiPdoEntry {
                index: r.u16()?,
                sub: r.u8()?,
                name: string_at(strings, r.u8()?),
                data_type: r.u8()?,
                bit_len: r.u8()?,
                flags: r.u16()?,
            });
        }
        pdos.push(SiiPdo { index, sync_manager, dc_sync, name, flags, entries });
    }
    Ok(pdos)
}

/// Decodes an SII image: checks the configuration-area CRC and reads the header and the categories.
pub fn decode(image: &[u8]) -> Result<SiiInfo, String> {
    let config = image.get(..14).ok_or("image shorter than the ESC configuration area")?;
    let crc = word(image, 7)?;
    if crc & 0xFF != u16::from(crc8(config)) {
        return Err(format!(
            "configuration-area CRC 0x{:02X} does not match the computed 0x{:02X}",
            crc & 0xFF,
            crc8(config)
        ));
    }
    let mut info = SiiInfo {
        vendor_id: dword(image, 0x08)?,
        product_code: dword(image, 0x0A)?,
        revision: dword(image, 0x0C)?,
        serial_number: dword(image, 0x0E)?,
        bootstrap_mailbox: mailbox(image, 0x14)?,
        standard_mailbox: mailbox(image, 0x18)?,
        mailbox_protocols: word(image, 0x1C)?,
        eeprom_bytes: (usize::from(word(image, 0x3E)?) + 1) * 1024 / 8,
        version: word(image, 0x3F)?,
        ..SiiInfo::default()
    };
    for (i, w) in info.esc_config.iter_mut().enumerate() {
        *w = word(image, i)?;
    }

    // Categories from word 0x40; STRINGS may come after the categories that refer to it, so collect first.
    let mut cats: Vec<(u16, &[u8])> = Vec::new();
    let mut w = 0x40usize;
    loop {
        let kind = word(image, w)?;
        if kind == category::END {
            break;
        }
        let len = usize::from(word(image, w + 1)?);
        let start = (w + 2) * 2;
        let data = image
            .get(start..start + len * 2)
            .ok_or_else(|| format!("category {kind} at word 0x{w:X} runs past the end of the image"))?;
        cats.push((kind, data));
        w += 2 + len;
    }
    for &(kind, data) in &cats {
        if kind == category::STRINGS {
            let mut r = Reader { data, at: 0, what: "STRINGS category" };
            let n = r.u8()?;
            for _ in 0..n {
                let len = usize::from(r.u8()?);
                let s = data.get(r.at..r.at + len).ok_or("STRINGS category truncated")?;
                info.strings.push(String::from_utf8_lossy(s).into_owned());
                r.at += len;
            }
        }
    }
    for &(kind, data) in &cats {
        match kind {
            category::GENERAL => {
                let mut r = Reader { data, at: 0, what: "GENERAL category" };
                let group = r.u8()?;
                let image_idx = r.u8()?;
                let order = r.u8()?;
                let name = r.u8()?;
                let _reserved = r.u8()?;
                let coe_details = r.u8()?;
                let foe_details = r.u8()?;
                let eoe_details = r.u8()?;
                r.at += 3; // SoE channels, DS402 channels, sysman class
                let flags = r.u8()?;
                let ebus_current_ma = r.u16()? as i16;
                r.at += 2; // group index (duplicate), reserved
                let physical_ports = r.u16()?;
                info.general = Some(General {
                    group: string_at(&info.strings, group),
                    image: string_at(&info.strings, image_idx),
                    order: string_at(&info.strings, order),
                    name: string_at(&info.strings, name),
                    coe_details,
                    foe_details,
                    eoe_details,
                    flags,
                    ebus_current_ma,
                    physical_ports,
                });
            }
            category::FMMU => info.fmmus = data.to_vec(),
            category::SYNCM => {
                let mut r = Reader { data, at: 0, what: "SYNCM category" };
                while r.at + 8 <= data.len() {
                    let start = r.u16()?;
                    let length = r.u16()?;
                    let control = r.u8()?;
                    let _status = r.u8()?;
                    let enable = r.u8()?;
                    let kind = SmKind::from_code(r.u8()?);
                    info.sync_managers.push(SyncManager { start, length, control, enable, kind });
                }
            }
            category::TXPDO => info.tx_pdos.extend(decode_pdos(data, &info.strings)?),
            category::RXPDO => info.rx_pdos.extend(decode_pdos(data, &info.strings)?),
            _ => {}
        }
    }
    Ok(info)
}
