//! The drive's dictionary at boot and its application-served entries: one path for the host (tests, drive-sim)
//! and the target (`rt::app`).
//!
//! # Boot ("persistent values are loaded at boot", CiA 301 §7.5.2.13/14; spec object-dictionary.md §8)
//! [`Drive::boot`] builds the value storage from the generated defaults ([`Dictionary::new`]), applies the
//! parameter store's record in force over them ([`ParamStore::load`] with [`Selection::All`]) and only then
//! creates the drive ([`Drive::with_dictionary`]), so every parameter the drive derives at construction (gains,
//! commutation, limits) comes from the stored values. It never fails: an empty flash, a flash without a valid
//! record (corrupt, torn, foreign contents) or a flash that cannot be read all give the factory defaults, and the
//! [`BootReport`] says which ([`ParameterSource`]).
//!
//! The node-ID 0x2000 (IDX L3480: "used after the next save and restart") is part of that: the defaults are built
//! for `DriveConfig::node_id` and 0x2000 reads it; when the record holds another node-ID, the defaults are built
//! again for that one (the `$NODEID+` COB-IDs follow it) and the record is applied again.
//!
//! # Application-served entries ([`DriveObjects`])
//! The generated dictionary marks 0x1010, 0x1011 and 0x1F50/0x1F51/0x1F56/0x1F57 as served by the application
//! (`Storage::Application`). [`DriveObjects`] is the drive's [`ApplicationObjects`]:
//! - 0x1010 *Store parameters* and 0x1011 *Restore default parameters* go to the parameter store
//!   ([`StoreObjects`]). Both are writable only in Pre-Operational with the power stage disabled (device.toml
//!   `writable_in`, checked by the access layer from the SDO server's [`AccessContext`]; IDX L1702 for 0x1011,
//!   Gamma L512 for both). The drive checks its own power stage again before it touches the flash and refuses
//!   with 0x0800_0022 (CiA 301 §7.2.4.3.17 Table 22: "data cannot be transferred or stored to the application
//!   because of the present device state") while it is switched on: erasing a parameter sector stalls every
//!   flash read for up to 0.5 s (RM0090 section 3.5), the current loop included.
//! - 0x1F50..0x1F57, program download and control (CiA 302-3), belong to the bootloader issue: they are handed
//!   to a second [`ApplicationObjects`] (`P`), by default [`NoApplicationObjects`], which answers every transfer
//!   with 0x0800_0020 (data cannot be transferred or stored to the application) and never panics.
//! - 0x3205:01 *Auto tuning command* runs the tuning on the value storage ([`super::auto_tuning`]), with the power
//!   stage off (0x0800_0022 otherwise).
//! - Any other application entry (none exists today) answers 0x0800_0020 as well.
//!
//! On the target the flash work happens in tier 3 inside `rt::tier2::with_drive` (see `rt::app`).

use super::{Drive, DriveConfig};
use crate::hal::flash::NorFlash;
use crate::od::abort::SdoAbort;
use crate::od::access::{AccessContext, ApplicationObjects, Dictionary, NoApplicationObjects, ReadOutcome, Table};
use crate::od::entry::Entry;
use crate::od::generated::handles as h;
use crate::od::store::{
    LoadReport, ParamStore, Selection, StoreError, StoreObjects, RESTORE_DEFAULT_PARAMETERS, STORE_PARAMETERS,
};
use crate::power_state::PowerState;

/// 0x1F50 *Program data* (CiA 302-3, IDX L3326).
pub const PROGRAM_DATA: u16 = 0x1F50;
/// 0x1F51 *Program control* (CiA 302-3, IDX L3355).
pub const PROGRAM_CONTROL: u16 = 0x1F51;
/// 0x1F56 *Program software identification* (IDX L3390).
pub const PROGRAM_SOFTWARE_IDENTIFICATION: u16 = 0x1F56;
/// 0x1F57 *Flash status identification* (IDX L3417).
pub const FLASH_STATUS_IDENTIFICATION: u16 = 0x1F57;
/// 0x2000 *Node-ID* (IDX L3480).
pub const NODE_ID: u16 = 0x2000;

/// Where the parameters in force at boot came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParameterSource {
    /// The record in force was applied over the defaults.
    Stored,
    /// The parameter sectors are erased: factory defaults (a new device, or nothing saved yet).
    Empty,
    /// The parameter sectors hold data but no valid record (corrupt, torn beyond both copies, or written by a
    /// foreign firmware): factory defaults. Worth an EMCY/diagnostic entry; the next save writes a valid record.
    Invalid,
    /// Reading the flash failed: factory defaults.
    Failed(StoreError),
}

