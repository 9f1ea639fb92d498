//! `drive-sim`: runs the firmware's drive against the simulated reference plant and reports what it measured.
//!
//! `drive-sim --help` lists the scenarios and `drive-sim SCENARIO --help` their options (drive-sim/cli.rs);
//! `drive-sim completions SHELL` prints a completion script.
//!
//! Every scenario command (the `ethercat` and `canopen` servers too) takes `--plant FILE`: a plant file
//! (`hal_sim::plant::file`, presets in `hal-sim/presets/`) instead of the reference plant. The drive is configured
//! for it from its ratings (`Simulation::commission_motor_data`: 0x3001 motor data, 0x3010:01 encoder lines,
//! 0x6073, 0x6080, 0x607F), and the scenario's numbers scale with the plant's ratings against the reference
//! (`scenarios::PlantScale`; `drive-sim --help` says how). The gains stay the reference-tuned defaults unless
//! `--auto-tune`.
//!
//! Each scenario prints a human-readable report, the paths of the CSV traces and SVG plots it wrote (under
//! `out/<scenario>/` of the current directory unless `--out` says otherwise), and as its last lines one
//! `key=value` per figure (the stable measurement interface). The long runs show a progress bar on stderr when it
//! is a terminal (drive-sim/progress.rs).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[path = "drive-sim/canopen.rs"]
mod canopen;
#[path = "drive-sim/cli.rs"]
mod cli;
#[path = "drive-sim/progress.rs"]
mod progress;

use clap::{CommandFactory, FromArgMatches};
use cli::{
    Cli, Command, CspScenario, CurrentLoopScenario, DualLoopScenario, EthercatArgs, FaultMatrixScenario, IdentifyArgs,
    Scenario, SsiArgs,
};
use progress::Progress;

use hal_sim::esc::pcap::PcapWriter;
use hal_sim::esc::socket::Direction;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::motion::{self, CspConfig};
use hal_sim::scenarios::profile::{self, Profile};
use hal_sim::scenarios::regeneration::{self, ChopperRating};
use hal_sim::scenarios::{self, PlantScale, Setup, SpinConfig, SpinStepFigures, SWEEP_FREQUENCIES_HZ};
use hal_sim::scenarios::{duty_cycle, faults, homing};
use hal_sim::sim::ethercat::{ClockMode, EthercatConfig, EthercatRunner};
use hal_sim::sim::ethercat_line::EthercatLine;
use hal_sim::sim::plot::{Plot, Series};
use hal_sim::sim::trace::Trace;

fn setup(args: &CurrentLoopScenario) -> Setup {
    Setup { seed: args.scenario.common.seed, gains: args.gains(), ..Setup::default() }
}

fn gains_text(s: &Setup) -> String {
    match s.gains {
        Some((p, i)) => format!("0x30A0 set at run time: P {p} uV/A, I {i} uV/(A ms)"),
        None => "0x30A0 dictionary defaults: P 1555000 uV/A, I 2450000 uV/(A ms)".to_owned(),
    }
}

fn write(trace: &Trace, plot: &Plot, dir: &Path, name: &str) -> Result<(), String> {
    let csv = dir.join(format!("{name}.csv"));
    let svg = dir.join(format!("{name}.svg"));
    trace.write_csv(&csv).map_err(|e| format!("{}: {e}", csv.display()))?;
    plot.write_svg(&svg).map_err(|e| format!("{}: {e}", svg.display()))?;
    println!("  wrote {} and {}", csv.display(), svg.display());
    Ok(())
}

fn time_plot(trace: &Trace, title: &str, signals: &[(&str, &str)], y_label: &str) -> Plot {
    let t_ms: Vec<f64> = trace.column("t_us").unwrap_or_default().iter().map(|t| t / 1000.0).collect();
    let mut plot = Plot::new(title, "time [ms]", y_label);
    for (col, name) in signals {
        plot.series.push(Series::new(name, &t_ms, &trace.column(col).unwrap_or_default()));
    }
    plot
}

fn current_step(args: &CurrentLoopScenario, dir: &Path) -> Result<(), String> {
    let s = setup(args);
    println!("current-step: plant (seed {}), shunt offsets {:?} LSB, {}", s.seed, s.offsets_lsb, gains_text(&s));
    let step = scenarios::current_step(&s, 2.0 * PlantScale::current_plant().current).map_err(|e| e.to_string())?;
    let p = step.prepared;
    println!(
        "\nOffset calibration (CiA 402 transition 3, {} ticks = {:.1} ms):",
        p.calibration_ticks,
        p.calibration_ticks as f64 * 0.04
    );
    for ch in 0..3 {
        println!(
            "  phase {}: true {:+.1} LSB, estimated {:+.3} LSB",
            ["A", "B", "C"][ch],
            s.offsets_lsb[ch],
            p.offsets_estimated_lsb[ch]
        );
    }
    println!("  largest residual {:.3} LSB (bound 2 LSB)", p.offset_residual_lsb);
    println!(
        "Commutation after commissioning (Hall start, Hall edge, index): angle error {:+.3} deg electrical",
        p.angle_error_deg
    );
    let f = step.figures;
    println!("\nq-current step 0 -> {:.1} A, rotor locked (plant's true currents at the sample instants):", f.step_a);
    println!("  rise time 10-90 %   {:7.1} us   (bound <= 200 us)", f.rise_us);
    println!("  overshoot           {:7.2} %    (bound <= 10 %)", f.overshoot_pct);
    println!("  steady-state error  {:7.3} %    (bound < 1 % of the step)", f.steady_error_pct);
    println!("  d-axis excursion    {:7.2} %    (bound <= 3 % of the step)", f.d_excursion_pct);
    println!("  settling to +-2 %   {:7.1} us", f.settle_us);
    let plot = time_plot(
        &step.trace,
        "q-current step 0 -> 2 A, locked rotor",
        &[
            ("iq_ref_a", "i_q reference"),
            ("iq_a", "i_q (plant)"),
            ("id_a", "i_d (plant)"),
            ("iq_measured_a", "i_q (drive)"),
        ],
        "current [A]",
    );
    write(&step.trace, &plot, dir, "step")?;

    let sc = PlantScale::current_plant();
    let sweep = scenarios::bandwidth(&s, 2.0 * sc.current, 1.0 * sc.current, &SWEEP_FREQUENCIES_HZ)
        .map_err(|e| e.to_string())?;
    println!(
        "\nClosed-loop frequency response, q reference {:.2} A + {:.2} A sine (no zero crossing), rotor locked:",
        2.0 * sc.current,
        1.0 * sc.current
    );
    println!("  {:>8}  {:>8}  {:>9}", "f [Hz]", "gain[dB]", "phase[deg]");
    for pt in &sweep.points {
        println!("  {:8.0}  {:8.2}  {:9.1}", pt.freq_hz, pt.gain_db(), pt.phase_deg);
    }
    println!("  -3 dB bandwidth {:.0} Hz (bound >= 2000 Hz), peak {:+.2} dB", sweep.bandwidth_hz, sweep.peak_db);
    let st = scenarios::sweep_trace(&sweep);
    let mut bode = Plot::new("Closed-loop current response (locked rotor)", "frequency [Hz]", "gain [dB]");
    bode.log_x = true;
    bode.series.push(
        Series::new(
            "|I_q / I_ref|",
            &st.column("freq_hz").unwrap_or_default(),
            &st.column("gain_db").unwrap_or_default(),
        )
        .with_markers(),
    );
    bode.h_lines.push((-3.0103, "-3 dB".into()));
    write(&st, &bode, dir, "sweep")?;

    println!();
    println!("rise_us={:.1}", f.rise_us);
    println!("overshoot_pct={:.2}", f.overshoot_pct);
    println!("steady_error_pct={:.3}", f.steady_error_pct);
    println!("bandwidth_hz={:.0}", sweep.bandwidth_hz);
    println!("offset_residual_lsb={:.3}", p.offset_residual_lsb);
    Ok(())
}

