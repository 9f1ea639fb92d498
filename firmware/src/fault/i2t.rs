//! Motor I²t protection: a first-order thermal model of the winding that limits the current demand to the
//! nominal current once the winding reaches its limit (`shared/spec/control-and-protection.md` §3.1).
//!
//! Seeds:
//! - EPOS3 (S0 L2455-2545): "ϑ = P_V·R_th·(1 − e^(−t/τ_th)) + ϑ_0·e^(−t/τ_th)", "P_V = (1/T_p)·∫ i²·R dt",
//!   "If the I2t calculation reaches its limit based on the configured Thermal time constant winding and the
//!   motor's Nominal current, the output current is reduced to the Continuous Current Limit". Example: 1470 mA
//!   continuous, 2940 mA output limit, τ = 2.8 s: standardized peak current 2 → standardized time ≈ 0.3 →
//!   840 ms (a reading of Fig. 5-30).
//! - EPOS4/IDX (S1 L1011-1015): the current limit is the nominal current 0x3001:01 or the output current limit
//!   0x3001:02 "depending on the I²t level" 0x3200:01; (S2 L5437-5449) the level is in percent, "values higher
//!   than 100% are possible". Thermal time constant winding 0x3001:04 in 0.1 s.
//!
//! Model (the spec's derived closed form, which reproduces both S0 examples): a normalised thermal state `x`
//! (winding temperature rise over its maximum; 1.0 = the limit = 100 %), driven by the squared current:
//!
//! `τ·dx/dt = (i/I_N)² − x`
//!
//! so `x` rises while `i² > I_N²·x` and falls back below it, with the time constant `τ` (0x3001:04). At the
//! nominal current `x → 1` asymptotically and never reaches the limit. From cold, at a constant `i = k·I_N`
//! (k > 1), the time to the limit is `t = τ·ln(k²/(k²−1))` (k = 2: 0.2877·τ, i.e. 806 ms for the S0 example
//! versus the chart's 0.3·τ = 840 ms). Cooling at zero current: `x(t) = x_0·e^(−t/τ)`.
//!
//! Limit and hysteresis: the limit is reached when `x ≥ 1` (level ≥ 100 %); from then on the returned current
//! limit is the nominal current (the "I²t limit" warning, statusword bit 11) until `x` has fallen below 0.95
//! (level < 95 %; no seed specifies a release level). Fed with the nominal current, `x` stays at 1, so the drive
//! delivers the continuous current indefinitely, as EPOS does.
//!
//! Discretisation and fixed point (no floats, no division per step):
//! - The step is the slow tick, `T = 400 µs`. Per step `x += α·(p − x)` with `p = (i/I_N)²` and
//!   `α = T/(τ + T/2) = 4/(1000·τ_ds + 2)` (the bilinear pole `(τ − T/2)/(τ + T/2)` matches `e^(−T/τ)` to third
//!   order; time-constant error ≈ 1e-6 at τ = 0.1 s). `α` is held in Q32, rounded (relative error 2e-7 at
//!   τ = 0.1 s, 2e-5 at 20 s, 5e-4 at the slowest τ of 6553.5 s).
//! - `x` and `p` are Q32 (`1 << 32` = 100 %) in a `u64`. The current ratio is `|i|·⌈2^40/I_N⌉ >> 24` in Q16,
//!   clamped to 255 (so `p < 2^48`); a current above 255·I_N heats as 255·I_N.
//! - The product `(p − x)·α` is split into two `i64` multiplies (16-bit low part) and rounded to nearest, so
//!   nothing overflows. Resolution: an increment below half an LSB is dropped, so `x` settles within
//!   `2^31/α_q32` LSB of `p`: 1.2e-5 of the limit at τ = 20 s, 0.19 % at the slowest τ (6553.5 s).
//! - Cost per step: one 32×64 saturating multiply (ratio), one 32×32→64 (square), two 64-bit multiplies (filter),
//!   one 64-bit multiply (percent); adds and shifts otherwise.

/// The slow tick the model is stepped at, in microseconds (2.5 kHz).
pub const STEP_US: u32 = 400;

/// The thermal state at the limit, Q32 (100 %).
pub const LIMIT: u64 = 1 << 32;

/// The release level in percent: once limited, the current limit returns to the peak limit when the level is
/// below this (hysteresis).
pub const RELEASE_PERCENT: u16 = 95;

/// The thermal state below which the limit is released, Q32 (95 %).
const RELEASE: u64 = (LIMIT / 100) * RELEASE_PERCENT as u64;

/// The largest current ratio `|i|/I_N` the model heats with, Q16 (255.0).
const RATIO_MAX: u64 = 255 << 16;

