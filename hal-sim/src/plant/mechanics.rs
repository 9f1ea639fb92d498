//! The shaft: the electromagnetic torque, the equation of motion with viscous and Coulomb friction (stiction
//! included), how each integration segment moves the shaft ([`SegmentMotion`]) and the load ([`ShaftSegment`]),
//! the load torque acting at the output ([`super::drivetrain`] joins the two), and the shaft held over a stretch of
//! switching intervals ([`Stretch`]).

use super::coeffs::Coeffs;
use super::drivetrain::LoadMotion;
use super::electrical::{abc_to_dq, dq_to_abc, remove_phase_current, rk4};
use super::{Mechanics, Plant, PERIOD_S};

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

/// The shaft over a stretch of switching intervals (half a period: from the period start to the sample instant,
/// or from there to the period end; shorter where the outputs stop switching, where the torque breaks a held motor
/// away, and, with a load profile, to one segment of at most `T / substeps_per_period`).
///
/// The shaft's time constants are far longer than a period (the reference plant's mechanical time constant is
/// seconds, the geared preset's coupling resonance 60 Hz), so over a stretch the electrical intervals see it turn
/// at a constant speed `omega_m`: the speed at the start plus half a stretch of the acceleration the last stretch
/// had (a predictor: the angle at the end is then what a constant acceleration gives). The stretch collects the
/// integral of the electromagnetic torque; [`Plant::finish_stretch`] then moves the shaft and the load over the
/// stretch with its mean, in one RK4 step.
#[derive(Clone, Copy, Debug)]
pub(super) struct Stretch {
    /// Start, in s into the period.
    t0: f64,
    /// How the motor and the load move (decided at the start, as for a segment).
    shaft: ShaftSegment,
    /// Integral of the electromagnetic torque since the start, in N m s.
    pub(super) torque_integral: f64,
    /// The motor's mechanical speed the electrical intervals assume, in rad/s.
    pub(super) omega_m: f64,
    /// Sine of the electrical angle at the start of the next interval.
    pub(super) sin: f64,
    /// Cosine of the electrical angle at the start of the next interval.
    pub(super) cos: f64,
    /// The free motor is held by static friction over the stretch: the stretch ends where the torque breaks it
    /// away ([`Plant::stretch_breaks_away`]).
    held: bool,
}

impl Plant {
    /// A stretch of switching intervals starting at `t0` into the period: the load torque then, and the shaft's
    /// motion decided from the torques at that instant.
    pub(super) fn start_stretch(&mut self, k: &Coeffs, t0: f64) -> Stretch {
        self.update_load(t0);
        let shaft = self.shaft_segment(k);
        let omega_m = match shaft.motor {
            SegmentMotion::Frozen => 0.0,
            SegmentMotion::Driven(w) => w,
            SegmentMotion::Free { .. } => self.omega_m + self.stretch_acceleration * 0.25 * PERIOD_S,
        };
        let (sin, cos) = (k.p * self.theta_m).sin_cos();
        let held = self.mechanics == Mechanics::Free && matches!(shaft.motor, SegmentMotion::Frozen);
        Stretch { t0, shaft, torque_integral: 0.0, omega_m, sin, cos, held }
    }

    /// The motor held by static friction over `stretch` breaks away with the currents now: the stretch ends here,
    /// so that the motion starts at the interval where it would (as the stiction rule of a segment decides).
    pub(super) fn stretch_breaks_away(&self, k: &Coeffs, stretch: &Stretch) -> bool {
        stretch.held && (k.torque(self.i_d, self.i_q) - stretch.shaft.motor_load).abs() > k.t_coulomb
    }

    /// End a stretch at `t1` into the period: the shaft and the load move over it under the mean electromagnetic
    /// torque (one RK4 step of `[omega_m, theta_m, omega_l, theta_l]`), with the same friction, stiction and
    /// sign-change rules as a segment; then the encoder follows.
    pub(super) fn finish_stretch(&mut self, k: &Coeffs, stretch: Stretch, t1: f64) {
        let h = t1 - stretch.t0;
        if h <= 0.0 {
            return;
        }
        let torque = stretch.torque_integral / h;
        let (omega_before, omega_l_before) = (self.omega_m, self.omega_l);
        let shaft = &stretch.shaft;
        match shaft.motor {
            SegmentMotion::Free { zero_speed_friction_sign } if !k.drive.compliant => {
                // One mass: `d omega / dt = drive - decay omega` with constant `drive` over the stretch.
                let inv_j = 1.0 / k.j;
                let drive = (torque - shaft.motor_load - k.t_coulomb * zero_speed_friction_sign) * inv_j;
                let decay = k.b_visc * inv_j;
                let m0 = [self.omega_m, self.theta_m];
                [self.omega_m, self.theta_m] = rk4(&m0, h, |m: &[f64; 2]| [drive - decay * m[0], m[0]]);
            }
            _ => {
                let m0 = [self.omega_m, self.theta_m, self.omega_l, self.theta_l];
                let m1 = rk4(&m0, h, |m: &[f64; 4]| k.mechanical_derivatives(shaft, torque, *m));
                [self.omega_m, self.theta_m, self.omega_l, self.theta_l] = m1;
            }
        }
        self.end_segment(k, &stretch.shaft, omega_before, omega_l_before);
        // An open phase ([`super::faults::PlantFaults::phase_open`]) ends every interval at exactly zero current;
        // at the rotor's new angle (a few microradians from the frame the intervals used) it still does.
        if let Some(x) = self.faults.phase_open.filter(|&x| x < 3) {
            let (sn, cs) = (k.p * self.theta_m).sin_cos();
            let mut i = dq_to_abc(self.i_d, self.i_q, sn, cs);
            remove_phase_current(&mut i, x);
            [self.i_d, self.i_q] = abc_to_dq(i, sn, cs);
        }
        // The predictor of the next stretch; none after a stop (friction ended the motion) or without free motion.
        self.stretch_acceleration = match stretch.shaft.motor {
            SegmentMotion::Free { .. } if self.omega_m != 0.0 => (self.omega_m - omega_before) / h,
            _ => 0.0,
        };
        self.update_encoder();
    }

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
