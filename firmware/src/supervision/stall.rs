//! Motor blocked (stall) supervision: the velocity or position loop pushes with all the current it may, and the
//! motor does not turn (issue 5; Nanotec PD4 "block detection", error code 7121h "motor blocked", PD4 p.108-109,
//! `shared/spec/control-and-protection.md` §3.10, `comms-faults-bootloader.md` §3.5.4; [`FaultId::MotorBlocked`],
//! class f: quick stop, then disable).
//!
//! # The check
//! The motor is blocked when, for [`STALL_TIME_MS`] without interruption,
//! 1. the loops drive the motor ([`SupervisionInputs::loops_drive_motor`]: PPM, PVM, HMM, CSP, CSV and the stops
//!    ramped on them). In CST the master sets the torque and a motor held still at any torque is its business
//!    (a torque-controlled press or winder stalls on purpose; the I2t protection looks after the winding);
//! 2. the current demand is at the current limit in force: `|i_ref.q| >= 90 %` of
//!    [`SupervisionInputs::current_limit`] (0x6073 / 0x3001:02 lowered by the I2t and thermal limits, the limit the
//!    velocity loop's output is clamped to). A loop that still has current in reserve is not blocked, it is only
//!    loaded. 90 % rather than 100 %: at the clamp the loop's output dips by its proportional gain times the
//!    velocity estimate's noise (up to 4 % of the 10 A limit measured while accelerating at it), and a dip must
//!    not restart the timer;
//! 3. the speed is below the velocity threshold 0x606F (default 40 rpm): |0x606C| under it is "zero speed" for the
//!    drive (PVM's statusword bit 12 uses the same object), and 40 rpm is above the encoder's quantisation at
//!    standstill (one increment per slow tick is 36.6 rpm), so a rotor pressed against a stop that rocks by one
//!    count still counts as standing.
//!
//! Then [`FaultId::MotorBlocked`] is raised (an event: the trip is the detection, and after the fault reaction
//! the loops no longer push, so there is no cause left to wait for) with the demanded current in mA as the
//! snapshot's detail; the timer restarts.
//!
//! No seed object configures this supervision: PD4's 203Ah "homing on block configuration" (minimum current for
//! block detection, time) belongs to the homing methods on a block, not to a fault; IDX and EPOS3 have no stall
//! supervision object. So the stall time and the 90 % are constants here ([`STALL_TIME_MS`],
//! [`DEMAND_PERMILLE_OF_LIMIT`]); the speed threshold is the dictionary's 0x606F.
//!
//! # Why it does not trip on a healthy drive
//! An acceleration at the current limit moves the motor: the reference motor at its 10 A limit reaches 40 rpm in
//! 0.2 ms unloaded, and a load that keeps it under 40 rpm for 500 ms at full current is a blocked motor by any
//! definition. A homing on a block (HMM methods -1..-4) ends at its current threshold 0x30B2 (default 500 mA,
//! far below the limit) within milliseconds of reaching the block; a threshold set above 90 % of the current
//! limit would let this check end such a homing after 500 ms. In CST the check is off (condition 1).

use super::SupervisionInputs;
use crate::cia402::Ticks;
use crate::fault::{FaultId, FaultManager};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// How long the blocked condition must hold without interruption before [`FaultId::MotorBlocked`], ms (PD4's
/// block detection works over a time; 500 ms is long enough for any acceleration of a free motor at its current
/// limit to leave zero speed, short enough that a blocked motor at its peak current does not reach the I2t limit:
/// 2.2 s at 10 A for the reference motor).
pub const STALL_TIME_MS: u32 = 500;

/// [`STALL_TIME_MS`] in slow ticks (1,250).
pub const STALL_TICKS: Ticks = Ticks::from_millis(STALL_TIME_MS);

/// The current demand counts as "at the limit" from this fraction of the limit in force, per mille.
pub const DEMAND_PERMILLE_OF_LIMIT: i64 = 900;

/// Motor blocked (stall) supervision. See the module documentation.
#[derive(Clone, Debug, Default)]
pub struct StallSupervision {
    /// 0x606F velocity threshold, rpm.
    speed_threshold_rpm: u32,
    /// The slow tick at which the blocked condition began, while it holds.
    since: Option<Ticks>,
}

