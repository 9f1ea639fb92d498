//! Simulated drives as CANopen nodes on one simulated CAN bus (issue 8, item 2): each drive is the reference plant
//! with the firmware's drive ([`Simulation`]) and its [`CanopenNode`]; the bus ([`CanBus`]) gives every frame its
//! time at the bit rate and arbitrates; one more bus port stands for the master (the socketcand clients of
//! `drive-sim canopen`, or a test in-process). This is what `drive-sim canopen --port N --nodes K` runs.
//!
//! Per PWM period (40 us of simulated time) the bus runs up to the period's end, each node receives the frames
//! that ended in it ([`CanopenNode::handle_frame`]: the SYNC path as the CAN receive interrupt would run it, the
//! rest as tier 3 would shortly after) and the frames it queued (the synchronous TPDOs) go onto the bus at once,
//! the plant and drive step, and every slow tick (400 us) each node runs the rest of its tier 3
//! ([`CanopenNode::process`]: SDO, EMCY, heartbeat, event-driven PDOs) and queues its frames on the bus.
//!
//! Two clocks, as for EtherCAT ([`super::ethercat`]):
//! - [`CanClock::RealTime`]: simulated time follows the wall clock (for a person at a CANopen tool).
//! - [`CanClock::LockStep`]: simulated time advances only for the master's frames: a SYNC (COB-ID
//!   [`SYNC_COB_ID`]) runs exactly one SYNC period ([`CanopenConfig::sync_period_ns`]); any other frame runs until
//!   the bus and every node are quiet again (the answer is out), at most [`QUIET_LIMIT_NS`]; RPDOs and the
//!   master's heartbeat, which nobody answers, run no time and cross the bus with the next frame that runs time
//!   (`CanopenRunner::lock_step`). The master's pace is
//!   the simulation's pace, so a tool on a busy 2-core machine gets the same verdict every run; time without
//!   SYNCs does not pass, so SYNC-driven tests measure supervision (heartbeat, SYNC loss) in SYNC periods.
//!
//! # The bootloader's fallback (issue 7, item 4)
//! Every drive boots as the target does: the bootloader ([`update::reset`]) decides over the drive's update
//! regions first. When slot A holds no valid image ([`Outcome::NoValidImage`]) the target stays in the
//! bootloader, which answers on CAN with its own compact service, [`FallbackNode`]; so does the simulated drive:
//! its bus port is served by a `FallbackNode` (node-ID the drive's, the program's trust anchor, the loader's
//! reason) instead of the drive's [`CanopenNode`], which, like the firmware's drive, does not run. The fallback
//! sends its boot-up when it starts, answers each frame in the PWM period the frame ends in (handing it the
//! drive's update regions, `SimProgram::flash_mut`), is polled every slow tick with simulated milliseconds (its
//! SDO timeout), and when it asks for a reset the runner sends its answer first and then runs the simulated
//! reset: the bootloader swaps a pending image in and the application boots (its boot-up follows at the next
//! slow tick), or it finds nothing valid again and a new fallback starts. Lock-step semantics are unchanged: a
//! frame to the fallback runs until its answer is out.
//!
//! The plant does not step while a drive is in the fallback: on the target no part of the application (current
//! loop, CiA 402) runs in the bootloader and the power stage is off; the rotor is taken to stand (program control
//! refuses to stop the program with the power stage enabled, and the fallback is entered only at a reset).
//! Flash work takes no simulated time here (as for program control in the application).
//! [`CanopenConfig::empty_slot_nodes`] (`drive-sim canopen --no-image K`) starts nodes with an erased slot A.

use std::collections::VecDeque;
use std::io;
use std::time::{Duration, Instant};

use firmware::boot::fallback::FallbackNode;
use firmware::boot::loader::Outcome;
use firmware::boot::program::{Interface, Request};
use firmware::boot::tables::{APPLICATION_TABLE, BOOTLOADER_TABLE};
use firmware::canopen::frame::{BusState, BusStatus, CanFrame};
use firmware::canopen::nmt::{NmtState, ResetKind};
use firmware::canopen::{CanopenNode, NodeEvent};
use firmware::cia402::State;
use firmware::drive::objects::DriveObjects;
use firmware::hal::power::SLOW_TICK_DIVIDER;
use firmware::od::generated::handles as h;
use firmware::od::store::ParamStore;
use firmware::recorder::objects::RecorderObjects;

use super::ethercat::{MAX_CATCH_UP_PERIODS, PERIOD_NS};
use super::update::{self, SimProgram};
use super::Simulation;
use crate::can::bus::{CanBus, Delivery, NodeIndex};
use crate::can::socketcand::SocketcandServer;
use crate::flash::SimFlash;

/// The default SYNC COB-ID (0x1005 = 0x80, CiA 301 §7.5.2.5): the frame lock-step mode counts as a cycle.
pub const SYNC_COB_ID: u16 = 0x080;

/// Longest a non-SYNC frame may run simulated time in lock-step mode before the runner stops waiting for quiet
/// (20 ms: a 127-segment block upload at 125 kbit/s takes about 14 ms).
pub const QUIET_LIMIT_NS: u64 = 20_000_000;

/// How simulated time advances.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CanClock {
    /// Simulated time follows the wall clock.
    RealTime,
    /// Simulated time advances with the master's frames (see the module documentation).
    LockStep,
}

