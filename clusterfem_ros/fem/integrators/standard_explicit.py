"""Standard explicit FEM: the same symplectic Euler as the clustered method, on the assembled scipy
matrices with D and K applied separately. The like-for-like reference for the "lossless" claim.

``warp=True``: the warped force, written with numpy per element or assembled matrices, which the clustered
warped kernels must match to round-off. ``warping_model="element"`` (default): each sub-step the element
rotations R_e are extracted (the compiled polar iteration, fem/materials/element_warping.py) and the force is
sum_e -R_e K_e (R_e^T w_e - x0_e) in numpy (fem/materials/corotational.py). ``"vertex"`` (eq. 10 symmetrised,
fem/materials/warping.py; needs ``allow_unbounded_warping=True``, fem/materials/warping_models.py): the vertex rotations
R_i and the block-sparse K warped, blocks (R_i K_ij R_i^T + R_j K_ij R_j^T) / 2 (assembled_warp.AssembledWarp). A
warped step plans its sub-steps for the body's stretch (fem/materials/stretch.py), as the clustered step does."""
from __future__ import annotations

import numpy as np

from ..model import Control, FemModel, State
from ..stability import check_safety, control_critical_step, max_eigenvalue, plan_substeps
from ..materials.registry import material_model
from ..materials.stretch import StretchPlan
from .base import StepCommon, StepInfo


class StandardExplicit:
    name = "standard_explicit"

    def __init__(self, model: FemModel, safety: float = 0.8, max_substeps: int = 10000,
                 lam_max: float | None = None, warp: bool = False, warping_model: str = "element",
                 plan_stretch: bool = True, allow_unbounded_warping: bool = False):
        self.model = model
        self.warp = bool(warp)
        self.material_model = material_model(self.warp, warping_model)
        self.material_model.check(allow_unbounded_warping, self.name, model.material)
        self.warping_model = warping_model
        self._parts = self.material_model.standard(model)       # None: the linear force of K
        self.name += self.material_model.suffix
        if self._parts is not None:
            self.frames = self._parts.frames
        self.safety = check_safety(safety)
        self.max_substeps = max_substeps
        self.lam_max = max_eigenvalue(model) if lam_max is None else lam_max
        self.K = model.K
        self.D = model.damping_matrix()
        self._inv_mass = np.where(model.fixed, 0.0, 1.0 / model.mass)
        self._common = StepCommon(model)
        energy = self.material_model.stretch_energy
        self.stretch = StretchPlan(model, energy=energy) if energy is not None and plan_stretch else None

    def set_max_substeps(self, n: int) -> None:
        """Refuse a step needing more than ``n`` sub-steps from now on."""
        self.max_substeps = int(n)

    def critical_step(self, control: Control | None = None, stiffer: float = 1.0) -> float:
        """h_crit for the linear K's largest eigenvalue times ``stiffer`` (a warped body's stretch factor)."""
        return control_critical_step(self.lam_max * stiffer, self.model.material, control)

    def step(self, state: State, control: Control, h: float) -> StepInfo:
        held = self._common.apply_prescribed(state, control)
        stiffer = self.stretch.factor(state.u, h) if self.stretch is not None else 1.0
        plan = plan_substeps(h, self.critical_step(control, stiffer), self.safety, self.max_substeps)
        inv_mass = (self._inv_mass if held is None else np.where(held, 0.0, self._inv_mass))[:, None]
        f_const = self._common.constant_forces(control)
        att = control.attachments
        m_att = self.model.mass[att.index][:, None]
        u, v = state.u.reshape(-1), state.v.reshape(-1)
        hs = plan.h_sub
        for s in range(plan.substeps):
            tau = s * hs
            if self._parts is not None:
                rotations = self._parts.rotations
                f = self._parts.explicit_force(state.u, state.v, None if rotations is None else rotations(state.u))
            else:
                f = -(self.K @ u) - (self.D @ v)
            f = f.reshape(-1, 3) + f_const
            if att.index.size:
                a = att.at(tau)
                fa = m_att * (a.target_a + a.kp[:, None] * (a.target_u - state.u[att.index])
                              + a.kd[:, None] * (a.target_v - state.v[att.index]))
                np.add.at(f, att.index, fa)
            v += hs * (inv_mass * f).reshape(-1)
            u += hs * v
        self._common.finish(state, h, self.name)
        return StepInfo(substeps=plan.substeps, margin=plan.margin)
