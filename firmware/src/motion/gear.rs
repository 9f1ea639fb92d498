//! The gear between motor and load (0x3003, control structure 0x3000:02 bit 12, CiA 402 gear ratio 0x6091) and
//! the user units it gives the master's objects.
//!
//! The gear in effect: 0x3003:01/02 (motor revolutions per load revolution, IDX L4067-4158: "absolute reduction =
//! numerator / denominator = input speed / output speed") when 0x3000:02 bit 12 "gear mounted" is set (IDX: "a gear
//! only works if bit 12 is set"), else 1:1. 0x6091 (PD4-E p.257: motor revolutions :01 per shaft revolutions :02)
//! is the CiA 402 view of the same gear, not a second one: it reads the ratio in effect, and a write of it writes
//! 0x3003:01/02 and bit 12 (`crate::drive::objects`), so there is never a gear that one object shows and the
//! other does not.
//!
//! User units with a gear in effect (IDX 0x3000:02 bits 15..14 "process value reference", 0 = on motor, is the
//! only value the seeds give, but IDX 0x3000:06 states the axis's speed limit on the gear output, in the velocity
//! unit, and PD4-E's factor group scales positions through 6091h to the shaft): the master's positions count
//! load increments, the main sensor's resolution 0x3000:05 per LOAD revolution (0x607A, 0x6064, 0x6062, 0x60F4,
//! 0x60B0, 0x607C, 0x30B0, 0x607D, 0x6065, 0x6067, the homing distances 0x30B1 and 0x30B3, 0x60BA..0x60BD); its
//! velocities are load rpm and its accelerations load rpm/s (every rpm object but the motor's own limits 0x6080
//! and 0x3003:03; `MotionScale::geared`); torques stay motor torque (per mille of the motor's rated torque).
//! The axis, its loops and tier 1 keep motor increments: only the values exchanged with the master convert, each
//! time from the absolute value (no error accumulates), exactly rounded ([`Ratio::apply`]), without a division
//! (the 2.5 kHz path has no time for a 64-bit software division: [`Ratio`] precomputes a 32.32 factor when the
//! gear is written and corrects its one possible rounding step with the exact integer remainder).
//!
//! In the dual loop the load encoder is the main sensor, and the master's positions count its increments
//! ([`UserUnits::with_main_sensor`]).
//!
//! 0x3003:04 bit 0 (the gear output turns opposite to its input) inverts the load's positions and velocities on
//! top of the polarity 0x607E (they combine as signs do); torques keep the motor's sign.
//!
//! Range: the axis counts wrapping `i32` motor increments; a master position whose motor value does not fit
//! (beyond +-2^31 motor increments) saturates at the end of the range (targets, limits) rather than wrapping into
//! a position on the other side.

use super::polarity::Polarity;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// 0x3000:02 bit 12: a gear is mounted (IDX L3858).
pub const GEAR_MOUNTED: u32 = 1 << 12;
/// 0x3003:04 bit 0: the gear output turns opposite to its input (IDX L4150).
pub const GEAR_DIRECTION_INVERTED: u32 = 1;

/// An exact rational factor `p / q` on positions, rounded to nearest (half up), without a division per use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Ratio {
    p: u32,
    q: u32,
    /// floor(p / q).
    whole: i64,
    /// (p mod q) / q in 0.32 fixed point, rounded (at most 2^32).
    fraction: i64,
}

impl Ratio {
    /// 1:1.
    pub const ONE: Self = Self { p: 1, q: 1, whole: 1, fraction: 0 };

    /// `p / q`; a zero `q` (refused by the dictionary) is taken as 1, a zero `p` as 1.
    #[must_use]
    pub fn new(p: u32, q: u32) -> Self {
        let (p, q) = (p.max(1), q.max(1));
        if p == q {
            return Self::ONE;
        }
        let whole = p.checked_div(q).unwrap_or(p);
        let rest = u64::from(p.checked_rem(q).unwrap_or(0));
        let half = u64::from(q) >> 1;
        let fraction = (rest << 32).saturating_add(half).checked_div(u64::from(q)).unwrap_or(0);
        Self { p, q, whole: i64::from(whole), fraction: i64::try_from(fraction).unwrap_or(0) }
    }

    /// Whether the factor is 1.
    #[must_use]
    pub const fn is_one(&self) -> bool {
        self.p == self.q
    }

