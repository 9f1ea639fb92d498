//! `drive-sim identify`: the motor identification (0x6060 = -2, `firmware::drive::auto_setup`) run as a master
//! runs it, through SDO requests to the simulated drive's own SDO server (CiA 301 expedited transfers): mode -2,
//! «Shutdown», «Switch on», «Enable operation», then controlword bit 4; while it runs the master polls the step,
//! the progress and the statusword every 10 ms; at the end it reads the results back and they are compared with
//! the plant's true values.

use firmware::comm::sdo::server::SdoServer;
use firmware::drive::DriveConfig;
use firmware::od::access::{AccessContext, CommState, NoApplicationObjects};

use firmware::od::store::ParamStore;

use crate::flash::SimFlash;
use crate::plant::PlantParams;
use crate::sim::Simulation;

/// Periods between the master's polls (10 ms).
const POLL_PERIODS: u64 = 250;
/// The master gives up after this much simulated time (the drive's own timeout is 20 s).
const GIVE_UP_S: f64 = 30.0;

/// What the master saw of the SDO server during the run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SdoFigures {
    /// Requests sent.
    pub requests: u32,
    /// Requests answered with a response (not an abort).
    pub answered: u32,
    /// Requests answered with an abort.
    pub aborted: u32,
    /// The longest simulated time between two answered requests while the procedure ran, ms.
    pub max_gap_ms: f64,
}

/// The identified values as the master read them back (their objects' units converted to SI).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Identified {
    /// 0x3002:01 (uOhm), ohm.
    pub resistance_ohm: f64,
    /// 0x3002:02, H.
    pub lq_h: f64,
    /// 0x3002:03, H.
    pub ld_h: f64,
    /// 0x3001:05, N m/A.
    pub kt_nm_per_a: f64,
    /// 0x3204:06 total inertia, kg m^2 (0: not identified).
    pub inertia_kg_m2: f64,
    /// 0x3204:05 Coulomb friction, N m (0: not identified).
    pub coulomb_friction_nm: f64,
    /// 0x3204:04.
    pub pole_pairs: u8,
    /// 0x3010:05 (-1 none).
    pub index_offset: i32,
    /// 0x301A:03.
    pub hall_offset: u16,
    /// 0x3010:02.
    pub encoder_type: u16,
    /// 0x3205:03 (0.1 Hz), Hz: the load's first resonance (0: rigid, or not identified).
    pub resonance_hz: f64,
    /// 0x3205:04 (0.1 Hz), Hz: the anti-resonance under it (0: rigid, or not identified).
    pub anti_resonance_hz: f64,
}

/// How the run ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Statusword bit 12: done.
    Done,
    /// Statusword bit 3: a fault with this 0x603F code; whether the power stage was off (PWM outputs disabled).
    Fault {
        /// 0x603F.
        code: u16,
        /// The PWM outputs were off at the end.
        power_off: bool,
    },
    /// Neither within 30 s of simulated time (the drive's own timeout is 20 s).
    GaveUp,
}

/// The run's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct IdentifyRun {
    /// How it ended.
    pub outcome: Outcome,
    /// Simulated seconds from controlword bit 4 to the end.
    pub identify_s: f64,
    /// The values read back.
    pub identified: Identified,
    /// The SDO figures.
    pub sdo: SdoFigures,
    /// The highest step 0x3204:02 showed (8 done, 255 failed).
    pub last_step: u8,
    /// The identified and tuned objects read back at the end ([`IDENTIFIED_OBJECTS`]).
    pub parameters: Parameters,
}

/// Issue 18's bounds ("What it must show") on [`IdentifyRun::errors_pct`], percent: R, Lq and kt 3 %, Ld 5 %, the
/// total inertia 5 % (a rigid load).
pub const ISSUE_BOUNDS_RIGID_PCT: [f64; 5] = [3.0, 5.0, 3.0, 3.0, 5.0];

impl IdentifyRun {
    /// Error of an identified value against the truth, percent.
    #[must_use]
    pub fn error_pct(identified: f64, truth: f64) -> f64 {
        (identified - truth) / truth * 100.0
    }

