//! An emulated EtherCAT slave controller (ESC): the register file and process RAM, the datagram engine, sync
//! managers, FMMUs, the SII EEPROM, distributed clocks, the watchdogs and the PDI event lines.
//!
//! Two sides reach it, as on the hardware:
//! - the **master** (ECAT side) through EtherCAT frames: in-process with [`Esc::process_frame`], or from a real
//!   master on a network interface through [`socket::serve`];
//! - the **firmware** (PDI side) through [`Esc::pdi_read`] / [`Esc::pdi_write`] and the event lines
//!   ([`Esc::al_event_request`], [`Esc::irq`], [`Esc::take_sync0`]). The AL state machine is the firmware's: a
//!   master's write of AL control (0x0120) only raises the AL control event; the PDI decides the AL status
//!   (0x0130) and status code (0x0134). [`esm::respond_minimal`] is a small stand-in for tests without
//!   firmware.
//!
//! Time is the caller's: nothing here reads a wall clock. [`Esc::advance`] moves the simulation time (the DC
//! local clock follows it with a rate error), runs the SYNC0 generator and the watchdogs. A lock-step
//! simulation advances time per cyclic frame and asks [`Esc::next_sync0_in`] when the next pulse is due.
//!
//! Register facts come from the Beckhoff ESC datasheet (section II, register description) and ETG.1000.4
//! (data link layer: commands, addressing, working counter); the behaviour real masters need is listed in
//! `shared/spec/fieldbus-real-masters.md` (the "spec file"), which is cited where it is the only source.

pub mod datagram;
pub mod dc;
pub mod esm;
pub mod fmmu;
pub mod pcap;
pub mod pdi;
pub mod registers;
pub mod sii;
pub mod sm;
pub mod socket;

use registers::{al_event, ecat_event, get_u16, get_u32, get_u64, put_u16, put_u32, put_u64, reg};
pub use registers::{FMMU_COUNT, RAM_BYTES, REGISTER_BYTES, SM_COUNT};
pub use sm::{Side, SmConfig};

/// Frame counters of the datagram engine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// EtherCAT frames processed.
    pub processed: u64,
    /// Malformed EtherCAT frames dropped (also counted, saturating, in 0x0300).
    pub malformed: u64,
    /// Frames ignored because they were not EtherCAT (other EtherType, or EtherCAT type other than 1).
    pub ignored: u64,
    /// Datagrams processed.
    pub datagrams: u64,
}

/// One watchdog (process data or PDI): ESC datasheet section I "Watchdog".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Watchdog {
    /// Running (triggered and not expired).
    pub running: bool,
    /// Simulation time of the last trigger, ns.
    pub last_trigger: u64,
    /// Expirations since reset.
    pub expirations: u64,
}

/// The emulated ESC. See the module documentation.
#[derive(Clone, Debug)]
pub struct Esc {
    regs: Box<[u8; REGISTER_BYTES]>,
    ram: Vec<u8>,
    sms: [sm::SmRuntime; SM_COUNT],
    sii: sii::SiiEeprom,
    clock: dc::Clock,
    /// Start time of cyclic operation as the master wrote it (0x0990 reads the next pulse instead).
    dc_start: u64,
    al_event: u32,
    ecat_event: u16,
    wd_pd: Watchdog,
    wd_pdi: Watchdog,
    stats: FrameStats,
    /// Register bytes the master wrote in the current datagram (their side effects run after it).
    touched: Vec<u16>,
    /// Local time at which the current frame arrived.
    rx_local: u64,
    /// Local time at which the current frame came back through port 1 (an ESC in a line, port 1 open).
    rx_local_port1: Option<u64>,
    /// While a frame passes: how far (ideal ns) the instant it reaches this ESC lies from the ESC's current time.
    /// In a line the frame reaches each ESC a little later than the one before it (the port-to-port delays), and
    /// the simulation steps each ESC's time on its own: DC reads, latches and the time control loop see the
    /// ESC's clock at the arrival instant. 0 outside a frame and for a single ESC.
    arrival_ns: i64,
    /// Port 1 open towards a following ESC (DL status link/loop/communication bits of port 1).
    port1_open: bool,
    /// Simulation (ideal) time of the latest SYNC0 pulse, ns.
    last_sync0_elapsed: Option<u64>,
    /// Output writes held for a PDI side that runs behind the frames ([`Esc::hold_output_writes`]).
    held: Option<HeldOutputs>,
}

/// A master's write of an output (buffered, master-written) sync manager, held until the PDI side's time
/// reaches it ([`Esc::hold_output_writes`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StampedWrite {
    /// The ESC's DC system time at which the frame wrote the buffer, ns.
    pub system_time: u64,
    /// The sync manager.
    pub sm: usize,
    /// Its configuration then (a reconfigured sync manager drops what was written for the old one).
    pub config: SmConfig,
    /// The buffer's content.
    pub data: Vec<u8>,
}

