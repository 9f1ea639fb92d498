//! A dq current controller on the plant's true state, for the plant's own tests (`hal-sim/tests/plant.rs`, and the
//! comparison of the integrator with the reference one in `reference`): PI with back-EMF and cross decoupling at
//! 1 kHz bandwidth, min-max centred modulation, the voltage rotated by the angle advance of one period (the delay
//! from the sample to the middle of the period the duties act in). Not the firmware's loop: it reads the true
//! currents and angle, so what a test measures is the plant's physics, not the drive's sensing.

use core::f64::consts::PI;

use firmware::hal::power::{PwmCommand, PWM_PERIOD_TICKS};

use super::{PlantParams, PlantState, PERIOD_S};

/// The controller's state and gains.
#[derive(Clone, Debug)]
pub struct TrueStateCurrentLoop {
    kp: f64,
    ki: f64,
    int: [f64; 2],
    p: PlantParams,
}

impl TrueStateCurrentLoop {
    /// The controller for the plant `p`: `Kp = Lq wc`, `Ki = (R + R_switch) wc`, `wc` = 2 pi 1 kHz.
    #[must_use]
    pub fn new(p: &PlantParams) -> Self {
        let wc = 2.0 * PI * 1000.0;
        let r = p.phase_resistance_ohm + p.switch_resistance_ohm;
        Self { kp: p.lq_h * wc, ki: r * wc, int: [0.0; 2], p: p.clone() }
    }

    /// The duties of the next period for the state `s` (sampled at the period centre) and the demand
    /// `reference_dq` (A).
    pub fn update(&mut self, s: &PlantState, reference_dq: [f64; 2]) -> PwmCommand {
        let p = &self.p;
        let v_lim = s.bus_voltage_v / 3f64.sqrt();
        let mut v = [0.0; 2];
        for k in 0..2 {
            let e = reference_dq[k] - s.i_dq_a[k];
            self.int[k] = (self.int[k] + self.ki * PERIOD_S * e).clamp(-v_lim, v_lim);
            v[k] = self.kp * e + self.int[k];
        }
        let we = s.omega_e_rad_s;
        v[0] -= we * p.lq_h * s.i_dq_a[1];
        v[1] += we * (p.ld_h * s.i_dq_a[0] + p.flux_linkage_wb);
        let (sn, cs) = (s.theta_e_rad + we * PERIOD_S).sin_cos();
        let alpha = v[0] * cs - v[1] * sn;
        let beta = v[0] * sn + v[1] * cs;
        let h = 0.5 * 3f64.sqrt();
        let ph = [alpha, -0.5 * alpha + h * beta, -0.5 * alpha - h * beta];
        let mid = 0.5 * (ph.iter().copied().fold(f64::MIN, f64::max) + ph.iter().copied().fold(f64::MAX, f64::min));
        let arr = f64::from(PWM_PERIOD_TICKS);
        let duty = ph.map(|x| ((0.5 + (x - mid) / s.bus_voltage_v).clamp(0.0, 1.0) * arr).round() as u16);
        PwmCommand { duty, enabled: true }
    }
}
