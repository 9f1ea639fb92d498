//! The CANopen conformance suite: the CiA 301 groups of the CANopen conformance test tool (EDS against the device,
//! SDO, NMT, heartbeat, SYNC, EMCY, PDO, store/restore) against one simulated drive on the simulated bus
//! (`hal_sim::sim::canopen::CanopenRunner`, the device `drive-sim canopen` serves: the drive's node, its parameter
//! store, program control and the restart of a reset node), spoken byte by byte as a test tool speaks it, so a
//! symmetric mistake of the firmware's own frame codec cannot hide.
//!
//! Every case starts from a freshly powered drive with node-ID 1 whose boot-up has been seen. Time runs only when a
//! case runs it: a request runs until the bus and the node are quiet again (the answer is out), [`Bus::run_ms`]
//! runs a span. Timing figures are exact: the simulation's clock is the node's.
//!
//! The expected answers are CiA 301's where it prescribes one; where it leaves the choice to the device, the
//! answer this drive documents (the module of `firmware` that says so is named in the case).

use firmware::canopen::frame::CanFrame;
use firmware::fault::FaultId;
use firmware::supervision::communication::LinkLoss;
use hal_sim::can::bus::Delivery;
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner, QUIET_LIMIT_NS};

use super::eds::Eds;
use super::{expect_eq, expect_that, run_suite, Case, Outcome, Skip, SuiteReport};

/// The node-ID of the drive under test.
pub const NODE: u8 = 1;
const SDO_RX: u16 = 0x600 + NODE as u16;
const SDO_TX: u16 = 0x580 + NODE as u16;
const EMCY: u16 = 0x080 + NODE as u16;
const HEARTBEAT: u16 = 0x700 + NODE as u16;
const SYNC: u16 = 0x080;
/// LSS (CiA 305 §4): master to slaves, slaves to master.
const LSS_MASTER: u16 = 0x7E5;
const LSS_SLAVE: u16 = 0x7E4;
/// "save" and "load" (CiA 301 §7.5.2.13/14), as the little-endian words written to 0x1010/0x1011.
const SAVE: u32 = u32::from_le_bytes(*b"save");
const LOAD: u32 = u32::from_le_bytes(*b"load");

/// One drive on the simulated bus, and the master's side of it.
pub struct Bus {
    runner: CanopenRunner,
    /// Every frame the drive sent, oldest first, until [`Bus::take_log`].
    log: Vec<CanFrame>,
}

impl Bus {
    /// A drive powered up, its boot-up seen.
    ///
    /// # Panics
    /// If no boot-up `0x701 [0x00]` comes within 100 ms.
    #[must_use]
    pub fn powered_up() -> Self {
        let runner = CanopenRunner::new(CanopenConfig {
            clock: CanClock::LockStep,
            nodes: 1,
            seed: 1,
            ..CanopenConfig::default()
        });
        let mut bus = Self { runner, log: Vec::new() };
        let frames = bus.run_ms(100);
        assert!(
            frames.iter().any(|f| f.id() == HEARTBEAT && f.data() == [0x00]),
            "the boot-up message within 100 ms: {frames:?}"
        );
        bus
    }

    /// `n` drives (slots 1..=n) powered up without a node-ID (CiA 305: they wait for an LSS master).
    #[must_use]
    pub fn unconfigured(n: u8) -> Self {
        let mut config = CanopenConfig { clock: CanClock::LockStep, nodes: n, seed: 1, ..CanopenConfig::default() };
        for slot in 1..=n {
            config = config.with_unconfigured(slot);
        }
        let mut bus = Self { runner: CanopenRunner::new(config), log: Vec::new() };
        bus.run_ms(100);
        bus
    }

    /// An LSS request (0x7E5); the answers on 0x7E4.
    pub fn lss(&mut self, data: [u8; 8]) -> Vec<[u8; 8]> {
        self.send(LSS_MASTER, &data)
            .into_iter()
            .filter(|f| f.id() == LSS_SLAVE)
            .filter_map(|f| f.data().try_into().ok())
            .collect()
    }

    /// Runs `ms` milliseconds; the frames the drive sent meanwhile.
    pub fn run_ms(&mut self, ms: u64) -> Vec<CanFrame> {
        let frames: Vec<_> = self.runner.run_for(ms * 1_000_000).into_iter().map(|d| d.frame).collect();
        self.log.extend_from_slice(&frames);
        frames
    }

    /// Every frame the drive sent since the last call (or power-up), whatever ran the time.
    pub fn take_log(&mut self) -> Vec<CanFrame> {
        std::mem::take(&mut self.log)
    }

    /// Runs `ms` milliseconds; the frames with their time on the bus.
    pub fn run_ms_timed(&mut self, ms: u64) -> Vec<Delivery> {
        let frames = self.runner.run_for(ms * 1_000_000);
        self.log.extend(frames.iter().map(|d| d.frame));
        frames
    }

    /// The simulated time, ns.
    #[must_use]
    pub fn now_ns(&self) -> u64 {
        self.runner.now_ns()
    }

    /// Sends a frame and runs until the bus and the node are quiet; the frames the drive sent.
    ///
    /// # Panics
    /// If `id` and `data` do not form a CAN frame (a case's mistake).
    pub fn send(&mut self, id: u16, data: &[u8]) -> Vec<CanFrame> {
        self.runner.send(CanFrame::new(id, data).expect("a valid frame"));
        let frames: Vec<_> = self.runner.run_until_quiet(QUIET_LIMIT_NS).into_iter().map(|d| d.frame).collect();
        self.log.extend_from_slice(&frames);
        frames
    }

    /// An NMT command `cs` to `target` (0: all).
    pub fn nmt(&mut self, cs: u8, target: u8) -> Vec<CanFrame> {
        self.send(0x000, &[cs, target])
    }

    /// One SDO request; the drive's answer, if any (more than one answer is an error of its own).
    ///
    /// # Errors
    /// The drive answered one request with two SDO frames.
    pub fn sdo(&mut self, request: [u8; 8]) -> Result<Option<[u8; 8]>, String> {
        let answers: Vec<_> = self.send(SDO_RX, &request).into_iter().filter(|f| f.id() == SDO_TX).collect();
        match answers.as_slice() {
            [] => Ok(None),
            [one] => {
                Ok(Some(one.data().try_into().map_err(|_| format!("an SDO answer of {} bytes", one.data().len()))?))
            }
            more => Err(format!("{} answers to one request: {more:02X?}", more.len())),
        }
    }

    /// One SDO request that must be answered.
    ///
    /// # Errors
    /// No answer, or more than one.
    pub fn ask(&mut self, request: [u8; 8]) -> Result<[u8; 8], String> {
        self.sdo(request)?.ok_or_else(|| format!("no answer to {request:02X?}"))
    }

    /// An upload spoken byte by byte (expedited or segmented, CiA 301 §7.2.4.3.6/7): `Ok(Ok(value))`,
    /// `Ok(Err(abort code))`.
    ///
    /// # Errors
    /// An answer no upload allows.
    pub fn upload(&mut self, index: u16, sub: u8) -> Result<Result<Vec<u8>, u32>, String> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.ask([0x40, i0, i1, sub, 0, 0, 0, 0])?;
        if r[0] == 0x80 {
            return Ok(Err(abort_code(&r)));
        }
        if r[1..4] != [i0, i1, sub] {
            return Err(format!("the answer names another object: {r:02X?}"));
        }
        match r[0] {
            c if c & 0xF3 == 0x43 => Ok(Ok(r[4..8 - usize::from((c >> 2) & 3)].to_vec())),
            0x42 => Ok(Ok(r[4..8].to_vec())),
            0x41 => {
                let size = abort_code(&r) as usize;
                let mut value = Vec::new();
                let mut toggle = 0u8;
                loop {
                    let s = self.ask([0x60 | toggle, 0, 0, 0, 0, 0, 0, 0])?;
                    if s[0] == 0x80 {
                        return Ok(Err(abort_code(&s)));
                    }
                    if s[0] & 0xE0 != 0 || s[0] & 0x10 != toggle {
                        return Err(format!("an upload segment with toggle {toggle:#04X} expected: {s:02X?}"));
                    }
                    let len = 7 - usize::from((s[0] >> 1) & 7);
                    value.extend_from_slice(&s[1..=len]);
                    if s[0] & 1 == 1 {
                        if value.len() != size {
                            return Err(format!("{} bytes after the initiate announced {size}", value.len()));
                        }
                        return Ok(Ok(value));
                    }
                    toggle ^= 0x10;
                }
            }
            other => Err(format!("an upload answered with command {other:#04X}: {r:02X?}")),
        }
    }

    /// An expedited download of 1..=4 bytes, size indicated: `Ok(Ok(()))` or `Ok(Err(abort code))`.
    ///
    /// # Errors
    /// An answer no download allows.
    pub fn download(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<Result<(), u32>, String> {
        let [i0, i1] = index.to_le_bytes();
        let unused = 4u8.saturating_sub(value.len() as u8);
        let mut req = [0x23 | (unused << 2), i0, i1, sub, 0, 0, 0, 0];
        req[4..4 + value.len().min(4)].copy_from_slice(&value[..value.len().min(4)]);
        let r = self.ask(req)?;
        match r[0] {
            0x60 if r[1..4] == [i0, i1, sub] => Ok(Ok(())),
            0x80 => Ok(Err(abort_code(&r))),
            _ => Err(format!("a download answered with {r:02X?}")),
        }
    }

    /// [`Self::download`] of a `u32`.
    ///
    /// # Errors
    /// As [`Self::download`].
    pub fn download_u32(&mut self, index: u16, sub: u8, value: u32) -> Result<Result<(), u32>, String> {
        self.download(index, sub, &value.to_le_bytes())
    }

    /// A download that must succeed.
    ///
    /// # Errors
    /// The drive aborted it, or answered oddly.
    pub fn set(&mut self, index: u16, sub: u8, value: &[u8]) -> Outcome {
        match self.download(index, sub, value)? {
            Ok(()) => Ok(()),
            Err(code) => Err(format!("writing {index:#06X}:{sub} was aborted with {code:#010X}")),
        }
    }

    /// An upload that must succeed, as an unsigned little-endian number.
    ///
    /// # Errors
    /// The drive aborted it, or the value is longer than 8 bytes.
    pub fn get(&mut self, index: u16, sub: u8) -> Result<u64, String> {
        match self.upload(index, sub)? {
            Ok(v) if v.len() <= 8 => {
                let mut b = [0u8; 8];
                b[..v.len()].copy_from_slice(&v);
                Ok(u64::from_le_bytes(b))
            }
            Ok(v) => Err(format!("{index:#06X}:{sub} holds {} bytes", v.len())),
            Err(code) => Err(format!("reading {index:#06X}:{sub} was aborted with {code:#010X}")),
        }
    }

    /// The drive's node, to inject what no master frame can (a lost link).
    fn drive(&mut self) -> &mut hal_sim::sim::canopen::CanDrive {
        self.runner.drive_mut(NODE).expect("node 1 is on the bus")
    }
}