/// The output writes an ESC holds, and their counters.
#[derive(Clone, Debug, Default)]
pub struct HeldOutputs {
    /// Most writes held at once.
    pub depth: usize,
    /// The system time of the frame being processed (set by the frame's path for each frame).
    pub stamp: Option<u64>,
    /// The writes not yet delivered, oldest first.
    pub queue: std::collections::VecDeque<StampedWrite>,
    /// Writes delivered to the PDI side.
    pub delivered: u64,
    /// Writes dropped because the queue was full (the oldest goes; the PDI side lagged by more than `depth`
    /// writes).
    pub overflows: u64,
    /// The most writes held at once so far.
    pub held_max: usize,
}

impl Esc {
    /// A powered-up ESC with `sii_image` in its EEPROM; the configuration area (words 0..=6) is loaded into
    /// the registers (PDI control/configuration, SYNC pulse length, station alias) as the ESC does at reset.
    pub fn new(sii_image: Vec<u8>) -> Self {
        let mut esc = Self {
            regs: Box::new([0; REGISTER_BYTES]),
            ram: vec![0; RAM_BYTES],
            sms: Default::default(),
            sii: sii::SiiEeprom { image: sii_image, ..Default::default() },
            clock: dc::Clock::default(),
            dc_start: 0,
            al_event: 0,
            ecat_event: 0,
            wd_pd: Watchdog::default(),
            wd_pdi: Watchdog::default(),
            stats: FrameStats::default(),
            touched: Vec::new(),
            rx_local: 0,
            rx_local_port1: None,
            arrival_ns: 0,
            port1_open: false,
            last_sync0_elapsed: None,
            held: None,
        };
        registers::reset_registers(&mut esc.regs);
        esc.load_config_area();
        esc.refresh();
        esc
    }

    /// An ESC with the drive's SII image, generated by od-gen from `firmware/device.toml` (the same image the
    /// firmware build writes to `drive-sii.bin`).
    pub fn with_drive_sii() -> Result<Self, String> {
        Ok(Self::new(drive_sii_image()?))
    }

    /// Loads SII words 0..=4 into the registers (ETG.1000.6 §5.4 Table 16). DL status bit 0 (PDI operational)
    /// is set only when the configuration-area CRC is right.
    fn load_config_area(&mut self) {
        let w = |k| self.sii.word(k);
        let (w0, w1, w2, w3, w4) = (w(0), w(1), w(2), w(3), w(4));
        put_u16(&mut self.regs[..], reg::PDI_CONTROL, w0);
        put_u16(&mut self.regs[..], reg::PDI_CONFIG, w1);
        put_u16(&mut self.regs[..], reg::DC_PULSE_LENGTH, w2);
        put_u16(&mut self.regs[..], reg::PDI_CONFIG_EXT, w3);
        put_u16(&mut self.regs[..], reg::STATION_ALIAS, w4);
        let mut dl = get_u16(&self.regs[..], reg::DL_STATUS);
        if self.sii.config_crc_ok() {
            dl |= 1;
        } else {
            dl &= !1;
        }
        put_u16(&mut self.regs[..], reg::DL_STATUS, dl);
        put_u16(&mut self.regs[..], reg::SII_CONTROL, self.sii.idle_status());
    }

    // ---------------------------------------------------------------------------------------------------
    // Time, SYNC0 and watchdogs
    // ---------------------------------------------------------------------------------------------------

    /// Advances the simulation time by `ns`: the DC local clock (with its rate error), SYNC0 pulses (0x098E
    /// bit 0, AL event bit 2 when 0x0151 bit 3 maps it), the process-data and PDI watchdogs.
    pub fn advance(&mut self, ns: u64) {
        let pulses = self.clock.advance(ns);
        self.note_sync0(pulses);
        self.run_watchdogs();
        self.refresh();
    }

    /// Holds the master's writes of output sync managers (buffered, master-written: SM2) for a PDI side that
    /// runs behind the frames, as the real-time line's drives do (`crate::sim::ethercat_line`, "Real time"):
    /// a write made while [`Esc::set_write_stamp`] names the frame's system time is kept, with a copy of the
    /// buffer, in a queue of at most `depth` (the oldest dropped and counted when full: a real ESC's three
    /// buffers keep the newest), and reaches the PDI side (buffer, status bit 0, SM event, watchdog) only when
    /// [`Esc::deliver_held_writes`] is called with a system time at or past the stamp. So each SYNC0 cycle of
    /// a drive that lags the wall clock sees the outputs of the frame that arrived in it, as the PDI of a real
    /// ESC does. `depth` 0 switches holding off (the default: writes complete at once).
    pub fn hold_output_writes(&mut self, depth: usize) {
        self.held = (depth > 0).then(|| HeldOutputs { depth, ..HeldOutputs::default() });
    }