fn print_spin(name: &str, f: &SpinStepFigures) {
    println!("  {name}: {:+.1} A at {:.0} rpm", f.step_a, f.speed_rpm);
    println!("    voltage limit active  {:7.0} us", f.saturated_us);
    println!("    recovery after limit  {:7.0} us   (bound <= 1000 us)", f.recovery_us);
    println!("    settling into +-5 %   {:7.0} us", f.settle_us);
    println!("    overshoot             {:7.2} %", f.overshoot_pct);
    println!("    tracking error after  {:7.2} %", f.tracking_error_pct);
    println!("    |i_d| peak            {:7.3} A", f.d_peak_a);
}

fn spinning(args: &CurrentLoopScenario, dir: &Path) -> Result<(), String> {
    let s = setup(args);
    let sc = PlantScale::current_plant();
    let d = SpinConfig::default();
    let cfg = SpinConfig {
        speed_rpm: d.speed_rpm * sc.speed,
        base_a: d.base_a * sc.current,
        high_a: d.high_a * sc.current,
        load_nm: d.load_nm * sc.torque,
        ..d
    };
    println!(
        "spinning: plant (seed {}), free shaft at {:.0} rpm, q current {:.1} A -> {:.1} A with a {:.2} N m load step, back after {:.0} ms; {}",
        s.seed, cfg.speed_rpm, cfg.base_a, cfg.high_a, cfg.load_nm, cfg.phase_ms, gains_text(&s)
    );
    let r = scenarios::spinning(&s, &cfg).map_err(|e| e.to_string())?;
    print_spin("step up with load", &r.up);
    print_spin("step down, load removed", &r.down);
    let plot = time_plot(
        &r.trace,
        "3000 rpm: q-current step with load step",
        &[
            ("iq_ref_a", "i_q reference"),
            ("iq_a", "i_q (plant)"),
            ("id_a", "i_d (plant)"),
            ("vq_v", "v_q [V]"),
            ("vd_v", "v_d [V]"),
        ],
        "current [A] / voltage [V]",
    );
    write(&r.trace, &plot, dir, "spinning")?;
    println!();
    println!("spin_speed_rpm={:.0}", r.up.speed_rpm);
    println!("spin_saturated_us={:.0}", r.up.saturated_us);
    println!("spin_recovery_us={:.0}", r.up.recovery_us.max(r.down.recovery_us));
    println!("spin_settle_us={:.0}", r.up.settle_us.max(r.down.settle_us));
    println!("spin_overshoot_pct={:.2}", r.up.overshoot_pct.max(r.down.overshoot_pct));
    println!("spin_tracking_error_pct={:.2}", r.up.tracking_error_pct.max(r.down.tracking_error_pct));
    Ok(())
}

/// A plot of `signals` over the trace's `t_s` column, in ms.
fn seconds_plot(trace: &Trace, title: &str, signals: &[(&str, &str)], y_label: &str) -> Plot {
    let t_ms: Vec<f64> = trace.column("t_s").unwrap_or_default().iter().map(|t| t * 1000.0).collect();
    let mut plot = Plot::new(title, "time [ms]", y_label);
    for (col, name) in signals {
        plot.series.push(Series::new(name, &t_ms, &trace.column(col).unwrap_or_default()));
    }
    plot
}

fn csp(args: &CspScenario, dir: &Path) -> Result<(), String> {
    let cfg = CspConfig {
        position_gains: args.position_gains,
        torque_feedforward: args.torque_feedforward,
        ..CspConfig::scaled_to_current_plant(args.scenario.common.seed)
    };
    println!(
        "csp: plant (seed {}), CiA 402 CSP, set-points every {:.1} ms (0x60C2 the same), {} revolutions, \
         jerk-limited (sin² ramps) up to {:.0} rpm and {:.0} rpm/s",
        cfg.seed,
        cfg.cycle_periods as f64 * 0.04,
        cfg.revolutions,
        cfg.max_rpm,
        cfg.peak_rpm_per_s
    );
    if cfg.torque_feedforward {
        println!("  the master sends J alpha + friction in 0x60B2 each cycle (0x60B1 = 0), 0x30A1:05 = :06 = 0");
    }
    let (f, trace) = motion::csp(&cfg).map_err(|e| e.to_string())?;
    println!("  move: {:.3} s, peak {:.0} rpm", f.move_s, f.peak_rpm);
    println!("  following error 0x60F4 peak {:6.1} inc   (bound <= 30)", f.following_error_peak_inc);
    println!("  following error 0x60F4 rms  {:6.2} inc   (bound <= 8)", f.following_error_rms_inc);
    println!("  |position - target| 20 ms after the last set-point {:.0} inc (bound <= 1)", f.settle_error_inc);
    println!("  |position - target| from then to the end            {:.0} inc", f.settle_error_max_inc);
    println!("  statusword bit 13 (following error) seen: {}", f.following_error_bit_seen);
    let plot = seconds_plot(
        &trace,
        "CSP: 10 revolutions, jerk-limited, 1 ms set-points",
        &[("following_error_inc", "following error [inc]"), ("rpm", "velocity [rpm / 100]")],
        "increments",
    );
    let mut plot = plot;
    if let Some(s) = plot.series.get_mut(1) {
        for p in &mut s.points {
            p.1 /= 100.0;
        }
    }
    write(&trace, &plot, dir, "csp")?;
    println!();
    println!("following_error_peak_inc={:.1}", f.following_error_peak_inc);
    println!("following_error_rms_inc={:.2}", f.following_error_rms_inc);
    println!("settle_error_inc={:.0}", f.settle_error_inc);
    Ok(())
}

fn dual_loop(args: &DualLoopScenario, dir: &Path) -> Result<(), String> {
    use hal_sim::scenarios::dual_loop::{self as dual, DualLoopConfig};
    let cfg = DualLoopConfig {
        seed: args.scenario.common.seed,
        dual_loop: !args.motor_encoder_only,
        main_loop_gains: args.main_loop_gains,
        ..DualLoopConfig::default()
    };
    let closed_by = if cfg.dual_loop {
        "the load encoder (dual loop: 0x3000:01 = 0x00040201, 0x3000:02 = 0x04021111, main loop 0x30AE)"
    } else {
        "the motor encoder alone (PID 0x30A1; the load encoder only measured)"
    };
    println!(
        "dual-loop: plant (seed {}), CiA 402 CSP, a {:.0} deg move of the load, set-points every {:.1} ms, up to \
         {:.0} rpm and {:.0} rpm/s at the motor, held {:.1} s; position loop closed by {closed_by}",
        cfg.seed,
        cfg.load_degrees,
        cfg.cycle_periods as f64 * 0.04,
        cfg.max_rpm,
        cfg.peak_rpm_per_s,
        cfg.hold_s,
    );
    let (f, trace) = dual::dual_loop(scenarios::scenario_plant(), &cfg).map_err(|e| e.to_string())?;
    println!("  move: {:.3} s; the gear's backlash is {:.1} load increments", f.move_s, f.backlash_inc);
    println!("  load following error peak during the move   {:7.1} load inc", f.load_following_error_peak_inc);
    println!(
        "  |load target - load| over the last {:.0} ms      {:7.1} load inc",
        dual::SETTLE_WINDOW_S * 1000.0,
        f.load_settle_error_inc
    );
    match f.load_settle_time_s {
        Some(t) => {
            println!("  within +-{:.0} load inc from                   {t:7.3} s after the move", dual::SETTLE_BAND_INC)
        }
        None => println!(
            "  within +-{:.0} load inc                          not at the end of the hold",
            dual::SETTLE_BAND_INC
        ),
    }
    println!("  |motor / gear - load| peak                   {:7.3} deg at the load", f.motor_load_deviation_peak_deg);
    println!(
        "  the drive's 0x60F4 peak during the move       {:7.1} inc (the master's units)",
        f.drive_following_error_peak_inc
    );
    let mut plot = seconds_plot(
        &trace,
        if cfg.dual_loop { "Dual loop: CSP move of the load" } else { "Motor encoder alone: CSP move of the load" },
        &[
            ("load_following_error_inc", "load following error [load inc]"),
            ("motor_load_deviation_deg", "motor / gear - load [0.01 deg]"),
        ],
        "load increments",
    );
    if let Some(s) = plot.series.get_mut(1) {
        for p in &mut s.points {
            p.1 *= 100.0;
        }
    }
    write(&trace, &plot, dir, "dual-loop")?;
    println!();
    println!("load_following_error_peak_inc={:.1}", f.load_following_error_peak_inc);
    println!("load_settle_error_inc={:.1}", f.load_settle_error_inc);
    println!("motor_load_deviation_peak_deg={:.3}", f.motor_load_deviation_peak_deg);
    match f.load_settle_time_s {
        Some(t) => println!("load_settle_time_s={t:.3}"),
        None => println!("load_settle_time_s=none"),
    }
    Ok(())
}

