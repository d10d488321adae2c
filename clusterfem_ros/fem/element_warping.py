"""Per-element corotated warping, compiled: the warped force that is the gradient of an energy.

For tet e with rest shape gradients g_c (c = 0..3, sum_c g_c = 0) and volume V_e:

    F_e = I + sum_c u_c g_c^T,   R_e = polar(F_e),
    f_c = -V_e R_e sigma_e g_c,   sigma_e = lambda tr(eps_e) I + 2 mu eps_e,   eps_e = sym(R_e^T G_e) - I,

with G_e = sum_c w_c g_c^T the gradient of w = x0 + u + zeta v (so G_e = F_e + zeta grad v). This is
f_e = -R_e K_e (R_e^T w_e - x0_e): the elastic force -R_e K_e (R_e^T x_e - x0_e) plus the stiffness damping
-zeta R_e K_e R_e^T v_e, with K_e the element's linear stiffness (V B^T C B for a linear tet). The mass
damping -xi M v is added by the caller (f = -e - xi M v, the clustered kernels' convention).

Why it cannot pump energy: with zeta = 0 the force is minus the gradient of the corotated energy
Psi_e = V_e (mu |sym(R^T F) - I|^2 + lambda/2 tr^2(R^T F - I)). dPsi/dF at fixed R is V R sigma; the dR
terms vanish because R^T F is symmetric at R = polar(F) (and at any fixed point of the fallback below:
sum_c r_c x f_c = 0 is the same condition), so R is a stationary point of Psi over rotations. A gradient
field integrated by symplectic Euler keeps a shadow energy bounded; the damping parts are -zeta R K R^T v
(R K R^T positive semi-definite, and zero for any rigid velocity) and -xi M v, so they only remove energy.
The paper's per-vertex warping (fem/warping.py, ``warping_model = "vertex"``) has no such energy: where
neighbouring rotations differ sharply (a torn vertex, an inverting sliver) it fed energy in.

Rotations: the warping's lane polar iteration (fem/warping.py: scaled Newton, then Newton-Schulz, LANES
elements at once) on R_e^T F_e, R_e the element's rotation from the previous call (polar(R^T F) =
R^T polar(F) for any rotation R: near the identity while elements turn little between calls, so fewer
passes); an inverted or nearly flat element (det F <= 1e-3 |F|^3 / 3^1.5) or a lane that did not converge
takes the scalar path, Mueller et al. (2016)'s iteration warm-started from the element's previous rotation,
which follows one branch of the nearest proper rotation continuously through inversion. Chunks of LANES
elements are independent: the threaded build runs them in parallel. Each element writes its four vertex
forces to its own rows; a second pass gathers them per vertex in element order, so serial and threaded
builds give the same bits (no atomics, no colouring).

A bounded shadow energy needs the step below the tangent's critical step. Under moderate deformation the
corotated tangent's eigenvalues are K's, but an element stretched several times its size stiffens in its
twist modes (2 mu + (2 lambda tr(S - I) - 4 mu) / (s_i + s_j), s the singular values: 2.1x K's largest at
s = (10, 1, 1), nu = 0.3), so the explicit step planned from K can be too long there: undamped, the bar with
a vertex torn 0.5 m away ran bounded at safety 0.2 and grew at 0.8 (tests/test_hard_cases.py).

``element_force`` and ``element_rotations`` are the checked public entries; ``ElementFrames`` holds the
element data and workspace; fem/corotational.py (numpy) is the twin the tests compare against.

What a build injects: the kernel sources ``_element_e`` and ``_element_force`` call compiled functions by
global names that no import defines, bound per build (serial or threaded) by numba_config.compiled, hence
``# noqa: F821`` at each call: ``element_pass`` and ``gather_rows`` in ``_element_e``; ``kernel_input``,
``element_e`` and ``finish`` in ``_element_force``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import prange

from .assembly import shape_gradients
from .cluster_force_kernel import finish_parallel, finish_serial, kernel_input_parallel, kernel_input_serial
from .kernel_args import checked_rows as _check
from .kernel_args import output_rows
from .kernel_args import pick_build as _pick
from .model import FemModel
from ..numba_config import SERIAL, compiled, serial_and_parallel
from .polar import LANES
from .polar import chunk_start as _chunk_start
from .polar import lane_accepted as _lane_accepted
from .polar import polar_lanes as _polar_lanes
from .polar import scalar_rotation as _scalar_rotation

WARPING_MODELS = ("element", "vertex")


def check_warping_model(name: str) -> str:
    """The warping model's name, checked: 'element' (default) or 'vertex' (the paper's eq. 10)."""
    if name not in WARPING_MODELS:
        raise ValueError(f"warping_model = {name!r}: choose 'element' (per-element corotation, conservative) or "
                         "'vertex' (the paper's per-vertex warping, for comparison)")
    return name


@numba.njit(**SERIAL)
def _chunk_gradients(k0, nl, tets, g, u, F):
    """F[:, l] <- F_e = I + sum_c (u_c - u_0) g_c^T (row-major) of element e = k0 + l, l < nl: differences of
    displacements, so the round-off is relative to the element's size, not to its distance from the origin."""
    for l in range(nl):
        e = k0 + l
        i0 = tets[e, 0]
        for a in range(3):
            d1 = u[tets[e, 1], a] - u[i0, a]
            d2 = u[tets[e, 2], a] - u[i0, a]
            d3 = u[tets[e, 3], a] - u[i0, a]
            for b in range(3):
                F[3 * a + b, l] = ((1.0 if a == b else 0.0) + d1 * g[e, 1, b]) + (d2 * g[e, 2, b] + d3 * g[e, 3, b])


