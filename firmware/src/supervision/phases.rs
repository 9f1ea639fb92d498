//! Motor phase open supervision: a motor lead or winding that no longer carries current (issue 5, "Detection,
//! each in the tier where it belongs").
//!
//! With one phase disconnected its current is zero and the other two carry equal and opposite currents, so the
//! phase currents still sum to zero and tier 1's sum check ([`FaultId::PhaseCurrentImplausible`]) cannot see it;
//! no single sample shows it either (a healthy phase crosses zero twice per electrical turn). It takes a window,
//! which is tier 2's. Two checks, one for a turning and one for a standing current vector:
//!
//! # 1. Balance over one electrical turn (the motor turns)
//! Over a window in which the electrical angle has advanced by at least one full turn, net
//! ([`BALANCE_WINDOW_TURN`]), and that holds at least [`MIN_WINDOW_TICKS`] samples, the mean square of each phase
//! current is accumulated. In a healthy star-connected motor the three phases carry the same current shifted by
//! 120 degrees, and the mean of `sin^2` over any whole number of half turns is 1/2 for every phase, whatever the
//! amplitude, the load angle, the voltage saturation or the back-EMF: so the three mean squares are equal. With a phase
//! open that phase's mean square is the noise's (2 LSB rms of 8 mA: 0.13 % of a sine's at the floor below). A window is
//! **unbalanced** when the smallest mean square is less than 1/16 of the largest (the rms ratio under 1/4) and the
//! largest is above the floor (the rms of a sine of 20 % of the nominal current 0x3001:01: below it the noise decides).
//! Two consecutive unbalanced windows that point at the same phase ([`UNBALANCED_WINDOWS`]) raise the fault.
//!
//! Why no false trip at top speed: this check does not look at the voltage at all. In voltage saturation (the
//! back-EMF near the bus voltage) the currents get smaller and the phase lag grows, but all three phases change
//! alike; if they fall below the floor the window is not judged. The supervision sees one sample per slow tick,
//! 84 degrees apart at 5,000 rpm (583 Hz electrical); a set of `k >= 3` samples spread evenly over a turn has a
//! mean `sin^2` of exactly 1/2, and the [`MIN_WINDOW_TICKS`] samples (5.8 turns at 5,000 rpm) dilute the uneven
//! end of a window. The sampling would alias only at 2 samples per turn (10,700 rpm for the reference motor),
//! twice 0x6080. Load steps and accelerations change the amplitude within a window: the worst case, a current
//! that jumps 10:1 in step with the angle, was searched offline over every period and phase of the jump from 10
//! to 5,000 rpm (the unit test `healthy_motor_with_synchronous_load_steps_does_not_trip` repeats it at six
//! speeds): the largest ratio of mean squares in one window is 10.9, at 300 to 600 rpm, against 16; a real load,
//! coupled through the velocity loop's bandwidth and the rotor's inertia, does not come near it, and one such window is
//! not enough anyway. Windows longer than [`MAX_WINDOW_TICKS`] (below 8.6 rpm for 7 pole pairs) are dropped unjudged: a
//! slow or reversing rotor can dwell at one angle, where the phase currents legitimately differ; check 2 covers it.
//!
//! # 2. Current deficit (the motor stands)
//! At standstill a healthy current vector can point anywhere, including along a phase's zero crossing, so the
//! balance means nothing. But the loop then gets what it asks for, while with a phase open it can only drive
//! current along the one axis left (the line of the two remaining phases): at other angles it saturates its
//! voltage and the current stays below the demand (at the angle where the open phase would carry all of it, at
//! zero). So: the speed below 0x606F (at such speeds the back-EMF is negligible: 40 rpm is 0.09 V for the
//! reference motor, against 13.9 V of phase voltage, so a saturated healthy loop would need `R I` far beyond the
//! bus), the demand `|i_ref|` above the floor (20 % of the nominal current), the voltage limit active and the
//! measured `|i_dq|` under half the demand, for [`DEFICIT_TICKS`] consecutive slow ticks (20 ms: thirty times the
//! winding's L/R, so no current-loop transient lasts that long). A phase open at standstill with the demand along
//! the remaining axis is not seen, and needs not be: the motor then makes the torque it is asked for. A rotor
//! that an open phase stops tends to come to rest where that phase would have carried the current (there the
//! torque is zero), which is where the deficit is largest.
//!
//! Both checks run while the current loop runs with a valid commutation angle, in every mode (CST too).
//!
//! # The fault
//! No other fault of `crate::fault::table` describes an open motor phase: 0x2330 (the phase-current sum) is a
//! sensing or earth fault, 0x7121 (motor blocked) a mechanical one. The detection raises [`PHASE_OPEN_FAULT`]
//! (0x7120 "motor", class d), with the open phase (1 = A, 2 = B, 3 = C) as the snapshot's detail: check 2 names
//! the phase check 1 suspects from a first unbalanced window, or else the one that carries no current while the
//! other two do, and gives 0 (not identified) when nothing flows.