/// The I²t parameters, converted once from the object dictionary (0x3001:01, :02, :04).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct I2tConfig {
    /// Nominal (continuous) current 0x3001:01, mA.
    nominal_ma: u32,
    /// Output (peak) current limit 0x3001:02, mA.
    peak_ma: u32,
    /// `⌈2^40 / I_N⌉` (I_N ≥ 1 mA): `|i|·inv_nominal >> 24` is `|i|/I_N` in Q16.
    inv_nominal: u64,
    /// `T/(τ + T/2)` in Q32, at most `2^32·4/1002 < 2^25`.
    alpha_q32: u32,
    /// The largest current the model distinguishes, `255 x I_N` in mA (capped at `u32`): clamping to it first
    /// keeps the ratio's product below 2^48 without a saturating multiply.
    max_ma: u32,
}

impl I2tConfig {
    /// Converts the motor data: nominal current 0x3001:01 (mA), output current limit 0x3001:02 (mA) and the thermal
    /// time constant winding 0x3001:04 (0.1 s units; reference motor 200 = 20 s).
    ///
    /// A nominal current of 0 is modelled as 1 mA (any current trips the limit, which is then 0 mA); a time
    /// constant of 0 as 1 (0.1 s, the fastest the objects allow).
    #[must_use]
    pub fn from_od(nominal_ma: u32, peak_ma: u32, time_constant_ds: u16) -> Self {
        let n = u64::from(nominal_ma.max(1));
        // ⌈2^40 / n⌉; n ≥ 1 so the quotient is at most 2^40.
        let inv_nominal = (1u64 << 40).div_ceil(n);
        let ds = u64::from(time_constant_ds.max(1));
        // α = 4/(1000·ds + 2) in Q32, rounded to nearest; den ≥ 1002 so α < 2^25.
        let den = ds.saturating_mul(1000).saturating_add(2);
        let alpha = (4u64 << 32).saturating_add(den / 2).checked_div(den).unwrap_or(u64::MAX);
        let max_ma = u32::try_from(n.saturating_mul(255)).unwrap_or(u32::MAX);
        Self { nominal_ma, peak_ma, inv_nominal, alpha_q32: u32::try_from(alpha).unwrap_or(u32::MAX), max_ma }
    }

    /// Nominal (continuous) current, mA.
    #[must_use]
    pub fn nominal_ma(&self) -> u32 {
        self.nominal_ma
    }

    /// Output (peak) current limit, mA.
    #[must_use]
    pub fn peak_ma(&self) -> u32 {
        self.peak_ma
    }

    /// The current limit while I²t limits: the nominal current (never above the peak limit).
    fn limited_ma(&self) -> u32 {
        self.nominal_ma.min(self.peak_ma)
    }
}

/// The result of one [`MotorI2t::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct I2tStatus {
    /// The I²t level for 0x3200:01, percent (100 = limit; may exceed 100; rounded down, saturating).
    pub level_percent: u16,
    /// The I²t limitation is active (warning, statusword bit 11 "internal limit active").
    pub limit_reached: bool,
    /// The current limit for the velocity/position loops, mA: the peak limit 0x3001:02 normally, the nominal
    /// current 0x3001:01 while limited.
    pub current_limit_ma: u32,
}

/// The thermal state of the motor winding (starts cold).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MotorI2t {
    /// Normalised winding temperature rise, Q32 (`LIMIT` = 100 %), at most `RATIO_MAX²` (Q32).
    x: u64,
    /// Latched limitation, released below [`RELEASE_PERCENT`].
    limited: bool,
}

impl MotorI2t {
    /// A cold motor (level 0 %, not limited).
    #[must_use]
    pub const fn new() -> Self {
        Self { x: 0, limited: false }
    }

    /// The thermal state, Q32 (`1 << 32` = 100 %).
    #[must_use]
    pub const fn state_q32(&self) -> u64 {
        self.x
    }

    /// The level in percent (0x3200:01), rounded down, saturating at `u16::MAX`.
    #[must_use]
    pub fn level_percent(&self) -> u16 {
        // x < 2^48, so x·100 < 2^55.
        let pct = self.x.wrapping_mul(100) >> 32;
        u16::try_from(pct).unwrap_or(u16::MAX)
    }

