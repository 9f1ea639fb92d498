//! An in-process EtherCAT master for the firmware's application layer: frames built with hal-sim's
//! [`FrameBuilder`] and run through the emulated ESC ([`Esc::process_frame`]), with the firmware's ESM and
//! mailbox polled on the ESC's PDI side ([`firmware::ecat::esc::Esc`] for `hal_sim::esc::Esc`).
//!
//! [`Bench`] holds both sides: `fp*` methods are the master's datagrams, [`Bench::poll`] runs the firmware
//! once, and the helpers on top (state requests, mailbox exchange, SDO upload/download like SOEM's
//! `ec_SDOread`/`ec_SDOwrite`) poll the firmware between the master's steps.

use firmware::ecat::esm::{Esm, EsmConfig, Transition};
use firmware::ecat::foe::{FoeAccess, FoeError, FoeProgress, FoeSink};
use firmware::ecat::mailbox::{Header, Mailbox, MailboxContext, MailboxLayout, HEADER_LEN};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{ApplicationObjects, Dictionary, ReadOutcome};
use firmware::od::entry::Entry;
use firmware::od::generated;
use firmware::recorder::objects::RecorderObjects;
use firmware::recorder::Recorder;
use hal_sim::esc::datagram::{Command, Frame, FrameBuilder};
use hal_sim::esc::Esc;

/// The station address the bench's master assigns.
pub const STATION: u16 = 0x1001;

/// The data and working counter of the first datagram of a frame the ESC has processed.
pub fn first_datagram(frame: &[u8]) -> (Vec<u8>, u16) {
    let f = Frame::new_checked(frame).expect("the returned frame parses");
    let d = f.datagram(0).expect("one datagram");
    (d.data().to_vec(), d.wkc())
}

/// The master's register access to the station [`STATION`], for a test rig that carries each datagram to its
/// emulated ESC its own way ([`StationMaster::datagram`]: straight into the ESC, through a runner's bus cycle,
/// through an SPI model).
pub trait StationMaster {
    /// One datagram in its own frame through the rig; its data and working counter.
    fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16);

    /// FPWR to the station; the working counter.
    fn fpwr(&mut self, ado: u16, data: &[u8]) -> u16 {
        self.datagram(Command::Fpwr, STATION, ado, data).1
    }

    /// FPRD of `len` bytes from the station; data and working counter.
    fn fprd(&mut self, ado: u16, len: usize) -> (Vec<u8>, u16) {
        self.datagram(Command::Fprd, STATION, ado, &vec![0; len])
    }

    /// Reads a u16 register.
    fn read_u16(&mut self, ado: u16) -> u16 {
        let (d, _) = self.fprd(ado, 2);
        u16::from_le_bytes([d[0], d[1]])
    }

    /// AL status (0x0130) and AL status code (0x0134), in one read.
    fn al_status(&mut self) -> (u16, u16) {
        let (d, _) = self.fprd(0x0130, 6);
        (u16::from_le_bytes([d[0], d[1]]), u16::from_le_bytes([d[4], d[5]]))
    }

    /// Writes sync manager `n`'s configuration, activated; asserts that the station took it.
    fn configure_sm(&mut self, n: u16, start: u16, len: u16, control: u8) {
        let [s0, s1] = start.to_le_bytes();
        let [l0, l1] = len.to_le_bytes();
        assert_eq!(self.fpwr(0x0800 + 8 * n, &[s0, s1, l0, l1, control, 0, 0x01, 0]), 1, "SM{n} configured");
    }
}

/// Mailbox type CoE.
pub const COE: u8 = 3;
/// Mailbox type FoE.
pub const FOE: u8 = 4;

/// A FoE sink that keeps the file in memory and records what happened.
#[derive(Clone, Debug, Default)]
pub struct MemorySink {
    /// Name and password of the last open.
    pub opened: Option<(Vec<u8>, u32, FoeAccess)>,
    /// The file written so far.
    pub file: Vec<u8>,
    /// `finish` was called.
    pub finished: bool,
    /// `abort` was called.
    pub aborted: bool,
    /// Answer the next `write` with busy this many times.
    pub busy_left: u32,
    /// The file `read` serves.
    pub readable: Vec<u8>,
}

