//! The SSI absolute encoder's frame: its format from the dictionary (IDX 0x3012, S2 L4159-4408) and the rules that
//! turn a clocked frame into a position, cheap enough for tier 1.
//!
//! # The frame (as the board's SPI receives it, first bit clocked = most significant, right-aligned in a `u32`)
//! `[start] [multi-turn bits] [single-turn bits] [special bits] [stop]`
//! - Data bits: multi-turn (0x3012:02 bits 23..16) then single-turn (bits 15..8), most significant first, binary or
//!   Gray coded over the whole data word (0x3012:03 bits 3..0, IDX Table 6-104).
//! - Special bits (0x3012:02 bits 7..0, at most 16): copied raw, not processed (IDX L4266 "no additional
//!   processing of the special bits will take place"); this drive takes them as trailing the data (0x3012:06;
//!   0x3012:0C, leading, stays 0: IDX's frame figure 6-33 is lost in the seed, and trailing is where the common
//!   encoders put their error and warning bits).
//! - Frame check (0x3012:03 bit 8, IDX Table 6-104 "frame start and end bit checking"): the master clocks one bit
//!   before the data, which a sensor that has latched its position drives high (start bit 1), and one after the
//!   data, where the sensor's monoflop holds the line low (stop bit 0). Without the check no extra bits are clocked.
//! - The seeds define no CRC or parity for SSI (IDX 0x3012 and EPOS3 0x2211 have none): none is checked.
//! - This drive clocks at most 32 bits per frame (two 16-bit SPI frames): a format with more is refused.
//!
//! # Errors (IDX L7274-7288)
//! - A frame whose every clocked bit reads the same level is no data at all: the sensor is not there, unpowered,
//!   or sees no clock (a stuck clock line leaves its data line at the idle level): 0x738C "SSI sensor driver could
//!   not sample position data" ([`SsiError::NoData`]).
//! - Otherwise a wrong start or stop bit is 0x738D "invalid SSI data frame" ([`SsiError::Frame`]).
//!
//! # Position bits (0x3012:0B, IDX Table 6-105)
//! The drive's position has at most 32 bits: 0x3012:0B chooses how many multi-turn (`MT'`) and single-turn
//! (`ST'`) bits it keeps; the lowest `ST - ST'` single-turn bits and the highest `MT - MT'` multi-turn bits are
//! dropped. Resolution: `2^ST'` increments per revolution (IDX L4365). This drive keeps `ST' <= 16`: tier 1 tracks
//! the position through a 16-bit count (the incremental encoder's counter width, [`crate::drive::encoder`]).
//!
//! # Tier 1's count
//! Tier 1 takes the low 16 bits of the position ([`SsiFormat::count16`]), which wrap like the encoder counter when
//! the position has 16 bits or more. A shorter position (`MT' + ST' < 16`, a single-turn sensor) is shifted left to
//! 16 bits ([`SsiFormat::align_bits`]), so that it wraps at 2^16 too; tier 1's counts per revolution are then
//! `2^(ST' + align)`, the low `align` bits always 0.

/// Errors of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SsiError {
    /// Every clocked bit read the same level: no sensor answered (missing, unpowered, clock stuck). 0x738C.
    NoData,
    /// The start or stop bit is wrong, or the data jumped farther than the shaft can move. 0x738D.
    Frame,
}

/// The format given in 0x3012 is not one this drive can read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SsiFormatError;

/// Highest bits clocked per frame (two 16-bit SPI frames).
pub const MAX_FRAME_BITS: u32 = 32;
/// Highest single-turn position bits kept (tier 1's 16-bit count).
pub const MAX_SINGLE_TURN_POSITION_BITS: u32 = 16;

