#!/usr/bin/env python3
"""SOEM (PyPI pysoem) works the drive's dictionary over CoE SDO: every readable object, parameter writes, PDO
remapping, mailbox throughput.

Run by tests/tests/ecat_soem_sdo.rs in a private network namespace against `drive-sim ethercat --lock-step`
(issue 6). The Rust test computes every expectation from the firmware's dictionary and hands it over in a file;
this script only does the transfers and prints what differs. One part per run (--part):

- objects: each line of --expect is `IIII SS rule hex size name` (hex `-`: no bytes): rule `exact` (the upload must equal hex),
  `len` (only its length: a measured value, see the Rust test) or `abort` (hex is the abort code expected).
  Prints the counts and one `mismatch_N` line per difference.
- params: each line of --cases is `name IIII SS data expect`: expect `ok` (the download is accepted and reads
  back equal) or the abort code; after a refused download the entry reads as before (CiA 301 §7.2.4.3.17: an
  aborted transfer changes nothing).
- remap: the CiA 301 / ETG.1020 procedure (assignment sub 0 = 0, mapping sub 0 = 0, entries, mapping sub 0 = n,
  assignment entries, assignment sub 0 = n) to a CSV set, refused mappings on the way, config_map, OP, CSV at
  --rpm, INIT, then back to the defaults given in --defaults (`IIII n v1 v2 ...`) and config_map again.
- throughput: --repeat segmented uploads of --index:--sub, --repeat expedited uploads of --exp-index:--exp-sub;
  each compared with --bytes / --exp-bytes (hex).
"""

import argparse
import struct
import time

import pysoem

from soem_common import Fail, emit, go_op, open_preop, reach, run_main, state_name, write_checked


RETRIES = {"wkc": 0}


def read_any(slave, index, sub, size=0):
    """(bytes, None) or (None, abort code); emergencies that pysoem raises first are skipped (the drive may
    queue one when it changes state, and it comes before the answer in the mailbox). A mailbox frame that came
    back too late for SOEM (WkcError: SOEM waits 2 ms per frame, which a host shared with builds can miss; an
    upload changes nothing, so it is repeated) is counted in `wkc_retries`."""
    for _ in range(8):
        try:
            if size:
                return slave.sdo_read(index, sub, size), None
            return slave.sdo_read(index, sub), None
        except pysoem.Emergency as e:
            emit("emcy_code", f"0x{e.error_code:04x}")
        except pysoem.SdoError as e:
            return None, e.abort_code
        except pysoem.WkcError:
            RETRIES["wkc"] += 1
    raise Fail(f"no answer to {index:04X}:{sub:02X} after 8 emergencies or late frames")


def write_any(slave, index, sub, data):
    """None when accepted, else the abort code; emergencies skipped as in read_any."""
    for _ in range(8):
        try:
            slave.sdo_write(index, sub, data)
            return None
        except pysoem.Emergency as e:
            emit("emcy_code", f"0x{e.error_code:04x}")
        except pysoem.SdoError as e:
            return e.abort_code
    raise Fail(f"no answer to the download {index:04X}:{sub:02X} after 8 emergencies")


def lines_of(path):
    with open(path, encoding="utf-8") as f:
        return [line.split() for line in f if line.strip() and not line.startswith("#")]


def part_objects(args, slave):
    mismatches = 0
    counts = {"exact": 0, "len": 0, "abort": 0}
    segmented = 0
    longest = 0
    for fields in lines_of(args.expect):
        index, sub, rule, hexval, size = int(fields[0], 16), int(fields[1], 16), fields[2], fields[3], int(fields[4])
        expected = int(hexval, 16) if rule == "abort" else bytes.fromhex("" if hexval == "-" else hexval)
        got, code = read_any(slave, index, sub, max(size + 16, 16))
        counts[rule] += 1
        if rule == "abort":
            ok = got is None and code == expected
        elif got is None:
            ok = False
        elif rule == "exact":
            ok = got == expected
        else:
            ok = len(got) == len(expected)
        if got is not None and len(got) > 4:
            segmented += 1
            longest = max(longest, len(got))
        if not ok:
            mismatches += 1
            shown = got.hex() if got is not None else f"abort 0x{code:08x}"
            want = hexval if rule != "abort" else f"abort 0x{expected:08x}"
            emit(f"mismatch_{mismatches}", f"{index:04X}:{sub:02X} {rule} got {shown} expected {want}")
    emit("objects_read", sum(counts.values()))
    for rule, n in counts.items():
        emit(f"objects_{rule}", n)
    emit("objects_longer_than_4", segmented)
    emit("objects_longest_bytes", longest)
    emit("objects_mismatches", mismatches)


