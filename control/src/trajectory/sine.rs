//! sin(pi u) and sin(2 pi u) in Q60 for the sin² ramps, by a Taylor series in 64-bit fixed point (error below
//! 1e-11, exactly zero at the ends), and the constants of the sin² closed forms.

/// 1.0 in Q60.
const ONE_Q60: i64 = 1 << 60;
/// 1.0 in Q62 (the segment fraction `u`).
pub(super) const ONE_Q62: i128 = 1 << 62;
/// pi in Q60, rounded.
const PI_Q60: i128 = 3_622_009_729_038_561_421;
/// 1 / (2 pi²) in Q60, rounded.
pub(super) const INV_2PI2_Q60: i128 = 58_407_685_746_735_358;
/// 1 / (2 pi) in Q60, rounded.
pub(super) const INV_2PI_Q60: i128 = 183_493_156_455_125_077;
/// Horner coefficients of the sine's Taylor series, `1 / ((2k)(2k + 1))` in Q60 for k = 7..1 (terms up to x^15;
/// truncation error below (pi/2)^17 / 17! = 6e-12).
const SIN_TAYLOR_Q60: [i64; 7] = [
    5_490_102_402_889_748,
    7_390_522_465_428_506,
    10_481_104_587_334_973,
    16_012_798_675_095_097,
    27_450_512_014_448_738,
    57_646_075_230_342_349,
    192_153_584_101_141_163,
];

use crate::wide::mul_shr;

/// sin(pi w) for `w` in Q62 within [0, 1] (clamped), in Q60 (>= 0). Exactly 0 at w = 0 and w = 1.
pub(super) fn sin_pi_q60(w: i128) -> i64 {
    let w = w.clamp(0, ONE_Q62);
    let m = w.min(ONE_Q62.saturating_sub(w)); // [0, 1/2]: sin(pi w) = sin(pi (1 - w))
                                              // x = pi m <= pi/2 < 2^61 in Q60.
    let x = i64::try_from(mul_shr(PI_Q60, m, 62)).unwrap_or(0);
    let x2 = mul_q60(x, x); // <= 2.47 in Q60 < 2^62
    let mut t = ONE_Q60;
    for c in SIN_TAYLOR_Q60 {
        // t stays within [0.5, 1]: every product is below 2^123 before the shift.
        t = ONE_Q60.wrapping_sub(mul_q60(mul_q60(x2, t), c));
    }
    mul_q60(x, t)
}

/// sin(2 pi u) for `u` in Q62 within [0, 1], in Q60 (signed).
pub(super) fn sin_2pi_q60(u: i128) -> i64 {
    let w = u.clamp(0, ONE_Q62).saturating_mul(2);
    if w <= ONE_Q62 {
        sin_pi_q60(w)
    } else {
        sin_pi_q60(w.saturating_sub(ONE_Q62)).wrapping_neg()
    }
}

/// `(a * b) >> 60` for Q60 values below 2^62 in magnitude (the product is below 2^124: no wrap).
#[inline(always)]
fn mul_q60(a: i64, b: i64) -> i64 {
    let p = i128::from(a).wrapping_mul(i128::from(b)) >> 60;
    i64::try_from(p).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sine_matches_f64() {
        let mut worst = 0.0f64;
        for k in 0..=4096i128 {
            let u = (k << 62) / 4096;
            let x = k as f64 / 4096.0;
            let e1 = (sin_pi_q60(u) as f64 / (1u64 << 60) as f64 - (std::f64::consts::PI * x).sin()).abs();
            let e2 = (sin_2pi_q60(u) as f64 / (1u64 << 60) as f64 - (std::f64::consts::TAU * x).sin()).abs();
            worst = worst.max(e1).max(e2);
        }
        assert!(worst < 1e-11, "worst {worst}");
        assert_eq!(sin_pi_q60(0), 0);
        assert_eq!(sin_pi_q60(ONE_Q62), 0);
        assert_eq!(sin_2pi_q60(ONE_Q62 / 2), 0);
    }

    #[test]
    fn constants_match_f64() {
        let q60 = (1u64 << 60) as f64;
        assert!((PI_Q60 as f64 / q60 - std::f64::consts::PI).abs() < 1e-15);
        assert!((INV_2PI2_Q60 as f64 / q60 - 1.0 / (2.0 * std::f64::consts::PI.powi(2))).abs() < 1e-16);
        assert!((INV_2PI_Q60 as f64 / q60 - 1.0 / std::f64::consts::TAU).abs() < 1e-16);
        for (c, k) in SIN_TAYLOR_Q60.iter().zip([7.0f64, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0]) {
            assert!((*c as f64 / q60 - 1.0 / ((2.0 * k) * (2.0 * k + 1.0))).abs() < 1e-16);
        }
    }
}
