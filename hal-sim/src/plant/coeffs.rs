//! The constants of one period ([`Coeffs`]), read from the parameters, the winding temperature and the brake at
//! the start of each period, and the DC source that feeds the bus.

use super::drivetrain::Drivetrain;
use super::Plant;

/// Constants of one period, copied out of the parameters so the integrator borrows nothing.
#[derive(Clone, Copy, Debug)]
pub(super) struct Coeffs {
    /// Pole pairs.
    pub(super) p: f64,
    /// Permanent-magnet flux linkage, in Wb.
    pub(super) psi: f64,
    /// d-axis inductance, in H.
    pub(super) ld: f64,
    /// q-axis inductance, in H.
    pub(super) lq: f64,
    /// Resistance in series with each phase: the winding at its temperature plus a switch, in ohm.
    pub(super) r: f64,
    /// Switch resistance, in ohm.
    pub(super) r_switch: f64,
    /// Diode forward drop, in V.
    pub(super) v_diode: f64,
    /// Inertia on the motor shaft, in kg m^2: the rotor plus the reflected load when rigid, the rotor alone when
    /// the load sits on a compliant coupling.
    pub(super) j: f64,
    /// Viscous friction, in N m s/rad.
    pub(super) b_visc: f64,
    /// Coulomb friction at the motor shaft, holding brake (and, when rigid, the reflected load friction) included,
    /// in N m.
    pub(super) t_coulomb: f64,
    /// The gear, the coupling and the load side.
    pub(super) drive: Drivetrain,
    /// Open-circuit voltage of the DC source, in V.
    pub(super) v_source: f64,
    /// Internal resistance of the DC source, in ohm.
    pub(super) r_source: f64,
    /// The DC source can sink current (else its current is never negative).
    pub(super) source_sinks: bool,
    /// Bus capacitance, in F.
    pub(super) c_bus: f64,
    /// Conductance of the braking resistor while the chopper conducts this period, in S (0: off or none).
    pub(super) g_chopper: f64,
    /// Reciprocals for the switching intervals' inner loop (a multiplication instead of a division): `1 / Ld`,
    /// `1 / Lq` (1/H), `1 / C_bus` (1/F), `1 / R_source` (S).
    pub(super) inv_ld: f64,
    pub(super) inv_lq: f64,
    pub(super) inv_c_bus: f64,
    pub(super) g_source: f64,
}

impl Coeffs {
    /// Current delivered by the DC source into the bus at bus voltage `v_bus`, in A.
    #[inline(always)]
    pub(super) fn source_current(&self, v_bus: f64) -> f64 {
        let i = (self.v_source - v_bus) / self.r_source;
        if self.source_sinks {
            i
        } else {
            i.max(0.0)
        }
    }

    /// [`Coeffs::bus_inflow`] with the source's conductance instead of its resistance (the switching intervals').
    #[inline(always)]
    pub(super) fn bus_inflow_fast(&self, v_bus: f64) -> f64 {
        let i = (self.v_source - v_bus) * self.g_source;
        let source = if self.source_sinks { i } else { i.max(0.0) };
        source - self.g_chopper * v_bus
    }

    /// Current into the bus capacitor from outside the inverter at bus voltage `v_bus`: the source's, less the
    /// braking resistor's while the chopper conducts, in A.
    #[inline(always)]
    pub(super) fn bus_inflow(&self, v_bus: f64) -> f64 {
        self.source_current(v_bus) - self.g_chopper * v_bus
    }
}

impl Plant {
    /// The constants of a period starting now.
    pub(super) fn coeffs(&self) -> Coeffs {
        let p = &self.params;
        let drive = Drivetrain::new(p);
        let (j, load_friction) = if drive.compliant {
            (p.rotor_inertia_kg_m2, 0.0)
        } else {
            (p.total_inertia_kg_m2(), p.load_coulomb_friction_nm / (drive.efficiency * drive.ratio))
        };
        Coeffs {
            p: f64::from(p.pole_pairs),
            psi: p.flux_linkage_wb,
            ld: p.ld_h,
            lq: p.lq_h,
            r: self.phase_resistance() + p.switch_resistance_ohm,
            r_switch: p.switch_resistance_ohm,
            v_diode: p.diode_drop_v,
            j,
            b_visc: p.viscous_friction_nm_s_rad,
            t_coulomb: p.coulomb_friction_nm + self.io.brake_friction_nm(&p.io) + load_friction,
            drive,
            v_source: p.source_voltage_v,
            r_source: p.source_resistance_ohm,
            source_sinks: p.source_sinks_current,
            c_bus: p.bus_capacitance_f,
            g_chopper: if self.chopper_gate { 1.0 / p.chopper_resistance_ohm } else { 0.0 },
            inv_ld: 1.0 / p.ld_h,
            inv_lq: 1.0 / p.lq_h,
            inv_c_bus: 1.0 / p.bus_capacitance_f,
            g_source: 1.0 / p.source_resistance_ohm,
        }
    }

    /// Phase resistance at the present winding temperature, in ohm.
    pub(super) fn phase_resistance(&self) -> f64 {
        let p = &self.params;
        p.phase_resistance_ohm * (1.0 + p.copper_temp_coeff_per_k * (self.t_winding - p.resistance_reference_temp_c))
    }
}
