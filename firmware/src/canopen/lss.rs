//! The LSS slave (CiA 305, layer setting services): how a CANopen master assigns the node-ID (and bit rate) of
//! drives that have none, without DIP switches (EPOS4 supports it, comms-faults-bootloader.md).
//!
//! Frames: the master sends on 0x7E5, the slave answers on 0x7E4; byte 0 is the command specifier (cs). The slave
//! is in the LSS *waiting* state or the *configuration* state:
//!
//! | cs | Service (CiA 305 §6) | Answer |
//! |---|---|---|
//! | 0x04 | switch state global (byte 1: 0 waiting, 1 configuration) | none |
//! | 0x40..0x43 | switch state selective: vendor-ID, product code, revision, serial, in this order | 0x44 after the serial |
//! | 0x11 | configure node-ID (1..127, or 0xFF: unconfigured), configuration state | 0x11, error 0 / 1 out of range |
//! | 0x13 | configure bit timing (table 0, CiA 301 index), configuration state | 0x13, error 0 / 1 not supported |
//! | 0x15 | activate bit timing (bytes 1..2: switch delay, ms), configuration state | none |
//! | 0x17 | store configuration (node-ID and bit rate), configuration state | 0x17, error 0 / 2 storage failed |
//! | 0x46..0x4B | identify remote slave: vendor, product, revision range, serial range | 0x4F when inside |
//! | 0x4C | identify non-configured remote slave | 0x50 when unconfigured |
//! | 0x51 | fastscan (unconfigured slaves in waiting state only) | 0x4F when the checked bits match |
//! | 0x5A..0x5E | inquire vendor, product, revision, serial, node-ID, configuration state | same cs + value |
//!
//! Anything else gets no answer, as CiA 305 defines none for it. A configured bit rate takes effect at the next
//! reset node, as 0x2001 written by SDO does ([`super::ids`]), or when the master activates it (0x15, CiA 305
//! §6.4.3): the node stays silent for the switch delay, changes its bit rate, and stays silent for the delay again
//! before it transmits at the new rate (the node carries it out, [`LssAction::ActivateBitTiming`]).
//!
//! Pure: the node passes the identity (0x1018:01..04) and whether it is unconfigured, and carries out what
//! [`LssAction`] asks (write 0x2000/0x2001, store, leave the unconfigured state).

/// The master's COB-ID.
pub const MASTER_TO_SLAVE: u16 = 0x7E5;
/// The slave's COB-ID.
pub const SLAVE_TO_MASTER: u16 = 0x7E4;
/// The node-ID of a slave that has none (CiA 305 §4: "invalid" node-ID).
pub const UNCONFIGURED: u8 = 0xFF;

/// LSS state (CiA 305 §5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LssState {
    /// Waiting: only switch state, identify, fastscan.
    #[default]
    Waiting,
    /// Configuration: node-ID, bit timing, store, inquire.
    Configuration,
}

/// What the node must do after a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LssAction {
    /// Nothing beyond the answer.
    None,
    /// Write `node_id` to 0x2000 (it takes effect at the next reset communication, or now for an unconfigured
    /// node when it returns to waiting); answer with the result.
    ConfigureNodeId(u8),
    /// Write the bit-rate code to 0x2001 (takes effect at the next reset node).
    ConfigureBitRate(u8),
    /// Store node-ID and bit rate in non-volatile memory.
    Store,
    /// Switch to the configured bit rate (0x2001): silent for `switch_delay_ms`, switch, silent for it again.
    ActivateBitTiming {
        /// The switch delay, ms (CiA 305 §6.4.3: both silent periods last it).
        switch_delay_ms: u16,
    },
    /// The slave went back to waiting: an unconfigured node with a new node-ID finishes its initialisation.
    EnteredWaiting,
}

/// The LSS slave's state between frames.
#[derive(Clone, Copy, Debug, Default)]
pub struct LssSlave {
    state: LssState,
    /// Switch state selective: how many of the four identity parts matched in sequence.
    selective: u8,
    /// Fastscan: which identity part (0..3) the master checks next.
    fastscan_part: u8,
}

