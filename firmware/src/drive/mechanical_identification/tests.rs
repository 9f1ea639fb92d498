//! The mechanical step against plant models written here: a rigid body with Coulomb and viscous friction and
//! back-EMF, and a two-mass drivetrain with a coupling spring and backlash (the presets of `hal-sim/presets/`),
//! plus the step's errors and the least-squares solver on exact data.

use super::*;
use core::f64::consts::TAU;

const F: f64 = 2_500.0;
const SUBSTEPS: u32 = 40;

/// A motor (q axis only, current loop as a first-order lag) on a rigid or elastic drivetrain, everything at the
/// motor shaft.
#[derive(Clone, Debug)]
struct Plant {
    kt: f64,
    pole_pairs: f64,
    r: f64,
    lq: f64,
    /// The inverter's voltage error per current sign (dead time, diode drops), volts.
    dead_time_v: f64,
    /// Current-loop time constant, s.
    current_tau: f64,
    j_motor: f64,
    /// Load inertia at the motor shaft; rigid when `stiffness` is 0.
    j_load: f64,
    /// Coupling stiffness and damping at the motor shaft (Nm/rad, Nm s/rad).
    stiffness: f64,
    damping: f64,
    /// Total backlash at the motor shaft, rad.
    backlash: f64,
    coulomb_motor: f64,
    coulomb_load: f64,
    viscous: f64,
    cpr: f64,
    v_bus: f64,
    /// An external torque on the motor shaft (an overhauling load), Nm.
    load_torque: f64,
    /// Bus capacitance, F (0: a stiff bus at `v_bus`). The supply feeds it through a diode at `v_bus`: braking
    /// energy charges it, nothing takes it back but the motor.
    bus_capacitance: f64,
    /// The bus voltage now (with a capacitance).
    bus_now: f64,
    /// The highest bus voltage seen.
    bus_peak: f64,
    /// Amplitude of a deterministic pseudo-noise on the measured current, A.
    current_noise: f64,
    // State.
    theta: f64,
    omega: f64,
    theta_load: f64,
    omega_load: f64,
    i_q: f64,
    noise_state: u32,
}

impl Plant {
    /// The reference plant (`reference.toml`): kt 0.0335, 176 g cm^2 rigid, Tc 3 mNm, B 2e-6 Nm s/rad.
    fn reference() -> Self {
        Self {
            kt: 0.0335,
            pole_pairs: 7.0,
            r: 0.26,
            lq: 165e-6,
            dead_time_v: 0.5e-6 * 25_000.0 * 24.0,
            current_tau: 0.2e-3,
            j_motor: 4.4e-6,
            j_load: 13.2e-6,
            stiffness: 0.0,
            damping: 0.0,
            backlash: 0.0,
            coulomb_motor: 0.003,
            coulomb_load: 0.0,
            viscous: 2e-6,
            cpr: 4096.0,
            v_bus: 24.0,
            load_torque: 0.0,
            bus_capacitance: 0.0,
            bus_now: 24.0,
            bus_peak: 0.0,
            current_noise: 0.02,
            theta: 0.0,
            omega: 0.0,
            theta_load: 0.0,
            omega_load: 0.0,
            i_q: 0.0,
            noise_state: 12_345,
        }
    }

    /// `small-gimbal.toml`: kt 0.05, 10 g cm^2, Tc 0.6 mNm, B 2e-7, 16,384 counts, 12 V.
    fn small_gimbal() -> Self {
        Self {
            kt: 0.05,
            pole_pairs: 11.0,
            r: 2.8,
            lq: 1.5e-3,
            dead_time_v: 0.5e-6 * 25_000.0 * 12.0,
            j_motor: 1e-6,
            j_load: 0.0,
            coulomb_motor: 0.0006,
            viscous: 2e-7,
            cpr: 16_384.0,
            v_bus: 12.0,
            current_noise: 0.005,
            ..Self::reference()
        }
    }

