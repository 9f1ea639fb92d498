//! The SDO client (CiA 301 §7.2.4): expedited and segmented upload and download on the default SDO channel of a
//! node (requests on COB-ID 0x600 + node-ID, answers on 0x580 + node-ID, §7.3.5 Table 70), with a timeout per
//! answer and the server's abort code kept.

use std::fmt;
use std::time::{Duration, Instant};

use crate::abort_text::abort_text;
use firmware::comm::sdo::crc::Crc16;

use crate::bus::{CanInterface, Frame};

/// Why an SDO transfer failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SdoError {
    /// The server aborted the transfer with this code (CiA 301 §7.2.4.3.17).
    Abort(u32),
    /// No answer within the timeout.
    Timeout,
    /// The server answered something the protocol does not allow here.
    Protocol(String),
    /// The CAN interface failed.
    Bus(String),
    /// The EtherCAT mailbox failed (datagram lost, working counter wrong, mailbox error).
    Mailbox(String),
}

impl From<String> for SdoError {
    /// A failure of the EtherCAT mailbox under the transfer.
    fn from(why: String) -> Self {
        Self::Mailbox(why)
    }
}

impl fmt::Display for SdoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Abort(code) => write!(f, "SDO abort 0x{code:08X}: {}", abort_text(*code)),
            Self::Timeout => write!(f, "no SDO answer (timeout)"),
            Self::Protocol(why) => write!(f, "SDO protocol error: {why}"),
            Self::Bus(why) => write!(f, "CAN interface: {why}"),
            Self::Mailbox(why) => write!(f, "EtherCAT mailbox: {why}"),
        }
    }
}

/// The SDO client of one CAN interface.
pub struct SdoClient<'a> {
    bus: &'a mut dyn CanInterface,
    /// Longest wait for one answer of the server.
    pub timeout: Duration,
}

/// Client command specifiers (CiA 301 §7.2.4.3): bits 7..5 of byte 0.
const CCS_DOWNLOAD_SEGMENT: u8 = 0 << 5;
const CCS_INITIATE_DOWNLOAD: u8 = 1 << 5;
const CCS_INITIATE_UPLOAD: u8 = 2 << 5;
const CCS_UPLOAD_SEGMENT: u8 = 3 << 5;
const CS_ABORT: u8 = 4 << 5;

impl<'a> SdoClient<'a> {
    /// A client on `bus` waiting `timeout` for each answer.
    pub fn new(bus: &'a mut dyn CanInterface, timeout: Duration) -> Self {
        Self { bus, timeout }
    }

    fn send(&mut self, node: u8, data: [u8; 8]) -> Result<(), SdoError> {
        self.bus.send(&Frame::new(0x600 + u16::from(node), &data)).map_err(|e| SdoError::Bus(e.to_string()))
    }

