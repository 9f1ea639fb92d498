//! EPOS4's dual-loop main loop (EPOS4 AN ch. 10.4, S1 L9117-9190; `shared/spec/control-and-protection.md` §1.7):
//! the load position, measured by the main sensor on the gear output, closes a proportional loop whose output is
//! the velocity demand of the auxiliary loop, the motor's velocity PI on the motor encoder.
//!
//! # Law (per slow tick, Ts = 0.4 ms)
//! ```text
//! w_ref,aux = K_Main (theta_des - theta_meas) + GearRatio w_ref,main              (S1 L9149-9156)
//! K_Main    = K_HighMain + (K_LowMain - K_HighMain) exp(-H |theta_meas - theta_des|)  (S1 L9158-9190)
//! ```
//! Positions here are motor increments: the firmware converts the load encoder's count through the gear ratio
//! before the loop (`firmware::motion::dual_loop`), so `theta_meas` is the load's position expressed at the motor
//! shaft and the demand `w_ref,main` is already `GearRatio w_ref,main`.
//!
//! # Gain scheduling
//! The seed prints the shape over a following-error axis of 0..50 increments of the main encoder
//! (S1 Fig. 10-144) for weights H of the order of 10 (the tuned examples, S1 Tab. 10-94/10-96), and not the unit
//! of H. Derived: the exponent is `H |e| / 100` with `e` in main-encoder (load) increments, so that H = 10 moves
//! the gain across the figure's axis (63 % of the way from K_Low to K_High at 10 increments, 95 % at 30).
//! `exp(-x)` comes from a table of 33 quarter steps (x = 0..8) with linear interpolation; beyond x = 8 the gain
//! is K_High (exp(-8) = 0.03 %).
//!
//! Cost: a table look-up, two multiplications and a saturation per step, in the dual-loop configuration only.

pub use super::units::{IncPerTick, Increments};
use super::velocity::{sat_i32, SLOW_TICK_HZ};

/// `exp(-i/4)` for i = 0..=33, `U16F16` (rounded; exp(0) = 1 as 65535, one LSB short, to fit 16 bits).
const EXP_NEG_QUARTERS: [u16; 34] = [
    65535, 51039, 39750, 30957, 24109, 18776, 14623, 11388, 8869, 6907, 5380, 4190, 3263, 2541, 1979, 1541, 1200, 935,
    728, 567, 442, 344, 268, 209, 162, 127, 99, 77, 60, 47, 36, 28, 22, 17,
];

/// The exponent beyond which the scheduled gain is K_High: 8 (`U16F16`).
const EXPONENT_LIMIT: u32 = 8 << 16;

/// The largest gain taken, 10^6 (1,000/s, the dictionary's limit of 0x30AE:01/02, five times EPOS4's largest
/// tuned example, S1 Tab. 10-96): K Ts stays below 2^31.
const GAIN_MAX: u32 = 1_000_000;

/// 2^52 / (1000 f_s), rounded: a gain in 0.001/s times this, >> 20, is K Ts in 2^-32 per tick (a multiplication
/// where a division would cost a call; for every gain up to [`GAIN_MAX`] within 1 LSB of the exact quotient, and
/// equal to its floor for the values the tests check).
const PER_TICK_Q52: u64 = (((1u128 << 53) / (1000 * SLOW_TICK_HZ as u128) + 1) >> 1) as u64;

/// The following-error clamp before the gains: +-2^23 increments (2,048 revolutions at 4096 inc/rev, far beyond
/// any following-error window 0x6065; the velocity demand saturates long before).
const ERROR_LIMIT: i32 = 1 << 23;

/// `exp(-x)` for `x` in `U16F16`, `U16F16` (exp(0) = 65535), within 0.8 % of exp(-x) (linear interpolation between
/// quarter steps); 0 from x = 8 on.
#[must_use]
pub fn exp_neg(x: u32) -> u32 {
    if x >= EXPONENT_LIMIT {
        return 0;
    }
    // x < 2^19: the index is at most 31, so index + 1 is within the table.
    let index = (x >> 14) as usize;
    let fraction = x & 0x3FFF;
    let lower = u32::from(EXP_NEG_QUARTERS.get(index).copied().unwrap_or(0));
    let upper = u32::from(EXP_NEG_QUARTERS.get(index.wrapping_add(1)).copied().unwrap_or(0));
    // lower >= upper; the difference times 2^14 stays below 2^30.
    lower.wrapping_sub(((lower.wrapping_sub(upper)).wrapping_mul(fraction)) >> 14)
}

/// The main loop's gains in the per-tick form. Construct with [`MainLoopGains::from_idx_0x30ae`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct MainLoopGains {
    /// K_LowMain Ts: 2^-32 (inc/tick) per increment.
    k_low: i64,
    /// K_HighMain Ts: 2^-32 (inc/tick) per increment.
    k_high: i64,
    /// H / 100 per motor increment of error, `U16F16` per increment (the load-to-motor factor divided out).
    weight: u32,
}

