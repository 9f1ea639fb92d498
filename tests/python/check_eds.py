#!/usr/bin/env python3
"""Checks the generated CANopen EDS against the firmware's runtime dictionary with two independent readers.

Usage: check_eds.py DRIVE.eds ENTRIES.json

ENTRIES.json (written by tests/tests/eds_canopen.rs from firmware::od::generated) holds
{"node_id": N, "entries": [{"index", "sub", "name", "object_code", "data_type", "access", "pdo",
"node_id_relative", "default" (hex bytes or null)}]}.

1. PyPI canopen (`canopen.import_od`) must load the EDS and find every entry of the firmware's table with the
   same object code, data type, access type, PDO-mappable flag and default value, and nothing else.
2. `eds-validate` (PyPI eds-utils) must accept the file without a single complaint.

Exit status: 0 all good, 1 mismatches (listed on stdout), 3 Python packages missing.
"""

import json
import shutil
import subprocess
import sys

try:
    import canopen
    from canopen import objectdictionary as odmod
except ImportError as exc:  # pragma: no cover - reported to the Rust test
    print(f"missing Python package: {exc}. Run scripts/setup.sh (pip install -r tests/python/requirements.txt)")
    sys.exit(3)

SIGNED = {0x0002: 1, 0x0003: 2, 0x0004: 4, 0x0015: 8}
UNSIGNED = {0x0001: 1, 0x0005: 1, 0x0006: 2, 0x0007: 4, 0x001B: 8}
VISIBLE_STRING, OCTET_STRING, DOMAIN = 0x0009, 0x000A, 0x000F


def expected_default(entry, node_id):
    """The default the EDS must state for `entry`, or None when the firmware table holds none."""
    if entry["default"] is None or entry["data_type"] == DOMAIN:
        return None
    raw = bytes.fromhex(entry["default"])
    t = entry["data_type"]
    if t == VISIBLE_STRING:
        return raw.rstrip(b"\0").decode("latin-1")
    if t == OCTET_STRING:
        return raw.rstrip(b"\0")
    signed = t in SIGNED
    value = int.from_bytes(raw, "little", signed=signed)
    if entry["node_id_relative"]:
        value += node_id
    return value


def main():
    eds_path, json_path = sys.argv[1], sys.argv[2]
    with open(json_path) as f:
        table = json.load(f)
    node_id = table["node_id"]
    entries = table["entries"]
    problems = []

    od = canopen.import_od(eds_path, node_id)

    wanted = set()
    for e in entries:
        index, sub = e["index"], e["sub"]
        wanted.add((index, sub))
        where = f"0x{index:04X}:{sub:02X} '{e['name']}'"
        try:
            obj = od[index]
        except KeyError:
            problems.append(f"{where}: object missing from the EDS")
            continue
        if e["object_code"] == 0x07:
            if not isinstance(obj, odmod.ODVariable):
                problems.append(f"{where}: expected a VAR, the EDS has {type(obj).__name__}")
                continue
            var = obj
        else:
            kind = odmod.ODArray if e["object_code"] == 0x08 else odmod.ODRecord
            if not isinstance(obj, kind):
                problems.append(f"{where}: expected {kind.__name__}, the EDS has {type(obj).__name__}")
                continue
            # Look the sub-index up directly: ODArray invents members for sub-indices it does not hold.
            if sub not in obj.subindices:
                problems.append(f"{where}: sub-object missing from the EDS")
                continue
            var = obj.subindices[sub]
        if var.data_type != e["data_type"]:
            problems.append(f"{where}: data type 0x{var.data_type:04X}, firmware 0x{e['data_type']:04X}")
        if var.access_type != e["access"]:
            problems.append(f"{where}: access {var.access_type}, firmware {e['access']}")
        if bool(var.pdo_mappable) != e["pdo"]:
            problems.append(f"{where}: PDO mapping {var.pdo_mappable}, firmware {e['pdo']}")
        if bool(getattr(var, "relative", False)) != e["node_id_relative"]:
            problems.append(f"{where}: $NODEID-relative {var.relative}, firmware {e['node_id_relative']}")
        want = expected_default(e, node_id)
        if want is not None:
            got = var.default
            if isinstance(want, bytes) and isinstance(got, (bytes, bytearray)):
                got = bytes(got).rstrip(b"\0")
            if got != want:
                problems.append(f"{where}: default {got!r}, firmware {want!r}")

    # Nothing extra: every object and sub-object canopen found must be in the firmware's table.
    for obj in od.values():
        if isinstance(obj, odmod.ODVariable):
            keys = [(obj.index, obj.subindex)]
        else:
            keys = [(obj.index, v.subindex) for v in obj.values()]
        for key in keys:
            if key not in wanted:
                problems.append(f"0x{key[0]:04X}:{key[1]:02X}: in the EDS but not in the firmware's dictionary")

    # eds-validate, as its command-line tool, must print nothing and exit 0.
    cmd = shutil.which("eds-validate")
    if cmd:
        argv = [cmd, eds_path]
    else:
        argv = [sys.executable, "-c",
                "import sys; from eds_utils.eds_validate import eds_validate; eds_validate(sys.argv[1:])",
                eds_path]
    try:
        run = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    except FileNotFoundError as exc:
        print(f"eds-validate not found ({exc}). Run scripts/setup.sh")
        sys.exit(3)
    if "No module named" in run.stderr:
        print(f"eds-utils missing: {run.stderr.strip()}. Run scripts/setup.sh")
        sys.exit(3)
    if run.returncode != 0 or run.stderr.strip() or run.stdout.strip():
        problems.append(f"eds-validate (exit {run.returncode}): {(run.stdout + run.stderr).strip()}")

    checked = len(entries)
    if problems:
        print(f"{len(problems)} problem(s) in {eds_path} ({checked} entries checked):")
        for p in problems:
            print("  " + p)
        sys.exit(1)
    print(f"ok: canopen {canopen.__version__} found all {checked} entries of {len(od)} objects; eds-validate clean")


if __name__ == "__main__":
    main()
