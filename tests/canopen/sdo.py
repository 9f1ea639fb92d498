"""SDO with PyPI canopen against `drive-sim canopen --lock-step` (issue 8, "What it must show").

--part objects: every readable entry listed in --expect (lines `IIII SS rule hexvalue size name`, written by
tests/tests/canopen_real_master.rs from the dictionary) is uploaded with `node.sdo.upload` and compared by the
rule: `exact` byte for byte, `len` by length only (measured values), `abort` the abort code.

--part transfers: expedited, segmented and block transfers both ways through canopen's client, then the abort
codes for bad requests (canopen's client where it can make the request, hand-made frames where it cannot:
toggle error, block CRC error, the server timeout).

Figures: see `emit` calls; every abort as `abort_<case>=0x........` (`none` when the request was accepted).
"""

import struct

import canopen

from can_common import (Fail, abort_code, barrier, connect, emit, int0, main, parser, sdo_raw,
                        send_syncs)

Aborted = canopen.sdo.exceptions.SdoAbortedError


def upload(node, index, sub):
    try:
        return node.sdo.upload(index, sub), None
    except Aborted as e:
        return None, e.code


def download_code(node, index, sub, data, **kw):
    try:
        node.sdo.download(index, sub, data, **kw)
        return "none"
    except Aborted as e:
        return f"0x{e.code:08x}"


def part_objects(args, node):
    counts = {"exact": 0, "len": 0, "abort": 0}
    mismatches = []
    read = longer = 0
    with open(args.expect) as f:
        lines = [line.split(" ", 5) for line in f if line.strip()]
    for index, sub, rule, value, size, name in lines:
        index, sub, size = int(index, 16), int(sub, 16), int(size)
        got, code = upload(node, index, sub)
        read += 1
        if rule == "abort":
            ok = code == int(value, 16)
        elif got is None:
            ok = False
        elif rule == "len":
            ok = len(got) == size
        else:
            ok = got.hex() == value
        longer += int(got is not None and len(got) > 4)
        counts[rule] += int(ok)
        if not ok:
            seen = got.hex() if got is not None else f"abort {code:08x}"
            mismatches.append(f"{index:04X}:{sub:02X}({rule} want {value} got {seen})")
    emit("objects_read", read)
    for rule, n in counts.items():
        emit(f"objects_{rule}", n)
    emit("objects_longer_than_4", longer)
    emit("objects_mismatches", len(mismatches))
    emit("objects_mismatch_list", " ".join(mismatches[:20]))


