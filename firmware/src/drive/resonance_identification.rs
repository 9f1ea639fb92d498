//! The resonance step of the motor identification (issue 18 items 3/4; step 7 of the auto setup, after the
//! mechanical step and before the auto-tuning): the motor-side frequency response of the drive train, and from it
//! the first anti-resonance and resonance of an elastic load, which the auto-tuning's elastic design takes from
//! 0x3205:03/04 ([`super::tuning`]: rho = (f_r / f_ar)^2).
//!
//! # The experiment
//! FOC with the commutation known, d current zero; the step returns the q current demand once per slow tick.
//! 1. Run-up: a slow speed loop (PI with the Coulomb friction of 0x3204:05 as feedforward, crossover 1.5 Hz, under
//!    the sweep) takes the motor to a bias speed, a quarter of the max system speed. The bias keeps the load's
//!    friction on one side of its sign change (it preloads the gear's teeth on one flank while the sine is small
//!    against it), so that the sine on top sees a steadier plant; at rest a small sine would rattle inside the
//!    backlash (geared-36v: 1.5 deg at the motor) and see the rotor alone.
//! 2. Sine dwells on top of the bias at [`PERIODS`] (whole slow-tick periods from 6 Hz to 227 Hz, about 12 %
//!    apart): each dwell settles, then correlates the measured q current (the slow tick's average) and the motor
//!    speed (the position difference per tick) with the sine and cosine over whole periods (one DFT bin; the bias
//!    speed and the speed loop's slow current correlate to nothing over whole periods, and the encoder's
//!    quantization enters the speed's bin times |1 - e^-jw|, small at these frequencies). The ratio of the bins
//!    is the plant's velocity response whatever the speed loop adds to the current; divided by the rigid
//!    response kt / (J_total w) (J_total and kt from the mechanical step, 0x30A3:05 and 0x3001:05) it is 1 for a
//!    rigid load at every frequency, and for a two-mass load dips at the anti-resonance and peaks at the
//!    resonance. The current amplitude of each dwell is set from the last dwell's response (at most 3/4 of the
//!    current limit) so that the motor's speed amplitude is a quarter of the bias or, where that is more, 0.15 rad
//!    of motor angle, at most the bias: at a resonance the motor's angle is the coupling's twist, which must be
//!    large against the backlash for the teeth-in-contact stiffness to dominate (with a quarter of the bias alone
//!    the geared preset's peak came at 45 Hz instead of 60 Hz), and the speed stays within bias +- bias, far
//!    from the max system speed.
//! 3. Run-down: the speed loop takes the motor back to rest, then the result.
//!
//! # The estimate
//! [`find_resonance`]: the deepest dip of the normalized response |G|^2 and the highest peak above it in
//! frequency. Both must be marked (dip below [`DIP_MAX`]^2, peak above [`PEAK_MIN`]^2 of the rigid response,
//! interior points of the sweep), else the load counts as rigid ("none", 0 in 0x3205:03/04). Each frequency is
//! refined by a parabola through the three points around it: |G|^2 near a zero and 1/|G|^2 near a pole of a
//! two-mass response are quadratic in w^2 (the lightly damped factor `k - J w^2 + j c w` squared), so the
//! parabola's vertex in f^2 is the zero's or the pole's frequency.
//!
//! Floats as in [`super::identification`]: tier 2 on the Cortex-M4F's FPU. Cost per slow tick: one table
//! sine/cosine, a dozen float operations; at the end of a dwell a few divisions and a square root (Newton); the
//! estimate at the end loops once over the sweep.

use crate::control::frames::Amps;
use crate::control::trig::sin_cos;
use crate::control::units::ElectricalAngle;
use crate::control::velocity::SLOW_TICK_HZ;

use super::mechanical_identification::MechanicalSample;

