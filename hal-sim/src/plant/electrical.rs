//! The electrical building blocks of the two segment integrators ([`super::switching`], [`super::freewheel`]):
//! the amplitude-invariant dq/abc transforms, the back-EMF, the terminal of a disconnected phase, the rotation of
//! the angle inside a segment, the leg model of one segment and the classical RK4 step.

use super::Plant;

const SQRT3: f64 = 1.732_050_807_568_877_2;
/// Currents below this are treated as zero by the diode-bridge model, in A.
pub(super) const ZERO_CURRENT_A: f64 = 1e-12;

/// Coefficients of one leg on one segment: pole voltage `a V_bus + b`, bus-current share `c i`.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct LegDrive {
    pub(super) a: f64,
    pub(super) b: f64,
    pub(super) c: f64,
}

impl LegDrive {
    /// High switch on: the pole at the bus voltage, the phase current drawn from the bus.
    pub(super) const HIGH: Self = Self { a: 1.0, b: 0.0, c: 1.0 };
    /// Low switch on: the pole at the negative rail.
    pub(super) const LOW: Self = Self { a: 0.0, b: 0.0, c: 0.0 };

    /// The upper diode conducts (a negative phase current): the pole a diode drop above the bus.
    pub(super) fn upper_diode(v_diode: f64) -> Self {
        Self { a: 1.0, b: v_diode, c: 1.0 }
    }

    /// The lower diode conducts (a positive phase current): the pole a diode drop below the negative rail.
    pub(super) fn lower_diode(v_diode: f64) -> Self {
        Self { a: 0.0, b: -v_diode, c: 0.0 }
    }
}

/// Classical fourth-order Runge-Kutta step.
#[inline(always)]
pub(super) fn rk4<const N: usize>(s: &[f64; N], h: f64, f: impl Fn(&[f64; N]) -> [f64; N]) -> [f64; N] {
    let add = |x: &[f64; N], k: &[f64; N], w: f64| -> [f64; N] { core::array::from_fn(|i| x[i] + w * k[i]) };
    let k1 = f(s);
    let k2 = f(&add(s, &k1, 0.5 * h));
    let k3 = f(&add(s, &k2, 0.5 * h));
    let k4 = f(&add(s, &k3, h));
    core::array::from_fn(|i| s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
}

/// Inverse Park then inverse (amplitude-invariant) Clarke.
#[inline(always)]
pub(super) fn dq_to_abc(i_d: f64, i_q: f64, sin: f64, cos: f64) -> [f64; 3] {
    let alpha = i_d * cos - i_q * sin;
    let beta = i_d * sin + i_q * cos;
    [alpha, -0.5 * alpha + 0.5 * SQRT3 * beta, -0.5 * alpha - 0.5 * SQRT3 * beta]
}

/// Amplitude-invariant Clarke then Park (the zero sequence drops out).
#[inline(always)]
pub(super) fn abc_to_dq(x: [f64; 3], sin: f64, cos: f64) -> [f64; 2] {
    let alpha = (2.0 * x[0] - x[1] - x[2]) / 3.0;
    let beta = (x[1] - x[2]) / SQRT3;
    [alpha * cos + beta * sin, -alpha * sin + beta * cos]
}

/// Back-EMF of the three phases: `-w_e psi sin(theta_e - k 120 deg)`.
#[inline(always)]
pub(super) fn back_emf(omega_e: f64, psi: f64, sin: f64, cos: f64) -> [f64; 3] {
    // sin(x - 120) = -sin/2 - cos sqrt3/2; sin(x + 120) = -sin/2 + cos sqrt3/2.
    let k = -omega_e * psi;
    [k * sin, k * (-0.5 * sin - 0.5 * SQRT3 * cos), k * (-0.5 * sin + 0.5 * SQRT3 * cos)]
}

/// Terminal voltage of the disconnected motor phase `x` (as [`open_phase_terminal_drive`], from the terminal
/// voltages `u` themselves): what the reference integrator evaluates at every RK4 stage.
#[cfg(test)]
#[inline(always)]
pub(super) fn open_phase_terminal(u: [f64; 3], e: [f64; 3], x: usize) -> f64 {
    let (y, z) = ((x + 1) % 3, (x + 2) % 3);
    e[x] + 0.5 * ((u[y] - e[y]) + (u[z] - e[z]))
}

/// The terminal of the disconnected motor phase `x` ([`super::faults::PlantFaults::phase_open`]) as a drive
/// `(a, b)`, terminal `a V_bus + b`, given the drives of the terminals of the other two and the back-EMFs `e`: the
/// phase carries no current, so its terminal is its back-EMF above the star point, and the star point is where the
/// two connected phases, which carry equal and opposite currents through equal inductances, put it: the mean of
/// their `u - e`. Substituted into the dq model (whose star point is the mean of the three terminals, the zero
/// sequence dropping out) this gives `di_x/dt = 0` exactly for `Ld = Lq` (the reference motor); with saliency the
/// projection after each interval removes the rest.
#[inline(always)]
pub(super) fn open_phase_terminal_drive(legs: &[LegDrive; 3], e: [f64; 3], x: usize) -> (f64, f64) {
    let (y, z) = ((x + 1) % 3, (x + 2) % 3);
    (0.5 * (legs[y].a + legs[z].a), e[x] + 0.5 * ((legs[y].b - e[y]) + (legs[z].b - e[z])))
}

/// `(cos delta, sin delta)` of a rotation by `delta` rad: a Taylor series for the angles one interval turns the
/// rotor frame by (truncation error below 3e-15 for |delta| < 0.1 rad: 0.1 rad is 10 us at 9,500 rad/s
/// electrical), the library function beyond.
#[inline(always)]
pub(super) fn small_rotation(delta: f64) -> (f64, f64) {
    if delta.abs() < 0.1 {
        let d2 = delta * delta;
        // Multiplications by the reciprocals (divisions are slow, and these do not fold).
        const INV: [f64; 7] = [1.0 / 6.0, 1.0 / 20.0, 1.0 / 42.0, 1.0 / 2.0, 1.0 / 12.0, 1.0 / 30.0, 1.0 / 56.0];
        let s = delta * (1.0 - d2 * INV[0] * (1.0 - d2 * INV[1] * (1.0 - d2 * INV[2])));
        let c = 1.0 - d2 * INV[3] * (1.0 - d2 * INV[4] * (1.0 - d2 * INV[5] * (1.0 - d2 * INV[6])));
        (c, s)
    } else {
        let (s, c) = delta.sin_cos();
        (c, s)
    }
}

/// `(sin, cos)` of `theta + delta` from `(sin, cos)` of `theta` and the rotation `(cos delta, sin delta)`.
#[inline(always)]
pub(super) fn rotate((sin, cos): (f64, f64), (c, s): (f64, f64)) -> (f64, f64) {
    (sin * c + cos * s, cos * c - sin * s)
}

/// sin and cos of `theta0 + delta` from those of `theta0`: a rotation by a short Taylor series for the small angle
/// steps inside one segment (truncation error below 1e-15 for |delta| < 0.02 rad), the library functions otherwise.
#[inline(always)]
fn sin_cos_after(sin0: f64, cos0: f64, theta0: f64, delta: f64) -> (f64, f64) {
    if delta.abs() < 0.02 {
        let d2 = delta * delta;
        let s = delta * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0));
        let c = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0));
        (sin0 * c + cos0 * s, cos0 * c - sin0 * s)
    } else {
        (theta0 + delta).sin_cos()
    }
}

