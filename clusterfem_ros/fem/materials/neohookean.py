"""Stable Neo-Hookean elements, compiled: a rotation-free elastic force, smooth through inversion.

``warping_model = "neohookean"`` replaces the corotated element energy by the stable Neo-Hookean energy in
its simplest form (Smith, de Goes and Kim 2018, without the logarithmic term):

    Psi(F) = mu / 2 (|F|^2 - 3) + lambda_s / 2 (J - alpha)^2 - lambda_s / 2 (1 - alpha)^2,
    lambda_s = lambda + mu,   alpha = 1 + mu / lambda_s,   J = det F,

    P = dPsi/dF = mu F + lambda_s (J - alpha) cof F,   f_c = -V_e P g_c,

with cof F = dJ/dF (rows f1 x f2, f2 x f0, f0 x f1 of F's rows f0, f1, f2). The constant makes Psi(I) = 0.
At F = I + H the stress is mu (H + H^T) + (lambda_s - mu) tr(H) I + O(H^2): the linear material with
Lame parameters (lambda, mu), so the small-strain limit is the linear FEM's (tests/test_neohookean.py).

Why it is here. Psi is a polynomial in F: smooth everywhere, inverted elements included, and rotation
invariant without a rotation. The corotated energy (fem/materials/element_warping.py) depends on F through the
rotation R = polar(F), which is not a smooth function of F where an inverted element's two smallest
singular values meet; symplectic Euler keeps a shadow energy bounded only for a smooth energy, and the
corotated bar with a vertex torn away and held, undamped, gains energy for as long as its elements stay
inverted. This energy has no such place: after the tear its shadow energy stays flat
(benchmarks/stability_table.py). The price is stiffness at large stretch: cof F grows with the product of
two singular values, so an element stretched tenfold is about a hundred times stiffer than at rest, and the step
plan must follow (below, and fem/materials/stretch.py). No polar iteration: the pass costs less than the corotated one
(benchmarks/core_benchmark.py --warping-only).

Damping. The stiffness damping is a viscous stress on the rate of the right Cauchy-Green tensor:
P_d = F S_d, S_d = lambda tr(E') I + 2 mu E', E' = sym(F^T zeta dF/dt). Its power S_d : E' / zeta >= 0, so it
only removes energy; it is zero for any rigid velocity (dF/dt = W F, W skew, gives E' = 0); at F = I it is
zeta K v, the linear model's. With w = x0 + u + zeta v (the kernels' input) zeta dF/dt = G - F, G the
gradient of w. The mass damping -xi M v is added by the caller, as for the other models.

The step plan's bound. The explicit step is planned for the largest eigenvalue of the tangent dP/dF over the
elements (fem/materials/stretch.py). With F's signed singular values s_i and J = s_0 s_1 s_2, the tangent's nine
eigenvalues (Smith, de Goes and Kim 2019, analytic eigensystems of isotropic energies) are the six twist and
flip values mu +- lambda_s (J - alpha) s_k and the eigenvalues of the 3 x 3 scaling block A,
A_ii = mu + lambda_s (s_j s_k)^2, A_ij = lambda_s s_k (2 J - alpha). No SVD: from the invariants of C = F^T F,
I1 = |F|^2 and I2 = |cof F|^2, every |s_i| <= s with s^2 = I1 / 3 + 2 / 3 sqrt(I1^2 - 3 I2) (the largest
eigenvalue of a symmetric 3 x 3 matrix is at most its mean plus sqrt 2 times the spread of its eigenvalues),
and (s_j s_k)^2 <= p, the same bound for cof C (invariants I2 and I1 J^2). So the largest eigenvalue is at
most the larger of mu + lambda_s |J - alpha| s and A's Gershgorin row bound
mu + lambda_s p + 2 lambda_s |2 J - alpha| s; taken with the cruder
mu + lambda_s I2 + sqrt(2) lambda_s |J - alpha| |F|_F, the smaller of the two. At rest and in any rigid
motion it is 3 lambda + 2 mu, the linear material's largest modulus, exactly; elsewhere within 1.6 x of the
tangent's largest eigenvalue (tests/test_neohookean.py). The force pass computes it beside each element's force
from the same F (``ElementFrames.bounds``; four square roots an element, about a seventh of the pass on the
jelly man), so the step gets it with its first force; ``tangent_bounds`` runs the pass without the forces. A
step's later sub-steps run the pass without the bound (``neohookean_e_unplanned_*``, the lane loop built with
``PLANS`` false: the same forces bit for bit): the plan reads only the bounds of the state the step starts
from, which the bounds then still hold. The bound is kept with the sign of J: negative for an inverted (or
flat) element, which the step plan takes a shorter step for (fem/materials/stretch.py, ``element_need``).

The compiled pass has the element warping's layout (fem/materials/element_warping.py: ``ElementFrames``, chunks of
LANES elements by lane, element corner forces gathered per vertex in element order, so serial and threaded
builds give the same bits) without the rotations. The serial build makes no separate gather: it adds each
chunk's corner forces to their vertices' rows as it makes them (``_fused_e``), in the gather's order. Both builds
move the corner rows on vectors (fem/materials/corner_rows.py): a vertex row of u or w is one 4-wide load, a
corner force one 4-wide read-modify-write of a padded row (the serial build's sums), four lanes transposed at a
time; the same subtractions and additions as scalar code, so the same bits.
``neohookean_force`` is the checked public entry; ``reference_force`` and ``energy`` (numpy) are the twins the
tests and the stability table use.

Builds: the element warping's pass and force sources (``element_pass_source``, ``element_force_source``) with this
module's ``_neohookean_chunk`` bound as their ``chunk`` (numba_config.compiled); the threaded pass and gather is the
element warping's ``element_e_source``, the serial one ``_fused_e``; each with the lane loop with the bounds and
(for the later sub-steps) without them.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from ..kernels.cluster_force_kernel import finish_parallel, finish_serial, kernel_input_parallel, kernel_input_serial
from .corner_rows import add_corner_rows, corner_row_differences, corner_row_differences_of_two
from .corotational import deformation_gradients
from .element_rotation import LANES
from .element_warping import (INLINED, ElementFrames, element_e_source, element_force_source, element_pass_source,
                              gather_parallel, lane_gradient, run_element_kernel, store_corner_forces)
from .kernel_args import checked_rows, pick_build
from ..model import FemModel
from ...numba_config import PARALLEL, SERIAL, compiled, serial_and_parallel

SQRT2 = math.sqrt(2.0)
THIRD = 1.0 / 3.0
# The lane arithmetic with FMA contraction: a product and the sum it feeds in one rounding, no reassociation, so
# the source's order holds and the serial and threaded builds give the same bits (tests/test_neohookean.py); the
# pass is shorter for it (benchmarks/core_benchmark.py --warping-only times the step).
CONTRACTED = dict(SERIAL, fastmath={"contract"})


def parameters(lam: float, mu: float) -> tuple[float, float]:
    """(lambda_s, alpha) of the energy for the linear material's Lame parameters (module docstring)."""
    lam_s = lam + mu
    return lam_s, 1.0 + mu / lam_s