/// What [`Drive::boot`] found and did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BootReport {
    /// Where the parameters came from.
    pub source: ParameterSource,
    /// The load's details (record, items applied, items skipped because the dictionary changed).
    pub load: LoadReport,
    /// The node-ID the defaults were built for (`DriveConfig::node_id`, or the stored 0x2000).
    pub node_id: u8,
}

impl BootReport {
    /// Whether the drive runs on factory defaults because the stored parameters could not be used (as opposed to
    /// an erased store, where defaults are expected).
    #[must_use]
    pub const fn defaults_after_error(&self) -> bool {
        matches!(self.source, ParameterSource::Invalid | ParameterSource::Failed(_))
    }
}

/// Whether every byte of the store's flash region reads 0xFF (`Ok(false)` as soon as one does not).
fn erased<F: NorFlash>(store: &mut ParamStore<F>) -> Result<bool, StoreError> {
    let capacity = store.flash().geometry().capacity();
    let mut chunk = [0u8; 64];
    let mut at = 0u32;
    while at < capacity {
        let n = capacity.saturating_sub(at).min(chunk.len() as u32);
        let buf = chunk.get_mut(..n as usize).ok_or(StoreError::Geometry)?;
        store.flash_mut().read(at, buf)?;
        if buf.iter().any(|b| *b != 0xFF) {
            return Ok(false);
        }
        at = at.saturating_add(n);
    }
    Ok(true)
}

/// The defaults for `node_id` with 0x2000 reading `node_id`.
fn defaults(node_id: u8) -> Dictionary {
    let mut dictionary = Dictionary::new(node_id);
    if let Ok(entry) = dictionary.find(NODE_ID, 0) {
        let _ = dictionary.values_mut().set_raw(entry, &[node_id]);
    }
    dictionary
}

/// The node-ID 0x2000 holds, if it is a valid CANopen node-ID (1..=127, CiA 301 §7.5.2).
fn stored_node_id(dictionary: &Dictionary) -> Option<u8> {
    let entry = dictionary.find(NODE_ID, 0).ok()?;
    match dictionary.values().raw(entry)? {
        [id @ 1..=127] => Some(*id),
        _ => None,
    }
}

/// Defaults for `node_id` with the record in force applied; on a read error the plain defaults.
fn load_over_defaults<F: NorFlash>(
    node_id: u8,
    store: &mut ParamStore<F>,
) -> (Dictionary, Result<LoadReport, StoreError>) {
    let mut dictionary = defaults(node_id);
    let entries = Table::GENERATED.entries();
    match store.load(Selection::All, entries, dictionary.values_mut().bytes_mut()) {
        Ok(report) => (dictionary, Ok(report)),
        // A read failed part-way: some items may be applied. Start again from the defaults.
        Err(e) => (defaults(node_id), Err(e)),
    }
}

/// The drive's dictionary as it boots: the defaults for `node_id` (or the stored node-ID, see the module
/// documentation) with the parameter store's record in force applied. Never fails; see [`BootReport`].
pub fn boot_dictionary<F: NorFlash>(node_id: u8, store: &mut ParamStore<F>) -> (Dictionary, BootReport) {
    let (mut dictionary, mut result) = load_over_defaults(node_id, store);
    let mut node_id = node_id;
    if result.is_ok() {
        if let Some(stored) = stored_node_id(&dictionary).filter(|id| *id != node_id) {
            node_id = stored;
            (dictionary, result) = load_over_defaults(node_id, store);
        }
    }
    let (source, load) = match result {
        Ok(load) if load.record.is_some() => (ParameterSource::Stored, load),
        Ok(load) => match erased(store) {
            Ok(true) => (ParameterSource::Empty, load),
            Ok(false) => (ParameterSource::Invalid, load),
            Err(e) => (ParameterSource::Failed(e), load),
        },
        Err(e) => (ParameterSource::Failed(e), LoadReport::default()),
    };
    (dictionary, BootReport { source, load, node_id })
}

