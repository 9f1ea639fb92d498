//! Polarity 0x607E: the sign of the position, velocity and torque values the master exchanges with the drive.
//!
//! Bit layout and meaning after Glentek Gamma (L1656-1672: "indicates if the position demand value shall be
//! multiplied by 1 or by -1"; bit 7 position polarity, used in PPM and CSP; bit 6 velocity polarity, used in PVM
//! and CSV; "no influence on homing mode") and Nanotec PD4-E (p.250, L627: bit 7 POS, bit 6 VEL, direction
//! reversal in the modes of each). `shared/spec/cia402-device-control.md` §2 "Polarity".
//!
//! Where it acts: at the boundary between the dictionary and the axis, in tier 2. The axis, its loops, the
//! homing, the limit switches and tier 1 keep the motor's own direction (internal coordinates); only values read
//! from or written to the master's objects are multiplied by -1:
//! - bit 7 (positions): target position 0x607A (PPM, CSP), position offset 0x60B0 (CSP), home offset 0x607C and
//!   home position 0x30B0 (the reference a homing sets, so that 0x6064 reads them after homing; the homing moves
//!   themselves are not reversed: Gamma "no influence on homing"), software position limits 0x607D (min and max
//!   swap sides), and the actual values 0x6064, 0x6062, 0x60F4 and the touch-probe positions 0x60BA..0x60BD;
//! - bit 6 (velocities): target velocity 0x60FF (PVM, CSV) and the actual values 0x606C, 0x606B, 0x6069, 0x30D3:01;
//! - velocity offset 0x60B1 takes the bit of the cyclic mode it feeds: bit 7 in CSP (it is the position command's
//!   feed-forward: Gamma "the position polarity bit is used for ... cyclic synchronous position mode"), bit 6 in
//!   CSV;
//! - torques (0x6071 target torque, 0x60B2 torque offset, 0x6077 torque actual, 0x6074 torque demand) take bit 6,
//!   the velocity bit: a torque is the rate of change of the velocity it drives, so a master that inverts its
//!   velocities gets a positive target torque that accelerates in its positive velocity direction and reads the
//!   torque that does so as positive; 0x60B2 in CSP takes bit 7, as 0x60B1 does there (it is the position
//!   command's acceleration feed-forward), bit 6 in CSV and CST. Neither seed gives a torque bit; this rule keeps
//!   the three quantities of one master direction consistent (with 0x607E = 0xC0 every value reverses together).
//!
//! Not inverted: the internal values
//! 0x6063 and 0x60FC (motor increments; CiA 402 places the polarity beside the position factor, before the
//! internal units **[std, not in seeds]**), windows and speeds that are magnitudes (0x6065, 0x6067, 0x6081, 0x6099).
//! The gear direction 0x3003:04 bit 0 combines with bits 7 and 6 for positions and velocities
//! ([`super::gear`]), not for torques (they stay the motor's torque).
//!
//! Changing it: 0x607E is writable only with the power stage off (device.toml `power-disabled`), so the axis never
//! sees a set-point or actual value change sign under its feet; while disabled the demand follows the actual
//! position, so the next enable starts from where the motor is whatever the new sign.

/// The two signs of 0x607E.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Polarity {
    /// -1 when bit 7 (position polarity) is set, else 1.
    position: i32,
    /// -1 when bit 6 (velocity polarity) is set, else 1.
    velocity: i32,
}

impl Default for Polarity {
    fn default() -> Self {
        Self::NONE
    }
}

impl Polarity {
    /// 0x607E = 0: no inversion.
    pub const NONE: Self = Self { position: 1, velocity: 1 };
    /// Bit 7: position polarity.
    pub const POSITION_BIT: u8 = 0x80;
    /// Bit 6: velocity polarity.
    pub const VELOCITY_BIT: u8 = 0x40;

    /// The signs of a 0x607E value (the other bits are refused by the dictionary).
    #[must_use]
    pub const fn from_0x607e(value: u8) -> Self {
        Self {
            position: if value & Self::POSITION_BIT != 0 { -1 } else { 1 },
            velocity: if value & Self::VELOCITY_BIT != 0 { -1 } else { 1 },
        }
    }

    /// Whether the position values are inverted.
    #[must_use]
    pub const fn position_inverted(self) -> bool {
        self.position < 0
    }

    /// A position between the master's coordinates and the axis's (the map is its own inverse). Wrapping, as
    /// positions wrap (0x6064 is a modular count).
    #[must_use]
    pub const fn position(self, value: i32) -> i32 {
        value.wrapping_mul(self.position)
    }

    /// A velocity of the master's, rpm (0x60FF, 0x60B1), in the axis's direction, widened so that the sign
    /// change cannot overflow.
    #[must_use]
    pub fn velocity_rpm(self, rpm: i32) -> i64 {
        i64::from(rpm).wrapping_mul(i64::from(self.velocity))
    }