/// Little-endian `u32` of bytes 1..5 of an LSS frame.
fn word(data: &[u8; 8]) -> u32 {
    u32::from_le_bytes([data[1], data[2], data[3], data[4]])
}

/// An answer frame's data: `cs`, then `rest`.
fn answer(cs: u8, rest: &[u8]) -> [u8; 8] {
    let mut out = [0u8; 8];
    out[0] = cs;
    for (o, r) in out.iter_mut().skip(1).zip(rest) {
        *o = *r;
    }
    out
}

impl LssSlave {
    /// The state.
    #[must_use]
    pub const fn state(&self) -> LssState {
        self.state
    }

    /// One master frame (8 bytes; shorter frames are no LSS request and are ignored by the caller). `identity`
    /// is 0x1018:01..04, `node_id` the active node-ID ([`UNCONFIGURED`] for none). Returns the answer, if any,
    /// and what the node must do; for [`LssAction::ConfigureNodeId`], [`LssAction::ConfigureBitRate`] and
    /// [`LssAction::Store`] the answer's error byte is the node's to fill in ([`Self::result`]).
    pub fn handle(&mut self, data: &[u8; 8], identity: &[u32; 4], node_id: u8) -> (Option<[u8; 8]>, LssAction) {
        let configuring = self.state == LssState::Configuration;
        let unconfigured = node_id == UNCONFIGURED;
        match data[0] {
            0x04 => match data[1] {
                0 => {
                    let was = core::mem::replace(&mut self.state, LssState::Waiting);
                    let action =
                        if was == LssState::Configuration { LssAction::EnteredWaiting } else { LssAction::None };
                    (None, action)
                }
                1 => {
                    self.state = LssState::Configuration;
                    (None, LssAction::None)
                }
                _ => (None, LssAction::None),
            },
            cs @ 0x40..=0x43 => {
                let part = cs.wrapping_sub(0x40);
                let matches = identity.get(usize::from(part)) == Some(&word(data));
                // The four parts in sequence; a part out of sequence or a mismatch starts over.
                self.selective = if matches && part == self.selective { part.wrapping_add(1) } else { 0 };
                if self.selective == 4 {
                    self.selective = 0;
                    self.state = LssState::Configuration;
                    return (Some(answer(0x44, &[])), LssAction::None);
                }
                (None, LssAction::None)
            }
            0x11 if configuring => (Some(answer(0x11, &[0, 0])), LssAction::ConfigureNodeId(data[1])),
            0x13 if configuring => {
                // Table selector 0: the CiA 301 bit timing table, whose index is the 0x2001 code.
                let code = if data[1] == 0 { data[2] } else { u8::MAX };
                (Some(answer(0x13, &[0, 0])), LssAction::ConfigureBitRate(code))
            }
            0x15 if configuring => {
                (None, LssAction::ActivateBitTiming { switch_delay_ms: u16::from_le_bytes([data[1], data[2]]) })
            }
            0x17 if configuring => (Some(answer(0x17, &[0, 0])), LssAction::Store),
            cs @ 0x5A..=0x5D if configuring => {
                let value = identity.get(usize::from(cs.wrapping_sub(0x5A))).copied().unwrap_or(0);
                (Some(answer(cs, &value.to_le_bytes())), LssAction::None)
            }
            0x5E if configuring => (Some(answer(0x5E, &[node_id])), LssAction::None),
            cs @ 0x46..=0x4B if !configuring => (self.identify(cs, word(data), identity), LssAction::None),
            0x4C if !configuring && unconfigured => (Some(answer(0x50, &[])), LssAction::None),
            0x51 if !configuring && unconfigured => (self.fastscan(data, identity), LssAction::None),
            _ => (None, LssAction::None),
        }
    }

