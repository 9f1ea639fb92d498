//! The cyclic synchronous modes on the reference plant, driven through CiA 402 as a master drives them: CSP
//! following a jerk-limited move, CSV step and velocity-loop bandwidth, CST torque through the current loop.
//!
//! The figures come from `hal_sim::scenarios::motion`, the code `drive-sim csp` and `drive-sim csv-sweep` run. Gains are
//! the dictionary defaults (0x30A1, 0x30A2), tuned for the reference plant. Bounds are the motion issue's.

use firmware::cia402::State;
use firmware::od::generated::handles as h;
use hal_sim::scenarios::motion::{self, CspConfig};

/// CSP at a 1 ms master cycle (0x60C2 = 1 ms), 10 revolutions, sin² ramps up to 3,000 rpm and 20,000 rpm/s.
///
/// Bounds (issue): peak following error <= 30 inc, RMS <= 8 inc (4,096 inc/rev), position within +-1 inc of
/// the target 20 ms after the last set-point, statusword bit 13 never set. The following error is 0x60F4, the
/// drive's own demand minus actual, sampled every slow tick of the move. Measured: peak 2 to 3 inc, RMS about
/// 0.7 inc over seeds 1..8, so the bounds hold with a wide margin; the settling bound is the tight one (the
/// Coulomb friction of 3 mNm needs the integral to act), so it is checked on three seeds.
#[test]
fn csp_follows_a_jerk_limited_move() {
    for seed in [1, 3, 4] {
        let (f, _) = motion::csp(&CspConfig { seed, ..CspConfig::default() }).expect("scenario runs");
        assert!(f.following_error_peak_inc <= 30.0, "seed {seed}: {f:?}");
        assert!(f.following_error_rms_inc <= 8.0, "seed {seed}: {f:?}");
        assert!(f.settle_error_inc <= 1.0, "seed {seed}: {f:?}");
        assert!(f.settle_error_max_inc <= 1.0, "seed {seed}: stays settled {f:?}");
        assert!(!f.following_error_bit_seen, "seed {seed}: bit 13 {f:?}");
        assert!((f.peak_rpm - 2449.0).abs() < 1.0, "the move is the one the issue asks for: {f:?}");
    }
}

/// CSP at a 200 us master cycle without interpolation (the period is shorter than a slow tick, so each
/// set-point is applied at the next slow tick): the same move stays within the same bounds.
#[test]
fn csp_at_a_fast_cycle() {
    let cfg = CspConfig { cycle_periods: 5, ..CspConfig::default() };
    let (f, _) = motion::csp(&cfg).expect("scenario runs");
    assert!(f.following_error_peak_inc <= 30.0, "{f:?}");
    assert!(f.following_error_rms_inc <= 8.0, "{f:?}");
    assert!(f.settle_error_inc <= 1.0, "{f:?}");
}

/// CSV: a 100 rpm step settles within 2 % without more than 10 % overshoot (issue), with the loops' output applied
/// in the middle of the slow period as on the target. Measured (seed 1, default gains 0x30A2:01/02 = 0.25 A s/rad,
/// 5 A/rad): 6.0 % overshoot, settled in 7.8 ms, 0.003 % steady error.
#[test]
fn csv_small_step() {
    let (f, _) = motion::csv_step(1, 100.0).expect("scenario runs");
    assert!(f.overshoot_pct <= 10.0, "{f:?}");
    assert!(f.steady_error_pct <= 2.0, "{f:?}");
    assert!(f.settle_ms.is_finite() && f.settle_ms < 200.0, "settles within 2 %: {f:?}");
}

/// CSV: velocity-loop small-signal bandwidth >= 100 Hz from a sine sweep (issue). Measured 154 Hz (seed 1, default
/// gains): the -3 dB crossing lies between the 130 and 200 Hz points.
#[test]
fn csv_velocity_bandwidth() {
    let (points, bw) = motion::csv_sweep(1).expect("scenario runs");
    assert!(bw >= 100.0, "bandwidth {bw} Hz, points {points:?}");
    assert!(points.iter().all(|p| p.gain_db < 3.0), "no resonance peak above 3 dB: {points:?}");
}

