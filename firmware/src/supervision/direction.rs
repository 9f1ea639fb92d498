//! Main sensor direction supervision: the motor turns away against the direction the loops drive it (IDX 7.2.25,
//! 0x7392 "Main sensor direction error": "position sensor supervision has detected a turn-away of the motor in the
//! opposite direction due to wrong setting of sensor polarity, wrong position sensor wiring, wrong motor wiring",
//! IDX L7306-7312; EPOS3 0xFF11, S0 L1160-1178; digest `control-and-protection.md` §2.7; [`FaultId::MainSensorDirection`],
//! class d).
//!
//! # The check
//! A healthy motor turns the way its torque pushes, unless a load stronger than that torque drives it. With the
//! sensor counting backwards (polarity, A/B lines swapped) or the torque reversed against the sensor (two motor
//! leads swapped), the sensor shows the motor turning away against the torque as soon as it starts, and the loops,
//! which see it run the wrong way, push harder. Such a fault is there from the installation, so it shows whenever
//! the motor starts from rest; the check looks there, where nothing else moves the motor:
//! 1. the motor stands: the measured velocity ([`SupervisionInputs::velocity`], the loops' own estimate, before the
//!    polarity 0x607E) stays within the threshold for [`REST_TICKS`] slow ticks (10 ms) while the loops drive the
//!    motor ([`SupervisionInputs::loops_drive_motor`]: not in CST, where a master may hold a torque against a load
//!    that overpowers it, and not disabled). The threshold is the larger of 0x606F (velocity threshold, the drive's
//!    "zero speed") and two sensor increments per slow tick (73 rpm for 4,096 inc/rev: one increment of
//!    quantisation either way cannot make it);
//! 2. it then leaves the threshold: with the sign of the q current the current loop measures (in the frame of its
//!    commutation angle: where that angle is right, the torque's; an open phase leaves it short of the demand and
//!    is [`super::phases`]' to name) the start is healthy and the watch ends until
//!    the motor stands again; against it the watch goes on while the motor stays beyond the threshold, and once the
//!    measured q current has been at least half the current limit in force ([`SupervisionInputs::current_limit`];
//!    [`DEMAND_PERMILLE_OF_LIMIT`]) for [`AWAY_TICKS`] slow ticks in a row with the motor running against it and its
//!    speed growing (braking would make it fall), the motor has turned away.
//!
//! Then [`FaultId::MainSensorDirection`] is raised (an event: the power stage is off after it and nothing pushes any
//! longer) with the measured q current in mA as the snapshot's detail; its EMCY carries the velocity.
//!
//! # Why it does not trip on a healthy drive
//! A start from rest accelerates with the torque (the loop's demand follows the set-point's direction), and a stop
//! brakes with it. Reversals, backlash and elastic couplings do their work while the motor runs: a reversal passes
//! zero speed within a few milliseconds (the geared preset's reversals throw the rotor back against the braking
//! torque through zero, by backlash and coupling, within 4 ms of the reversal), never standing 10 ms in between. A
//! load that pushes a standing motor back against half the current limit is one the motor cannot hold: it turns
//! away. A demand under half the limit never trips, and at low speed the threshold stays above the sensor's
//! quantisation.
//!
//! Bit 8 of 0x3000:04 "main sensor supervision disabled" (IDX Table 6-98,
//! [`super::feedback::MAIN_SENSOR_SUPERVISION_DISABLED`]) turns the check off, as the other main sensor checks.

use super::SupervisionInputs;
use crate::fault::{FaultId, FaultManager};

/// Slow ticks the motor must stand before a start is watched (10 ms): longer than a reversal takes to pass zero
/// speed at the current limit (the geared preset: under 4 ms), short enough that a move started after a pause is
/// watched.
pub const REST_TICKS: u8 = 25;

/// Consecutive slow ticks (1.6 ms) a watched start must run against a demand of half the current limit, its speed
/// growing, before it counts as a turn-away: the velocity estimate lags the rotor, so a start that the position
/// loop brakes at once (a free, light rotor overshooting a held position) can pass the threshold in the estimate
/// while the demand already brakes it; braking makes the speed fall within a tick, a turn-away makes it grow.
pub const AWAY_TICKS: u8 = 4;

/// The q-current demand counts as pushing from this fraction of the current limit in force, per mille (the check
/// compares twice the demand with the limit).
pub const DEMAND_PERMILLE_OF_LIMIT: u32 = 500;

/// 2^32 / 150,000: rpm times increments per turn times this is the velocity in Q32 increments per slow tick (60 s
/// per minute x 2,500 slow ticks per second = 150,000).
const RPM_TO_Q32_PER_COUNT: u64 = 28_633;

/// Main sensor direction supervision. See the module documentation. Its parameters are those the other
/// supervisions read already: bit 8 of 0x3000:04 ([`super::feedback::FeedbackSupervision::main_sensor_supervised`])
/// and 0x606F ([`super::stall::StallSupervision::speed_threshold_rpm`]).
#[derive(Clone, Debug, Default)]
pub struct DirectionSupervision {
    /// Consecutive slow ticks the motor stood (saturating at [`REST_TICKS`]).
    rest_ticks: u8,
    /// Consecutive slow ticks of a watched start running away against a pushing demand.
    away_ticks: u8,
    /// The measured speed of the last tick, Q32 increments per slow tick.
    last_speed: u64,
}

