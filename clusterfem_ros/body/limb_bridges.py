"""Tets that join a character's left and right limbs: a mesher's bridge across a gap narrower than its elements.

A mesh whose legs touch (feet together, an arms-down figure's inner ankles) or whose gap between them is narrower
than the tets fTetWild makes at a small ``body.target_tets`` comes out of the mesher as one solid: the tets across
the gap join the flesh of the left shin to the right's, and the first stride tears them (a vertex dragged 0.3 m
from its bone, a reset). Such a tet is found from the skeleton: its corners lie nearest (each to the segment of
its nearest bone that binds) to bones of limbs of opposite sides (bone_roles: 'l' and 'r', limb roles only) and
none to the trunk, the girdles or the head: no flesh of a human joins two limbs but through the trunk (the crotch's
tets with a corner on the pelvis stay). ``cut_bridges`` removes them and the vertices left in no tet.
"""
from __future__ import annotations

import numpy as np

from ..fem.mesh.tet_mesh import TetMesh
from .binding import segment_distance

LIMB_ROLES = ("upper_arm", "forearm", "hand", "finger", "thigh", "shin", "foot", "toe")


def bridge_tets(vertices: np.ndarray, tets: np.ndarray, starts: np.ndarray, ends: np.ndarray, roles,
                binds: np.ndarray) -> np.ndarray:
    """(m,) bool: the tets with corners nearest to limb bones of both sides and none to another bone (``roles``:
    bone_roles.BoneRoles;
    ``binds`` (nb,) bool: the bones that bind flesh, the only ones a corner is measured to)."""
    side = np.array([s if r in LIMB_ROLES else "" for r, s in zip(roles.roles, roles.sides)])
    use = np.flatnonzero(binds)
    nearest = use[np.argmin(segment_distance(np.asarray(vertices, dtype=np.float64), starts[use], ends[use]),
                            axis=1)]
    corner = side[nearest][np.asarray(tets)]
    return (corner == "l").any(axis=1) & (corner == "r").any(axis=1) & ~(corner == "").any(axis=1)


def cut_bridges(mesh: TetMesh, bridges: np.ndarray) -> TetMesh:
    """``mesh`` without the tets ``bridges`` marks and the vertices then in no tet (kept in order)."""
    tets = mesh.tets[~bridges]
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[tets.reshape(-1)] = True
    index = np.cumsum(used) - 1
    return TetMesh(mesh.vertices[used], index[tets]).validate()
