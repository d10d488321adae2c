"""Stiffness warping (eq. 10) on the constant clusters: per-vertex rotations, then

    f_i = -R_i sum_j K_ij (R_i^T x_j - x0_j)  -  zeta R_i sum_j K_ij R_i^T v_j  -  xi m_i v_i.

Rotation of vertex i: the least-squares deformation gradient of its cluster neighbourhood
    F_i = [sum_j (x_j - x_i)(x0_j - x0_i)^T] S_i^-1,   S_i = sum_j (x0_j - x0_i)(x0_j - x0_i)^T,
and R_i = polar(F_i) (rigid motion gives F_i = R exactly, at any angle up to 180 deg). The polar factor is
found by scaled Newton iteration X <- (g X + X^-T / g) / 2 (Higham), which starts from F itself, so it
needs no warm start and is exact at 180 deg. When the neighbourhood is inverted or nearly flat
(det F_i <= 1e-3 |F_i|^3 / 3^1.5) the polar factor is a reflection or ill-defined; then Mueller et al.
(2016)'s iteration R <- exp(w) R, w = sum_c r_c x f_c / |sum_c r_c . f_c|, warm-started from the vertex's
previous rotation, gives the nearest proper rotation instead.

Since sum_j K_ij t = 0 for any translation t, the kernel uses x_j - x_i and x0_j - x0_i (fewer round-off
losses): y_j = R_i^T (x_j - x_i + zeta v_j) - (x0_j - x0_i), f_i = -R_i sum_j K_ij y_j - xi m_i v_i.
Damping: the stiffness part is warped like the elastic force (the velocity is rotated into the rest
frame, damped by the constant blocks, rotated back), so a rigid spin is not damped; the mass part
xi M v is rotation invariant and unchanged. Rotations are held fixed within the force: no dR/dx terms.

``warped_force`` and ``vertex_rotations`` are the checked public entries; tests/naive_warping.py holds
the numpy twin.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import prange

from .cluster_force_kernel import cluster_args
from .model import FemModel
from .numba_config import PARALLEL_MIN_VERTICES, SERIAL, serial_and_parallel

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
        if w < 1e-12:
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


@numba.njit(**SERIAL)
def _vertex_rotation(i, k0, k1, cols, rest, s0inv, u, rot, scratch):
    """rot[i] <- R_i from the vertex's cluster neighbourhood (cluster blocks k0..k1)."""
    a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
    for k in range(k0, k1):
        j = cols[k]
        d0 = rest[j, 0] - rest[i, 0]
        d1 = rest[j, 1] - rest[i, 1]
        d2 = rest[j, 2] - rest[i, 2]
        x0 = d0 + u[j, 0] - u[i, 0]
        x1 = d1 + u[j, 1] - u[i, 1]
        x2 = d2 + u[j, 2] - u[i, 2]
        a00 += x0 * d0
        a01 += x0 * d1
        a02 += x0 * d2
        a10 += x1 * d0
        a11 += x1 * d1
        a12 += x1 * d2
        a20 += x2 * d0
        a21 += x2 * d1
        a22 += x2 * d2
    F = scratch[i, 0]
    S = s0inv[i]
    for b in range(3):
        F[0, b] = a00 * S[0, b] + a01 * S[1, b] + a02 * S[2, b]
        F[1, b] = a10 * S[0, b] + a11 * S[1, b] + a12 * S[2, b]
        F[2, b] = a20 * S[0, b] + a21 * S[1, b] + a22 * S[2, b]
    _rotation_of(F, scratch[i, 1], rot[i])


@numba.njit(**SERIAL)
def _vertex_force(i, k0, k1, cols, blocks, rest, u, v, mass, zeta, xi, rot, out):
    """out[i] <- -R_i sum_j K_ij (R_i^T (x_j - x_i + zeta v_j) - (x0_j - x0_i)) - xi m_i v_i."""
    R = rot[i]
    fx = 0.0
    fy = 0.0
    fz = 0.0
    for k in range(k0, k1):
        j = cols[k]
        d0 = rest[j, 0] - rest[i, 0]
        d1 = rest[j, 1] - rest[i, 1]
        d2 = rest[j, 2] - rest[i, 2]
        z0 = d0 + u[j, 0] - u[i, 0] + zeta * v[j, 0]
        z1 = d1 + u[j, 1] - u[i, 1] + zeta * v[j, 1]
        z2 = d2 + u[j, 2] - u[i, 2] + zeta * v[j, 2]
        y0 = R[0, 0] * z0 + R[1, 0] * z1 + R[2, 0] * z2 - d0
        y1 = R[0, 1] * z0 + R[1, 1] * z1 + R[2, 1] * z2 - d1
        y2 = R[0, 2] * z0 + R[1, 2] * z1 + R[2, 2] * z2 - d2
        fx += blocks[k, 0, 0] * y0 + blocks[k, 0, 1] * y1 + blocks[k, 0, 2] * y2
        fy += blocks[k, 1, 0] * y0 + blocks[k, 1, 1] * y1 + blocks[k, 1, 2] * y2
        fz += blocks[k, 2, 0] * y0 + blocks[k, 2, 1] * y1 + blocks[k, 2, 2] * y2
    d = xi * mass[i]
    out[i, 0] = -(R[0, 0] * fx + R[0, 1] * fy + R[0, 2] * fz) - d * v[i, 0]
    out[i, 1] = -(R[1, 0] * fx + R[1, 1] * fy + R[1, 2] * fz) - d * v[i, 1]
    out[i, 2] = -(R[2, 0] * fx + R[2, 1] * fy + R[2, 2] * fz) - d * v[i, 2]


