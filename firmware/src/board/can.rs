//! bxCAN: CAN1 of the STM32F405 as the CANopen node's bus ([`CanBus`]; RM0090 §32, issue 8). Register level, no
//! logic: the node ([`crate::canopen::CanopenNode`]) decides what to send and what a frame means.
//!
//! Pins: CAN1_RX on PA11, CAN1_TX on PA12 (AF9; RM0090 / DS8626 alternate-function table). PB8/PB9 (the other
//! CAN1 pair) is taken: PB8 is the encoder index (TIM4 CH3). PA11/PA12 are free: PA8..PA10 are TIM1's high sides,
//! and TIM1 CH4 (the ADC trigger) is used without its pin. Pin map addition (see the table in [`super`]): CAN1
//! RX/TX on PA11/PA12 (AF9) to the transceiver.
//!
//! - Clock: CAN1EN (RCC APB1ENR bit 25); the controller runs from APB1 = 42 MHz ([`APB1_HZ`], `clock`).
//! - Bit timing: [`crate::hal::can::bit_timing`] (table there): exact rates, sample point 85.7..87.5 %; 800 kbit/s
//!   has no exact setting from 42 MHz and is refused ([`CanError::BitRate`]).
//! - Mode (MCR): automatic bus-off management (ABOM: after bus-off the controller rejoins on its own after
//!   128 x 11 recessive bits, ISO 11898-1 §12.1.4.2), automatic retransmission (NART = 0), transmit mailboxes in
//!   request order (TXFP = 1: the node's transmit queue is in order, e.g. an SDO block's segments), receive FIFO
//!   not locked (RFLM = 0: on overrun the newest frame replaces the last one; overruns are counted), running
//!   while the core is halted by a debugger (DBF = 0: the bus must not freeze with the drive).
//! - Filter bank 0 (the banks belong to CAN1, FMR): one 32-bit mask filter into FIFO 0 that accepts every base
//!   (11-bit) identifier, data and remote, and no extended one (IDE must be 0; CiA 301's pre-defined connection
//!   set uses base frames only).
//! - Waits (entering and leaving initialisation) are bounded ([`MODE_POLLS`]); leaving initialisation needs 11
//!   recessive bits on RX, so without a transceiver and bus [`BxCan::init`] returns [`CanError::NormalTimeout`].
//!
//! **Who calls it** (nothing does on the QEMU image, which has no CAN controller): `rt` brings it up at start-up
//! with the bit rate of 0x2001 (the parameter store's) and hands it to tier 3, which calls
//! [`crate::canopen::CanopenNode::poll`] at least every millisecond (receive, process, transmit). For the SYNC path
//! at tier 2 (`canopen` module documentation), the CAN1 RX0 interrupt (FMPIE0) takes the frames for which
//! [`crate::canopen::CanopenNode::is_realtime`] holds to `handle_frame` and leaves the rest for tier 3 (the
//! runtime keeps them in a small queue; tier 3 masks the interrupt around its calls). At a
//! [`crate::canopen::NodeEvent::Reset`] with a bit rate, and at [`crate::canopen::NodeEvent::BitRateSwitched`]
//! (LSS activate bit timing), tier 3 calls [`BxCan::set_bit_rate`].

use super::reg::{base, rcc, Gpio, Reg};
use crate::canopen::frame::{BitRate, BusState, BusStatus, CanBus, CanFrame, TxBusy, MAX_ID};
use crate::hal::can::{timings, BitTiming};

/// CAN1 (RM0090 memory map: 0x4000_6400).
pub const CAN1: usize = 0x4000_6400;
/// The controller's clock: APB1 = SYSCLK / 4 (`clock`: PPRE1 = /4).
pub const APB1_HZ: u32 = super::clock::SYSCLK_HZ / 4;
const _: () = assert!(APB1_HZ == 42_000_000, "the bit timing table of hal::can is for 42 MHz");

/// Polls of INAK before giving up on a mode change: entering initialisation waits for the frame on the bus to end
/// (at 20 kbit/s up to about 8 ms), leaving it for 11 recessive bits; about 12 ms at 168 MHz.
pub const MODE_POLLS: u32 = 200_000;

