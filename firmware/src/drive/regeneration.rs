//! The DC-bus voltage limiter: braking without an over-voltage trip on a bus that cannot return energy.
//!
//! # Why
//! A braking motor returns the load's kinetic energy to the DC bus. Behind a diode-fed supply nothing takes it
//! back, so it charges the bus capacitor: stopping the reference load (4 x 44 g cm^2) from 5,000 rpm returns
//! 2.4 J, while its 470 uF holds 0.6 J between the 24 V supply and the 56 V over-voltage trip (IDX 0x3210, "supply
//! too high, typically regenerative braking": `shared/spec/control-and-protection.md` §3.4). Drives answer with a
//! braking chopper where the hardware has one (PD4-E: ballast above 50.5 V, trip at 51.5 V) and, always, with a
//! limiter that keeps the bus below the trip ([`super::chopper`] is the chopper).
//!
//! # What it does
//! Tier 2 updates it from the bus voltage tier 1 measured last ([`BusVoltageLimiter::observe`], once per slow
//! period, in [`super::Drive::background`]) and applies it to every current reference it hands tier 1
//! ([`BusVoltageLimiter::limit`]). Two actions, each from a voltage of 0x3202:
//! 1. **Loss braking**, from 0x3202:02: while the motor brakes (the q reference opposes the velocity), a negative
//!    d current proportional to the bus voltage above that level (gain 0x3202:03), up to what the current limit in
//!    force leaves beside the q current (`sqrt(limit^2 - q^2)`). The winding turns it into heat (`1.5 R |i|^2`, about
//!    40 W at the reference motor's 10 A) without torque, so the braking torque, and with it the profile the drive
//!    follows, holds: on the reference plant this alone absorbs a PPM stop from 5,000 rpm at 30,000 rpm/s. A
//!    negative d current also weakens the field, so it never needs more voltage than the q current alone. The motor
//!    I2t model counts it (`super::Drive::slow_tick`).
//! 2. **Regenerative current reduction**, from 0x3202:04 minus the band 0x3202:05: a q reference that brakes is
//!    scaled down linearly to zero at 0x3202:04, which lies below the trip. The braking torque then falls to what
//!    the losses absorb and the motor takes longer to stop than demanded: the bus, not the profile, wins. The axis
//!    learns of it ([`BusVoltageLimiter::braking_limited`]) and starts a stop ramp again from the actual motion
//!    (`motion::axis`), as a drive's DC-link limiter stretches its ramp-down, so that a quick stop it stretches does
//!    not end in a following error.
//!
//! A q reference that drives the motor (the same sign as the velocity) is never touched: it draws energy from the
//! bus. Both actions end as soon as the bus falls back below their levels. 0x3202:01 = 0 switches the limiter off.
//!
//! # Rate
//! At 2.5 kHz the bus moves between two updates: the reference motor braking at 10 A from 5,000 rpm returns about
//! 130 W more than the winding takes, which lifts 470 uF at 50 V by 2.2 V per slow period, more than the 2 V band
//! of the reduction. Both actions therefore act on the voltage the bus will have when a decision takes effect: the
//! sample plus its rise over [`LOOKAHEAD_TICKS`] slow periods (a loop set-point decided in a slow tick applies in
//! the middle of the next slow period, and the sample is up to one period old). A falling bus is taken as it is.
//!
//! # The current, not its reference
//! The reduction sets a reference; the bus takes the current the motor actually carries. The current loop (a PI
//! without back-EMF feed-forward) trails a back-EMF that ramps, and it ramps fastest when an elastic load throws
//! the rotor back: on the geared preset the coupling accelerated the rotor by about 26,000 rad/s^2, the back-EMF
//! rose by about 1,700 V/s, and 2.2 to 3 A of braking q current stayed under a zero reference, about 35 W into a
//! bus that the loss braking (10 W in its 0.05 ohm) could not hold: 55 to 56 V in 1.7 ms, the trip. While the
//! reduction acts, each sample of the measured q current is therefore compared with the braking reference handed
//! out, and half of the excess moves the next reference toward driving (at most to the current limit): an
//! integrator that brings the measured braking current, not only its reference, down to the factor.
//!
//! # Power, not current
//! The bus takes power, `1.5 p psi w i_q`: the same braking current returns more of it the faster the rotor turns.
//! The factor is therefore a share of the braking power at the speed the reduction began at: above that speed the
//! factor shrinks in proportion (`speed at the start / speed`). On the geared preset the coupling throws the rotor
//! from about 600 to 1,700-1,900 rpm while the reduction acts; a factor on the current alone let the braking power
//! triple with the speed.
//!
//! # Release
//! The factor falls at once and grows back by at most [`RELEASE_STEP_Q16`] per sample; the correction of "The
//! current, not its reference" is given back by the same share of the current limit per sample, not dropped.
//! Dropped in one sample, it handed the velocity loop's full braking back at once: on the geared preset
//! auto-tuned (`drive-sim duty-cycle --auto-tune --plant hal-sim/presets/geared-36v.toml`, 36.6 s) up to 4.5 A of
//! correction toward driving vanished the moment the bus fell below the band, -12 A came back at 1,700 rpm (about
//! 220 W, 3.5 V per slow period on 470 uF) and the bus went from 52.9 V to 56.03 V, the trip (0x3210).

