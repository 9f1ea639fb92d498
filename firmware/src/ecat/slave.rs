//! The drive as an EtherCAT slave: the state machine ([`Esm`]), the mailbox ([`Mailbox`], CoE and FoE) and the
//! process data ([`ProcessDataLayout`], [`SyncCounters`]) tied to the device ([`FieldbusDevice`], the drive).
//!
//! Two entry points, as the tiers of the firmware call them:
//! - [`EthercatSlave::poll`] (tier 3, background): the AL control requests, the mailbox, the drive's EMCYs as
//!   CoE emergencies, the communication supervision (process-data watchdog, synchronisation error) and the
//!   0x1C32/0x1C33 diagnostics;
//! - [`EthercatSlave::cycle`] (the process-data event: SM2 event SM-synchronous, SYNC0 in DC, a local tick in
//!   free run): outputs in, inputs out, the cycle counters. It neither searches nor divides; the images live in
//!   fixed arrays of the largest EtherCAT image (40 bytes, IDX L2196).
//!
//! **Outputs only in OP.** SM2 is read from SAFE-OP on (so the ESC's buffer turns over and the cycle is counted)
//! but unpacked into the dictionary and handed to the drive ([`FieldbusDevice::setpoint_received`]) only in OP: in
//! SAFE-OP the outputs stay in their safe state (ETG.1000.6 §6.4.1; comms-faults-bootloader.md §1.2 table). The
//! inputs are written from SAFE-OP on (ETG.1000.6 §6.4.1: "inputs valid" in SAFE-OP).
//!
//! **Communication supervision** (issue 6 "communication supervision"; comms-faults-bootloader.md §1.2, §3.4):
//! - the process-data watchdog: the ESC retriggers it with every complete SM2 write when SM2's control byte has
//!   the watchdog trigger bit (bit 6) and the watchdog time 0x0420 is not 0 (ESC datasheet section I
//!   "Watchdog", registers 0x0420 and 0x0440: bit 0 = 0 "expired"). In OP an expired watchdog takes the slave
//!   to SAFE-OP with error 0x001B ([`Esm::local_error`]; Beckhoff SSC `ECAT_StateChange(SAFEOP,
//!   ALSTATUSCODE_SMWATCHDOG)`, SOES the same) and reports [`LinkLoss::EthercatWatchdog`] to the drive, whose
//!   fault table applies the reaction 0x6007 selects;
//! - the synchronisation error: once [`SyncCounters::status`] reports it (0x10F1:02 limit passed), OP falls
//!   back to SAFE-OP with 0x001A (GT L571-L577) and the drive gets [`LinkLoss::EthercatSyncError`];
//! - either loss is reported as restored ([`FieldbusDevice::communication_restored`]) when the master has brought the
//!   slave to OP again, so that a fault reset is accepted from then on.
//!
//! **SM-event-missed** is counted in DC mode only (a SYNC0 without fresh outputs since the previous one,
//! [`SyncCounters::sync0`]), as ETG.1020 defines 0x1C32:0B ("number of missed SM events in OPERATIONAL, DC
//! mode only") and the Beckhoff SSC counts it in its SYNC0 handler. SM-synchronous, a master that stops sending
//! is caught by the process-data watchdog above, which gives the master the documented 0x001B instead of a
//! sync error a few cycles after the last frame.
//!
//! **Emergencies**: every EMCY the fault manager produces ([`FieldbusDevice::poll_emcy`]) goes out as a CoE emergency
//! (ETG.1000.6 §5.6.4) while the mailbox runs for CoE (PRE-OP, SAFE-OP, OP). A message the mailbox cannot
//! take yet (queue full, or the mailbox stopped) is kept and offered again at the next poll, and no further
//! one is taken from the drive meanwhile, so the order is kept and none is lost here.

use super::esc::{reg, AlStatusCode, Esc};
use super::esm::{AlState, Esm, EsmConfig};
use super::foe::{FoeSink, NoFoeSink};
use super::mailbox::{Mailbox, MailboxContext, MailboxLayout};
use super::process_data::ProcessDataLayout;
use super::sync::{SyncCounters, SyncMode};
use crate::comm::device::FieldbusDevice;
use crate::od::access::ApplicationObjects;
use crate::od::generated::MAX_PDO_BYTES_ETHERCAT;
use crate::supervision::communication::LinkLoss;

