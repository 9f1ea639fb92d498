//! The SDO part of CoE (CAN application protocol over EtherCAT, ETG.1000.6 §5.6.2): the same command byte and
//! multiplexer as the CAN SDO (CiA 301 §7.2.4.3), carried in a mailbox, so that a transfer can move far more
//! than seven bytes at a time:
//!
//! - expedited download/upload: up to 4 bytes in the initiate frame, as on CAN;
//! - normal download/upload: the initiate frame carries the size (bytes 4..7) *and* the data after it, as much
//!   as the mailbox holds (SOEM and ethercrab read a 23-byte string this way, `fieldbus-real-masters.md` item 6);
//! - segmented: what does not fit follows in upload/download segments of one command byte plus up to
//!   mailbox size − 9 bytes (6 mailbox header + 2 CoE header + 1 command byte; ETG.1000.6 §5.6.2.3 and
//!   §5.6.2.6, "seg data size" = 7 − n when fewer than 7 bytes, else the mailbox length says how many);
//! - complete access (ETG.1000.6 §5.6.2.1.1, bit 4 of the initiate command byte): the whole ARRAY or RECORD
//!   in one transfer, sub-index 0 (when the request names sub-index 0) as its UNSIGNED8 value padded to 16 bits
//!   (ETG.1020 §12.2 "SDO Complete Access"; SOES `complete_access_subindex_loop` does the same), then every
//!   sub-index's value packed in sub-index order (BOOLEAN as one bit, as the ESI declares it). Objects with
//!   strings or domains abort with 0x0601_0004.
//!
//! [`CoeSdoServer::handle`] works on the SDO part of a CoE mailbox (from the command byte on): the EtherCAT
//! front end strips the mailbox and CoE headers of the request and passes `out` sized to the room in its answer
//! (mailbox size − 8), so this module knows nothing of mailboxes, sync managers or the EtherCAT state machine.
//! Block transfers do not exist in CoE. The rule for a new initiate during a transfer is in the
//! [module docs](super).

use super::transfer::{expedited_data, read_start, SegmentedDownload, SegmentedUpload};
use crate::od::abort::SdoAbort;
use crate::od::access::{AccessContext, ApplicationObjects, Dictionary};
use crate::od::entry::{DataType, Entry, ObjectCode, Storage};
use crate::od::pdo_map;

/// Length of the SDO header in an initiate or abort frame: command, index, sub-index, 4 bytes of data or size
/// (ETG.1000.6 §5.6.2.1.1). Every response is at least this long (the mailbox minimum of 10 bytes with the CoE
/// header).
pub const SDO_HEADER_LEN: usize = 8;

/// Capacity of the complete-access image (the packed object for complete access): larger objects abort with
/// 0x0504_0005 (out of memory).
pub const COMPLETE_ACCESS_MAX: usize = 256;

/// Complete-access flag in the initiate command byte (ETG.1000.6 §5.6.2.1.1).
const COMPLETE_ACCESS: u8 = 0x10;

#[derive(Clone, Debug)]
enum State {
    Idle,
    Download(SegmentedDownload),
    Upload(SegmentedUpload),
    /// A complete-access download collecting its data in the image.
    CaDownload {
        first_sub: u8,
        size: usize,
        received: usize,
        toggle: bool,
    },
    /// A complete-access upload sending the image.
    CaUpload {
        len: usize,
        offset: usize,
        toggle: bool,
    },
}

/// The CoE SDO server (ETG.1000.6 §5.6.2), sans-IO, on the same dictionary calls as the CAN server.
#[derive(Clone, Debug)]
pub struct CoeSdoServer {
    state: State,
    mux: (u16, u8),
    image: [u8; COMPLETE_ACCESS_MAX],
}

impl Default for CoeSdoServer {
    fn default() -> Self {
        Self::new()
    }
}

/// Writes the 8-byte header `command, index, sub, data4` into `out`.
fn put_header(out: &mut [u8], command: u8, index: u16, sub: u8, data4: [u8; 4]) -> usize {
    let [lo, hi] = index.to_le_bytes();
    let header = [command, lo, hi, sub, data4[0], data4[1], data4[2], data4[3]];
    match out.get_mut(..SDO_HEADER_LEN) {
        Some(head) => {
            head.copy_from_slice(&header);
            SDO_HEADER_LEN
        }
        None => 0,
    }
}