/// The frame format and what the drive keeps of it (0x3012:02, :03, :0B, :0A), with the shifts and masks tier 1
/// uses precomputed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SsiFormat {
    /// Bits clocked per frame, start and stop bits included.
    pub frame_bits: u8,
    /// Multi-turn data bits (0x3012:02 bits 23..16).
    pub multi_turn_bits: u8,
    /// Single-turn data bits (0x3012:02 bits 15..8).
    pub single_turn_bits: u8,
    /// Special bits after the data (0x3012:02 bits 7..0).
    pub special_bits: u8,
    /// Multi-turn bits kept (0x3012:0B bits 15..8).
    pub multi_turn_position_bits: u8,
    /// Single-turn bits kept (0x3012:0B bits 7..0), at most 16.
    pub single_turn_position_bits: u8,
    /// Gray coded data (0x3012:03 bits 3..0 = 1).
    pub gray: bool,
    /// Start and stop bits clocked and checked (0x3012:03 bit 8).
    pub frame_check: bool,
    /// Counting direction inverted (0x3012:03 bit 4).
    pub inverted: bool,
    /// Left shift of a position shorter than 16 bits into tier 1's 16-bit count.
    pub align_bits: u8,
    /// The commutation offset 0x3012:0A: position increments added to the single-turn position before the
    /// electrical angle is taken from it (IDX L4326, EPOS4 AN ch. 8.3).
    pub commutation_offset: u32,
}

/// `n` low bits set (`n` up to 32).
#[inline(always)]
#[must_use]
pub const fn low_bits(n: u32) -> u32 {
    if n >= 32 {
        u32::MAX
    } else {
        (1u32 << n).wrapping_sub(1)
    }
}

/// Gray to binary over a whole word: bit `i` of the result is the XOR of Gray bits `i` and above, in five
/// shift-XOR steps (log2 32), valid for any width when the bits above the data are zero.
#[inline(always)]
#[must_use]
pub const fn gray_to_binary(gray: u32) -> u32 {
    let mut b = gray ^ (gray >> 16);
    b ^= b >> 8;
    b ^= b >> 4;
    b ^= b >> 2;
    b ^ (b >> 1)
}

impl SsiFormat {
    /// The reference sensor of the simulator's SSI preset: 12 multi-turn and 12 single-turn bits (4,096 inc/rev),
    /// Gray coded, no special bits, frame check on; everything kept; no commutation offset.
    pub const REFERENCE: Self = Self {
        frame_bits: 26,
        multi_turn_bits: 12,
        single_turn_bits: 12,
        special_bits: 0,
        multi_turn_position_bits: 12,
        single_turn_position_bits: 12,
        gray: true,
        frame_check: true,
        inverted: false,
        align_bits: 0,
        commutation_offset: 0,
    };

    /// From 0x3012:02 (number of data bits: 23..16 multi-turn, 15..8 single-turn, 7..0 special), 0x3012:03
    /// (encoding: 3..0 code, bit 4 direction, bit 8 frame check), 0x3012:0B (position bits: 15..8 multi-turn,
    /// 7..0 single-turn) and 0x3012:0A (commutation offset). Refused (IDX Tables 6-103..6-105, with this drive's
    /// limits): single-turn data bits outside 6..=32, special bits above 16, an encoding other than binary or
    /// Gray, more than 32 clocked bits, position bits more than the data has, single-turn position bits outside
    /// 6..=16, multi-turn position bits above 26.
    pub fn from_od(data_bits: u32, encoding: u16, position_bits: u32, offset: u32) -> Result<Self, SsiFormatError> {
        let [special, st, mt, _] = data_bits.to_le_bytes();
        let [st_kept, mt_kept, _, _] = position_bits.to_le_bytes();
        let code = encoding & 0x000F;
        let frame_check = encoding & 0x0100 != 0;
        let frame_bits = u32::from(mt)
            .saturating_add(u32::from(st))
            .saturating_add(u32::from(special))
            .saturating_add(if frame_check { 2 } else { 0 });
        let valid = (6..=32).contains(&st)
            && special <= 16
            && code <= 1
            && frame_bits <= MAX_FRAME_BITS
            && (6..=16).contains(&st_kept)
            && st_kept <= st
            && mt_kept <= mt
            && mt_kept <= 26;
        if !valid {
            return Err(SsiFormatError);
        }
        let kept = u32::from(mt_kept).saturating_add(u32::from(st_kept));
        Ok(Self {
            frame_bits: frame_bits as u8,
            multi_turn_bits: mt,
            single_turn_bits: st,
            special_bits: special,
            multi_turn_position_bits: mt_kept,
            single_turn_position_bits: st_kept,
            gray: code == 1,
            frame_check,
            inverted: encoding & 0x0010 != 0,
            align_bits: 16u32.saturating_sub(kept) as u8,
            commutation_offset: offset,
        })
    }

    /// Bits after the data: the special bits and the stop bit.
    #[inline(always)]
    const fn data_shift(&self) -> u32 {
        (self.special_bits as u32).wrapping_add(self.frame_check as u32)
    }

