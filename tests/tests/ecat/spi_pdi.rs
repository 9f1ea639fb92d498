//! The firmware's SPI PDI driver ([`firmware::ecat::spi_pdi::SpiEsc`]) against a model of an ET1100-class SPI
//! slave: the model chip below interprets the bytes the driver clocks out (address/command phase, address
//! extension, wait-state byte, read termination, write data) into reads and writes of `hal-sim`'s emulated ESC
//! through its PDI accessors, one byte at a time as the chip's SPI slave sees them, and answers on MISO (the AL
//! event request during the address phase, the data during a read). The firmware's slave
//! ([`EthercatSlave::poll`]) talks to the emulated ESC only through this, while an in-process master brings it
//! INIT -> PRE-OP and uploads objects over CoE. So the driver's byte patterns are proven against the same ESC the
//! real masters use (tests `ecat_real_masters`, `ecat_ethercrab`).
//!
//! The model is written from the ET1100 datasheet (section III, 6.3 "SPI Slave Interface"), independently of the
//! firmware's framing code, and records every departure from it as a violation; each test requires none.

use drive_tests::ecat_master::{first_datagram, StationMaster, STATION};
use firmware::drive::{Drive, DriveConfig};
use firmware::ecat::esc::Esc as _;
use firmware::ecat::mailbox::{Header, HEADER_LEN};
use firmware::ecat::slave::EthercatSlave;
use firmware::ecat::spi_pdi::{Addressing, SpiBus, SpiEsc};
use firmware::od::access::NoApplicationObjects;
use firmware::od::generated;
use hal_sim::esc::datagram::{Command, FrameBuilder};
use hal_sim::esc::Esc;

const COE: u8 = 3;

/// Where the model chip is within one access (one chip select).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Chip select high.
    Idle,
    /// Expecting byte 0: A[12:5].
    Address0,
    /// Expecting byte 1: A[4:0] and CMD0.
    Address1 { high: u16 },
    /// Expecting byte 2 of the 3-byte address: A[15:13], CMD1, two reserved bits.
    Address2 { low: u16 },
    /// Expecting the wait-state byte (0xFF) of a read with wait state.
    WaitState { address: u16 },
    /// Read data: the next byte comes from `address`.
    Read { address: u16, bytes: usize, terminated: bool },
    /// Write data: the next byte goes to `address`.
    Write { address: u16 },
}

/// What the model chip counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Counts {
    accesses: usize,
    reads: usize,
    writes: usize,
    /// Accesses with the 3-byte address phase.
    extended: usize,
    /// Data bytes read and written.
    data_bytes: usize,
}

/// An ET1100-class SPI slave in front of the emulated ESC (see the module documentation).
struct ModelChip {
    esc: Esc,
    phase: Phase,
    counts: Counts,
    /// Departures from the datasheet's framing, in words.
    violations: Vec<String>,
}

impl ModelChip {
    fn new(esc: Esc) -> Self {
        Self { esc, phase: Phase::Idle, counts: Counts::default(), violations: Vec::new() }
    }

    /// Byte `n` of the AL event request register, as the chip sends it during the address phase.
    fn al_event_byte(&self, n: u32) -> u8 {
        (self.esc.al_event_request() >> (8 * n)) as u8
    }

    /// After the command is known: where the access goes next.
    fn command(&mut self, address: u16, cmd: u8) -> Phase {
        match cmd {
            0b011 => {
                self.counts.reads += 1;
                Phase::WaitState { address }
            }
            0b010 => {
                // A read without wait state is legal on the chip, but the driver promises the wait state.
                self.violations.push(format!("read of {address:04X} without the wait-state command"));
                self.counts.reads += 1;
                Phase::Read { address, bytes: 0, terminated: false }
            }
            0b100 => {
                self.counts.writes += 1;
                Phase::Write { address }
            }
            other => {
                self.violations.push(format!("command {other:03b} at {address:04X}"));
                Phase::Idle
            }
        }
    }
}

impl SpiBus for ModelChip {
    fn select(&mut self) {
        if self.phase != Phase::Idle {
            self.violations.push("chip select asserted twice".into());
        }
        self.phase = Phase::Address0;
        self.counts.accesses += 1;
    }

