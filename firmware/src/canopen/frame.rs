//! The CAN frame and the narrow bus interface the CANopen node sits on (ARCHITECTURE convention 1: the node is
//! sans-IO; the board driver `board::can` and the simulator's bus implement [`CanBus`]).
//!
//! Only what CiA 301 uses: 11-bit identifiers (CAN 2.0A base frames; CiA 301 §7.2.1 uses no 29-bit identifiers
//! for the pre-defined connection set), 0..=8 data bytes, and remote frames (RTR) for the TPDOs that allow them.

/// Highest 11-bit CAN identifier.
pub const MAX_ID: u16 = 0x7FF;

/// Data bytes of a classic CAN frame.
pub const MAX_DLC: u8 = 8;

/// One classic CAN base frame: an 11-bit identifier, 0..=8 data bytes, or a remote request.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: u16,
    dlc: u8,
    data: [u8; 8],
    rtr: bool,
}

impl CanFrame {
    /// A data frame with `data` on `id`; `None` for an identifier above 0x7FF or more than 8 bytes.
    pub fn new(id: u16, data: &[u8]) -> Option<Self> {
        if id > MAX_ID || data.len() > usize::from(MAX_DLC) {
            return None;
        }
        let mut bytes = [0u8; 8];
        for (b, d) in bytes.iter_mut().zip(data) {
            *b = *d;
        }
        Some(Self { id, dlc: u8::try_from(data.len()).unwrap_or(MAX_DLC), data: bytes, rtr: false })
    }

    /// A remote frame (RTR) on `id` asking for `dlc` bytes; `None` for an identifier above 0x7FF or a DLC above 8.
    pub fn remote(id: u16, dlc: u8) -> Option<Self> {
        if id > MAX_ID || dlc > MAX_DLC {
            return None;
        }
        Some(Self { id, dlc, data: [0; 8], rtr: true })
    }

    /// A data frame from raw fields as a controller's receive FIFO delivers them: the identifier is masked to 11
    /// bits and the DLC limited to 8 (ISO 11898-1: DLC codes 9..15 mean 8 bytes on classic CAN).
    pub fn from_raw(id: u16, dlc: u8, data: [u8; 8], rtr: bool) -> Self {
        Self { id: id & MAX_ID, dlc: dlc.min(MAX_DLC), data, rtr }
    }

    /// The 11-bit identifier (the COB-ID).
    pub const fn id(&self) -> u16 {
        self.id
    }

    /// The data length code (0..=8).
    pub const fn dlc(&self) -> u8 {
        self.dlc
    }

    /// Whether this is a remote frame.
    pub const fn is_remote(&self) -> bool {
        self.rtr
    }

    /// The data bytes (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            return &[];
        }
        self.data.get(..usize::from(self.dlc)).unwrap_or(&self.data)
    }

    /// All 8 data-register bytes (those past the DLC are 0), for a controller's transmit mailbox.
    pub const fn raw_data(&self) -> [u8; 8] {
        self.data
    }
}

/// The bit rates of the IDX bit-rate object 0x2001 (IDX Table 6-88, L3490-L3556; comms-faults-bootloader.md
/// §2.7); code 9 (automatic detection) is not offered by this drive, code 5 is unused by IDX.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BitRate {
    /// Code 0: 1 Mbit/s (the default, device.toml `bit_rate_kbit`).
    #[default]
    Kbit1000,
    /// Code 1: 800 kbit/s.
    Kbit800,
    /// Code 2: 500 kbit/s.
    Kbit500,
    /// Code 3: 250 kbit/s.
    Kbit250,
    /// Code 4: 125 kbit/s.
    Kbit125,
    /// Code 6: 50 kbit/s.
    Kbit50,
    /// Code 7: 20 kbit/s.
    Kbit20,
}

impl BitRate {
    /// Every rate the drive offers, in declaration (and code) order: `ALL[rate.index()] == rate`.
    pub const ALL: [BitRate; 7] =
        [Self::Kbit1000, Self::Kbit800, Self::Kbit500, Self::Kbit250, Self::Kbit125, Self::Kbit50, Self::Kbit20];