/// Slow ticks per second, as `f32`.
const TICK_HZ: f32 = SLOW_TICK_HZ as f32;
/// Number of sine dwells.
pub const DWELLS: usize = 30;
/// The dwells' periods in slow ticks, 417 (6.0 Hz) down to 11 (227 Hz), each 0.88 times the one before rounded
/// (about 12 % in frequency; whole ticks, so that each correlation covers whole periods exactly).
pub const PERIODS: [u16; DWELLS] = [
    417, 367, 323, 284, 250, 220, 194, 171, 150, 132, 116, 102, 90, 79, 70, 62, 55, 48, 42, 37, 33, 29, 26, 23, 20, 18,
    16, 14, 12, 11,
];
/// Ticks of the run-up to the bias speed (a ramp), and as many again for the speed loop to settle.
const RUN_UP_TICKS: u32 = 250;
/// Ticks of the run-down (a ramp to rest), and as many again to come to rest.
const RUN_DOWN_TICKS: u32 = 250;
/// Shortest settling of a dwell (30 ms): a 5 %-damped 60 Hz resonance decays by e in 53 ms, and the amplitude
/// changes by a step only where the response changes.
const MIN_SETTLE_TICKS: u32 = 75;
/// Shortest correlation of a dwell (100 ms), rounded up to whole periods.
const MIN_MEASURE_TICKS: u32 = 250;
/// Motor angle amplitude the dwells aim at where a quarter of the bias speed would give less (rad).
const TWIST_RAD: f32 = 0.15;
/// The bias speed in parts of the max system speed.
const BIAS_DIVISOR: f32 = 4.0;
/// The dwells' speed amplitude at most, in bias speeds.
const AMPLITUDE_CAP: f32 = 1.0;
/// The speed loop's crossover (Hz), under the sweep's lowest frequency: the loop only holds the bias.
const BIAS_LOOP_HZ: f32 = 1.5;
/// A dip is an anti-resonance only under this fraction of the rigid response (and a peak above [`PEAK_MIN`]):
/// a rigid load's normalized response stays within some 20 % of 1 (noise, friction, quantization).
pub const DIP_MAX: f32 = 0.5;
/// A peak is a resonance only over this multiple of the rigid response.
pub const PEAK_MIN: f32 = 2.0;

/// What the step needs to know (from 0x3001, 0x3010, 0x30A3:05 and the procedure's limits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResonanceConfig {
    /// The largest q current amplitude (bias and sine together), e.g. the motor's nominal current 0x3001:01.
    pub current_limit: Amps,
    /// Max system speed in rpm: exceeding it ends the step (IDX 0xFF22); the bias is a quarter of it.
    pub max_speed_rpm: u32,
    /// Encoder counts per motor revolution.
    pub counts_per_rev: u32,
    /// Total inertia at the motor shaft in 0.001 g cm^2 (0x30A3:05, the mechanical step's result).
    pub inertia: u32,
    /// Torque constant in uNm/A (0x3001:05).
    pub torque_constant: u32,
    /// Coulomb friction at the motor shaft in uNm (0x3204:05): the speed loop's feedforward.
    pub coulomb_friction: u32,
    /// The step fails with [`ResonanceError::Timeout`] after this many slow ticks.
    pub timeout_ticks: u32,
}

/// What the step found, in 0x3205:03/04's unit (0.1 Hz); 0 in both for a rigid load.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResonanceResult {
    /// First resonance (0x3205:03).
    pub resonance_dhz: u16,
    /// The anti-resonance under it (0x3205:04).
    pub anti_resonance_dhz: u16,
    /// Slow ticks the step took.
    pub ticks: u32,
}

/// Why the step failed; each maps to one IDX code (seed 002 L7096-7110).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResonanceError {
    /// The speed exceeded the max system speed: IDX 0xFF22.
    SpeedLimit,
    /// The step did not finish within the timeout: IDX 0xFF19.
    Timeout,
    /// Inertia, torque constant, resolution, current limit or speed zero: IDX 0xFF16.
    InvalidConfig,
}

impl ResonanceError {
    /// The IDX error code (seed 002 L7096-7110).
    #[must_use]
    pub const fn code(self) -> u16 {
        match self {
            Self::SpeedLimit => 0xFF22,
            Self::Timeout => 0xFF19,
            Self::InvalidConfig => 0xFF16,
        }
    }
}

/// The step's answer to one sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResonanceStatus {
    /// Still running: apply this q current (d current zero) until the next slow tick.
    Running {
        /// The q current demand.
        i_q_demand: Amps,
    },
    /// Finished: the caller sets the q current to zero.
    Done(ResonanceResult),
    /// Failed: the caller switches the power stage off and raises the error's code.
    Failed(ResonanceError),
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Ramping the speed loop's reference to the bias, then settling.
    RunUp,
    /// Dwell `index`, `ticks` into it.
    Dwell { index: usize, ticks: u32 },
    /// Ramping the reference to rest, then waiting.
    RunDown { ticks: u32 },
}

