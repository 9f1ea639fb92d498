//! The Beckhoff-compatible SPI process data interface (PDI type 0x05) of the ET1100/ET1200 class and its
//! derivative the ASIX AX58100: the framing of one access (pure, host-tested) and [`SpiEsc`], the [`Esc`]
//! implementation over any full-duplex byte bus ([`SpiBus`]). The board supplies the bus (`board::esc_spi`,
//! SPI1 of the STM32F405); the tests supply a model chip that interprets the bytes into `hal-sim`'s emulated ESC
//! (`tests/tests/ecat/spi_pdi.rs`).
//!
//! **Why this class and not the LAN9252**: the ET1100-class SPI addresses the ESC's register file and process
//! RAM directly (the address is in the command), which is exactly what the [`Esc`] trait is: read or write `n`
//! bytes at an address. The LAN9252's SPI reaches the ESC core only indirectly, through its own CSR command
//! registers (0x0300/0x0304 and a busy poll per access) and the process-RAM FIFOs (0x0000/0x0020 with their
//! own command registers): several SPI transactions and a poll for every ESC access.
//!
//! **Framing** (ET1100 datasheet section III, 6.3 "SPI Slave Interface": 6.3.3 access, 6.3.4 commands, 6.3.5
//! address modes; the ET1200 manual's Tables 39/40 are the same), MSB first, one access per chip select:
//! - address/command phase, 2 bytes for addresses `0x0000..=0x1FFF` (the upper address bits are taken as 000):
//!   `A[12:5]`, `A[4:0] << 3 | CMD`; 3 bytes to reach the whole 64 KiB (address extension, CMD0 = 110b):
//!   `A[12:5]`, `A[4:0] << 3 | 110b`, `A[15:13] << 5 | CMD << 2 | 00b` (two reserved bits 0);
//! - commands (3 bits): 000 NOP, 010 read, 011 read with following wait-state bytes, 100 write, 110 address
//!   extension;
//! - reads use 011 and one wait-state byte 0xFF after the address phase: the ESC needs a read time (240 ns for
//!   the ET1100) between the address and the first data byte; one byte time covers it for any SPI clock up to
//!   33 MHz, so the driver does not depend on its clock for it (at the board's 21 MHz the byte takes 381 ns);
//! - read data phase: the master sends 0x00 for every data byte but the last, and 0xFF (the read termination)
//!   with the last one: the ESC stops prefetching there, so a read never touches the byte after the buffer
//!   (which matters at the end of a sync manager window, where the read of the last byte hands the buffer back);
//! - write data phase: the data bytes; the ESC increments the address after each;
//! - during the address phase the ESC sends the AL event request register 0x0220..=0x0221 (and 0x0222 with the
//!   3-byte address) on MISO, little-endian ([`SpiEsc::last_al_event`]).
//!
//! The SOES drivers for the ET1100 (`soes/hal/rt-kernel-twrk60/esc_hw.c`) and the AX58100 were read to check
//! these facts; nothing of them is copied.

use super::esc::Esc;

/// SPI command NOP (no operation).
pub const CMD_NOP: u8 = 0b000;
/// SPI command read (no wait state: the master must leave the read time itself).
pub const CMD_READ: u8 = 0b010;
/// SPI command read with following wait-state bytes.
pub const CMD_READ_WAIT_STATE: u8 = 0b011;
/// SPI command write.
pub const CMD_WRITE: u8 = 0b100;
/// SPI command "address extension": a third address/command byte follows.
pub const CMD_ADDRESS_EXTENSION: u8 = 0b110;
/// The wait-state byte the master sends after the address phase of a read with [`CMD_READ_WAIT_STATE`].
pub const WAIT_STATE_BYTE: u8 = 0xFF;
/// What the master sends with the last data byte of a read: the read termination.
pub const READ_TERMINATION: u8 = 0xFF;
/// What the master sends with every other data byte of a read.
pub const READ_NEXT: u8 = 0x00;
/// The highest address the 2-byte address phase reaches (`A[15:13]` = 000).
pub const SHORT_ADDRESS_MAX: u16 = 0x1FFF;

