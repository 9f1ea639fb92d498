//! The EtherCAT state machine (ESM; ETG.1000.6 §6.4 "Application layer state machine", the AL control / status
//! registers 0x0120 / 0x0130 / 0x0134 of the ESC datasheet section II), sans-IO: [`Esm::poll`] sees the AL
//! control event (0x0220 bit 0), reads the master's request (0x0120), runs the checks of the transition and
//! answers with AL status and AL status code.
//!
//! Transitions (ETG.1000.6 §6.4 state diagram and transition table; seed digest comms-faults-bootloader.md §1.2):
//!
//! | from \ to | INIT | PRE-OP | BOOT | SAFE-OP | OP |
//! |---|---|---|---|---|---|
//! | INIT | - | mailbox SM0/SM1 = SII (else 0x0016) | boot mailbox (else 0x0015) | 0x0011 | 0x0011 |
//! | PRE-OP | stop mailbox | - | 0x0011 | PDO layout, SM2/SM3, sync (0x001D/0x001E/0x0024/0x0025/...) | 0x0011 |
//! | BOOT | stop mailbox | 0x0011 | - | 0x0011 | 0x0011 |
//! | SAFE-OP | stop all | stop process data | 0x0011 | - | outputs valid (waits; 0x001B after the timeout) |
//! | OP | stop all | stop process data | 0x0011 (to SAFE-OP) | stop outputs | - |
//!
//! A refused request leaves the slave in its state with the error indication (AL status bit 4) and the AL status
//! code; from OP it falls back to SAFE-OP with the error indication, because OP cannot carry an error (ETG.1000.6
//! §6.4.1: a slave that cannot stay in OP indicates SAFE-OP + error; SOES `ESC_state` and the Beckhoff SSC do
//! the same). An unknown requested state gives 0x0012. The error indication stays until the master acknowledges
//! it (AL control bit 4) or requests INIT (ETG.1000.6 §6.4.1; SOES `ESC_state`): a request without the
//! acknowledge is ignored while the error is shown.
//!
//! The ESM also owns the sync managers' PDI side (0x0807 + 8n bit 0, "deactivate"): the mailbox sync managers
//! are enabled on entering PRE-OP/BOOT and disabled in INIT (which also throws away a reply the master never
//! read); the process-data sync managers are enabled on entering SAFE-OP (which resets SM2 so that "outputs
//! valid" means written since then) and disabled below SAFE-OP. On a local error (watchdog) SM2 is disabled so
//! that the master sees the error in the working counter (SOES `ESC_stopoutput`, Beckhoff SSC
//! `StopOutputHandler`); acknowledging the error enables it again.
//!
//! SAFE-OP -> OP needs valid outputs: with outputs mapped, the master must have written SM2 once since SAFE-OP
//! (SM2 status bits 5..4 != 0b11). Until then the request is held (the AL status stays SAFE-OP without error,
//! as the Beckhoff SSC does since V5.11 ESM6), and after [`EsmConfig::safeop_op_timeout_ms`] it is refused
//! with 0x001B (SSC: `ALSTATUSCODE_SMWATCHDOG` when no process data was received). So a master that requests OP
//! first and sends process data while it waits for the state gets through, as does one that sends it before.

use super::esc::{al_event, al_state, reg, AlStatusCode, Esc, SmConfig};
use super::mailbox::MailboxLayout;
use super::process_data::ProcessDataLayout;
use super::sync::{self, Synchronisation};
use crate::od::access::{CommState, Dictionary};

/// The time a SAFE-OP -> OP request may wait for the first outputs: the ESI default `SafeopOpTimeout` of
/// ETG.2000 (10 s), which masters use as their own timeout for this transition.
pub const SAFEOP_OP_TIMEOUT_MS: u32 = 10_000;

/// The AL states (AL control / status bits 3..0; ETG.1000.6 §6.4.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AlState {
    /// INIT (0x01): no mailbox, no process data.
    Init,
    /// PRE-OPERATIONAL (0x02): mailbox.
    PreOp,
    /// BOOTSTRAP (0x03): mailbox with FoE only (firmware download).
    Boot,
    /// SAFE-OPERATIONAL (0x04): mailbox and inputs; outputs in their safe state.
    SafeOp,
    /// OPERATIONAL (0x08): mailbox, inputs and outputs.
    Op,
}