    fn transfer(&mut self, mosi: u8) -> u8 {
        match self.phase {
            Phase::Idle => {
                self.violations.push(format!("byte {mosi:02X} with the chip deselected"));
                0xFF
            }
            Phase::Address0 => {
                self.phase = Phase::Address1 { high: u16::from(mosi) << 5 };
                self.al_event_byte(0)
            }
            Phase::Address1 { high } => {
                let address = high | u16::from(mosi >> 3);
                let cmd = mosi & 0b111;
                self.phase = if cmd == 0b110 { Phase::Address2 { low: address } } else { self.command(address, cmd) };
                self.al_event_byte(1)
            }
            Phase::Address2 { low } => {
                if mosi & 0b11 != 0 {
                    self.violations.push(format!("reserved bits set in the third address byte {mosi:02X}"));
                }
                let address = low | (u16::from(mosi >> 5) << 13);
                self.counts.extended += 1;
                let cmd = (mosi >> 2) & 0b111;
                self.phase = self.command(address, cmd);
                self.al_event_byte(2)
            }
            Phase::WaitState { address } => {
                if mosi != 0xFF {
                    self.violations.push(format!("wait-state byte {mosi:02X}, not FF, reading {address:04X}"));
                }
                self.phase = Phase::Read { address, bytes: 0, terminated: false };
                0xFF
            }
            Phase::Read { address, bytes, terminated } => {
                if terminated {
                    self.violations.push(format!("a data byte after the read termination at {address:04X}"));
                }
                let terminated = match mosi {
                    0xFF => true,
                    0x00 => false,
                    other => {
                        self.violations.push(format!("read data byte sent as {other:02X}, not 00/FF"));
                        false
                    }
                };
                let mut b = [0u8];
                self.esc.pdi_read(address, &mut b);
                self.counts.data_bytes += 1;
                self.phase = Phase::Read { address: address.wrapping_add(1), bytes: bytes + 1, terminated };
                b[0]
            }
            Phase::Write { address } => {
                self.esc.pdi_write(address, &[mosi]);
                self.counts.data_bytes += 1;
                self.phase = Phase::Write { address: address.wrapping_add(1) };
                0xFF
            }
        }
    }

    fn deselect(&mut self) {
        match self.phase {
            Phase::Idle => self.violations.push("chip select released twice".into()),
            Phase::Read { address, bytes, terminated: false } => {
                self.violations.push(format!("read of {bytes} bytes ending at {address:04X} without termination"))
            }
            Phase::Read { .. } | Phase::Write { .. } => {}
            other => self.violations.push(format!("access ended in {other:?}")),
        }
        self.phase = Phase::Idle;
    }
}

/// The master on the ECAT side of the emulated ESC, the drive's slave on its PDI side through the SPI driver.
struct Rig {
    spi: SpiEsc<ModelChip>,
    drive: Drive,
    slave: EthercatSlave,
    counter: u8,
    now_ms: u32,
}

impl Rig {
    fn new(addressing: Addressing) -> Self {
        let esc = Esc::with_drive_sii().expect("the drive's SII image");
        let mut rig = Self {
            spi: SpiEsc::new(ModelChip::new(esc), addressing),
            drive: Drive::new(DriveConfig::default()),
            slave: EthercatSlave::new(),
            counter: 0,
            now_ms: 0,
        };
        rig.datagram(Command::Apwr, 0, 0x0010, &STATION.to_le_bytes());
        rig.poll();
        rig
    }

    fn esc(&mut self) -> &mut Esc {
        &mut self.spi.bus_mut().esc
    }

    fn poll(&mut self) {
        self.now_ms += 1;
        self.slave.poll(&mut self.spi, &mut self.drive, &mut NoApplicationObjects, self.now_ms);
    }

