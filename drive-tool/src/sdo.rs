//! The SDO client (CiA 301 §7.2.4): expedited and segmented upload and download on the default SDO channel of a
//! node (requests on COB-ID 0x600 + node-ID, answers on 0x580 + node-ID, §7.3.5 Table 70), with a timeout per
//! answer and the server's abort code kept.

use std::fmt;
use std::time::{Duration, Instant};

use crate::abort_text::abort_text;
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
}

impl fmt::Display for SdoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Abort(code) => write!(f, "SDO abort 0x{code:08X}: {}", abort_text(*code)),
            Self::Timeout => write!(f, "no SDO answer (timeout)"),
            Self::Protocol(why) => write!(f, "SDO protocol error: {why}"),
            Self::Bus(why) => write!(f, "CAN interface: {why}"),
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

    /// Uploads (reads) object `index:sub` of `node`: expedited or segmented, as the server chooses
    /// (CiA 301 §7.2.4.3.4..7).
    pub fn upload(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
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

    /// Downloads (writes) `data` to `index:sub` of `node`: expedited up to 4 bytes, segmented above
    /// (CiA 301 §7.2.4.3.1..3), the size always indicated.
    pub fn download(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
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
    fn no_answer_is_a_timeout() {
        let mut bus = script(&[]);
        assert_eq!(SdoClient::new(&mut bus, Duration::from_millis(5)).upload(5, 0x1000, 0), Err(SdoError::Timeout));
    }
}