fn abort_code(r: &[u8; 8]) -> u32 {
    u32::from_le_bytes([r[4], r[5], r[6], r[7]])
}

/// `Ok(Err(code))` of an SDO helper compared with the expected abort.
fn expect_abort<T: std::fmt::Debug>(what: &str, seen: Result<Result<T, u32>, String>, code: u32) -> Outcome {
    match seen? {
        Err(c) if c == code => Ok(()),
        Err(c) => Err(format!("{what}: abort {c:#010X}, expected {code:#010X}")),
        Ok(v) => Err(format!("{what}: accepted ({v:?}), expected abort {code:#010X}")),
    }
}

fn heartbeat_states(frames: &[CanFrame]) -> Vec<u8> {
    frames.iter().filter(|f| f.id() == HEARTBEAT && f.data().len() == 1).map(|f| f.data()[0]).collect()
}

fn emcy_frames(frames: &[CanFrame]) -> Vec<Vec<u8>> {
    frames.iter().filter(|f| f.id() == EMCY).map(|f| f.data().to_vec()).collect()
}

// --- EDS and object dictionary (CiA 306 §4.6, CiA 301 §7.4) ------------------------------------------------

fn od_every_readable_variable_uploads_with_its_size(bus: &mut Bus) -> Outcome {
    let mut wrong = Vec::new();
    for e in Eds::shipped().entries.iter().filter(|e| e.readable()) {
        match (bus.upload(e.index, e.sub)?, e.fixed_size()) {
            (Ok(v), Some(size)) if v.len() != size => {
                wrong.push(format!("{:#06X}:{} {} bytes, type {:#06X}", e.index, e.sub, v.len(), e.data_type));
            }
            (Ok(_), _) => {}
            (Err(code), _) => wrong.push(format!("{:#06X}:{} aborted {code:#010X}", e.index, e.sub)),
        }
    }
    expect_that(wrong.is_empty(), || wrong.join("; "))
}

fn od_read_only_variables_refuse_a_download(bus: &mut Bus) -> Outcome {
    let mut wrong = Vec::new();
    for e in Eds::shipped().entries.iter().filter(|e| e.read_only()) {
        let Some(size) = e.fixed_size().filter(|s| *s <= 4) else { continue };
        let value = vec![0u8; size];
        match bus.download(e.index, e.sub, &value)? {
            Err(0x0601_0002) => {}
            other => wrong.push(format!("{:#06X}:{} {other:X?}", e.index, e.sub)),
        }
    }
    expect_that(wrong.is_empty(), || format!("not refused with 0x06010002: {}", wrong.join("; ")))
}

fn od_write_only_variables_refuse_an_upload(bus: &mut Bus) -> Outcome {
    let write_only: Vec<_> = Eds::shipped().entries.iter().filter(|e| !e.readable()).collect();
    expect_that(!write_only.is_empty(), || "the EDS lists no write-only variable".into())?;
    for e in write_only {
        expect_abort(&format!("upload of {:#06X}:{}", e.index, e.sub), bus.upload(e.index, e.sub), 0x0601_0001)?;
    }
    Ok(())
}

fn od_objects_absent_from_the_eds_do_not_exist(bus: &mut Bus) -> Outcome {
    let mut wrong = Vec::new();
    for index in (0x1000..=0x1FFF).chain([0x2FFF, 0x5FFF, 0x6FFF, 0x9FFF]) {
        if Eds::shipped().has_object(index) {
            continue;
        }
        match bus.upload(index, 0)? {
            Err(0x0602_0000) => {}
            other => wrong.push(format!("{index:#06X}: {other:X?}")),
        }
    }
    expect_that(wrong.is_empty(), || format!("not 0x06020000: {}", wrong.join("; ")))
}

fn od_sub_indices_past_the_highest_do_not_exist(bus: &mut Bus) -> Outcome {
    let mut wrong = Vec::new();
    let mut checked = 0;
    for e in Eds::shipped()
        .entries
        .iter()
        .filter(|e| e.sub == 0 && Eds::shipped().entries.iter().any(|o| o.index == e.index && o.sub > 0))
    {
        let highest = Eds::shipped().entries.iter().filter(|o| o.index == e.index).map(|o| o.sub).max().unwrap_or(0);
        let Some(past) = highest.checked_add(1) else { continue };
        checked += 1;
        match bus.upload(e.index, past)? {
            Err(0x0609_0011) => {}
            other => wrong.push(format!("{:#06X}:{past}: {other:X?}", e.index)),
        }
    }
    expect_that(checked > 0 && wrong.is_empty(), || format!("{checked} checked; not 0x06090011: {}", wrong.join("; ")))
}

fn od_constants_and_identity_read_as_the_eds_states(bus: &mut Bus) -> Outcome {
    let mut wrong = Vec::new();
    let mut checked = 0;
    for e in Eds::shipped().entries.iter().filter(|e| e.access == "const" || e.index == 0x1000 || e.index == 0x1018) {
        let (Some(expected), Some(size)) = (e.default_for(NODE), e.fixed_size()) else { continue };
        checked += 1;
        let expected = expected & size_mask(size);
        let seen = bus.get(e.index, e.sub)?;
        if seen != expected {
            wrong.push(format!("{:#06X}:{} = {seen:#X}, EDS {expected:#X}", e.index, e.sub));
        }
    }
    expect_that(checked > 0 && wrong.is_empty(), || format!("{checked} checked: {}", wrong.join("; ")))
}

fn od_writable_variables_read_their_eds_default_at_power_up(bus: &mut Bus) -> Outcome {
    let mut wrong = Vec::new();
    for e in Eds::shipped().entries.iter().filter(|e| !e.read_only() && e.readable()) {
        let (Some(expected), Some(size)) = (e.default_for(NODE), e.fixed_size()) else { continue };
        // 0x60FE:01 shows the holding-brake and ready outputs in its read-only bits 24 and 25 (device.toml): only
        // the bits a master writes (0, 16, 17) start at the default.
        let mask = if (e.index, e.sub) == (0x60FE, 1) { 0x0003_0001 } else { size_mask(size) };
        let seen = bus.get(e.index, e.sub)? & mask;
        if seen != expected & mask {
            wrong.push(format!("{:#06X}:{} = {seen:#X}, EDS {:#X}", e.index, e.sub, expected & mask));
        }
    }
    expect_that(wrong.is_empty(), || wrong.join("; "))
}

fn size_mask(size: usize) -> u64 {
    if size >= 8 {
        u64::MAX
    } else {
        (1u64 << (8 * size)) - 1
    }
}

fn od_a_value_too_long_or_too_short_is_refused(bus: &mut Bus) -> Outcome {
    // 0x1017 producer heartbeat time: UNSIGNED16.
    expect_abort("4 bytes to UNSIGNED16 0x1017", bus.download(0x1017, 0, &[10, 0, 0, 0]), 0x0607_0012)?;
    expect_abort("1 byte to UNSIGNED16 0x1017", bus.download(0x1017, 0, &[10]), 0x0607_0013)?;
    expect_eq("0x1017 after both", bus.get(0x1017, 0)?, 0)
}

// --- SDO (CiA 301 §7.2.4) -------------------------------------------------------------------------------------

fn sdo_expedited_upload_states_its_size(bus: &mut Bus) -> Outcome {
    // 0x1001 error register: UNSIGNED8 -> command 0x4F (e = 1, s = 1, n = 3).
    let r = bus.ask([0x40, 0x01, 0x10, 0x00, 0, 0, 0, 0])?;
    expect_eq("answer to the upload of 0x1001", r[..4].to_vec(), vec![0x4F, 0x01, 0x10, 0x00])?;
    // 0x1017: UNSIGNED16 -> 0x4B; 0x1000: UNSIGNED32 -> 0x43.
    expect_eq("command for UNSIGNED16 0x1017", bus.ask([0x40, 0x17, 0x10, 0x00, 0, 0, 0, 0])?[0], 0x4B)?;
    expect_eq("command for UNSIGNED32 0x1000", bus.ask([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])?[0], 0x43)
}

