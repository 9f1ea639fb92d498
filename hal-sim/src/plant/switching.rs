//! One integration interval with the outputs switching: each leg's pole set by its switch or, in dead time, by the
//! body diode that carries its current; a leg in dead time without current floating with the motor; the injected
//! open phase and output short ([`super::faults::PlantFaults`]); the diodes blocking reverse current at the end of
//! the interval; and the interval's share of the period averages.
//!
//! The interval runs between two switching instants (or the sample instant), so every pole voltage is `a V_bus + b`
//! with constant `a`, `b` over it. The shaft is held over the interval ([`super::mechanics::Stretch`]: constant
//! speed, the angle advancing with it), which leaves the electrical state `[i_d, i_q, V_bus]` a linear system
//! whose only time dependence is the rotation of the frame; one classical RK4 step integrates it, with the frame's
//! sine and cosine at the three instants RK4 needs (start, midpoint, end) reached by rotation.

use super::coeffs::Coeffs;
use super::electrical::{
    abc_to_dq, back_emf, dq_to_abc, open_phase_terminal_drive, remove_phase_current, rotate, small_rotation, LegDrive,
    ZERO_CURRENT_A,
};
use super::inverter::{LegPattern, LegState, OutputShort};
use super::mechanics::Stretch;
use super::{PeriodAverages, Plant};

impl Plant {
    /// One RK4 step over the interval `[t0, t1)` (between two consecutive switching instants) with the outputs
    /// switching and the shaft held by `stretch`; returns the currents out of the three legs at its end (the phase
    /// currents, plus a short's share, [`OutputShort`]): what the over-current comparator sees.
    ///
    /// A disconnected phase ([`super::faults::PlantFaults::phase_open`]) is a leg whose motor terminal floats at
    /// its back-EMF above the star point of the two others (`open_phase_terminal_drive`, at each RK4 instant),
    /// draws nothing from the bus, and ends every interval at exactly zero current (the projection of
    /// [`Plant::stop_phases`], as for a diode that stopped conducting). The current a phase carried when it was
    /// opened is cut at once (the arc of a real break lasts microseconds; its energy is dropped).
    pub(super) fn switching_interval(
        &mut self,
        k: &Coeffs,
        patterns: &[LegPattern; 3],
        stretch: &mut Stretch,
        t0: f64,
        t1: f64,
        acc: &mut PeriodAverages,
    ) -> [f64; 3] {
        let h = t1 - t0;
        let omega_e = k.p * stretch.omega_m;
        let start = (stretch.sin, stretch.cos);
        let half = small_rotation(0.5 * omega_e * h);
        let mid_angle = rotate(start, half);
        let end = rotate(mid_angle, half);
        let i0 = dq_to_abc(self.i_d, self.i_q, start.0, start.1);
        let (mut legs, off, mut floating) = legs_at(patterns, 0.5 * (t0 + t1), i0, k.v_diode);
        // Injected faults: a disconnected phase is taken out of the neutral of the floating legs below.
        let open = self.faults.phase_open.filter(|&x| x < 3);
        if let Some(x) = open {
            floating[x] = true;
        }
        let short = OutputShort::new(self.faults.phase_short, k.r_switch);
        if floating.iter().any(|f| *f) {
            // Back-EMF frozen over the interval (at most the 0.5 us dead time).
            let e0 = back_emf(omega_e, k.psi, start.0, start.1);
            drive_floating_legs(&mut legs, &mut floating, e0, self.v_bus, k.v_diode);
        }
        // The inverter's poles (what the averages and a short see); the motor terminal of an open phase follows
        // the back-EMF at each instant.
        let inverter_legs = legs;
        if let Some(x) = open {
            legs[x] = LegDrive::default();
        }
        let interval = SwitchingInterval::new(k, &legs, &inverter_legs, open, short, omega_e, [start, mid_angle, end]);
        let s0 = [self.i_d, self.i_q, self.v_bus];
        let (s1, s_mid) = interval.rk4(&s0, h);
        [self.i_d, self.i_q, self.v_bus] = s1;
        let mut i1 = dq_to_abc(self.i_d, self.i_q, end.0, end.1);
        let stopped = stopped_phases(&legs, off, floating, open, i1);
        self.stop_phases(stopped, &mut i1, end.0, end.1);
        // Simpson's rule over the interval (the torque at the midpoint from the currents there).
        let torques = [k.torque(s0[0], s0[1]), k.torque(s_mid[0], s_mid[1]), k.torque(self.i_d, self.i_q)];
        stretch.torque_integral += h * (1.0 / 6.0) * (torques[0] + 4.0 * torques[1] + torques[2]);
        (stretch.sin, stretch.cos) = end;
        interval.accumulate_averages(acc, h, &s0, &s1, i0, i1, mid_angle);
        interval.leg_currents(i1, self.v_bus)
    }

