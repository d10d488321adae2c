"""Plain numpy twins of the warping kernels (eq. 10), for tests only: slow, obvious, trusted."""
from __future__ import annotations

import numpy as np


def polar_svd(F: np.ndarray) -> np.ndarray:
    """Rotation of polar(F) by SVD with the reflection fixed (det R = +1)."""
    U, _, Vt = np.linalg.svd(F)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    return U @ D @ Vt


def vertex_rotations(dense_rows: dict, rest: np.ndarray, u: np.ndarray) -> np.ndarray:
    """R_i = polar(F_i), F_i the least-squares deformation gradient of vertex i's cluster neighbours."""
    n = len(rest)
    x = rest + u
    R = np.zeros((n, 3, 3))
    for i, row in dense_rows.items():
        A = sum(np.outer(x[j] - x[i], rest[j] - rest[i]) for j in row)
        S = sum(np.outer(rest[j] - rest[i], rest[j] - rest[i]) for j in row)
        R[i] = polar_svd(A @ np.linalg.inv(S))
    return R


def warped_force(dense_rows: dict, rest: np.ndarray, u: np.ndarray, v: np.ndarray, mass: np.ndarray,
                 zeta: float, xi: float) -> np.ndarray:
    """f_i = -R_i sum_j K_ij (R_i^T x_j - x0_j) - zeta R_i sum_j K_ij R_i^T v_j - xi m_i v_i, literally."""
    R = vertex_rotations(dense_rows, rest, u)
    x = rest + u
    f = np.zeros_like(u)
    for i, row in dense_rows.items():
        acc = np.zeros(3)
        for j, K in row.items():
            acc += K @ (R[i].T @ x[j] - rest[j]) + zeta * K @ (R[i].T @ v[j])
        f[i] = -R[i] @ acc - xi * mass[i] * v[i]
    return f
