//! The link to the drives: the services every command needs from a fieldbus (object access by SDO, finding the
//! drives, their communication state). CANopen over a CAN interface implements it here; EtherCAT (CoE SDO
//! through the mailbox, `crate::ecat`) is the second implementation.

use std::collections::BTreeMap;
use std::io;
use std::time::{Duration, Instant};

use crate::bus::{CanInterface, Frame};
use crate::sdo::{SdoClient, SdoError};

/// What the commands need from a fieldbus.
pub trait DriveLink {
    /// Reads object `index:sub` of drive `node`.
    fn upload(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError>;
    /// Writes `data` to object `index:sub` of drive `node`.
    fn download(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError>;
    /// Writes a large `data` to `index:sub` of `node` by the link's bulk transfer (CANopen: SDO block download),
    /// telling `progress` the bytes acknowledged so far.
    fn download_bulk(
        &mut self,
        node: u8,
        index: u16,
        sub: u8,
        data: &[u8],
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), SdoError>;
    /// Reads a large `index:sub` of `node` by the link's bulk transfer (CANopen: SDO block upload with CRC).
    fn upload_bulk(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError>;
    /// One LSS request (CiA 305: 0x7E5 to the slaves) and the first answer (0x7E4) within `wait`, if any; an
    /// error on a link without LSS.
    fn lss(&mut self, request: [u8; 8], wait: Duration) -> Result<Vec<[u8; 8]>, String>;
    /// From now on, remembers `node`'s next boot-up, even while another exchange takes the frames.
    fn expect_boot_up(&mut self, node: u8);
    /// Waits up to `timeout` for `node`'s boot-up since [`DriveLink::expect_boot_up`]; whether it came.
    fn wait_boot_up(&mut self, node: u8, timeout: Duration) -> Result<bool, String>;
    /// The addresses of the drives that answer, waiting at most `timeout` for them.
    fn scan(&mut self, timeout: Duration) -> Result<Vec<u8>, String>;
    /// Commands `node` (0: every node) into another communication state; for a reset, waits up to `timeout`
    /// for its boot-up and says whether it came.
    fn command_state(&mut self, node: u8, command: StateCommand, timeout: Duration) -> Result<bool, String>;
    /// The communication state of `node` as last seen (CANopen: the NMT state of its heartbeat), if known.
    fn comm_state(&self, node: u8) -> Option<String>;
    /// The name `scan` and `info` give the communication state (CANopen: `nmt`).
    fn comm_state_key(&self) -> &'static str {
        "nmt"
    }
    /// What the link itself knows of `node` beyond its objects (EtherCAT: station address, alias, SII name): JSON
    /// name, value and text.
    fn describe(&mut self, _node: u8) -> Vec<(&'static str, serde_json::Value, String)> {
        Vec::new()
    }
    /// The EtherCAT link, for the services only EtherCAT has (FoE, AL states); `None` on CANopen.
    #[cfg(target_os = "linux")]
    fn ecat(&mut self) -> Option<&mut crate::ecat::EcatLink> {
        None
    }
}

/// A CAN interface that remembers the heartbeats (NMT states, CiA 301 §7.2.8.3.2.2) it passes.
struct Watch {
    inner: Box<dyn CanInterface>,
    nmt: BTreeMap<u8, u8>,
    /// Nodes whose boot-up (0x700 + node-ID, data `00`) passed since [`DriveLink::expect_boot_up`].
    booted: std::collections::BTreeSet<u8>,
}

impl Watch {
    fn note(&mut self, frame: &Frame) {
        if let (0x700, node @ 1..=127, [state]) = (frame.id & 0x780, frame.id & 0x7F, frame.data.as_slice()) {
            self.nmt.insert(node as u8, *state & 0x7F);
            if *state == 0 {
                self.booted.insert(node as u8);
            }
        }
    }
}

impl CanInterface for Watch {
    fn send(&mut self, frame: &Frame) -> io::Result<()> {
        self.inner.send(frame)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Frame>> {
        let frame = self.inner.recv(timeout)?;
        if let Some(f) = &frame {
            self.note(f);
        }
        Ok(frame)
    }
}

/// A change of communication state (CANopen: the NMT node control commands, CiA 301 §7.2.8.3.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum StateCommand {
    /// To OPERATIONAL (NMT start remote node, 0x01).
    Start,
    /// To STOPPED (0x02): no SDO, no PDO; NMT and heartbeat only.
    Stop,
    /// To PRE-OPERATIONAL (0x80): SDO, no PDO.
    Preop,
    /// Reset node (0x81): the application restarts with its stored parameters.
    Reset,
    /// Reset communication (0x82): the communication objects take their stored values.
    ResetComm,
}

impl StateCommand {
    /// The NMT command specifier.
    pub fn specifier(self) -> u8 {
        match self {
            Self::Start => 0x01,
            Self::Stop => 0x02,
            Self::Preop => 0x80,
            Self::Reset => 0x81,
            Self::ResetComm => 0x82,
        }
    }
}

/// The name of NMT state `state` as a heartbeat carries it (CiA 301 Table 59).
pub fn nmt_state_name(state: u8) -> String {
    match state {
        0x00 => "boot-up".into(),
        0x04 => "stopped".into(),
        0x05 => "operational".into(),
        0x7F => "pre-operational".into(),
        other => format!("unknown 0x{other:02X}"),
    }
}

/// CANopen on a CAN interface: SDO for the objects, heartbeats for the NMT state.
pub struct CanopenLink {
    bus: Watch,
    /// SDO answer timeout.
    pub timeout: Duration,
    /// Every transfer by SDO block transfer (CiA 301 §7.2.4.3.9..16) instead of expedited/segmented.
    pub block: bool,
}

impl CanopenLink {
    /// The link over `bus` with SDO timeout `timeout`, block transfers if `block`.
    pub fn new(bus: Box<dyn CanInterface>, timeout: Duration, block: bool) -> Self {
        Self {
            bus: Watch { inner: bus, nmt: BTreeMap::new(), booted: std::collections::BTreeSet::new() },
            timeout,
            block,
        }
    }
}

impl DriveLink for CanopenLink {
    fn upload(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        let mut client = SdoClient::new(&mut self.bus, self.timeout);
        if self.block {
            client.block_upload(node, index, sub)
        } else {
            client.upload(node, index, sub)
        }
    }

    fn download(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        let mut client = SdoClient::new(&mut self.bus, self.timeout);
        if self.block {
            client.block_download(node, index, sub, data)
        } else {
            client.download(node, index, sub, data)
        }
    }

    fn upload_bulk(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        SdoClient::new(&mut self.bus, self.timeout).block_upload(node, index, sub)
    }

    fn download_bulk(
        &mut self,
        node: u8,
        index: u16,
        sub: u8,
        data: &[u8],
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), SdoError> {
        SdoClient::new(&mut self.bus, self.timeout).block_download_with_progress(node, index, sub, data, progress)
    }

    fn lss(&mut self, request: [u8; 8], wait: Duration) -> Result<Vec<[u8; 8]>, String> {
        // Several slaves answer one probe alike: the answers of the last request still queued are not this one's.
        // (A quarter of the answer window, at least 2 ms: on a socketcand link they may still be on their way.)
        let settle = (wait / 4).max(Duration::from_millis(2));
        while self.bus.recv(settle).map_err(|e| e.to_string())?.is_some() {}
        send_patiently(&mut self.bus, &Frame::new(0x7E5, &request)).map_err(|e| format!("LSS request: {e}"))?;
        let mut answers = Vec::new();
        let deadline = Instant::now() + wait;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(answers);
            }
            match self.bus.recv(left).map_err(|e| e.to_string())? {
                Some(frame) if frame.id == 0x7E4 => {
                    if let Ok(data) = <[u8; 8]>::try_from(frame.data.as_slice()) {
                        // Every service here needs one answer (a fastscan probe: whether any slave matched).
                        answers.push(data);
                        return Ok(answers);
                    }
                }
                Some(_) => {}
                None => return Ok(answers),
            }
        }
    }

