//! Clarke, Park and inverse Park transforms (amplitude-invariant), `I16F16` in and out.
//!
//! Multiplications are 32x32->64 (`fixed`'s `wide_mul`, one SMULL/SMLAL on Cortex-M4) followed by one shift back
//! to `I16F16`; nothing uses the 64x64 multiply that a plain `*` on `I16F16` compiles to (`shared/spec/target-qemu.md`,
//! pitfalls). Rounding is truncation towards minus infinity (one LSB, 15 uA or 15 uV, at most per product).
//!
//! Overflow (convention 10): the inputs are first saturated to +-2048 A (`clamp_phase`) where that matters. From
//! there every sum and product is proven in range and uses wrapping operations on purpose (comments at each site).

use fixed::types::{I16F16, I2F30};

use super::frames::{Abc, AlphaBeta, Amps, Dq};
use super::trig::SinCos;

/// 1/3 in Q32 (round(2^32 / 3)); fits an `i32` (< 2^31).
const ONE_THIRD_Q32: i32 = 1_431_655_765;
/// 4/sqrt(3) - 2 in Q32 (round((4/sqrt(3) - 2) * 2^32)).
const FOUR_OVER_SQRT3_MINUS_TWO_Q32: i32 = 1_328_867_506;

/// The largest phase-current magnitude [`clarke`] accepts without saturating: 2048 A in `I16F16` bits (2^27).
/// It is 124 times the reference shunt range (+-16.5 A); it exists so that Clarke and Park provably never overflow
/// (and so that the current loop can feed Park with alpha and beta times 4, see `rotate_hi_to_dq`).
pub const PHASE_CURRENT_LIMIT_BITS: i32 = 1 << 27;

/// Per-axis input saturation of [`park`] and [`inverse_park`]: 16384 in `I16F16` bits (2^30).
const AXIS_LIMIT_BITS: i32 = 1 << 30;

/// Saturates a phase current to +-2048 A (one SSAT on Cortex-M4).
#[inline(always)]
fn clamp_phase(x: Amps) -> i32 {
    x.to_bits().clamp(-PHASE_CURRENT_LIMIT_BITS, PHASE_CURRENT_LIMIT_BITS - 1)
}

/// High word of the 64-bit product, `(a * b) >> 32` floored (one SMMUL, or SMMLA with an addition, on Cortex-M4).
#[inline(always)]
pub(crate) fn mul_hi(a: i32, b: i32) -> i32 {
    (i64::from(a).wrapping_mul(i64::from(b)) >> 32) as i32
}

/// High word of the 64-bit product rounded to nearest, `(a * b + 2^31) >> 32` (one SMMULR on Cortex-M4). Never
/// wraps: |a * b + 2^31| < 2^63.
#[inline(always)]
pub(crate) fn mul_hi_round(a: i32, b: i32) -> i32 {
    (i64::from(a).wrapping_mul(i64::from(b)).wrapping_add(1 << 31) >> 32) as i32
}

/// Clarke transform of three phase currents, amplitude-invariant, with the zero-sequence component removed:
/// `alpha = (2a - b - c) / 3 = a - (a + b + c) / 3`, `beta = (b - c) / sqrt(3)`.
///
/// All three shunts are used (rather than reconstructing one phase from `a + b + c = 0`): the duty clamp of
/// [`super::svpwm`] keeps a sampling window open on every low side, so all three samples are valid, and removing the
/// mean cancels a common-mode error (equal offset drift in all three amplifiers) instead of folding it into alpha and
/// beta (a two-shunt Clarke turns an offset d common to all channels into an error vector of magnitude 2d). Cost:
/// about six instructions more than the two-shunt form (measured: the whole step stays within its budget). Each phase saturates at +-2048 A first. Error <= 1 LSB
/// (floor) per axis.
#[inline]
#[must_use]
pub fn clarke(i: Abc<Amps>) -> AlphaBeta<Amps> {
    let (alpha4, beta4) = clarke_x4(i);
    // Exact division by 4 of values below 2^30 in magnitude (floor).
    AlphaBeta { alpha: Amps::from_bits(alpha4 >> 2), beta: Amps::from_bits(beta4 >> 2) }
}

