//! One integration segment with the outputs switching: each leg's pole set by its switch or, in dead time, by the
//! body diode that carries its current; a leg in dead time without current floating with the motor; the injected
//! open phase and output short ([`super::faults::PlantFaults`]); the diodes blocking reverse current at the end of
//! the segment; and the segment's share of the period averages.

use super::coeffs::Coeffs;
use super::electrical::{
    abc_to_dq, back_emf, dq_to_abc, open_phase_terminal, remove_phase_current, rk4, LegDrive, SegmentAngle,
    ZERO_CURRENT_A,
};
use super::inverter::{LegPattern, LegState, OutputShort};
use super::mechanics::ShaftSegment;
use super::{PeriodAverages, Plant};

impl Plant {
    /// One RK4 segment `[t0, t1)` with the outputs switching; returns the currents out of the three legs at its end
    /// (the phase currents, plus a short's share, [`OutputShort`]): what the over-current comparator sees.
    ///
    /// A disconnected phase ([`super::faults::PlantFaults::phase_open`]) is a leg whose motor terminal floats at
    /// [`open_phase_terminal`], recomputed at every RK4 stage, draws nothing from the bus, and ends every segment at
    /// exactly zero current (the projection of [`Plant::stop_phases`], as for a diode that stopped conducting). The
    /// current a phase carried when it was opened is cut at once (the arc of a real break lasts microseconds; its
    /// energy is dropped).
    pub(super) fn segment_switching(
        &mut self,
        k: &Coeffs,
        patterns: &[LegPattern; 3],
        t0: f64,
        t1: f64,
        acc: &mut PeriodAverages,
    ) -> [f64; 3] {
        let h = t1 - t0;
        let mid = 0.5 * (t0 + t1);
        let angle = SegmentAngle::new(k.p * self.theta_m);
        let i0 = dq_to_abc(self.i_d, self.i_q, angle.sin, angle.cos);
        let (mut legs, off, mut floating) = legs_at(patterns, mid, i0, k.v_diode);
        // Injected faults: a disconnected phase is taken out of the neutral of the floating legs below.
        let open = self.faults.phase_open.filter(|&x| x < 3);
        if let Some(x) = open {
            floating[x] = true;
        }
        let short = OutputShort::new(self.faults.phase_short, k.r_switch);
        if floating.iter().any(|f| *f) {
            // Back-EMF frozen over the segment (at most the 0.5 us dead time).
            let e0 = back_emf(k.p * self.omega_m, k.psi, angle.sin, angle.cos);
            drive_floating_legs(&mut legs, &mut floating, e0, self.v_bus, k.v_diode);
        }
        // The inverter's poles (what the averages and a short see); the motor terminal of an open phase is
        // computed in the stages.
        let inverter_legs = legs;
        if let Some(x) = open {
            legs[x] = LegDrive::default();
        }
        let segment = SwitchingSegment { k, legs, inverter_legs, open, short, angle, shaft: self.shaft_segment(k) };
        let (omega_before, omega_l_before) = (self.omega_m, self.omega_l);
        let s0 = [self.i_d, self.i_q, self.omega_m, self.theta_m, self.v_bus, self.omega_l, self.theta_l];
        let s1 = rk4(&s0, h, |s: &[f64; 7]| segment.derivatives(s));
        [self.i_d, self.i_q, self.omega_m, self.theta_m, self.v_bus, self.omega_l, self.theta_l] = s1;
        self.end_segment(k, &segment.shaft, omega_before, omega_l_before);
        let (sn1, cs1) = angle.sin_cos_at(k.p * s1[3]);
        let mut i1 = dq_to_abc(self.i_d, self.i_q, sn1, cs1);
        let stopped = stopped_phases(&legs, off, floating, open, i1);
        self.stop_phases(stopped, &mut i1, sn1, cs1);
        segment.accumulate_averages(acc, h, &s0, &s1, i0, i1);
        segment.leg_currents(i1, self.v_bus)
    }

    /// Diodes block reverse current: each phase in `stopped` ends the segment at exactly zero current. One such
    /// phase: the current vector `i1` (at the electrical angle of sine `sn1` and cosine `cs1`) is projected onto the
    /// plane `i_x = 0`; two or three leave no current at all. Sets the plant's dq currents and `i1` to the result.
    fn stop_phases(&mut self, stopped: [bool; 3], i1: &mut [f64; 3], sn1: f64, cs1: f64) {
        match stopped.iter().filter(|s| **s).count() {
            0 => {}
            1 => {
                let x = stopped.iter().position(|s| *s).unwrap_or(0);
                remove_phase_current(i1, x);
                [self.i_d, self.i_q] = abc_to_dq(*i1, sn1, cs1);
            }
            _ => {
                *i1 = [0.0; 3];
                self.i_d = 0.0;
                self.i_q = 0.0;
            }
        }
    }
}

