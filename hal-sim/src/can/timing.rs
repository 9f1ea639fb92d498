//! Bit-level timing of a CAN 2.0A (11-bit identifier) data frame on the wire (ISO 11898-1 §10): how many bit
//! times a frame occupies the bus, stuff bits included, so the simulated bus can give each frame its real
//! duration, arbitration its real order and the bus load its real figure.
//!
//! The frame from the start-of-frame bit to the end of the CRC is bit-stuffed: after five consecutive bits of the
//! same level the transmitter inserts one of the opposite level, which itself starts the next run (ISO 11898-1
//! §10.5). The fixed-form tail (CRC delimiter, ACK slot, ACK delimiter, 7 end-of-frame bits) and the 3-bit
//! intermission that must pass before the next start of frame are not stuffed. The CRC is the 15-bit CAN CRC
//! (polynomial 0x4599) over the stuffed region before the CRC itself; it decides the stuff bits of the tail of
//! the frame, so it is computed, not estimated.

/// Bits after the CRC that are never stuffed: CRC delimiter, ACK slot, ACK delimiter and end of frame (1 + 1 + 1
/// + 7).
pub const TAIL_BITS: u32 = 10;

/// Intermission between frames (ISO 11898-1 §10.4.6.2): the bus is not free for a new start of frame before it.
pub const INTERMISSION_BITS: u32 = 3;

/// Bits an error frame costs with the intermission: a 6-bit error flag that may overlap the receivers' echo (6
/// to 12 bits; the simulation takes the 6 + 6 worst case), an 8-bit error delimiter and the intermission.
pub const ERROR_FRAME_BITS: u32 = 12 + 8 + INTERMISSION_BITS;

/// Bit times the bus must stay recessive before a bus-off node may take part again (ISO 11898-1 §12.1.4.2: 128
/// occurrences of 11 consecutive recessive bits).
pub const BUS_OFF_RECOVERY_BITS: u32 = 128 * 11;

/// The CAN CRC-15 (generator x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1) of `bits`, MSB first.
pub fn crc15(bits: &[bool]) -> u16 {
    let mut crc: u16 = 0;
    for &bit in bits {
        let feedback = bit ^ (crc & 0x4000 != 0);
        crc = (crc << 1) & 0x7FFF;
        if feedback {
            crc ^= 0x4599;
        }
    }
    crc
}

/// The unstuffed bits of a data or remote frame from start of frame through the CRC: SOF, 11 identifier bits,
/// RTR, IDE (0: standard), r0, the 4-bit DLC, the data (none for a remote frame) and the 15 CRC bits. Dominant is
/// `false`. `id` keeps its low 11 bits; `dlc` its low 4.
pub fn stuffed_region(id: u16, rtr: bool, dlc: u8, data: &[u8]) -> Vec<bool> {
    let mut bits = Vec::with_capacity(34 + 64 + 15);
    bits.push(false); // start of frame, dominant
    for k in (0..11).rev() {
        bits.push(id >> k & 1 != 0);
    }
    bits.push(rtr);
    bits.push(false); // IDE: standard identifier
    bits.push(false); // r0
    for k in (0..4).rev() {
        bits.push(dlc >> k & 1 != 0);
    }
    if !rtr {
        for byte in data {
            for k in (0..8).rev() {
                bits.push(byte >> k & 1 != 0);
            }
        }
    }
    let crc = crc15(&bits);
    for k in (0..15).rev() {
        bits.push(crc >> k & 1 != 0);
    }
    bits
}

/// `bits` with the stuff bits inserted (ISO 11898-1 §10.5).
pub fn stuff(bits: &[bool]) -> Vec<bool> {
    let mut out = Vec::with_capacity(bits.len() + bits.len() / 4 + 1);
    let mut run = 0u32;
    let mut last = None;
    for &bit in bits {
        if Some(bit) == last {
            run += 1;
        } else {
            run = 1;
            last = Some(bit);
        }
        out.push(bit);
        if run == 5 {
            // The stuff bit has the other level and starts a new run of one.
            out.push(!bit);
            last = Some(!bit);
            run = 1;
        }
    }
    out
}

