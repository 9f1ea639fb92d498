//! Commutation: the rotor's electrical angle from the Hall sensors, the incremental encoder and its index, or the
//! SSI absolute encoder.
//! The encoder's own counting (position and electrical count from the hardware counter) is [`super::encoder`].
//!
//! Sources: `shared/spec/control-and-protection.md` §2.6-2.9 (sensor objects, commutation, Hall and index errors
//! 0xFF01/0xFF02/0xFF08; the SSI/encoder "commutation offset", 0...resolution <-> 0...360 degrees electrical;
//! EPOS4's forced alignment with the motor held at a fixed electrical angle by a DC current) and the dictionary
//! objects 0x3001:03 (pole pairs), 0x3010 (encoder: pulses, type, index position), 0x301A (Halls: pattern,
//! commutation offset).
//!
//! # Angle convention
//! Electrical angle 0 = rotor d axis (magnet north) on the phase A axis; positive = the direction in which the
//! encoder counts up (after the 0x3010:02 bit 4 inversion). Hall state bits: bit 0 = H1, bit 1 = H2, bit 2 = H3
//! (EPOS3 0x2022, S0 L4603-4620). The seeds lose the Hall-to-sector figure (spec §2.9 gap, issue 23), so this
//! drive defines it: H1 rises at the 0x301A:03 commutation offset, H2 120 and H3 240 degrees later, each high for
//! 180 degrees; over one electrical turn the states are 5, 1, 3, 2, 6, 4, sector `k` covering
//! `[offset + 60k, offset + 60k + 60)` degrees. 0 and 7 are impossible (spec §2.7, Hall sensor error 0xFF01).
//!
//! # How the angle is built
//! - Exact position: the 16-bit encoder counter is differenced every tick (the wrap of the counter is the wrap of
//!   the `i16` difference, valid while the shaft moves less than 32,767 counts per tick: 480,000 rpm at 4096
//!   counts/rev). The difference feeds the multi-turn position (wrapping `i32` increments) and an **electrical
//!   count** in `[0, cpr)`: mechanical counts x pole pairs modulo the counts per revolution. Both are exact integers;
//!   nothing is accumulated in a float or a rounded angle.
//! - Angle: `electrical count x round(2^32 / cpr) + offset`, wrapping `u32` turns. Exact for a power-of-two cpr
//!   (the reference 4096 counts: 2^20 per count); otherwise the rounding of the per-count step is bounded by
//!   cpr / 2 turn bits (< 1.2e-4 degrees for a 10,000,000-count encoder), and it never accumulates because the
//!   electrical count wraps exactly.
//! - Start with Halls ([`CommutationMethod::Hall`]): the angle starts at the centre of the Hall sector (within
//!   +-30 degrees electrical), then the first Hall edge sets it to the edge's angle (assigned to the midpoint of the
//!   counts of the two samples around the edge, so the error is a fraction of one tick's travel), then the first
//!   index pulse sets it exactly: with a stored index offset (the electrical angle at the index), or, when none is
//!   stored, the drive learns it there from the edge-refined angle and uses it at every later index pulse.
//! - Start without Halls ([`CommutationMethod::ForcedAlignment`]): a d-axis current is injected at a fixed angle
//!   (first 90 degrees, then 0, so that a rotor resting at the unstable point 180 degrees away is still pulled in),
//!   ramped and held; then the angle is zeroed at the encoder count reached. The index refines it as above.
//! - Every index pulse re-applies the stored offset and records the correction made (for the supervision of the
//!   fault issue: index processing and encoder resolution errors 0xFF02/0xFF03).
//! - Start from the SSI absolute encoder alone (`CommutationMethod::Absolute`, 0x3000:03 = 0x20): the angle is the
//!   single-turn position plus the commutation offset 0x3012:0A, times the pole pairs, from the first period
//!   (exact to one sensor increment); the encoder counts are the sensor's 16-bit count (`crate::sensors::ssi`).

