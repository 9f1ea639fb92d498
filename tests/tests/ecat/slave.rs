//! The drive as an EtherCAT slave ([`firmware::ecat::slave::EthercatSlave`]) on the emulated ESC, with the plant
//! behind it (`hal_sim::sim::Simulation`) and an in-process master in front: INIT -> OP with the default PDO
//! mapping, CSP for 2,000 cycles of 1 ms SM-synchronous, then the process-data watchdog when the master stops;
//! and an SDO upload of every readable object compared with the dictionary.
//!
//! Timing as on the bus: per 1 ms cycle the master's LRW frame goes through the ESC, the slave's cycle runs on
//! the SM2 event, the slave's tier 3 polls, then the plant and the drive run 25 PWM periods of 40 us while the
//! ESC's clock advances with them (the watchdog and the DC time are the ESC's).

use drive_tests::ecat_master::{first_datagram, StationMaster, STATION};
use firmware::cia402::State;
use firmware::ecat::esm::AlState;
use firmware::ecat::mailbox::{Header, HEADER_LEN};
use firmware::ecat::process_data::ProcessDataLayout;
use firmware::ecat::slave::EthercatSlave;
use firmware::fault::{EmcyMessage, FaultId};
use firmware::od::access::NoApplicationObjects;
use firmware::od::generated;
use hal_sim::esc::datagram::{Command, FrameBuilder};
use hal_sim::esc::Esc;
use hal_sim::scenarios::motion::JerkLimitedMove;
use hal_sim::scenarios::{prepare, Setup};
use hal_sim::sim::Simulation;

const COE: u8 = 3;
/// PWM periods of 40 us per 1 ms bus cycle.
const PERIODS_PER_CYCLE: u64 = 25;
const PERIOD_NS: u64 = 40_000;
const CYCLE_NS: u64 = PERIOD_NS * PERIODS_PER_CYCLE;
/// The logical address the master maps the process image to (outputs, then inputs).
const LOGICAL: u32 = 0x0001_0000;
/// Increments per revolution of the reference encoder.
const INC_PER_REV: f64 = 4096.0;

/// The ESC, the plant and drive, the slave on the PDI side, and a master on the ECAT side.
struct Rig {
    esc: Esc,
    sim: Simulation,
    slave: EthercatSlave,
    app: NoApplicationObjects,
    counter: u8,
    /// CoE emergencies the master found in SM1 (the 8 EMCY bytes).
    emergencies: Vec<[u8; 8]>,
}

impl Rig {
    fn new(sim: Simulation) -> Self {
        let mut rig = Self {
            esc: Esc::with_drive_sii().expect("the drive's SII image"),
            sim,
            slave: EthercatSlave::new(),
            app: NoApplicationObjects,
            counter: 0,
            emergencies: Vec::new(),
        };
        rig.datagram(Command::Apwr, 0, 0x0010, &STATION.to_le_bytes());
        rig.poll();
        rig
    }

    /// The slave's tier 3, with the ESC's simulation time as its millisecond clock.
    fn poll(&mut self) {
        let now_ms = (self.esc.elapsed() / 1_000_000) as u32;
        self.slave.poll(&mut self.esc, &mut self.sim.drive, &mut self.app, now_ms);
    }

    /// The slave's process-data cycle at the ESC's local time.
    fn cycle(&mut self) {
        let now_ns = self.esc.local_time() as u32;
        self.slave.cycle(&mut self.esc, &mut self.sim.drive, now_ns);
    }

    /// One PWM period of plant and drive, and the ESC's clock with it.
    fn step(&mut self) {
        self.sim.step();
        self.esc.advance(PERIOD_NS);
    }

    fn lrw(&mut self, image: &[u8]) -> (Vec<u8>, u16) {
        let mut frame = FrameBuilder::new().push_logical(Command::Lrw, LOGICAL, image).build();
        self.esc.process_frame(&mut frame).expect("a well-formed frame");
        first_datagram(&frame)
    }

    fn configure_fmmu(&mut self, n: u16, logical: u32, len: u16, physical: u16, kind: u8) {
        let mut regs = logical.to_le_bytes().to_vec();
        regs.extend_from_slice(&len.to_le_bytes());
        regs.extend_from_slice(&[0, 7]);
        regs.extend_from_slice(&physical.to_le_bytes());
        regs.extend_from_slice(&[0, kind, 1, 0, 0, 0]);
        assert_eq!(self.fpwr(0x0600 + 16 * n, &regs), 1);
    }

