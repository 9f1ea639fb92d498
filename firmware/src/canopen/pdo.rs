//! The four RPDOs and four TPDOs (CiA 301 §7.2.2, objects 0x1400..0x1403 / 0x1600..0x1603 and 0x1800..0x1803 /
//! 0x1A00..0x1A03).
//!
//! **Configuration.** Each PDO's communication parameters are read from the dictionary when the node starts and
//! after every SDO write to them or to the mapping ([`Pdos::configure`]): COB-ID (bit 31 = PDO not valid, bit 30
//! = no RTR allowed, bit 29 = 29-bit identifier, which this node refuses), transmission type, inhibit time (100 us
//! units), event timer (ms) and the SYNC start value (0x18xx:06, used when 0x1019 > 0). The mapping is compiled
//! into copy steps ([`crate::comm::pdo::PdoItem`], the same steps the EtherCAT process data uses) only while the
//! PDO is valid, so the CiA 301 §7.5.2.36 remap procedure (PDO invalid, mapping count 0, entries, count, PDO
//! valid) compiles it once, when the PDO is made valid. The write rules of that procedure are checked by
//! [`super::guard`] before the dictionary stores anything.
//!
//! **Transmission types** (CiA 301 §7.5.2.35/37; E4 §5.5.1 L3233-L3257):
//! - RPDO 0..=240: the data received is applied at the next SYNC ([`Pdos::on_sync`]); 254/255: applied at once.
//! - TPDO 0: synchronous acyclic, sampled at every SYNC and sent when the data changed; 1..=240: sampled and sent
//!   at every n-th SYNC, starting at the SYNC whose counter equals the start value when 0x1019 > 0; 253: only on
//!   a remote request; 254/255: event-driven, sent when the mapped data changes ([`Pdos::poll_events`]), no
//!   sooner than the inhibit time after the previous one, and at the latest after the event timer.
//!
//! **Length errors.** An RPDO shorter than its mapping is not processed and reported as
//! [`LinkLoss::PdoLength`] (EMCY 0x8210 "PDO not processed due to length error", CiA 301 §7.2.2.2; IDX L7375),
//! once per error until a PDO of the right length arrives; a longer one is processed with its first bytes, as
//! CiA 301 §7.2.2.2 allows.
//!
//! **Per SYNC** ([`Pdos::on_sync`]) nothing is searched: four compiled TPDOs are packed and four RPDO buffers
//! unpacked, one copy step per mapped object.

use heapless::Vec;

use super::frame::CanFrame;
use crate::comm::device::FieldbusDevice;
use crate::comm::pdo::{compile_item, PdoItem};
use crate::od::abort::SdoAbort;
use crate::od::access::Dictionary;
use crate::od::entry::{DataType, Storage};
use crate::od::generated::MAX_PDO_BYTES_CANOPEN;
use crate::od::pdo_map::{self, Direction, MapTarget};
use crate::supervision::communication::LinkLoss;

use super::ids;

/// PDOs per direction.
pub const PDO_COUNT: usize = 4;

/// Copy steps one PDO may hold: 12 mapped entries at most (device.toml 0x16xx/0x1Axx sub 0 max 12).
pub const MAX_ENTRIES: usize = 12;

/// COB-ID bit 31: the PDO does not exist (is not valid).
pub const COB_INVALID: u32 = 1 << 31;
/// COB-ID bit 30 of a TPDO: no RTR allowed.
pub const COB_NO_RTR: u32 = 1 << 30;
/// COB-ID bit 29: 29-bit identifier (CAN 2.0B), not supported.
pub const COB_EXTENDED: u32 = 1 << 29;

/// First RPDO communication parameter object.
pub const RPDO_COMM: u16 = 0x1400;
/// First TPDO communication parameter object.
pub const TPDO_COMM: u16 = 0x1800;

/// A PDO's transmission type (CiA 301 §7.5.2.35 and §7.5.2.37).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Transmission {
    /// RPDO 0..=240: apply at the next SYNC; TPDO 0: send at a SYNC when the data changed.
    SyncAcyclic,
    /// TPDO 1..=240: send at every n-th SYNC.
    SyncCyclic(u8),
    /// TPDO 253: send only on a remote request.
    RtrOnly,
    /// 254/255: event-driven (RPDO: apply at once).
    #[default]
    Event,
}