const MCR: Reg = Reg::at(CAN1, 0x000);
const MSR: Reg = Reg::at(CAN1, 0x004);
const TSR: Reg = Reg::at(CAN1, 0x008);
const RF0R: Reg = Reg::at(CAN1, 0x00C);
const ESR: Reg = Reg::at(CAN1, 0x018);
const BTR: Reg = Reg::at(CAN1, 0x01C);
/// Receive FIFO 0 mailbox: identifier, length and time, data low, data high.
const RI0R: Reg = Reg::at(CAN1, 0x1B0);
const RDT0R: Reg = Reg::at(CAN1, 0x1B4);
const RDL0R: Reg = Reg::at(CAN1, 0x1B8);
const RDH0R: Reg = Reg::at(CAN1, 0x1BC);
/// Filter master, mode, scale, FIFO assignment and activation registers; filter bank 0's two registers.
const FMR: Reg = Reg::at(CAN1, 0x200);
const FM1R: Reg = Reg::at(CAN1, 0x204);
const FS1R: Reg = Reg::at(CAN1, 0x20C);
const FFA1R: Reg = Reg::at(CAN1, 0x214);
const FA1R: Reg = Reg::at(CAN1, 0x21C);
const F0R1: Reg = Reg::at(CAN1, 0x240);
const F0R2: Reg = Reg::at(CAN1, 0x244);

/// Transmit mailbox `n` (0..=2): identifier, length, data low, data high (RM0090 §32.9.3).
const fn tx_mailbox(n: usize) -> [Reg; 4] {
    let at = 0x180_usize.wrapping_add(n.wrapping_mul(0x10));
    [
        Reg::at(CAN1, at),
        Reg::at(CAN1, at.wrapping_add(4)),
        Reg::at(CAN1, at.wrapping_add(8)),
        Reg::at(CAN1, at.wrapping_add(12)),
    ]
}

// MCR bits.
const MCR_INRQ: u32 = 1 << 0;
const MCR_SLEEP: u32 = 1 << 1;
const MCR_TXFP: u32 = 1 << 2;
const MCR_RFLM: u32 = 1 << 3;
const MCR_NART: u32 = 1 << 4;
const MCR_AWUM: u32 = 1 << 5;
const MCR_ABOM: u32 = 1 << 6;
const MCR_TTCM: u32 = 1 << 7;
const MCR_DBF: u32 = 1 << 16;
// MSR bits.
const MSR_INAK: u32 = 1 << 0;
const MSR_SLAK: u32 = 1 << 1;
// TSR: transmit mailbox empty flags, and CODE (the number of the next empty mailbox).
const TSR_TME: u32 = 0b111 << 26;
const TSR_CODE_SHIFT: u32 = 24;
/// Frames receive FIFO 0 holds.
const FIFO_DEPTH: usize = 3;
// RF0R: FIFO 0 message pending count, overrun, release.
const RF0R_FMP: u32 = 0b11;
const RF0R_FOVR: u32 = 1 << 4;
const RF0R_RFOM: u32 = 1 << 5;
// Mailbox identifier register: request / remote / extended bits, base identifier at [31:21].
const ID_TXRQ: u32 = 1 << 0;
const ID_RTR: u32 = 1 << 1;
const ID_IDE: u32 = 1 << 2;
const ID_STID_SHIFT: u32 = 21;
// ESR fields.
const ESR_EWGF: u32 = 1 << 0;
const ESR_EPVF: u32 = 1 << 1;
const ESR_BOFF: u32 = 1 << 2;

/// Why the controller could not be brought up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CanError {
    /// No exact bit timing for this rate from [`APB1_HZ`] (800 kbit/s; see `hal::can`).
    BitRate,
    /// INAK did not set: the controller did not enter initialisation.
    InitTimeout,
    /// INAK did not clear: no 11 recessive bits on RX (no transceiver, or the bus held dominant).
    NormalTimeout,
}

/// The controller's error state (CAN_ESR, RM0090 §32.9.2; ISO 11898-1 §12.1.4 fault confinement).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ErrorCounters {
    /// Transmit error counter (TEC).
    pub transmit: u8,
    /// Receive error counter (REC).
    pub receive: u8,
    /// Error warning: a counter reached 96.
    pub warning: bool,
    /// Error passive: a counter above 127.
    pub passive: bool,
    /// Bus-off: TEC above 255 (the controller recovers on its own, ABOM).
    pub bus_off: bool,
    /// Last error code (LEC: 0 none, 1 stuff, 2 form, 3 acknowledgement, 4 bit recessive, 5 bit dominant, 6 CRC).
    pub last_error: u8,
    /// Frames lost because receive FIFO 0 was full (counted by the driver).
    pub rx_overruns: u32,
}