use super::SupervisionInputs;
use crate::control::angle::ElectricalAngle;
use crate::control::frames::Amps;
use crate::fault::{FaultId, FaultManager};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// The fault an open phase raises.
pub const PHASE_OPEN_FAULT: FaultId = FaultId::MotorPhaseOpen;

/// Net electrical travel a balance window needs, in turn bits (one full turn, 2^32).
pub const BALANCE_WINDOW_TURN: i64 = 1 << 32;
/// Fewest samples in a balance window, slow ticks (10 ms: one turn at 600 rpm, 5.8 turns at 5,000 rpm).
pub const MIN_WINDOW_TICKS: u32 = 25;
/// Longest balance window, slow ticks (1 s; one electrical turn per second is 8.6 rpm with 7 pole pairs).
pub const MAX_WINDOW_TICKS: u32 = 2_500;
/// Consecutive unbalanced windows pointing at the same phase before the fault.
pub const UNBALANCED_WINDOWS: u8 = 2;
/// A window is unbalanced when its largest mean square exceeds its smallest this many times (rms ratio 4).
pub const UNBALANCE_RATIO: u64 = 16;
/// Consecutive slow ticks of current deficit at standstill before the fault (20 ms).
pub const DEFICIT_TICKS: u16 = 50;
/// The demand floor of both checks, per mille of the nominal current 0x3001:01.
pub const FLOOR_PERMILLE_OF_NOMINAL: u32 = 200;

/// Right shift from `I16F16` bits before squaring (1/1024 A resolution): a square of the +-16.5 A span is below
/// 2^29, and 2,500 of them below 2^41.
const SQUARE_SHIFT: u32 = 6;

/// Motor phase open supervision. See the module documentation.
#[derive(Clone, Debug, Default)]
pub struct PhaseSupervision {
    /// 0x3001:01 nominal current, mA (to notice changes).
    nominal_ma: u32,
    /// The floor as an `I16F16` amplitude.
    floor: Amps,
    /// The floor as a mean square of a sine of that amplitude, in the shifted units of the sums.
    floor_mean_square: u64,
    /// 0x606F velocity threshold, rpm (standstill for check 2).
    speed_threshold_rpm: u32,
    /// Check 1: the angle of the previous slow tick, while the window runs.
    last_angle: Option<ElectricalAngle>,
    /// Check 1: net electrical travel of the window, turn bits.
    travel: i64,
    /// Check 1: samples in the window.
    samples: u32,
    /// Check 1: per phase, the sum of the squared currents of the window.
    sum_squares: [u64; 3],
    /// Check 1: the phase the last unbalanced windows pointed at, and how many in a row.
    suspect: Option<(usize, u8)>,
    /// Check 2: consecutive slow ticks of deficit.
    deficit_ticks: u16,
}

