//! Scenario `line` (issue 21 item 2): `--slaves N` drives in a line (`drive-sim ethercat --slaves N --lock-step`)
//! brought up together in DC mode: each one's identity and serial number, 0x1C32:01 = 0x1C33:01 = 2 and 0x60C2
//! in PRE-OP, SYNC0 on every drive (ethercrab measures the propagation delays, writes the offsets and delays and
//! runs its static drift compensation), OP, every drive enabled in CSP through its own controlword, then one
//! minimum-jerk move (the motion issue's CSP case) on all drives at once, 10,000 cycles in all. Figures: the
//! working counter of every cycle (3 per drive), per drive the following error 0x60F4 over the move (peak, RMS),
//! statusword bit 13, the position error at the end, the DC registers of every drive read back (0x0990 next
//! SYNC0 pulse, 0x0928 delay) and 0x1C32:0B over SDO.
//!
//! **Real time** (`--realtime-s S`, against `drive-sim ethercat --slaves N` without `--lock-step`): about
//! S x 1000 cycles after OP, paced as an ethercrab DC application paces them: SYNC0 half a cycle after the
//! frames (`sync0_shift`), and each frame sent when ethercrab's `next_cycle_wait` (from the reference clock's
//! system time the previous frame read) says, so the master follows the drives' clock. A frame is **lost** when
//! it is not answered within one cycle of being sent (never, or **late**: after the cycle) or comes back with a
//! wrong working counter; those are counted, not a failure. A cycle whose thread woke more than half a cycle
//! after its due time is the master's own miss (`master_late_wakeups`), not the simulator's; the cycles the run's
//! wall-clock time had room for but that no frame went out in are `cycles_skipped`.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use ethercrab::std::ethercat_now;
use ethercrab::subdevice_group::{DcConfiguration, HasDc, Op};
use ethercrab::{DcSync, DefaultLock, SubDeviceGroup};
use hal_sim::scenarios::motion::{JerkLimitedMove, INC_PER_REV};

use super::motion::{sync_config, Layout};
use super::{emit, err, Args, Master, Outcome};

/// Most drives on the line.
pub const LINE_MAX: usize = 16;
/// The line's process image, bytes (16 drives' default images fit with room).
pub const LINE_PDI: usize = 2048;

type LineGroup = SubDeviceGroup<LINE_MAX, LINE_PDI, DefaultLock, Op, HasDc>;

/// Controlword commands (CiA 402 §6.2.1): shutdown, switch on, enable operation.
const CW_SHUTDOWN: u16 = 0x06;
const CW_SWITCH_ON: u16 = 0x07;
const CW_ENABLE: u16 = 0x0F;

/// Writes drive `k`'s outputs.
fn put(group: &LineGroup, master: &'static Master, k: usize, layout: &Layout, values: &HashMap<u16, i64>) -> Outcome {
    let sd = group.subdevice(master, k).map_err(err("SubDevice"))?;
    let mut o = sd.outputs_raw_mut();
    for m in &layout.outputs {
        let v = values.get(&m.index).copied().unwrap_or(0);
        let bytes = v.to_le_bytes();
        if let (Some(dst), Some(src)) = (o.get_mut(m.offset..m.offset + m.bytes), bytes.get(..m.bytes)) {
            dst.copy_from_slice(src);
        }
    }
    Ok(())
}

/// Reads drive `k`'s inputs.
fn get(group: &LineGroup, master: &'static Master, k: usize, layout: &Layout) -> Result<HashMap<u16, i64>, String> {
    let sd = group.subdevice(master, k).map_err(err("SubDevice"))?;
    let i = sd.inputs_raw();
    let mut values = HashMap::new();
    for m in &layout.inputs {
        let Some(src) = i.get(m.offset..m.offset + m.bytes) else { continue };
        let mut b = [0u8; 8];
        b[..m.bytes].copy_from_slice(src);
        let mut v = i64::from_le_bytes(b);
        if m.signed && m.bytes < 8 {
            let shift = 64 - 8 * m.bytes as u32;
            v = (v << shift) >> shift;
        }
        values.insert(m.index, v);
    }
    Ok(values)
}