/// CAN1 brought up (see the module documentation). Owns the controller: one instance.
#[derive(Debug)]
pub struct BxCan {
    rate: BitRate,
    rx_overruns: u32,
}

/// Polls `ready` at most [`MODE_POLLS`] times.
fn wait(ready: impl Fn() -> bool) -> bool {
    (0..MODE_POLLS).any(|_| ready())
}

/// Requests initialisation mode (out of sleep) and waits for it.
fn enter_init() -> Result<(), CanError> {
    MCR.modify(MCR_SLEEP, MCR_INRQ);
    if wait(|| MSR.read() & (MSR_INAK | MSR_SLAK) == MSR_INAK) {
        Ok(())
    } else {
        Err(CanError::InitTimeout)
    }
}

/// Leaves initialisation and waits until the controller has synchronised to the bus (INAK clear).
fn enter_normal() -> Result<(), CanError> {
    MCR.modify(MCR_INRQ, 0);
    if wait(|| MSR.read() & MSR_INAK == 0) {
        Ok(())
    } else {
        Err(CanError::NormalTimeout)
    }
}

/// PA11 (CAN1_RX) and PA12 (CAN1_TX) as AF9; RX with pull-up (recessive when no transceiver drives it).
fn init_pins() {
    let a = Gpio(base::GPIOA);
    a.moder().modify((0b11 << 22) | (0b11 << 24), (0b10 << 22) | (0b10 << 24));
    a.ospeedr().modify(0b11 << 24, 0b10 << 24);
    a.pupdr().modify((0b11 << 22) | (0b11 << 24), 0b01 << 22);
    a.afrh().modify((0xF << 12) | (0xF << 16), (9 << 12) | (9 << 16));
}

/// Filter bank 0: 32-bit mask mode into FIFO 0, identifier 0 with only IDE compared: every base frame passes.
fn init_filters() {
    FMR.modify(0, 1); // FINIT: filters in initialisation
    FA1R.modify(1, 0); // bank 0 inactive while it is written
    FM1R.modify(1, 0); // mask mode
    FS1R.modify(0, 1); // 32-bit scale
    FFA1R.modify(1, 0); // FIFO 0
    F0R1.write(0); // identifier: IDE = 0
    F0R2.write(ID_IDE); // mask: only IDE must match
    FA1R.modify(0, 1);
    FMR.modify(1, 0); // FINIT off: filters active
}

impl BxCan {
    /// Brings CAN1 up at `rate`: clock, pins, mode, bit timing, filter, then normal mode (see the module
    /// documentation). Checks the rate before touching the hardware.
    pub fn init(rate: BitRate) -> Result<Self, CanError> {
        let timing = Self::timing(rate)?;
        rcc::AHB1ENR.modify(0, 1 << 0); // GPIOA
        rcc::APB1ENR.modify(0, 1 << 25); // CAN1EN
        let _ = rcc::APB1ENR.read(); // the enable takes effect after a bus cycle (RM0090 6.3.10 note)
        init_pins();
        enter_init()?;
        MCR.modify(MCR_TTCM | MCR_AWUM | MCR_NART | MCR_RFLM | MCR_DBF, MCR_ABOM | MCR_TXFP);
        BTR.write(timing.bxcan_btr());
        init_filters();
        enter_normal()?;
        Ok(Self { rate, rx_overruns: 0 })
    }

    /// The timing of `rate` from [`APB1_HZ`]: a table evaluated at build time (the search of
    /// [`crate::hal::can::bit_timing`] is not in the image).
    pub fn timing(rate: BitRate) -> Result<BitTiming, CanError> {
        const TIMINGS: [Option<BitTiming>; BitRate::ALL.len()] = timings(APB1_HZ);
        TIMINGS.get(rate.index()).copied().flatten().ok_or(CanError::BitRate)
    }

