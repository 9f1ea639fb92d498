//! Switching pattern of one inverter leg over one PWM period: TIM1 centre-aligned PWM with dead-time insertion.
//!
//! The counter runs 0 -> ARR -> 0 over one period T (ARR = [`PWM_PERIOD_TICKS`]); the period starts at the valley
//! (counter 0, update event). In PWM mode 1 the reference is active (high switch) while `CNT < CCR`, so a compare
//! value `c` with `0 < c < ARR` gives: high on `[0, t1)`, low on `[t1, T - t1)`, high on `[T - t1, T)` with
//! `t1 = c / ARR * T / 2`: the high-side on-time fraction is `c / ARR` and the low switches are all on at the centre,
//! where the shunts are sampled. `c = 0` keeps the low switch on all period, `c >= ARR` the high switch.
//!
//! Dead time: at every change of the reference, the conducting switch turns off at once and the complementary one
//! turns on `dead_time` later (TIM1's dead-time generator delays rising edges). In between, the leg is
//! [`LegState::Off`] and its voltage is set by the body diode that carries the phase current. A reference pulse
//! shorter than the dead time never turns its switch on. A change of reference level across the update event
//! (e.g. a compare value going from 0 to non-zero, or outputs being enabled) is an edge at the start of the period.

use firmware::hal::power::PWM_PERIOD_TICKS;

/// What a leg conducts through during one piece of the period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LegState {
    /// High-side switch on: pole at the bus voltage.
    High,
    /// Low-side switch on: pole at the negative rail (through the shunt).
    Low,
    /// Both switches off (dead time): the body diodes decide, by the sign of the phase current.
    Off,
}

/// The piecewise-constant state of one leg over one period, as pieces `[previous end, end)`.
#[derive(Clone, Copy, Debug)]
pub struct LegPattern {
    ends: [f64; Self::MAX_PIECES],
    states: [LegState; Self::MAX_PIECES],
    len: usize,
}

impl LegPattern {
    /// Most pieces a leg can have in one period: an edge at the start and two more in the period, each adding a
    /// dead-time piece.
    pub const MAX_PIECES: usize = 6;

    /// All switches off for the whole period (outputs disabled).
    pub fn off(period_s: f64) -> Self {
        let mut p = Self { ends: [0.0; Self::MAX_PIECES], states: [LegState::Off; Self::MAX_PIECES], len: 0 };
        p.push(period_s, LegState::Off);
        p
    }

    fn push(&mut self, end: f64, state: LegState) {
        if self.len > 0 && self.states[self.len - 1] == state {
            self.ends[self.len - 1] = end;
        } else if self.len < Self::MAX_PIECES {
            self.ends[self.len] = end;
            self.states[self.len] = state;
            self.len += 1;
        }
    }

    /// The pattern of a leg with compare value `compare` in this period, given the reference level the leg had
    /// at the end of the previous period (`None`: the outputs were disabled). Returns the pattern and the reference
    /// level at the end of this period.
    pub fn new(compare: u16, previous_level: Option<bool>, period_s: f64, dead_time_s: f64) -> (Self, bool) {
        let arr = PWM_PERIOD_TICKS;
        let c = compare.min(arr);
        // Reference intervals (end time, high?) and whether the first one starts with an edge.
        let mut intervals = [(0.0, false); 3];
        let n = if c == 0 {
            intervals[0] = (period_s, false);
            1
        } else if c >= arr {
            intervals[0] = (period_s, true);
            1
        } else {
            let t1 = f64::from(c) / f64::from(arr) * period_s * 0.5;
            intervals[0] = (t1, true);
            intervals[1] = (period_s - t1, false);
            intervals[2] = (period_s, true);
            3
        };
        let start_level = intervals[0].1;
        let mut pattern = Self { ends: [0.0; Self::MAX_PIECES], states: [LegState::Off; Self::MAX_PIECES], len: 0 };
        let mut start = 0.0;
        for (i, &(end, high)) in intervals.iter().take(n).enumerate() {
            let edge = i > 0 || previous_level != Some(start_level);
            let on_state = if high { LegState::High } else { LegState::Low };
            if edge {
                let off_end = (start + dead_time_s).min(end);
                if off_end > start {
                    pattern.push(off_end, LegState::Off);
                }
                if end > off_end {
                    pattern.push(end, on_state);
                }
            } else {
                pattern.push(end, on_state);
            }
            start = end;
        }
        (pattern, intervals[n - 1].1)
    }

