"""What the PyPI `canopen` scripts under tests/canopen/ share: the verdict protocol, the connection to
`drive-sim canopen` through python-can's socketcand interface, a recorder of the frames the nodes send, raw SDO
exchanges with hand-made frames, and the lock-step barrier.

Every script prints one `key=value` line per figure and as its last line `verdict=pass` or `verdict=fail
<reason>`; tests/tests/canopen_real_master.rs judges the figures (facts: shared/spec/fieldbus-real-masters.md,
"socketcand protocol as python-can speaks it").

Lock-step (hal-sim `sim::canopen`): simulated time passes only with the master's frames. A SYNC runs one SYNC
period; an NMT or SDO frame runs until the nodes are quiet (the answer is out); RPDOs and heartbeats run no time
and cross the bus with the next frame that does. The server handles the frames in order and sends what each
produced before it takes the next, so an answered SDO request is a barrier: every frame the nodes sent for
earlier requests has reached this client (and its callbacks have run: python-can delivers in order).
"""

import argparse
import struct
import sys
import threading
import time

import canopen

SYNC = 0x080
NMT_STATE = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}


class Fail(Exception):
    """A check failed: the reason is the verdict."""


def emit(key, value):
    print(f"{key}={value}", flush=True)


def connect(port, eds, node_ids):
    """A canopen network on the socketcand server at 127.0.0.1:`port` with one RemoteNode per id (the EDS gives
    the dictionary). Returns (network, nodes, recorder)."""
    network = canopen.Network()
    # tcp_tune: TCP_NODELAY and TCP_QUICKACK on the client (python-can >= 4.3); without it Nagle and delayed
    # ACKs hold every small frame back ~40 ms.
    network.connect(interface="socketcand", host="127.0.0.1", port=port, channel="can0", tcp_tune=True)
    recorder = Recorder(network)
    nodes = {}
    for node_id in node_ids:
        nodes[node_id] = network.add_node(node_id, eds)
    return network, nodes, recorder


class Recorder:
    """Every frame from the nodes (all COB-IDs but the master's own), with its simulated time; waits on them."""

    def __init__(self, network):
        self.frames = []
        self.cond = threading.Condition()
        # python-can's Notifier calls every listener; canopen's Network.notify only dispatches subscribed
        # COB-IDs, so a listener of our own sees the rest (unknown COB-IDs, bus errors) too.
        network.notifier.add_listener(self._on_message)

    def _on_message(self, msg):
        if msg.is_error_frame:
            return
        with self.cond:
            # The timestamp is the server's: simulated time when the frame's last bit passed.
            self.frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))
            self.cond.notify_all()

    def mark(self):
        """A position in the record: frames after it are `since(mark)`."""
        with self.cond:
            return len(self.frames)

    def since(self, mark, cob_id=None):
        with self.cond:
            got = self.frames[mark:]
        return [(c, d) for _, c, d in got if cob_id is None or c == cob_id]

    def timed_since(self, mark, cob_id=None):
        """As `since`, with the simulated time (s) of each frame first."""
        with self.cond:
            got = self.frames[mark:]
        return [(t, c, d) for t, c, d in got if cob_id is None or c == cob_id]

    def wait(self, mark, predicate, timeout):
        """Waits until `predicate(frames since mark)` holds; returns the frames then, or None at the timeout."""
        end = time.monotonic() + timeout
        with self.cond:
            while True:
                got = [(c, d) for _, c, d in self.frames[mark:]]
                if predicate(got):
                    return got
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)


def nmt_and_bootup(recorder, node, command):
    """Sends the NMT `command` (a reset) to `node` and returns the first frame on its boot-up COB-ID after it, as
    (cob_id, data); Fail when none comes within 2 s."""
    mark = recorder.mark()
    node.nmt.state = command
    got = recorder.wait(mark, lambda fs: any(c == 0x700 + node.id for c, _ in fs), 2.0)
    if got is None:
        raise Fail(f"no boot-up message after {command}")
    return next((c, d) for c, d in got if c == 0x700 + node.id)


def barrier(node):
    """An SDO upload of 0x1000 answered: everything sent before has been handled (see the module docstring)."""
    node.sdo.upload(0x1000, 0)


def sdo_raw(network, recorder, node_id, data, timeout=0.5):
    """Sends one hand-made SDO request (8 bytes unless the test wants otherwise) and returns the node's answer
    (8 bytes) or None when none came within `timeout` s. canopen's own SDO client of the node also queues the
    answer; it discards stale answers before its next request."""
    mark = recorder.mark()
    network.send_message(0x600 + node_id, bytes(data))
    got = recorder.wait(mark, lambda fs: any(c == 0x580 + node_id for c, _ in fs), timeout)
    if got is None:
        return None
    return next(d for c, d in got if c == 0x580 + node_id)


def abort_code(answer):
    """The abort code of an SDO abort answer (command 0x80), else None."""
    if answer is None or len(answer) != 8 or answer[0] != 0x80:
        return None
    return struct.unpack_from("<I", answer, 4)[0]


def send_syncs(network, count):
    for _ in range(count):
        network.send_message(SYNC, b"")


def int0(text):
    return int(text, 0)


def parser(doc):
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--eds", required=True)
    p.add_argument("--node", type=int, default=1)
    return p


def main(run, p):
    """Parses the arguments, runs `run(args)` and prints the verdict; the exit status says it too."""
    args = p.parse_args()
    started = time.monotonic()
    try:
        run(args)
    except Fail as e:
        print(f"verdict=fail {e}", flush=True)
        return 1
    except Exception as e:  # canopen raises its own errors (SdoAbortedError, SdoCommunicationError, ...)
        print(f"verdict=fail {type(e).__name__}: {e}", flush=True)
        return 1
    finally:
        emit("script_s", f"{time.monotonic() - started:.3f}")
    print("verdict=pass", flush=True)
    return 0


def run_main(run, p):
    sys.exit(main(run, p))