use super::encoder::{Encoder, EncoderConfig};
use crate::control::angle::{AngleDelta, ElectricalAngle};
use crate::control::frames::Amps;
use crate::hal::power::FeedbackSample;
use crate::power_state::{CommutationError, CommutationStage};
use crate::sensors::hall::HallSector;
use crate::sensors::ssi::SsiFormat;

/// The Hall commutation offset 0x301A:03 (1/65536 electrical turn) as an angle.
#[must_use]
pub const fn hall_offset_from_od(raw: u16) -> ElectricalAngle {
    ElectricalAngle((raw as u32) << 16)
}

/// The electrical angle of an SSI sensor's position at start-up (`feedback.encoder_count` is its 16-bit count):
/// the single-turn count in the drive's direction plus the commutation offset 0x3012:0A (position increments,
/// IDX L4326: the offset that brings the sensor's zero to the rotor's electrical zero, EPOS4 AN ch. 8.3), times
/// the pole pairs, modulo one revolution. Exact: a revolution is a power of two counts.
fn absolute_angle(ssi: &SsiFormat, encoder: &Encoder, feedback: &FeedbackSample) -> ElectricalAngle {
    let turn = ssi.counts_per_rev().wrapping_sub(1);
    let offset = ssi.commutation_offset.wrapping_shl(u32::from(ssi.align_bits));
    let mechanical = ssi.single_turn(feedback.encoder_count).wrapping_add(offset) & turn;
    let electrical = mechanical.wrapping_mul(u32::from(encoder.config().pole_pairs)) & turn;
    ElectricalAngle(encoder.raw_angle(electrical))
}

/// Forced alignment (no Halls): d current, ramp and hold times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AlignmentConfig {
    /// d-axis current held during alignment.
    pub current: Amps,
    /// Ticks of the current ramp 0 -> `current` at the first angle (90 degrees).
    pub ramp_ticks: u16,
    /// Ticks held at each of the two angles (90 degrees, then 0).
    pub hold_ticks: u16,
    /// Active damping: q current (`I16F16` bits) per encoder count per tick of speed. The d current makes the rotor
    /// a spring around the imposed angle with almost no damping (Coulomb friction only); a q current against the
    /// speed damps the swing so that it has settled when the angle is zeroed.
    pub damping_bits_per_count: i32,
}

impl AlignmentConfig {
    /// For the reference motor: nominal current 3.2 A (the friction of 3 mNm then leaves at most 1.6 degrees
    /// electrical of error), 100 ms ramp, 200 ms hold at each angle.
    ///
    /// Damping for a damping ratio of about 0.7: the spring is kt x I x p = 0.0335 x 3.2 x 7 = 0.75 N m/rad
    /// (mechanical); with the total inertia of 176 g cm^2 the rotor swings at 206 rad/s (33 Hz);
    /// c = 2 x 0.7 x sqrt(0.75 x 1.76e-5) = 5.1 mN m s/rad, i.e. 0.152 A per rad/s, and one count per tick (4,096
    /// counts, 25 kHz) is 38.3 rad/s: 5.83 A = 382,000 bits per count per tick.
    pub const REFERENCE: Self = Self {
        current: Amps::from_bits(3 * 65536 + 13107),
        ramp_ticks: 2500,
        hold_ticks: 5000,
        damping_bits_per_count: 382_000,
    };
}

/// How the commutation starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommutationMethod {
    /// From the Hall sensors (0x3000:03 absolute commutation sensor = Halls).
    Hall,
    /// Without Halls: forced alignment with a d current.
    ForcedAlignment(AlignmentConfig),
    /// From the SSI absolute encoder alone (0x3000:03 = 0x20, IDX L3780): the single-turn position gives the angle
    /// at once, exact to one count; the encoder counts are the sensor's position (tier 1 feeds its 16-bit count,
    /// [`SsiFormat::count16`]).
    Absolute(SsiFormat),
}

/// The forced alignment's current demand for one tick: the angle to use and the d current.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AlignmentDemand {
    /// The imposed electrical angle.
    pub angle: ElectricalAngle,
    /// The d-axis current.
    pub i_d: Amps,
    /// The q-axis damping current.
    pub i_q: Amps,
}

