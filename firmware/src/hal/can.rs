//! CAN bit timing (ISO 11898-1 §11.3.1; issue 8): the bit time divided into time quanta of `prescaler` controller
//! clock periods: one synchronisation quantum, `seg1` quanta (propagation and phase segment 1) up to the sample
//! point, `seg2` quanta (phase segment 2) after it. Pure arithmetic, so that the board's bxCAN driver
//! (`board::can`, target only) gets its register value from a function the host tests check.
//!
//! **Choice.** [`bit_timing`] takes only settings that give the rate exactly (an integer prescaler and quantum
//! count), with the sample point nearest [`SAMPLE_POINT_PERMILLE`] (87.5 %, what CiA 301 recommends up to
//! 1 Mbit/s), phase segment 2 at least 2 quanta so that the resynchronisation jump width can be 2, and, among
//! equally good sample points, the most quanta (finer resynchronisation). The limits are the bxCAN's field widths
//! (RM0090 §32.9.2 CAN_BTR): prescaler 1..=1024, `seg1` 1..=16, `seg2` 1..=8; 8..=25 quanta per bit.
//!
//! With the reference board's APB1 clock of 42 MHz (`board::clock`), every 0x2001 rate but 800 kbit/s is exact:
//!
//! | 0x2001 | rate | prescaler | quanta | seg1 | seg2 | SJW | sample point | rate from 42 MHz | CAN_BTR |
//! |---|---|---|---|---|---|---|---|---|---|
//! | 0 | 1 Mbit/s | 3 | 14 | 11 | 2 | 2 | 85.7 % | 1,000,000 | `0x011A_0002` |
//! | 1 | 800 kbit/s | — | — | — | — | — | — | none: 42 MHz / 800 kbit/s = 52.5 | — |
//! | 2 | 500 kbit/s | 6 | 14 | 11 | 2 | 2 | 85.7 % | 500,000 | `0x011A_0005` |
//! | 3 | 250 kbit/s | 12 | 14 | 11 | 2 | 2 | 85.7 % | 250,000 | `0x011A_000B` |
//! | 4 | 125 kbit/s | 21 | 16 | 13 | 2 | 2 | 87.5 % | 125,000 | `0x011C_0014` |
//! | 6 | 50 kbit/s | 56 | 15 | 12 | 2 | 2 | 86.7 % | 50,000 | `0x011B_0037` |
//! | 7 | 20 kbit/s | 140 | 15 | 12 | 2 | 2 | 86.7 % | 20,000 | `0x011B_008B` |
//!
//! 800 kbit/s: the nearest settings (52 clocks per bit, 807.7 kbit/s) are 0.96 % off, more than the 0.6 %
//! oscillator tolerance those 13 quanta allow (ISO 11898-1 / CiA 301 tolerance formula with phase segment 2 =
//! 2 quanta); so the board refuses it rather than run a rate that fails against an exact master. It would need
//! an APB1 clock that 800 kHz divides (e.g. 40 or 48 MHz).

/// The sample point aimed at, per mille of the bit time (CiA 301 recommends 87.5 %).
pub const SAMPLE_POINT_PERMILLE: u32 = 875;

/// Highest baud-rate prescaler (bxCAN BRP is 10 bits, value - 1).
pub const MAX_PRESCALER: u32 = 1024;
/// Fewest and most time quanta per bit (1 + seg1 + seg2 with the field limits below).
pub const QUANTA: core::ops::RangeInclusive<u32> = 8..=25;
/// Longest time segment 1 (bxCAN TS1 is 4 bits, value - 1).
pub const MAX_SEG1: u32 = 16;
/// Shortest phase segment 2 this choice takes (2: room for a jump width of 2) and the longest (bxCAN TS2 is 3
/// bits, value - 1).
pub const SEG2: core::ops::RangeInclusive<u32> = 2..=8;
/// The resynchronisation jump width used (at most `seg2`).
pub const SJW: u8 = 2;

/// Bit timing: see the module documentation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BitTiming {
    /// Controller clock periods per time quantum (1..=1024).
    pub prescaler: u16,
    /// Quanta from the end of the synchronisation segment to the sample point (1..=16).
    pub seg1: u8,
    /// Quanta from the sample point to the end of the bit (2..=8).
    pub seg2: u8,
    /// Resynchronisation jump width, quanta (1..=4, at most `seg2`).
    pub sjw: u8,
}

impl BitTiming {
    /// Time quanta per bit.
    pub const fn quanta(self) -> u32 {
        1u32.wrapping_add(self.seg1 as u32).wrapping_add(self.seg2 as u32)
    }