impl AlState {
    /// The state's code in AL control / AL status.
    pub const fn code(self) -> u16 {
        match self {
            Self::Init => al_state::INIT,
            Self::PreOp => al_state::PREOP,
            Self::Boot => al_state::BOOT,
            Self::SafeOp => al_state::SAFEOP,
            Self::Op => al_state::OP,
        }
    }

    /// The state for a code (bits 3..0), or `None` for a code that names no state.
    pub const fn from_code(code: u16) -> Option<Self> {
        match code {
            al_state::INIT => Some(Self::Init),
            al_state::PREOP => Some(Self::PreOp),
            al_state::BOOT => Some(Self::Boot),
            al_state::SAFEOP => Some(Self::SafeOp),
            al_state::OP => Some(Self::Op),
            _ => None,
        }
    }

    /// The communication state the dictionary judges writes in.
    pub const fn comm_state(self) -> CommState {
        match self {
            Self::Init => CommState::Init,
            Self::PreOp => CommState::PreOperational,
            Self::Boot => CommState::Bootstrap,
            Self::SafeOp => CommState::SafeOperational,
            Self::Op => CommState::Operational,
        }
    }

    /// Whether the mailbox runs in this state (every state but INIT).
    pub const fn mailbox_runs(self) -> bool {
        !matches!(self, Self::Init)
    }
}

/// What the ESM checks against.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EsmConfig {
    /// The standard mailbox (SII words 0x18..0x1B, category SM), checked on INIT -> PRE-OP.
    pub mailbox: MailboxLayout,
    /// The bootstrap mailbox (SII words 0x14..0x17), checked on INIT -> BOOT.
    pub boot_mailbox: MailboxLayout,
    /// Whether BOOT exists (FoE firmware download); else INIT -> BOOT is refused with 0x0013.
    pub boot_supported: bool,
    /// How long SAFE-OP -> OP waits for the first outputs before 0x001B.
    pub safeop_op_timeout_ms: u32,
}

impl EsmConfig {
    /// The drive's configuration: both mailboxes as od-gen writes them into the SII (same addresses and sizes,
    /// `firmware/device.toml` section `[device]`, keys `mailbox_*`), BOOT supported.
    pub const DRIVE: Self = Self {
        mailbox: MailboxLayout::DRIVE,
        boot_mailbox: MailboxLayout::DRIVE,
        boot_supported: true,
        safeop_op_timeout_ms: SAFEOP_OP_TIMEOUT_MS,
    };
}

/// A state change the ESM made or refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transition {
    /// The state before.
    pub from: AlState,
    /// The state after (with the error indication when `code` is not [`AlStatusCode::NoError`]).
    pub to: AlState,
    /// The AL status code written (0 = success).
    pub code: AlStatusCode,
}

/// The EtherCAT state machine. See the module documentation.
#[derive(Clone, Debug)]
pub struct Esm {
    config: EsmConfig,
    state: AlState,
    error: Option<AlStatusCode>,
    started: bool,
    /// Time (ms) at which a SAFE-OP -> OP request began to wait for valid outputs.
    pending_op: Option<u32>,
    layout: Option<ProcessDataLayout>,
    synchronisation: Option<Synchronisation>,
    /// SM2 disabled by a local error until the master acknowledges it.
    outputs_blocked: bool,
}

/// Sets or clears the PDI "deactivate" bit (0x0807 + 8n bit 0) of sync manager `n`, keeping the repeat
/// acknowledge (bit 1). Changing it resets the sync manager's buffer state on the ESC.
pub(crate) fn set_sm_deactivated<E: Esc>(esc: &mut E, n: u8, deactivated: bool) {
    let at = reg::sm(n, reg::SM_PDI_CONTROL_OFFSET);
    let mut b = [0u8; 1];
    esc.read(at, &mut b);
    let [old] = b;
    let new = if deactivated { old | 0x01 } else { old & !0x01 };
    if new != old {
        esc.write(at, &[new]);
    }
}