/// [`clarke`] times 4, in `I16F16` bits (|4 alpha|, |4 beta| < 2^30): the form [`rotate_hi_to_dq`] takes, with every
/// constant product the high word of one SMMUL.
#[inline(always)]
pub(crate) fn clarke_x4(i: Abc<Amps>) -> (i32, i32) {
    let a = clamp_phase(i.a);
    let b = clamp_phase(i.b);
    let c = clamp_phase(i.c);
    // |a + b + c| <= 3 * 2^27: no wrap.
    let sum = a.wrapping_add(b).wrapping_add(c);
    // 4 alpha = 4a - 4 sum / 3 = (4a - sum) - sum / 3; sum / 3 by a Q32 reciprocal (SMMUL, floor). |4 alpha| <= 4/3 2^29.
    let alpha4 = (a << 2).wrapping_sub(sum).wrapping_sub(mul_hi(sum, ONE_THIRD_Q32));
    // 4 beta = 4 (b - c) / sqrt(3) = 2 (b - c) + (b - c) (4/sqrt(3) - 2): the constant (0.309) fits a signed Q32 word,
    // so the product is one SMMUL (a Q31 1/sqrt(3) made LLVM emit an unsigned-times-signed UMULL + MLA sequence).
    // |b - c| <= 2^28, |4 beta| <= 4/sqrt(3) 2^28.
    let diff = b.wrapping_sub(c);
    let beta4 = (diff << 1).wrapping_add(mul_hi(diff, FOUR_OVER_SQRT3_MINUS_TWO_Q32));
    (alpha4, beta4)
}

/// Inverse Clarke transform (amplitude-invariant, no zero sequence): `a = alpha`,
/// `b = -alpha/2 + sqrt(3)/2 beta`, `c = -alpha/2 - sqrt(3)/2 beta`. Saturating, for any input. Not on the 25 kHz
/// path (the modulator folds it into its own arithmetic); provided for tests and diagnostics.
#[must_use]
pub fn inverse_clarke<T: Copy + From<I16F16> + Into<I16F16>>(v: AlphaBeta<T>) -> Abc<T> {
    let alpha: I16F16 = v.alpha.into();
    let beta: I16F16 = v.beta.into();
    let half_alpha = alpha.wrapping_shr(1);
    // sqrt(3)/2 in I2F30.
    let k = I2F30::from_bits(929_887_697);
    let beta_term = I16F16::saturating_from_num(beta.wide_mul(k));
    Abc {
        a: T::from(alpha),
        b: T::from(beta_term.saturating_sub(half_alpha)),
        c: T::from(half_alpha.saturating_neg().saturating_sub(beta_term)),
    }
}

/// Park rotation of raw `I16F16` bits by (sin, cos): `d = alpha cos + beta sin`, `q = -alpha sin + beta cos`, full
/// precision (Q46 products shifted back by 30). The caller guarantees |(alpha, beta)| < 2^31 / 1.0001 in bits (the
/// rotation gain is at most 1.00004).
#[inline(always)]
pub(crate) fn rotate_to_dq(alpha: i32, beta: i32, sc: SinCos) -> (i32, i32) {
    let (s, c) = (sc.sin, sc.cos);
    let (a, b) = (I16F16::from_bits(alpha), I16F16::from_bits(beta));
    // wide_mul: I16F16 x I2F30 -> I34F46 in an i64 (SMULL); the sums of two such products fit easily.
    let d = a.wide_mul(c).to_bits().wrapping_add(b.wide_mul(s).to_bits());
    let q = b.wide_mul(c).to_bits().wrapping_sub(a.wide_mul(s).to_bits());
    // Back to I16F16: the magnitude is preserved by the rotation, so the truncation to 32 bits does not wrap.
    ((d >> 30) as i32, (q >> 30) as i32)
}