fn sdo_segmented_upload_toggles_and_ends_with_the_size_announced(bus: &mut Bus) -> Outcome {
    let name =
        Eds::shipped().entry(0x1008, 0).and_then(|e| e.default.clone()).ok_or("0x1008 has a default in the EDS")?;
    expect_that(name.len() > 4, || format!("0x1008 {name:?} needs a segmented transfer"))?;
    expect_eq("0x1008 by segments", bus.upload(0x1008, 0)?, Ok(name.into_bytes()))
}

fn sdo_upload_segment_with_the_wrong_toggle_is_aborted(bus: &mut Bus) -> Outcome {
    let r = bus.ask([0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0])?;
    expect_eq("initiate of the segmented upload of 0x1008", r[0], 0x41)?;
    let s = bus.ask([0x70, 0, 0, 0, 0, 0, 0, 0])?;
    expect_eq("answer to toggle 1 as the first segment", (s[0], abort_code(&s)), (0x80, 0x0503_0000))
}

fn sdo_download_segment_with_the_wrong_toggle_is_aborted(bus: &mut Bus) -> Outcome {
    // 0x607A target position, 4 bytes, segmented.
    let r = bus.ask([0x21, 0x7A, 0x60, 0x00, 4, 0, 0, 0])?;
    expect_eq("initiate of the segmented download", r[..4].to_vec(), vec![0x60, 0x7A, 0x60, 0x00])?;
    let s = bus.ask([0x10 | (3 << 1) | 1, 1, 2, 3, 4, 0, 0, 0])?;
    expect_eq("answer to toggle 1 as the first segment", (s[0], abort_code(&s)), (0x80, 0x0503_0000))?;
    expect_eq("0x607A untouched", bus.get(0x607A, 0)?, 0)
}

fn sdo_unknown_command_specifier_is_aborted(bus: &mut Bus) -> Outcome {
    let r = bus.ask([0xE0, 0x00, 0x10, 0x00, 0, 0, 0, 0])?;
    expect_eq("answer to ccs 7", (r[0], abort_code(&r)), (0x80, 0x0504_0001))
}

fn sdo_segment_without_a_transfer_is_aborted(bus: &mut Bus) -> Outcome {
    let r = bus.ask([0x60, 0, 0, 0, 0, 0, 0, 0])?;
    expect_eq("answer to an upload segment request with no transfer", (r[0], abort_code(&r)), (0x80, 0x0504_0001))
}

fn sdo_expedited_download_without_size_takes_the_object_size(bus: &mut Bus) -> Outcome {
    // 0x22: e = 1, s = 0: the data's length is the object's (UNSIGNED16 0x1017).
    let r = bus.ask([0x22, 0x17, 0x10, 0x00, 0x2C, 0x01, 0xAA, 0xBB])?;
    expect_eq("answer", r[..4].to_vec(), vec![0x60, 0x17, 0x10, 0x00])?;
    expect_eq("0x1017", bus.get(0x1017, 0)?, 300)
}

fn sdo_segmented_download_longer_than_announced_is_aborted(bus: &mut Bus) -> Outcome {
    let r = bus.ask([0x21, 0x7A, 0x60, 0x00, 4, 0, 0, 0])?;
    expect_eq("initiate", r[0], 0x60)?;
    // One last segment of 7 bytes where 4 were announced.
    let s = bus.ask([0x01, 1, 2, 3, 4, 5, 6, 7])?;
    expect_eq("answer to 7 bytes after 4 announced", (s[0], abort_code(&s)), (0x80, 0x0607_0012))?;
    expect_eq("0x607A untouched", bus.get(0x607A, 0)?, 0)
}

fn sdo_block_upload_with_an_invalid_block_size_is_aborted(bus: &mut Bus) -> Outcome {
    for blksize in [0u8, 128] {
        let r = bus.ask([0xA4, 0x08, 0x10, 0x00, blksize, 0, 0, 0])?;
        expect_eq(&format!("answer to blksize {blksize}"), (r[0], abort_code(&r)), (0x80, 0x0504_0002))?;
    }
    Ok(())
}

/// Block download of `value` to `index:sub` up to the end frame, whose CRC is `crc`; the answer to the end.
fn block_download(bus: &mut Bus, index: u16, value: &[u8], crc: u16) -> Result<[u8; 8], String> {
    let [i0, i1] = index.to_le_bytes();
    let [s0, s1, s2, s3] = (value.len() as u32).to_le_bytes();
    let r = bus.ask([0xC6, i0, i1, 0, s0, s1, s2, s3])?;
    if r[0] & 0xFB != 0xA0 || r[4] == 0 || r[4] > 127 {
        return Err(format!("block download initiate answered {r:02X?}"));
    }
    let chunks: Vec<&[u8]> = value.chunks(7).collect();
    for (i, chunk) in chunks.iter().enumerate() {
        let last = i + 1 == chunks.len();
        let mut seg = [0u8; 8];
        seg[0] = (i as u8 + 1) | if last { 0x80 } else { 0 };
        seg[1..=chunk.len()].copy_from_slice(chunk);
        let answer = bus.sdo(seg)?;
        if last {
            let a = answer.ok_or("no acknowledgement of the sub-block")?;
            if a[0] != 0xA2 || usize::from(a[1]) != chunks.len() {
                return Err(format!("sub-block acknowledged {a:02X?}"));
            }
        }
    }
    let unused = (7 - value.len() % 7) % 7;
    let [c0, c1] = crc.to_le_bytes();
    bus.ask([0xC1 | ((unused as u8) << 2), c0, c1, 0, 0, 0, 0, 0])
}

/// CRC-16/XMODEM (CiA 301 §7.2.4.3.16: polynomial x^16 + x^12 + x^5 + 1, start 0), computed here.
fn crc16(data: &[u8]) -> u16 {
    let mut crc = 0u16;
    for b in data {
        crc ^= u16::from(*b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
        }
    }
    crc
}

fn sdo_block_download_with_its_crc_is_taken(bus: &mut Bus) -> Outcome {
    let value = (-123_456i32).to_le_bytes();
    let end = block_download(bus, 0x607A, &value, crc16(&value))?;
    expect_eq("answer to the end", end[0], 0xA1)?;
    expect_eq("0x607A", bus.get(0x607A, 0)? as u32 as i32, -123_456)
}

fn sdo_block_download_with_a_wrong_crc_is_aborted(bus: &mut Bus) -> Outcome {
    let value = 777i32.to_le_bytes();
    let end = block_download(bus, 0x607A, &value, crc16(&value) ^ 0x0101)?;
    expect_eq("answer to the end", (end[0], abort_code(&end)), (0x80, 0x0504_0004))?;
    expect_eq("0x607A untouched", bus.get(0x607A, 0)?, 0)
}

fn sdo_block_download_acknowledges_the_last_segment_in_sequence(bus: &mut Bus) -> Outcome {
    let value = 4242i32.to_le_bytes();
    let r = bus.ask([0xC6, 0x7A, 0x60, 0, 4, 0, 0, 0])?;
    expect_eq("initiate", r[0] & 0xFB, 0xA0)?;
    // Segment 2 (last) where 1 was due: the server acknowledges sequence 0, nothing was received in order.
    let mut seg = [0x82, 0, 0, 0, 0, 0, 0, 0];
    seg[1..5].copy_from_slice(&value);
    let ack = bus.ask(seg)?;
    expect_eq("acknowledgement of the out-of-sequence segment", (ack[0], ack[1]), (0xA2, 0))?;
    seg[0] = 0x81;
    let ack = bus.ask(seg)?;
    expect_eq("acknowledgement of the repeated segment", (ack[0], ack[1]), (0xA2, 1))?;
    let [c0, c1] = crc16(&value).to_le_bytes();
    let end = bus.ask([0xC1 | (3 << 2), c0, c1, 0, 0, 0, 0, 0])?;
    expect_eq("answer to the end", end[0], 0xA1)?;
    expect_eq("0x607A", bus.get(0x607A, 0)?, 4242)
}

fn sdo_silent_client_gets_the_timeout_abort(bus: &mut Bus) -> Outcome {
    let r = bus.ask([0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0])?;
    expect_eq("initiate of the segmented upload of 0x1008", r[0], 0x41)?;
    let start = bus.now_ns();
    let frames = bus.run_ms_timed(1_100);
    let abort: Vec<_> = frames.iter().filter(|d| d.frame.id() == SDO_TX).collect();
    let [one] = abort.as_slice() else { return Err(format!("{} SDO frames in 1.1 s", abort.len())) };
    let data: [u8; 8] = one.frame.data().try_into().map_err(|_| "8 bytes")?;
    expect_eq("the abort", (data[0], abort_code(&data)), (0x80, 0x0504_0000))?;
    // The node checks its timeout at each 400 us slow tick.
    let after_ms = (one.end_ns - start) as f64 / 1e6;
    expect_that((1_000.0..=1_001.0).contains(&after_ms), || {
        format!("abort after {after_ms:.3} ms, expected 1,000..1,001")
    })
}