/// The abort message for `abort` on `index:sub` (ETG.1000.6 §5.6.2.7: command 0x80, multiplexer, code).
pub fn abort_message(out: &mut [u8], index: u16, sub: u8, abort: SdoAbort) -> usize {
    put_header(out, 0x80, index, sub, abort.code().to_le_bytes())
}

fn byte(request: &[u8], at: usize) -> u8 {
    request.get(at).copied().unwrap_or(0)
}

fn u32_at_4(request: &[u8]) -> u32 {
    u32::from_le_bytes([byte(request, 4), byte(request, 5), byte(request, 6), byte(request, 7)])
}

/// Writes a segment response (ETG.1000.6 §5.6.2.6): command `0x00 | t | c`, with n = 7 − len and padding to 8
/// bytes when fewer than 7 bytes follow. `data` is already in `out[1..]`; returns the message length.
fn finish_segment(out: &mut [u8], toggle: bool, len: usize, last: bool) -> usize {
    let mut command = (u8::from(toggle) << 4) | u8::from(last);
    let total = if len < 7 {
        let n = u8::try_from(7usize.saturating_sub(len)).unwrap_or(0);
        command |= n << 1;
        if let Some(pad) = out.get_mut(len.saturating_add(1)..SDO_HEADER_LEN) {
            pad.fill(0);
        }
        SDO_HEADER_LEN
    } else {
        len.saturating_add(1)
    };
    if let Some(first) = out.first_mut() {
        *first = command;
    }
    total
}

/// The size of an entry in the complete-access stream, in bits: sub-index 0 of an ARRAY/RECORD is 16 (the U8
/// value plus padding, ETG.1020 §12.2), BOOLEAN 1, other fixed-size types their size; strings and domains cannot
/// be accessed completely (0x0601_0004).
fn ca_bits(object_code: ObjectCode, entry: &Entry) -> Result<usize, SdoAbort> {
    if entry.sub == 0 && object_code != ObjectCode::Var {
        return Ok(16);
    }
    match entry.data_type {
        DataType::Boolean => Ok(1),
        other => other.fixed_size().map(|size| size.saturating_mul(8)).ok_or(SdoAbort::CompleteAccessUnsupported),
    }
}

/// Copies `bits` bits from `from` (starting at bit 0) into `to` at bit position `at` (little-endian bit order).
fn put_bits(to: &mut [u8], at: usize, from: &[u8], bits: usize) -> Result<(), SdoAbort> {
    for i in 0..bits {
        let bit = from.get(i / 8).is_some_and(|b| (b >> (i % 8)) & 1 != 0);
        let pos = at.saturating_add(i);
        let slot = to.get_mut(pos / 8).ok_or(SdoAbort::OutOfMemory)?;
        let mask = 1u8 << (pos % 8);
        if bit {
            *slot |= mask;
        } else {
            *slot &= !mask;
        }
    }
    Ok(())
}

/// Copies `bits` bits from `from` at bit position `at` into `to` (from bit 0).
fn get_bits(from: &[u8], at: usize, to: &mut [u8], bits: usize) {
    to.fill(0);
    for i in 0..bits {
        let pos = at.saturating_add(i);
        let bit = from.get(pos / 8).is_some_and(|b| (b >> (pos % 8)) & 1 != 0);
        if let Some(slot) = to.get_mut(i / 8) {
            if bit {
                *slot |= 1 << (i % 8);
            }
        }
    }
}

/// The entries of `index` that a complete access starting at `first_sub` covers, with the object code.
fn ca_entries<const N: usize>(
    dict: &Dictionary<N>,
    index: u16,
    first_sub: u8,
) -> Result<(ObjectCode, &'static [Entry]), SdoAbort> {
    let object = dict.object(index).ok_or(SdoAbort::ObjectDoesNotExist)?;
    if first_sub > 1 {
        return Err(SdoAbort::CompleteAccessUnsupported);
    }
    let all = dict.table().entries_of(index);
    let start = all.partition_point(|e| e.sub < first_sub);
    let entries = all.get(start..).unwrap_or(&[]);
    if entries.is_empty() {
        return Err(SdoAbort::SubindexDoesNotExist);
    }
    for entry in entries {
        ca_bits(object.object_code, entry)?;
    }
    Ok((object.object_code, entries))
}

