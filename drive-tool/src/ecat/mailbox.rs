//! The EtherCAT mailbox as the master sees it (ETG.1000.4 §5.6 / ETG.1000.6 §5.2): a request written whole into
//! the drive's receive mailbox (SM0), the answer read whole out of its send mailbox (SM1) once the ESC reports it
//! full, through configured-address datagrams (FPWR/FPRD) of the master library. The protocols on top (CoE SDO,
//! FoE) exchange their messages with [`Mailbox::send`] and [`Mailbox::receive`].
//!
//! Every message starts with the 6-byte mailbox header: length u16 (of what follows the header), address u16,
//! channel/priority u8, then the type in bits 3..0 and the counter in bits 6..4 (ETG.1000.6 Table 29). The counter
//! runs 1..7 (ETG.1000.6 §5.2.1); a drive drops a request that repeats the previous one's counter as a
//! retransmission. Each run of the tool starts at 1: the init that precedes it takes the drive through INIT, where
//! the drive forgets the last counter (`firmware::ecat::mailbox`), and the master library sends no CoE request of
//! its own on the way to PRE-OP.

use std::time::{Duration, Instant};

use ethercrab::error::Error;
use ethercrab::{Command, MainDevice};

/// Mailbox types (ETG.1000.6 Table 29).
pub mod kind {
    /// CANopen over EtherCAT.
    pub const COE: u8 = 0x03;
    /// File access over EtherCAT.
    pub const FOE: u8 = 0x04;
}

/// What [`Mailbox::receive`] says when no answer came within the timeout.
pub const NO_ANSWER: &str = "no mailbox answer (timeout)";

/// Length of the mailbox header.
pub const HEADER_LEN: usize = 6;

/// Sync manager registers (ETG.1000.4 §6.7.2): SM n at 0x0800 + 8 n: start u16, length u16, control u8, status u8,
/// activate u8, PDI control u8.
const SM_BASE: u16 = 0x0800;
/// Bit 3 of an SM's status register: the mailbox is full (a message waits for the reader).
const SM_STATUS_FULL: u8 = 0x08;

/// A mailbox of one drive: where SM0 (master -> drive) and SM1 (drive -> master) are and how long.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// SM0 start and length.
    pub receive: (u16, u16),
    /// SM1 start and length.
    pub send: (u16, u16),
}

/// An error of the mailbox exchange (not of the protocol on top).
pub fn link_error(what: &str, e: Error) -> String {
    format!("{what}: {e}")
}

/// The mailbox of the drive at configured station address `station`.
pub struct Mailbox<'a> {
    master: &'a MainDevice<'a>,
    station: u16,
    layout: Layout,
    timeout: Duration,
    counter: &'a mut u8,
    /// Emergency messages (CoE service 1) that came instead of an answer: 8 bytes each (CiA 301 EMCY).
    pub emergencies: &'a mut Vec<[u8; 8]>,
}

