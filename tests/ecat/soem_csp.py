#!/usr/bin/env python3
"""SOEM (PyPI pysoem) as a real EtherCAT master against `drive-sim ethercat`.

Run by tests/tests/ecat_real_masters.rs inside a private network namespace (veth pair ecm0/ecs0, the simulator
on ecs0, this master on ecm0). It checks what it can itself and prints one `key=value` per figure, and as its
last line `verdict=pass` or `verdict=fail <reason>`; the Rust test compares the figures with the dictionary.

Steps (issue 6, "What it must show"; facts in shared/spec/fieldbus-real-masters.md):
1. config_init finds exactly one slave; its SII identity (vendor, product, revision) is printed.
   (SOEM reports 1 slave even for a slave that answers only a broadcast read, with an all-zero identity:
   the identity is asserted, not the count alone.)
2. The identity object 0x1018:01..03 read through SDO equals the SII's; 0x1008 (device name) is read.
3. config_map (PDO discovery over CoE: 0x1C12/0x1C13 and the mapping objects), SAFE-OP, then OP.
4. --cycles cycles of process data (LRW), each with the expected working counter (outputs + inputs = 3).
   With --dc: 0x1C32:01/0x1C33:01 = 2 (DC SYNC0) in PRE-OP, config_map with SOEM's automatic SAFE-OP request
   switched off (see run()), config_dc and SYNC0 every --cycle-ns, then SAFE-OP and OP; after the cycles
   0x1C32:01, 0x1C32:0A (SYNC0 cycle) and 0x1C32:0B (SM event missed) are read back over SDO.
5. Back to INIT.
"""

import argparse
import struct
import sys
import time

import pysoem

# The verdict protocol and state helpers are the SOEM scripts' shared ones.
from soem_common import Fail, emit, reach, state_name


