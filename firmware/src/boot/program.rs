//! Program control (CiA 302-3 as the IDX firmware specification and the EPOS4 application notes describe it):
//! 0x1F50 program data, 0x1F51 program control, 0x1F56 program software identification, 0x1F57 flash status,
//! and the FoE write in BOOT, all feeding one [`Download`] into slot B.
//!
//! # Sequence (IDX L3343-3381, L3350-3352; E4 Table 4-27/4-28 L2009-2093)
//! 1. 0x1F51:01 = 0 *stop program*: accepted only with the power stage disabled (E4 step "prepare controller");
//!    otherwise 0x0800_0022. The drive then behaves as with its bootloader active: the platform switches the
//!    dictionary to [`super::tables::BOOTLOADER_TABLE`] (0x1000 = 0x0000_012E, the reduced object set of E4
//!    Table 4-33) and the program objects are locked to the interface that sent the stop (IDX L3345-3350: "only
//!    one communication interface can be used ... until the application is started or the device is reset").
//! 2. 0x1F51:01 = 3 *clear program*: erases slot B (its image area).
//! 3. 0x1F50:01 *program data*: the image by segmented or block SDO, segment by segment at increasing offsets
//!    ([`Download::write`]); the last segment verifies the image in flash ([`Download::finish`]).
//! 4. 0x1F51:01 = 1 *start program*: a verified image is recorded as pending ([`Download::activate`]) and the
//!    platform resets ([`Request::Reset`]); the bootloader swaps it in ([`super::loader`]). Without a new image
//!    the stopped application simply starts again ([`Request::Start`]).
//! 5. 0x1F51:01 = 2 *reset program*: a device reset ([`Request::Reset`]). 0x80 (*ESM state change acknowledge
//!    upon application restart*, IDX L3343-3381) is remembered for the platform ([`ProgramControl::esm_acknowledge`]).
//!
//! On EtherCAT the same download arrives by FoE in BOOT (E4 Table 4-29 L2095-2130): a write request for the file
//! [`FOE_FILE_NAME`] with password [`FOE_PASSWORD`] stops the program and clears slot B, the data packets are the
//! image, the end of file verifies and activates it, and leaving BOOT (the master requests INIT) resets the drive.
//!
//! # Which interface asked
//! The dictionary's [`ApplicationObjects`] hook does not know the interface, so each fieldbus server builds a
//! [`ProgramPort`] for its transfer with [`ProgramControl::port`], naming its [`Interface`]. While the program is
//! stopped, a port of another interface is refused: 0x0800_0021 (CiA 301 Table 22: "because of local control")
//! on SDO, FoE 0x8004 (illegal in the present state).
//!
//! # Refusals
//! Every refusal is an SDO abort code (or FoE error code) and a 0x1F57 status (IDX L3413-3473, bits 7..1); the
//! running image and slot A are never touched by a download, so the old firmware keeps running:
//!
//! | cause | SDO abort | 0x1F57 status | FoE error |
//! |---|---|---|---|
//! | 0x1F50 without stop + clear, clear without stop | 0x0800_0022 | 66 authentication sequence error | 0x8004 |
//! | stop with the power stage on | 0x0800_0022 | unchanged | 0x8004 |
//! | another interface while stopped | 0x0800_0021 | unchanged | 0x8004 |
//! | image on trial not confirmed (slot B is the way back) | 0x0800_0022 | 7 flash secured | 0x8004 |
//! | unknown format (magic, version, header, load address) | 0x0609_0030 | 2 data format unknown | 0x8012 |
//! | wrong hardware id | 0x0609_0030 | 64 hardware version mismatch | 0x800D |
//! | payload CRC | 0x0800_0020 | 3 data CRC error | 0x800C |
//! | signature (forged, altered, other key) | 0x0800_0020 | 93 signature invalid (manufacturer-specific, IDX 93-127) | 0x8009 |
//! | security version below the minimum (anti-rollback, [`super::state`]) | 0x0609_0032 value too low | 94 image older than the minimum security version (manufacturer-specific) | 0x8009 |
//! | truncated (fewer bytes than the header says) | 0x0607_0013 | 3 data format error | 0x800B |
//! | oversized (beyond the slot or the header's length) | 0x0607_0012 | 6 general address error | 0x8003 |
//! | flash program / state log failure | 0x0606_0000 | 5 flash write error | 0x8011 |
//! | flash erase failure (clear) | 0x0606_0000 | 65 flash clear error | 0x8011 |
//!
//! The security version is checked when the header has arrived (the 0x1F50 transfer or FoE data packet that
//! completes it is refused), again when the image is verified (end of 0x1F50, FoE end of file) and at *start*.
//! An FoE error answer carries the 0x1F57 status as its text ([`status_text`], ETG.1000.5 FoE error request:
//! error code and error text), so that 93 and 94, which share 0x8009 "not bootstrap" (IDX Table 7-155: "file not
//! accepted for firmware update"), are told apart there too.

