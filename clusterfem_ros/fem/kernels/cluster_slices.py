"""The clusters packed for the SIMD force kernel: slices of C rows, one row per vector lane (SELL-C).

The per-vertex clusters (clusters.py, eqs. 5-6) keep their blocks row after row, each block's nine numbers
together. A kernel that walks one row at a time must then gather w_j for every block and add its nine
products into one 3-vector, which costs 2.7x a bare 4-wide read of the same blocks (see
benchmarks/core_benchmark.py). Here C rows are walked together, lane l of every vector belonging to row l of the
slice: entry (r, c) of the k-th block of the C rows is one C-wide load, the C neighbours' w are loaded as
rows and transposed once per position, and each row's sum stays in its own lane, so there is no horizontal
sum and no per-row loop exit.

- Shared clusters (variable length) are sorted longest first within windows of WINDOW rows and cut into
  slices of C; a slice has as many positions as its longest row, shorter rows are padded with zero blocks
  whose column is the row's own vertex (so a padded entry adds exactly 0 and depends on nothing else).
  Sorting keeps the padding small (0.5-2.5 % on the paper's shapes).
- Boundary clusters (exactly four blocks each, eq. 6) fill slices of four positions in vertex order, with no
  pointer, as in clusters.py.
- A neighbour j is stored as where its row of w starts, 3 j (w's rows are x, y, z), so the kernel loads it
  without a multiply: 7-10 % off the sweep on the paper's shapes against storing j. The kernel loads four
  doubles there (the row and the next row's x, unused), so w has a row per lane and one more
  (``cluster_force_kernel.input_rows``): the last vertex's load ends inside it. Rows of 3 instead of rows padded
  to 4 let the passes that write w run over flat arrays (u + zeta v, element by element), vectorized: 0.20
  instead of 0.42 us per pass on the paper's sphere, the same bits.

The kernel writes each row's K w to the row ``owner[s * C + l]`` of an (n_slices * C, 3) array: vertex i's
sum lands in row i, in vertex order, so the per-vertex passes after it run over flat arrays; each padding
lane has a row of its own past the n vertices' (no two lanes share a row, so threads never write the same
place). Nothing is approximated: every block of the clusters appears once, unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clusters import Clusters
from ...numba_config import simd_lanes


# Shared rows are sorted by length within windows of this many rows, not globally. A global sort put all
# long rows in the first slices, and the threaded sweep, which hands each thread an equal range of slices,
# ran 1.9 instead of 1.3 ms on a 320k-tet box (first half of the slices 1.9 ms, second 0.8 ms serial).
# Windows keep every range's mix of lengths, and the paper's shapes (< 1024 shared rows) pad as little
# as with the global sort.
WINDOW = 1024

# Doubles per row of the kernels' input w (x, y, z): neighbour j's row starts at W_ROW j. The kernels load a
# row as one 4-wide vector, reading one double past it, hence w's extra row (module docstring).
W_ROW = 3


def aligned_zeros(shape: tuple[int, ...], dtype=np.float64, alignment: int = 64) -> np.ndarray:
    """Zeros whose data starts on an ``alignment``-byte boundary (numpy gives only 16): a C-wide block load
    then never straddles two cache lines."""
    nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
    buf = np.zeros(nbytes + alignment, dtype=np.uint8)
    start = (-buf.ctypes.data) % alignment
    return buf[start:start + nbytes].view(dtype).reshape(shape)


@dataclass(frozen=True)
class ClusterSlices:
    lanes: int                   # C: rows per slice
    n_vertices: int
    shared_ptr: np.ndarray       # (s+1,) position range of each shared slice
    shared_w_at: np.ndarray      # (ps, C) W_ROW * neighbour vertex per position and lane (its row of w)
    shared_blocks: np.ndarray    # (ps, 9, C) block entry (row-major 3x3) per position and lane
    boundary_w_at: np.ndarray    # (4 b, C)
    boundary_blocks: np.ndarray  # (4 b, 9, C)
    owner: np.ndarray            # (n_slices * C,) output row of each lane: its vertex, or n + k for padding

    @property
    def shared_cols(self) -> np.ndarray:
        """(ps, C) neighbour vertex per position and lane."""
        return self.shared_w_at // W_ROW

    @property
    def boundary_cols(self) -> np.ndarray:
        return self.boundary_w_at // W_ROW

    @property
    def n_slices(self) -> int:
        return len(self.shared_ptr) - 1 + len(self.boundary_w_at) // 4

    @property
    def n_padded_blocks(self) -> int:
        return (len(self.shared_w_at) + len(self.boundary_w_at)) * self.lanes

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.shared_ptr, self.shared_w_at, self.shared_blocks, self.boundary_w_at,
                                      self.boundary_blocks, self.owner))


def _fill(rows: np.ndarray, lengths: np.ndarray, first: np.ndarray, cols: np.ndarray, blocks: np.ndarray,
          lanes: int, slice_start: np.ndarray, n_positions: int) -> tuple[np.ndarray, np.ndarray]:
    """Scatter rows (vertex ``rows[r]``, blocks first[r]..first[r]+lengths[r]) into lanes r % C of slices r // C,
    slice s starting at position slice_start[s]. Unused entries: zero block, the lane's own vertex (vertex 0 in
    the lanes past the last row)."""
    n_rows = len(rows)
    own = np.zeros(-(-n_rows // lanes) * lanes, np.int64)
    own[:n_rows] = rows
    own = own.reshape(-1, lanes)
    out_cols = np.repeat(own, np.diff(np.r_[slice_start, n_positions]), axis=0)
    out_blocks = aligned_zeros((n_positions, 9, lanes))
    r = np.repeat(np.arange(n_rows), lengths)                       # row of each block
    k = np.arange(len(r)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    pos, lane = slice_start[r // lanes] + k, r % lanes
    src = np.repeat(first, lengths) + k
    out_cols[pos, lane] = cols[src]
    out_blocks[pos, :, lane] = blocks[src].reshape(-1, 9)
    return np.ascontiguousarray(out_cols), out_blocks


def slice_clusters(cl: Clusters, lanes: int) -> ClusterSlices:
    """Pack ``cl`` into slices of ``lanes`` rows (see the module docstring)."""
    if lanes not in (2, 4, 8):
        raise ValueError(f"lanes = {lanes}: the slice kernel is built for 2, 4 or 8 rows per slice")
    length = np.diff(cl.shared_ptr)
    order = np.lexsort((-length, np.arange(len(length)) // WINDOW))   # longest first within each window
    n_sh = len(order)
    n_sh_slices = -(-n_sh // lanes)
    padded = np.zeros(n_sh_slices * lanes, np.int64)
    padded[:n_sh] = length[order]
    shared_ptr = np.zeros(n_sh_slices + 1, np.int64)
    np.cumsum(padded.reshape(-1, lanes).max(axis=1, initial=0), out=shared_ptr[1:])
    sh_cols, sh_blocks = _fill(cl.shared_rows[order], length[order], cl.shared_ptr[:-1][order], cl.shared_cols,
                               cl.shared_blocks, lanes, shared_ptr[:-1], int(shared_ptr[-1]))

    n_bd = len(cl.boundary_rows)
    n_bd_slices = -(-n_bd // lanes)
    bd_cols, bd_blocks = _fill(cl.boundary_rows, np.full(n_bd, 4, np.int64), 4 * np.arange(n_bd, dtype=np.int64),
                               cl.boundary_cols, cl.boundary_blocks, lanes,
                               4 * np.arange(n_bd_slices, dtype=np.int64), 4 * n_bd_slices)

    n_lanes = (n_sh_slices + n_bd_slices) * lanes
    owner = np.full(n_lanes, -1, np.int64)                          # vertex of every lane, then the padding's
    owner[:n_sh] = cl.shared_rows[order]
    owner[n_sh_slices * lanes:n_sh_slices * lanes + n_bd] = cl.boundary_rows
    padding = owner < 0
    owner[padding] = cl.n_vertices + np.arange(int(padding.sum()))
    return ClusterSlices(lanes=lanes, n_vertices=cl.n_vertices, shared_ptr=shared_ptr, shared_w_at=W_ROW * sh_cols,
                         shared_blocks=sh_blocks, boundary_w_at=W_ROW * bd_cols, boundary_blocks=bd_blocks, owner=owner)


def host_slices(cl: Clusters) -> ClusterSlices:
    """cl's blocks packed C rows at a time for the SIMD force kernels, C = this host's doubles per vector
    register (simd_lanes); built on first use and kept with cl, so a model that never runs a slice kernel does
    not hold the copy."""
    built = vars(cl).get(_HOST_SLICES)
    if built is None:
        built = vars(cl)[_HOST_SLICES] = slice_clusters(cl, simd_lanes())     # beside the frozen fields
    return built


def host_slices_nbytes(cl: Clusters) -> int:
    """Bytes cl's host slices hold, 0 while they have not been built (host_slices would build them)."""
    built = vars(cl).get(_HOST_SLICES)
    return built.nbytes if built is not None else 0


