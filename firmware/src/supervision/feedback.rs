//! Encoder and Hall sensor supervision: the four checks of the position sensors that need more than one sample
//! or more than one sensor, run at 2.5 kHz from [`SupervisionInputs`] (issue 5, "Detection, each in the tier
//! where it belongs").
//!
//! Sources: `shared/spec/control-and-protection.md` §2.7 (Hall sensor error 0xFF01 "impossible Hall
//! combination", index processing error 0xFF02 "no index within two turns ... or index pulses at unexpected
//! positions (noise)", Hall angle detection error 0xFF08 "encoder angle vs Hall angle difference too large",
//! position sensor breach 0x7380 "broken wiring, defective encoder"; S0 L931-1098, S2 L7266-7272, S4
//! L1060-1075), with the codes of `crate::fault::table` (0xFF05, 0x7122, 0x7320, 0x7380). The Hall convention
//! (states 5, 1, 3, 2, 6, 4 over one electrical turn from the 0x301A:03 offset) is
//! [`crate::drive::commutation`]'s.
//!
//! # The checks (reference figures: 7 pole pairs, 4,096 counts per turn, 0x6080 = 5,000 rpm)
//! 1. **Invalid Hall state** ([`FaultId::HallInvalidState`], level): 000 or 111 for [`INVALID_HALL_TICKS`]
//!    consecutive slow ticks while the Halls are configured and the power stage is powered (calibrating,
//!    switched on or enabled). Tier 1 already trips on the first invalid sample while the commutation runs with
//!    the Halls; this check covers the powered states where it does not look (calibration, «Switched on»). Two
//!    ticks (0.4 to 0.8 ms) filter a single disturbed read; a real Hall transition never passes through 000 or
//!    111 (the sensors switch 60 degrees apart). The cause stays present, also in «Fault», while the state is
//!    invalid, so a fault reset is refused until the Halls read a valid state again.
//! 2. **Hall/encoder mismatch** ([`FaultId::HallEncoderMismatch`], event): while the commutation angle is
//!    measured (stage [`CommutationStage::HallEdge`] or [`CommutationStage::Indexed`]) and an encoder and the
//!    Halls are both configured, the angle tier 1 commutates with must lie in the Hall sector read in the same
//!    fast tick, widened on both sides by a tolerance (see [`MismatchTolerance`]; 23.2 degrees electrical for the
//!    reference motor, so an angle more than 53.2 degrees from the sector's centre disagrees), for
//!    [`MISMATCH_TICKS`] consecutive slow ticks. Both signals are sampled in the same fast tick, so the speed
//!    enters only through the angle's own error, not through the 0.4 ms between slow ticks (84 degrees electrical
//!    per slow tick at 5,000 rpm: comparing samples of different ticks would not work at all). A stopped encoder
//!    counter also makes the angle disagree; while check 4 suspects one, the disagreement is held for up to
//!    [`MISMATCH_HOLD_TICKS`] so that 0x603F names the root cause, and it is not compared at all once the
//!    encoder signal loss is active.
//! 3. **Encoder index** ([`FaultId::EncoderIndexMissing`], event), with an index channel configured: the axis has
//!    moved more than [`INDEX_MISSING_TURNS_X2`] / 2 turns (in counts) from the last index pulse, or from where the
//!    watch started, without a new one (any stretch of the path longer than one turn contains the index);
//!    and each new index must lie a whole number of turns from the previous one within
//!    [`INDEX_POSITION_TOLERANCE`] counts: a displaced index means counts were lost or added (a noise burst),
//!    and the position is no longer valid. The snapshot's detail is the counts moved (missing) or the count
//!    error (displaced).
//! 4. **Encoder signal loss** ([`FaultId::EncoderSignalLoss`], level), with the Halls configured as a
//!    cross-check: whenever the Halls have advanced by two sectors in the same direction (120 degrees electrical
//!    expected, more than 60 degrees certain, see [`SignalLossWatch`]), the encoder must have moved at least a
//!    quarter of the counts of those two sectors in that direction (48.8 counts for the reference motor, which
//!    moves at least 97.5 counts over more than one sector); and the Halls must not pass two sectors in one
//!    direction without the counter changing at all. Otherwise (a frozen counter, a broken A/B line, a counter
//!    that only dithers or runs the wrong way) the fault is raised; the cause clears at the next window in which
//!    the encoder and the Halls agree again, so a reset is refused until the encoder is seen to count while the
//!    shaft turns. Without Halls there is no second sensor to compare with: a lost encoder then shows as a
//!    following error (0x8611, the position loop pushes while the position does not move) or as the stall
//!    supervision's «motor blocked» (the current at its limit with no motion).
//!
//! Checks 2, 3 and 4 watch the main sensor (the encoder); bit 8 of 0x3000:04 "main sensor supervision disabled"
//! (IDX Table 6-98) turns them off: their watches restart and their causes clear, so a fault they raised can be
//! reset. Check 1 watches the Halls and stays on.
//!
//! Checks 3 and 4 run in every state (the position is published in every state, and a sensor fault found with
//! the outputs off is still a fault); entering the offset calibration (switch-on) restarts them, because
//! `Drive::switch_on` re-reads the sensor configuration and may restart the encoder's position at 0.
//!
//! # Why none of them trips on a healthy drive up to 0x6080
//! 1 cannot: a healthy sensor never reads 000 or 111. 2: the angle error of the commutation is at most one count
//! when indexed and half a fast tick's travel plus one count after a Hall edge; the tolerance holds one and a half
//! fast ticks' travel at 0x6080 (8.4 degrees per tick for the reference: 12.6), one count (0.6) and 10 degrees for
//! the placement of the Hall sensors, so a healthy drive stays at least 10 degrees inside it. 3: the index is
//! latched in hardware on the counter (exact in the plant, one count either way on real encoders), against 4
//! counts of tolerance; between index pulses the shaft turns once, 2,048 counts short of the 1.5 turns, and the
//! watch sees each pulse at most one slow tick (136 counts at 5,000 rpm) after it.
//! 4: two Hall sectors in the same direction mean more than 60 degrees of travel (97.5 counts) against a
//! threshold of 48.8; at 5,000 rpm the Halls move 1.4 sectors per slow tick, so a step of 3 sectors (ambiguous in
//! direction) never happens and a step of 2 is counted as 2.