/// The resonance identification. See the module documentation.
#[derive(Clone, Debug)]
pub struct ResonanceIdentification {
    phase: Phase,
    ticks: u32,
    timeout_ticks: u32,
    /// The first sample's position is taken, `last_position` valid.
    started: bool,
    last_position: i32,
    /// Speed in counts per tick of one rad/s.
    counts_per_tick_per_rad_s: f32,
    /// Speed loop: bias reference, speed limit (rad/s), low-passed speed, P gain (A per rad/s), integrator (A).
    bias_rad_s: f32,
    limit_rad_s: f32,
    speed_rad_s: f32,
    kp: f32,
    integral: f32,
    current_limit: f32,
    /// Rigid response kt / J in (rad/s^2)/A.
    kt_per_j: f32,
    /// The Coulomb friction's current (A): the speed loop's feedforward.
    friction_current: f32,
    /// The sine: phase (2^32 = one period) and the current amplitude (A).
    angle: u32,
    amplitude: f32,
    /// Sine and cosine of the phase the last tick's demand was set at.
    last_sin_cos: [f32; 2],
    /// Correlation sums of the dwell: current with sin, cos; speed (counts/tick) with sin, cos.
    sums: [f32; 4],
    /// Normalized response |G|^2 (1 = rigid) per dwell.
    response: [f32; DWELLS],
}

impl ResonanceIdentification {
    /// A step at its start.
    #[must_use]
    pub fn new(config: &ResonanceConfig) -> Self {
        let kt = config.torque_constant as f32 * 1e-6;
        // 0.001 g cm^2 = 1e-10 kg m^2.
        let inertia = config.inertia as f32 * 1e-10;
        let kt_per_j = if inertia > 0.0 { kt / inertia } else { 0.0 };
        let max_rad_s = config.max_speed_rpm as f32 * (core::f32::consts::TAU / 60.0);
        let bias = max_rad_s / BIAS_DIVISOR;
        let loop_w = core::f32::consts::TAU * BIAS_LOOP_HZ;
        // The first dwell's amplitude: a quarter of the bias on the rigid response.
        let w0 = core::f32::consts::TAU * TICK_HZ / f32::from(PERIODS.first().copied().unwrap_or(1));
        let amplitude = if kt_per_j > 0.0 { speed_amplitude(bias, w0) * w0 / kt_per_j } else { 0.0 };
        let valid = kt_per_j > 0.0 && bias > 0.0 && config.counts_per_rev > 0 && config.current_limit > Amps::ZERO;
        Self {
            phase: Phase::RunUp,
            ticks: 0,
            timeout_ticks: if valid { config.timeout_ticks } else { 0 },
            started: false,
            last_position: 0,
            counts_per_tick_per_rad_s: config.counts_per_rev as f32 / (core::f32::consts::TAU * TICK_HZ),
            bias_rad_s: bias,
            limit_rad_s: max_rad_s,
            speed_rad_s: 0.0,
            kp: if kt_per_j > 0.0 { loop_w / kt_per_j } else { 0.0 },
            integral: 0.0,
            current_limit: config.current_limit.to_bits() as f32 / 65_536.0,
            kt_per_j,
            friction_current: if kt > 0.0 { config.coulomb_friction as f32 * 1e-6 / kt } else { 0.0 },
            angle: 0,
            amplitude,
            last_sin_cos: [0.0; 2],
            sums: [0.0; 4],
            response: [0.0; DWELLS],
        }
    }

    /// Progress of the step, per mille.
    #[must_use]
    pub fn progress_per_mille(&self) -> u16 {
        match self.phase {
            Phase::RunUp => 0,
            Phase::Dwell { index, .. } => index.saturating_mul(1000).checked_div(DWELLS).unwrap_or(0) as u16,
            Phase::RunDown { .. } => 1000,
        }
    }

    /// The normalized response |G|^2 of each dwell so far (1 = rigid; 0 before its dwell).
    #[must_use]
    pub const fn response(&self) -> &[f32; DWELLS] {
        &self.response
    }

