#!/usr/bin/env python3
"""SOEM (PyPI pysoem) runs a CSP move through the drive's process data, then (--watchdog) goes quiet.

Run by tests/tests/ecat_real_masters.rs in a private network namespace against `drive-sim ethercat --lock-step`
(issue 6, "What it must show"; the in-process version is tests/tests/ecat/slave.rs). Steps:
1. PRE-OP: 0x1C32:01 = --sync (0 free run, 1 SM-synchronous, 2 DC SYNC0), 0x1C33:01 likewise (0, 0x22, 2), in free run 0x1C32:02 =
   the cycle; 0x60C2 = the cycle (1 ms = 1 x 10^-3 s, 200 us = 200 x 10^-6 s) so that CSP interpolates between
   set-points; the PDO layout read over SDO (where the controlword, target, statusword... lie).
2. config_map (DC: config_dc and SYNC0 every --cycle-ns, SAFE-OP requested by the script), SAFE-OP, OP.
3. --cycles cycles: the controlword from the last statusword (0x06, 0x07, 0x0F), mode 8 (CSP); once the
   statusword shows «Operation enabled», a minimum-jerk move of --revs revolutions with --peak-rpm peak speed
   (s(u) = 10u^3 - 15u^4 + 6u^5: zero speed and acceleration at both ends; peak speed 1.875 x distance /
   duration). Figures: working-counter errors, the following error 0x60F4 from the TxPDO during the move (peak
   and RMS), statusword bit 13 seen, |position - end| at the end, 0x1C32:0B / 0x1C33:0B / 0x1C32:0C over SDO.
   With --ssi (a plant with an SSI absolute encoder, issue 20): in PRE-OP first 0x3000:01 = 0x00000300 (the SSI
   sensor alone, IDX 0x3000:01 sensor 2 type 3; read back), then TxPDO 4 (0x1A03) remapped to the SSI position raw
   value 0x3012:09 and assigned as the fourth TxPDO of 0x1C13 (CiA 301 procedure: assignment sub 0 = 0, mapping
   sub 0 = 0, entry, mapping sub 0 = 1, assignment entry, assignment sub 0 = 4). Figures: the largest distance,
   modulo 2^24, between 0x6064 and 0x3012:09 of the same frame, how many frames had them equal, and the span of
   0x3012:09 over the move.
4. --watchdog: no more process data until the AL status shows the error flag (at most --quiet-s seconds;
   drive-sim --idle-cycle runs a cycle per idle poll), then the AL state and status code, 0x603F and the statusword over SDO.
5. Back to INIT.
"""

import argparse
import math
import struct
import time

import pysoem

from soem_common import Fail, emit, go_op, offset_of, open_preop, pdo_layout, reach, run_main, state_name, u
from soem_common import write_checked

INC_PER_REV = 4096
# 0x3012:09 "SSI position raw value", UNSIGNED32 (firmware/device.toml): index << 16 | sub << 8 | bits.
SSI_POSITION_ENTRY = 0x30120920


def interpolation_period(cycle_ns):
    """0x60C2:01/02 for a cycle: the largest unit (index -3..-6) that gives an integer value up to 255."""
    for index in (-3, -4, -5, -6):
        unit_ns = 10 ** (9 + index)
        if cycle_ns % unit_ns == 0 and cycle_ns // unit_ns <= 255:
            return cycle_ns // unit_ns, index
    raise Fail(f"no 0x60C2 value for a {cycle_ns} ns cycle")


def read_past_emcy(slave, index, fmt):
    """An SDO upload of `index`:00; pysoem raises the CoE emergencies it finds in the mailbox first (the fault's
    EMCY): each one is printed as `emcy_code` and the read repeated."""
    for _ in range(8):
        try:
            return u(slave, index, 0, fmt)
        except pysoem.Emergency as e:
            emit("emcy_code", f"0x{e.error_code:04x}")
    raise Fail(f"no answer to {index:04X} after 8 emergencies")


