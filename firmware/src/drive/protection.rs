//! The tier-1 protection checks: conditions that must switch the power stage off within the same 25 kHz period
//! (the fault issue's "tier 1" list; IDX error codes in `crate::fault::table`).
//!
//! - Hardware break input: the over-current comparator of the reference power stage has already disabled the
//!   outputs in hardware (`hal::power::Measurements::break_input`); the drive latches the trip and answers with
//!   `PwmCommand::OFF` (which also acknowledges the break latch).
//! - DC-bus over-voltage (IDX 0x3210): above [`BUS_OVER_VOLTAGE_MV`], with the outputs off too (regeneration
//!   through the diodes can raise the bus; switching on would make it worse).
//! - DC-bus under-voltage (IDX 0x3220): below [`BUS_UNDER_VOLTAGE_MV`] while the power stage switches (offset
//!   calibration, operation enabled): the current loop cannot hold its currents, and the gate drivers' supply is
//!   at risk.
//! - Software over-current (IDX 0x2310): a calibrated phase current beyond the limit [`Limits::over_current`]
//!   (1.25 x the output current limit 0x3001:02, converted in tier 2), while the current loop runs.
//! - Phase-current sum (CiA 402 0x2330): the three shunt currents must sum to zero; more than
//!   [`PHASE_SUM_LIMIT_MA`] means a broken shunt, amplifier or ADC channel, or an earth fault.
//!
//! Every check is one comparison on a value tier 1 already has; the limits are raw `I16F16` bits prepared by tier
//! 2, so nothing converts or divides here.

use crate::control::frames::{Abc, Amps, Volts};
use crate::power_state::Trip;

/// Over-voltage trip of the reference power stage, mV. The reference bus has no braking chopper: braking the
/// reference load from 2,450 rpm returns about 0.6 J into the 470 uF capacitor and lifts the 24 V bus to 49.8 V
/// (measured on the plant at the end of `drive-sim csp`'s 10-revolution move). The trip sits above that and below
/// the 60 V rating of the reference power stage's parts and bus sensing.
pub const BUS_OVER_VOLTAGE_MV: i32 = 56_000;
/// The bus is deemed back below the over-voltage limit under this, mV (4 V of hysteresis, so that a fault reset
/// is refused until the bus has really come down).
pub const BUS_OVER_VOLTAGE_CLEAR_MV: i32 = 52_000;
/// Under-voltage trip while switching, mV (the reference power stage's lowest operating supply, 10 V, less the
/// ripple of a loaded bus).
pub const BUS_UNDER_VOLTAGE_MV: i32 = 9_000;
/// The bus is deemed back above the under-voltage limit over this, mV.
pub const BUS_UNDER_VOLTAGE_CLEAR_MV: i32 = 10_000;
/// Largest |i_a + i_b + i_c| accepted, mA: the shunt noise (2 LSB rms of 8 mA per channel) sums to about 28 mA
/// rms, so 1 A is 35 sigma away; a lost channel at any useful current exceeds it.
pub const PHASE_SUM_LIMIT_MA: i32 = 1_000;

/// Trip limits in tier 1's units, prepared by tier 2 when the parameters change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Phase-current magnitude limit, `I16F16` bits.
    pub over_current: i32,
    /// Phase-current sum limit, `I16F16` bits.
    pub phase_sum: i32,
    /// Bus over-voltage limit, `I16F16` bits.
    pub over_voltage: i32,
    /// Bus under-voltage limit, `I16F16` bits.
    pub under_voltage: i32,
    /// `2 x over_current` as unsigned (the one-compare magnitude check).
    over_current_span: u32,
    /// `2 x phase_sum` as unsigned.
    phase_sum_span: u32,
}

impl Limits {
    /// The limits for an output current limit of `output_limit_ma` (0x3001:02).
    #[must_use]
    pub fn new(output_limit_ma: u32) -> Self {
        // At most 1.25 x 12 A (0x3001:02's maximum) = 15 A, far below 2^14 A: the doubled spans fit a u32.
        let oc_ma = i32::try_from(output_limit_ma.saturating_add(output_limit_ma / 4)).unwrap_or(i32::MAX);
        let over_current = Amps::from_milliamps(oc_ma.min(1 << 24)).to_bits().max(0);
        let phase_sum = Amps::from_milliamps(PHASE_SUM_LIMIT_MA).to_bits();
        Self {
            over_current,
            phase_sum,
            over_current_span: over_current.unsigned_abs().saturating_mul(2),
            phase_sum_span: phase_sum.unsigned_abs().saturating_mul(2),
            over_voltage: Volts::from_millivolts(BUS_OVER_VOLTAGE_MV).to_bits(),
            under_voltage: Volts::from_millivolts(BUS_UNDER_VOLTAGE_MV).to_bits(),
        }
    }

    /// Whether the bus is outside its limits (over-voltage always, under-voltage while `switching`): the hot
    /// path, two compares; [`Self::bus_trip`] says which.
    #[inline(always)]
    #[must_use]
    pub fn bus_outside(&self, v_bus: Volts, switching: bool) -> bool {
        let v = v_bus.to_bits();
        v > self.over_voltage || (switching && v < self.under_voltage)
    }

