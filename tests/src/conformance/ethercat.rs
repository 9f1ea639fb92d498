//! The EtherCAT conformance suite, modelled on the groups of the ETG conformance test tool: the state machine and
//! its AL status codes (ETG.1000.6 §6.4, Table 11 of the codes), the mailbox link (ETG.1000.4/6 §5), CoE (SDO,
//! SDO information, complete access, emergencies: ETG.1000.6 §5.6), the SII and the ESI against what the device
//! answers (ETG.2010, ETG.2000), the sync parameters 0x1C32/0x1C33 (ETG.1020 §6) and the drive profile's
//! 0x6502 (ETG.6010 / CiA 402).
//!
//! The device is `hal_sim::sim::ethercat::EthercatRunner` in lock-step (what `drive-sim ethercat --lock-step`
//! serves: the emulated ESC with the drive's SII, the firmware's slave, the drive and its plant, its parameter
//! store and program control). The master here builds every datagram, mailbox and CoE frame byte by byte; a frame
//! with a cyclic datagram (LRW, LRD) runs one 1 ms cycle of simulated time, any other frame none. Every case
//! starts from a device powered up in INIT with station address 0x1001 assigned.

use firmware::ecat::process_data::ProcessDataLayout;
use firmware::od::generated;
use hal_sim::esc::datagram::{Command, FrameBuilder};
use hal_sim::sim::ethercat::{ClockMode, EthercatConfig, EthercatRunner};

use super::eds::Eds;
use super::{expect_eq, expect_that, run_suite, Case, Outcome, Skip, SuiteReport};
use crate::ecat_master::{first_datagram, StationMaster, STATION};

const ERR: u16 = 0x0010;
const INIT: u16 = 1;
const PREOP: u16 = 2;
const BOOT: u16 = 3;
const SAFEOP: u16 = 4;
const OP: u16 = 8;
/// Mailbox types (ETG.1000.6 §5.2 Table 29).
const MBX_ERROR: u8 = 0;
const MBX_COE: u8 = 3;
/// CoE services (ETG.1000.6 §5.6.1).
const COE_EMERGENCY: u8 = 1;
const COE_SDO_REQUEST: u8 = 2;
const COE_SDO_RESPONSE: u8 = 3;
const COE_SDO_INFO: u8 = 8;
/// Where the master maps the process image (outputs, then inputs).
const LOGICAL: u32 = 0x0001_0000;

fn esi_text() -> &'static str {
    static ESI: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    ESI.get_or_init(|| {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/generated/drive-esi.xml");
        std::fs::read_to_string(path).expect("the shipped ESI reads")
    })
}

/// `#x1A00` or `0x1A00` or `6656` as a number (ETG.2000 HexDecValue).
fn hex_dec(text: &str) -> Option<u64> {
    let t = text.trim();
    match t.strip_prefix("#x").or_else(|| t.strip_prefix("0x")) {
        Some(h) => u64::from_str_radix(h, 16).ok(),
        None => t.parse().ok(),
    }
}

/// The device on its segment, and the master's side of it.
pub struct Segment {
    runner: EthercatRunner,
    counter: u8,
    /// CoE emergencies read from SM1 so far (their 8 EMCY bytes).
    pub emergencies: Vec<[u8; 8]>,
}

impl StationMaster for Segment {
    fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
        let mut frame = FrameBuilder::new().push(cmd, adp, ado, data).build();
        self.runner.frame(&mut frame).expect("a well-formed frame is answered");
        first_datagram(&frame)
    }
}

impl Segment {
    /// A device powered up, station address assigned.
    ///
    /// # Panics
    /// If the device cannot be built.
    #[must_use]
    pub fn powered_up() -> Self {
        let runner = EthercatRunner::new(EthercatConfig {
            clock: ClockMode::LockStep,
            cycle_ns: 1_000_000,
            ..EthercatConfig::default()
        })
        .expect("the device");
        let mut seg = Self { runner, counter: 0, emergencies: Vec::new() };
        seg.datagram(Command::Apwr, 0, 0x0010, &STATION.to_le_bytes());
        seg
    }

    /// `n` cycles of 1 ms with a cyclic LRW of `image` (or an LRD of one byte without one); the last answer and
    /// working counter.
    pub fn cycles(&mut self, n: u32, image: Option<&[u8]>) -> (Vec<u8>, u16) {
        let mut last = (Vec::new(), 0);
        for _ in 0..n {
            let mut frame = match image {
                Some(img) => FrameBuilder::new().push_logical(Command::Lrw, LOGICAL, img).build(),
                None => FrameBuilder::new().push_logical(Command::Lrd, LOGICAL, &[0]).build(),
            };
            self.runner.frame(&mut frame).expect("a well-formed frame is answered");
            last = first_datagram(&frame);
        }
        last
    }

    /// Writes AL control; the AL status and code the master reads after it.
    pub fn request(&mut self, control: u16) -> (u16, u16) {
        self.fpwr(0x0120, &control.to_le_bytes());
        self.al_status()
    }

    /// SM0/SM1 as the SII's standard (and bootstrap) mailbox.
    pub fn configure_mailboxes(&mut self) {
        self.configure_sm(0, generated::MAILBOX_OUT_START, generated::MAILBOX_OUT_SIZE, 0x26);
        self.configure_sm(1, generated::MAILBOX_IN_START, generated::MAILBOX_IN_SIZE, 0x22);
    }

