//! What the power stage and its sensors exchange with the current loop once per PWM period (tier 1).
//!
//! Timing (the reference hardware of `shared/design/ARCHITECTURE.md`): TIM1 runs centre-aligned at 25 kHz; the
//! ADC's injected conversions sample the three low-side shunts at the centre of the period (all low switches on);
//! the duties computed from those samples are written to preload registers and take effect at the next update
//! event. `hal-sim` models exactly this so that the simulated transport delay matches the hardware.

/// TIM1 clock on the reference MCU (APB2 timer clock), in Hz.
pub const TIMER_CLOCK_HZ: u32 = 168_000_000;
/// Current-loop and PWM frequency (EPOS4: current loop sampled every 0.04 ms).
pub const PWM_FREQUENCY_HZ: u32 = 25_000;
/// Auto-reload value of centre-aligned TIM1: the compare value of a 100 % duty. 168 MHz / (2 x 25 kHz).
pub const PWM_PERIOD_TICKS: u16 = 3360;
/// Fast ticks per slow tick (25 kHz current loop, 2.5 kHz velocity/position loops).
pub const SLOW_TICK_DIVIDER: u32 = 10;
/// Full scale of the 12-bit ADC.
pub const ADC_FULL_SCALE: u16 = 4095;

/// Raw ADC results of one PWM period, sampled at the PWM centre.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AdcSamples {
    /// Shunt amplifier outputs of phases A, B, C (12-bit, mid-scale = zero current before calibration).
    pub phase_currents: [u16; 3],
    /// DC-bus voltage divider (12-bit).
    pub bus_voltage: u16,
    /// Power-stage temperature sensor (12-bit).
    pub temperature: u16,
    /// Motor winding temperature sensor (12-bit, the same linear sensor type as the power stage's).
    pub motor_temperature: u16,
}

/// Position sensors read in the same interrupt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FeedbackSample {
    /// Encoder timer counter (quadrature counts, wraps at 2^16).
    pub encoder_count: u16,
    /// Counter value latched at the last index pulse, if one occurred since the previous sample.
    pub index_latch: Option<u16>,
    /// Hall sensor state: bit 0 = H1, bit 1 = H2, bit 2 = H3.
    pub hall: u8,
    /// Levels of the digital inputs as wired (before the polarity of 0x3141:02): bit n = input n+1. Sampled every
    /// PWM period so that tier 1 can latch the position at an edge (homing, touch probe).
    pub digital_inputs: u8,
    /// The SSI absolute encoder's frame clocked at the previous PWM centre (right-aligned, first bit clocked
    /// highest), when an SSI sensor is configured; 0 otherwise.
    pub ssi_frame: u32,
}

/// Everything tier 1 reads at the start of its interrupt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Measurements {
    /// ADC results.
    pub adc: AdcSamples,
    /// Encoder and Halls.
    pub feedback: FeedbackSample,
    /// The hardware break input (over-current comparator) has tripped and disabled the outputs.
    pub break_input: bool,
}

/// What tier 1 writes back: compare values for the next PWM period.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PwmCommand {
    /// Compare values of phases A, B, C in timer ticks, 0..=`PWM_PERIOD_TICKS` (high-side on-time fraction).
    pub duty: [u16; 3],
    /// Outputs enabled (main output enable). Disabled means all six switches off.
    pub enabled: bool,
}

impl PwmCommand {
    /// All switches off: the safe state of the power stage.
    pub const OFF: Self = Self { duty: [0; 3], enabled: false };
}