impl Esm {
    /// An ESM in INIT. The first [`Esm::poll`] writes AL status INIT and disables the sync managers.
    pub const fn new(config: EsmConfig) -> Self {
        Self {
            config,
            state: AlState::Init,
            error: None,
            started: false,
            pending_op: None,
            layout: None,
            synchronisation: None,
            outputs_blocked: false,
        }
    }

    /// The current state.
    pub const fn state(&self) -> AlState {
        self.state
    }

    /// The AL status code shown with the error indication, if the error indication is on.
    pub const fn error(&self) -> Option<AlStatusCode> {
        self.error
    }

    /// The AL status register value (state | error indication).
    pub const fn status(&self) -> u16 {
        let error = if self.error.is_some() { al_state::ERROR } else { 0 };
        self.state.code() | error
    }

    /// Whether the master has asked for OP and the ESM waits for the first outputs.
    pub const fn op_pending(&self) -> bool {
        self.pending_op.is_some()
    }

    /// The communication state for the dictionary's write conditions.
    pub const fn comm_state(&self) -> CommState {
        self.state.comm_state()
    }

    /// Whether the inputs (SM3) are updated: SAFE-OP and OP.
    pub const fn inputs_enabled(&self) -> bool {
        matches!(self.state, AlState::SafeOp | AlState::Op)
    }

    /// Whether the outputs (SM2) are applied: OP only (in SAFE-OP the drive ignores the master's set-points,
    /// comms-faults-bootloader.md §1.2 table).
    pub const fn outputs_enabled(&self) -> bool {
        matches!(self.state, AlState::Op)
    }

    /// The process-data layout compiled on PRE-OP -> SAFE-OP (in SAFE-OP and OP).
    pub const fn layout(&self) -> Option<&ProcessDataLayout> {
        self.layout.as_ref()
    }

    /// The synchronisation resolved on PRE-OP -> SAFE-OP (in SAFE-OP and OP); the caller publishes it into
    /// 0x1C32/0x1C33 ([`Synchronisation::publish`]) and runs the cycle with it.
    pub const fn synchronisation(&self) -> Option<&Synchronisation> {
        self.synchronisation.as_ref()
    }

    /// Runs the ESM once: answers a pending AL control request, completes or times out a SAFE-OP -> OP
    /// request that waits for outputs, and re-checks the sync managers when the master changed one
    /// (AL event 0x0220 bit 4; SOES `ESC_sm_act_event`). `dict` is the dictionary the PDO layout is compiled
    /// from; `now_ms` a free-running millisecond clock (wrapping). Returns the transition made or refused.
    ///
    /// Call it before the mailbox's poll in the same loop, so that the SM-activation event, which any read of
    /// an SM activate register clears, is seen here first.
    pub fn poll<E: Esc>(&mut self, esc: &mut E, dict: &Dictionary, now_ms: u32) -> Option<Transition> {
        if !self.started {
            self.started = true;
            for n in 0..4 {
                set_sm_deactivated(esc, n, true);
            }
            self.write_status(esc);
        }
        let events = esc.read_u32(reg::AL_EVENT_REQUEST);
        if events & al_event::AL_CONTROL != 0 {
            let control = esc.read_u16(reg::AL_CONTROL);
            return self.on_control(esc, control, dict, now_ms);
        }
        if let Some(since) = self.pending_op {
            return self.try_op(esc, since, now_ms);
        }
        if events & al_event::SM_ACTIVATION != 0 {
            return self.recheck_sync_managers(esc);
        }
        None
    }

    /// A local error (process-data watchdog, synchronisation loss): from SAFE-OP or OP the ESM goes to SAFE-OP
    /// with the error indication and `code` and disables SM2 (the Beckhoff SSC's `ECAT_StateChange(SAFEOP,
    /// code)`, GT 0x10F1:01 "ErrSafeOp"); in the other states the error indication is shown in the current state.
    pub fn local_error<E: Esc>(&mut self, esc: &mut E, code: AlStatusCode) -> Transition {
        let from = self.state;
        if matches!(from, AlState::SafeOp | AlState::Op) {
            set_sm_deactivated(esc, 2, true);
            self.outputs_blocked = true;
            self.state = AlState::SafeOp;
        }
        self.pending_op = None;
        self.error = Some(code);
        self.write_status(esc);
        Transition { from, to: self.state, code }
    }

