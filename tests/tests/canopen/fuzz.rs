//! Fuzzing the drive as a CANopen node (issue 8: "a fuzz test (bounded in time in CI) of random frames into the
//! node: no panic, nothing lost, the node answers correctly after").
//!
//! The target is `firmware::canopen::CanopenNode` in-process with the simulated drive behind it
//! (`hal_sim::sim::Simulation`, the reference plant), frames in through `handle_frame`, tier 3 through `process`,
//! frames out through `transmit`, as `drive-sim canopen` runs it. A case is a few batches of actions; an action is
//! a frame or a short sequence a master (or a broken node) could send, built from valid frames and then varied:
//! - frames with random identifiers, lengths (0..=8), data and remote bit;
//! - SDO requests to the node's server with every command specifier class (expedited and segmented download and
//!   upload, their segments with either toggle, block download and upload initiations, sub-blocks, ends, aborts,
//!   random bytes) on interesting and random indices, and SDO frames of wrong length;
//! - NMT commands (every command, addressed to the node, to all or to another node, wrong lengths);
//! - SYNCs of every length (0..=8) and RPDOs 1..4 of every length, TPDO remote requests, heartbeats of other nodes;
//! - configurations that make the supervision fire (heartbeat consumer 0x1016, SYNC period 0x1006, SYNC counter
//!   0x1019, PDOs valid and synchronous), so that the drive raises communication faults and EMCYs;
//! - time: the plant, the drive and the node's tier 3 run for a while.
//!
//! After every batch: the node is in one of the NMT states, not stuck in initialisation; its counters are
//! consistent (frames ignored never exceed frames delivered and never decrease, SYNCs counted never exceed the
//! SYNC frames delivered, the transmit queue within its size); a master recovers it: NMT reset communication
//! (broadcast: a fuzzed 0x2000 may have changed the node-ID) gives the reset, then the boot-up message, then
//! pre-operational, and an SDO upload of 0x1000 answers 0x0002_0192 (CiA 402 drive). Nothing lost: once the drive's
//! EMCY queue has drained (pre-operational sends EMCYs), every EMCY the drive queued came out as a frame on the
//! EMCY COB-ID, or was counted as lost and reported in an overflow EMCY (`fault::emcy` accounting).
//!
//! Bounds: [`DEFAULT_CASES`] cases per property in the default run (about 3 s in the dev profile);
//! `CANOPEN_FUZZ_CASES=<n>` runs `n` cases instead with a random seed (`CANOPEN_FUZZ_SEED=<u64>` fixes it). A
//! failing case is shrunk, stored in `canopen_fuzz.proptest-regressions` and replayed first in later runs.

use firmware::canopen::frame::CanFrame;
use firmware::canopen::ids;
use firmware::canopen::nmt::{NmtState, ResetKind};
use firmware::canopen::{CanopenNode, NodeEvent, OUTBOX_LEN};
use firmware::od::access::NoApplicationObjects;
use hal_sim::sim::Simulation;
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// Cases per property in the default (CI) run.
const DEFAULT_CASES: u32 = 512;
/// The node-ID at power-on.
const NODE: u8 = 5;
/// PWM periods per millisecond (40 us each).
const PERIODS_PER_MS: u32 = 25;
/// The device type 0x1000 answers (CiA 402 drive).
const DEVICE_TYPE: u32 = 0x0002_0192;

/// What the fuzzer does in one step.
#[derive(Clone, Debug)]
enum Action {
    /// Any frame: identifier, data (0..=8 bytes), or a remote request of this DLC.
    Raw(u16, Vec<u8>, Option<u8>),
    /// An SDO request to the node's server (8 bytes), or a frame of the wrong length on its COB-ID.
    Sdo(Vec<u8>),
    /// NMT: command specifier, target (0 = all), frame length (2 is valid).
    Nmt(u8, u8, usize),
    /// A SYNC of this length.
    Sync(usize),
    /// RPDO `n` (0..=3) with this data.
    Rpdo(usize, Vec<u8>),
    /// A remote request for TPDO `n`.
    TpdoRemote(usize),
    /// A heartbeat of node `n` with this state byte.
    Heartbeat(u8, u8),
    /// An expedited download (4 bytes) the supervision or the PDOs react to.
    Configure(u16, u8, u32),
    /// Time passes: this many milliseconds of plant, drive and tier 3.
    Time(u16),
}

