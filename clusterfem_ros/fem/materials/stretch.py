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

For the stable Neo-Hookean energy (fem/materials/neohookean.py) element e has stiffened by
s_e = max(1, b_e / (3 lambda + 2 mu)), b_e the bound on its stress tangent that the Neo-Hookean force pass leaves
beside its forces (fem/materials/neohookean.py, The step plan's bound): exact at rest and in rigid motion, within
1.6x of the tangent elsewhere. The clustered step computes its first force before it plans its sub-steps, so the
plan is for the state the step starts from at no extra pass (fem/integrators/clustered_explicit.py).

The plan element by element. The body's largest eigenvalue sits on a few elements (a character's: its
mass-scaled fingers and toes, fem/mass_scaling.py), and an element far from it may stiffen several times before
the body's step changes. Element e weighs r_e = lambda_max(K_e, M_e) / lambda_max (``element_weights``, once): its
own 12 x 12 linear stiffness over its four vertices' whole (scaled) masses, at most 1 (the body's Rayleigh
quotient on one element's vertices), 1 where the element sets the body's step, a few hundredths for a large,
heavy one. The plan takes max(1, max_e r_e s_e a_e), a_e the accuracy factor below (``element_need``, one pass
over the bounds): never more than the body-wide max_e s_e a_e, the same where the stiffest element stiffens. It
is not a proven bound (an element's modes couple with its neighbours', and s_e scales the rest element exactly
only in its volumetric mode), so it is checked against the true tangent's largest eigenvalue (finite
differences): on a graded bar stretched, crushed, folded or moved at random it stays above 0.64 of it, the
stability limit of a step at safety 0.8 (tests/test_stretch.py); on the character's walk its need is 0.70-1.89
of it and the true eigenvalue at most 1.14 of the factor the step takes (``python -m benchmarks.stretch_plan_check``:
1.00-1.01 lambda_max on the walk, where the plan takes 1; up to 30x in the steps after placement, where the
crushed fingers plan 22-45x). The body-wide plan takes those fingers,
stretched to twice their rest stiffness all along the walk with a frequency of their own half the body's, for
the whole body: 1.8-2.8x, 2-3 sub-steps where one is stable.

``StretchPlan`` turns the stiffening into the factor the step is planned with. Symplectic Euler conserves a shadow
energy only while its step stays the same, and each change of step moves it: on the torn bar (undamped, 3 s,
benchmarks/stability_table.py), a corotated factor that followed g at every step ended at several times the work
put in, and the fewer times the factor fell, the less energy the run gained. So the factor is rounded up to a
quarter octave, rises at once, and falls only after ``hold`` simulated seconds without need: 5 s for the
corotated elements, whose torn bar gains several times as much with a hold of 0.5 s, and 0.5 s for the
Neo-Hookean ones of an undamped body, whose smooth energy gains a tenth more with it. A damped Neo-Hookean body
holds 20 ms (DAMPED_HOLD): its damping dissipates what a change of step leaves, and a body placed on its skeleton
starts with the elements between two bones crushed or pulled apart for about ten steps (the character's
fingers), whose sub-steps held for 0.5 s put the character's node more than physics.max_catchup_steps behind its
inputs, where it is placed again, and again.

