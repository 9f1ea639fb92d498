//! The mailbox on SM0 (master to drive) and SM1 (drive to master): ETG.1000.6 §5.2 ("Mailbox") with the data
//! link rules of ETG.1000.4 (mailbox counter, repeat request), sans-IO over the [`Esc`] trait.
//!
//! Every mailbox starts with a 6-byte header (ETG.1000.6 §5.2.1):
//!
//! ```text
//! length u16 | address u16 | channel (bits 5..0) + priority (bits 7..6) u8 | type (bits 3..0) + counter (bits 6..4) u8
//! ```
//!
//! followed by `length` bytes of the protocol (type 3 CoE: [`super::coe`], type 4 FoE: [`super::foe`]).
//!
//! Rules implemented here:
//! - **reading a request**: SM0's status bit 3 (mailbox full) says a request is there; the whole window is read
//!   so that its last byte is read and the ESC hands SM0 back to the master (ESC datasheet section I,
//!   "SyncManager, mailbox mode"). A request is taken only when the reply queue has room, so a request is
//!   never dropped for lack of memory: it waits in SM0 (the master's next write is refused by the ESC).
//! - **counter** (ETG.1000.6 §5.2.1 "Cnt", ETG.1000.4): the master numbers its requests 1..7 (after 7 comes 1;
//!   0 = the master does not use the counter). A request with the same non-zero counter as the one before is a
//!   retransmission: the master did not see the working counter of its write although the ESC took it. It is
//!   not executed a second time, and not answered a second time either: the answer to the first one is already
//!   on its way (queued or in SM1); a lost answer is recovered with the repeat request below (Beckhoff SSC
//!   `MBX_MailboxWriteInd` and SOES `ESC_mbxprocess` drop the repeated mailbox the same way). The drive numbers
//!   its own mailboxes 1..7 the same way.
//! - **repeat request** (ESC datasheet section I "SyncManager", mailbox repeat; registers 0x0806 and 0x0807
//!   bit 1): when the master lost a reply it already read, it toggles SM1's repeat request; the drive writes the
//!   last reply again (a newer reply still in SM1 is taken back and sent after it, as SOES `ESC_mbxprocess`
//!   does) and then toggles the repeat acknowledge.
//! - **mailbox errors** (ETG.1000.6 §5.2.2, type 0 service 1): a header whose length does not fit the
//!   mailbox gets 0x08 (invalid size), a channel other than 0 gets 0x03, a type the drive does not serve gets
//!   0x02 (in BOOT every type but FoE, as the Beckhoff SSC `MailboxServiceInd` does); the protocols add 0x04,
//!   0x06 and 0x08 for their own headers.
//! - **reply queue**: replies wait in a queue while SM1 is still full; unsolicited messages (SDO information
//!   fragments, emergencies) are produced only when the queue is empty, so they never push a reply out.
//!
//! The mailbox runs from PRE-OP on and in BOOT (ETG.1000.6 §6.4, comms-faults-bootloader.md §1.2); it follows
//! the state it is given in [`MailboxContext::state`] and resets itself (queue, counters, transfers in progress)
//! when the slave goes back to INIT.

use heapless::Deque;

use super::coe::Coe;
use super::esc::{reg, Esc, SmConfig};
use super::esm::{set_sm_deactivated, AlState};
use super::foe::{Foe, FoeSink};
use crate::od::access::{AccessContext, ApplicationObjects, Dictionary};
use crate::od::generated;

/// Length of the mailbox header.
pub const HEADER_LEN: usize = 6;

/// The larger of the drive's two mailboxes: the size of a message buffer.
pub const MAILBOX_CAPACITY: usize = {
    let out_size = generated::MAILBOX_OUT_SIZE as usize;
    let in_size = generated::MAILBOX_IN_SIZE as usize;
    if out_size > in_size {
        out_size
    } else {
        in_size
    }
};

/// Replies that can wait for SM1. One slot is kept free for the reply a repeat request takes back out of SM1.
pub const QUEUE_DEPTH: usize = 4;

/// Mailbox types (ETG.1000.6 §5.2.1).
pub mod kind {
    /// Mailbox error reply (slave to master).
    pub const ERROR: u8 = 0x00;
    /// ADS over EtherCAT.
    pub const AOE: u8 = 0x01;
    /// Ethernet over EtherCAT.
    pub const EOE: u8 = 0x02;
    /// CAN application protocol over EtherCAT.
    pub const COE: u8 = 0x03;
    /// File access over EtherCAT.
    pub const FOE: u8 = 0x04;
    /// Servo profile over EtherCAT.
    pub const SOE: u8 = 0x05;
    /// Vendor specific.
    pub const VOE: u8 = 0x0F;
}

