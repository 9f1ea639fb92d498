//! Current-offset calibration, run when the power stage is switched on (CiA 402 transition 3).
//!
//! IDX transition 3 "Switch on" initialises the current sensor and runs the current offset calibration
//! (`shared/spec/control-and-protection.md` §2.9, S2 L416-449; `shared/spec/cia402-device-control.md`, transition
//! table: "3 RTSO -> SO, Initialize current sensor; current-offset calibration").
//!
//! Procedure, one [`Calibration::step`] per fast tick:
//! 1. The outputs are enabled at 50 % duty on all three phases ([`CALIBRATION_COMMAND`]): zero line-to-line
//!    voltage, every low switch on at the PWM centre where the shunts are sampled, so a motor at rest carries no
//!    current and each shunt reads its own offset.
//! 2. `settle_ticks` periods are skipped (bootstrap charging, any current left from before decaying: the reference
//!    winding's L/R is 0.6 ms, the default 2 ms leaves e^-3.3 = 4 %, and that decays further during averaging).
//! 3. 256 samples per channel are summed; the sum is the offset in 1/256 LSB (the format of
//!    [`ShuntOffsets`]), so no division. With the reference 2 LSB rms noise the estimate's standard deviation is
//!    2 / sqrt(256) = 0.125 LSB.
//! 4. Validity: each offset within `window_lsb` of mid-scale (the reference hardware allows up to 50 LSB; default
//!    window 100 LSB), and each channel's spread (max - min) within `max_spread_lsb` (a moving motor or a broken
//!    amplifier shows up as a spread far above the noise). Samples with a code at either rail (0 or 4095) are
//!    rejected and not counted; if 256 good samples are not collected within `timeout_ticks` the calibration fails
//!    with [`CalibrationError::Timeout`]. So it always ends within `timeout_ticks`.
//!
//! The errors are typed so that the fault issue can map them to a fault code and reaction.

use super::scaling::{ShuntOffsets, OFFSET_FRACTION_BITS, SHUNT_MID_SCALE_CODE};
use crate::hal::power::{AdcSamples, PwmCommand, ADC_FULL_SCALE, PWM_PERIOD_TICKS};
use crate::power_state::CalibrationError;

/// Number of samples averaged per channel (2^8: the sum is the offset in 1/256 LSB).
pub const CALIBRATION_SAMPLES: u16 = 1 << OFFSET_FRACTION_BITS;

/// The power-stage command during calibration: all phases at 50 % duty (zero voltage), outputs enabled.
pub const CALIBRATION_COMMAND: PwmCommand = PwmCommand { duty: [PWM_PERIOD_TICKS / 2; 3], enabled: true };

/// Parameters of the offset calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CalibrationConfig {
    /// Periods skipped after the outputs are enabled before averaging starts.
    pub settle_ticks: u16,
    /// Largest accepted deviation of an offset from mid-scale, in LSB.
    pub window_lsb: u16,
    /// Largest accepted spread (max - min code) of one channel during averaging, in LSB.
    pub max_spread_lsb: u16,
    /// The calibration fails if it has not finished after this many periods.
    pub timeout_ticks: u16,
}

impl CalibrationConfig {
    /// Defaults for the reference hardware: 2 ms settling (50 ticks), 100 LSB window (twice the 50 LSB the
    /// reference sense chain may have), 48 LSB spread (0.39 A; 12 sigma of the 2 LSB rms noise on each side),
    /// timeout 25 ms (625 ticks: 50 + 256 with room for 319 rejected samples).
    pub const DEFAULT: Self = Self { settle_ticks: 50, window_lsb: 100, max_spread_lsb: 48, timeout_ticks: 625 };
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Progress of the calibration after one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibrationStatus {
    /// Still running: keep the outputs at [`CALIBRATION_COMMAND`].
    Running,
    /// Finished with valid offsets.
    Done(ShuntOffsets),
    /// Finished with an error; the offsets in use are unchanged.
    Failed(CalibrationError),
}

/// State of one offset calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Calibration {
    config: CalibrationConfig,
    ticks: u16,
    count: u16,
    sum: [u32; 3],
    min: [u16; 3],
    max: [u16; 3],
}

impl Calibration {
    /// A calibration that starts with the next step.
    #[must_use]
    pub const fn new(config: CalibrationConfig) -> Self {
        Self { config, ticks: 0, count: 0, sum: [0; 3], min: [u16::MAX; 3], max: [0; 3] }
    }

    /// Periods stepped so far.
    #[must_use]
    pub const fn ticks(&self) -> u16 {
        self.ticks
    }

    /// One period: `adc` is the sample of the period whose outputs were at [`CALIBRATION_COMMAND`].
    pub fn step(&mut self, adc: &AdcSamples) -> CalibrationStatus {
        self.ticks = self.ticks.saturating_add(1);
        if self.ticks > self.config.timeout_ticks {
            return CalibrationStatus::Failed(CalibrationError::Timeout);
        }
        if self.ticks <= self.config.settle_ticks {
            return CalibrationStatus::Running;
        }
        let codes = adc.phase_currents;
        if codes.iter().any(|&c| c == 0 || c >= ADC_FULL_SCALE) {
            return CalibrationStatus::Running;
        }
        for (((sum, min), max), code) in self.sum.iter_mut().zip(&mut self.min).zip(&mut self.max).zip(codes) {
            // At most 256 codes below 4096 are summed: < 2^20, no wrap.
            *sum = sum.wrapping_add(u32::from(code));
            *min = (*min).min(code);
            *max = (*max).max(code);
        }
        self.count = self.count.saturating_add(1);
        if self.count < CALIBRATION_SAMPLES {
            return CalibrationStatus::Running;
        }
        match self.result() {
            Ok(offsets) => CalibrationStatus::Done(offsets),
            Err(e) => CalibrationStatus::Failed(e),
        }
    }