The Neo-Hookean plan of an undamped body also keeps the step accurate where the energy is far from quadratic.
Symplectic Euler conserves the shadow energy of a quadratic energy exactly; beyond, its error grows with the
change of the stiffness over a step, at second order in the step. Where an element has stiffened past 4x the
linear material (KNEE), its need is s_e times min(4, s_e / 4) (ACCURACY): up to half the sub-step, reached at 16x.
The bar with a vertex torn 0.5 m away and held, undamped, gains 0.8-1 % of the work put in with it and 3-4 %
without (benchmarks/stability_table.py). While an element of an undamped body is inverted (the force pass says so
by the sign of its bound) its need takes INVERTED = 16 in place of the accuracy factor, a quarter of the sub-step:
the bar released with its outer half folded through itself, undamped, gains 6 % over 3 s with the stiffness
alone, 1.5 % with 4 and 0.3 % with 16; the fine bar diverges in its first step with the stiffness alone and gains
0.7 % / 0.04 % with 4 / 16 ("inverted start" of ``python -m benchmarks.stability_table --scales 1 2 --steps 300``,
with INVERTED set to each and every element weighed 1; element by element the coarse bar gains 0.7 % over its
first second and the torn one 0.8 %, both within the table's 1 %: ``--scales 1 --steps 100``;
tests/test_hard_cases.py checks the coarse bar). A damped body takes the stiffening
alone: it dissipates the drift, and the shorter sub-steps would take real motion that inverts or crushes elements
(a robot's sweep, a capture, a placement) past physics.max_substeps. The factor is held with the rest of the
plan: taken in the steps with an inverted element alone, it left the jelly man at 1.128 sub-steps a step, but
the torn bar's elements invert and recover during the run, and each switch of the sub-step moved its shadow
energy (0.3 % gained between 0.1 and 0.4 s, where the held plan gains nothing; tests/test_neohookean.py).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from ..linear.assembly import element_stiffness_blocks, shape_gradients
from .element_rotation import LANES
from ...numba_config import HOLDS_GIL

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


def element_weights(model, lam_max: float, block: int = 4096) -> np.ndarray:
    """r_e = min(1, lambda_max(K_e, M_e) / lam_max), (m,): element e's own largest eigenvalue at rest (its linear
    12 x 12 stiffness over its four vertices' whole, scaled, masses) against the body's. r_e <= 1 (the Rayleigh
    quotient of the body restricted to one element's vertices), 1 for the elements that set the body's step, small
    for large heavy ones (module docstring, The plan element by element). In blocks of ``block`` elements."""
    tets = np.asarray(model.mesh.tets)
    if not (lam_max > 0 and math.isfinite(lam_max)):
        raise ValueError(f"lam_max = {lam_max!r} 1/s^2: the body's largest eigenvalue must be positive and finite")
    K = element_stiffness_blocks(model.mesh, model.material)                  # (m, 4, 4, 3, 3)
    s = 1.0 / np.sqrt(np.repeat(np.asarray(model.mass, dtype=np.float64)[tets], 3, axis=1))    # (m, 12)
    out = np.empty(tets.shape[0])
    for a in range(0, tets.shape[0], block):
        Ke = np.transpose(K[a:a + block], (0, 1, 3, 2, 4)).reshape(-1, 12, 12)
        sb = s[a:a + block]
        out[a:a + block] = np.linalg.eigvalsh(Ke * sb[:, :, None] * sb[:, None, :])[:, -1]
    return np.minimum(1.0, out / lam_max)


def weights_by_lane(weights: np.ndarray) -> np.ndarray:
    """(chunks, LANES) of the element weights in the force pass's lane order (ElementFrames: element e in chunk e //
    LANES, lane e % LANES), the padding lanes 0."""
    chunks = -(-weights.size // LANES)
    lanes = np.zeros(chunks * LANES)
    lanes[:weights.size] = weights
    return lanes.reshape(chunks, LANES)


@numba.njit(**HOLDS_GIL)
def element_need(kept: np.ndarray, weights: np.ndarray, rest_modulus: float, knee: float, accuracy: float,
                 inverted_factor: float, scratch: np.ndarray) -> float:
    """max over elements of r_e s_e a_e: s_e = max(1, |b_e| / rest_modulus) from the tangent bounds the force pass
    left in kept[:, :LANES] (negative: inverted), a_e the accuracy factor min(accuracy, max(1, s_e / knee)), or
    ``inverted_factor`` for an inverted element when it is larger than 0 (module docstring). A chunk's LANES values
    go through ``scratch`` (LANES,): written without a running maximum, the lane loop runs on vectors (a third of
    the time of a loop that keeps one)."""
    inverted = inverted_factor > 0.0
    worst = 0.0
    for c in range(weights.shape[0]):
        w, k = weights[c], kept[c]
        for l in range(LANES):
            b = k[l]
            s = abs(b) / rest_modulus
            s = s if s > 1.0 else 1.0
            a = s / knee
            a = a if a > 1.0 else 1.0
            a = a if a < accuracy else accuracy
            scratch[l] = w[l] * s * (inverted_factor if (b < 0.0) & inverted else a)
        for l in range(LANES):
            worst = max(worst, scratch[l])
    return worst


_ONE_ELEMENT = np.eye(1, LANES)      # the weights of a body of one element: 1 in lane 0, padding 0


class StretchPlan:
    """The stretch factor a warped explicit body plans its sub-steps with (module docstring). The corotated
    bound (``factor``) is taken at most every ``every`` simulated seconds (5 ms: every fifth step of the node's
    1 ms, every step of a 10 ms one: a bound costs about a quarter of the jelly man's step). The Neo-Hookean one
    (``element_factor``; ``neohookean_factor`` for one element of weight 1) comes with every step's first force:
    its stiffness grows with the square of the stretch, and the fine hard-case bar torn at h = 1 ms diverged in the
    steps between two bounds 5 ms apart (benchmarks/stability_table.py). ``hold`` None takes the energy's own
    (HOLD, or DAMPED_HOLD for a body with damping; module docstring). ``lam_max``: the body's largest eigenvalue,
    which the Neo-Hookean plan weighs each element against (``element_weights``); None weighs every element 1."""

    EVERY = 0.005
    HOLD = {"corotated": 5.0, "neohookean": 0.5}
    DAMPED_HOLD = {"corotated": 5.0, "neohookean": 0.02}   # a damped body dissipates what a change of step leaves
    KNEE, ACCURACY = 4.0, 4.0      # Neo-Hookean: beyond 4x the linear stiffness, up to 4x more (half the sub-step)
    INVERTED = 16.0                # Neo-Hookean: 16x while an element is inverted (a quarter of the sub-step)

    def __init__(self, model, hold: float | None = None, every: float = EVERY, energy: str = "corotated",
                 lam_max: float | None = None):
        if energy not in self.HOLD:
            raise ValueError(f"energy = {energy!r}: 'corotated' or 'neohookean'")
        self.energy = energy
        damped = model.material.xi > 0.0 or model.material.zeta > 0.0
        hold = (self.DAMPED_HOLD if damped else self.HOLD)[energy] if hold is None else hold
        if energy == "neohookean":
            lam, mu = model.material.lame
            self.rest_modulus = 3.0 * lam + 2.0 * mu      # the tangent's largest eigenvalue at rest
            # each element's weight r_e by lane (``element_factor``); without lam_max every element weighs 1
            weights = np.ones(model.mesh.n_tets) if lam_max is None else element_weights(model, lam_max)
            self.weights = weights_by_lane(weights)
        else:
            self.tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
            self.gradients = np.ascontiguousarray(shape_gradients(model.rest, self.tets)[0])
            self.rest = np.ascontiguousarray(model.rest, dtype=np.float64)
            self._x = np.empty_like(self.rest)
        self.hold, self.every = float(hold), float(every)
        self._lanes = np.empty(LANES)  # element_need's workspace
        self.current = 1.0
        self._since = 0.0              # simulated seconds since ``current`` was last needed
        self._due = 0.0                # simulated seconds until the next corotated bound

    def factor(self, u: np.ndarray, h: float) -> float:
        """The corotated factor for a step of h from displacement u: >= 1 + g rounded up to a quarter octave."""
        if self.energy != "corotated":
            raise ValueError("factor(u, h) plans the corotated energy; the Neo-Hookean one: neohookean_factor")
        self._due -= h
        if self._due > 0.0:
            self._since += h
            return self.current
        self._due += max(self.every, h)
        return self._settle(1.0 + stiffening(self.tets, self.gradients, self.rest, u, self._x), h)

    def neohookean_factor(self, bound: float, h: float, inverted: bool = False) -> float:
        """The Neo-Hookean factor of an undamped body for a step of h whose elements' largest tangent bound is
        ``bound`` (fem/materials/neohookean.py; ``inverted``: that element's): ``element_factor``'s rule on one
        element of weight 1, >= 1 + g times the accuracy factor, rounded up to a quarter octave."""
        kept = np.zeros((1, LANES))
        kept[0, 0] = -bound if inverted else bound
        need = element_need(kept, _ONE_ELEMENT, self.rest_modulus, self.KNEE, self.ACCURACY, self.INVERTED, self._lanes)
        return self._settle(max(1.0, need), h)

    def element_factor(self, kept: np.ndarray, h: float, undamped: bool = False) -> float:
        """The Neo-Hookean factor element by element: >= max_e r_e s_e a_e (``element_need``; the tangent bounds by
        lane in kept[:, :LANES], as the force pass leaves them in ElementFrames.rot_lanes), rounded up to a quarter
        octave; ``undamped`` takes the accuracy factors (ACCURACY past KNEE, INVERTED for an inverted element), a damped
        body the stiffening alone."""
        if self.energy != "neohookean":
            raise ValueError("element_factor plans the Neo-Hookean energy; the corotated one: factor(u, h)")
        # the accuracy and inverted factors keep an undamped body's shadow energy; a damped one dissipates the drift,
        # and their shorter sub-steps would take a placement's crushed elements past physics.max_substeps
        need = element_need(kept, self.weights, self.rest_modulus, self.KNEE, self.ACCURACY if undamped else 1.0,
                            self.INVERTED if undamped else 0.0, self._lanes)
        return self._settle(max(1.0, need), h)

    def _settle(self, stiffer: float, h: float) -> float:
        """The factor for ``stiffer`` after rounding: it rises at once and falls after ``hold`` without need."""
        need = 2.0 ** (math.ceil(4.0 * math.log2(stiffer)) / 4.0) if stiffer > 1.0 else 1.0
        if need >= self.current:
            self.current, self._since = need, 0.0
        else:
            self._since += h
            if self._since > self.hold:
                self.current, self._since = need, 0.0
        return self.current
