//! Touch probes 1 and 2: 0x60B8 function, 0x60B9 status, 0x60BA..0x60BD latched positions, 0x60D0 sources,
//! 0x60D5..0x60D8 edge counters.
//!
//! Sources: cia402-device-control.md §4; IDX 6.2.117-6.2.125 (seed L6358-6600, probe 1 only); Glentek §8 (seed
//! L1328-1575: probe 2 in bits 8..13, 60BC/60BD, counters 60D7/60D8, the timeline of Table 8-11).
//!
//! Behaviour, per probe (bits of probe 2 are those of probe 1 shifted by 8):
//! * **Source** (0x60B8 bits 3:2, `device.toml` note on 0x60B8): `00` the touch-probe input (the lowest input with
//!   0x3142 = 26) for probe 1, and 0x60D0:01 when no input has that function (IDX Table 6-131 note \[a\]: "00 or 10
//!   results in the same behavior"); for probe 2, which has no input function, 0x60D0:02. `01` the encoder index
//!   (EPOS3, Glentek). `10` 0x60D0:n (1..4 = digital input 1..4, 5 = index; IDX Table 6-133). `11` reserved: no
//!   source, nothing is latched.
//! * **Edges**: an input's positive edge is its edge into the active level (0x3141:02 polarity applied, like every
//!   input function in 0x60FD); the index has positive edges only.
//! * **Enable** (bit 0): its rising edge arms the probe: status bit 0 set, stored flags and counters cleared, and
//!   edges latched up to and including this tick ignored (an edge and the enabling write in the same tick are not
//!   ordered, so the edge counts as earlier). Its falling edge clears status bits 0..2 and the counters (IDX L6565
//!   "cleared when the touch probe is disabled"); the positions keep their values (Glentek Table 8-11 step 14a, L1575).
//! * **Sampling** (bits 4/5): clearing a sampling bit clears its stored flag and keeps the position (Glentek steps
//!   7-8a); setting it again re-arms that edge (a single-event probe may latch once more; in continuous mode the
//!   counter goes on). Edges of the tick the bit is set in are ignored, as for the enable.
//! * **Single event** (bit 1 = 0): the first edge after arming latches the position, sets the stored flag and sets
//!   the counter to 1 (IDX Table 6-134: range 0..1); later edges are ignored until re-armed. **Continuous**: every
//!   edge latches, the counter counts every edge (wrapping, IDX "0...65'535 (with overflow)").
//! * Tier 1 keeps only the latest position of each latch, so of several edges of one kind within one slow tick
//!   (400 us) a continuous probe latches the last one (the counter still counts them all), and a single-event
//!   probe latches the last one rather than the first.
//! * Homing clears all probe states and positions (IDX L6362): [`TouchProbes::clear`].

use crate::motion::gear::UserUnits;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::sensors::latch::{PinLatches, DIGITAL_INPUTS};

use super::inputs::{function, InputConfig};

/// Number of touch probes (Glentek has two; IDX has probe 1 only).
pub const TOUCH_PROBES: usize = 2;

/// 0x60B8 bits of probe 1 (probe 2: shifted left by 8).
pub mod function_bits {
    /// Enable the probe.
    pub const ENABLE: u8 = 1 << 0;
    /// Continuous (1) or first event only (0).
    pub const CONTINUOUS: u8 = 1 << 1;
    /// Source selection, bits 3:2.
    pub const SOURCE_MASK: u8 = 0b11 << 2;
    /// Source `00`: the touch-probe input.
    pub const SOURCE_INPUT: u8 = 0b00 << 2;
    /// Source `01`: the encoder index.
    pub const SOURCE_INDEX: u8 = 0b01 << 2;
    /// Source `10`: 0x60D0.
    pub const SOURCE_OBJECT: u8 = 0b10 << 2;
    /// Sample positive edges.
    pub const POSITIVE: u8 = 1 << 4;
    /// Sample negative edges.
    pub const NEGATIVE: u8 = 1 << 5;
}

/// 0x60B9 bits of probe 1 (probe 2: shifted left by 8).
pub mod status_bits {
    /// The probe is enabled.
    pub const ENABLED: u8 = 1 << 0;
    /// A positive-edge position is stored.
    pub const POSITIVE_STORED: u8 = 1 << 1;
    /// A negative-edge position is stored.
    pub const NEGATIVE_STORED: u8 = 1 << 2;
}