    /// Checks the collected sums and turns them into offsets.
    fn result(&self) -> Result<ShuntOffsets, CalibrationError> {
        let mid = i32::from(SHUNT_MID_SCALE_CODE) << OFFSET_FRACTION_BITS;
        let window = i32::from(self.config.window_lsb) << OFFSET_FRACTION_BITS;
        let mut q8 = [0i32; 3];
        for (channel, (((out, &sum), &min), &max)) in
            q8.iter_mut().zip(&self.sum).zip(&self.min).zip(&self.max).enumerate()
        {
            let channel = channel as u8; // 0..=2
            let spread_lsb = max.saturating_sub(min);
            if spread_lsb > self.config.max_spread_lsb {
                return Err(CalibrationError::Unsteady { channel, spread_lsb });
            }
            // sum < 2^20: fits an i32; the deviation is within +-2^20.
            let offset = sum as i32;
            let deviation = offset.wrapping_sub(mid);
            if deviation.abs() > window {
                let deviation_lsb = (deviation >> OFFSET_FRACTION_BITS) as i16;
                return Err(CalibrationError::OffsetOutOfRange { channel, deviation_lsb });
            }
            *out = offset;
        }
        Ok(ShuntOffsets { q8 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(codes: [u16; 3]) -> AdcSamples {
        AdcSamples { phase_currents: codes, bus_voltage: 1638, temperature: 900, motor_temperature: 900 }
    }

    /// Runs a calibration on a fixed sequence generator; returns the final status and the ticks used.
    fn run(config: CalibrationConfig, mut codes: impl FnMut(u16) -> [u16; 3]) -> (CalibrationStatus, u16) {
        let mut cal = Calibration::new(config);
        for tick in 0..2000u16 {
            let status = cal.step(&sample(codes(tick)));
            if status != CalibrationStatus::Running {
                return (status, cal.ticks());
            }
        }
        panic!("calibration did not end");
    }

    #[test]
    fn estimates_offsets_with_noise_to_a_fraction_of_an_lsb() {
        // Offsets +37, -24, +50 LSB with a deterministic +-2 LSB triangle "noise" of zero mean over 4 samples.
        let noise = [-2i32, 1, 2, -1];
        let (status, ticks) = run(CalibrationConfig::DEFAULT, |t| {
            let n = noise[usize::from(t % 4)];
            [(2048 + 37 + n) as u16, (2048 - 24 - n) as u16, (2048 + 50 + n) as u16]
        });
        let CalibrationStatus::Done(offsets) = status else { panic!("{status:?}") };
        assert_eq!(ticks, 50 + 256, "bounded: settle + 256 samples");
        for (ch, want) in [37.0, -24.0, 50.0].into_iter().enumerate() {
            let got = offsets.deviation_lsb(ch).unwrap();
            assert!((got - want).abs() <= 0.02, "channel {ch}: {got} vs {want}");
        }
    }

    #[test]
    fn implausible_offset_is_a_typed_error() {
        let (status, _) = run(CalibrationConfig::DEFAULT, |_| [2048, 2048 - 101, 2048]);
        assert_eq!(
            status,
            CalibrationStatus::Failed(CalibrationError::OffsetOutOfRange { channel: 1, deviation_lsb: -101 })
        );
        // Exactly at the window edge is accepted.
        let (status, _) = run(CalibrationConfig::DEFAULT, |_| [2048 + 100, 2048, 2048]);
        assert!(matches!(status, CalibrationStatus::Done(_)), "{status:?}");
    }

    #[test]
    fn moving_signal_is_rejected_as_unsteady() {
        // A 1 A (124 LSB) sine on phase C: a spinning motor.
        let (status, _) = run(CalibrationConfig::DEFAULT, |t| {
            let s = (f64::from(t) * 0.3).sin() * 124.0;
            [2048, 2048, (2048.0 + s).round() as u16]
        });
        assert!(matches!(status, CalibrationStatus::Failed(CalibrationError::Unsteady { channel: 2, .. })));
    }

    #[test]
    fn saturated_samples_are_skipped_until_the_timeout() {
        let config = CalibrationConfig::DEFAULT;
        let (status, ticks) = run(config, |_| [2048, 4095, 2048]);
        assert_eq!(status, CalibrationStatus::Failed(CalibrationError::Timeout));
        assert_eq!(ticks, config.timeout_ticks + 1);
        // A few rail samples only delay the result.
        let (status, ticks) = run(config, |t| if t % 10 == 0 { [0, 2048, 2048] } else { [2050, 2047, 2046] });
        assert!(matches!(status, CalibrationStatus::Done(_)), "{status:?}");
        assert!(ticks > 50 + 256 && ticks < config.timeout_ticks);
    }

    #[test]
    fn settling_samples_are_ignored() {
        // A large decaying current during the first 50 ticks does not affect the estimate.
        let (status, _) =
            run(CalibrationConfig::DEFAULT, |t| if t < 50 { [3000, 1000, 2048] } else { [2060, 2040, 2048] });
        let CalibrationStatus::Done(o) = status else { panic!("{status:?}") };
        assert_eq!(o.deviation_lsb(0), Some(12.0));
        assert_eq!(o.deviation_lsb(1), Some(-8.0));
    }
}
