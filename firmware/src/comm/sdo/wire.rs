//! The CAN SDO frame (CiA 301 §7.2.4.3): eight data bytes, byte 0 the command specifier, bytes 1..3 the
//! multiplexer (index little-endian, sub-index) in initiate and abort frames, the rest data.
//!
//! [`SdoFrame`] is the zero-copy view (ARCHITECTURE convention 5, as smoltcp `wire`): [`SdoFrame::new_checked`]
//! accepts any buffer of at least eight bytes, and every accessor is then infallible. [`SdoRequest`] (client to
//! server) and [`SdoResponse`] (server to client) are the parsed representations with `emit`; a command byte
//! this module does not know parses as `Unknown(raw)`, so decoding never fails. [`BlockSegment`] is the
//! sub-block segment of a block transfer (CiA 301 §7.2.4.3.12/.15), which has no command specifier and is parsed
//! only where the protocol state says a segment is due.
//!
//! Command byte layouts (CiA 301 §7.2.4.3.3..7.2.4.3.17; the seeds show the expedited ones, EPOS4 Application
//! Notes Figures 5-32..5-34 and Table 5-45, seed 001 L2661-L2730):
//!
//! | service | client byte 0 | server byte 0 |
//! |---|---|---|
//! | initiate download | `001x nnes` | `0110 0000` |
//! | download segment | `000t nnnc` | `001t 0000` |
//! | initiate upload | `0100 0000` | `010x nnes` |
//! | upload segment | `011t 0000` | `000t nnnc` |
//! | abort | `1000 0000` | `1000 0000` |
//! | block download initiate / end | `110x xcs0` / `110n nnx1` | `1010 0c00` / `1010 0001` |
//! | block download sub-block ack | (segments) | `1010 0010` |
//! | block upload initiate / end / ack / start | `101x xc00` / `1010 0001` / `1010 0010` / `1010 0011` | `110x xcs0` / `110n nn01` |

/// Length of a CAN SDO frame (CiA 301 §7.2.4.3: DLC 8).
pub const FRAME_LEN: usize = 8;

/// Data bytes in one segment (CiA 301 §7.2.4.3.5/.7/.12).
pub const SEGMENT_DATA: usize = 7;

/// The largest number of segments in one block (CiA 301 §7.2.4.3.9: blksize 1..127).
pub const MAX_BLOCK_SIZE: u8 = 127;

/// A buffer too short for an SDO frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// Fewer than [`FRAME_LEN`] bytes.
    Truncated,
}

/// A zero-copy view of one CAN SDO frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdoFrame<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> SdoFrame<T> {
    /// Wraps `buffer` after checking it holds at least [`FRAME_LEN`] bytes (bytes past the eighth are ignored).
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        if buffer.as_ref().len() < FRAME_LEN {
            Err(WireError::Truncated)
        } else {
            Ok(Self { buffer })
        }
    }

    fn byte(&self, at: usize) -> u8 {
        self.buffer.as_ref().get(at).copied().unwrap_or(0)
    }

    /// Byte 0, the command specifier.
    pub fn command(&self) -> u8 {
        self.byte(0)
    }

    /// Bytes 1..2, the object index (initiate and abort frames).
    pub fn index(&self) -> u16 {
        u16::from_le_bytes([self.byte(1), self.byte(2)])
    }

    /// Byte 3, the sub-index (initiate and abort frames).
    pub fn sub(&self) -> u8 {
        self.byte(3)
    }

    /// Bytes 4..7 (expedited data, size, abort code).
    pub fn data4(&self) -> [u8; 4] {
        [self.byte(4), self.byte(5), self.byte(6), self.byte(7)]
    }

    /// Bytes 4..7 as a little-endian `u32`.
    pub fn u32_at_4(&self) -> u32 {
        u32::from_le_bytes(self.data4())
    }

    /// Bytes 1..7 (segment data).
    pub fn data7(&self) -> [u8; SEGMENT_DATA] {
        [self.byte(1), self.byte(2), self.byte(3), self.byte(4), self.byte(5), self.byte(6), self.byte(7)]
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }
}