fn csv_sweep(seed: u64, dir: &Path) -> Result<(), String> {
    println!("csv-sweep: plant (seed {seed}), CiA 402 CSV");
    let (step, trace) = motion::csv_step(seed, motion::csv_step_rpm()).map_err(|e| e.to_string())?;
    println!("  velocity step 0 -> {:.0} rpm (plant's true speed):", step.step_rpm);
    println!("    overshoot          {:6.2} %   (bound <= 10 %)", step.overshoot_pct);
    println!("    settling to +-2 %  {:6.1} ms", step.settle_ms);
    println!("    steady error       {:6.2} %   (bound <= 2 %)", step.steady_error_pct);
    let plot = seconds_plot(
        &trace,
        &format!("CSV: velocity step 0 -> {:.0} rpm", step.step_rpm),
        &[("target_rpm", "target"), ("speed_rpm", "speed")],
        "rpm",
    );
    write(&trace, &plot, dir, "csv_step")?;
    let (points, bw) = motion::csv_sweep(seed).map_err(|e| e.to_string())?;
    let (offset_rpm, amplitude_rpm) = motion::csv_sweep_rpm();
    println!("  velocity-loop response, {offset_rpm:.0} rpm +- {amplitude_rpm:.0} rpm sine (speed / velocity demand):");
    println!("  {:>8}  {:>8}  {:>9}", "f [Hz]", "gain[dB]", "phase[deg]");
    let mut t = Trace::new(&["freq_hz", "gain_db", "phase_deg"]);
    for p in &points {
        println!("  {:8.0}  {:8.2}  {:9.1}", p.hz, p.gain_db, p.phase_deg);
        t.push(&[p.hz, p.gain_db, p.phase_deg]);
    }
    println!("  -3 dB bandwidth {bw:.0} Hz (bound >= 100 Hz)");
    let mut bode = Plot::new("Velocity loop response (CSV)", "frequency [Hz]", "gain [dB]");
    bode.log_x = true;
    bode.series.push(
        Series::new(
            "|speed / demand|",
            &t.column("freq_hz").unwrap_or_default(),
            &t.column("gain_db").unwrap_or_default(),
        )
        .with_markers(),
    );
    bode.h_lines.push((-3.0103, "-3 dB".into()));
    write(&t, &bode, dir, "csv_sweep")?;
    println!();
    println!("csv_step_overshoot_pct={:.2}", step.overshoot_pct);
    println!("csv_step_steady_error_pct={:.2}", step.steady_error_pct);
    println!("velocity_bandwidth_hz={bw:.0}");
    Ok(())
}

/// The fast PPM case's distance: 40 revolutions of the reference encoder, enough to reach 5,000 rpm with either
/// profile type (sin²: 20.8 revolutions to accelerate at 20,000 rpm/s, 13.9 to brake at 30,000 rpm/s).
const FAST_DISTANCE_INC: i32 = 40 * 4096;

/// The quick stop's deceleration in `drive-sim ppm`: 0x6085 = 150,000 rpm/s, a 33 ms stop from 5,000 rpm at 8.2 A,
/// whose braking power (up to 145 W on the reference load) is far more than the motor's losses absorb (about 40 W
/// at the 10 A limit): the limiter alone must stretch it, a chopper need not.
const QUICK_STOP_RPM_PER_S: u32 = 150_000;

fn print_quick_stop(name: &str, f: &regeneration::QuickStopFigures) {
    println!(
        "    {name}: from {:.0} rpm, stopped in {:.1} ms (ramp {:.1} ms), bus {:.2} -> peak {:.2} V, chopper {:.3} J, \
         loss braking {}, regenerative current reduced {}, winding +{:.2} K, then {:?}",
        f.from_rpm,
        f.stop_ms,
        f.ramp_ms,
        f.bus_before_v,
        f.bus_peak_v,
        f.chopper_energy_j,
        f.loss_braking_seen,
        f.regen_reduced_seen,
        f.winding_rise_k,
        f.final_state
    );
}

fn ppm(seed: u64, dir: &Path) -> Result<(), String> {
    let sc = PlantScale::current_plant();
    let stop_rpm = (5000.0 * sc.speed).round() as i32;
    let stop_rpm_per_s = (f64::from(QUICK_STOP_RPM_PER_S) * sc.speed).round() as u32;
    println!("ppm: plant (seed {seed}), CiA 402 PPM, absolute moves from rest, position window 0x6067 = 10 inc");
    let mut worst = i64::MIN;
    let mut bus_peak = 0.0_f64;
    for (name, profile_type, distance, p) in [
        ("trapezoidal, 5 rev, 1000 rpm, 10000 rpm/s", 0_i16, 20_480, Profile::DEFAULT),
        ("sin², 5 rev, 1000 rpm, 10000 rpm/s", 1, 20_480, Profile::DEFAULT),
        ("trapezoidal, 40 rev, 5000 rpm, 20000/30000 rpm/s", 0, FAST_DISTANCE_INC, Profile::FAST),
        ("sin², 40 rev, 5000 rpm, 20000/30000 rpm/s", 1, FAST_DISTANCE_INC, Profile::FAST),
    ] {
        let scaled = |x: u32| (f64::from(x) * sc.speed).round() as u32;
        let p = Profile {
            velocity_rpm: scaled(p.velocity_rpm),
            acceleration_rpm_per_s: scaled(p.acceleration_rpm_per_s),
            deceleration_rpm_per_s: scaled(p.deceleration_rpm_per_s),
        };
        let (f, trace) = profile::ppm_move(seed, profile_type, (f64::from(distance) * sc.speed).round() as i32, &p)
            .map_err(|e| e.to_string())?;
        println!("  {name}:");
        println!(
            "    profile {} ticks; bit 10 {} tick(s) after the profile's end (bound <= 2); final error {} inc; peak \
             following error {} inc; peak speed {:.0} rpm; bus peak {:.2} V",
            f.analytic_ticks,
            f.target_reached_delay_ticks,
            f.final_error_inc,
            f.following_error_peak_inc,
            f.peak_speed_rpm,
            f.bus_peak_v
        );
        bus_peak = bus_peak.max(f.bus_peak_v);
        worst = worst.max(f.target_reached_delay_ticks);
        if profile_type == 1 && distance == FAST_DISTANCE_INC {
            let plot = seconds_plot(
                &trace,
                "PPM: sin² move, 10 revolutions",
                &[("following_error_inc", "following error [inc]")],
                "increments",
            );
            write(&trace, &plot, dir, "ppm")?;
        }
    }
    println!();
    println!(
        "  quick stop from {stop_rpm} rpm (PVM, 0x605A = 6, 0x6085 = {stop_rpm_per_s} rpm/s: a {:.0} ms ramp), trip at \
         56 V:",
        f64::from(stop_rpm) / f64::from(stop_rpm_per_s) * 1000.0
    );
    let (limiter, trace) =
        regeneration::quick_stop(seed, scenarios::scenario_plant(), None, true, stop_rpm, stop_rpm_per_s)
            .map_err(|e| format!("quick stop, limiter alone: {e}"))?;
    print_quick_stop("limiter alone (no chopper)", &limiter);
    write(
        &trace,
        &seconds_plot(&trace, &format!("Quick stop from {stop_rpm} rpm, limiter alone"), &[("bus_v", "bus [V]")], "V"),
        dir,
        "quick_stop",
    )?;
    let (chopper, trace) = regeneration::quick_stop(
        seed,
        scenarios::scenario_plant().with_chopper(),
        Some(ChopperRating::REFERENCE),
        true,
        stop_rpm,
        stop_rpm_per_s,
    )
    .map_err(|e| format!("quick stop with the chopper: {e}"))?;
    print_quick_stop("with a braking chopper (10 ohm, 50 W, 10 s) and the limiter", &chopper);
    write(
        &trace,
        &seconds_plot(
            &trace,
            &format!("Quick stop from {stop_rpm} rpm, chopper and limiter"),
            &[("bus_v", "bus [V]")],
            "V",
        ),
        dir,
        "quick_stop_chopper",
    )?;
    bus_peak = bus_peak.max(limiter.bus_peak_v);
    println!();
    println!("target_reached_delay_ticks={worst}");
    println!("bus_peak_v={bus_peak:.2}");
    println!("quick_stop_bus_peak_v={:.2}", limiter.bus_peak_v);
    println!("quick_stop_ms={:.1}", limiter.stop_ms);
    println!("quick_stop_chopper_bus_peak_v={:.2}", chopper.bus_peak_v);
    println!("quick_stop_chopper_ms={:.1}", chopper.stop_ms);
    println!("chopper_energy_j={:.3}", chopper.chopper_energy_j);
    Ok(())
}

