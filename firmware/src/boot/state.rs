//! The update state in BOOT_STATE (sector 4, 64 KiB): an append-only log of 16-byte records, each with its own
//! CRC, written by the application (image pending, confirmation) and by the bootloader (swap progress, trial,
//! revert).
//!
//! # Power-fail safety
//! * A record is one program of 16 bytes. A cut during it leaves either nothing (the slot still reads 0xFF
//!   and is reused), a slot whose CRC fails (skipped for ever), or the complete record. The record in force is
//!   the valid one at the highest slot; appends go after the highest slot that is not erased, so log order is
//!   time order even after torn writes.
//! * The log is erased only when its state is [`BootState::Idle`], which is also what an erased (or garbled)
//!   log means: slot A holds the confirmed image, nothing is pending. An erase torn by a cut therefore loses no
//!   information, and no erase ever removes the only copy of a state that matters (a pending image, a swap in
//!   progress, a trial). [`ensure_room`] does this compaction before an activation starts, so that the
//!   activation, the swap and a possible revert find [`RESERVE`] free slots.
//!
//! # The minimum security version (anti-rollback)
//! The drive refuses a signed image whose security version ([`super::image`]) is below a minimum, which rises when
//! an image confirms itself, never at its download: a trial that reverts must leave the previous image loadable.
//! The minimum lives in [`RecordKind::Floor`] records (their 4-byte field holds the version) and is the highest
//! one in the log ([`Scan::floor`]); a Floor record does not change the [`BootState`] (the state comes from the
//! newest other record). The log is erased when idle, so the minimum must also survive a power cut right after
//! that erase, before it is written again. It does because of one invariant: **in the idle and pending states,
//! slot A holds the confirmed image, and its security version is at least the minimum** (the minimum is only
//! ever raised to the security version of the image that confirms itself in slot A; a reverted trial leaves it
//! where it was; a new image must be at or above it to be activated). So the minimum in force is
//! [`minimum_security_version`]: the highest Floor record, and in the idle and pending states also slot A's
//! security version. Every write order is then safe:
//! * confirmation ([`super::update::confirm`]): `Confirmed`, then `Floor(security version of the image)`. A cut
//!   between them leaves the idle state with the old Floor: slot A's version (the new image) counts already. The
//!   other order would be wrong: `Floor` first and a cut before `Confirmed` would revert the trial with the
//!   minimum already raised, locking out the image it reverts to.
//! * compaction ([`ensure_room`], idle only): erase, and the activation that asked for it
//!   ([`super::update::Download::activate`]) then writes `Floor(minimum in force)` before `Pending`. A cut after
//!   the erase leaves an empty log (idle: slot A's version is the minimum); a cut before `Pending` leaves idle
//!   with the Floor. When `Pending` is in force the log's Floor is therefore the whole minimum, and the
//!   bootloader checks the pending image against it without reading slot A.
//! * a torn Floor record fails its CRC and is skipped (the previous ones still count); the log only ever gains
//!   Floor records with a version at least the previous ones', so a partial erase that leaves some old records
//!   can only leave a lower Floor, which slot A's version covers.
//!
//! During a swap and a trial, slot A's version does not count (slot A holds a half swap or the unconfirmed
//! image); the log's Floor, written before the Pending record, is the minimum then. Without a valid image in
//! slot A (the bootloader's fallback) the log's Floor alone is the minimum.
//!
//! # Record (little-endian)
//! ```text
//!  0  u8   kind (RecordKind)
//!  1  u8   direction of a swap step (1 activate, 2 revert)
//!  2  u8   sector index of a swap step
//!  3  u8   phase of a swap step (1 saved, 2 installed, 3 done)
//!  4  u32  payload CRC of the image concerned (information: which image is pending / on trial); in a Floor
//!           record the minimum security version
//!  8  u32  magic "OSDS"
//! 12  u32  CRC-32 of bytes 0..12
//! ```

use super::crc32;
use crate::hal::flash::{FlashError, NorFlash};

/// Size of one record.
pub const RECORD_LEN: u32 = 16;
/// Free record slots an activation needs: pending + 3 x 3 swap steps + trial + confirm, the same again for a
/// revert, and the rest for records torn by power cuts during the update.
pub const RESERVE: u32 = 64;
const RECORD_MAGIC: u32 = u32::from_le_bytes(*b"OSDS");
/// How many records are read per flash read while scanning.
const SCAN_BATCH: usize = 16;

/// What a record says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordKind {
    /// Slot B holds a verified image; activate it at the next reset (written by the application).
    Pending = 1,
    /// One step of a swap finished (written by the bootloader).
    Step = 2,
    /// The activation swap finished; the new image runs on trial until it confirms itself.
    Trial = 3,
    /// The image on trial confirmed itself (written by the application).
    Confirmed = 4,
    /// The unconfirmed image was swapped back out; the previous image runs again.
    Reverted = 5,
    /// The pending image failed verification at boot and was not activated.
    Rejected = 6,
    /// The application withdrew a pending image (a new download started).
    Cancelled = 7,
    /// The minimum accepted security version is (at least) the record's value; leaves the state as it is
    /// (module documentation).
    Floor = 8,
}

