//! The CANopen SDO server (CiA 301 §7.2.4): one server channel, sans-IO (ARCHITECTURE convention 1).
//!
//! The CAN front end calls [`SdoServer::handle`] with every frame received on the server's receive COB-ID
//! (0x600 + node-ID) and sends the returned frame on 0x580 + node-ID; then it calls [`SdoServer::poll`] until it
//! returns `None` (block-upload segments the server sends without a request, and the timeout abort), and again
//! by [`SdoServer::poll_at`] at the latest.
//!
//! Supported (CiA 301 §7.2.4.3): expedited and segmented download and upload (toggle check, 0x0503_0000);
//! block download and upload with the CRC when both sides support it (0x0504_0004), sub-block sequence numbers
//! with the acknowledgement of the last good segment and retransmission, block sizes 1..=127 (0x0504_0002) and
//! invalid sequence numbers (0x0504_0003); the server timeout (0x0504_0000); 0x0504_0001 for a command that is
//! unknown or unexpected in the present state. The block-upload protocol switch threshold is ignored (CiA 301
//! §7.2.4.3.14 lets the server choose): a block upload is always served as a block upload.
//!
//! Downloads go through the dictionary's staged download ([`Dictionary::begin_download`],
//! [`Dictionary::download_segment`]): a RAM value is stored only when the last segment arrived and passed every
//! check, so nothing is applied on abort; an application entry (program data 0x1F50:01) receives each segment as
//! it comes through [`ApplicationObjects::write`] with its offset, so a 64 KiB image is never buffered, and is
//! told to discard it on abort ([`ApplicationObjects::abort`]). Uploads stream from [`Dictionary::read_entry`]
//! at increasing offsets. The rule for a new initiate during a transfer is in the [module docs](super).

use super::crc::Crc16;
use super::transfer::{expedited_data, read_start, SegmentedDownload, SegmentedUpload};
use super::wire::{
    BlockSegment, DownloadInit, SdoFrame, SdoRequest, SdoResponse, FRAME_LEN, MAX_BLOCK_SIZE, SEGMENT_DATA,
};
use crate::od::abort::SdoAbort;
use crate::od::access::{AccessContext, ApplicationObjects, Dictionary, Download};
use crate::od::entry::Entry;

/// Default server timeout: 1 s without a frame from the client during a transfer (CANopenNode's customary
/// `SDO_SRV_TIMEOUT_TIME`; CiA 301 leaves the value to the device).
pub const DEFAULT_TIMEOUT_US: u64 = 1_000_000;

/// Server settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdoServerConfig {
    /// Time without a client frame after which a transfer in progress is aborted with 0x0504_0000, in µs.
    pub timeout_us: u64,
    /// Segments per block the server offers in a block download (1..=127, CiA 301 §7.2.4.3.9; out-of-range
    /// values are clamped).
    pub block_size: u8,
}

impl Default for SdoServerConfig {
    fn default() -> Self {
        Self { timeout_us: DEFAULT_TIMEOUT_US, block_size: MAX_BLOCK_SIZE }
    }
}

/// A block download in progress (CiA 301 §7.2.4.3.9..13).
#[derive(Clone, Debug)]
struct BlockDownload {
    download: Download,
    /// Both sides support the CRC.
    crc_on: bool,
    /// CRC of the data passed to the dictionary so far.
    crc: Crc16,
    blksize: u8,
    /// Sequence number of the last good segment in the present block (0 = none yet).
    last_seq: u8,
    /// After acknowledging a broken sub-block: ignore segments until the client restarts with sequence 1.
    resync: bool,
    /// The last good segment, held back until the next one (or the end frame, which says how many of its bytes
    /// are data) arrives.
    pending: Option<[u8; SEGMENT_DATA]>,
    /// The client sent the segment with c = 1; the end frame is due.
    ended: bool,
}

/// Where a block upload stands (CiA 301 §7.2.4.3.14..16).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum UploadPhase {
    /// Initiate answered; waiting for the client's start command.
    WaitStart,
    /// Sending the sub-block; `next` is the sequence number of the next segment.
    Sending { next: u8 },
    /// Sub-block sent (`sent` segments; `last` if it ended the data); waiting for the client's acknowledgement.
    WaitAck { sent: u8, last: bool },
    /// End frame sent; waiting for the client's end response.
    WaitEnd,
}

