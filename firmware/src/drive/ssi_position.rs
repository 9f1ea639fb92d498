//! Tier 2's side of the SSI absolute encoder: the absolute position across a restart, the raw-value objects and
//! the whole-frame check of the frames tier 1 reports.
//!
//! Tier 1 tracks the position from the frames' low 16 bits ([`crate::sensors::ssi::SsiFormat::count16`]),
//! starting at 0 when its commutation is built. Tier 2 reads the whole position of the frame of the first report
//! after that (multi-turn bits included) and makes the axis's position offset `base + saved offset`, where
//! `base = absolute - tier 1's position` and the saved offset is 0x3012:0E: 0x6064 continues where it was before
//! the restart, with no homing. A homing (e.g. method 37 or 35, which sets 0x6064 to the home position where the
//! axis stands) moves the axis's offset; the difference to `base` is written to 0x3012:0E, which 0x1010 saves.
//!
//! # Every frame whose bits are used is checked by whoever uses them
//! Tier 1 uses a frame's low 16 position bits for the angle and checks each frame before it does (start/stop
//! bits, constant line, a jump no motion explains: `super::tier1`). Tier 2 uses the whole position only of the
//! frames in its reports, and checks each of them whole: its position must equal tier 1's tracked position plus
//! `base` modulo the sensor's range; a frame whose multi-turn bits disagree raises 0x738D, and its position is
//! not used.

use crate::control::angle::ElectricalAngle;
use crate::sensors::ssi::{low_bits, SsiFormat};

/// What a report's frame gave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameVerdict {
    /// Not an SSI sensor, or the frame failed tier 1's check (tier 1 reports that itself).
    Ignored,
    /// The first good frame since the commutation was built: the axis's offset is to be `base + saved offset`.
    Established {
        /// Absolute position minus tier 1's position.
        base: i32,
    },
    /// The frame agrees with the tracked position.
    Consistent,
    /// The frame's position disagrees with the tracked one (a corrupted multi-turn bit): 0x738D. The detail is
    /// the difference, increments.
    Inconsistent(i32),
}

/// The absolute position's bookkeeping (module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SsiPosition {
    /// Absolute position minus tier 1's position, once established for the commutation in force.
    base: Option<i32>,
    /// The settings version whose commutation the base must come from (tier 1 restarts its position with it).
    since_version: u32,
    /// The value of 0x3012:0E the drive wrote or applied last.
    offset_applied: i32,
}

impl SsiPosition {
    /// The commutation was rebuilt with settings `version`: the base is found again from the first report of
    /// that version or a later one.
    pub fn restart(&mut self, version: u32) {
        self.base = None;
        self.since_version = version;
    }

    /// The base, once established.
    #[must_use]
    pub const fn base(&self) -> Option<i32> {
        self.base
    }

    /// One report: its frame (`frame`, tier 1's position `tracked`, tier 1's settings version `version`, whether
    /// tier 1 is in «Fault»).
    pub fn report(&mut self, ssi: &SsiFormat, frame: u32, tracked: i32, version: u32, faulted: bool) -> FrameVerdict {
        // Reports of settings older than the commutation's rebuild still count from the old start (versions
        // compare modulo 2^32, as the blocks' periods do).
        if faulted || ssi.check(frame).is_err() || version.wrapping_sub(self.since_version).cast_signed() < 0 {
            return FrameVerdict::Ignored;
        }
        let absolute = ssi.position(frame).wrapping_shl(u32::from(ssi.align_bits));
        let absolute = if ssi.inverted { absolute.wrapping_neg() } else { absolute };
        let Some(base) = self.base else {
            let base = absolute.cast_signed().wrapping_sub(tracked);
            self.base = Some(base);
            return FrameVerdict::Established { base };
        };
        // The sensor's range in tier 1's counts: 2^(position bits + align), all of u32 at 32.
        let range = low_bits(ssi.position_bits().wrapping_add(u32::from(ssi.align_bits)));
        let difference = tracked.wrapping_add(base).cast_unsigned().wrapping_sub(absolute);
        if difference & range == 0 {
            FrameVerdict::Consistent
        } else {
            FrameVerdict::Inconsistent(difference.cast_signed())
        }
    }

