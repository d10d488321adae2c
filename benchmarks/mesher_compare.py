"""fTetWild (pytetwild, MPL-2.0) beside TetGen (tetgen, AGPL) on the surfaces a character scene meets.

    python -m benchmarks.mesher_compare [--body PATH_TO_makehuman_base.obj] [--repeat 20]

Surfaces: a clean capsule; two capsules overlapping (self-intersecting, as a body and a separately
modelled limb); the capsule with a hole (not watertight); MakeHuman's body group decimated to 2500
triangles when --body is given. Per mesher: tets, wall time, smallest dihedral angle and radius ratio, or
the error it gave. TetGen is not a dependency of the package (AGPL): install it by hand to compare
(pip install tetgen); the row says so when it is missing.

A second table runs fTetWild ``--repeat`` times on the clean capsule with one edge length: it is not
repeatable, and the spread of its counts is what the edge-length search in fem/mesh/tetrahedralize.py steers
through.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from clusterfem_ros.fem.mesh.tetrahedralize import _mesh_once, read_surface, tet_quality
from .timing import table


def _surfaces(body: str | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    import trimesh
    cap = trimesh.creation.capsule(height=0.6, radius=0.1, count=[16, 16])
    limb = cap.copy()
    limb.apply_transform(trimesh.transformations.rotation_matrix(1.2, [1, 0, 0]))
    limb.apply_translation([0.0, 0.1, 0.1])
    both = trimesh.util.concatenate([cap, limb])
    holed = trimesh.Trimesh(cap.vertices, cap.faces[cap.triangles_center[:, 2] < 0.35])
    out = {"capsule (clean)": (cap.vertices, cap.faces), "two capsules overlapping": (both.vertices, both.faces),
           "capsule with a hole": (holed.vertices, holed.faces)}
    if body:
        import fast_simplification
        v, f = read_surface(body, "body")
        out["MakeHuman body (2500 triangles)"] = fast_simplification.simplify(v, f, target_reduction=1 - 2500 / len(f))
    return out


def run_tetgen(v: np.ndarray, f: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    import tetgen
    tg = tetgen.TetGen(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int32))
    out = tg.tetrahedralize(quality=True, minratio=1.5, maxvolume=edge ** 3 / (6 * np.sqrt(2)), verbose=0)
    return np.asarray(out[0]), np.asarray(out[1])


def _measure(mesher: str, v: np.ndarray, f: np.ndarray, edge: float, diag: float, out) -> None:
    """Run one mesher (in a child process: TetGen can abort the process on self-intersecting input; in a scratch
    folder: both write debug files into the working directory)."""
    import os
    import tempfile
    os.chdir(tempfile.mkdtemp(prefix="clusterfem_mesher_"))
    t0 = time.perf_counter()
    try:
        if mesher == "fTetWild":
            m = _mesh_once(v, f, edge, diag)
            tv, tt = m.vertices, m.tets
        else:
            tv, tt = run_tetgen(v, f, edge)
        secs = time.perf_counter() - t0
        d, r = tet_quality(tv, tt) if len(tt) else (float("nan"), float("nan"))
        out.put([len(tt), f"{secs:.1f}", f"{d:.1f}", f"{r:.3f}", ""])
    except ImportError:
        out.put(["-", "-", "-", "-", "not installed (pip install tetgen; AGPL)"])
    except Exception as exc:  # a mesher's failure is the measurement
        out.put(["-", f"{time.perf_counter() - t0:.1f}", "-", "-", f"{type(exc).__name__}: {str(exc)[:60]}"])


def repeatability(runs: int) -> list:
    """[edge, runs, min, median, max tets, share within 20 % of the median] of fTetWild on the clean capsule."""
    import trimesh
    cap = trimesh.creation.capsule(height=0.6, radius=0.1, count=[16, 16])
    v, f = np.asarray(cap.vertices, dtype=np.float64), np.asarray(cap.faces, dtype=np.int64)
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    edge = 0.116                                        # ~400 tets, the count of the tests' capsule
    n = np.array([_mesh_once(v, f, edge, diag).n_tets for _ in range(runs)])
    med = float(np.median(n))
    return [f"{edge:g} m", runs, int(n.min()), f"{med:g}", int(n.max()), f"{np.mean(abs(n / med - 1) <= 0.2):.0%}"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--body", default=None, help="MakeHuman's base.obj (its group 'body' is used)")
    ap.add_argument("--repeat", type=int, default=20, help="fTetWild runs on one input for the repeatability table")
    a = ap.parse_args(argv)
    rows = []
    for name, (v, f) in _surfaces(a.body).items():
        v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
        diag = float(np.linalg.norm(np.ptp(v, axis=0)))
        edge = diag / 20
        for mesher in ("fTetWild", "TetGen"):
            import multiprocessing as mp
            ctx = mp.get_context("fork")
            q = ctx.Queue()
            child = ctx.Process(target=_measure, args=(mesher, v, f, edge, diag, q))
            child.start()
            child.join()
            rows.append([name, mesher] + (q.get() if not q.empty() else
                                          ["-", "-", "-", "-", f"the process died (exit code {child.exitcode})"]))
    print(table(["surface", "mesher", "tets", "time [s]", "min dihedral [deg]", "min radius ratio", "failure"], rows))
    if a.repeat > 0:
        print("\nfTetWild on the same input and edge length, run after run (the clean capsule):")
        print(table(["edge length", "runs", "min tets", "median", "max tets", "within 20 % of the median"],
                    [repeatability(a.repeat)]))


if __name__ == "__main__":
    main()