/// Read or write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Read (command 011 with one wait-state byte).
    Read,
    /// Write (command 100).
    Write,
}

/// Which address phase the driver uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Addressing {
    /// 2 bytes up to [`SHORT_ADDRESS_MAX`], 3 bytes above: the shortest access (ET1100).
    Shortest,
    /// Always 3 bytes. For the AX58100, whose SPI was found reliable on an STM32F405 at 21 MHz with the 3-byte
    /// address and the wait-state byte (kubabuda/ecat_servo's AX58100 benchmarks).
    Extended,
}

/// The bytes the master sends before the data of one access: the address/command phase and, for a read, the
/// wait-state byte. At most 4 bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    bytes: [u8; 4],
    len: u8,
    address_phase: u8,
}

impl Header {
    /// The bytes to send, in order.
    pub fn bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// How many of [`Self::bytes`] are the address/command phase (2 or 3): the bytes during which the ESC sends
    /// the AL event request register.
    pub const fn address_phase_len(&self) -> usize {
        self.address_phase as usize
    }
}

/// The address/command phase (and the wait-state byte of a read) for an access at `address` (module
/// documentation). `A[12:5]` and `A[4:0]` are masked out of `address` explicitly, so every address gives a
/// well-formed header.
pub const fn header(address: u16, access: Access, addressing: Addressing) -> Header {
    let cmd = match access {
        Access::Read => CMD_READ_WAIT_STATE,
        Access::Write => CMD_WRITE,
    };
    let a12_5 = ((address >> 5) & 0xFF) as u8;
    let a4_0 = ((address & 0x1F) as u8) << 3;
    let extended = match addressing {
        Addressing::Shortest => address > SHORT_ADDRESS_MAX,
        Addressing::Extended => true,
    };
    let (bytes, address_phase): ([u8; 4], u8) = if extended {
        let a15_13 = ((address >> 13) & 0x07) as u8;
        ([a12_5, a4_0 | CMD_ADDRESS_EXTENSION, (a15_13 << 5) | (cmd << 2), WAIT_STATE_BYTE], 3)
    } else {
        ([a12_5, a4_0 | cmd, WAIT_STATE_BYTE, 0], 2)
    };
    let len = match access {
        Access::Read => address_phase.wrapping_add(1),
        Access::Write => address_phase,
    };
    Header { bytes, len, address_phase }
}

/// What the master sends with data byte `i` of a read of `len` bytes: [`READ_TERMINATION`] with the last one,
/// [`READ_NEXT`] before it.
pub const fn read_mosi(i: usize, len: usize) -> u8 {
    if i.saturating_add(1) >= len {
        READ_TERMINATION
    } else {
        READ_NEXT
    }
}

/// The AL event request bits the ESC sent during an address phase (`miso`: the 2 or 3 bytes received with it,
/// little-endian from 0x0220).
pub fn al_event_from_address_phase(miso: &[u8]) -> u32 {
    let mut value = 0u32;
    for (i, b) in miso.iter().take(3).enumerate() {
        let shift = u32::try_from(i).unwrap_or(0).wrapping_mul(8);
        value |= u32::from(*b) << shift;
    }
    value
}

/// One full-duplex SPI byte bus to the ESC, with its chip select: the only thing a board supplies.
pub trait SpiBus {
    /// Asserts the chip select: an access begins.
    fn select(&mut self);
    /// Clocks `mosi` out and returns the byte clocked in at the same time.
    fn transfer(&mut self, mosi: u8) -> u8;
    /// Releases the chip select: the access ends.
    fn deselect(&mut self);
}

/// An ET1100-class ESC on an SPI bus: the [`Esc`] trait in the framing of the module documentation.
#[derive(Debug)]
pub struct SpiEsc<B> {
    bus: B,
    addressing: Addressing,
    al_event: u32,
}