    /// The end times of the pieces, in order (the last is the period end).
    pub fn boundaries(&self) -> &[f64] {
        &self.ends[..self.len]
    }

    /// The state at time `t` (use the midpoint of a segment).
    pub fn state_at(&self, t: f64) -> LegState {
        for (&end, &state) in self.ends[..self.len].iter().zip(&self.states[..self.len]) {
            if t < end {
                return state;
            }
        }
        self.states[self.len.saturating_sub(1)]
    }

    /// Total time spent in `state` over the period, in s.
    pub fn time_in(&self, state: LegState) -> f64 {
        let mut start = 0.0;
        let mut total = 0.0;
        for (&end, &s) in self.ends[..self.len].iter().zip(&self.states[..self.len]) {
            if s == state {
                total += end - start;
            }
            start = end;
        }
        total
    }
}

impl LegState {
    /// The pole voltage (leg output to the negative rail) in this state, ignoring the switch resistance: the bus
    /// voltage (high switch), 0 (low switch) or, in dead time, the rail of the body diode that carries
    /// `leg_current` (positive out of the pole: the lower diode, `-v_diode`; negative: the upper one,
    /// `v_bus + v_diode`); a leg in dead time without current is taken at mid-bus.
    pub fn pole_voltage(self, leg_current: f64, v_bus: f64, v_diode: f64) -> f64 {
        match self {
            Self::High => v_bus,
            Self::Low => 0.0,
            Self::Off if leg_current > 0.0 => -v_diode,
            Self::Off if leg_current < 0.0 => v_bus + v_diode,
            Self::Off => 0.5 * v_bus,
        }
    }
}

/// Two inverter outputs shorted together through a resistance (`super::faults::PlantFaults::phase_short`): a
/// cable or insulation fault between two motor leads, or a solder bridge on the board.
///
/// Model: a pure resistance `R` between the two poles, no inductance (a short is a few centimetres of conductor, its
/// microhenries are negligible next to the motor's 165 uH). While the legs switch, their poles are stiff (switch
/// on) or clamped by a body diode, so the short carries `(u_x - u_y) / (R + 2 R_switch)`: out of the pole at the
/// higher voltage through its high switch, into the other through its low switch and its shunt. It does not
/// change the motor currents (the poles are imposed by the switches), only what the legs, their shunts and the
/// bus carry; the dead-time diodes stay chosen by the motor current alone (the short current, when both legs are
/// in different states, is already through the switches). With the outputs off (all switches open) the short
/// only connects two motor terminals through the diode bridge; that braking path is not modelled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputShort {
    /// The shorted legs (0..=2, distinct).
    legs: (usize, usize),
    /// The short's resistance plus the two switches in its path, in ohm.
    loop_ohm: f64,
}

impl OutputShort {
    /// The short of the injected fault `(phase, phase, ohm)` with switches of `r_switch_ohm`; `None` without a fault,
    /// for legs outside 0..=2 or equal, and for a resistance that is negative, not finite or leaves no loop
    /// resistance at all.
    pub fn new(fault: Option<(usize, usize, f64)>, r_switch_ohm: f64) -> Option<Self> {
        let (x, y, ohm) = fault?;
        let loop_ohm = ohm + 2.0 * r_switch_ohm;
        (x < 3 && y < 3 && x != y && ohm >= 0.0 && loop_ohm > 0.0 && loop_ohm.is_finite())
            .then_some(Self { legs: (x, y), loop_ohm })
    }

