//! Safe Torque Off: the drive's view of its two STO inputs (EPOS4 AN ch. 9, S1 L8600-8910; digest
//! `control-and-protection.md` §3.9; issue 19 item 1).
//!
//! The torque is removed by hardware: either de-energised input stops the switching of the output transistors
//! (S1 Tab. 9-87), with no part of the firmware in that path ([`crate::hal::sto`]). What the firmware adds is the
//! state around it:
//! - **STO active** ([`FaultId::SafeTorqueOff`], 0xFFA0, [`crate::fault::ReactionClass::TorqueOff`]) while either
//!   input is de-energised: an EMCY when it begins, 0x603F shows its code while no fault is active, statusword bit
//!   14 is set, and the CiA 402 machine goes to and stays in «Switch on disabled» (`cia402::machine`, "Safe Torque
//!   Off"). It clears itself when both inputs are energised again; the drive then waits for the master's
//!   «Shutdown», «Switch on», «Enable operation».
//! - **Discrepancy** ([`FaultId::StoDiscrepancy`], 0xFFA1, class d): the inputs disagree for longer than
//!   [`DISCREPANCY_TIME_MS`]. Both inputs carry one demand (S1 Tab. 9-87 lists the mixed rows only as "inactive"),
//!   so a lasting disagreement means a channel, its wiring or the safety device has failed and the second channel
//!   no longer backs the first. It latches until both inputs agree again (both energised or both not) and a fault
//!   reset arrives.
//!
//! # Timing
//! Tier 2 reads the inputs at the start of every slow period, before this step (`rt::tier2`; the simulation at the
//! same point), so the machine leaves its state with power in the slow tick that follows the change: the firmware
//! follows the hardware within one slow period (0.4 ms), far inside the 25 ms reaction time of S1 Tab. 9-85. The
//! STO input is not read in tier 1: the hardware, not the current loop, removes the torque.
//!
//! # Discrepancy time
//! No seed gives one. [`DISCREPANCY_TIME_MS`] = 100 ms: the two contacts of one door switch or emergency stop
//! open tens of milliseconds apart, which must not trip, while a channel that stays alone for 100 ms is found at the
//! first demand, long before a second failure is likely. A safety controller's test pulses (< 800 us, S1
//! L8821-8833) are three orders of magnitude shorter.

use super::SupervisionInputs;
use crate::cia402::Ticks;
use crate::fault::{FaultId, FaultManager};
use crate::hal::sto::StoInputs;

/// How long the two STO inputs may disagree before [`FaultId::StoDiscrepancy`], ms (module documentation).
pub const DISCREPANCY_TIME_MS: u32 = 100;

/// [`DISCREPANCY_TIME_MS`] in slow ticks (250).
pub const DISCREPANCY_TICKS: Ticks = Ticks::from_millis(DISCREPANCY_TIME_MS);

/// The STO state and the discrepancy check. See the module documentation.
#[derive(Clone, Debug, Default)]
pub struct StoSupervision {
    /// STO was active in the last step (starts released, so that inputs de-energised at start-up are reported).
    active: bool,
    /// Slow ticks the inputs have disagreed without interruption.
    disagreeing_for: u32,
    /// The discrepancy fault was raised for the present disagreement.
    discrepancy_raised: bool,
}

impl StoSupervision {
    /// One slow tick with the inputs tier 2 read for it; `inputs` gives the snapshot's values and the time. The
    /// snapshot's detail is [`StoInputs::bits`].
    pub fn step(&mut self, sto: StoInputs, inputs: &SupervisionInputs, faults: &mut FaultManager) {
        let active = !sto.torque_permitted();
        if active != self.active {
            self.active = active;
            if active {
                faults.raise(FaultId::SafeTorqueOff, inputs.snapshot(i32::from(sto.bits())), inputs.now);
            } else {
                faults.clear_cause(FaultId::SafeTorqueOff);
            }
        }
        if sto.disagree() {
            self.disagreeing_for = self.disagreeing_for.saturating_add(1);
            if !self.discrepancy_raised && self.disagreeing_for >= DISCREPANCY_TICKS.0 {
                self.discrepancy_raised = true;
                faults.raise(FaultId::StoDiscrepancy, inputs.snapshot(i32::from(sto.bits())), inputs.now);
            }
        } else {
            self.disagreeing_for = 0;
            if core::mem::take(&mut self.discrepancy_raised) {
                // Latched: the fault stays until a fault reset, which is accepted from now on.
                faults.clear_cause(FaultId::StoDiscrepancy);
            }
        }
    }