use crate::control::frames::{Amps, Dq, Volts};
use crate::control::wide::isqrt;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// 0x3202:06 bit 0: loss braking acts.
pub const STATE_LOSS_BRAKING: u8 = 1;
/// 0x3202:06 bit 1: the regenerative q current is reduced.
pub const STATE_REGEN_REDUCED: u8 = 1 << 1;

/// Slow periods of bus rise the limiter looks ahead (module documentation, "Rate"). Two: one from the sample to
/// the decision's effect, one of margin. Measured on the quick stop from 5,000 rpm at 150,000 rpm/s without a
/// chopper: bus peak 52.6 V with two, 54.3 V with one (`drive-sim ppm`).
pub const LOOKAHEAD_TICKS: i32 = 2;

/// Q16 one (a regenerative q current taken as it is).
const SCALE_ONE: i32 = 1 << 16;

/// The most the regenerative-current factor grows per slow period once the bus falls (module documentation,
/// "Release"): an eighth, full braking again 8 slow periods (3.2 ms) after the bus left the band.
pub const RELEASE_STEP_Q16: i32 = SCALE_ONE / 8;

/// The limiter's objects as the dictionary holds them (compared every slow period, converted on a change).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Objects {
    enabled: u8,
    loss_start_mv: u32,
    loss_gain_ma_per_v: u32,
    regen_zero_mv: u32,
    regen_band_mv: u32,
}

impl Objects {
    fn read(d: &Dictionary) -> Self {
        Self {
            enabled: d.get(h::BUS_LIMITER_ENABLE),
            loss_start_mv: d.get(h::BUS_LIMITER_LOSS_BRAKING_VOLTAGE),
            loss_gain_ma_per_v: d.get(h::BUS_LIMITER_LOSS_BRAKING_GAIN),
            regen_zero_mv: d.get(h::BUS_LIMITER_REGEN_ZERO_VOLTAGE),
            regen_band_mv: d.get(h::BUS_LIMITER_REGEN_BAND),
        }
    }
}

