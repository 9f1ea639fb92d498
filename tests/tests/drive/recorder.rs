//! The data recorder (issue 22 item 2) on the simulated drive, driven as a master drives it: configured, armed
//! and read back through the CANopen SDO server (`firmware::comm::sdo::server`) over the drive's dictionary and the
//! recorder behind its application-objects port, while the simulation runs tier 1 (its copy every period) and
//! tier 2 (the drain after every slow tick) as the target does.

use firmware::comm::sdo::server::SdoServer;
use firmware::comm::sdo::wire::{BlockSegment, SdoFrame, SdoRequest, SdoResponse};
use firmware::od::access::{AccessContext, CommState, NoApplicationObjects};
use firmware::recorder::objects::RecorderObjects;
use firmware::recorder::{sub, trigger, RecorderState, BUFFER, RECORDER, VARIABLES};
use hal_sim::scenarios::{self, Setup};
use hal_sim::sim::Simulation;

const CTX: AccessContext =
    AccessContext { comm_state: CommState::Operational, power_stage_enabled: true, max_pdo_bytes: 8 };

/// q current (mA, 16 bits), q reference (mA, 16 bits), bus voltage (mV, 32 bits).
const IQ: u32 = 0x3303_0500;
const IQ_REF: u32 = 0x3303_0600;
const V_BUS: u32 = 0x3303_0900;

/// A CANopen master's SDO client on the drive's server, frame by frame.
struct Master {
    server: SdoServer,
    now_us: u64,
}

fn abort_code(frame: &[u8; 8]) -> u32 {
    u32::from_le_bytes([frame[4], frame[5], frame[6], frame[7]])
}

impl Master {
    fn new() -> Self {
        Self { server: SdoServer::default(), now_us: 0 }
    }

    fn send(&mut self, sim: &mut Simulation, frame: [u8; 8]) -> Option<[u8; 8]> {
        self.now_us += 100;
        let mut none = NoApplicationObjects;
        let mut port = RecorderObjects::new(&mut sim.recorder, &mut none);
        self.server.handle(&frame, self.now_us, sim.drive.dictionary_mut(), CTX, &mut port)
    }

    fn poll(&mut self, sim: &mut Simulation) -> Option<[u8; 8]> {
        let mut none = NoApplicationObjects;
        let mut port = RecorderObjects::new(&mut sim.recorder, &mut none);
        self.server.poll(self.now_us, sim.drive.dictionary_mut(), &mut port)
    }