    /// Writes AL control, runs the slave once and returns AL status and code.
    fn request(&mut self, control: u16) -> (u16, u16) {
        self.fpwr(0x0120, &control.to_le_bytes());
        self.poll();
        self.al_status()
    }

    /// Sends a CoE mailbox and returns the CoE answer (CoE header onwards); emergencies that come first are
    /// collected in `emergencies`.
    fn coe(&mut self, data: &[u8]) -> Vec<u8> {
        self.counter = if self.counter >= 7 { 1 } else { self.counter + 1 };
        let header = Header { length: data.len() as u16, kind: COE, counter: self.counter, ..Header::default() };
        let mut window = header.encode().to_vec();
        window.extend_from_slice(data);
        window.resize(usize::from(generated::MAILBOX_OUT_SIZE), 0);
        assert_eq!(self.fpwr(generated::MAILBOX_OUT_START, &window), 1, "SM0 took the request");
        for _ in 0..10 {
            self.poll();
            let Some((h, answer)) = self.receive() else { continue };
            assert_eq!(h.kind, COE, "a CoE answer, got {h:?} {answer:02X?}");
            if answer[1] >> 4 == 1 {
                continue;
            }
            return answer;
        }
        panic!("no answer to the CoE request {data:02X?}");
    }

    /// Reads SM1 if it holds a mailbox; a CoE emergency is also recorded.
    fn receive(&mut self) -> Option<(Header, Vec<u8>)> {
        let (window, wkc) = self.fprd(generated::MAILBOX_IN_START, usize::from(generated::MAILBOX_IN_SIZE));
        if wkc == 0 {
            return None;
        }
        let header = Header::parse(&window).expect("a header");
        let end = (HEADER_LEN + usize::from(header.length)).min(window.len());
        let data = window[HEADER_LEN..end].to_vec();
        if header.kind == COE && data.len() >= 10 && data[1] >> 4 == 1 {
            self.emergencies.push(data[2..10].try_into().expect("8 EMCY bytes"));
        }
        Some((header, data))
    }

    /// One SDO request (service 2) with the SDO bytes padded to 8; the SDO bytes of the answer.
    fn sdo(&mut self, sdo: &[u8]) -> Vec<u8> {
        let mut data = vec![0x00, 0x20];
        data.extend_from_slice(sdo);
        data.resize(data.len().max(10), 0);
        let answer = self.coe(&data);
        answer[2..].to_vec()
    }

    /// SDO upload (expedited, normal, segmented); the value or the abort code.
    fn sdo_upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.sdo(&[0x40, i0, i1, sub, 0, 0, 0, 0]);
        if r[0] == 0x80 {
            return Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]]));
        }
        assert_eq!((r[1], r[2], r[3]), (i0, i1, sub), "the multiplexer is echoed");
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok(r[4..4 + n].to_vec());
        }
        assert_eq!(r[0], 0x41, "a normal upload response for {index:04X}:{sub}");
        let size = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
        let mut value = r[8..].to_vec();
        value.truncate(size);
        let mut toggle = 0u8;
        while value.len() < size {
            let s = self.sdo(&[0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]);
            if s[0] == 0x80 {
                return Err(u32::from_le_bytes([s[4], s[5], s[6], s[7]]));
            }
            assert_eq!(s[0] & 0xF0, toggle, "an upload segment with the toggle");
            let len = if s.len() > 8 { s.len() - 1 } else { 7 - usize::from((s[0] >> 1) & 7) };
            value.extend_from_slice(&s[1..1 + len]);
            toggle ^= 0x10;
            if s[0] & 0x01 != 0 {
                break;
            }
        }
        Ok(value)
    }

    /// Expedited SDO download of up to 4 bytes; the abort code if refused.
    fn sdo_download(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let n = 4 - value.len() as u8;
        let mut req = vec![0x23 | (n << 2), i0, i1, sub];
        req.extend_from_slice(value);
        req.resize(8, 0);
        let r = self.sdo(&req);
        if r[0] == 0x80 {
            Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]]))
        } else {
            assert_eq!(r[0], 0x60, "a download response");
            Ok(())
        }
    }

    /// INIT -> PRE-OP with the SII's mailboxes.
    fn enter_preop(&mut self) {
        self.configure_sm(0, generated::MAILBOX_OUT_START, generated::MAILBOX_OUT_SIZE, 0x26);
        self.configure_sm(1, generated::MAILBOX_IN_START, generated::MAILBOX_IN_SIZE, 0x22);
        assert_eq!(self.request(0x0002), (0x0002, 0x0000), "PRE-OP reached");
    }
}