impl Drive {
    /// The drive as it boots: defaults, then the stored parameters from `store`, then the drive built from those
    /// values (outputs off). `config.node_id` is replaced by a stored node-ID 0x2000 (module documentation).
    #[must_use]
    pub fn boot<F: NorFlash>(config: DriveConfig, store: &mut ParamStore<F>) -> (Self, BootReport) {
        let (dictionary, report) = boot_dictionary(config.node_id, store);
        let mut drive = Self::with_dictionary(DriveConfig { node_id: report.node_id, ..config }, dictionary);
        // Defaults loaded because the stored record was unreadable: the drive must not run on parameters the user
        // did not set without saying so (IDX L7252 0x6380; an erased store is a new device, not an error).
        let detail = match report.source {
            ParameterSource::Invalid => Some(0),
            ParameterSource::Failed(_) => Some(1),
            ParameterSource::Stored | ParameterSource::Empty => None,
        };
        if let Some(detail) = detail {
            drive.raise_boot_fault(crate::fault::table::FaultId::ParameterStoreCorrupt, detail);
        }
        (drive, report)
    }

    /// Whether the power stage is switched on (CiA 402 "Switched on", "Operation enabled" and the calibration
    /// between them): the state in which 0x1010/0x1011 refuse with 0x0800_0022. Enabled when tier 1's last report
    /// says so or when a request tier 1 has not yet acted on leads there: a flash erase must not start in the
    /// periods between a switch-on request and the report of the calibration it started, nor before a
    /// shutdown has taken effect.
    #[must_use]
    pub fn power_stage_enabled(&self) -> bool {
        let on = |state: PowerState| !matches!(state, PowerState::Off | PowerState::Fault(_));
        on(self.report().power) || on(self.state())
    }

    /// The drive's application objects over `store` for one SDO transfer, without program control (0x1F5x
    /// answer 0x0800_0020 until the bootloader issue provides them; see [`DriveObjects::with_program_control`]).
    /// Captures the power-stage state now: build it for each transfer.
    pub fn objects<'a, F: NorFlash>(&self, store: &'a mut ParamStore<F>) -> DriveObjects<'a, F> {
        DriveObjects::new(store, self.power_stage_enabled())
    }

    /// SDO upload through the drive's application objects (see [`Dictionary::read`]).
    pub fn sdo_read<F: NorFlash>(
        &self,
        index: u16,
        sub: u8,
        offset: usize,
        buf: &mut [u8],
        store: &mut ParamStore<F>,
    ) -> Result<ReadOutcome, SdoAbort> {
        let mut objects = self.objects(store);
        self.dictionary.read(index, sub, offset, buf, &mut objects)
    }

    /// SDO download of a whole value through the drive's application objects (see [`Dictionary::write`]):
    /// 0x1010 "save" and 0x1011 "load" reach the parameter store here.
    pub fn sdo_write<F: NorFlash>(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        ctx: AccessContext,
        store: &mut ParamStore<F>,
    ) -> Result<(), SdoAbort> {
        let before = DualLoopObjects::read(&self.dictionary);
        let was_valid = crate::motion::dual_loop::configuration(&self.dictionary).is_ok();
        let mut objects = self.objects(store);
        self.dictionary.write(index, sub, data, ctx, &mut objects)?;
        // 0x3000:05 is derived from 0x3010:01 and 0x3000:01, 0x3000:03 from 0x3000:01 (a write of them, or a
        // 0x1011 restore / 0x1010 reload replacing them): they follow at once, so the velocity and acceleration
        // units of the next slow tick use the new resolution, not only after the next switch-on.
        self.sync_sensor_objects();
        // 0x6091 and 0x3003 (and bit 12 of 0x3000:02) show one gear at once, not only after the next background step.
        self.gear_ratio.reconcile(&mut self.dictionary);
        // The dual loop's configuration is checked as a whole (`motion::dual_loop`): a write that leaves it without
        // its load encoder or with the gear scaling factor out of range is taken back, 0x0604_0043 (CiA 301
        // §7.2.4.3.17 Table 22, general parameter incompatibility). (A dictionary that was already invalid, from a
        // parameter record of another configuration, is not held against unrelated writes; the drive then runs
        // without the dual loop.)
        if was_valid && crate::motion::dual_loop::configuration(&self.dictionary).is_err() {
            before.restore(&mut self.dictionary);
            self.sync_sensor_objects();
            self.gear_ratio.reconcile(&mut self.dictionary);
            return Err(SdoAbort::ParameterIncompatibility);
        }
        Ok(())
    }
}

/// The drive's [`ApplicationObjects`]: parameter store for 0x1010/0x1011, `P` for program download and control
/// 0x1F50..0x1F57 (module documentation).
#[derive(Debug)]
pub struct DriveObjects<'a, F, P = NoApplicationObjects> {
    store: &'a mut ParamStore<F>,
    program: P,
    power_stage_enabled: bool,
}