    /// INIT -> PRE-OP.
    ///
    /// # Errors
    /// The device refused.
    pub fn to_preop(&mut self) -> Outcome {
        self.configure_mailboxes();
        expect_eq("AL status and code after INIT -> PRE-OP", self.request(PREOP), (PREOP, 0))
    }

    /// The process image sizes of the default mapping (outputs, inputs).
    fn image_sizes(&self) -> (u16, u16) {
        let layout = ProcessDataLayout::compile(self.runner.node.sim.drive.dictionary()).expect("the default mapping");
        (layout.output_bytes, layout.input_bytes)
    }

    /// SM2/SM3 and FMMUs for `outputs` and `inputs` bytes.
    fn configure_process_data(&mut self, outputs: u16, inputs: u16) {
        self.configure_sm(2, generated::PROCESS_OUT_START, outputs, 0x64);
        self.configure_sm(3, generated::PROCESS_IN_START, inputs, 0x20);
        self.configure_fmmu(0, LOGICAL, outputs, generated::PROCESS_OUT_START, 0x02);
        self.configure_fmmu(1, LOGICAL + u32::from(outputs), inputs, generated::PROCESS_IN_START, 0x01);
    }

    fn configure_fmmu(&mut self, n: u16, logical: u32, len: u16, physical: u16, kind: u8) {
        let mut regs = logical.to_le_bytes().to_vec();
        regs.extend_from_slice(&len.to_le_bytes());
        regs.extend_from_slice(&[0, 7]);
        regs.extend_from_slice(&physical.to_le_bytes());
        regs.extend_from_slice(&[0, kind, 1, 0, 0, 0]);
        self.fpwr(0x0600 + 16 * n, &regs);
    }

    /// PRE-OP -> SAFE-OP with the default mapping; the image length.
    ///
    /// # Errors
    /// The device refused.
    pub fn to_safeop(&mut self) -> Result<usize, String> {
        self.to_preop()?;
        let (outputs, inputs) = self.image_sizes();
        self.configure_process_data(outputs, inputs);
        expect_eq("AL status and code after PRE-OP -> SAFE-OP", self.request(SAFEOP), (SAFEOP, 0))?;
        Ok(usize::from(outputs + inputs))
    }

    /// SAFE-OP -> OP with valid outputs (one LRW first); the image length.
    ///
    /// # Errors
    /// The device refused.
    pub fn to_op(&mut self) -> Result<usize, String> {
        let len = self.to_safeop()?;
        let image = vec![0u8; len];
        let (_, wkc) = self.cycles(1, Some(&image));
        expect_eq("LRW working counter in SAFE-OP", wkc, 3)?;
        expect_eq("AL status and code after SAFE-OP -> OP", self.request(OP), (OP, 0))?;
        Ok(len)
    }

    /// Writes a mailbox (header with `kind` and `counter`, then `data`) into SM0; the working counter.
    pub fn send_mailbox(&mut self, kind: u8, counter: u8, data: &[u8]) -> u16 {
        let len = data.len() as u16;
        let mut window = vec![0u8; usize::from(generated::MAILBOX_OUT_SIZE)];
        window[0..2].copy_from_slice(&len.to_le_bytes());
        window[5] = (kind & 0x0F) | ((counter & 0x07) << 4);
        window[6..6 + data.len()].copy_from_slice(data);
        self.fpwr(generated::MAILBOX_OUT_START, &window)
    }

    /// Reads SM1 if it holds a mailbox: type and data (the header's length); CoE emergencies are kept aside and
    /// the next mailbox is read instead.
    pub fn receive(&mut self) -> Option<(u8, Vec<u8>)> {
        for _ in 0..8 {
            // SM1 status (0x080D) bit 3: mailbox full, as SOEM checks before it reads.
            let (status, _) = self.fprd(0x080D, 1);
            if status[0] & 0x08 == 0 {
                return None;
            }
            let (window, wkc) = self.fprd(generated::MAILBOX_IN_START, usize::from(generated::MAILBOX_IN_SIZE));
            if wkc == 0 {
                return None;
            }
            let len = usize::from(u16::from_le_bytes([window[0], window[1]]));
            let kind = window[5] & 0x0F;
            let data = window[6..(6 + len).min(window.len())].to_vec();
            if kind == MBX_COE && data.len() >= 10 && data[1] >> 4 == COE_EMERGENCY {
                self.emergencies.push(data[2..10].try_into().expect("8 bytes"));
                continue;
            }
            return Some((kind, data));
        }
        None
    }

    /// The next mailbox counter (1..7).
    fn next_counter(&mut self) -> u8 {
        self.counter = if self.counter >= 7 { 1 } else { self.counter + 1 };
        self.counter
    }

    /// A mailbox request with the next counter and its answer.
    ///
    /// # Errors
    /// SM0 did not take the request, or no answer came.
    pub fn exchange(&mut self, kind: u8, data: &[u8]) -> Result<(u8, Vec<u8>), String> {
        let counter = self.next_counter();
        expect_eq("SM0 working counter", self.send_mailbox(kind, counter, data), 1)?;
        self.receive().ok_or_else(|| format!("no answer to the mailbox {data:02X?}"))
    }

    /// A CoE SDO request (command byte onwards, padded to 8 bytes); the answer's CoE service and SDO bytes.
    ///
    /// # Errors
    /// No CoE answer.
    pub fn sdo(&mut self, sdo: &[u8]) -> Result<(u8, Vec<u8>), String> {
        let mut data = vec![0x00, COE_SDO_REQUEST << 4];
        data.extend_from_slice(sdo);
        data.resize(data.len().max(10), 0);
        let (kind, answer) = self.exchange(MBX_COE, &data)?;
        expect_eq("mailbox type of the answer", kind, MBX_COE)?;
        expect_that(answer.len() >= 10, || format!("a CoE SDO answer of {} bytes", answer.len()))?;
        Ok((answer[1] >> 4, answer[2..].to_vec()))
    }

