//! Sync managers (ESC datasheet section I "SyncManager", section II registers 0x0800 + 8n; ETG.1000.4 §6.7).
//!
//! A sync manager guards a window of the process RAM and gives it one of two disciplines:
//! - **mailbox** (control bits 1..0 = 0b10): one buffer. The writer opens it by writing the first byte and
//!   completes it by writing the last byte: the mailbox is then *full* (status bit 3) and further writes are
//!   refused until the reader has read the last byte;
//! - **buffered** (bits 1..0 = 0b00): three buffers. The writer always writes into a free buffer; completing it
//!   (last byte) makes it the newest; the reader, when it opens the window (first byte), gets the newest
//!   complete buffer and keeps it until it reads the last byte.
//!
//! Direction (control bits 3..2): 0b01 = the master (ECAT) writes and the PDI reads (SM0 mailbox out, SM2
//! outputs); 0b00 = the PDI writes and the master reads (SM1 mailbox in, SM3 inputs).

/// Which side of the ESC accesses memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The EtherCAT master, through datagrams.
    Ecat,
    /// The process data interface: the firmware.
    Pdi,
}

/// Decoded configuration registers of one sync manager (0x0800 + 8n ..= + 4, + 6, + 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct SmConfig {
    /// Physical start address (+0, u16).
    pub start: u16,
    /// Length in bytes (+2, u16).
    pub length: u16,
    /// Control (+4): bits 1..0 mode (0b00 buffered, 0b10 mailbox), 3..2 direction (0b00 ECAT reads,
    /// 0b01 ECAT writes), bit 4 ECAT event enable, bit 5 AL (PDI) event enable, bit 6 watchdog trigger.
    pub control: u8,
    /// Activate (+6): bit 0 enable, bit 1 repeat request.
    pub activate: u8,
    /// PDI control (+7): bit 0 deactivate, bit 1 repeat acknowledge.
    pub pdi_control: u8,
}

impl SmConfig {
    /// Decodes the 8 register bytes of one sync manager.
    pub fn decode(b: &[u8]) -> Self {
        let g = |i: usize| b.get(i).copied().unwrap_or(0);
        Self {
            start: u16::from_le_bytes([g(0), g(1)]),
            length: u16::from_le_bytes([g(2), g(3)]),
            control: g(4),
            activate: g(6),
            pdi_control: g(7),
        }
    }

    /// Mailbox (single buffer) mode.
    pub fn is_mailbox(&self) -> bool {
        self.control & 0x03 == 0x02
    }

    /// The master writes this window (direction 0b01).
    pub fn ecat_writes(&self) -> bool {
        self.control & 0x0C == 0x04
    }

    /// Enabled by the master and not deactivated by the PDI, with a non-empty window.
    pub fn is_active(&self) -> bool {
        self.activate & 0x01 != 0 && self.pdi_control & 0x01 == 0 && self.length > 0
    }

    /// Whether `addr` lies in the window; returns the offset.
    pub fn offset_of(&self, addr: u16) -> Option<u16> {
        let off = addr.checked_sub(self.start)?;
        (off < self.length).then_some(off)
    }

    /// The writer side of the window.
    pub fn writer(&self) -> Side {
        if self.ecat_writes() {
            Side::Ecat
        } else {
            Side::Pdi
        }
    }
}

/// What a completed buffer access means for the event registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Completion {
    /// The writer wrote the last byte.
    Written,
    /// The reader read the last byte.
    Read,
}

/// Runtime state of one sync manager: the buffers and the status bits.
#[derive(Clone, Debug, Default)]
pub struct SmRuntime {
    /// The configuration this state was set up for (a change resets the state).
    pub config: SmConfig,
    /// Mailbox full (mailbox mode).
    pub full: bool,
    /// The buffer the writer has opened.
    pub write_open: Option<usize>,
    /// The buffer the reader has opened.
    pub read_open: Option<usize>,
    /// The newest complete buffer (buffered mode).
    pub latest: Option<usize>,
    /// The three buffers of buffered mode (each `length` bytes).
    pub bufs: [Vec<u8>; 3],
    /// Status bit 0: a buffer was completely written (cleared when the reader opens it).
    pub irq_write: bool,
    /// Status bit 1: a buffer was completely read (cleared when the writer opens the next one).
    pub irq_read: bool,
    /// Completed writes since the last reset.
    pub writes: u64,
    /// Completed reads since the last reset.
    pub reads: u64,
}

impl SmRuntime {
    /// Resets the state for configuration `config` (enable, disable or any change of start/length/control).
    pub fn reset(&mut self, config: SmConfig) {
        let len = if config.is_mailbox() { 0 } else { usize::from(config.length) };
        *self = Self { config, ..Self::default() };
        for b in &mut self.bufs {
            b.resize(len, 0);
        }
    }

    /// The status register byte (+5): bit 0 write event, bit 1 read event, bit 3 mailbox full, bits 5..4
    /// last written buffer (0b11 none) in buffered mode, bit 6 read buffer open, bit 7 write buffer open.
    pub fn status(&self) -> u8 {
        let mut s = u8::from(self.irq_write) | u8::from(self.irq_read) << 1;
        if self.config.is_mailbox() {
            s |= u8::from(self.full) << 3;
        } else {
            let last = match self.latest {
                Some(i) => (i & 3) as u8,
                None => 3,
            };
            s |= last << 4;
        }
        s | u8::from(self.read_open.is_some()) << 6 | u8::from(self.write_open.is_some()) << 7
    }

