//! The bootloader's fallback service on CAN (issue 7, part 4): when slot A holds no valid image the bootloader
//! stays active and answers on the fieldbus so that a new image can be loaded (IDX L3345-3350: 0x1F51 reads 3
//! "no program"). The fieldbus is CAN: the 32 KiB bootloader cannot hold the ESC / EtherCAT stack, and the
//! seeds' bootloader serves one interface only (IDX L3345-3350).
//!
//! A compact CANopen node (CiA 301), sans-IO like [`crate::canopen`]: the platform hands it received frames
//! ([`FallbackNode::handle`]) and the time ([`FallbackNode::poll`]) and sends what it returns.
//!
//! # Objects (the reduced object set, E4 Table 4-32/4-33 L2162-2209; [`super::tables`])
//! | object | value |
//! |---|---|
//! | 0x1000:00 | 0x0000_012E ([`BOOTLOADER_DEVICE_TYPE`], CiA 302, E4 L2199) |
//! | 0x1008:00 | the generated device name (segmented upload) |
//! | 0x1018:00..04 | 4, vendor, product, revision 0 (E4 Table 4-33), serial from the generated defaults |
//! | 0x1F50:00/01 | 1 / program data (DOMAIN, write only) |
//! | 0x1F51:00/01 | 1 / 3 "no program" until a verified image waits, then 0 "stopped" (IDX L3343-3381) |
//! | 0x1F56:00/01 | 1 / [`BOOTLOADER_ID`] in bits 15..0, 0 in bits 31..16: no application (IDX L3382-3412) |
//! | 0x1F57:00/01 | 1 / status in bits 7..1, bit 0 = download in progress (IDX L3413-3473) |
//!
//! Every other object answers 0x0602_0000, a missing sub-index 0x0609_0011, a write to anything but 0x1F50:01
//! and 0x1F51:01 0x0601_0002, a read of 0x1F50:01 0x0601_0001.
//!
//! # SDO (CiA 301 §7.2.4; server on 0x600 + node-ID, answers on 0x580 + node-ID)
//! Expedited and segmented upload and download, block download with CRC (CiA 301 §7.2.4.3.9-7.2.4.3.16: PyPI
//! `canopen` writes 0x1F50 that way with `block_transfer=True`); block upload is not offered (0x0504_0001, as
//! every other unknown command specifier). One transfer at a time; 1 s without a frame of it aborts it with
//! 0x0504_0000 ([`SDO_TIMEOUT_MS`]). Segmented toggle errors 0x0503_0000, block CRC errors 0x0504_0004, sizes
//! 0x0607_0010 (indicated size differs from the data), 0x0607_0012 (too long), 0x0607_0013 (too short).
//! Frames on 0x600 + node-ID with another length than 8 are ignored (CiA 301 §7.2.4.3: SDO frames carry 8 bytes;
//! CANopenNode ignores them too).
//!
//! # Program control (one implementation: [`Download`] over slot B and BOOT_STATE, refusals by [`classify`])
//! * 0x1F51:01 = 0 *stop*: accepted (the program is stopped already); 0x80 (ESM acknowledge, EtherCAT only):
//!   accepted, nothing to do on CAN; other values 0x0609_0030.
//! * 3 *clear*: [`Download::clear`]; 0x1F57 reads 1 "no valid program" afterwards, 65 after an erase failure.
//! * 0x1F50:01: [`Download::write`] at increasing offsets, the end of the transfer [`Download::finish`]
//!   (header, CRC and signature verified in flash; 0x1F57 = 0 afterwards). An aborted transfer abandons the
//!   download: clear again.
//! * 1 *start*: with a verified image [`Download::activate`], then the reply and a reset (the bootloader swaps
//!   the image in at the next boot). Without one: 0x0800_0022 and 0x1F57 = 1 "no valid program available",
//!   the refusal program control gives for a start without a program (`program.rs` `start`, spec §4.8 item 6):
//!   the status says what is missing, while the abort of the failed download already carried its own status.
//! * 2 *reset*: the reply, then a reset.
//!
//! # NMT (CiA 301 §7.2.8.3.1; E4 Table 5-52 L3195-3223)
//! Reset node (0x81) and reset communication (0x82), to this node-ID or to all (0): reset. The other commands
//! are ignored: the bootloader stays pre-operational (no PDOs, no application to start by NMT).

use super::image::{ImageError, MAX_IMAGE_LEN};
use super::program::{classify, command, flash_status_word, program_state, status, BOOTLOADER_ID};
use super::swap::BootFlash;
use super::tables::BOOTLOADER_DEVICE_TYPE;
use super::update::{Download, Phase, UpdateError};
use super::verify::Trust;
use crate::canopen::frame::CanFrame;
use crate::canopen::ids::{cob_id, is_node_id, HEARTBEAT_BASE, NMT, SDO_RX_BASE, SDO_TX_BASE};
use crate::canopen::nmt::NmtCommand;
use crate::comm::sdo::crc::Crc16;
use crate::drive::objects::{
    FLASH_STATUS_IDENTIFICATION as FLASH_STATUS, PROGRAM_CONTROL, PROGRAM_DATA,
    PROGRAM_SOFTWARE_IDENTIFICATION as SOFTWARE_ID,
};
use crate::hal::flash::NorFlash;
use crate::od::abort::SdoAbort;
use crate::od::generated::{DEFAULT_NODE_ID, DEVICE_NAME, PRODUCT_CODE, SERIAL_NUMBER, VENDOR_ID};

/// An SDO transfer without a frame for this long is aborted with 0x0504_0000 (CiA 301 §7.2.4.3.17 leaves the
/// value to the device; CANopenNode's default server timeout is 1 s as well).
pub const SDO_TIMEOUT_MS: u32 = 1000;
/// Segments per block of a block download (CiA 301 §7.2.4.3.9: 1..=127). The largest block: the node keeps only
/// one segment (the last may carry padding, known only at the end), so the size costs no memory.
pub const BLOCK_SIZE: u8 = 127;
/// The verification buffer of [`Download::finish`] (a multiple of the F405's 4-byte write size).
const VERIFY_BUF_LEN: usize = 512;

const DEVICE_TYPE: u16 = 0x1000;
const DEVICE_NAME_INDEX: u16 = 0x1008;
const IDENTITY: u16 = 0x1018;

/// NMT command specifiers that reset (CiA 301 §7.2.8.3.1), as the application's NMT reads them.
const NMT_RESET_NODE: u8 = NmtCommand::ResetNode.specifier();
const NMT_RESET_COMMUNICATION: u8 = NmtCommand::ResetCommunication.specifier();
/// The abort frame's byte 0 (ccs/scs 4).
const ABORT: u8 = 0x80;

/// What the platform must do after a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FallbackReply {
    /// The answer to send (SDO response or abort), if any. Send it before acting on `reset`.
    pub frame: Option<CanFrame>,
    /// Reset the microcontroller (NMT reset node / reset communication, 0x1F51 = 1 start with a verified image,
    /// 0x1F51 = 2 reset): the bootloader runs again and swaps in a pending image.
    pub reset: bool,
}

