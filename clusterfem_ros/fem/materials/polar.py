"""Polar decomposition for the warping and stress passes: the rotation R = polar(F) of a 3x3 deformation
gradient, on LANES gradients at once (chunk_start, polar_lanes, lane_accepted) with a scalar path for the lanes
that the lane iteration does not settle (scalar_rotation).

The polar factor is found by iteration from F itself, so it needs no warm start and is exact at 180 deg:
scaled Newton X <- (g X + X^-T / g) / 2 (Higham) while any lane is far from it, then the division-free
Newton-Schulz X <- X (3 I - X^T X) / 2 (see the constants below for the tolerance and the accuracy it trades).
When F is inverted or nearly flat (det F <= 1e-3 |F|^3 / 3^1.5) the polar factor is a reflection or
ill-defined; then Mueller et al. (2016)'s iteration R <- exp(w) R, w = sum_c r_c x f_c / |sum_c r_c . f_c|,
warm-started from the previous rotation, gives the nearest proper rotation instead.

A caller runs, per chunk of at most LANES gradients F (9, nl): chunk_start (the start X and how each lane goes),
polar_lanes (the iteration on all lanes), then per lane lane_accepted, else scalar_rotation. Used by the
per-vertex warping (warping.py), the per-element warping (element_warping.py) and the stress (stress.py).
Every function is a serial numba build (numba_config.SERIAL) taking arrays and scalars only; nothing is
injected per build.
"""
from __future__ import annotations

import numba
import numpy as np

from ...numba_config import SERIAL

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
def chunk_start(nl, F, X, how):
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
def polar_lanes(nl, X, Y):
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
def lane_accepted(l, P, converged, how):
    """Whether lane l's polar factor P[:, l] is its rotation: the lane started from F (how[l] = 0) and every
    lane converged or this one is orthogonal. Otherwise the scalar path (scalar_rotation) redoes it."""
    return how[l] == 0 and (converged or _orthogonal(P[0, l], P[1, l], P[2, l], P[3, l], P[4, l], P[5, l],
                                                     P[6, l], P[7, l], P[8, l]))


@numba.njit(**SERIAL)
def scalar_rotation(l, F, tmp, R):
    """R <- the scalar _rotation_of of lane l of F (9, nl) (inverted/flat: Mueller, warm-started from R's
    value on entry). tmp: (2, 3, 3) scratch."""
    for a in range(3):
        for b in range(3):
            tmp[0, a, b] = F[3 * a + b, l]
    _rotation_of(tmp[0], tmp[1], R)
