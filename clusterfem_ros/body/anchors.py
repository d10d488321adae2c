"""Anchors: the vertices near given points held there by point constraints, as a scene file declares them.

A scene lists world points of the body's rest pose (``anchors.points``); every vertex within
``anchors.radius`` of a point is held at its rest position, fixed in the world, or carried by a bone
(``anchors.bones``: one name per point, '' for the world) like a point on that bone. They are the paper's
point constraints (``PointConstraint``) with the anchor gains, chosen by place rather than by vertex index,
which changes with the mesh resolution. A point on a bone may instead slide (``anchors.sliding``): its
vertices get the paper's line constraints (``LineConstraint``), kept at their distance from the bone's axis
and free along it between the bone's ends.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .constraints import LineConstraint, PointConstraint


def anchor_constraints(rest: np.ndarray, points: Sequence[float], radius: float, kp: float, kd: float,
                       bones: Sequence[str] = (), bone_names: Sequence[str] | None = None,
                       sliding: Sequence[bool] = ()) -> list[PointConstraint | LineConstraint]:
    """Point constraints for every vertex of ``rest`` (n, 3) within ``radius`` of each point of ``points``
    (flat x, y, z, ...). ``bones``: per point a bone name of ``bone_names`` or '' (world); empty: all world.
    ``sliding``: per point, True gives its vertices line constraints along their bone, stopped at its ends
    (``LineConstraint(within_bone=True)``); empty: none slide.
    Raises ValueError naming the point when no vertex is that close (with the nearest distance), a bone
    is unknown or a sliding point has none; a vertex near two points is held once, by the first."""
    p = np.asarray(points, dtype=np.float64).reshape(-1)
    if p.size % 3 or not np.isfinite(p).all():
        raise ValueError(f"anchors.points = {list(p)}: give finite x, y, z triples in metres")
    p = p.reshape(-1, 3)
    bones = list(bones) or [""] * len(p)
    if len(bones) != len(p):
        raise ValueError(f"anchors.bones has {len(bones)} names for {len(p)} anchor points: give one per point "
                         "('' for a point fixed in the world), or none")
    sliding = list(sliding) or [False] * len(p)
    if len(sliding) != len(p):
        raise ValueError(f"anchors.sliding has {len(sliding)} values for {len(p)} anchor points: give one per point, "
                         "or none")
    names = list(bone_names or [])
    out: list[PointConstraint | LineConstraint] = []
    taken: set[int] = set()
    for k, (point, bone) in enumerate(zip(p, bones)):
        b = None
        if bone:
            if bone not in names:
                raise ValueError(f"anchors.bones[{k}] = {bone!r} is not a bone of the skeleton "
                                 f"({', '.join(names[:8])}{', ...' if len(names) > 8 else ''}); use one of them "
                                 "or '' to fix the point in the world")
            b = names.index(bone)
        elif sliding[k]:
            raise ValueError(f"anchor point {k} slides (anchors.sliding) but has no bone: name its bone in "
                             "anchors.bones, or set sliding to false")
        d = np.linalg.norm(rest - point, axis=1)
        near = np.flatnonzero(d <= radius)
        if near.size == 0:
            raise ValueError(f"anchor point {k} at {point.tolist()} has no vertex within anchors.radius = {radius:g} m "
                             f"(the nearest is {d.min():.3g} m away): move the point onto the body or raise the radius")
        for i in near.tolist():
            if i in taken:
                continue
            taken.add(i)
            if sliding[k]:
                out.append(LineConstraint(i, b, kp=kp, kd=kd, within_bone=True))
            elif b is not None:
                out.append(PointConstraint(i, bone=b, kp=kp, kd=kd))
            else:
                out.append(PointConstraint(i, world=tuple(rest[i]), kp=kp, kd=kd))
    return out
