//! The scenarios with process data: the CSV remap and back, CSP in free run, SM-synchronous and DC SYNC0, and
//! the watchdog.

use std::collections::HashMap;
use std::time::Duration;

use ethercrab::error::Error;
use ethercrab::std::ethercat_now;
use ethercrab::subdevice_group::{DcConfiguration, HasDc, NoDc, Op};
use ethercrab::{DcSync, DefaultLock, SubDeviceGroup, SubDeviceRef};
use firmware::od::access::Dictionary;
use hal_sim::scenarios::motion::{JerkLimitedMove, INC_PER_REV};

use super::objects::dict_upload;
use super::{download, emit, err, Args, Master, Outcome, Sync, MAX_SUBDEVICES, PDI_LEN};

/// A group in OP, with or without DC.
type OpGroup<DC> = SubDeviceGroup<MAX_SUBDEVICES, PDI_LEN, DefaultLock, Op, DC>;

/// Controlword commands (CiA 402 §6.2.1 / cia402 digest): shutdown, switch on, enable operation.
const CW_SHUTDOWN: u16 = 0x06;
const CW_SWITCH_ON: u16 = 0x07;
const CW_ENABLE: u16 = 0x0F;

/// One process-data exchange of a group: its working counter and whether the SubDevice reports OP.
trait Exchange {
    async fn exchange(&self, master: &'static Master) -> Result<(u16, bool), Error>;
}

impl Exchange for OpGroup<NoDc> {
    async fn exchange(&self, master: &'static Master) -> Result<(u16, bool), Error> {
        self.tx_rx(master).await.map(|r| (r.working_counter, r.all_op()))
    }
}

impl Exchange for OpGroup<HasDc> {
    async fn exchange(&self, master: &'static Master) -> Result<(u16, bool), Error> {
        // The DC cycle: the LRW and the reference clock's system time (FRMW 0x0910) in one frame. In lock-step
        // the simulator runs to the next SYNC0 with each such frame, so the master does not wait `next_cycle_wait`.
        self.tx_rx_dc(master).await.map(|r| (r.working_counter, r.all_op()))
    }
}

/// One mapped object in the process image.
#[derive(Clone, Copy, Debug)]
pub(super) struct Mapped {
    pub(super) index: u16,
    pub(super) offset: usize,
    pub(super) bytes: usize,
    pub(super) signed: bool,
}

/// The process image as the drive's PDO assignment and mapping say, read over SDO (0x1C12/0x1C13, then each
/// assigned PDO's entries: ETG.1000.6 §5.6.7.4, what ethercrab reads itself to size the image).
#[derive(Clone, Debug, Default)]
pub(super) struct Layout {
    pub(super) outputs: Vec<Mapped>,
    pub(super) inputs: Vec<Mapped>,
    pub(super) output_bytes: usize,
    pub(super) input_bytes: usize,
}

impl Layout {
    pub(super) async fn read<S>(sd: &SubDeviceRef<'_, S>) -> Result<Self, String>
    where
        S: std::ops::Deref<Target = ethercrab::SubDevice>,
    {
        let d = Dictionary::new(1);
        let mut out = Layout::default();
        for (assign, outputs) in [(0x1C12u16, true), (0x1C13u16, false)] {
            let n: u8 = sd.sdo_read(assign, 0).await.map_err(err("assignment"))?;
            let mut offset = 0usize;
            let mut list = Vec::new();
            for k in 1..=n {
                let pdo: u16 = sd.sdo_read(assign, k).await.map_err(err("assigned PDO"))?;
                let m: u8 = sd.sdo_read(pdo, 0).await.map_err(err("mapping count"))?;
                for j in 1..=m {
                    let v: u32 = sd.sdo_read(pdo, j).await.map_err(err("mapping entry"))?;
                    let (index, bits) = ((v >> 16) as u16, (v & 0xFF) as usize);
                    let signed = d.find(index, (v >> 8) as u8).map(|e| e.data_type.is_signed()).unwrap_or(false);
                    list.push(Mapped { index, offset, bytes: bits / 8, signed });
                    offset += bits / 8;
                }
            }
            if outputs {
                out.outputs = list;
                out.output_bytes = offset;
            } else {
                out.inputs = list;
                out.input_bytes = offset;
            }
        }
        Ok(out)
    }

    fn describe(list: &[Mapped]) -> String {
        list.iter().map(|m| format!("{:04x}/{}", m.index, m.bytes)).collect::<Vec<_>>().join(",")
    }
}

/// The cyclic exchange of one group: writes outputs at their mapped offsets, exchanges, decodes the inputs,
/// counts working-counter errors.
struct Cyclic<'g, G> {
    group: &'g G,
    master: &'static Master,
    layout: Layout,
    /// One LRW over one write and one read FMMU: +2 +1 (ETG.1000.4 §5.4.3).
    expected_wkc: u16,
    cycles: u64,
    wkc_errors: u64,
    first_bad: Option<(u64, u16)>,
    left_op: u64,
    /// Whether the last exchange found the SubDevice in OP.
    last_op: bool,
    outputs: HashMap<u16, i64>,
}

impl<'g, DC> Cyclic<'g, OpGroup<DC>>
where
    OpGroup<DC>: Exchange,
{
    fn new(group: &'g OpGroup<DC>, master: &'static Master, layout: Layout) -> Self {
        Self {
            group,
            master,
            layout,
            expected_wkc: 3,
            cycles: 0,
            wkc_errors: 0,
            first_bad: None,
            left_op: 0,
            last_op: false,
            outputs: HashMap::new(),
        }
    }

    /// Sets an output object (kept for the following cycles).
    fn set(&mut self, index: u16, value: i64) {
        self.outputs.insert(index, value);
    }

    /// One cycle: the outputs into the image, one exchange, the inputs out of it. `in_op` says whether the
    /// SubDevice must already be in OP (a cycle that finds it elsewhere is counted).
    async fn cycle(&mut self, in_op: bool) -> Result<HashMap<u16, i64>, String> {
        let sd = self.group.subdevice(self.master, 0).map_err(err("SubDevice 0"))?;
        {
            let mut o = sd.outputs_raw_mut();
            for m in &self.layout.outputs {
                let v = self.outputs.get(&m.index).copied().unwrap_or(0);
                let bytes = v.to_le_bytes();
                if let (Some(dst), Some(src)) = (o.get_mut(m.offset..m.offset + m.bytes), bytes.get(..m.bytes)) {
                    dst.copy_from_slice(src);
                }
            }
        }
        let (wkc, all_op) = self.group.exchange(self.master).await.map_err(err("tx/rx"))?;
        if wkc != self.expected_wkc {
            self.wkc_errors += 1;
            self.first_bad.get_or_insert((self.cycles, wkc));
        }
        if in_op && !all_op {
            self.left_op += 1;
        }
        self.last_op = all_op;
        self.cycles += 1;
        let i = sd.inputs_raw();
        let mut values = HashMap::new();
        for m in &self.layout.inputs {
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

    /// Cycles until the SubDevice reports OP (after ethercrab's `request_into_op`), at most `limit` cycles.
    async fn until_op(&mut self, limit: u64) -> Result<u64, String> {
        for k in 0..limit {
            self.cycle(false).await?;
            if self.last_op {
                return Ok(k + 1);
            }
        }
        let sd = self.group.subdevice(self.master, 0).map_err(err("SubDevice 0"))?;
        let status = sd.status().await.map_err(err("AL status"))?;
        Err(format!("OP not reached in {limit} cycles: {status:?}"))
    }

    /// CiA 402 power-up through the controlword in the outputs: shutdown (0x06), switch on (0x07), enable
    /// operation (0x0F), each sent until the statusword shows the state it leads to. `hold` sets the set-points
    /// each cycle from the inputs (CSP: the target follows the actual position, so enabling moves nothing).
    async fn enable(
        &mut self,
        mode: i64,
        limit: u64,
        hold: impl Fn(&HashMap<u16, i64>, &mut Self),
    ) -> Result<(u64, HashMap<u16, i64>), String> {
        self.set(0x6060, mode);
        self.set(0x6040, i64::from(CW_SHUTDOWN));
        let mut inputs = self.cycle(true).await?;
        for k in 0..limit {
            let sw = inputs.get(&0x6041).copied().unwrap_or(0) as u16;
            // Statusword patterns (CiA 402 Table 30): fault xxxx 1000 (mask 0x4F), switch on disabled 0x40 (0x4F),
            // ready 0x21, switched on 0x23, operation enabled 0x27 (mask 0x6F).
            if sw & 0x4F == 0x08 {
                return Err(format!("fault while enabling: statusword {sw:#06x}, 0x603F {:?}", inputs.get(&0x603F)));
            }
            let cw = match sw & 0x6F {
                0x27 => {
                    if inputs.get(&0x6061).copied() != Some(mode) {
                        return Err(format!("mode display {:?}, expected {mode}", inputs.get(&0x6061)));
                    }
                    return Ok((k, inputs));
                }
                0x23 => CW_ENABLE,
                0x21 => CW_SWITCH_ON,
                _ => CW_SHUTDOWN,
            };
            self.set(0x6040, i64::from(cw));
            hold(&inputs, self);
            inputs = self.cycle(true).await?;
        }
        Err(format!(
            "operation enabled not reached in {limit} cycles: statusword {:#06x}",
            inputs.get(&0x6041).copied().unwrap_or(0)
        ))
    }

    fn report(&self, prefix: &str) {
        emit(&format!("{prefix}cycles"), self.cycles);
        emit(&format!("{prefix}wkc_errors"), self.wkc_errors);
        emit(&format!("{prefix}expected_wkc"), self.expected_wkc);
        emit(&format!("{prefix}cycles_not_op"), self.left_op);
    }

    fn check(&self) -> Outcome {
        if let Some((k, wkc)) = self.first_bad {
            return Err(format!("{} cycles with a wrong working counter, first at {k}: {wkc}", self.wkc_errors));
        }
        if self.left_op > 0 {
            return Err(format!("{} cycles outside OP", self.left_op));
        }
        Ok(())
    }
}

/// An input the mapping must carry.
fn input(values: &HashMap<u16, i64>, index: u16) -> Result<i64, String> {
    values.get(&index).copied().ok_or_else(|| format!("{index:#06x} is not in the inputs"))
}

/// SDO writes of the remap procedure (CiA 301 §7.5.2.36 / ETG.1000.6 §5.6.7.4): the assignment off (sub 0 = 0),
/// each mapping off, its entries, its count, then the assignment and its count.
async fn remap<S>(sd: &SubDeviceRef<'_, S>, rx: &[(u16, Vec<u32>)], tx: &[(u16, Vec<u32>)]) -> Outcome
where
    S: std::ops::Deref<Target = ethercrab::SubDevice>,
{
    let w = |what: &'static str| err(what);
    download(sd, 0x1C12, 0, 0u8).await.map_err(w("0x1C12:00 = 0"))?;
    download(sd, 0x1C13, 0, 0u8).await.map_err(w("0x1C13:00 = 0"))?;
    for (pdo, entries) in rx.iter().chain(tx) {
        download(sd, *pdo, 0, 0u8).await.map_err(|e| format!("{pdo:#06x}:00 = 0: {e}"))?;
        for (k, v) in entries.iter().enumerate() {
            let sub = u8::try_from(k + 1).map_err(|_| "too many entries")?;
            download(sd, *pdo, sub, *v).await.map_err(|e| format!("{pdo:#06x}:{sub} = {v:#010x}: {e}"))?;
        }
        let n = u8::try_from(entries.len()).map_err(|_| "too many entries")?;
        download(sd, *pdo, 0, n).await.map_err(|e| format!("{pdo:#06x}:00 = {n}: {e}"))?;
    }
    for (assign, list) in [(0x1C12u16, rx), (0x1C13u16, tx)] {
        let assigned: Vec<u16> = list.iter().filter(|(_, e)| !e.is_empty()).map(|(p, _)| *p).collect();
        for (k, pdo) in assigned.iter().enumerate() {
            let sub = u8::try_from(k + 1).map_err(|_| "too many PDOs")?;
            download(sd, assign, sub, *pdo).await.map_err(|e| format!("{assign:#06x}:{sub} = {pdo:#06x}: {e}"))?;
        }
        let n = u8::try_from(assigned.len()).map_err(|_| "too many PDOs")?;
        download(sd, assign, 0, n).await.map_err(|e| format!("{assign:#06x}:00 = {n}: {e}"))?;
    }
    Ok(())
}

/// The default mapping and assignment from the dictionary (firmware/device.toml): (PDO, entries) for
/// 0x1600..0x1603 and 0x1A00..0x1A03 in the order 0x1C12/0x1C13 assign them, unassigned ones last.
fn default_mapping(d: &Dictionary, assign: u16, first: u16) -> Result<Vec<(u16, Vec<u32>)>, String> {
    let num = |i: u16, s: u8| -> Result<u32, String> {
        let b = dict_upload(d, i, s).map_err(|c| format!("dictionary {i:#06x}:{s}: {c:#x}"))?;
        Ok(b.iter().rev().fold(0u32, |a, x| a << 8 | u32::from(*x)))
    };
    let n = num(assign, 0)?;
    let mut order: Vec<u16> = (1..=n).map(|k| num(assign, k as u8).map(|v| v as u16)).collect::<Result<_, _>>()?;
    for pdo in first..first + 4 {
        if !order.contains(&pdo) {
            order.push(pdo);
        }
    }
    order
        .into_iter()
        .map(|pdo| {
            let m = num(pdo, 0)?;
            let entries = (1..=m).map(|k| num(pdo, k as u8)).collect::<Result<Vec<_>, _>>()?;
            Ok((pdo, entries))
        })
        .collect()
}

/// The restore writes: every mapping object back to its default entries; only the defaults' assigned PDOs are
/// assigned again (an unassigned PDO keeps its default entries but gets no assignment entry).
async fn restore_defaults<S>(sd: &SubDeviceRef<'_, S>) -> Outcome
where
    S: std::ops::Deref<Target = ethercrab::SubDevice>,
{
    let d = Dictionary::new(1);
    let rx = default_mapping(&d, 0x1C12, 0x1600)?;
    let tx = default_mapping(&d, 0x1C13, 0x1A00)?;
    remap(sd, &rx, &tx).await?;
    // `remap` assigned every non-empty PDO; the defaults assign only the first 0x1C12:00 / 0x1C13:00 of them.
    for (assign, list) in [(0x1C12u16, &rx), (0x1C13u16, &tx)] {
        let n = dict_upload(&d, assign, 0).map_err(|c| format!("dictionary {assign:#06x}: {c:#x}"))?;
        let n = n.first().copied().unwrap_or(0);
        download(sd, assign, 0, 0u8).await.map_err(err("assignment off"))?;
        for (k, (pdo, _)) in list.iter().take(usize::from(n)).enumerate() {
            download(sd, assign, (k + 1) as u8, *pdo).await.map_err(err("assignment entry"))?;
        }
        download(sd, assign, 0, n).await.map_err(err("assignment count"))?;
    }
    Ok(())
}

/// Takes the group from OP through SAFE-OP and PRE-OP to INIT (ethercrab's typed transitions).
async fn down_to_init<DC>(group: OpGroup<DC>, master: &'static Master) -> Outcome {
    let g = group.into_safe_op(master).await.map_err(err("OP -> SAFE-OP"))?;
    let g = g.into_pre_op(master).await.map_err(err("SAFE-OP -> PRE-OP"))?;
    g.into_init(master).await.map_err(err("PRE-OP -> INIT"))?;
    emit("init_again", 1);
    Ok(())
}

/// Scenario `remap` (issue 6: "remap the PDOs to a CSV set and back"): in PRE-OP the mapping becomes outputs
/// 0x6040, 0x6060, 0x60FF (0x1600) and inputs 0x6041, 0x6061, 0x606C, 0x6064 (0x1A00), each the only PDO of its
/// SyncManager; ethercrab sizes its image from it (7 and 11 bytes); OP; CSV (mode 9) is enabled through the
/// controlword and runs at a velocity whose actual value must settle within a tolerance; then INIT, a new
/// init (the mapping survives INIT), the defaults written back, SAFE-OP with the default image size.
pub async fn remap_csv(master: &'static Master, args: &Args) -> Outcome {
    let group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("init"))?;
    {
        let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
        let rx = vec![(0x1600u16, vec![0x6040_0010u32, 0x6060_0008, 0x60FF_0020])];
        let tx = vec![(0x1A00u16, vec![0x6041_0010u32, 0x6061_0008, 0x606C_0020, 0x6064_0020])];
        remap(&sd, &rx, &tx).await?;
    }
    let group = group.into_safe_op(master).await.map_err(err("PRE-OP -> SAFE-OP"))?;
    let layout = {
        let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
        let io = sd.io_raw();
        emit("csv_pdi_output_bytes", io.outputs().len());
        emit("csv_pdi_input_bytes", io.inputs().len());
        drop(io);
        Layout::read(&sd).await?
    };
    emit("csv_outputs", Layout::describe(&layout.outputs));
    emit("csv_inputs", Layout::describe(&layout.inputs));
    emit("csv_output_bytes", layout.output_bytes);
    emit("csv_input_bytes", layout.input_bytes);
    let group = group.request_into_op(master).await.map_err(err("SAFE-OP -> OP"))?;
    let mut pd = Cyclic::new(&group, master, layout);
    let to_op = pd.until_op(2_000).await?;
    emit("csv_cycles_to_op", to_op);
    let (enable_cycles, _) = pd.enable(9, 20_000, |_, pd| pd.set(0x60FF, 0)).await?;
    emit("csv_enable_cycles", enable_cycles);
    // Velocity step: 600 rpm. Tolerance: the mean of the last 200 cycles within 1 % of the target, and every
    // one of them within the velocity window 0x606D (30 rpm default: what the drive itself calls "reached").
    const TARGET_RPM: i64 = 600;
    let cycles_per_s = 1_000_000 / args.cycle_us;
    pd.set(0x60FF, TARGET_RPM);
    let run = cycles_per_s; // 1 s
    let tail = 200.min(run);
    let (mut sum, mut worst, mut n) = (0i64, 0i64, 0i64);
    let mut first_within = None;
    for k in 0..run {
        let inp = pd.cycle(true).await?;
        let v = input(&inp, 0x606C)?;
        if first_within.is_none() && (v - TARGET_RPM).abs() <= 30 {
            first_within = Some(k);
        }
        if k >= run - tail {
            sum += v;
            n += 1;
            worst = worst.max((v - TARGET_RPM).abs());
        }
    }
    let mean = sum as f64 / n.max(1) as f64;
    emit("csv_target_rpm", TARGET_RPM);
    emit("csv_mean_rpm", format!("{mean:.1}"));
    emit("csv_worst_deviation_rpm", worst);
    emit("csv_cycles_to_window", first_within.map_or(-1, |k| k as i64));
    pd.set(0x60FF, 0);
    pd.set(0x6040, i64::from(CW_SHUTDOWN));
    for _ in 0..cycles_per_s / 2 {
        pd.cycle(true).await?;
    }
    pd.report("csv_");
    pd.check()?;
    if (mean - TARGET_RPM as f64).abs() > 0.01 * TARGET_RPM as f64 || worst > 30 {
        return Err(format!("CSV: mean {mean:.1} rpm, worst deviation {worst} rpm (target {TARGET_RPM})"));
    }
    down_to_init(group, master).await?;

    // Second init: the mapping is the drive's (it survives INIT); the defaults are written back.
    let group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("re-init"))?;
    {
        let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
        let kept = Layout::read(&sd).await?;
        emit("after_init_outputs", Layout::describe(&kept.outputs));
        restore_defaults(&sd).await?;
    }
    let group = group.into_safe_op(master).await.map_err(err("PRE-OP -> SAFE-OP (defaults)"))?;
    let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
    let layout = Layout::read(&sd).await?;
    let io = sd.io_raw();
    emit("default_pdi_output_bytes", io.outputs().len());
    emit("default_pdi_input_bytes", io.inputs().len());
    emit("default_outputs", Layout::describe(&layout.outputs));
    emit("default_inputs", Layout::describe(&layout.inputs));
    emit("default_output_bytes", layout.output_bytes);
    emit("default_input_bytes", layout.input_bytes);
    drop(io);
    let g = group.into_pre_op(master).await.map_err(err("SAFE-OP -> PRE-OP"))?;
    g.into_init(master).await.map_err(err("PRE-OP -> INIT"))?;
    emit("init_final", 1);
    Ok(())
}

/// 0x60C2 (interpolation time period: value, power-of-ten index) for a cycle in us: whole ms as 10^-3, else
/// 100 us units as 10^-4 (200 us = 2 x 10^-4 s).
fn interpolation_period(cycle_us: u64) -> (u8, i8) {
    if cycle_us.is_multiple_of(1_000) {
        (u8::try_from(cycle_us / 1_000).unwrap_or(u8::MAX), -3)
    } else {
        (u8::try_from(cycle_us / 100).unwrap_or(u8::MAX), -4)
    }
}

/// Configures the synchronisation in PRE-OP (0x1C32:01 / 0x1C33:01, in free run also 0x1C32:02 = the cycle) and
/// 0x60C2, returns the group in OP (requested; the cycles until OP follow).
pub(super) async fn sync_config<S>(sd: &SubDeviceRef<'_, S>, args: &Args) -> Outcome
where
    S: std::ops::Deref<Target = ethercrab::SubDevice>,
{
    let (out_sync, in_sync) = args.sync.sync_types();
    download(sd, 0x1C32, 1, out_sync).await.map_err(err("0x1C32:01"))?;
    download(sd, 0x1C33, 1, in_sync).await.map_err(err("0x1C33:01"))?;
    if args.sync == Sync::FreeRun {
        let ns = u32::try_from(args.cycle_us * 1_000).map_err(|_| "cycle too long")?;
        download(sd, 0x1C32, 2, ns).await.map_err(err("0x1C32:02"))?;
    }
    let (value, index) = interpolation_period(args.cycle_us);
    download(sd, 0x60C2, 1, value).await.map_err(err("0x60C2:01"))?;
    download(sd, 0x60C2, 2, index).await.map_err(err("0x60C2:02"))?;
    let st: u16 = sd.sdo_read(0x1C32, 1).await.map_err(err("0x1C32:01"))?;
    emit("sync_type", st);
    emit("interpolation_period", format!("{value}e{index}"));
    Ok(())
}

/// The CSP move's figures.
#[derive(Debug, Default)]
struct CspFigures {
    fe_peak: i64,
    fe_sq: f64,
    fe_n: u64,
    bit13: u64,
    final_error: i64,
}

/// Scenario `csp` (issue 6: "run CSP on the reference plant for 10,000 cycles ... with every working counter
/// right, SM-event-missed at 0, and the motion issue's following-error bounds met"): sync mode and 0x60C2 in
/// PRE-OP, OP, enable in mode 8 through the outputs, then 10,000 cycles: the motion issue's CSP move (10
/// revolutions of 4,096 increments, jerk-limited sin² ramps, 3,000 rpm allowed, 20,000 rpm/s peak: 2,449 rpm
/// peak reached) and the hold on the target. Figures: 0x60F4 from the inputs over the move (peak, RMS),
/// statusword bit 13 (following error) over all cycles, the position error at the end, the working counters,
/// 0x1C32:0B over SDO at the end.
pub async fn csp(master: &'static Master, args: &Args) -> Outcome {
    let mut group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("init"))?;
    let layout = {
        let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
        sync_config(&sd, args).await?;
        Layout::read(&sd).await?
    };
    emit("outputs", Layout::describe(&layout.outputs));
    emit("inputs", Layout::describe(&layout.inputs));
    let cycle = Duration::from_micros(args.cycle_us);
    if args.sync == Sync::Dc {
        for mut sd in group.iter_mut(master) {
            sd.set_dc_sync(DcSync::Sync0);
        }
        let group = group.into_pre_op_pdi(master).await.map_err(err("PDI"))?;
        // ethercrab's alignment cycles (LRW + FRMW of the reference clock's system time), then SYNC0.
        for _ in 0..100 {
            group.tx_rx_sync_system_time(master).await.map_err(err("sync system time"))?;
        }
        let group = group
            .configure_dc_sync(
                master,
                DcConfiguration { start_delay: cycle * 10, sync0_period: cycle, sync0_shift: Duration::ZERO },
            )
            .await
            .map_err(err("configure DC sync"))?;
        let group = group.into_safe_op(master).await.map_err(err("PRE-OP -> SAFE-OP (DC)"))?;
        let group = group.request_into_op(master).await.map_err(err("SAFE-OP -> OP (DC)"))?;
        csp_run(&group, master, layout, args).await?;
        down_to_init(group, master).await
    } else {
        let group = group.into_safe_op(master).await.map_err(err("PRE-OP -> SAFE-OP"))?;
        let group = group.request_into_op(master).await.map_err(err("SAFE-OP -> OP"))?;
        csp_run(&group, master, layout, args).await?;
        down_to_init(group, master).await
    }
}

/// The CSP run in OP (see [`csp`]).
async fn csp_run<DC>(group: &OpGroup<DC>, master: &'static Master, layout: Layout, args: &Args) -> Outcome
where
    OpGroup<DC>: Exchange,
{
    let mut pd = Cyclic::new(group, master, layout);
    emit("cycles_to_op", pd.until_op(5_000).await?);
    let follow = |inp: &HashMap<u16, i64>, pd: &mut Cyclic<'_, OpGroup<DC>>| {
        if let Some(p) = inp.get(&0x6064) {
            pd.set(0x607A, *p);
        }
    };
    let enable_limit = 5 * 1_000_000 / args.cycle_us; // 5 s of drive time
    let (enable_cycles, inputs) = pd.enable(8, enable_limit, follow).await?;
    emit("enable_cycles", enable_cycles);
    let start = input(&inputs, 0x6064)?;
    // The motion issue's CSP case (hal_sim::scenarios::motion::CspConfig::default): 10 rev, 3,000 rpm, 20,000 rpm/s.
    let per_rpm = INC_PER_REV / 60.0;
    let mv = JerkLimitedMove::new(start as f64, 10.0 * INC_PER_REV, 3_000.0 * per_rpm, 20_000.0 * per_rpm);
    let target = (start as f64 + mv.distance).round() as i64;
    let cycle_s = args.cycle_us as f64 * 1e-6;
    let move_cycles = (mv.duration_s() / cycle_s).ceil() as u64;
    emit("move_peak_rpm", format!("{:.0}", mv.peak_velocity / per_rpm));
    emit("move_cycles", move_cycles);
    const CYCLES: u64 = 10_000;
    let mut f = CspFigures::default();
    let mut last = inputs;
    let wkc_before = pd.wkc_errors;
    let cycles_before = pd.cycles;
    for k in 0..CYCLES {
        let demand = (mv.position(k as f64 * cycle_s)).round() as i64;
        pd.set(0x607A, demand);
        last = pd.cycle(true).await?;
        let sw = input(&last, 0x6041)?;
        if sw & (1 << 13) != 0 {
            f.bit13 += 1;
        }
        if sw & 0x4F == 0x08 {
            return Err(format!("fault at cycle {k}: statusword {sw:#06x}, 0x603F {:?}", last.get(&0x603F)));
        }
        // Over the move: from its first set-point to its last one, as the motion issue measures.
        if k <= move_cycles {
            let fe = input(&last, 0x60F4)?;
            f.fe_peak = f.fe_peak.max(fe.abs());
            f.fe_sq += (fe * fe) as f64;
            f.fe_n += 1;
        }
    }
    f.final_error = input(&last, 0x6064)? - target;
    let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
    let missed: u16 = sd.sdo_read(0x1C32, 0x0B).await.map_err(err("0x1C32:0B"))?;
    let too_small: u16 = sd.sdo_read(0x1C32, 0x0C).await.map_err(err("0x1C32:0C"))?;
    let sync_type: u16 = sd.sdo_read(0x1C32, 0x01).await.map_err(err("0x1C32:01"))?;
    let rms = (f.fe_sq / f.fe_n.max(1) as f64).sqrt();
    emit("motion_cycles", pd.cycles - cycles_before);
    emit("motion_wkc_errors", pd.wkc_errors - wkc_before);
    emit("fe_peak_inc", f.fe_peak);
    emit("fe_rms_inc", format!("{rms:.2}"));
    emit("bit13_cycles", f.bit13);
    emit("final_error_inc", f.final_error);
    emit("target_inc", target);
    emit("sdo_sm_event_missed", missed);
    emit("sdo_cycle_time_too_small", too_small);
    emit("sdo_sync_type", sync_type);
    // Power down before leaving OP.
    pd.set(0x6040, i64::from(CW_SHUTDOWN));
    for _ in 0..10 {
        pd.cycle(true).await?;
    }
    pd.report("");
    pd.check()?;
    let mut bad = Vec::new();
    if f.fe_peak > 30 {
        bad.push(format!("following error peak {} inc > 30", f.fe_peak));
    }
    if rms > 8.0 {
        bad.push(format!("following error RMS {rms:.2} inc > 8"));
    }
    if f.bit13 > 0 {
        bad.push(format!("statusword bit 13 in {} cycles", f.bit13));
    }
    if f.final_error.abs() > 1 {
        bad.push(format!("{} inc from the target after the move", f.final_error));
    }
    if missed != 0 {
        bad.push(format!("0x1C32:0B = {missed}"));
    }
    if bad.is_empty() {
        Ok(())
    } else {
        Err(bad.join("; "))
    }
}

/// Scenario `watchdog` (issue 6: "when the master stops sending process data, the drive reaches the fault ...
/// with the reaction 0x6007 selects, within the configured watchdog time plus one cycle"), run against
/// `drive-sim ethercat --lock-step --idle-cycle` (an idle poll runs one cycle, so a quiet master lets simulated
/// time and the process-data watchdog run): SM-synchronous OP, enabled in CSP holding position for 500 cycles,
/// then no process data; every 100 ms (wall) the AL status registers are read (not a cyclic frame) until the
/// error flag shows, for at most 10 s; then 0x603F and 0x6041 over SDO. The timing is drive-sim's (simulated time).
pub async fn watchdog(master: &'static Master, args: &Args) -> Outcome {
    let group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("init"))?;
    let layout = {
        let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
        sync_config(&sd, args).await?;
        let option: i16 = sd.sdo_read(0x6007, 0).await.map_err(err("0x6007"))?;
        emit("abort_connection_option", option);
        Layout::read(&sd).await?
    };
    let group = group.into_safe_op(master).await.map_err(err("PRE-OP -> SAFE-OP"))?;
    let group = group.request_into_op(master).await.map_err(err("SAFE-OP -> OP"))?;
    let mut pd = Cyclic::new(&group, master, layout);
    emit("cycles_to_op", pd.until_op(5_000).await?);
    let follow = |inp: &HashMap<u16, i64>, pd: &mut Cyclic<'_, OpGroup<NoDc>>| {
        if let Some(p) = inp.get(&0x6064) {
            pd.set(0x607A, *p);
        }
    };
    let (enable_cycles, _) = pd.enable(8, 5_000, follow).await?;
    emit("enable_cycles", enable_cycles);
    for _ in 0..500 {
        pd.cycle(true).await?;
    }
    pd.report("");
    pd.check()?;
    // Quiet: register reads only.
    let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
    let quiet = std::time::Instant::now();
    let mut al = 0u16;
    while quiet.elapsed() < Duration::from_secs(10) {
        async_io::Timer::after(Duration::from_millis(100)).await;
        al = sd.register_read::<u16>(0x0130u16).await.map_err(err("AL status"))?;
        if al & 0x10 != 0 {
            break;
        }
    }
    let code = sd.register_read::<u16>(0x0134u16).await.map_err(err("AL status code"))?;
    emit("quiet_wall_s", format!("{:.3}", quiet.elapsed().as_secs_f64()));
    emit("al_status_after_quiet", format!("0x{al:04x}"));
    emit("al_status_code", format!("0x{code:04x}"));
    if al & 0x10 == 0 {
        return Err(format!("no AL error within 10 s of silence (AL status 0x{al:04x})"));
    }
    let error_code: u16 = sd.sdo_read(0x603F, 0).await.map_err(err("0x603F"))?;
    let statusword: u16 = sd.sdo_read(0x6041, 0).await.map_err(err("0x6041"))?;
    emit("sdo_error_code", format!("0x{error_code:04x}"));
    emit("sdo_statusword", format!("0x{statusword:04x}"));
    Ok(())
}
