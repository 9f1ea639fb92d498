//! FoE, file access over EtherCAT (ETG.1000.5 §5.3 / ETG.1000.6 §5.7 "FoE"), as the mailbox's type 4: the
//! firmware download path of the bootloader (comms-faults-bootloader.md §1.9 and §4.8 item 8: BOOT, FoE write
//! of the image, INIT).
//!
//! Every FoE mailbox starts with a 6-byte header: opcode u8, reserved u8, then a u32 whose meaning depends on
//! the opcode (password of a read/write request, packet number of data and acknowledge, error code of an error;
//! done u16 + entire u16 of busy), followed by the file name, the file data or the error text.
//!
//! - **write** (WRQ, opcode 2): the sink opens the file; the drive acknowledges packet 0. Data packets
//!   (opcode 3) follow with packet numbers 1, 2, ...; each is handed to the sink at its file offset and
//!   acknowledged (opcode 4). A packet shorter than the mailbox allows (mailbox size − 12 bytes) is the last one
//!   (an empty one ends a file whose size is a multiple of it): the sink finishes the file, then the drive
//!   acknowledges. A sink that cannot take data now (flash erase) answers busy (opcode 6) and the master
//!   sends the same packet again.
//! - **read** (RRQ, opcode 1, optional in the sink): the drive sends data packets 1, 2, ... and waits for each
//!   acknowledge; a short packet ends the file.
//! - **errors** (opcode 5, ETG.1000.5 FoE error codes, IDX Table 7-155): a request outside BOOT gets 0x8008
//!   "bootstrap only" (IDX: FoE download only in BOOT; the Beckhoff SSC `FOE_Write` returns
//!   `ECAT_FOE_ERRCODE_BOOTSTRAPONLY` = 0x8008 for it; 0x8009 "not bootstrap" is the opposite case, a file that
//!   is not valid in BOOT); a data packet with the wrong number gets 0x8005; a packet the state does not expect
//!   gets 0x8004 (illegal); the sink's own refusals carry its code and the text it gives
//!   ([`FoeSink::error_text`]). The master's error request ends the transfer without an answer. A mailbox shorter than the FoE header is mailbox error 0x06.

use super::mailbox::MailboxError;

/// Length of the FoE header.
pub const FOE_HEADER_LEN: usize = 6;

/// FoE opcodes (ETG.1000.5 FoE header).
pub mod opcode {
    /// Read request.
    pub const RRQ: u8 = 1;
    /// Write request.
    pub const WRQ: u8 = 2;
    /// Data.
    pub const DATA: u8 = 3;
    /// Acknowledge.
    pub const ACK: u8 = 4;
    /// Error.
    pub const ERR: u8 = 5;
    /// Busy.
    pub const BUSY: u8 = 6;
}

/// FoE error codes (ETG.1000.5; IDX Table 7-155; comms-faults-bootloader.md §1.9).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum FoeError {
    /// 0x8000: not defined.
    NotDefined = 0x8000,
    /// 0x8001: file not found.
    NotFound = 0x8001,
    /// 0x8002: access denied.
    AccessDenied = 0x8002,
    /// 0x8003: disk full.
    DiskFull = 0x8003,
    /// 0x8004: illegal (cannot be done in the present state).
    Illegal = 0x8004,
    /// 0x8005: illegal packet number.
    PacketNumber = 0x8005,
    /// 0x8006: file already exists.
    AlreadyExists = 0x8006,
    /// 0x8007: no user.
    NoUser = 0x8007,
    /// 0x8008: bootstrap only (FoE download only in BOOT).
    BootstrapOnly = 0x8008,
    /// 0x8009: not bootstrap (the file is not valid in BOOT).
    NotBootstrap = 0x8009,
    /// 0x800A: no rights (wrong password).
    NoRights = 0x800A,
    /// 0x800B: program error.
    ProgramError = 0x800B,
    /// 0x800C: wrong checksum.
    Checksum = 0x800C,
    /// 0x800D: firmware does not fit the hardware.
    FirmwareMismatch = 0x800D,
    /// 0x8011: flash problem.
    FlashProblem = 0x8011,
    /// 0x8012: file incompatible.
    FileIncompatible = 0x8012,
}

impl FoeError {
    /// The code on the wire.
    pub const fn code(self) -> u32 {
        self as u32
    }
}

/// What a request asks of a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FoeAccess {
    /// The master downloads the file (write request).
    Write,
    /// The master uploads the file (read request).
    Read,
}

/// How a sink took a block of data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FoeProgress {
    /// Taken.
    Done,
    /// Not taken now (busy, e.g. erasing flash): the master sends the block again. `done` of `entire` tells
    /// the progress (ETG.1000.5 FoE busy).
    Busy {
        /// Work done.
        done: u16,
        /// Work in all.
        entire: u16,
    },
}