/// The bus-voltage limiter (module documentation).
#[derive(Clone, Copy, Debug)]
pub struct BusVoltageLimiter {
    objects: Option<Objects>,
    enabled: bool,
    /// 0x3202:02 in volt bits.
    loss_start: i32,
    /// 0x3202:03 as amp bits per volt, Q16.
    loss_gain_q16: i64,
    /// 0x3202:04 minus 0x3202:05 in volt bits: where the reduction starts.
    regen_start: i32,
    /// 0x3202:04 in volt bits.
    regen_zero: i32,
    /// The last bus sample, volt bits (for the rate of rise).
    last_v: i32,
    /// The loss-braking current the last bus sample calls for, amp bits (0: none).
    loss_current: i32,
    /// The current limit in force at the last sample, amp bits.
    limit_bits: i32,
    /// The factor on a regenerative q current, Q16 ([`SCALE_ONE`]: none).
    regen_scale_q16: i32,
    /// The last [`BusVoltageLimiter::limit`] reduced a braking q current.
    braking_limited: bool,
    /// The braking q reference the last [`BusVoltageLimiter::limit`] handed out, amp bits, and the velocity's sign
    /// it braked against (0: it did not brake): what the measured current is compared with.
    braking_reference: i32,
    braking_sign: i32,
    /// How far the q reference is moved toward driving, amp bits (>= 0), so that the measured braking current,
    /// not only its reference, follows the reduction (module documentation, "The current, not its reference").
    lag_correction: i32,
    /// |velocity| (Q32 inc/tick) when the reduction began, 0 while the factor is one: the speed whose braking power
    /// the factor scales (module documentation, "Power, not current").
    reduction_speed: i64,
}

impl Default for BusVoltageLimiter {
    fn default() -> Self {
        Self {
            objects: None,
            enabled: false,
            loss_start: i32::MAX,
            loss_gain_q16: 0,
            regen_start: i32::MAX,
            regen_zero: i32::MAX,
            last_v: 0,
            loss_current: 0,
            limit_bits: 0,
            regen_scale_q16: SCALE_ONE,
            braking_limited: false,
            braking_reference: 0,
            braking_sign: 0,
            lag_correction: 0,
            reduction_speed: 0,
        }
    }
}

impl BusVoltageLimiter {
    /// Takes over 0x3202:01..05 when they changed (the dictionary's ranges keep the voltages below the trip and
    /// the band positive).
    #[inline(never)]
    pub fn refresh(&mut self, d: &Dictionary) {
        let objects = Objects::read(d);
        if self.objects == Some(objects) {
            return;
        }
        self.objects = Some(objects);
        let volts = |mv: u32| Volts::from_millivolts(i32::try_from(mv).unwrap_or(i32::MAX)).to_bits();
        self.enabled = objects.enabled != 0;
        self.loss_start = volts(objects.loss_start_mv);
        // mA/V -> A/V in Q16: x 65536 / 1000 (exact enough: 1 mA/V is 65.536).
        self.loss_gain_q16 = i64::from(objects.loss_gain_ma_per_v).saturating_mul(65_536) / 1000;
        self.regen_zero = volts(objects.regen_zero_mv);
        self.regen_start = volts(objects.regen_zero_mv.saturating_sub(objects.regen_band_mv));
    }

