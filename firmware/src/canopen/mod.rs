//! The drive as a CANopen node (CiA 301 + CiA 402 over CAN; issue 8): NMT slave, SDO server, 4 RPDO and 4 TPDO,
//! SYNC consumer, EMCY producer, heartbeat producer and consumers, all on the one dictionary and the one SDO core
//! the EtherCAT side uses ([`crate::comm::sdo::server::SdoServer`], [`crate::comm::pdo`]).
//!
//! Sans-IO (ARCHITECTURE convention 1): frames in ([`CanopenNode::handle_frame`]), frames out
//! ([`CanopenNode::transmit`]) and time (`now_us`, a monotonic microsecond clock); [`CanopenNode::poll`] does all
//! three over a [`CanBus`] (the board's bxCAN driver, the simulator's bus).
//!
//! | File | Job |
//! |---|---|
//! | [`frame`] | the CAN frame, the bit rates, the [`CanBus`] trait |
//! | [`nmt`] | NMT states and commands, what each state allows |
//! | [`ids`] | node-ID, bit rate, COB-IDs, reset of the communication parameters |
//! | [`guard`] | the CANopen-specific SDO write rules (PDO valid bits, 8-byte PDOs, 0x1016, 0x1019) |
//! | [`pdo`] | RPDOs and TPDOs |
//! | [`sync`] | SYNC consumer and its supervision |
//! | [`emcy`] | EMCY producer |
//! | [`heartbeat`] | heartbeat producer and consumers |
//! | [`lss`] | the LSS slave (CiA 305): node-ID and bit rate assigned by the master, fastscan |
//!
//! **Who calls what (tiers, ARCHITECTURE).**
//! - Tier 3 (background, at least every millisecond): [`CanopenNode::poll`], or [`CanopenNode::handle_frame`] for
//!   the frames received, then [`CanopenNode::process`] and [`CanopenNode::transmit`]. NMT, SDO, heartbeat,
//!   EMCY, event-driven TPDOs, deadlines and the resets run here.
//! - The SYNC path may run at tier 2 (the CAN receive interrupt at the motion loop's priority): a frame for which
//!   [`CanopenNode::is_realtime`] holds (SYNC or an RPDO) is handed to [`CanopenNode::handle_frame`] there; it
//!   copies an RPDO's bytes, or at a SYNC packs the synchronous TPDOs into the transmit queue and unpacks the
//!   RPDOs received since the previous SYNC (no search, no division: [`pdo::Pdos::on_sync`]). Every other frame is
//!   left to tier 3. The runtime must not run both paths at once on one node (the target's tier 2 preempts tier
//!   3, so tier 3 masks the CAN interrupt around its calls).
//!
//! **Resets** (CiA 301 §7.3.2.2.1). An NMT reset (and power-on, [`CanopenNode::new`]) puts the node into
//! initialisation; its next [`CanopenNode::process`] carries the reset out and returns [`NodeEvent::Reset`]:
//! - reset communication: the node-ID 0x2000 asks for becomes the node-ID; the writable communication parameters
//!   0x1000..0x1FFF go back to their power-on values for it: the defaults ([`ids::reset_communication_parameters`]),
//!   then the values saved with 0x1010 from the parameter store, through the application objects
//!   ([`ApplicationObjects::reload_communication`]), as a power cycle would load them; the SDO transfer
//!   in progress, the PDO data, the SYNC and heartbeat supervision are dropped, and the communication losses
//!   reported are restored (IDX L7336-L7350: reset communication is the recovery of the CAN errors);
//! - reset node: first the power stage goes to a safe state (controlword 0x6040 = 0 "disable voltage" and
//!   [`FieldbusDevice::shutdown`]: outputs off, the motor coasts), then as reset communication. The application part
//!   (0x2000..0x9FFF back to their power-on values) is the runtime's, told by the event: on the target it restarts
//!   the microcontroller, which loads the parameter store; the event also carries the bit rate 0x2001 asks for.
//!
//! The next [`CanopenNode::process`] reads the configuration, sends the boot-up message and enters
//! pre-operational ([`NodeEvent::Booted`]). Frames received during initialisation are ignored.
//!
//! A COB-ID saved with its `$NODEID+` default is stored as the value it had, like every other parameter: after a
//! change of the node-ID the saved COB-IDs keep the old node-ID until they are saved again (or restored with
//! 0x1011).
//!
//! **Unconfigured** (CiA 305 §5): a node whose node-ID is [`lss::UNCONFIGURED`] (0x2000 = 0xFF, stored or
//! configured through LSS) carries out its power-on reset and then waits in initialisation, silent except for LSS,
//! until an LSS master gives it a node-ID and switches it back to the waiting state: then it resets its
//! communication with that node-ID and boots. A configured node takes a node-ID configured through LSS at its next
//! reset communication, as one written to 0x2000.
//!
//! **Frames nobody expects** are ignored without an answer, as CiA 301 has no reply for them: unknown COB-IDs,
//! an NMT frame that is not 2 bytes, SDO frames that are not 8 bytes, anything in a state that does not allow
//! the service (SDO in stopped, PDOs outside operational). An RPDO shorter than its mapping and a SYNC of the
//! wrong length are reported (EMCY 0x8210, 0x8240) and not processed.

