//! Torque demand (per mille of rated torque) to q-axis current, limits, and actual values back to dictionary units.
//!
//! The current loop's reference comes from CST's target torque 0x6071 plus the torque offset 0x60B2 (CiA 402,
//! `shared/spec/control-and-protection.md` §3 "CST: target torque 0x6071 + torque offset -> current loop
//! directly"), both INTEGER16 in per mille of the motor rated torque 0x6076. The rated torque is, by its
//! definition in `device.toml`, the nominal current 0x3001:01 times the torque constant 0x3001:05, so one per mille
//! of rated torque is one per mille of the nominal current: `i_q = demand x I_N / 1000` (the torque constant
//! cancels, and 0x6076 is derived from 0x3001 by the drive, [`rated_torque_micro_nm`]). 0x30D0 "current demand"
//! is read-only (IDX L4728: an output of the torque path), so it is written, not read.
//!
//! Limits: the torque demand is clamped to +-0x6072 max torque, then the current to the lower of 0x6073 max current
//! (per mille of the nominal current) and 0x3001:02 output current limit.
//!
//! Arithmetic: the scales are computed with divisions when the parameters change ([`DemandScale::from_od`], slow
//! tick); the fast tick uses one 32x32->64 multiply and a shift per conversion.

use crate::frames::Amps;

/// Scales and limits of the torque path, derived from the motor data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DemandScale {
    /// `I16F16` bits of current per per mille of rated torque, Q16.
    bits_per_permille_q16: i64,
    /// Largest torque demand magnitude, per mille (0x6072).
    max_torque_permille: i32,
    /// Largest current magnitude, `I16F16` bits.
    current_limit_bits: i32,
    /// Per mille of nominal current per `I16F16` bit, Q32.
    permille_per_bit_q32: i64,
}

/// Rated torque 0x6076 in uNm = nominal current 0x3001:01 (mA) x torque constant 0x3001:05 (uNm/A) / 1000,
/// saturating.
#[must_use]
pub fn rated_torque_micro_nm(nominal_ma: u32, torque_constant_micro_nm_per_a: u32) -> u32 {
    let t = u64::from(nominal_ma).saturating_mul(u64::from(torque_constant_micro_nm_per_a)) / 1000;
    u32::try_from(t).unwrap_or(u32::MAX)
}

impl DemandScale {
    /// From 0x3001:01 nominal current (mA), 0x3001:02 output current limit (mA), 0x6073 max current (per mille of
    /// nominal) and 0x6072 max torque (per mille of rated). A zero nominal current is treated as 1 mA.
    #[must_use]
    pub fn from_od(nominal_ma: u32, output_limit_ma: u32, max_current_permille: u16, max_torque_permille: u16) -> Self {
        let nominal = u64::from(nominal_ma.max(1));
        // nominal mA / 1000 per per mille, in I16F16 bits, Q16: nominal * 2^32 / 10^6 (< 2^56 for nominal < 2^24).
        let bits_per_permille_q16 = i64::try_from((nominal << 32) / 1_000_000).unwrap_or(i64::MAX);
        // 0x6073 is per mille of the nominal current.
        let max_current_ma = nominal.saturating_mul(u64::from(max_current_permille)) / 1000;
        let limit_ma = max_current_ma.min(u64::from(output_limit_ma));
        let limit_ma = i32::try_from(limit_ma).unwrap_or(i32::MAX);
        // 1000 / (nominal / 1000) per ampere = 10^6 / nominal per 65536 bits: 10^6 * 2^16 / nominal, Q32.
        let permille_per_bit_q32 =
            i64::try_from((1_000_000u64 << 16).checked_div(nominal).unwrap_or(0)).unwrap_or(i64::MAX);
        Self {
            bits_per_permille_q16,
            max_torque_permille: i32::from(max_torque_permille),
            current_limit_bits: Amps::from_milliamps(limit_ma).to_bits(),
            permille_per_bit_q32,
        }
    }

    /// The reference motor's defaults: 3.2 A nominal, 10 A output limit, 0x6073 = 3125, 0x6072 = 3000.
    #[must_use]
    pub fn reference() -> Self {
        Self::from_od(3200, 10_000, 3125, 3000)
    }

