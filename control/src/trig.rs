//! Sine and cosine of an [`ElectricalAngle`] from a 256-interval table with linear interpolation.
//!
//! - Table: 257 node values `sin(2 pi k / 256)`, `k = 0..=256`, in `I2F30` bits (2^30 = 1.0), computed at compile
//!   time by the integer-only `const fn` `build_table`: a Taylor series of sin on [0, pi/2] evaluated in Q60 with
//!   `i128` (terms up to x^31, truncation error below 2^-60), folded to the full turn by quarter-wave symmetry.
//!   They are stored as 256 segments (start value, twice the rise) packed in a `u64` each, so that the look-up needs
//!   no wrap of the index and one multiply.
//! - Minimax nodes: a chord between two exact nodes lies inside the arc by up to h^2/8 * |sin| (h = 2 pi / 256), so
//!   every node is scaled by (1 + h^2/16); the interpolation error then swings +-h^2/16 * |sin| (3.77e-5) instead
//!   of 0..h^2/8 (7.53e-5). The price: |sin| and |cos| reach 1 + 3.77e-5 at the nodes nearest the peaks.
//! - Lookup: the top 8 bits of the turn pick the interval, the other 24 bits interpolate (no angle quantisation
//!   beyond the u32 turn); per function value one segment load and one SMMLA (high word of a 32x32->64 product,
//!   added). cos(x) = sin(x + 1/4 turn) shares the interpolation fraction.
//!
//! Stated bound (property tests `trig_max_error` and `trig_error_any_angle` in `firmware/tests/control_props.rs`,
//! against `f64`, a sweep of 2^22 angles plus every node and midpoint, and random `u32` turns): |error| <= 4.0e-5 for
//! both sin and cos (measured maximum 3.8e-5).

use fixed::types::I2F30;

use super::angle::ElectricalAngle;
use super::transforms::mul_hi;

/// Sine and cosine of the same angle, `I2F30` (2^30 = 1.0; range [-2, 2), values within [-1.0000377, 1.0000377]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SinCos {
    /// sin(angle).
    pub sin: I2F30,
    /// cos(angle).
    pub cos: I2F30,
}

/// pi in Q60 (round(pi * 2^60)).
const PI_Q60: i128 = 3_622_009_729_038_561_421;
/// Table intervals per turn.
const INTERVALS: usize = 256;

/// The interpolation table (see the module documentation for how it is computed). Tests only; the look-up uses
/// [`SINE_SEGMENTS_Q30`], derived from the same `const fn`.
#[cfg(test)]
static SINE_Q30: [i32; INTERVALS + 1] = build_table();

/// sin(x) in Q60 for 0 <= x <= pi/2 (x in Q60), by its Taylor series; each term is below 2^123 in magnitude.
const fn sin_q60(x: i128) -> i128 {
    let x2 = x.wrapping_mul(x) >> 60;
    let mut term = x;
    let mut sum = x;
    let mut n: i128 = 1;
    while n < 31 {
        // term_{n+2} = -term_n * x^2 / ((n + 1)(n + 2))
        let divisor = n.wrapping_add(1).wrapping_mul(n.wrapping_add(2));
        // divisor >= 6: the quotient always exists.
        term = match (term.wrapping_mul(x2) >> 60).wrapping_neg().checked_div(divisor) {
            Some(t) => t,
            None => 0,
        };
        sum = sum.wrapping_add(term);
        n = n.wrapping_add(2);
    }
    sum
}

/// Builds the table of the module documentation. Compile-time only (it initialises a `static`).
#[allow(clippy::indexing_slicing)] // const evaluation: an out-of-bounds index is a compile error, not a panic
const fn build_table() -> [i32; INTERVALS + 1] {
    let quarter = INTERVALS / 4;
    // h = 2 pi / 256 = pi / 128; the node scale 1 + h^2/16 (see the module documentation).
    let h = PI_Q60 / 128;
    let correction = (h.wrapping_mul(h) >> 60) / 16;
    let mut table = [0i32; INTERVALS + 1];
    let mut k = 0;
    while k <= INTERVALS {
        let quadrant = (k / quarter) % 4;
        let r = k % quarter;
        // sin(pi/2 + y) = sin(pi/2 - y); sin(pi + y) = -sin(y).
        let reduced = if quadrant % 2 == 1 { quarter.wrapping_sub(r) } else { r };
        let x = (reduced as i128).wrapping_mul(PI_Q60) / 128;
        let s = sin_q60(x);
        let scaled = s.wrapping_add(s.wrapping_mul(correction) >> 60);
        // Round half up to Q30 (scaled >= 0).
        let q30 = (scaled.wrapping_add(1 << 29) >> 30) as i32;
        table[k] = if quadrant >= 2 { q30.wrapping_neg() } else { q30 };
        k = k.wrapping_add(1);
    }
    table
}

