//! A line of simulated drives on one EtherCAT segment (issue 21 item 1, `drive-sim ethercat --slaves N`): N
//! [`EthercatRunner`]s, each with its own ESC, firmware, plant, ESC oscillator error and port-to-port delay,
//! wired in a line as real drives are (port 1 of each to port 0 of the next, the last one's port 1 closed).
//!
//! **The frame's path** (ETG.1000.4 §5.3, ESC datasheet section I "Frame processing"): a frame from the master
//! enters slave 0's port 0, is processed on the way out to the next slave and comes back through every port 1 to
//! the master. Each ESC executes every datagram as the frame passes it, in order, so the ETG.1000.4 rules compose
//! by themselves: auto-increment addresses (each ESC increments ADP, the one that sees 0 acts), configured
//! addresses and aliases, broadcasts (every ESC acts and adds its working counter: read 1, write 1,
//! read/write 3), logical commands through each ESC's own FMMUs, ARMW/FRMW (the addressed ESC, the reference
//! clock, reads its system time into the datagram and every other ESC takes it as the time control loop's
//! input). The malformed-frame check is the same for all, so a frame one ESC drops, all drop.
//!
//! **Delays and distributed clocks**: slave `k` has a port-to-port delay ([`hop_ns`]: through the
//! ESC and its PHYs and the cable to the next one, the same both ways). The frame reaches slave `k` at
//! `T_k = hop_0 + ... + hop_(k-1)` after slave 0 and comes back through its port 1 at `2 T_last - T_k`; each ESC
//! latches its local clock at those instants ([`crate::esc::Esc::process_frame_at`]), so a master's propagation-delay
//! measurement (0x0900 latch, port receive times 0x0900..0x090F) finds `hop_k` between neighbours. The ESCs'
//! times step on their own (each drive runs whole PWM periods of its own oscillator), so the instant of a frame
//! is slave 0's time and the others' clocks are read at it, corrected by how far each lies from it.
//!
//! **Oscillators**: with more than one slave each ESC's clock runs `--clock-error-ppm` plus a deterministic share
//! of `--clock-spread-ppm` ([`clock_spread_ppb`]: every slave its own value in ±spread), so the master's drift
//! compensation (ARMW/FRMW on 0x0910) has real work to do.
//!
//! **Identity**: every slave has the drive's SII image and dictionary; the serial number (SII words 0x0E/0x0F and
//! 0x1018:04) is the slave's position + 1, as distinct drives of one type have.
//!
//! **Stepping**: after the frame passed the line, each drive runs its firmware and plant as a single drive does
//! ([`EthercatRunner`]'s lock-step or real-time rules). The drives share nothing, so with several slaves the
//! cyclic frames step them on two threads; each drive's result does not depend on the order, so lock-step stays
//! deterministic.
//!
//! **Real time** ([`EthercatLine::serve_real_time`], what `drive-sim ethercat` serves without `--lock-step`): as
//! a real ESC processes the frame in hardware on the fly while its microcontroller (the PDI side) runs on its
//! own, the frame path and the drives run apart. The serving thread owns the socket and answers every frame as
//! soon as it arrives, from the ESCs as they stand (registers, SyncManager buffers, process image, DC times);
//! [`REAL_TIME_WORKERS`] worker threads (the machine's two cores) run the drives: each drive in turn takes the
//! SM2 event of the frames since its last turn (the SM-synchronous cycle), runs the firmware's poll, and
//! advances simulated time towards the wall clock (its SYNC0 pulses and DC cycles with it) by at most
//! [`REAL_TIME_CHUNK_PERIODS`] PWM periods. A drive's simulated time lags the wall clock by a varying amount
//! (up to its worker's round over the drives), so the frame path does not hand the outputs it writes to the
//! drive at once: each ESC stamps an SM2 write with its DC system time at the frame's arrival (the kernel's
//! receive time of the frame on the drive's time, plus the port delays before it) and holds it, with a copy of the buffer, in a queue of
//! [`OUTPUT_QUEUE_DEPTH`] ([`crate::esc::Esc::hold_output_writes`]); the drive's stepping delivers each write
//! (buffer, SM2 event) in the PWM period in which its simulated time passes the stamp, before or after that
//! period's SYNC0 pulse as the stamp says. So every SYNC0 cycle sees the outputs of the frame that arrived in
//! it, as a real ESC's PDI does, however late the drive is stepped (within the queue's depth). Each slave sits behind its own lock, which the frame path takes
//! for the few microseconds of a frame and a drive's turn for one chunk, so a frame waits for at most one
//! chunk of each of the two drives being stepped; a worker gives way while a frame waits.

