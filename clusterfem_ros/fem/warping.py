"""The paper's per-vertex stiffness warping, kept for comparison (``warping_model = "vertex"``); the default is
per-element corotation (element_warping.py), the gradient of an energy, which this model is not: on an
inverting sliver or a torn vertex at the scene's damping it fed energy in (benchmarks/stability_table.py).

Stiffness warping (eq. 10) on the constant clusters: per-vertex rotations R_i, then, with w = x + zeta v,

    f_i = -sum_j 1/2 (R_i K_ij R_i^T + R_j K_ij R_j^T) (w_j - w_i - R_i (x0_j - x0_i))  -  xi m_i v_i.

Eq. 10 as printed is f_i = -R_i sum_j K_ij (R_i^T x_j - x0_j) = -sum_j R_i K_ij R_i^T (x_j - x_i - R_i (x0_j - x0_i))
(sum_j K_ij = 0): the same, with the block R_i K_ij R_i^T where we use its mean with R_j K_ij R_j^T. Why:
with the rotations held, eq. 10's force is linear in x with Jacobian blocks R_i K_ij R_i^T, and block
(j, i) = R_j K_ij^T R_j^T is not the transpose of block (i, j) once R_i != R_j. A non-symmetric stiffness
is not the gradient of any energy: it circulates energy (flutter). Where neighbouring rotations differ a
lot, as around a held vertex torn 0.5 m from its neighbours, eq. 10 gained energy: 1.3-3.1x the work put
in on the stability table's bar, growing exponentially with the rotations frozen. With the mean blocks,
block (j, i) of the held-rotation Jacobian is the transpose of block (i, j); what stays non-symmetric is
each vertex's own diagonal block, -sum_j of its row's others (K_ij is not symmetric, so the R_j halves do
not sum to a symmetric block). In the torn state that skew part was 0.24 % of the Jacobian's norm against
eq. 10's 4.1 % (largest imaginary eigenvalue part 340x smaller), and the case settles (max E / budget
0.93; benchmarks/stability_table.py, tests/test_hard_cases.py). Exact symmetry and translation invariance
together need one rotation per element (fem/corotational.py). What stays exactly as in eq. 10: the same
constant clusters and per-vertex rotations; zero force for any rigid motion (all R_i equal: the two halves
coincide with eq. 10); linear FEM to second order for small deformations (the first-order part of
w_j - w_i - R_i d_ij is the linear one for every block of the row, since R_i is the row's); translation
invariance. Cost: six 3x3 matrix-vector products per block instead of two, and a rotation gather.
Stiffness damping uses the same symmetric blocks on the velocity differences (a rigid spin is not
damped); xi M v is unchanged.
Rotations are held fixed within the force: no dR/dx terms.

Rotation of vertex i: the least-squares deformation gradient of its cluster neighbourhood
    F_i = [sum_j (x_j - x_i)(x0_j - x0_i)^T] S_i^-1,   S_i = sum_j (x0_j - x0_i)(x0_j - x0_i)^T,
and R_i = polar(F_i) (rigid motion gives F_i = R exactly, at any angle up to 180 deg). The kernel evaluates
F_i = I + sum_j (u_j - u_i) g_j^T with the constant g_j = S_i^-1 (x0_j - x0_i) stored per block of the
cluster slices (warped_force_kernel.py).
The polar factor is found by iteration from F itself, so it needs no warm start and is exact at 180 deg:
scaled Newton X <- (g X + X^-T / g) / 2 (Higham) while any vertex is far from it, then the division-free
Newton-Schulz X <- X (3 I - X^T X) / 2; both run on LANES vertices at once (see the constants below for
the tolerance and the accuracy it trades). When the neighbourhood is inverted or nearly flat
(det F_i <= 1e-3 |F_i|^3 / 3^1.5) the polar factor is a reflection or ill-defined; then Mueller et al.
(2016)'s iteration R <- exp(w) R, w = sum_c r_c x f_c / |sum_c r_c . f_c|, warm-started from the vertex's
previous rotation, gives the nearest proper rotation instead.

The kernel makes two passes: all rotations (a row's force reads its neighbours'), then the forces, over the
linear kernel's slices (warped_force_kernel.py): per block y = R_i^T (w_j - w_i) - d_ij (so the bracket is
R_i y); the R_i half is R_i sum_j K_ij y, the row's rotation applied once after the loop; the R_j half is
sum_j R_j (K_ij (R_j^T (R_i y))).

``warped_force`` and ``vertex_rotations`` are the checked public entries; tests/naive_warping.py holds
the numpy twin. ``_lane_accepted`` and ``_scalar_rotation`` (accept a lane's polar factor, or redo it) are
also used by fem/stress.py.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp
from numba import prange

from .cluster_force_kernel import (finish_parallel, finish_serial, input_rows, kernel_input_parallel,
                                   kernel_input_serial)
from .cluster_slices import ClusterSlices, aligned_zeros, lane_vertices, position_lanes, rest_offsets
from .model import FemModel
from .numba_config import PARALLEL_MIN_VERTICES, SERIAL, compiled, serial_and_parallel
from .warped_force_kernel import (ROT_ROW, copy_rows_parallel, copy_rows_serial, gradient_sweep_parallel,
                                  gradient_sweep_serial, warped_sweep_parallel, warped_sweep_serial)

NEWTON_MAXIT = 40
MUELLER_MAXIT = 200


@numba.njit(**SERIAL)
def _polar_newton(X) -> bool:
    """X <- orthogonal polar factor of X in place (det X > 0). False if it did not converge."""
    for _ in range(NEWTON_MAXIT):
        c00 = X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1]
        c01 = X[1, 2] * X[2, 0] - X[1, 0] * X[2, 2]
        c02 = X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]
        c10 = X[0, 2] * X[2, 1] - X[0, 1] * X[2, 2]
        c11 = X[0, 0] * X[2, 2] - X[0, 2] * X[2, 0]
        c12 = X[0, 1] * X[2, 0] - X[0, 0] * X[2, 1]
        c20 = X[0, 1] * X[1, 2] - X[0, 2] * X[1, 1]
        c21 = X[0, 2] * X[1, 0] - X[0, 0] * X[1, 2]
        c22 = X[0, 0] * X[1, 1] - X[0, 1] * X[1, 0]
        det = X[0, 0] * c00 + X[0, 1] * c01 + X[0, 2] * c02
        nx = 0.0
        for a in range(3):
            for b in range(3):
                nx += X[a, b] * X[a, b]
        nc = (c00 * c00 + c01 * c01 + c02 * c02 + c10 * c10 + c11 * c11 + c12 * c12
              + c20 * c20 + c21 * c21 + c22 * c22) / (det * det)
        g = np.sqrt(np.sqrt(nc / nx))           # Frobenius scaling: |X| and |X^-T| balanced
        s = 0.5 / (g * det)
        cof = (c00, c01, c02, c10, c11, c12, c20, c21, c22)
        diff = 0.0
        for a in range(3):
            for b in range(3):
                new = 0.5 * g * X[a, b] + s * cof[3 * a + b]
                d = new - X[a, b]
                diff += d * d
                X[a, b] = new
        if diff < 1e-26:                        # quadratic convergence: the error left is ~diff
            return True
    return False


@numba.njit(**SERIAL)
def _rotation_mueller(F, R):
    """R <- the rotation that locally maximises tr(R^T F), iterating from the R given (Mueller 2016)."""
    for _ in range(MUELLER_MAXIT):
        wx = 0.0
        wy = 0.0
        wz = 0.0
        dot = 0.0
        for c in range(3):                      # columns r_c of R and f_c of F
            wx += R[1, c] * F[2, c] - R[2, c] * F[1, c]
            wy += R[2, c] * F[0, c] - R[0, c] * F[2, c]
            wz += R[0, c] * F[1, c] - R[1, c] * F[0, c]
            dot += R[0, c] * F[0, c] + R[1, c] * F[1, c] + R[2, c] * F[2, c]
        s = 1.0 / (abs(dot) + 1e-9)
        wx *= s
        wy *= s
        wz *= s
        w = np.sqrt(wx * wx + wy * wy + wz * wz)
        if not w >= 1e-12:                      # converged, or F is not finite (a diverged state): stop
            return
        kx, ky, kz = wx / w, wy / w, wz / w
        sn, cs = np.sin(w), np.cos(w)
        t = 1.0 - cs
        q00, q01, q02 = cs + t * kx * kx, t * kx * ky - sn * kz, t * kx * kz + sn * ky
        q10, q11, q12 = t * kx * ky + sn * kz, cs + t * ky * ky, t * ky * kz - sn * kx
        q20, q21, q22 = t * kx * kz - sn * ky, t * ky * kz + sn * kx, cs + t * kz * kz
        for c in range(3):                      # R <- Q R
            r0, r1, r2 = R[0, c], R[1, c], R[2, c]
            R[0, c] = q00 * r0 + q01 * r1 + q02 * r2
            R[1, c] = q10 * r0 + q11 * r1 + q12 * r2
            R[2, c] = q20 * r0 + q21 * r1 + q22 * r2


@numba.njit(**SERIAL)
def _rotation_of(F, X, R):
    """R <- rotation of the deformation F (R holds the previous rotation: the fallback's warm start)."""
    det = (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
           + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))
    nf = 0.0
    for a in range(3):
        for b in range(3):
            nf += F[a, b] * F[a, b]
    if det > 1e-3 * (nf / 3.0) ** 1.5:
        for a in range(3):
            for b in range(3):
                X[a, b] = F[a, b]
        if _polar_newton(X):
            for a in range(3):
                for b in range(3):
                    R[a, b] = X[a, b]
            return
    _rotation_mueller(F, R)


