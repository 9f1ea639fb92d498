"""CSP over CAN with PyPI canopen against `drive-sim canopen --lock-step --sync-us N` (issue 8, "What it must
show"): PDO configuration through canopen's PDO API, then the drives enabled through the controlword in their
RPDO and moved along a set-point table, SYNC by SYNC; optionally the master's heartbeat stops afterwards.

Per node (canopen's PDO API: `read`, `clear`, `add_variable`, `trans_type`, `enabled`, `save`): RPDO 1 =
controlword 0x6040 + target position 0x607A, synchronous (type 1); TPDO 1 = statusword 0x6041 + position actual
0x6064, synchronous every SYNC; with --tpdo-fe TPDO 2 = following error actual 0x60F4, synchronous; with
--tpdo-sensors TPDO 3 = the positions of sensor 1 and 2 0x60E4:01/02, synchronous; with --ssi the drive is first
set to its SSI absolute encoder alone (0x3000:01 = 0x00000300, a plant with an SSI sensor) and TPDO 4 = the SSI
position raw value 0x3012:09, synchronous; every other
PDO disabled. Then 0x6060 = 8 (CSP), 0x60C2 the interpolation period, 0x1006 the SYNC period, NMT start.

Each cycle the master sends every node's RPDO (set-point for the coming SYNC, CiA 301 §7.2.2.2.2), its own
heartbeat every --hb-every cycles when asked, then the SYNC, and waits for every node's TPDOs of that SYNC
(decoded by canopen's PdoMap). A TPDO that has not arrived within --tpdo-wait-s of wall time is late (under
lock-step it can only be late because the bus had no room in the SYNC period: the server answers after the
whole period ran); more than --max-late late cycles end the run early (an overloaded period).

--setpoints: one line per cycle of the move, one column per node: the set-point offset from where the node
stood when it became «Operation enabled» (written by tests/tests/canopen_real_master.rs from hal-sim's
JerkLimitedMove). The table's last line is held afterwards for --settle cycles.

Figures per node id: enabled_at_<id>, fe_peak_<id> / fe_rms_<id> / fe_samples_<id> (from TPDO 2 over the move),
bit13_<id>, final_error_<id> (position actual minus the final set-point after settling), tpdo1_map_<id> (read
back through `tpdo.read()` after the save); overall cycles, late_cycles.

--hb-loss: 0x1016:01 = node 127 at --hb-consumer-ms, 0x1017 = --hb-producer-ms; after the move the master's
heartbeat stops while SYNC and set-points go on; figures hb_loss_reaction_syncs_after_last_hb (SYNC periods from the
last heartbeat to the TPDO statusword «Quick stop active»), emcy_<code> frames seen, error_code_603f, the drive's heartbeat states.
"""

import struct

from can_common import Fail, connect, emit, main, parser

MASTER_HB_ID = 127


def map_synchronous(pdo, variables):
    """Maps `variables` ((index,) or (index, subindex) each) into `pdo`, synchronous (transmission type 1), enabled."""
    pdo.clear()
    for variable in variables:
        pdo.add_variable(*variable)
    pdo.trans_type = 1
    pdo.enabled = True


