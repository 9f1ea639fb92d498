//! Plant parameters and the named presets.
//!
//! Every field carries its unit in its name. [`PlantParams::reference`] is the reference plant of
//! `shared/design/ARCHITECTURE.md` ("Reference plant" and "Reference hardware"); each number says where it comes
//! from. Values marked *assumption* are not in the architecture document and were chosen here as plausible for the
//! class of hardware; they are named so tests and presets can override them.

use core::f64::consts::PI;

use super::io::IoParams;

/// Everything that defines a plant: supply, inverter, motor, mechanics, thermal model, sensors and integration.
///
/// Conventions: phase currents are positive when flowing from the inverter into the motor; the dq frame is the
/// amplitude-invariant one (`i_q` equals the phase-current amplitude of a pure q current), so the torque is
/// `1.5 * p * (psi * i_q + (Ld - Lq) * i_d * i_q)`; the mechanical angle is zero when the rotor d axis (magnet north)
/// is aligned with the phase A axis, and the electrical angle is `pole_pairs * mechanical angle`.
///
/// A plant file ([`super::file`]) names these fields as its keys; every field but `io` can be given there.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantParams {
    // ---- DC supply and bus ----
    /// Open-circuit voltage of the DC source, in V.
    pub source_voltage_v: f64,
    /// Series resistance between the source and the bus capacitor, in ohm.
    pub source_resistance_ohm: f64,
    /// Whether the source can sink current (a regenerative supply). `false` models a supply behind a diode: the
    /// source current is never negative, so regenerated energy charges the bus capacitor and raises the voltage.
    pub source_sinks_current: bool,
    /// Bus capacitance, in F.
    pub bus_capacitance_f: f64,
    /// Braking resistor switched across the bus by the chopper output, in ohm; `f64::INFINITY`: no chopper fitted
    /// (the gate then does nothing).
    pub chopper_resistance_ohm: f64,

    // ---- Inverter ----
    /// Dead time inserted at every switching edge (both switches of a leg off), in s.
    pub dead_time_s: f64,
    /// On-state resistance of each power switch, in ohm (in series with each phase while a switch conducts).
    pub switch_resistance_ohm: f64,
    /// Forward voltage of the body diodes (conducting during dead time and when the outputs are disabled), in V.
    pub diode_drop_v: f64,
    /// Threshold of the hardware over-current comparator on any phase current (break input), in A;
    /// `f64::INFINITY` disables it.
    pub break_current_a: f64,

    // ---- Motor (sinusoidal PMSM, rotor dq frame) ----
    /// Pole pairs.
    pub pole_pairs: u32,
    /// Phase resistance at `resistance_reference_temp_c`, in ohm (per phase, star equivalent).
    pub phase_resistance_ohm: f64,
    /// Temperature at which `phase_resistance_ohm` holds, in degC.
    pub resistance_reference_temp_c: f64,
    /// Temperature coefficient of the winding resistance, in 1/K (copper: 0.0039); 0 makes R constant.
    pub copper_temp_coeff_per_k: f64,
    /// d-axis inductance, in H.
    pub ld_h: f64,
    /// q-axis inductance, in H.
    pub lq_h: f64,
    /// Permanent-magnet flux linkage (amplitude), in Wb (V s/rad electrical).
    pub flux_linkage_wb: f64,

    // ---- Mechanics (see `drivetrain` for the gear, the coupling and the load side) ----
    /// Rotor inertia, in kg m^2.
    pub rotor_inertia_kg_m2: f64,
    /// Load inertia at the gear output (the load side of the coupling), in kg m^2. With a rigid coupling the motor
    /// sees `load_inertia_kg_m2 / gear_ratio^2` on its shaft.
    pub load_inertia_kg_m2: f64,
    /// Viscous friction at the motor shaft, in N m s/rad.
    pub viscous_friction_nm_s_rad: f64,
    /// Coulomb (and breakaway) friction at the motor shaft, in N m.
    pub coulomb_friction_nm: f64,
    /// Gear reduction: motor turns per output turn (1 = direct drive).
    pub gear_ratio: f64,
    /// Total backlash of the gear, at the output, in degrees (0 = none). Needs a compliant coupling
    /// (`coupling_stiffness_nm_per_rad > 0`): the dead band sits in series with the coupling's spring.
    pub gear_backlash_deg: f64,
    /// Gear efficiency in (0, 1]: the motor delivers `T_out / (efficiency * ratio)` to drive a torque `T_out` at
    /// the output and receives `efficiency * T_out / ratio` when the output drives it back.
    pub gear_efficiency: f64,
    /// Stiffness of the coupling between the gear output and the load, in N m/rad (0 = rigid: one mass).
    pub coupling_stiffness_nm_per_rad: f64,
    /// Damping of the coupling (in parallel with its spring), in N m s/rad.
    pub coupling_damping_nm_s_per_rad: f64,
    /// Coulomb (and breakaway) friction of the load, at the output, in N m.
    pub load_coulomb_friction_nm: f64,

    // ---- Ratings (not used by the simulation; for tests and presets) ----
    /// Nominal (continuous) current, in A (q-current amplitude).
    pub nominal_current_a: f64,
    /// Peak current, in A.
    pub peak_current_a: f64,
    /// Maximum speed, in rpm.
    pub max_speed_rpm: f64,
    /// Winding temperature limit, in degC.
    pub winding_limit_c: f64,

    // ---- Thermal ----
    /// Ambient temperature and initial temperature of every thermal node, in degC.
    pub ambient_c: f64,
    /// Thermal time constant of the winding (winding capacity x winding-to-housing resistance), in s.
    pub winding_time_constant_s: f64,
    /// Thermal time constant of the housing (housing capacity x housing-to-ambient resistance), in s.
    pub housing_time_constant_s: f64,
    /// Thermal resistance winding to housing, in K/W.
    pub winding_to_housing_k_per_w: f64,
    /// Thermal resistance housing to ambient, in K/W.
    pub housing_to_ambient_k_per_w: f64,
    /// Thermal time constant of the power stage (heat sink), in s.
    pub power_stage_time_constant_s: f64,
    /// Thermal resistance power stage to ambient, in K/W.
    pub power_stage_to_ambient_k_per_w: f64,

    // ---- Position sensors ----
    /// Encoder quadrature counts per mechanical revolution (4 x lines): any value, power of two or not (2,000,
    /// 4,000, 5,000, 10,000 for the common 500 / 1,000 / 1,250 / 2,500-line encoders). The 16-bit counter wraps
    /// at 2^16 independently of the revolution and the index is the total count congruent to `index_count`
    /// ([`super::sensors`]), as on a real encoder. [`crate::sim::Simulation`] writes `counts / 4` to 0x3010:01,
    /// so for the drive to match it is a multiple of 4 in 64..=10,000,000 (0x3010:01 = 16..=2,500,000 lines).
    pub encoder_counts_per_rev: u32,
    /// Encoder count at mechanical angle 0 (the counter's value when the d axis is aligned with phase A).
    pub encoder_offset_counts: i64,
    /// Encoder count (modulo `encoder_counts_per_rev`) whose quadrature state carries the index pulse.
    pub index_count: u32,
    /// Quadrature counts per revolution of a second encoder on the load (at the output); 0 = none fitted.
    pub load_encoder_counts_per_rev: u32,
    /// Electrical angle at which Hall 1 rises (for positive rotation), in rad; Hall 2 and Hall 3 follow at
    /// +120 and +240 degrees electrical.
    pub hall_offset_rad: f64,
    /// Single-turn bits of an SSI absolute encoder on the motor shaft (`2^bits` increments per revolution); 0 = no
    /// SSI sensor fitted. Its frame ([`super::sensors::ssi_frame`]) is in the drive's format
    /// (`firmware::sensors::ssi`): start bit, multi-turn and single-turn bits MSB first, stop bit.
    pub ssi_single_turn_bits: u32,
    /// Multi-turn bits of the SSI encoder (the revolutions it counts, kept without power: its position is absolute).
    pub ssi_multi_turn_bits: u32,
    /// The SSI encoder sends Gray code (else binary).
    pub ssi_gray: bool,
    /// The SSI master clocks the frame's start and stop bits (the drive's 0x3012:03 bit 8).
    pub ssi_frame_check: bool,
    /// The SSI encoder's position at mechanical angle 0, in its increments (where its zero and its multi-turn
    /// count sit on the shaft; a multiple of `2^single-turn bits` leaves it aligned with the rotor, as a maxon
    /// encoder is from the factory).
    pub ssi_offset_counts: i64,

    // ---- ADC ----
    /// Shunt-channel gains (phases A, B, C), in LSB per A of phase current (negative for an inverting amplifier).
    pub shunt_gain_lsb_per_a: [f64; 3],
    /// Shunt-channel offsets (phases A, B, C) added to mid-scale (2048), in LSB.
    pub shunt_offset_lsb: [f64; 3],
    /// RMS noise of each shunt conversion, in LSB.
    pub shunt_noise_lsb_rms: f64,
    /// Bus-voltage channel gain, in LSB per V.
    pub bus_gain_lsb_per_v: f64,
    /// RMS noise of the bus-voltage conversion, in LSB.
    pub bus_noise_lsb_rms: f64,
    /// ADC reference voltage (full scale = 4095 at this input voltage), in V.
    pub adc_reference_v: f64,
    /// Temperature-sensor output at 0 degC, in V.
    pub temp_sensor_v_at_0c: f64,
    /// Temperature-sensor slope, in V/K.
    pub temp_sensor_v_per_k: f64,
    /// RMS noise of the temperature conversion, in LSB.
    pub temp_noise_lsb_rms: f64,

    // ---- Integration ----
    /// Sub-steps per PWM period: with the outputs off, the integrator's maximum step is `T / substeps_per_period`
    /// (the instants where a diode stops conducting are found to that step). The switching instants and the sample
    /// instant are always segment boundaries; with the outputs switching each interval between them is one step.
    /// 8 by default (5 us steps).
    pub substeps_per_period: u32,

    // ---- Digital I/O ----
    /// Limit and home switches on the inputs, and the holding brake (see [`super::io`]). Not part of a plant file:
    /// the switches belong to the scenario's axis, not to the motor; a file always gets [`IoParams::reference`].
    #[serde(skip, default = "IoParams::reference")]
    pub io: IoParams,
}

