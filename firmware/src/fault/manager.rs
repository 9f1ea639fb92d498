//! The fault manager: the active faults and warnings, their latch and reset rules, the trip snapshots, and
//! what the drive reports about them (0x603F, 0x1001, 0x1003, EMCY, the CiA 402 state machine's fault inputs).
//!
//! Sans-IO (ARCHITECTURE convention 1): the detectors call [`FaultManager::raise`] and
//! [`FaultManager::clear_cause`], the drive calls [`FaultManager::reset_request`] on the controlword's fault-reset
//! edge, [`FaultManager::take_machine_input`] once per tier-2 step, [`FaultManager::publish`] to copy the state
//! into the dictionary and [`FaultManager::poll_emcy`] to send emergencies. Nothing here allocates or panics.
//!
//! Rules (digest `shared/spec/comms-faults-bootloader.md` §3):
//! - A fault is raised once per event (IDX L7017-L7024: "transmitted only once per error event"): raising a fault
//!   that is already active keeps its first snapshot and sends nothing; it only marks a level cause present again.
//! - Faults ([`LatchPolicy::Latching`]) stay active until a fault reset arrives after their cause has gone; a reset
//!   while any latched fault's cause persists is refused as a whole and clears nothing (CiA 402 transition 15
//!   "if no fault is present any more"; IDX L7156-L7176 "reset only when valid"). Event causes are gone at once.
//! - Warnings ([`LatchPolicy::SelfClearing`]) go as soon as their cause goes; a fault reset does not touch them.
//!   They set statusword bit 7 ([`FaultManager::warning_active`]), send an EMCY, and stay out of 0x1001, 0x603F and
//!   0x1003 (digest §3.6: a warning is neither error nor fault).
//! - 0x1001: the OR of the active faults' register bits (IDX L7028-L7032: "summary of all active error flags").
//! - Safe Torque Off ([`ReactionClass::TorqueOff`]) is neither: it clears itself like a warning, but shows in
//!   0x603F (below every fault) and in [`FaultManager::safe_torque_off_active`], which the CiA 402 machine takes;
//!   it stays out of 0x1001 and 0x1003 and does not block a fault reset.
//! - 0x603F: the code of the most severe active fault (class d over f over a), the earliest raised among equals
//!   (the root cause of a cascade); the STO code when only STO is active; 0 when none is (device.toml 0x603F "0
//!   when none is pending").
//! - 0x1003: every new fault event enters the history, newest first ([`super::history`]).
//! - EMCY: one message per new fault or warning event; an "error reset" (code 0x0000) when the last fault or
//!   warning has gone (CiA 301 EMCY protocol; while a warning remains the drive has something to report, so it
//!   does not announce "no error" yet; 0x1001 = 0 already shows the fault has gone).
//! - The first fault raised while none was active is kept with its snapshot after the reset too
//!   ([`FaultManager::first_trip`]): the root cause a field engineer asks for.

use super::emcy::{EmcyMessage, EmcyProducer, InhibitTime, DEFAULT_QUEUE};
use super::history::{self, HistoryEntry};
use super::snapshot::DiagnosisSnapshot;
use super::table::Cause;
use super::table::{FaultId, LatchPolicy, ReactionClass, FAULT_COUNT};
use crate::cia402::{FaultClass, FaultInput, Ticks};
use crate::od::access::Dictionary;
use crate::od::generated::handles::{ERROR_CODE, ERROR_REGISTER};
use heapless::Deque;

/// History entries waiting for [`FaultManager::publish`]. More than the history holds (8) is never needed: the
/// oldest pending entries would be shifted out of 0x1003 anyway, so dropping them when this is full is the same
/// saturation.
const HISTORY_PENDING: usize = 16;

/// A fault reset was refused: the cause of a latched fault persists.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ResetRefused {
    /// The first (by table order) latched fault whose cause is still present.
    pub blocking: FaultId,
}

