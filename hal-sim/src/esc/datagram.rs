//! EtherCAT frames and the datagram engine (ETG.1000.4 §5.3 "Frame structure", §5.4 "EtherCAT DLPDU",
//! §5.2 commands; the working-counter rules of ETG.1000.4 Table 3 ff., as the spec file lists them).
//!
//! Frame layout: Ethernet header (destination, source, optional 802.1Q tag, EtherType 0x88A4), EtherCAT header
//! (u16 LE: bits 10..0 length of the datagrams, bits 15..12 type, 1 = DLPDUs), then chained datagrams:
//!
//! ```text
//! cmd u8 | idx u8 | ADP u16 | ADO u16 (or logical u32) | len u16 (10..0 length, 14 circulating, 15 more)
//! | IRQ u16 | data[len] | WKC u16
//! ```
//!
//! [`Frame::new_checked`] validates the whole chain before anything is processed, so a malformed frame never
//! has half its datagrams applied; it never panics on any input. [`FrameBuilder`] writes frames for tests.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;

use super::registers::{get_u16, reg};
use super::{Esc, Side};

/// The EtherCAT EtherType.
pub const ETHERTYPE_ETHERCAT: u16 = 0x88A4;
/// The 802.1Q VLAN tag EtherType.
pub const ETHERTYPE_VLAN: u16 = 0x8100;
/// Datagram header length.
pub const DATAGRAM_HEADER: usize = 10;
/// Working counter length.
pub const WKC_LEN: usize = 2;
/// Largest datagram data length (11 bits).
pub const MAX_DATA: usize = 0x7FF;

/// EtherCAT commands (ETG.1000.4 Table 20). Unknown codes are kept and processed as NOP.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// 0: no operation.
    Nop,
    /// 1: auto-increment physical read.
    Aprd,
    /// 2: auto-increment physical write.
    Apwr,
    /// 3: auto-increment physical read/write.
    Aprw,
    /// 4: configured-address physical read.
    Fprd,
    /// 5: configured-address physical write.
    Fpwr,
    /// 6: configured-address physical read/write.
    Fprw,
    /// 7: broadcast read.
    Brd,
    /// 8: broadcast write.
    Bwr,
    /// 9: broadcast read/write.
    Brw,
    /// 10: logical read.
    Lrd,
    /// 11: logical write.
    Lwr,
    /// 12: logical read/write.
    Lrw,
    /// 13: auto-increment physical read, multiple write.
    Armw,
    /// 14: configured-address physical read, multiple write.
    Frmw,
    /// Any other code.
    Unknown(u8),
}

impl Command {
    /// The command of a code.
    pub const fn from_code(c: u8) -> Self {
        match c {
            0 => Self::Nop,
            1 => Self::Aprd,
            2 => Self::Apwr,
            3 => Self::Aprw,
            4 => Self::Fprd,
            5 => Self::Fpwr,
            6 => Self::Fprw,
            7 => Self::Brd,
            8 => Self::Bwr,
            9 => Self::Brw,
            10 => Self::Lrd,
            11 => Self::Lwr,
            12 => Self::Lrw,
            13 => Self::Armw,
            14 => Self::Frmw,
            c => Self::Unknown(c),
        }
    }

    /// The code of a command.
    pub const fn code(self) -> u8 {
        match self {
            Self::Nop => 0,
            Self::Aprd => 1,
            Self::Apwr => 2,
            Self::Aprw => 3,
            Self::Fprd => 4,
            Self::Fpwr => 5,
            Self::Fprw => 6,
            Self::Brd => 7,
            Self::Bwr => 8,
            Self::Brw => 9,
            Self::Lrd => 10,
            Self::Lwr => 11,
            Self::Lrw => 12,
            Self::Armw => 13,
            Self::Frmw => 14,
            Self::Unknown(c) => c,
        }
    }
}

/// Why a frame was not processed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// Shorter than an Ethernet header: not a frame for us (not counted).
    TooShort,
    /// Another EtherType (not counted).
    NotEtherCat(u16),
    /// An EtherCAT header type other than 1 (network variables, mailbox gateway): not processed, not counted.
    UnsupportedType(u8),
    /// The EtherCAT header is missing or its length exceeds the frame (counted as malformed).
    BadLength,
    /// Datagram `n` runs past the EtherCAT length or the frame (counted as malformed).
    Truncated(usize),
    /// The EtherCAT length holds no datagram (counted as malformed).
    Empty,
}

impl FrameError {
    /// Whether the ESC counts the frame as malformed (RX error counter 0x0300).
    pub const fn is_malformed(self) -> bool {
        matches!(self, Self::BadLength | Self::Truncated(_) | Self::Empty)
    }
}