use super::SupervisionInputs;
use crate::control::angle::ElectricalAngle;
use crate::fault::{FaultId, FaultManager};
use crate::hal::power::PWM_FREQUENCY_HZ;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::power_state::{CommutationStage, PowerState};
use crate::sensors::hall::HallSector;

/// Bit 8 of 0x3000:04 "axis configuration miscellaneous": main sensor supervision disabled (IDX Table 6-98).
pub const MAIN_SENSOR_SUPERVISION_DISABLED: u32 = 1 << 8;
/// Consecutive slow ticks of an invalid Hall state before [`FaultId::HallInvalidState`] (0.4 to 0.8 ms).
pub const INVALID_HALL_TICKS: u8 = 2;
/// Consecutive slow ticks of disagreement before [`FaultId::HallEncoderMismatch`] (1.2 ms): one disturbed Hall
/// read cannot trip it, and the angle error it reports has to be there for 30 fast ticks.
pub const MISMATCH_TICKS: u8 = 3;
/// Consecutive disagreeing slow ticks that are not counted while [`SignalLossWatch::encoder_stopped`] suspects
/// a stopped counter (10 ms): a stopped counter makes the angle disagree with the Halls as soon as the rotor has
/// left the sector, and the root cause (0x603F) is the signal loss, which check 4 reports at the second sector.
/// Above 143 rpm (one sector, 1/42 turn, in 10 ms) the rotor gets there within the hold; below it, or if the
/// rotor stops after one sector, the mismatch is reported after the hold instead.
pub const MISMATCH_HOLD_TICKS: u8 = 25;
/// Twice the travel without an index pulse, in turns, after which [`FaultId::EncoderIndexMissing`] is raised
/// (1.5 turns: more than the one turn that always contains the index, with half a turn for the latch's
/// tolerances; the seeds allow two turns at start-up, spec §2.7 0xFF02).
pub const INDEX_MISSING_TURNS_X2: u32 = 3;
/// Counts by which an index may lie off a whole number of turns from the previous one (the hardware latch is
/// exact to one count in either direction of travel; a noise burst adds many).
pub const INDEX_POSITION_TOLERANCE: i32 = 4;

/// One sixth of an electrical turn (60 degrees, one Hall sector) in turn bits, rounded.
const SIXTH_TURN: u32 = 715_827_883;
/// The allowance for the placement of the Hall sensors on the stator (and their switching hysteresis): 10
/// degrees electrical, `2^32 x 10 / 360`. The reference plant's Halls are exact.
const HALL_PLACEMENT: u32 = 119_304_647;

/// The tolerance of the Hall/encoder comparison, from 0x6080 (max motor speed), the pole pairs and the counts per
/// turn (re-computed only when one of them changes).
///
/// `tolerance = 10 degrees + 1.5 x (electrical travel of one fast tick at 0x6080) + one count`, at most 30
/// degrees (beyond that the widened sector would span two sectors and the check would mean nothing). The travel
/// covers the angle's error after a Hall edge (half a fast tick: the edge is placed at the midpoint of the two
/// samples around it) and a skew of up to one fast tick between the Hall read and the counter read. Reference:
/// 5,000 rpm x 7 / 60 / 25,000 = 0.0233 turn = 8.4 degrees per tick, so 10 + 12.6 + 0.6 = 23.2 degrees.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MismatchTolerance {
    /// 0x6080, rpm.
    max_speed_rpm: u32,
    pole_pairs: u8,
    counts_per_turn: u32,
    /// Half a sector plus the tolerance, turn bits: the largest healthy distance from the sector's centre.
    limit: u32,
}

impl MismatchTolerance {
    /// The tolerance for these parameters.
    #[must_use]
    pub fn new(max_speed_rpm: u32, pole_pairs: u8, counts_per_turn: u32) -> Self {
        let pp = u64::from(pole_pairs.max(1));
        // Electrical turns per fast tick at the max speed, in turn bits: rpm x pp x 2^32 / (60 x f_pwm). The
        // product is below 2^32 x 2^8 x 2^32 = 2^72: exact in u128 for any u32 0x6080 (its range ends at 25,000).
        let per_tick = u128::from(max_speed_rpm)
            .saturating_mul(u128::from(pp))
            .saturating_mul(1u128 << 32)
            .checked_div(60u128.saturating_mul(u128::from(PWM_FREQUENCY_HZ)))
            .unwrap_or(0);
        let travel = per_tick.saturating_mul(3) / 2;
        let count = (u128::from(pp) << 32).checked_div(u128::from(counts_per_turn.max(1))).unwrap_or(0);
        let tolerance = u128::from(HALL_PLACEMENT).saturating_add(travel).saturating_add(count);
        let tolerance = u32::try_from(tolerance.min(u128::from(SIXTH_TURN / 2))).unwrap_or(SIXTH_TURN / 2);
        Self { max_speed_rpm, pole_pairs, counts_per_turn, limit: (SIXTH_TURN / 2).saturating_add(tolerance) }
    }

