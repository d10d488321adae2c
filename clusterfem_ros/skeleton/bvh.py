"""Reading BVH motion capture files (Biovision hierarchy), e.g. the CMU captures.

``load_bvh(path)`` returns a ``BvhMotion``: the joint hierarchy in file order (parents before children)
with offsets, per-joint channel lists in their file order (the Euler order: "Zrotation Yrotation
Xrotation" means R = Rz(z) Ry(y) Rx(x) from the parent), end sites, the frame time and the raw frames
(F, C) in file units and degrees. Line endings may be LF or CRLF. A malformed file raises ``BvhError``
naming the line.

Units and axes are recorded, not applied to the frames: ``unit_m`` metres per file unit, ``to_ros`` (3, 3),
the rotation taking file axes to ROS axes (Z up, X forward), and ``root_shift`` (3,) [m, ROS], where the
root's origin is moved (the floor under the feet). ``unit``, ``up`` and ``forward`` are found from the
skeleton unless given (``bvh_placement``: a standing human; ``unit="auto"``, ``"cm"``, ``"cmu"`` or metres
per unit, axes such as ``"Y"`` or ``"-Z"``); ``placement`` is the line that says what was decided. Y up
and Z forward (CMU: walking along +Z) map file (x, y, z) to ROS (z, x, y).

The root's position channels are its position (its OFFSET counts only along axes without a position
channel), as the BVH format and mature readers (Blender's importer) define it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ClusterFemError
from .bvh_placement import CMU_UNIT_M, PlacementError, parse_unit, place
CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_AXIS = {"X": 0, "Y": 1, "Z": 2}


class BvhError(ClusterFemError, ValueError):
    """A malformed BVH file; the message names the file line and what was expected."""


@dataclass
class BvhJoint:
    name: str
    parent: int                               # index into BvhMotion.joints, -1 for the root
    offset: np.ndarray                        # (3,) file units, in the parent's frame
    channels: list[str]                       # e.g. ["Zrotation", "Yrotation", "Xrotation"]
    channel_start: int                        # first column of this joint in BvhMotion.frames
    end_site: np.ndarray | None = None        # (3,) offset of the end site, file units, or None


@dataclass
class BvhMotion:
    joints: list[BvhJoint]
    frame_time: float                         # [s]
    frames: np.ndarray                        # (F, C): positions in file units, angles in degrees
    unit_m: float = CMU_UNIT_M
    to_ros: np.ndarray = field(default_factory=lambda: axes_to_ros("Y", "Z"))
    source: str = ""
    root_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))     # [m, ROS] added to the root's origin
    placement: str = ""                       # what unit, axes and floor were decided, one line
    unit_name: str = "cmu"                    # the unit's name (m, cm, mm, inch, cmu, or "<metres> m")
    height_m: float = 0.0                     # the rest pose's height, feet to head [m]

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def parents(self) -> np.ndarray:
        return np.array([j.parent for j in self.joints], dtype=np.int64)

    @property
    def offsets(self) -> np.ndarray:
        """(J, 3) offsets in file units."""
        return np.array([j.offset for j in self.joints])

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.frames.shape[1])

    def channel(self, joint: str, name: str) -> np.ndarray:
        """The (F,) column of channel ``name`` (e.g. "Zrotation") of joint ``joint``."""
        for j in self.joints:
            if j.name == joint:
                if name not in j.channels:
                    raise KeyError(f"joint {joint!r} has no channel {name!r} (it has {j.channels})")
                return self.frames[:, j.channel_start + j.channels.index(name)]
        raise KeyError(f"no joint {joint!r} in the BVH hierarchy")


def elementary_rotations(axis: str, angles_deg: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations about file axis ``axis`` ("X", "Y" or "Z") by ``angles_deg`` (F,) degrees."""
    a = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][_AXIS[axis]]
    R = np.zeros(a.shape + (3, 3))
    R[..., _AXIS[axis], _AXIS[axis]] = 1.0
    R[..., i, i], R[..., i, j], R[..., j, i], R[..., j, j] = c, -s, s, c
    return R