/// A read-only view of one datagram (header, data and working counter).
#[derive(Clone, Copy, Debug)]
pub struct Datagram<'a> {
    bytes: &'a [u8],
}

fn le16(b: &[u8], at: usize) -> u16 {
    match b.get(at..at + 2) {
        Some(s) => u16::from_le_bytes([s[0], s[1]]),
        None => 0,
    }
}

impl<'a> Datagram<'a> {
    /// The command.
    pub fn command(&self) -> Command {
        Command::from_code(self.bytes.first().copied().unwrap_or(0))
    }

    /// The index (the master's tag).
    pub fn index(&self) -> u8 {
        self.bytes.get(1).copied().unwrap_or(0)
    }

    /// ADP: position (auto-increment) or station address.
    pub fn adp(&self) -> u16 {
        le16(self.bytes, 2)
    }

    /// ADO: register or memory offset.
    pub fn ado(&self) -> u16 {
        le16(self.bytes, 4)
    }

    /// The 32-bit logical address (logical commands).
    pub fn logical(&self) -> u32 {
        u32::from(self.adp()) | u32::from(self.ado()) << 16
    }

    /// Data length.
    pub fn len(&self) -> usize {
        usize::from(le16(self.bytes, 6) & 0x07FF)
    }

    /// Whether the data is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The "more datagrams follow" bit.
    pub fn more(&self) -> bool {
        le16(self.bytes, 6) & 0x8000 != 0
    }

    /// The circulating bit.
    pub fn circulating(&self) -> bool {
        le16(self.bytes, 6) & 0x4000 != 0
    }

    /// The IRQ field.
    pub fn irq(&self) -> u16 {
        le16(self.bytes, 8)
    }

    /// The data.
    pub fn data(&self) -> &'a [u8] {
        self.bytes.get(DATAGRAM_HEADER..DATAGRAM_HEADER + self.len()).unwrap_or(&[])
    }

    /// The working counter.
    pub fn wkc(&self) -> u16 {
        le16(self.bytes, DATAGRAM_HEADER + self.len())
    }
}

/// A checked view of an EtherCAT frame: where the EtherCAT payload and each datagram are.
#[derive(Clone, Debug)]
pub struct Frame<'a> {
    buf: &'a [u8],
    layout: Layout,
}

/// Positions of the parts of a checked frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Offset of the EtherCAT header.
    pub header: usize,
    /// Byte ranges of the datagrams (header to working counter).
    pub datagrams: Vec<Range<usize>>,
}

/// Checks a whole frame and returns the positions of its datagrams.
pub fn parse_layout(buf: &[u8]) -> Result<Layout, FrameError> {
    if buf.len() < 14 {
        return Err(FrameError::TooShort);
    }
    let ethertype_at = |at: usize| buf.get(at..at + 2).map(|b| u16::from_be_bytes([b[0], b[1]]));
    let mut at = 12;
    let mut ethertype = ethertype_at(at).ok_or(FrameError::TooShort)?;
    if ethertype == ETHERTYPE_VLAN {
        at += 4;
        ethertype = ethertype_at(at).ok_or(FrameError::TooShort)?;
    }
    if ethertype != ETHERTYPE_ETHERCAT {
        return Err(FrameError::NotEtherCat(ethertype));
    }
    let header = at + 2;
    let h = buf.get(header..header + 2).ok_or(FrameError::BadLength)?;
    let h = u16::from_le_bytes([h[0], h[1]]);
    let kind = (h >> 12) as u8;
    if kind != 1 {
        return Err(FrameError::UnsupportedType(kind));
    }
    let length = usize::from(h & 0x07FF);
    let start = header + 2;
    let end = start + length;
    if end > buf.len() {
        return Err(FrameError::BadLength);
    }
    let mut datagrams = Vec::new();
    let mut p = start;
    loop {
        let n = datagrams.len();
        if p + DATAGRAM_HEADER > end {
            return Err(if n == 0 { FrameError::Empty } else { FrameError::Truncated(n) });
        }
        let lenf = u16::from_le_bytes([buf[p + 6], buf[p + 7]]);
        let total = DATAGRAM_HEADER + usize::from(lenf & 0x07FF) + WKC_LEN;
        if p + total > end {
            return Err(FrameError::Truncated(n));
        }
        datagrams.push(p..p + total);
        p += total;
        if lenf & 0x8000 == 0 {
            break;
        }
    }
    Ok(Layout { header, datagrams })
}