/// Bit 0 of a sync manager's status byte (0x0805 + 8n): a buffer was completely written by the master and not
/// yet opened by the PDI (ESC datasheet section II, register 0x0805 "interrupt write"). SM2's fresh outputs.
const SM_STATUS_WRITTEN: u8 = 0x01;

/// Bit 6 of a sync manager's control byte (0x0804 + 8n): writes to it retrigger the process-data watchdog
/// (ESC datasheet section II, register 0x0804).
const SM_CONTROL_WATCHDOG: u8 = 0x40;

/// How many EMCYs one poll hands to the mailbox at most: the CoE emergency queue's depth, so that a poll's
/// work stays bounded (the rest wait in the drive's queue).
const EMCY_PER_POLL: usize = super::coe::EMERGENCY_QUEUE;

/// The process data of one SAFE-OP/OP period: where SM2 and SM3 are, the synchronisation and its counters.
/// Built when the ESM has compiled the layout (PRE-OP -> SAFE-OP), dropped when it leaves SAFE-OP/OP.
#[derive(Clone, Debug)]
struct ProcessData {
    /// SM2's physical start (the output window).
    out_start: u16,
    /// Output image bytes (SM2's length, checked by the ESM).
    out_len: usize,
    /// SM3's physical start (the input window).
    in_start: u16,
    /// Input image bytes (SM3's length).
    in_len: usize,
    /// SM2 writes retrigger the ESC's process-data watchdog (SM2 control bit 6).
    watchdog_triggered: bool,
    /// What starts the cycle.
    mode: SyncMode,
    /// SM-event-missed, cycle-time-too-small, sync error.
    counters: SyncCounters,
}

/// The EtherCAT slave of the drive. See the module documentation.
#[derive(Debug)]
pub struct EthercatSlave {
    esm: Esm,
    mailbox: Mailbox,
    /// FoE has no sink until the bootloader issue provides one: every file request gets 0x8001 (not found).
    foe_sink: NoFoeSink,
    process_data: Option<ProcessData>,
    /// An EMCY taken from the drive that the mailbox could not queue yet.
    pending_emcy: Option<[u8; 8]>,
    /// The loss reported to the drive and not yet restored.
    lost: Option<LinkLoss>,
    /// The ESM state at the end of the last poll.
    last_state: AlState,
    /// The output image (SM2), at most the EtherCAT image limit.
    outputs: [u8; MAX_PDO_BYTES_ETHERCAT],
    /// The input image (SM3).
    inputs: [u8; MAX_PDO_BYTES_ETHERCAT],
}

impl Default for EthercatSlave {
    fn default() -> Self {
        Self::new()
    }
}

impl EthercatSlave {
    /// A slave in INIT.
    #[must_use]
    pub fn new() -> Self {
        Self {
            esm: Esm::new(EsmConfig::DRIVE),
            mailbox: Mailbox::new(MailboxLayout::DRIVE),
            foe_sink: NoFoeSink,
            process_data: None,
            pending_emcy: None,
            lost: None,
            last_state: AlState::Init,
            outputs: [0; MAX_PDO_BYTES_ETHERCAT],
            inputs: [0; MAX_PDO_BYTES_ETHERCAT],
        }
    }

    /// Tier 3: the AL control requests, the mailbox (SDO with the drive's application objects `app`), the
    /// EMCYs from [`FieldbusDevice::poll_emcy`], the process-data watchdog; `now_ms` is a millisecond clock.
    ///
    /// Order: the ESM first and the mailbox after it (see [`Esm::poll`]: the SM-activation event is the ESM's
    /// to see), the supervision between them so that a loss found now is reported in this poll's emergency.
    pub fn poll<D: FieldbusDevice + ?Sized, E: Esc, A: ApplicationObjects + ?Sized>(
        &mut self,
        esc: &mut E,
        drive: &mut D,
        app: &mut A,
        now_ms: u32,
    ) {
        let mut sink = self.foe_sink;
        self.poll_with_foe(esc, drive, app, &mut sink, now_ms);
    }