def part_params(args, slave):
    failed = 0
    cases = 0
    for name, index, sub, data, expect in lines_of(args.cases):
        index, sub, data = int(index, 16), int(sub, 16), bytes.fromhex(data)
        cases += 1
        before = read_any(slave, index, sub)
        code = write_any(slave, index, sub, data)
        after = read_any(slave, index, sub)
        if expect == "ok":
            ok = code is None and after == (data, None)
            what = f"download {'accepted' if code is None else f'refused 0x{code:08x}'}, reads {after}"
            # Put the old value back so that later cases see the defaults again.
            if code is None and before[0] is not None:
                write_any(slave, index, sub, before[0])
        else:
            ok = code == int(expect, 16) and after == before
            shown = "accepted" if code is None else f"0x{code:08x}"
            what = f"abort {shown}, before {before}, after {after}"
        emit(f"case_{name}", ("ok " if ok else "FAIL ") + what)
        failed += 0 if ok else 1
    emit("params_cases", cases)
    emit("params_failed", failed)


# The CSV process data (issue 6): outputs controlword, modes of operation, target velocity; inputs statusword,
# modes of operation display, velocity actual value, position actual value, and the positions of sensor 1 (motor
# encoder) and sensor 2 (load encoder, the dual loop's main sensor; issue 20 item 2), 0x60E4:01/02. Entries:
# index << 16 | sub << 8 | bits.
CSV_RX = [0x60400010, 0x60600008, 0x60FF0020]
CSV_TX = [0x60410010, 0x60610008, 0x606C0020, 0x60640020, 0x60E40120, 0x60E40220]


def expect_refused(slave, index, sub, data, code, what):
    """A download that must be refused with `code`, the entry unchanged afterwards."""
    before = read_any(slave, index, sub)
    got = write_any(slave, index, sub, data)
    after = read_any(slave, index, sub)
    emit(f"refused_{what}", "none" if got is None else f"0x{got:08x}")
    emit(f"unchanged_{what}", int(after == before))
    if got != code or after != before:
        raise Fail(f"{what}: {index:04X}:{sub:02X} = {data.hex()} gave {got}, {before} -> {after}")


def write_pdo(slave, mapping, entries, refusals=()):
    """mapping sub 0 = 0, the entries (then `refusals` run while the PDO is disabled), sub 0 = n."""
    write_checked(slave, mapping, 0, b"\x00")
    for k, e in enumerate(entries, start=1):
        write_checked(slave, mapping, k, struct.pack("<I", e))
    for check in refusals:
        check()
    write_checked(slave, mapping, 0, struct.pack("<B", len([e for e in entries if e])))


def assign_pdos(slave, assign, indices, slots):
    for k in range(1, slots + 1):
        pdo = indices[k - 1] if k <= len(indices) else 0
        write_checked(slave, assign, k, struct.pack("<H", pdo))
    write_checked(slave, assign, 0, struct.pack("<B", len(indices)))


