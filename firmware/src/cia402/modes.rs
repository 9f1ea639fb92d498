//! Modes of operation: the requested mode 0x6060, the mode display 0x6061 and the supported drive modes 0x6502.
//!
//! Values and bit layout: IDX L5707-5748 (Table 6-122) and L6735-6770; Gamma L956-997; digest
//! `shared/spec/cia402-device-control.md` §1.8. The drive offers PPM 1, PVM 3, HMM 6, CSP 8, CSV 9 and CST 10 (the
//! IDX set; `device.toml` 0x6060 values and 0x6502 default 0x03A5).
//!
//! Mode changes (what the seeds say, and what is decided here):
//! - 0x6060 "switches the actually chosen operating mode"; the running mode is only in 0x6061, which masters
//!   are told to read after writing 0x6060 (IDX L5709, E3 L6799-6802, Gamma L959). No seed restricts the states
//!   in which the mode may change (Nanotec's figure marks states where "selection of operating mode is admissible /
//!   not admissible", but which ones is not legible, NT p.36 L199), and Gamma's default PDOs are made for a mode
//!   "dynamically switchable among CSP, CSV, and CST" (Gamma L607, L675): switching on the fly while enabled.
//! - 0 is "no mode change assigned" (Gamma Table 6-6 L967): the active mode is kept.
//! - Statusword bit 10 "is always set to 1 when the operation mode is changed" (Gamma L912): the machine reports
//!   the change ([`ModeUpdate::Changed`]) so that the new mode starts with target reached set.
//!
//! Decision: a supported request takes effect at the next tier-2 step in every state, including OE for every pair
//! of modes (the mode layer starts the new mode bumpless from the actual values), except while a stop is running
//! (QSA, FRA, or the ramp of transitions 5, 8, 9): the stop ramps use the deceleration of the active mode (Gamma
//! L1004), so the request is held ([`ModeUpdate::Deferred`]) and applied when the stop has finished. A value the
//! drive does not support is refused and the active mode kept ([`ModeUpdate::Rejected`]); the dictionary already
//! refuses such writes with SDO abort 0x06090030, so this only guards a bypassed dictionary.

/// An operating mode the drive supports.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Mode {
    /// Profile Position Mode, 1.
    ProfilePosition,
    /// Profile Velocity Mode, 3.
    ProfileVelocity,
    /// Homing Mode, 6.
    Homing,
    /// Cyclic Synchronous Position Mode, 8.
    CyclicSyncPosition,
    /// Cyclic Synchronous Velocity Mode, 9.
    CyclicSyncVelocity,
    /// Cyclic Synchronous Torque Mode, 10.
    CyclicSyncTorque,
    /// Auto setup, -2 (0xFE): the motor identification (PD4-E "Auto setup", seed 003 p.25-27, p.76-77; started
    /// by controlword bit 4, statusword bit 12 when done; `crate::drive::auto_setup`). A manufacturer mode: no
    /// bit in 0x6502's CiA 402 part.
    AutoSetup,
}

/// 0x6502 supported drive modes: bits 0 PP, 2 PV, 5 HM, 7 CSP, 8 CSV, 9 CST (IDX L6735-6770; Gamma L997).
pub const SUPPORTED_DRIVE_MODES: u32 = {
    let mut bits = 0u32;
    let mut i = 0;
    while i < Mode::ALL.len() {
        // Const evaluation: an out-of-range index or overflow would fail the build, not the firmware.
        #[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
        {
            bits |= Mode::ALL[i].support_bit();
            i += 1;
        }
    }
    bits
};

/// 0x6060 value 0: no mode change (Gamma Table 6-6).
pub const NO_MODE_CHANGE: i8 = 0;

impl Mode {
    /// Every supported mode.
    pub const ALL: [Mode; 6] = [
        Mode::ProfilePosition,
        Mode::ProfileVelocity,
        Mode::Homing,
        Mode::CyclicSyncPosition,
        Mode::CyclicSyncVelocity,
        Mode::CyclicSyncTorque,
    ];

    /// The 0x6060/0x6061 code.
    pub const fn code(self) -> i8 {
        match self {
            Mode::ProfilePosition => 1,
            Mode::ProfileVelocity => 3,
            Mode::Homing => 6,
            Mode::CyclicSyncPosition => 8,
            Mode::CyclicSyncVelocity => 9,
            Mode::CyclicSyncTorque => 10,
            Mode::AutoSetup => -2,
        }
    }