impl StationMaster for Rig {
    fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
        let mut frame = FrameBuilder::new().push(cmd, adp, ado, data).build();
        self.esc.process_frame(&mut frame).expect("a well-formed frame");
        first_datagram(&frame)
    }
}

/// Where each mapped object lies in an image: (index, byte offset), from the compiled layout.
fn offsets(items: &[firmware::ecat::process_data::PdoItem]) -> Vec<(u16, usize)> {
    items.iter().filter(|i| i.index != 0).map(|i| (i.index, usize::from(i.bit_offset / 8))).collect()
}

fn at(offsets: &[(u16, usize)], index: u16) -> usize {
    offsets.iter().find(|(i, _)| *i == index).unwrap_or_else(|| panic!("{index:04X} mapped")).1
}

/// The reference plant commissioned (encoder indexed) and at rest, the CiA 402 machine not yet enabled by a
/// master: what `hal_sim::scenarios::motion::prepare_motion` does before its controlword sequence.
fn commissioned_drive() -> Simulation {
    let (mut sim, _) = prepare(&Setup { seed: 1, ..Setup::default() }).expect("commissioning");
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, 0.0);
    sim.run(250);
    sim
}

/// CSP over EtherCAT for 2,000 cycles of 1 ms, then the master goes silent.
///
/// Proves: the default PDO mapping brings the slave to OP; every LRW has working counter 3 (SM3 read + SM2
/// written); the controlword sequence 0x06, 0x07, 0x0F in the RxPDO takes the drive to «Operation enabled»,
/// which the master sees in the TxPDO's statusword; the drive follows a 10-revolution jerk-limited move
/// (2,449 rpm peak, the motion issue's CSP case) within the motion bounds of tests/tests/motion/cyclic.rs (peak
/// following error <= 30 inc, RMS <= 8 inc, statusword bit 13 never set) read from the TxPDO; 0x1C32:0B and
/// 0x1C33:0B stay 0. Then, without frames, the ESC's process-data watchdog (0x0420 default: 100 ms) expires,
/// the slave shows SAFE-OP + error 0x001B, the drive reaches the 0x6007 reaction (default 3: «Quick stop
/// active») no earlier than the watchdog time and within it plus one cycle, and the fault's EMCY arrives as a
/// CoE emergency when the master reads SM1.
#[test]
fn csp_over_ethercat_then_the_watchdog_stops_the_drive() {
    let mut rig = Rig::new(commissioned_drive());
    rig.enter_preop();
    // 0x60C2 = 1 ms: the master's cycle, so that CSP interpolates between set-points (as motion_cyclic does).
    assert_eq!(rig.sdo_download(0x60C2, 1, &[1]), Ok(()));
    assert_eq!(rig.sdo_upload(0x60C2, 2), Ok(vec![(-3i8) as u8]));

    let layout = ProcessDataLayout::compile(rig.sim.drive.dictionary()).expect("default mapping compiles");
    let (out_len, in_len) = (layout.output_bytes, layout.input_bytes);
    let outs = offsets(layout.output_items());
    let ins = offsets(layout.input_items());
    rig.configure_sm(2, generated::PROCESS_OUT_START, out_len, 0x64);
    rig.configure_sm(3, generated::PROCESS_IN_START, in_len, 0x20);
    rig.configure_fmmu(0, LOGICAL, out_len, generated::PROCESS_OUT_START, 0x02);
    rig.configure_fmmu(1, LOGICAL + u32::from(out_len), in_len, generated::PROCESS_IN_START, 0x01);
    assert_eq!(rig.request(0x0004), (0x0004, 0x0000), "SAFE-OP reached");

    let total = usize::from(out_len + in_len);
    let out_len = usize::from(out_len);
    let (cw_at, mode_at, target_at) = (at(&outs, 0x6040), at(&outs, 0x6060), at(&outs, 0x607A));
    let (sw_at, pos_at, fe_at) = (at(&ins, 0x6041), at(&ins, 0x6064), at(&ins, 0x60F4));
    let i32_at = |b: &[u8], o: usize| i32::from_le_bytes(b[o..o + 4].try_into().unwrap());

    // The outputs: controlword, mode 8 (CSP) and the target position, in the first LRW already.
    let mut controlword: u16 = 0x0000;
    let mut target = rig.sim.drive.dictionary().get(generated::handles::POSITION_ACTUAL_VALUE);
    let image = |controlword: u16, target: i32| {
        let mut img = vec![0u8; total];
        img[cw_at..cw_at + 2].copy_from_slice(&controlword.to_le_bytes());
        img[mode_at] = 8;
        img[target_at..target_at + 4].copy_from_slice(&target.to_le_bytes());
        img
    };
    let (_, wkc) = rig.lrw(&image(controlword, target));
    assert_eq!(wkc, 3);
    rig.cycle();
    assert_eq!(rig.request(0x0008), (0x0008, 0x0000), "OP reached");
    assert_eq!(rig.slave.state(), AlState::Op);
    // The rest of this 1 ms cycle: the next frame comes one cycle later (no cycle-time-too-small).
    for _ in 0..PERIODS_PER_CYCLE {
        rig.step();
    }

    let mut enabled_at: Option<u64> = None;
    let mut mv: Option<JerkLimitedMove> = None;
    let (mut fe_peak, mut fe_sq, mut fe_n) = (0i32, 0f64, 0u32);
    let mut bit13 = false;
    let mut statusword = 0u16;
    let mut actual = 0i32;
    for k in 0..2000u64 {
        // The master: the controlword from the last statusword it received (CiA 402 §"device control").
        controlword = match statusword & 0x6F {
            0x21 => 0x0007,
            0x23 | 0x27 => 0x000F,
            _ => 0x0006,
        };
        if statusword & 0x6F == 0x27 && enabled_at.is_none() {
            enabled_at = Some(k);
            let per_rpm = INC_PER_REV / 60.0;
            mv =
                Some(JerkLimitedMove::new(f64::from(target), 10.0 * INC_PER_REV, 3000.0 * per_rpm, 20_000.0 * per_rpm));
        }
        match (mv, enabled_at) {
            (Some(m), Some(k0)) => target = m.position((k - k0) as f64 * 1e-3).round() as i32,
            _ => target = if k == 0 { target } else { actual },
        }
        let (inputs, wkc) = rig.lrw(&image(controlword, target));
        assert_eq!(wkc, 3, "cycle {k}: every LRW reads SM3 and writes SM2");
        let inputs = &inputs[out_len..];
        statusword = u16::from_le_bytes([inputs[sw_at], inputs[sw_at + 1]]);
        actual = i32_at(inputs, pos_at);
        if let (Some(m), Some(k0)) = (mv, enabled_at) {
            let t = (k - k0) as f64 * 1e-3;
            if k > k0 + 1 && t <= m.duration_s() {
                let fe = i32_at(inputs, fe_at);
                fe_peak = fe_peak.max(fe.abs());
                fe_sq += f64::from(fe) * f64::from(fe);
                fe_n += 1;
            }
            bit13 |= statusword & (1 << 13) != 0;
        }
        rig.cycle();
        rig.poll();
        for _ in 0..PERIODS_PER_CYCLE {
            rig.step();
        }
    }
    let k0 = enabled_at.expect("«Operation enabled» seen in the TxPDO statusword");
    assert!(k0 < 500, "enabled after {k0} cycles");
    assert_eq!(rig.sim.cia402_state(), State::OperationEnabled);
    assert_eq!(statusword & 0x6F, 0x27, "statusword in the TxPDO: operation enabled");
    assert_ne!(statusword & (1 << 9), 0, "statusword bit 9 remote in OP");
    let m = mv.expect("the move ran");
    let end = (m.start + m.distance).round() as i32;
    assert!((actual - end).abs() <= 1, "at the target after the move: {actual} vs {end}");
    let fe_rms = (fe_sq / f64::from(fe_n)).sqrt();
    println!("enabled after {k0} cycles; following error peak {fe_peak} inc, RMS {fe_rms:.2} inc over {fe_n} cycles");
    assert!(fe_n > 400, "following error sampled over the move ({fe_n} cycles)");
    assert!(fe_peak <= 30, "peak following error {fe_peak} inc");
    assert!(fe_rms <= 8.0, "RMS following error {fe_rms} inc");
    assert!(!bit13, "statusword bit 13 (following error) never set");
    let counters = rig.slave.sync_counters().expect("counters in OP");
    assert_eq!((counters.sm_event_missed(), counters.cycle_time_too_small()), (0, 0));
    assert_eq!(rig.sdo_upload(0x1C32, 0x0B), Ok(vec![0, 0]), "0x1C32:0B SM-event missed");
    assert_eq!(rig.sdo_upload(0x1C33, 0x0B), Ok(vec![0, 0]), "0x1C33:0B SM-event missed");
    assert_eq!(rig.sdo_upload(0x1C32, 0x20), Ok(vec![0]), "no sync error");
    assert_eq!(rig.al_status(), (0x0008, 0x0000), "still OP");

    // The master goes silent: no more process data. The watchdog was last triggered by the last LRW.
    let last_frame_ns = rig.esc.pd_watchdog().last_trigger;
    let watchdog_ns = 100 * 1_000_000;
    let mut reaction_ns = None;
    let mut safeop_ns = None;
    for _ in 0..200 {
        rig.poll();
        if safeop_ns.is_none() && rig.slave.state() == AlState::SafeOp {
            safeop_ns = Some(rig.esc.elapsed());
        }
        for _ in 0..PERIODS_PER_CYCLE {
            rig.step();
            if reaction_ns.is_none() && rig.sim.cia402_state() == State::QuickStopActive {
                reaction_ns = Some(rig.esc.elapsed());
            }
        }
        if reaction_ns.is_some() {
            break;
        }
    }
    let safeop_after = safeop_ns.expect("SAFE-OP after the watchdog") - last_frame_ns;
    let reaction_after = reaction_ns.expect("the 0x6007 reaction (quick stop)") - last_frame_ns;
    println!("after the last frame: SAFE-OP at {safeop_after} ns, quick stop at {reaction_after} ns");
    assert!(safeop_after >= watchdog_ns, "not before the watchdog time: {safeop_after} ns");
    assert!(reaction_after >= watchdog_ns, "reaction not before the watchdog time: {reaction_after} ns");
    assert!(
        reaction_after <= watchdog_ns + CYCLE_NS,
        "reaction within the watchdog time + 1 cycle: {reaction_after} ns"
    );
    assert_eq!(rig.al_status(), (0x0014, 0x001B), "SAFE-OP + error, SM watchdog");
    assert_eq!(rig.esc.pd_watchdog().expirations, 1);

    // The EMCY of the fault arrives as a CoE emergency (service 1) when the master reads SM1.
    let code = FaultId::EthercatWatchdog.info().code;
    for _ in 0..20 {
        if rig.emergencies.iter().any(|e| u16::from_le_bytes([e[0], e[1]]) == code) {
            break;
        }
        rig.poll();
        rig.receive();
    }
    let emcy = rig.emergencies.iter().find(|e| u16::from_le_bytes([e[0], e[1]]) == code);
    let emcy = emcy.unwrap_or_else(|| panic!("EMCY {code:04X} in the mailbox, got {:02X?}", rig.emergencies));
    assert_eq!(emcy[3], FaultId::EthercatWatchdog.number(), "byte 3: the fault's number");
}