    /// The server's next answer (8 bytes on 0x580 + node); an abort becomes [`SdoError::Abort`].
    fn answer(&mut self, node: u8) -> Result<[u8; 8], SdoError> {
        let deadline = Instant::now() + self.timeout;
        let cob_id = 0x580 + u16::from(node);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(SdoError::Timeout);
            }
            let Some(frame) = self.bus.recv(left).map_err(|e| SdoError::Bus(e.to_string()))? else { continue };
            if frame.id != cob_id {
                continue;
            }
            let Ok(bytes) = <[u8; 8]>::try_from(frame.data.as_slice()) else {
                return Err(SdoError::Protocol(format!("an answer of {} bytes, not 8", frame.data.len())));
            };
            if bytes[0] == CS_ABORT {
                return Err(SdoError::Abort(u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]])));
            }
            return Ok(bytes);
        }
    }

    /// Aborts the transfer on our side (so the server frees its channel), ignoring send errors.
    fn abort(&mut self, node: u8, index: u16, sub: u8, code: u32) {
        let [i0, i1] = index.to_le_bytes();
        let [c0, c1, c2, c3] = code.to_le_bytes();
        let _ = self.send(node, [CS_ABORT, i0, i1, sub, c0, c1, c2, c3]);
    }

    fn check_multiplexer(&mut self, node: u8, index: u16, sub: u8, answer: &[u8; 8]) -> Result<(), SdoError> {
        if u16::from_le_bytes([answer[1], answer[2]]) != index || answer[3] != sub {
            self.abort(node, index, sub, 0x0800_0000);
            return Err(SdoError::Protocol(format!(
                "answer for 0x{:04X}:{:02X}, asked for 0x{index:04X}:{sub:02X}",
                u16::from_le_bytes([answer[1], answer[2]]),
                answer[3]
            )));
        }
        Ok(())
    }

    /// The expedited or segmented upload, without the abort after a timeout.
    fn upload_unguarded(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        let [i0, i1] = index.to_le_bytes();
        self.send(node, [CCS_INITIATE_UPLOAD, i0, i1, sub, 0, 0, 0, 0])?;
        let answer = self.answer(node)?;
        if answer[0] & 0xE0 != 2 << 5 {
            self.abort(node, index, sub, 0x0504_0001);
            return Err(SdoError::Protocol(format!("initiate upload answered with 0x{:02X}", answer[0])));
        }
        self.check_multiplexer(node, index, sub, &answer)?;
        let expedited = answer[0] & 0x02 != 0;
        let size_indicated = answer[0] & 0x01 != 0;
        if expedited {
            let len = if size_indicated { 4 - usize::from((answer[0] >> 2) & 0x03) } else { 4 };
            return Ok(answer[4..4 + len].to_vec());
        }
        let size = size_indicated.then(|| u32::from_le_bytes([answer[4], answer[5], answer[6], answer[7]]) as usize);
        let mut data = Vec::with_capacity(size.unwrap_or(64));
        let mut toggle = 0u8;
        loop {
            self.send(node, [CCS_UPLOAD_SEGMENT | toggle << 4, 0, 0, 0, 0, 0, 0, 0])?;
            let seg = self.answer(node)?;
            if seg[0] & 0xE0 != 0 {
                self.abort(node, index, sub, 0x0504_0001);
                return Err(SdoError::Protocol(format!("upload segment answered with 0x{:02X}", seg[0])));
            }
            if (seg[0] >> 4) & 1 != toggle {
                self.abort(node, index, sub, 0x0503_0000);
                return Err(SdoError::Protocol("toggle bit not alternated".into()));
            }
            let unused = usize::from((seg[0] >> 1) & 0x07);
            data.extend_from_slice(&seg[1..8 - unused]);
            if seg[0] & 0x01 != 0 {
                break;
            }
            toggle ^= 1;
            if data.len() > 1 << 24 {
                self.abort(node, index, sub, 0x0504_0005);
                return Err(SdoError::Protocol("more than 16 MiB uploaded".into()));
            }
        }
        if let Some(size) = size {
            if size != data.len() {
                return Err(SdoError::Protocol(format!("{} bytes received, {size} announced", data.len())));
            }
        }
        Ok(data)
    }

    /// The expedited or segmented download, without the abort after a timeout.
    fn download_unguarded(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        let [i0, i1] = index.to_le_bytes();
        if data.len() <= 4 && !data.is_empty() {
            let mut frame = [CCS_INITIATE_DOWNLOAD | ((4 - data.len() as u8) << 2) | 0x03, i0, i1, sub, 0, 0, 0, 0];
            frame[4..4 + data.len()].copy_from_slice(data);
            self.send(node, frame)?;
            let answer = self.answer(node)?;
            if answer[0] & 0xE0 != 3 << 5 {
                return Err(SdoError::Protocol(format!("initiate download answered with 0x{:02X}", answer[0])));
            }
            return self.check_multiplexer(node, index, sub, &answer);
        }
        let [s0, s1, s2, s3] = u32::try_from(data.len())
            .map_err(|_| SdoError::Protocol("more than 4 GiB to download".into()))?
            .to_le_bytes();
        self.send(node, [CCS_INITIATE_DOWNLOAD | 0x01, i0, i1, sub, s0, s1, s2, s3])?;
        let answer = self.answer(node)?;
        if answer[0] & 0xE0 != 3 << 5 {
            return Err(SdoError::Protocol(format!("initiate download answered with 0x{:02X}", answer[0])));
        }
        self.check_multiplexer(node, index, sub, &answer)?;
        let mut toggle = 0u8;
        let mut chunks = data.chunks(7).peekable();
        while let Some(chunk) = chunks.next() {
            let last = u8::from(chunks.peek().is_none());
            let mut frame =
                [CCS_DOWNLOAD_SEGMENT | toggle << 4 | ((7 - chunk.len() as u8) << 1) | last, 0, 0, 0, 0, 0, 0, 0];
            frame[1..1 + chunk.len()].copy_from_slice(chunk);
            self.send(node, frame)?;
            let seg = self.answer(node)?;
            if seg[0] & 0xE0 != 1 << 5 {
                self.abort(node, index, sub, 0x0504_0001);
                return Err(SdoError::Protocol(format!("download segment answered with 0x{:02X}", seg[0])));
            }
            if (seg[0] >> 4) & 1 != toggle {
                self.abort(node, index, sub, 0x0503_0000);
                return Err(SdoError::Protocol("toggle bit not alternated".into()));
            }
            toggle ^= 1;
        }
        Ok(())
    }
}