    /// The largest distance of a healthy angle from the Hall sector's centre, in turn bits.
    #[must_use]
    pub const fn limit(&self) -> u32 {
        self.limit
    }

    /// The tolerance beyond the sector's edges, in turn bits.
    #[must_use]
    pub const fn tolerance(&self) -> u32 {
        self.limit.saturating_sub(SIXTH_TURN / 2)
    }
}

/// The index watch (check 3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct IndexWatch {
    /// Watching (an encoder with index is configured and the watch has its start).
    tracking: bool,
    /// `index_pulses` at the last step.
    seen: u32,
    /// Position of the last index pulse seen since the watch started.
    last_index: Option<i32>,
    /// Where the travel without an index is measured from: the last index, or the watch's start.
    origin: i32,
}

/// The Hall-counted travel that the encoder must follow (check 4).
///
/// The Hall sector is read every slow tick. Two criteria, both on sectors passed in one direction:
/// - **Windows**: `steps` counts the sectors passed since the sample at `reference_position`. A sample in sector
///   `S` and a later one in `S + 2` are more than 60 degrees electrical apart, whatever happened in between (the
///   rotor crossed both edges after the first sample), and less than 180. When two sectors have passed, the
///   encoder must have moved at least a quarter of the counts of two sectors in that direction; then the window
///   restarts here. This catches a counter that stops, runs backwards or only dithers (one broken channel of the
///   quadrature pair makes the counter toggle by one count without getting anywhere).
/// - **Stopped counter**: `still_steps` counts the sectors passed since the encoder last changed at all. Two mean
///   a stopped counter at once, without waiting for a window that began before it stopped (a window may hold
///   counts from before the break and still agree).
///
/// A reversal restarts both counts at the sample that showed it (the rotor dithering across a Hall edge never
/// makes two steps); a step of 3 sectors (direction unknown, only above 1.5 x the reference's 0x6080) restarts the
/// window too.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SignalLossWatch {
    last_sector: Option<HallSector>,
    steps: i32,
    reference_position: i32,
    last_position: i32,
    still_steps: i32,
}

/// What [`SignalLossWatch::step`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SignalCheck {
    /// A window closed with the encoder following the Halls.
    Agrees,
    /// The encoder moved this many counts (in the Halls' direction) over two sectors: less than a quarter of the
    /// expected counts, or nothing at all since it stopped.
    Lost(i32),
}

/// Sectors passed from `previous` to `now`: -2..=2, or `None` for 3 (direction unknown).
fn sector_step(previous: HallSector, now: HallSector) -> Option<i32> {
    // Sectors moved forward, modulo 6 (both indices are 0..=5).
    match now.index().wrapping_add(6).wrapping_sub(previous.index()) % 6 {
        0 => Some(0),
        1 => Some(1),
        2 => Some(2),
        4 => Some(-2),
        5 => Some(-1),
        _ => None,
    }
}

/// The count `total` continued by `step`: their sum when both go the same way, 0 after a reversal (the count
/// starts afresh at the sample that showed it).
fn same_direction(total: i32, step: i32) -> i32 {
    if total != 0 && (total > 0) != (step > 0) {
        0
    } else {
        total.saturating_add(step)
    }
}

impl SignalLossWatch {
    /// Forgets the travel (sensors not both configured, invalid Hall state, restart).
    pub fn restart(&mut self) {
        *self = Self::default();
    }

    /// The Halls have left the sector they showed when the encoder last moved, and the encoder has not moved
    /// since: a stopped counter is suspected (the Hall/encoder comparison leaves it to this check).
    #[must_use]
    pub const fn encoder_stopped(&self) -> bool {
        self.still_steps != 0
    }

    /// One sample: the Hall sector and the encoder position of the same fast tick.
    pub fn step(
        &mut self,
        sector: HallSector,
        position: i32,
        counts_per_turn: u32,
        pole_pairs: u8,
    ) -> Option<SignalCheck> {
        let moved_now = position != self.last_position;
        self.last_position = position;
        let Some(previous) = self.last_sector.replace(sector) else {
            self.steps = 0;
            self.still_steps = 0;
            self.reference_position = position;
            return None;
        };
        if moved_now {
            self.still_steps = 0;
        }
        let Some(step) = sector_step(previous, sector) else {
            self.steps = 0;
            self.still_steps = 0;
            self.reference_position = position;
            return None;
        };
        if step == 0 {
            return None;
        }
        if !moved_now {
            self.still_steps = same_direction(self.still_steps, step);
            if self.still_steps.unsigned_abs() >= 2 {
                self.still_steps = 0;
                self.steps = 0;
                self.reference_position = position;
                return Some(SignalCheck::Lost(0));
            }
        }
        self.steps = same_direction(self.steps, step);
        if self.steps == 0 {
            self.reference_position = position;
        }
        if self.steps.unsigned_abs() < 2 {
            return None;
        }
        let moved = position.wrapping_sub(self.reference_position);
        let along = if self.steps > 0 { moved } else { moved.wrapping_neg() };
        // Expected: |steps| x cpr / (6 x pp) counts; lost below a quarter of it:
        // along x 24 x pp < |steps| x cpr (i64: |along| < 2^31, 24 x 255 < 2^13).
        let lhs = i64::from(along).saturating_mul(24).saturating_mul(i64::from(pole_pairs.max(1)));
        let rhs = i64::from(self.steps.unsigned_abs()).saturating_mul(i64::from(counts_per_turn));
        self.steps = 0;
        self.reference_position = position;
        Some(if lhs < rhs { SignalCheck::Lost(along) } else { SignalCheck::Agrees })
    }
}

