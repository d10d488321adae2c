"""Plain numpy twins of the warping kernels, for tests only: obvious, trusted, vectorised over K's 3x3
blocks (from the assembled matrix, not the clusters) so that short runs on small meshes are affordable."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def polar_svd(F: np.ndarray) -> np.ndarray:
    """Rotation of polar(F) by SVD with the reflection fixed (det R = +1); F (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(F)
    D = np.ones(F.shape[:-1])
    D[..., 2] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


class BlockTwin:
    """K as a list of blocks K_ij (block row i, column j), d_ij = x0_j - x0_i."""

    def __init__(self, K: sp.spmatrix, rest: np.ndarray):
        B = sp.bsr_matrix(K, blocksize=(3, 3))
        self.n = len(rest)
        self.rest = rest
        self.i = np.repeat(np.arange(self.n), np.diff(B.indptr))
        self.j = B.indices
        self.K = B.data
        self.d = rest[self.j] - rest[self.i]
        S = self._sum(self.d[:, :, None] * self.d[:, None, :])
        self.S_inv = np.linalg.inv(S)

    def _sum(self, per_block: np.ndarray) -> np.ndarray:
        out = np.zeros((self.n,) + per_block.shape[1:])
        np.add.at(out, self.i, per_block)
        return out

    def rotations(self, u: np.ndarray) -> np.ndarray:
        """R_i = polar(F_i), F_i = [sum_j (x_j - x_i) d_ij^T] S_i^-1 over vertex i's block row."""
        x = self.rest + u
        e = x[self.j] - x[self.i]
        return polar_svd(self._sum(e[:, :, None] * self.d[:, None, :]) @ self.S_inv)

    def force(self, u: np.ndarray, v: np.ndarray, mass: np.ndarray, zeta: float, xi: float,
              form: str = "symmetric", R: np.ndarray | None = None) -> np.ndarray:
        """Warped elastic + damping force, (n, 3), with z_ij = (x_j - x_i) + zeta (v_j - v_i):
        "eq10"       f_i = -sum_j R_i K_ij R_i^T (z_ij - R_i d_ij) - xi m_i v_i: the paper's
                     -R_i sum_j K_ij (R_i^T x_j - x0_j) (as sum_j K_ij = 0) plus its warped stiffness damping;
        "symmetric"  the block R_i K_ij R_i^T replaced by 1/2 (R_i K_ij R_i^T + R_j K_ij R_j^T)
        (fem/materials/warping.py). ``R``: rotations to hold instead of the rotations of u."""
        R = self.rotations(u) if R is None else R
        x = self.rest + u
        Ri = R[self.i]
        z = (x[self.j] - x[self.i]) + zeta * (v[self.j] - v[self.i]) - np.einsum("bij,bj->bi", Ri, self.d)

        def warped(Rb):        # R K R^T z, per block
            return np.einsum("bij,bj->bi", Rb, np.einsum("bij,bj->bi", self.K, np.einsum("bki,bk->bi", Rb, z)))
        if form == "eq10":
            t = warped(Ri)
        elif form == "symmetric":
            t = 0.5 * (warped(Ri) + warped(R[self.j]))
        else:
            raise ValueError(form)
        return -self._sum(t) - xi * mass[:, None] * v