    /// round(x p / q), half up, exact for every `i32` `x` and `p / q` below 2^31: the 32.32 factor's estimate is
    /// within 0.75 of x p / q (its fraction errs by at most 2^-33 per unit of x), so one step against the exact
    /// remainder x p - estimate q (small, so exact in wrapping 64-bit arithmetic) corrects it.
    #[must_use]
    pub fn apply(&self, x: i32) -> i64 {
        if self.is_one() {
            return i64::from(x);
        }
        let x = i64::from(x);
        let estimate =
            x.wrapping_mul(self.whole).wrapping_add(x.wrapping_mul(self.fraction).wrapping_add(1 << 31) >> 32);
        let q = i64::from(self.q);
        let remainder = x.wrapping_mul(i64::from(self.p)).wrapping_sub(estimate.wrapping_mul(q));
        let twice = remainder.wrapping_mul(2);
        if twice >= q {
            estimate.wrapping_add(1)
        } else if twice < q.wrapping_neg() {
            estimate.wrapping_sub(1)
        } else {
            estimate
        }
    }

    /// [`Self::apply`] saturated into `i32`.
    #[must_use]
    pub fn apply_i32(&self, x: i32) -> i32 {
        saturate_i32(self.apply(x))
    }

    /// A magnitude (window, distance) through the factor, saturating.
    #[must_use]
    pub fn apply_u32(&self, x: u32) -> u32 {
        let x = i32::try_from(x).unwrap_or(i32::MAX);
        u32::try_from(self.apply(x).max(0)).unwrap_or(u32::MAX)
    }
}

fn saturate_i32(x: i64) -> i32 {
    i32::try_from(x).unwrap_or(if x < 0 { i32::MIN } else { i32::MAX })
}

/// The gear in effect: motor revolutions `numerator` per `denominator` load revolutions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Gear {
    /// Motor revolutions (0x3003:01).
    pub numerator: u32,
    /// Load revolutions (0x3003:02).
    pub denominator: u32,
    /// 0x3003:04 bit 0.
    pub inverted: bool,
    /// 0x3003:03, rpm at the motor; `u32::MAX` without a gear.
    pub max_input_speed: u32,
}

impl Default for Gear {
    fn default() -> Self {
        Self::NONE
    }
}

impl Gear {
    /// No gear.
    pub const NONE: Self = Self { numerator: 1, denominator: 1, inverted: false, max_input_speed: u32::MAX };

    /// The gear the dictionary puts in effect (module documentation).
    #[must_use]
    pub fn in_effect(d: &Dictionary) -> Self {
        if d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED == 0 {
            return Self::NONE;
        }
        Self {
            numerator: d.get(h::GEAR_REDUCTION_NUMERATOR).max(1),
            denominator: d.get(h::GEAR_REDUCTION_DENOMINATOR).max(1),
            inverted: d.get(h::GEAR_MISCELLANEOUS_CONFIGURATION) & GEAR_DIRECTION_INVERTED != 0,
            max_input_speed: d.get(h::MAX_GEAR_INPUT_SPEED),
        }
    }

    /// 0x3000:06 max system speed, load rpm (IDX L3898-3939): min(max motor speed, max gear input speed) over the
    /// reduction, rounded down so that the limit it states is never above the motor's.
    #[must_use]
    pub fn max_system_speed(&self, max_motor_speed: u32) -> u32 {
        let motor = u64::from(max_motor_speed.min(self.max_input_speed));
        let load = motor.saturating_mul(u64::from(self.denominator)).checked_div(u64::from(self.numerator));
        u32::try_from(load.unwrap_or(motor)).unwrap_or(u32::MAX)
    }
}

/// The conversion of the master's positions (polarity 0x607E and the gear) to the axis's motor increments and
/// back; velocities convert through the geared `MotionScale`, torques through [`Polarity::torque`] of
/// `torque_polarity`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct UserUnits {
    /// The signs of positions and velocities (0x607E combined with 0x3003:04 bit 0).
    pub polarity: Polarity,
    /// 0x607E alone: the sign of torques (bit 6, [`Polarity::torque`]).
    pub torque_polarity: Polarity,
    /// The gear in effect.
    pub gear: Gear,
    /// Load increments to motor increments: numerator / denominator.
    to_motor: Ratio,
    /// Motor increments to load increments: denominator / numerator.
    to_load: Ratio,
}

