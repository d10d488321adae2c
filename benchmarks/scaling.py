"""Scaling: ms/step and memory against mesh size, 1k to 200k+ tets, with the fitted log-log slope.

    python -m benchmarks.scaling [--max-tets 220000] [--timeout 900]

Body: the paper's cube (0.1 m, bottom 20 % held, the core benchmark's material) split into n^3 voxels
of 5 tets. Step h = 0.8 h_crit(n), so the explicit methods do exactly one sub-step: the columns are the
cost of one step of each method at the same h (at a fixed h the explicit cost grows by another factor
n ~ tets^(1/3), since h_crit ~ 1/n).

Methods: clustered (serial kernel and the threaded build on both cores), clustered + warping (same),
standard implicit (direct: SuperLU in symmetric mode, factorized once, fem/integrators/spd_factor.py; CG:
Jacobi-preconditioned, warm-started) and modal 30. Each (size, method) runs in its own process so its
memory can be measured: 'model MB' is the resident memory the assembled model adds, 'method MB' the peak
resident memory of the method's set-up and stepping above that (Linux peak-RSS counter reset with
/proc/self/clear_refs; the method's numba code is loaded on a tiny model first, so neither counts
compiled code). ms/step is the median after warm-up (JIT excluded); set-up (factorization, eigen-solve,
largest eigenvalue) is reported separately. A full run takes about 7 minutes on 2 cores; implicit direct
and modal 30 spend 94 and 118 s of it setting up at 214k tets (docs/benchmarks.md has the latest table).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time

import numpy as np

DIVISIONS = (6, 10, 16, 22, 28, 35)            # 1080 ... 214375 tets
METHODS = {                                     # label -> (make_integrator method, options)
    "clustered": ("clustered", {"threads": False}),
    "clustered x2": ("clustered", {"threads": True}),
    "clustered_warp": ("clustered", {"threads": False, "warp": True}),
    "clustered_warp x2": ("clustered", {"threads": True, "warp": True}),
    "implicit_direct": ("implicit_direct", {}),
    "implicit_cg": ("implicit_cg", {}),
    "modal_30": ("modal", {"k": 30}),
}


def _status_kb(field: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    return 0


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def measure_one(n: int, label: str) -> dict:
    """One (size, method) in this process; returns the numbers as a dict (printed as JSON by --one)."""
    from clusterfem_ros.fem.integrators import make_integrator
    from clusterfem_ros.fem.kernels.cluster_slices import host_slices_nbytes
    from clusterfem_ros.fem.model import Control, State, build_model
    from clusterfem_ros.fem.stability import critical_step, max_eigenvalue
    from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
    from .core_benchmark import MATERIAL
    from .timing import median_seconds
    method, opts = METHODS[label]
    tiny = build_model(box_mesh((0.1,) * 3, (2, 2, 2)), MATERIAL, fixed=np.arange(4))
    make_integrator(method, tiny, **opts).step(State.rest(tiny), Control(), 1e-4)   # load/compile numba code
    rss0 = _status_kb("VmRSS")
    mesh = box_mesh((0.1, 0.1, 0.1), (n, n, n), (-0.05, -0.05, -0.05))
    z = mesh.vertices[:, 2]
    model = build_model(mesh, MATERIAL, fixed=z <= z.min() + 0.2 * np.ptp(z))
    t0 = time.perf_counter()
    lam = max_eigenvalue(model)
    lam_s = time.perf_counter() - t0
    h = 0.8 * critical_step(lam, MATERIAL.xi, MATERIAL.zeta) * (1 - 1e-9)
    rss_model = _status_kb("VmRSS")
    exact = _reset_peak()
    if method == "clustered":
        opts = dict(opts, lam_max=lam)
    t0 = time.perf_counter()
    integ = make_integrator(method, model, **opts)
    state, control = State.rest(model), Control()
    integ.step(state, control, h)                   # factorization / first compile happen here
    setup = time.perf_counter() - t0 + (lam_s if method == "clustered" else 0.0)
    sec = median_seconds(lambda: integ.step(state, control, h), min_time=1.0, repeats=5, warmup=2)
    peak = _status_kb("VmHWM")
    return {"n": n, "method": label, "tets": mesh.n_tets, "vertices": mesh.n_vertices, "h": h,
            "ms": sec * 1e3, "setup_s": setup, "model_mb": (rss_model - rss0) / 1024,
            "method_mb": max(peak - rss_model, 0) / 1024, "peak_exact": exact,
            "clusters_mb": model.clusters.nbytes / 1e6, "slices_mb": host_slices_nbytes(model.clusters) / 1e6}


def _child(n: int, label: str, timeout: float) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.scaling", "--one", str(n), label]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"n": n, "method": label, "error": f"timeout after {timeout:g} s"}
    for line in reversed(r.stdout.splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    tail = (r.stderr.strip().splitlines() or ["no output"])[-1]
    return {"n": n, "method": label, "error": tail[:160]}


def slope(rows: list[dict], key: str = "ms") -> float:
    """Fitted log-log slope of ``key`` against tets (nan with fewer than 2 points)."""
    pts = [(r["tets"], r[key]) for r in rows if "error" not in r and r.get(key, 0) > 0]
    if len(pts) < 2:
        return math.nan
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--max-tets", type=int, default=220000, help="largest mesh (default 220000)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds allowed per (size, method) process")
    ap.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    ap.add_argument("--one", nargs=2, metavar=("N", "METHOD"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure_one(int(args.one[0]), args.one[1])), flush=True)
        return 0
    from .timing import table
    sizes = [n for n in DIVISIONS if 5 * n ** 3 <= args.max_tets]
    if not sizes:
        print(f"--max-tets {args.max_tets} is below the smallest mesh ({5 * DIVISIONS[0] ** 3} tets)", file=sys.stderr)
        return 2
    results: dict[str, list[dict]] = {m: [] for m in args.methods}
    t_start = time.perf_counter()
    failed: set[str] = set()
    for n in sizes:
        for m in args.methods:
            if m in failed:             # a method that timed out on a smaller mesh is not retried on larger
                results[m].append({"n": n, "method": m, "tets": 5 * n ** 3, "error": "skipped (failed smaller)"})
                continue
            r = _child(n, m, args.timeout)
            r.setdefault("tets", 5 * n ** 3)
            results[m].append(r)
            if "error" in r:
                failed.add(m)
            print(f"[{time.perf_counter() - t_start:6.0f} s] {r['tets']:7d} tets {m:18s} "
                  + (r["error"] if "error" in r else
                     f"{r['ms']:9.3f} ms/step  set-up {r['setup_s']:6.2f} s  method {r['method_mb']:7.1f} MB"),
                  file=sys.stderr, flush=True)
    first = next(r for rs in results.values() for r in rs if "error" not in r)
    heads = ["tets (vertices)"] + [f"{m} ms/step (MB)" for m in args.methods]
    rows = []
    for i, n in enumerate(sizes):
        base = next((results[m][i] for m in args.methods if "error" not in results[m][i]), results[args.methods[0]][i])
        rows.append([f"{base['tets']} ({base.get('vertices', '?')})"] +
                    [("n/a: " + results[m][i]["error"][:40]) if "error" in results[m][i] else
                     f"{results[m][i]['ms']:.3f} ({results[m][i]['method_mb']:.0f})" for m in args.methods])
    rows.append(["log-log slope ms"] + [f"{slope(results[m]):.2f}" for m in args.methods])
    rows.append(["log-log slope MB"] + [f"{slope(results[m], 'method_mb'):.2f}" for m in args.methods])
    print(f"cube 0.1 m, bottom 20 % held; h = 0.8 h_crit(n) (one explicit sub-step), "
          f"e.g. {first['h']:.3g} s at {first['tets']} tets; peak memory counter reset: {first['peak_exact']}")
    print(table(heads, rows))
    setup = [[f"{results[args.methods[0]][i]['tets']}"] +
             [("n/a" if "error" in results[m][i] else f"{results[m][i]['setup_s']:.2f}") for m in args.methods]
             for i in range(len(sizes))]
    print("\nset-up seconds (largest eigenvalue, factorization, modal basis):")
    print(table(["tets"] + list(args.methods), setup))
    model_mb = [f"{results[args.methods[0]][i]['tets']}: {results[args.methods[0]][i].get('model_mb', math.nan):.0f} MB"
                for i in range(len(sizes))]
    print("\nmodel (mesh, K, clusters) resident memory: " + ", ".join(model_mb)
          + f"; log-log slope {slope(results[args.methods[0]], 'model_mb'):.2f}")
    if "clustered" in results:
        packed = [f"{r['tets']}: {r['clusters_mb']:.0f} + {r['slices_mb']:.0f} MB" for r in results["clustered"]
                  if "error" not in r and "slices_mb" in r]
        print("the linear clustered step's data, clusters + their SIMD slices (a second copy of the blocks; the "
              "process reuses memory freed after assembly, so 'method MB' does not see it): " + ", ".join(packed))
    if "clustered" in results and "clustered x2" in results:
        gain = [f"{a['tets']}: {a['ms'] / b['ms']:.2f}x" for a, b in zip(results["clustered"], results["clustered x2"])
                if "error" not in a and "error" not in b]
        print("two-core speed-up of the clustered step: " + ", ".join(gain))
    return 0


if __name__ == "__main__":
    sys.exit(main())
