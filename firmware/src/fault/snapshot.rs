//! The diagnosis data kept with a fault: the measured values at the moment of the trip.
//!
//! The detector fills a [`DiagnosisSnapshot`] from the values it has in hand when it detects the condition (the
//! tier-1 sample that was over the limit, not a later one) and hands it to `FaultManager::raise`; the manager
//! stores it with the fault and never replaces it while the fault stays active, so what a field engineer reads
//! is the trip, not the aftermath (E3 L1262-L1280: the EtherCAT emergency's "additional error information";
//! ETG.1020 diagnosis messages carry parameters the same way, digest §3.2.4).

use crate::cia402::{State, Ticks};

use super::table::SnapshotField;

/// The measured values at the moment a fault was detected. Units are in the field names (ARCHITECTURE
/// convention 4); they follow the dictionary's units (IDX 0x30D1 current mA, 0x2200 voltage, 0x3201 temperature
/// 0.1 degC, 0x3200 I2t percent, 0x6064 position increments, 0x606C velocity rpm).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DiagnosisSnapshot {
    /// Phase currents a, b, c in mA.
    pub phase_currents_ma: [i32; 3],
    /// DC-bus voltage in mV.
    pub bus_voltage_mv: i32,
    /// Power-stage temperature in 0.1 degC.
    pub power_stage_temperature_ddegc: i16,
    /// Motor I2t level in percent (100 = limit).
    pub motor_i2t_percent: u16,
    /// Actual position in increments.
    pub position_inc: i32,
    /// Actual velocity in rpm.
    pub velocity_rpm: i32,
    /// The CiA 402 state when the fault was detected.
    pub state: State,
    /// The tier-2 time of the detection.
    pub tick: Ticks,
    /// The detector's own measurement, documented per fault: following error in increments, loop cost in CPU
    /// cycles, the Hall pattern, the consumer heartbeat's node-ID, the received PDO length in bytes, ...
    pub detail: i32,
}

impl DiagnosisSnapshot {
    /// A snapshot with nothing measured (all zero, state "Not ready to switch on"), to fill in with struct update
    /// syntax.
    pub const EMPTY: Self = Self {
        phase_currents_ma: [0; 3],
        bus_voltage_mv: 0,
        power_stage_temperature_ddegc: 0,
        motor_i2t_percent: 0,
        position_inc: 0,
        velocity_rpm: 0,
        state: State::NotReadyToSwitchOn,
        tick: Ticks(0),
        detail: 0,
    };

    /// The phase current with the largest magnitude, mA (saturating).
    pub fn peak_phase_current_ma(&self) -> i32 {
        let [a, b, c] = self.phase_currents_ma;
        let mut peak = a;
        for x in [b, c] {
            if x.unsigned_abs() > peak.unsigned_abs() {
                peak = x;
            }
        }
        peak
    }

    /// The sum of the phase currents, mA (saturating; zero for a healthy star-connected motor).
    pub fn phase_current_sum_ma(&self) -> i32 {
        let [a, b, c] = self.phase_currents_ma;
        a.saturating_add(b).saturating_add(c)
    }

    /// The value `field` selects, as the EMCY's manufacturer bytes 4..7 carry it.
    pub fn field(&self, field: SnapshotField) -> i32 {
        match field {
            SnapshotField::PeakPhaseCurrent => self.peak_phase_current_ma(),
            SnapshotField::PhaseCurrentSum => self.phase_current_sum_ma(),
            SnapshotField::BusVoltage => self.bus_voltage_mv,
            SnapshotField::PowerStageTemperature => i32::from(self.power_stage_temperature_ddegc),
            SnapshotField::MotorI2tLevel => i32::from(self.motor_i2t_percent),
            SnapshotField::Position => self.position_inc,
            SnapshotField::Velocity => self.velocity_rpm,
            SnapshotField::Detail => self.detail,
        }
    }
}

impl Default for DiagnosisSnapshot {
    fn default() -> Self {
        Self::EMPTY
    }
}
