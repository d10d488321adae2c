"""Selective mass scaling: lumped mass added at the few vertices that would otherwise set the explicit step.

The explicit step is planned for the largest eigenvalue of M^-1 K (fem/stability.py), and that mode sits on a
handful of vertices that are stiff for their mass: where a mesher keeps a surface's detail (a character's
fingers, ears, toes) its elements are a few millimetres across and their vertices weigh a hundredth of the body's
median one; where vertices were moved off a regular grid (the smooth jelly man, skeleton/smooth_body.py) the
thinner skin tets have eigenvalues ~ E / (rho a^2) for an altitude a, and a floor of 0.7 of the voxel altitude
doubles the body's largest eigenvalue. Adding mass there (the selective mass scaling of explicit crash codes)
lowers that eigenvalue and leaves the rest of the body untouched.

Which vertices and how much, from Gershgorin's bound on the rows of M^-1 K: vertex i's three rows bound the
eigenvalues by its rate r_i / m_i, r_i the largest absolute row sum of its three rows of K (``vertex_rates``).
A cap T on the rates gives m_i' = max(m_i, r_i / T) (``cap_rates``): the least mass that brings every vertex's
bound under T. ``scale_to_eigenvalue`` searches T (bisection, the true eigenvalue measured by
``largest_eigenvalue`` after each) for the least mass whose largest eigenvalue is at most a goal, never adding
more than ``max_share`` of the body's mass. Two goals:

- ``scale_mass``: the eigenvalue whose critical step, with the attachment gains, is a goal step (one sub-step of
  the scene's step): ``physics.mass_scaling`` on any explicit scene, at most its share of the mass.
- ``scale_to_reference``: the eigenvalue of a reference mesh of the same tets (the voxels the smooth jelly man
  was moved from), so the moved body keeps the reference's critical step.

The price is inertia that is not the material's: the scaled vertices respond more slowly to fast loads, and the
skeleton's attachment forces (per unit mass, fem/model.py's Attachments) grow with them; gravity pulls on the
material's mass alone (FemModel.added_mass). On a 0.4 m cantilever whose tip layer is a tenth as thick as the
rest, sagging under gravity from rest, one sub-step instead of two takes 0.52 % of the mass, all on the tip's
nine vertices, and moves the vertices by up to 1.55 % of the largest deflection (``python -m pytest -s
tests/test_mass_scaling.py`` prints it); on the character's walk: ``python -m benchmarks.mass_scaling_error``; on
the smooth jelly man: ``python -m benchmarks.skin_compare``.

Arrays: mass (n,) [kg]; K (3n, 3n) [N/m]; rates (n,) [1/s^2].
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .linear.assembly import assemble_stiffness, lumped_mass
from .linear.material import Material, ParameterError
from .mesh.tet_mesh import TetMesh
from .model import FemModel
from .stability import critical_step, largest_eigenvalue

SEARCH_ROUNDS = 12          # bisections of the cap on the measured eigenvalue at most
SEARCH_RATIO = 1.02         # the search stops when its bracket of caps is this narrow
TOLERANCE = 2e-3            # scale_to_reference: the scaled body's largest eigenvalue may exceed the reference's by this share


@dataclass(frozen=True)
class MassScaling:
    """What a scaling did: the masses, which vertices it raised, and the eigenvalues and steps before and after."""
    mass: np.ndarray            # (n,) the scaled lumped masses [kg]
    raised: np.ndarray          # (k,) the vertices whose mass was raised
    added_share: float          # added mass / the body's own mass
    max_factor: float           # the largest scaled / own mass of a vertex (1 when none was raised)
    cap: float                  # the rate cap [1/s^2] (inf: nothing capped)
    lam_before: float = math.nan    # largest eigenvalue of M^-1 K, own masses [1/s^2]
    lam_after: float = math.nan     # with the scaled masses
    lam_goal: float = math.nan      # what it aimed at
    h_crit_before: float = math.nan     # the critical step before [s] (scale_mass: with its gains and damping)
    h_crit_after: float = math.nan      # and after
    limited: bool = False           # max_share stopped it before the goal was reached

    def summary(self) -> str:
        """One log line."""
        if self.raised.size == 0:
            return (f"mass scaling: none needed (largest eigenvalue of M^-1 K {self.lam_before:.4g} 1/s^2, critical "
                    f"step {self.h_crit_before * 1e3:.3g} ms)")
        return (f"mass scaling: {self.raised.size} vertices given {self.added_share:.2%} of the body's mass (at most "
                f"x{self.max_factor:.2f}), largest eigenvalue of M^-1 K {self.lam_before:.4g} -> {self.lam_after:.4g} "
                f"1/s^2 (goal {self.lam_goal:.4g}), critical step {self.h_crit_before * 1e3:.3g} -> "
                f"{self.h_crit_after * 1e3:.3g} ms"
                + (" (stopped at its share of the mass: the goal needs more)" if self.limited else ""))

    def applied(self, model: FemModel) -> FemModel:
        """``model`` with these masses, the added part kept as inertia only (FemModel.added_mass)."""
        added = self.mass - model.mass
        if model.added_mass is not None:
            added = added + model.added_mass
        return dataclasses.replace(model, mass=self.mass, added_mass=added if self.raised.size else model.added_mass)


def vertex_rates(K: sp.spmatrix, mass: np.ndarray) -> np.ndarray:
    """(n,) Gershgorin bound of each vertex's rows of M^-1 K: max over its 3 rows of sum_j |K_ij|, over m_i."""
    mass = np.asarray(mass, dtype=np.float64)
    if K.shape != (3 * mass.size, 3 * mass.size):
        raise ParameterError(f"K has shape {K.shape}, expected ({3 * mass.size}, {3 * mass.size}) for {mass.size} "
                             "masses")
    if not (mass > 0).all():
        i = int(np.flatnonzero(~(mass > 0))[0])
        raise ParameterError(f"vertex {i} has mass {float(mass[i])!r} kg: every vertex needs a positive mass (a vertex "
                             "in no tet has none; remove it from the mesh)")
    rows = np.asarray(abs(sp.csr_matrix(K)).sum(axis=1)).ravel().reshape(-1, 3).max(axis=1)
    return rows / mass