    /// The sample point, per mille of the bit time (rounded down).
    pub const fn sample_point_permille(self) -> u32 {
        match (1u32.wrapping_add(self.seg1 as u32)).wrapping_mul(1000).checked_div(self.quanta()) {
            Some(p) => p,
            None => 0,
        }
    }

    /// The bit rate this timing gives from a controller clock of `clock_hz` (rounded down).
    pub const fn bit_rate(self, clock_hz: u32) -> u32 {
        match clock_hz.checked_div((self.prescaler as u32).wrapping_mul(self.quanta())) {
            Some(r) => r,
            None => 0,
        }
    }

    /// The bxCAN CAN_BTR value (RM0090 §32.9.2): BRP (bits 9..0) = prescaler - 1, TS1 (bits 19..16) = seg1 - 1,
    /// TS2 (bits 22..20) = seg2 - 1, SJW (bits 25..24) = sjw - 1; loop-back and silent mode off.
    pub const fn bxcan_btr(self) -> u32 {
        let brp = (self.prescaler as u32).wrapping_sub(1) & 0x3FF;
        let ts1 = (self.seg1 as u32).wrapping_sub(1) & 0xF;
        let ts2 = (self.seg2 as u32).wrapping_sub(1) & 0x7;
        let sjw = (self.sjw as u32).wrapping_sub(1) & 0x3;
        brp | (ts1 << 16) | (ts2 << 20) | (sjw << 24)
    }
}

/// The timing for exactly `bits_per_second` from a controller clock of `clock_hz` (see the module documentation
/// for the choice), or `None` when no prescaler and quantum count give the rate exactly. A `const fn`, so that a
/// board evaluates it for its clock at build time ([`timings`]) instead of searching at run time.
pub const fn bit_timing(clock_hz: u32, bits_per_second: u32) -> Option<BitTiming> {
    let Some(clocks_per_bit) = clock_hz.checked_div(bits_per_second) else { return None };
    match bits_per_second.checked_mul(clocks_per_bit) {
        Some(c) if c == clock_hz => {}
        _ => return None,
    }
    let mut best: Option<(u32, BitTiming)> = None;
    // Most quanta first, so that a later candidate replaces an earlier one only with a better sample point.
    let mut quanta = *QUANTA.end();
    while quanta >= *QUANTA.start() {
        let prescaler = match (clocks_per_bit.checked_rem(quanta), clocks_per_bit.checked_div(quanta)) {
            (Some(0), Some(p)) => p,
            _ => 0,
        };
        if prescaler != 0 && prescaler <= MAX_PRESCALER {
            let mut seg2 = *SEG2.start();
            while seg2 <= *SEG2.end() {
                let seg1 = quanta.saturating_sub(seg2).saturating_sub(1);
                if seg1 != 0 && seg1 <= MAX_SEG1 && seg1.saturating_add(seg2).saturating_add(1) == quanta {
                    // In range: prescaler <= 1024, seg1 <= 16, seg2 <= 8 (checked above / by SEG2).
                    let timing = BitTiming {
                        prescaler: prescaler as u16,
                        seg1: seg1 as u8,
                        seg2: seg2 as u8,
                        sjw: if SJW < seg2 as u8 { SJW } else { seg2 as u8 },
                    };
                    let error = timing.sample_point_permille().abs_diff(SAMPLE_POINT_PERMILLE);
                    let better = match best {
                        Some((e, _)) => error < e,
                        None => true,
                    };
                    if better {
                        best = Some((error, timing));
                    }
                }
                seg2 = seg2.wrapping_add(1);
            }
        }
        quanta = quanta.wrapping_sub(1);
    }
    match best {
        Some((_, timing)) => Some(timing),
        None => None,
    }
}

/// The timing of every 0x2001 rate from `clock_hz`, in the order of [`BitRate::ALL`] (`None`: not exact);
/// meant to be evaluated at build time (`const`), so that the image carries the table, not the search.
pub const fn timings(clock_hz: u32) -> [Option<BitTiming>; BitRate::ALL.len()] {
    let mut table = [None; BitRate::ALL.len()];
    let mut i = 0;
    while i < table.len() {
        // In bounds: i < table.len() = BitRate::ALL.len(). Const evaluation would fail the build otherwise.
        #[allow(clippy::indexing_slicing)]
        {
            table[i] = bit_timing(clock_hz, BitRate::ALL[i].bits_per_second());
        }
        i = i.wrapping_add(1);
    }
    table
}

