"""Tetrahedral meshes: the array convention, validation with clear errors, surface and vertex classes.

Convention (enforced by ``TetMesh.validate``): ``vertices`` is (n, 3) float64 in metres, ``tets`` is
(m, 4) int64 with positive signed volume ``det[x1-x0, x2-x0, x3-x0] / 6 > 0``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ...errors import ClusterFemError
from ...numba_config import HOLDS_GIL


class MeshError(ClusterFemError, ValueError):
    """A mesh that cannot be simulated; the message names the offending entity and the way out."""


def signed_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume of every tet, (m,)."""
    x = vertices[tets]
    e = x[:, 1:] - x[:, :1]
    return np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0


def total_volume(vertices: np.ndarray, corners: np.ndarray) -> float:
    """Sum of the signed volumes of the tets whose corner indices are the rows of ``corners`` (4, m) (the tets
    transposed, contiguous): signed_volumes(vertices, corners.T).sum() to round-off, for the checks that run
    after every batch of steps and on every output (a compiled loop, 1/10 of numpy's time; it keeps the GIL)."""
    return _total_volume(np.ascontiguousarray(vertices, dtype=np.float64), corners) / 6.0


@numba.njit(**HOLDS_GIL)
def _total_volume(x, corners):
    total = 0.0
    for t in range(corners.shape[1]):
        a, b, c, d = corners[0, t], corners[1, t], corners[2, t], corners[3, t]
        e1x, e1y, e1z = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        e2x, e2y, e2z = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        e3x, e3y, e3z = x[d, 0] - x[a, 0], x[d, 1] - x[a, 1], x[d, 2] - x[a, 2]
        total += e1x * (e2y * e3z - e2z * e3y) + e1y * (e2z * e3x - e2x * e3z) + e1z * (e2x * e3y - e2y * e3x)
    return total


@dataclass(frozen=True)
class TetMesh:
    vertices: np.ndarray
    tets: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", np.ascontiguousarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "tets", np.ascontiguousarray(self.tets, dtype=np.int64))

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_tets(self) -> int:
        return int(self.tets.shape[0])

    def volumes(self) -> np.ndarray:
        return signed_volumes(self.vertices, self.tets)

    def validate(self, min_volume: float = 0.0) -> "TetMesh":
        """Raise MeshError on anything the solver cannot take; return self so calls chain."""
        v, t = self.vertices, self.tets
        if v.ndim != 2 or v.shape[1] != 3:
            raise MeshError(f"vertices must be (n, 3), got shape {v.shape}: pass an array of xyz rows")
        if t.ndim != 2 or t.shape[1] != 4:
            raise MeshError(f"tets must be (m, 4) vertex indices, got shape {t.shape}: only linear tetrahedra are supported")
        if len(t) == 0:
            raise MeshError("the mesh has no tetrahedra: a volume mesh is needed, not a surface")
        bad = np.flatnonzero(~np.isfinite(v).all(axis=1))
        if bad.size:
            raise MeshError(f"vertex {bad[0]} has non-finite coordinates {v[bad[0]].tolist()} "
                            f"({bad.size} such vertices): fix or remove them in the mesh file")
        out = np.flatnonzero((t < 0).any(axis=1) | (t >= len(v)).any(axis=1))
        if out.size:
            raise MeshError(f"tet {out[0]} has vertex indices {t[out[0]].tolist()} outside [0, {len(v) - 1}] "
                            f"({out.size} such tets): the index base or the vertex list is wrong")
        dup = np.flatnonzero(np.sort(t, axis=1)[:, 1:] == np.sort(t, axis=1)[:, :-1])
        if dup.size:
            i = dup[0] // 3
            raise MeshError(f"tet {i} repeats a vertex {t[i].tolist()}: it has zero volume; remove it")
        vol = self.volumes()
        scale = max(float(np.ptp(v, axis=0).max()), 1e-300) ** 3
        tol = max(min_volume, 1e-14 * scale)
        bad = np.flatnonzero(vol <= tol)
        if bad.size:
            i = bad[np.argmin(vol[bad])]
            raise MeshError(f"tet {i} has signed volume {vol[i]:.3g} m^3 (tolerance {tol:.3g}; {bad.size} such tets): "
                            "the mesh is inverted or degenerate; fix the mesh, or load it with "
                            "orient=True to flip negatively oriented tets")
        used = np.zeros(len(v), dtype=bool)
        used[t.ravel()] = True
        if not used.all():
            i = int(np.flatnonzero(~used)[0])
            raise MeshError(f"vertex {i} is not used by any tet ({int((~used).sum())} unreferenced vertices): "
                            "call remove_unreferenced(mesh) or clean the mesh file")
        return self


def orient(mesh: TetMesh) -> TetMesh:
    """Flip tets with negative signed volume (swap their last two vertices)."""
    t = mesh.tets.copy()
    neg = mesh.volumes() < 0
    t[neg, 2], t[neg, 3] = mesh.tets[neg, 3], mesh.tets[neg, 2]
    return TetMesh(mesh.vertices, t)


def remove_unreferenced(mesh: TetMesh) -> TetMesh:
    used = np.unique(mesh.tets)
    remap = np.full(mesh.n_vertices, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return TetMesh(mesh.vertices[used], remap[mesh.tets])


# Faces of tet (0,1,2,3) whose right-hand normal points away from the opposite vertex
# (for a positively oriented tet).
_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def boundary_triangles(mesh: TetMesh) -> np.ndarray:
    """Outward-oriented boundary triangles (k, 3): the tet faces used by exactly one tet."""
    faces = mesh.tets[:, _FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return np.ascontiguousarray(faces[counts[inv.ravel()] == 1])


def tet_pieces(n_vertices: int, tets: np.ndarray) -> tuple[int, np.ndarray]:
    """(number of connected pieces, (n_vertices,) piece label per vertex): vertices joined through tets (a vertex
    in no tet is a piece of its own)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    tets = np.asarray(tets, dtype=np.int64)
    a, b = np.repeat(tets[:, 0], 3), tets[:, 1:].reshape(-1)
    graph = sp.coo_matrix((np.ones(a.size), (a, b)), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=False)


def elements_per_vertex(mesh: TetMesh) -> np.ndarray:
    return np.bincount(mesh.tets.ravel(), minlength=mesh.n_vertices)


def vertex_classes(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """The paper's classes (Fig. 2): (shared, boundary) vertex indices.

    A *boundary* vertex is used by exactly one element, a *shared* vertex by two or more.
    """
    count = elements_per_vertex(mesh)
    return np.flatnonzero(count >= 2), np.flatnonzero(count == 1)