/// The value of an upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Value {
    /// Up to 4 bytes: an expedited answer.
    Small([u8; 4], u8),
    /// More: a segmented answer.
    Long(&'static [u8]),
}

/// The SDO transfer in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Transfer {
    Idle,
    /// Segmented upload: `offset` bytes of `data` sent, `toggle` (bit 4) expected next.
    Upload {
        data: &'static [u8],
        offset: u32,
        toggle: u8,
    },
    /// Segmented download: `received` bytes so far, `size` if the client indicated it.
    Download {
        size: Option<u32>,
        received: u32,
        toggle: u8,
    },
    /// Block download: `received` bytes written, `seq` the last in-order segment of this block, `held` the
    /// latest segment if `pending` (written when the next one or the end arrives: only the end says how many of
    /// the last segment's bytes are data), `last` once the segment with c = 1 arrived in order; `crc` runs over
    /// the bytes written if the client sends one.
    Block {
        size: Option<u32>,
        received: u32,
        crc: Option<Crc16>,
        seq: u8,
        held: [u8; 7],
        pending: bool,
        last: bool,
    },
}

/// The bootloader's CANopen service while no valid application exists.
#[derive(Debug)]
pub struct FallbackNode {
    node_id: u8,
    trust: Trust,
    /// 0x1F57 status code (bits 7..1).
    status: u8,
    download: Download,
    transfer: Transfer,
    /// Index and sub-index of the transfer (echoed in responses and aborts).
    index: u16,
    sub: u8,
    /// The value byte of a 0x1F51:01 write arriving by segments.
    control: u8,
    last_ms: u32,
    buf: [u8; VERIFY_BUF_LEN],
}

fn u32_value(v: u32) -> Value {
    Value::Small(v.to_le_bytes(), 4)
}

impl FallbackNode {
    /// `node_id` 1..=127 (anything else: the device default), `reason`: the loader's ImageError (0x1F57 status).
    pub fn new(node_id: u8, trust: Trust, reason: ImageError) -> Self {
        let node_id = if is_node_id(node_id) { node_id } else { DEFAULT_NODE_ID };
        // No magic at all (an erased or never programmed slot): "no valid program available"; anything else is
        // the status program control gives the same fault in a download (`classify`).
        let status = match reason {
            ImageError::BadMagic => status::NO_PROGRAM,
            e => classify(UpdateError::Image(e)).status.unwrap_or(status::NO_PROGRAM),
        };
        Self {
            node_id,
            trust,
            status,
            download: Download::new(),
            transfer: Transfer::Idle,
            index: 0,
            sub: 0,
            control: 0,
            last_ms: 0,
            buf: [0; VERIFY_BUF_LEN],
        }
    }

    /// The node-ID the service answers on.
    pub fn node_id(&self) -> u8 {
        self.node_id
    }

    /// The boot-up message (0x700 + node-ID, one data byte 0x00), sent once when the service starts and after
    /// nothing else: the platform sends it.
    pub fn boot_up(&self) -> CanFrame {
        CanFrame::from_raw(cob_id(HEARTBEAT_BASE, self.node_id), 1, [0; 8], false)
    }

    /// 0x1F57:01: status in bits 7..1, bit 0 while a download is in progress (IDX L3413-3473), as
    /// [`super::program::ProgramControl::flash_status`].
    pub fn flash_status(&self) -> u32 {
        flash_status_word(self.status, self.download.phase())
    }

    /// One received frame (any identifier: frames not for this node give [`FallbackReply::default`]).
    pub fn handle<A: NorFlash, B: NorFlash, S: NorFlash>(
        &mut self,
        frame: &CanFrame,
        flash: &mut BootFlash<A, B, S>,
        now_ms: u32,
    ) -> FallbackReply {
        let none = FallbackReply::default();
        if frame.is_remote() {
            return none;
        }
        if frame.id() == NMT {
            let reset = matches!(frame.data(), [NMT_RESET_NODE | NMT_RESET_COMMUNICATION, node, ..]
                if *node == 0 || *node == self.node_id);
            return FallbackReply { frame: None, reset };
        }
        if frame.id() != cob_id(SDO_RX_BASE, self.node_id) || frame.dlc() != 8 {
            return none;
        }
        self.last_ms = now_ms;
        let mut reset = false;
        let answer = match self.sdo(&frame.raw_data(), flash, &mut reset) {
            Ok(answer) => answer,
            Err(abort) => {
                reset = false;
                Some(self.abort(abort))
            }
        };
        FallbackReply { frame: answer.map(|d| self.response(d)), reset }
    }

    /// Time passes: an SDO transfer idle for 1 s is aborted with 0x0504_0000 (the returned frame).
    pub fn poll(&mut self, now_ms: u32) -> Option<CanFrame> {
        if self.transfer == Transfer::Idle || now_ms.wrapping_sub(self.last_ms) < SDO_TIMEOUT_MS {
            return None;
        }
        let d = self.abort(SdoAbort::Timeout);
        Some(self.response(d))
    }

    fn response(&self, data: [u8; 8]) -> CanFrame {
        CanFrame::from_raw(cob_id(SDO_TX_BASE, self.node_id), 8, data, false)
    }

    /// A response frame's bytes: `cs`, the transfer's index and sub-index, `rest`.
    fn reply(&self, cs: u8, rest: [u8; 4]) -> [u8; 8] {
        let [i0, i1] = self.index.to_le_bytes();
        let [r0, r1, r2, r3] = rest;
        [cs, i0, i1, self.sub, r0, r1, r2, r3]
    }

    /// Ends the transfer with `abort` (a program download is abandoned with it) and returns the abort frame.
    fn abort(&mut self, abort: SdoAbort) -> [u8; 8] {
        self.end_transfer();
        self.reply(ABORT, abort.code().to_le_bytes())
    }

    fn end_transfer(&mut self) {
        if self.transfer != Transfer::Idle && self.index == PROGRAM_DATA {
            self.download.abort();
        }
        self.transfer = Transfer::Idle;
    }

    /// Records a refusal's 0x1F57 status and returns its abort code.
    fn refuse(&mut self, e: UpdateError) -> SdoAbort {
        let r = classify(e);
        if let Some(s) = r.status {
            self.status = s;
        }
        r.abort
    }

