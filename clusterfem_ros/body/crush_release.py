"""Letting go where the targets crush the flesh: a bound vertex's gains fall as its bones' targets squeeze its elements.

Each bound vertex is pulled to a rigid target on its own bone (``binding.bind_to_skeleton``). An element whose four
vertices are bound to one bone keeps its volume in that target field exactly; an element spanning two or more bones
does not: where a joint folds hard (a hip or knee bent past 90 degrees, a spine curled in a backflip) the bones'
targets overlap inside the fold, and such elements' targets have a fraction of their rest volume or less, inverted
at worst. The body follows (``python -m benchmarks.volume_where``: the target field loses as much as the body).

Here, every step, the target field's volume ratio ``r = V* / V0`` of each spanning element is computed from the
targets the driver has just made; each vertex takes the smallest ratio of its spanning elements, and its gains kp
and kd are scaled by ``g = clip((r - floor) / (1 - floor), 0, 1)`` and ``sqrt(g)`` (the damping ratio kept): 1 while
the targets keep the volume (to round-off: ``KEPT``), 0 (free, carried by the flesh around it) once they crush it to ``floor`` of its rest
volume or below. A vertex whose elements the targets stretch keeps its gains. Which elements span bones is decided
once at bind time from the binding (no bone names); the stiffest gains never rise, so the integrator's sub-step plan
(``Attachments.gain_max``) stays an upper bound.

Array conventions: rows index the driver's bound vertices (``SkeletonDriver.bound``); ``v0`` is six times the
signed rest volume of each spanning element.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ..numba_config import HOLDS_GIL
from .binding import Binding


KEPT = 1.0 - 1.0e-9     # a target volume ratio this close to 1 is kept volume (a rigid motion's round-off): full gains


@dataclass(frozen=True)
class CrushRelease:
    """The spanning elements of a driver's bound vertices and the floor of the gains' fall (see the module docstring)."""
    rows: np.ndarray        # (k, 4) int64: the elements' corners as rows of the driver's bound vertices
    v0: np.ndarray          # (k,) float64: six times each element's signed rest volume (> 0)
    touched: np.ndarray     # (t,) int64: the rows that are a corner of at least one of them, ascending
    floor: float            # target volume ratio at which a vertex is let go entirely

    def summary(self) -> str:
        return (f"crush release: {self.rows.shape[0]} elements span two or more bones ({self.touched.size} vertices "
                f"bound); a vertex's gains fall to 0 as its bones' targets crush them to {self.floor:g} of their volume")


def crush_release(binding: Binding, tets: np.ndarray, rest_vertices: np.ndarray, bound: np.ndarray,
                  floor: float, held_bones: np.ndarray | None = None) -> CrushRelease | None:
    """The ``CrushRelease`` of the elements of ``tets`` (m, 4) whose corners are all in ``bound`` (the driver's bound
    vertices, in its row order) and bound to two or more bones, none of them one of ``held_bones`` (bone indices:
    a hand's fingers, whose flesh has no flesh around it to carry it when let go); None when ``floor`` is 0 (off) or
    no element spans bones. ``floor`` in [0, 1)."""
    if not (np.isfinite(floor) and 0.0 <= floor < 1.0):
        raise ValueError(f"crush release floor {floor!r} must be in [0, 1): the target volume ratio at which a "
                         "vertex is let go (0 = off)")
    if floor == 0.0:
        return None
    tets = np.asarray(tets, dtype=np.int64)
    x = np.asarray(rest_vertices, dtype=np.float64)
    row_of = np.full(x.shape[0], -1, dtype=np.int64)
    row_of[np.asarray(bound, dtype=np.int64)] = np.arange(len(bound))
    rows = row_of[tets]
    bones = binding.bone[tets]
    span = (rows >= 0).all(axis=1) & (bones != bones[:, :1]).any(axis=1)
    if held_bones is not None and len(held_bones):
        span &= ~np.isin(bones, np.asarray(held_bones, dtype=np.int64)).any(axis=1)
    if not span.any():
        return None
    e = x[tets[span, 1:]] - x[tets[span, :1]]
    v0 = np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2])
    if not (v0 > 0).all():
        k = int(np.flatnonzero(span)[np.argmin(v0)])
        raise ValueError(f"tet {k} has signed volume {v0.min() / 6:.3g} m^3 at rest: the mesh is inverted or "
                         "degenerate; fix the mesh")
    r = np.ascontiguousarray(rows[span])
    return CrushRelease(rows=r, v0=np.ascontiguousarray(v0), touched=np.unique(r), floor=float(floor))


@numba.njit(**HOLDS_GIL)
def release_gains(x, rows, v0, touched, floor, kp0, kd0, kp, kd, ratio):
    """Kernel: kp, kd (n,) = kp0, kd0 scaled at the ``touched`` rows by the target field ``x`` (n, 3)'s smallest volume
    ratio over each row's elements ``rows`` (k, 4) (rest volumes ``v0``), as the module docstring says; ``ratio`` (n,)
    scratch. Rows not touched are left as they are (kp0, kd0 once, at the start)."""
    for j in range(touched.shape[0]):
        ratio[touched[j]] = 1.0
    for e in range(rows.shape[0]):
        a, b, c, d = rows[e, 0], rows[e, 1], rows[e, 2], rows[e, 3]
        e10, e11, e12 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        e20, e21, e22 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        e30, e31, e32 = x[d, 0] - x[a, 0], x[d, 1] - x[a, 1], x[d, 2] - x[a, 2]
        r = ((e11 * e22 - e12 * e21) * e30 + (e12 * e20 - e10 * e22) * e31 + (e10 * e21 - e11 * e20) * e32) / v0[e]
        for k in (a, b, c, d):
            if r < ratio[k]:
                ratio[k] = r
    span = 1.0 - floor
    for j in range(touched.shape[0]):
        k = touched[j]
        if ratio[k] >= KEPT:
            kp[k], kd[k] = kp0[k], kd0[k]
            continue
        g = (ratio[k] - floor) / span
        g = 0.0 if g < 0.0 else g
        kp[k] = kp0[k] * g
        kd[k] = kd0[k] * np.sqrt(g)