/// The commutation state: encoder, offsets, stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Commutation {
    method: CommutationMethod,
    encoder: Encoder,
    /// Electrical angle at electrical count 0.
    offset: u32,
    stage: CommutationStage,
    hall_offset: ElectricalAngle,
    last_sector: Option<HallSector>,
    index_offset: Option<ElectricalAngle>,
    last_index_latch: Option<u16>,
    last_index_correction: AngleDelta,
    index_pulses: u32,
    /// No encoder: the Halls alone give the angle (sector centres, updated at each edge).
    hall_only: bool,
    /// The angle was indexed since this commutation was built: the encoder has kept counting since, so a restart
    /// (re-enable) keeps the indexed angle instead of falling back to the Hall sector.
    indexed: bool,
    align_ticks: u32,
    align_current: i32,
    align_step: i32,
    /// Low-pass filtered encoder speed during alignment, counts per tick, Q8.
    align_speed_q8: i32,
    angle: ElectricalAngle,
}

impl Commutation {
    /// A commutation that has not started. `index_offset` is the stored electrical angle at the index pulse, if
    /// known (else it is learned at the first index pulse).
    #[must_use]
    pub fn new(
        method: CommutationMethod,
        encoder: EncoderConfig,
        hall_offset: ElectricalAngle,
        index_offset: Option<ElectricalAngle>,
    ) -> Self {
        Self {
            method,
            encoder: Encoder::new(encoder),
            offset: 0,
            stage: CommutationStage::Unknown,
            hall_offset,
            last_sector: None,
            index_offset,
            last_index_latch: None,
            last_index_correction: AngleDelta::ZERO,
            index_pulses: 0,
            indexed: false,
            hall_only: false,
            align_ticks: 0,
            align_current: 0,
            align_step: 0,
            align_speed_q8: 0,
            angle: ElectricalAngle::ZERO,
        }
    }

    /// Starts (or restarts) the commutation from the sensors' state now, after [`Commutation::update`] took the
    /// same sample: the angle comes from the Hall sector at the encoder's count now (or forced alignment begins).
    /// The encoder keeps counting across starts; a known index offset is kept.
    pub fn start(&mut self, feedback: &FeedbackSample) -> Result<(), CommutationError> {
        if self.indexed {
            // The offset set at the last index still holds: the electrical count was tracked while stopped.
            if let CommutationMethod::Hall = self.method {
                self.last_sector = Some(HallSector::from_state(feedback.hall)?);
            }
            self.stage = CommutationStage::Indexed;
            self.angle = self.current_angle();
            return Ok(());
        }
        match self.method {
            CommutationMethod::Hall => {
                let sector = HallSector::from_state(feedback.hall)?;
                self.last_sector = Some(sector);
                self.set_angle_at(self.encoder.electrical_count(), sector.centre_angle(self.hall_offset));
                self.stage = CommutationStage::HallSector;
            }
            CommutationMethod::Absolute(ssi) => {
                self.last_sector = None;
                self.set_angle_at(self.encoder.electrical_count(), absolute_angle(&ssi, &self.encoder, feedback));
                self.stage = CommutationStage::Indexed;
            }
            CommutationMethod::ForcedAlignment(cfg) => {
                self.last_sector = None;
                self.stage = CommutationStage::Aligning;
                self.align_ticks = 0;
                self.align_current = 0;
                self.align_speed_q8 = 0;
                let ramp = i32::from(cfg.ramp_ticks.max(1));
                self.align_step = cfg.current.to_bits().checked_div(ramp).unwrap_or(0).max(1);
            }
        }
        self.angle = self.current_angle();
        Ok(())
    }

    /// The identification procedure takes over the angle (`super::identification`): only the encoder is tracked
    /// until [`Commutation::stop`] and a new [`Commutation::start`]. A learned index offset is kept.
    pub fn begin_injection(&mut self) {
        self.stage = CommutationStage::Injecting;
    }

