//! The simulated drive as an EtherCAT slave: the reference plant and the firmware's drive ([`Simulation`]), the
//! emulated ESC ([`Esc::with_drive_sii`]) and the firmware's application layer
//! ([`firmware::ecat::slave::EthercatSlave`]) tied together, reachable in-process ([`EthercatRunner::frame`]) or
//! from a real master on a network interface ([`EthercatRunner::serve`], over [`crate::esc::socket::serve`]).
//! This is what `drive-sim ethercat` runs (issue 6, item 3).
//!
//! Two clocks:
//! - [`ClockMode::RealTime`]: simulated time follows the wall clock; every received frame and every idle poll
//!   runs the plant (and the ESC's time) up to now. For a person at a master; on a loaded host the simulation
//!   falls behind and the verdict depends on the load ([`RunnerStats::lag_events`] counts the catch-ups cut short).
//! - [`ClockMode::LockStep`]: simulated time advances by exactly one master cycle with each cyclic frame (one that
//!   carries an LRW, LRD or LWR datagram), the DC system time with it ([`Esc::advance`]), and not at all
//!   otherwise. The master's pace is the simulation's pace, so a master on a busy 2-core machine gets the same
//!   answers every run. **In DC mode** (0x1C32:01 = 2 and SYNC0 armed, its next pulse at most one SYNC0
//!   cycle away) a cyclic frame instead runs simulated time up to and including the next SYNC0 pulse: the
//!   master is locked to the ESC's clock as a real DC master is (it follows the reference clock's system time
//!   that its cyclic `FRMW 0x0910` reads, fieldbus-real-masters.md item 8), so each frame is followed by exactly
//!   one SYNC0 whatever the ESC's clock error (`--clock-error-ppm`). With a fixed master cycle instead, SYNC0
//!   (ESC time) and the frames (simulated time) drift apart: at +100 ppm one SYNC0 pulse per 10,000 cycles
//!   finds no fresh outputs and counts an SM event missed (0x1C32:0B). A frame then arrives at most one PWM
//!   period after the pulse that ended the previous one, and the outputs it brings are used at the next pulse.
//!
//! The firmware runs as on the target: [`EthercatSlave::poll`] (tier 3: AL control, mailbox, watchdog) after every
//! frame and idle event; [`EthercatSlave::cycle`] (the process-data cycle) where 0x1C32:01 says: after a frame
//! that wrote SM2 (SM-synchronous, ETG.1020 "SM2 event"), at each SYNC0 pulse ([`Esc::take_sync0`]; DC), or at
//! every slow tick (free run). The plant and the ESC's time advance in whole 40 us PWM periods; the rest of a
//! cycle that is not a whole number of periods is carried to the next one, so no time is lost.
//!
//! **The drive's oscillator** ([`DriveClock`], issue 6 item 2): the drive's PWM periods are `2 x ARR` ticks of
//! its own 168 MHz clock, which runs [`EthercatConfig::drive_clock_error_ppb`] off simulated (master) time (`drive-sim
//! ethercat --drive-clock-error-ppm`), so each period lasts `40 us / (1 + error)` of simulated time, lengthened or
//! shortened by the trim of the DC phase-locked loop ([`firmware::ecat::sync_pll`]). In DC mode every SYNC0 pulse
//! is captured where it fell in the drive's period (ticks from the period's start, as the board's capture timer
//! sees it) and fed to the loop, whose ARR applies from the next period on; without the loop
//! ([`EthercatRunner::set_sync_pll`]) the slow tick drifts through the bus cycle. The plant keeps stepping the
//! nominal 40 us: a few hundred ppm of step length changes the motor's motion by as little (the current
//! loop's and the plant's dynamics are not resolved to 0.05 %), and only the timing of the periods against SYNC0
//! is under test.

use std::cell::RefCell;
use std::io;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use firmware::boot::loader::Outcome;
use firmware::boot::program::{Interface, Request, SharedPort};
use firmware::boot::tables::{APPLICATION_TABLE, BOOTLOADER_TABLE};
use firmware::cia402::State;
use firmware::drive::objects::DriveObjects;
use firmware::ecat::esm::AlState;
use firmware::ecat::slave::EthercatSlave;
use firmware::ecat::sync::sync_type;
use firmware::ecat::sync_pll::{PllStatus, Sync0Capture, SyncPll};
use firmware::hal::power::{PWM_FREQUENCY_HZ, SLOW_TICK_DIVIDER};
use firmware::od::generated::handles as h;
use firmware::od::store::ParamStore;
use firmware::recorder::objects::RecorderObjects;

use super::update::{self, SimProgram};
use super::Simulation;
use crate::esc::datagram::{Command, FrameReport};
use crate::esc::socket::{serve_socket_tapped, Direction, RawSocket, ServeEvent};
use crate::esc::Esc;
use crate::flash::SimFlash;

/// One PWM period (the current-loop period and the simulation step), ns.
pub const PERIOD_NS: u64 = 1_000_000_000 / PWM_FREQUENCY_HZ as u64;

/// Most PWM periods one event may run in real-time mode (100 ms): a host that fell further behind skips the
/// rest (counted in [`RunnerStats::lag_events`]) instead of answering the next frame late.
pub const MAX_CATCH_UP_PERIODS: u64 = 2_500;

/// AL status register (0x0130), as the master reads it.
const AL_STATUS: u16 = 0x0130;

/// How simulated time advances.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClockMode {
    /// Simulated time follows the wall clock.
    RealTime,
    /// Simulated time advances by the master cycle with each cyclic frame.
    LockStep,
}

/// The runner's settings (the `drive-sim ethercat` options).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EthercatConfig {
    /// How simulated time advances.
    pub clock: ClockMode,
    /// The master's cycle in lock-step mode, ns (`--cycle-us`).
    pub cycle_ns: u64,
    /// Rate error of the ESC's local clock against simulated (master) time, parts per billion
    /// (`--clock-error-ppm` x 1000).
    pub clock_error_ppb: i64,
    /// Seed of the plant's noise.
    pub seed: u64,
    /// Lock-step only (`drive-sim ethercat --idle-cycle`): an idle poll (no frame within the poll interval) also
    /// runs one master cycle of simulated time, so that a master that goes quiet lets the ESC's process-data
    /// watchdog expire in simulated time (issue 6: the watchdog with a real master). Opt-in because it makes the
    /// wall clock part of the simulation again: a host hiccup longer than the poll interval between two cyclic
    /// frames inserts a cycle without outputs, which in DC mode counts an SM event missed (0x1C32:0B) and moves
    /// a CSP set-point one cycle late. Idle cycles run the master's cycle, not up to SYNC0.
    pub idle_cycle: bool,
    /// Rate error of the drive's oscillator (its PWM timebase) against simulated time, parts per billion, positive
    /// = fast = shorter periods (`--drive-clock-error-ppm` x 1000). See [`DriveClock`].
    pub drive_clock_error_ppb: i64,
}