/// The electrical angle at the start of a segment with its sine and cosine: the angles inside the segment are
/// reached from it by a rotation ([`sin_cos_after`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct SegmentAngle {
    /// Electrical angle at the segment start, in rad.
    pub(super) theta: f64,
    /// Its sine.
    pub(super) sin: f64,
    /// Its cosine.
    pub(super) cos: f64,
}

impl SegmentAngle {
    #[inline(always)]
    pub(super) fn new(theta: f64) -> Self {
        let (sin, cos) = theta.sin_cos();
        Self { theta, sin, cos }
    }

    /// sin and cos of the electrical angle `theta`, reached inside the segment.
    #[inline(always)]
    pub(super) fn sin_cos_at(&self, theta: f64) -> (f64, f64) {
        sin_cos_after(self.sin, self.cos, self.theta, theta - self.theta)
    }
}

/// Take phase `x` out of the phase currents `i`: its current is removed and shared equally by the two others (the
/// projection onto the plane `i_x = 0` that keeps the sum of the three).
#[inline(always)]
pub(super) fn remove_phase_current(i: &mut [f64; 3], x: usize) {
    let ix = i[x];
    for (y, iy) in i.iter_mut().enumerate() {
        *iy += if y == x { -ix } else { 0.5 * ix };
    }
}

impl Plant {
    /// The phase currents A, B, C now, in A.
    pub(super) fn i_abc(&self) -> [f64; 3] {
        let (s, c) = (f64::from(self.params.pole_pairs) * self.theta_m).sin_cos();
        dq_to_abc(self.i_d, self.i_q, s, c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_round_trip() {
        let (s, c) = 0.7f64.sin_cos();
        let abc = dq_to_abc(1.5, -2.0, s, c);
        assert!((abc[0] + abc[1] + abc[2]).abs() < 1e-12);
        let dq = abc_to_dq(abc, s, c);
        assert!((dq[0] - 1.5).abs() < 1e-12 && (dq[1] + 2.0).abs() < 1e-12);
        // Back-EMF lies on the q axis with amplitude w_e psi.
        let e = back_emf(100.0, 0.01, s, c);
        let edq = abc_to_dq(e, s, c);
        assert!(edq[0].abs() < 1e-12 && (edq[1] - 1.0).abs() < 1e-12);
    }
}