@numba.njit(**SERIAL)
def _warm_start(k0, nl, F, rot, X, how):
    """X[:, l] <- R_e^T F_e (R_e: element e = k0 + l's previous rotation), whose polar factor is R_e^T polar(F_e):
    near the identity while the element turns little between calls, so the iteration starts close to it.
    how[l] = 1 (X = I, unused) where F_e is inverted or nearly flat, as warping._chunk_start decides."""
    _chunk_start(nl, F, X, how)
    for l in range(nl):
        if how[l] == 0:
            e = k0 + l
            for a in range(3):
                for b in range(3):
                    X[3 * a + b, l] = rot[e, 0, a] * F[b, l] + rot[e, 1, a] * F[3 + b, l] + rot[e, 2, a] * F[6 + b, l]


@numba.njit(**SERIAL)
def _chunk_store(k0, nl, F, P, converged, how, tmp, rot):
    """rot[k0 + l] <- R_e times lane l's polar factor (of R_e^T F_e) if accepted, else the scalar path's rotation
    of F_e (warm-started from R_e)."""
    for l in range(nl):
        e = k0 + l
        if _lane_accepted(l, P, converged, how):
            for a in range(3):
                r0, r1, r2 = rot[e, a, 0], rot[e, a, 1], rot[e, a, 2]
                for b in range(3):
                    tmp[0, a, b] = r0 * P[b, l] + r1 * P[3 + b, l] + r2 * P[6 + b, l]
            for a in range(3):
                for b in range(3):
                    rot[e, a, b] = tmp[0, a, b]
        else:
            _scalar_rotation(l, F, tmp, rot[e])