    /// Without an encoder (0x3000:01 sensor 1 none) the angle comes from the Hall sectors alone.
    pub fn set_hall_only(&mut self, hall_only: bool) {
        self.hall_only = hall_only;
    }

    /// Back to not started (outputs off, e.g. on a fault). Keeps the learned index offset.
    pub fn stop(&mut self) {
        self.stage = CommutationStage::Unknown;
    }

    #[inline(always)]
    fn current_angle(&self) -> ElectricalAngle {
        ElectricalAngle(self.encoder.raw_angle(self.encoder.electrical_count()).wrapping_add(self.offset))
    }

    /// Sets the offset so that the electrical count `count` has the angle `angle`.
    fn set_angle_at(&mut self, count: u32, angle: ElectricalAngle) {
        self.offset = angle.0.wrapping_sub(self.encoder.raw_angle(count));
    }

    /// One tick: reads the encoder, the index latch and the Halls; returns the electrical angle. Before
    /// [`Commutation::start`] (stage `Unknown`) only the encoder is tracked. An invalid Hall state is an error
    /// whenever Halls are the configured commutation sensor and the commutation runs, even after indexing (spec
    /// §2.7, Hall sensor error 0xFF01).
    #[inline]
    pub fn update(&mut self, feedback: &FeedbackSample) -> Result<ElectricalAngle, CommutationError> {
        self.encoder.update(feedback.encoder_count);
        // Not started, or the identification imposes the angle: the encoder alone is tracked (one compare for
        // both: the two stages are adjacent).
        if matches!(self.stage, CommutationStage::Unknown | CommutationStage::Injecting) {
            if let Some(latch) = feedback.index_latch {
                self.last_index_latch = Some(latch);
            }
            return Ok(self.angle);
        }
        if let CommutationMethod::Hall = self.method {
            let sector = HallSector::from_state(feedback.hall)?;
            if self.stage == CommutationStage::HallSector {
                self.refine_at_hall_edge(sector);
            } else if self.stage == CommutationStage::HallEdge && self.hall_only && self.last_sector != Some(sector) {
                // No encoder to carry the angle between edges: every edge sets it, to the centre of the sector
                // just entered (+-30 degrees electrical at most, no lag on average).
                self.set_angle_at(self.encoder.electrical_count(), sector.centre_angle(self.hall_offset));
            }
            self.last_sector = Some(sector);
        }
        if let Some(latch) = feedback.index_latch {
            if self.encoder.config().has_index {
                self.on_index(latch);
            }
        }
        self.angle = self.current_angle();
        Ok(self.angle)
    }

    /// First Hall edge after a sector start: the angle there is the edge's.
    fn refine_at_hall_edge(&mut self, sector: HallSector) {
        let Some(previous) = self.last_sector else { return };
        let edge = if sector == previous.next() {
            sector.start_angle(self.hall_offset)
        } else if sector == previous.previous() {
            previous.start_angle(self.hall_offset)
        } else {
            // Same sector (no edge), or two sectors in one tick (too fast to tell where): wait for the next edge.
            return;
        };
        // The edge lay between the last two samples: assign it to their midpoint.
        let now = edge.wrapping_add(self.encoder.half_last_step());
        self.set_angle_at(self.encoder.electrical_count(), now);
        self.stage = CommutationStage::HallEdge;
    }

    /// An index pulse latched the counter at `latch`.
    fn on_index(&mut self, latch: u16) {
        self.last_index_latch = Some(latch);
        self.index_pulses = self.index_pulses.wrapping_add(1);
        let count = self.encoder.electrical_count_at(latch);
        let estimate = ElectricalAngle(self.encoder.raw_angle(count).wrapping_add(self.offset));
        match self.index_offset {
            Some(stored) if self.stage != CommutationStage::Aligning && self.stage != CommutationStage::Unknown => {
                self.last_index_correction = stored.difference(estimate);
                self.set_angle_at(count, stored);
                self.stage = CommutationStage::Indexed;
                self.indexed = true;
            }
            None if matches!(self.stage, CommutationStage::HallEdge | CommutationStage::Aligned) => {
                self.index_offset = Some(estimate);
                self.last_index_correction = AngleDelta::ZERO;
                self.stage = CommutationStage::Indexed;
                self.indexed = true;
            }
            _ => {}
        }
    }

