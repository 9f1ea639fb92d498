//! The synchronisation objects 0x1C32 (SM2, outputs) and 0x1C33 (SM3, inputs) per ETG.1020 §"SyncManager
//! parameter" / ETG.6010 (comms-faults-bootloader.md §1.6, §1.7): which event starts the drive's application
//! cycle, the checks of PRE-OP to SAFE-OP, and the counters the master reads in OP.
//!
//! Sync types (sub 1): 0x0000 free run (a local timer, independent of the bus; GT L1917-L1938), 0x0001
//! synchronous with the SM2 event (the output frame's arrival; IDX L3067-L3086), 0x0002 DC SYNC0 (GT
//! L1940-L1965); for the inputs 0x0022 means "synchronous with the SM2 event" (IDX L3207-L3226). Supported
//! cycle times are whole multiples of the 40 us current period from 200 us (0x1C32:05) up to 100 ms (the write
//! limit of 0x1C32:02), because in DC mode the PWM period is locked to SYNC0 and the 2.5 kHz tier keeps a fixed
//! phase to the bus cycle only then (issue 6).
//!
//! **DC set up through the ESC only.** SOEM (`ecx_dcsync0`) and ethercrab activate SYNC0 by writing 0x0981 and
//! 0x09A0 and never write 0x1C32:01 (fieldbus-real-masters.md register table: 0x0981 BWR/1 by all three masters,
//! no 0x1C32 download). So the SM-synchronous default (0x1C32:01 = 1, 0x1C33:01 = 0x22) with SYNC0 activated is
//! taken as DC SYNC0; an explicit free run (0) with SYNC0 activated, or DC (2) without it, is refused with
//! 0x0030. Sub 1 keeps what the master wrote ([`Synchronisation::publish`] does not rewrite it), so that the
//! same rule applies again at the next PRE-OP to SAFE-OP.
//!
//! **Order of the master's steps.** The check reads 0x0981/0x09A0 when SAFE-OP is requested, so SYNC0 must be
//! armed before that request. SOEM's `config_map` itself requests SAFE-OP at its end (`ecx_config_map_group`
//! writes AL control = SAFE-OP after the FMMUs unless the context's `manualstatechange` is set), i.e. before
//! `config_dc`/`dc_sync`: with 0x1C32:01 = 2 that request is refused with 0x0030 and the slave stays in
//! PRE-OP + error (checked with pysoem 1.1.13: 0x0981 = 0 at the request, 0x03 after `dc_sync`). A DC master
//! with SOEM sets `manual_state_change` (or arms SYNC0 in the PRE-OP to SAFE-OP hook) and requests SAFE-OP
//! itself; tests/ecat/soem_csp.py --dc does so.
//!
//! **Counters** ([`SyncCounters`], published into sub 0x0B, 0x0C, 0x20 of both objects): an SM-event-missed is
//! a cycle start (SYNC0) without fresh outputs since the previous one, or, SM-synchronous, one and a half cycles
//! without an SM2 event; a cycle-time-too-small is an SM2 event less than the minimum cycle time (0x1C32:05)
//! after the previous one, sooner than the application can finish a cycle. The sync error (sub 0x20, AL status
//! 0x001A) follows GT L571-L577 (0x10F1:02 "sync error counter limit", default 4): an internal error counter
//! rises by 3 for each missed event and falls by 1 for each good cycle (a design choice, GT gives no weights: an
//! isolated miss is tolerated, two in a row with the default limit are not); above the limit the
//! drive reports the sync error and the state machine goes to SAFE-OP with 0x001A.

use super::esc::{reg, AlStatusCode, Esc};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::od::values;

/// The current-loop period: cycle times must be whole multiples of it.
pub const CURRENT_PERIOD_NS: u32 = 40_000;
/// The shortest supported cycle (0x1C32:05 / 0x1C33:05 report it).
pub const MIN_CYCLE_NS: u32 = 200_000;
/// The longest supported cycle (the upper write limit of 0x1C32:02).
pub const MAX_CYCLE_NS: u32 = 100_000_000;