/// Mailbox error codes (ETG.1000.6 §5.2.2), sent in a type-0 mailbox with service 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum MailboxError {
    /// 0x01: syntax of the 6-byte mailbox header is wrong.
    Syntax = 0x01,
    /// 0x02: the mailbox protocol is not supported.
    UnsupportedProtocol = 0x02,
    /// 0x03: the channel field contains a wrong value.
    InvalidChannel = 0x03,
    /// 0x04: the service in the mailbox protocol is not supported.
    ServiceNotSupported = 0x04,
    /// 0x05: the mailbox protocol header is wrong (after the 6-byte header).
    InvalidHeader = 0x05,
    /// 0x06: the length of the received mailbox data is too short.
    SizeTooShort = 0x06,
    /// 0x07: the mailbox protocol cannot be processed because of limited resources.
    NoMoreMemory = 0x07,
    /// 0x08: the length of the data is inconsistent.
    InvalidSize = 0x08,
}

/// The mailbox header (ETG.1000.6 §5.2.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Header {
    /// Length of the data after the header.
    pub length: u16,
    /// Station address of the source or destination (0 in the drive's replies: the master).
    pub address: u16,
    /// Channel (bits 5..0 of byte 4); always 0.
    pub channel: u8,
    /// Priority (bits 7..6 of byte 4).
    pub priority: u8,
    /// Mailbox type ([`kind`]).
    pub kind: u8,
    /// Counter 0..7 (bits 6..4 of byte 5).
    pub counter: u8,
}

impl Header {
    /// Decodes the first 6 bytes of `bytes` (`None` if shorter).
    pub fn parse(bytes: &[u8]) -> Option<Self> {
        let b = bytes.get(..HEADER_LEN)?;
        let g = |i: usize| b.get(i).copied().unwrap_or(0);
        Some(Self {
            length: u16::from_le_bytes([g(0), g(1)]),
            address: u16::from_le_bytes([g(2), g(3)]),
            channel: g(4) & 0x3F,
            priority: g(4) >> 6,
            kind: g(5) & 0x0F,
            counter: (g(5) >> 4) & 0x07,
        })
    }

    /// The 6 header bytes.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let [l0, l1] = self.length.to_le_bytes();
        let [a0, a1] = self.address.to_le_bytes();
        [
            l0,
            l1,
            a0,
            a1,
            (self.channel & 0x3F) | (self.priority << 6),
            (self.kind & 0x0F) | ((self.counter & 0x07) << 4),
        ]
    }
}

/// The next mailbox counter after `counter` (1..7, after 7 comes 1; ETG.1000.6 §5.2.1).
pub const fn next_counter(counter: u8) -> u8 {
    if counter >= 7 {
        1
    } else {
        counter.wrapping_add(1)
    }
}

/// Where the two mailbox sync managers must be (SII words 0x18..0x1B and category SM; ETG.2010).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MailboxLayout {
    /// SM0 (master to drive) physical start.
    pub out_start: u16,
    /// SM0 length.
    pub out_size: u16,
    /// SM1 (drive to master) physical start.
    pub in_start: u16,
    /// SM1 length.
    pub in_size: u16,
}

impl MailboxLayout {
    /// The drive's mailboxes from `firmware/device.toml` (the same values od-gen writes into the SII and ESI,
    /// and `hal_sim::esc::drive_sii_image` carries): 0x1000/128 out, 0x1080/128 in.
    pub const DRIVE: Self = Self {
        out_start: generated::MAILBOX_OUT_START,
        out_size: generated::MAILBOX_OUT_SIZE,
        in_start: generated::MAILBOX_IN_START,
        in_size: generated::MAILBOX_IN_SIZE,
    };

