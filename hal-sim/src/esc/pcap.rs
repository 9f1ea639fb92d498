//! A minimal capture writer: the classic libpcap file format (not pcapng) with microsecond timestamps and
//! link type `LINKTYPE_ETHERNET` (1), readable by tshark/Wireshark, tcpdump and scapy.
//!
//! Format (tcpdump.org "pcap-savefile(5)", IETF draft-ietf-opsawg-pcap): a 24-byte global header (magic
//! 0xA1B2C3D4 written in the writer's byte order, version 2.4, thiszone 0, sigfigs 0, snaplen, link type), then
//! per packet a 16-byte record header (seconds, microseconds, captured length, original length) and the bytes.
//! Everything here is little-endian.
//!
//! The writer takes the timestamp from its caller: the ESC reads no clock (see the module documentation of
//! [`super`]); the serve loop of `sim::ethercat` stamps frames with the wall clock.

use std::io::{self, Write};
use std::time::Duration;

/// Magic number of a microsecond-resolution capture.
pub const MAGIC_US: u32 = 0xA1B2_C3D4;
/// `LINKTYPE_ETHERNET`: IEEE 802.3 frames from the destination MAC address on (no FCS).
pub const LINKTYPE_ETHERNET: u32 = 1;
/// Largest packet stored in full (longer ones are cut, keeping their original length in the record).
pub const SNAPLEN: u32 = 65_535;

/// A pcap writer on any byte sink (a buffered file in practice).
#[derive(Debug)]
pub struct PcapWriter<W: Write> {
    out: W,
    packets: u64,
}

impl<W: Write> PcapWriter<W> {
    /// Writes the global header to `out`.
    pub fn new(mut out: W) -> io::Result<Self> {
        let mut h = [0u8; 24];
        h[0..4].copy_from_slice(&MAGIC_US.to_le_bytes());
        // Version 2.4; bytes 8..12 thiszone = 0 (UTC) and 12..16 sigfigs = 0 stay zero.
        h[4..6].copy_from_slice(&2u16.to_le_bytes());
        h[6..8].copy_from_slice(&4u16.to_le_bytes());
        h[16..20].copy_from_slice(&SNAPLEN.to_le_bytes());
        h[20..24].copy_from_slice(&LINKTYPE_ETHERNET.to_le_bytes());
        out.write_all(&h)?;
        Ok(Self { out, packets: 0 })
    }

    /// Appends one frame captured at `time` (since the Unix epoch). Frames longer than [`SNAPLEN`] are cut.
    pub fn write_frame(&mut self, time: Duration, frame: &[u8]) -> io::Result<()> {
        let orig = u32::try_from(frame.len()).unwrap_or(u32::MAX);
        let incl = orig.min(SNAPLEN);
        let secs = u32::try_from(time.as_secs()).unwrap_or(u32::MAX);
        let mut h = [0u8; 16];
        h[0..4].copy_from_slice(&secs.to_le_bytes());
        h[4..8].copy_from_slice(&time.subsec_micros().to_le_bytes());
        h[8..12].copy_from_slice(&incl.to_le_bytes());
        h[12..16].copy_from_slice(&orig.to_le_bytes());
        self.out.write_all(&h)?;
        self.out.write_all(&frame[..incl as usize])?;
        self.packets += 1;
        Ok(())
    }

    /// Frames written so far.
    pub fn packets(&self) -> u64 {
        self.packets
    }

    /// Flushes the sink.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    /// Flushes and returns the sink.
    pub fn into_inner(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_is_a_global_header_then_a_record_per_frame() {
        let mut w = PcapWriter::new(Vec::new()).unwrap();
        let frame: Vec<u8> = (0..60u8).collect();
        w.write_frame(Duration::new(1_700_000_000, 123_456_789), &frame).unwrap();
        w.write_frame(Duration::new(1_700_000_001, 5_000), &frame[..14]).unwrap();
        assert_eq!(w.packets(), 2);
        let b = w.into_inner().unwrap();
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        assert_eq!(b.len(), 24 + 16 + 60 + 16 + 14);
        assert_eq!(&b[0..4], &[0xD4, 0xC3, 0xB2, 0xA1], "little-endian microsecond magic");
        assert_eq!((u16::from_le_bytes([b[4], b[5]]), u16::from_le_bytes([b[6], b[7]])), (2, 4));
        assert_eq!((u32_at(8), u32_at(12), u32_at(16), u32_at(20)), (0, 0, SNAPLEN, 1));
        assert_eq!((u32_at(24), u32_at(28), u32_at(32), u32_at(36)), (1_700_000_000, 123_456, 60, 60));
        assert_eq!(&b[40..100], &frame[..]);
        assert_eq!((u32_at(100), u32_at(104), u32_at(108), u32_at(112)), (1_700_000_001, 5, 14, 14));
        assert_eq!(&b[116..130], &frame[..14]);
    }
}