def configure(node, tpdo_fe, period_us, tpdo_sensors=False, ssi=False):
    if ssi:
        # The SSI absolute encoder as the only sensor (IDX 0x3000:01 sensor 2 type 3), written in PRE-OPERATIONAL with
        # the power stage off as the object requires; taken at the next switch-on.
        node.sdo.download(0x3000, 1, struct.pack("<I", 0x00000300))
        emit(f"sensors_configuration_{node.id}", f"0x{struct.unpack('<I', node.sdo.upload(0x3000, 1))[0]:08x}")
    node.rpdo.read()
    node.tpdo.read()
    for pdo in (node.rpdo, node.tpdo):
        for n in range(1, 5):
            pdo[n].enabled = False
    map_synchronous(node.rpdo[1], [(0x6040,), (0x607A,)])
    map_synchronous(node.tpdo[1], [(0x6041,), (0x6064,)])
    if tpdo_fe:
        map_synchronous(node.tpdo[2], [(0x60F4,)])
    if tpdo_sensors:
        # The positions of sensor 1 (motor encoder) and sensor 2 (load encoder, the dual loop's main sensor).
        map_synchronous(node.tpdo[3], [(0x60E4, 1), (0x60E4, 2)])
    if ssi:
        map_synchronous(node.tpdo[4], [(0x3012, 9)])
    node.rpdo.save()
    node.tpdo.save()
    # Read back what the node holds now.
    node.tpdo.read()
    node.rpdo.read()
    emit(f"tpdo1_map_{node.id}", " ".join(f"{v.index:04x}:{v.subindex:02x}/{v.length}" for v in node.tpdo[1].map))
    emit(f"rpdo1_map_{node.id}", " ".join(f"{v.index:04x}:{v.subindex:02x}/{v.length}" for v in node.rpdo[1].map))
    emit(f"tpdo1_type_{node.id}", node.tpdo[1].trans_type)
    emit(f"tpdo2_enabled_{node.id}", int(bool(node.tpdo[2].enabled)))
    if tpdo_sensors:
        emit(f"tpdo3_map_{node.id}", " ".join(f"{v.index:04x}:{v.subindex:02x}/{v.length}" for v in node.tpdo[3].map))
    if ssi:
        emit(f"tpdo4_map_{node.id}", " ".join(f"{v.index:04x}:{v.subindex:02x}/{v.length}" for v in node.tpdo[4].map))
    node.sdo.download(0x6060, 0, b"\x08")
    if period_us % 1000 == 0:
        value, exponent = period_us // 1000, -3
    else:
        value, exponent = period_us // 100, -4
    node.sdo.download(0x60C2, 1, struct.pack("<B", value))
    node.sdo.download(0x60C2, 2, struct.pack("<b", exponent))
    node.sdo.download(0x1006, 0, struct.pack("<I", period_us))


class Axis:
    def __init__(self, node, column, tpdo_fe, tpdo_sensors=False, ssi=False):
        self.node = node
        self.column = column
        self.tpdo_fe = tpdo_fe
        self.tpdo_sensors = tpdo_sensors
        self.ssi = ssi
        self.count1 = self.count2 = self.count3 = self.count4 = 0
        self.ssi_raw = 0
        self.ssi_diff_max = 0
        self.ssi_raw_min = self.ssi_raw_max = None
        self.sensor1 = self.sensor2 = 0
        self.sensor1_diff_max = 0
        self.sensor2_values = set()
        self.statusword = 0
        self.actual = 0
        self.fe = 0
        self.enabled_at = None
        self.start = None
        self.fe_peak = 0
        self.fe_sq = 0.0
        self.fe_n = 0
        self.bit13 = False
        self.final_setpoint = None
        node.tpdo[1].add_callback(self.on_tpdo1)
        if tpdo_fe:
            node.tpdo[2].add_callback(self.on_tpdo2)
        if tpdo_sensors:
            node.tpdo[3].add_callback(self.on_tpdo3)
        if ssi:
            node.tpdo[4].add_callback(self.on_tpdo4)

    def on_tpdo1(self, m):
        self.statusword = m[0x6041].raw
        self.actual = m[0x6064].raw
        self.count1 += 1

    def on_tpdo2(self, m):
        self.fe = m[0x60F4].raw
        self.count2 += 1

    def on_tpdo3(self, m):
        # Both entries share the index: by position in the mapping (sub 1, then sub 2).
        self.sensor1 = m.map[0].raw
        self.sensor2 = m.map[1].raw
        self.count3 += 1

    def on_tpdo4(self, m):
        self.ssi_raw = m.map[0].raw
        self.count4 += 1

    def check_sensors(self):
        """After a SYNC whose TPDOs all arrived: without homing 0x6064 is the motor encoder's count, which 0x60E4:01
        carries; 0x60E4:02 is the load encoder's."""
        if self.tpdo_sensors:
            self.sensor1_diff_max = max(self.sensor1_diff_max, abs(self.sensor1 - self.actual))
            self.sensor2_values.add(self.sensor2)
        if self.ssi:
            # Without homing 0x6064 is the SSI sensor's absolute position (0x3012:0E = 0), 24 bits here: equal
            # modulo 2^24 to the raw value 0x3012:09, or one slow tick's travel apart.
            diff = (self.actual - self.ssi_raw) % (1 << 24)
            diff = min(diff, (1 << 24) - diff)
            self.ssi_diff_max = max(self.ssi_diff_max, diff)
            # The span from the enable on: before the first switch-on the drive has not read the sensor yet.
            if self.enabled_at is not None:
                self.ssi_raw_min = self.ssi_raw if self.ssi_raw_min is None else min(self.ssi_raw_min, self.ssi_raw)
                self.ssi_raw_max = self.ssi_raw if self.ssi_raw_max is None else max(self.ssi_raw_max, self.ssi_raw)

    def arrived(self, cycles):
        return (self.count1 >= cycles and (not self.tpdo_fe or self.count2 >= cycles)
                and (not self.tpdo_sensors or self.count3 >= cycles) and (not self.ssi or self.count4 >= cycles))

    def controlword(self):
        s = self.statusword & 0x6F
        if self.statusword & 0x08:
            return 0x0080 if self.count1 % 2 else 0x0000
        return {0x21: 0x0007, 0x23: 0x000F, 0x27: 0x000F}.get(s, 0x0006)