    /// Data bits (multi-turn + single-turn).
    #[inline(always)]
    const fn data_bits(&self) -> u32 {
        (self.multi_turn_bits as u32).wrapping_add(self.single_turn_bits as u32)
    }

    /// Position bits kept (`MT' + ST'`).
    #[must_use]
    pub const fn position_bits(&self) -> u32 {
        (self.multi_turn_position_bits as u32).wrapping_add(self.single_turn_position_bits as u32)
    }

    /// Single-turn data bits dropped at the bottom.
    #[inline(always)]
    const fn dropped_bits(&self) -> u32 {
        (self.single_turn_bits as u32).wrapping_sub(self.single_turn_position_bits as u32)
    }

    /// The data word of a frame, binary.
    #[inline(always)]
    #[must_use]
    pub const fn data(&self, frame: u32) -> u32 {
        let raw = (frame >> self.data_shift()) & low_bits(self.data_bits());
        if self.gray {
            gray_to_binary(raw)
        } else {
            raw
        }
    }

    /// The position kept of a frame: `MT' + ST'` bits, unsigned, not inverted (0x3012:03 bit 4 is applied by the
    /// tracking, [`crate::drive::encoder`], and by [`Self::single_turn`]).
    #[must_use]
    pub const fn position(&self, frame: u32) -> u32 {
        (self.data(frame) >> self.dropped_bits()) & low_bits(self.position_bits())
    }

    /// Tier 1's 16-bit count of a frame (module documentation).
    #[inline(always)]
    #[must_use]
    pub const fn count16(&self, frame: u32) -> u16 {
        // Deliberate truncation: the low 16 bits wrap like the encoder counter.
        ((self.data(frame) >> self.dropped_bits()) << self.align_bits) as u16
    }

    /// Tier 1's counts per revolution: `2^(ST' + align)`.
    #[must_use]
    pub const fn counts_per_rev(&self) -> u32 {
        1u32 << (self.single_turn_position_bits as u32).wrapping_add(self.align_bits as u32)
    }

    /// Increments per revolution of the position (0x3000:05): `2^ST'` (IDX L4365).
    #[must_use]
    pub const fn resolution(&self) -> u32 {
        1u32 << self.single_turn_position_bits as u32
    }

    /// The single-turn count within tier 1's revolution of a 16-bit count, in the drive's positive direction.
    #[must_use]
    pub const fn single_turn(&self, count16: u16) -> u32 {
        let turn = self.counts_per_rev().wrapping_sub(1);
        let count = count16 as u32;
        if self.inverted {
            count.wrapping_neg() & turn
        } else {
            count & turn
        }
    }

    /// The special bits of a frame (0x3012:06).
    #[must_use]
    pub const fn special(&self, frame: u32) -> u32 {
        (frame >> self.frame_check as u32) & low_bits(self.special_bits as u32)
    }

    /// The bits the frame check compares, and the values they must have: the start bit (the highest clocked) 1,
    /// the stop bit (bit 0) 0. Both 0 without the frame check.
    #[must_use]
    pub const fn check_bits(&self) -> (u32, u32) {
        if self.frame_check {
            let start = 1u32 << (self.frame_bits as u32).wrapping_sub(1);
            (start | 1, start)
        } else {
            (0, 0)
        }
    }

    /// Checks a frame: [`SsiError::NoData`] when every clocked bit has the same level, [`SsiError::Frame`] when a
    /// start or stop bit is wrong.
    pub const fn check(&self, frame: u32) -> Result<(), SsiError> {
        let all = low_bits(self.frame_bits as u32);
        let frame = frame & all;
        if frame == 0 || frame == all {
            return Err(SsiError::NoData);
        }
        let (mask, expected) = self.check_bits();
        if frame & mask != expected {
            return Err(SsiError::Frame);
        }
        Ok(())
    }