impl SdoClient<'_> {
    /// After a timeout the client aborts the transfer with 0x0504_0000 (CiA 301 §7.2.4.3.17), so that a server
    /// still in the middle of it frees its channel for the next request.
    fn guarded<T>(&mut self, node: u8, index: u16, sub: u8, result: Result<T, SdoError>) -> Result<T, SdoError> {
        if matches!(result, Err(SdoError::Timeout)) {
            self.abort(node, index, sub, 0x0504_0000);
        }
        result
    }

    /// Uploads (reads) object `index:sub` of `node`: expedited or segmented, as the server chooses
    /// (CiA 301 §7.2.4.3.4..7).
    pub fn upload(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        let result = self.upload_unguarded(node, index, sub);
        self.guarded(node, index, sub, result)
    }

    /// Downloads (writes) `data` to `index:sub` of `node`: expedited up to 4 bytes, segmented above
    /// (CiA 301 §7.2.4.3.1..3), the size always indicated.
    pub fn download(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        let result = self.download_unguarded(node, index, sub, data);
        self.guarded(node, index, sub, result)
    }

    /// [`SdoClient::upload`] by block transfer (CiA 301 §7.2.4.3.14..16).
    pub fn block_upload(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        let result = self.block_upload_unguarded(node, index, sub);
        self.guarded(node, index, sub, result)
    }

    /// [`SdoClient::download`] by block transfer (CiA 301 §7.2.4.3.9..13).
    pub fn block_download(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        self.block_download_with_progress(node, index, sub, data, &mut |_| {})
    }

    /// [`SdoClient::block_download`], telling `progress` the bytes the server has acknowledged after every
    /// sub-block.
    pub fn block_download_with_progress(
        &mut self,
        node: u8,
        index: u16,
        sub: u8,
        data: &[u8],
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), SdoError> {
        let result = self.block_download_unguarded(node, index, sub, data, progress);
        self.guarded(node, index, sub, result)
    }
}

/// Block transfers (CiA 301 §7.2.4.3.9..16): the client's block size and its sub-commands.
const BLOCK_SIZE: u8 = 127;
const CCS_BLOCK_UPLOAD: u8 = 5 << 5;
const CCS_BLOCK_DOWNLOAD: u8 = 6 << 5;
/// Block sub-commands of the client (bits 1..0 of byte 0 for upload, bit 0 for download).
const BLOCK_UPLOAD_START: u8 = 0x03;
const BLOCK_ACK: u8 = 0x02;
const BLOCK_END: u8 = 0x01;

