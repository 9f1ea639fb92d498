//! A start after a reset by the independent watchdog (issue 19 item 3; IDX 7.2.48, L7490: 0xFF02 "Watchdog
//! error", error register 0000 0001b, class d, "reset fault with controlword"), on the simulated CAN bus: the
//! simulated microcontroller restarts as the IWDG restarts the board (`CanDrive::watchdog_reset`).

use firmware::canopen::frame::CanFrame;
use firmware::fault::{history, EmcyMessage, FaultId};
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner};

const NODE: u8 = 1;
const EMCY: u16 = 0x080 + NODE as u16;
const BOOT_UP: u16 = 0x700 + NODE as u16;

/// After the restart the node sends its boot-up, then the EMCY of 0xFF02 (register 0x01, the generic bit; fault
/// number 33 in byte 3; detail 0); 0x603F and 0x1003:01 hold 0xFF02; a fault reset by the controlword clears
/// 0x603F and keeps the history entry.
#[test]
fn a_watchdog_reset_is_reported_after_the_boot_up_with_emcy_0xff02() {
    let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
    r.run_for(2_000_000);
    r.drive_mut(NODE).expect("node 1").watchdog_reset();
    let frames = r.run_for(20_000_000);
    let boot_up = frames.iter().position(|d| d.frame.id() == BOOT_UP && d.frame.data() == [0]);
    let emcys: Vec<(usize, EmcyMessage)> = frames
        .iter()
        .enumerate()
        .filter(|(_, d)| d.frame.id() == EMCY)
        .map(|(i, d)| (i, EmcyMessage::parse(d.frame.data()).expect("8 bytes")))
        .collect();
    assert_eq!(FaultId::WatchdogReset.info().code, 0xFF02);
    assert_eq!(
        emcys.iter().map(|(_, e)| *e).collect::<Vec<_>>(),
        vec![EmcyMessage::fault(FaultId::WatchdogReset, 0x01, 0)]
    );
    let boot_up = boot_up.expect("a boot-up after the restart");
    assert!(boot_up < emcys[0].0, "the EMCY follows the boot-up");

    let drive = &r.drive(NODE).expect("node 1").sim.drive;
    let dict = drive.dictionary();
    assert_eq!(dict.get(firmware::od::generated::handles::ERROR_CODE), 0xFF02);
    let newest = history::entry(dict, 1).expect("one history entry");
    assert_eq!((newest.code, newest.register), (0xFF02, 0x01));

    // Reset fault with the controlword (IDX 7.2.48 "Error recovery"): 0x6040 = 0x0080 by SDO.
    let answer = r.lock_step(CanFrame::new(0x600 + u16::from(NODE), &[0x2B, 0x40, 0x60, 0, 0x80, 0, 0, 0]).unwrap());
    assert!(answer.iter().any(|d| d.frame.id() == 0x580 + u16::from(NODE) && d.frame.data()[0] == 0x60));
    r.run_for(5_000_000);
    let dict = r.drive(NODE).expect("node 1").sim.drive.dictionary();
    assert_eq!(dict.get(firmware::od::generated::handles::ERROR_CODE), 0, "0x603F cleared by the fault reset");
    assert_eq!(history::entry(dict, 1).map(|e| e.code), Some(0xFF02), "the history keeps it");
}
