//! The CiA 402 device state a statusword reports (CiA 402-2 §6.2, the statusword's state bits: xxxx xxxx
//! x0xx 0000 "Not ready to switch on" and so on; IDX L5680).

/// The state of statusword `sw`.
pub fn state_name(sw: u16) -> &'static str {
    if sw & 0x4F == 0x00 {
        "Not ready to switch on"
    } else if sw & 0x4F == 0x40 {
        "Switch on disabled"
    } else if sw & 0x6F == 0x21 {
        "Ready to switch on"
    } else if sw & 0x6F == 0x23 {
        "Switched on"
    } else if sw & 0x6F == 0x27 {
        "Operation enabled"
    } else if sw & 0x6F == 0x07 {
        "Quick stop active"
    } else if sw & 0x4F == 0x0F {
        "Fault reaction active"
    } else if sw & 0x4F == 0x08 {
        "Fault"
    } else {
        "unknown"
    }
}

/// Statusword bit 3: fault.
pub const SW_FAULT: u16 = 1 << 3;
/// Statusword bit 10: target reached.
pub const SW_TARGET_REACHED: u16 = 1 << 10;
/// Statusword bit 12 in PPM: set-point acknowledge.
pub const SW_SETPOINT_ACK: u16 = 1 << 12;
/// Statusword bit 14 (this drive): Safe Torque Off active.
pub const SW_STO: u16 = 1 << 14;

/// Controlword «Shutdown» (CiA 402-2 Table 27): to Ready to switch on.
pub const CW_SHUTDOWN: u16 = 0x0006;
/// Controlword «Switch on».
pub const CW_SWITCH_ON: u16 = 0x0007;
/// Controlword «Enable operation».
pub const CW_ENABLE_OPERATION: u16 = 0x000F;
/// Controlword bit 4 in PPM: new set-point.
pub const CW_NEW_SETPOINT: u16 = 1 << 4;
/// Controlword bit 5 in PPM: change set immediately.
pub const CW_CHANGE_IMMEDIATELY: u16 = 1 << 5;
/// Controlword bit 6 in PPM: relative target.
pub const CW_RELATIVE: u16 = 1 << 6;
/// Controlword bit 7: fault reset (on its rising edge).
pub const CW_FAULT_RESET: u16 = 1 << 7;
/// Controlword bit 8: halt.
pub const CW_HALT: u16 = 1 << 8;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_states_of_cia_402_table_30() {
        assert_eq!(state_name(0x0250), "Switch on disabled");
        assert_eq!(state_name(0x0231), "Ready to switch on");
        assert_eq!(state_name(0x0233), "Switched on");
        assert_eq!(state_name(0x1637), "Operation enabled");
        assert_eq!(state_name(0x0217), "Quick stop active");
        assert_eq!(state_name(0x021F), "Fault reaction active");
        assert_eq!(state_name(0x0218), "Fault");
        assert_eq!(state_name(0x4040), "Switch on disabled");
    }
}