    /// The DC system time at which the frame about to be processed reaches this ESC (`None` after it): the
    /// stamp of the output writes it makes while holding is on.
    pub fn set_write_stamp(&mut self, system_time: Option<u64>) {
        if let Some(h) = self.held.as_mut() {
            h.stamp = system_time;
        }
    }

    /// The held output writes and their counters, if holding is on.
    pub fn held_outputs(&self) -> Option<&HeldOutputs> {
        self.held.as_ref()
    }

    /// Completes, in order, the held output writes stamped at or before system time `up_to` (see
    /// [`Esc::hold_output_writes`]). Returns how many reached the PDI side.
    pub fn deliver_held_writes(&mut self, up_to: u64) -> usize {
        let mut n = 0;
        while let Some(w) = self.held.as_mut().and_then(|h| {
            let due = h.queue.front().is_some_and(|w| w.system_time <= up_to);
            if due {
                h.queue.pop_front()
            } else {
                None
            }
        }) {
            let Some(sm) = self.sms.get_mut(w.sm) else { continue };
            if sm.config != w.config || !sm.config.is_active() {
                continue;
            }
            sm.deliver(&w.data);
            self.completed(w.sm, Side::Ecat, sm::Completion::Written);
            if let Some(h) = self.held.as_mut() {
                h.delivered += 1;
            }
            n += 1;
        }
        if n > 0 {
            self.refresh();
        }
        n
    }

    /// The DC system time at ideal (simulation) time `elapsed`, from the clock as it stands now: the local
    /// clock's rate error applied to the distance, the offset as it is.
    pub fn system_time_at(&self, elapsed: u64) -> u64 {
        let ahead = i128::from(elapsed) - i128::from(self.clock.elapsed);
        let local = ahead + ahead * i128::from(self.clock.error_ppb) / 1_000_000_000;
        self.clock.system_time().wrapping_add_signed(i64::try_from(local).unwrap_or(0))
    }

    /// Opens port 1 towards a following ESC (an ESC inside a line) or closes it (the last one, or alone): DL
    /// status 0x0110 shows link on port 1 (bit 5), its loop open (bit 10 clear) and communication on it
    /// (bit 11), which is how masters find the topology (ESC datasheet section II, 0x0110).
    pub fn set_port1_open(&mut self, open: bool) {
        self.port1_open = open;
        let mut dl = get_u16(&self.regs[..], reg::DL_STATUS);
        let port1 = registers::DL_STATUS_PORT1_LINK | registers::DL_STATUS_PORT1_COMMUNICATION;
        if open {
            dl = (dl | port1) & !registers::DL_STATUS_PORT1_LOOP_CLOSED;
        } else {
            dl = (dl & !port1) | registers::DL_STATUS_PORT1_LOOP_CLOSED;
        }
        put_u16(&mut self.regs[..], reg::DL_STATUS, dl);
    }

    /// Whether port 1 is open towards a following ESC.
    pub fn port1_open(&self) -> bool {
        self.port1_open
    }

    /// Sets the rate error of the local clock in parts per billion (+1000 = 1 ppm fast).
    pub fn set_clock_error_ppb(&mut self, ppb: i64) {
        self.clock.error_ppb = ppb;
    }

    /// The DC local time, ns.
    pub fn local_time(&self) -> u64 {
        self.clock.local
    }

    /// The DC system time (local time + offset 0x0920), ns.
    pub fn system_time(&self) -> u64 {
        self.clock.system_time()
    }

    /// Simulation time elapsed since construction (sum of [`Esc::advance`]), ns.
    pub fn elapsed(&self) -> u64 {
        self.clock.elapsed
    }

    /// The last system time difference of the time control loop (local copy minus received), ns.
    pub fn last_time_difference(&self) -> i64 {
        self.clock.last_diff
    }

    /// The SYNC0 pulses since the last call: the simulation delivers them to the firmware (the SYNC0
    /// interrupt line). `count > 1` means pulses were missed.
    pub fn take_sync0(&mut self) -> Option<dc::Sync0Pulse> {
        self.clock.take_sync0()
    }

    /// Simulation time until the next SYNC0 pulse (ideal ns, ignoring the clock's rate error), if armed.
    pub fn next_sync0_in(&self) -> Option<u64> {
        self.clock.next_sync0().map(|t| t.saturating_sub(self.clock.system_time()))
    }

