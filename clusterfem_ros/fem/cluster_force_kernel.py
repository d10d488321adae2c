"""The clustered elastic-damping force, one fused numba pass (eqs. 4-6).

    f = -D v - K u = -K (u + zeta v) - xi M v          (D = xi M + zeta K)

so one sweep over the K clusters serves both matrices: f_i = f_s + f_b, the shared clusters'
contribution plus the boundary clusters'. ``clustered_force`` is the checked public entry; the
``_`` kernels take arrays and scalars only. tests/naive.py holds the plain numpy twin.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import prange

from .clusters import Clusters
from .numba_config import PARALLEL_MIN_VERTICES, SERIAL, serial_and_parallel


@numba.njit(**SERIAL)
def _row_force(i, k0, k1, cols, blocks, w, v, mass, xi, out):
    """out[i] <- -sum_k blocks[k] w[cols[k]] - xi m_i v_i over the cluster blocks k0..k1 of vertex i."""
    fx = 0.0
    fy = 0.0
    fz = 0.0
    for k in range(k0, k1):
        j = cols[k]
        wx = w[j, 0]
        wy = w[j, 1]
        wz = w[j, 2]
        fx += blocks[k, 0, 0] * wx + blocks[k, 0, 1] * wy + blocks[k, 0, 2] * wz
        fy += blocks[k, 1, 0] * wx + blocks[k, 1, 1] * wy + blocks[k, 1, 2] * wz
        fz += blocks[k, 2, 0] * wx + blocks[k, 2, 1] * wy + blocks[k, 2, 2] * wz
    d = xi * mass[i]
    out[i, 0] = -fx - d * v[i, 0]
    out[i, 1] = -fy - d * v[i, 1]
    out[i, 2] = -fz - d * v[i, 2]


def _force_rows_kernel(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks, w, v, mass, xi, out):
    """out <- -K w - xi M v from the clusters, w = u + zeta v given: shared rows, then boundary rows, in
    one loop (one parallel region in the threaded build)."""
    ns = sh_rows.shape[0]
    for r in prange(ns + bd_rows.shape[0]):
        if r < ns:
            _row_force(sh_rows[r], sh_ptr[r], sh_ptr[r + 1], sh_cols, sh_blocks, w, v, mass, xi, out)
        else:
            b = r - ns
            _row_force(bd_rows[b], 4 * b, 4 * b + 4, bd_cols, bd_blocks, w, v, mass, xi, out)


def _force_kernel(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks,
                  u, v, mass, zeta, xi, w, out):
    n = u.shape[0]
    for i in prange(n):
        for c in range(3):
            w[i, c] = u[i, c] + zeta * v[i, c]
    ns = sh_rows.shape[0]
    for r in prange(ns + bd_rows.shape[0]):
        if r < ns:
            _row_force(sh_rows[r], sh_ptr[r], sh_ptr[r + 1], sh_cols, sh_blocks, w, v, mass, xi, out)
        else:
            b = r - ns
            _row_force(bd_rows[b], 4 * b, 4 * b + 4, bd_cols, bd_blocks, w, v, mass, xi, out)


force_kernel_serial, force_kernel_parallel = serial_and_parallel(_force_kernel)
force_rows_serial, force_rows_parallel = serial_and_parallel(_force_rows_kernel)


def cluster_args(cl: Clusters) -> tuple:
    """The cluster arrays in kernel argument order."""
    return (cl.shared_rows, cl.shared_ptr, cl.shared_cols, cl.shared_blocks,
            cl.boundary_rows, cl.boundary_cols, cl.boundary_blocks)


def pick_kernel(n_vertices: int, threads: bool | None = None):
    """The serial build for small meshes, the threaded one for large (``threads`` forces a choice)."""
    use = n_vertices >= PARALLEL_MIN_VERTICES if threads is None else threads
    return force_kernel_parallel if use else force_kernel_serial


def clustered_force(cl: Clusters, u: np.ndarray, v: np.ndarray, mass: np.ndarray, zeta: float, xi: float,
                    out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """f = -K (u + zeta v) - xi M v, (n, 3), from the clusters. Checks shapes and finiteness."""
    n = cl.n_vertices
    u = np.ascontiguousarray(u, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    for name, a in (("u", u), ("v", v)):
        if a.shape != (n, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({n}, 3) for this mesh")
    if out is None:
        out = np.empty((n, 3))
    w = np.empty((n, 3))
    pick_kernel(n, threads)(*cluster_args(cl), u, v, np.ascontiguousarray(mass, dtype=np.float64),
                            float(zeta), float(xi), w, out)
    return out
