//! The dual loop's configuration and its main sensor (EPOS4 AN ch. 10; `shared/spec/control-and-protection.md`
//! §1.7): the load encoder (sensor 2, 0x3020) on the gear output closes the position loop, the motor encoder
//! (sensor 1) the velocity loop and the commutation.
//!
//! # Configuration (0x3000:01/:02, IDX L3791-3850)
//! The dual loop is on when 0x3000:02 names sensor 2 as main sensor (bits 19..16 = 2) mounted on the gear output
//! (bits 27..26 = 1). It needs sensor 2 to be the digital incremental encoder 2 (0x3000:01 bits 15..8 = 2) and a
//! gear scaling factor `GearRatio x aux resolution / main resolution` within 2^-11..2^15 (EPOS3 L6343: outside
//! it EPOS3 reports the gear scaling factor error 0xFF0F, L1134). Here the combination is checked when it is
//! written: a write that would leave it invalid is refused with 0x0604_0043 and changes nothing
//! (`Drive::sdo_write`), so a configuration in force is always valid ([`configuration`]).
//!
//! # Load position in motor increments
//! The process values stay at the motor (0x3000:02 bits 15..14 = 0): the load encoder's count is converted to
//! motor increments through the gear ratio, `motor = load x num / den` with `num = gear numerator x 0x3000:05` and
//! `den = gear denominator x 4 x 0x3020:01`, exactly (the remainder of the division is carried from one slow tick
//! to the next, so no increment is lost however long the axis turns). The position starts at the motor
//! encoder's when the dual loop takes over, so the position actual value does not jump.

use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// 0x3000:02 bits 19..16 main sensor = 2 and bits 27..26 mounting position of sensor 2 = 1 (gear output).
const DUAL_LOOP_STRUCTURE_MASK: u32 = (0xF << 16) | (0b11 << 26);
const DUAL_LOOP_STRUCTURE: u32 = (2 << 16) | (1 << 26);
/// 0x3000:01 bits 15..8: sensor 2 = digital incremental encoder 2.
const SENSOR_2_MASK: u32 = 0xFF << 8;
const SENSOR_2_INCREMENTAL: u32 = 2 << 8;
/// The gear scaling factor's range, 2^-11..2^15 (EPOS3 L6343).
const FACTOR_MIN_SHIFT: u32 = 11;
const FACTOR_MAX_SHIFT: u32 = 15;
/// The largest load-encoder change taken in one slow tick (2^24 increments in 0.4 ms is beyond any encoder).
const DELTA_LIMIT: i32 = 1 << 24;

/// Why a dual-loop configuration is refused (0x0604_0043).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DualLoopError {
    /// 0x3000:02 selects sensor 2 as main sensor, but 0x3000:01 has no load encoder as sensor 2.
    NoLoadEncoder,
    /// The gear scaling factor lies outside 2^-11..2^15 (EPOS3's 0xFF0F).
    ScalingFactor,
}

/// The gear reduction, motor revolutions per load revolution, as 0x3003:01 / 0x3003:02 (IDX L4075). The one place
/// the dual loop reads the gear ratio.
#[must_use]
pub fn gear_ratio(d: &Dictionary) -> (u32, u32) {
    (d.get(h::GEAR_REDUCTION_NUMERATOR).max(1), d.get(h::GEAR_REDUCTION_DENOMINATOR).max(1))
}

/// Motor increments per load-encoder increment as the reduced fraction `num / den`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct LoadScale {
    /// Gear numerator x motor increments per revolution (reduced), 1..2^38.
    pub num: i64,
    /// Gear denominator x load increments per revolution (reduced), 1..2^46.
    pub den: i64,
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        let r = a.checked_rem(b).unwrap_or(0);
        a = b;
        b = r;
    }
    a
}

