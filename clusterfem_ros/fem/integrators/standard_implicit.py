"""Standard implicit FEM, the paper's ground truth (eq. 3): linearly implicit Euler

    A dv = h [ -D v - K (u + h v) + f ],   A = M + h D + h^2 K,   v += dv,   u += h v.

Fixed and prescribed DOFs are removed from the system. Attachment gains enter A (h kd m + h^2 kp m on
their diagonal) so stiff constraints stay stable. The direct solver factorizes A once per (h, constraint
set) and reuses the factor (fem/integrators/spd_factor.py: SuperLU in symmetric mode); the CG solver (the paper's
choice) is Jacobi-preconditioned and warm-started.

``warp=True``, ``warping_model="element"`` (default): standard corotational implicit. The element rotations
R_e (fem/materials/element_warping.py) are held over the step:
    K_w = sum_e R_e K_e R_e^T   (symmetric positive semi-definite and zero on translations),
    A = (1 + h xi) M + (h zeta + h^2) K_w,   rhs = h [ f_w(u, v) - h K_w v + f ],
with f_w the element-warped force (elastic + damping). Held rotations leave out dR/dx here too, so the
same turn check and sub-steps as below apply, measured on the element rotations.

``warping_model="vertex"`` (the paper's per-vertex warping, for comparison; refused at set-up unless
``allow_unbounded_warping=True``: fem/materials/warping_models.py). Linearisation about the
current state, with the vertex rotations R_i (fem/materials/warping.py) frozen over the step:
    K_w = R K R^T,  R = blockdiag(R_i)   (blocks R_i K_ij R_j^T: symmetric positive semi-definite, so CG works),
    D_w = xi M + zeta K_w,   A = M + h D_w + h^2 K_w,
    rhs = h [ f_w(u, v) - h H v + f ],
with f_w the exact warped force (elastic + damping, the clustered warped kernel) and H its Jacobian with
the rotations held (off-diagonal blocks (R_i K_ij R_i^T + R_j K_ij R_j^T) / 2, diagonal blocks minus the
sum of their row's others). The step's fixed point is f_w's; A's K_w differs from H by O(|R_i - R_j|) and
both leave out dR/dx, which only costs Newton-like accuracy, not consistency (the method stays first
order). The velocity term must be H, not K_w: K_w is not translation invariant (K_w t != 0 once the R_i
differ), and a body falling at metres per second picked up forces ~ |K| |R_i - R_j| |v| from round-off-
sized rotation differences, which grew into a deformation of 0.1 m and a spin within 2 s of free fall
(tests/test_hard_cases.py). A is re-assembled and re-factorized every step.

Because the rotations are held over a step, the step treats their change explicitly, and that has a
limit of its own. Measured on the stability table's bar at h = 10 ms, one step each: a released 180 deg
twist and a vertex torn 0.5 m both ran away (energy many times the work put in, then divergence), while
both stay bounded once the step is cut so that no vertex rotation turns by more than ~0.1 rad. So a warped step is
checked after it is taken: if some R_i turned by more than ``max_rotation`` (rad), the step is redone
from its start as 2, 4, ... equal sub-steps (prescribed vertices and attachment targets advanced within
the step), up to ``max_substeps``, which is then taken whatever the turn (a vertex torn from its
neighbours keeps turning fast: the torn bar ran bounded at h / 64 although some R_i turned 0.1-0.3 rad per
sub-step). StepInfo.substeps reports the count. With the vertex model, near incompressibility is refused at
set-up (the element model ran nu = 0.499 bounded on the stability table, so it is not refused): with
nu = 0.499 the warped implicit step diverged at every step tried (h / 64 with up to 64 sub-steps
included), as the held rotations miss the dR/dx coupling through the volumetric stiffness, which grows
as 1 / (1 - 2 nu); nu <= 0.49 (fem/materials/registry.VERTEX_IMPLICIT_MAX_NU) stayed bounded.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..model import Control, FemModel, State
from .spd_factor import factorize_spd
from ..stability import StabilityError
from ..materials.registry import material_model
from .base import StepCommon, StepInfo


class StandardImplicit:
    def __init__(self, model: FemModel, solver: str = "direct", cg_rtol: float = 1e-10, cg_maxiter: int = 2000,
                 warp: bool = False, max_rotation: float = 0.1, max_substeps: int = 64,
                 warping_model: str = "element", allow_unbounded_warping: bool = False):
        if solver not in ("direct", "cg"):
            raise ValueError(f"implicit solver {solver!r}: choose 'direct' or 'cg'")
        self.model = model
        self.solver = solver
        self.warp = bool(warp)
        self.material_model = material_model(self.warp, warping_model)
        self.material_model.check(allow_unbounded_warping, f"implicit_{solver}")
        self.warping_model = warping_model
        self.name = f"implicit_{solver}" + self.material_model.suffix
        self._parts = parts = self.material_model.standard(model)     # None: the linear force of K
        nu = model.material.nu
        limit = None if parts is None else parts.implicit_max_nu
        if limit is not None and nu > limit:
            raise StabilityError(
                f"implicit with stiffness warping refuses nu = {nu:g} (> {limit}): the held rotations miss "
                f"the dR/dx coupling through the volumetric stiffness, which grows as 1 / (1 - 2 nu), and the step "
                f"diverged at every step size tried; use nu <= {limit}, turn warping off, or the clustered "
                "method")
        if not (max_rotation > 0 and max_substeps >= 1):
            raise ValueError(f"max_rotation = {max_rotation} rad and max_substeps = {max_substeps} must be positive")
        self.max_rotation = float(max_rotation)
        self.max_substeps = int(max_substeps)
        if parts is not None:
            self.frames = parts.frames
        self.cg_rtol = cg_rtol
        self.cg_maxiter = cg_maxiter
        self.K = model.K
        self.D = model.damping_matrix()
        self.M = sp.diags(np.repeat(model.mass, 3)).tocsr()
        self._common = StepCommon(model)
        self._key = None
        self._dv_prev: np.ndarray | None = None

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
        if self._parts is None:
            return self._step(state, control, h)
        start = state.copy()
        n = 1
        while True:
            last = 2 * n > self.max_substeps
            iterations, turned = 0, 0.0
            for s in range(n):
                sub = control.at(s * h / n)
                self._common.apply_prescribed(state, sub)    # a prescribed jump is input, not the step's turn
                R0 = self._rotations(state.u)
                iterations += self._step(state, sub, h / n, R0).iterations
                turned = max(turned, _largest_turn(R0, self._rotations(state.u)))
                if turned > self.max_rotation and not last:
                    break
            if turned <= self.max_rotation or last:
                return StepInfo(substeps=n, iterations=iterations)
            state.u[:], state.v[:], state.t = start.u, start.v, start.t
            n *= 2

    def _rotations(self, u: np.ndarray) -> np.ndarray | None:
        """The rotations of u (the material model's: per element or per vertex); None for a model without."""
        return None if self._parts.rotations is None else self._parts.rotations(u)

    def _step(self, state: State, control: Control, h: float, R: np.ndarray | None = None) -> StepInfo:
        """One linearly implicit step; R: the element or vertex rotations of state.u (warped steps)."""
        held = self._common.apply_prescribed(state, control)
        if held is None:
            held = self.model.fixed
        u, v = state.u.reshape(-1), state.v.reshape(-1)
        if self._parts is not None:
            Ks, fw, H = self._parts.implicit_terms(state.u, state.v, R)
            free = self._system(h, held, control, Ks)
            f = self._common.constant_forces(control).reshape(-1) + fw - h * (H @ v)
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


def _largest_turn(R0: np.ndarray, R1: np.ndarray) -> float:
    """The largest angle [rad] of R0_i^T R1_i over the vertices (0 for a model without rotations)."""
    if R0 is None:
        return 0.0
    c = 0.5 * (np.einsum("nij,nij->n", R0, R1) - 1.0)
    return float(np.arccos(np.clip(c, -1.0, 1.0)).max()) if len(c) else 0.0