    /// The frame a sensor of this format sends for `position` (`MT' + ST'` bits, dropped bits 0) and `special`
    /// bits: what the simulator's sensor and the tests build.
    #[must_use]
    pub const fn encode(&self, position: u32, special: u32) -> u32 {
        let data = (position & low_bits(self.position_bits())) << self.dropped_bits();
        let data = if self.gray { data ^ (data >> 1) } else { data };
        let body = (data << self.special_bits as u32) | (special & low_bits(self.special_bits as u32));
        if self.frame_check {
            (1u32 << (self.frame_bits as u32).wrapping_sub(1)) | (body << 1)
        } else {
            body
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 0x3012:02 of `mt` multi-turn, `st` single-turn and `special` bits.
    fn data_bits(mt: u32, st: u32, special: u32) -> u32 {
        mt << 16 | st << 8 | special
    }

    /// IDX Table 6-104 code 1 "Gray coded data": the reflected binary code, bit i = b_i ^ b_(i+1); decoding every
    /// 16-bit value and sampled 32-bit values gives the binary back, e.g. Gray 0b1000 (8) = binary 15.
    #[test]
    fn gray_decode_inverts_the_reflected_binary_code() {
        assert_eq!(gray_to_binary(0b1000), 15);
        assert_eq!(gray_to_binary(0b1100), 8);
        for b in 0..=0xFFFFu32 {
            assert_eq!(gray_to_binary(b ^ (b >> 1)), b);
        }
        for b in [u32::MAX, 0x8000_0000, 0xDEAD_BEEF, 0x1234_5678] {
            assert_eq!(gray_to_binary(b ^ (b >> 1)), b);
        }
    }

    /// IDX Table 6-103 (multi-turn 0..32, single-turn 6..32, special 0..16, 62 in all) with this drive's limit of
    /// 32 clocked bits, and Table 6-105 (single-turn position bits 6..31, here 6..=16; multi-turn 0..=26): the
    /// reference 12 + 12 Gray with frame check is 26 clocked bits; 13 + 17 + 2 frame bits is 32, accepted; one
    /// more bit is refused, as are 5 single-turn bits, 17 special bits, encoding 2, 17 single-turn position bits
    /// and more position bits than the data has.
    #[test]
    fn format_limits() {
        let f = SsiFormat::from_od(data_bits(12, 12, 0), 0x0101, 0x0C0C, 0).unwrap();
        assert_eq!(f, SsiFormat::REFERENCE);
        assert_eq!((f.counts_per_rev(), f.resolution(), f.position_bits()), (4096, 4096, 24));
        let wide = SsiFormat::from_od(data_bits(13, 17, 0), 0x0100, 0x0D10, 0).unwrap();
        assert_eq!((wide.frame_bits, wide.resolution(), wide.align_bits), (32, 65_536, 0));
        for (bits, encoding, position) in [
            (data_bits(14, 17, 0), 0x0100, 0x0D10),
            (data_bits(12, 5, 0), 0x0000, 0x0C05),
            (data_bits(0, 12, 17), 0x0000, 0x000C),
            (data_bits(12, 12, 0), 0x0002, 0x0C0C),
            (data_bits(12, 17, 0), 0x0000, 0x0C11),
            (data_bits(12, 12, 0), 0x0000, 0x0D0C),
            (data_bits(12, 12, 0), 0x0000, 0x0C0D),
        ] {
            assert_eq!(SsiFormat::from_od(bits, encoding, position, 0), Err(SsiFormatError), "{bits:#x} {position:#x}");
        }
    }

    /// Binary and Gray frames of every bit count decode to the position they carry (IDX Table 6-104 bits 3..0),
    /// with the special bits copied raw (IDX L4266): 12 + 12 Gray with 2 trailing special bits 0b10 and the frame
    /// bits, position 0x5A5_3C7, is the frame 0x5A53C7 in Gray, and gives back 0x5A53C7 and 0b10.
    #[test]
    fn frames_decode_to_their_position_binary_and_gray() {
        for (mt, st, special) in [(12, 12, 2), (0, 12, 0), (0, 16, 0), (14, 16, 0), (4, 10, 4), (13, 17, 0)] {
            for code in [0x0100u16, 0x0101] {
                let st_kept = st.min(16);
                let f = SsiFormat::from_od(data_bits(mt, st, special), code, mt << 8 | st_kept, 0).unwrap();
                for position in [0u32, 1, 0x5A5_3C7, 0xFFFF_FFFF, 0x8000_0001, 0x0001_2345] {
                    let position = position & low_bits(f.position_bits());
                    let frame = f.encode(position, 0b10);
                    assert_eq!(f.check(frame), Ok(()), "start 1 and stop 0 are never a constant line");
                    assert_eq!(f.position(frame), position, "{mt}+{st}+{special} code {code:#x} {position:#x}");
                    assert_eq!(f.special(frame), 0b10 & low_bits(special));
                    // Tier 1's count: the low 16 bits, left-aligned when the position is shorter.
                    let want = (position << f.align_bits) as u16;
                    assert_eq!(f.count16(frame), want);
                }
            }
        }
        let f = SsiFormat::from_od(data_bits(12, 12, 2), 0x0101, 0x0C0C, 0).unwrap();
        let frame = f.encode(0x5A_53C7, 0b10);
        let gray = 0x5A_53C7 ^ (0x5A_53C7 >> 1);
        assert_eq!(frame, 1 << 27 | gray << 3 | 0b10 << 1);
        assert_eq!(f.position(frame), 0x5A_53C7);
    }

    /// Position bits fewer than the data bits (IDX Table 6-105, L4365): 13 + 17 kept as 12 + 16 drops the lowest
    /// single-turn bit and the highest multi-turn bit; resolution 2^16.
    #[test]
    fn position_bits_drop_the_lowest_single_turn_and_highest_multi_turn_bits() {
        let f = SsiFormat::from_od(data_bits(13, 17, 0), 0x0101, 0x0C10, 0).unwrap();
        let data = 0b1_0000_0000_0011 << 17 | 0x1_2345;
        let frame = f.encode(0, 0) | {
            let g = data ^ (data >> 1);
            g << 1
        };
        assert_eq!(f.position(frame), (0b0000_0000_0011 << 16) | (0x1_2345 >> 1));
        assert_eq!(f.resolution(), 65_536);
    }

    /// The frame check (IDX Table 6-104 bit 8; errors IDX L7274-7288): a flipped start bit or stop bit is 0x738D
    /// ([`SsiError::Frame`]); a frame of all ones (the line idle high: clock stuck, or no sensor with a fail-safe
    /// receiver) or all zeros (no sensor, line pulled low) is 0x738C ([`SsiError::NoData`]); without the frame check
    /// only the constant frames are refused.
    #[test]
    fn frame_check_refuses_bad_start_and_stop_bits_and_constant_lines() {
        let f = SsiFormat::REFERENCE;
        let good = f.encode(0x12_3456, 0);
        assert_eq!(f.check(good), Ok(()));
        assert_eq!(f.check(good ^ (1 << 25)), Err(SsiError::Frame), "start bit 0");
        assert_eq!(f.check(good ^ 1), Err(SsiError::Frame), "stop bit 1");
        assert_eq!(f.check(0x03FF_FFFF), Err(SsiError::NoData), "26 ones");
        assert_eq!(f.check(0xFFFF_FFFF), Err(SsiError::NoData), "bits above the frame are not clocked");
        assert_eq!(f.check(0), Err(SsiError::NoData));
        let unchecked = SsiFormat::from_od(data_bits(12, 12, 0), 0x0001, 0x0C0C, 0).unwrap();
        assert_eq!(unchecked.frame_bits, 24);
        assert_eq!(unchecked.check(unchecked.encode(0x12_3456, 0) ^ 1), Ok(()));
        assert_eq!(unchecked.check(0x00FF_FFFF), Err(SsiError::NoData));
    }

    /// 0x3012:03 bit 4 "direction inverted": the single-turn count runs the other way, 0 staying 0 (4,096
    /// increments: count 1 is 4,095).
    #[test]
    fn inverted_direction_mirrors_the_single_turn_count() {
        let f = SsiFormat { inverted: true, ..SsiFormat::REFERENCE };
        assert_eq!((f.single_turn(0), f.single_turn(1), f.single_turn(0x1FFF)), (0, 4095, 1));
        assert_eq!(SsiFormat::REFERENCE.single_turn(0x1FFF), 4095);
    }

    /// A single-turn sensor of 12 bits is left-aligned into tier 1's 16 bits: counts per revolution 2^16, the
    /// position's resolution (0x3000:05) 2^12.
    #[test]
    fn short_positions_are_aligned_to_sixteen_bits() {
        let f = SsiFormat::from_od(data_bits(0, 12, 0), 0x0100, 0x000C, 0).unwrap();
        assert_eq!((f.align_bits, f.counts_per_rev(), f.resolution()), (4, 65_536, 4096));
        assert_eq!(f.count16(f.encode(4095, 0)), 0xFFF0);
        assert_eq!(f.count16(f.encode(1, 0)), 0x0010);
    }
}
