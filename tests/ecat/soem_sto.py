#!/usr/bin/env python3
"""SOEM (PyPI pysoem) with Safe Torque Off active from power-up: the EtherCAT state machine and SDO work, the drive
refuses to be enabled and says why (issue 19 item 1; the field trap of a CiA 402 start-up that stalls on a
de-energised STO input, ros2_canopen#421).

Run by tests/tests/ecat_real_masters.rs in a private network namespace against `drive-sim ethercat --lock-step
--sto-open`. Steps: PRE-OP (config_init); SDO upload of 0x1000 (in lock-step no simulated time has passed yet: the
drive has not run a slow tick, so its state is read in OP); config_map, SAFE-OP, OP; --cycles cycles with the controlword
from the last statusword (0x06, 0x07, 0x0F) and mode 9 (CSV); the statusword from the TxPDO; 0x603F and 0x6041 over
SDO in OP (the CoE emergencies pysoem finds in the mailbox first are recorded); back to INIT.

Figures: `device_type`, `op`, `wkc_errors`, `statusword_end` (TxPDO), `enabled_seen`, `sdo_statusword_op`,
`sdo_error_code_op`, `sdo_error_register_op`, `emcy_codes`, `state_end`.
"""

import argparse
import struct

import pysoem

from soem_common import Fail, emit, go_op, offset_of, open_preop, pdo_layout, reach, run_main, state_name

EMCY = []


def read(slave, index, fmt):
    """An SDO upload of `index`:00; the CoE emergencies pysoem raises first are recorded and the read repeated."""
    for _ in range(8):
        try:
            return struct.unpack(fmt, slave.sdo_read(index, 0))[0]
        except pysoem.Emergency as e:
            EMCY.append(e.error_code)
    raise Fail(f"no answer to {index:04X} after 8 emergencies")


def run(args):
    master, slave = open_preop(args.iface)
    try:
        emit("device_type", f"0x{read(slave, 0x1000, '<I'):08x}")
        outs, ins = pdo_layout(slave, 0x1C12), pdo_layout(slave, 0x1C13)
        cw_at, mode_at, sw_at = offset_of(outs, 0x6040), offset_of(outs, 0x6060), offset_of(ins, 0x6041)
        master.config_map()
        out = bytearray(len(slave.output))
        state = {"cw": 0}

        def outputs():
            struct.pack_into("<H", out, cw_at, state["cw"])
            struct.pack_into("<b", out, mode_at, 9)
            slave.output = bytes(out)

        expected_wkc = go_op(master, slave, outputs, args.wkc_timeout_us)
        statusword, bad, enabled = 0, 0, False
        for _ in range(args.cycles):
            sw = statusword & 0x6F
            state["cw"] = 0x0007 if sw == 0x21 else 0x000F if sw in (0x23, 0x27) else 0x0006
            outputs()
            master.send_processdata()
            if master.receive_processdata(args.wkc_timeout_us) != expected_wkc:
                bad += 1
                continue
            statusword = struct.unpack_from("<H", slave.input, sw_at)[0]
            enabled |= statusword & 0x6F == 0x27
        emit("wkc_errors", bad)
        emit("statusword_end", f"0x{statusword:04x}")
        emit("enabled_seen", int(enabled))
        emit("sdo_statusword_op", f"0x{read(slave, 0x6041, '<H'):04x}")
        emit("sdo_error_code_op", f"0x{read(slave, 0x603F, '<H'):04x}")
        emit("sdo_error_register_op", f"0x{read(slave, 0x1001, '<B'):02x}")
        emit("emcy_codes", " ".join(f"{c:04x}" for c in EMCY))
        master.read_state()
        emit("state_end", state_name(slave.state))
        if bad:
            raise Fail(f"{bad} cycles with a wrong working counter")
        reach(master, slave, pysoem.INIT_STATE, 2_000_000, "back to INIT")
        emit("init_again", 1)
    finally:
        master.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iface", default="ecm0")
    p.add_argument("--cycles", type=int, default=500)
    p.add_argument("--wkc-timeout-us", type=int, default=200_000)
    run_main(run, p)
