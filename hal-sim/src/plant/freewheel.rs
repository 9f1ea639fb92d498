//! One integration segment with all switches off (outputs disabled or the break tripped): the three-phase diode
//! bridge, in abc coordinates with the mean inductance (see the module docs of [`super`]): which diodes conduct,
//! the currents they carry until they reach zero, and the segment's share of the period averages.

use super::coeffs::Coeffs;
use super::electrical::{
    abc_to_dq, back_emf, dq_to_abc, remove_phase_current, rk4, LegDrive, SegmentAngle, ZERO_CURRENT_A,
};
use super::mechanics::ShaftSegment;
use super::{PeriodAverages, Plant};

impl Plant {
    /// One RK4 segment of length `h` with all switches off: the diode-bridge model (see the module docs).
    pub(super) fn segment_freewheel(&mut self, k: &Coeffs, h: f64, acc: &mut PeriodAverages) {
        let angle = SegmentAngle::new(k.p * self.theta_m);
        let disconnected = self.faults.phase_open.filter(|&x| x < 3);
        let mut i = self.freewheel_start_currents(angle, disconnected);
        let e = back_emf(k.p * self.omega_m, k.psi, angle.sin, angle.cos);
        let v = self.v_bus;
        let conducting = conducting_diodes(&mut i, e, v, k.v_diode, disconnected);
        let bridge = DiodeBridge::new(k, conducting, angle, self.shaft_segment(k));
        let (omega_before, omega_l_before) = (self.omega_m, self.omega_l);
        let s0 = [i[0], i[1], i[2], self.omega_m, self.theta_m, v, self.omega_l, self.theta_l];
        let s1 = rk4(&s0, h, |s: &[f64; 8]| bridge.derivatives(s));
        let i1 = bridge.block_reverse_currents(&s1);
        self.omega_m = s1[3];
        self.theta_m = s1[4];
        self.v_bus = s1[5];
        self.omega_l = s1[6];
        self.theta_l = s1[7];
        self.end_segment(k, &bridge.shaft, omega_before, omega_l_before);
        let (sn1, cs1) = angle.sin_cos_at(k.p * self.theta_m);
        [self.i_d, self.i_q] = abc_to_dq(i1, sn1, cs1);
        bridge.accumulate_averages(acc, h, &s0, &s1, i1);
    }

    /// The phase currents at the start of a segment with all switches off (electrical angle `angle`), those below
    /// [`ZERO_CURRENT_A`] taken as zero.
    fn freewheel_start_currents(&self, angle: SegmentAngle, disconnected: Option<usize>) -> [f64; 3] {
        let mut i = dq_to_abc(self.i_d, self.i_q, angle.sin, angle.cos);
        for x in i.iter_mut() {
            if x.abs() < ZERO_CURRENT_A {
                *x = 0.0;
            }
        }
        // A disconnected phase ([`super::faults::PlantFaults::phase_open`]) never conducts; a current it still carried
        // when it was opened is cut at once (as in `segment_switching`).
        if let Some(x) = disconnected {
            if i[x] != 0.0 {
                remove_phase_current(&mut i, x);
            }
        }
        i
    }
}