fn homing_matrix(seed: u64, dir: &Path) -> Result<(), String> {
    let cfg = homing::HomingConfig::new(seed, 1, homing::Start::Below);
    println!(
        "homing: plant (seed {}), CiA 402 HMM, every method of 0x60E3 from each side of its reference \
         (switch search {} rpm, zero search {} rpm, 0x609A {} rpm/s, distances x{:.3} of the reference's counts)",
        seed, cfg.switch_search_rpm, cfg.zero_search_rpm, cfg.acceleration_rpm_s, cfg.distance_scale
    );
    let mut bar = Progress::on_terminal("homing");
    let m = homing::homing_matrix_with_progress(seed, &mut |done, total| bar.update(done, total));
    bar.finish();
    let m = m.map_err(|e| e.to_string())?;
    println!("  {:>6}  {:<10}  {:>9}  {:>9}  {:>10}", "method", "start", "outcome", "error", "homing [s]");
    let mut t = Trace::new(&["method", "home_error_inc", "position_error_inc", "homing_s"]);
    for r in &m.rows {
        println!(
            "  {:>6}  {:<10}  {:>9}  {:>+9}  {:>10.3}",
            r.method,
            format!("{:?}", r.start),
            if r.passed() { "ok" } else { "FAILED" },
            r.home_error_inc,
            r.homing_s
        );
        t.push(&[f64::from(r.method), r.home_error_inc as f64, r.position_error_inc as f64, r.homing_s]);
    }
    let csv = dir.join("homing.csv");
    t.write_csv(&csv).map_err(|e| format!("{}: {e}", csv.display()))?;
    println!("  wrote {}", csv.display());
    println!();
    println!("methods_tested={}", m.methods_tested);
    println!("methods_passed={}", m.methods_passed);
    println!("home_error_max_inc={}", m.home_error_max_inc);
    Ok(())
}

fn fault_matrix(args: &FaultMatrixScenario, dir: &Path) -> Result<(), String> {
    let seed = args.scenario.common.seed;
    println!(
        "fault-matrix: plant (seed {seed}), every fault of the table injected where it matters; detection, \
         0x603F/0x1001/0x1003/EMCY, the reaction and the reset checked"
    );
    // `--only TEXT`: the cases whose fault name or injection contains TEXT (one failure on its own).
    let cases: Vec<_> = faults::cases()
        .into_iter()
        .filter(|c| {
            args.only.as_ref().is_none_or(|only| {
                c.fault.info().name.to_lowercase().contains(only) || c.injection.to_lowercase().contains(only)
            })
        })
        .collect();
    let mut bar = Progress::on_terminal("fault-matrix");
    let total = cases.len() as u64;
    bar.update(0, total);
    let mut outcomes = Vec::with_capacity(cases.len());
    for (done, case) in (1..).zip(&cases) {
        outcomes.push(faults::run_case(case, seed));
        bar.update(done, total);
    }
    bar.finish();
    let table = faults::matrix_table(&outcomes);
    print!("{table}");
    let path = dir.join("fault-matrix.md");
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    std::fs::write(&path, &table).map_err(|e| format!("{}: {e}", path.display()))?;
    println!("  wrote {}", path.display());
    let immediate = outcomes
        .iter()
        .filter(|o| o.reaction == firmware::fault::ReactionClass::DisablePowerImmediately)
        .filter_map(|o| o.off_after_detect_periods)
        .max()
        .unwrap_or(0);
    println!();
    println!("faults_tested={}", outcomes.len());
    println!("faults_passed={}", outcomes.iter().filter(|o| o.passed()).count());
    println!("immediate_off_latency_ticks_max={immediate}");
    Ok(())
}

fn duty_cycle(seed: u64, dir: &Path) -> Result<(), String> {
    println!(
        "duty-cycle: plant (seed {}), {} s of CSV velocity steps at the current limit with regeneration and load \
         steps, reference sensor noise",
        seed,
        duty_cycle::DURATION_S
    );
    let mut bar = Progress::on_terminal("duty-cycle");
    let run = duty_cycle::duty_cycle_with_progress(seed, &mut |done, total| bar.update(done, total));
    bar.finish();
    let (figures, trace) = run.map_err(|e| e.to_string())?;
    println!(
        "  moves {}, peak |iq| {:.2} A, bus {:.1}..{:.1} V, peak speed {:.0} rpm",
        figures.moves, figures.peak_current_a, figures.bus_min_v, figures.bus_max_v, figures.peak_speed_rpm
    );
    for event in &figures.events {
        println!("  {event}");
    }
    let csv = dir.join("duty-cycle.csv");
    trace.write_csv(&csv).map_err(|e| format!("{}: {e}", csv.display()))?;
    println!("  wrote {}", csv.display());
    println!();
    println!("false_trips={}", figures.false_trips);
    println!("warnings={}", figures.warnings);
    Ok(())
}