impl Default for UserUnits {
    fn default() -> Self {
        Self::NONE
    }
}

impl UserUnits {
    /// No polarity, no gear.
    pub const NONE: Self = Self {
        polarity: Polarity::NONE,
        torque_polarity: Polarity::NONE,
        gear: Gear::NONE,
        to_motor: Ratio::ONE,
        to_load: Ratio::ONE,
    };

    /// The units of `gear` with polarity `polarity_0x607e` (divides: when either changes).
    #[must_use]
    pub fn new(gear: &Gear, polarity_0x607e: u8) -> Self {
        let flip = if gear.inverted { Polarity::POSITION_BIT | Polarity::VELOCITY_BIT } else { 0 };
        Self {
            polarity: Polarity::from_0x607e(polarity_0x607e ^ flip),
            torque_polarity: Polarity::from_0x607e(polarity_0x607e),
            gear: *gear,
            to_motor: Ratio::new(gear.numerator, gear.denominator),
            to_load: Ratio::new(gear.denominator, gear.numerator),
        }
    }

    /// These units with the dual loop's main sensor (EPOS4 AN ch. 10, 0x3000:02 main sensor 2 on the gear output):
    /// the master's positions count the load encoder's increments (4 x 0x3020:01 per load revolution), as the
    /// position loop closes on them, instead of the motor encoder's resolution at the load, which would make one
    /// master increment several load increments (8 on geared-36v) and round every set-point to them. `scale` is
    /// motor increments per load increment ([`super::dual_loop::LoadScale`]); one whose terms do not fit 32 bits
    /// (beyond any catalogue encoder and gear) keeps the gear's units. Velocities stay load rpm. Divides: not for
    /// the slow tick.
    #[must_use]
    pub fn with_main_sensor(mut self, scale: Option<super::dual_loop::LoadScale>) -> Self {
        if let Some(s) = scale {
            if let (Ok(num), Ok(den)) = (u32::try_from(s.num), u32::try_from(s.den)) {
                self.to_motor = Ratio::new(num, den);
                self.to_load = Ratio::new(den, num);
            }
        }
        self
    }

    /// The units the dictionary sets now (divides: not for the slow tick).
    #[must_use]
    pub fn from_dictionary(d: &Dictionary) -> Self {
        Self::new(&Gear::in_effect(d), d.get(h::POLARITY))
    }

    /// A master position (0x607A, 0x60B0, 0x607C + 0x30B0, 0x607D) in the axis's motor increments, saturating.
    #[must_use]
    #[inline(never)]
    pub fn position_to_axis(&self, position: i32) -> i32 {
        self.to_motor.apply_i32(self.polarity.position(position))
    }

    /// An axis position (motor increments) as the master sees it (0x6064, 0x6062, 0x60F4, touch probes).
    #[must_use]
    #[inline(never)]
    pub fn position_to_master(&self, position: i32) -> i32 {
        self.polarity.position(self.to_load.apply_i32(position))
    }

    /// A master distance or window (0x6065, 0x6067, homing distances) in motor increments (no sign).
    #[must_use]
    #[inline(never)]
    pub fn distance_to_axis(&self, distance: u32) -> u32 {
        self.to_motor.apply_u32(distance)
    }

    /// A master signed distance without the polarity (homing moves keep the motor's direction, Gamma L1659).
    #[must_use]
    #[inline(never)]
    pub fn offset_to_axis(&self, distance: i32) -> i32 {
        self.to_motor.apply_i32(distance)
    }

    /// The software position limits 0x607D (min, max) in the axis's motor increments: mirrored by the position
    /// sign ([`Polarity::limits`], saturating), then through the gear (which keeps their order).
    #[must_use]
    #[inline(never)]
    pub fn limits_to_axis(&self, min: i32, max: i32) -> (i32, i32) {
        let (min, max) = self.polarity.limits(min, max);
        (self.to_motor.apply_i32(min), self.to_motor.apply_i32(max))
    }

