//! The SDO part of CoE (`firmware::comm::sdo::coe`, ETG.1000.6 §5.6.2) on the generated dictionary: expedited,
//! normal and segmented transfers with mailbox-sized segments, and complete access (ETG.1020 §12.2: sub-index 0
//! padded to 16 bits) of the PDO mapping objects, whose sub-index-0-first procedure (CiA 301 §7.5.2.36) the
//! dictionary enforces.

use firmware::comm::sdo::coe::{CoeSdoServer, SDO_HEADER_LEN};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, ApplicationObjects, CommState, Dictionary, ReadOutcome};
use firmware::od::entry::Entry;
use firmware::od::generated::{self, handles};

const PRE_OP: AccessContext =
    AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 40 };
const OP: AccessContext = AccessContext { comm_state: CommState::Operational, ..PRE_OP };

/// Records program data 0x1F50:01 as it arrives.
#[derive(Default)]
struct App {
    program: Vec<u8>,
    complete: bool,
    aborted: bool,
}

impl ApplicationObjects for App {
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
        assert_eq!(offset, self.program.len());
        self.program.extend_from_slice(data);
        self.complete = complete;
        Ok(())
    }

    fn abort(&mut self, _: &'static Entry) {
        self.aborted = true;
    }
}

struct Bench {
    server: CoeSdoServer,
    dict: Dictionary,
    app: App,
    ctx: AccessContext,
    /// Room for the SDO part of an answer: the mailbox size − 8 (mailbox header 6 + CoE header 2).
    room: usize,
}

impl Bench {
    fn new(mailbox: usize) -> Self {
        Self {
            server: CoeSdoServer::new(),
            dict: Dictionary::new(generated::DEFAULT_NODE_ID),
            app: App::default(),
            ctx: PRE_OP,
            room: mailbox - 8,
        }
    }

    fn send(&mut self, request: &[u8]) -> Vec<u8> {
        let mut out = vec![0u8; self.room];
        let len = self.server.handle(request, &mut out, &mut self.dict, self.ctx, &mut self.app);
        out.truncate(len);
        out
    }

    fn abort_code(&mut self, request: &[u8]) -> u32 {
        let answer = self.send(request);
        assert_eq!(answer[0], 0x80, "abort expected for {request:02X?}, got {answer:02X?}");
        u32::from_le_bytes(answer[4..8].try_into().unwrap())
    }

    /// A whole upload as SOEM does it: initiate (expedited or normal), then upload segments until c = 1.
    fn upload(&mut self, index: u16, sub: u8, complete: bool) -> Vec<u8> {
        let [lo, hi] = index.to_le_bytes();
        let command = if complete { 0x50 } else { 0x40 };
        let answer = self.send(&[command, lo, hi, sub, 0, 0, 0, 0]);
        assert_eq!(&answer[1..4], &[lo, hi, sub]);
        if answer[0] & 0xE2 == 0x42 {
            // Expedited (ETG.1000.6 §5.6.2.5).
            let len = 4 - usize::from((answer[0] >> 2) & 3);
            return answer[4..4 + len].to_vec();
        }
        assert_eq!(answer[0], 0x41, "normal upload response");
        let size = u32::from_le_bytes(answer[4..8].try_into().unwrap()) as usize;
        let mut data = answer[SDO_HEADER_LEN..].to_vec();
        let mut toggle = false;
        while data.len() < size {
            let segment = self.send(&[0x60 | (u8::from(toggle) << 4), 0, 0, 0, 0, 0, 0, 0]);
            assert!(segment.len() <= self.room);
            assert_eq!(segment[0] & 0xF0, u8::from(toggle) << 4, "upload segment response with the toggle echoed");
            let n = usize::from((segment[0] >> 1) & 7);
            let len = if segment.len() > SDO_HEADER_LEN { segment.len() - 1 } else { 7 - n };
            data.extend_from_slice(&segment[1..1 + len]);
            let last = segment[0] & 1 != 0;
            assert_eq!(last, data.len() >= size);
            toggle = !toggle;
        }
        assert_eq!(data.len(), size);
        assert!(!self.server.is_busy());
        data
    }

