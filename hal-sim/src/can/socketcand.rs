//! The simulated CAN bus on TCP: a server speaking the socketcand ASCII protocol in raw mode, the way python-can's
//! `socketcand` interface speaks it (shared/spec/fieldbus-real-masters.md, "socketcand protocol as python-can
//! speaks it"), so that PyPI `canopen` or any python-can tool can join the simulated bus on 127.0.0.1.
//!
//! Per client: the server greets with `< hi >` alone; `< open NAME >` and `< rawmode >` are each answered with
//! `< ok >` alone (the client compares whole reads, so nothing may follow in the same write); then `< send ID DLC
//! B0 .. >` puts a frame on the bus and every bus frame goes to the client as `< frame ID SECS.USECS DATA >`.
//! Two quirks of the client are respected: a frame without data keeps two spaces before `>`, and no
//! unsolicited frame (a boot-up message, say) goes out until the client sent its first frame or 50 ms have
//! passed since its `rawmode` was acknowledged.
//!
//! Several clients make a hub: a frame one client sends reaches the simulated nodes and every other client.
//! Extended (29-bit) identifiers and unknown commands are answered with `< error ... >` lines the client logs,
//! and counted; nothing a client sends can stop the server.

use std::io::{self, ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::time::{Duration, Instant};

use super::CanFrame;

/// Time after `rawmode` is acknowledged before unsolicited frames go to a client that has not sent one yet.
pub const QUIET_AFTER_RAWMODE: Duration = Duration::from_millis(50);

/// Longest protocol element accepted (a `send` of 8 bytes is under 40 characters); longer input is discarded
/// up to the next `<`.
const MAX_ELEMENT: usize = 256;

/// A client's place in the handshake.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClientPhase {
    /// Greeted; waiting for `open`.
    Greeted,
    /// Channel open; waiting for `rawmode`.
    Open,
    /// In raw mode: frames flow.
    Raw,
}

/// A command parsed from a client.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    /// `< open NAME >`.
    Open(String),
    /// `< rawmode >`.
    RawMode,
    /// `< send ID DLC B0 .. >` with a standard identifier.
    Send(CanFrame),
    /// Anything else, with the reason it was refused.
    Refused(String),
}

/// Parses one protocol element (the text between `<` and `>`).
pub fn parse_command(element: &str) -> Command {
    let mut words = element.split_ascii_whitespace();
    match words.next() {
        Some("open") => match words.next() {
            Some(name) => Command::Open(name.to_owned()),
            None => Command::Refused("open without a bus name".into()),
        },
        Some("rawmode") => Command::RawMode,
        Some("send") => parse_send(words),
        Some(other) => Command::Refused(format!("unknown command {other}")),
        None => Command::Refused("empty element".into()),
    }
}

fn parse_send<'a>(mut words: impl Iterator<Item = &'a str>) -> Command {
    let (Some(id_text), Some(dlc_text)) = (words.next(), words.next()) else {
        return Command::Refused("send needs an identifier and a length".into());
    };
    if id_text.len() != 3 {
        return Command::Refused(format!("identifier {id_text}: only 11-bit (3 hex digits) identifiers"));
    }
    let Ok(id) = u16::from_str_radix(id_text, 16) else {
        return Command::Refused(format!("identifier {id_text} is not hexadecimal"));
    };
    let Ok(dlc) = usize::from_str_radix(dlc_text, 16) else {
        return Command::Refused(format!("length {dlc_text} is not hexadecimal"));
    };
    let mut data = Vec::with_capacity(8);
    for w in words {
        match u8::from_str_radix(w, 16) {
            Ok(b) => data.push(b),
            Err(_) => return Command::Refused(format!("data byte {w} is not hexadecimal")),
        }
    }
    if data.len() != dlc {
        return Command::Refused(format!("length {dlc} but {} data bytes", data.len()));
    }
    match CanFrame::new(id, &data) {
        Some(frame) => Command::Send(frame),
        None => Command::Refused(format!("identifier {id:03x} or length {dlc} out of range")),
    }
}