    /// Expedited download (CiA 301 §7.2.4.3.3); the abort code when refused.
    fn download(&mut self, sim: &mut Simulation, index: u16, sub: u8, data: &[u8]) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let mut frame = [0x23 | ((4 - data.len() as u8) << 2), i0, i1, sub, 0, 0, 0, 0];
        frame[4..4 + data.len()].copy_from_slice(data);
        let r = self.send(sim, frame).expect("an answer");
        if r[0] == 0x80 {
            return Err(abort_code(&r));
        }
        assert_eq!(r[0], 0x60, "download acknowledged");
        Ok(())
    }

    fn configure(&mut self, sim: &mut Simulation, s: u8, value: u32, len: usize) {
        self.download(sim, RECORDER, s, &value.to_le_bytes()[..len]).unwrap_or_else(|c| panic!("0x3300:{s}: {c:08X}"));
    }

    /// Segmented upload (CiA 301 §7.2.4.3.5..7); the abort code when refused.
    fn upload_segmented(&mut self, sim: &mut Simulation, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.send(sim, [0x40, i0, i1, sub, 0, 0, 0, 0]).expect("an answer");
        if r[0] == 0x80 {
            return Err(abort_code(&r));
        }
        if r[0] & 0x02 != 0 {
            let n = if r[0] & 0x01 != 0 { 4 - usize::from((r[0] >> 2) & 3) } else { 4 };
            return Ok(r[4..4 + n].to_vec());
        }
        assert_eq!(r[0], 0x41, "segmented, size indicated");
        let size = abort_code(&r) as usize;
        let mut data = Vec::new();
        let mut toggle = 0u8;
        loop {
            let s = self.send(sim, [0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]).expect("a segment");
            assert_ne!(s[0], 0x80, "no abort during the upload");
            assert_eq!(s[0] & 0x10, toggle, "toggle");
            let n = 7 - usize::from((s[0] >> 1) & 7);
            data.extend_from_slice(&s[1..1 + n]);
            toggle ^= 0x10;
            if s[0] & 0x01 != 0 {
                break;
            }
        }
        assert_eq!(data.len(), size, "the announced size");
        Ok(data)
    }

    /// Block upload with CRC (CiA 301 §7.2.4.3.14..16), sub-blocks of `blksize` segments.
    fn upload_block(&mut self, sim: &mut Simulation, index: u16, sub: u8, blksize: u8) -> Vec<u8> {
        let init = SdoRequest::BlockUploadInitiate { index, sub, crc: true, blksize, pst: 0 };
        let r = self.send(sim, init.to_frame()).expect("an answer");
        let Some(SdoResponse::BlockUploadInitiate { size: Some(size), .. }) =
            SdoFrame::new_checked(&r[..]).ok().map(|f| SdoResponse::parse(&f))
        else {
            panic!("block upload initiate answered {r:02X?}")
        };
        let mut data = Vec::new();
        let mut frame = self.send(sim, SdoRequest::BlockUploadStart.to_frame());
        loop {
            let mut ackseq = 0;
            let mut ended = false;
            while let Some(f) = frame {
                let seg = BlockSegment::parse(&SdoFrame::new_checked(&f[..]).expect("a frame"));
                assert_eq!(seg.seqno, ackseq + 1, "segments in sequence");
                ackseq = seg.seqno;
                data.extend_from_slice(&seg.data);
                ended = seg.last;
                frame = self.poll(sim);
            }
            let raw = self.send(sim, SdoRequest::BlockUploadAck { ackseq, blksize }.to_frame()).expect("an answer");
            if ended {
                let Ok(SdoResponse::BlockUploadEnd { unused, .. }) =
                    SdoFrame::new_checked(&raw[..]).map(|f| SdoResponse::parse(&f))
                else {
                    panic!("block upload end answered {raw:02X?}")
                };
                data.truncate(data.len() - usize::from(unused));
                assert_eq!(self.send(sim, SdoRequest::BlockUploadEnd.to_frame()), None);
                break;
            }
            frame = Some(raw);
        }
        assert_eq!(data.len(), size as usize, "the announced size");
        data
    }

    fn state(&mut self, sim: &mut Simulation) -> u8 {
        self.upload_segmented(sim, RECORDER, sub::STATE).expect("state readable")[0]
    }
}

/// The drive of the current-step scenario (`hal_sim::scenarios::prepare`: calibrated, commutation indexed, rotor
/// locked, zero current for 200 periods) with the recorder's sample memory attached.
fn locked_drive() -> Simulation {
    let (mut sim, _) = scenarios::prepare(&Setup::default()).expect("the drive is prepared");
    sim.attach_recorder();
    sim.plant.lock_rotor(true);
    sim.set_q_reference(0.0);
    sim.run(200);
    sim
}

/// What the simulation itself saw in one period: tier 1's measured q current and reference (mA, rounded), its bus
/// voltage (mV), and the plant's true q current (A).
#[derive(Clone, Copy, Debug)]
struct Truth {
    iq_ma: i32,
    iq_ref_ma: i32,
    v_bus_mv: i32,
    iq_true_a: f64,
}

fn truth(sim: &Simulation) -> Truth {
    let s = sim.tier1().signals();
    Truth {
        iq_ma: s.i_dq.q.to_milliamps(),
        iq_ref_ma: s.i_ref.q.to_milliamps(),
        v_bus_mv: s.v_bus.to_millivolts(),
        iq_true_a: sim.plant.state_at_sample().i_dq_a[1],
    }
}