/// The runner's settings (the `drive-sim canopen` options).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CanopenConfig {
    /// How simulated time advances.
    pub clock: CanClock,
    /// Simulated time one SYNC from the master runs in lock-step mode, ns.
    pub sync_period_ns: u64,
    /// Bus bit rate, bit/s.
    pub bit_rate: u32,
    /// Drives on the bus, node-IDs 1..=nodes.
    pub nodes: u8,
    /// Seed of the plants' noise (drive k uses seed + k).
    pub seed: u64,
    /// Nodes whose slot A is erased before their first boot, bit k for node-ID k: the bootloader finds no valid
    /// image and they start in its fallback (see the module documentation). 0: every node runs the factory image.
    pub empty_slot_nodes: u128,
    /// Drives without a node-ID, bit k for the drive in slot k (`drive-sim canopen --unconfigured K`): they start
    /// unconfigured (0x2000 = 0xFF) and wait for an LSS master (CiA 305; `firmware::canopen::lss`).
    pub unconfigured_nodes: u128,
}

impl Default for CanopenConfig {
    fn default() -> Self {
        Self {
            clock: CanClock::RealTime,
            sync_period_ns: 1_000_000,
            bit_rate: 1_000_000,
            nodes: 1,
            seed: 1,
            empty_slot_nodes: 0,
            unconfigured_nodes: 0,
        }
    }
}

impl CanopenConfig {
    /// The same settings with node-ID `id` (1..=127) starting with an erased slot A.
    pub fn with_empty_slot(mut self, id: u8) -> Self {
        self.empty_slot_nodes |= 1u128.checked_shl(u32::from(id)).unwrap_or(0);
        self
    }

    /// Whether node-ID `id` starts with an erased slot A.
    pub fn empty_slot(&self, id: u8) -> bool {
        self.empty_slot_nodes.checked_shr(u32::from(id)).is_some_and(|b| b & 1 == 1)
    }

    /// The same settings with the drive in slot `slot` (1..=127) starting without a node-ID.
    pub fn with_unconfigured(mut self, slot: u8) -> Self {
        self.unconfigured_nodes |= 1u128.checked_shl(u32::from(slot)).unwrap_or(0);
        self
    }

    /// Whether the drive in slot `slot` starts without a node-ID.
    pub fn unconfigured(&self, slot: u8) -> bool {
        self.unconfigured_nodes.checked_shr(u32::from(slot)).is_some_and(|b| b & 1 == 1)
    }
}

/// Following error of one drive while it runs CSP enabled, from 0x60F4 at every slow tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FollowingError {
    /// Slow ticks sampled.
    pub samples: u64,
    /// Largest magnitude, increments.
    pub peak_inc: i64,
    /// Sum of squares, for the RMS.
    sum_sq: f64,
}

impl FollowingError {
    /// RMS over the samples, increments.
    pub fn rms_inc(&self) -> f64 {
        if self.samples == 0 {
            0.0
        } else {
            (self.sum_sq / self.samples as f64).sqrt()
        }
    }

    fn sample(&mut self, fe: i32) {
        self.samples += 1;
        self.peak_inc = self.peak_inc.max(i64::from(fe).abs());
        self.sum_sq += f64::from(fe) * f64::from(fe);
    }
}

/// One drive on the bus.
#[derive(Debug)]
pub struct CanDrive {
    /// The plant and the firmware's drive.
    pub sim: Simulation,
    /// The firmware's CANopen node.
    pub node: CanopenNode,
    /// Its bus port.
    pub port: NodeIndex,
    inbox: VecDeque<CanFrame>,
    /// The drive's parameter store (0x1010 save / 0x1011 load, and what a restart loads).
    pub store: ParamStore<SimFlash>,
    /// Following error while enabled in CSP.
    pub following_error: FollowingError,
    /// Node events (resets, boots) seen.
    pub events: Vec<NodeEvent>,
    /// Between power-on (or a restart) and the boot: the node's own power-on reset is not a restart request.
    powering_up: bool,
    /// Program control over the simulated update regions (0x1F50..0x1F57; issue 7).
    pub program: SimProgram,
    /// What the bootloader decided at the last (simulated) reset ([`update::reset`]).
    pub last_boot: Outcome,
    /// Whether an image on trial confirms itself when the node has booted (default on).
    pub auto_confirm: bool,
    /// The bootloader's CAN service while slot A holds no valid image (`None`: the application runs).
    fallback: Option<FallbackNode>,
    /// Frames this drive sends in the current PWM period, in order (they go onto the bus at its end).
    outbox: Vec<CanFrame>,
    /// The simulator's own trace of tier 1's q current (`drive-sim canopen --trace FILE`): one CSV line every
    /// current-loop period, the reference a recording of the drive's data recorder is checked against.
    pub trace: Option<super::current_trace::CurrentTrace>,
    /// Frames the fallback services answered or sent since power-on (boot-ups, answers, timeouts).
    fallback_frames: u64,
    /// What the drive's CAN controller reports (an injected error state): the node reads it before every slow
    /// step, as tier 3 does; while it is bus-off the drive neither receives nor sends (its frames wait in the
    /// node's queue).
    pub controller: BusStatus,
    /// The board's serial number (0x1018:04): each simulated drive has its own, as boards do, so that an LSS
    /// master tells them apart; the drive in slot k has the factory value + k - 1.
    serial: u32,
    /// The drive's slot on the bus: its node-ID while its parameter store holds none (a board's switches).
    slot: u8,
    /// The bit rate (bit/s) an LSS activate bit timing switched the drive's controller to (`None`: still the rate
    /// it powered up with, the bus's). A drive whose rate differs from the bus's neither sends nor receives.
    pub bit_rate: Option<u32>,
}