    /// The value of an object for an upload (module documentation).
    fn read(&self, index: u16, sub: u8) -> Result<Value, SdoAbort> {
        let one = Value::Small([1, 0, 0, 0], 1);
        let value = match (index, sub) {
            (DEVICE_TYPE, 0) => u32_value(BOOTLOADER_DEVICE_TYPE),
            (DEVICE_NAME_INDEX, 0) => Value::Long(DEVICE_NAME.as_bytes()),
            (IDENTITY, 0) => Value::Small([4, 0, 0, 0], 1),
            (IDENTITY, 1) => u32_value(VENDOR_ID),
            (IDENTITY, 2) => u32_value(PRODUCT_CODE),
            // Revision: software and application version 0 while the bootloader is active (E4 Table 4-33).
            (IDENTITY, 3) => u32_value(0),
            (IDENTITY, 4) => u32_value(SERIAL_NUMBER),
            (PROGRAM_DATA | PROGRAM_CONTROL | SOFTWARE_ID | FLASH_STATUS, 0) => one,
            (PROGRAM_DATA, 1) => return Err(SdoAbort::WriteOnly),
            (PROGRAM_CONTROL, 1) => {
                let state = match self.download.phase() {
                    Phase::Verified(_) | Phase::Activated(_) => program_state::STOPPED,
                    _ => program_state::NO_PROGRAM,
                };
                Value::Small([state, 0, 0, 0], 1)
            }
            (SOFTWARE_ID, 1) => u32_value(u32::from(BOOTLOADER_ID)),
            (FLASH_STATUS, 1) => u32_value(self.flash_status()),
            (
                DEVICE_TYPE | DEVICE_NAME_INDEX | IDENTITY | PROGRAM_DATA | PROGRAM_CONTROL | SOFTWARE_ID
                | FLASH_STATUS,
                _,
            ) => return Err(SdoAbort::SubindexDoesNotExist),
            _ => return Err(SdoAbort::ObjectDoesNotExist),
        };
        Ok(value)
    }

    /// Whether `index:sub` may be written: 0x1F50:01 and 0x1F51:01 only; the rest exists read-only or not at all.
    fn writable(&self, index: u16, sub: u8) -> Result<(), SdoAbort> {
        match (index, sub) {
            (PROGRAM_DATA | PROGRAM_CONTROL, 1) => Ok(()),
            _ => match self.read(index, sub) {
                Ok(_) | Err(SdoAbort::WriteOnly) => Err(SdoAbort::ReadOnly),
                Err(e) => Err(e),
            },
        }
    }

    /// The size an initiate indicated, checked against the object: 0x1F51:01 is UNSIGNED8, 0x1F50:01 at most
    /// an image area.
    fn check_size(&self, size: u32) -> Result<(), SdoAbort> {
        let max = if self.index == PROGRAM_DATA { MAX_IMAGE_LEN } else { 1 };
        if size > max {
            Err(SdoAbort::LengthTooHigh)
        } else if size == 0 && self.index == PROGRAM_CONTROL {
            Err(SdoAbort::LengthTooLow)
        } else {
            Ok(())
        }
    }

    /// `data` of the download at `offset`.
    fn chunk<A: NorFlash, B: NorFlash, S: NorFlash>(
        &mut self,
        flash: &mut BootFlash<A, B, S>,
        offset: u32,
        data: &[u8],
    ) -> Result<(), SdoAbort> {
        if self.index == PROGRAM_DATA {
            let trust = self.trust;
            return self.download.write(&mut flash.slot_b, offset, data, &trust).map_err(|e| self.refuse(e));
        }
        let len = u32::try_from(data.len()).unwrap_or(u32::MAX);
        self.check_size(offset.saturating_add(len))?;
        if let (0, Some(b)) = (offset, data.first()) {
            self.control = *b;
        }
        Ok(())
    }

    /// The download of `total` bytes is complete: verify the image, or carry out the 0x1F51 command.
    fn complete<A: NorFlash, B: NorFlash, S: NorFlash>(
        &mut self,
        flash: &mut BootFlash<A, B, S>,
        total: u32,
        reset: &mut bool,
    ) -> Result<(), SdoAbort> {
        if self.index == PROGRAM_DATA {
            self.download.finish(&mut flash.slot_b, &self.trust, &mut self.buf).map_err(|e| self.refuse(e))?;
            self.status = status::OK;
            return Ok(());
        }
        if total == 0 {
            return Err(SdoAbort::LengthTooLow);
        }
        match self.control {
            command::STOP | command::ESM_ACKNOWLEDGE => Ok(()),
            command::CLEAR => match self.download.clear(&mut flash.slot_b, &mut flash.state, None) {
                Ok(()) => {
                    self.status = status::NO_PROGRAM;
                    Ok(())
                }
                Err(UpdateError::Flash(_)) => {
                    self.status = status::CLEAR_ERROR;
                    Err(SdoAbort::HardwareError)
                }
                Err(e) => Err(self.refuse(e)),
            },
            command::START => match self.download.phase() {
                Phase::Activated(_) => {
                    *reset = true;
                    Ok(())
                }
                Phase::Verified(_) => {
                    self.download.activate(&mut flash.state).map_err(|e| self.refuse(e))?;
                    *reset = true;
                    Ok(())
                }
                _ => {
                    self.status = status::NO_PROGRAM;
                    Err(SdoAbort::DeviceState)
                }
            },
            command::RESET => {
                *reset = true;
                Ok(())
            }
            _ => Err(SdoAbort::InvalidValue),
        }
    }