    /// `geared-36v.toml` at the motor shaft: kt 0.1, rotor 200 g cm^2, load 0.0075 kg m^2 through 5:1 (300 g cm^2
    /// at the motor), coupling 66.62 Nm/rad at the output (2.665 at the motor: 60 Hz resonance, 15 Hz
    /// anti-resonance), 0.3 deg backlash at the output (1.5 deg at the motor), Tc 10 mNm + 45 mNm / 5 at the
    /// motor, B 1e-5, 5,000 counts, 36 V.
    fn geared() -> Self {
        Self {
            kt: 0.1,
            pole_pairs: 5.0,
            r: 0.05,
            lq: 90e-6,
            dead_time_v: 0.5e-6 * 25_000.0 * 36.0,
            j_motor: 2e-5,
            j_load: 0.0075 / 25.0,
            stiffness: 66.6198 / 25.0,
            damping: 0.017671 / 25.0,
            backlash: 0.3_f64.to_radians() * 5.0,
            coulomb_motor: 0.01,
            coulomb_load: 0.045 / 5.0,
            viscous: 1e-5,
            cpr: 5000.0,
            v_bus: 36.0,
            current_noise: 0.05,
            ..Self::reference()
        }
    }

    fn rigid(&self) -> bool {
        self.stiffness == 0.0
    }

    fn total_inertia(&self) -> f64 {
        self.j_motor + self.j_load
    }

    fn total_coulomb(&self) -> f64 {
        self.coulomb_motor + self.coulomb_load
    }

    fn noise(&mut self) -> f64 {
        // xorshift32: deterministic, uniform in [-1, 1).
        let mut x = self.noise_state;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.noise_state = x;
        f64::from(x) / f64::from(u32::MAX) * 2.0 - 1.0
    }

    /// One body's speed after a substep with Coulomb friction that sticks at zero speed.
    fn integrate(omega: f64, torque: f64, coulomb: f64, inertia: f64, h: f64) -> f64 {
        if omega == 0.0 && torque.abs() <= coulomb {
            return 0.0;
        }
        let direction = if omega != 0.0 { omega.signum() } else { torque.signum() };
        let next = omega + h * (torque - coulomb * direction) / inertia;
        if omega != 0.0 && next.signum() != omega.signum() {
            0.0
        } else {
            next
        }
    }

    /// One slow tick with the q current demand `i_ref`: the sample the drive would take (averaged current and
    /// voltage, quantised position).
    fn tick(&mut self, i_ref: f64) -> MechanicalSample {
        let h = 1.0 / F / f64::from(SUBSTEPS);
        let (mut i_sum, mut v_sum) = (0.0, 0.0);
        for _ in 0..SUBSTEPS {
            let di = (i_ref - self.i_q) / self.current_tau * h;
            let di = if di.abs() > (i_ref - self.i_q).abs() { i_ref - self.i_q } else { di };
            self.i_q += di;
            let v = self.r * self.i_q
                + self.lq * di / h
                + self.kt / 1.5 * self.omega
                + self.dead_time_v * self.i_q.signum();
            i_sum += self.i_q;
            v_sum += v;
            if self.bus_capacitance > 0.0 {
                // Power into the motor 1.5 v_q i_q (amplitude-invariant dq) drawn from the capacitor; the supply
                // tops it up to v_bus through its diode.
                self.bus_now -= 1.5 * v * self.i_q / self.bus_now / self.bus_capacitance * h;
                self.bus_now = self.bus_now.max(self.v_bus);
                self.bus_peak = self.bus_peak.max(self.bus_now);
            }
            let drive = self.kt * self.i_q + self.load_torque - self.viscous * self.omega;
            if self.rigid() {
                self.omega = Self::integrate(self.omega, drive, self.total_coulomb(), self.total_inertia(), h);
                self.theta += self.omega * h;
            } else {
                let twist = self.theta - self.theta_load;
                let half = self.backlash / 2.0;
                let spring = if twist > half {
                    self.stiffness * (twist - half) + self.damping * (self.omega - self.omega_load)
                } else if twist < -half {
                    self.stiffness * (twist + half) + self.damping * (self.omega - self.omega_load)
                } else {
                    0.0
                };
                self.omega = Self::integrate(self.omega, drive - spring, self.coulomb_motor, self.j_motor, h);
                self.omega_load = Self::integrate(self.omega_load, spring, self.coulomb_load, self.j_load, h);
                self.theta += self.omega * h;
                self.theta_load += self.omega_load * h;
            }
        }
        let noise = self.noise() * self.current_noise;
        let n = f64::from(SUBSTEPS);
        MechanicalSample {
            position: (self.theta / TAU * self.cpr).floor() as i64 as i32,
            i_q: Amps::from_bits((((i_sum / n) + noise) * 65_536.0).round() as i32),
            v_q: Volts::from_bits(((v_sum / n) * 65_536.0).round() as i32),
            v_bus: Volts::from_bits((self.bus_now.max(self.v_bus) * 65_536.0) as i32),
        }
    }
}

