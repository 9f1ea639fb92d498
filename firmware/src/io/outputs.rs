//! Digital outputs: functions (0x3151), polarity and logic state (0x3150), the master's outputs 0x60FE:01 and the
//! holding brake (0x3158).
//!
//! IDX 6.2.68-6.2.70 (seed L5002-5162) and 6.2.128 (L6661-6712):
//! * Each output holds one function (Table 6-111): 0 "set brake (GPIO)", driven by the master through 0x60FE:01
//!   bit 0 "to drive a brake operated by the host in conformance to CiA 402"; 16/17 general purpose A/B, 0x60FE:01
//!   bits 16/17; 24 holding brake, driven by the drive: active (energised) while the CiA 402 machine requests
//!   the brake released, so a permanent-magnet brake holds whenever the output is off (L5107: Figure 6-38 is drawn for
//!   "High active" polarity); 25 ready/fault, "active on device ready / inactive on device fault state".
//! * 0x60FE:01 holds the function states before polarity; bits 0..23 are written by the master, bits 24..31 are
//!   read only (L6678) and show the drive-driven functions: the drive writes bit 24 (holding brake energised) and
//!   bit 25 (ready) back each tick and keeps the master's bits 0..23.
//! * 0x3150:02 bit n set inverts output n+1 ("1 in 0x60FE will set the output pin low", L5033); 0x3150:01 shows
//!   the pin levels after polarity.
//! * 0x3158:03 holding brake state (Table 6-112): 1 active (engaged), 0 inactive; it follows the request of the
//!   machine, which already waits the rise and fall times (0x3158:01/02, see `cia402::machine`). Without an output
//!   with function 24 there is no brake and the state stays 0.

use crate::cia402::machine::Brake;
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// Number of digital outputs (0x3150, 0x3151: outputs 1 and 2).
pub const DIGITAL_OUTPUTS: usize = 2;

/// Output function codes of 0x3151 (IDX Table 6-111).
pub mod function {
    /// Set brake (GPIO): 0x60FE:01 bit 0, driven by the master.
    pub const SET_BRAKE: u8 = 0;
    /// General purpose A: 0x60FE:01 bit 16.
    pub const GENERAL_PURPOSE_A: u8 = 16;
    /// General purpose B: 0x60FE:01 bit 17.
    pub const GENERAL_PURPOSE_B: u8 = 17;
    /// Holding brake, driven by the drive (0x60FE:01 bit 24, read only).
    pub const HOLDING_BRAKE: u8 = 24;
    /// Ready/fault (0x60FE:01 bit 25, read only).
    pub const READY_FAULT: u8 = 25;
    /// No function.
    pub const NONE: u8 = 255;
}

/// The bits of 0x60FE:01 the master writes (IDX L6678: bits 0..23 RW, 24..31 RO).
pub const MASTER_BITS: u32 = 0x00FF_FFFF;

/// The output configuration of one tick: 0x3150:02 and 0x3151:01/02.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct OutputConfig {
    /// 0x3150:02 (bit n set: output n+1 inverted), limited to the two outputs.
    pub polarity: u8,
    /// 0x3151:01/02.
    pub functions: [u8; DIGITAL_OUTPUTS],
}

impl Default for OutputConfig {
    /// The defaults of `device.toml` (IDX Table 6-110: general purpose A and B, polarity 0).
    fn default() -> Self {
        Self { polarity: 0, functions: [function::GENERAL_PURPOSE_A, function::GENERAL_PURPOSE_B] }
    }
}

impl OutputConfig {
    /// Reads the configuration from the dictionary.
    #[must_use]
    pub fn read(d: &Dictionary) -> Self {
        // 0x3150:02 max 0x0003; the mask makes the cast lossless.
        let polarity = (d.get(h::DIGITAL_OUTPUTS_POLARITY) & 0x0003) as u8;
        Self {
            polarity,
            functions: [d.get(h::DIGITAL_OUTPUT_1_CONFIGURATION), d.get(h::DIGITAL_OUTPUT_2_CONFIGURATION)],
        }
    }

    /// Whether an output drives the holding brake (function 24).
    #[must_use]
    pub fn brake_present(&self) -> bool {
        // Two compares: `contains` stays a loop in a crate optimised for size, and every slow tick asks.
        let [first, second] = self.functions;
        first == function::HOLDING_BRAKE || second == function::HOLDING_BRAKE
    }
}

/// The function states of 0x60FE:01: the master's bits 0..23 and the drive's bits 24 (holding brake energised,
/// i.e. released) and 25 (ready).
#[must_use]
pub fn physical_outputs(master: u32, brake: Brake, ready: bool) -> u32 {
    let released = u32::from(brake == Brake::Released) << function::HOLDING_BRAKE;
    let ready = u32::from(ready) << function::READY_FAULT;
    (master & MASTER_BITS) | released | ready
}

/// The pin levels (bit n = output n+1, polarity applied) for the function states `physical` (0x60FE:01 layout).
#[must_use]
pub fn pin_levels(config: &OutputConfig, physical: u32) -> u8 {
    let mut pins = 0u8;
    for (bit, &code) in config.functions.iter().enumerate() {
        // Function codes 0, 16, 17, 24 and 25 are their own bit in 0x60FE:01; "none" and anything else is off.
        let state = match code {
            function::SET_BRAKE
            | function::GENERAL_PURPOSE_A
            | function::GENERAL_PURPOSE_B
            | function::HOLDING_BRAKE
            | function::READY_FAULT => physical.checked_shr(u32::from(code)).is_some_and(|v| v & 1 != 0),
            _ => false,
        };
        let mask = u32::try_from(bit).ok().and_then(|b| 1u8.checked_shl(b)).unwrap_or(0);
        let inverted = config.polarity & mask != 0;
        if state != inverted {
            pins |= mask;
        }
    }
    pins
}

