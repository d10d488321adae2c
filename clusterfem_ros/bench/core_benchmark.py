"""Issue-2 benchmark: ms/step of the clustered and standard methods on the paper's three objects.

    python -m clusterfem_ros.bench.core_benchmark [--step 1e-3] [--scale 1.0] [--sizes 1,2,4]

Every method runs the same scene (the object's bottom fixed, gravity, same material and step) and
is timed after warm-up (JIT compilation excluded). 'stream' is a bare pass that reads every block
and column index of the clusters once, vectorized: the memory-bound floor for the force kernel.

The floor is the stream over 64-byte-aligned copies of the clusters' block and index arrays (numpy
gives them 16-byte alignment, over which the stream ran up to 1.7x slower on this host). 'kernel' is the
whole force the integrator needs, f = -K (u + zeta v) - xi M v: the w pass, the sweep over the blocks and
the finish in vertex order (cluster_force_kernel.force_kernel_serial). 'sweep' is the pass over the block
data alone (stiffness_slices_serial).

History, measured on the 2026-11-23 host (Intel Xeon, AVX-512; earlier sessions ran on a Zen 1):
- The row kernel (one cluster row at a time, the nine products of a block in 4-wide FMAs, w[j] gathered
  per block) was 5.7-6.0 us on the sphere, 2.7-2.9x the stream, however it was arranged: 4 or 8
  accumulator sets, 8-wide FMAs, pre-shuffled w, pre-multiplied indices, padded or aligned blocks each
  moved it 10 % or less. With w hoisted (no gather) it ran 1.2 instead of 1.45 ns per block; with all
  blocks in one row, 1.22 ns with the gather and 0.66 ns without (the stream's speed): the gather and the
  per-row reduction were the cost.
- Slices of C rows (cluster_slices.py, SELL-C; C = 8 here) remove the per-row reduction and turn the
  per-block gather into C row loads and one transpose per position: the sweep is 2.9-3.3 us on the sphere,
  1.45-1.53x the stream on the paper's shapes. A C prototype of the same layout (gcc -O3 -march=native,
  intrinsics) ran 2.9-3.2 us, so the IR kernel is at what this layout gives.
- What is left between the sweep and the whole force is per vertex: the w pass (~0.4 us) and the finish
  (~0.6 us: -xi m_i v_i, and reading each vertex's K w from its slot), which keep the whole force at
  ~2.0x the stream on the paper's shapes. Once the clusters leave L2 the ratio falls (the second table).
"""
from __future__ import annotations

import argparse
import sys

import numba
import numpy as np

from ..fem.cluster_force_kernel import cluster_args, force_kernel_serial, scratch, stiffness_slices_serial
from ..fem.cluster_slices import aligned_zeros
from ..fem.integrators import make_integrator
from ..fem.material import Material
from ..fem.model import Control, State, build_model
from ..fem.voxel_mesh import PAPER_SHAPES, paper_mesh
from .timing import median_seconds, table

PAPER_MS = {"sphere": (1.60, 0.73, 0.83), "cube": (1.89, 0.92, 1.09), "torus": (2.15, 0.97, 1.12)}
MATERIAL = Material(E=3.0e4, nu=0.3, rho=1000.0, xi=1.0, zeta=1e-5)


@numba.njit(cache=True, fastmath={"reassoc", "contract", "nsz", "arcp"})
def _stream(sh_cols, sh_blocks, bd_cols, bd_blocks, reps):
    s = 0.0
    for _ in range(reps):
        a = sh_blocks.reshape(-1)
        for k in range(a.shape[0]):
            s += a[k]
        for k in range(sh_cols.shape[0]):
            s += sh_cols[k]
        b = bd_blocks.reshape(-1)
        for k in range(b.shape[0]):
            s += b[k]
        for k in range(bd_cols.shape[0]):
            s += bd_cols[k]
    return s


@numba.njit(cache=True)
def _force_loop(a0, a1, a2, a3, a4, slot, u, v, m, zeta, xi, w, kw, f, reps):
    for _ in range(reps):
        force_kernel_serial(a0, a1, a2, a3, a4, slot, u, v, m, zeta, xi, w, kw, f)


