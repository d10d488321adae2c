"""Where a BVH capture stands: its length unit, its up and forward axes and its floor, decided from the skeleton.

A BVH file states none of these. They are read from the geometry of the skeleton's rest pose (every joint
rotation zero; OFFSETs summed from the root) and of its frames, each with an override:

* **up / forward** (``up``: ``auto``, ``X``, ``Y``, ``Z``, ``-X`` ...): the *pelvis* is the first joint below
  the root with two or more child chains; its legs are the two child chains with the fewest end points (a leg
  ends in a toe, the spine in a head and two hands); each foot is the end point of its leg farthest from the
  pelvis. Up is the file axis nearest to pelvis - mean(feet) as the frames pose them (the median direction over
  up to 200 frames spread over the clip; the rest pose's when the file has none): the capture's world decides,
  whatever pose the rig rests in. Forward is the horizontal axis nearest to the
  horizontal part of mean(feet) - pelvis: the hips' sideways offsets cancel left against right and the toes
  point forward. A skeleton without two legs keeps the BVH convention, Y up and Z forward, and says so.
* **unit** (``auto``, ``m``, ``cm``, ``mm``, ``inch``, ``cmu`` (0.056444 m, the CMU conversions) or metres per
  unit as a number): the stature in file units is estimated from the rest pose's extent along its own
  feet-to-pelvis axis (head to feet) and from the pelvis height over the feet (a standing adult's hip is at ``HIP_RATIO`` of the stature),
  their geometric mean when both are sound; the unit is the one of ``UNITS`` that makes that stature nearest to
  ``STANDING_HEIGHT`` (by ratio). A skeleton whose height in the unit chosen (or given) is outside
  ``HEIGHT_RANGE`` is refused (``PlacementError``, a ``BvhError`` from ``parse_bvh``) naming the parameter.
* **floor**: the lowest point of the body (joints and end sites, all frames played as the file gives them) is
  put at z = 0; a few frames below the others (``FLOOR_PERCENTILE``: a glitch that kicks a foot through the
  floor) do not count. The shift is applied to the skeleton's root link in the URDF, the joint values are
  untouched. ``floor=False`` keeps the file's own height.

``place(motion, unit, up, forward, floor)`` returns the decisions (``Placement``) for a parsed ``BvhMotion``
(read through its attributes: this module is below ``bvh.py``, which applies them), with the one line that
says what was decided (``BvhMotion.placement``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import ClusterFemError

CMU_UNIT_M = 0.056444           # m per unit of the CMU conversions
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "cmu": CMU_UNIT_M}
STANDING_HEIGHT = 1.7           # m: the prior the unit is chosen by
HIP_RATIO = 0.53                # hip joint height over stature of a standing adult
HEIGHT_RANGE = (0.5, 3.0)       # m: a skeleton outside this after the unit is refused
FLOOR_PERCENTILE = 2.0          # the floor is this percentile of the per-frame lowest point
AXES = ("X", "Y", "Z", "-X", "-Y", "-Z")
_DEFAULT_FORWARD = {"X": "Z", "Y": "Z", "Z": "X"}


class PlacementError(ClusterFemError, ValueError):
    """A skeleton no unit makes a standing human; the message names the parameters that set it."""


@dataclass(frozen=True)
class Placement:
    unit_name: str
    unit_m: float                   # metres per file unit
    up: str                         # signed file axes, e.g. "Y", "-Z"
    forward: str
    root_shift: np.ndarray          # (3,) [m, ROS] added to the root's origin (the floor under the feet)
    text: str                       # the one log line
    height_m: float                 # the rest pose's extent along up [m]


def parse_unit(value) -> tuple[str, float] | None:
    """(name, metres per file unit) of a unit parameter, None for 'auto'; ValueError naming the choices."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        text = repr(float(value))
    else:
        text = str(value).strip().lower()
    if text in ("", "auto"):
        return None
    if text in UNITS:
        return text, UNITS[text]
    if text == "in":
        return "inch", UNITS["inch"]
    try:
        metres = float(text)
    except ValueError:
        metres = float("nan")
    if not (np.isfinite(metres) and metres > 0):
        raise ValueError(f"unit {value!r}: give auto, {', '.join(UNITS)} or the metres per file unit as a positive "
                         "number")
    return f"{metres:g} m", metres


def parse_axis(value, what: str = "up") -> str | None:
    """A signed file axis ('Y', '-Z', '+X') of an axis parameter, None for 'auto'; ValueError naming the choices."""
    text = str(value).strip().upper().lstrip("+")
    if text in ("", "AUTO"):
        return None
    if text not in AXES:
        raise ValueError(f"{what} axis {value!r}: give auto or one of {', '.join(AXES)}")
    return text


def _signed_axis(v: np.ndarray, exclude: str = "") -> str:
    """The signed file axis ('Y', '-Z') nearest to direction v, among the axes other than ``exclude``'s."""
    allowed = [k for k in range(3) if "XYZ"[k] != exclude.lstrip("-")]
    k = max(allowed, key=lambda i: abs(v[i]))
    return ("-" if v[k] < 0 else "") + "XYZ"[k]


