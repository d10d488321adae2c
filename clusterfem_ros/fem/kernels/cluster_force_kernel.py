"""The clustered elastic-damping force, one fused numba pass (eqs. 4-6).

    f = -D v - K u = -K (u + zeta v) - xi M v          (D = xi M + zeta K)

so one sweep over the K clusters serves both matrices: f_i = f_s + f_b, the shared clusters'
contribution plus the boundary clusters'. The sweep runs over the clusters packed C rows at a time
(cluster_slices.py) and writes (K w)_i to row i of a scratch array, in vertex order; a flat pass finishes
f_i = -(K w)_i - xi m_i v_i (the clustered integrator folds that pass into its velocity update).
``clustered_force`` is the checked public entry; the ``_`` kernels take arrays and scalars only.
tests/naive.py holds the plain numpy twin.

What a build injects: kernel sources here call compiled functions by global names that no import defines,
bound per build by numba_config.compiled (hence ``# noqa: F821`` at each call): ``slice_kernel`` in ``_sweep``
(the slice kernel of slice_sweep: ``_slice_force`` or the warped passes'), ``sweep`` in ``_stiffness_slices``
(the serial or threaded linear sweep, or a sweep around another slice kernel: stiffness_around), and
``kernel_input``, ``stiffness`` and ``finish`` in ``_force_kernel`` (their serial or threaded builds). One
source thus yields serial and threaded builds that cannot drift apart and that numba caches on disk (a
closure over a compiled function would miss the cache in every process).
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import prange, types
from numba.extending import intrinsic

from .cluster_slices import W_ROW, ClusterSlices, aligned_zeros, host_slices
from .clusters import Clusters
from .llvm_ir import (F64, accumulating_loop, double_data, fused_multiply_add, gathered_rows, i64, lane_values,
                      position_entries, slice_kernel_args, slice_kernel_typing, store_lane_rows)
from ...numba_config import PARALLEL_MIN_VERTICES, compiled, serial_and_parallel


_LINEAR_SPECS = (("w_at", 2, types.int64), ("blocks", 3, types.float64), ("w", 2, types.float64),
                 ("owner", 1, types.int64), ("out", 2, types.float64))


def slice_force_intrinsic(gather: bool):
    """The slice kernel below; ``gather=False`` builds the benchmark's control, which reads the same blocks and
    does the same FMAs but holds w at row 0 instead of gathering each position's C rows (its time against the
    full kernel's is the gather's cost: benchmarks/core_benchmark.py)."""
    @intrinsic(prefer_literal=True)
    def _slice_force(typingctx, lanes, s, p0, p1, per_position, common):
        """out[owner[C s + l]] <- sum_p blocks[p, :, l] w[j_p,l] over positions p0..p1 of slice s, each lane l;
        per_position = (w_at, blocks), common = (w, owner, out).

        ``lanes`` (C, a literal) rows at once, lane l for row l: per position, C rows of w (32-byte loads at
        the offsets w_at = 3 j: x, y, z and one double past) transposed into three C-wide vectors, then nine C-wide
        loads of block entries and nine FMAs into three accumulators (x, y, z), one rounding each, in position
        order, so serial and threaded builds give the same bits. Written in LLVM IR because numba's pipeline
        runs no SLP vectorizer. The C sums are stored as rows of out, in vertex order. w_at (P, C) int64,
        blocks (P, 9, C), w (S C + 1, 3) (scratch), owner (S C,) int64, out (S C, 3) float64, C-contiguous
        (checked at typing); callers check the shapes of w and out.
        """
        return _slice_force_typing(gather, lanes, s, p0, p1, per_position, common)
    return _slice_force


def _slice_force_typing(gather, lanes, s, p0, p1, per_position, common):
    C, sig = slice_kernel_typing("_slice_force", lanes, s, p0, p1, per_position, common, _LINEAR_SPECS)
    VC = ir.VectorType(F64, C)

    def codegen(context, builder, signature, args):
        sv, p0v, p1v, arrays = slice_kernel_args(context, builder, signature, args)
        atp, ownp = arrays[0].data, arrays[3].data
        blkp, wp, outp = (double_data(builder, arrays[k]) for k in (1, 2, 4))
        zero = ir.Constant(VC, [0.0] * C)
        if not gather:                          # row 0 of w in every lane, loaded once
            held = gathered_rows(builder, wp, [i64(0)] * C)

        def position(p, acc):
            wxyz = gathered_rows(builder, wp, lane_values(builder, atp, builder.mul(p, i64(C)), C)) if gather else held
            K = position_entries(builder, blkp, p, 9, VC)
            new = []
            for r in range(3):                  # row r of the C blocks: entries (r, 0..2)
                a = acc[r]
                for c in range(3):
                    a = fused_multiply_add(builder, K[3 * r + c], wxyz[c], a)
                new.append(a)
            return new

        totals = accumulating_loop(builder, p0v, p1v, 1, [zero] * 3, position)
        store_lane_rows(builder, outp, ownp, builder.mul(sv, i64(C)), totals)    # lane l -> row owner[C s + l]
        return context.get_dummy_value()

    return sig, codegen


_slice_force = slice_force_intrinsic(gather=True)


def _sweep(sh_ptr, shared, boundary, common):
    """The loop over every slice around one slice kernel, the global ``slice_kernel`` (bound per build by
    slice_sweep): shared slices (positions sh_ptr[s]..sh_ptr[s+1]) then boundary slices of four positions, in
    one loop (one parallel region when threaded), the kernel built for the slices' lane count (8, 4 or 2).
    ``shared`` and ``boundary``: the per-position arrays of each part, w_at (P, C) first; ``common``: the
    kernel's other arguments."""
    lanes = shared[0].shape[1]
    ns = sh_ptr.shape[0] - 1
    for s in prange(ns + boundary[0].shape[0] // 4):
        if s < ns:
            p0, p1, arrays = sh_ptr[s], sh_ptr[s + 1], shared
        else:
            p0, p1, arrays = 4 * (s - ns), 4 * (s - ns) + 4, boundary
        if lanes == 8:
            slice_kernel(8, s, p0, p1, arrays, common)  # noqa: F821 (bound by slice_sweep)
        elif lanes == 4:
            slice_kernel(4, s, p0, p1, arrays, common)  # noqa: F821
        else:
            slice_kernel(2, s, p0, p1, arrays, common)  # noqa: F821


def slice_sweep(slice_fn, name: str):
    """(serial, parallel) builds of the sweep over every slice around the slice kernel ``slice_fn(lanes, s, p0,
    p1, per_position, common)``, called as sweep(sh_ptr, shared, boundary, common); ``name`` tells their cache
    entries apart. Used here and by the warped sweeps (warped_force_kernel.py)."""
    bound = {"slice_kernel": slice_fn}
    return serial_and_parallel(_sweep, "_" + name, serial=bound, parallel=bound)


def _stiffness_slices(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner, w, kw):
    """kw[i] <- (K w)_i for every vertex i (rows past n: the padding lanes', zero), by the global ``sweep``
    (bound per build: serial or threaded, or a sweep around another slice kernel: stiffness_around)."""
    if kw.shape[0] != owner.shape[0] or kw.shape[1] != 3:
        raise ValueError("the cluster force kernel needs kw with a row of 3 per lane of the slices (scratch())")
    if w.shape[1] != W_ROW or w.shape[0] <= owner.shape[0]:
        raise ValueError("the cluster force kernel needs w with rows of 3 (x, y, z), a row per lane of the slices "
                         "and one more: it loads 4 doubles from a row (scratch())")
    sweep(sh_ptr, (sh_w_at, sh_blocks), (bd_w_at, bd_blocks), (w, owner, kw))  # noqa: F821 (bound)


_linear_sweeps = slice_sweep(_slice_force, "linear")
# no loop of their own: the sweeps carry the threads
stiffness_slices_serial, stiffness_slices_parallel = (compiled(_stiffness_slices, suffix, sweep=sweep)
                                                      for suffix, sweep in zip(("", "_parallel"), _linear_sweeps))


def stiffness_around(slice_kernel, suffix: str):
    """A serial build of the stiffness pass (stiffness_slices_serial's arguments) around another slice kernel
    with the linear one's arguments, e.g. slice_force_intrinsic(gather=False), the benchmark's control
    (benchmarks/core_benchmark.py); ``suffix`` keeps its cache entries apart."""
    return compiled(_stiffness_slices, suffix, sweep=compiled(_sweep, suffix, slice_kernel=slice_kernel))


def _finish_kernel(kw, v, mass3, xi, out):
    """out <- -K w - xi M v over flat arrays (mass3: the lumped mass per coordinate, 3n), K w read from the
    sweep's first n rows (vertex order)."""
    kf = kw.reshape(-1)             # one view per statement (see _kernel_input)
    vf = v.reshape(-1)
    of = out.reshape(-1)
    for k in prange(of.shape[0]):
        of[k] = -kf[k] - (xi * mass3[k]) * vf[k]


finish_serial, finish_parallel = serial_and_parallel(_finish_kernel)


def _kernel_input(n, zeta, rest, u, v, w, warped):
    """w[:n] <- the force kernels' input: u + zeta v (linear), x0 + u + zeta v (warped; ``rest`` is x0,
    unread when not warped), element by element over the flat arrays (w's rows are x, y, z like u's), so the
    loops vectorize. One source for the force kernels here and in warping.py and the clustered integrator's
    passes."""
    # one view per statement: unpacked from one tuple, the threaded build of numba 0.68 lost every store to w
    wf = w.reshape(-1)
    rf = rest.reshape(-1)
    uf = u.reshape(-1)
    vf = v.reshape(-1)
    if warped:
        for k in prange(3 * n):
            wf[k] = (rf[k] + uf[k]) + zeta * vf[k]
    else:
        for k in prange(3 * n):
            wf[k] = uf[k] + zeta * vf[k]


kernel_input_serial, kernel_input_parallel = serial_and_parallel(_kernel_input)


def _force_kernel(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner, u, v, mass3, zeta, xi, w, kw, out):
    """w[:n] <- u + zeta v (w: scratch()), the slice sweep, then the finish: f = -K w - xi M v (mass3: the
    lumped mass per coordinate; the clustered integrator runs the same sweep, with the finish inside its
    update; the core benchmark times this). ``kernel_input``, ``stiffness`` and ``finish``: globals bound per
    build."""
    kernel_input(u.shape[0], zeta, u, u, v, w, False)  # noqa: F821 (bound)
    stiffness(sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner, w, kw)  # noqa: F821
    finish(kw, v, mass3, xi, out)  # noqa: F821


# no loop of their own: their callees carry the threads
force_kernel_serial = compiled(_force_kernel, kernel_input=kernel_input_serial, stiffness=stiffness_slices_serial,
                               finish=finish_serial)
force_kernel_parallel = compiled(_force_kernel, "_parallel", kernel_input=kernel_input_parallel,
                                 stiffness=stiffness_slices_parallel, finish=finish_parallel)


def cluster_args(sl: ClusterSlices) -> tuple:
    """The slice arrays in kernel argument order (sh_ptr, sh_w_at, sh_blocks, bd_w_at, bd_blocks, owner)."""
    return (sl.shared_ptr, sl.shared_w_at, sl.shared_blocks, sl.boundary_w_at, sl.boundary_blocks, sl.owner)


def input_rows(sl: ClusterSlices) -> np.ndarray:
    """Zeros for a per-vertex array the slice kernels gather (w, or the warped path's copy of u): (n_slices * C
    + 1, 3), 64-byte aligned, vertex j's x, y, z to go in row j. A kernel loads 4 doubles from a row, so the last
    vertex's load needs a row after it; the rows past the n vertices' stay zero."""
    return aligned_zeros((len(sl.owner) + 1, W_ROW))


def scratch(sl: ClusterSlices) -> tuple[np.ndarray, np.ndarray]:
    """(w, kw): the kernel's input rows (input_rows) and the sweep's (n_slices * C, 3) output rows (vertex i's
    K w in row i; the padding lanes' rows after the n vertices')."""
    return input_rows(sl), np.zeros((len(sl.owner), 3))


def pick_kernel(n_vertices: int, threads: bool | None = None):
    """The serial build for small meshes, the threaded one for large (``threads`` forces a choice)."""
    use = n_vertices >= PARALLEL_MIN_VERTICES if threads is None else threads
    return force_kernel_parallel if use else force_kernel_serial


def clustered_force(cl: Clusters, u: np.ndarray, v: np.ndarray, mass: np.ndarray, zeta: float, xi: float,
                    out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """f = -K (u + zeta v) - xi M v, (n, 3), from the clusters, into ``out`` if given. Checks shapes."""
    n = cl.n_vertices
    u = np.ascontiguousarray(u, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    for name, a in (("u", u), ("v", v)):
        if a.shape != (n, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({n}, 3) for this mesh")
    mass = np.asarray(mass, dtype=np.float64)
    if mass.shape != (n,):
        raise ValueError(f"mass has shape {mass.shape}, expected ({n},): one lumped mass per vertex")
    if out is None:
        out = np.empty((n, 3))
    elif out.shape != (n, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous ({n}, 3) float64 array, got {out.dtype} {out.shape}")
    sl = host_slices(cl)
    w, kw = scratch(sl)
    pick_kernel(n, threads)(*cluster_args(sl), u, v, np.repeat(mass, 3), float(zeta), float(xi), w, kw, out)
    return out