fn config(plant: &Plant, current_limit_a: f64, max_rpm: u32) -> MechanicalConfig {
    MechanicalConfig {
        current_limit: Amps::from_bits((current_limit_a * 65_536.0) as i32),
        max_speed_rpm: max_rpm,
        counts_per_rev: plant.cpr as u32,
        pole_pairs: plant.pole_pairs as u8,
        phase_resistance_milliohm: (plant.r * 1000.0).round() as u32,
        timeout_ticks: 12_500,
        regeneration_limit: Volts::from_bits(51 << 16),
    }
}

/// What a run shows besides the outcome: the largest current demanded and speed reached.
struct Run {
    status: MechanicalStatus,
    max_demand_a: f64,
    max_speed_rpm: f64,
    seconds: f64,
}

fn run(plant: &mut Plant, config: &MechanicalConfig) -> Run {
    let mut id = MechanicalIdentification::new(config);
    let mut demand = 0.0;
    let mut max_demand_a: f64 = 0.0;
    let mut max_speed_rpm: f64 = 0.0;
    let mut last_progress = 0;
    for tick in 0..100_000u32 {
        let sample = plant.tick(demand);
        max_speed_rpm = max_speed_rpm.max(plant.omega.abs() * 60.0 / TAU);
        let status = id.step(&sample);
        let progress = id.progress_per_mille();
        assert!(progress >= last_progress, "progress goes forward");
        last_progress = progress;
        match status {
            MechanicalStatus::Running { i_q_demand } => {
                demand = f64::from(i_q_demand.to_bits()) / 65_536.0;
                max_demand_a = max_demand_a.max(demand.abs());
            }
            other => {
                assert_eq!(id.step(&sample), other, "a finished step repeats its outcome");
                return Run { status: other, max_demand_a, max_speed_rpm, seconds: f64::from(tick + 1) / F };
            }
        }
    }
    panic!("the step never finished");
}

fn error_pct(measured: f64, truth: f64) -> f64 {
    (measured - truth) / truth * 100.0
}

/// Runs the identification on `plant` and checks kt, inertia and friction against the plant's values.
/// Returns the errors in percent (kt, inertia, Coulomb, viscous) for the message.
fn identify(mut plant: Plant, limit_a: f64, max_rpm: u32) -> (MechanicalResult, [f64; 4], Run) {
    let config = config(&plant, limit_a, max_rpm);
    let truth = plant.clone();
    let run = run(&mut plant, &config);
    let MechanicalStatus::Done(result) = run.status else { panic!("identification failed: {:?}", run.status) };
    let kt = f64::from(result.torque_constant) * 1e-6;
    let inertia = f64::from(result.inertia) * 1e-10;
    let coulomb = f64::from(result.coulomb_friction) * 1e-6;
    let viscous = f64::from(result.viscous_friction) * 1e-9 / (TAU / 60.0);
    let errors = [
        error_pct(kt, truth.kt),
        error_pct(inertia, truth.total_inertia()),
        error_pct(coulomb, truth.total_coulomb()),
        error_pct(viscous, truth.viscous),
    ];
    println!(
        "kt {:.2} %, inertia {:.2} %, coulomb {:.1} %, viscous {:.1} %, relay {:.3} A, {} half cycles, {:.2} s, \
         max {:.0} rpm, {result:?}",
        errors[0],
        errors[1],
        errors[2],
        errors[3],
        f64::from(result.relay_current.to_bits()) / 65_536.0,
        result.half_cycles,
        run.seconds,
        run.max_speed_rpm
    );
    assert!(run.max_demand_a <= limit_a + 1e-4, "current demand {} above the limit {limit_a}", run.max_demand_a);
    assert!(run.max_speed_rpm < f64::from(max_rpm), "speed {} above the max system speed", run.max_speed_rpm);
    assert!(run.seconds < 5.0, "took {} s of the procedure's 20 s", run.seconds);
    (result, errors, run)
}

// Tolerances: issue 18 "What it must show" asks kt within 3 %, inertia within 5 % (rigid) and 10 % (elastic).
// Friction has no stated tolerance; Coulomb friction is checked within 25 % (it is 2 to 9 % of the relay's torque,
// so 25 % of it is 0.5 to 2 % of the torque the fit resolves) and viscous friction, which adds less than 1 % of
// the torque at the relay speed on these plants, only for its order of magnitude on the reference.

#[test]
fn reference_plant_kt_within_3_pct_inertia_within_5_pct() {
    let (_, e, _) = identify(Plant::reference(), 3.2, 5000);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
    assert!(e[2].abs() < 25.0, "Coulomb friction error {} %", e[2]);
    assert!(e[3].abs() < 100.0, "viscous friction error {} %", e[3]);
}

