//! The ESC as the firmware sees it: a register file and process RAM read and written from the PDI side.
//!
//! Register facts: Beckhoff ESC datasheet section II; ETG.1000.4/.6. The emulation in `hal-sim::esc` implements
//! [`Esc`] through its PDI accessors; a board driver implements it over SPI.

/// The PDI side of an EtherCAT slave controller.
pub trait Esc {
    /// Reads `buf.len()` bytes from ESC address `address` (registers below 0x1000, process RAM from 0x1000). A
    /// read that covers the last byte of a sync manager's window completes the buffer, as on the hardware.
    fn read(&mut self, address: u16, buf: &mut [u8]);
    /// Writes `data` at ESC address `address`. A write that covers the last byte of a sync manager's window
    /// completes the buffer.
    fn write(&mut self, address: u16, data: &[u8]);

    /// Reads a little-endian u16.
    fn read_u16(&mut self, address: u16) -> u16 {
        let mut b = [0; 2];
        self.read(address, &mut b);
        u16::from_le_bytes(b)
    }
    /// Reads a little-endian u32.
    fn read_u32(&mut self, address: u16) -> u32 {
        let mut b = [0; 4];
        self.read(address, &mut b);
        u32::from_le_bytes(b)
    }
    /// Writes a little-endian u16.
    fn write_u16(&mut self, address: u16, value: u16) {
        self.write(address, &value.to_le_bytes());
    }
}

/// ESC register addresses the firmware uses (datasheet section II).
pub mod reg {
    /// AL control (master's request), u16.
    pub const AL_CONTROL: u16 = 0x0120;
    /// AL status, u16.
    pub const AL_STATUS: u16 = 0x0130;
    /// AL status code, u16.
    pub const AL_STATUS_CODE: u16 = 0x0134;
    /// AL event request, u32.
    pub const AL_EVENT_REQUEST: u16 = 0x0220;
    /// Watchdog time process data, u16 in units of the watchdog divider 0x0400 (0 = watchdog off).
    pub const WATCHDOG_TIME_PD: u16 = 0x0420;
    /// Watchdog status process data, u16 (bit 0: 1 = not expired).
    pub const WATCHDOG_STATUS_PD: u16 = 0x0440;
    /// First sync manager's configuration; each is 8 bytes.
    pub const SM_BASE: u16 = 0x0800;
    /// DC SYNC activation (0x0981) and cyclic unit control (0x0980).
    pub const DC_ACTIVATION: u16 = 0x0980;
    /// DC SYNC0 cycle time, u32 ns.
    pub const DC_SYNC0_CYCLE: u16 = 0x09A0;
    /// Offset of the status byte in a sync manager's 8 registers (bit 3: mailbox full; bits 5..4: last
    /// buffer written in buffered mode, 0b11 = none since the sync manager was (re)activated).
    pub const SM_STATUS_OFFSET: u16 = 5;
    /// Offset of the activate byte (master: bit 0 enable, bit 1 repeat request).
    pub const SM_ACTIVATE_OFFSET: u16 = 6;
    /// Offset of the PDI control byte (PDI: bit 0 deactivate, bit 1 repeat acknowledge).
    pub const SM_PDI_CONTROL_OFFSET: u16 = 7;

    /// The address of register byte `offset` of sync manager `n`.
    pub fn sm(n: u8, offset: u16) -> u16 {
        SM_BASE.wrapping_add(u16::from(n).wrapping_mul(8)).wrapping_add(offset)
    }
}

/// AL event request bits (0x0220).
pub mod al_event {
    /// AL control written by the master.
    pub const AL_CONTROL: u32 = 1 << 0;
    /// DC SYNC0.
    pub const SYNC0: u32 = 1 << 2;
    /// An SM activate register changed (master side); cleared by a PDI read of an SM activate register.
    pub const SM_ACTIVATION: u32 = 1 << 4;
    /// Sync manager n event: bit 8 + n.
    pub const SM0: u32 = 1 << 8;
}

/// AL states (0x0120/0x0130 bits 3..0) and the error flag (bit 4).
pub mod al_state {
    /// INIT.
    pub const INIT: u16 = 0x01;
    /// PRE-OPERATIONAL.
    pub const PREOP: u16 = 0x02;
    /// BOOTSTRAP.
    pub const BOOT: u16 = 0x03;
    /// SAFE-OPERATIONAL.
    pub const SAFEOP: u16 = 0x04;
    /// OPERATIONAL.
    pub const OP: u16 = 0x08;
    /// The state bits.
    pub const MASK: u16 = 0x0F;
    /// Error indication (status) / error acknowledge (control).
    pub const ERROR: u16 = 0x10;
}

/// A sync manager's configuration as the firmware reads it (0x0800 + 8n).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SmConfig {
    /// Physical start address.
    pub start: u16,
    /// Length in bytes.
    pub length: u16,
    /// Control: bits 1..0 mode (0b00 buffered, 0b10 mailbox), bits 3..2 direction (0b01 master writes).
    pub control: u8,
    /// Activate: bit 0 enable.
    pub activate: u8,
}

