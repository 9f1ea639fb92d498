//! The drive as a CANopen node (`firmware::canopen::CanopenNode`) in-process, frames in and out, with the
//! simulated drive and the reference plant behind it: boot-up, NMT states and what each allows (CiA 301 Table
//! 88), SDO expedited/segmented/block through the node, the CiA 301 remap procedure and its abort codes, a CSP
//! run driven by SYNC at 1 ms with RPDO set-points and TPDO actual values, heartbeat and EMCY frames, the
//! heartbeat loss with the 0x6007 reaction, and frames nobody expects; and the node over a device that is not the
//! drive (a recording double of `comm::device::FieldbusDevice`).
//!
//! Timing as on the bus: the master's frames of a 1 ms cycle are handed to the node at the start of the cycle
//! (SYNC first, then the RPDO), then the plant and the drive run 25 PWM periods of 40 us and the node's tier 3
//! (`process`) runs once; the node's clock is the simulation's.

use firmware::canopen::frame::CanFrame;
use firmware::canopen::nmt::{NmtState, ResetKind};
use firmware::canopen::{CanopenNode, NodeEvent};
use firmware::cia402::State;
use firmware::comm::sdo::crc::Crc16;
use firmware::comm::sdo::wire::{BlockSegment, SdoFrame, SdoRequest, SdoResponse};
use firmware::fault::FaultId;
use firmware::od::access::NoApplicationObjects;
use firmware::od::generated::handles;
use hal_sim::scenarios::motion::JerkLimitedMove;
use hal_sim::scenarios::{prepare, Setup};
use hal_sim::sim::Simulation;

const NODE: u8 = 5;
const PERIODS_PER_CYCLE: u64 = 25;
const PERIOD_US: u64 = 40;
const INC_PER_REV: f64 = 4096.0;

struct Rig {
    sim: Simulation,
    node: CanopenNode,
    app: NoApplicationObjects,
    now_us: u64,
    /// Every frame the node sent, with the time.
    sent: Vec<(u64, CanFrame)>,
}

impl Rig {
    /// The node booted (power-on reset, then boot-up) on `sim`.
    fn new(sim: Simulation) -> Self {
        let mut rig =
            Self { sim, node: CanopenNode::new(NODE), app: NoApplicationObjects, now_us: 0, sent: Vec::new() };
        assert!(matches!(rig.process(), Some(NodeEvent::Reset { kind: ResetKind::Node, node_id: NODE, .. })));
        assert_eq!(rig.process(), Some(NodeEvent::Booted));
        rig
    }

    fn frame(&mut self, id: u16, data: &[u8]) {
        let f = CanFrame::new(id, data).expect("a valid frame");
        self.deliver(&f);
    }

    fn deliver(&mut self, f: &CanFrame) {
        self.node.handle_frame(f, &mut self.sim.drive, &mut self.app, self.now_us);
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(f) = self.node.transmit() {
            self.sent.push((self.now_us, f));
        }
    }

    fn process(&mut self) -> Option<NodeEvent> {
        let e = self.node.process(&mut self.sim.drive, &mut self.app, self.now_us);
        self.drain();
        e
    }

    /// One 1 ms cycle of plant, drive and node.
    fn cycle(&mut self) {
        for _ in 0..PERIODS_PER_CYCLE {
            self.sim.step();
            self.now_us += PERIOD_US;
        }
        self.process();
    }

    fn take(&mut self) -> Vec<CanFrame> {
        self.sent.drain(..).map(|(_, f)| f).collect()
    }

    fn nmt(&mut self, cs: u8, target: u8) {
        self.frame(0x000, &[cs, target]);
        self.process();
    }

    /// One SDO request; the node's answer on 0x580 + node-ID, if any.
    fn sdo(&mut self, request: [u8; 8]) -> Option<[u8; 8]> {
        self.sent.clear();
        self.frame(0x600 + u16::from(NODE), &request);
        self.process();
        let answers: Vec<_> = self.take().into_iter().filter(|f| f.id() == 0x580 + u16::from(NODE)).collect();
        assert!(answers.len() <= 1, "one answer per request: {answers:?}");
        answers.first().map(|f| f.data().try_into().expect("8 bytes"))
    }