impl CanDrive {
    /// A drive with node-ID `id` on bus port `port`, powered on: the bootloader runs over `program`'s regions,
    /// then the application (drive and node) or the bootloader's fallback starts.
    fn power_on(id: u8, slot: u8, port: NodeIndex, mut sim: Simulation, mut program: SimProgram) -> Self {
        let mut store = ParamStore::new(SimFlash::params());
        // Power-on as on the target: the bootloader starts the image in slot A, which builds the dictionary from
        // the parameter store (empty here: defaults).
        let last_boot = update::reset(&mut program);
        sim.replace_drive(update::boot_drive_with_node_id(&mut store, &program, slot));
        let mut d = Self {
            program,
            last_boot,
            auto_confirm: true,
            sim,
            node: CanopenNode::new(id),
            port,
            inbox: VecDeque::new(),
            store,
            following_error: FollowingError::default(),
            events: Vec::new(),
            powering_up: true,
            fallback: None,
            outbox: Vec::new(),
            trace: None,
            fallback_frames: 0,
            controller: BusStatus::default(),
            serial: firmware::od::generated::SERIAL_NUMBER.wrapping_add(u32::from(slot).saturating_sub(1)),
            slot,
            bit_rate: None,
        };
        d.apply_serial();
        d.enter_fallback_if_no_image(id);
        d
    }

    /// A drive as it leaves the factory without a node-ID: 0x2000 = 0xFF saved in its parameter store, and the
    /// node unconfigured from power-on (it waits for an LSS master; `firmware::canopen::lss`).
    fn leave_factory_unconfigured(&mut self) {
        use firmware::canopen::{ids, lss};
        use firmware::od::access::ApplicationObjects;
        let d = self.sim.drive.dictionary_mut();
        let _ = ids::write(d, ids::NODE_ID_OBJECT, 0, u64::from(lss::UNCONFIGURED));
        if let Ok(entry) = d.find(ids::STORE_PARAMETERS, ids::SAVE_MANUFACTURER) {
            let mut objects = DriveObjects::new(&mut self.store, false);
            let saved = objects.write(entry, 0, &ids::SAVE_SIGNATURE, true, d.values_mut().bytes_mut());
            debug_assert!(saved.is_ok(), "the factory save: {saved:?}");
        }
        self.node = CanopenNode::new(lss::UNCONFIGURED);
    }

    /// The board's serial number into 0x1018:04 (read-only to a master; the runtime's to set at start).
    fn apply_serial(&mut self) {
        let _ = firmware::canopen::ids::write(self.sim.drive.dictionary_mut(), 0x1018, 4, u64::from(self.serial));
    }

    /// Whether the bootloader's fallback serves this drive's bus port (slot A held no valid image at the last
    /// reset): its [`CanDrive::node`] and drive do not run meanwhile.
    pub fn in_fallback(&self) -> bool {
        self.fallback.is_some()
    }

    /// The bootloader's fallback service, while it runs.
    pub fn fallback(&self) -> Option<&FallbackNode> {
        self.fallback.as_ref()
    }

    /// Frames the bootloader's fallback sent since power-on (boot-ups, SDO answers and aborts).
    pub fn fallback_frames(&self) -> u64 {
        self.fallback_frames
    }

    /// After the loader's decision: no valid image -> the fallback starts and sends its boot-up.
    fn enter_fallback_if_no_image(&mut self, id: u8) {
        self.fallback = match self.last_boot {
            Outcome::NoValidImage(reason) => {
                let node = FallbackNode::new(id, *self.program.trust(), reason);
                self.outbox.push(node.boot_up());
                self.fallback_frames += 1;
                Some(node)
            }
            Outcome::Run { .. } => None,
        };
    }

    /// The microcontroller restarts: the bootloader runs (it activates a pending image, reverts an unconfirmed
    /// one), then the drive starts anew from its parameter store and the node with node-ID `id` boots, or the
    /// fallback starts if no valid image is left. Frames not yet handled are lost, as on the target.
    fn restart(&mut self, id: u8) {
        self.last_boot = update::reset(&mut self.program);
        self.sim.replace_drive(update::boot_drive_with_node_id(&mut self.store, &self.program, self.slot));
        self.apply_serial();
        // As `rt::canopen::start`: the node-ID the restarted drive loaded from its parameter store (a node-ID
        // written to 0x2000 and not saved is gone with the RAM).
        let id = firmware::canopen::ids::startup_node_id(self.sim.drive.dictionary()).unwrap_or(id);
        self.node = CanopenNode::new(id);
        self.inbox.clear();
        self.powering_up = true;
        self.enter_fallback_if_no_image(id);
    }

    /// The independent watchdog resets the microcontroller (a tier stopped running; `board::watchdog` on the
    /// target): the microcontroller restarts as after program control's reset (bootloader, then the drive and the
    /// node from scratch), and the new start reports the cause as the board reads it from RCC_CSR (`Drive::report_reset`: fault 0xFF02, sent as an EMCY once the node has booted).
    pub fn watchdog_reset(&mut self) {
        self.restart(self.node.node_id());
        self.sim.drive.report_reset(firmware::hal::reset::ResetCause::IndependentWatchdog);
    }

    /// Acts on program control after a request (issue 7): a stop or start changes the dictionary, a reset
    /// restarts the microcontroller (bootloader, then the drive and the node from scratch).
    fn follow_program(&mut self) {
        match self.program.take_request() {
            Some(Request::Stop) => update::use_table(&mut self.sim.drive, BOOTLOADER_TABLE),
            Some(Request::Start) => update::use_table(&mut self.sim.drive, APPLICATION_TABLE),
            Some(Request::Reset) => self.restart(self.node.node_id()),
            None => {}
        }
    }

