//! CoE, the CAN application protocol over EtherCAT (ETG.1000.6 §5.6), as the mailbox's type 3.
//!
//! A CoE mailbox's data starts with the 2-byte CoE header: number (bits 8..0, 0 here) and service (bits
//! 15..12; ETG.1000.6 §5.6.1): 1 emergency, 2 SDO request, 3 SDO response, 4..7 PDO services, 8 SDO
//! information. This module serves:
//! - **SDO** (service 2): the shared [`CoeSdoServer`] does the transfer (expedited, normal, segmented, complete
//!   access); this front end checks the sizes the mailbox header gives against the SDO command (the Beckhoff SSC
//!   `SDOS_SdoInd` rules: an upload request and an expedited download are exactly 10 bytes, a normal download
//!   carries no more data than it announces; else mailbox error 0x08; fewer than 10 bytes: 0x06) and wraps the
//!   answer: an SDO response is service 3, an abort goes out as service 2 ("Abort SDO Transfer Request",
//!   ETG.1000.6 §5.6.2.7; SOES `SDO_abort` does the same).
//! - **SDO information** (service 8, ETG.1000.6 §5.6.3): get OD list (list types 0..5), get object description,
//!   get entry description, answered from the dictionary table. An answer longer than the mailbox is sent in
//!   fragments (info header bit 7 "incomplete" and "fragments left"), one per SM1 buffer, after the first one
//!   when SM1 is free again. A failure is an SDO information error request (opcode 7) with the abort code.
//! - **emergencies** (service 1, ETG.1000.6 §5.6.4): [`Coe::queue_emergency`] keeps the 8-byte EMCY (error code,
//!   error register, 5 bytes) until the mailbox can send it.
//!
//! Any other service is answered with mailbox error 0x04 (service not supported, ETG.1000.6).

use heapless::Deque;

use super::mailbox::{EmergencyRefused, MailboxError};
use crate::comm::sdo::coe::{CoeSdoServer, SDO_HEADER_LEN};
use crate::od::abort::SdoAbort;
use crate::od::access::{AccessContext, ApplicationObjects, Dictionary, Table};
use crate::od::entry::{Entry, Object, ObjectCode, Storage, WriteCondition};

/// Length of the CoE header.
pub const COE_HEADER_LEN: usize = 2;
/// Length of the SDO information header (opcode + incomplete, reserved, fragments left).
pub const INFO_HEADER_LEN: usize = 4;
/// Emergencies that can wait for the mailbox.
pub const EMERGENCY_QUEUE: usize = 8;
/// Room for an object or entry description (header fields and the longest name, with margin).
const DESCRIPTION_BYTES: usize = 128;
/// Offset of the SDO information data (after the CoE and SDO information headers).
const INFO_DATA: usize = COE_HEADER_LEN + INFO_HEADER_LEN;

/// CoE services (ETG.1000.6 §5.6.1).
pub mod service {
    /// Emergency.
    pub const EMERGENCY: u8 = 1;
    /// SDO request (also the abort, from either side).
    pub const SDO_REQUEST: u8 = 2;
    /// SDO response.
    pub const SDO_RESPONSE: u8 = 3;
    /// SDO information.
    pub const SDO_INFO: u8 = 8;
}

/// SDO information opcodes (ETG.1000.6 §5.6.3.2).
pub mod info_opcode {
    /// Get OD list request.
    pub const OD_LIST_REQUEST: u8 = 1;
    /// Get OD list response.
    pub const OD_LIST_RESPONSE: u8 = 2;
    /// Get object description request.
    pub const OD_REQUEST: u8 = 3;
    /// Get object description response.
    pub const OD_RESPONSE: u8 = 4;
    /// Get entry description request.
    pub const ED_REQUEST: u8 = 5;
    /// Get entry description response.
    pub const ED_RESPONSE: u8 = 6;
    /// SDO information error request.
    pub const ERROR: u8 = 7;
}

/// The OD list types of "get OD list" (ETG.1000.6 §5.6.3.3).
pub mod list_type {
    /// The number of objects in each of the lists 1..5.
    pub const LENGTHS: u16 = 0;
    /// All objects.
    pub const ALL: u16 = 1;
    /// Objects with an entry mappable into an RxPDO.
    pub const RX_PDO: u16 = 2;
    /// Objects with an entry mappable into a TxPDO.
    pub const TX_PDO: u16 = 3;
    /// Objects stored for a device replacement (backup).
    pub const BACKUP: u16 = 4;
    /// Objects usable as start-up parameters (settings).
    pub const SETTINGS: u16 = 5;
}

