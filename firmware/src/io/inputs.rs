//! Digital inputs: polarity and logic state (0x3141), functions (0x3142) and the function bits of 0x60FD, and the
//! limit and home switches with their latched edges for the motion layer.
//!
//! IDX 6.2.66 (seed L4900-4943): 0x3141:01 shows the pin levels before polarity, 0x3141:02 bit n set makes input
//! n+1 active low. IDX 6.2.67 (L4945-5000, Table 6-108): each input holds one function, whose code is also its bit
//! in 0x60FD (IDX 6.2.127, L6625-6659: "after polarity correction").
//!
//! "Limit switch without errors" (codes 24/25, L4987-4988: "Used in some homing modes / does not generate limit
//! errors"): such an input feeds the same [`SwitchEdges`] as a limit switch (codes 0/1), so the homing methods that
//! search a limit switch find it, but its [`InputState::negative_limit_error`] /
//! [`InputState::positive_limit_error`] stay false, so the supervision raises no 0x8A80 / 0x8A81
//! (control-and-protection.md §3.6: "only used by homing"). When both codes of one side are assigned, the input
//! with the error-generating code feeds the switch; among inputs with the same code the lowest-numbered one wins
//! (IDX L4958: "Each function can only be mapped once").

use crate::od::access::Dictionary;
use crate::od::generated::handles as h;
use crate::sensors::latch::{EdgeLatch, PinLatches, SwitchEdges, DIGITAL_INPUTS};

use super::InputState;

/// Input function codes of 0x3142 (IDX Table 6-108, L4974-5000); each is also the bit of 0x60FD it sets.
pub mod function {
    /// Negative limit switch: homing and limit error 0x8A80.
    pub const NEGATIVE_LIMIT: u8 = 0;
    /// Positive limit switch: homing and limit error 0x8A81.
    pub const POSITIVE_LIMIT: u8 = 1;
    /// Home switch.
    pub const HOME_SWITCH: u8 = 2;
    /// General purpose A (B, C, D follow as 17, 18, 19).
    pub const GENERAL_PURPOSE_A: u8 = 16;
    /// General purpose D.
    pub const GENERAL_PURPOSE_D: u8 = 19;
    /// Negative limit switch without errors (homing only).
    pub const NEGATIVE_LIMIT_NO_ERROR: u8 = 24;
    /// Positive limit switch without errors (homing only).
    pub const POSITIVE_LIMIT_NO_ERROR: u8 = 25;
    /// Touch probe (the input that source bits 00 of 0x60B8 select for probe 1).
    pub const TOUCH_PROBE: u8 = 26;
    /// Drive enable.
    pub const DRIVE_ENABLE: u8 = 27;
    /// Quick stop.
    pub const QUICK_STOP: u8 = 28;
    /// No function.
    pub const NONE: u8 = 255;
}

/// The 0x60FD bit of function `code`; 0 for "none" and the reserved codes (3..15, 20..23, 29..254), which the
/// dictionary refuses anyway but a restored parameter image could hold.
#[must_use]
pub const fn function_bit(code: u8) -> u32 {
    match code {
        function::NEGATIVE_LIMIT..=function::HOME_SWITCH
        | function::GENERAL_PURPOSE_A..=function::GENERAL_PURPOSE_D
        | function::NEGATIVE_LIMIT_NO_ERROR..=function::QUICK_STOP => 1u32 << code,
        _ => 0,
    }
}

/// The input configuration of one tick: 0x3141:02 and 0x3142:01..04.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct InputConfig {
    /// 0x3141:02 (bit n set: input n+1 active low), limited to the four inputs.
    pub polarity: u8,
    /// 0x3142:01..04.
    pub functions: [u8; DIGITAL_INPUTS],
}

impl Default for InputConfig {
    /// The defaults of `device.toml` (IDX Table 6-107, CANopen/EtherCAT: 0, 1, 2, 19; polarity 0).
    fn default() -> Self {
        Self { polarity: 0, functions: [function::NEGATIVE_LIMIT, function::POSITIVE_LIMIT, function::HOME_SWITCH, 19] }
    }
}

