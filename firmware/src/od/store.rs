//! Parameter persistence: CiA 301 0x1010 *Store parameters* ("save") and 0x1011 *Restore default parameters*
//! ("load") over a NOR flash with two ping-pong sectors (PARAMS_A and PARAMS_B of `memory.x`).
//!
//! # Behaviour (CiA 301 v4.2 §7.5.2.13 and §7.5.2.14; IDX Tables 6-61/6-62, L1677-L1717; spec §8)
//! * Sub-indices select a group (CiA 301 §7.5.2.13/14): 1 = all parameters, 2 = communication (0x1000-0x1FFF),
//!   3 = application (0x6000-0x9FFF), 4 = manufacturer-specific (0x2000-0x5FFF); see [`Selection`].
//! * Writing "save" (0x65766173) to 0x1010:n stores the current values of every persistent entry (IDX Backup flag
//!   YES; `Entry::persistent`) of the selected group(s). Writing "load" (0x64616F6C) to 0x1011:n marks the group(s)
//!   as "defaults": the defaults take effect at the next reset or power cycle (CiA 301 §7.5.2.14, IDX L1702), the
//!   running values stay unchanged until then. Any other value aborts with 0x0800_0020 (CiA 301 §7.5.2.13: "the
//!   CANopen device refuses to store and responds with abort 0800 0020h"; Gamma L514/L534).
//! * Reading 0x1010:n returns 1 (bit 0: the device saves on command; bit 1 = 0: no autonomous saving) and
//!   reading 0x1011:n returns 1 (the device restores defaults on command).
//! * At boot [`ParamStore::load`] applies the stored values over the defaults in the value image. Entries the
//!   running firmware does not know, or whose length changed (a firmware update changed the dictionary), are
//!   skipped and keep their defaults.
//!
//! # Atomicity
//! Every save or restore writes one complete new record into the sector that does *not* hold the record in
//! force: erase, program payload, program header with CRC, read back and verify, then program the commit word.
//! A record counts only if its commit word, magic, version, bounds, CRC-32 and item structure are all right, and
//! boot takes the valid record with the newest sequence number (wrapping comparison). A power cut at any point
//! therefore leaves either the old record (the new one is torn, or its sector half-erased) or the complete new
//! one in force. A group save merges the current values of its group with the stored values of the other
//! groups, so saving one group never loses another.
//!
//! # Record format (little-endian; offsets within the sector)
//! ```text
//!  0  u32  magic "OSDP" (0x5044_534F)
//!  4  u16  format version (1)
//!  6  u8   stored groups: bit 0 communication, bit 1 application, bit 2 manufacturer (values in the payload)
//!  7  u8   restored groups: groups set to default by 0x1011 since their last save (information only)
//!  8  u32  sequence number (+1 per record, wrapping)
//! 12  u32  payload length in bytes
//! 16  u32  number of items
//! 20  u32  reserved (0)
//! 24  u32  CRC-32 (IEEE 802.3) of the payload followed by header bytes 0..24
//! 28  u32  commit word "VALD" (0x444C_4156), programmed last
//! 32  ...  payload: items (u16 index, u8 sub, u16 length, `length` value bytes), packed; padded with 0xFF
//!          to the flash write size
//! ```

use crate::boot::crc32::Crc32;
use crate::hal::flash::{FlashError, Geometry, NorFlash};
use crate::od::abort::SdoAbort;
use crate::od::access::{ApplicationObjects, ReadOutcome};
use crate::od::entry::{Entry, Storage};

/// 0x1010 *Store parameters* (CiA 301 §7.5.2.13).
pub const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1011 *Restore default parameters* (CiA 301 §7.5.2.14).
pub const RESTORE_DEFAULT_PARAMETERS: u16 = 0x1011;
/// "save": the value to write to 0x1010:n (bytes 's','a','v','e'; IDX Table 6-61, L1677-L1682).
pub const SAVE_SIGNATURE: u32 = 0x6576_6173;
/// "load": the value to write to 0x1011:n (bytes 'l','o','a','d'; IDX Table 6-62, L1712-L1717).
pub const LOAD_SIGNATURE: u32 = 0x6461_6F6C;
/// Highest sub-index of 0x1010 and 0x1011 (sub 0 reads this).
pub const HIGHEST_SUB: u8 = 4;
/// What 0x1010:n and 0x1011:n read: bit 0 set = on command, bit 1 clear = never autonomously (CiA 301).
pub const COMMAND_READ_VALUE: u32 = 1;

