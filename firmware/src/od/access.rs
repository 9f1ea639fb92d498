//! Dictionary access as the SDO server needs it: read and write by (index, sub-index), partial reads and
//! segmented writes of strings and domains, and the CiA 301 abort code for every failure.
//!
//! The checks and their order follow CiA 301 §7.2.4.3 (SDO services) with the abort codes of Table 22:
//! 1. the entry exists: 0x0602_0000 for a missing object, 0x0609_0011 for a missing sub-index of one that exists;
//! 2. the access type allows the transfer (IDX 6.1.3): 0x0601_0001 reading a write-only entry, 0x0601_0002
//!    writing a read-only or constant one;
//! 3. the entry is writable in the present state (its [`WriteCondition`], object-dictionary.md §3): 0x0800_0022;
//! 4. the length fits the data type: 0x0607_0013 too short, 0x0607_0012 too long (a VISIBLE_STRING may be shorter
//!    than its capacity; the rest is filled with NUL);
//! 5. the value is within the entry's limits: 0x0609_0032 too low, 0x0609_0031 too high, 0x0609_0030 not one of
//!    the listed values (option codes) or a BOOLEAN other than 0/1;
//! 6. whole-object rules for PDO mappings and assignments ([`pdo_map::check_write`]).
//!
//! Only then is the value stored, all bytes at once: a failed write changes nothing. Entries the application
//! serves ([`Storage::Application`]: store/restore 0x1010/0x1011, program control 0x1F50/0x1F51) pass checks 1-4
//! (and 5 for fixed-size types) and are then handed to an [`ApplicationObjects`] implementation.

use super::abort::SdoAbort;
use super::entry::{DataType, Entry, Handle, Limits, Object, Storage, WriteCondition};
use super::generated::{ENTRIES, LIMITS, OBJECTS, VALUE_BYTES};
use super::pdo_map;
use super::values::{Scalar, Values};

/// A dictionary table: the entries sorted by (index, sub-index) and the objects sorted by index
/// (ARCHITECTURE convention 7). [`Table::GENERATED`] is the drive's; tests build their own.
#[derive(Clone, Copy, Debug)]
pub struct Table {
    entries: &'static [Entry],
    objects: &'static [Object],
    limits: &'static [Limits],
}

impl Table {
    /// The dictionary od-gen generated from `firmware/device.toml`.
    pub const GENERATED: Table = Table { entries: &ENTRIES, objects: &OBJECTS, limits: &LIMITS };

    /// A table over `entries` (sorted by (index, sub)) and `objects` (sorted by index), whose entries' limits are
    /// positions in the generated list (`LIMITS`). Lookups on an unsorted table give wrong answers but never panic.
    pub const fn new(entries: &'static [Entry], objects: &'static [Object]) -> Self {
        Self { entries, objects, limits: &LIMITS }
    }

    /// [`Table::new`] with a list of limits of its own: each entry's [`Entry::limits`] is a position in `limits`.
    pub const fn with_limits(entries: &'static [Entry], objects: &'static [Object], limits: &'static [Limits]) -> Self {
        Self { entries, objects, limits }
    }

    /// The limits of `entry`, `None` when its position is outside the table's list (never for a generated table:
    /// od-gen writes every position it uses).
    pub fn limits_of(&self, entry: &Entry) -> Option<&'static Limits> {
        self.limits.get(usize::from(entry.limits.0))
    }

    /// Every entry, sorted by (index, sub-index).
    pub const fn entries(&self) -> &'static [Entry] {
        self.entries
    }

    /// Every object, sorted by index.
    pub const fn objects(&self) -> &'static [Object] {
        self.objects
    }

    /// The entry at (index, sub) by binary search: 0x0602_0000 if no entry has `index`, 0x0609_0011 if the
    /// object exists but has no sub-index `sub` (CiA 301 Table 22; E4 L2700-L2811 shows 0x0609_0011 for 0x2000:08).
    pub fn find(&self, index: u16, sub: u8) -> Result<&'static Entry, SdoAbort> {
        let entries = self.entries;
        match entries.binary_search_by(|e| (e.index, e.sub).cmp(&(index, sub))) {
            Ok(position) => entries.get(position).ok_or(SdoAbort::InternalIncompatibility),
            Err(_) if self.entries_of(index).is_empty() => Err(SdoAbort::ObjectDoesNotExist),
            Err(_) => Err(SdoAbort::SubindexDoesNotExist),
        }
    }

    /// The entries of object `index` (empty if it does not exist).
    pub fn entries_of(&self, index: u16) -> &'static [Entry] {
        let entries = self.entries;
        let start = entries.partition_point(|e| e.index < index);
        let end = entries.partition_point(|e| e.index <= index);
        entries.get(start..end).unwrap_or(&[])
    }

    /// The object header of `index` (name, object code, highest sub-index), by binary search.
    pub fn object(&self, index: u16) -> Option<&'static Object> {
        let objects = self.objects;
        objects.binary_search_by_key(&index, |o| o.index).ok().and_then(|position| objects.get(position))
    }
}