impl<B: SpiBus> SpiEsc<B> {
    /// The ESC on `bus`, addressed as `addressing` says.
    pub const fn new(bus: B, addressing: Addressing) -> Self {
        Self { bus, addressing, al_event: 0 }
    }

    /// The AL event request bits (0x0220..) the ESC sent in the last access's address phase: bits 0..15 with
    /// the 2-byte address, 0..23 with the 3-byte one. Free with every access, so the PDI interrupt handler can
    /// tell an SM2 event from a SYNC0 without reading 0x0220 itself.
    pub const fn last_al_event(&self) -> u32 {
        self.al_event
    }

    /// The bus (for the board's interrupt and pin helpers).
    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    /// Sends the header of an access (chip select already asserted), keeping the AL event bits.
    fn start(&mut self, address: u16, access: Access) {
        let header = header(address, access, self.addressing);
        let mut miso = [0u8; 3];
        let phase = header.address_phase_len();
        for (i, byte) in header.bytes().iter().enumerate() {
            let received = self.bus.transfer(*byte);
            if i < phase {
                if let Some(slot) = miso.get_mut(i) {
                    *slot = received;
                }
            }
        }
        self.al_event = al_event_from_address_phase(miso.get(..phase).unwrap_or(&[]));
    }
}

impl<B: SpiBus> Esc for SpiEsc<B> {
    /// One read access: header, then one byte in per byte out with the read termination on the last. An empty
    /// `buf` makes no access (a read with no data byte would have no byte to carry the termination).
    fn read(&mut self, address: u16, buf: &mut [u8]) {
        if buf.is_empty() {
            return;
        }
        self.bus.select();
        self.start(address, Access::Read);
        let len = buf.len();
        for (i, slot) in buf.iter_mut().enumerate() {
            *slot = self.bus.transfer(read_mosi(i, len));
        }
        self.bus.deselect();
    }