impl LoadScale {
    /// The scale for a gear `ratio`, `motor_resolution` increments per motor revolution (0x3000:05) and
    /// `load_resolution` increments per load revolution (4 x 0x3020:01), checked against the gear scaling factor's
    /// range.
    pub fn new(ratio: (u32, u32), motor_resolution: u32, load_resolution: u32) -> Result<Self, DualLoopError> {
        let num = u64::from(ratio.0).saturating_mul(u64::from(motor_resolution.max(1)));
        let den = u64::from(ratio.1).saturating_mul(u64::from(load_resolution.max(1)));
        // 2^-11 <= num / den <= 2^15 (both are products of two u32: below 2^64 / 2^15, the shifts exact).
        if num.saturating_mul(1 << FACTOR_MIN_SHIFT) < den || num > den.saturating_mul(1 << FACTOR_MAX_SHIFT) {
            return Err(DualLoopError::ScalingFactor);
        }
        let g = gcd(num, den).max(1);
        let (num, den) = (num.checked_div(g).unwrap_or(num), den.checked_div(g).unwrap_or(den));
        // The carry's product (|delta| <= 2^24) stays within i64 for num below 2^38, the fraction's (remainder
        // 2^16) for den below 2^46.
        match (i64::try_from(num), i64::try_from(den)) {
            (Ok(num), Ok(den)) if num < 1 << 38 && den < 1 << 46 => Ok(Self { num, den }),
            _ => Err(DualLoopError::ScalingFactor),
        }
    }
}

/// The dual loop in force for the dictionary `d`: `Ok(None)` when 0x3000:02 does not select it, the load scale
/// when it does and the configuration is complete, the reason otherwise.
#[inline(never)]
pub fn configuration(d: &Dictionary) -> Result<Option<LoadScale>, DualLoopError> {
    if d.get(h::CONTROL_STRUCTURE) & DUAL_LOOP_STRUCTURE_MASK != DUAL_LOOP_STRUCTURE {
        return Ok(None);
    }
    if d.get(h::SENSORS_CONFIGURATION) & SENSOR_2_MASK != SENSOR_2_INCREMENTAL {
        return Err(DualLoopError::NoLoadEncoder);
    }
    let load_resolution = d.get(h::LOAD_ENCODER_PULSES).saturating_mul(4);
    LoadScale::new(gear_ratio(d), d.get(h::MAIN_SENSOR_RESOLUTION), load_resolution).map(Some)
}

/// The load position in motor increments, from the load encoder's count.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct LoadFeedback {
    scale: LoadScale,
    last_count: u32,
    /// The remainder of the conversion, in 1/den motor increments (0..den).
    remainder: i64,
    position: i32,
    started: bool,
}

impl LoadFeedback {
    /// A conversion with `scale` that starts at the next [`Self::update`].
    #[must_use]
    pub const fn new(scale: LoadScale) -> Self {
        Self { scale, last_count: 0, remainder: 0, position: 0, started: false }
    }

    /// The scale.
    #[must_use]
    pub const fn scale(&self) -> LoadScale {
        self.scale
    }

    /// The fraction of a motor increment beyond the last [`Self::update`]'s position, `U0F16` (remainder / den).
    #[must_use]
    pub fn fraction(&self) -> u16 {
        // 0 <= remainder < den < 2^46: the shifted remainder fits, the quotient is below 2^16.
        let q = (self.remainder << 16).checked_div(self.scale.den).unwrap_or(0);
        u16::try_from(q).unwrap_or(0)
    }