    fn write_status<E: Esc>(&self, esc: &mut E) {
        // The code first, so that a master that sees the error flag reads the matching code.
        let code = self.error.unwrap_or(AlStatusCode::NoError);
        esc.write_u16(reg::AL_STATUS_CODE, code as u16);
        esc.write_u16(reg::AL_STATUS, self.status());
    }

    fn on_control<E: Esc>(&mut self, esc: &mut E, control: u16, dict: &Dictionary, now_ms: u32) -> Option<Transition> {
        let requested = control & al_state::MASK;
        let acknowledge = control & al_state::ERROR != 0;
        if self.error.is_some() && !acknowledge && requested != al_state::INIT {
            // The error indication stays until acknowledged (ETG.1000.6 §6.4.1).
            return None;
        }
        let from = self.state;
        self.error = None;
        self.pending_op = None;
        let Some(target) = AlState::from_code(requested) else {
            return Some(self.refuse(esc, from, AlStatusCode::UnknownState));
        };
        if self.outputs_blocked && from == AlState::SafeOp && matches!(target, AlState::SafeOp | AlState::Op) {
            // The master acknowledged the local error: SM2 comes back (reset, so outputs must be written anew).
            set_sm_deactivated(esc, 2, false);
            self.outputs_blocked = false;
        }
        match self.enter(esc, from, target, dict) {
            Ok(true) => {
                self.state = target;
                self.write_status(esc);
                Some(Transition { from, to: target, code: AlStatusCode::NoError })
            }
            Ok(false) => {
                // SAFE-OP -> OP waits for outputs; the status stays SAFE-OP (error cleared if acknowledged).
                self.write_status(esc);
                self.pending_op = Some(now_ms);
                self.try_op(esc, now_ms, now_ms)
            }
            Err(code) => Some(self.refuse(esc, from, code)),
        }
    }

    /// Refuses a request in state `from` with `code`: the error indication in `from`, or SAFE-OP when `from` is
    /// OP (the outputs stop).
    fn refuse<E: Esc>(&mut self, esc: &mut E, from: AlState, code: AlStatusCode) -> Transition {
        if from == AlState::Op {
            self.state = AlState::SafeOp;
        }
        self.error = Some(code);
        self.write_status(esc);
        Transition { from, to: self.state, code }
    }

    /// Runs the checks and the side effects of `from -> to`: `Ok(true)` done, `Ok(false)` SAFE-OP -> OP has to
    /// wait for outputs, `Err` refused with the code.
    fn enter<E: Esc>(
        &mut self,
        esc: &mut E,
        from: AlState,
        to: AlState,
        dict: &Dictionary,
    ) -> Result<bool, AlStatusCode> {
        use AlState::*;
        match (from, to) {
            (a, b) if a == b => Ok(true),
            // Stop everything (ETG.1000.6 transitions PI, SI, OI, BI): the mailbox and process data.
            (_, Init) => self.enter_init(esc),
            (Init, PreOp) => {
                if !self.config.mailbox.matches(esc) {
                    return Err(AlStatusCode::InvalidMailboxConfig);
                }
                set_sm_deactivated(esc, 0, false);
                set_sm_deactivated(esc, 1, false);
                Ok(true)
            }
            (Init, Boot) => {
                if !self.config.boot_supported {
                    return Err(AlStatusCode::BootstrapNotSupported);
                }
                if !self.config.boot_mailbox.matches(esc) {
                    return Err(AlStatusCode::InvalidBootMailboxConfig);
                }
                set_sm_deactivated(esc, 0, false);
                set_sm_deactivated(esc, 1, false);
                Ok(true)
            }
            (PreOp, SafeOp) => {
                // The PDO configuration (0x0025 outputs / 0x0024 inputs), then SM2/SM3 against it (0x001D /
                // 0x001E), then 0x1C32/0x1C33 against the DC registers (sync module: 0x0027, 0x0028, 0x0030,
                // 0x0035, 0x0036; comms-faults-bootloader.md §1.2 "Derived ESM rules").
                let layout = ProcessDataLayout::compile(dict).map_err(|e| e.al_status())?;
                let sm2 = SmConfig::read(esc, 2);
                let sm3 = SmConfig::read(esc, 3);
                layout.check_sync_managers(&sm2, &sm3)?;
                let synchronisation = sync::check_esc(esc, dict)?;
                set_sm_deactivated(esc, 3, false);
                set_sm_deactivated(esc, 2, false);
                self.layout = Some(layout);
                self.synchronisation = Some(synchronisation);
                Ok(true)
            }
            (SafeOp, Op) => Ok(self.outputs_valid(esc)),
            (SafeOp | Op, PreOp) => {
                set_sm_deactivated(esc, 2, true);
                set_sm_deactivated(esc, 3, true);
                self.layout = None;
                self.synchronisation = None;
                self.outputs_blocked = false;
                Ok(true)
            }
            (Op, SafeOp) => Ok(true),
            _ => Err(AlStatusCode::InvalidStateChange),
        }
    }