use crate::canopen::frame::BitRate;

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference board's APB1 clock (`board::clock`: 168 MHz / 4).
    const APB1_HZ: u32 = 42_000_000;

    /// The build-time table holds, for each rate of [`BitRate::ALL`] (whose order is `index()`), what the search
    /// gives at run time.
    #[test]
    fn the_build_time_table_is_the_search_for_every_rate() {
        const TABLE: [Option<BitTiming>; 7] = timings(APB1_HZ);
        for (i, rate) in BitRate::ALL.iter().enumerate() {
            assert_eq!(rate.index(), i);
            assert_eq!(BitRate::from_code(rate.code()), Some(*rate));
            assert_eq!(TABLE[i], bit_timing(APB1_HZ, rate.bits_per_second()), "{rate:?}");
        }
        assert!(TABLE[BitRate::Kbit800.index()].is_none(), "800 kbit/s is not exact from 42 MHz");
        assert_eq!(TABLE[BitRate::Kbit1000.index()].map(BitTiming::bxcan_btr), Some(0x011A_0002));
    }

    /// Proves the table of the module documentation: for every 0x2001 rate the timing chosen from 42 MHz, its
    /// exact rate, its sample point (85.7..87.5 %, within 2 % of CiA 301's 87.5 %) and its CAN_BTR value; and
    /// that 800 kbit/s has no exact timing.
    #[test]
    fn the_bit_rates_of_0x2001_from_42_mhz() {
        let table = [
            (BitRate::Kbit1000, Some((3, 11, 2, 857, 0x011A_0002))),
            (BitRate::Kbit800, None),
            (BitRate::Kbit500, Some((6, 11, 2, 857, 0x011A_0005))),
            (BitRate::Kbit250, Some((12, 11, 2, 857, 0x011A_000B))),
            (BitRate::Kbit125, Some((21, 13, 2, 875, 0x011C_0014))),
            (BitRate::Kbit50, Some((56, 12, 2, 866, 0x011B_0037))),
            (BitRate::Kbit20, Some((140, 12, 2, 866, 0x011B_008B))),
        ];
        for (rate, expected) in table {
            let timing = bit_timing(APB1_HZ, rate.bits_per_second());
            let Some((prescaler, seg1, seg2, sample, btr)) = expected else {
                assert_eq!(timing, None, "{rate:?}");
                continue;
            };
            let t = timing.unwrap_or_else(|| panic!("{rate:?} has a timing"));
            assert_eq!((t.prescaler, t.seg1, t.seg2, t.sjw), (prescaler, seg1, seg2, 2), "{rate:?}");
            assert_eq!(t.bit_rate(APB1_HZ), rate.bits_per_second(), "{rate:?} exact");
            assert_eq!(
                u64::from(t.prescaler) * u64::from(t.quanta()) * u64::from(rate.bits_per_second()),
                u64::from(APB1_HZ),
                "{rate:?}: no remainder"
            );
            assert_eq!(t.sample_point_permille(), sample, "{rate:?}");
            assert!(t.sample_point_permille().abs_diff(SAMPLE_POINT_PERMILLE) <= 20, "{rate:?}");
            assert!(QUANTA.contains(&t.quanta()) && t.sjw <= t.seg2, "{rate:?}");
            assert_eq!(t.bxcan_btr(), btr, "{rate:?}: CAN_BTR {:#010x}", t.bxcan_btr());
        }
    }

    /// Proves the search keeps to the field limits and to exact rates: from clocks that do divide (48 MHz gives
    /// 800 kbit/s at 86.7 %, 15 quanta) and that do not, and for rates of 0 and above the clock.
    #[test]
    fn timings_are_exact_and_within_the_bxcan_fields() {
        let t = bit_timing(48_000_000, 800_000).expect("48 MHz / 800 kbit/s = 60 clocks per bit");
        assert_eq!((t.prescaler, t.quanta(), t.sample_point_permille()), (4, 15, 866));
        assert_eq!(bit_timing(42_000_000, 0), None);
        assert_eq!(bit_timing(42_000_000, 84_000_000), None);
        assert_eq!(bit_timing(42_000_000, 1_000_001), None);
        for clock in [8_000_000u32, 36_000_000, 42_000_000, 45_000_000, 48_000_000] {
            for rate in [10_000u32, 20_000, 33_333, 50_000, 83_333, 100_000, 125_000, 250_000, 500_000, 1_000_000] {
                if let Some(t) = bit_timing(clock, rate) {
                    assert_eq!(t.bit_rate(clock), rate);
                    assert_eq!(u64::from(t.prescaler) * u64::from(t.quanta()) * u64::from(rate), u64::from(clock));
                    assert!(t.prescaler >= 1 && u32::from(t.prescaler) <= MAX_PRESCALER);
                    assert!(t.seg1 >= 1 && u32::from(t.seg1) <= MAX_SEG1 && SEG2.contains(&u32::from(t.seg2)));
                }
            }
        }
    }
}
