"""Standard explicit FEM: the same symplectic Euler as the clustered method, on the assembled scipy
matrices with D and K applied separately. The like-for-like reference for the "lossless" claim.

``warp=True``: the warped force (fem/warping.py: eq. 10 symmetrised) on the assembled matrix. Each
sub-step the vertex rotations R_i are extracted and the block-sparse K is warped into the symmetric K_w,
blocks (R_i K_ij R_i^T + R_j K_ij R_j^T) / 2 (see _warped_force); the clustered warped kernel must match
it to round-off."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..model import Control, FemModel, State
from ..stability import control_critical_step, max_eigenvalue, plan_substeps
from ..warping import VertexFrames, vertex_rotations
from .base import StepCommon, StepInfo


class StandardExplicit:
    name = "standard_explicit"

    def __init__(self, model: FemModel, safety: float = 0.8, max_substeps: int = 10000,
                 lam_max: float | None = None, warp: bool = False):
        self.model = model
        self.warp = bool(warp)
        if self.warp:
            self.name = "standard_explicit_warp"
            self.frames = VertexFrames.from_model(model)
            self._Kb = model.K.tobsr(blocksize=(3, 3))
            self._Kb.sort_indices()
            self._block_row = np.repeat(np.arange(model.n_vertices), np.diff(self._Kb.indptr))
        self.safety = safety
        self.max_substeps = max_substeps
        self.lam_max = max_eigenvalue(model) if lam_max is None else lam_max
        self.K = model.K
        self.D = model.damping_matrix()
        self._inv_mass = np.where(model.fixed, 0.0, 1.0 / model.mass)
        self._common = StepCommon(model)

    def critical_step(self, control: Control | None = None) -> float:
        return control_critical_step(self.lam_max, self.model.material, control)

    def step(self, state: State, control: Control, h: float) -> StepInfo:
        plan = plan_substeps(h, self.critical_step(control), self.safety, self.max_substeps)
        held = self._common.apply_prescribed(state, control)
        inv_mass = (self._inv_mass if held is None else np.where(held, 0.0, self._inv_mass))[:, None]
        f_const = self._common.constant_forces(control)
        att = control.attachments
        m_att = self.model.mass[att.index][:, None]
        u, v = state.u.reshape(-1), state.v.reshape(-1)
        hs = plan.h_sub
        for s in range(plan.substeps):
            tau = s * hs
            if self.warp:
                f = self._warped_force(state.u, state.v)
            else:
                f = -(self.K @ u) - (self.D @ v)
            f = f.reshape(-1, 3) + f_const
            if att.index.size:
                tu = att.target_u + tau * att.target_v + 0.5 * tau * tau * att.target_a
                tv = att.target_v + tau * att.target_a
                fa = m_att * (att.target_a + att.kp[:, None] * (tu - state.u[att.index])
                              + att.kd[:, None] * (tv - state.v[att.index]))
                np.add.at(f, att.index, fa)
            v += hs * (inv_mass * f).reshape(-1)
            u += hs * v
        self._common.finish(state, h, self.name)
        return StepInfo(substeps=plan.substeps, margin=plan.margin)

    def _warped_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The warped force (fem/warping.py) with assembled matrices, (n, 3): with w = x + zeta v and the
        symmetric block-sparse K_w, blocks J_ij = (R_i K_ij R_i^T + R_j K_ij R_j^T) / 2,
            f_i = -sum_j J_ij (w_j - w_i - R_i (x0_j - x0_i))
                = -(K_w w)_i + (sum_j J_ij) w_i + (Q x0)_i - (sum_j Q_ij) R_i x0_i,  Q blocks J_ij R_i,
        then - xi M v."""
        R = vertex_rotations(self.model, u, self.frames)
        Ri, Rj = R[self._block_row], R[self._Kb.indices]
        K = self._Kb.data
        J = 0.5 * (Ri @ K @ np.swapaxes(Ri, 1, 2) + Rj @ K @ np.swapaxes(Rj, 1, 2))
        Q = J @ Ri
        m = self.model.material
        x0 = self.model.rest
        w = x0 + u + m.zeta * v
        f = (-self._apply(self._blocks(J), w) + np.einsum("nij,nj->ni", self._row_sums(J), w)
             + self._apply(self._blocks(Q), x0) - np.einsum("nij,nj->ni", self._row_sums(Q), x0))
        return f - m.xi * self.model.mass[:, None] * v

    def _blocks(self, data: np.ndarray) -> sp.bsr_matrix:
        Kb = self._Kb
        return sp.bsr_matrix((data, Kb.indices, Kb.indptr), shape=Kb.shape)

    @staticmethod
    def _apply(A: sp.bsr_matrix, x: np.ndarray) -> np.ndarray:
        return (A @ x.reshape(-1)).reshape(-1, 3)

    def _row_sums(self, data: np.ndarray) -> np.ndarray:
        out = np.zeros((self.model.n_vertices, 3, 3))
        np.add.at(out, self._block_row, data)
        return out
