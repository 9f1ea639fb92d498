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
//!   positive rotation. The load torque acts at the output of a gear (ratio, backlash, efficiency) on a load that
//!   is either rigidly coupled (one mass, `T_load` and the load inertia reflected to the shaft) or on a compliant
//!   coupling (two masses, the load's angle and speed integrated with the rest): see `drivetrain`.
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
//!   floating at its back-EMF above the star point of the two others (`electrical`), switching or not; a
//!   short between two outputs is a resistance between their poles ([`inverter::OutputShort`]), loading the legs,
//!   their shunts, the bus and the over-current comparator while they switch.
//! * **Safe Torque Off** ([`Plant::set_sto_inputs`]): either STO input de-energised keeps the bridge from
//!   switching, as disabled outputs, whatever the command (the hardware path of EPOS4 AN ch. 9; `sto`).
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
//! instant: about 14 intervals, on each of which every pole voltage is `a V_bus + b` with constant `a`, `b` (the
//! dead-time diode chosen by the current's sign at the interval's start).
//!
//! * **Outputs switching** (`switching`): the shaft is held over each half period (`mechanics::Stretch`): the
//!   electrical intervals see it turn at a constant speed (the speed at the start of the half plus half a half period
//!   of the last half's acceleration, so that the angle at the end is what a constant acceleration gives) while they
//!   collect the integral of the electromagnetic torque (Simpson's rule per interval); at the sample instant and at the
//!   period end the shaft and the load then move over the half under its mean torque (one RK4 step of `w, theta, w_l,
//!   theta_l`; the load's pair only on a compliant coupling, whose resonance, 60 Hz for the geared preset, is slow
//!   against 20 us); the dq currents carry over to the rotor's new angle (a few microradians from the frame the
//!   intervals used; an open phase is held at zero there too). A motor held by static friction is released at the end
//!   of the interval where the torque breaks it away; with a load profile (an end stop's stiff spring) the intervals
//!   are split into segments of at most `T / substeps_per_period`, each a stretch of its own, so the profile is
//!   evaluated as often as before. With the shaft's speed fixed, the electrical state `[i_d, i_q, V_bus]` is a linear
//!   system whose only time dependence is the rotation of the rotor frame, and each interval is one classical
//!   Runge-Kutta (RK4) step of it, the frame's sine and cosine at the step's start, midpoint and end reached by
//!   rotation (one `sin_cos` per half period). The fastest dynamics are the bus (`R_source C` = 23.5 us against
//!   intervals of at most 20 us, mostly under 10 us: RK4 local error about `(h / tau)^5 / 120`, below 4e-3 of the bus's
//!   few millivolts of ripple at 20 us) and the winding (`L / R` = 0.61 ms).
//! * **Outputs off** (`freewheel`): each interval is split into equal segments no longer than
//!   `T / substeps_per_period` (8 by default: 5 us), each one RK4 step of the joint state (`i_abc, w, theta, V_bus`,
//!   `w_l, theta_l`): the diodes stop conducting at a segment's end.
//!
//! Held against the reference integrator the plant used before (RK4 segments of at most 5 us of the joint state
//! with the shaft; kept for the tests in `reference`, itself within 1.2e-4 A, 0.6 mV and 1.4e-4 rad/s of a
//! 128-sub-step run), fed the same commands: a 5 A current step on the free reference rotor differs by 0.2 mA in
//! the currents, 0.02 mV on the bus and 0.002 rad/s in speed, a run at 3,000 rpm with a load step by 0.4 mA, and
//! with the shaft's motion given (dynamometer, currents crossing zero in the dead times) by 1e-7 A; the sampled
//! codes differ by at most one. The model's own idealisations (ideal switches, constant diode drops) dominate by
//! orders of magnitude. The thermal nodes (time constants of 20 s and more) take one Euler step per period. No
//! allocation in `step`: one simulated second costs about 0.03 s of CPU in release builds (`drive-sim bench`).
//!
//! # Code layout
//!
//! This file holds the plant's state, the period loop ([`Plant::step`]) and the public accessors and hooks. The rest is
//! split by job: `coeffs` (the constants of one period), `switching` and `freewheel` (one integration interval with the
//! legs switching, and one segment with all switches off), `electrical` (the transforms, back-EMF, rotations and RK4
//! step both use), `mechanics` (torque, friction, stiction, load, the shaft held over a half period), `reference` (the
//! reference integrator, tests only), `thermal` (the temperature nodes) and `sampling` (the encoder after each segment
//! and stretch, the sample at the period centre); the public modules [`inverter`],
//! [`sensors`], [`faults`], [`io`] and [`rng`] hold the leg patterns, the sensor functions, the injected faults, the
//! digital I/O and the noise source.