fn sdo_short_frame_gets_no_answer(bus: &mut Bus) -> Outcome {
    let frames = bus.send(SDO_RX, &[0x40, 0x00, 0x10, 0x00]);
    expect_that(frames.iter().all(|f| f.id() != SDO_TX), || format!("answered a 4-byte SDO frame: {frames:?}"))?;
    expect_eq(
        "0x1000 after it",
        bus.get(0x1000, 0)?,
        Eds::shipped().entry(0x1000, 0).and_then(|e| e.default_for(NODE)).unwrap_or(0),
    )
}

fn sdo_client_abort_ends_the_transfer(bus: &mut Bus) -> Outcome {
    expect_eq("initiate", bus.ask([0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0])?[0], 0x41)?;
    let frames = bus.send(SDO_RX, &[0x80, 0x08, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]);
    expect_that(frames.iter().all(|f| f.id() != SDO_TX), || "an abort is not answered".into())?;
    let r = bus.ask([0x60, 0, 0, 0, 0, 0, 0, 0])?;
    expect_eq("a segment request after the abort", (r[0], abort_code(&r)), (0x80, 0x0504_0001))
}

// --- NMT (CiA 301 §7.2.8.3.1, §7.3.2) -------------------------------------------------------------------------

/// The distinct states of the heartbeats in the next 25 ms (10 ms producer time: two or three of them).
fn nmt_states_by_heartbeat(bus: &mut Bus) -> Result<Vec<u8>, String> {
    let mut states = heartbeat_states(&bus.run_ms(25));
    if states.len() < 2 {
        return Err(format!("{} heartbeats in 25 ms at 10 ms", states.len()));
    }
    states.dedup();
    Ok(states)
}

fn nmt_the_commands_move_the_state_machine(bus: &mut Bus) -> Outcome {
    bus.set(0x1017, 0, &10u16.to_le_bytes())?;
    expect_eq("pre-operational after boot-up", nmt_states_by_heartbeat(bus)?, vec![0x7F])?;
    bus.nmt(0x01, NODE);
    expect_eq("after start remote node", nmt_states_by_heartbeat(bus)?, vec![0x05])?;
    bus.nmt(0x02, NODE);
    expect_eq("after stop remote node", nmt_states_by_heartbeat(bus)?, vec![0x04])?;
    bus.nmt(0x80, NODE);
    expect_eq("after enter pre-operational", nmt_states_by_heartbeat(bus)?, vec![0x7F])?;
    bus.nmt(0x01, 0);
    expect_eq("after start to all (node-ID 0)", nmt_states_by_heartbeat(bus)?, vec![0x05])?;
    bus.nmt(0x02, NODE + 1);
    expect_eq("after a stop to another node", nmt_states_by_heartbeat(bus)?, vec![0x05])
}

fn nmt_unknown_commands_and_bad_lengths_are_ignored(bus: &mut Bus) -> Outcome {
    bus.set(0x1017, 0, &10u16.to_le_bytes())?;
    let frames = bus.nmt(0x03, NODE);
    expect_that(frames.iter().all(|f| f.id() != HEARTBEAT || f.data() != [0]), || "no reset on cs 0x03".into())?;
    let frames = bus.send(0x000, &[0x01]);
    expect_that(frames.iter().all(|f| f.id() != HEARTBEAT || f.data() == [0x7F]), || format!("{frames:?}"))?;
    let frames = bus.send(0x000, &[0x01, NODE, 0]);
    expect_that(frames.iter().all(|f| f.id() != HEARTBEAT || f.data() == [0x7F]), || format!("{frames:?}"))?;
    expect_eq("still pre-operational", nmt_states_by_heartbeat(bus)?, vec![0x7F])
}

fn nmt_no_sdo_in_stopped(bus: &mut Bus) -> Outcome {
    bus.nmt(0x02, NODE);
    expect_eq("answer to an upload in stopped", bus.sdo([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])?, None)?;
    bus.nmt(0x80, NODE);
    expect_that(bus.sdo([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])?.is_some(), || "no answer in pre-operational".into())
}

fn nmt_reset_communication_boots_again_with_the_communication_defaults(bus: &mut Bus) -> Outcome {
    bus.set(0x1017, 0, &50u16.to_le_bytes())?;
    bus.set(0x6081, 0, &1_234u32.to_le_bytes())?;
    let frames = bus.nmt(0x82, NODE);
    let frames = [frames, bus.run_ms(5)].concat();
    expect_eq(
        "frames after reset communication",
        frames.iter().filter(|f| f.id() == HEARTBEAT).map(|f| f.data().to_vec()).collect::<Vec<_>>(),
        vec![vec![0x00]],
    )?;
    expect_eq("0x1017 back to the EDS default", bus.get(0x1017, 0)?, 0)?;
    expect_eq("0x6081 (application) kept", bus.get(0x6081, 0)?, 1_234)
}

fn nmt_reset_node_boots_again_with_the_power_on_values(bus: &mut Bus) -> Outcome {
    bus.set(0x1017, 0, &50u16.to_le_bytes())?;
    bus.set(0x6081, 0, &1_234u32.to_le_bytes())?;
    let frames = [bus.nmt(0x81, NODE), bus.run_ms(100)].concat();
    expect_that(frames.iter().any(|f| f.id() == HEARTBEAT && f.data() == [0x00]), || {
        format!("no boot-up: {frames:?}")
    })?;
    let default = Eds::shipped().entry(0x6081, 0).and_then(|e| e.default_for(NODE)).ok_or("0x6081 default")?;
    expect_eq("0x6081 back to its power-on value", bus.get(0x6081, 0)?, default)?;
    expect_eq("0x1017 back", bus.get(0x1017, 0)?, 0)
}

/// RPDO 1's COB-ID and what its default mapping's first object is.
fn rpdo1(bus: &mut Bus) -> Result<(u16, u16), String> {
    let cob = bus.get(0x1400, 1)? as u16 & 0x7FF;
    let first = (bus.get(0x1600, 1)? >> 16) as u16;
    Ok((cob, first))
}

fn nmt_rpdo_only_in_operational(bus: &mut Bus) -> Outcome {
    let (cob, first) = rpdo1(bus)?;
    expect_eq("RPDO 1 maps the controlword first", first, 0x6040)?;
    let length: u64 =
        (1..=bus.get(0x1600, 0)? as u8).map(|s| bus.get(0x1600, s).map(|m| m & 0xFF)).sum::<Result<u64, _>>()? / 8;
    let mut data = vec![0u8; length as usize];
    data[0] = 0x06;
    bus.send(cob, &data);
    bus.run_ms(2);
    expect_eq("controlword after an RPDO in pre-operational", bus.get(0x6040, 0)?, 0)?;
    bus.nmt(0x01, NODE);
    bus.send(cob, &data);
    bus.run_ms(2);
    expect_eq("controlword after an RPDO in operational", bus.get(0x6040, 0)?, 0x06)
}

fn nmt_tpdo_only_in_operational(bus: &mut Bus) -> Outcome {
    // TPDO 1 synchronous (type 1).
    bus.set(0x1800, 1, &(0x8000_0180u32 + u32::from(NODE)).to_le_bytes())?;
    bus.set(0x1800, 2, &[1])?;
    bus.set(0x1800, 1, &(0x4000_0180u32 + u32::from(NODE)).to_le_bytes())?;
    let tpdo = 0x180 + u16::from(NODE);
    let frames = [bus.send(SYNC, &[]), bus.run_ms(1)].concat();
    expect_that(frames.iter().all(|f| f.id() != tpdo), || "a TPDO in pre-operational".into())?;
    bus.nmt(0x01, NODE);
    let frames = [bus.send(SYNC, &[]), bus.run_ms(1)].concat();
    expect_eq("TPDO 1 after a SYNC in operational", frames.iter().filter(|f| f.id() == tpdo).count(), 1)
}

// --- Heartbeat (CiA 301 §7.2.8.3.2) ----------------------------------------------------------------------------

fn hb_producer_time_is_kept(bus: &mut Bus) -> Outcome {
    bus.set(0x1017, 0, &10u16.to_le_bytes())?;
    let frames: Vec<_> = bus.run_ms_timed(105).into_iter().filter(|d| d.frame.id() == HEARTBEAT).collect();
    expect_eq("heartbeats in 105 ms at 10 ms", frames.len(), 10)?;
    let gaps: Vec<u64> = frames.windows(2).map(|w| (w[1].end_ns - w[0].end_ns) / 100_000).collect();
    expect_that(gaps.iter().all(|g| *g == 100), || format!("gaps in 0.1 ms: {gaps:?}"))?;
    bus.set(0x1017, 0, &[0, 0])?;
    let frames = bus.run_ms(100);
    expect_eq("heartbeats with 0x1017 = 0", heartbeat_states(&frames).len(), 0)
}

fn hb_consumer_entries_for_one_producer_are_refused(bus: &mut Bus) -> Outcome {
    bus.set(0x1016, 1, &0x0005_0064u32.to_le_bytes())?;
    expect_abort("a second entry for node 5", bus.download_u32(0x1016, 2, 0x0005_00C8), 0x0604_0043)?;
    expect_abort("reserved bits 31..24", bus.download_u32(0x1016, 2, 0x0106_0064), 0x0609_0030)?;
    expect_eq("sub 2 untouched", bus.get(0x1016, 2)?, 0)
}

