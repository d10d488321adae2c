"""Warped stiffness (eq. 10, symmetric blocks: fem/materials/warping.py) on the assembled block-sparse K, for the
standard (reference) methods and the tests: the same force as the cluster kernel, written with scipy sparse
matrices, and its Jacobian with the rotations held (the implicit method's velocity matrix).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..model import FemModel


class AssembledWarp:
    """The warped blocks on the assembled block-sparse K, for the standard (reference) methods: the same force
    as the cluster kernel, written with sparse matrices. With J_ij = (R_i K_ij R_i^T + R_j K_ij R_j^T) / 2,
    ``jacobian`` is H, the force's Jacobian with the rotations held (off-diagonal blocks J_ij, each diagonal
    block minus its row's others: H t = 0 for every translation t), and
        f_i = -sum_j J_ij (w_j - w_i - R_i d_ij) = -(H w)_i + (Q x0)_i - (sum_j Q_ij) x0_i,  Q_ij = J_ij R_i."""

    def __init__(self, model: FemModel):
        self.model = model
        self.Kb = model.K.tobsr(blocksize=(3, 3))
        self.Kb.sort_indices()
        self.row = np.repeat(np.arange(model.n_vertices), np.diff(self.Kb.indptr))
        self.diagonal = self.Kb.indices == self.row

    def matrix(self, blocks: np.ndarray) -> sp.csr_matrix:
        Kb = self.Kb
        return sp.bsr_matrix((blocks, Kb.indices, Kb.indptr), shape=Kb.shape).tocsr()

    def _row_sums(self, blocks: np.ndarray) -> np.ndarray:
        out = np.zeros((self.model.n_vertices, 3, 3))
        np.add.at(out, self.row, blocks)
        return out

    def mean_blocks(self, R: np.ndarray) -> np.ndarray:
        """J_ij for every block of K, (nb, 3, 3)."""
        Ri, Rj = R[self.row], R[self.Kb.indices]
        K = self.Kb.data
        return 0.5 * (Ri @ K @ np.swapaxes(Ri, 1, 2) + Rj @ K @ np.swapaxes(Rj, 1, 2))

    def jacobian(self, R: np.ndarray, J: np.ndarray | None = None) -> sp.csr_matrix:
        """H (see the class docstring), from J = mean_blocks(R) when given."""
        H = self.mean_blocks(R) if J is None else J.copy()
        H[self.diagonal] -= self._row_sums(H)[self.row[self.diagonal]]
        return self.matrix(H)

    def rotated(self, R: np.ndarray) -> sp.csr_matrix:
        """R K R^T, blocks R_i K_ij R_j^T: symmetric positive semi-definite, not translation invariant."""
        return self.matrix(R[self.row] @ self.Kb.data @ np.swapaxes(R[self.Kb.indices], 1, 2))

    def force(self, R: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The warped elastic + damping force, (n, 3), with w = x0 + u + zeta v; then - xi M v."""
        m = self.model.material
        x0 = self.model.rest
        w = (x0 + u + m.zeta * v).reshape(-1)
        J = self.mean_blocks(R)
        Q = J @ R[self.row]
        f = (-(self.jacobian(R, J) @ w) + self.matrix(Q) @ x0.reshape(-1)).reshape(-1, 3)
        f -= np.einsum("nij,nj->ni", self._row_sums(Q), x0)
        return f - m.xi * self.model.mass[:, None] * v