impl Default for EthercatConfig {
    fn default() -> Self {
        Self {
            clock: ClockMode::RealTime,
            cycle_ns: 1_000_000,
            clock_error_ppb: 0,
            seed: 1,
            idle_cycle: false,
            drive_clock_error_ppb: 0,
        }
    }
}

/// What the runner counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunnerStats {
    /// EtherCAT frames processed and sent back.
    pub frames: u64,
    /// Frames dropped (malformed or not EtherCAT).
    pub dropped: u64,
    /// Idle polls (no frame within the poll interval).
    pub idle: u64,
    /// Frames that carried an LRW, LRD or LWR datagram.
    pub cyclic_frames: u64,
    /// Frames whose SM2 (outputs) buffer was completely written.
    pub sm2_writes: u64,
    /// [`EthercatSlave::cycle`] calls.
    pub cycles: u64,
    /// SYNC0 pulses seen by the runner.
    pub sync0_pulses: u64,
    /// SYNC0 pulses that fell due while an earlier one was still pending (the runner missed them; 0 in
    /// lock-step, which advances one PWM period at a time).
    pub sync0_missed: u64,
    /// Real-time catch-ups cut short at [`MAX_CATCH_UP_PERIODS`].
    pub lag_events: u64,
    /// The highest AL state the ESC's AL status register showed (0x0130 bits 3..0; OP 8 > SAFE-OP 4 > BOOT 3 >
    /// PRE-OP 2 > INIT 1).
    pub highest_al_state: u16,
    /// Simulated time of the last completed SM2 (outputs) write, ns: what the process-data watchdog counts from.
    pub last_sm2_write_ns: u64,
    /// Whether the AL status register (0x0130) shows the error flag (bit 4) now.
    pub al_error_shown: bool,
    /// Simulated time the AL status last raised its error flag, ns.
    pub al_error_ns: Option<u64>,
    /// Whether the drive's CiA 402 state is «Operation enabled» now.
    pub operation_enabled: bool,
    /// Simulated time the CiA 402 state last left «Operation enabled», ns, and the state it went to (the
    /// reaction of a fault such as 0x6007 on a communication loss).
    pub left_operation_enabled: Option<(u64, State)>,
    /// Real-time line: output writes held by the ESC until the drive's time reached their stamp, delivered
    /// ([`Esc::hold_output_writes`]).
    pub outputs_delivered: u64,
    /// Real-time line: held output writes dropped because the drive lagged by more than the queue's depth.
    pub output_overflows: u64,
    /// Real-time line: the most output writes held at once (how many frames the drive lagged behind).
    pub outputs_held_max: u64,
}

/// The drive as an EtherCAT slave on the simulated plant. See the module documentation.
#[derive(Debug)]
pub struct EthercatRunner {
    /// The emulated ESC (the master's side of the slave).
    pub esc: Esc,
    /// Everything behind the ESC's PDI.
    pub node: SlaveNode,
}

/// The PDI side of [`EthercatRunner`]: plant, drive and application layer, and the clock that drives them. Kept
/// apart from the [`Esc`] because the socket loop lends the ESC to its callback.
#[derive(Debug)]
pub struct SlaveNode {
    /// The reference plant and the firmware's drive.
    pub sim: Simulation,
    /// The firmware's EtherCAT application layer.
    pub slave: EthercatSlave,
    config: EthercatConfig,
    /// The drive's parameter store (0x1010 save / 0x1011 load over CoE, and what a reset loads).
    pub store: ParamStore<SimFlash>,
    /// Program control over the simulated update regions (0x1F50..0x1F57 over CoE, FoE in BOOT; issue 7). In a
    /// cell because the mailbox takes the CoE objects and the FoE sink at once ([`SharedPort`]).
    pub program: RefCell<SimProgram>,
    /// What the bootloader decided at the last simulated reset ([`update::reset`]).
    pub last_boot: Outcome,
    /// Simulated resets since power-on (an update's start or reset program).
    pub resets: u32,
    /// Whether an image on trial confirms itself once the slave reaches PRE-OP after its start (default on; off
    /// for the test that an image that never confirms is reverted).
    pub auto_confirm: bool,
    /// The simulator's own trace of tier 1's q current (`drive-sim ethercat --trace FILE`), one line a period.
    pub trace: Option<super::current_trace::CurrentTrace>,
    stats: RunnerStats,
    /// Simulated time not yet run because it is less than one PWM period, ns.
    owed_ns: u64,
    /// Wall-clock origin of real-time mode (the first event).
    origin: Option<Instant>,
    /// SM2 buffer completions seen so far (the ESC's counter).
    sm2_seen: u64,
    /// The drive's oscillator, PWM timebase and DC phase-locked loop.
    drive_clock: DriveClock,
}

impl EthercatRunner {
    /// The reference plant (noise seed from `config`), the default drive, the ESC with the drive's SII image
    /// and its clock error set, and the slave in INIT.
    pub fn new(config: EthercatConfig) -> Result<Self, String> {
        Self::with_plant(config, crate::plant::PlantParams::reference())
    }

    /// [`Self::new`] on the plant `params` (`drive-sim ethercat --plant FILE`), the drive's motor data written
    /// from its ratings ([`Simulation::commission_motor_data`]) when it is not the reference plant.
    pub fn with_plant(config: EthercatConfig, params: crate::plant::PlantParams) -> Result<Self, String> {
        let mut esc = Esc::with_drive_sii()?;
        esc.set_clock_error_ppb(config.clock_error_ppb);
        let mut program = update::factory_program();
        let last_boot = update::reset(&mut program);
        let mut sim = Simulation::new(params.clone(), config.seed, firmware::drive::DriveConfig::DEFAULT);
        // A master records through the data recorder (0x3300..0x3302) as on the board.
        sim.attach_recorder();
        update::use_table(&mut sim.drive, update::table_for(program.mode()));
        if params != crate::plant::PlantParams::reference() {
            sim.commission_motor_data(&params);
        }
        let node = SlaveNode {
            sim,
            slave: EthercatSlave::new(),
            config,
            store: ParamStore::new(SimFlash::params()),
            program: RefCell::new(program),
            last_boot,
            resets: 0,
            auto_confirm: true,
            trace: None,
            stats: RunnerStats::default(),
            owed_ns: 0,
            origin: None,
            sm2_seen: 0,
            drive_clock: DriveClock::new(config.drive_clock_error_ppb, config.clock_error_ppb),
        };
        Ok(Self { esc, node })
    }

    /// In-process master: processes `frame` in place as the socket path does and runs the firmware after it.
    /// Returns the ESC's report, or `None` for a dropped frame (which must not be answered).
    pub fn frame(&mut self, frame: &mut [u8]) -> Option<FrameReport> {
        match self.esc.process_frame(frame) {
            Ok(report) => {
                self.node.on_frame(&mut self.esc, &report);
                Some(report)
            }
            Err(_) => {
                self.node.on_dropped(&mut self.esc);
                None
            }
        }
    }