use core::cell::RefCell;

use super::image::ImageError;
use super::loader::Outcome;
use super::swap::BootFlash;
use super::update::{self, Download, Phase, UpdateError};
use super::verify::Trust;
use crate::drive::objects::{
    FLASH_STATUS_IDENTIFICATION, PROGRAM_CONTROL, PROGRAM_DATA, PROGRAM_SOFTWARE_IDENTIFICATION,
};
use crate::ecat::foe::{FoeAccess, FoeError, FoeProgress, FoeSink};
use crate::hal::flash::NorFlash;
use crate::od::abort::SdoAbort;
use crate::od::access::{ApplicationObjects, ReadOutcome};
use crate::od::entry::Entry;

/// The bootloader identification in bits 15..0 of 0x1F56:01 (IDX L3382-3412).
pub const BOOTLOADER_ID: u16 = 0x0001;
/// The FoE file name of a firmware download (E4 Table 4-29 step C, L2095-2130: target file name "EPOS4").
pub const FOE_FILE_NAME: &[u8] = b"EPOS4";
/// The FoE password of a firmware download (E4 Table 4-29 step C: password 0).
pub const FOE_PASSWORD: u32 = 0;
/// Size of the verification buffer (a multiple of the F405's write size).
pub const VERIFY_BUF_LEN: usize = 1024;

/// 0x1F51:01 command values (IDX L3343-3381).
pub mod command {
    /// Stop program: activate the bootloader.
    pub const STOP: u8 = 0x00;
    /// Start program: activate the application.
    pub const START: u8 = 0x01;
    /// Reset program: device reset.
    pub const RESET: u8 = 0x02;
    /// Clear program: erase the flash before a download.
    pub const CLEAR: u8 = 0x03;
    /// ESM state change acknowledge upon application restart.
    pub const ESM_ACKNOWLEDGE: u8 = 0x80;
}

/// 0x1F51:01 read values (IDX L3343-3381).
pub mod program_state {
    /// Program stopped: the bootloader is active.
    pub const STOPPED: u8 = 0x00;
    /// Program started: the application is active.
    pub const STARTED: u8 = 0x01;
    /// No valid application in flash.
    pub const NO_PROGRAM: u8 = 0x03;
}

/// 0x1F57:01 status codes, bits 7..1 (IDX L3413-3473).
pub mod status {
    /// No error, valid program available.
    pub const OK: u8 = 0;
    /// No valid program available.
    pub const NO_PROGRAM: u8 = 1;
    /// Data format unknown.
    pub const FORMAT_UNKNOWN: u8 = 2;
    /// Data format error or data CRC error.
    pub const DATA_ERROR: u8 = 3;
    /// Flash write error.
    pub const WRITE_ERROR: u8 = 5;
    /// General address error.
    pub const ADDRESS_ERROR: u8 = 6;
    /// Flash secured (write access currently forbidden).
    pub const SECURED: u8 = 7;
    /// Hardware version mismatch.
    pub const HARDWARE_MISMATCH: u8 = 64;
    /// Flash clear error.
    pub const CLEAR_ERROR: u8 = 65;
    /// Authentication sequence error (stop -> clear -> program data not observed).
    pub const SEQUENCE_ERROR: u8 = 66;
    /// Manufacturer-specific (IDX reserves 93-127): the Ed25519 signature does not verify with the trusted key.
    pub const SIGNATURE_INVALID: u8 = 93;
    /// Manufacturer-specific (IDX reserves 93-127): the image's security version is below the minimum the drive
    /// accepts (anti-rollback, [`crate::boot::state`]).
    pub const ROLLBACK: u8 = 94;
}