    /// Identify remote slave (cs 0x46..0x4B): the master sends vendor, product, revision low, revision high,
    /// serial low, serial high in turn; the slave answers 0x4F after the serial high when its identity lies
    /// inside (the parts that matched so far are bits of `selective`, which the selective switch uses otherwise).
    fn identify(&mut self, cs: u8, value: u32, identity: &[u32; 4]) -> Option<[u8; 8]> {
        // Bit k of `selective` (as a mask): part k matched so far; 0x46 starts over.
        let inside = match cs {
            0x46 => {
                self.selective = 0;
                identity[0] == value
            }
            0x47 => identity[1] == value,
            0x48 => identity[2] >= value,
            0x49 => identity[2] <= value,
            0x4A => identity[3] >= value,
            _ => identity[3] <= value,
        };
        let bit = 1u8 << cs.wrapping_sub(0x46);
        if inside {
            self.selective |= bit;
        }
        (cs == 0x4B && self.selective == 0x3F).then(|| {
            self.selective = 0;
            answer(0x4F, &[])
        })
    }

    /// Fastscan (CiA 305 §6.7): byte 5 is the bit checked (0x80: a new scan), byte 6 the identity part
    /// checked, byte 7 the part the master checks next. The slave answers while the part's bits from the
    /// checked one up agree with the master's; after the serial's last bit it enters configuration.
    fn fastscan(&mut self, data: &[u8; 8], identity: &[u32; 4]) -> Option<[u8; 8]> {
        let (bit, part, next) = (data[5], data[6], data[7]);
        if bit == 0x80 {
            self.fastscan_part = 0;
            return Some(answer(0x4F, &[]));
        }
        if bit > 31 || part != self.fastscan_part {
            return None;
        }
        let mine = identity.get(usize::from(part)).copied()?;
        if (mine ^ word(data)).checked_shr(u32::from(bit)).unwrap_or(0) != 0 {
            return None;
        }
        if bit == 0 {
            self.fastscan_part = next;
            if next < part {
                self.fastscan_part = 0;
                self.state = LssState::Configuration;
            }
        }
        Some(answer(0x4F, &[]))
    }