    /// Whether SM0 and SM1 on `esc` are configured as this layout's mailboxes and enabled by the master: SM0
    /// at `out_start`/`out_size` in mailbox mode written by the master, SM1 at `in_start`/`in_size` in mailbox
    /// mode read by the master (the INIT -> PRE-OP check; ETG.1000.6 §6.4, SOES `ESC_checkmbx`). The interrupt
    /// enable bits of the control byte are the master's choice and not checked.
    pub fn matches<E: Esc>(&self, esc: &mut E) -> bool {
        let sm0 = SmConfig::read(esc, 0);
        let sm1 = SmConfig::read(esc, 1);
        let fits = usize::from(self.out_size) <= MAILBOX_CAPACITY
            && usize::from(self.in_size) <= MAILBOX_CAPACITY
            && usize::from(self.out_size) > HEADER_LEN
            && usize::from(self.in_size) > HEADER_LEN;
        fits && sm0.start == self.out_start
            && sm0.length == self.out_size
            && sm0.is_mailbox()
            && sm0.master_writes()
            && sm0.enabled()
            && sm1.start == self.in_start
            && sm1.length == self.in_size
            && sm1.is_mailbox()
            && sm1.control & 0x0C == 0x00
            && sm1.enabled()
    }
}

/// One mailbox message from the drive: header and data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Message {
    bytes: [u8; MAILBOX_CAPACITY],
    len: usize,
}

impl Message {
    /// A message of type `kind` whose data `fill` writes into the buffer it is given (at most `room` bytes) and
    /// whose length it returns.
    fn build(kind: u8, room: usize, fill: impl FnOnce(&mut [u8]) -> usize) -> Self {
        let mut bytes = [0u8; MAILBOX_CAPACITY];
        let end = HEADER_LEN.saturating_add(room).min(MAILBOX_CAPACITY);
        let data_len = match bytes.get_mut(HEADER_LEN..end) {
            Some(data) => fill(data).min(data.len()),
            None => 0,
        };
        let header = Header { length: u16::try_from(data_len).unwrap_or(0), kind, ..Header::default() };
        if let Some(h) = bytes.get_mut(..HEADER_LEN) {
            h.copy_from_slice(&header.encode());
        }
        Self { bytes, len: HEADER_LEN.saturating_add(data_len) }
    }

    /// A mailbox error reply (ETG.1000.6 §5.2.2: type 0, service 0x0001, the code).
    pub fn error(code: MailboxError) -> Self {
        Self::build(kind::ERROR, 4, |d| {
            let [s0, s1] = 0x0001u16.to_le_bytes();
            let [c0, c1] = (code as u16).to_le_bytes();
            for (slot, v) in d.iter_mut().zip([s0, s1, c0, c1]) {
                *slot = v;
            }
            4
        })
    }

    /// The message bytes (header and data).
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or(&[])
    }

    /// The header.
    pub fn header(&self) -> Header {
        Header::parse(&self.bytes).unwrap_or_default()
    }

    fn set_counter(&mut self, counter: u8) {
        if let Some(b) = self.bytes.get_mut(5) {
            *b = (*b & 0x8F) | ((counter & 0x07) << 4);
        }
    }
}

/// Counters of the mailbox (diagnostics and tests).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MailboxStats {
    /// Requests read from SM0.
    pub requests: u32,
    /// Requests dropped as retransmissions (same counter).
    pub duplicates: u32,
    /// Mailbox error replies sent.
    pub errors: u32,
    /// Repeat requests served.
    pub repeats: u32,
    /// Messages written to SM1 (repeats included).
    pub sent: u32,
}

/// Why an emergency was not queued.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmergencyRefused {
    /// The mailbox does not run (INIT) or runs for FoE only (BOOT): no CoE emergencies there.
    NotRunning,
    /// The emergency queue is full; the caller keeps the message and tries again.
    QueueFull,
}

/// What the services behind the mailbox need from the rest of the firmware, for one poll.
pub struct MailboxContext<'a, A: ApplicationObjects + ?Sized, S: FoeSink + ?Sized> {
    /// The ESM state ([`super::esm::Esm::state`]).
    pub state: AlState,
    /// The dictionary the SDO services read and write.
    pub dict: &'a mut Dictionary,
    /// The application objects (store/restore, program data).
    pub app: &'a mut A,
    /// Whether the power stage is enabled (write conditions of the dictionary).
    pub power_stage_enabled: bool,
    /// Where FoE writes go (the bootloader's flash writer).
    pub foe_sink: &'a mut S,
}