pub mod emcy;
pub mod frame;
pub mod guard;
pub mod heartbeat;
pub mod ids;
pub mod lss;
pub mod nmt;
pub mod pdo;
pub mod sync;

use heapless::Deque;

use self::emcy::EmcyProducer;
use self::frame::{BitRate, BusState, BusStatus, CanBus, CanFrame};
use self::heartbeat::{Heartbeat, HeartbeatEvent};
use self::lss::{LssAction, LssSlave};
use self::nmt::{Nmt, NmtCommand, NmtState, ResetKind, Service};
use self::pdo::{FrameSink, Pdos};
use self::sync::{SyncConsumer, SyncEvent};
use crate::comm::device::FieldbusDevice;
use crate::comm::sdo::server::{abort_frame, SdoServer};
use crate::od::access::{AccessContext, ApplicationObjects};
use crate::od::generated::{handles, MAX_PDO_BYTES_ETHERCAT};
use crate::supervision::communication::LinkLoss;

/// Frames the transmit queue holds: a SYNC's four TPDOs, a block-upload burst, EMCYs and the heartbeat.
pub const OUTBOX_LEN: usize = 32;

/// Frames one [`CanopenNode::poll`] takes from the bus at most (bounded work per call).
pub const RX_PER_POLL: usize = 32;

/// What a [`CanopenNode::process`] reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum NodeEvent {
    /// A reset was carried out (see the module documentation); the node boots at the next process.
    Reset {
        /// Which reset.
        kind: ResetKind,
        /// The node-ID from now on.
        node_id: u8,
        /// For a reset node: the bit rate 0x2001 asks for (the runtime reprograms the controller).
        bit_rate: Option<BitRate>,
    },
    /// The boot-up message is queued; the node is pre-operational.
    Booted,
    /// LSS activate bit timing (CiA 305 §6.4.3): the first silent period is over and the node now runs at this
    /// bit rate (the runtime reprograms the controller); it stays silent for the switch delay again.
    BitRateSwitched(BitRate),
}

/// An LSS bit-rate switch under way (CiA 305 §6.4.3): the node sends nothing until `resume_at_us`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct BitRateSwitch {
    rate: BitRate,
    /// End of the first silent period: the node switches.
    switch_at_us: u64,
    /// End of the second: the node transmits again.
    resume_at_us: u64,
    switched: bool,
}

/// The transmit queue.
#[derive(Clone, Debug, Default)]
struct Outbox {
    queue: Deque<CanFrame, OUTBOX_LEN>,
    dropped: u32,
}

impl FrameSink for Outbox {
    fn push(&mut self, frame: CanFrame) -> bool {
        if self.queue.push_back(frame).is_err() {
            self.dropped = self.dropped.wrapping_add(1);
            return false;
        }
        true
    }

