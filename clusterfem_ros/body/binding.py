"""Binding a soft body to a skeleton (the paper's section 4.1): nearest bone and nested levels.

Every vertex is bound, in the rest pose, to the bone whose *segment* (start -> end) is nearest. Its
distance to that segment puts it in a level: level k holds the vertices with
``level_radii[k-1] < d <= level_radii[k]``, so the paper's nested sets are
Omega'_1 = {level 0} ⊂ Omega'_2 = {level <= 1} ⊂ ... (``Binding.level_set(k)``). Vertices beyond the
last radius are free flesh (level -1). The paper speaks of distance to the bone axis; we measure to
the segment, so flesh beyond a bone's end (a fingertip, the top of the head) is not bound by an
infinite line.

On a real character (``surface_depth`` given: each vertex's distance to the body's surface) the radii are
fractions of the local flesh thickness instead of metres: a vertex's relative depth is
``d / (d + depth)``, 0 on the bone and 1 on the skin, so a finger and a thigh both get a core of the same
share of their thickness.

Array conventions: vertices (n, 3) float64 [m]; bones (nb, 3) segment ends [m]; rest placements
``rest_rotation`` (nb, 3, 3) and ``rest_translation`` (nb, 3) map bone-local to world: x = R c + p.
"""
from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class Binding:
    """The result of ``bind_to_skeleton``; arrays are per vertex (n,) or per bone (nb,)."""
    bone: np.ndarray            # (n,) int64: nearest bone of every vertex
    distance: np.ndarray        # (n,) float64 [m]: distance to that bone's segment at rest
    level: np.ndarray           # (n,) int64: 0 innermost ... L-1, -1 = free flesh
    local: np.ndarray           # (n, 3): rest position in the bone's local frame, R0^T (x - p0)
    level_radii: np.ndarray     # (L,) increasing [m]
    rest_rotation: np.ndarray   # (nb, 3, 3)
    rest_translation: np.ndarray  # (nb, 3)
    axis_local: np.ndarray      # (nb, 2, 3): segment start and end in the bone's local frame
    warnings: list[str] = field(default_factory=list)

    @property
    def n_levels(self) -> int:
        return int(self.level_radii.size)

    @property
    def n_bones(self) -> int:
        return int(self.rest_rotation.shape[0])

    @property
    def bound(self) -> np.ndarray:
        """(k,) indices of all constrained vertices (level >= 0), ascending."""
        return np.flatnonzero(self.level >= 0)

    def level_set(self, k: int) -> np.ndarray:
        """Indices of the paper's Omega'_{k+1}: vertices of levels 0..k (nested: level_set(k) ⊂ level_set(k+1))."""
        if not 0 <= k < self.n_levels:
            raise ValueError(f"level {k} does not exist: this binding has levels 0..{self.n_levels - 1}")
        return np.flatnonzero((self.level >= 0) & (self.level <= k))

    def summary(self) -> str:
        counts = [int((self.level == k).sum()) for k in range(self.n_levels)]
        return (f"{self.level.size} vertices: " + ", ".join(
            f"level {k} (<= {r:.3g} m) {c}" for k, (r, c) in enumerate(zip(self.level_radii, counts)))
            + f", free {int((self.level < 0).sum())}")