    /// Sends a CoE mailbox and returns the CoE answer (CoE header onwards), polling the slave up to 10 times.
    fn coe(&mut self, data: &[u8]) -> Vec<u8> {
        self.counter = if self.counter >= 7 { 1 } else { self.counter + 1 };
        let header = Header { length: data.len() as u16, kind: COE, counter: self.counter, ..Header::default() };
        let mut window = header.encode().to_vec();
        window.extend_from_slice(data);
        window.resize(usize::from(generated::MAILBOX_OUT_SIZE), 0);
        assert_eq!(self.fpwr(generated::MAILBOX_OUT_START, &window), 1, "SM0 took the request");
        for _ in 0..10 {
            self.poll();
            let (window, wkc) = self.fprd(generated::MAILBOX_IN_START, usize::from(generated::MAILBOX_IN_SIZE));
            if wkc == 0 {
                continue;
            }
            let h = Header::parse(&window).expect("a header");
            assert_eq!(h.kind, COE, "a CoE answer");
            let end = (HEADER_LEN + usize::from(h.length)).min(window.len());
            return window[HEADER_LEN..end].to_vec();
        }
        panic!("no answer to the CoE request {data:02X?}");
    }

    /// One SDO request; the SDO bytes of the answer.
    fn sdo(&mut self, sdo: &[u8]) -> Vec<u8> {
        let mut data = vec![0x00, 0x20];
        data.extend_from_slice(sdo);
        data.resize(data.len().max(10), 0);
        let answer = self.coe(&data);
        // An SDO response (service 3), or an abort (service 2, command 0x80).
        let service = answer[1] >> 4;
        assert!(service == 3 || (service == 2 && answer[2] == 0x80), "an SDO answer, got {answer:02X?}");
        answer[2..].to_vec()
    }

    /// SDO upload (expedited, normal, segmented); the value or the abort code.
    fn sdo_upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.sdo(&[0x40, i0, i1, sub, 0, 0, 0, 0]);
        if r[0] == 0x80 {
            return Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]]));
        }
        assert_eq!((r[1], r[2], r[3]), (i0, i1, sub), "the multiplexer is echoed");
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok(r[4..4 + n].to_vec());
        }
        assert_eq!(r[0], 0x41, "a normal upload response");
        let size = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
        let mut value = r[8..].to_vec();
        value.truncate(size);
        let mut toggle = 0u8;
        while value.len() < size {
            let s = self.sdo(&[0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]);
            if s[0] == 0x80 {
                return Err(u32::from_le_bytes([s[4], s[5], s[6], s[7]]));
            }
            let len = if s.len() > 8 { s.len() - 1 } else { 7 - usize::from((s[0] >> 1) & 7) };
            value.extend_from_slice(&s[1..1 + len]);
            toggle ^= 0x10;
            if s[0] & 0x01 != 0 {
                break;
            }
        }
        Ok(value)
    }

    /// What the drive's dictionary holds for `index:sub`.
    fn dictionary_value(&self, index: u16, sub: u8) -> Vec<u8> {
        let mut buf = vec![0u8; 1024];
        let r = self
            .drive
            .dictionary()
            .read(index, sub, 0, &mut buf, &mut NoApplicationObjects)
            .unwrap_or_else(|a| panic!("{index:04X}:{sub} readable: {a:?}"));
        buf.truncate(r.len);
        buf
    }

    fn violations(&mut self) -> Vec<String> {
        self.spi.bus_mut().violations.clone()
    }
}

impl StationMaster for Rig {
    fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
        let mut frame = FrameBuilder::new().push(cmd, adp, ado, data).build();
        self.esc().process_frame(&mut frame).expect("a well-formed frame");
        first_datagram(&frame)
    }
}

