//! 128-bit fixed-point arithmetic for the profile generator ([`super::trajectory`]) and the unit conversions: exact
//! multiply-shift with a 256-bit intermediate, exact shifted division, integer square root, rounding and
//! saturation. Every function is total: no input panics, results saturate.
//!
//! # Why this is its own module, and why it is written out
//! The Cortex-M4 has a 32x32 -> 64-bit multiplier and a 32/32-bit divider and nothing wider. A 128-bit product of
//! two values below 2^64 is a handful of instructions (`u64 x u64 -> u128`, measured 7 in QEMU), but the library's
//! 128-bit division (`__udivti3`) is a bit-serial loop of 2,000 to 4,000 instructions, and `u128::isqrt` about
//! 850. The trajectory planner divides about ten times per move and the sampler twice per slow tick, so the
//! library routines alone made a profile-mode slow tick 24,000 to 53,000 instructions (issue 16's bench).
//!
//! [`div_rem`] divides in 32-bit digits with the hardware divider instead (Knuth's algorithm D). The result is
//! the exact floor, the same bits as the library's division, so the planner's outputs do not change.

/// The low 64 bits of a `u128`.
const LOW64: u128 = u64::MAX as u128;

/// `a * b` for values whose product fits in 128 bits; uses the 64x64-bit product when both operands fit in 64
/// bits (the common case: a quotient estimate times a divisor).
#[inline(always)]
fn mul_u128(a: u128, b: u128) -> u128 {
    match (u64::try_from(a), u64::try_from(b)) {
        (Ok(a), Ok(b)) => u128::from(a).wrapping_mul(u128::from(b)),
        _ => a.wrapping_mul(b),
    }
}

/// `n / d` and `n % d`, exact (the same bits as the library's division); `None` for `d = 0`.
///
/// Schoolbook division in 32-bit digits on the hardware divider (Knuth, TAOCP vol. 2, 4.3.1, algorithm D; the
/// word-size steps as in Hacker's Delight, 9-4 and 9-5):
/// - a divisor below 2^64: `div_128_by_64` once, or twice when the quotient needs more than 64 bits;
/// - a larger divisor (quotient below 2^64): the top 64 bits of the normalised divisor give the quotient or one
///   more, and one comparison settles it.
#[must_use]
pub fn div_rem(n: u128, d: u128) -> Option<(u128, u128)> {
    if d == 0 {
        return None;
    }
    if n < d {
        return Some((0, n));
    }
    let (n_hi, n_lo) = split(n);
    if let Ok(d) = u64::try_from(d) {
        // The high quotient word first when it is not zero (a small divisor), so that the second step's dividend
        // is below the divisor times 2^64.
        let (q_hi, r_hi) =
            if n_hi >= d { (n_hi.checked_div(d).unwrap_or(0), n_hi.checked_rem(d).unwrap_or(0)) } else { (0, n_hi) };
        let (q_lo, r) = div_128_by_64(r_hi, n_lo, d);
        return Some(((u128::from(q_hi) << 64) | u128::from(q_lo), u128::from(r)));
    }
    // d >= 2^64: shift = lz(d) < 64. The top 64 bits of the normalised divisor, `v`, and the dividend halved, so
    // that its high word is below `v` (v >= 2^63 > (n >> 1) >> 64).
    let shift = d.leading_zeros();
    let (_, v) = split(d.wrapping_shl(shift) >> 64);
    let (h_hi, h_lo) = split(n >> 1);
    let (q1, _) = div_128_by_64(h_hi, h_lo, v);
    // floor(n / d) is q or q + 1 for q = (q1 2^shift >> 63) - 1, floored at zero (Hacker's Delight 9-5).
    let mut q = (u128::from(q1).wrapping_shl(shift) >> 63).saturating_sub(1);
    // q <= n / d < 2^64 and d < 2^128: q * d <= n, no wrap.
    let mut r = n.wrapping_sub(mul_u128(q, d));
    if r >= d {
        r = r.wrapping_sub(d);
        q = q.wrapping_add(1);
    }
    Some((q, r))
}

/// The high and low 64-bit words of a `u128`.
#[inline(always)]
fn split(x: u128) -> (u64, u64) {
    let hi = u64::try_from(x >> 64).unwrap_or(u64::MAX);
    let lo = u64::try_from(x & LOW64).unwrap_or(0);
    (hi, lo)
}

