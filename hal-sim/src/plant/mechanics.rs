//! The shaft: the electromagnetic torque, the equation of motion with viscous and Coulomb friction (stiction
//! included), how each integration segment moves the shaft ([`SegmentMotion`]), and the load torque acting on it.

use super::coeffs::Coeffs;
use super::{Mechanics, Plant};

fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Per-segment mechanical mode, decided at the segment start (stiction needs the sign of the breakaway).
#[derive(Clone, Copy, Debug)]
pub(super) enum SegmentMotion {
    /// Angle and speed frozen (locked, or stuck by static friction).
    Frozen,
    /// Constant speed.
    Driven(f64),
    /// Free, with the friction sign for the segment (the sign of the speed at its start, or of the breakaway torque
    /// at rest).
    Free { zero_speed_friction_sign: f64 },
}

impl Coeffs {
    /// Electromagnetic torque at the currents `i_d`, `i_q`, in N m.
    #[inline(always)]
    pub(super) fn torque(&self, i_d: f64, i_q: f64) -> f64 {
        1.5 * self.p * (self.psi * i_q + (self.ld - self.lq) * i_d * i_q)
    }

    /// Mechanical derivatives (d omega, d theta).
    #[inline(always)]
    pub(super) fn shaft_derivatives(&self, mode: SegmentMotion, torque: f64, load: f64, omega: f64) -> (f64, f64) {
        match mode {
            SegmentMotion::Frozen => (0.0, 0.0),
            SegmentMotion::Driven(w) => (0.0, w),
            SegmentMotion::Free { zero_speed_friction_sign } => {
                // One friction sign for the whole segment (the speed's at its start): re-evaluating it at the RK4
                // stages lets the stages straddling zero cancel, so a speed below `T_c h / J` would creep on
                // instead of stopping (0.14 rad/s with an engaged brake); a sign change is clamped afterwards.
                let s = zero_speed_friction_sign;
                ((torque - load - self.b_visc * omega - self.t_coulomb * s) / self.j, omega)
            }
        }
    }
}

impl Plant {
    /// Evaluate the load torque (constant plus profile) at `t_in_period` into the period, for the next segment.
    pub(super) fn update_load(&mut self, t_in_period: f64) {
        let time = self.time_s() + t_in_period;
        let extra = match self.load_profile.as_mut() {
            Some(f) => f(time, self.theta_m, self.omega_m),
            None => 0.0,
        };
        self.last_load_nm = self.load_torque_nm + extra;
    }

    /// Mechanical mode of the next segment (stiction decided from the torques at its start).
    pub(super) fn segment_motion(&self, k: &Coeffs) -> SegmentMotion {
        match self.mechanics {
            Mechanics::Locked => SegmentMotion::Frozen,
            Mechanics::Driven { speed_rad_s } => SegmentMotion::Driven(speed_rad_s),
            Mechanics::Free => {
                if self.omega_m != 0.0 {
                    SegmentMotion::Free { zero_speed_friction_sign: sign(self.omega_m) }
                } else {
                    let drive = k.torque(self.i_d, self.i_q) - self.last_load_nm;
                    if drive.abs() <= k.t_coulomb {
                        SegmentMotion::Frozen
                    } else {
                        SegmentMotion::Free { zero_speed_friction_sign: sign(drive) }
                    }
                }
            }
        }
    }

    /// After a free segment: a speed that changed sign stops at zero (friction cannot reverse the motion).
    pub(super) fn clamp_speed(&mut self, mode: SegmentMotion, omega_before: f64) {
        if let SegmentMotion::Free { zero_speed_friction_sign } = mode {
            let reference = if omega_before != 0.0 { sign(omega_before) } else { zero_speed_friction_sign };
            if self.omega_m * reference < 0.0 {
                self.omega_m = 0.0;
            }
        }
    }
}
