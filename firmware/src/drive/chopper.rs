//! The braking chopper: a resistor switched across the DC bus when regeneration lifts it, with the resistor's own
//! overload protection.
//!
//! # Why
//! Where the board has a chopper (a transistor and a braking resistor on the bus), it takes the energy a braking
//! motor returns, and the motor stops as fast as demanded; without one the bus-voltage limiter
//! ([`super::regeneration`]) holds the bus by braking less or by burning energy in the winding. The PD4-E's ballast
//! circuit switches on above 50.5 V for a 51.5 V trip (`shared/spec/control-and-protection.md` §3.4); this drive
//! trips at 56 V, and the defaults of 0x3203 switch the chopper on at 50 V and off at 48.5 V, below the limiter's
//! first level (51 V, 0x3202:02), so the chopper acts first and the limiter only when the chopper cannot keep up.
//!
//! # Control
//! Tier 2, once per slow period on tier 1's last bus sample ([`BrakingChopper::step`]): on at or above 0x3203:04,
//! off at or below 0x3203:05 (hysteresis, so the resistor is not switched at every sample). At 2.5 kHz the bus
//! moves at most a few volts between two decisions (the limiter's documentation gives the rates); the band between
//! on and the limiter's first level covers that.
//!
//! # Resistor overload (I2t of the resistor)
//! A first-order thermal model of the resistor: its load `x` (1 = the temperature rise of the rated continuous
//! power 0x3203:02) follows `x' = (P / P_rated - x) / tau` with `P = V^2 / R` while the chopper conducts and 0
//! otherwise, time constant 0x3203:03. At `x >= 1` the chopper is switched off and warning 0x7113 raised (the
//! limiter keeps the bus below the trip meanwhile); it switches on again, and the warning goes, once `x` has fallen
//! to 90 %. 0x3203:06 shows `x` in percent.
//!
//! 0x3203:01 = 0 (the default: the reference board has no chopper) keeps the gate off for ever.

use crate::control::frames::Volts;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// The model's load at which the chopper stops (Q32 one: the rated continuous power's temperature rise). Q32, not
/// less: the step `x += (p - x) T/tau` rounds by one LSB, and `tau / T` such steps (25,000 at the default 10 s)
/// must not add up to a visible error.
const OVERLOAD: i64 = 1 << 32;
/// The load below which it may switch on again: 90 %.
const RECOVERED: i64 = OVERLOAD / 10 * 9;
/// The largest power ratio the model takes (256 times the rated power: overloads within one slow period for any time
/// constant in range), Q32.
const RATIO_MAX: i64 = 1 << 40;
/// Fraction bits of `T / tau`: 28 keeps the products in `i64` (ratio < 2^41, `T / tau` < 2^20 in Q28) and resolves
/// the longest time constant, 600 s, to 0.6 %.
const ALPHA_BITS: u32 = 28;
/// Slow period, us (2.5 kHz).
const PERIOD_US: i64 = 400;

/// 0x3203:07 bit 0: the chopper conducts.
pub const STATE_ON: u8 = 1;
/// 0x3203:07 bit 1: switched off by the resistor's overload protection.
pub const STATE_OVERLOADED: u8 = 1 << 1;

/// The chopper's objects as the dictionary holds them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Objects {
    resistance_mohm: u32,
    rated_power_mw: u32,
    time_constant_ms: u32,
    on_mv: u32,
    off_mv: u32,
}

impl Objects {
    fn read(d: &Dictionary) -> Self {
        Self {
            resistance_mohm: d.get(h::CHOPPER_RESISTANCE),
            rated_power_mw: d.get(h::CHOPPER_RATED_POWER),
            time_constant_ms: d.get(h::CHOPPER_THERMAL_TIME_CONSTANT),
            on_mv: d.get(h::CHOPPER_ON_VOLTAGE),
            off_mv: d.get(h::CHOPPER_OFF_VOLTAGE),
        }
    }
}