    fn room(&self) -> usize {
        OUTBOX_LEN.saturating_sub(self.queue.len())
    }
}

/// Node counters for diagnosis and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NodeCounters {
    /// Frames ignored (unknown COB-ID, wrong length, service not allowed in the state).
    pub ignored: u32,
    /// Frames lost because the transmit queue was full.
    pub tx_dropped: u32,
    /// SYNCs received.
    pub syncs: u32,
    /// SYNCs missed (supervision 0x1006).
    pub syncs_missed: u32,
}

/// The CANopen node. See the module documentation.
#[derive(Clone, Debug)]
pub struct CanopenNode {
    node_id: u8,
    nmt: Nmt,
    sdo: SdoServer,
    /// A block download's sub-block may be under way: every frame is a segment, none is checked by the guard.
    block_download: bool,
    pdos: Pdos,
    sync: SyncConsumer,
    emcy: EmcyProducer,
    heartbeat: Heartbeat,
    outbox: Outbox,
    /// A SYNC loss reported to the drive and not yet restored.
    sync_lost: bool,
    last_state: NmtState,
    ignored: u32,
    /// The power-on reset has been carried out.
    powered_on: bool,
    /// What the CAN controller reported last ([`CanopenNode::observe_bus`]).
    bus: BusStatus,
    lss: LssSlave,
    bit_rate_switch: Option<BitRateSwitch>,
}

impl CanopenNode {
    /// A node at power-on, in initialisation, with the node-ID the runtime chose (the stored 0x2000 or switches);
    /// [`lss::UNCONFIGURED`] leaves it unconfigured (module documentation), any other `node_id` outside 1..=127
    /// is replaced by the default node-ID 1. The power-on reset writes it to 0x2000; the
    /// node-ID written to 0x2000 later takes over at the next NMT reset.
    #[must_use]
    pub fn new(node_id: u8) -> Self {
        Self {
            node_id: if ids::is_node_id(node_id) || node_id == lss::UNCONFIGURED {
                node_id
            } else {
                ids::DEFAULT_NODE_ID
            },
            nmt: Nmt::new(),
            sdo: SdoServer::default(),
            block_download: false,
            pdos: Pdos::default(),
            sync: SyncConsumer::default(),
            emcy: EmcyProducer::default(),
            heartbeat: Heartbeat::default(),
            outbox: Outbox::default(),
            sync_lost: false,
            last_state: NmtState::Initialisation,
            ignored: 0,
            powered_on: false,
            bus: BusStatus::default(),
            lss: LssSlave::default(),
            bit_rate_switch: None,
        }
    }

    /// The node-ID in use.
    #[must_use]
    pub const fn node_id(&self) -> u8 {
        self.node_id
    }

    /// The NMT state.
    #[must_use]
    pub const fn state(&self) -> NmtState {
        self.nmt.state()
    }

    /// The counters.
    #[must_use]
    pub fn counters(&self) -> NodeCounters {
        NodeCounters {
            ignored: self.ignored,
            tx_dropped: self.outbox.dropped,
            syncs: self.sync.received(),
            syncs_missed: self.sync.missed(),
        }
    }

    /// The SDO server (transfer state).
    #[must_use]
    pub const fn sdo(&self) -> &SdoServer {
        &self.sdo
    }

    /// Frames waiting to be sent.
    #[must_use]
    pub fn pending_frames(&self) -> usize {
        self.outbox.queue.len()
    }

    /// Whether `frame` belongs to the SYNC path that may run at tier 2 (the SYNC or a valid RPDO's COB-ID).
    #[must_use]
    pub fn is_realtime(&self, frame: &CanFrame) -> bool {
        !frame.is_remote() && (frame.id() == self.sync.cob_id() || self.pdos.rpdo_for(frame.id()).is_some())
    }

    /// The next frame to send, oldest first; none while an LSS bit-rate switch keeps the node silent.
    pub fn transmit(&mut self) -> Option<CanFrame> {
        if self.bit_rate_switch.is_some() {
            return None;
        }
        self.outbox.queue.pop_front()
    }

