//! Planning: a move, a velocity command or a stop as up to four segments in continuous time, each sampled in
//! closed form (see the module documentation of [`super`]), and the samples they give.

use super::params::{ProfileParams, ProfileType};
use super::sine::{sin_2pi_q60, sin_pi_q60, INV_2PI2_Q60, INV_2PI_Q60, ONE_Q62};
use super::units::{Acceleration, Velocity};
use super::ONE_Q32;
use crate::wide::{div_shl, isqrt, mul_shr, mul_sign, round_shr, sat_i64};

/// How far (Q32 inc, 2^-8 inc) a start velocity may exceed what can be stopped within the distance before the
/// planner treats the move as an overshoot (stop and come back) rather than as a rounding residue.
const OVERSHOOT_TOLERANCE: i128 = 1 << 24;
/// Segments of a plan: stop + ramp + cruise + ramp.
const MAX_SEGMENTS: usize = 4;

/// Internal limits of one plan: peak velocity (Q32), mean acceleration and deceleration (Q40), all > 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Limits {
    pub(super) vmax: i128,
    pub(super) acc: i128,
    pub(super) dec: i128,
    pub(super) shape: ProfileType,
}

impl Limits {
    /// `None` when the velocity or an acceleration is zero (the move could never end).
    fn new(vmax: Velocity, acc: Acceleration, dec: Acceleration, shape: ProfileType) -> Option<Self> {
        let vmax = vmax.wide().saturating_abs();
        let (acc, dec) = (acc.wide().saturating_abs(), dec.wide().saturating_abs());
        if vmax == 0 || acc == 0 || dec == 0 {
            return None;
        }
        Some(Self { vmax, acc: mean_rate(acc, shape), dec: mean_rate(dec, shape), shape })
    }

    pub(super) fn from_params(params: &ProfileParams, velocity: Velocity) -> Option<Self> {
        Self::new(velocity, params.acceleration, params.deceleration, params.profile_type)
    }
}

/// The mean acceleration of a ramp whose peak is `peak` (half of it for sin²), at least one LSB.
pub(super) fn mean_rate(peak: i128, shape: ProfileType) -> i128 {
    match shape {
        ProfileType::Trapezoidal => peak,
        ProfileType::SinSquared => (peak >> 1).max(1),
    }
}

/// One sample of the profile, produced every slow tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Setpoint {
    /// Position demand in increments, rounded to nearest (exact at the target), i.e. 0x6062.
    pub position: i64,
    /// The same position in Q16 increments (2^-16 inc), floor of the internal value, for sub-increment use.
    pub position_fine: i64,
    /// Velocity demand (feedforward for the velocity/position loop; 0x606B after conversion to rpm).
    pub velocity: Velocity,
    /// Acceleration demand (feedforward).
    pub acceleration: Acceleration,
}

impl Setpoint {
    /// The position as the CiA 402 INTEGER32 (0x6062), wrapping like the sensor count.
    #[must_use]
    pub const fn position_i32(&self) -> i32 {
        self.position as i32
    }
}

/// Position, velocity and acceleration at one instant, full precision: Q32 inc, Q32 inc/tick, Q40 inc/tick².
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct State {
    pub(super) p: i128,
    pub(super) v: i128,
    pub(super) a: i128,
}

impl State {
    pub(super) fn setpoint(&self) -> Setpoint {
        Setpoint {
            position: sat_i64(round_shr(self.p, 32)),
            position_fine: sat_i64(self.p >> 16),
            velocity: Velocity(sat_i64(self.v)),
            acceleration: Acceleration(sat_i64(self.a)),
        }
    }
}

/// One ramp or cruise: velocity from `v0` to `v0 + dv` over `duration`, shaped linear or sin².
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Segment {
    /// Q32 ticks from the plan's origin.
    start: i128,
    /// Q32 ticks, > 0.
    duration: i128,
    /// Q32 inc.
    p0: i128,
    /// Q32 inc/tick.
    v0: i128,
    /// Q32 inc/tick.
    dv: i128,
    /// `dv * duration`, Q32 inc.
    area: i128,
    /// The mean acceleration, Q40 inc/tick², signed like `dv`: the ramp's rate (its duration is `|dv| / rate`,
    /// so `dv / duration` is the rate up to the rounding of the duration), 0 for a cruise.
    accel: i128,
    shape: ProfileType,
}