impl MainLoopGains {
    /// Gains from 0x30AE:01 `k_low` and 0x30AE:02 `k_high` [0.001/s] and 0x30AE:03 `weight` [0.001] (raw values 1000
    /// times EPOS4's display values, digest §7), for a main sensor whose increment is `motor_per_load_num /
    /// motor_per_load_den` motor increments (the gear ratio times the motor encoder's resolution over the load
    /// encoder's; zero denominators count as 1). Call when the dictionary changes, never per tick.
    #[must_use]
    pub fn from_idx_0x30ae(
        k_low: u32,
        k_high: u32,
        weight: u32,
        motor_per_load_num: u64,
        motor_per_load_den: u64,
    ) -> Self {
        // K Ts in 2^-32 inc/tick per inc = raw * 1e-3 / f_s * 2^32 (raw limited to GAIN_MAX, the dictionary's).
        // raw <= 2^20 and the factor < 2^31: the product stays below 2^51.
        let per_tick = |raw: u32| -> i64 {
            let q = u64::from(raw.min(GAIN_MAX)).wrapping_mul(PER_TICK_Q52) >> 20;
            i64::try_from(q).unwrap_or(i64::MAX)
        };
        // H e_load / 100 with e_load = e_motor den / num: (raw / 1000) / 100 * den / num per motor increment.
        let num = motor_per_load_num.max(1);
        let den = motor_per_load_den.max(1);
        let weight_q16 =
            (u64::from(weight) << 16).saturating_mul(den).checked_div(num.saturating_mul(100_000)).unwrap_or(0);
        Self { k_low: per_tick(k_low), k_high: per_tick(k_high), weight: u32::try_from(weight_q16).unwrap_or(u32::MAX) }
    }

    /// The scheduled gain K_Main Ts (2^-32 inc/tick per increment) at a following error of `error` motor
    /// increments (S1 L9158-9190).
    #[must_use]
    pub fn scheduled(&self, error: i32) -> i64 {
        let x = self.weight.saturating_mul(error.unsigned_abs());
        let share = i64::from(exp_neg(x));
        // Both gains lie in 0..2^31 (`GAIN_MAX`) and share in 0..=2^16: the product stays within 2^47, the sum
        // between the two gains.
        let span = self.k_low.wrapping_sub(self.k_high);
        self.k_high.wrapping_add(span.wrapping_mul(share) >> 16)
    }
}

/// The main loop of the dual loop: load position error to the auxiliary loop's velocity demand.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct MainLoop {
    gains: MainLoopGains,
    following_error: i32,
}

impl MainLoop {
    /// A main loop with `gains`.
    #[must_use]
    pub const fn new(gains: MainLoopGains) -> Self {
        Self { gains, following_error: 0 }
    }

    /// The gains.
    #[must_use]
    pub const fn gains(&self) -> MainLoopGains {
        self.gains
    }

    /// The following error of the last step, `theta_des - theta_meas` (motor increments).
    #[must_use]
    pub const fn following_error(&self) -> i32 {
        self.following_error
    }