/// What [`FaultManager::raise`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Raised {
    /// A new event: stored with its snapshot, queued for the history and the EMCY.
    New,
    /// The fault was already active: its first snapshot is kept, nothing is reported again.
    AlreadyActive,
    /// Not raised: [`FaultId::EmcyOverflow`] is reported by the EMCY producer itself, never through the manager.
    Ignored,
}

/// One active fault or warning.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ActiveFault {
    /// Which fault.
    pub id: FaultId,
    /// The measured values at the trip.
    pub snapshot: DiagnosisSnapshot,
    /// The manager's time when it was raised.
    pub raised_at: Ticks,
    /// Whether the cause is still present (always `false` for event causes).
    pub cause_present: bool,
    /// Activation order (smaller = earlier), for 0x603F's tie-break.
    order: u32,
}

/// The first fault of an episode (raised while none was active), kept after the reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Trip {
    /// Which fault.
    pub id: FaultId,
    /// The measured values at the trip.
    pub snapshot: DiagnosisSnapshot,
}

/// What tier 2 asks the manager every step, computed when a fault changes instead of per query.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct Summary {
    any_fault: bool,
    warning: bool,
    torque_off: bool,
    connection_lost: bool,
    cause_present: bool,
    error_code: u16,
    error_register: u8,
}

/// The fault manager; `Q` is the EMCY queue capacity.
#[derive(Clone, Debug)]
pub struct FaultManager<const Q: usize = DEFAULT_QUEUE> {
    summary: Summary,
    /// 0x603F and 0x1001 differ from what was last published.
    unpublished: bool,
    slots: [Option<ActiveFault>; FAULT_COUNT],
    order: u32,
    raised_class: Option<FaultClass>,
    history_pending: Deque<HistoryEntry, HISTORY_PENDING>,
    error_number: u8,
    first_trip: Option<Trip>,
    emcy: EmcyProducer<Q>,
}

impl<const Q: usize> Default for FaultManager<Q> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const Q: usize> FaultManager<Q> {
    /// A manager with nothing active and an EMCY inhibit time of 0.
    pub const fn new() -> Self {
        Self {
            summary: Summary {
                any_fault: false,
                warning: false,
                torque_off: false,
                connection_lost: false,
                cause_present: false,
                error_code: 0,
                error_register: 0,
            },
            unpublished: true,
            slots: [None; FAULT_COUNT],
            order: 0,
            raised_class: None,
            history_pending: Deque::new(),
            error_number: 0,
            first_trip: None,
            emcy: EmcyProducer::new(InhibitTime(0)),
        }
    }

    fn slot(&self, id: FaultId) -> Option<&ActiveFault> {
        self.slots.get(usize::from(id.number())).and_then(Option::as_ref)
    }

    fn slot_mut(&mut self, id: FaultId) -> Option<&mut Option<ActiveFault>> {
        self.slots.get_mut(usize::from(id.number()))
    }

    /// Raises `id` with the values measured when it was detected, at manager time `now`.
    pub fn raise(&mut self, id: FaultId, snapshot: DiagnosisSnapshot, now: Ticks) -> Raised {
        let raised = self.raise_inner(id, snapshot, now);
        if raised != Raised::Ignored {
            self.update_summary();
        }
        raised
    }

