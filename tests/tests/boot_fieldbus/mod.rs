//! Shared helpers of the boot_program_control / boot_foe tests: an in-process EtherCAT master in front of the
//! simulator's runner (`hal_sim::sim::ethercat::EthercatRunner`, lock-step), test images signed with the
//! development key, and a raw CANopen SDO client (segmented and block download) in front of the CAN runner.
//!
//! The EtherCAT master is modelled as one that exchanges one mailbox datagram per 1 ms bus cycle: every frame
//! it sends carries its mailbox (or register) datagram together with a cyclic LRD, so that the runner in
//! lock-step runs one cycle of simulated time per frame. Update times over CoE and FoE are in those cycles.
#![allow(dead_code)]

use drive_tests::ecat_master::first_datagram;
pub use drive_tests::ecat_master::{StationMaster, STATION};
use firmware::boot::image::HARDWARE_ID;
use firmware::canopen::frame::CanFrame;
use firmware::comm::sdo::crc::Crc16;
use firmware::ecat::mailbox::{Header, HEADER_LEN};
use firmware::od::generated;
use hal_sim::esc::datagram::{Command, FrameBuilder};
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner};
use hal_sim::sim::ethercat::{ClockMode, EthercatConfig, EthercatRunner};
use hal_sim::sim::update::{dev_seed, payload, signed_image};

pub const COE: u8 = 3;
pub const FOE: u8 = 4;
pub const CYCLE_NS: u64 = 1_000_000;

/// The old (factory) image's version and the new one's.
pub const OLD_VERSION: u32 = hal_sim::sim::update::FACTORY_VERSION;
pub const NEW_VERSION: u32 = 0x0002_0003;
pub const NEW_VERSION_STRING: &str = "2.0.3";
/// Payload of the test application image: 128 KiB, the order of the release firmware's flash contents.
pub const APP_PAYLOAD: usize = 128 * 1024;

pub fn new_image(len: usize) -> Vec<u8> {
    signed_image(&payload(len, NEW_VERSION), NEW_VERSION, NEW_VERSION_STRING, HARDWARE_ID, &dev_seed())
}

/// An image of firmware `version` (0x1F56 identification `version & 0xFFFF_0000`) at security version
/// `security_version`, signed with the development key.
pub fn image_with_security(len: usize, version: u32, security_version: u32) -> Vec<u8> {
    use firmware::boot::image::ImageHeader;
    let body = payload(len, version);
    let mut header = ImageHeader::new(HARDWARE_ID, version, version & 0xFFFF_0000, 0, 0);
    header.version_string[..3].copy_from_slice(b"sec");
    header.security_version = security_version;
    firmware::boot::sign::sign_image(&mut header, &body, &dev_seed(), [security_version as u8; 16]);
    let mut image = header.to_bytes().to_vec();
    image.extend_from_slice(&body);
    image
}

pub fn u32_of(v: &[u8]) -> u32 {
    let mut b = [0u8; 4];
    b[..v.len().min(4)].copy_from_slice(&v[..v.len().min(4)]);
    u32::from_le_bytes(b)
}

/// The in-process EtherCAT master (see the module documentation).
pub struct EcatRig {
    pub r: EthercatRunner,
    counter: u8,
    /// Frames (= bus cycles) sent so far.
    pub frames: u64,
    /// The text of the last FoE error answer (ETG.1000.5: after the error code).
    pub foe_error_text: Vec<u8>,
}

impl EcatRig {
    pub fn new() -> Self {
        let config = EthercatConfig { clock: ClockMode::LockStep, cycle_ns: CYCLE_NS, ..EthercatConfig::default() };
        let mut rig =
            Self { r: EthercatRunner::new(config).expect("runner"), counter: 0, frames: 0, foe_error_text: Vec::new() };
        rig.datagram(Command::Apwr, 0, 0x0010, &STATION.to_le_bytes());
        rig
    }