    /// One SDO request; `Ok(None)`: no answer (a client abort, a block segment inside a block).
    fn sdo<A: NorFlash, B: NorFlash, S: NorFlash>(
        &mut self,
        d: &[u8; 8],
        flash: &mut BootFlash<A, B, S>,
        reset: &mut bool,
    ) -> Result<Option<[u8; 8]>, SdoAbort> {
        let [b0, i0, i1, sub, p0, p1, p2, p3] = *d;
        if b0 == ABORT {
            // The client aborts (CiA 301 §7.2.4.3.17; in a block also "c = 1, seqno 0", which no segment is).
            self.end_transfer();
            return Ok(None);
        }
        let payload = [p0, p1, p2, p3];
        let segment = [i0, i1, sub, p0, p1, p2, p3];
        let toggle_bit = b0 & 0x10;
        match self.transfer {
            Transfer::Idle => {
                self.index = u16::from_le_bytes([i0, i1]);
                self.sub = sub;
                match b0 >> 5 {
                    1 => self.initiate_download(b0, payload, flash, reset),
                    2 => self.initiate_upload(),
                    6 if b0 & 1 == 0 => {
                        self.writable(self.index, sub)?;
                        let size = u32::from_le_bytes(payload);
                        if b0 & 0x02 != 0 {
                            self.check_size(size)?;
                        }
                        self.transfer = Transfer::Block {
                            size: (b0 & 0x02 != 0).then_some(size),
                            received: 0,
                            crc: (b0 & 0x04 != 0).then(Crc16::new),
                            seq: 0,
                            held: [0; 7],
                            pending: false,
                            last: false,
                        };
                        // scs 5, sc = 1 (the server checks the CRC), ss = 0; blksize in byte 4.
                        Ok(Some(self.reply(0xA4, [BLOCK_SIZE, 0, 0, 0])))
                    }
                    _ => {
                        (self.index, self.sub) = (0, 0);
                        Err(SdoAbort::CommandSpecifier)
                    }
                }
            }
            Transfer::Upload { data, offset, toggle } => {
                if b0 >> 5 != 3 {
                    return Err(SdoAbort::CommandSpecifier);
                }
                if toggle_bit != toggle {
                    return Err(SdoAbort::ToggleBit);
                }
                let rest = data.get(offset as usize..).unwrap_or(&[]);
                let n = rest.len().min(7);
                let mut seg = [0u8; 7];
                if let (Some(to), Some(from)) = (seg.get_mut(..n), rest.get(..n)) {
                    to.copy_from_slice(from);
                }
                let last = rest.len() <= 7;
                // scs 0: t, n = bytes without data (bits 3..1), c = last.
                let unused = u8::try_from(7usize.saturating_sub(n)).unwrap_or(0);
                let [s0, s1, s2, s3, s4, s5, s6] = seg;
                let out = [toggle | (unused << 1) | u8::from(last), s0, s1, s2, s3, s4, s5, s6];
                self.transfer = if last {
                    Transfer::Idle
                } else {
                    Transfer::Upload { data, offset: offset.saturating_add(7), toggle: toggle ^ 0x10 }
                };
                Ok(Some(out))
            }
            Transfer::Download { size, received, toggle } => {
                if b0 >> 5 != 0 {
                    return Err(SdoAbort::CommandSpecifier);
                }
                if toggle_bit != toggle {
                    return Err(SdoAbort::ToggleBit);
                }
                let n = 7usize.saturating_sub(usize::from((b0 >> 1) & 0x07));
                let data = segment.get(..n).unwrap_or(&[]);
                let total = received.saturating_add(n as u32);
                if size.is_some_and(|s| total > s) {
                    return Err(SdoAbort::LengthTooHigh);
                }
                self.chunk(flash, received, data)?;
                let last = b0 & 1 != 0;
                if last {
                    if size.is_some_and(|s| total != s) {
                        return Err(SdoAbort::LengthMismatch);
                    }
                    self.transfer = Transfer::Idle;
                    self.complete(flash, total, reset)?;
                } else {
                    self.transfer = Transfer::Download { size, received: total, toggle: toggle ^ 0x10 };
                }
                Ok(Some([0x20 | toggle, 0, 0, 0, 0, 0, 0, 0]))
            }
            Transfer::Block { size, mut received, mut crc, mut seq, mut held, mut pending, last: false } => {
                let seqno = b0 & 0x7F;
                let c = b0 & 0x80 != 0;
                let mut last = false;
                if seqno == seq.saturating_add(1) {
                    // In order. The held segment was not the last one: all its 7 bytes are data.
                    if pending {
                        let total = received.saturating_add(7);
                        if size.is_some_and(|s| total > s) {
                            return Err(SdoAbort::LengthTooHigh);
                        }
                        self.chunk(flash, received, &held)?;
                        if let Some(crc) = crc.as_mut() {
                            crc.update(&held);
                        }
                        received = total;
                    }
                    (held, pending, seq, last) = (segment, true, seqno, c);
                }
                // At the end of a block (or of the data) acknowledge the last segment in order (CiA 301
                // §7.2.4.3.13); the client repeats the rest in the next block, numbered from 1 again. Segments
                // out of order are dropped (a frame lost in an overrun of the receive FIFO costs a repetition).
                let end_of_block = c || seqno >= BLOCK_SIZE;
                let answer = end_of_block.then_some([0xA2, seq, BLOCK_SIZE, 0, 0, 0, 0, 0]);
                if end_of_block && !last {
                    seq = 0;
                }
                self.transfer = Transfer::Block { size, received, crc, seq, held, pending, last };
                Ok(answer)
            }
            Transfer::Block { size, received, crc, held, last: true, .. } => {
                // End of block download: ccs 6, n = bytes of the last segment without data, cs = 1.
                if b0 & 0xE3 != 0xC1 {
                    return Err(SdoAbort::CommandSpecifier);
                }
                let n = 7usize.saturating_sub(usize::from((b0 >> 2) & 0x07));
                let data = held.get(..n).unwrap_or(&[]);
                let total = received.saturating_add(n as u32);
                if size.is_some_and(|s| total > s) {
                    return Err(SdoAbort::LengthTooHigh);
                }
                self.chunk(flash, received, data)?;
                if size.is_some_and(|s| total != s) {
                    return Err(SdoAbort::LengthMismatch);
                }
                let crc_of_all = crc.map(|mut c| {
                    c.update(data);
                    c.value()
                });
                if crc_of_all.is_some_and(|v| v != u16::from_le_bytes([i0, i1])) {
                    return Err(SdoAbort::CrcError);
                }
                self.transfer = Transfer::Idle;
                self.complete(flash, total, reset)?;
                Ok(Some([0xA1, 0, 0, 0, 0, 0, 0, 0]))
            }
        }
    }

    fn initiate_upload(&mut self) -> Result<Option<[u8; 8]>, SdoAbort> {
        match self.read(self.index, self.sub)? {
            Value::Small(bytes, len) => {
                // scs 2, n = 4 - len, e = 1, s = 1.
                let unused = 4u8.saturating_sub(len);
                Ok(Some(self.reply(0x43 | (unused << 2), bytes)))
            }
            Value::Long(data) => {
                let len = u32::try_from(data.len()).unwrap_or(u32::MAX);
                self.transfer = Transfer::Upload { data, offset: 0, toggle: 0 };
                // scs 2, e = 0, s = 1: the size in bytes 4..7.
                Ok(Some(self.reply(0x41, len.to_le_bytes())))
            }
        }
    }