#[test]
fn small_gimbal_kt_within_3_pct_inertia_within_5_pct() {
    let (_, e, _) = identify(Plant::small_gimbal(), 0.6, 1200);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
    assert!(e[2].abs() < 25.0, "Coulomb friction error {} %", e[2]);
}

#[test]
fn geared_two_mass_with_backlash_kt_within_3_pct_total_inertia_within_10_pct() {
    let (_, e, _) = identify(Plant::geared(), 5.0, 2000);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 10.0, "inertia error {} %", e[1]);
    // The coupling rings after each reversal (60 Hz, 5 % damping); what is left of it in the steady blocks is of
    // the order of the friction (2 % of the relay torque), so Coulomb friction only within 50 % here.
    assert!(e[2].abs() < 50.0, "Coulomb friction error {} %", e[2]);
}

/// The solver recovers exact coefficients from exact data whose sums need the scaling (y y above 2^80).
#[test]
fn least_squares_recovers_exact_coefficients_from_large_sums() {
    let mut fit = Regression3::default();
    for k in 0..5_000i64 {
        let x = [(k * 7_919 % 2_003 - 1_000) * 100_000, k % 3 - 1, 1];
        fit.add(x, 5 * x[0] - 300_000 * x[1] + 11_000_000 * x[2]);
    }
    let solution = fit.solve().expect("regular equations");
    // The scaling rounds each sum to 40 bits of the diagonal's size: relative errors of about 2^-40 times the
    // equations' condition (here ~1e7, the regressors differ by 1e8 in size) remain, below 1e-4.
    let near = |value: Option<i64>, truth: i64| {
        let value = value.expect("a value");
        assert!((value - truth).abs() as f64 <= truth.abs() as f64 * 1e-4, "{value} vs {truth}");
    };
    near(solution.scaled(0, 1_000, 1), 5_000);
    near(solution.scaled(1, 1, 1), -300_000);
    near(solution.scaled(2, 1, 1), 11_000_000);
    near(solution.ratio(1, 0, 1, 1), -60_000);
    near(solution.inverse_scaled(0, 1_000, 1), 200);
}

/// Equations that do not determine the coefficients (one regressor always zero) give no solution.
#[test]
fn least_squares_refuses_singular_equations() {
    let mut fit = Regression3::default();
    for k in 0..100i64 {
        fit.add([k, 0, 1], 2 * k);
    }
    assert_eq!(fit.solve(), None);
}

/// A blocked shaft: no movement at any probe level up to the full test current ends the step with
/// `Obstructed`, IDX 0xFF21 (seed 002 L7585 "motor movement has been obstructed"), after the five probe levels.
#[test]
fn blocked_shaft_fails_obstructed_0xff21_after_trying_the_full_current() {
    let mut plant = Plant { coulomb_motor: 1.0, ..Plant::reference() };
    let config = config(&plant, 3.2, 5000);
    let run = run(&mut plant, &config);
    assert_eq!(run.status, MechanicalStatus::Failed(MechanicalError::Obstructed));
    assert_eq!(MechanicalError::Obstructed.code(), 0xFF21);
    assert!((run.max_demand_a - 3.2).abs() < 1e-4, "tried up to {} A", run.max_demand_a);
    let ticks = (run.seconds * F).round() as u32;
    assert_eq!(ticks, SPEED_TICKS + (PROBE_LEVELS + 1) * PROBE_TICKS);
}

/// An overhauling load that the test current cannot hold drives the motor past the max system speed: the step
/// fails with `SpeedLimit`, IDX 0xFF22 (seed 002 L7591), at the first sample above it.
#[test]
fn overhauling_load_fails_speed_limit_0xff22_at_the_max_system_speed() {
    let mut plant = Plant { load_torque: 0.2, ..Plant::reference() };
    let config = config(&plant, 3.2, 5000);
    let run = run(&mut plant, &config);
    assert_eq!(run.status, MechanicalStatus::Failed(MechanicalError::SpeedLimit));
    assert_eq!(MechanicalError::SpeedLimit.code(), 0xFF22);
    // The speed over the last 3.2 ms crossed 5,000 rpm; the shaft's own speed is at most a few % above.
    assert!(run.max_speed_rpm > 5000.0 && run.max_speed_rpm < 5300.0, "{} rpm", run.max_speed_rpm);
}