    /// A whole download: normal initiate with as much data as fits, then download segments.
    fn download(&mut self, index: u16, sub: u8, complete: bool, value: &[u8]) -> Result<(), u32> {
        let [lo, hi] = index.to_le_bytes();
        let command = if complete { 0x31 } else { 0x21 };
        let mut request = vec![command, lo, hi, sub];
        request.extend_from_slice(&(value.len() as u32).to_le_bytes());
        let first = value.len().min(self.room - SDO_HEADER_LEN);
        request.extend_from_slice(&value[..first]);
        let answer = self.send(&request);
        if answer[0] == 0x80 {
            return Err(u32::from_le_bytes(answer[4..8].try_into().unwrap()));
        }
        assert_eq!(&answer[..4], &[0x60, lo, hi, sub]);
        let mut sent = first;
        let mut toggle = false;
        while sent < value.len() {
            let len = (value.len() - sent).min(self.room - 1);
            let last = sent + len == value.len();
            let mut segment = vec![(u8::from(toggle) << 4) | u8::from(last)];
            segment.extend_from_slice(&value[sent..sent + len]);
            if len < 7 {
                segment[0] |= ((7 - len) as u8) << 1;
                segment.resize(SDO_HEADER_LEN, 0);
            }
            let answer = self.send(&segment);
            if answer[0] == 0x80 {
                return Err(u32::from_le_bytes(answer[4..8].try_into().unwrap()));
            }
            assert_eq!(answer[0], 0x20 | (u8::from(toggle) << 4));
            sent += len;
            toggle = !toggle;
        }
        Ok(())
    }
}

fn mapping_image(sub0: u8, entries: &[u32]) -> Vec<u8> {
    let mut image = vec![sub0, 0];
    for i in 0..12 {
        image.extend_from_slice(&entries.get(i).copied().unwrap_or(0).to_le_bytes());
    }
    image
}

#[test]
fn expedited_and_normal_uploads() {
    let mut b = Bench::new(128);
    assert_eq!(b.send(&[0x40, 0x00, 0x10, 0, 0, 0, 0, 0]), {
        let mut v = vec![0x43, 0x00, 0x10, 0x00];
        v.extend_from_slice(&generated::DEVICE_TYPE.to_le_bytes());
        v
    });
    // Normal upload of a string: size and data in one answer (fieldbus-real-masters.md item 6).
    let answer = b.send(&[0x40, 0x09, 0x10, 0, 0, 0, 0, 0]);
    assert_eq!(&answer[..8], &[0x41, 0x09, 0x10, 0x00, 23, 0, 0, 0]);
    assert_eq!(&answer[8..], b"STM32F405 reference 1.0");
    assert!(!b.server.is_busy());
    assert_eq!(b.upload(0x1008, 0, false), b"OSD-402");
}

#[test]
fn segmented_upload_of_a_string_longer_than_the_mailbox() {
    // Mailbox 20 bytes: 4 data bytes in the initiate answer, 11 per segment, last segment 8 bytes.
    let mut b = Bench::new(20);
    assert_eq!(b.upload(0x1009, 0, false), b"STM32F405 reference 1.0");
    // Mailbox 22: 6 + 13 + 4, the last segment short (n = 3, padded to 8 bytes).
    let mut b = Bench::new(22);
    let answer = b.send(&[0x40, 0x09, 0x10, 0, 0, 0, 0, 0]);
    assert_eq!(answer.len(), 14);
    assert_eq!(&answer[8..], b"STM32F");
    assert_eq!(b.send(&[0x60, 0, 0, 0, 0, 0, 0, 0]), [&[0x00][..], b"405 reference"].concat());
    assert_eq!(b.send(&[0x70, 0, 0, 0, 0, 0, 0, 0]), [0x10 | (3 << 1) | 1, b' ', b'1', b'.', b'0', 0, 0, 0]);
    assert!(!b.server.is_busy());
    // Toggle error.
    b.send(&[0x40, 0x09, 0x10, 0, 0, 0, 0, 0]);
    assert_eq!(b.abort_code(&[0x70, 0, 0, 0, 0, 0, 0, 0]), SdoAbort::ToggleBit.code());
    assert!(!b.server.is_busy());
}

#[test]
fn expedited_normal_and_segmented_downloads() {
    let mut b = Bench::new(128);
    assert_eq!(b.send(&[0x23, 0x7A, 0x60, 0, 0x10, 0, 0, 0]), [0x60, 0x7A, 0x60, 0, 0, 0, 0, 0]);
    assert_eq!(b.dict.get(handles::TARGET_POSITION), 16);
    assert_eq!(b.download(0x607A, 0, false, &(-3i32).to_le_bytes()), Ok(()));
    assert_eq!(b.dict.get(handles::TARGET_POSITION), -3);
    // Program data: 100 bytes in one mailbox, then 1000 bytes in 120-byte segments.
    let program: Vec<u8> = (0..1000u32).map(|i| (i * 7) as u8).collect();
    assert_eq!(b.download(0x1F50, 1, false, &program[..100]), Ok(()));
    assert_eq!(b.app.program, &program[..100]);
    assert_eq!(b.download(0x1F50, 1, false, &program), Ok(()));
    assert_eq!(b.app.program, program);
    assert!(b.app.complete);
    // Errors surface as abort codes.
    assert_eq!(b.download(0x607A, 0, false, &[1, 2, 3, 4, 5]), Err(SdoAbort::LengthTooHigh.code()));
    assert_eq!(b.download(0x6041, 0, false, &[0, 0]), Err(SdoAbort::ReadOnly.code()));
    assert_eq!(b.abort_code(&[0x40, 0x00, 0x20, 0x08, 0, 0, 0, 0]), SdoAbort::SubindexDoesNotExist.code());
    assert_eq!(b.abort_code(&[0xE0, 0x00, 0x10, 0x00, 0, 0, 0, 0]), SdoAbort::CommandSpecifier.code());
}

