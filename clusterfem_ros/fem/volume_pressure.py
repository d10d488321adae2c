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

Each connected piece of the mesh has its own V0, V and pressure (a loose piece carried by its bone, a hand cut
off by the mesher, keeps its own volume and does not take up what the trunk loses).

Properties (tests/test_volume_pressure.py): the force is minus the gradient of E_p (finite differences);
it is zero at the rest volume and for any rigid motion; it sums to zero force and zero torque (a closed
surface), so it moves no centre of mass and turns no body; V is the tets' total signed volume to round-off.

Cost and step. One pass over the surface vertices' triangles a step, in the skeleton stage of the node's timing
(``scripts/run`` prints it; docs/benchmarks.md, A surface character, has the character with and without). The force is
evaluated once per physics step, from the state the step starts from, and held over its sub-steps as an
external force: its stiffness is k g g^T (g = dV/dx), one mode a piece of rate omega^2 = k sum_i |g_i|^2 / m_i,
which ``VolumePressure.mode_rates`` gives at rest. Held over a step the force is symplectic Euler on that mode,
stable for omega h < 2; ``volume_pressure`` lowers the kappa of a piece whose omega h would exceed
``MAX_OMEGA_H`` (half that) to the largest that keeps it, and the set-up log line says so.

Arrays: triangles (t, 3) int64 outward oriented; positions and forces (n, 3) [m, N].
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .linear.material import ParameterError
from ..numba_config import HOLDS_GIL
from .mesh.tet_mesh import boundary_triangles, tet_pieces

MAX_OMEGA_H = 1.0           # a piece's pressure mode's omega h at most this: held over a step, half the limit of 2


@numba.njit(**HOLDS_GIL)
def _volumes_and_gradient(rest, u, surface, ptr, pairs, vertex_piece, origin, xs, six_v, grad):
    """six_v[q] <- 6 V of piece q and grad[i] <- 6 dV/dx_i for the ``surface`` vertices (the others are never
    written: zero), at x = rest + u measured from ``origin`` (a point near the body: V and dV/dx do not depend on it
    for a closed surface, the round-off does). By vertex, no scatter: surface vertex k's triangles are the pairs
    pairs[ptr[k]:ptr[k + 1]] of its two other corners in the triangle's cyclic order (into ``surface``), and
    6 dV/dx_k = sum of x_j x x_l over them; sum_k x_k . (6 dV/dx_k) is three times 6 V."""
    for k in range(surface.shape[0]):
        i = surface[k]
        xs[k, 0] = rest[i, 0] + u[i, 0] - origin[0]
        xs[k, 1] = rest[i, 1] + u[i, 1] - origin[1]
        xs[k, 2] = rest[i, 2] + u[i, 2] - origin[2]
    six_v[:] = 0.0
    for k in range(surface.shape[0]):
        gx = 0.0
        gy = 0.0
        gz = 0.0
        for e in range(ptr[k], ptr[k + 1]):
            j, m = pairs[e, 0], pairs[e, 1]
            gx += xs[j, 1] * xs[m, 2] - xs[j, 2] * xs[m, 1]
            gy += xs[j, 2] * xs[m, 0] - xs[j, 0] * xs[m, 2]
            gz += xs[j, 0] * xs[m, 1] - xs[j, 1] * xs[m, 0]
        i = surface[k]
        grad[i, 0] = gx
        grad[i, 1] = gy
        grad[i, 2] = gz
        six_v[vertex_piece[k]] += (xs[k, 0] * gx + xs[k, 1] * gy + xs[k, 2] * gz) * (1.0 / 3.0)


