//! Why the microcontroller last started: the reset flags the board reads once at start-up (RM0090 section 7.3.21,
//! RCC_CSR), as plain data. A reset by the independent watchdog is a fault the drive reports at the next start
//! (IDX 0xFF02 "Watchdog error", L7093; issue 19 item 3).

/// The cause of the last reset, as the reset flags tell it. Several flags can be set at once (a pin reset also
/// sets PINRSTF after a watchdog reset, since the watchdog drives NRST low): the most specific cause wins.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ResetCause {
    /// The independent watchdog (IWDG) expired: some tier stopped running (`supervision::watchdog`).
    IndependentWatchdog,
    /// The window watchdog (WWDG); the firmware does not start it.
    WindowWatchdog,
    /// A software reset (SYSRESETREQ): program control's restart, the update's activation.
    Software,
    /// The supply: power-on, power-down or brown-out.
    PowerOn,
    /// The NRST pin alone.
    Pin,
    /// Low-power management (entering standby or stop with the option bytes set to reset).
    LowPower,
    /// No flag set (flags cleared by an earlier start without a reset since, or a host build).
    Unknown,
}

/// RCC_CSR flag bits (RM0090 section 7.3.21).
mod csr {
    pub const BORRSTF: u32 = 1 << 25;
    pub const PINRSTF: u32 = 1 << 26;
    pub const PORRSTF: u32 = 1 << 27;
    pub const SFTRSTF: u32 = 1 << 28;
    pub const IWDGRSTF: u32 = 1 << 29;
    pub const WWDGRSTF: u32 = 1 << 30;
    pub const LPWRRSTF: u32 = 1 << 31;
}

impl ResetCause {
    /// The cause RCC_CSR's flags give, the most specific first: a watchdog, then software, low power, the supply,
    /// and the pin last (every reset pulls NRST, so PINRSTF accompanies the others).
    #[must_use]
    pub const fn from_rcc_csr(bits: u32) -> Self {
        if bits & csr::IWDGRSTF != 0 {
            Self::IndependentWatchdog
        } else if bits & csr::WWDGRSTF != 0 {
            Self::WindowWatchdog
        } else if bits & csr::SFTRSTF != 0 {
            Self::Software
        } else if bits & csr::LPWRRSTF != 0 {
            Self::LowPower
        } else if bits & (csr::PORRSTF | csr::BORRSTF) != 0 {
            Self::PowerOn
        } else if bits & csr::PINRSTF != 0 {
            Self::Pin
        } else {
            Self::Unknown
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_watchdog_flag_wins_over_the_pin_flag_it_comes_with() {
        // RM0090 7.3.21: IWDGRSTF with PINRSTF, as after an IWDG reset.
        assert_eq!(ResetCause::from_rcc_csr(0x2400_0000), ResetCause::IndependentWatchdog);
        assert_eq!(ResetCause::from_rcc_csr(0x4400_0000), ResetCause::WindowWatchdog);
    }

    #[test]
    fn each_flag_alone_names_its_cause() {
        assert_eq!(ResetCause::from_rcc_csr(1 << 28), ResetCause::Software);
        assert_eq!(ResetCause::from_rcc_csr(1 << 31), ResetCause::LowPower);
        // Power-on sets PORRSTF, BORRSTF and PINRSTF together (the reset value of RCC_CSR is 0x0E00_0000).
        assert_eq!(ResetCause::from_rcc_csr(0x0E00_0000), ResetCause::PowerOn);
        assert_eq!(ResetCause::from_rcc_csr(1 << 25), ResetCause::PowerOn);
        assert_eq!(ResetCause::from_rcc_csr(1 << 26), ResetCause::Pin);
        // LSI bits (LSION, LSIRDY) and the RMVF bit are not causes.
        assert_eq!(ResetCause::from_rcc_csr(0b11), ResetCause::Unknown);
    }
}