    /// Tier 3 with a bus: takes up to [`RX_PER_POLL`] received frames, runs [`CanopenNode::process`], and hands
    /// the queued frames to the bus while it takes them (the rest wait for the next poll).
    pub fn poll<D: FieldbusDevice + ?Sized, B: CanBus, A: ApplicationObjects + ?Sized>(
        &mut self,
        bus: &mut B,
        drive: &mut D,
        app: &mut A,
        now_us: u64,
    ) -> Option<NodeEvent> {
        self.observe_bus(bus.status(), drive);
        for _ in 0..RX_PER_POLL {
            let Some(frame) = bus.receive() else {
                break;
            };
            self.handle_frame(&frame, drive, app, now_us);
        }
        let event = self.process(drive, app, now_us);
        if event == Some(NodeEvent::Booted) {
            ids::write(drive.dictionary_mut(), ids::BIT_RATE_DISPLAY, 0, u64::from(bus.bit_rate().code()));
        }
        while let Some(frame) = self.outbox.queue.front().filter(|_| self.bit_rate_switch.is_none()) {
            if bus.send(frame).is_err() {
                break;
            }
            self.outbox.queue.pop_front();
        }
        event
    }

    /// The CAN controller's state, as tier 3 reads it before each poll: error passive (0x8120) and bus-off
    /// (0x81FD) are reported to the drive as communication losses when the controller enters them and as restored
    /// when it leaves them (the controller rejoins the bus on its own after bus-off: ISO 11898-1 §12.1.4.2, the
    /// automatic bus-off management of `board::can`), and frames the receive FIFO lost as an overrun (0x8110,
    /// with the number lost). The reaction is 0x6007's, as for every communication fault; the faults stay
    /// until a fault reset once the cause is gone (IDX 7.2.26, 7.2.28, 7.2.36). Their EMCYs wait in the queue
    /// while the controller is off the bus and leave when it is back.
    pub fn observe_bus<D: FieldbusDevice + ?Sized>(&mut self, status: BusStatus, drive: &mut D) {
        let last = core::mem::replace(&mut self.bus, status);
        let passive = |s: &BusStatus| s.state == BusState::ErrorPassive;
        let off = |s: &BusStatus| s.state == BusState::BusOff;
        if off(&last) && !off(&status) {
            drive.communication_restored(LinkLoss::CanBusOff);
        }
        if passive(&last) && !passive(&status) {
            drive.communication_restored(LinkLoss::CanErrorPassive { transmit_errors: status.transmit_errors });
        }
        if passive(&status) && !passive(&last) {
            drive.communication_lost(LinkLoss::CanErrorPassive { transmit_errors: status.transmit_errors });
        }
        if off(&status) && !off(&last) {
            drive.communication_lost(LinkLoss::CanBusOff);
        }
        let lost = status.rx_overruns.wrapping_sub(last.rx_overruns);
        if lost > 0 {
            drive.communication_lost(LinkLoss::CanRxOverrun { lost });
        }
    }