fn hb_consumer_timeout_raises_the_emcy(bus: &mut Bus) -> Outcome {
    // Producer 127 supervised at 50 ms.
    bus.set(0x1016, 1, &0x007F_0032u32.to_le_bytes())?;
    bus.send(0x77F, &[0x05]);
    let sent = bus.now_ns();
    let frames = bus.run_ms_timed(60);
    let emcy: Vec<_> = frames.iter().filter(|d| d.frame.id() == EMCY).collect();
    let [one] = emcy.as_slice() else { return Err(format!("{} EMCY in 60 ms", emcy.len())) };
    expect_eq(
        "EMCY code",
        u16::from_le_bytes([one.frame.data()[0], one.frame.data()[1]]),
        FaultId::HeartbeatLost.info().code,
    )?;
    let after_ms = (one.end_ns - sent) as f64 / 1e6;
    expect_that((50.0..=51.0).contains(&after_ms), || {
        format!("EMCY {after_ms:.3} ms after the last heartbeat, expected 50..51")
    })
}

// --- SYNC (CiA 301 §7.2.5) -------------------------------------------------------------------------------------

fn sync_counter_overflow_rules(bus: &mut Bus) -> Outcome {
    expect_abort("0x1019 = 1", bus.download(0x1019, 0, &[1]), 0x0609_0030)?;
    bus.set(0x1006, 0, &1_000u32.to_le_bytes())?;
    expect_abort("0x1019 while 0x1006 is not 0", bus.download(0x1019, 0, &[4]), 0x0800_0022)?;
    bus.set(0x1006, 0, &0u32.to_le_bytes())?;
    bus.set(0x1019, 0, &[4])?;
    expect_eq("0x1019", bus.get(0x1019, 0)?, 4)
}

fn sync_tpdo_every_nth_sync(bus: &mut Bus) -> Outcome {
    bus.set(0x1800, 1, &(0x8000_0180u32 + u32::from(NODE)).to_le_bytes())?;
    bus.set(0x1800, 2, &[3])?;
    bus.set(0x1800, 1, &(0x4000_0180u32 + u32::from(NODE)).to_le_bytes())?;
    bus.nmt(0x01, NODE);
    let tpdo = 0x180 + u16::from(NODE);
    let mut pattern = Vec::new();
    for _ in 0..9 {
        let frames = [bus.send(SYNC, &[]), bus.run_ms(1)].concat();
        pattern.push(frames.iter().filter(|f| f.id() == tpdo).count());
    }
    // Without a SYNC counter CiA 301 leaves the phase to the device (this one sends at the first SYNC).
    let at: Vec<usize> = pattern.iter().enumerate().filter(|(_, n)| **n > 0).map(|(i, _)| i).collect();
    expect_that(pattern.iter().all(|n| *n <= 1) && at.len() == 3 && at.windows(2).all(|w| w[1] - w[0] == 3), || {
        format!("TPDOs per SYNC with transmission type 3: {pattern:?}")
    })
}

fn sync_start_value_sets_the_phase(bus: &mut Bus) -> Outcome {
    bus.set(0x1019, 0, &[6])?;
    bus.set(0x1800, 1, &(0x8000_0180u32 + u32::from(NODE)).to_le_bytes())?;
    bus.set(0x1800, 2, &[3])?;
    bus.set(0x1800, 6, &[2])?;
    bus.set(0x1800, 1, &(0x4000_0180u32 + u32::from(NODE)).to_le_bytes())?;
    bus.nmt(0x01, NODE);
    let tpdo = 0x180 + u16::from(NODE);
    let mut sent_at = Vec::new();
    for counter in [1u8, 2, 3, 4, 5, 6, 1, 2, 3, 4, 5, 6] {
        let frames = [bus.send(SYNC, &[counter]), bus.run_ms(1)].concat();
        if frames.iter().any(|f| f.id() == tpdo) {
            sent_at.push(counter);
        }
    }
    expect_eq("SYNC counters at which the type-3 TPDO with start value 2 is sent", sent_at, vec![2, 5, 2, 5])
}

fn sync_cob_id_producer_bit_is_refused(bus: &mut Bus) -> Outcome {
    expect_abort("0x1005 with bit 30 (SYNC producer)", bus.download_u32(0x1005, 0, 0x4000_0080), 0x0609_0030)?;
    expect_eq("0x1005", bus.get(0x1005, 0)?, 0x80)
}

// --- EMCY (CiA 301 §7.2.7) --------------------------------------------------------------------------------------

fn raise_rxpdo_timeout(bus: &mut Bus) {
    bus.drive().sim.drive.communication_lost(LinkLoss::RxPdoTimeout);
}

fn emcy_fault_and_reset(bus: &mut Bus) -> Outcome {
    raise_rxpdo_timeout(bus);
    let frames = bus.run_ms(5);
    let emcy = emcy_frames(&frames);
    let [one] = emcy.as_slice() else { return Err(format!("{} EMCY after the fault", emcy.len())) };
    expect_eq("code", u16::from_le_bytes([one[0], one[1]]), FaultId::RxPdoTimeout.info().code)?;
    expect_eq("byte 2 = 0x1001", u64::from(one[2]), bus.get(0x1001, 0)?)?;
    expect_that(one[2] != 0, || "0x1001 shows the fault".into())?;
    bus.drive().sim.drive.communication_restored(LinkLoss::RxPdoTimeout);
    bus.set(0x6040, 0, &0x0000u16.to_le_bytes())?;
    bus.take_log();
    bus.set(0x6040, 0, &0x0080u16.to_le_bytes())?;
    bus.run_ms(5);
    let emcy = emcy_frames(&bus.take_log());
    expect_eq("EMCY after the fault reset", emcy, vec![vec![0, 0, 0, 0, 0, 0, 0, 0]])?;
    expect_eq("0x1001 after the fault reset", bus.get(0x1001, 0)?, 0)
}

fn emcy_inhibit_time_spaces_the_messages(bus: &mut Bus) -> Outcome {
    // 0x1015 in 100 us: 10 ms.
    bus.set(0x1015, 0, &100u16.to_le_bytes())?;
    bus.take_log();
    raise_rxpdo_timeout(bus);
    bus.drive().sim.drive.communication_lost(LinkLoss::HeartbeatLost { node: 127 });
    let frames: Vec<_> = bus.run_ms_timed(30).into_iter().filter(|d| d.frame.id() == EMCY).collect();
    let [first, second] = frames.as_slice() else { return Err(format!("{} EMCY in 30 ms", frames.len())) };
    let gap_ms = (second.end_ns - first.end_ns) as f64 / 1e6;
    expect_that((10.0..=10.5).contains(&gap_ms), || format!("{gap_ms:.3} ms between the two EMCY, expected 10..10.5"))
}

fn emcy_history_counts_and_clears(bus: &mut Bus) -> Outcome {
    raise_rxpdo_timeout(bus);
    bus.run_ms(5);
    expect_eq("0x1003:00 after one fault", bus.get(0x1003, 0)?, 1)?;
    expect_eq("0x1003:01 low word", bus.get(0x1003, 1)? & 0xFFFF, u64::from(FaultId::RxPdoTimeout.info().code))?;
    expect_abort("0x1003:00 = 1", bus.download(0x1003, 0, &[1]), 0x0609_0030)?;
    bus.set(0x1003, 0, &[0])?;
    expect_eq("0x1003:00 after clearing", bus.get(0x1003, 0)?, 0)
}

fn emcy_none_in_stopped(bus: &mut Bus) -> Outcome {
    bus.nmt(0x02, NODE);
    raise_rxpdo_timeout(bus);
    let frames = bus.run_ms(5);
    expect_eq("EMCY in stopped", emcy_frames(&frames).len(), 0)
}

// --- PDO (CiA 301 §7.2.2, §7.5.2.35..38) ----------------------------------------------------------------------

fn pdo_valid_pdo_refuses_mapping_and_cob_id_changes(bus: &mut Bus) -> Outcome {
    expect_abort("mapping sub 0 of a valid RPDO", bus.download(0x1600, 0, &[0]), 0x0601_0000)?;
    let cob = bus.get(0x1400, 1)? as u32;
    expect_abort("COB-ID change of a valid RPDO", bus.download_u32(0x1400, 1, (cob & 0x7FF) + 1), 0x0609_0030)?;
    expect_abort("inhibit time of a valid TPDO", bus.download(0x1800, 3, &[10, 0]), 0x0609_0030)
}

fn pdo_reserved_transmission_types_are_refused(bus: &mut Bus) -> Outcome {
    for t in 241u8..=253 {
        expect_abort(&format!("RPDO transmission type {t}"), bus.download(0x1400, 2, &[t]), 0x0609_0030)?;
    }
    bus.set(0x1400, 2, &[255])?;
    bus.set(0x1400, 2, &[0])
}