/// The node with the drive, and what the test counted.
struct Rig {
    sim: Simulation,
    node: CanopenNode,
    app: NoApplicationObjects,
    now_us: u64,
    /// Frames handed to the node, and the SYNC frames among them (on the SYNC COB-ID, any length).
    delivered: u64,
    syncs_delivered: u64,
    /// Frames the node sent that were EMCYs (on the EMCY COB-ID of the moment, 8 bytes).
    emcy_frames: u64,
    /// Everything the node sent since the last `take`.
    sent: Vec<CanFrame>,
    last_ignored: u32,
    last_dropped: u32,
    /// What the fuzzing reached (for the coverage test).
    reached: Reached,
}

/// Coverage of a run.
#[derive(Clone, Copy, Debug, Default)]
struct Reached {
    /// NMT states seen after an action (bit per state: 0 pre-op, 1 operational, 2 stopped).
    states: u8,
    sdo_answers: u64,
    sdo_aborts: u64,
    tpdos: u64,
    emcys: u64,
    ignored: u64,
    batches: u64,
}

impl Reached {
    fn add(&mut self, o: &Self) {
        self.states |= o.states;
        self.sdo_answers += o.sdo_answers;
        self.sdo_aborts += o.sdo_aborts;
        self.tpdos += o.tpdos;
        self.emcys += o.emcys;
        self.ignored += o.ignored;
        self.batches += o.batches;
    }
}

impl Rig {
    /// The node after its power-on reset and boot, pre-operational.
    fn new() -> Self {
        let mut rig = Self {
            sim: Simulation::reference(7),
            node: CanopenNode::new(NODE),
            app: NoApplicationObjects,
            now_us: 0,
            delivered: 0,
            syncs_delivered: 0,
            emcy_frames: 0,
            sent: Vec::new(),
            last_ignored: 0,
            last_dropped: 0,
            reached: Reached::default(),
        };
        assert!(matches!(rig.process(), Some(NodeEvent::Reset { kind: ResetKind::Node, .. })));
        assert_eq!(rig.process(), Some(NodeEvent::Booted));
        assert_eq!(rig.node.state(), NmtState::PreOperational);
        rig
    }

    fn id(&self, base: u16) -> u16 {
        base + u16::from(self.node.node_id())
    }

    /// The EMCY COB-ID now, if EMCY is valid (0x1014 bit 31 clear).
    fn emcy_cob_id(&self) -> Option<u16> {
        let raw = ids::read_u32(self.sim.drive.dictionary(), 0x1014, 0);
        (raw & (1 << 31) == 0).then_some((raw & 0x7FF) as u16)
    }

    /// Takes the node's frames out and counts the EMCYs among them.
    fn drain(&mut self) {
        let emcy = self.emcy_cob_id();
        let sdo_tx = self.id(0x580);
        while let Some(f) = self.node.transmit() {
            if Some(f.id()) == emcy && f.dlc() == 8 && !f.is_remote() {
                self.emcy_frames += 1;
                self.reached.emcys += 1;
            } else if f.id() == sdo_tx {
                self.reached.sdo_answers += 1;
                self.reached.sdo_aborts += u64::from(f.data().first() == Some(&0x80));
            } else if (0x181..=0x4FF).contains(&f.id()) {
                self.reached.tpdos += 1;
            }
            self.sent.push(f);
        }
    }

    fn deliver(&mut self, f: &CanFrame) {
        self.delivered += 1;
        if f.id() == 0x080 {
            self.syncs_delivered += 1;
        }
        self.node.handle_frame(f, &mut self.sim.drive, &mut self.app, self.now_us);
        self.drain();
    }

    fn frame(&mut self, id: u16, data: &[u8]) {
        let f = CanFrame::new(id & 0x7FF, &data[..data.len().min(8)]).expect("a valid frame");
        self.deliver(&f);
    }