/// `drive-sim ssi`: the SSI absolute encoder as the only sensor (`hal_sim::scenarios::ssi`).
fn ssi(args: &SsiArgs) -> Result<(), String> {
    use hal_sim::scenarios::ssi;
    let seed = args.common.seed;
    let params = args.common.plant.as_ref().map_or_else(ssi::reference_ssi_plant, |f| f.params.clone());
    if params.ssi_single_turn_bits == 0 {
        return Err(
            "ssi: the plant has no SSI sensor (ssi_single_turn_bits = 0; see hal-sim/presets/reference-ssi.toml)"
                .into(),
        );
    }
    if args.common.plant.is_none() {
        println!("plant: reference motor with an SSI sensor (hal-sim/presets/reference-ssi.toml)");
    }
    println!(
        "ssi: plant (seed {seed}) with a {} + {}-bit SSI sensor ({}), Halls stuck at 000 and the encoder's lines broken: \
         SSI only (0x3000:01 = 0x0000_0300)",
        params.ssi_multi_turn_bits,
        params.ssi_single_turn_bits,
        if params.ssi_gray { "Gray" } else { "binary" }
    );
    let f = ssi::run(&params, seed)?;
    println!("  start-up commutation in PPM at rest, shaft at {:.3} rad", ssi::START_ANGLE_RAD);
    println!("  move of {} revolutions: |0x6064 - target| = {} inc", ssi::MOVE_REVOLUTIONS, f.move_error_inc);
    println!(
        "  homing method 37 with 0x607C = {}: 0x6064 = {}, 0x3012:0E = {} (saved with 0x1010)",
        ssi::HOME_POSITION,
        f.homed_position_inc,
        f.saved_offset_inc
    );
    println!(
        "  power cycle, shaft turned {:.1} revolutions by hand meanwhile: 0x6064 {} before, {} after, no homing",
        ssi::TURNED_WHILE_OFF_RAD / core::f64::consts::TAU,
        f.position_before_inc,
        f.position_after_inc
    );
    println!();
    println!("commutation_error_deg={:.3}", f.commutation_error_deg);
    println!("move_error_inc={}", f.move_error_inc);
    println!("absolute_position_error_inc={}", f.absolute_position_error_inc);
    println!("flipped_bit_code={:#06x}", f.flipped_bit_code);
    println!("stuck_clock_code={:#06x}", f.stuck_clock_code);
    println!("missing_sensor_code={:#06x}", f.missing_sensor_code);
    Ok(())
}

/// `drive-sim identify`: the motor identification run by a master over SDO, its results against the plant's truth.
fn identify(args: &IdentifyArgs) -> Result<(), String> {
    let seed = args.common.seed;
    use hal_sim::scenarios::identification::{self, IdentifyRun, Outcome};
    let params = scenarios::scenario_plant();
    println!(
        "identify: 0x6060 = -2, enable, controlword bit 4 over SDO; the master polls 0x3204:02/:03 and 0x6041 every \
         10 ms, then reads the results back (seed {seed})"
    );
    let mut bar = Progress::on_terminal("identify");
    let resonance = resonance_override(args.resonance);
    let run = identification::identify_then_with_progress(&params, seed, |_| {}, resonance, &mut |done, total| {
        bar.update(done, total)
    });
    bar.finish();
    let id = &run.identified;
    let err = IdentifyRun::error_pct;
    println!(
        "  R {:.4} ohm (true {:.4}), Ld {:.1} uH (true {:.1}), Lq {:.1} uH (true {:.1}), pole pairs {}, 0x3010:02 {:#06x}, \
         index offset {}, Hall offset {}",
        id.resistance_ohm,
        params.phase_resistance_ohm,
        id.ld_h * 1e6,
        params.ld_h * 1e6,
        id.lq_h * 1e6,
        params.lq_h * 1e6,
        id.pole_pairs,
        id.encoder_type,
        id.index_offset,
        id.hall_offset
    );
    println!(
        "  SDO: {} requests, {} answered, {} aborted, longest gap between answers {:.1} ms; last step {}",
        run.sdo.requests, run.sdo.answered, run.sdo.aborted, run.sdo.max_gap_ms, run.last_step
    );
    let pct = |value: f64, truth: f64| {
        if value > 0.0 {
            format!("{:.2}", err(value, truth))
        } else {
            "nan".to_owned()
        }
    };
    match run.outcome {
        Outcome::Done => println!("  done (statusword bit 12)"),
        Outcome::Fault { code, power_off } => println!("  fault {code:#06x}, power stage off: {power_off}"),
        Outcome::GaveUp => println!("  neither done nor failed within 30 s"),
    }
    println!();
    println!("r_error_pct={}", pct(id.resistance_ohm, params.phase_resistance_ohm));
    println!("ld_error_pct={}", pct(id.ld_h, params.ld_h));
    println!("lq_error_pct={}", pct(id.lq_h, params.lq_h));
    // 0x3001:05 holds the commissioned value until the mechanical step writes it: an error only once it did.
    let kt = if id.inertia_kg_m2 > 0.0 { id.kt_nm_per_a } else { 0.0 };
    println!("kt_error_pct={}", pct(kt, params.torque_constant_nm_per_a()));
    println!("inertia_error_pct={}", pct(id.inertia_kg_m2, params.total_inertia_kg_m2()));
    // The Coulomb friction the motor sees: its own and the load's through the gear (driving, the motor supplies
    // T / (N eta)). The gear's losses, proportional to the torque it carries, add to it in the relay (they oppose
    // the motion like friction) and are not in this figure's truth.
    let coulomb_at_motor =
        params.coulomb_friction_nm + params.load_coulomb_friction_nm / (params.gear_ratio * params.gear_efficiency);
    println!("friction_error_pct={}", pct(id.coulomb_friction_nm, coulomb_at_motor));
    // The load's resonance pair (0x3205:03/04) against the two-mass truth: "none" where the drive found a rigid
    // load, the error "none" where both agree on rigid, "spurious" where the plant is rigid but the drive found a
    // pair, "missed" where the plant is elastic and the drive found none.
    let pair = [
        ("resonance", id.resonance_hz, params.coupling_resonance_hz()),
        ("anti_resonance", id.anti_resonance_hz, params.coupling_anti_resonance_hz()),
    ];
    for (name, found, truth) in pair {
        let shown = if found > 0.0 { format!("{found:.1}") } else { "none".to_owned() };
        let error = match (found > 0.0, truth > 0.0) {
            (true, true) => format!("{:.2}", err(found, truth)),
            (false, false) => "none".to_owned(),
            (true, false) => "spurious".to_owned(),
            (false, true) => "missed".to_owned(),
        };
        println!("{name}_hz={shown}");
        println!("{name}_error_pct={error}");
    }
    println!("identify_s={:.3}", run.identify_s);
    println!("sdo_requests={}", run.sdo.requests);
    println!("sdo_answered={}", run.sdo.answered);
    println!("sdo_max_gap_ms={:.1}", run.sdo.max_gap_ms);
    match run.outcome {
        Outcome::Done => Ok(()),
        other => Err(format!("identification did not finish: {other:?}")),
    }
}

fn bench(seconds: f64, drives: usize) -> Result<(), String> {
    if cfg!(debug_assertions) {
        println!("note: a debug build; the figure is for `cargo run --release`");
    }
    let b = scenarios::bench(seconds, drives).map_err(|e| e.to_string())?;
    println!(
        "bench: {:.2} s of drive time on each of {} drive(s) ({} fast ticks each with the plant, slow tick every \
         10th) in {:.3} s wall-clock, on one thread",
        b.simulated_s,
        b.drives,
        (b.simulated_s * 25_000.0).round(),
        b.wall_s
    );
    println!();
    println!("drives={}", b.drives);
    println!("sim_speed_ratio_total={:.2}", b.sim_speed_ratio * b.drives as f64);
    println!("sim_speed_ratio={:.2}", b.sim_speed_ratio);
    Ok(())
}

/// The `--pcap` capture of the EtherCAT servers, if one was asked for.
type Capture = Option<PcapWriter<std::io::BufWriter<std::fs::File>>>;

/// Opens the `--pcap` file of `drive-sim ethercat` (one drive or a line).
fn open_pcap(path: Option<&Path>) -> Result<Capture, String> {
    let Some(path) = path else { return Ok(None) };
    let file = std::fs::File::create(path).map_err(|err| format!("--pcap {}: {err}", path.display()))?;
    Ok(Some(PcapWriter::new(std::io::BufWriter::new(file)).map_err(|err| format!("--pcap: {err}"))?))
}

/// Writes `frame` to the capture, stamped with the wall clock, as a capture on the interface would be.
fn capture(pcap: &mut Capture, frame: &[u8]) -> std::io::Result<()> {
    match pcap.as_mut() {
        Some(w) => {
            let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
            w.write_frame(now, frame)
        }
        None => Ok(()),
    }
}