/// How an initiate-download request carries its data (CiA 301 §7.2.4.3.3, bits e and s).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DownloadInit {
    /// e = 1: the data is in bytes 4..7; `len` is 4 - n when s = 1, `None` when the size is not indicated.
    Expedited {
        /// Bytes 4..7.
        data: [u8; 4],
        /// Number of valid bytes (1..=4) if indicated.
        len: Option<u8>,
    },
    /// e = 0: a segmented download follows; `size` is bytes 4..7 when s = 1.
    Segmented {
        /// Announced size in bytes, if indicated.
        size: Option<u32>,
    },
}

/// A request from the SDO client, by command specifier (CiA 301 §7.2.4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SdoRequest {
    /// ccs = 1: initiate download (§7.2.4.3.3).
    InitiateDownload {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Expedited data or segmented size.
        init: DownloadInit,
    },
    /// ccs = 0: download segment (§7.2.4.3.5).
    DownloadSegment {
        /// Toggle bit t.
        toggle: bool,
        /// Bytes 1..7.
        data: [u8; SEGMENT_DATA],
        /// Valid bytes (7 - n).
        len: u8,
        /// c: no more segments.
        last: bool,
    },
    /// ccs = 2: initiate upload (§7.2.4.3.6).
    InitiateUpload {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
    },
    /// ccs = 3: upload segment (§7.2.4.3.7).
    UploadSegment {
        /// Toggle bit t.
        toggle: bool,
    },
    /// cs = 4: abort transfer (§7.2.4.3.17).
    Abort {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Abort code (CiA 301 Table 22).
        code: u32,
    },
    /// ccs = 6, cs = 0: initiate block download (§7.2.4.3.9).
    BlockDownloadInitiate {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// cc: the client supports the CRC.
        crc: bool,
        /// Announced size (s = 1).
        size: Option<u32>,
    },
    /// ccs = 6, cs = 1: end block download (§7.2.4.3.13).
    BlockDownloadEnd {
        /// n: bytes of the last segment that carry no data (0..=7).
        unused: u8,
        /// The client's CRC (bytes 1..2), meaningful when both sides support it.
        crc: u16,
    },
    /// ccs = 5, cs = 0: initiate block upload (§7.2.4.3.14).
    BlockUploadInitiate {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// cc: the client supports the CRC.
        crc: bool,
        /// Segments per block the client accepts (byte 4).
        blksize: u8,
        /// Protocol switch threshold (byte 5).
        pst: u8,
    },
    /// ccs = 5, cs = 3: start the upload of the first sub-block (§7.2.4.3.14).
    BlockUploadStart,
    /// ccs = 5, cs = 2: acknowledge a sub-block (§7.2.4.3.15).
    BlockUploadAck {
        /// Sequence number of the last segment received correctly (0 = none).
        ackseq: u8,
        /// Segments in the next block.
        blksize: u8,
    },
    /// ccs = 5, cs = 1: end block upload (§7.2.4.3.16).
    BlockUploadEnd,
    /// A command byte this module does not know (answered with 0x0504_0001).
    Unknown(u8),
}

/// Bits 3..2 (n) of an expedited frame as a byte count 4 - n.
const fn expedited_len(command: u8) -> u8 {
    4u8.wrapping_sub((command >> 2) & 0x03)
}

/// Bits 3..1 (n) of a segment frame as a byte count 7 - n.
const fn segment_len(command: u8) -> u8 {
    7u8.wrapping_sub((command >> 1) & 0x07)
}

/// The multiplexer bytes 1..3.
fn put_mux(out: &mut [u8; FRAME_LEN], index: u16, sub: u8) {
    let [lo, hi] = index.to_le_bytes();
    out[1] = lo;
    out[2] = hi;
    out[3] = sub;
}

fn put4(out: &mut [u8; FRAME_LEN], data: [u8; 4]) {
    out[4..8].copy_from_slice(&data);
}

fn put7(out: &mut [u8; FRAME_LEN], data: [u8; SEGMENT_DATA]) {
    out[1..8].copy_from_slice(&data);
}

/// `data` with the bytes past `len` cleared (CiA 301 §7.2.4.3.6: bytes 8 - n..7 "do not contain data"; this
/// server sends them as 0).
fn mask4(data: [u8; 4], len: u8) -> [u8; 4] {
    let mut masked = [0u8; 4];
    for (i, (to, from)) in masked.iter_mut().zip(data).enumerate() {
        if i < usize::from(len) {
            *to = from;
        }
    }
    masked
}

