//! Sensor models that are pure functions of the true state: ADC quantisation, incremental encoder with index,
//! Hall sensors.

use core::f64::consts::PI;

/// Mid-scale code of the 12-bit shunt channels: the code of zero current before offsets.
pub const ADC_MID_SCALE: f64 = 2048.0;

/// Quantise an ideal ADC input, expressed in LSB, to a 12-bit code: round to nearest, clamp to 0..=4095.
pub fn adc_code(lsb: f64) -> u16 {
    let max = f64::from(firmware::hal::power::ADC_FULL_SCALE);
    if lsb.is_nan() {
        return 0;
    }
    // In range after the clamp, so the cast is exact.
    lsb.round().clamp(0.0, max) as u16
}

/// Total (unwrapped) encoder count at mechanical angle `theta_m_rad`: `floor(theta_m / 2pi * cpr) + offset`.
/// Count `n` is the quadrature state covering angles `[n, n + 1)` counts.
pub fn encoder_count(theta_m_rad: f64, counts_per_rev: u32, offset_counts: i64) -> i64 {
    // Angles stay far below 2^53 counts in any simulation, so the float-to-int conversion is exact.
    (theta_m_rad / (2.0 * PI) * f64::from(counts_per_rev)).floor() as i64 + offset_counts
}

/// The 16-bit encoder-mode timer counter for a total count (wraps like the hardware counter: at 2^16, whatever
/// the counts per revolution; for a resolution that does not divide 2^16 the counter value at the index differs
/// from turn to turn, as on the hardware).
pub fn counter_register(total_count: i64) -> u16 {
    // Deliberate truncation: the timer counter keeps the low 16 bits.
    total_count as u16
}

/// If the count moved from `previous` to `now` and entered the index state (a count congruent to `index_count`
/// modulo `counts_per_rev`) on the way, the total count of the last index state entered. Moving forward the states
/// `previous + 1 ..= now` are entered, moving backward `now ..= previous - 1`; the index pulse is one quadrature
/// state wide, so the same counter value is latched in both directions.
pub fn index_entry(previous: i64, now: i64, counts_per_rev: u32, index_count: u32) -> Option<i64> {
    let cpr = i64::from(counts_per_rev);
    let idx = i64::from(index_count);
    if now > previous {
        // The largest n <= now with n = idx (mod cpr).
        let n = now - (now - idx).rem_euclid(cpr);
        (n > previous).then_some(n)
    } else if now < previous {
        // The smallest n >= now with n = idx (mod cpr).
        let n = now + (idx - now).rem_euclid(cpr);
        (n < previous).then_some(n)
    } else {
        None
    }
}

/// The SSI absolute encoder's position at mechanical angle `theta_m_rad` (`floor(theta_m / 2pi * 2^st) +
/// offset`, modulo its `2^(mt + st)` increments) and the frame it clocks out for it: start bit 1, the position
/// MSB first (Gray coded when `gray`: `b ^ (b >> 1)`), stop bit 0 (the frame bits only with `frame_check`).
pub fn ssi_frame(theta_m_rad: f64, st: u32, mt: u32, gray: bool, frame_check: bool, offset: i64) -> u32 {
    let bits = st + mt;
    let count = (theta_m_rad / (2.0 * PI) * f64::from(1u32 << st)).floor() as i64 + offset;
    // The position wraps at 2^(mt + st) (<= 32 bits with the frame bits): the truncation is the sensor's.
    let position = (count.rem_euclid(1i64 << bits)) as u32;
    let data = if gray { position ^ (position >> 1) } else { position };
    if frame_check {
        (1 << (bits + 1)) | (data << 1)
    } else {
        data
    }
}