def _axis_vector(axis: str) -> np.ndarray:
    e = np.zeros(3)
    e["XYZ".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    return e


def rest_points(motion) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """Rest pose in file units: (joint heads (J, 3), end points (J, 3): the end site, or the head of a joint
    without children or end site; NaN for inner joints, children lists)."""
    J = len(motion.joints)
    heads = np.zeros((J, 3))
    children: list[list[int]] = [[] for _ in range(J)]
    for k, j in enumerate(motion.joints):
        if j.parent >= 0:
            heads[k] = heads[j.parent] + j.offset
            children[j.parent].append(k)
    ends = np.full((J, 3), np.nan)
    for k, j in enumerate(motion.joints):
        if j.end_site is not None:
            ends[k] = heads[k] + j.end_site
        elif not children[k]:
            ends[k] = heads[k]
    return heads, ends, children


def find_legs(motion) -> tuple[int, list[int]] | None:
    """(pelvis joint, the two foot end points as joint indices into ``rest_points``' ends), or None."""
    heads, ends, children = rest_points(motion)
    pelvis = 0
    while len(children[pelvis]) == 1:
        pelvis = children[pelvis][0]
    if len(children[pelvis]) < 2:
        return None

    def subtree(k: int) -> list[int]:
        out, stack = [], [k]
        while stack:
            n = stack.pop()
            out.append(n)
            stack += children[n]
        return out

    chains = []
    for c in children[pelvis]:
        tips = [n for n in subtree(c) if np.isfinite(ends[n]).all()]
        reach = [float(np.linalg.norm(ends[n] - heads[pelvis])) for n in tips]
        chains.append((len(tips), -max(reach), tips[int(np.argmax(reach))]))
    if len(chains) == 2 and chains[0][0] != chains[1][0]:
        return None                                   # a leg and a spine, or two unlike limbs: not a pair of legs
    chains.sort()
    feet = [chains[0][2], chains[1][2]]
    if np.linalg.norm(ends[feet].mean(0) - heads[pelvis]) <= 0:
        return None
    return pelvis, feet


def posed_down(motion, pelvis: int, feet: list[int], samples: int = 200) -> np.ndarray | None:
    """The median unit direction from the pelvis to the middle of the feet over up to ``samples`` frames spread
    over the clip, in file axes (None without frames): where the capture's world has its floor, whatever pose the
    rig rests in (a rig whose bones lie along their parents' axes until the frames pose them)."""
    if motion.n_frames == 0:
        return None
    rows = np.unique(np.linspace(0, motion.n_frames - 1, min(samples, motion.n_frames)).round().astype(int))
    points = world_points(motion, rows)
    J = len(motion.joints)
    with_end = [k for k, j in enumerate(motion.joints) if j.end_site is not None]
    tips = [J + with_end.index(k) if motion.joints[k].end_site is not None else k for k in feet]
    down = points[:, tips].mean(axis=1) - points[:, pelvis]
    length = np.linalg.norm(down, axis=1, keepdims=True)
    if not (length > 0).any():
        return None
    return np.median(down[length[:, 0] > 0] / length[length[:, 0] > 0], axis=0)


def rest_up(motion) -> str:
    """The signed file axis from the feet to the pelvis in the rest pose (Y without a pair of legs): the axis the
    rest pose's stature is measured along."""
    legs = find_legs(motion)
    if legs is None:
        return "Y"
    heads, ends, _ = rest_points(motion)
    return _signed_axis(heads[legs[0]] - ends[legs[1]].mean(0))


def detect_axes(motion, up: str | None = None, forward: str | None = None) -> tuple[str, str, str]:
    """(up, forward, how they were found) as signed file axes; given axes are kept (see the module docstring)."""
    legs = find_legs(motion)
    heads, ends, _ = rest_points(motion)
    how = "given"
    if legs is not None:
        pelvis, feet = legs
        down = ends[feet].mean(0) - heads[pelvis]
        if up is None:
            posed = posed_down(motion, pelvis, feet)
            if posed is not None and np.linalg.norm(posed) > 0.5:
                up, how = _signed_axis(-posed), "from the legs in the frames"
            else:
                up, how = _signed_axis(-down), "from the legs"
        if forward is None:
            horizontal = down - np.dot(down, _axis_vector(up)) * _axis_vector(up)
            if np.linalg.norm(horizontal) > 0.05 * np.linalg.norm(down):
                forward = _signed_axis(horizontal, exclude=up)
    elif up is None:
        up, how = "Y", "the BVH convention (no pair of legs found)"
    if forward is None or forward.lstrip("-") == up.lstrip("-"):
        forward = _DEFAULT_FORWARD[up.lstrip("-")]
    return up, forward, how


def stature_file_units(motion, up: str) -> tuple[float, float]:
    """(rest pose extent along ``up``, stature estimate) in file units (see the module docstring)."""
    heads, ends, _ = rest_points(motion)
    u = _axis_vector(up)
    pts = np.vstack([heads, ends[np.isfinite(ends).all(1)]]) @ u
    extent = float(pts.max() - pts.min())
    legs = find_legs(motion)
    if legs is None:
        return extent, extent
    hip = float(heads[legs[0]] @ u - pts.min())
    if not 0.3 * extent < hip < 0.75 * extent:      # not a standing pelvis over its feet: the extent alone
        return extent, extent
    return extent, float(np.sqrt(extent * hip / HIP_RATIO))


def choose_unit(stature: float) -> tuple[str, float]:
    """(name, metres) of the unit of ``UNITS`` that makes ``stature`` (file units) nearest to STANDING_HEIGHT."""
    if not stature > 0:
        return "cmu", CMU_UNIT_M
    name = min(UNITS, key=lambda n: abs(np.log(stature * UNITS[n] / STANDING_HEIGHT)))
    return name, UNITS[name]


def _local_rotations(motion, k: int, rows: np.ndarray) -> np.ndarray:
    """(F, 3, 3) joint k's rotation channels in file order (intrinsic: "Zrotation Xrotation" is Rz Rx)."""
    j = motion.joints[k]
    rot = [i for i, c in enumerate(j.channels) if c.endswith("rotation")]
    if not rot:
        return np.broadcast_to(np.eye(3), (rows.size, 3, 3))
    order = "".join(j.channels[i][0] for i in rot)
    angles = motion.frames[np.ix_(rows, [j.channel_start + i for i in rot])]
    return Rotation.from_euler(order, angles, degrees=True).as_matrix().reshape(rows.size, 3, 3)


def world_points(motion, frames: np.ndarray | None = None) -> np.ndarray:
    """(F, P, 3) every joint head and end site in file units and axes over the frames (all by default): the root at
    its position channels (its OFFSET along axes it has no channel for), as the BVH format defines it."""
    rows = np.arange(motion.n_frames) if frames is None else np.asarray(frames)
    F = rows.size
    J = len(motion.joints)
    R = np.zeros((F, J, 3, 3))
    p = np.zeros((F, J, 3))
    tips = []
    for k, j in enumerate(motion.joints):
        local = _local_rotations(motion, k, rows)
        if j.parent < 0:
            p[:, k] = root_position(motion)[rows]
            R[:, k] = local
        else:
            p[:, k] = p[:, j.parent] + R[:, j.parent] @ j.offset
            R[:, k] = R[:, j.parent] @ local
        if j.end_site is not None:
            tips.append(p[:, k] + R[:, k] @ j.end_site)
    return np.concatenate([p, np.stack(tips, axis=1)], axis=1) if tips else p


def root_position(motion) -> np.ndarray:
    """(F, 3) the root's position in file units: its position channels, its OFFSET along axes without one."""
    root = motion.joints[0]
    pos = np.broadcast_to(root.offset, (motion.n_frames, 3)).copy()
    for k, c in enumerate(root.channels):
        if c.endswith("position"):
            pos[:, "XYZ".index(c[0])] = motion.frames[:, root.channel_start + k]
    return pos


def place(motion, unit="auto", up="auto", forward="auto", floor: bool = True) -> Placement:
    """The unit, axes and floor of ``motion`` (see the module docstring); PlacementError for a skeleton that is no
    standing human in the unit chosen or given."""
    given_unit = parse_unit(unit)
    up_axis, fwd_axis, how = detect_axes(motion, parse_axis(up, "up"), parse_axis(forward, "forward"))
    extent, stature = stature_file_units(motion, rest_up(motion) if parse_axis(up, "up") is None else up_axis)
    if given_unit is None:
        name, metres = choose_unit(stature)
        why = "found from the skeleton"
    else:
        name, metres = given_unit
        why = "given"
    height = extent * metres
    if not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
        raise PlacementError(
            f"{motion.source}: the skeleton is {height:.3g} m tall in unit {name} ({extent:.4g} file units along "
            f"{up_axis}): not a human between {HEIGHT_RANGE[0]:g} and {HEIGHT_RANGE[1]:g} m; set the player's 'unit' "
            "parameter (the scene's skeleton.bvh_unit) to the file's unit (m, cm, mm, inch, cmu or metres per "
            "unit) or 'up' (skeleton.bvh_up) to its up axis")
    text = (f"{motion.source}: unit {name} ({metres:g} m per file unit, {why}), skeleton {height:.2f} m tall "
            f"(rest pose, feet to head), up {up_axis} forward {fwd_axis} ({how})")
    shift = np.zeros(3)
    if floor:
        z = world_points(motion) @ _axis_vector(up_axis) * metres
        lowest = float(np.percentile(z.min(axis=1), FLOOR_PERCENTILE))
        shift[2] = -lowest
        text += f", floor under the feet (root moved {-lowest:+.3f} m)"
    return Placement(name, float(metres), up_axis, fwd_axis, shift, text, float(height))