    /// An idle poll: no frame came.
    pub fn idle(&mut self) {
        self.node.on_idle(&mut self.esc);
    }

    /// Serves the ESC on network interface `iface` (raw socket; needs `CAP_NET_RAW`) until `stop` says so; `stop`
    /// is asked after every event with the counters so far. `poll` bounds the wait for a frame before an idle
    /// event.
    pub fn serve(&mut self, iface: &str, poll: Duration, stop: impl FnMut(&RunnerStats) -> bool) -> io::Result<()> {
        self.serve_tapped(iface, poll, |_, _| Ok(()), stop)
    }

    /// [`EthercatRunner::serve`] that hands every frame received and every answer sent to `tap` (a capture:
    /// `drive-sim ethercat --pcap`); see [`serve_socket_tapped`].
    pub fn serve_tapped(
        &mut self,
        iface: &str,
        poll: Duration,
        tap: impl FnMut(Direction, &[u8]) -> io::Result<()>,
        mut stop: impl FnMut(&RunnerStats) -> bool,
    ) -> io::Result<()> {
        let node = &mut self.node;
        let socket = RawSocket::bind(iface)?;
        serve_socket_tapped(&socket, &mut self.esc, poll, tap, |esc, event| {
            match event {
                ServeEvent::Frame(report) => node.on_frame(esc, report),
                ServeEvent::Dropped => node.on_dropped(esc),
                ServeEvent::Idle => node.on_idle(esc),
            }
            if stop(&node.stats) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
    }

    /// The counters.
    pub fn stats(&self) -> RunnerStats {
        let mut stats = self.node.stats;
        if let Some(h) = self.esc.held_outputs() {
            stats.outputs_delivered = h.delivered;
            stats.output_overflows = h.overflows;
            stats.outputs_held_max = h.held_max as u64;
        }
        stats
    }

    /// The firmware's ESM state.
    pub fn state(&self) -> AlState {
        self.node.slave.state()
    }

    /// SM event missed 0x1C32:0B as the firmware keeps it.
    pub fn sm_event_missed(&self) -> u16 {
        self.node.sim.drive.dictionary().get(h::SM2_SM_EVENT_MISSED)
    }

    /// Simulated time run so far, ns (the ESC's ideal time).
    pub fn simulated_ns(&self) -> u64 {
        self.esc.elapsed()
    }

    /// Switches the DC phase-locked loop on (the default) or off (the PWM periods then keep the drive's own
    /// clock: the test that the loop is what holds the phase).
    pub fn set_sync_pll(&mut self, on: bool) {
        self.node.drive_clock.pll_enabled = on;
    }

    /// The DC phase-locked loop's figures.
    pub fn sync_pll(&self) -> PllStatus {
        self.node.drive_clock.pll.status()
    }

    /// Where the last SYNC0 pulse fell in the drive's PWM timebase (its period index counts as
    /// [`Simulation::ticks`] does, from 0, so `period % 10` is the slow-tick phase).
    pub fn last_sync0_capture(&self) -> Option<Sync0Capture> {
        self.node.drive_clock.last_capture
    }
}

impl SlaveNode {
    /// The settings.
    pub fn config(&self) -> &EthercatConfig {
        &self.config
    }

    pub(crate) fn on_frame(&mut self, esc: &mut Esc, report: &FrameReport) {
        self.stats.frames = self.stats.frames.saturating_add(1);
        let cyclic = report.datagrams.iter().any(|(c, _)| matches!(c, Command::Lrw | Command::Lrd | Command::Lwr));
        let sm2_written = self.take_sm2_write(esc);
        self.poll(esc);
        // SM-synchronous: the SM2 event starts the cycle (ETG.1020 "Synchronous with SM2 event"); the outputs
        // of this frame reach the drive now, and the inputs it writes go out with the next frame.
        if sm2_written && self.sync_type() == sync_type::SM_SYNCHRONOUS {
            self.cycle(esc);
        }
        if cyclic {
            self.stats.cyclic_frames = self.stats.cyclic_frames.saturating_add(1);
        }
        match self.config.clock {
            ClockMode::LockStep if cyclic => {
                if !self.run_to_sync0(esc) {
                    self.run_for(esc, self.config.cycle_ns);
                }
            }
            ClockMode::LockStep => {}
            ClockMode::RealTime => self.catch_up(esc),
        }
    }

    pub(crate) fn on_dropped(&mut self, esc: &mut Esc) {
        self.stats.dropped = self.stats.dropped.saturating_add(1);
        self.poll(esc);
        if self.config.clock == ClockMode::RealTime {
            self.catch_up(esc);
        }
    }

    fn on_idle(&mut self, esc: &mut Esc) {
        self.stats.idle = self.stats.idle.saturating_add(1);
        self.poll(esc);
        match self.config.clock {
            // `EthercatConfig::idle_cycle`: a quiet master still lets simulated time run, one cycle per poll.
            ClockMode::LockStep if self.config.idle_cycle => self.run_for(esc, self.config.cycle_ns),
            ClockMode::LockStep => {}
            ClockMode::RealTime => self.catch_up(esc),
        }
    }

    /// Whether SM2's buffer was completed since the last look (the ESC counts completed writes).
    fn take_sm2_write(&mut self, esc: &Esc) -> bool {
        let writes = esc.sm_runtime(2).map_or(0, |sm| sm.writes);
        // A reconfigured SM2 restarts its counter.
        let written = writes != self.sm2_seen && writes > 0;
        self.sm2_seen = writes;
        if written {
            self.stats.sm2_writes = self.stats.sm2_writes.saturating_add(1);
            self.stats.last_sm2_write_ns = esc.elapsed();
        }
        written
    }

    /// 0x1C32:01 as the master left it.
    fn sync_type(&self) -> u16 {
        self.sim.drive.dictionary().get(h::SM2_SYNC_TYPE)
    }

    fn poll(&mut self, esc: &mut Esc) {
        let now_ms = u32::try_from(esc.elapsed() / 1_000_000).unwrap_or(u32::MAX);
        let before = self.slave.state();
        let on = self.sim.drive.power_stage_enabled();
        let mut drive_objects = DriveObjects::new(&mut self.store, on).with_program_control(SharedPort::new(
            &self.program,
            Interface::Ethercat,
            on,
        ));
        let mut app = RecorderObjects::new(&mut self.sim.recorder, &mut drive_objects);
        let mut foe = SharedPort::new(&self.program, Interface::Ethercat, on);
        self.slave.poll_with_foe(esc, &mut self.sim.drive, &mut app, &mut foe, now_ms);
        self.follow_program(before);
        let status = esc.register_u16(AL_STATUS);
        let error = status & 0x10 != 0;
        if error && !self.stats.al_error_shown {
            self.stats.al_error_ns = Some(esc.elapsed());
        }
        self.stats.al_error_shown = error;
        let state = status & 0x0F;
        if state > self.stats.highest_al_state {
            self.stats.highest_al_state = state;
        }
    }

    /// Acts on program control after a poll (issue 7): leaving BOOT ends an FoE download, an image on trial
    /// confirms itself in PRE-OP (the fieldbus is up: a successful start), and a stop, start or reset changes
    /// the dictionary or restarts the drive.
    fn follow_program(&mut self, before: AlState) {
        let after = self.slave.state();
        let program = self.program.get_mut();
        if before == AlState::Boot && after != AlState::Boot {
            program.leave_bootstrap();
        }
        if after == AlState::PreOp && self.auto_confirm && program.on_trial() {
            let _ = program.confirm();
        }
        match program.take_request() {
            Some(Request::Stop) => update::use_table(&mut self.sim.drive, BOOTLOADER_TABLE),
            Some(Request::Start) => update::use_table(&mut self.sim.drive, APPLICATION_TABLE),
            Some(Request::Reset) => self.reset(),
            None => {}
        }
    }

    /// A simulated reset of the drive's microcontroller: the bootloader runs over the update regions, then the
    /// drive starts from its parameter store and the slave from INIT (the ESC and the plant keep running).
    pub fn reset(&mut self) {
        self.last_boot = update::reset(self.program.get_mut());
        self.sim.replace_drive(update::boot_drive(&mut self.store, self.program.get_mut()));
        self.slave = EthercatSlave::new();
        self.resets = self.resets.saturating_add(1);
    }

    fn cycle(&mut self, esc: &mut Esc) {
        // The ESC's local time, wrapped to 32 bits as the firmware's counters expect.
        let now_ns = esc.local_time() as u32;
        self.slave.cycle(esc, &mut self.sim.drive, now_ns);
        self.stats.cycles = self.stats.cycles.saturating_add(1);
    }

    /// Runs `ns` of simulated time in whole PWM periods (the rest is owed to the next call).
    fn run_for(&mut self, esc: &mut Esc, ns: u64) {
        self.owed_ns = self.owed_ns.saturating_add(ns);
        let periods = self.owed_ns / PERIOD_NS;
        self.owed_ns %= PERIOD_NS;
        for _ in 0..periods {
            self.step(esc);
        }
    }

    /// Lock-step in DC mode (see the module documentation): runs whole PWM periods until the next SYNC0 pulse
    /// has fired, if 0x1C32:01 asks for DC, SYNC0 is armed and its next pulse is due within one cycle (so
    /// that a start time far ahead, as SOEM's `dc_sync` sets it, is reached at the master's own cycle first).
    /// Returns whether it ran; a cycle carry owed by [`Self::run_for`] is dropped (the ESC's clock sets the
    /// pace now).
    fn run_to_sync0(&mut self, esc: &mut Esc) -> bool {
        if self.sync_type() != sync_type::DC_SYNC0 {
            return false;
        }
        let (Some(cycle), Some(next_in)) = (esc.sync0_cycle(), esc.next_sync0_in()) else { return false };
        let cycle = u64::from(cycle);
        if next_in > cycle {
            return false;
        }
        self.owed_ns = 0;
        // Bounded: the pulse is at most one cycle (of local time, which runs at most 0.1 % off) away.
        let max_periods = (3 * cycle).div_ceil(PERIOD_NS) + 1;
        let pulses = self.stats.sync0_pulses;
        for _ in 0..max_periods {
            self.step(esc);
            if self.stats.sync0_pulses != pulses {
                break;
            }
        }
        true
    }

    /// Real-time mode: runs the plant up to the wall clock (at most [`MAX_CATCH_UP_PERIODS`] at once).
    fn catch_up(&mut self, esc: &mut Esc) {
        self.catch_up_at_most(esc, MAX_CATCH_UP_PERIODS);
    }

    /// The real-time line's frame path ([`super::ethercat_line::EthercatLine::serve_real_time`]): counts a frame
    /// the ESC answered; the firmware sees its effects at the drive's next [`Self::service_real_time`].
    pub(crate) fn count_frame(&mut self, report: &FrameReport) {
        self.stats.frames = self.stats.frames.saturating_add(1);
        if report.datagrams.iter().any(|(c, _)| matches!(c, Command::Lrw | Command::Lrd | Command::Lwr)) {
            self.stats.cyclic_frames = self.stats.cyclic_frames.saturating_add(1);
        }
    }

    /// The real-time line's drive side, called by a worker thread again and again (the ESC's PDI side): the
    /// SM2 event of the frames since the last call (the SM-synchronous cycle), the firmware's poll (AL control,
    /// mailbox, watchdog), then simulated time towards the wall clock, at most `chunk` PWM periods so that the
    /// ESC is not held from the frame path for longer. Returns whether the drive is still behind the wall clock.
    pub(crate) fn service_real_time(&mut self, esc: &mut Esc, chunk: u64) -> bool {
        self.service_before_step(esc);
        self.catch_up_at_most(esc, chunk)
    }

    /// [`Self::service_real_time`] with `periods` PWM periods instead of the wall clock's: the drive's side of
    /// the real-time line stepped by a caller that decides how late it runs (tests).
    #[cfg(test)]
    pub(crate) fn service_periods(&mut self, esc: &mut Esc, periods: u64) {
        self.service_before_step(esc);
        for _ in 0..periods {
            self.step(esc);
        }
    }

    fn service_before_step(&mut self, esc: &mut Esc) {
        let sm2_written = self.take_sm2_write(esc);
        self.poll(esc);
        if sm2_written && self.sync_type() == sync_type::SM_SYNCHRONOUS {
            self.cycle(esc);
        }
    }

    /// The real-time line's frame path: the ESC's DC system time at which a frame that arrived at wall-clock
    /// `arrived` reaches this drive's ESC, `port_delay_ns` after the line's first port: the arrival on this
    /// drive's simulated time (whose origin is the wall clock's, [`Self::catch_up_at_most`]) mapped to the ESC's
    /// clock ([`Esc::system_time_at`]). The stamp of the output writes the frame makes.
    pub(crate) fn write_stamp(&mut self, esc: &Esc, arrived: Instant, port_delay_ns: u64) -> u64 {
        let origin = *self.origin.get_or_insert(arrived);
        let since = u64::try_from(arrived.saturating_duration_since(origin).as_nanos()).unwrap_or(u64::MAX);
        esc.system_time_at(since.saturating_add(port_delay_ns))
    }

    /// Runs the plant towards the wall clock, at most `limit` PWM periods now; a lag beyond
    /// [`MAX_CATCH_UP_PERIODS`] is given up and counted. Returns whether periods remain to be run.
    fn catch_up_at_most(&mut self, esc: &mut Esc, limit: u64) -> bool {
        let origin = *self.origin.get_or_insert_with(Instant::now);
        let wall_ns = u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let behind = wall_ns.saturating_sub(esc.elapsed().saturating_add(self.owed_ns));
        let mut periods = behind.saturating_add(self.owed_ns) / PERIOD_NS;
        if periods > MAX_CATCH_UP_PERIODS {
            self.stats.lag_events = self.stats.lag_events.saturating_add(1);
            // Give up the time that cannot be caught up: the origin moves so that the next event starts from
            // here instead of racing to recover it.
            let skipped = (periods - MAX_CATCH_UP_PERIODS).saturating_mul(PERIOD_NS);
            self.origin = Some(origin + Duration::from_nanos(skipped));
            periods = MAX_CATCH_UP_PERIODS;
        }
        for _ in 0..periods.min(limit) {
            self.step(esc);
        }
        periods > limit
    }

    /// One PWM period: plant and drive, the ESC's time (SYNC0, watchdogs), and the cycle SYNC0 or free run
    /// starts.
    fn step(&mut self, esc: &mut Esc) {
        self.sim.step();
        if let Some(trace) = self.trace.as_mut() {
            trace.record(&self.sim, self.sim.ticks().is_multiple_of(u64::from(SLOW_TICK_DIVIDER)));
        }
        let state = self.sim.cia402_state();
        let enabled = state == State::OperationEnabled;
        if self.stats.operation_enabled && !enabled {
            self.stats.left_operation_enabled = Some((esc.elapsed(), state));
        }
        self.stats.operation_enabled = enabled;
        esc.advance(self.drive_clock.next_period_ns());
        let sync = self.sync_type();
        self.drive_clock.follow_dc_mode(esc, sync == sync_type::DC_SYNC0);
        // Held output writes (the real-time line; none in lock-step) reach the PDI when this period passes
        // their stamp: those before a SYNC0 pulse are the outputs of its cycle, the rest wait for the next.
        let mut delivered = 0;
        if let Some(pulse) = esc.take_sync0() {
            self.stats.sync0_pulses = self.stats.sync0_pulses.saturating_add(u64::from(pulse.count));
            self.stats.sync0_missed = self.stats.sync0_missed.saturating_add(u64::from(pulse.count.saturating_sub(1)));
            delivered += esc.deliver_held_writes(pulse.system_time);
            if sync == sync_type::DC_SYNC0 {
                self.drive_clock.on_sync0(esc, pulse.system_time);
                self.cycle(esc);
            }
        }
        delivered += esc.deliver_held_writes(esc.system_time());
        if delivered > 0 && self.take_sm2_write(esc) && sync == sync_type::SM_SYNCHRONOUS {
            // The SM2 event starts the SM-synchronous cycle when the write reaches the PDI.
            self.cycle(esc);
        }
        if sync == sync_type::FREE_RUN && self.sim.ticks().is_multiple_of(u64::from(SLOW_TICK_DIVIDER)) {
            self.cycle(esc);
        }
    }
}

/// The drive's oscillator and PWM timebase in the runner, and the DC phase-locked loop that trims it (see the
/// module documentation). Period boundaries are kept as the drive's tick count since the start and converted to
/// simulated ns from there, so no rounding accumulates.
#[derive(Debug)]
pub struct DriveClock {
    /// Rate error of the drive's oscillator, ppb.
    error_ppb: i64,
    /// Rate error of the ESC's clock, ppb (to place a SYNC0 pulse in simulated time).
    esc_error_ppb: i64,
    /// The firmware's loop.
    pll: SyncPll,
    /// Whether the loop may run (DC mode decides when it does).
    pll_enabled: bool,
    /// Index of the period in progress (`u64::MAX` before the first).
    period: u64,
    /// Drive ticks from the start to the start of the period in progress.
    start_ticks: u128,
    /// ARR of the period in progress.
    arr: u16,
    /// The last capture fed to the loop.
    last_capture: Option<Sync0Capture>,
}

impl DriveClock {
    /// The drive's clock `error_ppb` off, the ESC's `esc_error_ppb`; the loop enabled, off until DC mode.
    pub fn new(error_ppb: i64, esc_error_ppb: i64) -> Self {
        Self {
            error_ppb,
            esc_error_ppb,
            pll: SyncPll::new(),
            pll_enabled: true,
            period: u64::MAX,
            start_ticks: 0,
            arr: firmware::hal::power::PWM_PERIOD_TICKS,
            last_capture: None,
        }
    }

    /// Simulated ns from the start to `ticks` of the drive's clock: `ticks / (168 MHz x (1 + error))`.
    fn ns_at(&self, ticks: u128) -> u64 {
        let hz_ppb = 168 * (1_000_000_000 + i128::from(self.error_ppb)).max(1);
        u64::try_from(i128::try_from(ticks).unwrap_or(i128::MAX) * 1_000_000_000_000 / hz_ppb).unwrap_or(u64::MAX)
    }

    /// Starts the next PWM period (its ARR from the loop when it runs, else nominal) and returns its length in
    /// simulated ns.
    fn next_period_ns(&mut self) -> u64 {
        if self.period != u64::MAX {
            self.start_ticks += 2 * u128::from(self.arr);
        }
        self.period = self.period.wrapping_add(1);
        self.arr = self.pll.arr(self.period as u32);
        let end = self.start_ticks + 2 * u128::from(self.arr);
        self.ns_at(end) - self.ns_at(self.start_ticks)
    }

    /// Runs the loop while DC mode is on with a supported SYNC0 cycle (0x09A0) and it is enabled; stops it
    /// otherwise. Also the loop's holdover supervision (on the target: the slow tier).
    fn follow_dc_mode(&mut self, esc: &Esc, dc: bool) {
        match esc.sync0_cycle() {
            Some(cycle) if dc && self.pll_enabled => {
                let per = firmware::ecat::sync::CURRENT_PERIOD_NS;
                if self.pll.periods_per_cycle().saturating_mul(per) != cycle {
                    // An unsupported cycle leaves the loop off (nominal periods).
                    let _ = self.pll.start(cycle);
                }
            }
            _ => self.pll.stop(),
        }
        self.pll.supervise(self.period as u32);
    }

    /// A SYNC0 pulse at ESC system time `pulse_system_time` fell in the period just run: where, in the drive's
    /// ticks (even, as the 84 MHz capture timer counts), goes to the loop.
    fn on_sync0(&mut self, esc: &Esc, pulse_system_time: u64) {
        // How long ago the pulse was, in ESC (local) ns, then in simulated ns.
        let ago_local = i128::from(esc.system_time().wrapping_sub(pulse_system_time));
        let ago = ago_local * 1_000_000_000 / (1_000_000_000 + i128::from(self.esc_error_ppb)).max(1);
        let end = self.start_ticks + 2 * u128::from(self.arr);
        let length = i128::from(self.ns_at(end)) - i128::from(self.ns_at(self.start_ticks));
        let into_ns = (length - ago).max(0);
        let ticks = into_ns * 168 * (1_000_000_000 + i128::from(self.error_ppb)) / 1_000_000_000_000;
        let last = 2 * i128::from(self.arr) - 1;
        let ticks = u16::try_from(ticks.min(last)).unwrap_or(0) & !1;
        let capture = Sync0Capture { period: self.period as u32, ticks };
        self.last_capture = Some(capture);
        if self.pll_enabled {
            self.pll.on_sync0(capture);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::esc::datagram::FrameBuilder;

    fn lock_step(cycle_ns: u64, clock_error_ppb: i64) -> EthercatRunner {
        let config =
            EthercatConfig { clock: ClockMode::LockStep, cycle_ns, clock_error_ppb, ..EthercatConfig::default() };
        EthercatRunner::new(config).expect("drive SII")
    }

    fn send(r: &mut EthercatRunner, frame: FrameBuilder) -> FrameReport {
        let mut f = frame.build();
        r.frame(&mut f).expect("a well-formed frame is processed")
    }

    fn lrw() -> FrameBuilder {
        FrameBuilder::new().push_logical(Command::Lrw, 0, &[0; 4])
    }

    /// Arms SYNC0 as a master does (ESC datasheet: 0x09A0 cycle, 0x0990 start time, 0x0981 = 0x03 activate).
    fn arm_sync0(r: &mut EthercatRunner, cycle_ns: u32, start_ns: u64) {
        send(
            r,
            FrameBuilder::new()
                .push(Command::Bwr, 0, 0x09A0, &cycle_ns.to_le_bytes())
                .push(Command::Bwr, 0, 0x0990, &start_ns.to_le_bytes())
                .push(Command::Bwr, 0, 0x0981, &[0x03]),
        );
    }

    #[test]
    fn lock_step_advances_one_cycle_per_cyclic_frame_and_not_otherwise() {
        let mut r = lock_step(1_000_000, 0);
        send(&mut r, FrameBuilder::new().push(Command::Brd, 0, 0x0130, &[0; 2]));
        r.idle();
        assert_eq!(r.simulated_ns(), 0, "mailbox and idle events leave simulated time alone");
        for _ in 0..10 {
            send(&mut r, lrw());
        }
        assert_eq!(r.simulated_ns(), 10_000_000);
        assert_eq!(r.node.sim.ticks(), 250, "25 PWM periods per 1 ms cycle");
        for k in [Command::Lrd, Command::Lwr] {
            send(&mut r, FrameBuilder::new().push_logical(k, 0, &[0; 2]));
        }
        assert_eq!(r.simulated_ns(), 12_000_000);
        let s = r.stats();
        assert_eq!((s.frames, s.cyclic_frames, s.idle), (13, 12, 1));
    }

    #[test]
    fn a_cycle_that_is_not_whole_pwm_periods_carries_the_rest() {
        // 100 us = 2.5 periods: two frames run 5 periods, none is lost or gained.
        let mut r = lock_step(100_000, 0);
        send(&mut r, lrw());
        assert_eq!(r.simulated_ns(), 80_000);
        send(&mut r, lrw());
        assert_eq!(r.simulated_ns(), 200_000);
        assert_eq!(r.node.sim.ticks(), 5);
    }

    #[test]
    fn the_clock_error_runs_the_esc_local_clock_off_simulated_time() {
        let mut r = lock_step(1_000_000, 100_000);
        for _ in 0..1_000 {
            send(&mut r, lrw());
        }
        assert_eq!(r.esc.elapsed(), 1_000_000_000);
        assert_eq!(r.esc.local_time(), 1_000_100_000, "+100 ppm over 1 s is 100 us");
    }

    #[test]
    fn in_dc_mode_every_sync0_pulse_starts_one_cycle_and_none_is_missed() {
        let mut r = lock_step(1_000_000, 100_000);
        r.node.sim.drive.dictionary_mut().set(h::SM2_SYNC_TYPE, sync_type::DC_SYNC0);
        // SYNC0 every 1 ms from 0.5 ms on (ESC datasheet: 0x09A0 cycle, 0x0990 start, 0x0981 = 0x03 activate).
        arm_sync0(&mut r, 1_000_000, 500_000);
        for _ in 0..100 {
            send(&mut r, lrw());
        }
        let s = r.stats();
        // The local clock is 100 ppm fast: after 100 ms it is 10 us ahead, still 100 pulses.
        assert_eq!(s.sync0_pulses, 100);
        assert_eq!(s.sync0_missed, 0);
        assert_eq!(s.cycles, 100);
    }

    #[test]
    fn in_dc_mode_lock_step_follows_the_esc_clock_so_a_fast_clock_gains_no_sync0_pulse() {
        // +1000 ppm (the option's limit): with a fixed 1 ms per frame, 3,000 frames would run 3,000 ms of
        // simulated time and see 3,003 pulses. Locked to SYNC0, each frame is followed by exactly one.
        let mut r = lock_step(1_000_000, 1_000_000);
        r.node.sim.drive.dictionary_mut().set(h::SM2_SYNC_TYPE, sync_type::DC_SYNC0);
        arm_sync0(&mut r, 1_000_000, 500_000);
        for k in 1..=3_000u64 {
            send(&mut r, lrw());
            assert_eq!(r.stats().sync0_pulses, k, "one SYNC0 pulse per frame (frame {k})");
        }
        let s = r.stats();
        assert_eq!((s.sync0_missed, s.cycles), (0, 3_000));
        // The ESC's clock ran 3,000 cycles (less 0.5 ms to the first pulse) in 1000 ppm less simulated time.
        let local = r.esc.local_time();
        assert!((2_999_500_000..2_999_500_000 + PERIOD_NS + 1_000).contains(&local), "local {local}");
        let ideal = r.simulated_ns();
        assert!(ideal < 2_997_000_000 && ideal > 2_996_000_000, "simulated {ideal}");
    }

    #[test]
    fn without_sync0_armed_dc_lock_step_keeps_the_master_cycle() {
        let mut r = lock_step(1_000_000, 1_000_000);
        r.node.sim.drive.dictionary_mut().set(h::SM2_SYNC_TYPE, sync_type::DC_SYNC0);
        // SYNC0 armed, but its start 10 ms ahead: the master's cycle runs until it is one cycle away.
        arm_sync0(&mut r, 1_000_000, 10_000_000);
        for _ in 0..5 {
            send(&mut r, lrw());
        }
        assert_eq!(r.simulated_ns(), 5_000_000);
        assert_eq!(r.stats().sync0_pulses, 0);
    }

    #[test]
    fn sm_synchronous_cycles_follow_the_sm2_writes() {
        let mut r = lock_step(1_000_000, 0);
        // SM2: 4 bytes at 0x1100, buffered, master writes, enabled (ETG.1000.4 SM register layout).
        let sm2 = [0x00, 0x11, 0x04, 0x00, 0x24, 0x00, 0x01, 0x00];
        send(&mut r, FrameBuilder::new().push(Command::Bwr, 0, 0x0810, &sm2));
        // The PDI releases the process-data SMs (PDI control bit 0), as the firmware does for SAFE-OP.
        r.esc.pdi_write(0x0817, &[0]);
        for _ in 0..5 {
            send(&mut r, FrameBuilder::new().push(Command::Bwr, 0, 0x1100, &[1, 2, 3, 4]));
        }
        // A frame that does not reach SM2's last byte completes no buffer.
        send(&mut r, FrameBuilder::new().push(Command::Bwr, 0, 0x1100, &[1, 2]));
        let s = r.stats();
        assert_eq!(s.sm2_writes, 5);
        assert_eq!(s.cycles, 5, "default 0x1C32:01 = 1: SM-synchronous");
    }

    #[test]
    fn a_malformed_frame_is_dropped_and_counted() {
        let mut r = lock_step(1_000_000, 0);
        let mut f = lrw().build();
        // EtherCAT header length far beyond the frame.
        f[14] = 0xFF;
        f[15] = 0x17;
        assert!(r.frame(&mut f).is_none());
        assert_eq!(r.stats().dropped, 1);
        assert_eq!(r.simulated_ns(), 0);
    }

    #[test]
    fn real_time_mode_runs_the_plant_up_to_the_wall_clock() {
        let config = EthercatConfig { clock: ClockMode::RealTime, ..EthercatConfig::default() };
        let mut r = EthercatRunner::new(config).expect("drive SII");
        r.idle();
        std::thread::sleep(Duration::from_millis(20));
        r.idle();
        let t = r.simulated_ns();
        // At least the 20 ms slept (minus one period of rounding); at most the catch-up bound.
        assert!(t >= 20_000_000 - PERIOD_NS, "{t}");
        assert!(t <= MAX_CATCH_UP_PERIODS * PERIOD_NS * 2, "{t}");
    }

    /// The runner with an in-process master, brought to OP in DC mode (SYNC0 every 1 ms, 0x1C32:01 = 2) in
    /// lock-step, as the multi-axis tests' masters do.
    struct DcRig {
        r: EthercatRunner,
        image: Vec<u8>,
    }

    const STATION: u16 = 0x1001;
    const LOGICAL: u32 = 0x0001_0000;
    const CYCLE_NS: u64 = 1_000_000;

    impl DcRig {
        fn op() -> Self {
            use firmware::ecat::process_data::ProcessDataLayout;
            use firmware::od::generated as g;
            let mut rig = Self { r: lock_step(CYCLE_NS, 0), image: Vec::new() };
            rig.fpwr_ap(0x0010, &STATION.to_le_bytes());
            rig.sm(0, g::MAILBOX_OUT_START, g::MAILBOX_OUT_SIZE, 0x26);
            rig.sm(1, g::MAILBOX_IN_START, g::MAILBOX_IN_SIZE, 0x22);
            assert_eq!(rig.request(0x0002), (0x0002, 0), "PRE-OP");
            let layout = ProcessDataLayout::compile(rig.r.node.sim.drive.dictionary()).expect("default mapping");
            let (out_len, in_len) = (layout.output_bytes, layout.input_bytes);
            rig.sm(2, g::PROCESS_OUT_START, out_len, 0x64);
            rig.sm(3, g::PROCESS_IN_START, in_len, 0x20);
            rig.fmmu(0, LOGICAL, out_len, g::PROCESS_OUT_START, 0x02);
            rig.fmmu(1, LOGICAL + u32::from(out_len), in_len, g::PROCESS_IN_START, 0x01);
            rig.image = vec![0; usize::from(out_len + in_len)];
            rig.r.node.sim.drive.dictionary_mut().set(h::SM2_SYNC_TYPE, sync_type::DC_SYNC0);
            rig.r.node.sim.drive.dictionary_mut().set(h::SM3_SYNC_TYPE, sync_type::DC_SYNC0);
            rig.fpwr(0x09A0, &(CYCLE_NS as u32).to_le_bytes());
            let start = rig.r.esc.system_time() + CYCLE_NS / 2;
            rig.fpwr(0x0990, &start.to_le_bytes());
            rig.fpwr(0x0981, &[0x03]);
            assert_eq!(rig.request(0x0004), (0x0004, 0), "SAFE-OP in DC");
            for _ in 0..3 {
                rig.lock_step_cycle();
            }
            assert_eq!(rig.request(0x0008), (0x0008, 0), "OP");
            for _ in 0..10 {
                rig.lock_step_cycle();
            }
            rig
        }

        fn datagram(&mut self, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
            let mut f = FrameBuilder::new().push(cmd, adp, ado, data).build();
            self.r.frame(&mut f).expect("a well-formed frame");
            let frame = crate::esc::datagram::Frame::new_checked(&f).expect("parses");
            let d = frame.datagram(0).expect("one datagram");
            (d.data().to_vec(), d.wkc())
        }

        fn fpwr_ap(&mut self, ado: u16, data: &[u8]) {
            assert_eq!(self.datagram(Command::Apwr, 0, ado, data).1, 1);
        }

        fn fpwr(&mut self, ado: u16, data: &[u8]) {
            assert_eq!(self.datagram(Command::Fpwr, STATION, ado, data).1, 1, "FPWR 0x{ado:04X}");
        }

        fn sm(&mut self, n: u16, start: u16, len: u16, control: u8) {
            let [s0, s1] = start.to_le_bytes();
            let [l0, l1] = len.to_le_bytes();
            self.fpwr(0x0800 + 8 * n, &[s0, s1, l0, l1, control, 0, 0x01, 0]);
        }

        fn fmmu(&mut self, n: u16, logical: u32, len: u16, physical: u16, kind: u8) {
            let mut regs = logical.to_le_bytes().to_vec();
            regs.extend_from_slice(&len.to_le_bytes());
            regs.extend_from_slice(&[0, 7]);
            regs.extend_from_slice(&physical.to_le_bytes());
            regs.extend_from_slice(&[0, kind, 1, 0, 0, 0]);
            self.fpwr(0x0600 + 16 * n, &regs);
        }

        fn request(&mut self, control: u16) -> (u16, u16) {
            self.fpwr(0x0120, &control.to_le_bytes());
            let (d, _) = self.datagram(Command::Fprd, STATION, 0x0130, &[0; 6]);
            (u16::from_le_bytes([d[0], d[1]]), u16::from_le_bytes([d[4], d[5]]))
        }

        /// AL status and AL status code as the ESC shows them, without a frame.
        fn al(&self) -> (u16, u16) {
            (self.r.esc.register_u16(0x0130), self.r.esc.register_u16(0x0134))
        }

        fn lock_step_cycle(&mut self) {
            let mut f = FrameBuilder::new().push_logical(Command::Lrw, LOGICAL, &self.image).build();
            self.r.frame(&mut f).expect("a well-formed frame");
        }

        /// The real-time frame path: an LRW processed by the ESC at once (the drive not stepped), its output
        /// write stamped with `system_time` (ignored unless the ESC holds output writes). Returns the working
        /// counter.
        fn frame_at(&mut self, system_time: u64) -> u16 {
            let mut f = FrameBuilder::new().push_logical(Command::Lrw, LOGICAL, &self.image).build();
            self.r.esc.set_write_stamp(Some(system_time));
            let report = self.r.esc.process_frame(&mut f).expect("a well-formed frame");
            self.r.esc.set_write_stamp(None);
            self.r.node.count_frame(&report);
            crate::esc::datagram::Frame::new_checked(&f).expect("parses").datagram(0).expect("LRW").wkc()
        }
    }

    /// What a late-stepped run saw.
    #[derive(Debug)]
    struct LateRun {
        /// SYNC0 pulses after the first frame.
        pulses: u64,
        /// Pulses at which the outputs delivered so far were not exactly the frames stamped before the pulse.
        pulses_off_by_frames: u64,
        /// 0x1C32:0B at the end.
        sm_event_missed: u16,
        /// AL status and code at the end.
        al: (u16, u16),
        /// Output writes delivered and dropped.
        delivered: u64,
        overflows: u64,
        /// LRW frames whose working counter was not 3 (outputs written, inputs read).
        wkc_not_3: u64,
    }

    /// 1,000 cycles of the real-time line's pattern without the wall clock: frame `k` arrives (its stamp)
    /// 100..=800 us before SYNC0 pulse `k`, spread over the cycle; the frame path processes every frame at
    /// once; the drive is stepped late and in chunks of 5 PWM periods: only at every third frame, and then only
    /// up to 0..=900 us before that frame's arrival, so that it runs 0 to 3.9 cycles behind the frames.
    /// `hold`: the ESC holds the output writes for the drive (the real-time line) or publishes them at once.
    fn late_run(hold: bool) -> LateRun {
        let mut rig = DcRig::op();
        assert_eq!(rig.al(), (0x0008, 0));
        rig.r.esc.hold_output_writes(if hold { 16 } else { 0 });
        let first_pulse = rig.r.esc.system_time() + rig.r.esc.next_sync0_in().expect("SYNC0 armed");
        let pulses0 = rig.r.stats().sync0_pulses;
        let mut stamps: Vec<u64> = Vec::new();
        let mut off = 0;
        let mut wkc_not_3 = 0;
        let mut last_pulses = pulses0;
        for k in 0..1_000u64 {
            let stamp = first_pulse + k * CYCLE_NS - 100_000 - (k * 37 % 8) * 100_000;
            if k % 3 == 0 {
                let target = stamp.saturating_sub((k * 7_919 % 10) * 100_000);
                while rig.r.esc.system_time() + PERIOD_NS <= target {
                    let behind = (target - rig.r.esc.system_time()) / PERIOD_NS;
                    // Period by period within the chunk, to look at every pulse as it fires.
                    for _ in 0..behind.min(5) {
                        rig.r.node.service_periods(&mut rig.r.esc, 1);
                        let s = rig.r.stats();
                        if s.sync0_pulses != last_pulses {
                            last_pulses = s.sync0_pulses;
                            let pulse = first_pulse + (s.sync0_pulses - pulses0 - 1) * CYCLE_NS;
                            let due = stamps.iter().filter(|&&t| t <= pulse).count() as u64;
                            let seen = if hold { s.outputs_delivered } else { stamps.len() as u64 };
                            if seen != due {
                                off += 1;
                            }
                        }
                    }
                }
            }
            if rig.frame_at(stamp) != 3 {
                wkc_not_3 += 1;
            }
            stamps.push(stamp);
        }
        let s = rig.r.stats();
        LateRun {
            pulses: s.sync0_pulses - pulses0,
            pulses_off_by_frames: off,
            sm_event_missed: rig.r.sm_event_missed(),
            al: rig.al(),
            delivered: s.outputs_delivered,
            overflows: s.output_overflows,
            wkc_not_3,
        }
    }

    #[test]
    fn held_output_writes_give_a_late_stepped_drive_exactly_the_frame_of_each_sync0_cycle_and_no_0x001a() {
        // ETG.1020 0x1C32:0B counts a SYNC0 without fresh outputs; the sync error 0x001A (ETG.1000.6 AL status
        // codes) follows when the counter passes 0x10F1:02. With the writes held until the drive's time passes
        // their stamps, every pulse finds exactly the frames that arrived before it, whatever the lag.
        let run = late_run(true);
        assert!(run.pulses >= 990, "the drive ran (nearly) all 1,000 cycles: {run:?}");
        assert_eq!(run.pulses_off_by_frames, 0, "each pulse saw exactly the frames stamped before it: {run:?}");
        assert_eq!(run.sm_event_missed, 0, "no SM event missed (0x1C32:0B): {run:?}");
        assert_eq!(run.al, (0x0008, 0x0000), "still OP, no AL status code: {run:?}");
        assert_eq!(run.overflows, 0, "a lag of under 4 cycles fits the queue of 16: {run:?}");
        assert!(run.delivered >= run.pulses, "one write delivered per pulse: {run:?}");
        assert_eq!(run.wkc_not_3, 0, "every LRW counted 3: {run:?}");
    }

    #[test]
    fn without_holding_the_same_late_stepped_drive_misses_sm_events_and_leaves_op_with_0x001a() {
        // The behaviour before the stamps: outputs published when the frame path writes them reach a lagging
        // drive together, so one SYNC0 finds several frames' outputs and the next none.
        let run = late_run(false);
        assert!(run.pulses_off_by_frames > 0, "{run:?}");
        assert!(run.sm_event_missed > 0, "{run:?}");
        assert_eq!(run.al, (0x0014, 0x001A), "SAFE-OP + error, sync error 0x001A: {run:?}");
        // The firmware deactivated SM2 (0x0817 bit 0) on the error: the ESC refuses the outputs from then on
        // and the LRW counts 1 (inputs read), how the master sees the slave's error (ETG.1000.4 §5.4).
        assert!(run.wkc_not_3 > 0, "{run:?}");
    }

    #[test]
    fn a_held_queue_that_overflows_counts_it_and_delivers_the_newest() {
        // A real ESC's three buffers keep the newest write: so does the queue when the drive lags by more than
        // its depth.
        let mut rig = DcRig::op();
        rig.r.esc.hold_output_writes(4);
        let now = rig.r.esc.system_time();
        for k in 0..6u64 {
            rig.image[0] = k as u8 + 1;
            rig.frame_at(now + 100_000 + k * 10_000);
        }
        let s = rig.r.stats();
        assert_eq!((s.output_overflows, s.outputs_held_max), (2, 4));
        rig.r.node.service_periods(&mut rig.r.esc, 10);
        let s = rig.r.stats();
        assert_eq!(s.outputs_delivered, 4);
        let sm2 = rig.r.esc.sm_runtime(2).expect("SM2");
        let newest = sm2.latest.and_then(|b| sm2.bufs.get(b)).expect("a complete buffer");
        assert_eq!(newest[0], 6, "the newest frame's outputs are the last delivered");
    }
}
