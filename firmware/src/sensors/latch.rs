//! Position latches of tier 1: the encoder position at each edge of the digital inputs and at the encoder index,
//! for homing (switch and index edges) and the touch probe (0x60B8..0x60BD).
//!
//! The inputs are sampled once per PWM period with the encoder count, so an input edge is placed within 40 us:
//! at the homing zero-search speed (0x6099:02, default 10 rpm = 0.03 inc per period at 4096 inc/rev) that is
//! exact to the increment. The index is captured by the encoder timer in hardware (TIM4 CCR3), so its position
//! is exact at any speed. The positions are raw encoder positions ([`crate::drive::encoder::Encoder::position`]);
//! tier 2 moves them into the coordinates of 0x6064.
//!
//! Cost in tier 1: one compare when nothing changed; the latching itself is a cold path.

/// One captured edge of a position-latching signal (a digital input or the encoder index).
///
/// The fast tick records the encoder position at the edge (an input is sampled every 40 us, the index is latched
/// by the encoder timer in hardware). `count` increments with every edge (wrapping), so a mode sees a new edge as
/// a changed count and never misses one between two slow ticks (only the latest position of a burst is kept).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct EdgeLatch {
    /// Edges seen since start-up (wrapping).
    pub count: u16,
    /// Position actual value (increments, the coordinates of [`crate::motion::AxisFeedback::position`]) at the
    /// latest edge.
    pub position: i32,
}

/// A switch function (limit or home switch) with its level and its latched edges, polarity already applied:
/// "activated" is the edge into the active level, whatever the wiring.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct SwitchEdges {
    /// The switch is active now.
    pub active: bool,
    /// The latest edge into the active level.
    pub activated: EdgeLatch,
    /// The latest edge out of the active level.
    pub released: EdgeLatch,
}

/// Number of digital inputs (0x3141, 0x3142: inputs 1..4).
pub const DIGITAL_INPUTS: usize = 4;

/// Edges of the wired input levels and of the index, with the raw encoder position at each.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PinLatches {
    /// Levels as wired at the last sample: bit n = input n+1 (0xFF before the first sample).
    pub levels: u8,
    /// The latest low-to-high edge of each input (as wired).
    pub rising: [EdgeLatch; DIGITAL_INPUTS],
    /// The latest high-to-low edge of each input (as wired).
    pub falling: [EdgeLatch; DIGITAL_INPUTS],
    /// The latest index pulse.
    pub index: EdgeLatch,
}

/// `levels` before the first sample.
const UNSAMPLED: u8 = 0xFF;

impl Default for PinLatches {
    fn default() -> Self {
        Self {
            levels: UNSAMPLED,
            rising: [EdgeLatch::default(); DIGITAL_INPUTS],
            falling: [EdgeLatch::default(); DIGITAL_INPUTS],
            index: EdgeLatch::default(),
        }
    }
}

impl PinLatches {
    /// Takes one sample: `levels` of the inputs and the `position` of the encoder at the same instant.
    #[inline(always)]
    pub fn sample_inputs(&mut self, levels: u8, position: i32) {
        // `levels` holds 0xFF until the first sample (no input has bits above 3): the first sample differs and
        // only sets the levels.
        let levels = levels & 0b1111;
        if levels != self.levels {
            self.latch_inputs(levels, position);
        }
    }

    #[inline(always)]
    fn latch_inputs(&mut self, levels: u8, position: i32) {
        let previous = core::mem::replace(&mut self.levels, levels);
        if previous == UNSAMPLED {
            return;
        }
        // One test per input, written out (tier 1; a loop over the inputs would stay rolled in this crate, which
        // is optimised for size).
        let changed = levels ^ previous;
        self.latch_input(0, changed, levels, position);
        self.latch_input(1, changed, levels, position);
        self.latch_input(2, changed, levels, position);
        self.latch_input(3, changed, levels, position);
    }

    /// Latches `position` at input `bit`'s edge if it `changed` (the new `levels` tell the direction).
    #[inline(always)]
    fn latch_input(&mut self, bit: usize, changed: u8, levels: u8, position: i32) {
        let mask = 1u8 << bit;
        if changed & mask == 0 {
            return;
        }
        let edges = if levels & mask != 0 { &mut self.rising } else { &mut self.falling };
        if let Some(latch) = edges.get_mut(bit) {
            latch.count = latch.count.wrapping_add(1);
            latch.position = position;
        }
    }

    /// Records an index pulse at encoder `position`.
    #[inline(always)]
    pub fn latch_index(&mut self, position: i32) {
        self.index.count = self.index.count.wrapping_add(1);
        self.index.position = position;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_sample_sets_levels_without_edges() {
        let mut l = PinLatches::default();
        l.sample_inputs(0b0101, 7);
        assert_eq!(l.levels, 0b0101);
        assert!(l.rising.iter().chain(l.falling.iter()).all(|e| e.count == 0));
    }

    #[test]
    fn edges_latch_position_per_input_and_direction() {
        let mut l = PinLatches::default();
        l.sample_inputs(0, 0);
        l.sample_inputs(0b0010, 100);
        l.sample_inputs(0b0010, 105);
        l.sample_inputs(0b1000, 120);
        assert_eq!(l.rising[1], EdgeLatch { count: 1, position: 100 });
        assert_eq!(l.falling[1], EdgeLatch { count: 1, position: 120 });
        assert_eq!(l.rising[3], EdgeLatch { count: 1, position: 120 });
        assert_eq!(l.rising[0].count, 0);
        l.latch_index(-5);
        l.latch_index(4091);
        assert_eq!(l.index, EdgeLatch { count: 2, position: 4091 });
    }

    #[test]
    fn levels_above_four_inputs_are_ignored() {
        let mut l = PinLatches::default();
        l.sample_inputs(0, 0);
        l.sample_inputs(0b1111_0000, 1);
        assert_eq!(l.levels, 0);
        assert!(l.rising.iter().all(|e| e.count == 0));
    }
}