/// The CoE header for `service` (number 0).
fn coe_header(service: u8) -> [u8; 2] {
    (u16::from(service) << 12).to_le_bytes()
}

fn put(out: &mut [u8], at: usize, bytes: &[u8]) -> bool {
    match out.get_mut(at..at.saturating_add(bytes.len())) {
        Some(slot) => {
            slot.copy_from_slice(bytes);
            true
        }
        None => false,
    }
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b.get(at).copied().unwrap_or(0), b.get(at.saturating_add(1)).copied().unwrap_or(0)])
}

/// Whether `object` belongs to OD list `list`.
fn in_list(table: &Table, object: &Object, list: u16) -> bool {
    let entries = table.entries_of(object.index);
    match list {
        list_type::ALL => true,
        list_type::RX_PDO => entries.iter().any(|e| e.pdo().rx()),
        list_type::TX_PDO => entries.iter().any(|e| e.pdo().tx()),
        list_type::BACKUP => entries.iter().any(|e| e.persistent()),
        list_type::SETTINGS => entries.iter().any(|e| e.persistent() && e.access().writable()),
        _ => false,
    }
}

fn list_len(table: &Table, list: u16) -> u16 {
    let n = table.objects().iter().filter(|o| in_list(table, o, list)).count();
    u16::try_from(n).unwrap_or(u16::MAX)
}

/// The data type an object description names: the value's type for a VAR, the elements' type for an ARRAY
/// (sub-index 1), 0 for a RECORD (no structure types are defined; SOES answers 0 as well).
fn object_data_type(table: &Table, object: &Object) -> u16 {
    let entries = table.entries_of(object.index);
    match object.object_code {
        ObjectCode::Var => entries.first().map_or(0, |e| e.data_type.code()),
        ObjectCode::Array => entries.iter().find(|e| e.sub == 1).or(entries.first()).map_or(0, |e| e.data_type.code()),
        ObjectCode::Record => 0,
    }
}

/// The object access word of an entry description (ETG.1000.6 §5.6.3.6): bits 0..2 readable in
/// PRE-OP/SAFE-OP/OP, bits 3..5 writable in PRE-OP/SAFE-OP/OP, bit 6 RxPDO mappable, bit 7 TxPDO mappable,
/// bit 8 backup, bit 9 settings.
fn object_access(entry: &Entry) -> u16 {
    let mut access = 0u16;
    if entry.access().readable() {
        access |= 0x0007;
    }
    let writable = entry.access().writable() && !matches!(entry.storage, Storage::Const(_));
    if writable {
        access |= match entry.write_condition() {
            WriteCondition::Always | WriteCondition::PowerDisabled => 0x0038,
            WriteCondition::PreOperational | WriteCondition::PreOperationalPowerDisabled => 0x0008,
        };
    }
    if entry.pdo().rx() {
        access |= 0x0040;
    }
    if entry.pdo().tx() {
        access |= 0x0080;
    }
    if entry.persistent() {
        access |= 0x0100;
        if writable {
            access |= 0x0200;
        }
    }
    access
}

/// The bit length of an entry description: the type's size, a string's capacity, 0 for application data.
fn bit_length(entry: &Entry) -> u16 {
    if let Some(bits) = entry.bit_size() {
        return bits;
    }
    let bytes = match entry.storage {
        Storage::Ram { len, .. } => usize::from(len),
        Storage::Const(value) => value.bytes().len(),
        Storage::Application => 0,
    };
    u16::try_from(bytes.saturating_mul(8)).unwrap_or(u16::MAX)
}

/// The body of an SDO information answer that may need fragments.
#[derive(Clone, Debug)]
enum InfoBody {
    /// An OD list: the list type, then the indices of its objects from position `cursor` of the table on.
    List { table: Table, list: u16, cursor: usize },
    /// A description, built whole.
    Bytes { buf: [u8; DESCRIPTION_BYTES], len: usize },
}