/// The signal a probe watches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProbeSource {
    /// Digital input, 0-based.
    Input(usize),
    /// The encoder index (positive edges only).
    Index,
    /// No signal (reserved selection or an invalid 0x60D0 value).
    None,
}

impl ProbeSource {
    /// The meaning of a 0x60D0 value (IDX Table 6-133): 1..4 digital input 1..4, 5 the index.
    #[must_use]
    pub fn from_object(value: i16) -> Self {
        match value {
            1..=4 => usize::try_from(value).ok().and_then(|v| v.checked_sub(1)).map_or(Self::None, Self::Input),
            5 => Self::Index,
            _ => Self::None,
        }
    }

    /// The source of probe `probe` (0-based) for its 0x60B8 bits `bits`, the input configuration and its 0x60D0
    /// value (see the module docs).
    #[must_use]
    pub fn select(probe: usize, bits: u8, inputs: &InputConfig, object: i16) -> Self {
        match bits & function_bits::SOURCE_MASK {
            function_bits::SOURCE_INPUT => match (probe, inputs.input_with(function::TOUCH_PROBE)) {
                (0, Some(input)) => Self::Input(input),
                _ => Self::from_object(object),
            },
            function_bits::SOURCE_INDEX => Self::Index,
            function_bits::SOURCE_OBJECT => Self::from_object(object),
            _ => Self::None,
        }
    }
}

/// Edge counts of every latch seen at the previous tick (to find the new edges).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct Seen {
    rising: [u16; DIGITAL_INPUTS],
    falling: [u16; DIGITAL_INPUTS],
    index: u16,
}

impl Seen {
    fn of(pins: &PinLatches) -> Self {
        // Written out: a slow-tick path, and `map` stays a loop in a crate optimised for size.
        let [r0, r1, r2, r3] = pins.rising;
        let [f0, f1, f2, f3] = pins.falling;
        Self {
            rising: [r0.count, r1.count, r2.count, r3.count],
            falling: [f0.count, f1.count, f2.count, f3.count],
            index: pins.index.count,
        }
    }
}

/// New edges of one kind since the previous tick: how many, and the raw position of the latest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct NewEdges {
    count: u16,
    position: i32,
}

/// One probe's state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct Probe {
    /// Its 0x60B8 bits at the previous tick.
    previous: u8,
    /// Its 0x60B9 bits.
    status: u8,
    positive_value: i32,
    negative_value: i32,
    positive_counter: u16,
    negative_counter: u16,
}

impl Probe {
    fn step(&mut self, bits: u8, positive: NewEdges, negative: NewEdges, position_offset: i32) {
        use function_bits as f;
        use status_bits as s;
        let rose = bits & !self.previous;
        let fell = self.previous & !bits;
        self.previous = bits;
        if fell & f::ENABLE != 0 {
            self.status = 0;
            self.positive_counter = 0;
            self.negative_counter = 0;
        }
        if bits & f::ENABLE == 0 {
            return;
        }
        if rose & f::ENABLE != 0 {
            self.status = s::ENABLED;
            self.positive_counter = 0;
            self.negative_counter = 0;
            return;
        }
        let continuous = bits & f::CONTINUOUS != 0;
        Self::edge(
            Edge { bit: f::POSITIVE, stored: s::POSITIVE_STORED, rose, fell, bits, continuous },
            &mut self.status,
            &mut self.positive_value,
            &mut self.positive_counter,
            positive,
            position_offset,
        );
        Self::edge(
            Edge { bit: f::NEGATIVE, stored: s::NEGATIVE_STORED, rose, fell, bits, continuous },
            &mut self.status,
            &mut self.negative_value,
            &mut self.negative_counter,
            negative,
            position_offset,
        );
    }

    fn edge(e: Edge, status: &mut u8, value: &mut i32, counter: &mut u16, new: NewEdges, position_offset: i32) {
        if e.fell & e.bit != 0 {
            *status &= !e.stored;
        }
        if e.bits & e.bit == 0 {
            return;
        }
        if e.rose & e.bit != 0 {
            // Re-armed: edges of this tick count as earlier; a single-event counter starts again from 0.
            if !e.continuous {
                *counter = 0;
            }
            return;
        }
        if new.count == 0 {
            return;
        }
        if e.continuous {
            *counter = counter.wrapping_add(new.count);
        } else if *status & e.stored == 0 {
            *counter = 1;
        } else {
            return;
        }
        *value = new.position.wrapping_add(position_offset);
        *status |= e.stored;
    }
}

