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
The paper's per-vertex warping (fem/materials/warping.py, ``warping_model = "vertex"``) has no such energy: where
neighbouring rotations differ sharply (a torn vertex, an inverting sliver) it fed energy in.

Rotations: fem/materials/element_rotation.py, Newton's method on each element's rotation started from its rotation of
the previous call (two passes to round-off in smooth motion, whatever the strain), the lane polar iteration of
fem/materials/polar.py and Mueller et al. (2016)'s scalar iteration for inverted or flat elements and chunks Newton
does not settle. Per chunk of LANES elements one call does the vertex differences, the gradients, the
rotations and the forces, on (9 LANES,) arrays by lane, so every loop runs on vectors (the differences' gather
too: fem/materials/corner_rows.py). Chunks are independent: the threaded build runs them in parallel. Each element writes its four
vertex forces to its own slots; a second pass gathers them per vertex in element order, so serial and
threaded builds give the same bits (no atomics, no colouring).

A bounded shadow energy needs the step below the tangent's critical step. Under moderate deformation the
corotated tangent's eigenvalues are K's, but an element stretched several times its size stiffens in its
twist modes (2 mu + (2 lambda tr(S - I) - 4 mu) / (s_i + s_j), s the singular values: 2.1x K's largest at
s = (10, 1, 1), nu = 0.3), so the explicit step planned from K can be too long there: undamped, the bar with
a vertex torn 0.5 m away diverged at safety 0.8 with the step planned from K (tests/test_hard_cases.py).
Inverted elements are the model's weak point: the rotation of an inverted element is not a smooth function
of F (the iteration follows one branch through inversion), and the undamped torn bar, whose tear inverts
tens of elements, gains a few per cent of energy (benchmarks/stability_table.py's docstring).

``element_force`` and ``element_rotations`` are the checked public entries; ``ElementFrames`` holds the
element data and workspace; fem/materials/corotational.py (numpy) is the twin the tests compare against.

What a build injects: the kernel sources ``element_e_source`` and ``element_force_source`` (public: every
element model builds its kernels from them) call compiled functions by global names that no import defines,
bound per build (serial or threaded) by numba_config.compiled, hence ``# noqa: F821`` at each call: ``chunk``
(``_element_chunk``; fem/materials/neohookean.py binds its own) in ``element_pass_source``; ``element_pass``
and ``gather_rows`` in ``element_e_source``; ``kernel_input``, ``element_e`` and ``finish`` in
``element_force_source``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import prange

from ..linear.assembly import shape_gradients
from ..kernels.cluster_slices import aligned_zeros
from ..kernels.cluster_force_kernel import finish_parallel, finish_serial, kernel_input_parallel, kernel_input_serial
from .kernel_args import checked_rows, output_rows, pick_build
from ..model import FemModel
from .warping_models import WARPING_MODELS  # noqa: F401 (re-export)
from ...numba_config import SERIAL, compiled, serial_and_parallel
from .element_rotation import LANES, chunk_rotations
from .corner_rows import ROW, corner_row_differences, corner_row_differences_of_two

# Elements are processed in chunks of LANES (fem/materials/element_rotation.py), each chunk's 3x3 matrices as flat
# (9 LANES,) arrays, entry k of lane l at k LANES + l (structure of arrays: every per-element loop below runs
# on vectors). 64 lanes keep a chunk's working set (rest gradients, rotations, differences, iterates: ~25 KiB)
# in L1; the padding lanes of the last chunk are an element with zero gradients, which stays at F = I, R = I
# and zero force.
# Chunks are handed to threads in BLOCKS contiguous runs, each with its own workspace (a chunk's result does
# not depend on the workspace it used, so serial and threaded builds give the same bits).
BLOCKS = 16
# The lane steps shared with fem/materials/neohookean.py are inlined by numba, not left to LLVM: called as functions,
# their indexing kept the element pass from vectorising (the jelly man's warped force took 1.9x as long).
INLINED = dict(SERIAL, inline="always")


@numba.njit(**INLINED)
def lane_gradient(D, grad, l, one):
    """one I + sum_c d_c g_c^T of lane l (d_c = D's rows 3 (c - 1).., g_c = grad's), row-major: with one = 1
    and D the differences of u, F = I + grad u; with one = 0 and D those of w = x0 + u + zeta v, G, the gradient
    of w. The element passes' shared first step (here and in fem/materials/neohookean.py), inlined into their lane
    loops."""
    g10, g11, g12 = grad[l], grad[1 * LANES + l], grad[2 * LANES + l]
    g20, g21, g22 = grad[3 * LANES + l], grad[4 * LANES + l], grad[5 * LANES + l]
    g30, g31, g32 = grad[6 * LANES + l], grad[7 * LANES + l], grad[8 * LANES + l]
    d10, d11, d12 = D[l], D[1 * LANES + l], D[2 * LANES + l]
    d20, d21, d22 = D[3 * LANES + l], D[4 * LANES + l], D[5 * LANES + l]
    d30, d31, d32 = D[6 * LANES + l], D[7 * LANES + l], D[8 * LANES + l]
    return ((one + d10 * g10) + (d20 * g20 + d30 * g30), d10 * g11 + (d20 * g21 + d30 * g31),
            d10 * g12 + (d20 * g22 + d30 * g32), d11 * g10 + (d21 * g20 + d31 * g30),
            (one + d11 * g11) + (d21 * g21 + d31 * g31), d11 * g12 + (d21 * g22 + d31 * g32),
            d12 * g10 + (d22 * g20 + d32 * g30), d12 * g11 + (d22 * g21 + d32 * g31),
            (one + d12 * g12) + (d22 * g22 + d32 * g32))


@numba.njit(**INLINED)
def store_corner_forces(fe, grad, l, p00, p01, p02, p10, p11, p12, p20, p21, p22):
    """fe[(3 c + a) LANES + l] <- component a of P g_c (c = 1, 2, 3), fe_0 = -(fe_1 + fe_2 + fe_3): lane l's
    corner forces (the force is -fe) from its stress P times volume, row-major; the element passes' last step."""
    g10, g11, g12 = grad[l], grad[1 * LANES + l], grad[2 * LANES + l]
    g20, g21, g22 = grad[3 * LANES + l], grad[4 * LANES + l], grad[5 * LANES + l]
    g30, g31, g32 = grad[6 * LANES + l], grad[7 * LANES + l], grad[8 * LANES + l]
    f10 = p00 * g10 + p01 * g11 + p02 * g12
    f11 = p10 * g10 + p11 * g11 + p12 * g12
    f12 = p20 * g10 + p21 * g11 + p22 * g12
    f20 = p00 * g20 + p01 * g21 + p02 * g22
    f21 = p10 * g20 + p11 * g21 + p12 * g22
    f22 = p20 * g20 + p21 * g21 + p22 * g22
    f30 = p00 * g30 + p01 * g31 + p02 * g32
    f31 = p10 * g30 + p11 * g31 + p12 * g32
    f32 = p20 * g30 + p21 * g31 + p22 * g32
    fe[l], fe[LANES + l], fe[2 * LANES + l] = -(f10 + f20 + f30), -(f11 + f21 + f31), -(f12 + f22 + f32)
    fe[3 * LANES + l], fe[4 * LANES + l], fe[5 * LANES + l] = f10, f11, f12
    fe[6 * LANES + l], fe[7 * LANES + l], fe[8 * LANES + l] = f20, f21, f22
    fe[9 * LANES + l], fe[10 * LANES + l], fe[11 * LANES + l] = f30, f31, f32


@numba.njit(**SERIAL)
def _warm_gradients(D, grad, rot, X):
    """X <- R^T F per lane: F = I + sum_c d_c g_c^T (d_c = D's rows 3 (c - 1)..), R the element's previous
    rotation, whose polar factor R^T polar(F) is near the identity while the element turns little."""
    for l in range(LANES):
        f00, f01, f02, f10, f11, f12, f20, f21, f22 = lane_gradient(D, grad, l, 1.0)
        r00, r01, r02 = rot[l], rot[1 * LANES + l], rot[2 * LANES + l]
        r10, r11, r12 = rot[3 * LANES + l], rot[4 * LANES + l], rot[5 * LANES + l]
        r20, r21, r22 = rot[6 * LANES + l], rot[7 * LANES + l], rot[8 * LANES + l]
        X[l] = r00 * f00 + r10 * f10 + r20 * f20
        X[1 * LANES + l] = r00 * f01 + r10 * f11 + r20 * f21
        X[2 * LANES + l] = r00 * f02 + r10 * f12 + r20 * f22
        X[3 * LANES + l] = r01 * f00 + r11 * f10 + r21 * f20
        X[4 * LANES + l] = r01 * f01 + r11 * f11 + r21 * f21
        X[5 * LANES + l] = r01 * f02 + r11 * f12 + r21 * f22
        X[6 * LANES + l] = r02 * f00 + r12 * f10 + r22 * f20
        X[7 * LANES + l] = r02 * f01 + r12 * f11 + r22 * f21
        X[8 * LANES + l] = r02 * f02 + r12 * f12 + r22 * f22


@numba.njit(**SERIAL)
def _chunk_forces(DW, grad, vol, lam, mu, R, fe):
    """fe[(3 c + a) LANES + l] <- component a of V R sigma g_c per lane (module docstring; the force is -fe):
    G = sum_c dw_c g_c^T the gradient of w, A = R^T G, sigma = mu (A + A^T) - 2 mu I + lambda tr(A - I) I."""
    for l in range(LANES):
        G00, G01, G02, G10, G11, G12, G20, G21, G22 = lane_gradient(DW, grad, l, 0.0)
        r00, r01, r02 = R[l], R[1 * LANES + l], R[2 * LANES + l]
        r10, r11, r12 = R[3 * LANES + l], R[4 * LANES + l], R[5 * LANES + l]
        r20, r21, r22 = R[6 * LANES + l], R[7 * LANES + l], R[8 * LANES + l]
        a00 = r00 * G00 + r10 * G10 + r20 * G20                  # A = R^T G
        a01 = r00 * G01 + r10 * G11 + r20 * G21
        a02 = r00 * G02 + r10 * G12 + r20 * G22
        a10 = r01 * G00 + r11 * G10 + r21 * G20
        a11 = r01 * G01 + r11 * G11 + r21 * G21
        a12 = r01 * G02 + r11 * G12 + r21 * G22
        a20 = r02 * G00 + r12 * G10 + r22 * G20
        a21 = r02 * G01 + r12 * G11 + r22 * G21
        a22 = r02 * G02 + r12 * G12 + r22 * G22
        v = vol[l]
        diag = lam * (a00 + a11 + a22 - 3.0) - 2.0 * mu
        s00, s11, s22 = v * (2.0 * mu * a00 + diag), v * (2.0 * mu * a11 + diag), v * (2.0 * mu * a22 + diag)
        s01, s02, s12 = v * mu * (a01 + a10), v * mu * (a02 + a20), v * mu * (a12 + a21)
        p00 = r00 * s00 + r01 * s01 + r02 * s02                  # P = R V sigma
        p01 = r00 * s01 + r01 * s11 + r02 * s12
        p02 = r00 * s02 + r01 * s12 + r02 * s22
        p10 = r10 * s00 + r11 * s01 + r12 * s02
        p11 = r10 * s01 + r11 * s11 + r12 * s12
        p12 = r10 * s02 + r11 * s12 + r12 * s22
        p20 = r20 * s00 + r21 * s01 + r22 * s02
        p21 = r20 * s01 + r21 * s11 + r22 * s12
        p22 = r20 * s02 + r21 * s12 + r22 * s22
        store_corner_forces(fe, grad, l, p00, p01, p02, p10, p11, p12, p20, p21, p22)


@numba.njit(**SERIAL)
def _element_chunk(c, buf, how, tmp, forces, corner, grad, vol, lam, mu, u, w, rot, fe):
    """Chunk c: differences, warm-started gradients, rotations (fem/materials/element_rotation.py) stored in rot[c], and
    with ``forces`` the element forces. buf: (6, 9 LANES) workspace."""
    D, DW, X = buf[0], buf[1], buf[2]
    if forces:
        corner_row_differences_of_two(corner[c], u, w, D, DW)
    else:
        corner_row_differences(corner[c], u, D)
    _warm_gradients(D, grad[c], rot[c], X)
    R = chunk_rotations(X, D, buf[3], buf[4], buf[5], how, tmp, rot[c])     # D is free once X is made
    rot[c, :] = R
    if forces:
        _chunk_forces(DW, grad[c], vol[c], lam, mu, R, fe[c])


# Argument groups (ElementFrames): ``elems`` = (corner, grad, vol, lame), the fixed element data by chunk;
# ``gather`` = (vptr, slot), each vertex's element-corner rows in element order; ``work`` = (rot, buf, how,
# tmp, fe, e, rows), rotations by chunk (kept between calls: the warm start) and workspace.

def element_pass_source(elems, u, w, work, forces):
    """rot <- the element rotations of u; with ``forces``, fe <- the element forces of w (blocks of chunks in
    parallel)."""
    corner, grad, vol, lame = elems
    rot, buf, how, tmp, fe, _, _ = work
    chunks = rot.shape[0]
    blocks = buf.shape[0]
    per = -(-chunks // blocks)
    for b in prange(blocks):
        for c in range(b * per, min((b + 1) * per, chunks)):
            chunk(c, buf[b], how[b], tmp[b], forces, corner, grad, vol, lame[0], lame[1], u, w, rot, fe)  # noqa: F821


def _gather(gather, fe, e):
    """e[i] <- sum of fe over vertex i's element corners, in element order (vertices in parallel)."""
    vptr, slot = gather
    flat = fe.reshape(-1)
    for i in prange(vptr.shape[0] - 1):
        x = 0.0
        y = 0.0
        z = 0.0
        for k in range(vptr[i], vptr[i + 1]):
            r = slot[k]
            x += flat[r]
            y += flat[r + LANES]
            z += flat[r + 2 * LANES]
        e[i, 0] = x
        e[i, 1] = y
        e[i, 2] = z


element_pass_serial, element_pass_parallel = serial_and_parallel(element_pass_source, serial={"chunk": _element_chunk},
                                                                 parallel={"chunk": _element_chunk})
gather_serial, gather_parallel = serial_and_parallel(_gather)


def element_e_source(elems, gather, u, w, work):
    """e <- the elastic-damping part of the element-warped force of w = x0 + u + zeta v (f = -e - xi M v), in
    rows by vertex; rot <- the element rotations of u. Same arguments as warping._warped_e, so the clustered
    integrator's warped step source runs either (``element_pass`` and ``gather_rows``: bound per build)."""
    element_pass(elems, u, w, work, True)  # noqa: F821 (bound)
    gather_rows(gather, work[4], work[5])  # noqa: F821


def element_force_source(elems, gather, rest, u, v, w, mass3, zeta, xi, work, out):
    """out <- the element-warped force of (u, v), f = -e - xi M v (mass3: the lumped mass per coordinate)."""
    kernel_input(u.shape[0], zeta, rest, u, v, w, True)  # noqa: F821 (bound)
    element_e(elems, gather, u, w, work)  # noqa: F821
    finish(work[5], v, mass3, xi, out)  # noqa: F821


# no loop of their own: their callees carry the threads
element_e_serial = compiled(element_e_source, element_pass=element_pass_serial, gather_rows=gather_serial)
element_e_parallel = compiled(element_e_source, "_parallel", element_pass=element_pass_parallel,
                              gather_rows=gather_parallel)
element_kernel_serial = compiled(element_force_source, kernel_input=kernel_input_serial, element_e=element_e_serial,
                                 finish=finish_serial)
element_kernel_parallel = compiled(element_force_source, "_parallel", kernel_input=kernel_input_parallel,
                                   element_e=element_e_parallel, finish=finish_parallel)


def _by_chunk(a: np.ndarray, chunks: int) -> np.ndarray:
    """(m, k) per-element rows -> (chunks, k, LANES), lanes past m zero."""
    out = np.zeros((chunks * LANES,) + a.shape[1:], dtype=a.dtype)
    out[:a.shape[0]] = a
    return np.ascontiguousarray(np.moveaxis(out.reshape((chunks, LANES) + a.shape[1:]), 1, -1))


def _flat_lanes(a: np.ndarray, chunks: int) -> np.ndarray:
    """(m, 9) per-element rows -> (chunks, 9 LANES), entry k of lane l at k LANES + l."""
    return _by_chunk(a, chunks).reshape(chunks, -1)


def lane_elements(model: FemModel) -> tuple:
    """The element data by chunk, ElementFrames.elems: (corner (chunks, 4, LANES) int64, grad (chunks, 9 LANES):
    rest gradients g_1..g_3, vol (chunks, LANES), lame (2,) = (lambda, mu)); padding lanes: vertex 0, zeros."""
    tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
    m = tets.shape[0]
    chunks = -(-m // LANES)
    g, vol = shape_gradients(model.rest, tets)
    return (_by_chunk(tets, chunks), _flat_lanes(g[:, 1:].reshape(m, 9), chunks), _by_chunk(vol, chunks),
            np.array(model.material.lame, dtype=np.float64))


@dataclass
class ElementFrames:
    """What element warping keeps per model: the element data by chunk, each element's last rotation (the warm
    start), the per-vertex gather and workspace. Build once per model (``from_model``)."""
    rest: np.ndarray        # (n, 3)
    elems: tuple            # the element data by chunk (lane_elements)
    gather: tuple           # (vptr (n + 1,), slot (4 m,)): where vertex i's element corners' x components are in
                            #   fe (flat), by ascending element
    rot_lanes: np.ndarray   # (chunks, 9 LANES) rotations by lane, updated by every force / rotation call (the
                            #   Neo-Hookean pass keeps its tangent bounds in the first LANES: ``bounds``)
    buf: np.ndarray         # (BLOCKS, 6, 9 LANES) workspace: differences, iterates
    how: np.ndarray         # (BLOCKS, LANES) workspace of the robust path: 0 polar, 1 inverted/flat
    tmp: np.ndarray         # (BLOCKS, 3, 3, 3) workspace of the scalar fallback
    fe: np.ndarray          # (chunks, 12 LANES) workspace: element corner forces (-f), component a of corner c
                            #   of lane l at (3 c + a) LANES + l
    e: np.ndarray           # (n + 1, 3) workspace: their sums by vertex (the last row unused)
    rows: np.ndarray        # (n + 1, 4) workspace: the same sums in padded rows (x, y, z, 0), which the serial
                            #   Neo-Hookean pass adds to a row at a time (fem/materials/corner_rows.py)
    w: np.ndarray           # (n + 1, 3) workspace: x0 + u + zeta v
    m: int                  # elements

    @classmethod
    def from_model(cls, model: FemModel) -> "ElementFrames":
        tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
        m, n = tets.shape[0], model.n_vertices
        order = np.argsort(tets.reshape(-1), kind="stable")         # corners 4 e + c by vertex, element order kept
        vptr = np.zeros(n + 1, dtype=np.int64)
        vptr[1:] = np.cumsum(np.bincount(tets.reshape(-1), minlength=n))
        chunks = -(-m // LANES)
        blocks = min(BLOCKS, chunks)
        e, c = order // 4, order % 4
        slot = (e // LANES) * (12 * LANES) + 3 * c * LANES + e % LANES
        rot = _by_chunk(np.repeat(np.eye(3).reshape(1, 9), m, axis=0), chunks)
        rot[:, [0, 4, 8], :] = 1.0                                  # padding lanes too
        rot = rot.reshape(chunks, -1)
        elems = lane_elements(model)
        return cls(np.ascontiguousarray(model.rest, dtype=np.float64), elems, (vptr, slot.astype(np.int64)), rot,
                   aligned_zeros((blocks, 6, 9 * LANES)), np.zeros((blocks, LANES), dtype=np.int8),
                   np.zeros((blocks, 3, 3, 3)), aligned_zeros((chunks, 12 * LANES)), np.zeros((n + 1, 3)),
                   aligned_zeros((n + 1, ROW)), np.zeros((n + 1, 3)), m)

    @property
    def work(self) -> tuple:
        """The kernels' workspace group: (rot_lanes, buf, how, tmp, fe, e, rows)."""
        return self.rot_lanes, self.buf, self.how, self.tmp, self.fe, self.e, self.rows

    @property
    def bounds(self) -> np.ndarray:
        """(chunks, LANES) view: the Neo-Hookean pass's tangent bounds by lane (fem/materials/neohookean.py), kept where
        the corotated pass keeps its rotations (padding lanes: the rest value)."""
        return self.rot_lanes[:, :LANES]

    @property
    def rot(self) -> np.ndarray:
        """The element rotations, (m, 3, 3) (a copy of rot_lanes by element)."""
        chunks = self.rot_lanes.shape[0]
        return np.moveaxis(self.rot_lanes.reshape(chunks, 9, LANES), 2, 1).reshape(-1, 3, 3)[:self.m].copy()


def element_rotations(model: FemModel, u: np.ndarray, frames: ElementFrames | None = None,
                      threads: bool | None = None) -> np.ndarray:
    """R_e for every element, (m, 3, 3), of the displacement u (n, 3); ``frames`` keeps the warm start."""
    (u,) = checked_rows(model, u=u)
    frames = ElementFrames.from_model(model) if frames is None else frames
    kern = pick_build(model.n_vertices, threads, element_pass_serial, element_pass_parallel)
    kern(frames.elems, u, frames.w, frames.work, False)
    return frames.rot


def element_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None, frames: ElementFrames | None = None,
                  out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """Element-warped elastic + damping force, (n, 3) (module docstring), including -xi M v."""
    return run_element_kernel(element_kernel_serial, element_kernel_parallel, model, u, v, frames, out, threads)


def run_element_kernel(serial, parallel, model: FemModel, u: np.ndarray, v: np.ndarray | None,
                       frames: ElementFrames | None, out: np.ndarray | None, threads: bool | None) -> np.ndarray:
    """out <- the force of (u, v) by an element kernel's serial or threaded build (this module's, or
    fem/materials/neohookean.py's), arguments checked (kernel_args) and frames built if not given."""
    (u,) = checked_rows(model, u=u)
    (v,) = checked_rows(model, v=np.zeros_like(u) if v is None else v)
    frames = ElementFrames.from_model(model) if frames is None else frames
    n = model.n_vertices
    out = output_rows(n, out)
    kern = pick_build(n, threads, serial, parallel)
    m = model.material
    kern(frames.elems, frames.gather, frames.rest, u, v, frames.w, np.repeat(model.mass, 3), float(m.zeta),
         float(m.xi), frames.work, out)
    return out