    fn process(&mut self) -> Option<NodeEvent> {
        let e = self.node.process(&mut self.sim.drive, &mut self.app, self.now_us);
        self.drain();
        e
    }

    /// `ms` milliseconds: 25 PWM periods and one tier-3 pass per millisecond.
    fn time(&mut self, ms: u32) {
        for _ in 0..ms {
            for _ in 0..PERIODS_PER_MS {
                self.sim.step();
            }
            self.now_us += 1_000;
            self.process();
        }
    }

    fn act(&mut self, action: &Action) {
        match action {
            Action::Raw(id, data, remote) => match remote {
                Some(dlc) => self.deliver(&CanFrame::remote(id & 0x7FF, (*dlc).min(8)).expect("a remote frame")),
                None => self.frame(*id, data),
            },
            Action::Sdo(bytes) => {
                let id = self.id(0x600);
                self.frame(id, bytes);
            }
            Action::Nmt(cs, target, len) => {
                let mut data = vec![*cs, *target, 0x55, 0xAA];
                data.truncate(*len);
                self.frame(0x000, &data);
            }
            Action::Sync(len) => self.frame(0x080, &[0x11; 8][..*len]),
            Action::Rpdo(n, data) => {
                let id = self.id([0x200, 0x300, 0x400, 0x500][*n % 4]);
                self.frame(id, data);
            }
            Action::TpdoRemote(n) => {
                let id = self.id([0x180, 0x280, 0x380, 0x480][*n % 4]);
                self.deliver(&CanFrame::remote(id, 8).expect("a remote frame"));
            }
            Action::Heartbeat(n, state) => self.frame(0x700 + u16::from((*n).clamp(1, 127)), &[*state]),
            Action::Configure(index, sub, value) => {
                let [i0, i1] = index.to_le_bytes();
                let [v0, v1, v2, v3] = value.to_le_bytes();
                let id = self.id(0x600);
                self.frame(id, &[0x23, i0, i1, *sub, v0, v1, v2, v3]);
            }
            Action::Time(ms) => self.time(u32::from(*ms)),
        }
        // Tier 3 after every frame, as the runtime's background loop would run soon after.
        self.process();
        self.reached.states |= match self.node.state() {
            NmtState::PreOperational => 1,
            NmtState::Operational => 2,
            NmtState::Stopped => 4,
            NmtState::Initialisation => 0,
        };
    }