fn pdo_remap_procedure_and_its_refusals(bus: &mut Bus) -> Outcome {
    let cob = bus.get(0x1400, 1)? as u32 & 0x7FF;
    bus.set(0x1400, 1, &(0x8000_0000 | cob).to_le_bytes())?;
    bus.set(0x1600, 0, &[0])?;
    bus.set(0x1600, 1, &0x607A_0020u32.to_le_bytes())?;
    bus.set(0x1600, 2, &0x6040_0010u32.to_le_bytes())?;
    bus.set(0x1600, 3, &0x60FF_0020u32.to_le_bytes())?;
    expect_abort("mapping a missing object", bus.download_u32(0x1600, 4, 0x1234_0020), 0x0602_0000)?;
    expect_abort("mapping the statusword into an RPDO", bus.download_u32(0x1600, 4, 0x6041_0010), 0x0604_0041)?;
    expect_abort("three entries of 10 bytes", bus.download(0x1600, 0, &[3]), 0x0604_0042)?;
    bus.set(0x1600, 0, &[2])?;
    bus.set(0x1400, 1, &cob.to_le_bytes())?;
    bus.nmt(0x01, NODE);
    expect_abort("mapping in operational", bus.download(0x1600, 0, &[0]), 0x0800_0022)?;
    let mut data = 4321i32.to_le_bytes().to_vec();
    data.extend_from_slice(&0x0006u16.to_le_bytes());
    bus.send(cob as u16, &data);
    bus.run_ms(2);
    expect_eq("0x607A from the remapped RPDO", bus.get(0x607A, 0)?, 4321)?;
    expect_eq("0x6040 from the remapped RPDO", bus.get(0x6040, 0)?, 6)
}

fn pdo_restricted_and_extended_cob_ids_are_refused(bus: &mut Bus) -> Outcome {
    for id in
        [0x000u32, 0x001, 0x07F, 0x101, 0x180, 0x581, 0x5FF, 0x601, 0x67F, 0x6E0, 0x6FF, 0x701, 0x77F, 0x780, 0x7FF]
    {
        expect_abort(&format!("RPDO 1 COB-ID {id:#05X}"), bus.download_u32(0x1400, 1, id), 0x0609_0030)?;
    }
    expect_abort("a 29-bit COB-ID", bus.download_u32(0x1400, 1, 0x2000_0201), 0x0609_0030)
}

fn pdo_short_rpdo_is_dropped_with_emcy_8210(bus: &mut Bus) -> Outcome {
    let (cob, _) = rpdo1(bus)?;
    bus.nmt(0x01, NODE);
    let frames = [bus.send(cob, &[0x06]), bus.run_ms(5)].concat();
    expect_eq("controlword after a 1-byte RPDO 1", bus.get(0x6040, 0)?, 0)?;
    let emcy = emcy_frames(&frames);
    let [one] = emcy.as_slice() else { return Err(format!("{} EMCY", emcy.len())) };
    expect_eq("EMCY code", u16::from_le_bytes([one[0], one[1]]), 0x8210)
}

fn pdo_event_timer_sends_the_tpdo(bus: &mut Bus) -> Outcome {
    let cob = 0x180 + u32::from(NODE);
    bus.set(0x1800, 1, &(0x8000_0000 | cob).to_le_bytes())?;
    bus.set(0x1800, 2, &[255])?;
    bus.set(0x1800, 5, &20u16.to_le_bytes())?;
    bus.set(0x1800, 1, &(0x4000_0000 | cob).to_le_bytes())?;
    bus.nmt(0x01, NODE);
    bus.run_ms(30);
    let frames: Vec<_> = bus.run_ms_timed(200).into_iter().filter(|d| d.frame.id() == cob as u16).collect();
    expect_eq("TPDOs in 200 ms at a 20 ms event timer", frames.len(), 10)
}

// --- Store and restore (CiA 301 §7.5.2.13/14) -------------------------------------------------------------------

fn sr_signatures(bus: &mut Bus) -> Outcome {
    expect_eq("0x1010:01 bit 0 (saves on command)", bus.get(0x1010, 1)? & 1, 1)?;
    expect_abort("0x1010:01 without the signature", bus.download_u32(0x1010, 1, 0x1234_5678), 0x0800_0020)?;
    expect_abort("0x1011:01 without the signature", bus.download_u32(0x1011, 1, SAVE), 0x0800_0020)?;
    expect_eq("0x1010:01 with \"save\"", bus.download_u32(0x1010, 1, SAVE)?, Ok(()))?;
    expect_eq("0x1011:01 with \"load\"", bus.download_u32(0x1011, 1, LOAD)?, Ok(()))
}

fn sr_saved_values_come_back_after_reset_node_and_restore_brings_the_defaults(bus: &mut Bus) -> Outcome {
    bus.set(0x1017, 0, &100u16.to_le_bytes())?;
    bus.set(0x6081, 0, &4_321u32.to_le_bytes())?;
    bus.set(0x1010, 1, &SAVE.to_le_bytes())?;
    let frames = [bus.nmt(0x81, NODE), bus.run_ms(100)].concat();
    expect_that(frames.iter().any(|f| f.id() == HEARTBEAT && f.data() == [0]), || {
        "no boot-up after reset node".into()
    })?;
    expect_eq("0x1017 after save and reset node", bus.get(0x1017, 0)?, 100)?;
    expect_eq("0x6081 after save and reset node", bus.get(0x6081, 0)?, 4_321)?;
    bus.set(0x1011, 1, &LOAD.to_le_bytes())?;
    expect_eq("0x6081 before the reset that restores", bus.get(0x6081, 0)?, 4_321)?;
    bus.nmt(0x81, NODE);
    bus.run_ms(100);
    let default = Eds::shipped().entry(0x6081, 0).and_then(|e| e.default_for(NODE)).ok_or("0x6081 default")?;
    expect_eq("0x6081 after restore and reset node", bus.get(0x6081, 0)?, default)?;
    expect_eq("0x1017 after restore and reset node", bus.get(0x1017, 0)?, 0)
}

// --- LSS (CiA 305) ---------------------------------------------------------------------------------------------

fn lss_frame(cs: u8, rest: &[u8]) -> [u8; 8] {
    let mut f = [0u8; 8];
    f[0] = cs;
    f[1..=rest.len()].copy_from_slice(rest);
    f
}

/// The identity 0x1018:01..04 the EDS gives (the drive in slot 1 has the EDS serial; slot k the serial + k - 1).
fn eds_identity() -> Result<[u32; 4], String> {
    let mut id = [0u32; 4];
    for (sub, v) in (1..=4u8).zip(id.iter_mut()) {
        *v = Eds::shipped().entry(0x1018, sub).and_then(|e| e.default_for(NODE)).ok_or("0x1018 in the EDS")? as u32;
    }
    Ok(id)
}

fn lss_unconfigured_drive_waits_silent(_: &mut Bus) -> Outcome {
    let mut bus = Bus::unconfigured(1);
    let frames = bus.take_log();
    expect_that(frames.is_empty(), || format!("an unconfigured drive sent {frames:?}"))?;
    expect_eq("SDO to node 1", bus.sdo([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])?, None)?;
    expect_eq("identify non-configured remote slave", bus.lss(lss_frame(0x4C, &[])), vec![lss_frame(0x50, &[])])?;
    expect_eq("the EDS's LSS_Supported (CiA 306 §4.6.2)", Eds::shipped().device_info_number("LSS_Supported"), Some(1))
}

fn lss_selective_switch_configure_and_boot(_: &mut Bus) -> Outcome {
    let mut bus = Bus::unconfigured(1);
    let id = eds_identity()?;
    let mut answers = Vec::new();
    for (cs, part) in (0x40u8..).zip(id) {
        answers = bus.lss(lss_frame(cs, &part.to_le_bytes()));
    }
    expect_eq("answer to the selective switch", answers, vec![lss_frame(0x44, &[])])?;
    expect_eq("inquire node-ID", bus.lss(lss_frame(0x5E, &[])), vec![lss_frame(0x5E, &[0xFF])])?;
    expect_eq("configure node-ID 128", bus.lss(lss_frame(0x11, &[128])), vec![lss_frame(0x11, &[1])])?;
    expect_eq("configure node-ID 5", bus.lss(lss_frame(0x11, &[5])), vec![lss_frame(0x11, &[0])])?;
    let frames = [bus.send(LSS_MASTER, &lss_frame(0x04, &[0])), bus.run_ms(5)].concat();
    expect_that(frames.iter().any(|f| f.id() == 0x705 && f.data() == [0]), || {
        format!("no boot-up of node 5: {frames:?}")
    })?;
    bus.take_log();
    let [i0, i1] = 0x1018u16.to_le_bytes();
    let r = bus.send(0x605, &[0x40, i0, i1, 4, 0, 0, 0, 0]);
    let answer = r.iter().find(|f| f.id() == 0x585).ok_or("no SDO answer of node 5")?;
    expect_eq("0x1018:04 of node 5", u32::from_le_bytes(answer.data()[4..8].try_into().map_err(|_| "4 bytes")?), id[3])
}

fn lss_inquire_identity_and_bit_timing(_: &mut Bus) -> Outcome {
    let mut bus = Bus::unconfigured(1);
    bus.lss(lss_frame(0x04, &[1]));
    let id = eds_identity()?;
    for (cs, part) in (0x5Au8..).zip(id) {
        expect_eq(
            &format!("inquire {cs:#04X}"),
            bus.lss(lss_frame(cs, &[])),
            vec![lss_frame(cs, &part.to_le_bytes())],
        )?;
    }
    expect_eq(
        "bit timing 500 kbit/s (table 0, index 2)",
        bus.lss(lss_frame(0x13, &[0, 2])),
        vec![lss_frame(0x13, &[0])],
    )?;
    expect_eq(
        "bit timing index 5 (100 kbit/s, not supported)",
        bus.lss(lss_frame(0x13, &[0, 5])),
        vec![lss_frame(0x13, &[1])],
    )?;
    expect_eq("bit timing table 1", bus.lss(lss_frame(0x13, &[1, 0])), vec![lss_frame(0x13, &[1])])?;
    let d = bus.drive().sim.drive.dictionary();
    expect_eq("0x2001 after the configuration", firmware::canopen::ids::read(d, 0x2001, 0), Some(2))
}