/// Per-drive figures of the move.
#[derive(Clone, Debug, Default)]
struct Axis {
    out: HashMap<u16, i64>,
    inp: HashMap<u16, i64>,
    start: i64,
    fe_peak: i64,
    fe_sq: f64,
    bit13: u64,
}

/// The real-time figures (see the module documentation).
#[derive(Debug)]
struct Pacer {
    cycle: Duration,
    /// When the run started.
    start: Instant,
    /// When the next frame is due (ethercrab's `next_cycle_wait` after the last one), `None`: at once.
    due: Option<Instant>,
    /// Frames not answered at all (ethercrab's PDU timeout).
    unanswered: u64,
    /// Frames answered after their cycle.
    late: u64,
    /// Frames answered within their cycle with a wrong working counter.
    wrong_wkc: u64,
    /// The longest time from sending a frame to its answer.
    answer_max: Duration,
    /// Wake-ups more than half a cycle after the due time.
    master_late_wakeups: u64,
    /// Whether this cycle's wake-up was one of them.
    woke_late: bool,
    /// Lost frames (late, unanswered or wrong working counter) in cycles whose wake-up was on time: the
    /// simulator's losses as far as the master can tell (its own receive path still counts in).
    lost_on_time: u64,
    /// The latest wake-up after a due time.
    wake_late_max: Duration,
    /// Answered frames whose AL status checks showed a drive out of OP (a drive's own reaction, e.g. a sync
    /// error 0x001A or a watchdog 0x001B), and the first such frame's index.
    not_op_frames: u64,
    first_not_op: Option<u64>,
}

impl Pacer {
    fn new(cycle: Duration) -> Self {
        Self {
            cycle,
            start: Instant::now(),
            due: None,
            unanswered: 0,
            late: 0,
            wrong_wkc: 0,
            answer_max: Duration::ZERO,
            master_late_wakeups: 0,
            woke_late: false,
            lost_on_time: 0,
            wake_late_max: Duration::ZERO,
            not_op_frames: 0,
            first_not_op: None,
        }
    }

    /// Sleeps until the next frame is due and counts how late the thread woke.
    fn wait(&mut self) {
        self.woke_late = false;
        let Some(due) = self.due else { return };
        let now = Instant::now();
        if now < due {
            std::thread::sleep(due - now);
        }
        let late = Instant::now().saturating_duration_since(due);
        self.wake_late_max = self.wake_late_max.max(late);
        if late > self.cycle / 2 {
            self.master_late_wakeups += 1;
            self.woke_late = true;
        }
    }

    /// After the frame sent at `sent`: how long its answer took, whether it came, whether its working counter was
    /// right, and ethercrab's wait from `sent` to the next cycle (SYNC0 plus the shift, in the reference clock's
    /// time).
    fn answered(&mut self, sent: Instant, took: Duration, answered: Option<Duration>, wkc_ok: bool) {
        self.answer_max = self.answer_max.max(took);
        let lost = match answered {
            None => {
                self.unanswered += 1;
                true
            }
            Some(_) if took > self.cycle => {
                self.late += 1;
                true
            }
            Some(_) if !wkc_ok => {
                self.wrong_wkc += 1;
                true
            }
            Some(_) => false,
        };
        if lost && !self.woke_late {
            self.lost_on_time += 1;
        }
        self.due = answered.map(|wait| sent + wait);
    }

    fn lost(&self) -> u64 {
        self.unanswered + self.late + self.wrong_wkc
    }

