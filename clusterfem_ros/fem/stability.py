"""The explicit step's stability limit, sub-stepping, and divergence detection.

Symplectic Euler on one mode (omega^2 = eigenvalue of M^-1 K, damping c = xi + zeta omega^2) has the
amplification matrix with trace 2 - h c - h^2 omega^2 and determinant 1 - h c; it is stable iff
    h^2 omega^2 + 2 h c < 4,
so h_crit = (sqrt(c^2 + 4 omega^2) - c) / omega^2  (2/omega without damping). Attachments add kp to
omega^2 and kd to c. A step longer than safety * h_crit is split into equal sub-steps.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import ClusterFemError
from .linear.material import Material, ParameterError
from .model import Control, FemModel


class StabilityError(ClusterFemError, RuntimeError):
    """The requested step cannot be made stable within the allowed sub-steps."""


class DivergenceError(ClusterFemError, RuntimeError):
    """The state became non-finite or exploded; it is never published."""


def max_eigenvalue(model: FemModel) -> float:
    """Largest eigenvalue of M^-1 K on the free DOFs [1/s^2]."""
    return largest_eigenvalue(model.K, model.mass, model.free_dofs)


def largest_eigenvalue(K: sp.spmatrix, mass: np.ndarray, free: np.ndarray | None = None) -> float:
    """Largest eigenvalue of M^-1 K (K (3n, 3n), lumped mass (n,)) on the DOFs ``free`` (None: all) [1/s^2]."""
    free = np.arange(K.shape[0]) if free is None else free
    if free.size == 0:
        return 0.0
    K = sp.csr_matrix(K)
    s = 1.0 / np.sqrt(np.repeat(mass, 3)[free])
    A = (sp.diags(s) @ K[free][:, free] @ sp.diags(s)).tocsr()
    if A.shape[0] <= 60:
        return float(np.linalg.eigvalsh(A.toarray())[-1])
    rng = np.random.default_rng(0)
    lam = spla.eigsh(A, k=1, which="LA", tol=1e-4, v0=rng.standard_normal(A.shape[0]),
                     return_eigenvectors=False, maxiter=5000)
    return float(lam[0]) * (1.0 + 1e-3)        # eigsh tolerance, rounded up


def critical_step(lam_max: float, xi: float, zeta: float, kp: float = 0.0, kd: float = 0.0) -> float:
    """h_crit of symplectic Euler for the stiffest mode (see module docstring)."""
    w2 = lam_max + kp
    c = xi + zeta * lam_max + kd
    if w2 <= 0.0:
        return math.inf if c == 0.0 else 2.0 / c
    h = (math.sqrt(c * c + 4.0 * w2) - c) / w2
    return min(h, 2.0 / c) if c > 0 else h


def control_critical_step(lam_max: float, material: Material, control: Control | None = None) -> float:
    """critical_step with the stiffest attachment gains of ``control`` (none: the free body's)."""
    kp, kd = control.attachments.gain_maxima() if control is not None else (0.0, 0.0)
    return critical_step(lam_max, material.xi, material.zeta, kp, kd)


@dataclass(frozen=True)
class SubStepPlan:
    substeps: int
    h_sub: float
    h_crit: float

    @property
    def margin(self) -> float:
        """h_crit / h_sub: > 1 is stable; the larger the safer."""
        return self.h_crit / self.h_sub


def check_safety(safety) -> float:
    """``safety`` as a float, refused (ParameterError) outside (0, 1]: a sub-step longer than the critical step is
    unstable by construction, and 0 or less plans no step."""
    ok = isinstance(safety, (int, float, np.integer, np.floating)) and not isinstance(safety, bool)
    if not (ok and 0.0 < float(safety) <= 1.0):
        raise ParameterError(f"safety = {safety!r}: the fraction of the critical step a sub-step may take must be "
                             "in (0, 1] (0.8 is the default; smaller plans more sub-steps)")
    return float(safety)


def plan_substeps(h: float, h_crit: float, safety: float = 0.8, max_substeps: int = 10000) -> SubStepPlan:
    check_safety(safety)
    if not (h > 0 and math.isfinite(h)):
        raise StabilityError(f"time step h = {h!r} s must be positive and finite")
    n = max(1, math.ceil(h / (safety * h_crit))) if math.isfinite(h_crit) else 1
    if n > max_substeps:
        raise StabilityError(f"step {h:.3g} s needs {n} explicit sub-steps (critical step {h_crit:.3g} s, safety "
                             f"{safety}); the limit is {max_substeps}: use a smaller step, a softer material, "
                             "or the implicit method")
    return SubStepPlan(n, h / n, h_crit)


def check_finite(u: np.ndarray, v: np.ndarray, limit: float, where: str = "") -> None:
    """Raise DivergenceError if u or v is non-finite or |u| exceeds ``limit`` metres."""
    if not (np.isfinite(u).all() and np.isfinite(v).all()):
        raise DivergenceError(f"state became non-finite {where}: the step is unstable for this "
                              "material; reduce the step or enable sub-stepping")
    m = float(np.abs(u).max()) if u.size else 0.0
    if m > limit:
        raise DivergenceError(f"displacement {m:.3g} m exceeds the divergence limit {limit:.3g} m {where}: "
                              "the simulation is exploding; reduce the step or check the loads")