/// The step ends with `Timeout`, IDX 0xFF19, at the configured tick.
#[test]
fn step_fails_timeout_0xff19_at_the_configured_tick() {
    let mut plant = Plant::reference();
    let config = MechanicalConfig { timeout_ticks: 400, ..config(&plant, 3.2, 5000) };
    let run = run(&mut plant, &config);
    assert_eq!(run.status, MechanicalStatus::Failed(MechanicalError::Timeout));
    assert_eq!(MechanicalError::Timeout.code(), 0xFF19);
    assert_eq!((run.seconds * F).round() as u32, 401);
}

/// A motor that turns against the current (wrong direction or commutation) fails with `SampleMismatch`,
/// IDX 0xFF15, in the probe, before any speed builds up.
#[test]
fn motor_turning_against_the_current_fails_sample_mismatch_0xff15() {
    let mut plant = Plant { kt: -0.0335, ..Plant::reference() };
    let config = config(&plant, 3.2, 5000);
    let run = run(&mut plant, &config);
    assert_eq!(run.status, MechanicalStatus::Failed(MechanicalError::SampleMismatch));
    assert_eq!(MechanicalError::SampleMismatch.code(), 0xFF15);
    assert!(run.max_speed_rpm < 1500.0, "{} rpm", run.max_speed_rpm);
}

/// A zero encoder resolution, current limit, max speed, pole-pair count or limiter voltage is refused with `InvalidConfig`, IDX 0xFF16, at the
/// first sample, without any current.
#[test]
fn zero_configuration_values_fail_invalid_config_0xff16() {
    let plant = Plant::reference();
    let good = config(&plant, 3.2, 5000);
    for bad in [
        MechanicalConfig { counts_per_rev: 0, ..good },
        MechanicalConfig { current_limit: Amps::ZERO, ..good },
        MechanicalConfig { max_speed_rpm: 0, ..good },
        MechanicalConfig { pole_pairs: 0, ..good },
        MechanicalConfig { regeneration_limit: Volts::ZERO, ..good },
    ] {
        let mut id = MechanicalIdentification::new(&bad);
        assert_eq!(
            id.step(&MechanicalSample::default()),
            MechanicalStatus::Failed(MechanicalError::InvalidConfig),
            "{bad:?}"
        );
    }
    assert_eq!(MechanicalError::InvalidConfig.code(), 0xFF16);
}

/// A bus that cannot take the braking energy (the geared preset's 36 V supply, 470 uF, no chopper; 51 V the
/// limiter's loss-braking voltage 0x3202:02): the relay lowers its speed until a braking half cycle keeps the bus
/// below 15/16 of 51 V (47.8 V). From 1,000 rpm the 3,200 g cm^2 return 1.75 J, while the capacitor holds 0.31 J
/// between 36 and 47.8 V: the speed must fall below 1,000 sqrt(0.31 / 1.75) = 420 rpm (less the friction's
/// share). The figures stay within the elastic tolerances.
#[test]
fn relay_speed_falls_until_braking_keeps_the_bus_below_the_limiter() {
    let plant = Plant { bus_capacitance: 470e-6, bus_now: 36.0, ..Plant::geared() };
    let (result, e, _) = identify(plant, 5.0, 2000);
    assert!(result.relay_speed_rpm < 420, "relay speed {} rpm", result.relay_speed_rpm);
    assert!(result.relay_speed_rpm >= 2000 / 16, "floor 1/16 of the max speed: {} rpm", result.relay_speed_rpm);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 10.0, "inertia error {} %", e[1]);
}

/// Where samples leave the fit (module documentation, "The experiment" 2), in `Volts` bits (1/65,536 V), against
/// the default limiter voltage 0x3202:02 = 51 V: 15/16 of it (47.8125 V) under a 24 or 36 V supply; half way from
/// a 48 V supply (49.5 V), where 15/16 lies under the supply itself; with the limiter off (its voltage `i32::MAX`
/// bits) 15/16 of that; and no experiment (`None`, IDX 0xFF16) where the bus rests within 1/32 of the limit
/// (1.59 V): 50 V under 51 V, while 49.375 V (1.625 V under it) still runs.
#[test]
fn samples_leave_the_fit_at_15_16_of_the_limiter_or_half_way_to_it_from_a_high_supply() {
    let v = |volts: f64| Volts::from_bits((volts * 65_536.0) as i32);
    assert_eq!(bus_high_voltage(v(24.0), v(51.0)), Some(v(47.8125)));
    assert_eq!(bus_high_voltage(v(36.0), v(51.0)), Some(v(47.8125)));
    assert_eq!(bus_high_voltage(v(48.0), v(51.0)), Some(v(49.5)));
    let off = Volts::from_bits(i32::MAX);
    assert_eq!(bus_high_voltage(v(48.0), off), Some(Volts::from_bits(i32::MAX - (i32::MAX >> 4))));
    assert_eq!(bus_high_voltage(v(49.375), v(51.0)), Some(v(50.1875)), "1.625 V: just above 1/32 of 51 V");
    assert_eq!(bus_high_voltage(v(50.0), v(51.0)), None);
}