use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use super::ethercat::{ClockMode, EthercatConfig, EthercatRunner, RunnerStats};
use crate::esc::datagram::{Command, FrameReport};
use crate::esc::socket::{Direction, RawSocket, MAX_FRAME};

/// Most slaves on one line (`drive-sim ethercat --slaves`).
pub const MAX_SLAVES: usize = 64;

/// Threads that run the drives in real time (the machine's two cores; the frame path has its own thread).
pub const REAL_TIME_WORKERS: usize = 2;

/// Most PWM periods a drive runs in real time before the frame path may have its ESC again (200 us of simulated
/// time, some tens of microseconds of the host's).
pub const REAL_TIME_CHUNK_PERIODS: u64 = 5;

/// Output writes an ESC holds for its drive in real time ([`crate::esc::Esc::hold_output_writes`]): 16 frames,
/// 16 ms at a 1 ms cycle, more than a drive lags unless the host stalls it (then the oldest are dropped and
/// counted, [`RunnerStats::output_overflows`]).
pub const OUTPUT_QUEUE_DEPTH: usize = 16;

/// How long a real-time worker sleeps when all its drives have reached the wall clock.
const REAL_TIME_IDLE_SLEEP: Duration = Duration::from_micros(100);

/// Port-to-port delay of the first slave, ns: an ESC with MII PHYs forwards a frame in roughly half a
/// microsecond (ESC datasheet section I, "Frame processing": the PHYs' delays dominate), plus a few metres of
/// cable at 5 ns/m.
pub const HOP_BASE_NS: u64 = 600;

/// The port-to-port delay of slave `k`: [`HOP_BASE_NS`] plus a deterministic 0..=99 ns (cable lengths differ).
pub fn hop_ns(k: usize) -> u64 {
    HOP_BASE_NS + (k as u64 * 53) % 100
}

/// The share of `spread_ppb` for slave `k` of `n`: 0 for a single slave (today's behaviour), otherwise a
/// deterministic value in `-spread_ppb..=spread_ppb` (slave 0 at `-spread`, the others scattered).
pub fn clock_spread_ppb(k: usize, n: usize, spread_ppb: i64) -> i64 {
    if n <= 1 {
        return 0;
    }
    let step = (k as i64 * 73) % 201 - 100;
    spread_ppb * step / 100
}

/// The line's own counters (each drive keeps its [`RunnerStats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineStats {
    /// Frames that passed the line and were sent back.
    pub frames: u64,
    /// Frames dropped (malformed or not EtherCAT).
    pub dropped: u64,
    /// Idle polls.
    pub idle: u64,
    /// Frames with an LRW, LRD or LWR datagram.
    pub cyclic_frames: u64,
    /// Cyclic frames after which every slave's latest SYNC0 pulse was the same pulse (within half a SYNC0 cycle
    /// of each other): the samples of [`Self::sync0_spread_max_ns`].
    pub sync0_samples: u64,
    /// The largest spread of the slaves' latest SYNC0 pulses over those samples, simulated ns.
    pub sync0_spread_max_ns: u64,
    /// Real time: the longest time from a frame's arrival to its answer being sent, ns.
    pub answer_max_ns: u64,
    /// Real time: answers sent more than 100 us after their frame arrived.
    pub answers_over_100us: u64,
    /// Real time: answers sent more than 1 ms after their frame arrived.
    pub answers_over_1ms: u64,
    /// Real time: the longest wait of a frame for the ESCs (a worker's chunk in progress), ns.
    pub esc_wait_max_ns: u64,
}

/// N simulated drives in a line. See the module documentation.
#[derive(Debug)]
pub struct EthercatLine {
    /// The drives, in line order (slave 0 next to the master).
    pub slaves: Vec<EthercatRunner>,
    hops: Vec<u64>,
    stats: LineStats,
    /// Step the drives on two threads (several slaves; see the module documentation).
    parallel: bool,
}