    /// [`EthercatSlave::poll`] with FoE writes going to `foe_sink` (issue 7: the firmware download in BOOT,
    /// `boot::program::SharedPort`) instead of the built-in sink that answers 0x8001.
    pub fn poll_with_foe<D: FieldbusDevice + ?Sized, E: Esc, A: ApplicationObjects + ?Sized, S: FoeSink + ?Sized>(
        &mut self,
        esc: &mut E,
        drive: &mut D,
        app: &mut A,
        foe_sink: &mut S,
        now_ms: u32,
    ) {
        let _ = self.esm.poll(esc, drive.dictionary(), now_ms);
        self.follow_state(esc, drive);
        self.supervise(esc, drive);
        self.forward_emergencies(drive);
        let power_stage_enabled = drive.power_stage_enabled();
        let mut ctx = MailboxContext {
            state: self.esm.state(),
            dict: drive.dictionary_mut(),
            app,
            power_stage_enabled,
            foe_sink,
        };
        self.mailbox.poll(esc, &mut ctx);
        if let Some(pd) = self.process_data.as_ref() {
            pd.counters.publish(drive.dictionary_mut());
        }
    }

    /// The process-data cycle (SM2 event in SM-synchronous mode, SYNC0 in DC mode, every slow tick in free run):
    /// reads the outputs, hands them to the drive with [`FieldbusDevice::setpoint_received`], writes the inputs,
    /// counts; `now_ns` is the ESC's local time.
    ///
    /// Outputs are read only when SM2 holds a buffer the master wrote since the last read (SM2 status bit 0), so
    /// a cycle without a new frame neither latches the old set-point again nor counts an SM event.
    #[inline]
    pub fn cycle<D: FieldbusDevice + ?Sized, E: Esc>(&mut self, esc: &mut E, drive: &mut D, now_ns: u32) {
        let (Some(pd), Some(layout)) = (self.process_data.as_mut(), self.esm.layout()) else {
            return;
        };
        if let Some(image) = self.outputs.get_mut(..pd.out_len).filter(|i| !i.is_empty()) {
            let mut status = [0u8; 1];
            esc.read(reg::sm(2, reg::SM_STATUS_OFFSET), &mut status);
            let [status] = status;
            if status & SM_STATUS_WRITTEN != 0 {
                // The whole window: reading its last byte hands the buffer back to the ESC.
                esc.read(pd.out_start, image);
                pd.counters.sm_event(now_ns);
                if self.esm.outputs_enabled() {
                    layout.unpack_outputs(image, drive.dictionary_mut());
                    drive.setpoint_received();
                }
            }
        }
        if pd.mode == SyncMode::DcSync0 {
            // The result is kept in the counters; tier 3 acts on it (`supervise`).
            let _ = pd.counters.sync0();
        }
        if let Some(image) = self.inputs.get_mut(..pd.in_len).filter(|i| !i.is_empty()) {
            layout.pack_inputs(drive.dictionary(), image);
            // The whole window: writing its last byte completes the buffer for the master.
            esc.write(pd.in_start, image);
        }
    }

    /// The ESM state.
    #[must_use]
    pub fn state(&self) -> AlState {
        self.esm.state()
    }

    /// The state machine (AL status, error, layout, synchronisation).
    #[must_use]
    pub const fn esm(&self) -> &Esm {
        &self.esm
    }

    /// The mailbox (statistics, CoE and FoE state).
    #[must_use]
    pub const fn mailbox(&self) -> &Mailbox {
        &self.mailbox
    }

    /// The cycle counters of the current SAFE-OP/OP period (`None` below SAFE-OP).
    #[must_use]
    pub fn sync_counters(&self) -> Option<&SyncCounters> {
        self.process_data.as_ref().map(|pd| &pd.counters)
    }

    /// An EMCY taken from the drive and waiting for room in the mailbox.
    #[must_use]
    pub const fn pending_emergency(&self) -> Option<&[u8; 8]> {
        self.pending_emcy.as_ref()
    }

