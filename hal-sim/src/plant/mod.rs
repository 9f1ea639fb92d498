//! The simulated motor, inverter, DC bus and sensors that tier 1 of the firmware runs against.
//!
//! One call of [`Plant::step`] simulates one PWM period and returns what the ADC and the position sensors captured
//! in it, in the data contract of `firmware::hal::power`. The plant is deterministic: the same parameters, seed and
//! command sequence give bit-identical results.
//!
//! # Timeline
//!
//! Period `n` is `[n T, (n + 1) T)` with `T` = 40 us (25 kHz). TIM1 counts centre-aligned, 0 -> ARR -> 0:
//!
//! ```text
//!            period n-1                      period n                       period n+1
//!   |----------------------------|----------------------------|----------------------------|
//!  UEV          ^ sample n-1     UEV(n)       ^ sample n      UEV(n+1)
//!   CNT: 0 ... ARR ... 0           0  ...    ARR   ...  0
//!                 \__ tick n-1 runs, writes the preload        \__ tick n runs, writes the preload
//!                     registers during period n-1                  registers during period n
//! ```
//!
//! * **Update event (UEV)** at the valley `n T`: the preloaded compare values (and the output enable) become
//!   active for the whole of period `n`.
//! * **Sample** at the centre `(n + 1/2) T` (counter at ARR, all low switches on): the three shunts, the bus
//!   voltage and the temperature are converted, and the encoder counter and Halls are read.
//! * Tier-1 tick `n` handles sample `n` and writes its duties into the preload registers during the second half of
//!   period `n`; they take effect at UEV(n+1), the start of period `n + 1`.
//!
//! In the API: **call `n` of `step(cmd)` simulates period `n`**. Its `cmd` is the preload content written by tick
//! `n - 1` during the previous period; it is applied at the update event that starts the period this call
//! simulates, and the returned [`Measurements`] are the ones sampled at the centre of that period. The natural
//! loop `let m = plant.step(&cmd); cmd = current_step(&m);` therefore reproduces the hardware exactly: the duties
//! computed from sample `n` (tick `n`) are passed to call `n + 1` and act over period `n + 1`, half a period after
//! the sample; their first effect on a measurement is sample `n + 1`, one period after the sample they were
//! computed from. So the transport delay is one period (sample to sample), half a period of pure delay plus the
//! half-period centre of the zero-order hold. Tier 1 never sees a duty change in the sample of the tick that
//! wrote it. Counted in tier-1 ticks, as the issue states it: the duties written in tick `k` take effect at the
//! update event at the start of period `k + 1` (and reach the plant through call `k + 1`).
//!
//! The output enable is applied at the update event too (in hardware, clearing MOE acts at once: the model
//! disables up to half a period late).
//!
//! # Model
//!
//! * **Motor**: sinusoidal PMSM in the rotor dq frame (amplitude-invariant), `v_d = R i_d + Ld di_d/dt - w_e Lq
//!   i_q`, `v_q = R i_q + Lq di_q/dt + w_e (Ld i_d + psi)`, torque `1.5 p (psi i_q + (Ld - Lq) i_d i_q)`; `R`
//!   follows the winding temperature. The switch resistance is in series with every phase.
//! * **Mechanics**: `J dw/dt = T_e - T_load - b w - T_c sgn(w)`, with stiction: a rotor at rest stays at rest
//!   while `|T_e - T_load| <= T_c`, and the speed is clamped to zero when it would change sign. The rotor can be
//!   locked or driven at a fixed speed by an ideal dynamometer ([`Mechanics`]). A positive load torque opposes
//!   positive rotation.
//! * **Inverter**: each leg follows the centre-aligned pattern of its compare value with dead time
//!   ([`inverter::LegPattern`]): pole at the bus voltage (high switch), at 0 (low switch) or, both switches off, at
//!   `-V_diode` for a positive phase current or `V_bus + V_diode` for a negative one (the diode's side is chosen
//!   from the current's sign at the start of the dead time). A current that reaches zero during the dead time stops
//!   there, and a leg entering dead time with zero current floats (its terminal follows the motor so that the
//!   current stays zero, unless the back-EMF pulls it beyond a rail): the zero-current clamping of real inverters.
//!   Over a period with a constant current sign the pole voltage averages
//!   `d V_bus - sgn(i) (V_bus + 2 V_diode) t_dead / T - R_switch i`; compare values of 0 and ARR have no edges and
//!   no dead-time error.
//! * **Disabled outputs** (or a tripped break input): a three-phase diode bridge. A phase with current keeps
//!   conducting through the diode that carries it (`-V_diode` for a positive current, `V_bus + V_diode` for a
//!   negative one) until its current reaches zero, where it stops (diodes block reverse current); an open phase
//!   starts conducting when its back-EMF would pull its terminal beyond a rail, so a motor spinning with a
//!   line-to-line EMF above `V_bus + 2 V_diode` charges the bus, and below it the currents decay to zero and stay
//!   there. This part works in abc coordinates with the mean inductance `(Ld + Lq) / 2` (exact when `Ld = Lq`).
//! * **Injected power faults** ([`faults::PlantFaults`]): an open motor phase carries no current, its terminal
//!   floating at its back-EMF above the star point of the two others (`open_phase_terminal`), switching or not; a
//!   short between two outputs is a resistance between their poles ([`inverter::OutputShort`]), loading the legs,
//!   their shunts, the bus and the over-current comparator while they switch.
//! * **DC bus**: `C dV/dt = i_source - i_dc` with `i_source = (V_source - V) / R_source` (not negative unless the
//!   source sinks current) and `i_dc` the sum of the phase currents of the legs connected to the positive rail, so
//!   regeneration raises the bus voltage.
//! * **Thermal**: winding and housing nodes (copper loss `1.5 R |i_dq|^2` into the winding; 20 s and 600 s time
//!   constants), and a power-stage node heated by the switch conduction losses, integrated once per period.
//! * **Sensors**: see [`Plant::step`] and [`sensors`].
//!
//! # Integration
//!
//! The period is cut at every switching instant of the three legs (edges and dead-time ends) and at the sample
//! instant; each interval is split into equal segments no longer than `T / substeps_per_period` (8 by default:
//! 5 us, so a period has about 14 to 20 segments). The pole voltages are therefore constant on each segment apart
//! from the bus voltage, which is part of the state, and each segment is one classical Runge-Kutta (RK4) step of
//! the joint state (`i_d, i_q, w, theta, V_bus`). The fastest dynamics are the bus (`R_source C` = 23.5 us, at
//! least 4.7 steps per time constant: RK4 local error about `(h / tau)^5 / 120` = 3e-6 relative) and the winding
//! (`L / R` = 0.61 ms, over 120 steps per time constant). Against a 128-sub-step run of 0.24 s of switching and
//! coasting, the default differs by at most 1.2e-4 A in the currents, 0.6 mV on the bus and 1.4e-4 rad/s in speed:
//! the model's own idealisations (ideal switches, constant diode drops) dominate by orders of magnitude. An exact
//! discretisation of the RL part alone would not cover its coupling with the bus and the back-EMF, and RK4 needs no
//! matrix exponentials. Angles inside a segment are advanced by a rotation instead of new `sin_cos` calls. The
//! thermal nodes (time constants of 20 s and more) take one Euler step per period. No allocation in `step`: one
//! simulated second costs about 0.05 s of CPU in release builds.

pub mod faults;
pub mod inverter;
pub mod io;
mod params;
pub mod rng;
pub mod sensors;

pub use io::{BrakeParams, InputSource, InputWiring, IoParams};
pub use params::PlantParams;

use core::f64::consts::PI;

use firmware::hal::power::{AdcSamples, FeedbackSample, Measurements, PwmCommand, PWM_FREQUENCY_HZ};

