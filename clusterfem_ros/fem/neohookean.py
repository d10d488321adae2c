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
invariant without a rotation. The corotated energy (fem/element_warping.py) depends on F through the
rotation R = polar(F), which is not a smooth function of F where an inverted element's two smallest
singular values meet; symplectic Euler keeps a shadow energy bounded only for a smooth energy, and the
corotated bar with a vertex torn away and held, undamped, gains energy for as long as its elements stay
inverted. This energy has no such place: after the tear its shadow energy stays flat
(benchmarks/stability_table.py). The price is stiffness at large stretch: cof F grows with the product of
two singular values, so an element stretched tenfold is about a hundred times stiffer than at rest, and the step
plan must follow (fem/stretch.py, ``neohookean_stiffening``). No polar iteration: the pass costs less than
the corotated one (benchmarks/core_benchmark.py --warping-only).

Damping. The stiffness damping is a viscous stress on the rate of the right Cauchy-Green tensor:
P_d = F S_d, S_d = lambda tr(E') I + 2 mu E', E' = sym(F^T zeta dF/dt). Its power S_d : E' / zeta >= 0, so it
only removes energy; it is zero for any rigid velocity (dF/dt = W F, W skew, gives E' = 0); at F = I it is
zeta K v, the linear model's. With w = x0 + u + zeta v (the kernels' input) zeta dF/dt = G - F, G the
gradient of w. The mass damping -xi M v is added by the caller, as for the other models.

The compiled pass has the element warping's layout (fem/element_warping.py: ``ElementFrames``, chunks of
LANES elements by lane, element corner forces gathered per vertex in element order, so serial and threaded
builds give the same bits) without the rotations. ``neohookean_force`` is the checked public entry;
``reference_force`` and ``energy`` (numpy) are the twins the tests and the stability table use.

Builds: the element warping's pass, pass-and-gather and force sources (``_element_pass``, ``_element_e``,
``_element_force``) with this module's ``_neohookean_chunk`` bound as their ``chunk`` (numba_config.compiled).
"""
from __future__ import annotations

import numba
import numpy as np

from .assembly import shape_gradients
from .cluster_force_kernel import finish_parallel, finish_serial, kernel_input_parallel, kernel_input_serial
from .corotational import deformation_gradients
from .element_rotation import LANES
from .element_warping import (ElementFrames, _differences, _element_e, _element_force, _element_pass,
                              gather_parallel, gather_serial, lane_gradient, run_element_kernel,
                              store_corner_forces)
from .model import FemModel
from ..numba_config import SERIAL, compiled, serial_and_parallel


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
    tets = model.mesh.tets
    g, vol = shape_gradients(model.rest, tets)
    return deformation_gradients(g, tets, u), g, vol


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


@numba.njit(**SERIAL)
def _chunk_forces(D, DW, grad, vol, lam, mu, fe):
    """fe[(3 c + a) LANES + l] <- component a of V P g_c per lane (the force is -fe): F = I + sum_c d_c g_c^T from
    the differences of u (D), G = sum_c dw_c g_c^T from those of w = x0 + u + zeta v (DW), P the elastic stress
    plus the damping F S_d with zeta dF/dt = G - F (module docstring)."""
    lam_s = lam + mu
    alpha = 1.0 + mu / lam_s
    for l in range(LANES):
        f00, f01, f02, f10, f11, f12, f20, f21, f22 = lane_gradient(D, grad, l, 1.0)
        G00, G01, G02, G10, G11, G12, G20, G21, G22 = lane_gradient(DW, grad, l, 0.0)
        z00, z01, z02 = G00 - f00, G01 - f01, G02 - f02                 # Z = G - F = zeta dF/dt
        z10, z11, z12 = G10 - f10, G11 - f11, G12 - f12
        z20, z21, z22 = G20 - f20, G21 - f21, G22 - f22
        c00, c01, c02 = f11 * f22 - f12 * f21, f12 * f20 - f10 * f22, f10 * f21 - f11 * f20     # cof F
        c10, c11, c12 = f21 * f02 - f22 * f01, f22 * f00 - f20 * f02, f20 * f01 - f21 * f00
        c20, c21, c22 = f01 * f12 - f02 * f11, f02 * f10 - f00 * f12, f00 * f11 - f01 * f10
        k = lam_s * ((f00 * c00 + f01 * c01 + f02 * c02) - alpha)
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


@numba.njit(**SERIAL)
def _neohookean_chunk(c, buf, how, tmp, forces, corner, grad, vol, lam, mu, u, w, rot, fe):
    """Chunk c: differences of u and w, then the element forces. The element warping's chunk signature, so its
    pass runs this one; the rotation workspace (how, tmp, rot) is unused and ``forces`` is always true here."""
    D, DW = buf[0], buf[1]
    _differences(corner[c], u, w, D, DW, True)
    _chunk_forces(D, DW, grad[c], vol[c], lam, mu, fe[c])


# the element warping's sources around this chunk: the pass over blocks of chunks, the pass and gather, and
# the whole force (w, the pass and gather, the finish)
neohookean_pass_serial, neohookean_pass_parallel = serial_and_parallel(
    _element_pass, "_neohookean", serial={"chunk": _neohookean_chunk}, parallel={"chunk": _neohookean_chunk})
neohookean_e_serial = compiled(_element_e, "_neohookean", element_pass=neohookean_pass_serial,
                               gather_rows=gather_serial)
neohookean_e_parallel = compiled(_element_e, "_neohookean_parallel", element_pass=neohookean_pass_parallel,
                                 gather_rows=gather_parallel)
neohookean_kernel_serial = compiled(_element_force, "_neohookean", kernel_input=kernel_input_serial,
                                    element_e=neohookean_e_serial, finish=finish_serial)
neohookean_kernel_parallel = compiled(_element_force, "_neohookean_parallel", kernel_input=kernel_input_parallel,
                                      element_e=neohookean_e_parallel, finish=finish_parallel)


def neohookean_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None,
                     frames: ElementFrames | None = None, out: np.ndarray | None = None,
                     threads: bool | None = None) -> np.ndarray:
    """Stable Neo-Hookean elastic + damping force, (n, 3) (module docstring), including -xi M v."""
    return run_element_kernel(neohookean_kernel_serial, neohookean_kernel_parallel, model, u, v, frames, out, threads)