    /// One write access: header, then the data bytes. An empty `data` makes no access.
    fn write(&mut self, address: u16, data: &[u8]) {
        if data.is_empty() {
            return;
        }
        self.bus.select();
        self.start(address, Access::Write);
        for byte in data {
            let _ = self.bus.transfer(*byte);
        }
        self.bus.deselect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_read_below_0x2000_is_two_address_bytes_with_command_011_and_one_wait_state_byte() {
        // AL event request 0x0220: A[12:5] = 0x11, A[4:0] = 0x00.
        assert_eq!(header(0x0220, Access::Read, Addressing::Shortest).bytes(), &[0x11, 0x03, 0xFF]);
        // AL control 0x0120: A[12:5] = 0x09, A[4:0] = 0x00.
        assert_eq!(header(0x0120, Access::Read, Addressing::Shortest).bytes(), &[0x09, 0x03, 0xFF]);
        // 0x1FFF, the last 2-byte address: A[12:5] = 0xFF, A[4:0] = 0x1F -> 0xF8 | 011.
        let h = header(0x1FFF, Access::Read, Addressing::Shortest);
        assert_eq!(h.bytes(), &[0xFF, 0xFB, 0xFF]);
        assert_eq!(h.address_phase_len(), 2);
    }

    #[test]
    fn a_write_below_0x2000_is_two_address_bytes_with_command_100_and_no_wait_state() {
        // AL status 0x0130: A[12:5] = 0x09, A[4:0] = 0x10 -> 0x80 | 100.
        assert_eq!(header(0x0130, Access::Write, Addressing::Shortest).bytes(), &[0x09, 0x84]);
        // Process RAM 0x1000: A[12:5] = 0x80, A[4:0] = 0.
        assert_eq!(header(0x1000, Access::Write, Addressing::Shortest).bytes(), &[0x80, 0x04]);
    }

    #[test]
    fn an_address_above_0x1fff_takes_the_address_extension_with_a15_13_in_the_third_byte() {
        // 0x2000: A[12:5] = 0, A[4:0] = 0, A[15:13] = 001; CMD0 = 110, CMD1 = 011 (read) in bits 4..2.
        let h = header(0x2000, Access::Read, Addressing::Shortest);
        assert_eq!(h.bytes(), &[0x00, 0x06, 0x2C, 0xFF]);
        assert_eq!(h.address_phase_len(), 3);
        // 0x2F05 write: A[12:5] = 0x78, A[4:0] = 0x05 -> 0x28 | 110, A[15:13] = 001 -> 0x20 | 100 << 2.
        assert_eq!(header(0x2F05, Access::Write, Addressing::Shortest).bytes(), &[0x78, 0x2E, 0x30]);
        // The top of the address space: A[15:13] = 111.
        assert_eq!(header(0xFFFF, Access::Write, Addressing::Shortest).bytes(), &[0xFF, 0xFE, 0xF0]);
    }

    #[test]
    fn extended_addressing_uses_three_bytes_for_low_addresses_too() {
        assert_eq!(header(0x0220, Access::Read, Addressing::Extended).bytes(), &[0x11, 0x06, 0x0C, 0xFF]);
        assert_eq!(header(0x0130, Access::Write, Addressing::Extended).bytes(), &[0x09, 0x86, 0x10]);
    }

    #[test]
    fn a_read_terminates_with_0xff_on_its_last_data_byte_only() {
        let mosi: Vec<u8> = (0..4).map(|i| read_mosi(i, 4)).collect();
        assert_eq!(mosi, [0x00, 0x00, 0x00, 0xFF]);
        assert_eq!(read_mosi(0, 1), 0xFF);
    }

    #[test]
    fn the_address_phase_carries_the_al_event_request_little_endian() {
        assert_eq!(al_event_from_address_phase(&[0x01, 0x04]), 0x0401);
        assert_eq!(al_event_from_address_phase(&[0x01, 0x04, 0x80]), 0x0080_0401);
    }

    /// A bus that records every byte of every access and answers from a script.
    #[derive(Default)]
    struct Recorder {
        accesses: Vec<Vec<u8>>,
        selected: bool,
        answer: Vec<u8>,
    }

    impl SpiBus for Recorder {
        fn select(&mut self) {
            assert!(!self.selected, "select while selected");
            self.selected = true;
            self.accesses.push(Vec::new());
        }
        fn transfer(&mut self, mosi: u8) -> u8 {
            assert!(self.selected, "a byte outside an access");
            let access = self.accesses.last_mut().expect("an access");
            let answer = self.answer.get(access.len()).copied().unwrap_or(0);
            access.push(mosi);
            answer
        }
        fn deselect(&mut self) {
            assert!(self.selected, "deselect while not selected");
            self.selected = false;
        }
    }

    #[test]
    fn the_driver_sends_one_access_per_call_and_keeps_the_al_event_from_the_address_phase() {
        let mut esc = SpiEsc::new(Recorder::default(), Addressing::Shortest);
        // MISO: AL event 0x0401 in the address phase, a don't-care byte under the wait state, then the data.
        esc.bus_mut().answer = vec![0x01, 0x04, 0x55, 0xAA, 0xBB];
        let mut buf = [0u8; 2];
        esc.read(0x0130, &mut buf);
        assert_eq!(buf, [0xAA, 0xBB]);
        assert_eq!(esc.last_al_event(), 0x0401);
        esc.write(0x0134, &[0x11, 0x00]);
        esc.read(0x0000, &mut []);
        esc.write(0x0000, &[]);
        let accesses = &esc.bus_mut().accesses;
        assert_eq!(accesses.len(), 2, "empty reads and writes make no access");
        assert_eq!(accesses[0], [0x09, 0x83, 0xFF, 0x00, 0xFF]);
        assert_eq!(accesses[1], [0x09, 0xA4, 0x11, 0x00]);
    }
}