use inverter::{LegPattern, LegState};
use rng::Rng;

/// Length of one PWM period (and of one call of [`Plant::step`]), in s.
pub const PERIOD_S: f64 = 1.0 / PWM_FREQUENCY_HZ as f64;

const SQRT3: f64 = 1.732_050_807_568_877_2;
/// Currents below this are treated as zero by the diode-bridge model, in A.
const ZERO_CURRENT_A: f64 = 1e-12;

/// How the shaft moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mechanics {
    /// Free shaft: the motor torque, friction and load torque accelerate the total inertia.
    Free,
    /// Locked rotor: the angle stays where it is and the speed is zero.
    Locked,
    /// Driven at a constant speed by an ideal dynamometer; the motor and load torques have no effect.
    Driven {
        /// Mechanical speed, in rad/s.
        speed_rad_s: f64,
    },
}

/// The true state of the plant at one instant (for tests; the firmware sees only [`Measurements`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlantState {
    /// Simulated time since the start, in s.
    pub time_s: f64,
    /// Phase currents A, B, C (positive into the motor), in A.
    pub i_abc_a: [f64; 3],
    /// d and q currents (amplitude-invariant), in A.
    pub i_dq_a: [f64; 2],
    /// Currents through the shunts A, B, C at the sample instant (the phase current where the low switch or low
    /// diode conducts, else 0), in A. Only [`Plant::state_at_sample`] fills it; [`Plant::state`] gives zeros.
    pub shunt_currents_a: [f64; 3],
    /// Mechanical angle, unwrapped (0 = d axis on phase A), in rad.
    pub theta_m_rad: f64,
    /// Electrical angle of the d axis, wrapped to [0, 2pi), in rad.
    pub theta_e_rad: f64,
    /// Mechanical speed, in rad/s.
    pub omega_m_rad_s: f64,
    /// Mechanical speed, in rpm.
    pub speed_rpm: f64,
    /// Electrical speed, in rad/s.
    pub omega_e_rad_s: f64,
    /// Electromagnetic torque, in N m.
    pub torque_nm: f64,
    /// Load torque acting on the shaft (constant plus profile, last evaluated), in N m.
    pub load_torque_nm: f64,
    /// DC-bus (capacitor) voltage, in V.
    pub bus_voltage_v: f64,
    /// Current delivered by the DC source, in A.
    pub source_current_a: f64,
    /// Winding temperature, in degC.
    pub winding_temp_c: f64,
    /// Housing temperature, in degC.
    pub housing_temp_c: f64,
    /// Power-stage temperature, in degC.
    pub power_stage_temp_c: f64,
    /// Phase resistance at the current winding temperature, in ohm.
    pub phase_resistance_ohm: f64,
    /// The over-current break is latched (outputs forced off).
    pub break_latched: bool,
}

/// Averages over the last simulated period.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PeriodAverages {
    /// Pole (leg output to negative rail) voltages A, B, C, including switch and diode drops, in V.
    pub pole_voltage_v: [f64; 3],
    /// Phase (line-to-neutral) voltages A, B, C: pole voltage minus the mean of the three, in V.
    pub phase_voltage_v: [f64; 3],
    /// Terminal voltage in the rotor frame (d, q), in V.
    pub dq_voltage_v: [f64; 2],
    /// DC-bus voltage, in V.
    pub bus_voltage_v: f64,
    /// DC current drawn by the inverter from the bus (negative when regenerating), in A.
    pub bus_current_a: f64,
    /// Copper loss in the winding, in W.
    pub copper_loss_w: f64,
}

/// A load-torque profile: `f(time_s, theta_m_rad, omega_m_rad_s) -> N m`, evaluated at the start of every
/// integration segment.
pub type LoadProfile = Box<dyn FnMut(f64, f64, f64) -> f64 + Send>;

/// Coefficients of one leg on one segment: pole voltage `a V_bus + b`, bus-current share `c i`.
#[derive(Clone, Copy, Debug, Default)]
struct LegDrive {
    a: f64,
    b: f64,
    c: f64,
}

