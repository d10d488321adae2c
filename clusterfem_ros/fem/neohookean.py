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
two singular values, so an element stretched tenfold is tens of times stiffer than at rest, and the step
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

What a build injects: ``_neohookean_e`` calls ``neohookean_pass`` and ``gather_rows``, ``_neohookean_force``
calls ``kernel_input``, ``neohookean_e`` and ``finish``, by global names bound per build
(numba_config.compiled), hence ``# noqa: F821`` at each call.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import prange

from .assembly import shape_gradients
from .cluster_force_kernel import finish_parallel, finish_serial, kernel_input_parallel, kernel_input_serial
from .element_rotation import LANES
from .element_warping import ElementFrames, _differences, gather_parallel, gather_serial
from .kernel_args import checked_rows, output_rows, pick_build
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
    """(F (m, 3, 3), rest gradients (m, 4, 3), rest volumes (m,)) of displacement u, relative to each tet's first
    vertex (round-off relative to the element's size)."""
    tets = model.mesh.tets
    g, vol = shape_gradients(model.rest, tets)
    d = u[tets] - u[tets][:, :1]
    return np.eye(3) + np.einsum("eca,ecb->eab", d, g), g, vol


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
        tets = model.mesh.tets
        dv = v[tets] - v[tets][:, :1]
        Z = m.zeta * np.einsum("eca,ecb->eab", dv, g)                # zeta dF/dt
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
        g10, g11, g12 = grad[l], grad[1 * LANES + l], grad[2 * LANES + l]
        g20, g21, g22 = grad[3 * LANES + l], grad[4 * LANES + l], grad[5 * LANES + l]
        g30, g31, g32 = grad[6 * LANES + l], grad[7 * LANES + l], grad[8 * LANES + l]
        d10, d11, d12 = D[l], D[1 * LANES + l], D[2 * LANES + l]
        d20, d21, d22 = D[3 * LANES + l], D[4 * LANES + l], D[5 * LANES + l]
        d30, d31, d32 = D[6 * LANES + l], D[7 * LANES + l], D[8 * LANES + l]
        f00 = (1.0 + d10 * g10) + (d20 * g20 + d30 * g30)
        f01 = d10 * g11 + (d20 * g21 + d30 * g31)
        f02 = d10 * g12 + (d20 * g22 + d30 * g32)
        f10 = d11 * g10 + (d21 * g20 + d31 * g30)
        f11 = (1.0 + d11 * g11) + (d21 * g21 + d31 * g31)
        f12 = d11 * g12 + (d21 * g22 + d31 * g32)
        f20 = d12 * g10 + (d22 * g20 + d32 * g30)
        f21 = d12 * g11 + (d22 * g21 + d32 * g31)
        f22 = (1.0 + d12 * g12) + (d22 * g22 + d32 * g32)
        w10, w11, w12 = DW[l], DW[1 * LANES + l], DW[2 * LANES + l]
        w20, w21, w22 = DW[3 * LANES + l], DW[4 * LANES + l], DW[5 * LANES + l]
        w30, w31, w32 = DW[6 * LANES + l], DW[7 * LANES + l], DW[8 * LANES + l]
        z00 = (w10 * g10 + (w20 * g20 + w30 * g30)) - f00           # Z = G - F = zeta dF/dt
        z01 = (w10 * g11 + (w20 * g21 + w30 * g31)) - f01
        z02 = (w10 * g12 + (w20 * g22 + w30 * g32)) - f02
        z10 = (w11 * g10 + (w21 * g20 + w31 * g30)) - f10
        z11 = (w11 * g11 + (w21 * g21 + w31 * g31)) - f11
        z12 = (w11 * g12 + (w21 * g22 + w31 * g32)) - f12
        z20 = (w12 * g10 + (w22 * g20 + w32 * g30)) - f20
        z21 = (w12 * g11 + (w22 * g21 + w32 * g31)) - f21
        z22 = (w12 * g12 + (w22 * g22 + w32 * g32)) - f22
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
        h10 = p00 * g10 + p01 * g11 + p02 * g12                     # fe_c = P g_c, fe_0 = -(fe_1 + fe_2 + fe_3)
        h11 = p10 * g10 + p11 * g11 + p12 * g12
        h12 = p20 * g10 + p21 * g11 + p22 * g12
        h20 = p00 * g20 + p01 * g21 + p02 * g22
        h21 = p10 * g20 + p11 * g21 + p12 * g22
        h22 = p20 * g20 + p21 * g21 + p22 * g22
        h30 = p00 * g30 + p01 * g31 + p02 * g32
        h31 = p10 * g30 + p11 * g31 + p12 * g32
        h32 = p20 * g30 + p21 * g31 + p22 * g32
        fe[l], fe[LANES + l], fe[2 * LANES + l] = -(h10 + h20 + h30), -(h11 + h21 + h31), -(h12 + h22 + h32)
        fe[3 * LANES + l], fe[4 * LANES + l], fe[5 * LANES + l] = h10, h11, h12
        fe[6 * LANES + l], fe[7 * LANES + l], fe[8 * LANES + l] = h20, h21, h22
        fe[9 * LANES + l], fe[10 * LANES + l], fe[11 * LANES + l] = h30, h31, h32


