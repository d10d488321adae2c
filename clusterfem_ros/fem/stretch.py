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

``StretchPlan`` turns g into the factor the step is planned with. Symplectic Euler conserves a shadow
energy only while its step stays the same, and each change of step moves it: on the torn bar (undamped, 3 s,
benchmarks/stability_table.py), a factor that follows g at every step ended at several times the work put in,
and the fewer times the factor fell, the less energy the run gained. So the factor
is rounded up to a quarter octave, rises at once, and falls only after ``hold`` simulated seconds (5 s)
without need: a body stretched by a glitch steps finer for those seconds, then returns to its usual step.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .assembly import shape_gradients
from ..numba_config import HOLDS_GIL

SQRT3 = math.sqrt(3.0)


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


class StretchPlan:
    """The stretch factor a warped explicit body plans its sub-steps with (module docstring). The bound is
    taken at most every ``every`` simulated seconds (5 ms: every fifth step of the node's 1 ms, every step of
    a 10 ms one: a bound costs about a quarter of the jelly man's step)."""

    def __init__(self, model, hold: float = 5.0, every: float = 0.005):
        self.tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
        self.gradients = np.ascontiguousarray(shape_gradients(model.rest, self.tets)[0])
        self.rest = np.ascontiguousarray(model.rest, dtype=np.float64)
        self._x = np.empty_like(self.rest)
        self.hold, self.every = float(hold), float(every)
        self.current = 1.0
        self._since = 0.0              # simulated seconds since ``current`` was last needed
        self._due = 0.0                # simulated seconds until the next bound

    def factor(self, u: np.ndarray, h: float) -> float:
        """The factor for a step of h from displacement u: >= 1 + g rounded up to a quarter octave."""
        self._due -= h
        if self._due > 0.0:
            self._since += h
            return self.current
        self._due += max(self.every, h)
        g = stiffening(self.tets, self.gradients, self.rest, u, self._x)
        need = 2.0 ** (math.ceil(4.0 * math.log2(1.0 + g)) / 4.0) if g > 0.0 else 1.0
        if need >= self.current:
            self.current, self._since = need, 0.0
        else:
            self._since += h
            if self._since > self.hold:
                self.current, self._since = need, 0.0
        return self.current