    /// The saved offset 0x3012:0E the drive applied or wrote last.
    #[must_use]
    pub const fn offset_applied(&self) -> i32 {
        self.offset_applied
    }

    /// Records the saved offset applied or written.
    pub fn set_offset_applied(&mut self, offset: i32) {
        self.offset_applied = offset;
    }
}

/// The electrical angle of a raw single-turn value and a commutation offset, for tests and tools: `(raw +
/// offset) x pole pairs / 2^bits` turns.
#[must_use]
pub fn electrical_angle(single_turn: u32, offset: u32, pole_pairs: u8, bits: u32) -> ElectricalAngle {
    let turn = low_bits(bits);
    let electrical = single_turn.wrapping_add(offset).wrapping_mul(u32::from(pole_pairs)) & turn;
    ElectricalAngle(electrical.wrapping_shl(32u32.wrapping_sub(bits)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference 12 + 12 sensor: the first good report establishes `base = absolute - tracked`; later reports
    /// agree while tier 1's position and the sensor move together, also across the sensor's wrap at 2^24; a frame
    /// whose multi-turn bit 16 (binary) is flipped from 0 to 1 disagrees by exactly -65,536; a faulted tier 1, a
    /// frame failing its check and a report of an older settings version are ignored.
    #[test]
    fn base_is_established_once_and_frames_are_checked_against_it() {
        let f = SsiFormat::REFERENCE;
        let mut p = SsiPosition::default();
        p.restart(5);
        assert_eq!(p.report(&f, f.encode(1000, 0), 0, 4, false), FrameVerdict::Ignored, "older settings");
        assert_eq!(
            p.report(&f, f.encode(0x12_3456, 0), 7, 5, false),
            FrameVerdict::Established { base: 0x12_3456 - 7 }
        );
        assert_eq!(p.report(&f, f.encode(0x12_3456 + 100, 0), 107, 5, false), FrameVerdict::Consistent);
        // Across the wrap of the 24-bit position: tracked keeps counting, the sensor starts again at 0.
        let tracked = 0x100_0000 - 0x12_3456 + 7 + 5;
        assert_eq!(p.report(&f, f.encode(5, 0), tracked, 5, false), FrameVerdict::Consistent);
        // Multi-turn bit 16 (binary) wrong: 65,536 increments off.
        let good = 0x12_3456 + 200;
        assert_eq!(p.report(&f, f.encode(good ^ (1 << 16), 0), 207, 5, false), FrameVerdict::Inconsistent(-65_536));
        assert_eq!(p.report(&f, f.encode(good, 0) ^ 1, 207, 5, false), FrameVerdict::Ignored, "stop bit wrong");
        assert_eq!(p.report(&f, f.encode(good ^ 1 << 20, 0), 207, 5, true), FrameVerdict::Ignored, "faulted");
    }

    /// EPOS4 AN ch. 8.3's worked example (S1 L8504-8600): 12 single-turn bits, 7 pole pairs, raw 3205, offset 208:
    /// (3205 + 208) x 7 mod 4096 = 3411 -> 299.8 degrees, the 5/6-turn reference (300 degrees) within the
    /// example's rounding of 585.1 increments per electrical turn to whole increments.
    #[test]
    fn commutation_offset_of_the_application_note_gives_its_reference_angle() {
        let a = electrical_angle(3205, 208, 7, 12);
        let degrees = f64::from(a.0) / 4_294_967_296.0 * 360.0;
        assert!((degrees - 300.0).abs() < 1.0, "{degrees}");
        assert_eq!(a.0, (((3205 + 208) * 7) % 4096) << 20);
    }
}