/// Each leg's drive over a segment, from its state at the segment's midpoint `mid` and the phase currents `i0` at
/// the segment's start: its switch, or in dead time the body diode that carries its current. Returns the drives,
/// which legs are in dead time, and which of those carry no current: they float, their drive still to be found
/// ([`drive_floating_legs`]).
fn legs_at(patterns: &[LegPattern; 3], mid: f64, i0: [f64; 3], v_diode: f64) -> ([LegDrive; 3], [bool; 3], [bool; 3]) {
    let upper_diode = LegDrive::upper_diode(v_diode);
    let lower_diode = LegDrive::lower_diode(v_diode);
    let mut legs = [LegDrive::default(); 3];
    let mut off = [false; 3];
    let mut floating = [false; 3];
    for x in 0..3 {
        let state = patterns[x].state_at(mid);
        off[x] = state == LegState::Off;
        legs[x] = match state {
            LegState::High => LegDrive::HIGH,
            LegState::Low => LegDrive::LOW,
            LegState::Off if i0[x] < -ZERO_CURRENT_A => upper_diode,
            LegState::Off if i0[x] > ZERO_CURRENT_A => lower_diode,
            LegState::Off => {
                floating[x] = true;
                LegDrive::default()
            }
        };
    }
    (legs, off, floating)
}

/// A leg in dead time with no current floats: its terminal follows the motor (back-EMF `e0` plus the neutral set
/// by the driven legs) so that its current stays zero, unless that would pass a rail of the bus at `v_bus`, where
/// its diode starts to conduct (then it no longer floats). Sets the drive of every floating leg.
fn drive_floating_legs(legs: &mut [LegDrive; 3], floating: &mut [bool; 3], e0: [f64; 3], v_bus: f64, v_diode: f64) {
    let n_fixed = floating.iter().filter(|f| !**f).count();
    let (mut a_n, mut b_n) = (0.5, 0.0);
    if n_fixed > 0 {
        (a_n, b_n) = (0.0, 0.0);
        for x in (0..3).filter(|&x| !floating[x]) {
            a_n += legs[x].a / n_fixed as f64;
            b_n += (legs[x].b - e0[x]) / n_fixed as f64;
        }
    }
    for x in 0..3 {
        if !floating[x] {
            continue;
        }
        let leg = LegDrive { a: a_n, b: e0[x] + b_n, c: 0.0 };
        let u = leg.a * v_bus + leg.b;
        if u > v_bus + v_diode {
            legs[x] = LegDrive::upper_diode(v_diode);
            floating[x] = false;
        } else if u < -v_diode {
            legs[x] = LegDrive::lower_diode(v_diode);
            floating[x] = false;
        } else {
            legs[x] = leg;
        }
    }
}

/// The phases that end the segment at exactly zero current, given the phase currents `i1` at its end: a leg in
/// dead time whose current reached zero (or that floated), and a disconnected phase.
fn stopped_phases(
    legs: &[LegDrive; 3],
    off: [bool; 3],
    floating: [bool; 3],
    open: Option<usize>,
    i1: [f64; 3],
) -> [bool; 3] {
    let mut stopped = [false; 3];
    for x in 0..3 {
        // The diode conducting in dead time carries a negative current (upper) or a positive one (lower).
        let diode_sign = if legs[x].c != 0.0 { -1.0 } else { 1.0 };
        stopped[x] = off[x] && (floating[x] || i1[x] * diode_sign <= 0.0);
    }
    if let Some(x) = open {
        stopped[x] = true;
    }
    stopped
}

/// How the inverter drives the motor over one segment with the outputs switching.
struct SwitchingSegment<'a> {
    k: &'a Coeffs,
    /// The drive of the motor terminals (an open phase's is zero: its terminal is computed in the stages).
    legs: [LegDrive; 3],
    /// The drive of the inverter's poles (what the averages and a short see).
    inverter_legs: [LegDrive; 3],
    /// The disconnected phase ([`super::faults::PlantFaults::phase_open`]).
    open: Option<usize>,
    /// The short between two outputs ([`super::faults::PlantFaults::phase_short`]).
    short: Option<OutputShort>,
    /// The electrical angle at the segment start.
    angle: SegmentAngle,
    /// How the motor shaft and the load move in the segment.
    shaft: ShaftSegment,
}