    fn upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let r = self.sdo(SdoRequest::InitiateUpload { index, sub }.to_frame()).expect("an answer");
        match SdoResponse::parse(&SdoFrame::new_checked(&r[..]).unwrap()) {
            SdoResponse::UploadExpedited { data, len, .. } => Ok(data[..usize::from(len)].to_vec()),
            SdoResponse::UploadSegmented { size, .. } => {
                let mut value = Vec::new();
                let mut toggle = false;
                loop {
                    let s = self.sdo(SdoRequest::UploadSegment { toggle }.to_frame()).expect("a segment");
                    match SdoResponse::parse(&SdoFrame::new_checked(&s[..]).unwrap()) {
                        SdoResponse::UploadSegment { data, len, last, .. } => {
                            value.extend_from_slice(&data[..usize::from(len)]);
                            if last {
                                assert_eq!(value.len(), size as usize);
                                return Ok(value);
                            }
                        }
                        SdoResponse::Abort { code, .. } => return Err(code),
                        other => panic!("unexpected {other:?}"),
                    }
                    toggle = !toggle;
                }
            }
            SdoResponse::Abort { code, .. } => Err(code),
            other => panic!("unexpected {other:?}"),
        }
    }

    /// Expedited download of 1..=4 bytes.
    fn download(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let n = 4 - value.len() as u8;
        let mut req = [0x23 | (n << 2), i0, i1, sub, 0, 0, 0, 0];
        req[4..4 + value.len()].copy_from_slice(value);
        let r = self.sdo(req).expect("an answer");
        match r[0] {
            0x60 => Ok(()),
            0x80 => Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]])),
            other => panic!("unexpected command {other:02X}"),
        }
    }

    fn download_u32(&mut self, index: u16, sub: u8, value: u32) -> Result<(), u32> {
        self.download(index, sub, &value.to_le_bytes())
    }
}

/// The reference plant commissioned and at rest (as tests/tests/ecat/slave.rs does).
fn commissioned_drive() -> Simulation {
    let (mut sim, _) = prepare(&Setup { seed: 1, ..Setup::default() }).expect("commissioning");
    let theta = sim.plant.state().theta_m_rad;
    sim.plant.set_rotor_state(theta, 0.0);
    sim.run(250);
    sim
}

fn idle_drive() -> Simulation {
    Simulation::reference(1)
}

/// Proves: the power-on reset and boot send exactly the boot-up frame 0x700 + node-ID [0x00] and leave the node
/// pre-operational with the node-ID's COB-IDs; NMT start/stop/pre-op move it, addressed to the node or to all,
/// not when addressed to another node; in each state the services CiA 301 Table 88 allows answer and the others
/// are silent (SDO not in stopped, RPDO only in operational, heartbeat in all three with the state code, EMCY
/// not in stopped); reset communication sends a new boot-up and restores 0x1017.
#[test]
fn boot_up_and_nmt_states_allow_what_cia_301_says() {
    let mut rig = Rig::new(idle_drive());
    let boot = rig.take();
    assert_eq!(boot.len(), 1);
    assert_eq!((boot[0].id(), boot[0].data()), (0x705, &[0u8][..]), "boot-up message");
    assert_eq!(rig.node.state(), NmtState::PreOperational);
    assert_eq!(rig.upload(0x1200, 1), Ok(0x605u32.to_le_bytes().to_vec()));
    assert_eq!(rig.upload(0x1014, 0), Ok(0x85u32.to_le_bytes().to_vec()));
    assert_eq!(rig.upload(0x1800, 1), Ok(0x4000_0185u32.to_le_bytes().to_vec()));
    assert_eq!(rig.upload(0x2000, 0), Ok(vec![NODE]));

    // Heartbeat every 10 ms, with the state code.
    assert_eq!(rig.download(0x1017, 0, &10u16.to_le_bytes()), Ok(()));
    let heartbeats = |rig: &mut Rig| -> Vec<u8> {
        rig.take().into_iter().filter(|f| f.id() == 0x705).map(|f| f.data()[0]).collect()
    };
    for _ in 0..30 {
        rig.cycle();
    }
    let hb = heartbeats(&mut rig);
    assert_eq!(hb, vec![0x7F; 3], "pre-operational heartbeats every 10 ms over 30 ms");

    // Pre-operational: an RPDO is ignored.
    let cw_before = rig.sim.drive.dictionary().get(handles::CONTROLWORD);
    rig.frame(0x205, &[0x06, 0x00, 0x01]);
    assert_eq!(rig.sim.drive.dictionary().get(handles::CONTROLWORD), cw_before, "no RPDO in pre-operational");

    // Another node's command changes nothing; a broadcast start does.
    rig.nmt(0x01, 6);
    assert_eq!(rig.node.state(), NmtState::PreOperational);
    rig.nmt(0x01, 0);
    assert_eq!(rig.node.state(), NmtState::Operational);
    rig.cycle();
    assert_ne!(rig.sim.statusword() & (1 << 9), 0, "statusword bit 9 remote in operational");
    rig.frame(0x205, &[0x06, 0x00, 0x01]);
    assert_eq!(rig.sim.drive.dictionary().get(handles::CONTROLWORD), 0x0006, "RPDO 1 applied in operational");
    for _ in 0..10 {
        rig.cycle();
    }
    assert!(heartbeats(&mut rig).iter().all(|s| *s == 0x05));

    // Stopped: no SDO answer, heartbeat 0x04, no EMCY even when a fault is raised.
    rig.nmt(0x02, NODE);
    assert_eq!(rig.node.state(), NmtState::Stopped);
    assert_eq!(rig.sdo(SdoRequest::InitiateUpload { index: 0x1000, sub: 0 }.to_frame()), None, "no SDO in stopped");
    rig.sim.drive.communication_lost(firmware::supervision::communication::LinkLoss::RxPdoTimeout);
    for _ in 0..20 {
        rig.cycle();
    }
    let frames = rig.take();
    assert!(frames.iter().all(|f| f.id() != 0x085), "no EMCY in stopped: {frames:?}");
    assert!(frames.iter().filter(|f| f.id() == 0x705).all(|f| f.data() == [0x04]));
    assert!(frames.iter().any(|f| f.id() == 0x705), "heartbeat in stopped");

    // Back to pre-operational: the EMCY held back leaves now, on 0x80 + node-ID.
    rig.nmt(0x80, NODE);
    assert_eq!(rig.node.state(), NmtState::PreOperational);
    let emcy: Vec<_> = rig.take().into_iter().filter(|f| f.id() == 0x085).collect();
    assert_eq!(emcy.len(), 1, "the EMCY kept while stopped");
    assert_eq!(u16::from_le_bytes([emcy[0].data()[0], emcy[0].data()[1]]), FaultId::RxPdoTimeout.info().code);
    assert_eq!(emcy[0].data()[3], FaultId::RxPdoTimeout.number());
    assert_eq!(rig.sdo(SdoRequest::InitiateUpload { index: 0x1000, sub: 0 }.to_frame()).map(|r| r[0]), Some(0x43));

    // Reset communication: initialisation (frames ignored), then a new boot-up and 0x1017 back to 0.
    rig.nmt(0x82, NODE);
    assert_eq!(rig.node.state(), NmtState::Initialisation);
    let ignored = rig.node.counters().ignored;
    rig.frame(0x605, &SdoRequest::InitiateUpload { index: 0x1000, sub: 0 }.to_frame());
    assert_eq!(rig.node.counters().ignored, ignored + 1, "a frame during the reset is ignored");
    let _ = rig.take();
    assert_eq!(rig.process(), Some(NodeEvent::Booted));
    let frames = rig.take();
    assert_eq!(frames.iter().map(|f| (f.id(), f.data().to_vec())).collect::<Vec<_>>(), vec![(0x705, vec![0])]);
    assert_eq!(rig.upload(0x1017, 0), Ok(vec![0, 0]), "0x1017 back to its default");
}

