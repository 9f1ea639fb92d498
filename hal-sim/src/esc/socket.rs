//! The ESC on a network interface: a raw `AF_PACKET` socket (Linux `packet(7)`) bound to one interface and
//! EtherType 0x88A4. Each received EtherCAT frame is processed and sent back out of the same interface, as a
//! one-port slave with its other ports closed returns every frame to the master.
//!
//! Opening the socket needs `CAP_NET_RAW`. Tests run it inside a private network namespace on one end of a
//! veth pair (`unshare --net` as root; see the spec file, "What works here").
//!
//! The emulator's `unsafe` code lives in two private `sys` modules: this one, seven libc calls, each wrapped so
//! that its pointer and length arguments come from a Rust slice or a local struct, and the scheduling calls of
//! [`crate::sim::host_priority`].

use std::io;
use std::ops::ControlFlow;
use std::os::fd::{AsRawFd, OwnedFd};
use std::time::Duration;

use super::datagram::{FrameReport, ETHERTYPE_ETHERCAT};
use super::Esc;

/// Largest Ethernet frame handled (no jumbo frames).
pub const MAX_FRAME: usize = 1518;

/// A raw packet socket bound to one interface for EtherCAT frames.
#[derive(Debug)]
pub struct RawSocket {
    fd: OwnedFd,
    iface: String,
}

impl RawSocket {
    /// Opens the socket on `iface`. Errors name the interface and, for a permission error, the capability.
    pub fn bind(iface: &str) -> io::Result<Self> {
        if iface.is_empty() || iface.len() > 15 || iface.bytes().any(|b| b == 0 || b == b'/') {
            return Err(io::Error::new(io::ErrorKind::InvalidInput, format!("bad interface name {iface:?}")));
        }
        let fd = sys::packet_socket(ETHERTYPE_ETHERCAT).map_err(|e| {
            if e.kind() == io::ErrorKind::PermissionDenied {
                io::Error::new(
                    e.kind(),
                    format!("raw socket for {iface}: {e} (needs CAP_NET_RAW: run as root or in `unshare -Urn`)"),
                )
            } else {
                io::Error::new(e.kind(), format!("raw socket for {iface}: {e}"))
            }
        })?;
        let index = sys::interface_index(iface)
            .map_err(|e| io::Error::new(io::ErrorKind::NotFound, format!("interface {iface}: {e}")))?;
        sys::bind(&fd, index, ETHERTYPE_ETHERCAT)
            .map_err(|e| io::Error::new(e.kind(), format!("bind to {iface}: {e}")))?;
        Ok(Self { fd, iface: iface.to_string() })
    }

    /// The interface name.
    pub fn interface(&self) -> &str {
        &self.iface
    }