@numba.njit(**SERIAL)
def _chunk_forces(k0, nl, tets, g, vol, lam, mu, w, rot, fe):
    """fe[e, c] <- V_e R_e sigma_e g_c for the chunk's elements (module docstring; the force is -fe). Scalars
    throughout (small local arrays kept LLVM from holding the 3x3 products in registers: twice the time)."""
    for l in range(nl):
        e = k0 + l
        i0, i1, i2, i3 = tets[e, 0], tets[e, 1], tets[e, 2], tets[e, 3]
        r00, r01, r02 = rot[e, 0, 0], rot[e, 0, 1], rot[e, 0, 2]
        r10, r11, r12 = rot[e, 1, 0], rot[e, 1, 1], rot[e, 1, 2]
        r20, r21, r22 = rot[e, 2, 0], rot[e, 2, 1], rot[e, 2, 2]
        # q_c = R^T (w_c - w_0), c = 1, 2, 3
        x, y, z = w[i1, 0] - w[i0, 0], w[i1, 1] - w[i0, 1], w[i1, 2] - w[i0, 2]
        q10, q11, q12 = r00 * x + r10 * y + r20 * z, r01 * x + r11 * y + r21 * z, r02 * x + r12 * y + r22 * z
        x, y, z = w[i2, 0] - w[i0, 0], w[i2, 1] - w[i0, 1], w[i2, 2] - w[i0, 2]
        q20, q21, q22 = r00 * x + r10 * y + r20 * z, r01 * x + r11 * y + r21 * z, r02 * x + r12 * y + r22 * z
        x, y, z = w[i3, 0] - w[i0, 0], w[i3, 1] - w[i0, 1], w[i3, 2] - w[i0, 2]
        q30, q31, q32 = r00 * x + r10 * y + r20 * z, r01 * x + r11 * y + r21 * z, r02 * x + r12 * y + r22 * z
        g10, g11, g12 = g[e, 1, 0], g[e, 1, 1], g[e, 1, 2]
        g20, g21, g22 = g[e, 2, 0], g[e, 2, 1], g[e, 2, 2]
        g30, g31, g32 = g[e, 3, 0], g[e, 3, 1], g[e, 3, 2]
        # A = R^T G = sum_c q_c g_c^T
        a00 = q10 * g10 + q20 * g20 + q30 * g30
        a01 = q10 * g11 + q20 * g21 + q30 * g31
        a02 = q10 * g12 + q20 * g22 + q30 * g32
        a10 = q11 * g10 + q21 * g20 + q31 * g30
        a11 = q11 * g11 + q21 * g21 + q31 * g31
        a12 = q11 * g12 + q21 * g22 + q31 * g32
        a20 = q12 * g10 + q22 * g20 + q32 * g30
        a21 = q12 * g11 + q22 * g21 + q32 * g31
        a22 = q12 * g12 + q22 * g22 + q32 * g32
        # sigma = mu (A + A^T) - 2 mu I + lambda tr(A - I) I, times the volume
        v = vol[e]
        diag = lam * (a00 + a11 + a22 - 3.0) - 2.0 * mu
        s00, s11, s22 = v * (2.0 * mu * a00 + diag), v * (2.0 * mu * a11 + diag), v * (2.0 * mu * a22 + diag)
        s01, s02, s12 = v * mu * (a01 + a10), v * mu * (a02 + a20), v * mu * (a12 + a21)
        # P = R sigma; fe_c = P g_c, fe_0 = -(fe_1 + fe_2 + fe_3) (sum_c g_c = 0)
        p00 = r00 * s00 + r01 * s01 + r02 * s02
        p01 = r00 * s01 + r01 * s11 + r02 * s12
        p02 = r00 * s02 + r01 * s12 + r02 * s22
        p10 = r10 * s00 + r11 * s01 + r12 * s02
        p11 = r10 * s01 + r11 * s11 + r12 * s12
        p12 = r10 * s02 + r11 * s12 + r12 * s22
        p20 = r20 * s00 + r21 * s01 + r22 * s02
        p21 = r20 * s01 + r21 * s11 + r22 * s12
        p22 = r20 * s02 + r21 * s12 + r22 * s22
        f10 = p00 * g10 + p01 * g11 + p02 * g12
        f11 = p10 * g10 + p11 * g11 + p12 * g12
        f12 = p20 * g10 + p21 * g11 + p22 * g12
        f20 = p00 * g20 + p01 * g21 + p02 * g22
        f21 = p10 * g20 + p11 * g21 + p12 * g22
        f22 = p20 * g20 + p21 * g21 + p22 * g22
        f30 = p00 * g30 + p01 * g31 + p02 * g32
        f31 = p10 * g30 + p11 * g31 + p12 * g32
        f32 = p20 * g30 + p21 * g31 + p22 * g32
        fe[e, 1, 0], fe[e, 1, 1], fe[e, 1, 2] = f10, f11, f12
        fe[e, 2, 0], fe[e, 2, 1], fe[e, 2, 2] = f20, f21, f22
        fe[e, 3, 0], fe[e, 3, 1], fe[e, 3, 2] = f30, f31, f32
        fe[e, 0, 0], fe[e, 0, 1], fe[e, 0, 2] = -(f10 + f20 + f30), -(f11 + f21 + f31), -(f12 + f22 + f32)