/// Proves: a node-ID written to 0x2000 takes effect at the next reset communication, with every COB-ID derived
/// from it (SDO, EMCY, PDOs, heartbeat), and the old SDO COB-ID is no longer served.
#[test]
fn a_new_node_id_takes_effect_at_reset_communication() {
    let mut rig = Rig::new(idle_drive());
    assert_eq!(rig.download(0x2000, 0, &[9]), Ok(()));
    assert_eq!(rig.upload(0x1014, 0), Ok(0x85u32.to_le_bytes().to_vec()), "not before the reset");
    rig.nmt(0x82, NODE);
    assert_eq!(rig.process(), Some(NodeEvent::Booted));
    assert_eq!(rig.node.node_id(), 9);
    let boot = rig.take();
    assert_eq!((boot[0].id(), boot[0].data()), (0x709, &[0u8][..]));
    rig.sent.clear();
    rig.frame(0x609, &SdoRequest::InitiateUpload { index: 0x1400, sub: 1 }.to_frame());
    rig.process();
    let r = rig.take();
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].id(), 0x589);
    assert_eq!(&r[0].data()[4..8], &0x209u32.to_le_bytes());
    // The old COB-ID is nobody's now.
    rig.frame(0x605, &SdoRequest::InitiateUpload { index: 0x1000, sub: 0 }.to_frame());
    rig.process();
    assert!(rig.take().is_empty());
}

