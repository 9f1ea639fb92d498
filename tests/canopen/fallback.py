#!/usr/bin/env python3
"""Recovering a drive in the bootloader's CAN fallback with PyPI canopen (issue 7, item 4).

Run by tests/tests/boot_fallback.rs against `drive-sim canopen --no-image 1 --lock-step`: node 1's slot A is erased,
so its bootloader found no valid image and answers on the bus with its own compact service
(firmware/src/boot/fallback.rs). The script checks what the fallback shows (boot-up after an NMT reset node,
device type 0x0000012E, 0x1F51:01 = 3 "no program", 0x1F56:01, 0x1F57:01, no application objects) and what it
refuses (0x1F50 before clear, a corrupted image), then loads the signed image into 0x1F50:01 by SDO block
download with its CRC (clear first), starts it, waits for the application's boot-up, reads 0x1F56:01, 0x100A and
0x1000 of the new image and enables the drive by controlword (SYNCs give the offset calibration its time in
lock-step). Prints one figure per line and the verdict.
"""

import sys
import time

import canopen

from can_common import Fail, barrier, connect, emit, main, parser, send_syncs


def u32(node, index, sub):
    """An unsigned value of up to 4 bytes (0x1F51 is UNSIGNED8, 0x1000/0x1F56/0x1F57 UNSIGNED32)."""
    return int.from_bytes(node.sdo.upload(index, sub)[:4], "little")


def abort_of(action):
    """Runs `action`; returns the SDO abort code it raised as 0x%08x, or "none"."""
    try:
        action()
    except canopen.SdoAbortedError as e:
        return f"0x{e.code:08x}"
    return "none"


def first_abort(recorder, node_id, action):
    """Runs `action` (a transfer the node refuses); returns the first abort code the node sent during it, and the
    one canopen raised. They can differ: canopen writes through an io.BufferedWriter whose close() (the `with`
    exit) flushes one more segment after the refusal; the server, whose transfer the abort ended, answers that
    stray segment with 0x05040001, and that exception replaces the first."""
    mark = recorder.mark()
    raised = abort_of(action)
    answers = recorder.since(mark, 0x580 + node_id)
    sent = next((f"0x{int.from_bytes(d[4:8], 'little'):08x}" for _, d in answers if d[0] == 0x80), "none")
    return sent, raised


def block_download(node, data):
    with node.sdo.open(0x1F50, 1, "wb", size=len(data), block_transfer=True) as f:
        f.write(data)


def wait_bootup(recorder, mark, node_id, what):
    got = recorder.wait(mark, lambda fs: any(c == 0x700 + node_id and d == b"\x00" for c, d in fs), 5.0)
    if got is None:
        raise Fail(f"no boot-up message after {what}")
    return sum(1 for c, d in got if c == 0x700 + node_id and d == b"\x00")


def enable(network, node, cw, want):
    """Writes the controlword `cw`, then reads the statusword until its state bits (mask 0x6F) are `want`, with
    5 SYNCs (5 ms in lock-step) between reads, at most 100 reads."""
    node.sdo.download(0x6040, 0, cw.to_bytes(2, "little"))
    for _ in range(100):
        sw = u32(node, 0x6041, 0)
        if sw & 0x6F == want:
            return sw
        send_syncs(network, 5)
    raise Fail(f"statusword 0x{sw:04x} after controlword 0x{cw:04x}, want 0x{want:02x} & 0x6F")


def run(args):
    image = open(args.image, "rb").read()
    corrupted = open(args.corrupted, "rb").read()
    emit("image_bytes", len(image))
    network, nodes, recorder = connect(args.port, args.eds, [args.node])
    node = nodes[args.node]
    try:
        # The fallback started before this client connected: reset it to see its boot-up.
        mark = recorder.mark()
        node.nmt.send_command(0x81)
        emit("bootup_after_reset", wait_bootup(recorder, mark, args.node, "the reset node"))
        emit("device_type_fallback", f"0x{u32(node, 0x1000, 0):08x}")
        emit("program_state_fallback", u32(node, 0x1F51, 1))
        emit("sw_id_fallback", f"0x{u32(node, 0x1F56, 1):08x}")
        emit("flash_status_fallback", u32(node, 0x1F57, 1))
        emit("statusword_abort", abort_of(lambda: node.sdo.upload(0x6041, 0)))

        # Program data before clear: program control's sequence refusal (segmented download).
        sent, raised = first_abort(recorder, args.node, lambda: node.sdo.download(0x1F50, 1, image))
        emit("write_before_clear_abort", sent)
        emit("write_before_clear_raised", raised)

        node.sdo.download(0x1F51, 1, b"\x03")  # clear
        sent, raised = first_abort(recorder, args.node, lambda: block_download(node, corrupted))
        emit("corrupted_abort", sent)
        emit("corrupted_raised", raised)
        emit("flash_status_corrupted", u32(node, 0x1F57, 1))
        emit("device_type_after_corrupted", f"0x{u32(node, 0x1000, 0):08x}")

        node.sdo.download(0x1F51, 1, b"\x03")  # clear again: the refused download was abandoned
        mark = recorder.mark()
        barrier(node)
        started = time.monotonic()
        block_download(node, image)
        wall = time.monotonic() - started
        barrier(node)
        answers = [t for t, _, _ in recorder.timed_since(mark, 0x580 + args.node)]
        emit("download_wall_s", f"{wall:.3f}")
        emit("download_sim_s", f"{answers[-1] - answers[0]:.6f}")
        emit("flash_status_after_download", u32(node, 0x1F57, 1))

        # Start: the fallback answers, then resets; the bootloader swaps the image in and the application boots.
        mark = recorder.mark()
        node.sdo.download(0x1F51, 1, b"\x01")
        emit("bootup_after_start", wait_bootup(recorder, mark, args.node, "the start"))
        emit("sw_id_after", f"0x{u32(node, 0x1F56, 1):08x}")
        emit("version_after", node.sdo.upload(0x100A, 0).decode("ascii", "replace").rstrip("\x00"))
        emit("device_type_after", f"0x{u32(node, 0x1000, 0):08x}")
        emit("program_state_after", u32(node, 0x1F51, 1))

        node.sdo.download(0x6060, 0, b"\x03")  # profile velocity mode
        enable(network, node, 0x0006, 0x21)
        enable(network, node, 0x0007, 0x23)
        sw = enable(network, node, 0x000F, 0x27)
        emit("statusword_enabled", f"0x{sw & 0x6F:02x}")
        node.sdo.download(0x6040, 0, b"\x00\x00")  # disable voltage before leaving
    finally:
        network.disconnect()


if __name__ == "__main__":
    p = parser(__doc__)
    p.add_argument("--image", required=True)
    p.add_argument("--corrupted", required=True)
    sys.exit(main(run, p))