/// An SDO information answer in fragments.
#[derive(Clone, Debug)]
struct InfoAnswer {
    opcode: u8,
    body: InfoBody,
    /// Body bytes already sent.
    sent: usize,
    /// Body bytes in all.
    total: usize,
    /// Fragments after the next one.
    fragments_left: u16,
    /// Body bytes per fragment (even, so that an index never splits).
    chunk: usize,
}

impl InfoAnswer {
    fn new(opcode: u8, body: InfoBody, total: usize, room: usize) -> Self {
        let chunk = room.saturating_sub(INFO_DATA) & !1;
        let fragments = if chunk == 0 { 1 } else { total.div_ceil(chunk).max(1) };
        let fragments_left = u16::try_from(fragments.saturating_sub(1)).unwrap_or(u16::MAX);
        Self { opcode, body, sent: 0, total, fragments_left, chunk }
    }

    /// Writes the next fragment into `out`; returns its length and whether more follow.
    fn fragment(&mut self, out: &mut [u8]) -> (usize, bool) {
        let more = self.fragments_left > 0;
        let [f0, f1] = self.fragments_left.to_le_bytes();
        let [s0, s1] = coe_header(service::SDO_INFO);
        let head = [s0, s1, self.opcode | (u8::from(more) << 7), 0, f0, f1];
        put(out, 0, &head);
        let start = INFO_DATA;
        let want = self.total.saturating_sub(self.sent).min(self.chunk);
        let mut written = 0usize;
        match &mut self.body {
            InfoBody::List { table, list, cursor } => {
                if self.sent == 0 && want >= 2 {
                    put(out, start, &list.to_le_bytes());
                    written = 2;
                }
                let objects = table.objects();
                while written.saturating_add(2) <= want {
                    let Some(object) = objects.get(*cursor) else { break };
                    *cursor = cursor.saturating_add(1);
                    if in_list(table, object, *list) {
                        put(out, start.saturating_add(written), &object.index.to_le_bytes());
                        written = written.saturating_add(2);
                    }
                }
            }
            InfoBody::Bytes { buf, len } => {
                let end = self.sent.saturating_add(want).min(*len);
                let part = buf.get(self.sent..end).unwrap_or(&[]);
                put(out, start, part);
                written = part.len();
            }
        }
        self.sent = self.sent.saturating_add(written);
        self.fragments_left = self.fragments_left.saturating_sub(1);
        (start.saturating_add(written), more)
    }
}

/// The SDO information error request (opcode 7) with `abort`.
fn info_error(out: &mut [u8], abort: SdoAbort) -> usize {
    let [s0, s1] = coe_header(service::SDO_INFO);
    let [a0, a1, a2, a3] = abort.code().to_le_bytes();
    if put(out, 0, &[s0, s1, info_opcode::ERROR, 0, 0, 0, a0, a1, a2, a3]) {
        10
    } else {
        0
    }
}

/// The CoE service: SDO server, SDO information and emergencies. See the module documentation.
#[derive(Clone, Debug)]
pub struct Coe {
    sdo: CoeSdoServer,
    info: Option<InfoAnswer>,
    emergencies: Deque<[u8; 8], EMERGENCY_QUEUE>,
}

impl Default for Coe {
    fn default() -> Self {
        Self::new()
    }
}

impl Coe {
    /// An idle CoE service.
    pub const fn new() -> Self {
        Self { sdo: CoeSdoServer::new(), info: None, emergencies: Deque::new() }
    }

    /// Whether an SDO segmented transfer is in progress.
    pub const fn sdo_busy(&self) -> bool {
        self.sdo.is_busy()
    }

    /// Whether SDO information fragments wait to be sent.
    pub const fn info_pending(&self) -> bool {
        self.info.is_some()
    }

    /// Emergencies waiting to be sent.
    pub fn emergencies_queued(&self) -> usize {
        self.emergencies.len()
    }

    /// Queues an emergency (service 1) until the mailbox can send it.
    pub fn queue_emergency(&mut self, emcy: &[u8; 8]) -> Result<(), EmergencyRefused> {
        self.emergencies.push_back(*emcy).map_err(|_| EmergencyRefused::QueueFull)
    }

    /// Ends everything in progress (mailbox stopped): the SDO transfer (nothing stored), pending fragments and
    /// emergencies.
    pub fn reset<A: ApplicationObjects + ?Sized>(&mut self, dict: &mut Dictionary, app: &mut A) {
        self.sdo.cancel(dict, app);
        self.info = None;
        self.emergencies.clear();
    }