impl<'a> Frame<'a> {
    /// Checks `buf` (a whole Ethernet frame).
    pub fn new_checked(buf: &'a [u8]) -> Result<Self, FrameError> {
        Ok(Self { buf, layout: parse_layout(buf)? })
    }

    /// The datagrams, in order.
    pub fn datagrams(&self) -> impl Iterator<Item = Datagram<'a>> + '_ {
        let buf = self.buf;
        self.layout.datagrams.iter().map(move |r| Datagram { bytes: buf.get(r.clone()).unwrap_or(&[]) })
    }

    /// Datagram `n`.
    pub fn datagram(&self, n: usize) -> Option<Datagram<'a>> {
        let r = self.layout.datagrams.get(n)?;
        Some(Datagram { bytes: self.buf.get(r.clone())? })
    }

    /// The source MAC address.
    pub fn source(&self) -> [u8; 6] {
        let mut m = [0; 6];
        m.copy_from_slice(&self.buf[6..12]);
        m
    }
}

/// Builds EtherCAT frames (for tests and tools): broadcast destination, a master-like source address.
#[derive(Clone, Debug, Default)]
pub struct FrameBuilder {
    source: Option<[u8; 6]>,
    datagrams: Vec<(Command, u8, u32, Vec<u8>)>,
}

impl FrameBuilder {
    /// An empty frame.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the source MAC address (default 01:01:01:01:01:01, SOEM's primary).
    pub fn source(mut self, mac: [u8; 6]) -> Self {
        self.source = Some(mac);
        self
    }

    /// Appends a physical-address datagram (`adp`, `ado`) with `data` (its length is the access length).
    pub fn push(mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> Self {
        let idx = self.datagrams.len() as u8;
        self.datagrams.push((cmd, idx, u32::from(adp) | u32::from(ado) << 16, data.to_vec()));
        self
    }

    /// Appends a logical datagram at `address`.
    pub fn push_logical(mut self, cmd: Command, address: u32, data: &[u8]) -> Self {
        let idx = self.datagrams.len() as u8;
        self.datagrams.push((cmd, idx, address, data.to_vec()));
        self
    }

    /// The frame bytes, padded to the 60-byte Ethernet minimum.
    pub fn build(&self) -> Vec<u8> {
        let mut f = vec![0xFF; 6];
        f.extend_from_slice(&self.source.unwrap_or([0x01; 6]));
        f.extend_from_slice(&ETHERTYPE_ETHERCAT.to_be_bytes());
        let body: usize = self.datagrams.iter().map(|d| DATAGRAM_HEADER + d.3.len().min(MAX_DATA) + WKC_LEN).sum();
        let h = (body.min(0x7FF) as u16) | 0x1000;
        f.extend_from_slice(&h.to_le_bytes());
        let n = self.datagrams.len();
        for (i, (cmd, idx, address, data)) in self.datagrams.iter().enumerate() {
            let data = &data[..data.len().min(MAX_DATA)];
            f.push(cmd.code());
            f.push(*idx);
            f.extend_from_slice(&address.to_le_bytes());
            let more = if i + 1 < n { 0x8000 } else { 0 };
            f.extend_from_slice(&(data.len() as u16 | more).to_le_bytes());
            f.extend_from_slice(&0u16.to_le_bytes());
            f.extend_from_slice(data);
            f.extend_from_slice(&0u16.to_le_bytes());
        }
        if f.len() < 60 {
            f.resize(60, 0);
        }
        f
    }
}

/// What one processed frame did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FrameReport {
    /// Per datagram: the command and the working counter this ESC added.
    pub datagrams: Vec<(Command, u16)>,
}

impl Esc {
    /// Processes an EtherCAT frame in place, as the frame passes the ESC's processing unit on port 0 and
    /// returns through the closed ports: every datagram is executed, working counters and IRQ fields updated,
    /// and bit 1 of the first source-MAC byte is set (what a real slave does; ethercrab uses it to tell
    /// returned frames from its own).
    ///
    /// A malformed frame is not processed: it is counted (frame stats and 0x0300, saturating) and the error
    /// returned; a frame that is not EtherCAT is ignored. Either way the caller must not send it back.
    pub fn process_frame(&mut self, frame: &mut [u8]) -> Result<FrameReport, FrameError> {
        self.process_frame_at(frame, 0, None)
    }