def part_transfers(args, network, node, recorder):
    nid = node.id
    # Expedited both ways.
    emit("exp_upload_1000", f"0x{struct.unpack('<I', node.sdo.upload(0x1000, 0))[0]:08x}")
    node.sdo.download(0x1017, 0, struct.pack("<H", 250))
    emit("exp_download_1017", struct.unpack("<H", node.sdo.upload(0x1017, 0))[0])
    node.sdo.download(0x1017, 0, struct.pack("<H", 0))
    # Segmented both ways: 0x1009 is 23 bytes (no expedited upload); the download is forced segmented.
    emit("seg_upload_1009", node.sdo.upload(0x1009, 0).decode("ascii"))
    node.sdo.download(0x607A, 0, struct.pack("<i", -123_456), force_segment=True)
    emit("seg_download_607a", struct.unpack("<i", node.sdo.upload(0x607A, 0))[0])
    # Block both ways (with CRC; canopen asks for it by default).
    with node.sdo.open(0x1009, 0, "rb", block_transfer=True) as f:
        emit("block_upload_1009", f.read().decode("ascii"))
    with node.sdo.open(0x1008, 0, "rb", block_transfer=True) as f:
        emit("block_upload_1008", f.read().decode("ascii"))
    with node.sdo.open(0x607A, 0, "wb", size=4, block_transfer=True) as f:
        f.write(struct.pack("<i", 654_321))
    emit("block_download_607a", struct.unpack("<i", node.sdo.upload(0x607A, 0))[0])

    # Aborts through canopen's client.
    emit("abort_missing_object", f"0x{upload(node, 0x1234, 0)[1] or 0:08x}")
    emit("abort_missing_sub", f"0x{upload(node, 0x1018, 0x09)[1] or 0:08x}")
    emit("abort_wrong_size_long", download_code(node, 0x1017, 0, struct.pack("<I", 100)))
    emit("abort_wrong_size_short", download_code(node, 0x1006, 0, struct.pack("<H", 100)))
    emit("abort_read_only", download_code(node, 0x1000, 0, struct.pack("<I", 1)))
    emit("abort_value_range", download_code(node, 0x1400, 2, b"\xf5"))
    emit("abort_mapping_of_valid_pdo", download_code(node, 0x1600, 0, b"\x00"))
    node.nmt.state = "OPERATIONAL"
    barrier(node)
    node.sdo.download(0x1400, 1, struct.pack("<I", 0x8000_0200 + nid))
    emit("abort_mapping_in_operational", download_code(node, 0x1600, 0, b"\x00"))
    node.sdo.download(0x1400, 1, struct.pack("<I", 0x0000_0200 + nid))
    node.nmt.state = "PRE-OPERATIONAL"
    barrier(node)

    # Hand-made frames: a segmented download of 4 bytes to 0x607A (CiA 301 §7.2.4.3.3), its first segment with
    # the toggle bit set (it must be clear): 0x0503_0000.
    init = [0x21, 0x7A, 0x60, 0x00, 4, 0, 0, 0]
    ack = sdo_raw(network, recorder, nid, init)
    emit("toggle_initiate_answer", ack.hex() if ack else "none")
    emit("abort_toggle", f"0x{abort_code(sdo_raw(network, recorder, nid, [0x17, 1, 2, 3, 4, 0, 0, 0])) or 0:08x}")
    # Block download of 4 bytes with CRC (CiA 301 §7.2.4.3.9): initiate, one last segment, the end with a wrong
    # CRC: 0x0504_0004.
    ack = sdo_raw(network, recorder, nid, [0xC6, 0x7A, 0x60, 0x00, 4, 0, 0, 0])
    emit("block_initiate_answer", ack.hex() if ack else "none")
    ack = sdo_raw(network, recorder, nid, [0x81, 9, 9, 9, 9, 0, 0, 0])
    emit("block_segment_answer", ack.hex() if ack else "none")
    crc_right = crc16(bytes([9, 9, 9, 9]))
    end = [0xC1 | (3 << 2), (crc_right ^ 0x5A5A) & 0xFF, (crc_right ^ 0x5A5A) >> 8, 0, 0, 0, 0, 0]
    emit("abort_block_crc", f"0x{abort_code(sdo_raw(network, recorder, nid, end)) or 0:08x}")
    emit("after_block_crc_607a", struct.unpack("<i", node.sdo.upload(0x607A, 0))[0])

    # The server timeout: a segmented download initiated and then left alone. Time passes in lock-step only
    # with frames, so SYNCs (1 ms each, no answer in pre-operational) carry it; the abort's simulated time
    # minus the initiate answer's is the timeout.
    mark = recorder.mark()
    ack = sdo_raw(network, recorder, nid, init)
    emit("timeout_initiate_answer", ack.hex() if ack else "none")
    send_syncs(network, args.timeout_syncs)
    got = recorder.wait(mark, lambda fs: sum(c == 0x580 + nid for c, _ in fs) >= 2, 20.0)
    if got is None:
        raise Fail("no abort within the SYNCs sent")
    answers = recorder.timed_since(mark, 0x580 + nid)
    emit("abort_timeout", f"0x{abort_code(answers[1][2]) or 0:08x}")
    emit("timeout_s", f"{answers[1][0] - answers[0][0]:.6f}")
    barrier(node)
    emit("sdo_after_aborts", f"0x{struct.unpack('<I', node.sdo.upload(0x1000, 0))[0]:08x}")


def crc16(data):
    """CRC-16-CCITT (polynomial 0x1021, initial 0), the block transfer's CRC (CiA 301 §7.2.4.3.16)."""
    crc = 0
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021 if crc & 0x8000 else crc << 1) & 0xFFFF
    return crc


def run(args):
    network, nodes, recorder = connect(args.port, args.eds, [args.node])
    node = nodes[args.node]
    try:
        if args.part == "objects":
            part_objects(args, node)
        else:
            part_transfers(args, network, node, recorder)
    finally:
        network.disconnect()


if __name__ == "__main__":
    p = parser(__doc__)
    p.add_argument("--part", choices=("objects", "transfers"), required=True)
    p.add_argument("--expect")
    p.add_argument("--timeout-syncs", type=int, default=1_200)
    import sys

    sys.exit(main(run, p))