/// `drive-sim ethercat`: the drive as an EtherCAT slave on a network interface until `--seconds` (wall clock)
/// pass, the master falls silent for `--idle-exit-ms` after its first frame, or the process is stopped.
fn ethercat(e: &EthercatArgs) -> Result<(), String> {
    // Real time runs the frame path apart from the drives (hal_sim::sim::ethercat_line, "Real time"), one drive too.
    if e.slaves > 1 || !e.plant_for.is_empty() || !e.lock_step {
        return ethercat_line(e);
    }
    let iface = e.iface.as_str();
    let cycle_us = e.cycle_us;
    let config = EthercatConfig {
        clock: if e.lock_step { ClockMode::LockStep } else { ClockMode::RealTime },
        cycle_ns: cycle_us.saturating_mul(1_000),
        clock_error_ppb: (e.clock_error_ppm * 1_000.0).round() as i64,
        seed: e.common.seed,
        idle_cycle: e.idle_cycle,
        drive_clock_error_ppb: (e.drive_clock_error_ppm * 1_000.0).round() as i64,
    };
    if cfg!(debug_assertions) {
        println!("note: a debug build; real masters' timeouts want `cargo run --release`");
    }
    let mut runner = EthercatRunner::with_plant(config, scenarios::scenario_plant())?;
    if let Some(path) = &e.trace {
        runner.node.trace = Some(hal_sim::sim::current_trace::CurrentTrace::create(path)?);
    }
    if e.sto_open {
        runner.node.sim.plant.set_sto_inputs(firmware::hal::sto::StoInputs::DEMANDED);
        println!("  STO-IN1 and STO-IN2 de-energised (Safe Torque Off active from power-up)");
    }
    match config.clock {
        ClockMode::LockStep => println!(
            "ethercat: serving the simulated drive on {iface}, lock-step: {cycle_us} us of simulated time per cyclic \
             frame (LRW/LRD/LWR)"
        ),
        ClockMode::RealTime => println!("ethercat: serving the simulated drive on {iface}, real time"),
    }
    println!(
        "  plant (seed {}), ESC local clock {:+} ppm and drive clock {:+} ppm against the master, stop: {}",
        e.common.seed,
        e.clock_error_ppm,
        e.drive_clock_error_ppm,
        match (e.seconds, e.idle_exit_ms) {
            (Some(s), Some(ms)) => format!("after {s} s or {ms} ms without frames"),
            (Some(s), None) => format!("after {s} s"),
            (None, Some(ms)) => format!("after {ms} ms without frames"),
            (None, None) => "Ctrl-C".to_owned(),
        }
    );
    let start = std::time::Instant::now();
    let limit = e.seconds.map(std::time::Duration::from_secs_f64);
    let idle_exit = e.idle_exit_ms.map(std::time::Duration::from_millis);
    let mut last_frames = 0;
    let mut last_frame_at = start;
    let mut pcap = open_pcap(e.pcap.as_deref())?;
    let tap = |_: Direction, frame: &[u8]| capture(&mut pcap, frame);
    runner
        .serve_tapped(iface, std::time::Duration::from_millis(1), tap, |stats| {
            let now = std::time::Instant::now();
            if stats.frames != last_frames {
                last_frames = stats.frames;
                last_frame_at = now;
            }
            let timed_out = limit.is_some_and(|l| now.duration_since(start) >= l);
            let silent = idle_exit.is_some_and(|d| stats.frames > 0 && now.duration_since(last_frame_at) >= d);
            timed_out || silent
        })
        .map_err(|err| err.to_string())?;
    let pcap_packets = match pcap {
        Some(w) => {
            let n = w.packets();
            w.into_inner().map_err(|err| format!("--pcap: {err}"))?;
            Some(n)
        }
        None => None,
    };
    let s = runner.stats();
    let wall = start.elapsed().as_secs_f64();
    println!(
        "  {} frames ({} cyclic, {} dropped) in {wall:.2} s wall-clock, {:.3} s simulated; {} process-data cycles",
        s.frames,
        s.cyclic_frames,
        s.dropped,
        runner.simulated_ns() as f64 * 1e-9,
        s.cycles
    );
    // The DC phase-locked loop (firmware::ecat::sync_pll): state, applied trim, frequency estimate, phase error at
    // the last SYNC0 pulse.
    let pll = runner.sync_pll();
    println!(
        "  DC PLL: {:?}, trim {:+.1} ppm, drive clock estimated {:+.1} ppm off SYNC0, phase error {:+} ns \
         ({} pulses, {} missing, {} jumps)",
        pll.state,
        f64::from(pll.trim_ppb) / 1_000.0,
        f64::from(pll.frequency_ppb) / 1_000.0,
        pll.phase_error_ns,
        pll.pulses,
        pll.missed,
        pll.jumps
    );
    println!();
    println!("frames={}", s.frames);
    if let Some(n) = pcap_packets {
        println!("pcap_packets={n}");
    }
    println!("cyclic_frames={}", s.cyclic_frames);
    println!("dropped_frames={}", s.dropped);
    println!("cycles={}", s.cycles);
    println!("sm2_writes={}", s.sm2_writes);
    println!("sync0_pulses={}", s.sync0_pulses);
    println!("sync0_missed={}", s.sync0_missed);
    println!("lag_events={}", s.lag_events);
    println!("state_reached={}", al_state_name(s.highest_al_state));
    println!("state_final={:?}", runner.state());
    println!("sm_event_missed={}", runner.sm_event_missed());
    println!("simulated_s={:.6}", runner.simulated_ns() as f64 * 1e-9);
    // The watchdog's timing in simulated time (`--idle-cycle`): the last outputs, the AL error, the CiA 402
    // reaction.
    println!("idle_polls={}", s.idle);
    println!("last_sm2_write_ns={}", s.last_sm2_write_ns);
    if let Some(t) = s.al_error_ns {
        println!("al_error_ns={t}");
    }
    if let Some((t, state)) = s.left_operation_enabled {
        println!("left_operation_enabled_ns={t}");
        println!("left_operation_enabled_to={state:?}");
    }
    println!("cia402_state_final={:?}", runner.node.sim.cia402_state());
    println!("statusword_final=0x{:04x}", runner.node.sim.statusword());
    // The process-data watchdog as the master configured it: SM2's control byte (bit 6 = the ESC retriggers the
    // watchdog with every SM2 write), 0x0400 divider and 0x0420 time, and how often it expired.
    println!("sm2_control=0x{:02x}", runner.esc.register(0x0814));
    let reg16 = |a: u16| u16::from_le_bytes([runner.esc.register(a), runner.esc.register(a + 1)]);
    println!("watchdog_divider={}", reg16(0x0400));
    println!("watchdog_time_pd={}", reg16(0x0420));
    println!("pd_watchdog_expirations={}", runner.esc.pd_watchdog().expirations);
    // The DC phase-locked loop (firmware::ecat::sync_pll).
    println!("pll_state={:?}", pll.state);
    println!("pll_trim_ppm={:.3}", f64::from(pll.trim_ppb) / 1_000.0);
    println!("pll_frequency_ppm={:.3}", f64::from(pll.frequency_ppb) / 1_000.0);
    println!("pll_phase_error_ns={}", pll.phase_error_ns);
    println!("pll_pulses={}", pll.pulses);
    // The DC registers as the master left them (0x0981 SYNC activation, 0x09A0 SYNC0 cycle).
    println!("dc_activation=0x{:02x}", runner.esc.register(0x0981));
    println!(
        "sync0_cycle_ns={}",
        u32::from_le_bytes([0x09A0u16, 0x09A1, 0x09A2, 0x09A3].map(|a| runner.esc.register(a)))
    );
    Ok(())
}