impl<'a> Mailbox<'a> {
    /// The mailbox of `station` with `layout`, or the layout read from the ESC's SM0/SM1 registers (as the master
    /// configured them) when `None`.
    pub async fn open(
        master: &'a MainDevice<'a>,
        station: u16,
        layout: Option<Layout>,
        timeout: Duration,
        counter: &'a mut u8,
        emergencies: &'a mut Vec<[u8; 8]>,
    ) -> Result<Mailbox<'a>, String> {
        let sm = |n: u16| async move {
            let raw = Command::fprd(station, SM_BASE + 8 * n)
                .with_wkc(1)
                .receive::<[u8; 4]>(master)
                .await
                .map_err(|e| link_error(&format!("station 0x{station:04X} SM{n} registers"), e))?;
            Ok::<_, String>((u16::from_le_bytes([raw[0], raw[1]]), u16::from_le_bytes([raw[2], raw[3]])))
        };
        let layout = match layout {
            Some(known) => known,
            None => Layout { receive: sm(0).await?, send: sm(1).await? },
        };
        if layout.receive.1 < 16 || layout.send.1 < 16 {
            return Err(format!(
                "station 0x{station:04X} has no mailbox configured (SM0 {} bytes, SM1 {} bytes)",
                layout.receive.1, layout.send.1
            ));
        }
        Ok(Self { master, station, layout, timeout, counter, emergencies })
    }

    /// The SM0 length: the largest request, header included.
    pub fn receive_len(&self) -> usize {
        usize::from(self.layout.receive.1)
    }

    /// Where SM0 and SM1 are.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// Reads SM1's status byte.
    async fn send_mailbox_full(&self) -> Result<bool, String> {
        let status = Command::fprd(self.station, SM_BASE + 8 + 5)
            .with_wkc(1)
            .receive::<u8>(self.master)
            .await
            .map_err(|e| link_error("SM1 status", e))?;
        Ok(status & SM_STATUS_FULL != 0)
    }

    /// Reads the waiting message out of SM1 (the whole length: reading its last byte frees the mailbox).
    async fn read_message(&self) -> Result<Vec<u8>, String> {
        let (start, len) = self.layout.send;
        let data = Command::fprd(self.station, start)
            .with_wkc(1)
            .receive_slice(self.master, len)
            .await
            .map_err(|e| link_error("reading the send mailbox (SM1)", e))?;
        Ok(data.to_vec())
    }

    /// Throws away an answer left in SM1 by an earlier exchange that gave up waiting.
    pub async fn drain(&mut self) -> Result<(), String> {
        while self.send_mailbox_full().await? {
            self.read_message().await?;
        }
        Ok(())
    }

    /// Writes one message of type `kind` with `body` (the header is added) into SM0, retrying while the drive
    /// has not read the previous one (working counter 0).
    pub async fn send(&mut self, kind: u8, body: &[u8]) -> Result<(), String> {
        let (start, len) = self.layout.receive;
        let total = HEADER_LEN + body.len();
        if total > usize::from(len) {
            return Err(format!("a mailbox message of {total} bytes does not fit the {len}-byte mailbox"));
        }
        *self.counter = if *self.counter >= 7 { 1 } else { *self.counter + 1 };
        let mut message = vec![0u8; usize::from(len)];
        message[0..2].copy_from_slice(&(body.len() as u16).to_le_bytes());
        message[5] = (kind & 0x0F) | (*self.counter << 4);
        message[HEADER_LEN..total].copy_from_slice(body);
        let deadline = Instant::now() + self.timeout;
        loop {
            match Command::fpwr(self.station, start).with_wkc(1).send(self.master, message.as_slice()).await {
                Ok(()) => return Ok(()),
                Err(Error::WorkingCounter { .. }) if Instant::now() < deadline => {
                    async_io::Timer::after(Duration::from_millis(1)).await;
                }
                Err(e) => return Err(link_error("writing the receive mailbox (SM0)", e)),
            }
        }
    }

    /// The next message of type `kind` from SM1 within the timeout: its body (after the header, as long as the
    /// header says). CoE emergencies met on the way are kept in [`Mailbox::emergencies`]; other messages are
    /// dropped.
    pub async fn receive(&mut self, kind: u8) -> Result<Vec<u8>, String> {
        let deadline = Instant::now() + self.timeout;
        loop {
            if self.send_mailbox_full().await? {
                let message = self.read_message().await?;
                let len = usize::from(u16::from_le_bytes([message[0], message[1]]));
                let body = message.get(HEADER_LEN..HEADER_LEN + len).ok_or_else(|| {
                    format!("a mailbox answer says {len} bytes, the mailbox holds {}", message.len() - HEADER_LEN)
                })?;
                let got = message[5] & 0x0F;
                // CoE service 1 (bits 15..12 of the CoE header): an emergency (ETG.1000.6 §5.6.4).
                if got == kind::COE && body.len() >= 10 && body[1] >> 4 == 1 {
                    let mut emcy = [0u8; 8];
                    emcy.copy_from_slice(&body[2..10]);
                    self.emergencies.push(emcy);
                    continue;
                }
                // Mailbox type 0: a mailbox error (ETG.1000.6 §5.2.2) answers a request the drive could not take.
                if got == 0 && body.len() >= 4 {
                    let code = u16::from_le_bytes([body[2], body[3]]);
                    return Err(format!("mailbox error 0x{code:04X}: {}", mailbox_error_text(code)));
                }
                if got == kind {
                    return Ok(body.to_vec());
                }
                continue;
            }
            if Instant::now() >= deadline {
                return Err(NO_ANSWER.into());
            }
            async_io::Timer::after(Duration::from_micros(500)).await;
        }
    }
}

/// The text of a mailbox error code (ETG.1000.6 Table 30).
fn mailbox_error_text(code: u16) -> &'static str {
    match code {
        0x01 => "syntax of the mailbox header",
        0x02 => "unsupported mailbox protocol",
        0x03 => "invalid channel",
        0x04 => "service not supported",
        0x05 => "invalid mailbox header",
        0x06 => "mailbox data too short",
        0x07 => "no more memory",
        0x08 => "inconsistent data length",
        _ => "not defined by ETG.1000.6",
    }
}