/// `(u_hi 2^64 + u_lo) / v` and the remainder, for `u_hi < v` (so the quotient fits in 64 bits): two quotient
/// digits of 32 bits, each estimated from the top two dividend digits and the top divisor digit and corrected
/// with the second divisor digit (at most twice, Knuth's theorem B). `v = 0` is excluded by `u_hi < v`.
fn div_128_by_64(u_hi: u64, u_lo: u64, v: u64) -> (u64, u64) {
    const BASE: u64 = 1 << 32;
    if v == 0 {
        return (u64::MAX, 0);
    }
    // Normalise: the divisor's top bit set, the dividend shifted along (u_hi < v keeps its top word below v's).
    let shift = v.leading_zeros();
    let v = v.wrapping_shl(shift);
    let (vn1, vn0) = (v >> 32, v & (BASE - 1));
    let un32 = if shift == 0 { u_hi } else { u_hi.wrapping_shl(shift) | u_lo.wrapping_shr(64u32.wrapping_sub(shift)) };
    let un10 = u_lo.wrapping_shl(shift);
    let (un1, un0) = (un10 >> 32, un10 & (BASE - 1));

    let q1 = quotient_digit(un32, un1, vn1, vn0);
    // The partial remainder is below v: the wrapping arithmetic gives it exactly.
    let un21 = un32.wrapping_mul(BASE).wrapping_add(un1).wrapping_sub(q1.wrapping_mul(v));
    let q0 = quotient_digit(un21, un0, vn1, vn0);
    let r = un21.wrapping_mul(BASE).wrapping_add(un0).wrapping_sub(q0.wrapping_mul(v));
    (q1.wrapping_mul(BASE) | q0, r.wrapping_shr(shift))
}

/// One 32-bit quotient digit of `(un 2^32 + next) / (vn1 2^32 + vn0)`, for `un < vn1 2^32 + vn0` and `vn1 >= 2^31`:
/// the estimate `un / vn1` (at most `2^32 - 1`) corrected until `q vn0 <= (un - q vn1) 2^32 + next`.
#[inline(always)]
fn quotient_digit(un: u64, next: u64, vn1: u64, vn0: u64) -> u64 {
    const BASE: u64 = 1 << 32;
    let (mut q, mut rhat) = if un >> 32 >= vn1 {
        // The estimate would be 2^32 or more: the digit is at most 2^32 - 1.
        (BASE - 1, un.wrapping_sub((BASE - 1).wrapping_mul(vn1)))
    } else {
        let (q, r) = div_64_by_32(un, vn1);
        (q, r)
    };
    // rhat < 2^32 in the loop, so rhat 2^32 + next < 2^64; q < 2^32 and vn0 < 2^32: no product wraps.
    while rhat < BASE && q.wrapping_mul(vn0) > rhat.wrapping_mul(BASE).wrapping_add(next) {
        q = q.wrapping_sub(1);
        rhat = rhat.wrapping_add(vn1);
    }
    q
}

/// `u / v` and `u % v` for `u < v 2^32` and `2^31 <= v < 2^32` (a 32-bit quotient), with the 32/32-bit hardware
/// divider: two 16-bit digits the same way as [`div_128_by_64`]'s 32-bit ones.
#[inline(always)]
fn div_64_by_32(u: u64, v: u64) -> (u64, u64) {
    const HALF: u64 = 1 << 16;
    let (u1, u0) = (u >> 32, u & 0xFFFF_FFFF);
    let (vn1, vn0) = (v >> 16, v & (HALF - 1));
    let (un1, un0) = (u0 >> 16, u0 & (HALF - 1));
    let digit = |un: u64, next: u64| -> u64 {
        // un < v <= 2^32: a 32-bit division; vn1 >= 2^15 is never zero.
        let (Ok(n32), Ok(d32)) = (u32::try_from(un), u32::try_from(vn1)) else { return 0 };
        let mut q = u64::from(n32.checked_div(d32).unwrap_or(0));
        let mut rhat = un.wrapping_sub(q.wrapping_mul(vn1));
        while q >= HALF || (rhat < HALF && q.wrapping_mul(vn0) > rhat.wrapping_mul(HALF).wrapping_add(next)) {
            q = q.wrapping_sub(1);
            rhat = rhat.wrapping_add(vn1);
            if rhat >= HALF && q < HALF {
                break;
            }
        }
        q
    };
    let q1 = digit(u1, un1);
    let un21 = u1.wrapping_mul(HALF).wrapping_add(un1).wrapping_sub(q1.wrapping_mul(v));
    let q0 = digit(un21, un0);
    let r = un21.wrapping_mul(HALF).wrapping_add(un0).wrapping_sub(q0.wrapping_mul(v));
    (q1.wrapping_mul(HALF) | q0, r)
}