/// What one step decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChopperStep {
    /// The gate for the next slow period.
    pub gate: bool,
    /// The overload protection switched the chopper off in this step (raise the warning).
    pub overload_began: bool,
    /// The resistor cooled below 90 % in this step (the warning's cause has gone).
    pub overload_ended: bool,
}

/// The braking chopper (module documentation).
#[derive(Clone, Copy, Debug, Default)]
pub struct BrakingChopper {
    objects: Option<Objects>,
    /// `T / tau` in Q28 (at most 2^28 x 400 / 100,000).
    alpha: i64,
    gate: bool,
    overloaded: bool,
    /// The resistor's load, Q32 (one = rated), 0..=[`RATIO_MAX`].
    load_q32: i64,
}

impl BrakingChopper {
    /// One slow period on the bus voltage `v_bus` (tier 1's last sample): the gate, and whether the overload
    /// protection acted. Reads 0x3203:01..05 when they changed.
    #[inline(never)]
    pub fn step(&mut self, d: &Dictionary, v_bus: Volts) -> ChopperStep {
        let objects = Objects::read(d);
        if self.objects != Some(objects) {
            self.objects = Some(objects);
            // T / tau with tau >= 100 ms (the object's range): below 2^28 / 250.
            let tau_us = i64::from(objects.time_constant_ms).saturating_mul(1000);
            self.alpha = (PERIOD_US << ALPHA_BITS).checked_div(tau_us).unwrap_or(PERIOD_US << ALPHA_BITS);
        }
        let v_mv = v_bus.to_millivolts().clamp(0, 1 << 17);
        let fitted = objects.resistance_mohm != 0;
        // The heat of the period that ends now, from the gate that was in force during it.
        let power_ratio_q32 = if self.gate && fitted {
            let v = i64::from(v_mv);
            // mV^2 / mOhm = mW (v < 2^17: the square fits); / rated mW in Q16 (p < 2^34), then Q32.
            let p_mw = v.wrapping_mul(v).checked_div(i64::from(objects.resistance_mohm)).unwrap_or(0);
            let ratio_q16 = (p_mw << 16).checked_div(i64::from(objects.rated_power_mw)).unwrap_or(RATIO_MAX);
            ratio_q16.min(RATIO_MAX >> 16) << 16
        } else {
            0
        };
        // x += (p - x) T/tau: |p - x| <= 2^40 and T/tau < 2^20 in Q28, the product fits i64; x stays in
        // 0..=RATIO_MAX (a step moves it towards p, never past).
        let delta = power_ratio_q32.wrapping_sub(self.load_q32).wrapping_mul(self.alpha) >> ALPHA_BITS;
        self.load_q32 = self.load_q32.wrapping_add(delta).clamp(0, RATIO_MAX);

        let mut step = ChopperStep { gate: false, overload_began: false, overload_ended: false };
        if self.overloaded {
            if self.load_q32 <= RECOVERED {
                self.overloaded = false;
                step.overload_ended = true;
            }
        } else if self.load_q32 >= OVERLOAD {
            self.overloaded = true;
            step.overload_began = true;
        }
        self.gate = if !fitted || self.overloaded {
            false
        } else if v_mv >= i32::try_from(objects.on_mv).unwrap_or(i32::MAX) {
            true
        } else if v_mv <= i32::try_from(objects.off_mv).unwrap_or(i32::MAX) {
            false
        } else {
            self.gate
        };
        step.gate = self.gate;
        step
    }

    /// The gate in force.
    #[must_use]
    pub const fn gate(&self) -> bool {
        self.gate
    }

    /// 0x3203:06, the resistor's load in percent of its rated continuous power's temperature rise.
    #[must_use]
    pub fn load_percent(&self) -> u16 {
        u16::try_from(self.load_q32.wrapping_mul(100).wrapping_add(1 << 31) >> 32).unwrap_or(u16::MAX)
    }

