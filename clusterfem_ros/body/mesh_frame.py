"""A humanoid surface's own frame, read from its shape: which file axis is up, which way it faces, its unit.

``body.surface_unit``, ``skeleton.fit_up`` and ``skeleton.fit_forward`` are ``auto`` by default: a character
file states none of them, and modelling tools disagree (Y up or Z up, metres or centimetres, facing +Z or -Y).
``measure_frame`` reads them from the surface alone, for a human standing in any pose (T, A, arms down):

- the **left-right axis** is the file axis the surface is most nearly mirror-symmetric about (the area-weighted
  mean distance of the triangles' centroids, mirrored through the body's centre, to the nearest centroid);
- the **front-back axis** is the thinner of the other two (a standing body is shallower than it is tall, and
  than it is wide with its arms out), the **up axis** the one left;
- the **head** is the end of the up axis the surface's area lies nearer to (head, trunk and arms above the hips;
  legs are thin);
- the **face** is the side the feet reach further out to (toes in front of the ankles, heels barely behind);
- the **unit** is the first of ``UNITS`` (m, dm, cm, mm, inch) in which the height along up is a human's
  (``HUMAN_HEIGHT_M``); none fitting is an error naming the height and ``body.surface_unit``.

A given (not ``auto``) up axis is kept and the others are read against it; a given forward axis is kept. The
skeleton is fitted to the result (body/fit.py scales it to the skeleton within a factor of 2 of the unit), and
``skeleton.bind_pose 'auto'`` reads the face again from the feet' long axes (body/auto_bind.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fit import FitError

AXES = "XYZ"
# metres per file unit, in the order tried: the first in which the body is a human's height is taken (0.9-2.5 m
# admits one of m, dm, cm, mm for any height; cm before inch, so a 95 cm child is not taken for 2.4 m)
UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "inch": 0.0254}
HUMAN_HEIGHT_M = (0.9, 2.5)
FEET_BAND = 0.04        # the feet: the vertices within this fraction of the height from the bottom


@dataclass(frozen=True)
class MeshFrame:
    lateral: str            # 'X', 'Y' or 'Z'
    up: str                 # 'Y', '-Z', ...: feet to head, as skeleton.fit_up spells it
    forward: str            # the way the face looks, as skeleton.fit_forward spells it
    height: float           # along up [file units]
    unit: str               # a key of UNITS, '' when no unit gives a human's height
    metres_per_unit: float  # nan when unit is ''

    def describe(self) -> str:
        size = (f"{self.height:.4g} file units tall: {self.unit} ({self.height * self.metres_per_unit:.2f} m)"
                if self.unit else f"{self.height:.4g} file units tall: no unit makes that a human's height")
        return f"up {self.up}, forward {self.forward} (left-right {self.lateral}), {size}"


def _signed(axis: int, sign: float) -> str:
    return ("" if sign > 0 else "-") + AXES[axis]


def unit_of_height(height: float) -> str:
    """The first unit of UNITS in which ``height`` file units is a human's height, '' if none."""
    return next((u for u, m in UNITS.items() if HUMAN_HEIGHT_M[0] <= height * m <= HUMAN_HEIGHT_M[1]), "")