/// Communication state of the fieldbus: the NMT state (CiA 301 §7.3.2) or the EtherCAT state machine state
/// (ETG.1000.6; comms-faults-bootloader.md §1.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommState {
    /// EtherCAT INIT / CANopen initialisation.
    Init,
    /// Pre-Operational: SDO parameterisation, PDO mapping and assignment may change.
    PreOperational,
    /// EtherCAT SAFE-OP.
    SafeOperational,
    /// Operational.
    Operational,
    /// CANopen Stopped.
    Stopped,
    /// EtherCAT BOOT (firmware download).
    Bootstrap,
}

/// The state a write is judged in, passed in by the SDO server (ARCHITECTURE convention 1: no hidden state).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AccessContext {
    /// Communication state.
    pub comm_state: CommState,
    /// Whether the power stage is enabled (CiA 402 "Operation enabled" and the states that keep it switched on).
    pub power_stage_enabled: bool,
    /// The bus's PDO length limit in bytes (IDX L2196: 8 on CANopen, 40 on EtherCAT; the generated
    /// `MAX_PDO_BYTES_CANOPEN` / `MAX_PDO_BYTES_ETHERCAT`).
    pub max_pdo_bytes: u16,
}

impl AccessContext {
    /// Whether an entry with `condition` accepts writes in this context.
    pub const fn allows(&self, condition: WriteCondition) -> bool {
        let pre_op = matches!(self.comm_state, CommState::PreOperational);
        match condition {
            WriteCondition::Always => true,
            WriteCondition::PreOperational => pre_op,
            WriteCondition::PowerDisabled => !self.power_stage_enabled,
            WriteCondition::PreOperationalPowerDisabled => pre_op && !self.power_stage_enabled,
        }
    }
}

/// The result of a (partial) read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadOutcome {
    /// Bytes copied into the buffer, starting at the requested offset of the value.
    pub len: usize,
    /// Length of the whole value (for a VISIBLE_STRING: up to its first NUL), which an SDO upload announces.
    pub total_len: usize,
}

/// Copies `value[offset..]` into `buf` as far as it fits.
fn copy_out(value: &[u8], offset: usize, buf: &mut [u8]) -> ReadOutcome {
    let rest = value.get(offset..).unwrap_or(&[]);
    let len = rest.len().min(buf.len());
    if let (Some(to), Some(from)) = (buf.get_mut(..len), rest.get(..len)) {
        to.copy_from_slice(from);
    }
    ReadOutcome { len, total_len: value.len() }
}

/// The entries the application serves itself ([`Storage::Application`]): store/restore parameters (0x1010/
/// 0x1011, CiA 301 §7.5.2.13/14), program data and control (0x1F50/0x1F51, CiA 302-3). The access layer has
/// checked existence, access, state and length (and limits for fixed-size types) before it calls these.
pub trait ApplicationObjects {
    /// Reads `entry` from byte `offset` into `buf`.
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort>;

    /// Receives bytes `offset..offset + data.len()` of a value written to `entry`; `complete` marks the last part
    /// of the transfer (an expedited or whole write is one call with offset 0 and `complete`). `values` is the
    /// dictionary's value storage (for "save" 0x1010, which persists it, and "load" 0x1011).
    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        values: &mut [u8],
    ) -> Result<(), SdoAbort>;

    /// A transfer to `entry` was aborted (by either side, or because a part failed): discard what was received.
    fn abort(&mut self, entry: &'static Entry) {
        let _ = entry;
    }

    /// A reset (NMT reset node or reset communication, the node's power-on reset included) has just set the
    /// communication area 0x1000..0x1FFF of `values` to its defaults: applies the stored communication parameters
    /// over them, so that the area holds its power-on values (CiA 301 §7.3.2: both resets load the power-on
    /// values of the communication parameters; §7.5.2.13: saved values are the power-on values). Without a
    /// parameter store there is nothing to apply.
    fn reload_communication(&mut self, values: &mut [u8]) {
        let _ = values;
    }
}

/// An [`ApplicationObjects`] that serves nothing: every transfer aborts with 0x0800_0020 (data cannot be
/// transferred or stored to the application).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoApplicationObjects;

impl ApplicationObjects for NoApplicationObjects {
    fn read(&mut self, _: &'static Entry, _: usize, _: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        Err(SdoAbort::CannotTransfer)
    }

    fn write(&mut self, _: &'static Entry, _: usize, _: &[u8], _: bool, _: &mut [u8]) -> Result<(), SdoAbort> {
        Err(SdoAbort::CannotTransfer)
    }
}

/// A borrowed server serves as the server itself, so that the drive's objects can hold their program port as
/// `&mut dyn ApplicationObjects`: one instance of their code whatever the port (`rt::canopen`, `rt::ethercat`; the
/// parameter store's write path inlined into each instance cost slot A 1.4 KB).
impl<T: ApplicationObjects + ?Sized> ApplicationObjects for &mut T {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        (**self).read(entry, offset, buf)
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        (**self).write(entry, offset, data, complete, values)
    }

    fn abort(&mut self, entry: &'static Entry) {
        (**self).abort(entry);
    }

    fn reload_communication(&mut self, values: &mut [u8]) {
        (**self).reload_communication(values);
    }
}

/// Default staging capacity of a [`Download`] for segmented writes of RAM strings and domains.
pub const DOWNLOAD_STAGING: usize = 64;

