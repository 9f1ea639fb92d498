//! The CAN side of a CANopen link: a classic frame with an 11-bit identifier and the interface that carries
//! frames to and from the bus. Two interfaces implement it: the socketcand protocol over TCP (the simulator,
//! `--socketcand`) and Linux SocketCAN (real adapters, `--can`).

use std::io;
use std::time::Duration;

/// A classic CAN data frame with a standard (11-bit) identifier, as CANopen uses them (CiA 301 §7.1).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    /// The COB-ID (11 bits).
    pub id: u16,
    /// 0..=8 data bytes.
    pub data: Vec<u8>,
}

impl Frame {
    /// A frame; `data` must hold at most 8 bytes (callers build CANopen frames of fixed size).
    pub fn new(id: u16, data: &[u8]) -> Self {
        Self { id, data: data.to_vec() }
    }
}

/// Something that puts frames on a CAN bus and hands back the frames it sees there.
pub trait CanInterface {
    /// Sends one frame.
    fn send(&mut self, frame: &Frame) -> io::Result<()>;
    /// The next frame seen on the bus within `timeout`, or `None` when none came.
    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Frame>>;
}