    fn expect_boot_up(&mut self, node: u8) {
        self.bus.booted.remove(&node);
    }

    fn wait_boot_up(&mut self, node: u8, timeout: Duration) -> Result<bool, String> {
        // CiA 301 §7.2.8.3.2.1: 0x700 + node-ID [0x00], noted by `Watch` whoever read it.
        let deadline = Instant::now() + timeout;
        while !self.bus.booted.contains(&node) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(false);
            }
            self.bus.recv(left).map_err(|e| e.to_string())?;
        }
        Ok(true)
    }

    /// Asks every node-ID 1..=127 for 0x1018:01 at once (one request each, so no server sees two) and collects
    /// who answers within `timeout`: with its value or with an abort, a node that answers is there. Boot-ups and
    /// heartbeats seen meanwhile count too.
    fn scan(&mut self, timeout: Duration) -> Result<Vec<u8>, String> {
        for node in 1..=127u16 {
            let frame = Frame::new(0x600 + node, &[0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0]);
            send_patiently(&mut self.bus, &frame).map_err(|e| format!("sending the scan requests: {e}"))?;
        }
        let mut found = std::collections::BTreeSet::new();
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            if let Some(frame) = self.bus.recv(left).map_err(|e| e.to_string())? {
                let node = (frame.id & 0x7F) as u8;
                let sdo_answer = frame.id & 0x780 == 0x580
                    && frame.data.len() == 8
                    && frame.data[1..4] == [0x18, 0x10, 0x01]
                    && (frame.data[0] & 0xE0 == 0x40 || frame.data[0] == 0x80);
                if (sdo_answer || frame.id & 0x780 == 0x700) && node != 0 {
                    found.insert(node);
                }
            }
        }
        Ok(found.into_iter().collect())
    }

    fn command_state(&mut self, node: u8, command: StateCommand, timeout: Duration) -> Result<bool, String> {
        self.bus.nmt.remove(&node);
        self.bus.send(&Frame::new(0x000, &[command.specifier(), node])).map_err(|e| format!("NMT command: {e}"))?;
        if !matches!(command, StateCommand::Reset | StateCommand::ResetComm) {
            return Ok(true);
        }
        // CiA 301 §7.2.8.3.2.1: a node that finished its reset sends its boot-up, 0x700 + node-ID [0x00].
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(false);
            }
            if let Some(frame) = self.bus.recv(left).map_err(|e| e.to_string())? {
                if frame.data == [0]
                    && (frame.id == 0x700 + u16::from(node) || (node == 0 && frame.id & 0x780 == 0x700))
                {
                    return Ok(true);
                }
            }
        }
    }

    fn comm_state(&self, node: u8) -> Option<String> {
        self.bus.nmt.get(&node).map(|&s| nmt_state_name(s))
    }
}

/// Sends `frame`, waiting and retrying while the interface's transmit queue is full (SocketCAN answers ENOBUFS
/// when 127 requests outrun a short queue).
fn send_patiently(bus: &mut dyn CanInterface, frame: &Frame) -> io::Result<()> {
    let deadline = Instant::now() + Duration::from_secs(2);
    loop {
        match bus.send(frame) {
            Err(e)
                if (e.raw_os_error() == Some(105) || e.kind() == io::ErrorKind::WouldBlock)
                    && Instant::now() < deadline =>
            {
                std::thread::sleep(Duration::from_millis(2));
            }
            other => return other,
        }
    }
}