/// The Park rotation of the current loop: the same as [`rotate_to_dq`], for alpha and beta given times 4 (from
/// [`clarke_x4`], within +-2^31 / 1.0001 in magnitude), with the shift folded away: each output is the high word of
/// an SMULL + SMLAL pair, `(4 alpha cos) >> 32 = (alpha cos) >> 30`.
#[inline(always)]
pub(crate) fn rotate_hi_to_dq(alpha4: i32, beta4: i32, sc: SinCos) -> (i32, i32) {
    let (s, c) = (sc.sin.to_bits(), sc.cos.to_bits());
    let wide = |x: i32, y: i32| i64::from(x).wrapping_mul(i64::from(y));
    // -alpha sin = alpha (-sin): |sin| <= 2^30 (1 + 4e-5), so the negation cannot wrap; the difference becomes an
    // SMLAL.
    let d = wide(alpha4, c).wrapping_add(wide(beta4, s));
    let q = wide(beta4, c).wrapping_add(wide(alpha4, s.wrapping_neg()));
    ((d >> 32) as i32, (q >> 32) as i32)
}

/// Inverse Park rotation of raw bits: `alpha = d cos - q sin`, `beta = d sin + q cos`, returning the high words of
/// the Q30 products: the output has two fraction bits fewer than the input (`I16F16` in, Q14 out). One SMULL and
/// one SMLAL per output, no shift. Never wraps for |(d, q)| < 2^31 / 1.0001.
#[inline(always)]
pub(crate) fn rotate_hi_to_alpha_beta(d: i32, q: i32, sc: SinCos) -> (i32, i32) {
    let (s, c) = (sc.sin.to_bits(), sc.cos.to_bits());
    let wide = |a: i32, b: i32| i64::from(a).wrapping_mul(i64::from(b));
    // -q sin = q (-sin): |sin| <= 2^30 (1 + 4e-5), so the negation cannot wrap; it makes the difference an SMLAL.
    let alpha = wide(d, c).wrapping_add(wide(q, s.wrapping_neg()));
    let beta = wide(d, s).wrapping_add(wide(q, c));
    ((alpha >> 32) as i32, (beta >> 32) as i32)
}

/// Park transform: the stator-frame current seen from the rotor frame at the angle whose sin/cos is `sc`.
///
/// Saturates the input vector to +-16384 A per axis first, so that the rotation never overflows for any input (the
/// output of [`clarke`] is always inside that range).
#[inline]
#[must_use]
pub fn park(i: AlphaBeta<Amps>, sc: SinCos) -> Dq<Amps> {
    let alpha = i.alpha.to_bits().clamp(-AXIS_LIMIT_BITS, AXIS_LIMIT_BITS - 1);
    let beta = i.beta.to_bits().clamp(-AXIS_LIMIT_BITS, AXIS_LIMIT_BITS - 1);
    let (d, q) = rotate_to_dq(alpha, beta, sc);
    Dq { d: Amps::from_bits(d), q: Amps::from_bits(q) }
}

/// Inverse Park transform: a rotor-frame vector (any `I16F16` quantity, e.g. volts) back to the stator frame.
/// Saturates the input to +-16384 per axis first, like [`park`].
#[inline]
#[must_use]
pub fn inverse_park<T: Copy + From<I16F16> + Into<I16F16>>(v: Dq<T>, sc: SinCos) -> AlphaBeta<T> {
    let d = v.d.into().to_bits().clamp(-AXIS_LIMIT_BITS, AXIS_LIMIT_BITS - 1);
    let q = v.q.into().to_bits().clamp(-AXIS_LIMIT_BITS, AXIS_LIMIT_BITS - 1);
    let (s, c) = (sc.sin, sc.cos);
    let (d, q) = (I16F16::from_bits(d), I16F16::from_bits(q));
    // I16F16 x I2F30 -> Q46 (wide_mul); |(d, q)| <= 2^30.5 bits and the rotation gain <= 1.00004: the result after
    // the shift back to I16F16 fits 32 bits.
    let alpha = d.wide_mul(c).to_bits().wrapping_sub(q.wide_mul(s).to_bits());
    let beta = d.wide_mul(s).to_bits().wrapping_add(q.wide_mul(c).to_bits());
    AlphaBeta {
        alpha: T::from(I16F16::from_bits((alpha >> 30) as i32)),
        beta: T::from(I16F16::from_bits((beta >> 30) as i32)),
    }
}