    fn initiate_download<A: NorFlash, B: NorFlash, S: NorFlash>(
        &mut self,
        b0: u8,
        payload: [u8; 4],
        flash: &mut BootFlash<A, B, S>,
        reset: &mut bool,
    ) -> Result<Option<[u8; 8]>, SdoAbort> {
        self.writable(self.index, self.sub)?;
        let sized = b0 & 0x01 != 0;
        if b0 & 0x02 != 0 {
            // Expedited: n bytes of 4..7 carry no data when the size is indicated; without it the object's size.
            let len = match (sized, self.index) {
                (true, _) => 4u32.saturating_sub(u32::from((b0 >> 2) & 0x03)),
                (false, PROGRAM_CONTROL) => 1,
                (false, _) => 4,
            };
            self.check_size(len)?;
            self.chunk(flash, 0, payload.get(..len as usize).unwrap_or(&[]))?;
            self.complete(flash, len, reset)?;
        } else {
            let size = u32::from_le_bytes(payload);
            if sized {
                self.check_size(size)?;
            }
            self.transfer = Transfer::Download { size: sized.then_some(size), received: 0, toggle: 0 };
        }
        Ok(Some(self.reply(0x60, [0; 4])))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boot::image::{ImageHeader, HARDWARE_ID, HEADER_LEN, MAX_PAYLOAD_LEN};
    use crate::boot::loader::{boot, Outcome};
    use crate::boot::sign::{public_key, sign_image};
    use crate::hal::flash::{FlashError, Geometry};

    /// A NOR flash region in RAM with the F405's semantics (erase to 0xFF, programming only clears bits).
    struct RamFlash {
        geometry: Geometry,
        data: Vec<u8>,
    }

    impl RamFlash {
        fn new(sector_size: u32, sector_count: u32) -> Self {
            let geometry = Geometry { sector_size, sector_count, write_size: 4 };
            Self { geometry, data: vec![0xFF; geometry.capacity() as usize] }
        }
    }

    impl NorFlash for RamFlash {
        fn geometry(&self) -> Geometry {
            self.geometry
        }
        fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), FlashError> {
            let at = offset as usize;
            let src = self.data.get(at..at + buf.len()).ok_or(FlashError::OutOfBounds)?;
            buf.copy_from_slice(src);
            Ok(())
        }
        fn program(&mut self, offset: u32, data: &[u8]) -> Result<(), FlashError> {
            if !offset.is_multiple_of(4) || !data.len().is_multiple_of(4) {
                return Err(FlashError::Misaligned);
            }
            let at = offset as usize;
            let dst = self.data.get_mut(at..at + data.len()).ok_or(FlashError::OutOfBounds)?;
            if dst.iter().zip(data).any(|(old, new)| old & new != *new) {
                return Err(FlashError::NotErased);
            }
            dst.copy_from_slice(data);
            Ok(())
        }
        fn erase_sector(&mut self, sector: u32) -> Result<(), FlashError> {
            let start = self.geometry.sector_start(sector).ok_or(FlashError::OutOfBounds)? as usize;
            self.data[start..start + self.geometry.sector_size as usize].fill(0xFF);
            Ok(())
        }
    }

    type Flash = BootFlash<RamFlash, RamFlash, RamFlash>;

    const SEED: [u8; 32] = [7; 32];
    const NODE: u8 = 5;

    fn trust() -> Trust {
        Trust { public_key: public_key(&SEED), hardware_id: HARDWARE_ID, max_payload: MAX_PAYLOAD_LEN }
    }

    /// The memory.x layout: slot A 3 x 128 KiB, slot B one sector more, BOOT_STATE 64 KiB; slot A erased.
    fn flash() -> Flash {
        BootFlash {
            slot_a: RamFlash::new(128 * 1024, 3),
            slot_b: RamFlash::new(128 * 1024, 4),
            state: RamFlash::new(64 * 1024, 1),
        }
    }

    /// A signed image (header then payload) of firmware `version` with a payload of `len` bytes.
    fn image(version: u32, len: usize) -> Vec<u8> {
        let payload: Vec<u8> = (0..len).map(|i| (i * 31 + version as usize) as u8).collect();
        let mut header = ImageHeader::new(HARDWARE_ID, version, version & 0xFFFF_0000, 0, 0);
        sign_image(&mut header, &payload, &SEED, [1; 16]);
        let mut out = header.to_bytes().to_vec();
        out.extend_from_slice(&payload);
        out
    }

    /// A client talking to one node over one flash, with a clock.
    struct Client {
        node: FallbackNode,
        flash: Flash,
        now: u32,
        resets: u32,
    }

    impl Client {
        fn new() -> Self {
            Self { node: FallbackNode::new(NODE, trust(), ImageError::BadMagic), flash: flash(), now: 0, resets: 0 }
        }

        /// One request; the response's 8 bytes (`None`: no answer).
        fn request(&mut self, data: [u8; 8]) -> Option<[u8; 8]> {
            self.now = self.now.wrapping_add(1);
            let frame = CanFrame::new(0x600 + u16::from(NODE), &data).unwrap();
            let reply = self.node.handle(&frame, &mut self.flash, self.now);
            self.resets += u32::from(reply.reset);
            reply.frame.map(|f| {
                assert_eq!((f.id(), f.dlc()), (0x580 + u16::from(NODE), 8));
                f.raw_data()
            })
        }