    /// Writes AL control and waits (a few cycles) for the AL status to follow; returns (status, code).
    pub fn request(&mut self, control: u16) -> (u16, u16) {
        self.fpwr(0x0120, &control.to_le_bytes());
        let mut s = self.al_status();
        for _ in 0..20 {
            if s.0 & 0x0F == control & 0x0F || s.0 & 0x10 != 0 {
                break;
            }
            s = self.al_status();
        }
        s
    }

    fn mailboxes(&mut self) {
        self.configure_sm(0, generated::MAILBOX_OUT_START, generated::MAILBOX_OUT_SIZE, 0x26);
        self.configure_sm(1, generated::MAILBOX_IN_START, generated::MAILBOX_IN_SIZE, 0x22);
    }

    pub fn enter_preop(&mut self) {
        self.mailboxes();
        assert_eq!(self.request(0x0002), (0x0002, 0x0000), "PRE-OP reached");
    }

    pub fn enter_boot(&mut self) {
        assert_eq!(self.request(0x0001).0 & 0x1F, 0x0001, "INIT first");
        self.mailboxes();
        assert_eq!(self.request(0x0003), (0x0003, 0x0000), "BOOT reached");
    }

    /// Sends one mailbox of `kind` and polls SM1 (one cycle each) until an answer of that kind comes.
    pub fn exchange(&mut self, kind: u8, data: &[u8]) -> Option<Vec<u8>> {
        self.counter = if self.counter >= 7 { 1 } else { self.counter + 1 };
        let header = Header { length: data.len() as u16, kind, counter: self.counter, ..Header::default() };
        let mut window = header.encode().to_vec();
        window.extend_from_slice(data);
        window.resize(usize::from(generated::MAILBOX_OUT_SIZE), 0);
        if self.fpwr(generated::MAILBOX_OUT_START, &window) != 1 {
            return None;
        }
        for _ in 0..10 {
            let (w, wkc) = self.fprd(generated::MAILBOX_IN_START, usize::from(generated::MAILBOX_IN_SIZE));
            if wkc == 0 {
                continue;
            }
            let h = Header::parse(&w).expect("a header");
            let d = w[HEADER_LEN..(HEADER_LEN + usize::from(h.length)).min(w.len())].to_vec();
            if h.kind == COE && d.len() >= 2 && d[1] >> 4 == 1 {
                continue; // an emergency
            }
            if h.kind == kind {
                return Some(d);
            }
        }
        None
    }

    /// An SDO request; the SDO bytes of the answer (`None`: no answer, as E4 documents for stop/start).
    pub fn sdo(&mut self, sdo: &[u8]) -> Option<Vec<u8>> {
        let mut data = vec![0x00, 0x20];
        data.extend_from_slice(sdo);
        data.resize(data.len().max(10), 0);
        self.exchange(COE, &data).map(|a| a[2..].to_vec())
    }

