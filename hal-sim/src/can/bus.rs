//! A simulated CAN bus: several nodes, one wire, frames that take their real time (bit stuffing included,
//! [`super::timing`]), arbitration by identifier, bus load, and injected errors.
//!
//! Model:
//! - Each node has a transmit queue served in order (one transmit buffer fed by a software FIFO, as CANopen
//!   stacks on bxCAN-class controllers do); the frame at its head takes part in arbitration once it is queued.
//! - When the bus is free (the previous frame and its intermission are over), the lowest identifier among the
//!   heads wins (ISO 11898-1 §10.4: dominant bits win bitwise, so the numerically lowest identifier). Two nodes
//!   with the same identifier would collide on a real bus; here the lower node number wins and the clash is
//!   counted ([`BusStats::id_clashes`]), since it is a configuration error the tests want to see.
//! - Every node but the sender receives a frame when its last bit has passed ([`Delivery::end_ns`]).
//! - Injected errors ([`Injection`]): a frame destroyed on the wire is followed by an error frame and sent
//!   again automatically (the transmit error counter rises by 8, ISO 11898-1 §12.1.4.2 rule 3, and falls by 1
//!   for every success); a frame lost at one receiver (overrun) is delivered to the others only; a node driven
//!   bus-off sends nothing until 128 x 11 recessive bits have passed, and its queue waits.

use std::collections::VecDeque;

use super::timing::{bits_to_ns, frame_bits, BUS_OFF_RECOVERY_BITS, ERROR_FRAME_BITS};
use super::CanFrame;

/// A node's place on the bus.
pub type NodeIndex = usize;

/// Transmit error counter at which a node goes bus-off (ISO 11898-1 §12.1.4.2).
const BUS_OFF_TEC: u16 = 256;

/// A frame that crossed the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Delivery {
    /// The frame.
    pub frame: CanFrame,
    /// The node that sent it.
    pub from: NodeIndex,
    /// Its start of frame, ns of bus time.
    pub start_ns: u64,
    /// Its last bit (before the intermission), ns of bus time: when receivers have it.
    pub end_ns: u64,
    /// A receiver that lost it (an injected overrun), if any.
    pub lost_at: Option<NodeIndex>,
}

/// An error to inject.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Injection {
    /// The next `count` frames with identifier `id` (any, if `None`) are destroyed on the wire (a bit error seen
    /// by every node): an error frame follows and the sender repeats them.
    Corrupt {
        /// Identifier to hit, or any.
        id: Option<u16>,
        /// How many.
        count: u32,
    },
    /// The next `count` frames with identifier `id` (any, if `None`) are lost at receiver `node` only.
    LoseAt {
        /// The receiver that misses them.
        node: NodeIndex,
        /// Identifier to hit, or any.
        id: Option<u16>,
        /// How many.
        count: u32,
    },
    /// `node` goes bus-off now (as after 32 failed transmissions in a row).
    BusOff {
        /// The node.
        node: NodeIndex,
    },
}

/// What the bus counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Frames that crossed the bus successfully.
    pub frames: u64,
    /// Bit times taken by frames and error frames (intermission included).
    pub busy_bits: u64,
    /// Error frames (destroyed transmissions).
    pub error_frames: u64,
    /// Frame receptions lost at a receiver.
    pub lost_receptions: u64,
    /// Arbitration rounds where two nodes offered the same identifier.
    pub id_clashes: u64,
    /// Times a node went bus-off.
    pub bus_off_events: u64,
}

#[derive(Clone, Debug, Default)]
struct Port {
    queue: VecDeque<(u64, CanFrame)>,
    tec: u16,
    /// Bus-off until this bus time, ns.
    bus_off_until: Option<u64>,
}

/// The bus. See the module documentation.
#[derive(Clone, Debug)]
pub struct CanBus {
    bit_rate: u32,
    ports: Vec<Port>,
    /// The bus is busy (frame or intermission) until this time, ns.
    free_at: u64,
    /// Time up to which the bus has been run, ns.
    now: u64,
    injections: Vec<Injection>,
    stats: BusStats,
}