/// CiA 305 §6.4.3: activate bit timing is unanswered; the node sends nothing for twice the switch delay (its
/// 10 ms heartbeat pauses), switches to the configured rate after the first delay, and transmits again after the
/// second. The simulated bus takes the rate once every drive on it has switched (here the only one).
fn lss_activate_bit_timing_silences_the_node_and_switches_the_rate(bus: &mut Bus) -> Outcome {
    expect_eq("heartbeat 10 ms", bus.download(0x1017, 0, &10u16.to_le_bytes())?, Ok(()))?;
    bus.lss(lss_frame(0x04, &[1]));
    expect_eq("bit timing 500 kbit/s", bus.lss(lss_frame(0x13, &[0, 2])), vec![lss_frame(0x13, &[0])])?;
    bus.run_ms(20);
    let sent_ns = bus.now_ns();
    expect_eq("answers to activate bit timing", bus.lss(lss_frame(0x15, &50u16.to_le_bytes())), vec![])?;
    let frames = bus.run_ms_timed(150);
    let silent_until = sent_ns + 100_000_000;
    let early: Vec<_> = frames.iter().filter(|d| d.start_ns < silent_until).map(|d| d.frame).collect();
    expect_eq("frames within the two 50 ms periods", early, vec![])?;
    let heartbeat = frames.iter().find(|d| d.frame.id() == HEARTBEAT).ok_or("no heartbeat after the switch")?;
    let resumed_ms = (heartbeat.start_ns - sent_ns) as f64 / 1e6;
    // The second period ends 100 ms after the request (plus its ~0.1 ms on the bus); the overdue heartbeat goes
    // at the next millisecond poll.
    expect_that((100.0..=101.5).contains(&resumed_ms), || {
        format!("first heartbeat {resumed_ms:.3} ms after the request")
    })?;
    // A 1-byte standard data frame is at least 52 bits (with stuffing more): at 500 kbit/s >= 104 us on the bus.
    let on_bus_ns = heartbeat.end_ns - heartbeat.start_ns;
    expect_that((104_000..130_000).contains(&on_bus_ns), || format!("heartbeat {on_bus_ns} ns on the bus"))?;
    expect_eq("the bus's bit rate", bus.runner.bus.bit_rate(), 500_000)?;
    let d = bus.drive().sim.drive.dictionary();
    expect_eq("0x200A (bit rate in use)", firmware::canopen::ids::read(d, 0x200A, 0), Some(2))?;
    expect_eq("0x1000 answered at the new rate", bus.upload(0x1000, 0)?.is_ok(), true)
}

/// One fastscan probe; whether a slave answered.
fn probe(bus: &mut Bus, id: u32, bit: u8, part: u8, next: u8) -> bool {
    let mut f = lss_frame(0x51, &id.to_le_bytes());
    (f[5], f[6], f[7]) = (bit, part, next);
    !bus.lss(f).is_empty()
}

/// The master's fastscan (CiA 305 §6.7): the identity of one unconfigured slave, left in configuration.
fn fastscan(bus: &mut Bus) -> Option<[u32; 4]> {
    if !probe(bus, 0, 0x80, 0, 0) {
        return None;
    }
    let mut found = [0u32; 4];
    for part in 0..4u8 {
        for bit in (0..32u8).rev() {
            if !probe(bus, found[usize::from(part)], bit, part, part) {
                found[usize::from(part)] |= 1 << bit;
            }
        }
        if !probe(bus, found[usize::from(part)], 0, part, (part + 1) & 3) {
            return None;
        }
    }
    Some(found)
}

fn lss_fastscan_assigns_three_drives_that_keep_their_ids(_: &mut Bus) -> Outcome {
    let mut bus = Bus::unconfigured(3);
    let base = eds_identity()?;
    let mut serials = Vec::new();
    for new_id in [5u8, 6, 7] {
        let found = fastscan(&mut bus).ok_or_else(|| format!("fastscan found no drive for node-ID {new_id}"))?;
        expect_eq("vendor, product, revision found", found[..3].to_vec(), base[..3].to_vec())?;
        serials.push(found[3]);
        expect_eq("configure node-ID", bus.lss(lss_frame(0x11, &[new_id])), vec![lss_frame(0x11, &[0])])?;
        expect_eq("store configuration", bus.lss(lss_frame(0x17, &[])), vec![lss_frame(0x17, &[0])])?;
        let frames = [bus.send(LSS_MASTER, &lss_frame(0x04, &[0])), bus.run_ms(5)].concat();
        let boot = 0x700 + u16::from(new_id);
        expect_that(frames.iter().any(|f| f.id() == boot && f.data() == [0]), || format!("no boot-up of {new_id}"))?;
    }
    expect_eq("fastscan after all are configured", fastscan(&mut bus), None)?;
    serials.sort_unstable();
    expect_eq("the three serial numbers found", serials, vec![base[3], base[3] + 1, base[3] + 2])?;
    bus.take_log();
    bus.nmt(0x81, 0);
    bus.run_ms(200);
    let mut booted: Vec<u16> = bus
        .take_log()
        .iter()
        .filter(|f| f.data() == [0] && (0x701..=0x77F).contains(&f.id()))
        .map(|f| f.id() - 0x700)
        .collect();
    booted.sort_unstable();
    expect_eq("node-IDs booting after reset node", booted, vec![5, 6, 7])
}

fn lss_configured_node_takes_its_new_id_at_reset_communication(bus: &mut Bus) -> Outcome {
    bus.lss(lss_frame(0x04, &[1]));
    expect_eq("configure node-ID 9", bus.lss(lss_frame(0x11, &[9])), vec![lss_frame(0x11, &[0])])?;
    bus.send(LSS_MASTER, &lss_frame(0x04, &[0]));
    expect_that(bus.sdo([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])?.is_some(), || "node 1 stopped answering".into())?;
    let frames = [bus.nmt(0x82, NODE), bus.run_ms(5)].concat();
    expect_that(frames.iter().any(|f| f.id() == 0x709 && f.data() == [0]), || {
        format!("no boot-up of node 9: {frames:?}")
    })?;
    expect_eq("node 1 after the reset", bus.sdo([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])?, None)
}