/// The reference motor on a 48 V supply (the common industrial class) with 470 uF and the default limiter at
/// 51 V. Before the rule above, 15/16 of 51 V (47.8 V) lay under the supply: every sample left the fit, the relay
/// lowered its speed to its floor and the step failed with 0xFF15 on a motor it identifies at 24 V. Now the relay
/// lowers its speed from 2,500 rpm until braking keeps the bus under 49.5 V (this model has no limiter, so the
/// first half cycles lift it further), and kt is within 3 %, the inertia within 5 % (issue 18, rigid).
#[test]
fn a_48_v_supply_under_the_default_limiter_identifies_within_3_and_5_pct() {
    let plant = Plant {
        v_bus: 48.0,
        bus_now: 48.0,
        bus_capacitance: 470e-6,
        dead_time_v: 0.5e-6 * 25_000.0 * 48.0,
        ..Plant::reference()
    };
    let (result, e, _) = identify(plant, 3.2, 5000);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
    assert!(result.relay_speed_rpm < 2500, "relay speed {} rpm: lowered", result.relay_speed_rpm);
}

/// A supply within 1/32 of the limiter's voltage (50 V under 51 V): the limiter would act on the first braking,
/// so the step refuses at the end of its start, before any current: IDX 0xFF16, 0x3202:02 against the supply.
#[test]
fn a_supply_within_2_64_of_the_limiter_fails_invalid_config_0xff16_before_any_current() {
    let mut plant = Plant { v_bus: 50.0, bus_now: 50.0, ..Plant::reference() };
    let config = config(&plant, 3.2, 5000);
    let run = run(&mut plant, &config);
    assert_eq!(run.status, MechanicalStatus::Failed(MechanicalError::InvalidConfig));
    assert_eq!(run.max_demand_a, 0.0, "no current was demanded");
    assert_eq!(run.seconds, f64::from(SPEED_TICKS) / F, "at the end of the start");
}

/// A coarse encoder: a stepper-class motor (kt 0.15 Nm/A, 8 ohm, 6 mH, 500 g cm^2, 10 mNm) with 1,024 counts/rev,
/// about 3.4 counts per tick at the relay speed (500 rpm). The torque-constant fit over single ticks had their
/// quantization in its speed regressor and came out 4.75 % low in the simulator (`tests/tests/drive/
/// coarse_encoder.rs`); over blocks of 8 ticks kt is within 3 % and the inertia within 5 % (issue 18, rigid).
#[test]
fn a_1024_count_encoder_leaves_kt_within_3_pct_and_inertia_within_5_pct() {
    let plant = Plant {
        kt: 0.15,
        pole_pairs: 3.0,
        r: 8.0,
        lq: 6e-3,
        dead_time_v: 0.5e-6 * 25_000.0 * 24.0,
        j_motor: 5e-5,
        j_load: 0.0,
        coulomb_motor: 0.01,
        viscous: 1e-5,
        cpr: 1024.0,
        ..Plant::reference()
    };
    let (_, e, _) = identify(plant, 0.8, 1000);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
}

/// A Coulomb friction of 2.5 and 5 times the small gimbal's (1.5 and 3 mNm, 5 and 10 % of the nominal torque,
/// as large as the relay's own torque): the relay current, adapted to the inertia alone, may fall below the
/// breakaway torque; the relay doubles it when the speed is not reached, and blocks where the shaft stood stay out
/// of the fit (static friction is not the sign(w) model). kt within 3 %, inertia within 5 % (issue 18, rigid).
#[test]
fn small_gimbal_with_up_to_five_times_its_friction_kt_within_3_pct_inertia_within_5_pct() {
    let (_, e, _) = identify(Plant { coulomb_motor: 0.0015, ..Plant::small_gimbal() }, 0.6, 1200);
    assert!(e[0].abs() < 3.0, "kt error {} %", e[0]);
    assert!(e[1].abs() < 5.0, "inertia error {} %", e[1]);
    // Five times: right values or the plausibility check's fault (on this model the even and odd cycles
    // disagree), never a wrong value.
    let mut plant = Plant { coulomb_motor: 0.003, ..Plant::small_gimbal() };
    let truth = plant.clone();
    match run(&mut plant, &config(&truth, 0.6, 1200)).status {
        MechanicalStatus::Done(r) => {
            let inertia = error_pct(f64::from(r.inertia) * 1e-10, truth.total_inertia());
            let kt = error_pct(f64::from(r.torque_constant) * 1e-6, truth.kt);
            assert!(kt.abs() < 3.0 && inertia.abs() < 5.0, "kt {kt} %, inertia {inertia} %");
        }
        other => assert_eq!(other, MechanicalStatus::Failed(MechanicalError::SampleMismatch)),
    }
}