    /// A write of `v` at window offset `off` by the writer side. `ram` is the window in the process RAM (used
    /// in mailbox mode). Returns whether the byte was accepted, and the completion it caused.
    pub fn write(&mut self, off: u16, v: u8, ram: &mut [u8]) -> (bool, Option<Completion>) {
        match self.store(off, v, ram) {
            None => (false, None),
            Some(false) => (true, None),
            Some(true) => {
                self.publish();
                (true, Some(Completion::Written))
            }
        }
    }

    /// [`Self::write`] in buffered mode for an ESC whose PDI side runs behind (a real-time line, see
    /// [`super::Esc::hold_output_writes`]): the byte goes into the writer's buffer as usual, but the buffer the
    /// last byte completes is handed back (its content) and freed instead of becoming the newest; it reaches
    /// the reader later through [`Self::deliver`]. Returns whether the byte was accepted.
    pub fn write_held(&mut self, off: u16, v: u8, ram: &mut [u8]) -> (bool, Option<Vec<u8>>) {
        match self.store(off, v, ram) {
            None => (false, None),
            Some(false) => (true, None),
            Some(true) => {
                let data = self.write_open.take().and_then(|w| self.bufs.get(w)).cloned().unwrap_or_default();
                (true, Some(data))
            }
        }
    }

    /// A buffer written earlier ([`Self::write_held`]) completes now, as if the master had written it at this
    /// instant: it goes into a free buffer and becomes the newest (status bit 0, the write counter). Buffered
    /// mode only; `data` is cut or padded to the window's length.
    pub fn deliver(&mut self, data: &[u8]) {
        let free = (0..3).find(|i| Some(*i) != self.latest && Some(*i) != self.read_open).unwrap_or(0);
        if let Some(b) = self.bufs.get_mut(free) {
            let n = b.len().min(data.len());
            b[..n].copy_from_slice(&data[..n]);
        }
        self.write_open = Some(free);
        self.publish();
    }

    /// Stores one byte of the writer side. `None`: refused; otherwise whether it was the window's last byte
    /// (the buffer is complete; `write_open` still names it).
    fn store(&mut self, off: u16, v: u8, ram: &mut [u8]) -> Option<bool> {
        let o = usize::from(off);
        if self.config.is_mailbox() {
            if self.full {
                return None;
            }
            if off == 0 {
                self.write_open = Some(0);
                self.irq_read = false;
            }
            self.write_open?;
            if let Some(b) = ram.get_mut(o) {
                *b = v;
            }
        } else {
            if off == 0 {
                let free = (0..3).find(|i| Some(*i) != self.latest && Some(*i) != self.read_open).unwrap_or(0);
                self.write_open = Some(free);
                self.irq_read = false;
            }
            let w = self.write_open?;
            if let Some(b) = self.bufs.get_mut(w).and_then(|b| b.get_mut(o)) {
                *b = v;
            }
        }
        Some(off + 1 == self.config.length)
    }

    /// The open write buffer is complete: the mailbox is full, or the buffer becomes the newest.
    fn publish(&mut self) {
        if self.config.is_mailbox() {
            self.full = true;
        } else {
            self.latest = self.write_open;
        }
        self.write_open = None;
        self.irq_write = true;
        self.writes += 1;
    }

    /// A read at window offset `off` by the reader side. `None` = refused (an empty mailbox towards the
    /// master: no working counter, the datagram's data stays as it was).
    pub fn read(&mut self, off: u16, ram: &[u8], side: Side) -> (Option<u8>, Option<Completion>) {
        let len = self.config.length;
        let o = usize::from(off);
        let v;
        if self.config.is_mailbox() {
            if !self.full {
                // The PDI reads memory as it is; the master gets nothing.
                return (if side == Side::Pdi { ram.get(o).copied() } else { None }, None);
            }
            if off == 0 {
                self.read_open = Some(0);
                self.irq_write = false;
            }
            v = ram.get(o).copied().unwrap_or(0);
            if off + 1 == len {
                self.full = false;
            }
        } else {
            if off == 0 {
                self.read_open = self.latest;
                self.irq_write = false;
            }
            let b = self.read_open.or(self.latest).unwrap_or(0);
            v = self.bufs.get(b).and_then(|b| b.get(o)).copied().unwrap_or(0);
        }
        if off + 1 == len {
            self.read_open = None;
            self.irq_read = true;
            self.reads += 1;
            return (Some(v), Some(Completion::Read));
        }
        (Some(v), None)
    }

    /// The byte at `off` as the writer side sees it without side effects (the newest buffer in buffered mode).
    pub fn peek(&self, off: u16, ram: &[u8]) -> u8 {
        let o = usize::from(off);
        if self.config.is_mailbox() {
            ram.get(o).copied().unwrap_or(0)
        } else {
            let b = self.write_open.or(self.latest).unwrap_or(0);
            self.bufs.get(b).and_then(|b| b.get(o)).copied().unwrap_or(0)
        }
    }
}