/// Where FoE files go: the bootloader issue implements it over the flash slots.
pub trait FoeSink {
    /// A request for file `name` (trailing NULs removed) with `password`.
    fn open(&mut self, name: &[u8], password: u32, access: FoeAccess) -> Result<(), FoeError>;
    /// `data` at `offset` of the file being written.
    fn write(&mut self, offset: u32, data: &[u8]) -> Result<FoeProgress, FoeError>;
    /// The last packet arrived: the file is complete (checks, activation). An error is sent to the master
    /// instead of the last acknowledge.
    fn finish(&mut self) -> Result<(), FoeError>;
    /// The transfer ended early (master error, wrong packet, INIT, a new request): discard what was written.
    fn abort(&mut self) {}
    /// The error text to send with `error` (ETG.1000.5 FoE error request: code, then text), asked once for each
    /// error answer; the default sends none.
    fn error_text(&mut self, error: FoeError) -> &'static [u8] {
        let _ = error;
        &[]
    }
    /// Reads up to `buf.len()` bytes at `offset` of the file being read; returns how many (fewer than asked:
    /// end of file). Sinks without readable files keep the default, which refuses.
    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<usize, FoeError> {
        let _ = (offset, buf);
        Err(FoeError::Illegal)
    }
}

/// A sink without files: every request is answered with 0x8001 (not found). For firmware without a bootloader.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoFoeSink;

impl FoeSink for NoFoeSink {
    fn open(&mut self, _: &[u8], _: u32, _: FoeAccess) -> Result<(), FoeError> {
        Err(FoeError::NotFound)
    }

    fn write(&mut self, _: u32, _: &[u8]) -> Result<FoeProgress, FoeError> {
        Err(FoeError::Illegal)
    }

    fn finish(&mut self) -> Result<(), FoeError> {
        Err(FoeError::Illegal)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Idle,
    /// Waiting for data packet `next` at file offset `offset`.
    Writing {
        next: u32,
        offset: u32,
    },
    /// Data packet `packet` (of `len` bytes from `offset`) sent, waiting for its acknowledge; `last` = it was
    /// the short one.
    Reading {
        packet: u32,
        offset: u32,
        len: usize,
        last: bool,
    },
}

/// Statistics of the FoE service.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FoeStats {
    /// Files written completely (sink finished without error).
    pub files_written: u32,
    /// Bytes handed to the sink.
    pub bytes_written: u32,
    /// Error answers sent.
    pub errors: u32,
}

/// The FoE service. See the module documentation.
#[derive(Clone, Debug)]
pub struct Foe {
    state: State,
    stats: FoeStats,
}

impl Default for Foe {
    fn default() -> Self {
        Self::new()
    }
}

fn header(out: &mut [u8], op: u8, value: u32) -> usize {
    let [v0, v1, v2, v3] = value.to_le_bytes();
    match out.get_mut(..FOE_HEADER_LEN) {
        Some(h) => {
            h.copy_from_slice(&[op, 0, v0, v1, v2, v3]);
            FOE_HEADER_LEN
        }
        None => 0,
    }
}

impl Foe {
    /// An idle service.
    pub const fn new() -> Self {
        Self { state: State::Idle, stats: FoeStats { files_written: 0, bytes_written: 0, errors: 0 } }
    }

    /// Whether a transfer is in progress.
    pub const fn is_busy(&self) -> bool {
        !matches!(self.state, State::Idle)
    }

    /// Statistics.
    pub const fn stats(&self) -> FoeStats {
        self.stats
    }

    /// Ends a transfer in progress (the mailbox stopped): the sink discards it.
    pub fn reset<S: FoeSink + ?Sized>(&mut self, sink: &mut S) {
        if self.is_busy() {
            sink.abort();
        }
        self.state = State::Idle;
    }