    /// Handles the CoE data of one mailbox (`request`: from the CoE header on, as long as the mailbox header
    /// says) and writes the answer's CoE data into `out` (the room of the answering mailbox). `Ok(Some(len))`:
    /// an answer of `len` bytes; `Ok(None)`: no answer (the master's SDO abort); `Err`: a mailbox error.
    pub fn handle<A: ApplicationObjects + ?Sized>(
        &mut self,
        request: &[u8],
        out: &mut [u8],
        dict: &mut Dictionary,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<Option<usize>, MailboxError> {
        if request.len() < COE_HEADER_LEN {
            return Err(MailboxError::SizeTooShort);
        }
        let service = (u16_at(request, 0) >> 12) as u8;
        match service {
            service::SDO_REQUEST => self.sdo_request(request, out, dict, ctx, app),
            service::SDO_INFO => {
                self.info = None;
                self.info_request(request, out, dict.table())
            }
            _ => Err(MailboxError::ServiceNotSupported),
        }
    }

    /// The next unsolicited message (an SDO information fragment, else an emergency) into `out`; its length.
    pub fn next_message(&mut self, out: &mut [u8]) -> Option<usize> {
        if let Some(info) = self.info.as_mut() {
            let (len, more) = info.fragment(out);
            if !more {
                self.info = None;
            }
            return Some(len);
        }
        let emcy = self.emergencies.pop_front()?;
        let [s0, s1] = coe_header(service::EMERGENCY);
        put(out, 0, &[s0, s1]);
        put(out, COE_HEADER_LEN, &emcy);
        Some(COE_HEADER_LEN.saturating_add(emcy.len()))
    }

    fn sdo_request<A: ApplicationObjects + ?Sized>(
        &mut self,
        request: &[u8],
        out: &mut [u8],
        dict: &mut Dictionary,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<Option<usize>, MailboxError> {
        let sdo = request.get(COE_HEADER_LEN..).unwrap_or(&[]);
        if sdo.len() < SDO_HEADER_LEN {
            return Err(MailboxError::SizeTooShort);
        }
        let command = sdo.first().copied().unwrap_or(0);
        let exact = sdo.len() == SDO_HEADER_LEN;
        match command >> 5 {
            // Upload initiate and upload segment requests carry nothing after the SDO header.
            2 | 3 if !exact => return Err(MailboxError::InvalidSize),
            1 => {
                let expedited = command & 0x02 != 0;
                let size_indicated = command & 0x01 != 0;
                if expedited && !exact {
                    return Err(MailboxError::InvalidSize);
                }
                let announced = u32::from_le_bytes([
                    sdo.get(4).copied().unwrap_or(0),
                    sdo.get(5).copied().unwrap_or(0),
                    sdo.get(6).copied().unwrap_or(0),
                    sdo.get(7).copied().unwrap_or(0),
                ]);
                let carried = sdo.len().saturating_sub(SDO_HEADER_LEN);
                let announced = usize::try_from(announced).unwrap_or(usize::MAX);
                if !expedited && size_indicated && carried > announced {
                    return Err(MailboxError::InvalidSize);
                }
            }
            _ => {}
        }
        let room = out.get_mut(COE_HEADER_LEN..).unwrap_or(&mut []);
        let len = self.sdo.handle(sdo, room, dict, ctx, app);
        if len == 0 {
            return Ok(None);
        }
        let abort = out.get(COE_HEADER_LEN).copied() == Some(0x80);
        let service = if abort { service::SDO_REQUEST } else { service::SDO_RESPONSE };
        put(out, 0, &coe_header(service));
        Ok(Some(COE_HEADER_LEN.saturating_add(len)))
    }

    fn info_request(&mut self, request: &[u8], out: &mut [u8], table: &Table) -> Result<Option<usize>, MailboxError> {
        let start = INFO_DATA;
        if request.len() < start {
            return Err(MailboxError::SizeTooShort);
        }
        let opcode = request.get(COE_HEADER_LEN).copied().unwrap_or(0) & 0x7F;
        let needed = match opcode {
            info_opcode::OD_LIST_REQUEST | info_opcode::OD_REQUEST => INFO_DATA + 2,
            info_opcode::ED_REQUEST => INFO_DATA + 4,
            _ => start,
        };
        if request.len() < needed {
            return Err(MailboxError::SizeTooShort);
        }
        let room = out.len();
        let answer = match opcode {
            info_opcode::OD_LIST_REQUEST => Self::od_list(table, u16_at(request, start), room),
            info_opcode::OD_REQUEST => Self::object_description(table, u16_at(request, start), room),
            info_opcode::ED_REQUEST => {
                let index = u16_at(request, start);
                let sub = request.get(INFO_DATA + 2).copied().unwrap_or(0);
                Self::entry_description(table, index, sub, room)
            }
            _ => Err(SdoAbort::CommandSpecifier),
        };
        match answer {
            Ok(mut answer) => {
                let (len, more) = answer.fragment(out);
                if more {
                    self.info = Some(answer);
                }
                Ok(Some(len))
            }
            Err(abort) => Ok(Some(info_error(out, abort))),
        }
    }

    /// Get OD list (ETG.1000.6 §5.6.3.3): list type 0 gives the lengths of lists 1..5, the others the indices.
    fn od_list(table: &Table, list: u16, room: usize) -> Result<InfoAnswer, SdoAbort> {
        if list == list_type::LENGTHS {
            let mut buf = [0u8; DESCRIPTION_BYTES];
            put(&mut buf, 0, &list.to_le_bytes());
            for (k, l) in (list_type::ALL..=list_type::SETTINGS).enumerate() {
                put(&mut buf, 2usize.saturating_add(k.saturating_mul(2)), &list_len(table, l).to_le_bytes());
            }
            return Ok(InfoAnswer::new(info_opcode::OD_LIST_RESPONSE, InfoBody::Bytes { buf, len: 12 }, 12, room));
        }
        if list > list_type::SETTINGS {
            return Err(SdoAbort::UnsupportedAccess);
        }
        let total = 2usize.saturating_add(usize::from(list_len(table, list)).saturating_mul(2));
        Ok(InfoAnswer::new(
            info_opcode::OD_LIST_RESPONSE,
            InfoBody::List { table: *table, list, cursor: 0 },
            total,
            room,
        ))
    }

    /// Get object description (ETG.1000.6 §5.6.3.5): index, data type, max sub-index, object code, name.
    fn object_description(table: &Table, index: u16, room: usize) -> Result<InfoAnswer, SdoAbort> {
        let object = table.object(index).ok_or(SdoAbort::ObjectDoesNotExist)?;
        let mut buf = [0u8; DESCRIPTION_BYTES];
        put(&mut buf, 0, &index.to_le_bytes());
        put(&mut buf, 2, &object_data_type(table, object).to_le_bytes());
        put(&mut buf, 4, &[object.max_sub, object.object_code.code()]);
        let name = object.name.as_str().as_bytes();
        let name = name.get(..name.len().min(DESCRIPTION_BYTES - 6)).unwrap_or(&[]);
        put(&mut buf, 6, name);
        let len = 6usize.saturating_add(name.len());
        Ok(InfoAnswer::new(info_opcode::OD_RESPONSE, InfoBody::Bytes { buf, len }, len, room))
    }

    /// Get entry description (ETG.1000.6 §5.6.3.6): index, sub-index, value info (0: no unit, default, minimum
    /// or maximum follow, as the Beckhoff SSC answers), data type, bit length, object access, name.
    fn entry_description(table: &Table, index: u16, sub: u8, room: usize) -> Result<InfoAnswer, SdoAbort> {
        let entry = table.find(index, sub)?;
        let mut buf = [0u8; DESCRIPTION_BYTES];
        put(&mut buf, 0, &index.to_le_bytes());
        put(&mut buf, 2, &[sub, 0]);
        put(&mut buf, 4, &entry.data_type.code().to_le_bytes());
        put(&mut buf, 6, &bit_length(entry).to_le_bytes());
        put(&mut buf, 8, &object_access(entry).to_le_bytes());
        let name = entry.name.as_str().as_bytes();
        let name = name.get(..name.len().min(DESCRIPTION_BYTES - 10)).unwrap_or(&[]);
        put(&mut buf, 10, name);
        let len = 10usize.saturating_add(name.len());
        Ok(InfoAnswer::new(info_opcode::ED_RESPONSE, InfoBody::Bytes { buf, len }, len, room))
    }
}