    /// Whether the outputs are valid for OP: no outputs mapped, or SM2 written completely since it was enabled
    /// (status bits 5..4 "last buffer written" != 0b11, ESC datasheet register 0x0805).
    fn outputs_valid<E: Esc>(&self, esc: &mut E) -> bool {
        if self.layout.as_ref().is_some_and(|l| l.output_bytes == 0) {
            return true;
        }
        let mut status = [0u8; 1];
        esc.read(reg::sm(2, reg::SM_STATUS_OFFSET), &mut status);
        let [status] = status;
        status & 0x30 != 0x30
    }

    /// Completes a waiting SAFE-OP -> OP when the outputs are valid, or refuses it after the timeout (0x001B).
    fn try_op<E: Esc>(&mut self, esc: &mut E, since: u32, now_ms: u32) -> Option<Transition> {
        if self.outputs_valid(esc) {
            self.pending_op = None;
            self.state = AlState::Op;
            self.write_status(esc);
            return Some(Transition { from: AlState::SafeOp, to: AlState::Op, code: AlStatusCode::NoError });
        }
        if now_ms.wrapping_sub(since) >= self.config.safeop_op_timeout_ms {
            self.pending_op = None;
            return Some(self.refuse(esc, AlState::SafeOp, AlStatusCode::SmWatchdog));
        }
        None
    }

    /// The master changed a sync manager's activation while the mailbox or process data runs: a mailbox that no
    /// longer matches drops the slave to INIT + error 0x0016, process-data sync managers that no longer match the
    /// layout drop it to PRE-OP + error 0x001D/0x001E (SOES `ESC_sm_act_event`).
    fn recheck_sync_managers<E: Esc>(&mut self, esc: &mut E) -> Option<Transition> {
        let from = self.state;
        let mailbox = match from {
            AlState::Init => return None,
            AlState::Boot => self.config.boot_mailbox,
            _ => self.config.mailbox,
        };
        if !mailbox.matches(esc) {
            let _ = self.enter_init(esc);
            self.state = AlState::Init;
            self.pending_op = None;
            self.error = Some(AlStatusCode::InvalidMailboxConfig);
            self.write_status(esc);
            return Some(Transition { from, to: AlState::Init, code: AlStatusCode::InvalidMailboxConfig });
        }
        if let (AlState::SafeOp | AlState::Op, Some(layout)) = (from, self.layout.as_ref()) {
            let sm2 = SmConfig::read(esc, 2);
            let sm3 = SmConfig::read(esc, 3);
            if let Err(code) = layout.check_sync_managers(&sm2, &sm3) {
                set_sm_deactivated(esc, 2, true);
                set_sm_deactivated(esc, 3, true);
                self.layout = None;
                self.synchronisation = None;
                self.outputs_blocked = false;
                self.state = AlState::PreOp;
                self.pending_op = None;
                self.error = Some(code);
                self.write_status(esc);
                return Some(Transition { from, to: AlState::PreOp, code });
            }
        }
        None
    }

    /// Disables all four sync managers and forgets the process-data layout.
    fn enter_init<E: Esc>(&mut self, esc: &mut E) -> Result<bool, AlStatusCode> {
        for n in 0..4 {
            set_sm_deactivated(esc, n, true);
        }
        self.layout = None;
        self.synchronisation = None;
        self.outputs_blocked = false;
        Ok(true)
    }
}
