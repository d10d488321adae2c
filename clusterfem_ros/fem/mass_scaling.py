"""Selective mass scaling: extra lumped mass at the few vertices whose thin tets would shorten the explicit step.

The explicit step's critical step comes from the largest eigenvalue of M^-1 K (fem/stability.py). A mesh whose
vertices were moved off a regular grid (the smooth jelly man, skeleton/smooth_body.py) keeps the grid's tets but
has some thinner ones at its skin, and a tet of altitude a has eigenvalues ~ E / (rho a^2): a floor of 0.7 of the
voxel altitude doubles the body's largest eigenvalue, and the step it allows falls by 1 / sqrt(2).

``vertex_rates`` bounds each vertex's row of M^-1 K by Gershgorin (the sum of |K_ij| over its three rows, the
largest, over its mass); the largest eigenvalue is at most the largest rate. ``cap_rates`` raises the mass of
every vertex whose rate exceeds a cap to the mass that brings it down to the cap, and nothing else; with the cap
at the largest rate of a reference mesh of the same tets (the smooth body's voxels), no vertex is stiffer for its
mass than the reference's stiffest; ``scale_to_reference`` then lowers the cap until the largest eigenvalue
(fem/stability.py) is the reference's, so the body keeps the reference's critical step. The extra mass is a
modelling error, stated by ``MassScaling``: it adds weight and inertia at those vertices only (gravity acts on
the scaled mass, the binding's gains are per unit mass, so its targets are followed the same way).

Arrays: mass (n,) [kg]; K (3n, 3n) [N/m]; rates (n,) [1/s^2].
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from .linear.assembly import assemble_stiffness, lumped_mass
from .linear.material import Material, ParameterError
from .mesh.tet_mesh import TetMesh
from .model import FemModel
from .stability import largest_eigenvalue

ROUNDS = 6                  # lowerings of the cap at most (the jelly man needs none or one)
TOLERANCE = 2e-3            # the scaled body's largest eigenvalue may exceed the reference's by this share


@dataclass(frozen=True)
class MassScaling:
    """What ``cap_rates`` did: the new masses, which vertices it raised and by how much in all."""
    mass: np.ndarray            # (n,) the scaled lumped masses [kg]
    raised: np.ndarray          # (k,) the vertices whose mass was raised
    added_share: float          # sum of the added mass over the body's own mass
    max_factor: float           # the largest scaled / own mass of a vertex (1 when none was raised)
    cap: float                  # the rate cap [1/s^2]
    eigenvalues: tuple = ()     # (own, scaled, reference) largest eigenvalues of M^-1 K [1/s^2] (scale_to_reference)

    def summary(self, n: int) -> str:
        text = (f"mass scaling: {self.raised.size} of {n} vertices heavier (at most x{self.max_factor:.2f}), "
                f"+{100 * self.added_share:.2f} % of the body's mass")
        if self.eigenvalues:
            own, lam, ref = self.eigenvalues
            text += (f": largest eigenvalue of M^-1 K {own:.4g} -> {lam:.4g} 1/s^2 (the reference's {ref:.4g}; "
                     f"free critical step x{np.sqrt(own / lam):.2f})")
        return text


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


def cap_rates(K: sp.spmatrix, mass: np.ndarray, cap: float) -> MassScaling:
    """The masses raised where a vertex's rate (``vertex_rates``) exceeds ``cap`` [1/s^2], to exactly the cap."""
    if not (np.isfinite(cap) and cap > 0):
        raise ParameterError(f"rate cap = {float(cap)!r} 1/s^2 must be positive and finite (the largest vertex rate of "
                             "a reference mesh: reference_rate)")
    mass = np.asarray(mass, dtype=np.float64)
    rates = vertex_rates(K, mass)
    scaled = np.where(rates > cap, mass * rates / cap, mass)
    raised = np.flatnonzero(rates > cap)
    return MassScaling(scaled, raised, float(scaled.sum() / mass.sum() - 1.0), float((scaled / mass).max()),
                       float(cap))


def reference_rate(mesh: TetMesh, material: Material) -> float:
    """The largest vertex rate of ``mesh`` with ``material`` (its stiffest vertex for its mass) [1/s^2]."""
    return float(vertex_rates(assemble_stiffness(mesh, material), lumped_mass(mesh, material.rho)).max())


def scale_to_reference(model: FemModel, reference: TetMesh) -> tuple[FemModel, MassScaling]:
    """``model`` with its masses capped so that its largest eigenvalue is at most that of ``reference`` (same
    tets, other vertex positions: the mesh it was moved from), and what that did. The cap starts at the
    reference's largest vertex rate and is lowered by the eigenvalues' ratio while the scaled body's largest
    eigenvalue is above the reference's (the rates bound each body's own eigenvalue, not as tightly on both)."""
    tets = model.mesh.tets
    if reference.tets.shape != tets.shape or not np.array_equal(reference.tets, tets):
        raise ParameterError(f"the reference mesh has {reference.n_tets} tets and the body {model.mesh.n_tets}, or "
                             "other connectivity: mass scaling compares a body with the mesh it was moved from "
                             "(the same tets)")
    K_ref, m_ref = assemble_stiffness(reference, model.material), lumped_mass(reference, model.material.rho)
    free = model.free_dofs
    target = largest_eigenvalue(K_ref, m_ref, free)
    cap = float(vertex_rates(K_ref, m_ref).max())
    own = largest_eigenvalue(model.K, model.mass, free)
    scaling = cap_rates(model.K, model.mass, cap)
    lam = largest_eigenvalue(model.K, scaling.mass, free)
    for _ in range(ROUNDS):
        if lam <= target * (1.0 + TOLERANCE):
            break
        scaling = cap_rates(model.K, model.mass, scaling.cap * target / lam)
        lam = largest_eigenvalue(model.K, scaling.mass, free)
    scaling = replace(scaling, eigenvalues=(own, lam, target))
    return replace(model, mass=scaling.mass), scaling
