"""What the SOEM (PyPI pysoem) scripts under tests/ecat/ share: the verdict protocol, finding the drive and
taking it to PRE-OP, SDO helpers that return the abort code instead of raising, and OP with the process image.

Every script prints one `key=value` line per figure and as its last line `verdict=pass` or `verdict=fail
<reason>`; tests/tests/ecat_real_masters.rs judges the figures (facts: shared/spec/fieldbus-real-masters.md).
"""

import struct
import sys
import time

import pysoem

STATE_NAMES = {
    pysoem.NONE_STATE: "NONE",
    pysoem.INIT_STATE: "INIT",
    pysoem.PREOP_STATE: "PREOP",
    pysoem.BOOT_STATE: "BOOT",
    pysoem.SAFEOP_STATE: "SAFEOP",
    pysoem.OP_STATE: "OP",
}


class Fail(Exception):
    """A check failed: the reason is the verdict."""


def state_name(code):
    base = STATE_NAMES.get(code & 0x0F, f"0x{code & 0x0F:02x}")
    return base + ("+ERROR" if code & pysoem.STATE_ERROR else "")


def emit(key, value):
    print(f"{key}={value}", flush=True)


def reach(master, slave, state, timeout_us, what):
    """Requests `state` for all slaves and waits for it; the AL status code explains a refusal."""
    master.state = state
    master.write_state()
    reached = master.state_check(state, timeout_us)
    if reached != state:
        master.read_state()
        raise Fail(
            f"{what}: slave in {state_name(slave.state)}, AL status code 0x{slave.al_status:04x} "
            f"(wanted {state_name(state)})"
        )


def open_preop(iface, sdo_timeout_us=500_000):
    """Opens the master on `iface`, finds exactly one slave with a real identity and checks PRE-OP (which
    config_init requests). Returns (master, slave); the caller closes the master."""
    master = pysoem.Master()
    master.sdo_read_timeout = sdo_timeout_us
    master.sdo_write_timeout = sdo_timeout_us
    master.open(iface)
    found = master.config_init()
    emit("slaves_found", found)
    if found != 1:
        master.close()
        raise Fail(f"config_init found {found} slaves, expected 1")
    slave = master.slaves[0]
    if slave.man == 0 and slave.id == 0:
        master.close()
        raise Fail("all-zero identity: the slave answered only broadcasts")
    if master.state_check(pysoem.PREOP_STATE, 2_000_000) != pysoem.PREOP_STATE:
        master.read_state()
        master.close()
        raise Fail(f"PRE-OP not reached: {state_name(slave.state)}, AL status code 0x{slave.al_status:04x}")
    emit("preop", 1)
    return master, slave


def abort_of(e):
    """The SDO abort code of a pysoem SdoError."""
    return getattr(e, "abort_code", None)


def sdo_read(slave, index, sub, size=0):
    """(value bytes, None) or (None, abort code)."""
    try:
        if size:
            return slave.sdo_read(index, sub, size), None
        return slave.sdo_read(index, sub), None
    except pysoem.SdoError as e:
        return None, abort_of(e)


def sdo_write(slave, index, sub, data):
    """None when accepted, else the abort code."""
    try:
        slave.sdo_write(index, sub, data)
        return None
    except pysoem.SdoError as e:
        return abort_of(e)


def write_checked(slave, index, sub, data):
    """An SDO download that must be accepted."""
    code = sdo_write(slave, index, sub, data)
    if code is not None:
        raise Fail(f"download {index:04X}:{sub:02X} = {data.hex()} refused with 0x{code:08x}")


def u(slave, index, sub, fmt):
    """An SDO upload unpacked with struct format `fmt`."""
    return struct.unpack(fmt, slave.sdo_read(index, sub))[0]


def go_op(master, slave, outputs, wkc_timeout_us):
    """SAFE-OP (unless the caller already asked for it), valid outputs, OP; returns the expected working
    counter. `outputs` fills the output image before each frame."""
    expected_wkc = master.expected_wkc
    reach(master, slave, pysoem.SAFEOP_STATE, 2_000_000, "SAFE-OP")
    emit("safeop", 1)
    outputs()
    master.send_processdata()
    master.receive_processdata(wkc_timeout_us)
    master.state = pysoem.OP_STATE
    master.write_state()
    for _ in range(400):
        outputs()
        master.send_processdata()
        master.receive_processdata(wkc_timeout_us)
        if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
            emit("op", 1)
            return expected_wkc
    master.read_state()
    raise Fail(f"OP not reached: {state_name(slave.state)}, AL status code 0x{slave.al_status:04x}")


def pdo_layout(slave, assign):
    """[(index, sub, bits, byte offset)] of the objects the assignment `assign` (0x1C12/0x1C13) maps, read over
    SDO as SOEM's config_map does (CiA 301 mapping entries: index << 16 | sub << 8 | bits)."""
    layout = []
    bit = 0
    for k in range(1, u(slave, assign, 0, "<B") + 1):
        pdo = u(slave, assign, k, "<H")
        for j in range(1, u(slave, pdo, 0, "<B") + 1):
            entry = u(slave, pdo, j, "<I")
            index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            layout.append((index, sub, bits, bit // 8))
            bit += bits
    return layout


def offset_of(layout, index):
    for i, _, _, off in layout:
        if i == index:
            return off
    raise Fail(f"{index:04X} is not mapped")


def main(run, parser):
    """Parses the arguments, runs `run(args)` and prints the verdict; the exit status says it too."""
    args = parser.parse_args()
    started = time.monotonic()
    try:
        run(args)
    except Fail as e:
        print(f"verdict=fail {e}", flush=True)
        return 1
    except Exception as e:  # pysoem raises its own errors (SdoError, WkcError, ...): they are the verdict too
        print(f"verdict=fail {type(e).__name__}: {e}", flush=True)
        return 1
    finally:
        emit("script_s", f"{time.monotonic() - started:.3f}")
    print("verdict=pass", flush=True)
    return 0


def run_main(run, parser):
    sys.exit(main(run, parser))