@numba.njit(cache=True)
def _sweep_loop(a0, a1, a2, a3, a4, w, kw, reps):
    for _ in range(reps):
        stiffness_slices_serial(a0, a1, a2, a3, a4, w, kw)


def aligned_copy(a: np.ndarray, alignment: int = 64) -> np.ndarray:
    """A copy of ``a`` whose data starts on an ``alignment``-byte boundary."""
    out = aligned_zeros(a.shape, a.dtype, alignment)
    out[...] = a
    return out


def kernel_vs_stream(model, reps: int = 200) -> tuple[float, float, float, float]:
    """(force kernel s, sweep s, stream over the clusters' blocks s, stream over the slices s) per call, timed
    inside numba so dispatch is excluded. The kernel is the whole force: w = u + zeta v, the slice sweep and
    the finish (-xi M v, vertex order). The floor is the stream over 64-byte-aligned copies of the clusters'
    own blocks and indices (numpy gives them 16-byte alignment, over which the stream ran up to 1.7x slower
    on this host); the slices the kernel reads are the same blocks plus 0.5-2.5 % zero padding."""
    cl = model.clusters
    sl = cl.slices
    n = model.n_vertices
    rng = np.random.default_rng(0)
    u, v = rng.normal(size=(2, n, 3))
    w, kw = scratch(sl)
    f = np.empty((n, 3))
    args = cluster_args(sl)
    kern = median_seconds(lambda: _force_loop(*args, sl.slot, u, v, model.mass, 1e-3, 1.0, w, kw, f, reps)) / reps
    sweep = median_seconds(lambda: _sweep_loop(*args, w, kw, reps)) / reps
    aligned = tuple(aligned_copy(a) for a in (cl.shared_cols, cl.shared_blocks, cl.boundary_cols, cl.boundary_blocks))
    stream = median_seconds(lambda: _stream(*aligned, reps)) / reps
    sliced = (sl.shared_cols.reshape(-1), sl.shared_blocks, sl.boundary_cols.reshape(-1), sl.boundary_blocks)
    stream_slices = median_seconds(lambda: _stream(*sliced, reps)) / reps
    return kern, sweep, stream, stream_slices