/// An SDO upload through CoE of every readable entry of the dictionary (strings and domains included) gives
/// the dictionary's value, or the abort code the dictionary gives (application objects without a store).
#[test]
fn every_readable_object_reads_through_coe_as_in_the_dictionary() {
    let mut rig = Rig::new(Simulation::reference(1));
    rig.enter_preop();
    let table = *rig.sim.drive.dictionary().table();
    let mut checked = 0;
    let mut segmented = 0;
    for entry in table.entries().iter().filter(|e| e.access().readable()) {
        let mut buf = vec![0u8; 4096];
        let expected = rig
            .sim
            .drive
            .dictionary()
            .read(entry.index, entry.sub, 0, &mut buf, &mut NoApplicationObjects)
            .map(|r| {
                assert!(r.total_len <= buf.len(), "{:04X}:{} fits the test buffer", entry.index, entry.sub);
                buf[..r.len].to_vec()
            })
            .map_err(|a| a.code());
        let got = rig.sdo_upload(entry.index, entry.sub);
        assert_eq!(got, expected, "{:04X}:{:02X} {}", entry.index, entry.sub, entry.name);
        if got.as_ref().is_ok_and(|v| v.len() > 4) {
            segmented += 1;
        }
        checked += 1;
    }
    assert!(checked > 300, "{checked} entries read");
    assert!(segmented > 0, "strings/domains went through normal/segmented uploads");
    assert_eq!(rig.al_status(), (0x0002, 0x0000), "still PRE-OP without error");
}