    /// Diodes block reverse current: each phase in `stopped` ends the segment at exactly zero current. One such
    /// phase: the current vector `i1` (at the electrical angle of sine `sn1` and cosine `cs1`) is projected onto the
    /// plane `i_x = 0`; two or three leave no current at all. Sets the plant's dq currents and `i1` to the result.
    pub(super) fn stop_phases(&mut self, stopped: [bool; 3], i1: &mut [f64; 3], sn1: f64, cs1: f64) {
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
pub(super) fn legs_at(
    patterns: &[LegPattern; 3],
    mid: f64,
    i0: [f64; 3],
    v_diode: f64,
) -> ([LegDrive; 3], [bool; 3], [bool; 3]) {
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
pub(super) fn drive_floating_legs(
    legs: &mut [LegDrive; 3],
    floating: &mut [bool; 3],
    e0: [f64; 3],
    v_bus: f64,
    v_diode: f64,
) {
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
pub(super) fn stopped_phases(
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

/// The linear model of one instant of the interval, in the rotor frame at that instant: the terminal voltage
/// `v_dq = a_dq V_bus + b_dq` and the inverter's bus current `c_dq . i_dq`.
#[derive(Clone, Copy, Debug, Default)]
struct FrameAt {
    a_dq: [f64; 2],
    b_dq: [f64; 2],
    c_dq: [f64; 2],
}

/// How the inverter drives the motor over one interval with the outputs switching, at the interval's start,
/// midpoint and end (the instants of an RK4 step).
struct SwitchingInterval<'a> {
    k: &'a Coeffs,
    /// The drive of the inverter's poles (what the averages and a short see).
    inverter_legs: [LegDrive; 3],
    /// The drive of the motor terminals (an open phase's is zero: [`FrameAt`] holds its terminal).
    legs: [LegDrive; 3],
    /// The short between two outputs ([`super::faults::PlantFaults::phase_short`]).
    short: Option<OutputShort>,
    /// Electrical speed, in rad/s.
    omega_e: f64,
    /// The model at the start, the midpoint and the end.
    frames: [FrameAt; 3],
    /// A short's share of the bus current: `short_g v + short_0`, in S and A.
    short_g: f64,
    short_0: f64,
}

impl<'a> SwitchingInterval<'a> {
    /// The interval's model with the legs `legs` at the motor terminals, `inverter_legs` at the poles, at the
    /// electrical angles of sine and cosine `angles` (start, midpoint, end).
    fn new(
        k: &'a Coeffs,
        legs: &[LegDrive; 3],
        inverter_legs: &[LegDrive; 3],
        open: Option<usize>,
        short: Option<OutputShort>,
        omega_e: f64,
        angles: [(f64, f64); 3],
    ) -> Self {
        // The pole drives and the bus-current shares in alpha-beta once; each instant only turns them.
        let a = clarke(legs.map(|l| l.a));
        let b = clarke(legs.map(|l| l.b));
        // c . i_abc = c' . i_alphabeta with i_abc the inverse Clarke of i_alphabeta.
        let c = legs.map(|l| l.c);
        let c_ab = [c[0] - 0.5 * (c[1] + c[2]), HALF_SQRT3 * (c[1] - c[2])];
        let frames = angles.map(|(sn, cs)| {
            let (a, b) = match open {
                // The open phase's terminal: its back-EMF above the star point of the two others, at this instant.
                Some(x) => {
                    let mut drive = *legs;
                    (drive[x].a, drive[x].b) = open_phase_terminal_drive(legs, back_emf(omega_e, k.psi, sn, cs), x);
                    (clarke(drive.map(|l| l.a)), clarke(drive.map(|l| l.b)))
                }
                None => (a, b),
            };
            FrameAt { a_dq: park(a, sn, cs), b_dq: park(b, sn, cs), c_dq: park(c_ab, sn, cs) }
        });
        let (mut short_g, mut short_0) = (0.0, 0.0);
        if let Some(s) = short {
            // The short's current is linear in the poles: it leaves through the high switch of the leg at the
            // higher pole.
            let c = inverter_legs.map(|l| l.c);
            short_g = dot(c, s.leg_currents(inverter_legs.map(|l| l.a)));
            short_0 = dot(c, s.leg_currents(inverter_legs.map(|l| l.b)));
        }
        Self { k, inverter_legs: *inverter_legs, legs: *legs, short, omega_e, frames, short_g, short_0 }
    }

    /// The derivatives of `[i_d, i_q, V_bus]` at the instant of `frame`.
    #[inline(always)]
    fn derivatives(&self, frame: &FrameAt, s: &[f64; 3]) -> [f64; 3] {
        let k = self.k;
        let [i_d, i_q, v] = *s;
        let v_d = frame.a_dq[0] * v + frame.b_dq[0];
        let v_q = frame.a_dq[1] * v + frame.b_dq[1];
        let di_d = (v_d - k.r * i_d + self.omega_e * k.lq * i_q) * k.inv_ld;
        let di_q = (v_q - k.r * i_q - self.omega_e * (k.ld * i_d + k.psi)) * k.inv_lq;
        let i_dc = frame.c_dq[0] * i_d + frame.c_dq[1] * i_q + self.short_g * v + self.short_0;
        let dv = (k.bus_inflow_fast(v) - i_dc) * k.inv_c_bus;
        [di_d, di_q, dv]
    }

    /// One classical RK4 step of length `h` from `s0`: the state at the end, and at the midpoint (the cubic
    /// Hermite interpolation between the ends with the derivatives there, fourth-order accurate like the step).
    #[inline(always)]
    fn rk4(&self, s0: &[f64; 3], h: f64) -> ([f64; 3], [f64; 3]) {
        let add =
            |x: &[f64; 3], d: &[f64; 3], w: f64| -> [f64; 3] { [x[0] + w * d[0], x[1] + w * d[1], x[2] + w * d[2]] };
        let [start, mid, end] = &self.frames;
        let k1 = self.derivatives(start, s0);
        let k2 = self.derivatives(mid, &add(s0, &k1, 0.5 * h));
        let k3 = self.derivatives(mid, &add(s0, &k2, 0.5 * h));
        let k4 = self.derivatives(end, &add(s0, &k3, h));
        let w = h * (1.0 / 6.0);
        let s1: [f64; 3] = core::array::from_fn(|i| s0[i] + w * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
        // y(h/2) = (y0 + y1) / 2 + h (y'0 - y'1) / 8, with k4 standing for y'1.
        let s_mid = core::array::from_fn(|i| 0.5 * (s0[i] + s1[i]) + 0.125 * h * (k1[i] - k4[i]));
        (s1, s_mid)
    }

    /// Adds the interval of length `h` to the period integrals `acc` (trapezoidal in the bus voltage and currents),
    /// from the states `s0`, `s1` (`[i_d, i_q, V_bus]`, `s1` as integrated) at its ends and the phase currents
    /// `i0`, `i1` at its ends (`i1` after the diodes stopped any), the frame taken at the midpoint angle `mid`.
    #[allow(clippy::too_many_arguments)]
    fn accumulate_averages(
        &self,
        acc: &mut PeriodAverages,
        h: f64,
        s0: &[f64; 3],
        s1: &[f64; 3],
        i0: [f64; 3],
        i1: [f64; 3],
        mid: (f64, f64),
    ) {
        let k = self.k;
        let v_mid = 0.5 * (s0[2] + s1[2]);
        let poles =
            accumulate_leg_averages(acc, h, k.r_switch, &self.legs, &self.inverter_legs, self.short, v_mid, i0, i1);
        let vdq = park(clarke(poles), mid.0, mid.1);
        accumulate_dq_averages(acc, h, k, vdq, v_mid, [s0[0], s0[1]], [s1[0], s1[1]]);
    }

    /// The currents out of the three legs with the phase currents `i` and the bus at `v_bus`
    /// ([`currents_out_of_legs`]).
    fn leg_currents(&self, i: [f64; 3], v_bus: f64) -> [f64; 3] {
        currents_out_of_legs(self.short, &self.inverter_legs, i, v_bus)
    }
}

/// Adds the pole voltages and the bus current of an interval of length `h` to the period integrals `acc`, with the
/// bus at `v_mid` and the phase currents `i0`, `i1` at its ends (trapezoidal), the legs driven as `legs` (phase
/// currents) and `inverter_legs` (a short's share); returns the pole voltages at the midpoint (the plant's
/// integrator and the tests' reference integrator alike).
#[allow(clippy::too_many_arguments)]
pub(super) fn accumulate_leg_averages(
    acc: &mut PeriodAverages,
    h: f64,
    r_switch: f64,
    legs: &[LegDrive; 3],
    inverter_legs: &[LegDrive; 3],
    short: Option<OutputShort>,
    v_mid: f64,
    i0: [f64; 3],
    i1: [f64; 3],
) -> [f64; 3] {
    let mut poles = [0.0; 3];
    for x in 0..3 {
        let i_mid = 0.5 * (i0[x] + i1[x]);
        poles[x] = inverter_legs[x].a * v_mid + inverter_legs[x].b - r_switch * i_mid;
        acc.pole_voltage_v[x] += poles[x] * h;
        acc.bus_current_a += legs[x].c * i_mid * h;
    }
    if let Some(short) = short {
        let s_mid = short.leg_currents(inverter_legs.map(|l| l.a * v_mid + l.b));
        for x in 0..3 {
            acc.bus_current_a += inverter_legs[x].c * s_mid[x] * h;
        }
    }
    poles
}

/// Adds the rest of an interval of length `h` to the period integrals `acc`: the dq voltage `vdq` at its midpoint,
/// the bus at `v_mid`, and the winding's copper loss from the dq currents `idq0`, `idq1` at its ends (trapezoidal
/// in their squares); the switches' share of the resistance is the inverter's loss, not the motor's (the plant's
/// integrator and the tests' reference integrator alike).
pub(super) fn accumulate_dq_averages(
    acc: &mut PeriodAverages,
    h: f64,
    k: &Coeffs,
    vdq: [f64; 2],
    v_mid: f64,
    idq0: [f64; 2],
    idq1: [f64; 2],
) {
    acc.dq_voltage_v[0] += vdq[0] * h;
    acc.dq_voltage_v[1] += vdq[1] * h;
    acc.bus_voltage_v += v_mid * h;
    let i_sq = 0.5 * (idq0[0] * idq0[0] + idq0[1] * idq0[1] + idq1[0] * idq1[0] + idq1[1] * idq1[1]);
    acc.copper_loss_w += 1.5 * (k.r - k.r_switch) * i_sq * h;
}

/// The currents out of the three legs driven as `inverter_legs` with the phase currents `i` and the bus at `v_bus`:
/// the phase currents plus a short's share (the plant's integrator and the tests' reference integrator alike).
pub(super) fn currents_out_of_legs(
    short: Option<OutputShort>,
    inverter_legs: &[LegDrive; 3],
    i: [f64; 3],
    v_bus: f64,
) -> [f64; 3] {
    let mut legs_i = i;
    if let Some(short) = short {
        let s_end = short.leg_currents(inverter_legs.map(|l| l.a * v_bus + l.b));
        for x in 0..3 {
            legs_i[x] += s_end[x];
        }
    }
    legs_i
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

const HALF_SQRT3: f64 = 0.866_025_403_784_438_6;

/// The amplitude-invariant Clarke transform (as [`abc_to_dq`]'s first half, multiplying by constants).
#[inline(always)]
fn clarke(x: [f64; 3]) -> [f64; 2] {
    const THIRD: f64 = 1.0 / 3.0;
    const INV_SQRT3: f64 = 0.577_350_269_189_625_8;
    [(2.0 * x[0] - x[1] - x[2]) * THIRD, (x[1] - x[2]) * INV_SQRT3]
}

/// The Park transform: alpha-beta into the frame at the angle of sine `sn` and cosine `cs`.
#[inline(always)]
fn park(x: [f64; 2], sn: f64, cs: f64) -> [f64; 2] {
    [x[0] * cs + x[1] * sn, -x[0] * sn + x[1] * cs]
}
