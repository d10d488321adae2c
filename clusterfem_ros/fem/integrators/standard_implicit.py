"""Standard implicit FEM, the paper's ground truth (eq. 3): linearly implicit Euler

    A dv = h [ -D v - K (u + h v) + f ],   A = M + h D + h^2 K,   v += dv,   u += h v.

Fixed and prescribed DOFs are removed from the system. Attachment gains enter A (h kd m + h^2 kp m on
their diagonal) so stiff constraints stay stable. The direct solver factorizes A once per (h, constraint
set) and reuses the factor (fem/spd_factor.py: SuperLU in symmetric mode); the CG solver (the paper's
choice) is Jacobi-preconditioned and warm-started.

``warp=True`` (stiffness warping, the paper's comparison). Linearisation about the current state, with
the vertex rotations R_i (fem/warping.py) frozen over the step:
    K_w = R K R^T,  R = blockdiag(R_i)   (blocks R_i K_ij R_j^T: symmetric positive semi-definite, so CG works),
    D_w = xi M + zeta K_w,   A = M + h D_w + h^2 K_w,
    rhs = h [ f_w(u, v) - h K_w v + f ],
with f_w the exact warped force (elastic + damping, the clustered warped kernel). The step's fixed point
is f_w's; K_w differs from f_w's own Jacobian with held rotations (blocks (R_i K_ij R_i^T + R_j K_ij
R_j^T) / 2, symmetric but not always positive semi-definite) by O(|R_i - R_j|) and leaves out dR/dx,
which only costs Newton-like accuracy, not consistency (the method stays first order). A is re-assembled
and re-factorized every step.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..model import Control, FemModel, State
from ..spd_factor import factorize_spd
from ..warping import VertexFrames, vertex_rotations, warped_force
from .base import StepCommon, StepInfo


class StandardImplicit:
    def __init__(self, model: FemModel, solver: str = "direct", cg_rtol: float = 1e-10, cg_maxiter: int = 2000,
                 warp: bool = False):
        if solver not in ("direct", "cg"):
            raise ValueError(f"implicit solver {solver!r}: choose 'direct' or 'cg'")
        self.model = model
        self.solver = solver
        self.warp = bool(warp)
        self.name = f"implicit_{solver}" + ("_warp" if self.warp else "")
        if self.warp:
            self.frames = VertexFrames.from_model(model)
            self._Kb = model.K.tobsr(blocksize=(3, 3))
            self._Kb.sort_indices()
            self._block_row = np.repeat(np.arange(model.n_vertices), np.diff(self._Kb.indptr))
        self.cg_rtol = cg_rtol
        self.cg_maxiter = cg_maxiter
        self.K = model.K
        self.D = model.damping_matrix()
        self.M = sp.diags(np.repeat(model.mass, 3)).tocsr()
        self._common = StepCommon(model)
        self._key = None
        self._dv_prev: np.ndarray | None = None

    def _warped_stiffness(self, u: np.ndarray) -> sp.csr_matrix:
        """K_w = R K R^T with the current vertex rotations (blocks R_i K_ij R_j^T)."""
        R = vertex_rotations(self.model, u, self.frames)
        Kb = self._Kb
        data = R[self._block_row] @ Kb.data @ np.swapaxes(R[Kb.indices], 1, 2)
        return sp.bsr_matrix((data, Kb.indices, Kb.indptr), shape=Kb.shape).tocsr()

    def _system(self, h: float, held: np.ndarray, control: Control, K: sp.csr_matrix | None = None):
        att = control.attachments
        key = (h, held.tobytes(), att.index.tobytes(), att.kp.tobytes(), att.kd.tobytes())
        if key != self._key or K is not None:
            extra = np.zeros(self.model.n_vertices)
            np.add.at(extra, att.index, self.model.mass[att.index] * (h * att.kd + h * h * att.kp))
            if K is None:
                A = (self.M + h * self.D + (h * h) * self.K + sp.diags(np.repeat(extra, 3))).tocsr()
            else:
                m = self.model.material
                A = ((1.0 + h * m.xi) * self.M + (h * m.zeta + h * h) * K + sp.diags(np.repeat(extra, 3))).tocsr()
            free = np.flatnonzero(np.repeat(~held, 3))
            A_ff = A[free][:, free].tocsc()
            self._free = free
            self._A = A_ff
            self._lu = factorize_spd(A_ff) if self.solver == "direct" else None
            self._jacobi = sp.diags(1.0 / A_ff.diagonal()) if self.solver == "cg" else None
            if K is None:
                self._dv_prev = None
            self._key = key if K is None else None
        return self._free

    def step(self, state: State, control: Control, h: float) -> StepInfo:
        held = self._common.apply_prescribed(state, control)
        if held is None:
            held = self.model.fixed
        u, v = state.u.reshape(-1), state.v.reshape(-1)
        if self.warp:
            Kw = self._warped_stiffness(state.u)
            free = self._system(h, held, control, Kw)
            fw = warped_force(self.model, state.u, state.v, self.frames).reshape(-1)
            f = self._common.constant_forces(control).reshape(-1) + fw - h * (Kw @ v)
        else:
            free = self._system(h, held, control)
            f = self._common.constant_forces(control).reshape(-1) - self.D @ v - self.K @ (u + h * v)
        att = control.attachments
        if att.index.size:
            m = self.model.mass[att.index][:, None]
            fa = m * (att.target_a + att.kp[:, None] * (att.target_u - (state.u[att.index] + h * state.v[att.index]))
                      + att.kd[:, None] * (att.target_v - state.v[att.index]))
            f = f.reshape(-1, 3)
            np.add.at(f, att.index, fa)
            f = f.reshape(-1)
        rhs = h * f[free]
        iterations = 0
        if self.solver == "direct":
            dv = self._lu.solve(rhs)
        else:
            count = [0]

            def cb(_):
                count[0] += 1
            dv, info = spla.cg(self._A, rhs, x0=self._dv_prev, rtol=self.cg_rtol, atol=0.0,
                               maxiter=self.cg_maxiter, M=self._jacobi, callback=cb)
            iterations = count[0]
            if info > 0:
                raise RuntimeError(f"CG did not reach rtol {self.cg_rtol} in {self.cg_maxiter} iterations; "
                                   "raise cg_maxiter or use the direct solver")
            self._dv_prev = dv
        v[free] += dv
        u[free] += h * v[free]
        held_dofs = np.flatnonzero(np.repeat(held, 3))
        u[held_dofs] += h * v[held_dofs]
        fixed = np.flatnonzero(np.repeat(self.model.fixed, 3))
        u[fixed] = 0.0
        self._common.finish(state, h, self.name)
        return StepInfo(substeps=1, iterations=iterations)