    /// One slow tick: the sample of the tick that ends, the q current demand for the next.
    pub fn step(&mut self, sample: &MechanicalSample) -> ResonanceStatus {
        self.ticks = self.ticks.saturating_add(1);
        if self.ticks > self.timeout_ticks {
            return ResonanceStatus::Failed(if self.timeout_ticks == 0 {
                ResonanceError::InvalidConfig
            } else {
                ResonanceError::Timeout
            });
        }
        let counts = if self.started { sample.position.wrapping_sub(self.last_position) } else { 0 };
        self.started = true;
        self.last_position = sample.position;
        let speed_counts = counts as f32;
        // The speed loop's measurement: the tick's speed low-passed over 16 ticks (6.4 ms).
        let speed = speed_counts / self.counts_per_tick_per_rad_s;
        self.speed_rad_s += (speed - self.speed_rad_s) * (1.0 / 16.0);
        if self.speed_rad_s.abs() > self.limit_rad_s {
            return ResonanceStatus::Failed(ResonanceError::SpeedLimit);
        }
        let (reference, sine) = match self.phase {
            Phase::RunUp => {
                let ramp = (self.ticks as f32 / RUN_UP_TICKS as f32).min(1.0);
                if self.ticks >= RUN_UP_TICKS.saturating_mul(2) {
                    self.phase = Phase::Dwell { index: 0, ticks: 0 };
                }
                (self.bias_rad_s * ramp, 0.0)
            }
            Phase::Dwell { index, ticks } => {
                let period = u32::from(PERIODS.get(index).copied().unwrap_or(1));
                let settle = period.max(MIN_SETTLE_TICKS);
                let measure = MIN_MEASURE_TICKS.div_ceil(period).max(1).saturating_mul(period);
                let step = u32::MAX.checked_div(period).unwrap_or(0);
                if ticks >= settle {
                    // The sample ends the tick whose demand the last tick set: correlate with its sine.
                    let [s, c] = self.last_sin_cos;
                    let current = sample.i_q.to_bits() as f32 / 65_536.0;
                    let products = [current * s, current * c, speed_counts * s, speed_counts * c];
                    for (sum, p) in self.sums.iter_mut().zip(products) {
                        *sum += p;
                    }
                }
                let ticks = ticks.saturating_add(1);
                self.phase = if ticks >= settle.saturating_add(measure) {
                    self.end_dwell(index, period);
                    let next = index.saturating_add(1);
                    if next < DWELLS {
                        Phase::Dwell { index: next, ticks: 0 }
                    } else {
                        self.amplitude = 0.0;
                        Phase::RunDown { ticks: 0 }
                    }
                } else {
                    Phase::Dwell { index, ticks }
                };
                let now = sin_cos(ElectricalAngle(self.angle));
                self.angle = self.angle.wrapping_add(step);
                let sine = i2f30(now.sin.to_bits());
                self.last_sin_cos = [sine, i2f30(now.cos.to_bits())];
                (self.bias_rad_s, self.amplitude * sine)
            }
            Phase::RunDown { ticks } => {
                let ticks = ticks.saturating_add(1);
                self.phase = Phase::RunDown { ticks };
                if ticks >= RUN_DOWN_TICKS.saturating_mul(2) {
                    let (anti, resonance) = find_resonance(&PERIODS, &self.response).unwrap_or((0.0, 0.0));
                    return ResonanceStatus::Done(ResonanceResult {
                        resonance_dhz: decihertz(resonance),
                        anti_resonance_dhz: decihertz(anti),
                        ticks: self.ticks,
                    });
                }
                let ramp = 1.0 - (ticks as f32 / RUN_DOWN_TICKS as f32).min(1.0);
                (self.bias_rad_s * ramp, 0.0)
            }
        };
        // PI speed loop: P at the crossover, the integrator's corner at a quarter of it.
        let error = reference - self.speed_rad_s;
        let integral_gain = self.kp * core::f32::consts::TAU * BIAS_LOOP_HZ / 4.0 / TICK_HZ;
        // max/min, not clamp: f32::clamp asserts its bounds' order with a formatted panic (float formatting, some
        // 19 KB in the images that print panics; flash, issue 17).
        let limit = self.current_limit;
        self.integral = (self.integral + integral_gain * error).max(-limit).min(limit);
        let feedforward = if reference > 0.0 { self.friction_current } else { 0.0 };
        let demand = (feedforward + self.integral + self.kp * error + sine).max(-limit).min(limit);
        ResonanceStatus::Running { i_q_demand: Amps::from_bits((demand * 65_536.0) as i32) }
    }

    /// The end of dwell `index`: its normalized response and the next dwell's amplitude.
    fn end_dwell(&mut self, index: usize, period: u32) {
        let [is, ic, vs, vc] = self.sums;
        self.sums = [0.0; 4];
        let current2 = is * is + ic * ic;
        let speed2 = vs * vs + vc * vc;
        let w = core::f32::consts::TAU * TICK_HZ / period as f32;
        // The rigid response in counts per tick per A: kt / (J w), scaled.
        let rigid = self.kt_per_j / w * self.counts_per_tick_per_rad_s;
        let response = if current2 > 0.0 { speed2 / current2 / (rigid * rigid) } else { 0.0 };
        if let Some(r) = self.response.get_mut(index) {
            *r = response;
        }
        // The next dwell's amplitude: the bias / 4 on this dwell's response, scaled to the next frequency as a
        // rigid load would (the response changes little from one dwell to the next except at a sharp peak,
        // where the motor then moves more, within the speed loop's range).
        let next = u32::from(PERIODS.get(index.saturating_add(1)).copied().unwrap_or(1));
        let gain = sqrt(response.max(1.0 / 16.0));
        let w_next = core::f32::consts::TAU * TICK_HZ / next as f32;
        let target = speed_amplitude(self.bias_rad_s, w_next) * w_next / self.kt_per_j;
        self.amplitude = (target / gain).min(self.current_limit * 0.75);
    }
}

