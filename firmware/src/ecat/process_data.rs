//! The process data: the PDO mapping 0x1600..0x1603 / 0x1A00..0x1A03 and the assignment 0x1C12/0x1C13 validated as a
//! whole, compiled once into a copy list, and the images packed and unpacked through the dictionary with it.
//!
//! **When it may change.** The assignment and mapping objects accept SDO writes only in PRE-OP (ETG.1000.6 objects
//! 0x1C12/0x1C13; IDX L2196-L2216 "write only in Pre-Operational", L2978-L3055; comms-faults-bootloader.md §1.4, §1.5).
//! The dictionary enforces it: every entry of these objects carries `writable_in = "pre-op"`
//! ([`WriteCondition::PreOperational`](crate::od::entry::WriteCondition)), which the SDO access check
//! ([`AccessContext::allows`](crate::od::access::AccessContext::allows)) turns into abort 0x0800_0022 in any other
//! state; [`writable_in_state`] states the same rule for the EtherCAT state machine. The single mapping and assignment
//! entries are checked as they are written ([`pdo_map::check_write`]); this module checks the whole once more at the
//! PRE-OP to SAFE-OP transition (ETG.1000.6 §6.4, application layer state machine; comms-faults-bootloader.md §1.2
//! "derived ESM rules"), because the image is only defined by all of them together: the assigned PDOs exist and have
//! the right direction, every mapped object exists, is mappable in that direction (RxPDO objects rx-mappable, TxPDO
//! objects tx-mappable) and has the stated length, no PDO is assigned twice, and each image fits the 40-byte EtherCAT
//! limit (IDX L2196).
//!
//! **Compiled layout.** [`ProcessDataLayout::from_dictionary`] resolves every mapped object to its location in the
//! dictionary's value storage (the byte offset a typed [`Handle`](crate::od::entry::Handle) uses, `od/values.rs`) and
//! its bit offset and length in the image, so that [`ProcessDataLayout::unpack_outputs`] and
//! [`ProcessDataLayout::pack_inputs`] copy values without any search or division per cycle: a byte-aligned object is
//! one slice copy (the storage is little-endian, the CiA 301 §7.1.3 transfer syntax, so the stored bytes are the wire
//! bytes); a BOOLEAN (one bit: the mapping entry states the length in bits, CiA 301 §7.4.7.1) or an object placed after
//! a gap of a bit count that is not a multiple of 8 is copied bit by bit. Gaps (index 0, ETG.1000.6) and CiA 301 dummy
//! entries (0x0001..0x0007) take room in the image; the drive ignores them in the outputs and sends them as 0 in the
//! inputs, as it does for the bits after the last TxPDO entry up to the byte boundary.

use heapless::Vec;

use super::esc::{AlStatusCode, SmConfig};
use crate::comm::pdo::compile_item;
pub use crate::comm::pdo::{Location, PdoItem};
use crate::od::abort::SdoAbort;
use crate::od::access::{CommState, Dictionary};
use crate::od::generated::MAX_PDO_BYTES_ETHERCAT;
use crate::od::pdo_map::{self, Direction, MapTarget};

/// PDOs one assignment object may list: 0x1C12/0x1C13 sub 1..4 (device.toml; the mapping objects 0x1600..0x1603
/// and 0x1A00..0x1A03).
pub const MAX_ASSIGNED_PDOS: usize = 4;

/// Copy steps one image may hold: 4 PDOs of at most 12 mapped entries (device.toml 0x16xx/0x1Axx sub 0 max 12)
/// and the trailing pad of the inputs, rounded up.
pub const MAX_ITEMS: usize = 64;

/// First byte of the ESC's process RAM (Beckhoff ESC datasheet section I, "process data RAM" from 0x1000): a
/// process-data sync manager window must lie there.
pub const PROCESS_RAM_START: u16 = 0x1000;