    /// One received frame (see the module documentation for which tier calls it for which frame).
    pub fn handle_frame<D: FieldbusDevice + ?Sized, A: ApplicationObjects + ?Sized>(
        &mut self,
        frame: &CanFrame,
        drive: &mut D,
        app: &mut A,
        now_us: u64,
    ) {
        let state = self.nmt.state();
        let id = frame.id();
        if state == NmtState::Initialisation {
            // LSS serves an unconfigured node, which waits here (module documentation).
            self.lss_or_ignore(frame, drive, app, now_us);
            return;
        }
        if id == ids::NMT {
            match (frame.is_remote(), NmtCommand::parse(frame.data(), self.node_id)) {
                (false, Some(command)) => {
                    self.nmt.command(command);
                    self.follow_state(drive);
                }
                _ => self.ignore(),
            }
            return;
        }
        if frame.is_remote() {
            // A remote request for a TPDO that allows RTR (COB-ID bit 30 clear), in operational.
            match self.pdos.tpdo_for(id).filter(|_| state.allows(Service::Pdo)) {
                Some(n) => {
                    if let Some(reply) = self.pdos.remote_request(n, drive, now_us) {
                        let _ = self.outbox.push(reply);
                    }
                }
                None => self.ignore(),
            }
            return;
        }
        if id == self.sync.cob_id() && state.allows(Service::Sync) {
            self.on_sync(frame.data(), drive, now_us);
            return;
        }
        if id == ids::cob_id(ids::SDO_RX_BASE, self.node_id) && state.allows(Service::Sdo) {
            self.on_sdo(frame.data(), drive, app, now_us);
            return;
        }
        if let (0x701..=0x77F, [_]) = (id, frame.data()) {
            if state.allows(Service::ErrorControl) {
                let node = u8::try_from(id.wrapping_sub(ids::HEARTBEAT_BASE)).unwrap_or(0);
                if let Some(HeartbeatEvent::Restored(loss)) = self.heartbeat.on_heartbeat(node, now_us) {
                    drive.communication_restored(loss);
                }
                return;
            }
        }
        if state.allows(Service::Pdo) {
            if let Some(n) = self.pdos.rpdo_for(id) {
                let _ = self.pdos.receive(n, frame.data(), drive, now_us);
                return;
            }
        }
        // Last: LSS frames are rare, and the SYNC path above must not pay for their check.
        self.lss_or_ignore(frame, drive, app, now_us);
    }

    /// An LSS request (0x7E5, 8 bytes) to the LSS slave; any other frame is ignored.
    fn lss_or_ignore<D: FieldbusDevice + ?Sized, A: ApplicationObjects + ?Sized>(
        &mut self,
        frame: &CanFrame,
        drive: &mut D,
        app: &mut A,
        now_us: u64,
    ) {
        match <&[u8; 8]>::try_from(frame.data()) {
            Ok(data) if frame.id() == lss::MASTER_TO_SLAVE && !frame.is_remote() => {
                self.on_lss(data, drive, app, now_us);
            }
            _ => self.ignore(),
        }
    }

    /// Tier 3 without a bus: the reset and boot in initialisation, else the SDO server's own frames (block-upload
    /// segments, timeout), EMCYs, the SYNC supervision, the event-driven TPDOs and RPDO deadlines, the heartbeat.
    pub fn process<D: FieldbusDevice + ?Sized, A: ApplicationObjects + ?Sized>(
        &mut self,
        drive: &mut D,
        app: &mut A,
        now_us: u64,
    ) -> Option<NodeEvent> {
        if let Some(switch) = self.bit_rate_switch.as_mut() {
            // CiA 305 §6.4.3: silent for the switch delay, the switch, silent for it again; the other services
            // wait (what they queue is sent after the second period).
            if !switch.switched && now_us >= switch.switch_at_us {
                switch.switched = true;
                let rate = switch.rate;
                ids::write(drive.dictionary_mut(), ids::BIT_RATE_DISPLAY, 0, u64::from(rate.code()));
                return Some(NodeEvent::BitRateSwitched(rate));
            }
            if now_us < switch.resume_at_us {
                return None;
            }
            self.bit_rate_switch = None;
        }
        let state = self.nmt.state();
        if state == NmtState::Initialisation {
            if let Some(kind) = self.nmt.pending_reset() {
                let bit_rate = self.reset(kind, drive, app);
                self.nmt.reset_done();
                return Some(NodeEvent::Reset { kind, node_id: self.node_id, bit_rate });
            }
            if self.node_id == lss::UNCONFIGURED {
                // Waits for an LSS master (module documentation).
                return None;
            }
            self.boot(drive, now_us);
            return Some(NodeEvent::Booted);
        }
        if state.allows(Service::Sdo) {
            while self.outbox.room() > 0 {
                let Some(frame) = self.sdo.poll(now_us, drive.dictionary_mut(), app) else {
                    break;
                };
                self.send_sdo(frame);
            }
            if !self.sdo.is_busy() {
                self.block_download = false;
            }
        }
        if state.allows(Service::Emcy) {
            self.emcy.poll(drive, &mut self.outbox);
        }
        if state.allows(Service::Sync) {
            if let Some(loss) = self.sync.poll(now_us) {
                drive.communication_lost(loss);
                self.sync_lost = true;
            }
        }
        if state.allows(Service::Pdo) {
            self.pdos.poll_events(drive, now_us, &mut self.outbox);
        }
        if let Some(frame) = self.heartbeat.produce(now_us, self.node_id, state.heartbeat_code()) {
            let _ = self.outbox.push(frame);
        }
        if let Some(HeartbeatEvent::Lost(loss)) = self.heartbeat.poll(now_us) {
            drive.communication_lost(loss);
        }
        None
    }