/// The mailbox. See the module documentation.
#[derive(Clone, Debug)]
pub struct Mailbox {
    layout: MailboxLayout,
    /// The state the mailbox was started for (`None`: stopped).
    running: Option<AlState>,
    /// Counter of the last request taken (0: none yet, or a master without counters).
    last_counter: u8,
    /// Counter of the last message sent.
    sent_counter: u8,
    queue: Deque<Message, QUEUE_DEPTH>,
    /// The message in SM1 that the master has not read yet.
    posted: Option<Message>,
    /// The last message the master read (sent again on a repeat request).
    backup: Option<Message>,
    /// SM1 repeat acknowledge as last written (0x080F bit 1).
    repeat_ack: bool,
    coe: Coe,
    foe: Foe,
    stats: MailboxStats,
}

impl Default for Mailbox {
    fn default() -> Self {
        Self::new(MailboxLayout::DRIVE)
    }
}

impl Mailbox {
    /// A stopped mailbox for `layout`.
    pub const fn new(layout: MailboxLayout) -> Self {
        Self {
            layout,
            running: None,
            last_counter: 0,
            sent_counter: 0,
            queue: Deque::new(),
            posted: None,
            backup: None,
            repeat_ack: false,
            coe: Coe::new(),
            foe: Foe::new(),
            stats: MailboxStats { requests: 0, duplicates: 0, errors: 0, repeats: 0, sent: 0 },
        }
    }

    /// Counters.
    pub const fn stats(&self) -> MailboxStats {
        self.stats
    }

    /// Whether the mailbox runs.
    pub const fn is_running(&self) -> bool {
        self.running.is_some()
    }

    /// Replies waiting for SM1.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// The CoE service (SDO server state, pending SDO information fragments, emergencies).
    pub const fn coe(&self) -> &Coe {
        &self.coe
    }

    /// The FoE service.
    pub const fn foe(&self) -> &Foe {
        &self.foe
    }

    /// Queues a CoE emergency (ETG.1000.6 §5.6.4; the fault manager's 8-byte EMCY, `FieldbusDevice::poll_emcy`).
    /// It goes out when SM1 and the reply queue are free. Only while the mailbox runs for CoE (PRE-OP, SAFE-OP, OP).
    pub fn send_emergency(&mut self, emcy: &[u8; 8]) -> Result<(), EmergencyRefused> {
        match self.running {
            Some(AlState::PreOp | AlState::SafeOp | AlState::Op) => self.coe.queue_emergency(emcy),
            _ => Err(EmergencyRefused::NotRunning),
        }
    }