/// The text of a 0x1F57 status, sent with an FoE error (module documentation); empty for 0 "no error".
pub const fn status_text(code: u8) -> &'static [u8] {
    match code {
        status::NO_PROGRAM => b"no valid program",
        status::FORMAT_UNKNOWN => b"data format unknown",
        status::DATA_ERROR => b"data format or CRC error",
        status::WRITE_ERROR => b"flash write error",
        status::ADDRESS_ERROR => b"address error",
        status::SECURED => b"flash secured",
        status::HARDWARE_MISMATCH => b"hardware version mismatch",
        status::CLEAR_ERROR => b"flash clear error",
        status::SEQUENCE_ERROR => b"sequence error",
        status::SIGNATURE_INVALID => b"signature invalid",
        status::ROLLBACK => b"image older than minimum security version",
        _ => b"",
    }
}

/// The 0x1F57:01 word (IDX L3413-3473): status code `status` in bits 7..1, bit 0 set while `phase` is receiving.
/// Program control and the bootloader's fallback ([`super::fallback`]) both report through it.
pub fn flash_status_word(status: u8, phase: Phase) -> u32 {
    let in_progress = u32::from(matches!(phase, Phase::Receiving));
    (u32::from(status & 0x7F) << 1) | in_progress
}

/// The fieldbus (or service) interface a request came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interface {
    /// CANopen SDO.
    Canopen,
    /// EtherCAT CoE SDO or FoE.
    Ethercat,
    /// A service interface (USB, serial).
    Service,
}

/// What the platform must do after a program-control request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request {
    /// The program stopped: behave as the bootloader (reduced dictionary, power stage kept off).
    Stop,
    /// The stopped application starts again (no new image).
    Start,
    /// A device reset: the bootloader runs (and activates a pending image).
    Reset,
}

/// Whether the application runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// The application runs.
    Running,
    /// The program is stopped (or there is none); `owner` is the interface the bootloader is locked to.
    Stopped {
        /// The first interface that sent a command (IDX L3345-3350).
        owner: Option<Interface>,
    },
}

/// A refusal in the three vocabularies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refusal {
    /// The SDO abort code.
    pub abort: SdoAbort,
    /// The 0x1F57 status (`None`: the status is left as it was).
    pub status: Option<u8>,
    /// The FoE error code.
    pub foe: FoeError,
}

const fn refusal(abort: SdoAbort, status: Option<u8>, foe: FoeError) -> Refusal {
    Refusal { abort, status, foe }
}

/// The refusal of an update error (table in the module documentation).
pub const fn classify(e: UpdateError) -> Refusal {
    match e {
        UpdateError::Sequence => refusal(SdoAbort::DeviceState, Some(status::SEQUENCE_ERROR), FoeError::Illegal),
        UpdateError::NotConfirmed => refusal(SdoAbort::DeviceState, Some(status::SECURED), FoeError::Illegal),
        UpdateError::OutOfOrder { .. } => {
            refusal(SdoAbort::GeneralError, Some(status::ADDRESS_ERROR), FoeError::PacketNumber)
        }
        UpdateError::Flash(_) | UpdateError::StateFull | UpdateError::Image(ImageError::Flash(_)) => {
            refusal(SdoAbort::HardwareError, Some(status::WRITE_ERROR), FoeError::FlashProblem)
        }
        UpdateError::Image(ImageError::Truncated) => {
            refusal(SdoAbort::LengthTooLow, Some(status::DATA_ERROR), FoeError::ProgramError)
        }
        UpdateError::Image(ImageError::TrailingData | ImageError::Oversized { .. }) => {
            refusal(SdoAbort::LengthTooHigh, Some(status::ADDRESS_ERROR), FoeError::DiskFull)
        }
        UpdateError::Image(
            ImageError::BadMagic
            | ImageError::UnsupportedVersion(_)
            | ImageError::MalformedHeader
            | ImageError::WrongLoadAddress(_),
        ) => refusal(SdoAbort::InvalidValue, Some(status::FORMAT_UNKNOWN), FoeError::FileIncompatible),
        UpdateError::Image(ImageError::WrongHardware { .. }) => {
            refusal(SdoAbort::InvalidValue, Some(status::HARDWARE_MISMATCH), FoeError::FirmwareMismatch)
        }
        UpdateError::Image(ImageError::Crc { .. }) => {
            refusal(SdoAbort::CannotTransfer, Some(status::DATA_ERROR), FoeError::Checksum)
        }
        UpdateError::Image(ImageError::BadSignature) => {
            refusal(SdoAbort::CannotTransfer, Some(status::SIGNATURE_INVALID), FoeError::NotBootstrap)
        }
        // CiA 301 Table 22 0x0609_0032 "value of parameter written too low": the header's security version.
        UpdateError::Image(ImageError::Rollback { .. }) => {
            refusal(SdoAbort::ValueTooLow, Some(status::ROLLBACK), FoeError::NotBootstrap)
        }
    }
}