    /// The identified R, Ld, Lq, kt and total inertia against the plant `truth`: each name and its error, percent.
    #[must_use]
    pub fn errors_pct(&self, truth: &PlantParams) -> [(&'static str, f64); 5] {
        let id = &self.identified;
        [
            ("R", Self::error_pct(id.resistance_ohm, truth.phase_resistance_ohm)),
            ("Ld", Self::error_pct(id.ld_h, truth.ld_h)),
            ("Lq", Self::error_pct(id.lq_h, truth.lq_h)),
            ("kt", Self::error_pct(id.kt_nm_per_a, truth.torque_constant_nm_per_a())),
            ("inertia", Self::error_pct(id.inertia_kg_m2, truth.total_inertia_kg_m2())),
        ]
    }

    /// Every one of [`Self::errors_pct`] outside its bound in `bounds_pct` (the same order), as "name +x.xx %
    /// (bound b %)"; empty when all are within.
    #[must_use]
    pub fn errors_outside(&self, truth: &PlantParams, bounds_pct: [f64; 5]) -> Vec<String> {
        self.errors_pct(truth)
            .into_iter()
            .zip(bounds_pct)
            .filter(|((_, error), bound)| error.abs() > *bound || error.is_nan())
            .map(|((name, error), bound)| format!("{name} {error:+.2} % (bound {bound} %)"))
            .collect()
    }
}

/// The master's side: an SDO client on the drive's SDO server.
struct Master {
    server: SdoServer,
    sdo: SdoFigures,
    last_answer_s: Option<f64>,
}

impl Master {
    fn request(&mut self, sim: &mut Simulation, frame: [u8; 8]) -> Option<[u8; 8]> {
        self.sdo.requests += 1;
        let ctx = AccessContext {
            comm_state: CommState::Operational,
            power_stage_enabled: sim.drive.state() == firmware::power_state::PowerState::OperationEnabled,
            max_pdo_bytes: 8,
        };
        let now_us = (sim.time_s() * 1e6) as u64;
        let answer = self.server.handle(&frame, now_us, sim.drive.dictionary_mut(), ctx, &mut NoApplicationObjects);
        let t = sim.time_s();
        match answer {
            Some(a) if a[0] != 0x80 => {
                self.sdo.answered += 1;
                if let Some(last) = self.last_answer_s {
                    self.sdo.max_gap_ms = self.sdo.max_gap_ms.max((t - last) * 1000.0);
                }
                self.last_answer_s = Some(t);
                Some(a)
            }
            _ => {
                self.sdo.aborted += 1;
                None
            }
        }
    }

    fn download(&mut self, sim: &mut Simulation, index: u16, sub: u8, data: &[u8]) -> bool {
        let command = match data.len() {
            1 => 0x2F,
            2 => 0x2B,
            3 => 0x27,
            _ => 0x23,
        };
        let [lo, hi] = index.to_le_bytes();
        let mut frame = [command, lo, hi, sub, 0, 0, 0, 0];
        for (slot, byte) in frame[4..].iter_mut().zip(data) {
            *slot = *byte;
        }
        self.request(sim, frame).is_some_and(|a| a[0] == 0x60)
    }

    /// An expedited upload's data bytes, as many as the answer names (CiA 301 7.2.4.3.3: `n` bytes unused).
    fn upload_bytes(&mut self, sim: &mut Simulation, index: u16, sub: u8) -> Option<Vec<u8>> {
        let [lo, hi] = index.to_le_bytes();
        let answer = self.request(sim, [0x40, lo, hi, sub, 0, 0, 0, 0])?;
        (answer[0] & 0xE3 == 0x43).then(|| answer[4..8 - usize::from((answer[0] >> 2) & 3)].to_vec())
    }