impl InputConfig {
    /// Reads the configuration from the dictionary.
    #[must_use]
    pub fn read(d: &Dictionary) -> Self {
        // Only the low four bits mean anything (0x3141:02 max 0x000F); the mask makes the cast lossless.
        let polarity = (d.get(h::DIGITAL_INPUTS_POLARITY) & 0x000F) as u8;
        Self {
            polarity,
            functions: [
                d.get(h::DIGITAL_INPUT_1_CONFIGURATION),
                d.get(h::DIGITAL_INPUT_2_CONFIGURATION),
                d.get(h::DIGITAL_INPUT_3_CONFIGURATION),
                d.get(h::DIGITAL_INPUT_4_CONFIGURATION),
            ],
        }
    }

    /// The lowest-numbered input (0-based) assigned function `code`.
    #[must_use]
    pub fn input_with(&self, code: u8) -> Option<usize> {
        // Four compares in a row rather than a search loop: every slow tick asks this several times, and the crate
        // is optimised for size, which keeps such loops rolled.
        let [first, second, third, fourth] = self.functions;
        if first == code {
            Some(0)
        } else if second == code {
            Some(1)
        } else if third == code {
            Some(2)
        } else if fourth == code {
            Some(3)
        } else {
            None
        }
    }

    /// Whether input `input` (0-based) is active low.
    #[must_use]
    pub fn active_low(&self, input: usize) -> bool {
        u32::try_from(input).ok().and_then(|bit| 1u8.checked_shl(bit)).is_some_and(|mask| self.polarity & mask != 0)
    }

    /// The active state of each input, polarity applied: bit n = input n+1 active.
    #[must_use]
    pub const fn active_levels(&self, levels: u8) -> u8 {
        (levels ^ self.polarity) & 0b1111
    }
}

/// The [`SwitchEdges`] of input `input` (0-based): "activated" is the pin edge into the active level (the falling
/// edge of an active-low input), positions moved into the coordinates of 0x6064 by `position_offset` (wrapping,
/// like 0x6064 itself).
#[must_use]
pub fn switch_edges(pins: &PinLatches, config: &InputConfig, input: usize, position_offset: i32) -> SwitchEdges {
    let shift = |latch: Option<&EdgeLatch>| {
        latch.map_or_else(EdgeLatch::default, |l| EdgeLatch {
            count: l.count,
            position: l.position.wrapping_add(position_offset),
        })
    };
    let rising = shift(pins.rising.get(input));
    let falling = shift(pins.falling.get(input));
    let active_low = config.active_low(input);
    let active = u32::try_from(input)
        .ok()
        .and_then(|bit| 1u8.checked_shl(bit))
        .is_some_and(|mask| config.active_levels(pins.levels) & mask != 0);
    if active_low {
        SwitchEdges { active, activated: falling, released: rising }
    } else {
        SwitchEdges { active, activated: rising, released: falling }
    }
}