/// The bits one sampling edge needs in [`Probe::edge`].
#[derive(Clone, Copy, Debug)]
struct Edge {
    bit: u8,
    stored: u8,
    rose: u8,
    fell: u8,
    bits: u8,
    continuous: bool,
}

/// Touch probes 1 and 2.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TouchProbes {
    probes: [Probe; TOUCH_PROBES],
    seen: Seen,
    primed: bool,
}

impl TouchProbes {
    /// Probes switched off, nothing stored.
    #[must_use]
    pub const fn new() -> Self {
        const OFF: Probe = Probe {
            previous: 0,
            status: 0,
            positive_value: 0,
            negative_value: 0,
            positive_counter: 0,
            negative_counter: 0,
        };
        Self {
            probes: [OFF; TOUCH_PROBES],
            seen: Seen { rising: [0; DIGITAL_INPUTS], falling: [0; DIGITAL_INPUTS], index: 0 },
            primed: false,
        }
    }

    /// One slow tick: reads 0x60B8 and 0x60D0, takes the new edges of each probe's source from `pins` (raw
    /// positions plus `position_offset` = 0x6064 coordinates) and publishes 0x60B9, 0x60BA..0x60BD, 0x60D5..0x60D8.
    /// The first call only notes the latch counts (edges before start-up are not probe events).
    pub fn step(&mut self, pins: &PinLatches, inputs: &InputConfig, position_offset: i32, d: &mut Dictionary) {
        let now = Seen::of(pins);
        let seen = if self.primed { self.seen } else { now };
        self.primed = true;
        self.seen = now;
        let [function_1, function_2] = d.get(h::TOUCH_PROBE_FUNCTION).to_le_bytes();
        let (source_1, source_2) = (d.get(h::TOUCH_PROBE_1_SOURCE), d.get(h::TOUCH_PROBE_2_SOURCE));
        // Each probe written out rather than a loop over zipped arrays: a slow-tick path in a crate optimised for
        // size, where such loops stay rolled with their bookkeeping.
        let at = ProbeInputs { pins, seen: &seen, inputs, position_offset };
        let [probe_1, probe_2] = &mut self.probes;
        step_probe(probe_1, 0, function_1, source_1, &at);
        step_probe(probe_2, 1, function_2, source_2, &at);
        self.publish(d);
    }

    /// Clears what the probes stored (positions, counters, stored flags), keeping them enabled: homing does this
    /// when it ends (IDX L6362 "After homing, all touch probe states and latched positions are cleared"), and
    /// publishes them.
    pub fn clear(&mut self, d: &mut Dictionary) {
        for p in &mut self.probes {
            p.status &= status_bits::ENABLED;
            p.positive_value = 0;
            p.negative_value = 0;
            p.positive_counter = 0;
            p.negative_counter = 0;
        }
        self.publish(d);
        // Zero is zero in any units.
        for handle in [
            h::TOUCH_PROBE_1_POSITIVE_VALUE,
            h::TOUCH_PROBE_1_NEGATIVE_VALUE,
            h::TOUCH_PROBE_2_POSITIVE_VALUE,
            h::TOUCH_PROBE_2_NEGATIVE_VALUE,
        ] {
            d.set(handle, 0);
        }
    }

    /// Publishes the latched positions in the master's units (polarity 0x607E bit 7 and the gear,
    /// [`crate::motion::gear`]: they are positions like 0x6064). Run after the slow tick with the other master
    /// positions, outside its budget.
    pub fn publish_positions(&self, units: &UserUnits, d: &mut Dictionary) {
        let [p1, p2] = &self.probes;
        d.set(h::TOUCH_PROBE_1_POSITIVE_VALUE, units.position_to_master(p1.positive_value));
        d.set(h::TOUCH_PROBE_1_NEGATIVE_VALUE, units.position_to_master(p1.negative_value));
        d.set(h::TOUCH_PROBE_2_POSITIVE_VALUE, units.position_to_master(p2.positive_value));
        d.set(h::TOUCH_PROBE_2_NEGATIVE_VALUE, units.position_to_master(p2.negative_value));
    }