/// The suite's cases, in the tool's group order.
#[must_use]
pub fn cases() -> Vec<Case<Bus>> {
    vec![
        case!("OD-01", "CiA 306 §4.6.3, CiA 301 §7.4.7.1", "every readable EDS variable uploads; a fixed-size one with its type's size", od_every_readable_variable_uploads_with_its_size),
        case!("OD-02", "CiA 301 §7.2.4.3.17 Table 22", "every ro/const EDS variable refuses a download: 0x06010002", od_read_only_variables_refuse_a_download),
        case!("OD-03", "CiA 301 §7.2.4.3.17 Table 22", "every wo EDS variable refuses an upload: 0x06010001", od_write_only_variables_refuse_an_upload),
        case!("OD-04", "CiA 301 §7.2.4.3.17 Table 22", "every 0x1000..0x1FFF index absent from the EDS: 0x06020000", od_objects_absent_from_the_eds_do_not_exist),
        case!("OD-05", "CiA 301 §7.2.4.3.17 Table 22", "the sub-index past each ARRAY/RECORD's highest: 0x06090011", od_sub_indices_past_the_highest_do_not_exist),
        case!("OD-06", "CiA 306 §4.6.3 DefaultValue, CiA 301 §7.5.2.1/23", "const variables, 0x1000 and 0x1018 read the EDS value", od_constants_and_identity_read_as_the_eds_states),
        case!("OD-07", "CiA 306 §4.6.3 DefaultValue", "every writable EDS variable with a default reads it after power-up", od_writable_variables_read_their_eds_default_at_power_up),
        case!("OD-08", "CiA 301 §7.2.4.3.17 Table 22", "4 bytes to UNSIGNED16: 0x06070012; 1 byte: 0x06070013; value kept", od_a_value_too_long_or_too_short_is_refused),
        case!("SDO-01", "CiA 301 §7.2.4.3.6", "expedited upload answers 0x4F/0x4B/0x43 for 1/2/4 bytes, index and sub echoed", sdo_expedited_upload_states_its_size),
        case!("SDO-02", "CiA 301 §7.2.4.3.6/7", "0x1008 by segments: size announced, toggles 0,1,0.., last bit, the EDS text", sdo_segmented_upload_toggles_and_ends_with_the_size_announced),
        case!("SDO-03", "CiA 301 §7.2.4.3.7", "upload segment with toggle 1 first: abort 0x05030000", sdo_upload_segment_with_the_wrong_toggle_is_aborted),
        case!("SDO-04", "CiA 301 §7.2.4.3.5", "download segment with toggle 1 first: abort 0x05030000, object kept", sdo_download_segment_with_the_wrong_toggle_is_aborted),
        case!("SDO-05", "CiA 301 §7.2.4.3.17 Table 22", "client command specifier 7: abort 0x05040001", sdo_unknown_command_specifier_is_aborted),
        case!("SDO-06", "CiA 301 §7.2.4.3.17 Table 22", "upload segment with no transfer: abort 0x05040001", sdo_segment_without_a_transfer_is_aborted),
        case!("SDO-07", "CiA 301 §7.2.4.3.3", "expedited download without size (0x22) takes the object's 2 bytes", sdo_expedited_download_without_size_takes_the_object_size),
        case!("SDO-08", "CiA 301 §7.2.4.3.5, Table 22", "7 bytes after 4 announced: abort 0x06070012 (too high), object kept", sdo_segmented_download_longer_than_announced_is_aborted),
        case!("SDO-09", "CiA 301 §7.2.4.3.12", "block upload with blksize 0 or 128: abort 0x05040002", sdo_block_upload_with_an_invalid_block_size_is_aborted),
        case!("SDO-10", "CiA 301 §7.2.4.3.9..11, .16", "block download with CRC: 0xA4/0xA0, ack 0xA2 of the sub-block, end 0xA1, value written", sdo_block_download_with_its_crc_is_taken),
        case!("SDO-11", "CiA 301 §7.2.4.3.16", "block download with a wrong CRC: abort 0x05040004, object kept", sdo_block_download_with_a_wrong_crc_is_aborted),
        case!("SDO-12", "CiA 301 §7.2.4.3.10/11", "out-of-sequence segment: ackseq 0; repeated in order: ackseq 1; end 0xA1", sdo_block_download_acknowledges_the_last_segment_in_sequence),
        case!("SDO-13", "CiA 301 §7.2.4.3.17 Table 22", "client silent in a segmented upload: abort 0x05040000 after 1,000..1,001 ms", sdo_silent_client_gets_the_timeout_abort),
        case!("SDO-14", "CiA 301 §7.2.4.3 (8-byte SDO frames)", "an SDO request of 4 bytes gets no answer", sdo_short_frame_gets_no_answer),
        case!("SDO-15", "CiA 301 §7.2.4.3.17", "a client's abort is not answered and ends the transfer (next segment: 0x05040001)", sdo_client_abort_ends_the_transfer),
        case!("NMT-01", "CiA 301 §7.3.2.2.1, §7.2.8.3.1", "heartbeat 0x7F, start 0x05, stop 0x04, pre-op 0x7F, node-ID 0 = all, other IDs ignored", nmt_the_commands_move_the_state_machine),
        case!("NMT-02", "CiA 301 §7.2.8.3.1", "unknown command 0x03 and NMT frames of 1 or 3 bytes change nothing", nmt_unknown_commands_and_bad_lengths_are_ignored),
        case!("NMT-03", "CiA 301 §7.3.2.2.1 Table 88", "no SDO answer in stopped; answers again in pre-operational", nmt_no_sdo_in_stopped),
        case!("NMT-04", "CiA 301 §7.3.2.2.1", "reset communication: one boot-up 0x701 [00], 0x1017 default, application value kept", nmt_reset_communication_boots_again_with_the_communication_defaults),
        case!("NMT-05", "CiA 301 §7.3.2.2.1", "reset node: boot-up, application and communication values back to power-on", nmt_reset_node_boots_again_with_the_power_on_values),
        case!("NMT-06", "CiA 301 §7.3.2.2.1 Table 88", "an RPDO is taken in operational only", nmt_rpdo_only_in_operational),
        case!("NMT-07", "CiA 301 §7.3.2.2.1 Table 88", "a synchronous TPDO is sent in operational only", nmt_tpdo_only_in_operational),
        case!("HB-01", "CiA 301 §7.2.8.3.2.2, §7.5.2.20", "0x1017 = 10: 10 heartbeats in 105 ms, 10.0 ms apart; 0: none", hb_producer_time_is_kept),
        case!("HB-02", "CiA 301 §7.5.2.19", "second 0x1016 entry for one producer: 0x06040043; reserved bits: 0x06090030", hb_consumer_entries_for_one_producer_are_refused),
        case!("HB-03", "CiA 301 §7.2.8.3.2.2, CiA 402 0x6007", "producer 127 silent at 50 ms: EMCY 0x8130 50..51 ms after its heartbeat", hb_consumer_timeout_raises_the_emcy),
        case!("SYNC-01", "CiA 301 §7.5.2.22", "0x1019 = 1: 0x06090030; while 0x1006 is not 0: 0x08000022; 4 with 0x1006 = 0", sync_counter_overflow_rules),
        case!("SYNC-02", "CiA 301 §7.5.2.37 (transmission type)", "TPDO type 3: sent on every third SYNC", sync_tpdo_every_nth_sync),
        case!("SYNC-04", "CiA 301 §7.5.2.37 (SYNC start value), §7.2.5", "0x1019 = 6, type 3, start value 2: sent at counters 2, 5, 2, 5", sync_start_value_sets_the_phase),
        case!("SYNC-03", "CiA 301 §7.5.2.5", "0x1005 bit 30 (producer) refused: 0x06090030 (the drive consumes SYNC only)", sync_cob_id_producer_bit_is_refused),
        case!("EMCY-01", "CiA 301 §7.2.7.3.1", "a fault: one EMCY with its code and 0x1001; fault reset: EMCY 00 00 00..", emcy_fault_and_reset),
        case!("EMCY-02", "CiA 301 §7.5.2.18", "0x1015 = 100 (10 ms): two faults at once give two EMCY 10.0..10.5 ms apart", emcy_inhibit_time_spaces_the_messages),
        case!("EMCY-03", "CiA 301 §7.5.2.4", "0x1003:00 counts, :01 holds the code; 1 to :00: 0x06090030; 0 clears", emcy_history_counts_and_clears),
        case!("EMCY-04", "CiA 301 §7.3.2.2.1 Table 88", "no EMCY in stopped", emcy_none_in_stopped),
        case!("PDO-01", "CiA 301 §7.5.2.35..37", "valid PDO: mapping 0x06010000, COB-ID 0x06090030, inhibit time 0x06090030", pdo_valid_pdo_refuses_mapping_and_cob_id_changes),
        case!("PDO-02", "CiA 301 §7.5.2.35", "RPDO transmission types 241..253: 0x06090030; 0 and 255 taken", pdo_reserved_transmission_types_are_refused),
        case!("PDO-03", "CiA 301 §7.5.2.36", "remap: missing 0x06020000, not mappable 0x06040041, too long 0x06040042, in operational 0x08000022; the new map applies", pdo_remap_procedure_and_its_refusals),
        case!("PDO-04", "CiA 301 §7.3.5 Table 72, §7.5.2.35", "restricted COB-IDs and 29-bit IDs for a valid RPDO: 0x06090030", pdo_restricted_and_extended_cob_ids_are_refused),
        case!("PDO-05", "CiA 301 §7.2.2.2, Table 21", "an RPDO shorter than its mapping is dropped: EMCY 0x8210", pdo_short_rpdo_is_dropped_with_emcy_8210),
        case!("PDO-06", "CiA 301 §7.5.2.37 (event timer)", "type 255, event timer 20 ms: 10 TPDOs in 200 ms", pdo_event_timer_sends_the_tpdo),
        case!("SR-01", "CiA 301 §7.5.2.13/14", "0x1010:01 bit 0 set; wrong signatures 0x08000020; \"save\" and \"load\" taken", sr_signatures),
        case!("LSS-01", "CiA 305 §5", "an unconfigured drive sends nothing, answers no SDO; identify non-configured: 0x50; the EDS says LSS_Supported=1", lss_unconfigured_drive_waits_silent),
        case!("LSS-02", "CiA 305 §6.2, §6.3", "selective switch: 0x44; node-ID 0xFF; 128 refused (error 1), 5 taken; to waiting: boot-up 0x705", lss_selective_switch_configure_and_boot),
        case!("LSS-03", "CiA 305 §6.3, §6.4", "inquire 0x5A..0x5D = 0x1018; bit timing 500k taken, 100k and table 1 refused (error 1), 0x2001 = 2", lss_inquire_identity_and_bit_timing),
        case!("LSS-04", "CiA 305 §6.7, §6.3", "fastscan finds three drives one by one; node-IDs 5, 6, 7 stored; they boot with them after reset node", lss_fastscan_assigns_three_drives_that_keep_their_ids),
        case!("LSS-06", "CiA 305 §6.4.3", "activate bit timing (delay 50 ms): no answer, no frame for 100 ms, then at 500 kbit/s; 0x200A = 2", lss_activate_bit_timing_silences_the_node_and_switches_the_rate),
        case!("LSS-05", "CiA 305 §6.3 (configured node)", "node-ID 9 configured on node 1: still 1 until reset communication, then boot-up 0x709", lss_configured_node_takes_its_new_id_at_reset_communication),
        case!("SR-02", "CiA 301 §7.5.2.13/14", "saved values after reset node; after \"load\" and reset node the EDS defaults", sr_saved_values_come_back_after_reset_node_and_restore_brings_the_defaults),
    ]
}

/// What the suite does not run, and why.
pub const SKIPS: &[Skip] = &[Skip {
    id: "NG-01",
    clause: "CiA 301 §7.2.8.3.2.1 (node guarding)",
    why: "the drive produces and consumes heartbeat (HB-01..03); CiA 301 lets a device offer either, and no seed \
          defines node guarding's 0x100C/0x100D for the drive",
}];

/// Runs the suite.
#[must_use]
pub fn run() -> SuiteReport {
    run_suite("canopen", &cases(), SKIPS, Bus::powered_up)
}
