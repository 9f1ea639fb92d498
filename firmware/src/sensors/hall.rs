//! The six Hall sectors of a turn of the rotor's electrical angle, in the order the three Hall sensors step through
//! them moving forward (the sequence and the angle convention are described with the commutation,
//! `crate::drive::commutation`).

use crate::control::angle::ElectricalAngle;
use crate::power_state::CommutationError;

/// One sixth of a turn in `u32` turn bits (60 degrees), rounded: 2^32 / 6 = 715,827,882.67.
pub(crate) const SIXTH_TURN: u32 = 715_827_883;
/// The Hall states in sector order 0..=5.
pub(crate) const HALL_SEQUENCE: [u8; 6] = [0b101, 0b001, 0b011, 0b010, 0b110, 0b100];

/// One of the six 60-degree Hall sectors, 0..=5 (sector 0 is the Hall state 0b101).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HallSector(u8);

impl HallSector {
    /// The sector of a Hall state (bit 0 = H1, bit 1 = H2, bit 2 = H3).
    pub const fn from_state(state: u8) -> Result<Self, CommutationError> {
        match state {
            0b101 => Ok(Self(0)),
            0b001 => Ok(Self(1)),
            0b011 => Ok(Self(2)),
            0b010 => Ok(Self(3)),
            0b110 => Ok(Self(4)),
            0b100 => Ok(Self(5)),
            other => Err(CommutationError::InvalidHallState(other)),
        }
    }

    /// The sector number 0..=5.
    #[must_use]
    pub const fn index(self) -> u8 {
        self.0
    }

    /// The Hall state of this sector.
    #[must_use]
    pub fn state(self) -> u8 {
        HALL_SEQUENCE.get(usize::from(self.0)).copied().unwrap_or(0)
    }

    /// The sector's lower edge (where it is entered moving forward), relative to the Hall offset.
    #[must_use]
    pub const fn start_angle(self, hall_offset: ElectricalAngle) -> ElectricalAngle {
        // index <= 5: 5 * SIXTH_TURN < 2^32.
        ElectricalAngle((self.0 as u32).wrapping_mul(SIXTH_TURN).wrapping_add(hall_offset.0))
    }

    /// The sector's centre (the best guess within it), relative to the Hall offset.
    #[must_use]
    pub const fn centre_angle(self, hall_offset: ElectricalAngle) -> ElectricalAngle {
        ElectricalAngle(self.start_angle(hall_offset).0.wrapping_add(SIXTH_TURN / 2))
    }

    /// The next sector in the positive direction.
    #[must_use]
    pub const fn next(self) -> Self {
        // self.0 <= 4 in the else branch: no wrap.
        Self(if self.0 >= 5 { 0 } else { self.0.wrapping_add(1) })
    }

    /// The next sector in the negative direction.
    #[must_use]
    pub const fn previous(self) -> Self {
        // self.0 >= 1 in the else branch: no wrap.
        Self(if self.0 == 0 { 5 } else { self.0.wrapping_sub(1) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEG: f64 = 4_294_967_296.0 / 360.0;

    fn deg(a: ElectricalAngle) -> f64 {
        f64::from(a.0) / DEG
    }

    #[test]
    fn hall_sector_mapping_covers_every_state() {
        let expected: [(u8, Result<u8, CommutationError>); 8] = [
            (0, Err(CommutationError::InvalidHallState(0))),
            (1, Ok(1)),
            (2, Ok(3)),
            (3, Ok(2)),
            (4, Ok(5)),
            (5, Ok(0)),
            (6, Ok(4)),
            (7, Err(CommutationError::InvalidHallState(7))),
        ];
        for (state, want) in expected {
            assert_eq!(HallSector::from_state(state).map(HallSector::index), want, "state {state}");
        }
        assert_eq!(HallSector::from_state(9), Err(CommutationError::InvalidHallState(9)));
        // Centres at 30 + 60 k degrees, edges at 60 k; the offset shifts them.
        for k in 0..6u8 {
            let s = HallSector(k);
            assert_eq!(HallSector::from_state(s.state()), Ok(s));
            assert!((deg(s.centre_angle(ElectricalAngle::ZERO)) - (30.0 + 60.0 * f64::from(k))).abs() < 1e-6);
            assert!((deg(s.start_angle(ElectricalAngle::ZERO)) - 60.0 * f64::from(k)).abs() < 1e-6);
            let shifted = s.centre_angle(ElectricalAngle(0x4000 << 16));
            assert!((deg(shifted) - (120.0 + 60.0 * f64::from(k)).rem_euclid(360.0)).abs() < 1e-6);
        }
        assert_eq!(HallSector(5).next(), HallSector(0));
        assert_eq!(HallSector(0).previous(), HallSector(5));
    }
}
