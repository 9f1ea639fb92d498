//! The temperature sensors of the reference board (`shared/design/ARCHITECTURE.md`, "Reference plant", sensors):
//! linear sensors, 0.5 V at 0 degC and 10 mV/K (MCP9700/TMP235 class), on 12-bit ADC channels with 3.3 V at code
//! 4095, for the power stage and the motor. Converted in tier 2 (a division), read by the thermal supervision.

/// Temperature-channel full scale: 3.3 V (the ADC reference) at code 4095, in mV (0.806 mV = 0.0806 K per LSB).
pub const TEMPERATURE_FULL_SCALE_MILLIVOLTS: u32 = 3300;
/// Temperature-sensor output at 0 degC, mV (the sensors' datasheet value; the plant's `temp_sensor_v_at_0c`).
pub const TEMPERATURE_MV_AT_0C: i32 = 500;

/// Temperature in 0.1 degC (the unit of 0x3201) from a temperature channel's 12-bit code (codes above 4095 are
/// clamped): the sensor gives 10 mV/K, i.e. 1 mV per 0.1 K, so `0.1 degC = code x 3300 / 4095 - 500`, rounded to
/// nearest. Range -500 (code 0) ..= 2800 (code 4095). A division: tier 2 only.
#[must_use]
pub fn temperature_ddegc(code: u16) -> i16 {
    let full_scale = u32::from(crate::hal::power::ADC_FULL_SCALE);
    let code = u32::from(code).min(full_scale);
    // code x 3300 + 2047 < 2^24: no wrap; the millivolts are <= 3300 (the divisor is the constant 4095).
    let mv = code
        .wrapping_mul(TEMPERATURE_FULL_SCALE_MILLIVOLTS)
        .wrapping_add(full_scale >> 1)
        .checked_div(full_scale)
        .unwrap_or(0);
    // -500 ..= 2800 fits an i16.
    (mv as i32).wrapping_sub(TEMPERATURE_MV_AT_0C) as i16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temperature_scale() {
        // The sensor's own points: 0.5 V = 0 degC, 1.5 V = 100 degC, 1.75 V = 125 degC (10 mV/K), at
        // 4095 / 3.3 V codes per volt. Each code is within half an LSB (0.04 K) of the voltage.
        let code = |v: f64| (v / 3.3 * 4095.0).round() as u16;
        for (volts, ddegc) in [(0.5, 0), (0.75, 250), (1.5, 1000), (1.75, 1250), (1.7, 1200)] {
            let t = temperature_ddegc(code(volts));
            assert!((i32::from(t) - ddegc).abs() <= 1, "{volts} V: {t}");
        }
        // Every code against the formula in f64: rounded to nearest.
        for c in 0..=4095u16 {
            let exact = f64::from(c) * 3300.0 / 4095.0 - 500.0;
            assert!((f64::from(temperature_ddegc(c)) - exact).abs() <= 0.5 + 1e-6, "code {c}");
        }
        assert_eq!(temperature_ddegc(0), -500);
        assert_eq!(temperature_ddegc(4095), 2800);
        assert_eq!(temperature_ddegc(u16::MAX), 2800);
    }
}
