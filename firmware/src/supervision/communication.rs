//! Communication supervision: the one interface through which the fieldbus layers report a lost or restored
//! link, and the process-data watchdog they share (issue 5: "communication supervision inputs from the fieldbuses
//! (heartbeat/PDO/SYNC loss, EtherCAT watchdog) through one interface, so the fieldbus issues only report the
//! event").
//!
//! A fieldbus layer detects; the drive reacts. The CANopen layer reports a consumer-heartbeat timeout (0x1016), an
//! RPDO or SYNC that stopped arriving, a PDO or SYNC of the wrong length; the EtherCAT layer reports its
//! sync-manager watchdog, a lost link and synchronisation errors. Each becomes the fault of the table
//! ([`LinkLoss::fault`]); the communication faults have the reaction class "a", so the CiA 402 machine carries out
//! the abort connection option code 0x6007 (IDX L5496: 0 none, 1 fault, 2 disable voltage, 3 quick stop; digest
//! `comms-faults-bootloader.md` §3.4) through `cia402::Inputs::connection_lost`, and the fault stays until a
//! fault reset after the link is back (IDX L7340-L7436: class "a" errors are reset with the controlword).
//!
//! [`ProcessDataWatchdog`] is the timing both buses need for "no process data within the expected time": the
//! layer calls [`ProcessDataWatchdog::received`] when a set-point frame arrives and [`ProcessDataWatchdog::tick`]
//! once per slow tick; it reports [`WatchdogEvent::Expired`] once when the time runs out and
//! [`WatchdogEvent::Restored`] when data flows again. It arms at the first frame, so a master that has not started
//! sending yet is not a loss.

use crate::cia402::Ticks;
use crate::fault::table::FaultId;

/// A communication loss a fieldbus layer reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LinkLoss {
    /// A supervised producer's heartbeat (CiA 301 0x1016) or the node guarding timed out; the producer's node-ID.
    HeartbeatLost {
        /// Node-ID of the silent producer.
        node: u8,
    },
    /// No RxPDO (or no SYNC) arrived within the expected time while process data was expected.
    RxPdoTimeout,
    /// The EtherCAT sync-manager (process-data) watchdog expired or the link was lost in SAFE-OP/OP.
    EthercatWatchdog,
    /// The EtherCAT cycle or SYNC0 events were missed or out of tolerance (0x1C32/0x1C33 counters).
    EthercatSyncError,
    /// A received PDO was shorter than its mapping; the received length in bytes.
    PdoLength {
        /// Bytes received.
        received: u16,
    },
    /// A CANopen SYNC arrived with an unexpected data length (CiA 301: 0 or 1 byte with the counter).
    CanSyncLength {
        /// Bytes received.
        received: u8,
    },
    /// The CAN controller is error passive (an error counter above 127, ISO 11898-1 §12.1.4): it no longer
    /// signals errors it sees, typically a wrong bit rate elsewhere or a bus without termination.
    CanErrorPassive {
        /// The transmit error counter when it went passive.
        transmit_errors: u8,
    },
    /// The CAN controller is bus-off (transmit error counter above 255): it neither sends nor receives until it
    /// has seen 128 x 11 recessive bits (it rejoins on its own).
    CanBusOff,
    /// Received frames were lost because the controller's receive FIFO was full.
    CanRxOverrun {
        /// Frames lost since the last report.
        lost: u32,
    },
}

impl LinkLoss {
    /// The fault of the table this loss raises.
    #[must_use]
    pub const fn fault(self) -> FaultId {
        match self {
            Self::HeartbeatLost { .. } => FaultId::HeartbeatLost,
            Self::RxPdoTimeout => FaultId::RxPdoTimeout,
            Self::EthercatWatchdog => FaultId::EthercatWatchdog,
            Self::EthercatSyncError => FaultId::EthercatSyncError,
            Self::PdoLength { .. } => FaultId::PdoLength,
            Self::CanSyncLength { .. } => FaultId::CanSyncLength,
            Self::CanErrorPassive { .. } => FaultId::CanErrorPassive,
            Self::CanBusOff => FaultId::CanBusOff,
            Self::CanRxOverrun { .. } => FaultId::CanRxOverrun,
        }
    }

    /// The value the diagnosis snapshot (and the EMCY's bytes 4..7) carries: the node-ID or the length received,
    /// 0 where the loss has no measured value.
    #[must_use]
    pub fn detail(self) -> i32 {
        match self {
            Self::HeartbeatLost { node } => i32::from(node),
            Self::PdoLength { received } => i32::from(received),
            Self::CanSyncLength { received } => i32::from(received),
            Self::CanErrorPassive { transmit_errors } => i32::from(transmit_errors),
            Self::CanRxOverrun { lost } => i32::try_from(lost).unwrap_or(i32::MAX),
            Self::RxPdoTimeout | Self::EthercatWatchdog | Self::EthercatSyncError | Self::CanBusOff => 0,
        }
    }
}