    /// The load position (motor increments) at the load encoder's `count` (wrapping, any width up to 32 bits read
    /// as u32); the first call starts it at `motor_position`.
    pub fn update(&mut self, count: u32, motor_position: i32) -> i32 {
        if !self.started {
            self.started = true;
            self.last_count = count;
            self.remainder = 0;
            self.position = motor_position;
            return motor_position;
        }
        // `as`: the wrapping difference of two counts read as a signed step.
        let delta = (count.wrapping_sub(self.last_count) as i32).clamp(-DELTA_LIMIT, DELTA_LIMIT);
        self.last_count = count;
        let LoadScale { num, den } = self.scale;
        // |delta num| < 2^62 and 0 <= remainder < den < 2^46: no overflow.
        let total = self.remainder.wrapping_add(i64::from(delta).wrapping_mul(num));
        // The floor of total / den, and the remainder total - steps den in 0..den (den > 0).
        let mut steps = total.checked_div(den).unwrap_or(0);
        let mut remainder = total.wrapping_sub(steps.wrapping_mul(den));
        if remainder < 0 {
            steps = steps.wrapping_sub(1);
            remainder = remainder.wrapping_add(den);
        }
        self.remainder = remainder;
        // |steps| <= 2^24 x 2^15: an i32 step, added wrapping like every position.
        self.position = self.position.wrapping_add(i32::try_from(steps).unwrap_or(0));
        self.position
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// EPOS3 L6343: the factor must lie in 2^-11..2^15. 5:1 with 4096 motor and 20,000 load increments is 1.024
    /// (20,480 / 20,000, reduced 128 / 125); 1 / 2048 is the lowest allowed, 1 / 2049 refused; 2^15 the highest.
    #[test]
    fn scaling_factor_range_is_checked() {
        assert_eq!(LoadScale::new((5, 1), 4096, 20_000), Ok(LoadScale { num: 128, den: 125 }));
        assert_eq!(LoadScale::new((1, 1), 1, 2048), Ok(LoadScale { num: 1, den: 2048 }));
        assert_eq!(LoadScale::new((1, 1), 1, 2049), Err(DualLoopError::ScalingFactor));
        assert_eq!(LoadScale::new((32_768, 1), 64, 64), Ok(LoadScale { num: 32_768, den: 1 }));
        assert_eq!(LoadScale::new((32_769, 1), 64, 64), Err(DualLoopError::ScalingFactor));
    }

    /// The conversion is exact over any distance: 125 load increments are 128 motor increments, one at a time or
    /// all at once, and back; it starts at the motor position and follows the 32-bit counter's wrap.
    #[test]
    fn load_counts_become_motor_increments_exactly() {
        let scale = LoadScale::new((5, 1), 4096, 20_000).unwrap();
        let mut f = LoadFeedback::new(scale);
        assert_eq!(f.update(u32::MAX - 10, 1_000), 1_000, "starts at the motor position");
        let mut count = u32::MAX - 10;
        for _ in 0..125 {
            count = count.wrapping_add(1);
            f.update(count, 0);
        }
        assert_eq!(f.update(count, 0), 1_128);
        assert_eq!(f.update(count.wrapping_add(125 * 1000), 0), 1_128 + 128 * 1000);
        assert_eq!(f.update(count, 0), 1_128);
        // One load increment: 1.024 motor increments, the fraction carried (1, then 2 after two, ...).
        assert_eq!(f.update(count.wrapping_add(1), 0), 1_129);
        assert_eq!(f.fraction(), 1_572, "0.024 = 3 / 125 of an increment: 1,572.864 / 2^16");
        assert_eq!(f.update(count.wrapping_sub(1), 0), 1_126, "-1 load inc: floor of 1128 - 1.024");
    }

    /// A configuration selecting the load encoder as main sensor needs it in 0x3000:01 (0x0604_0043 otherwise).
    #[test]
    fn configuration_needs_the_load_encoder() {
        let mut d = Dictionary::new(1);
        assert_eq!(configuration(&d), Ok(None), "the default: the motor encoder closes the position loop");
        d.set(h::CONTROL_STRUCTURE, 0x0402_1111);
        assert_eq!(configuration(&d), Err(DualLoopError::NoLoadEncoder));
        d.set(h::SENSORS_CONFIGURATION, 0x0004_0201);
        d.set(h::GEAR_REDUCTION_NUMERATOR, 5);
        d.set(h::LOAD_ENCODER_PULSES, 5_000);
        assert_eq!(configuration(&d), Ok(Some(LoadScale { num: 128, den: 125 })));
    }
}
