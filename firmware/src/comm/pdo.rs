//! The copy steps of compiled PDO mappings, shared by the EtherCAT process data ([`crate::ecat::process_data`]) and
//! the CANopen PDOs ([`crate::canopen::pdo`]): one mapped entry resolved to its place in the value storage and in
//! the PDO image, so that a cycle copies values without any search or division.
//!
//! A byte-aligned object is one slice copy (the storage is little-endian, the CiA 301 §7.1.3 transfer syntax, so
//! the stored bytes are the wire bytes); a BOOLEAN (one bit: the mapping entry states the length in bits, CiA 301
//! §7.4.7.1) or an object placed after a gap of a bit count that is not a multiple of 8 is copied bit by bit. Gaps
//! (index 0, ETG.1000.6) and CiA 301 dummy entries (0x0001..0x0007) take room in the image; received padding is
//! ignored and sent padding is 0.

use crate::od::abort::SdoAbort;
use crate::od::entry::{DataType, Storage};
use crate::od::pdo_map::{Direction, MapTarget};

/// A byte range `start..end` in the image or in the value storage, computed once when the layout is compiled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Span {
    start: u16,
    end: u16,
}

impl Span {
    /// `start..start + len`, or `None` when it would pass `u16::MAX`.
    fn new(start: u16, len: u16) -> Option<Self> {
        Some(Self { start, end: start.checked_add(len)? })
    }

    fn range(self) -> core::ops::Range<usize> {
        usize::from(self.start)..usize::from(self.end)
    }
}

/// How one mapped entry is copied; chosen when the layout is compiled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    /// Whole bytes between the image and the value storage.
    Bytes { image: Span, value: Span },
    /// Bit by bit between the image and the value storage (a BOOLEAN, or an object after an odd gap).
    Bits { value: Span },
    /// A constant object sent in the inputs, whole bytes.
    ConstBytes { image: Span, data: &'static [u8] },
    /// A constant object sent in the inputs, bit by bit.
    ConstBits { data: &'static [u8] },
    /// Padding in the inputs: whole bytes of 0.
    ZeroBytes { image: Span },
    /// Padding in the inputs: bits of 0.
    ZeroBits,
    /// Padding in the outputs: ignored.
    Skip,
}

/// Where a mapped item's value comes from or goes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Location {
    /// In the dictionary's value storage at this byte offset (a typed handle's offset) with this length.
    Value {
        /// Byte offset in the value storage.
        offset: u16,
        /// Length in bytes.
        len: u16,
    },
    /// A constant object (sent in the inputs only).
    Constant,
    /// A gap or dummy entry, or the pad after the last TxPDO entry.
    Padding,
}

/// One entry of the compiled layout: a mapped object (or padding) and its place in the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PdoItem {
    /// The mapping object (0x16xx / 0x1Axx) that maps it; 0 for the pad after the last TxPDO entry.
    pub pdo: u16,
    /// Index of the mapped object (0 for padding).
    pub index: u16,
    /// Sub-index of the mapped object (0 for padding).
    pub sub: u8,
    /// Position of the first bit in the image (bit 0 = least significant bit of byte 0; ETG.1000.4 bit order).
    pub bit_offset: u16,
    /// Length in bits.
    pub bits: u8,
    /// Where the value lives.
    pub location: Location,
    op: Op,
}

impl PdoItem {
    /// Copies this item from the output image into the value storage.
    #[inline]
    pub fn unpack(&self, image: &[u8], values: &mut [u8]) {
        match self.op {
            Op::Bytes { image: from, value: to } => {
                if let (Some(src), Some(dst)) = (image.get(from.range()), values.get_mut(to.range())) {
                    copy_bytes(dst, src);
                }
            }
            Op::Bits { value } => {
                let bits = read_bits(image, self.bit_offset, self.bits);
                if let Some(dst) = values.get_mut(value.range()) {
                    store_le(dst, bits);
                }
            }
            Op::ConstBytes { .. } | Op::ConstBits { .. } | Op::ZeroBytes { .. } | Op::ZeroBits | Op::Skip => {}
        }
    }