/// The 256-bit product of two `u128` as (high, low).
fn wide_mul(a: u128, b: u128) -> (u128, u128) {
    let (a1, a0) = (a >> 64, a & LOW64);
    let (b1, b0) = (b >> 64, b & LOW64);
    // Each partial product of two values below 2^64 is below 2^128: no wrap.
    let p00 = a0.wrapping_mul(b0);
    let p01 = a0.wrapping_mul(b1);
    let p10 = a1.wrapping_mul(b0);
    let p11 = a1.wrapping_mul(b1);
    // Three terms below 2^64 each: no wrap.
    let mid = (p00 >> 64).wrapping_add(p01 & LOW64).wrapping_add(p10 & LOW64);
    let lo = (p00 & LOW64) | (mid << 64);
    // The full product is below 2^256, so the high word cannot wrap.
    let hi = p11.wrapping_add(p01 >> 64).wrapping_add(p10 >> 64).wrapping_add(mid >> 64);
    (hi, lo)
}

/// `(a * b) >> s` of magnitudes, truncated, saturating at `u128::MAX`. Operands below 2^64 (the planner's in
/// practice) take one 64x64-bit product inline; larger ones the 256-bit product out of line.
#[inline(always)]
fn mul_shr_u(a: u128, b: u128, s: u32) -> u128 {
    match (u64::try_from(a), u64::try_from(b)) {
        (Ok(a), Ok(b)) => u128::from(a).wrapping_mul(u128::from(b)).checked_shr(s).unwrap_or(0),
        _ => mul_shr_u_wide(a, b, s),
    }
}

/// [`mul_shr_u`] for operands of 64 bits or more.
#[inline(never)]
fn mul_shr_u_wide(a: u128, b: u128, s: u32) -> u128 {
    let (hi, lo) = wide_mul(a, b);
    if s == 0 {
        if hi == 0 {
            lo
        } else {
            u128::MAX
        }
    } else if s < 128 {
        if hi.wrapping_shr(s) != 0 {
            u128::MAX
        } else {
            hi.wrapping_shl(128u32.wrapping_sub(s)) | lo.wrapping_shr(s)
        }
    } else if s < 256 {
        hi.wrapping_shr(s.wrapping_sub(128))
    } else {
        0
    }
}

/// `(a * b) >> s`, truncated toward zero (so sign-symmetric), saturating at +-(2^127 - 1).
#[must_use]
#[inline(always)]
pub fn mul_shr(a: i128, b: i128, s: u32) -> i128 {
    let m = i128::try_from(mul_shr_u(a.unsigned_abs(), b.unsigned_abs(), s)).unwrap_or(i128::MAX);
    if (a < 0) != (b < 0) {
        m.wrapping_neg()
    } else {
        m
    }
}

/// `(n << s) / d`, truncated toward zero, saturating at +-(2^127 - 1); a zero divisor gives the saturated value
/// with the sign of `n` (0 for n = 0). Exact: when `n << s` does not fit in 128 bits, the quotient's fraction is
/// formed from the remainder bit by bit.
#[must_use]
pub fn div_shl(n: i128, d: i128, s: u32) -> i128 {
    let (nu, du) = (n.unsigned_abs(), d.unsigned_abs());
    let negative = (n < 0) != (d < 0);
    let saturated = if negative { i128::MIN.wrapping_add(1) } else { i128::MAX };
    if nu == 0 {
        return 0;
    }
    if s >= 127 {
        return saturated;
    }
    let magnitude = if nu.leading_zeros() >= s {
        // The shifted numerator fits: one exact division.
        div_rem(nu.wrapping_shl(s), du).map(|(q, _)| q)
    } else {
        div_rem(nu, du).and_then(|(q, r)| {
            if q != 0 && q.leading_zeros() <= s {
                return None;
            }
            let mut r = r;
            let mut f: u128 = 0;
            // r < du <= 2^127, so r << 1 never wraps.
            for _ in 0..s {
                r = r.wrapping_shl(1);
                f = f.wrapping_shl(1);
                if r >= du {
                    r = r.wrapping_sub(du);
                    f |= 1;
                }
            }
            Some(q.wrapping_shl(s) | f)
        })
    };
    let Some(m) = magnitude.and_then(|m| i128::try_from(m).ok()) else {
        return saturated;
    };
    if negative {
        m.wrapping_neg()
    } else {
        m
    }
}