    /// Advances the model by one slow tick (400 µs) with the measured current (q current or phase RMS), mA.
    pub fn step(&mut self, current_ma: i32, config: &I2tConfig) -> I2tStatus {
        // |i|/I_N in Q16, clamped: |i| < 2^32 and inv ≤ 2^40, so saturate the product.
        // |i| <= 255 I_N and inv <= 2^40 / I_N + 1: the product stays below 2^49, no overflow.
        let clamped = u64::from(current_ma.unsigned_abs().min(config.max_ma));
        let ratio = (clamped.wrapping_mul(config.inv_nominal) >> 24).min(RATIO_MAX);
        // ratio < 2^24 fits u32; the square < 2^48 is p in Q32.
        let r = u32::try_from(ratio).unwrap_or(u32::MAX >> 8);
        let p = u64::from(r).wrapping_mul(u64::from(r));
        // Both below 2^48: the difference fits i64 exactly.
        let diff = i64::try_from(p).unwrap_or(0).wrapping_sub(i64::try_from(self.x).unwrap_or(0));
        let alpha = i64::from(config.alpha_q32);
        // diff·α / 2^32 rounded to nearest: hi = ⌊diff/2^16⌋ (|hi| < 2^32), lo = diff mod 2^16; α < 2^25.
        let hi = diff >> 16;
        let lo = diff & 0xFFFF;
        let v = hi.wrapping_mul(alpha).wrapping_add(lo.wrapping_mul(alpha) >> 16);
        let inc = v.wrapping_add(0x8000) >> 16;
        // x + inc lies between x and p (|inc| ≤ |diff|), so it stays in [0, 2^48).
        let x = i64::try_from(self.x).unwrap_or(0).wrapping_add(inc).max(0);
        self.x = u64::try_from(x).unwrap_or(0);

        if self.x >= LIMIT {
            self.limited = true;
        } else if self.x < RELEASE {
            self.limited = false;
        }
        I2tStatus {
            level_percent: self.level_percent(),
            limit_reached: self.limited,
            current_limit_ma: if self.limited { config.limited_ma() } else { config.peak_ma },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference motor: 20 s thermal time constant.
    const TAU_DS: u16 = 200;
    const NOMINAL: u32 = 1000;
    const PEAK: u32 = 3000;
    /// Steps per time constant at 400 µs.
    fn steps_per_tau(ds: u16) -> f64 {
        f64::from(ds) * 0.1 / (f64::from(STEP_US) * 1e-6)
    }

    /// Steps from cold until the limit at a constant current.
    fn steps_to_limit(cfg: &I2tConfig, current: i32, max: u32) -> Option<u32> {
        let mut m = MotorI2t::new();
        for n in 1..=max {
            let s = m.step(current, cfg);
            if s.limit_reached {
                return Some(n);
            }
        }
        None
    }

    fn rel_err(measured: f64, expected: f64) -> f64 {
        (measured - expected).abs() / expected
    }

    #[test]
    fn time_to_limit_matches_closed_form() {
        for &(tau_ds, nominal) in &[(TAU_DS, NOMINAL), (28, 1470), (1, 500), (5400, 10_000)] {
            let cfg = I2tConfig::from_od(nominal, nominal.saturating_mul(3), tau_ds);
            for &k in &[2u32, 3] {
                let k2 = f64::from(k * k);
                let expected = steps_per_tau(tau_ds) * (k2 / (k2 - 1.0)).ln();
                let current = i32::try_from(nominal * k).unwrap();
                let n = steps_to_limit(&cfg, current, (expected * 2.0) as u32).unwrap();
                let err = rel_err(f64::from(n), expected);
                println!("tau {tau_ds} ds, I_N {nominal} mA, k {k}: {n} steps vs {expected:.1} (err {err:.2e})");
                // 2 %, or one step where the time is below 50 steps (τ = 0.1 s, k = 3: 29.4 steps).
                assert!(err < 0.02 || (f64::from(n) - expected).abs() <= 1.0, "tau {tau_ds} k {k}: {n} vs {expected}");
                // Negative current heats the same.
                assert_eq!(steps_to_limit(&cfg, -current, n), Some(n));
            }
        }
    }

    #[test]
    fn seed_example_epos3() {
        // S0: 1470 mA, 2940 mA, τ = 2.8 s: model 0.2877·τ = 806 ms (chart 0.3·τ = 840 ms).
        let cfg = I2tConfig::from_od(1470, 2940, 28);
        let n = steps_to_limit(&cfg, 2940, 10_000).unwrap();
        let t_ms = f64::from(n) * 0.4;
        assert!(rel_err(t_ms, 2800.0 * (4.0f64 / 3.0).ln()) < 0.01, "{t_ms}");
        assert!(rel_err(t_ms, 840.0) < 0.05, "{t_ms}");
    }

    #[test]
    fn limited_current_holds_the_level_at_the_limit() {
        let cfg = I2tConfig::from_od(NOMINAL, PEAK, TAU_DS);
        let mut m = MotorI2t::new();
        let mut s = m.step(2000, &cfg);
        assert_eq!(s.current_limit_ma, PEAK);
        while !s.limit_reached {
            assert_eq!(s.current_limit_ma, PEAK);
            s = m.step(2000, &cfg);
        }
        assert_eq!(s.level_percent, 100);
        assert_eq!(s.current_limit_ma, NOMINAL);
        let at_limit = m.state_q32();
        // Ten time constants at the limited current: stays limited at 100 %, never above the crossing.
        for _ in 0..(10 * steps_per_tau(TAU_DS) as u32) {
            s = m.step(i32::try_from(s.current_limit_ma).unwrap(), &cfg);
            assert!(s.limit_reached);
            assert_eq!(s.current_limit_ma, NOMINAL);
            assert_eq!(s.level_percent, 100);
            assert!(m.state_q32() <= at_limit);
            assert!(m.state_q32() >= LIMIT);
        }
    }

    #[test]
    fn at_or_below_nominal_never_limits() {
        for &tau_ds in &[1u16, TAU_DS] {
            let cfg = I2tConfig::from_od(NOMINAL, PEAK, tau_ds);
            for &i in &[0, 500, 999, 1000, -1000] {
                let mut m = MotorI2t::new();
                // Twenty time constants: x is within e^-20 of its asymptote (≤ 1).
                for _ in 0..(20 * steps_per_tau(tau_ds) as u32) {
                    let s = m.step(i, &cfg);
                    assert!(!s.limit_reached, "tau {tau_ds} i {i}");
                    assert_eq!(s.current_limit_ma, PEAK);
                    assert!(s.level_percent <= 99);
                }
            }
        }
    }

    #[test]
    fn cooling_follows_the_time_constant_and_releases_below_95() {
        let cfg = I2tConfig::from_od(NOMINAL, PEAK, TAU_DS);
        let mut m = MotorI2t::new();
        while !m.step(3000, &cfg).limit_reached {}
        let x0 = m.state_q32() as f64;
        let tau_steps = steps_per_tau(TAU_DS) as u32;
        let mut released_at = None;
        for n in 1..=tau_steps {
            let s = m.step(0, &cfg);
            if !s.limit_reached && released_at.is_none() {
                released_at = Some(n);
                assert_eq!(s.current_limit_ma, PEAK);
                assert!(s.level_percent < 95);
            }
            if released_at.is_none() {
                assert_eq!(s.current_limit_ma, NOMINAL);
            }
        }
        let expected = x0 * (-1.0f64).exp();
        let err = rel_err(m.state_q32() as f64, expected);
        println!("cooling one tau: {} vs {expected:.0} (err {err:.2e}), level {}", m.state_q32(), m.level_percent());
        assert!(err < 0.02);
        // Release at x0·e^(−t/τ) = 0.95.
        let expected_release = steps_per_tau(TAU_DS) * (x0 / (0.95 * LIMIT as f64)).ln();
        assert!((f64::from(released_at.unwrap()) - expected_release).abs() <= 2.0);
    }

    #[test]
    fn extreme_inputs_do_not_panic() {
        let currents = [i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX];
        let amps = [0u32, 1, 2, 1000, u32::MAX / 2, u32::MAX];
        let taus = [0u16, 1, 200, u16::MAX];
        for &n in &amps {
            for &p in &amps {
                for &t in &taus {
                    let cfg = I2tConfig::from_od(n, p, t);
                    for &i in &currents {
                        let mut m = MotorI2t::new();
                        for _ in 0..3000 {
                            let s = m.step(i, &cfg);
                            assert!(s.current_limit_ma <= p);
                        }
                        // Then cool from wherever it got.
                        for _ in 0..3000 {
                            m.step(0, &cfg);
                        }
                        assert!(m.state_q32() <= RATIO_MAX * RATIO_MAX);
                    }
                }
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn random_sequences_stay_bounded(
            n in proptest::num::u32::ANY,
            p in proptest::num::u32::ANY,
            t in proptest::num::u16::ANY,
            seq in proptest::collection::vec(proptest::num::i32::ANY, 1..200),
        ) {
            let cfg = I2tConfig::from_od(n, p, t);
            let mut m = MotorI2t::new();
            for &i in &seq {
                let s = m.step(i, &cfg);
                let expected = if s.limit_reached { n.min(p) } else { p };
                proptest::prop_assert_eq!(s.current_limit_ma, expected);
                proptest::prop_assert!(m.state_q32() <= RATIO_MAX * RATIO_MAX);
            }
        }
    }
}