/// The `< frame ... >` line for `frame` received at `time_us` (bus time, µs).
pub fn format_frame(frame: &CanFrame, time_us: u64) -> String {
    let data: String = frame.data().iter().map(|b| format!("{b:02X}")).collect();
    // A frame without data still has the space before its (empty) data field: "< frame 080 1.000000  >".
    format!("< frame {:03X} {}.{:06} {} >", frame.id(), time_us / 1_000_000, time_us % 1_000_000, data)
}

/// Splits complete `<...>` elements off the front of `buffer`, leaving an incomplete one in it.
fn take_elements(buffer: &mut Vec<u8>) -> Vec<String> {
    let mut out = Vec::new();
    while let Some(close) = buffer.iter().position(|&b| b == b'>') {
        // The element is what follows the last `<` before the `>`; anything before it is garbage (an element that
        // never ended, stray text) and dropped.
        if let Some(open) = buffer[..close].iter().rposition(|&b| b == b'<') {
            out.push(String::from_utf8_lossy(&buffer[open + 1..close]).trim().to_owned());
        }
        buffer.drain(..=close);
    }
    // An element still open: keep it from its `<`, unless it has grown past any valid element.
    match buffer.iter().rposition(|&b| b == b'<') {
        Some(open) if buffer.len() - open <= MAX_ELEMENT => {
            buffer.drain(..open);
        }
        _ => buffer.clear(),
    }
    out
}

/// A connected client.
#[derive(Debug)]
struct Client {
    id: u64,
    stream: TcpStream,
    phase: ClientPhase,
    input: Vec<u8>,
    output: Vec<u8>,
    /// When `rawmode` was acknowledged.
    raw_since: Option<Instant>,
    /// The client sent a frame.
    sent_frame: bool,
    closed: bool,
}

impl Client {
    fn queue(&mut self, text: &str) {
        self.output.extend_from_slice(text.as_bytes());
    }

    /// Whether unsolicited frames may go to this client now.
    fn takes_frames(&self) -> bool {
        self.phase == ClientPhase::Raw
            && (self.sent_frame || self.raw_since.is_some_and(|t| t.elapsed() >= QUIET_AFTER_RAWMODE))
    }

    /// Writes what the socket takes now.
    fn flush(&mut self) {
        while !self.output.is_empty() {
            match self.stream.write(&self.output) {
                Ok(0) => {
                    self.closed = true;
                    return;
                }
                Ok(n) => {
                    self.output.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => {
                    self.closed = true;
                    return;
                }
            }
        }
    }
}

/// What the server counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServerStats {
    /// Clients accepted.
    pub clients_accepted: u64,
    /// Frames received from clients.
    pub frames_in: u64,
    /// Frames sent to clients (one per client).
    pub frames_out: u64,
    /// Elements refused (unknown commands, bad frames).
    pub refused: u64,
    /// Frames not sent to a client because it was not ready for unsolicited frames yet.
    pub held_back: u64,
}

/// The socketcand server. Non-blocking: [`SocketcandServer::poll`] does what can be done now.
#[derive(Debug)]
pub struct SocketcandServer {
    listener: TcpListener,
    clients: Vec<Client>,
    next_id: u64,
    stats: ServerStats,
}