/// Magic word at offset 0 of a record: "OSDP".
pub const RECORD_MAGIC: u32 = u32::from_le_bytes(*b"OSDP");
/// Record format version this firmware writes and reads.
pub const RECORD_VERSION: u16 = 1;
/// Commit word at offset 28, programmed after everything else: "VALD".
pub const RECORD_COMMIT: u32 = u32::from_le_bytes(*b"VALD");
/// Size of the record header (the payload starts here).
pub const RECORD_HEADER_LEN: u32 = 32;
/// Size of an item header (index, sub, length).
pub const ITEM_HEADER_LEN: u32 = 5;

pub(crate) const OFF_MAGIC: usize = 0;
pub(crate) const OFF_VERSION: usize = 4;
pub(crate) const OFF_STORED: usize = 6;
const OFF_RESTORED: usize = 7;
pub(crate) const OFF_SEQUENCE: usize = 8;
pub(crate) const OFF_PAYLOAD_LEN: usize = 12;
pub(crate) const OFF_ITEM_COUNT: usize = 16;
pub(crate) const OFF_CRC: usize = 24;
pub(crate) const OFF_COMMIT: usize = 28;
/// Header bytes the CRC covers (everything before the CRC word).
pub(crate) const CRC_HEADER_LEN: usize = 24;
/// Payload bytes buffered per program operation.
const CHUNK: usize = 128;
/// Bytes read per flash read when checking or copying.
const READ_CHUNK: usize = 64;

/// A parameter group of 0x1010/0x1011 (CiA 301 §7.5.2.13/14: sub 2 communication, 3 application,
/// 4 manufacturer-defined).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Group {
    /// Communication profile area 0x1000-0x1FFF (sub 2).
    Communication,
    /// Device-profile (application) area 0x6000-0x9FFF (sub 3).
    Application,
    /// Manufacturer-specific area 0x2000-0x5FFF (sub 4).
    Manufacturer,
}

impl Group {
    /// Every group, in sub-index order.
    pub const ALL: [Group; 3] = [Group::Communication, Group::Application, Group::Manufacturer];

    /// The group's bit in [`GroupSet`] and in the record header.
    pub const fn bit(self) -> u8 {
        match self {
            Self::Communication => 0b001,
            Self::Application => 0b010,
            Self::Manufacturer => 0b100,
        }
    }
}

/// The group an object index belongs to for 0x1010/0x1011 sub-indices 2..4.
///
/// 0x1000-0x1FFF communication, 0x2000-0x5FFF manufacturer, 0x6000-0x9FFF application (CiA 301 §7.5.2.13).
/// CiA 301 assigns no group to 0x0000-0x0FFF (data types, never persistent) and 0xA000-0xFFFF (network
/// variables, MDP device area); they are counted with communication and application respectively, so that
/// "save all" still covers any persistent entry there.
pub const fn store_group_of(index: u16) -> Group {
    match index {
        0x0000..=0x1FFF => Group::Communication,
        0x2000..=0x5FFF => Group::Manufacturer,
        _ => Group::Application,
    }
}

/// A set of groups (bit 0 communication, bit 1 application, bit 2 manufacturer).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GroupSet(u8);

impl GroupSet {
    /// No group.
    pub const EMPTY: Self = Self(0);
    /// Every group.
    pub const ALL: Self = Self(0b111);

    /// The set from its bits; bits above 2 are dropped.
    pub const fn from_bits(bits: u8) -> Self {
        Self(bits & 0b111)
    }

    /// The bits of the set.
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// Whether `group` is in the set.
    pub const fn contains(self, group: Group) -> bool {
        self.0 & group.bit() != 0
    }

    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Union.
    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }

    /// Difference (`self` without `other`).
    pub const fn without(self, other: Self) -> Self {
        Self(self.0 & !other.0)
    }

    /// Intersection.
    pub const fn intersection(self, other: Self) -> Self {
        Self(self.0 & other.0)
    }
}

/// Which groups a 0x1010/0x1011 sub-index addresses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Selection {
    /// Sub 1: all parameters.
    All,
    /// Subs 2..4: one group.
    Only(Group),
}

impl Selection {
    /// The selection of sub-index `sub` of 0x1010/0x1011, or `None` for sub 0 and subs above 4.
    pub const fn from_sub(sub: u8) -> Option<Self> {
        match sub {
            1 => Some(Self::All),
            2 => Some(Self::Only(Group::Communication)),
            3 => Some(Self::Only(Group::Application)),
            4 => Some(Self::Only(Group::Manufacturer)),
            _ => None,
        }
    }

    /// The groups selected.
    pub const fn groups(self) -> GroupSet {
        match self {
            Self::All => GroupSet::ALL,
            Self::Only(g) => GroupSet(g.bit()),
        }
    }

    /// Whether entries of object `index` are selected.
    pub const fn covers(self, index: u16) -> bool {
        self.groups().contains(store_group_of(index))
    }
}