impl EthercatLine {
    /// `plants.len()` drives (at least one) with `config`; slave `k` gets plant `plants[k]`, noise seed
    /// `config.seed + k`, ESC clock error `config.clock_error_ppb + clock_spread_ppb(k, n, spread_ppb)` and
    /// serial number `k + 1` when there is more than one slave (a single slave is exactly
    /// [`EthercatRunner::with_plant`]).
    pub fn new(config: EthercatConfig, plants: &[crate::plant::PlantParams], spread_ppb: i64) -> Result<Self, String> {
        let n = plants.len();
        if n == 0 || n > MAX_SLAVES {
            return Err(format!("{n} slaves: 1..={MAX_SLAVES}"));
        }
        let mut slaves = Vec::with_capacity(n);
        for (k, plant) in plants.iter().enumerate() {
            let mut c = config;
            if n > 1 {
                c.seed = config.seed.wrapping_add(k as u64);
                c.clock_error_ppb =
                    (config.clock_error_ppb + clock_spread_ppb(k, n, spread_ppb)).clamp(-1_000_000, 1_000_000);
            }
            let mut runner = EthercatRunner::with_plant(c, plant.clone())?;
            if n > 1 {
                let serial = k as u32 + 1;
                let mut sii = crate::esc::drive_sii_image()?;
                if let Some(w) = sii.get_mut(2 * 0x0E..2 * 0x0E + 4) {
                    w.copy_from_slice(&serial.to_le_bytes());
                }
                runner.esc = crate::esc::Esc::new(sii);
                runner.esc.set_clock_error_ppb(c.clock_error_ppb);
                let _ =
                    firmware::canopen::ids::write(runner.node.sim.drive.dictionary_mut(), 0x1018, 4, u64::from(serial));
            }
            runner.esc.set_port1_open(k + 1 < n);
            slaves.push(runner);
        }
        let hops = (0..n).map(hop_ns).collect();
        Ok(Self { slaves, hops, stats: LineStats::default(), parallel: n > 1 })
    }

    /// Number of slaves.
    pub fn len(&self) -> usize {
        self.slaves.len()
    }

    /// Whether the line is empty (never: [`Self::new`] refuses it).
    pub fn is_empty(&self) -> bool {
        self.slaves.is_empty()
    }

    /// Steps the drives on one thread only (for a comparison of the two; the result is the same).
    pub fn set_parallel(&mut self, on: bool) {
        self.parallel = on && self.slaves.len() > 1;
    }

    /// The port-to-port delay of slave `k`, ns.
    pub fn hop(&self, k: usize) -> u64 {
        self.hops.get(k).copied().unwrap_or(0)
    }

    /// The line's counters.
    pub fn stats(&self) -> LineStats {
        self.stats
    }

    /// Passes `frame` through the ESCs in order (see the module documentation), in place; returns each ESC's
    /// report, or `None` for a dropped frame (not to be answered). The drives do not run yet: see
    /// [`Self::after_frame`].
    pub fn pass(&mut self, frame: &mut [u8]) -> Option<Vec<FrameReport>> {
        let mut runners: Vec<&mut EthercatRunner> = self.slaves.iter_mut().collect();
        pass_through(&mut runners, &self.hops, frame)
    }

    /// In-process master: [`Self::pass`], then every drive runs ([`Self::after_frame`] or, dropped,
    /// [`Self::after_dropped`]).
    pub fn frame(&mut self, frame: &mut [u8]) -> Option<Vec<FrameReport>> {
        match self.pass(frame) {
            Some(reports) => {
                self.after_frame(&reports);
                Some(reports)
            }
            None => {
                self.after_dropped();
                None
            }
        }
    }

    /// The drives run after a frame passed (each its firmware, and its plant as the clock mode says).
    pub fn after_frame(&mut self, reports: &[FrameReport]) {
        self.stats.frames += 1;
        let cyclic = reports
            .first()
            .is_some_and(|r| r.datagrams.iter().any(|(c, _)| matches!(c, Command::Lrw | Command::Lrd | Command::Lwr)));
        if cyclic {
            self.stats.cyclic_frames += 1;
        }
        let heavy = cyclic || self.clock() == ClockMode::RealTime;
        self.each(heavy, |s, k| s.node_frame(&reports[k]));
        if cyclic {
            self.sample_sync0();
        }
    }

    /// After a cyclic frame: the spread of the slaves' latest SYNC0 pulses, when they are one pulse.
    fn sample_sync0(&mut self) {
        let Some(cycle) = self.slaves.first().and_then(|s| s.esc.sync0_cycle()) else { return };
        let Some(spread) = self.sync0_spread_ns() else { return };
        if spread < u64::from(cycle) / 2 {
            self.stats.sync0_samples += 1;
            self.stats.sync0_spread_max_ns = self.stats.sync0_spread_max_ns.max(spread);
        }
    }

    /// The drives run after a dropped frame.
    pub fn after_dropped(&mut self) {
        self.stats.dropped += 1;
        let heavy = self.clock() == ClockMode::RealTime;
        self.each(heavy, |s, _| s.node_dropped());
    }

    /// An idle poll: no frame came.
    pub fn idle(&mut self) {
        self.stats.idle += 1;
        let c = self.slaves.first().map(|s| *s.node.config());
        let heavy = c.is_some_and(|c| c.clock == ClockMode::RealTime || c.idle_cycle);
        self.each(heavy, |s, _| s.idle());
    }