/// Bit times a standard data or remote frame occupies the bus, stuff bits, the fixed tail and the intermission
/// included: 47 + 8 x data bytes without stuff bits, at most 24 stuff bits more for 8 data bytes (111..=135).
/// `dlc` is the data length code sent (for a remote frame, the length asked for; for a data frame the length of
/// `data`, at most 8).
pub fn frame_bits(id: u16, rtr: bool, dlc: u8, data: &[u8]) -> u32 {
    let len = data.len().min(8);
    let dlc = if rtr { dlc.min(8) } else { len as u8 };
    let region = stuffed_region(id & 0x7FF, rtr, dlc, &data[..len]);
    stuff(&region).len() as u32 + TAIL_BITS + INTERMISSION_BITS
}

/// Duration of `bits` bit times at `bit_rate` bit/s, in ns (rounded up: a frame never ends early).
pub fn bits_to_ns(bits: u32, bit_rate: u32) -> u64 {
    (u64::from(bits) * 1_000_000_000).div_ceil(u64::from(bit_rate.max(1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Removes the stuff bits again (what a receiver does), or `None` at a stuff error (six equal bits).
    fn destuff(bits: &[bool]) -> Option<Vec<bool>> {
        let mut out = Vec::new();
        let mut run = 0u32;
        let mut last = None;
        let mut skip = false;
        for &bit in bits {
            if skip {
                if Some(bit) == last {
                    return None;
                }
                skip = false;
                run = 1;
                last = Some(bit);
                continue;
            }
            if Some(bit) == last {
                run += 1;
            } else {
                run = 1;
                last = Some(bit);
            }
            out.push(bit);
            if run == 5 {
                skip = true;
            }
        }
        Some(out)
    }

    #[test]
    fn stuffing_never_leaves_six_equal_bits_and_a_receiver_recovers_the_frame() {
        let mut seed = 0x1234_5678u32;
        for _ in 0..2_000 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let id = (seed >> 8) as u16 & 0x7FF;
            let len = (seed >> 20) as usize % 9;
            let data: Vec<u8> = (0..len).map(|k| (seed >> (k % 4 * 8)) as u8 ^ (k as u8).wrapping_mul(37)).collect();
            let region = stuffed_region(id, false, len as u8, &data);
            let wire = stuff(&region);
            assert!(wire.windows(6).all(|w| w.iter().any(|&b| b != w[0])), "six equal bits in {id:03x} {data:02x?}");
            assert_eq!(destuff(&wire).as_deref(), Some(&region[..]), "destuffed {id:03x} {data:02x?}");
        }
    }

    #[test]
    fn the_crc_of_a_frame_with_its_crc_appended_is_zero() {
        // A CRC register fed with the message and then its own CRC ends at zero: the check a receiver makes.
        for (id, data) in [(0x000u16, vec![]), (0x705, vec![0x05]), (0x581, vec![0x43, 0x00, 0x10, 0, 0x92, 1, 2, 0])] {
            let region = stuffed_region(id, false, data.len() as u8, &data);
            assert_eq!(crc15(&region), 0, "{id:03x}");
        }
    }

    #[test]
    fn frame_lengths_stay_within_the_unstuffed_and_worst_case_bounds() {
        // 8 data bytes: 111 bits unstuffed, 135 with the most stuff bits (the textbook bounds for CAN 2.0A).
        for data in [[0u8; 8], [0xFF; 8], [0x55; 8], [0x0F; 8]] {
            let bits = frame_bits(0x181, false, 8, &data);
            assert!((111..=135).contains(&bits), "{data:02x?}: {bits}");
        }
        // All-zero identifier and data: every fifth bit is a stuff bit over most of the frame.
        assert!(frame_bits(0x000, false, 8, &[0; 8]) > 125);
        // Alternating bits need no stuffing in the data field.
        let plain = 47 + 64;
        assert!(frame_bits(0x555, false, 8, &[0x55; 8]) - plain < 6);
        // A zero-length frame (NMT-free SYNC 0x080): 47 bits plus its stuff bits.
        let sync = frame_bits(0x080, false, 0, &[]);
        assert!((47..=47 + 8).contains(&sync), "{sync}");
    }

    #[test]
    fn a_frame_takes_its_bit_count_in_bit_times() {
        assert_eq!(bits_to_ns(111, 1_000_000), 111_000);
        assert_eq!(bits_to_ns(135, 500_000), 270_000);
        assert_eq!(bits_to_ns(1, 3), 333_333_334, "rounded up");
    }
}