    /// One bus sample and q current sample (tier 1's last, in [`super::Drive::background`]) with the current
    /// limit in force: the loss-braking current and the regenerative-current factor, in force until the next
    /// sample, for the voltage the bus will have when they take effect (module documentation, "Rate"), and the
    /// correction for a braking current that lags its reduced reference ("The current, not its reference").
    #[inline(never)]
    pub fn observe(&mut self, v_bus: Volts, i_q_measured: Amps, current_limit: Amps, velocity_bits: i64) {
        let v = v_bus.to_bits();
        // No rise before the first sample.
        let rise = if self.last_v == 0 { 0 } else { v.saturating_sub(self.last_v).max(0) };
        self.last_v = v;
        let v = v.saturating_add(rise.saturating_mul(LOOKAHEAD_TICKS));
        let below = v <= self.loss_start && v <= self.regen_start;
        if !self.enabled || (below && self.regen_scale_q16 == SCALE_ONE && self.lag_correction == 0) {
            self.loss_current = 0;
            self.regen_scale_q16 = SCALE_ONE;
            self.lag_correction = 0;
            self.braking_sign = 0;
            self.reduction_speed = 0;
            return;
        }
        let limit = current_limit.to_bits().max(0);
        let excess = i64::from(v.saturating_sub(self.loss_start).max(0));
        // Q16 volts x Q16 A/V >> 16: amp bits, at most the current limit.
        let loss = (excess.saturating_mul(self.loss_gain_q16) >> 16).min(i64::from(limit));
        self.loss_current = i32::try_from(loss).unwrap_or(limit);
        self.limit_bits = limit;
        let scale = if v >= self.regen_zero {
            0
        } else if v <= self.regen_start {
            SCALE_ONE
        } else {
            // (zero - v) / (zero - start), both positive and below 2^31: Q16 without overflow in i64.
            let num = i64::from(self.regen_zero.wrapping_sub(v)) << 16;
            let den = i64::from(self.regen_zero.wrapping_sub(self.regen_start)).max(1);
            i32::try_from(num.checked_div(den).unwrap_or(0)).unwrap_or(SCALE_ONE)
        };
        // The factor acts on the braking power of the speed the reduction began at: above it, a rotor the load
        // throws faster gets proportionally less current (module documentation, "Power, not current").
        let speed = velocity_bits.saturating_abs();
        if scale < SCALE_ONE && self.reduction_speed == 0 {
            self.reduction_speed = speed.max(1);
        }
        let scale = if scale < SCALE_ONE && speed > self.reduction_speed {
            // reduction_speed < speed: the ratio is below one, Q16; the product below 2^32.
            let ratio = self.reduction_speed.saturating_mul(i64::from(SCALE_ONE)).checked_div(speed).unwrap_or(0);
            i32::try_from(i64::from(scale).saturating_mul(ratio) >> 16).unwrap_or(0)
        } else {
            scale
        };
        // Reduced at once, given back by at most a step per sample ("Release").
        self.regen_scale_q16 = scale.min(self.regen_scale_q16.saturating_add(RELEASE_STEP_Q16));
        if self.regen_scale_q16 == SCALE_ONE {
            self.reduction_speed = 0;
        }
        self.correct_lag(i_q_measured.to_bits(), v <= self.regen_start);
    }

    /// Integrates how much more the motor brakes than the last reference asked (the measured q current against
    /// [`Self::braking_reference`], in the braking direction), by half of it per sample: the correction
    /// [`Self::limit`] moves the next reference by (module documentation, "The current, not its reference").
    /// Below the band it is given back by an eighth of the current limit per sample (as the factor is, "Release");
    /// none while the motor did not brake.
    fn correct_lag(&mut self, i_q_measured: i32, below_band: bool) {
        if self.braking_sign == 0 {
            self.lag_correction = 0;
            return;
        }
        if below_band {
            // Dropped at once it would hand the loops' full braking current back in one step.
            let give_back = (self.limit_bits >> 3).max(1);
            self.lag_correction = self.lag_correction.saturating_sub(give_back).max(0);
            return;
        }
        // Braking currents have the sign opposite to the velocity: s x (reference - measured) > 0 when the motor
        // brakes more than asked.
        let lag = self.braking_sign.saturating_mul(self.braking_reference.saturating_sub(i_q_measured));
        self.lag_correction = self.lag_correction.saturating_add(lag / 2).clamp(0, self.limit_bits);
    }

    /// Whether either action acts now.
    #[must_use]
    pub const fn active(&self) -> bool {
        self.loss_current != 0 || self.regen_scale_q16 != SCALE_ONE || self.lag_correction != 0
    }

    /// 0x3202:06: [`STATE_LOSS_BRAKING`] and [`STATE_REGEN_REDUCED`].
    #[must_use]
    pub const fn state_bits(&self) -> u8 {
        let mut bits = 0;
        if self.loss_current != 0 {
            bits |= STATE_LOSS_BRAKING;
        }
        if self.regen_scale_q16 != SCALE_ONE || self.lag_correction != 0 {
            bits |= STATE_REGEN_REDUCED;
        }
        bits
    }