    /// An SDO upload (expedited or normal, with segments), or the abort code.
    ///
    /// # Errors
    /// An answer no upload allows.
    pub fn upload(&mut self, index: u16, sub: u8, complete: bool) -> Result<Result<Vec<u8>, u32>, String> {
        let [i0, i1] = index.to_le_bytes();
        let (service, r) = self.sdo(&[0x40 | if complete { 0x10 } else { 0 }, i0, i1, sub, 0, 0, 0, 0])?;
        if r[0] == 0x80 {
            return Ok(Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]])));
        }
        expect_eq("CoE service of the upload response", service, COE_SDO_RESPONSE)?;
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok(Ok(r[4..4 + n].to_vec()));
        }
        let size = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
        let mut value = r[8..].to_vec();
        value.truncate(size);
        let mut toggle = 0u8;
        while value.len() < size {
            let (_, s) = self.sdo(&[0x60 | toggle, 0, 0, 0, 0, 0, 0, 0])?;
            if s[0] == 0x80 {
                return Ok(Err(u32::from_le_bytes([s[4], s[5], s[6], s[7]])));
            }
            let len = if s.len() > 8 { s.len() - 1 } else { 7 - usize::from((s[0] >> 1) & 7) };
            value.extend_from_slice(&s[1..1 + len.min(s.len() - 1)]);
            toggle ^= 0x10;
            if s[0] & 0x01 != 0 {
                break;
            }
        }
        value.truncate(size);
        Ok(Ok(value))
    }

    /// An upload that must succeed, as an unsigned little-endian number.
    ///
    /// # Errors
    /// Aborted, or longer than 8 bytes.
    pub fn get(&mut self, index: u16, sub: u8) -> Result<u64, String> {
        match self.upload(index, sub, false)? {
            Ok(v) if v.len() <= 8 => {
                let mut b = [0u8; 8];
                b[..v.len()].copy_from_slice(&v);
                Ok(u64::from_le_bytes(b))
            }
            Ok(v) => Err(format!("{index:#06X}:{sub} holds {} bytes", v.len())),
            Err(code) => Err(format!("reading {index:#06X}:{sub} was aborted with {code:#010X}")),
        }
    }

    /// A download: expedited up to 4 bytes, normal beyond (with `complete` access); `Ok` or the abort code.
    ///
    /// # Errors
    /// An answer no download allows.
    pub fn download(&mut self, index: u16, sub: u8, value: &[u8], complete: bool) -> Result<Result<(), u32>, String> {
        let [i0, i1] = index.to_le_bytes();
        let ca = if complete { 0x10 } else { 0 };
        let mut req = if value.len() <= 4 && !complete {
            let unused = 4 - value.len() as u8;
            let mut r = vec![0x23 | (unused << 2), i0, i1, sub];
            r.extend_from_slice(value);
            r
        } else {
            let mut r = vec![0x21 | ca, i0, i1, sub];
            r.extend_from_slice(&(value.len() as u32).to_le_bytes());
            r.extend_from_slice(value);
            r
        };
        req.resize(req.len().max(8), 0);
        let (_, r) = self.sdo(&req)?;
        match r[0] {
            0x60 => Ok(Ok(())),
            0x80 => Ok(Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]]))),
            _ => Err(format!("a download answered with {r:02X?}")),
        }
    }

    /// A download that must succeed.
    ///
    /// # Errors
    /// Aborted.
    pub fn set(&mut self, index: u16, sub: u8, value: &[u8]) -> Outcome {
        match self.download(index, sub, value, false)? {
            Ok(()) => Ok(()),
            Err(code) => Err(format!("writing {index:#06X}:{sub} was aborted with {code:#010X}")),
        }
    }

    /// One SDO information request (opcode and data); every fragment's data concatenated, or the abort of an
    /// SDO information error.
    ///
    /// # Errors
    /// An answer that is no SDO information response of the expected opcode.
    pub fn sdo_info(&mut self, opcode: u8, data: &[u8]) -> Result<Result<Vec<u8>, u32>, String> {
        let mut req = vec![0x00, COE_SDO_INFO << 4, opcode, 0, 0, 0];
        req.extend_from_slice(data);
        let (mut kind, mut answer) = self.exchange(MBX_COE, &req)?;
        let mut out = Vec::new();
        loop {
            expect_eq("mailbox type", kind, MBX_COE)?;
            expect_eq("CoE service", answer.get(1).map(|b| b >> 4), Some(COE_SDO_INFO))?;
            let op = answer[2] & 0x7F;
            if op == 7 {
                return Ok(Err(u32::from_le_bytes([answer[6], answer[7], answer[8], answer[9]])));
            }
            expect_eq("SDO information opcode", op, opcode + 1)?;
            out.extend_from_slice(&answer[6..]);
            if answer[2] & 0x80 == 0 {
                return Ok(Ok(out));
            }
            (kind, answer) = self.receive().ok_or("the next fragment")?;
        }
    }

    /// A word of the SII EEPROM read through the ESC's EEPROM interface (0x0502..0x050B), as a master reads it.
    fn sii_word(&mut self, word: u32) -> u16 {
        self.fpwr(0x0504, &word.to_le_bytes());
        self.fpwr(0x0502, &0x0100u16.to_le_bytes());
        let (d, _) = self.fprd(0x0508, 2);
        u16::from_le_bytes([d[0], d[1]])
    }
}