def _warped_force_kernel(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks,
                         rest, s0inv, u, v, mass, zeta, xi, rot, scratch, out):
    for r in prange(sh_rows.shape[0]):
        i = sh_rows[r]
        _vertex_rotation(i, sh_ptr[r], sh_ptr[r + 1], sh_cols, rest, s0inv, u, rot, scratch)
        _vertex_force(i, sh_ptr[r], sh_ptr[r + 1], sh_cols, sh_blocks, rest, u, v, mass, zeta, xi, rot, out)
    for r in prange(bd_rows.shape[0]):
        i = bd_rows[r]
        _vertex_rotation(i, 4 * r, 4 * r + 4, bd_cols, rest, s0inv, u, rot, scratch)
        _vertex_force(i, 4 * r, 4 * r + 4, bd_cols, bd_blocks, rest, u, v, mass, zeta, xi, rot, out)


def _rotation_kernel(sh_rows, sh_ptr, sh_cols, bd_rows, bd_cols, rest, s0inv, u, rot, scratch):
    for r in prange(sh_rows.shape[0]):
        _vertex_rotation(sh_rows[r], sh_ptr[r], sh_ptr[r + 1], sh_cols, rest, s0inv, u, rot, scratch)
    for r in prange(bd_rows.shape[0]):
        _vertex_rotation(bd_rows[r], 4 * r, 4 * r + 4, bd_cols, rest, s0inv, u, rot, scratch)


warped_kernel_serial, warped_kernel_parallel = serial_and_parallel(_warped_force_kernel)
rotation_kernel_serial, rotation_kernel_parallel = serial_and_parallel(_rotation_kernel)


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
    """What warping keeps per model: rest positions, S_i^-1, and each vertex's last rotation (warm start)."""
    rest: np.ndarray        # (n, 3)
    s0inv: np.ndarray       # (n, 3, 3)
    rot: np.ndarray         # (n, 3, 3), updated by every force / rotation call
    scratch: np.ndarray     # (n, 2, 3, 3)

    @classmethod
    def from_model(cls, model: FemModel) -> "VertexFrames":
        n = model.n_vertices
        return cls(np.ascontiguousarray(model.rest), rest_gram_inverse(model),
                   np.repeat(np.eye(3)[None], n, axis=0), np.zeros((n, 2, 3, 3)))

    def kernel_args(self) -> tuple:
        return self.rest, self.s0inv


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
    cl = model.clusters
    kern = _pick(model.n_vertices, threads, rotation_kernel_serial, rotation_kernel_parallel)
    kern(cl.shared_rows, cl.shared_ptr, cl.shared_cols, cl.boundary_rows, cl.boundary_cols,
         frames.rest, frames.s0inv, u, frames.rot, frames.scratch)
    return frames.rot.copy()


def warped_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None, frames: VertexFrames | None = None,
                 out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """Eq. 10 elastic + damping force, (n, 3): -R_i sum_j K_ij (R_i^T x_j - x0_j) - zeta (...) v - xi m v."""
    u, = _check(model, u=u)
    v, = _check(model, v=np.zeros_like(u) if v is None else v)
    frames = VertexFrames.from_model(model) if frames is None else frames
    if out is None:
        out = np.empty((model.n_vertices, 3))
    m = model.material
    kern = _pick(model.n_vertices, threads, warped_kernel_serial, warped_kernel_parallel)
    kern(*cluster_args(model.clusters), frames.rest, frames.s0inv, u, v, model.mass, float(m.zeta), float(m.xi),
         frames.rot, frames.scratch, out)
    return out