/// Proves: SDO through the node in both directions and all three protocols: expedited, segmented upload of
/// 0x1009 (23 bytes, 4 segments with toggles), block upload of 0x1009 with CRC, block download of 0x607A with CRC
/// (the block sub-block is not mistaken for new requests), and the dictionary's abort codes on the wire.
#[test]
fn sdo_expedited_segmented_and_block_through_the_node() {
    let mut rig = Rig::new(idle_drive());
    assert_eq!(rig.upload(0x1000, 0), Ok(0x0002_0192u32.to_le_bytes().to_vec()));
    assert_eq!(rig.upload(0x1009, 0), Ok(b"STM32F405 reference 1.0".to_vec()));
    assert_eq!(rig.upload(0x1234, 0), Err(0x0602_0000));
    assert_eq!(rig.download(0x1000, 0, &[1, 2, 3, 4]), Err(0x0601_0002));

    // Block upload of 0x1009, block size 3: sub-blocks of 3 segments, the CRC over the 23 bytes.
    let r =
        rig.sdo(SdoRequest::BlockUploadInitiate { index: 0x1009, sub: 0, crc: true, blksize: 3, pst: 0 }.to_frame());
    let r = SdoResponse::parse(&SdoFrame::new_checked(&r.unwrap()[..]).unwrap());
    assert!(matches!(r, SdoResponse::BlockUploadInitiate { size: Some(23), .. }), "{r:?}");
    let mut value = Vec::new();
    let mut request = SdoRequest::BlockUploadStart.to_frame();
    loop {
        rig.sent.clear();
        rig.frame(0x605, &request);
        rig.process();
        let frames = rig.take();
        let last = frames.last().expect("frames").data().to_vec();
        if let SdoResponse::BlockUploadEnd { unused, crc } =
            SdoResponse::parse(&SdoFrame::new_checked(&last[..]).unwrap())
        {
            value.truncate(value.len() - usize::from(unused));
            assert_eq!(
                crc,
                {
                    let mut c = Crc16::new();
                    c.update(&value);
                    c.value()
                },
                "CRC over the value"
            );
            rig.frame(0x605, &SdoRequest::BlockUploadEnd.to_frame());
            break;
        }
        let mut seq = 0;
        for f in &frames {
            let s = BlockSegment::parse(&SdoFrame::new_checked(f.data()).unwrap());
            value.extend_from_slice(&s.data);
            seq = s.seqno;
        }
        request = SdoRequest::BlockUploadAck { ackseq: seq, blksize: 3 }.to_frame();
    }
    assert_eq!(value, b"STM32F405 reference 1.0");

    // Block download of 4 bytes to 0x607A: one segment whose command byte (0x81 = seq 1, last) is no initiate.
    let v = (-123_456i32).to_le_bytes();
    let r = rig.sdo(SdoRequest::BlockDownloadInitiate { index: 0x607A, sub: 0, crc: true, size: Some(4) }.to_frame());
    assert_eq!(r.map(|r| r[0]), Some(0xA4), "block download initiate response with CRC");
    let mut data = [0u8; 7];
    data[..4].copy_from_slice(&v);
    let ack = rig.sdo(BlockSegment { seqno: 1, last: true, data }.to_frame());
    assert_eq!(ack.map(|a| (a[0], a[1])), Some((0xA2, 1)));
    let mut crc = Crc16::new();
    crc.update(&v);
    let end = rig.sdo(SdoRequest::BlockDownloadEnd { unused: 3, crc: crc.value() }.to_frame());
    assert_eq!(end.map(|e| e[0]), Some(0xA1));
    assert_eq!(rig.sim.drive.dictionary().get(handles::TARGET_POSITION), -123_456);

    // A short SDO frame is ignored (CiA 301: SDO frames have 8 bytes).
    rig.sent.clear();
    rig.frame(0x605, &[0x40, 0x00, 0x10, 0x00]);
    rig.process();
    assert!(rig.take().is_empty());
}