    /// One PWM period of the bootloader's fallback: the frames that arrived, then (every slow tick) its SDO
    /// timeout. A reset it asks for runs after its answer is queued.
    fn fallback_period(&mut self, now_ms: u32, slow: bool) {
        while let Some(frame) = self.inbox.pop_front() {
            let Some(fallback) = self.fallback.as_mut() else { return };
            let reply = fallback.handle(&frame, self.program.flash_mut(), now_ms);
            let id = fallback.node_id();
            if let Some(answer) = reply.frame {
                self.outbox.push(answer);
                self.fallback_frames += 1;
            }
            if reply.reset {
                self.restart(id);
                return;
            }
        }
        if slow {
            if let Some(abort) = self.fallback.as_mut().and_then(|f| f.poll(now_ms)) {
                self.outbox.push(abort);
                self.fallback_frames += 1;
            }
        }
    }

    /// One PWM period of the application: the frames that arrived, the plant and drive, and every slow tick the
    /// node's tier 3.
    fn application_period(&mut self, now_us: u64, slow: bool) {
        let bus_off = self.controller.state == BusState::BusOff;
        if bus_off {
            self.inbox.clear();
        }
        while let Some(frame) = self.inbox.pop_front() {
            let on = self.sim.drive.power_stage_enabled();
            let mut drive_objects =
                DriveObjects::new(&mut self.store, on).with_program_control(self.program.port(Interface::Canopen, on));
            let mut app = RecorderObjects::new(&mut self.sim.recorder, &mut drive_objects);
            self.node.handle_frame(&frame, &mut self.sim.drive, &mut app, now_us);
            self.follow_program();
            if self.in_fallback() {
                return;
            }
        }
        // The SYNC path queued its TPDOs; the target's background (tier 3) hands them to the controller's
        // transmit mailboxes within microseconds, not at the next slow tick.
        while let Some(frame) = if bus_off { None } else { self.node.transmit() } {
            self.outbox.push(frame);
        }
        self.sim.step();
        if let Some(trace) = self.trace.as_mut() {
            trace.record(&self.sim, slow);
        }
        if !slow {
            return;
        }
        self.node.observe_bus(self.controller, &mut self.sim.drive);
        let on = self.sim.drive.power_stage_enabled();
        let mut drive_objects =
            DriveObjects::new(&mut self.store, on).with_program_control(self.program.port(Interface::Canopen, on));
        let mut app = RecorderObjects::new(&mut self.sim.recorder, &mut drive_objects);
        if let Some(event) = self.node.process(&mut self.sim.drive, &mut app, now_us) {
            self.events.push(event);
            if let NodeEvent::BitRateSwitched(rate) = event {
                self.bit_rate = Some(rate.bits_per_second());
            }
            if event == NodeEvent::Booted {
                self.powering_up = false;
                // The node is up after a start: an image on trial confirms itself (issue 7).
                if self.auto_confirm && self.program.on_trial() {
                    let _ = self.program.confirm();
                }
            }
            if let (NodeEvent::Reset { kind: ResetKind::Node, node_id, .. }, false) = (event, self.powering_up) {
                // What the target does at a reset node: the microcontroller restarts, so the drive comes back
                // with the values in its parameter store and the node boots anew (the node has already put the
                // power stage in a safe state). The plant keeps turning meanwhile. The bootloader runs first
                // (issue 7: it activates a pending image, reverts an unconfirmed one, or stays in its fallback).
                self.restart(node_id);
                if self.in_fallback() {
                    return;
                }
            }
        }
        while let Some(frame) = if bus_off { None } else { self.node.transmit() } {
            self.outbox.push(frame);
        }
        let dict = self.sim.drive.dictionary();
        let csp = dict.get(h::MODES_OF_OPERATION_DISPLAY) == 8i8;
        if csp && self.sim.cia402_state() == State::OperationEnabled {
            self.following_error.sample(dict.get(h::FOLLOWING_ERROR_ACTUAL_VALUE));
        }
    }
}

/// What the runner counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CanRunnerStats {
    /// Frames the master sent.
    pub master_frames: u64,
    /// SYNCs the master sent.
    pub master_syncs: u64,
    /// Frames delivered to the master (sent by the nodes).
    pub frames_to_master: u64,
    /// Lock-step waits for quiet that hit [`QUIET_LIMIT_NS`].
    pub quiet_limit_hits: u64,
    /// Real-time catch-ups cut short.
    pub lag_events: u64,
    /// Frames a drive sent at a bit rate other than the bus's (lost: nobody can receive them).
    pub rate_mismatch_frames: u64,
}

/// Simulated drives on a CAN bus. See the module documentation.
#[derive(Debug)]
pub struct CanopenRunner {
    /// The bus.
    pub bus: CanBus,
    /// The drives, node-ID k at index k - 1.
    pub drives: Vec<CanDrive>,
    master: NodeIndex,
    config: CanopenConfig,
    now_ns: u64,
    ticks: u64,
    stats: CanRunnerStats,
    origin: Option<Instant>,
}

impl CanopenRunner {
    /// `config.nodes` reference drives (at least one), node-IDs 1.., booted (their boot-up messages are on the bus
    /// after the first period; those of the nodes in the bootloader's fallback at once).
    pub fn new(config: CanopenConfig) -> Self {
        Self::with_plant(config, &crate::plant::PlantParams::reference())
    }

