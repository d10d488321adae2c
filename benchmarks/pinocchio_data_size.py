"""How much memory pinocchio's Data takes against the number of joints, and what kinematics.data_bytes says.

    python -m benchmarks.pinocchio_data_size                    # stars and chains of 25 to 400 joints
    python -m benchmarks.pinocchio_data_size --joints 50 100    # other sizes

Each size runs in a process of its own (python -c): it builds the model of a star (one root, n leaves) or a chain
(n deep) from benchmarks/hostile_urdf.py, then makes Data and runs forwardKinematics and updateFramePlacements;
the row is the growth of that process's own peak resident memory (VmHWM in /proc/self/status) across those
calls. ru_maxrss is not used: after fork+exec it starts at the resident size of the process that forked it.
Nothing on the node's path makes Data (skeleton/kinematics.py); this measures what a regression would cost and
checks the fit behind ``kinematics.MAX_DATA_BYTES``. A 400-joint row takes ~4 GB.
"""
from __future__ import annotations

import argparse
import subprocess
import sys

from .timing import table

_CHILD = """
import os, sys
import pinocchio as pin
from benchmarks.hostile_urdf import chain, memory_kb, star
kind, n = sys.argv[1], int(sys.argv[2])
model = pin.buildModelFromXML((star if kind == "star" else chain)(n + 1))
before = memory_kb(os.getpid())[1]
data = model.createData()
pin.forwardKinematics(model, data, pin.neutral(model))
pin.updateFramePlacements(model, data)
print(model.nv, (memory_kb(os.getpid())[1] - before) / 1024)
"""


def measure(kind: str, joints: int) -> tuple[int, float]:
    """(nv, Data's peak growth [MB]) of a ``kind`` ('star' or 'chain') of ``joints`` revolute joints."""
    out = subprocess.run([sys.executable, "-c", _CHILD, kind, str(joints)], capture_output=True, text=True,
                         check=True)
    nv, mb = out.stdout.split()
    return int(nv), float(mb)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--joints", type=int, nargs="*", default=[25, 50, 100, 150, 200, 300, 400])
    args = ap.parse_args(argv)
    from clusterfem_ros.skeleton.kinematics import MAX_DATA_BYTES, data_bytes
    rows = []
    for n in args.joints:
        star_nv, star_mb = measure("star", n)
        _, chain_mb = measure("chain", n)
        fit = data_bytes(star_nv) / 2 ** 20
        rows.append([star_nv, f"{star_mb:.1f}", f"{chain_mb:.1f}", f"{fit:.1f}", f"{(fit / star_mb - 1) * 100:+.0f} %",
                     "refused" if data_bytes(star_nv) > MAX_DATA_BYTES else "made"])
        print(f"[pinocchio_data_size] {star_nv} joints: {star_mb:.0f} MB", flush=True)
    print(f"\npinocchio's Data: growth of a fresh process's VmHWM [MB]; fit = kinematics.data_bytes; "
          f"max_data_bytes {MAX_DATA_BYTES / 2 ** 20:.0f} MB")
    print(table(["joints", "star [MB]", "chain [MB]", "fit [MB]", "fit error", "pinocchio_data"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