/// Synchronisation type values of sub 1 (ETG.1020; comms-faults-bootloader.md §1.6).
pub mod sync_type {
    /// Free run: the local timer starts the cycle.
    pub const FREE_RUN: u16 = 0x0000;
    /// Synchronous with the SM2 event (0x1C32).
    pub const SM_SYNCHRONOUS: u16 = 0x0001;
    /// DC SYNC0.
    pub const DC_SYNC0: u16 = 0x0002;
    /// Inputs synchronous with the SM2 event (0x1C33).
    pub const SM2_SYNCHRONOUS_INPUTS: u16 = 0x0022;
}

/// Bits of sub 4 "synchronization types supported" (ETG.1020; IDX Table 6-82).
pub mod supported {
    /// Bit 0: free run.
    pub const FREE_RUN: u16 = 1 << 0;
    /// Bit 1: synchronous with an SM event.
    pub const SM_SYNCHRONOUS: u16 = 1 << 1;
    /// Bits 4..2: DC type.
    pub const DC_MASK: u16 = 0b111 << 2;
    /// Bits 4..2 = 001: DC SYNC0.
    pub const DC_SYNC0: u16 = 0b001 << 2;
}

/// Bits of the ESC's SYNC activation register 0x0981 (Beckhoff ESC datasheet section II, 0x0981).
pub mod dc_activation {
    /// Bit 0: cyclic operation (the sync unit generates SYNC signals).
    pub const CYCLIC_OPERATION: u8 = 1 << 0;
    /// Bit 1: SYNC0 generation.
    pub const SYNC0: u8 = 1 << 1;
    /// Bit 2: SYNC1 generation (the drive does not use SYNC1).
    pub const SYNC1: u8 = 1 << 2;
}

/// What starts the drive's application cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SyncMode {
    /// A local timer, independent of the bus.
    FreeRun,
    /// The SM2 event (arrival of the outputs).
    SmSynchronous,
    /// The ESC's DC SYNC0 signal.
    DcSync0,
}

/// The synchronisation settings the master left in the dictionary, read at PRE-OP to SAFE-OP.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SyncConfig {
    /// 0x1C32:01.
    pub output_type: u16,
    /// 0x1C33:01.
    pub input_type: u16,
    /// 0x1C32:02, ns: the local cycle in free run.
    pub cycle_ns: u32,
    /// 0x1C32:04.
    pub supported: u16,
    /// 0x1C32:05, ns.
    pub min_cycle_ns: u32,
}

impl SyncConfig {
    /// Reads 0x1C32:01/02/04/05 and 0x1C33:01 (once per transition: sub 4 and 5 are found by search).
    pub fn from_dictionary(d: &Dictionary) -> Self {
        let stored = |sub: u8| {
            d.find(0x1C32, sub).ok().and_then(|entry| values::unsigned(d.values().bytes(), entry)).unwrap_or(0)
        };
        Self {
            output_type: d.get(h::SM2_SYNC_TYPE),
            input_type: d.get(h::SM3_SYNC_TYPE),
            cycle_ns: d.get(h::SM2_CYCLE_TIME),
            supported: u16::try_from(stored(4)).unwrap_or(0),
            min_cycle_ns: u32::try_from(stored(5)).unwrap_or(MIN_CYCLE_NS),
        }
    }

