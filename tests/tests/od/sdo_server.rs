//! The CANopen SDO server (`firmware::comm::sdo::server`, CiA 301 §7.2.4) on the generated dictionary:
//! golden frames from the EPOS4 Application Notes (seed 001, Tables 5-47..5-51, L2751-L2858), expedited,
//! segmented and block transfers, the CRC, toggle and sequence checks, the timeout, the dictionary's abort codes
//! on the wire, and a property test that random frames never break the server.

use firmware::comm::sdo::crc::Crc16;
use firmware::comm::sdo::server::{SdoServer, SdoServerConfig, DEFAULT_TIMEOUT_US};
use firmware::comm::sdo::wire::{BlockSegment, DownloadInit, SdoFrame, SdoRequest, SdoResponse};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{
    AccessContext, ApplicationObjects, CommState, Dictionary, NoApplicationObjects, ReadOutcome,
};
use firmware::od::entry::Entry;
use firmware::od::generated::{self, handles};
use proptest::prelude::*;

const PRE_OP: AccessContext =
    AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 8 };
const OP: AccessContext = AccessContext { comm_state: CommState::Operational, ..PRE_OP };

/// Stands in for the bootloader and persistence: records every write to program data 0x1F50:01 by offset,
/// checks the offsets are contiguous, and reads fixed-size application values as 1.
#[derive(Default, Debug)]
struct App {
    program: Vec<u8>,
    complete: bool,
    aborted: bool,
    largest_chunk: usize,
    writes: usize,
}

impl ApplicationObjects for App {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        let value = match entry.data_type.fixed_size() {
            Some(size) => {
                let mut v = vec![0u8; size];
                v[0] = 1;
                v
            }
            None => self.program.clone(),
        };
        let rest = value.get(offset..).unwrap_or(&[]);
        let len = rest.len().min(buf.len());
        buf[..len].copy_from_slice(&rest[..len]);
        Ok(ReadOutcome { len, total_len: value.len() })
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        _: &mut [u8],
    ) -> Result<(), SdoAbort> {
        if (entry.index, entry.sub) == (0x1F50, 1) {
            if offset == 0 {
                self.program.clear();
                self.aborted = false;
            }
            assert_eq!(offset, self.program.len(), "program data arrives in order, without gaps");
            self.program.extend_from_slice(data);
            self.largest_chunk = self.largest_chunk.max(data.len());
            self.writes += 1;
        }
        self.complete = complete;
        Ok(())
    }

    fn abort(&mut self, _: &'static Entry) {
        self.aborted = true;
    }
}

struct Bench {
    server: SdoServer,
    dict: Dictionary,
    app: App,
    now: u64,
    ctx: AccessContext,
}

impl Bench {
    fn new() -> Self {
        Self::with(SdoServerConfig::default())
    }

    fn with(config: SdoServerConfig) -> Self {
        Self {
            server: SdoServer::new(config),
            dict: Dictionary::new(generated::DEFAULT_NODE_ID),
            app: App::default(),
            now: 0,
            ctx: PRE_OP,
        }
    }

    fn send(&mut self, frame: [u8; 8]) -> Option<[u8; 8]> {
        self.now += 100;
        self.server.handle(&frame, self.now, &mut self.dict, self.ctx, &mut self.app)
    }

    fn request(&mut self, request: SdoRequest) -> Option<SdoResponse> {
        self.send(request.to_frame()).map(|f| SdoResponse::parse(&SdoFrame::new_checked(&f[..]).unwrap()))
    }

    fn poll(&mut self) -> Option<[u8; 8]> {
        self.server.poll(self.now, &mut self.dict, &mut self.app)
    }

    fn upload(&mut self, index: u16, sub: u8) -> Option<SdoResponse> {
        self.request(SdoRequest::InitiateUpload { index, sub })
    }

    fn abort_code(&mut self, request: SdoRequest) -> u32 {
        match self.request(request) {
            Some(SdoResponse::Abort { code, .. }) => code,
            other => panic!("expected an abort for {request:?}, got {other:?}"),
        }
    }