/// Program control over the three update regions. See the module documentation.
#[derive(Debug)]
pub struct ProgramControl<A, B, S> {
    flash: BootFlash<A, B, S>,
    trust: Trust,
    running: Option<super::image::ImageHeader>,
    trial: bool,
    mode: Mode,
    download: Download,
    status: u8,
    request: Option<Request>,
    esm_acknowledge: bool,
    /// The FoE code of the refusal just made, until its FoE answer takes its text ([`status_text`]).
    refused: Option<FoeError>,
    buf: [u8; VERIFY_BUF_LEN],
}

impl<A: NorFlash, B: NorFlash, S: NorFlash> ProgramControl<A, B, S> {
    /// Program control over `flash`, before the loader ran: no program known yet (call
    /// [`ProgramControl::started`] with the loader's outcome).
    pub fn new(flash: BootFlash<A, B, S>, trust: Trust) -> Self {
        Self {
            flash,
            trust,
            running: None,
            trial: false,
            mode: Mode::Stopped { owner: None },
            download: Download::new(),
            status: status::NO_PROGRAM,
            request: None,
            esm_acknowledge: false,
            refused: None,
            buf: [0; VERIFY_BUF_LEN],
        }
    }

    /// The regions (the loader runs over them at a reset).
    pub fn flash_mut(&mut self) -> &mut BootFlash<A, B, S> {
        &mut self.flash
    }

    /// The regions.
    pub const fn flash(&self) -> &BootFlash<A, B, S> {
        &self.flash
    }

    /// The trust anchor (key, hardware id, slot size).
    pub const fn trust(&self) -> &Trust {
        &self.trust
    }

    /// After a reset: what the loader started. A run image is the program (0x1F56; the platform shows its version
    /// string in 0x100A with [`super::tables::show_software_version`]); without one the
    /// program stays stopped with no interface locked yet (0x1F51 reads 3, 0x1F57 status 1).
    pub fn started(&mut self, outcome: Outcome) {
        self.download = Download::new();
        self.request = None;
        match outcome {
            Outcome::Run { header, trial, .. } => {
                self.running = Some(header);
                self.trial = trial;
                self.mode = Mode::Running;
                self.status = status::OK;
            }
            Outcome::NoValidImage(_) => {
                self.running = None;
                self.trial = false;
                self.mode = Mode::Stopped { owner: None };
                self.status = status::NO_PROGRAM;
            }
        }
    }

    /// The running image confirms itself after a successful start (ends its trial and raises the minimum security
    /// version to its own; [`update::confirm`]).
    pub fn confirm(&mut self) -> Result<bool, UpdateError> {
        let security_version = self.running.map_or(0, |h| h.security_version);
        let confirmed = update::confirm(&mut self.flash.state, security_version)?;
        self.trial = false;
        Ok(confirmed)
    }

    /// Whether the running image is on trial (not confirmed yet).
    pub const fn on_trial(&self) -> bool {
        self.trial
    }

    /// The header of the running image (what the loader verified).
    pub const fn running(&self) -> Option<&super::image::ImageHeader> {
        self.running.as_ref()
    }

    /// Running or stopped.
    pub const fn mode(&self) -> Mode {
        self.mode
    }

    /// Where the download stands.
    pub fn download_phase(&self) -> Phase {
        self.download.phase()
    }

    /// Whether 0x1F51 = 0x80 asked for the ESM state change acknowledge at the application's restart.
    pub const fn esm_acknowledge(&self) -> bool {
        self.esm_acknowledge
    }

    /// The platform's next action, taken once.
    pub fn take_request(&mut self) -> Option<Request> {
        self.request.take()
    }

    /// 0x1F51:01 as read.
    pub const fn program_state(&self) -> u8 {
        match (self.mode, self.running.is_some()) {
            (Mode::Running, _) => program_state::STARTED,
            (Mode::Stopped { .. }, true) => program_state::STOPPED,
            (Mode::Stopped { .. }, false) => program_state::NO_PROGRAM,
        }
    }