def cap_rates(K: sp.spmatrix, mass: np.ndarray, cap: float, fixed: np.ndarray | None = None) -> MassScaling:
    """The masses raised where a vertex's rate (``vertex_rates``) exceeds ``cap`` [1/s^2], to exactly the cap
    (``fixed`` vertices, which do not move, never)."""
    if not (np.isfinite(cap) and cap > 0):
        raise ParameterError(f"rate cap = {float(cap)!r} 1/s^2 must be positive and finite (the largest vertex rate of "
                             "a reference mesh: reference_rate)")
    mass = np.asarray(mass, dtype=np.float64)
    rates = vertex_rates(K, mass)
    if fixed is not None:
        rates = np.where(fixed, 0.0, rates)
    over = rates > cap
    scaled = np.where(over, mass * rates / cap, mass)
    return MassScaling(scaled, np.flatnonzero(over), float(scaled.sum() / mass.sum() - 1.0),
                       float((scaled / mass).max()), float(cap))


def reference_rate(mesh: TetMesh, material: Material) -> float:
    """The largest vertex rate of ``mesh`` with ``material`` (its stiffest vertex for its mass) [1/s^2]."""
    return float(vertex_rates(assemble_stiffness(mesh, material), lumped_mass(mesh, material.rho)).max())


def _check_share(max_share) -> float:
    if not (isinstance(max_share, (int, float)) and not isinstance(max_share, bool) and 0.0 <= max_share <= 1.0):
        raise ParameterError(f"physics.mass_scaling = {max_share!r}: give the largest share of the body's mass that may "
                             "be added, in [0, 1] (0 = off; 0.01 adds at most 1 %)")
    return float(max_share)