/// A block upload in progress.
#[derive(Clone, Copy, Debug)]
struct BlockUpload {
    entry: &'static Entry,
    total: usize,
    /// Bytes the client acknowledged.
    acked: usize,
    crc_on: bool,
    /// CRC of the acknowledged bytes.
    crc: Crc16,
    /// CRC of the acknowledged bytes plus the present sub-block as sent.
    running: Crc16,
    blksize: u8,
    phase: UploadPhase,
}

#[derive(Clone, Debug)]
enum State {
    Idle,
    Download(SegmentedDownload),
    Upload(SegmentedUpload),
    BlockDownload(BlockDownload),
    BlockUpload(BlockUpload),
}

/// One CANopen SDO server channel (CiA 301 §7.2.4), sans-IO.
#[derive(Clone, Debug)]
pub struct SdoServer {
    config: SdoServerConfig,
    state: State,
    /// Multiplexer (index, sub-index) of the transfer in progress, for its abort frame.
    mux: (u16, u8),
    /// Time of the last frame received (or block segment sent), µs.
    last_us: u64,
}

impl Default for SdoServer {
    fn default() -> Self {
        Self::new(SdoServerConfig::default())
    }
}

/// The abort frame for `abort` on `index:sub` (CiA 301 §7.2.4.3.17; EPOS4 Table 5-49, seed 001 L2800-L2813).
pub fn abort_frame(index: u16, sub: u8, abort: SdoAbort) -> [u8; FRAME_LEN] {
    SdoResponse::Abort { index, sub, code: abort.code() }.to_frame()
}

/// Bytes in a transfer's last segment that carry no data (CiA 301 §7.2.4.3.13/.16: n), for `total` bytes in
/// 7-byte segments (an empty transfer is one segment with no data).
fn unused_in_last(total: usize) -> u8 {
    let used = match total.checked_rem(SEGMENT_DATA) {
        Some(0) if total > 0 => SEGMENT_DATA,
        Some(rest) => rest,
        None => 0,
    };
    u8::try_from(SEGMENT_DATA.saturating_sub(used)).unwrap_or(0)
}

impl SdoServer {
    /// A server with `config`, idle.
    pub fn new(config: SdoServerConfig) -> Self {
        let block_size = config.block_size.clamp(1, MAX_BLOCK_SIZE);
        Self { config: SdoServerConfig { block_size, ..config }, state: State::Idle, mux: (0, 0), last_us: 0 }
    }

    /// The settings.
    pub const fn config(&self) -> SdoServerConfig {
        self.config
    }

    /// Whether a transfer is in progress.
    pub const fn is_busy(&self) -> bool {
        !matches!(self.state, State::Idle)
    }

    /// The time by which [`SdoServer::poll`] must be called (the timeout of the transfer in progress), or `None`
    /// when idle.
    pub fn poll_at(&self) -> Option<u64> {
        match self.state {
            State::Idle => None,
            _ => Some(self.last_us.saturating_add(self.config.timeout_us)),
        }
    }

    /// Handles one frame the client sent (CAN data, 8 bytes; shorter frames are ignored, as CANopenNode does,
    /// since CiA 301 §7.2.4.3 SDO frames always have DLC 8). Returns the response frame, if any.
    pub fn handle<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        request: &[u8],
        now_us: u64,
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Option<[u8; FRAME_LEN]> {
        let frame = SdoFrame::new_checked(request).ok()?;
        self.last_us = now_us;
        let mut state = core::mem::replace(&mut self.state, State::Idle);
        let in_sub_block = matches!(&state, State::BlockDownload(block) if !block.ended);
        if in_sub_block && frame.command() == 0x80 {
            // The client's abort (as a segment it would carry the invalid sequence number 0).
            cancel(&mut state, dict, app);
            return None;
        }
        let result = match &mut state {
            State::BlockDownload(block) if in_sub_block => Self::block_segment(block, &frame, dict, ctx, app),
            _ => self.step(&mut state, SdoRequest::parse(&frame), &frame, dict, ctx, app),
        };
        self.finish(state, result, dict, app)
    }