/// Errors of the parameter store. Each maps to a CiA 301 SDO abort code ([`StoreError::abort`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreError {
    /// The flash failed; the record in force is unchanged (abort 0x0606_0000, hardware error).
    Flash(FlashError),
    /// The flash region is not two or more sectors with a power-of-two write size up to 32 bytes.
    Geometry,
    /// The record does not fit into one sector (abort 0x0800_0020).
    TooLarge,
    /// The record read back differs from what was written; it was not committed (abort 0x0606_0000).
    VerifyFailed,
    /// A committed record became unreadable while it was being used (abort 0x0606_0000).
    Corrupt,
    /// A persistent entry's storage lies outside the value image (table and image disagree; abort 0x0800_0000).
    ValueImage,
    /// Wrong signature written to 0x1010/0x1011 (abort 0x0800_0020, CiA 301 §7.5.2.13/14).
    WrongSignature,
    /// The object is not 0x1010/0x1011 (abort 0x0602_0000).
    NoSuchObject,
    /// Sub-index beyond 4 (abort 0x0609_0011).
    NoSuchSubIndex,
    /// Write to sub 0 (abort 0x0601_0002).
    ReadOnly,
    /// The written data is not 4 bytes (abort 0x0607_0010).
    WrongLength,
}

impl StoreError {
    /// The CiA 301 SDO abort code (§7.2.4.3.17 Table 22) to answer the transfer with.
    pub const fn abort(self) -> SdoAbort {
        match self {
            Self::Flash(_) | Self::VerifyFailed | Self::Corrupt => SdoAbort::HardwareError,
            Self::Geometry | Self::TooLarge | Self::WrongSignature => SdoAbort::CannotTransfer,
            Self::ValueImage => SdoAbort::GeneralError,
            Self::NoSuchObject => SdoAbort::ObjectDoesNotExist,
            Self::NoSuchSubIndex => SdoAbort::SubindexDoesNotExist,
            Self::ReadOnly => SdoAbort::ReadOnly,
            Self::WrongLength => SdoAbort::LengthMismatch,
        }
    }
}

impl From<StoreError> for SdoAbort {
    fn from(e: StoreError) -> Self {
        e.abort()
    }
}

impl From<FlashError> for StoreError {
    fn from(e: FlashError) -> Self {
        Self::Flash(e)
    }
}

/// A valid, committed record found in flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordInfo {
    /// Store sector (0 = PARAMS_A, 1 = PARAMS_B).
    pub sector: u32,
    /// Sequence number.
    pub sequence: u32,
    /// Groups whose values the record holds.
    pub stored: GroupSet,
    /// Groups set to default by 0x1011 since their last save.
    pub restored: GroupSet,
    /// Number of items.
    pub items: u32,
    /// Payload length in bytes.
    pub payload_len: u32,
}

/// What [`ParamStore::load`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoadReport {
    /// The record the values came from, or `None` if no valid record exists (all defaults).
    pub record: Option<RecordInfo>,
    /// Items written into the value image.
    pub applied: u32,
    /// Items skipped because the dictionary has no persistent RAM entry with that (index, sub).
    pub unknown: u32,
    /// Items skipped because the entry's size differs from the stored length (or lies outside the image).
    pub mismatched: u32,
}

/// Whether sequence number `a` is newer than `b` (serial-number arithmetic: newer within half the range).
pub const fn sequence_newer(a: u32, b: u32) -> bool {
    let d = a.wrapping_sub(b);
    d != 0 && d < 0x8000_0000
}

// ---------------------------------------------------------------------------------------------------------------
// CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320, initial value and final XOR 0xFFFFFFFF): the records share
// the update code's half-byte-table CRC (`boot::crc32`), which the bootloader needs anyway to read the stored
// communication settings (`boot::stored_comms`); a byte table of its own here cost 1 KiB of flash. The store runs
// it at start-up and on 0x1010 "save" only, in no tick.

/// CRC-32 (IEEE 802.3) of `data`, the checksum the record format uses (check value of "123456789": 0xCBF43926).
pub fn crc32(data: &[u8]) -> u32 {
    crate::boot::crc32::checksum(data)
}

// ---------------------------------------------------------------------------------------------------------------
// Little helpers without indexing or unchecked arithmetic.

fn le_u32(buf: &[u8], at: usize) -> u32 {
    buf.get(at..).and_then(|s| s.first_chunk::<4>()).map_or(0, |b| u32::from_le_bytes(*b))
}

fn le_u16(buf: &[u8], at: usize) -> u16 {
    buf.get(at..).and_then(|s| s.first_chunk::<2>()).map_or(0, |b| u16::from_le_bytes(*b))
}