    /// Torque demand (target + offset, clamped to the max torque) in per mille, and its q current clamped to the
    /// current limit.
    ///
    /// The limits are not negative (0x6072 is unsigned; the current limit comes from unsigned milliamperes and
    /// [`Self::limited_to`] floors it at 0) and are taken with max/min: `clamp` would assert the bounds' order with
    /// a formatted panic, whose `i32` and `i64` formatting stays in the images that print panics (flash, issue 17).
    /// With ordered bounds the results are the same.
    #[inline(always)]
    #[must_use]
    pub fn torque_to_current(&self, target_permille: i16, offset_permille: i16) -> (i16, Amps) {
        let demand = i32::from(target_permille)
            .wrapping_add(i32::from(offset_permille))
            .max(self.max_torque_permille.wrapping_neg())
            .min(self.max_torque_permille);
        // |demand| <= 65,535 and the scale < 2^40 for any nominal current in 0x3001:01's range (<= 10 A: < 2^36):
        // the product < 2^57. Rounded to nearest.
        let bits = (i64::from(demand).wrapping_mul(self.bits_per_permille_q16).wrapping_add(1 << 15) >> 16)
            .max(i64::from(self.current_limit_bits.wrapping_neg()))
            .min(i64::from(self.current_limit_bits));
        // Clamped to +-2^31 by the limit: the conversions are exact.
        (demand.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16, Amps::from_bits(bits as i32))
    }

    /// A current as per mille of the nominal current (0x6078; also 0x6077 torque actual, per mille of rated torque,
    /// since rated torque = nominal current x torque constant). Saturates at the `i16` range.
    #[must_use]
    pub fn current_to_permille(&self, current: Amps) -> i16 {
        let p = i64::from(current.to_bits()).wrapping_mul(self.permille_per_bit_q32).wrapping_add(1 << 31) >> 32;
        i16::try_from(p).unwrap_or(if p < 0 { i16::MIN } else { i16::MAX })
    }

    /// The same scale with the current limit lowered to `limit` (the I2t protection's), if that is lower.
    #[must_use]
    pub fn limited_to(self, limit: Amps) -> Self {
        Self { current_limit_bits: self.current_limit_bits.min(limit.to_bits().max(0)), ..self }
    }

    /// The current limit in force.
    #[must_use]
    pub const fn current_limit(&self) -> Amps {
        Amps::from_bits(self.current_limit_bits)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_mille_to_amps() {
        let s = DemandScale::reference();
        // 625 per mille of 3.2 A = 2 A.
        let (d, i) = s.torque_to_current(625, 0);
        assert_eq!(d, 625);
        assert!((i.0.to_num::<f64>() - 2.0).abs() < 2e-5, "{}", i.0);
        let (d, i) = s.torque_to_current(-500, 100);
        assert_eq!(d, -400);
        assert!((i.0.to_num::<f64>() + 1.28).abs() < 2e-5);
        // Max torque 3000 per mille clamps the demand; the 10 A output limit clamps the current (3000 -> 9.6 A).
        let (d, i) = s.torque_to_current(i16::MAX, i16::MAX);
        assert_eq!(d, 3000);
        assert!((i.0.to_num::<f64>() - 9.6).abs() < 2e-5);
        let tight = DemandScale::from_od(3200, 5000, 3125, 3000);
        assert_eq!(tight.torque_to_current(-3000, 0).1, Amps::from_milliamps(-5000));
        assert_eq!(tight.current_limit(), Amps::from_milliamps(5000));
    }

    #[test]
    fn amps_to_per_mille() {
        let s = DemandScale::reference();
        assert_eq!(s.current_to_permille(Amps::from_milliamps(2000)), 625);
        assert_eq!(s.current_to_permille(Amps::from_milliamps(-3200)), -1000);
        assert_eq!(s.current_to_permille(Amps::from_milliamps(1_000_000)), i16::MAX);
        assert_eq!(rated_torque_micro_nm(3200, 33_500), 107_200);
    }
}