    /// The synchronisation the drive runs with, given the ESC's SYNC activation (0x0981) and SYNC0 cycle time
    /// (0x09A0), or the AL status code that refuses SAFE-OP (ETG.1000.6 Table 11; ETG.1020):
    /// - 0x0028: a sync type the drive does not know (0x1C32:01 not 0/1/2, 0x1C33:01 not 0/2/0x22), a pair of
    ///   them that does not go together (outputs and inputs must both be free run, SM-synchronous (1 / 0x22)
    ///   or DC (2 / 2)), or a mode 0x1C32:04 does not list; 0x0027 for free run when it is not listed;
    /// - 0x0030: DC and the activation disagree: cyclic operation without SYNC0, DC requested without cyclic
    ///   operation, SYNC0 active with free run requested, or a SYNC0 cycle of 0 (single shot);
    /// - 0x0036: a cycle (SYNC0 in DC, 0x1C32:02 in free run) below the minimum 0x1C32:05 (200 us);
    /// - 0x0035: a cycle above 100 ms or not a whole multiple of 40 us.
    ///
    /// SM-synchronous, the cycle is the master's and only measured, so 0x1C32:02 is not checked.
    pub fn resolve(&self, dc_activation: u8, sync0_cycle_ns: u32) -> Result<Synchronisation, AlStatusCode> {
        use sync_type::{DC_SYNC0, FREE_RUN, SM2_SYNCHRONOUS_INPUTS, SM_SYNCHRONOUS};
        let requested = match (self.output_type, self.input_type) {
            (FREE_RUN, FREE_RUN) => SyncMode::FreeRun,
            (SM_SYNCHRONOUS, SM2_SYNCHRONOUS_INPUTS) => SyncMode::SmSynchronous,
            (DC_SYNC0, DC_SYNC0) => SyncMode::DcSync0,
            _ => return Err(AlStatusCode::SyncNotSupported),
        };
        let cyclic = dc_activation & dc_activation::CYCLIC_OPERATION != 0;
        let sync0 = dc_activation & dc_activation::SYNC0 != 0;
        if cyclic && !sync0 {
            return Err(AlStatusCode::InvalidDcSyncConfig);
        }
        let mode = match (requested, cyclic) {
            (SyncMode::FreeRun, true) | (SyncMode::DcSync0, false) => return Err(AlStatusCode::InvalidDcSyncConfig),
            (SyncMode::SmSynchronous, true) => SyncMode::DcSync0,
            (mode, _) => mode,
        };
        let listed = match mode {
            SyncMode::FreeRun => self.supported & supported::FREE_RUN != 0,
            SyncMode::SmSynchronous => self.supported & supported::SM_SYNCHRONOUS != 0,
            SyncMode::DcSync0 => self.supported & supported::DC_MASK == supported::DC_SYNC0,
        };
        match (listed, mode) {
            (true, _) => {}
            (false, SyncMode::FreeRun) => return Err(AlStatusCode::FreeRunNotSupported),
            (false, _) => return Err(AlStatusCode::SyncNotSupported),
        }
        let cycle_ns = match mode {
            SyncMode::DcSync0 if sync0_cycle_ns == 0 => return Err(AlStatusCode::InvalidDcSyncConfig),
            SyncMode::DcSync0 => sync0_cycle_ns,
            SyncMode::FreeRun => self.cycle_ns,
            SyncMode::SmSynchronous => {
                return Ok(Synchronisation { mode, cycle_ns: self.cycle_ns, sync0_cycle_ns: 0, current_periods: 0 });
            }
        };
        let current_periods = self.check_cycle(cycle_ns)?;
        let sync0_cycle_ns = if mode == SyncMode::DcSync0 { cycle_ns } else { 0 };
        Ok(Synchronisation { mode, cycle_ns, sync0_cycle_ns, current_periods })
    }

    /// The cycle in current periods, or 0x0036 (too small) / 0x0035 (too long or not a whole multiple).
    fn check_cycle(&self, cycle_ns: u32) -> Result<u32, AlStatusCode> {
        if cycle_ns < self.min_cycle_ns.max(MIN_CYCLE_NS) {
            return Err(AlStatusCode::DcSync0CycleTime);
        }
        if cycle_ns > MAX_CYCLE_NS || cycle_ns.checked_rem(CURRENT_PERIOD_NS) != Some(0) {
            return Err(AlStatusCode::DcInvalidSyncCycleTime);
        }
        cycle_ns.checked_div(CURRENT_PERIOD_NS).ok_or(AlStatusCode::DcInvalidSyncCycleTime)
    }
}

/// Checks the synchronisation settings for PRE-OP to SAFE-OP (see [`SyncConfig::resolve`] for the codes).
pub fn check(config: &SyncConfig, dc_activation: u8, sync0_cycle_ns: u32) -> Result<(), AlStatusCode> {
    config.resolve(dc_activation, sync0_cycle_ns).map(|_| ())
}

