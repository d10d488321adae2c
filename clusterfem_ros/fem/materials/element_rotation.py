"""Element rotations warm-started from the previous call: Newton's method on the rotation, lanes at once.

Per-element warping needs R = polar(F) for every tet at every force. The previous call's rotation R_old is
close: X = R_old^T F has the polar factor Q = R_old^T polar(F), a rotation by the angle the element turned
since (a few mrad per millisecond step of a walking body). Newton's method on that rotation converges in
the angle alone, whatever the strain: the scaled-Newton / Newton-Schulz iteration of fem/materials/polar.py starts
from X and converges in the singular values, so a chunk's most stretched element (20 % and more on the
walking jelly man) set its pass count (3-5); here two passes reach round-off on every chunk of the walk.

One pass, for M = Q_k^T X (Q_0 = I, M_0 = X): Q^T X is symmetric at the polar factor, so solve the
linearised condition skew(exp(-[w]) M) = 0,

    H w = b,   b = axial(skew M) = (M_21 - M_12, M_02 - M_20, M_10 - M_01) / 2,   H = (tr(S) I - S) / 2,  S = sym M,

((tr(S) I - S) / 2 is the derivative of axial(skew([w] M)) up to the skew part of M, which vanishes at the
solution, so the convergence stays quadratic), then Q <- Q C(w), M <- C(w)^T M with the Cayley rotation
C(w) = I + 4 / (4 + |w|^2) ([w] + [w]^2 / 2), orthogonal to round-off and equal to exp([w]) to second order.
A lane has converged when |w|^2 < ROTATION_TOL: the error left after that step is ~|w|^2 / 50 or less (on the
walking jelly man), under the 1.5e-12 the lane iteration of fem/materials/polar.py accepts.

Newton finds any rotation that makes Q^T X symmetric, also the saddles where Q^T X has two negative
eigenvalues; those have an indefinite H, and at the polar factor (Q^T X positive definite) H is positive
definite. So a lane whose H is not positive definite (Sylvester: h00 > 0, the leading 2x2 minor > 0,
det H > 0; false for non-finite values too), an inverted or nearly flat element (det X <= 1e-3 (|X|^2 /
3)^1.5, as fem/materials/polar.py decides), or a chunk that has not converged after ROTATION_MAXPASS passes sends
the whole chunk to the robust path: fem/materials/polar.py's lane iteration from X, its scalar path (Mueller's
iteration from I, which follows one branch through inversion) for the lanes it does not accept. That
happens on a first call far from the previous rotation and on inverted elements, not in smooth motion.

Arrays: a chunk's 3x3 matrices are flat (9 LANES,) arrays, entry k of lane l at k LANES + l (row-major
entries, one lane per element). The stride is a compile-time constant, so LLVM sees that the rows of one
array do not overlap and vectorises every loop over lanes; with (9, lanes) arrays and their run-time row
stride it gave up past 9 rows read (too many run-time overlap checks) and ran them scalar, 3-4x slower.
"""
from __future__ import annotations

import numba
import numpy as np

from ...numba_config import SERIAL
from .polar import chunk_start, lane_accepted, polar_lanes, scalar_rotation

LANES = 64
ROTATION_TOL = 1e-12
ROTATION_MAXPASS = 4


@numba.njit(**SERIAL)
def _fit_for_newton(X) -> int:
    """The lanes of X that Newton must not take: inverted or nearly flat (det X <= 1e-3 (|X|^2/3)^1.5,
    as polar.chunk_start), or not finite."""
    bad = 0
    for l in range(LANES):
        x00, x01, x02 = X[l], X[1 * LANES + l], X[2 * LANES + l]
        x10, x11, x12 = X[3 * LANES + l], X[4 * LANES + l], X[5 * LANES + l]
        x20, x21, x22 = X[6 * LANES + l], X[7 * LANES + l], X[8 * LANES + l]
        det = x00 * (x11 * x22 - x12 * x21) - x01 * (x10 * x22 - x12 * x20) + x02 * (x10 * x21 - x11 * x20)
        nf = (((x00 * x00 + x01 * x01) + (x02 * x02 + x10 * x10)) + ((x11 * x11 + x12 * x12) + (x20 * x20 + x21 * x21))
              + x22 * x22) / 3.0
        if not (det > 0.0 and det * det > 1e-6 * (nf * nf * nf)):
            bad += 1
    return bad