/// Direction of a swap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Slot B (new) to slot A; the old image goes to slot B.
    Activate = 1,
    /// Back: the image on trial goes to slot B, the previous one to slot A.
    Revert = 2,
}

/// Progress of one sector of a swap (A = slot A sector i, B = slot B sector i, S = scratch sector).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Phase {
    /// A was copied to S.
    Saved = 1,
    /// B was copied to A.
    Installed = 2,
    /// S was copied to B: the sector is swapped.
    Done = 3,
}

/// One record of the log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Record {
    /// What happened.
    pub kind: RecordKind,
    /// Direction of a swap step (`Activate` for other records).
    pub direction: Direction,
    /// Sector of a swap step (0 for other records).
    pub sector: u8,
    /// Phase of a swap step (`Done` for other records).
    pub phase: Phase,
    /// Payload CRC of the image concerned; in a [`RecordKind::Floor`] record the minimum security version.
    pub image_crc: u32,
}

impl Record {
    /// A record of `kind` about the image with payload CRC `image_crc`.
    pub const fn new(kind: RecordKind, image_crc: u32) -> Self {
        Self { kind, direction: Direction::Activate, sector: 0, phase: Phase::Done, image_crc }
    }

    /// A record raising the minimum accepted security version to `security_version`.
    pub const fn floor(security_version: u32) -> Self {
        Self::new(RecordKind::Floor, security_version)
    }

    /// A swap step record.
    pub const fn step(direction: Direction, sector: u8, phase: Phase, image_crc: u32) -> Self {
        Self { kind: RecordKind::Step, direction, sector, phase, image_crc }
    }

    /// The record's bytes.
    pub fn to_bytes(&self) -> [u8; RECORD_LEN as usize] {
        let mut b = [0u8; RECORD_LEN as usize];
        let head = [self.kind as u8, self.direction as u8, self.sector, self.phase as u8];
        let crc_in = concat12(head, self.image_crc.to_le_bytes(), RECORD_MAGIC.to_le_bytes());
        let crc = crc32::checksum(&crc_in);
        for (dst, src) in b.iter_mut().zip(crc_in.iter().chain(crc.to_le_bytes().iter())) {
            *dst = *src;
        }
        b
    }

    /// Parses a slot; `None` if it is not a valid record (erased, torn, garbage).
    pub fn parse(b: &[u8]) -> Option<Self> {
        let b: &[u8; RECORD_LEN as usize] = b.first_chunk()?;
        let (body, crc) = b.split_first_chunk::<12>()?;
        if crc32::checksum(body) != u32::from_le_bytes(*crc.first_chunk::<4>()?) {
            return None;
        }
        let [k, d, s, p, c0, c1, c2, c3, m0, m1, m2, m3] = *body;
        if u32::from_le_bytes([m0, m1, m2, m3]) != RECORD_MAGIC {
            return None;
        }
        let kind = match k {
            1 => RecordKind::Pending,
            2 => RecordKind::Step,
            3 => RecordKind::Trial,
            4 => RecordKind::Confirmed,
            5 => RecordKind::Reverted,
            6 => RecordKind::Rejected,
            7 => RecordKind::Cancelled,
            8 => RecordKind::Floor,
            _ => return None,
        };
        let direction = match d {
            1 => Direction::Activate,
            2 => Direction::Revert,
            _ => return None,
        };
        let phase = match p {
            1 => Phase::Saved,
            2 => Phase::Installed,
            3 => Phase::Done,
            _ => return None,
        };
        Some(Self { kind, direction, sector: s, phase, image_crc: u32::from_le_bytes([c0, c1, c2, c3]) })
    }
}

fn concat12(a: [u8; 4], b: [u8; 4], c: [u8; 4]) -> [u8; 12] {
    let [a0, a1, a2, a3] = a;
    let [b0, b1, b2, b3] = b;
    let [c0, c1, c2, c3] = c;
    [a0, a1, a2, a3, b0, b1, b2, b3, c0, c1, c2, c3]
}

/// The update state the log is in (from its newest valid record).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BootState {
    /// Slot A holds the confirmed image; nothing pending. Also the meaning of an empty log.
    Idle,
    /// Slot B holds a verified image to activate at the next reset.
    Pending {
        /// Its payload CRC.
        image_crc: u32,
    },
    /// A swap is in progress: the last finished step.
    Swapping {
        /// Activation or revert.
        direction: Direction,
        /// Sector of the last finished step.
        sector: u8,
        /// Phase of the last finished step.
        phase: Phase,
        /// Payload CRC of the image being activated (or reverted).
        image_crc: u32,
    },
    /// The new image in slot A runs unconfirmed; slot B holds the previous one.
    Trial {
        /// Payload CRC of the image on trial.
        image_crc: u32,
    },
}