    fn ignore(&mut self) {
        self.ignored = self.ignored.wrapping_add(1);
    }

    /// An LSS request (CiA 305): the slave's answer, and what it asks of the node carried out here.
    fn on_lss<D: FieldbusDevice + ?Sized, A: ApplicationObjects + ?Sized>(
        &mut self,
        data: &[u8; 8],
        drive: &mut D,
        app: &mut A,
        now_us: u64,
    ) {
        let d = drive.dictionary();
        let identity = [1, 2, 3, 4].map(|sub| ids::read_u32(d, 0x1018, sub));
        let (answer, action) = self.lss.handle(data, &identity, self.node_id);
        let error = match action {
            LssAction::None => None,
            LssAction::ActivateBitTiming { switch_delay_ms } => {
                // The rate configured by 0x13 (or written to 0x2001); a switch under way is not restarted.
                let rate = ids::read(drive.dictionary(), ids::BIT_RATE_OBJECT, 0)
                    .and_then(|code| u8::try_from(code).ok())
                    .and_then(BitRate::from_code);
                if let (Some(rate), None) = (rate, self.bit_rate_switch) {
                    let delay_us = u64::from(switch_delay_ms).saturating_mul(1_000);
                    self.bit_rate_switch = Some(BitRateSwitch {
                        rate,
                        switch_at_us: now_us.saturating_add(delay_us),
                        resume_at_us: now_us.saturating_add(delay_us.saturating_mul(2)),
                        switched: false,
                    });
                }
                None
            }
            LssAction::EnteredWaiting => {
                if self.node_id == lss::UNCONFIGURED && ids::configured_node_id(drive.dictionary()).is_some() {
                    self.nmt.restart_communication();
                }
                None
            }
            LssAction::ConfigureNodeId(id) => {
                let valid = ids::is_node_id(id) || id == lss::UNCONFIGURED;
                Some(if valid && ids::write(drive.dictionary_mut(), ids::NODE_ID_OBJECT, 0, u64::from(id)) {
                    0
                } else {
                    1
                })
            }
            LssAction::ConfigureBitRate(code) => {
                let valid = BitRate::from_code(code).is_some();
                Some(if valid && ids::write(drive.dictionary_mut(), ids::BIT_RATE_OBJECT, 0, u64::from(code)) {
                    0
                } else {
                    1
                })
            }
            LssAction::Store => Some(match drive.dictionary().find(ids::STORE_PARAMETERS, ids::SAVE_MANUFACTURER) {
                // "save" to 0x1010:04 stores the manufacturer parameters 0x2000..0x5FFF, 0x2000 and 0x2001 among them.
                Ok(entry) => {
                    let values = drive.dictionary_mut().values_mut().bytes_mut();
                    if app.write(entry, 0, &ids::SAVE_SIGNATURE, true, values).is_ok() {
                        0
                    } else {
                        2
                    }
                }
                Err(_) => 2,
            }),
        };
        let reply = match (answer, error) {
            (Some(a), Some(e)) => Some(LssSlave::result(a[0], e)),
            (a, _) => a,
        };
        if let Some(frame) = reply.and_then(|r| CanFrame::new(lss::SLAVE_TO_MASTER, &r)) {
            let _ = self.outbox.push(frame);
        }
    }

    fn send_sdo(&mut self, data: [u8; 8]) {
        if let Some(frame) = CanFrame::new(ids::cob_id(ids::SDO_TX_BASE, self.node_id), &data) {
            let _ = self.outbox.push(frame);
        }
    }