/// More EMCYs than the mailbox can hold while the master does not read SM1 (one in SM1, eight in the CoE
/// queue): the slave keeps the one that did not fit, takes no further one from the drive meanwhile, and when the
/// master reads SM1 every message arrives, once, in the order the drive produced them.
#[test]
fn emergencies_that_do_not_fit_wait_and_none_is_lost() {
    let mut rig = Rig::new(Simulation::reference(1));
    rig.enter_preop();
    let sent: Vec<EmcyMessage> = (0..14u16)
        .map(|k| EmcyMessage { code: 0xFF00 | k, register: 0x80, manufacturer: [k as u8, 0, 0, 0, 0] })
        .collect();
    for m in &sent {
        rig.sim.drive.axis_mut().faults_mut().emcy_mut().push(*m);
    }
    for _ in 0..5 {
        rig.poll();
    }
    assert!(rig.slave.pending_emergency().is_some(), "the mailbox is full: one EMCY waits in the slave");
    assert_eq!(rig.slave.mailbox().coe().emergencies_queued(), 8);
    let left_in_drive = rig.sim.drive.axis().faults().emcy().pending();
    assert_eq!(left_in_drive, 14 - 1 - 8 - 1, "the rest stays in the drive's queue");
    for _ in 0..40 {
        rig.receive();
        rig.poll();
    }
    let got: Vec<EmcyMessage> = rig.emergencies.iter().map(|e| EmcyMessage::parse(e).expect("8 bytes")).collect();
    assert_eq!(got, sent, "all of them, in order");
    assert!(rig.slave.pending_emergency().is_none());
    assert_eq!(rig.sim.drive.axis().faults().emcy().stats().lost, 0);
}

