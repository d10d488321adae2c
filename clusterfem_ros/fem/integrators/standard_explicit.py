"""Standard explicit FEM: the same symplectic Euler as the clustered method, on the assembled scipy
matrices with D and K applied separately. The like-for-like reference for the "lossless" claim.

``warp=True``: eq. 10 on the assembled matrix. Each sub-step the vertex rotations R_i are extracted
(fem/warping.py) and the block-sparse K is warped row by row, blocks R_i K_ij R_i^T, so
f = -K_w (x + zeta v) + R_i (K x0)_i - xi M v; the clustered warped kernel must match it to round-off."""
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
            self._Kx0 = (model.K @ model.rest.reshape(-1)).reshape(-1, 3)
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
        """Eq. 10 with the assembled matrix, (n, 3)."""
        R = vertex_rotations(self.model, u, self.frames)
        Rr = R[self._block_row]
        Kb = self._Kb
        Kw = sp.bsr_matrix((Rr @ Kb.data @ np.swapaxes(Rr, 1, 2), Kb.indices, Kb.indptr), shape=Kb.shape)
        m = self.model.material
        x = self.model.rest + u
        f = -(Kw @ (x + m.zeta * v).reshape(-1)).reshape(-1, 3) + np.einsum("nij,nj->ni", R, self._Kx0)
        return f - m.xi * self.model.mass[:, None] * v