/// Clamps a byte count to 0..=max.
fn clamp(len: u8, max: u8) -> u8 {
    len.min(max)
}

impl SdoRequest {
    /// Decodes a client frame (never fails: unknown command bytes give [`SdoRequest::Unknown`]).
    pub fn parse<T: AsRef<[u8]>>(frame: &SdoFrame<T>) -> Self {
        let cmd = frame.command();
        let (index, sub) = (frame.index(), frame.sub());
        match cmd >> 5 {
            0 => Self::DownloadSegment {
                toggle: cmd & 0x10 != 0,
                data: frame.data7(),
                len: segment_len(cmd),
                last: cmd & 0x01 != 0,
            },
            1 => {
                let init = match (cmd & 0x02 != 0, cmd & 0x01 != 0) {
                    (true, true) => DownloadInit::Expedited { data: frame.data4(), len: Some(expedited_len(cmd)) },
                    (true, false) => DownloadInit::Expedited { data: frame.data4(), len: None },
                    (false, true) => DownloadInit::Segmented { size: Some(frame.u32_at_4()) },
                    (false, false) => DownloadInit::Segmented { size: None },
                };
                Self::InitiateDownload { index, sub, init }
            }
            2 => Self::InitiateUpload { index, sub },
            3 => Self::UploadSegment { toggle: cmd & 0x10 != 0 },
            4 => Self::Abort { index, sub, code: frame.u32_at_4() },
            5 => match cmd & 0x03 {
                0 => Self::BlockUploadInitiate {
                    index,
                    sub,
                    crc: cmd & 0x04 != 0,
                    blksize: frame.byte(4),
                    pst: frame.byte(5),
                },
                1 => Self::BlockUploadEnd,
                2 => Self::BlockUploadAck { ackseq: frame.byte(1), blksize: frame.byte(2) },
                _ => Self::BlockUploadStart,
            },
            6 => {
                if cmd & 0x01 == 0 {
                    let size = if cmd & 0x02 != 0 { Some(frame.u32_at_4()) } else { None };
                    Self::BlockDownloadInitiate { index, sub, crc: cmd & 0x04 != 0, size }
                } else {
                    Self::BlockDownloadEnd {
                        unused: (cmd >> 2) & 0x07,
                        crc: u16::from_le_bytes([frame.byte(1), frame.byte(2)]),
                    }
                }
            }
            _ => Self::Unknown(cmd),
        }
    }

    /// Encodes the request into `out` (reserved bytes 0).
    pub fn emit(&self, out: &mut [u8; FRAME_LEN]) {
        *out = [0; FRAME_LEN];
        match *self {
            Self::InitiateDownload { index, sub, init } => {
                put_mux(out, index, sub);
                out[0] = match init {
                    DownloadInit::Expedited { data, len } => {
                        put4(out, data);
                        match len {
                            Some(len) => 0x23 | (4u8.wrapping_sub(clamp(len, 4).max(1)) << 2),
                            None => 0x22,
                        }
                    }
                    DownloadInit::Segmented { size: Some(size) } => {
                        put4(out, size.to_le_bytes());
                        0x21
                    }
                    DownloadInit::Segmented { size: None } => 0x20,
                };
            }
            Self::DownloadSegment { toggle, data, len, last } => {
                put7(out, data);
                out[0] = (u8::from(toggle) << 4) | (7u8.wrapping_sub(clamp(len, 7)) << 1) | u8::from(last);
            }
            Self::InitiateUpload { index, sub } => {
                put_mux(out, index, sub);
                out[0] = 0x40;
            }
            Self::UploadSegment { toggle } => out[0] = 0x60 | (u8::from(toggle) << 4),
            Self::Abort { index, sub, code } => {
                put_mux(out, index, sub);
                put4(out, code.to_le_bytes());
                out[0] = 0x80;
            }
            Self::BlockDownloadInitiate { index, sub, crc, size } => {
                put_mux(out, index, sub);
                out[0] = 0xC0 | (u8::from(crc) << 2);
                if let Some(size) = size {
                    put4(out, size.to_le_bytes());
                    out[0] |= 0x02;
                }
            }
            Self::BlockDownloadEnd { unused, crc } => {
                let [lo, hi] = crc.to_le_bytes();
                out[0] = 0xC1 | (clamp(unused, 7) << 2);
                out[1] = lo;
                out[2] = hi;
            }
            Self::BlockUploadInitiate { index, sub, crc, blksize, pst } => {
                put_mux(out, index, sub);
                out[0] = 0xA0 | (u8::from(crc) << 2);
                out[4] = blksize;
                out[5] = pst;
            }
            Self::BlockUploadStart => out[0] = 0xA3,
            Self::BlockUploadAck { ackseq, blksize } => {
                out[0] = 0xA2;
                out[1] = ackseq;
                out[2] = blksize;
            }
            Self::BlockUploadEnd => out[0] = 0xA1,
            Self::Unknown(raw) => out[0] = raw,
        }
    }
}

