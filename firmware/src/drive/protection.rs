//! The tier-1 protection step: checks that must act within the same 25 kHz period, before any output is computed.
//!
//! Today: the hardware break input (the over-current comparator of the reference power stage, which has already
//! disabled the outputs in hardware, `hal::power::Measurements::break_input`) latches a trip and the drive answers
//! with `PwmCommand::OFF` (which also acknowledges the break latch, `hal::power`). The fault issue adds its tier-1
//! checks here (software over-current on the calibrated phase currents, bus over/under-voltage): each is one
//! [`Trip`] variant and one comparison in [`check`], and `Drive::fast_tick` turns any trip into the fault state.

use crate::hal::power::Measurements;

/// A condition that switches the power stage off within the same period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trip {
    /// The hardware break input (over-current comparator) tripped.
    BreakInput,
}

/// The tier-1 protection checks on the raw measurements; `Some` when the outputs must go off now.
#[inline(always)]
#[must_use]
pub fn check(m: &Measurements) -> Option<Trip> {
    if m.break_input {
        return Some(Trip::BreakInput);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn break_input_trips() {
        assert_eq!(check(&Measurements::default()), None);
        assert_eq!(check(&Measurements { break_input: true, ..Measurements::default() }), Some(Trip::BreakInput));
    }
}
