//! Linux SocketCAN (`--can IFACE`): real CAN adapters and `vcan` interfaces, through the `socketcan` crate.

use std::io;
use std::time::Duration;

use socketcan::{CanFrame, CanSocket, EmbeddedFrame, Id, Socket, StandardId};

use crate::bus::{CanInterface, Frame};

/// An open raw CAN socket bound to one interface.
pub struct SocketCan {
    socket: CanSocket,
}

impl SocketCan {
    /// Opens interface `iface` (`can0`, `vcan0`, ...).
    pub fn open(iface: &str) -> Result<Self, String> {
        let socket = CanSocket::open(iface).map_err(|e| format!("--can {iface}: cannot open the interface: {e}"))?;
        Ok(Self { socket })
    }
}

impl CanInterface for SocketCan {
    fn send(&mut self, frame: &Frame) -> io::Result<()> {
        let id = StandardId::new(frame.id).ok_or_else(|| {
            io::Error::new(io::ErrorKind::InvalidInput, format!("COB-ID 0x{:X} above 11 bits", frame.id))
        })?;
        let out = CanFrame::new(id, &frame.data)
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "more than 8 data bytes"))?;
        self.socket.write_frame(&out)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Frame>> {
        // A zero timeout would make poll() return at once even with a frame queued; wait at least 1 ms.
        match self.socket.read_frame_timeout(timeout.max(Duration::from_millis(1))) {
            Ok(frame) => {
                // Extended identifiers, remote and error frames are not CANopen traffic this tool reads.
                match (frame.id(), frame.is_remote_frame(), &frame) {
                    (Id::Standard(id), false, CanFrame::Data(_)) => Ok(Some(Frame::new(id.as_raw(), frame.data()))),
                    _ => Ok(None),
                }
            }
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock) => Ok(None),
            Err(e) => Err(e),
        }
    }
}