#[test]
fn complete_access_read_of_rxpdo_1_mapping() {
    let mut b = Bench::new(128);
    // Sub-index 0 as UNSIGNED8 plus a padding byte (ETG.1020 §12.2), then the twelve UNSIGNED32 entries.
    let expected = mapping_image(2, &[0x6040_0010, 0x6060_0008]);
    assert_eq!(b.upload(0x1600, 0, true), expected);
    // From sub-index 1 (as ethercrab's complete access does): no sub-index 0.
    assert_eq!(b.upload(0x1600, 1, true), expected[2..]);
    // Through a small mailbox: segmented.
    let mut b = Bench::new(24);
    assert_eq!(b.upload(0x1600, 0, true), expected);
    // Objects of variable length and sub-indices above 1 cannot be accessed completely.
    assert_eq!(b.abort_code(&[0x50, 0x08, 0x10, 0, 0, 0, 0, 0]), SdoAbort::CompleteAccessUnsupported.code());
    assert_eq!(b.abort_code(&[0x50, 0x00, 0x16, 2, 0, 0, 0, 0]), SdoAbort::CompleteAccessUnsupported.code());
}

#[test]
fn complete_access_write_of_txpdo_1_mapping() {
    let mut b = Bench::new(128);
    let new = mapping_image(2, &[0x6041_0010, 0x6064_0020]);
    assert_eq!(b.download(0x1A00, 0, true, &new), Ok(()));
    assert_eq!(b.upload(0x1A00, 0, true), new);

    // Not in Operational (the mapping objects are writable in Pre-Operational only).
    let original = b.upload(0x1A00, 0, true);
    b.ctx = OP;
    assert_eq!(b.download(0x1A00, 0, true, &mapping_image(1, &[0x6041_0010])), Err(SdoAbort::DeviceState.code()));
    b.ctx = PRE_OP;
    assert_eq!(b.upload(0x1A00, 0, true), original);

    // An entry that cannot be mapped, or a mapping too long for the bus: nothing changes.
    let bad = mapping_image(2, &[0x6041_0010, 0x6040_0010]);
    assert_eq!(b.download(0x1A00, 0, true, &bad), Err(SdoAbort::CannotBeMapped.code()));
    assert_eq!(b.upload(0x1A00, 0, true), original);
    let long = mapping_image(11, &[0x6064_0020; 11]); // 44 bytes > the 40 of EtherCAT (IDX L2196)
    assert_eq!(b.download(0x1A00, 0, true, &long), Err(SdoAbort::PdoLengthExceeded.code()));
    assert_eq!(b.upload(0x1A00, 0, true), original);

    // Segmented through a small mailbox.
    let mut b = Bench::new(24);
    assert_eq!(b.download(0x1A00, 0, true, &new), Ok(()));
    assert_eq!(b.upload(0x1A00, 0, true), new);
    // Without sub-index 0 the entries may not change while the mapping is enabled (CiA 301 §7.5.2.36).
    assert_eq!(b.download(0x1A00, 1, true, &new[2..]), Err(SdoAbort::UnsupportedAccess.code()));
    // A length that ends inside an entry.
    assert_eq!(b.download(0x1A00, 0, true, &new[..5]), Err(SdoAbort::LengthTooLow.code()));
}

#[test]
fn a_new_initiate_and_a_client_abort_end_a_segmented_download() {
    let mut b = Bench::new(24);
    let program: Vec<u8> = (0..200u8).collect();
    let mut request = vec![0x21, 0x50, 0x1F, 0x01];
    request.extend_from_slice(&200u32.to_le_bytes());
    request.extend_from_slice(&program[..8]);
    assert_eq!(b.send(&request)[0], 0x60);
    assert!(b.server.is_busy());
    // A new upload is served; the download is discarded.
    assert_eq!(b.upload(0x1000, 0, false), generated::DEVICE_TYPE.to_le_bytes());
    assert!(b.app.aborted && !b.app.complete);
    b.app.aborted = false;
    assert_eq!(b.send(&request)[0], 0x60);
    assert_eq!(b.send(&[0x80, 0x50, 0x1F, 0x01, 0, 0, 0, 0x08]), Vec::<u8>::new());
    assert!(b.app.aborted && !b.server.is_busy());
}
