"""How much a warped body's elements have stiffened by stretching: the factor that shortens the explicit step.

The explicit step's critical step comes from the linear K's largest eigenvalue (fem/stability.py). A
corotated element is as stiff as the linear one near rest, but stretched it stiffens: with S = R^T F (the
stretch of the polar decomposition F = R S, eigenvalues sigma_i) the volumetric term lambda/2 tr(S - I)^2 adds
lambda tr(S - I) d^2 tr(S) / dF^2 to the tangent, whose twist modes are 2 / (sigma_i + sigma_j): an element
stretched tenfold along one axis (tr(S) - 3 = 9) is several times stiffer than the linear K in those modes,
so an explicit step planned from K alone grows without bound (a vertex torn 0.5 m from a 0.1 m bar,
undamped, at safety 0.8; benchmarks/stability_table.py).

``stiffening`` bounds that factor from the deformation gradients alone, without the rotations:
tr(S) = sum sigma_i <= sqrt(3) |F|_F, so g = max(0, sqrt(3) max_e |F_e|_F - 3) >= max_e tr(S_e) - 3, and the
step is planned for lambda_max (1 + g): zero for a body at rest or in rigid motion, about 1.4 on the walking
jelly man (stability margin 2.4 -> 1.5 on `scripts/run`'s summary line), where it still takes one sub-step.
One pass over the vertices (x = X + u), one over the elements (36 multiply-adds each).

``neohookean_stiffening`` is the same factor for the stable Neo-Hookean energy (fem/neohookean.py). Its tangent's
nine eigenvalues, with F's signed singular values s_i and J = s_0 s_1 s_2 (Smith, de Goes and Kim 2019, analytic
eigensystems of isotropic energies), are the six twist and flip values mu +- lambda_s (J - alpha) s_k and the
eigenvalues of the 3 x 3 scaling block A, A_ii = mu + lambda_s (s_j s_k)^2, A_ij = lambda_s s_k (2 J - alpha).
No SVD: from the invariants of C = F^T F, I1 = |F|^2 and I2 = |cof F|^2, every |s_i| <= s with
s^2 = I1 / 3 + 2 / 3 sqrt(I1^2 - 3 I2) (the largest eigenvalue of a symmetric 3 x 3 matrix is at most its mean
plus sqrt 2 times the spread of its eigenvalues), and (s_j s_k)^2 <= p, the same bound for cof C (invariants I2
and I1 J^2). So the largest eigenvalue is at most the larger of mu + lambda_s |J - alpha| s and A's Gershgorin
row bound mu + lambda_s p + 2 lambda_s |2 J - alpha| s; taken with the cruder mu + lambda_s I2 + sqrt(2)
lambda_s |J - alpha| |F|_F, the smaller of the two. At rest and in any rigid motion it is 3 lambda + 2 mu, the
linear material's largest modulus, exactly; elsewhere within 1.6 x of the tangent's largest eigenvalue
(tests/test_neohookean.py), and g = max_e b_e / (3 lambda + 2 mu) - 1. The pass runs in the element warping's
chunks of lanes (element_warping.lane_elements), so it vectorises.

``StretchPlan`` turns g into the factor the step is planned with. Symplectic Euler conserves a shadow
energy only while its step stays the same, and each change of step moves it: on the torn bar (undamped, 3 s,
benchmarks/stability_table.py), a corotated factor that followed g at every step ended at several times the work
put in, and the fewer times the factor fell, the less energy the run gained. So the factor is rounded up to a
quarter octave, rises at once, and falls only after ``hold`` simulated seconds without need: 5 s for the
corotated elements, whose torn bar gains several times as much with a hold of 0.5 s, and 0.5 s for the
Neo-Hookean ones, whose smooth energy gains a tenth more with it. A body placed on its skeleton starts
with the elements between two bones pulled apart for some tens of milliseconds; a 5 s hold would plan its
first 5 s for them.

The Neo-Hookean plan also keeps the step accurate where the energy is far from quadratic. Symplectic Euler
conserves the shadow energy of a quadratic energy exactly; beyond, its error grows with the change of the
stiffness over a step, at second order in the step. Where an element has stiffened past 4x the linear
material (KNEE), the plan takes (1 + g) times min(4, (1 + g) / 4) (ACCURACY): up to half the sub-step,
reached at 16x. The walking jelly man stays under the knee once placed; the bar with a vertex torn 0.5 m away
and held, undamped, gains 0.8-1 % of the work put in with it and 3-4 % without
(benchmarks/stability_table.py).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .assembly import shape_gradients
from .element_rotation import LANES
from .element_warping import _differences, lane_elements, lane_gradient
from .neohookean import parameters
from ..numba_config import HOLDS_GIL

SQRT3 = math.sqrt(3.0)
SQRT2 = math.sqrt(2.0)


@numba.njit(**HOLDS_GIL)
def max_gradient_norm(tets: np.ndarray, gradients: np.ndarray, rest: np.ndarray, u: np.ndarray,
                      x: np.ndarray) -> float:
    """max over elements of |F_e|_F, F_e = sum_c x_c outer g_{e,c}, x = rest + u (written to ``x`` (n, 3) first:
    each vertex once, not once per element corner, and one array to gather from instead of two)."""
    for i in range(rest.shape[0]):
        x[i, 0] = rest[i, 0] + u[i, 0]
        x[i, 1] = rest[i, 1] + u[i, 1]
        x[i, 2] = rest[i, 2] + u[i, 2]
    worst = 0.0
    for e in range(tets.shape[0]):
        f00 = f01 = f02 = f10 = f11 = f12 = f20 = f21 = f22 = 0.0
        for c in range(4):
            v = tets[e, c]
            x0, x1, x2 = x[v, 0], x[v, 1], x[v, 2]
            g0, g1, g2 = gradients[e, c, 0], gradients[e, c, 1], gradients[e, c, 2]
            f00 += x0 * g0
            f01 += x0 * g1
            f02 += x0 * g2
            f10 += x1 * g0
            f11 += x1 * g1
            f12 += x1 * g2
            f20 += x2 * g0
            f21 += x2 * g1
            f22 += x2 * g2
        s = (f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12
             + f20 * f20 + f21 * f21 + f22 * f22)
        if s > worst:
            worst = s
    return math.sqrt(worst)


def stiffening(tets: np.ndarray, gradients: np.ndarray, rest: np.ndarray, u: np.ndarray,
               x: np.ndarray | None = None) -> float:
    """g >= max_e tr(S_e) - 3 (>= 0): plan the explicit step for lambda_max (1 + g) (module docstring). ``x``: an
    (n, 3) workspace (allocated if not given)."""
    if tets.shape[0] == 0:
        return 0.0
    x = np.empty_like(rest) if x is None else x
    return max(0.0, SQRT3 * max_gradient_norm(tets, gradients, rest, u, x) - 3.0)


@numba.njit(**HOLDS_GIL)
def max_neohookean_bound(elems: tuple, u: np.ndarray, D: np.ndarray, lam_s: float, alpha: float,
                         mu: float) -> float:
    """max over elements of the bound b_e on the stable Neo-Hookean tangent (module docstring), in the element
    warping's chunks of LANES elements (elems: element_warping.lane_elements; D: a (9 LANES,) workspace), so
    the lanes vectorise; padding lanes (F = I) give the rest value 3 lambda + 2 mu."""
    corner, grad = elems[0], elems[1]
    b = np.empty(LANES)
    worst = 0.0
    for c in range(corner.shape[0]):
        _differences(corner[c], u, u, D, D, False)
        for l in range(LANES):
            f00, f01, f02, f10, f11, f12, f20, f21, f22 = lane_gradient(D, grad[c], l, 1.0)
            c00, c01, c02 = f11 * f22 - f12 * f21, f12 * f20 - f10 * f22, f10 * f21 - f11 * f20
            c10, c11, c12 = f21 * f02 - f22 * f01, f22 * f00 - f20 * f02, f20 * f01 - f21 * f00
            c20, c21, c22 = f01 * f12 - f02 * f11, f02 * f10 - f00 * f12, f00 * f11 - f01 * f10
            i2 = (c00 * c00 + c01 * c01 + c02 * c02 + c10 * c10 + c11 * c11 + c12 * c12
                  + c20 * c20 + c21 * c21 + c22 * c22)                  # |cof F|^2
            i1 = (f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12
                  + f20 * f20 + f21 * f21 + f22 * f22)                  # |F|^2
            j = f00 * c00 + f01 * c01 + f02 * c02
            nf = math.sqrt(i1)
            s = math.sqrt(i1 / 3.0 + 2.0 / 3.0 * math.sqrt(max(0.0, i1 * i1 - 3.0 * i2)))    # >= |s_i|
            p = min(i2, i2 / 3.0 + 2.0 / 3.0 * math.sqrt(max(0.0, i2 * i2 - 3.0 * i1 * j * j)))   # >= (s_j s_k)^2
            frobenius = mu + lam_s * i2 + SQRT2 * lam_s * abs(j - alpha) * nf
            twist = mu + lam_s * abs(j - alpha) * s
            scaling = mu + lam_s * p + lam_s * abs(2.0 * j - alpha) * min(2.0 * s, SQRT2 * nf)
            b[l] = min(frobenius, max(twist, scaling))
        for l in range(LANES):
            worst = max(worst, b[l])
    return worst


def neohookean_stiffening(elems: tuple, u: np.ndarray, D: np.ndarray | None = None) -> float:
    """g >= the stable Neo-Hookean tangent's largest eigenvalue over the linear material's, minus 1 (>= 0; module
    docstring). elems: element_warping.lane_elements; ``D``: a (9 LANES,) workspace (allocated if not given)."""
    D = np.empty(9 * LANES) if D is None else D
    lam, mu = elems[3]
    b = max_neohookean_bound(elems, u, D, *parameters(lam, mu), mu)
    return max(0.0, b / (3.0 * lam + 2.0 * mu) - 1.0)


class StretchPlan:
    """The stretch factor a warped explicit body plans its sub-steps with (module docstring). The corotated
    bound is taken at most every ``every`` simulated seconds (5 ms: every fifth step of the node's 1 ms, every
    step of a 10 ms one: a bound costs about a quarter of the jelly man's step). The Neo-Hookean bound is taken
    every step: its stiffness grows with the square of the stretch, and the fine hard-case bar torn at h = 1 ms
    diverged in the steps between two bounds 5 ms apart (benchmarks/stability_table.py). ``every`` and ``hold``
    None take the energy's own (EVERY, HOLD; module docstring)."""

    EVERY = {"corotated": 0.005, "neohookean": 0.0}
    HOLD = {"corotated": 5.0, "neohookean": 0.5}
    KNEE, ACCURACY = 4.0, 4.0      # Neo-Hookean: beyond 4x the linear stiffness, up to 4x more (half the sub-step)

    def __init__(self, model, hold: float | None = None, every: float | None = None, energy: str = "corotated"):
        if energy not in self.EVERY:
            raise ValueError(f"energy = {energy!r}: 'corotated' or 'neohookean'")
        self.energy = energy
        every = self.EVERY[energy] if every is None else every
        hold = self.HOLD[energy] if hold is None else hold
        if energy == "neohookean":
            self.elems, self._D = lane_elements(model), np.empty(9 * LANES)
        else:
            self.tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
            self.gradients = np.ascontiguousarray(shape_gradients(model.rest, self.tets)[0])
            self.rest = np.ascontiguousarray(model.rest, dtype=np.float64)
            self._x = np.empty_like(self.rest)
        self.hold, self.every = float(hold), float(every)
        self.current = 1.0
        self._since = 0.0              # simulated seconds since ``current`` was last needed
        self._due = 0.0                # simulated seconds until the next bound

    def factor(self, u: np.ndarray, h: float) -> float:
        """The factor for a step of h from displacement u: >= 1 + g (Neo-Hookean: times the accuracy factor)
        rounded up to a quarter octave."""
        self._due -= h
        if self._due > 0.0:
            self._since += h
            return self.current
        self._due += max(self.every, h)
        if self.energy == "neohookean":
            stiffer = 1.0 + neohookean_stiffening(self.elems, u, self._D)
            stiffer *= min(self.ACCURACY, max(1.0, stiffer / self.KNEE))
        else:
            stiffer = 1.0 + stiffening(self.tets, self.gradients, self.rest, u, self._x)
        need = 2.0 ** (math.ceil(4.0 * math.log2(stiffer)) / 4.0) if stiffer > 1.0 else 1.0
        if need >= self.current:
            self.current, self._since = need, 0.0
        else:
            self._since += h
            if self._since > self.hold:
                self.current, self._since = need, 0.0
        return self.current