    /// Follows the ESM: sets the process data up when SAFE-OP was entered (layout compiled), drops it below
    /// SAFE-OP, reports a restored link on reaching OP again, and sets statusword bit 9 "remote" in SAFE-OP and
    /// OP (the master's process data reaches the drive).
    fn follow_state<D: FieldbusDevice + ?Sized, E: Esc>(&mut self, esc: &mut E, drive: &mut D) {
        let state = self.esm.state();
        match (self.esm.layout(), self.esm.synchronisation()) {
            (Some(layout), Some(sync)) => {
                if self.process_data.is_none() {
                    self.process_data = Some(Self::start_process_data(esc, drive, layout, sync));
                }
            }
            _ => self.process_data = None,
        }
        if state == AlState::Op && self.last_state != AlState::Op {
            if let Some(loss) = self.lost.take() {
                drive.communication_restored(loss);
            }
            // A sync error stays in the counters until reset: the master's new OP starts a clean count.
            if let Some(pd) = self.process_data.as_mut() {
                if pd.counters.sync_error() {
                    pd.counters.reset();
                }
            }
        }
        drive.set_remote(matches!(state, AlState::SafeOp | AlState::Op));
        self.last_state = state;
    }

    /// The process data for a layout just compiled: SM2/SM3 where the master put them (checked against the
    /// layout by the ESM), the synchronisation published into 0x1C32/0x1C33 (sub 2 and 0x0A in DC), fresh
    /// counters with the limit 0x10F1:02.
    fn start_process_data<D: FieldbusDevice + ?Sized, E: Esc>(
        esc: &mut E,
        drive: &mut D,
        layout: &ProcessDataLayout,
        sync: &super::sync::Synchronisation,
    ) -> ProcessData {
        // Bytes 0..=4 of SM2/SM3 (start, length, control): no side effects, unlike the activate byte.
        let mut sm2 = [0u8; 5];
        esc.read(reg::sm(2, 0), &mut sm2);
        let [o0, o1, _, _, control] = sm2;
        let in_start = esc.read_u16(reg::sm(3, 0));
        sync.publish(drive.dictionary_mut());
        ProcessData {
            out_start: u16::from_le_bytes([o0, o1]),
            out_len: usize::from(layout.output_bytes).min(MAX_PDO_BYTES_ETHERCAT),
            in_start,
            in_len: usize::from(layout.input_bytes).min(MAX_PDO_BYTES_ETHERCAT),
            watchdog_triggered: control & SM_CONTROL_WATCHDOG != 0,
            mode: sync.mode,
            counters: SyncCounters::from_dictionary(sync, drive.dictionary()),
        }
    }

    /// In OP: the process-data watchdog (0x001B) and the synchronisation error (0x001A), see the module
    /// documentation.
    fn supervise<D: FieldbusDevice + ?Sized, E: Esc>(&mut self, esc: &mut E, drive: &mut D) {
        if self.esm.state() != AlState::Op {
            return;
        }
        let Some(pd) = self.process_data.as_ref() else {
            return;
        };
        let sync_error = pd.counters.status().is_err();
        // The watchdog supervises the outputs; it runs only when SM2 triggers it and 0x0420 is not 0 (0 = off).
        let watchdog_on = pd.out_len > 0 && pd.watchdog_triggered && esc.read_u16(reg::WATCHDOG_TIME_PD) != 0;
        // Reading 0x0440 also clears the watchdog's AL event (0x0220 bit 6).
        if watchdog_on && esc.read_u16(reg::WATCHDOG_STATUS_PD) & 0x0001 == 0 {
            self.lose(esc, drive, AlStatusCode::SmWatchdog, LinkLoss::EthercatWatchdog);
        } else if sync_error {
            self.lose(esc, drive, AlStatusCode::SyncError, LinkLoss::EthercatSyncError);
        }
    }

    /// OP -> SAFE-OP with `code` and the error indication (SM2 disabled), and the loss to the drive.
    fn lose<D: FieldbusDevice + ?Sized, E: Esc>(
        &mut self,
        esc: &mut E,
        drive: &mut D,
        code: AlStatusCode,
        loss: LinkLoss,
    ) {
        let _ = self.esm.local_error(esc, code);
        self.last_state = self.esm.state();
        drive.communication_lost(loss);
        self.lost = Some(loss);
    }

    /// Hands the drive's EMCYs to the mailbox, keeping the one it could not take (see the module documentation).
    fn forward_emergencies<D: FieldbusDevice + ?Sized>(&mut self, drive: &mut D) {
        for _ in 0..EMCY_PER_POLL {
            let Some(emcy) = self.pending_emcy.take().or_else(|| drive.poll_emcy()) else {
                return;
            };
            if self.mailbox.send_emergency(&emcy).is_err() {
                self.pending_emcy = Some(emcy);
                return;
            }
        }
    }
}