impl<'a, F: NorFlash> DriveObjects<'a, F> {
    /// The objects over `store`; `power_stage_enabled` is the drive's state now ([`Drive::power_stage_enabled`]).
    pub fn new(store: &'a mut ParamStore<F>, power_stage_enabled: bool) -> Self {
        Self { store, program: NoApplicationObjects, power_stage_enabled }
    }

    /// The same objects with `program` serving 0x1F50..0x1F57 (the bootloader issue's hook).
    pub fn with_program_control<P: ApplicationObjects>(self, program: P) -> DriveObjects<'a, F, P> {
        DriveObjects { store: self.store, program, power_stage_enabled: self.power_stage_enabled }
    }
}

impl<F: NorFlash, P> DriveObjects<'_, F, P> {
    /// The hook for 0x1010/0x1011.
    fn store_objects(&mut self) -> StoreObjects<'_, F> {
        StoreObjects { store: self.store, entries: Table::GENERATED.entries() }
    }
}

/// Which server an application entry belongs to.
enum Served {
    Store,
    Program,
    AutoTuning,
    Nobody,
}

const fn served(index: u16) -> Served {
    match index {
        STORE_PARAMETERS | RESTORE_DEFAULT_PARAMETERS => Served::Store,
        PROGRAM_DATA | PROGRAM_CONTROL | PROGRAM_SOFTWARE_IDENTIFICATION | FLASH_STATUS_IDENTIFICATION => {
            Served::Program
        }
        super::auto_tuning::AUTO_TUNING => Served::AutoTuning,
        _ => Served::Nobody,
    }
}

impl<F: NorFlash, P: ApplicationObjects> ApplicationObjects for DriveObjects<'_, F, P> {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        match served(entry.index) {
            Served::Store => self.store_objects().read(entry, offset, buf),
            Served::Program => self.program.read(entry, offset, buf),
            // 0x3205:01 is write-only: the access layer answers a read before it comes here.
            Served::AutoTuning | Served::Nobody => Err(SdoAbort::CannotTransfer),
        }
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        match served(entry.index) {
            // The flash is erased and programmed only with the power stage off (module documentation).
            Served::Store if self.power_stage_enabled => Err(SdoAbort::DeviceState),
            Served::Store => self.store_objects().write(entry, offset, data, complete, values),
            Served::Program => self.program.write(entry, offset, data, complete, values),
            // The gains change only with the power stage off (device.toml `writable_in`, checked again here as for
            // the store). The access layer has checked the length (UNSIGNED8, one byte, expedited: `complete`).
            Served::AutoTuning if self.power_stage_enabled => Err(SdoAbort::DeviceState),
            Served::AutoTuning => super::auto_tuning::run(data, values),
            Served::Nobody => Err(SdoAbort::CannotTransfer),
        }
    }

    fn abort(&mut self, entry: &'static Entry) {
        match served(entry.index) {
            Served::Store => self.store_objects().abort(entry),
            Served::Program => self.program.abort(entry),
            Served::AutoTuning | Served::Nobody => {}
        }
    }

    fn reload_communication(&mut self, values: &mut [u8]) {
        self.store_objects().reload_communication(values);
    }
}

/// The objects the dual loop's configuration depends on (`motion::dual_loop::configuration`), to take a refused
/// write back.
#[derive(Clone, Copy, Debug)]
struct DualLoopObjects {
    words: [u32; 6],
    pole_pairs: u8,
}

impl DualLoopObjects {
    const HANDLES: [crate::od::entry::Handle<u32>; 6] = [
        h::SENSORS_CONFIGURATION,
        h::CONTROL_STRUCTURE,
        h::GEAR_REDUCTION_NUMERATOR,
        h::GEAR_REDUCTION_DENOMINATOR,
        h::LOAD_ENCODER_PULSES,
        h::ENCODER_PULSES,
    ];

    fn read(d: &Dictionary) -> Self {
        Self { words: Self::HANDLES.map(|handle| d.get(handle)), pole_pairs: d.get(h::MOTOR_POLE_PAIRS) }
    }

    fn restore(&self, d: &mut Dictionary) {
        for (handle, value) in Self::HANDLES.iter().zip(self.words) {
            d.set(*handle, value);
        }
        d.set(h::MOTOR_POLE_PAIRS, self.pole_pairs);
    }
}