    /// Handles the FoE data of one mailbox (`request`, as long as the mailbox header says) in state BOOT
    /// (`boot`) or another, with `capacity` = the request mailbox's data size (a data packet of capacity − 6
    /// bytes is not the last one). Writes the answer into `out`. `Ok(None)`: no answer (the master's error).
    pub fn handle<S: FoeSink + ?Sized>(
        &mut self,
        request: &[u8],
        boot: bool,
        capacity: usize,
        sink: &mut S,
        out: &mut [u8],
    ) -> Result<Option<usize>, MailboxError> {
        if request.len() < FOE_HEADER_LEN {
            return Err(MailboxError::SizeTooShort);
        }
        let op = request.first().copied().unwrap_or(0);
        let value = u32::from_le_bytes([
            request.get(2).copied().unwrap_or(0),
            request.get(3).copied().unwrap_or(0),
            request.get(4).copied().unwrap_or(0),
            request.get(5).copied().unwrap_or(0),
        ]);
        let data = request.get(FOE_HEADER_LEN..).unwrap_or(&[]);
        let answer = match op {
            opcode::WRQ | opcode::RRQ => self.request(op, value, data, boot, sink, out),
            opcode::DATA => self.data(value, data, capacity, sink, out),
            opcode::ACK | opcode::BUSY => self.acknowledged(op, value, sink, out),
            opcode::ERR => {
                self.reset(sink);
                return Ok(None);
            }
            _ => Err(FoeError::Illegal),
        };
        Ok(Some(match answer {
            // The acknowledge of the last packet of a read ends the transfer without an answer.
            Ok(0) => return Ok(None),
            Ok(len) => len,
            Err(error) => {
                self.stats.errors = self.stats.errors.saturating_add(1);
                let len = header(out, opcode::ERR, error.code());
                let text = sink.error_text(error);
                let room = out.len().saturating_sub(len).min(text.len());
                match (out.get_mut(len..len.saturating_add(room)), text.get(..room)) {
                    (Some(dst), Some(src)) => {
                        dst.copy_from_slice(src);
                        len.saturating_add(room)
                    }
                    _ => len,
                }
            }
        }))
    }

    fn request<S: FoeSink + ?Sized>(
        &mut self,
        op: u8,
        password: u32,
        name: &[u8],
        boot: bool,
        sink: &mut S,
        out: &mut [u8],
    ) -> Result<usize, FoeError> {
        // A new request ends the old transfer (the master gave it up).
        self.reset(sink);
        if !boot {
            return Err(FoeError::BootstrapOnly);
        }
        let end = name.iter().rposition(|&b| b != 0).map_or(0, |i| i.saturating_add(1));
        let name = name.get(..end).unwrap_or(&[]);
        if op == opcode::WRQ {
            sink.open(name, password, FoeAccess::Write)?;
            self.state = State::Writing { next: 1, offset: 0 };
            Ok(header(out, opcode::ACK, 0))
        } else {
            sink.open(name, password, FoeAccess::Read)?;
            self.send_data(1, 0, sink, out)
        }
    }

    /// Reads the next block from the sink and sends it as data packet `packet`.
    fn send_data<S: FoeSink + ?Sized>(
        &mut self,
        packet: u32,
        offset: u32,
        sink: &mut S,
        out: &mut [u8],
    ) -> Result<usize, FoeError> {
        let room = out.len().saturating_sub(FOE_HEADER_LEN);
        let buf = out.get_mut(FOE_HEADER_LEN..).unwrap_or(&mut []);
        let len = match sink.read(offset, buf) {
            Ok(len) => len.min(room),
            Err(e) => {
                self.reset(sink);
                return Err(e);
            }
        };
        self.state = State::Reading { packet, offset, len, last: len < room };
        Ok(header(out, opcode::DATA, packet).saturating_add(len))
    }

    fn data<S: FoeSink + ?Sized>(
        &mut self,
        packet: u32,
        data: &[u8],
        capacity: usize,
        sink: &mut S,
        out: &mut [u8],
    ) -> Result<usize, FoeError> {
        let State::Writing { next, offset } = self.state else {
            return Err(FoeError::Illegal);
        };
        if packet != next {
            self.reset(sink);
            return Err(FoeError::PacketNumber);
        }
        match sink.write(offset, data) {
            Ok(FoeProgress::Done) => {}
            Ok(FoeProgress::Busy { done, entire }) => {
                let value = u32::from(done) | (u32::from(entire) << 16);
                return Ok(header(out, opcode::BUSY, value));
            }
            Err(e) => {
                self.reset(sink);
                return Err(e);
            }
        }
        let len = u32::try_from(data.len()).unwrap_or(u32::MAX);
        self.stats.bytes_written = self.stats.bytes_written.saturating_add(len);
        let last = data.len() < capacity.saturating_sub(FOE_HEADER_LEN);
        if last {
            self.state = State::Idle;
            sink.finish()?;
            self.stats.files_written = self.stats.files_written.saturating_add(1);
        } else {
            self.state = State::Writing { next: next.wrapping_add(1), offset: offset.saturating_add(len) };
        }
        Ok(header(out, opcode::ACK, packet))
    }

    /// An acknowledge (or busy) from the master while it reads: the next packet, the same again on busy.
    fn acknowledged<S: FoeSink + ?Sized>(
        &mut self,
        op: u8,
        packet: u32,
        sink: &mut S,
        out: &mut [u8],
    ) -> Result<usize, FoeError> {
        let State::Reading { packet: sent, offset, len, last } = self.state else {
            return Err(FoeError::Illegal);
        };
        if op == opcode::BUSY {
            return self.send_data(sent, offset, sink, out);
        }
        if packet != sent {
            self.reset(sink);
            return Err(FoeError::PacketNumber);
        }
        if last {
            self.state = State::Idle;
            return Ok(0);
        }
        let next_offset = offset.saturating_add(u32::try_from(len).unwrap_or(u32::MAX));
        self.send_data(sent.wrapping_add(1), next_offset, sink, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default)]
    struct Sink {
        data: Vec<u8>,
        finished: bool,
        aborted: bool,
        /// Refuse the end of file with this code and text.
        refuse: Option<(FoeError, &'static [u8])>,
    }