    /// 0x60B9 as the probes see it now.
    #[must_use]
    pub fn status(&self) -> u16 {
        let [p1, p2] = &self.probes;
        u16::from_le_bytes([p1.status, p2.status])
    }

    /// Publishes the probes' status and counters (the slow tick); their positions follow in
    /// [`Self::publish_positions`], after the slow tick.
    fn publish(&self, d: &mut Dictionary) {
        let [p1, p2] = &self.probes;
        d.set(h::TOUCH_PROBE_STATUS, self.status());
        d.set(h::TOUCH_PROBE_1_POSITIVE_COUNTER, p1.positive_counter);
        d.set(h::TOUCH_PROBE_1_NEGATIVE_COUNTER, p1.negative_counter);
        d.set(h::TOUCH_PROBE_2_POSITIVE_COUNTER, p2.positive_counter);
        d.set(h::TOUCH_PROBE_2_NEGATIVE_COUNTER, p2.negative_counter);
    }
}

/// What every probe's step reads: the tier-1 latches, the counts seen at the previous slow tick, the input
/// configuration and the offset into 0x6064 coordinates.
struct ProbeInputs<'a> {
    pins: &'a PinLatches,
    seen: &'a Seen,
    inputs: &'a InputConfig,
    position_offset: i32,
}