// --- ESM (ETG.1000.6 §6.4) -------------------------------------------------------------------------------------

fn esm_power_up_in_init(seg: &mut Segment) -> Outcome {
    expect_eq("AL status and code at power-up", seg.al_status(), (INIT, 0))
}

fn esm_preop_without_mailboxes(seg: &mut Segment) -> Outcome {
    expect_eq("INIT -> PRE-OP without SM0/SM1", seg.request(PREOP), (INIT | ERR, 0x0016))
}

fn esm_invalid_transitions(seg: &mut Segment) -> Outcome {
    expect_eq("INIT -> SAFE-OP", seg.request(SAFEOP), (INIT | ERR, 0x0011))?;
    expect_eq("INIT -> OP, error not acknowledged", seg.request(OP), (INIT | ERR, 0x0011))?;
    expect_eq("INIT -> OP with acknowledge", seg.request(OP | ERR), (INIT | ERR, 0x0011))?;
    expect_eq("INIT (clears the error)", seg.request(INIT), (INIT, 0))?;
    seg.to_preop()?;
    expect_eq("PRE-OP -> OP", seg.request(OP), (PREOP | ERR, 0x0011))?;
    expect_eq("PRE-OP -> BOOT with acknowledge", seg.request(BOOT | ERR), (PREOP | ERR, 0x0011))
}

fn esm_unknown_state(seg: &mut Segment) -> Outcome {
    for state in [0x0005u16, 0x0006, 0x0007, 0x0009, 0x000F] {
        seg.request(INIT);
        expect_eq(&format!("request {state:#06X}"), seg.request(state), (INIT | ERR, 0x0012))?;
    }
    Ok(())
}

fn esm_error_stays_until_acknowledged(seg: &mut Segment) -> Outcome {
    expect_eq("INIT -> SAFE-OP", seg.request(SAFEOP), (INIT | ERR, 0x0011))?;
    seg.configure_mailboxes();
    expect_eq("PRE-OP requested without acknowledge", seg.request(PREOP), (INIT | ERR, 0x0011))?;
    expect_eq("PRE-OP requested with acknowledge", seg.request(PREOP | ERR), (PREOP, 0))
}

fn esm_boot_from_init_only(seg: &mut Segment) -> Outcome {
    expect_eq("INIT -> BOOT without the bootstrap mailbox", seg.request(BOOT), (INIT | ERR, 0x0015))?;
    seg.request(INIT);
    seg.configure_mailboxes();
    expect_eq("INIT -> BOOT", seg.request(BOOT), (BOOT, 0))?;
    expect_eq("BOOT -> PRE-OP", seg.request(PREOP), (BOOT | ERR, 0x0011))?;
    expect_eq("BOOT -> INIT", seg.request(INIT), (INIT, 0))
}

fn esm_safeop_without_process_data(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    // ETG.1000.6 Table 11 gives 0x001D (outputs) and 0x001E (inputs) for a process-data sync manager that does not
    // fit; either names the first one checked.
    let (status, code) = seg.request(SAFEOP);
    expect_that(status == PREOP | ERR && matches!(code, 0x001D | 0x001E), || {
        format!("AL status {status:#06X} code {code:#06X}, expected PRE-OP + ERR with 0x001D or 0x001E")
    })?;
    let (outputs, inputs) = seg.image_sizes();
    seg.request(PREOP | ERR);
    seg.configure_process_data(outputs + 2, inputs);
    expect_eq("SM2 2 bytes too long", seg.request(SAFEOP), (PREOP | ERR, 0x001D))?;
    seg.request(PREOP | ERR);
    seg.configure_process_data(outputs, inputs - 2);
    expect_eq("SM3 2 bytes too short", seg.request(SAFEOP), (PREOP | ERR, 0x001E))?;
    seg.request(PREOP | ERR);
    seg.configure_process_data(outputs, inputs);
    expect_eq("the default sizes", seg.request(SAFEOP), (SAFEOP, 0))
}

fn esm_op_waits_for_valid_outputs(seg: &mut Segment) -> Outcome {
    let len = seg.to_safeop()?;
    expect_eq("SAFE-OP -> OP before any output: held", seg.request(OP), (SAFEOP, 0))?;
    seg.cycles(5, None);
    expect_eq("5 ms later, no output yet: still held", seg.al_status(), (SAFEOP, 0))?;
    seg.cycles(1, Some(&vec![0u8; len]));
    expect_eq("after the first outputs", seg.al_status(), (OP, 0))
}

fn esm_op_without_outputs_times_out(seg: &mut Segment) -> Outcome {
    seg.to_safeop()?;
    expect_eq("SAFE-OP -> OP before any output: held", seg.request(OP), (SAFEOP, 0))?;
    let timeout = firmware::ecat::esm::SAFEOP_OP_TIMEOUT_MS;
    seg.cycles(timeout - 2, None);
    expect_eq("2 ms before the timeout", seg.al_status(), (SAFEOP, 0))?;
    seg.cycles(3, None);
    expect_eq("after the timeout", seg.al_status(), (SAFEOP | ERR, 0x001B))
}