    /// The answer to a configure or store request with the node's `error` (0 success).
    #[must_use]
    pub fn result(cs: u8, error: u8) -> [u8; 8] {
        answer(cs, &[error, 0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: [u32; 4] = [0x0000_0ACE, 0x0001_0001, 0x0001_0000, 0x1234_5678];

    fn frame(cs: u8, rest: &[u8]) -> [u8; 8] {
        answer(cs, rest)
    }

    #[test]
    fn selective_switch_needs_the_four_parts_in_order() {
        let mut s = LssSlave::default();
        for (i, part) in ID.iter().enumerate().take(3) {
            assert_eq!(s.handle(&frame(0x40 + i as u8, &part.to_le_bytes()), &ID, 1).0, None);
        }
        assert_eq!(s.handle(&frame(0x43, &ID[3].to_le_bytes()), &ID, 1).0, Some(frame(0x44, &[])));
        assert_eq!(s.state(), LssState::Configuration);
        let mut other = LssSlave::default();
        for (i, part) in ID.iter().enumerate() {
            let v = if i == 2 { part + 1 } else { *part };
            assert_eq!(other.handle(&frame(0x40 + i as u8, &v.to_le_bytes()), &ID, 1).0, None);
        }
        assert_eq!(other.state(), LssState::Waiting);
    }

    #[test]
    fn configuration_services_answer_only_in_configuration() {
        let mut s = LssSlave::default();
        assert_eq!(s.handle(&frame(0x11, &[5]), &ID, UNCONFIGURED), (None, LssAction::None));
        assert_eq!(s.handle(&frame(0x5E, &[]), &ID, UNCONFIGURED).0, None);
        assert_eq!(s.handle(&frame(0x15, &[10, 0]), &ID, UNCONFIGURED), (None, LssAction::None));
        s.handle(&frame(0x04, &[1]), &ID, UNCONFIGURED);
        assert_eq!(s.handle(&frame(0x11, &[5]), &ID, UNCONFIGURED).1, LssAction::ConfigureNodeId(5));
        assert_eq!(s.handle(&frame(0x13, &[0, 2]), &ID, UNCONFIGURED).1, LssAction::ConfigureBitRate(2));
        assert_eq!(s.handle(&frame(0x13, &[1, 2]), &ID, UNCONFIGURED).1, LssAction::ConfigureBitRate(u8::MAX));
        assert_eq!(
            s.handle(&frame(0x15, &[0x34, 0x12]), &ID, UNCONFIGURED),
            (None, LssAction::ActivateBitTiming { switch_delay_ms: 0x1234 }),
            "activate bit timing: no answer, the delay little-endian"
        );
        assert_eq!(s.handle(&frame(0x17, &[]), &ID, UNCONFIGURED).1, LssAction::Store);
        assert_eq!(s.handle(&frame(0x5D, &[]), &ID, UNCONFIGURED).0, Some(frame(0x5D, &ID[3].to_le_bytes())));
        assert_eq!(s.handle(&frame(0x5E, &[]), &ID, UNCONFIGURED).0, Some(frame(0x5E, &[0xFF])));
        assert_eq!(s.handle(&frame(0x04, &[0]), &ID, UNCONFIGURED), (None, LssAction::EnteredWaiting));
        assert_eq!(s.handle(&frame(0x04, &[0]), &ID, UNCONFIGURED), (None, LssAction::None));
    }

    /// The master's side of a fastscan as CiA 305 §6.7 runs it, against one slave; the identity it finds.
    fn scan(s: &mut LssSlave, identity: &[u32; 4]) -> Option<[u32; 4]> {
        let mut probe = |id: u32, bit: u8, part: u8, next: u8| {
            let mut f = frame(0x51, &id.to_le_bytes());
            (f[5], f[6], f[7]) = (bit, part, next);
            s.handle(&f, identity, UNCONFIGURED).0.is_some()
        };
        if !probe(0, 0x80, 0, 0) {
            return None;
        }
        let mut found = [0u32; 4];
        for part in 0..4u8 {
            for bit in (0..32u8).rev() {
                if !probe(found[usize::from(part)], bit, part, part) {
                    found[usize::from(part)] |= 1 << bit;
                }
            }
            if !probe(found[usize::from(part)], 0, part, (part + 1) & 3) {
                return None;
            }
        }
        Some(found)
    }

    #[test]
    fn fastscan_finds_the_identity_and_switches_to_configuration() {
        let mut s = LssSlave::default();
        assert_eq!(scan(&mut s, &ID), Some(ID));
        assert_eq!(s.state(), LssState::Configuration);
    }

    #[test]
    fn a_configured_slave_takes_no_part_in_fastscan_or_the_non_configured_identify() {
        let mut s = LssSlave::default();
        let mut f = frame(0x51, &[]);
        f[5] = 0x80;
        assert_eq!(s.handle(&f, &ID, 5).0, None);
        assert_eq!(s.handle(&frame(0x4C, &[]), &ID, 5).0, None);
        assert_eq!(s.handle(&frame(0x4C, &[]), &ID, UNCONFIGURED).0, Some(frame(0x50, &[])));
    }

    #[test]
    fn identify_remote_slave_answers_inside_the_ranges() {
        let mut s = LssSlave::default();
        let bounds = [ID[0], ID[1], ID[2], ID[2], ID[3] - 1, ID[3] + 1];
        let mut last = None;
        for (i, b) in bounds.iter().enumerate() {
            last = s.handle(&frame(0x46 + i as u8, &b.to_le_bytes()), &ID, 5).0;
        }
        assert_eq!(last, Some(frame(0x4F, &[])));
        let outside = [ID[0], ID[1], ID[2], ID[2], ID[3] + 1, ID[3] + 2];
        for (i, b) in outside.iter().enumerate() {
            last = s.handle(&frame(0x46 + i as u8, &b.to_le_bytes()), &ID, 5).0;
        }
        assert_eq!(last, None);
    }
}