/// `drive-sim ethercat --slaves N` (N > 1): N drives in a line on the interface (hal_sim::sim::ethercat_line), until
/// `--seconds` pass or the master falls silent for `--idle-exit-ms`. Prints the line's figures and each slave's
/// (`slaveK_...`).
fn ethercat_line(e: &EthercatArgs) -> Result<(), String> {
    let iface = e.iface.as_str();
    let n = usize::from(e.slaves);
    let config = EthercatConfig {
        clock: if e.lock_step { ClockMode::LockStep } else { ClockMode::RealTime },
        cycle_ns: e.cycle_us.saturating_mul(1_000),
        clock_error_ppb: (e.clock_error_ppm * 1_000.0).round() as i64,
        seed: e.common.seed,
        idle_cycle: e.idle_cycle,
        drive_clock_error_ppb: (e.drive_clock_error_ppm * 1_000.0).round() as i64,
    };
    if cfg!(debug_assertions) {
        println!("note: a debug build; real masters' timeouts want `cargo run --release`");
    }
    let mut plants = vec![scenarios::scenario_plant(); n];
    for (k, file) in &e.plant_for {
        let slot = plants
            .get_mut(usize::from(*k))
            .ok_or_else(|| format!("--plant-for {k}: there are only {n} slaves (0..={})", n - 1))?;
        *slot = file.params.clone();
        println!("  slave {k}: plant {}", file.path.display());
    }
    let spread_ppb = (e.clock_spread_ppm * 1_000.0).round() as i64;
    let mut line = EthercatLine::new(config, &plants, spread_ppb)?;
    if e.sto_open {
        for s in &mut line.slaves {
            s.node.sim.plant.set_sto_inputs(firmware::hal::sto::StoInputs::DEMANDED);
        }
        println!("  STO-IN1 and STO-IN2 de-energised on every drive");
    }
    match config.clock {
        ClockMode::LockStep => println!(
            "ethercat: serving {n} simulated drives in a line on {iface}, lock-step: {} us of simulated time per \
             cyclic frame (LRW/LRD/LWR)",
            e.cycle_us
        ),
        ClockMode::RealTime => {
            println!(
                "ethercat: serving {n} simulated drives in a line on {iface}, real time: frames answered on their \
                 own thread, the drives on {} threads",
                hal_sim::sim::ethercat_line::REAL_TIME_WORKERS.min(n)
            );
            // The priority the line was started at (`chrt -f P`): the frame path's; the workers step one below.
            let (policy, priority) = hal_sim::sim::host_priority::current();
            println!("realtime_policy={policy}");
            println!("realtime_priority={priority}");
        }
    }
    println!(
        "  ESC clocks {:+} ppm, spread +-{} ppm over the slaves; port-to-port delays {}..{} ns",
        e.clock_error_ppm,
        e.clock_spread_ppm,
        (0..n).map(|k| line.hop(k)).min().unwrap_or(0),
        (0..n).map(|k| line.hop(k)).max().unwrap_or(0)
    );
    let start = std::time::Instant::now();
    let limit = e.seconds.map(std::time::Duration::from_secs_f64);
    let idle_exit = e.idle_exit_ms.map(std::time::Duration::from_millis);
    let mut last_frames = 0;
    let mut last_frame_at = start;
    let mut pcap = open_pcap(e.pcap.as_deref())?;
    let tap = |_: Direction, frame: &[u8]| capture(&mut pcap, frame);
    let stop = |stats: &hal_sim::sim::ethercat_line::LineStats| {
        let now = std::time::Instant::now();
        if stats.frames != last_frames {
            last_frames = stats.frames;
            last_frame_at = now;
        }
        let timed_out = limit.is_some_and(|l| now.duration_since(start) >= l);
        let silent = idle_exit.is_some_and(|d| stats.frames > 0 && now.duration_since(last_frame_at) >= d);
        timed_out || silent
    };
    let poll = std::time::Duration::from_millis(1);
    match config.clock {
        ClockMode::LockStep => line.serve_tapped(iface, poll, tap, stop),
        ClockMode::RealTime => line.serve_real_time(iface, poll, tap, stop),
    }
    .map_err(|err| err.to_string())?;
    if let Some(w) = pcap {
        println!("pcap_packets={}", w.packets());
        w.into_inner().map_err(|err| format!("--pcap: {err}"))?;
    }
    let wall = start.elapsed().as_secs_f64();
    let ls = line.stats();
    let all = line.slave_stats();
    let simulated_s = line.slaves.first().map_or(0.0, |s| s.simulated_ns() as f64 * 1e-9);
    println!(
        "  {} frames ({} cyclic, {} dropped) in {wall:.2} s wall-clock, {simulated_s:.3} s simulated",
        ls.frames, ls.cyclic_frames, ls.dropped
    );
    println!();
    println!("slaves={n}");
    println!("frames={}", ls.frames);
    println!("cyclic_frames={}", ls.cyclic_frames);
    println!("dropped_frames={}", ls.dropped);
    println!("idle_polls={}", ls.idle);
    println!("wall_s={wall:.3}");
    println!("simulated_s={simulated_s:.6}");
    let lowest = all.iter().map(|s| s.highest_al_state).min().unwrap_or(0);
    println!("state_reached_all={}", al_state_name(lowest));
    println!("sm_event_missed_total={}", line.slaves.iter().map(|s| u64::from(s.sm_event_missed())).sum::<u64>());
    println!("sync0_missed_total={}", all.iter().map(|s| s.sync0_missed).sum::<u64>());
    println!("lag_events_total={}", all.iter().map(|s| s.lag_events).sum::<u64>());
    println!("cycles_min={}", all.iter().map(|s| s.cycles).min().unwrap_or(0));
    println!("cycles_max={}", all.iter().map(|s| s.cycles).max().unwrap_or(0));
    println!("sync0_pulses_min={}", all.iter().map(|s| s.sync0_pulses).min().unwrap_or(0));
    if config.clock == ClockMode::RealTime {
        println!("answer_max_us={:.1}", ls.answer_max_ns as f64 / 1_000.0);
        println!("answers_over_100us={}", ls.answers_over_100us);
        println!("answers_over_1ms={}", ls.answers_over_1ms);
        println!("esc_wait_max_us={:.1}", ls.esc_wait_max_ns as f64 / 1_000.0);
        // The output writes each ESC held until its drive's time reached their stamp.
        println!("outputs_delivered_total={}", all.iter().map(|s| s.outputs_delivered).sum::<u64>());
        println!("output_overflows_total={}", all.iter().map(|s| s.output_overflows).sum::<u64>());
        println!("outputs_held_max={}", all.iter().map(|s| s.outputs_held_max).max().unwrap_or(0));
    }
    println!("sync0_samples={}", ls.sync0_samples);
    println!("sync0_spread_max_ns={}", ls.sync0_spread_max_ns);
    println!("system_time_spread_ns={}", line.system_time_spread_ns());
    println!(
        "operation_enabled_all={}",
        u8::from(line.slaves.iter().all(|s| s.node.sim.cia402_state() == firmware::cia402::State::OperationEnabled))
    );
    for (k, s) in line.slaves.iter().enumerate() {
        let st = &all[k];
        let reg32 = |a: u16| u32::from_le_bytes([a, a + 1, a + 2, a + 3].map(|x| s.esc.register(x)));
        println!(
            "slave{k}: serial={} clock_error_ppm={:+.3} hop_ns={} state_reached={} state_final={:?} cycles={} \
             sync0_pulses={} sync0_missed={} sm_event_missed={} sm2_writes={} lag_events={} cia402_state_final={:?} \
             dc_activation=0x{:02x} sync0_cycle_ns={} system_time_delay_ns={} pll_state={:?} al_status_code=0x{:04x} \
             al_error_ns={} left_operation_enabled={:?}",
            {
                let mut b = [0u8; 4];
                let _ = s.node.sim.drive.dictionary().read(
                    0x1018,
                    4,
                    0,
                    &mut b,
                    &mut firmware::od::access::NoApplicationObjects,
                );
                u32::from_le_bytes(b)
            },
            s.node.config().clock_error_ppb as f64 / 1_000.0,
            line.hop(k),
            al_state_name(st.highest_al_state),
            s.state(),
            st.cycles,
            st.sync0_pulses,
            st.sync0_missed,
            s.sm_event_missed(),
            st.sm2_writes,
            st.lag_events,
            s.node.sim.cia402_state(),
            s.esc.register(0x0981),
            reg32(0x09A0),
            reg32(0x0928),
            s.sync_pll().state,
            s.esc.register_u16(0x0134),
            st.al_error_ns.map_or(-1, |t| t as i64),
            st.left_operation_enabled,
        );
    }
    Ok(())
}

