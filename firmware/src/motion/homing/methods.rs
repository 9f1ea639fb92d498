//! The homing method catalogue as data: for each 0x6098 value, which signal defines the reference, on which side
//! of its edge a switch is active, the direction of the final approach, and whether the index pulse is used.
//!
//! Sources: the CiA 402 definitions as the seeds give them — Glentek Gamma §7.3 (GT L1097-1240: methods 1-14,
//! 17-30, 33-35), Nanotec PD4-E p.62-68 (NT L251-263: the left switching edge for 3/4 and 19/20, the right one for
//! 5/6 and 21/22, 7-10 with the positive and 11-14 with the negative limit switch), maxon EPOS3 §5.5.3 (E3
//! L1848-2035: the sequences of 1, 2, 7, 11, 17, 18, 23, 27, 33, 34, 35, 37, -1..-4) and IDX §3.5.3 (IDX L859-930:
//! 17, 18, 23, 27, 37, -3, -4); digest `shared/spec/cia402-device-control.md` §3.3.
//!
//! # The reference of each method (CiA 402 figures)
//! Every switch method is described by one edge `E` of one switch and the *approach direction* `F`: the home
//! reference is `E` crossed while moving in `F` (edge methods 17-30), or the first index pulse met moving in `F`
//! after that crossing (index methods 1-14). For a home switch active over a band (7-14, 23-30) the band has a
//! lower (negative) and an upper (positive) edge:
//!
//! | methods | switch (active where) | edge `E` | `F` (index side of `E`) | search starts |
//! |---|---|---|---|---|
//! | 1 / 17 | negative limit (below `E`) | the limit's edge | positive (right) | negative unless on the switch |
//! | 2 / 18 | positive limit (above `E`) | the limit's edge | negative (left) | positive unless on the switch |
//! | 3 / 19 | home switch, positive half axis | its (left) edge | negative (left) | toward the edge (switch state) |
//! | 4 / 20 | home switch, positive half axis | its (left) edge | positive (right) | toward the edge |
//! | 5 / 21 | home switch, negative half axis | its (right) edge | positive (right) | toward the edge |
//! | 6 / 22 | home switch, negative half axis | its (right) edge | negative (left) | toward the edge |
//! | 7 / 23 | home band, positive limit | lower | negative (left) | positive, reverse at the limit |
//! | 8 / 24 | home band, positive limit | lower | positive (right) | positive, reverse at the limit |
//! | 9 / 25 | home band, positive limit | upper | negative (left) | positive, reverse at the limit |
//! | 10 / 26 | home band, positive limit | upper | positive (right) | positive, reverse at the limit |
//! | 11 / 27 | home band, negative limit | upper | positive (right) | negative, reverse at the limit |
//! | 12 / 28 | home band, negative limit | upper | negative (left) | negative, reverse at the limit |
//! | 13 / 29 | home band, negative limit | lower | positive (right) | negative, reverse at the limit |
//! | 14 / 30 | home band, negative limit | lower | negative (left) | negative, reverse at the limit |
//!
//! 7-14 (GT L1140-1166): "the initial direction of movement is to the right [7-10] / to the left [11-14] except if
//! the home switch is active at the start of the motion. In such case, the initial direction of motion depends on
//! the edge of interest"; "the drive should reverse on encountering the relevant limit switch". 17-30 "are similar
//! to methods 1 through 14 except that the home position is ... only dependent on the relevant home or limit switch
//! transitions" (GT L1170-1224). With these tables, maxon's descriptions agree: 23 and 27 reference the *falling*
//! edge of the home switch (E3 L1945-1950: 23 leaves the band at its lower edge moving negative, 27 at its upper
//! edge moving positive), and 26 references the right edge (NT p.67 L261).
//!
//! Methods 33 / 34: the next index pulse moving negative / positive (GT L1228-1236, E3 L1952-1971). 35 / 37: the
//! actual position (GT L1238-1240, E3 L1973-1977, IDX L905-910). -1..-4: a mechanical end stop found by the
//! averaged current exceeding 0x30B2, positive for -1/-3, negative for -2/-4; -1/-2 continue to the next index
//! pulse, away from the stop (E3 L1979-2035, IDX L912-930).

/// A direction of motion along the axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Toward negative positions (left in the CiA 402 figures).
    Negative,
    /// Toward positive positions (right).
    Positive,
}

impl Direction {
    /// The opposite direction.
    #[must_use]
    pub const fn reverse(self) -> Self {
        match self {
            Self::Negative => Self::Positive,
            Self::Positive => Self::Negative,
        }
    }
}

/// A switch input function of [`super::super::AxisFeedback`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Switch {
    /// Negative limit switch.
    NegativeLimit,
    /// Positive limit switch.
    PositiveLimit,
    /// Home switch.
    Home,
}