    /// 0x1F56:01: application identification (bits 31..16, from the running image's header) and bootloader
    /// identification (bits 15..0); the application part is 0 without a valid program (IDX L3382-3412).
    pub fn software_identification(&self) -> u32 {
        let app = self.running.map_or(0, |h| h.software_id & 0xFFFF_0000);
        app | u32::from(BOOTLOADER_ID)
    }

    /// 0x1F57:01: status code in bits 7..1, bit 0 set while a download is in progress (IDX L3413-3473).
    pub fn flash_status(&self) -> u32 {
        flash_status_word(self.status, self.download.phase())
    }

    /// The 0x1F57 status code alone.
    pub const fn status_code(&self) -> u8 {
        self.status
    }

    /// The hook for one transfer from `interface`; `power_stage_enabled` is the drive's state now
    /// ([`crate::drive::Drive::power_stage_enabled`]).
    pub fn port(&mut self, interface: Interface, power_stage_enabled: bool) -> ProgramPort<'_, A, B, S> {
        ProgramPort { control: self, interface, power_stage_enabled }
    }

    /// The EtherCAT state machine left BOOT (the master requested INIT after an FoE write, E4 Table 4-29 step
    /// D): an activated image needs a reset; a program stopped by FoE starts again.
    pub fn leave_bootstrap(&mut self) {
        if matches!(self.download.phase(), Phase::Activated(_)) {
            self.request = Some(Request::Reset);
        } else if self.mode == (Mode::Stopped { owner: Some(Interface::Ethercat) }) && self.running.is_some() {
            self.download.abort();
            self.mode = Mode::Running;
            self.request = Some(Request::Start);
        }
    }

    /// Whether `interface` may use the program objects now.
    fn admits(&self, interface: Interface) -> bool {
        match self.mode {
            Mode::Stopped { owner: Some(owner) } => owner == interface,
            _ => true,
        }
    }

    /// Records a refusal's status and returns it.
    fn refuse(&mut self, e: UpdateError) -> Refusal {
        let r = classify(e);
        if let Some(s) = r.status {
            self.status = s;
            self.refused = Some(r.foe);
        }
        r
    }

    /// Stop: only with the power stage off; locks the program objects to `interface`.
    fn stop(&mut self, interface: Interface, power_stage_enabled: bool) -> Result<(), Refusal> {
        if power_stage_enabled {
            return Err(refusal(SdoAbort::DeviceState, None, FoeError::Illegal));
        }
        if self.mode == Mode::Running {
            self.request = Some(Request::Stop);
        }
        self.mode = Mode::Stopped { owner: Some(interface) };
        self.download.abort();
        Ok(())
    }

    /// Clear: only while stopped; erases slot B.
    fn clear(&mut self, interface: Interface) -> Result<(), Refusal> {
        if self.mode == Mode::Running {
            return Err(self.refuse(UpdateError::Sequence));
        }
        self.mode = Mode::Stopped { owner: Some(interface) };
        // The running image is the confirmed one here (`clear` refuses during a trial).
        let slot_a_version = self.running.map(|h| h.security_version);
        match self.download.clear(&mut self.flash.slot_b, &mut self.flash.state, slot_a_version) {
            Ok(()) => {
                self.status = if self.running.is_some() { status::OK } else { status::NO_PROGRAM };
                Ok(())
            }
            Err(UpdateError::Flash(e)) => {
                let _ = self.refuse(UpdateError::Flash(e));
                self.status = status::CLEAR_ERROR;
                Err(refusal(SdoAbort::HardwareError, Some(status::CLEAR_ERROR), FoeError::FlashProblem))
            }
            Err(e) => Err(self.refuse(e)),
        }
    }

    /// Start: activates a verified image (reset follows) or restarts the stopped application.
    fn start(&mut self) -> Result<(), Refusal> {
        match self.download.phase() {
            Phase::Verified(_) => {
                self.download.activate(&mut self.flash.state).map_err(|e| self.refuse(e))?;
                self.request = Some(Request::Reset);
                Ok(())
            }
            Phase::Activated(_) => {
                self.request = Some(Request::Reset);
                Ok(())
            }
            _ if self.mode == Mode::Running => Ok(()),
            _ if self.running.is_some() => {
                self.download.abort();
                self.mode = Mode::Running;
                self.request = Some(Request::Start);
                Ok(())
            }
            _ => Err(refusal(SdoAbort::DeviceState, Some(status::NO_PROGRAM), FoeError::Illegal)),
        }
    }

    /// One piece of the image; `last` verifies it.
    fn data(&mut self, offset: u32, data: &[u8], last: bool) -> Result<(), Refusal> {
        if self.mode == Mode::Running {
            return Err(self.refuse(UpdateError::Sequence));
        }
        let trust = self.trust;
        if !data.is_empty() || !matches!(self.download.phase(), Phase::Receiving) {
            self.download.write(&mut self.flash.slot_b, offset, data, &trust).map_err(|e| self.refuse(e))?;
        }
        if last {
            self.download.finish(&mut self.flash.slot_b, &trust, &mut self.buf).map_err(|e| self.refuse(e))?;
            self.status = status::OK;
        }
        Ok(())
    }
}