def run(args):
    ids = [int(x) for x in args.nodes.split(",")]
    with open(args.setpoints) as f:
        table = [[int(x) for x in line.split()] for line in f if line.strip()]
    network, nodes, recorder = connect(args.port, args.eds, ids)
    try:
        for i in ids:
            configure(nodes[i], args.tpdo_fe, args.sync_us, args.tpdo_sensors, args.ssi)
        if args.hb_loss:
            nodes[ids[0]].sdo.download(0x1016, 1, struct.pack("<I", MASTER_HB_ID << 16 | args.hb_consumer_ms))
            nodes[ids[0]].sdo.download(0x1017, 0, struct.pack("<H", args.hb_producer_ms))
        axes = [Axis(nodes[i], k, args.tpdo_fe, args.tpdo_sensors, args.ssi) for k, i in enumerate(ids)]
        for i in ids:
            nodes[i].nmt.state = "OPERATIONAL"
        # The NMT frames run until quiet; an SDO answered after them is the barrier.
        nodes[ids[0]].sdo.upload(0x1000, 0)
        mark = recorder.mark()
        late, cycles, last_hb = 0, 0, None
        move_len = len(table)
        total = args.enable_cycles + move_len + args.settle
        for k in range(total):
            for a in axes:
                if a.enabled_at is None and a.statusword & 0x6F == 0x27:
                    a.enabled_at = k
                    a.start = a.actual
                step = k - a.enabled_at if a.enabled_at is not None else None
                if step is None:
                    target = a.actual
                else:
                    target = a.start + table[min(step, move_len - 1)][a.column]
                    a.final_setpoint = a.start + table[-1][a.column]
                    if 2 < step < move_len and a.tpdo_fe:
                        a.fe_peak = max(a.fe_peak, abs(a.fe))
                        a.fe_sq += a.fe * a.fe
                        a.fe_n += 1
                    a.bit13 |= bool(a.statusword & (1 << 13))
                m = a.node.rpdo[1]
                m[0x6040].raw = a.controlword()
                m[0x607A].raw = target
                m.transmit()
            if args.hb_every and k % args.hb_every == 0:
                network.send_message(0x700 + MASTER_HB_ID, b"\x05")
                last_hb = cycles + 1
            network.send_message(0x080, b"")
            cycles += 1
            got = recorder.wait(mark, lambda fs: all(a.arrived(cycles) for a in axes), args.tpdo_wait_s)
            if got is None:
                late += 1
                if late > args.max_late:
                    break
            else:
                for a in axes:
                    a.check_sensors()
            if k == args.enable_cycles - 1 and any(a.enabled_at is None for a in axes):
                raise Fail("not all drives «Operation enabled»: statuswords "
                           + " ".join(f"0x{a.statusword:04x}" for a in axes))
        emit("cycles", cycles)
        emit("late_cycles", late)
        for a in axes:
            i = a.node.id
            emit(f"enabled_at_{i}", a.enabled_at)
            emit(f"statusword_{i}", f"0x{a.statusword:04x}")
            emit(f"bit13_{i}", int(a.bit13))
            if a.final_setpoint is not None:
                emit(f"final_error_{i}", a.actual - a.final_setpoint)
                emit(f"distance_{i}", a.final_setpoint - a.start)
            if a.tpdo_fe:
                emit(f"fe_samples_{i}", a.fe_n)
                emit(f"fe_peak_{i}", a.fe_peak)
                emit(f"fe_rms_{i}", f"{(a.fe_sq / a.fe_n) ** 0.5 if a.fe_n else 0:.3f}")
            if a.tpdo_sensors:
                emit(f"sensor1_position_diff_max_{i}", a.sensor1_diff_max)
                emit(f"sensor2_values_{i}", " ".join(str(v) for v in sorted(a.sensor2_values)))
            if a.ssi:
                emit(f"ssi_position_diff_max_{i}", a.ssi_diff_max)
                emit(f"ssi_raw_span_{i}", (a.ssi_raw_max or 0) - (a.ssi_raw_min or 0))
        if args.hb_loss:
            heartbeat_loss(args, network, recorder, axes[0], cycles, last_hb)
    finally:
        network.disconnect()