impl Transmission {
    /// The type of `code` for a PDO of `direction`; `None` for a reserved code (RPDO 241..=253, TPDO
    /// 241..=252: 252 "synchronous RTR" is not supported), which a write is refused with 0x0609_0030.
    pub const fn from_code(code: u8, direction: Direction) -> Option<Self> {
        match (direction, code) {
            (Direction::Rx, 0..=240) => Some(Self::SyncAcyclic),
            (Direction::Tx, 0) => Some(Self::SyncAcyclic),
            (Direction::Tx, 1..=240) => Some(Self::SyncCyclic(code)),
            (Direction::Tx, 253) => Some(Self::RtrOnly),
            (_, 254 | 255) => Some(Self::Event),
            _ => None,
        }
    }

    /// Whether the PDO follows the SYNC.
    pub const fn is_synchronous(self) -> bool {
        matches!(self, Self::SyncAcyclic | Self::SyncCyclic(_))
    }
}

/// A compiled mapping: the copy steps and the PDO length.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
struct Compiled {
    items: Vec<PdoItem, MAX_ENTRIES>,
    len: u8,
    /// When every mapped object is copied as whole bytes (the usual mapping; padding needs no copy): the same
    /// copies as `items` in a form that runs inline, without the general step's dispatch. Four TPDOs and an RPDO
    /// per SYNC are copied with it (`insn.can_sync`, issue 8: at most 1,500 instructions).
    bytes: Option<Vec<ByteCopy, MAX_ENTRIES>>,
}

impl Compiled {
    /// The PDO's data from the value storage: bytes past the length are 0.
    #[inline]
    fn pack(&self, values: &[u8]) -> [u8; 8] {
        let mut data = [0u8; 8];
        match &self.bytes {
            Some(copies) => {
                for c in copies {
                    c.pack(values, &mut data);
                }
            }
            None => {
                for item in &self.items {
                    item.pack(values, &mut data);
                }
            }
        }
        data
    }

    /// Copies a received PDO's data (at least `len` bytes) into the value storage.
    #[inline]
    fn unpack(&self, data: &[u8], values: &mut [u8]) {
        match &self.bytes {
            Some(copies) => {
                for c in copies {
                    c.unpack(data, values);
                }
            }
            None => {
                for item in &self.items {
                    item.unpack(data, values);
                }
            }
        }
    }
}

/// One mapped object copied as whole bytes between the PDO data and the value storage: what
/// [`PdoItem::pack`]/[`PdoItem::unpack`] do for a byte-aligned object of 1, 2, 4 or 8 bytes in RAM that is not a
/// BOOLEAN (`comm::pdo::compile_item`), resolved to its two offsets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct ByteCopy {
    /// First byte in the PDO data.
    image: u8,
    /// First byte in the value storage.
    value: u16,
    /// Bytes: 1, 2, 4 or 8.
    len: u8,
}

impl ByteCopy {
    /// The copy of one compiled entry, if it is a whole-byte object copy; `Some(None)` for padding (nothing to
    /// copy: received padding is ignored, sent padding is 0 in the zeroed data); `None` for anything else.
    fn of(target: MapTarget, bit_offset: u32, bits: u8) -> Option<Option<Self>> {
        let MapTarget::Object(entry) = target else {
            return Some(None);
        };
        let Storage::Ram { offset, len, .. } = entry.storage else {
            return None;
        };
        let aligned = bit_offset & 7 == 0 && bits & 7 == 0;
        let whole = u16::from(bits.wrapping_shr(3)) == len && matches!(len, 1 | 2 | 4 | 8);
        if !aligned || !whole || entry.data_type == DataType::Boolean {
            return None;
        }
        let image = u8::try_from(bit_offset.wrapping_shr(3)).ok()?;
        Some(Some(Self { image, value: offset, len: u8::try_from(len).ok()? }))
    }

    #[inline(always)]
    fn pack(self, values: &[u8], data: &mut [u8; 8]) {
        let (v, i) = (usize::from(self.value), usize::from(self.image));
        match self.len {
            1 => copy::<1>(data, i, values, v),
            2 => copy::<2>(data, i, values, v),
            4 => copy::<4>(data, i, values, v),
            _ => copy::<8>(data, i, values, v),
        }
    }

