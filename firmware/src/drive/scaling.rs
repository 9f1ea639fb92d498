//! ADC codes to physical quantities: the sense-chain constants of the reference board, in one place.
//!
//! Reference hardware (`shared/design/ARCHITECTURE.md`, "Reference plant", sensors):
//! - phase currents: three low-side shunt amplifiers on a 12-bit ADC spanning +-16.5 A, zero current at
//!   mid-scale (code 2048) before calibration, a higher code for a current flowing into the motor;
//! - DC bus: a divider on a 12-bit channel, 60 V at full scale (code 4095);
//! - temperatures (power stage, motor): converted in tier 2 (`crate::sensors::temperature`).
//!
//! Both conversions are one multiply and one shift, no division (tier 1, ARCHITECTURE convention 10):
//! - current: 33 A / 4096 codes = 528 / 65536 A per LSB, so `I16F16` bits = LSB x 528 exactly. The calibrated
//!   offsets are kept in 1/256 LSB ([`ShuntOffsets`]), so `bits = (code x 256 - offset) x 33 / 16`;
//! - bus: 60 V / 4095 codes = 960.23 `I16F16` bits per LSB, applied as `code x 983,280 >> 10` (relative error
//!   4e-7, far below one LSB).

use crate::control::frames::{Abc, Amps, Volts};
use crate::hal::power::AdcSamples;

/// Shunt-channel code of zero current before calibration (12-bit mid-scale).
pub const SHUNT_MID_SCALE_CODE: u16 = 2048;
/// Full span of a shunt channel: +-16.5 A over 4096 codes, i.e. 33 A (ARCHITECTURE.md, reference plant).
pub const SHUNT_SPAN_MILLIAMPS: u32 = 33_000;
/// Size of one shunt-channel LSB in `I16F16` bits: 33 A / 4096 x 65536 = 528 (exact).
pub const SHUNT_LSB_BITS: i32 = 528;
/// Bus-voltage channel full scale: 60 V at code 4095 (ARCHITECTURE.md, reference plant).
pub const BUS_FULL_SCALE_MILLIVOLTS: u32 = 60_000;
/// `round(60 V / 4095 x 65536 x 2^10)`: the bus LSB in `I16F16` bits, Q10.
const BUS_LSB_BITS_Q10: u32 = 983_280;
/// Fraction bits of the offsets (1/256 LSB): the calibration averages 256 samples, so its sum is the offset.
pub const OFFSET_FRACTION_BITS: u32 = 8;

/// Zero-current codes of the three shunt channels in 1/256 LSB (mid-scale 2048 = 524,288).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShuntOffsets {
    /// Phases A, B, C, in 1/256 LSB.
    pub q8: [i32; 3],
}

impl ShuntOffsets {
    /// The nominal offsets (mid-scale on every channel): what the drive uses before its first calibration.
    pub const NOMINAL: Self = Self { q8: [(SHUNT_MID_SCALE_CODE as i32) << OFFSET_FRACTION_BITS; 3] };

    /// The offset of `channel` (0..=2) relative to mid-scale, in LSB (for diagnostics and tests; `None` for an
    /// unknown channel).
    #[must_use]
    pub fn deviation_lsb(&self, channel: usize) -> Option<f32> {
        let q8 = *self.q8.get(channel)?;
        let mid = i32::from(SHUNT_MID_SCALE_CODE) << OFFSET_FRACTION_BITS;
        // Offsets are within 0..2^20: the difference cannot wrap.
        Some(q8.wrapping_sub(mid) as f32 / (1u32 << OFFSET_FRACTION_BITS) as f32)
    }
}

impl Default for ShuntOffsets {
    fn default() -> Self {
        Self::NOMINAL
    }
}

/// One shunt code minus its offset, in `I16F16` amps.
#[inline(always)]
fn shunt_bits(code: u16, offset_q8: i32) -> i32 {
    // code << 8 <= 2^20 and the offset is in 0..2^20 (calibration bounds it), so the difference is within +-2^20
    // and its product with 33 within +-2^26: no wrap. The shift rounds towards minus infinity (<= 1/65536 A).
    (i32::from(code) << OFFSET_FRACTION_BITS).wrapping_sub(offset_q8).wrapping_mul(33) >> 4
}

/// Phase currents (positive into the motor) from the three shunt codes and the calibrated offsets.
#[inline]
#[must_use]
pub fn phase_currents(adc: &AdcSamples, offsets: &ShuntOffsets) -> Abc<Amps> {
    let [a, b, c] = adc.phase_currents;
    let [oa, ob, oc] = offsets.q8;
    Abc::new(Amps::from_bits(shunt_bits(a, oa)), Amps::from_bits(shunt_bits(b, ob)), Amps::from_bits(shunt_bits(c, oc)))
}

/// DC-bus voltage from its 12-bit code (codes above 4095 are clamped).
#[inline]
#[must_use]
pub fn bus_voltage(code: u16) -> Volts {
    let code = u32::from(code.min(crate::hal::power::ADC_FULL_SCALE));
    // code <= 4095 and the factor < 2^20: the product < 2^32. The result < 2^22 fits an i32.
    Volts::from_bits((code.wrapping_mul(BUS_LSB_BITS_Q10) >> 10) as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn current_scale_is_exact() {
        // 124.12 LSB per ampere (4096 / 33): +124 LSB is 124 * 33 / 4096 A.
        let adc = AdcSamples { phase_currents: [2048 + 124, 2048, 2048 - 4096 / 33], ..AdcSamples::default() };
        let i = phase_currents(&adc, &ShuntOffsets::NOMINAL);
        assert_eq!(i.a.to_bits(), 124 * 528);
        assert_eq!(i.b.to_bits(), 0);
        assert_eq!(i.c.to_bits(), -(4096 / 33) * 528);
        // Full scale: code 4095 is 2047 LSB above mid-scale = 16.49 A.
        let adc = AdcSamples { phase_currents: [4095, 0, 2048], ..AdcSamples::default() };
        let i = phase_currents(&adc, &ShuntOffsets::NOMINAL);
        assert!((i.a.0.to_num::<f64>() - 2047.0 * 33.0 / 4096.0).abs() < 1e-4);
        assert!((i.b.0.to_num::<f64>() + 16.5).abs() < 1e-4);
    }

    #[test]
    fn fractional_offsets_are_removed() {
        // Offset 2048 + 37.5 LSB; a code of 2086 is half an LSB above it.
        let offsets = ShuntOffsets { q8: [(2048 * 256) + 37 * 256 + 128, 2048 * 256, 2048 * 256] };
        let adc = AdcSamples { phase_currents: [2086, 2048, 2048], ..AdcSamples::default() };
        assert_eq!(phase_currents(&adc, &offsets).a.to_bits(), 264);
        assert_eq!(offsets.deviation_lsb(0), Some(37.5));
        assert_eq!(offsets.deviation_lsb(3), None);
    }

    #[test]
    fn bus_scale() {
        assert!((bus_voltage(4095).0.to_num::<f64>() - 60.0).abs() < 1e-3);
        let v24 = bus_voltage(1638).0.to_num::<f64>();
        assert!((v24 - 1638.0 * 60.0 / 4095.0).abs() < 1e-4, "{v24}");
        assert_eq!(bus_voltage(u16::MAX), bus_voltage(4095));
    }
}
