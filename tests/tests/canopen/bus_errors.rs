//! The CAN controller's error states through the node (issue 19, item 4): error passive (EMCY 0x8120), bus-off
//! (0x81FD) and receive overruns (0x8110), injected into the simulated controller of a drive on the simulated
//! bus (`hal_sim::sim::canopen::CanDrive::controller`), as `board::can` reports them on the target (CAN_ESR).
//! Each case names the IDX clause and the exact EMCY expected: code, error register 0x11 (generic and
//! communication bits, IDX 7.2), the fault number in byte 3 and the detail in bytes 4..7.

use firmware::canopen::frame::{BusState, BusStatus, CanFrame};
use firmware::fault::{EmcyMessage, FaultId};
use hal_sim::can::bus::Delivery;
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner};

const NODE: u8 = 1;
const EMCY: u16 = 0x080 + NODE as u16;
const HEARTBEAT: u16 = 0x700 + NODE as u16;

/// The node booted, producing a heartbeat every 10 ms (0x1017 written by SDO).
fn booted() -> CanopenRunner {
    let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
    r.run_for(2_000_000);
    let answer = r.lock_step(CanFrame::new(0x600 + u16::from(NODE), &[0x2B, 0x17, 0x10, 0, 10, 0, 0, 0]).unwrap());
    assert!(answer.iter().any(|d| d.frame.id() == 0x580 + u16::from(NODE) && d.frame.data()[0] == 0x60));
    r
}

fn set_controller(r: &mut CanopenRunner, state: BusState, transmit_errors: u8, rx_overruns: u32) {
    r.drive_mut(NODE).expect("node 1").controller = BusStatus { state, transmit_errors, rx_overruns };
}

/// The EMCYs among `frames`.
fn emcys(frames: &[Delivery]) -> Vec<EmcyMessage> {
    frames
        .iter()
        .filter(|d| d.frame.id() == EMCY)
        .map(|d| EmcyMessage::parse(d.frame.data()).expect("8 bytes"))
        .collect()
}

/// The EMCY of fault `id` with the communication error register (0x11) and `detail` in bytes 4..7.
fn expected(id: FaultId, detail: i32) -> EmcyMessage {
    EmcyMessage::fault(id, 0x11, detail)
}

fn heartbeats(frames: &[Delivery]) -> usize {
    frames.iter().filter(|d| d.frame.id() == HEARTBEAT).count()
}

/// IDX 7.2.28: the controller going error passive raises 0x8120 with the transmit error counter as its detail;
/// back to error active, no new EMCY is sent (the fault waits for a fault reset, as every class "a" fault).
#[test]
fn error_passive_sends_emcy_0x8120() {
    let mut r = booted();
    set_controller(&mut r, BusState::ErrorPassive, 130, 0);
    let frames = r.run_for(20_000_000);
    assert_eq!(emcys(&frames), vec![expected(FaultId::CanErrorPassive, 130)]);
    assert_eq!(FaultId::CanErrorPassive.info().code, 0x8120);
    assert!(heartbeats(&frames) >= 1, "an error-passive node still sends");
    set_controller(&mut r, BusState::ErrorActive, 90, 0);
    let frames = r.run_for(20_000_000);
    assert_eq!(emcys(&frames), vec![], "no EMCY on the way back");
}

/// IDX 7.2.36 and ISO 11898-1 §12.1.4: a bus-off node sends nothing for 100 ms (no heartbeat, no EMCY); when
/// the controller is back on the bus the queued EMCY 0x81FD leaves, then CiA 301's 0x8140 "recovered from bus
/// off" (a warning: error register 0x11 of the bus-off still active, detail 0), and the heartbeat resumes.
#[test]
fn bus_off_holds_the_emcy_0x81fd_until_the_controller_is_back() {
    let mut r = booted();
    set_controller(&mut r, BusState::BusOff, 255, 0);
    let silent = r.run_for(100_000_000);
    assert_eq!(silent.iter().filter(|d| d.frame.id() & 0x7F == u16::from(NODE)).count(), 0, "{silent:?}");
    set_controller(&mut r, BusState::ErrorActive, 0, 0);
    let back = r.run_for(30_000_000);
    assert_eq!(emcys(&back), vec![expected(FaultId::CanBusOff, 0), expected(FaultId::CanBusOffRecovered, 0)]);
    assert_eq!(FaultId::CanBusOff.info().code, 0x81FD);
    assert_eq!(FaultId::CanBusOffRecovered.info().code, 0x8140);
    assert!(heartbeats(&back) >= 2, "the heartbeat resumes: {back:?}");
}

/// IDX 7.2.26: frames lost in the receive FIFO raise 0x8110 once per report, with the number lost.
#[test]
fn receive_overrun_sends_emcy_0x8110_with_the_frames_lost() {
    let mut r = booted();
    set_controller(&mut r, BusState::ErrorActive, 0, 3);
    let frames = r.run_for(20_000_000);
    assert_eq!(emcys(&frames), vec![expected(FaultId::CanRxOverrun, 3)]);
    assert_eq!(FaultId::CanRxOverrun.info().code, 0x8110);
    let frames = r.run_for(20_000_000);
    assert_eq!(emcys(&frames), vec![], "the same count is not reported twice");
}