    fn clock(&self) -> ClockMode {
        self.slaves.first().map_or(ClockMode::LockStep, |s| s.node.config().clock)
    }

    /// Runs `f` on every slave; on two threads when `heavy` and the line steps in parallel (each drive's work
    /// is its own, so the order does not change the result).
    fn each(&mut self, heavy: bool, f: impl Fn(&mut EthercatRunner, usize) + Sync) {
        if !(heavy && self.parallel) {
            for (k, s) in self.slaves.iter_mut().enumerate() {
                f(s, k);
            }
            return;
        }
        let half = self.slaves.len() / 2;
        let (a, b) = self.slaves.split_at_mut(half);
        let f = &f;
        std::thread::scope(|scope| {
            scope.spawn(move || {
                for (k, s) in a.iter_mut().enumerate() {
                    f(s, k);
                }
            });
            for (k, s) in b.iter_mut().enumerate() {
                f(s, half + k);
            }
        });
    }

    /// Serves the line on network interface `iface` (raw socket; needs `CAP_NET_RAW`) until `stop` says so
    /// (asked after every event with the line's counters); every frame received and every answer sent goes to
    /// `tap`. The answer is sent before the drives run, as a single slave's serve loop does.
    pub fn serve_tapped(
        &mut self,
        iface: &str,
        poll: Duration,
        mut tap: impl FnMut(Direction, &[u8]) -> io::Result<()>,
        mut stop: impl FnMut(&LineStats) -> bool,
    ) -> io::Result<()> {
        let socket = RawSocket::bind(iface)?;
        socket.set_read_timeout(Some(poll.max(Duration::from_micros(1))))?;
        let mut buf = [0u8; MAX_FRAME];
        loop {
            match socket.recv(&mut buf)? {
                None => self.idle(),
                Some(n) => {
                    let frame = &mut buf[..n.min(MAX_FRAME)];
                    tap(Direction::Received, frame)?;
                    match self.pass(frame) {
                        Some(reports) => {
                            socket.send(frame)?;
                            tap(Direction::Sent, frame)?;
                            self.after_frame(&reports);
                        }
                        None => self.after_dropped(),
                    }
                }
            }
            if stop(&self.stats) {
                return Ok(());
            }
        }
    }

    /// Serves the line in real time on `iface` (see the module documentation, "Real time") until `stop` says so
    /// (asked after every frame and idle poll of `poll`); every frame received and every answer sent goes to
    /// `tap`. The drives run on [`REAL_TIME_WORKERS`] threads meanwhile; their clock mode should be
    /// [`ClockMode::RealTime`].
    pub fn serve_real_time(
        &mut self,
        iface: &str,
        poll: Duration,
        mut tap: impl FnMut(Direction, &[u8]) -> io::Result<()>,
        mut stop: impl FnMut(&LineStats) -> bool,
    ) -> io::Result<()> {
        let socket = RawSocket::bind(iface)?;
        socket.set_read_timeout(Some(poll.max(Duration::from_micros(1))))?;
        for s in &mut self.slaves {
            s.esc.hold_output_writes(OUTPUT_QUEUE_DEPTH);
        }
        let slaves: Vec<Mutex<EthercatRunner>> = std::mem::take(&mut self.slaves).into_iter().map(Mutex::new).collect();
        let workers = REAL_TIME_WORKERS.min(slaves.len());
        let frame_waiting = AtomicBool::new(false);
        let quit = AtomicBool::new(false);
        let result = std::thread::scope(|scope| {
            for first in 0..workers {
                let (slaves, frame_waiting, quit) = (&slaves, &frame_waiting, &quit);
                scope.spawn(move || run_drives(slaves, first, workers, frame_waiting, quit));
            }
            let r = self.answer_frames(&socket, &slaves, &frame_waiting, &mut tap, &mut stop);
            quit.store(true, Ordering::Relaxed);
            r
        });
        self.slaves = slaves.into_iter().map(|m| m.into_inner().unwrap_or_else(PoisonError::into_inner)).collect();
        result
    }