    /// A whole segmented upload as a client does it (CiA 301 §7.2.4.3.6/.7).
    fn segmented_upload(&mut self, index: u16, sub: u8) -> Vec<u8> {
        let Some(SdoResponse::UploadSegmented { size, .. }) = self.upload(index, sub) else { panic!("segmented") };
        let mut data = Vec::new();
        let mut toggle = false;
        loop {
            let Some(SdoResponse::UploadSegment { toggle: t, data: d, len, last }) =
                self.request(SdoRequest::UploadSegment { toggle })
            else {
                panic!("segment")
            };
            assert_eq!(t, toggle);
            data.extend_from_slice(&d[..usize::from(len)]);
            toggle = !toggle;
            if last {
                break;
            }
        }
        assert_eq!(data.len(), size as usize);
        assert!(!self.server.is_busy());
        data
    }

    /// A whole segmented download (CiA 301 §7.2.4.3.3/.5).
    fn segmented_download(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
        let init = DownloadInit::Segmented { size: Some(value.len() as u32) };
        match self.request(SdoRequest::InitiateDownload { index, sub, init }) {
            Some(SdoResponse::InitiateDownload { index: i, sub: s }) => assert_eq!((i, s), (index, sub)),
            Some(SdoResponse::Abort { code, .. }) => return Err(code),
            other => panic!("{other:?}"),
        }
        let mut toggle = false;
        let chunks: Vec<&[u8]> = value.chunks(7).collect();
        for (i, chunk) in chunks.iter().enumerate() {
            let mut data = [0u8; 7];
            data[..chunk.len()].copy_from_slice(chunk);
            let last = i + 1 == chunks.len();
            let seg = SdoRequest::DownloadSegment { toggle, data, len: chunk.len() as u8, last };
            match self.request(seg) {
                Some(SdoResponse::DownloadSegment { toggle: t }) => assert_eq!(t, toggle),
                Some(SdoResponse::Abort { code, .. }) => return Err(code),
                other => panic!("{other:?}"),
            }
            toggle = !toggle;
        }
        Ok(())
    }