mod coeffs;
mod drivetrain;
mod electrical;
pub mod faults;
pub mod file;
mod freewheel;
pub mod inverter;
pub mod io;
mod mechanics;
mod params;
#[cfg(test)]
mod reference;
pub mod rng;
mod sampling;
pub mod sensors;
mod sto;
mod switching;
mod thermal;
pub mod true_state_current_loop;

pub use file::PlantFileError;
pub use io::{BrakeParams, InputSource, InputWiring, IoParams};
pub use params::PlantParams;

use core::f64::consts::PI;

use firmware::hal::power::{Measurements, PwmCommand, PWM_FREQUENCY_HZ};

use coeffs::Coeffs;
use inverter::LegPattern;
use rng::Rng;

/// Length of one PWM period (and of one call of [`Plant::step`]), in s.
pub const PERIOD_S: f64 = 1.0 / PWM_FREQUENCY_HZ as f64;

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
    /// Angle of the load at the gear output, unwrapped, in rad (`theta_m / gear_ratio` when rigidly coupled).
    pub load_angle_rad: f64,
    /// Speed of the load at the gear output, in rad/s.
    pub load_speed_rad_s: f64,
    /// Electrical speed, in rad/s.
    pub omega_e_rad_s: f64,
    /// Electromagnetic torque, in N m.
    pub torque_nm: f64,
    /// Load torque acting at the gear output (constant plus profile, last evaluated), in N m.
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

