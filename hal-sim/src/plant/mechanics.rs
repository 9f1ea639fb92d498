//! The shaft: the electromagnetic torque, the equation of motion with viscous and Coulomb friction (stiction
//! included), how each integration segment moves the shaft ([`SegmentMotion`]) and the load ([`ShaftSegment`]), and
//! the load torque acting at the output ([`super::drivetrain`] joins the two).

use super::coeffs::Coeffs;
use super::drivetrain::LoadMotion;
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

/// The mechanics of one segment: how the motor and the load move, and the torques constant over it.
#[derive(Clone, Copy, Debug)]
pub(super) struct ShaftSegment {
    /// How the motor shaft moves.
    pub(super) motor: SegmentMotion,
    /// How the load moves.
    pub(super) load: LoadMotion,
    /// Rigid drivetrain: the load's torque at the motor shaft (external load and nothing else; the load's friction
    /// is in the Coulomb friction), in N m. Unused with a compliant coupling, where it follows the state.
    pub(super) motor_load: f64,
    /// External load torque at the output, in N m.
    pub(super) external: f64,
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

impl Coeffs {
    /// Derivatives of the mechanical state `[omega_m, theta_m, omega_l, theta_l]` under the electromagnetic torque
    /// `torque` (the load's are zero when it follows the motor rigidly).
    #[inline(always)]
    pub(super) fn mechanical_derivatives(&self, seg: &ShaftSegment, torque: f64, m: [f64; 4]) -> [f64; 4] {
        let [omega, theta, omega_l, theta_l] = m;
        if !self.drive.compliant {
            let (dw, dth) = self.shaft_derivatives(seg.motor, torque, seg.motor_load, omega);
            return [dw, dth, 0.0, 0.0];
        }
        let t_s = self.drive.coupling_torque(theta, omega, theta_l, omega_l);
        let (dw, dth) = self.shaft_derivatives(seg.motor, torque, self.drive.reflect(t_s, omega), omega);
        let (dwl, dthl) = self.drive.load_derivatives(seg.load, t_s, seg.external, omega_l);
        [dw, dth, dwl, dthl]
    }
}

/// How a body at rest or moving at `omega` goes through a segment against `t_coulomb`, driven by `drive` (its
/// torque less the opposing ones).
fn friction_motion(omega: f64, drive: f64, t_coulomb: f64) -> Option<f64> {
    if omega != 0.0 {
        Some(sign(omega))
    } else if drive.abs() <= t_coulomb {
        None
    } else {
        Some(sign(drive))
    }
}

impl Plant {
    /// Evaluate the load torque (constant plus profile, at the output) at `t_in_period` into the period, for the
    /// next segment. The profile sees the load's angle and speed (the motor's over the ratio when rigid).
    pub(super) fn update_load(&mut self, t_in_period: f64) {
        let time = self.time_s() + t_in_period;
        let extra = match self.load_profile.as_mut() {
            Some(f) => f(time, self.theta_l, self.omega_l),
            None => 0.0,
        };
        self.last_load_nm = self.load_torque_nm + extra;
    }

    /// The mechanics of the next segment (stiction of the motor and of the load decided from the torques at its
    /// start).
    pub(super) fn shaft_segment(&self, k: &Coeffs) -> ShaftSegment {
        let d = &k.drive;
        let (motor_load, load) = if d.compliant {
            let t_s = d.coupling_torque(self.theta_m, self.omega_m, self.theta_l, self.omega_l);
            let load = match friction_motion(self.omega_l, t_s - self.last_load_nm, d.t_coulomb_load) {
                Some(s) => LoadMotion::Free { zero_speed_friction_sign: s },
                None => LoadMotion::Frozen,
            };
            (d.reflect(t_s, self.omega_m), load)
        } else {
            (d.reflect(self.last_load_nm, self.omega_m), LoadMotion::Follows)
        };
        ShaftSegment { motor: self.segment_motion(k, motor_load), load, motor_load, external: self.last_load_nm }
    }

    /// Mechanical mode of the motor over the next segment against the load `motor_load` at its shaft.
    fn segment_motion(&self, k: &Coeffs, motor_load: f64) -> SegmentMotion {
        match self.mechanics {
            Mechanics::Locked => SegmentMotion::Frozen,
            Mechanics::Driven { speed_rad_s } => SegmentMotion::Driven(speed_rad_s),
            Mechanics::Free => {
                match friction_motion(self.omega_m, k.torque(self.i_d, self.i_q) - motor_load, k.t_coulomb) {
                    Some(s) => SegmentMotion::Free { zero_speed_friction_sign: s },
                    None => SegmentMotion::Frozen,
                }
            }
        }
    }

    /// After a segment: a free speed that changed sign stops at zero (friction cannot reverse the motion), for the
    /// motor and for a compliantly coupled load; a rigidly coupled load follows the motor through the gear.
    pub(super) fn end_segment(&mut self, k: &Coeffs, seg: &ShaftSegment, omega_before: f64, omega_l_before: f64) {
        if let SegmentMotion::Free { zero_speed_friction_sign } = seg.motor {
            let reference = if omega_before != 0.0 { sign(omega_before) } else { zero_speed_friction_sign };
            if self.omega_m * reference < 0.0 {
                self.omega_m = 0.0;
            }
        }
        match seg.load {
            LoadMotion::Follows => self.follow_motor(k.drive.ratio),
            LoadMotion::Frozen => {}
            LoadMotion::Free { zero_speed_friction_sign } => {
                let reference = if omega_l_before != 0.0 { sign(omega_l_before) } else { zero_speed_friction_sign };
                if self.omega_l * reference < 0.0 {
                    self.omega_l = 0.0;
                }
            }
        }
    }

    /// Put the load where the motor holds it through a gear of `ratio` with the coupling relaxed.
    pub(super) fn follow_motor(&mut self, ratio: f64) {
        self.theta_l = self.theta_m / ratio;
        self.omega_l = self.omega_m / ratio;
    }
}
