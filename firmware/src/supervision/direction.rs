//! Main sensor direction supervision: the motor turns away against the direction the loops drive it (IDX 7.2.25,
//! 0x7392 "Main sensor direction error": "position sensor supervision has detected a turn-away of the motor in the
//! opposite direction due to wrong setting of sensor polarity, wrong position sensor wiring, wrong motor wiring",
//! IDX L7306-7312; EPOS3 0xFF11, S0 L1160-1178; digest `control-and-protection.md` §2.7; [`FaultId::MainSensorDirection`],
//! class d).
//!
//! # The check
//! A healthy motor accelerates the way its torque pushes, unless a load stronger than that torque holds it. With the
//! sensor counting backwards (polarity, A/B lines swapped) or the torque reversed against the sensor (two motor leads
//! swapped), the sensor shows the motor accelerating against the torque, and the loops, which see it run the wrong
//! way, push harder: a run-away. The check compares the sign of the torque demand with the measured acceleration
//! over windows of [`WINDOW_TICKS`] slow ticks (2 ms). A window counts as a turn-away when, through all of it,
//! 1. the loops drive the motor ([`SupervisionInputs::loops_drive_motor`]: not in CST, where a master may hold a
//!    torque against a load that overpowers it, and not disabled);
//! 2. the q-current demand keeps one sign and at least half the current limit in force
//!    ([`SupervisionInputs::current_limit`]; [`DEMAND_PERMILLE_OF_LIMIT`]): the loop pushes hard one way. A sign
//!    change or a weaker demand restarts the window, so reversals and the small demands of holding and cruising
//!    never count;
//! 3. at the window's end the measured velocity runs against the demand by at least the threshold, and it has
//!    grown in that direction over the window by at least the threshold: the motor gains speed against its torque.
//!    The threshold is the larger of 0x606F (velocity threshold, the drive's "zero speed") and two sensor
//!    increments per slow tick (73 rpm for 4,096 inc/rev: one increment of quantisation either way cannot make it).
//!
//! Then [`FaultId::MainSensorDirection`] is raised (an event: the power stage is off after it and nothing pushes any
//! longer) with the demanded current in mA as the snapshot's detail; its EMCY carries the velocity.
//!
//! # Why it does not trip on a healthy drive
//! Braking (regeneration, a reversal, a stop) has the torque against the velocity, but the speed falls: condition
//! 3 needs it to grow against the torque. Backlash and an elastic coupling let the motor run free or spring back;
//! free, it accelerates with its torque; sprung back, the coupling's torque pushes it against the demand only while
//! it exceeds the motor's, at which point the loop has not reached half its limit for a whole window unless the
//! spring torque exceeds that half. A load step holds the motor or pushes it back until the loop's demand exceeds the
//! load; a load that still drives the motor backwards against half the current limit for 2 ms is one the motor
//! cannot hold: the motor turns away. At low speed the threshold stays above the sensor's quantisation.
//!
//! Bit 8 of 0x3000:04 "main sensor supervision disabled" (IDX Table 6-98,
//! [`super::feedback::MAIN_SENSOR_SUPERVISION_DISABLED`]) turns the check off, as the other main sensor checks.

use super::feedback::MAIN_SENSOR_SUPERVISION_DISABLED;
use super::SupervisionInputs;
use crate::fault::{FaultId, FaultManager};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// Slow ticks per window (2 ms): short enough for the first swing of a reversed sensor (the rotor turns 45 degrees
/// electrical, 1/56 turn of the reference motor, in about 4 ms at its limit), long enough for the velocity estimate
/// to show a real acceleration rather than one increment of quantisation.
pub const WINDOW_TICKS: u8 = 5;

/// The q-current demand counts as pushing from this fraction of the current limit in force, per mille.
pub const DEMAND_PERMILLE_OF_LIMIT: i64 = 500;

/// 2^32 / 150,000: rpm times increments per turn times this is the velocity in Q32 increments per slow tick (60 s
/// per minute x 2,500 slow ticks per second = 150,000).
const RPM_TO_Q32_PER_COUNT: i64 = 28_633;