/// The speed amplitude (rad/s) a dwell at `w` aims at with the bias speed `bias`: a quarter of the bias, or
/// [`TWIST_RAD`] of motor angle where that is more (at a resonance the motor's angle is the coupling's twist, which
/// must be large against the gear's backlash for the resonance of the teeth in contact), at most [`AMPLITUDE_CAP`]
/// times the bias.
fn speed_amplitude(bias: f32, w: f32) -> f32 {
    (TWIST_RAD * w).max(bias / 4.0).min(bias * AMPLITUDE_CAP)
}

/// I2F30 bits as `f32`.
fn i2f30(bits: i32) -> f32 {
    bits as f32 * (1.0 / 1_073_741_824.0)
}

/// Frequency in 0.1 Hz, saturated to `u16`.
fn decihertz(hz: f32) -> u16 {
    // `as` saturates (and takes NaN to 0).
    (hz * 10.0 + 0.5) as u16
}

/// Square root by Newton's iteration from a bit-level first guess (no `libm` in the firmware; the M4F's
/// `vsqrt` is not reachable from `core` on stable): relative error below 1e-6 after four steps.
fn sqrt(x: f32) -> f32 {
    if x <= 0.0 {
        return 0.0;
    }
    let mut y = f32::from_bits((x.to_bits() >> 1).wrapping_add(0x1FC0_0000));
    for _ in 0..4 {
        y = 0.5 * (y + x / y);
    }
    y
}

/// The first anti-resonance and resonance (Hz) of a normalized velocity response `response` (|G|^2, 1 = rigid)
/// measured at `periods` (slow ticks, decreasing): the deepest dip and the highest peak above it, each refined
/// by a parabola in f^2 (of |G|^2 at the dip, of 1/|G|^2 at the peak). `None` unless the dip is below
/// [`DIP_MAX`], the peak above [`PEAK_MIN`], and both inside the sweep (a neighbour on each side).
#[must_use]
pub fn find_resonance(periods: &[u16], response: &[f32]) -> Option<(f32, f32)> {
    let at = |k: usize| response.get(k).copied().unwrap_or(0.0);
    let last = response.len().min(periods.len()).checked_sub(1)?;
    let mut dip = 0;
    for k in 1..=last {
        if at(k) < at(dip) {
            dip = k;
        }
    }
    let mut peak = dip;
    for k in dip..=last {
        if at(k) > at(peak) {
            peak = k;
        }
    }
    let interior = |k: usize| k > 0 && k < last;
    if !(interior(dip) && interior(peak) && at(dip) < DIP_MAX * DIP_MAX && at(peak) > PEAK_MIN * PEAK_MIN) {
        return None;
    }
    Some((vertex(periods, response, dip, false), vertex(periods, response, peak, true)))
}

/// The frequency (Hz) of the minimum of the parabola in f^2 through the points k - 1, k, k + 1 of `response`
/// (of its inverse at a `peak`); the point's own where the three are not convex, and never outside the
/// neighbours. One copy for both uses, out of line (flash, issue 17).
#[inline(never)]
fn vertex(periods: &[u16], response: &[f32], k: usize, peak: bool) -> f32 {
    let point = |j: usize| {
        let f = TICK_HZ / f32::from(periods.get(j).copied().unwrap_or(1));
        let y = response.get(j).copied().unwrap_or(0.0);
        (f * f, if peak { 1.0 / y.max(f32::MIN_POSITIVE) } else { y })
    };
    let ((x0, y0), (x1, y1), (x2, y2)) = (point(k.saturating_sub(1)), point(k), point(k.saturating_add(1)));
    // Newton's form: y = y0 + d01 (x - x0) + b (x - x0)(x - x1), whose derivative is zero at
    // x = (x0 + x1) / 2 - d01 / (2 b).
    let d01 = (y1 - y0) / (x1 - x0);
    let d12 = (y2 - y1) / (x2 - x1);
    let b = (d12 - d01) / (x2 - x0);
    let x = if b.is_nan() || b <= 0.0 { x1 } else { 0.5 * (x0 + x1) - d01 / (2.0 * b) };
    sqrt(x.max(x0.min(x2)).min(x0.max(x2)))
}

#[cfg(test)]
mod tests;