def run(args):
    master = pysoem.Master()
    master.sdo_read_timeout = args.sdo_timeout_us
    master.sdo_write_timeout = args.sdo_timeout_us
    master.open(args.iface)
    try:
        started = time.monotonic()
        found = master.config_init()
        emit("slaves_found", found)
        emit("config_init_s", f"{time.monotonic() - started:.3f}")
        if found != 1:
            raise Fail(f"config_init found {found} slaves, expected 1")
        slave = master.slaves[0]
        emit("sii_vendor", f"0x{slave.man:08x}")
        emit("sii_product", f"0x{slave.id:08x}")
        emit("sii_revision", f"0x{slave.rev:08x}")
        emit("sii_name", slave.name)
        if slave.man == 0 and slave.id == 0:
            raise Fail("all-zero identity: the slave answered only broadcasts")

        # PRE-OP (config_init requested it; check it was reached).
        if master.state_check(pysoem.PREOP_STATE, 2_000_000) != pysoem.PREOP_STATE:
            master.read_state()
            raise Fail(f"PRE-OP not reached: {state_name(slave.state)}, AL status code 0x{slave.al_status:04x}")
        emit("preop", 1)

        identity = [struct.unpack("<I", slave.sdo_read(0x1018, sub))[0] for sub in (1, 2, 3)]
        emit("sdo_vendor", f"0x{identity[0]:08x}")
        emit("sdo_product", f"0x{identity[1]:08x}")
        emit("sdo_revision", f"0x{identity[2]:08x}")
        if identity != [slave.man, slave.id, slave.rev]:
            raise Fail(f"0x1018 {identity} differs from the SII {[slave.man, slave.id, slave.rev]}")
        name = slave.sdo_read(0x1008, 0).decode("ascii", "replace").rstrip("\x00")
        emit("sdo_device_name", name)

        if args.dc:
            # DC SYNC0 (ETG.1020): 0x1C32:01 = 0x1C33:01 = 2 in PRE-OP, the clocks configured, SYNC0 armed.
            slave.sdo_write(0x1C32, 1, struct.pack("<H", 2))
            slave.sdo_write(0x1C33, 1, struct.pack("<H", 2))
            emit("sync_type", struct.unpack("<H", slave.sdo_read(0x1C32, 1))[0])

        if args.dc:
            # SOEM's config_map ends by requesting SAFE-OP of every slave it mapped (ecx_config_map_group writes
            # AL control = 0x04 after the FMMUs unless `manualstatechange` is set), that is before config_dc and
            # dc_sync have armed SYNC0: a DC slave must refuse that request with 0x0030 (ETG.1000.6 Table 11, SYNC0
            # not activated) and stays in PRE-OP + error. The master requests SAFE-OP itself once SYNC0 runs.
            master.manual_state_change = True
        # Process data: SOEM discovers the mapping over CoE, sets up SM2/SM3 and the FMMUs.
        io_bytes = master.config_map()
        if args.dc:
            emit("dc_slaves", int(master.config_dc()))
            slave.dc_sync(1, args.cycle_ns)
        emit("io_map_bytes", io_bytes)
        emit("output_bytes", len(slave.output))
        emit("input_bytes", len(slave.input))
        if len(slave.output) == 0 or len(slave.input) == 0:
            raise Fail("no process data mapped")
        expected_wkc = master.expected_wkc
        emit("expected_wkc", expected_wkc)

        reach(master, slave, pysoem.SAFEOP_STATE, 2_000_000, "SAFE-OP")
        emit("safeop", 1)

        # Valid outputs before OP (ETG.1000.6: SAFE-OP -> OP needs valid outputs), then OP.
        master.send_processdata()
        master.receive_processdata(args.wkc_timeout_us)
        master.state = pysoem.OP_STATE
        master.write_state()
        reached = 0
        for _ in range(400):
            master.send_processdata()
            master.receive_processdata(args.wkc_timeout_us)
            if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                reached = 1
                break
        if not reached:
            master.read_state()
            raise Fail(f"OP not reached: {state_name(slave.state)}, AL status code 0x{slave.al_status:04x}")
        emit("op", 1)

        bad = 0
        first_bad = None
        started = time.monotonic()
        for k in range(args.cycles):
            master.send_processdata()
            wkc = master.receive_processdata(args.wkc_timeout_us)
            if wkc != expected_wkc:
                bad += 1
                if first_bad is None:
                    first_bad = (k, wkc)
        emit("cycles", args.cycles)
        emit("cycles_s", f"{time.monotonic() - started:.3f}")
        emit("wkc_errors", bad)
        master.read_state()
        emit("state_after_cycles", state_name(slave.state))
        if args.dc:
            # ETG.1020 0x1C32 as the drive keeps it in OP: the sync type, the SYNC0 cycle it runs with, and
            # the SM events missed (a SYNC0 without fresh outputs).
            emit("sdo_sync_type", struct.unpack("<H", slave.sdo_read(0x1C32, 0x01))[0])
            emit("sdo_sync0_cycle_ns", struct.unpack("<I", slave.sdo_read(0x1C32, 0x0A))[0])
            emit("sdo_sm_event_missed", struct.unpack("<H", slave.sdo_read(0x1C32, 0x0B))[0])
        if bad:
            raise Fail(f"{bad} cycles with a wrong working counter, first at cycle {first_bad[0]}: {first_bad[1]}")
        if slave.state != pysoem.OP_STATE:
            raise Fail(f"left OP during the cycles: {state_name(slave.state)}, code 0x{slave.al_status:04x}")

        reach(master, slave, pysoem.INIT_STATE, 2_000_000, "back to INIT")
        emit("init_again", 1)
    finally:
        master.close()


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iface", default="ecm0")
    p.add_argument("--cycles", type=int, default=1000)
    p.add_argument("--wkc-timeout-us", type=int, default=200_000, help="lock-step: a late answer is not a lost cycle, so wait long (a loaded 2-core CI host can take tens of ms)")
    p.add_argument("--sdo-timeout-us", type=int, default=500_000)
    p.add_argument("--dc", action="store_true", help="DC SYNC0 synchronisation instead of SM-synchronous")
    p.add_argument("--cycle-ns", type=int, default=1_000_000, help="SYNC0 cycle with --dc")
    args = p.parse_args()
    try:
        run(args)
    except Fail as e:
        print(f"verdict=fail {e}", flush=True)
        return 1
    except Exception as e:  # pysoem raises its own errors (SdoError, WkcError, ...): they are the verdict too
        print(f"verdict=fail {type(e).__name__}: {e}", flush=True)
        return 1
    print("verdict=pass", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