    /// [`Self::new`] with every drive on the plant `params` (`drive-sim canopen --plant FILE`), its motor data
    /// written from the plant's ratings ([`Simulation::commission_motor_data`]) when it is not the reference plant.
    pub fn with_plant(config: CanopenConfig, params: &crate::plant::PlantParams) -> Self {
        let mut bus = CanBus::new(config.bit_rate);
        let master = bus.attach();
        let drives = (1..=config.nodes.max(1))
            .map(|id| {
                let mut sim = Simulation::new(
                    params.clone(),
                    config.seed.wrapping_add(u64::from(id)),
                    firmware::drive::DriveConfig::DEFAULT,
                );
                if *params != crate::plant::PlantParams::reference() {
                    sim.commission_motor_data(params);
                }
                // A master records through the data recorder (0x3300..0x3302) as on the board.
                sim.attach_recorder();
                // The factory image in slot A, or (`empty_slot_nodes`) nothing: the bootloader's fallback.
                let program = if config.empty_slot(id) { update::blank_program() } else { update::factory_program() };
                let mut drive = CanDrive::power_on(id, id, bus.attach(), sim, program);
                if config.unconfigured(id) {
                    drive.leave_factory_unconfigured();
                }
                drive
            })
            .collect();
        Self { bus, drives, master, config, now_ns: 0, ticks: 0, stats: CanRunnerStats::default(), origin: None }
    }

    /// The settings.
    pub fn config(&self) -> &CanopenConfig {
        &self.config
    }

    /// Simulated time, ns.
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// The counters.
    pub fn stats(&self) -> CanRunnerStats {
        self.stats
    }

    /// The master's bus port.
    pub fn master_port(&self) -> NodeIndex {
        self.master
    }

    /// The drive with node-ID `id`.
    pub fn drive(&self, id: u8) -> Option<&CanDrive> {
        self.drives.get(usize::from(id).checked_sub(1)?)
    }

    /// The drive with node-ID `id`, to inject a fault into (its controller's error state, its plant).
    pub fn drive_mut(&mut self, id: u8) -> Option<&mut CanDrive> {
        self.drives.get_mut(usize::from(id).checked_sub(1)?)
    }

    /// Queues a frame from the master now (it crosses the bus as time runs).
    pub fn send(&mut self, frame: CanFrame) {
        self.stats.master_frames += 1;
        if frame.id() == SYNC_COB_ID {
            self.stats.master_syncs += 1;
        }
        self.bus.send(self.master, self.now_ns, frame);
    }

    /// Runs `ns` of simulated time (whole PWM periods, rounded up); returns the frames the nodes sent that
    /// reached the master.
    pub fn run_for(&mut self, ns: u64) -> Vec<Delivery> {
        let mut out = Vec::new();
        for _ in 0..ns.div_ceil(PERIOD_NS) {
            self.step(&mut out);
        }
        out
    }

    /// Runs until the bus is idle, no node has a frame to send and no SDO transfer sends on its own (at least one
    /// slow tick, at most `limit_ns`); returns the frames for the master. Quiet is checked right after a slow
    /// tick, whose frames (a block-upload burst goes out slow tick by slow tick) are then on the bus: so a slow tick
    /// that sent nothing and an idle bus mean the node waits for the master. A transfer in progress that waits for
    /// the client (a segmented one between segments, a block upload after its sub-block) is quiet: waiting for
    /// its server timeout would run 20 ms of simulated time after every segment.
    pub fn run_until_quiet(&mut self, limit_ns: u64) -> Vec<Delivery> {
        let mut out = Vec::new();
        let start = self.now_ns;
        loop {
            self.step(&mut out);
            let slow_tick_done = self.ticks.is_multiple_of(u64::from(SLOW_TICK_DIVIDER));
            if slow_tick_done && self.now_ns - start >= PERIOD_NS * u64::from(SLOW_TICK_DIVIDER) && self.quiet() {
                break;
            }
            if self.now_ns - start >= limit_ns {
                self.stats.quiet_limit_hits += 1;
                break;
            }
        }
        out
    }

    /// In lock-step mode: the master's frame `frame`, and the time it runs (see the module documentation).
    pub fn lock_step(&mut self, frame: CanFrame) -> Vec<Delivery> {
        let sync = frame.id() == SYNC_COB_ID;
        let carried = self.carried_by_next(&frame);
        self.send(frame);
        if sync {
            self.run_for(self.config.sync_period_ns)
        } else if carried {
            Vec::new()
        } else {
            self.run_until_quiet(QUIET_LIMIT_NS)
        }
    }

    /// Whether a master frame runs no time in lock-step mode and crosses the bus with the next frame that does:
    /// an RPDO of some drive or a heartbeat (COB-ID 0x701..=0x77F, one byte). Nobody answers either, and a master
    /// sends them every cycle before its SYNC (CiA 301 §7.2.2.2.2: RPDOs received before a SYNC are taken at it);
    /// waiting for quiet after each would stretch the master's cycle by a slow tick or more, so a SYNC period of
    /// 1 ms would last 1.4 ms of simulated time. The master's frames keep their order on the bus (one transmit
    /// queue per node), so the RPDO still precedes the SYNC.
    fn carried_by_next(&self, frame: &CanFrame) -> bool {
        if frame.is_remote() || frame.id() == SYNC_COB_ID {
            return false;
        }
        let heartbeat = (0x701..=0x77F).contains(&frame.id()) && frame.data().len() == 1;
        heartbeat || self.drives.iter().any(|d| !d.in_fallback() && d.node.is_realtime(frame))
    }

    fn quiet(&self) -> bool {
        (0..self.bus.nodes()).all(|p| self.bus.pending(p) == 0)
            && self.drives.iter().all(|d| {
                d.inbox.is_empty()
                    && d.outbox.is_empty()
                    && (d.in_fallback() || (d.node.pending_frames() == 0 && d.node.state() != NmtState::Initialisation))
            })
    }

