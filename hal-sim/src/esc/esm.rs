//! A minimal stand-in for the firmware's AL state machine, for tests and tools that run the ESC without
//! firmware. The firmware owns the real decision (ETG.1000.6 §6.4, the spec file item 3); this one only
//! implements the transition table and the two checks the spec file names:
//! - invalid transitions are refused with the error flag and AL status code 0x0011;
//! - INIT -> PRE-OP needs SM0 and SM1 configured as mailboxes (else 0x0016).
//!
//! It runs on the PDI side, exactly like the firmware will: it sees the AL control event, reads 0x0120 and
//! writes 0x0130/0x0134.

use super::registers::{al_event, al_state, reg};
use super::Esc;

/// AL status code: invalid requested state change (ETG.1000.6 Table 11).
pub const CODE_INVALID_TRANSITION: u16 = 0x0011;
/// AL status code: unknown requested state.
pub const CODE_UNKNOWN_STATE: u16 = 0x0012;
/// AL status code: invalid mailbox configuration (PRE-OP).
pub const CODE_INVALID_MAILBOX: u16 = 0x0016;

/// What [`respond_minimal`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AlResponse {
    /// AL control as read.
    pub control: u16,
    /// AL status written.
    pub status: u16,
    /// AL status code written.
    pub code: u16,
}

/// Whether `from -> to` is an ESM transition (ETG.1000.6 Figure 9: INIT<->PREOP<->SAFEOP<->OP, any state
/// back to INIT, OP/SAFEOP back to PREOP, OP back to SAFEOP, INIT<->BOOT).
pub fn transition_allowed(from: u16, to: u16) -> bool {
    use al_state::*;
    matches!(
        (from, to),
        (INIT, INIT | PREOP | BOOT)
            | (PREOP, INIT | PREOP | SAFEOP)
            | (SAFEOP, INIT | PREOP | SAFEOP | OP)
            | (OP, INIT | PREOP | SAFEOP | OP)
            | (BOOT, INIT | BOOT)
    )
}

/// Answers a pending AL control event as a minimal firmware would; `None` when no event is pending.
pub fn respond_minimal(esc: &mut Esc) -> Option<AlResponse> {
    if esc.al_event_request() & al_event::AL_CONTROL == 0 {
        return None;
    }
    let control = esc.pdi_al_control();
    let status = esc.pdi_read_u16(reg::AL_STATUS);
    let current = status & al_state::MASK;
    let requested = control & al_state::MASK;
    let in_error = status & al_state::ERROR != 0;
    let ack = control & al_state::ERROR != 0;
    let (status, code) = if in_error && !ack && requested != al_state::INIT {
        // The error stays until the master acknowledges it (or asks for INIT).
        (status, esc.pdi_read_u16(reg::AL_STATUS_CODE))
    } else if !matches!(requested, al_state::INIT | al_state::PREOP | al_state::BOOT | al_state::SAFEOP | al_state::OP)
    {
        (current | al_state::ERROR, CODE_UNKNOWN_STATE)
    } else if !transition_allowed(current, requested) {
        (current | al_state::ERROR, CODE_INVALID_TRANSITION)
    } else if current == al_state::INIT && requested == al_state::PREOP && !mailboxes_ok(esc) {
        (current | al_state::ERROR, CODE_INVALID_MAILBOX)
    } else {
        (requested, 0)
    };
    esc.pdi_set_al_status(status, code);
    Some(AlResponse { control, status, code })
}

fn mailboxes_ok(esc: &Esc) -> bool {
    let ok = |n: usize, ecat_writes: bool| {
        esc.sm_config(n).is_some_and(|c| c.is_active() && c.is_mailbox() && c.ecat_writes() == ecat_writes)
    };
    ok(0, true) && ok(1, false)
}