    /// Simulation (ideal) time of the latest SYNC0 pulse, ns (its distance from now counted in local ns: the rate
    /// error changes it by well under a nanosecond).
    pub fn last_sync0_elapsed(&self) -> Option<u64> {
        self.last_sync0_elapsed
    }

    /// The SYNC0 cycle time (0x09A0 as armed), ns, if SYNC0 is armed and cyclic (not single shot).
    pub fn sync0_cycle(&self) -> Option<u32> {
        self.clock.sync0.map(|g| g.cycle).filter(|&c| c > 0)
    }

    fn note_sync0(&mut self, pulses: u32) {
        if pulses == 0 {
            return;
        }
        // The pulse fell between two advances: back from now by how far the system time has passed it.
        if let Some(p) = self.clock.pending {
            let ago = self.clock.system_time().wrapping_sub(p.system_time);
            self.last_sync0_elapsed = Some(self.clock.elapsed.saturating_sub(ago));
        }
        self.regs[usize::from(reg::DC_SYNC0_STATUS)] |= 1;
        if self.regs[usize::from(reg::PDI_CONFIG) + 1] & 0x08 != 0 {
            self.al_event |= al_event::SYNC0;
        }
    }

    fn watchdog_period(&self, time_reg: u16) -> u64 {
        let divider = u64::from(get_u16(&self.regs[..], reg::WATCHDOG_DIVIDER));
        (divider + 2) * 40 * u64::from(get_u16(&self.regs[..], time_reg))
    }

    fn run_watchdogs(&mut self) {
        let now = self.clock.elapsed;
        let pd = self.watchdog_period(reg::WATCHDOG_TIME_PD);
        if self.wd_pd.running && pd > 0 && now.saturating_sub(self.wd_pd.last_trigger) >= pd {
            self.wd_pd.running = false;
            self.wd_pd.expirations += 1;
            let c = &mut self.regs[usize::from(reg::WATCHDOG_COUNTER_PD)];
            *c = c.saturating_add(1);
            self.al_event |= al_event::WATCHDOG_PD;
        }
        let pdi = self.watchdog_period(reg::WATCHDOG_TIME_PDI);
        if self.wd_pdi.running && pdi > 0 && now.saturating_sub(self.wd_pdi.last_trigger) >= pdi {
            self.wd_pdi.running = false;
            self.wd_pdi.expirations += 1;
            let c = &mut self.regs[usize::from(reg::WATCHDOG_COUNTER_PDI)];
            *c = c.saturating_add(1);
        }
    }

    /// The process-data watchdog (triggered by master writes to a sync manager with control bit 6).
    pub fn pd_watchdog(&self) -> Watchdog {
        self.wd_pd
    }

    /// The PDI watchdog (triggered by every PDI access; it starts with the first one).
    pub fn pdi_watchdog(&self) -> Watchdog {
        self.wd_pdi
    }

    // ---------------------------------------------------------------------------------------------------
    // Observation (no side effects)
    // ---------------------------------------------------------------------------------------------------

    /// Frame counters.
    pub fn stats(&self) -> FrameStats {
        self.stats
    }

    /// The register byte at `addr` (< 0x1000) as the master would read it, without side effects.
    pub fn register(&self, addr: u16) -> u8 {
        if usize::from(addr) < REGISTER_BYTES {
            self.reg_value(addr)
        } else {
            0
        }
    }

    /// A little-endian u16 register, without side effects.
    pub fn register_u16(&self, addr: u16) -> u16 {
        u16::from_le_bytes([self.register(addr), self.register(addr.wrapping_add(1))])
    }

    /// The configured station address 0x0010.
    pub fn station_address(&self) -> u16 {
        get_u16(&self.regs[..], reg::STATION_ADDRESS)
    }

    /// The AL event request register 0x0220 (the PDI's interrupt sources), without side effects.
    pub fn al_event_request(&self) -> u32 {
        self.al_event
    }

    /// The ECAT event request register 0x0210.
    pub fn ecat_event_request(&self) -> u16 {
        self.ecat_event
    }

    /// The PDI interrupt line: an AL event request bit is set that the AL event mask 0x0204 lets through.
    pub fn irq(&self) -> bool {
        self.al_event & get_u32(&self.regs[..], reg::AL_EVENT_MASK) != 0
    }

    /// The decoded configuration of sync manager `n`.
    pub fn sm_config(&self, n: usize) -> Option<SmConfig> {
        self.sms.get(n).map(|s| s.config)
    }

    /// The status byte (0x0805 + 8n) of sync manager `n`.
    pub fn sm_status(&self, n: usize) -> u8 {
        self.sms.get(n).map_or(0, |s| s.status())
    }

    /// The runtime state of sync manager `n` (buffers, counters).
    pub fn sm_runtime(&self, n: usize) -> Option<&sm::SmRuntime> {
        self.sms.get(n)
    }