impl BootState {
    fn from_record(r: Option<Record>) -> Self {
        match r {
            None => Self::Idle,
            Some(r) => match r.kind {
                RecordKind::Pending => Self::Pending { image_crc: r.image_crc },
                RecordKind::Step => {
                    Self::Swapping { direction: r.direction, sector: r.sector, phase: r.phase, image_crc: r.image_crc }
                }
                RecordKind::Trial => Self::Trial { image_crc: r.image_crc },
                // A Floor record never becomes `last` (`scan`); as one it would mean nothing pending.
                RecordKind::Confirmed
                | RecordKind::Reverted
                | RecordKind::Rejected
                | RecordKind::Cancelled
                | RecordKind::Floor => Self::Idle,
            },
        }
    }
}

/// The result of scanning the log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Scan {
    /// The state in force.
    pub state: BootState,
    /// The newest valid record that is not a [`RecordKind::Floor`], if any.
    pub last: Option<Record>,
    /// The highest minimum security version of the Floor records (0 without one).
    pub floor: u32,
    /// Index of the first slot after the highest non-erased one (where the next record goes).
    pub next_free: u32,
    /// Number of record slots in the region.
    pub capacity: u32,
}

impl Scan {
    /// Free record slots.
    pub const fn free(&self) -> u32 {
        self.capacity.saturating_sub(self.next_free)
    }
}

/// The minimum accepted security version in force (module documentation): the log's Floor, and in the idle and
/// pending states also the security version of the confirmed image in slot A (`slot_a_version`, `None` when
/// slot A holds no valid image).
pub fn minimum_security_version(scan: &Scan, slot_a_version: Option<u32>) -> u32 {
    match scan.state {
        BootState::Idle | BootState::Pending { .. } => scan.floor.max(slot_a_version.unwrap_or(0)),
        BootState::Swapping { .. } | BootState::Trial { .. } => scan.floor,
    }
}

/// Errors of the state log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StateError {
    /// The flash failed.
    Flash(FlashError),
    /// No free slot and the state is not idle, so the log may not be erased.
    Full,
}

impl From<FlashError> for StateError {
    fn from(e: FlashError) -> Self {
        Self::Flash(e)
    }
}

/// Reads the whole log.
pub fn scan<S: NorFlash>(flash: &mut S) -> Result<Scan, FlashError> {
    let capacity = flash.geometry().capacity() / RECORD_LEN;
    let mut last = None;
    let mut floor = 0u32;
    let mut next_free = 0u32;
    let mut buf = [0u8; SCAN_BATCH * RECORD_LEN as usize];
    let mut index = 0u32;
    while index < capacity {
        let n = (capacity.saturating_sub(index)).min(SCAN_BATCH as u32);
        let bytes = buf.get_mut(..(n.saturating_mul(RECORD_LEN)) as usize).ok_or(FlashError::OutOfBounds)?;
        flash.read(index.saturating_mul(RECORD_LEN), bytes)?;
        for (i, slot) in bytes.chunks_exact(RECORD_LEN as usize).enumerate() {
            let at = index.saturating_add(i as u32);
            if slot.iter().any(|b| *b != 0xFF) {
                next_free = at.saturating_add(1);
                match Record::parse(slot) {
                    Some(Record { kind: RecordKind::Floor, image_crc: version, .. }) => floor = floor.max(version),
                    Some(r) => last = Some(r),
                    None => {}
                }
            }
        }
        index = index.saturating_add(n);
    }
    Ok(Scan { state: BootState::from_record(last), last, floor, next_free, capacity })
}

/// Appends `record` to the log.
pub fn append<S: NorFlash>(flash: &mut S, record: Record) -> Result<(), StateError> {
    let s = scan(flash)?;
    if s.free() == 0 {
        return Err(StateError::Full);
    }
    flash.program(s.next_free.saturating_mul(RECORD_LEN), &record.to_bytes())?;
    Ok(())
}

/// Makes sure [`RESERVE`] slots are free, erasing the log if needed, which is allowed only in the idle state
/// (see the module docs). Returns the scan after it. The erase takes the Floor records with it: the caller
/// writes the minimum again ([`super::update::Download::activate`]; why a cut in between loses nothing: module
/// documentation).
pub fn ensure_room<S: NorFlash>(flash: &mut S) -> Result<Scan, StateError> {
    let s = scan(flash)?;
    if s.free() >= RESERVE {
        return Ok(s);
    }
    if s.state != BootState::Idle {
        return Err(StateError::Full);
    }
    for sector in 0..flash.geometry().sector_count {
        flash.erase_sector(sector)?;
    }
    Ok(scan(flash)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_a_flipped_bit_invalidates() {
        let r = Record::step(Direction::Revert, 2, Phase::Installed, 0xABCD_0123);
        let b = r.to_bytes();
        assert_eq!(Record::parse(&b), Some(r));
        for i in 0..b.len() * 8 {
            let mut x = b;
            x[i / 8] ^= 1 << (i % 8);
            assert_eq!(Record::parse(&x), None, "bit {i}");
        }
        assert_eq!(Record::parse(&[0xFF; 16]), None);
        assert_eq!(Record::parse(&b[..15]), None);
    }
}