/// Proves the CiA 301 §7.5.2.36 remap procedure and its abort codes through the node: mapping changes while the
/// PDO is valid (0x0601_0000), a COB-ID change of a valid PDO and a reserved transmission type (0x0609_0030), a
/// mapping above 8 bytes (0x0604_0042), a missing object (0x0602_0000), an object that cannot be mapped
/// (0x0604_0041), mapping in operational (0x0800_0022), a restricted COB-ID (0x0609_0030), the TPDO inhibit time
/// of a valid PDO (0x0609_0030), a segmented download to a checked object (0x0601_0000); then the new mapping
/// is used: RPDO 1 = target position + controlword applies in operational.
#[test]
fn pdo_remap_follows_the_cia_301_procedure() {
    let mut rig = Rig::new(idle_drive());
    assert_eq!(rig.download(0x1600, 0, &[0]), Err(0x0601_0000), "mapping of a valid PDO");
    assert_eq!(rig.download_u32(0x1400, 1, 0x206), Err(0x0609_0030), "COB-ID change of a valid PDO");
    assert_eq!(rig.download(0x1400, 2, &[245]), Err(0x0609_0030), "reserved transmission type");
    assert_eq!(rig.download(0x1800, 3, &[0, 0]), Err(0x0609_0030), "inhibit time of a valid TPDO");
    assert_eq!(rig.download_u32(0x1400, 1, 0x8000_0205), Ok(()), "step 1: PDO not valid");
    assert_eq!(rig.download(0x1600, 0, &[0]), Ok(()), "step 2: mapping disabled");
    assert_eq!(rig.download_u32(0x1600, 1, 0x607A_0020), Ok(()));
    assert_eq!(rig.download_u32(0x1600, 2, 0x6040_0010), Ok(()));
    assert_eq!(rig.download_u32(0x1600, 3, 0x60FF_0020), Ok(()));
    assert_eq!(rig.download_u32(0x1600, 4, 0x1234_0020), Err(0x0602_0000), "missing object");
    assert_eq!(rig.download_u32(0x1600, 4, 0x6041_0010), Err(0x0604_0041), "statusword is not rx-mappable");
    assert_eq!(rig.download(0x1600, 0, &[3]), Err(0x0604_0042), "10 bytes do not fit a CAN frame");
    assert_eq!(rig.download(0x1600, 0, &[2]), Ok(()), "step 4: two entries, 6 bytes");
    assert_eq!(rig.download_u32(0x1400, 1, 0x0000_0005), Err(0x0609_0030), "restricted COB-ID");
    // A segmented download of 4 bytes to a checked object.
    let r = rig.sdo([0x21, 0x00, 0x14, 0x01, 4, 0, 0, 0]).unwrap();
    assert_eq!(u32::from_le_bytes([r[4], r[5], r[6], r[7]]), 0x0601_0000);
    assert_eq!(rig.download_u32(0x1400, 1, 0x0000_0205), Ok(()), "step 5: PDO valid");
    assert_eq!(rig.download(0x1400, 2, &[255]), Ok(()), "transmission type may change while valid");
    rig.nmt(0x01, NODE);
    assert_eq!(rig.download(0x1600, 0, &[0]), Err(0x0800_0022), "mapping only in pre-operational");
    let mut pdo = 4321i32.to_le_bytes().to_vec();
    pdo.extend_from_slice(&0x0006u16.to_le_bytes());
    rig.frame(0x205, &pdo);
    assert_eq!(rig.sim.drive.dictionary().get(handles::TARGET_POSITION), 4321);
    assert_eq!(rig.sim.drive.dictionary().get(handles::CONTROLWORD), 0x0006);
    // Too short: not processed, EMCY 0x8210.
    rig.frame(0x205, &[1, 2, 3]);
    assert_eq!(rig.sim.drive.dictionary().get(handles::TARGET_POSITION), 4321);
    rig.process();
    let emcy: Vec<_> = rig.take().into_iter().filter(|f| f.id() == 0x085).collect();
    assert_eq!(emcy.len(), 1);
    assert_eq!(&emcy[0].data()[..2], &0x8210u16.to_le_bytes(), "PDO length error");
    assert_eq!(&emcy[0].data()[4..8], &3i32.to_le_bytes(), "the length received");
}

/// Indices in the CSP images.
const RPDO_CW_TARGET: u16 = 0x205;

