"""The fixed model, the changing state and the control input (warp.sim's Model / State / Control).

``FemModel`` is built once and never changes while stepping; ``State`` is advanced by an
integrator's ``step(state, control, h)``; ``Control`` carries what changes from outside each step.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from .linear.assembly import assemble_stiffness, element_stiffness_blocks, lumped_mass, shape_gradients
from .kernels.clusters import Clusters, build_clusters
from .linear.material import Material, ParameterError
from .mesh.tet_mesh import TetMesh
from .mesh.tet_quality import MIN_QUALITY, MeshQuality, check_quality


@dataclass(frozen=True)
class FemModel:
    mesh: TetMesh
    material: Material
    mass: np.ndarray            # (n,) lumped [kg]
    K: sp.csr_matrix            # (3n, 3n) assembled stiffness [N/m]
    clusters: Clusters          # the same K as per-vertex clusters
    fixed: np.ndarray           # (n,) bool: Dirichlet vertices held at zero displacement
    gravity: np.ndarray         # (3,) [m/s^2]
    quality: MeshQuality | None = None      # the tets' shape quality, measured by build_model (fem/mesh/tet_quality.py)
    added_mass: np.ndarray | None = None    # (n,) [kg] the part of ``mass`` mass scaling added (fem/mass_scaling.py):
                                            # inertia only, gravity pulls on the material's mass

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @cached_property
    def rest_gradients(self) -> tuple[np.ndarray, np.ndarray]:
        """(g, vol): each tet's rest shape gradients (m, 4, 3) and volume (m,) [m^3], made on first use and kept
        with the model (the stress asks at every output)."""
        return shape_gradients(self.rest, self.mesh.tets)

    @property
    def rest(self) -> np.ndarray:
        return self.mesh.vertices

    @property
    def free_dofs(self) -> np.ndarray:
        return np.flatnonzero(np.repeat(~self.fixed, 3))

    def gravity_force(self) -> np.ndarray:
        """The weight of the material's mass (n, 3) [N] (mass scaling's added inertia weighs nothing)."""
        mass = self.mass if self.added_mass is None else self.mass - self.added_mass
        return mass[:, None] * self.gravity[None, :]

    def damping_matrix(self) -> sp.csr_matrix:
        """D = xi M + zeta K, assembled (for the standard methods; the clustered one never forms it)."""
        return (self.material.xi * sp.diags(np.repeat(self.mass, 3)) + self.material.zeta * self.K).tocsr()

    def elastic_energy(self, u: np.ndarray) -> float:
        x = u.reshape(-1)
        return 0.5 * float(x @ (self.K @ x))

    def kinetic_energy(self, v: np.ndarray) -> float:
        return 0.5 * float((self.mass[:, None] * v * v).sum())


def build_model(mesh: TetMesh, material: Material, fixed: np.ndarray | None = None,
                gravity=(0.0, 0.0, -9.81), min_quality: float = MIN_QUALITY) -> FemModel:
    """Validate the mesh (a tet below ``min_quality`` is refused: fem/mesh/tet_quality.py), assemble K and M, and build
    the clusters."""
    mesh.validate()
    quality = check_quality(mesh.vertices, mesh.tets, min_quality)
    blocks = element_stiffness_blocks(mesh, material)
    if fixed is None:
        fixed = np.zeros(mesh.n_vertices, dtype=bool)
    fixed = np.asarray(fixed)
    if fixed.dtype != bool:
        idx = fixed.astype(np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= mesh.n_vertices):
            raise ParameterError(f"fixed vertex index {int(idx.max() if idx.max() >= mesh.n_vertices else idx.min())} "
                                 f"is outside [0, {mesh.n_vertices - 1}]")
        fixed = np.zeros(mesh.n_vertices, dtype=bool)
        fixed[idx] = True
    if fixed.shape != (mesh.n_vertices,):
        raise ParameterError(f"fixed mask has shape {fixed.shape}, expected ({mesh.n_vertices},)")
    g = np.asarray(gravity, dtype=np.float64)
    if g.shape != (3,) or not np.isfinite(g).all():
        raise ParameterError(f"gravity must be 3 finite numbers in m/s^2, got {gravity!r}")
    return FemModel(mesh=mesh, material=material, mass=lumped_mass(mesh, material.rho),
                    K=assemble_stiffness(mesh, material, blocks), clusters=build_clusters(mesh, blocks),
                    fixed=fixed, gravity=g, quality=quality)


@dataclass
class State:
    u: np.ndarray               # (n, 3) displacement from rest [m]
    v: np.ndarray               # (n, 3) velocity [m/s]
    t: float = 0.0

    @classmethod
    def rest(cls, model: FemModel) -> "State":
        n = model.n_vertices
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), 0.0)

    def positions(self, model: FemModel) -> np.ndarray:
        return model.rest + self.u

    def copy(self) -> "State":
        return State(self.u.copy(), self.v.copy(), self.t)


@dataclass
class Attachments:
    """Per-vertex constraint forces f_i = m_i (a_i + kp (u*_i - u_i) + kd (v*_i - v_i)) (eq. 9 + stabilisation).

    Targets are displacements u* at the start of the step, moving with v* during it. ``kp`` [1/s^2]
    and ``kd`` [1/s] are per vertex, so nested levels can carry their own gains.
    """
    index: np.ndarray                   # (k,) int64
    target_u: np.ndarray                # (k, 3)
    target_v: np.ndarray                # (k, 3)
    target_a: np.ndarray                # (k, 3)
    kp: np.ndarray                      # (k,)
    kd: np.ndarray                      # (k,)
    gain_max: tuple[float, float] | None = None    # (max kp, max kd) when the maker knows them (a skeleton
                                                   # driver's constant gains): not scanned again every step

    @classmethod
    def none(cls) -> "Attachments":
        z3 = np.zeros((0, 3))
        return cls(np.zeros(0, np.int64), z3, z3.copy(), z3.copy(), np.zeros(0), np.zeros(0))

    def gain_maxima(self) -> tuple[float, float]:
        """(max kp, max kd), what the explicit step is planned for: ``gain_max`` when given, else scanned; zeros
        without attachments."""
        if self.gain_max is not None:
            return self.gain_max
        if not self.index.size:
            return 0.0, 0.0
        return float(self.kp.max()), float(self.kd.max())

    def at(self, tau: float) -> "Attachments":
        """The targets tau into the step: u* + tau v* + tau^2 a* / 2, v* + tau a*."""
        return Attachments(self.index, self.target_u + tau * self.target_v + 0.5 * tau * tau * self.target_a,
                           self.target_v + tau * self.target_a, self.target_a, self.kp, self.kd, self.gain_max)


@dataclass
class Control:
    """Inputs for one step: external forces (gravity is the model's and is added by the integrator),
    constraint attachments, and prescribed (kinematic) vertices whose motion is set exactly."""
    f_ext: np.ndarray | None = None                     # (n, 3) [N]
    attachments: Attachments = field(default_factory=Attachments.none)
    prescribed_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    prescribed_u: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    prescribed_v: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def at(self, tau: float) -> "Control":
        """The control of a sub-step starting tau into the step: prescribed vertices and attachment targets
        moved on along their velocities (and the attachments' accelerations)."""
        if tau == 0.0:
            return self
        att = self.attachments.at(tau) if self.attachments.index.size else self.attachments
        return Control(f_ext=self.f_ext, attachments=att, prescribed_index=self.prescribed_index,
                       prescribed_u=self.prescribed_u + tau * self.prescribed_v, prescribed_v=self.prescribed_v)
