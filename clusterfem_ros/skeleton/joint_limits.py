"""What values a skeleton's scalar joints may take, read from the URDF: ranges to check, angles to wrap, mimics.

A joint value from the world is taken when it makes sense for the joint (skeleton/joint_map.py applies this):

* a ``continuous`` joint, a ``revolute`` joint whose URDF range spans a full turn or more (every angle is
  reachable: our generated skeletons' joints span [-pi, pi], a BVH's channels [-1e4, 1e4] rad) and a revolute
  joint of the root (``root``: no bone above it, ``Skeleton.root_joint_mask``) is an angle: any finite value
  is wrapped to [-pi, pi) on arrival (the joint stream then unwraps it against the previous sample, so motion
  stays continuous);
* a prismatic joint of the root has no range here: the joint stream bounds the root's distance from the
  origin by input.max_root_distance (root_range), which a user raises for a scene that needs it;
* any other ``revolute`` or ``prismatic`` joint must lie within its URDF ``<limit lower upper>`` widened by
  ``margin`` times the range (upper - lower) on each side, plus ``LIMIT_FLOOR`` (so a joint whose limits
  coincide takes its own value despite round-off); beyond, the value is refused;
* a ``<mimic joint= multiplier= offset=>`` joint that a message does not name follows its master:
  q = multiplier q_master + offset (URDF defaults 1 and 0); one that a message names is checked like any other.

Decided from the URDF's numbers, never from names. A revolute or prismatic joint without a ``<limit>`` (urdfdom
refuses one; Pinocchio then does too) has no range here. Units: rad and m.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Sequence

import numpy as np

FULL_TURN = 2.0 * np.pi * (1.0 - 1e-9)      # a revolute range at least this wide is a full circle
LIMIT_FLOOR = 1e-9                           # rad or m added to every margin


@dataclass(frozen=True)
class JointLimits:
    """Per scalar joint, in the skeleton's joint order: the accepted interval, the angles wrapped, the mimics."""
    lower: np.ndarray           # (n,) lowest value taken (-inf: no limit) [rad, m]
    upper: np.ndarray           # (n,) highest value taken (+inf: no limit)
    wrap: np.ndarray            # (n,) bool: an angle wrapped to [-pi, pi) on arrival
    mimic: tuple[tuple[int, int, float, float], ...] = ()   # (joint, master, multiplier, offset), by index

    @classmethod
    def none(cls, n: int) -> "JointLimits":
        """No range, no wrap, no mimic: every finite value taken as it is."""
        return cls(np.full(n, -np.inf), np.full(n, np.inf), np.zeros(n, dtype=bool))


def _float(element: ET.Element | None, attr: str, default: float) -> float:
    try:
        value = float(element.get(attr, default)) if element is not None else default
    except ValueError:
        return default
    return value if np.isfinite(value) else default


def joint_limits(xml: str, joint_names: Sequence[str], margin: float, root: np.ndarray | None = None) -> JointLimits:
    """The limits of ``joint_names`` (a skeleton's scalar joints) from the URDF text; ``root`` (n,) bool marks the
    root's joints (see the module docstring)."""
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"joint limit margin = {margin!r}: give a finite fraction of the range >= 0")
    joints = {j.get("name"): j for j in ET.fromstring(xml).findall("joint")}
    index = {n: k for k, n in enumerate(joint_names)}
    n = len(joint_names)
    out = JointLimits.none(n)
    mimic = []
    for k, name in enumerate(joint_names):
        j = joints.get(name)
        if j is None:
            continue
        kind = j.get("type")
        limit = j.find("limit")
        at_root = root is not None and bool(root[k])
        if kind == "continuous" or (kind == "revolute" and at_root):
            out.wrap[k] = True
        elif at_root:
            pass                                    # a root translation: input.max_root_distance bounds it
        elif kind in ("revolute", "prismatic") and limit is not None:
            lo, hi = _float(limit, "lower", 0.0), _float(limit, "upper", 0.0)
            span = hi - lo
            if kind == "revolute" and span >= FULL_TURN:
                out.wrap[k] = True
            elif span >= 0:
                pad = margin * span + LIMIT_FLOOR
                out.lower[k], out.upper[k] = lo - pad, hi + pad
        m = j.find("mimic")
        if m is not None and m.get("joint") in index and m.get("joint") != name:
            mimic.append((k, index[m.get("joint")], _float(m, "multiplier", 1.0), _float(m, "offset", 0.0)))
    return JointLimits(out.lower, out.upper, out.wrap, tuple(mimic))
