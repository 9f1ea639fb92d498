//! The drivetrain between the rotor and the load: the gear (ratio, backlash at the output, efficiency), the coupling
//! between the gear output and the load (a spring and a damper in parallel, in series with the backlash's dead band)
//! and the load side (inertia and Coulomb friction at the output, the external load torque).
//!
//! * **Rigid** (`coupling_stiffness_nm_per_rad` = 0): one mass. The motor shaft carries the rotor plus the load
//!   inertia reflected through the gear (`J_load / N^2`), the load's Coulomb friction (`T_cl / (eta N)`) and the
//!   external load torque (`T / (eta N)` while the motor drives it, `eta T / N` while the load drives the motor);
//!   the load angle is `theta_m / N`. With the reference plant's direct drive (`N` = 1, `eta` = 1, no load friction)
//!   every one of these is an exact identity in floating point, so the reference plant integrates bit for bit as
//!   it did before the drivetrain existed.
//! * **Compliant** (`coupling_stiffness_nm_per_rad` > 0): two masses. The load angle and speed join the integrated
//!   state; the coupling torque at the output is `T_s = k dz(theta_m / N - theta_l) + c (omega_m / N - omega_l)`
//!   where `dz` is the backlash's dead band (zero inside `+-backlash / 2`, the excess outside). With backlash the
//!   contact only pushes (a torque that would pull the teeth apart is zero) and the damper acts only in contact.
//!   The motor sees `T_s` through the gear with the efficiency on the side that delivers power; the load obeys
//!   `J_load d omega_l / dt = T_s - T_load - T_cl sgn(omega_l)` with the same stiction rule as the motor (a load
//!   at rest stays at rest while `|T_s - T_load| <= T_cl`, decided at the start of each segment or half-period stretch).

use super::PlantParams;

/// The drivetrain's constants for one period.
#[derive(Clone, Copy, Debug)]
pub(super) struct Drivetrain {
    /// Motor turns per output turn.
    pub(super) ratio: f64,
    /// Gear efficiency in (0, 1].
    pub(super) efficiency: f64,
    /// Half the backlash at the output, in rad.
    pub(super) half_gap_rad: f64,
    /// Coupling stiffness, in N m/rad (0: rigid).
    pub(super) stiffness: f64,
    /// Coupling damping, in N m s/rad.
    pub(super) damping: f64,
    /// Load inertia at the output, in kg m^2.
    pub(super) j_load: f64,
    /// Coulomb friction of the load at the output, in N m.
    pub(super) t_coulomb_load: f64,
    /// Two masses on a compliant coupling (else the load is rigidly on the gear output).
    pub(super) compliant: bool,
}

/// How the load moves over one segment.
#[derive(Clone, Copy, Debug)]
pub(super) enum LoadMotion {
    /// Rigidly on the gear output: not integrated, set from the motor after the segment.
    Follows,
    /// Held by its static friction.
    Frozen,
    /// Free, with the friction sign for the segment (as [`super::mechanics::SegmentMotion::Free`]).
    Free { zero_speed_friction_sign: f64 },
}

impl Drivetrain {
    /// The drivetrain of `p`.
    pub(super) fn new(p: &PlantParams) -> Self {
        Self {
            ratio: p.gear_ratio,
            efficiency: p.gear_efficiency,
            half_gap_rad: 0.5 * p.gear_backlash_deg.to_radians(),
            stiffness: p.coupling_stiffness_nm_per_rad,
            damping: p.coupling_damping_nm_s_per_rad,
            j_load: p.load_inertia_kg_m2,
            t_coulomb_load: p.load_coulomb_friction_nm,
            compliant: p.coupling_is_compliant(),
        }
    }

    /// The torque at the motor shaft of a torque `t_out` at the output (positive opposing positive rotation) with
    /// the motor at `omega_m`: the gear's losses fall on the side that delivers power (the motor while `t_out`
    /// opposes its motion or the motor is at rest).
    #[inline(always)]
    pub(super) fn reflect(&self, t_out: f64, omega_m: f64) -> f64 {
        if t_out * omega_m >= 0.0 {
            t_out / (self.efficiency * self.ratio)
        } else {
            t_out * self.efficiency / self.ratio
        }
    }

    /// The coupling torque at the output (positive: driving the load forward, holding the motor back) with the
    /// motor at `theta_m`, `omega_m` and the load at `theta_l`, `omega_l`.
    #[inline(always)]
    pub(super) fn coupling_torque(&self, theta_m: f64, omega_m: f64, theta_l: f64, omega_l: f64) -> f64 {
        let twist = theta_m / self.ratio - theta_l;
        let twist_rate = omega_m / self.ratio - omega_l;
        if self.half_gap_rad <= 0.0 {
            return self.stiffness * twist + self.damping * twist_rate;
        }
        let spring = if twist > self.half_gap_rad {
            twist - self.half_gap_rad
        } else if twist < -self.half_gap_rad {
            twist + self.half_gap_rad
        } else {
            return 0.0;
        };
        let torque = self.stiffness * spring + self.damping * twist_rate;
        // Teeth in contact push; they cannot pull.
        if torque * spring > 0.0 {
            torque
        } else {
            0.0
        }
    }

    /// The load's derivatives (d omega_l, d theta_l) under the coupling torque `t_s` and the external torque
    /// `t_load`, at speed `omega_l`.
    #[inline(always)]
    pub(super) fn load_derivatives(&self, mode: LoadMotion, t_s: f64, t_load: f64, omega_l: f64) -> (f64, f64) {
        match mode {
            LoadMotion::Follows | LoadMotion::Frozen => (0.0, 0.0),
            LoadMotion::Free { zero_speed_friction_sign } => {
                ((t_s - t_load - self.t_coulomb_load * zero_speed_friction_sign) / self.j_load, omega_l)
            }
        }
    }
}