_HOST_SLICES = "_host_slices"


def lane_vertices(sl: ClusterSlices) -> np.ndarray:
    """(n_slices * C,) the vertex of every lane, 0 for the padding lanes (whose blocks are zero and whose
    columns are vertex 0): where a kernel reads a lane's own row of a per-vertex array (owner says where its
    result goes)."""
    return np.where(sl.owner < sl.n_vertices, sl.owner, 0)


def position_lanes(sl: ClusterSlices) -> tuple[np.ndarray, np.ndarray]:
    """(shared (ps, C), boundary (4 b, C)): the vertex of the lane each block entry belongs to (lane_vertices)."""
    own = lane_vertices(sl).reshape(-1, sl.lanes)
    ns = len(sl.shared_ptr) - 1
    return np.repeat(own[:ns], np.diff(sl.shared_ptr), axis=0), np.repeat(own[ns:], 4, axis=0)


def rest_offsets(sl: ClusterSlices, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(shared, boundary) d_ij = x0_j - x0_i per position and lane, (P, 3, C) beside the (P, 9, C) blocks,
    64-byte aligned; zero in every padding entry (its column is the lane's own vertex, or vertex 0 in a
    padding lane). The warped force kernel reads them (warped_force_kernel.py)."""
    out = []
    for cols, own in zip((sl.shared_cols, sl.boundary_cols), position_lanes(sl)):
        d = aligned_zeros((len(cols), 3, sl.lanes))
        d[...] = np.swapaxes(rest[cols] - rest[own], 1, 2)
        out.append(d)
    return out[0], out[1]