/// Hall state (bit 0 = H1, bit 1 = H2, bit 2 = H3) at electrical angle `theta_e_rad`.
///
/// Each sensor is high for 180 degrees electrical: H1 on `[offset, offset + 180)`, H2 on `[offset + 120,
/// offset + 300)`, H3 on `[offset + 240, offset + 420)`. Over one electrical turn in the positive direction,
/// starting at `offset`, the states are 5, 1, 3, 2, 6, 4 (0b101, 0b001, 0b011, 0b010, 0b110, 0b100), 60 degrees
/// each; 0 and 7 never occur. With the reference offset 0, sector `k` (`[60k, 60k + 60)` degrees after the d axis
/// passes phase A) has state `[5, 1, 3, 2, 6, 4][k]`.
pub fn hall_state(theta_e_rad: f64, offset_rad: f64) -> u8 {
    const SEQUENCE: [u8; 6] = [0b101, 0b001, 0b011, 0b010, 0b110, 0b100];
    let x = (theta_e_rad - offset_rad).rem_euclid(2.0 * PI);
    // x in [0, 2pi): the sector is 0..=5 (min guards the rounding case x * 3/pi == 6).
    let sector = ((x * 3.0 / PI) as usize).min(5);
    SEQUENCE[sector]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adc_rounds_and_clamps() {
        assert_eq!(adc_code(2048.4), 2048);
        assert_eq!(adc_code(2048.6), 2049);
        assert_eq!(adc_code(-3.0), 0);
        assert_eq!(adc_code(5000.0), 4095);
    }

    #[test]
    fn index_entries() {
        assert_eq!(index_entry(4095, 4096, 4096, 0), Some(4096));
        assert_eq!(index_entry(4096, 4100, 4096, 0), None);
        assert_eq!(index_entry(4097, 4096, 4096, 0), Some(4096));
        assert_eq!(index_entry(4096, 4095, 4096, 0), None);
        assert_eq!(index_entry(1, -1, 4096, 4095), Some(-1));
        assert_eq!(counter_register(-1), 0xFFFF);
        assert_eq!(encoder_count(-1e-9, 4096, 0), -1);
    }

    /// A resolution that does not divide 2^16 (5,000 counts, 1,250 lines) with the index at count 17: over 40
    /// turns both ways the index is entered once per turn, exactly `cpr` apart, and the 16-bit counter at the
    /// index differs from turn to turn (65,536 mod 5,000 = 536) while the wrapped difference of two latches is
    /// still one turn.
    #[test]
    fn index_entries_at_a_resolution_that_does_not_divide_the_counter() {
        let cpr = 5_000_u32;
        let mut latches = Vec::new();
        let mut previous = -3;
        for now in (-2..200_000_i64).step_by(7).chain((-3..200_000).rev().step_by(11)) {
            if let Some(n) = index_entry(previous, now, cpr, 17) {
                latches.push(n);
            }
            previous = now;
        }
        assert_eq!(latches.len(), 80, "40 turns forward, 40 back");
        assert!(latches.iter().all(|n| n.rem_euclid(5_000) == 17));
        assert!(latches.windows(2).all(|w| (w[1] - w[0]).abs() == 5_000 || w[1] == w[0]));
        let counters: Vec<u16> = latches.iter().map(|&n| counter_register(n)).collect();
        assert_eq!(counters[0], 17);
        assert_eq!(counters[14], (14 * 5_000 + 17 - 65_536) as u16, "wrapped past 2^16");
        assert!(counters.windows(2).all(|w| w[1].wrapping_sub(w[0]) as i16 == 5_000
            || w[0] == w[1]
            || w[1].wrapping_sub(w[0]) as i16 == -5_000));
    }

    #[test]
    fn hall_sectors() {
        let deg = PI / 180.0;
        let states: Vec<u8> = (0..6).map(|k| hall_state((30.0 + 60.0 * f64::from(k)) * deg, 0.0)).collect();
        assert_eq!(states, [5, 1, 3, 2, 6, 4]);
        assert_eq!(hall_state(-30.0 * deg, 0.0), 4);
    }
}
