"""Linear-tetrahedron stiffness and lumped mass, vectorized over all elements.

For tet e with vertices x_a (a = 0..3) and shape-function gradients g_a (constant in the tet),
the element stiffness block coupling vertices a and b is
    K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I),
the isotropic form of V B_a^T C B_b. No Python loop runs over elements.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .material import Material
from ..mesh.tet_mesh import TetMesh


def shape_gradients(vertices: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gradients (m, 4, 3), volumes (m,)) of the linear shape functions of every tet."""
    x = vertices[tets]
    Dm = np.transpose(x[:, 1:] - x[:, :1], (0, 2, 1))          # columns x_a - x_0, (m, 3, 3)
    vol = np.linalg.det(Dm) / 6.0
    Dinv = np.linalg.inv(Dm)                                   # rows are gradients of N_1..N_3
    g = np.empty((len(tets), 4, 3))
    g[:, 1:] = Dinv
    g[:, 0] = -Dinv.sum(axis=1)
    return g, vol


def element_stiffness_blocks(mesh: TetMesh, material: Material) -> np.ndarray:
    """Element stiffness as 3x3 blocks, (m, 4, 4, 3, 3): [e, a, b] couples vertex a to vertex b."""
    lam, mu = material.lame
    g, vol = shape_gradients(mesh.vertices, mesh.tets)
    gg = np.einsum("eai,ebj->eabij", g, g)                      # g_a g_b^T
    dot = np.einsum("eai,ebi->eab", g, g)
    K = lam * gg + mu * np.swapaxes(gg, -1, -2)
    K[..., [0, 1, 2], [0, 1, 2]] += (mu * dot)[..., None]
    K *= vol[:, None, None, None, None]
    return K


def block_pattern(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column vertex of every element block, (m*16,) each, in [e, a, b] order."""
    rows = np.repeat(tets, 4, axis=1).ravel()
    cols = np.tile(tets, (1, 4)).ravel()
    return rows, cols


def assemble_stiffness(mesh: TetMesh, material: Material, blocks: np.ndarray | None = None) -> sp.csr_matrix:
    """Global K, (3n, 3n) CSR, symmetric positive semi-definite (six rigid modes)."""
    if blocks is None:
        blocks = element_stiffness_blocks(mesh, material)
    n = mesh.n_vertices
    r, c = block_pattern(mesh.tets)
    rows = (3 * r[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2).ravel()
    cols = (3 * c[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1).ravel()
    K = sp.coo_matrix((blocks.reshape(-1), (rows, cols)), shape=(3 * n, 3 * n)).tocsr()
    K.sum_duplicates()
    return K


def lumped_mass(mesh: TetMesh, density: float) -> np.ndarray:
    """Per-vertex mass (n,) [kg]: a quarter of each adjacent tet's mass."""
    vol = mesh.volumes()
    return np.bincount(mesh.tets.ravel(), weights=np.repeat(density * vol / 4.0, 4), minlength=mesh.n_vertices)