    #[inline(always)]
    fn unpack(self, data: &[u8], values: &mut [u8]) {
        let (v, i) = (usize::from(self.value), usize::from(self.image));
        match self.len {
            1 => copy::<1>(values, v, data, i),
            2 => copy::<2>(values, v, data, i),
            4 => copy::<4>(values, v, data, i),
            _ => copy::<8>(values, v, data, i),
        }
    }
}

/// Copies `K` bytes from `src[s..]` to `dst[d..]` when both ranges exist (they do for a compiled copy).
#[inline(always)]
fn copy<const K: usize>(dst: &mut [u8], d: usize, src: &[u8], s: usize) {
    let to = dst.get_mut(d..d.saturating_add(K)).and_then(|t| <&mut [u8; K]>::try_from(t).ok());
    let from = src.get(s..s.saturating_add(K)).and_then(|f| <&[u8; K]>::try_from(f).ok());
    if let (Some(to), Some(from)) = (to, from) {
        *to = *from;
    }
}

/// Compiles mapping object `index` for a CAN PDO: validated as a whole ([`pdo_map::mapping`]), at most 8 bytes
/// (0x0604_0042; IDX L2196), every entry turned into a copy step.
fn compile<const N: usize>(d: &Dictionary<N>, index: u16, direction: Direction) -> Result<Compiled, SdoAbort> {
    let mapping = pdo_map::mapping(d.table(), d.values().bytes(), index)?;
    let len = usize::try_from(mapping.total_bytes()).map_err(|_| SdoAbort::PdoLengthExceeded)?;
    if len > MAX_PDO_BYTES_CANOPEN {
        return Err(SdoAbort::PdoLengthExceeded);
    }
    let mut compiled = Compiled { items: Vec::new(), len: u8::try_from(len).unwrap_or(0), bytes: Some(Vec::new()) };
    for mapped in mapping {
        let item = compile_item::<N>(index, mapped.target, mapped.bit_offset, mapped.bits, direction)?;
        compiled.items.push(item).map_err(|_| SdoAbort::PdoLengthExceeded)?;
        compiled.bytes = match (compiled.bytes.take(), ByteCopy::of(mapped.target, mapped.bit_offset, mapped.bits)) {
            (Some(mut copies), Some(copy)) => {
                if let Some(c) = copy {
                    copies.push(c).map_err(|_| SdoAbort::PdoLengthExceeded)?;
                }
                Some(copies)
            }
            _ => None,
        };
    }
    Ok(compiled)
}

/// `data` (at most 8 bytes, a CAN frame's) in an 8-byte buffer, zero-padded: one copy for a full frame, the
/// common case on the SYNC path; only the first `len` bytes of the mapping are ever read from it.
#[inline(always)]
fn padded(data: &[u8]) -> [u8; 8] {
    if let Ok(full) = <[u8; 8]>::try_from(data) {
        return full;
    }
    let mut buffer = [0u8; 8];
    for (b, d) in buffer.iter_mut().zip(data) {
        *b = *d;
    }
    buffer
}

/// One RPDO.
#[derive(Clone, Debug, Default)]
struct Rpdo {
    valid: bool,
    cob_id: u16,
    transmission: Transmission,
    compiled: Compiled,
    /// Data of a synchronous RPDO waiting for the next SYNC.
    buffer: [u8; 8],
    pending: bool,
    /// Deadline monitoring (0x14xx:05, ms -> us; 0 = off).
    event_timer_us: u64,
    last_us: Option<u64>,
    timed_out: bool,
    /// A length error has been reported and not yet cleared by a PDO of the right length.
    length_error: bool,
}

/// One TPDO.
#[derive(Clone, Debug, Default)]
struct Tpdo {
    valid: bool,
    cob_id: u16,
    rtr_allowed: bool,
    transmission: Transmission,
    inhibit_us: u64,
    event_timer_us: u64,
    sync_start: u8,
    compiled: Compiled,
    last_sent_us: Option<u64>,
    last_data: [u8; 8],
    sync_count: u8,
    started: bool,
}

impl Tpdo {
    /// The PDO's data now.
    #[inline]
    fn sample(&self, values: &[u8]) -> [u8; 8] {
        self.compiled.pack(values)
    }

