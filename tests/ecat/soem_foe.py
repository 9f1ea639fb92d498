#!/usr/bin/env python3
"""A firmware update over FoE with SOEM (PyPI pysoem) against `drive-sim ethercat` (issue 7, "What it must
show": an update end to end over FoE with a real master; a refusal with the old firmware still running).

Run by tests/tests/boot_real_master.rs inside a private network namespace (see tests/src/real_master.rs). The
sequence is the seeds' (E4 Table 4-29 L2095-2130: request BOOT, FoE write of the file "EPOS4" with password 0,
request INIT, the drive reboots), done the way SOEM's firmware-update example does it:
1. config_init, PRE-OP; the factory image's identification: 0x1F56:01 and 0x100A over SDO.
2. INIT; the bootstrap mailbox from the SII (words 0x14..0x17, ETG.1000.6 Table 16) written into SM0/SM1
   (`amend_mbx`), then BOOT.
3. `foe_write("EPOS4", 0, image)`, timed; SOEM returns a negative value when the drive answers with an FoE error
   (the code itself is in the capture the Rust test decodes: SOEM does not hand it out).
4. INIT (leaving BOOT ends the download: a complete image resets the drive into it, anything else starts the old
   application again), then a fresh master: config_init, PRE-OP, 0x1F56:01, 0x100A, 0x1F51:01, 0x1F57:01.
5. "The drive runs normally": SAFE-OP, OP, --cycles cycles of process data in CSP holding the position, the
   controlword walking the CiA 402 state machine (0x06, 0x07, 0x0F) until «Operation enabled», every working
   counter right; back to INIT.
Every figure is a `key=value` line; the last line is the verdict (soem_common.py).
"""

import argparse
import struct
import time

import pysoem
from soem_common import Fail, emit, go_op, offset_of, open_preop, pdo_layout, reach, run_main, state_name, u

FILE_NAME = "EPOS4"  # firmware::boot::program::FOE_FILE_NAME
PASSWORD = 0  # firmware::boot::program::FOE_PASSWORD


def identification(slave, tag):
    """0x1F56:01 (software id), 0x100A (version string), 0x1F51:01 (program state), 0x1F57:01 (flash status)."""
    emit(f"sw_id_{tag}", f"0x{u(slave, 0x1F56, 1, '<I'):08x}")
    emit(f"version_{tag}", slave.sdo_read(0x100A, 0).decode("ascii", "replace").rstrip("\x00"))
    emit(f"program_state_{tag}", slave.sdo_read(0x1F51, 1)[0])
    emit(f"flash_status_{tag}", int.from_bytes(slave.sdo_read(0x1F57, 1), "little"))


def enter_boot(master, slave):
    """INIT, the SII's bootstrap mailbox into SM0/SM1, BOOT (SOEM's firmware-update example)."""
    reach(master, slave, pysoem.INIT_STATE, 2_000_000, "INIT before BOOT")
    rx = slave.eeprom_read(0x14)  # bootstrap receive mailbox (master -> slave): offset, size
    tx = slave.eeprom_read(0x16)  # bootstrap send mailbox (slave -> master): offset, size
    rx_at, rx_len = struct.unpack("<HH", rx)
    tx_at, tx_len = struct.unpack("<HH", tx)
    emit("sii_boot_rx", f"0x{rx_at:04x}/{rx_len}")
    emit("sii_boot_tx", f"0x{tx_at:04x}/{tx_len}")
    if rx_len < 16 or tx_len < 16:
        raise Fail(f"no bootstrap mailbox in the SII: rx {rx_at:#x}/{rx_len}, tx {tx_at:#x}/{tx_len}")
    slave.amend_mbx("out", rx_at, rx_len)
    slave.amend_mbx("in", tx_at, tx_len)
    slave.state = pysoem.BOOT_STATE
    slave.write_state()
    if slave.state_check(pysoem.BOOT_STATE, 3_000_000) != pysoem.BOOT_STATE:
        master.read_state()
        raise Fail(f"BOOT not reached: {state_name(slave.state)}, AL status code 0x{slave.al_status:04x}")
    emit("boot", 1)
    return rx_len