def measure_frame(vertices: np.ndarray, triangles: np.ndarray, up: str | None = None) -> MeshFrame:
    """The surface's frame from its shape (the module docstring says how); ``up`` (a signed axis as
    skeleton.fit_up spells it), when given, is kept and the other axes are read against it."""
    from scipy.spatial import cKDTree
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or len(f) == 0 or not np.isfinite(v).all():
        raise FitError(f"the surface has {len(v)} vertices and {len(f)} triangles (finite, 3-D expected): "
                       "no frame can be read from it")
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise FitError("the surface has no area: no frame can be read from it")
    centroids = tri.mean(axis=1)
    centre = (centroids * area[:, None]).sum(axis=0) / area.sum()
    extent = np.ptp(v, axis=0)
    tree = cKDTree(centroids)
    given = None if up is None else AXES.index(up.lstrip("+-"))
    candidates = [a for a in range(3) if a != given]
    asymmetry = {}
    for a in candidates:
        mirrored = centroids.copy()
        mirrored[:, a] = 2.0 * centre[a] - mirrored[:, a]
        asymmetry[a] = float(np.average(tree.query(mirrored)[0], weights=area))
    lateral = min(candidates, key=lambda a: asymmetry[a])
    if given is None:
        depth = min((a for a in range(3) if a != lateral), key=lambda a: extent[a])
        up_axis = 3 - lateral - depth
    else:
        up_axis, depth = given, 3 - lateral - given
    lo, hi = v[:, up_axis].min(), v[:, up_axis].max()
    height = float(hi - lo)
    if given is None:
        up_sign = 1.0 if centre[up_axis] - lo > 0.5 * height else -1.0
    else:
        up_sign = -1.0 if up.startswith("-") else 1.0
    feet_level = lo + FEET_BAND * height if up_sign > 0 else hi - FEET_BAND * height
    feet = v[(v[:, up_axis] <= feet_level) if up_sign > 0 else (v[:, up_axis] >= feet_level), depth]
    forward_sign = 1.0 if feet.max() - centre[depth] > centre[depth] - feet.min() else -1.0
    unit = unit_of_height(height)
    return MeshFrame(AXES[lateral], _signed(up_axis, up_sign), _signed(depth, forward_sign), height, unit,
                     UNITS[unit] if unit else float("nan"))


def resolve_frame(vertices: np.ndarray, triangles: np.ndarray, unit, up: str,
                  forward: str) -> tuple[float, str, str, str | None]:
    """(metres per file unit, up, forward, the log line saying what was read, or None when nothing is ``auto``) for
    ``body.surface_unit`` = ``unit`` (a number, a unit name or 'auto'), ``skeleton.fit_up`` = ``up`` and
    ``skeleton.fit_forward`` = ``forward`` ('auto' or a signed axis). FitError names the parameter to set when the
    surface's height is no human's in any unit, or when a given forward lies along the up axis read."""
    from ..skeleton.bvh_placement import parse_unit
    try:
        parsed = parse_unit(unit)
    except ValueError as exc:
        raise FitError(f"body.surface_unit: {exc}") from None
    auto_up, auto_forward = up == "auto", forward == "auto"
    if parsed is not None and not auto_up and not auto_forward:
        return parsed[1], up, forward, None
    frame = measure_frame(vertices, triangles, None if auto_up else up)
    if parsed is None and not frame.unit:
        raise FitError(f"the surface is {frame.height:.4g} file units tall along its up axis {frame.up}: in none "
                       f"of {', '.join(UNITS)} is that a standing human's height ({HUMAN_HEIGHT_M[0]:g}-"
                       f"{HUMAN_HEIGHT_M[1]:g} m); set body.surface_unit to the metres per file unit")
    up_out = frame.up if auto_up else up
    forward_out = frame.forward if auto_forward else forward
    if forward_out.lstrip("+-") == up_out.lstrip("+-"):
        raise FitError(f"skeleton.fit_forward = {forward!r} lies along the surface's up axis {up_out} (read from its "
                       "shape): give the axis the character faces, or 'auto'")
    metres = frame.metres_per_unit if parsed is None else parsed[1]
    read = [what for what, is_auto in (("unit", parsed is None), ("up", auto_up), ("forward", auto_forward))
            if is_auto]
    line = (f"surface frame read from its shape ({', '.join(read)}): {frame.describe()}; taken: up {up_out}, "
            f"forward {forward_out}, {metres:g} m per file unit (set body.surface_unit, skeleton.fit_up, "
            "skeleton.fit_forward to override)")
    return float(metres), up_out, forward_out, line