/// INIT -> PRE-OP -> SDO uploads, all of the slave's ESC traffic through the SPI framing; returns the counts.
fn init_preop_and_upload(addressing: Addressing) -> Counts {
    let mut rig = Rig::new(addressing);
    assert_eq!(rig.al_status(), (0x0001, 0x0000), "INIT after power-up");

    rig.configure_sm(0, generated::MAILBOX_OUT_START, generated::MAILBOX_OUT_SIZE, 0x26);
    rig.configure_sm(1, generated::MAILBOX_IN_START, generated::MAILBOX_IN_SIZE, 0x22);
    assert_eq!(rig.fpwr(0x0120, &0x0002u16.to_le_bytes()), 1);
    // The AL control event (0x0220 bit 0) is what the chip sends in the address phase of the next access.
    let _ = rig.spi.read_u16(0x0130);
    assert_eq!(rig.spi.last_al_event() & 0x0001, 0x0001, "AL control event seen in the address phase");
    rig.poll();
    assert_eq!(rig.al_status(), (0x0002, 0x0000), "PRE-OP reached through the SPI PDI");

    // Expedited (vendor ID), and a string longer than 4 bytes (normal/segmented upload) over the mailbox.
    for (index, sub) in [(0x1018, 1), (0x1018, 2), (0x1008, 0)] {
        let expected = rig.dictionary_value(index, sub);
        assert_eq!(rig.sdo_upload(index, sub), Ok(expected), "{index:04X}:{sub}");
    }
    assert!(rig.dictionary_value(0x1008, 0).len() > 4, "0x1008 takes more than an expedited transfer");
    // A missing object: the abort comes back through the same path.
    assert_eq!(rig.sdo_upload(0x5FFF, 0), Err(0x0602_0000), "object does not exist");
    // An invalid request (OP from PRE-OP without process data) is refused with an AL status code, read back
    // by the master from registers the slave wrote through the driver.
    assert_eq!(rig.fpwr(0x0120, &0x0008u16.to_le_bytes()), 1);
    rig.poll();
    let (status, code) = rig.al_status();
    assert_eq!(status, 0x0012, "PRE-OP with the error indication");
    assert_ne!(code, 0, "a refusal code");

    let v = rig.violations();
    assert!(v.is_empty(), "framing violations: {v:#?}");
    rig.spi.bus_mut().counts
}

/// ET1100 style: 2-byte addresses (every register and the drive's mailboxes are below 0x2000).
#[test]
fn init_preop_and_sdo_upload_work_through_the_spi_framing_with_two_byte_addresses() {
    let counts = init_preop_and_upload(Addressing::Shortest);
    assert_eq!(counts.extended, 0, "nothing of the exchange lies above 0x1FFF");
    assert!(counts.reads > 10 && counts.writes > 3, "{counts:?}");
    assert!(counts.data_bytes > usize::from(generated::MAILBOX_OUT_SIZE), "mailbox windows went through: {counts:?}");
}

/// AX58100 style: every access with the 3-byte address phase.
#[test]
fn init_preop_and_sdo_upload_work_through_the_spi_framing_with_three_byte_addresses() {
    let counts = init_preop_and_upload(Addressing::Extended);
    assert_eq!(counts.extended, counts.accesses, "every access extended: {counts:?}");
}

/// Process RAM above 0x1FFF (the emulated ESC has 8 KiB, 0x1000..=0x2FFF) is reached through the address
/// extension: what the driver writes there the master reads at that address, and the reverse, and the
/// neighbouring bytes stay untouched (the A[15:13] bits are not lost or shifted).
#[test]
fn addresses_above_0x1fff_reach_the_process_ram_through_the_address_extension() {
    let mut rig = Rig::new(Addressing::Shortest);
    let before = rig.spi.bus_mut().counts;
    rig.spi.write(0x2F05, &[0xDE, 0xAD, 0xBE, 0xEF]);
    let (seen, wkc) = rig.fprd(0x2F04, 6);
    assert_eq!(wkc, 1);
    assert_eq!(seen, [0x00, 0xDE, 0xAD, 0xBE, 0xEF, 0x00], "written at 0x2F05, not at 0x0F05 or 0x1F05");
    let (low, _) = rig.fprd(0x0F05, 4);
    assert_eq!(low, [0, 0, 0, 0], "0x0F05 untouched");

    assert_eq!(rig.fpwr(0x2000, &[0x12, 0x34, 0x56]), 1);
    let mut buf = [0u8; 3];
    rig.spi.read(0x2000, &mut buf);
    assert_eq!(buf, [0x12, 0x34, 0x56]);
    let after = rig.spi.bus_mut().counts;
    assert_eq!(after.extended - before.extended, 2, "both accesses used the 3-byte address");
    let v = rig.violations();
    assert!(v.is_empty(), "framing violations: {v:#?}");
}