@numba.njit(**SERIAL)
def _element_chunk(c, forces, tets, g, vol, lam, mu, u, w, rot, F, scratch, how, tmp, fe):
    """Chunk c (elements c LANES ..): gradients, polar iteration on all lanes, rotations stored, and with
    ``forces`` the element forces."""
    m = tets.shape[0]
    k0 = c * LANES
    nl = min(LANES, m - k0)
    Fc = F[c]
    _chunk_gradients(k0, nl, tets, g, u, Fc)
    buf = scratch[c]
    _warm_start(k0, nl, Fc, rot, buf[0], how[c])
    P, converged = _polar_lanes(nl, buf[0], buf[1])
    _chunk_store(k0, nl, Fc, P, converged, how[c], tmp[c], rot)
    if forces:
        _chunk_forces(k0, nl, tets, g, vol, lam, mu, w, rot, fe)


# Argument groups (ElementFrames): ``elems`` = (tets, g, vol, lame), the fixed element data; ``gather`` =
# (vptr, slot), each vertex's element-corner rows in element order; ``work`` = (rot, F, scratch, how, tmp, fe,
# e), rotations (kept between calls: the fallback's warm start) and workspace.

def _element_pass(elems, u, w, work, forces):
    """rot <- the element rotations of u; with ``forces``, fe <- the element forces of w (chunks in parallel)."""
    tets, g, vol, lame = elems
    rot, F, scratch, how, tmp, fe, _ = work
    for c in prange(scratch.shape[0]):
        _element_chunk(c, forces, tets, g, vol, lame[0], lame[1], u, w, rot, F, scratch, how, tmp, fe)


def _gather(gather, fe, e):
    """e[i] <- sum of fe over vertex i's element corners, in element order (vertices in parallel)."""
    vptr, slot = gather
    rows = fe.reshape(-1, 3)
    for i in prange(vptr.shape[0] - 1):
        x = 0.0
        y = 0.0
        z = 0.0
        for k in range(vptr[i], vptr[i + 1]):
            r = slot[k]
            x += rows[r, 0]
            y += rows[r, 1]
            z += rows[r, 2]
        e[i, 0] = x
        e[i, 1] = y
        e[i, 2] = z


element_pass_serial, element_pass_parallel = serial_and_parallel(_element_pass)
gather_serial, gather_parallel = serial_and_parallel(_gather)


def _element_e(elems, gather, u, w, work):
    """e <- the elastic-damping part of the element-warped force of w = x0 + u + zeta v (f = -e - xi M v), in
    rows by vertex; rot <- the element rotations of u. Same arguments as warping._warped_e, so the clustered
    integrator's warped step source runs either (``element_pass`` and ``gather_rows``: bound per build)."""
    element_pass(elems, u, w, work, True)  # noqa: F821 (bound)
    gather_rows(gather, work[5], work[6])  # noqa: F821


def _element_force(elems, gather, rest, u, v, w, mass3, zeta, xi, work, out):
    """out <- the element-warped force of (u, v), f = -e - xi M v (mass3: the lumped mass per coordinate)."""
    kernel_input(u.shape[0], zeta, rest, u, v, w, True)  # noqa: F821 (bound)
    element_e(elems, gather, u, w, work)  # noqa: F821
    finish(work[6], v, mass3, xi, out)  # noqa: F821


# no loop of their own: their callees carry the threads
element_e_serial = compiled(_element_e, element_pass=element_pass_serial, gather_rows=gather_serial)
element_e_parallel = compiled(_element_e, "_parallel", element_pass=element_pass_parallel, gather_rows=gather_parallel)
element_kernel_serial = compiled(_element_force, kernel_input=kernel_input_serial, element_e=element_e_serial,
                                 finish=finish_serial)