    /// The frame path of [`Self::serve_real_time`]: every frame through the ESCs and straight back.
    fn answer_frames(
        &mut self,
        socket: &RawSocket,
        slaves: &[Mutex<EthercatRunner>],
        frame_waiting: &AtomicBool,
        tap: &mut impl FnMut(Direction, &[u8]) -> io::Result<()>,
        stop: &mut impl FnMut(&LineStats) -> bool,
    ) -> io::Result<()> {
        let mut buf = [0u8; MAX_FRAME];
        loop {
            match socket.recv(&mut buf)? {
                None => self.stats.idle += 1,
                Some(n) => {
                    let arrived = Instant::now();
                    // The instant the frame reached the interface (the kernel's receive time), not when this
                    // thread got to it: on a loaded host the two lie up to milliseconds apart, and a real ESC
                    // processes the frame as it passes.
                    let on_wire = socket.last_receive_time().and_then(|t| {
                        let age = std::time::SystemTime::now().duration_since(t).ok()?;
                        arrived.checked_sub(age.min(Duration::from_millis(100)))
                    });
                    let on_wire = on_wire.unwrap_or(arrived);
                    let frame = &mut buf[..n.min(MAX_FRAME)];
                    tap(Direction::Received, frame)?;
                    frame_waiting.store(true, Ordering::Release);
                    let reports = {
                        let mut guards: Vec<MutexGuard<'_, EthercatRunner>> = slaves.iter().map(lock).collect();
                        frame_waiting.store(false, Ordering::Release);
                        let waited = u64::try_from(arrived.elapsed().as_nanos()).unwrap_or(u64::MAX);
                        self.stats.esc_wait_max_ns = self.stats.esc_wait_max_ns.max(waited);
                        let mut runners: Vec<&mut EthercatRunner> = guards.iter_mut().map(|g| &mut **g).collect();
                        // Each ESC stamps the outputs the frame writes with its system time at the frame's
                        // arrival there (the wall clock on its drive's time, plus the ports before it).
                        let mut port_delay = 0;
                        for (k, s) in runners.iter_mut().enumerate() {
                            let stamp = s.node.write_stamp(&s.esc, on_wire, port_delay);
                            s.esc.set_write_stamp(Some(stamp));
                            port_delay += self.hops.get(k).copied().unwrap_or(0);
                        }
                        let reports = pass_through(&mut runners, &self.hops, frame);
                        for s in runners.iter_mut() {
                            s.esc.set_write_stamp(None);
                        }
                        for (s, r) in runners.iter_mut().zip(reports.iter().flatten()) {
                            s.node.count_frame(r);
                        }
                        reports
                    };
                    match reports {
                        Some(reports) => {
                            socket.send(frame)?;
                            let took = u64::try_from(arrived.elapsed().as_nanos()).unwrap_or(u64::MAX);
                            self.stats.answer_max_ns = self.stats.answer_max_ns.max(took);
                            if took > 100_000 {
                                self.stats.answers_over_100us += 1;
                            }
                            if took > 1_000_000 {
                                self.stats.answers_over_1ms += 1;
                            }
                            tap(Direction::Sent, frame)?;
                            self.stats.frames += 1;
                            let cyclic = reports.first().is_some_and(|r| {
                                r.datagrams.iter().any(|(c, _)| matches!(c, Command::Lrw | Command::Lrd | Command::Lwr))
                            });
                            if cyclic {
                                self.stats.cyclic_frames += 1;
                            }
                        }
                        None => self.stats.dropped += 1,
                    }
                }
            }
            if stop(&self.stats) {
                return Ok(());
            }
        }
    }

    /// The drives' counters, in line order.
    pub fn slave_stats(&self) -> Vec<RunnerStats> {
        self.slaves.iter().map(EthercatRunner::stats).collect()
    }

    /// The spread of the slaves' latest SYNC0 pulses in simulated (ideal) time, ns: the largest minus the
    /// smallest instant at which each ESC's SYNC0 generator last fired, `None` before every slave has fired.
    /// What the drives' interrupts see; 0 for one slave.
    pub fn sync0_spread_ns(&self) -> Option<u64> {
        let times: Option<Vec<u64>> = self.slaves.iter().map(|s| s.esc.last_sync0_elapsed()).collect();
        let times = times?;
        Some(times.iter().max()? - times.iter().min()?)
    }

    /// The largest spread of the ESCs' system times (0x0910) at one instant, ns: every clock read at slave 0's
    /// time, as a master reading them in one frame and subtracting the delays 0x0928 would find.
    pub fn system_time_spread_ns(&self) -> u64 {
        let now = self.slaves.first().map_or(0, |s| s.esc.elapsed());
        let times: Vec<i128> = self
            .slaves
            .iter()
            .map(|s| i128::from(s.esc.system_time()) + i128::from(now) - i128::from(s.esc.elapsed()))
            .collect();
        let (Some(max), Some(min)) = (times.iter().max(), times.iter().min()) else { return 0 };
        u64::try_from(max - min).unwrap_or(u64::MAX)
    }
}

/// A slave's lock; a panic elsewhere (which ends the run anyway) does not hide the slave.
fn lock(slave: &Mutex<EthercatRunner>) -> MutexGuard<'_, EthercatRunner> {
    slave.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A real-time worker: drives `first`, `first + step`, ... of `slaves` in turn, each one chunk towards the wall