    /// 0x3203:07: [`STATE_ON`], [`STATE_OVERLOADED`].
    #[must_use]
    pub const fn state_bits(&self) -> u8 {
        (if self.gate { STATE_ON } else { 0 }) | (if self.overloaded { STATE_OVERLOADED } else { 0 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fitted(resistance_mohm: u32, rated_mw: u32, tau_ms: u32) -> Dictionary {
        let mut d = Dictionary::new(1);
        d.set(h::CHOPPER_RESISTANCE, resistance_mohm);
        d.set(h::CHOPPER_RATED_POWER, rated_mw);
        d.set(h::CHOPPER_THERMAL_TIME_CONSTANT, tau_ms);
        d
    }

    fn volts(v: f64) -> Volts {
        Volts::from_millivolts((v * 1000.0) as i32)
    }

    #[test]
    fn without_a_resistor_the_gate_stays_off() {
        let d = Dictionary::new(1);
        let mut c = BrakingChopper::default();
        assert!(!c.step(&d, volts(55.0)).gate);
        assert_eq!(c.state_bits(), 0);
    }

    #[test]
    fn the_gate_follows_the_bus_with_hysteresis() {
        // Defaults: on at 50 V, off at 48.5 V.
        let d = fitted(10_000, 50_000, 10_000);
        let mut c = BrakingChopper::default();
        assert!(!c.step(&d, volts(49.9)).gate);
        assert!(c.step(&d, volts(50.0)).gate);
        assert!(c.step(&d, volts(49.0)).gate, "inside the band: stays on");
        assert!(!c.step(&d, volts(48.5)).gate);
        assert!(!c.step(&d, volts(49.0)).gate, "inside the band: stays off");
        assert_eq!(c.state_bits(), 0);
    }

    #[test]
    fn the_resistor_model_reaches_its_rated_rise_after_tau_at_rated_power() {
        // 10 ohm at 50 V: 250 W; rated 250 W, tau 1 s: after 1 s the load is 1 - 1/e = 63 %, steady state 100 %.
        let d = fitted(10_000, 250_000, 1_000);
        let mut c = BrakingChopper::default();
        let mut first_overload = None;
        for tick in 0..2_500 {
            let s = c.step(&d, volts(50.0));
            if s.overload_began && first_overload.is_none() {
                first_overload = Some(tick);
            }
        }
        assert!(first_overload.is_none(), "rated power never overloads");
        let after_1s = c.load_percent();
        assert!((62..=64).contains(&after_1s), "{after_1s} %");
    }

    #[test]
    fn an_overloaded_resistor_is_switched_off_until_it_cooled_to_90_percent() {
        // 10 ohm at 50 V = 250 W into a 50 W resistor with tau 1 s: x reaches 1 after -tau ln(1 - 0.2) = 223 ms.
        let d = fitted(10_000, 50_000, 1_000);
        let mut c = BrakingChopper::default();
        let mut began = None;
        for tick in 0..2_500_u32 {
            let s = c.step(&d, volts(51.0));
            if s.overload_began {
                began = Some(tick);
                break;
            }
        }
        // 51 V: 260.1 W, x = 1 at -ln(1 - 50/260.1) s = 213 ms = 533 ticks (+-2 for the discrete steps).
        let began = began.expect("the overload protection acts");
        assert!((531..=536).contains(&began), "{began}");
        assert_eq!(c.state_bits(), STATE_OVERLOADED);
        assert!(!c.gate());
        // Cooling from 100 % to 90 %: tau ln(1/0.9) = 105 ms = 263 ticks, and up to 4 more because the load is up to
        // one heating step (0.17 %) past 100 % when the protection acts; gate off all along, even at 55 V.
        let mut ended = None;
        for tick in 0..1_000_u32 {
            let s = c.step(&d, volts(55.0));
            if s.overload_ended {
                ended = Some(tick);
                break;
            }
            assert!(!s.gate);
        }
        let ended = ended.expect("it recovers");
        assert!((262..=268).contains(&ended), "{ended}");
    }
}