/// A response of the SDO server, by command specifier (CiA 301 §7.2.4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SdoResponse {
    /// scs = 3: initiate download response (§7.2.4.3.3).
    InitiateDownload {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
    },
    /// scs = 1: download segment response (§7.2.4.3.5).
    DownloadSegment {
        /// Toggle bit t (echoed).
        toggle: bool,
    },
    /// scs = 2, e = 1, s = 1: expedited upload with 1..=4 bytes (§7.2.4.3.6).
    UploadExpedited {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Bytes 4..7.
        data: [u8; 4],
        /// Valid bytes (4 - n).
        len: u8,
    },
    /// scs = 2, e = 0, s = 1: a segmented upload of `size` bytes follows (§7.2.4.3.6).
    UploadSegmented {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Size in bytes.
        size: u32,
    },
    /// scs = 0: upload segment (§7.2.4.3.7).
    UploadSegment {
        /// Toggle bit t (echoed).
        toggle: bool,
        /// Bytes 1..7.
        data: [u8; SEGMENT_DATA],
        /// Valid bytes (7 - n).
        len: u8,
        /// c: no more segments.
        last: bool,
    },
    /// cs = 4: abort transfer (§7.2.4.3.17).
    Abort {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Abort code (CiA 301 Table 22).
        code: u32,
    },
    /// scs = 5, ss = 0: initiate block download response (§7.2.4.3.9).
    BlockDownloadInitiate {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// sc: the server supports the CRC.
        crc: bool,
        /// Segments per block the server accepts.
        blksize: u8,
    },
    /// scs = 5, ss = 2: sub-block acknowledged (§7.2.4.3.12).
    BlockDownloadAck {
        /// Last sequence number received correctly.
        ackseq: u8,
        /// Segments in the next block.
        blksize: u8,
    },
    /// scs = 5, ss = 1: end block download response (§7.2.4.3.13).
    BlockDownloadEnd,
    /// scs = 6, ss = 0: initiate block upload response (§7.2.4.3.14).
    BlockUploadInitiate {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// sc: the server supports the CRC.
        crc: bool,
        /// Size in bytes, if indicated.
        size: Option<u32>,
    },
    /// scs = 6, ss = 1: end block upload (§7.2.4.3.16).
    BlockUploadEnd {
        /// n: bytes of the last segment that carry no data.
        unused: u8,
        /// CRC of the data.
        crc: u16,
    },
    /// A command byte this module does not know.
    Unknown(u8),
}

impl SdoResponse {
    /// Decodes a server frame (for clients and tests; never fails). Block-upload segments carry no command
    /// specifier: decode them with [`BlockSegment::parse`].
    pub fn parse<T: AsRef<[u8]>>(frame: &SdoFrame<T>) -> Self {
        let cmd = frame.command();
        let (index, sub) = (frame.index(), frame.sub());
        match cmd >> 5 {
            0 => Self::UploadSegment {
                toggle: cmd & 0x10 != 0,
                data: frame.data7(),
                len: segment_len(cmd),
                last: cmd & 0x01 != 0,
            },
            1 => Self::DownloadSegment { toggle: cmd & 0x10 != 0 },
            2 => match (cmd & 0x02 != 0, cmd & 0x01 != 0) {
                (true, true) => {
                    let len = expedited_len(cmd);
                    Self::UploadExpedited { index, sub, data: mask4(frame.data4(), len), len }
                }
                (true, false) => Self::UploadExpedited { index, sub, data: frame.data4(), len: 4 },
                (false, _) => Self::UploadSegmented { index, sub, size: frame.u32_at_4() },
            },
            3 => Self::InitiateDownload { index, sub },
            4 => Self::Abort { index, sub, code: frame.u32_at_4() },
            5 => match cmd & 0x03 {
                0 => Self::BlockDownloadInitiate { index, sub, crc: cmd & 0x04 != 0, blksize: frame.byte(4) },
                1 => Self::BlockDownloadEnd,
                2 => Self::BlockDownloadAck { ackseq: frame.byte(1), blksize: frame.byte(2) },
                _ => Self::Unknown(cmd),
            },
            6 => match cmd & 0x01 {
                0 => Self::BlockUploadInitiate {
                    index,
                    sub,
                    crc: cmd & 0x04 != 0,
                    size: if cmd & 0x02 != 0 { Some(frame.u32_at_4()) } else { None },
                },
                _ => Self::BlockUploadEnd {
                    unused: (cmd >> 2) & 0x07,
                    crc: u16::from_le_bytes([frame.byte(1), frame.byte(2)]),
                },
            },
            _ => Self::Unknown(cmd),
        }
    }

