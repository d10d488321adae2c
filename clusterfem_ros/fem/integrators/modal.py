"""Modal analysis baseline (the paper compares against k = 30 modes).

Modes: the lowest k eigenpairs of K phi = lambda M phi on the free DOFs (fixed and prescribed vertices
removed), M-orthonormal (Phi^T M Phi = I, Phi^T K Phi = diag lambda). Repeated eigenvalues keep every copy:

- The rigid modes (lambda = 0) are built, not solved for: the rigid motions that leave the held vertices still,
  per connected piece of the mesh (fem/integrators/rigid_modes.py; six for a free body). They come first.
- The rest are solved for in the rigid modes' M-orthogonal complement. Small systems (<= DENSE_MAX_DOFS free
  DOFs, or a block as large as the complement) take a dense eigh there. Larger ones take block subspace
  iteration with shift-invert: X <- (K - sigma M)^-1 M X on a block of p = max(2 k, k + 8) columns, rigid
  components projected out after each solve, then a Rayleigh-Ritz step (a p x p eigh), until the k wanted
  Ritz pairs' residuals |K x - theta M x|_(M^-1) fall under TOL (theta - sigma). sigma = -1e-4 tr(K)/tr(M), a
  small *negative* shift, so K - sigma M is positive definite even for an unconstrained body and factorizes
  (fem/integrators/spd_factor.py). A block method holds all copies of an eigenvalue of multiplicity up to p; a
  single-vector Krylov method (ARPACK's eigsh) finds one vector per distinct
  eigenvalue in exact arithmetic and, in floating point, loses copies above about 600 DOF
  (tests/test_modal.py compares with a dense eigh on a symmetric cube).

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
import scipy.sparse as sp

from ..linear.material import ParameterError
from ..materials.registry import LINEAR
from ..model import Control, FemModel, State
from .rigid_modes import rigid_modes
from .spd_factor import factorize_spd
from .base import StepCommon, StepInfo

DENSE_MAX_DOFS = 600
TOL = 1e-10             # relative residual of a converged Ritz pair (its eigenvalue then to ~TOL^2)
MAX_ITERATIONS = 1000


@dataclass(frozen=True)
class ModalBasis:
    free: np.ndarray        # (f,) free DOF indices
    phi: np.ndarray         # (f, k) M-orthonormal modes
    lam: np.ndarray         # (k,) eigenvalues [1/s^2], ascending, >= 0
    mass: np.ndarray        # (f,) diagonal of M on the free DOFs
    rigid: int = 0          # the first ``rigid`` columns are the built rigid modes


def _dense_complement(K: sp.spmatrix, m: np.ndarray, Z: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The lowest k eigenpairs of K in the M-orthogonal complement of Z's columns, dense."""
    s = 1.0 / np.sqrt(m)
    A = (K.multiply(s[:, None]).multiply(s[None, :])).toarray()
    Q = sla.qr(np.sqrt(m)[:, None] * Z, mode="full")[0][:, Z.shape[1]:] if Z.shape[1] else np.eye(m.size)
    B = Q.T @ A @ Q
    lam, V = sla.eigh(0.5 * (B + B.T), subset_by_index=(0, k - 1))
    return lam, s[:, None] * (Q @ V)


def _subspace_complement(K: sp.spmatrix, m: np.ndarray, Z: np.ndarray, k: int,
                         p: int) -> tuple[np.ndarray, np.ndarray]:
    """The lowest k eigenpairs of K in the M-orthogonal complement of Z's columns, by shift-invert block subspace
    iteration on p columns (module docstring)."""
    sigma = -1e-4 * K.diagonal().sum() / m.sum()
    shifted = factorize_spd(K - sigma * sp.diags(m))
    X = np.random.default_rng(0).standard_normal((m.size, p))
    for it in range(MAX_ITERATIONS):
        X = shifted.solve(m[:, None] * X)
        if Z.shape[1]:
            X -= Z @ (Z.T @ (m[:, None] * X))
        KX = K @ X
        Kr, Mr = X.T @ KX, X.T @ (m[:, None] * X)
        theta, W = sla.eigh(0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T))
        X, KX = X @ W, KX @ W
        R = KX[:, :k] - (m[:, None] * X[:, :k]) * theta[:k]
        residual = np.sqrt((R * R / m[:, None]).sum(axis=0)) / (theta[:k] - sigma)
        if residual.max() <= TOL:
            return theta[:k], X[:, :k]
    raise ParameterError(f"modal basis: {k} modes not converged in {MAX_ITERATIONS} subspace iterations "
                         f"(largest relative residual {residual.max():.2e}); ask for fewer modes")


def modal_basis(model: FemModel, k: int, held: np.ndarray | None = None) -> ModalBasis:
    """The lowest k modes of K phi = lambda M phi with the ``held`` vertices (default: fixed) removed, every copy
    of a repeated eigenvalue kept (module docstring)."""
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ParameterError(f"modal k = {k!r}: give the number of modes, an integer >= 1")
    held = model.fixed if held is None else held
    free = np.flatnonzero(np.repeat(~held, 3))
    m = np.repeat(model.mass, 3)[free]
    if free.size == 0:
        return ModalBasis(free, np.zeros((0, 0)), np.zeros(0), m)
    k = min(int(k), free.size)
    Z = rigid_modes(model.rest, model.mesh.tets, model.mass, held)
    r = Z.shape[1]
    if k <= r:
        return ModalBasis(free, np.ascontiguousarray(Z[:, :k]), np.zeros(k), m, rigid=k)
    K = model.K[free][:, free].tocsc()
    rest = k - r
    p = min(max(2 * rest, rest + 8), free.size - r)
    if free.size <= DENSE_MAX_DOFS or p >= free.size - r:
        lam, phi = _dense_complement(K, m, Z, rest)
    else:
        lam, phi = _subspace_complement(K, m, Z, rest, p)
    phi = np.hstack([Z, phi])
    lam = np.concatenate([np.zeros(r), np.maximum(lam, 0.0)])
    return ModalBasis(free, np.ascontiguousarray(phi), lam, m, rigid=r)


class ModalIntegrator:
    """k-mode modal dynamics with the standard integrator interface (``step(state, control, h)``)."""
    name = "modal"
    material_model = LINEAR             # the modes of the linear K

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