    /// Which bus limit `v_bus` violates (cold path after [`Self::bus_outside`]).
    #[must_use]
    pub fn bus_trip(&self, v_bus: Volts) -> Trip {
        if v_bus.to_bits() > self.over_voltage {
            Trip::BusOverVoltage
        } else {
            Trip::BusUnderVoltage
        }
    }

    /// Whether a phase current or their sum is outside its limit: the hot path, one add and one unsigned compare
    /// per value (`x + l` as unsigned exceeds `2 l` exactly when `|x| > l`); [`Self::current_trip`] says which.
    #[inline(always)]
    #[must_use]
    pub fn currents_outside(&self, i: &Abc<Amps>) -> bool {
        let (a, b, c) = (i.a.to_bits(), i.b.to_bits(), i.c.to_bits());
        let l = self.over_current;
        // Limits are positive and below 2^30; wrapping on purpose: the reinterpretation as u32 is the trick.
        let outside = |x: i32| (x.wrapping_add(l) as u32) > self.over_current_span;
        // The currents come from 12-bit codes (+-16.5 A, far inside I16F16): the sum cannot wrap.
        let sum = a.wrapping_add(b).wrapping_add(c);
        // Bitwise or: four compares and no branch until the one that decides.
        outside(a) | outside(b) | outside(c) | ((sum.wrapping_add(self.phase_sum) as u32) > self.phase_sum_span)
    }

    /// Which current limit is violated (cold path after [`Self::currents_outside`]).
    #[must_use]
    pub fn current_trip(&self, i: &Abc<Amps>) -> Trip {
        let limit = self.over_current.unsigned_abs();
        if i.a.to_bits().unsigned_abs() > limit
            || i.b.to_bits().unsigned_abs() > limit
            || i.c.to_bits().unsigned_abs() > limit
        {
            Trip::OverCurrent
        } else {
            Trip::PhaseSum
        }
    }
}

impl Default for Limits {
    /// The limits for the dictionary's default output current limit (10 A).
    fn default() -> Self {
        Self::new(10_000)
    }
}

/// Whether the cause of `trip` is still there in the latest measurement (`break_input`, bus voltage `v_bus_mv`):
/// a fault reset is refused while it is. Current trips are events.
#[must_use]
pub fn cause_present(trip: Trip, break_input: bool, v_bus_mv: i32) -> bool {
    match trip {
        Trip::BreakInput => break_input,
        Trip::BusOverVoltage => v_bus_mv > BUS_OVER_VOLTAGE_CLEAR_MV,
        Trip::BusUnderVoltage => v_bus_mv < BUS_UNDER_VOLTAGE_CLEAR_MV,
        Trip::OverCurrent | Trip::PhaseSum => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn amps(ma: i32) -> Amps {
        Amps::from_milliamps(ma)
    }

    /// The bus checks as tier 1 runs them: the hot test, then which limit.
    impl Limits {
        fn check_bus(&self, v_bus: Volts, switching: bool) -> Option<Trip> {
            self.bus_outside(v_bus, switching).then(|| self.bus_trip(v_bus))
        }

        fn check_currents(&self, i: &Abc<Amps>) -> Option<Trip> {
            self.currents_outside(i).then(|| self.current_trip(i))
        }
    }

    #[test]
    fn bus_limits() {
        let l = Limits::default();
        assert_eq!(l.check_bus(Volts::from_millivolts(24_000), true), None);
        assert_eq!(l.check_bus(Volts::from_millivolts(56_100), false), Some(Trip::BusOverVoltage));
        assert_eq!(l.check_bus(Volts::from_millivolts(50_000), true), None, "regeneration of a normal stop");
        assert_eq!(l.check_bus(Volts::from_millivolts(8_900), true), Some(Trip::BusUnderVoltage));
        assert_eq!(l.check_bus(Volts::from_millivolts(8_900), false), None, "no under-voltage with outputs off");
    }

    #[test]
    fn current_limits() {
        let l = Limits::new(10_000);
        assert_eq!(l.check_currents(&Abc::new(amps(12_000), amps(-6_000), amps(-6_000))), None);
        assert_eq!(l.check_currents(&Abc::new(amps(-12_600), amps(6_300), amps(6_300))), Some(Trip::OverCurrent));
        assert_eq!(l.check_currents(&Abc::new(amps(3_000), amps(-1_000), amps(-900))), Some(Trip::PhaseSum));
        assert_eq!(l.check_currents(&Abc::new(amps(3_000), amps(-1_500), amps(-1_400))), None);
    }

    #[test]
    fn causes() {
        assert!(cause_present(Trip::BusOverVoltage, false, 53_000));
        assert!(!cause_present(Trip::BusOverVoltage, false, 51_000));
        assert!(cause_present(Trip::BreakInput, true, 24_000));
        assert!(!cause_present(Trip::OverCurrent, false, 24_000));
    }
}