impl Segment {
    /// A ramp from `v0` to `v1` over `duration` at the mean rate `rate` (Q40, > 0; 0 for a cruise).
    fn new(start: i128, duration: i128, p0: i128, v0: i128, v1: i128, rate: i128, shape: ProfileType) -> Self {
        let dv = v1.saturating_sub(v0);
        let accel = mul_sign(rate, dv.signum());
        Self { start, duration, p0, v0, dv, area: mul_shr(dv, duration, 32), accel, shape }
    }

    fn end(&self) -> i128 {
        self.start.saturating_add(self.duration)
    }

    fn v1(&self) -> i128 {
        self.v0.saturating_add(self.dv)
    }

    /// The state `tau` (Q32 ticks, clamped to [0, duration]) after the segment's start.
    ///
    /// With `u = tau / duration` and `K = dv * duration`:
    /// - linear: `p = p0 + v0 tau + K u²/2`, `v = v0 + dv u`, `a = dv / duration`;
    /// - sin²: `p = p0 + v0 tau + K (u²/2 - sin²(pi u) / (2 pi²))`, `v = v0 + dv (u - sin(2 pi u) / (2 pi))`,
    ///   `a = (dv / duration) 2 sin²(pi u)`.
    ///
    /// At `u = 1` both give `p0 + (v0 + v1) duration / 2` (the sine terms vanish exactly).
    fn eval(&self, tau: i128) -> State {
        // The upper bound floored at 0: the bounds are then ordered for the compiler too, and `clamp` has no
        // formatted 128-bit panic to keep (1.7 KB of formatting in the images that print panics, issue 17).
        let tau = tau.clamp(0, self.duration.max(0));
        let pv = self.p0.saturating_add(mul_shr(self.v0, tau, 32));
        if self.dv == 0 {
            return State { p: pv, v: self.v0, a: 0 };
        }
        // u = tau / duration in Q62: the shape terms are then exact to ~2^-62 of the segment's area, so the exact
        // v0 tau term and the shape term never disagree by a visible amount (monotonic samples near a slow end).
        let u = if tau >= self.duration { ONE_Q62 } else { div_shl(tau, self.duration, 62) };
        let half_u2 = mul_shr(u, u, 63); // Q62, u <= 2^62
        let (g, vs, a_shape) = match self.shape {
            ProfileType::Trapezoidal => (half_u2, u, ONE_Q62),
            // At the ends the sines are exactly zero (`sin_pi_q60` and `sin_2pi_q60` return 0 there): the end state
            // of every planned segment is taken here without evaluating them.
            ProfileType::SinSquared if u == ONE_Q62 => (half_u2, u, 0),
            ProfileType::SinSquared => {
                let s1 = i128::from(sin_pi_q60(u));
                let sin2 = mul_shr(s1, s1, 60); // sin²(pi u), Q60
                let s2 = i128::from(sin_2pi_q60(u));
                (
                    half_u2.saturating_sub(mul_shr(sin2, INV_2PI2_Q60, 58)),
                    u.saturating_sub(mul_shr(s2, INV_2PI_Q60, 58)),
                    sin2 << 3, // 2 sin², Q62
                )
            }
        };
        State {
            p: pv.saturating_add(mul_shr(self.area, g, 62)),
            v: self.v0.saturating_add(mul_shr(self.dv, vs, 62)),
            a: mul_shr(self.accel, a_shape, 62),
        }
    }
}

/// What a plan does once its segments are over.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) enum PlanKind {
    /// At rest, nothing planned.
    #[default]
    Idle,
    /// A position move to `target` (increments).
    Position { target: i64 },
    /// A velocity command: the end velocity is kept forever.
    Velocity,
    /// A halt or quick stop: at rest at the end.
    Stop,
}