/// DC SYNC0 at 1 ms: one missed frame is counted in 0x1C32:0B and tolerated; two in a row pass the sync error
/// limit (0x10F1:02 = 4, a miss weighs 3): OP falls back to SAFE-OP + 0x001A, 0x1C32:20 is set and the drive
/// has the EtherCAT sync fault. After the master's acknowledge and a new OP the count starts clean.
#[test]
fn missed_frames_in_dc_mode_count_and_then_raise_the_sync_error() {
    let mut rig = Rig::new(Simulation::reference(1));
    rig.enter_preop();
    let layout = ProcessDataLayout::compile(rig.sim.drive.dictionary()).expect("default mapping compiles");
    let (out_len, in_len) = (layout.output_bytes, layout.input_bytes);
    rig.configure_sm(2, generated::PROCESS_OUT_START, out_len, 0x64);
    rig.configure_sm(3, generated::PROCESS_IN_START, in_len, 0x20);
    rig.configure_fmmu(0, LOGICAL, out_len, generated::PROCESS_OUT_START, 0x02);
    rig.configure_fmmu(1, LOGICAL + u32::from(out_len), in_len, generated::PROCESS_IN_START, 0x01);
    // As SOEM's `ecx_dcsync0`: SYNC0 cycle, start time (half a cycle after the frames), activation 0x03.
    assert_eq!(rig.fpwr(0x09A0, &1_000_000u32.to_le_bytes()), 1);
    let start = rig.esc.system_time() + 1_500_000;
    assert_eq!(rig.fpwr(0x0990, &start.to_le_bytes()), 1);
    assert_eq!(rig.fpwr(0x0981, &[0x03]), 1);
    assert_eq!(rig.request(0x0004), (0x0004, 0x0000), "SAFE-OP reached in DC");
    let sync = *rig.slave.esm().synchronisation().expect("resolved");
    assert_eq!(sync.mode, firmware::ecat::sync::SyncMode::DcSync0);
    assert_eq!(rig.sdo_upload(0x1C32, 0x0A), Ok(1_000_000u32.to_le_bytes().to_vec()), "SYNC0 cycle published");

    let image = vec![0u8; usize::from(out_len + in_len)];
    // One 1 ms cycle: the frame (unless skipped), then SYNC0 starts the slave's cycle; tier 3 after it.
    let run = |rig: &mut Rig, send: bool| {
        if send {
            assert_eq!(rig.lrw(&image).1, 3);
        }
        for _ in 0..PERIODS_PER_CYCLE {
            rig.step();
            if rig.esc.take_sync0().is_some() {
                rig.cycle();
            }
        }
        rig.poll();
    };
    run(&mut rig, true);
    assert_eq!(rig.request(0x0008), (0x0008, 0x0000), "OP reached");
    for _ in 0..20 {
        run(&mut rig, true);
    }
    let missed = |rig: &Rig| rig.slave.sync_counters().expect("counters").sm_event_missed();
    assert_eq!(missed(&rig), 0);
    run(&mut rig, false);
    for _ in 0..5 {
        run(&mut rig, true);
    }
    assert_eq!(missed(&rig), 1, "one frame missed");
    assert_eq!(rig.sdo_upload(0x1C32, 0x0B), Ok(vec![1, 0]));
    assert_eq!(rig.al_status(), (0x0008, 0x0000), "one miss is tolerated");
    assert!(!rig.sim.drive.axis().faults().is_active(FaultId::EthercatSyncError));

    run(&mut rig, false);
    run(&mut rig, false);
    assert_eq!(rig.al_status(), (0x0014, 0x001A), "SAFE-OP + error, synchronisation error");
    assert!(rig.sim.drive.axis().faults().is_active(FaultId::EthercatSyncError));
    assert_eq!(rig.sdo_upload(0x1C32, 0x20), Ok(vec![1]), "0x1C32:20 sync error");

    // Acknowledge, fresh outputs, OP again: a clean count.
    assert_eq!(rig.request(0x0014), (0x0004, 0x0000));
    run(&mut rig, true);
    assert_eq!(rig.request(0x0008), (0x0008, 0x0000), "OP again");
    for _ in 0..5 {
        run(&mut rig, true);
    }
    assert!(!rig.slave.sync_counters().expect("counters").sync_error());
    assert_eq!(rig.sdo_upload(0x1C32, 0x20), Ok(vec![0]));
    assert_eq!(rig.al_status(), (0x0008, 0x0000));
}