/// Whether the PDO configuration (0x1600..0x1603, 0x1A00..0x1A03, 0x1C12, 0x1C13) may be written in `state`:
/// only in PRE-OP (IDX L2196-L2216, L2978-L3055; comms-faults-bootloader.md §1.4). The dictionary enforces this
/// through the entries' `WriteCondition::PreOperational` (abort 0x0800_0022 otherwise); the EtherCAT state machine
/// relies on it to keep a compiled layout valid in SAFE-OP and OP.
pub const fn writable_in_state(state: CommState) -> bool {
    matches!(state, CommState::PreOperational)
}

/// Whether `index` is one of the objects [`writable_in_state`] governs.
pub const fn is_pdo_configuration(index: u16) -> bool {
    matches!(index, 0x1600..=0x1603 | 0x1A00..=0x1A03 | pdo_map::RX_ASSIGNMENT | pdo_map::TX_ASSIGNMENT)
}

/// Why the PDO configuration cannot be compiled: the direction at fault and the CoE abort code that names the
/// problem (the code an SDO write of the same configuration would have been refused with).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PdoError {
    /// Outputs (RxPDOs, 0x1C12) or inputs (TxPDOs, 0x1C13).
    pub direction: Direction,
    /// The abort code.
    pub abort: SdoAbort,
}

impl PdoError {
    /// The AL status code that refuses PRE-OP to SAFE-OP for this error (ETG.1000.6 Table 11): 0x0025 invalid
    /// output mapping, 0x0024 invalid input mapping.
    pub const fn al_status(&self) -> AlStatusCode {
        match self.direction {
            Direction::Rx => AlStatusCode::InvalidOutputMapping,
            Direction::Tx => AlStatusCode::InvalidInputMapping,
        }
    }
}

/// One direction's compiled image.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
struct Image {
    bytes: u16,
    pdos: Vec<u16, MAX_ASSIGNED_PDOS>,
    items: Vec<PdoItem, MAX_ITEMS>,
}

/// The process-data layout compiled from the dictionary's PDO assignment and mapping.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ProcessDataLayout {
    /// Bytes of the output image (RxPDOs, SM2).
    pub output_bytes: u16,
    /// Bytes of the input image (TxPDOs, SM3).
    pub input_bytes: u16,
    outputs: Image,
    inputs: Image,
}

impl ProcessDataLayout {
    /// Compiles the layout from 0x1C12/0x1C13 and the mappings they assign; the abort code says what is wrong
    /// (see [`ProcessDataLayout::compile`], which also names the direction).
    pub fn from_dictionary<const N: usize>(d: &Dictionary<N>) -> Result<Self, SdoAbort> {
        Self::compile(d).map_err(|e| e.abort)
    }

    /// Compiles the layout, outputs first. The checks and their abort codes:
    /// - 0x1C12/0x1C13 sub 0 above [`MAX_ASSIGNED_PDOS`] or above the entries the object has: 0x0609_0031;
    /// - an assigned entry that is no existing mapping object of the direction, or a PDO assigned twice:
    ///   0x0609_0030;
    /// - a mapping entry: [`pdo_map::resolve`] (0x0602_0000 missing object, 0x0604_0041 not mappable in this
    ///   direction or not mappable at all, 0x0604_0043 wrong length), plus 0x0604_0041 for an RxPDO object
    ///   that is a constant or served by the application (nothing to write it into);
    /// - the image longer than 40 bytes (`MAX_PDO_BYTES_ETHERCAT`, IDX L2196) or more than [`MAX_ITEMS`]
    ///   entries: 0x0604_0042;
    /// - a value slot outside the storage (a table that does not fit its storage): 0x0604_0047.
    pub fn compile<const N: usize>(d: &Dictionary<N>) -> Result<Self, PdoError> {
        let outputs = compile_image(d, Direction::Rx).map_err(|abort| PdoError { direction: Direction::Rx, abort })?;
        let inputs = compile_image(d, Direction::Tx).map_err(|abort| PdoError { direction: Direction::Tx, abort })?;
        Ok(Self { output_bytes: outputs.bytes, input_bytes: inputs.bytes, outputs, inputs })
    }

