//! Faults injected into the plant (issue 5 "hal-sim fault injection"): each one a physical failure of the power
//! stage, the motor or a sensor, set from tests and from `drive-sim` through [`super::Plant::faults_mut`], and
//! taking effect with the next period. The effect of each is modelled where that part of the plant is computed
//! (inverter, motor, sensors); this file only holds what is injected.
//!
//! Faults with a direct hook elsewhere: shunt offset drift ([`super::Plant::set_adc_offset`]), supply sag
//! ([`super::Plant::set_source_voltage`]), over-temperature ([`super::Plant::set_power_stage_temperature`],
//! [`super::Plant::set_winding_temperature`]), locked rotor ([`super::Plant::lock_rotor`]), limit switches
//! ([`super::io`]).

/// A burst of spurious encoder edges (electrical noise on the A/B lines).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderNoise {
    /// Spurious counts added per PWM period while the burst lasts (signed: the direction the noise counts).
    pub counts_per_period: i32,
    /// Periods the burst still lasts.
    pub periods_left: u32,
}

/// Everything injected into the plant. All off by default.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlantFaults {
    /// A motor phase is disconnected (0..=2 for A, B, C): no current can flow in it.
    pub phase_open: Option<usize>,
    /// Two inverter outputs are shorted together through this resistance, in ohm: `(phase, phase, ohm)`.
    pub phase_short: Option<(usize, usize, f64)>,
    /// The encoder's A/B lines are broken: the counter no longer moves (the index line with them).
    pub encoder_wire_break: bool,
    /// The encoder's A and B lines are swapped (a wiring error): the counter counts the shaft's motion backwards.
    pub encoder_reversed: bool,
    /// A noise burst on the encoder lines.
    pub encoder_noise: Option<EncoderNoise>,
    /// The encoder's index line is broken: no index pulse reaches the counter.
    pub index_lost: bool,
    /// The Hall sensors read this state whatever the rotor does (a stuck sensor or a broken cable).
    pub hall_stuck: Option<u8>,
    /// The motor temperature channel reads this code whatever the winding temperature: `Some(0)` a sensor not
    /// connected (the input's pull-down), `Some(4095)` a sensor line shorted to the supply.
    pub motor_temperature_code_stuck: Option<u16>,
    /// The SSI clock line is stuck (or the sensor lost its supply): the sensor never shifts, its data line stays at
    /// the idle level and every clocked bit reads 1.
    pub ssi_clock_stuck: bool,
    /// No SSI sensor answers (not connected: the receiver's fail-safe reads 1 on every bit).
    pub ssi_missing: bool,
    /// Flip this bit (0 = the last clocked) of the next SSI frame, once (a disturbed transmission).
    pub ssi_flip_bit_once: Option<u32>,
}