# One chunk of LANES lanes of the deformation gradients (in slice order, from the gradient sweep:
# warped_force_kernel.py) is the polar iteration's unit of work: its iterates, (2, 9, LANES) doubles = 18 KiB,
# stay in L1, and the iteration runs on all lanes at once (no data-dependent exit inside a lane loop, so it is
# vectorised and the long latency chain of one 3x3 polar step overlaps across vertices). Chunks are
# independent, so the threaded build runs them in parallel.
LANES = 128
# A lane has converged when the squared Frobenius change of its last polar step is below POLAR_TOL. Both
# iterations used converge quadratically: near the polar factor a step that changes X by delta leaves an
# error of about delta^2 / 2 (Newton) or 3 delta^2 / 2 (Newton-Schulz), so |R - polar(F)|_F <~ 1.5e-12 here
# (tests/test_warping.py checks 1e-11 against the SVD). That is the accuracy traded: the elastic force
# changes by ~|K| |x_j - x_i| 1.5e-12, ~1e-10 of the force at 1 % strain; a rigid motion (F = R exactly)
# still converges in one step to round-off. 1e-16 would cost one more pass for most vertices of a walking
# body (~45 -> ~54 ns per vertex on the jelly man).
# The passes stop when every lane has converged. If a chunk hits POLAR_MAXPASS first (or has a non-finite
# lane), each lane is accepted only if it is orthogonal, |X^T X - I|_F^2 < ORTHO_TOL (X = U S V^T all along,
# so |X - U V^T| ~ |X^T X - I| / 2 <= 5e-12); the others take the scalar path.
POLAR_TOL = 1e-12
ORTHO_TOL = 1e-22
# Scaled Newton until every lane's squared change is below SCHULZ_FROM (singular values within ~0.1 of 1),
# then the division-free Newton-Schulz step X <- X (3 I - X^T X) / 2, which converges for singular values
# in (0, sqrt 3). A lane that does not converge in POLAR_MAXPASS passes is redone by the scalar path.
SCHULZ_FROM = 1e-2
POLAR_MAXPASS = 40


