//! Host speed of the plant. Run in release and read the figure:
//! `cargo test -p hal-sim --release --test plant_speed -- --ignored --nocapture`.

use std::time::Instant;

/// CPU time of this thread in s (Linux `schedstat`), so the figure does not depend on other load on the machine.
fn thread_cpu_s() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

use firmware::hal::power::PwmCommand;
use hal_sim::plant::{Plant, PlantParams, PERIOD_S};

/// Simulated seconds per wall-clock second while switching (rotating duties) and while disabled.
#[test]
#[ignore = "timing: run in release with --ignored --nocapture"]
fn simulated_seconds_per_wall_second() {
    let periods: u32 = 250_000; // 10 simulated seconds
    let mut plant = Plant::new(PlantParams::reference(), 1);
    let start = Instant::now();
    let cpu0 = thread_cpu_s();
    let mut sink = 0u64;
    for k in 0..periods {
        // Rotating 0.2-amplitude voltage vector: every leg switches every period.
        let th = f64::from(k) * 0.01;
        let duty = [0.0, 1.0, 2.0]
            .map(|s: f64| (3360.0 * (0.5 + 0.2 * (th - s * 2.0 * core::f64::consts::PI / 3.0).cos())).round() as u16);
        let m = plant.step(&PwmCommand { duty, enabled: true });
        sink = sink.wrapping_add(u64::from(m.adc.phase_currents[0]));
    }
    let switching = f64::from(periods) * PERIOD_S / start.elapsed().as_secs_f64();
    let cpu1 = thread_cpu_s();
    let start = Instant::now();
    for _ in 0..periods {
        let m = plant.step(&PwmCommand::OFF);
        sink = sink.wrapping_add(u64::from(m.adc.phase_currents[0]));
    }
    let disabled = f64::from(periods) * PERIOD_S / start.elapsed().as_secs_f64();
    let cpu2 = thread_cpu_s();
    println!("plant speed: {switching:.1} simulated s per wall s switching, {disabled:.1} disabled (checksum {sink})");
    if let (Some(a), Some(b), Some(c)) = (cpu0, cpu1, cpu2) {
        let sim = f64::from(periods) * PERIOD_S;
        println!("plant speed per CPU second: {:.1} switching, {:.1} disabled", sim / (b - a), sim / (c - b));
    }
    assert!(switching > 1.0);
}