/// CSP over CAN: 3,000 SYNC cycles of 1 ms with RPDO 1 = controlword + target position (synchronous, type 1)
/// and TPDO 1 = statusword + position actual value, TPDO 2 = following error (both type 1), then the master's
/// heartbeat stops.
///
/// Proves: the controlword sequence 0x06, 0x07, 0x0F in the RPDO enables the drive, seen in the TPDO statusword;
/// the drive follows the 10-revolution jerk-limited move of tests/tests/motion/cyclic.rs (2,449 rpm peak) within
/// the motion bounds (peak following error <= 30 inc, RMS <= 8 inc, statusword bit 13 never set) read from the
/// TPDOs, which come once per SYNC; no SYNC is missed. Then, with 0x1016:01 supervising node 127 at 50 ms, the
/// master's silence makes the drive carry out the 0x6007 reaction (default 3: «Quick stop active») no earlier than
/// 50 ms after its last heartbeat and within 50 ms + 1 cycle + one tier-3 poll, and the EMCY 0x8130 with the
/// producer's node-ID in bytes 4..7 leaves on 0x85.
#[test]
fn csp_driven_by_sync_then_the_heartbeat_loss_stops_the_drive() {
    let mut rig = Rig::new(commissioned_drive());
    // RPDO 1 = controlword + target position, synchronous; TPDO 1 = statusword + position actual; TPDO 2 =
    // following error; TPDOs synchronous every SYNC.
    assert_eq!(rig.download_u32(0x1400, 1, 0x8000_0205), Ok(()));
    assert_eq!(rig.download(0x1600, 0, &[0]), Ok(()));
    assert_eq!(rig.download_u32(0x1600, 1, 0x6040_0010), Ok(()));
    assert_eq!(rig.download_u32(0x1600, 2, 0x607A_0020), Ok(()));
    assert_eq!(rig.download(0x1600, 0, &[2]), Ok(()));
    assert_eq!(rig.download(0x1400, 2, &[1]), Ok(()));
    assert_eq!(rig.download_u32(0x1400, 1, 0x205), Ok(()));
    assert_eq!(rig.download_u32(0x1800, 1, 0xC000_0185), Ok(()));
    assert_eq!(rig.download(0x1A00, 0, &[0]), Ok(()));
    assert_eq!(rig.download_u32(0x1A00, 1, 0x6041_0010), Ok(()));
    assert_eq!(rig.download_u32(0x1A00, 2, 0x6064_0020), Ok(()));
    assert_eq!(rig.download(0x1A00, 0, &[2]), Ok(()));
    assert_eq!(rig.download(0x1800, 2, &[1]), Ok(()));
    assert_eq!(rig.download_u32(0x1800, 1, 0x4000_0185), Ok(()));
    assert_eq!(rig.download_u32(0x1801, 1, 0xC000_0285), Ok(()));
    assert_eq!(rig.download(0x1A01, 0, &[0]), Ok(()));
    assert_eq!(rig.download_u32(0x1A01, 1, 0x60F4_0020), Ok(()));
    assert_eq!(rig.download(0x1A01, 0, &[1]), Ok(()));
    assert_eq!(rig.download(0x1801, 2, &[1]), Ok(()));
    assert_eq!(rig.download_u32(0x1801, 1, 0x4000_0285), Ok(()));
    assert_eq!(rig.download(0x6060, 0, &[8]), Ok(()), "CSP");
    assert_eq!(rig.download(0x60C2, 1, &[1]), Ok(()), "interpolation period 1 ms");
    assert_eq!(rig.download_u32(0x1006, 0, 1000), Ok(()), "SYNC period supervised");
    assert_eq!(rig.download_u32(0x1016, 1, (127 << 16) | 50), Ok(()), "consumer: node 127, 50 ms");
    assert_eq!(rig.download_u32(0x1016, 2, (127 << 16) | 80), Err(0x0604_0043), "node 127 twice");
    rig.nmt(0x01, NODE);
    let _ = rig.take();

    let mut target = rig.sim.drive.dictionary().get(handles::POSITION_ACTUAL_VALUE);
    let mut statusword = 0u16;
    let mut actual = target;
    let mut enabled_at: Option<u64> = None;
    let mut mv: Option<JerkLimitedMove> = None;
    let (mut fe_peak, mut fe_sq, mut fe_n, mut bit13) = (0i32, 0f64, 0u32, false);
    let mut last_heartbeat_us = 0;
    for k in 0..3000u64 {
        if k % 20 == 0 {
            rig.frame(0x77F, &[0x05]);
            last_heartbeat_us = rig.now_us;
        }
        // SYNC: the TPDOs sampled now come back at once.
        rig.frame(0x080, &[]);
        let frames = rig.take();
        let tpdo1: Vec<_> = frames.iter().filter(|f| f.id() == 0x185).collect();
        let tpdo2: Vec<_> = frames.iter().filter(|f| f.id() == 0x285).collect();
        assert_eq!((tpdo1.len(), tpdo2.len()), (1, 1), "cycle {k}: one TPDO 1 and one TPDO 2 per SYNC");
        statusword = u16::from_le_bytes(tpdo1[0].data()[0..2].try_into().unwrap());
        actual = i32::from_le_bytes(tpdo1[0].data()[2..6].try_into().unwrap());
        let fe = i32::from_le_bytes(tpdo2[0].data()[0..4].try_into().unwrap());
        if let (Some(m), Some(k0)) = (mv, enabled_at) {
            let t = (k - k0) as f64 * 1e-3;
            if k > k0 + 2 && t <= m.duration_s() {
                fe_peak = fe_peak.max(fe.abs());
                fe_sq += f64::from(fe) * f64::from(fe);
                fe_n += 1;
            }
            bit13 |= statusword & (1 << 13) != 0;
        }
        let controlword: u16 = match statusword & 0x6F {
            0x21 => 0x0007,
            0x23 | 0x27 => 0x000F,
            _ => 0x0006,
        };
        if statusword & 0x6F == 0x27 && enabled_at.is_none() {
            enabled_at = Some(k);
            let per_rpm = INC_PER_REV / 60.0;
            mv =
                Some(JerkLimitedMove::new(f64::from(actual), 10.0 * INC_PER_REV, 3000.0 * per_rpm, 20_000.0 * per_rpm));
        }
        match (mv, enabled_at) {
            (Some(m), Some(k0)) => target = m.position((k + 1 - k0) as f64 * 1e-3).round() as i32,
            _ => target = actual,
        }
        let mut rpdo = controlword.to_le_bytes().to_vec();
        rpdo.extend_from_slice(&target.to_le_bytes());
        rig.frame(RPDO_CW_TARGET, &rpdo);
        rig.cycle();
    }
    let k0 = enabled_at.expect("«Operation enabled» seen in the TPDO statusword");
    assert!(k0 < 500, "enabled after {k0} cycles");
    assert_ne!(statusword & (1 << 9), 0, "remote");
    let m = mv.unwrap();
    let end = (m.start + m.distance).round() as i32;
    assert!((actual - end).abs() <= 1, "at the target: {actual} vs {end}");
    let fe_rms = (fe_sq / f64::from(fe_n)).sqrt();
    println!(
        "CAN CSP: enabled after {k0} SYNCs; following error peak {fe_peak} inc, RMS {fe_rms:.2} inc over {fe_n} SYNCs"
    );
    assert!(fe_n > 400, "sampled over the move ({fe_n})");
    assert!(fe_peak <= 30, "peak following error {fe_peak} inc");
    assert!(fe_rms <= 8.0, "RMS following error {fe_rms} inc");
    assert!(!bit13, "statusword bit 13 never set");
    assert_eq!(rig.node.counters().syncs_missed, 0, "no SYNC lost");
    assert_eq!(rig.node.counters().syncs, 3000);
    assert_eq!(rig.node.counters().tx_dropped, 0);

    // The master stops its heartbeat but keeps SYNC and set-points going: the consumer times out.
    let mut reaction_us = None;
    for _ in 0..200 {
        rig.frame(0x080, &[]);
        let mut rpdo = 0x000Fu16.to_le_bytes().to_vec();
        rpdo.extend_from_slice(&actual.to_le_bytes());
        rig.frame(RPDO_CW_TARGET, &rpdo);
        for _ in 0..PERIODS_PER_CYCLE {
            rig.sim.step();
            rig.now_us += PERIOD_US;
            if reaction_us.is_none() && rig.sim.cia402_state() == State::QuickStopActive {
                reaction_us = Some(rig.now_us);
            }
        }
        rig.process();
        if reaction_us.is_some() {
            break;
        }
    }
    let after = reaction_us.expect("the 0x6007 reaction (quick stop)") - last_heartbeat_us;
    println!("heartbeat loss: quick stop {after} us after the last heartbeat (consumer time 50 ms)");
    assert!(after > 50_000, "not before the consumer time: {after} us");
    assert!(after <= 50_000 + 2_000, "within the consumer time + 1 cycle + 1 poll: {after} us");
    rig.process();
    let emcy: Vec<_> = rig.sent.iter().map(|(_, f)| *f).filter(|f| f.id() == 0x085).collect();
    let hb = emcy.iter().find(|f| u16::from_le_bytes([f.data()[0], f.data()[1]]) == 0x8130);
    let hb = hb.unwrap_or_else(|| panic!("EMCY 0x8130 on 0x85, got {emcy:?}"));
    assert_eq!(hb.data()[3], FaultId::HeartbeatLost.number());
    assert_eq!(&hb.data()[4..8], &127i32.to_le_bytes(), "the silent producer's node-ID");
}