    /// During forced alignment: the angle and d current for this tick (advances the alignment by one tick);
    /// `None` when not aligning. At the end of the second hold the angle is zeroed at the encoder count reached.
    pub fn alignment_demand(&mut self) -> Option<AlignmentDemand> {
        let CommutationMethod::ForcedAlignment(cfg) = self.method else { return None };
        if self.stage != CommutationStage::Aligning {
            return None;
        }
        let ramp = u32::from(cfg.ramp_ticks);
        let hold = u32::from(cfg.hold_ticks);
        let t = self.align_ticks;
        self.align_ticks = t.saturating_add(1);
        let first = ramp.saturating_add(hold);
        let angle = if t < first { ElectricalAngle::QUARTER_TURN } else { ElectricalAngle::ZERO };
        if t < ramp {
            self.align_current = self.align_current.saturating_add(self.align_step).min(cfg.current.to_bits());
        } else {
            self.align_current = cfg.current.to_bits();
        }
        if t >= first.saturating_add(hold) {
            // Aligned: the rotor's d axis sits at angle 0.
            self.set_angle_at(self.encoder.electrical_count(), ElectricalAngle::ZERO);
            self.stage = CommutationStage::Aligned;
            self.angle = self.current_angle();
            return None;
        }
        // Speed: first-order low-pass of the counts per tick, time constant 16 ticks (0.64 ms). |delta| <= 2^15,
        // so the Q8 values stay within 2^23 and nothing wraps.
        let delta_q8 = self.encoder.last_delta().clamp(-32_768, 32_767) << 8;
        self.align_speed_q8 = self.align_speed_q8.wrapping_add(delta_q8.wrapping_sub(self.align_speed_q8) >> 4);
        let damping = i64::from(self.align_speed_q8).wrapping_mul(i64::from(cfg.damping_bits_per_count)) >> 8;
        let limit = i64::from(cfg.current.to_bits());
        // Clamped to +-the alignment current (< 2^31, not negative): the conversion is exact. Max/min: `clamp`
        // would assert the bounds' order with a formatted panic (flash in the images that print panics, issue 17).
        let i_q = Amps::from_bits(damping.wrapping_neg().max(limit.wrapping_neg()).min(limit) as i32);
        Some(AlignmentDemand { angle, i_d: Amps::from_bits(self.align_current), i_q })
    }

    /// Sets the Hall offset (0x301A:03) for the next start.
    pub fn set_hall_offset(&mut self, offset: ElectricalAngle) {
        self.hall_offset = offset;
    }

    /// The configured start method.
    #[must_use]
    pub const fn method(&self) -> CommutationMethod {
        self.method
    }

    /// The Hall offset in use (0x301A:03).
    #[must_use]
    pub const fn hall_offset(&self) -> ElectricalAngle {
        self.hall_offset
    }

    /// The angle computed by the last [`Commutation::update`].
    #[must_use]
    pub const fn angle(&self) -> ElectricalAngle {
        self.angle
    }

    /// How well the angle is known.
    #[must_use]
    pub const fn stage(&self) -> CommutationStage {
        self.stage
    }

    /// The encoder.
    #[must_use]
    pub const fn encoder(&self) -> &Encoder {
        &self.encoder
    }

    /// The electrical angle at the index pulse (stored or learned).
    #[must_use]
    pub const fn index_offset(&self) -> Option<ElectricalAngle> {
        self.index_offset
    }

    /// Sets (or forgets) the stored index offset.
    pub fn set_index_offset(&mut self, offset: Option<ElectricalAngle>) {
        if offset != self.index_offset {
            // A different angle at the index: the indexed offset no longer holds until the next index pulse.
            self.indexed = false;
        }
        self.index_offset = offset;
    }