def segment_distance(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Distance of every point (n, 3) to every segment (nb, 3)-(nb, 3), as (n, nb). Zero-length segments are points."""
    d = ends - starts                                           # (nb, 3)
    L2 = np.einsum("bj,bj->b", d, d)
    rel = points[:, None, :] - starts[None, :, :]               # (n, nb, 3)
    s = np.einsum("nbj,bj->nb", rel, d) / np.where(L2 > 0, L2, 1.0)
    s = np.clip(np.where(L2 > 0, s, 0.0), 0.0, 1.0)
    return np.linalg.norm(rel - s[..., None] * d[None], axis=2)


def _check_array(name: str, a, shape: tuple) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape)):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} has shape {a.shape}, expected {want}")
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{name} has a non-finite entry at index {tuple(int(i) for i in bad[0])}: "
                         "give finite coordinates in metres")
    return a


def bind_to_skeleton(rest_vertices: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                     level_radii: Sequence[float], bone_mask: np.ndarray | None = None, *,
                     rest_rotation: np.ndarray | None = None, rest_translation: np.ndarray | None = None,
                     bone_names: Sequence[str] | None = None, warn: bool = True,
                     surface_depth: np.ndarray | None = None, allowed: np.ndarray | None = None) -> Binding:
    """Bind every vertex to its nearest bone and sort it into nested levels by distance.

    ``starts``/``ends`` (nb, 3) are the bone segments in the rest pose; ``bone_mask`` (nb,) bool picks the
    bones that may bind flesh (default all). ``rest_rotation`` (nb, 3, 3) / ``rest_translation`` (nb, 3)
    are the bone frames at rest (default: identity rotation at the segment start). Raises ValueError on
    bad radii or when no vertex at all is within the outermost radius; a bone without any vertex in the
    innermost level, or a level that adds no vertex, is reported in ``Binding.warnings`` (and as a
    ``UserWarning`` when ``warn``). With ``surface_depth`` (n,) [m] the radii are fractions in (0, 1] of the
    flesh thickness (see the module docstring). ``allowed`` (n, nb) bool limits the bones each vertex may bind to
    (a voxel body's vertex to the bones of its own voxels; a row without any True allows every bone).
    """
    x = _check_array("rest_vertices", rest_vertices, (None, 3))
    s = _check_array("bone starts", starts, (None, 3))
    e = _check_array("bone ends", ends, (s.shape[0], 3))
    nb = s.shape[0]
    if nb == 0:
        raise ValueError("the skeleton has no bones: nothing to bind to")
    names = list(bone_names) if bone_names is not None else [f"bone {b}" for b in range(nb)]
    if len(names) != nb:
        raise ValueError(f"{len(names)} bone names for {nb} bones")
    r = np.asarray(level_radii, dtype=np.float64).reshape(-1)
    if r.size == 0:
        raise ValueError("level_radii is empty: give at least one radius in metres, e.g. (0.03, 0.05)")
    if not (np.isfinite(r).all() and (r > 0).all()):
        raise ValueError(f"level_radii {r.tolist()} must be positive finite distances in metres")
    unit = "m"
    if surface_depth is not None:
        unit = "of the flesh thickness"
        if (r > 1).any():
            raise ValueError(f"level_radii {r.tolist()} are fractions of the flesh thickness on a surface body: "
                             "give values in (0, 1], e.g. (0.35, 0.6)")
    if r.size > 1 and not (np.diff(r) > 0).all():
        k = int(np.flatnonzero(np.diff(r) <= 0)[0])
        raise ValueError(f"level_radii must increase (nested levels): radius {k + 1} = {r[k + 1]:g} m is not "
                         f"larger than radius {k} = {r[k]:g} m in {r.tolist()}; sort them innermost first")
    R0 = (np.broadcast_to(np.eye(3), (nb, 3, 3)).copy() if rest_rotation is None
          else _check_array("rest_rotation", rest_rotation, (nb, 3, 3)))
    p0 = s.copy() if rest_translation is None else _check_array("rest_translation", rest_translation, (nb, 3))
    orth = np.abs(np.einsum("bij,bik->bjk", R0, R0) - np.eye(3)).max(axis=(1, 2))
    if (orth > 1e-6).any():
        b = int(np.argmax(orth))
        raise ValueError(f"rest_rotation of {names[b]} is not a rotation (|R^T R - I| = {orth[b]:.2g})")
    mask = np.ones(nb, dtype=bool) if bone_mask is None else np.asarray(bone_mask, dtype=bool).reshape(-1)
    if mask.shape != (nb,):
        raise ValueError(f"bone_mask has shape {mask.shape}, expected ({nb},)")
    if not mask.any():
        raise ValueError("bone_mask excludes every bone: at least one bone must bind flesh")

    dist = segment_distance(x, s, e)
    dist[:, ~mask] = np.inf
    if allowed is not None:
        allowed = np.asarray(allowed, dtype=bool)
        if allowed.shape != dist.shape:
            raise ValueError(f"allowed has shape {allowed.shape}, expected {dist.shape} (vertices, bones)")
        limit = allowed & mask
        dist[limit.any(axis=1)[:, None] & ~limit] = np.inf
    bone = np.argmin(dist, axis=1).astype(np.int64)
    d = dist[np.arange(x.shape[0]), bone]
    rel = d
    if surface_depth is not None:
        depth = _check_array("surface_depth", surface_depth, (x.shape[0],))
        total = d + depth
        rel = np.where(total > 0, d / np.where(total > 0, total, 1.0), 0.0)
    level = np.searchsorted(r, rel, side="left").astype(np.int64)     # rel <= r[k] -> level k
    level[level >= r.size] = -1
    if not (level >= 0).any():
        raise ValueError(f"no vertex lies within the outermost level radius {r[-1]:g} {unit} of any bone "
                         f"(nearest vertex at {rel.min():.3g} {unit}): the skeleton is outside the body or the "
                         "radii are too small")
    local = np.einsum("nji,nj->ni", R0[bone], x - p0[bone])
    axis_local = np.stack([np.einsum("bji,bj->bi", R0, s - p0), np.einsum("bji,bj->bi", R0, e - p0)], axis=1)

    notes: list[str] = []
    inner = np.bincount(bone[level == 0], minlength=nb)
    for b in np.flatnonzero(mask & (inner == 0)):
        notes.append(f"{names[b]} has no vertex within the innermost radius {r[0]:g} {unit}: it drives no flesh "
                     "directly; raise level_radii[0] or exclude it with bone_mask")
    counts = np.bincount(level[level >= 0], minlength=r.size)
    for k in np.flatnonzero(counts == 0):
        notes.append(f"level {k} (radius {r[k]:g} {unit}) holds no vertex: the radii skip over the mesh spacing; "
                     "merge it with a neighbour or spread the radii")
    if warn:
        for n in notes:
            _warnings.warn(n, UserWarning, stacklevel=2)
    return Binding(bone=bone, distance=d, level=level, local=local, level_radii=r, rest_rotation=R0,
                   rest_translation=p0, axis_local=axis_local, warnings=notes)