/// Classical fourth-order Runge-Kutta step.
#[inline(always)]
fn rk4<const N: usize>(s: &[f64; N], h: f64, f: impl Fn(&[f64; N]) -> [f64; N]) -> [f64; N] {
    let add = |x: &[f64; N], k: &[f64; N], w: f64| -> [f64; N] { core::array::from_fn(|i| x[i] + w * k[i]) };
    let k1 = f(s);
    let k2 = f(&add(s, &k1, 0.5 * h));
    let k3 = f(&add(s, &k2, 0.5 * h));
    let k4 = f(&add(s, &k3, h));
    core::array::from_fn(|i| s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
}

/// Inverse Park then inverse (amplitude-invariant) Clarke.
#[inline(always)]
fn dq_to_abc(i_d: f64, i_q: f64, sin: f64, cos: f64) -> [f64; 3] {
    let alpha = i_d * cos - i_q * sin;
    let beta = i_d * sin + i_q * cos;
    [alpha, -0.5 * alpha + 0.5 * SQRT3 * beta, -0.5 * alpha - 0.5 * SQRT3 * beta]
}

/// Amplitude-invariant Clarke then Park (the zero sequence drops out).
#[inline(always)]
fn abc_to_dq(x: [f64; 3], sin: f64, cos: f64) -> [f64; 2] {
    let alpha = (2.0 * x[0] - x[1] - x[2]) / 3.0;
    let beta = (x[1] - x[2]) / SQRT3;
    [alpha * cos + beta * sin, -alpha * sin + beta * cos]
}

/// Back-EMF of the three phases: `-w_e psi sin(theta_e - k 120 deg)`.
#[inline(always)]
fn back_emf(omega_e: f64, psi: f64, sin: f64, cos: f64) -> [f64; 3] {
    // sin(x - 120) = -sin/2 - cos sqrt3/2; sin(x + 120) = -sin/2 + cos sqrt3/2.
    let k = -omega_e * psi;
    [k * sin, k * (-0.5 * sin - 0.5 * SQRT3 * cos), k * (-0.5 * sin + 0.5 * SQRT3 * cos)]
}

/// Terminal voltage of the disconnected motor phase `x` ([`faults::PlantFaults::phase_open`]) given the terminal
/// voltages `u` of the other two and the back-EMFs `e`: the phase carries no current, so its terminal is its
/// back-EMF above the star point, and the star point is where the two connected phases, which carry equal and
/// opposite currents through equal inductances, put it: the mean of their `u - e`. Substituted into the dq model
/// (whose star point is the mean of the three terminals, the zero sequence dropping out) this gives `di_x/dt = 0`
/// exactly for `Ld = Lq` (the reference motor); with saliency the projection after each segment removes the rest.
#[inline(always)]
fn open_phase_terminal(u: [f64; 3], e: [f64; 3], x: usize) -> f64 {
    let (y, z) = ((x + 1) % 3, (x + 2) % 3);
    e[x] + 0.5 * ((u[y] - e[y]) + (u[z] - e[z]))
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

fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Per-segment mechanical mode, decided at the segment start (stiction needs the sign of the breakaway).
#[derive(Clone, Copy, Debug)]
enum SegMech {
    /// Angle and speed frozen (locked, or stuck by static friction).
    Frozen,
    /// Constant speed.
    Driven(f64),
    /// Free, with the friction sign for the segment (the sign of the speed at its start, or of the breakaway torque
    /// at rest).
    Free { zero_speed_friction_sign: f64 },
}

/// Constants of one period, copied out of the parameters so the integrator borrows nothing.
#[derive(Clone, Copy, Debug)]
struct Coeffs {
    p: f64,
    psi: f64,
    ld: f64,
    lq: f64,
    r: f64,
    r_switch: f64,
    v_diode: f64,
    j: f64,
    b_visc: f64,
    t_coulomb: f64,
    v_source: f64,
    r_source: f64,
    source_sinks: bool,
    c_bus: f64,
}

impl Coeffs {
    #[inline(always)]
    fn source_current(&self, v_bus: f64) -> f64 {
        let i = (self.v_source - v_bus) / self.r_source;
        if self.source_sinks {
            i
        } else {
            i.max(0.0)
        }
    }

    #[inline(always)]
    fn torque(&self, i_d: f64, i_q: f64) -> f64 {
        1.5 * self.p * (self.psi * i_q + (self.ld - self.lq) * i_d * i_q)
    }

    /// Mechanical derivatives (d omega, d theta).
    #[inline(always)]
    fn mech(&self, mode: SegMech, torque: f64, load: f64, omega: f64) -> (f64, f64) {
        match mode {
            SegMech::Frozen => (0.0, 0.0),
            SegMech::Driven(w) => (0.0, w),
            SegMech::Free { zero_speed_friction_sign } => {
                // One friction sign for the whole segment (the speed's at its start): re-evaluating it at the RK4
                // stages lets the stages straddling zero cancel, so a speed below `T_c h / J` would creep on
                // instead of stopping (0.14 rad/s with an engaged brake); a sign change is clamped afterwards.
                let s = zero_speed_friction_sign;
                ((torque - load - self.b_visc * omega - self.t_coulomb * s) / self.j, omega)
            }
        }
    }
}

/// The simulated plant: PMSM, mechanics, inverter, DC bus, thermal nodes and sensors. See the module docs.
pub struct Plant {
    params: PlantParams,
    rng: Rng,
    /// The motor temperature channel's noise: a stream of its own, so that adding the channel left every other
    /// channel's noise (and so every existing trace) bit-for-bit as it was for a seed.
    motor_sensor_rng: Rng,
    i_d: f64,
    i_q: f64,
    omega_m: f64,
    theta_m: f64,
    v_bus: f64,
    t_winding: f64,
    t_housing: f64,
    t_power_stage: f64,
    mechanics: Mechanics,
    load_torque_nm: f64,
    load_profile: Option<LoadProfile>,
    last_load_nm: f64,
    /// Reference level of each leg at the end of the last period (`None`: outputs were off).
    levels: [Option<bool>; 3],
    break_latched: bool,
    last_count: i64,
    /// What the encoder counter shows beyond the true count `last_count`: the spurious counts of noise bursts and
    /// the counts missed while the A/B lines were broken ([`faults::PlantFaults`]). Zero for a healthy encoder.
    encoder_error: i64,
    pending_index: Option<u16>,
    period: u64,
    at_sample: PlantState,
    averages: PeriodAverages,
    last_measurements: Measurements,
    /// Digital I/O state: forced inputs, output pins, holding brake ([`io`]).
    io: io::PlantIo,
    /// Injected failures ([`faults`]).
    faults: faults::PlantFaults,
}

impl core::fmt::Debug for Plant {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Plant")
            .field("period", &self.period)
            .field("state", &self.state())
            .field("mechanics", &self.mechanics)
            .field("has_load_profile", &self.load_profile.is_some())
            .finish_non_exhaustive()
    }
}

impl Plant {
    /// A plant at rest: zero currents, rotor at angle 0, bus charged to the source voltage, all temperatures at
    /// ambient, outputs off. `seed` determines all noise.
    pub fn new(params: PlantParams, seed: u64) -> Self {
        let mut plant = Self {
            rng: Rng::new(seed),
            motor_sensor_rng: Rng::new(seed ^ 0x6D6F_746F_725F_5445),
            i_d: 0.0,
            i_q: 0.0,
            omega_m: 0.0,
            theta_m: 0.0,
            v_bus: params.source_voltage_v,
            t_winding: params.ambient_c,
            t_housing: params.ambient_c,
            t_power_stage: params.ambient_c,
            mechanics: Mechanics::Free,
            load_torque_nm: 0.0,
            load_profile: None,
            last_load_nm: 0.0,
            levels: [None; 3],
            break_latched: false,
            last_count: 0,
            encoder_error: 0,
            pending_index: None,
            period: 0,
            at_sample: PlantState::default(),
            averages: PeriodAverages::default(),
            last_measurements: Measurements::default(),
            io: io::PlantIo::default(),
            faults: faults::PlantFaults::default(),
            params,
        };
        plant.last_count = plant.count_now();
        plant.at_sample = plant.state();
        plant
    }

    /// The parameters in use.
    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    /// Change any parameter (fault injection, parameter studies). Every parameter is read afresh at the start of
    /// each period, so a change takes effect with the next call of [`Plant::step`].
    pub fn params_mut(&mut self) -> &mut PlantParams {
        &mut self.params
    }

    /// Number of periods simulated so far (the index of the period the next call simulates).
    pub fn period_index(&self) -> u64 {
        self.period
    }

    /// Simulated time, in s.
    pub fn time_s(&self) -> f64 {
        self.period as f64 * PERIOD_S
    }

    /// Simulate one PWM period with `cmd` as the active compare values and output enable, and return the
    /// measurements sampled at its centre. See the module docs for the timeline.
    ///
    /// Measurements:
    /// * `adc.phase_currents[x]`: `round(2048 + offset[x] + gain[x] * i_shunt[x] + noise)` clamped to 0..=4095,
    ///   where `i_shunt` is the phase current if the low switch (or the low diode, for a positive current) conducts
    ///   at the centre, else 0 (at compare values above about 97.5 % of ARR the low switch is not on at the centre
    ///   and that shunt reads zero current, as on the hardware).
    /// * `adc.bus_voltage`: `round(gain * V_bus + noise)`; `adc.temperature`: the power-stage temperature through
    ///   a linear sensor, `round((V_0 + k T) / V_ref * 4095 + noise)`; `adc.motor_temperature`: the winding
    ///   temperature through the same sensor model (its own noise), or the code a broken sensor reads
    ///   ([`faults::PlantFaults::motor_temperature_code_stuck`]).
    /// * `feedback.encoder_count`: the 16-bit counter at the sample instant; `index_latch`: the counter value at
    ///   the last entry into the index state since the previous sample; `hall`: the Hall state at the sample. The
    ///   injected sensor faults ([`faults::PlantFaults`]: wire break, noise burst, lost index, stuck Halls) act on
    ///   these three only.
    /// * `break_input`: the over-current comparator (any leg current, the phase current plus the share of an
    ///   injected output short, beyond `break_current_a`, checked every sub-step while the outputs are enabled)
    ///   has tripped. The trip latches and forces the outputs off until a command
    ///   with `enabled == false` acknowledges it.
    pub fn step(&mut self, cmd: &PwmCommand) -> Measurements {
        let p = &self.params;
        let k = self.coeffs();
        let period_s = PERIOD_S;
        let dead_time_s = p.dead_time_s;
        let h_max = period_s / f64::from(p.substeps_per_period.max(1));
        let sample_t = 0.5 * period_s;

        if !cmd.enabled {
            self.break_latched = false;
        }
        let enabled = cmd.enabled && !self.break_latched;
        let mut patterns = [LegPattern::off(period_s); 3];
        let mut end_levels = [None; 3];
        if enabled {
            for x in 0..3 {
                let (pattern, level) = LegPattern::new(cmd.duty[x], self.levels[x], period_s, dead_time_s);
                patterns[x] = pattern;
                end_levels[x] = Some(level);
            }
        }

        // Breakpoints: every switching instant of the three legs, the sample instant and the period end, sorted.
        let mut breaks = [0.0f64; 3 * LegPattern::MAX_PIECES + 2];
        let mut n_breaks = 0;
        for b in [sample_t, period_s] {
            breaks[n_breaks] = b;
            n_breaks += 1;
        }
        if enabled {
            for pattern in &patterns {
                for &b in pattern.boundaries() {
                    breaks[n_breaks] = b;
                    n_breaks += 1;
                }
            }
        }
        let breaks = &mut breaks[..n_breaks];
        breaks.sort_unstable_by(f64::total_cmp);

        let mut acc = PeriodAverages::default();
        let mut sampled = false;
        let mut measurements = self.last_measurements;
        let mut t = 0.0;
        for &b in breaks.iter() {
            let span = b - t;
            if span > 1e-13 {
                // Split the interval into equal segments no longer than the maximum step.
                let n = (span / h_max - 1e-9).ceil().max(1.0);
                let h = span / n;
                let mut j = 0.0;
                while j < n {
                    let t0 = t + j * h;
                    let t1 = if j + 1.0 >= n { b } else { t0 + h };
                    self.update_load(t0);
                    if enabled && !self.break_latched {
                        let i = self.segment_switching(&k, &patterns, t0, t1, &mut acc);
                        if i.iter().any(|x| x.abs() > self.params.break_current_a) {
                            self.break_latched = true;
                        }
                    } else {
                        self.segment_freewheel(&k, t1 - t0, &mut acc);
                    }
                    self.update_encoder();
                    j += 1.0;
                }
                t = b;
            }
            if !sampled && t >= sample_t - 1e-15 {
                sampled = true;
                let switching_now = enabled && !self.break_latched;
                measurements = self.sample(&patterns, switching_now, sample_t, t);
            }
        }

        // Period bookkeeping: averages, thermal nodes, leg levels.
        for v in acc.pole_voltage_v.iter_mut() {
            *v /= period_s;
        }
        let mean = (acc.pole_voltage_v[0] + acc.pole_voltage_v[1] + acc.pole_voltage_v[2]) / 3.0;
        acc.phase_voltage_v = acc.pole_voltage_v.map(|v| v - mean);
        acc.dq_voltage_v = acc.dq_voltage_v.map(|v| v / period_s);
        acc.bus_voltage_v /= period_s;
        acc.bus_current_a /= period_s;
        acc.copper_loss_w /= period_s;
        // Conduction loss of the switches: every phase current flows through one switch (or diode) at a time.
        let switch_loss_w = acc.copper_loss_w * k.r_switch / (k.r - k.r_switch).max(1e-12);
        self.update_thermal(acc.copper_loss_w, switch_loss_w, period_s);
        self.averages = acc;
        self.levels = if self.break_latched { [None; 3] } else { end_levels };
        self.io.advance(&self.params.io, period_s);
        self.period += 1;
        self.last_measurements = measurements;
        measurements
    }

    fn coeffs(&self) -> Coeffs {
        let p = &self.params;
        Coeffs {
            p: f64::from(p.pole_pairs),
            psi: p.flux_linkage_wb,
            ld: p.ld_h,
            lq: p.lq_h,
            r: self.phase_resistance() + p.switch_resistance_ohm,
            r_switch: p.switch_resistance_ohm,
            v_diode: p.diode_drop_v,
            j: p.total_inertia_kg_m2(),
            b_visc: p.viscous_friction_nm_s_rad,
            t_coulomb: p.coulomb_friction_nm + self.io.brake_friction_nm(&p.io),
            v_source: p.source_voltage_v,
            r_source: p.source_resistance_ohm,
            source_sinks: p.source_sinks_current,
            c_bus: p.bus_capacitance_f,
        }
    }

    fn phase_resistance(&self) -> f64 {
        let p = &self.params;
        p.phase_resistance_ohm * (1.0 + p.copper_temp_coeff_per_k * (self.t_winding - p.resistance_reference_temp_c))
    }

    fn update_load(&mut self, t_in_period: f64) {
        let time = self.time_s() + t_in_period;
        let extra = match self.load_profile.as_mut() {
            Some(f) => f(time, self.theta_m, self.omega_m),
            None => 0.0,
        };
        self.last_load_nm = self.load_torque_nm + extra;
    }

    /// Mechanical mode of the next segment (stiction decided from the torques at its start).
    fn seg_mech(&self, k: &Coeffs) -> SegMech {
        match self.mechanics {
            Mechanics::Locked => SegMech::Frozen,
            Mechanics::Driven { speed_rad_s } => SegMech::Driven(speed_rad_s),
            Mechanics::Free => {
                if self.omega_m != 0.0 {
                    SegMech::Free { zero_speed_friction_sign: sign(self.omega_m) }
                } else {
                    let drive = k.torque(self.i_d, self.i_q) - self.last_load_nm;
                    if drive.abs() <= k.t_coulomb {
                        SegMech::Frozen
                    } else {
                        SegMech::Free { zero_speed_friction_sign: sign(drive) }
                    }
                }
            }
        }
    }

    /// After a free segment: a speed that changed sign stops at zero (friction cannot reverse the motion).
    fn clamp_speed(&mut self, mode: SegMech, omega_before: f64) {
        if let SegMech::Free { zero_speed_friction_sign } = mode {
            let reference = if omega_before != 0.0 { sign(omega_before) } else { zero_speed_friction_sign };
            if self.omega_m * reference < 0.0 {
                self.omega_m = 0.0;
            }
        }
    }

    fn i_abc(&self) -> [f64; 3] {
        let (s, c) = (f64::from(self.params.pole_pairs) * self.theta_m).sin_cos();
        dq_to_abc(self.i_d, self.i_q, s, c)
    }

    /// One RK4 segment `[t0, t1)` with the outputs switching; returns the currents out of the three legs at its end
    /// (the phase currents, plus a short's share, [`inverter::OutputShort`]): what the over-current comparator sees.
    ///
    /// A disconnected phase ([`faults::PlantFaults::phase_open`]) is a leg whose motor terminal floats at
    /// [`open_phase_terminal`], recomputed at every RK4 stage, draws nothing from the bus, and ends every segment at
    /// exactly zero current (the projection below, as for a diode that stopped conducting). The current a phase
    /// carried when it was opened is cut at once (the arc of a real break lasts microseconds; its energy is dropped).
    fn segment_switching(
        &mut self,
        k: &Coeffs,
        patterns: &[LegPattern; 3],
        t0: f64,
        t1: f64,
        acc: &mut PeriodAverages,
    ) -> [f64; 3] {
        let h = t1 - t0;
        let mid = 0.5 * (t0 + t1);
        let th0 = k.p * self.theta_m;
        let (sn0, cs0) = th0.sin_cos();
        let i0 = dq_to_abc(self.i_d, self.i_q, sn0, cs0);
        let upper_diode = LegDrive { a: 1.0, b: k.v_diode, c: 1.0 };
        let lower_diode = LegDrive { a: 0.0, b: -k.v_diode, c: 0.0 };
        let mut legs = [LegDrive::default(); 3];
        let mut off = [false; 3];
        let mut floating = [false; 3];
        for x in 0..3 {
            let state = patterns[x].state_at(mid);
            off[x] = state == LegState::Off;
            legs[x] = match state {
                LegState::High => LegDrive { a: 1.0, b: 0.0, c: 1.0 },
                LegState::Low => LegDrive { a: 0.0, b: 0.0, c: 0.0 },
                LegState::Off if i0[x] < -ZERO_CURRENT_A => upper_diode,
                LegState::Off if i0[x] > ZERO_CURRENT_A => lower_diode,
                LegState::Off => {
                    floating[x] = true;
                    LegDrive::default()
                }
            };
        }
        // Injected faults: a disconnected phase is taken out of the neutral of the floating legs below.
        let open = self.faults.phase_open.filter(|&x| x < 3);
        if let Some(x) = open {
            floating[x] = true;
        }
        let short = inverter::OutputShort::new(self.faults.phase_short, k.r_switch);
        if floating.iter().any(|f| *f) {
            // A leg in dead time with no current floats: its terminal follows the motor (back-EMF plus the neutral
            // set by the driven legs) so that its current stays zero, unless that would pass a rail, where its
            // diode starts to conduct. Back-EMF frozen over the segment (at most the 0.5 us dead time).
            let e0 = back_emf(k.p * self.omega_m, k.psi, sn0, cs0);
            let n_fixed = floating.iter().filter(|f| !**f).count();
            let (mut a_n, mut b_n) = (0.5, 0.0);
            if n_fixed > 0 {
                (a_n, b_n) = (0.0, 0.0);
                for x in (0..3).filter(|&x| !floating[x]) {
                    a_n += legs[x].a / n_fixed as f64;
                    b_n += (legs[x].b - e0[x]) / n_fixed as f64;
                }
            }
            for x in 0..3 {
                if !floating[x] {
                    continue;
                }
                let leg = LegDrive { a: a_n, b: e0[x] + b_n, c: 0.0 };
                let u = leg.a * self.v_bus + leg.b;
                if u > self.v_bus + k.v_diode {
                    legs[x] = upper_diode;
                    floating[x] = false;
                } else if u < -k.v_diode {
                    legs[x] = lower_diode;
                    floating[x] = false;
                } else {
                    legs[x] = leg;
                }
            }
        }
        // The inverter's poles (what the averages and a short see); the motor terminal of an open phase is
        // computed in the stages.
        let inverter_legs = legs;
        if let Some(x) = open {
            legs[x] = LegDrive::default();
        }
        let mode = self.seg_mech(k);
        let load = self.last_load_nm;
        let omega_before = self.omega_m;
        let s0 = [self.i_d, self.i_q, self.omega_m, self.theta_m, self.v_bus];
        let s1 = rk4(&s0, h, |s: &[f64; 5]| {
            let [i_d, i_q, omega, theta, v] = *s;
            let (sn, cs) = sin_cos_after(sn0, cs0, th0, k.p * theta - th0);
            let mut u = [legs[0].a * v + legs[0].b, legs[1].a * v + legs[1].b, legs[2].a * v + legs[2].b];
            if let Some(x) = open {
                u[x] = open_phase_terminal(u, back_emf(k.p * omega, k.psi, sn, cs), x);
            }
            let [v_d, v_q] = abc_to_dq(u, sn, cs);
            let omega_e = k.p * omega;
            let di_d = (v_d - k.r * i_d + omega_e * k.lq * i_q) / k.ld;
            let di_q = (v_q - k.r * i_q - omega_e * (k.ld * i_d + k.psi)) / k.lq;
            let i = dq_to_abc(i_d, i_q, sn, cs);
            let mut i_dc = legs[0].c * i[0] + legs[1].c * i[1] + legs[2].c * i[2];
            if let Some(short) = short {
                // The short's current leaves through the high switch of the leg at the higher pole.
                let poles = inverter_legs.map(|l| l.a * v + l.b);
                let s = short.leg_currents(poles);
                i_dc += inverter_legs[0].c * s[0] + inverter_legs[1].c * s[1] + inverter_legs[2].c * s[2];
            }
            let dv = (k.source_current(v) - i_dc) / k.c_bus;
            let (dw, dth) = k.mech(mode, k.torque(i_d, i_q), load, omega);
            [di_d, di_q, dw, dth, dv]
        });
        [self.i_d, self.i_q, self.omega_m, self.theta_m, self.v_bus] = s1;
        self.clamp_speed(mode, omega_before);
        let (sn1, cs1) = sin_cos_after(sn0, cs0, th0, k.p * s1[3] - th0);
        let mut i1 = dq_to_abc(self.i_d, self.i_q, sn1, cs1);

        // Diodes block reverse current: a leg in dead time whose current reached zero (or that floated) ends the
        // segment at exactly zero current; the current vector is projected onto the plane i_x = 0 (two such
        // phases leave no current at all).
        let mut stopped = [false; 3];
        for x in 0..3 {
            // The diode conducting in dead time carries a negative current (upper) or a positive one (lower).
            let diode_sign = if legs[x].c != 0.0 { -1.0 } else { 1.0 };
            stopped[x] = off[x] && (floating[x] || i1[x] * diode_sign <= 0.0);
        }
        if let Some(x) = open {
            stopped[x] = true;
        }
        match stopped.iter().filter(|s| **s).count() {
            0 => {}
            1 => {
                let x = stopped.iter().position(|s| *s).unwrap_or(0);
                let ix = i1[x];
                for (y, iy) in i1.iter_mut().enumerate() {
                    *iy += if y == x { -ix } else { 0.5 * ix };
                }
                [self.i_d, self.i_q] = abc_to_dq(i1, sn1, cs1);
            }
            _ => {
                i1 = [0.0; 3];
                self.i_d = 0.0;
                self.i_q = 0.0;
            }
        }

        // Averages (trapezoidal in the bus voltage and currents).
        let v_mid = 0.5 * (s0[4] + s1[4]);
        let mut poles = [0.0; 3];
        for x in 0..3 {
            let i_mid = 0.5 * (i0[x] + i1[x]);
            poles[x] = inverter_legs[x].a * v_mid + inverter_legs[x].b - k.r_switch * i_mid;
            acc.pole_voltage_v[x] += poles[x] * h;
            acc.bus_current_a += legs[x].c * i_mid * h;
        }
        let mut legs_i = i1;
        if let Some(short) = short {
            let s_mid = short.leg_currents(inverter_legs.map(|l| l.a * v_mid + l.b));
            let s_end = short.leg_currents(inverter_legs.map(|l| l.a * self.v_bus + l.b));
            for x in 0..3 {
                acc.bus_current_a += inverter_legs[x].c * s_mid[x] * h;
                legs_i[x] += s_end[x];
            }
        }
        let (sn, cs) = sin_cos_after(sn0, cs0, th0, k.p * 0.5 * (s0[3] + s1[3]) - th0);
        let vdq = abc_to_dq(poles, sn, cs);
        acc.dq_voltage_v[0] += vdq[0] * h;
        acc.dq_voltage_v[1] += vdq[1] * h;
        acc.bus_voltage_v += v_mid * h;
        let i_sq = 0.5 * (s0[0] * s0[0] + s0[1] * s0[1] + s1[0] * s1[0] + s1[1] * s1[1]);
        acc.copper_loss_w += 1.5 * (k.r - k.r_switch) * i_sq * h;
        legs_i
    }

    /// One RK4 segment of length `h` with all switches off: the diode-bridge model (see the module docs).
    fn segment_freewheel(&mut self, k: &Coeffs, h: f64, acc: &mut PeriodAverages) {
        let l = 0.5 * (k.ld + k.lq);
        let th0 = k.p * self.theta_m;
        let (sn, cs) = th0.sin_cos();
        let mut i = dq_to_abc(self.i_d, self.i_q, sn, cs);
        for x in i.iter_mut() {
            if x.abs() < ZERO_CURRENT_A {
                *x = 0.0;
            }
        }
        // A disconnected phase ([`faults::PlantFaults::phase_open`]) never conducts; a current it still carried when
        // it was opened is cut at once (as in `segment_switching`).
        let disconnected = self.faults.phase_open.filter(|&x| x < 3);
        if let Some(x) = disconnected {
            let ix = i[x];
            if ix != 0.0 {
                for (y, iy) in i.iter_mut().enumerate() {
                    *iy += if y == x { -ix } else { 0.5 * ix };
                }
            }
        }
        let e = back_emf(k.p * self.omega_m, k.psi, sn, cs);
        let v = self.v_bus;
        // Conduction: per phase, None (open) or Some(upper?) for the diode carrying its current.
        let mut conducting: [Option<bool>; 3] = i.map(|x| if x != 0.0 { Some(x < 0.0) } else { None });
        let rail = |upper: bool| if upper { v + k.v_diode } else { -k.v_diode };
        let count = |c: &[Option<bool>; 3]| c.iter().filter(|x| x.is_some()).count();
        if count(&conducting) < 2 {
            conducting = [None; 3];
            i = [0.0; 3];
            let first = usize::from(disconnected == Some(0));
            let (mut hi, mut lo) = (first, first);
            for x in (first + 1..3).filter(|&x| Some(x) != disconnected) {
                if e[x] > e[hi] {
                    hi = x;
                }
                if e[x] < e[lo] {
                    lo = x;
                }
            }
            if e[hi] - e[lo] > v + 2.0 * k.v_diode {
                conducting[hi] = Some(true);
                conducting[lo] = Some(false);
            }
        }
        if count(&conducting) == 2 {
            let mut v_n = 0.0;
            let mut open = 0;
            for x in 0..3 {
                match conducting[x] {
                    Some(up) => v_n += 0.5 * (rail(up) - e[x]),
                    None => open = x,
                }
            }
            let v_open = e[open] + v_n;
            if Some(open) != disconnected {
                if v_open > v + k.v_diode {
                    conducting[open] = Some(true);
                } else if v_open < -k.v_diode {
                    conducting[open] = Some(false);
                }
            }
        }
        let n_on = count(&conducting);
        let mask = conducting.map(|c| if c.is_some() { 1.0 } else { 0.0 });
        let drive = conducting.map(|c| match c {
            Some(true) => LegDrive { a: 1.0, b: k.v_diode, c: 1.0 },
            Some(false) => LegDrive { a: 0.0, b: -k.v_diode, c: 0.0 },
            None => LegDrive::default(),
        });
        let inv_n = if n_on > 0 { 1.0 / n_on as f64 } else { 0.0 };
        let mode = self.seg_mech(k);
        let load = self.last_load_nm;
        let omega_before = self.omega_m;
        // Neutral voltage of a state: mean over the conducting phases of (pole - R i - e).
        let neutral = |s: &[f64; 6], e: &[f64; 3]| -> f64 {
            let mut sum = 0.0;
            for x in 0..3 {
                sum += mask[x] * (drive[x].a * s[5] + drive[x].b - k.r * s[x] - e[x]);
            }
            sum * inv_n
        };
        let s0 = [i[0], i[1], i[2], self.omega_m, self.theta_m, v];
        let s1 = rk4(&s0, h, |s: &[f64; 6]| {
            let (sn, cs) = sin_cos_after(sn, cs, th0, k.p * s[4] - th0);
            let e = back_emf(k.p * s[3], k.psi, sn, cs);
            let v_n = neutral(s, &e);
            let mut d = [0.0; 6];
            let mut i_dc = 0.0;
            for x in 0..3 {
                d[x] = mask[x] * (drive[x].a * s[5] + drive[x].b - k.r * s[x] - e[x] - v_n) / l;
                i_dc += mask[x] * drive[x].c * s[x];
            }
            let [i_d, i_q] = abc_to_dq([s[0], s[1], s[2]], sn, cs);
            let (dw, dth) = k.mech(mode, k.torque(i_d, i_q), load, s[3]);
            d[3] = dw;
            d[4] = dth;
            d[5] = (k.source_current(s[5]) - i_dc) / k.c_bus;
            d
        });
        // Diodes block reverse current: a conducting phase whose current reached or crossed zero stops.
        let mut i1 = [s1[0], s1[1], s1[2]];
        for x in 0..3 {
            if let Some(up) = conducting[x] {
                let expected = if up { -1.0 } else { 1.0 };
                if i1[x] * expected <= ZERO_CURRENT_A {
                    i1[x] = 0.0;
                }
            } else {
                i1[x] = 0.0;
            }
        }
        let nonzero = i1.iter().filter(|x| **x != 0.0).count();
        if nonzero < 2 {
            i1 = [0.0; 3];
        } else {
            let mean = (i1[0] + i1[1] + i1[2]) / nonzero as f64;
            for x in i1.iter_mut() {
                if *x != 0.0 {
                    *x -= mean;
                }
            }
        }
        self.omega_m = s1[3];
        self.theta_m = s1[4];
        self.v_bus = s1[5];
        self.clamp_speed(mode, omega_before);
        let (sn1, cs1) = sin_cos_after(sn, cs, th0, k.p * self.theta_m - th0);
        [self.i_d, self.i_q] = abc_to_dq(i1, sn1, cs1);

        // Averages at the segment midpoint (open phases float at e + v_n; all open: neutral at mid-bus).
        let (sn_mid, cs_mid) = sin_cos_after(sn, cs, th0, k.p * 0.5 * (s0[4] + s1[4]) - th0);
        let e_mid = back_emf(k.p * 0.5 * (s0[3] + s1[3]), k.psi, sn_mid, cs_mid);
        let v_mid = 0.5 * (v + self.v_bus);
        let mut s_mid = [0.0; 6];
        for x in 0..6 {
            s_mid[x] = 0.5 * (s0[x] + if x < 3 { i1[x] } else { s1[x] });
        }
        let v_n = if n_on >= 2 { neutral(&s_mid, &e_mid) } else { 0.5 * v_mid };
        let mut poles = [0.0; 3];
        for x in 0..3 {
            poles[x] = if conducting[x].is_some() {
                drive[x].a * v_mid + drive[x].b - k.r_switch * s_mid[x]
            } else {
                e_mid[x] + v_n
            };
            acc.pole_voltage_v[x] += poles[x] * h;
            acc.bus_current_a += drive[x].c * mask[x] * s_mid[x] * h;
        }
        let vdq = abc_to_dq(poles, sn_mid, cs_mid);
        acc.dq_voltage_v[0] += vdq[0] * h;
        acc.dq_voltage_v[1] += vdq[1] * h;
        acc.bus_voltage_v += v_mid * h;
        let i_sq = (s_mid[0] * s_mid[0] + s_mid[1] * s_mid[1] + s_mid[2] * s_mid[2]) * (2.0 / 3.0);
        acc.copper_loss_w += 1.5 * (k.r - k.r_switch) * i_sq * h;
    }

    fn update_thermal(&mut self, copper_loss_w: f64, switch_loss_w: f64, dt: f64) {
        let p = &self.params;
        let r_wh = p.winding_to_housing_k_per_w;
        let r_ha = p.housing_to_ambient_k_per_w;
        let c_w = p.winding_time_constant_s / r_wh;
        let c_h = p.housing_time_constant_s / r_ha;
        let flow_wh = (self.t_winding - self.t_housing) / r_wh;
        let flow_ha = (self.t_housing - p.ambient_c) / r_ha;
        self.t_winding += dt * (copper_loss_w - flow_wh) / c_w;
        self.t_housing += dt * (flow_wh - flow_ha) / c_h;
        let r_ps = p.power_stage_to_ambient_k_per_w;
        let c_ps = p.power_stage_time_constant_s / r_ps;
        self.t_power_stage += dt * (switch_loss_w - (self.t_power_stage - p.ambient_c) / r_ps) / c_ps;
    }

    /// Follow the encoder after a segment: latch the counter if the index state was entered.
    ///
    /// Injected sensor faults change only what the counter shows, never the shaft: with the A/B lines broken the
    /// counter holds its value while the shaft turns (the motion goes into `encoder_error`) and the index, which
    /// needs the A/B state, is not latched either; with the index line broken no pulse reaches the latch. The
    /// latched value is the counter's at the index, spurious counts included.
    fn update_encoder(&mut self) {
        let count = self.count_now();
        if self.faults.encoder_wire_break {
            self.encoder_error -= count - self.last_count;
        } else if let Some(n) =
            sensors::index_entry(self.last_count, count, self.params.encoder_counts_per_rev, self.params.index_count)
        {
            if !self.faults.index_lost {
                self.pending_index = Some(sensors::counter_register(n + self.encoder_error));
            }
        }
        self.last_count = count;
    }

    /// A noise burst ([`faults::EncoderNoise`]) adds its spurious counts once per period, at the sample, until it
    /// has lasted its periods.
    fn apply_encoder_noise(&mut self) {
        if let Some(noise) = self.faults.encoder_noise.as_mut() {
            if noise.periods_left > 0 {
                self.encoder_error += i64::from(noise.counts_per_period);
                noise.periods_left -= 1;
            }
            if noise.periods_left == 0 {
                self.faults.encoder_noise = None;
            }
        }
    }

    /// The encoder count the rotor's true angle gives now, in the plant's coordinates (where the limit and home
    /// switches are placed), without the injected sensor faults.
    pub fn true_encoder_count(&self) -> i64 {
        self.count_now()
    }

    fn count_now(&self) -> i64 {
        sensors::encoder_count(self.theta_m, self.params.encoder_counts_per_rev, self.params.encoder_offset_counts)
    }

    fn shunt_currents(&self, patterns: &[LegPattern; 3], switching: bool, t: f64) -> [f64; 3] {
        let mut i = self.i_abc();
        // A short between two outputs ([`inverter::OutputShort`]) adds its current to what the two legs carry
        // (zero at the centre while both low switches are on).
        let short = inverter::OutputShort::new(self.faults.phase_short, self.params.switch_resistance_ohm);
        if let Some(short) = short.filter(|_| switching) {
            let p = &self.params;
            let poles =
                core::array::from_fn(|x| patterns[x].state_at(t).pole_voltage(i[x], self.v_bus, p.diode_drop_v));
            let s = short.leg_currents(poles);
            for x in 0..3 {
                i[x] += s[x];
            }
        }
        core::array::from_fn(|x| {
            let low_conducts = if switching {
                match patterns[x].state_at(t) {
                    LegState::Low => true,
                    LegState::Off => i[x] > 0.0,
                    LegState::High => false,
                }
            } else {
                i[x] > 0.0
            };
            if low_conducts {
                i[x]
            } else {
                0.0
            }
        })
    }

    fn sample(&mut self, patterns: &[LegPattern; 3], switching: bool, sample_t: f64, t: f64) -> Measurements {
        self.apply_encoder_noise();
        let shunt = self.shunt_currents(patterns, switching, sample_t);
        let p = &self.params;
        let mut phase_currents = [0u16; 3];
        for x in 0..3 {
            let noise = self.rng.gaussian() * p.shunt_noise_lsb_rms;
            let lsb = sensors::ADC_MID_SCALE + p.shunt_offset_lsb[x] + p.shunt_gain_lsb_per_a[x] * shunt[x] + noise;
            phase_currents[x] = sensors::adc_code(lsb);
        }
        let bus_noise = self.rng.gaussian() * p.bus_noise_lsb_rms;
        let bus_voltage = sensors::adc_code(p.bus_gain_lsb_per_v * self.v_bus + bus_noise);
        let temp_noise = self.rng.gaussian() * p.temp_noise_lsb_rms;
        let full_scale = f64::from(firmware::hal::power::ADC_FULL_SCALE);
        let sensor_v = p.temp_sensor_v_at_0c + p.temp_sensor_v_per_k * self.t_power_stage;
        let temperature = sensors::adc_code(sensor_v / p.adc_reference_v * full_scale + temp_noise);
        let motor_noise = self.motor_sensor_rng.gaussian() * p.temp_noise_lsb_rms;
        let motor_v = p.temp_sensor_v_at_0c + p.temp_sensor_v_per_k * self.t_winding;
        let motor_temperature = match self.faults.motor_temperature_code_stuck {
            Some(code) => code,
            None => sensors::adc_code(motor_v / p.adc_reference_v * full_scale + motor_noise),
        };
        // A stuck Hall sensor or a broken Hall cable reads its fixed state whatever the rotor does.
        let hall = match self.faults.hall_stuck {
            Some(stuck) => stuck,
            None => sensors::hall_state(f64::from(p.pole_pairs) * self.theta_m, p.hall_offset_rad),
        };
        let feedback = FeedbackSample {
            encoder_count: sensors::counter_register(self.last_count + self.encoder_error),
            index_latch: self.pending_index.take(),
            hall,
            digital_inputs: self.io.input_levels(&p.io, self.last_count),
        };
        let mut state = self.state_at(t);
        state.shunt_currents_a = shunt;
        self.at_sample = state;
        Measurements {
            adc: AdcSamples { phase_currents, bus_voltage, temperature, motor_temperature },
            feedback,
            break_input: self.break_latched,
        }
    }

    fn state_at(&self, t_in_period: f64) -> PlantState {
        let p = &self.params;
        let pp = f64::from(p.pole_pairs);
        let i_abc = self.i_abc();
        let r = self.phase_resistance();
        let k = self.coeffs();
        PlantState {
            time_s: self.time_s() + t_in_period,
            i_abc_a: i_abc,
            i_dq_a: [self.i_d, self.i_q],
            shunt_currents_a: [0.0; 3],
            theta_m_rad: self.theta_m,
            theta_e_rad: (pp * self.theta_m).rem_euclid(2.0 * PI),
            omega_m_rad_s: self.omega_m,
            speed_rpm: self.omega_m * 60.0 / (2.0 * PI),
            omega_e_rad_s: pp * self.omega_m,
            torque_nm: k.torque(self.i_d, self.i_q),
            load_torque_nm: self.last_load_nm,
            bus_voltage_v: self.v_bus,
            source_current_a: k.source_current(self.v_bus),
            winding_temp_c: self.t_winding,
            housing_temp_c: self.t_housing,
            power_stage_temp_c: self.t_power_stage,
            phase_resistance_ohm: r,
            break_latched: self.break_latched,
        }
    }

    /// The true state now, at the end of the last simulated period (without shunt currents; see
    /// [`Plant::state_at_sample`] for what the shunts carried).
    pub fn state(&self) -> PlantState {
        self.state_at(0.0)
    }

    /// The true state at the last sample instant (the centre of the last simulated period), including the
    /// currents the shunts carried when the ADC sampled them.
    pub fn state_at_sample(&self) -> PlantState {
        self.at_sample
    }

    /// Averages over the last simulated period.
    pub fn period_averages(&self) -> PeriodAverages {
        self.averages
    }

    /// The measurements returned by the last call of [`Plant::step`].
    pub fn last_measurements(&self) -> Measurements {
        self.last_measurements
    }

    // ---- Hooks: mechanics and load ----

    /// Choose how the shaft moves (free, locked, driven at a speed).
    pub fn set_mechanics(&mut self, mechanics: Mechanics) {
        self.mechanics = mechanics;
        match mechanics {
            Mechanics::Free => {}
            Mechanics::Locked => self.omega_m = 0.0,
            Mechanics::Driven { speed_rad_s } => self.omega_m = speed_rad_s,
        }
    }

    /// The current mechanical mode.
    pub fn mechanics(&self) -> Mechanics {
        self.mechanics
    }

    /// Lock the rotor where it is (`true`) or free it (`false`).
    pub fn lock_rotor(&mut self, locked: bool) {
        self.set_mechanics(if locked { Mechanics::Locked } else { Mechanics::Free });
    }

    /// Set the rotor's mechanical angle (rad, unwrapped) and speed (rad/s) at once, e.g. as an initial condition.
    /// The encoder follows without producing index latches for the jump.
    pub fn set_rotor_state(&mut self, theta_m_rad: f64, omega_m_rad_s: f64) {
        self.theta_m = theta_m_rad;
        self.omega_m = omega_m_rad_s;
        self.last_count = self.count_now();
        self.pending_index = None;
    }

    /// Set a constant external load torque, in N m (positive opposes positive rotation). A load profile, if set,
    /// adds to it.
    pub fn set_load_torque(&mut self, torque_nm: f64) {
        self.load_torque_nm = torque_nm;
    }

    /// Set a load-torque profile `f(time_s, theta_m_rad, omega_m_rad_s) -> N m`, added to the constant load torque
    /// and evaluated at the start of every integration segment; `None` removes it.
    pub fn set_load_profile(&mut self, profile: Option<LoadProfile>) {
        self.load_profile = profile;
    }

    // ---- Hooks: electrical and sensors ----

    /// Set the offset of shunt channel `channel` (0..=2 for A, B, C), in LSB. Other channels are ignored.
    pub fn set_adc_offset(&mut self, channel: usize, offset_lsb: f64) {
        if let Some(o) = self.params.shunt_offset_lsb.get_mut(channel) {
            *o = offset_lsb;
        }
    }

    /// Set the open-circuit voltage of the DC source, in V.
    pub fn set_source_voltage(&mut self, volts: f64) {
        self.params.source_voltage_v = volts;
    }

    /// Force the bus-capacitor voltage, in V.
    pub fn set_bus_voltage(&mut self, volts: f64) {
        self.v_bus = volts;
    }

    /// Force the winding temperature (the housing keeps its own), in degC.
    pub fn set_winding_temperature(&mut self, celsius: f64) {
        self.t_winding = celsius;
    }

    /// Force the power-stage temperature (what the temperature channel measures), in degC.
    pub fn set_power_stage_temperature(&mut self, celsius: f64) {
        self.t_power_stage = celsius;
    }

    /// Trip the break input as the over-current comparator would: outputs off until acknowledged with a command
    /// whose `enabled` is false.
    pub fn force_break(&mut self) {
        self.break_latched = true;
    }

    /// The injected failures ([`faults::PlantFaults`]); a change takes effect with the next period.
    pub fn faults_mut(&mut self) -> &mut faults::PlantFaults {
        &mut self.faults
    }

    /// The injected failures.
    pub fn faults(&self) -> &faults::PlantFaults {
        &self.faults
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

/// The injected encoder and Hall faults ([`faults::PlantFaults`]) change what the sensors report, exactly, and
/// nothing else: the shaft is driven at a fixed speed by the dynamometer with the outputs off, so the true count
/// is known at every period.
#[cfg(test)]
mod sensor_fault_tests {
    use super::*;

    /// Radians per encoder count of the reference encoder.
    const RAD_PER_COUNT: f64 = 2.0 * PI / 4096.0;

    /// The reference plant, shaft at `start_counts + 0.5` counts, driven at `counts_per_period` counts per period.
    fn driven(start_counts: f64, counts_per_period: f64) -> Plant {
        let mut p = Plant::new(PlantParams::reference(), 1);
        let speed = counts_per_period * RAD_PER_COUNT / PERIOD_S;
        p.set_rotor_state((start_counts + 0.5) * RAD_PER_COUNT, speed);
        p.set_mechanics(Mechanics::Driven { speed_rad_s: speed });
        p
    }

    /// Runs `n` periods with the outputs off; the measurements of each.
    fn run(p: &mut Plant, n: usize) -> Vec<Measurements> {
        (0..n).map(|_| p.step(&PwmCommand::OFF)).collect()
    }

    /// The true count at the last sample.
    fn true_count(p: &Plant) -> i64 {
        sensors::encoder_count(p.state_at_sample().theta_m_rad, 4096, 0)
    }

    #[test]
    fn wire_break_freezes_the_counter_and_the_index() {
        let mut p = driven(-100.0, 2.0);
        let before = run(&mut p, 10);
        assert_eq!(before[9].feedback.encoder_count.wrapping_sub(before[0].feedback.encoder_count), 18);
        p.faults_mut().encoder_wire_break = true;
        // 100 periods = 200 counts: the shaft passes the index at count 0 on the way. The counter stops where the
        // break found it, at the end of the last healthy period: one count (half a period) after its last sample.
        let broken = run(&mut p, 100);
        let frozen = broken[0].feedback.encoder_count;
        assert_eq!(frozen.wrapping_sub(before[9].feedback.encoder_count), 1);
        assert!(true_count(&p) > 50, "the shaft has passed the index: {}", true_count(&p));
        assert!(broken.iter().all(|m| m.feedback.encoder_count == frozen), "the counter holds its value");
        assert!(broken.iter().all(|m| m.feedback.index_latch.is_none()), "no index without the A/B lines");
        // Repaired: the counter moves on from where it stopped, by the shaft's motion from then on.
        p.faults_mut().encoder_wire_break = false;
        let t0 = sensors::encoder_count(p.state().theta_m_rad, 4096, 0); // at the end of the last broken period
        let after = run(&mut p, 10);
        let moved = after[9].feedback.encoder_count.wrapping_sub(frozen);
        assert_eq!(i64::from(moved), true_count(&p) - t0);
    }

    #[test]
    fn noise_burst_adds_its_counts_and_displaces_the_index() {
        let mut p = driven(-300.0, 0.0);
        let c0 = run(&mut p, 1)[0].feedback.encoder_count;
        p.faults_mut().encoder_noise = Some(faults::EncoderNoise { counts_per_period: 3, periods_left: 5 });
        let burst = run(&mut p, 8);
        let seen: Vec<i16> = burst.iter().map(|m| m.feedback.encoder_count.wrapping_sub(c0) as i16).collect();
        assert_eq!(seen, [3, 6, 9, 12, 15, 15, 15, 15], "3 counts per period for 5 periods, then none");
        assert_eq!(p.faults().encoder_noise, None, "the burst is over");
        // Now turning: the index (true count 0) is latched at the counter's value there, 15 counts beyond.
        let speed = 2.0 * RAD_PER_COUNT / PERIOD_S;
        p.set_mechanics(Mechanics::Driven { speed_rad_s: speed });
        let latches: Vec<u16> = run(&mut p, 200).iter().filter_map(|m| m.feedback.index_latch).collect();
        assert_eq!(latches, [15]);
    }

    #[test]
    fn lost_index_latches_nothing_until_repaired() {
        let mut p = driven(-100.0, 2.0);
        p.faults_mut().index_lost = true;
        // 2.5 turns: the index is passed twice.
        let lost = run(&mut p, 5120);
        assert!(lost.iter().all(|m| m.feedback.index_latch.is_none()));
        let counts = lost.last().map(|m| m.feedback.encoder_count).unwrap_or(0);
        assert_eq!(i64::from(counts), true_count(&p) & 0xFFFF, "the counter itself is unaffected");
        p.faults_mut().index_lost = false;
        let latches: Vec<u16> = run(&mut p, 2048).iter().filter_map(|m| m.feedback.index_latch).collect();
        assert_eq!(latches, [3 * 4096], "the next index, at three turns");
    }

    #[test]
    fn stuck_halls_read_their_state() {
        let mut p = driven(0.0, 2.0);
        for stuck in [0b000, 0b111, 0b101] {
            p.faults_mut().hall_stuck = Some(stuck);
            // 300 periods = 600 counts = 369 degrees electrical: every true state passes.
            assert!(run(&mut p, 300).iter().all(|m| m.feedback.hall == stuck), "stuck at {stuck:03b}");
        }
        p.faults_mut().hall_stuck = None;
        let m = run(&mut p, 1)[0];
        let truth = sensors::hall_state(7.0 * p.state_at_sample().theta_m_rad, 0.0);
        assert_eq!(m.feedback.hall, truth);
    }
}