/// A relay current below the breakaway torque from the start of the relay: the shaft sticks, the relay doubles
/// the current after [`STALL_TICKS`] without reaching the relay speed, and the step still ends with values within
/// the tolerances (the stuck blocks count in no fit).
#[test]
fn a_stuck_relay_doubles_its_current_and_the_stuck_blocks_stay_out_of_the_fit() {
    let mut plant = Plant { coulomb_motor: 0.0015, ..Plant::small_gimbal() };
    let config = config(&plant, 0.6, 1200);
    let truth = plant.clone();
    let mut id = MechanicalIdentification::new(&config);
    let mut demand = 0.0;
    let mut stuck_ticks = 0u32;
    let mut lowered = false;
    let result = loop {
        let sample = plant.tick(demand);
        if let Phase::Relay { .. } = id.phase {
            if id.half_cycles == 1 && !lowered {
                lowered = true;
                // After the first reversal: the current below the breakaway (0.0015 / 0.05 = 30 mA).
                id.relay_current = (0.02 * 65_536.0) as i64;
            }
            stuck_ticks += u32::from(plant.omega == 0.0);
        }
        match id.step(&sample) {
            MechanicalStatus::Running { i_q_demand } => demand = f64::from(i_q_demand.to_bits()) / 65_536.0,
            MechanicalStatus::Done(result) => break result,
            other => panic!("{other:?}"),
        }
    };
    assert!(stuck_ticks > STALL_TICKS / 2, "the shaft stuck for {stuck_ticks} ticks");
    let inertia = error_pct(f64::from(result.inertia) * 1e-10, truth.total_inertia());
    let kt = error_pct(f64::from(result.torque_constant) * 1e-6, truth.kt);
    assert!(kt.abs() < 3.0 && inertia.abs() < 5.0, "kt {kt} %, inertia {inertia} %, {result:?}");
}

/// The inertia doubles after the fourth half cycle (a load that couples in): the even relay cycles (half cycles
/// 0-1 and 4-5) see both inertias, the odd ones (2-3) the first alone; they disagree by more than a quarter of the
/// whole fit's inertia, and the step fails with `SampleMismatch`, IDX 0xFF15, instead of writing an inertia that
/// is neither.
#[test]
fn relay_cycles_that_disagree_on_the_inertia_fail_sample_mismatch_0xff15() {
    let mut plant = Plant::reference();
    let config = config(&plant, 3.2, 5000);
    let mut id = MechanicalIdentification::new(&config);
    let mut demand = 0.0;
    let mut doubled = false;
    let status = loop {
        let sample = plant.tick(demand);
        if id.half_cycles == 4 && !doubled {
            doubled = true;
            plant.j_motor *= 2.0;
            plant.j_load *= 2.0;
        }
        match id.step(&sample) {
            MechanicalStatus::Running { i_q_demand } => demand = f64::from(i_q_demand.to_bits()) / 65_536.0,
            other => break other,
        }
    };
    assert_eq!(status, MechanicalStatus::Failed(MechanicalError::SampleMismatch));
}