    /// The frame of `data`, remembered as the last sent. Built from the raw fields (no byte loop: this runs four
    /// times per SYNC, `insn.can_sync`): the COB-ID is 11 bits and the length at most 8 by [`Pdos::configure`]
    /// and [`compile`], and `sample` leaves the bytes past the length 0, so the frame equals what
    /// [`CanFrame::new`] would build.
    #[inline]
    fn frame(&mut self, data: [u8; 8], now_us: u64) -> Option<CanFrame> {
        self.last_data = data;
        self.last_sent_us = Some(now_us);
        Some(CanFrame::from_raw(self.cob_id, self.compiled.len, data, false))
    }
}

/// What happened to a received RPDO.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RpdoOutcome {
    /// Applied to the dictionary now (event-driven).
    Applied,
    /// Kept for the next SYNC (synchronous).
    Buffered,
    /// Shorter than its mapping: not processed (the length received).
    LengthError(u8),
}

/// Where a TPDO's frame is put: the node's transmit queue.
pub trait FrameSink {
    /// Queues a frame; `false` when the queue is full (the frame is lost and counted by the node).
    fn push(&mut self, frame: CanFrame) -> bool;
    /// Frames the queue can take now.
    fn room(&self) -> usize;
}

/// The node's RPDOs and TPDOs.
#[derive(Clone, Debug, Default)]
pub struct Pdos {
    rpdo: [Rpdo; PDO_COUNT],
    tpdo: [Tpdo; PDO_COUNT],
    /// The SYNC counter overflow value 0x1019 (0 = SYNC without counter).
    counter_overflow: u8,
}

/// The index of the communication parameter object of PDO `n` in `direction`.
pub const fn comm_index(direction: Direction, n: usize) -> u16 {
    let base = match direction {
        Direction::Rx => RPDO_COMM,
        Direction::Tx => TPDO_COMM,
    };
    base.wrapping_add(n as u16)
}

/// The index of the mapping object of PDO `n` in `direction`.
pub const fn mapping_index(direction: Direction, n: usize) -> u16 {
    let base = match direction {
        Direction::Rx => pdo_map::RX_MAPPING_FIRST,
        Direction::Tx => pdo_map::TX_MAPPING_FIRST,
    };
    base.wrapping_add(n as u16)
}

/// The PDO number (0-based) and direction of a communication (0x1400.., 0x1800..) or mapping (0x1600..,
/// 0x1A00..) object of the four PDOs.
pub const fn pdo_of(index: u16) -> Option<(Direction, usize, bool)> {
    match index {
        0x1400..=0x1403 => Some((Direction::Rx, (index & 3) as usize, false)),
        0x1600..=0x1603 => Some((Direction::Rx, (index & 3) as usize, true)),
        0x1800..=0x1803 => Some((Direction::Tx, (index & 3) as usize, false)),
        0x1A00..=0x1A03 => Some((Direction::Tx, (index & 3) as usize, true)),
        _ => None,
    }
}

/// Whether PDO `n` of `direction` is valid (COB-ID bit 31 clear) in the dictionary.
pub fn is_valid<const N: usize>(d: &Dictionary<N>, direction: Direction, n: usize) -> bool {
    ids::read_u32(d, comm_index(direction, n), 1) & COB_INVALID == 0
}

impl Pdos {
    /// Reads every PDO's configuration (tier 3).
    pub fn configure<const N: usize>(&mut self, d: &Dictionary<N>) {
        self.counter_overflow = ids::read(d, 0x1019, 0).and_then(|v| u8::try_from(v).ok()).unwrap_or(0);
        for n in 0..PDO_COUNT {
            self.configure_rpdo(d, n);
            self.configure_tpdo(d, n);
        }
    }

