"""One pressure for the whole body: the flesh's near-incompressibility, kept for its total volume only.

Flesh is nearly incompressible (its bulk modulus is orders of magnitude above its shear modulus), but an explicit
step planned for a Poisson ratio near 0.5 is many times shorter. The elements keep the scene's Poisson ratio,
and this adds the energy of the body's total volume V alone:

    E_p = k / 2 (V - V0)^2,   k = kappa K / V0,   K = lambda + 2 mu / 3 (the elements' bulk modulus),
    f_i = -dE_p/dx_i = p dV/dx_i,   p = k (V0 - V),

with V the volume the boundary triangles enclose (outward oriented: V = sum_t a . (b x c) / 6, equal to the
sum of the tets' signed volumes) and dV/dx_a = sum over a's triangles of (b x c) / 6 for each corner a in cyclic
order. So the body behaves as if its bulk modulus were (1 + kappa) K for a change of its whole volume, and as
the elements say for any other deformation. Where a joint folds hard the bones' targets crush the elements
across it (body/crush_release.py); the pressure pushes the flesh out where it is free to go, as flesh bulges.

Properties (tests/test_volume_pressure.py): the force is minus the gradient of E_p (finite differences);
it is zero at the rest volume and for any rigid motion; it sums to zero force and zero torque (a closed
surface), so it moves no centre of mass and turns no body; V is the tets' total signed volume to round-off.

Cost and step. A pass over the boundary triangles (about 3000 on a 5000-tet body: microseconds). The force is
evaluated once per physics step, from the state the step starts from, and held over its sub-steps as an
external force: its stiffness is k g g^T (g = dV/dx), one mode of rate omega^2 = k sum_i |g_i|^2 / m_i, which
``VolumePressure.mode_rate`` gives at rest. Held over a step the force is symplectic Euler on that mode,
stable for omega h < 2; ``volume_pressure`` lowers a kappa whose omega h would exceed ``MAX_OMEGA_H`` (half
that) to the largest that keeps it, and the set-up log line says so.

Arrays: triangles (t, 3) int64 outward oriented; positions and forces (n, 3) [m, N].
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .linear.material import ParameterError
from ..numba_config import HOLDS_GIL
from .mesh.tet_mesh import boundary_triangles

MAX_OMEGA_H = 1.0           # the pressure mode's omega h at most this: held over a step, half the limit of 2


@numba.njit(**HOLDS_GIL)
def _volume_and_gradient(rest, u, triangles, surface, origin, grad):
    """V enclosed by ``triangles`` at x = rest + u, and grad[i] <- dV/dx_i for the ``surface`` vertices (the
    others are never written: zero), measured from ``origin`` (a point near the body: V and dV/dx do not depend on
    it for a closed surface, the round-off does)."""
    for k in range(surface.shape[0]):
        i = surface[k]
        grad[i, 0] = 0.0
        grad[i, 1] = 0.0
        grad[i, 2] = 0.0
    six_v = 0.0
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ax = rest[a, 0] + u[a, 0] - origin[0]
        ay = rest[a, 1] + u[a, 1] - origin[1]
        az = rest[a, 2] + u[a, 2] - origin[2]
        bx = rest[b, 0] + u[b, 0] - origin[0]
        by = rest[b, 1] + u[b, 1] - origin[1]
        bz = rest[b, 2] + u[b, 2] - origin[2]
        cx = rest[c, 0] + u[c, 0] - origin[0]
        cy = rest[c, 1] + u[c, 1] - origin[1]
        cz = rest[c, 2] + u[c, 2] - origin[2]
        bcx, bcy, bcz = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx      # b x c
        cax, cay, caz = cy * az - cz * ay, cz * ax - cx * az, cx * ay - cy * ax      # c x a
        abx, aby, abz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx      # a x b
        six_v += ax * bcx + ay * bcy + az * bcz
        grad[a, 0] += bcx
        grad[a, 1] += bcy
        grad[a, 2] += bcz
        grad[b, 0] += cax
        grad[b, 1] += cay
        grad[b, 2] += caz
        grad[c, 0] += abx
        grad[c, 1] += aby
        grad[c, 2] += abz
    for k in range(surface.shape[0]):
        i = surface[k]
        grad[i, 0] *= 1.0 / 6.0
        grad[i, 1] *= 1.0 / 6.0
        grad[i, 2] *= 1.0 / 6.0
    return six_v / 6.0


@numba.njit(**HOLDS_GIL)
def _scale_rows(grad, surface, factor):
    """grad[i] *= factor for the ``surface`` vertices."""
    for k in range(surface.shape[0]):
        i = surface[k]
        grad[i, 0] *= factor
        grad[i, 1] *= factor
        grad[i, 2] *= factor


@dataclass
class VolumePressure:
    """The whole-volume pressure of one body (see the module docstring); ``force`` reuses its own buffer."""
    rest: np.ndarray            # (n, 3) rest positions [m]
    triangles: np.ndarray       # (t, 3) outward boundary triangles
    rest_volume: float          # V0 [m^3]
    stiffness: float            # k = kappa K / V0 [Pa / m^3]
    kappa: float                # the multiple of the bulk modulus in use
    asked: float | None = None  # the multiple asked for, where it was lowered for the step

    def __post_init__(self):
        self._grad = np.zeros_like(self.rest)
        self._surface = np.unique(self.triangles)
        self._origin = self.rest.mean(axis=0)

    def volume(self, u: np.ndarray) -> float:
        """V enclosed by the boundary at displacement u [m^3]."""
        return _volume_and_gradient(self.rest, u, self.triangles, self._surface, self._origin, self._grad)

    def force(self, u: np.ndarray) -> np.ndarray:
        """f = k (V0 - V) dV/dx at displacement u, (n, 3) [N]: a view of the object's buffer, valid until the next
        call."""
        v = _volume_and_gradient(self.rest, u, self.triangles, self._surface, self._origin, self._grad)
        _scale_rows(self._grad, self._surface, self.stiffness * (self.rest_volume - v))
        return self._grad

    def energy(self, u: np.ndarray) -> float:
        """E_p = k / 2 (V - V0)^2 [J]."""
        d = self.volume(u) - self.rest_volume
        return 0.5 * self.stiffness * d * d

    def mode_rate(self, mass: np.ndarray) -> float:
        """omega^2 = k sum_i |dV/dx_i|^2 / m_i at rest [1/s^2]: the pressure's one mode (module docstring)."""
        self.volume(np.zeros_like(self.rest))
        g2 = np.einsum("ij,ij->i", self._grad, self._grad)
        return float(self.stiffness * np.sum(g2 / mass))

    def summary(self, h: float, mass: np.ndarray) -> str:
        w = np.sqrt(self.mode_rate(mass))
        lowered = (f", lowered from {self.asked:g} so that the mode's omega h stays at {MAX_OMEGA_H:g} for the "
                   f"{h:g} s step (light surface vertices)" if self.asked is not None else "")
        return (f"volume pressure: kappa {self.kappa:.3g}{lowered} (k = {self.stiffness:.3g} Pa/m^3 on V0 = "
                f"{self.rest_volume:.4g} m^3, {self.triangles.shape[0]} boundary triangles), its mode's omega h = "
                f"{w * h:.3f}")


