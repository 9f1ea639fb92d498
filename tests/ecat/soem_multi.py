#!/usr/bin/env python3
"""SOEM (PyPI pysoem) brings up a line of drives in DC mode and runs one coordinated CSP move on all of them.

Run by tests/tests/ecat_multi_axis.rs in a private network namespace against `drive-sim ethercat --slaves N
--lock-step` (issue 21 item 2). Steps:
1. config_init finds --slaves drives; each one's identity (SII) and its serial number (SII word 0x0E and 0x1018:04
   over SDO) are read: one type, distinct serials.
2. PRE-OP, every drive: 0x1C32:01 = 0x1C33:01 = 2 (DC SYNC0), 0x60C2 = the cycle; the PDO layout over SDO.
3. config_map, config_dc (SOEM measures the propagation delays and writes 0x0920/0x0928), dc_sync on every
   drive (SYNC0 every --cycle-ns), SAFE-OP, OP.
4. --cycles cycles: each drive's controlword from its own statusword (0x06, 0x07, 0x0F), mode 8 (CSP); once every
   drive shows «Operation enabled», one minimum-jerk move of --revs revolutions at --peak-rpm peak speed on all
   drives at once (s(u) = 10u^3 - 15u^4 + 6u^5). Figures: working-counter errors (the LRW's expected counter is
   3 per drive), per drive the following error 0x60F4 from the TxPDO during the move (peak and RMS),
   statusword bit 13, |position - end| at the end.
   --realtime-s S (against drive-sim in real time, not lock-step): the cycles are paced to the wall clock for S
   seconds instead, each answer awaited for one cycle at most; a frame not back within its cycle (or with a
   wrong working counter) counts as lost (`lost_frames`), and lateness is reported.
5. The DC registers of every drive (FPRD): 0x0990 (the next SYNC0 pulse), 0x0910 (system time), 0x0928 (delay),
   in one pass; the SYNC0 start times must agree. 0x1C32:0B (SM event missed) over SDO, then back to INIT.
"""

import argparse
import math
import struct
import time

import pysoem

from soem_common import Fail, emit, offset_of, pdo_layout, reach, run_main, state_name, u
from soem_common import write_checked
from soem_motion import interpolation_period

INC_PER_REV = 4096