    /// Changes the bit rate (a reset node with a new 0x2001): initialisation, CAN_BTR, normal mode. Frames still
    /// in the mailboxes are aborted by the mode change. A refused rate leaves the controller as it was.
    pub fn set_bit_rate(&mut self, rate: BitRate) -> Result<(), CanError> {
        let timing = Self::timing(rate)?;
        enter_init()?;
        BTR.write(timing.bxcan_btr());
        self.rate = rate;
        enter_normal()
    }

    /// Whether all three transmit mailboxes are empty (TSR.TME0..2): every queued frame has been sent or
    /// aborted. The bootloader waits for this before a reset, so that its last SDO response leaves first.
    pub fn tx_idle(&self) -> bool {
        TSR.read() & TSR_TME == TSR_TME
    }

    /// The error counters and state.
    pub fn errors(&self) -> ErrorCounters {
        let esr = ESR.read();
        ErrorCounters {
            transmit: u8::try_from((esr >> 16) & 0xFF).unwrap_or(u8::MAX),
            receive: u8::try_from(esr >> 24).unwrap_or(u8::MAX),
            warning: esr & ESR_EWGF != 0,
            passive: esr & ESR_EPVF != 0,
            bus_off: esr & ESR_BOFF != 0,
            last_error: u8::try_from((esr >> 4) & 0b111).unwrap_or(0),
            rx_overruns: self.rx_overruns,
        }
    }
}

impl CanBus for BxCan {
    /// Into the empty mailbox TSR.CODE names; [`TxBusy`] when all three are full.
    fn send(&mut self, frame: &CanFrame) -> Result<(), TxBusy> {
        let tsr = TSR.read();
        if tsr & TSR_TME == 0 {
            return Err(TxBusy);
        }
        let n = usize::try_from((tsr >> TSR_CODE_SHIFT) & 0b11).unwrap_or(0).min(2);
        let [tir, tdtr, tdlr, tdhr] = tx_mailbox(n);
        let [d0, d1, d2, d3, d4, d5, d6, d7] = frame.raw_data();
        tdtr.write(u32::from(frame.dlc()));
        tdlr.write(u32::from_le_bytes([d0, d1, d2, d3]));
        tdhr.write(u32::from_le_bytes([d4, d5, d6, d7]));
        let rtr = if frame.is_remote() { ID_RTR } else { 0 };
        tir.write((u32::from(frame.id() & MAX_ID) << ID_STID_SHIFT) | rtr | ID_TXRQ);
        Ok(())
    }

    /// The oldest frame of FIFO 0 (FMP > 0), released with RFOM; an extended frame (which the filter does not
    /// let through) would be released and skipped, at most a FIFO's depth of them per call.
    fn receive(&mut self) -> Option<CanFrame> {
        for _ in 0..FIFO_DEPTH {
            let rf0r = RF0R.read();
            if rf0r & RF0R_FOVR != 0 {
                self.rx_overruns = self.rx_overruns.wrapping_add(1);
                RF0R.write(RF0R_FOVR); // rc_w1
            }
            if rf0r & RF0R_FMP == 0 {
                return None;
            }
            let (id, dlc, low, high) = (RI0R.read(), RDT0R.read(), RDL0R.read(), RDH0R.read());
            RF0R.write(RF0R_RFOM);
            if id & ID_IDE != 0 {
                continue;
            }
            let [d0, d1, d2, d3] = low.to_le_bytes();
            let [d4, d5, d6, d7] = high.to_le_bytes();
            let stid = u16::try_from(id >> ID_STID_SHIFT).unwrap_or(0);
            let dlc = u8::try_from(dlc & 0xF).unwrap_or(0);
            return Some(CanFrame::from_raw(stid, dlc, [d0, d1, d2, d3, d4, d5, d6, d7], id & ID_RTR != 0));
        }
        None
    }

    fn bit_rate(&self) -> BitRate {
        self.rate
    }

    /// From CAN_ESR (BOFF, EPVF, TEC) and the driver's overrun count.
    fn status(&self) -> BusStatus {
        let e = self.errors();
        let state = if e.bus_off {
            BusState::BusOff
        } else if e.passive {
            BusState::ErrorPassive
        } else {
            BusState::ErrorActive
        };
        BusStatus { state, transmit_errors: e.transmit, rx_overruns: e.rx_overruns }
    }
}