/// Maps the pin levels and latches to the input functions (pure; see the module docs for codes 24/25).
#[must_use]
pub fn evaluate(pins: &PinLatches, config: &InputConfig, position_offset: i32) -> InputState {
    let active = config.active_levels(pins.levels);
    let mut functions = 0u32;
    for (bit, &code) in config.functions.iter().enumerate() {
        let mask = u32::try_from(bit).ok().and_then(|b| 1u8.checked_shl(b)).unwrap_or(0);
        if active & mask != 0 {
            functions |= function_bit(code);
        }
    }
    let edges = |input: Option<usize>| {
        input.map_or_else(SwitchEdges::default, |i| switch_edges(pins, config, i, position_offset))
    };
    let with_error = |code: u8, no_error: u8| -> (SwitchEdges, bool) {
        match config.input_with(code) {
            Some(i) => {
                let e = edges(Some(i));
                (e, e.active)
            }
            None => (edges(config.input_with(no_error)), false),
        }
    };
    let (negative_limit, negative_limit_error) =
        with_error(function::NEGATIVE_LIMIT, function::NEGATIVE_LIMIT_NO_ERROR);
    let (positive_limit, positive_limit_error) =
        with_error(function::POSITIVE_LIMIT, function::POSITIVE_LIMIT_NO_ERROR);
    InputState {
        functions,
        negative_limit,
        positive_limit,
        home_switch: edges(config.input_with(function::HOME_SWITCH)),
        quick_stop: functions & function_bit(function::QUICK_STOP) != 0,
        // IDX L4985 "Enable/disable the drive": without a drive-enable input the drive is always enabled.
        drive_enable: config.input_with(function::DRIVE_ENABLE).is_none()
            || functions & function_bit(function::DRIVE_ENABLE) != 0,
        negative_limit_error,
        positive_limit_error,
    }
}

