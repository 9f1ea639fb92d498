"""Bad frames through socketcand against `drive-sim canopen` in real time (issue 8, "What it must show"): wrong
DLC, unknown COB-IDs, SDO sequence errors, frames in stopped and during a reset node; after each the node must
answer correctly (an SDO upload of 0x1000 through canopen's client).

Real time, not lock-step: in lock-step the runner finishes a reset before it takes the next frame, so no frame
can arrive during the reset. Here a second socketcand client (a plain TCP socket) writes an NMT reset node and
--burst SDO requests in one write: the server puts them on the bus at one instant, back to back (about 130 us
each at 1 Mbit/s), and the node's initialisation (from the slow tick that carries the reset out to the one that
boots, 400 us) falls inside the burst whatever the slow tick's phase.

Figures: `<case>_answer` (`none` or the answer's hex), `<case>_abort`, `after_<case>` (0x1000 read after it),
`burst_*`.
"""

import socket
import struct
import time

from can_common import abort_code, connect, emit, main, parser, sdo_raw

DEVICE_TYPE_UPLOAD = [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]


def answer_text(a):
    return a.hex() if a is not None else "none"


def after(node, case):
    emit(f"after_{case}", f"0x{struct.unpack('<I', node.sdo.upload(0x1000, 0))[0]:08x}")


def silent(network, recorder, node_id, cob_id, data, wait=0.3):
    """Sends one frame and returns how many frames the node sent in the next `wait` s."""
    mark = recorder.mark()
    network.send_message(cob_id, bytes(data))
    time.sleep(wait)
    return sum(1 for c, _ in recorder.since(mark) if c & 0x7F == node_id)


def raw_client(port):
    """A second socketcand client: greeting, open, rawmode (each answer read alone, as python-can does)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=2.0)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    for expect, send in ((b"< hi >", b"< open can0 >"), (b"< ok >", b"< rawmode >"), (b"< ok >", None)):
        got = s.recv(256)
        if got.strip() != expect:
            raise RuntimeError(f"socketcand handshake: {got!r}, wanted {expect!r}")
        if send:
            s.sendall(send)
    return s


def run(args):
    nid = args.node
    network, nodes, recorder = connect(args.port, args.eds, [nid])
    node = nodes[nid]
    try:
        after(node, "start")
        # Wrong DLC: an SDO request of 5 bytes, an NMT command of 3 and of 1 byte (stop: obeyed, the SDO below
        # would not be answered).
        emit("sdo_dlc5_answer", answer_text(sdo_raw(network, recorder, nid, DEVICE_TYPE_UPLOAD[:5], 0.3)))
        after(node, "sdo_dlc5")
        network.send_message(0x000, bytes([0x02, nid, 0]))
        network.send_message(0x000, bytes([0x02]))
        after(node, "nmt_wrong_dlc")
        # Unknown COB-IDs (nobody's, another node's SDO, the SDO COB-ID of node 0, LSS, a TPDO's COB-ID).
        unknown = 0
        for cob_id in (0x123, 0x602, 0x600, 0x7E5, 0x181, 0x7FF):
            unknown += silent(network, recorder, nid, cob_id, DEVICE_TYPE_UPLOAD, 0.2)
        emit("unknown_cob_id_frames_from_node", unknown)
        after(node, "unknown_cob_ids")
        # SDO sequence errors: segments and block requests with no transfer in progress, then an upload segment
        # with the wrong toggle in a segmented upload of 0x1009.
        for case, req in (("upload_segment_idle", [0x60] + [0] * 7), ("download_segment_idle", [0x00] + [0] * 7),
                          ("block_upload_start_idle", [0xA3] + [0] * 7),
                          ("block_download_end_idle", [0xC1] + [0] * 7)):
            a = sdo_raw(network, recorder, nid, req)
            emit(f"{case}_answer", answer_text(a))
            emit(f"{case}_abort", f"0x{abort_code(a) or 0:08x}")
        a = sdo_raw(network, recorder, nid, [0x40, 0x09, 0x10, 0x00, 0, 0, 0, 0])
        emit("seg_upload_initiate_answer", answer_text(a))
        a = sdo_raw(network, recorder, nid, [0x70] + [0] * 7)
        emit("upload_toggle_abort", f"0x{abort_code(a) or 0:08x}")
        after(node, "sequence_errors")
        # Stopped: an SDO request, an RPDO and a SYNC get nothing; back in pre-operational the SDO answers.
        network.send_message(0x000, bytes([0x02, nid]))
        time.sleep(0.05)
        emit("stopped_sdo_answer", answer_text(sdo_raw(network, recorder, nid, DEVICE_TYPE_UPLOAD, 0.3)))
        emit("stopped_rpdo_frames", silent(network, recorder, nid, 0x200 + nid, [0x06, 0, 1, 2, 3, 4], 0.1))
        emit("stopped_sync_frames", silent(network, recorder, nid, 0x080, [], 0.1))
        network.send_message(0x000, bytes([0x80, nid]))
        time.sleep(0.05)
        after(node, "stopped")
        # During a reset node: one write with the NMT command and the SDO burst.
        s = raw_client(args.port)
        mark = recorder.mark()
        burst = f"< send 000 2 81 {nid:x} >" + f"< send {0x600 + nid:03x} 8 40 0 10 0 0 0 0 0 >" * args.burst
        s.sendall(burst.encode("ascii"))
        time.sleep(0.5)
        s.close()
        frames = recorder.since(mark)
        boot = [k for k, (c, d) in enumerate(frames) if c == 0x700 + nid and d == b"\x00"]
        answers = [(k, d) for k, (c, d) in enumerate(frames) if c == 0x580 + nid]
        emit("burst_sent", args.burst)
        emit("burst_bootups", len(boot))
        emit("burst_answers", len(answers))
        emit("burst_answers_after_bootup", sum(1 for k, _ in answers if boot and k > boot[0]))
        emit("burst_answers_wrong", sum(1 for _, d in answers if d[:4] != bytes([0x43, 0x00, 0x10, 0x00])))
        after(node, "reset")
    finally:
        network.disconnect()


if __name__ == "__main__":
    p = parser(__doc__)
    p.add_argument("--burst", type=int, default=20)
    import sys

    sys.exit(main(run, p))