/// A planned motion: segments from the plan's origin, then the end state (continued at `end_velocity`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Plan {
    segments: [Segment; MAX_SEGMENTS],
    len: usize,
    /// Q32 ticks until the end state.
    pub(super) duration: i128,
    /// Q32 inc at `duration` (the exact target for position moves and stops).
    pub(super) end_position: i128,
    /// Q32 inc/tick after `duration`.
    pub(super) end_velocity: i128,
    /// The residual (`end_position` minus where the segments end) over `duration`, Q32 inc/tick: the rate at which
    /// the residual is spread over the plan.
    residual_rate: i128,
    /// Sign of the final approach to a resting end (the clamp against passing the target), 0 for none.
    approach: i128,
    pub(super) kind: PlanKind,
    pub(super) limits: Option<Limits>,
}

impl Plan {
    pub(super) fn rest(position: i128) -> Self {
        Self {
            segments: [Segment::default(); MAX_SEGMENTS],
            len: 0,
            duration: 0,
            end_position: position,
            end_velocity: 0,
            residual_rate: 0,
            approach: 0,
            kind: PlanKind::Idle,
            limits: None,
        }
    }

    /// At rest at `position` (Q32 inc), nothing planned, in place ([`Self::rest`] without writing the segments,
    /// which are left as they are, beyond the length).
    pub(super) fn set_rest(&mut self, position: i128) {
        self.len = 0;
        self.duration = 0;
        self.end_position = position;
        self.end_velocity = 0;
        self.residual_rate = 0;
        self.approach = 0;
        self.kind = PlanKind::Idle;
        self.limits = None;
    }

    /// At `position` (Q32 inc) moving at `velocity` (Q32 inc/tick) from now on, in place: a velocity command whose
    /// ramp is over.
    pub(super) fn set_endless(&mut self, position: i128, velocity: i128) {
        self.set_rest(position);
        self.end_velocity = velocity;
        self.kind = PlanKind::Velocity;
    }

    pub(super) fn eval(&self, t: i128) -> State {
        if t >= self.duration {
            let tau = t.saturating_sub(self.duration);
            return State {
                p: self.end_position.saturating_add(mul_shr(self.end_velocity, tau, 32)),
                v: self.end_velocity,
                a: 0,
            };
        }
        let last = self.len.saturating_sub(1);
        for (i, seg) in self.segments.iter().take(self.len).enumerate() {
            if t < seg.end() {
                let mut st = seg.eval(t.saturating_sub(seg.start));
                if self.residual_rate != 0 {
                    // `residual_rate t` is `residual t / duration` up to the rate's rounding (less than one Q32
                    // LSB per tick of the plan): a multiply per sample instead of a division.
                    st.p = st.p.saturating_add(mul_shr(self.residual_rate, t.max(0), 32));
                    st.v = st.v.saturating_add(self.residual_rate);
                }
                if i == last && self.approach > 0 {
                    st.p = st.p.min(self.end_position);
                } else if i == last && self.approach < 0 {
                    st.p = st.p.max(self.end_position);
                }
                return st;
            }
        }
        State { p: self.end_position, v: self.end_velocity, a: 0 }
    }
}

/// Appends segments, tracking the time, position and velocity at the end of the last one.
struct Builder<'a> {
    /// The plan being written, in place (a plan is several hundred bytes: building it elsewhere and copying it
    /// would cost more than some of the arithmetic).
    plan: &'a mut Plan,
    t: i128,
    p: i128,
    v: i128,
    shape: ProfileType,
}

impl<'a> Builder<'a> {
    /// Starts writing `plan` anew (its old segments are overwritten or left beyond its length).
    fn new(plan: &'a mut Plan, p: i128, v: i128, shape: ProfileType) -> Self {
        plan.len = 0;
        Self { plan, t: 0, p, v, shape }
    }

    /// Ramps to `v1` at the mean rate `rate` (Q40, > 0).
    fn ramp_to(&mut self, v1: i128, rate: i128) {
        let duration = ramp_duration(v1.saturating_sub(self.v).saturating_abs(), rate);
        self.ramp_over(v1, rate, duration);
    }

    /// Ramps to `v1` at the mean rate `rate` over `duration`, the [`ramp_duration`] of the step (computed once by
    /// the caller that needed it before).
    fn ramp_over(&mut self, v1: i128, rate: i128, duration: i128) {
        if v1 == self.v {
            return;
        }
        if duration <= 0 {
            // A velocity step far below one LSB of time: take it at once.
            self.v = v1;
            return;
        }
        self.push(duration, v1, rate, self.shape);
    }

