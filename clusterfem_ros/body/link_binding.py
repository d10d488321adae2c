"""Binding a robot's cover to its links: every vertex to the bone of its own link, in levels by depth.

A robot cover (skeleton/robot_cover.py) knows each vertex's link and its depth: its distance to the link's
surface, negative inside. The nearest-segment rule of ``binding.bind_to_skeleton`` would bind a vertex of a
gripper finger to the hand, or a vertex of one link to its neighbour across a joint, gluing what the cover
keeps apart; here the bone is given. Levels go by depth: level 0 holds the vertices on or in their link
(depth <= ``core``), the next levels the skin outwards, up to the outermost, which holds the rest: every
vertex is bound (no flesh hangs free on a robot). A bone whose vertices all lie beyond ``core`` (a link
thinner than a voxel) gets its innermost vertices (within ``core`` of its smallest depth) in level 0, so every
covered link holds its part firmly.

``Binding.distance`` stays the distance to the bone's segment at rest, as the output check
(``body/bone_distance.py``) measures it; ``Binding.level_radii`` hold the depths that bound the levels [m].
"""
from __future__ import annotations

import numpy as np

from .binding import Binding, segment_distance


def bind_to_links(rest_vertices: np.ndarray, bone: np.ndarray, depth: np.ndarray, levels: int, core: float,
                  skin: float, starts: np.ndarray, ends: np.ndarray, rest_rotation: np.ndarray,
                  rest_translation: np.ndarray) -> Binding:
    """The binding of the module docstring: ``levels`` levels, level 0 up to depth ``core`` [m], the others spread
    evenly up to depth ``skin`` [m] and beyond it (the outermost takes the rest). Bones (nb, 3) at rest."""
    x = np.asarray(rest_vertices, dtype=np.float64)
    bone = np.asarray(bone, dtype=np.int64).reshape(-1)
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    nb = np.asarray(starts).shape[0]
    if bone.shape != (x.shape[0],) or depth.shape != (x.shape[0],):
        raise ValueError(f"bone {bone.shape} and depth {depth.shape} need one entry per vertex ({x.shape[0]})")
    if bone.size and (bone.min() < 0 or bone.max() >= nb):
        raise ValueError(f"bone indices span {bone.min()}..{bone.max()}, the skeleton has bones 0..{nb - 1}")
    if not (isinstance(levels, (int, np.integer)) and levels >= 1):
        raise ValueError(f"levels = {levels!r}: give a whole number >= 1")
    if not (np.isfinite(depth).all() and 0 < core <= skin):
        raise ValueError(f"depths must be finite and 0 < core ({core!r}) <= skin ({skin!r}) [m]")
    radii = np.linspace(core, max(skin, 1.5 * core), levels) if levels > 1 else np.array([core])
    level = np.minimum(np.searchsorted(radii, depth, side="left"), levels - 1).astype(np.int64)
    for b in np.unique(bone):
        mine = bone == b
        if not (level[mine] == 0).any():
            level[mine & (depth <= depth[mine].min() + core)] = 0
    R0 = np.asarray(rest_rotation, dtype=np.float64)
    p0 = np.asarray(rest_translation, dtype=np.float64)
    s, e = np.asarray(starts, dtype=np.float64), np.asarray(ends, dtype=np.float64)
    distance = np.empty(x.shape[0])
    for b in np.unique(bone):
        mine = np.flatnonzero(bone == b)
        distance[mine] = segment_distance(x[mine], s[b:b + 1], e[b:b + 1])[:, 0]
    local = np.einsum("nji,nj->ni", R0[bone], x - p0[bone])
    axis_local = np.stack([np.einsum("bji,bj->bi", R0, s - p0), np.einsum("bji,bj->bi", R0, e - p0)], axis=1)
    return Binding(bone=bone, distance=distance, level=level, local=local, level_radii=radii, rest_rotation=R0,
                   rest_translation=p0, axis_local=axis_local, warnings=[])