    /// [`Esc::process_frame`] for an ESC in a line: the frame reaches this ESC's port 0 `arrival_ns` (ideal ns,
    /// may be negative) from the ESC's current time and, with port 1 open, comes back through port 1 at
    /// `return_ns`. The DC receive times latch the local clock at those instants, and reads of the system time
    /// (0x0910) and the time control loop's writes see it at the arrival, so that a master measuring the
    /// propagation delay finds the line's port-to-port delays (ESC datasheet section I, "Propagation delay
    /// measurement"). `process_frame` is `process_frame_at(frame, 0, None)`.
    pub fn process_frame_at(
        &mut self,
        frame: &mut [u8],
        arrival_ns: i64,
        return_ns: Option<i64>,
    ) -> Result<FrameReport, FrameError> {
        self.arrival_ns = arrival_ns;
        let result = self.process_frame_inner(frame, return_ns);
        self.arrival_ns = 0;
        self.refresh();
        result
    }

    fn process_frame_inner(&mut self, frame: &mut [u8], return_ns: Option<i64>) -> Result<FrameReport, FrameError> {
        let layout = match parse_layout(frame) {
            Ok(l) => l,
            Err(e) => {
                if e.is_malformed() {
                    self.stats.malformed += 1;
                    let c = &mut self.regs[usize::from(reg::RX_ERROR_COUNTER)];
                    *c = c.saturating_add(1);
                } else {
                    self.stats.ignored += 1;
                }
                return Err(e);
            }
        };
        self.rx_local = self.clock.local.wrapping_add_signed(self.arrival_ns);
        self.rx_local_port1 = return_ns.map(|r| self.clock.local.wrapping_add_signed(r));
        let mut report = FrameReport::default();
        for r in layout.datagrams {
            if let Some(d) = frame.get_mut(r) {
                report.datagrams.push(self.process_datagram(d));
            }
        }
        if let Some(b) = frame.get_mut(6) {
            *b |= 0x02;
        }
        self.stats.processed += 1;
        self.refresh();
        Ok(report)
    }

    /// Executes one datagram (`d` = header .. working counter, already length-checked).
    fn process_datagram(&mut self, d: &mut [u8]) -> (Command, u16) {
        self.stats.datagrams += 1;
        self.refresh();
        let cmd = Command::from_code(d[0]);
        let adp = u16::from_le_bytes([d[2], d[3]]);
        let ado = u16::from_le_bytes([d[4], d[5]]);
        let len = usize::from(u16::from_le_bytes([d[6], d[7]]) & 0x07FF);
        let (head, rest) = d.split_at_mut(DATAGRAM_HEADER);
        let (data, wkc_bytes) = rest.split_at_mut(len);

        let station = self.station_address();
        let alias_on = self.regs[usize::from(reg::DL_CONTROL_ALIAS)] & 1 != 0;
        let alias = get_u16(&self.regs[..], reg::STATION_ALIAS);
        let fp_hit = adp == station || (alias_on && adp == alias);
        let ap_hit = adp == 0;

        use Command as C;
        let add: u16 = match cmd {
            C::Nop | C::Unknown(_) => 0,
            C::Aprd => self.hit_if(ap_hit, |e| e.phys_read(ado, data, false)),
            C::Apwr => self.hit_if(ap_hit, |e| e.phys_write(ado, data)),
            C::Aprw => self.hit_if(ap_hit, |e| e.phys_rw(ado, data, false)),
            C::Fprd => self.hit_if(fp_hit, |e| e.phys_read(ado, data, false)),
            C::Fpwr => self.hit_if(fp_hit, |e| e.phys_write(ado, data)),
            C::Fprw => self.hit_if(fp_hit, |e| e.phys_rw(ado, data, false)),
            C::Brd => self.phys_read(ado, data, true),
            C::Bwr => self.phys_write(ado, data),
            C::Brw => self.phys_rw(ado, data, true),
            C::Armw | C::Frmw => {
                let reader = if cmd == C::Armw { ap_hit } else { fp_hit };
                // The addressed slave (the reference clock) reads; every other slave writes what it got.
                if reader {
                    self.phys_read(ado, data, false)
                } else {
                    self.phys_write(ado, data)
                }
            }
            C::Lrd => self.logical(u32::from(adp) | u32::from(ado) << 16, data, true, false),
            C::Lwr => self.logical(u32::from(adp) | u32::from(ado) << 16, data, false, true),
            C::Lrw => self.logical(u32::from(adp) | u32::from(ado) << 16, data, true, true),
        };
        // Position addressing: every slave increments ADP (AP*, ARMW and B*).
        if matches!(cmd, C::Aprd | C::Apwr | C::Aprw | C::Armw | C::Brd | C::Bwr | C::Brw) {
            head[2..4].copy_from_slice(&adp.wrapping_add(1).to_le_bytes());
        }
        let irq =
            u16::from_le_bytes([head[8], head[9]]) | (self.ecat_event & get_u16(&self.regs[..], reg::ECAT_EVENT_MASK));
        head[8..10].copy_from_slice(&irq.to_le_bytes());
        let wkc = u16::from_le_bytes([wkc_bytes[0], wkc_bytes[1]]).wrapping_add(add);
        wkc_bytes[..2].copy_from_slice(&wkc.to_le_bytes());
        self.apply_ecat_writes();
        (cmd, add)
    }