impl PhaseSupervision {
    /// Over the parameters of `d` (0x3001:01, 0x606F).
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut s = Self::default();
        s.refresh(d);
        s
    }

    /// Re-reads the nominal current 0x3001:01 (the floor) and the velocity threshold 0x606F.
    pub fn refresh(&mut self, d: &Dictionary) {
        self.speed_threshold_rpm = u32::from(d.get(h::VELOCITY_THRESHOLD));
        let nominal_ma = d.get(h::MOTOR_NOMINAL_CURRENT);
        if nominal_ma != self.nominal_ma || self.floor_mean_square == 0 {
            self.nominal_ma = nominal_ma;
            let floor_ma = u64::from(nominal_ma).saturating_mul(u64::from(FLOOR_PERMILLE_OF_NOMINAL)) / 1000;
            self.floor = Amps::from_milliamps(i32::try_from(floor_ma).unwrap_or(i32::MAX));
            let amplitude = u64::from(self.floor.to_bits().unsigned_abs() >> SQUARE_SHIFT);
            // Mean square of a sine: amplitude^2 / 2; at least 1 so that an empty window is never judged.
            self.floor_mean_square = (amplitude.saturating_mul(amplitude) / 2).max(1);
        }
    }

    /// The demand floor of both checks (20 % of the nominal current).
    #[must_use]
    pub const fn floor(&self) -> Amps {
        self.floor
    }

    /// Check 1's unbalanced windows in a row and the phase (0 = A) they point at.
    #[must_use]
    pub const fn suspect(&self) -> Option<(usize, u8)> {
        self.suspect
    }

    /// One slow tick: raises [`PHASE_OPEN_FAULT`] when either check finds an open phase.
    pub fn step(&mut self, inputs: &SupervisionInputs, faults: &mut FaultManager) {
        if !(inputs.operation_enabled && inputs.commutation.is_valid()) {
            self.restart_window();
            self.last_angle = None;
            self.suspect = None;
            self.deficit_ticks = 0;
            return;
        }
        if let Some(phase) = self.balance(inputs) {
            faults.raise(PHASE_OPEN_FAULT, inputs.snapshot(phase_detail(Some(phase))), inputs.now);
        }
        if self.deficit(inputs) {
            // The phase check 1 suspects from a first unbalanced window, else the one without current now.
            let phase = self.suspect.map(|(phase, _)| phase).or_else(|| self.silent_phase(inputs));
            faults.raise(PHASE_OPEN_FAULT, inputs.snapshot(phase_detail(phase)), inputs.now);
        }
    }

    fn restart_window(&mut self) {
        self.travel = 0;
        self.samples = 0;
        self.sum_squares = [0; 3];
    }

    /// Check 1: accumulates this tick's sample; at the end of a window judges it. The open phase (0 = A) once
    /// [`UNBALANCED_WINDOWS`] windows in a row found it.
    fn balance(&mut self, inputs: &SupervisionInputs) -> Option<usize> {
        let angle = inputs.electrical_angle;
        let previous = self.last_angle.replace(angle);
        let Some(previous) = previous else {
            // The first sample only starts the window (no travel to measure yet).
            self.restart_window();
            return None;
        };
        // At most 0.23 turn per slow tick at 5,000 rpm: the wrapping difference is the travel.
        let step = i64::from(angle.difference(previous).turn_bits());
        if (step > 0 && self.travel < 0) || (step < 0 && self.travel > 0) {
            // A reversal: the rotor dwelt near one angle while the current turned it round, so the phases
            // legitimately differ over this window (a light rotor reverses within a few ms); no verdict, as for
            // a window too slow to judge.
            self.restart_window();
            self.suspect = None;
            return None;
        }
        self.travel = self.travel.saturating_add(step);
        self.samples = self.samples.saturating_add(1);
        let i = inputs.i_abc;
        for (sum, x) in self.sum_squares.iter_mut().zip([i.a, i.b, i.c]) {
            let m = u64::from(x.to_bits().unsigned_abs() >> SQUARE_SHIFT);
            *sum = sum.saturating_add(m.saturating_mul(m));
        }
        if self.travel.unsigned_abs() < BALANCE_WINDOW_TURN.unsigned_abs() || self.samples < MIN_WINDOW_TICKS {
            if self.samples >= MAX_WINDOW_TICKS {
                // Too slow to judge (see the module documentation): no verdict, and no longer "in a row".
                self.restart_window();
                self.suspect = None;
            }
            return None;
        }
        let verdict = judge(&self.sum_squares, self.samples, self.floor_mean_square);
        self.restart_window();
        self.suspect = match (verdict, self.suspect) {
            (Some(phase), Some((p, n))) if p == phase => Some((phase, n.saturating_add(1))),
            (Some(phase), _) => Some((phase, 1)),
            (None, _) => None,
        };
        match self.suspect {
            Some((phase, n)) if n >= UNBALANCED_WINDOWS => {
                self.suspect = None;
                Some(phase)
            }
            _ => None,
        }
    }

    /// Check 2: whether the deficit has lasted [`DEFICIT_TICKS`].
    fn deficit(&mut self, inputs: &SupervisionInputs) -> bool {
        let magnitude_sq = |d: i32, q: i32| {
            let (d, q) = (i64::from(d), i64::from(q));
            // |bits| < 2^31: each square < 2^62, their sum saturates at worst.
            d.saturating_mul(d).saturating_add(q.saturating_mul(q))
        };
        let demand = magnitude_sq(inputs.i_ref.d.to_bits(), inputs.i_ref.q.to_bits());
        let measured = magnitude_sq(inputs.i_dq.d.to_bits(), inputs.i_dq.q.to_bits());
        let floor = i64::from(self.floor.to_bits());
        let standing = inputs.velocity_rpm.unsigned_abs() < self.speed_threshold_rpm;
        // Under half the demand: |i_dq|^2 < |i_ref|^2 / 4.
        let short_of_demand = measured.saturating_mul(4) < demand;
        if standing && inputs.saturated && demand > floor.saturating_mul(floor) && short_of_demand {
            self.deficit_ticks = self.deficit_ticks.saturating_add(1);
        } else {
            self.deficit_ticks = 0;
        }
        if self.deficit_ticks >= DEFICIT_TICKS {
            self.deficit_ticks = 0;
            return true;
        }
        false
    }
}

