"""The warped step's cost against the linear one, and the clustered step against the standard methods, on the
jelly man and the paper's three objects (docs/benchmarks.md, "Core", has the tables and what they show).

    python -m benchmarks.core_benchmark [--step 1e-3] [--scale 1.0] [--sizes 1,2,4] [--warping-only]

First table: the warped step's cost against the linear one (per-element and per-vertex warping, Neo-Hookean)
on the jelly man (the default scene's body, free, from a twisted state) and the paper's shapes
(``warping_cost``); under it one roofline line: the Neo-Hookean step per tet against the floor its flops and
bytes set on this host, and one line of its serial pass by piece (benchmarks/roofline.py).

Every method runs the same scene (the object's bottom fixed, gravity, same material and step) and is timed after
warm-up (JIT compilation excluded). All methods and kernel pieces of a shape are timed in interleaved rounds
(benchmarks/timing.interleaved_seconds): times are medians over the rounds, ratios the medians of each round's
own ratio, so a slow spell of the host cannot flip a comparison. 'stream' is a bare pass that reads every block
and column index of the clusters once, vectorized: the memory-bound floor for the force kernel.

The floor is the faster of two bare reads of 64-byte-aligned copies of the clusters' block and index arrays:
numba's own loop, which LLVM vectorizes 4 wide (it prefers 256-bit vectors on AVX-512 parts), and an IR loop as
wide as the kernel's vectors (8 doubles); while the blocks sit in L2 the wider read is the faster, so taking
the faster of the two keeps the floor honest on every host. (numpy gives the arrays 16-byte alignment, over
which a stream reads markedly slower.)
'step' is the clustered step's compiled part (ClusteredExplicit.compiled_step: the sweep and the passes
over the vertices), timed inside numba; the whole step, with Python and numba's dispatch, beside it.
'kernel' is the whole force the integrator needs, f = -K (u + zeta v) - xi M v: the w pass, the sweep over the
blocks and the finish in vertex order (cluster_force_kernel.force_kernel_serial). 'sweep' is the pass over
the block data alone (stiffness_slices_serial). 'w held' is the sweep with w held at one row: the same block
loads, FMAs and stores without the gather of w (and without reading the indices), which shows how much of the
sweep's excess over the floor is the gather.
"""
from __future__ import annotations

import argparse
import functools
import statistics
import sys

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core.errors import TypingError
from numba.extending import intrinsic

from clusterfem_ros.fem.kernels.cluster_force_kernel import (cluster_args, force_kernel_serial, scratch,
                                                             slice_force_intrinsic, stiffness_around,
                                                             stiffness_slices_serial)
from clusterfem_ros.fem.kernels.cluster_slices import aligned_zeros, host_slices
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.kernels.llvm_ir import accumulating_loop, i64, vector_at
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.numba_config import contains_threads
from clusterfem_ros.fem.mesh.voxel_mesh import PAPER_SHAPES, paper_mesh
from .roofline import pieces_line, roofline_line
from .timing import interleaved_seconds, paired_ratio, table

PAPER_MS = {"sphere": (1.60, 0.73, 0.83), "cube": (1.89, 0.92, 1.09), "torus": (2.15, 0.97, 1.12)}
MATERIAL = Material(E=3.0e4, nu=0.3, rho=1000.0, xi=1.0, zeta=1e-5)
# The gather's control: the serial stiffness sweep with w held at row 0 (the same block loads and FMAs, no
# gather of w); its time against the full sweep's is the gather's cost.
stiffness_held_w_serial = stiffness_around(slice_force_intrinsic(gather=False), "_held_w")


@intrinsic(prefer_literal=True)
def _wide_sum(typingctx, lanes, a, m):
    """The sum of a[:m] (m a multiple of 4 * lanes) in four accumulators of ``lanes``-wide vectors: LLVM
    vectorizes numba's loops 4 wide on this host (it prefers 256-bit vectors on AVX-512 parts), while the
    force kernel loads 8 doubles at a time, so the floor needs a read as wide as the kernel's."""
    if not isinstance(lanes, types.IntegerLiteral):
        raise TypingError(f"_wide_sum: lanes must be a literal, got {lanes}")
    if not (isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype in (types.float64, types.int64)):
        raise TypingError(f"_wide_sum: a must be a 1-d C-contiguous float64 or int64 array, got {a}")
    C = lanes.literal_value
    dt = a.dtype

    def codegen(context, builder, signature, args):
        is_float = dt == types.float64
        vt = ir.VectorType(context.get_value_type(dt), C)
        add = builder.fadd if is_float else builder.add
        data = context.make_array(signature.args[1])(context, builder, args[1]).data
        m = context.cast(builder, args[2], signature.args[2], types.int64)
        zero = ir.Constant(vt, [0.0 if is_float else 0] * C)

        def four_vectors(k, acc):
            return [add(a_k, builder.load(vector_at(builder, data, builder.add(k, i64(j * C)), vt), align=8))
                    for j, a_k in enumerate(acc)]

        totals = accumulating_loop(builder, i64(0), m, 4 * C, [zero] * 4, four_vectors)
        v = add(add(totals[0], totals[1]), add(totals[2], totals[3]))
        out = builder.extract_element(v, ir.Constant(ir.IntType(32), 0))
        for lane in range(1, C):
            out = add(out, builder.extract_element(v, ir.Constant(ir.IntType(32), lane)))
        return out

    return dt(lanes, a, m), codegen


