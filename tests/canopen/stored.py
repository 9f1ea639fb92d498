"""Saved communication parameters with PyPI canopen against `drive-sim canopen --lock-step --sync-us 10000`, as a
new user tries them: set the heartbeat time 0x1017, the EMCY inhibit time 0x1015, the configuration date 0x1020:01
and TPDO 1's event timer 0x1800:05, save them with `RemoteNode.store()` (0x1010:01 "save"), change them again
without saving, then reset node and reset communication: both bring back the saved values (CiA 301 §7.3.2: the
resets load the power-on values; §7.5.2.13: saved values are the power-on values), and the heartbeat runs with
them. Then "save communication parameters" alone (0x1010:02) and "restore default parameters" of the
communication group (0x1011:02) followed by a reset communication (§7.5.2.14).

Figures: `<name>_after_node` / `<name>_after_comm` (each parameter read back after the reset), `heartbeats_after_node` /
`heartbeats_after_comm` (heartbeats in 100 SYNC periods of 10 ms, i.e. 1 s of simulated time), `hb_after_save_comm`
(0x1017 after 0x1010:02 and a reset communication), `<name>_after_restore` (after 0x1011:02 and a reset
communication).
"""

import struct

from can_common import Fail, barrier, connect, emit, main, nmt_and_bootup, parser, send_syncs

# (name, index, sub, struct format, value to save)
PARAMETERS = [
    ("heartbeat_ms", 0x1017, 0, "<H", 150),
    ("emcy_inhibit", 0x1015, 0, "<H", 7),
    ("verify_date", 0x1020, 1, "<I", 15000),
    ("tpdo1_event_timer", 0x1800, 5, "<H", 200),
]
SYNCS_PER_SECOND = 100


def reset(recorder, node, command):
    _, data = nmt_and_bootup(recorder, node, command)
    if data != b"\x00":
        raise Fail(f"boot-up after {command} carried {data.hex()}, not 00")


def read(node, index, sub, fmt):
    return struct.unpack(fmt, node.sdo.upload(index, sub))[0]


def run(args):
    network, nodes, recorder = connect(args.port, args.eds, [args.node])
    node = nodes[args.node]
    try:
        for _, index, sub, fmt, value in PARAMETERS:
            node.sdo.download(index, sub, struct.pack(fmt, value))
        node.store(1)
        for _, index, sub, fmt, value in PARAMETERS:
            node.sdo.download(index, sub, struct.pack(fmt, value + 1))
        for command, key in (("RESET", "node"), ("RESET COMMUNICATION", "comm")):
            reset(recorder, node, command)
            for name, index, sub, fmt, _ in PARAMETERS:
                emit(f"{name}_after_{key}", read(node, index, sub, fmt))
            mark = recorder.mark()
            send_syncs(network, SYNCS_PER_SECOND)
            barrier(node)
            emit(f"heartbeats_after_{key}", len(recorder.since(mark, 0x700 + node.id)))
        node.sdo.download(0x1017, 0, struct.pack("<H", 100))
        node.store(2)
        reset(recorder, node, "RESET COMMUNICATION")
        emit("hb_after_save_comm", read(node, 0x1017, 0, "<H"))
        node.restore(2)
        reset(recorder, node, "RESET COMMUNICATION")
        for name, index, sub, fmt, _ in PARAMETERS:
            emit(f"{name}_after_restore", read(node, index, sub, fmt))
    finally:
        network.disconnect()


if __name__ == "__main__":
    import sys

    sys.exit(main(run, parser(__doc__)))
