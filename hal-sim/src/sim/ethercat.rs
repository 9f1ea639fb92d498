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

use std::io;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use firmware::ecat::esm::AlState;
use firmware::ecat::slave::EthercatSlave;
use firmware::ecat::sync::sync_type;
use firmware::hal::power::{PWM_FREQUENCY_HZ, SLOW_TICK_DIVIDER};
use firmware::od::access::NoApplicationObjects;
use firmware::od::generated::handles as h;

use super::Simulation;
use crate::esc::datagram::{Command, FrameReport};
use crate::esc::socket::{serve_socket_tapped, Direction, RawSocket, ServeEvent};
use crate::esc::Esc;

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
}

impl Default for EthercatConfig {
    fn default() -> Self {
        Self { clock: ClockMode::RealTime, cycle_ns: 1_000_000, clock_error_ppb: 0, seed: 1 }
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
    app: NoApplicationObjects,
    stats: RunnerStats,
    /// Simulated time not yet run because it is less than one PWM period, ns.
    owed_ns: u64,
    /// Wall-clock origin of real-time mode (the first event).
    origin: Option<Instant>,
    /// SM2 buffer completions seen so far (the ESC's counter).
    sm2_seen: u64,
}

impl EthercatRunner {
    /// The reference plant (noise seed from `config`), the default drive, the ESC with the drive's SII image
    /// and its clock error set, and the slave in INIT.
    pub fn new(config: EthercatConfig) -> Result<Self, String> {
        let mut esc = Esc::with_drive_sii()?;
        esc.set_clock_error_ppb(config.clock_error_ppb);
        let node = SlaveNode {
            sim: Simulation::reference(config.seed),
            slave: EthercatSlave::new(),
            config,
            app: NoApplicationObjects,
            stats: RunnerStats::default(),
            owed_ns: 0,
            origin: None,
            sm2_seen: 0,
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
        self.node.stats
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
}

impl SlaveNode {
    /// The settings.
    pub fn config(&self) -> &EthercatConfig {
        &self.config
    }

    fn on_frame(&mut self, esc: &mut Esc, report: &FrameReport) {
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

    fn on_dropped(&mut self, esc: &mut Esc) {
        self.stats.dropped = self.stats.dropped.saturating_add(1);
        self.poll(esc);
        if self.config.clock == ClockMode::RealTime {
            self.catch_up(esc);
        }
    }

    fn on_idle(&mut self, esc: &mut Esc) {
        self.stats.idle = self.stats.idle.saturating_add(1);
        self.poll(esc);
        if self.config.clock == ClockMode::RealTime {
            self.catch_up(esc);
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
        }
        written
    }

    /// 0x1C32:01 as the master left it.
    fn sync_type(&self) -> u16 {
        self.sim.drive.dictionary().get(h::SM2_SYNC_TYPE)
    }

    fn poll(&mut self, esc: &mut Esc) {
        let now_ms = u32::try_from(esc.elapsed() / 1_000_000).unwrap_or(u32::MAX);
        self.slave.poll(esc, &mut self.sim.drive, &mut self.app, now_ms);
        let state = esc.register_u16(AL_STATUS) & 0x0F;
        if state > self.stats.highest_al_state {
            self.stats.highest_al_state = state;
        }
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
        for _ in 0..periods {
            self.step(esc);
        }
    }

    /// One PWM period: plant and drive, the ESC's time (SYNC0, watchdogs), and the cycle SYNC0 or free run
    /// starts.
    fn step(&mut self, esc: &mut Esc) {
        self.sim.step();
        esc.advance(PERIOD_NS);
        let sync = self.sync_type();
        if let Some(pulse) = esc.take_sync0() {
            self.stats.sync0_pulses = self.stats.sync0_pulses.saturating_add(u64::from(pulse.count));
            self.stats.sync0_missed = self.stats.sync0_missed.saturating_add(u64::from(pulse.count.saturating_sub(1)));
            if sync == sync_type::DC_SYNC0 {
                self.cycle(esc);
            }
        }
        if sync == sync_type::FREE_RUN && self.sim.ticks().is_multiple_of(u64::from(SLOW_TICK_DIVIDER)) {
            self.cycle(esc);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::esc::datagram::FrameBuilder;

    fn lock_step(cycle_ns: u64, clock_error_ppb: i64) -> EthercatRunner {
        let config = EthercatConfig { clock: ClockMode::LockStep, cycle_ns, clock_error_ppb, seed: 1 };
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
}