/// Issue 22 item 2, "What it must show": a q-current step 0 -> 2 A (the `current-step` scenario's) recorded at
/// 25 kHz with 20 preceding samples, triggered by i_q rising through 1 A, configured, armed and read back by SDO
/// (segmented, and block with CRC: the same bytes), against the simulator's own trace of the same run, sample by
/// sample.
///
/// Tolerances: against tier 1's own measured q current and reference (what the simulation's trace records as the
/// measurement) the recording is exact to 1 mA, its unit (the recorder rounds the same `I16F16` value to mA):
/// that is the "matches the simulator's own within 1 %" with room to spare. Against the plant's true q
/// current the recording is within 1 % of the step (20 mA) in rms over the 100 samples (13.8 mA on seed 1), and
/// no sample is further from it than tier 1's own measurement plus the 1 mA rounding (worst 45.8 mA on seed 1):
/// what separates them is the current measurement itself (ADC quantisation, noise and the PWM ripple of the
/// reference plant), not the recorder. The trigger sample is the first whose q current reaches 1 A, preceded by
/// the 20 samples before it.
#[test]
fn records_a_current_step_with_preceding_samples_as_the_simulation_saw_it() {
    let mut sim = locked_drive();
    let mut master = Master::new();
    for (k, c) in [IQ, IQ_REF, V_BUS].iter().enumerate() {
        master.download(&mut sim, VARIABLES, k as u8 + 1, &c.to_le_bytes()).expect("channel accepted");
    }
    master.download(&mut sim, VARIABLES, 0, &[3]).expect("three channels");
    master.configure(&mut sim, sub::PERIOD, 1, 2);
    master.configure(&mut sim, sub::SAMPLES, 100, 4);
    master.configure(&mut sim, sub::PRECEDING, 20, 4);
    master.configure(&mut sim, sub::MODE, u32::from(trigger::RISING), 1);
    master.configure(&mut sim, sub::TRIGGER_CHANNEL, 1, 1);
    master.configure(&mut sim, sub::THRESHOLD, 1_000, 4);
    assert_eq!(master.upload_segmented(&mut sim, RECORDER, sub::MAX_SAMPLES), Ok(8_192u32.to_le_bytes().to_vec()));
    master.configure(&mut sim, sub::CONTROL, 1, 1);
    let mut seen = Vec::new();
    for _ in 0..60 {
        sim.step();
        seen.push(truth(&sim));
    }
    assert_eq!(master.state(&mut sim), RecorderState::Waiting as u8, "no trigger before the step");
    sim.set_q_reference(2.0);
    for _ in 0..200 {
        sim.step();
        seen.push(truth(&sim));
    }
    assert_eq!(master.state(&mut sim), RecorderState::Complete as u8);
    assert_eq!(master.upload_segmented(&mut sim, RECORDER, sub::RECORDED), Ok(100u32.to_le_bytes().to_vec()));

    let data = master.upload_segmented(&mut sim, BUFFER, 0).expect("the recording");
    assert_eq!(master.upload_block(&mut sim, BUFFER, 0, 127), data, "block upload gives the same bytes");
    assert_eq!(master.upload_block(&mut sim, BUFFER, 0, 5), data, "in small sub-blocks as well");
    assert_eq!(data.len(), 100 * 8, "100 samples of 2 + 2 + 4 bytes");
    let recorded: Vec<(i32, i32, i32)> = data
        .chunks(8)
        .map(|s| {
            (
                i32::from(i16::from_le_bytes([s[0], s[1]])),
                i32::from(i16::from_le_bytes([s[2], s[3]])),
                i32::from_le_bytes([s[4], s[5], s[6], s[7]]),
            )
        })
        .collect();
    let trigger_at = seen.iter().position(|t| t.iq_ma >= 1_000).expect("the step crossed 1 A");
    assert!((60..70).contains(&trigger_at), "the crossing came within 10 periods of the step, period {trigger_at}");
    let window = &seen[trigger_at - 20..trigger_at + 80];
    assert!(recorded[20].0 >= 1_000 && recorded[19].0 < 1_000, "sample 20 is the trigger: {:?}", &recorded[18..22]);
    let (mut worst_true_ma, mut square_sum, mut worst_measured_ma): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for (k, (r, t)) in recorded.iter().zip(window).enumerate() {
        assert!((r.0 - t.iq_ma).abs() <= 1, "sample {k}: i_q {} mA recorded, {} mA in tier 1", r.0, t.iq_ma);
        assert!((r.1 - t.iq_ref_ma).abs() <= 1, "sample {k}: reference {} mA recorded, {} mA", r.1, t.iq_ref_ma);
        assert!((r.2 - t.v_bus_mv).abs() <= 1, "sample {k}: bus {} mV recorded, {} mV", r.2, t.v_bus_mv);
        let error = f64::from(r.0) - t.iq_true_a * 1000.0;
        worst_true_ma = worst_true_ma.max(error.abs());
        square_sum += error * error;
        worst_measured_ma = worst_measured_ma.max((f64::from(t.iq_ma) - t.iq_true_a * 1000.0).abs());
    }
    let rms_ma = (square_sum / 100.0).sqrt();
    eprintln!("recorded i_q against the true current: rms {rms_ma:.1} mA, worst {worst_true_ma:.1} mA; tier 1's measurement worst {worst_measured_ma:.1} mA");
    assert!(rms_ma <= 20.0, "recorded i_q {rms_ma:.1} mA rms from the plant's true current (1 % of 2 A)");
    assert!(
        worst_true_ma <= worst_measured_ma + 1.0,
        "the recorder adds at most its rounding to the measurement's error"
    );
    // The recording spans the step: zero before it, the 2 A reference after.
    assert!(recorded[0].1.abs() <= 1 && recorded[99].1 == 2_000, "reference {:?} .. {:?}", recorded[0], recorded[99]);
}