/// Packs the object `index` from `first_sub` on into `image` (complete-access read); returns its length in
/// bytes. Write-only entries read as 0.
fn ca_read<const N: usize, A: ApplicationObjects + ?Sized>(
    dict: &Dictionary<N>,
    app: &mut A,
    index: u16,
    first_sub: u8,
    image: &mut [u8],
) -> Result<usize, SdoAbort> {
    let (code, entries) = ca_entries(dict, index, first_sub)?;
    image.fill(0);
    let mut bit = 0usize;
    for entry in entries {
        let bits = ca_bits(code, entry)?;
        let mut value = [0u8; 8];
        if entry.access().readable() {
            let size = entry.data_type.fixed_size().unwrap_or(0);
            let part = value.get_mut(..size).ok_or(SdoAbort::InternalIncompatibility)?;
            dict.read_entry(entry, 0, part, app)?;
        }
        put_bits(image, bit, &value, bits)?;
        bit = bit.saturating_add(bits);
    }
    Ok(bit.div_ceil(8))
}

/// The value of `entry` at bit `at` of a complete-access image, as the bytes a write takes.
fn ca_value(entry: &Entry, image: &[u8], at: usize, bits: usize) -> ([u8; 8], usize) {
    let mut value = [0u8; 8];
    get_bits(image, at, &mut value, bits);
    (value, entry.data_type.fixed_size().unwrap_or(0))
}

/// Whether `entry` takes part in a complete-access write (read-only and constant entries are skipped, as their
/// bytes only keep the layout).
fn ca_writable(entry: &Entry) -> bool {
    entry.access().writable() && !matches!(entry.storage, Storage::Const(_))
}

/// Writes the entries of `index` from `first_sub` on that `data` covers (complete-access write). PDO mapping and
/// assignment objects follow their procedure (CiA 301 §7.5.2.36; ETG.1000.6 0x1C12/0x1C13; IDX L2196-L2216):
/// sub-index 0 is set to 0 first, the entries are written, and sub-index 0 gets its new value last, so the
/// dictionary's checks see the same sequence a master would send one by one. When a write fails, the entries
/// already written are put back from a snapshot taken before (best effort) and the first failure is returned.
fn ca_write<const N: usize, A: ApplicationObjects + ?Sized>(
    dict: &mut Dictionary<N>,
    app: &mut A,
    ctx: AccessContext,
    index: u16,
    first_sub: u8,
    data: &[u8],
) -> Result<(), SdoAbort> {
    let (code, entries) = ca_entries(dict, index, first_sub)?;
    // Which entries the data covers: whole entries only.
    let available = data.len().saturating_mul(8);
    let mut covered = 0usize;
    let mut end_bits = 0usize;
    let mut full_bits = 0usize;
    for entry in entries {
        let bits = ca_bits(code, entry)?;
        full_bits = full_bits.saturating_add(bits);
        if full_bits <= available {
            covered = covered.saturating_add(1);
            end_bits = full_bits;
        }
    }
    if data.len() > full_bits.div_ceil(8) {
        return Err(SdoAbort::LengthTooHigh);
    }
    if data.len() != end_bits.div_ceil(8) || covered == 0 {
        return Err(SdoAbort::LengthTooLow);
    }
    let entries = entries.get(..covered).unwrap_or(&[]);
    if !entries.iter().any(ca_writable) {
        return Err(SdoAbort::ReadOnly);
    }
    let mut snapshot = [0u8; COMPLETE_ACCESS_MAX];
    ca_read(dict, app, index, first_sub, &mut snapshot)?;
    let pdo_rule = pdo_map::mapping_direction(index).is_some() || pdo_map::assignment_direction(index).is_some();
    let result = ca_apply(dict, app, ctx, code, entries, data, pdo_rule);
    if result.is_err() {
        // Put back what was there (the snapshot was valid, so these writes pass the same checks).
        let _ = ca_apply(dict, app, ctx, code, entries, &snapshot, pdo_rule);
    }
    result
}