@numba.njit(**SERIAL)
def _newton_pass(M_in, M_out, R_in, R_out):
    """One Newton step of every lane (module docstring): w from M_in, then M_out <- C^T M_in, R_out <- R_in C
    (outputs distinct from the inputs). Returns (lanes not converged, lanes whose H is not positive
    definite)."""
    left = 0
    bad = 0
    for l in range(LANES):
        m00, m01, m02 = M_in[l], M_in[1 * LANES + l], M_in[2 * LANES + l]
        m10, m11, m12 = M_in[3 * LANES + l], M_in[4 * LANES + l], M_in[5 * LANES + l]
        m20, m21, m22 = M_in[6 * LANES + l], M_in[7 * LANES + l], M_in[8 * LANES + l]
        b0 = 0.5 * (m21 - m12)
        b1 = 0.5 * (m02 - m20)
        b2 = 0.5 * (m10 - m01)
        h00, h11, h22 = 0.5 * (m11 + m22), 0.5 * (m00 + m22), 0.5 * (m00 + m11)
        h01, h02, h12 = -0.25 * (m01 + m10), -0.25 * (m02 + m20), -0.25 * (m12 + m21)
        a00 = h11 * h22 - h12 * h12                   # adjugate of H (symmetric)
        a01 = h02 * h12 - h01 * h22
        a02 = h01 * h12 - h02 * h11
        a11 = h00 * h22 - h02 * h02
        a12 = h01 * h02 - h00 * h12
        a22 = h00 * h11 - h01 * h01
        det = h00 * a00 + h01 * a01 + h02 * a02
        if not (h00 > 0.0 and a22 > 0.0 and det > 0.0):
            bad += 1
        inv = 1.0 / det
        w0 = inv * (a00 * b0 + a01 * b1 + a02 * b2)
        w1 = inv * (a01 * b0 + a11 * b1 + a12 * b2)
        w2 = inv * (a02 * b0 + a12 * b1 + a22 * b2)
        ww = w0 * w0 + w1 * w1 + w2 * w2
        if not ww < ROTATION_TOL:
            left += 1
        k = 4.0 / (4.0 + ww)                          # C = I + k ([w] + [w]^2 / 2), [w]^2 = w w^T - |w|^2 I
        h = 0.5 * k
        c00, c11, c22 = 1.0 + h * (w0 * w0 - ww), 1.0 + h * (w1 * w1 - ww), 1.0 + h * (w2 * w2 - ww)
        p01, p02, p12 = h * w0 * w1, h * w0 * w2, h * w1 * w2
        kw0, kw1, kw2 = k * w0, k * w1, k * w2
        c01, c10 = p01 - kw2, p01 + kw2
        c02, c20 = p02 + kw1, p02 - kw1
        c12, c21 = p12 - kw0, p12 + kw0
        M_out[l] = c00 * m00 + c10 * m10 + c20 * m20          # C^T M
        M_out[1 * LANES + l] = c00 * m01 + c10 * m11 + c20 * m21
        M_out[2 * LANES + l] = c00 * m02 + c10 * m12 + c20 * m22
        M_out[3 * LANES + l] = c01 * m00 + c11 * m10 + c21 * m20
        M_out[4 * LANES + l] = c01 * m01 + c11 * m11 + c21 * m21
        M_out[5 * LANES + l] = c01 * m02 + c11 * m12 + c21 * m22
        M_out[6 * LANES + l] = c02 * m00 + c12 * m10 + c22 * m20
        M_out[7 * LANES + l] = c02 * m01 + c12 * m11 + c22 * m21
        M_out[8 * LANES + l] = c02 * m02 + c12 * m12 + c22 * m22
        for a in range(3):                                        # R C
            r0, r1, r2 = R_in[(3 * a) * LANES + l], R_in[(3 * a + 1) * LANES + l], R_in[(3 * a + 2) * LANES + l]
            R_out[(3 * a) * LANES + l] = r0 * c00 + r1 * c10 + r2 * c20
            R_out[(3 * a + 1) * LANES + l] = r0 * c01 + r1 * c11 + r2 * c21
            R_out[(3 * a + 2) * LANES + l] = r0 * c02 + r1 * c12 + r2 * c22
    return left, bad


@numba.njit(**SERIAL)
def _newton_rotations(X, M1, M2, R_old, R1, R2):
    """(True, the buffer R1 or R2 holding R_old polar(X)) by Newton passes, or (False, R1) if the chunk must take
    the robust path (module docstring). The passes alternate between the buffers: a pass in place ran the
    scalar loop (LLVM's run-time check sees the arrays overlap)."""
    if _fit_for_newton(X) > 0:
        return False, R1
    left, bad = _newton_pass(X, M1, R_old, R1)
    k = 1
    while bad == 0 and left > 0 and k < ROTATION_MAXPASS:
        if k % 2 == 1:
            left, bad = _newton_pass(M1, M2, R1, R2)
        else:
            left, bad = _newton_pass(M2, M1, R2, R1)
        k += 1
    return bad == 0 and left == 0, (R1 if k % 2 == 1 else R2)


@numba.njit(**SERIAL)
def _robust_rotations(X, Y, Z, how, tmp, R_old, R):
    """R <- R_old Q, Q the rotation of X from fem/materials/polar.py's lane iteration (start X, or I where inverted or
    flat), its scalar path (Mueller from I) for the lanes it does not accept. tmp: (3, 3, 3) scratch."""
    X, Y, Z = X.reshape((9, LANES)), Y.reshape((9, LANES)), Z.reshape((9, LANES))
    R_old, R = R_old.reshape((9, LANES)), R.reshape((9, LANES))
    chunk_start(LANES, X, Y, how)
    P, converged = polar_lanes(LANES, Y, Z)
    for l in range(LANES):
        q = tmp[2]
        if lane_accepted(l, P, converged, how):
            for a in range(3):
                for b in range(3):
                    q[a, b] = P[3 * a + b, l]
        else:
            for a in range(3):
                for b in range(3):
                    q[a, b] = 1.0 if a == b else 0.0
            scalar_rotation(l, X, tmp, q)
        for a in range(3):
            r0, r1, r2 = R_old[3 * a, l], R_old[3 * a + 1, l], R_old[3 * a + 2, l]
            for b in range(3):
                R[3 * a + b, l] = r0 * q[0, b] + r1 * q[1, b] + r2 * q[2, b]


@numba.njit(**SERIAL)
def chunk_rotations(X, M1, M2, R1, R2, how, tmp, R_old):
    """The element rotations R_old polar(X) of a chunk, X = R_old^T F: Newton passes, or the robust path for
    the chunk. Returns the buffer holding them, R1 or R2; M1, M2: scratch like X; how (LANES,), tmp (3, 3, 3):
    the robust path's."""
    ok, R = _newton_rotations(X, M1, M2, R_old, R1, R2)
    if not ok:
        _robust_rotations(X, M1, M2, how, tmp, R_old, R1)
        return R1
    return R