/// Reads the ESC's SYNC activation (0x0981) and SYNC0 cycle time (0x09A0) and resolves the dictionary's
/// settings against them: the PRE-OP to SAFE-OP step of the state machine (see [`SyncConfig::resolve`]).
pub fn check_esc<E: Esc + ?Sized>(esc: &mut E, d: &Dictionary) -> Result<Synchronisation, AlStatusCode> {
    let mut activation = [0u8];
    // 0x0980 is the cyclic unit control, 0x0981 the activation (ESC datasheet section II).
    esc.read(reg::DC_ACTIVATION.wrapping_add(1), &mut activation);
    let [activation] = activation;
    let sync0_cycle_ns = esc.read_u32(reg::DC_SYNC0_CYCLE);
    SyncConfig::from_dictionary(d).resolve(activation, sync0_cycle_ns)
}

/// The synchronisation in force from SAFE-OP on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Synchronisation {
    /// What starts the application cycle.
    pub mode: SyncMode,
    /// The cycle, ns: SYNC0's in DC, 0x1C32:02 otherwise.
    pub cycle_ns: u32,
    /// The SYNC0 cycle, ns (0 unless DC).
    pub sync0_cycle_ns: u32,
    /// The cycle in 40 us current periods (DC and free run; 0 SM-synchronous, where the master sets the pace).
    pub current_periods: u32,
}

impl Synchronisation {
    /// Publishes the cycle into 0x1C32/0x1C33: in DC, sub 2 and sub 0x0A become the SYNC0 cycle (ETG.1020:
    /// "DC: cycle time = SYNC0 cycle register"); otherwise sub 0x0A is 0 and sub 2 stays as the master wrote it.
    pub fn publish(&self, d: &mut Dictionary) {
        if self.mode == SyncMode::DcSync0 {
            d.set(h::SM2_CYCLE_TIME, self.cycle_ns);
            d.set(h::SM3_CYCLE_TIME, self.cycle_ns);
        }
        d.set(h::SM2_SYNC0_CYCLE_TIME, self.sync0_cycle_ns);
        d.set(h::SM3_SYNC0_CYCLE_TIME, self.sync0_cycle_ns);
    }
}

/// The SM-event-missed, cycle-time-too-small and sync-error bookkeeping of one run in SAFE-OP/OP (see the
/// module documentation for the rules). Times are a free-running nanosecond count that may wrap (u32: the
/// differences of interest are far below 4.29 s).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SyncCounters {
    mode: SyncMode,
    declared_cycle_ns: u32,
    min_interval_ns: u32,
    limit: u16,
    last_event_ns: Option<u32>,
    /// SM-synchronous: when the last event came or the last missed one was counted.
    reference_ns: u32,
    timeout_ns: u32,
    fresh: bool,
    last_interval_ns: u32,
    sm_event_missed: u16,
    cycle_time_too_small: u16,
    error_counter: u16,
    sync_error: bool,
}

/// What a missed event adds to the internal sync error counter, and a good cycle takes away (module docs).
const MISSED_WEIGHT: u16 = 3;

impl SyncCounters {
    /// Counters for `sync` with the sync error counter limit `limit` (0x10F1:02).
    pub fn new(sync: &Synchronisation, limit: u16) -> Self {
        Self {
            mode: sync.mode,
            declared_cycle_ns: sync.cycle_ns,
            min_interval_ns: MIN_CYCLE_NS,
            limit,
            last_event_ns: None,
            reference_ns: 0,
            timeout_ns: 0,
            fresh: false,
            last_interval_ns: 0,
            sm_event_missed: 0,
            cycle_time_too_small: 0,
            error_counter: 0,
            sync_error: false,
        }
    }

    /// Counters for `sync` with the limit the dictionary holds in 0x10F1:02.
    pub fn from_dictionary(sync: &Synchronisation, d: &Dictionary) -> Self {
        Self::new(sync, d.get(h::SYNC_ERROR_COUNTER_LIMIT))
    }

    /// An SM2 event (fresh outputs) at `now_ns`: counts a too-small cycle if it came less than the minimum
    /// cycle after the previous one; SM-synchronous it is a good cycle.
    #[inline]
    pub fn sm_event(&mut self, now_ns: u32) {
        if let Some(last) = self.last_event_ns {
            let interval = now_ns.wrapping_sub(last);
            if interval < self.min_interval_ns {
                self.cycle_time_too_small = self.cycle_time_too_small.saturating_add(1);
            }
            self.last_interval_ns = interval;
        }
        self.last_event_ns = Some(now_ns);
        self.fresh = true;
        if self.mode == SyncMode::SmSynchronous {
            self.error_counter = self.error_counter.saturating_sub(1);
            // One and a half of the longer of the declared and the measured cycle: no false misses when the
            // master runs slower than 0x1C32:02 says (SOEM and ethercrab leave it at its default).
            let cycle = self.declared_cycle_ns.max(self.last_interval_ns);
            self.timeout_ns = cycle.saturating_add(cycle.wrapping_shr(1));
            self.reference_ns = now_ns;
        }
    }