impl SwitchingSegment<'_> {
    /// The derivatives of the state `[i_d, i_q, omega_m, theta_m, V_bus, omega_l, theta_l]`.
    #[inline(always)]
    fn derivatives(&self, s: &[f64; 7]) -> [f64; 7] {
        let (k, legs, inverter_legs) = (self.k, self.legs, self.inverter_legs);
        let [i_d, i_q, omega, theta, v, omega_l, theta_l] = *s;
        let (sn, cs) = self.angle.sin_cos_at(k.p * theta);
        let mut u = [legs[0].a * v + legs[0].b, legs[1].a * v + legs[1].b, legs[2].a * v + legs[2].b];
        if let Some(x) = self.open {
            u[x] = open_phase_terminal(u, back_emf(k.p * omega, k.psi, sn, cs), x);
        }
        let [v_d, v_q] = abc_to_dq(u, sn, cs);
        let omega_e = k.p * omega;
        let di_d = (v_d - k.r * i_d + omega_e * k.lq * i_q) / k.ld;
        let di_q = (v_q - k.r * i_q - omega_e * (k.ld * i_d + k.psi)) / k.lq;
        let i = dq_to_abc(i_d, i_q, sn, cs);
        let mut i_dc = legs[0].c * i[0] + legs[1].c * i[1] + legs[2].c * i[2];
        if let Some(short) = self.short {
            // The short's current leaves through the high switch of the leg at the higher pole.
            let poles = inverter_legs.map(|l| l.a * v + l.b);
            let s = short.leg_currents(poles);
            i_dc += inverter_legs[0].c * s[0] + inverter_legs[1].c * s[1] + inverter_legs[2].c * s[2];
        }
        let dv = (k.bus_inflow(v) - i_dc) / k.c_bus;
        let [dw, dth, dwl, dthl] =
            k.mechanical_derivatives(&self.shaft, k.torque(i_d, i_q), [omega, theta, omega_l, theta_l]);
        [di_d, di_q, dw, dth, dv, dwl, dthl]
    }

    /// Adds the segment of length `h` to the period integrals `acc` (trapezoidal in the bus voltage and currents),
    /// from the states `s0`, `s1` at its ends (`s1` as integrated) and the phase currents `i0`, `i1` at its ends
    /// (`i1` after the diodes stopped any).
    fn accumulate_averages(
        &self,
        acc: &mut PeriodAverages,
        h: f64,
        s0: &[f64; 7],
        s1: &[f64; 7],
        i0: [f64; 3],
        i1: [f64; 3],
    ) {
        let (k, legs, inverter_legs) = (self.k, self.legs, self.inverter_legs);
        let v_mid = 0.5 * (s0[4] + s1[4]);
        let mut poles = [0.0; 3];
        for x in 0..3 {
            let i_mid = 0.5 * (i0[x] + i1[x]);
            poles[x] = inverter_legs[x].a * v_mid + inverter_legs[x].b - k.r_switch * i_mid;
            acc.pole_voltage_v[x] += poles[x] * h;
            acc.bus_current_a += legs[x].c * i_mid * h;
        }
        if let Some(short) = self.short {
            let s_mid = short.leg_currents(inverter_legs.map(|l| l.a * v_mid + l.b));
            for x in 0..3 {
                acc.bus_current_a += inverter_legs[x].c * s_mid[x] * h;
            }
        }
        let (sn, cs) = self.angle.sin_cos_at(k.p * 0.5 * (s0[3] + s1[3]));
        let vdq = abc_to_dq(poles, sn, cs);
        acc.dq_voltage_v[0] += vdq[0] * h;
        acc.dq_voltage_v[1] += vdq[1] * h;
        acc.bus_voltage_v += v_mid * h;
        let i_sq = 0.5 * (s0[0] * s0[0] + s0[1] * s0[1] + s1[0] * s1[0] + s1[1] * s1[1]);
        acc.copper_loss_w += 1.5 * (k.r - k.r_switch) * i_sq * h;
    }

    /// The currents out of the three legs with the phase currents `i` and the bus at `v_bus`: the phase currents
    /// plus a short's share.
    fn leg_currents(&self, i: [f64; 3], v_bus: f64) -> [f64; 3] {
        let mut legs_i = i;
        if let Some(short) = self.short {
            let s_end = short.leg_currents(self.inverter_legs.map(|l| l.a * v_bus + l.b));
            for x in 0..3 {
                legs_i[x] += s_end[x];
            }
        }
        legs_i
    }
}