    /// The decoded FMMU `n`.
    pub fn fmmu(&self, n: usize) -> Option<fmmu::Fmmu> {
        let a = usize::from(reg::FMMU0) + 16 * n;
        (n < FMMU_COUNT).then(|| fmmu::Fmmu::decode(&self.regs[a..a + 16]))
    }

    /// The SII EEPROM (image and access counts).
    pub fn sii(&self) -> &sii::SiiEeprom {
        &self.sii
    }

    // ---------------------------------------------------------------------------------------------------
    // PDI side
    // ---------------------------------------------------------------------------------------------------

    /// Reads `buf.len()` bytes from `addr` as the PDI (the firmware's SPI access): registers as they are (a
    /// read of AL control clears the AL control event, of 0x0440 the watchdog event, of 0x098E the SYNC0
    /// status, of an SM activation register the SM-activation event), sync manager windows with the PDI's
    /// buffer semantics (reading the last byte of a mailbox empties it). Unmapped addresses read 0.
    pub fn pdi_read(&mut self, addr: u16, buf: &mut [u8]) {
        self.pdi_touch();
        for (i, b) in buf.iter_mut().enumerate() {
            *b = match u16::try_from(usize::from(addr) + i) {
                Ok(a) => self.mem_read(Side::Pdi, a).unwrap_or(0),
                Err(_) => 0,
            };
        }
        self.refresh();
    }

    /// Writes `data` at `addr` as the PDI: only PDI-writable register bits change (AL status/code, alias, AL
    /// event mask, SM PDI control, user RAM); sync manager windows with the PDI's buffer semantics (writing the
    /// last byte of a mailbox makes it full for the master).
    pub fn pdi_write(&mut self, addr: u16, data: &[u8]) {
        self.pdi_touch();
        let mut sm_regs = false;
        for (i, &v) in data.iter().enumerate() {
            let Ok(a) = u16::try_from(usize::from(addr) + i) else { break };
            self.mem_write(Side::Pdi, a, v);
            if (reg::AL_STATUS..=reg::AL_STATUS_CODE + 1).contains(&a) {
                self.ecat_event |= ecat_event::AL_STATUS;
            }
            sm_regs |= (reg::SM0..reg::SM0 + 8 * SM_COUNT as u16).contains(&a);
        }
        if sm_regs {
            self.sync_sm_configs(Side::Pdi);
        }
        self.refresh();
    }

    /// PDI read of a little-endian u16.
    pub fn pdi_read_u16(&mut self, addr: u16) -> u16 {
        let mut b = [0; 2];
        self.pdi_read(addr, &mut b);
        u16::from_le_bytes(b)
    }

    /// PDI read of a little-endian u32.
    pub fn pdi_read_u32(&mut self, addr: u16) -> u32 {
        let mut b = [0; 4];
        self.pdi_read(addr, &mut b);
        u32::from_le_bytes(b)
    }

    /// PDI write of a little-endian u16.
    pub fn pdi_write_u16(&mut self, addr: u16, v: u16) {
        self.pdi_write(addr, &v.to_le_bytes());
    }

    /// The PDI reads AL control 0x0120 (clearing the AL control event).
    pub fn pdi_al_control(&mut self) -> u16 {
        self.pdi_read_u16(reg::AL_CONTROL)
    }

    /// The PDI writes AL status 0x0130 and AL status code 0x0134.
    pub fn pdi_set_al_status(&mut self, status: u16, code: u16) {
        self.pdi_write_u16(reg::AL_STATUS_CODE, code);
        self.pdi_write_u16(reg::AL_STATUS, status);
    }

    fn pdi_touch(&mut self) {
        self.wd_pdi.running = true;
        self.wd_pdi.last_trigger = self.clock.elapsed;
    }

    // ---------------------------------------------------------------------------------------------------
    // Memory access shared by both sides
    // ---------------------------------------------------------------------------------------------------

    /// The register byte with the values that live outside the array (SM status, event requests).
    fn reg_value(&self, addr: u16) -> u8 {
        let sm_end = reg::SM0 + 8 * SM_COUNT as u16;
        match addr {
            a if (reg::SM0..sm_end).contains(&a) && a & 7 == 5 => self.sms[usize::from((a - reg::SM0) / 8)].status(),
            a if (reg::ECAT_EVENT_REQUEST..reg::ECAT_EVENT_REQUEST + 2).contains(&a) => {
                self.ecat_event.to_le_bytes()[usize::from(a - reg::ECAT_EVENT_REQUEST)]
            }
            a if (reg::AL_EVENT_REQUEST..reg::AL_EVENT_REQUEST + 4).contains(&a) => {
                self.al_event.to_le_bytes()[usize::from(a - reg::AL_EVENT_REQUEST)]
            }
            a => self.regs[usize::from(a) % REGISTER_BYTES],
        }
    }