    /// One PWM period of every drive and the bus.
    fn step(&mut self, to_master: &mut Vec<Delivery>) {
        self.now_ns += PERIOD_NS;
        self.ticks += 1;
        let bus_rate = self.bus.bit_rate();
        for delivery in self.bus.run_until(self.now_ns) {
            for d in &mut self.drives {
                if d.port != delivery.from
                    && delivery.lost_at != Some(d.port)
                    && d.bit_rate.unwrap_or(bus_rate) == bus_rate
                {
                    d.inbox.push_back(delivery.frame);
                }
            }
            if delivery.from != self.master && delivery.lost_at != Some(self.master) {
                self.stats.frames_to_master += 1;
                to_master.push(delivery);
            }
        }
        let now_us = self.now_ns / 1_000;
        // The fallback's millisecond clock wraps as the target's tick counter does.
        let now_ms = (self.now_ns / 1_000_000) as u32;
        let slow = self.ticks.is_multiple_of(u64::from(SLOW_TICK_DIVIDER));
        for d in &mut self.drives {
            if d.in_fallback() {
                d.fallback_period(now_ms, slow);
            } else {
                d.application_period(now_us, slow);
            }
            for frame in d.outbox.drain(..) {
                if d.bit_rate.unwrap_or(bus_rate) == bus_rate {
                    self.bus.send(d.port, self.now_ns, frame);
                } else {
                    self.stats.rate_mismatch_frames += 1;
                }
            }
        }
        // CiA 305 §6.4.3: the master switches every node of the bus together and then its own adapter; the
        // simulated master (socketcand clients have no bit rate) follows once every drive runs at one new rate.
        let mut rates = self.drives.iter().map(|d| d.bit_rate.unwrap_or(bus_rate));
        if let Some(first) = rates.next() {
            if first != bus_rate && rates.all(|r| r == first) {
                self.bus.set_bit_rate(first);
            }
        }
    }

    /// Real-time mode: runs up to the wall clock (at most [`MAX_CATCH_UP_PERIODS`] at once).
    fn catch_up(&mut self, to_master: &mut Vec<Delivery>) {
        let origin = *self.origin.get_or_insert_with(Instant::now);
        let wall_ns = u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let mut periods = wall_ns.saturating_sub(self.now_ns) / PERIOD_NS;
        if periods > MAX_CATCH_UP_PERIODS {
            self.stats.lag_events += 1;
            let skipped = (periods - MAX_CATCH_UP_PERIODS) * PERIOD_NS;
            self.origin = Some(origin + Duration::from_nanos(skipped));
            periods = MAX_CATCH_UP_PERIODS;
        }
        for _ in 0..periods {
            self.step(to_master);
        }
    }

    /// Serves the bus to socketcand clients on `server` until `stop` says so (asked after every round with the
    /// counters). Frames from clients go onto the bus (and, by the server, to the other clients); frames from the
    /// nodes go to every client.
    pub fn serve(
        &mut self,
        server: &mut SocketcandServer,
        poll: Duration,
        mut stop: impl FnMut(&Self) -> bool,
    ) -> io::Result<()> {
        loop {
            let mut out = Vec::new();
            let frames = server.poll(self.now_ns / 1_000);
            let busy = !frames.is_empty();
            for frame in frames {
                match self.config.clock {
                    CanClock::LockStep => out.extend(self.lock_step(frame)),
                    CanClock::RealTime => self.send(frame),
                }
            }
            if self.config.clock == CanClock::RealTime {
                self.catch_up(&mut out);
            }
            for d in &out {
                server.broadcast(&d.frame, d.end_ns / 1_000);
            }
            if stop(self) {
                return Ok(());
            }
            if !busy && out.is_empty() {
                std::thread::sleep(poll);
            }
        }
    }

    /// Whether every drive is in NMT state `state` (a drive in the bootloader's fallback has no NMT state of the
    /// application and is in none).
    pub fn all_in(&self, state: NmtState) -> bool {
        self.drives.iter().all(|d| !d.in_fallback() && d.node.state() == state)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lock_step(nodes: u8) -> CanopenRunner {
        CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, nodes, ..CanopenConfig::default() })
    }

    #[test]
    fn the_nodes_boot_and_their_boot_up_messages_reach_the_master() {
        let mut r = lock_step(3);
        let got = r.run_for(2_000_000);
        let mut ids: Vec<_> = got.iter().map(|d| (d.frame.id(), d.frame.data().to_vec())).collect();
        ids.sort();
        assert_eq!(ids, [(0x701, vec![0]), (0x702, vec![0]), (0x703, vec![0])]);
        assert!(r.all_in(NmtState::PreOperational));
    }

    #[test]
    fn an_sdo_request_in_lock_step_runs_until_the_answer_is_out() {
        let mut r = lock_step(1);
        r.run_for(1_000_000);
        let t0 = r.now_ns();
        let got = r.lock_step(CanFrame::new(0x601, &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0]).unwrap());
        assert_eq!(got.len(), 1, "{got:?}");
        assert_eq!(got[0].frame.id(), 0x581);
        assert_eq!(got[0].frame.data()[0], 0x43, "expedited upload of 0x1000");
        assert!(r.now_ns() - t0 < 2_000_000, "quiet within 2 ms: {} ns", r.now_ns() - t0);
        assert_eq!(r.stats().quiet_limit_hits, 0);
    }

    /// Node 2 with an erased slot A boots into the bootloader's fallback: both boot-ups reach the master, node 2's
    /// device type is the bootloader's (0x0000_012E) and its plant does not step; node 1 runs the application.
    #[test]
    fn a_node_with_an_empty_slot_a_runs_the_fallback_beside_an_application_node() {
        let mut r = CanopenRunner::new(
            CanopenConfig { clock: CanClock::LockStep, nodes: 2, ..CanopenConfig::default() }.with_empty_slot(2),
        );
        assert!(r.config().empty_slot(2) && !r.config().empty_slot(1));
        let got = r.run_for(2_000_000);
        let mut ids: Vec<_> = got.iter().map(|d| (d.frame.id(), d.frame.data().to_vec())).collect();
        ids.sort();
        assert_eq!(ids, [(0x701, vec![0]), (0x702, vec![0])]);
        assert!(!r.drives[0].in_fallback() && r.drives[1].in_fallback());
        assert!(!r.all_in(NmtState::PreOperational), "the fallback has no application NMT state");
        let t_plant = r.drives[1].sim.time_s();
        let got = r.lock_step(CanFrame::new(0x602, &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0]).unwrap());
        assert_eq!(got.len(), 1, "{got:?}");
        assert_eq!(got[0].frame.data(), [0x43, 0x00, 0x10, 0, 0x2E, 0x01, 0, 0]);
        assert_eq!(r.drives[1].sim.time_s(), t_plant, "the plant stands still in the bootloader");
        assert_eq!(r.drives[1].fallback_frames(), 2, "boot-up and one answer");
        assert_eq!(r.stats().quiet_limit_hits, 0);
    }

    #[test]
    fn a_sync_in_lock_step_runs_exactly_one_period() {
        let mut r = lock_step(1);
        r.run_for(1_000_000);
        let t0 = r.now_ns();
        r.lock_step(CanFrame::new(SYNC_COB_ID, &[]).unwrap());
        assert_eq!(r.now_ns() - t0, 1_000_000);
        assert_eq!(r.stats().master_syncs, 1);
    }
}