/// Every configuration write acts or refuses with its CiA 301 Table 22 code, on the wire: 0x0604_0041 for a
/// channel that cannot be recorded (0x1008 device name, not mappable), 0x0609_0030 for a trigger mode that does
/// not exist, 0x0604_0043 for an arm with 2 preceding samples of 2, 0x0800_0022 for a configuration write and a
/// buffer upload while armed, and none of them changes what was configured.
#[test]
fn refusals_by_sdo_name_their_clause() {
    let mut sim = locked_drive();
    let mut master = Master::new();
    assert_eq!(master.download(&mut sim, VARIABLES, 1, &0x1008_0000u32.to_le_bytes()), Err(0x0604_0041));
    assert_eq!(master.download(&mut sim, RECORDER, sub::MODE, &[7]), Err(0x0609_0030));
    master.download(&mut sim, VARIABLES, 1, &IQ.to_le_bytes()).expect("i_q accepted");
    master.download(&mut sim, VARIABLES, 0, &[1]).expect("one channel");
    master.configure(&mut sim, sub::SAMPLES, 2, 4);
    master.configure(&mut sim, sub::PRECEDING, 2, 4);
    assert_eq!(master.download(&mut sim, RECORDER, sub::CONTROL, &[1]), Err(0x0604_0043));
    assert_eq!(master.state(&mut sim), RecorderState::Idle as u8);
    master.configure(&mut sim, sub::PRECEDING, 1, 4);
    master.configure(&mut sim, sub::MODE, u32::from(trigger::RISING), 1);
    master.configure(&mut sim, sub::THRESHOLD, 30_000, 4);
    master.configure(&mut sim, sub::CONTROL, 1, 1);
    sim.run(50);
    assert_eq!(master.download(&mut sim, RECORDER, sub::THRESHOLD, &[0, 0, 0, 0]), Err(0x0800_0022));
    assert_eq!(master.download(&mut sim, VARIABLES, 0, &[0]), Err(0x0800_0022));
    assert_eq!(master.upload_segmented(&mut sim, BUFFER, 0), Err(0x0800_0022));
    assert_eq!(master.upload_segmented(&mut sim, RECORDER, sub::THRESHOLD), Ok(30_000u32.to_le_bytes().to_vec()));
    master.configure(&mut sim, sub::CONTROL, 2, 1);
    sim.run(10);
    assert_eq!(master.state(&mut sim), RecorderState::Complete as u8, "trigger now, then two samples");
    assert_eq!(master.upload_segmented(&mut sim, BUFFER, 0).map(|d| d.len()), Ok(4));
}