    /// The RxPDOs assigned to SM2, in image order.
    pub fn output_pdos(&self) -> &[u16] {
        &self.outputs.pdos
    }

    /// The TxPDOs assigned to SM3, in image order.
    pub fn input_pdos(&self) -> &[u16] {
        &self.inputs.pdos
    }

    /// The entries of the output image in image order (gaps and dummy entries included).
    pub fn output_items(&self) -> &[PdoItem] {
        &self.outputs.items
    }

    /// The entries of the input image in image order (gaps, dummy entries and the trailing pad included).
    pub fn input_items(&self) -> &[PdoItem] {
        &self.inputs.items
    }

    /// Checks SM2 (outputs) and SM3 (inputs) against the layout at PRE-OP to SAFE-OP (ETG.1000.6 §6.4;
    /// SOES `ESC_checkSM23` makes the same checks): a non-empty image needs its sync manager enabled, in
    /// buffered mode (control bits 1..0 = 00), with the right direction (SM2 bits 3..2 = 01 master writes, SM3
    /// 00 master reads), in process RAM, and exactly as long as the image; else 0x001D (outputs) or 0x001E
    /// (inputs). An empty image is fine with its sync manager disabled or of length 0.
    pub fn check_sync_managers(&self, sm2: &SmConfig, sm3: &SmConfig) -> Result<(), AlStatusCode> {
        if !window_fits(sm2, self.output_bytes, true) {
            return Err(AlStatusCode::InvalidOutputConfig);
        }
        if !window_fits(sm3, self.input_bytes, false) {
            return Err(AlStatusCode::InvalidInputConfig);
        }
        Ok(())
    }

    /// Writes the output image's values into the dictionary (RxPDO -> set-points), without the SDO checks
    /// (limits, access, state: the application judges set-points, as for a CANopen RPDO). `image` is SM2's
    /// buffer of [`ProcessDataLayout::output_bytes`]; an entry that does not lie within a shorter `image` is
    /// left unchanged. No search, no division: one step per mapped object.
    #[inline]
    pub fn unpack_outputs<const N: usize>(&self, image: &[u8], d: &mut Dictionary<N>) {
        let values: &mut [u8] = d.values_mut().bytes_mut();
        for item in &self.outputs.items {
            item.unpack(image, values);
        }
    }

    /// Fills the input image from the dictionary (actual values -> TxPDO): every bit of the first
    /// [`ProcessDataLayout::input_bytes`] bytes is written, padding as 0. An entry that does not lie within a
    /// shorter `image` is skipped. No search, no division: one step per mapped object.
    #[inline]
    pub fn pack_inputs<const N: usize>(&self, d: &Dictionary<N>, image: &mut [u8]) {
        let values: &[u8] = d.values().bytes();
        for item in &self.inputs.items {
            item.pack(values, image);
        }
    }
}

/// Whether sync manager `sm` is a valid window for an image of `bytes` (see `check_sync_managers`).
fn window_fits(sm: &SmConfig, bytes: u16, master_writes: bool) -> bool {
    if bytes == 0 {
        return !sm.enabled() || sm.length == 0;
    }
    let buffered = sm.control & 0x03 == 0x00;
    let direction = if master_writes { sm.master_writes() } else { sm.control & 0x0C == 0x00 };
    let in_ram = sm.start >= PROCESS_RAM_START && sm.start.checked_add(sm.length).is_some();
    sm.enabled() && buffered && direction && in_ram && sm.length == bytes
}