    /// The active sync manager whose window holds `addr`, and the offset in it.
    fn sm_at(&self, addr: u16) -> Option<(usize, u16)> {
        self.sms.iter().enumerate().find_map(|(n, s)| {
            if s.config.is_active() {
                s.config.offset_of(addr).map(|off| (n, off))
            } else {
                None
            }
        })
    }

    /// Whether `addr` lies in the window of a sync manager the master enabled (0x0806 + 8n bit 0) and the PDI
    /// deactivated (0x0807 + 8n bit 0): "SyncManager deactivated and reset, SyncManager locks access to memory
    /// area" (ESC datasheet section II, 0x0807 bit 0). The master's reads and writes there are refused and
    /// count no working counter (ETG.1000.4 §5.4: a slave increments the working counter only for memory it
    /// accessed), which is how a slave that left OP on a local error shows it (SAFE-OP: inputs only). A sync
    /// manager the master disabled (0x0806 bit 0 = 0) leaves its window plain memory ("access to memory without
    /// SyncManager control").
    fn sm_locked(&self, addr: u16) -> bool {
        self.sms.iter().any(|s| {
            let c = &s.config;
            c.activate & 0x01 != 0 && c.pdi_control & 0x01 != 0 && c.length > 0 && c.offset_of(addr).is_some()
        })
    }

    /// Keeps a held output write (see [`Esc::hold_output_writes`]); a full queue drops its oldest.
    fn hold(&mut self, write: StampedWrite) {
        let Some(h) = self.held.as_mut() else { return };
        if h.queue.len() >= h.depth {
            h.queue.pop_front();
            h.overflows += 1;
        }
        h.queue.push_back(write);
        h.held_max = h.held_max.max(h.queue.len());
    }