impl FoeSink for MemorySink {
    fn open(&mut self, name: &[u8], password: u32, access: FoeAccess) -> Result<(), FoeError> {
        if name != b"firmware.bin" {
            return Err(FoeError::NotFound);
        }
        if password != 0 {
            return Err(FoeError::NoRights);
        }
        self.opened = Some((name.to_vec(), password, access));
        self.file.clear();
        self.finished = false;
        Ok(())
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<FoeProgress, FoeError> {
        if self.busy_left > 0 {
            self.busy_left -= 1;
            return Ok(FoeProgress::Busy { done: 1, entire: 2 });
        }
        assert_eq!(offset as usize, self.file.len(), "the offsets follow each other");
        self.file.extend_from_slice(data);
        Ok(FoeProgress::Done)
    }

    fn finish(&mut self) -> Result<(), FoeError> {
        self.finished = true;
        Ok(())
    }

    fn abort(&mut self) {
        self.aborted = true;
    }

    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<usize, FoeError> {
        let rest = self.readable.get(offset as usize..).unwrap_or(&[]);
        let n = rest.len().min(buf.len());
        buf[..n].copy_from_slice(&rest[..n]);
        Ok(n)
    }
}

/// Application objects for the tests: program data 0x1F50:01 is collected in memory.
#[derive(Clone, Debug, Default)]
pub struct ProgramApp {
    /// The bytes written to 0x1F50:01.
    pub program: Vec<u8>,
    /// The last write was complete.
    pub complete: bool,
}

impl ApplicationObjects for ProgramApp {
    fn read(&mut self, _: &'static Entry, _: usize, _: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        Err(SdoAbort::CannotTransfer)
    }

    fn write(
        &mut self,
        _: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        _: &mut [u8],
    ) -> Result<(), SdoAbort> {
        if offset == 0 {
            self.program.clear();
        }
        self.program.extend_from_slice(data);
        self.complete = complete;
        Ok(())
    }
}

/// The emulated ESC with the firmware's ESM and mailbox on its PDI side and a master on its ECAT side.
pub struct Bench {
    /// The emulated ESC.
    pub esc: Esc,
    /// The firmware's state machine.
    pub esm: Esm,
    /// The firmware's mailbox.
    pub mailbox: Mailbox,
    /// The dictionary.
    pub dict: Dictionary,
    /// Application objects.
    pub app: ProgramApp,
    /// The data recorder in front of `app` (0x3300..0x3302), as the drive's runtime holds it.
    pub recorder: Recorder,
    /// The FoE sink.
    pub sink: MemorySink,
    /// The firmware's millisecond clock.
    pub now_ms: u32,
    /// The mailbox layout the master configures.
    pub layout: MailboxLayout,
    /// Every transition the ESM reported.
    pub transitions: Vec<Transition>,
    counter: u8,
}

impl Default for Bench {
    fn default() -> Self {
        Self::new()
    }
}

impl Bench {
    /// The drive's ESC (SII from od-gen) and firmware, the station address assigned.
    pub fn new() -> Self {
        Self::with_layout(MailboxLayout::DRIVE)
    }

    /// A bench whose firmware and master use `layout` for the mailboxes (to test small mailboxes).
    pub fn with_layout(layout: MailboxLayout) -> Self {
        let config = EsmConfig { mailbox: layout, boot_mailbox: layout, ..EsmConfig::DRIVE };
        let mut bench = Self {
            esc: Esc::with_drive_sii().expect("the drive's SII image"),
            esm: Esm::new(config),
            mailbox: Mailbox::new(layout),
            dict: Dictionary::new(generated::DEFAULT_NODE_ID),
            app: ProgramApp::default(),
            recorder: Recorder::new(),
            sink: MemorySink::default(),
            now_ms: 0,
            layout,
            transitions: Vec::new(),
            counter: 0,
        };
        bench.datagram(Command::Apwr, 0, 0x0010, &STATION.to_le_bytes());
        bench.poll();
        bench
    }

    /// Runs the firmware once: the ESM, then the mailbox.
    pub fn poll(&mut self) {
        if let Some(t) = self.esm.poll(&mut self.esc, &self.dict, self.now_ms) {
            self.transitions.push(t);
        }
        let mut app = RecorderObjects::new(&mut self.recorder, &mut self.app);
        let mut ctx = MailboxContext {
            state: self.esm.state(),
            dict: &mut self.dict,
            app: &mut app,
            power_stage_enabled: false,
            foe_sink: &mut self.sink,
        };
        self.mailbox.poll(&mut self.esc, &mut ctx);
    }

    /// One datagram in its own frame; returns the data and the working counter.
    pub fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
        let mut frame = FrameBuilder::new().push(cmd, adp, ado, data).build();
        self.esc.process_frame(&mut frame).expect("a well-formed frame");
        first_datagram(&frame)
    }