def _cofactor(F: np.ndarray) -> np.ndarray:
    """cof F = dJ/dF for a stack (m, 3, 3)."""
    c = np.empty_like(F)
    c[:, 0] = np.cross(F[:, 1], F[:, 2])
    c[:, 1] = np.cross(F[:, 2], F[:, 0])
    c[:, 2] = np.cross(F[:, 0], F[:, 1])
    return c


def _gradients(model: FemModel, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F (m, 3, 3), rest gradients (m, 4, 3), rest volumes (m,)) of displacement u."""
    g, vol = model.rest_gradients                 # made once per model
    return deformation_gradients(g, model.mesh.tets, u), g, vol


def energy(model: FemModel, u: np.ndarray) -> float:
    """sum_e V_e Psi(F_e) (numpy; module docstring)."""
    lam, mu = model.material.lame
    lam_s, alpha = parameters(lam, mu)
    F, _, vol = _gradients(model, np.asarray(u, dtype=np.float64))
    J = np.linalg.det(F)
    psi = 0.5 * mu * (np.einsum("eab,eab->e", F, F) - 3.0) + 0.5 * lam_s * ((J - alpha) ** 2 - (1.0 - alpha) ** 2)
    return float(vol @ psi)


def reference_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """The elastic + damping force of (u, v), (n, 3), including -xi M v: the numpy twin of ``neohookean_force``."""
    u = np.asarray(u, dtype=np.float64)
    v = np.zeros_like(u) if v is None else np.asarray(v, dtype=np.float64)
    m = model.material
    lam, mu = m.lame
    lam_s, alpha = parameters(lam, mu)
    F, g, vol = _gradients(model, u)
    P = mu * F + (lam_s * (np.linalg.det(F) - alpha))[:, None, None] * _cofactor(F)
    if m.zeta:
        Z = deformation_gradients(g, model.mesh.tets, m.zeta * v) - np.eye(3)     # zeta dF/dt
        A = np.einsum("eba,ebc->eac", F, Z)
        E = 0.5 * (A + np.transpose(A, (0, 2, 1)))
        S = 2.0 * mu * E + (lam * np.trace(E, axis1=1, axis2=2))[:, None, None] * np.eye(3)
        P = P + F @ S
    fc = -np.einsum("e,eab,ecb->eca", vol, P, g)
    out = np.zeros_like(u)
    np.add.at(out, model.mesh.tets.reshape(-1), fc.reshape(-1, 3))
    return out - m.xi * model.mass[:, None] * v


@numba.njit(**INLINED)
def lane_cofactor(f00, f01, f02, f10, f11, f12, f20, f21, f22):
    """cof F = dJ/dF, row-major (rows f1 x f2, f2 x f0, f0 x f1 of F's rows f0, f1, f2)."""
    return (f11 * f22 - f12 * f21, f12 * f20 - f10 * f22, f10 * f21 - f11 * f20,
            f21 * f02 - f22 * f01, f22 * f00 - f20 * f02, f20 * f01 - f21 * f00,
            f01 * f12 - f02 * f11, f02 * f10 - f00 * f12, f00 * f11 - f01 * f10)


@numba.njit(**INLINED)
def lane_tangent_bound(f00, f01, f02, f10, f11, f12, f20, f21, f22,
                       c00, c01, c02, c10, c11, c12, c20, c21, c22, j, lam_s, alpha, mu):
    """b >= the largest eigenvalue of dP/dF at F (cof F = c, J = det F; module docstring, The step plan's bound)."""
    i2 = (c00 * c00 + c01 * c01 + c02 * c02 + c10 * c10 + c11 * c11 + c12 * c12
          + c20 * c20 + c21 * c21 + c22 * c22)                      # |cof F|^2
    i1 = (f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12
          + f20 * f20 + f21 * f21 + f22 * f22)                      # |F|^2
    nf = math.sqrt(i1)
    s = math.sqrt(THIRD * (i1 + 2.0 * math.sqrt(max(0.0, i1 * i1 - 3.0 * i2))))         # >= |s_i|
    p = min(i2, THIRD * (i2 + 2.0 * math.sqrt(max(0.0, i2 * i2 - 3.0 * i1 * j * j))))    # >= (s_j s_k)^2
    a = abs(j - alpha)
    frobenius = i2 + SQRT2 * a * nf                                 # each bound less mu, over lam_s
    twist = a * s
    scaling = p + abs(2.0 * j - alpha) * min(2.0 * s, SQRT2 * nf)
    return mu + lam_s * min(frobenius, max(twist, scaling))


def _chunk_forces_source(D, DW, grad, vol, lam, mu, fe, bound):
    """fe[(3 c + a) LANES + l] <- component a of V P g_c per lane (the force is -fe): F = I + sum_c d_c g_c^T from
    the differences of u (D), G = sum_c dw_c g_c^T from those of w = x0 + u + zeta v (DW), P the elastic stress
    plus the damping F S_d with zeta dF/dt = G - F (module docstring); bound[l] <- the tangent bound at F where
    the build ``PLANS`` (a constant per build: the other build has no bound in its lane loop, bound unread)."""
    lam_s = lam + mu
    alpha = 1.0 + mu / lam_s
    for l in range(LANES):
        f00, f01, f02, f10, f11, f12, f20, f21, f22 = lane_gradient(D, grad, l, 1.0)
        G00, G01, G02, G10, G11, G12, G20, G21, G22 = lane_gradient(DW, grad, l, 0.0)
        z00, z01, z02 = G00 - f00, G01 - f01, G02 - f02                 # Z = G - F = zeta dF/dt
        z10, z11, z12 = G10 - f10, G11 - f11, G12 - f12
        z20, z21, z22 = G20 - f20, G21 - f21, G22 - f22
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = lane_cofactor(f00, f01, f02, f10, f11, f12, f20, f21, f22)
        j = f00 * c00 + f01 * c01 + f02 * c02
        if PLANS:  # noqa: F821 (bound per build)
            b = lane_tangent_bound(f00, f01, f02, f10, f11, f12, f20, f21, f22,
                                   c00, c01, c02, c10, c11, c12, c20, c21, c22, j, lam_s, alpha, mu)
            bound[l] = b if j > 0.0 else -b                         # the sign says: inverted (or flat)
        k = lam_s * (j - alpha)
        e00 = f00 * z00 + f10 * z10 + f20 * z20                     # E' = sym(F^T Z)
        e11 = f01 * z01 + f11 * z11 + f21 * z21
        e22 = f02 * z02 + f12 * z12 + f22 * z22
        e01 = 0.5 * ((f00 * z01 + f10 * z11 + f20 * z21) + (f01 * z00 + f11 * z10 + f21 * z20))
        e02 = 0.5 * ((f00 * z02 + f10 * z12 + f20 * z22) + (f02 * z00 + f12 * z10 + f22 * z20))
        e12 = 0.5 * ((f01 * z02 + f11 * z12 + f21 * z22) + (f02 * z01 + f12 * z11 + f22 * z21))
        t = lam * (e00 + e11 + e22)
        s00, s11, s22 = mu + 2.0 * mu * e00 + t, mu + 2.0 * mu * e11 + t, mu + 2.0 * mu * e22 + t
        s01, s02, s12 = 2.0 * mu * e01, 2.0 * mu * e02, 2.0 * mu * e12
        v = vol[l]                                                  # P = F (mu I + S_d) + k cof F, times V
        p00 = v * (f00 * s00 + f01 * s01 + f02 * s02 + k * c00)
        p01 = v * (f00 * s01 + f01 * s11 + f02 * s12 + k * c01)
        p02 = v * (f00 * s02 + f01 * s12 + f02 * s22 + k * c02)
        p10 = v * (f10 * s00 + f11 * s01 + f12 * s02 + k * c10)
        p11 = v * (f10 * s01 + f11 * s11 + f12 * s12 + k * c11)
        p12 = v * (f10 * s02 + f11 * s12 + f12 * s22 + k * c12)
        p20 = v * (f20 * s00 + f21 * s01 + f22 * s02 + k * c20)
        p21 = v * (f20 * s01 + f21 * s11 + f22 * s12 + k * c21)
        p22 = v * (f20 * s02 + f21 * s12 + f22 * s22 + k * c22)
        store_corner_forces(fe, grad, l, p00, p01, p02, p10, p11, p12, p20, p21, p22)


@numba.njit(**CONTRACTED)
def _chunk_bounds(D, grad, lam, mu, bound):
    """bound[l] <- the tangent bound at F = I + sum_c d_c g_c^T (D: the differences of u), without the forces."""
    lam_s = lam + mu
    alpha = 1.0 + mu / lam_s
    for l in range(LANES):
        f00, f01, f02, f10, f11, f12, f20, f21, f22 = lane_gradient(D, grad, l, 1.0)
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = lane_cofactor(f00, f01, f02, f10, f11, f12, f20, f21, f22)
        j = f00 * c00 + f01 * c01 + f02 * c02
        b = lane_tangent_bound(f00, f01, f02, f10, f11, f12, f20, f21, f22,
                               c00, c01, c02, c10, c11, c12, c20, c21, c22, j, lam_s, alpha, mu)
        bound[l] = b if j > 0.0 else -b


# the lane loop with the tangent bounds (the pass a step plans from: its first force, and every public call) and
# without them (the later sub-steps of a step: nothing plans from their state); the same forces, bit for bit
_chunk_forces = compiled(_chunk_forces_source, "", CONTRACTED, PLANS=True)
_chunk_forces_unplanned = compiled(_chunk_forces_source, "_unplanned", CONTRACTED, PLANS=False)


def _neohookean_chunk_source(c, buf, how, tmp, forces, corner, grad, vol, lam, mu, u, w, kept, fe):
    """Chunk c: differences of u (and of w), the tangent bounds in kept[c, :LANES] (ElementFrames.bounds: where
    the corotated chunk keeps its rotations) and with ``forces`` the element forces (``chunk_forces``: bound per
    build, with or without the bounds). The element warping's chunk signature, so its pass runs this one; the
    rotation workspace (how, tmp) is unused."""
    D, DW = buf[0], buf[1]
    if forces:
        corner_row_differences_of_two(corner[c], u, w, D, DW)
        chunk_forces(D, DW, grad[c], vol[c], lam, mu, fe[c], kept[c])  # noqa: F821 (bound per build)
    else:
        corner_row_differences(corner[c], u, D)
        _chunk_bounds(D, grad[c], lam, mu, kept[c])


_neohookean_chunk = compiled(_neohookean_chunk_source, "", INLINED, chunk_forces=_chunk_forces)
_neohookean_chunk_unplanned = compiled(_neohookean_chunk_source, "_unplanned", INLINED,
                                      chunk_forces=_chunk_forces_unplanned)


def _fused_e(elems, gather, u, w, work):
    """The serial pass and gather in one sweep: the padded rows by vertex <- 0, then each chunk's corner forces
    added to their vertices' rows while they are in L1 (add_corner_rows: a 4-wide read-modify-write a corner),
    then e <- the rows' x, y, z. Chunk by chunk and lane by lane is ascending element order, the gather's order
    for every vertex (ElementFrames.gather), so e has the gather's bits; the padding lanes are left out, as the
    gather leaves them. Same arguments as element_e_source. The chunk's two steps (``_neohookean_chunk_source``
    with forces) are written out here, so the workspace views are made once, not per chunk; ``chunk_forces``:
    bound per build."""
    corner, grad, vol, lame = elems
    rot, buf, _, _, fe, e, rows = work
    D, DW = buf[0, 0], buf[0, 1]
    lam, mu = lame[0], lame[1]
    vptr = gather[0]
    m = vptr[vptr.shape[0] - 1] // 4                # 4 corners an element
    rows[:, :] = 0.0
    for c in range(rot.shape[0]):
        lanes = corner[c]
        corner_row_differences_of_two(lanes, u, w, D, DW)
        chunk_forces(D, DW, grad[c], vol[c], lam, mu, fe[c], rot[c])  # noqa: F821 (bound per build)
        add_corner_rows(lanes, fe[c], min(LANES, m - c * LANES), rows)
    for i in range(e.shape[0]):
        e[i, 0] = rows[i, 0]
        e[i, 1] = rows[i, 1]
        e[i, 2] = rows[i, 2]


# the element warping's sources around this chunk: the pass over blocks of chunks, the pass and gather (the
# serial build fused, _fused_e), and the whole force (w, the pass and gather, the finish); the pass and gather
# without the bounds for the step's later sub-steps (``neohookean_e_unplanned_*``)
neohookean_pass_serial, neohookean_pass_parallel = serial_and_parallel(
    element_pass_source, "_neohookean", serial={"chunk": _neohookean_chunk}, parallel={"chunk": _neohookean_chunk})
neohookean_e_serial = compiled(_fused_e, "_neohookean", chunk_forces=_chunk_forces)
neohookean_e_parallel = compiled(element_e_source, "_neohookean_parallel", element_pass=neohookean_pass_parallel,
                                 gather_rows=gather_parallel)
_pass_unplanned_parallel = compiled(element_pass_source, "_neohookean_unplanned_parallel", PARALLEL,
                                    chunk=_neohookean_chunk_unplanned)
neohookean_e_unplanned_serial = compiled(_fused_e, "_neohookean_unplanned", chunk_forces=_chunk_forces_unplanned)
neohookean_e_unplanned_parallel = compiled(element_e_source, "_neohookean_unplanned_parallel",
                                           element_pass=_pass_unplanned_parallel, gather_rows=gather_parallel)
neohookean_kernel_serial = compiled(element_force_source, "_neohookean", kernel_input=kernel_input_serial,
                                    element_e=neohookean_e_serial, finish=finish_serial)
neohookean_kernel_parallel = compiled(element_force_source, "_neohookean_parallel", kernel_input=kernel_input_parallel,
                                      element_e=neohookean_e_parallel, finish=finish_parallel)


def neohookean_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None,
                     frames: ElementFrames | None = None, out: np.ndarray | None = None,
                     threads: bool | None = None) -> np.ndarray:
    """Stable Neo-Hookean elastic + damping force, (n, 3) (module docstring), including -xi M v."""
    return run_element_kernel(neohookean_kernel_serial, neohookean_kernel_parallel, model, u, v, frames, out, threads)


def tangent_bounds(model: FemModel, u: np.ndarray, frames: ElementFrames | None = None,
                   threads: bool | None = None) -> np.ndarray:
    """b_e >= the largest eigenvalue of element e's stress tangent dP/dF at displacement u, (m,) (module
    docstring, The step plan's bound): the pass without the forces."""
    (u,) = checked_rows(model, u=u)
    frames = ElementFrames.from_model(model) if frames is None else frames
    kern = pick_build(model.n_vertices, threads, neohookean_pass_serial, neohookean_pass_parallel)
    kern(frames.elems, u, frames.w, frames.work, False)
    return np.abs(frames.bounds.reshape(-1)[:frames.m])