    /// The invariants, the recovery and the EMCY accounting (see the module documentation).
    fn check_and_recover(&mut self, batch: usize) {
        // A node left in initialisation (an NMT reset as the batch's last frame) finishes at its next passes.
        for _ in 0..2 {
            if self.node.state() == NmtState::Initialisation {
                self.process();
            }
        }
        assert_ne!(self.node.state(), NmtState::Initialisation, "batch {batch}: stuck in initialisation");
        let c = self.node.counters();
        assert!(u64::from(c.ignored) <= self.delivered, "batch {batch}: {c:?}, {} delivered", self.delivered);
        assert!(c.ignored >= self.last_ignored && c.tx_dropped >= self.last_dropped, "batch {batch}: {c:?}");
        assert!(u64::from(c.syncs) <= self.syncs_delivered, "batch {batch}: {c:?}, {} SYNCs", self.syncs_delivered);
        assert!(self.node.pending_frames() <= OUTBOX_LEN);
        self.reached.ignored += u64::from(c.ignored - self.last_ignored);
        self.last_ignored = c.ignored;
        self.last_dropped = c.tx_dropped;

        // Recovery: reset communication for all, reset, boot-up, pre-operational.
        self.sent.clear();
        self.frame(0x000, &[0x82, 0]);
        assert_eq!(self.node.state(), NmtState::Initialisation, "batch {batch}: reset communication accepted");
        let reset = self.process();
        assert!(
            matches!(reset, Some(NodeEvent::Reset { kind: ResetKind::Communication, .. })),
            "batch {batch}: {reset:?}"
        );
        assert_eq!(self.process(), Some(NodeEvent::Booted), "batch {batch}");
        let boot_up: Vec<_> =
            self.sent.iter().filter(|f| f.id() == self.id(0x700)).map(|f| f.data().to_vec()).collect();
        assert_eq!(boot_up, [vec![0u8]], "batch {batch}: one boot-up message");
        assert_eq!(self.node.state(), NmtState::PreOperational, "batch {batch}");
        assert!(!self.node.sdo().is_busy(), "batch {batch}: the reset ended any SDO transfer");

        // SDO upload of 0x1000.
        self.sent.clear();
        let id = self.id(0x600);
        self.frame(id, &[0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
        self.process();
        let answers: Vec<_> = self.sent.iter().filter(|f| f.id() == self.id(0x580)).collect();
        assert_eq!(answers.len(), 1, "batch {batch}: {:?}", self.sent);
        let mut expected = vec![0x43, 0x00, 0x10, 0x00];
        expected.extend_from_slice(&DEVICE_TYPE.to_le_bytes());
        assert_eq!(answers[0].data(), &expected[..], "batch {batch}: 0x1000 uploaded");

        // Nothing lost: let the drive's EMCY queue drain (inhibit time 0x1015 runs on the drive's clock).
        for _ in 0..200 {
            if self.sim.drive.axis().faults().emcy().is_idle() {
                break;
            }
            self.time(1);
        }
        let emcy = self.sim.drive.axis().faults().emcy();
        assert!(emcy.is_idle(), "batch {batch}: the EMCY queue drains in pre-operational");
        let s = emcy.stats();
        assert_eq!(s.enqueued, s.emitted + s.lost, "batch {batch}: every EMCY sent or counted as lost: {s:?}");
        assert!(s.lost == 0 || s.overflow_reports > 0, "batch {batch}: losses reported: {s:?}");
        assert_eq!(
            self.emcy_frames,
            u64::from(s.emitted + s.overflow_reports),
            "batch {batch}: every EMCY the drive handed out is a frame: {s:?}"
        );
        self.reached.batches += 1;
    }
}

/// Indices a fuzzed SDO request addresses: the communication objects, the drive's, and a few that do not exist.
fn index() -> impl Strategy<Value = u16> {
    prop_oneof![
        3 => prop::sample::select(vec![
            0x1000u16, 0x1001, 0x1003, 0x1005, 0x1006, 0x1008, 0x1010, 0x1014, 0x1015, 0x1016, 0x1017, 0x1018,
            0x1019, 0x1200, 0x1400, 0x1401, 0x1600, 0x1601, 0x1800, 0x1801, 0x1A00, 0x1A01, 0x1F50, 0x2000,
            0x2001, 0x6040, 0x6060, 0x607A, 0x6041,
        ]),
        1 => any::<u16>(),
    ]
}

/// An SDO request: every command class, mostly 8 bytes.
fn sdo() -> impl Strategy<Value = Vec<u8>> {
    let command = prop_oneof![
        prop::sample::select(vec![
            0x20u8, 0x21, 0x22, 0x23, 0x27, 0x2B, 0x2F, // initiate download
            0x40, // initiate upload
            0x00, 0x01, 0x0D, 0x10, 0x11, 0x1D, // download segments
            0x60, 0x70, // upload segments
            0xC0, 0xC2, 0xC4, 0xC6, 0xC1, 0xC5, // block download initiate, end
            0xA0, 0xA4, 0xA2, 0xA3, 0xA1, // block upload initiate, start, ack, end
            0x80, // abort
        ]),
        any::<u8>(),
    ];
    (
        command,
        index(),
        prop_oneof![4 => 0u8..=12, 1 => any::<u8>()],
        any::<[u8; 4]>(),
        prop_oneof![8 => Just(8usize), 1 => 0usize..=8],
    )
        .prop_map(|(cmd, index, sub, data, len)| {
            let [i0, i1] = index.to_le_bytes();
            let mut f = vec![cmd, i0, i1, sub, data[0], data[1], data[2], data[3]];
            f.truncate(len);
            f
        })
}

fn small_data() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..=8)
}