    /// A SYNC: counter and length ([`SyncConsumer::on_frame`]), then the PDOs in operational.
    #[inline]
    fn on_sync<D: FieldbusDevice + ?Sized>(&mut self, data: &[u8], drive: &mut D, now_us: u64) {
        match self.sync.on_frame(data, now_us) {
            SyncEvent::Sync { counter, restored } => {
                if restored && core::mem::take(&mut self.sync_lost) {
                    drive.communication_restored(LinkLoss::RxPdoTimeout);
                }
                if self.nmt.state().allows(Service::Pdo) {
                    let _ = self.pdos.on_sync(counter, drive, now_us, &mut self.outbox);
                }
            }
            SyncEvent::BadLength { report } => {
                if let Some(loss) = report {
                    drive.communication_lost(loss);
                }
            }
        }
    }

    /// An SDO request: the CANopen write rules ([`guard`]) on an initiate, then the shared server; a download to
    /// a communication object reconfigures the node part it belongs to.
    fn on_sdo<D: FieldbusDevice + ?Sized, A: ApplicationObjects + ?Sized>(
        &mut self,
        data: &[u8],
        drive: &mut D,
        app: &mut A,
        now_us: u64,
    ) {
        let [cmd, i0, i1, sub, v0, v1, v2, v3] = *data else {
            // CiA 301 §7.2.4.3: SDO frames have 8 bytes; others are ignored (as the server does).
            self.ignore();
            return;
        };
        let index = u16::from_le_bytes([i0, i1]);
        let ctx = AccessContext {
            comm_state: self.nmt.state().comm_state(),
            power_stage_enabled: drive.power_stage_enabled(),
            // The CAN limit of 8 bytes per PDO is the guard's; the dictionary's own check then only has to keep an
            // EtherCAT assignment (0x1C12/0x1C13, meaningless on CAN) within the EtherCAT limit.
            max_pdo_bytes: u16::try_from(MAX_PDO_BYTES_ETHERCAT).unwrap_or(u16::MAX),
        };
        let initiate_download = match cmd.wrapping_shr(5) {
            1 => Some((cmd & 0x02 != 0).then(|| {
                let unused = usize::from(cmd.wrapping_shr(2) & 0x03);
                let mut bytes = [v0, v1, v2, v3];
                if cmd & 0x01 != 0 {
                    for b in bytes.iter_mut().skip(4usize.saturating_sub(unused)) {
                        *b = 0;
                    }
                }
                u32::from_le_bytes(bytes)
            })),
            6 if cmd & 0x01 == 0 => Some(None),
            _ => None,
        };
        let mut download_done = false;
        if let (Some(value), false) = (initiate_download, self.block_download) {
            if let Err(abort) = guard::check_download(drive.dictionary(), index, sub, value, ctx) {
                if self.sdo.is_busy() {
                    // End the transfer in progress as a client abort would (no frame of its own).
                    let _ = self.sdo.handle(&[0x80, 0, 0, 0, 0, 0, 0, 0], now_us, drive.dictionary_mut(), ctx, app);
                }
                self.send_sdo(abort_frame(index, sub, abort));
                return;
            }
            download_done = value.is_some();
        }
        let was_busy = self.sdo.is_busy();
        let response = self.sdo.handle(data, now_us, drive.dictionary_mut(), ctx, app);
        if let Some(response) = response {
            if response.first() == Some(&0xA4) {
                self.block_download = true;
            }
            // An expedited download answered 0x60, or the last frame of a segmented/block download accepted.
            let stored = matches!(response.first(), Some(0x60)) && download_done
                || was_busy && !self.sdo.is_busy() && matches!(response.first(), Some(0x20 | 0x30 | 0xA1));
            if stored && matches!(index, 0x1000..=0x1FFF) {
                self.reconfigure(drive, now_us);
            }
            self.send_sdo(response);
        }
        if !self.sdo.is_busy() {
            self.block_download = false;
        }
    }

