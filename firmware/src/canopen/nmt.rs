//! The NMT slave (CiA 301 §7.3.2): the states, the commands, and which services each state enables.
//!
//! After power-on or a reset the node is in «Initialisation»; when it has finished (the node's next poll), it
//! sends the boot-up message (COB-ID 0x700 + node-ID, one byte 0x00) and enters «Pre-operational» on its own
//! (CiA 301 §7.3.2.2.1; E4 L3190-L3232). The NMT master's commands (COB-ID 0x000, byte 0 command specifier,
//! byte 1 node-ID or 0 for all; E4 Table 5-52 L3195-L3223) move it:
//!
//! | CS | Command | From | To |
//! |---|---|---|---|
//! | 0x01 | start remote node | pre-operational, stopped | operational |
//! | 0x02 | stop remote node | pre-operational, operational | stopped |
//! | 0x80 | enter pre-operational | operational, stopped | pre-operational |
//! | 0x81 | reset node | any | initialisation (application and communication reset) |
//! | 0x82 | reset communication | any | initialisation (communication reset) |
//!
//! Services per state (CiA 301 Table 88; [`NmtState::allows`]): NMT in every state; SDO, SYNC and EMCY in
//! pre-operational and operational; PDO only in operational; the heartbeat (error control) in pre-operational,
//! operational and stopped; the boot-up message only on leaving initialisation. A command frame of any other
//! length than 2 bytes or with an unknown specifier is ignored (an NMT command is unconfirmed, CiA 301
//! §7.2.8.3.1: there is nobody to answer).

use crate::od::access::CommState;

/// The NMT states of a slave.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum NmtState {
    /// Resetting and booting; nothing but the boot-up message leaves the node.
    Initialisation,
    /// Configuration by SDO; no PDOs.
    PreOperational,
    /// Everything runs.
    Operational,
    /// Only NMT and the heartbeat.
    Stopped,
}

/// A CiA 301 communication service, for [`NmtState::allows`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Service {
    /// Process data objects.
    Pdo,
    /// Service data objects.
    Sdo,
    /// SYNC consumption.
    Sync,
    /// Emergency production.
    Emcy,
    /// Heartbeat production and consumption (error control).
    ErrorControl,
    /// NMT commands.
    Nmt,
}

impl NmtState {
    /// The state code of the heartbeat (E4 Table 5-54 L3585-L3596): 0x00 boot-up, 0x04 stopped, 0x05
    /// operational, 0x7F pre-operational.
    pub const fn heartbeat_code(self) -> u8 {
        match self {
            Self::Initialisation => 0x00,
            Self::Stopped => 0x04,
            Self::Operational => 0x05,
            Self::PreOperational => 0x7F,
        }
    }

    /// Whether `service` runs in this state (CiA 301 Table 88).
    pub const fn allows(self, service: Service) -> bool {
        match (self, service) {
            (Self::Initialisation, _) => false,
            (_, Service::Nmt | Service::ErrorControl) => true,
            (Self::Operational, _) => true,
            (Self::PreOperational, Service::Sdo | Service::Sync | Service::Emcy) => true,
            (Self::PreOperational, Service::Pdo) => false,
            (Self::Stopped, _) => false,
        }
    }

    /// The state the dictionary judges SDO writes in ([`CommState`]: PDO mapping only in pre-operational).
    pub const fn comm_state(self) -> CommState {
        match self {
            Self::Initialisation => CommState::Init,
            Self::PreOperational => CommState::PreOperational,
            Self::Operational => CommState::Operational,
            Self::Stopped => CommState::Stopped,
        }
    }
}

/// The two resets (CiA 301 §7.3.2.2.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ResetKind {
    /// Reset node: the application parameters (0x2000..0x9FFF) and the communication parameters.
    Node,
    /// Reset communication: the communication parameters (0x1000..0x1FFF) only.
    Communication,
}

/// An NMT command (CiA 301 §7.2.8.3.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum NmtCommand {
    /// 0x01 start remote node.
    Start,
    /// 0x02 stop remote node.
    Stop,
    /// 0x80 enter pre-operational.
    EnterPreOperational,
    /// 0x81 reset node.
    ResetNode,
    /// 0x82 reset communication.
    ResetCommunication,
}

impl NmtCommand {
    /// The command of a frame on COB-ID 0x000 if it is addressed to `node_id` (or to all, node-ID 0); `None` for
    /// another node, a length other than 2 or an unknown command specifier.
    pub fn parse(data: &[u8], node_id: u8) -> Option<Self> {
        let [cs, target] = data else {
            return None;
        };
        if *target != 0 && *target != node_id {
            return None;
        }
        match cs {
            0x01 => Some(Self::Start),
            0x02 => Some(Self::Stop),
            0x80 => Some(Self::EnterPreOperational),
            0x81 => Some(Self::ResetNode),
            0x82 => Some(Self::ResetCommunication),
            _ => None,
        }
    }