#[cfg(test)]
mod reset_tests {
    use super::*;

    #[test]
    fn a_node_reset_by_nmt_boots_again_and_says_so() {
        let mut r =
            CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, nodes: 2, ..CanopenConfig::default() });
        r.run_for(2_000_000);
        let got = r.lock_step(CanFrame::new(0x000, &[0x81, 2]).unwrap());
        let ids: Vec<_> = got.iter().map(|d| (d.frame.id(), d.frame.data().to_vec())).collect();
        assert_eq!(ids, [(0x702, vec![0])], "{:?}", r.drives[1].events);
        assert_eq!(r.stats().quiet_limit_hits, 0);
    }

    fn sdo(r: &mut CanopenRunner, request: [u8; 8]) -> [u8; 8] {
        let got = r.lock_step(CanFrame::new(0x601, &request).unwrap());
        let reply = got.iter().find(|d| d.frame.id() == 0x581).expect("an SDO answer");
        reply.frame.data().try_into().unwrap()
    }

    /// 0x1010 "save" reaches the parameter store, and a reset node restarts the drive from it, as the target does.
    #[test]
    fn a_saved_parameter_survives_a_reset_node() {
        let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
        r.run_for(2_000_000);
        // 0x6065 following error window := 12345.
        let v = 12_345u32.to_le_bytes();
        assert_eq!(sdo(&mut r, [0x23, 0x65, 0x60, 0, v[0], v[1], v[2], v[3]])[0], 0x60);
        let save = u32::from_le_bytes(*b"save").to_le_bytes();
        assert_eq!(sdo(&mut r, [0x23, 0x10, 0x10, 1, save[0], save[1], save[2], save[3]])[0], 0x60, "saved");
        // Changed again without saving: the restart must bring back the saved value, not this one.
        let w = 777u32.to_le_bytes();
        assert_eq!(sdo(&mut r, [0x23, 0x65, 0x60, 0, w[0], w[1], w[2], w[3]])[0], 0x60);
        let boot = r.lock_step(CanFrame::new(0x000, &[0x81, 1]).unwrap());
        assert!(boot.iter().any(|d| d.frame.id() == 0x701), "boot-up after the reset");
        let reply = sdo(&mut r, [0x40, 0x65, 0x60, 0, 0, 0, 0, 0]);
        assert_eq!(reply[..4], [0x43, 0x65, 0x60, 0]);
        assert_eq!(u32::from_le_bytes(reply[4..].try_into().unwrap()), 12_345);
    }

    /// Expedited download of `value` (`len` bytes) to `index:sub`; the answer's command byte.
    fn download(r: &mut CanopenRunner, index: u16, sub: u8, value: u32, len: u8) -> u8 {
        let command = 0x23 | ((4 - len) << 2);
        let [i0, i1] = index.to_le_bytes();
        let v = value.to_le_bytes();
        sdo(r, [command, i0, i1, sub, v[0], v[1], v[2], v[3]])[0]
    }

    /// Expedited upload of `index:sub` as an unsigned value.
    fn upload(r: &mut CanopenRunner, index: u16, sub: u8) -> u32 {
        let [i0, i1] = index.to_le_bytes();
        let reply = sdo(r, [0x40, i0, i1, sub, 0, 0, 0, 0]);
        assert_eq!(reply[0] & 0xF3, 0x43, "upload {index:#06x}:{sub}: {reply:02x?}");
        let len = 4 - usize::from((reply[0] >> 2) & 3);
        let mut v = [0u8; 4];
        v[..len].copy_from_slice(&reply[4..4 + len]);
        u32::from_le_bytes(v)
    }

    /// Proves CiA 301 §7.5.2.13 for the whole communication area: every persistent RAM entry of 0x1000..0x1FFF
    /// (its `$NODEID+` COB-IDs aside, which keep their defaults here so that the node stays reachable) set to
    /// another value within its limits, saved with 0x1010:02 and changed back to the defaults unsaved, holds the
    /// saved bytes again after a reset node (a restart from the parameter store) and after a reset communication.
    #[test]
    fn every_persistent_communication_entry_comes_back_after_both_resets() {
        use firmware::od::entry::{Limits, Storage};
        let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
        r.run_for(2_000_000);
        let entries: Vec<_> = {
            let d = r.drives[0].sim.drive.dictionary();
            d.table()
                .entries()
                .iter()
                .filter(|e| (0x1000..=0x1FFF).contains(&e.index) && e.persistent() && !e.node_id_relative())
                .filter(|e| matches!(e.storage, Storage::Ram { .. }) && e.data_type.fixed_size().is_some())
                .copied()
                .collect()
        };
        assert!(entries.len() > 100, "{} persistent communication entries", entries.len());
        // Each value one above its default (or one below at the top of its range), as raw little-endian bytes.
        let defaults = r.drives[0].sim.drive.dictionary().values().bytes().to_vec();
        let dict = r.drives[0].sim.drive.dictionary_mut();
        let mut changed = 0;
        for e in &entries {
            let Some(raw) = dict.values_mut().raw_mut(e) else { continue };
            let mut bytes = [0u8; 8];
            bytes[..raw.len()].copy_from_slice(raw);
            let value = u64::from_le_bytes(bytes);
            let max = match *e.generated_limits() {
                Limits::Unsigned { max, .. } => u64::from(max),
                _ => u64::MAX >> (64 - 8 * raw.len() as u32),
            };
            let new = if value < max { value + 1 } else { value - 1 };
            raw.copy_from_slice(&new.to_le_bytes()[..raw.len()]);
            changed += 1;
        }
        let saved = r.drives[0].sim.drive.dictionary().values().bytes().to_vec();
        let save = u32::from_le_bytes(*b"save");
        assert_eq!(download(&mut r, 0x1010, 2, save, 4), 0x60, "save communication");
        // Unsaved: the running values back to the defaults.
        r.drives[0].sim.drive.dictionary_mut().values_mut().bytes_mut().copy_from_slice(&defaults);
        for command in [0x81, 0x82] {
            nmt(&mut r, command);
            let now = r.drives[0].sim.drive.dictionary().values().bytes().to_vec();
            for e in &entries {
                let Storage::Ram { offset, len, .. } = e.storage else { continue };
                let range = usize::from(offset)..usize::from(offset) + usize::from(len);
                assert_eq!(now[range.clone()], saved[range], "{:#06x}:{} after NMT {command:#x}", e.index, e.sub);
            }
        }
        println!("{changed} persistent communication entries saved and back after reset node and reset communication");
    }

    /// The communication parameters a new user sets (heartbeat 0x1017, EMCY inhibit 0x1015, verify configuration
    /// 0x1020:01, TPDO 1 event timer 0x1800:05) and their defaults.
    const COMMUNICATION: [(u16, u8, u32, u8, u32); 4] =
        [(0x1017, 0, 150, 2, 0), (0x1015, 0, 7, 2, 0), (0x1020, 1, 15_000, 4, 0), (0x1800, 5, 200, 2, 0)];

    fn nmt(r: &mut CanopenRunner, command: u8) {
        let boot = r.lock_step(CanFrame::new(0x000, &[command, 1]).unwrap());
        assert!(boot.iter().any(|d| d.frame.id() == 0x701 && d.frame.data() == [0]), "boot-up after {command:#x}");
    }

    /// Proves CiA 301 §7.3.2 and §7.5.2.13: communication parameters saved with 0x1010 are the power-on values,
    /// so a reset node (the drive restarts from its parameter store) and a reset communication both bring them
    /// back, not the defaults, while unsaved changes are dropped; the heartbeat runs with the saved 0x1017 (150 ms:
    /// 6 or 7 heartbeats in one second); "save communication parameters" (0x1010:02) alone is enough; after
    /// "restore defaults" (0x1011:02) the next reset brings the defaults (0).
    #[test]
    fn saved_communication_parameters_survive_reset_node_and_reset_communication() {
        let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
        r.run_for(2_000_000);
        for (index, sub, value, len, _) in COMMUNICATION {
            assert_eq!(download(&mut r, index, sub, value, len), 0x60, "{index:#06x}:{sub}");
        }
        let save = u32::from_le_bytes(*b"save");
        assert_eq!(download(&mut r, 0x1010, 1, save, 4), 0x60, "save all");
        // Changed again without saving: the resets bring back the saved values, not these.
        for (index, sub, value, len, _) in COMMUNICATION {
            assert_eq!(download(&mut r, index, sub, value + 1, len), 0x60, "{index:#06x}:{sub}");
        }
        for command in [0x81, 0x82] {
            nmt(&mut r, command);
            for (index, sub, value, _, _) in COMMUNICATION {
                assert_eq!(upload(&mut r, index, sub), value, "{index:#06x}:{sub} after NMT {command:#x}");
            }
            let heartbeats = r.run_for(1_000_000_000).iter().filter(|d| d.frame.id() == 0x701).count();
            assert!((6..=7).contains(&heartbeats), "{heartbeats} heartbeats in 1 s after NMT {command:#x}");
        }
        // "Save communication parameters" alone.
        assert_eq!(download(&mut r, 0x1017, 0, 100, 2), 0x60);
        assert_eq!(download(&mut r, 0x1010, 2, save, 4), 0x60, "save communication");
        nmt(&mut r, 0x82);
        assert_eq!(upload(&mut r, 0x1017, 0), 100, "0x1017 after save communication and reset communication");
        // "Restore default parameters" of the communication group: the defaults at the next reset.
        let load = u32::from_le_bytes(*b"load");
        assert_eq!(download(&mut r, 0x1011, 2, load, 4), 0x60, "restore communication defaults");
        assert_eq!(upload(&mut r, 0x1017, 0), 100, "running values unchanged until the reset");
        nmt(&mut r, 0x82);
        for (index, sub, _, _, default) in COMMUNICATION {
            assert_eq!(upload(&mut r, index, sub), default, "{index:#06x}:{sub} after restoring the defaults");
        }
    }
}