@numba.njit(cache=True)
def _flat_sum(a, lanes):
    """The sum of a 1-d array, ``lanes`` (8 or 4) wide, the tail past the last 4 * lanes elements one by one."""
    m = a.shape[0] - a.shape[0] % (4 * lanes)
    s = _wide_sum(8, a, m) if lanes == 8 else _wide_sum(4, a, m)
    for k in range(m, a.shape[0]):
        s += a[k]
    return s


@numba.njit(cache=True)
def _wide_stream(sh_cols, sh_blocks, bd_cols, bd_blocks, reps, lanes):
    """The bare read of _stream, in four accumulators of ``lanes``-wide vectors (the kernel's lanes)."""
    s = 0.0
    t = 0
    for _ in range(reps):
        s += _flat_sum(sh_blocks.reshape(-1), lanes) + _flat_sum(bd_blocks.reshape(-1), lanes)
        t += _flat_sum(sh_cols.reshape(-1), lanes) + _flat_sum(bd_cols.reshape(-1), lanes)
    return s + t


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


@functools.lru_cache(maxsize=None)
def _inside_numba(fn):
    """A compiled loop that calls ``fn(*args)`` reps times: its time per call has no Python dispatch in it.
    One loop per function (numba compiles it once per argument types). Serial builds only: a threaded build
    would be inlined into this loop (numba_config.PARALLEL) and run serial."""
    if contains_threads(fn):
        raise ValueError(f"in_numba times serial builds; {fn.__name__} is threaded: time it from Python")
    @numba.njit
    def loop(args, reps):
        for _ in range(reps):
            fn(*args)
    return loop


def in_numba(fn, args: tuple, reps: int):
    """A zero-argument callable that runs ``fn(*args)`` reps times inside numba (_inside_numba)."""
    return functools.partial(_inside_numba(fn), args, reps)


def aligned_copy(a: np.ndarray, alignment: int = 64) -> np.ndarray:
    """A copy of ``a`` whose data starts on an ``alignment``-byte boundary."""
    out = aligned_zeros(a.shape, a.dtype, alignment)
    out[...] = a
    return out


def kernel_calls(model, reps: int = 200) -> dict[str, object]:
    """Zero-argument callables that each run one piece ``reps`` times inside numba (no dispatch per call):
    - kernel: the whole force, w = u + zeta v, the slice sweep and the finish (-xi M v, vertex order);
    - sweep: the pass over the slices alone; held: the same pass with w held (no gather of w);
    - stream4, stream8: the bare reads of 64-byte-aligned copies of the clusters' own blocks and indices (numba's
      loop, which LLVM vectorizes 4 wide here, and an IR loop as wide as the kernel's vectors; numpy gives the
      arrays 16-byte alignment, over which the stream ran up to 1.7x slower on one host); the floor is the
      faster of the two in each round (per_call);
    - slices4, slices8: the same bare reads of the kernel's slices (the same blocks plus 0.5-2.5 % padding)."""
    cl = model.clusters
    sl = host_slices(cl)
    n = model.n_vertices
    rng = np.random.default_rng(0)
    u, v = rng.normal(size=(2, n, 3))
    w, kw = scratch(sl)
    f = np.empty((n, 3))
    mass3 = np.repeat(model.mass, 3)
    args = cluster_args(sl)
    lanes = 8 if sl.lanes == 8 else 4
    aligned = tuple(aligned_copy(a) for a in (cl.shared_cols, cl.shared_blocks, cl.boundary_cols, cl.boundary_blocks))
    sliced = (sl.shared_w_at.reshape(-1), sl.shared_blocks, sl.boundary_w_at.reshape(-1), sl.boundary_blocks)

    return {
        "kernel": in_numba(force_kernel_serial, (*args, u, v, mass3, 1e-3, 1.0, w, kw, f), reps),
        "sweep": in_numba(stiffness_slices_serial, (*args, w, kw), reps),
        "held": in_numba(stiffness_held_w_serial, (*args, w, kw), reps),
        "stream4": lambda: _stream(*aligned, reps),
        "stream8": lambda: _wide_stream(*aligned, reps, lanes),
        "slices4": lambda: _stream(*sliced, reps),
        "slices8": lambda: _wide_stream(*sliced, reps, lanes),
    }


