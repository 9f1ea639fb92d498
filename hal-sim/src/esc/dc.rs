//! Distributed clocks (ESC datasheet section I "Distributed Clocks", registers 0x0900..=0x09FF; ETG.1000.4
//! §6.8 / ETG.1000.3 §4.6).
//!
//! The clock is fully driven by the caller: no wall clock is read here. [`Clock::advance`] moves ideal
//! (simulation) time forward; the ESC's local clock follows it with a configurable rate error in parts per
//! billion, and the time control loop nudges it when the master writes the reference time to 0x0910.
//!
//! Simplifications (documented, not in a standard):
//! - the time control loop corrects the local clock by at most [`MAX_STEP_NS`] per system-time write instead
//!   of the ESC's speed-counter based rate adjustment;
//! - a SYNC0 start time that is already in the past when the unit is activated is moved to the next cycle
//!   boundary (a real ESC waits for the 32/64-bit wrap and sets a status bit in 0x0984).

/// Largest correction of the local clock per system-time write, ns.
pub const MAX_STEP_NS: i64 = 1_000;

/// The local clock and the SYNC0 generator of one ESC.
#[derive(Clone, Debug, Default)]
pub struct Clock {
    /// Local time in ns (0x0910 reads `local + offset`).
    pub local: u64,
    /// Ideal time elapsed since construction (simulation time), ns; the watchdogs count in it.
    pub elapsed: u64,
    /// Rate error of the local oscillator, parts per billion (+1000 = 1 ppm fast).
    pub error_ppb: i64,
    /// Fractional nanoseconds of the rate error not yet applied, in 1e-9 ns.
    frac: i64,
    /// System time offset 0x0920.
    pub offset: u64,
    /// System time delay 0x0928.
    pub delay: u32,
    /// Last system time difference (signed: local copy minus received), ns.
    pub last_diff: i64,
    /// SYNC0 generator state.
    pub sync0: Option<Sync0Gen>,
    /// SYNC0 pulses since the last [`Clock::take_sync0`].
    pub pending: Option<Sync0Pulse>,
}

/// An armed SYNC0 generator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sync0Gen {
    /// System time of the next pulse.
    pub next: u64,
    /// Cycle time in ns (0 = single shot).
    pub cycle: u32,
}

/// SYNC0 pulses that occurred since the simulation last asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sync0Pulse {
    /// System time of the latest pulse.
    pub system_time: u64,
    /// Number of pulses since the last take (more than 1 = the simulation missed pulses).
    pub count: u32,
}

impl Clock {
    /// System time: local time plus offset (0x0910 read semantics).
    pub fn system_time(&self) -> u64 {
        self.local.wrapping_add(self.offset)
    }

    /// Moves ideal time forward by `ns`; the local clock advances by `ns` scaled by the rate error. Emits the
    /// SYNC0 pulses that fall due and returns how many.
    pub fn advance(&mut self, ns: u64) -> u32 {
        self.elapsed = self.elapsed.wrapping_add(ns);
        let scaled = i128::from(ns) * i128::from(self.error_ppb) + i128::from(self.frac);
        let whole = scaled / 1_000_000_000;
        self.frac = (scaled % 1_000_000_000) as i64;
        let delta = i128::from(ns) + whole;
        let delta = u64::try_from(delta.max(0)).unwrap_or(u64::MAX);
        self.local = self.local.wrapping_add(delta);
        self.run_sync0()
    }

    /// The time control loop input: the master wrote `received` (the reference clock's system time) to
    /// 0x0910. `bits32` = only the low 32 bits were written. `arrival_ns`: how far the instant the write
    /// reached this ESC lies from the clock's current time (ideal ns; 0 for a single ESC, see
    /// [`super::Esc::process_frame_at`]). Returns the 0x092C register value.
    pub fn system_time_write(&mut self, received: u64, bits32: bool, arrival_ns: i64) -> u32 {
        let expected = received.wrapping_add(u64::from(self.delay));
        let local = self.system_time().wrapping_add_signed(arrival_ns);
        let diff = if bits32 {
            i64::from((local as u32).wrapping_sub(expected as u32) as i32)
        } else {
            local.wrapping_sub(expected) as i64
        };
        self.last_diff = diff;
        let step = diff.clamp(-MAX_STEP_NS, MAX_STEP_NS);
        self.local = self.local.wrapping_add_signed(-step);
        diff_register(diff)
    }

    /// Arms (or disarms) SYNC0 from the activation register 0x0981, the start time 0x0990 and the cycle
    /// 0x09A0. Returns the pulses already due (a start time equal to the current time).
    pub fn activate(&mut self, activation: u8, start: u64, cycle: u32) -> u32 {
        if activation & 0x03 != 0x03 {
            self.sync0 = None;
            return 0;
        }
        let now = self.system_time();
        let mut next = start;
        if next < now && cycle > 0 {
            let k = (now - next).div_ceil(u64::from(cycle));
            next = next.saturating_add(k * u64::from(cycle));
        }
        self.sync0 = Some(Sync0Gen { next, cycle });
        self.run_sync0()
    }

    fn run_sync0(&mut self) -> u32 {
        let now = self.system_time();
        let Some(g) = self.sync0 else { return 0 };
        if now < g.next {
            return 0;
        }
        let (count, last, following) = if g.cycle == 0 {
            (1u64, g.next, None)
        } else {
            let c = u64::from(g.cycle);
            let k = (now - g.next) / c;
            (k + 1, g.next + k * c, Some(g.next + (k + 1) * c))
        };
        let count = u32::try_from(count).unwrap_or(u32::MAX);
        let prev = self.pending.map_or(0, |p| p.count);
        self.pending = Some(Sync0Pulse { system_time: last, count: prev.saturating_add(count) });
        self.sync0 = following.map(|next| Sync0Gen { next, cycle: g.cycle });
        count
    }

    /// The SYNC0 pulses since the last call.
    pub fn take_sync0(&mut self) -> Option<Sync0Pulse> {
        self.pending.take()
    }

    /// System time of the next SYNC0 pulse, if armed.
    pub fn next_sync0(&self) -> Option<u64> {
        self.sync0.map(|g| g.next)
    }
}

/// Encodes a signed difference as register 0x092C: bit 31 set when the local copy is smaller than the
/// received time, bits 30..0 the magnitude (saturated).
pub fn diff_register(diff: i64) -> u32 {
    let mag = u32::try_from(diff.unsigned_abs().min(0x7FFF_FFFF)).unwrap_or(0x7FFF_FFFF);
    if diff < 0 {
        mag | 0x8000_0000
    } else {
        mag
    }
}
