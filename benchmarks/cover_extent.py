"""Robot covers (body.kind robot_cover) of URDFs whose links lie far apart or are long: what each costs to build.

    python -m benchmarks.cover_extent                 # issue 37's cases
    python -m benchmarks.cover_extent --tets 40000    # at another body.target_tets

Each URDF is built into a robot-cover scene's parts (``scene_build.scene_parts``, skeleton.source
robot_description, as the node builds one it receives) in a fresh child process, after a small cover has loaded
the imports; per URDF the table gives the growth of the child's own peak resident memory (VmHWM, /proc/self/status)
over the build, its seconds and its outcome: the cover's tets, links covered and voxel, or the refusal. The
generators below are also the tests' (tests/test_robot_cover.py).
"""
from __future__ import annotations

import argparse
import subprocess
import sys

import numpy as np

from .timing import table

_INERTIAL = ("<inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial>")
_LIMIT = "<limit lower='-1' upper='1' effort='1' velocity='1'/>"
BOX = "<box size='0.05 0.05 0.05'/>"


def _link(name: str, shape: str, rpy: str = "0 0 0") -> str:
    return (f"<link name='{name}'>{_INERTIAL}<collision><origin xyz='0 0 0' rpy='{rpy}'/><geometry>{shape}</geometry>"
            "</collision></link>")


def _joint(name: str, parent: str, child: str, xyz) -> str:
    return (f"<joint name='{name}' type='revolute'><parent link='{parent}'/><child link='{child}'/>"
            f"<origin xyz='{' '.join(f'{v:.9g}' for v in xyz)}'/><axis xyz='0 1 0'/>{_LIMIT}</joint>")


def far_apart(d: float, plane: bool = False) -> str:
    """Three links, each a 5 cm box: a root at the origin and two leaves on revolute joints, ``d`` metres apart across
    it on the space diagonal (at +-d/2 (1, 1, 1) / sqrt 3), or, with ``plane``, at a right angle in the floor plane
    (at d / sqrt 2 on x and on y)."""
    a, b = (d / np.sqrt(2) * np.eye(3)[:2]) if plane else (d / 2 / np.sqrt(3) * np.array([[1, 1, 1], [-1, -1, -1]]))
    return ("<robot name='far_apart'>" + _link("root", BOX) + _link("a", BOX) + _link("b", BOX)
            + _joint("ja", "root", "a", a) + _joint("jb", "root", "b", b) + "</robot>")


def diagonal_bar(length: float) -> str:
    """A root link whose shape is a 1 cm bar of ``length`` [m] along the space diagonal, and a 5 cm box on it."""
    rpy = f"0 {-np.arctan(1 / np.sqrt(2)):.9f} {np.pi / 4:.9f}"            # x onto (1, 1, 1) / sqrt 3
    return ("<robot name='diagonal_bar'>" + _link("bar", f"<box size='{length:g} 0.01 0.01'/>", rpy)
            + _link("tip", BOX) + _joint("j", "bar", "tip", (0.0, 0.0, 0.5)) + "</robot>")


CASES = [("far_apart(9, plane=True)", "3 boxes, leaves 9 m apart in a plane"),
         ("far_apart(9)", "3 boxes, leaves 9 m apart across the diagonal"),
         ("far_apart(100, plane=True)", "3 boxes, leaves 100 m apart in a plane"),
         ("far_apart(100)", "3 boxes, leaves 100 m apart across the diagonal"),
         ("far_apart(1000)", "3 boxes, leaves 1 km apart across the diagonal"),
         ("diagonal_bar(10)", "a 10 m bar on the space diagonal"),
         ("diagonal_bar(30)", "a 30 m bar on the space diagonal")]

_CHILD = """
import os, sys, time
from benchmarks.cover_extent import diagonal_bar, far_apart  # noqa: F401
from benchmarks.hostile_urdf import memory_kb
from clusterfem_ros.config import SceneConfig
from clusterfem_ros.scene_build import scene_parts
config = SceneConfig().with_values({"skeleton.source": "robot_description", "body.kind": "robot_cover",
                                    "body.target_tets": int(sys.argv[2])})
scene_parts(config, far_apart(0.3))
before = memory_kb(os.getpid())[1]
t = time.perf_counter()
try:
    cover = scene_parts(config, eval(sys.argv[1])).cover
    what = [n for n in cover.notes if n.startswith("robot cover:")][0].split(" (")[0]
except Exception as exc:  # a refusal is a row
    what = f"{type(exc).__name__}: {exc}"
print(f"{(memory_kb(os.getpid())[1] - before) / 1024:.0f}\\t{time.perf_counter() - t:.1f}\\t{what}")
"""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tets", type=int, default=4800, help="body.target_tets")
    args = ap.parse_args(argv)
    rows = []
    for expr, what in CASES:
        out = subprocess.run([sys.executable, "-c", _CHILD, expr, str(args.tets)], capture_output=True, text=True)
        if out.returncode:
            rows.append([what, "-", "-", f"child failed: {out.stderr.strip().splitlines()[-1]}"])
            continue
        grew, seconds, outcome = out.stdout.strip().split("\t")
        rows.append([what, grew, seconds, outcome])
    print(table(["URDF", "VmHWM growth [MB]", "build [s]", "outcome"], rows))


if __name__ == "__main__":
    main()