    fn upload(&mut self, sim: &mut Simulation, index: u16, sub: u8) -> Option<u32> {
        let [lo, hi] = index.to_le_bytes();
        let answer = self.request(sim, [0x40, lo, hi, sub, 0, 0, 0, 0])?;
        (answer[0] & 0xE3 == 0x43).then(|| u32::from_le_bytes([answer[4], answer[5], answer[6], answer[7]]))
    }
}

/// The objects the identification and its auto-tuning write (the drive's parameters a master saves after it and
/// writes into a drive it commissions): motor data, winding, encoder direction and index offset, Hall offset, and
/// the gains of the current, position and velocity loops, the observer and the dual loop's main loop.
pub const IDENTIFIED_OBJECTS: [(u16, u8); 31] = [
    (0x3001, 5),
    (0x3002, 1),
    (0x3002, 2),
    (0x3002, 3),
    (0x3010, 2),
    (0x3010, 5),
    (0x301A, 3),
    (0x30A0, 1),
    (0x30A0, 2),
    (0x30A1, 1),
    (0x30A1, 2),
    (0x30A1, 3),
    (0x30A1, 4),
    (0x30A1, 5),
    (0x30A1, 6),
    (0x30A1, 7),
    (0x30A2, 1),
    (0x30A2, 2),
    (0x30A2, 3),
    (0x30A2, 4),
    (0x30A2, 5),
    (0x30A3, 1),
    (0x30A3, 2),
    (0x30A3, 3),
    (0x30A3, 4),
    (0x30A3, 5),
    (0x30AE, 1),
    (0x30AE, 2),
    (0x30AE, 3),
    (0x3205, 3),
    (0x3205, 4),
];

/// The values of [`IDENTIFIED_OBJECTS`] one identification left in its drive, as an SDO upload gave them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Parameters {
    /// Index, sub-index and the data bytes.
    pub values: Vec<(u16, u8, Vec<u8>)>,
}

/// Writes `parameters` into the drive of `sim` with SDO downloads (the power stage off), as a master commissions a
/// drive from a saved parameter set.
///
/// # Errors
/// The first object the drive refused, by index and sub-index.
pub fn commission(sim: &mut Simulation, parameters: &Parameters) -> Result<(), String> {
    let mut master = Master { server: SdoServer::default(), sdo: SdoFigures::default(), last_answer_s: None };
    for (index, sub, data) in &parameters.values {
        if !master.download(sim, *index, *sub, data) {
            return Err(format!("the drive refused the identified 0x{index:04X}:{sub:02X} = {data:02X?}"));
        }
    }
    Ok(())
}

/// Runs the identification on `params` (noise seeded with `seed`), after `setup` (fault injection, a wrong
/// parameter) has acted on the commissioned simulation.
pub fn identify(params: &PlantParams, seed: u64, setup: impl FnOnce(&mut Simulation)) -> IdentifyRun {
    identify_then(params, seed, setup, None)
}

/// [`identify`], and then, when `resonance` is given, a master's own resonance pair (0.1 Hz: resonance,
/// anti-resonance) in place of the one the identification measured: with the power stage off it writes
/// 0x3205:03/04 and runs the auto-tuning again (0x3205:01 = 1); the parameters are read after it.
pub fn identify_then(
    params: &PlantParams,
    seed: u64,
    setup: impl FnOnce(&mut Simulation),
    resonance: Option<(u16, u16)>,
) -> IdentifyRun {
    identify_then_with_progress(params, seed, setup, resonance, &mut |_, _| {})
}

/// The identification's last step, 0x3204:02 = 9 "done" (device.toml): the total of the progress it reports.
const LAST_STEP: u8 = 9;

