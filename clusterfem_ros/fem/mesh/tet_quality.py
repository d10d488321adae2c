"""Tet shape quality: how far each element is from a regular tetrahedron, measured once at set-up.

q = 6 sqrt(2) V / l_rms^3, V the signed volume and l_rms the root mean square of the six edge lengths: 1 for a
regular tet, 0.77 for a voxel's corner tet, about 0 for a sliver (four nearly coplanar corners) or a needle.
It is scale free and, unlike the volume alone, says what an element costs the explicit step: a flat tet of
height eps q l has shape gradients of size 1 / (q l), so its stiffness grows as 1 / q against a mass that
shrinks as q; the largest eigenvalue of M^-1 K, and with it the number of sub-steps, grow with 1 / q
(its square root) where such an element sits. The shape gradients also lose about log10(1 / q) digits.

``mesh_quality`` summarises a mesh (worst element, the number of slivers below SLIVER); the scene logs it and
/diagnostics carries it. ``check_quality`` refuses an element below ``min_quality`` (MIN_QUALITY by default,
the scene's body.min_tet_quality): at 1e-8 a sub-step is ten thousand times shorter than the rest of the mesh
allows and the element's gradients keep half their digits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .tet_mesh import MeshError

MIN_QUALITY = 1e-8      # below this an element is degenerate and refused (module docstring)
SLIVER = 0.05           # below this an element is counted as a sliver in the set-up summary
_NORM = 6.0 * math.sqrt(2.0)
_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


def tet_quality(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """q = 6 sqrt(2) V / l_rms^3 of every tet, (m,): 1 regular, <= 0 inverted or flat (module docstring)."""
    x = np.asarray(vertices, dtype=np.float64)[np.asarray(tets, dtype=np.int64)]
    e = x[:, 1:] - x[:, :1]
    vol = np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0
    d = x[:, _EDGES[:, 1]] - x[:, _EDGES[:, 0]]
    l_rms = np.sqrt(np.einsum("ekc,ekc->e", d, d) / 6.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = _NORM * vol / l_rms ** 3
    return np.where(l_rms > 0.0, q, 0.0)


@dataclass(frozen=True)
class MeshQuality:
    worst: float            # the lowest q over the elements
    worst_tet: int          # its index
    slivers: int            # elements with q < SLIVER
    median: float

    def summary(self) -> str:
        """One log line."""
        return (f"tet quality (6 sqrt2 V / l_rms^3, 1 = regular): worst {self.worst:.3g} (tet {self.worst_tet}), "
                f"median {self.median:.3g}, {self.slivers} sliver{'s' if self.slivers != 1 else ''} below {SLIVER:g}")


def mesh_quality(vertices: np.ndarray, tets: np.ndarray) -> MeshQuality:
    q = tet_quality(vertices, tets)
    if q.size == 0:
        return MeshQuality(1.0, -1, 0, 1.0)
    i = int(np.argmin(q))
    return MeshQuality(float(q[i]), i, int((q < SLIVER).sum()), float(np.median(q)))


def check_quality(vertices: np.ndarray, tets: np.ndarray, min_quality: float = MIN_QUALITY) -> MeshQuality:
    """The mesh's MeshQuality; MeshError naming the worst element when one is below ``min_quality``."""
    if not (isinstance(min_quality, (int, float)) and 0.0 <= min_quality < 1.0):
        raise MeshError(f"min_quality = {min_quality!r}: give a tet quality in [0, 1) (0 accepts any shape)")
    quality = mesh_quality(vertices, tets)
    if quality.worst < min_quality:
        bad = int((tet_quality(vertices, tets) < min_quality).sum())
        raise MeshError(f"tet {quality.worst_tet} has quality {quality.worst:.3g} (6 sqrt2 V / l_rms^3, 1 for a "
                         f"regular tet; {bad} tets below the limit {min_quality:g}): it is degenerate, nearly flat, "
                         "and would make the explicit step take thousands of sub-steps; remesh the body (a mesher "
                         "with a quality bound) or lower body.min_tet_quality (0 accepts any shape)")
    return quality