/// Safe Torque Off at power-up must not block the EtherCAT state machine or SDO (issue 19 item 1; the field trap of
/// a CiA 402 start-up that stalls on a de-energised STO input, ros2_canopen#421).
///
/// Proves, with both STO inputs de-energised from the first PWM period (EPOS4 AN ch. 9): INIT -> PRE-OP -> SAFE-OP
/// -> OP with the default mapping and every LRW's working counter 3; CoE SDO uploads of 0x1000 and 0x6041 answer;
/// the drive announces STO with a CoE emergency 0xFFA0 (fault number of `FaultId::SafeTorqueOff`); a master
/// that sends «Shutdown», «Switch on», «Enable operation» from the TxPDO's statusword gets nowhere: the statusword
/// stays «Switch on disabled» (0x40) with bit 14 set, 0x603F reads 0xFFA0 and the power stage stays off. Once the
/// inputs are energised, the same master takes the drive to «Operation enabled» through the normal sequence, bit
/// 14 clears and 0x603F reads 0.
#[test]
fn sto_low_at_power_up_reaches_op_and_refuses_to_enable() {
    use firmware::hal::sto::StoInputs;
    let mut sim = Simulation::reference(1);
    sim.plant.set_sto_inputs(StoInputs::DEMANDED);
    let mut rig = Rig::new(sim);
    rig.enter_preop();
    assert_eq!(rig.sdo_upload(0x1000, 0), Ok(0x0002_0192u32.to_le_bytes().to_vec()), "0x1000 device type");

    let layout = ProcessDataLayout::compile(rig.sim.drive.dictionary()).expect("default mapping compiles");
    let (out_len, in_len) = (layout.output_bytes, layout.input_bytes);
    let outs = offsets(layout.output_items());
    let ins = offsets(layout.input_items());
    rig.configure_sm(2, generated::PROCESS_OUT_START, out_len, 0x64);
    rig.configure_sm(3, generated::PROCESS_IN_START, in_len, 0x20);
    rig.configure_fmmu(0, LOGICAL, out_len, generated::PROCESS_OUT_START, 0x02);
    rig.configure_fmmu(1, LOGICAL + u32::from(out_len), in_len, generated::PROCESS_IN_START, 0x01);
    assert_eq!(rig.request(0x0004), (0x0004, 0x0000), "SAFE-OP reached with STO active");
    let total = usize::from(out_len + in_len);
    let out_len = usize::from(out_len);
    let (cw_at, mode_at) = (at(&outs, 0x6040), at(&outs, 0x6060));
    let sw_at = at(&ins, 0x6041);
    let image = |controlword: u16| {
        let mut img = vec![0u8; total];
        img[cw_at..cw_at + 2].copy_from_slice(&controlword.to_le_bytes());
        img[mode_at] = 9;
        img
    };
    let (_, wkc) = rig.lrw(&image(0));
    assert_eq!(wkc, 3);
    rig.cycle();
    assert_eq!(rig.request(0x0008), (0x0008, 0x0000), "OP reached with STO active");

    // A master following the statusword: «Shutdown», then «Switch on», then «Enable operation»; `cycles` 1 ms
    // cycles or until the TxPDO shows «Operation enabled». Returns the last statusword.
    let master = |rig: &mut Rig, cycles: u32, sto_active: bool| {
        let mut statusword = 0u16;
        for k in 0..cycles {
            let controlword = match statusword & 0x6F {
                0x21 => 0x0007,
                0x23 | 0x27 => 0x000F,
                _ => 0x0006,
            };
            let (inputs, wkc) = rig.lrw(&image(controlword));
            assert_eq!(wkc, 3, "cycle {k}");
            statusword = u16::from_le_bytes([inputs[out_len + sw_at], inputs[out_len + sw_at + 1]]);
            if statusword & 0x6F == 0x27 {
                break;
            }
            rig.cycle();
            rig.poll();
            for _ in 0..PERIODS_PER_CYCLE {
                rig.step();
                assert!(!(sto_active && rig.sim.command().enabled), "the power stage stays off with STO");
            }
        }
        statusword
    };
    let statusword = master(&mut rig, 200, true);
    assert_eq!(statusword & 0x6F, 0x40, "«Switch on disabled» after 200 cycles of «Shutdown»: {statusword:#06x}");
    assert_ne!(statusword & (1 << 14), 0, "statusword bit 14: STO active");
    assert_eq!(rig.sdo_upload(0x603F, 0), Ok(0xFFA0u16.to_le_bytes().to_vec()), "0x603F shows STO");
    assert_eq!(rig.sdo_upload(0x1001, 0), Ok(vec![0]), "STO is not an error (0x1001)");
    assert_eq!(rig.al_status(), (0x0008, 0x0000), "still OP");
    let code = FaultId::SafeTorqueOff.info().code;
    let emcy = rig.emergencies.iter().find(|e| u16::from_le_bytes([e[0], e[1]]) == code);
    let emcy = emcy.unwrap_or_else(|| panic!("EMCY {code:04X} in the mailbox, got {:02X?}", rig.emergencies));
    assert_eq!(emcy[3], FaultId::SafeTorqueOff.number(), "byte 3: the fault's number");

    // STO released: the same master enables the drive through the normal sequence.
    rig.sim.plant.set_sto_inputs(StoInputs::RELEASED);
    let statusword = master(&mut rig, 500, false);
    let enabled = statusword & 0x6F == 0x27;
    assert!(enabled, "«Operation enabled» after STO was released: {statusword:#06x}");
    assert_eq!(statusword & (1 << 14), 0, "bit 14 clear");
    assert_eq!(rig.sdo_upload(0x603F, 0), Ok(vec![0, 0]), "0x603F clear");
}