/// [`identify_then`], telling `progress(step, 9)` the identification's step (0x3204:02: 1 standstill ... 8
/// tuning, 9 done) each time the master's poll reads a new one (for a progress bar: `drive-sim identify` and
/// `--auto-tune` on a terminal). The observer only reads the step; the run and its results are the same with any
/// observer.
pub fn identify_then_with_progress(
    params: &PlantParams,
    seed: u64,
    setup: impl FnOnce(&mut Simulation),
    resonance: Option<(u16, u16)>,
    progress: &mut dyn FnMut(u64, u64),
) -> IdentifyRun {
    let mut sim = Simulation::new(params.clone(), seed, DriveConfig::DEFAULT);
    sim.commission_motor_data(params);
    setup(&mut sim);
    sim.run(10);
    let mut master = Master { server: SdoServer::default(), sdo: SdoFigures::default(), last_answer_s: None };
    let statusword = |m: &mut Master, s: &mut Simulation| m.upload(s, 0x6041, 0).unwrap_or(0) as u16;
    master.download(&mut sim, 0x6060, 0, &[(-2i8).to_le_bytes()[0]]);
    for (controlword, mask, state) in [(0x0006u16, 0x6F, 0x21), (0x0007, 0x6F, 0x23), (0x000F, 0x6F, 0x27)] {
        master.download(&mut sim, 0x6040, 0, &controlword.to_le_bytes());
        for _ in 0..400 {
            sim.run(25);
            if statusword(&mut master, &mut sim) & mask == state {
                break;
            }
        }
    }
    // Tier 1 enables in the period the slow tick named; then the rising edge of bit 4 starts.
    sim.run(50);
    master.download(&mut sim, 0x6040, 0, &0x001Fu16.to_le_bytes());
    let start_s = sim.time_s();
    master.last_answer_s = Some(start_s);
    let mut last_step = 0u8;
    let outcome = loop {
        sim.run(POLL_PERIODS);
        let step = master.upload(&mut sim, 0x3204, 2).unwrap_or(0) as u8;
        let _progress = master.upload(&mut sim, 0x3204, 3);
        if (1..=LAST_STEP).contains(&step) && step != last_step {
            progress(u64::from(step), u64::from(LAST_STEP));
        }
        last_step = if step == 0 { last_step } else { step };
        let sw = statusword(&mut master, &mut sim);
        if sw & (1 << 3) != 0 {
            let code = master.upload(&mut sim, 0x603F, 0).unwrap_or(0) as u16;
            break Outcome::Fault { code, power_off: !sim.command().enabled };
        }
        if sw & (1 << 12) != 0 {
            break Outcome::Done;
        }
        if sim.time_s() - start_s > GIVE_UP_S {
            break Outcome::GaveUp;
        }
    };
    let identify_s = sim.time_s() - start_s;
    if let (Some((r, ar)), Outcome::Done) = (resonance, outcome) {
        master.download(&mut sim, 0x6040, 0, &0x0006u16.to_le_bytes());
        for _ in 0..400 {
            sim.run(25);
            if statusword(&mut master, &mut sim) & 0x6F == 0x21 {
                break;
            }
        }
        // Through the drive's own dictionary access (the command 0x3205:01 is an application object, which this
        // master's plain SDO server does not serve), with the power stage off as 0x3205:01 requires.
        let mut store = ParamStore::new(SimFlash::params());
        let ctx = AccessContext { comm_state: CommState::Operational, power_stage_enabled: false, max_pdo_bytes: 8 };
        for (sub, data) in [(3u8, r.to_le_bytes().to_vec()), (4, ar.to_le_bytes().to_vec()), (1, vec![1])] {
            if let Err(abort) = sim.drive.sdo_write(0x3205, sub, &data, ctx, &mut store) {
                panic!(
                    "the drive refused the master's 0x3205:{sub:02X} = {data:?} (pair {r}/{ar} x 0.1 Hz): {abort:?}"
                );
            }
        }
        sim.run(50);
    }
    let mut read = |index: u16, sub: u8| master.upload(&mut sim, index, sub).unwrap_or(0);
    let identified = Identified {
        resistance_ohm: f64::from(read(0x3002, 1)) * 1e-6,
        lq_h: f64::from(read(0x3002, 2)) * 1e-6,
        ld_h: f64::from(read(0x3002, 3)) * 1e-6,
        kt_nm_per_a: f64::from(read(0x3001, 5)) * 1e-6,
        inertia_kg_m2: f64::from(read(0x3204, 6)) * 1e-3 * 1e-7,
        coulomb_friction_nm: f64::from(read(0x3204, 5)) * 1e-6,
        pole_pairs: read(0x3204, 4) as u8,
        index_offset: read(0x3010, 5) as i32,
        hall_offset: read(0x301A, 3) as u16,
        encoder_type: read(0x3010, 2) as u16,
        resonance_hz: f64::from(read(0x3205, 3)) * 0.1,
        anti_resonance_hz: f64::from(read(0x3205, 4)) * 0.1,
    };
    let parameters = Parameters {
        values: IDENTIFIED_OBJECTS
            .iter()
            .filter_map(|&(index, sub)| Some((index, sub, master.upload_bytes(&mut sim, index, sub)?)))
            .collect(),
    };
    IdentifyRun { outcome, identify_s, identified, sdo: master.sdo, last_step, parameters }
}