impl SocketcandServer {
    /// Listens on `addr` (e.g. `127.0.0.1:29536`; port 0 picks a free one).
    pub fn bind(addr: SocketAddr) -> io::Result<Self> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        Ok(Self { listener, clients: Vec::new(), next_id: 0, stats: ServerStats::default() })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.clients.len()
    }

    /// Clients in raw mode now.
    pub fn raw_clients(&self) -> usize {
        self.clients.iter().filter(|c| c.phase == ClientPhase::Raw).count()
    }

    /// The counters.
    pub fn stats(&self) -> ServerStats {
        self.stats
    }

    /// Accepts new clients, reads what they sent, answers the handshake, forwards their frames to the other
    /// clients (stamped `time_us`) and returns them, in order, for the simulated bus.
    pub fn poll(&mut self, time_us: u64) -> Vec<CanFrame> {
        loop {
            match self.listener.accept() {
                Ok((stream, _)) => {
                    if stream.set_nonblocking(true).is_err() {
                        continue;
                    }
                    let _ = stream.set_nodelay(true);
                    let mut client = Client {
                        id: self.next_id,
                        stream,
                        phase: ClientPhase::Greeted,
                        input: Vec::new(),
                        output: Vec::new(),
                        raw_since: None,
                        sent_frame: false,
                        closed: false,
                    };
                    self.next_id += 1;
                    client.queue("< hi >");
                    client.flush();
                    self.stats.clients_accepted += 1;
                    self.clients.push(client);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
        let mut frames: Vec<(u64, CanFrame)> = Vec::new();
        for client in &mut self.clients {
            let mut chunk = [0u8; 4096];
            loop {
                match client.stream.read(&mut chunk) {
                    Ok(0) => {
                        client.closed = true;
                        break;
                    }
                    Ok(n) => client.input.extend_from_slice(&chunk[..n]),
                    Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    Err(_) => {
                        client.closed = true;
                        break;
                    }
                }
            }
            for element in take_elements(&mut client.input) {
                match (parse_command(&element), client.phase) {
                    (Command::Open(_), ClientPhase::Greeted) => {
                        client.phase = ClientPhase::Open;
                        client.queue("< ok >");
                        // Each answer alone on the wire: the client compares whole reads.
                        client.flush();
                    }
                    (Command::RawMode, ClientPhase::Open) => {
                        client.phase = ClientPhase::Raw;
                        client.raw_since = Some(Instant::now());
                        client.queue("< ok >");
                        client.flush();
                    }
                    (Command::Send(frame), ClientPhase::Raw) => {
                        client.sent_frame = true;
                        frames.push((client.id, frame));
                        self.stats.frames_in += 1;
                    }
                    (Command::Refused(why), _) => {
                        self.stats.refused += 1;
                        client.queue(&format!("< error {why} >"));
                    }
                    (command, phase) => {
                        self.stats.refused += 1;
                        client.queue(&format!("< error {command:?} not allowed in phase {phase:?} >"));
                    }
                }
            }
        }
        // The hub: each client's frames go to every other client in raw mode.
        for (from, frame) in &frames {
            self.forward(frame, time_us, Some(*from));
        }
        self.clients.retain_mut(|c| {
            c.flush();
            !c.closed
        });
        frames.into_iter().map(|(_, f)| f).collect()
    }

    /// Sends a frame from the simulated bus to every client in raw mode.
    pub fn broadcast(&mut self, frame: &CanFrame, time_us: u64) {
        self.forward(frame, time_us, None);
        for c in &mut self.clients {
            c.flush();
        }
    }

    fn forward(&mut self, frame: &CanFrame, time_us: u64, except: Option<u64>) {
        let line = format_frame(frame, time_us);
        for c in &mut self.clients {
            if Some(c.id) == except || c.phase != ClientPhase::Raw {
                continue;
            }
            if c.takes_frames() {
                c.queue(&line);
                self.stats.frames_out += 1;
            } else {
                self.stats.held_back += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::BufRead;

    #[test]
    fn send_lines_parse_as_python_can_writes_them() {
        let f = |id, d: &[u8]| Command::Send(CanFrame::new(id, d).unwrap());
        assert_eq!(parse_command("send 605 8 40 0 10 0 0 0 0 0"), f(0x605, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]));
        assert_eq!(parse_command("send 000 2 1 5"), f(0x000, &[1, 5]));
        assert_eq!(parse_command("send 080 0 "), f(0x080, &[]));
        assert_eq!(parse_command("open can0"), Command::Open("can0".into()));
        assert_eq!(parse_command("rawmode"), Command::RawMode);
        for bad in [
            "send 12345678 1 0",
            "send 605 2 1",
            "send 60g 1 0",
            "send 800 0",
            "send 605 9 0 0 0 0 0 0 0 0 0",
            "bcmmode",
            "",
        ] {
            assert!(matches!(parse_command(bad), Command::Refused(_)), "{bad:?}");
        }
    }

    #[test]
    fn frame_lines_keep_the_two_spaces_of_an_empty_frame() {
        let sync = CanFrame::new(0x080, &[]).unwrap();
        assert_eq!(format_frame(&sync, 1_000_000), "< frame 080 1.000000  >");
        let sdo = CanFrame::new(0x585, &[0x43, 0, 0x10, 0, 0x92, 1, 2, 0]).unwrap();
        assert_eq!(format_frame(&sdo, 1_795_296_634_669_835), "< frame 585 1795296634.669835 4300100092010200 >");
    }

    #[test]
    fn elements_split_across_reads_and_garbage_between_them_are_handled() {
        let mut buf = b"xx< open can0 >< raw".to_vec();
        assert_eq!(take_elements(&mut buf), ["open can0"]);
        buf.extend_from_slice(b"mode >junk");
        assert_eq!(take_elements(&mut buf), ["rawmode"]);
        assert!(buf.is_empty());
        let mut long = b"<".to_vec();
        long.extend(std::iter::repeat_n(b'a', 400));
        long.extend_from_slice(b"< rawmode >");
        assert_eq!(take_elements(&mut long), ["rawmode"], "an element without end is dropped");
    }

    /// Reads one protocol element from a client socket (the reads python-can makes).
    fn read_element(r: &mut std::io::BufReader<TcpStream>) -> String {
        let mut v = Vec::new();
        r.read_until(b'>', &mut v).unwrap();
        String::from_utf8(v).unwrap().trim_start().to_owned()
    }

    #[test]
    fn a_client_handshakes_sends_a_frame_and_receives_bus_frames_and_a_second_clients_frames() {
        let mut server = SocketcandServer::bind("127.0.0.1:0".parse().unwrap()).unwrap();
        let addr = server.local_addr().unwrap();
        let connect = |server: &mut SocketcandServer| {
            let s = TcpStream::connect(addr).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            let mut w = s.try_clone().unwrap();
            let mut r = std::io::BufReader::new(s);
            for _ in 0..50 {
                server.poll(0);
                if server.clients() > 0 && server.clients.iter().all(|c| c.output.is_empty()) {
                    break;
                }
            }
            assert_eq!(read_element(&mut r), "< hi >");
            w.write_all(b"< open can0 >").unwrap();
            while server.clients.iter().any(|c| c.phase == ClientPhase::Greeted) {
                server.poll(0);
            }
            assert_eq!(read_element(&mut r), "< ok >");
            w.write_all(b"< rawmode >").unwrap();
            while server.clients.iter().any(|c| c.phase != ClientPhase::Raw) {
                server.poll(0);
            }
            assert_eq!(read_element(&mut r), "< ok >");
            (w, r)
        };
        let (mut w1, mut r1) = connect(&mut server);
        // Unsolicited frames wait until the client sent one (or 50 ms passed).
        let boot = CanFrame::new(0x701, &[0]).unwrap();
        server.broadcast(&boot, 10);
        assert_eq!(server.stats().held_back, 1);
        w1.write_all(b"< send 000 2 1 1 >").unwrap();
        let mut got = Vec::new();
        for _ in 0..1000 {
            got.extend(server.poll(20));
            if !got.is_empty() {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(got, [CanFrame::new(0, &[1, 1]).unwrap()]);
        server.broadcast(&boot, 30);
        assert_eq!(read_element(&mut r1), "< frame 701 0.000030 00 >");

        let (mut w2, _r2) = connect(&mut server);
        w2.write_all(b"< send 080 0  >").unwrap();
        let mut got = Vec::new();
        for _ in 0..1000 {
            got.extend(server.poll(40));
            if !got.is_empty() {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(got, [CanFrame::new(0x080, &[]).unwrap()]);
        assert_eq!(read_element(&mut r1), "< frame 080 0.000040  >", "the hub forwards to the other client");
        // Bad input is answered and the server goes on.
        w1.write_all(b"< send 1234abcd 1 00 >< bogus >").unwrap();
        for _ in 0..1000 {
            server.poll(50);
            if server.stats().refused == 2 {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(server.stats().refused, 2);
        assert!(read_element(&mut r1).starts_with("< error identifier 1234abcd"));
    }
}