/// What [`ProcessDataWatchdog::tick`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WatchdogEvent {
    /// Nothing changed.
    None,
    /// The timeout just ran out (reported once per loss).
    Expired,
    /// Data arrived again after an expiry.
    Restored,
}

/// A process-data watchdog counted in slow ticks. See the module documentation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ProcessDataWatchdog {
    /// Timeout in slow ticks; 0 disables the watchdog.
    timeout: u32,
    /// Slow ticks since the last frame.
    silent: u32,
    /// A frame arrived since the watchdog was (re)configured.
    armed: bool,
    /// A frame arrived since the last tick.
    fresh: bool,
    expired: bool,
}

impl ProcessDataWatchdog {
    /// A watchdog with `timeout` (zero: disabled), not armed.
    #[must_use]
    pub const fn new(timeout: Ticks) -> Self {
        Self { timeout: timeout.0, silent: 0, armed: false, fresh: false, expired: false }
    }

    /// Changes the timeout (zero disables) and disarms until the next frame.
    pub fn configure(&mut self, timeout: Ticks) {
        *self = Self::new(timeout);
    }

    /// A process-data frame arrived.
    pub fn received(&mut self) {
        self.armed = true;
        self.fresh = true;
    }

    /// Whether the timeout has run out and no frame came since.
    #[must_use]
    pub const fn expired(&self) -> bool {
        self.expired
    }

    /// One slow tick: counts the silence, reports an expiry once and a restoration once.
    pub fn tick(&mut self) -> WatchdogEvent {
        if core::mem::take(&mut self.fresh) {
            self.silent = 0;
            if core::mem::take(&mut self.expired) {
                return WatchdogEvent::Restored;
            }
            return WatchdogEvent::None;
        }
        if self.timeout == 0 || !self.armed || self.expired {
            return WatchdogEvent::None;
        }
        self.silent = self.silent.saturating_add(1);
        if self.silent >= self.timeout {
            self.expired = true;
            return WatchdogEvent::Expired;
        }
        WatchdogEvent::None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expires_once_after_the_timeout_and_restores_on_the_next_frame() {
        let mut w = ProcessDataWatchdog::new(Ticks(5));
        // Not armed before the first frame: silence is no loss.
        for _ in 0..20 {
            assert_eq!(w.tick(), WatchdogEvent::None);
        }
        w.received();
        assert_eq!(w.tick(), WatchdogEvent::None);
        for _ in 0..4 {
            assert_eq!(w.tick(), WatchdogEvent::None);
        }
        assert_eq!(w.tick(), WatchdogEvent::Expired, "the fifth silent tick");
        assert!(w.expired());
        for _ in 0..10 {
            assert_eq!(w.tick(), WatchdogEvent::None, "reported once");
        }
        w.received();
        assert_eq!(w.tick(), WatchdogEvent::Restored);
        assert!(!w.expired());
    }

    #[test]
    fn frames_within_the_timeout_keep_it_quiet_and_zero_disables() {
        let mut w = ProcessDataWatchdog::new(Ticks(3));
        for _ in 0..100 {
            w.received();
            assert_eq!(w.tick(), WatchdogEvent::None);
            assert_eq!(w.tick(), WatchdogEvent::None);
        }
        let mut off = ProcessDataWatchdog::new(Ticks(0));
        off.received();
        for _ in 0..100 {
            assert_eq!(off.tick(), WatchdogEvent::None);
        }
    }

    #[test]
    fn every_loss_maps_to_a_communication_fault_of_class_a() {
        use crate::fault::table::ReactionClass;
        for loss in [
            LinkLoss::HeartbeatLost { node: 5 },
            LinkLoss::RxPdoTimeout,
            LinkLoss::EthercatWatchdog,
            LinkLoss::EthercatSyncError,
            LinkLoss::PdoLength { received: 3 },
            LinkLoss::CanSyncLength { received: 2 },
        ] {
            assert_eq!(loss.fault().info().reaction, ReactionClass::AbortConnection, "{loss:?}");
        }
        assert_eq!(LinkLoss::HeartbeatLost { node: 5 }.detail(), 5);
        assert_eq!(LinkLoss::PdoLength { received: 3 }.detail(), 3);
    }
}
