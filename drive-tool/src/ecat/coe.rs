//! The CoE SDO client (ETG.1000.6 §5.6.2): upload and download of an object through the mailbox, expedited
//! (up to 4 bytes in the request), normal (the whole value in one mailbox) and segmented (the rest in segments of
//! up to the mailbox's length), with the complete-access flag (the whole object from sub-index 0 or 1 at once,
//! §5.6.2.1.2) for a caller that wants it. The SDO part of each message is CiA 301's (command specifier, index, sub-index, 4 data bytes), after
//! a 2-byte CoE header (number, service 2 = request, 3 = response; ETG.1000.6 Table 35). An abort keeps the drive's
//! code, shown with its CiA 301 text as over CANopen.

use crate::ecat::mailbox::{kind, Mailbox};
use crate::sdo::SdoError;

/// CoE services (ETG.1000.6 Table 35).
const SDO_REQUEST: u8 = 2;
const SDO_RESPONSE: u8 = 3;
/// The CoE header plus the 8 bytes of the SDO header.
const SDO_HEADER_LEN: usize = 10;
/// Command specifiers (CiA 301 §7.2.4.3, bits 7..5) and the complete-access flag (ETG.1000.6 §5.6.2.1.2, bit 4).
const CCS_DOWNLOAD_SEGMENT: u8 = 0 << 5;
const CCS_INITIATE_DOWNLOAD: u8 = 1 << 5;
const CCS_INITIATE_UPLOAD: u8 = 2 << 5;
const CCS_UPLOAD_SEGMENT: u8 = 3 << 5;
const CS_ABORT: u8 = 4 << 5;
const COMPLETE_ACCESS: u8 = 0x10;
/// Largest value accepted from a drive (the dictionary's longest objects are far shorter).
const MAX_VALUE: usize = 1 << 20;

fn protocol(why: String) -> SdoError {
    SdoError::Protocol(why)
}

/// A CoE SDO request: CoE header (service 2), command, index, sub-index, then `rest` (4 bytes or more).
fn request(command: u8, index: u16, sub: u8, rest: &[u8]) -> Vec<u8> {
    let mut m = vec![0u8, SDO_REQUEST << 4, command];
    m.extend_from_slice(&index.to_le_bytes());
    m.push(sub);
    m.extend_from_slice(rest);
    m
}

/// The drive's next SDO response (CoE service 3); an abort becomes [`SdoError::Abort`].
async fn response(mbx: &mut Mailbox<'_>) -> Result<Vec<u8>, SdoError> {
    loop {
        let body = mbx.receive(kind::COE).await.map_err(|e| {
            if e == crate::ecat::mailbox::NO_ANSWER {
                SdoError::Timeout
            } else {
                SdoError::Mailbox(e)
            }
        })?;
        if body.len() < 3 {
            return Err(protocol(format!("a CoE answer of {} bytes", body.len())));
        }
        let service = body[1] >> 4;
        // An abort travels as an SDO request whichever side sends it (ETG.1000.6 §5.6.2.7.1).
        if (service == SDO_REQUEST || service == SDO_RESPONSE) && body[2] & 0xE0 == CS_ABORT {
            if body.len() < SDO_HEADER_LEN {
                return Err(protocol(format!("an abort of {} bytes", body.len())));
            }
            return Err(SdoError::Abort(u32::from_le_bytes([body[6], body[7], body[8], body[9]])));
        }
        if service != SDO_RESPONSE {
            // Another CoE service (SDO information, ...): not this transfer's answer.
            continue;
        }
        return Ok(body);
    }
}

/// Aborts the transfer on our side (the drive frees its SDO server), ignoring errors.
async fn abort(mbx: &mut Mailbox<'_>, index: u16, sub: u8, code: u32) {
    let _ = mbx.send(kind::COE, &request(CS_ABORT, index, sub, &code.to_le_bytes())).await;
}

fn check_multiplexer(answer: &[u8], index: u16, sub: u8, complete: bool) -> Result<(), SdoError> {
    let got_index = u16::from_le_bytes([answer[3], answer[4]]);
    // Complete access answers name the sub-index asked for (0 or 1).
    if got_index != index || (answer[5] != sub && !complete) {
        return Err(protocol(format!(
            "answer for 0x{got_index:04X}:{:02X}, asked for 0x{index:04X}:{sub:02X}",
            answer[5]
        )));
    }
    Ok(())
}