@numba.njit(**HOLDS_GIL)
def _pressure_force(rest, u, surface, ptr, pairs, vertex_piece, origin, xs, six_v, grad, stiffness, rest_volumes):
    """grad[i] <- f_i = k (V0 - V) dV/dx_i of vertex i's piece (``_volumes_and_gradient``, then scaled), in one
    call: a step pays one dispatch."""
    _volumes_and_gradient(rest, u, surface, ptr, pairs, vertex_piece, origin, xs, six_v, grad)
    for q in range(six_v.shape[0]):
        six_v[q] = stiffness[q] * (rest_volumes[q] - six_v[q] * (1.0 / 6.0)) * (1.0 / 6.0)
    for k in range(surface.shape[0]):
        i = surface[k]
        f = six_v[vertex_piece[k]]
        grad[i, 0] *= f
        grad[i, 1] *= f
        grad[i, 2] *= f


@dataclass
class VolumePressure:
    """The whole-volume pressure of one body, a pressure per connected piece (see the module docstring);
    ``force`` reuses its own buffer."""
    rest: np.ndarray            # (n, 3) rest positions [m]
    triangles: np.ndarray       # (t, 3) outward boundary triangles
    piece: np.ndarray           # (t,) the connected piece of each triangle, 0 .. pieces - 1
    rest_volumes: np.ndarray    # (pieces,) V0 of each piece [m^3]
    bulk: float                 # K, the elements' bulk modulus [Pa]
    kappa: np.ndarray           # (pieces,) the multiple of K in use on each piece
    asked: float                # the multiple asked for (a piece whose mode is too fast for the step gets less)

    def __post_init__(self):
        self._grad = np.zeros_like(self.rest)
        self._surface = np.unique(self.triangles)
        local = np.searchsorted(self._surface, self.triangles)      # the triangles into the surface vertices
        first = np.zeros(self._surface.size, dtype=np.int64)
        first[local.reshape(-1)] = np.repeat(self.piece, 3)
        self._vertex_piece = first                                  # the piece of each surface vertex
        centre = local.reshape(-1)                                  # each corner, with the two after it in turn
        others = np.stack([local[:, [1, 2, 0]].reshape(-1), local[:, [2, 0, 1]].reshape(-1)], axis=1)
        order = np.argsort(centre, kind="stable")
        self._pairs = np.ascontiguousarray(others[order])
        self._ptr = np.concatenate([[0], np.cumsum(np.bincount(centre, minlength=self._surface.size))])
        self._xs = np.zeros((self._surface.size, 3))
        self._six_v = np.zeros(self.rest_volumes.size)
        self.set_kappa(self.kappa)
        self._origin = self.rest.mean(axis=0)

    @property
    def rest_volume(self) -> float:
        return float(self.rest_volumes.sum())

    @property
    def stiffness(self) -> np.ndarray:
        """k of each piece = kappa K / V0 [Pa / m^3]."""
        return self._stiffness

    def set_kappa(self, kappa: np.ndarray) -> None:
        """Use these multiples of K, one a piece."""
        self.kappa = np.asarray(kappa, dtype=np.float64).copy()
        self._stiffness = self.kappa * self.bulk / self.rest_volumes

    def volumes(self, u: np.ndarray) -> np.ndarray:
        """V of each piece at displacement u, (pieces,) [m^3]; leaves 6 dV/dx in the buffer."""
        _volumes_and_gradient(self.rest, u, self._surface, self._ptr, self._pairs, self._vertex_piece, self._origin,
                              self._xs, self._six_v, self._grad)
        return self._six_v / 6.0

    def volume(self, u: np.ndarray) -> float:
        """V enclosed by the boundary at displacement u [m^3]."""
        return float(self.volumes(u).sum())

    def force(self, u: np.ndarray) -> np.ndarray:
        """f = k (V0 - V) dV/dx of each piece at displacement u, (n, 3) [N]: a view of the object's buffer, valid
        until the next call."""
        _pressure_force(self.rest, u, self._surface, self._ptr, self._pairs, self._vertex_piece, self._origin,
                        self._xs, self._six_v, self._grad, self._stiffness, self.rest_volumes)
        return self._grad

    def energy(self, u: np.ndarray) -> float:
        """E_p = sum over pieces of k / 2 (V - V0)^2 [J]."""
        d = self.volumes(u) - self.rest_volumes
        return float(0.5 * np.sum(self.stiffness * d * d))

    def mode_rates(self, mass: np.ndarray) -> np.ndarray:
        """omega^2 = k sum_i |dV/dx_i|^2 / m_i of each piece at rest, (pieces,) [1/s^2]: its one mode."""
        self.volumes(np.zeros_like(self.rest))
        g2 = np.einsum("ij,ij->i", self._grad[self._surface], self._grad[self._surface]) / 36.0
        by_piece = np.bincount(self._vertex_piece, g2 / mass[self._surface], minlength=self.rest_volumes.size)
        return self.stiffness * by_piece

    def mode_rate(self, mass: np.ndarray) -> float:
        """The fastest piece's omega^2 [1/s^2]."""
        return float(self.mode_rates(mass).max())

    def summary(self, h: float, mass: np.ndarray) -> str:
        w = np.sqrt(self.mode_rates(mass))
        low = self.kappa < self.asked
        lowered = ""
        if low.any():
            share = self.rest_volumes[low].sum() / self.rest_volume
            lowered = (f"; lowered on {int(low.sum())} of {low.size} pieces ({share:.1%} of the volume, kappa down "
                       f"to {self.kappa.min():.3g}) so that each mode's omega h stays at {MAX_OMEGA_H:g} for the "
                       f"{h:g} s step (light surface vertices)")
        return (f"volume pressure: kappa {self.asked:g} on {low.size} piece{'s' if low.size > 1 else ''} "
                f"(K = {self.bulk:.4g} Pa, V0 = {self.rest_volume:.4g} m^3, {self.triangles.shape[0]} boundary "
                f"triangles), the fastest mode's omega h = {w.max() * h:.3f}{lowered}")