def scale_to_eigenvalue(model: FemModel, lam_goal: float, max_share: float = 1.0,
                        lam_before: float | None = None, tolerance: float = 0.0) -> MassScaling:
    """The least Gershgorin-selected mass (module docstring) that brings the largest eigenvalue of M^-1 K to at
    most ``lam_goal`` [1/s^2] (times 1 + ``tolerance``), at most ``max_share`` of the body's mass (when that is not enough: all the share
    allows, ``limited``). The critical steps are the free ones (no gains); apply it with ``MassScaling.applied``."""
    max_share = _check_share(max_share)
    free = model.free_dofs
    xi, zeta = float(model.material.xi), float(model.material.zeta)
    lam0 = largest_eigenvalue(model.K, model.mass, free) if lam_before is None else float(lam_before)
    m = model.mass
    rates = np.where(model.fixed, 0.0, vertex_rates(model.K, m))
    t_top = float(rates.max())
    none = MassScaling(m.copy(), np.zeros(0, dtype=np.int64), 0.0, 1.0, math.inf, lam0, lam0, float(lam_goal),
                       critical_step(lam0, xi, zeta), critical_step(lam0, xi, zeta), False)
    if lam0 <= lam_goal * (1.0 + tolerance) or max_share == 0.0 or t_top <= 0.0:
        return none
    total = float(m.sum())

    rows = rates * m                             # r_i: the mass that gives vertex i the rate T is r_i / T

    def share(T: float) -> float:
        return float((np.maximum(m, rows / T) - m).sum()) / total

    # the cap at the share: share(T) falls as T grows, from T = max rate (nothing added)
    lo, hi = t_top * 1e-6, t_top
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if share(mid) > max_share else (lo, mid)
    t_share = hi
    # the cap for the goal: Gershgorin over-estimates the eigenvalue, so the cap is searched on the measured one
    lo, hi = t_share, t_top
    best = None
    for _ in range(SEARCH_ROUNDS):
        mid = math.sqrt(lo * hi)
        s = cap_rates(model.K, m, mid, model.fixed)
        lam = largest_eigenvalue(model.K, s.mass, free)
        if lam <= lam_goal * (1.0 + tolerance):
            best, lo = (s, lam), mid            # reached: try adding less
        else:
            hi = mid
        if hi / lo < SEARCH_RATIO:
            break
    limited = best is None
    if limited:                                 # the share cannot reach the goal: take all the share allows
        s = cap_rates(model.K, m, t_share, model.fixed)
        best = (s, largest_eigenvalue(model.K, s.mass, free))
    s, lam = best
    return dataclasses.replace(s, lam_before=lam0, lam_after=lam, lam_goal=float(lam_goal),
                               h_crit_before=critical_step(lam0, xi, zeta), h_crit_after=critical_step(lam, xi, zeta),
                               limited=limited)


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
    """(the model with mass added, what was done): the least mass (``scale_to_eigenvalue``) that brings the
    critical step (the material's damping, attachment gains ``kp`` [1/s^2] and ``kd`` [1/s]) to ``h_goal`` [s], at
    most ``max_share`` of the body's mass. ``max_share`` 0 returns the model unchanged."""
    max_share = _check_share(max_share)
    if not (h_goal > 0 and math.isfinite(h_goal)):
        raise ParameterError(f"mass scaling goal h = {h_goal!r} s must be positive and finite")
    xi, zeta = float(model.material.xi), float(model.material.zeta)
    lam0 = largest_eigenvalue(model.K, model.mass, model.free_dofs) if lam_max is None else float(lam_max)
    h0 = critical_step(lam0, xi, zeta, kp, kd)
    if max_share == 0.0 or h0 >= h_goal or lam0 <= 0.0:
        none = MassScaling(model.mass.copy(), np.zeros(0, dtype=np.int64), 0.0, 1.0, math.inf, lam0, lam0, lam0,
                           h0, h0, False)
        return model, none
    s = scale_to_eigenvalue(model, _lam_for_step(h_goal, xi, zeta, kp, kd, lam0), max_share, lam0)
    s = dataclasses.replace(s, h_crit_before=h0, h_crit_after=critical_step(s.lam_after, xi, zeta, kp, kd))
    return s.applied(model), s


def scale_to_reference(model: FemModel, reference: TetMesh, max_share: float = 1.0) -> tuple[FemModel, MassScaling]:
    """``model`` with its masses raised so that its largest eigenvalue is at most that of ``reference`` (same tets,
    other vertex positions: the mesh it was moved from), and what that did."""
    tets = model.mesh.tets
    if reference.tets.shape != tets.shape or not np.array_equal(reference.tets, tets):
        raise ParameterError(f"the reference mesh has {reference.n_tets} tets and the body {model.mesh.n_tets}, or "
                             "other connectivity: mass scaling compares a body with the mesh it was moved from "
                             "(the same tets)")
    K_ref, m_ref = assemble_stiffness(reference, model.material), lumped_mass(reference, model.material.rho)
    s = scale_to_eigenvalue(model, largest_eigenvalue(K_ref, m_ref, model.free_dofs), max_share, tolerance=TOLERANCE)
    return s.applied(model), s