impl PhaseSupervision {
    /// At rest with one phase open, the other two carry the same current in opposite directions and the open one
    /// none: the phase (0 = A) whose current is under a quarter of the largest, when the largest is above an
    /// eighth of the floor (well over the measurement noise); `None` when nothing flows.
    fn silent_phase(&self, inputs: &SupervisionInputs) -> Option<usize> {
        let i = inputs.i_abc;
        let magnitudes = [i.a, i.b, i.c].map(|x| x.to_bits().unsigned_abs());
        let largest = magnitudes.iter().copied().max().unwrap_or(0);
        let (phase, smallest) = magnitudes.iter().copied().enumerate().min_by_key(|&(_, m)| m)?;
        let flowing = largest >= (self.floor.to_bits().unsigned_abs() >> 3);
        (flowing && smallest.saturating_mul(4) < largest).then_some(phase)
    }
}

/// The snapshot's detail for an open phase (0 = A): 1 = A, 2 = B, 3 = C; 0 when not identified.
fn phase_detail(phase: Option<usize>) -> i32 {
    phase.map_or(0, |p| i32::try_from(p).unwrap_or(-1).saturating_add(1))
}

/// The phase (0 = A) whose mean square is under 1/[`UNBALANCE_RATIO`] of the largest, if the largest is above
/// `floor_mean_square` (all three sums over the same `samples`, so they compare directly).
fn judge(sum_squares: &[u64; 3], samples: u32, floor_mean_square: u64) -> Option<usize> {
    let max = sum_squares.iter().copied().max().unwrap_or(0);
    let (phase, min) = sum_squares.iter().copied().enumerate().min_by_key(|&(_, s)| s)?;
    let loud_enough = max >= floor_mean_square.saturating_mul(u64::from(samples));
    (loud_enough && min.saturating_mul(UNBALANCE_RATIO) < max).then_some(phase)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::Ticks;
    use crate::control::frames::{Abc, Dq};
    use crate::power_state::CommutationStage;

    const TURN: f64 = 4_294_967_296.0;

    fn amps(a: f64) -> Amps {
        Amps::from_bits((a * 65536.0).round() as i32)
    }

    /// The reference drive running with an indexed commutation.
    fn base() -> SupervisionInputs {
        SupervisionInputs::reference_running()
    }

    /// Slow tick `n` of a rotor at `rpm` (7 pole pairs) with a q current of amplitude `i_q`; `open` zeroes one
    /// phase and gives the other two what the remaining axis carries (the projection of the vector on it).
    fn running(n: u32, rpm: f64, i_q: f64, open: Option<usize>) -> SupervisionInputs {
        let theta = 2.0 * core::f64::consts::PI * (rpm / 60.0 * 7.0 * f64::from(n) / 2500.0 + 0.123);
        // The current vector on the q axis: angle theta + 90 degrees.
        let (s, c) = (theta + core::f64::consts::FRAC_PI_2).sin_cos();
        let (alpha, beta) = (i_q * c, i_q * s);
        let mut abc = [alpha, -0.5 * alpha + 0.866_025 * beta, -0.5 * alpha - 0.866_025 * beta];
        if let Some(x) = open {
            // Only the difference of the other two survives: i_y = -i_z = (i_y - i_z) / 2.
            let (y, z) = ((x + 1) % 3, (x + 2) % 3);
            let d = 0.5 * (abc[y] - abc[z]);
            abc = [0.0; 3];
            abc[y] = d;
            abc[z] = -d;
        }
        SupervisionInputs {
            now: Ticks(n),
            electrical_angle: ElectricalAngle(((theta / (2.0 * core::f64::consts::PI)).rem_euclid(1.0) * TURN) as u32),
            i_abc: Abc::new(amps(abc[0]), amps(abc[1]), amps(abc[2])),
            i_ref: Dq::new(Amps::ZERO, amps(i_q)),
            i_dq: Dq::new(Amps::ZERO, amps(i_q)),
            velocity_rpm: rpm as i32,
            ..base()
        }
    }

    fn supervision() -> PhaseSupervision {
        PhaseSupervision::new(&Dictionary::new(1))
    }

    /// Runs ticks `0..ticks` of `f`; the first tick with the fault active.
    fn run(s: &mut PhaseSupervision, ticks: u32, f: impl Fn(u32) -> SupervisionInputs) -> Option<u32> {
        let mut faults = FaultManager::new();
        (0..ticks).find(|&n| {
            s.step(&f(n), &mut faults);
            faults.is_active(PHASE_OPEN_FAULT)
        })
    }

    #[test]
    fn floor_of_the_reference_motor() {
        let s = supervision();
        assert_eq!(s.floor().to_milliamps(), 640);
        // (640 mA in 1/1024 A)^2 / 2.
        assert_eq!(s.floor_mean_square, 655 * 655 / 2);
    }

    #[test]
    fn open_phase_found_in_two_turns_at_300_rpm() {
        for open in 0..3 {
            let mut s = supervision();
            // 300 rpm: 35 Hz electrical, 71.4 slow ticks per turn. Window 1 starts at tick 1 (the first sample
            // only sets the angle), so the second window ends at tick 144.
            let at = run(&mut s, 2500, |n| running(n, 300.0, 1.5, Some(open)));
            assert_eq!(at, Some(144), "phase {open}");
        }
    }

    #[test]
    fn detail_names_the_open_phase() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        for n in 0..200 {
            s.step(&running(n, 300.0, 1.5, Some(1)), &mut faults);
        }
        let a = faults.active().find(|a| a.id == PHASE_OPEN_FAULT).expect("raised");
        assert_eq!(a.snapshot.detail, 2, "phase B");
    }

    #[test]
    fn healthy_motor_never_trips_from_10_to_6000_rpm() {
        // Every speed from 10 rpm (a 0.86 s window) to beyond 0x6080, in steps that hit the aliasing-prone
        // ratios of the sample rate (4, 5, 6, 7 samples per turn), at 1.5 A and reversed.
        let mut rpm = 10.0;
        while rpm <= 6000.0 {
            for sign in [1.0, -1.0] {
                let mut s = supervision();
                assert_eq!(run(&mut s, 5000, |n| running(n, sign * rpm, 1.5, None)), None, "{rpm} rpm");
            }
            rpm += if rpm < 500.0 { 10.0 } else { 7.0 };
        }
        for samples_per_turn in [4.0, 5.0, 6.0, 7.0, 8.0] {
            let rpm = 2500.0 / samples_per_turn / 7.0 * 60.0;
            let mut s = supervision();
            assert_eq!(run(&mut s, 5000, |n| running(n, rpm, 1.5, None)), None, "{rpm} rpm");
        }
    }

    #[test]
    fn healthy_motor_with_synchronous_load_steps_does_not_trip() {
        // The amplitude jumps between 0.7 A and 7 A every `period` slow ticks, for every period up to 80 ticks
        // and several phases of the jump: the worst a load in step with the angle can do to the balance (ratio
        // of mean squares up to 10.9 at 300 to 600 rpm, against 16).
        for rpm in [60.0, 300.0, 600.0, 1000.0, 3000.0, 5000.0] {
            for period in (1..80).step_by(2) {
                for offset in [0, 4, 8, 12, 16] {
                    let mut s = supervision();
                    let amplitude = |n: u32| if ((n + offset) / period).is_multiple_of(2) { 0.7 } else { 7.0 };
                    let at = run(&mut s, 3000, |n| running(n, rpm, amplitude(n), None));
                    assert_eq!(at, None, "{rpm} rpm, period {period}, offset {offset}");
                }
            }
        }
    }

    #[test]
    fn short_windows_at_speed_hold_at_least_ten_ms() {
        // 3,000 rpm: 7.1 samples per turn, so a window closes at the 25th sample (and the first, tick 0, only
        // sets the angle): the second window ends at tick 50.
        let mut s = supervision();
        assert_eq!(run(&mut s, 2500, |n| running(n, 3000.0, 1.5, Some(2))), Some(50));
    }

    #[test]
    fn small_currents_are_not_judged() {
        let mut s = supervision();
        assert_eq!(run(&mut s, 5000, |n| running(n, 300.0, 0.5, Some(0))), None, "under the 0.64 A floor");
    }

    #[test]
    fn a_standing_vector_is_not_judged_by_the_balance() {
        // Standstill with the vector along phase A's zero crossing: phase A carries nothing, healthily.
        let mut s = supervision();
        assert_eq!(run(&mut s, 10_000, |n| running(n, 0.0, 3.0, None)), None);
        assert_eq!(s.suspect(), None);
    }

    #[test]
    fn deficit_at_standstill_after_20_ms() {
        let mut s = supervision();
        let stuck = |n| SupervisionInputs {
            now: Ticks(n),
            i_ref: Dq::new(Amps::ZERO, amps(5.0)),
            i_dq: Dq::new(Amps::ZERO, amps(0.3)),
            saturated: true,
            ..base()
        };
        assert_eq!(run(&mut s, 1000, stuck), Some(u32::from(DEFICIT_TICKS) - 1));
    }

    /// Check 2 names the phase without current at rest (the other two carry the same current in opposite
    /// directions), and 0 when no phase carries anything measurable (under an eighth of the 640 mA floor).
    #[test]
    fn deficit_names_the_silent_phase() {
        for (abc, detail) in [
            ([1.2, -1.2, 0.0], 3),
            ([0.0, 0.9, -0.9], 1),
            ([0.5, 0.01, -0.5], 2),
            ([0.05, -0.05, 0.0], 0),
            ([0.0, 0.0, 0.0], 0),
        ] {
            let mut s = supervision();
            let mut faults = FaultManager::new();
            for n in 0..u32::from(DEFICIT_TICKS) {
                let inputs = SupervisionInputs {
                    now: Ticks(n),
                    i_abc: Abc::new(amps(abc[0]), amps(abc[1]), amps(abc[2])),
                    i_ref: Dq::new(Amps::ZERO, amps(5.0)),
                    i_dq: Dq::new(Amps::ZERO, amps(0.3)),
                    saturated: true,
                    ..base()
                };
                s.step(&inputs, &mut faults);
            }
            let a = faults.active().find(|a| a.id == PHASE_OPEN_FAULT).expect("raised");
            assert_eq!(a.snapshot.detail, detail, "{abc:?}");
        }
    }

    #[test]
    fn no_deficit_when_moving_unsaturated_or_half_served() {
        let deficit = SupervisionInputs {
            i_ref: Dq::new(Amps::ZERO, amps(5.0)),
            i_dq: Dq::new(Amps::ZERO, amps(0.3)),
            saturated: true,
            ..base()
        };
        for (what, inputs) in [
            // Top speed in voltage saturation: the back-EMF eats the voltage, the current lags far behind.
            ("moving", SupervisionInputs { velocity_rpm: 5000, ..deficit }),
            ("unsaturated", SupervisionInputs { saturated: false, ..deficit }),
            ("more than half", SupervisionInputs { i_dq: Dq::new(amps(1.5), amps(2.1)), ..deficit }),
            ("under the floor", SupervisionInputs { i_ref: Dq::new(Amps::ZERO, amps(0.6)), ..deficit }),
            ("disabled", SupervisionInputs { operation_enabled: false, ..deficit }),
            ("aligning", SupervisionInputs { commutation: CommutationStage::Aligning, ..deficit }),
        ] {
            let mut s = supervision();
            assert_eq!(run(&mut s, 1000, |n| SupervisionInputs { now: Ticks(n), ..inputs }), None, "{what}");
        }
    }

    #[test]
    fn judge_thresholds() {
        let floor = 100;
        assert_eq!(judge(&[0, 1600, 1600], 1, floor), Some(0));
        assert_eq!(judge(&[1600, 99, 1600], 1, floor), Some(1));
        assert_eq!(judge(&[1600, 1600, 100], 1, floor), None, "rms ratio exactly 4");
        assert_eq!(judge(&[0, 99, 99], 1, floor), None, "under the floor");
        assert_eq!(judge(&[0, 0, 0], 0, 1), None, "empty");
    }
}