impl SmConfig {
    /// Reads sync manager `n` from `esc`.
    pub fn read(esc: &mut impl Esc, n: u8) -> Self {
        let mut b = [0u8; 8];
        esc.read(reg::SM_BASE.wrapping_add(u16::from(n).wrapping_mul(8)), &mut b);
        let [s0, s1, l0, l1, control, _status, activate, _pdi] = b;
        Self { start: u16::from_le_bytes([s0, s1]), length: u16::from_le_bytes([l0, l1]), control, activate }
    }

    /// Enabled by the master.
    pub const fn enabled(&self) -> bool {
        self.activate & 1 != 0
    }

    /// Mailbox (one buffer) mode.
    pub const fn is_mailbox(&self) -> bool {
        self.control & 0x03 == 0x02
    }

    /// The master writes this window.
    pub const fn master_writes(&self) -> bool {
        self.control & 0x0C == 0x04
    }
}

/// AL status codes (0x0134; ETG.1000.6 Table 11, ETG.1020): why a state change was refused or an error state
/// entered.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum AlStatusCode {
    /// No error.
    NoError = 0x0000,
    /// Unspecified error.
    Unspecified = 0x0001,
    /// Invalid requested state change.
    InvalidStateChange = 0x0011,
    /// Unknown requested state.
    UnknownState = 0x0012,
    /// Bootstrap not supported.
    BootstrapNotSupported = 0x0013,
    /// Invalid mailbox configuration (BOOT).
    InvalidBootMailboxConfig = 0x0015,
    /// Invalid mailbox configuration (PRE-OP).
    InvalidMailboxConfig = 0x0016,
    /// Invalid sync manager configuration.
    InvalidSmConfig = 0x0017,
    /// No valid inputs available.
    NoValidInputs = 0x0018,
    /// No valid outputs.
    NoValidOutputs = 0x0019,
    /// Synchronisation error.
    SyncError = 0x001A,
    /// Sync manager watchdog.
    SmWatchdog = 0x001B,
    /// Invalid sync manager types.
    InvalidSmTypes = 0x001C,
    /// Invalid output configuration.
    InvalidOutputConfig = 0x001D,
    /// Invalid input configuration.
    InvalidInputConfig = 0x001E,
    /// Invalid watchdog configuration.
    InvalidWatchdogConfig = 0x001F,
    /// Slave needs cold start.
    NeedsColdStart = 0x0020,
    /// Slave needs INIT.
    NeedsInit = 0x0021,
    /// Slave needs PRE-OP.
    NeedsPreop = 0x0022,
    /// Slave needs SAFE-OP.
    NeedsSafeop = 0x0023,
    /// Invalid input mapping.
    InvalidInputMapping = 0x0024,
    /// Invalid output mapping.
    InvalidOutputMapping = 0x0025,
    /// Inconsistent settings.
    InconsistentSettings = 0x0026,
    /// Free run not supported.
    FreeRunNotSupported = 0x0027,
    /// Synchronisation not supported.
    SyncNotSupported = 0x0028,
    /// Free run needs 3-buffer mode.
    FreeRunNeeds3Buffer = 0x0029,
    /// Background watchdog.
    BackgroundWatchdog = 0x002A,
    /// No valid inputs and outputs.
    NoValidInputsOutputs = 0x002B,
    /// Fatal sync error.
    FatalSyncError = 0x002C,
    /// No sync error (SYNC0 not received).
    NoSyncError = 0x002D,
    /// Invalid DC SYNC configuration.
    InvalidDcSyncConfig = 0x0030,
    /// Invalid DC latch configuration.
    InvalidDcLatchConfig = 0x0031,
    /// PLL error.
    PllError = 0x0032,
    /// DC sync IO error.
    DcSyncIoError = 0x0033,
    /// DC sync timeout error.
    DcSyncTimeout = 0x0034,
    /// DC invalid sync cycle time.
    DcInvalidSyncCycleTime = 0x0035,
    /// DC SYNC0 cycle time.
    DcSync0CycleTime = 0x0036,
    /// DC SYNC1 cycle time.
    DcSync1CycleTime = 0x0037,
    /// Mailbox EoE.
    MailboxEoe = 0x0041,
    /// Mailbox CoE.
    MailboxCoe = 0x0042,
    /// Mailbox FoE.
    MailboxFoe = 0x0043,
    /// Mailbox SoE.
    MailboxSoe = 0x0044,
    /// Mailbox VoE.
    MailboxVoe = 0x004F,
    /// EEPROM no access.
    EepromNoAccess = 0x0050,
    /// EEPROM error.
    EepromError = 0x0051,
    /// Slave restarted locally.
    RestartedLocally = 0x0060,
}
