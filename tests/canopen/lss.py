"""LSS (CiA 305) with PyPI canopen's LSS master against `drive-sim canopen --lock-step --nodes 3 --unconfigured 1
--unconfigured 2 --unconfigured 3` (issue 21, item 4): three drives without a node-ID get 5, 6 and 7.

For each new node-ID: `fast_scan()` finds one unconfigured drive (it is left in the configuration state),
`configure_node_id`, `store_configuration`, and the switch back to the waiting state, after which the drive boots
with its new node-ID. A fourth fastscan finds nobody. Then an NMT reset node to all: the drives restart from their
parameter stores and boot with 5, 6 and 7, and each answers SDO with its own serial number.

Lock-step: an LSS request runs until the drives are quiet, so a probe nobody answers costs only the master's
response timeout, set short here.

Figures: `fastscan_<id>` (the identity found, hex), `configured_<id>`, `stored_<id>`, `bootup_<id>`,
`fastscan_after`, `booted_after_reset` (node-IDs, sorted), `serial_<id>`.
"""

import struct

from can_common import Fail, connect, emit, main, parser

NEW_IDS = [5, 6, 7]


def run(args):
    network, _, recorder = connect(args.port, args.eds, [])
    lss = network.lss
    # Every answer is out before the server takes the next frame (lock-step): a short timeout only shortens the
    # probes nobody answers.
    lss.RESPONSE_TIMEOUT = 0.1
    for new_id in NEW_IDS:
        found, identity = lss.fast_scan()
        if not found:
            raise Fail(f"fastscan found no unconfigured drive for node-ID {new_id}")
        emit(f"fastscan_{new_id}", ":".join(f"{part:08x}" for part in identity))
        emit(f"configured_{new_id}", lss.configure_node_id(new_id) is None)
        lss.store_configuration()
        emit(f"stored_{new_id}", True)
        mark = recorder.mark()
        lss.send_switch_state_global(lss.WAITING_STATE)
        got = recorder.wait(mark, lambda fs, n=new_id: (0x700 + n, b"\x00") in fs, 2.0)
        emit(f"bootup_{new_id}", got is not None)
        if got is None:
            raise Fail(f"no boot-up of node-ID {new_id} after the switch to waiting")
    found, _ = lss.fast_scan()
    emit("fastscan_after", found)
    mark = recorder.mark()
    network.send_message(0x000, bytes([0x81, 0]))
    got = recorder.wait(mark, lambda fs: len({c for c, d in fs if 0x701 <= c <= 0x77F and d == b"\x00"}) >= 3, 3.0)
    booted = sorted({c - 0x700 for c, d in (got or []) if 0x701 <= c <= 0x77F and d == b"\x00"})
    emit("booted_after_reset", ",".join(str(n) for n in booted))
    if booted != NEW_IDS:
        raise Fail(f"node-IDs after reset node: {booted}")
    identities = {}
    for new_id in NEW_IDS:
        node = network.add_node(new_id, args.eds)
        identities[new_id] = [struct.unpack("<I", node.sdo.upload(0x1018, sub))[0] for sub in (1, 2, 3, 4)]
        emit(f"serial_{new_id}", f"{identities[new_id][3]:08x}")
    # CiA 305 §6.4.3: each drive selected and given 250 kbit/s (table 0, index 3), then all switched to
    # configuration and the rate activated together with a 5 ms switch delay.
    for new_id in NEW_IDS:
        lss.send_switch_state_selective(*identities[new_id])
        lss.configure_bit_timing(3)
        lss.send_switch_state_global(lss.WAITING_STATE)
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    lss.activate_bit_timing(5)
    lss.send_switch_state_global(lss.WAITING_STATE)
    # In lock-step the simulated time runs only with the master's frames: the first request waits out the silent
    # periods (answered with the value it found on arrival), a later one sees the rate in use.
    for new_id in NEW_IDS:
        for _ in range(20):
            code = network[new_id].sdo.upload(0x200A, 0)[0]
            if code == 3:
                break
        emit(f"bit_rate_code_{new_id}", code)
    network.disconnect()


if __name__ == "__main__":
    import sys

    sys.exit(main(run, parser(__doc__)))