/// [`ProgramControl`] as seen by one transfer from one interface: the [`ApplicationObjects`] of 0x1F50, 0x1F51,
/// 0x1F56 and 0x1F57, and on EtherCAT the [`FoeSink`].
#[derive(Debug)]
pub struct ProgramPort<'a, A, B, S> {
    control: &'a mut ProgramControl<A, B, S>,
    interface: Interface,
    power_stage_enabled: bool,
}

fn copy_out(value: &[u8], offset: usize, buf: &mut [u8]) -> ReadOutcome {
    let rest = value.get(offset..).unwrap_or(&[]);
    let len = rest.len().min(buf.len());
    if let (Some(to), Some(from)) = (buf.get_mut(..len), rest.get(..len)) {
        to.copy_from_slice(from);
    }
    ReadOutcome { len, total_len: value.len() }
}

impl<A: NorFlash, B: NorFlash, S: NorFlash> ApplicationObjects for ProgramPort<'_, A, B, S> {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        let c = &*self.control;
        if !c.admits(self.interface) {
            return Err(SdoAbort::LocalControl);
        }
        match entry.index {
            PROGRAM_CONTROL => Ok(copy_out(&[c.program_state()], offset, buf)),
            PROGRAM_SOFTWARE_IDENTIFICATION => Ok(copy_out(&c.software_identification().to_le_bytes(), offset, buf)),
            FLASH_STATUS_IDENTIFICATION => Ok(copy_out(&c.flash_status().to_le_bytes(), offset, buf)),
            _ => Err(SdoAbort::CannotTransfer),
        }
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        _values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        let interface = self.interface;
        let c = &mut *self.control;
        if !c.admits(interface) {
            return Err(SdoAbort::LocalControl);
        }
        let result = match (entry.index, data) {
            (PROGRAM_CONTROL, [command::STOP]) => c.stop(interface, self.power_stage_enabled),
            (PROGRAM_CONTROL, [command::CLEAR]) => c.clear(interface),
            (PROGRAM_CONTROL, [command::START]) => c.start(),
            (PROGRAM_CONTROL, [command::RESET]) => {
                c.request = Some(Request::Reset);
                Ok(())
            }
            (PROGRAM_CONTROL, [command::ESM_ACKNOWLEDGE]) => {
                c.esm_acknowledge = true;
                Ok(())
            }
            (PROGRAM_CONTROL, _) => Err(refusal(SdoAbort::InvalidValue, None, FoeError::Illegal)),
            (PROGRAM_DATA, _) => c.data(u32::try_from(offset).unwrap_or(u32::MAX), data, complete),
            _ => Err(refusal(SdoAbort::CannotTransfer, None, FoeError::Illegal)),
        };
        result.map_err(|r| r.abort)
    }

    fn abort(&mut self, entry: &'static Entry) {
        // Only the owner's download is discarded: a refused request from another interface leaves it alone.
        if entry.index == PROGRAM_DATA && self.control.admits(self.interface) {
            self.control.download.abort();
        }
    }
}