/// Proves: frames nobody expects never panic the node and leave it answering: 20,000 pseudo-random frames
/// (identifiers, lengths, data, remote bit; fixed seed, so the run is repeatable) in pre-operational and
/// operational, with the NMT commands filtered out so the node stays in its state; afterwards an SDO upload of
/// 0x1000 is answered correctly and the NMT still works. Wrong-length SYNC gives EMCY 0x8240 once.
#[test]
fn random_frames_never_break_the_node() {
    let mut rig = Rig::new(idle_drive());
    let mut seed: u64 = 0x1234_5678_9ABC_DEF0;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for round in 0..2 {
        if round == 1 {
            rig.nmt(0x01, NODE);
        }
        for _ in 0..10_000 {
            let r = next();
            let id = (r & 0x7FF) as u16;
            if id == 0 {
                continue;
            }
            let len = ((r >> 11) % 9) as usize;
            let data: Vec<u8> = (0..len).map(|k| (r >> (16 + 5 * k)) as u8).collect();
            let f = if (r >> 60) & 0xF == 0 {
                CanFrame::remote(id, len as u8).unwrap()
            } else {
                CanFrame::new(id, &data).unwrap()
            };
            rig.deliver(&f);
            if (r >> 56) & 0x0F == 0 {
                rig.now_us += 100;
                rig.process();
            }
        }
        // Any SDO transfer a random frame started is ended by a new initiate.
        rig.sent.clear();
        assert_eq!(rig.upload(0x1000, 0), Ok(0x0002_0192u32.to_le_bytes().to_vec()), "round {round}");
    }
    rig.nmt(0x80, 0);
    assert_eq!(rig.node.state(), NmtState::PreOperational);
}

/// A device that is not the drive: a dictionary and a record of the events the node reports.
struct RecordingDevice {
    dictionary: firmware::od::access::Dictionary,
    remote: Vec<bool>,
    setpoints: u32,
    lost: Vec<firmware::supervision::communication::LinkLoss>,
    shutdowns: u32,
    emcy: Option<[u8; 8]>,
}

