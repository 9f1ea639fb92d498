"""Safe Torque Off at power-up with PyPI canopen against `drive-sim canopen --lock-step --sto-open 1` (issue 19
item 1; the field trap of a CiA 402 start-up that stalls on a de-energised STO input, ros2_canopen#421): NMT and
SDO work, the drive refuses to be enabled and says why.

Steps: reset node (the drive restarts with its STO inputs still de-energised) and the boot-up; the EMCYs that
follow it; SDO uploads of 0x1000, 0x6041, 0x603F and 0x1001 in PRE-OPERATIONAL; NMT Start with the heartbeat
(0x1017 = 10 ms) reporting the state; «Shutdown», «Switch on», «Enable operation» written to 0x6040 by SDO, 20
SYNC periods after each, the statusword read back.

Figures: `bootup` (`701:00`), `emcy_codes` (the EMCY error codes after the boot-up, hex), `device_type`,
`statusword_preop`, `error_code_preop`, `error_register_preop`, `hb_after_start` (heartbeat state bytes after
NMT Start but the first), `statusword_after_<cw>` for cw 0006/0007/000f, `error_code_end`.
"""

import struct

from can_common import Fail, connect, emit, main, nmt_and_bootup, parser, send_syncs

HEARTBEAT_MS = 10


def u16(node, index):
    return struct.unpack("<H", node.sdo.upload(index, 0)[:2])[0]


def run(args):
    network, nodes, recorder = connect(args.port, args.eds, [args.node])
    node = nodes[args.node]
    try:
        mark = recorder.mark()
        cob_id, data = nmt_and_bootup(recorder, node, "RESET")
        emit("bootup", f"{cob_id:03x}:{data.hex()}")
        # The EMCY of the STO state leaves right after the boot-up (PRE-OPERATIONAL may send EMCY, CiA 301 Table
        # 88); an SDO answer is a barrier for it (can_common).
        emit("device_type", f"0x{struct.unpack('<I', node.sdo.upload(0x1000, 0))[0]:08x}")
        emcy = [struct.unpack("<H", d[:2])[0] for c, d in recorder.since(mark, 0x80 + node.id) if len(d) == 8]
        emit("emcy_codes", " ".join(f"{c:04x}" for c in emcy))
        emit("statusword_preop", f"0x{u16(node, 0x6041):04x}")
        emit("error_code_preop", f"0x{u16(node, 0x603F):04x}")
        emit("error_register_preop", f"0x{node.sdo.upload(0x1001, 0)[0]:02x}")

        node.sdo.download(0x1017, 0, struct.pack("<H", HEARTBEAT_MS))
        mark = recorder.mark()
        node.nmt.state = "OPERATIONAL"
        send_syncs(network, 30)
        got = recorder.wait(mark, lambda fs: sum(c == 0x700 + node.id for c, _ in fs) >= 3, 3.0)
        if got is None:
            raise Fail("fewer than 3 heartbeats after NMT Start")
        states = [d[0] for c, d in recorder.since(mark, 0x700 + node.id) if len(d) == 1][1:]
        emit("hb_after_start", " ".join(sorted({f"{s:02x}" for s in states})))

        for cw in (0x0006, 0x0007, 0x000F):
            node.sdo.download(0x6040, 0, struct.pack("<H", cw))
            send_syncs(network, 20)
            emit(f"statusword_after_{cw:04x}", f"0x{u16(node, 0x6041):04x}")
        emit("error_code_end", f"0x{u16(node, 0x603F):04x}")
    finally:
        network.disconnect()


if __name__ == "__main__":
    import sys

    sys.exit(main(run, parser(__doc__)))