impl<A: NorFlash, B: NorFlash, S: NorFlash> FoeSink for ProgramPort<'_, A, B, S> {
    fn open(&mut self, name: &[u8], password: u32, access: FoeAccess) -> Result<(), FoeError> {
        if name != FOE_FILE_NAME {
            return Err(FoeError::NotFound);
        }
        if password != FOE_PASSWORD {
            return Err(FoeError::NoRights);
        }
        if access != FoeAccess::Write {
            return Err(FoeError::AccessDenied);
        }
        if !self.control.admits(self.interface) {
            return Err(FoeError::Illegal);
        }
        // A write request is stop + clear of the SDO sequence (E4 Table 4-29: the FoE path has no separate steps).
        self.control.stop(self.interface, self.power_stage_enabled).map_err(|r| r.foe)?;
        self.control.clear(self.interface).map_err(|r| r.foe)
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<FoeProgress, FoeError> {
        if !self.control.admits(self.interface) {
            return Err(FoeError::Illegal);
        }
        self.control.data(offset, data, false).map(|()| FoeProgress::Done).map_err(|r| r.foe)
    }

    fn finish(&mut self) -> Result<(), FoeError> {
        if !self.control.admits(self.interface) {
            return Err(FoeError::Illegal);
        }
        let c = &mut *self.control;
        c.data(0, &[], true).map_err(|r| r.foe)?;
        c.download.activate(&mut c.flash.state).map_err(|e| c.refuse(e).foe)
    }

    fn abort(&mut self) {
        if self.control.admits(self.interface) && !matches!(self.control.download.phase(), Phase::Activated(_)) {
            self.control.download.abort();
        }
    }

    fn error_text(&mut self, error: FoeError) -> &'static [u8] {
        match self.control.refused.take() {
            Some(refused) if refused == error => status_text(self.control.status),
            _ => b"",
        }
    }
}

/// [`ProgramControl`] in a [`RefCell`], seen by one interface: the form a platform hands to the EtherCAT slave,
/// whose mailbox needs the dictionary's application objects (CoE) and the FoE sink at the same time. Each call
/// borrows the control for its own duration only; a nested call (which no server makes) is refused, not a panic.
#[derive(Debug)]
pub struct SharedPort<'a, A, B, S> {
    control: &'a RefCell<ProgramControl<A, B, S>>,
    interface: Interface,
    power_stage_enabled: bool,
}

impl<'a, A, B, S> SharedPort<'a, A, B, S> {
    /// The port of `interface` over `control`; `power_stage_enabled` is the drive's state now.
    pub const fn new(
        control: &'a RefCell<ProgramControl<A, B, S>>,
        interface: Interface,
        power_stage_enabled: bool,
    ) -> Self {
        Self { control, interface, power_stage_enabled }
    }
}

impl<A: NorFlash, B: NorFlash, S: NorFlash> ApplicationObjects for SharedPort<'_, A, B, S> {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        let mut c = self.control.try_borrow_mut().map_err(|_| SdoAbort::LocalControl)?;
        ApplicationObjects::read(&mut c.port(self.interface, self.power_stage_enabled), entry, offset, buf)
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        let mut c = self.control.try_borrow_mut().map_err(|_| SdoAbort::LocalControl)?;
        ApplicationObjects::write(
            &mut c.port(self.interface, self.power_stage_enabled),
            entry,
            offset,
            data,
            complete,
            values,
        )
    }

    fn abort(&mut self, entry: &'static Entry) {
        if let Ok(mut c) = self.control.try_borrow_mut() {
            ApplicationObjects::abort(&mut c.port(self.interface, self.power_stage_enabled), entry);
        }
    }
}

impl<A: NorFlash, B: NorFlash, S: NorFlash> FoeSink for SharedPort<'_, A, B, S> {
    fn open(&mut self, name: &[u8], password: u32, access: FoeAccess) -> Result<(), FoeError> {
        let mut c = self.control.try_borrow_mut().map_err(|_| FoeError::Illegal)?;
        c.port(self.interface, self.power_stage_enabled).open(name, password, access)
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<FoeProgress, FoeError> {
        let mut c = self.control.try_borrow_mut().map_err(|_| FoeError::Illegal)?;
        FoeSink::write(&mut c.port(self.interface, self.power_stage_enabled), offset, data)
    }

    fn finish(&mut self) -> Result<(), FoeError> {
        let mut c = self.control.try_borrow_mut().map_err(|_| FoeError::Illegal)?;
        c.port(self.interface, self.power_stage_enabled).finish()
    }

    fn abort(&mut self) {
        if let Ok(mut c) = self.control.try_borrow_mut() {
            FoeSink::abort(&mut c.port(self.interface, self.power_stage_enabled));
        }
    }

    fn error_text(&mut self, error: FoeError) -> &'static [u8] {
        match self.control.try_borrow_mut() {
            Ok(mut c) => c.port(self.interface, self.power_stage_enabled).error_text(error),
            Err(_) => b"",
        }
    }
}