/// Encoder and Hall sensor supervision. See the module documentation.
#[derive(Clone, Debug, Default)]
pub struct FeedbackSupervision {
    /// 0x6080 as last read.
    max_speed_rpm: u32,
    tolerance: MismatchTolerance,
    invalid_hall_ticks: u8,
    mismatch_ticks: u8,
    /// Disagreeing ticks held in a row while a stopped counter is suspected.
    held_ticks: u8,
    index: IndexWatch,
    signal: SignalLossWatch,
    /// Bit 8 of 0x3000:04 clear: checks 2 to 4 run.
    main_sensor_supervised: bool,
}

impl FeedbackSupervision {
    /// Over the parameters of `d` (0x6080).
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut s = Self::default();
        s.refresh(d);
        s
    }

    /// Re-reads 0x6080 (max motor speed), which sets the Hall/encoder tolerance, and bit 8 of 0x3000:04 (main
    /// sensor supervision disabled).
    pub fn refresh(&mut self, d: &Dictionary) {
        self.max_speed_rpm = d.get(h::MAX_MOTOR_SPEED);
        self.main_sensor_supervised = d.get(h::AXIS_CONFIGURATION_MISC) & MAIN_SENSOR_SUPERVISION_DISABLED == 0;
    }

    /// Bit 8 of 0x3000:04 "main sensor supervision disabled" is clear: the main sensor's checks run (these and
    /// [`super::direction`]).
    #[must_use]
    pub const fn main_sensor_supervised(&self) -> bool {
        self.main_sensor_supervised
    }

    /// The Hall/encoder tolerance in use.
    #[must_use]
    pub const fn tolerance(&self) -> &MismatchTolerance {
        &self.tolerance
    }

    /// One slow tick: raises and clears this detector's faults.
    pub fn step(&mut self, inputs: &SupervisionInputs, faults: &mut FaultManager) {
        let sector = HallSector::from_state(inputs.hall).ok();
        // Entering the calibration (switch-on) may restart the encoder's position: the position watches restart.
        let restart = matches!(inputs.power, PowerState::Calibrating);
        self.invalid_hall(inputs, sector.is_none(), faults);
        if !self.main_sensor_supervised {
            self.index = IndexWatch::default();
            self.signal = SignalLossWatch::default();
            (self.mismatch_ticks, self.held_ticks) = (0, 0);
            for id in [FaultId::EncoderSignalLoss, FaultId::HallEncoderMismatch, FaultId::EncoderIndexMissing] {
                faults.clear_cause(id);
            }
            return;
        }
        self.signal_loss(inputs, sector, restart, faults);
        self.mismatch(inputs, sector, faults);
        self.index(inputs, restart, faults);
    }

    /// Check 1.
    fn invalid_hall(&mut self, inputs: &SupervisionInputs, invalid: bool, faults: &mut FaultManager) {
        if !(inputs.halls_present && invalid) {
            self.invalid_hall_ticks = 0;
            faults.clear_cause(FaultId::HallInvalidState);
            return;
        }
        self.invalid_hall_ticks = self.invalid_hall_ticks.saturating_add(1);
        let powered =
            matches!(inputs.power, PowerState::Calibrating | PowerState::SwitchedOn | PowerState::OperationEnabled);
        // While the fault is active (in «Fault», outputs off) the raise only keeps its cause present.
        if self.invalid_hall_ticks >= INVALID_HALL_TICKS && (powered || faults.is_active(FaultId::HallInvalidState)) {
            faults.raise(FaultId::HallInvalidState, inputs.snapshot(i32::from(inputs.hall)), inputs.now);
        }
    }

    /// Check 2.
    fn mismatch(&mut self, inputs: &SupervisionInputs, sector: Option<HallSector>, faults: &mut FaultManager) {
        // With the encoder signal known lost, its angle means nothing: the disagreement is that fault's.
        let measured = matches!(inputs.commutation, CommutationStage::HallEdge | CommutationStage::Indexed)
            && !faults.is_active(FaultId::EncoderSignalLoss);
        let sector = match sector {
            Some(s) if measured && inputs.halls_present && inputs.encoder_present => s,
            _ => {
                self.mismatch_ticks = 0;
                return;
            }
        };
        let t = &self.tolerance;
        if t.max_speed_rpm != self.max_speed_rpm
            || t.pole_pairs != inputs.pole_pairs
            || t.counts_per_turn != inputs.encoder_counts_per_turn
        {
            self.tolerance =
                MismatchTolerance::new(self.max_speed_rpm, inputs.pole_pairs, inputs.encoder_counts_per_turn);
        }
        let off = hall_distance(inputs.electrical_angle, sector, inputs.hall_offset);
        let stopped = self.signal.encoder_stopped();
        if !stopped {
            self.held_ticks = 0;
        }
        if off.unsigned_abs() <= self.tolerance.limit {
            self.mismatch_ticks = 0;
            return;
        }
        if stopped && self.held_ticks < MISMATCH_HOLD_TICKS {
            self.held_ticks = self.held_ticks.saturating_add(1);
            return;
        }
        self.mismatch_ticks = self.mismatch_ticks.saturating_add(1);
        if self.mismatch_ticks >= MISMATCH_TICKS {
            // Detail: the angle's distance from the Hall sector's centre in 1/65536 electrical turn (0x301A:03's
            // unit).
            faults.raise(FaultId::HallEncoderMismatch, inputs.snapshot(off >> 16), inputs.now);
            self.mismatch_ticks = 0;
        }
    }

    /// Check 3.
    fn index(&mut self, inputs: &SupervisionInputs, restart: bool, faults: &mut FaultManager) {
        let w = &mut self.index;
        if !(inputs.encoder_present && inputs.encoder_has_index) || restart {
            w.tracking = false;
            return;
        }
        let position = inputs.encoder_position;
        if !w.tracking {
            *w = IndexWatch { tracking: true, seen: inputs.index_pulses, last_index: None, origin: position };
            return;
        }
        let cpr = i64::from(inputs.encoder_counts_per_turn.max(1));
        if inputs.index_pulses != w.seen {
            w.seen = inputs.index_pulses;
            let at = inputs.index_position;
            if let Some(previous) = w.last_index {
                // Count error: the distance from the nearest whole number of turns, in [-cpr/2, cpr/2).
                let d = i64::from(at.wrapping_sub(previous));
                let error = d.saturating_add(cpr / 2).checked_rem_euclid(cpr).unwrap_or(0).saturating_sub(cpr / 2);
                if error.unsigned_abs() > u64::from(INDEX_POSITION_TOLERANCE.unsigned_abs()) {
                    let detail = i32::try_from(error).unwrap_or(i32::MAX);
                    faults.raise(FaultId::EncoderIndexMissing, inputs.snapshot(detail), inputs.now);
                }
            }
            w.last_index = Some(at);
            w.origin = at;
            return;
        }
        let moved = i64::from(position.wrapping_sub(w.origin));
        if moved.unsigned_abs().saturating_mul(2) > cpr.unsigned_abs().saturating_mul(u64::from(INDEX_MISSING_TURNS_X2))
        {
            let detail = i32::try_from(moved).unwrap_or(i32::MAX);
            faults.raise(FaultId::EncoderIndexMissing, inputs.snapshot(detail), inputs.now);
            // The next report after another 1.5 turns; the last index stays the reference for the displacement.
            w.origin = position;
        }
    }

    /// Check 4.
    fn signal_loss(
        &mut self,
        inputs: &SupervisionInputs,
        sector: Option<HallSector>,
        restart: bool,
        faults: &mut FaultManager,
    ) {
        if !(inputs.halls_present && inputs.encoder_present) {
            // No second sensor to compare with: nothing can show the cause any longer.
            self.signal.restart();
            faults.clear_cause(FaultId::EncoderSignalLoss);
            return;
        }
        let Some(sector) = sector.filter(|_| !restart) else {
            self.signal.restart();
            return;
        };
        match self.signal.step(sector, inputs.encoder_position, inputs.encoder_counts_per_turn, inputs.pole_pairs) {
            Some(SignalCheck::Lost(moved)) => {
                faults.raise(FaultId::EncoderSignalLoss, inputs.snapshot(moved), inputs.now);
            }
            Some(SignalCheck::Agrees) => faults.clear_cause(FaultId::EncoderSignalLoss),
            None => {}
        }
    }
}

