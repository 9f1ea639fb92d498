//! Plant files: a TOML file whose keys are the field names of [`PlantParams`] (`drive-sim --plant FILE`, the
//! presets in `hal-sim/presets/`).
//!
//! * A missing key keeps the reference plant's value ([`PlantParams::reference`]), so a file gives only what differs.
//! * Every key sits at the top level; arrays (`shunt_gain_lsb_per_a`, `shunt_offset_lsb`) are TOML arrays of three
//!   numbers, an infinite value (`chopper_resistance_ohm`, `break_current_a`) is `inf`, an integer is accepted
//!   where a float is expected.
//! * The digital I/O (`PlantParams::io`: limit and home switches, brake) is not in the file: it is the scenario's
//!   axis, not the motor's, and a file always gets [`super::IoParams::reference`]. An `[io]` table is therefore an
//!   unknown key like any other.
//! * An unknown key, a value of the wrong type and a value that is not physical ([`PlantParams::validate`]) are
//!   each an error naming the key and the file ([`PlantFileError`]).

use std::fmt;
use std::path::Path;

use super::PlantParams;

/// Why a plant file was refused: the file, the key at fault (none for a TOML syntax error, which carries its line
/// and column in `reason`) and what is wrong with it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlantFileError {
    /// The file as given (or the name passed to [`PlantParams::from_toml_str`]).
    pub file: String,
    /// The key at fault.
    pub key: Option<String>,
    /// What is wrong.
    pub reason: String,
}

impl fmt::Display for PlantFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.key {
            Some(key) => write!(f, "plant file {}: key `{key}`: {}", self.file, self.reason),
            None => write!(f, "plant file {}: {}", self.file, self.reason),
        }
    }
}

impl std::error::Error for PlantFileError {}