    fn raise_inner(&mut self, id: FaultId, snapshot: DiagnosisSnapshot, now: Ticks) -> Raised {
        if id == FaultId::EmcyOverflow {
            return Raised::Ignored;
        }
        let info = id.info();
        let cause_present = info.cause == Cause::Level;
        let no_fault_before = !self.any_fault();
        let order = self.order;
        let Some(slot) = self.slot_mut(id) else { return Raised::Ignored };
        if let Some(active) = slot {
            // Same event: keep the first snapshot (the trip), refresh only the level.
            active.cause_present |= cause_present;
            return Raised::AlreadyActive;
        }
        *slot = Some(ActiveFault { id, snapshot, raised_at: now, cause_present, order });
        self.order = self.order.wrapping_add(1);

        let register = self.active().fold(0, |acc, a| acc | a.id.info().register);
        if info.reaction.is_fault() {
            if no_fault_before {
                self.first_trip = Some(Trip { id, snapshot });
            }
            // The running number skips 0 so that an entry is never all-zero in its high byte.
            self.error_number = match self.error_number.wrapping_add(1) {
                0 => 1,
                n => n,
            };
            if self.history_pending.is_full() {
                let _ = self.history_pending.pop_front();
            }
            let _ =
                self.history_pending.push_back(HistoryEntry { code: info.code, register, number: self.error_number });
            if let Some(class) = info.reaction.machine_class() {
                self.raised_class = Some(match self.raised_class {
                    Some(FaultClass::Critical) => FaultClass::Critical,
                    _ => class,
                });
            }
        }
        self.emcy.push(EmcyMessage::fault(id, register, snapshot.field(info.emcy_field)));
        Raised::New
    }

    /// The cause of `id` has gone: a warning disappears, a latched fault waits for a fault reset.
    pub fn clear_cause(&mut self, id: FaultId) {
        let latch = id.info().latch;
        let Some(slot) = self.slot_mut(id) else { return };
        match (latch, slot.as_mut()) {
            (_, None) => {}
            (LatchPolicy::Latching, Some(active)) => {
                if active.cause_present {
                    active.cause_present = false;
                    self.update_summary();
                }
            }
            (LatchPolicy::SelfClearing, Some(_)) => {
                *slot = None;
                self.report_if_all_clear();
                self.update_summary();
            }
        }
    }

    /// Recomputes what the per-step queries return (once per change, not per query). One pass over the slots:
    /// a chain of iterators per field was unrolled over every slot six times (5.5 KB of flash).
    fn update_summary(&mut self) {
        let mut summary = Summary::default();
        // The fault 0x603F shows: (severity, order, code) of the most severe, the earliest among equals.
        let mut shown: Option<(u8, u32, u16)> = None;
        for a in self.slots.iter().flatten() {
            let info = a.id.info();
            if info.reaction.is_warning() {
                summary.warning = true;
                continue;
            }
            let severity = info.reaction.severity();
            if shown.is_none_or(|(s, order, _)| severity > s || (severity == s && a.order < order)) {
                shown = Some((severity, a.order, info.code));
            }
            if !info.reaction.is_fault() {
                summary.torque_off = true;
                continue;
            }
            summary.any_fault = true;
            summary.connection_lost |= info.reaction == ReactionClass::AbortConnection;
            summary.cause_present |= a.cause_present && info.reaction.machine_class().is_some();
            summary.error_register |= info.register;
        }
        summary.error_code = shown.map_or(0, |(_, _, code)| code);
        if summary.error_code != self.summary.error_code || summary.error_register != self.summary.error_register {
            self.unpublished = true;
        }
        self.summary = summary;
    }

    /// A fault reset (controlword bit 7 rising edge, CiA 402 transition 15): clears every latched fault if none
    /// of their causes persists; refused, clearing nothing, otherwise. Warnings are not affected.
    pub fn reset_request(&mut self) -> Result<(), ResetRefused> {
        if let Some(blocking) = self.blocking_fault() {
            return Err(ResetRefused { blocking });
        }
        let mut cleared = false;
        for slot in self.slots.iter_mut() {
            if slot.is_some_and(|a| a.id.info().latch == LatchPolicy::Latching) {
                *slot = None;
                cleared = true;
            }
        }
        self.raised_class = None;
        if cleared {
            self.report_if_all_clear();
            self.update_summary();
        }
        Ok(())
    }

    /// The first latched fault whose cause persists (what a fault reset would be refused for).
    pub fn blocking_fault(&self) -> Option<FaultId> {
        self.active().find(|a| a.cause_present).map(|a| a.id)
    }