    /// Whether STO was active in the last step.
    #[must_use]
    pub const fn active(&self) -> bool {
        self.active
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CH1_ONLY: StoInputs = StoInputs { channel_1: false, channel_2: true };

    fn run(s: &mut StoSupervision, faults: &mut FaultManager, sto: StoInputs, ticks: u32, from: u32) {
        for n in from..from.saturating_add(ticks) {
            let inputs = SupervisionInputs { now: Ticks(n), ..SupervisionInputs::reference_running() };
            s.step(sto, &inputs, faults);
        }
    }

    #[test]
    fn sto_active_follows_either_input_and_clears_itself() {
        // S1 Tab. 9-87: the power stage is active only with both inputs energised.
        for sto in [StoInputs::DEMANDED, CH1_ONLY, StoInputs { channel_1: true, channel_2: false }] {
            let (mut s, mut faults) = (StoSupervision::default(), FaultManager::<16>::new());
            run(&mut s, &mut faults, sto, 1, 0);
            assert!(faults.is_active(FaultId::SafeTorqueOff), "{sto:?}");
            assert!(faults.safe_torque_off_active() && !faults.any_fault(), "{sto:?}: a state, not a fault");
            assert_eq!(faults.error_code(), 0xFFA0, "{sto:?}: 0x603F shows STO");
            assert_eq!(faults.error_register(), 0, "{sto:?}: not an error (0x1001)");
            run(&mut s, &mut faults, StoInputs::RELEASED, 1, 1);
            assert!(!faults.is_active(FaultId::SafeTorqueOff) && !faults.safe_torque_off_active(), "{sto:?}");
            assert_eq!(faults.error_code(), 0, "{sto:?}");
        }
    }

    #[test]
    fn released_inputs_report_nothing() {
        let (mut s, mut faults) = (StoSupervision::default(), FaultManager::<16>::new());
        run(&mut s, &mut faults, StoInputs::RELEASED, 1_000, 0);
        assert!(faults.active().next().is_none() && !faults.safe_torque_off_active());
        assert_eq!(faults.poll_emcy(Ticks(1_000)), None, "no EMCY");
    }

    #[test]
    fn one_emcy_per_demand_with_the_input_levels() {
        let (mut s, mut faults) = (StoSupervision::default(), FaultManager::<16>::new());
        run(&mut s, &mut faults, StoInputs::DEMANDED, 10, 0);
        let frame = faults.poll_emcy(Ticks(10)).expect("an EMCY at the demand");
        let m = crate::fault::EmcyMessage::parse(&frame).expect("a valid frame");
        assert_eq!((m.code, m.fault_number(), m.value()), (0xFFA0, FaultId::SafeTorqueOff.number(), 0));
        assert_eq!(faults.poll_emcy(Ticks(11)), None, "once per demand");
    }

    #[test]
    fn discrepancy_trips_after_the_discrepancy_time_and_not_before() {
        let (mut s, mut faults) = (StoSupervision::default(), FaultManager::<16>::new());
        run(&mut s, &mut faults, CH1_ONLY, DISCREPANCY_TICKS.0 - 1, 0);
        assert!(!faults.is_active(FaultId::StoDiscrepancy), "99.6 ms of disagreement is allowed");
        run(&mut s, &mut faults, CH1_ONLY, 1, DISCREPANCY_TICKS.0 - 1);
        assert!(faults.is_active(FaultId::StoDiscrepancy), "100 ms: tripped");
        assert_eq!(faults.error_code(), 0xFFA1, "the fault outranks the STO state in 0x603F");
        assert_eq!(faults.snapshot(FaultId::StoDiscrepancy).map(|s| s.detail), Some(0b10), "IN2 energised");
    }

    #[test]
    fn contacts_opening_one_after_the_other_are_no_discrepancy() {
        let (mut s, mut faults) = (StoSupervision::default(), FaultManager::<16>::new());
        // Twice: channel 1 opens, channel 2 follows 60 ms later; then both close together.
        for k in 0..2 {
            let t = k * 1_000;
            run(&mut s, &mut faults, CH1_ONLY, 150, t);
            run(&mut s, &mut faults, StoInputs::DEMANDED, 100, t + 150);
            run(&mut s, &mut faults, StoInputs::RELEASED, 100, t + 250);
        }
        assert!(!faults.is_active(FaultId::StoDiscrepancy));
    }

    #[test]
    fn discrepancy_latches_until_the_inputs_agree_and_a_reset() {
        let (mut s, mut faults) = (StoSupervision::default(), FaultManager::<16>::new());
        run(&mut s, &mut faults, CH1_ONLY, 300, 0);
        assert_eq!(faults.reset_request().map_err(|r| r.blocking), Err(FaultId::StoDiscrepancy), "inputs disagree");
        // Both de-energised: they agree (STO demanded), the reset is accepted and STO remains.
        run(&mut s, &mut faults, StoInputs::DEMANDED, 1, 300);
        assert!(faults.is_active(FaultId::StoDiscrepancy), "latched until the reset");
        assert_eq!(faults.reset_request(), Ok(()));
        assert!(!faults.is_active(FaultId::StoDiscrepancy));
        assert!(faults.is_active(FaultId::SafeTorqueOff), "a fault reset does not clear the STO state");
        assert_eq!(faults.error_code(), 0xFFA0);
    }
}