    /// Copies this item from the value storage into the input image.
    #[inline]
    pub fn pack(&self, values: &[u8], image: &mut [u8]) {
        match self.op {
            Op::Bytes { image: to, value: from } => {
                if let (Some(src), Some(dst)) = (values.get(from.range()), image.get_mut(to.range())) {
                    copy_bytes(dst, src);
                }
            }
            Op::Bits { value } => {
                let raw = values.get(value.range()).map_or(0, load_le);
                write_bits(image, self.bit_offset, self.bits, normalise(raw, self.bits));
            }
            Op::ConstBytes { image: to, data } => {
                if let Some(dst) = image.get_mut(to.range()) {
                    copy_bytes(dst, data);
                }
            }
            Op::ConstBits { data } => {
                write_bits(image, self.bit_offset, self.bits, normalise(load_le(data), self.bits))
            }
            Op::ZeroBytes { image: to } => {
                if let Some(dst) = image.get_mut(to.range()) {
                    dst.fill(0);
                }
            }
            Op::ZeroBits => write_bits(image, self.bit_offset, self.bits, 0),
            Op::Skip => {}
        }
    }
}

/// Copies `src` into `dst` when both have the same length (always so for a compiled step). The mapped types
/// are 1, 2, 4 or 8 bytes long: those copies are inlined loads and stores instead of a `memcpy` call, which
/// keeps a cycle's unpack and pack within the instruction budget.
#[inline(always)]
fn copy_bytes(dst: &mut [u8], src: &[u8]) {
    match dst.len() {
        1 => copy_n::<1>(dst, src),
        2 => copy_n::<2>(dst, src),
        4 => copy_n::<4>(dst, src),
        8 => copy_n::<8>(dst, src),
        _ => {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = *s;
            }
        }
    }
}

/// [`copy_bytes`] for a length known at compile time.
#[inline(always)]
fn copy_n<const K: usize>(dst: &mut [u8], src: &[u8]) {
    if let (Ok(d), Ok(s)) = (<&mut [u8; K]>::try_from(dst), <&[u8; K]>::try_from(src)) {
        *d = *s;
    }
}

/// A one-bit BOOLEAN is true for any non-zero stored byte (CiA 301 BOOLEAN, as `Scalar for bool` reads it);
/// wider values are sent as stored.
const fn normalise(raw: u64, bits: u8) -> u64 {
    if bits != 1 {
        raw
    } else if raw != 0 {
        1
    } else {
        0
    }
}

/// Up to 8 little-endian bytes as a zero-extended `u64`.
fn load_le(bytes: &[u8]) -> u64 {
    let mut wide = [0u8; 8];
    for (w, b) in wide.iter_mut().zip(bytes) {
        *w = *b;
    }
    u64::from_le_bytes(wide)
}

/// Stores the low `dst.len()` (at most 8) bytes of `value` little-endian.
fn store_le(dst: &mut [u8], value: u64) {
    for (d, b) in dst.iter_mut().zip(value.to_le_bytes()) {
        *d = b;
    }
}

/// Bits `bit_offset..bit_offset + bits` of `image` (LSB first), as a value; bits outside `image` read as 0.
fn read_bits(image: &[u8], bit_offset: u16, bits: u8) -> u64 {
    let mut value = 0u64;
    for k in 0..bits {
        let position = bit_offset.wrapping_add(u16::from(k));
        let set = image
            .get(usize::from(position.wrapping_shr(3)))
            .is_some_and(|byte| byte.wrapping_shr(u32::from(position & 7)) & 1 != 0);
        if set {
            value |= 1u64.wrapping_shl(u32::from(k));
        }
    }
    value
}