    /// The current each leg delivers into the short (out of its pole, in A) with the poles at `poles` (V): `+i` for
    /// the first leg, `-i` for the second, 0 for the third.
    pub fn leg_currents(&self, poles: [f64; 3]) -> [f64; 3] {
        let (x, y) = self.legs;
        let i = (poles[x] - poles[y]) / self.loop_ohm;
        let mut out = [0.0; 3];
        out[x] = i;
        out[y] = -i;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_short_carries_the_pole_difference() {
        // A high, B low on a 24 V bus through 0.1 ohm and two 10 mOhm switches: 200 A out of A, into B.
        let short = OutputShort::new(Some((0, 1, 0.1)), 0.01).expect("a valid short");
        let i = short.leg_currents([24.0, 0.0, 12.0]);
        assert!((i[0] - 200.0).abs() < 1e-9 && (i[1] + 200.0).abs() < 1e-9 && i[2] == 0.0, "{i:?}");
        // Both low (the sample instant): nothing flows.
        assert_eq!(short.leg_currents([0.0, 0.0, 24.0]), [0.0, 0.0, 0.0]);
        assert!(OutputShort::new(Some((1, 1, 0.1)), 0.01).is_none());
        assert!(OutputShort::new(Some((0, 3, 0.1)), 0.01).is_none());
        assert!(OutputShort::new(Some((0, 1, -1.0)), 0.01).is_none());
        assert!(OutputShort::new(None, 0.01).is_none());
    }

    #[test]
    fn pole_voltage_of_each_state() {
        assert_eq!(LegState::High.pole_voltage(-1.0, 24.0, 0.7), 24.0);
        assert_eq!(LegState::Low.pole_voltage(1.0, 24.0, 0.7), 0.0);
        assert_eq!(LegState::Off.pole_voltage(1.0, 24.0, 0.7), -0.7);
        assert_eq!(LegState::Off.pole_voltage(-1.0, 24.0, 0.7), 24.7);
        assert_eq!(LegState::Off.pole_voltage(0.0, 24.0, 0.7), 12.0);
    }

    const T: f64 = 40e-6;
    const TD: f64 = 0.5e-6;

    #[test]
    fn half_duty_continuing_high() {
        let (p, end) = LegPattern::new(1680, Some(true), T, TD);
        assert!(end);
        assert_eq!(p.state_at(1e-6), LegState::High);
        assert_eq!(p.state_at(10.2e-6), LegState::Off);
        assert_eq!(p.state_at(20e-6), LegState::Low);
        assert_eq!(p.state_at(30.2e-6), LegState::Off);
        assert_eq!(p.state_at(39e-6), LegState::High);
        assert!((p.time_in(LegState::High) - (0.5 * T - TD)).abs() < 1e-15);
        assert!((p.time_in(LegState::Low) - (0.5 * T - TD)).abs() < 1e-15);
        assert!((p.time_in(LegState::Off) - 2.0 * TD).abs() < 1e-15);
    }

    #[test]
    fn enabling_inserts_an_edge_at_the_start() {
        let (p, _) = LegPattern::new(1680, None, T, TD);
        assert_eq!(p.state_at(0.1e-6), LegState::Off);
        assert_eq!(p.state_at(1e-6), LegState::High);
        let (p, end) = LegPattern::new(0, Some(true), T, TD);
        assert!(!end);
        assert_eq!(p.state_at(0.1e-6), LegState::Off);
        assert!((p.time_in(LegState::Low) - (T - TD)).abs() < 1e-15);
        let (p, _) = LegPattern::new(0, Some(false), T, TD);
        assert_eq!(p.time_in(LegState::Low), T);
        let (p, _) = LegPattern::new(4000, Some(true), T, TD);
        assert_eq!(p.time_in(LegState::High), T);
    }

    #[test]
    fn pulse_shorter_than_dead_time_is_swallowed() {
        // 10 ticks: high reference for 2 x 10 / 168 MHz = 0.119 us in total, less than the dead time.
        let (p, _) = LegPattern::new(10, Some(true), T, TD);
        assert!((p.time_in(LegState::High) - 10.0 / 3360.0 * T * 0.5).abs() < 1e-15);
        let (p, _) = LegPattern::new(3355, Some(true), T, TD);
        assert_eq!(p.time_in(LegState::Low), 0.0);
        assert_eq!(p.boundaries()[0], 3355.0 / 3360.0 * T * 0.5);
    }
}