impl CanBus {
    /// An idle bus at `bit_rate` bit/s with no nodes.
    pub fn new(bit_rate: u32) -> Self {
        Self {
            bit_rate: bit_rate.max(1),
            ports: Vec::new(),
            free_at: 0,
            now: 0,
            injections: Vec::new(),
            stats: BusStats::default(),
        }
    }

    /// The bit rate, bit/s.
    pub fn bit_rate(&self) -> u32 {
        self.bit_rate
    }

    /// Changes the bit rate (an LSS activate bit timing, CiA 305 §6.4.3): frames sent from now on take the new bit
    /// times.
    pub fn set_bit_rate(&mut self, bit_rate: u32) {
        self.bit_rate = bit_rate.max(1);
    }

    /// Connects a node; returns its index.
    pub fn attach(&mut self) -> NodeIndex {
        self.ports.push(Port::default());
        self.ports.len() - 1
    }

    /// Nodes on the bus.
    pub fn nodes(&self) -> usize {
        self.ports.len()
    }

    /// Queues `frame` at `node` at bus time `at_ns` (not before the time the bus has been run to). A frame of an
    /// unknown node is ignored and `false` returned.
    pub fn send(&mut self, node: NodeIndex, at_ns: u64, frame: CanFrame) -> bool {
        let now = self.now;
        match self.ports.get_mut(node) {
            Some(port) => {
                port.queue.push_back((at_ns.max(now), frame));
                true
            }
            None => false,
        }
    }

    /// Frames waiting at `node`.
    pub fn pending(&self, node: NodeIndex) -> usize {
        self.ports.get(node).map_or(0, |p| p.queue.len())
    }

    /// Whether `node` is bus-off now.
    pub fn is_bus_off(&self, node: NodeIndex) -> bool {
        self.ports.get(node).is_some_and(|p| p.bus_off_until.is_some_and(|t| t > self.now))
    }

    /// Adds an error to inject.
    pub fn inject(&mut self, injection: Injection) {
        if let Injection::BusOff { node } = injection {
            let until = self.now.max(self.free_at) + bits_to_ns(BUS_OFF_RECOVERY_BITS, self.bit_rate);
            if let Some(port) = self.ports.get_mut(node) {
                port.bus_off_until = Some(until);
                port.tec = BUS_OFF_TEC;
                self.stats.bus_off_events += 1;
            }
            return;
        }
        self.injections.push(injection);
    }

    /// The counters.
    pub fn stats(&self) -> BusStats {
        self.stats
    }

    /// Time the bus has been run to, ns.
    pub fn now_ns(&self) -> u64 {
        self.now
    }

    /// Bus load so far: the share of bus time taken by frames and error frames (0..=1).
    pub fn load(&self) -> f64 {
        if self.now == 0 {
            return 0.0;
        }
        (bits_to_ns(self.stats.busy_bits.min(u64::from(u32::MAX)) as u32, self.bit_rate) as f64 / self.now as f64)
            .min(1.0)
    }