    /// Holds the current velocity for `duration` (Q32 ticks).
    fn cruise(&mut self, duration: i128) {
        if duration > 0 && self.v != 0 {
            self.push(duration, self.v, 0, ProfileType::Trapezoidal);
        }
    }

    /// Appends the segment from the builder's state to `v1` over `duration` at the mean rate `rate` (the arguments
    /// of [`Segment::new`]). It is built in its slot, not moved there: a segment is 144 bytes, and the planning
    /// slow tick is the slowest of all.
    fn push(&mut self, duration: i128, v1: i128, rate: i128, shape: ProfileType) {
        let Some(slot) = self.plan.segments.get_mut(self.plan.len) else {
            // No free slot cannot happen (at most four segments per plan); the velocity still follows the command
            // and the residual correction takes the position to the end state (`Segment::v1`: v0 + (v1 - v0)).
            self.v = self.v.saturating_add(v1.saturating_sub(self.v));
            return;
        };
        *slot = Segment::new(self.t, duration, self.p, self.v, v1, rate, shape);
        let end = slot.eval(slot.duration);
        self.plan.len = self.plan.len.saturating_add(1);
        self.t = slot.end();
        self.p = end.p;
        self.v = slot.v1();
    }

    fn finish(self, kind: PlanKind, end_position: i128, end_velocity: i128, limits: Option<Limits>) {
        let residual = end_position.saturating_sub(self.p);
        let duration = self.t;
        let plan = self.plan;
        plan.residual_rate = if duration > 0 { div_shl(residual, duration, 32) } else { 0 };
        plan.approach = match plan.segments.get(plan.len.saturating_sub(1)) {
            Some(last) if plan.len > 0 && end_velocity == 0 => last.v0.signum(),
            _ => 0,
        };
        plan.duration = duration;
        plan.end_position = end_position;
        plan.end_velocity = end_velocity;
        plan.kind = kind;
        plan.limits = limits;
    }
}

/// Time to change the velocity by `dv` (Q32, >= 0) at the mean rate `rate` (Q40): Q32 ticks.
fn ramp_duration(dv: i128, rate: i128) -> i128 {
    div_shl(dv, rate.max(1), 40)
}

/// The duration of a ramp from `v0` to `v1` and the position of its end relative to its start, exactly as the
/// segment evaluates it.
fn ramp_distance(v0: i128, v1: i128, rate: i128, shape: ProfileType) -> (i128, i128) {
    let duration = ramp_duration(v1.saturating_sub(v0).saturating_abs(), rate);
    if duration <= 0 {
        return (duration, 0);
    }
    (duration, Segment::new(0, duration, 0, v0, v1, rate, shape).eval(duration).p)
}

/// `2 * rate * distance` in Q64 (inc²/tick²): rate Q40, distance Q32.
pub(super) fn twice_rate_distance(rate: i128, distance: i128) -> i128 {
    mul_shr(rate, distance, 7)
}