    /// FPWR to the bench's station; the working counter.
    pub fn fpwr(&mut self, ado: u16, data: &[u8]) -> u16 {
        self.datagram(Command::Fpwr, STATION, ado, data).1
    }

    /// FPRD of `len` bytes from the bench's station; data and working counter.
    pub fn fprd(&mut self, ado: u16, len: usize) -> (Vec<u8>, u16) {
        self.datagram(Command::Fprd, STATION, ado, &vec![0; len])
    }

    /// Reads a u16 register.
    pub fn read_u16(&mut self, ado: u16) -> u16 {
        let (d, _) = self.fprd(ado, 2);
        u16::from_le_bytes([d[0], d[1]])
    }

    /// AL status and AL status code as the master reads them.
    pub fn al_status(&mut self) -> (u16, u16) {
        (self.read_u16(0x0130), self.read_u16(0x0134))
    }

    /// Writes sync manager `n`'s configuration.
    pub fn configure_sm(&mut self, n: u16, start: u16, len: u16, control: u8, activate: u8) {
        let [s0, s1] = start.to_le_bytes();
        let [l0, l1] = len.to_le_bytes();
        let wkc = self.fpwr(0x0800 + 8 * n, &[s0, s1, l0, l1, control, 0, activate, 0]);
        assert_eq!(wkc, 1);
    }

    /// SM0/SM1 as the SII describes them (control 0x26 / 0x22, enabled).
    pub fn configure_mailboxes(&mut self) {
        let l = self.layout;
        self.configure_sm(0, l.out_start, l.out_size, 0x26, 0x01);
        self.configure_sm(1, l.in_start, l.in_size, 0x22, 0x01);
    }

    /// Writes AL control, runs the firmware and returns AL status and code.
    pub fn request(&mut self, control: u16) -> (u16, u16) {
        self.fpwr(0x0120, &control.to_le_bytes());
        self.poll();
        self.al_status()
    }

    /// INIT -> PRE-OP with the mailboxes configured; panics if refused.
    pub fn to_preop(&mut self) {
        self.configure_mailboxes();
        assert_eq!(self.request(0x0002), (0x0002, 0x0000), "PRE-OP reached");
    }

    /// INIT -> BOOT with the mailboxes configured; panics if refused.
    pub fn to_boot(&mut self) {
        self.configure_mailboxes();
        assert_eq!(self.request(0x0003), (0x0003, 0x0000), "BOOT reached");
    }

    /// The counter the next request carries (1..7).
    pub fn next_counter(&mut self) -> u8 {
        self.counter = if self.counter >= 7 { 1 } else { self.counter + 1 };
        self.counter
    }

    /// Writes a raw mailbox (header included, padded to the SM0 window) into SM0; the working counter.
    pub fn send_raw(&mut self, bytes: &[u8]) -> u16 {
        let mut window = vec![0u8; usize::from(self.layout.out_size)];
        window[..bytes.len()].copy_from_slice(bytes);
        self.fpwr(self.layout.out_start, &window)
    }

    /// Writes a mailbox of `kind` with `data` and counter `counter`; the working counter.
    pub fn send_with_counter(&mut self, kind: u8, counter: u8, data: &[u8]) -> u16 {
        let header = Header { length: data.len() as u16, kind, counter, ..Header::default() };
        let mut bytes = header.encode().to_vec();
        bytes.extend_from_slice(data);
        self.send_raw(&bytes)
    }

    /// Writes a mailbox of `kind` with `data` and the next counter; the working counter.
    pub fn send(&mut self, kind: u8, data: &[u8]) -> u16 {
        let counter = self.next_counter();
        self.send_with_counter(kind, counter, data)
    }

    /// Reads SM1 if it holds a mailbox: the header and the data (`length` bytes).
    pub fn receive(&mut self) -> Option<(Header, Vec<u8>)> {
        let (window, wkc) = self.fprd(self.layout.in_start, usize::from(self.layout.in_size));
        if wkc == 0 {
            return None;
        }
        let header = Header::parse(&window).expect("a header");
        let end = (HEADER_LEN + usize::from(header.length)).min(window.len());
        Some((header, window[HEADER_LEN..end].to_vec()))
    }

    /// Sends a mailbox, runs the firmware and reads the answer; panics when none comes.
    pub fn exchange(&mut self, kind: u8, data: &[u8]) -> (Header, Vec<u8>) {
        assert_eq!(self.send(kind, data), 1, "SM0 took the request");
        self.poll();
        self.receive().expect("an answer in SM1")
    }