/// A segmented write (CiA 301 §7.2.4.3.3..7 segmented/block download, or a CoE segmented download) in progress.
///
/// Created by [`Dictionary::begin_download`] after the checks CiA 301 lets the server make at initiation;
/// driven by [`Dictionary::download_segment`]. RAM entries are collected here (up to `S` bytes) and validated and
/// stored only with the last segment; application entries receive each segment as it comes. Nothing is applied
/// when the transfer fails or is aborted ([`Dictionary::abort_download`]).
#[derive(Clone, Debug)]
pub struct Download<const S: usize = DOWNLOAD_STAGING> {
    entry: &'static Entry,
    size: Option<usize>,
    received: usize,
    done: bool,
    staged: [u8; S],
}

impl<const S: usize> Download<S> {
    /// The entry being written.
    pub const fn entry(&self) -> &'static Entry {
        self.entry
    }

    /// Bytes received so far.
    pub const fn received(&self) -> usize {
        self.received
    }

    /// The size the client announced, if it did.
    pub const fn size(&self) -> Option<usize> {
        self.size
    }

    /// Whether the transfer has ended (completed or failed).
    pub const fn is_done(&self) -> bool {
        self.done
    }
}

/// Checks the access type and the write condition of `entry`.
fn check_writable(entry: &Entry, ctx: AccessContext) -> Result<(), SdoAbort> {
    if !entry.access().writable() || matches!(entry.storage, Storage::Const(_)) {
        return Err(SdoAbort::ReadOnly);
    }
    if !ctx.allows(entry.write_condition()) {
        return Err(SdoAbort::DeviceState);
    }
    Ok(())
}

/// Checks a write of `len` bytes against the entry's size: fixed-size types must match exactly; a
/// VISIBLE_STRING or DOMAIN in RAM may be shorter than its capacity, an OCTET_STRING in RAM must fill it (as in
/// CANopenNode, which only lets strings be shorter); application strings and domains have no size here.
fn check_length(entry: &Entry, len: usize) -> Result<(), SdoAbort> {
    let (expected, shorter_ok) = match (entry.data_type.fixed_size(), entry.storage) {
        (Some(size), _) => (size, false),
        (None, Storage::Ram { len: capacity, .. }) => {
            (usize::from(capacity), !matches!(entry.data_type, DataType::OctetString))
        }
        (None, Storage::Const(_) | Storage::Application) => return Ok(()),
    };
    if len > expected {
        Err(SdoAbort::LengthTooHigh)
    } else if len < expected && !shorter_ok {
        Err(SdoAbort::LengthTooLow)
    } else {
        Ok(())
    }
}

/// The value of a fixed-size integer or BOOLEAN (little-endian, sign-extended for signed types), or `None` for
/// strings and domains. `data` has the type's size (checked before).
fn decode(data_type: DataType, data: &[u8]) -> Option<i128> {
    let size = data_type.fixed_size()?;
    let mut wide = [0u8; 16];
    let negative = data_type.is_signed() && data.last().is_some_and(|b| b & 0x80 != 0);
    if negative {
        wide = [0xFF; 16];
    }
    wide.get_mut(..size)?.copy_from_slice(data.get(..size)?);
    Some(i128::from_le_bytes(wide))
}

/// The bytes of a fixed-size value (at most 8) as a zero-extended `u64`.
fn zero_extend(data: &[u8]) -> u64 {
    let mut wide = [0u8; 8];
    if let Some(low) = wide.get_mut(..data.len()) {
        low.copy_from_slice(data);
    }
    u64::from_le_bytes(wide)
}

/// Checks a fixed-size value against the entry's limits (CiA 301 Table 22, 0x0609_0030..0x0609_0032). An entry
/// whose limits the table does not hold refuses every value (0x0604_0047), so that no write goes unchecked.
fn check_value(table: &Table, entry: &Entry, value: i128) -> Result<(), SdoAbort> {
    if entry.data_type == DataType::Boolean && !(0..=1).contains(&value) {
        return Err(SdoAbort::InvalidValue);
    }
    let (min, max) = match *table.limits_of(entry).ok_or(SdoAbort::InternalIncompatibility)? {
        Limits::None => return Ok(()),
        Limits::Signed { min, max } => (i128::from(min), i128::from(max)),
        Limits::Unsigned { min, max } => (i128::from(min), i128::from(max)),
        Limits::OneOf(allowed) => {
            return if allowed.iter().any(|a| i128::from(*a) == value) { Ok(()) } else { Err(SdoAbort::InvalidValue) };
        }
    };
    if value < min {
        Err(SdoAbort::ValueTooLow)
    } else if value > max {
        Err(SdoAbort::ValueTooHigh)
    } else {
        Ok(())
    }
}

/// The object dictionary at run time: a [`Table`] and its [`Values`]. `N` is the size of the value storage
/// (the generated `VALUE_BYTES` unless a test brings its own table).
#[derive(Clone, Debug)]
pub struct Dictionary<const N: usize = VALUE_BYTES> {
    table: Table,
    values: Values<N>,
}

impl Dictionary<VALUE_BYTES> {
    /// The generated dictionary with its defaults for `node_id`.
    pub fn new(node_id: u8) -> Self {
        Self::with_table(Table::GENERATED, Values::new(node_id))
    }
}

