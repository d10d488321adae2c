"""Meshes shared by the tests."""
from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from clusterfem_ros.fem.mesh.tet_mesh import TetMesh, orient


def random_delaunay_mesh(n_points: int = 300, seed: int = 7) -> TetMesh:
    """A 'real-shaped' unstructured mesh: Delaunay tets of random points in an ellipsoid, slivers dropped."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n_points * 3, 3))
    p = p / np.linalg.norm(p, axis=1)[:, None] * rng.random((len(p), 1)) ** (1 / 3)
    p = p[:n_points] * np.array([0.2, 0.1, 0.07])
    tets = Delaunay(p).simplices
    mesh = orient(TetMesh(p, tets))
    vol = mesh.volumes()
    keep = vol > 1e-3 * np.median(vol)
    used = np.unique(tets[keep])
    remap = np.full(len(p), -1)
    remap[used] = np.arange(len(used))
    return TetMesh(p[used], remap[mesh.tets[keep]]).validate()
