//! The reference integrator of the switching periods, for tests: the period cut at every switching instant and
//! the sample instant, each interval split into equal segments no longer than `T / substeps_per_period`, and each
//! segment one classical RK4 step of the joint state `[i_d, i_q, omega_m, theta_m, V_bus, omega_l, theta_l]` (the
//! shaft integrated with the currents; sub-steps of 5 us by default). It is what the plant integrated before the
//! switching intervals ([`super::switching`]) held the shaft over half a period; the tests below hold the two
//! against each other.

use super::coeffs::Coeffs;
use super::electrical::{abc_to_dq, back_emf, dq_to_abc, open_phase_terminal, rk4, LegDrive, SegmentAngle};
use super::inverter::{LegPattern, OutputShort};
use super::mechanics::ShaftSegment;
use super::switching::{
    accumulate_dq_averages, accumulate_leg_averages, currents_out_of_legs, drive_floating_legs, legs_at, stopped_phases,
};
use super::{PeriodAverages, Plant};

impl Plant {
    /// Use the reference integrator from the next period on (`true`), or the plant's own (`false`).
    pub(super) fn set_reference_integration(&mut self, on: bool) {
        self.reference_integration = on;
    }

    /// One reference segment `[t0, t1)` with the outputs switching: the load torque at its start, the RK4 step
    /// (tripping the over-current break if a leg current exceeds it), then the encoder follows the shaft.
    pub(super) fn reference_segment(
        &mut self,
        k: &Coeffs,
        patterns: &[LegPattern; 3],
        t0: f64,
        t1: f64,
        acc: &mut PeriodAverages,
    ) {
        self.update_load(t0);
        let i = self.reference_switching(k, patterns, t0, t1, acc);
        if i.iter().any(|x| x.abs() > self.params.break_current_a) {
            self.break_latched = true;
        }
        self.update_encoder();
    }
}

impl Plant {
    /// One RK4 segment `[t0, t1)` with the outputs switching; returns the currents out of the three legs at its end
    /// (the phase currents, plus a short's share, [`OutputShort`]): what the over-current comparator sees.
    ///
    /// A disconnected phase ([`super::faults::PlantFaults::phase_open`]) is a leg whose motor terminal floats at
    /// [`open_phase_terminal`], recomputed at every RK4 stage, draws nothing from the bus, and ends every segment at
    /// exactly zero current (the projection of [`Plant::stop_phases`], as for a diode that stopped conducting). The
    /// current a phase carried when it was opened is cut at once (the arc of a real break lasts microseconds; its
    /// energy is dropped).
    fn reference_switching(
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
        let k = self.k;
        let v_mid = 0.5 * (s0[4] + s1[4]);
        let poles =
            accumulate_leg_averages(acc, h, k.r_switch, &self.legs, &self.inverter_legs, self.short, v_mid, i0, i1);
        let (sn, cs) = self.angle.sin_cos_at(k.p * 0.5 * (s0[3] + s1[3]));
        let vdq = abc_to_dq(poles, sn, cs);
        accumulate_dq_averages(acc, h, k, vdq, v_mid, [s0[0], s0[1]], [s1[0], s1[1]]);
    }

    /// The currents out of the three legs with the phase currents `i` and the bus at `v_bus`
    /// ([`currents_out_of_legs`]).
    fn leg_currents(&self, i: [f64; 3], v_bus: f64) -> [f64; 3] {
        currents_out_of_legs(self.short, &self.inverter_legs, i, v_bus)
    }
}

/// The plant's integrator ([`super::switching`] intervals with the shaft held over half a period) against the
/// reference (RK4 segments of at most 5 us of the joint state), both fed the same commands: a dq current loop on
/// the reference plant's true state, so the two see identical duties and any difference is the integration's.
#[cfg(test)]
mod tests {
    use crate::plant::true_state_current_loop::TrueStateCurrentLoop;
    use crate::plant::{Mechanics, Plant, PlantParams};

    /// The largest differences between the two integrators over a run, at the sample instants.
    #[derive(Debug, Default)]
    struct Deviation {
        /// Phase currents, in A.
        current_a: f64,
        /// Bus voltage, in V.
        bus_v: f64,
        /// Mechanical speed, in rad/s.
        speed_rad_s: f64,
        /// Mechanical angle, in rad.
        angle_rad: f64,
        /// ADC codes of the shunts and the bus (the same noise: the same seed).
        adc_codes: i32,
        /// Encoder counter.
        encoder_counts: i32,
    }