impl StallSupervision {
    /// Over the parameters of `d` (0x606F).
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut s = Self::default();
        s.refresh(d);
        s
    }

    /// Re-reads 0x606F (velocity threshold).
    pub fn refresh(&mut self, d: &Dictionary) {
        self.speed_threshold_rpm = u32::from(d.get(h::VELOCITY_THRESHOLD));
    }

    /// 0x606F (velocity threshold) as last read, rpm: the drive's "zero speed" (also [`super::direction`]'s).
    #[must_use]
    pub const fn speed_threshold_rpm(&self) -> u32 {
        self.speed_threshold_rpm
    }

    /// Whether the blocked condition holds in this slow tick (conditions 1 to 3 of the module documentation).
    #[must_use]
    pub fn blocked_now(&self, inputs: &SupervisionInputs) -> bool {
        let demand = i64::from(inputs.i_ref.q.to_bits()).abs();
        let limit = i64::from(inputs.current_limit.to_bits());
        // |bits| < 2^31 and the factors <= 1000: the products stay far inside i64.
        let at_limit =
            demand > 0 && limit > 0 && demand.saturating_mul(1000) >= limit.saturating_mul(DEMAND_PERMILLE_OF_LIMIT);
        let standing = inputs.velocity_rpm.unsigned_abs() < self.speed_threshold_rpm;
        inputs.loops_drive_motor && at_limit && standing
    }

    /// Slow ticks the blocked condition has held at `now` (0 when it does not hold).
    #[must_use]
    pub fn blocked_for(&self, now: Ticks) -> Ticks {
        self.since.map_or(Ticks(0), |since| now.since(since))
    }

    /// One slow tick: raises [`FaultId::MotorBlocked`] once the condition has held for [`STALL_TICKS`].
    pub fn step(&mut self, inputs: &SupervisionInputs, faults: &mut FaultManager) {
        if !self.blocked_now(inputs) {
            self.since = None;
            return;
        }
        let since = *self.since.get_or_insert(inputs.now);
        if inputs.now.since(since) >= STALL_TICKS {
            faults.raise(FaultId::MotorBlocked, inputs.snapshot(inputs.i_ref.q.to_milliamps()), inputs.now);
            self.since = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::frames::{Amps, Dq};

    /// The reference drive in CSV, the loop pushing 10 A (its limit) with the rotor standing.
    fn blocked(now: u32) -> SupervisionInputs {
        let limit = Dq::new(Amps::ZERO, Amps::from_milliamps(10_000));
        SupervisionInputs { now: Ticks(now), i_dq: limit, i_ref: limit, ..SupervisionInputs::reference_running() }
    }

    fn supervision() -> StallSupervision {
        StallSupervision::new(&Dictionary::new(1))
    }

    /// Runs `ticks` slow ticks from `start` with `f(now)` as the inputs; the tick of the first MotorBlocked.
    fn run(
        s: &mut StallSupervision,
        faults: &mut FaultManager,
        start: u32,
        ticks: u32,
        f: impl Fn(u32) -> SupervisionInputs,
    ) -> Option<u32> {
        (start..start + ticks).find(|&now| {
            s.step(&f(now), faults);
            faults.is_active(FaultId::MotorBlocked)
        })
    }

    #[test]
    fn stall_time_is_1250_ticks() {
        assert_eq!(STALL_TICKS, Ticks(1250));
        assert_eq!(supervision().speed_threshold_rpm, 40, "0x606F default");
    }

    #[test]
    fn raises_after_exactly_the_stall_time() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        let raised = run(&mut s, &mut faults, 100, 2000, blocked);
        // Condition first seen at tick 100; 1,250 ticks later the fault.
        assert_eq!(raised, Some(100 + 1250));
        let a = faults.active().find(|a| a.id == FaultId::MotorBlocked).expect("active");
        assert_eq!(a.snapshot.detail, 10_000, "the demanded current, mA");
        assert_eq!(a.id.info().code, 0x7121);
    }

    #[test]
    fn any_interruption_restarts_the_timer() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        // Moving at 40 rpm (the threshold) for one tick in the middle.
        let raised = run(&mut s, &mut faults, 0, 3000, |now| SupervisionInputs {
            velocity_rpm: if now == 1000 { -40 } else { 0 },
            ..blocked(now)
        });
        assert_eq!(raised, Some(1001 + 1250));
    }

    #[test]
    fn a_motor_that_moves_or_has_current_in_reserve_is_not_blocked() {
        let s = supervision();
        let b = blocked(0);
        assert!(s.blocked_now(&b));
        assert!(s.blocked_now(&SupervisionInputs { velocity_rpm: 39, ..b }), "under 0x606F");
        assert!(!s.blocked_now(&SupervisionInputs { velocity_rpm: 40, ..b }), "0x606F reached");
        assert!(!s.blocked_now(&SupervisionInputs { velocity_rpm: 3000, ..b }), "accelerating at the limit");
        let demand = |ma| Dq::new(Amps::ZERO, Amps::from_milliamps(ma));
        assert!(s.blocked_now(&SupervisionInputs { i_ref: demand(-9_000), ..b }), "90 % of the limit, negative");
        assert!(!s.blocked_now(&SupervisionInputs { i_ref: demand(8_990), ..b }), "under 90 %");
        // The I2t protection lowered the limit to the nominal current: the loop at 3.2 A is at the limit.
        let i2t = SupervisionInputs { i_ref: demand(3_200), current_limit: Amps::from_milliamps(3_200), ..b };
        assert!(s.blocked_now(&i2t));
        // No demand, no limit: nothing pushes.
        let zero = SupervisionInputs { i_ref: demand(0), current_limit: Amps::ZERO, ..b };
        assert!(!s.blocked_now(&zero));
    }

    #[test]
    fn never_in_cst_or_disabled() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        let cst = |now| SupervisionInputs { loops_drive_motor: false, ..blocked(now) };
        assert_eq!(run(&mut s, &mut faults, 0, 5000, cst), None);
        assert_eq!(s.blocked_for(Ticks(5000)), Ticks(0));
    }

    #[test]
    fn follows_the_velocity_threshold_object() {
        let mut d = Dictionary::new(1);
        d.set(h::VELOCITY_THRESHOLD, 100);
        let s = StallSupervision::new(&d);
        assert!(s.blocked_now(&SupervisionInputs { velocity_rpm: 99, ..blocked(0) }));
        assert!(!s.blocked_now(&SupervisionInputs { velocity_rpm: 100, ..blocked(0) }));
    }
}
