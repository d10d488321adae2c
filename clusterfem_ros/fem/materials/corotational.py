"""Per-element corotational linear FEM (Mueller & Gross 2004): the reference stiffness warping is compared to.

For tet e: F_e = I + sum_a u_a g_a^T (g_a the rest shape gradients), R_e = polar(F_e) (3x3 SVD with the
reflection fixed, so an inverted tet still gets a proper rotation), and

    f_e = -R_e K_e (R_e^T x_e - x0_e) - zeta R_e K_e R_e^T v_e,      E_e = 1/2 y_e^T K_e y_e,  y_e = R_e^T x_e - x0_e.

Positions are taken relative to the tet's first vertex (K_e ignores translations), which keeps round-off
small. Vectorized numpy over elements; meant for tests, stress and energy bookkeeping, not the hot loop.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..linear.assembly import element_stiffness_blocks, shape_gradients
from ..model import FemModel


NEWTON_ITERATIONS = 30


def polar_rotations(F: np.ndarray) -> np.ndarray:
    """Rotation factor of polar(F) for a stack (..., 3, 3); det = +1 even when det F <= 0.

    Batched scaled Newton X <- (g X + X^-T / g) / 2 on the well-conditioned elements (det F > 0; cofactor
    inverses, no LAPACK call per element: ~15x faster than an SVD on thousands of tets), an SVD with the
    reflection fixed for the inverted, flat or non-converged rest.
    """
    F = np.asarray(F, dtype=np.float64)
    shape = F.shape
    F = F.reshape(-1, 3, 3)
    R = np.empty_like(F)
    det = np.linalg.det(F)
    nf = np.einsum("eij,eij->e", F, F)
    good = det > 1e-6 * (nf / 3.0) ** 1.5
    X = F[good]
    done = np.zeros(X.shape[0], dtype=bool)
    for _ in range(NEWTON_ITERATIONS):
        r0, r1, r2 = X[:, 0], X[:, 1], X[:, 2]
        cof = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=1)
        Y = cof / np.einsum("ei,ei->e", r0, cof[:, 0])[:, None, None]    # X^-T = cof(X) / det X
        g = np.sqrt(np.sqrt(np.einsum("eij,eij->e", Y, Y) / np.einsum("eij,eij->e", X, X)))
        Xn = 0.5 * (g[:, None, None] * X + Y / g[:, None, None])
        change = np.einsum("eij,eij->e", Xn - X, Xn - X)
        X = Xn
        done = change < 1e-26
        if done.all():
            break
    R[good] = X
    rest = ~good
    rest[np.flatnonzero(good)[~done]] = True
    if rest.any():
        U, _, Vt = np.linalg.svd(F[rest])
        d = np.sign(np.linalg.det(U @ Vt))
        d[d == 0] = 1.0
        U[..., :, 2] *= d[..., None]
        R[rest] = U @ Vt
    return R.reshape(shape)


def deformation_gradients(g: np.ndarray, tets: np.ndarray, u: np.ndarray) -> np.ndarray:
    """F_e = I + grad u, (m, 3, 3), from rest shape gradients g (m, 4, 3)."""
    return np.eye(3) + np.einsum("eai,eaj->eij", u[tets], g)


class ElementCorotation:
    """The per-element corotational model of one FemModel (element blocks and gradients cached)."""

    def __init__(self, model: FemModel):
        self.model = model
        self.tets = model.mesh.tets
        self.blocks = element_stiffness_blocks(model.mesh, model.material)       # (m, 4, 4, 3, 3)
        self.g, self.volume = shape_gradients(model.rest, self.tets)
        self._pattern = None

    def _check(self, name: str, a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        if a.shape != (self.model.n_vertices, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({self.model.n_vertices}, 3) for this mesh")
        return a

    def rotations(self, u: np.ndarray) -> np.ndarray:
        """R_e, (m, 3, 3)."""
        return polar_rotations(deformation_gradients(self.g, self.tets, self._check("u", u)))

    def _local(self, u: np.ndarray, R: np.ndarray) -> np.ndarray:
        x0 = self.model.rest[self.tets]
        d0 = x0 - x0[:, :1]
        xe = x0 + u[self.tets]
        d = xe - xe[:, :1]
        return np.einsum("eji,eaj->eai", R, d) - d0                               # R^T (x_a - x_0) - (x0_a - x0_0)

    def force(self, u: np.ndarray, v: np.ndarray | None = None, R: np.ndarray | None = None) -> np.ndarray:
        """Elastic (and, with v, damping) force (n, 3), including -xi m v; R: the element rotations to use
        (default polar(F_e))."""
        u = self._check("u", u)
        R = self.rotations(u) if R is None else R
        y = self._local(u, R)
        m = self.model.material
        if v is not None:
            v = self._check("v", v)
            y = y + m.zeta * np.einsum("eji,eaj->eai", R, v[self.tets])
        fe = -np.einsum("eij,eabjk,ebk->eai", R, self.blocks, y)
        f = np.zeros((self.model.n_vertices, 3))
        np.add.at(f, self.tets, fe)
        if v is not None:
            f -= m.xi * self.model.mass[:, None] * v
        return f

    def energy(self, u: np.ndarray, R: np.ndarray | None = None) -> float:
        """Corotated elastic energy sum_e 1/2 y_e^T K_e y_e [J]; R as in ``force``."""
        u = self._check("u", u)
        y = self._local(u, self.rotations(u) if R is None else R)
        return 0.5 * float(np.einsum("eai,eabij,ebj->", y, self.blocks, y))

    def rotated_stiffness(self, R: np.ndarray) -> sp.csr_matrix:
        """sum_e R_e K_e R_e^T assembled, (3n, 3n): symmetric positive semi-definite and zero on every
        translation (each K_e is), the stiffness of the standard corotational implicit step."""
        if self._pattern is None:
            t = self.tets
            rows = (3 * t[:, :, None, None, None] + np.arange(3)[None, None, None, :, None])
            cols = (3 * t[:, None, :, None, None] + np.arange(3)[None, None, None, None, :])
            shape = (self.model.n_vertices * 3,) * 2
            rows, cols = np.broadcast_arrays(rows, cols)
            # sums the element entries into K's pattern: a sparse (nnz, 16 * 9 m) 0/1 matrix, built once
            ones = sp.coo_matrix((np.ones(rows.size), (rows.ravel(), cols.ravel())), shape=shape).tocsr()
            ones.sum_duplicates()
            ones.sort_indices()
            ncol = shape[1]
            stored = np.repeat(np.arange(shape[0]), np.diff(ones.indptr)) * ncol + ones.indices   # ascending
            key = np.searchsorted(stored, rows.ravel() * ncol + cols.ravel())
            self._pattern = (ones, sp.csr_matrix((np.ones(key.size), (key, np.arange(key.size))),
                                                 shape=(ones.nnz, key.size)))
        ones, summing = self._pattern
        blocks = np.einsum("eij,eabjk,elk->eabil", R, self.blocks, R)
        return sp.csr_matrix((summing @ blocks.reshape(-1), ones.indices, ones.indptr), shape=ones.shape)


def corotated_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """One-off per-element corotational force; build an ElementCorotation to reuse the element data."""
    return ElementCorotation(model).force(u, v)