@numba.njit(**SERIAL)
def _chunk_start(nl, F, X, how):
    """X[:, l] <- the polar iteration's start for lane l of the chunk's deformation gradients F (9, nl): F
    itself, or I when the neighbourhood is inverted or nearly flat (how[l] = 1: the Mueller fallback's)."""
    for l in range(nl):
        f00, a01, a02 = F[0, l], F[1, l], F[2, l]
        a10, f11, a12 = F[3, l], F[4, l], F[5, l]
        a20, a21, f22 = F[6, l], F[7, l], F[8, l]
        det = (f00 * (f11 * f22 - a12 * a21) - a01 * (a10 * f22 - a12 * a20) + a02 * (a10 * a21 - f11 * a20))
        nf = (((f00 * f00 + a01 * a01) + (a02 * a02 + a10 * a10)) + ((f11 * f11 + a12 * a12) + (a20 * a20 + a21 * a21))
              + f22 * f22) / 3.0
        if det > 0.0 and det * det > 1e-6 * (nf * nf * nf):       # det > 1e-3 (|F|^2 / 3)^1.5, as _rotation_of
            how[l] = 0
            for a in range(9):
                X[a, l] = F[a, l]
        else:
            how[l] = 1
            for a in range(9):
                X[a, l] = 1.0 if a % 4 == 0 else 0.0