    /// Runs `periods` periods of the plant `params` (set up by `setup`) with both integrators, the current loop
    /// following `reference_dq(period)` on the reference's state, and `load(period)` at the output.
    fn compare(
        params: &PlantParams,
        setup: impl Fn(&mut Plant),
        reference_dq: impl Fn(usize) -> [f64; 2],
        load: impl Fn(usize) -> f64,
        periods: usize,
    ) -> Deviation {
        let mut fast = Plant::new(params.clone(), 7);
        let mut reference = Plant::new(params.clone(), 7);
        reference.set_reference_integration(true);
        setup(&mut fast);
        setup(&mut reference);
        let mut ctl = TrueStateCurrentLoop::new(params);
        let mut cmd = ctl.update(&reference.state_at_sample(), reference_dq(0));
        let mut d = Deviation::default();
        for n in 0..periods {
            fast.set_load_torque(load(n));
            reference.set_load_torque(load(n));
            let (mf, mr) = (fast.step(&cmd), reference.step(&cmd));
            let (f, r) = (fast.state_at_sample(), reference.state_at_sample());
            for x in 0..3 {
                d.current_a = d.current_a.max((f.i_abc_a[x] - r.i_abc_a[x]).abs());
                let codes = i32::from(mf.adc.phase_currents[x]) - i32::from(mr.adc.phase_currents[x]);
                d.adc_codes = d.adc_codes.max(codes.abs());
            }
            d.adc_codes = d.adc_codes.max((i32::from(mf.adc.bus_voltage) - i32::from(mr.adc.bus_voltage)).abs());
            d.encoder_counts = d
                .encoder_counts
                .max(i32::from(mf.feedback.encoder_count.wrapping_sub(mr.feedback.encoder_count) as i16).abs());
            d.bus_v = d.bus_v.max((f.bus_voltage_v - r.bus_voltage_v).abs());
            d.speed_rad_s = d.speed_rad_s.max((f.omega_m_rad_s - r.omega_m_rad_s).abs());
            d.angle_rad = d.angle_rad.max((f.theta_m_rad - r.theta_m_rad).abs());
            cmd = ctl.update(&r, reference_dq(n + 1));
        }
        d
    }

    /// A 5 A step of i_q from rest, free rotor, for 40 ms (to 3,600 rpm). Tolerances: currents within 1 mA (an
    /// eighth of one shunt code, 124 codes/A; measured 0.2 mA), the bus within 0.1 mV (measured 0.02 mV), the speed
    /// within 0.01 rad/s (measured 0.0016: the breakaway from stiction is found at the end of an interval, not of a
    /// 5 us segment), the sampled codes and the encoder counter within one.
    #[test]
    fn current_step_matches_the_reference() {
        let p = PlantParams::reference();
        let d = compare(&p, |_| {}, |n| [0.0, if n < 50 { 0.0 } else { 5.0 }], |_| 0.0, 1000);
        assert!(d.current_a < 1e-3 && d.bus_v < 1e-4 && d.speed_rad_s < 0.01, "{d:?}");
        assert!(d.adc_codes <= 1 && d.encoder_counts <= 1, "{d:?}");
    }

    /// Spinning at 3,000 rpm with 2 A and a 0.1 N m load step after 20 ms. Tolerances: currents within 1 mA
    /// (measured 0.4 mA), the bus within 0.5 mV (measured 0.07 mV), the speed within 0.01 rad/s (measured 0.002),
    /// codes and counter within one.
    #[test]
    fn spinning_with_a_load_step_matches_the_reference() {
        let p = PlantParams::reference();
        let load = |n: usize| if n < 500 { 0.0 } else { 0.1 };
        let d = compare(&p, |pl| pl.set_rotor_state(0.3, 314.0), |_| [0.0, 2.0], load, 1000);
        assert!(d.current_a < 1e-3 && d.bus_v < 5e-4 && d.speed_rad_s < 0.01, "{d:?}");
        assert!(d.adc_codes <= 1 && d.encoder_counts <= 1, "{d:?}");
    }

    /// 0.3 A at 955 rpm on the dynamometer: each phase current crosses zero every 4.5 ms (27 crossings in all), where
    /// a leg in dead time stops conducting through its diode and floats. With the shaft's motion given, the two
    /// integrators differ only in the electrical step: currents within 1 uA (measured 0.08 uA), the bus within
    /// 10 uV, identical codes.
    #[test]
    fn dead_time_and_zero_crossings_match_the_reference() {
        let p = PlantParams::reference();
        let driven = |pl: &mut Plant| pl.set_mechanics(Mechanics::Driven { speed_rad_s: 100.0 });
        let d = compare(&p, driven, |_| [0.0, 0.3], |_| 0.0, 1000);
        assert!(d.current_a < 1e-6 && d.bus_v < 1e-5 && d.adc_codes == 0, "{d:?}");
    }

    /// The geared preset (salient motor, 5:1 gear with backlash, compliant coupling, 36 V): a 5 A step from rest for
    /// 80 ms, through the backlash and the coupling's oscillation with the motor sticking. Tolerances: currents
    /// within 20 mA (measured 6.8 mA), the bus within 1 mV (0.3 mV), the speed within 0.05 rad/s (measured 0.022:
    /// the instant the motor sticks is found at the end of a half period, not of a 5 us segment; 0.022 rad/s is
    /// under 1 us of its 25,000 rad/s^2), codes within one, the counter within one.
    #[test]
    fn geared_preset_matches_the_reference() {
        let geared = PlantParams::from_toml_str(include_str!("../../presets/geared-36v.toml"), "geared-36v.toml")
            .expect("the preset");
        let d = compare(&geared, |_| {}, |n| [0.0, if n < 50 { 0.0 } else { 5.0 }], |_| 0.0, 2000);
        assert!(d.current_a < 0.02 && d.bus_v < 1e-3 && d.speed_rad_s < 0.05, "{d:?}");
        assert!(d.adc_codes <= 1 && d.encoder_counts <= 1, "{d:?}");
    }
}
