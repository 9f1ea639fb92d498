#!/usr/bin/env python3
"""Firmware update over CANopen with PyPI canopen: program control and an SDO block download of a signed image.

Run by tests/tests/canopen_real_master.rs against `drive-sim canopen --lock-step`. The sequence of the IDX spec and
the EPOS4 application notes (program control, firmware/src/boot/program.rs): 0x1F51:01 = 0 (stop program),
= 3 (clear program), the image into 0x1F50:01 by SDO block download (canopen computes the block CRC, the drive's
SDO server checks it: CiA 301 §7.2.4.3.9), 0x1F51:01 = 1 (start: the drive resets and does not answer), then the
boot-up message, and 0x1F56:01, 0x100A and 0x1F57:01 read back. Prints one figure per line and the verdict.
"""

import time

import canopen

from can_common import Fail, connect, emit, main, parser


def u32(node, index, sub):
    """An unsigned value of up to 4 bytes (0x1F51 is UNSIGNED8, 0x1F56/0x1F57 UNSIGNED32)."""
    return int.from_bytes(node.sdo.upload(index, sub)[:4], "little")


def run(args):
    image = open(args.image, "rb").read()
    emit("image_bytes", len(image))
    network, nodes, recorder = connect(args.port, args.eds, [args.node])
    node = nodes[args.node]
    try:
        emit("sw_id_before", f"0x{u32(node, 0x1F56, 1):08x}")
        emit("version_before", node.sdo.upload(0x100A, 0).decode("ascii", "replace").rstrip("\x00"))
        emit("program_state_before", u32(node, 0x1F51, 1) & 0xFF)
        node.sdo.download(0x1F51, 1, b"\x00")  # stop
        node.sdo.download(0x1F51, 1, b"\x03")  # clear
        emit("program_state_stopped", node.sdo.upload(0x1F51, 1)[0])
        started = time.monotonic()
        with node.sdo.open(0x1F50, 1, "wb", size=len(image), block_transfer=True) as f:
            f.write(image)
        emit("block_download_s", f"{time.monotonic() - started:.3f}")
        emit("flash_status_after_download", u32(node, 0x1F57, 1))
        # Start: the drive resets at once (E4: no answer to expect); canopen's client times out.
        mark = recorder.mark()
        try:
            node.sdo.download(0x1F51, 1, b"\x01")
            emit("start_answered", 1)
        except canopen.SdoCommunicationError:
            emit("start_answered", 0)
        bootup = recorder.wait(mark, lambda fs: any(c == 0x700 + args.node and d == b"\x00" for c, d in fs), 5.0)
        if bootup is None:
            raise Fail("no boot-up message after the start")
        emit("bootup_after_start", 1)
        emit("sw_id_after", f"0x{u32(node, 0x1F56, 1):08x}")
        emit("version_after", node.sdo.upload(0x100A, 0).decode("ascii", "replace").rstrip("\x00"))
        emit("program_state_after", u32(node, 0x1F51, 1) & 0xFF)
        emit("flash_status_after", u32(node, 0x1F57, 1))
    finally:
        network.disconnect()


if __name__ == "__main__":
    p = parser(__doc__)
    p.add_argument("--image", required=True)
    import sys

    sys.exit(main(run, p))