impl PlantParams {
    /// The reference plant of `shared/design/ARCHITECTURE.md`: a 24 V, 70 W class BLDC servo motor on a
    /// 25 kHz three-shunt inverter. Sources of each number:
    ///
    /// | Quantity | Value | Source |
    /// |---|---|---|
    /// | DC source, series resistance, bus capacitance | 24 V, 0.05 ohm, 470 uF | ARCHITECTURE "Reference plant" |
    /// | Source sinks current | no (no braking chopper: regeneration raises the bus) | ARCHITECTURE |
    /// | Braking chopper | none | ARCHITECTURE ([`Self::reference_with_chopper`] adds one) |
    /// | Dead time, switch resistance | 0.5 us, 10 mohm | ARCHITECTURE "Inverter" |
    /// | Body-diode drop | 0.7 V | assumption (typical MOSFET body diode) |
    /// | Break (over-current comparator) | 15 A | assumption: above the 10 A peak, inside the +-16.5 A ADC span |
    /// | Pole pairs, R, Ld = Lq | 7, 0.26 ohm, 0.165 mH | ARCHITECTURE |
    /// | Flux linkage | kt / (1.5 p) = 0.0335 / 10.5 = 3.190 mWb | from kt = 0.0335 Nm/A (ARCHITECTURE) |
    /// | R temperature coefficient | 0.0039 /K from 25 degC | copper (physics); R = 0.26 ohm at 25 degC |
    /// | Rotor / load inertia | 44 g cm^2 / 3 x 44 g cm^2 | ARCHITECTURE |
    /// | Viscous / Coulomb friction | 2e-6 Nm s/rad / 3 mNm | ARCHITECTURE |
    /// | Gear, coupling, load friction, load encoder | none: direct drive, rigid, 0, none | ARCHITECTURE (load rigidly coupled) |
    /// | Nominal / peak current, max speed, winding limit | 3.2 A / 10 A, 5,000 rpm, 125 degC | ARCHITECTURE |
    /// | Winding / housing time constants | 20 s / 600 s | ARCHITECTURE |
    /// | Thermal resistances | 5 K/W winding-housing, 20 K/W housing-ambient | derived: nominal current's copper loss 1.5 R I_N^2 = 4.0 W heats the winding by 100 K (25 -> 125 degC) => 25 K/W in total; the 1:4 split is an assumption |
    /// | Power stage thermal | 60 s, 5 K/W | assumption |
    /// | Encoder | 1,024 lines = 4,096 counts/rev, index at count 0, count 0 at d axis = phase A | ARCHITECTURE; alignment: assumption (factory-aligned like a maxon motor) |
    /// | Halls | H1 rises at 0 deg electrical, H2 at 120, H3 at 240 | assumption, see `sensors::hall_state` |
    /// | Shunt ADC | 12 bit spanning +-16.5 A: 4096 / 33 = 124.12 LSB/A, mid-scale 2048 | ARCHITECTURE |
    /// | Shunt offsets | +37, -24, +12 LSB | ARCHITECTURE allows up to +-50 LSB; fixed values chosen so calibration is exercised |
    /// | Shunt noise | 2 LSB rms | ARCHITECTURE |
    /// | Bus ADC | 12 bit, 60 V full scale: 4095 / 60 = 68.25 LSB/V, 1 LSB rms noise | ARCHITECTURE; noise: assumption |
    /// | Temperature sensor | linear 0.5 V + 10 mV/K (MCP9700/TMP235 class) on a 3.3 V ADC, 1 LSB rms | assumption |
    /// | Sub-steps | at most 5 us per step (8 per period) | this module's integrator choice |
    /// | Digital I/O | inputs 1..3 negative limit, positive limit, home switch, no positions; no brake | [`IoParams::reference`] |
    pub fn reference() -> Self {
        let kt_nm_per_a = 0.0335;
        let pole_pairs = 7;
        let rotor_inertia_kg_m2 = 44.0e-7; // 44 g cm^2
        Self {
            source_voltage_v: 24.0,
            source_resistance_ohm: 0.05,
            source_sinks_current: false,
            bus_capacitance_f: 470.0e-6,
            chopper_resistance_ohm: f64::INFINITY,
            dead_time_s: 0.5e-6,
            switch_resistance_ohm: 0.010,
            diode_drop_v: 0.7,
            break_current_a: 15.0,
            pole_pairs,
            phase_resistance_ohm: 0.26,
            resistance_reference_temp_c: 25.0,
            copper_temp_coeff_per_k: 0.0039,
            ld_h: 0.165e-3,
            lq_h: 0.165e-3,
            flux_linkage_wb: kt_nm_per_a / (1.5 * f64::from(pole_pairs)),
            rotor_inertia_kg_m2,
            load_inertia_kg_m2: 3.0 * rotor_inertia_kg_m2,
            viscous_friction_nm_s_rad: 2.0e-6,
            coulomb_friction_nm: 3.0e-3,
            gear_ratio: 1.0,
            gear_backlash_deg: 0.0,
            gear_efficiency: 1.0,
            coupling_stiffness_nm_per_rad: 0.0,
            coupling_damping_nm_s_per_rad: 0.0,
            load_coulomb_friction_nm: 0.0,
            nominal_current_a: 3.2,
            peak_current_a: 10.0,
            max_speed_rpm: 5000.0,
            winding_limit_c: 125.0,
            ambient_c: 25.0,
            winding_time_constant_s: 20.0,
            housing_time_constant_s: 600.0,
            winding_to_housing_k_per_w: 5.0,
            housing_to_ambient_k_per_w: 20.0,
            power_stage_time_constant_s: 60.0,
            power_stage_to_ambient_k_per_w: 5.0,
            encoder_counts_per_rev: 4096,
            encoder_offset_counts: 0,
            index_count: 0,
            load_encoder_counts_per_rev: 0,
            hall_offset_rad: 0.0,
            ssi_single_turn_bits: 0,
            ssi_multi_turn_bits: 0,
            ssi_gray: true,
            ssi_frame_check: true,
            ssi_offset_counts: 0,
            shunt_gain_lsb_per_a: [4096.0 / 33.0; 3],
            shunt_offset_lsb: [37.0, -24.0, 12.0],
            shunt_noise_lsb_rms: 2.0,
            bus_gain_lsb_per_v: 4095.0 / 60.0,
            bus_noise_lsb_rms: 1.0,
            adc_reference_v: 3.3,
            temp_sensor_v_at_0c: 0.5,
            temp_sensor_v_per_k: 0.010,
            temp_noise_lsb_rms: 1.0,
            substeps_per_period: 8,
            io: IoParams::reference(),
        }
    }