fn byte(buf: &[u8], at: usize) -> u8 {
    buf.get(at).copied().unwrap_or(0)
}

fn put(buf: &mut [u8], at: usize, bytes: &[u8]) {
    if let Some(dst) = at.checked_add(bytes.len()).and_then(|end| buf.get_mut(at..end)) {
        dst.copy_from_slice(bytes);
    }
}

fn len_u32(n: usize) -> Option<u32> {
    u32::try_from(n).ok()
}

/// Reads at `rel` within the sector starting at `base`.
fn read_rel<F: NorFlash>(flash: &mut F, base: u32, rel: u32, buf: &mut [u8]) -> Result<(), StoreError> {
    let at = base.checked_add(rel).ok_or(StoreError::Flash(FlashError::OutOfBounds))?;
    Ok(flash.read(at, buf)?)
}

/// Programs at `rel` within the sector starting at `base`.
fn program_rel<F: NorFlash>(flash: &mut F, base: u32, rel: u32, data: &[u8]) -> Result<(), StoreError> {
    let at = base.checked_add(rel).ok_or(StoreError::Flash(FlashError::OutOfBounds))?;
    Ok(flash.program(at, data)?)
}

/// The geometry if the store can use it: at least two sectors, write size a power of two dividing the header.
fn checked_geometry(g: Geometry) -> Result<Geometry, StoreError> {
    let ok = g.sector_count >= 2
        && g.write_size.is_power_of_two()
        && g.write_size <= RECORD_HEADER_LEN
        && g.sector_size >= RECORD_HEADER_LEN
        && g.sector_size.checked_rem(g.write_size) == Some(0)
        && g.sector_start(1).is_some();
    if ok {
        Ok(g)
    } else {
        Err(StoreError::Geometry)
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Items.

/// One item of a record's payload.
#[derive(Clone, Copy, Debug)]
struct Item {
    index: u16,
    sub: u8,
    len: u16,
    /// Offset of the value bytes within the sector.
    data: u32,
}

/// Walks the items of a payload. `Ok(None)` at the end; `Err(Corrupt)` if the structure is broken.
struct Items {
    next: u32,
    end: u32,
    left: u32,
}

impl Items {
    fn new(payload_len: u32, count: u32) -> Option<Self> {
        Some(Self { next: RECORD_HEADER_LEN, end: RECORD_HEADER_LEN.checked_add(payload_len)?, left: count })
    }

    fn next<F: NorFlash>(&mut self, flash: &mut F, base: u32) -> Result<Option<Item>, StoreError> {
        if self.left == 0 {
            return if self.next == self.end { Ok(None) } else { Err(StoreError::Corrupt) };
        }
        let data = self.next.checked_add(ITEM_HEADER_LEN).filter(|d| *d <= self.end).ok_or(StoreError::Corrupt)?;
        let mut hdr = [0u8; ITEM_HEADER_LEN as usize];
        read_rel(flash, base, self.next, &mut hdr)?;
        let [i0, i1, sub, l0, l1] = hdr;
        let len = u16::from_le_bytes([l0, l1]);
        let after = data.checked_add(u32::from(len)).filter(|a| *a <= self.end).ok_or(StoreError::Corrupt)?;
        self.next = after;
        self.left = self.left.saturating_sub(1);
        Ok(Some(Item { index: u16::from_le_bytes([i0, i1]), sub, len, data }))
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Record writer: streams the payload into a freshly erased sector, chunk by chunk.

struct Writer<'a, F: NorFlash> {
    flash: &'a mut F,
    base: u32,
    /// Sector-relative offset where `buf` will be programmed.
    at: u32,
    buf: [u8; CHUNK],
    fill: usize,
    limit: u32,
    write_size: u32,
    crc: Crc32,
    payload_len: u32,
    items: u32,
}

impl<'a, F: NorFlash> Writer<'a, F> {
    fn new(flash: &'a mut F, base: u32, geometry: Geometry) -> Self {
        Self {
            flash,
            base,
            at: RECORD_HEADER_LEN,
            buf: [0xFF; CHUNK],
            fill: 0,
            limit: geometry.sector_size,
            write_size: geometry.write_size,
            crc: Crc32::new(),
            payload_len: 0,
            items: 0,
        }
    }

    fn push(&mut self, mut bytes: &[u8]) -> Result<(), StoreError> {
        let n = len_u32(bytes.len()).ok_or(StoreError::TooLarge)?;
        self.payload_len = self.payload_len.checked_add(n).ok_or(StoreError::TooLarge)?;
        let end = RECORD_HEADER_LEN.checked_add(self.payload_len).ok_or(StoreError::TooLarge)?;
        if end > self.limit {
            return Err(StoreError::TooLarge);
        }
        self.crc.update(bytes);
        while !bytes.is_empty() {
            let room = CHUNK.saturating_sub(self.fill);
            let (now, rest) = bytes.split_at(room.min(bytes.len()));
            put(&mut self.buf, self.fill, now);
            self.fill = self.fill.saturating_add(now.len());
            bytes = rest;
            if self.fill == CHUNK {
                self.flush()?;
            }
        }
        Ok(())
    }

    /// Programs the buffered bytes, padded with 0xFF to the write size.
    fn flush(&mut self) -> Result<(), StoreError> {
        if self.fill == 0 {
            return Ok(());
        }
        let ws = usize::try_from(self.write_size).map_err(|_| StoreError::Geometry)?;
        let padded = self.fill.div_ceil(ws).saturating_mul(ws).min(CHUNK);
        let data = self.buf.get(..padded).ok_or(StoreError::Geometry)?;
        program_rel(self.flash, self.base, self.at, data)?;
        self.at = self.at.checked_add(len_u32(padded).ok_or(StoreError::TooLarge)?).ok_or(StoreError::TooLarge)?;
        self.buf = [0xFF; CHUNK];
        self.fill = 0;
        Ok(())
    }

    fn item(&mut self, index: u16, sub: u8, len: u16) -> Result<(), StoreError> {
        let [i0, i1] = index.to_le_bytes();
        let [l0, l1] = len.to_le_bytes();
        self.items = self.items.checked_add(1).ok_or(StoreError::TooLarge)?;
        self.push(&[i0, i1, sub, l0, l1])
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The store.

/// The parameter store over a flash region of (at least) two sectors; sectors 0 and 1 are the ping-pong pair.
///
/// The store keeps no state of its own besides the flash: every operation finds the record in force by reading
/// the two sector headers, so a failed or interrupted operation never leaves a stale view behind.
#[derive(Debug)]
pub struct ParamStore<F> {
    flash: F,
}

impl<F: NorFlash> ParamStore<F> {
    /// A store over `flash` (sectors 0 and 1 of it).
    pub const fn new(flash: F) -> Self {
        Self { flash }
    }

    /// The flash (for diagnostics and tests).
    pub const fn flash(&self) -> &F {
        &self.flash
    }

    /// The flash, mutable (for tests that inject faults).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    fn geometry(&self) -> Result<Geometry, StoreError> {
        checked_geometry(self.flash.geometry())
    }

    /// Checks the record in `sector`: `Ok(None)` if it is absent, torn or corrupt. With `committed` false the
    /// commit word is not required (used to verify a record before committing it).
    fn check(&mut self, geometry: Geometry, sector: u32, committed: bool) -> Result<Option<RecordInfo>, StoreError> {
        let base = geometry.sector_start(sector).ok_or(StoreError::Geometry)?;
        let mut hdr = [0u8; RECORD_HEADER_LEN as usize];
        read_rel(&mut self.flash, base, 0, &mut hdr)?;
        let payload_len = le_u32(&hdr, OFF_PAYLOAD_LEN);
        let items = le_u32(&hdr, OFF_ITEM_COUNT);
        let room = geometry.sector_size.saturating_sub(RECORD_HEADER_LEN);
        if le_u32(&hdr, OFF_MAGIC) != RECORD_MAGIC
            || le_u16(&hdr, OFF_VERSION) != RECORD_VERSION
            || (committed && le_u32(&hdr, OFF_COMMIT) != RECORD_COMMIT)
            || payload_len > room
            // Each item takes at least its header, so the count is bounded by the payload length.
            || items > payload_len / ITEM_HEADER_LEN
        {
            return Ok(None);
        }
        // CRC over the payload, then the header bytes before the CRC word.
        let mut crc = Crc32::new();
        let mut chunk = [0u8; READ_CHUNK];
        let mut at = RECORD_HEADER_LEN;
        let mut left = payload_len;
        while left > 0 {
            let n = left.min(READ_CHUNK as u32);
            let buf = chunk.get_mut(..n as usize).ok_or(StoreError::Corrupt)?;
            read_rel(&mut self.flash, base, at, buf)?;
            crc.update(buf);
            at = at.saturating_add(n);
            left = left.saturating_sub(n);
        }
        crc.update(hdr.get(..CRC_HEADER_LEN).unwrap_or(&[]));
        if crc.finalize() != le_u32(&hdr, OFF_CRC) {
            return Ok(None);
        }
        // Structure: exactly `items` items filling exactly the payload.
        let Some(mut walk) = Items::new(payload_len, items) else { return Ok(None) };
        loop {
            match walk.next(&mut self.flash, base) {
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(StoreError::Corrupt) => return Ok(None),
                Err(e) => return Err(e),
            }
        }
        Ok(Some(RecordInfo {
            sector,
            sequence: le_u32(&hdr, OFF_SEQUENCE),
            stored: GroupSet::from_bits(byte(&hdr, OFF_STORED)),
            restored: GroupSet::from_bits(byte(&hdr, OFF_RESTORED)),
            items,
            payload_len,
        }))
    }

    /// The record in force: the valid record with the newest sequence number, or `None` (factory defaults).
    pub fn current(&mut self) -> Result<Option<RecordInfo>, StoreError> {
        let geometry = self.geometry()?;
        let a = self.check(geometry, 0, true)?;
        let b = self.check(geometry, 1, true)?;
        Ok(match (a, b) {
            (Some(a), Some(b)) => Some(if sequence_newer(b.sequence, a.sequence) { b } else { a }),
            (a, b) => a.or(b),
        })
    }

    /// Applies the stored values of the `selection` groups over `values` (a value image initialised with the
    /// defaults, `od::values::Values::bytes_mut()`), using `entries` (sorted by (index, sub), as generated).
    ///
    /// Called at boot with [`Selection::All`]; after an NMT *reset communication* with
    /// `Selection::Only(Group::Communication)` once the communication area has been reset to its defaults
    /// (CiA 301 §7.5.2.14: communication defaults take effect at reset communication). Items the dictionary
    /// does not know as a persistent RAM entry, or whose length differs, are skipped (counted in the report).
    /// Corrupt flash is never an error: without a valid record the values stay as they are.
    pub fn load(
        &mut self,
        selection: Selection,
        entries: &[Entry],
        values: &mut [u8],
    ) -> Result<LoadReport, StoreError> {
        let geometry = self.geometry()?;
        let mut report = LoadReport { record: self.current()?, ..LoadReport::default() };
        let Some(record) = report.record else { return Ok(report) };
        let base = geometry.sector_start(record.sector).ok_or(StoreError::Geometry)?;
        let wanted = record.stored.intersection(selection.groups());
        let mut walk = Items::new(record.payload_len, record.items).ok_or(StoreError::Corrupt)?;
        while let Some(item) = walk.next(&mut self.flash, base)? {
            if !wanted.contains(store_group_of(item.index)) {
                continue;
            }
            let found = entries
                .binary_search_by(|e| (e.index, e.sub).cmp(&(item.index, item.sub)))
                .ok()
                .and_then(|i| entries.get(i))
                .filter(|e| e.persistent());
            let Some(entry) = found else {
                report.unknown = report.unknown.saturating_add(1);
                continue;
            };
            let target = match entry.storage {
                Storage::Ram { offset, len, .. } if len == item.len => {
                    let start = usize::from(offset);
                    start.checked_add(usize::from(len)).and_then(|end| values.get_mut(start..end))
                }
                _ => None,
            };
            let Some(target) = target else {
                report.mismatched = report.mismatched.saturating_add(1);
                continue;
            };
            read_rel(&mut self.flash, base, item.data, target)?;
            report.applied = report.applied.saturating_add(1);
        }
        Ok(report)
    }

    /// 0x1010 "save" for `selection`: writes a new record holding the current `values` of every persistent RAM
    /// entry of the selected groups plus the stored values of the other groups (CiA 301 §7.5.2.13).
    pub fn save(&mut self, selection: Selection, entries: &[Entry], values: &[u8]) -> Result<RecordInfo, StoreError> {
        let sel = selection.groups();
        let current = self.current()?;
        let (stored, restored) = match current {
            Some(c) => (c.stored.union(sel), c.restored.without(sel)),
            None => (sel, GroupSet::EMPTY),
        };
        self.write_record(current, sel, stored, restored, Some((entries, values)))
    }

    /// 0x1011 "load" for `selection`: writes a new record without the selected groups' values, so that their
    /// defaults take effect at the next reset; the running values are not touched (CiA 301 §7.5.2.14, IDX L1702).
    /// Returns the record now in force (`None` if nothing is stored at all). When no selected group holds stored
    /// values, nothing is written.
    pub fn restore_defaults(&mut self, selection: Selection) -> Result<Option<RecordInfo>, StoreError> {
        let sel = selection.groups();
        let current = self.current()?;
        let Some(c) = current else { return Ok(None) };
        if c.stored.intersection(sel).is_empty() {
            return Ok(current);
        }
        let info = self.write_record(current, sel, c.stored.without(sel), c.restored.union(sel), None)?;
        Ok(Some(info))
    }

    /// Writes a new record into the sector not holding `current`: the items of `current` outside `replace`, then
    /// (if given) the current values of the persistent entries inside `replace`.
    fn write_record(
        &mut self,
        current: Option<RecordInfo>,
        replace: GroupSet,
        stored: GroupSet,
        restored: GroupSet,
        fresh: Option<(&[Entry], &[u8])>,
    ) -> Result<RecordInfo, StoreError> {
        let geometry = self.geometry()?;
        let (target, sequence) = match current {
            Some(c) => (if c.sector == 0 { 1 } else { 0 }, c.sequence.wrapping_add(1)),
            None => (0, 1),
        };
        let base = geometry.sector_start(target).ok_or(StoreError::Geometry)?;

        // 1. Erase.
        self.flash.erase_sector(target)?;

        // 2. Payload: values of the other groups copied from the record in force...
        let mut old_walk = match current {
            Some(c) => Some((
                geometry.sector_start(c.sector).ok_or(StoreError::Geometry)?,
                c.stored.without(replace),
                Items::new(c.payload_len, c.items).ok_or(StoreError::Corrupt)?,
            )),
            None => None,
        };
        let mut scratch = [0u8; READ_CHUNK];
        let (payload_len, items, crc) = {
            // The writer borrows the flash mutably; reads of the old sector go through it too.
            let mut w = Writer::new(&mut self.flash, base, geometry);
            if let Some((old_base, keep, walk)) = old_walk.as_mut() {
                while let Some(item) = walk.next(w.flash, *old_base)? {
                    if !keep.contains(store_group_of(item.index)) {
                        continue;
                    }
                    w.item(item.index, item.sub, item.len)?;
                    let mut at = item.data;
                    let mut left = u32::from(item.len);
                    while left > 0 {
                        let n = left.min(READ_CHUNK as u32);
                        let buf = scratch.get_mut(..n as usize).ok_or(StoreError::Corrupt)?;
                        read_rel(w.flash, *old_base, at, buf)?;
                        w.push(buf)?;
                        at = at.saturating_add(n);
                        left = left.saturating_sub(n);
                    }
                }
            }
            // ...and the current values of the replaced groups.
            if let Some((entries, values)) = fresh {
                for e in entries.iter().filter(|e| e.persistent() && replace.contains(store_group_of(e.index))) {
                    let Storage::Ram { offset, len, .. } = e.storage else { continue };
                    let start = usize::from(offset);
                    let bytes = start
                        .checked_add(usize::from(len))
                        .and_then(|end| values.get(start..end))
                        .ok_or(StoreError::ValueImage)?;
                    w.item(e.index, e.sub, len)?;
                    w.push(bytes)?;
                }
            }
            w.flush()?;
            (w.payload_len, w.items, w.crc)
        };

        // 3. Header with CRC (commit word left erased).
        let mut hdr = [0xFFu8; OFF_COMMIT];
        put(&mut hdr, OFF_MAGIC, &RECORD_MAGIC.to_le_bytes());
        put(&mut hdr, OFF_VERSION, &RECORD_VERSION.to_le_bytes());
        put(&mut hdr, OFF_STORED, &[stored.bits()]);
        put(&mut hdr, OFF_RESTORED, &[restored.bits()]);
        put(&mut hdr, OFF_SEQUENCE, &sequence.to_le_bytes());
        put(&mut hdr, OFF_PAYLOAD_LEN, &payload_len.to_le_bytes());
        put(&mut hdr, OFF_ITEM_COUNT, &items.to_le_bytes());
        put(&mut hdr, 20, &0u32.to_le_bytes());
        let mut crc = crc;
        crc.update(hdr.get(..CRC_HEADER_LEN).unwrap_or(&[]));
        put(&mut hdr, OFF_CRC, &crc.finalize().to_le_bytes());
        program_rel(&mut self.flash, base, 0, &hdr)?;

        // 4. Read back and verify before committing.
        if self.check(geometry, target, false)?.is_none() {
            return Err(StoreError::VerifyFailed);
        }

        // 5. Commit: from here on the new record is in force.
        program_rel(&mut self.flash, base, OFF_COMMIT as u32, &RECORD_COMMIT.to_le_bytes())?;
        self.check(geometry, target, true)?.ok_or(StoreError::VerifyFailed)
    }

    /// SDO read of 0x1010:sub or 0x1011:sub (the application-object hook): sub 0 reads 4, subs 1..4 read 1.
    pub fn read_command(index: u16, sub: u8) -> Result<u32, StoreError> {
        if index != STORE_PARAMETERS && index != RESTORE_DEFAULT_PARAMETERS {
            return Err(StoreError::NoSuchObject);
        }
        match sub {
            0 => Ok(u32::from(HIGHEST_SUB)),
            1..=HIGHEST_SUB => Ok(COMMAND_READ_VALUE),
            _ => Err(StoreError::NoSuchSubIndex),
        }
    }

    /// SDO write of 0x1010:sub or 0x1011:sub (the application-object hook): checks the signature ("save"
    /// 0x65766173 for 0x1010, "load" 0x64616F6C for 0x1011; otherwise abort 0x0800_0020 as CiA 301
    /// §7.5.2.13/14 prescribe) and saves or restores the selected group(s). `data` is the expedited payload
    /// (4 bytes, little-endian). The caller checks the write condition (0x1011 only in Pre-Operational with the
    /// power stage disabled, IDX L1702) before calling.
    pub fn write_command(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        entries: &[Entry],
        values: &[u8],
    ) -> Result<(), StoreError> {
        if index != STORE_PARAMETERS && index != RESTORE_DEFAULT_PARAMETERS {
            return Err(StoreError::NoSuchObject);
        }
        let selection = match sub {
            0 => return Err(StoreError::ReadOnly),
            s => Selection::from_sub(s).ok_or(StoreError::NoSuchSubIndex)?,
        };
        let signature = data.first_chunk::<4>().filter(|_| data.len() == 4).ok_or(StoreError::WrongLength)?;
        let signature = u32::from_le_bytes(*signature);
        if index == STORE_PARAMETERS {
            if signature != SAVE_SIGNATURE {
                return Err(StoreError::WrongSignature);
            }
            self.save(selection, entries, values).map(|_| ())
        } else {
            if signature != LOAD_SIGNATURE {
                return Err(StoreError::WrongSignature);
            }
            self.restore_defaults(selection).map(|_| ())
        }
    }
}

/// The store as the dictionary's [`ApplicationObjects`] hook for 0x1010 and 0x1011 (every other application
/// entry aborts with 0x0800_0020). A drive that serves more application objects (program control 0x1F50/0x1F51)
/// forwards the entries of 0x1010/0x1011 to this.
#[derive(Debug)]
pub struct StoreObjects<'a, F> {
    /// The store.
    pub store: &'a mut ParamStore<F>,
    /// The dictionary's entry table (sorted by (index, sub)), whose persistent entries a save stores.
    pub entries: &'a [Entry],
}

impl<F: NorFlash> ApplicationObjects for StoreObjects<'_, F> {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        let bytes = ParamStore::<F>::read_command(entry.index, entry.sub)?.to_le_bytes();
        let rest = bytes.get(offset..).unwrap_or(&[]);
        let len = rest.len().min(buf.len());
        if let (Some(to), Some(from)) = (buf.get_mut(..len), rest.get(..len)) {
            to.copy_from_slice(from);
        }
        Ok(ReadOutcome { len, total_len: bytes.len() })
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        // The signature is an UNSIGNED32: always one expedited transfer (offset 0, complete).
        if offset != 0 || !complete {
            return Err(SdoAbort::LengthMismatch);
        }
        Ok(self.store.write_command(entry.index, entry.sub, data, self.entries, values)?)
    }

    fn reload_communication(&mut self, values: &mut [u8]) {
        // A flash that cannot be read leaves the defaults: the boot has already reported the store's state
        // (0x6380 when its record is unreadable), and a reset must complete in any case.
        let _ = self.store.load(Selection::Only(Group::Communication), self.entries, values);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_check_value() {
        // The standard check value of CRC-32/ISO-HDLC.
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn signatures_spell_save_and_load() {
        assert_eq!(SAVE_SIGNATURE.to_le_bytes(), *b"save");
        assert_eq!(LOAD_SIGNATURE.to_le_bytes(), *b"load");
    }

    #[test]
    fn groups_follow_cia_301_ranges() {
        assert_eq!(store_group_of(0x1017), Group::Communication);
        assert_eq!(store_group_of(0x1FFF), Group::Communication);
        assert_eq!(store_group_of(0x2000), Group::Manufacturer);
        assert_eq!(store_group_of(0x5FFF), Group::Manufacturer);
        assert_eq!(store_group_of(0x6000), Group::Application);
        assert_eq!(store_group_of(0x9FFF), Group::Application);
        assert_eq!(Selection::from_sub(0), None);
        assert_eq!(Selection::from_sub(1), Some(Selection::All));
        assert_eq!(Selection::from_sub(4), Some(Selection::Only(Group::Manufacturer)));
        assert_eq!(Selection::from_sub(5), None);
        assert!(Selection::Only(Group::Application).covers(0x6081));
        assert!(!Selection::Only(Group::Application).covers(0x1600));
    }

    #[test]
    fn sequence_comparison_wraps() {
        assert!(sequence_newer(2, 1));
        assert!(!sequence_newer(1, 2));
        assert!(!sequence_newer(7, 7));
        assert!(sequence_newer(0, u32::MAX));
        assert!(sequence_newer(3, u32::MAX - 3));
    }
}