    /// Encodes the response into `out` (reserved bytes 0).
    pub fn emit(&self, out: &mut [u8; FRAME_LEN]) {
        *out = [0; FRAME_LEN];
        match *self {
            Self::InitiateDownload { index, sub } => {
                put_mux(out, index, sub);
                out[0] = 0x60;
            }
            Self::DownloadSegment { toggle } => out[0] = 0x20 | (u8::from(toggle) << 4),
            Self::UploadExpedited { index, sub, data, len } => {
                put_mux(out, index, sub);
                let len = clamp(len, 4).max(1);
                put4(out, mask4(data, len));
                out[0] = 0x43 | (4u8.wrapping_sub(len) << 2);
            }
            Self::UploadSegmented { index, sub, size } => {
                put_mux(out, index, sub);
                put4(out, size.to_le_bytes());
                out[0] = 0x41;
            }
            Self::UploadSegment { toggle, data, len, last } => {
                put7(out, data);
                out[0] = (u8::from(toggle) << 4) | (7u8.wrapping_sub(clamp(len, 7)) << 1) | u8::from(last);
            }
            Self::Abort { index, sub, code } => {
                put_mux(out, index, sub);
                put4(out, code.to_le_bytes());
                out[0] = 0x80;
            }
            Self::BlockDownloadInitiate { index, sub, crc, blksize } => {
                put_mux(out, index, sub);
                out[0] = 0xA0 | (u8::from(crc) << 2);
                out[4] = blksize;
            }
            Self::BlockDownloadAck { ackseq, blksize } => {
                out[0] = 0xA2;
                out[1] = ackseq;
                out[2] = blksize;
            }
            Self::BlockDownloadEnd => out[0] = 0xA1,
            Self::BlockUploadInitiate { index, sub, crc, size } => {
                put_mux(out, index, sub);
                out[0] = 0xC0 | (u8::from(crc) << 2);
                if let Some(size) = size {
                    put4(out, size.to_le_bytes());
                    out[0] |= 0x02;
                }
            }
            Self::BlockUploadEnd { unused, crc } => {
                let [lo, hi] = crc.to_le_bytes();
                out[0] = 0xC1 | (clamp(unused, 7) << 2);
                out[1] = lo;
                out[2] = hi;
            }
            Self::Unknown(raw) => out[0] = raw,
        }
    }

    /// The response as a frame.
    pub fn to_frame(&self) -> [u8; FRAME_LEN] {
        let mut out = [0; FRAME_LEN];
        self.emit(&mut out);
        out
    }
}

impl SdoRequest {
    /// The request as a frame.
    pub fn to_frame(&self) -> [u8; FRAME_LEN] {
        let mut out = [0; FRAME_LEN];
        self.emit(&mut out);
        out
    }
}

/// One segment of a block sub-block (CiA 301 §7.2.4.3.12 download, §7.2.4.3.15 upload): byte 0 = c (bit 7,
/// last segment of the transfer) | seqno (bits 6..0, 1..=blksize), bytes 1..7 data. The same layout in both
/// directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockSegment {
    /// Sequence number in the block (valid: 1..=blksize).
    pub seqno: u8,
    /// c: the last segment of the whole transfer.
    pub last: bool,
    /// Bytes 1..7 (in the last segment, the end frame's n says how many carry data).
    pub data: [u8; SEGMENT_DATA],
}