    /// A velocity offset 0x60B1, rpm, for the cyclic mode it feeds: the position bit in CSP, the velocity bit in
    /// CSV (module documentation).
    #[must_use]
    pub fn velocity_offset_rpm(self, rpm: i32, position_mode: bool) -> i64 {
        let sign = if position_mode { self.position } else { self.velocity };
        i64::from(rpm).wrapping_mul(i64::from(sign))
    }

    /// An actual or demand velocity of the axis, rpm or increments per second, as the master sees it
    /// (saturating: -i32::MIN does not exist).
    #[must_use]
    pub const fn shown_velocity(self, value: i32) -> i32 {
        value.saturating_mul(self.velocity)
    }

    /// A torque of the master's, per mille (0x6071, 0x60B2 in CSV/CST), in the motor's direction, or the
    /// motor's (0x6077, 0x6074) as the master sees it: bit 6 (module documentation); saturating.
    #[must_use]
    pub const fn torque(self, permille: i16) -> i16 {
        if self.velocity < 0 {
            permille.saturating_neg()
        } else {
            permille
        }
    }

    /// A torque offset 0x60B2 for the cyclic mode it feeds: bit 7 in CSP (as 0x60B1), bit 6 otherwise.
    #[must_use]
    pub const fn torque_offset(self, permille: i16, position_mode: bool) -> i16 {
        let sign = if position_mode { self.position } else { self.velocity };
        if sign < 0 {
            permille.saturating_neg()
        } else {
            permille
        }
    }

    /// The software position limits 0x607D (min, max) in the axis's coordinates: with the position inverted the
    /// range mirrors, [-max, -min] (saturating at the ends of the range).
    #[must_use]
    pub const fn limits(self, min: i32, max: i32) -> (i32, i32) {
        if self.position_inverted() {
            (max.saturating_neg(), min.saturating_neg())
        } else {
            (min, max)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Gamma Table 9-2: bit 6 or 7 = 1 means "multiply by -1", 0 "multiply by 1"; the bits are independent.
    #[test]
    fn each_bit_inverts_its_own_quantity() {
        let none = Polarity::from_0x607e(0x00);
        assert_eq!((none.position(1000), none.velocity_rpm(300)), (1000, 300));
        let pos = Polarity::from_0x607e(0x80);
        assert_eq!((pos.position(1000), pos.velocity_rpm(300)), (-1000, 300));
        let vel = Polarity::from_0x607e(0x40);
        assert_eq!((vel.position(1000), vel.velocity_rpm(300), vel.shown_velocity(-7)), (1000, -300, 7));
        let both = Polarity::from_0x607e(0xC0);
        assert_eq!((both.position(-5), both.velocity_rpm(-300)), (5, 300));
    }

    /// The velocity offset takes the bit of the mode it feeds (CSP: bit 7, CSV: bit 6).
    #[test]
    fn velocity_offset_follows_the_mode_bit() {
        let pos = Polarity::from_0x607e(0x80);
        assert_eq!((pos.velocity_offset_rpm(50, true), pos.velocity_offset_rpm(50, false)), (-50, 50));
        let vel = Polarity::from_0x607e(0x40);
        assert_eq!((vel.velocity_offset_rpm(50, true), vel.velocity_offset_rpm(50, false)), (50, -50));
    }

    /// Torques take bit 6 (0x6071, 0x6077), the torque offset bit 7 in CSP; -i16::MIN saturates.
    #[test]
    fn torques_follow_the_velocity_bit() {
        let vel = Polarity::from_0x607e(0x40);
        assert_eq!((vel.torque(300), vel.torque_offset(50, true), vel.torque_offset(50, false)), (-300, 50, -50));
        let pos = Polarity::from_0x607e(0x80);
        assert_eq!((pos.torque(300), pos.torque_offset(50, true), pos.torque_offset(50, false)), (300, -50, 50));
        assert_eq!(Polarity::from_0x607e(0xC0).torque(i16::MIN), i16::MAX);
    }

    /// Edges: i32::MIN has no negation (velocity saturates to i32::MAX; positions wrap as the count does; the
    /// widened master velocity is exact), and the limits mirror and swap.
    #[test]
    fn extremes_saturate_or_wrap_and_limits_mirror() {
        let both = Polarity::from_0x607e(0xC0);
        assert_eq!(both.shown_velocity(i32::MIN), i32::MAX);
        assert_eq!(both.position(i32::MIN), i32::MIN);
        assert_eq!(both.velocity_rpm(i32::MIN), 2_147_483_648);
        assert_eq!(both.limits(-1000, 5000), (-5000, 1000));
        assert_eq!(both.limits(i32::MIN, 0), (0, i32::MAX));
        assert_eq!(Polarity::NONE.limits(-1000, 5000), (-1000, 5000));
    }
}