/// The name of an AL state code (0x0130 bits 3..0).
fn al_state_name(code: u16) -> &'static str {
    match code {
        1 => "INIT",
        2 => "PREOP",
        3 => "BOOT",
        4 => "SAFEOP",
        8 => "OP",
        _ => "NONE",
    }
}

fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    // The subcommand's name is the default output directory's (out/<scenario>).
    let scenario = matches.subcommand_name().unwrap_or_default().to_owned();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    let plant = |file: Option<&cli::PlantFile>| file.map_or_else(PlantParams::reference, |f| f.params.clone());
    let result = match &cli.command {
        Command::Completions { shell } => {
            clap_complete::generate(*shell, &mut Cli::command(), "drive-sim", &mut std::io::stdout());
            Ok(())
        }
        Command::Canopen(args) => {
            // A node-ID past the bus is a bad value of its option, refused as clap refuses one (status 2).
            let config = args.config().unwrap_or_else(|e| {
                let canopen = Cli::command().find_subcommand("canopen").cloned();
                let mut command = canopen.unwrap_or_else(Cli::command).bin_name("drive-sim canopen");
                command.error(clap::error::ErrorKind::ValueValidation, e).exit()
            });
            canopen::run(args, config).map_err(|e| format!("canopen: {e}"))
        }
        Command::Bench(args) => {
            scenarios::with_plant(plant(args.plant.as_ref()), || bench(args.seconds, usize::from(args.drives)))
        }
        Command::Identify(args) => {
            print_plant(args.common.plant.as_ref());
            scenarios::with_plant(plant(args.common.plant.as_ref()), || identify(args))
        }
        Command::Ssi(args) => {
            // The default is the SSI preset's plant, not the reference: printed by `ssi` itself.
            if args.common.plant.is_some() {
                print_plant(args.common.plant.as_ref());
            }
            ssi(args)
        }
        Command::Ethercat(args) => {
            print_plant(args.common.plant.as_ref());
            scenarios::with_plant(plant(args.common.plant.as_ref()), || ethercat(args))
        }
        Command::CurrentStep(args) | Command::Spinning(args) => {
            simulated(&args.scenario, &scenario, |dir| match &cli.command {
                Command::Spinning(_) => spinning(args, dir),
                _ => current_step(args, dir),
            })
        }
        Command::Csp(args) => simulated(&args.scenario, &scenario, |dir| csp(args, dir)),
        Command::DualLoop(args) => simulated(&args.scenario, &scenario, |dir| dual_loop(args, dir)),
        Command::FaultMatrix(args) => simulated(&args.scenario, &scenario, |dir| fault_matrix(args, dir)),
        Command::CsvSweep(args) => simulated(args, &scenario, |dir| csv_sweep(args.common.seed, dir)),
        Command::Ppm(args) => simulated(args, &scenario, |dir| ppm(args.common.seed, dir)),
        Command::Homing(args) => simulated(args, &scenario, |dir| homing_matrix(args.common.seed, dir)),
        Command::DutyCycle(args) => simulated(args, &scenario, |dir| duty_cycle(args.common.seed, dir)),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("drive-sim: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Runs a simulated scenario named `name` on the plant of `args`, after the identification with its auto-tuning
/// when `--auto-tune` asks for it; `run` gets the output directory.
fn simulated(args: &Scenario, name: &str, run: impl FnOnce(&Path) -> Result<(), String>) -> Result<(), String> {
    let dir = args.out.clone().unwrap_or_else(|| PathBuf::from("out").join(name));
    let file = args.common.plant.as_ref();
    let params = file.map_or_else(PlantParams::reference, |f| f.params.clone());
    print_plant(file);
    if args.auto_tune {
        let parameters = auto_tuned(args, &params)?;
        scenarios::with_plant(params, || scenarios::with_parameters(parameters, || run(&dir)))
    } else {
        scenarios::with_plant(params, || run(&dir))
    }
}

/// What the master writes after the identification (which measured its own pair) before it runs the auto-tuning
/// 0x3205:01 again: `--resonance`'s pair for 0x3205:03/04 (0.1 Hz).
fn resonance_override(resonance: Option<(f64, f64)>) -> Option<(u16, u16)> {
    resonance.map(|(r, ar)| ((r * 10.0).round() as u16, (ar * 10.0).round() as u16))
}

/// `--auto-tune`: the identification with its auto-tuning (`drive-sim identify`'s run) on the plant, and the
/// parameters it found, which every drive of the scenario then gets after its motor data.
fn auto_tuned(args: &Scenario, params: &PlantParams) -> Result<hal_sim::scenarios::identification::Parameters, String> {
    use hal_sim::scenarios::identification;
    let mut bar = Progress::on_terminal("auto-tune: identify");
    let run = identification::identify_then_with_progress(
        params,
        args.common.seed,
        |_| {},
        resonance_override(args.resonance),
        &mut |done, total| bar.update(done, total),
    );
    bar.finish();
    let id = &run.identified;
    println!(
        "auto-tune: identified in {:.2} s (simulated): R {:.4} ohm, Ld {:.1} uH, Lq {:.1} uH, kt {:.4} Nm/A, \
         J {:.1} g cm^2; gains 0x30A0..0x30A3 from 0x3205's stiffness",
        run.identify_s,
        id.resistance_ohm,
        id.ld_h * 1e6,
        id.lq_h * 1e6,
        id.kt_nm_per_a,
        id.inertia_kg_m2 * 1e7,
    );
    // The loops' gains as the auto-tuning wrote them (the objects' own units, device.toml), for a reader who wants
    // to compare them or set them by hand.
    let gains: Vec<String> = run
        .parameters
        .values
        .iter()
        .filter(|(index, _, _)| (0x30A0..=0x30A3).contains(index))
        .map(|(index, sub, data)| {
            let mut bytes = [0u8; 4];
            for (b, d) in bytes.iter_mut().zip(data) {
                *b = *d;
            }
            format!("{index:04X}:{sub:02X}={}", u32::from_le_bytes(bytes))
        })
        .collect();
    println!("auto-tune: gains {}", gains.join(" "));
    match run.outcome {
        identification::Outcome::Done => Ok(run.parameters),
        other => Err(format!("--auto-tune: the identification did not finish: {other:?}")),
    }
}

/// One line on the plant in use and how it scales the scenarios.
fn print_plant(file: Option<&cli::PlantFile>) {
    let reference = PlantParams::reference();
    let p = file.map_or(&reference, |f| &f.params);
    let sc = PlantScale::of(p);
    println!(
        "plant: {} ({} V, {} pole pairs, kt {:.4} Nm/A, {} / {} A, {} rpm, gear {}:1, {} counts/rev; scale: speed x{:.3}, \
         current x{:.3}, torque x{:.3}, inertia x{:.3})",
        file.map_or("reference (PlantParams::reference())".to_owned(), |f| f.path.display().to_string()),
        p.source_voltage_v,
        p.pole_pairs,
        p.torque_constant_nm_per_a(),
        p.nominal_current_a,
        p.peak_current_a,
        p.max_speed_rpm,
        p.gear_ratio,
        p.encoder_counts_per_rev,
        sc.speed,
        sc.current,
        sc.torque,
        sc.inertia
    );
}