    /// Reads RPDO `n`'s configuration; an invalid PDO or a mapping that does not compile (one written through
    /// another bus with EtherCAT's 40-byte limit) leaves it not valid.
    fn configure_rpdo<const N: usize>(&mut self, d: &Dictionary<N>, n: usize) {
        let comm = comm_index(Direction::Rx, n);
        let cob = ids::read_u32(d, comm, 1);
        let transmission = ids::read(d, comm, 2)
            .and_then(|v| u8::try_from(v).ok())
            .and_then(|c| Transmission::from_code(c, Direction::Rx))
            .unwrap_or_default();
        let event_timer_us = ids::read(d, comm, 5).unwrap_or(0).saturating_mul(1000);
        let compiled = if cob & (COB_INVALID | COB_EXTENDED) == 0 {
            compile(d, mapping_index(Direction::Rx, n), Direction::Rx).ok()
        } else {
            None
        };
        if let Some(pdo) = self.rpdo.get_mut(n) {
            *pdo = Rpdo {
                valid: compiled.is_some(),
                cob_id: u16::try_from(cob & 0x7FF).unwrap_or(0),
                transmission,
                compiled: compiled.unwrap_or_default(),
                event_timer_us,
                ..Rpdo::default()
            };
        }
    }

    /// Reads TPDO `n`'s configuration (see [`Pdos::configure_rpdo`]).
    fn configure_tpdo<const N: usize>(&mut self, d: &Dictionary<N>, n: usize) {
        let comm = comm_index(Direction::Tx, n);
        let cob = ids::read_u32(d, comm, 1);
        let transmission = ids::read(d, comm, 2)
            .and_then(|v| u8::try_from(v).ok())
            .and_then(|c| Transmission::from_code(c, Direction::Tx))
            .unwrap_or_default();
        let compiled = if cob & (COB_INVALID | COB_EXTENDED) == 0 {
            compile(d, mapping_index(Direction::Tx, n), Direction::Tx).ok()
        } else {
            None
        };
        if let Some(pdo) = self.tpdo.get_mut(n) {
            *pdo = Tpdo {
                valid: compiled.is_some(),
                cob_id: u16::try_from(cob & 0x7FF).unwrap_or(0),
                rtr_allowed: cob & COB_NO_RTR == 0,
                transmission,
                inhibit_us: ids::read(d, comm, 3).unwrap_or(0).saturating_mul(100),
                event_timer_us: ids::read(d, comm, 5).unwrap_or(0).saturating_mul(1000),
                sync_start: ids::read(d, comm, 6).and_then(|v| u8::try_from(v).ok()).unwrap_or(0),
                compiled: compiled.unwrap_or_default(),
                ..Tpdo::default()
            };
        }
    }

    /// Forgets received data and transmission history (leaving operational: the PDOs stop; entering it again
    /// starts the event-driven TPDOs with a first transmission and the cyclic ones afresh).
    pub fn stop(&mut self) {
        for r in &mut self.rpdo {
            r.pending = false;
            r.last_us = None;
        }
        for t in &mut self.tpdo {
            t.last_sent_us = None;
            t.sync_count = 0;
            t.started = false;
        }
    }

    /// The RPDO (0-based) a data frame on `cob_id` belongs to: four comparisons.
    pub fn rpdo_for(&self, cob_id: u16) -> Option<usize> {
        self.rpdo.iter().position(|r| r.valid && r.cob_id == cob_id)
    }

    /// The TPDO (0-based) a remote frame on `cob_id` asks for.
    pub fn tpdo_for(&self, cob_id: u16) -> Option<usize> {
        self.tpdo.iter().position(|t| t.valid && t.cob_id == cob_id)
    }

    /// RPDO `n` received `data` at `now_us` (operational only; the node checks). An event-driven RPDO is written
    /// into the dictionary and handed to the drive at once ([`FieldbusDevice::setpoint_received`]); a synchronous
    /// one waits for the next SYNC. A deadline loss or a length error reported earlier is restored by a good PDO.
    pub fn receive<D: FieldbusDevice + ?Sized>(
        &mut self,
        n: usize,
        data: &[u8],
        drive: &mut D,
        now_us: u64,
    ) -> Option<RpdoOutcome> {
        let pdo = self.rpdo.get_mut(n)?;
        let need = usize::from(pdo.compiled.len);
        if data.len() < need {
            let received = u8::try_from(data.len()).unwrap_or(u8::MAX);
            if !pdo.length_error {
                pdo.length_error = true;
                drive.communication_lost(LinkLoss::PdoLength { received: u16::from(received) });
            }
            return Some(RpdoOutcome::LengthError(received));
        }
        if core::mem::take(&mut pdo.length_error) {
            drive.communication_restored(LinkLoss::PdoLength { received: 0 });
        }
        pdo.last_us = Some(now_us);
        if core::mem::take(&mut pdo.timed_out) {
            drive.communication_restored(LinkLoss::RxPdoTimeout);
        }
        if pdo.transmission.is_synchronous() {
            pdo.buffer = padded(data);
            pdo.pending = true;
            return Some(RpdoOutcome::Buffered);
        }
        pdo.compiled.unpack(data, drive.dictionary_mut().values_mut().bytes_mut());
        drive.setpoint_received();
        Some(RpdoOutcome::Applied)
    }