    /// Whether the master's positions are the axis's (no gear, no inversion): the cheap path.
    #[must_use]
    pub fn positions_unchanged(&self) -> bool {
        self.to_motor.is_one() && !self.polarity.position_inverted()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// round(x p / q) half up, by the exact i128 division.
    fn reference(x: i32, p: u32, q: u32) -> i64 {
        let n = i128::from(x) * i128::from(p);
        let q = i128::from(q);
        i64::try_from((2 * n + q).div_euclid(2 * q)).unwrap()
    }

    /// The conversion is the exactly rounded x p / q for integer, inverse and non-integer ratios (359424/875, a
    /// ratio whose 32.32 fraction is not exact), over small, tie and extreme positions.
    #[test]
    fn ratio_is_exactly_rounded() {
        let ratios = [(5, 1), (1, 5), (359_424, 875), (875, 359_424), (3, 2), (2, 3), (7, 7), (u32::MAX, 3), (1, 1000)];
        let mut xs = vec![0, 1, -1, 2, -2, 3, 437, -437, 1_000_000, -999_999, i32::MAX, i32::MIN, i32::MAX - 1];
        xs.extend((0..2000).map(|i| i * 7919 - 8_000_000));
        for (p, q) in ratios {
            let r = Ratio::new(p, q);
            for &x in &xs {
                let want = reference(x, p, q);
                if u64::from(p) / u64::from(q) < 1 << 31 && want.unsigned_abs() < 1 << 62 {
                    assert_eq!(r.apply(x), want, "{x} * {p}/{q}");
                }
            }
        }
        // Ties round up: 1 * 3/2 = 1.5 -> 2, -1 * 3/2 = -1.5 -> -1.
        assert_eq!((Ratio::new(3, 2).apply(1), Ratio::new(3, 2).apply(-1)), (2, -1));
    }

    /// IDX L3898-3939: 0x3000:06 = min(0x6080, 0x3003:03) / reduction; without a gear the motor's limit.
    #[test]
    fn max_system_speed_is_the_limit_over_the_reduction() {
        let gear = Gear { numerator: 5, denominator: 1, inverted: false, max_input_speed: 4000 };
        assert_eq!(gear.max_system_speed(5000), 800);
        assert_eq!(gear.max_system_speed(3000), 600);
        assert_eq!(Gear::NONE.max_system_speed(5000), 5000);
    }

    /// 5:1 with polarity 0x80: load 100 <-> motor -500; the gear direction bit flips it back.
    #[test]
    fn positions_convert_through_gear_and_signs() {
        let gear = Gear { numerator: 5, denominator: 1, inverted: false, max_input_speed: 4000 };
        let u = UserUnits::new(&gear, 0x80);
        assert_eq!((u.position_to_axis(100), u.position_to_master(-500), u.position_to_master(-502)), (-500, 100, 100));
        let inverted = UserUnits::new(&Gear { inverted: true, ..gear }, 0x80);
        assert_eq!(inverted.position_to_axis(100), 500);
        assert_eq!(u.position_to_axis(i32::MAX), i32::MIN, "saturates, no wrap");
        assert_eq!(UserUnits::new(&gear, 0).position_to_axis(i32::MAX), i32::MAX);
    }

    /// EPOS4 AN ch. 10: in the dual loop the master's positions count the main sensor's, the load encoder's,
    /// increments. geared-36v: 5:1, 5,000 motor increments and 40,000 load increments per revolution, so 5 x 5,000
    /// / 40,000 = 5/8 motor increment per load increment: one load revolution (40,000) is 25,000 motor increments
    /// and back, a quarter turn (10,000) 6,250. Without the dual loop the same gear counts 5,000 per load
    /// revolution; a scale whose terms pass 32 bits keeps those units.
    #[test]
    fn the_dual_loops_main_sensor_sets_the_position_units() {
        use crate::motion::dual_loop::LoadScale;
        let gear = Gear { numerator: 5, ..Gear::NONE };
        let geared = UserUnits::new(&gear, 0);
        assert_eq!(geared.position_to_axis(5_000), 25_000);
        let scale = LoadScale::new((5, 1), 5_000, 40_000).expect("in range");
        let dual = geared.with_main_sensor(Some(scale));
        assert_eq!(dual.position_to_axis(40_000), 25_000);
        assert_eq!(dual.position_to_axis(10_000), 6_250);
        assert_eq!(dual.position_to_master(25_000), 40_000);
        assert_eq!(dual.position_to_master(-6_250), -10_000);
        assert_eq!(dual.distance_to_axis(8), 5);
        assert_eq!(geared.with_main_sensor(None), geared);
        let wide = LoadScale { num: 1 << 33, den: 3 };
        assert_eq!(geared.with_main_sensor(Some(wide)), geared);
    }
}