    impl FoeSink for Sink {
        fn open(&mut self, _: &[u8], _: u32, _: FoeAccess) -> Result<(), FoeError> {
            Ok(())
        }
        fn write(&mut self, _: u32, data: &[u8]) -> Result<FoeProgress, FoeError> {
            self.data.extend_from_slice(data);
            Ok(FoeProgress::Done)
        }
        fn finish(&mut self) -> Result<(), FoeError> {
            self.finished = true;
            self.refuse.map_or(Ok(()), |(e, _)| Err(e))
        }
        fn abort(&mut self) {
            self.aborted = true;
        }
        fn error_text(&mut self, error: FoeError) -> &'static [u8] {
            match self.refuse.take() {
                Some((e, text)) if e == error => text,
                _ => b"",
            }
        }
    }

    fn run(foe: &mut Foe, sink: &mut Sink, boot: bool, request: &[u8]) -> Result<Option<Vec<u8>>, MailboxError> {
        let mut out = [0u8; 122];
        foe.handle(request, boot, 122, sink, &mut out).map(|r| r.map(|n| out[..n].to_vec()))
    }

    #[test]
    fn a_write_request_outside_boot_gets_bootstrap_only() {
        let (mut foe, mut sink) = (Foe::new(), Sink::default());
        let answer = run(&mut foe, &mut sink, false, &[2, 0, 0, 0, 0, 0, b'f']);
        assert_eq!(answer, Ok(Some(vec![5, 0, 0x08, 0x80, 0, 0])));
        assert!(!foe.is_busy());
    }

    #[test]
    fn a_short_header_is_a_mailbox_error() {
        let (mut foe, mut sink) = (Foe::new(), Sink::default());
        assert_eq!(run(&mut foe, &mut sink, true, &[2, 0, 0]), Err(MailboxError::SizeTooShort));
    }

    #[test]
    fn a_write_is_acknowledged_packet_by_packet_and_finished_by_a_short_packet() {
        let (mut foe, mut sink) = (Foe::new(), Sink::default());
        assert_eq!(run(&mut foe, &mut sink, true, &[2, 0, 0, 0, 0, 0, b'f']), Ok(Some(vec![4, 0, 0, 0, 0, 0])));
        let mut full = vec![3, 0, 1, 0, 0, 0];
        full.extend_from_slice(&[0xAA; 116]);
        assert_eq!(run(&mut foe, &mut sink, true, &full), Ok(Some(vec![4, 0, 1, 0, 0, 0])));
        assert!(!sink.finished);
        assert_eq!(run(&mut foe, &mut sink, true, &[3, 0, 2, 0, 0, 0, 0xBB]), Ok(Some(vec![4, 0, 2, 0, 0, 0])));
        assert!(sink.finished);
        assert_eq!(sink.data.len(), 117);
        assert!(!foe.is_busy());
    }

    /// ETG.1000.5 FoE error request: the code, then the sink's text for its own refusal (once); the service's own
    /// errors carry none.
    #[test]
    fn a_sink_refusal_carries_its_text() {
        let mut sink = Sink { refuse: Some((FoeError::NotBootstrap, b"why")), ..Sink::default() };
        let mut foe = Foe::new();
        run(&mut foe, &mut sink, true, &[2, 0, 0, 0, 0, 0, b'f']).ok();
        let answer = run(&mut foe, &mut sink, true, &[3, 0, 1, 0, 0, 0, 0xBB]);
        assert_eq!(answer, Ok(Some(vec![5, 0, 0x09, 0x80, 0, 0, b'w', b'h', b'y'])));
        // The next error (a data packet without a transfer: illegal) is the service's own: no text.
        let answer = run(&mut foe, &mut sink, true, &[3, 0, 2, 0, 0, 0, 0xBB]);
        assert_eq!(answer, Ok(Some(vec![5, 0, 0x04, 0x80, 0, 0])));
    }

    #[test]
    fn a_wrong_packet_number_aborts_with_0x8005() {
        let (mut foe, mut sink) = (Foe::new(), Sink::default());
        run(&mut foe, &mut sink, true, &[2, 0, 0, 0, 0, 0, b'f']).ok();
        assert_eq!(run(&mut foe, &mut sink, true, &[3, 0, 3, 0, 0, 0, 1]), Ok(Some(vec![5, 0, 0x05, 0x80, 0, 0])));
        assert!(sink.aborted);
        assert!(!foe.is_busy());
    }
}