    /// Produces the frames the server sends without a request: the segments of a block-upload sub-block (one per
    /// call), and the abort 0x0504_0000 when the client has been silent for the timeout during a transfer.
    pub fn poll<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        now_us: u64,
        dict: &mut Dictionary<N>,
        app: &mut A,
    ) -> Option<[u8; FRAME_LEN]> {
        let mut state = core::mem::replace(&mut self.state, State::Idle);
        if let State::BlockUpload(upload) = &mut state {
            if matches!(upload.phase, UploadPhase::Sending { .. }) {
                self.last_us = now_us;
                let result = Self::upload_segment(upload, dict, app);
                return self.finish(state, result, dict, app);
            }
        }
        if matches!(state, State::Idle) || now_us.saturating_sub(self.last_us) < self.config.timeout_us {
            self.state = state;
            return None;
        }
        self.finish(state, Err(SdoAbort::Timeout), dict, app)
    }

    /// Stores the state after a step, or ends the transfer with an abort frame.
    fn finish<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        mut state: State,
        result: Result<Option<[u8; FRAME_LEN]>, SdoAbort>,
        dict: &mut Dictionary<N>,
        app: &mut A,
    ) -> Option<[u8; FRAME_LEN]> {
        match result {
            Ok(response) => {
                self.state = state;
                response
            }
            Err(abort) => {
                cancel(&mut state, dict, app);
                self.state = State::Idle;
                let (index, sub) = self.mux;
                Some(abort_frame(index, sub, abort))
            }
        }
    }

    /// One request outside a block-download sub-block.
    fn step<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        state: &mut State,
        request: SdoRequest,
        frame: &SdoFrame<&[u8]>,
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<Option<[u8; FRAME_LEN]>, SdoAbort> {
        match request {
            SdoRequest::Abort { .. } => {
                cancel(state, dict, app);
                *state = State::Idle;
                return Ok(None);
            }
            SdoRequest::InitiateDownload { index, sub, init } => {
                cancel(state, dict, app);
                *state = State::Idle;
                self.mux = (index, sub);
                return Self::initiate_download(state, index, sub, init, dict, ctx, app);
            }
            SdoRequest::InitiateUpload { index, sub } => {
                cancel(state, dict, app);
                *state = State::Idle;
                self.mux = (index, sub);
                return Self::initiate_upload(state, index, sub, dict, app);
            }
            SdoRequest::BlockDownloadInitiate { index, sub, crc, size } => {
                cancel(state, dict, app);
                *state = State::Idle;
                self.mux = (index, sub);
                let size = size.map(|s| usize::try_from(s).unwrap_or(usize::MAX));
                let download = dict.begin_download(index, sub, size, ctx)?;
                let blksize = self.config.block_size;
                *state = State::BlockDownload(BlockDownload {
                    download,
                    crc_on: crc,
                    crc: Crc16::new(),
                    blksize,
                    last_seq: 0,
                    resync: false,
                    pending: None,
                    ended: false,
                });
                // The server always supports the CRC (sc = 1); it is used when the client does too.
                return Ok(Some(SdoResponse::BlockDownloadInitiate { index, sub, crc: true, blksize }.to_frame()));
            }
            SdoRequest::BlockUploadInitiate { index, sub, crc, blksize, .. } => {
                cancel(state, dict, app);
                *state = State::Idle;
                self.mux = (index, sub);
                if blksize == 0 || blksize > MAX_BLOCK_SIZE {
                    return Err(SdoAbort::InvalidBlockSize);
                }
                let entry = dict.find(index, sub)?;
                let (_, total) = read_start(dict, entry, &mut [], app)?;
                let size = u32::try_from(total).map_err(|_| SdoAbort::LengthTooHigh)?;
                *state = State::BlockUpload(BlockUpload {
                    entry,
                    total,
                    acked: 0,
                    crc_on: crc,
                    crc: Crc16::new(),
                    running: Crc16::new(),
                    blksize,
                    phase: UploadPhase::WaitStart,
                });
                return Ok(Some(
                    SdoResponse::BlockUploadInitiate { index, sub, crc: true, size: Some(size) }.to_frame(),
                ));
            }
            _ => {}
        }
        match (&mut *state, request) {
            (State::Download(download), SdoRequest::DownloadSegment { toggle, data, len, last }) => {
                let part = data.get(..usize::from(len)).unwrap_or(&data);
                download.segment(dict, toggle, part, last, ctx, app)?;
                if last {
                    *state = State::Idle;
                }
                Ok(Some(SdoResponse::DownloadSegment { toggle }.to_frame()))
            }
            (State::Upload(upload), SdoRequest::UploadSegment { toggle }) => {
                let mut data = [0u8; SEGMENT_DATA];
                let (len, last) = upload.next(dict, app, toggle, &mut data)?;
                if last {
                    *state = State::Idle;
                }
                let len = u8::try_from(len).unwrap_or(0);
                Ok(Some(SdoResponse::UploadSegment { toggle, data, len, last }.to_frame()))
            }
            (State::BlockDownload(block), SdoRequest::BlockDownloadEnd { unused, crc }) => {
                let last = block.pending.take().ok_or(SdoAbort::CommandSpecifier)?;
                let used = SEGMENT_DATA.saturating_sub(usize::from(unused));
                let part = last.get(..used).unwrap_or(&last);
                block.crc.update(part);
                if block.crc_on && block.crc.value() != crc {
                    return Err(SdoAbort::CrcError);
                }
                dict.download_segment(&mut block.download, part, true, ctx, app)?;
                *state = State::Idle;
                Ok(Some(SdoResponse::BlockDownloadEnd.to_frame()))
            }
            (State::BlockUpload(upload), SdoRequest::BlockUploadStart) if upload.phase == UploadPhase::WaitStart => {
                upload.phase = UploadPhase::Sending { next: 1 };
                upload.running = upload.crc;
                Self::upload_segment(upload, dict, app)
            }
            (State::BlockUpload(upload), SdoRequest::BlockUploadAck { ackseq, blksize }) => {
                let UploadPhase::WaitAck { sent, last } = upload.phase else {
                    return Err(SdoAbort::CommandSpecifier);
                };
                Self::upload_ack(upload, sent, last, ackseq, blksize, dict, app)
            }
            (State::BlockUpload(upload), SdoRequest::BlockUploadEnd) if upload.phase == UploadPhase::WaitEnd => {
                *state = State::Idle;
                Ok(None)
            }
            (State::Idle, _) => {
                self.mux = (frame.index(), frame.sub());
                Err(SdoAbort::CommandSpecifier)
            }
            _ => Err(SdoAbort::CommandSpecifier),
        }
    }

    fn initiate_download<const N: usize, A: ApplicationObjects + ?Sized>(
        state: &mut State,
        index: u16,
        sub: u8,
        init: DownloadInit,
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<Option<[u8; FRAME_LEN]>, SdoAbort> {
        match init {
            DownloadInit::Expedited { data, len } => {
                let entry = dict.find(index, sub)?;
                dict.write_entry(entry, expedited_data(entry, &data, len), ctx, app)?;
            }
            DownloadInit::Segmented { size } => {
                let size = size.map(|s| usize::try_from(s).unwrap_or(usize::MAX));
                *state = State::Download(SegmentedDownload::new(dict.begin_download(index, sub, size, ctx)?));
            }
        }
        Ok(Some(SdoResponse::InitiateDownload { index, sub }.to_frame()))
    }

    fn initiate_upload<const N: usize, A: ApplicationObjects + ?Sized>(
        state: &mut State,
        index: u16,
        sub: u8,
        dict: &Dictionary<N>,
        app: &mut A,
    ) -> Result<Option<[u8; FRAME_LEN]>, SdoAbort> {
        let entry = dict.find(index, sub)?;
        let mut data = [0u8; 4];
        let (len, total) = read_start(dict, entry, &mut data, app)?;
        if (1..=4).contains(&total) {
            if len < total {
                return Err(SdoAbort::InternalIncompatibility);
            }
            let len = u8::try_from(total).unwrap_or(4);
            return Ok(Some(SdoResponse::UploadExpedited { index, sub, data, len }.to_frame()));
        }
        // Longer (or empty) values go segmented; the size is always indicated (CiA 301 §7.2.4.3.6).
        let size = u32::try_from(total).map_err(|_| SdoAbort::LengthTooHigh)?;
        *state = State::Upload(SegmentedUpload::new(entry, 0, total));
        Ok(Some(SdoResponse::UploadSegmented { index, sub, size }.to_frame()))
    }

    /// One frame received during a block-download sub-block (CiA 301 §7.2.4.3.12).
    fn block_segment<const N: usize, A: ApplicationObjects + ?Sized>(
        block: &mut BlockDownload,
        frame: &SdoFrame<&[u8]>,
        dict: &mut Dictionary<N>,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<Option<[u8; FRAME_LEN]>, SdoAbort> {
        let segment = BlockSegment::parse(frame);
        if segment.seqno == 0 || segment.seqno > block.blksize {
            return Err(SdoAbort::InvalidSequence);
        }
        if block.resync {
            if segment.seqno != 1 {
                return Ok(None);
            }
            block.resync = false;
            block.last_seq = 0;
        }
        if segment.seqno == block.last_seq.wrapping_add(1) {
            if let Some(previous) = block.pending.take() {
                block.crc.update(&previous);
                dict.download_segment(&mut block.download, &previous, false, ctx, app)?;
            }
            block.pending = Some(segment.data);
            block.last_seq = segment.seqno;
            if segment.last || segment.seqno == block.blksize {
                block.ended = segment.last;
                block.last_seq = 0;
                let ack = SdoResponse::BlockDownloadAck { ackseq: segment.seqno, blksize: block.blksize };
                return Ok(Some(ack.to_frame()));
            }
            Ok(None)
        } else if segment.seqno == block.last_seq {
            // A repeated frame: ignore.
            Ok(None)
        } else {
            // A segment was lost: acknowledge the last good one; the client repeats the rest as a new block
            // starting at sequence 1 (CiA 301 §7.2.4.3.12, ackseq).
            let ackseq = block.last_seq;
            block.last_seq = 0;
            block.resync = true;
            Ok(Some(SdoResponse::BlockDownloadAck { ackseq, blksize: block.blksize }.to_frame()))
        }
    }

    /// The next segment of a block-upload sub-block (CiA 301 §7.2.4.3.15), read from the dictionary.
    fn upload_segment<const N: usize, A: ApplicationObjects + ?Sized>(
        upload: &mut BlockUpload,
        dict: &Dictionary<N>,
        app: &mut A,
    ) -> Result<Option<[u8; FRAME_LEN]>, SdoAbort> {
        let UploadPhase::Sending { next } = upload.phase else {
            return Ok(None);
        };
        let skip = usize::from(next.saturating_sub(1)).saturating_mul(SEGMENT_DATA);
        let offset = upload.acked.saturating_add(skip);
        let len = upload.total.saturating_sub(offset).min(SEGMENT_DATA);
        let mut data = [0u8; SEGMENT_DATA];
        let part = data.get_mut(..len).ok_or(SdoAbort::InternalIncompatibility)?;
        if dict.read_entry(upload.entry, offset, part, app)?.len < len {
            return Err(SdoAbort::InternalIncompatibility);
        }
        upload.running.update(part);
        let last = offset.saturating_add(len) >= upload.total;
        upload.phase = if last || next >= upload.blksize {
            UploadPhase::WaitAck { sent: next, last }
        } else {
            UploadPhase::Sending { next: next.saturating_add(1) }
        };
        Ok(Some(BlockSegment { seqno: next, last, data }.to_frame()))
    }

    /// The client's acknowledgement of a block-upload sub-block (CiA 301 §7.2.4.3.15).
    #[allow(clippy::too_many_arguments)]
    fn upload_ack<const N: usize, A: ApplicationObjects + ?Sized>(
        upload: &mut BlockUpload,
        sent: u8,
        last: bool,
        ackseq: u8,
        blksize: u8,
        dict: &Dictionary<N>,
        app: &mut A,
    ) -> Result<Option<[u8; FRAME_LEN]>, SdoAbort> {
        if ackseq > sent {
            return Err(SdoAbort::InvalidSequence);
        }
        if blksize == 0 || blksize > MAX_BLOCK_SIZE {
            return Err(SdoAbort::InvalidBlockSize);
        }
        let acked = usize::from(ackseq).saturating_mul(SEGMENT_DATA).min(upload.total.saturating_sub(upload.acked));
        if ackseq == sent {
            upload.crc = upload.running;
        } else {
            // Part of the sub-block was lost: the CRC covers only what the client kept; read it again.
            let mut offset = upload.acked;
            let end = upload.acked.saturating_add(acked);
            let mut data = [0u8; SEGMENT_DATA];
            while offset < end {
                let len = end.saturating_sub(offset).min(SEGMENT_DATA);
                let part = data.get_mut(..len).ok_or(SdoAbort::InternalIncompatibility)?;
                dict.read_entry(upload.entry, offset, part, app)?;
                upload.crc.update(part);
                offset = offset.saturating_add(len);
            }
        }
        upload.acked = upload.acked.saturating_add(acked);
        upload.blksize = blksize;
        if ackseq == sent && last {
            upload.phase = UploadPhase::WaitEnd;
            let crc = if upload.crc_on { upload.crc.value() } else { 0 };
            return Ok(Some(SdoResponse::BlockUploadEnd { unused: unused_in_last(upload.total), crc }.to_frame()));
        }
        upload.phase = UploadPhase::Sending { next: 1 };
        upload.running = upload.crc;
        Self::upload_segment(upload, dict, app)
    }
}

/// Ends the transfer in `state` without storing anything.
fn cancel<const N: usize, A: ApplicationObjects + ?Sized>(state: &mut State, dict: &mut Dictionary<N>, app: &mut A) {
    match state {
        State::Download(download) => download.cancel(dict, app),
        State::BlockDownload(block) => dict.abort_download(&mut block.download, app),
        State::Idle | State::Upload(_) | State::BlockUpload(_) => {}
    }
}
