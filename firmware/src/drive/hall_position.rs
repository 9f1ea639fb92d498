//! Position from the Hall sensors alone: one increment per Hall state change, `6 x pole pairs` increments per
//! revolution (42 on the reference motor), as EPOS4 counts them when the Halls are the main sensor (S1 Hall
//! example L1433-1455). Used by tier 2 when 0x3000:01 configures no encoder.
//!
//! Tier 1 feeds every sample; a change to the next sector counts +1, to the previous one -1, anything else (two
//! sectors in one 40 us period, i.e. above 23,800 rpm on the reference motor, or an invalid state) is not
//! counted: an invalid state is the commutation's fault, and the next valid state resynchronises the count.

use crate::sensors::hall::HallSector;

/// The Hall position counter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HallPosition {
    last: Option<HallSector>,
    last_state: u8,
    position: i32,
}

impl HallPosition {
    /// One sample of the Hall state (after inversion, bit 0 = H1).
    #[inline(always)]
    pub fn update(&mut self, hall: u8) {
        if hall != self.last_state {
            self.step(hall);
        }
    }

    #[cold]
    fn step(&mut self, hall: u8) {
        self.last_state = hall;
        let Ok(sector) = HallSector::from_state(hall) else { return };
        if let Some(last) = self.last {
            if sector == last.next() {
                self.position = self.position.wrapping_add(1);
            } else if sector == last.previous() {
                self.position = self.position.wrapping_sub(1);
            }
        }
        self.last = Some(sector);
    }

    /// Hall increments since start-up (wrapping).
    #[must_use]
    pub const fn position(&self) -> i32 {
        self.position
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Hall sequence in the forward direction (bit 0 = H1), one electrical turn.
    const FORWARD: [u8; 6] = [0b001, 0b011, 0b010, 0b110, 0b100, 0b101];

    #[test]
    fn counts_each_state_change_with_its_direction() {
        let mut h = HallPosition::default();
        for turn in 0..3 {
            for &s in &FORWARD {
                h.update(s);
                h.update(s);
            }
            assert_eq!(h.position(), 6 * turn + 5);
        }
        for &s in FORWARD.iter().rev() {
            h.update(s);
        }
        assert_eq!(h.position(), 17 - 5);
    }

    #[test]
    fn invalid_states_and_jumps_do_not_count() {
        let mut h = HallPosition::default();
        h.update(FORWARD[0]);
        h.update(0b000);
        h.update(0b111);
        assert_eq!(h.position(), 0);
        h.update(FORWARD[2]);
        assert_eq!(h.position(), 0, "two sectors at once: not counted");
        h.update(FORWARD[3]);
        assert_eq!(h.position(), 1);
    }
}
