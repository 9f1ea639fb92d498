//! The socketcand protocol's client side over TCP, as hal-sim's server (`hal-sim/src/can/socketcand.rs`) and the
//! socketcand daemon speak it: the server greets with `< hi >`; `< open BUS >` and `< rawmode >` are each
//! answered `< ok >`; then `< send ID DLC B0 .. >` puts a frame on the bus and every bus frame arrives as
//! `< frame ID SECS.USECS DATA >` (identifier and data in hex, data bytes run together).

use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use crate::bus::{CanInterface, Frame};

/// How long the handshake may take before the server is judged not to speak socketcand.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// A socketcand connection in raw mode.
pub struct Socketcand {
    stream: TcpStream,
    /// Bytes received but not yet split into `< ... >` elements.
    input: Vec<u8>,
}

impl Socketcand {
    /// Connects to `address` (`HOST:PORT`), opens bus `bus` and enters raw mode.
    pub fn connect(address: &str, bus: &str) -> Result<Self, String> {
        let stream = TcpStream::connect(address).map_err(|e| format!("--socketcand {address}: cannot connect: {e}"))?;
        stream.set_nodelay(true).map_err(|e| format!("--socketcand {address}: {e}"))?;
        let mut link = Self { stream, input: Vec::new() };
        link.expect(address, "hi")?;
        link.write(&format!("< open {bus} >")).map_err(|e| format!("--socketcand {address}: {e}"))?;
        link.expect(address, "ok")?;
        link.write("< rawmode >").map_err(|e| format!("--socketcand {address}: {e}"))?;
        link.expect(address, "ok")?;
        Ok(link)
    }

    fn write(&mut self, text: &str) -> io::Result<()> {
        self.stream.write_all(text.as_bytes())
    }

    /// Waits for the element `word` of the handshake.
    fn expect(&mut self, address: &str, word: &str) -> Result<(), String> {
        match self.next_element(HANDSHAKE_TIMEOUT).map_err(|e| format!("--socketcand {address}: {e}"))? {
            Some(e) if e == word => Ok(()),
            Some(e) => Err(format!("--socketcand {address}: expected `< {word} >`, the server sent `< {e} >`")),
            None => Err(format!("--socketcand {address}: no `< {word} >` within {HANDSHAKE_TIMEOUT:?}")),
        }
    }

    /// The next complete `< ... >` element (its inner text, trimmed) within `timeout`.
    fn next_element(&mut self, timeout: Duration) -> io::Result<Option<String>> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(close) = self.input.iter().position(|&b| b == b'>') {
                let element: Vec<u8> = self.input.drain(..=close).collect();
                let open = element.iter().rposition(|&b| b == b'<').map_or(0, |o| o + 1);
                let text = String::from_utf8_lossy(&element[open..element.len() - 1]).trim().to_owned();
                return Ok(Some(text));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.stream.set_read_timeout(Some(left))?;
            let mut chunk = [0u8; 4096];
            match self.stream.read(&mut chunk) {
                Ok(0) => return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "the server closed the connection")),
                Ok(n) => self.input.extend_from_slice(&chunk[..n]),
                Err(e) if matches!(e.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut) => return Ok(None),
                Err(e) => return Err(e),
            }
        }
    }
}

/// The frame of a `frame ID SECS.USECS DATA` element, or `None` for any other element.
pub fn parse_frame(element: &str) -> Option<Frame> {
    let mut words = element.split_whitespace();
    if words.next()? != "frame" {
        return None;
    }
    let id = u16::from_str_radix(words.next()?, 16).ok().filter(|&id| id <= 0x7FF)?;
    let _time = words.next()?;
    let hex = words.next().unwrap_or("");
    if !hex.len().is_multiple_of(2) || hex.len() > 16 {
        return None;
    }
    let data: Option<Vec<u8>> =
        (0..hex.len()).step_by(2).map(|k| hex.get(k..k + 2).and_then(|b| u8::from_str_radix(b, 16).ok())).collect();
    Some(Frame { id, data: data? })
}

/// The `< send ... >` element for `frame`.
pub fn format_send(frame: &Frame) -> String {
    let mut text = format!("< send {:03X} {}", frame.id, frame.data.len());
    for b in &frame.data {
        text.push_str(&format!(" {b:02X}"));
    }
    text.push_str(" >");
    text
}

impl CanInterface for Socketcand {
    fn send(&mut self, frame: &Frame) -> io::Result<()> {
        let text = format_send(frame);
        self.write(&text)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Frame>> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next_element(left)? {
                Some(element) => {
                    if let Some(frame) = parse_frame(&element) {
                        return Ok(Some(frame));
                    }
                    // `< error ... >` and other elements: the server's log lines, not frames.
                }
                None => return Ok(None),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_parse_with_and_without_data() {
        assert_eq!(
            parse_frame("frame 581 1.000000 4300100000000000"),
            Some(Frame::new(0x581, &[0x43, 0, 0x10, 0, 0, 0, 0, 0]))
        );
        assert_eq!(parse_frame("frame 080 1.000000"), Some(Frame::new(0x080, &[])));
        assert_eq!(parse_frame("ok"), None);
        assert_eq!(parse_frame("frame 800 1.0 00"), None, "29-bit identifiers are not CANopen's");
    }

    #[test]
    fn send_elements_list_the_bytes() {
        assert_eq!(format_send(&Frame::new(0x601, &[0x40, 0x18, 0x10, 1])), "< send 601 4 40 18 10 01 >");
    }
}