    /// This plant with a braking chopper: a 10 ohm resistor across the bus while the drive's chopper
    /// output conducts (5 A and 250 W at 50 V: a typical 50 W, 10 ohm braking resistor of this power class, whose
    /// rating the drive knows from 0x3203, not the plant). Everything else stays.
    #[must_use]
    pub fn with_chopper(self) -> Self {
        Self { chopper_resistance_ohm: 10.0, ..self }
    }

    /// The reference plant with [`Self::with_chopper`]'s braking chopper.
    pub fn reference_with_chopper() -> Self {
        Self::reference().with_chopper()
    }

    /// The reference plant with ideal sensors: no ADC noise and no shunt offsets (for tests that check the
    /// physics, not the calibration).
    pub fn reference_ideal_sensors() -> Self {
        Self {
            shunt_offset_lsb: [0.0; 3],
            shunt_noise_lsb_rms: 0.0,
            bus_noise_lsb_rms: 0.0,
            temp_noise_lsb_rms: 0.0,
            ..Self::reference()
        }
    }

    /// Torque constant `1.5 * p * psi`, in N m per A of q current (0.0335 for the reference plant).
    pub fn torque_constant_nm_per_a(&self) -> f64 {
        1.5 * f64::from(self.pole_pairs) * self.flux_linkage_wb
    }