    /// Runs the mailbox once: follows the ESM state (start, stop), notes that the master read SM1, serves a
    /// repeat request, takes a request from SM0 and answers it, and writes the next message into SM1.
    pub fn poll<E, A, S>(&mut self, esc: &mut E, ctx: &mut MailboxContext<'_, A, S>)
    where
        E: Esc,
        A: ApplicationObjects + ?Sized,
        S: FoeSink + ?Sized,
    {
        self.follow_state(esc, ctx);
        let Some(state) = self.running else {
            return;
        };
        let mut sm1_full = self.sm_status(esc, 1) & 0x08 != 0;
        if self.posted.is_some() && !sm1_full {
            // The master read the last byte of SM1: the message arrived (or is lost, then it asks to repeat).
            self.backup = self.posted.take();
        }
        if self.serve_repeat(esc) {
            sm1_full = self.sm_status(esc, 1) & 0x08 != 0;
        }
        if self.queue.len() < QUEUE_DEPTH.saturating_sub(1) && self.sm_status(esc, 0) & 0x08 != 0 {
            self.receive(esc, state, ctx);
        }
        if self.posted.is_none() && !sm1_full {
            self.post(esc, state);
        }
    }

    /// Starts or stops the mailbox with the ESM state.
    fn follow_state<E, A, S>(&mut self, esc: &mut E, ctx: &mut MailboxContext<'_, A, S>)
    where
        E: Esc,
        A: ApplicationObjects + ?Sized,
        S: FoeSink + ?Sized,
    {
        let wanted = ctx.state.mailbox_runs();
        let boot = ctx.state == AlState::Boot;
        if let Some(running) = self.running {
            if !wanted || (running == AlState::Boot) != boot {
                self.stop(ctx);
            }
        }
        if self.running.is_none() && wanted {
            self.start(esc, ctx.state);
        } else if let Some(running) = self.running.as_mut() {
            *running = ctx.state;
        }
    }

    /// Starts the mailbox: no repeat request pending (acknowledge = request, SOES `ESC_startmbx`).
    fn start<E: Esc>(&mut self, esc: &mut E, state: AlState) {
        let request = self.read_byte(esc, reg::sm(1, reg::SM_ACTIVATE_OFFSET)) & 0x02 != 0;
        self.repeat_ack = request;
        self.write_repeat_ack(esc);
        self.last_counter = 0;
        self.sent_counter = 0;
        self.running = Some(state);
    }

    /// Stops the mailbox: drops the queue and the messages kept for a repeat, ends CoE and FoE transfers (the
    /// ESM has disabled SM0/SM1, which empties them on the ESC).
    fn stop<A, S>(&mut self, ctx: &mut MailboxContext<'_, A, S>)
    where
        A: ApplicationObjects + ?Sized,
        S: FoeSink + ?Sized,
    {
        self.coe.reset(ctx.dict, ctx.app);
        self.foe.reset(ctx.foe_sink);
        self.queue.clear();
        self.posted = None;
        self.backup = None;
        self.running = None;
    }

    fn read_byte<E: Esc>(&self, esc: &mut E, address: u16) -> u8 {
        let mut b = [0u8; 1];
        esc.read(address, &mut b);
        let [v] = b;
        v
    }

    fn sm_status<E: Esc>(&self, esc: &mut E, n: u8) -> u8 {
        self.read_byte(esc, reg::sm(n, reg::SM_STATUS_OFFSET))
    }

    fn write_repeat_ack<E: Esc>(&self, esc: &mut E) {
        let at = reg::sm(1, reg::SM_PDI_CONTROL_OFFSET);
        let old = self.read_byte(esc, at);
        let new = (old & !0x02) | (u8::from(self.repeat_ack) << 1);
        if new != old {
            esc.write(at, &[new]);
        }
    }

    /// Serves a repeat request (SM1 activate bit 1 differs from the acknowledge): writes the last message the
    /// master read again; a newer message still in SM1 is taken back (SM1 reset through the PDI deactivate
    /// bit) and queued first. Returns whether a request was served.
    fn serve_repeat<E: Esc>(&mut self, esc: &mut E) -> bool {
        let request = self.read_byte(esc, reg::sm(1, reg::SM_ACTIVATE_OFFSET)) & 0x02 != 0;
        if request == self.repeat_ack {
            return false;
        }
        self.stats.repeats = self.stats.repeats.saturating_add(1);
        if let Some(newer) = self.posted.take() {
            set_sm_deactivated(esc, 1, true);
            set_sm_deactivated(esc, 1, false);
            // A slot is always free for this one (requests are taken only below QUEUE_DEPTH - 1).
            let _ = self.queue.push_front(newer);
        }
        if let Some(last) = self.backup.take() {
            self.write_sm1(esc, &last);
            self.posted = Some(last);
        }
        self.repeat_ack = request;
        self.write_repeat_ack(esc);
        true
    }

    /// Reads the request in SM0 and queues its answer.
    fn receive<E, A, S>(&mut self, esc: &mut E, state: AlState, ctx: &mut MailboxContext<'_, A, S>)
    where
        E: Esc,
        A: ApplicationObjects + ?Sized,
        S: FoeSink + ?Sized,
    {
        let mut request = [0u8; MAILBOX_CAPACITY];
        let size = usize::from(self.layout.out_size).min(MAILBOX_CAPACITY);
        let window = request.get_mut(..size).unwrap_or(&mut []);
        // The whole window, so that its last byte is read and SM0 is free again.
        esc.read(self.layout.out_start, window);
        self.stats.requests = self.stats.requests.saturating_add(1);
        if let Some(reply) = self.dispatch(window, state, ctx) {
            if reply.header().kind == super::mailbox::kind::ERROR {
                self.stats.errors = self.stats.errors.saturating_add(1);
            }
            let _ = self.queue.push_back(reply);
        }
    }

    /// Checks the header of `request` (the SM0 window) and hands the data to its protocol. Returns the reply.
    fn dispatch<A, S>(&mut self, request: &[u8], state: AlState, ctx: &mut MailboxContext<'_, A, S>) -> Option<Message>
    where
        A: ApplicationObjects + ?Sized,
        S: FoeSink + ?Sized,
    {
        let Some(header) = Header::parse(request) else {
            return Some(Message::error(MailboxError::Syntax));
        };
        let capacity = request.len().saturating_sub(HEADER_LEN);
        let length = usize::from(header.length);
        if length > capacity {
            return Some(Message::error(MailboxError::InvalidSize));
        }
        if header.counter != 0 && header.counter == self.last_counter {
            self.stats.duplicates = self.stats.duplicates.saturating_add(1);
            return None;
        }
        self.last_counter = header.counter;
        if header.channel != 0 {
            return Some(Message::error(MailboxError::InvalidChannel));
        }
        let data = request.get(HEADER_LEN..HEADER_LEN.saturating_add(length)).unwrap_or(&[]);
        let room = usize::from(self.layout.in_size).min(MAILBOX_CAPACITY).saturating_sub(HEADER_LEN);
        let boot = state == AlState::Boot;
        let mut outcome: Result<Option<usize>, MailboxError> = Ok(None);
        let reply = match header.kind {
            kind::FOE => {
                let foe = &mut self.foe;
                let sink = &mut *ctx.foe_sink;
                Message::build(kind::FOE, room, |out| {
                    outcome = foe.handle(data, boot, capacity, sink, out);
                    outcome.ok().flatten().unwrap_or(0)
                })
            }
            kind::COE if !boot => {
                let access = AccessContext {
                    comm_state: state.comm_state(),
                    power_stage_enabled: ctx.power_stage_enabled,
                    max_pdo_bytes: u16::try_from(generated::MAX_PDO_BYTES_ETHERCAT).unwrap_or(u16::MAX),
                };
                let coe = &mut self.coe;
                let (dict, app) = (&mut *ctx.dict, &mut *ctx.app);
                Message::build(kind::COE, room, |out| {
                    outcome = coe.handle(data, out, dict, access, app);
                    outcome.ok().flatten().unwrap_or(0)
                })
            }
            _ => return Some(Message::error(MailboxError::UnsupportedProtocol)),
        };
        match outcome {
            Ok(Some(_)) => Some(reply),
            Ok(None) => None,
            Err(code) => Some(Message::error(code)),
        }
    }

    /// Writes the next message into SM1: a queued reply, else an unsolicited CoE message.
    fn post<E: Esc>(&mut self, esc: &mut E, state: AlState) {
        let mut message = match self.queue.pop_front() {
            Some(m) => m,
            None if state != AlState::Boot => {
                let room = usize::from(self.layout.in_size).min(MAILBOX_CAPACITY).saturating_sub(HEADER_LEN);
                let coe = &mut self.coe;
                let mut produced = false;
                let m = Message::build(kind::COE, room, |out| match coe.next_message(out) {
                    Some(len) => {
                        produced = true;
                        len
                    }
                    None => 0,
                });
                if !produced {
                    return;
                }
                m
            }
            None => return,
        };
        self.sent_counter = next_counter(self.sent_counter);
        message.set_counter(self.sent_counter);
        self.write_sm1(esc, &message);
        self.posted = Some(message);
    }

    /// Writes `message` into SM1 and completes the buffer (the last byte of the window is written).
    fn write_sm1<E: Esc>(&mut self, esc: &mut E, message: &Message) {
        let bytes = message.as_bytes();
        let size = usize::from(self.layout.in_size);
        esc.write(self.layout.in_start, bytes);
        if bytes.len() < size {
            let last = self.layout.in_start.wrapping_add(self.layout.in_size).wrapping_sub(1);
            esc.write(last, &[0]);
        }
        self.stats.sent = self.stats.sent.saturating_add(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_header_round_trips_with_channel_priority_and_counter() {
        let h = Header { length: 0x1234, address: 0x1001, channel: 0x05, priority: 2, kind: kind::COE, counter: 7 };
        let bytes = h.encode();
        assert_eq!(bytes, [0x34, 0x12, 0x01, 0x10, 0x85, 0x73]);
        assert_eq!(Header::parse(&bytes), Some(h));
        assert_eq!(Header::parse(&bytes[..5]), None);
    }

    #[test]
    fn the_counter_runs_1_to_7_and_skips_0() {
        let mut c = 0;
        let seq: Vec<u8> = (0..9)
            .map(|_| {
                c = next_counter(c);
                c
            })
            .collect();
        assert_eq!(seq, [1, 2, 3, 4, 5, 6, 7, 1, 2]);
    }

    #[test]
    fn a_mailbox_error_is_type_0_service_1_with_the_code() {
        let m = Message::error(MailboxError::InvalidSize);
        assert_eq!(m.as_bytes(), [4, 0, 0, 0, 0, 0, 0x01, 0x00, 0x08, 0x00]);
    }
}