    pub fn upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.sdo(&[0x40, i0, i1, sub, 0, 0, 0, 0]).expect("an answer");
        if r[0] == 0x80 {
            return Err(u32_of(&r[4..8]));
        }
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok(r[4..4 + n].to_vec());
        }
        let size = u32_of(&r[4..8]) as usize;
        let mut v = r[8..].to_vec();
        v.truncate(size);
        Ok(v)
    }

    pub fn upload_u32(&mut self, index: u16, sub: u8) -> Result<u32, u32> {
        self.upload(index, sub).map(|v| u32_of(&v))
    }

    /// Expedited download (up to 4 bytes); `None` if no answer came.
    pub fn download(&mut self, index: u16, sub: u8, value: &[u8]) -> Option<Result<(), u32>> {
        let [i0, i1] = index.to_le_bytes();
        let n = 4 - value.len() as u8;
        let mut req = vec![0x23 | (n << 2), i0, i1, sub];
        req.extend_from_slice(value);
        req.resize(8, 0);
        let r = self.sdo(&req)?;
        Some(if r[0] == 0x80 { Err(u32_of(&r[4..8])) } else { Ok(()) })
    }

    /// Normal download with the size announced, then segments of up to `segment` bytes (CoE: as many as the
    /// mailbox holds); the first abort ends it.
    pub fn download_domain(&mut self, index: u16, sub: u8, value: &[u8], segment: usize) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let mut req = vec![0x21, i0, i1, sub];
        req.extend_from_slice(&(value.len() as u32).to_le_bytes());
        let first = value.len().min(segment.saturating_sub(8));
        req.extend_from_slice(&value[..first]);
        let r = self.sdo(&req).expect("an initiate answer");
        if r[0] == 0x80 {
            return Err(u32_of(&r[4..8]));
        }
        let mut toggle = 0u8;
        let mut at = first;
        while at < value.len() {
            let n = (value.len() - at).min(segment);
            let last = at + n == value.len();
            let mut seg = if n < 7 {
                vec![toggle | (((7 - n) as u8) << 1) | u8::from(last)]
            } else {
                vec![toggle | u8::from(last)]
            };
            seg.extend_from_slice(&value[at..at + n]);
            seg.resize(seg.len().max(8), 0);
            let r = self.sdo(&seg).expect("a segment answer");
            if r[0] == 0x80 {
                return Err(u32_of(&r[4..8]));
            }
            toggle ^= 0x10;
            at += n;
        }
        Ok(())
    }

    /// An FoE write of `data` to `name` with `password` (packets of mailbox size - 12 bytes); `Err(code)` is the
    /// drive's FoE error.
    pub fn foe_write(&mut self, name: &[u8], password: u32, data: &[u8]) -> Result<(), u32> {
        let packet = usize::from(generated::MAILBOX_OUT_SIZE) - 12;
        let mut req = vec![2, 0];
        req.extend_from_slice(&password.to_le_bytes());
        req.extend_from_slice(name);
        let a = self.exchange(FOE, &req).expect("an FoE answer to the write request");
        if a[0] == 5 {
            self.foe_error_text = a[6..].to_vec();
            return Err(u32_of(&a[2..6]));
        }
        let mut number = 1u32;
        let mut at = 0;
        loop {
            let n = (data.len() - at).min(packet);
            let mut req = vec![3, 0];
            req.extend_from_slice(&number.to_le_bytes());
            req.extend_from_slice(&data[at..at + n]);
            let a = self.exchange(FOE, &req).expect("an FoE answer to a data packet");
            match a[0] {
                4 => {}
                5 => {
                    self.foe_error_text = a[6..].to_vec();
                    return Err(u32_of(&a[2..6]));
                }
                other => panic!("FoE opcode {other} to a data packet"),
            }
            at += n;
            number += 1;
            if n < packet {
                return Ok(());
            }
        }
    }
}

impl StationMaster for EcatRig {
    /// One frame: the datagram and a cyclic LRD (one bus cycle of simulated time).
    fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
        let mut frame =
            FrameBuilder::new().push(cmd, adp, ado, data).push_logical(Command::Lrd, 0x0001_0000, &[0]).build();
        self.r.frame(&mut frame).expect("a well-formed frame");
        self.frames += 1;
        first_datagram(&frame)
    }
}

/// A CANopen SDO client on the CAN runner (lock-step, 1 Mbit/s, node 1).
pub struct CanRig {
    pub r: CanopenRunner,
}

impl CanRig {
    pub fn new() -> Self {
        let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
        r.run_for(2_000_000);
        Self { r }
    }

    /// A request; the node's SDO answer (`None`: none within the quiet limit).
    pub fn sdo(&mut self, req: [u8; 8]) -> Option<[u8; 8]> {
        let got = self.r.lock_step(CanFrame::new(0x601, &req).unwrap());
        got.iter().rev().find(|d| d.frame.id() == 0x581).map(|d| d.frame.data().try_into().unwrap())
    }