    /// A SYNC (with its counter when 0x1019 > 0) in operational: first the synchronous TPDOs are sampled and
    /// queued (actual values as at the SYNC), then the synchronous RPDOs received since the previous SYNC are
    /// applied and handed to the drive once ([`FieldbusDevice::setpoint_received`]). Returns whether set-points were
    /// applied.
    #[inline]
    pub fn on_sync<D: FieldbusDevice + ?Sized, S: FrameSink + ?Sized>(
        &mut self,
        counter: Option<u8>,
        drive: &mut D,
        now_us: u64,
        sink: &mut S,
    ) -> bool {
        let use_start = self.counter_overflow > 0;
        {
            let values: &[u8] = drive.dictionary().values().bytes();
            for t in &mut self.tpdo {
                if !t.valid {
                    continue;
                }
                let send = match t.transmission {
                    Transmission::SyncAcyclic => true,
                    Transmission::SyncCyclic(every) => {
                        if !t.started {
                            let at_start = !use_start || t.sync_start == 0 || counter == Some(t.sync_start);
                            t.started = at_start;
                            t.sync_count = 0;
                            at_start
                        } else {
                            t.sync_count = t.sync_count.wrapping_add(1);
                            if t.sync_count >= every {
                                t.sync_count = 0;
                                true
                            } else {
                                false
                            }
                        }
                    }
                    Transmission::RtrOnly | Transmission::Event => false,
                };
                if !send {
                    continue;
                }
                let data = t.sample(values);
                // Type 0 is acyclic: sent only when the data changed since the last transmission.
                if t.transmission == Transmission::SyncAcyclic && t.last_sent_us.is_some() && data == t.last_data {
                    continue;
                }
                if let Some(frame) = t.frame(data, now_us) {
                    let _ = sink.push(frame);
                }
            }
        }
        let mut applied = false;
        let values: &mut [u8] = drive.dictionary_mut().values_mut().bytes_mut();
        for r in &mut self.rpdo {
            if r.valid && core::mem::take(&mut r.pending) {
                r.compiled.unpack(&r.buffer, values);
                applied = true;
            }
        }
        if applied {
            drive.setpoint_received();
        }
        applied
    }

    /// Tier 3 in operational: the event-driven TPDOs (change of the mapped data, inhibit time, event timer) and
    /// the RPDO deadlines (event timer 0x14xx:05, armed by the first PDO: [`LinkLoss::RxPdoTimeout`] once).
    pub fn poll_events<D: FieldbusDevice + ?Sized, S: FrameSink + ?Sized>(
        &mut self,
        drive: &mut D,
        now_us: u64,
        sink: &mut S,
    ) {
        let values: &[u8] = drive.dictionary().values().bytes();
        for t in &mut self.tpdo {
            if !t.valid || t.transmission != Transmission::Event {
                continue;
            }
            let data = t.sample(values);
            let (changed, timer_due, inhibit_over) = match t.last_sent_us {
                None => (true, false, true),
                Some(last) => {
                    let since = now_us.saturating_sub(last);
                    (data != t.last_data, t.event_timer_us > 0 && since >= t.event_timer_us, since >= t.inhibit_us)
                }
            };
            if (changed || timer_due) && inhibit_over {
                if let Some(frame) = t.frame(data, now_us) {
                    let _ = sink.push(frame);
                }
            }
        }
        let mut lost = false;
        for r in &mut self.rpdo {
            if let (true, Some(last)) = (r.valid && r.event_timer_us > 0 && !r.timed_out, r.last_us) {
                if now_us.saturating_sub(last) > r.event_timer_us {
                    r.timed_out = true;
                    lost = true;
                }
            }
        }
        if lost {
            drive.communication_lost(LinkLoss::RxPdoTimeout);
        }
    }