    fn hit_if(&mut self, hit: bool, f: impl FnOnce(&mut Self) -> u16) -> u16 {
        if hit {
            f(self)
        } else {
            0
        }
    }

    /// Physical read: +1 if any byte was read. `or`: broadcast read, data OR-ed with the memory.
    fn phys_read(&mut self, ado: u16, data: &mut [u8], or: bool) -> u16 {
        let mut any = false;
        for (i, b) in data.iter_mut().enumerate() {
            let Ok(a) = u16::try_from(usize::from(ado) + i) else { break };
            if let Some(v) = self.mem_read(Side::Ecat, a) {
                *b = if or { *b | v } else { v };
                any = true;
            }
        }
        u16::from(any)
    }

    /// Physical write: +1 if any byte was accepted.
    fn phys_write(&mut self, ado: u16, data: &[u8]) -> u16 {
        let mut any = false;
        for (i, &v) in data.iter().enumerate() {
            let Ok(a) = u16::try_from(usize::from(ado) + i) else { break };
            any |= self.mem_write(Side::Ecat, a, v);
        }
        u16::from(any)
    }

    /// Physical read/write: the memory's value goes into the frame, the frame's value into memory;
    /// +1 read, +2 write.
    fn phys_rw(&mut self, ado: u16, data: &mut [u8], or: bool) -> u16 {
        let orig = data.to_vec();
        let r = self.phys_read(ado, data, or);
        let w = self.phys_write(ado, &orig);
        r + 2 * w
    }

    /// Logical access through the FMMUs: +1 when a read FMMU served a byte, +1 (LWR) or +2 (LRW) when a
    /// write FMMU stored one. Reads happen before writes, so an overlapping read and write mapping returns the
    /// old value.
    fn logical(&mut self, address: u32, data: &mut [u8], read: bool, write: bool) -> u16 {
        let fmmus: Vec<_> = (0..super::FMMU_COUNT).filter_map(|n| self.fmmu(n)).collect();
        let base = u64::from(address);
        let n = data.len() as u64;
        let orig = data.to_vec();
        let range_of = |f: &super::fmmu::Fmmu| {
            let lo = u64::from(f.logical_start).saturating_sub(base);
            let hi = (u64::from(f.logical_start) + u64::from(f.length)).saturating_sub(base).min(n);
            lo..hi
        };
        let mut wkc = 0;
        if read {
            let readers: Vec<_> = fmmus.iter().filter(|f| f.reads() && f.overlaps(base, n)).collect();
            let mut need = BTreeSet::new();
            for f in &readers {
                for i in range_of(f) {
                    f.map_byte(base + i, |_, p, _| {
                        need.insert(p);
                    });
                }
            }
            let values: BTreeMap<u16, Option<u8>> =
                need.into_iter().map(|p| (p, self.mem_read(Side::Ecat, p))).collect();
            if values.values().any(Option::is_some) {
                wkc += 1;
            }
            for f in &readers {
                for i in range_of(f) {
                    let Some(b) = data.get_mut(i as usize) else { continue };
                    f.map_byte(base + i, |bit, p, pbit| {
                        if let Some(Some(v)) = values.get(&p) {
                            let x = (v >> pbit) & 1;
                            *b = (*b & !(1 << bit)) | (x << bit);
                        }
                    });
                }
            }
        }
        if write {
            let mut out: BTreeMap<u16, (u8, u8)> = BTreeMap::new();
            for f in fmmus.iter().filter(|f| f.writes() && f.overlaps(base, n)) {
                for i in range_of(f) {
                    let src = orig.get(i as usize).copied().unwrap_or(0);
                    f.map_byte(base + i, |bit, p, pbit| {
                        let e = out.entry(p).or_insert((0, 0));
                        let x = (src >> bit) & 1;
                        e.0 |= 1 << pbit;
                        e.1 = (e.1 & !(1 << pbit)) | (x << pbit);
                    });
                }
            }
            let mut hit = false;
            for (p, (mask, bits)) in out {
                let v = if mask == 0xFF { bits } else { (self.mem_peek(p) & !mask) | bits };
                hit |= self.mem_write(Side::Ecat, p, v);
            }
            if hit {
                wkc += if read { 2 } else { 1 };
            }
        }
        wkc
    }
}