    /// Runs the bus up to bus time `until_ns`: every frame whose transmission ends by then is returned in bus
    /// order. A frame still on the wire at `until_ns` completes in a later call.
    pub fn run_until(&mut self, until_ns: u64) -> Vec<Delivery> {
        let mut out = Vec::new();
        loop {
            // The earliest moment some node has a frame and the bus is free (a bus-off node: and it recovered).
            let ready_at =
                |p: &Port| p.queue.front().map(|(t, _)| (*t).max(self.free_at).max(p.bus_off_until.unwrap_or(0)));
            let Some(start) = self.ports.iter().filter_map(ready_at).min() else {
                break;
            };
            // Arbitration among the heads ready by then.
            let mut winner: Option<(u16, NodeIndex)> = None;
            let mut clash = false;
            for (node, port) in self.ports.iter().enumerate() {
                let Some((_, frame)) = port.queue.front() else { continue };
                if ready_at(port).is_some_and(|t| t <= start) {
                    match winner {
                        Some((id, _)) if id == frame.id() => clash = true,
                        Some((id, _)) if id < frame.id() => {}
                        _ => winner = Some((frame.id(), node)),
                    }
                }
            }
            let Some((_, node)) = winner else { break };
            let frame = self.ports[node].queue.front().map(|(_, f)| *f).expect("the winner has a frame");
            let bits = frame_bits(frame.id(), frame.is_remote(), frame.dlc(), frame.data());
            let end = start + bits_to_ns(bits - super::timing::INTERMISSION_BITS, self.bit_rate);
            if end > until_ns {
                break;
            }
            if clash {
                self.stats.id_clashes += 1;
            }
            let port = &mut self.ports[node];
            if port.bus_off_until.is_some_and(|t| t <= start) {
                // Recovered (ISO 11898-1 §12.1.4.2): error counters back to 0.
                port.bus_off_until = None;
                port.tec = 0;
            }
            if self
                .take_injection(|i| matches!(i, Injection::Corrupt { id, .. } if id.is_none_or(|id| id == frame.id())))
                .is_some()
            {
                // Destroyed: an error frame after (at worst) the whole frame, then arbitration again.
                self.stats.error_frames += 1;
                self.stats.busy_bits += u64::from(bits + ERROR_FRAME_BITS);
                self.free_at = start + bits_to_ns(bits + ERROR_FRAME_BITS, self.bit_rate);
                let port = &mut self.ports[node];
                port.tec = port.tec.saturating_add(8);
                if port.tec >= BUS_OFF_TEC {
                    port.bus_off_until = Some(self.free_at + bits_to_ns(BUS_OFF_RECOVERY_BITS, self.bit_rate));
                    self.stats.bus_off_events += 1;
                }
                continue;
            }
            self.ports[node].queue.pop_front();
            let port = &mut self.ports[node];
            port.tec = port.tec.saturating_sub(1);
            self.stats.frames += 1;
            self.stats.busy_bits += u64::from(bits);
            self.free_at = start + bits_to_ns(bits, self.bit_rate);
            let lost_at = self
                .take_injection(|i| {
                    matches!(i, Injection::LoseAt { node: at, id, .. }
                        if *at != node && id.is_none_or(|id| id == frame.id()))
                })
                .and_then(|i| match i {
                    Injection::LoseAt { node, .. } => Some(node),
                    _ => None,
                });
            if lost_at.is_some() {
                self.stats.lost_receptions += 1;
            }
            out.push(Delivery { frame, from: node, start_ns: start, end_ns: end, lost_at });
        }
        self.now = self.now.max(until_ns);
        out
    }

    /// Uses up one count of the first injection `matches` accepts; returns it.
    fn take_injection(&mut self, matches: impl Fn(&Injection) -> bool) -> Option<Injection> {
        let k = self.injections.iter().position(matches)?;
        let found = self.injections[k];
        let count = match &mut self.injections[k] {
            Injection::Corrupt { count, .. } | Injection::LoseAt { count, .. } => count,
            Injection::BusOff { .. } => return Some(found),
        };
        *count = count.saturating_sub(1);
        if *count == 0 {
            self.injections.remove(k);
        }
        Some(found)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(id, data).expect("valid frame")
    }

    #[test]
    fn the_lowest_identifier_wins_arbitration_and_every_other_node_receives_it() {
        let mut bus = CanBus::new(1_000_000);
        let (a, b, c) = (bus.attach(), bus.attach(), bus.attach());
        bus.send(a, 0, frame(0x381, &[1]));
        bus.send(b, 0, frame(0x080, &[]));
        bus.send(c, 0, frame(0x181, &[2, 3]));
        let got = bus.run_until(1_000_000);
        let order: Vec<_> = got.iter().map(|d| (d.frame.id(), d.from)).collect();
        assert_eq!(order, [(0x080, b), (0x181, c), (0x381, a)]);
        // Back to back: each starts when the previous frame and its intermission are over.
        for pair in got.windows(2) {
            let gap = pair[1].start_ns - pair[0].end_ns;
            assert_eq!(gap, 3_000, "the 3-bit intermission at 1 Mbit/s");
        }
    }