    /// The rate's position in [`BitRate::ALL`] (its declaration order).
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The rate of an 0x2001 code, or `None` for a code the drive does not offer.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::Kbit1000),
            1 => Some(Self::Kbit800),
            2 => Some(Self::Kbit500),
            3 => Some(Self::Kbit250),
            4 => Some(Self::Kbit125),
            6 => Some(Self::Kbit50),
            7 => Some(Self::Kbit20),
            _ => None,
        }
    }

    /// The 0x2001 / 0x200A code.
    pub const fn code(self) -> u8 {
        match self {
            Self::Kbit1000 => 0,
            Self::Kbit800 => 1,
            Self::Kbit500 => 2,
            Self::Kbit250 => 3,
            Self::Kbit125 => 4,
            Self::Kbit50 => 6,
            Self::Kbit20 => 7,
        }
    }

    /// Bits per second.
    pub const fn bits_per_second(self) -> u32 {
        match self {
            Self::Kbit1000 => 1_000_000,
            Self::Kbit800 => 800_000,
            Self::Kbit500 => 500_000,
            Self::Kbit250 => 250_000,
            Self::Kbit125 => 125_000,
            Self::Kbit50 => 50_000,
            Self::Kbit20 => 20_000,
        }
    }
}

/// The transmit side could not take the frame now (all mailboxes or the queue busy); the node keeps it and
/// offers it again at its next poll.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TxBusy;

/// A CAN controller as the node needs it: send a frame, take a received frame, the bit rate it runs at.
pub trait CanBus {
    /// Queues `frame` for transmission; [`TxBusy`] when there is no room now.
    fn send(&mut self, frame: &CanFrame) -> Result<(), TxBusy>;
    /// The next received frame, if any.
    fn receive(&mut self) -> Option<CanFrame>;
    /// The bit rate the controller runs at.
    fn bit_rate(&self) -> BitRate;
    /// The controller's fault-confinement state and lost frames now.
    fn status(&self) -> BusStatus;
}

/// A CAN controller's fault-confinement state (ISO 11898-1 §12.1.4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BusState {
    /// Both error counters at most 127: the controller takes part in error signalling.
    #[default]
    ErrorActive,
    /// An error counter above 127: the controller signals errors only passively.
    ErrorPassive,
    /// The transmit error counter above 255: the controller is off the bus until it has seen 128 x 11 recessive
    /// bits (automatic recovery).
    BusOff,
}

/// What the CAN controller reports to the node ([`CanBus::status`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusStatus {
    /// The fault-confinement state.
    pub state: BusState,
    /// The transmit error counter.
    pub transmit_errors: u8,
    /// Received frames lost since start-up because the receive FIFO was full (wrapping).
    pub rx_overruns: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_check_identifier_and_length() {
        assert!(CanFrame::new(0x800, &[]).is_none());
        assert!(CanFrame::new(0x7FF, &[0; 9]).is_none());
        let f = CanFrame::new(0x181, &[1, 2, 3]).unwrap();
        assert_eq!((f.id(), f.dlc(), f.data(), f.is_remote()), (0x181, 3, &[1u8, 2, 3][..], false));
        let r = CanFrame::remote(0x181, 4).unwrap();
        assert_eq!((r.dlc(), r.data().len(), r.is_remote()), (4, 0, true));
        let raw = CanFrame::from_raw(0xFFFF, 15, [9; 8], false);
        assert_eq!((raw.id(), raw.dlc()), (0x7FF, 8));
    }

    #[test]
    fn bit_rate_codes_round_trip() {
        for code in 0..=10u8 {
            if let Some(rate) = BitRate::from_code(code) {
                assert_eq!(rate.code(), code);
            }
        }
        assert_eq!(BitRate::from_code(5), None);
        assert_eq!(BitRate::from_code(9), None);
        assert_eq!(BitRate::default().bits_per_second(), 1_000_000);
    }
}