def run_csv(args, master, slave):
    """OP with the CSV image; enable, mode 9, the target velocity for --csv-cycles cycles; the velocity actual
    value of the last --window cycles. Then 0 rpm and «Shutdown» before leaving OP."""
    unit = struct.unpack("<I", slave.sdo_read(0x60A9, 0))[0]
    emit("velocity_unit", f"0x{unit:08x}")
    # CiA 402 §6.2 / ETG.5001 units: bits 31..24 the decimal prefix (signed), 23..16 the unit (0xB4 revolution),
    # 15..8 the denominator (0x47 minute). The drive accepts only 0x00B44700: rpm with prefix 10^0.
    prefix = struct.unpack("<b", bytes([unit >> 24]))[0]
    if (unit >> 8) & 0xFFFF != 0xB447:
        raise Fail(f"velocity unit 0x{unit:08x} is not a power of ten of rpm")
    target = round(args.rpm / 10.0**prefix)
    emit("csv_target", target)
    out = bytearray(len(slave.output))
    state = {"cw": 0, "v": 0}

    def outputs():
        struct.pack_into("<HbI", out, 0, state["cw"], 9, state["v"] & 0xFFFFFFFF)
        slave.output = bytes(out)

    expected_wkc = go_op(master, slave, outputs, args.wkc_timeout_us)
    emit("expected_wkc", expected_wkc)
    statusword, velocity = 0, 0
    samples = []
    enabled_at = None
    bad, first_bad = 0, None
    sensor1_diff_max, sensor2_seen = 0, set()
    for k in range(args.csv_cycles + 300):
        sw = statusword & 0x6F
        stopping = k >= args.csv_cycles
        if stopping:
            state["v"] = 0
            state["cw"] = 0x000F if k < args.csv_cycles + 200 else 0x0006
        else:
            state["cw"] = 0x0007 if sw == 0x21 else 0x000F if sw in (0x23, 0x27) else 0x0006
            if sw == 0x27 and enabled_at is None:
                enabled_at = k
            state["v"] = target if enabled_at is not None else 0
        outputs()
        master.send_processdata()
        wkc = master.receive_processdata(args.wkc_timeout_us)
        if wkc != expected_wkc:
            bad += 1
            first_bad = first_bad or (k, wkc)
            continue
        statusword, mode, velocity, position, sensor1, sensor2 = struct.unpack_from("<Hbiiii", slave.input, 0)
        if not stopping and k >= args.csv_cycles - args.window:
            samples.append((velocity, mode))
            # Without homing 0x6064 is the motor encoder's count: 0x60E4:01 follows it (both from the same tier-1
            # report; within one slow tick's travel where a cycle falls between the two publications).
            sensor1_diff_max = max(sensor1_diff_max, abs(sensor1 - position))
            sensor2_seen.add(sensor2)
    emit("wkc_errors", bad)
    emit("first_bad_wkc", first_bad)
    emit("enabled_at_cycle", enabled_at)
    if enabled_at is None or not samples:
        raise Fail(f"«Operation enabled» never seen (statusword 0x{statusword:04x})")
    vs = [v for v, _ in samples]
    emit("csv_mode_display", samples[-1][1])
    emit("csv_samples", len(vs))
    emit("csv_velocity_mean", f"{sum(vs) / len(vs):.2f}")
    emit("csv_velocity_min", min(vs))
    emit("csv_velocity_max", max(vs))
    emit("velocity_after_stop", velocity)
    emit("sensor1_position_diff_max", sensor1_diff_max)
    emit("sensor2_values", " ".join(str(v) for v in sorted(sensor2_seen)))


def part_remap(args, master, slave):
    defaults = {int(f[0], 16): [int(x, 16) for x in f[1:]] for f in lines_of(args.defaults)}
    # ETG.1020 / CiA 301 §7.4.8: outputs first.
    write_checked(slave, 0x1C12, 0, b"\x00")

    def rx_refusals():
        # The statusword is TxPDO-only: not into an RxPDO (CiA 301 abort 0x0604_0041).
        expect_refused(slave, 0x1600, 4, struct.pack("<I", 0x60410010), 0x06040041, "tx_object_in_rxpdo")

    write_pdo(slave, 0x1600, CSV_RX + [0] * 9, [rx_refusals])
    assign_pdos(slave, 0x1C12, [0x1600], 4)
    write_checked(slave, 0x1C13, 0, b"\x00")

    def tx_refusals():
        # 0x1000 (device type) is not PDO-mappable at all: 0x0604_0041.
        expect_refused(slave, 0x1A00, 7, struct.pack("<I", 0x10000020), 0x06040041, "unmappable_object")
        # Six more 32-bit entries: 19 + 24 = 43 bytes, above the 40 bytes an EtherCAT PDO may carry (IDX L2196):
        # 0x0604_0042 at sub 0, which stays 0.
        for k in range(len(CSV_TX) + 1, 13):
            write_checked(slave, 0x1A00, k, struct.pack("<I", 0x60640020))
        expect_refused(slave, 0x1A00, 0, b"\x0c", 0x06040042, "pdo_too_long")
        for k in range(len(CSV_TX) + 1, 13):
            write_checked(slave, 0x1A00, k, b"\x00\x00\x00\x00")

    write_pdo(slave, 0x1A00, CSV_TX + [0] * (12 - len(CSV_TX)), [tx_refusals])
    assign_pdos(slave, 0x1C13, [0x1A00], 4)
    emit("csv_rx_map", " ".join(f"{x:08x}" for x in CSV_RX))
    emit("csv_tx_map", " ".join(f"{x:08x}" for x in CSV_TX))
    master.config_map()
    emit("csv_output_bytes", len(slave.output))
    emit("csv_input_bytes", len(slave.input))
    run_csv(args, master, slave)
    reach(master, slave, pysoem.INIT_STATE, 2_000_000, "back to INIT")
    emit("init_again", 1)
    reach(master, slave, pysoem.PREOP_STATE, 2_000_000, "PRE-OP again")

    # Back to the defaults, same procedure: assignments emptied first, then every mapping object, then the
    # assignments.
    for assign in (0x1C12, 0x1C13):
        write_checked(slave, assign, 0, b"\x00")
    for index in sorted(i for i in defaults if 0x1600 <= i <= 0x1BFF):
        count, *entries = defaults[index]
        write_checked(slave, index, 0, b"\x00")
        for k, e in enumerate(entries, start=1):
            write_checked(slave, index, k, struct.pack("<I", e))
        write_checked(slave, index, 0, struct.pack("<B", count))
    for assign in (0x1C12, 0x1C13):
        count, *entries = defaults[assign]
        for k, e in enumerate(entries, start=1):
            write_checked(slave, assign, k, struct.pack("<H", e))
        write_checked(slave, assign, 0, struct.pack("<B", count))
    differ = 0
    for index, (count, *entries) in defaults.items():
        fmt = "<H" if index in (0x1C12, 0x1C13) else "<I"
        got = [struct.unpack("<B", slave.sdo_read(index, 0))[0]]
        got += [struct.unpack(fmt, slave.sdo_read(index, k))[0] for k in range(1, len(entries) + 1)]
        differ += int(got != [count] + entries)
    emit("default_objects_differing", differ)
    # config_init again (SOEM's own start: INIT, the SII, PRE-OP), then config_map from the restored mapping.
    if master.config_init() != 1:
        raise Fail("the drive is gone after the remap")
    slave = master.slaves[0]
    master.config_map()
    emit("default_output_bytes", len(slave.output))
    emit("default_input_bytes", len(slave.input))
    reached = master.state_check(pysoem.SAFEOP_STATE, 2_000_000)
    emit("default_safeop", state_name(reached))
    reach(master, slave, pysoem.INIT_STATE, 2_000_000, "INIT at the end")