    /// The current reference tier 1 gets for the q reference `i_q` at velocity sign `velocity_bits` (any
    /// velocity's raw bits: only the sign counts): while the motor brakes (`i_q` opposes the velocity), the
    /// loss-braking d current, and `i_q` reduced by the factor and to the room the d current leaves. `(0, i_q)`
    /// while the limiter does not act (one compare) or the motor does not brake.
    #[must_use]
    pub fn limit(&mut self, i_q: Amps, velocity_bits: i64) -> Dq<Amps> {
        self.braking_limited = false;
        if !self.active() {
            return Dq::new(Amps::ZERO, i_q);
        }
        let demanded = i_q.to_bits();
        let braking = (demanded < 0 && velocity_bits > 0) || (demanded > 0 && velocity_bits < 0);
        if !braking {
            self.braking_sign = 0;
            return Dq::new(Amps::ZERO, i_q);
        }
        let sign: i32 = if velocity_bits > 0 { 1 } else { -1 };
        let scaled = i32::try_from(i64::from(demanded).saturating_mul(i64::from(self.regen_scale_q16)) >> 16)
            .unwrap_or(demanded);
        // The lag correction moves the reference toward driving (the velocity's sign), at most to the limit (not
        // negative: floored at 0 in `observe`). Max/min: `clamp` would assert the bounds' order with a formatted
        // panic (flash in the images that print panics, issue 17).
        let q = scaled
            .saturating_add(sign.saturating_mul(self.lag_correction))
            .max(self.limit_bits.wrapping_neg())
            .min(self.limit_bits);
        self.braking_reference = q;
        self.braking_sign = sign;
        self.braking_limited = q != demanded;
        // Loss braking takes what the limit leaves beside the q current, sqrt(limit^2 - q^2) (amp bits below 2^31:
        // the squares fit u64).
        let limit_sq = i128::from(self.limit_bits).pow(2);
        let q_sq = i128::from(q).pow(2);
        let room = i32::try_from(isqrt(limit_sq.saturating_sub(q_sq))).unwrap_or(0);
        Dq::new(Amps::from_bits(self.loss_current.min(room).wrapping_neg()), Amps::from_bits(q))
    }

    /// The last [`Self::limit`] reduced a braking q current: the motor brakes less than the loops asked.
    #[must_use]
    pub const fn braking_limited(&self) -> bool {
        self.braking_limited
    }
}