impl<const N: usize> Dictionary<N> {
    /// A dictionary over any table and a value storage laid out for it.
    pub const fn with_table(table: Table, values: Values<N>) -> Self {
        Self { table, values }
    }

    /// Serves the values under `table` from now on, keeping every value: program control switches between the
    /// application's and the stopped program's tables (`boot::tables`), which share the generated value layout.
    pub fn set_table(&mut self, table: Table) {
        self.table = table;
    }

    /// The table.
    pub const fn table(&self) -> &Table {
        &self.table
    }

    /// See [`Table::find`].
    pub fn find(&self, index: u16, sub: u8) -> Result<&'static Entry, SdoAbort> {
        self.table.find(index, sub)
    }

    /// See [`Table::object`].
    pub fn object(&self, index: u16) -> Option<&'static Object> {
        self.table.object(index)
    }

    /// The value storage.
    pub const fn values(&self) -> &Values<N> {
        &self.values
    }

    /// The value storage, mutable (the parameter store restores an image through it; no checks).
    pub fn values_mut(&mut self) -> &mut Values<N> {
        &mut self.values
    }

    /// Reads a typed value (the control tiers' path: no search, no checks).
    #[inline]
    pub fn get<T: Scalar>(&self, handle: Handle<T>) -> T {
        self.values.get(handle)
    }

    /// Writes a typed value (the control tiers' path: no search, no checks).
    #[inline]
    pub fn set<T: Scalar>(&mut self, handle: Handle<T>, value: T) {
        self.values.set(handle, value);
    }

    /// SDO upload: reads `index:sub` from byte `offset` into `buf` (a segmented upload reads on at increasing
    /// offsets). A VISIBLE_STRING reads up to its first NUL. Write-only entries abort with 0x0601_0001.
    pub fn read<A: ApplicationObjects + ?Sized>(
        &self,
        index: u16,
        sub: u8,
        offset: usize,
        buf: &mut [u8],
        app: &mut A,
    ) -> Result<ReadOutcome, SdoAbort> {
        let entry = self.find(index, sub)?;
        self.read_entry(entry, offset, buf, app)
    }

    /// [`Dictionary::read`] for an entry already found.
    pub fn read_entry<A: ApplicationObjects + ?Sized>(
        &self,
        entry: &'static Entry,
        offset: usize,
        buf: &mut [u8],
        app: &mut A,
    ) -> Result<ReadOutcome, SdoAbort> {
        if !entry.access().readable() {
            return Err(SdoAbort::WriteOnly);
        }
        let value = match entry.storage {
            Storage::Application => return app.read(entry, offset, buf),
            Storage::Const(bytes) => bytes.bytes(),
            Storage::Ram { .. } => self.values.raw(entry).ok_or(SdoAbort::InternalIncompatibility)?,
        };
        let value = if entry.data_type == DataType::VisibleString {
            let end = value.iter().position(|b| *b == 0).unwrap_or(value.len());
            value.get(..end).unwrap_or(value)
        } else {
            value
        };
        Ok(copy_out(value, offset, buf))
    }

    /// SDO download of a whole value (expedited, or segmented and collected by the server): writes `data` to
    /// `index:sub` after every check in the module documentation; nothing changes when it fails.
    pub fn write<A: ApplicationObjects + ?Sized>(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<(), SdoAbort> {
        let entry = self.find(index, sub)?;
        self.write_entry(entry, data, ctx, app)
    }

    /// [`Dictionary::write`] for an entry already found.
    pub fn write_entry<A: ApplicationObjects + ?Sized>(
        &mut self,
        entry: &'static Entry,
        data: &[u8],
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<(), SdoAbort> {
        check_writable(entry, ctx)?;
        check_length(entry, data.len())?;
        let value = decode(entry.data_type, data);
        if let Some(value) = value {
            check_value(&self.table, entry, value)?;
        }
        match entry.storage {
            Storage::Const(_) => Err(SdoAbort::ReadOnly),
            Storage::Application => app.write(entry, 0, data, true, self.values.bytes_mut()),
            Storage::Ram { .. } => {
                if value.is_some() {
                    // Fixed-size values are at most 8 bytes: their bits, zero-extended, are the stored value.
                    pdo_map::check_write(
                        &self.table,
                        self.values.bytes(),
                        entry,
                        zero_extend(data),
                        ctx.max_pdo_bytes,
                    )?;
                }
                let slot = self.values.raw_mut(entry).ok_or(SdoAbort::InternalIncompatibility)?;
                let (head, tail) = slot.split_at_mut(data.len().min(slot.len()));
                head.copy_from_slice(data.get(..head.len()).unwrap_or_default());
                tail.fill(0);
                Ok(())
            }
        }
    }

    /// Starts a segmented download to `index:sub` of `size` bytes (if the client indicated it): makes the checks
    /// CiA 301 allows at initiation (existence, access, state, announced size). A RAM entry larger than the
    /// staging capacity `S` aborts with 0x0504_0005 (out of memory).
    pub fn begin_download<const S: usize>(
        &self,
        index: u16,
        sub: u8,
        size: Option<usize>,
        ctx: AccessContext,
    ) -> Result<Download<S>, SdoAbort> {
        let entry = self.find(index, sub)?;
        check_writable(entry, ctx)?;
        if let Storage::Ram { len, .. } = entry.storage {
            if usize::from(len) > S {
                return Err(SdoAbort::OutOfMemory);
            }
        }
        if let Some(size) = size {
            check_length(entry, size)?;
        }
        Ok(Download { entry, size, received: 0, done: false, staged: [0; S] })
    }

    /// Feeds the next segment of a download; `last` marks the final one, which stores a RAM value after all
    /// checks. On any error the transfer is over, nothing is stored and an application entry has been told to
    /// discard what it received ([`ApplicationObjects::abort`]).
    pub fn download_segment<const S: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        download: &mut Download<S>,
        data: &[u8],
        last: bool,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<(), SdoAbort> {
        if download.done {
            return Err(SdoAbort::GeneralError);
        }
        let result = self.segment(download, data, last, ctx, app);
        if result.is_err() || last {
            download.done = true;
        }
        if result.is_err() && matches!(download.entry.storage, Storage::Application) {
            app.abort(download.entry);
        }
        result
    }

    fn segment<const S: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        download: &mut Download<S>,
        data: &[u8],
        last: bool,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<(), SdoAbort> {
        let entry = download.entry;
        let start = download.received;
        let end = start.checked_add(data.len()).ok_or(SdoAbort::LengthTooHigh)?;
        if let Some(size) = download.size {
            if end > size {
                return Err(SdoAbort::LengthTooHigh);
            }
            if last && end < size {
                return Err(SdoAbort::LengthTooLow);
            }
        }
        match entry.storage {
            Storage::Const(_) => Err(SdoAbort::ReadOnly),
            Storage::Application => {
                check_writable(entry, ctx)?;
                if let Some(size) = entry.data_type.fixed_size() {
                    // Fixed-size application values (store/restore signatures) are short: collect them so that
                    // the limits can be checked on the whole value before the last part goes out.
                    if end > size {
                        return Err(SdoAbort::LengthTooHigh);
                    }
                    download.staged.get_mut(start..end).ok_or(SdoAbort::OutOfMemory)?.copy_from_slice(data);
                    if last {
                        check_length(entry, end)?;
                        if let Some(value) = decode(entry.data_type, download.staged.get(..end).unwrap_or_default()) {
                            check_value(&self.table, entry, value)?;
                        }
                    }
                }
                app.write(entry, start, data, last, self.values.bytes_mut())?;
                download.received = end;
                Ok(())
            }
            Storage::Ram { .. } => {
                let part = download.staged.get_mut(start..end).ok_or(SdoAbort::LengthTooHigh)?;
                part.copy_from_slice(data);
                download.received = end;
                if last {
                    let staged = download.staged.get(..end).ok_or(SdoAbort::InternalIncompatibility)?;
                    self.write_entry(entry, staged, ctx, app)
                } else {
                    Ok(())
                }
            }
        }
    }

    /// Ends a download the client aborted or the server timed out: nothing is stored; an application entry is
    /// told to discard what it received.
    pub fn abort_download<const S: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        download: &mut Download<S>,
        app: &mut A,
    ) {
        if !download.done && matches!(download.entry.storage, Storage::Application) {
            app.abort(download.entry);
        }
        download.done = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::entry::{Access, Attributes, ConstRef, LimitsRef, Name, ObjectCode, PdoMapping};

    const fn entry(index: u16, sub: u8, data_type: DataType, access: Access, storage: Storage) -> Entry {
        Entry {
            index,
            sub,
            name: Name::EMPTY,
            data_type,
            attributes: Attributes::new(access, PdoMapping::No, false, WriteCondition::Always),
            limits: LimitsRef::NONE,
            storage,
        }
    }

    const fn ram(offset: u16, len: u16) -> Storage {
        Storage::Ram { offset, len, node_id_relative: false }
    }

    const fn mapping(index: u16, sub: u8, offset: u16) -> Entry {
        let data_type = if sub == 0 { DataType::Unsigned8 } else { DataType::Unsigned32 };
        let len = if sub == 0 { 1 } else { 4 };
        let mut e = entry(index, sub, data_type, Access::ReadWrite, ram(offset, len));
        e.attributes = e.attributes.with_write_condition(WriteCondition::PreOperational);
        if sub == 0 {
            e.limits = LimitsRef(1);
        }
        e
    }

    const fn pdo(mut e: Entry, pdo: PdoMapping) -> Entry {
        e.attributes = e.attributes.with_pdo(pdo);
        e
    }

    const fn limited(mut e: Entry, limits: LimitsRef) -> Entry {
        e.limits = limits;
        e
    }

    static ENTRIES: [Entry; 12] = [
        entry(0x1008, 0, DataType::VisibleString, Access::Const, Storage::Const(ConstRef::new(&(b"OSD\0x" as &[u8])))),
        entry(0x1010, 1, DataType::Unsigned32, Access::ReadWrite, Storage::Application),
        mapping(0x1600, 0, 0),
        mapping(0x1600, 1, 1),
        mapping(0x1600, 2, 5),
        entry(0x2003, 0, DataType::Unsigned16, Access::WriteOnly, ram(9, 2)),
        entry(0x2100, 0, DataType::VisibleString, Access::ReadWrite, ram(11, 8)),
        entry(0x2101, 0, DataType::OctetString, Access::ReadWrite, ram(19, 4)),
        pdo(entry(0x6040, 0, DataType::Unsigned16, Access::ReadWrite, ram(23, 2)), PdoMapping::Rx),
        pdo(entry(0x6041, 0, DataType::Unsigned16, Access::ReadOnly, ram(25, 2)), PdoMapping::Tx),
        limited(entry(0x605A, 0, DataType::Integer16, Access::ReadWrite, ram(27, 2)), LimitsRef(2)),
        pdo(
            limited(entry(0x607A, 0, DataType::Integer32, Access::ReadWrite, ram(29, 4)), LimitsRef(3)),
            PdoMapping::Rx,
        ),
    ];

    const fn object(index: u16) -> Object {
        Object { index, name: Name::EMPTY, object_code: ObjectCode::Var, max_sub: 0 }
    }

    /// The test table's limits, by the positions its entries name.
    static LIMITS: [Limits; 4] = [
        Limits::None,
        Limits::Unsigned { min: 0, max: 2 },
        Limits::OneOf(&[0, 1, 2, 5, 6]),
        Limits::Signed { min: -1000, max: 1000 },
    ];

    static OBJECTS: [Object; 9] = [
        object(0x1008),
        object(0x1010),
        object(0x1600),
        object(0x2003),
        object(0x2100),
        object(0x2101),
        object(0x6040),
        object(0x6041),
        object(0x605A),
    ];

    const PRE_OP: AccessContext =
        AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 8 };
    const OP: AccessContext = AccessContext { comm_state: CommState::Operational, ..PRE_OP };

    /// Records what the application received.
    #[derive(Default)]
    struct App {
        received: [u8; 8],
        complete: bool,
        aborted: bool,
    }

    impl ApplicationObjects for App {
        fn read(&mut self, _: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
            Ok(copy_out(&[1, 0, 0, 0], offset, buf))
        }
        fn write(
            &mut self,
            _: &'static Entry,
            offset: usize,
            data: &[u8],
            complete: bool,
            _: &mut [u8],
        ) -> Result<(), SdoAbort> {
            let end = offset + data.len();
            self.received[offset..end].copy_from_slice(data);
            self.complete = complete;
            Ok(())
        }
        fn abort(&mut self, _: &'static Entry) {
            self.aborted = true;
        }
    }

    fn dictionary() -> Dictionary<40> {
        let mut bytes = [0u8; 40];
        bytes[0] = 1;
        bytes[1..5].copy_from_slice(&0x6040_0010u32.to_le_bytes());
        bytes[27..29].copy_from_slice(&6i16.to_le_bytes());
        Dictionary::with_table(Table::with_limits(&ENTRIES, &OBJECTS, &LIMITS), Values::from_bytes(bytes))
    }

    #[test]
    fn find_distinguishes_missing_object_and_missing_sub() {
        let dict = dictionary();
        assert_eq!(dict.find(0x6040, 0).map(|e| e.index), Ok(0x6040));
        assert_eq!(dict.find(0x1600, 2).map(|e| e.sub), Ok(2));
        assert_eq!(dict.find(0x6042, 0), Err(SdoAbort::ObjectDoesNotExist));
        assert_eq!(dict.find(0x1600, 3), Err(SdoAbort::SubindexDoesNotExist));
        assert_eq!(dict.find(0x0000, 0), Err(SdoAbort::ObjectDoesNotExist));
        assert_eq!(dict.find(0xFFFF, 0xFF), Err(SdoAbort::ObjectDoesNotExist));
        assert_eq!(dict.object(0x605A).map(|o| o.index), Some(0x605A));
        assert_eq!(dict.object(0x607B), None);
    }

    #[test]
    fn reads_check_access_and_support_offsets() {
        let dict = dictionary();
        let mut app = App::default();
        let mut buf = [0u8; 8];
        assert_eq!(dict.read(0x605A, 0, 0, &mut buf, &mut app), Ok(ReadOutcome { len: 2, total_len: 2 }));
        assert_eq!(&buf[..2], &[6, 0]);
        assert_eq!(dict.read(0x2003, 0, 0, &mut buf, &mut app), Err(SdoAbort::WriteOnly));
        // A visible string reads up to its first NUL; partial reads continue at an offset.
        assert_eq!(dict.read(0x1008, 0, 0, &mut buf[..2], &mut app), Ok(ReadOutcome { len: 2, total_len: 3 }));
        assert_eq!(&buf[..2], b"OS");
        assert_eq!(dict.read(0x1008, 0, 2, &mut buf, &mut app), Ok(ReadOutcome { len: 1, total_len: 3 }));
        assert_eq!(buf[0], b'D');
        assert_eq!(dict.read(0x1008, 0, 9, &mut buf, &mut app), Ok(ReadOutcome { len: 0, total_len: 3 }));
        assert_eq!(dict.read(0x1010, 1, 0, &mut buf, &mut app), Ok(ReadOutcome { len: 4, total_len: 4 }));
    }

    #[test]
    fn a_write_to_an_entry_whose_limits_the_table_lacks_is_refused_and_changes_nothing() {
        // 0x605A names limits position 2; a table whose list stops before it answers 0x0604_0047 (CiA 301
        // Table 22) instead of storing an unchecked value, and the stored 6 stays.
        let mut bytes = [0u8; 40];
        bytes[27..29].copy_from_slice(&6i16.to_le_bytes());
        let table = Table::with_limits(&ENTRIES, &OBJECTS, &[Limits::None]);
        let mut dict = Dictionary::with_table(table, Values::from_bytes(bytes));
        let app = &mut App::default();
        assert_eq!(dict.write(0x605A, 0, &[1, 0], OP, app), Err(SdoAbort::InternalIncompatibility));
        assert_eq!(dict.values().bytes()[27..29], [6, 0]);
        // Entries without limits (position 0) still take any value.
        assert_eq!(dict.write(0x6040, 0, &[0x0F, 0], OP, app), Ok(()));
    }

    #[test]
    fn writes_check_access_state_length_and_limits() {
        let mut dict = dictionary();
        let app = &mut App::default();
        assert_eq!(dict.write(0x6041, 0, &[0, 0], OP, app), Err(SdoAbort::ReadOnly));
        assert_eq!(dict.write(0x1008, 0, b"x", OP, app), Err(SdoAbort::ReadOnly));
        assert_eq!(dict.write(0x6040, 0, &[1], OP, app), Err(SdoAbort::LengthTooLow));
        assert_eq!(dict.write(0x6040, 0, &[1, 2, 3], OP, app), Err(SdoAbort::LengthTooHigh));
        assert_eq!(dict.write(0x6040, 0, &[0x0F, 0], OP, app), Ok(()));
        assert_eq!(dict.values().raw(&ENTRIES[8]), Some(&[0x0F, 0][..]));
        assert_eq!(dict.write(0x605A, 0, &3i16.to_le_bytes(), OP, app), Err(SdoAbort::InvalidValue));
        assert_eq!(dict.write(0x605A, 0, &5i16.to_le_bytes(), OP, app), Ok(()));
        assert_eq!(dict.write(0x607A, 0, &(-1001i32).to_le_bytes(), OP, app), Err(SdoAbort::ValueTooLow));
        assert_eq!(dict.write(0x607A, 0, &1001i32.to_le_bytes(), OP, app), Err(SdoAbort::ValueTooHigh));
        assert_eq!(dict.write(0x607A, 0, &(-1000i32).to_le_bytes(), OP, app), Ok(()));
        assert_eq!(dict.write(0x1600, 0, &[0], OP, app), Err(SdoAbort::DeviceState));
        assert_eq!(dict.write(0x1600, 0, &[3], PRE_OP, app), Err(SdoAbort::ValueTooHigh));
        assert_eq!(dict.write(0x2003, 0, &[1, 2], OP, app), Ok(()));
    }

    #[test]
    fn strings_may_be_shorter_octet_strings_may_not() {
        let mut dict = dictionary();
        let app = &mut App::default();
        let mut buf = [0u8; 16];
        assert_eq!(dict.write(0x2100, 0, b"abcdefgh", OP, app), Ok(()));
        assert_eq!(dict.write(0x2100, 0, b"xy", OP, app), Ok(()));
        assert_eq!(dict.read(0x2100, 0, 0, &mut buf, app), Ok(ReadOutcome { len: 2, total_len: 2 }));
        assert_eq!(&buf[..2], b"xy");
        assert_eq!(dict.write(0x2100, 0, b"abcdefghi", OP, app), Err(SdoAbort::LengthTooHigh));
        assert_eq!(dict.write(0x2101, 0, &[1, 2, 3], OP, app), Err(SdoAbort::LengthTooLow));
        assert_eq!(dict.write(0x2101, 0, &[1, 2, 3, 4, 5], OP, app), Err(SdoAbort::LengthTooHigh));
        assert_eq!(dict.write(0x2101, 0, &[1, 2, 3, 4], OP, app), Ok(()));
    }

    #[test]
    fn mapping_follows_the_cia_301_procedure() {
        let mut dict = dictionary();
        let app = &mut App::default();
        // Entries may not change while the mapping is enabled.
        assert_eq!(dict.write(0x1600, 1, &0x607A_0020u32.to_le_bytes(), PRE_OP, app), Err(SdoAbort::UnsupportedAccess));
        assert_eq!(dict.write(0x1600, 0, &[0], PRE_OP, app), Ok(()));
        // Step 3 checks each entry.
        assert_eq!(dict.write(0x1600, 2, &0x6041_0010u32.to_le_bytes(), PRE_OP, app), Err(SdoAbort::CannotBeMapped));
        assert_eq!(
            dict.write(0x1600, 2, &0x6042_0010u32.to_le_bytes(), PRE_OP, app),
            Err(SdoAbort::ObjectDoesNotExist)
        );
        assert_eq!(
            dict.write(0x1600, 2, &0x607A_0010u32.to_le_bytes(), PRE_OP, app),
            Err(SdoAbort::ParameterIncompatibility)
        );
        assert_eq!(dict.write(0x1600, 2, &0x2101_0020u32.to_le_bytes(), PRE_OP, app), Err(SdoAbort::CannotBeMapped));
        assert_eq!(dict.write(0x1600, 2, &0x607A_0020u32.to_le_bytes(), PRE_OP, app), Ok(()));
        // Step 4 checks the whole: 6 bytes fit CANopen's 8, not a 4-byte limit.
        let small = AccessContext { max_pdo_bytes: 4, ..PRE_OP };
        assert_eq!(dict.write(0x1600, 0, &[2], small, app), Err(SdoAbort::PdoLengthExceeded));
        assert_eq!(dict.read(0x1600, 0, 0, &mut [0u8; 1], app), Ok(ReadOutcome { len: 1, total_len: 1 }));
        assert_eq!(dict.values().raw(&ENTRIES[2]), Some(&[0][..]), "nothing changes on failure");
        assert_eq!(dict.write(0x1600, 0, &[2], PRE_OP, app), Ok(()));
        let table = *dict.table();
        let map = pdo_map::mapping(&table, dict.values().bytes(), 0x1600).map(|m| {
            let total = m.total_bits();
            let items: Vec<_> = m.map(|i| (i.target, i.bit_offset, i.bits)).collect();
            (total, items)
        });
        assert_eq!(
            map,
            Ok((
                48,
                vec![
                    (pdo_map::MapTarget::Object(&ENTRIES[8]), 0, 16),
                    (pdo_map::MapTarget::Object(&ENTRIES[11]), 16, 32)
                ]
            ))
        );
        // Dummy entries pad; their length must match their type.
        assert_eq!(dict.write(0x1600, 0, &[0], PRE_OP, app), Ok(()));
        assert_eq!(dict.write(0x1600, 2, &0x0005_0008u32.to_le_bytes(), PRE_OP, app), Ok(()));
        assert_eq!(
            dict.write(0x1600, 2, &0x0005_0010u32.to_le_bytes(), PRE_OP, app),
            Err(SdoAbort::ParameterIncompatibility)
        );
        assert_eq!(dict.write(0x1600, 0, &[2], PRE_OP, app), Ok(()));
    }

    #[test]
    fn application_entries_are_handed_over_after_the_checks() {
        let mut dict = dictionary();
        let mut app = App::default();
        assert_eq!(dict.write(0x1010, 1, b"sav", OP, &mut app), Err(SdoAbort::LengthTooLow));
        assert!(!app.complete);
        assert_eq!(dict.write(0x1010, 1, b"save", OP, &mut app), Ok(()));
        assert_eq!(&app.received[..4], b"save");
        assert!(app.complete);
        assert_eq!(dict.write(0x1010, 1, b"save", OP, &mut NoApplicationObjects), Err(SdoAbort::CannotTransfer));
    }

    #[test]
    fn segmented_downloads_apply_only_when_complete() {
        let mut dict = dictionary();
        let app = &mut App::default();
        let mut download: Download = dict.begin_download(0x2100, 0, Some(6), OP).unwrap();
        assert_eq!(dict.download_segment(&mut download, b"abc", false, OP, app), Ok(()));
        assert_eq!(dict.values().raw(&ENTRIES[6]), Some(&[0u8; 8][..]));
        assert_eq!(dict.download_segment(&mut download, b"def", true, OP, app), Ok(()));
        assert_eq!(dict.values().raw(&ENTRIES[6]), Some(&b"abcdef\0\0"[..]));
        assert!(download.is_done());
        assert_eq!(dict.download_segment(&mut download, b"x", true, OP, app), Err(SdoAbort::GeneralError));

        // Announced too long, or more data than announced.
        assert_eq!(dict.begin_download::<64>(0x2100, 0, Some(9), OP).map(|_| ()), Err(SdoAbort::LengthTooHigh));
        let mut download: Download = dict.begin_download(0x2100, 0, Some(2), OP).unwrap();
        assert_eq!(dict.download_segment(&mut download, b"xyz", true, OP, app), Err(SdoAbort::LengthTooHigh));
        assert_eq!(dict.values().raw(&ENTRIES[6]), Some(&b"abcdef\0\0"[..]));
        // Too much data without a size, or a staging buffer smaller than the entry.
        let mut download: Download = dict.begin_download(0x2100, 0, None, OP).unwrap();
        assert_eq!(dict.download_segment(&mut download, b"12345", false, OP, app), Ok(()));
        assert_eq!(dict.download_segment(&mut download, b"6789", true, OP, app), Err(SdoAbort::LengthTooHigh));
        assert_eq!(dict.begin_download::<4>(0x2100, 0, None, OP).map(|_| ()), Err(SdoAbort::OutOfMemory));

        // Application entries get each segment; an abort tells them to discard.
        let mut download: Download = dict.begin_download(0x1010, 1, Some(4), OP).unwrap();
        assert_eq!(dict.download_segment(&mut download, b"sa", false, OP, app), Ok(()));
        assert!(!app.complete);
        dict.abort_download(&mut download, app);
        assert!(app.aborted);
        assert_eq!(dict.begin_download::<64>(0x6041, 0, None, OP).map(|_| ()), Err(SdoAbort::ReadOnly));
    }
}