/// A load-torque profile: `f(time_s, theta_l_rad, omega_l_rad_s) -> N m` at the gear output, from the load's angle and
/// speed (the motor's for the direct-drive reference plant), evaluated at the start of every integration segment (at
/// most `T / substeps_per_period`, with the outputs switching or not).
pub type LoadProfile = Box<dyn FnMut(f64, f64, f64) -> f64 + Send>;

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
    /// Load speed at the gear output, in rad/s (see `drivetrain`).
    omega_l: f64,
    /// Load angle at the gear output, in rad.
    theta_l: f64,
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
    /// The SSI frame latched at the last sample: the drive reads it one period later (the board's transfer runs
    /// during the period after the PWM centre that latched it).
    ssi_latched: u32,
    period: u64,
    at_sample: PlantState,
    averages: PeriodAverages,
    last_measurements: Measurements,
    /// Digital I/O state: forced inputs, output pins, holding brake ([`io`]).
    io: io::PlantIo,
    /// Injected failures ([`faults`]).
    faults: faults::PlantFaults,
    /// The chopper output: the braking resistor conducts (when the plant has one).
    chopper_gate: bool,
    /// Energy the braking resistor has taken since the start, in J.
    chopper_energy_j: f64,
    /// The Safe Torque Off inputs ([`sto`]): either one de-energised keeps the bridge from switching.
    sto: firmware::hal::sto::StoInputs,
    /// The motor's acceleration over the last stretch of switching intervals, in rad/s^2: the speed predictor of
    /// the next ([`mechanics::Stretch`]); 0 after anything else moved the shaft.
    stretch_acceleration: f64,
    /// Integrate with the reference integrator (RK4 segments of the joint state, `reference`) instead: only the
    /// tests set it.
    reference_integration: bool,
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
            omega_l: 0.0,
            theta_l: 0.0,
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
            ssi_latched: 0,
            period: 0,
            at_sample: PlantState::default(),
            averages: PeriodAverages::default(),
            last_measurements: Measurements::default(),
            io: io::PlantIo::default(),
            faults: faults::PlantFaults::default(),
            chopper_gate: false,
            chopper_energy_j: 0.0,
            sto: firmware::hal::sto::StoInputs::RELEASED,
            stretch_acceleration: 0.0,
            reference_integration: false,
            params,
        };
        plant.last_count = plant.count_now();
        plant.ssi_latched = plant.ssi_frame_now();
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
    /// * `break_input`: the over-current comparator (any leg current, the phase current plus the share of an injected
    ///   output short, beyond `break_current_a`, checked after every switching interval while the outputs are enabled)
    ///   has tripped. The trip latches and forces the outputs off until a command with `enabled == false` acknowledges
    ///   it.
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
        // The STO path gates the bridge in hardware, whatever the command ([`sto`]).
        let enabled = cmd.enabled && !self.break_latched && self.sto.torque_permitted();
        let mut patterns = [LegPattern::off(period_s); 3];
        let mut end_levels = [None; 3];
        if enabled {
            for x in 0..3 {
                let (pattern, level) = LegPattern::new(cmd.duty[x], self.levels[x], period_s, dead_time_s);
                patterns[x] = pattern;
                end_levels[x] = Some(level);
            }
        }
        let (breaks, n_breaks) = breakpoints(&patterns, enabled, sample_t, period_s);

        let mut acc = PeriodAverages::default();
        let mut sampled = false;
        let mut measurements = self.last_measurements;
        let mut t = 0.0;
        // The shaft held over the switching intervals since its start ([`mechanics::Stretch`]).
        let mut stretch: Option<mechanics::Stretch> = None;
        for &b in breaks[..n_breaks].iter() {
            if b - t > 1e-13 {
                // While the outputs switch, the interval between two switching instants is one step: every pole
                // voltage is constant over it. With the outputs off (and with the reference integrator), and with a
                // load profile (an end stop's stiff spring, a cogging map: evaluated as often as before), it is
                // split into equal segments no longer than the maximum step.
                let one_step = enabled && !self.break_latched && !self.reference_integration;
                let n = if one_step && self.load_profile.is_none() {
                    1.0
                } else {
                    ((b - t) / h_max - 1e-9).ceil().max(1.0)
                };
                let h = (b - t) / n;
                let mut j = 0.0;
                while j < n {
                    let t0 = t + j * h;
                    let t1 = if j + 1.0 >= n { b } else { t0 + h };
                    j += 1.0;
                    if enabled && !self.break_latched && !self.reference_integration {
                        // A segment of a split interval is a stretch of its own.
                        if n > 1.0 {
                            if let Some(s) = stretch.take() {
                                self.finish_stretch(&k, s, t0);
                            }
                        }
                        let s = match stretch.as_mut() {
                            Some(s) => s,
                            None => stretch.insert(self.start_stretch(&k, t0)),
                        };
                        let i = self.switching_interval(&k, &patterns, s, t0, t1, &mut acc);
                        if i.iter().any(|x| x.abs() > self.params.break_current_a) {
                            self.break_latched = true;
                        }
                        if self.stretch_breaks_away(&k, s) {
                            if let Some(s) = stretch.take() {
                                self.finish_stretch(&k, s, t1);
                            }
                        }
                        continue;
                    }
                    if let Some(s) = stretch.take() {
                        self.finish_stretch(&k, s, t0);
                    }
                    #[cfg(test)]
                    if enabled && !self.break_latched {
                        self.reference_segment(&k, &patterns, t0, t1, &mut acc);
                        continue;
                    }
                    self.freewheel_segment(&k, t0, t1, &mut acc);
                }
                t = b;
            }
            if !sampled && t >= sample_t - 1e-15 {
                if let Some(s) = stretch.take() {
                    self.finish_stretch(&k, s, t);
                }
                sampled = true;
                let switching_now = enabled && !self.break_latched;
                measurements = self.sample(&patterns, switching_now, sample_t, t);
            }
        }
        if let Some(s) = stretch.take() {
            self.finish_stretch(&k, s, t);
        }

        // Period bookkeeping: averages, thermal nodes, leg levels.
        let acc = PeriodAverages::from_integrals(acc, period_s);
        // Conduction loss of the switches: every phase current flows through one switch (or diode) at a time.
        let switch_loss_w = acc.copper_loss_w * k.r_switch / (k.r - k.r_switch).max(1e-12);
        self.update_thermal(acc.copper_loss_w, switch_loss_w, period_s);
        // The resistor's energy from the period's mean bus voltage (the bus moves by millivolts within a period).
        self.chopper_energy_j += k.g_chopper * acc.bus_voltage_v * acc.bus_voltage_v * period_s;
        self.averages = acc;
        self.levels = if self.break_latched { [None; 3] } else { end_levels };
        self.io.advance(&self.params.io, period_s);
        self.period += 1;
        self.last_measurements = measurements;
        measurements
    }

    /// One integration segment `[t0, t1)` of the period with all switches off (outputs disabled or the break
    /// tripped): the load torque at its start, the diode bridge ([`freewheel`]), then the encoder follows the shaft.
    fn freewheel_segment(&mut self, k: &Coeffs, t0: f64, t1: f64, acc: &mut PeriodAverages) {
        self.stretch_acceleration = 0.0;
        self.update_load(t0);
        self.segment_freewheel(k, t1 - t0, acc);
        self.update_encoder();
    }

    fn state_at(&self, t_in_period: f64) -> PlantState {
        self.state_with(t_in_period, self.i_abc())
    }

    /// The state at `t_in_period` with the phase currents `i_abc` (those now, computed by the caller).
    fn state_with(&self, t_in_period: f64, i_abc: [f64; 3]) -> PlantState {
        let p = &self.params;
        let pp = f64::from(p.pole_pairs);
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
            load_angle_rad: self.theta_l,
            load_speed_rad_s: self.omega_l,
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

    /// The encoder count the rotor's true angle gives now, in the plant's coordinates (where the limit and home
    /// switches are placed), without the injected sensor faults.
    pub fn true_encoder_count(&self) -> i64 {
        self.count_now()
    }

    // ---- Hooks: mechanics and load ----

    /// Choose how the shaft moves (free, locked, driven at a speed). A load on a compliant coupling stays free.
    pub fn set_mechanics(&mut self, mechanics: Mechanics) {
        self.mechanics = mechanics;
        self.stretch_acceleration = 0.0;
        match mechanics {
            Mechanics::Free => {}
            Mechanics::Locked => self.omega_m = 0.0,
            Mechanics::Driven { speed_rad_s } => self.omega_m = speed_rad_s,
        }
        if !self.params.coupling_is_compliant() {
            self.follow_motor(self.params.gear_ratio);
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
    /// The encoder follows without producing index latches for the jump; the load follows through the gear with the
    /// coupling relaxed (in the middle of the backlash).
    pub fn set_rotor_state(&mut self, theta_m_rad: f64, omega_m_rad_s: f64) {
        self.theta_m = theta_m_rad;
        self.omega_m = omega_m_rad_s;
        self.stretch_acceleration = 0.0;
        self.follow_motor(self.params.gear_ratio);
        self.last_count = self.count_now();
        self.ssi_latched = self.ssi_frame_now();
        self.pending_index = None;
    }

    /// Set the load's angle (rad at the output, unwrapped) and speed (rad/s), e.g. to start a free oscillation of
    /// a compliant coupling. With a rigid coupling the load follows the motor again at the next segment.
    pub fn set_load_state(&mut self, theta_l_rad: f64, omega_l_rad_s: f64) {
        self.theta_l = theta_l_rad;
        self.omega_l = omega_l_rad_s;
    }

    /// The total count of the load encoder now (`PlantParams::load_encoder_counts_per_rev` counts per output turn,
    /// count 0 at load angle 0), or `None` without one: the drive's sensor 2 (0x3020, the dual loop's main sensor).
    pub fn load_encoder_count(&self) -> Option<i64> {
        let cpr = self.params.load_encoder_counts_per_rev;
        (cpr > 0).then(|| sensors::encoder_count(self.theta_l, cpr, 0))
    }

    /// Set a constant external load torque at the gear output, in N m (positive opposes positive rotation). A load
    /// profile, if set, adds to it.
    pub fn set_load_torque(&mut self, torque_nm: f64) {
        self.load_torque_nm = torque_nm;
    }

    /// Set a load-torque profile `f(time_s, theta_l_rad, omega_l_rad_s) -> N m` (see [`LoadProfile`]), added to the
    /// constant load torque and evaluated at the start of every integration segment; `None` removes it.
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

    /// The drive's chopper output for the periods from the next on: the braking resistor across the bus while
    /// `on` (nothing when the plant has none, `PlantParams::chopper_resistance_ohm` infinite).
    pub fn set_chopper_gate(&mut self, on: bool) {
        self.chopper_gate = on;
    }

    /// Energy the braking resistor has taken since the start, in J.
    pub fn chopper_energy_j(&self) -> f64 {
        self.chopper_energy_j
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

/// Most instants that cut one period: every piece end of the three legs, the sample instant and the period end.
const MAX_BREAKPOINTS: usize = 3 * LegPattern::MAX_PIECES + 2;

/// Breakpoints of the period, sorted: every switching instant of the three legs (while the outputs are enabled),
/// the sample instant and the period end. The first `n` entries of the returned `(array, n)` are the breakpoints.
fn breakpoints(
    patterns: &[LegPattern; 3],
    enabled: bool,
    sample_t: f64,
    period_s: f64,
) -> ([f64; MAX_BREAKPOINTS], usize) {
    let mut breaks = [0.0f64; MAX_BREAKPOINTS];
    let mut n_breaks = 0;
    for b in [sample_t, period_s] {
        breaks[n_breaks] = b;
        n_breaks += 1;
    }
    if enabled {
        for pattern in patterns {
            for &b in pattern.boundaries() {
                breaks[n_breaks] = b;
                n_breaks += 1;
            }
        }
    }
    breaks[..n_breaks].sort_unstable_by(f64::total_cmp);
    (breaks, n_breaks)
}

impl PeriodAverages {
    /// The averages from the integrals over a period of `period_s` the segments accumulated (the phase voltages,
    /// which the segments leave at zero, from the averaged pole voltages).
    fn from_integrals(mut acc: Self, period_s: f64) -> Self {
        for v in acc.pole_voltage_v.iter_mut() {
            *v /= period_s;
        }
        let mean = (acc.pole_voltage_v[0] + acc.pole_voltage_v[1] + acc.pole_voltage_v[2]) / 3.0;
        acc.phase_voltage_v = acc.pole_voltage_v.map(|v| v - mean);
        acc.dq_voltage_v = acc.dq_voltage_v.map(|v| v / period_s);
        acc.bus_voltage_v /= period_s;
        acc.bus_current_a /= period_s;
        acc.copper_loss_w /= period_s;
        acc
    }
}