    /// Total inertia seen by the motor shaft with the load rigidly coupled (rotor + load / ratio^2), in kg m^2.
    pub fn total_inertia_kg_m2(&self) -> f64 {
        self.rotor_inertia_kg_m2 + self.load_inertia_kg_m2 / (self.gear_ratio * self.gear_ratio)
    }

    /// Whether the load sits on a compliant coupling (a two-mass system) rather than rigidly on the gear output.
    pub fn coupling_is_compliant(&self) -> bool {
        self.coupling_stiffness_nm_per_rad > 0.0
    }

    /// First resonance of the free two-mass system (motor and load on the coupling, no friction), in Hz:
    /// `sqrt(k (1 / J_load + 1 / (J_rotor N^2))) / 2 pi` with the rotor reflected to the output; 0 when rigid.
    pub fn coupling_resonance_hz(&self) -> f64 {
        if !self.coupling_is_compliant() {
            return 0.0;
        }
        let rotor_at_output = self.rotor_inertia_kg_m2 * self.gear_ratio * self.gear_ratio;
        (self.coupling_stiffness_nm_per_rad * (1.0 / self.load_inertia_kg_m2 + 1.0 / rotor_at_output)).sqrt()
            / (2.0 * PI)
    }

    /// Anti-resonance of the two-mass system seen from the motor (the load alone on the coupling, the motor held),
    /// in Hz: `sqrt(k / J_load) / 2 pi`; 0 when rigid. With the resonance of [`Self::coupling_resonance_hz`] it is
    /// the truth of the identification's resonance step (0x3205:03/04).
    pub fn coupling_anti_resonance_hz(&self) -> f64 {
        if !self.coupling_is_compliant() {
            return 0.0;
        }
        (self.coupling_stiffness_nm_per_rad / self.load_inertia_kg_m2).sqrt() / (2.0 * PI)
    }

    /// Electrical time constant of the winding alone, `Lq / R`, in s (0.635 ms for the reference plant).
    pub fn winding_time_constant_electrical_s(&self) -> f64 {
        self.lq_h / self.phase_resistance_ohm
    }

    /// Electrical time constant of the current loop through the inverter, `Lq / (R + R_switch)`, in s
    /// (0.611 ms for the reference plant).
    pub fn loop_time_constant_electrical_s(&self) -> f64 {
        self.lq_h / (self.phase_resistance_ohm + self.switch_resistance_ohm)
    }

    /// Convert a speed from rpm to mechanical rad/s.
    pub fn rpm_to_rad_s(rpm: f64) -> f64 {
        rpm * 2.0 * PI / 60.0
    }
}

impl Default for PlantParams {
    /// The reference plant.
    fn default() -> Self {
        Self::reference()
    }
}