def run_normally(master, slave, cycles, wkc_timeout_us):
    """OP in CSP holding the position, the controlword up to «Operation enabled», `cycles` cycles."""
    outs, ins = pdo_layout(slave, 0x1C12), pdo_layout(slave, 0x1C13)
    cw_at, mode_at, target_at = offset_of(outs, 0x6040), offset_of(outs, 0x6060), offset_of(outs, 0x607A)
    sw_at = offset_of(ins, 0x6041)
    master.config_map()
    out = bytearray(len(slave.output))
    state = {"cw": 0, "target": u(slave, 0x6064, 0, "<i")}

    def outputs():
        struct.pack_into("<H", out, cw_at, state["cw"])
        struct.pack_into("<b", out, mode_at, 8)
        struct.pack_into("<i", out, target_at, state["target"])
        slave.output = bytes(out)

    expected_wkc = go_op(master, slave, outputs, wkc_timeout_us)
    emit("expected_wkc", expected_wkc)
    statusword, enabled_at, bad = 0, None, 0
    for k in range(cycles):
        sw = statusword & 0x6F
        state["cw"] = 0x0007 if sw == 0x21 else 0x000F if sw in (0x23, 0x27) else 0x0006
        if sw == 0x27 and enabled_at is None:
            enabled_at = k
        outputs()
        master.send_processdata()
        if master.receive_processdata(wkc_timeout_us) != expected_wkc:
            bad += 1
            continue
        statusword = struct.unpack_from("<H", slave.input, sw_at)[0]
    emit("cycles", cycles)
    emit("wkc_errors", bad)
    emit("enabled_at_cycle", enabled_at)
    emit("statusword_end", f"0x{statusword:04x}")
    master.read_state()
    emit("state_after_cycles", state_name(slave.state))
    if enabled_at is None:
        raise Fail(f"«Operation enabled» never seen (statusword 0x{statusword:04x})")
    reach(master, slave, pysoem.INIT_STATE, 2_000_000, "INIT at the end")


def run(args):
    with open(args.image, "rb") as f:
        image = f.read()
    master, slave = open_preop(args.iface)
    try:
        identification(slave, "before")
        mailbox = enter_boot(master, slave)
        # SOEM's FoE write sends mailbox size - 12 bytes per packet (mailbox and FoE headers, 6 + 6).
        per_packet = mailbox - 12
        emit("foe_bytes", len(image))
        emit("foe_packets", -(-len(image) // per_packet))
        started = time.monotonic()
        rc = slave.foe_write(FILE_NAME, PASSWORD, image, args.foe_timeout_us)
        emit("foe_write_s", f"{time.monotonic() - started:.3f}")
        emit("foe_write_rc", rc)
        if args.expect == "accept" and rc <= 0:
            raise Fail(f"foe_write refused: SOEM returned {rc}")
        if args.expect == "refuse" and rc > 0:
            raise Fail(f"foe_write of a bad image accepted (SOEM returned {rc})")
        reach(master, slave, pysoem.INIT_STATE, 3_000_000, "INIT after BOOT")
        emit("init_after_boot", 1)
    finally:
        master.close()

    # The drive restarted (or its application resumed) from INIT: a fresh master finds it again, as a master does
    # after a firmware update (config_init appends to pysoem's slave list, so a new Master, not a second call).
    master, slave = open_preop(args.iface)
    try:
        emit("found_again", 1)
        identification(slave, "after")
        run_normally(master, slave, args.cycles, args.wkc_timeout_us)
    finally:
        master.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iface", required=True)
    p.add_argument("--image", required=True, help="the signed image file to write")
    p.add_argument("--expect", choices=["accept", "refuse"], required=True)
    p.add_argument("--cycles", type=int, default=500)
    p.add_argument("--foe-timeout-us", type=int, default=2_000_000)
    p.add_argument("--wkc-timeout-us", type=int, default=100_000)
    run_main(run, p)
