"""Clustered explicit FEM (eqs. 4-5): symplectic Euler driven by the fused cluster force kernel.

All sub-steps of one step run inside one numba call: force, constraint forces, velocity and position
updates, with no Python in between. ``warp=True`` swaps in the stiffness-warped force of eq. 10
(fem/warping.py) on the same clusters; the linear path is a separate compiled function, untouched.
The critical step is the linear one: R_i K R_i^T has K's spectrum, so warping does not shift it much.
"""
from __future__ import annotations

import numba
import numpy as np

from ..cluster_force_kernel import cluster_args, force_kernel_parallel, force_kernel_serial, pick_kernel
from ..model import Control, FemModel, State
from ..numba_config import SERIAL
from ..stability import critical_step, max_eigenvalue, plan_substeps
from ..warping import VertexFrames, warped_kernel_parallel, warped_kernel_serial
from .base import StepCommon, StepInfo


def _make_symplectic_euler(force):
    """The fused step around one build of the force kernel (a closure: numba inlines the call)."""

    def symplectic_euler(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks,
                         mass, inv_mass, u, v, f_const, att_idx, att_u, att_v, att_a, att_kp, att_kd,
                         zeta, xi, h, nsub, w, f):
        n = u.shape[0]
        umax = 0.0
        probe = 0.0
        for s in range(nsub):
            force(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks, u, v, mass, zeta, xi, w, f)
            tau = s * h
            for a in range(att_idx.shape[0]):
                i = att_idx[a]
                m = mass[i]
                for c in range(3):
                    tu = att_u[a, c] + tau * att_v[a, c] + 0.5 * tau * tau * att_a[a, c]
                    tv = att_v[a, c] + tau * att_a[a, c]
                    f[i, c] += m * (att_a[a, c] + att_kp[a] * (tu - u[i, c]) + att_kd[a] * (tv - v[i, c]))
            for i in range(n):
                im = h * inv_mass[i]
                for c in range(3):
                    v[i, c] += im * (f[i, c] + f_const[i, c])
                    u[i, c] += h * v[i, c]
        for i in range(n):          # divergence probe: nan if anything is non-finite
            for c in range(3):
                probe += (u[i, c] - u[i, c]) + (v[i, c] - v[i, c])
                umax = max(umax, abs(u[i, c]))
        return umax, probe

    return symplectic_euler


_step_serial = numba.njit(**SERIAL)(_make_symplectic_euler(force_kernel_serial))
_step_parallel = numba.njit(**SERIAL)(_make_symplectic_euler(force_kernel_parallel))


def _make_warped_symplectic_euler(force):
    """The fused step around one build of the warped force kernel (eq. 10); otherwise as above."""

    def warped_symplectic_euler(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks,
                                rest, s0inv, rot, scratch,
                                mass, inv_mass, u, v, f_const, att_idx, att_u, att_v, att_a, att_kp, att_kd,
                                zeta, xi, h, nsub, f):
        n = u.shape[0]
        umax = 0.0
        probe = 0.0
        for s in range(nsub):
            force(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks,
                  rest, s0inv, u, v, mass, zeta, xi, rot, scratch, f)
            tau = s * h
            for a in range(att_idx.shape[0]):
                i = att_idx[a]
                m = mass[i]
                for c in range(3):
                    tu = att_u[a, c] + tau * att_v[a, c] + 0.5 * tau * tau * att_a[a, c]
                    tv = att_v[a, c] + tau * att_a[a, c]
                    f[i, c] += m * (att_a[a, c] + att_kp[a] * (tu - u[i, c]) + att_kd[a] * (tv - v[i, c]))
            for i in range(n):
                im = h * inv_mass[i]
                for c in range(3):
                    v[i, c] += im * (f[i, c] + f_const[i, c])
                    u[i, c] += h * v[i, c]
        for i in range(n):
            for c in range(3):
                probe += (u[i, c] - u[i, c]) + (v[i, c] - v[i, c])
                umax = max(umax, abs(u[i, c]))
        return umax, probe

    return warped_symplectic_euler


_warped_step_serial = numba.njit(**SERIAL)(_make_warped_symplectic_euler(warped_kernel_serial))
_warped_step_parallel = numba.njit(**SERIAL)(_make_warped_symplectic_euler(warped_kernel_parallel))


class ClusteredExplicit:
    """The paper's method. ``safety`` scales the critical step; ``threads`` forces the threaded kernel on/off;
    ``warp`` turns on stiffness warping (eq. 10)."""
    name = "clustered"

    def __init__(self, model: FemModel, safety: float = 0.8, max_substeps: int = 10000,
                 threads: bool | None = None, lam_max: float | None = None, warp: bool = False):
        self.model = model
        self.warp = bool(warp)
        if self.warp:
            self.name = "clustered_warp"
            self.frames = VertexFrames.from_model(model)
        self.safety = safety
        self.max_substeps = max_substeps
        self.lam_max = max_eigenvalue(model) if lam_max is None else lam_max
        kernel = pick_kernel(model.n_vertices, threads)
        self._step = _step_parallel if kernel is force_kernel_parallel else _step_serial
        if self.warp:
            self._step = _warped_step_parallel if kernel is force_kernel_parallel else _warped_step_serial
        self._args = cluster_args(model.clusters)
        n = model.n_vertices
        self._w = np.empty((n, 3))
        self._f = np.empty((n, 3))
        self._inv_mass = np.where(model.fixed, 0.0, 1.0 / model.mass)
        self._common = StepCommon(model)
        m = model.material
        self._h_crit_free = critical_step(self.lam_max, m.xi, m.zeta)

    def critical_step(self, control: Control | None = None) -> float:
        if control is None or not control.attachments.index.size:
            return self._h_crit_free
        kp, kd = float(control.attachments.kp.max()), float(control.attachments.kd.max())
        m = self.model.material
        return critical_step(self.lam_max, m.xi, m.zeta, kp, kd)

    def step(self, state: State, control: Control, h: float) -> StepInfo:
        plan = plan_substeps(h, self.critical_step(control), self.safety, self.max_substeps)
        held = self._common.apply_prescribed(state, control)
        inv_mass = self._inv_mass if held is None else np.where(held, 0.0, self._inv_mass)
        att = control.attachments
        m = self.model.material
        if self.warp:
            fr = self.frames
            umax, probe = self._step(*self._args, fr.rest, fr.s0inv, fr.rot, fr.scratch, self.model.mass,
                                     inv_mass, state.u, state.v, self._common.constant_forces(control), att.index,
                                     att.target_u, att.target_v, att.target_a, att.kp, att.kd, m.zeta, m.xi,
                                     plan.h_sub, plan.substeps, self._f)
            self._common.finish(state, h, self.name, umax=umax if probe == 0.0 else float("nan"))
            return StepInfo(substeps=plan.substeps, margin=plan.margin)
        umax, probe = self._step(*self._args, self.model.mass, inv_mass, state.u, state.v,
                   self._common.constant_forces(control), att.index, att.target_u, att.target_v, att.target_a,
                   att.kp, att.kd, m.zeta, m.xi, plan.h_sub, plan.substeps, self._w, self._f)
        self._common.finish(state, h, self.name, umax=umax if probe == 0.0 else float("nan"))
        return StepInfo(substeps=plan.substeps, margin=plan.margin)