def _neohookean_pass(elems, u, w, work):
    """fe <- the element forces of (u, w) (blocks of chunks in parallel; ElementFrames' argument groups)."""
    corner, grad, vol, lame = elems
    _, buf, _, _, fe, _ = work
    chunks = fe.shape[0]
    blocks = buf.shape[0]
    per = -(-chunks // blocks)
    for b in prange(blocks):
        D, DW = buf[b, 0], buf[b, 1]
        for c in range(b * per, min((b + 1) * per, chunks)):
            _differences(corner[c], u, w, D, DW, True)
            _chunk_forces(D, DW, grad[c], vol[c], lame[0], lame[1], fe[c])


neohookean_pass_serial, neohookean_pass_parallel = serial_and_parallel(_neohookean_pass)


def _neohookean_e(elems, gather, u, w, work):
    """e <- the elastic-damping part of the force of w = x0 + u + zeta v (f = -e - xi M v), in rows by vertex;
    the clustered integrator's warped step source runs it in place of the element warping's."""
    neohookean_pass(elems, u, w, work)  # noqa: F821 (bound)
    gather_rows(gather, work[4], work[5])  # noqa: F821


def _neohookean_force(elems, gather, rest, u, v, w, mass3, zeta, xi, work, out):
    """out <- the force of (u, v), f = -e - xi M v (mass3: the lumped mass per coordinate)."""
    kernel_input(u.shape[0], zeta, rest, u, v, w, True)  # noqa: F821 (bound)
    neohookean_e(elems, gather, u, w, work)  # noqa: F821
    finish(work[5], v, mass3, xi, out)  # noqa: F821


# no loop of their own: their callees carry the threads
neohookean_e_serial = compiled(_neohookean_e, neohookean_pass=neohookean_pass_serial, gather_rows=gather_serial)
neohookean_e_parallel = compiled(_neohookean_e, "_parallel", neohookean_pass=neohookean_pass_parallel,
                                 gather_rows=gather_parallel)
neohookean_kernel_serial = compiled(_neohookean_force, kernel_input=kernel_input_serial,
                                    neohookean_e=neohookean_e_serial, finish=finish_serial)
neohookean_kernel_parallel = compiled(_neohookean_force, "_parallel", kernel_input=kernel_input_parallel,
                                      neohookean_e=neohookean_e_parallel, finish=finish_parallel)


def neohookean_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None,
                     frames: ElementFrames | None = None, out: np.ndarray | None = None,
                     threads: bool | None = None) -> np.ndarray:
    """Stable Neo-Hookean elastic + damping force, (n, 3) (module docstring), including -xi M v."""
    (u,) = checked_rows(model, u=u)
    (v,) = checked_rows(model, v=np.zeros_like(u) if v is None else v)
    frames = ElementFrames.from_model(model) if frames is None else frames
    n = model.n_vertices
    out = output_rows(n, out)
    kern = pick_build(n, threads, neohookean_kernel_serial, neohookean_kernel_parallel)
    m = model.material
    kern(frames.elems, frames.gather, frames.rest, u, v, frames.w, np.repeat(model.mass, 3), float(m.zeta),
         float(m.xi), frames.work, out)
    return out