def joint_rotations(motion: "BvhMotion", joint: int) -> np.ndarray:
    """(F, 3, 3) local rotation of joint ``joint`` in every frame: the product of its rotation channels in order."""
    j = motion.joints[joint]
    R = np.broadcast_to(np.eye(3), (motion.n_frames, 3, 3)).copy()
    for k, c in enumerate(j.channels):
        if c.endswith("rotation"):
            R = R @ elementary_rotations(c[0], motion.frames[:, j.channel_start + k])
    return R


def _signed_unit(axis: str) -> np.ndarray | None:
    a = axis.upper().lstrip("+")
    if a.lstrip("-") not in _AXIS or a.count("-") > 1:
        return None
    return np.eye(3)[_AXIS[a[-1]]] * (-1.0 if a.startswith("-") else 1.0)


def axes_to_ros(up: str = "Y", forward: str = "Z") -> np.ndarray:
    """Rotation (3, 3) taking a file whose ``up``/``forward`` axes are given ("Y", "-Z", ...) to ROS (X forward,
    Z up, Y left)."""
    u, f = _signed_unit(up), _signed_unit(forward)
    if u is None or f is None or abs(u @ f) > 0:
        raise ValueError(f"up = {up!r}, forward = {forward!r}: give two different axes among X, Y, Z (signed: -Z)")
    left = np.cross(u, f)
    return np.array([f, left, u])                # rows: file coordinates of ROS X, Y, Z