impl PlantParams {
    /// The plant of the file at `path` (see the module documentation).
    pub fn from_toml_file(path: &Path) -> Result<Self, PlantFileError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| PlantFileError {
            file: file.clone(),
            key: None,
            reason: format!("cannot read it: {e}"),
        })?;
        Self::from_toml_str(&text, &file)
    }

    /// The plant of the TOML text `text`, errors naming it `file` (see the module documentation).
    pub fn from_toml_str(text: &str, file: &str) -> Result<Self, PlantFileError> {
        let error = |key: Option<&str>, reason: String| PlantFileError {
            file: file.to_owned(),
            key: key.map(str::to_owned),
            reason,
        };
        let given: toml::Table = text.parse().map_err(|e: toml::de::Error| error(None, e.to_string()))?;
        let reference = toml::Table::try_from(Self::reference())
            .map_err(|e| error(None, format!("the reference plant does not serialise: {e}")))?;
        let mut merged = reference.clone();
        for (key, value) in given {
            if !reference.contains_key(&key) {
                return Err(error(
                    Some(&key),
                    "unknown key (the keys are the fields of PlantParams, io excluded)".into(),
                ));
            }
            // Each key on its own over the reference, so that a type error is pinned to its key.
            let mut alone = reference.clone();
            alone.insert(key.clone(), value.clone());
            alone.try_into::<Self>().map_err(|e| error(Some(&key), one_line(&e.to_string())))?;
            merged.insert(key, value);
        }
        let params: Self = merged.try_into().map_err(|e| error(None, one_line(&e.to_string())))?;
        params.validate().map_err(|(key, reason)| error(Some(key), reason))?;
        Ok(params)
    }

    /// The plant as a plant file: every key, in field order (what `reference.toml` holds for the reference).
    pub fn to_toml_string(&self) -> String {
        toml::to_string(self).unwrap_or_else(|e| format!("# does not serialise: {e}\n"))
    }

    /// Physical sanity: `Err((key, reason))` for the first field out of range. Resistances, inductances, the flux
    /// linkage, the rotor inertia, the bus capacitance and the ratings positive; pole pairs at least 1; the gear
    /// ratio positive, its efficiency in (0, 1]; stiffness, damping, frictions, load inertia and backlash not
    /// negative; backlash only with a compliant coupling, a compliant coupling only with a load inertia; the
    /// encoder a multiple of 4 counts (quadrature), the index on one of them; an SSI sensor of 6..=16 single-turn
    /// bits and at most 32 clocked bits; at least one integration sub-step.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let positive: [(&'static str, f64); 15] = [
            ("source_voltage_v", self.source_voltage_v),
            ("source_resistance_ohm", self.source_resistance_ohm),
            ("bus_capacitance_f", self.bus_capacitance_f),
            ("chopper_resistance_ohm", self.chopper_resistance_ohm),
            ("phase_resistance_ohm", self.phase_resistance_ohm),
            ("ld_h", self.ld_h),
            ("lq_h", self.lq_h),
            ("flux_linkage_wb", self.flux_linkage_wb),
            ("rotor_inertia_kg_m2", self.rotor_inertia_kg_m2),
            ("nominal_current_a", self.nominal_current_a),
            ("peak_current_a", self.peak_current_a),
            ("max_speed_rpm", self.max_speed_rpm),
            ("gear_ratio", self.gear_ratio),
            ("gear_efficiency", self.gear_efficiency),
            ("break_current_a", self.break_current_a),
        ];
        for (key, value) in positive {
            if value.is_nan() || value <= 0.0 {
                return Err((key, format!("must be positive, got {value}")));
            }
        }
        let not_negative: [(&'static str, f64); 11] = [
            ("load_inertia_kg_m2", self.load_inertia_kg_m2),
            ("viscous_friction_nm_s_rad", self.viscous_friction_nm_s_rad),
            ("coulomb_friction_nm", self.coulomb_friction_nm),
            ("gear_backlash_deg", self.gear_backlash_deg),
            ("coupling_stiffness_nm_per_rad", self.coupling_stiffness_nm_per_rad),
            ("coupling_damping_nm_s_per_rad", self.coupling_damping_nm_s_per_rad),
            ("load_coulomb_friction_nm", self.load_coulomb_friction_nm),
            ("dead_time_s", self.dead_time_s),
            ("switch_resistance_ohm", self.switch_resistance_ohm),
            ("diode_drop_v", self.diode_drop_v),
            ("copper_temp_coeff_per_k", self.copper_temp_coeff_per_k),
        ];
        for (key, value) in not_negative {
            if value.is_nan() || value < 0.0 {
                return Err((key, format!("must not be negative, got {value}")));
            }
        }
        let finite: [(&'static str, f64); 6] = [
            ("load_inertia_kg_m2", self.load_inertia_kg_m2),
            ("gear_ratio", self.gear_ratio),
            ("gear_backlash_deg", self.gear_backlash_deg),
            ("coupling_stiffness_nm_per_rad", self.coupling_stiffness_nm_per_rad),
            ("rotor_inertia_kg_m2", self.rotor_inertia_kg_m2),
            ("max_speed_rpm", self.max_speed_rpm),
        ];
        for (key, value) in finite {
            if !value.is_finite() {
                return Err((key, format!("must be finite, got {value}")));
            }
        }
        if self.gear_efficiency > 1.0 {
            return Err(("gear_efficiency", format!("must be in (0, 1], got {}", self.gear_efficiency)));
        }
        if self.peak_current_a < self.nominal_current_a {
            return Err(("peak_current_a", format!("below nominal_current_a ({})", self.nominal_current_a)));
        }
        if self.pole_pairs < 1 {
            return Err(("pole_pairs", "must be at least 1".into()));
        }
        if self.gear_backlash_deg > 0.0 && !self.coupling_is_compliant() {
            return Err((
                "gear_backlash_deg",
                "needs a compliant coupling (coupling_stiffness_nm_per_rad > 0): the dead band sits in series with \
                 the coupling's spring"
                    .into(),
            ));
        }
        if self.coupling_is_compliant() && self.load_inertia_kg_m2 <= 0.0 {
            return Err(("load_inertia_kg_m2", "must be positive with a compliant coupling (the load side)".into()));
        }
        if self.encoder_counts_per_rev < 4 || !self.encoder_counts_per_rev.is_multiple_of(4) {
            return Err((
                "encoder_counts_per_rev",
                format!("must be a positive multiple of 4 (quadrature), got {}", self.encoder_counts_per_rev),
            ));
        }
        if self.index_count >= self.encoder_counts_per_rev {
            return Err(("index_count", format!("must be below encoder_counts_per_rev, got {}", self.index_count)));
        }
        if !self.load_encoder_counts_per_rev.is_multiple_of(4) {
            return Err((
                "load_encoder_counts_per_rev",
                format!("must be 0 (none) or a multiple of 4 (quadrature), got {}", self.load_encoder_counts_per_rev),
            ));
        }
        if self.ssi_single_turn_bits != 0 && !(6..=16).contains(&self.ssi_single_turn_bits) {
            return Err((
                "ssi_single_turn_bits",
                format!("must be 0 (no SSI sensor) or 6..=16, got {}", self.ssi_single_turn_bits),
            ));
        }
        let ssi_clocked =
            self.ssi_single_turn_bits + self.ssi_multi_turn_bits + if self.ssi_frame_check { 2 } else { 0 };
        if self.ssi_single_turn_bits != 0 && ssi_clocked > 32 {
            return Err((
                "ssi_multi_turn_bits",
                format!("the SSI frame has at most 32 clocked bits (frame bits included), got {ssi_clocked}"),
            ));
        }
        if self.substeps_per_period < 1 {
            return Err(("substeps_per_period", "must be at least 1".into()));
        }
        Ok(())
    }
}

/// A serde message on one line (the TOML error's excerpt of the file is dropped: the key names the place).
fn one_line(message: &str) -> String {
    let lines: Vec<&str> = message.lines().map(str::trim).filter(|l| !l.is_empty() && !l.contains('|')).collect();
    lines.join("; ")
}