/// `x >> s` rounded to nearest (ties toward +infinity), `1 <= s < 127`.
#[must_use]
#[inline(always)]
pub fn round_shr(x: i128, s: u32) -> i128 {
    x.saturating_add(1i128.wrapping_shl(s.wrapping_sub(1))).wrapping_shr(s)
}

/// Integer square root (floor) of a non-negative value, 0 for negatives.
///
/// Below 2^64 the library's 64-bit root. Above, the root of the top 64 bits (even shift) gives the root to 32
/// bits, one Newton step `(s + x / s) / 2` with [`div_rem`] leaves it at most a few above the root (never
/// below: the step starts above it), and the final comparisons settle it.
#[must_use]
pub fn isqrt(x: i128) -> i128 {
    let Ok(x) = u128::try_from(x) else { return 0 };
    if let Ok(small) = u64::try_from(x) {
        return i128::from(small.isqrt());
    }
    // x >= 2^64: shift right by an even amount so that 64 bits remain.
    let shift = 64u32.wrapping_sub(x.leading_zeros()).wrapping_add(1) & !1;
    let top = u64::try_from(x >> shift).unwrap_or(u64::MAX);
    // The estimate s0 = isqrt(top) 2^(shift/2) + 2^(shift/2) - 1 is at least the root, so the Newton step from
    // it stays at or above the root; from 32 correct bits it lands within 2^(shift/2 - 30) <= 4 of it.
    let half = shift >> 1;
    let s0 = (u128::from(top.isqrt()) << half).wrapping_add((1u128 << half).wrapping_sub(1));
    let s1 = div_rem(x, s0).map_or(s0, |(q, _)| s0.wrapping_add(q) >> 1).min(s0);
    // The root of a value below 2^128 is below 2^64: s1 * s1 fits.
    let mut root = s1;
    while root > 0 && mul_u128(root, root) > x {
        root = root.wrapping_sub(1);
    }
    i128::try_from(root).unwrap_or(0)
}

/// `n / d` rounded half up; 0 for d = 0.
#[must_use]
pub fn div_round_u(n: u128, d: u128) -> u128 {
    div_rem(n.saturating_add(d / 2), d).map_or(0, |(q, _)| q)
}

/// `x * sign` for a `sign` of -1, 0 or 1 (a `signum`): the same value as `x.saturating_mul(sign)` (`-x` saturates
/// at `i128::MAX`), without the general 128-bit product and its overflow check: about 350 bytes at each of the
/// planner's sign flips (flash, issue 17), and the QEMU bench's longest plan takes 6,043 instructions instead of
/// 7,108. Other signs are not multiplied (a positive one gives `x`, a negative one `-x`).
#[must_use]
#[inline(always)]
pub fn mul_sign(x: i128, sign: i128) -> i128 {
    if sign > 0 {
        x
    } else if sign < 0 {
        x.saturating_neg()
    } else {
        0
    }
}

/// Saturates to `i64`.
#[must_use]
#[inline(always)]
pub fn sat_i64(x: i128) -> i64 {
    i64::try_from(x).unwrap_or(if x < 0 { i64::MIN } else { i64::MAX })
}