/// A bus that cannot take the braking energy (as in
/// [`relay_speed_falls_until_braking_keeps_the_bus_below_the_limiter`]): each lowered relay speed adapts the current again, so that the half cycles the fit takes stay near
/// [`HALF_CYCLE_TARGET_TICKS`] instead of shrinking with the speed (a speed lowered four times by 3/4 at the first
/// half cycles' current made them 188 ticks on the geared preset: a relay fundamental of 6.7 Hz, half its 14 Hz
/// anti-resonance, where the motor no longer moves with the load and the inertia came out 7 to 10 % low).
/// Bound: the clean half cycles at the end last at least 3/4 of the target (the adaptation's friction share and
/// its factor-2 steps leave them within about 10 % of it).
#[test]
fn a_lowered_relay_speed_keeps_the_half_cycle_near_its_target() {
    let mut plant = Plant { bus_capacitance: 470e-6, bus_now: 36.0, ..Plant::geared() };
    let config = config(&plant, 5.0, 2000);
    let mut id = MechanicalIdentification::new(&config);
    let mut demand = 0.0;
    let mut reversals = Vec::new();
    let mut lowered = 0;
    let mut half_cycles = 0;
    let mut relay_speed = id.relay_speed;
    loop {
        let sample = plant.tick(demand);
        let status = id.step(&sample);
        if id.half_cycles != half_cycles {
            half_cycles = id.half_cycles;
            reversals.push(id.relay_ticks);
        }
        if id.relay_speed != relay_speed {
            relay_speed = id.relay_speed;
            lowered += 1;
        }
        match status {
            MechanicalStatus::Running { i_q_demand } => demand = f64::from(i_q_demand.to_bits()) / 65_536.0,
            MechanicalStatus::Done(_) => break,
            other => panic!("{other:?}"),
        }
    }
    assert!(lowered >= 2, "the relay speed was lowered {lowered} times");
    let last: Vec<u32> = reversals.windows(2).map(|w| w[1] - w[0]).rev().take(4).collect();
    assert!(
        last.iter().all(|&t| t >= HALF_CYCLE_TARGET_TICKS * 3 / 4),
        "last half cycles {last:?} ticks, target {HALF_CYCLE_TARGET_TICKS}"
    );
}

/// The run-up from rest to the first reversal is a half cycle of driving alone (the motor accelerates the load
/// through the gear); the others brake for half of their time. Through a gear with losses the motor sees the load
/// inertia divided by the efficiency while it drives and multiplied by it while the load drives it back (geared
/// preset, 90 %: +10.4 % and -9.4 % of the total), and only a relay that brakes as long as it drives averages them
/// out; with the run-up in the fit the geared preset's inertia came out up to 11 % high. The run-up adds no
/// equation to the mechanical fits.
#[test]
fn the_run_up_from_rest_adds_nothing_to_the_mechanical_fit() {
    let mut plant = Plant::geared();
    let config = config(&plant, 5.0, 2000);
    let mut id = MechanicalIdentification::new(&config);
    let mut demand = 0.0;
    let mut relay_ticks_before_the_reversal = 0;
    while id.half_cycles == 0 {
        let sample = plant.tick(demand);
        match id.step(&sample) {
            MechanicalStatus::Running { i_q_demand } => demand = f64::from(i_q_demand.to_bits()) / 65_536.0,
            other => panic!("{other:?}"),
        }
        if id.half_cycles == 0 {
            relay_ticks_before_the_reversal = id.relay_ticks;
        }
    }
    assert!(
        relay_ticks_before_the_reversal > 8 * BLOCK_TICKS,
        "the run-up took {relay_ticks_before_the_reversal} relay ticks"
    );
    assert_eq!(id.mechanical, [Regression3::default(); 2], "equations of the run-up in the mechanical fit");
}

/// Friction split (module documentation): a fit whose viscous torque at the relay's mean speed is at most a
/// quarter of its Coulomb friction is kept as it is (the reference plant's: 2,957 uNm and 282 x 0.001 uNm/rpm at
/// a 1,400 rpm relay, 0.20 mNm at 700 rpm); a larger share, in either sign, becomes all Coulomb friction, the sum
/// at the mean speed (the geared preset's seed 4: 6,863 uNm + 182,614 x 116 / 1000 = 28,046 uNm, B 0; a negative
/// B likewise: 20,000 - 80,000 x 116 / 1000 = 10,720 uNm).
#[test]
fn a_viscous_share_the_relay_could_not_resolve_is_kept_as_coulomb_friction() {
    assert_eq!(split_friction(2_957, 282, 1_400), (2_957, 282));
    assert_eq!(split_friction(6_863, 182_614, 232), (28_046, 0));
    assert_eq!(split_friction(20_000, -80_000, 232), (10_720, 0));
    // At the limit: 4 x 5,000 uNm of viscous torque at 500 rpm (B = 10,000) against 20,000 uNm is kept, one more
    // uNm of it is not.
    assert_eq!(split_friction(20_000, 10_000, 1_000), (20_000, 10_000));
    assert_eq!(split_friction(20_000, 10_002, 1_000), (25_001, 0));
}