impl BlockSegment {
    /// Decodes a frame as a sub-block segment.
    pub fn parse<T: AsRef<[u8]>>(frame: &SdoFrame<T>) -> Self {
        let cmd = frame.command();
        Self { seqno: cmd & 0x7F, last: cmd & 0x80 != 0, data: frame.data7() }
    }

    /// Encodes the segment into `out`.
    pub fn emit(&self, out: &mut [u8; FRAME_LEN]) {
        put7(out, self.data);
        out[0] = (u8::from(self.last) << 7) | (self.seqno & 0x7F);
    }

    /// The segment as a frame.
    pub fn to_frame(&self) -> [u8; FRAME_LEN] {
        let mut out = [0; FRAME_LEN];
        self.emit(&mut out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn request(bytes: [u8; 8]) -> SdoRequest {
        SdoRequest::parse(&SdoFrame::new_checked(bytes).unwrap())
    }

    fn response(bytes: [u8; 8]) -> SdoResponse {
        SdoResponse::parse(&SdoFrame::new_checked(bytes).unwrap())
    }

    #[test]
    fn short_buffers_are_rejected() {
        assert_eq!(SdoFrame::new_checked(&[0u8; 7][..]).map(|_| ()), Err(WireError::Truncated));
        assert!(SdoFrame::new_checked(&[0u8; 12][..]).is_ok());
    }

    #[test]
    fn epos4_golden_frames_decode() {
        // EPOS4 Application Notes Table 5-47 (seed 001 L2754-L2776): read statusword 0x6041:00 = 0x0008.
        assert_eq!(request([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]), SdoRequest::InitiateUpload { index: 0x6041, sub: 0 });
        assert_eq!(
            response([0x4B, 0x41, 0x60, 0, 0x08, 0, 0, 0]),
            SdoResponse::UploadExpedited { index: 0x6041, sub: 0, data: [8, 0, 0, 0], len: 2 }
        );
        // Table 5-48 (L2779-L2797): write controlword 0x000F with size not indicated (0x22).
        assert_eq!(
            request([0x22, 0x40, 0x60, 0, 0x0F, 0, 0, 0]),
            SdoRequest::InitiateDownload {
                index: 0x6040,
                sub: 0,
                init: DownloadInit::Expedited { data: [0x0F, 0, 0, 0], len: None }
            }
        );
        assert_eq!(
            SdoResponse::InitiateDownload { index: 0x6040, sub: 0 }.to_frame(),
            [0x60, 0x40, 0x60, 0, 0, 0, 0, 0]
        );
        // Table 5-49 (L2800-L2813): abort 0x0609_0011 for 0x2000:08.
        assert_eq!(
            SdoResponse::Abort { index: 0x2000, sub: 8, code: 0x0609_0011 }.to_frame(),
            [0x80, 0x00, 0x20, 0x08, 0x11, 0x00, 0x09, 0x06]
        );
        // Table 5-50 (L2817-L2834): 4-byte expedited upload 0x43.
        assert_eq!(
            SdoResponse::UploadExpedited { index: 0x6064, sub: 0, data: [0xCA, 0x04, 0, 0], len: 4 }.to_frame(),
            [0x43, 0x64, 0x60, 0, 0xCA, 0x04, 0, 0]
        );
        // Table 5-46 (L2733-L2749): 0x2F / 0x2B / 0x23 carry 1 / 2 / 4 bytes.
        for (cmd, len) in [(0x2F, 1), (0x2B, 2), (0x27, 3), (0x23, 4)] {
            let SdoRequest::InitiateDownload { init: DownloadInit::Expedited { len: got, .. }, .. } =
                request([cmd, 0, 0, 0, 0, 0, 0, 0])
            else {
                panic!("{cmd:#x}")
            };
            assert_eq!(got, Some(len));
        }
    }

    proptest! {
        #[test]
        fn any_eight_bytes_decode_and_re_encode_stably(bytes in any::<[u8; 8]>()) {
            let req = request(bytes);
            let again = request(req.to_frame());
            prop_assert_eq!(req, again);
            let rsp = response(bytes);
            let again = response(rsp.to_frame());
            prop_assert_eq!(rsp, again);
            let seg = BlockSegment::parse(&SdoFrame::new_checked(bytes).unwrap());
            prop_assert_eq!(seg.to_frame(), bytes);
        }
    }
}