/// Plans a position move from (`p0`, `v0`) to `target` (Q32 inc), arriving with `end_velocity` (signed, in the
/// direction of the move; 0 for a normal move), into `out`.
pub(super) fn plan_position(
    out: &mut Plan,
    p0: i128,
    v0: i128,
    target: i128,
    target_inc: i64,
    end_velocity: i128,
    lim: Limits,
) {
    let mut b = Builder::new(out, p0, v0, lim.shape);
    // Two passes at most: a stop (moving away, or overshoot) makes the second pass start at rest.
    for _ in 0..2 {
        let d = target.saturating_sub(b.p);
        let s = if d != 0 { d.signum() } else { b.v.signum() };
        if s == 0 {
            break;
        }
        // Normalised to the direction of the target: s = +-1, so the products are sign flips (`mul_sign`).
        let dn = mul_sign(d, s);
        let u0 = mul_sign(b.v, s);
        let wn = mul_sign(end_velocity, s).clamp(0, lim.vmax.max(0));
        if u0 < 0 {
            b.ramp_to(0, lim.dec);
            continue;
        }
        let u0_sq = mul_shr(u0, u0, 0);
        let wn_sq = mul_shr(wn, wn, 0);
        if u0 > wn {
            // Distance needed to slow from u0 to wn: (u0² - wn²) / 2d, Q32.
            let excess = u0_sq.saturating_sub(wn_sq);
            let needed = div_shl(excess, lim.dec.saturating_mul(2), 8);
            if needed > dn.saturating_add(OVERSHOOT_TOLERANCE) {
                if wn == 0 {
                    // Cannot stop before the target: stop past it, then come back (reversal).
                    b.ramp_to(0, lim.dec);
                    continue;
                }
                // Continuing move: arrive faster than wn, decelerating all the way.
                let w2 = isqrt(u0_sq.saturating_sub(twice_rate_distance(lim.dec, dn)));
                b.ramp_to(mul_sign(w2, s), lim.dec);
                break;
            }
        } else if u0 < wn {
            let room = twice_rate_distance(lim.acc, dn);
            if wn_sq.saturating_sub(u0_sq) > room {
                // Too short to reach the end velocity: accelerate all the way.
                let w2 = isqrt(u0_sq.saturating_add(room));
                b.ramp_to(mul_sign(w2, s), lim.acc);
                break;
            }
        }
        // Peak velocity: (vp² - u0²)/2a + (vp² - wn²)/2d = dn  =>  vp² = 2 dn h + u0² (1 - r) + wn² r,
        // r = a / (a + d), h = d r.
        let vp = if u0 >= lim.vmax {
            lim.vmax
        } else {
            let r = div_shl(lim.acc, lim.acc.saturating_add(lim.dec), 32).clamp(0, ONE_Q32);
            let h = mul_shr(lim.dec, r, 32);
            let vp_sq = twice_rate_distance(h, dn)
                .saturating_add(mul_shr(u0_sq, ONE_Q32.saturating_sub(r), 32))
                .saturating_add(mul_shr(wn_sq, r, 32));
            isqrt(vp_sq).min(lim.vmax)
        };
        let rate = if vp >= u0 { lim.acc } else { lim.dec };
        b.ramp_to(mul_sign(vp, s), rate);
        let (last_duration, last) = ramp_distance(vp, wn, lim.dec, lim.shape);
        let cruise = mul_sign(target.saturating_sub(b.p), s).saturating_sub(last);
        if cruise > 0 && vp > 0 {
            b.cruise(div_shl(cruise, vp, 32));
        }
        // b.v is vp s here (the ramp and the cruise end there): the last ramp is the one just measured.
        b.ramp_over(mul_sign(wn, s), lim.dec, last_duration);
        break;
    }
    let end_velocity = b.v;
    b.finish(PlanKind::Position { target: target_inc }, target, end_velocity, Some(lim))
}

/// Plans a velocity command from (`p0`, `v0`) to `target` (Q32 inc/tick): stop first if the sign changes, ramp up
/// with the acceleration and down with the deceleration, then keep the velocity. Into `out`.
pub(super) fn plan_velocity(out: &mut Plan, p0: i128, v0: i128, target: i128, lim: Limits) {
    let mut b = Builder::new(out, p0, v0, lim.shape);
    if v0 != 0 && target != 0 && v0.signum() != target.signum() {
        b.ramp_to(0, lim.dec);
    }
    let rate = if target.saturating_abs() >= b.v.saturating_abs() { lim.acc } else { lim.dec };
    b.ramp_to(target, rate);
    let (p, v) = (b.p, b.v);
    b.finish(PlanKind::Velocity, p, v, Some(lim))
}

/// Plans a stop from (`p0`, `v0`) with the mean deceleration `dec`, ending at rest on a whole increment, into
/// `out`.
pub(super) fn plan_stop(out: &mut Plan, p0: i128, v0: i128, dec: i128, shape: ProfileType) {
    let mut b = Builder::new(out, p0, v0, shape);
    b.ramp_to(0, dec.max(1));
    let end = round_shr(b.p, 32).saturating_mul(ONE_Q32);
    b.finish(PlanKind::Stop, end, 0, None)
}
