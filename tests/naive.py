"""Plain numpy twins of the numba kernels, for tests only: slow, obvious, trusted."""
from __future__ import annotations

import numpy as np


def cluster_force(dense_rows: dict, n: int, u: np.ndarray, v: np.ndarray, mass: np.ndarray,
                  zeta: float, xi: float) -> np.ndarray:
    """f_i = -sum_j K_ij (u_j + zeta v_j) - xi m_i v_i, from {i: {j: K_ij}}."""
    f = np.zeros((n, 3))
    w = u + zeta * v
    for i, row in dense_rows.items():
        for j, B in row.items():
            f[i] -= B @ w[j]
        f[i] -= xi * mass[i] * v[i]
    return f


def element_stiffness(x: np.ndarray, E: float, nu: float) -> np.ndarray:
    """12x12 stiffness of one tet as V B^T C B (textbook Voigt form)."""
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[range(3), range(3)] += 2 * mu
    C[range(3, 6), range(3, 6)] = mu
    Dm = np.column_stack([x[1] - x[0], x[2] - x[0], x[3] - x[0]])
    V = np.linalg.det(Dm) / 6
    G = np.linalg.inv(Dm)
    g = np.vstack([-G.sum(axis=0), G])
    B = np.zeros((6, 12))
    for a in range(4):
        gx, gy, gz = g[a]
        B[:, 3 * a:3 * a + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz], [0, gz, gy], [gz, 0, gx], [gy, gx, 0]]
    return V * B.T @ C @ B


def capsule_inside(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Twin of skeleton.jelly_body.capsule_inside: the numpy einsum form it replaced (all points against all
    bones at once)."""
    d = ends - starts
    L2 = np.einsum("bj,bj->b", d, d)
    rel = points[:, None, :] - starts[None]
    t = np.clip(np.einsum("kbj,bj->kb", rel, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    q = rel - t[..., None] * d
    return (np.einsum("kbj,kbj->kb", q, q) <= radii * radii).any(axis=1)


def stress(rest: np.ndarray, tets: np.ndarray, u: np.ndarray, lam: float, mu: float, corotated: bool):
    """(element stress (m, 3, 3), vertex stress (n, 3, 3)) as fem/materials/stress.py defines them: F = I + grad u per
    tet from its rest edges, R = polar(F) by SVD (or I), eps = sym(R^T F) - I, s = lam tr(eps) I + 2 mu eps,
    sigma = R s R^T; per vertex the volume-weighted mean of its tets'."""
    x0 = rest[tets]
    D0 = (x0[:, 1:] - x0[:, :1]).transpose(0, 2, 1)            # rest edge matrix (m, 3, 3)
    D = ((rest + u)[tets][:, 1:] - (rest + u)[tets][:, :1]).transpose(0, 2, 1)
    F = D @ np.linalg.inv(D0)
    if corotated:
        U, _, Vt = np.linalg.svd(F)
        R = U @ Vt
    else:
        R = np.broadcast_to(np.eye(3), F.shape)
    G = R.transpose(0, 2, 1) @ F
    eps = 0.5 * (G + G.transpose(0, 2, 1)) - np.eye(3)
    s = lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 2.0 * mu * eps
    sigma = R @ s @ R.transpose(0, 2, 1)
    vol = np.abs(np.linalg.det(D0)) / 6.0
    vs = np.zeros((len(rest), 3, 3))
    w = np.zeros(len(rest))
    for c in range(4):
        np.add.at(vs, tets[:, c], vol[:, None, None] * sigma)
        np.add.at(w, tets[:, c], vol)
    return sigma, vs / w[:, None, None]


def tet_quality(x: np.ndarray) -> tuple[float, float]:
    """(smallest dihedral angle [deg], radius ratio 3 r_in / r_circ) of one tet (4, 3), written out another way
    than fem.tetrahedralize.tet_quality: each dihedral angle between the two faces along an edge, from the other
    two vertices projected onto the plane across the edge; the circumradius from the edge lengths (Crelle:
    6 V R = sqrt of the Heron product of the opposite-edge products)."""
    angles = []
    for i, j in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)):
        k, m = [c for c in range(4) if c not in (i, j)]
        e = (x[j] - x[i]) / np.linalg.norm(x[j] - x[i])
        a = x[k] - x[i] - ((x[k] - x[i]) @ e) * e
        b = x[m] - x[i] - ((x[m] - x[i]) @ e) * e
        angles.append(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))
    volume = abs(np.linalg.det(x[1:] - x[0])) / 6.0
    area = sum(0.5 * np.linalg.norm(np.cross(x[b] - x[a], x[c] - x[a]))
               for a, b, c in ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)))
    r_in = 3.0 * volume / area
    L = lambda a, b: np.linalg.norm(x[a] - x[b])          # noqa: E731
    p, q, r = L(0, 1) * L(2, 3), L(0, 2) * L(1, 3), L(0, 3) * L(1, 2)
    s = 0.5 * (p + q + r)
    r_circ = np.sqrt(s * (s - p) * (s - q) * (s - r)) / (6.0 * volume)
    return float(min(angles)), float(3.0 * r_in / r_circ)