    /// The RAM window of sync manager `n` (clipped to the RAM).
    fn sm_window<'a>(ram: &'a mut [u8], cfg: &SmConfig) -> &'a mut [u8] {
        let start = usize::from(cfg.start).saturating_sub(usize::from(reg::RAM_START)).min(ram.len());
        let end = (start + usize::from(cfg.length)).min(ram.len());
        &mut ram[start..end]
    }

    /// Reads one byte. `None`: refused (no working counter): memory that does not exist, an empty mailbox
    /// or the writer's own window towards the master.
    pub(crate) fn mem_read(&mut self, side: Side, addr: u16) -> Option<u8> {
        if usize::from(addr) < REGISTER_BYTES {
            let v = self.reg_value(addr);
            self.read_hook(side, addr);
            return Some(v);
        }
        let ram_off = usize::from(addr - reg::RAM_START);
        if ram_off >= RAM_BYTES {
            return None;
        }
        let Some((n, off)) = self.sm_at(addr) else {
            if side == Side::Ecat && self.sm_locked(addr) {
                return None;
            }
            return self.ram.get(ram_off).copied();
        };
        let cfg = self.sms[n].config;
        if cfg.writer() == side {
            return match side {
                Side::Ecat => None,
                Side::Pdi => Some(self.sms[n].peek(off, Self::sm_window(&mut self.ram, &cfg))),
            };
        }
        if off == 0 {
            self.opened(n, side);
        }
        let window = Self::sm_window(&mut self.ram, &cfg);
        let (v, done) = self.sms[n].read(off, window, side);
        if let Some(c) = done {
            self.completed(n, side, c);
        }
        v
    }

    /// Writes one byte. Returns whether it was accepted (for the working counter). Register writes always
    /// count, even to read-only bits; a full mailbox or the reader's window refuses the write.
    pub(crate) fn mem_write(&mut self, side: Side, addr: u16, v: u8) -> bool {
        if usize::from(addr) < REGISTER_BYTES {
            let a = usize::from(addr);
            match side {
                Side::Ecat => {
                    let clear_on_write = (0x0300..=0x0313).contains(&addr) || (0x0442..=0x0443).contains(&addr);
                    if clear_on_write {
                        self.regs[a] = 0;
                    } else {
                        let m = registers::ecat_write_mask(addr);
                        self.regs[a] = (self.regs[a] & !m) | (v & m);
                    }
                    self.touched.push(addr);
                }
                Side::Pdi => {
                    let m = registers::pdi_write_mask(addr);
                    self.regs[a] = (self.regs[a] & !m) | (v & m);
                }
            }
            return true;
        }
        let ram_off = usize::from(addr - reg::RAM_START);
        if ram_off >= RAM_BYTES {
            return false;
        }
        let Some((n, off)) = self.sm_at(addr) else {
            if side == Side::Ecat && self.sm_locked(addr) {
                return false;
            }
            self.ram[ram_off] = v;
            return true;
        };
        let cfg = self.sms[n].config;
        if cfg.writer() != side {
            return false;
        }
        if off == 0 {
            self.opened(n, side);
        }
        let window = Self::sm_window(&mut self.ram, &cfg);
        let stamp = self.held.as_ref().and_then(|h| h.stamp);
        if let (Some(system_time), Side::Ecat, false) = (stamp, side, cfg.is_mailbox()) {
            let (ok, done) = self.sms[n].write_held(off, v, window);
            if let Some(data) = done {
                self.hold(StampedWrite { system_time, sm: n, config: cfg, data });
            }
            return ok;
        }
        let (ok, done) = self.sms[n].write(off, v, window);
        if let Some(c) = done {
            self.completed(n, side, c);
        }
        ok
    }

    /// A byte as it is, without side effects (for read-modify-write of partly mapped FMMU bytes).
    pub(crate) fn mem_peek(&self, addr: u16) -> u8 {
        if usize::from(addr) < REGISTER_BYTES {
            return self.reg_value(addr);
        }
        let ram_off = usize::from(addr - reg::RAM_START);
        if let Some((n, off)) = self.sm_at(addr) {
            let cfg = self.sms[n].config;
            let start = usize::from(cfg.start).saturating_sub(usize::from(reg::RAM_START)).min(self.ram.len());
            let end = (start + usize::from(cfg.length)).min(self.ram.len());
            return self.sms[n].peek(off, &self.ram[start..end]);
        }
        self.ram.get(ram_off).copied().unwrap_or(0)
    }

    fn read_hook(&mut self, side: Side, addr: u16) {
        match side {
            Side::Pdi => match addr {
                0x0120..=0x0121 => self.al_event &= !al_event::AL_CONTROL,
                0x0440 => self.al_event &= !al_event::WATCHDOG_PD,
                0x098E => {
                    self.regs[usize::from(reg::DC_SYNC0_STATUS)] &= !1;
                    self.al_event &= !al_event::SYNC0;
                }
                a if (reg::SM0..reg::SM0 + 8 * SM_COUNT as u16).contains(&a) && a & 7 == 6 => {
                    self.al_event &= !al_event::SM_ACTIVATION;
                }
                _ => {}
            },
            Side::Ecat => {
                if (reg::AL_STATUS..reg::AL_STATUS + 2).contains(&addr) {
                    self.ecat_event &= !ecat_event::AL_STATUS;
                }
            }
        }
    }

    /// A side opened SM `n`'s buffer (first byte): its pending event for that SM is consumed.
    fn opened(&mut self, n: usize, side: Side) {
        match side {
            Side::Pdi => self.al_event &= !al_event::sm(n),
            Side::Ecat => self.ecat_event &= !ecat_event::sm(n),
        }
    }

    /// A side completed a buffer access of SM `n`: raise the other side's event; a master write to an SM with
    /// the watchdog trigger bit (control bit 6) retriggers the process-data watchdog.
    fn completed(&mut self, n: usize, side: Side, c: sm::Completion) {
        let control = self.sms[n].config.control;
        match side {
            Side::Ecat => {
                if control & 0x20 != 0 {
                    self.al_event |= al_event::sm(n);
                }
                if c == sm::Completion::Written && control & 0x40 != 0 {
                    self.wd_pd.running = true;
                    self.wd_pd.last_trigger = self.clock.elapsed;
                }
            }
            Side::Pdi => {
                if control & 0x10 != 0 {
                    self.ecat_event |= ecat_event::sm(n);
                }
            }
        }
    }

    /// Brings the SM runtime in line with the registers: a change of start, length, control or the
    /// active state resets the SM's buffers; a master's change of the activate byte raises the
    /// SM-activation event.
    fn sync_sm_configs(&mut self, side: Side) {
        for n in 0..SM_COUNT {
            let a = usize::from(reg::SM0) + 8 * n;
            let new = SmConfig::decode(&self.regs[a..a + 8]);
            let old = self.sms[n].config;
            if new == old {
                continue;
            }
            let layout_changed = (new.start, new.length, new.control) != (old.start, old.length, old.control)
                || new.is_active() != old.is_active();
            if layout_changed {
                self.sms[n].reset(new);
            } else {
                self.sms[n].config = new;
            }
            if side == Side::Ecat && new.activate != old.activate {
                self.al_event |= al_event::SM_ACTIVATION;
            }
        }
    }

    /// Side effects of the register bytes the master wrote in the datagram just processed.
    pub(crate) fn apply_ecat_writes(&mut self) {
        if self.touched.is_empty() {
            return;
        }
        let touched = std::mem::take(&mut self.touched);
        let any = |lo: u16, hi: u16| touched.iter().any(|a| (lo..=hi).contains(a));
        if any(reg::SM0, reg::SM0 + 8 * SM_COUNT as u16 - 1) {
            self.sync_sm_configs(Side::Ecat);
        }
        if any(reg::AL_CONTROL, reg::AL_CONTROL + 1) {
            self.al_event |= al_event::AL_CONTROL;
        }
        if any(reg::SII_CONTROL, reg::SII_CONTROL + 1) && self.sii.execute(&mut self.regs[..]) {
            self.load_config_area();
        }
        if any(reg::DC_RECEIVE_TIME_PORT0, reg::DC_RECEIVE_TIME_PORT0 + 3) {
            // Port 0 and the processing unit latch the arrival time; port 1, when open towards a following ESC,
            // latches the time the frame comes back through it (ESC datasheet section I "Propagation delay
            // measurement"). Closed ports (DL status loop bits) see no frame and keep their old values.
            put_u32(&mut self.regs[..], reg::DC_RECEIVE_TIME_PORT0, self.rx_local as u32);
            put_u64(&mut self.regs[..], reg::DC_RECEIVE_TIME_PU, self.rx_local);
            if let (true, Some(t)) = (self.port1_open, self.rx_local_port1) {
                put_u32(&mut self.regs[..], reg::DC_RECEIVE_TIME_PORT1, t as u32);
            }
        }
        if any(reg::DC_SYSTEM_TIME_OFFSET, reg::DC_SYSTEM_TIME_OFFSET + 7) {
            self.clock.offset = get_u64(&self.regs[..], reg::DC_SYSTEM_TIME_OFFSET);
        }
        if any(reg::DC_SYSTEM_TIME_DELAY, reg::DC_SYSTEM_TIME_DELAY + 3) {
            self.clock.delay = get_u32(&self.regs[..], reg::DC_SYSTEM_TIME_DELAY);
        }
        if any(reg::DC_SYSTEM_TIME, reg::DC_SYSTEM_TIME + 7) {
            let bits32 = !any(reg::DC_SYSTEM_TIME + 4, reg::DC_SYSTEM_TIME + 7);
            let received = get_u64(&self.regs[..], reg::DC_SYSTEM_TIME);
            let diff = self.clock.system_time_write(received, bits32, self.arrival_ns);
            put_u32(&mut self.regs[..], reg::DC_SYSTEM_TIME_DIFF, diff);
        }
        if any(reg::DC_START_TIME, reg::DC_START_TIME + 7) {
            self.dc_start = get_u64(&self.regs[..], reg::DC_START_TIME);
        }
        if any(reg::DC_ACTIVATION, reg::DC_ACTIVATION) {
            let activation = self.regs[usize::from(reg::DC_ACTIVATION)];
            let cycle = get_u32(&self.regs[..], reg::DC_SYNC0_CYCLE);
            let pulses = self.clock.activate(activation, self.dc_start, cycle);
            self.note_sync0(pulses);
        }
        self.touched = touched;
        self.touched.clear();
        self.refresh();
    }

    /// Rewrites the registers that mirror internal state: system time, next SYNC0 pulse, watchdog status,
    /// DL status PDI-watchdog bit.
    pub(crate) fn refresh(&mut self) {
        put_u64(&mut self.regs[..], reg::DC_SYSTEM_TIME, self.clock.system_time().wrapping_add_signed(self.arrival_ns));
        let next = self.clock.next_sync0().unwrap_or(self.dc_start);
        put_u64(&mut self.regs[..], reg::DC_START_TIME, next);
        self.regs[usize::from(reg::DC_ACTIVATION_STATUS)] = u8::from(self.clock.sync0.is_some());
        put_u16(&mut self.regs[..], reg::WATCHDOG_STATUS_PD, u16::from(self.wd_pd.running));
        let mut dl = get_u16(&self.regs[..], reg::DL_STATUS);
        let pdi_ok = self.wd_pdi.running || self.wd_pdi.expirations == 0;
        if pdi_ok {
            dl |= registers::DL_STATUS_PDI_WATCHDOG;
        } else {
            dl &= !registers::DL_STATUS_PDI_WATCHDOG;
        }
        put_u16(&mut self.regs[..], reg::DL_STATUS, dl);
    }
}

/// The drive's SII EEPROM image, generated by od-gen from `firmware/device.toml` (compiled in, so the
/// simulation does not depend on the working directory).
pub fn drive_sii_image() -> Result<Vec<u8>, String> {
    let text = include_str!("../../../firmware/device.toml");
    let model = od_gen::load_str(text, "firmware/device.toml")?;
    Ok(od_gen::sii::sii(&model))
}