def part_throughput(args, slave):
    expected = bytes.fromhex(args.bytes)
    wrong = 0
    started = time.monotonic()
    for _ in range(args.repeat):
        got, code = read_any(slave, args.index, args.sub, len(expected) + 16)
        wrong += int(got != expected)
    seg_s = time.monotonic() - started
    emit("seg_uploads", args.repeat)
    emit("seg_bytes_each", len(expected))
    emit("seg_wrong", wrong)
    emit("seg_wall_s", f"{seg_s:.4f}")
    emit("seg_bytes_per_s", f"{args.repeat * len(expected) / seg_s:.0f}")
    exp = bytes.fromhex(args.exp_bytes)
    wrong = 0
    started = time.monotonic()
    for _ in range(args.repeat):
        got, code = read_any(slave, args.exp_index, args.exp_sub)
        wrong += int(got != exp)
    exp_s = time.monotonic() - started
    emit("exp_uploads", args.repeat)
    emit("exp_wrong", wrong)
    emit("exp_wall_s", f"{exp_s:.4f}")
    emit("exp_per_s", f"{args.repeat / exp_s:.0f}")


def run(args):
    master, slave = open_preop(args.iface)
    try:
        if args.part == "objects":
            part_objects(args, slave)
        elif args.part == "params":
            part_params(args, slave)
        elif args.part == "remap":
            part_remap(args, master, slave)
        else:
            part_throughput(args, slave)
    finally:
        emit("wkc_retries", RETRIES["wkc"])
        master.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iface", default="ecm0")
    p.add_argument("--part", choices=("objects", "params", "remap", "throughput"), required=True)
    p.add_argument("--expect")
    p.add_argument("--cases")
    p.add_argument("--defaults")
    p.add_argument("--rpm", type=float, default=1000.0)
    p.add_argument("--csv-cycles", type=int, default=2000)
    p.add_argument("--window", type=int, default=500)
    # Under lock-step a late answer is no lost cycle (simulated time waits for the frame); 100 ms covers a host
    # shared with builds (a 20 ms wait timed out once in 2,300 cycles at load average 10).
    p.add_argument("--wkc-timeout-us", type=int, default=100_000)
    p.add_argument("--index", type=lambda s: int(s, 0))
    p.add_argument("--sub", type=lambda s: int(s, 0))
    p.add_argument("--bytes")
    p.add_argument("--exp-index", type=lambda s: int(s, 0))
    p.add_argument("--exp-sub", type=lambda s: int(s, 0))
    p.add_argument("--exp-bytes")
    p.add_argument("--repeat", type=int, default=200)
    run_main(run, p)