fn esm_watchdog_expiry_and_recovery(seg: &mut Segment) -> Outcome {
    let len = seg.to_op()?;
    let image = vec![0u8; len];
    seg.cycles(10, Some(&image));
    expect_eq("OP while outputs come", seg.al_status(), (OP, 0))?;
    // The default process-data watchdog: 0x0420 = 1,000 ticks of (0x0400 + 2) x 40 ns = 100 ms.
    let ticks = u64::from(seg.read_u16(0x0420));
    let tick_ns = (u64::from(seg.read_u16(0x0400)) + 2) * 40;
    let watchdog_ms = ticks * tick_ns / 1_000_000;
    expect_eq("process-data watchdog, ms", watchdog_ms, 100)?;
    seg.cycles(watchdog_ms as u32 - 2, None);
    expect_eq("OP 2 ms before the watchdog", seg.al_status(), (OP, 0))?;
    seg.cycles(3, None);
    expect_eq("after the watchdog", seg.al_status(), (SAFEOP | ERR, 0x001B))?;
    expect_eq("OP requested with acknowledge: held for outputs", seg.request(OP | ERR), (SAFEOP, 0))?;
    seg.cycles(1, Some(&image));
    expect_eq("after the first outputs", seg.al_status(), (OP, 0))
}

fn esm_any_state_to_init(seg: &mut Segment) -> Outcome {
    seg.to_op()?;
    expect_eq("OP -> INIT", seg.request(INIT), (INIT, 0))?;
    let counter = seg.next_counter();
    seg.send_mailbox(MBX_COE, counter, &[0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
    let got = seg.receive();
    expect_that(got.is_none(), || format!("a mailbox answered in INIT: {got:02X?}"))
}

// --- Mailbox (ETG.1000.4, ETG.1000.6 §5) -------------------------------------------------------------------------

fn mbx_unknown_type(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let (kind, data) = seg.exchange(0x0F, &[1, 2, 3, 4])?;
    expect_eq(
        "mailbox error reply: type, service, code",
        (kind, data.get(..4).map(<[u8]>::to_vec)),
        (MBX_ERROR, Some(vec![0x01, 0x00, 0x02, 0x00])),
    )
}

fn mbx_repeated_counter_is_not_executed_twice(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let write = |v: u8| [0x00, 0x20, 0x2F, 0x60, 0x60, 0x00, v, 0, 0, 0];
    expect_eq("SM0", seg.send_mailbox(MBX_COE, 3, &write(1)), 1)?;
    expect_that(seg.receive().is_some(), || "no answer to the first write".into())?;
    expect_eq("SM0", seg.send_mailbox(MBX_COE, 3, &write(3)), 1)?;
    expect_that(seg.receive().is_none(), || "the repeated counter was answered".into())?;
    expect_eq("0x6060 after the repeated counter", seg.get(0x6060, 0)?, 1)
}

fn mbx_repeat_request_gives_the_last_reply_again(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let counter = seg.next_counter();
    seg.send_mailbox(MBX_COE, counter, &[0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
    let (_, first) = seg.receive().ok_or("the answer")?;
    // The master lost it: it toggles SM1's repeat request (0x080E bit 1 of the activate register 0x0806 + 8).
    let (activate, _) = seg.fprd(0x0806 + 8, 2);
    seg.fpwr(0x0806 + 8, &[activate[0] ^ 0x02]);
    let (pdi, _) = seg.fprd(0x0807 + 8, 1);
    expect_eq("repeat acknowledge follows the request", pdi[0] & 0x02, (activate[0] ^ 0x02) & 0x02)?;
    let (_, again) = seg.receive().ok_or("the repeated answer")?;
    expect_eq("the repeated answer", again, first)
}

fn mbx_too_short_for_coe(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let (kind, data) = seg.exchange(MBX_COE, &[0x00, 0x20, 0x40, 0x00])?;
    expect_eq(
        "mailbox error: type, code",
        (kind, data.get(2..4).map(<[u8]>::to_vec)),
        (MBX_ERROR, Some(vec![0x06, 0x00])),
    )
}

fn mbx_unknown_coe_service(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let (kind, data) = seg.exchange(MBX_COE, &[0x00, 0xF0, 0, 0, 0, 0, 0, 0, 0, 0])?;
    expect_eq(
        "mailbox error: type, code",
        (kind, data.get(2..4).map(<[u8]>::to_vec)),
        (MBX_ERROR, Some(vec![0x04, 0x00])),
    )
}

// --- CoE (ETG.1000.6 §5.6) --------------------------------------------------------------------------------------

fn coe_od_list_is_the_eds_object_list(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let data = seg.sdo_info(1, &1u16.to_le_bytes())?.map_err(|c| format!("aborted {c:#010X}"))?;
    expect_eq("list type echoed", data.get(..2).map(<[u8]>::to_vec), Some(vec![1, 0]))?;
    let listed: Vec<u16> = data[2..].chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    let mut expected: Vec<u16> = Eds::shipped().entries.iter().map(|e| e.index).collect();
    expected.dedup();
    expect_eq("indices of the OD list (all objects)", listed, expected)
}

fn coe_object_and_entry_descriptions(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let d = seg.sdo_info(3, &0x1018u16.to_le_bytes())?.map_err(|c| format!("aborted {c:#010X}"))?;
    let name = Eds::shipped().sections.get("1018").and_then(|s| s.get("parametername")).cloned().unwrap_or_default();
    expect_eq(
        "0x1018: index, data type, max sub, object code, name",
        (u16::from_le_bytes([d[0], d[1]]), d[4], d[5], String::from_utf8_lossy(&d[6..]).into_owned()),
        (0x1018, 4, 9, name),
    )?;
    let e = seg.sdo_info(5, &[0x40, 0x60, 0x00, 0x00])?.map_err(|c| format!("aborted {c:#010X}"))?;
    let access = u16::from_le_bytes([e[8], e[9]]);
    expect_eq(
        "0x6040:00: data type, bit length, readable in PRE-OP/SAFE-OP/OP, writable in all, RxPDO mappable",
        (u16::from_le_bytes([e[4], e[5]]), u16::from_le_bytes([e[6], e[7]]), access & 0x7F),
        (0x0006, 16, 0x7F),
    )?;
    expect_eq("missing object", seg.sdo_info(3, &0x1234u16.to_le_bytes())?, Err(0x0602_0000))
}

fn coe_complete_access_of_the_pdo_assignment(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    for index in [0x1C12u16, 0x1C13, 0x1A00] {
        let whole =
            seg.upload(index, 0, true)?.map_err(|c| format!("{index:#06X} complete access aborted {c:#010X}"))?;
        let n = seg.get(index, 0)?;
        expect_eq(&format!("{index:#06X}: sub 0 padded to 16 bits"), (u64::from(whole[0]), whole[1]), (n, 0))?;
        let width = if index == 0x1A00 { 4 } else { 2 };
        for sub in 1..=n as u8 {
            let at = 2 + (usize::from(sub) - 1) * width;
            let mut b = [0u8; 8];
            b[..width].copy_from_slice(&whole[at..at + width]);
            expect_eq(
                &format!("{index:#06X}:{sub} in the complete access"),
                u64::from_le_bytes(b),
                seg.get(index, sub)?,
            )?;
        }
    }
    // A complete-access download of 0x1C12: one RxPDO, 0x1600.
    let value = [1u8, 0, 0x00, 0x16];
    expect_eq("complete-access download of 0x1C12", seg.download(0x1C12, 0, &value, true)?, Ok(()))?;
    expect_eq("0x1C12:00 after it", seg.get(0x1C12, 0)?, 1)?;
    expect_eq("0x1C12:01 after it", seg.get(0x1C12, 1)?, 0x1600)
}

fn coe_wrong_sizes_are_refused(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    expect_eq("4 bytes to UNSIGNED16 0x6040", seg.download(0x6040, 0, &[0, 0, 0, 0], false)?, Err(0x0607_0012))?;
    expect_eq("1 byte to UNSIGNED32 0x6081", seg.download(0x6081, 0, &[1], false)?, Err(0x0607_0013))
}

fn coe_supported_drive_modes(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    let modes = seg.get(0x6502, 0)?;
    // CiA 402 0x6502 bits 0..9 and the mode each stands for (bit 4 reserved).
    let profile: [(u32, i8); 9] = [(0, 1), (1, 2), (2, 3), (3, 4), (5, 6), (6, 7), (7, 8), (8, 9), (9, 10)];
    let mut wrong = Vec::new();
    for (bit, mode) in profile {
        let supported = modes & (1 << bit) != 0;
        let answer = seg.download(0x6060, 0, &[mode as u8], false)?;
        if answer.is_ok() != supported {
            wrong.push(format!("mode {mode} (bit {bit} {}): {answer:X?}", u8::from(supported)));
        }
    }
    expect_that(modes & 0x1A0 == 0x1A0, || format!("0x6502 = {modes:#X} lacks CSP/CSV/CST"))?;
    expect_that(wrong.is_empty(), || wrong.join("; "))
}

fn coe_sync_parameters(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    for index in [0x1C32u16, 0x1C33] {
        expect_eq(&format!("{index:#06X}:00"), seg.get(index, 0)?, 0x20)?;
        let supported = seg.get(index, 4)?;
        expect_that(seg.get(index, 5)? > 0, || format!("{index:#06X}:05 minimum cycle time is 0"))?;
        // 0x1C3x:04 bit 0 free run, bit 1 synchronous (SM event), bits 4..2 DC types (ETG.1020 §6).
        if index == 0x1C32 {
            let pairs = [(0u16, supported & 0x01 != 0), (1, supported & 0x02 != 0), (2, supported & 0x0C != 0)];
            for (sync_type, allowed) in pairs {
                let answer = seg.download(index, 1, &sync_type.to_le_bytes(), false)?;
                expect_that(answer.is_ok() == allowed, || {
                    format!("{index:#06X}:01 = {sync_type}: {answer:X?}, 0x1C32:04 = {supported:#X}")
                })?;
            }
            expect_eq(
                "0x1C32:01 = 0x22 (no such type)",
                seg.download(index, 1, &0x22u16.to_le_bytes(), false)?,
                Err(0x0609_0030),
            )?;
        }
    }
    Ok(())
}

fn coe_emergency_on_a_fault(seg: &mut Segment) -> Outcome {
    seg.to_preop()?;
    seg.runner.node.sim.drive.communication_lost(firmware::supervision::communication::LinkLoss::EthercatWatchdog);
    seg.cycles(3, None);
    while seg.receive().is_some() {}
    let code = u64::from(firmware::fault::FaultId::EthercatWatchdog.info().code);
    let [one] = seg.emergencies.as_slice() else { return Err(format!("{} emergencies", seg.emergencies.len())) };
    expect_eq("emergency code", u64::from(u16::from_le_bytes([one[0], one[1]])), code)?;
    expect_eq("emergency error register = 0x1001", u64::from(one[2]), seg.get(0x1001, 0)?)
}

// --- SII and ESI (ETG.2010, ETG.2000) -----------------------------------------------------------------------------

fn sii_identity_and_mailboxes_agree_with_the_device(seg: &mut Segment) -> Outcome {
    let word32 = |seg: &mut Segment, w: u32| u64::from(seg.sii_word(w)) | u64::from(seg.sii_word(w + 1)) << 16;
    let sii = [word32(seg, 0x08), word32(seg, 0x0A), word32(seg, 0x0C), word32(seg, 0x0E)];
    seg.to_preop()?;
    let od = [seg.get(0x1018, 1)?, seg.get(0x1018, 2)?, seg.get(0x1018, 3)?, seg.get(0x1018, 4)?];
    expect_eq("SII words 0x08..0x0F against 0x1018:01..04", sii, od)?;
    let mbx: Vec<u16> = (0x18..=0x1B).map(|w| seg.sii_word(w)).collect();
    expect_eq(
        "SII standard mailbox (words 0x18..0x1B)",
        mbx,
        vec![
            generated::MAILBOX_OUT_START,
            generated::MAILBOX_OUT_SIZE,
            generated::MAILBOX_IN_START,
            generated::MAILBOX_IN_SIZE,
        ],
    )?;
    // Word 0x1C: mailbox protocols; CoE (bit 2) at least.
    expect_that(seg.sii_word(0x1C) & 0x04 != 0, || "SII announces no CoE".into())
}

fn esi_identity_and_pdos_agree_with_the_device(seg: &mut Segment) -> Outcome {
    let doc = roxmltree::Document::parse(esi_text()).map_err(|e| format!("the ESI parses: {e}"))?;
    let vendor = doc
        .descendants()
        .find(|n| n.has_tag_name("Vendor"))
        .and_then(|v| v.children().find(|c| c.has_tag_name("Id")))
        .and_then(|i| i.text())
        .and_then(hex_dec)
        .ok_or("Vendor/Id")?;
    let ty = doc
        .descendants()
        .find(|n| n.has_tag_name("Type") && n.attribute("ProductCode").is_some())
        .ok_or("Device/Type")?;
    let product = ty.attribute("ProductCode").and_then(hex_dec).ok_or("ProductCode")?;
    let revision = ty.attribute("RevisionNo").and_then(hex_dec).ok_or("RevisionNo")?;
    seg.to_preop()?;
    expect_eq(
        "ESI vendor, product, revision against 0x1018",
        (vendor, product, revision),
        (seg.get(0x1018, 1)?, seg.get(0x1018, 2)?, seg.get(0x1018, 3)?),
    )?;
    for (tag, assign, sm) in [("RxPdo", 0x1C12u16, "2"), ("TxPdo", 0x1C13, "3")] {
        let assigned: Vec<u64> = doc
            .descendants()
            .filter(|n| n.has_tag_name(tag) && n.attribute("Sm") == Some(sm))
            .filter_map(|n| n.children().find(|c| c.has_tag_name("Index")).and_then(|i| i.text()).and_then(hex_dec))
            .collect();
        let n = seg.get(assign, 0)?;
        let device: Vec<u64> = (1..=n as u8).map(|s| seg.get(assign, s)).collect::<Result<_, _>>()?;
        expect_eq(&format!("ESI {tag} with Sm={sm} against {assign:#06X}"), assigned, device)?;
        for pdo in doc.descendants().filter(|n| n.has_tag_name(tag)) {
            let index = pdo
                .children()
                .find(|c| c.has_tag_name("Index"))
                .and_then(|i| i.text())
                .and_then(hex_dec)
                .ok_or("PDO index")? as u16;
            let entries: Vec<u64> = pdo
                .children()
                .filter(|c| c.has_tag_name("Entry"))
                .map(|e| {
                    let get = |t: &str| {
                        e.children().find(|c| c.has_tag_name(t)).and_then(|c| c.text()).and_then(hex_dec).unwrap_or(0)
                    };
                    get("Index") << 16 | get("SubIndex") << 8 | get("BitLen")
                })
                .collect();
            let n = seg.get(index, 0)?;
            let device: Vec<u64> = (1..=n as u8).map(|s| seg.get(index, s)).collect::<Result<_, _>>()?;
            expect_eq(&format!("ESI entries of {index:#06X} against the device"), entries, device)?;
        }
    }
    let coe = doc.descendants().find(|n| n.has_tag_name("CoE")).ok_or("Mailbox/CoE")?;
    let complete_access =
        coe.attribute("CompleteAccess") == Some("true") || coe.attribute("CompleteAccess") == Some("1");
    let works = seg.upload(0x1C12, 0, true)?.is_ok();
    expect_eq("ESI CompleteAccess against a complete-access upload of 0x1C12", complete_access, works)
}

/// The suite's cases, in the tool's group order.
#[must_use]
pub fn cases() -> Vec<Case<Segment>> {
    vec![
        case!("ESM-01", "ETG.1000.6 §6.4.1", "power-up: AL status 0x0001 (INIT), code 0x0000", esm_power_up_in_init),
        case!("ESM-02", "ETG.1000.6 §6.4.1 Table 11", "INIT -> PRE-OP without SM0/SM1: INIT + ERR, 0x0016", esm_preop_without_mailboxes),
        case!("ESM-03", "ETG.1000.6 §6.4.1 Table 11", "INIT -> SAFE-OP/OP, PRE-OP -> OP/BOOT: 0x0011 in the current state; INIT clears", esm_invalid_transitions),
        case!("ESM-04", "ETG.1000.6 §6.4.1 Table 11", "requests 5, 6, 7, 9, 15: INIT + ERR, 0x0012", esm_unknown_state),
        case!("ESM-05", "ETG.1000.6 §6.4.1 (error acknowledge)", "the error stays until a request with bit 4; then PRE-OP, 0x0000", esm_error_stays_until_acknowledged),
        case!("ESM-06", "ETG.1000.6 §6.4.1 Table 11", "BOOT without bootstrap mailbox 0x0015; INIT -> BOOT; BOOT -> PRE-OP 0x0011; BOOT -> INIT", esm_boot_from_init_only),
        case!("ESM-07", "ETG.1000.6 §6.4.1 Table 11", "SAFE-OP without SM2/SM3: 0x001D/0x001E; SM2 too long 0x001D; SM3 too short 0x001E; default sizes SAFE-OP", esm_safeop_without_process_data),
        case!("ESM-08", "ETG.1000.6 §6.4.1 (SAFE-OP -> OP: valid outputs)", "OP requested before any output: held in SAFE-OP without error; OP after the first LRW", esm_op_waits_for_valid_outputs),
        case!("ESM-11", "ETG.1000.6 §6.4.1 Table 11", "OP requested, no outputs for the 10 s transition timeout: SAFE-OP + ERR 0x001B at 10 s", esm_op_without_outputs_times_out),
        case!("ESM-09", "ETG.1000.6 §6.4.1 Table 11, ESC SM watchdog", "outputs stop in OP: OP until 100 ms, then SAFE-OP + ERR 0x001B; OP + acknowledge held until outputs, then OP", esm_watchdog_expiry_and_recovery),
        case!("ESM-10", "ETG.1000.6 §6.4.1", "OP -> INIT allowed; no mailbox in INIT", esm_any_state_to_init),
        case!("MBX-01", "ETG.1000.6 §5.2 Table 29/30", "unknown mailbox type: error reply type 0, service 1, code 0x0002", mbx_unknown_type),
        case!("MBX-02", "ETG.1000.6 §5.2.1 (counter)", "a repeated counter is not executed again and not answered", mbx_repeated_counter_is_not_executed_twice),
        case!("MBX-03", "ETG.1000.4 (mailbox repeat), ESC 0x0806/0x0807 bit 1", "repeat request toggled: acknowledge follows, SM1 holds the last reply again", mbx_repeat_request_gives_the_last_reply_again),
        case!("MBX-04", "ETG.1000.6 §5.2 Table 30", "CoE request of 4 bytes: mailbox error 0x0006 (size too short)", mbx_too_short_for_coe),
        case!("MBX-05", "ETG.1000.6 §5.6.1, §5.2 Table 30", "CoE service 15: mailbox error 0x0004 (service not supported)", mbx_unknown_coe_service),
        case!("COE-01", "ETG.1000.6 §5.6.3.3", "Get OD list (all objects): every object of the EDS, in order", coe_od_list_is_the_eds_object_list),
        case!("COE-02", "ETG.1000.6 §5.6.3.5/6", "0x1018 description: RECORD, max sub 4, the EDS name; 0x6040:00 UINT 16 bit rw RxPDO; missing: 0x06020000", coe_object_and_entry_descriptions),
        case!("COE-03", "ETG.1000.6 §5.6.2.1.1, ETG.1020 §12.2", "complete access of 0x1C12/0x1C13/0x1A00: sub 0 padded to 16 bits, entries as read one by one; CA download of 0x1C12", coe_complete_access_of_the_pdo_assignment),
        case!("COE-04", "ETG.1000.6 §5.6.2, CiA 301 Table 22", "4 bytes to UINT: 0x06070012; 1 byte to UDINT: 0x06070013", coe_wrong_sizes_are_refused),
        case!("COE-05", "CiA 402 0x6502, ETG.6010", "every mode 0x6502 sets is accepted by 0x6060, every profile mode it clears refused; CSP, CSV, CST set", coe_supported_drive_modes),
        case!("COE-06", "ETG.1020 §6 (0x1C32/0x1C33)", "sub 0 = 32, minimum cycle time set, 0x1C32:01 takes exactly the types :04 supports, 0x22 refused 0x06090030", coe_sync_parameters),
        case!("COE-07", "ETG.1000.6 §5.6.4", "a fault: one CoE emergency with its code and 0x1001", coe_emergency_on_a_fault),
        case!("SII-01", "ETG.2010 Table 2", "SII identity words = 0x1018:01..04; standard mailbox = SM0/SM1 of the device; CoE announced", sii_identity_and_mailboxes_agree_with_the_device),
        case!("ESI-01", "ETG.2000 (Vendor, Type, RxPdo/TxPdo, CoE)", "ESI identity = 0x1018; Sm-assigned PDOs = 0x1C12/0x1C13; PDO entries = the device's mapping; CompleteAccess = what the device does", esi_identity_and_pdos_agree_with_the_device),
    ]
}

/// What the suite does not run, and why.
pub const SKIPS: &[Skip] = &[
    Skip {
        id: "EOE-01",
        clause: "ETG.1000.6 §5.7 (EoE)",
        why: "a servo drive of this kind has no Ethernet port behind the slave; the SII announces CoE and FoE only",
    },
    Skip {
        id: "SOE-01",
        clause: "ETG.1000.6 §5.8 (SoE)",
        why: "the drive profile is CiA 402 over CoE, not IEC 61800-7-204 (SERCOS)",
    },
];

/// Runs the suite.
#[must_use]
pub fn run() -> SuiteReport {
    run_suite("ecat", &cases(), SKIPS, Segment::powered_up)
}