/// CST: the target torque goes to the current loop every 40 us, so the torque demand follows 0x6071 + 0x60B2 at
/// once and the motor's current within the current-loop figures. Tolerance 2 % of the demand at 5 ms: the
/// loop's steady-state error bound is 1 % of the step, plus the plant's current ripple.
#[test]
fn cst_torque_follows_the_target() {
    let mut sim = motion::prepare_motion(1, 10).expect("enabled in CST");
    sim.plant.lock_rotor(true);
    sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 300);
    sim.drive.dictionary_mut().set(h::TORQUE_OFFSET, 50);
    // 1 ms: the 350 per mille (1.12 A of the 3.2 A rated current) is reached and averaged.
    // 5 ms: the current loop's step settles within 1 % of a 2 A step in a few hundred us, then the integral
    // removes the dead-time error within about 3 ms at this low current (measured on the locked rotor).
    sim.run(125);
    let iq = sim.plant.state().i_dq_a[1];
    let iref = f64::from(sim.tier1().signals().i_ref.q.to_milliamps()) / 1000.0;
    assert!((iref - 1.12).abs() < 0.002, "the reference is 350 per mille of 3.2 A at once: {iref} A");
    assert!((iq - 1.12).abs() < 0.0224, "i_q {iq} A for 350 per mille");
    sim.run_slow_ticks(10);
    assert_eq!(sim.drive.dictionary().get(h::TORQUE_DEMAND_VALUE), 350);
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
}

/// CST: a stop with the slow-down ramp («Disable operation» with 0x605C = 1, the default) takes the torque away
/// at the torque slope 0x6087 (the slow-down ramp of the CiA 402 torque modes), then switches to «Switched on»
/// (transition 5). From 350 per mille (1.12 A of the 3.2 A rated current, rotor locked):
/// - 0x6087 = 100,000 per mille/s (default): 40 per mille (128 mA) less per slow tick, 9 ticks;
/// - 0x6087 = 10,000 per mille/s: 4 per mille (12.8 mA) per tick, 88 ticks (350 / 4 = 87.5).
///
/// Checked on tier 1's q reference after each slow tick: it never rises, never falls by more than one step (plus
/// 1 mA of rounding), ends at 0, and the state changes only once it is 0. Tolerance on the tick counts: one tick
/// (the ramp's first step falls in the tick that takes the controlword). Measured: 9 and 88 ticks to a reference
/// of 0, «Switched on» one tick later.
#[test]
fn cst_slow_down_stop_ramps_the_torque_at_0x6087() {
    let ramp = |slope: u32| {
        let mut sim = motion::prepare_motion(1, 10).expect("enabled in CST");
        sim.plant.lock_rotor(true);
        sim.drive.dictionary_mut().set(h::TARGET_TORQUE, 350);
        sim.drive.dictionary_mut().set(h::TORQUE_SLOPE, slope);
        sim.run(125);
        let mut refs = vec![sim.tier1().signals().i_ref.q.to_milliamps()];
        sim.drive.dictionary_mut().set(h::CONTROLWORD, 0x0007);
        for _ in 0..500 {
            sim.run_slow_ticks(1);
            refs.push(sim.tier1().signals().i_ref.q.to_milliamps());
            if sim.cia402_state() == State::SwitchedOn {
                break;
            }
        }
        assert_eq!(sim.cia402_state(), State::SwitchedOn, "0x6087 = {slope}: the stop ends");
        refs
    };
    for (slope, step_ma, ticks) in [(100_000u32, 128, 9usize), (10_000, 13, 88)] {
        let refs = ramp(slope);
        assert!((refs[0] - 1120).abs() <= 2, "0x6087 = {slope}: starts at 350 per mille: {refs:?}");
        assert!(refs.windows(2).all(|w| w[1] <= w[0] && w[0] - w[1] <= step_ma + 1), "0x6087 = {slope}: {refs:?}");
        // Slow ticks from the controlword to a q reference of 0.
        let falling = refs.iter().position(|&r| r == 0).unwrap_or(usize::MAX);
        assert!(falling.abs_diff(ticks) <= 1, "0x6087 = {slope}: {falling} ticks, expected {ticks}: {refs:?}");
        assert_eq!(refs[refs.len() - 2], 0, "0x6087 = {slope}: the torque is gone before the state changes: {refs:?}");
        println!("0x6087 = {slope}: {falling} ticks of ramp, {} slow ticks to «Switched on»", refs.len() - 1);
    }
}