    /// Sets the receive timeout (`None` = block).
    pub fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        sys::set_rcvtimeo(&self.fd, timeout.unwrap_or(Duration::ZERO))
    }

    /// Receives one frame sent to this host (frames this socket sent itself are skipped). Returns its length;
    /// `Ok(None)` on timeout.
    pub fn recv(&self, buf: &mut [u8]) -> io::Result<Option<usize>> {
        loop {
            match sys::recv(&self.fd, buf) {
                Ok((_, true)) => continue, // our own outgoing frame
                Ok((n, false)) => return Ok(Some(n)),
                Err(e) if matches!(e.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut) => return Ok(None),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
    }

    /// The kernel's receive time of the frame [`Self::recv`] returned last (`SIOCGSTAMPNS`, `socket(7)`): when
    /// it reached the interface, independent of when this thread got to it. The first call switches the
    /// kernel's time-stamping on and may return the current time. `None` if the kernel gives none.
    pub fn last_receive_time(&self) -> Option<std::time::SystemTime> {
        let (secs, nanos) = sys::last_receive_time(&self.fd).ok()?;
        std::time::UNIX_EPOCH.checked_add(Duration::new(secs, nanos))
    }

    /// Sends one frame out of the interface.
    pub fn send(&self, frame: &[u8]) -> io::Result<()> {
        let n = sys::send(&self.fd, frame)?;
        if n == frame.len() {
            Ok(())
        } else {
            Err(io::Error::new(io::ErrorKind::WriteZero, format!("sent {n} of {} bytes", frame.len())))
        }
    }
}

/// What the serve loop tells its callback.
#[derive(Debug)]
pub enum ServeEvent<'a> {
    /// A frame was processed and sent back.
    Frame(&'a FrameReport),
    /// A frame was dropped (malformed or not EtherCAT).
    Dropped,
    /// No frame within the poll interval: a chance to run the firmware and advance time.
    Idle,
}

/// Runs the ESC on `iface` until the callback breaks: receive, [`Esc::process_frame`], send back, call
/// `on_event` (where the simulation runs the firmware's PDI side and advances the ESC's time; the loop never
/// touches the clock). `poll` bounds the wait for a frame before an [`ServeEvent::Idle`] call.
pub fn serve<F>(iface: &str, esc: &mut Esc, poll: Duration, on_event: F) -> io::Result<()>
where
    F: FnMut(&mut Esc, ServeEvent<'_>) -> ControlFlow<()>,
{
    let socket = RawSocket::bind(iface)?;
    serve_socket(&socket, esc, poll, on_event)
}

/// [`serve`] on an open socket.
pub fn serve_socket<F>(socket: &RawSocket, esc: &mut Esc, poll: Duration, on_event: F) -> io::Result<()>
where
    F: FnMut(&mut Esc, ServeEvent<'_>) -> ControlFlow<()>,
{
    serve_socket_tapped(socket, esc, poll, |_, _| Ok(()), on_event)
}

/// Which way a frame went on the interface (for a capture such as [`super::pcap`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Received from the master, before the ESC processed it (every frame, dropped ones included).
    Received,
    /// The processed frame as sent back.
    Sent,
}

/// [`serve_socket`] that also hands every frame to `tap`: each received one before processing, each answer
/// after it is sent. An error of `tap` ends the loop with that error.
pub fn serve_socket_tapped<T, F>(
    socket: &RawSocket,
    esc: &mut Esc,
    poll: Duration,
    mut tap: T,
    mut on_event: F,
) -> io::Result<()>
where
    T: FnMut(Direction, &[u8]) -> io::Result<()>,
    F: FnMut(&mut Esc, ServeEvent<'_>) -> ControlFlow<()>,
{
    socket.set_read_timeout(Some(poll.max(Duration::from_micros(1))))?;
    let mut buf = [0u8; MAX_FRAME];
    loop {
        let flow = match socket.recv(&mut buf)? {
            None => on_event(esc, ServeEvent::Idle),
            Some(n) => {
                let frame = &mut buf[..n.min(MAX_FRAME)];
                tap(Direction::Received, frame)?;
                match esc.process_frame(frame) {
                    Ok(report) => {
                        socket.send(frame)?;
                        tap(Direction::Sent, frame)?;
                        on_event(esc, ServeEvent::Frame(&report))
                    }
                    Err(_) => on_event(esc, ServeEvent::Dropped),
                }
            }
        };
        if flow.is_break() {
            return Ok(());
        }
    }
}

impl AsRawFd for RawSocket {
    fn as_raw_fd(&self) -> std::os::fd::RawFd {
        self.fd.as_raw_fd()
    }
}

/// The socket FFI (see the module documentation). Every call passes pointers to live locals or slices
/// with their true lengths, and checks the return value.
#[allow(unsafe_code)]
mod sys {
    use std::ffi::CString;
    use std::io;
    use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
    use std::time::Duration;

    /// `socket(AF_PACKET, SOCK_RAW | SOCK_CLOEXEC, htons(ethertype))`.
    pub fn packet_socket(ethertype: u16) -> io::Result<OwnedFd> {
        // SAFETY: plain integer arguments; the result is checked before it is wrapped.
        let fd =
            unsafe { libc::socket(libc::AF_PACKET, libc::SOCK_RAW | libc::SOCK_CLOEXEC, i32::from(ethertype.to_be())) };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` is a fresh descriptor that nothing else owns.
        Ok(unsafe { OwnedFd::from_raw_fd(fd) })
    }

    /// `if_nametoindex(name)`.
    pub fn interface_index(name: &str) -> io::Result<i32> {
        let c = CString::new(name).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
        // SAFETY: `c` is a NUL-terminated string that outlives the call.
        let index = unsafe { libc::if_nametoindex(c.as_ptr()) };
        if index == 0 {
            return Err(io::Error::last_os_error());
        }
        i32::try_from(index).map_err(|_| io::Error::from(io::ErrorKind::InvalidData))
    }

    /// `bind` to `sockaddr_ll { AF_PACKET, htons(ethertype), ifindex }`.
    pub fn bind(fd: &OwnedFd, ifindex: i32, ethertype: u16) -> io::Result<()> {
        // SAFETY: sockaddr_ll is plain old data; all-zero is a valid value.
        let mut addr: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        addr.sll_family = libc::AF_PACKET as u16;
        addr.sll_protocol = ethertype.to_be();
        addr.sll_ifindex = ifindex;
        let len = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
        // SAFETY: `addr` is a live local of the size passed.
        let r = unsafe { libc::bind(fd.as_raw_fd(), (&raw const addr).cast(), len) };
        if r < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }

    /// `setsockopt(SO_RCVTIMEO)`; zero = block.
    pub fn set_rcvtimeo(fd: &OwnedFd, t: Duration) -> io::Result<()> {
        let tv = libc::timeval {
            tv_sec: libc::time_t::try_from(t.as_secs()).unwrap_or(libc::time_t::MAX),
            tv_usec: libc::suseconds_t::from(t.subsec_micros().min(999_999) as i32),
        };
        let len = std::mem::size_of::<libc::timeval>() as libc::socklen_t;
        // SAFETY: `tv` is a live local of the size passed.
        let r = unsafe {
            libc::setsockopt(fd.as_raw_fd(), libc::SOL_SOCKET, libc::SO_RCVTIMEO, (&raw const tv).cast(), len)
        };
        if r < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }

    /// `recvfrom`; returns the length and whether the frame is one this host sent (`PACKET_OUTGOING`).
    pub fn recv(fd: &OwnedFd, buf: &mut [u8]) -> io::Result<(usize, bool)> {
        // SAFETY: sockaddr_ll is plain old data; all-zero is a valid value.
        let mut from: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        let mut len = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
        // SAFETY: `buf` is a live slice of the length passed; `from`/`len` are live locals of matching size.
        let n = unsafe {
            libc::recvfrom(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len(), 0, (&raw mut from).cast(), &raw mut len)
        };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        let outgoing = from.sll_pkttype == libc::PACKET_OUTGOING;
        Ok((usize::try_from(n).unwrap_or(0).min(buf.len()), outgoing))
    }

    /// `ioctl(SIOCGSTAMPNS)`: the receive time of the last packet, seconds and nanoseconds (`CLOCK_REALTIME`).
    pub fn last_receive_time(fd: &OwnedFd) -> io::Result<(u64, u32)> {
        /// `SIOCGSTAMPNS` (`linux/sockios.h`, the `timespec` with native `time_t`); not in the libc crate.
        const SIOCGSTAMPNS: libc::c_ulong = 0x8907;
        let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: the request writes one `timespec` to the pointer, which points at a live local of that type.
        let r = unsafe { libc::ioctl(fd.as_raw_fd(), SIOCGSTAMPNS as _, &raw mut ts) };
        if r < 0 {
            return Err(io::Error::last_os_error());
        }
        let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
        let nanos = u32::try_from(ts.tv_nsec).unwrap_or(0).min(999_999_999);
        Ok((secs, nanos))
    }

    /// `send` on the bound socket.
    pub fn send(fd: &OwnedFd, frame: &[u8]) -> io::Result<usize> {
        // SAFETY: `frame` is a live slice of the length passed.
        let n = unsafe { libc::send(fd.as_raw_fd(), frame.as_ptr().cast(), frame.len(), 0) };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(usize::try_from(n).unwrap_or(0))
    }
}