impl SdoClient<'_> {
    /// Uploads `index:sub` of `node` by block transfer (CiA 301 §7.2.4.3.14..16), with the CRC when the server
    /// offers it: initiate with our block size, start, sub-blocks of up to [`BLOCK_SIZE`] segments each
    /// acknowledged with the last in-sequence number (the server repeats the rest), end with the unused bytes
    /// of the last segment and the CRC.
    fn block_upload_unguarded(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        let [i0, i1] = index.to_le_bytes();
        // cc = 1 (we check a CRC); pst = 0 (no switch to segmented for small objects).
        self.send(node, [CCS_BLOCK_UPLOAD | 0x04, i0, i1, sub, BLOCK_SIZE, 0, 0, 0])?;
        let answer = self.answer(node)?;
        if answer[0] & 0xE1 != 6 << 5 {
            self.abort(node, index, sub, 0x0504_0001);
            return Err(SdoError::Protocol(format!("block upload initiate answered with 0x{:02X}", answer[0])));
        }
        self.check_multiplexer(node, index, sub, &answer)?;
        let server_crc = answer[0] & 0x04 != 0;
        let size =
            (answer[0] & 0x02 != 0).then(|| u32::from_le_bytes([answer[4], answer[5], answer[6], answer[7]]) as usize);
        self.send(node, [CCS_BLOCK_UPLOAD | BLOCK_UPLOAD_START, 0, 0, 0, 0, 0, 0, 0])?;
        let mut data: Vec<u8> = Vec::new();
        loop {
            // One sub-block: segments 1..=BLOCK_SIZE; it ends with segment BLOCK_SIZE or one with c = 1. Only
            // segments in sequence are kept; the acknowledgement names the last of them, and the server repeats
            // the rest in the next sub-block.
            let mut good = 0u8;
            let mut last = false;
            loop {
                let seg = self.answer(node)?;
                let seqno = seg[0] & 0x7F;
                let final_segment = seg[0] & 0x80 != 0;
                if seqno == good + 1 {
                    good = seqno;
                    data.extend_from_slice(&seg[1..8]);
                    last = final_segment;
                }
                if final_segment || seqno == BLOCK_SIZE {
                    break;
                }
            }
            self.send(node, [CCS_BLOCK_UPLOAD | BLOCK_ACK, good, BLOCK_SIZE, 0, 0, 0, 0, 0])?;
            if last {
                break;
            }
            if data.len() > 1 << 24 {
                self.abort(node, index, sub, 0x0504_0005);
                return Err(SdoError::Protocol("more than 16 MiB uploaded".into()));
            }
        }
        let end = self.answer(node)?;
        if end[0] & 0xE3 != (6 << 5) | BLOCK_END {
            self.abort(node, index, sub, 0x0504_0001);
            return Err(SdoError::Protocol(format!("block upload end answered with 0x{:02X}", end[0])));
        }
        let unused = usize::from((end[0] >> 2) & 0x07);
        data.truncate(data.len().saturating_sub(unused));
        if server_crc {
            let crc = u16::from_le_bytes([end[1], end[2]]);
            if crc != Crc16::of(&data) {
                self.abort(node, index, sub, 0x0504_0004);
                return Err(SdoError::Protocol(format!(
                    "CRC 0x{crc:04X} does not match the data's 0x{:04X}",
                    Crc16::of(&data)
                )));
            }
        }
        self.send(node, [CCS_BLOCK_UPLOAD | BLOCK_END, 0, 0, 0, 0, 0, 0, 0])?;
        if let Some(size) = size {
            if size != data.len() {
                return Err(SdoError::Protocol(format!("{} bytes received, {size} announced", data.len())));
            }
        }
        Ok(data)
    }

    /// Downloads `data` to `index:sub` of `node` by block transfer (CiA 301 §7.2.4.3.9..13), size indicated and
    /// the CRC given: sub-blocks of the server's block size, resent from the server's acknowledged sequence
    /// number when it missed a segment.
    fn block_download_unguarded(
        &mut self,
        node: u8,
        index: u16,
        sub: u8,
        data: &[u8],
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), SdoError> {
        let [i0, i1] = index.to_le_bytes();
        let [s0, s1, s2, s3] = u32::try_from(data.len())
            .map_err(|_| SdoError::Protocol("more than 4 GiB to download".into()))?
            .to_le_bytes();
        // cc = 1 (we give a CRC), s = 1 (size indicated).
        self.send(node, [CCS_BLOCK_DOWNLOAD | 0x04 | 0x02, i0, i1, sub, s0, s1, s2, s3])?;
        let answer = self.answer(node)?;
        if answer[0] & 0xE3 != 5 << 5 {
            self.abort(node, index, sub, 0x0504_0001);
            return Err(SdoError::Protocol(format!("block download initiate answered with 0x{:02X}", answer[0])));
        }
        self.check_multiplexer(node, index, sub, &answer)?;
        let mut blksize = answer[4];
        let segments: Vec<&[u8]> = if data.is_empty() { vec![&[][..]] } else { data.chunks(7).collect() };
        let mut next = 0usize;
        while next < segments.len() {
            if !(1..=127).contains(&blksize) {
                self.abort(node, index, sub, 0x0504_0002);
                return Err(SdoError::Protocol(format!("block size {blksize} from the server")));
            }
            let in_block = usize::from(blksize).min(segments.len() - next);
            for k in 0..in_block {
                let chunk = segments[next + k];
                let last = next + k + 1 == segments.len();
                let mut frame = [(k as u8 + 1) | if last { 0x80 } else { 0 }, 0, 0, 0, 0, 0, 0, 0];
                frame[1..1 + chunk.len()].copy_from_slice(chunk);
                self.send(node, frame)?;
            }
            let ack = self.answer(node)?;
            if ack[0] & 0xE3 != (5 << 5) | BLOCK_ACK {
                self.abort(node, index, sub, 0x0504_0001);
                return Err(SdoError::Protocol(format!("sub-block answered with 0x{:02X}", ack[0])));
            }
            // ackseq: the last segment the server took in sequence; the rest of the sub-block is sent again.
            next += usize::from(ack[1]).min(in_block);
            blksize = ack[2];
            progress((next * 7).min(data.len()));
        }
        let unused = segments.last().map_or(7, |s| 7 - s.len()) as u8;
        let [c0, c1] = Crc16::of(data).to_le_bytes();
        self.send(node, [CCS_BLOCK_DOWNLOAD | unused << 2 | BLOCK_END, c0, c1, 0, 0, 0, 0, 0])?;
        let end = self.answer(node)?;
        if end[0] & 0xE3 != (5 << 5) | BLOCK_END {
            return Err(SdoError::Protocol(format!("block download end answered with 0x{:02X}", end[0])));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    /// A scripted server: every sent frame is recorded, answers come from a queue.
    struct Script {
        sent: Vec<Frame>,
        answers: VecDeque<Frame>,
    }

    impl CanInterface for Script {
        fn send(&mut self, frame: &Frame) -> std::io::Result<()> {
            self.sent.push(frame.clone());
            Ok(())
        }
        fn recv(&mut self, _: Duration) -> std::io::Result<Option<Frame>> {
            Ok(self.answers.pop_front())
        }
    }

    fn script(answers: &[[u8; 8]]) -> Script {
        Script { sent: Vec::new(), answers: answers.iter().map(|a| Frame::new(0x585, a)).collect() }
    }

    #[test]
    fn expedited_upload_takes_the_indicated_size() {
        // CiA 301 §7.2.4.3.5: scs 2, e = 1, s = 1, n = 2 -> 2 bytes.
        let mut bus = script(&[[0x4B, 0x41, 0x60, 0x00, 0x37, 0x02, 0xFF, 0xFF]]);
        let got = SdoClient::new(&mut bus, Duration::from_millis(1)).upload(5, 0x6041, 0);
        assert_eq!(got, Ok(vec![0x37, 0x02]));
        assert_eq!(bus.sent, vec![Frame::new(0x605, &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0])]);
    }

    #[test]
    fn segmented_upload_joins_the_segments_and_alternates_the_toggle() {
        // "OSD-402-X" (9 bytes): initiate with size 9, a segment of 7, a last one of 2 (n = 5, c = 1, t = 1).
        let mut bus = script(&[
            [0x41, 0x08, 0x10, 0x00, 9, 0, 0, 0],
            [0x00, b'O', b'S', b'D', b'-', b'4', b'0', b'2'],
            [0x10 | 5 << 1 | 1, b'-', b'X', 0, 0, 0, 0, 0],
        ]);
        let got = SdoClient::new(&mut bus, Duration::from_millis(1)).upload(5, 0x1008, 0);
        assert_eq!(got.as_deref(), Ok(&b"OSD-402-X"[..]));
        assert_eq!(bus.sent[1].data[0], 0x60);
        assert_eq!(bus.sent[2].data[0], 0x70);
    }

    #[test]
    fn an_abort_keeps_its_code() {
        let mut bus = script(&[[0x80, 0x00, 0x10, 0x00, 0x02, 0x00, 0x01, 0x06]]);
        let got = SdoClient::new(&mut bus, Duration::from_millis(1)).download(5, 0x1000, 0, &[1, 2, 3, 4]);
        assert_eq!(got, Err(SdoError::Abort(0x0601_0002)));
        assert_eq!(bus.sent[0].data, vec![0x23, 0x00, 0x10, 0x00, 1, 2, 3, 4]);
    }

    #[test]
    fn segmented_download_sends_sevens_and_marks_the_last() {
        let mut bus =
            script(&[[0x60, 0x08, 0x10, 0, 0, 0, 0, 0], [0x20, 0, 0, 0, 0, 0, 0, 0], [0x30, 0, 0, 0, 0, 0, 0, 0]]);
        SdoClient::new(&mut bus, Duration::from_millis(1)).download(5, 0x1008, 0, b"0123456789").expect("download");
        assert_eq!(bus.sent[0].data, vec![0x21, 0x08, 0x10, 0, 10, 0, 0, 0]);
        assert_eq!(bus.sent[1].data, b"\x000123456".to_vec());
        assert_eq!(bus.sent[2].data, vec![0x10 | 4 << 1 | 1, b'7', b'8', b'9', 0, 0, 0, 0]);
    }

    #[test]
    fn block_download_resends_from_the_acknowledged_segment_and_ends_with_the_crc() {
        // CiA 301 §7.2.4.3.10: the server took segment 1 of 2 only (ackseq 1); segment 2 goes again as
        // sequence number 1 of the next sub-block, with c = 1; the end carries n = 4 unused bytes and the CRC.
        let mut bus = script(&[
            [0xA4, 0x65, 0x60, 0x00, 127, 0, 0, 0],
            [0xA2, 1, 127, 0, 0, 0, 0, 0],
            [0xA2, 1, 127, 0, 0, 0, 0, 0],
            [0xA1, 0, 0, 0, 0, 0, 0, 0],
        ]);
        let data = b"0123456789";
        SdoClient::new(&mut bus, Duration::from_millis(1)).block_download(5, 0x6065, 0, data).expect("download");
        let firsts: Vec<u8> = bus.sent.iter().map(|f| f.data[0]).collect();
        assert_eq!(firsts, vec![0xC6, 0x01, 0x82, 0x81, 0xC1 | 4 << 2]);
        assert_eq!(bus.sent[0].data[4..8], [10, 0, 0, 0], "size indicated");
        assert_eq!(bus.sent[3].data[1..4], *b"789");
        assert_eq!(u16::from_le_bytes([bus.sent[4].data[1], bus.sent[4].data[2]]), Crc16::of(data));
    }

    #[test]
    fn block_upload_keeps_segments_in_sequence_and_checks_the_crc() {
        let data = b"OSD-402-X";
        let [c0, c1] = Crc16::of(data).to_le_bytes();
        let mut bus = script(&[
            [0xC6, 0x08, 0x10, 0x00, 9, 0, 0, 0],
            [0x01, b'O', b'S', b'D', b'-', b'4', b'0', b'2'],
            [0x82, b'-', b'X', 0, 0, 0, 0, 0],
            [0xC1 | 5 << 2, c0, c1, 0, 0, 0, 0, 0],
        ]);
        let got = SdoClient::new(&mut bus, Duration::from_millis(1)).block_upload(5, 0x1008, 0);
        assert_eq!(got.as_deref(), Ok(&data[..]));
        let firsts: Vec<u8> = bus.sent.iter().map(|f| f.data[0]).collect();
        assert_eq!(firsts, vec![0xA4, 0xA3, 0xA2, 0xA1]);
        assert_eq!(bus.sent[2].data[1], 2, "acknowledged up to segment 2");
        let mut bad = script(&[
            [0xC6, 0x08, 0x10, 0x00, 9, 0, 0, 0],
            [0x01, b'O', b'S', b'D', b'-', b'4', b'0', b'2'],
            [0x82, b'-', b'X', 0, 0, 0, 0, 0],
            [0xC1 | 5 << 2, c0 ^ 1, c1, 0, 0, 0, 0, 0],
        ]);
        let got = SdoClient::new(&mut bad, Duration::from_millis(1)).block_upload(5, 0x1008, 0);
        assert!(matches!(got, Err(SdoError::Protocol(ref why)) if why.contains("CRC")), "{got:?}");
        assert_eq!(bad.sent.last().map(|f| f.data.clone()), Some(vec![0x80, 0x08, 0x10, 0x00, 0x04, 0x00, 0x04, 0x05]));
    }

    #[test]
    fn no_answer_is_a_timeout_and_the_client_aborts_the_transfer() {
        let mut bus = script(&[]);
        assert_eq!(SdoClient::new(&mut bus, Duration::from_millis(5)).upload(5, 0x1000, 0), Err(SdoError::Timeout));
        assert_eq!(bus.sent.last().map(|f| f.data.clone()), Some(vec![0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]));
    }
}