    #[test]
    fn a_frame_lasts_its_stuffed_bit_count_and_the_load_follows() {
        let mut bus = CanBus::new(500_000);
        let a = bus.attach();
        bus.attach();
        let f = frame(0x201, &[0, 0, 0, 0, 0, 0, 0, 0]);
        let bits = frame_bits(0x201, false, 8, f.data());
        bus.send(a, 0, f);
        let got = bus.run_until(10_000_000);
        assert_eq!(got[0].end_ns - got[0].start_ns, bits_to_ns(bits - 3, 500_000));
        let load = bus.load();
        let expected = bits_to_ns(bits, 500_000) as f64 / 10_000_000.0;
        assert!((load - expected).abs() < 1e-9, "{load} vs {expected}");
    }

    #[test]
    fn a_frame_that_ends_after_the_horizon_waits_for_the_next_call() {
        let mut bus = CanBus::new(1_000_000);
        let a = bus.attach();
        bus.attach();
        bus.send(a, 0, frame(0x100, &[0; 8]));
        assert!(bus.run_until(50_000).is_empty());
        assert_eq!(bus.run_until(200_000).len(), 1);
    }

    #[test]
    fn a_destroyed_frame_is_repeated_after_an_error_frame() {
        let mut bus = CanBus::new(1_000_000);
        let a = bus.attach();
        bus.attach();
        bus.inject(Injection::Corrupt { id: Some(0x080), count: 2 });
        bus.send(a, 0, frame(0x080, &[]));
        let got = bus.run_until(1_000_000);
        assert_eq!(got.len(), 1, "delivered once, after two failures");
        assert_eq!(bus.stats().error_frames, 2);
        let one = bits_to_ns(frame_bits(0x080, false, 0, &[]) + ERROR_FRAME_BITS, 1_000_000);
        assert_eq!(got[0].start_ns, 2 * one);
    }

    #[test]
    fn a_frame_lost_at_one_receiver_reaches_the_others() {
        let mut bus = CanBus::new(1_000_000);
        let (a, b) = (bus.attach(), bus.attach());
        bus.attach();
        bus.inject(Injection::LoseAt { node: b, id: None, count: 1 });
        bus.send(a, 0, frame(0x181, &[1]));
        bus.send(a, 0, frame(0x181, &[2]));
        let got = bus.run_until(1_000_000);
        assert_eq!(got[0].lost_at, Some(b));
        assert_eq!(got[1].lost_at, None);
        assert_eq!(bus.stats().lost_receptions, 1);
    }

    #[test]
    fn a_bus_off_node_sends_nothing_until_it_recovers() {
        let mut bus = CanBus::new(1_000_000);
        let (a, b) = (bus.attach(), bus.attach());
        bus.inject(Injection::BusOff { node: a });
        assert!(bus.is_bus_off(a));
        bus.send(a, 0, frame(0x181, &[1]));
        bus.send(b, 0, frame(0x182, &[1]));
        let got = bus.run_until(1_000_000);
        assert_eq!(got.iter().map(|d| d.from).collect::<Vec<_>>(), [b], "only b within 1 ms");
        // 128 x 11 bits = 1.408 ms at 1 Mbit/s.
        let got = bus.run_until(2_000_000);
        assert_eq!(got.len(), 1);
        assert!(got[0].start_ns >= 1_408_000);
        assert!(!bus.is_bus_off(a));
    }

    #[test]
    fn a_node_repeatedly_destroyed_goes_bus_off() {
        let mut bus = CanBus::new(1_000_000);
        let a = bus.attach();
        bus.attach();
        bus.inject(Injection::Corrupt { id: None, count: 32 });
        bus.send(a, 0, frame(0x181, &[1]));
        bus.run_until(10_000_000);
        assert_eq!(bus.stats().error_frames, 32);
        assert_eq!(bus.stats().bus_off_events, 1);
    }

    #[test]
    fn two_nodes_offering_the_same_identifier_are_counted_as_a_clash() {
        let mut bus = CanBus::new(1_000_000);
        let (a, b) = (bus.attach(), bus.attach());
        bus.send(a, 0, frame(0x701, &[5]));
        bus.send(b, 0, frame(0x701, &[5]));
        assert_eq!(bus.run_until(1_000_000).len(), 2);
        assert_eq!(bus.stats().id_clashes, 1);
    }
}