    /// One slow tick: `w = K_Main (theta_des - theta_meas) + w_ref` for the demand `theta_des`, the load position
    /// `theta_meas + fraction / 2^16` (motor increments: the load encoder resolves a motor increment further, and
    /// the loop closes on that finer position, not on the motor increment it falls in) and the demanded motor
    /// velocity `w_ref`, saturated to the velocity format (the auxiliary loop's limit then applies, S1 L9154:
    /// "limited to the maximal permitted motor speed").
    pub fn step(
        &mut self,
        theta_des: Increments,
        theta_meas: Increments,
        fraction: u16,
        w_ref: IncPerTick,
    ) -> IncPerTick {
        let raw = theta_des.wrapping_sub(theta_meas);
        self.following_error = raw;
        // The error in 2^-8 increments: |e| <= 2^31 + 255.
        let e = (i64::from(raw.clamp(-ERROR_LIMIT, ERROR_LIMIT)) << 8).wrapping_sub(i64::from(fraction >> 8));
        let k = self.gains.scheduled(sat_i32(e >> 8));
        // 0 <= k < 2^31 and |e| < 2^31 + 2^8: the product stays below 2^62.1; >> 24 gives 2^-16 inc/tick.
        let w = k.wrapping_mul(e) >> 24;
        IncPerTick::from_bits(sat_i32(w).saturating_add(w_ref.to_bits()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table against exp: every quarter step exact to the rounding; between two steps the chord, which lies
    /// above the convex exp by at most (1/4)^2 / 8 = 0.8 % of exp(-x) (0.7 % at x = 1/8, below).
    #[test]
    fn exp_table_follows_exp() {
        assert_eq!(exp_neg(0), 65535, "1.0, one LSB short");
        assert_eq!(exp_neg(1 << 16), 24109, "exp(-1) = 0.367879 = 24109.4 / 65536");
        assert_eq!(exp_neg(3 << 16), 3263, "exp(-3) = 0.049787");
        assert_eq!(exp_neg(8 << 16), 0, "beyond the table: K_High");
        // Halfway between 0 and 1/4: chord (65535 + 51039) / 2 = 58287; exp(-1/8) = 57835.6.
        assert_eq!(exp_neg(1 << 13), 58287);
        // Monotone non-increasing over the whole range.
        let mut last = u32::MAX;
        for x in (0..(9 << 16)).step_by(97) {
            let y = exp_neg(x);
            assert!(y <= last, "exp_neg({x}) = {y} above {last}");
            last = y;
        }
    }

    /// S1 L9158-9190: zero error gives K_Low, a large error K_High. 0x30AE:01 = 221,340 (221.34/s, EPOS4 UC1),
    /// :02 = 44,268: K Ts = 221.34 / 2500 per tick = 0.088536 = 380,259,224 / 2^32 (floor).
    #[test]
    fn gain_schedule_runs_from_k_low_to_k_high() {
        let g = MainLoopGains::from_idx_0x30ae(221_340, 44_268, 10_000, 1, 1);
        // K_Low to within one part in 65,536 (the table's exp(0) = 65535 / 65536): 380,254,582.
        assert_eq!(g.scheduled(0), 380_254_582);
        assert_eq!(g.k_high, 76_051_844);
        assert_eq!(g.scheduled(1_000), 76_051_844, "H |e| / 100 = 100: K_High");
        // 10 load increments with H = 10: x = 10 * 6553 / 65536 (H / 100 = 0.1 rounded down in U16F16), just
        // below 1: exp(-0.99991) = 0.36791, K = K_High + 0.36791 (K_Low - K_High).
        let k = g.scheduled(10);
        assert_eq!(exp_neg(65_530), 24_112);
        let expected = 76_051_844 + (((380_259_224 - 76_051_844) * 24_112) >> 16);
        assert_eq!(k, expected);
        assert_eq!(g.scheduled(-10), k, "the scheduler sees |e|");
    }

    /// The weight counts load increments: with 1.024 motor increments per load increment (5:1 gear, 4096 motor
    /// inc/rev, 20,000 load inc/rev) 100 load increments are 102.4 motor increments. With H = 1 the gain there is
    /// the one a direct sensor has at 100 increments (exp(-1)), within 1 % of the span (102 of 102.4 increments,
    /// the weight's U16F16 rounding).
    #[test]
    fn weight_is_per_load_increment() {
        let g = MainLoopGains::from_idx_0x30ae(100_000, 10_000, 1_000, 5 * 4096, 20_000);
        let direct = MainLoopGains::from_idx_0x30ae(100_000, 10_000, 1_000, 1, 1);
        let span = direct.scheduled(0) - direct.k_high;
        let geared = g.scheduled(102) - g.k_high;
        let reference = direct.scheduled(100) - direct.k_high;
        assert!((geared - reference).abs() * 100 <= span, "{geared} vs {reference}");
        assert!(g.scheduled(200) < reference, "a larger error: nearer K_High");
    }

    /// S1 L9149-9156: `w = K e + w_ref`. K = 25/s (0x30AE:01 = :02 = 25,000) is 0.01 per tick: an error of 100
    /// increments asks 1 inc/tick (65536 in `I16F16`) on top of the demand's 2 inc/tick; the sign follows the error.
    #[test]
    fn main_loop_law_is_gain_times_error_plus_demand() {
        let mut m = MainLoop::new(MainLoopGains::from_idx_0x30ae(25_000, 25_000, 10_000, 1, 1));
        let w = m.step(Increments(1_100), Increments(1_000), 0, IncPerTick::from_bits(2 << 16));
        assert_eq!(m.following_error(), 100);
        // K Ts = 42,949,672 / 2^32 (floor of 0.01 * 2^32): 100 * 42,949,672 >> 16 = 65,535.
        assert_eq!(w.to_bits(), (2 << 16) + 65_535);
        let w = m.step(Increments(900), Increments(1_000), 0, IncPerTick::ZERO);
        assert_eq!(w.to_bits(), -65_536, "floor of -1 inc/tick");
        // No error: the demand alone (the dual loop follows the path by its feedforward).
        assert_eq!(m.step(Increments(5), Increments(5), 0, IncPerTick::from_bits(777)).to_bits(), 777);
        // Across the i32 wrap of both positions the error is the short way.
        m.step(Increments(i32::MIN.wrapping_add(10)), Increments(i32::MAX.wrapping_sub(9)), 0, IncPerTick::ZERO);
        assert_eq!(m.following_error(), 20);
        // The load half an increment short of 1,000 (999 + 0x8000 / 2^16): half the gain's 1 inc/tick per 100 inc,
        // 0.005 inc/tick = 327.68 / 2^16, floor; the following error 0x60F4 stays in whole increments.
        let w = m.step(Increments(1_000), Increments(999), 0x8000, IncPerTick::ZERO);
        assert_eq!((w.to_bits(), m.following_error()), (327, 1));
    }
}