impl firmware::comm::device::FieldbusDevice for RecordingDevice {
    fn dictionary(&self) -> &firmware::od::access::Dictionary {
        &self.dictionary
    }
    fn dictionary_mut(&mut self) -> &mut firmware::od::access::Dictionary {
        &mut self.dictionary
    }
    fn power_stage_enabled(&self) -> bool {
        false
    }
    fn setpoint_received(&mut self) {
        self.setpoints += 1;
    }
    fn set_remote(&mut self, remote: bool) {
        self.remote.push(remote);
    }
    fn communication_lost(&mut self, loss: firmware::supervision::communication::LinkLoss) {
        self.lost.push(loss);
    }
    fn communication_restored(&mut self, _: firmware::supervision::communication::LinkLoss) {}
    fn poll_emcy(&mut self) -> Option<[u8; 8]> {
        self.emcy.take()
    }
    fn shutdown(&mut self) {
        self.shutdowns += 1;
    }
}

/// Proves the node works against the narrow device interface alone (`comm::device::FieldbusDevice`), with no
/// drive behind it: boot-up 0x705 [00]; an SDO upload answered from the device's dictionary (0x1000, CiA 301
/// §7.2.4.3.6 expedited answer 0x43); NMT start reports remote = true and an event-driven RPDO 1 writes the
/// controlword and reports one set-point; an EMCY the device produces goes out on 0x085; NMT reset node makes
/// the node put the device in its safe state (`shutdown` once more than the power-on reset did) before the
/// boot-up.
#[test]
fn the_node_serves_any_device_through_the_fieldbus_interface() {
    let mut device = RecordingDevice {
        dictionary: firmware::od::access::Dictionary::new(NODE),
        remote: Vec::new(),
        setpoints: 0,
        lost: Vec::new(),
        shutdowns: 0,
        emcy: None,
    };
    let mut app = NoApplicationObjects;
    let mut node = CanopenNode::new(NODE);
    let mut now_us = 0u64;
    let mut sent = Vec::new();
    let mut run = |node: &mut CanopenNode, device: &mut RecordingDevice, frame: Option<CanFrame>| {
        now_us += 400;
        if let Some(f) = frame {
            node.handle_frame(&f, device, &mut app, now_us);
        }
        let event = node.process(device, &mut app, now_us);
        let mut out = Vec::new();
        while let Some(f) = node.transmit() {
            out.push(f);
        }
        sent.extend(out.iter().copied());
        (event, out)
    };
    assert!(matches!(run(&mut node, &mut device, None).0, Some(NodeEvent::Reset { kind: ResetKind::Node, .. })));
    let (event, out) = run(&mut node, &mut device, None);
    assert_eq!(event, Some(NodeEvent::Booted));
    assert_eq!(out.iter().map(|f| (f.id(), f.data().to_vec())).collect::<Vec<_>>(), vec![(0x705, vec![0])]);

    let request = SdoRequest::InitiateUpload { index: 0x1000, sub: 0 }.to_frame();
    let (_, out) = run(&mut node, &mut device, CanFrame::new(0x605, &request));
    let answer = out.iter().find(|f| f.id() == 0x585).expect("an SDO answer");
    let device_type = firmware::od::generated::DEVICE_TYPE;
    assert_eq!(answer.data()[0], 0x43);
    assert_eq!(u32::from_le_bytes(answer.data()[4..8].try_into().unwrap()), device_type);

    run(&mut node, &mut device, CanFrame::new(0x000, &[0x01, NODE]));
    assert_eq!(device.remote.last(), Some(&true), "operational: remote");
    run(&mut node, &mut device, CanFrame::new(0x205, &[0x0F, 0x00, 0x01]));
    assert_eq!(device.dictionary.get(handles::CONTROLWORD), 0x000F, "RPDO 1 written into the device's dictionary");
    assert_eq!(device.setpoints, 1, "one set-point reported");

    device.emcy = Some([0x10, 0x81, 0x11, 0, 0, 0, 0, 0]);
    let (_, out) = run(&mut node, &mut device, None);
    assert!(out.iter().any(|f| f.id() == 0x085 && f.data()[..2] == [0x10, 0x81]), "the device's EMCY: {out:?}");

    // The power-on reset is a reset node too (one shutdown already); the NMT command adds one.
    let shutdowns = device.shutdowns;
    run(&mut node, &mut device, CanFrame::new(0x000, &[0x81, NODE]));
    assert_eq!(device.shutdowns, shutdowns + 1, "reset node: the device to its safe state");
    assert!(device.lost.is_empty());
    let (_, out) = run(&mut node, &mut device, None);
    assert!(out.iter().any(|f| f.id() == 0x705 && f.data() == [0]), "boot-up after the reset: {out:?}");
}