    /// A block download as a client does it (CiA 301 §7.2.4.3.9..13), with hooks to corrupt it.
    fn block_download(&mut self, index: u16, sub: u8, value: &[u8], fault: BlockFault) -> Result<(), u32> {
        let init = SdoRequest::BlockDownloadInitiate { index, sub, crc: true, size: Some(value.len() as u32) };
        let blksize = match self.request(init) {
            Some(SdoResponse::BlockDownloadInitiate { crc, blksize, .. }) => {
                assert!(crc, "the server supports the CRC");
                blksize
            }
            Some(SdoResponse::Abort { code, .. }) => return Err(code),
            other => panic!("{other:?}"),
        };
        assert!((1..=127).contains(&blksize));
        let segments: Vec<[u8; 7]> = value
            .chunks(7)
            .map(|c| {
                let mut d = [0u8; 7];
                d[..c.len()].copy_from_slice(c);
                d
            })
            .collect();
        let mut next = 0usize; // index of the first segment of the present block
        let mut dropped = false;
        while next < segments.len() {
            let mut response = None;
            let count = (segments.len() - next).min(usize::from(blksize));
            for k in 0..count {
                let seqno = (k + 1) as u8;
                let last = next + k + 1 == segments.len();
                if let BlockFault::DropSegment(n) = fault {
                    if !dropped && next + k == n {
                        dropped = true;
                        continue;
                    }
                }
                let seqno = match fault {
                    BlockFault::BadSequence(n) if next + k == n => 0,
                    _ => seqno,
                };
                let frame = BlockSegment { seqno, last, data: segments[next + k] }.to_frame();
                if let Some(f) = self.send(frame) {
                    if let SdoResponse::Abort { code, .. } = SdoResponse::parse(&SdoFrame::new_checked(&f[..]).unwrap())
                    {
                        return Err(code);
                    }
                    assert!(response.is_none() || dropped, "one response per block");
                    response.get_or_insert(f);
                }
            }
            let frame = response.expect("the server acknowledges every block");
            match SdoResponse::parse(&SdoFrame::new_checked(&frame[..]).unwrap()) {
                SdoResponse::BlockDownloadAck { ackseq, blksize: b } => {
                    assert_eq!(b, blksize);
                    next += usize::from(ackseq);
                }
                SdoResponse::Abort { code, .. } => return Err(code),
                other => panic!("{other:?}"),
            }
        }
        let unused = (segments.len() * 7 - value.len()) as u8;
        let mut crc = Crc16::of(value);
        if matches!(fault, BlockFault::WrongCrc) {
            crc ^= 0x5555;
        }
        match self.request(SdoRequest::BlockDownloadEnd { unused, crc }) {
            Some(SdoResponse::BlockDownloadEnd) => Ok(()),
            Some(SdoResponse::Abort { code, .. }) => Err(code),
            other => panic!("{other:?}"),
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum BlockFault {
    None,
    WrongCrc,
    /// Send sequence number 0 in place of segment n.
    BadSequence(usize),
    /// Lose segment n once (the server acknowledges the segments before it and the client repeats the rest).
    DropSegment(usize),
}

fn image(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i.wrapping_mul(31) ^ (i >> 8)) as u8).collect()
}

#[test]
fn epos4_application_note_frames() {
    let mut b = Bench::new();
    b.dict.set(handles::STATUSWORD, 0x0008);
    b.dict.set(handles::POSITION_ACTUAL_VALUE, 1226);
    // Table 5-47 (seed 001 L2754-L2776): read statusword.
    assert_eq!(b.send([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]), Some([0x4B, 0x41, 0x60, 0, 0x08, 0, 0, 0]));
    // Table 5-48 (L2779-L2797): write controlword 0x000F, size not indicated.
    assert_eq!(b.send([0x22, 0x40, 0x60, 0, 0x0F, 0, 0, 0]), Some([0x60, 0x40, 0x60, 0, 0, 0, 0, 0]));
    assert_eq!(b.dict.get(handles::CONTROLWORD), 0x000F);
    // Table 5-49 (L2800-L2813): read the missing 0x2000:08.
    assert_eq!(b.send([0x40, 0x00, 0x20, 0x08, 0, 0, 0, 0]), Some([0x80, 0x00, 0x20, 0x08, 0x11, 0x00, 0x09, 0x06]));
    // Table 5-50 (L2817-L2834): read position actual value 0x000004CA.
    assert_eq!(b.send([0x40, 0x64, 0x60, 0, 0, 0, 0, 0]), Some([0x43, 0x64, 0x60, 0, 0xCA, 0x04, 0, 0]));
    // Table 5-51 (L2838-L2858): write target position 2222.
    assert_eq!(b.send([0x22, 0x7A, 0x60, 0, 0xAE, 0x08, 0, 0]), Some([0x60, 0x7A, 0x60, 0, 0, 0, 0, 0]));
    assert_eq!(b.dict.get(handles::TARGET_POSITION), 2222);
}

#[test]
fn expedited_read_of_device_type_and_write_of_an_rw_object() {
    let mut b = Bench::new();
    assert_eq!(
        b.upload(0x1000, 0),
        Some(SdoResponse::UploadExpedited {
            index: 0x1000,
            sub: 0,
            data: generated::DEVICE_TYPE.to_le_bytes(),
            len: 4
        })
    );
    // 0x23: four bytes indicated (EPOS4 Table 5-46, L2733-L2749).
    assert_eq!(b.send([0x23, 0x7A, 0x60, 0, 0x78, 0x56, 0x34, 0x12]), Some([0x60, 0x7A, 0x60, 0, 0, 0, 0, 0]));
    assert_eq!(b.dict.get(handles::TARGET_POSITION), 0x1234_5678);
    // 0x2B: two bytes into a UNSIGNED16.
    assert_eq!(b.send([0x2B, 0x40, 0x60, 0, 0x06, 0x00, 0xEE, 0xEE]), Some([0x60, 0x40, 0x60, 0, 0, 0, 0, 0]));
    assert_eq!(b.dict.get(handles::CONTROLWORD), 6);
    assert!(!b.server.is_busy());
}

#[test]
fn segmented_upload_of_the_device_name_and_a_longer_string() {
    let mut b = Bench::new();
    assert_eq!(b.segmented_upload(0x1008, 0), b"OSD-402");
    // The golden frames of the one-segment upload: 0x41 + size 7, then 0x01 (t = 0, n = 0, c = 1).
    assert_eq!(b.send([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]), Some([0x41, 0x08, 0x10, 0, 7, 0, 0, 0]));
    assert_eq!(b.send([0x60, 0, 0, 0, 0, 0, 0, 0]), Some([0x01, b'O', b'S', b'D', b'-', b'4', b'0', b'2']));
    // 0x1009 needs four segments with alternating toggles.
    assert_eq!(b.segmented_upload(0x1009, 0), b"STM32F405 reference 1.0");
}

#[test]
fn segmented_download_stores_only_when_complete() {
    let mut b = Bench::new();
    assert_eq!(b.segmented_download(0x607A, 0, &(-5i32).to_le_bytes()), Ok(()));
    assert_eq!(b.dict.get(handles::TARGET_POSITION), -5);
    // A download abandoned half-way stores nothing.
    let init = DownloadInit::Segmented { size: Some(4) };
    b.request(SdoRequest::InitiateDownload { index: 0x607A, sub: 0, init });
    let seg = SdoRequest::DownloadSegment { toggle: false, data: [9, 0, 0, 0, 0, 0, 0], len: 2, last: false };
    assert_eq!(b.request(seg), Some(SdoResponse::DownloadSegment { toggle: false }));
    assert_eq!(b.request(SdoRequest::Abort { index: 0x607A, sub: 0, code: 0x0800_0000 }), None);
    assert_eq!(b.dict.get(handles::TARGET_POSITION), -5);
    // Program data: segments reach the application as they come.
    let data = image(100);
    assert_eq!(b.segmented_download(0x1F50, 1, &data), Ok(()));
    assert_eq!(b.app.program, data);
    assert!(b.app.complete);
    assert_eq!(b.app.largest_chunk, 7);
    // Too much data for the announced size.
    assert_eq!(b.segmented_download(0x607A, 0, &[1, 2, 3, 4, 5]), Err(0x0607_0012));
}

#[test]
fn toggle_errors_abort_both_directions() {
    let mut b = Bench::new();
    assert!(matches!(b.upload(0x1009, 0), Some(SdoResponse::UploadSegmented { .. })));
    assert!(matches!(b.request(SdoRequest::UploadSegment { toggle: false }), Some(SdoResponse::UploadSegment { .. })));
    assert_eq!(b.abort_code(SdoRequest::UploadSegment { toggle: false }), SdoAbort::ToggleBit.code());
    assert!(!b.server.is_busy());

    let init = DownloadInit::Segmented { size: Some(14) };
    b.request(SdoRequest::InitiateDownload { index: 0x1F50, sub: 1, init });
    let seg = |toggle, last| SdoRequest::DownloadSegment { toggle, data: [1; 7], len: 7, last };
    assert_eq!(b.request(seg(false, false)), Some(SdoResponse::DownloadSegment { toggle: false }));
    let frame = b.send(seg(false, true).to_frame()).unwrap();
    assert_eq!(frame, [0x80, 0x50, 0x1F, 0x01, 0x00, 0x00, 0x03, 0x05], "abort 0x0503_0000 on 0x1F50:01");
    assert!(b.app.aborted, "the application discards the partial image");
    assert!(!b.server.is_busy());
}

#[test]
fn block_download_of_64_kib_program_data_with_crc() {
    let mut b = Bench::new();
    let data = image(64 * 1024 + 5);
    assert_eq!(b.block_download(0x1F50, 1, &data, BlockFault::None), Ok(()));
    assert_eq!(b.app.program.len(), data.len());
    assert!(b.app.program == data, "the application received the image byte for byte");
    assert!(b.app.complete && !b.app.aborted);
    assert_eq!(b.app.largest_chunk, 7, "streamed segment by segment, never buffered whole");
    assert!(!b.server.is_busy());
}

#[test]
fn block_download_with_a_wrong_crc_aborts_and_discards() {
    let mut b = Bench::new();
    let data = image(64 * 1024);
    let frame_code = b.block_download(0x1F50, 1, &data, BlockFault::WrongCrc);
    assert_eq!(frame_code, Err(SdoAbort::CrcError.code()));
    assert!(b.app.aborted && !b.app.complete);
    // A RAM entry is not written either.
    let before = b.dict.get(handles::TARGET_POSITION);
    assert_eq!(b.block_download(0x607A, 0, &7i32.to_le_bytes(), BlockFault::WrongCrc), Err(0x0504_0004));
    assert_eq!(b.dict.get(handles::TARGET_POSITION), before);
    assert_eq!(b.block_download(0x607A, 0, &7i32.to_le_bytes(), BlockFault::None), Ok(()));
    assert_eq!(b.dict.get(handles::TARGET_POSITION), 7);
}

#[test]
fn block_download_sequence_errors() {
    let mut b = Bench::new();
    let data = image(64 * 1024);
    assert_eq!(b.block_download(0x1F50, 1, &data, BlockFault::BadSequence(300)), Err(0x0504_0003));
    assert!(b.app.aborted);
    assert!(!b.server.is_busy());

    // A sequence number above the block size the server offered.
    let mut b = Bench::with(SdoServerConfig { block_size: 16, ..SdoServerConfig::default() });
    let init = SdoRequest::BlockDownloadInitiate { index: 0x1F50, sub: 1, crc: true, size: None };
    assert_eq!(
        b.request(init),
        Some(SdoResponse::BlockDownloadInitiate { index: 0x1F50, sub: 1, crc: true, blksize: 16 })
    );
    assert_eq!(b.send(BlockSegment { seqno: 1, last: false, data: [0; 7] }.to_frame()), None);
    let abort = b.send(BlockSegment { seqno: 17, last: false, data: [0; 7] }.to_frame()).unwrap();
    assert_eq!(abort, [0x80, 0x50, 0x1F, 0x01, 0x03, 0x00, 0x04, 0x05]);
}

#[test]
fn block_download_recovers_a_lost_segment() {
    let mut b = Bench::new();
    let data = image(5000);
    assert_eq!(b.block_download(0x1F50, 1, &data, BlockFault::DropSegment(130)), Ok(()));
    assert!(b.app.program == data);
    let mut b = Bench::new();
    assert_eq!(b.block_download(0x1F50, 1, &data, BlockFault::DropSegment(0)), Ok(()));
    assert!(b.app.program == data);
}

/// A block upload as a client does it (CiA 301 §7.2.4.3.14..16); `lose` drops segment n (counted over the
/// transfer) once, so the client acknowledges only the segments before it.
fn block_upload(b: &mut Bench, index: u16, sub: u8, blksize: u8, lose: Option<usize>) -> Vec<u8> {
    let init = SdoRequest::BlockUploadInitiate { index, sub, crc: true, blksize, pst: 0 };
    let Some(SdoResponse::BlockUploadInitiate { crc: true, size: Some(size), .. }) = b.request(init) else {
        panic!("initiate")
    };
    let mut data: Vec<u8> = Vec::new();
    let mut frame = b.send(SdoRequest::BlockUploadStart.to_frame());
    let mut lost = false;
    loop {
        // One sub-block: the answer to the request, then what poll gives.
        let mut block = Vec::new();
        while let Some(f) = frame {
            block.push(f);
            frame = b.poll();
        }
        assert!(!block.is_empty() && block.len() <= usize::from(blksize));
        let (mut ackseq, mut ended, mut broken) = (0u8, false, false);
        for f in &block {
            let seg = BlockSegment::parse(&SdoFrame::new_checked(&f[..]).unwrap());
            if broken {
                continue;
            }
            if !lost && lose == Some(data.len() / 7) {
                lost = true;
                broken = true;
                continue;
            }
            assert_eq!(seg.seqno, ackseq + 1);
            ackseq = seg.seqno;
            data.extend_from_slice(&seg.data);
            ended = seg.last;
        }
        let raw = b.send(SdoRequest::BlockUploadAck { ackseq, blksize }.to_frame());
        if ended {
            let response = raw.map(|f| SdoResponse::parse(&SdoFrame::new_checked(&f[..]).unwrap()));
            let Some(SdoResponse::BlockUploadEnd { unused, crc }) = response else { panic!("end {response:?}") };
            data.truncate(data.len() - usize::from(unused));
            assert_eq!(crc, Crc16::of(&data), "CRC of the uploaded data");
            assert_eq!(b.send(SdoRequest::BlockUploadEnd.to_frame()), None);
            break;
        }
        frame = Some(raw.expect("next sub-block"));
    }
    assert_eq!(data.len(), size as usize);
    assert!(!b.server.is_busy());
    data
}

#[test]
fn block_upload_with_crc() {
    let mut b = Bench::new();
    assert_eq!(block_upload(&mut b, 0x1009, 0, 127, None), b"STM32F405 reference 1.0");
    assert_eq!(block_upload(&mut b, 0x1009, 0, 2, None), b"STM32F405 reference 1.0");
    assert_eq!(block_upload(&mut b, 0x1000, 0, 5, None), generated::DEVICE_TYPE.to_le_bytes());
    // A lost segment: the client acknowledges the one before, the server repeats the rest and keeps the CRC.
    assert_eq!(block_upload(&mut b, 0x1009, 0, 3, Some(1)), b"STM32F405 reference 1.0");
    assert_eq!(block_upload(&mut b, 0x1009, 0, 3, Some(0)), b"STM32F405 reference 1.0");
    // Block size 0 is refused (CiA 301 §7.2.4.3.14: 1..127).
    let init = SdoRequest::BlockUploadInitiate { index: 0x1009, sub: 0, crc: true, blksize: 0, pst: 0 };
    assert_eq!(b.abort_code(init), SdoAbort::InvalidBlockSize.code());
}

#[test]
fn block_upload_ack_beyond_the_block_is_a_sequence_error() {
    let mut b = Bench::new();
    let init = SdoRequest::BlockUploadInitiate { index: 0x1009, sub: 0, crc: false, blksize: 2, pst: 0 };
    assert!(b.request(init).is_some());
    assert!(b.send(SdoRequest::BlockUploadStart.to_frame()).is_some());
    assert!(b.poll().is_some());
    assert_eq!(b.poll(), None);
    assert_eq!(b.abort_code(SdoRequest::BlockUploadAck { ackseq: 3, blksize: 2 }), 0x0504_0003);
}

#[test]
fn silent_clients_time_out() {
    let mut b = Bench::new();
    assert!(matches!(b.upload(0x1009, 0), Some(SdoResponse::UploadSegmented { .. })));
    let deadline = b.server.poll_at().unwrap();
    assert_eq!(deadline, b.now + DEFAULT_TIMEOUT_US);
    b.now = deadline - 1;
    assert_eq!(b.poll(), None);
    b.now = deadline;
    assert_eq!(b.poll(), Some([0x80, 0x09, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]));
    assert!(!b.server.is_busy());
    assert_eq!(b.server.poll_at(), None);

    // A stalled block download tells the application to discard.
    let mut b = Bench::with(SdoServerConfig { timeout_us: 5_000, ..SdoServerConfig::default() });
    let init = SdoRequest::BlockDownloadInitiate { index: 0x1F50, sub: 1, crc: true, size: None };
    b.request(init);
    b.send(BlockSegment { seqno: 1, last: false, data: [1; 7] }.to_frame());
    b.send(BlockSegment { seqno: 2, last: false, data: [2; 7] }.to_frame());
    b.now += 5_000;
    let abort = b.poll().unwrap();
    assert_eq!(abort, [0x80, 0x50, 0x1F, 0x01, 0x00, 0x00, 0x04, 0x05]);
    assert!(b.app.aborted);
}

#[test]
fn every_dictionary_abort_reaches_the_wire() {
    let mut b = Bench::new();
    let up = |index, sub| SdoRequest::InitiateUpload { index, sub };
    let write = |index, sub, bytes: &[u8]| {
        let mut data = [0u8; 4];
        data[..bytes.len()].copy_from_slice(bytes);
        SdoRequest::InitiateDownload {
            index,
            sub,
            init: DownloadInit::Expedited { data, len: Some(bytes.len() as u8) },
        }
    };
    let cases: Vec<(SdoRequest, SdoAbort)> = vec![
        (up(0x5FFF, 0), SdoAbort::ObjectDoesNotExist),
        (up(0x2000, 8), SdoAbort::SubindexDoesNotExist),
        (up(0x1F50, 1), SdoAbort::WriteOnly),
        (write(0x6041, 0, &[0, 0]), SdoAbort::ReadOnly),
        (write(0x1000, 0, &[0, 0, 0, 0]), SdoAbort::ReadOnly),
        (write(0x6040, 0, &[1]), SdoAbort::LengthTooLow),
        (write(0x6040, 0, &[1, 2, 3]), SdoAbort::LengthTooHigh),
        (write(0x2000, 0, &[0]), SdoAbort::ValueTooLow),
        (write(0x2000, 0, &[128]), SdoAbort::ValueTooHigh),
        (write(0x6060, 0, &[2]), SdoAbort::InvalidValue),
        (write(0x1600, 1, &0x6040_0010u32.to_le_bytes()), SdoAbort::UnsupportedAccess),
        (write(0x1010, 1, b"save"), SdoAbort::CannotTransfer),
        (SdoRequest::Unknown(0xE0), SdoAbort::CommandSpecifier),
        (SdoRequest::UploadSegment { toggle: false }, SdoAbort::CommandSpecifier),
    ];
    for (request, abort) in cases {
        let code = match request {
            // 0x1010 through an application that serves nothing.
            SdoRequest::InitiateDownload { index: 0x1010, .. } => {
                let f = b.server.handle(&request.to_frame(), 0, &mut b.dict, b.ctx, &mut NoApplicationObjects).unwrap();
                u32::from_le_bytes([f[4], f[5], f[6], f[7]])
            }
            _ => b.abort_code(request),
        };
        assert_eq!(code, abort.code(), "{request:?}");
    }
    // State and mapping rules.
    b.ctx = OP;
    assert_eq!(b.abort_code(write(0x1600, 0, &[0])), SdoAbort::DeviceState.code());
    b.ctx = PRE_OP;
    assert_eq!(b.request(write(0x1600, 0, &[0])), Some(SdoResponse::InitiateDownload { index: 0x1600, sub: 0 }));
    assert_eq!(b.abort_code(write(0x1600, 1, &0x6041_0010u32.to_le_bytes())), SdoAbort::CannotBeMapped.code());
    b.request(write(0x1600, 1, &0x607A_0020u32.to_le_bytes()));
    b.request(write(0x1600, 2, &0x60FF_0020u32.to_le_bytes()));
    b.request(write(0x1600, 3, &0x6040_0010u32.to_le_bytes()));
    assert_eq!(b.abort_code(write(0x1600, 0, &[3])), SdoAbort::PdoLengthExceeded.code());
}

#[test]
fn a_new_initiate_ends_the_transfer_in_progress() {
    let mut b = Bench::new();
    let init = DownloadInit::Segmented { size: Some(20) };
    b.request(SdoRequest::InitiateDownload { index: 0x1F50, sub: 1, init });
    let seg = SdoRequest::DownloadSegment { toggle: false, data: [7; 7], len: 7, last: false };
    assert_eq!(b.request(seg), Some(SdoResponse::DownloadSegment { toggle: false }));
    // The client restarts with an upload: it is served, the old download is discarded.
    assert!(matches!(b.upload(0x1000, 0), Some(SdoResponse::UploadExpedited { index: 0x1000, .. })));
    assert!(b.app.aborted);
    assert!(!b.server.is_busy());
    // A stray segment afterwards is an unknown command for the idle server.
    assert_eq!(b.abort_code(seg), SdoAbort::CommandSpecifier.code());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn random_frames_never_break_the_server(
        frames in proptest::collection::vec((any::<[u8; 8]>(), 0u8..8, any::<bool>(), 0u64..3_000_000), 0..60),
    ) {
        let mut b = Bench::new();
        for (mut frame, kind, poll, dt) in frames {
            // Bias the command bytes towards the ones the server knows, with the 0x1F50/0x1009/0x607A targets.
            match kind {
                0 => frame[0] = 0x21,
                1 => frame[0] = (frame[0] & 0x1F) | 0x60,
                2 => frame[0] &= 0x1F,
                3 => { frame[0] = 0xC6; frame[1..4].copy_from_slice(&[0x50, 0x1F, 0x01]); }
                4 => { frame[0] = 0xA4; frame[1..4].copy_from_slice(&[0x09, 0x10, 0x00]); frame[4] |= 1; }
                5 => frame[0] = 0xA0 | (frame[0] & 0x03),
                _ => {}
            }
            b.now += dt;
            let _ = b.server.handle(&frame, b.now, &mut b.dict, b.ctx, &mut b.app);
            if poll {
                while b.poll().is_some() {
                    if !b.server.is_busy() { break; }
                }
            }
        }
        // The client aborts whatever it had going, then reads the device type.
        prop_assert_eq!(b.send([0x80, 0, 0, 0, 0, 0, 0, 0]), None);
        prop_assert_eq!(
            b.send([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]),
            Some(SdoResponse::UploadExpedited {
                index: 0x1000, sub: 0, data: generated::DEVICE_TYPE.to_le_bytes(), len: 4
            }.to_frame())
        );
    }
}