@numba.njit(**SERIAL)
def _store_iterate(dst, l, old, new):
    """dst[:, l] <- new (a 3x3 iterate's 9 entries, row-major); returns |new - old|_F^2, the convergence
    measure of both polar steps below. Inlined into their lane loops, which stay vectorised."""
    e0, e1, e2 = new[0] - old[0], new[1] - old[1], new[2] - old[2]
    e3, e4, e5 = new[3] - old[3], new[4] - old[4], new[5] - old[5]
    e6, e7, e8 = new[6] - old[6], new[7] - old[7], new[8] - old[8]
    for k in range(9):
        dst[k, l] = new[k]
    return ((e0 * e0 + e1 * e1) + (e2 * e2 + e3 * e3)) + ((e4 * e4 + e5 * e5) + (e6 * e6 + e7 * e7)) + e8 * e8


@numba.njit(**SERIAL)
def _newton_lanes(nl, src, dst):
    """dst <- one scaled Newton step (g X + X^-T / g) / 2 of every lane of src. Returns the number of lanes
    whose squared change is not below SCHULZ_FROM, and not below POLAR_TOL (loop kept vectorisable: counts
    only, no per-lane stores besides dst)."""
    big = 0
    left = 0
    for l in range(nl):
        x00, x01, x02 = src[0, l], src[1, l], src[2, l]
        x10, x11, x12 = src[3, l], src[4, l], src[5, l]
        x20, x21, x22 = src[6, l], src[7, l], src[8, l]
        c00 = x11 * x22 - x12 * x21
        c01 = x12 * x20 - x10 * x22
        c02 = x10 * x21 - x11 * x20
        c10 = x02 * x21 - x01 * x22
        c11 = x00 * x22 - x02 * x20
        c12 = x01 * x20 - x00 * x21
        c20 = x01 * x12 - x02 * x11
        c21 = x02 * x10 - x00 * x12
        c22 = x00 * x11 - x01 * x10
        det = x00 * c00 + x01 * c01 + x02 * c02
        nx = (((x00 * x00 + x01 * x01) + (x02 * x02 + x10 * x10)) + ((x11 * x11 + x12 * x12) + (x20 * x20 + x21 * x21))
              + x22 * x22)
        nc = (((c00 * c00 + c01 * c01) + (c02 * c02 + c10 * c10)) + ((c11 * c11 + c12 * c12) + (c20 * c20 + c21 * c21))
              + c22 * c22)
        g = np.sqrt(np.sqrt(nc / nx) / abs(det))     # Frobenius scaling: |g X| = |X^-T / g|
        a = 0.5 * g
        s = 0.5 / (g * det)
        n00 = a * x00 + s * c00
        n01 = a * x01 + s * c01
        n02 = a * x02 + s * c02
        n10 = a * x10 + s * c10
        n11 = a * x11 + s * c11
        n12 = a * x12 + s * c12
        n20 = a * x20 + s * c20
        n21 = a * x21 + s * c21
        n22 = a * x22 + s * c22
        diff = _store_iterate(dst, l, (x00, x01, x02, x10, x11, x12, x20, x21, x22),
                              (n00, n01, n02, n10, n11, n12, n20, n21, n22))
        if not diff < SCHULZ_FROM:
            big += 1
        if not diff < POLAR_TOL:
            left += 1
    return big, left


@numba.njit(**SERIAL)
def _schulz_lanes(nl, src, dst):
    """dst <- one Newton-Schulz step X (3 I - X^T X) / 2 of every lane; returns the lanes not converged."""
    left = 0
    for l in range(nl):
        x00, x01, x02 = src[0, l], src[1, l], src[2, l]
        x10, x11, x12 = src[3, l], src[4, l], src[5, l]
        x20, x21, x22 = src[6, l], src[7, l], src[8, l]
        p00 = 1.5 - 0.5 * (x00 * x00 + x10 * x10 + x20 * x20)       # T = (3 I - X^T X) / 2, symmetric
        p11 = 1.5 - 0.5 * (x01 * x01 + x11 * x11 + x21 * x21)
        p22 = 1.5 - 0.5 * (x02 * x02 + x12 * x12 + x22 * x22)
        p01 = -0.5 * (x00 * x01 + x10 * x11 + x20 * x21)
        p02 = -0.5 * (x00 * x02 + x10 * x12 + x20 * x22)
        p12 = -0.5 * (x01 * x02 + x11 * x12 + x21 * x22)
        n00 = x00 * p00 + x01 * p01 + x02 * p02
        n01 = x00 * p01 + x01 * p11 + x02 * p12
        n02 = x00 * p02 + x01 * p12 + x02 * p22
        n10 = x10 * p00 + x11 * p01 + x12 * p02
        n11 = x10 * p01 + x11 * p11 + x12 * p12
        n12 = x10 * p02 + x11 * p12 + x12 * p22
        n20 = x20 * p00 + x21 * p01 + x22 * p02
        n21 = x20 * p01 + x21 * p11 + x22 * p12
        n22 = x20 * p02 + x21 * p12 + x22 * p22
        diff = _store_iterate(dst, l, (x00, x01, x02, x10, x11, x12, x20, x21, x22),
                              (n00, n01, n02, n10, n11, n12, n20, n21, n22))
        if not diff < POLAR_TOL:
            left += 1
    return left


