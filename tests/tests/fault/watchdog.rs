//! The reset cause at start-up (issue 19 item 3): only a reset by the independent watchdog is a fault of the new
//! start (IDX 7.2.48 0xFF02, class d, error register 0x01); power-on, pin, software (program control's restart),
//! low-power and unknown causes start clean. The drive runs in the reference simulation for ten slow ticks, the
//! time the fault manager takes to publish 0x603F, 0x1001 and 0x1003 (one slow tick) with room to spare.

use firmware::fault::{history, FaultId};
use firmware::hal::reset::ResetCause;
use firmware::od::generated::handles::{ERROR_CODE, ERROR_REGISTER};
use hal_sim::sim::Simulation;

fn started_after(cause: ResetCause) -> Simulation {
    let mut sim = Simulation::reference(7);
    sim.drive.report_reset(cause);
    sim.run_slow_ticks(10);
    sim
}

#[test]
fn only_a_watchdog_reset_is_a_fault_of_the_start() {
    for cause in [ResetCause::PowerOn, ResetCause::Pin, ResetCause::Software, ResetCause::LowPower, ResetCause::Unknown]
    {
        let sim = started_after(cause);
        assert!(!sim.drive.axis().faults().is_active(FaultId::WatchdogReset), "{cause:?}");
        assert_eq!(sim.drive.dictionary().get(ERROR_CODE), 0, "{cause:?}");
        assert_eq!(history::count(sim.drive.dictionary()), 0, "{cause:?}");
    }
    let mut sim = started_after(ResetCause::IndependentWatchdog);
    assert!(sim.drive.axis().faults().is_active(FaultId::WatchdogReset));
    assert_eq!(sim.drive.dictionary().get(ERROR_CODE), 0xFF02);
    assert_eq!(sim.drive.dictionary().get(ERROR_REGISTER), 0x01);
    let newest = history::entry(sim.drive.dictionary(), 1).expect("one history entry");
    assert_eq!((newest.code, newest.register), (0xFF02, 0x01));
    let emcy = sim.drive.poll_emcy().expect("the EMCY is queued for the fieldbus");
    assert_eq!(&emcy[..3], &[0x02, 0xFF, 0x01], "code 0xFF02 little-endian, register 0x01");
}