def run(args):
    master = pysoem.Master()
    master.sdo_read_timeout = 500_000
    master.sdo_write_timeout = 500_000
    master.open(args.iface)
    try:
        found = master.config_init()
        emit("slaves_found", found)
        if found != args.slaves:
            raise Fail(f"config_init found {found} slaves, expected {args.slaves}")
        slaves = list(master.slaves)
        if master.state_check(pysoem.PREOP_STATE, 5_000_000) != pysoem.PREOP_STATE:
            raise Fail("PRE-OP not reached on every drive")
        identities = {(s.man, s.id, s.rev) for s in slaves}
        emit("identities", len(identities))
        serials_sii = [struct.unpack("<I", s.eeprom_read(0x0E, 500_000))[0] for s in slaves]
        serials_sdo = [u(s, 0x1018, 4, "<I") for s in slaves]
        emit("serials_sii", ",".join(str(v) for v in serials_sii))
        emit("serials_sdo", ",".join(str(v) for v in serials_sdo))
        if serials_sii != serials_sdo or len(set(serials_sdo)) != len(slaves):
            raise Fail(f"serial numbers SII {serials_sii} SDO {serials_sdo}")

        value, index = interpolation_period(args.cycle_ns)
        layouts = []
        dc = args.sync == 2
        for s in slaves:
            write_checked(s, 0x1C32, 1, struct.pack("<H", args.sync))
            # 0x1C33:01 (ETG.1020): 0x22 synchronous with the SM2 event, 2 DC SYNC0.
            write_checked(s, 0x1C33, 1, struct.pack("<H", 2 if dc else 0x22))
            write_checked(s, 0x60C2, 1, struct.pack("<B", value))
            write_checked(s, 0x60C2, 2, struct.pack("<b", index))
            outs, ins = pdo_layout(s, 0x1C12), pdo_layout(s, 0x1C13)
            layouts.append(
                (
                    offset_of(outs, 0x6040),
                    offset_of(outs, 0x6060),
                    offset_of(outs, 0x607A),
                    offset_of(ins, 0x6041),
                    offset_of(ins, 0x6064),
                    offset_of(ins, 0x60F4),
                )
            )
        master.manual_state_change = True  # SAFE-OP only once SYNC0 runs (soem_csp.py)
        master.config_map()
        emit("dc_slaves", int(master.config_dc()))
        if dc:
            for s in slaves:
                s.dc_sync(1, args.cycle_ns)
        n = len(slaves)
        expected_wkc = master.expected_wkc
        emit("expected_wkc", expected_wkc)
        if expected_wkc != 3 * n:
            raise Fail(f"expected working counter {expected_wkc}, not 3 per drive")

        cw = [0] * n
        target = [u(s, 0x6064, 0, "<i") for s in slaves]
        outs = [bytearray(len(s.output)) for s in slaves]

        def outputs():
            for k, s in enumerate(slaves):
                cw_at, mode_at, target_at = layouts[k][:3]
                struct.pack_into("<H", outs[k], cw_at, cw[k])
                struct.pack_into("<b", outs[k], mode_at, 8)
                struct.pack_into("<i", outs[k], target_at, target[k])
                s.output = bytes(outs[k])

        reach(master, slaves[0], pysoem.SAFEOP_STATE, 5_000_000, "SAFE-OP")
        emit("safeop", 1)
        outputs()
        master.send_processdata()
        master.receive_processdata(args.wkc_timeout_us)
        master.state = pysoem.OP_STATE
        master.write_state()
        for _ in range(2000):
            outputs()
            master.send_processdata()
            master.receive_processdata(args.wkc_timeout_us)
            if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        else:
            master.read_state()
            raise Fail("OP not reached: " + ",".join(state_name(s.state) for s in slaves))
        emit("op", 1)

        cycle_s = args.cycle_ns * 1e-9
        distance = round(args.revs * INC_PER_REV)
        duration = 1.875 * distance / (args.peak_rpm * INC_PER_REV / 60.0)
        emit("move_s", f"{duration:.4f}")
        statusword = [0] * n
        actual = [0] * n
        start = [0] * n
        enabled_at = None
        fe_peak = [0] * n
        fe_sq = [0.0] * n
        fe_n = 0
        bit13 = [0] * n
        bad, first_bad = 0, None
        wall = time.monotonic()
        cycles = args.cycles
        if args.realtime_s:
            cycles = int(args.realtime_s / cycle_s)
        late_max = 0.0
        next_at = time.monotonic()
        for k in range(cycles):
            if args.realtime_s:
                next_at += cycle_s
                pause = next_at - time.monotonic()
                if pause > 0:
                    time.sleep(pause)
            for j in range(n):
                sw = statusword[j] & 0x6F
                cw[j] = 0x0007 if sw == 0x21 else 0x000F if sw in (0x23, 0x27) else 0x0006
            if enabled_at is None and all(sw & 0x6F == 0x27 for sw in statusword):
                enabled_at = k
                start = list(actual)
            if enabled_at is not None:
                uu = min(1.0, (k - enabled_at) * cycle_s / duration)
                s_u = 10 * uu**3 - 15 * uu**4 + 6 * uu**5
                for j in range(n):
                    target[j] = round(start[j] + distance * s_u)
            elif k > 0:
                target = list(actual)  # hold where each drive is until all are enabled
            outputs()
            sent_at = time.monotonic()
            master.send_processdata()
            wkc = master.receive_processdata(args.wkc_timeout_us)
            late_max = max(late_max, time.monotonic() - sent_at)
            if wkc != expected_wkc:
                bad += 1
                first_bad = first_bad or (k, wkc)
                continue
            sample = enabled_at is not None and k > enabled_at + 1 and (k - enabled_at) * cycle_s <= duration
            if sample:
                fe_n += 1
            for j, s in enumerate(slaves):
                inp = s.input
                sw_at, pos_at, fe_at = layouts[j][3:]
                statusword[j] = struct.unpack_from("<H", inp, sw_at)[0]
                actual[j] = struct.unpack_from("<i", inp, pos_at)[0]
                if enabled_at is not None and statusword[j] & (1 << 13):
                    bit13[j] += 1
                if sample:
                    fe = struct.unpack_from("<i", inp, fe_at)[0]
                    fe_peak[j] = max(fe_peak[j], abs(fe))
                    fe_sq[j] += fe * fe
        emit("cycles", cycles)
        emit("cycles_s", f"{time.monotonic() - wall:.3f}")
        emit("wkc_errors", bad)
        emit("lost_frames", bad)
        emit("answer_max_us", f"{late_max * 1e6:.0f}")
        emit("first_bad_wkc", first_bad)
        emit("enabled_at_cycle", enabled_at)
        enabled_end = sum(1 for sw in statusword if sw & 0x6F == 0x27)
        emit("enabled_at_end", enabled_end)
        emit("fe_samples", fe_n)
        rms = [math.sqrt(fe_sq[j] / fe_n) if fe_n else float("nan") for j in range(n)]
        emit("fe_peak_inc_each", ",".join(str(v) for v in fe_peak))
        emit("fe_rms_inc_each", ",".join(f"{v:.2f}" for v in rms))
        emit("fe_peak_inc_max", max(fe_peak))
        emit("fe_rms_inc_max", f"{max(rms):.2f}")
        emit("bit13_seen", sum(1 for b in bit13 if b))
        end_err = [abs(actual[j] - (start[j] + distance)) for j in range(n)] if enabled_at is not None else []
        emit("end_error_inc_max", max(end_err) if end_err else "none")

        # DC registers of every drive, read in one pass (one FPRD each, back to back): the next SYNC0 pulse 0x0990
        # (in system time: equal on all drives when their clocks agree), the system time 0x0910 and the
        # delay 0x0928.
        starts, times, delays = [], [], []
        for s in slaves:
            starts.append(struct.unpack("<Q", s._fprd(0x0990, 8, 200_000))[0])
        for s in slaves:
            times.append(struct.unpack("<Q", s._fprd(0x0910, 8, 200_000))[0])
            delays.append(struct.unpack("<I", s._fprd(0x0928, 4, 200_000))[0])
        emit("sync0_start_spread_ns", max(starts) - min(starts))
        emit("system_delay_ns_each", ",".join(str(d) for d in delays))
        cyc = [struct.unpack("<I", s._fprd(0x09A0, 4, 200_000))[0] for s in slaves]
        emit("sync0_cycle_ns_all", ",".join(sorted({str(c) for c in cyc})))
        act = [s._fprd(0x0981, 1, 200_000)[0] for s in slaves]
        emit("dc_activation_all", ",".join(sorted({f"0x{a:02x}" for a in act})))
        master.read_state()
        emit("states_after_cycles", ",".join(sorted({state_name(s.state) for s in slaves})))
        missed = [u(s, 0x1C32, 0x0B, "<H") for s in slaves]
        emit("sdo_sm_event_missed_total", sum(missed))
        if enabled_at is None:
            raise Fail(f"«Operation enabled» not reached on every drive: {[hex(v) for v in statusword]}")
        if bad and not args.realtime_s:
            raise Fail(f"{bad} cycles with a wrong working counter, first {first_bad}")
        reach(master, slaves[0], pysoem.INIT_STATE, 5_000_000, "back to INIT")
        emit("init_again", 1)
    finally:
        master.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iface", default="ecm0")
    p.add_argument("--slaves", type=int, default=16)
    p.add_argument("--cycle-ns", type=int, default=1_000_000)
    p.add_argument("--cycles", type=int, default=10_000)
    p.add_argument("--revs", type=float, default=10.0)
    p.add_argument("--peak-rpm", type=float, default=2449.0)
    p.add_argument("--sync", type=int, choices=(1, 2), default=2, help="0x1C32:01: 1 SM-synchronous, 2 DC SYNC0")
    p.add_argument("--wkc-timeout-us", type=int, default=500_000)
    p.add_argument("--realtime-s", type=float, default=0.0)
    run_main(run, p)