/// How the referenced switch is laid out along the axis (the CiA 402 figures).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Layout {
    /// A limit switch, active from its edge to the end of travel (1, 2, 17, 18). The other limit switch must not
    /// be reached: no reversal.
    Limit,
    /// A home switch active over the half axis on one side of its only edge (3-6, 19-22); its state tells on which
    /// side of the edge the axis is, so no reversal is ever needed.
    HalfAxis,
    /// A home switch active over a band with two edges (7-14, 23-30). When the switch is inactive at the start,
    /// the search begins in `initial`; it reverses once at the limit switch ahead.
    Band {
        /// The first direction when the switch is inactive at the start.
        initial: Direction,
    },
}

/// What defines the home reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reference {
    /// An edge of a switch (methods 1-14, 17-30).
    SwitchEdge {
        /// The switch.
        switch: Switch,
        /// Its layout.
        layout: Layout,
        /// The side of the edge on which the switch is active (for a band: positive for its lower edge, negative
        /// for its upper edge).
        active_side: Direction,
    },
    /// The next index pulse in the approach direction (33, 34).
    Index,
    /// A mechanical end stop in direction `toward`, found by the current threshold (-1..-4).
    EndStop {
        /// Where the stop is.
        toward: Direction,
    },
    /// The actual position, no motion (35, 37).
    ActualPosition,
}

/// One homing method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Method {
    /// The 0x6098 value.
    pub number: i8,
    /// The signal that defines the reference.
    pub reference: Reference,
    /// The approach direction `F`: the switch edge is referenced when crossed moving in `F`, and the index is the
    /// first one met moving in `F` after it; for 33/34 the search direction, for -1/-2 away from the stop.
    pub approach: Direction,
    /// The reference is the index pulse found after the switch edge or end stop (1-14, 33, 34, -1, -2).
    pub index: bool,
}

/// 0x60E3 Supported homing methods, in the order of `firmware/device.toml` (and 0x6098's value list).
pub const SUPPORTED_METHODS: [i8; 36] = [
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 33, 34, 35,
    37, -1, -2, -3, -4,
];

use Direction::{Negative as NEG, Positive as POS};

const fn limit(number: i8, switch: Switch, active_side: Direction, index: bool) -> Method {
    Method {
        number,
        reference: Reference::SwitchEdge { switch, layout: Layout::Limit, active_side },
        approach: active_side.reverse(),
        index,
    }
}

const fn half(number: i8, active_side: Direction, approach: Direction, index: bool) -> Method {
    Method {
        number,
        reference: Reference::SwitchEdge { switch: Switch::Home, layout: Layout::HalfAxis, active_side },
        approach,
        index,
    }
}

/// `lower`: the band's lower edge (active above it) is the reference, else its upper edge.
const fn band(number: i8, initial: Direction, lower: bool, approach: Direction, index: bool) -> Method {
    let active_side = if lower { POS } else { NEG };
    Method {
        number,
        reference: Reference::SwitchEdge { switch: Switch::Home, layout: Layout::Band { initial }, active_side },
        approach,
        index,
    }
}

const fn end_stop(number: i8, toward: Direction, index: bool) -> Method {
    Method { number, reference: Reference::EndStop { toward }, approach: toward.reverse(), index }
}

const fn next_index(number: i8, approach: Direction) -> Method {
    Method { number, reference: Reference::Index, approach, index: true }
}

const fn here(number: i8) -> Method {
    Method { number, reference: Reference::ActualPosition, approach: POS, index: false }
}

/// The catalogue, in the order of [`SUPPORTED_METHODS`].
pub const METHODS: [Method; 36] = [
    limit(1, Switch::NegativeLimit, NEG, true),
    limit(2, Switch::PositiveLimit, POS, true),
    half(3, POS, NEG, true),
    half(4, POS, POS, true),
    half(5, NEG, POS, true),
    half(6, NEG, NEG, true),
    band(7, POS, true, NEG, true),
    band(8, POS, true, POS, true),
    band(9, POS, false, NEG, true),
    band(10, POS, false, POS, true),
    band(11, NEG, false, POS, true),
    band(12, NEG, false, NEG, true),
    band(13, NEG, true, POS, true),
    band(14, NEG, true, NEG, true),
    limit(17, Switch::NegativeLimit, NEG, false),
    limit(18, Switch::PositiveLimit, POS, false),
    half(19, POS, NEG, false),
    half(20, POS, POS, false),
    half(21, NEG, POS, false),
    half(22, NEG, NEG, false),
    band(23, POS, true, NEG, false),
    band(24, POS, true, POS, false),
    band(25, POS, false, NEG, false),
    band(26, POS, false, POS, false),
    band(27, NEG, false, POS, false),
    band(28, NEG, false, NEG, false),
    band(29, NEG, true, POS, false),
    band(30, NEG, true, NEG, false),
    next_index(33, NEG),
    next_index(34, POS),
    here(35),
    here(37),
    end_stop(-1, POS, true),
    end_stop(-2, NEG, true),
    end_stop(-3, POS, false),
    end_stop(-4, NEG, false),
];

/// The method with 0x6098 value `number`, `None` for an unsupported one (0, 15, 16, 31, 32, 36, ...).
#[must_use]
pub fn method(number: i8) -> Option<Method> {
    METHODS.iter().find(|m| m.number == number).copied()
}