    pub fn upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.sdo([0x40, i0, i1, sub, 0, 0, 0, 0]).expect("an answer");
        if r[0] == 0x80 {
            return Err(u32_of(&r[4..8]));
        }
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok(r[4..4 + n].to_vec());
        }
        let size = u32_of(&r[4..8]) as usize;
        let mut v = Vec::new();
        let mut toggle = 0u8;
        while v.len() < size {
            let s = self.sdo([0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]).expect("a segment");
            if s[0] == 0x80 {
                return Err(u32_of(&s[4..8]));
            }
            let n = 7 - usize::from((s[0] >> 1) & 7);
            v.extend_from_slice(&s[1..1 + n]);
            toggle ^= 0x10;
            if s[0] & 1 != 0 {
                break;
            }
        }
        Ok(v)
    }

    pub fn upload_u32(&mut self, index: u16, sub: u8) -> Result<u32, u32> {
        self.upload(index, sub).map(|v| u32_of(&v))
    }

    pub fn download(&mut self, index: u16, sub: u8, value: &[u8]) -> Option<Result<(), u32>> {
        let [i0, i1] = index.to_le_bytes();
        let n = 4 - value.len() as u8;
        let mut req = [0x23 | (n << 2), i0, i1, sub, 0, 0, 0, 0];
        req[4..4 + value.len()].copy_from_slice(value);
        let r = self.sdo(req)?;
        Some(if r[0] == 0x80 { Err(u32_of(&r[4..8])) } else { Ok(()) })
    }

    /// SDO block download with CRC (CiA 301 §7.2.4.3.9-14): sub-blocks of the size the server grants, each
    /// sent back to back and acknowledged once.
    pub fn block_download(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let mut req = [0xC6, i0, i1, sub, 0, 0, 0, 0];
        req[4..8].copy_from_slice(&(value.len() as u32).to_le_bytes());
        let r = self.sdo(req).expect("a block initiate answer");
        if r[0] == 0x80 {
            return Err(u32_of(&r[4..8]));
        }
        assert_eq!(r[0] & 0xE0, 0xA0, "block download initiate response {r:02X?}");
        let mut blksize = usize::from(r[4]);
        let mut at = 0;
        let mut last_len = 7;
        while at < value.len() {
            let start = at;
            let mut seq = 0u8;
            while seq < blksize as u8 && at < value.len() {
                seq += 1;
                let n = (value.len() - at).min(7);
                let last = at + n == value.len();
                let mut f = [0u8; 8];
                f[0] = seq | if last { 0x80 } else { 0 };
                f[1..1 + n].copy_from_slice(&value[at..at + n]);
                self.r.send(CanFrame::new(0x601, &f).unwrap());
                at += n;
                last_len = n;
            }
            let got = self.r.run_until_quiet(hal_sim::sim::canopen::QUIET_LIMIT_NS);
            // An abort in the middle of the sub-block ends the transfer; the server takes the segments after it
            // for new requests and answers them too, so the first abort is the answer.
            let first_abort = got.iter().find(|d| d.frame.id() == 0x581 && d.frame.data()[0] == 0x80);
            if let Some(abort) = first_abort {
                return Err(u32_of(&abort.frame.data()[4..8]));
            }
            let a: [u8; 8] = got
                .iter()
                .rev()
                .find(|d| d.frame.id() == 0x581)
                .map(|d| d.frame.data().try_into().unwrap())
                .expect("a sub-block acknowledge");
            if a[0] == 0x80 {
                return Err(u32_of(&a[4..8]));
            }
            assert_eq!((a[0], a[1]), (0xA2, seq), "every segment of the sub-block acknowledged (from {start})");
            blksize = usize::from(a[2]);
        }
        let mut crc = Crc16::new();
        crc.update(value);
        let [c0, c1] = crc.value().to_le_bytes();
        let end = self.sdo([0xC1 | (((7 - last_len) as u8) << 2), c0, c1, 0, 0, 0, 0, 0]).expect("a block end answer");
        if end[0] == 0x80 {
            return Err(u32_of(&end[4..8]));
        }
        assert_eq!(end[0], 0xA1);
        Ok(())
    }
}