/// Publishes 0x3141:01 (levels before polarity) and 0x60FD (function bits after polarity).
pub fn publish(pins: &PinLatches, state: &InputState, d: &mut Dictionary) {
    d.set(h::DIGITAL_INPUTS_LOGIC_STATE, u16::from(pins.levels & 0b1111));
    d.set(h::DIGITAL_INPUTS, state.functions);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::rig::Rig;

    #[test]
    fn function_bits_are_the_codes_and_reserved_codes_set_nothing() {
        assert_eq!(function_bit(function::NEGATIVE_LIMIT), 1);
        assert_eq!(function_bit(function::HOME_SWITCH), 1 << 2);
        assert_eq!(function_bit(18), 1 << 18);
        assert_eq!(function_bit(function::QUICK_STOP), 1 << 28);
        for code in [3, 15, 20, 23, 29, 254, function::NONE] {
            assert_eq!(function_bit(code), 0, "code {code}");
        }
    }

    #[test]
    fn polarity_and_functions_map_into_60fd_and_3141() {
        let mut r = Rig::new();
        // Defaults 0, 1, 2, 19; input 2 active low.
        r.d.set(h::DIGITAL_INPUTS_POLARITY, 0b0010);
        r.pin(0, true, 10);
        r.pin(3, true, 20);
        let s = r.tick();
        // Pins 0b1001; active 0b1011: negative limit (pin high), positive limit (active low, pin low), GP D.
        assert_eq!(r.d.get(h::DIGITAL_INPUTS_LOGIC_STATE), 0b1001);
        assert_eq!(s.inputs.functions, 1 | 1 << 1 | 1 << 19);
        assert_eq!(r.d.get(h::DIGITAL_INPUTS), s.inputs.functions);
        assert!(s.inputs.negative_limit.active && s.inputs.positive_limit.active && !s.inputs.home_switch.active);
        // Reassign: input 1 none, input 4 general purpose A, input 3 home active low (pin low = active).
        r.d.set(h::DIGITAL_INPUT_1_CONFIGURATION, function::NONE);
        r.d.set(h::DIGITAL_INPUT_4_CONFIGURATION, function::GENERAL_PURPOSE_A);
        r.d.set(h::DIGITAL_INPUTS_POLARITY, 0b0110);
        let s = r.tick();
        assert_eq!(s.inputs.functions, 1 << 1 | 1 << 2 | 1 << 16);
        assert!(!s.inputs.negative_limit.active && s.inputs.home_switch.active);
        assert_eq!(r.d.get(h::DIGITAL_INPUTS_LOGIC_STATE), 0b1001, "0x3141:01 is before polarity");
    }

    #[test]
    fn switch_edges_follow_polarity_in_0x6064_coordinates() {
        let mut r = Rig::new();
        r.offset = -500;
        // Home switch (input 3) active low: the falling pin edge is its activation.
        r.d.set(h::DIGITAL_INPUTS_POLARITY, 0b0100);
        r.pin(2, true, 900);
        let s = r.tick();
        assert!(!s.inputs.home_switch.active);
        assert_eq!(s.inputs.home_switch.released, EdgeLatch { count: 1, position: 400 });
        assert_eq!(s.inputs.home_switch.activated.count, 0);
        r.pin(2, false, 1000);
        let s = r.tick();
        assert!(s.inputs.home_switch.active);
        assert_eq!(s.inputs.home_switch.activated, EdgeLatch { count: 1, position: 500 });
        // Positive limit (input 2) active high: the rising pin edge; the offset wraps like 0x6064.
        r.offset = i32::MAX;
        r.pin(1, true, 2);
        let s = r.tick();
        assert!(s.inputs.positive_limit.active);
        assert_eq!(s.inputs.positive_limit.activated, EdgeLatch { count: 1, position: i32::MIN + 1 });
        assert_eq!(s.inputs.positive_limit.released.count, 0);
        assert!(s.inputs.positive_limit_error && !s.inputs.negative_limit_error);
        // Polarity changes swap the roles of the latched edges.
        r.d.set(h::DIGITAL_INPUTS_POLARITY, 0b0010);
        let s = r.tick();
        assert!(!s.inputs.positive_limit.active);
        assert_eq!(s.inputs.positive_limit.released.count, 1);
    }

    #[test]
    fn limits_without_error_feed_switches_but_raise_no_error() {
        let mut r = Rig::new();
        r.d.set(h::DIGITAL_INPUT_1_CONFIGURATION, function::NEGATIVE_LIMIT_NO_ERROR);
        r.d.set(h::DIGITAL_INPUT_2_CONFIGURATION, function::POSITIVE_LIMIT);
        r.pin(0, true, -300);
        r.pin(1, true, 300);
        let s = r.tick();
        assert_eq!(s.inputs.functions, 1 << 24 | 1 << 1);
        assert!(s.inputs.negative_limit.active && !s.inputs.negative_limit_error);
        assert_eq!(s.inputs.negative_limit.activated, EdgeLatch { count: 1, position: -300 });
        assert!(s.inputs.positive_limit.active && s.inputs.positive_limit_error);
        // Function 0 on another input takes precedence over 24 for the switch, and raises the error.
        r.d.set(h::DIGITAL_INPUT_3_CONFIGURATION, function::NEGATIVE_LIMIT);
        let s = r.tick();
        assert!(!s.inputs.negative_limit.active && !s.inputs.negative_limit_error);
        r.pin(2, true, -400);
        let s = r.tick();
        assert!(s.inputs.negative_limit.active && s.inputs.negative_limit_error);
        assert_eq!(s.inputs.negative_limit.activated.position, -400);
    }

    #[test]
    fn drive_enable_and_quick_stop_inputs() {
        let mut r = Rig::new();
        let s = r.tick();
        assert!(s.inputs.drive_enable, "no drive-enable input: enabled");
        assert!(!s.inputs.quick_stop);
        r.d.set(h::DIGITAL_INPUT_4_CONFIGURATION, function::DRIVE_ENABLE);
        r.d.set(h::DIGITAL_INPUT_3_CONFIGURATION, function::QUICK_STOP);
        let s = r.tick();
        assert!(!s.inputs.drive_enable && !s.inputs.quick_stop);
        r.pin(3, true, 0);
        r.pin(2, true, 0);
        let s = r.tick();
        assert!(s.inputs.drive_enable && s.inputs.quick_stop);
        assert_eq!(s.inputs.functions, 1 << 27 | 1 << 28);
        // An active-low quick stop (wire break stops the drive).
        r.d.set(h::DIGITAL_INPUTS_POLARITY, 0b0100);
        let s = r.tick();
        assert!(!s.inputs.quick_stop);
        r.pin(2, false, 0);
        let s = r.tick();
        assert!(s.inputs.quick_stop && s.inputs.drive_enable);
    }
}