def volume_pressure(model, kappa: float, h: float, triangles: np.ndarray | None = None) -> VolumePressure | None:
    """The ``VolumePressure`` of ``model`` (fem.model.FemModel) for ``kappa`` >= 0 (None for 0: nothing built) and the
    step h: one pressure per connected piece of the mesh (a piece's volume is its own: a hand's loose piece does
    not take up what the trunk loses). A piece whose mode's omega h would exceed MAX_OMEGA_H gets the largest kappa
    that keeps it (a small piece with light surface vertices has a fast mode); ``summary`` says so. ``triangles``:
    the mesh's outward boundary triangles where the caller has them (tet_mesh.boundary_triangles otherwise)."""
    kappa = float(kappa)
    if not np.isfinite(kappa) or kappa < 0.0:
        raise ParameterError(f"material.volume_stiffness = {kappa!r}: give a multiple >= 0 of the elements' bulk "
                             "modulus (0 = off)")
    if not (np.isfinite(h) and h > 0.0):
        raise ParameterError(f"physics.step = {h!r}: give a positive step in seconds")
    if kappa == 0.0:
        return None
    lam, mu = model.material.lame
    triangles = boundary_triangles(model.mesh) if triangles is None else triangles
    _, labels = tet_pieces(model.n_vertices, model.mesh.tets)
    ids, piece = np.unique(labels[triangles[:, 0]], return_inverse=True)       # every piece has a boundary
    piece = piece.reshape(-1).astype(np.int64)
    tet_piece = np.searchsorted(ids, labels[model.mesh.tets[:, 0]])
    rest_volumes = np.bincount(tet_piece, model.mesh.volumes(), minlength=ids.size)
    rest = np.ascontiguousarray(model.rest, dtype=np.float64)
    p = VolumePressure(rest, triangles, piece, rest_volumes, lam + 2.0 * mu / 3.0,
                       np.full(rest_volumes.size, kappa), kappa)
    w2 = p.mode_rates(model.mass)
    fast = w2 * h * h > MAX_OMEGA_H ** 2
    lowered = p.kappa.copy()
    lowered[fast] = kappa * MAX_OMEGA_H ** 2 / (w2[fast] * h * h)
    p.set_kappa(lowered)
    return p