/// Configurations that make the node's supervision and PDOs run (expedited downloads; some are refused).
fn configure() -> impl Strategy<Value = Action> {
    prop_oneof![
        // Heartbeat consumer: node 1..3, 2..20 ms.
        (1u32..=3, 2u32..=20).prop_map(|(n, ms)| Action::Configure(0x1016, 1, (n << 16) | ms)),
        // Own heartbeat 1..10 ms.
        (1u32..=10).prop_map(|ms| Action::Configure(0x1017, 0, ms)),
        // SYNC period 1..5 ms.
        (1u32..=5).prop_map(|ms| Action::Configure(0x1006, 0, ms * 1_000)),
        // SYNC counter overflow (0, 2..=240 valid; others refused).
        any::<u8>().prop_map(|v| Action::Configure(0x1019, 0, u32::from(v))),
        // RPDO and TPDO transmission types (synchronous, cyclic, event).
        (0u16..4, prop::sample::select(vec![0u32, 1, 2, 240, 254, 255])).prop_map(|(n, t)| Action::Configure(
            0x1400 + n,
            2,
            t
        )),
        (0u16..4, prop::sample::select(vec![0u32, 1, 3, 253, 254, 255])).prop_map(|(n, t)| Action::Configure(
            0x1800 + n,
            2,
            t
        )),
        // TPDO 2..4 valid (the default is not valid) on their default COB-IDs.
        (1u16..4).prop_map(|n| Action::Configure(
            0x1800 + n,
            1,
            0x4000_0000 | (0x180 + 0x100 * u32::from(n) + u32::from(NODE))
        )),
        // EMCY inhibit time 0..5 ms (100 us units).
        (0u32..=50).prop_map(|t| Action::Configure(0x1015, 0, t)),
    ]
}

fn action() -> impl Strategy<Value = Action> {
    prop_oneof![
        4 => (0u16..0x800, small_data(), prop_oneof![6 => Just(None), 1 => (0u8..=8).prop_map(Some)])
            .prop_map(|(id, d, r)| Action::Raw(id, d, r)),
        6 => sdo().prop_map(Action::Sdo),
        2 => (
            prop::sample::select(vec![0x01u8, 0x02, 0x80, 0x81, 0x82, 0x00, 0x83, 0xFF]),
            prop::sample::select(vec![0u8, NODE, NODE + 1, 127]),
            prop_oneof![6 => Just(2usize), 1 => 0usize..=4],
        )
            .prop_map(|(cs, t, l)| Action::Nmt(cs, t, l)),
        3 => Just(Action::Nmt(0x01, 0, 2)),
        4 => prop_oneof![4 => Just(0usize), 1 => 0usize..=8].prop_map(Action::Sync),
        4 => (0usize..4, small_data()).prop_map(|(n, d)| Action::Rpdo(n, d)),
        1 => (0usize..4).prop_map(Action::TpdoRemote),
        2 => (1u8..=4, prop::sample::select(vec![0x05u8, 0x7F, 0x04, 0x00, 0x12])).prop_map(|(n, s)| Action::Heartbeat(n, s)),
        3 => configure(),
        2 => (1u16..=30).prop_map(Action::Time),
    ]
}

fn batches() -> impl Strategy<Value = Vec<Vec<Action>>> {
    prop::collection::vec(prop::collection::vec(action(), 1..40), 1..4)
}

/// SDO traffic only, in pre-operational or operational: transfers in progress meet unexpected requests more often.
fn sdo_batches() -> impl Strategy<Value = Vec<Vec<Action>>> {
    let traffic = prop_oneof![8 => sdo().prop_map(Action::Sdo), 1 => (1u16..=5).prop_map(Action::Time), 1 => Just(Action::Nmt(0x01, 0, 2))];
    prop::collection::vec(prop::collection::vec(traffic, 1..60), 1..4)
}

/// Runs a case: every batch, then the invariants and the recovery.
fn run(batches: &[Vec<Action>]) -> Rig {
    let mut rig = Rig::new();
    for (k, batch) in batches.iter().enumerate() {
        for a in batch {
            rig.act(a);
        }
        rig.check_and_recover(k);
    }
    rig
}