/// Uploads `index:sub` (`complete`: the whole object from `sub`, ETG.1000.6 §5.6.2.4).
pub async fn upload(mbx: &mut Mailbox<'_>, index: u16, sub: u8, complete: bool) -> Result<Vec<u8>, SdoError> {
    mbx.drain().await.map_err(SdoError::Mailbox)?;
    let ca = if complete { COMPLETE_ACCESS } else { 0 };
    mbx.send(kind::COE, &request(CCS_INITIATE_UPLOAD | ca, index, sub, &[0; 4])).await.map_err(SdoError::Mailbox)?;
    let answer = response(mbx).await?;
    if answer.len() < SDO_HEADER_LEN || answer[2] & 0xE0 != CCS_INITIATE_UPLOAD {
        abort(mbx, index, sub, 0x0504_0001).await;
        return Err(protocol(format!("initiate upload answered with 0x{:02X}", answer.get(2).unwrap_or(&0))));
    }
    check_multiplexer(&answer, index, sub, complete)?;
    let command = answer[2];
    if command & 0x02 != 0 {
        // Expedited: up to 4 bytes in the header (bits 3..2: bytes not used when the size is indicated).
        let len = if command & 0x01 != 0 { 4 - usize::from((command >> 2) & 0x03) } else { 4 };
        return Ok(answer[6..6 + len].to_vec());
    }
    let size = u32::from_le_bytes([answer[6], answer[7], answer[8], answer[9]]) as usize;
    if size > MAX_VALUE {
        abort(mbx, index, sub, 0x0504_0005).await;
        return Err(protocol(format!("the drive announces {size} bytes")));
    }
    let mut data = answer[SDO_HEADER_LEN..].to_vec();
    let mut toggle = 0u8;
    while data.len() < size {
        mbx.send(kind::COE, &request(CCS_UPLOAD_SEGMENT | toggle << 4, 0, 0, &[0; 4]))
            .await
            .map_err(SdoError::Mailbox)?;
        let segment = response(mbx).await?;
        if segment.len() < 3 || segment[2] & 0xE0 != 0 {
            abort(mbx, index, sub, 0x0504_0001).await;
            return Err(protocol(format!("upload segment answered with 0x{:02X}", segment.get(2).unwrap_or(&0))));
        }
        if (segment[2] >> 4) & 1 != toggle {
            abort(mbx, index, sub, 0x0503_0000).await;
            return Err(protocol("toggle bit not alternated".into()));
        }
        // A segment of fewer than 7 bytes is padded to 7 and says how many are unused (bits 3..1).
        let payload = &segment[3..];
        let unused = usize::from((segment[2] >> 1) & 0x07);
        let len = if payload.len() <= 7 { 7usize.saturating_sub(unused).min(payload.len()) } else { payload.len() };
        data.extend_from_slice(&payload[..len]);
        if segment[2] & 0x01 != 0 {
            break;
        }
        toggle ^= 1;
    }
    if data.len() < size {
        return Err(protocol(format!("{} bytes uploaded, the drive announced {size}", data.len())));
    }
    data.truncate(size);
    Ok(data)
}

/// Downloads `data` to `index:sub` (`complete`: the whole object from `sub`), expedited when it fits 4 bytes,
/// else normal and, beyond one mailbox, segmented; `progress` hears the bytes the drive confirmed.
pub async fn download(
    mbx: &mut Mailbox<'_>,
    index: u16,
    sub: u8,
    data: &[u8],
    complete: bool,
    progress: &mut dyn FnMut(usize),
) -> Result<(), SdoError> {
    mbx.drain().await.map_err(SdoError::Mailbox)?;
    let ca = if complete { COMPLETE_ACCESS } else { 0 };
    let first = if (1..=4).contains(&data.len()) {
        // Expedited with the size indicated: bits 3..2 the bytes not used of the 4.
        let mut bytes = [0u8; 4];
        bytes[..data.len()].copy_from_slice(data);
        let command = CCS_INITIATE_DOWNLOAD | ca | ((4 - data.len() as u8) << 2) | 0x03;
        mbx.send(kind::COE, &request(command, index, sub, &bytes)).await.map_err(SdoError::Mailbox)?;
        data.len()
    } else {
        // Normal: the complete size in the 4 data bytes, then as much of the value as the mailbox holds.
        let room = mbx.receive_len() - crate::ecat::mailbox::HEADER_LEN - SDO_HEADER_LEN;
        let first = data.len().min(room);
        let mut rest = (data.len() as u32).to_le_bytes().to_vec();
        rest.extend_from_slice(&data[..first]);
        mbx.send(kind::COE, &request(CCS_INITIATE_DOWNLOAD | ca | 0x01, index, sub, &rest))
            .await
            .map_err(SdoError::Mailbox)?;
        first
    };
    let answer = response(mbx).await?;
    if answer.len() < SDO_HEADER_LEN || answer[2] & 0xE0 != 3 << 5 {
        abort(mbx, index, sub, 0x0504_0001).await;
        return Err(protocol(format!("initiate download answered with 0x{:02X}", answer.get(2).unwrap_or(&0))));
    }
    check_multiplexer(&answer, index, sub, complete)?;
    progress(first);
    let mut sent = first;
    let mut toggle = 0u8;
    // Segments: CoE header, command, then up to mailbox length - 9 bytes (at least 7, padded).
    let room = mbx.receive_len() - crate::ecat::mailbox::HEADER_LEN - 3;
    while sent < data.len() {
        let len = (data.len() - sent).min(room);
        let last = sent + len == data.len();
        let unused = 7usize.saturating_sub(len) as u8;
        let command = CCS_DOWNLOAD_SEGMENT | toggle << 4 | unused << 1 | u8::from(last);
        let mut m = vec![0u8, SDO_REQUEST << 4, command];
        m.extend_from_slice(&data[sent..sent + len]);
        m.resize(m.len().max(10), 0);
        mbx.send(kind::COE, &m).await.map_err(SdoError::Mailbox)?;
        let answer = response(mbx).await?;
        if answer.len() < 3 || answer[2] & 0xE0 != 1 << 5 {
            abort(mbx, index, sub, 0x0504_0001).await;
            return Err(protocol(format!("download segment answered with 0x{:02X}", answer.get(2).unwrap_or(&0))));
        }
        if (answer[2] >> 4) & 1 != toggle {
            abort(mbx, index, sub, 0x0503_0000).await;
            return Err(protocol("toggle bit not alternated".into()));
        }
        sent += len;
        progress(sent);
        toggle ^= 1;
    }
    Ok(())
}