/// Main sensor direction supervision. See the module documentation.
#[derive(Clone, Debug, Default)]
pub struct DirectionSupervision {
    /// 0x606F velocity threshold, rpm.
    speed_threshold_rpm: u32,
    /// Bit 8 of 0x3000:04 clear.
    supervised: bool,
    /// The sign of the demand of the current window (0: no window).
    push: i8,
    /// Slow ticks of the current window.
    ticks: u8,
    /// The velocity at the window's start, Q32 increments per slow tick.
    start: i64,
}

impl DirectionSupervision {
    /// Over the parameters of `d` (0x606F, 0x3000:04).
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut s = Self::default();
        s.refresh(d);
        s
    }

    /// Re-reads 0x606F (velocity threshold) and bit 8 of 0x3000:04.
    pub fn refresh(&mut self, d: &Dictionary) {
        self.speed_threshold_rpm = u32::from(d.get(h::VELOCITY_THRESHOLD));
        self.supervised = d.get(h::AXIS_CONFIGURATION_MISC) & MAIN_SENSOR_SUPERVISION_DISABLED == 0;
    }

    /// The speed threshold of condition 3, Q32 increments per slow tick.
    fn threshold(&self, counts_per_turn: u32) -> i64 {
        let object = i64::from(self.speed_threshold_rpm)
            .saturating_mul(i64::from(counts_per_turn))
            .saturating_mul(RPM_TO_Q32_PER_COUNT);
        object.max(2 << 32)
    }

    /// One slow tick: raises [`FaultId::MainSensorDirection`] at the end of a window that shows a turn-away.
    pub fn step(&mut self, inputs: &SupervisionInputs, faults: &mut FaultManager) {
        let demand = i64::from(inputs.i_ref.q.to_bits());
        let limit = i64::from(inputs.current_limit.to_bits());
        // |bits| < 2^31 and the factors <= 1000: the products stay far inside i64.
        let pushing = limit > 0
            && demand.saturating_abs().saturating_mul(1000) >= limit.saturating_mul(DEMAND_PERMILLE_OF_LIMIT);
        let push = if !(self.supervised && inputs.loops_drive_motor && pushing) {
            0
        } else if demand > 0 {
            1
        } else {
            -1
        };
        let velocity = inputs.velocity.0;
        if push == 0 || push != self.push {
            (self.push, self.ticks, self.start) = (push, 0, velocity);
            return;
        }
        self.ticks = self.ticks.saturating_add(1);
        if self.ticks < WINDOW_TICKS {
            return;
        }
        let threshold = self.threshold(inputs.encoder_counts_per_turn);
        let along = velocity.saturating_mul(i64::from(push));
        let gained = velocity.saturating_sub(self.start).saturating_mul(i64::from(push));
        if along <= threshold.saturating_neg() && gained <= threshold.saturating_neg() {
            faults.raise(FaultId::MainSensorDirection, inputs.snapshot(inputs.i_ref.q.to_milliamps()), inputs.now);
        }
        (self.ticks, self.start) = (0, velocity);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::Ticks;
    use crate::control::frames::{Amps, Dq};
    use crate::control::trajectory::Velocity;

    /// One increment per slow tick, Q32 (36.6 rpm at 4,096 inc/rev).
    const COUNT: i64 = 1 << 32;

    /// The reference drive in CSV at slow tick `now`, demanding `ma` mA, the velocity estimate at `counts` per tick.
    fn at(now: u32, ma: i32, counts: f64) -> SupervisionInputs {
        let demand = Dq::new(Amps::ZERO, Amps::from_milliamps(ma));
        SupervisionInputs {
            now: Ticks(now),
            i_ref: demand,
            i_dq: demand,
            velocity: Velocity((counts * COUNT as f64) as i64),
            ..SupervisionInputs::reference_running()
        }
    }

    /// Runs `ticks` slow ticks with `f(now)`; the tick of the first raise.
    fn run(s: &mut DirectionSupervision, ticks: u32, f: impl Fn(u32) -> SupervisionInputs) -> Option<u32> {
        let mut faults = FaultManager::new();
        (0..ticks).find(|&now| {
            s.step(&f(now), &mut faults);
            faults.is_active(FaultId::MainSensorDirection)
        })
    }

    fn supervision() -> DirectionSupervision {
        DirectionSupervision::new(&Dictionary::new(1))
    }

    #[test]
    fn threshold_is_0x606f_or_two_increments_per_tick() {
        let s = supervision();
        // 0x606F = 40 rpm at 4,096 inc/rev is 1.09 increments per tick: two increments (73 rpm) rule.
        assert_eq!(s.threshold(4096), 2 * COUNT);
        // At 40,000 inc/rev 40 rpm is 10.7 increments per tick.
        assert_eq!(s.threshold(40_000) / (COUNT / 1000), 10_666);
    }

    /// IDX 7.2.25: a sensor counting backwards: 6 A pushing forward while the velocity runs backwards and grows by
    /// one increment per tick per tick: raised at the end of the first full window (tick 0 starts it).
    #[test]
    fn a_motor_accelerating_against_its_torque_raises_0x7392_at_the_end_of_a_window() {
        let mut s = supervision();
        let raised = run(&mut s, 100, |now| at(now, 6_000, -2.0 - f64::from(now)));
        assert_eq!(raised, Some(u32::from(WINDOW_TICKS)));
        assert_eq!(FaultId::MainSensorDirection.info().code, 0x7392);
        // The same backwards, and negative torque with a growing positive velocity.
        assert_eq!(run(&mut supervision(), 100, |now| at(now, -6_000, 2.0 + f64::from(now))), Some(5));
    }

    #[test]
    fn braking_a_reversal_and_a_healthy_acceleration_do_not_raise() {
        // Braking from 2,000 rpm at the limit: torque against the velocity, the speed falls.
        assert_eq!(run(&mut supervision(), 1000, |now| at(now, -10_000, 55.0 - 0.05 * f64::from(now))), None);
        // Accelerating with the torque.
        assert_eq!(run(&mut supervision(), 1000, |now| at(now, 10_000, 0.05 * f64::from(now))), None);
        // A demand that changes sign every 4 ticks (a reversal, an oscillation) never completes a window.
        let flipping = |now: u32| at(now, if (now / 4) % 2 == 0 { 6_000 } else { -6_000 }, -3.0 - f64::from(now));
        assert_eq!(run(&mut supervision(), 1000, flipping), None);
    }

    #[test]
    fn a_weak_demand_or_a_slow_turn_away_does_not_raise() {
        // Under half the 10 A limit: a load pushing the motor back while the loop builds up its demand.
        assert_eq!(run(&mut supervision(), 1000, |now| at(now, 4_990, -2.0 - f64::from(now))), None);
        // Against the demand but within two increments per tick: quantisation of a held position.
        assert_eq!(run(&mut supervision(), 1000, |now| at(now, 6_000, if now % 2 == 0 { -1.9 } else { 0.0 })), None);
        // Running backwards at a steady speed: not gaining speed against the torque.
        assert_eq!(run(&mut supervision(), 1000, |now| at(now, 6_000, -50.0)), None);
    }

    #[test]
    fn off_in_cst_and_with_0x3000_04_bit_8() {
        let cst = |now| SupervisionInputs { loops_drive_motor: false, ..at(now, 6_000, -2.0 - f64::from(now)) };
        assert_eq!(run(&mut supervision(), 100, cst), None);
        let mut d = Dictionary::new(1);
        d.set(h::AXIS_CONFIGURATION_MISC, MAIN_SENSOR_SUPERVISION_DISABLED);
        let mut s = DirectionSupervision::new(&d);
        assert_eq!(run(&mut s, 100, |now| at(now, 6_000, -2.0 - f64::from(now))), None);
        // Set clear again: on again.
        s.refresh(&Dictionary::new(1));
        assert_eq!(run(&mut s, 100, |now| at(now, 6_000, -2.0 - f64::from(now))), Some(5));
    }
}