    /// Reads the node's configuration again after a download to the communication area (tier 3): every part reads
    /// its objects (a few table look-ups each); the PDOs restart their transmission history.
    fn reconfigure<D: FieldbusDevice + ?Sized>(&mut self, drive: &D, now_us: u64) {
        let d = drive.dictionary();
        self.pdos.configure(d);
        self.sync.configure(d);
        self.emcy.configure(d);
        self.heartbeat.configure(d, now_us);
    }

    /// Carries out `kind` (see the module documentation); returns the bit rate a reset node asks for.
    fn reset<D: FieldbusDevice + ?Sized, A: ApplicationObjects + ?Sized>(
        &mut self,
        kind: ResetKind,
        drive: &mut D,
        app: &mut A,
    ) -> Option<BitRate> {
        if kind == ResetKind::Node {
            drive.dictionary_mut().set(handles::CONTROLWORD, 0);
            drive.shutdown();
        }
        drive.set_remote(false);
        if self.sdo.is_busy() {
            let ctx = AccessContext {
                comm_state: crate::od::access::CommState::Init,
                power_stage_enabled: drive.power_stage_enabled(),
                max_pdo_bytes: 0,
            };
            let _ = self.sdo.handle(&[0x80, 0, 0, 0, 0, 0, 0, 0], 0, drive.dictionary_mut(), ctx, app);
        }
        self.sdo = SdoServer::default();
        self.block_download = false;
        if self.powered_on {
            if let Some(id) = ids::startup_node_id(drive.dictionary()) {
                self.node_id = id;
            }
        } else {
            // Power-on: the runtime chose the node-ID (the stored 0x2000, or switches); 0x2000 shows it, so that a
            // later NMT reset keeps it unless the master writes a new one.
            self.powered_on = true;
            ids::write(drive.dictionary_mut(), ids::NODE_ID_OBJECT, 0, u64::from(self.node_id));
        }
        // The power-on values of the communication area: its defaults for this node-ID, then the stored values.
        ids::reset_communication_parameters(drive.dictionary_mut(), self.node_id);
        app.reload_communication(drive.dictionary_mut().values_mut().bytes_mut());
        for loss in self.heartbeat.take_lost() {
            drive.communication_restored(loss);
        }
        if core::mem::take(&mut self.sync_lost) {
            drive.communication_restored(LinkLoss::RxPdoTimeout);
        }
        self.pdos = Pdos::default();
        self.sync = SyncConsumer::default();
        self.heartbeat = Heartbeat::default();
        self.outbox.queue.clear();
        let rate = ids::read(drive.dictionary(), ids::BIT_RATE_OBJECT, 0).and_then(|v| u8::try_from(v).ok());
        match kind {
            ResetKind::Node => rate.and_then(BitRate::from_code),
            ResetKind::Communication => None,
        }
    }

    /// End of initialisation: configuration read, boot-up message queued, pre-operational.
    fn boot<D: FieldbusDevice + ?Sized>(&mut self, drive: &mut D, now_us: u64) {
        self.reconfigure(drive, now_us);
        drive.dictionary_mut().set(handles::ACTIVE_FIELDBUS, 1);
        if let Some(frame) = CanFrame::new(ids::cob_id(ids::HEARTBEAT_BASE, self.node_id), &[0]) {
            let _ = self.outbox.push(frame);
        }
        self.heartbeat.restart(now_us);
        self.nmt.booted();
        self.follow_state(drive);
    }

    /// After a state change: statusword bit 9 "remote" in operational (IDX L5582), the PDOs stop when
    /// operational is left, the SYNC supervision restarts when SYNC is no longer consumed.
    fn follow_state<D: FieldbusDevice + ?Sized>(&mut self, drive: &mut D) {
        let state = self.nmt.state();
        if state == self.last_state {
            return;
        }
        drive.set_remote(state == NmtState::Operational);
        if self.last_state == NmtState::Operational {
            self.pdos.stop();
        }
        if !state.allows(Service::Sync) {
            self.sync.disarm();
        }
        self.last_state = state;
    }
}