/// clock (see the module documentation), giving way while a frame waits for the ESCs; sleeps when all of them
/// have reached the wall clock; ends when `quit` is set.
fn run_drives(
    slaves: &[Mutex<EthercatRunner>],
    first: usize,
    step: usize,
    frame_waiting: &AtomicBool,
    quit: &AtomicBool,
) {
    // Below the frame path when the line runs at a real-time priority (`chrt`): a frame preempts the stepping.
    super::host_priority::step_below_inherited();
    while !quit.load(Ordering::Relaxed) {
        let mut behind = false;
        for slave in slaves.iter().skip(first).step_by(step.max(1)) {
            while frame_waiting.load(Ordering::Acquire) {
                std::thread::yield_now();
            }
            let mut guard = lock(slave);
            let runner = &mut *guard;
            behind |= runner.node.service_real_time(&mut runner.esc, REAL_TIME_CHUNK_PERIODS);
        }
        if !behind {
            std::thread::sleep(REAL_TIME_IDLE_SLEEP);
        }
    }
}

/// [`EthercatLine::pass`] over `runners` (the line's slaves in order, with port-to-port delays `hops`).
fn pass_through(runners: &mut [&mut EthercatRunner], hops: &[u64], frame: &mut [u8]) -> Option<Vec<FrameReport>> {
    let n = runners.len();
    // Arrival of the frame at each slave after slave 0, ns.
    let mut arrival = Vec::with_capacity(n);
    let mut t = 0u64;
    for k in 0..n {
        arrival.push(t);
        t += hops.get(k).copied().unwrap_or(0);
    }
    let last = arrival.last().copied().unwrap_or(0);
    let now = runners.first().map_or(0, |s| s.esc.elapsed());
    let mut reports = Vec::with_capacity(n);
    let mut dropped = false;
    for (k, s) in runners.iter_mut().enumerate() {
        // The frame's instant is slave 0's time; this ESC's clock may stand a little apart from it.
        let skew = i128::from(now) - i128::from(s.esc.elapsed());
        let at = i64::try_from(skew + i128::from(arrival[k])).unwrap_or(0);
        let back =
            (k + 1 < n).then(|| i64::try_from(skew + 2 * i128::from(last) - i128::from(arrival[k])).unwrap_or(0));
        match s.esc.process_frame_at(frame, at, back) {
            Ok(r) => reports.push(r),
            Err(_) => dropped = true,
        }
    }
    (!dropped).then_some(reports)
}

impl EthercatRunner {
    fn node_frame(&mut self, report: &FrameReport) {
        let (esc, node) = (&mut self.esc, &mut self.node);
        node.on_frame(esc, report);
    }