_CORNER = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])


def grid_mesh(mask: np.ndarray, lo: np.ndarray, spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, tets) of the voxels of ``mask`` split in five tets each, on the dense grid of every corner: each
    voxel's corners numbered over the whole (nx + 1, ny + 1, nz + 1) grid, the unused corners dropped, then each
    tet oriented positively."""
    from clusterfem_ros.fem.mesh.voxel_mesh import _SPLIT
    nx, ny, nz = mask.shape
    vid = lambda p: (p[..., 0] * (ny + 1) + p[..., 1]) * (nz + 1) + p[..., 2]  # noqa: E731
    ijk = np.argwhere(mask)
    tets = np.concatenate([vid(c[:, None, :] + _CORNER)[:, _SPLIT[parity]].reshape(-1, 4)
                           for parity in (0, 1) for c in [ijk[ijk.sum(axis=1) % 2 == parity]]])
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    vertices = np.asarray(lo, dtype=np.float64) + g.reshape(-1, 3) * spacing
    used = np.unique(tets)
    remap = np.full(len(vertices), -1)
    remap[used] = np.arange(len(used))
    vertices, tets = vertices[used], remap[tets]
    e = vertices[tets[:, 1:]] - vertices[tets[:, :1]]
    neg = np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3], tets[neg, 2].copy()
    return vertices, tets


def separate(mask: np.ndarray, body: np.ndarray) -> np.ndarray:
    """``mask`` (nx, ny, nz) without the voxels that share a face, edge or corner with a voxel of another body
    (``body`` per voxel): of each such pair the voxel of the body with more voxels goes, of equal ones the body
    with the higher index. One voxel and one neighbour at a time."""
    size = np.bincount(body[mask])
    keep = mask.copy()
    n = mask.shape
    for a in np.argwhere(mask):
        for off in np.ndindex(3, 3, 3):
            b = a + np.array(off) - 1
            if (b < 0).any() or (b >= n).any() or not mask[tuple(b)]:
                continue
            ba, bb = body[tuple(a)], body[tuple(b)]
            if ba != bb and (size[ba] > size[bb] or (size[ba] == size[bb] and ba > bb)):
                keep[tuple(a)] = False
    return keep


def release_gains(x: np.ndarray, rows: np.ndarray, v0: np.ndarray, floor: float, kp0: np.ndarray,
                  kd0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """body/crush_release.release_gains: each corner's smallest target volume ratio over its elements, mapped to
    g = clip((r - floor) / (1 - floor), 0, 1), 1 for r within 1e-9 of 1 or above; (kp0 g, kd0 sqrt g)."""
    ratio = np.full(x.shape[0], np.inf)
    for e, corners in enumerate(rows):
        r = np.linalg.det(np.stack([x[c] - x[corners[0]] for c in corners[1:]])) / v0[e]
        for c in corners:
            ratio[c] = min(ratio[c], r)
    g = np.clip((ratio - floor) / (1.0 - floor), 0.0, 1.0)
    g[~(ratio < 1.0 - 1.0e-9)] = 1.0              # kept volume (to round-off) or no element: the levels' gains
    return kp0 * g, kd0 * np.sqrt(g)


def corner_differences(corner: np.ndarray, p: np.ndarray) -> np.ndarray:
    """A chunk's corner differences by lane (fem/materials/corner_rows.corner_row_differences): entry
    (3 (c - 1) + a) LANES + l = p[corner[c, l], a] - p[corner[0, l], a], c = 1, 2, 3; corner (4, LANES)."""
    d = p[corner[1:]] - p[corner[0]][None]                    # (3, LANES, 3): corner, lane, component
    return np.ascontiguousarray(np.moveaxis(d, 1, 2)).reshape(-1)