/// The velocity actual values beside 0x606C are real (issue 19, no silent objects): on a CSV step to 600 rpm,
/// 0x6069 "velocity sensor actual value" is the same estimate in increments per second (600 rpm = 40,960 inc/s
/// at 4,096 inc/rev), and 0x30D3:01 "velocity actual value averaged" is 0x606C through a 5 Hz first-order
/// low-pass: 32 ms after the step it has covered 1 - 1/e (63 %, within 10 % of the step: the actual speed itself
/// takes a few ms to rise), and after 300 ms (more than 9 time constants) it agrees with 0x606C within 2 rpm.
/// 0x6069 is published in the background step and 0x606C in the slow tick, one estimate apart, and the estimate
/// ripples by a few rpm from tick to tick (one count in a slow tick is 36 rpm before the filter): so the two are
/// compared as means over the last 100 slow ticks, within one rpm's worth (69 inc/s, for 0x606C's rounding to
/// whole rpm). Measured: 383 rpm at 32 ms; 600 rpm and a mean of 40,914 inc/s settled.
#[test]
fn velocity_sensor_and_averaged_velocity_are_the_estimate() {
    let mut sim = motion::prepare_motion(1, 9).expect("enabled in CSV");
    sim.drive.dictionary_mut().set(h::INTERPOLATION_TIME_PERIOD_VALUE, 0);
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 600);
    let mut average_at_32ms = 0;
    let (mut rpm_sum, mut inc_per_s_sum, mut n) = (0_i64, 0_i64, 0_i64);
    for period in 0..7_500u32 {
        if period % 10 == 0 {
            sim.setpoint_received();
        }
        sim.step();
        if period == 800 {
            average_at_32ms = sim.drive.dictionary().get(h::VELOCITY_ACTUAL_VALUE_AVERAGED);
        }
        if period >= 6_500 && period % 10 == 0 {
            let d = sim.drive.dictionary();
            rpm_sum += i64::from(d.get(h::VELOCITY_ACTUAL_VALUE));
            inc_per_s_sum += i64::from(d.get(h::VELOCITY_SENSOR_ACTUAL_VALUE));
            n += 1;
        }
    }
    let d = sim.drive.dictionary();
    let rpm = d.get(h::VELOCITY_ACTUAL_VALUE);
    let inc_per_s = inc_per_s_sum / n;
    assert!((rpm - 600).abs() <= 2, "0x606C {rpm}");
    assert!((inc_per_s - rpm_sum * 4096 / 60 / n).abs() <= 69, "0x6069 mean {inc_per_s} at {} rpm", rpm_sum / n);
    assert!((d.get(h::VELOCITY_ACTUAL_VALUE_AVERAGED) - rpm).abs() <= 2, "0x30D3:01 settled");
    assert!((average_at_32ms - 379).abs() <= 60, "0x30D3:01 after one time constant: {average_at_32ms} rpm");
    println!("0x30D3:01 at 32 ms: {average_at_32ms} rpm; settled: 0x606C {rpm} rpm, 0x6069 {inc_per_s} inc/s");
}

/// Issue 20 item 4: "CSP with a 0x60B2 feedforward from the master lowers the following error peak of the reference
/// CSP move by at least 30 %". The master computes J alpha + B omega + T_c sign(omega) of the move it sends from the
/// plant's inertia and friction, in per mille of 0x6076, and writes it into 0x60B2 with each 0x607A (0x60B1 stays
/// 0 in both runs: the drive derives the velocity feedforward from the set-points); it turns the drive's own,
/// three periods late, acceleration feedforward 0x30A1:05 off, which its feedforward replaces (IDX L977: the torque
/// offset is CSP's torque feedforward input). Measured on seeds 1..3: peak 3 -> 2 inc (-33 %), RMS 0.74 -> 0.61
/// inc; without the drive acting on 0x60B2 the same master setting gives a peak of 4 inc.
///
/// Tolerance: 0x60F4 counts whole increments and the peak is 2 to 3 of them, so a 30 % reduction means one
/// increment less than without: `peak_ff <= 0.7 x peak` admits no rounding in the feedforward's favour. Three
/// seeds (the plant's current noise) so that one lucky run cannot pass it; the RMS must fall too, and the
/// move's other bounds (settling within 1 inc, no bit 13) hold with the feedforward.
#[test]
fn csp_torque_feedforward_from_the_master_lowers_the_following_error_peak_by_30_percent() {
    for seed in [1, 2, 3] {
        let (base, _) = motion::csp(&CspConfig { seed, ..CspConfig::default() }).expect("scenario runs");
        let cfg = CspConfig { seed, torque_feedforward: true, ..CspConfig::default() };
        let (ff, _) = motion::csp(&cfg).expect("scenario runs");
        println!(
            "seed {seed}: peak {} -> {} inc, rms {:.2} -> {:.2} inc",
            base.following_error_peak_inc,
            ff.following_error_peak_inc,
            base.following_error_rms_inc,
            ff.following_error_rms_inc
        );
        assert!(
            ff.following_error_peak_inc <= 0.7 * base.following_error_peak_inc,
            "seed {seed}: peak {} with the feedforward, {} without",
            ff.following_error_peak_inc,
            base.following_error_peak_inc
        );
        assert!(ff.following_error_rms_inc < base.following_error_rms_inc, "seed {seed}: {ff:?} against {base:?}");
        assert!(ff.settle_error_inc <= 1.0 && ff.settle_error_max_inc <= 1.0, "seed {seed}: {ff:?}");
        assert!(!ff.following_error_bit_seen, "seed {seed}: {ff:?}");
    }
}