/// The signed distance of `angle` from the centre of the Hall sector `sector`, in turn bits (`[-1/2, 1/2)` turn).
#[must_use]
pub fn hall_distance(angle: ElectricalAngle, sector: HallSector, hall_offset: ElectricalAngle) -> i32 {
    angle.difference(sector.centre_angle(hall_offset)).0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::Ticks;
    use crate::control::angle::ElectricalAngle;

    const DEG: f64 = 4_294_967_296.0 / 360.0;
    const SEQUENCE: [u8; 6] = [0b101, 0b001, 0b011, 0b010, 0b110, 0b100];

    /// The reference motor running with an indexed commutation at mechanical count 0.
    fn inputs() -> SupervisionInputs {
        SupervisionInputs::reference_running()
    }

    /// An ideal reference rotor at `counts` (fractional mechanical counts from the index): the drive's inputs,
    /// with the commutation angle off by `angle_error_deg`.
    fn at(counts: f64, angle_error_deg: f64) -> SupervisionInputs {
        let whole = counts.floor();
        let e_deg = (counts * 7.0 / 4096.0 * 360.0).rem_euclid(360.0);
        let angle = (whole * 7.0 / 4096.0 * 360.0 + angle_error_deg).rem_euclid(360.0);
        SupervisionInputs {
            hall: SEQUENCE[(e_deg / 60.0) as usize % 6],
            encoder_position: whole as i32,
            electrical_angle: ElectricalAngle((angle * DEG) as u32),
            ..inputs()
        }
    }

    fn supervision() -> FeedbackSupervision {
        FeedbackSupervision::new(&Dictionary::new(1))
    }

    #[test]
    fn tolerance_of_the_reference_motor() {
        let t = MismatchTolerance::new(5000, 7, 4096);
        let deg = f64::from(t.tolerance()) / DEG;
        // 10 + 1.5 x 8.4 + 0.615 degrees.
        assert!((deg - 23.215).abs() < 0.01, "{deg}");
        assert!((f64::from(t.limit()) / DEG - 53.215).abs() < 0.01);
        // Capped at 30 degrees for absurd speeds.
        assert_eq!(MismatchTolerance::new(25_000, 255, 16).tolerance(), SIXTH_TURN / 2);
        assert_eq!(MismatchTolerance::new(u32::MAX, 255, 0).tolerance(), SIXTH_TURN / 2);
    }

    #[test]
    fn invalid_hall_needs_two_ticks_and_a_powered_stage() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        let mut i =
            SupervisionInputs { power: PowerState::Off, hall: 0, commutation: CommutationStage::Unknown, ..inputs() };
        for _ in 0..5 {
            s.step(&i, &mut faults);
        }
        assert!(!faults.is_active(FaultId::HallInvalidState), "not powered: nothing");
        // Switched on: one more tick of the invalid state that persisted is enough.
        i.power = PowerState::SwitchedOn;
        s.step(&i, &mut faults);
        assert!(faults.is_active(FaultId::HallInvalidState), "persisted while off, now powered");
        i.hall = 0b001;
        s.step(&i, &mut faults);
        assert!(faults.reset_request().is_ok());
        i.hall = 0b111;
        s.step(&i, &mut faults);
        assert!(!faults.is_active(FaultId::HallInvalidState), "one tick is not enough");
        s.step(&i, &mut faults);
        assert!(faults.is_active(FaultId::HallInvalidState), "two ticks");
        assert_eq!(faults.snapshot(FaultId::HallInvalidState).map(|s| s.detail), Some(7));
        // In «Fault» (outputs off) the cause stays present while the state is invalid.
        i.power = PowerState::Off;
        s.step(&i, &mut faults);
        assert!(faults.reset_request().is_err(), "refused while invalid");
        i.hall = 0b001;
        s.step(&i, &mut faults);
        assert!(faults.reset_request().is_ok(), "accepted once valid");
        // Halls not configured: an invalid state means nothing.
        i.power = PowerState::SwitchedOn;
        i.halls_present = false;
        i.hall = 0;
        for _ in 0..5 {
            s.step(&i, &mut faults);
        }
        assert!(!faults.any_fault());
    }

    #[test]
    fn mismatch_beyond_the_tolerance_for_three_ticks() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        // At the centre of sector 0 (count 49: 30.15 degrees): 53 degrees off is inside, 54 outside.
        let centre = 49.5;
        for _ in 0..10 {
            s.step(&at(centre, 53.0), &mut faults);
            s.step(&at(centre, -53.0), &mut faults);
        }
        assert!(!faults.any_fault(), "inside the tolerance");
        s.step(&at(centre, 54.0), &mut faults);
        s.step(&at(centre, 54.0), &mut faults);
        s.step(&at(centre, 0.0), &mut faults);
        s.step(&at(centre, -54.0), &mut faults);
        s.step(&at(centre, -54.0), &mut faults);
        assert!(!faults.any_fault(), "not three ticks in a row");
        s.step(&at(centre, -54.0), &mut faults);
        assert!(faults.is_active(FaultId::HallEncoderMismatch));
        let detail = faults.snapshot(FaultId::HallEncoderMismatch).map_or(0, |s| s.detail);
        assert!((f64::from(detail) / 65536.0 * 360.0 + 54.0).abs() < 0.7, "detail {detail}");
        // Not compared before the angle is measured.
        let mut s = supervision();
        let mut faults = FaultManager::new();
        for stage in [CommutationStage::HallSector, CommutationStage::Unknown, CommutationStage::Aligned] {
            for _ in 0..5 {
                s.step(&SupervisionInputs { commutation: stage, ..at(centre, 180.0) }, &mut faults);
            }
        }
        assert!(!faults.any_fault());
    }

    /// 0x3000:04 bit 8 (IDX Table 6-98 "main sensor supervision disabled"): a stopped encoder counter under
    /// turning Halls raises 0x7380 with the bit clear; with it set, the same run raises nothing, and setting it
    /// while the fault is active clears the cause, so the fault can be reset. The Hall check stays on.
    #[test]
    fn bit_8_of_0x3000_04_turns_the_main_sensor_checks_off() {
        let run = |s: &mut FeedbackSupervision, faults: &mut FaultManager| {
            let mut pos = 0.5;
            for _ in 0..100 {
                pos += 20.48;
                let mut i = at(pos, 0.0);
                if pos > 60.0 {
                    i.encoder_position = 60;
                    i.electrical_angle = ElectricalAngle((60.0 * 7.0 / 4096.0 * 360.0 * DEG) as u32);
                }
                s.step(&i, faults);
            }
        };
        let mut d = Dictionary::new(1);
        let mut s = FeedbackSupervision::new(&d);
        let mut faults = FaultManager::new();
        run(&mut s, &mut faults);
        assert!(faults.is_active(FaultId::EncoderSignalLoss), "supervised: the stopped counter is found");
        assert!(faults.reset_request().is_err(), "the cause persists");
        d.set(h::AXIS_CONFIGURATION_MISC, MAIN_SENSOR_SUPERVISION_DISABLED);
        s.refresh(&d);
        s.step(&at(300.5, 0.0), &mut faults);
        assert!(faults.reset_request().is_ok(), "the disabled check no longer holds its cause");
        let mut s = FeedbackSupervision::new(&d);
        let mut faults = FaultManager::new();
        run(&mut s, &mut faults);
        assert!(!faults.any_fault(), "not supervised: nothing raised");
        // The Hall check is not the main sensor's: still on.
        let invalid = SupervisionInputs { hall: 0, ..inputs() };
        s.step(&invalid, &mut faults);
        s.step(&invalid, &mut faults);
        assert!(faults.is_active(FaultId::HallInvalidState));
    }

    #[test]
    fn mismatch_waits_for_the_signal_loss_check_while_the_counter_stands() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        // Turning forward at 300 rpm (20.48 counts per slow tick); the counter stops at count 60 (35 degrees
        // electrical, sector 0).
        let mut pos = 0.5;
        let mut first = None;
        for tick in 0..100 {
            pos += 20.48;
            let mut i = at(pos, 0.0);
            if pos > 60.0 {
                i.encoder_position = 60;
                i.electrical_angle = ElectricalAngle((60.0 * 7.0 / 4096.0 * 360.0 * DEG) as u32);
            }
            s.step(&i, &mut faults);
            if first.is_none() {
                first = faults.active().next().map(|a| (a.id, tick));
            }
        }
        // Sector 2 begins at count 195: the stopped counter is reported there, not the angle it leaves behind.
        assert_eq!(first.map(|(id, _)| id), Some(FaultId::EncoderSignalLoss), "{first:?}");
        assert!(!faults.is_active(FaultId::HallEncoderMismatch), "the lost encoder's angle is not compared");
        // Standing still after one sector (the rotor trapped): the mismatch comes after the hold.
        let mut s = supervision();
        let mut faults = FaultManager::new();
        // Counter stopped at 40 (24.6 degrees, sector 0), rotor at 150 (92.3 degrees, sector 1): 65.4 degrees from
        // the centre of sector 1.
        let frozen = at(40.5, 0.0);
        s.step(&frozen, &mut faults);
        let moved_on =
            SupervisionInputs { encoder_position: 40, electrical_angle: frozen.electrical_angle, ..at(150.5, 0.0) };
        let mut ticks = 0;
        while !faults.any_fault() && ticks < 100 {
            s.step(&moved_on, &mut faults);
            ticks += 1;
        }
        assert!(faults.is_active(FaultId::HallEncoderMismatch));
        assert_eq!(ticks, u32::from(MISMATCH_HOLD_TICKS) + u32::from(MISMATCH_TICKS));
    }

    /// An ideal rotor sampled every slow tick at up to 0x6080 (5,000 rpm) and through reversals, with the
    /// commutation's worst healthy angle error (half a fast tick at 5,000 rpm plus one count, both ways): no
    /// check trips. The index pulses come from the ideal encoder.
    #[test]
    fn no_trip_on_a_healthy_rotor_up_to_max_speed() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        let counts_per_tick = |rpm: f64| rpm / 60.0 * 4096.0 / 2500.0;
        let max_error = 4.2 + 0.62;
        let mut pos = 1234.5_f64;
        let mut pulses = 0u32;
        let mut index_at = 0i32;
        let mut k = 0u32;
        // Speed profile: ramps between +5,000 and -5,000 rpm with holds, 4 s of slow ticks.
        for tick in 0..10_000u32 {
            let phase = f64::from(tick % 2500) / 2500.0;
            let rpm = 5000.0 * (2.0 * core::f64::consts::PI * phase).sin().clamp(-0.9, 0.9) / 0.9;
            let next = pos + counts_per_tick(rpm);
            // Index pulses at every multiple of 4096 passed.
            let (lo, hi) = (pos.min(next), pos.max(next));
            let passed = (hi / 4096.0).floor() - (lo / 4096.0).floor();
            if passed > 0.0 {
                pulses += 1;
                index_at = ((hi / 4096.0).floor() * 4096.0) as i32;
            }
            pos = next;
            k = k.wrapping_add(1);
            let err = if k.is_multiple_of(2) { max_error } else { -max_error };
            let i = SupervisionInputs { index_pulses: pulses, index_position: index_at, ..at(pos, err) };
            s.step(&i, &mut faults);
        }
        let active: Vec<_> = faults.active().map(|a| a.id).collect();
        assert!(active.is_empty(), "{active:?}");
        assert!(pulses > 50);
    }

    #[test]
    fn index_missing_after_one_and_a_half_turns() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        let step = |s: &mut FeedbackSupervision, f: &mut FaultManager, pos: i32, pulses: u32, at: i32| {
            let i = SupervisionInputs { encoder_position: pos, index_pulses: pulses, index_position: at, ..inputs() };
            s.step(&i, f);
        };
        step(&mut s, &mut faults, 100, 0, 0);
        // The first index at 4096, then none: 1.5 turns from it is 4096 + 6144.
        step(&mut s, &mut faults, 4100, 1, 4096);
        step(&mut s, &mut faults, 4096 + 6144, 1, 4096);
        assert!(!faults.any_fault());
        step(&mut s, &mut faults, 4096 + 6145, 1, 4096);
        assert!(faults.is_active(FaultId::EncoderIndexMissing));
        assert_eq!(faults.snapshot(FaultId::EncoderIndexMissing).map(|s| s.detail), Some(6145));
        // Event: the reset is accepted at once.
        assert!(faults.reset_request().is_ok());
        // Backwards from the start without any index: 1.5 turns from where the watch started.
        let mut s = supervision();
        let mut faults = FaultManager::new();
        step(&mut s, &mut faults, 0, 7, 999);
        step(&mut s, &mut faults, -6144, 7, 999);
        assert!(!faults.any_fault());
        step(&mut s, &mut faults, -6145, 7, 999);
        assert!(faults.is_active(FaultId::EncoderIndexMissing));
    }

    #[test]
    fn displaced_index_reports_the_count_error() {
        for (second, expected) in
            [(4096 * 3 + 4, None), (-4096 - 4, None), (4096 + 5, Some(5)), (4096 * 2 - 9, Some(-9))]
        {
            let mut s = supervision();
            let mut faults = FaultManager::new();
            let i = SupervisionInputs { encoder_position: 10, index_pulses: 0, ..inputs() };
            s.step(&i, &mut faults);
            s.step(&SupervisionInputs { index_pulses: 1, index_position: 0, ..i }, &mut faults);
            s.step(
                &SupervisionInputs { encoder_position: second, index_pulses: 2, index_position: second, ..i },
                &mut faults,
            );
            let got = faults.snapshot(FaultId::EncoderIndexMissing).map(|s| s.detail);
            assert_eq!(got, expected, "second index at {second}");
        }
    }

    #[test]
    fn index_watch_restarts_at_switch_on_and_without_index() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        let i = SupervisionInputs { encoder_position: 50_000, ..inputs() };
        s.step(&i, &mut faults);
        // Switch-on restarts the encoder at 0: the jump is not travel.
        s.step(&SupervisionInputs { power: PowerState::Calibrating, encoder_position: 0, ..i }, &mut faults);
        s.step(&SupervisionInputs { encoder_position: 0, ..i }, &mut faults);
        s.step(&SupervisionInputs { encoder_position: 100, ..i }, &mut faults);
        // No index channel: no watch.
        let n = SupervisionInputs { encoder_has_index: false, ..i };
        for pos in [0, 100_000, -100_000] {
            s.step(&SupervisionInputs { encoder_position: pos, ..n }, &mut faults);
        }
        assert!(!faults.any_fault());
    }

    #[test]
    fn signal_loss_when_the_encoder_stops_while_the_halls_turn() {
        let mut s = supervision();
        let mut faults = FaultManager::new();
        // Turning at 300 rpm (about 20 counts per slow tick), then the counter freezes at 600.
        let mut pos = 0.5;
        let mut raised_at = None;
        for _ in 0..200 {
            pos += 20.48;
            let mut i = at(pos, 0.0);
            if pos > 600.0 {
                i.encoder_position = 600;
                i.commutation = CommutationStage::Unknown; // keep check 2 out of this test
            }
            s.step(&i, &mut faults);
            if raised_at.is_none() && faults.is_active(FaultId::EncoderSignalLoss) {
                raised_at = Some(pos);
            }
        }
        // Two sectors (195 counts) after the freeze at the latest, plus the sector the freeze fell in.
        let raised_at = raised_at.expect("raised");
        assert!(raised_at > 600.0 && raised_at < 600.0 + 3.0 * 97.6, "{raised_at}");
        assert!(faults.reset_request().is_err(), "level: refused while the encoder does not follow");
        // The encoder counts again: the next two sectors agree and the cause clears.
        for _ in 0..20 {
            pos += 20.48;
            s.step(&at(pos, 0.0), &mut faults);
        }
        assert!(faults.reset_request().is_ok());
    }

    #[test]
    fn signal_watch_counts_sectors_in_one_direction() {
        let sector = |k: u8| HallSector::from_state(SEQUENCE[usize::from(k % 6)]).unwrap();
        let mut w = SignalLossWatch::default();
        assert_eq!(w.step(sector(0), 0, 4096, 7), None);
        assert_eq!(w.step(sector(1), 0, 4096, 7), None);
        // Back and forth at an edge with no counts: a reversal restarts, nothing is judged.
        for _ in 0..5 {
            assert_eq!(w.step(sector(0), 0, 4096, 7), None);
            assert_eq!(w.step(sector(1), 0, 4096, 7), None);
        }
        // From the reversal in sector 1: two more sectors with 49 counts (more than a quarter of 195) agree.
        assert_eq!(w.step(sector(0), 0, 4096, 7), None);
        assert_eq!(w.step(sector(1), 20, 4096, 7), None);
        assert_eq!(w.step(sector(2), 49, 4096, 7), Some(SignalCheck::Agrees));
        // Two sectors in one tick, 48 counts: lost; three sectors: unknown direction, restart.
        assert_eq!(w.step(sector(4), 97, 4096, 7), Some(SignalCheck::Lost(48)));
        assert_eq!(w.step(sector(1), 97, 4096, 7), None);
        // Backwards: the counts must go down.
        assert_eq!(w.step(sector(0), 97, 4096, 7), None);
        assert_eq!(w.step(sector(5), 200, 4096, 7), Some(SignalCheck::Lost(-103)));
        // A counter that stops just after a window began: that window still agrees (it holds the counts from
        // before), the stopped-counter criterion reports at the second sector passed without a count.
        let mut w = SignalLossWatch::default();
        assert_eq!(w.step(sector(0), 0, 4096, 7), None);
        assert_eq!(w.step(sector(1), 97, 4096, 7), None);
        assert_eq!(w.step(sector(1), 120, 4096, 7), None);
        assert_eq!(w.step(sector(2), 120, 4096, 7), Some(SignalCheck::Agrees));
        assert!(w.encoder_stopped(), "one sector without a count");
        assert_eq!(w.step(sector(3), 120, 4096, 7), Some(SignalCheck::Lost(0)));
        // Cleared by configuration: Halls absent.
        let mut s = supervision();
        let mut faults = FaultManager::new();
        faults.raise(FaultId::EncoderSignalLoss, inputs().snapshot(0), Ticks(0));
        s.step(&SupervisionInputs { halls_present: false, ..inputs() }, &mut faults);
        assert!(faults.reset_request().is_ok());
    }
}