/// One probe's slow tick: the new edges of its source (0x60B8 byte `function`, 0x60D0 sub-index `source`) since the
/// previous tick, handed to the probe.
fn step_probe(probe: &mut Probe, p: usize, function: u8, source: i16, at: &ProbeInputs<'_>) {
    let ProbeInputs { pins, seen, inputs, position_offset } = *at;
    let bits = function & 0b0011_1111;
    let (positive, negative) = match ProbeSource::select(p, bits, inputs, source) {
        ProbeSource::Input(i) => {
            let edges =
                |latches: &[crate::sensors::latch::EdgeLatch; DIGITAL_INPUTS], seen: &[u16; DIGITAL_INPUTS]| match (
                    latches.get(i),
                    seen.get(i),
                ) {
                    (Some(l), Some(&s)) => NewEdges { count: l.count.wrapping_sub(s), position: l.position },
                    _ => NewEdges::default(),
                };
            let rising = edges(&pins.rising, &seen.rising);
            let falling = edges(&pins.falling, &seen.falling);
            if inputs.active_low(i) {
                (falling, rising)
            } else {
                (rising, falling)
            }
        }
        ProbeSource::Index => (
            NewEdges { count: pins.index.count.wrapping_sub(seen.index), position: pins.index.position },
            NewEdges::default(),
        ),
        ProbeSource::None => (NewEdges::default(), NewEdges::default()),
    };
    probe.step(bits, positive, negative, position_offset);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::rig::Rig;

    const ENABLE: u16 = function_bits::ENABLE as u16;
    const CONTINUOUS: u16 = function_bits::CONTINUOUS as u16;
    const INDEX: u16 = function_bits::SOURCE_INDEX as u16;
    const OBJECT: u16 = function_bits::SOURCE_OBJECT as u16;
    const POS: u16 = function_bits::POSITIVE as u16;
    const NEG: u16 = function_bits::NEGATIVE as u16;

    /// Input 4 (0-based 3) as touch-probe input.
    fn probe_rig() -> Rig {
        let mut r = Rig::new();
        r.d.set(h::DIGITAL_INPUT_4_CONFIGURATION, function::TOUCH_PROBE);
        r.offset = 1000;
        r
    }

    fn probe1(r: &Rig) -> (u16, i32, i32, u16, u16) {
        (
            r.d.get(h::TOUCH_PROBE_STATUS),
            r.d.get(h::TOUCH_PROBE_1_POSITIVE_VALUE),
            r.d.get(h::TOUCH_PROBE_1_NEGATIVE_VALUE),
            r.d.get(h::TOUCH_PROBE_1_POSITIVE_COUNTER),
            r.d.get(h::TOUCH_PROBE_1_NEGATIVE_COUNTER),
        )
    }

    #[test]
    fn single_event_latches_the_first_edges_only() {
        let mut r = probe_rig();
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | POS | NEG);
        r.tick();
        assert_eq!(probe1(&r), (0b001, 0, 0, 0, 0));
        r.pin(3, true, 100);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1100, 0, 1, 0));
        r.pin(3, false, 150);
        r.tick();
        assert_eq!(probe1(&r), (0b111, 1100, 1150, 1, 1));
        r.pin(3, true, 300);
        r.pin(3, false, 350);
        r.tick();
        assert_eq!(probe1(&r), (0b111, 1100, 1150, 1, 1), "later edges ignored");
    }

    #[test]
    fn continuous_latches_every_edge_and_counts_them() {
        let mut r = probe_rig();
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | POS);
        r.tick();
        r.pin(3, true, 100);
        r.pin(3, false, 120);
        r.pin(3, true, 200);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1200, 0, 2, 0), "the latest of a burst, every edge counted");
        r.pin(3, false, 220);
        r.pin(3, true, 300);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1300, 0, 3, 0), "negative edges not sampled");
        // The counter wraps (IDX Table 6-134).
        r.pins.rising[3].count = r.pins.rising[3].count.wrapping_add(65_535);
        r.tick();
        assert_eq!(probe1(&r).3, 2);
    }

    #[test]
    fn enabling_ignores_earlier_edges_and_disabling_clears_status_and_counters() {
        let mut r = probe_rig();
        // Edges while disabled and in the tick of the enable are not events (sampling bits set beforehand).
        r.d.set(h::TOUCH_PROBE_FUNCTION, CONTINUOUS | POS | NEG);
        r.pin(3, true, 100);
        r.tick();
        assert_eq!(probe1(&r), (0, 0, 0, 0, 0));
        r.pin(3, false, 150);
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | POS | NEG);
        r.tick();
        assert_eq!(probe1(&r), (0b001, 0, 0, 0, 0));
        r.pin(3, true, 200);
        r.pin(3, false, 250);
        r.tick();
        assert_eq!(probe1(&r), (0b111, 1200, 1250, 1, 1));
        // Disable: status and counters cleared, positions kept (Glentek Table 8-11 step 14a).
        r.d.set(h::TOUCH_PROBE_FUNCTION, CONTINUOUS | POS | NEG);
        r.pin(3, true, 400);
        r.tick();
        assert_eq!(probe1(&r), (0, 1200, 1250, 0, 0));
        // Re-enable: armed afresh.
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | POS | NEG);
        r.tick();
        assert_eq!(probe1(&r), (0b001, 1200, 1250, 0, 0));
        r.pin(3, false, 500);
        r.tick();
        assert_eq!(probe1(&r), (0b101, 1200, 1500, 0, 1));
    }

    #[test]
    fn sampling_bit_rearms_a_single_event_probe() {
        let mut r = probe_rig();
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | POS);
        r.tick();
        r.pin(3, true, 100);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1100, 0, 1, 0));
        // Glentek Table 8-11 (7)-(12a): clearing bit 4 resets the stored flag, keeps the value.
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE);
        r.pin(3, false, 150);
        r.pin(3, true, 160);
        r.tick();
        assert_eq!(probe1(&r), (0b001, 1100, 0, 1, 0), "not sampling: nothing latched");
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | POS);
        r.tick();
        assert_eq!(probe1(&r), (0b001, 1100, 0, 0, 0));
        r.pin(3, false, 170);
        r.pin(3, true, 180);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1180, 0, 1, 0));
    }

    #[test]
    fn index_source_latches_index_pulses() {
        let mut r = probe_rig();
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | INDEX | POS | NEG);
        r.tick();
        r.pin(3, true, 50);
        r.tick();
        assert_eq!(probe1(&r), (0b001, 0, 0, 0, 0), "the touch-probe input is not the source");
        r.pins.latch_index(4096);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 5096, 0, 1, 0), "index: positive edges only");
        r.pins.latch_index(8192);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 9192, 0, 2, 0));
    }

    #[test]
    fn probe_2_uses_its_bits_and_0x60d0_02() {
        let mut r = probe_rig();
        // Probe 2, source 10 = 0x60D0:02 (default 5 = index), single event; probe 1 stays off.
        r.d.set(h::TOUCH_PROBE_FUNCTION, (ENABLE | OBJECT | POS) << 8);
        r.tick();
        assert_eq!(r.d.get(h::TOUCH_PROBE_STATUS), 0x0100);
        r.pins.latch_index(-4096);
        r.tick();
        assert_eq!(r.d.get(h::TOUCH_PROBE_STATUS), 0x0300);
        assert_eq!(r.d.get(h::TOUCH_PROBE_2_POSITIVE_VALUE), -3096);
        assert_eq!(r.d.get(h::TOUCH_PROBE_2_POSITIVE_COUNTER), 1);
        assert_eq!(probe1(&r), (0x0300, 0, 0, 0, 0));
        // 0x60D0:02 = 1: input 1, negative edges.
        r.d.set(h::TOUCH_PROBE_2_SOURCE, 1);
        r.d.set(h::TOUCH_PROBE_FUNCTION, (ENABLE | OBJECT | NEG) << 8);
        r.tick();
        r.pin(0, true, 10);
        r.pin(0, false, 20);
        r.tick();
        assert_eq!(r.d.get(h::TOUCH_PROBE_STATUS), 0x0500);
        assert_eq!(r.d.get(h::TOUCH_PROBE_2_NEGATIVE_VALUE), 1020);
        assert_eq!(r.d.get(h::TOUCH_PROBE_2_NEGATIVE_COUNTER), 1);
    }

    #[test]
    fn input_sources_follow_0x3142_0x60d0_and_polarity() {
        let mut r = probe_rig();
        // Source 00 takes the input with function 26 (input 4), not 0x60D0:01 (set to input 2 here).
        r.d.set(h::TOUCH_PROBE_1_SOURCE, 2);
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | POS);
        r.tick();
        r.pin(1, true, 10);
        r.tick();
        assert_eq!(probe1(&r).3, 0);
        r.pin(3, true, 20);
        r.tick();
        assert_eq!(probe1(&r).1, 1020);
        // Source 10 takes 0x60D0:01 = input 2; active low, so its falling pin edge is the positive edge.
        r.d.set(h::DIGITAL_INPUTS_POLARITY, 0b0010);
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | OBJECT | POS);
        r.tick();
        r.pin(1, false, 30);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1030, 0, 2, 0));
        // Source 00 without a touch-probe input falls back to 0x60D0:01 (IDX Table 6-131 note [a]).
        r.d.set(h::DIGITAL_INPUT_4_CONFIGURATION, function::GENERAL_PURPOSE_D);
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | POS);
        r.tick();
        r.pin(1, true, 40);
        r.pin(1, false, 50);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1050, 0, 3, 0));
        // Source 11 is reserved: nothing latches.
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | OBJECT | INDEX | POS);
        r.tick();
        r.pin(1, true, 60);
        r.pin(1, false, 70);
        r.pins.latch_index(0);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1050, 0, 3, 0));
    }

    #[test]
    fn clear_after_homing_keeps_the_probe_enabled() {
        let mut r = probe_rig();
        r.d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | POS);
        r.tick();
        r.pin(3, true, 100);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1100, 0, 1, 0));
        r.io.clear_touch_probes(&mut r.d);
        assert_eq!(probe1(&r), (0b001, 0, 0, 0, 0));
        r.pin(3, false, 150);
        r.pin(3, true, 200);
        r.tick();
        assert_eq!(probe1(&r), (0b011, 1200, 0, 1, 0));
        assert_eq!(r.io.touch_probe_status(), 0b011);
    }

    #[test]
    fn first_tick_ignores_edges_latched_before_start_up() {
        let mut pins = PinLatches::default();
        pins.sample_inputs(0, 0);
        pins.sample_inputs(0b1000, 77);
        let mut d = Dictionary::new(1);
        d.set(h::DIGITAL_INPUT_4_CONFIGURATION, function::TOUCH_PROBE);
        d.set(h::TOUCH_PROBE_FUNCTION, ENABLE | CONTINUOUS | POS);
        let mut probes = TouchProbes::new();
        let config = InputConfig::read(&d);
        probes.step(&pins, &config, 0, &mut d);
        assert_eq!(d.get(h::TOUCH_PROBE_STATUS), 0b001);
        probes.step(&pins, &config, 0, &mut d);
        assert_eq!(d.get(h::TOUCH_PROBE_STATUS), 0b001);
        assert_eq!(d.get(h::TOUCH_PROBE_1_POSITIVE_COUNTER), 0);
    }
}