    /// A remote frame for TPDO `n`: its data now, if the PDO allows RTR (COB-ID bit 30 clear).
    pub fn remote_request<D: FieldbusDevice + ?Sized>(&mut self, n: usize, drive: &D, now_us: u64) -> Option<CanFrame> {
        let t = self.tpdo.get_mut(n)?;
        if !t.valid || !t.rtr_allowed {
            return None;
        }
        let data = t.sample(drive.dictionary().values().bytes());
        t.frame(data, now_us)
    }

    /// The length of RPDO `n`'s mapping in bytes, if it is valid.
    pub fn rpdo_len(&self, n: usize) -> Option<u8> {
        self.rpdo.get(n).filter(|r| r.valid).map(|r| r.compiled.len)
    }

    /// The COB-ID of TPDO `n`, if it is valid.
    pub fn tpdo_cob_id(&self, n: usize) -> Option<u16> {
        self.tpdo.get(n).filter(|t| t.valid).map(|t| t.cob_id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transmission_codes_follow_cia_301() {
        assert_eq!(Transmission::from_code(0, Direction::Rx), Some(Transmission::SyncAcyclic));
        assert_eq!(Transmission::from_code(240, Direction::Rx), Some(Transmission::SyncAcyclic));
        assert_eq!(Transmission::from_code(241, Direction::Rx), None);
        assert_eq!(Transmission::from_code(253, Direction::Rx), None);
        assert_eq!(Transmission::from_code(255, Direction::Rx), Some(Transmission::Event));
        assert_eq!(Transmission::from_code(1, Direction::Tx), Some(Transmission::SyncCyclic(1)));
        assert_eq!(Transmission::from_code(252, Direction::Tx), None);
        assert_eq!(Transmission::from_code(253, Direction::Tx), Some(Transmission::RtrOnly));
        assert_eq!(Transmission::from_code(254, Direction::Tx), Some(Transmission::Event));
    }

    /// Proves the whole-byte copies ([`ByteCopy`]) do what the general copy steps do: every default mapping
    /// (RPDO and TPDO 1..4) takes the fast form, and packing from and unpacking into a value storage of
    /// pseudo-random bytes gives the same bytes both ways; padding (a dummy entry) keeps the fast form.
    #[test]
    fn whole_byte_copies_equal_the_general_copy_steps() {
        let d = Dictionary::new(1);
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut values = d.values().bytes().to_vec();
        for v in values.iter_mut() {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            *v = seed as u8;
        }
        for direction in [Direction::Rx, Direction::Tx] {
            for n in 0..PDO_COUNT {
                let c = compile(&d, mapping_index(direction, n), direction).expect("default mapping compiles");
                assert!(c.bytes.is_some(), "{direction:?} {n}: whole bytes");
                let mut general = [0u8; 8];
                for item in &c.items {
                    item.pack(&values, &mut general);
                }
                assert_eq!(c.pack(&values), general, "{direction:?} {n}: pack");
                let image = [0xA5, 0x5A, 0x01, 0x80, 0xFF, 0x00, 0x7E, 0x42];
                let (mut fast, mut slow) = (values.clone(), values.clone());
                c.unpack(&image, &mut fast);
                for item in &c.items {
                    item.unpack(&image, &mut slow);
                }
                assert_eq!(fast, slow, "{direction:?} {n}: unpack");
            }
        }
        let padding = ByteCopy::of(MapTarget::Padding, 8, 16);
        assert_eq!(padding, Some(None));
    }

    #[test]
    fn default_mappings_compile_within_eight_bytes() {
        let d = Dictionary::new(1);
        let mut pdos = Pdos::default();
        pdos.configure(&d);
        assert_eq!(pdos.rpdo_for(0x201), Some(0));
        assert_eq!(pdos.tpdo_cob_id(0), Some(0x181));
        assert_eq!(pdos.tpdo_cob_id(1), None, "TPDO 2 ships not valid");
        assert!(pdos.rpdo_len(0).is_some_and(|l| l <= 8));
        assert_eq!(pdo_of(0x1A02), Some((Direction::Tx, 2, true)));
        assert_eq!(pdo_of(0x1404), None);
    }
}
