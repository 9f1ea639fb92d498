"""NMT with PyPI canopen against `drive-sim canopen --lock-step`: the boot-up message after reset node and reset
communication, the states the NMT commands move the node through as its heartbeat reports them, and no SDO
answer in stopped (issue 8, "What it must show"; CiA 301 §7.2.8.2.1, §7.3.2).

Figures: `bootup_after_reset_node` / `bootup_after_reset_comm` (the frame seen, `701:00`), `hb_<STATE>` (the
distinct heartbeat state bytes seen after the command but the first, hex), `hb_count_<STATE>` (those
heartbeats in 25 SYNC periods),
`canopen_state_<STATE>` (what canopen's NmtMaster made of them), `stopped_sdo` (`timeout` when canopen raised
SdoCommunicationError), `sdo_after_stopped` (0x1000 read after leaving stopped).
"""

import struct

import canopen

from can_common import Fail, barrier, connect, emit, main, nmt_and_bootup, parser, send_syncs

HEARTBEAT_MS = 10
SYNCS_PER_STATE = 30


def bootup(recorder, node, command, name):
    cob_id, data = nmt_and_bootup(recorder, node, command)
    emit(name, f"{cob_id:03x}:{data.hex()}")


def heartbeats_in(network, recorder, node, command):
    """Sends `command`, then SYNCs (simulated time), and returns the heartbeat state bytes that arrived."""
    mark = recorder.mark()
    node.nmt.state = command
    send_syncs(network, SYNCS_PER_STATE)
    # The last SYNC's period has run when its heartbeats are here: wait for at least two, then a little more
    # for the rest of the burst (the server sends them as soon as each SYNC is done).
    got = recorder.wait(mark, lambda fs: sum(c == 0x700 + node.id for c, _ in fs) >= 3, 3.0)
    if got is None:
        raise Fail(f"fewer than 3 heartbeats after {command}")
    recorder.wait(mark, lambda fs: False, 0.2)
    # The first heartbeat may have been produced while the command was still crossing the bus (the node's
    # heartbeat is due at any slow tick): it is left out.
    return [d[0] for c, d in recorder.since(mark, 0x700 + node.id) if len(d) == 1][1:]


def run(args):
    network, nodes, recorder = connect(args.port, args.eds, [args.node])
    node = nodes[args.node]
    try:
        bootup(recorder, node, "RESET", "bootup_after_reset_node")
        bootup(recorder, node, "RESET COMMUNICATION", "bootup_after_reset_comm")
        node.sdo.download(0x1017, 0, struct.pack("<H", HEARTBEAT_MS))
        emit("heartbeat_time_ms", struct.unpack("<H", node.sdo.upload(0x1017, 0))[0])
        for command in ("PRE-OPERATIONAL", "OPERATIONAL", "STOPPED", "PRE-OPERATIONAL", "OPERATIONAL", "STOPPED",
                        "OPERATIONAL", "PRE-OPERATIONAL"):
            states = heartbeats_in(network, recorder, node, command)
            key = command.replace("-", "_").replace(" ", "_")
            emit(f"hb_{key}", " ".join(sorted({f"{s:02x}" for s in states})))
            emit(f"hb_count_{key}", len(states))
            emit(f"canopen_state_{key}", node.nmt.state.replace(" ", "_"))
            if command == "STOPPED":
                # CiA 301 Table 88: no SDO in stopped. canopen's client waits RESPONSE_TIMEOUT (0.3 s), retries
                # once, then raises.
                try:
                    node.sdo.upload(0x1000, 0)
                    emit("stopped_sdo", "answered")
                except canopen.sdo.exceptions.SdoCommunicationError:
                    emit("stopped_sdo", "timeout")
            else:
                barrier(node)
        emit("sdo_after_stopped", f"0x{struct.unpack('<I', node.sdo.upload(0x1000, 0))[0]:08x}")
    finally:
        network.disconnect()


if __name__ == "__main__":
    main_parser = parser(__doc__)
    import sys

    sys.exit(main(run, main_parser))
