"""Mass scaling: lumped mass added to the few lightest, stiffest vertices so they stop setting the body's step.

The explicit step is planned for the largest eigenvalue of M^-1 K (fem/stability.py), and on a graded mesh that
mode sits on a handful of light vertices: where a mesher keeps a surface's detail (a character's fingers, ears,
toes) its elements are a few millimetres across, their vertices weigh a hundredth of the body's median one, and
their stiffness over mass sets the sub-step of the whole body. Adding mass there (the selective mass scaling of
explicit crash codes) lowers that eigenvalue and leaves the rest of the body untouched; the price is inertia
that is not the material's: the scaled vertices respond more slowly to fast loads, and the skeleton's attachment forces
(per unit mass, fem/model.py's Attachments) grow with them; gravity pulls on the material's mass alone
(FemModel.added_mass).

Which vertices and how much, from Gershgorin's bound on the rows of M^-1 K: vertex i's rows bound the
eigenvalues by r_i / m_i, r_i the largest absolute row sum of its three rows of K. A bound target T gives
m_i' = max(m_i, r_i / T): the least mass that brings every vertex's bound under T. The target is searched
(bisection on T, the true eigenvalue measured by ``max_eigenvalue`` after each) for the largest eigenvalue
that the critical step ``h_goal`` allows, and never takes more than ``max_share`` of the body's mass: when the
share is not enough, the scaling stops at the share and the plan keeps more sub-steps.

What it costs in accuracy, against the unscaled run: on a 0.4 m cantilever whose tip layer is a tenth as thick as
the rest, sagging under gravity from rest, twice the critical step (one sub-step instead of two) takes 0.52 % of
the mass, all on the tip's nine vertices, and moves the vertices by up to 1.55 % of the largest deflection
(0.59 mm of 38 mm; ``python -m pytest -s tests/test_mass_scaling.py`` prints it). On the character's walk:
``python -m benchmarks.mass_scaling_error``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .linear.material import ParameterError
from .model import FemModel
from .stability import critical_step, max_eigenvalue


@dataclass(frozen=True)
class MassScaling:
    """What ``scale_mass`` did: the numbers its log line and /diagnostics report."""
    scaled: int                 # vertices given mass
    added_share: float          # added mass / the body's mass
    lam_before: float           # largest eigenvalue of M^-1 K before [1/s^2]
    lam_after: float            # and after
    h_crit_before: float        # the critical step for the goal's damping and gains, before [s]
    h_crit_after: float         # after
    limited: bool               # max_share stopped it before h_goal was reached

    def summary(self) -> str:
        """One log line."""
        if self.scaled == 0:
            return (f"mass scaling: none needed (critical step {self.h_crit_before * 1e3:.3g} ms already reaches "
                    "the goal)")
        return (f"mass scaling: {self.scaled} vertices given {self.added_share:.2%} of the body's mass, critical step "
                f"{self.h_crit_before * 1e3:.3g} -> {self.h_crit_after * 1e3:.3g} ms"
                + (" (stopped at physics.mass_scaling's share: the goal needs more)" if self.limited else ""))


def row_bounds(model: FemModel) -> np.ndarray:
    """r (n,): each vertex's largest absolute row sum of K over its three rows (Gershgorin: lam <= max r_i / m_i)."""
    r = np.asarray(abs(model.K).sum(axis=1)).reshape(-1, 3).max(axis=1)
    return np.where(model.fixed, 0.0, r)


def _lam_for_step(h_goal: float, xi: float, zeta: float, kp: float, kd: float, lam_hi: float) -> float:
    """The largest eigenvalue whose critical step is >= h_goal (critical_step falls as the eigenvalue grows)."""
    if critical_step(0.0, xi, zeta, kp, kd) < h_goal:
        return 0.0                              # the gains alone set a shorter step: no mass reaches the goal
    lo, hi = 0.0, lam_hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if critical_step(mid, xi, zeta, kp, kd) >= h_goal:
            lo = mid
        else:
            hi = mid
    return lo


def scale_mass(model: FemModel, h_goal: float, max_share: float, kp: float = 0.0, kd: float = 0.0,
               lam_max: float | None = None) -> tuple[FemModel, MassScaling]:
    """(the model with mass added, what was done): the least Gershgorin-selected mass (module docstring) that
    brings the critical step (the material's damping, attachment gains ``kp`` [1/s^2] and ``kd`` [1/s]) to
    ``h_goal`` [s], at most ``max_share`` of the body's mass. ``max_share`` 0 returns the model unchanged."""
    if not (isinstance(max_share, (int, float)) and 0.0 <= max_share <= 1.0):
        raise ParameterError(f"physics.mass_scaling = {max_share!r}: give the largest share of the body's mass that may "
                             "be added, in [0, 1] (0 = off; 0.01 adds at most 1 %)")
    if not (h_goal > 0 and math.isfinite(h_goal)):
        raise ParameterError(f"mass scaling goal h = {h_goal!r} s must be positive and finite")
    xi, zeta = float(model.material.xi), float(model.material.zeta)
    lam0 = max_eigenvalue(model) if lam_max is None else float(lam_max)
    h0 = critical_step(lam0, xi, zeta, kp, kd)
    if max_share == 0.0 or h0 >= h_goal or lam0 <= 0.0:
        return model, MassScaling(0, 0.0, lam0, lam0, h0, h0, False)
    lam_goal = _lam_for_step(h_goal, xi, zeta, kp, kd, lam0)
    r = row_bounds(model)
    m = model.mass
    total = float(m.sum())

    def scaled(T: float) -> np.ndarray:
        return np.maximum(m, r / T)

    def share(T: float) -> float:
        return float((scaled(T) - m).sum()) / total

    # the bound target at the share: share(T) falls as T grows, between T = max r/m (nothing added) and below
    t_top = float((r / m).max())
    lo, hi = t_top * 1e-6, t_top
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if share(mid) > max_share else (lo, mid)
    t_share = hi
    # the bound target for the goal: Gershgorin over-estimates the eigenvalue, so search T on the measured one
    lo, hi = t_share, t_top
    best_T, best_lam = None, lam0
    for _ in range(12):
        mid = math.sqrt(lo * hi)
        lam = max_eigenvalue(dataclasses.replace(model, mass=scaled(mid)))
        if lam <= lam_goal:
            best_T, best_lam, lo = mid, lam, mid     # reached: try adding less
        else:
            hi = mid
        if hi / lo < 1.02:
            break
    limited = best_T is None
    if limited:                                     # the share cannot reach the goal: take all the share allows
        best_T = t_share
        best_lam = max_eigenvalue(dataclasses.replace(model, mass=scaled(best_T)))
    mass = scaled(best_T)
    added = mass - m if model.added_mass is None else model.added_mass + (mass - m)
    out = dataclasses.replace(model, mass=mass, added_mass=added)
    return out, MassScaling(int((mass > m).sum()), float((mass - m).sum()) / total, lam0, best_lam, h0,
                            critical_step(best_lam, xi, zeta, kp, kd), limited)