        fn abort_code(r: [u8; 8]) -> Result<[u8; 8], u32> {
            if r[0] == 0x80 {
                Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]]))
            } else {
                Ok(r)
            }
        }

        /// An upload, expedited or segmented; the value or the abort code.
        fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
            let [i0, i1] = index.to_le_bytes();
            let r = Self::abort_code(self.request([0x40, i0, i1, sub, 0, 0, 0, 0]).unwrap())?;
            assert_eq!(&r[1..4], &[i0, i1, sub]);
            if r[0] & 0x02 != 0 {
                assert_eq!(r[0] & 0xF3, 0x43, "expedited with size");
                return Ok(r[4..8 - usize::from((r[0] >> 2) & 3)].to_vec());
            }
            assert_eq!(r[0], 0x41);
            let size = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
            let mut out = Vec::new();
            let mut toggle = 0u8;
            loop {
                let r = Self::abort_code(self.request([0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]).unwrap())?;
                assert_eq!(r[0] & 0xF0, toggle);
                out.extend_from_slice(&r[1..8 - usize::from((r[0] >> 1) & 7)]);
                if r[0] & 1 != 0 {
                    break;
                }
                toggle ^= 0x10;
            }
            assert_eq!(out.len(), size);
            Ok(out)
        }

        fn read_u32(&mut self, index: u16, sub: u8) -> u32 {
            let v = self.read(index, sub).unwrap();
            assert_eq!(v.len(), 4, "{index:#06x}:{sub}");
            u32::from_le_bytes(v.try_into().unwrap())
        }

        /// An expedited download of `value` (1..=4 bytes, size indicated).
        fn write(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
            let [i0, i1] = index.to_le_bytes();
            let mut d = [0x23 | ((4 - value.len() as u8) << 2), i0, i1, sub, 0, 0, 0, 0];
            d[4..4 + value.len()].copy_from_slice(value);
            let r = Self::abort_code(self.request(d).unwrap())?;
            assert_eq!(r, [0x60, i0, i1, sub, 0, 0, 0, 0]);
            Ok(())
        }

        /// A segmented download of `data`, size indicated.
        fn write_segmented(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), u32> {
            let [i0, i1] = index.to_le_bytes();
            let [s0, s1, s2, s3] = (data.len() as u32).to_le_bytes();
            let r = Self::abort_code(self.request([0x21, i0, i1, sub, s0, s1, s2, s3]).unwrap())?;
            assert_eq!(r, [0x60, i0, i1, sub, 0, 0, 0, 0]);
            let mut toggle = 0u8;
            let chunks: Vec<&[u8]> = data.chunks(7).collect();
            for (k, chunk) in chunks.iter().enumerate() {
                let last = k + 1 == chunks.len();
                let mut d = [toggle | ((7 - chunk.len() as u8) << 1) | u8::from(last), 0, 0, 0, 0, 0, 0, 0];
                d[1..=chunk.len()].copy_from_slice(chunk);
                let r = Self::abort_code(self.request(d).unwrap())?;
                assert_eq!(r, [0x20 | toggle, 0, 0, 0, 0, 0, 0, 0]);
                toggle ^= 0x10;
            }
            Ok(())
        }

        /// A block download of `data` with CRC (`crc_delta` is added to the CRC sent: nonzero corrupts it);
        /// the segment numbers in `lose` (counted over the whole transfer, first is 0) are lost once.
        fn write_block(&mut self, index: u16, sub: u8, data: &[u8], lose: &[usize], crc_delta: u16) -> Result<(), u32> {
            let [i0, i1] = index.to_le_bytes();
            let [s0, s1, s2, s3] = (data.len() as u32).to_le_bytes();
            let r = Self::abort_code(self.request([0xC6, i0, i1, sub, s0, s1, s2, s3]).unwrap())?;
            assert_eq!(&r[..4], &[0xA4, i0, i1, sub]);
            let blksize = usize::from(r[4]);
            let chunks: Vec<&[u8]> = data.chunks(7).collect();
            let mut lost: Vec<usize> = lose.to_vec();
            let mut next = 0usize;
            while next < chunks.len() {
                let mut ack = None;
                let mut seqno = 0usize;
                while seqno < blksize && next + seqno < chunks.len() {
                    let k = next + seqno;
                    seqno += 1;
                    let last = k + 1 == chunks.len();
                    let mut d = [(u8::from(last) << 7) | seqno as u8, 0, 0, 0, 0, 0, 0, 0];
                    d[1..=chunks[k].len()].copy_from_slice(chunks[k]);
                    if let Some(p) = lost.iter().position(|l| *l == k) {
                        lost.remove(p);
                        continue;
                    }
                    if let Some(r) = self.request(d) {
                        ack = Some(Self::abort_code(r)?);
                    }
                }
                let r = ack.expect("the block is acknowledged");
                assert_eq!((r[0], r[2]), (0xA2, blksize as u8));
                next += usize::from(r[1]);
            }
            let unused = (7 - chunks.last().map_or(7, |c| c.len())) as u8;
            let [c0, c1] = Crc16::of(data).wrapping_add(crc_delta).to_le_bytes();
            let r = Self::abort_code(self.request([0xC1 | (unused << 2), c0, c1, 0, 0, 0, 0, 0]).unwrap())?;
            assert_eq!(r[0], 0xA1);
            Ok(())
        }
    }

    fn status(c: &mut Client) -> u32 {
        c.read_u32(FLASH_STATUS, 1)
    }

    #[test]
    fn every_object_of_the_reduced_set_reads_its_bootloader_value() {
        let mut c = Client::new();
        assert_eq!(c.read_u32(0x1000, 0), 0x0000_012E);
        assert_eq!(c.read(0x1008, 0).unwrap(), DEVICE_NAME.as_bytes());
        assert!(DEVICE_NAME.len() > 4, "0x1008 exercises the segmented upload");
        assert_eq!(c.read(0x1018, 0).unwrap(), [4]);
        assert_eq!(c.read_u32(0x1018, 1), VENDOR_ID);
        assert_eq!(c.read_u32(0x1018, 2), PRODUCT_CODE);
        assert_eq!(c.read_u32(0x1018, 3), 0);
        assert_eq!(c.read_u32(0x1018, 4), SERIAL_NUMBER);
        for index in [0x1F50, 0x1F51, 0x1F56, 0x1F57] {
            assert_eq!(c.read(index, 0).unwrap(), [1], "{index:#06x}");
        }
        assert_eq!(c.read(0x1F51, 1).unwrap(), [program_state::NO_PROGRAM]);
        assert_eq!(c.read_u32(0x1F56, 1), u32::from(BOOTLOADER_ID));
        // Slot A erased (no magic): status 1 "no valid program", no download in progress.
        assert_eq!(status(&mut c), 1 << 1);
    }

    #[test]
    fn the_flash_status_starts_from_the_loaders_reason() {
        let cases = [
            (ImageError::BadMagic, status::NO_PROGRAM),
            (ImageError::Crc { expected: 1, computed: 2 }, status::DATA_ERROR),
            (ImageError::BadSignature, status::SIGNATURE_INVALID),
            (ImageError::WrongHardware { expected: 1, found: 2 }, status::HARDWARE_MISMATCH),
            (ImageError::Truncated, status::DATA_ERROR),
        ];
        for (reason, code) in cases {
            let node = FallbackNode::new(NODE, trust(), reason);
            assert_eq!(node.flash_status(), u32::from(code) << 1, "{reason:?}");
        }
    }

    #[test]
    fn bad_requests_get_their_abort_codes() {
        let mut c = Client::new();
        assert_eq!(c.read(0x6040, 0), Err(0x0602_0000));
        assert_eq!(c.read(0x1010, 1), Err(0x0602_0000));
        assert_eq!(c.read(0x1018, 5), Err(0x0609_0011));
        assert_eq!(c.read(0x1F51, 2), Err(0x0609_0011));
        assert_eq!(c.read(0x1F50, 1), Err(0x0601_0001));
        assert_eq!(c.write(0x1000, 0, &[0, 0, 0, 0]), Err(0x0601_0002));
        assert_eq!(c.write(0x1F56, 1, &[0, 0, 0, 0]), Err(0x0601_0002));
        assert_eq!(c.write(0x1F50, 0, &[2]), Err(0x0601_0002));
        assert_eq!(c.write(0x6040, 0, &[0, 0]), Err(0x0602_0000));
        assert_eq!(c.write(0x1F51, 3, &[0]), Err(0x0609_0011));
        // 0x1F51:01 is UNSIGNED8: longer 0x0607_0012, an indicated size of 0 0x0607_0013, an unknown command
        // 0x0609_0030.
        assert_eq!(c.write(0x1F51, 1, &[3, 0]), Err(0x0607_0012));
        assert_eq!(c.request([0x21, 0x51, 0x1F, 1, 0, 0, 0, 0]).map(Client::abort_code), Some(Err(0x0607_0013)));
        assert_eq!(c.write(0x1F51, 1, &[5]), Err(0x0609_0030));
        // Block upload (ccs 5) and ccs 7 are not offered; a segment without a transfer is no command either.
        for b0 in [0xA0, 0xE0, 0x00, 0x60] {
            let r = c.request([b0, 0x00, 0x10, 0, 0, 0, 0, 0]).unwrap();
            assert_eq!(Client::abort_code(r), Err(0x0504_0001), "{b0:#04x}");
        }
        // The indicated size differs from the data sent: 0x0607_0010.
        assert_eq!(c.request([0x21, 0x51, 0x1F, 1, 1, 0, 0, 0]).unwrap()[0], 0x60);
        let r = c.request([0x0B, 3, 0, 0, 0, 0, 0, 0]).unwrap(); // 2 bytes, last
        assert_eq!(Client::abort_code(r), Err(0x0607_0012));
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.request([0x21, 0x50, 0x1F, 1, 10, 0, 0, 0]).unwrap()[0], 0x60);
        let r = c.request([0x01, 1, 2, 3, 4, 5, 6, 7]).unwrap(); // 7 bytes, last: 3 short of 10
        assert_eq!(Client::abort_code(r), Err(0x0607_0010));
        // An image larger than the slot is refused at the initiate.
        let [s0, s1, s2, s3] = (MAX_IMAGE_LEN + 1).to_le_bytes();
        let r = c.request([0x21, 0x50, 0x1F, 1, s0, s1, s2, s3]).unwrap();
        assert_eq!(Client::abort_code(r), Err(0x0607_0012));
        let r = c.request([0xC6, 0x50, 0x1F, 1, s0, s1, s2, s3]).unwrap();
        assert_eq!(Client::abort_code(r), Err(0x0607_0012));
        // The abort echoes index and sub-index.
        assert_eq!(&c.request([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]).unwrap()[..4], &[0x80, 0x41, 0x60, 0]);
        assert_eq!(c.resets, 0);
    }

    #[test]
    fn a_toggle_error_aborts_the_segmented_transfers() {
        let mut c = Client::new();
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.request([0x21, 0x50, 0x1F, 1, 14, 0, 0, 0]).unwrap()[0], 0x60);
        assert_eq!(c.request([0x00, 1, 2, 3, 4, 5, 6, 7]).unwrap()[0], 0x20);
        let r = c.request([0x01, 1, 2, 3, 4, 5, 6, 7]).unwrap(); // toggle still 0
        assert_eq!(Client::abort_code(r), Err(0x0503_0000));
        // The download is abandoned: data without a new clear is out of sequence.
        assert_eq!(c.write(0x1F50, 1, &[1, 2, 3, 4]), Err(0x0800_0022));
        assert_eq!(c.request([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]).unwrap()[0], 0x41);
        let r = c.request([0x70, 0, 0, 0, 0, 0, 0, 0]).unwrap(); // upload segment with toggle 1 first
        assert_eq!(Client::abort_code(r), Err(0x0503_0000));
        assert_eq!(c.read(0x1008, 0).unwrap(), DEVICE_NAME.as_bytes(), "a new upload works after the abort");
    }

    #[test]
    fn an_idle_transfer_times_out_after_one_second_and_a_client_abort_ends_it() {
        let mut c = Client::new();
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.request([0x21, 0x50, 0x1F, 1, 0, 1, 0, 0]).unwrap()[0], 0x60);
        let start = c.now;
        assert_eq!(c.node.poll(start), None, "nothing while idle for less than 1 s");
        assert_eq!(c.node.poll(start.wrapping_add(SDO_TIMEOUT_MS - 1)), None);
        let f = c.node.poll(start.wrapping_add(SDO_TIMEOUT_MS)).expect("abort after 1 s");
        assert_eq!(f.raw_data(), [0x80, 0x50, 0x1F, 1, 0x00, 0x00, 0x04, 0x05]);
        assert_eq!(c.node.poll(start.wrapping_add(5000)), None, "once");
        assert_eq!(c.write(0x1F50, 1, &[1, 2, 3, 4]), Err(0x0800_0022), "the timed-out download is abandoned");
        // The clock wraps: an SDO started just before the wrap times out 1 s later.
        c.now = u32::MAX - 10;
        assert_eq!(c.request([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]).unwrap()[0], 0x41);
        assert_eq!(c.node.poll(u32::MAX), None);
        assert!(c.node.poll((u32::MAX - 9).wrapping_add(SDO_TIMEOUT_MS)).is_some());
        // A client abort ends a transfer without an answer.
        assert_eq!(c.request([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]).unwrap()[0], 0x41);
        assert_eq!(c.request([0x80, 0x08, 0x10, 0, 0, 0, 0, 0x08]), None);
        assert_eq!(c.node.poll(c.now.wrapping_add(2 * SDO_TIMEOUT_MS)), None);
    }

    #[test]
    fn frames_for_others_and_nmt() {
        let mut c = Client::new();
        let send =
            |c: &mut Client, id: u16, data: &[u8]| c.node.handle(&CanFrame::new(id, data).unwrap(), &mut c.flash, 0);
        let quiet = FallbackReply::default();
        assert_eq!(send(&mut c, 0x601, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]), quiet, "another node's SDO");
        assert_eq!(send(&mut c, 0x605, &[0x40, 0, 0x10, 0]), quiet, "an SDO frame of 4 bytes");
        assert_eq!(send(&mut c, 0x585, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]), quiet, "a server response");
        assert_eq!(c.node.handle(&CanFrame::remote(0x605, 8).unwrap(), &mut c.flash, 0), quiet);
        assert_eq!(send(&mut c, 0x000, &[0x01, NODE]), quiet, "start remote node: stays pre-operational");
        assert_eq!(send(&mut c, 0x000, &[0x02, 0]), quiet);
        assert_eq!(send(&mut c, 0x000, &[0x80, NODE]), quiet);
        assert_eq!(send(&mut c, 0x000, &[0x81, NODE + 1]), quiet, "reset of another node");
        assert_eq!(send(&mut c, 0x000, &[0x81]), quiet, "NMT frame without a node-ID");
        let reset = FallbackReply { frame: None, reset: true };
        assert_eq!(send(&mut c, 0x000, &[0x81, NODE]), reset);
        assert_eq!(send(&mut c, 0x000, &[0x82, NODE]), reset);
        assert_eq!(send(&mut c, 0x000, &[0x81, 0]), reset);
        assert_eq!(send(&mut c, 0x000, &[0x82, 0]), reset);
    }

    #[test]
    fn node_id_and_boot_up() {
        let n = FallbackNode::new(NODE, trust(), ImageError::BadMagic);
        assert_eq!((n.boot_up().id(), n.boot_up().data()), (0x705, &[0u8][..]));
        for bad in [0, 128, 255] {
            let n = FallbackNode::new(bad, trust(), ImageError::BadMagic);
            assert_eq!(n.node_id(), DEFAULT_NODE_ID);
            assert_eq!(n.boot_up().id(), 0x700 + u16::from(DEFAULT_NODE_ID));
        }
        assert_eq!(FallbackNode::new(127, trust(), ImageError::BadMagic).node_id(), 127);
    }

    /// After `start` the node asked for a reset; the bootloader's next run activates the image and runs it.
    fn boot_runs(c: &mut Client, version: u32) {
        let mut buf = [0u8; 1024];
        match boot(&mut c.flash, &trust(), &mut buf) {
            Ok(Outcome::Run { header, trial, .. }) => {
                assert_eq!(header.firmware_version, version);
                assert!(trial, "a new image starts on trial");
            }
            other => panic!("the new image must run: {other:?}"),
        }
    }

    #[test]
    fn segmented_download_of_a_signed_image_then_start_resets_into_it() {
        let mut c = Client::new();
        let img = image(0x0002_0003, 3000);
        assert_ne!(img.len() % 7, 0, "the last segment carries padding");
        // The seeds' sequence (IDX L3350-3352): stop, clear, program data, start.
        c.write(0x1F51, 1, &[command::STOP]).unwrap();
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(status(&mut c), 1 << 1);
        // A transfer of the first 700 bytes only: the image is truncated (0x0607_0013, status 3).
        assert_eq!(c.write_segmented(0x1F50, 1, &img[..700]), Err(0x0607_0013));
        assert_eq!(status(&mut c), u32::from(status::DATA_ERROR) << 1);
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        c.write_segmented(0x1F50, 1, &img).unwrap();
        assert_eq!(status(&mut c), 0, "verified: valid program, no download in progress");
        assert_eq!(c.read(0x1F51, 1).unwrap(), [program_state::STOPPED]);
        assert_eq!(c.resets, 0);
        c.write(0x1F51, 1, &[command::START]).unwrap();
        assert_eq!(c.resets, 1, "the reply, then a reset");
        boot_runs(&mut c, 0x0002_0003);
    }

    #[test]
    fn block_download_with_crc_and_lost_segments_then_start_resets_into_it() {
        let mut c = Client::new();
        // More than two blocks of 127 segments, the last one padded; segments lost inside the first block, just
        // before its end, and in the second (a lost block end or last segment leaves the client waiting for an
        // acknowledgement that never comes: it aborts, CiA 301 §7.2.4.3.13).
        let img = image(0x0003_0001, 2 * 127 * 7 + 506);
        assert_ne!(img.len() % 7, 0);
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        c.write_block(0x1F50, 1, &img, &[3, 125, 200], 0).unwrap();
        assert_eq!(status(&mut c), 0);
        c.write(0x1F51, 1, &[command::START]).unwrap();
        assert_eq!(c.resets, 1);
        boot_runs(&mut c, 0x0003_0001);
    }

    #[test]
    fn a_block_crc_mismatch_aborts_and_abandons_the_download() {
        let mut c = Client::new();
        let img = image(0x0003_0001, 1000);
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.write_block(0x1F50, 1, &img, &[], 1), Err(0x0504_0004));
        assert_eq!(c.write(0x1F51, 1, &[command::START]), Err(0x0800_0022));
        assert_eq!(c.resets, 0);
    }

    #[test]
    fn a_corrupted_image_is_refused_with_abort_and_status_and_start_is_refused() {
        let mut c = Client::new();
        let mut img = image(0x0002_0000, 2000);
        img[HEADER_LEN as usize + 100] ^= 0x01;
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.write_segmented(0x1F50, 1, &img), Err(0x0800_0020), "payload CRC");
        assert_eq!(status(&mut c), u32::from(status::DATA_ERROR) << 1);
        assert_eq!(c.read(0x1F51, 1).unwrap(), [program_state::NO_PROGRAM]);
        // Start without a verified image: 0x0800_0022, 0x1F57 = 1 "no valid program available".
        assert_eq!(c.write(0x1F51, 1, &[command::START]), Err(0x0800_0022));
        assert_eq!(status(&mut c), u32::from(status::NO_PROGRAM) << 1);
        assert_eq!(c.resets, 0);
        // Signed with another key: 0x0800_0020, status 93.
        let mut other = image(0x0002_0000, 2000);
        let mut header = ImageHeader::parse(&other[..HEADER_LEN as usize]).unwrap();
        let payload = other[HEADER_LEN as usize..].to_vec();
        sign_image(&mut header, &payload, &[9; 32], [2; 16]);
        other[..HEADER_LEN as usize].copy_from_slice(&header.to_bytes());
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.write_block(0x1F50, 1, &other, &[], 0), Err(0x0800_0020));
        assert_eq!(status(&mut c), u32::from(status::SIGNATURE_INVALID) << 1);
        // The bootloader still finds no valid image: nothing was activated.
        let mut buf = [0u8; 1024];
        assert!(matches!(boot(&mut c.flash, &trust(), &mut buf), Ok(Outcome::NoValidImage(_))));
    }

    /// Anti-rollback in the fallback: without a valid image in slot A the log's minimum alone counts
    /// (`state::minimum_security_version`); an image below it is refused with 0x0609_0032 and status 94, one at it
    /// is accepted.
    #[test]
    fn an_image_below_the_logs_minimum_security_version_is_refused() {
        let mut c = Client::new();
        crate::boot::state::append(&mut c.flash.state, crate::boot::state::Record::floor(5)).unwrap();
        let with_security = |security: u32| {
            let mut img = image(0x0002_0000, 2000);
            let mut header = ImageHeader::parse(&img[..HEADER_LEN as usize]).unwrap();
            header.security_version = security;
            let payload = img[HEADER_LEN as usize..].to_vec();
            sign_image(&mut header, &payload, &SEED, [3; 16]);
            img[..HEADER_LEN as usize].copy_from_slice(&header.to_bytes());
            img
        };
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.write_segmented(0x1F50, 1, &with_security(4)), Err(0x0609_0032));
        assert_eq!(status(&mut c), u32::from(status::ROLLBACK) << 1);
        assert_eq!(c.write(0x1F51, 1, &[command::START]), Err(0x0800_0022), "nothing to start");
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.write_block(0x1F50, 1, &with_security(5), &[], 0), Ok(()));
        assert_eq!(status(&mut c), 0);
        assert_eq!(c.write(0x1F51, 1, &[command::START]), Ok(()));
        assert_eq!(c.resets, 1);
    }

    #[test]
    fn the_sequence_is_enforced() {
        let mut c = Client::new();
        let img = image(0x0002_0000, 500);
        // Program data before clear: 0x0800_0022, status 66 "authentication sequence error".
        assert_eq!(c.write_segmented(0x1F50, 1, &img), Err(0x0800_0022));
        assert_eq!(status(&mut c), u32::from(status::SEQUENCE_ERROR) << 1);
        // Start without an image: refused, no reset.
        assert_eq!(c.write(0x1F51, 1, &[command::START]), Err(0x0800_0022));
        assert_eq!(c.resets, 0);
        // Reset: the reply, then a reset.
        c.write(0x1F51, 1, &[command::RESET]).unwrap();
        assert_eq!(c.resets, 1);
        // While a download is in progress 0x1F57 bit 0 is set.
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        assert_eq!(c.request([0x21, 0x50, 0x1F, 1, 0, 2, 0, 0]).unwrap()[0], 0x60);
        assert_eq!(c.request([0x00, 1, 2, 3, 4, 5, 6, 7]).unwrap()[0], 0x20);
        assert_eq!(c.node.flash_status() & 1, 1);
        // After a verified download, a start activates once; a second start (reset lost) resets again.
        let mut c = Client::new();
        c.write(0x1F51, 1, &[command::CLEAR]).unwrap();
        c.write_segmented(0x1F50, 1, &img).unwrap();
        c.write(0x1F51, 1, &[command::START]).unwrap();
        c.write(0x1F51, 1, &[command::START]).unwrap();
        assert_eq!(c.resets, 2);
        boot_runs(&mut c, 0x0002_0000);
    }
}