/// An upper bound of the current vector's magnitude `sqrt(d^2 + q^2)` within 12 % (`max + min / 2`): what the
/// motor I2t model integrates, so that the loss-braking d current heats the model as it heats the winding. Never
/// below the magnitude (`(1 + t/2)^2 >= 1 + t^2` for `0 <= t <= 1`), so the model errs on the safe side.
#[must_use]
pub fn current_magnitude_bound(i: Dq<Amps>) -> Amps {
    let d = i.d.to_bits().saturating_abs();
    let q = i.q.to_bits().saturating_abs();
    let (big, small) = if d > q { (d, q) } else { (q, d) };
    Amps::from_bits(big.saturating_add(small >> 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::generated::handles as h;

    const LIMIT: f64 = 10.0;

    fn limiter() -> BusVoltageLimiter {
        let mut l = BusVoltageLimiter::default();
        l.refresh(&Dictionary::new(1));
        l
    }

    fn amps(a: f64) -> Amps {
        Amps::from_milliamps((a * 1000.0).round() as i32)
    }

    fn mv(v: f64) -> Volts {
        Volts::from_millivolts((v * 1000.0).round() as i32)
    }

    /// A steady bus at `v` (two samples: no rise to look ahead by).
    fn steady(l: &mut BusVoltageLimiter, v: f64) {
        l.observe(mv(v), Amps::ZERO, amps(LIMIT), 1);
        l.observe(mv(v), Amps::ZERO, amps(LIMIT), 1);
    }

    /// The limiter with the defaults but loss braking off (gain 0), to see the factor and the correction alone.
    fn limiter_without_loss_braking() -> BusVoltageLimiter {
        let mut d = Dictionary::new(1);
        d.set(h::BUS_LIMITER_LOSS_BRAKING_GAIN, 0);
        let mut l = BusVoltageLimiter::default();
        l.refresh(&d);
        l
    }

    /// Bus at the zero level (55 V), -6 A asked: the braking reference is zero; the current loop still brakes with
    /// -3 A (a rotor the load accelerates), so half of it moves the reference to +1.5 A; then -1 A against +1.5 A
    /// asked: 1.25 A more, +2.75 A. Each step asserted on the way.
    fn lagging_braking_corrected_to_2_75_a() -> BusVoltageLimiter {
        let mut l = limiter_without_loss_braking();
        steady(&mut l, 55.0);
        assert_eq!(l.limit(amps(-6.0), 1).q, Amps::ZERO);
        l.observe(mv(55.0), amps(-3.0), amps(LIMIT), 1);
        assert!(near(l.limit(amps(-6.0), 1).q, 1.5));
        l.observe(mv(55.0), amps(-1.0), amps(LIMIT), 1);
        assert!(near(l.limit(amps(-6.0), 1).q, 2.75));
        l
    }

    fn near(a: Amps, expected_a: f64) -> bool {
        (f64::from(a.to_milliamps()) / 1000.0 - expected_a).abs() <= 0.002
    }

    #[test]
    fn below_the_loss_braking_level_nothing_changes() {
        let mut l = limiter();
        steady(&mut l, 50.9);
        assert!(!l.active());
        assert_eq!(l.limit(amps(-3.0), 1), Dq::new(Amps::ZERO, amps(-3.0)));
        assert_eq!(l.state_bits(), 0);
        assert!(!l.braking_limited());
    }

    #[test]
    fn loss_braking_grows_with_the_bus_and_acts_only_while_braking() {
        // Defaults: from 51 V at 5 A/V.
        let mut l = limiter();
        steady(&mut l, 52.0);
        assert_eq!(l.state_bits(), STATE_LOSS_BRAKING);
        let braking = l.limit(amps(-2.0), 1000);
        assert!(near(braking.d, -5.0), "{braking:?}");
        assert_eq!(braking.q, amps(-2.0));
        assert!(!l.braking_limited(), "sqrt(10^2 - 5^2) = 8.66 A of room: q untouched");
        // Driving (q with the velocity): untouched.
        assert_eq!(l.limit(amps(2.0), 1000), Dq::new(Amps::ZERO, amps(2.0)));
        // At rest (no velocity): no braking either.
        assert_eq!(l.limit(amps(-2.0), 0), Dq::new(Amps::ZERO, amps(-2.0)));
    }

    #[test]
    fn the_loss_current_takes_what_the_q_current_leaves_under_the_limit() {
        let mut l = limiter();
        steady(&mut l, 52.6); // 8 A of loss braking wanted
                              // 9 A of braking q: sqrt(10^2 - 9^2) = 4.36 A left for d; q is not touched below the reduction band.
        let i = l.limit(amps(9.0), -1);
        assert!(near(i.d, -4.359), "{i:?}");
        assert_eq!(i.q, amps(9.0));
        assert!(!l.braking_limited());
        // 4 A of braking q leaves 9.17 A: the 8 A wanted fit.
        let i = l.limit(amps(-4.0), 1);
        assert!(near(i.d, -8.0) && i.q == amps(-4.0), "{i:?}");
        // The limit itself: nothing left for d.
        assert_eq!(l.limit(amps(10.0), -1).d, Amps::ZERO);
    }

    #[test]
    fn a_braking_q_current_falls_to_zero_across_the_band() {
        // Defaults: zero at 55 V, band 2 V; loss braking off (gain 0) to see the factor alone.
        let mut l = limiter_without_loss_braking();
        steady(&mut l, 53.0);
        assert_eq!(l.limit(amps(-4.0), 1).q, amps(-4.0));
        // A bus that stands at 54 V from the start (a step up would be looked ahead by, a step down released slowly).
        let mut l = limiter_without_loss_braking();
        steady(&mut l, 54.0);
        assert!(near(l.limit(amps(-4.0), 1).q, -2.0));
        assert!(l.braking_limited());
        assert_eq!(l.state_bits(), STATE_REGEN_REDUCED);
        steady(&mut l, 55.0);
        assert_eq!(l.limit(amps(-4.0), 1).q, Amps::ZERO);
        // Driving current is never reduced.
        assert_eq!(l.limit(amps(4.0), 1).q, amps(4.0));
        // Back below: given back an eighth per sample, then all gone.
        for _ in 0..8 {
            assert!(l.active());
            l.observe(mv(40.0), Amps::ZERO, amps(LIMIT), 1);
        }
        assert!(!l.active());
    }

    #[test]
    fn the_factor_is_given_back_an_eighth_per_sample_after_the_bus_left_the_band() {
        let mut l = limiter_without_loss_braking();
        steady(&mut l, 55.0);
        assert_eq!(l.limit(amps(-8.0), 1).q, Amps::ZERO);
        // 8 A braking on the bus at 40 V: 1, 2, ... 7 A, then 8 A untouched (the limiter off).
        for eighths in 1..8 {
            l.observe(mv(40.0), amps(-f64::from(eighths - 1)), amps(LIMIT), 1);
            let i = l.limit(amps(-8.0), 1);
            assert!(near(i.q, -f64::from(eighths)), "{eighths}: {i:?}");
            assert!(l.braking_limited());
        }
        l.observe(mv(40.0), amps(-7.0), amps(LIMIT), 1);
        assert!(!l.active());
        assert_eq!(l.limit(amps(-8.0), 1), Dq::new(Amps::ZERO, amps(-8.0)));
    }

    #[test]
    fn a_braking_current_that_lags_its_reduced_reference_moves_the_reference_toward_driving() {
        // Defaults without loss braking; bus at the zero level: a braking q reference becomes zero.
        let mut l = lagging_braking_corrected_to_2_75_a();
        // The measured current follows (+2.75 A): the correction holds; a current above its reference takes it back.
        l.observe(mv(55.0), amps(2.75), amps(LIMIT), 1);
        assert!(near(l.limit(amps(-6.0), 1).q, 2.75));
        l.observe(mv(55.0), amps(4.75), amps(LIMIT), 1);
        assert!(near(l.limit(amps(-6.0), 1).q, 1.75));
        // Negative velocity: the same in the mirror (the correction given back below the band first).
        steady(&mut l, 40.0);
        for _ in 0..8 {
            l.observe(mv(40.0), Amps::ZERO, amps(LIMIT), 1);
        }
        assert!(!l.active());
        steady(&mut l, 55.0);
        assert_eq!(l.limit(amps(6.0), -1).q, Amps::ZERO);
        l.observe(mv(55.0), amps(3.0), amps(LIMIT), 1);
        assert!(near(l.limit(amps(6.0), -1).q, -1.5));
        // Never beyond the current limit.
        for _ in 0..20 {
            l.observe(mv(55.0), amps(9.0), amps(LIMIT), 1);
        }
        assert_eq!(l.limit(amps(6.0), -1).q, amps(-LIMIT));
        // A motor that does not brake gets no correction (and resets it).
        assert_eq!(l.limit(amps(-6.0), -1).q, amps(-6.0));
        l.observe(mv(55.0), amps(9.0), amps(LIMIT), 1);
        assert_eq!(l.limit(amps(6.0), -1).q, Amps::ZERO);
    }

    #[test]
    fn the_correction_is_given_back_step_by_step_when_the_bus_leaves_the_band() {
        // Bus at 55 V, -6 A asked, -3 A measured: +1.5 A handed out, then -1 A measured: +2.75 A. The bus falls to
        // 40 V: the factor grows by an eighth and the correction falls by an eighth of the 10 A limit per sample, so
        // the braking reference comes back in steps of at most 0.75 + 1.25 A, not all at once (module
        // documentation, "Release": the loops' full braking at once lifted the geared preset's bus to the trip).
        let mut l = lagging_braking_corrected_to_2_75_a();
        // 1/8 x -6 + (2.75 - 1.25) = +0.75 A; 2/8 x -6 + 0.25 = -1.25 A; 3/8 x -6 + 0 = -2.25 A.
        for expected in [0.75, -1.25, -2.25] {
            l.observe(mv(40.0), Amps::ZERO, amps(LIMIT), 1);
            let i = l.limit(amps(-6.0), 1);
            assert!(near(i.q, expected), "{expected}: {i:?}");
            assert!(l.active() && l.state_bits() & STATE_REGEN_REDUCED != 0);
        }
    }

    #[test]
    fn above_the_speed_the_reduction_began_at_the_factor_shrinks_with_the_speed() {
        // The reduction begins at speed 1,000 (any unit: only the ratio counts) with the bus at 54 V (factor one
        // half); the load throws the rotor to 2,000 and 4,000 with the bus where it was: a quarter, an eighth of
        // the braking current, the same braking power (module documentation, "Power, not current").
        let mut l = limiter_without_loss_braking();
        l.observe(mv(54.0), Amps::ZERO, amps(LIMIT), 1000);
        l.observe(mv(54.0), Amps::ZERO, amps(LIMIT), 1000);
        assert!(near(l.limit(amps(-8.0), 1000).q, -4.0));
        l.observe(mv(54.0), Amps::ZERO, amps(LIMIT), 2000);
        assert!(near(l.limit(amps(-8.0), 2000).q, -2.0));
        l.observe(mv(54.0), Amps::ZERO, amps(LIMIT), 4000);
        assert!(near(l.limit(amps(-8.0), 4000).q, -1.0));
        // Slower than at the start: the factor of the voltage alone, one half, reached by the release's eighths
        // (1/8 -> 2/8 -> 3/8 -> 4/8).
        for expected in [-2.0, -3.0, -4.0, -4.0] {
            l.observe(mv(54.0), Amps::ZERO, amps(LIMIT), 500);
            assert!(near(l.limit(amps(-8.0), 500).q, expected), "{expected}");
        }
    }

    #[test]
    fn a_rising_bus_is_met_where_it_will_be_two_slow_periods_later() {
        // 50.0 V, then 50.6 V: a rise of 0.6 V per period looks like 51.8 V, 0.8 V into loss braking (4 A).
        let mut l = limiter();
        l.observe(mv(50.0), Amps::ZERO, amps(LIMIT), 1);
        l.observe(mv(50.6), Amps::ZERO, amps(LIMIT), 1);
        assert!(near(l.limit(amps(-1.0), 1).d, -4.0));
        // A falling bus is taken as it is.
        l.observe(mv(50.5), Amps::ZERO, amps(LIMIT), 1);
        assert!(!l.active());
    }

    #[test]
    fn switched_off_by_0x3202_01() {
        let mut d = Dictionary::new(1);
        d.set(h::BUS_LIMITER_ENABLE, 0);
        let mut l = BusVoltageLimiter::default();
        l.refresh(&d);
        steady(&mut l, 55.5);
        assert!(!l.active());
        assert_eq!(l.limit(amps(-4.0), 1), Dq::new(Amps::ZERO, amps(-4.0)));
    }

    #[test]
    fn the_magnitude_bound_is_never_below_the_magnitude_and_within_12_percent() {
        for (d, q) in [(0.0, 3.0), (3.0, 0.0), (-3.0, 3.0), (-1.0, 4.0), (-8.0, -2.0), (-5.0, 2.5)] {
            let bound = f64::from(current_magnitude_bound(Dq::new(amps(d), amps(q))).to_milliamps()) / 1000.0;
            let exact = f64::hypot(d, q);
            assert!(bound >= exact - 0.002 && bound <= exact * 1.12 + 0.002, "{d} {q}: {bound} vs {exact}");
        }
    }
}
