"""Modal analysis baseline (the paper compares against k = 30 modes).

Modes: the lowest k eigenpairs of K phi = lambda M phi on the free DOFs (fixed and prescribed vertices
removed), M-orthonormal (Phi^T M Phi = I, Phi^T K Phi = diag lambda). For k < the free DOF count they
come from scipy's eigsh in shift-invert mode with sigma = -1e-4 * tr(K)/tr(M) (a small *negative*
shift): K - sigma M is then positive definite even when the body is unconstrained, so the six rigid
modes (lambda = 0) factorize (fem/spd_factor.py) without a singular matrix and come out first; the eigsh
vectors are then refined by one Rayleigh-Ritz step (a k x k eigh) so the basis is M-orthonormal to
round-off and the tiny negative lambdas of rigid modes are clamped to 0. Small systems (or k >= free
DOFs) use dense eigh.

Each mode is a damped oscillator with the model's Rayleigh damping, c = xi + zeta lambda, driven by
the projected force g = Phi^T f, f = gravity + f_ext + attachments (as forces, evaluated at the start of
the step) - K_fh (u_h + h v_h) - D_fh v_h (the pull of prescribed vertices h on the free ones).
It is stepped with the same linearly implicit Euler as the standard method (eq. 3), per mode:

    (1 + h c + h^2 lambda) dq' = h [ g - c q' - lambda (q + h q') ],  q' += dq',  q += h q'.

With all modes this is the standard implicit step in another basis (equal to round-off, without
attachments: those enter the standard method's matrix). The state stays the full (n, 3) u, v: each step
projects it, q = Phi^T M u_f, and writes back u_f = Phi q (components outside the basis are dropped).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse.linalg as spla

from ..material import ParameterError
from ..model import Control, FemModel, State
from ..spd_factor import factorize_spd
from .base import StepCommon, StepInfo

DENSE_MAX_DOFS = 600


@dataclass(frozen=True)
class ModalBasis:
    free: np.ndarray        # (f,) free DOF indices
    phi: np.ndarray         # (f, k) M-orthonormal modes
    lam: np.ndarray         # (k,) eigenvalues [1/s^2], ascending, >= 0
    mass: np.ndarray        # (f,) diagonal of M on the free DOFs


def modal_basis(model: FemModel, k: int, held: np.ndarray | None = None) -> ModalBasis:
    """The lowest k modes of K phi = lambda M phi with the ``held`` vertices (default: fixed) removed."""
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ParameterError(f"modal k = {k!r}: give the number of modes, an integer >= 1")
    held = model.fixed if held is None else held
    free = np.flatnonzero(np.repeat(~held, 3))
    m = np.repeat(model.mass, 3)[free]
    if free.size == 0:
        return ModalBasis(free, np.zeros((0, 0)), np.zeros(0), m)
    K = model.K[free][:, free].tocsc()
    k = min(int(k), free.size)
    if free.size <= DENSE_MAX_DOFS or k >= free.size - 1:
        s = 1.0 / np.sqrt(m)
        lam, V = sla.eigh((K.multiply(s[:, None]).multiply(s[None, :])).toarray(), subset_by_index=(0, k - 1))
        phi = s[:, None] * V
    else:
        import scipy.sparse as sp
        M = sp.diags(m).tocsc()
        sigma = -1e-4 * K.diagonal().sum() / m.sum()
        v0 = np.random.default_rng(0).standard_normal(free.size)
        shifted = factorize_spd(K - sigma * M)
        _, phi = spla.eigsh(K, k=k, M=M, sigma=sigma, which="LM", v0=v0, tol=1e-12, OPinv=shifted.operator())
        Kr = phi.T @ (K @ phi)
        Mr = phi.T @ (m[:, None] * phi)
        lam, W = sla.eigh(0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T))
        phi = phi @ W
    return ModalBasis(free, np.ascontiguousarray(phi), np.maximum(lam, 0.0), m)


class ModalIntegrator:
    """k-mode modal dynamics with the standard integrator interface (``step(state, control, h)``)."""
    name = "modal"

    def __init__(self, model: FemModel, k: int = 30):
        self.model = model
        self.k = k
        self._common = StepCommon(model)
        self._bases: dict[bytes, ModalBasis] = {}
        self.basis = self._basis(model.fixed)           # computes (and validates k) at set-up

    def _basis(self, held: np.ndarray) -> ModalBasis:
        key = held.tobytes()
        if key not in self._bases:
            if len(self._bases) > 8:
                self._bases.clear()
            self._bases[key] = modal_basis(self.model, self.k, held)
        return self._bases[key]

    def step(self, state: State, control: Control, h: float) -> StepInfo:
        if not (h > 0 and np.isfinite(h)):
            raise ParameterError(f"time step h = {h!r} s must be positive and finite")
        held = self._common.apply_prescribed(state, control)
        extra_held = held is not None
        if held is None:
            held = self.model.fixed
        b = self._basis(held)
        mat = self.model.material
        f = self._common.constant_forces(control).copy()
        att = control.attachments
        if att.index.size:
            mm = self.model.mass[att.index][:, None]
            np.add.at(f, att.index, mm * (att.target_a + att.kp[:, None] * (att.target_u - state.u[att.index])
                                          + att.kd[:, None] * (att.target_v - state.v[att.index])))
        f = f.reshape(-1)
        u, v = state.u.reshape(-1), state.v.reshape(-1)
        held_dofs = np.flatnonzero(np.repeat(held, 3))
        if extra_held:                                   # prescribed vertices pull on the free ones
            w = np.zeros_like(u)
            w[held_dofs] = u[held_dofs] + (h + mat.zeta) * v[held_dofs]
            f = f - self.model.K @ w
        free = b.free
        if free.size:
            g = b.phi.T @ f[free]
            q = b.phi.T @ (b.mass * u[free])
            qd = b.phi.T @ (b.mass * v[free])
            c = mat.xi + mat.zeta * b.lam
            qd += h * (g - c * qd - b.lam * (q + h * qd)) / (1.0 + h * c + h * h * b.lam)
            q += h * qd
            v[free] = b.phi @ qd
            u[free] = b.phi @ q
        u[held_dofs] += h * v[held_dofs]
        if self._common.fixed_index.size:
            state.u[self._common.fixed_index] = 0.0
        self._common.finish(state, h, self.name)
        return StepInfo(substeps=1, iterations=0)
