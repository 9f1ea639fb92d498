//! The data recorder's buffer read over EtherCAT (issue 22 item 2: "upload by SDO block or segmented transfer and
//! by CoE"): a recording made on the simulated drive, uploaded through the slave's mailbox and CoE SDO server
//! (normal upload followed by segments, as SOEM's `ec_SDOread` does) from the drive's dictionary and the recorder
//! behind its application-objects port, against the same recording read directly from the recorder.

use drive_tests::ecat_master::Bench;
use firmware::od::access::{AccessContext, CommState, NoApplicationObjects};
use firmware::recorder::objects::RecorderObjects;
use firmware::recorder::{sub, trigger, BUFFER, RECORDER, VARIABLES};
use hal_sim::sim::Simulation;

const CTX: AccessContext =
    AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 40 };

/// 200 samples of the bus voltage (mV, 32 bits) and duty A (16 bits), at 2.5 kHz (0x3300:03 = 10), triggered at
/// once: 1,200 bytes, more than a dozen mailbox segments. Before the recording is complete the CoE upload is
/// refused with 0x0800_0022 (CiA 301 Table 22, as on CANopen); once complete, the CoE upload gives exactly the
/// bytes the dictionary holds, and they are the bus voltage the drive measured (20 to 28 V on the reference plant).
#[test]
fn recording_uploads_by_coe() {
    let mut sim = Simulation::reference(1);
    sim.attach_recorder();
    sim.run(20);
    let dict = sim.drive.dictionary_mut();
    let mut none = NoApplicationObjects;
    let mut port = RecorderObjects::new(&mut sim.recorder, &mut none);
    let mut write = |index: u16, s: u8, data: &[u8]| {
        dict.write(index, s, data, CTX, &mut port).unwrap_or_else(|e| panic!("{index:04X}:{s}: {e:?}"))
    };
    write(VARIABLES, 1, &0x3303_0900u32.to_le_bytes());
    write(VARIABLES, 2, &0x3303_0A00u32.to_le_bytes());
    write(VARIABLES, 0, &[2]);
    write(RECORDER, sub::PERIOD, &10u16.to_le_bytes());
    write(RECORDER, sub::SAMPLES, &200u32.to_le_bytes());
    write(RECORDER, sub::MODE, &[trigger::IMMEDIATE]);
    write(RECORDER, sub::CONTROL, &[1]);

    let mut bench = Bench::new();
    bench.dict = sim.drive.dictionary().clone();
    // The slave's port reaches the simulation's recorder while it is waiting, then again once it is complete.
    std::mem::swap(&mut bench.recorder, &mut sim.recorder);
    bench.to_preop();
    assert_eq!(bench.sdo_upload(BUFFER, 0), Err(0x0800_0022), "no complete recording yet");
    std::mem::swap(&mut bench.recorder, &mut sim.recorder);

    sim.run(2_100);
    let mut direct = vec![0u8; 1_200];
    let mut none = NoApplicationObjects;
    let mut port = RecorderObjects::new(&mut sim.recorder, &mut none);
    let outcome = sim.drive.dictionary().read(BUFFER, 0, 0, &mut direct, &mut port).expect("complete");
    assert_eq!(outcome.total_len, 1_200);
    bench.dict = sim.drive.dictionary().clone();
    std::mem::swap(&mut bench.recorder, &mut sim.recorder);
    let (coe, segments) = bench.sdo_upload(BUFFER, 0).expect("the recording by CoE");
    assert!(segments > 5, "a segmented upload ({segments} segments)");
    assert_eq!(coe, direct, "CoE gives the dictionary's bytes");
    for sample in coe.chunks(6) {
        let mv = i32::from_le_bytes([sample[0], sample[1], sample[2], sample[3]]);
        assert!((20_000..=28_000).contains(&mv), "bus voltage {mv} mV");
    }
}