/// CSV set-points of 0 rpm every 1 ms (0x60C2 = 1 ms) on the locked rotor, `n` master cycles.
fn csv_cycles(sim: &mut hal_sim::sim::Simulation, n: usize) {
    for _ in 0..n {
        sim.setpoint_received();
        sim.run(25);
    }
}

/// The q reference tier 1 follows (the loops' demand), I16F16 bits.
/// CSV enabled on the locked rotor, holding 0 rpm at a 1 ms interpolation period (0x6072 = `max_torque` when
/// given), settled for 20 cycles: the hold in which a torque offset shows alone in the q reference.
fn locked_csv_hold(max_torque: Option<u16>) -> hal_sim::sim::Simulation {
    let mut sim = motion::prepare_motion(1, 9).expect("enabled in CSV");
    sim.plant.lock_rotor(true);
    let d = sim.drive.dictionary_mut();
    d.set(h::INTERPOLATION_TIME_PERIOD_VALUE, 1);
    d.set(h::INTERPOLATION_TIME_INDEX, -3);
    d.set(h::TARGET_VELOCITY, 0);
    if let Some(max) = max_torque {
        d.set(h::MAX_TORQUE, max);
    }
    csv_cycles(&mut sim, 20);
    sim
}

fn q_reference_bits(sim: &hal_sim::sim::Simulation) -> i32 {
    sim.tier1().signals().i_ref.q.to_bits()
}

/// CSV (Gamma L1720, EPOS3 L7733; IDX L1016 leaves it out, device.toml's note): 0x60B2 adds torque to the
/// velocity loop's demand. On the locked rotor holding 0 rpm the velocity error is 0, so the integral does not
/// move and the q reference changes by exactly the offset's conversion through the demand scale (200 per mille of
/// the 3.2 A rated current = 640 mA; -150 per mille = -480 mA), the scale's rounding included (compared in
/// I16F16 bits), and comes back when the offset is 0 again.
#[test]
fn csv_torque_offset_adds_its_conversion_to_the_q_reference_at_standstill() {
    use firmware::control::demand::DemandScale;
    let mut sim = locked_csv_hold(None);
    let before = q_reference_bits(&sim);
    let scale = DemandScale::reference();
    for offset in [200i16, -150] {
        sim.drive.dictionary_mut().set(h::TORQUE_OFFSET, offset);
        csv_cycles(&mut sim, 5);
        let expected = scale.torque_to_current(offset, 0).1.to_bits();
        assert_eq!(q_reference_bits(&sim) - before, expected, "0x60B2 = {offset}");
    }
    assert_eq!(scale.torque_to_current(200, 0).1.to_milliamps(), 640);
    sim.drive.dictionary_mut().set(h::TORQUE_OFFSET, 0);
    csv_cycles(&mut sim, 5);
    assert_eq!(q_reference_bits(&sim), before, "the offset gone, the demand is the loop's alone again");
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
}

/// The feedforward is limited as CST's torque is: with 0x6072 = 100 per mille an offset of +-500 per mille adds
/// +-320 mA (100 per mille of 3.2 A), not +-1.6 A. Same locked-rotor hold as above, exact in I16F16 bits.
#[test]
fn csv_torque_offset_is_limited_by_0x6072() {
    use firmware::control::demand::DemandScale;
    let mut sim = locked_csv_hold(Some(100));
    let before = q_reference_bits(&sim);
    let capped = DemandScale::from_od(3200, 10_000, 3125, 100).torque_to_current(100, 0).1;
    assert_eq!(capped.to_milliamps(), 320);
    for (offset, sign) in [(500i16, 1), (-500, -1)] {
        sim.drive.dictionary_mut().set(h::TORQUE_OFFSET, offset);
        csv_cycles(&mut sim, 5);
        assert_eq!(q_reference_bits(&sim) - before, sign * capped.to_bits(), "0x60B2 = {offset}, 0x6072 = 100");
    }
}