/// Writes the low `bits` bits of `value` at `bit_offset..` of `image` (LSB first), leaving the other bits alone.
fn write_bits(image: &mut [u8], bit_offset: u16, bits: u8, value: u64) {
    for k in 0..bits {
        let position = bit_offset.wrapping_add(u16::from(k));
        if let Some(byte) = image.get_mut(usize::from(position.wrapping_shr(3))) {
            let mask = 1u8.wrapping_shl(u32::from(position & 7));
            if value.wrapping_shr(u32::from(k)) & 1 != 0 {
                *byte |= mask;
            } else {
                *byte &= !mask;
            }
        }
    }
}

/// Compiles one mapped entry of `pdo` at `bit_offset` of the image, for a value storage of `N` bytes. Fails with
/// 0x0604_0042 when the entry lies beyond the image's 16-bit bit offsets, 0x0604_0041 for a received constant or an
/// application-served object (nothing to copy into or out of), 0x0604_0047 when the slot does not fit the storage.
pub fn compile_item<const N: usize>(
    pdo: u16,
    target: MapTarget,
    bit_offset: u32,
    bits: u8,
    direction: Direction,
) -> Result<PdoItem, SdoAbort> {
    let bit_offset = u16::try_from(bit_offset).map_err(|_| SdoAbort::PdoLengthExceeded)?;
    let aligned = bit_offset & 7 == 0 && bits & 7 == 0;
    let image_span =
        Span::new(bit_offset.wrapping_shr(3), u16::from(bits.wrapping_shr(3))).ok_or(SdoAbort::PdoLengthExceeded)?;
    let (index, sub, location, op) = match target {
        MapTarget::Padding => {
            let op = match (direction, aligned) {
                (Direction::Rx, _) => Op::Skip,
                (Direction::Tx, true) => Op::ZeroBytes { image: image_span },
                (Direction::Tx, false) => Op::ZeroBits,
            };
            (0, 0, Location::Padding, op)
        }
        MapTarget::Object(entry) => {
            let expected = entry.data_type.fixed_size().and_then(|n| u16::try_from(n).ok());
            let (location, op) = match (entry.storage, direction) {
                (Storage::Ram { offset, len, .. }, _) => {
                    let value = Span::new(offset, len).ok_or(SdoAbort::InternalIncompatibility)?;
                    if Some(len) != expected || usize::from(value.end) > N {
                        return Err(SdoAbort::InternalIncompatibility);
                    }
                    let op = if aligned && entry.data_type != DataType::Boolean {
                        Op::Bytes { image: image_span, value }
                    } else {
                        Op::Bits { value }
                    };
                    (Location::Value { offset, len }, op)
                }
                (Storage::Const(constant), Direction::Tx) => {
                    let data = constant.bytes();
                    if u16::try_from(data.len()).ok() != expected {
                        return Err(SdoAbort::InternalIncompatibility);
                    }
                    let op = if aligned && entry.data_type != DataType::Boolean {
                        Op::ConstBytes { image: image_span, data }
                    } else {
                        Op::ConstBits { data }
                    };
                    (Location::Constant, op)
                }
                // Nothing to write a received constant into; application entries have no storage to copy.
                (Storage::Const(_), Direction::Rx) | (Storage::Application, _) => {
                    return Err(SdoAbort::CannotBeMapped);
                }
            };
            (entry.index, entry.sub, location, op)
        }
    };
    Ok(PdoItem { pdo, index, sub, bit_offset, bits, location, op })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_helpers_round_trip() {
        let mut image = [0u8; 3];
        write_bits(&mut image, 5, 13, 0x1ABC);
        assert_eq!(read_bits(&image, 5, 13), 0x1ABC);
        assert_eq!(read_bits(&image, 0, 5), 0);
        write_bits(&mut image, 20, 8, 0xFF);
        assert_eq!(image[2], 0xF0 | (0x1ABC >> 11) as u8);
        assert_eq!(read_bits(&image, 20, 8), 0x0F, "bits past the end read as 0");
        assert_eq!(load_le(&[1, 2]), 0x0201);
        let mut out = [0u8; 2];
        store_le(&mut out, 0x0304);
        assert_eq!(out, [4, 3]);
    }
}