/// The writes of a complete-access download of `entries` from `image`.
fn ca_apply<const N: usize, A: ApplicationObjects + ?Sized>(
    dict: &mut Dictionary<N>,
    app: &mut A,
    ctx: AccessContext,
    code: ObjectCode,
    entries: &'static [Entry],
    image: &[u8],
    pdo_rule: bool,
) -> Result<(), SdoAbort> {
    let zero_first = pdo_rule && entries.first().is_some_and(|e| e.sub == 0 && ca_writable(e));
    if zero_first {
        if let Some(sub0) = entries.first() {
            dict.write_entry(sub0, &[0], ctx, app)?;
        }
    }
    let mut bit = 0usize;
    let mut sub0_value = None;
    for entry in entries {
        let bits = ca_bits(code, entry)?;
        if ca_writable(entry) {
            let (value, size) = ca_value(entry, image, bit, bits);
            let bytes = value.get(..size).ok_or(SdoAbort::InternalIncompatibility)?;
            if zero_first && entry.sub == 0 {
                sub0_value = Some(value);
            } else {
                dict.write_entry(entry, bytes, ctx, app)?;
            }
        }
        bit = bit.saturating_add(bits);
    }
    if let (Some(value), Some(sub0)) = (sub0_value, entries.first()) {
        dict.write_entry(sub0, value.get(..1).unwrap_or(&[0]), ctx, app)?;
    }
    Ok(())
}

impl CoeSdoServer {
    /// An idle server.
    pub const fn new() -> Self {
        Self { state: State::Idle, mux: (0, 0), image: [0; COMPLETE_ACCESS_MAX] }
    }

    /// Whether a segmented transfer is in progress.
    pub const fn is_busy(&self) -> bool {
        !matches!(self.state, State::Idle)
    }