    fn emit(&self, frames: u64) {
        let wall = self.start.elapsed();
        emit("realtime_frames", frames);
        emit("realtime_wall_s", format!("{:.3}", wall.as_secs_f64()));
        // Cycles the run's wall-clock time had room for but no frame was sent in (a late wake-up, a late answer).
        let room = (wall.as_secs_f64() / self.cycle.as_secs_f64()).floor() as u64;
        emit("cycles_skipped", room.saturating_sub(frames));
        emit("lost_frames", self.lost());
        emit("lost_frames_master_on_time", self.lost_on_time);
        emit("lost_frames_master_woke_late", self.lost() - self.lost_on_time);
        emit("late_frames", self.late);
        emit("unanswered_frames", self.unanswered);
        emit("wrong_wkc_frames", self.wrong_wkc);
        emit("answer_max_us", self.answer_max.as_micros());
        emit("master_late_wakeups", self.master_late_wakeups);
        emit("master_wake_late_max_us", self.wake_late_max.as_micros());
        emit("not_op_frames", self.not_op_frames);
        emit("first_not_op_frame", self.first_not_op.map_or(-1, |k| k as i64));
    }
}

/// The scenario (see the module documentation); `--sync dc` is implied.
pub async fn line(master: &'static Master, args: &Args) -> Outcome {
    let mut group = master.init_single_group::<LINE_MAX, LINE_PDI>(ethercat_now).await.map_err(err("init"))?;
    let n = group.len();
    emit("subdevices_found", n);
    if n != args.slaves {
        return Err(format!("{n} SubDevices found, expected {}", args.slaves));
    }
    let mut layouts = Vec::with_capacity(n);
    let mut serials = Vec::with_capacity(n);
    let mut identities = std::collections::BTreeSet::new();
    for sd in group.iter(master) {
        let id = sd.identity();
        identities.insert((id.vendor_id, id.product_id, id.revision));
        let serial: u32 = sd.sdo_read(0x1018, 4).await.map_err(err("0x1018:04"))?;
        if serial != id.serial {
            return Err(format!("serial number: SII {} but 0x1018:04 {serial}", id.serial));
        }
        serials.push(serial);
        sync_config(&sd, args).await?;
        layouts.push(Layout::read(&sd).await?);
    }
    emit("identities", identities.len());
    emit("serials", serials.iter().map(u32::to_string).collect::<Vec<_>>().join(","));
    let cycle = Duration::from_micros(args.cycle_us);
    for mut sd in group.iter_mut(master) {
        sd.set_dc_sync(DcSync::Sync0);
    }
    let group = group.into_pre_op_pdi(master).await.map_err(err("PDI"))?;
    emit("pdi_bytes", layouts.iter().map(|l| l.output_bytes + l.input_bytes).sum::<usize>());
    for _ in 0..100 {
        group.tx_rx_sync_system_time(master).await.map_err(err("sync system time"))?;
    }
    let group = group
        .configure_dc_sync(
            master,
            // Real time: the master's frames half a cycle after SYNC0 (ethercrab's own example), so that the
            // outputs reach every drive well before its next pulse; lock-step: the simulator runs to SYNC0 itself.
            DcConfiguration {
                start_delay: cycle * 10,
                sync0_period: cycle,
                sync0_shift: if args.realtime_s.is_some() { cycle / 2 } else { Duration::ZERO },
            },
        )
        .await
        .map_err(err("configure DC sync"))?;
    let group = if args.realtime_s.is_some() {
        // Real time, as ethercrab's own DC sequence: OP requested at once and the process data sent every cycle
        // from then on (below), so the drives' SM event and watchdog supervision never see the master fall silent
        // while SYNC0 runs.
        group.request_into_op(master).await.map_err(err("PRE-OP -> OP (DC)"))?
    } else {
        let group = group.into_safe_op(master).await.map_err(err("PRE-OP -> SAFE-OP (DC)"))?;
        group.request_into_op(master).await.map_err(err("SAFE-OP -> OP (DC)"))?
    };

    let expected_wkc = u16::try_from(3 * n).map_err(|_| "too many drives")?;
    emit("expected_wkc", expected_wkc);
    let mut axes = vec![Axis::default(); n];
    let mut wkc_errors = 0u64;
    let mut first_bad = None;
    let mut cycles = 0u64;
    // Cycles until every drive reports OP.
    let mut op_after = None;
    for k in 0..5_000u64 {
        let sent = std::time::Instant::now();
        let r = group.tx_rx_dc(master).await.map_err(err("tx/rx"))?;
        cycles += 1;
        if r.all_op() {
            op_after = Some(k + 1);
            break;
        }
        if args.realtime_s.is_some() {
            std::thread::sleep((sent + r.extra.next_cycle_wait).saturating_duration_since(Instant::now()));
        }
    }
    let op_after = op_after.ok_or("OP not reached on every drive in 5,000 cycles")?;
    emit("cycles_to_op", op_after);

    // The move (the motion issue's CSP case), from each drive's own position, all started in the same cycle.
    let per_rpm = INC_PER_REV / 60.0;
    let mv = JerkLimitedMove::new(0.0, 10.0 * INC_PER_REV, 3_000.0 * per_rpm, 20_000.0 * per_rpm);
    let cycle_s = args.cycle_us as f64 * 1e-6;
    let move_cycles = (mv.duration_s() / cycle_s).ceil() as u64;
    emit("move_peak_rpm", format!("{:.0}", mv.peak_velocity / per_rpm));
    emit("move_cycles", move_cycles);
    // Lock-step: 10,000 cycles; real time: the seconds asked for, paced.
    let cycles_total = match args.realtime_s {
        Some(s) => (s / cycle_s).round() as u64,
        None => 10_000,
    };
    let mut pacer = args.realtime_s.map(|_| Pacer::new(cycle));
    let mut enabled_at: Option<u64> = None;
    let mut fe_n = 0u64;
    for k in 0..cycles_total {
        for (j, a) in axes.iter_mut().enumerate() {
            let sw = a.inp.get(&0x6041).copied().unwrap_or(0) as u16;
            if sw & 0x4F == 0x08 {
                return Err(format!("drive {j} faulted at cycle {k}: statusword {sw:#06x}"));
            }
            let cw = match sw & 0x6F {
                0x27 | 0x23 => CW_ENABLE,
                0x21 => CW_SWITCH_ON,
                _ => CW_SHUTDOWN,
            };
            a.out.insert(0x6040, i64::from(cw));
            a.out.insert(0x6060, 8);
        }
        let all_enabled = axes.iter().all(|a| a.inp.get(&0x6041).copied().unwrap_or(0) & 0x6F == 0x27);
        if enabled_at.is_none() && all_enabled {
            enabled_at = Some(k);
            for a in &mut axes {
                a.start = a.inp.get(&0x6064).copied().unwrap_or(0);
            }
        }
        for a in &mut axes {
            let target = match enabled_at {
                Some(e) => a.start + mv.position((k - e) as f64 * cycle_s).round() as i64,
                None => a.inp.get(&0x6064).copied().unwrap_or(0),
            };
            a.out.insert(0x607A, target);
        }
        for (j, a) in axes.iter().enumerate() {
            put(&group, master, j, &layouts[j], &a.out)?;
        }
        let working_counter = match pacer.as_mut() {
            Some(p) => {
                p.wait();
                let sent = Instant::now();
                let r = group.tx_rx_dc(master).await;
                let wkc = r.as_ref().map_or(0, |r| r.working_counter);
                if r.as_ref().is_ok_and(|r| !r.all_op()) {
                    p.not_op_frames += 1;
                    p.first_not_op.get_or_insert(k);
                }
                p.answered(sent, sent.elapsed(), r.as_ref().ok().map(|r| r.extra.next_cycle_wait), wkc == expected_wkc);
                wkc
            }
            None => group.tx_rx_dc(master).await.map_err(err("tx/rx"))?.working_counter,
        };
        cycles += 1;
        if working_counter != expected_wkc {
            wkc_errors += 1;
            first_bad.get_or_insert((k, working_counter));
        }
        let sample = enabled_at.is_some_and(|e| k > e && k - e <= move_cycles);
        if sample {
            fe_n += 1;
        }
        for (j, a) in axes.iter_mut().enumerate() {
            a.inp = get(&group, master, j, &layouts[j])?;
            if enabled_at.is_some() && a.inp.get(&0x6041).copied().unwrap_or(0) & (1 << 13) != 0 {
                a.bit13 += 1;
            }
            if sample {
                let fe = a.inp.get(&0x60F4).copied().unwrap_or(i64::MAX / 2);
                a.fe_peak = a.fe_peak.max(fe.abs());
                a.fe_sq += (fe * fe) as f64;
            }
        }
    }
    let enabled_end = axes.iter().filter(|a| a.inp.get(&0x6041).copied().unwrap_or(0) & 0x6F == 0x27).count();
    let rms: Vec<f64> = axes.iter().map(|a| (a.fe_sq / fe_n.max(1) as f64).sqrt()).collect();
    let end_errors: Vec<i64> = axes
        .iter()
        .map(|a| (a.inp.get(&0x6064).copied().unwrap_or(0) - (a.start + mv.distance.round() as i64)).abs())
        .collect();
    if let Some(p) = &pacer {
        p.emit(cycles_total);
    }
    emit("cycles", cycles);
    emit("enabled_at_cycle", enabled_at.map_or(-1, |e| e as i64));
    emit("enabled_at_end", enabled_end);
    emit("motion_wkc_errors", wkc_errors);
    emit("first_bad_wkc", format!("{first_bad:?}"));
    emit("fe_samples", fe_n);
    emit("fe_peak_inc_each", axes.iter().map(|a| a.fe_peak.to_string()).collect::<Vec<_>>().join(","));
    emit("fe_rms_inc_each", rms.iter().map(|r| format!("{r:.2}")).collect::<Vec<_>>().join(","));
    emit("fe_peak_inc_max", axes.iter().map(|a| a.fe_peak).max().unwrap_or(0));
    emit("fe_rms_inc_max", format!("{:.2}", rms.iter().cloned().fold(0.0, f64::max)));
    emit("bit13_drives", axes.iter().filter(|a| a.bit13 > 0).count());
    emit("end_error_inc_max", end_errors.iter().max().copied().unwrap_or(0));

    // The DC registers of every drive: the next SYNC0 pulse (0x0990, system time), the delay 0x0928.
    let mut starts = Vec::with_capacity(n);
    let mut delays = Vec::with_capacity(n);
    let mut missed = 0u32;
    for sd in group.iter(master) {
        starts.push(sd.register_read::<u64>(0x0990u16).await.map_err(err("0x0990"))?);
        delays.push(sd.register_read::<u32>(0x0928u16).await.map_err(err("0x0928"))?);
    }
    for sd in group.iter(master) {
        missed += u32::from(sd.sdo_read::<u16>(0x1C32, 0x0B).await.map_err(err("0x1C32:0B"))?);
    }
    let spread = starts.iter().max().copied().unwrap_or(0) - starts.iter().min().copied().unwrap_or(0);
    emit("sync0_start_spread_ns", spread);
    emit("system_delay_ns_each", delays.iter().map(u32::to_string).collect::<Vec<_>>().join(","));
    emit("sdo_sm_event_missed_total", missed);
    // Power down before leaving OP.
    for (j, a) in axes.iter_mut().enumerate() {
        a.out.insert(0x6040, i64::from(CW_SHUTDOWN));
        put(&group, master, j, &layouts[j], &a.out)?;
    }
    for _ in 0..10 {
        group.tx_rx_dc(master).await.map_err(err("tx/rx"))?;
    }
    if let (Some((k, w)), None) = (first_bad, &pacer) {
        return Err(format!("{wkc_errors} cycles with a wrong working counter, first at {k}: {w}"));
    }
    if enabled_at.is_none() {
        return Err("«Operation enabled» not reached on every drive".into());
    }
    let g = group.into_safe_op(master).await.map_err(err("OP -> SAFE-OP"))?;
    let g = g.into_pre_op(master).await.map_err(err("SAFE-OP -> PRE-OP"))?;
    g.into_init(master).await.map_err(err("PRE-OP -> INIT"))?;
    emit("init_again", 1);
    Ok(())
}
