//! FoE write (ETG.1000.5 §5.3, ETG.1000.6 §5.7): a file into the drive through the mailbox. Every FoE message has
//! a 6-byte header (opcode u8, reserved u8, a u32 that is the password of a request, the packet number of data and
//! acknowledge, the code of an error) and then the file name, the data or the error text.
//!
//! The write request (opcode 2) names the file; the drive acknowledges packet 0. Data packets (opcode 3) follow,
//! numbered from 1, each as long as the mailbox allows (its length - 12) except the last, which is shorter (an empty
//! one ends a file whose size is a multiple of it); the drive acknowledges each (opcode 4), answers busy (opcode 6)
//! when it cannot take it yet (the packet is sent again) or an error (opcode 5: code and text).

use std::fmt;

use crate::ecat::mailbox::{kind, Mailbox, HEADER_LEN};

/// FoE opcodes (ETG.1000.5 FoE header).
const WRQ: u8 = 2;
const DATA: u8 = 3;
const ACK: u8 = 4;
const ERR: u8 = 5;
const BUSY: u8 = 6;
/// Length of the FoE header.
const FOE_HEADER_LEN: usize = 6;
/// Most busy answers for one packet before giving up (a flash erase takes a few).
const MAX_BUSY: u32 = 10_000;

/// Why an FoE write failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FoeFailure {
    /// The drive answered with an FoE error: its code and text.
    Refused {
        /// The FoE error code (ETG.1000.5; IDX Table 7-155).
        code: u32,
        /// The drive's text.
        text: String,
    },
    /// The mailbox failed or the drive answered outside the protocol.
    Link(String),
}

impl fmt::Display for FoeFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Refused { code, text } if text.is_empty() => {
                write!(f, "FoE error 0x{code:04X} ({})", foe_error_name(*code))
            }
            Self::Refused { code, text } => write!(f, "FoE error 0x{code:04X} ({}): {text}", foe_error_name(*code)),
            Self::Link(why) => write!(f, "FoE: {why}"),
        }
    }
}

/// The name of an FoE error code (ETG.1000.5 FoE error codes; IDX Table 7-155).
pub fn foe_error_name(code: u32) -> &'static str {
    match code {
        0x8000 => "not defined",
        0x8001 => "not found",
        0x8002 => "access denied",
        0x8003 => "disk full",
        0x8004 => "illegal",
        0x8005 => "packet number wrong",
        0x8006 => "already exists",
        0x8007 => "no user",
        0x8008 => "bootstrap only",
        0x8009 => "not bootstrap",
        0x800A => "no rights",
        0x800B => "program error",
        0x800C => "checksum wrong",
        0x800D => "firmware does not fit the hardware",
        0x800F => "no file to read",
        0x8010 => "file header missing",
        0x8011 => "flash problem",
        0x8012 => "file incompatible",
        _ => "unknown FoE error",
    }
}

fn message(opcode: u8, word: u32, rest: &[u8]) -> Vec<u8> {
    let mut m = vec![opcode, 0];
    m.extend_from_slice(&word.to_le_bytes());
    m.extend_from_slice(rest);
    m
}

/// What the drive answered to a packet.
enum Answer {
    Ack(u32),
    Busy,
}

async fn answer(mbx: &mut Mailbox<'_>) -> Result<Answer, FoeFailure> {
    let body = mbx.receive(kind::FOE).await.map_err(FoeFailure::Link)?;
    if body.len() < FOE_HEADER_LEN {
        return Err(FoeFailure::Link(format!("an FoE answer of {} bytes", body.len())));
    }
    let word = u32::from_le_bytes([body[2], body[3], body[4], body[5]]);
    match body[0] {
        ACK => Ok(Answer::Ack(word)),
        BUSY => Ok(Answer::Busy),
        ERR => {
            let text = String::from_utf8_lossy(&body[FOE_HEADER_LEN..]).trim_end_matches('\0').to_owned();
            Err(FoeFailure::Refused { code: word, text })
        }
        other => Err(FoeFailure::Link(format!("FoE opcode {other} where an acknowledge belongs"))),
    }
}

/// Sends `body` and waits for the acknowledge of `packet`, sending it again while the drive is busy.
async fn send_acknowledged(mbx: &mut Mailbox<'_>, body: &[u8], packet: u32) -> Result<(), FoeFailure> {
    for _ in 0..MAX_BUSY {
        mbx.send(kind::FOE, body).await.map_err(FoeFailure::Link)?;
        match answer(mbx).await? {
            Answer::Ack(n) if n == packet => return Ok(()),
            Answer::Ack(n) => {
                return Err(FoeFailure::Link(format!("acknowledge of packet {n}, packet {packet} was sent")));
            }
            Answer::Busy => async_io::Timer::after(std::time::Duration::from_millis(1)).await,
        };
    }
    Err(FoeFailure::Link(format!("the drive stayed busy for {MAX_BUSY} answers to packet {packet}")))
}

/// Writes `file` as `name` with `password`; `progress` hears the bytes acknowledged.
pub async fn write(
    mbx: &mut Mailbox<'_>,
    name: &[u8],
    password: u32,
    file: &[u8],
    progress: &mut dyn FnMut(usize),
) -> Result<(), FoeFailure> {
    mbx.drain().await.map_err(FoeFailure::Link)?;
    send_acknowledged(mbx, &message(WRQ, password, name), 0).await?;
    let per_packet = mbx.receive_len() - HEADER_LEN - FOE_HEADER_LEN;
    let mut packet = 1u32;
    let mut sent = 0usize;
    loop {
        let len = (file.len() - sent).min(per_packet);
        send_acknowledged(mbx, &message(DATA, packet, &file[sent..sent + len]), packet).await?;
        sent += len;
        progress(sent);
        if len < per_packet {
            return Ok(());
        }
        packet = packet.wrapping_add(1);
    }
}