class _Tokens:
    def __init__(self, lines: list[str], path: str):
        self.items = [(tok, k + 1) for k, line in enumerate(lines) for tok in line.split()]
        self.pos = 0
        self.path = path

    def error(self, text: str, line: int | None = None) -> BvhError:
        if line is None:
            line = self.items[min(self.pos, len(self.items) - 1)][1] if self.items else 1
        return BvhError(f"{self.path}:{line}: {text}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"file ends where {what} was expected")
        self.pos += 1
        return self.items[self.pos - 1]

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok.upper() != word.upper():
            raise self.error(f"expected {word!r}, found {tok!r}", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            return float(tok)
        except ValueError:
            raise self.error(f"expected a number for {what}, found {tok!r}", line) from None


def _parse_joint(tk: _Tokens, name: str, parent: int, joints: list[BvhJoint], column: int) -> int:
    tk.expect("{")
    tk.expect("OFFSET")
    offset = np.array([tk.number(f"the OFFSET of {name!r}") for _ in range(3)])
    tok, line = tk.next("CHANNELS")
    if tok.upper() != "CHANNELS":
        raise tk.error(f"joint {name!r}: expected CHANNELS after OFFSET, found {tok!r}", line)
    count_tok, line = tk.next("the channel count")
    if not count_tok.isdigit():
        raise tk.error(f"joint {name!r}: channel count {count_tok!r} is not a whole number", line)
    channels = []
    for _ in range(int(count_tok)):
        ch, line = tk.next(f"a channel name of {name!r}")
        if ch not in CHANNEL_NAMES:
            raise tk.error(f"joint {name!r}: unknown channel {ch!r}, expected one of {CHANNEL_NAMES}", line)
        channels.append(ch)
    me = len(joints)
    joints.append(BvhJoint(name, parent, offset, channels, column))
    column += len(channels)
    while True:
        tok, line = tk.next(f"JOINT, End Site or '}}' in {name!r}")
        key = tok.upper()
        if key == "}":
            return column
        if key == "JOINT":
            child, _ = tk.next("a joint name")
            column = _parse_joint(tk, child, me, joints, column)
        elif key == "END":
            tk.expect("Site")
            tk.expect("{")
            tk.expect("OFFSET")
            joints[me].end_site = np.array([tk.number(f"the End Site OFFSET of {name!r}") for _ in range(3)])
            tk.expect("}")
        else:
            raise tk.error(f"in joint {name!r}: expected JOINT, End Site or '}}', found {tok!r}", line)


def parse_bvh(text: str, source: str = "<bvh>", unit_m: float | str = "auto", up: str = "auto",
              forward: str = "auto", floor: bool = True) -> BvhMotion:
    """Parse BVH text (see ``load_bvh``)."""
    parse_unit(unit_m)                           # a bad unit is refused before the file is read
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    motion_line = next((k for k, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    if motion_line is None:
        raise BvhError(f"{source}: no MOTION line: the file has no frame data (is it a BVH file?)")
    tk = _Tokens(lines[:motion_line], source)
    tk.expect("HIERARCHY")
    tk.expect("ROOT")
    root, _ = tk.next("the root joint name")
    joints: list[BvhJoint] = []
    n_channels = _parse_joint(tk, root, -1, joints, 0)
    if tk.pos < len(tk.items):
        tok, line = tk.items[tk.pos]
        raise tk.error(f"unexpected {tok!r} after the root joint (only one ROOT is supported)", line)

    def header(k: int, key: str) -> str:
        if k >= len(lines) or not lines[k].strip().lower().startswith(key.lower()):
            raise BvhError(f"{source}:{k + 1}: expected '{key} ...' after MOTION")
        return lines[k].split(":", 1)[1].strip()

    n_frames_txt, ft_txt = header(motion_line + 1, "Frames:"), header(motion_line + 2, "Frame Time:")
    try:
        n_frames, frame_time = int(n_frames_txt), float(ft_txt)
    except ValueError:
        raise BvhError(f"{source}:{motion_line + 2}: cannot read 'Frames: {n_frames_txt}' / "
                       f"'Frame Time: {ft_txt}' as a count and seconds") from None
    if n_frames < 1 or not (np.isfinite(frame_time) and frame_time > 0):
        raise BvhError(f"{source}:{motion_line + 2}: {n_frames} frames of {frame_time} s: need >= 1 frame, time > 0")
    room = len(lines) - (motion_line + 3)        # one line per frame: the file bounds the count before allocating
    if n_frames > room:
        raise BvhError(f"{source}:{motion_line + 2}: 'Frames: {n_frames}' but only {room} lines follow: the "
                       "count is wrong or the file is truncated; fix the Frames line")
    frames = np.empty((n_frames, n_channels))
    k = motion_line + 3
    for f in range(n_frames):
        while k < len(lines) and not lines[k].strip():
            k += 1
        if k >= len(lines):
            raise BvhError(f"{source}:{k}: file ends after {f} of {n_frames} frames: the file is truncated")
        try:
            row = np.array(lines[k].split(), dtype=np.float64)
        except ValueError:
            raise BvhError(f"{source}:{k + 1}: frame {f} has a non-numeric value") from None
        if row.size != n_channels:
            raise BvhError(f"{source}:{k + 1}: frame {f} has {row.size} values, the hierarchy has {n_channels} "
                           "channels")
        if not np.isfinite(row).all():
            raise BvhError(f"{source}:{k + 1}: frame {f} has a non-finite value")
        frames[f] = row
        k += 1
    motion = BvhMotion(joints, frame_time, frames, source=source)
    try:
        p = place(motion, unit_m, up, forward, floor)
    except PlacementError as exc:
        raise BvhError(str(exc)) from None
    motion.unit_m, motion.to_ros, motion.root_shift, motion.placement = (
        p.unit_m, axes_to_ros(p.up, p.forward), p.root_shift, p.text)
    motion.unit_name, motion.height_m = p.unit_name, p.height_m
    return motion


def load_bvh(path: str | Path, unit_m: float | str = "auto", up: str = "auto", forward: str = "auto",
             floor: bool = True) -> BvhMotion:
    """Read a BVH file; ``unit_m`` metres per file unit or a unit name, ``up``/``forward`` the file's axes,
    ``floor`` puts the lowest point of the body at z = 0 (each 'auto' or default: found from the skeleton, see
    the module docstring)."""
    try:
        text = Path(path).read_text(encoding="latin-1")
    except OSError as e:
        raise BvhError(f"cannot read BVH file {str(path)!r}: {e.strerror}") from e
    return parse_bvh(text, str(path), unit_m, up, forward, floor)