    /// The command specifier byte.
    pub const fn specifier(self) -> u8 {
        match self {
            Self::Start => 0x01,
            Self::Stop => 0x02,
            Self::EnterPreOperational => 0x80,
            Self::ResetNode => 0x81,
            Self::ResetCommunication => 0x82,
        }
    }
}

/// The NMT slave state machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Nmt {
    state: NmtState,
    /// The reset to carry out while in initialisation (`None`: done, the boot-up message is due).
    reset: Option<ResetKind>,
}

impl Default for Nmt {
    fn default() -> Self {
        Self::new()
    }
}

impl Nmt {
    /// Power-on: initialisation with a node reset to carry out.
    pub const fn new() -> Self {
        Self { state: NmtState::Initialisation, reset: Some(ResetKind::Node) }
    }

    /// The state.
    pub const fn state(&self) -> NmtState {
        self.state
    }

    /// The reset still to be carried out in initialisation.
    pub const fn pending_reset(&self) -> Option<ResetKind> {
        self.reset
    }

    /// The reset has been carried out; the boot-up message is due.
    pub fn reset_done(&mut self) {
        self.reset = None;
    }

    /// The boot-up message has been queued: initialisation ends in pre-operational (CiA 301 §7.3.2.2.1).
    pub fn booted(&mut self) {
        if self.state == NmtState::Initialisation && self.reset.is_none() {
            self.state = NmtState::PreOperational;
        }
    }

    /// An unconfigured node got its node-ID through LSS (CiA 305 §5): it carries out a reset communication for
    /// it and boots, from initialisation, where it waited.
    pub fn restart_communication(&mut self) {
        self.state = NmtState::Initialisation;
        self.reset = Some(ResetKind::Communication);
    }

    /// Applies `command`. Commands are ignored in initialisation (the node is not on the bus yet); a reset
    /// restarts initialisation even if one is under way.
    pub fn command(&mut self, command: NmtCommand) {
        if self.state == NmtState::Initialisation {
            return;
        }
        match command {
            NmtCommand::Start => self.state = NmtState::Operational,
            NmtCommand::Stop => self.state = NmtState::Stopped,
            NmtCommand::EnterPreOperational => self.state = NmtState::PreOperational,
            NmtCommand::ResetNode => {
                self.state = NmtState::Initialisation;
                self.reset = Some(ResetKind::Node);
            }
            NmtCommand::ResetCommunication => {
                self.state = NmtState::Initialisation;
                self.reset = Some(ResetKind::Communication);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_move_through_the_states() {
        let mut nmt = Nmt::new();
        nmt.command(NmtCommand::Start);
        assert_eq!(nmt.state(), NmtState::Initialisation, "ignored before boot-up");
        nmt.booted();
        assert_eq!(nmt.state(), NmtState::Initialisation, "not before the reset is done");
        nmt.reset_done();
        nmt.booted();
        assert_eq!(nmt.state(), NmtState::PreOperational);
        nmt.command(NmtCommand::Start);
        assert_eq!(nmt.state(), NmtState::Operational);
        nmt.command(NmtCommand::Stop);
        assert_eq!(nmt.state(), NmtState::Stopped);
        nmt.command(NmtCommand::EnterPreOperational);
        assert_eq!(nmt.state(), NmtState::PreOperational);
        nmt.command(NmtCommand::ResetCommunication);
        assert_eq!((nmt.state(), nmt.pending_reset()), (NmtState::Initialisation, Some(ResetKind::Communication)));
    }

    #[test]
    fn parse_checks_length_target_and_specifier() {
        assert_eq!(NmtCommand::parse(&[0x01, 0], 5), Some(NmtCommand::Start));
        assert_eq!(NmtCommand::parse(&[0x82, 5], 5), Some(NmtCommand::ResetCommunication));
        assert_eq!(NmtCommand::parse(&[0x01, 6], 5), None);
        assert_eq!(NmtCommand::parse(&[0x01], 5), None);
        assert_eq!(NmtCommand::parse(&[0x01, 5, 0], 5), None);
        assert_eq!(NmtCommand::parse(&[0x03, 5], 5), None);
    }

    #[test]
    fn services_follow_table_88() {
        use Service::*;
        let s = NmtState::PreOperational;
        assert!(s.allows(Sdo) && s.allows(Sync) && s.allows(Emcy) && s.allows(ErrorControl) && !s.allows(Pdo));
        let o = NmtState::Operational;
        assert!(o.allows(Pdo) && o.allows(Sdo));
        let t = NmtState::Stopped;
        assert!(!t.allows(Sdo) && !t.allows(Pdo) && !t.allows(Emcy) && !t.allows(Sync));
        assert!(t.allows(ErrorControl) && t.allows(Nmt));
        assert!(!NmtState::Initialisation.allows(Nmt));
    }
}