def per_call(samples: dict[str, list[float]], reps: dict[str, int]) -> dict[str, list[float]]:
    """Interleaved samples per call (batches of ``reps[name]`` calls, 1 if absent), with the floor ``stream``
    (and ``stream_slices``) the faster of the 4- and 8-wide reads in each round."""
    out = {name: [t / reps.get(name, 1) for t in ts] for name, ts in samples.items()}
    for floor, pair in (("stream", ("stream4", "stream8")), ("stream_slices", ("slices4", "slices8"))):
        if all(p in out for p in pair):
            out[floor] = [min(a, b) for a, b in zip(out[pair[0]], out[pair[1]])]
    return out


def summarize(samples: dict[str, list[float]], base: str, keys) -> dict:
    """Median seconds per call of every entry, and (key, base) -> the paired ratio of key to base."""
    out = {name: statistics.median(ts) for name, ts in samples.items()}
    out.update({(key, base): paired_ratio(samples[key], samples[base]) for key in keys})
    return out


def stream_by_size(scales: list[float]) -> list[list[object]]:
    """Kernel against stream on the sphere as its cluster data grows out of L1/L2 into L3 and memory."""
    rows = []
    for scale in scales:
        mesh = paper_mesh("sphere", scale)
        model = build_model(mesh, MATERIAL)
        cl = model.clusters
        reps = max(5, 800_000 // cl.n_blocks)
        calls = kernel_calls(model, reps)
        t = summarize(per_call(interleaved_seconds(calls), dict.fromkeys(calls, reps)), "stream",
                      ("kernel", "sweep", "held"))
        us = lambda key: f"{t[key] * 1e6:.1f}"  # noqa: E731
        rows.append([f"{scale:g}", mesh.n_vertices, mesh.n_tets, cl.n_blocks, f"{cl.nbytes / 1e6:.2f}",
                     us("kernel"), us("sweep"), us("held"), us("stream"), f"{t['kernel', 'stream']:.2f}",
                     f"{t['sweep', 'stream']:.2f}", f"{t['held', 'stream']:.2f}"])
    return rows


METHODS = ("clustered", "standard_explicit", "implicit_direct", "implicit_cg")

WARPINGS = {"linear": {}, "warped, element": {"warp": True, "warping_model": "element"},
            "warped, vertex": {"warp": True, "warping_model": "vertex", "allow_unbounded_warping": True},
            "neohookean": {"warp": True, "warping_model": "neohookean"}}


def twisted_state(model) -> State:
    """The body twisted about its vertical axis, 0.5 rad from bottom to top, plus a shear of 5 %: rotations and
    strains like a moving body's, so the polar iterations take their usual number of passes (at rest they stop
    after one)."""
    x = model.rest
    z = (x[:, 2] - x[:, 2].min()) / np.ptp(x[:, 2])
    th = 0.5 * z
    c, sn = np.cos(th), np.sin(th)
    state = State.rest(model)
    state.u[:, 0] = c * x[:, 0] - sn * x[:, 1] - x[:, 0] + 0.05 * np.ptp(x[:, 2]) * z
    state.u[:, 1] = sn * x[:, 0] + c * x[:, 1] - x[:, 1]
    return state


def warping_cost(model, h: float, reps: int = 50) -> dict:
    """The clustered step's compiled part (serial, inside numba) linear and with each warping model, timed
    interleaved from the twisted state (twisted_state): median seconds per step by name and the paired ratios
    (name, 'linear')."""
    calls, lam = {}, None
    for label, opts in WARPINGS.items():
        integ = make_integrator("clustered", model, threads=False, **opts, **({"lam_max": lam} if lam else {}))
        lam = integ.lam_max
        state, control = twisted_state(model), Control()
        fn, args = integ.compiled_step(state, control, h)
        fn(*args)                                           # compiled or loaded before timing
        calls[label] = in_numba(fn, args, reps)
    return summarize(per_call(interleaved_seconds(calls), dict.fromkeys(calls, reps)), "linear", list(WARPINGS)[1:])


def jelly_man_model(target_tets: int):
    """The default scene's jelly man (benchmarks/jelly_report.build_scene), or None without the skeleton package."""
    from .jelly_report import build_scene
    try:
        return build_scene(target_tets, 0.01, 1e-3)[2]
    except ImportError:
        return None


def warping_rows(h: float, target_tets: int, timed: dict | None = None) -> list[list[object]]:
    """warping_cost on the jelly man and the paper's shapes, as table rows; ``timed`` gets each body's
    (tets, warping_cost, model)."""
    bodies = [("jelly man", jelly_man_model(target_tets))]
    for name in PAPER_SHAPES:
        mesh = paper_mesh(name)
        bodies.append((name, build_model(mesh, MATERIAL, fixed=mesh.vertices[:, 2] < mesh.vertices[:, 2].min() + 1e-9)))
    rows = []
    for name, model in bodies:
        if model is None:
            continue
        print(f"  timing warping on {name} ...", file=sys.stderr, flush=True)
        t = warping_cost(model, h)
        if timed is not None:
            timed[name] = (model.mesh.n_tets, t, model)
        us = lambda k: f"{t[k] * 1e6:.1f}"  # noqa: E731
        rows.append([name, model.n_vertices, model.mesh.n_tets, us("linear"),
                     f"{us('warped, element')} ({t['warped, element', 'linear']:.2f}x)",
                     f"{us('warped, vertex')} ({t['warped, vertex', 'linear']:.2f}x)",
                     f"{us('neohookean')} ({t['neohookean', 'linear']:.2f}x)"])
    return rows


def bench_shape(name: str, h: float, scale: float, reps: int = 200) -> dict:
    """Every method's step and the kernel pieces on one shape, timed interleaved (timing.interleaved_seconds):
    median seconds per call by name, paired ratios under (name, 'clustered') and (name, 'stream')."""
    mesh = paper_mesh(name, scale)
    zmin = mesh.vertices[:, 2].min()
    model = build_model(mesh, MATERIAL, fixed=mesh.vertices[:, 2] < zmin + 1e-9 + 0.2 * np.ptp(mesh.vertices[:, 2]))
    out = {"mesh": name, "vertices": mesh.n_vertices, "tets": mesh.n_tets, "blocks": model.clusters.n_blocks}
    calls, lam = {}, None
    for method in METHODS:
        opts = {} if method.startswith("implicit") else ({"lam_max": lam} if lam else {})
        integ = make_integrator(method, model, **opts)
        lam = getattr(integ, "lam_max", lam)
        state, control = State.rest(model), Control()
        info = integ.step(state, control, h)
        for _ in range(200):            # past JIT, cache loads and the first-touch of every array
            integ.step(state, control, h)
        calls[method] = functools.partial(integ.step, state, control, h)
        if method == "clustered":
            out["substeps"] = info.substeps
            out["margin"] = info.margin
            fn, args = integ.compiled_step(state, control, h)
            calls["step_numba"] = in_numba(fn, args, reps)
    pieces = kernel_calls(model, reps)
    calls.update(pieces)
    samples = per_call(interleaved_seconds(calls), dict.fromkeys([*pieces, "step_numba"], reps))
    out.update(summarize(samples, "clustered", METHODS[1:]))
    out.update(summarize(samples, "stream", ("step_numba", "kernel", "sweep", "held")))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step", type=float, default=1e-3, help="physics step h in seconds (default 1e-3)")
    ap.add_argument("--scale", type=float, default=1.0, help="mesh refinement factor (1 = the paper's sizes)")
    ap.add_argument("--warping-only", action="store_true",
                    help="print only the warped-step cost table (jelly man and the paper's shapes)")
    ap.add_argument("--tets", type=int, default=4800, help="the jelly man's approximate tet count (default 4800)")
    ap.add_argument("--sizes", default="1,2,4",
                    help="sphere scales for the kernel/stream-by-size table (comma-separated; '' skips it)")
    args = ap.parse_args(argv)
    try:
        sizes = [float(x) for x in args.sizes.split(",") if x.strip()]
    except ValueError:
        ap.error(f"--sizes {args.sizes!r}: expected comma-separated numbers such as 1,2,4")
    print(f"material E={MATERIAL.E:g} Pa nu={MATERIAL.nu} rho={MATERIAL.rho:g} xi={MATERIAL.xi} "
          f"zeta={MATERIAL.zeta:g}; h = {args.step:g} s; numba threads off (serial kernels)", flush=True)
    print("\nwarped step cost: the clustered step's compiled part (serial, timed inside numba) from a twisted state, "
          "us per step, ratio to the linear step in brackets (paired medians of interleaved rounds); 'element': "
          "per-element corotation (fem/materials/element_warping.py), 'vertex': the paper's per-vertex warping "
          "(fem/materials/warping.py), 'neohookean': stable Neo-Hookean elements (fem/materials/neohookean.py)")
    timed = {}
    print(table(["body", "verts", "tets", "linear us", "warped, element us", "warped, vertex us", "neohookean us"],
                warping_rows(args.step, args.tets, timed)))
    body = "jelly man" if "jelly man" in timed else next(iter(timed), None)
    if body is not None:
        tets, t, model = timed[body]
        print(roofline_line(body, tets, t["neohookean"], t["linear"]))
        print(pieces_line(body, model, twisted_state(model).u, t["neohookean"]))
    if args.warping_only:
        return 0
    rows, rows_raw, ok = [], [], True
    print("  warming up (one untimed pass: the first shape timed in a fresh process ran ~1.8x slow)",
          file=sys.stderr, flush=True)
    bench_shape(PAPER_SHAPES[0], args.step, args.scale)
    for name in PAPER_SHAPES:
        print(f"  timing {name} ...", file=sys.stderr, flush=True)
        r = bench_shape(name, args.step, args.scale)
        rows_raw.append(r)
        c = r["clustered"]
        ms = lambda s: f"{s * 1e3:.3g}"  # noqa: E731  (3 significant digits: the clustered step is ~0.007 ms)
        rows.append([name, r["vertices"], r["tets"], ms(c), f"{r['substeps']}", f"{r['margin']:.2f}",
                     *(f"{ms(r[m])} ({r[m, 'clustered']:.1f}x)" for m in METHODS[1:]),
                     f"{r['step_numba'] * 1e6:.1f} ({c * 1e6:.1f}) / {r['stream'] * 1e6:.1f}: "
                     f"{r['step_numba', 'stream']:.2f}",
                     f"{r['kernel'] * 1e6:.1f} / {r['stream'] * 1e6:.1f}: {r['kernel', 'stream']:.2f}",
                     f"{r['sweep'] * 1e6:.1f} / {r['stream'] * 1e6:.1f}: {r['sweep', 'stream']:.2f}",
                     f"{r['held'] * 1e6:.1f} ({r['held', 'stream']:.2f})",
                     f"{r['stream_slices'] * 1e6:.1f}",
                     "{:.2f} / {:.2f} / {:.2f}".format(*PAPER_MS[name])])
        if name == "sphere":
            ok &= r["standard_explicit", "clustered"] >= 2 and r["implicit_direct", "clustered"] >= 20
    print(table(["mesh", "verts", "tets", "clustered ms/step", "sub-steps", "margin", "standard explicit",
                 "implicit direct", "implicit CG", "step/stream us", "kernel/stream us", "sweep/stream us",
                 "sweep, w held us",
                 "stream over slices us", "paper std/clust/modal ms"],
                rows))
    print("times: medians over rounds that time every method and kernel piece in turn; ratios: medians of the "
          "rounds' own ratios (a slow spell of the host falls on both sides of each). "
          "ratios in brackets: method time / clustered time (higher = clustered faster). "
          "step/stream: the clustered step's compiled part, timed inside numba (in brackets the whole step, "
          "Python and dispatch included), against the floor; "
          "kernel/stream: the whole clustered force (w, slice sweep, finish) against a bare read of the "
          "clusters' blocks and indices, 64-byte aligned, the faster of a 4- and an 8-wide read (the floor); "
          "sweep/stream: the pass over the blocks alone; 'w held': the sweep without gathering w (same block loads, "
          "FMAs and stores), its ratio to the stream in brackets; 'over slices': the bare read of the "
          "kernel's padded slices.")
    print(f"sphere targets (>= 2x standard explicit, >= 20x implicit direct): {'met' if ok else 'NOT met'}")
    verdicts = []
    for key, what in (("step_numba", "the step's compiled part"), ("kernel", "the whole force"),
                      ("sweep", "the sweep over the blocks")):
        worst = max(rows_raw, key=lambda r: r[key, "stream"])
        ratio = worst[key, "stream"]
        verdicts.append(f"{what} {'yes' if ratio <= 1.5 else 'NO'} (worst {ratio:.2f}, {worst['mesh']})")
    print("within 1.5x of the stream: " + "; ".join(verdicts))
    if sizes:
        print("  timing kernel and stream by size ...", file=sys.stderr, flush=True)
        print("\nkernel/stream as the sphere's cluster data grows (same kernel, same aligned stream):")
        print(table(["scale", "verts", "tets", "blocks", "cluster MB", "kernel us", "sweep us", "w held us",
                     "stream us", "kernel/stream", "sweep/stream", "held/stream"], stream_by_size(sizes)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