@numba.njit(**SERIAL)
def _polar_lanes(nl, X, Y):
    """Polar factors of lanes 0..nl of X (every det > 0): (the buffer, X or Y, holding them, whether every
    lane converged)."""
    src, dst = X, Y
    scaled = True
    for _ in range(POLAR_MAXPASS):
        if scaled:
            big, left = _newton_lanes(nl, src, dst)
            scaled = big > 0
        else:
            left = _schulz_lanes(nl, src, dst)
        src, dst = dst, src
        if left == 0:
            return src, True
    return src, False


@numba.njit(**SERIAL)
def _orthogonal(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """|R^T R - I|_F^2 < ORTHO_TOL (False for non-finite R)."""
    q00 = r00 * r00 + r10 * r10 + r20 * r20 - 1.0
    q11 = r01 * r01 + r11 * r11 + r21 * r21 - 1.0
    q22 = r02 * r02 + r12 * r12 + r22 * r22 - 1.0
    q01 = r00 * r01 + r10 * r11 + r20 * r21
    q02 = r00 * r02 + r10 * r12 + r20 * r22
    q12 = r01 * r02 + r11 * r12 + r21 * r22
    return (q00 * q00 + q11 * q11 + q22 * q22) + 2.0 * (q01 * q01 + q02 * q02 + q12 * q12) < ORTHO_TOL


@numba.njit(**SERIAL)
def _lane_accepted(l, P, converged, how):
    """Whether lane l's polar factor P[:, l] is its rotation: the lane started from F (how[l] = 0) and every
    lane converged or this one is orthogonal. Otherwise the scalar path (_scalar_rotation) redoes it."""
    return how[l] == 0 and (converged or _orthogonal(P[0, l], P[1, l], P[2, l], P[3, l], P[4, l], P[5, l],
                                                     P[6, l], P[7, l], P[8, l]))


@numba.njit(**SERIAL)
def _scalar_rotation(l, F, tmp, R):
    """R <- the scalar _rotation_of of lane l of F (9, nl) (inverted/flat: Mueller, warm-started from R's
    value on entry). tmp: (2, 3, 3) scratch."""
    for a in range(3):
        for b in range(3):
            tmp[0, a, b] = F[3 * a + b, l]
    _rotation_of(tmp[0], tmp[1], R)


@numba.njit(**SERIAL)
def _chunk_rotations(k0, nl, owner, F, P, converged, how, tmp, rot, rot4):
    """rot[i] and rot4[i] (i = owner[k0 + l], skipped past the n vertices: padding lanes) <- lane l's polar
    factor P[:, l] if accepted, else the scalar path's, warm-started from the vertex's previous rotation."""
    n = rot.shape[0]
    for l in range(nl):
        i = owner[k0 + l]
        if i >= n:
            continue
        if _lane_accepted(l, P, converged, how):
            for a in range(3):
                for b in range(3):
                    rot[i, a, b] = P[3 * a + b, l]
        else:
            _scalar_rotation(l, F, tmp, rot[i])
        for a in range(3):
            for b in range(3):
                rot4[i, 4 * a + b] = rot[i, a, b]


@numba.njit(**SERIAL)
def _rotate_chunk(c, owner, F, rot, rot4, scratch, how, tmp):
    """Chunk c's vertex rotations: lanes c LANES.. of F (slice order), polar iteration on all lanes, stored."""
    k0 = c * LANES
    nl = min(LANES, F.shape[1] - k0)
    Fc = F[:, k0:k0 + nl]
    buf = scratch[c]
    _chunk_start(nl, Fc, buf[0], how[c])
    P, converged = _polar_lanes(nl, buf[0], buf[1])
    _chunk_rotations(k0, nl, owner, Fc, P, converged, how[c], tmp[c], rot, rot4)


# The warped kernels, one source each, serial and threaded builds. The globals ``gradient_sweep``,
# ``copy_rows``, ``rotations``, ``sweep``, ``kernel_input``, ``warped_e`` and ``finish`` are bound per build
# (numba_config.compiled).
# Argument groups (VertexFrames): ``gradients`` and ``slices``, the two sweeps' slice arrays; ``work``, the
# workspace (rot, rot4, u_rows, F, scratch, how, tmp, e).

def _rotations(gradients, u, work):
    """rot, rot4 <- the vertex rotations of u: the gradient sweep, then the polar iteration by chunks."""
    rot, rot4, u_rows, F, scratch, how, tmp, _ = work
    sh_ptr, shared, boundary, lane_vertex, owner = gradients
    copy_rows(u, u_rows)  # noqa: F821 (bound)
    gradient_sweep(sh_ptr, shared, boundary, (u_rows, lane_vertex, F))  # noqa: F821
    for c in prange(scratch.shape[0]):
        _rotate_chunk(c, owner, F, rot, rot4, scratch, how, tmp)


def _warped_e(gradients, slices, u, w, work):
    """e <- the elastic-damping part of the warped force of w = x0 + u + zeta v (warped_force_kernel.py), in
    rows by vertex (the padding lanes' rows after the n vertices'); rot <- the vertex rotations of u. Every
    rotation first (a row reads its neighbours'), then the sweep."""
    rotations(gradients, u, work)  # noqa: F821 (bound)
    sh_ptr, shared, boundary, lane_vertex, owner = slices
    sweep(sh_ptr, shared, boundary, (w, work[1], lane_vertex, owner, work[7]))  # noqa: F821


def _warped_force(gradients, slices, rest, u, v, w, mass3, zeta, xi, work, out):
    """out <- the warped force of (u, v), f = -e - xi M v (mass3: the lumped mass per coordinate)."""
    kernel_input(u.shape[0], zeta, rest, u, v, w, True)  # noqa: F821 (bound)
    warped_e(gradients, slices, u, w, work)  # noqa: F821
    finish(work[7], v, mass3, xi, out)  # noqa: F821


rotation_kernel_serial, rotation_kernel_parallel = serial_and_parallel(
    _rotations, serial={"gradient_sweep": gradient_sweep_serial, "copy_rows": copy_rows_serial},
    parallel={"gradient_sweep": gradient_sweep_parallel, "copy_rows": copy_rows_parallel})
# no loop of their own: their callees carry the threads
warped_e_serial = compiled(_warped_e, rotations=rotation_kernel_serial, sweep=warped_sweep_serial)
warped_e_parallel = compiled(_warped_e, "_parallel", rotations=rotation_kernel_parallel, sweep=warped_sweep_parallel)
warped_kernel_serial = compiled(_warped_force, kernel_input=kernel_input_serial, warped_e=warped_e_serial,
                                finish=finish_serial)
warped_kernel_parallel = compiled(_warped_force, "_parallel", kernel_input=kernel_input_parallel,
                                  warped_e=warped_e_parallel, finish=finish_parallel)


def rest_gram_inverse(model: FemModel) -> np.ndarray:
    """S_i^-1, (n, 3, 3): inverse of sum_j (x0_j - x0_i)(x0_j - x0_i)^T over each vertex's cluster."""
    ptr, cols = model.clusters.neighbours()
    rows = np.repeat(np.arange(model.n_vertices), np.diff(ptr))
    d = model.rest[cols] - model.rest[rows]
    S = np.zeros((model.n_vertices, 3, 3))
    np.add.at(S, rows, d[:, :, None] * d[:, None, :])
    det = np.linalg.det(S)
    scale = np.einsum("nii->n", S) ** 3
    bad = np.flatnonzero(~(det > 1e-12 * scale))
    if bad.size:
        raise ValueError(f"vertex {bad[0]}'s cluster neighbours are coplanar (det S = {det[bad[0]]:.3g}): "
                         "its rotation is undefined; fix the mesh (every vertex needs a non-flat tet)")
    return np.linalg.inv(S)


@dataclass
class VertexFrames:
    """What warping keeps per model: rest positions, S_i^-1, each vertex's last rotation (the fallback's
    warm start), the kernels' argument groups over the cluster slices (cluster_slices.py) and workspace."""
    rest: np.ndarray        # (n, 3)
    s0inv: np.ndarray       # (n, 3, 3)
    rot: np.ndarray         # (n, 3, 3), updated by every force / rotation call
    gradients: tuple        # the gradient sweep's: (sh_ptr, (sh_w_at, sh_grads), (bd_w_at, bd_grads), lane_vertex,
                            #   owner); g = S_i^-1 (x0_j - x0_i) per block, (P, 3, C)
    slices: tuple           # the force sweep's: (sh_ptr, (sh_w_at, sh_blocks, sh_offsets), (bd_w_at, bd_blocks,
                            #   bd_offsets), lane_vertex, owner); offsets d = x0_j - x0_i per block, (P, 3, C)
    w: np.ndarray           # (lanes + 1, 3) workspace: x + zeta v in the first n rows (input_rows)
    rot4: np.ndarray        # (n, 12) workspace: the rotations' rows padded to 4
    u_rows: np.ndarray      # (lanes + 1, 3) workspace: u in the first n rows (input_rows)
    F: np.ndarray           # (9, n_slices * C) workspace: deformation gradient per lane, slice order
    scratch: np.ndarray     # (chunks, 2, 9, LANES) workspace: polar iterates
    how: np.ndarray         # (chunks, LANES) workspace: 0 polar, 1 inverted/flat
    tmp: np.ndarray         # (chunks, 2, 3, 3) workspace of the scalar fallback
    e: np.ndarray           # (n_slices * C, 3) workspace: the force sweep's rows (vertex i's in row i)

    @classmethod
    def from_model(cls, model: FemModel, slices: ClusterSlices | None = None) -> "VertexFrames":
        """``slices``: the cluster slices to walk (default the model's, as wide as this host's vectors)."""
        n = model.n_vertices
        sl = model.clusters.slices if slices is None else slices
        lanes = len(sl.owner)
        chunks = -(-lanes // LANES)
        rest = np.ascontiguousarray(model.rest, dtype=np.float64)
        s0inv = rest_gram_inverse(model)
        lane_vertex = lane_vertices(sl)
        offsets = rest_offsets(sl, rest)
        grads = []
        for d, own in zip(offsets, position_lanes(sl)):       # g = S_i^-1 d per entry; zero where d is
            g = aligned_zeros(d.shape)
            g[...] = np.einsum("pcab,pbc->pac", s0inv[own], d)
            grads.append(g)
        gradients = (sl.shared_ptr, (sl.shared_w_at, grads[0]), (sl.boundary_w_at, grads[1]), lane_vertex, sl.owner)
        slices = (sl.shared_ptr, (sl.shared_w_at, sl.shared_blocks, offsets[0]),
                  (sl.boundary_w_at, sl.boundary_blocks, offsets[1]), lane_vertex, sl.owner)
        return cls(rest, s0inv, np.repeat(np.eye(3)[None], n, axis=0), gradients, slices,
                   input_rows(sl), aligned_zeros((n, ROT_ROW)), input_rows(sl), aligned_zeros((9, lanes)),
                   np.zeros((chunks, 2, 9, LANES)), np.zeros((chunks, LANES), dtype=np.int8),
                   np.zeros((chunks, 2, 3, 3)), np.zeros((lanes, 3)))

    @property
    def work(self) -> tuple:
        """The kernels' workspace group: (rot, rot4, u_rows, F, scratch, how, tmp, e)."""
        return self.rot, self.rot4, self.u_rows, self.F, self.scratch, self.how, self.tmp, self.e


class AssembledWarp:
    """The warped blocks on the assembled block-sparse K, for the standard (reference) methods: the same force
    as the cluster kernel, written with sparse matrices. With J_ij = (R_i K_ij R_i^T + R_j K_ij R_j^T) / 2,
    ``jacobian`` is H, the force's Jacobian with the rotations held (off-diagonal blocks J_ij, each diagonal
    block minus its row's others: H t = 0 for every translation t), and
        f_i = -sum_j J_ij (w_j - w_i - R_i d_ij) = -(H w)_i + (Q x0)_i - (sum_j Q_ij) x0_i,  Q_ij = J_ij R_i."""

    def __init__(self, model: FemModel):
        self.model = model
        self.Kb = model.K.tobsr(blocksize=(3, 3))
        self.Kb.sort_indices()
        self.row = np.repeat(np.arange(model.n_vertices), np.diff(self.Kb.indptr))
        self.diagonal = self.Kb.indices == self.row

    def matrix(self, blocks: np.ndarray) -> sp.csr_matrix:
        Kb = self.Kb
        return sp.bsr_matrix((blocks, Kb.indices, Kb.indptr), shape=Kb.shape).tocsr()

    def _row_sums(self, blocks: np.ndarray) -> np.ndarray:
        out = np.zeros((self.model.n_vertices, 3, 3))
        np.add.at(out, self.row, blocks)
        return out

    def mean_blocks(self, R: np.ndarray) -> np.ndarray:
        """J_ij for every block of K, (nb, 3, 3)."""
        Ri, Rj = R[self.row], R[self.Kb.indices]
        K = self.Kb.data
        return 0.5 * (Ri @ K @ np.swapaxes(Ri, 1, 2) + Rj @ K @ np.swapaxes(Rj, 1, 2))

    def jacobian(self, R: np.ndarray, J: np.ndarray | None = None) -> sp.csr_matrix:
        """H (see the class docstring), from J = mean_blocks(R) when given."""
        H = self.mean_blocks(R) if J is None else J.copy()
        H[self.diagonal] -= self._row_sums(H)[self.row[self.diagonal]]
        return self.matrix(H)

    def rotated(self, R: np.ndarray) -> sp.csr_matrix:
        """R K R^T, blocks R_i K_ij R_j^T: symmetric positive semi-definite, not translation invariant."""
        return self.matrix(R[self.row] @ self.Kb.data @ np.swapaxes(R[self.Kb.indices], 1, 2))

    def force(self, R: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The warped elastic + damping force, (n, 3), with w = x0 + u + zeta v; then - xi M v."""
        m = self.model.material
        x0 = self.model.rest
        w = (x0 + u + m.zeta * v).reshape(-1)
        J = self.mean_blocks(R)
        Q = J @ R[self.row]
        f = (-(self.jacobian(R, J) @ w) + self.matrix(Q) @ x0.reshape(-1)).reshape(-1, 3)
        f -= np.einsum("nij,nj->ni", self._row_sums(Q), x0)
        return f - m.xi * self.model.mass[:, None] * v


def output_rows(n: int, out: np.ndarray | None) -> np.ndarray:
    """``out`` checked as a force's (n, 3) C-contiguous float64 destination, or a new one."""
    if out is None:
        return np.empty((n, 3))
    if out.shape != (n, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous ({n}, 3) float64 array, got {out.dtype} {out.shape}")
    return out


def _pick(n: int, threads: bool | None, serial, parallel):
    use = n >= PARALLEL_MIN_VERTICES if threads is None else threads
    return parallel if use else serial


def _check(model: FemModel, **arrays) -> list[np.ndarray]:
    out = []
    for name, a in arrays.items():
        a = np.ascontiguousarray(a, dtype=np.float64)
        if a.shape != (model.n_vertices, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({model.n_vertices}, 3) for this mesh")
        if not np.isfinite(a).all():
            raise ValueError(f"{name} has non-finite entries: the state diverged; reset it before warping")
        out.append(a)
    return out


def vertex_rotations(model: FemModel, u: np.ndarray, frames: VertexFrames | None = None,
                     threads: bool | None = None) -> np.ndarray:
    """R_i for every vertex, (n, 3, 3), of the displacement u (n, 3)."""
    (u,) = _check(model, u=u)
    frames = VertexFrames.from_model(model) if frames is None else frames
    kern = _pick(model.n_vertices, threads, rotation_kernel_serial, rotation_kernel_parallel)
    kern(frames.gradients, u, frames.work)
    return frames.rot.copy()


def warped_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None, frames: VertexFrames | None = None,
                 out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """Warped elastic + damping force, (n, 3): eq. 10 with symmetric blocks (module docstring)."""
    u, = _check(model, u=u)
    v, = _check(model, v=np.zeros_like(u) if v is None else v)
    frames = VertexFrames.from_model(model) if frames is None else frames
    n = model.n_vertices
    out = output_rows(n, out)
    kern = _pick(n, threads, warped_kernel_serial, warped_kernel_parallel)
    m = model.material
    kern(frames.gradients, frames.slices, frames.rest, u, v, frames.w, np.repeat(model.mass, 3), float(m.zeta),
         float(m.xi), frames.work, out)
    return out