/// The look-up form of the table: per interval, the value at its start (low word) and twice the rise across it
/// (high word), packed in a `u64` so that one LDRD fetches both and the interpolation is one SMMLA (the high word of
/// a 32x32->64 product, added). |2 (y1 - y0)| <= 5.3e7 < 2^26.
static SINE_SEGMENTS_Q30: [u64; INTERVALS] = build_segments();

/// Builds [`SINE_SEGMENTS_Q30`] from [`build_table`]. Compile-time only.
#[allow(clippy::indexing_slicing)] // const evaluation: an out-of-bounds index is a compile error, not a panic
const fn build_segments() -> [u64; INTERVALS] {
    let table = build_table();
    let mut segments = [0u64; INTERVALS];
    let mut k = 0;
    while k < INTERVALS {
        let rise2 = table[k.wrapping_add(1)].wrapping_sub(table[k]).wrapping_mul(2);
        segments[k] = ((rise2 as u32 as u64) << 32) | (table[k] as u32 as u64);
        k = k.wrapping_add(1);
    }
    segments
}

/// Interpolated sine of a turn fraction, `I2F30` bits.
#[inline(always)]
fn sin_bits(turn: u32) -> i32 {
    let index = (turn >> 24) as usize; // 0..=255: the interval
                                       // Position inside the interval as a Q31 fraction (the low 24 bits of the turn, moved to bits 30..7): in [0, 1).
    let frac = ((turn << 8) >> 1) as i32;
    // `index` <= 255 is provably in bounds (256 segments): the fallback compiles away.
    let segment = SINE_SEGMENTS_Q30.get(index).copied().unwrap_or(0);
    let (y0, rise2) = (segment as u32 as i32, (segment >> 32) as u32 as i32);
    // (2 rise x frac_Q31) >> 32 = rise x frac, floored; its magnitude is below |rise|, so the sum stays between the
    // two nodes and cannot wrap.
    y0.wrapping_add(mul_hi(rise2, frac))
}

/// sin and cos of an electrical angle (table + linear interpolation; error <= 4.0e-5, see the module docs).
#[inline]
#[must_use]
pub fn sin_cos(angle: ElectricalAngle) -> SinCos {
    SinCos {
        sin: I2F30::from_bits(sin_bits(angle.0)),
        // cos(x) = sin(x + 1/4 turn); the turn wraps.
        cos: I2F30::from_bits(sin_bits(angle.0.wrapping_add(1 << 30))),
    }
}

/// sin of an electrical angle (error <= 4.0e-5).
#[inline]
#[must_use]
pub fn sin(angle: ElectricalAngle) -> I2F30 {
    I2F30::from_bits(sin_bits(angle.0))
}

/// cos of an electrical angle (error <= 4.0e-5).
#[inline]
#[must_use]
pub fn cos(angle: ElectricalAngle) -> I2F30 {
    I2F30::from_bits(sin_bits(angle.0.wrapping_add(1 << 30)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_scaled_sine() {
        let h = 2.0 * core::f64::consts::PI / 256.0;
        let scale = 1.0 + h * h / 16.0;
        for (k, &v) in SINE_Q30.iter().enumerate() {
            let want = (k as f64 * h).sin() * scale;
            let got = f64::from(v) / f64::from(1u32 << 30);
            assert!((got - want).abs() < 1.5e-9, "k={k} got={got} want={want}");
        }
        assert_eq!(SINE_Q30[0], 0);
        assert_eq!(SINE_Q30[128], 0);
        assert_eq!(SINE_Q30[256], 0);
        assert_eq!(SINE_Q30[64], -SINE_Q30[192]);
        for (k, &seg) in SINE_SEGMENTS_Q30.iter().enumerate() {
            assert_eq!(seg as u32 as i32, SINE_Q30[k]);
            assert_eq!((seg >> 32) as u32 as i32, 2 * (SINE_Q30[k + 1] - SINE_Q30[k]));
        }
    }
}
