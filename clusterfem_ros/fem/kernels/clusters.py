"""The clustered representation of K (the paper's eqs. 5-6).

K is cut into 3x3 blocks K_ij; vertex i's row of blocks is its *cluster*. Clusters of *shared*
vertices (used by two or more tets) have a variable number of blocks and are stored CSR-like;
clusters of *boundary* vertices (used by one tet) have exactly four blocks (the vertex and its three
tet neighbours) and are stored with a fixed stride, no index pointer. Both are laid out row after
row in vertex order, each block's nine numbers contiguous, so the force pass streams through memory
once. Nothing is approximated: the blocks are the assembled K's blocks.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..linear.assembly import block_pattern
from ..mesh.tet_mesh import TetMesh, elements_per_vertex


@dataclass(frozen=True)
class Clusters:
    n_vertices: int
    shared_rows: np.ndarray      # (s,) vertex of each shared cluster
    shared_ptr: np.ndarray       # (s+1,) block range of each shared cluster
    shared_cols: np.ndarray      # (bs,) neighbour vertex of each block
    shared_blocks: np.ndarray    # (bs, 3, 3)
    boundary_rows: np.ndarray    # (l,)
    boundary_cols: np.ndarray    # (l*4,) four neighbours per cluster
    boundary_blocks: np.ndarray  # (l*4, 3, 3)

    @property
    def n_blocks(self) -> int:
        return int(len(self.shared_cols) + len(self.boundary_cols))

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.shared_rows, self.shared_ptr, self.shared_cols, self.shared_blocks,
                                      self.boundary_rows, self.boundary_cols, self.boundary_blocks))

    def neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """CSR (ptr (n+1,), cols) of every vertex's cluster neighbours (itself included), in vertex order."""
        rows = np.concatenate([np.repeat(self.shared_rows, np.diff(self.shared_ptr)),
                               np.repeat(self.boundary_rows, 4)])
        cols = np.concatenate([self.shared_cols, self.boundary_cols])
        order = np.lexsort((cols, rows))
        ptr = np.zeros(self.n_vertices + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=self.n_vertices), out=ptr[1:])
        return ptr, np.ascontiguousarray(cols[order])

    def to_dense_rows(self) -> dict[int, dict[int, np.ndarray]]:
        """{i: {j: K_ij}} for tests and debugging on small meshes."""
        out: dict[int, dict[int, np.ndarray]] = {}
        for r, i in enumerate(self.shared_rows):
            out[int(i)] = {int(j): self.shared_blocks[k] for k, j in
                           zip(range(self.shared_ptr[r], self.shared_ptr[r + 1]),
                               self.shared_cols[self.shared_ptr[r]:self.shared_ptr[r + 1]])}
        for r, i in enumerate(self.boundary_rows):
            out[int(i)] = {int(self.boundary_cols[4 * r + k]): self.boundary_blocks[4 * r + k] for k in range(4)}
        return out


def build_clusters(mesh: TetMesh, element_blocks: np.ndarray) -> Clusters:
    """Sum element blocks (m, 4, 4, 3, 3) into per-vertex clusters, split shared / boundary."""
    n = mesh.n_vertices
    r, c = block_pattern(mesh.tets)
    key = r * n + c
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    starts = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
    blocks = np.add.reduceat(element_blocks.reshape(-1, 3, 3)[order], starts, axis=0)
    rows, cols = key_sorted[starts] // n, key_sorted[starts] % n
    count = elements_per_vertex(mesh)
    is_boundary_block = count[rows] == 1
    per_row = np.bincount(rows, minlength=n)
    shared_rows = np.flatnonzero(count >= 2)
    boundary_rows = np.flatnonzero(count == 1)
    assert (per_row[boundary_rows] == 4).all(), "a vertex of a single tet must have exactly four blocks"
    ptr = np.zeros(len(shared_rows) + 1, dtype=np.int64)
    np.cumsum(per_row[shared_rows], out=ptr[1:])
    s = ~is_boundary_block
    return Clusters(
        n_vertices=n,
        shared_rows=shared_rows.astype(np.int64),
        shared_ptr=ptr,
        shared_cols=np.ascontiguousarray(cols[s]),
        shared_blocks=np.ascontiguousarray(blocks[s]),
        boundary_rows=boundary_rows.astype(np.int64),
        boundary_cols=np.ascontiguousarray(cols[~s]),
        boundary_blocks=np.ascontiguousarray(blocks[~s]),
    )