/// Which diode conducts in each phase over the segment, from the phase currents `i` at its start, the back-EMFs `e`
/// and the bus voltage `v`: `None` (open) or `Some(upper?)`. With fewer than two phases carrying current the
/// currents are set to zero and the bridge conducts only if the back-EMF pulls two terminals beyond the rails; an
/// open third phase starts conducting when the two others pull its terminal beyond a rail. A disconnected phase
/// never conducts.
fn conducting_diodes(
    i: &mut [f64; 3],
    e: [f64; 3],
    v: f64,
    v_diode: f64,
    disconnected: Option<usize>,
) -> [Option<bool>; 3] {
    // Conduction: per phase, None (open) or Some(upper?) for the diode carrying its current.
    let mut conducting: [Option<bool>; 3] = i.map(|x| if x != 0.0 { Some(x < 0.0) } else { None });
    let rail = |upper: bool| if upper { v + v_diode } else { -v_diode };
    let count = |c: &[Option<bool>; 3]| c.iter().filter(|x| x.is_some()).count();
    if count(&conducting) < 2 {
        conducting = [None; 3];
        *i = [0.0; 3];
        let first = usize::from(disconnected == Some(0));
        let (mut hi, mut lo) = (first, first);
        for x in (first + 1..3).filter(|&x| Some(x) != disconnected) {
            if e[x] > e[hi] {
                hi = x;
            }
            if e[x] < e[lo] {
                lo = x;
            }
        }
        if e[hi] - e[lo] > v + 2.0 * v_diode {
            conducting[hi] = Some(true);
            conducting[lo] = Some(false);
        }
    }
    if count(&conducting) == 2 {
        let mut v_n = 0.0;
        let mut open = 0;
        for x in 0..3 {
            match conducting[x] {
                Some(up) => v_n += 0.5 * (rail(up) - e[x]),
                None => open = x,
            }
        }
        let v_open = e[open] + v_n;
        if Some(open) != disconnected {
            if v_open > v + v_diode {
                conducting[open] = Some(true);
            } else if v_open < -v_diode {
                conducting[open] = Some(false);
            }
        }
    }
    conducting
}

/// The diode bridge over one segment: which diodes conduct, and the model of the motor, shaft and bus they give.
struct DiodeBridge<'a> {
    k: &'a Coeffs,
    /// Mean inductance `(Ld + Lq) / 2`, in H.
    l: f64,
    /// Per phase, None (open) or Some(upper?) for the diode carrying its current.
    conducting: [Option<bool>; 3],
    /// Number of conducting phases.
    n_on: usize,
    /// 1 for a conducting phase, 0 for an open one.
    mask: [f64; 3],
    /// Pole drive of the diode conducting in each phase (zero for an open phase).
    drive: [LegDrive; 3],
    /// `1 / n_on` (0 with no phase conducting).
    inv_n: f64,
    /// The electrical angle at the segment start.
    angle: SegmentAngle,
    /// How the motor shaft and the load move in the segment.
    shaft: ShaftSegment,
}

impl<'a> DiodeBridge<'a> {
    fn new(k: &'a Coeffs, conducting: [Option<bool>; 3], angle: SegmentAngle, shaft: ShaftSegment) -> Self {
        let l = 0.5 * (k.ld + k.lq);
        let n_on = conducting.iter().filter(|x| x.is_some()).count();
        let mask = conducting.map(|c| if c.is_some() { 1.0 } else { 0.0 });
        let drive = conducting.map(|c| match c {
            Some(true) => LegDrive::upper_diode(k.v_diode),
            Some(false) => LegDrive::lower_diode(k.v_diode),
            None => LegDrive::default(),
        });
        let inv_n = if n_on > 0 { 1.0 / n_on as f64 } else { 0.0 };
        Self { k, l, conducting, n_on, mask, drive, inv_n, angle, shaft }
    }

    /// Neutral voltage of a state: mean over the conducting phases of (pole - R i - e).
    #[inline(always)]
    fn neutral(&self, s: &[f64; 8], e: &[f64; 3]) -> f64 {
        let (k, mask, drive) = (self.k, self.mask, self.drive);
        let mut sum = 0.0;
        for x in 0..3 {
            sum += mask[x] * (drive[x].a * s[5] + drive[x].b - k.r * s[x] - e[x]);
        }
        sum * self.inv_n
    }

