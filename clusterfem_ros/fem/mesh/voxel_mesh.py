"""Tet meshes from voxels (the paper's Figure 2): each voxel split into five tetrahedra.

The five-tet split alternates with voxel parity so that neighbouring voxels share face diagonals and
the mesh is conforming. A corner tet's outer vertex can belong to that tet alone: the paper's
*boundary* vertex; every other vertex is *shared*.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from .tet_mesh import MeshError, TetMesh, orient

# Cube corners numbered by bits (x + 2y + 4z).
_CORNER = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])


def _five_tets(central: tuple[int, int, int, int]) -> np.ndarray:
    tets = [list(central)]
    for c in range(8):
        if c not in central:
            tets.append([c, c ^ 1, c ^ 2, c ^ 4])
    return np.array(tets)


_SPLIT = (_five_tets((0, 3, 5, 6)), _five_tets((1, 2, 4, 7)))


def grid_mesh(mask: np.ndarray, lo: np.ndarray, spacing: np.ndarray) -> TetMesh:
    """Tet mesh of the voxels where ``mask`` (nx, ny, nz) is True; voxel (i, j, k) spans lo + [i, i+1] * spacing."""
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 3:
        raise MeshError(f"voxel mask must be 3-D, got shape {mask.shape}")
    return cells_mesh(np.argwhere(mask), lo, spacing)


def cells_mesh(cells: np.ndarray, lo: np.ndarray, spacing: np.ndarray) -> TetMesh:
    """Tet mesh of the voxels ``cells`` (m, 3) integer (i, j, k) >= 0, in lexicographic order (as ``np.argwhere``
    gives them): voxel (i, j, k) spans lo + [i, i+1] * spacing. Its cost follows the cells, not the grid they lie
    in; for the cells of a mask it is ``grid_mesh``'s mesh, vertex for vertex."""
    ijk = np.asarray(cells)
    if ijk.ndim != 2 or ijk.shape[1] != 3:
        raise MeshError(f"voxel cells must be (m, 3) integer indices, got shape {ijk.shape}")
    if len(ijk) == 0:
        raise MeshError("no voxel is inside the shape: make the spacing smaller or the shape larger")
    ijk = ijk.astype(np.int64)
    if ijk.min() < 0:
        raise MeshError(f"voxel cells must have indices >= 0, got {ijk.min(axis=0)}: shift lo instead")
    spacing = np.broadcast_to(np.asarray(spacing, dtype=np.float64), (3,))
    size = ijk.max(axis=0) + 2                                                 # corners per axis
    vid = lambda p: (p[..., 0] * size[1] + p[..., 1]) * size[2] + p[..., 2]  # noqa: E731
    tets = []
    for parity in (0, 1):
        cell = ijk[ijk.sum(axis=1) % 2 == parity]
        corners = cell[:, None, :] + _CORNER[None, :, :]                    # (c, 8, 3)
        tets.append(vid(corners)[:, _SPLIT[parity]].reshape(-1, 4))
    used, tets = np.unique(np.concatenate(tets), return_inverse=True)      # vertices in lexicographic order
    corner = np.stack([used // (size[1] * size[2]), used // size[2] % size[1], used % size[2]], axis=1)
    vertices = np.asarray(lo, dtype=np.float64) + corner * spacing
    return orient(TetMesh(vertices, tets.reshape(-1, 4))).validate()


def voxel_centres(lo, hi, spacing: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    """(centres (nx ny nz, 3) in C order, (nx, ny, nz)) of the regular grid of voxels of edge ``spacing`` over
    [lo, hi]: voxel (i, j, k) spans lo + [i, i+1] * spacing."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if not (np.isfinite(spacing) and spacing > 0):
        raise MeshError(f"voxel spacing must be a positive length in metres, got {spacing!r}")
    n = np.maximum(np.ceil((hi - lo) / spacing - 1e-9).astype(int), 1)
    if np.prod(n) > 5e7:
        raise MeshError(f"{np.prod(n):.3g} voxels at spacing {spacing} m: choose a larger spacing")
    c = [lo[a] + (np.arange(n[a]) + 0.5) * spacing for a in range(3)]
    return np.stack(np.meshgrid(*c, indexing="ij"), -1).reshape(-1, 3), tuple(int(k) for k in n)


def voxelize(inside: Callable[[np.ndarray], np.ndarray], lo, hi, spacing: float) -> TetMesh:
    """Mesh the voxels of a regular grid over [lo, hi] whose centres satisfy ``inside(points (k, 3)) -> bool (k,)``."""
    centres, n = voxel_centres(lo, hi, spacing)
    mask = np.asarray(inside(centres), dtype=bool).reshape(n)
    return grid_mesh(mask, np.asarray(lo, dtype=np.float64), np.full(3, spacing))


def box_mesh(size=(1.0, 1.0, 1.0), divisions=(4, 4, 4), origin=(0.0, 0.0, 0.0)) -> TetMesh:
    """A box [origin, origin + size] split into divisions voxels per axis (5 tets each)."""
    d = np.asarray(divisions, dtype=int)
    if (d < 1).any():
        raise MeshError(f"box divisions must be >= 1 per axis, got {tuple(d)}")
    return grid_mesh(np.ones(tuple(d), dtype=bool), np.asarray(origin, float), np.asarray(size, float) / d)


def sphere_mesh(radius: float = 0.1, resolution: float = 8) -> TetMesh:
    """A voxel sphere: ``resolution`` voxels across the diameter."""
    h = 2.0 * radius / resolution
    return voxelize(lambda p: (p ** 2).sum(1) <= radius ** 2, [-radius] * 3, [radius] * 3, h)


def torus_mesh(major: float = 0.1, minor: float = 0.04, resolution: float = 8) -> TetMesh:
    """A voxel torus around z: ``resolution`` voxels across the tube (2 * minor)."""
    h = 2.0 * minor / resolution
    ext = major + minor

    def inside(p: np.ndarray) -> np.ndarray:
        rho = np.hypot(p[:, 0], p[:, 1])
        return (rho - major) ** 2 + p[:, 2] ** 2 <= minor ** 2

    return voxelize(inside, [-ext, -ext, -minor], [ext, ext, minor], h)


PAPER_SHAPES = ("sphere", "cube", "torus")


def paper_mesh(name: str, scale: float = 1.0) -> TetMesh:
    """The paper's three test objects near its sizes (Table 1); ``scale`` refines for scaling runs.

    Paper: sphere 376 vertices / 1091 tets, cube 453 / 1198, torus 609 / 1823. Here at scale 1:
    sphere 368 / 1085, cube 343 / 1080 (6^3 voxels), torus 656 / 1800. Tet counts grow as scale**3
    (scale 5.6 gives about 200k tets).
    """
    if name == "sphere":
        return sphere_mesh(0.1, 7.5 * scale)
    if name == "cube":
        n = max(1, int(round(6 * scale)))
        return box_mesh((0.1, 0.1, 0.1), (n, n, n), (-0.05, -0.05, -0.05))
    if name == "torus":
        return torus_mesh(0.09, 0.04, 4 * scale)
    raise MeshError(f"unknown paper mesh {name!r}: choose 'sphere', 'cube' or 'torus'")