/// Saturates to `i32`.
#[must_use]
#[inline(always)]
pub fn sat_i32(x: i128) -> i32 {
    i32::try_from(x).unwrap_or(if x < 0 { i32::MIN } else { i32::MAX })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn helpers_exact_at_the_edges() {
        assert_eq!(mul_shr(-3, 5, 0), -15);
        assert_eq!(mul_shr(i128::MAX, i128::MAX, 0), i128::MAX);
        assert_eq!(mul_shr(1 << 100, 1 << 100, 100), 1 << 100);
        assert_eq!(mul_shr(-(1 << 100), 1 << 100, 150), -(1 << 50));
        assert_eq!(div_shl(1, 3, 32), (1i128 << 32) / 3);
        assert_eq!(div_shl(-7, 2, 0), -3);
        assert_eq!(div_shl(5, 0, 3), i128::MAX);
        assert_eq!(div_shl(-5, 0, 3), i128::MIN + 1);
        assert_eq!(div_shl(1 << 120, 3 << 118, 60), (4i128 << 60) / 3);
        assert_eq!(div_shl(1, 1, 127), i128::MAX);
        assert_eq!(div_shl(1 << 100, 1, 27), i128::MAX);
        // Remainder carried bit by bit.
        let n = (1i128 << 125) + 12345;
        let d = (1i128 << 124) + 7;
        let expect = {
            let mut q = n / d;
            let mut r = n % d;
            for _ in 0..8 {
                r <<= 1;
                q <<= 1;
                if r >= d {
                    r -= d;
                    q |= 1;
                }
            }
            q
        };
        assert_eq!(div_shl(n, d, 8), expect);
        assert_eq!(round_shr(3 << 31, 32), 2);
        assert_eq!(round_shr(-(3 << 31), 32), -1);
        assert_eq!(isqrt((1 << 100) + 5), 1 << 50);
        assert_eq!(isqrt(i128::MAX), 13_043_817_825_332_782_212);
        assert_eq!(isqrt(-4), 0);
        assert_eq!(div_rem(u128::MAX, 1), Some((u128::MAX, 0)));
        assert_eq!(div_rem(u128::MAX, u128::MAX), Some((1, 0)));
        assert_eq!(div_rem(7, 0), None);
        assert_eq!(div_round_u(7, 2), 4);
        assert_eq!(div_round_u(7, 0), 0);
    }

    #[test]
    fn mul_sign_is_the_saturating_product_by_a_signum() {
        for x in [0, 1, -1, 12_345, -12_345, i128::MAX, i128::MIN, i128::MIN + 1, i128::MAX - 1] {
            for sign in [-1, 0, 1] {
                assert_eq!(mul_sign(x, sign), x.saturating_mul(sign), "{x} * {sign}");
            }
        }
    }

    /// Operands spread over every magnitude: a random value shifted right by a random amount.
    fn any_magnitude() -> impl Strategy<Value = u128> {
        (any::<u128>(), 0u32..128).prop_map(|(x, s)| x >> s)
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 20_000, ..ProptestConfig::default() })]

        /// The hardware-divider division gives the library's quotient and remainder for any operands.
        #[test]
        fn div_rem_is_the_exact_division(n in any_magnitude(), d in any_magnitude()) {
            prop_assert_eq!(div_rem(n, d), n.checked_div(d).zip(n.checked_rem(d)));
        }

        /// Dividends built as `q d + r` with divisors of every shape (all-ones and power-of-two digits included,
        /// where the digit estimates need their corrections): the quotient and remainder come back.
        #[test]
        fn div_rem_recovers_quotient_and_remainder(
            d in prop_oneof![
                any_magnitude(),
                (1u32..128).prop_map(|k| (1u128 << k) - 1),
                (0u32..128).prop_map(|k| 1u128 << k),
                (1u32..128, any::<u64>()).prop_map(|(k, x)| ((1u128 << k) - 1) ^ u128::from(x & 0xFFFF)),
            ],
            q in any_magnitude(), r in any::<u128>(),
        ) {
            prop_assume!(d != 0);
            let r = r % d;
            if let Some(n) = q.checked_mul(d).and_then(|p| p.checked_add(r)) {
                prop_assert_eq!(div_rem(n, d), Some((q, r)));
            }
        }

        /// The square root is the floor of the true root for any non-negative value.
        #[test]
        fn isqrt_is_the_floor_root(x in any_magnitude()) {
            let x = x >> 1;
            let want = i128::try_from(x.isqrt()).unwrap();
            prop_assert_eq!(isqrt(i128::try_from(x).unwrap()), want);
        }

        /// The shifted division equals the exact floor of `n 2^s / d` wherever that fits in 127 bits.
        #[test]
        fn div_shl_is_exact(n in any_magnitude(), d in any_magnitude(), s in 0u32..100) {
            let (n, d) = (i128::try_from(n >> 1).unwrap(), i128::try_from(d >> 1).unwrap());
            prop_assume!(d != 0);
            if (n as u128).leading_zeros() > s {
                let want = (n << s) / d;
                prop_assert_eq!(div_shl(n, d, s), want);
                prop_assert_eq!(div_shl(-n, d, s), -want);
            }
        }
    }
}