def volume_pressure(model, kappa: float, h: float) -> VolumePressure | None:
    """The ``VolumePressure`` of ``model`` (fem.model.FemModel) for ``kappa`` >= 0 (None for 0: nothing built) and the
    step h. A kappa whose mode's omega h would exceed MAX_OMEGA_H is lowered to the largest that keeps it (a mesh
    with light surface vertices has a faster mode); ``summary`` says so."""
    kappa = float(kappa)
    if not np.isfinite(kappa) or kappa < 0.0:
        raise ParameterError(f"material.volume_stiffness = {kappa!r}: give a multiple >= 0 of the elements' bulk "
                             "modulus (0 = off)")
    if not (np.isfinite(h) and h > 0.0):
        raise ParameterError(f"physics.step = {h!r}: give a positive step in seconds")
    if kappa == 0.0:
        return None
    lam, mu = model.material.lame
    bulk = lam + 2.0 * mu / 3.0
    triangles = boundary_triangles(model.mesh)
    rest = np.ascontiguousarray(model.rest, dtype=np.float64)
    v0 = float(model.mesh.volumes().sum())
    p = VolumePressure(rest, triangles, v0, kappa * bulk / v0, kappa)
    w2 = p.mode_rate(model.mass)
    if w2 * h * h > MAX_OMEGA_H ** 2:
        p.kappa = kappa * MAX_OMEGA_H ** 2 / (w2 * h * h)
        p.stiffness = p.kappa * bulk / v0
        p.asked = kappa
    return p