def stream_by_size(scales: list[float]) -> list[list[object]]:
    """Kernel against stream on the sphere as its cluster data grows out of L1/L2 into L3 and memory."""
    rows = []
    for scale in scales:
        mesh = paper_mesh("sphere", scale)
        model = build_model(mesh, MATERIAL)
        cl = model.clusters
        kern, sweep, stream, _ = kernel_vs_stream(model, reps=max(5, 800_000 // cl.n_blocks))
        rows.append([f"{scale:g}", mesh.n_vertices, mesh.n_tets, cl.n_blocks, f"{cl.nbytes / 1e6:.2f}",
                     f"{kern * 1e6:.1f}", f"{sweep * 1e6:.1f}", f"{stream * 1e6:.1f}", f"{kern / stream:.2f}",
                     f"{sweep / stream:.2f}"])
    return rows


def bench_shape(name: str, h: float, scale: float) -> dict:
    mesh = paper_mesh(name, scale)
    zmin = mesh.vertices[:, 2].min()
    model = build_model(mesh, MATERIAL, fixed=mesh.vertices[:, 2] < zmin + 1e-9 + 0.2 * np.ptp(mesh.vertices[:, 2]))
    out = {"mesh": name, "vertices": mesh.n_vertices, "tets": mesh.n_tets, "blocks": model.clusters.n_blocks}
    lam = None
    for method in ("clustered", "standard_explicit", "implicit_direct", "implicit_cg"):
        opts = {} if method.startswith("implicit") else ({"lam_max": lam} if lam else {})
        integ = make_integrator(method, model, **opts)
        lam = getattr(integ, "lam_max", lam)
        state, control = State.rest(model), Control()
        info = integ.step(state, control, h)
        for _ in range(200):            # past JIT, cache loads and the first-touch of every array
            integ.step(state, control, h)
        out[method] = median_seconds(lambda: integ.step(state, control, h))
        if method == "clustered":
            out["substeps"] = info.substeps
            out["margin"] = info.margin
    out["kernel"], out["sweep"], out["stream"], out["stream_slices"] = kernel_vs_stream(model)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step", type=float, default=1e-3, help="physics step h in seconds (default 1e-3)")
    ap.add_argument("--scale", type=float, default=1.0, help="mesh refinement factor (1 = the paper's sizes)")
    ap.add_argument("--sizes", default="1,2,4",
                    help="sphere scales for the kernel/stream-by-size table (comma-separated; '' skips it)")
    args = ap.parse_args(argv)
    try:
        sizes = [float(x) for x in args.sizes.split(",") if x.strip()]
    except ValueError:
        ap.error(f"--sizes {args.sizes!r}: expected comma-separated numbers such as 1,2,4")
    print(f"material E={MATERIAL.E:g} Pa nu={MATERIAL.nu} rho={MATERIAL.rho:g} xi={MATERIAL.xi} "
          f"zeta={MATERIAL.zeta:g}; h = {args.step:g} s; numba threads off (serial kernels)", flush=True)
    rows, rows_raw, ok = [], [], True
    print("  warming up (one untimed pass: the first shape timed in a fresh process ran ~1.8x slow)",
          file=sys.stderr, flush=True)
    bench_shape(PAPER_SHAPES[0], args.step, args.scale)
    for name in PAPER_SHAPES:
        print(f"  timing {name} ...", file=sys.stderr, flush=True)
        r = bench_shape(name, args.step, args.scale)
        rows_raw.append(r)
        c = r["clustered"]
        ms = lambda s: f"{s * 1e3:.3f}"  # noqa: E731
        rows.append([name, r["vertices"], r["tets"], ms(c), f"{r['substeps']}", f"{r['margin']:.2f}",
                     f"{ms(r['standard_explicit'])} ({r['standard_explicit'] / c:.1f}x)",
                     f"{ms(r['implicit_direct'])} ({r['implicit_direct'] / c:.1f}x)",
                     f"{ms(r['implicit_cg'])} ({r['implicit_cg'] / c:.1f}x)",
                     f"{r['kernel'] * 1e6:.1f} / {r['stream'] * 1e6:.1f} = {r['kernel'] / r['stream']:.2f}",
                     f"{r['sweep'] * 1e6:.1f} / {r['stream'] * 1e6:.1f} = {r['sweep'] / r['stream']:.2f}",
                     f"{r['stream_slices'] * 1e6:.1f}",
                     "{:.2f} / {:.2f} / {:.2f}".format(*PAPER_MS[name])])
        if name == "sphere":
            ok &= r["standard_explicit"] / c >= 2 and r["implicit_direct"] / c >= 20
    print(table(["mesh", "verts", "tets", "clustered ms/step", "sub-steps", "margin", "standard explicit",
                 "implicit direct", "implicit CG", "kernel/stream us", "sweep/stream us", "stream over slices us", "paper std/clust/modal ms"],
                rows))
    print("ratios in brackets: method time / clustered time (higher = clustered faster). "
          "kernel/stream: the whole clustered force (w, slice sweep, finish) against a bare read of the "
          "clusters' blocks and indices, 64-byte aligned (the floor); sweep/stream: the pass over the blocks "
          "alone; 'over slices': the bare read of the kernel's padded slices.")
    print(f"sphere targets (>= 2x standard explicit, >= 20x implicit direct): {'met' if ok else 'NOT met'}")
    worst = max(rows_raw, key=lambda r: r["sweep"] / r["stream"])
    worst_force = max(rows_raw, key=lambda r: r["kernel"] / r["stream"])
    print(f"within 1.5x of the stream: the sweep over the blocks {'yes' if worst['sweep'] / worst['stream'] <= 1.5 else 'NO'} "
          f"(worst {worst['sweep'] / worst['stream']:.2f}, {worst['mesh']}); the whole force "
          f"{'yes' if worst_force['kernel'] / worst_force['stream'] <= 1.5 else 'NO'} "
          f"(worst {worst_force['kernel'] / worst_force['stream']:.2f}, {worst_force['mesh']})")
    if sizes:
        print("  timing kernel and stream by size ...", file=sys.stderr, flush=True)
        print("\nkernel/stream as the sphere's cluster data grows (same kernel, same aligned stream):")
        print(table(["scale", "verts", "tets", "blocks", "cluster MB", "kernel us", "sweep us", "stream us",
                     "kernel/stream", "sweep/stream"], stream_by_size(sizes)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