    fn report_if_all_clear(&mut self) {
        if self.slots.iter().all(Option::is_none) {
            self.emcy.push(EmcyMessage::error_reset(0));
        }
    }

    /// The active faults (not warnings, not the STO state), in table order.
    pub fn active(&self) -> impl Iterator<Item = &ActiveFault> + '_ {
        self.slots.iter().flatten().filter(|a| a.id.info().reaction.is_fault())
    }

    /// The active warnings, in table order.
    pub fn warnings(&self) -> impl Iterator<Item = &ActiveFault> + '_ {
        self.slots.iter().flatten().filter(|a| a.id.info().reaction.is_warning())
    }

    /// Whether `id` (fault or warning) is active.
    pub fn is_active(&self, id: FaultId) -> bool {
        self.slot(id).is_some()
    }

    /// Whether any fault (not warning) is active.
    pub fn any_fault(&self) -> bool {
        self.summary.any_fault
    }

    /// Statusword bit 7: a warning is active (IDX L5584).
    pub fn warning_active(&self) -> bool {
        self.summary.warning
    }

    /// Safe Torque Off is active: the hardware holds the power stage off (`cia402::Inputs::safe_torque_off`,
    /// statusword bit 14).
    pub fn safe_torque_off_active(&self) -> bool {
        self.summary.torque_off
    }

    /// The snapshot stored with active `id`.
    pub fn snapshot(&self, id: FaultId) -> Option<&DiagnosisSnapshot> {
        self.slot(id).map(|a| &a.snapshot)
    }

    /// The first fault of the latest episode with its snapshot; kept after the reset until the next episode.
    pub const fn first_trip(&self) -> Option<&Trip> {
        self.first_trip.as_ref()
    }

    /// 0x1001: the OR of the active faults' register bits (0 when none).
    pub fn error_register(&self) -> u8 {
        self.summary.error_register
    }

    /// 0x603F: the code of the most severe active fault, the earliest among equals; the STO code when only STO is
    /// active; 0 when none.
    pub fn error_code(&self) -> u16 {
        self.summary.error_code
    }

    /// The state machine's fault input for this step: the most severe class raised since the previous call (an
    /// event, consumed here) and whether a latched fault of class d or f still has its cause present (a level).
    pub fn take_machine_input(&mut self) -> FaultInput {
        FaultInput { raised: self.raised_class.take(), present: self.summary.cause_present }
    }

    /// `cia402::Inputs::connection_lost`: a communication fault (class "a", reaction per 0x6007) is active. It
    /// stays set until the fault is reset, so the 0x6007 reaction holds until then (IDX: class "a" errors end in
    /// Fault and are reset with the controlword, L7340-L7436).
    pub fn connection_lost(&self) -> bool {
        self.summary.connection_lost
    }

    /// Writes 0x603F and 0x1001 through their typed handles and adds the new history entries to 0x1003.
    pub fn publish(&mut self, dict: &mut Dictionary) {
        if core::mem::take(&mut self.unpublished) {
            dict.set(ERROR_CODE, self.summary.error_code);
            dict.set(ERROR_REGISTER, self.summary.error_register);
        }
        while let Some(entry) = self.history_pending.pop_front() {
            history::push(dict, entry);
        }
    }

    /// The EMCY producer (inhibit time, statistics).
    pub const fn emcy(&self) -> &EmcyProducer<Q> {
        &self.emcy
    }

    /// The EMCY producer, mutable (to set the inhibit time after a write to 0x1015).
    pub fn emcy_mut(&mut self) -> &mut EmcyProducer<Q> {
        &mut self.emcy
    }

    /// The next EMCY frame to send at `now`, respecting the inhibit time.
    pub fn poll_emcy(&mut self, now: Ticks) -> Option<[u8; 8]> {
        self.emcy.poll(now)
    }
}