    /// DC: SYNC0 starts a cycle. Without an SM2 event since the previous SYNC0 the event was missed (from the
    /// first SM2 event on: before it the outputs are not valid yet, which the state machine judges).
    #[inline]
    pub fn sync0(&mut self) -> Result<(), AlStatusCode> {
        if self.last_event_ns.is_none() {
            return self.status();
        }
        if self.fresh {
            self.fresh = false;
            self.error_counter = self.error_counter.saturating_sub(1);
            self.status()
        } else {
            self.missed()
        }
    }

    /// SM-synchronous: counts an event missed for every one and a half cycles without one (call it from a
    /// periodic task; free run and DC need no polling). Detection starts with the second SM2 event, when the
    /// master's cycle has been measured.
    #[inline]
    pub fn poll(&mut self, now_ns: u32) -> Result<(), AlStatusCode> {
        if self.mode != SyncMode::SmSynchronous || self.last_interval_ns == 0 {
            return self.status();
        }
        if now_ns.wrapping_sub(self.reference_ns) > self.timeout_ns {
            // The next miss is one cycle later, not another one and a half.
            self.reference_ns = self.reference_ns.wrapping_add(self.declared_cycle_ns.max(self.last_interval_ns));
            return self.missed();
        }
        self.status()
    }

    /// Counts one missed SM event; the sync error is set when the internal counter passes the limit.
    pub fn missed(&mut self) -> Result<(), AlStatusCode> {
        self.sm_event_missed = self.sm_event_missed.saturating_add(1);
        self.error_counter = self.error_counter.saturating_add(MISSED_WEIGHT);
        if self.error_counter > self.limit {
            self.sync_error = true;
        }
        self.status()
    }

    /// `Err(0x001A)` once the sync error is set (it stays until [`SyncCounters::reset`]).
    pub const fn status(&self) -> Result<(), AlStatusCode> {
        if self.sync_error {
            Err(AlStatusCode::SyncError)
        } else {
            Ok(())
        }
    }

    /// SM events missed (sub 0x0B).
    pub const fn sm_event_missed(&self) -> u16 {
        self.sm_event_missed
    }

    /// Cycles too short for the application (sub 0x0C).
    pub const fn cycle_time_too_small(&self) -> u16 {
        self.cycle_time_too_small
    }

    /// The sync error (sub 0x20).
    pub const fn sync_error(&self) -> bool {
        self.sync_error
    }

    /// The last measured interval between two SM2 events, ns (0 before the second).
    pub const fn measured_cycle_ns(&self) -> u32 {
        self.last_interval_ns
    }

    /// Clears the counters and the sync error (a new SAFE-OP, or 0x1C32:08 = 2 "reset").
    pub fn reset(&mut self) {
        *self = Self::new(
            &Synchronisation {
                mode: self.mode,
                cycle_ns: self.declared_cycle_ns,
                sync0_cycle_ns: 0,
                current_periods: 0,
            },
            self.limit,
        );
    }

    /// Writes sub 0x0B, 0x0C and 0x20 of 0x1C32 and 0x1C33 (both objects count the same events: the inputs
    /// follow SM2 or SYNC0).
    #[inline]
    pub fn publish(&self, d: &mut Dictionary) {
        d.set(h::SM2_SM_EVENT_MISSED, self.sm_event_missed);
        d.set(h::SM3_SM_EVENT_MISSED, self.sm_event_missed);
        d.set(h::SM2_CYCLE_TIME_TOO_SMALL, self.cycle_time_too_small);
        d.set(h::SM3_CYCLE_TIME_TOO_SMALL, self.cycle_time_too_small);
        d.set(h::SM2_SYNC_ERROR, self.sync_error);
        d.set(h::SM3_SYNC_ERROR, self.sync_error);
    }
}