    /// A CoE SDO request (service 2) with `sdo` (command byte onwards, padded to 8 bytes); the answer's CoE
    /// header service and SDO bytes.
    pub fn sdo(&mut self, sdo: &[u8]) -> (u8, Vec<u8>) {
        let mut data = vec![0x00, 0x20];
        data.extend_from_slice(sdo);
        if data.len() < 10 {
            data.resize(10, 0);
        }
        let (h, answer) = self.exchange(COE, &data);
        assert_eq!(h.kind, COE, "a CoE answer, got {h:?} {answer:02X?}");
        let service = answer[1] >> 4;
        (service, answer[2..].to_vec())
    }

    /// SDO upload like SOEM's `ec_SDOread`: expedited, normal, or normal followed by segments. Returns the
    /// value and how many upload segments it took, or the abort code.
    pub fn sdo_upload(&mut self, index: u16, sub: u8) -> Result<(Vec<u8>, usize), u32> {
        let [i0, i1] = index.to_le_bytes();
        let (service, r) = self.sdo(&[0x40, i0, i1, sub, 0, 0, 0, 0]);
        if r[0] == 0x80 {
            assert_eq!(service, 2, "an abort is an SDO request");
            return Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]]));
        }
        assert_eq!(service, 3, "an SDO response");
        assert_eq!((r[1], r[2], r[3]), (i0, i1, sub), "the multiplexer is echoed");
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok((r[4..4 + n].to_vec(), 0));
        }
        assert_eq!(r[0], 0x41, "a normal upload response");
        let size = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
        let mut value = r[8..].to_vec();
        value.truncate(size);
        let mut toggle = 0u8;
        let mut segments = 0;
        while value.len() < size {
            let (service, s) = self.sdo(&[0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]);
            if s[0] == 0x80 {
                return Err(u32::from_le_bytes([s[4], s[5], s[6], s[7]]));
            }
            assert_eq!(service, 3);
            assert_eq!(s[0] & 0xE0, 0x00, "an upload segment response");
            assert_eq!(s[0] & 0x10, toggle, "the toggle is echoed");
            let len = if s.len() > 8 { s.len() - 1 } else { 7 - usize::from((s[0] >> 1) & 7) };
            value.extend_from_slice(&s[1..1 + len]);
            segments += 1;
            toggle ^= 0x10;
            if s[0] & 0x01 != 0 {
                break;
            }
        }
        Ok((value, segments))
    }

    /// SDO download like SOEM's `ec_SDOwrite`: expedited up to 4 bytes, else normal with as much data as the
    /// mailbox holds and download segments for the rest. Returns the number of segments, or the abort code.
    pub fn sdo_download(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<usize, u32> {
        let [i0, i1] = index.to_le_bytes();
        let abort = |r: &[u8]| u32::from_le_bytes([r[4], r[5], r[6], r[7]]);
        if value.len() <= 4 {
            let n = 4 - value.len() as u8;
            let mut req = vec![0x23 | (n << 2), i0, i1, sub];
            req.extend_from_slice(value);
            req.resize(8, 0);
            let (_, r) = self.sdo(&req);
            return if r[0] == 0x80 { Err(abort(&r)) } else { Ok(0) };
        }
        let room = usize::from(self.layout.out_size) - HEADER_LEN - 2 - 8;
        let first = value.len().min(room);
        let mut req = vec![0x21, i0, i1, sub];
        req.extend_from_slice(&(value.len() as u32).to_le_bytes());
        req.extend_from_slice(&value[..first]);
        let (_, r) = self.sdo(&req);
        if r[0] == 0x80 {
            return Err(abort(&r));
        }
        assert_eq!(r[0], 0x60);
        let mut sent = first;
        let mut toggle = 0u8;
        let mut segments = 0;
        let seg_room = usize::from(self.layout.out_size) - HEADER_LEN - 2 - 1;
        while sent < value.len() {
            let len = (value.len() - sent).min(seg_room);
            let last = u8::from(sent + len == value.len());
            let mut seg = Vec::new();
            if len < 7 {
                seg.push(toggle | (((7 - len) as u8) << 1) | last);
                seg.extend_from_slice(&value[sent..sent + len]);
                seg.resize(8, 0);
            } else {
                seg.push(toggle | last);
                seg.extend_from_slice(&value[sent..sent + len]);
            }
            let (_, r) = self.sdo(&seg);
            if r[0] == 0x80 {
                return Err(abort(&r));
            }
            assert_eq!(r[0], 0x20 | toggle, "download segment response with the toggle");
            sent += len;
            segments += 1;
            toggle ^= 0x10;
        }
        Ok(segments)
    }
}
