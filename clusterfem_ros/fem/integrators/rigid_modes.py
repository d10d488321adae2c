"""The rigid motions a body keeps when some of its vertices are held: the null space of K, built exactly.

Linear elasticity's K has zero strain energy for every infinitesimal rigid motion u = t + w x (x - c), so
each connected piece of a mesh (vertices joined by tets) has six zero-energy modes: three translations and
three rotations. A piece with held vertices keeps those rigid motions that leave its held vertices still:
all six with none held, the three rotations about the point with one, the rotation about the axis through
two, none with three not on a line. These are read from the geometry (the null space of the rigid motions
evaluated at the held vertices), so the modal basis (fem/integrators/modal.py) holds every one of them
exactly instead of asking an eigensolver to find copies of the eigenvalue 0, which Lanczos-type solvers
lose (a free beam's modal basis with 4 of its 6 rigid modes falls sideways under gravity).

A vertex in no tet is a piece of its own: three translations, no rotation.
"""
from __future__ import annotations

import numpy as np

from ..mesh.tet_mesh import tet_pieces

RANK_TOL = 1e-9     # singular values below this (relative) count as zero: rigid motions of unit size


def _piece_motions(x: np.ndarray) -> np.ndarray:
    """(3 v, 6) rigid motions of points x (v, 3): translations along x, y, z and rotations about those axes
    through the centroid, scaled by the points' rms radius so all six columns are of unit size."""
    r = x - x.mean(axis=0)
    radius = float(np.sqrt((r * r).sum(axis=1).mean()))
    B = np.zeros((x.shape[0], 3, 6))
    B[:, 0, 0] = B[:, 1, 1] = B[:, 2, 2] = 1.0
    if radius > 0.0:
        r = r / radius
        B[:, 1, 3], B[:, 2, 3] = -r[:, 2], r[:, 1]          # e_x x r
        B[:, 0, 4], B[:, 2, 4] = r[:, 2], -r[:, 0]          # e_y x r
        B[:, 0, 5], B[:, 1, 5] = -r[:, 1], r[:, 0]          # e_z x r
    return B.reshape(-1, 6)


def _span(B: np.ndarray, mass3: np.ndarray) -> np.ndarray:
    """An M-orthonormal basis (columns) of the span of B's columns; dependent columns dropped."""
    G = B.T @ (mass3[:, None] * B)
    w, V = np.linalg.eigh(0.5 * (G + G.T))
    keep = w > RANK_TOL * max(float(w.max(initial=0.0)), np.finfo(float).tiny)
    return B @ (V[:, keep] / np.sqrt(w[keep]))


def rigid_modes(rest: np.ndarray, tets: np.ndarray, mass: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The rigid motions that leave ``held`` vertices still, on the free DOFs (rows of
    ``flatnonzero(repeat(~held, 3))``), M-orthonormal (Z^T M Z = I, M the lumped ``mass``): (f, r), r <= 6 per
    connected piece of the mesh (module docstring)."""
    n = rest.shape[0]
    free_dofs = np.flatnonzero(np.repeat(~held, 3))
    where = np.full(3 * n, -1, dtype=np.int64)
    where[free_dofs] = np.arange(free_dofs.size)
    count, label = tet_pieces(n, tets)
    columns = []
    for piece in range(count):
        verts = np.flatnonzero(label == piece)
        B = _piece_motions(rest[verts])
        held_here = held[verts]
        if held_here.any():
            C = B.reshape(-1, 3, 6)[held_here].reshape(-1, 6)
            _, s, Vt = np.linalg.svd(C)
            rank = int((s > RANK_TOL * np.sqrt(6.0)).sum())      # columns of B have unit size
            B = B @ Vt[rank:].T
        if B.shape[1] == 0:
            continue
        free_here = np.repeat(~held_here, 3)
        Z = _span(B[free_here], np.repeat(mass[verts], 3)[free_here])
        if Z.shape[1]:
            full = np.zeros((free_dofs.size, Z.shape[1]))
            full[where[np.repeat(3 * verts, 3) + np.tile(np.arange(3), verts.size)][free_here]] = Z
            columns.append(full)
    return np.hstack(columns) if columns else np.zeros((free_dofs.size, 0))