    /// The mode with this code, or `None` for 0, a reserved value or a mode this drive does not offer (VL 2,
    /// TQ 4, IP 7, vendor modes).
    pub const fn from_code(code: i8) -> Option<Mode> {
        match code {
            1 => Some(Mode::ProfilePosition),
            3 => Some(Mode::ProfileVelocity),
            6 => Some(Mode::Homing),
            8 => Some(Mode::CyclicSyncPosition),
            9 => Some(Mode::CyclicSyncVelocity),
            10 => Some(Mode::CyclicSyncTorque),
            -2 => Some(Mode::AutoSetup),
            _ => None,
        }
    }

    /// The mode's bit in 0x6502.
    pub const fn support_bit(self) -> u32 {
        match self {
            Mode::ProfilePosition => 1 << 0,
            Mode::ProfileVelocity => 1 << 2,
            Mode::Homing => 1 << 5,
            Mode::CyclicSyncPosition => 1 << 7,
            Mode::CyclicSyncVelocity => 1 << 8,
            Mode::CyclicSyncTorque => 1 << 9,
            Mode::AutoSetup => 0,
        }
    }

    /// Whether controlword bit 8 (halt) applies: PPM, PVM, HMM (IDX Table 6-116 L5526-5564; maxon has no halt in
    /// CSP/CSV/CST, where the master commands the stop itself).
    pub const fn halt_applies(self) -> bool {
        matches!(self, Mode::ProfilePosition | Mode::ProfileVelocity | Mode::Homing)
    }

    /// Whether the mode is one of the cyclic synchronous modes.
    pub const fn is_cyclic(self) -> bool {
        matches!(self, Mode::CyclicSyncPosition | Mode::CyclicSyncVelocity | Mode::CyclicSyncTorque)
    }
}

/// What became of the 0x6060 request in one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ModeUpdate {
    /// The request is 0 or the active mode: nothing to do.
    Unchanged,
    /// The active mode changed.
    Changed {
        /// The mode before.
        from: Mode,
        /// The mode now active.
        to: Mode,
    },
    /// A supported mode is requested but a stop is running; it is applied when the stop has finished.
    Deferred(Mode),
    /// The request names no supported mode; the active mode is kept.
    Rejected(i8),
}

/// Tracks the active mode (0x6061) against the requested one (0x6060).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ModeSelector {
    active: Mode,
}

impl ModeSelector {
    /// Starts in `initial` (`device.toml`: 0x6060/0x6061 default 1, PPM, as IDX and E3).
    pub const fn new(initial: Mode) -> Self {
        Self { active: initial }
    }

    /// The active mode.
    pub const fn active(&self) -> Mode {
        self.active
    }

    /// 0x6061, modes of operation display.
    pub const fn display(&self) -> i8 {
        self.active.code()
    }

    /// Applies the request `requested` (0x6060) if `may_change` (no stop running).
    pub fn update(&mut self, requested: i8, may_change: bool) -> ModeUpdate {
        if requested == NO_MODE_CHANGE {
            return ModeUpdate::Unchanged;
        }
        let Some(to) = Mode::from_code(requested) else {
            return ModeUpdate::Rejected(requested);
        };
        if to == self.active {
            ModeUpdate::Unchanged
        } else if may_change {
            let from = self.active;
            self.active = to;
            ModeUpdate::Changed { from, to }
        } else {
            ModeUpdate::Deferred(to)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn supported_modes_match_idx() {
        assert_eq!(SUPPORTED_DRIVE_MODES, 0x0000_03A5);
        for code in i8::MIN..=i8::MAX {
            match Mode::from_code(code) {
                Some(Mode::AutoSetup) => assert_eq!(code, -2),
                Some(m) => {
                    assert_eq!(m.code(), code);
                    assert_ne!(SUPPORTED_DRIVE_MODES & m.support_bit(), 0);
                }
                None => assert!(!matches!(code, 1 | 3 | 6 | 8 | 9 | 10 | -2)),
            }
        }
    }

    #[test]
    fn selector_rules() {
        let mut s = ModeSelector::new(Mode::ProfilePosition);
        assert_eq!(s.update(0, true), ModeUpdate::Unchanged);
        assert_eq!(s.update(7, true), ModeUpdate::Rejected(7));
        assert_eq!(s.update(-128, true), ModeUpdate::Rejected(-128));
        assert_eq!(s.display(), 1);
        assert_eq!(s.update(8, false), ModeUpdate::Deferred(Mode::CyclicSyncPosition));
        assert_eq!(s.display(), 1);
        assert_eq!(
            s.update(8, true),
            ModeUpdate::Changed { from: Mode::ProfilePosition, to: Mode::CyclicSyncPosition }
        );
        assert_eq!(s.display(), 8);
        assert_eq!(s.update(8, true), ModeUpdate::Unchanged);
    }
}