    /// The derivatives of the state `[i_a, i_b, i_c, omega_m, theta_m, V_bus, omega_l, theta_l]`.
    #[inline(always)]
    fn derivatives(&self, s: &[f64; 8]) -> [f64; 8] {
        let (k, mask, drive) = (self.k, self.mask, self.drive);
        let (sn, cs) = self.angle.sin_cos_at(k.p * s[4]);
        let e = back_emf(k.p * s[3], k.psi, sn, cs);
        let v_n = self.neutral(s, &e);
        let mut d = [0.0; 8];
        let mut i_dc = 0.0;
        for x in 0..3 {
            d[x] = mask[x] * (drive[x].a * s[5] + drive[x].b - k.r * s[x] - e[x] - v_n) / self.l;
            i_dc += mask[x] * drive[x].c * s[x];
        }
        let [i_d, i_q] = abc_to_dq([s[0], s[1], s[2]], sn, cs);
        let [dw, dth, dwl, dthl] = k.mechanical_derivatives(&self.shaft, k.torque(i_d, i_q), [s[3], s[4], s[6], s[7]]);
        d[3] = dw;
        d[4] = dth;
        d[6] = dwl;
        d[7] = dthl;
        d[5] = (k.bus_inflow(s[5]) - i_dc) / k.c_bus;
        d
    }

    /// The phase currents at the end of the segment from the integrated state `s1`. Diodes block reverse current:
    /// a conducting phase whose current reached or crossed zero stops.
    fn block_reverse_currents(&self, s1: &[f64; 8]) -> [f64; 3] {
        let conducting = self.conducting;
        let mut i1 = [s1[0], s1[1], s1[2]];
        for x in 0..3 {
            if let Some(up) = conducting[x] {
                let expected = if up { -1.0 } else { 1.0 };
                if i1[x] * expected <= ZERO_CURRENT_A {
                    i1[x] = 0.0;
                }
            } else {
                i1[x] = 0.0;
            }
        }
        let nonzero = i1.iter().filter(|x| **x != 0.0).count();
        if nonzero < 2 {
            i1 = [0.0; 3];
        } else {
            let mean = (i1[0] + i1[1] + i1[2]) / nonzero as f64;
            for x in i1.iter_mut() {
                if *x != 0.0 {
                    *x -= mean;
                }
            }
        }
        i1
    }

    /// Adds the segment of length `h` to the period integrals `acc`, at its midpoint between the states `s0` and
    /// `s1` (as integrated) with the phase currents `i1` at its end (after the diodes stopped any). Open phases
    /// float at e + v_n; all open: neutral at mid-bus.
    fn accumulate_averages(&self, acc: &mut PeriodAverages, h: f64, s0: &[f64; 8], s1: &[f64; 8], i1: [f64; 3]) {
        let (k, mask, drive) = (self.k, self.mask, self.drive);
        let (sn_mid, cs_mid) = self.angle.sin_cos_at(k.p * 0.5 * (s0[4] + s1[4]));
        let e_mid = back_emf(k.p * 0.5 * (s0[3] + s1[3]), k.psi, sn_mid, cs_mid);
        let v_mid = 0.5 * (s0[5] + s1[5]);
        let mut s_mid = [0.0; 8];
        for x in 0..8 {
            s_mid[x] = 0.5 * (s0[x] + if x < 3 { i1[x] } else { s1[x] });
        }
        let v_n = if self.n_on >= 2 { self.neutral(&s_mid, &e_mid) } else { 0.5 * v_mid };
        let mut poles = [0.0; 3];
        for x in 0..3 {
            poles[x] = if self.conducting[x].is_some() {
                drive[x].a * v_mid + drive[x].b - k.r_switch * s_mid[x]
            } else {
                e_mid[x] + v_n
            };
            acc.pole_voltage_v[x] += poles[x] * h;
            acc.bus_current_a += drive[x].c * mask[x] * s_mid[x] * h;
        }
        let vdq = abc_to_dq(poles, sn_mid, cs_mid);
        acc.dq_voltage_v[0] += vdq[0] * h;
        acc.dq_voltage_v[1] += vdq[1] * h;
        acc.bus_voltage_v += v_mid * h;
        let i_sq = (s_mid[0] * s_mid[0] + s_mid[1] * s_mid[1] + s_mid[2] * s_mid[2]) * (2.0 / 3.0);
        acc.copper_loss_w += 1.5 * (k.r - k.r_switch) * i_sq * h;
    }
}