fn cases() -> u32 {
    std::env::var("CANOPEN_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(DEFAULT_CASES)
}

/// The default run is the same every time (a fixed seed); a long run (`CANOPEN_FUZZ_CASES`) explores with a random
/// seed; `CANOPEN_FUZZ_SEED=<n>` fixes it.
fn seed() -> RngSeed {
    match std::env::var("CANOPEN_FUZZ_SEED").ok().and_then(|v| v.parse().ok()) {
        Some(seed) => RngSeed::Fixed(seed),
        None if std::env::var_os("CANOPEN_FUZZ_CASES").is_some() => RngSeed::Random,
        None => RngSeed::Fixed(0x0C0A_4F0C_2201),
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(),
        rng_seed: seed(),
        max_shrink_iters: 1_000,
        ..ProptestConfig::default()
    })]

    /// Random and mutated frames of every service: no panic, consistent counters, EMCYs accounted for, and a
    /// reset communication always recovers a node that answers an SDO upload of 0x1000.
    #[test]
    fn random_frames_never_leave_the_node_unrecoverable(batches in batches()) {
        run(&batches);
    }

    /// SDO request sequences: the same invariants and recovery.
    #[test]
    fn sdo_sequences_never_leave_the_node_unrecoverable(batches in sdo_batches()) {
        run(&batches);
    }
}

/// The recovery is not vacuous: a node left stopped with a segmented upload in progress and a fuzzed node-ID in
/// 0x2000 is recovered (reset communication takes the new node-ID; the boot-up and the SDO answer come on its
/// COB-IDs), and a wrong-length SYNC's EMCY 0x8240 is counted as a frame.
#[test]
fn the_recovery_resets_the_node_and_answers_on_its_new_node_id() {
    let mut rig = Rig::new();
    rig.act(&Action::Sdo(vec![0x2F, 0x00, 0x20, 0x00, 9, 0, 0, 0])); // 0x2000 = 9 (UNSIGNED8)
    rig.act(&Action::Sdo(vec![0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0])); // segmented upload of the device name
    rig.act(&Action::Nmt(0x01, 0, 2));
    rig.act(&Action::Sync(3));
    rig.act(&Action::Nmt(0x02, NODE, 2));
    assert_eq!(rig.node.state(), NmtState::Stopped);
    rig.check_and_recover(0);
    assert_eq!(rig.node.node_id(), 9);
    assert!(rig.emcy_frames >= 1, "the SYNC length EMCY came out");
}

/// The fuzzing is not vacuous: a fixed-seed run of the same generators (48 general cases, 24 SDO cases) reaches
/// the three NMT states, gets SDO answers and aborts, TPDOs and EMCYs out and frames ignored, every batch ending in
/// a checked recovery.
#[test]
fn a_fixed_seed_run_reaches_the_states_and_the_services() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::{RngAlgorithm, TestRng, TestRunner};
    let rng = TestRng::from_seed(RngAlgorithm::ChaCha, &[0xC0; 32]);
    let mut runner = TestRunner::new_with_rng(ProptestConfig::default(), rng);
    let mut total = Reached::default();
    let strategy = batches();
    for _ in 0..48 {
        let case = strategy.new_tree(&mut runner).expect("a case").current();
        total.add(&run(&case).reached);
    }
    eprintln!("{total:?}");
    assert_eq!(total.states, 0b111, "pre-operational, operational and stopped reached: {total:?}");
    assert!(total.sdo_answers > 200 && total.sdo_aborts > 50, "{total:?}");
    assert!(total.tpdos > 20 && total.emcys > 10 && total.ignored > 100, "{total:?}");
    assert!(total.batches >= 48, "{total:?}");

    let strategy = sdo_batches();
    let mut total = Reached::default();
    for _ in 0..24 {
        let case = strategy.new_tree(&mut runner).expect("a case").current();
        total.add(&run(&case).reached);
    }
    eprintln!("SDO sequences: {total:?}");
    assert!(total.sdo_answers > 300 && total.sdo_aborts > 50 && total.batches >= 24, "{total:?}");
}