/// Compiles the image of one direction (see [`ProcessDataLayout::compile`]).
fn compile_image<const N: usize>(d: &Dictionary<N>, direction: Direction) -> Result<Image, SdoAbort> {
    let table = d.table();
    let bytes: &[u8] = d.values().bytes();
    let assignment = pdo_map::assignment_index(direction);
    let count = pdo_map::count(table, bytes, assignment).ok_or(SdoAbort::ObjectDoesNotExist)?;
    if usize::from(count) > MAX_ASSIGNED_PDOS {
        return Err(SdoAbort::ValueTooHigh);
    }
    // Each assigned PDO exists with the right direction and each of its entries resolves (the same checks
    // and codes as an SDO write of sub 0); the sum is checked against the EtherCAT limit.
    let total_bits = pdo_map::check_assignment(table, bytes, assignment, count, None)?;
    let limit = u32::try_from(MAX_PDO_BYTES_ETHERCAT).unwrap_or(u32::MAX);
    if pdo_map::bytes_for_bits(total_bits) > limit {
        return Err(SdoAbort::PdoLengthExceeded);
    }
    let mut image = Image::default();
    let mut base: u32 = 0;
    for pdo in pdo_map::assignment(table, bytes, assignment)? {
        if image.pdos.contains(&pdo) {
            return Err(SdoAbort::InvalidValue);
        }
        image.pdos.push(pdo).map_err(|_| SdoAbort::ValueTooHigh)?;
        let mapping = pdo_map::mapping(table, bytes, pdo)?;
        let pdo_bits = mapping.total_bits();
        let mut seen: u32 = 0;
        for mapped in mapping {
            let bit_offset = base.checked_add(mapped.bit_offset).ok_or(SdoAbort::PdoLengthExceeded)?;
            let item = compile_item::<N>(pdo, mapped.target, bit_offset, mapped.bits, direction)?;
            image.items.push(item).map_err(|_| SdoAbort::PdoLengthExceeded)?;
            seen = seen.saturating_add(u32::from(mapped.bits));
        }
        // `mapping` validated every entry, so the walk covers them all; anything else is a table fault.
        if seen != pdo_bits {
            return Err(SdoAbort::InternalIncompatibility);
        }
        base = base.saturating_add(pdo_bits);
    }
    if base != total_bits {
        return Err(SdoAbort::InternalIncompatibility);
    }
    let image_bytes = pdo_map::bytes_for_bits(base);
    // The inputs are sent whole: the bits after the last entry up to the byte boundary go out as 0.
    let tail = image_bytes.saturating_mul(8).saturating_sub(base);
    if direction == Direction::Tx && tail > 0 {
        let item = compile_item::<N>(0, MapTarget::Padding, base, u8::try_from(tail).unwrap_or(0), direction)?;
        image.items.push(item).map_err(|_| SdoAbort::PdoLengthExceeded)?;
    }
    image.bytes = u16::try_from(image_bytes).map_err(|_| SdoAbort::PdoLengthExceeded)?;
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::access::{AccessContext, NoApplicationObjects, Table};
    use crate::od::entry::{
        Access, Attributes, ConstRef, DataType, Entry, LimitsRef, Name, PdoMapping, Storage, WriteCondition,
    };
    use crate::od::values::Values;

    const fn entry(index: u16, sub: u8, data_type: DataType, pdo: PdoMapping, storage: Storage) -> Entry {
        Entry {
            index,
            sub,
            name: Name::EMPTY,
            data_type,
            attributes: Attributes::new(Access::ReadWrite, pdo, false, WriteCondition::Always),
            limits: LimitsRef::NONE,
            storage,
        }
    }

    const fn ram(offset: u16, len: u16) -> Storage {
        Storage::Ram { offset, len, node_id_relative: false }
    }

    // A small table with BOOLEANs (which the drive's dictionary does not map) to prove bit-level mapping.
    // Storage: 0x1600 sub0 @0, sub1..4 @1..17; 0x1A00 sub0 @17, sub1..4 @18..34; 0x1C12 sub0 @34, sub1 @35;
    // 0x1C13 sub0 @37, sub1 @38; 0x2000 bool @40, 0x2001 u16 @41, 0x2002 bool @43, 0x2003 i32 @44 (tx).
    static ENTRIES: [Entry; 20] = [
        entry(0x1600, 0, DataType::Unsigned8, PdoMapping::No, ram(0, 1)),
        entry(0x1600, 1, DataType::Unsigned32, PdoMapping::No, ram(1, 4)),
        entry(0x1600, 2, DataType::Unsigned32, PdoMapping::No, ram(5, 4)),
        entry(0x1600, 3, DataType::Unsigned32, PdoMapping::No, ram(9, 4)),
        entry(0x1600, 4, DataType::Unsigned32, PdoMapping::No, ram(13, 4)),
        entry(0x1A00, 0, DataType::Unsigned8, PdoMapping::No, ram(17, 1)),
        entry(0x1A00, 1, DataType::Unsigned32, PdoMapping::No, ram(18, 4)),
        entry(0x1A00, 2, DataType::Unsigned32, PdoMapping::No, ram(22, 4)),
        entry(0x1A00, 3, DataType::Unsigned32, PdoMapping::No, ram(26, 4)),
        entry(0x1A00, 4, DataType::Unsigned32, PdoMapping::No, ram(30, 4)),
        entry(0x1C12, 0, DataType::Unsigned8, PdoMapping::No, ram(34, 1)),
        entry(0x1C12, 1, DataType::Unsigned16, PdoMapping::No, ram(35, 2)),
        entry(0x1C13, 0, DataType::Unsigned8, PdoMapping::No, ram(37, 1)),
        entry(0x1C13, 1, DataType::Unsigned16, PdoMapping::No, ram(38, 2)),
        entry(0x2000, 0, DataType::Boolean, PdoMapping::Both, ram(40, 1)),
        entry(0x2001, 0, DataType::Unsigned16, PdoMapping::Both, ram(41, 2)),
        entry(0x2002, 0, DataType::Boolean, PdoMapping::Both, ram(43, 1)),
        entry(0x2003, 0, DataType::Integer32, PdoMapping::Tx, ram(44, 4)),
        entry(0x2004, 0, DataType::Unsigned8, PdoMapping::Tx, Storage::Const(ConstRef::new(&(b"\xA5" as &[u8])))),
        entry(0x2005, 0, DataType::Unsigned8, PdoMapping::Rx, Storage::Const(ConstRef::new(&(b"\x5A" as &[u8])))),
    ];

    const PRE_OP: AccessContext =
        AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 40 };

    fn dictionary(rx: &[u32], tx: &[u32]) -> Dictionary<48> {
        let table = Table::new(&ENTRIES, &[]);
        let mut d = Dictionary::with_table(table, Values::from_bytes([0; 48]));
        let app = &mut NoApplicationObjects;
        for (index, map, assign) in [(0x1600u16, rx, 0x1C12u16), (0x1A00, tx, 0x1C13)] {
            for (sub, raw) in (1u8..).zip(map) {
                assert_eq!(d.write(index, sub, &raw.to_le_bytes(), PRE_OP, app), Ok(()), "{index:04X}:{sub}");
            }
            let count = u8::try_from(map.len()).unwrap();
            assert_eq!(d.write(index, 0, &[count], PRE_OP, app), Ok(()));
            assert_eq!(d.write(assign, 1, &index.to_le_bytes(), PRE_OP, app), Ok(()));
            assert_eq!(d.write(assign, 0, &[1], PRE_OP, app), Ok(()));
        }
        d
    }

    #[test]
    fn booleans_and_odd_gaps_are_mapped_bit_by_bit() {
        // Outputs: bool, 3-bit gap, u16 at bit 4, bool at bit 20 -> 21 bits, 3 bytes.
        // Inputs: bool, u16 at bit 1, constant u8 at bit 17, bool at bit 25 -> 26 bits + 6-bit pad.
        let mut d = dictionary(
            &[0x2000_0001, 0x0000_0003, 0x2001_0010, 0x2002_0001],
            &[0x2002_0001, 0x2001_0010, 0x2004_0008, 0x2000_0001],
        );
        let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
        assert_eq!((layout.output_bytes, layout.input_bytes), (3, 4));
        let offsets: std::vec::Vec<_> = layout.output_items().iter().map(|i| (i.index, i.bit_offset, i.bits)).collect();
        assert_eq!(offsets, [(0x2000, 0, 1), (0, 1, 3), (0x2001, 4, 16), (0x2002, 20, 1)]);
        let tail = layout.input_items().last().copied().unwrap();
        assert_eq!((tail.pdo, tail.bit_offset, tail.bits, tail.location), (0, 26, 6, Location::Padding));

        // 0x2000 = 1, gap bits ignored, 0x2001 = 0xBEEF, 0x2002 = 1.
        let image = [0b1111_0001 | 0b1110, 0xEE, 0x1B | 0x10];
        layout.unpack_outputs(&image, &mut d);
        assert_eq!(d.values().bytes()[40..44], [1, 0xEF, 0xBE, 1]);

        let mut input = [0xFFu8; 4];
        layout.pack_inputs(&d, &mut input);
        // bit 0 = 0x2002 (1); bits 1..16 = 0xBEEF; bits 17..24 = 0xA5; bit 25 = 0x2000 (1); bits 26..31 = 0.
        let expected: u32 = 1 | (0xBEEF << 1) | (0xA5 << 17) | (1 << 25);
        assert_eq!(u32::from_le_bytes(input), expected);
        // A BOOLEAN stored as any non-zero byte is sent as 1; cleared bits go back to 0.
        d.values_mut().bytes_mut()[43] = 0;
        d.values_mut().bytes_mut()[40] = 7;
        layout.pack_inputs(&d, &mut input);
        assert_eq!(u32::from_le_bytes(input), expected & !1);
    }

    #[test]
    fn received_constants_cannot_be_mapped() {
        let d = dictionary(&[0x2001_0010], &[0x2003_0020]);
        assert!(ProcessDataLayout::from_dictionary(&d).is_ok());
        // The SDO layer accepts 0x2005 (it is rx-mappable) but there is no storage to write it into.
        let mut d = d;
        let app = &mut NoApplicationObjects;
        assert_eq!(d.write(0x1C12, 0, &[0], PRE_OP, app), Ok(()));
        assert_eq!(d.write(0x1600, 0, &[0], PRE_OP, app), Ok(()));
        assert_eq!(d.write(0x1600, 1, &0x2005_0008u32.to_le_bytes(), PRE_OP, app), Ok(()));
        assert_eq!(d.write(0x1600, 0, &[1], PRE_OP, app), Ok(()));
        assert_eq!(d.write(0x1C12, 0, &[1], PRE_OP, app), Ok(()));
        let err = ProcessDataLayout::compile(&d).unwrap_err();
        assert_eq!(err, PdoError { direction: Direction::Rx, abort: SdoAbort::CannotBeMapped });
        assert_eq!(err.al_status(), AlStatusCode::InvalidOutputMapping);
    }

    #[test]
    fn short_images_never_panic() {
        let mut d = dictionary(&[0x2001_0010, 0x2000_0001], &[0x2003_0020, 0x2002_0001]);
        let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
        assert_eq!((layout.output_bytes, layout.input_bytes), (3, 5));
        layout.unpack_outputs(&[0x34], &mut d);
        assert_eq!(d.values().bytes()[41..43], [0, 0], "an entry outside the image is left alone");
        let mut input = [0u8; 2];
        layout.pack_inputs(&d, &mut input);
        layout.pack_inputs(&d, &mut []);
    }
}