impl DirectionSupervision {
    /// The speed threshold for 0x606F = `speed_threshold_rpm`, Q32 increments per slow tick.
    fn threshold(speed_threshold_rpm: u32, counts_per_turn: u32) -> u64 {
        // 0x606F < 2^16, counts per turn < 2^32 (at most 10^7 configurable), the factor < 2^15: the product stays
        // below 2^63 for any configurable resolution, and wraps (never panics) beyond it.
        let object =
            u64::from(speed_threshold_rpm).wrapping_mul(u64::from(counts_per_turn)).wrapping_mul(RPM_TO_Q32_PER_COUNT);
        object.max(2 << 32)
    }

    /// One slow tick: raises [`FaultId::MainSensorDirection`] when a start from rest turns away against the demand;
    /// `supervised`: bit 8 of 0x3000:04 clear; `speed_threshold_rpm`: 0x606F.
    pub fn step(
        &mut self,
        inputs: &SupervisionInputs,
        supervised: bool,
        speed_threshold_rpm: u32,
        faults: &mut FaultManager,
    ) {
        if !(supervised && inputs.loops_drive_motor) {
            (self.rest_ticks, self.away_ticks) = (0, 0);
            return;
        }
        let velocity = inputs.velocity.0;
        let speed = velocity.unsigned_abs();
        let gaining = speed >= self.last_speed;
        self.last_speed = speed;
        if speed < Self::threshold(speed_threshold_rpm, inputs.encoder_counts_per_turn) {
            (self.rest_ticks, self.away_ticks) = (self.rest_ticks.saturating_add(1).min(REST_TICKS), 0);
            return;
        }
        // The q current the current loop measures, in the frame of the angle it commutates with: where the sensor is
        // right, the motor's torque follows it (an open phase may leave it short of, or against, the demand while
        // the motor turns away: that fault is the phase supervision's to name); a reversed sensor or swapped leads
        // leave it equal to the demand while the motor turns the other way.
        let demand = inputs.i_dq.q.to_bits();
        if self.rest_ticks < REST_TICKS || (demand > 0) == (velocity > 0) {
            // Not from rest, or running with the demand (or without one): a healthy start.
            (self.rest_ticks, self.away_ticks) = (0, 0);
            return;
        }
        // |demand| x 1000 >= limit x 500, i.e. |demand| >= limit / 2 (a limit <= 0 never pushes: 2 x |demand| >= 0
        // holds, so it is excluded first).
        let limit = inputs.current_limit.to_bits();
        let pushing = limit > 0 && u64::from(demand.unsigned_abs()).wrapping_mul(2) >= u64::from(limit.unsigned_abs());
        // A tick that brakes (the speed falls) or pushes weakly restarts the count, the start stays watched.
        self.away_ticks = if pushing && gaining { self.away_ticks.saturating_add(1) } else { 0 };
        if self.away_ticks >= AWAY_TICKS {
            faults.raise(FaultId::MainSensorDirection, inputs.snapshot(inputs.i_dq.q.to_milliamps()), inputs.now);
            (self.rest_ticks, self.away_ticks) = (0, 0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::Ticks;
    use crate::control::frames::{Amps, Dq};
    use crate::control::trajectory::Velocity;
    use crate::od::access::Dictionary;
    use crate::od::generated::handles as h;
    use crate::supervision::feedback::FeedbackSupervision;
    use crate::supervision::feedback::MAIN_SENSOR_SUPERVISION_DISABLED;
    use crate::supervision::stall::StallSupervision;

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

    /// Runs `ticks` slow ticks with `f(now)` and the parameters of `d`; the tick of the first raise.
    fn run_with(d: &Dictionary, ticks: u32, f: impl Fn(u32) -> SupervisionInputs) -> Option<u32> {
        let (feedback, stall) = (FeedbackSupervision::new(d), StallSupervision::new(d));
        let mut s = DirectionSupervision::default();
        let mut faults = FaultManager::new();
        (0..ticks).find(|&now| {
            s.step(&f(now), feedback.main_sensor_supervised(), stall.speed_threshold_rpm(), &mut faults);
            faults.is_active(FaultId::MainSensorDirection)
        })
    }

    /// [`run_with`] the dictionary's defaults.
    fn run(ticks: u32, f: impl Fn(u32) -> SupervisionInputs) -> Option<u32> {
        run_with(&Dictionary::new(1), ticks, f)
    }

    #[test]
    fn threshold_is_0x606f_or_two_increments_per_tick() {
        let object = StallSupervision::new(&Dictionary::new(1)).speed_threshold_rpm();
        assert_eq!(object, 40, "0x606F default");
        // 0x606F = 40 rpm at 4,096 inc/rev is 1.09 increments per tick: two increments (73 rpm) rule.
        assert_eq!(DirectionSupervision::threshold(object, 4096), 2 << 32);
        // At 40,000 inc/rev 40 rpm is 10.7 increments per tick.
        assert_eq!(DirectionSupervision::threshold(object, 40_000) / ((1 << 32) / 1000), 10_666);
    }

    /// The reference drive standing for `rest` ticks, then `f(tick after the rest)` as the inputs.
    fn from_rest(rest: u32, f: impl Fn(u32) -> SupervisionInputs) -> impl Fn(u32) -> SupervisionInputs {
        move |now| if now < rest { at(now, 0, 0.0) } else { SupervisionInputs { now: Ticks(now), ..f(now - rest) } }
    }

    /// IDX 7.2.25: a sensor counting backwards: after 10 ms at rest the loop's demand rises by 1 A per tick while the
    /// measured velocity runs against it by one increment per tick per tick: raised at the fourth tick with the
    /// demand at half the 10 A limit or more and the motor beyond two increments per tick (ticks 25 + 5..=8).
    #[test]
    fn a_start_from_rest_turning_away_against_the_demand_raises_0x7392() {
        let away = |k: u32| at(k, 1_000 * k as i32, -f64::from(k));
        assert_eq!(run(100, from_rest(25, away)), Some(33));
        assert_eq!(FaultId::MainSensorDirection.info().code, 0x7392);
        // Negative demand, the motor turning forward.
        let forward = |k: u32| at(k, -1_000 * k as i32, f64::from(k));
        assert_eq!(run(100, from_rest(25, forward)), Some(33));
    }

    #[test]
    fn healthy_starts_stops_reversals_and_backlash_throws_do_not_raise() {
        // A start with the demand, from rest.
        let start = |k: u32| at(k, 10_000, 0.05 * f64::from(k));
        assert_eq!(run(2000, from_rest(25, start)), None);
        // Braking from 2,000 rpm at the limit through zero speed, and on in the other direction.
        assert_eq!(run(2000, |now| at(now, -10_000, 55.0 - 0.05 * f64::from(now))), None);
        // A reversal thrown back by backlash: braking (demand +), the rotor passes zero in 2 ticks and is thrown
        // back against the demand to 40 increments per tick.
        let thrown = |now: u32| {
            let v = match now {
                0..=9 => -16.0 + 4.0 * f64::from(now),
                10..=11 => 1.0,
                _ => -40.0,
            };
            at(now, 8_000, v)
        };
        assert_eq!(run(100, thrown), None);
        // A light rotor overshooting a held position: the lagging estimate passes the threshold (5 increments per
        // tick) while the loop already brakes at its limit; the speed falls by one increment per tick.
        let overshoot = |k: u32| at(k, -10_000, (5.0 - f64::from(k)).max(0.0));
        assert_eq!(run(100, from_rest(25, overshoot)), None);
        // The same with the speed held for three ticks before it falls: not four in a row.
        let held = |k: u32| at(k, -10_000, if k < 3 { 5.0 } else { (7.0 - f64::from(k)).max(0.0) });
        assert_eq!(run(100, from_rest(25, held)), None);
        // An open phase: the demand pushes at 6 A, the measured q current falls short of half the limit while the
        // motor turns away (the phase supervision names that fault).
        let open = |k: u32| SupervisionInputs {
            i_dq: Dq::new(Amps::ZERO, Amps::from_milliamps(4_000)),
            ..at(k, 6_000, -2.0 - f64::from(k))
        };
        assert_eq!(run(100, from_rest(25, open)), None);
    }

    #[test]
    fn a_weak_demand_too_short_a_rest_or_quantisation_does_not_raise() {
        // Under half the 10 A limit: a load pushing the motor back while the loop builds up its demand.
        let weak = |k: u32| at(k, 4_990, -f64::from(k));
        assert_eq!(run(1000, from_rest(25, weak)), None);
        // 24 ticks at rest: not a start from rest.
        let away = |k: u32| at(k, 6_000, -2.0 - f64::from(k));
        assert_eq!(run(100, from_rest(24, away)), None);
        // Against the demand but within two increments per tick: quantisation of a held position.
        let dither = |now: u32| at(now, 6_000, if now.is_multiple_of(2) { -1.9 } else { 0.0 });
        assert_eq!(run(1000, dither), None);
    }

    #[test]
    fn off_in_cst_and_with_0x3000_04_bit_8() {
        let away = |k: u32| at(k, 6_000, -2.0 - f64::from(k));
        let cst = |now| SupervisionInputs { loops_drive_motor: false, ..from_rest(25, away)(now) };
        assert_eq!(run(100, cst), None);
        let mut d = Dictionary::new(1);
        d.set(h::AXIS_CONFIGURATION_MISC, MAIN_SENSOR_SUPERVISION_DISABLED);
        assert_eq!(run_with(&d, 100, from_rest(25, away)), None);
        // Bit 8 clear again: on again.
        d.set(h::AXIS_CONFIGURATION_MISC, 0u32);
        assert_eq!(run_with(&d, 100, from_rest(25, away)), Some(28));
    }
}