    fn node_dropped(&mut self) {
        let (esc, node) = (&mut self.esc, &mut self.node);
        node.on_dropped(esc);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::esc::datagram::{Frame, FrameBuilder};
    use crate::plant::PlantParams;

    fn line(n: usize) -> EthercatLine {
        let config = EthercatConfig { clock: ClockMode::LockStep, ..EthercatConfig::default() };
        EthercatLine::new(config, &vec![PlantParams::reference(); n], 100_000).expect("line")
    }

    /// Sends `frame` through the line; returns the frame as it came back.
    fn send(l: &mut EthercatLine, frame: FrameBuilder) -> Vec<u8> {
        let mut f = frame.build();
        l.frame(&mut f).expect("a well-formed frame passes");
        f
    }

    fn datagram(f: &[u8], n: usize) -> (Vec<u8>, u16, u16) {
        let frame = Frame::new_checked(f).expect("frame");
        let d = frame.datagram(n).expect("datagram");
        (d.data().to_vec(), d.wkc(), d.adp())
    }

    #[test]
    fn broadcasts_add_every_slaves_working_counter_read_1_write_1_read_write_3() {
        // ETG.1000.4 §5.4: each slave that reads adds 1, that writes adds 1, that reads and writes adds 3.
        let mut l = line(3);
        let f = send(
            &mut l,
            FrameBuilder::new().push(Command::Brd, 0, 0x0000, &[0]).push(Command::Bwr, 0, 0x0F80, &[1]).push(
                Command::Brw,
                0,
                0x0F81,
                &[2],
            ),
        );
        assert_eq!(datagram(&f, 0).1, 3);
        assert_eq!(datagram(&f, 1).1, 3);
        assert_eq!(datagram(&f, 2).1, 9);
        // Every slave incremented the position field of the broadcasts.
        assert_eq!(datagram(&f, 0).2, 3);
    }

    #[test]
    fn auto_increment_reaches_the_slave_whose_position_counts_to_zero_and_configured_addresses_each_slave() {
        let mut l = line(3);
        // Station addresses 0x1001.. by position (ADP = -k reaches slave k), as masters assign them.
        for k in 0..3u16 {
            let f = send(
                &mut l,
                FrameBuilder::new().push(Command::Apwr, 0u16.wrapping_sub(k), 0x0010, &(0x1001 + k).to_le_bytes()),
            );
            assert_eq!(datagram(&f, 0).1, 1, "exactly one slave at position {k}");
        }
        for k in 0..3 {
            assert_eq!(l.slaves[k].esc.station_address(), 0x1001 + k as u16);
        }
        let f = send(&mut l, FrameBuilder::new().push(Command::Fprd, 0x1002, 0x0010, &[0, 0]));
        let (data, wkc, _) = datagram(&f, 0);
        assert_eq!((data, wkc), (vec![0x02, 0x10], 1));
        let f = send(&mut l, FrameBuilder::new().push(Command::Fprd, 0x1009, 0x0010, &[0, 0]));
        assert_eq!(datagram(&f, 0).1, 0, "no slave has 0x1009");
    }

    #[test]
    fn only_the_last_slave_shows_port_1_closed_in_dl_status() {
        let l = line(3);
        let dl: Vec<u16> = l.slaves.iter().map(|s| s.esc.register_u16(0x0110)).collect();
        // Bit 5 link port 1, bit 10 loop port 1 closed, bit 11 communication on port 1 (ESC datasheet 0x0110).
        assert_eq!(
            dl.iter().map(|d| (d & 0x0020 != 0, d & 0x0400 != 0, d & 0x0800 != 0)).collect::<Vec<_>>(),
            vec![(true, false, true), (true, false, true), (false, true, false)]
        );
        assert_eq!(
            line(1).slaves[0].esc.register_u16(0x0110),
            crate::esc::registers::DL_STATUS,
            "one slave: as before"
        );
    }

    #[test]
    fn the_receive_times_of_ports_0_and_1_give_each_port_to_port_delay() {
        let mut l = line(4);
        // Some time first, so the clocks with different rate errors stand apart.
        for _ in 0..5 {
            send(&mut l, FrameBuilder::new().push_logical(Command::Lrw, 0, &[0; 4]));
        }
        send(&mut l, FrameBuilder::new().push(Command::Bwr, 0, 0x0900, &[0; 4]));
        let port = |s: &EthercatRunner, a: u16| u32::from_le_bytes([a, a + 1, a + 2, a + 3].map(|x| s.esc.register(x)));
        // Loop time behind each port 1: twice the delays of the rest of the line.
        let loops: Vec<i64> =
            l.slaves[..3].iter().map(|s| i64::from(port(s, 0x0904).wrapping_sub(port(s, 0x0900)))).collect();
        for k in 0..2 {
            let measured = (loops[k] - loops[k + 1]) / 2;
            assert!((measured - l.hop(k) as i64).abs() <= 1, "hop {k}: measured {measured}, line {}", l.hop(k));
        }
        assert_eq!(loops[2] / 2, l.hop(2) as i64, "the loop behind slave 2 is slave 3's hop, out and back");
    }

    #[test]
    fn armw_of_the_reference_clocks_system_time_brings_the_other_clocks_together() {
        let mut l = line(4);
        // Offsets as a master writes them: each slave's system time = its local time at the latch minus that.
        send(&mut l, FrameBuilder::new().push(Command::Bwr, 0, 0x0900, &[0; 4]));
        let mut delay = 0u64;
        for k in 0..4 {
            let s = &l.slaves[k];
            let rx = u64::from_le_bytes(std::array::from_fn(|i| s.esc.register(0x0918 + i as u16)));
            let offset = 0u64.wrapping_sub(rx);
            let adp = 0u16.wrapping_sub(k as u16);
            send(&mut l, FrameBuilder::new().push(Command::Apwr, adp, 0x0920, &offset.to_le_bytes()));
            send(&mut l, FrameBuilder::new().push(Command::Apwr, adp, 0x0928, &(delay as u32).to_le_bytes()));
            delay += l.hop(k);
        }
        // Static drift compensation: ARMW 0x0910 from slave 0, one per 1 ms cycle.
        for _ in 0..200 {
            send(
                &mut l,
                FrameBuilder::new().push_logical(Command::Lrw, 0, &[0; 4]).push(Command::Armw, 0, 0x0910, &[0; 8]),
            );
        }
        // +-100 ppm apart: at most 200 ns drift per 1 ms cycle between corrections.
        let spread = l.system_time_spread_ns();
        assert!(spread <= 250, "system times {spread} ns apart");
    }

    #[test]
    fn logical_commands_go_through_each_slaves_own_fmmus() {
        let mut l = line(2);
        // FMMU0 of slave k: logical 0x100 + 4k, 4 bytes -> physical 0x1000 (user RAM), read+write.
        for k in 0..2u16 {
            let mut fmmu = [0u8; 16];
            fmmu[0..4].copy_from_slice(&(0x100u32 + 4 * u32::from(k)).to_le_bytes());
            fmmu[4..6].copy_from_slice(&4u16.to_le_bytes());
            fmmu[7] = 7;
            fmmu[8..10].copy_from_slice(&0x1000u16.to_le_bytes());
            fmmu[11] = 3;
            fmmu[12] = 1;
            send(&mut l, FrameBuilder::new().push(Command::Apwr, 0u16.wrapping_sub(k), 0x0600, &fmmu));
        }
        let f = send(&mut l, FrameBuilder::new().push_logical(Command::Lwr, 0x100, &[1, 2, 3, 4, 5, 6, 7, 8]));
        assert_eq!(datagram(&f, 0).1, 2, "one write per slave");
        let f = send(&mut l, FrameBuilder::new().push_logical(Command::Lrd, 0x100, &[0; 8]));
        assert_eq!(datagram(&f, 0), (vec![1, 2, 3, 4, 5, 6, 7, 8], 2, 0x100));
        // Each slave's own RAM holds its own four bytes.
        for k in 0..2u16 {
            let f = send(&mut l, FrameBuilder::new().push(Command::Aprd, 0u16.wrapping_sub(k), 0x1000, &[0; 4]));
            let first = 1 + 4 * k as u8;
            assert_eq!(datagram(&f, 0).0, vec![first, first + 1, first + 2, first + 3], "slave {k}");
        }
    }

    #[test]
    fn each_slave_has_its_own_serial_number_in_the_sii_and_0x1018_04() {
        let l = line(3);
        for (k, s) in l.slaves.iter().enumerate() {
            let sii = &s.esc.sii().image;
            assert_eq!(u32::from_le_bytes([sii[0x1C], sii[0x1D], sii[0x1E], sii[0x1F]]), k as u32 + 1);
            let mut b = [0u8; 4];
            s.node
                .sim
                .drive
                .dictionary()
                .read(0x1018, 4, 0, &mut b, &mut firmware::od::access::NoApplicationObjects)
                .expect("0x1018:04");
            assert_eq!(u32::from_le_bytes(b), k as u32 + 1);
        }
        let rates: Vec<i64> = l.slaves.iter().map(|s| s.node.config().clock_error_ppb).collect();
        assert_eq!(rates, vec![-100_000, -27_000, 46_000], "each its own oscillator error within +-100 ppm");
    }

    #[test]
    fn a_line_of_one_answers_byte_for_byte_as_the_single_slave_runner() {
        let config = EthercatConfig { clock: ClockMode::LockStep, ..EthercatConfig::default() };
        let mut single = EthercatRunner::new(config).expect("runner");
        let mut l = line(1);
        let frames = [
            FrameBuilder::new().push(Command::Brd, 0, 0x0000, &[0; 16]),
            FrameBuilder::new().push(Command::Bwr, 0, 0x0900, &[0; 4]).push(Command::Aprd, 0, 0x0900, &[0; 32]),
            FrameBuilder::new().push_logical(Command::Lrw, 0, &[0; 8]).push(Command::Armw, 0, 0x0910, &[0; 8]),
            FrameBuilder::new().push(Command::Brd, 0, 0x0130, &[0; 6]),
        ];
        for fb in frames.iter().cycle().take(40) {
            let (mut a, mut b) = (fb.build(), fb.build());
            single.frame(&mut a);
            l.frame(&mut b);
            assert_eq!(a, b);
        }
    }

    #[test]
    fn stepping_the_drives_on_two_threads_gives_the_same_result_as_on_one() {
        let mut results = Vec::new();
        for parallel in [false, true] {
            let mut l = line(3);
            l.set_parallel(parallel);
            for _ in 0..50 {
                send(&mut l, FrameBuilder::new().push_logical(Command::Lrw, 0, &[0; 4]));
            }
            results.push(
                l.slaves
                    .iter()
                    .map(|s| {
                        (
                            s.node.sim.ticks(),
                            s.esc.local_time(),
                            s.node.sim.statusword(),
                            format!("{:?}", s.node.sim.plant.state()),
                        )
                    })
                    .collect::<Vec<_>>(),
            );
        }
        assert_eq!(results[0], results[1]);
    }
}