/// Drives the outputs for one tick: reads the configuration and 0x60FE:01, writes back 0x60FE:01 bits 24/25,
/// publishes 0x3150:01 and 0x3158:03 and returns the configuration with the pin levels.
pub fn step(brake: Brake, ready: bool, d: &mut Dictionary) -> (OutputConfig, u8) {
    let config = OutputConfig::read(d);
    let master = d.get(h::PHYSICAL_OUTPUTS);
    let physical = physical_outputs(master, brake, ready);
    if physical != master {
        d.set(h::PHYSICAL_OUTPUTS, physical);
    }
    let pins = pin_levels(&config, physical);
    d.set(h::DIGITAL_OUTPUTS_LOGIC_STATE, u16::from(pins));
    let engaged = config.brake_present() && brake == Brake::Engaged;
    d.set(h::BRAKE_STATE, u8::from(engaged));
    (config, pins)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::rig::Rig;

    #[test]
    fn general_purpose_outputs_follow_60fe_with_polarity() {
        let mut r = Rig::new();
        assert_eq!(r.tick().output_pins, 0);
        r.d.set(h::PHYSICAL_OUTPUTS, 1 << 16);
        assert_eq!(r.tick().output_pins, 0b01);
        r.d.set(h::PHYSICAL_OUTPUTS, 1 << 17);
        assert_eq!(r.tick().output_pins, 0b10);
        assert_eq!(r.d.get(h::DIGITAL_OUTPUTS_LOGIC_STATE), 0b10);
        // Output 2 inverted: its function is on, its pin low; output 1 inverted: off, so high.
        r.d.set(h::DIGITAL_OUTPUTS_POLARITY, 0b11);
        assert_eq!(r.tick().output_pins, 0b01);
        assert_eq!(r.d.get(h::DIGITAL_OUTPUTS_LOGIC_STATE), 0b01, "0x3150:01 is after polarity");
        // No function: off (and inverted: high).
        r.d.set(h::DIGITAL_OUTPUT_2_CONFIGURATION, function::NONE);
        r.d.set(h::DIGITAL_OUTPUTS_POLARITY, 0b00);
        assert_eq!(r.tick().output_pins, 0b00);
    }

    #[test]
    fn set_brake_output_follows_the_master() {
        let mut r = Rig::new();
        r.d.set(h::DIGITAL_OUTPUT_2_CONFIGURATION, function::SET_BRAKE);
        r.brake = Brake::Released;
        assert_eq!(r.tick().output_pins, 0);
        r.d.set(h::PHYSICAL_OUTPUTS, 1);
        assert_eq!(r.tick().output_pins, 0b10);
        assert!(!r.io.brake_present(), "a master-driven brake is not the drive's holding brake");
        assert_eq!(r.d.get(h::BRAKE_STATE), 0);
    }

    #[test]
    fn holding_brake_output_follows_the_request() {
        let mut r = Rig::new();
        assert!(!r.io.brake_present());
        r.d.set(h::DIGITAL_OUTPUT_1_CONFIGURATION, function::HOLDING_BRAKE);
        r.brake = Brake::Engaged;
        assert_eq!(r.tick().output_pins & 1, 0, "engaged: de-energised");
        assert!(r.io.brake_present());
        assert_eq!(r.d.get(h::BRAKE_STATE), 1);
        assert_eq!(r.d.get(h::PHYSICAL_OUTPUTS) & 1 << 24, 0);
        r.brake = Brake::Released;
        assert_eq!(r.tick().output_pins & 1, 1, "released: energised");
        assert_eq!(r.d.get(h::BRAKE_STATE), 0);
        assert_eq!(r.d.get(h::PHYSICAL_OUTPUTS) & 1 << 24, 1 << 24);
        // Inverted output: energised = pin low.
        r.d.set(h::DIGITAL_OUTPUTS_POLARITY, 0b01);
        assert_eq!(r.tick().output_pins & 1, 0);
        r.brake = Brake::Engaged;
        assert_eq!(r.tick().output_pins & 1, 1);
        // The master cannot drive it through 0x60FE bit 24.
        r.d.set(h::PHYSICAL_OUTPUTS, 1 << 24);
        assert_eq!(r.tick().output_pins & 1, 1);
        assert_eq!(r.d.get(h::PHYSICAL_OUTPUTS) & 1 << 24, 0);
    }

    #[test]
    fn ready_fault_output_and_read_only_bits() {
        let mut r = Rig::new();
        r.d.set(h::DIGITAL_OUTPUT_2_CONFIGURATION, function::READY_FAULT);
        r.d.set(h::PHYSICAL_OUTPUTS, 0xFF00_0000 | 1 << 16);
        r.ready = true;
        assert_eq!(r.tick().output_pins, 0b11);
        assert_eq!(r.d.get(h::PHYSICAL_OUTPUTS), 1 << 25 | 1 << 16, "bits 24..31 are the drive's");
        r.ready = false;
        assert_eq!(r.tick().output_pins, 0b01);
        assert_eq!(r.d.get(h::PHYSICAL_OUTPUTS), 1 << 16);
        assert_eq!(r.d.get(h::BRAKE_STATE), 0, "no brake output: state stays inactive");
    }
}
