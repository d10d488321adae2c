"""Key-frame files: timed joint targets in YAML or CSV -> ``JointTrajectory``.

YAML::

    joints: [r_shoulder_roll, r_elbow_pitch]     # names of the joints the file drives
    angle_unit: deg                              # optional: rad (default) or deg (revolute joints only)
    interpolation: catmull_rom                   # optional: catmull_rom (default) or linear
    frames:
      - {t: 0.0, q: [0.0, 0.0]}
      - {t: 1.0, q: [-80, -45]}

CSV: a header ``t,<joint>,<joint>,...`` then one row per frame (radians and metres; ``#`` comments).
Times must increase strictly; every frame gives one finite value per joint. Joints not in the file
are not driven (a JointState consumer keeps their last value). Errors are ``KeyframeError`` naming
the file, line and frame. Prismatic joints (values in metres, never converted) are the names given
in ``prismatic`` (default: ``root_x``, ``root_y``, ``root_z``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from ..errors import ClusterFemError
from .trajectory import INTERPOLATIONS, JointTrajectory

DEFAULT_PRISMATIC = ("root_x", "root_y", "root_z")


class KeyframeError(ClusterFemError, ValueError):
    """A key-frame file that cannot be played; the message names the file, line and frame."""


def _finish(src: str, joints: list, times: list, rows: list, lines: list[int], known: Sequence[str] | None,
            prismatic: Sequence[str], deg: bool, interpolation: str) -> JointTrajectory:
    if not joints or not all(isinstance(j, str) and j for j in joints):
        raise KeyframeError(f"{src}: 'joints' must be a non-empty list of joint names, got {joints!r}")
    dup = sorted({j for j in joints if joints.count(j) > 1})
    if dup:
        raise KeyframeError(f"{src}: joints {dup} are listed twice: list each joint once")
    if known is not None:
        bad = [j for j in joints if j not in set(known)]
        if bad:
            raise KeyframeError(f"{src}: joints {bad} are not in the skeleton: check the names against the URDF")
    if not rows:
        raise KeyframeError(f"{src}: no frames: give at least one {{t: ..., q: [...]}}")
    for k, (t, q, line) in enumerate(zip(times, rows, lines)):
        where = f"{src}:{line}: frame {k}"
        if not isinstance(t, (int, float)) or isinstance(t, bool) or not np.isfinite(t):
            raise KeyframeError(f"{where}: t = {t!r} is not a finite time in seconds")
        if k and t <= times[k - 1]:
            raise KeyframeError(f"{where}: t = {t} does not come after the previous frame's t = {times[k - 1]}: "
                                "times must increase")
        if not isinstance(q, (list, tuple)) or len(q) != len(joints):
            raise KeyframeError(f"{where}: q has {len(q) if isinstance(q, (list, tuple)) else q!r} values, expected "
                                f"{len(joints)} (one per joint: {joints})")
        for j, x in zip(joints, q):
            if not isinstance(x, (int, float)) or isinstance(x, bool) or not np.isfinite(x):
                raise KeyframeError(f"{where}: joint {j!r} value {x!r} is not a finite number")
    revolute = np.array([j not in set(prismatic) for j in joints])
    pos = np.array(rows, dtype=np.float64)
    if deg:
        pos[:, revolute] = np.deg2rad(pos[:, revolute])
    if interpolation not in INTERPOLATIONS:
        raise KeyframeError(f"{src}: interpolation {interpolation!r}: choose one of {INTERPOLATIONS}")
    return JointTrajectory(np.array(times, float), joints, pos, revolute=revolute, interpolation=interpolation)


def parse_keyframes_yaml(text: str, source: str = "<yaml>", joint_names: Sequence[str] | None = None,
                         prismatic: Sequence[str] = DEFAULT_PRISMATIC) -> JointTrajectory:
    """Key frames from YAML text (see the module docstring); ``joint_names`` checks names against a skeleton."""
    try:
        node = yaml.compose(text)
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise KeyframeError(f"{source}: not valid YAML: {e}") from e
    if not isinstance(data, dict) or "joints" not in data or "frames" not in data:
        raise KeyframeError(f"{source}: expected a mapping with 'joints' and 'frames' keys")
    unit = data.get("angle_unit", "rad")
    if unit not in ("rad", "deg"):
        raise KeyframeError(f"{source}: angle_unit {unit!r}: use 'rad' or 'deg'")
    frames = data["frames"]
    if not isinstance(frames, list):
        raise KeyframeError(f"{source}: 'frames' must be a list of {{t: ..., q: [...]}}")
    frame_nodes = next(v for k, v in node.value if k.value == "frames").value
    lines = [fn.start_mark.line + 1 for fn in frame_nodes]
    times, rows = [], []
    for k, (f, line) in enumerate(zip(frames, lines)):
        if not isinstance(f, dict) or "t" not in f or "q" not in f:
            raise KeyframeError(f"{source}:{line}: frame {k} must be a mapping with t and q, got {f!r}")
        times.append(f["t"])
        rows.append(f["q"])
    joints = data["joints"] if isinstance(data["joints"], list) else [data["joints"]]
    return _finish(source, joints, times, rows, lines, joint_names, prismatic, unit == "deg",
                   data.get("interpolation", "catmull_rom"))


def parse_keyframes_csv(text: str, source: str = "<csv>", joint_names: Sequence[str] | None = None,
                        prismatic: Sequence[str] = DEFAULT_PRISMATIC) -> JointTrajectory:
    """Key frames from CSV text: header ``t,<joints...>``, then rows (radians, metres)."""
    rows, times, lines, header = [], [], [], None
    for k, raw in enumerate(text.replace("\r\n", "\n").split("\n"), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            if cells[0] != "t":
                raise KeyframeError(f"{source}:{k}: the header must start with 't', found {cells[0]!r}")
            header = cells[1:]
            continue
        try:
            vals = [float(c) for c in cells]
        except ValueError:
            raise KeyframeError(f"{source}:{k}: frame {len(rows)}: non-numeric value in {cells}") from None
        times.append(vals[0])
        rows.append(vals[1:])
        lines.append(k)
    if header is None:
        raise KeyframeError(f"{source}: empty file: write a header 't,<joint>,...' and one row per frame")
    return _finish(source, header, times, rows, lines, joint_names, prismatic, False, "catmull_rom")


def load_keyframes(path: str | Path, joint_names: Sequence[str] | None = None,
                   prismatic: Sequence[str] = DEFAULT_PRISMATIC) -> JointTrajectory:
    """Read a ``.yaml``/``.yml`` or ``.csv`` key-frame file (see the module docstring)."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise KeyframeError(f"cannot read key-frame file {str(p)!r}: {e.strerror}") from e
    if p.suffix.lower() == ".csv":
        return parse_keyframes_csv(text, str(p), joint_names, prismatic)
    return parse_keyframes_yaml(text, str(p), joint_names, prismatic)


def example_path(name: str = "wave.yaml") -> Path:
    """Path of a key-frame file shipped in ``clusterfem_ros/skeleton/data``."""
    return Path(__file__).with_name("data") / name