def heartbeat_loss(args, network, recorder, a, cycles, last_hb):
    """The master's heartbeat stops; SYNC and set-points go on until the drive shows «Quick stop active».
    `last_hb` is the number of the SYNC the last heartbeat went with (it crossed the bus just before it)."""
    node = a.node
    mark = recorder.mark()
    hold = a.final_setpoint if a.final_setpoint is not None else a.actual
    reaction = None
    for k in range(args.hb_loss_cycles):
        m = node.rpdo[1]
        m[0x6040].raw = 0x000F
        m[0x607A].raw = hold
        m.transmit()
        network.send_message(0x080, b"")
        cycles += 1
        recorder.wait(mark, lambda fs: a.arrived(cycles), args.tpdo_wait_s)
        if reaction is None and a.statusword & 0x6F == 0x07:
            # The TPDO of SYNC number `cycles` shows it: sampled at that SYNC.
            reaction = cycles
        # 60 more SYNCs for the EMCY and the drive's heartbeats (0x1017) to leave.
        if reaction is not None and cycles >= reaction + 60:
            break
    emit("hb_last_sync", last_hb)
    emit("hb_loss_reaction_sync", reaction)
    emit("hb_loss_reaction_syncs_after_last_hb", reaction - last_hb if reaction and last_hb else None)
    emit("hb_loss_statusword", f"0x{a.statusword:04x}")
    frames = recorder.since(mark)
    emcys = [d for c, d in frames if c == 0x80 + node.id]
    for d in emcys:
        emit(f"emcy_{struct.unpack_from('<H', d, 0)[0]:04x}", d.hex())
    emit("emcy_count", len(emcys))
    states = sorted({d[0] for c, d in frames if c == 0x700 + node.id and len(d) == 1})
    emit("drive_heartbeat_states", " ".join(f"{s:02x}" for s in states))
    emit("drive_heartbeats", sum(1 for c, d in frames if c == 0x700 + node.id))
    emit("error_code_603f", f"0x{struct.unpack('<H', node.sdo.upload(0x603F, 0))[0]:04x}")


if __name__ == "__main__":
    p = parser(__doc__)
    p.add_argument("--nodes", default="1")
    p.add_argument("--setpoints", required=True)
    p.add_argument("--sync-us", type=int, default=1000)
    p.add_argument("--tpdo-fe", action="store_true")
    p.add_argument("--tpdo-sensors", action="store_true")
    p.add_argument("--ssi", action="store_true")
    p.add_argument("--enable-cycles", type=int, default=400)
    p.add_argument("--settle", type=int, default=200)
    p.add_argument("--tpdo-wait-s", type=float, default=1.0)
    p.add_argument("--max-late", type=int, default=20)
    p.add_argument("--hb-every", type=int, default=0)
    p.add_argument("--hb-loss", action="store_true")
    p.add_argument("--hb-consumer-ms", type=int, default=50)
    p.add_argument("--hb-producer-ms", type=int, default=20)
    p.add_argument("--hb-loss-cycles", type=int, default=300)
    import sys

    sys.exit(main(run, p))