element_kernel_parallel = compiled(_element_force, "_parallel", kernel_input=kernel_input_parallel,
                                   element_e=element_e_parallel, finish=finish_parallel)


@dataclass
class ElementFrames:
    """What element warping keeps per model: the element data, each element's last rotation (the fallback's
    warm start), the per-vertex gather and workspace. Build once per model (``from_model``)."""
    rest: np.ndarray        # (n, 3)
    elems: tuple            # (tets (m, 4) int64, g (m, 4, 3) rest shape gradients, vol (m,), lame (2,) = (lambda, mu))
    gather: tuple           # (vptr (n + 1,), slot (4 m,)): vertex i's rows 4 e + c of fe, ascending
    rot: np.ndarray         # (m, 3, 3), updated by every force / rotation call
    F: np.ndarray           # (chunks, 9, LANES) workspace: deformation gradients by lane
    scratch: np.ndarray     # (chunks, 2, 9, LANES) workspace: polar iterates
    how: np.ndarray         # (chunks, LANES) workspace: 0 polar, 1 inverted/flat
    tmp: np.ndarray         # (chunks, 2, 3, 3) workspace of the scalar fallback
    fe: np.ndarray          # (m, 4, 3) workspace: element corner forces (-f)
    e: np.ndarray           # (n + 1, 3) workspace: their sums by vertex (the last row unused)
    w: np.ndarray           # (n + 1, 3) workspace: x0 + u + zeta v

    @classmethod
    def from_model(cls, model: FemModel) -> "ElementFrames":
        tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
        m, n = tets.shape[0], model.n_vertices
        g, vol = shape_gradients(model.rest, tets)
        lam, mu = model.material.lame
        order = np.argsort(tets.reshape(-1), kind="stable")         # rows 4 e + c by vertex, element order kept
        vptr = np.zeros(n + 1, dtype=np.int64)
        vptr[1:] = np.cumsum(np.bincount(tets.reshape(-1), minlength=n))
        chunks = -(-m // LANES)
        return cls(np.ascontiguousarray(model.rest, dtype=np.float64),
                   (tets, np.ascontiguousarray(g), np.ascontiguousarray(vol), np.array([lam, mu], dtype=np.float64)),
                   (vptr, order.astype(np.int64)), np.repeat(np.eye(3)[None], m, axis=0),
                   np.zeros((chunks, 9, LANES)), np.zeros((chunks, 2, 9, LANES)),
                   np.zeros((chunks, LANES), dtype=np.int8), np.zeros((chunks, 2, 3, 3)), np.zeros((m, 4, 3)),
                   np.zeros((n + 1, 3)), np.zeros((n + 1, 3)))

    @property
    def work(self) -> tuple:
        """The kernels' workspace group: (rot, F, scratch, how, tmp, fe, e)."""
        return self.rot, self.F, self.scratch, self.how, self.tmp, self.fe, self.e


def element_rotations(model: FemModel, u: np.ndarray, frames: ElementFrames | None = None,
                      threads: bool | None = None) -> np.ndarray:
    """R_e for every element, (m, 3, 3), of the displacement u (n, 3); ``frames`` keeps the warm start."""
    (u,) = _check(model, u=u)
    frames = ElementFrames.from_model(model) if frames is None else frames
    kern = _pick(model.n_vertices, threads, element_pass_serial, element_pass_parallel)
    kern(frames.elems, u, frames.w, frames.work, False)
    return frames.rot.copy()


def element_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None, frames: ElementFrames | None = None,
                  out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """Element-warped elastic + damping force, (n, 3) (module docstring), including -xi M v."""
    (u,) = _check(model, u=u)
    (v,) = _check(model, v=np.zeros_like(u) if v is None else v)
    frames = ElementFrames.from_model(model) if frames is None else frames
    n = model.n_vertices
    out = output_rows(n, out)
    kern = _pick(n, threads, element_kernel_serial, element_kernel_parallel)
    m = model.material
    kern(frames.elems, frames.gather, frames.rest, u, v, frames.w, np.repeat(model.mass, 3), float(m.zeta),
         float(m.xi), frames.work, out)
    return out