    /// Ends a transfer in progress without storing anything (the EtherCAT front end calls this when the
    /// mailbox is reset or the state machine falls back to INIT) and returns its multiplexer.
    pub fn cancel<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        dict: &mut Dictionary<N>,
        app: &mut A,
    ) -> Option<(u16, u8)> {
        let busy = self.is_busy();
        let mut state = core::mem::replace(&mut self.state, State::Idle);
        if let State::Download(download) = &mut state {
            download.cancel(dict, app);
        }
        busy.then_some(self.mux)
    }

    /// Handles the SDO part of one CoE SDO request (from the command byte on) and writes the SDO part of the
    /// answer into `out` (sized to the room in the answering mailbox; at least [`SDO_HEADER_LEN`]). Returns the
    /// answer's length: 0 when there is nothing to send (the client's abort, ETG.1000.6 §5.6.2.7, is not
    /// answered) or `out` is shorter than [`SDO_HEADER_LEN`].
    pub fn handle<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        request: &[u8],
        out: &mut [u8],
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> usize {
        if out.len() < SDO_HEADER_LEN {
            return 0;
        }
        let result = if request.len() < SDO_HEADER_LEN {
            self.cancel(dict, app);
            self.mux = (0, 0);
            Err(SdoAbort::CommandSpecifier)
        } else {
            self.step(request, out, dict, ctx, app)
        };
        match result {
            Ok(len) => len,
            Err(abort) => {
                self.cancel(dict, app);
                let (index, sub) = self.mux;
                abort_message(out, index, sub, abort)
            }
        }
    }

    fn step<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        request: &[u8],
        out: &mut [u8],
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<usize, SdoAbort> {
        let command = byte(request, 0);
        let index = u16::from_le_bytes([byte(request, 1), byte(request, 2)]);
        let sub = byte(request, 3);
        let complete = command & COMPLETE_ACCESS != 0;
        match command >> 5 {
            // Abort from the client (ETG.1000.6 §5.6.2.7).
            4 => {
                self.cancel(dict, app);
                Ok(0)
            }
            // Initiate download (§5.6.2.1/.2).
            1 => {
                self.cancel(dict, app);
                self.mux = (index, sub);
                self.initiate_download(command, index, sub, complete, request, out, dict, ctx, app)
            }
            // Initiate upload (§5.6.2.4/.5).
            2 => {
                self.cancel(dict, app);
                self.mux = (index, sub);
                self.initiate_upload(index, sub, complete, out, dict, app)
            }
            // Download segment (§5.6.2.3).
            0 => {
                let toggle = command & 0x10 != 0;
                let last = command & 0x01 != 0;
                let len = if request.len() > SDO_HEADER_LEN {
                    request.len().saturating_sub(1)
                } else {
                    7usize.saturating_sub(usize::from((command >> 1) & 0x07))
                };
                let data = request.get(1..len.saturating_add(1)).ok_or(SdoAbort::LengthTooLow)?;
                self.download_segment(toggle, data, last, out, dict, ctx, app)
            }
            // Upload segment (§5.6.2.6).
            3 => self.upload_segment(command & 0x10 != 0, out, dict, app),
            _ => {
                if !self.is_busy() {
                    self.mux = (index, sub);
                }
                Err(SdoAbort::CommandSpecifier)
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn initiate_download<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        command: u8,
        index: u16,
        sub: u8,
        complete: bool,
        request: &[u8],
        out: &mut [u8],
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<usize, SdoAbort> {
        let expedited = command & 0x02 != 0;
        let size_indicated = command & 0x01 != 0;
        let after_header = request.get(SDO_HEADER_LEN..).unwrap_or(&[]);
        let response = |out: &mut [u8]| put_header(out, 0x60, index, sub, [0; 4]);
        if complete {
            let data: &[u8] = if expedited {
                let len = if size_indicated { 4usize.saturating_sub(usize::from((command >> 2) & 3)) } else { 4 };
                request.get(4..4usize.saturating_add(len)).unwrap_or(&[])
            } else {
                after_header
            };
            let size = if expedited || !size_indicated {
                data.len()
            } else {
                usize::try_from(u32_at_4(request)).unwrap_or(usize::MAX)
            };
            if size > COMPLETE_ACCESS_MAX {
                return Err(SdoAbort::OutOfMemory);
            }
            let first = data.get(..size.min(data.len())).unwrap_or(&[]);
            self.image.get_mut(..first.len()).ok_or(SdoAbort::OutOfMemory)?.copy_from_slice(first);
            if first.len() >= size {
                let image = self.image;
                ca_write(dict, app, ctx, index, sub, image.get(..size).unwrap_or(&[]))?;
            } else {
                // Check the object before collecting segments.
                ca_entries(dict, index, sub)?;
                self.state = State::CaDownload { first_sub: sub, size, received: first.len(), toggle: false };
            }
            return Ok(response(out));
        }
        let entry = dict.find(index, sub)?;
        if expedited {
            let data4 = [byte(request, 4), byte(request, 5), byte(request, 6), byte(request, 7)];
            let len = size_indicated.then(|| 4u8.saturating_sub((command >> 2) & 3));
            dict.write_entry(entry, expedited_data(entry, &data4, len), ctx, app)?;
            return Ok(response(out));
        }
        // Normal transfer: size in bytes 4..7, data after the header.
        let size =
            if size_indicated { usize::try_from(u32_at_4(request)).unwrap_or(usize::MAX) } else { after_header.len() };
        if after_header.len() >= size {
            dict.write_entry(entry, after_header.get(..size).unwrap_or(after_header), ctx, app)?;
        } else {
            let mut download = SegmentedDownload::new(dict.begin_download(index, sub, Some(size), ctx)?);
            // The first part carries no toggle; the segments that follow start with toggle 0.
            dict.download_segment(&mut download.download, after_header, false, ctx, app)?;
            self.state = State::Download(download);
        }
        Ok(response(out))
    }

    fn initiate_upload<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        index: u16,
        sub: u8,
        complete: bool,
        out: &mut [u8],
        dict: &Dictionary<N>,
        app: &mut A,
    ) -> Result<usize, SdoAbort> {
        let room = out.len().saturating_sub(SDO_HEADER_LEN);
        if complete {
            let len = ca_read(dict, app, index, sub, &mut self.image)?;
            let size = u32::try_from(len).map_err(|_| SdoAbort::OutOfMemory)?;
            let now = len.min(room);
            let from = self.image.get(..now).ok_or(SdoAbort::InternalIncompatibility)?;
            out.get_mut(SDO_HEADER_LEN..SDO_HEADER_LEN.saturating_add(now))
                .ok_or(SdoAbort::InternalIncompatibility)?
                .copy_from_slice(from);
            if now < len {
                self.state = State::CaUpload { len, offset: now, toggle: false };
            }
            return Ok(put_header(out, 0x41, index, sub, size.to_le_bytes()).saturating_add(now));
        }
        let entry = dict.find(index, sub)?;
        let (read, total) = {
            let (_, tail) = out.split_at_mut(SDO_HEADER_LEN);
            read_start(dict, entry, tail, app)?
        };
        if (1..=4).contains(&total) {
            // Expedited (ETG.1000.6 §5.6.2.5, as CiA 301 §7.2.4.3.6): the data moves to bytes 4..7.
            let mut data4 = [0u8; 4];
            for (i, slot) in data4.iter_mut().enumerate().take(total) {
                *slot = byte(out, SDO_HEADER_LEN.saturating_add(i));
            }
            if read < total {
                return Err(SdoAbort::InternalIncompatibility);
            }
            let n = u8::try_from(4usize.saturating_sub(total)).unwrap_or(0);
            return Ok(put_header(out, 0x43 | (n << 2), index, sub, data4));
        }
        let size = u32::try_from(total).map_err(|_| SdoAbort::LengthTooHigh)?;
        let now = read.min(room);
        if now < total {
            self.state = State::Upload(SegmentedUpload::new(entry, now, total));
        }
        Ok(put_header(out, 0x41, index, sub, size.to_le_bytes()).saturating_add(now))
    }

    #[allow(clippy::too_many_arguments)]
    fn download_segment<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        toggle: bool,
        data: &[u8],
        last: bool,
        out: &mut [u8],
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<usize, SdoAbort> {
        let response = |out: &mut [u8]| put_header(out, 0x20 | (u8::from(toggle) << 4), 0, 0, [0; 4]);
        match &mut self.state {
            State::Download(download) => {
                download.segment(dict, toggle, data, last, ctx, app)?;
                if last {
                    self.state = State::Idle;
                }
                Ok(response(out))
            }
            State::CaDownload { first_sub, size, received, toggle: expected } => {
                if toggle != *expected {
                    return Err(SdoAbort::ToggleBit);
                }
                let end = received.saturating_add(data.len());
                if end > *size {
                    return Err(SdoAbort::LengthTooHigh);
                }
                if last && end < *size {
                    return Err(SdoAbort::LengthTooLow);
                }
                self.image.get_mut(*received..end).ok_or(SdoAbort::OutOfMemory)?.copy_from_slice(data);
                *received = end;
                *expected = !*expected;
                if last {
                    let (first_sub, size) = (*first_sub, *size);
                    self.state = State::Idle;
                    let image = self.image;
                    let (index, _) = self.mux;
                    ca_write(dict, app, ctx, index, first_sub, image.get(..size).unwrap_or(&[]))?;
                }
                Ok(response(out))
            }
            _ => Err(SdoAbort::CommandSpecifier),
        }
    }

    fn upload_segment<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        toggle: bool,
        out: &mut [u8],
        dict: &Dictionary<N>,
        app: &mut A,
    ) -> Result<usize, SdoAbort> {
        let room = out.len().saturating_sub(1);
        let (len, last) = match &mut self.state {
            State::Upload(upload) => {
                let tail = out.get_mut(1..).ok_or(SdoAbort::InternalIncompatibility)?;
                upload.next(dict, app, toggle, tail.get_mut(..room).unwrap_or(&mut []))?
            }
            State::CaUpload { len, offset, toggle: expected } => {
                if toggle != *expected {
                    return Err(SdoAbort::ToggleBit);
                }
                let now = len.saturating_sub(*offset).min(room);
                let end = offset.saturating_add(now);
                let from = self.image.get(*offset..end).ok_or(SdoAbort::InternalIncompatibility)?;
                out.get_mut(1..now.saturating_add(1)).ok_or(SdoAbort::InternalIncompatibility)?.copy_from_slice(from);
                *offset = end;
                *expected = !*expected;
                (now, end >= *len)
            }
            _ => return Err(SdoAbort::CommandSpecifier),
        };
        if last {
            self.state = State::Idle;
        }
        Ok(finish_segment(out, toggle, len, last))
    }
}