    /// The counter value latched at the last index pulse (0x3010:04).
    #[must_use]
    pub const fn last_index_latch(&self) -> Option<u16> {
        self.last_index_latch
    }

    /// The correction the last index pulse applied to the angle (stored offset minus the estimate before it).
    #[must_use]
    pub const fn last_index_correction(&self) -> AngleDelta {
        self.last_index_correction
    }

    /// Index pulses seen since the start (wrapping).
    #[must_use]
    pub const fn index_pulses(&self) -> u32 {
        self.index_pulses
    }

    /// The Hall sector seen last (Hall method only).
    #[must_use]
    pub const fn hall_sector(&self) -> Option<HallSector> {
        self.last_sector
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEG: f64 = 4_294_967_296.0 / 360.0;

    fn deg(a: ElectricalAngle) -> f64 {
        f64::from(a.0) / DEG
    }

    fn fb(count: u16, hall: u8, index: Option<u16>) -> FeedbackSample {
        FeedbackSample { encoder_count: count, index_latch: index, hall, digital_inputs: 0, ssi_frame: 0 }
    }

    /// The drive's order: update with the sample, then start from it.
    fn begin(c: &mut Commutation, sample: FeedbackSample) -> Result<(), CommutationError> {
        c.update(&sample)?;
        c.start(&sample)
    }

    /// Hall state of the reference plant's convention at an electrical angle in degrees (offset 0).
    fn hall_at(e_deg: f64) -> u8 {
        crate::sensors::hall::HALL_SEQUENCE[(e_deg.rem_euclid(360.0) / 60.0) as usize]
    }

    #[test]
    fn hall_start_then_edge_then_index() {
        // Reference plant: count 0 = electrical 0, index at count 0, Halls with offset 0.
        // Start at mechanical count 1000 (electrical 1000 * 7 * 360 / 4096 = 615.2 -> 255.2 degrees, sector 4).
        let cpr = 4096.0;
        let e_of = |count: i64| (count as f64 * 7.0 / cpr * 360.0).rem_euclid(360.0);
        let mut c = Commutation::new(CommutationMethod::Hall, EncoderConfig::REFERENCE, ElectricalAngle::ZERO, None);
        assert!(!c.stage().is_valid());
        let start = 1000i64;
        begin(&mut c, fb(start as u16, hall_at(e_of(start)), None)).unwrap();
        assert_eq!(c.stage(), CommutationStage::HallSector);
        assert!((deg(c.angle()) - 270.0).abs() < 1e-6, "sector centre");
        // Move forward 2 counts per tick until the next Hall edge (300 degrees, count 487.6 + 585.1 = 1072.4).
        let mut count = start;
        let mut stage_at_edge = None;
        while count < 1100 {
            count += 2;
            let a = c.update(&fb(count as u16, hall_at(e_of(count)), None)).unwrap();
            if c.stage() == CommutationStage::HallEdge && stage_at_edge.is_none() {
                stage_at_edge = Some(count);
                // Error within one tick's travel (2 counts = 4.1 degrees electrical), half of it on average.
                let err = deg(a) - e_of(count);
                assert!(err.abs() < 2.5, "edge refinement error {err} deg at {count}");
            }
        }
        assert_eq!(stage_at_edge, Some(1074));
        // No index stored: the first index pulse (count 4096) learns the offset from the edge-refined angle.
        while count < 4096 + 10 {
            count += 3;
            let latch = (count - 3 < 4096 && count >= 4096).then_some(4096u16);
            c.update(&fb(count as u16, hall_at(e_of(count)), latch)).unwrap();
        }
        assert_eq!(c.stage(), CommutationStage::Indexed);
        let learned = deg(c.index_offset().unwrap());
        assert!((learned + 180.0).rem_euclid(360.0) - 180.0 < 2.5, "learned index offset {learned}");
        // A stored exact offset (0: the plant's index is at electrical 0) corrects the angle at the next index.
        c.set_index_offset(Some(ElectricalAngle::ZERO));
        while count < 2 * 4096 + 10 {
            count += 3;
            let latch = (count - 3 < 8192 && count >= 8192).then_some(8192u16);
            c.update(&fb(count as u16, hall_at(e_of(count)), latch)).unwrap();
        }
        let err = (deg(c.angle()) - e_of(count) + 180.0).rem_euclid(360.0) - 180.0;
        assert!(err.abs() < 1e-6, "indexed angle exact: {err}");
        assert!(f64::from(c.last_index_correction().0).abs() / DEG < 2.5);
        assert_eq!(c.last_index_latch(), Some(8192));
    }

    #[test]
    fn stored_index_offset_applies_at_the_first_pulse_even_from_a_sector_start() {
        let mut c = Commutation::new(
            CommutationMethod::Hall,
            EncoderConfig::REFERENCE,
            ElectricalAngle::ZERO,
            Some(ElectricalAngle::ZERO),
        );
        // Start just below the index (count 4090 -> 4096 + 2), moving backwards through it.
        begin(&mut c, fb(4100, hall_at(4100.0 * 7.0 * 360.0 / 4096.0), None)).unwrap();
        let a = c.update(&fb(4094, hall_at(4094.0 * 7.0 * 360.0 / 4096.0), Some(4096))).unwrap();
        assert_eq!(c.stage(), CommutationStage::Indexed);
        assert_eq!(a.0, (4094u32 * 7) << 20);
    }

    #[test]
    fn invalid_hall_states_are_errors() {
        let mut c = Commutation::new(CommutationMethod::Hall, EncoderConfig::REFERENCE, ElectricalAngle::ZERO, None);
        assert_eq!(begin(&mut c, fb(0, 0, None)), Err(CommutationError::InvalidHallState(0)));
        begin(&mut c, fb(0, 5, None)).unwrap();
        assert_eq!(c.update(&fb(1, 7, None)), Err(CommutationError::InvalidHallState(7)));
    }

    #[test]
    fn forced_alignment_sequence() {
        let cfg = AlignmentConfig {
            current: Amps::from_milliamps(2000),
            ramp_ticks: 10,
            hold_ticks: 20,
            damping_bits_per_count: 1000,
        };
        let mut c = Commutation::new(
            CommutationMethod::ForcedAlignment(cfg),
            EncoderConfig::REFERENCE,
            ElectricalAngle::ZERO,
            None,
        );
        begin(&mut c, fb(123, 0, None)).unwrap();
        assert_eq!(c.stage(), CommutationStage::Aligning);
        assert!(!c.stage().is_valid());
        let mut demands = Vec::new();
        for _ in 0..100 {
            c.update(&fb(123, 0, None)).unwrap(); // Halls are ignored without the Hall method
            match c.alignment_demand() {
                Some(d) => demands.push(d),
                None => break,
            }
        }
        assert_eq!(demands.len(), 50);
        assert_eq!(demands[0].angle, ElectricalAngle::QUARTER_TURN);
        assert!(demands[0].i_d.to_milliamps() > 0 && demands[0].i_d.to_milliamps() <= 201);
        assert_eq!(demands[9].i_d.to_milliamps(), 2000);
        assert_eq!(demands[29].angle, ElectricalAngle::QUARTER_TURN);
        assert_eq!(demands[30].angle, ElectricalAngle::ZERO);
        assert_eq!(c.stage(), CommutationStage::Aligned);
        assert_eq!(c.angle(), ElectricalAngle::ZERO);
        // Moving 100 counts forward: 100 * 7 * 2^20 turn bits.
        let a = c.update(&fb(223, 0, None)).unwrap();
        assert_eq!(a.0, 700u32 << 20);
        // The first index pulse learns the offset.
        c.update(&fb(230, 0, Some(225))).unwrap();
        assert_eq!(c.stage(), CommutationStage::Indexed);
        assert_eq!(c.index_offset(), Some(ElectricalAngle((102u32 * 7) << 20)));
    }
}