def run(args):
    master, slave = open_preop(args.iface)
    try:
        write_checked(slave, 0x1C32, 1, struct.pack("<H", args.sync))
        # 0x1C33:01 (ETG.1020): 0 free run, 0x22 synchronous with the SM2 event, 2 DC SYNC0.
        write_checked(slave, 0x1C33, 1, struct.pack("<H", {0: 0, 1: 0x22, 2: 2}[args.sync]))
        if args.sync == 0:
            write_checked(slave, 0x1C32, 2, struct.pack("<I", args.cycle_ns))
        value, index = interpolation_period(args.cycle_ns)
        write_checked(slave, 0x60C2, 1, struct.pack("<B", value))
        write_checked(slave, 0x60C2, 2, struct.pack("<b", index))
        emit("interpolation_period", f"{value}e{index}")
        if args.ssi:
            write_checked(slave, 0x3000, 1, struct.pack("<I", 0x00000300))
            emit("sensors_configuration", f"0x{u(slave, 0x3000, 1, '<I'):08x}")
            write_checked(slave, 0x1C13, 0, b"\x00")
            write_checked(slave, 0x1A03, 0, b"\x00")
            write_checked(slave, 0x1A03, 1, struct.pack("<I", SSI_POSITION_ENTRY))
            write_checked(slave, 0x1A03, 2, b"\x00\x00\x00\x00")
            write_checked(slave, 0x1A03, 0, b"\x01")
            write_checked(slave, 0x1C13, 4, struct.pack("<H", 0x1A03))
            write_checked(slave, 0x1C13, 0, b"\x04")
        outs, ins = pdo_layout(slave, 0x1C12), pdo_layout(slave, 0x1C13)
        cw_at, mode_at, target_at = offset_of(outs, 0x6040), offset_of(outs, 0x6060), offset_of(outs, 0x607A)
        sw_at, pos_at, fe_at = offset_of(ins, 0x6041), offset_of(ins, 0x6064), offset_of(ins, 0x60F4)
        ssi_at = offset_of(ins, 0x3012) if args.ssi else None
        if args.ssi:
            emit("txpdo_map", " ".join(f"{i:04x}:{s:02x}/{b}" for i, s, b, _ in ins))

        if args.sync == 2:
            master.manual_state_change = True  # see soem_csp.py: SAFE-OP only once SYNC0 runs
        master.config_map()
        if args.sync == 2:
            emit("dc_slaves", int(master.config_dc()))
            slave.dc_sync(1, args.cycle_ns)
        out = bytearray(len(slave.output))
        state = {"cw": 0, "target": 0}

        def outputs():
            struct.pack_into("<H", out, cw_at, state["cw"])
            struct.pack_into("<b", out, mode_at, 8)
            struct.pack_into("<i", out, target_at, state["target"])
            slave.output = bytes(out)

        # Hold the position the drive reports (0 before OP: the reference plant starts at rest at 0).
        state["target"] = u(slave, 0x6064, 0, "<i")
        expected_wkc = go_op(master, slave, outputs, args.wkc_timeout_us)
        emit("expected_wkc", expected_wkc)

        cycle_s = args.cycle_ns * 1e-9
        distance = round(args.revs * INC_PER_REV)
        duration = 1.875 * distance / (args.peak_rpm * INC_PER_REV / 60.0)
        emit("move_s", f"{duration:.4f}")
        start = end = None
        enabled_at = None
        fe_peak, fe_sq, fe_n = 0, 0.0, 0
        bit13 = False
        ssi = {"diff_max": 0, "equal": 0, "frames": 0, "min": None, "max": None}
        statusword, actual = 0, 0
        bad, first_bad = 0, None
        wall = time.monotonic()
        for k in range(args.cycles):
            sw = statusword & 0x6F
            state["cw"] = 0x0007 if sw == 0x21 else 0x000F if sw in (0x23, 0x27) else 0x0006
            if sw == 0x27 and enabled_at is None:
                enabled_at, start = k, actual
                end = start + distance
            if enabled_at is None and args.ssi:
                # The SSI sensor's absolute position comes at switch-on: until enabled, the target follows it.
                state["target"] = actual
            if enabled_at is not None:
                uu = min(1.0, (k - enabled_at) * cycle_s / duration)
                state["target"] = round(start + distance * (10 * uu**3 - 15 * uu**4 + 6 * uu**5))
            outputs()
            master.send_processdata()
            wkc = master.receive_processdata(args.wkc_timeout_us)
            if wkc != expected_wkc:
                bad += 1
                first_bad = first_bad or (k, wkc)
                continue
            inp = slave.input
            statusword = struct.unpack_from("<H", inp, sw_at)[0]
            actual = struct.unpack_from("<i", inp, pos_at)[0]
            if ssi_at is not None and enabled_at is not None:
                raw = struct.unpack_from("<I", inp, ssi_at)[0]
                # Without homing (0x3012:0E = 0) 0x6064 is the SSI sensor's absolute position; the raw value keeps
                # its 24 position bits (0x3012:0B = 0x0C0C): the two agree modulo 2^24.
                diff = (actual - raw + (1 << 23)) % (1 << 24) - (1 << 23)
                ssi["diff_max"] = max(ssi["diff_max"], abs(diff))
                ssi["equal"] += int(diff == 0)
                ssi["frames"] += 1
                ssi["min"] = raw if ssi["min"] is None else min(ssi["min"], raw)
                ssi["max"] = raw if ssi["max"] is None else max(ssi["max"], raw)
            if enabled_at is not None:
                bit13 |= bool(statusword & (1 << 13))
                if k > enabled_at + 1 and (k - enabled_at) * cycle_s <= duration:
                    fe = struct.unpack_from("<i", inp, fe_at)[0]
                    fe_peak = max(fe_peak, abs(fe))
                    fe_sq += fe * fe
                    fe_n += 1
        emit("cycles", args.cycles)
        emit("cycles_s", f"{time.monotonic() - wall:.3f}")
        emit("wkc_errors", bad)
        emit("first_bad_wkc", first_bad)
        emit("enabled_at_cycle", enabled_at)
        emit("statusword_end", f"0x{statusword:04x}")
        emit("fe_samples", fe_n)
        emit("fe_peak_inc", fe_peak)
        emit("fe_rms_inc", f"{math.sqrt(fe_sq / fe_n):.2f}" if fe_n else "nan")
        emit("bit13_seen", int(bit13))
        emit("end_error_inc", abs(actual - end) if end is not None else "none")
        if args.ssi:
            emit("start_position", start)
            emit("ssi_frames", ssi["frames"])
            emit("ssi_equal_frames", ssi["equal"])
            emit("ssi_position_diff_max", ssi["diff_max"])
            emit("ssi_raw_span", (ssi["max"] or 0) - (ssi["min"] or 0))
        master.read_state()
        emit("state_after_cycles", state_name(slave.state))
        emit("sdo_sync_type", u(slave, 0x1C32, 1, "<H"))
        emit("sdo_sm2_event_missed", u(slave, 0x1C32, 0x0B, "<H"))
        emit("sdo_sm3_event_missed", u(slave, 0x1C33, 0x0B, "<H"))
        emit("sdo_cycle_time_too_small", u(slave, 0x1C32, 0x0C, "<H"))
        if enabled_at is None:
            raise Fail(f"«Operation enabled» never seen (statusword 0x{statusword:04x})")

        if args.watchdog:
            # The master goes quiet: no process data. It looks at the AL status every 100 ms of wall time (a
            # register read, not a cyclic frame: simulated time runs only in drive-sim's idle polls) until the
            # slave shows the error flag, for at most --quiet-s.
            quiet_from = time.monotonic()
            while time.monotonic() - quiet_from < args.quiet_s:
                time.sleep(0.1)
                master.read_state()
                if slave.state & pysoem.STATE_ERROR:
                    break
            emit("quiet_wall_s", f"{time.monotonic() - quiet_from:.3f}")
            emit("al_state_after_quiet", state_name(slave.state))
            emit("al_status_code", f"0x{slave.al_status:04x}")
            emit("sdo_error_code", f"0x{read_past_emcy(slave, 0x603F, '<H'):04x}")
            emit("sdo_statusword", f"0x{read_past_emcy(slave, 0x6041, '<H'):04x}")
        elif bad:
            raise Fail(f"{bad} cycles with a wrong working counter, first {first_bad}")
        reach(master, slave, pysoem.INIT_STATE, 2_000_000, "back to INIT")
        emit("init_again", 1)
    finally:
        master.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iface", default="ecm0")
    p.add_argument("--sync", type=int, choices=(0, 1, 2), default=1)
    p.add_argument("--cycle-ns", type=int, default=1_000_000)
    p.add_argument("--cycles", type=int, default=10_000)
    p.add_argument("--revs", type=float, default=10.0)
    p.add_argument("--peak-rpm", type=float, default=2449.0)
    p.add_argument("--wkc-timeout-us", type=int, default=200_000, help="lock-step: a late answer is not a lost cycle, so wait long (a loaded 2-core CI host can take tens of ms)")
    p.add_argument("--watchdog", action="store_true")
    p.add_argument("--quiet-s", type=float, default=10.0)
    p.add_argument("--ssi", action="store_true", help="SSI sensor alone, 0x3012:09 mapped into TxPDO 4")
    run_main(run, p)
