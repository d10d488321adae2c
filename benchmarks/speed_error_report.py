"""Speed against error (issue 6): every method, several steps, on the paper's shapes and the jelly man.

    python -m benchmarks.speed_error_report [--quick] [--out reports/speed_error]

Scenes. 'sphere', 'cube', 'torus': the paper-sized object (``paper_mesh``), its bottom 20 % held,
under gravity from rest for ``duration`` s (the core benchmark's material). 'jelly_man': the default
jelly man (``jelly_report.build_scene``) carried by the built-in walk, started on the skeleton.
Every method of a scene sees the same model, start state and inputs (the same trajectory object,
sampled at each method's own step times).

Methods: implicit_direct and implicit_cg (eq. 3), standard_explicit, clustered (the linear model),
clustered_warp (the per-element corotated model, fem/materials/element_warping.py), clustered_neohookean (the stable
Neo-Hookean elements every scene runs by default, fem/materials/neohookean.py), modal_10 / 30 / 60. Each table row names
the model its method runs (linear, corotated, neohookean). Explicit methods take the requested step h as their
outer step and sub-step inside it below their critical step (safety 0.8; a warped one also for the stretch,
fem/materials/stretch.py), as the node does.

Timing: the median wall time of one physics step (inputs excluded) over the run, after three warm-up
steps on a throw-away copy of the state (numba compiled, the implicit factor and modal basis built);
set-up (factorization, eigen-solve) is reported separately. A scene's runs (every method and step, each
with its own integrator) take turns of 10 steps or more (``interleaved_runs``), so a slow spell of the
host falls on all of them; the first step of a turn, whose caches the other runs have emptied, is not
timed. Cost across different steps is compared per simulated second, ms/step / h: a step twice as long
covers twice the time.

Reference: the same model stepped by symplectic Euler (the clustered kernel, linear or warped as the
method under test) with sub-steps of 0.02 of the critical step, 40 times finer than the methods' own
0.8. Why not implicit Euler at a small step: its error is numerical damping of order h omega^2 t / 2
in amplitude; for the sphere's first mode (omega ~ 60 rad/s) over 0.5 s at h = 1e-5 s that is ~1 %,
as large as the error of the clustered method we want to measure, and its error goes down only as h.
Symplectic Euler has no numerical damping. Measured on the sphere (0.5 s): the reference at 0.05 of
the critical step differs from one at 0.0125 by 1.4e-3 relative L2 (0.012 mm), and converges at first
order, so at 0.02 it is ~3e-4 from converged: 2-3 % of the smallest error measured here (the clustered
method's 1.3e-2). On the jelly man the reference also refreshes its inputs every 2.5e-5 s, 20 times
more often than the finest step measured (the inputs are the same continuous walk, sampled at each
run's own step times); there the error falls as h^1.8 (21 mm at 1e-3 s, 1.9 mm at 2.5e-4 s against
a 1e-4 s reference), so the reference is ~0.03 mm from converged. Errors of modal and of the
implicit and linear explicit methods are against the linear reference; clustered_warp against the
corotated one, clustered_neohookean against the Neo-Hookean one (each model's own converged solution: the
error measures the step, not the difference between the models). Von Mises stress: the linear one for the
linear model, the corotated one (rotation removed) for the two nonlinear models.

Errors, over the samples every ``sample_dt`` of the run: relative L2 of the displacement
sum |u - u_ref|^2 / sum |u_ref - u_carried|^2 (u_carried: the skeleton's rigid carry of the jelly man,
zero for the shapes, so only deformation counts), the max vertex error [mm], the relative L2 of the
element von Mises stress (corotated for the warped model), and max |V - V_ref| / V0 [%].

Writes the measured points as CSV (read by clusterfem_ros.method_choice): a full run (every scene, not
--quick) replaces the copy the package ships (clusterfem_ros/data/speed_error.csv, what a scene's error
budget reads), a partial one writes <out>/speed_error.csv; ``--points`` names another file. Writes into
``--out``: speed_error.md (tables, beside the paper's Table 1), speed_error.png (error against compute per
simulated second, log-log, Pareto front marked) and figure5.png (displacement difference to the
reference on the surface, clustered vs modal 30: the paper's Figure 5). In the same run the shapes go
through MuJoCo's tetrahedral flex (benchmarks/peer_mujoco.py: ms/step and what each computes) unless --no-peer.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.stability import DivergenceError
from clusterfem_ros.fem.materials.stress import compute_stress
from clusterfem_ros.fem.mesh.tet_mesh import boundary_triangles, signed_volumes
from clusterfem_ros.method_choice import METRICS, SHIPPED_POINTS, MeasuredPoint, choose, pareto_front, write_points
from .core_benchmark import MATERIAL, PAPER_MS
from .scenarios import Run, RunInProgress, Scenario, make_scenario, reference
from .timing import table

# label -> (make_integrator method, options, model kind)
METHODS = {
    "implicit_direct": ("implicit_direct", {}, "linear"),
    "implicit_cg": ("implicit_cg", {}, "linear"),
    "standard_explicit": ("standard_explicit", {}, "linear"),
    # serial kernels, as the report says: on the jelly man (1803 vertices) the integrator's default would
    # time both builds and keep the faster, which made one warped point 1.5x slower than its twin
    "clustered": ("clustered", {"threads": False}, "linear"),
    "clustered_warp": ("clustered", {"threads": False, "warp": True}, "corotated"),
    "clustered_neohookean": ("clustered", {"threads": False, "warp": True, "warping_model": "neohookean"},
                             "neohookean"),
    "modal_10": ("modal", {"k": 10}, "linear"),
    "modal_30": ("modal", {"k": 30}, "linear"),
    "modal_60": ("modal", {"k": 60}, "linear"),
}
TABLE_H = 1e-3              # step of the Table 1 comparison (the paper does not give its step)
FULL = dict(scenes=("sphere", "cube", "torus", "jelly_man"), steps=(1e-2, 5e-3, 2e-3, 1e-3, 5e-4),
            walk_steps=(5e-3, 2e-3, 1e-3, 5e-4), duration=0.5, walk_duration=1.0, sample_dt=0.01)
QUICK = dict(scenes=("sphere", "jelly_man"), steps=(5e-3, 2e-3, 1e-3), walk_steps=(5e-3, 2e-3, 1e-3),
             duration=0.2, walk_duration=0.2, sample_dt=0.01)


# Each run's turn lasts at least this many steps; its first step is not timed (cold caches after the others').
TURN_STEPS = 10
FAILURES = (DivergenceError, RuntimeError, ValueError, FloatingPointError)


def failure_status(e: Exception) -> str:
    return f"{type(e).__name__}: {str(e).splitlines()[0][:120]}"


def interleaved_runs(runs: dict, progress: Callable[[str], None] = lambda s: None) -> dict:
    """Advance every RunInProgress of ``runs`` by turns of TURN_STEPS steps or more until all are done, so a
    slow spell of the host (a shared VM can slow down 1.5-2x for seconds) falls on all of them alike instead
    of on whichever is running: timed one after the other, modal_10's step (whose cost does not depend on h)
    can read 1.7x its neighbours', and implicit CG's at 1 ms more than its cost at 2 ms. Returns, per
    key, the run's Run or the failure's status; ``progress`` hears every quarter of the samples."""
    out: dict = {}
    live = dict(runs)
    total = max((r.sc.n_samples for r in runs.values()), default=0)
    told = 0
    while live:
        for key, r in list(live.items()):
            try:
                r.advance(-(-TURN_STEPS // r.per), time_first=False)
            except FAILURES as e:
                out[key] = failure_status(e)
                del live[key]
                continue
            if r.done:
                out[key] = r.result()
                del live[key]
        reached = max((r.samples_done for r in live.values()), default=total)
        if total and reached * 4 // total > told and live:
            told = reached * 4 // total
            progress(f"sample {reached}/{total} of every run, {len(live)} runs in turn")
    return out


@dataclass
class RefData:
    run: Run
    von_mises: np.ndarray           # (S', m) at the stress samples
    volume: np.ndarray              # (S,)
    norm: float                     # sqrt(sum |u_ref - u_carried|^2)
    stress_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


MAX_STRESS_SAMPLES = 25


def reference_data(sc: Scenario, run: Run, corotated: bool) -> RefData:
    S = sc.n_samples
    idx = np.unique(np.linspace(0, S - 1, min(S, MAX_STRESS_SAMPLES)).round().astype(int))
    vm = np.stack([compute_stress(sc.model, run.u[j], corotated=corotated).element_von_mises for j in idx])
    vol = np.array([signed_volumes(sc.model.rest + run.u[j], sc.model.mesh.tets).sum() for j in range(S)])
    if sc.carried is None:
        norm = float(np.sqrt((run.u ** 2).sum()))
    else:
        norm = float(np.sqrt(sum(((run.u[j] - sc.carried((j + 1) * sc.sample_dt)) ** 2).sum() for j in range(S))))
    return RefData(run, vm, vol, max(norm, 1e-300), idx)


def errors(sc: Scenario, u: np.ndarray, ref: RefData, corotated: bool) -> dict:
    """The four error metrics of a run's samples ``u`` (S, n, 3) against the reference (module docstring)."""
    if u.shape != ref.run.u.shape:
        raise ValueError(f"run samples {u.shape} do not match the reference {ref.run.u.shape}")
    if not np.isfinite(u).all():
        return {m: math.nan for m in METRICS}
    d = u - ref.run.u
    vm = np.stack([compute_stress(sc.model, u[j], corotated=corotated).element_von_mises for j in ref.stress_idx])
    vol = np.array([signed_volumes(sc.model.rest + u[j], sc.model.mesh.tets).sum() for j in range(len(u))])
    v0 = float(sc.model.mesh.volumes().sum())
    return {"max_mm": float(np.linalg.norm(d, axis=2).max()) * 1e3,
            "rel_l2": float(np.sqrt((d ** 2).sum())) / ref.norm,
            "von_mises_rel": float(np.linalg.norm(vm - ref.von_mises) / max(np.linalg.norm(ref.von_mises), 1e-300)),
            "volume_pct": float(np.abs(vol - ref.volume).max()) / v0 * 100.0}


# -- the whole report ------------------------------------------------------------------------------
def run_report(cfg: dict, methods=tuple(METHODS), progress: Callable[[str], None] | None = print):
    """Measure every (scene, method, step); returns (points, extras for the figures)."""
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    points, last_u, scenes = [], {}, {}
    total = sum(len(cfg["walk_steps"] if s == "jelly_man" else cfg["steps"]) for s in cfg["scenes"]) * len(methods)
    done = 0
    for name in cfg["scenes"]:
        say(f"[{time.perf_counter() - t_start:6.1f} s] {name}: building the scene")
        sc = make_scenario(name, cfg)
        scenes[name] = sc
        refs = {}
        for kind in sorted({METHODS[m][2] for m in methods}):
            t0 = time.perf_counter()
            run = reference(sc, kind)
            refs[kind] = reference_data(sc, run, kind != "linear")
            say(f"[{time.perf_counter() - t_start:6.1f} s] {name}: {kind} reference "
                f"({sc.model.n_vertices} vertices, {sc.model.mesh.n_tets} tets) in {time.perf_counter() - t0:.1f} s")
        steps = cfg["walk_steps"] if name == "jelly_man" else cfg["steps"]
        runs, status, setup = {}, {}, {}
        for label in methods:                           # one integrator per step: an implicit one keeps its
            method, opts, kind = METHODS[label]          # factor for one h
            for h in steps:
                t0 = time.perf_counter()
                try:
                    integ = make_integrator(method, sc.model, **opts)
                except Exception as e:                  # e.g. more modes than free DOFs
                    setup[label, h], status[label, h] = math.nan, f"set-up failed: {e}"
                    continue
                setup[label, h] = time.perf_counter() - t0
                try:
                    runs[label, h] = RunInProgress(sc, integ, h)       # its warm-up steps
                except FAILURES as e:
                    status[label, h] = failure_status(e)
        say(f"[{time.perf_counter() - t_start:6.1f} s] {name}: {len(runs)} runs set up, stepping them in turns")
        finished = interleaved_runs(runs, lambda s: say(f"[{time.perf_counter() - t_start:6.1f} s] {name}: {s}"))
        for label in methods:
            method, opts, kind = METHODS[label]
            for h in steps:
                done += 1
                run = finished.get((label, h))
                if not isinstance(run, Run):
                    status.setdefault((label, h), run)
                    run = None
                err = errors(sc, run.u, refs[kind], kind != "linear") if run is not None \
                    else {m: math.nan for m in METRICS}
                st = status.get((label, h), "ok")
                if run is not None and not np.isfinite(run.u).all():
                    st = "diverged (non-finite state)"
                ms = run.ms_per_step if run is not None else math.nan
                p = MeasuredPoint(name, label, h, int(opts.get("k", 0)), ms, err,
                                  {"model": kind, "substeps": run.substeps if run else "", "status": st,
                                   "setup_s": f"{setup[label, h]:.3g}", "vertices": sc.model.n_vertices,
                                   "tets": sc.model.mesh.n_tets})
                points.append(p)
                if run is not None and label in ("clustered", "modal_30"):
                    last_u[(name, label, h)] = run.u[-1]
                say(f"[{time.perf_counter() - t_start:6.1f} s] {done:3d}/{total} {name:9s} {label:17s} h={h:<7g} "
                    + (f"{ms:8.3f} ms/step  max err {err['max_mm']:.3g} mm  rel L2 {err['rel_l2']:.2e}"
                       if st == "ok" else st))
        for kind, r in refs.items():
            last_u[(name, f"reference_{kind}")] = r.run.u[-1]
    return points, {"last_u": last_u, "scenes": scenes, "seconds": time.perf_counter() - t_start}


def table1_rows(points: list[MeasuredPoint], h: float = TABLE_H) -> list[list[str]]:
    """Paper Table 1 (ms/step and ratios) beside ours at step h, per shape measured."""
    at = {(p.scene, p.method): p for p in points if abs(p.h - h) < 1e-12}
    rows = []
    for shape, (std, clu, mod) in PAPER_MS.items():
        c = at.get((shape, "clustered"))
        if c is None:
            continue
        g = lambda m: at[(shape, m)].ms_per_step if (shape, m) in at else math.nan  # noqa: E731
        rows.append([shape, f"{std:.2f} / {clu:.2f} / {mod:.2f}", f"{std / clu:.2f}", f"{mod / clu:.2f}",
                     f"{g('implicit_cg'):.3f} / {c.ms_per_step:.3f} / {g('modal_30'):.3f}",
                     f"{g('implicit_cg') / c.ms_per_step:.2f}", f"{g('implicit_direct') / c.ms_per_step:.2f}",
                     f"{g('modal_30') / c.ms_per_step:.2f}"])
    return rows


def write_markdown(path: Path, points, cfg: dict, seconds: float, budget_example: tuple | None,
                   peer: list[list[str]] | None = None) -> None:
    lines = [f"# Speed against error ({'quick' if cfg.get('quick') else 'full'} run)", "",
             "Regenerate: `python -m benchmarks.speed_error_report"
             + (" --quick" if cfg.get("quick") else "") + f" --out {path.parent}`", "",
             f"Runs: shapes {cfg['duration']:g} s, jelly man {cfg['walk_duration']:g} s; samples every "
             f"{cfg['sample_dt']:g} s; measured in {seconds:.0f} s on this machine (2 shared cores, serial "
             "kernels). ms/step: median physics step after warm-up. cost: ms per simulated second. "
             "Errors against the same model's converged reference (see the module docstring).", ""]
    rows = table1_rows(points)
    if rows:
        lines += [f"## Table 1 beside ours (h = {TABLE_H:g} s)", "",
                  table(["shape", "paper std / clust / modal30 ms", "paper std/clust", "paper modal/clust",
                         "ours CG / clust / modal30 ms", "ours CG/clust", "ours direct/clust", "ours modal/clust"],
                        rows), "",
                  "The paper's standard FEM is implicit Euler with conjugate gradients (our implicit_cg, "
                  "Jacobi-preconditioned, rtol 1e-10).", ""]
    for scene in dict.fromkeys(p.scene for p in points):
        pts = [p for p in points if p.scene == scene]
        front = {id(p) for p in pareto_front(pts, "rel_l2")}
        lines += [f"## {scene} ({pts[0].info['vertices']} vertices, {pts[0].info['tets']} tets)", "",
                  table(["method", "model", "h [s]", "sub", "ms/step", "cost ms/s", "rel L2", "max mm",
                         "von Mises rel", "volume %", "Pareto", "status"],
                        [[p.method, p.info.get("model", ""), f"{p.h:g}", p.info.get("substeps", ""),
                          f"{p.ms_per_step:.3f}", f"{p.cost:.3g}",
                          f"{p.errors['rel_l2']:.2e}", f"{p.errors['max_mm']:.3g}", f"{p.errors['von_mises_rel']:.2e}",
                          f"{p.errors['volume_pct']:.2e}", "*" if id(p) in front else "", p.info.get("status", "")]
                         for p in pts]), ""]
    if peer is not None:
        from . import peer_mujoco
        lines += [f"## A peer: MuJoCo's tetrahedral flex, same mesh, material, load and step (h = {TABLE_H:g} s)", "",
                  table(peer_mujoco.HEADERS, peer) if peer else "MuJoCo is not installed: no peer rows.", "",
                  peer_mujoco.NOTE + " What each simulator computes: `benchmarks/peer_mujoco.py`.", ""]
    if budget_example:
        lines += ["## Method choice from these points", ""] + [f"- {s}" for s in budget_example] + [""]
    path.write_text("\n".join(lines))


def plot_speed_error(path: Path, points, metric: str = "rel_l2") -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    scenes = list(dict.fromkeys(p.scene for p in points))
    cols = min(2, len(scenes))
    rows = math.ceil(len(scenes) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.2 * cols, 4.6 * rows), dpi=90, squeeze=False)
    colours = dict(zip(METHODS, plt.get_cmap("tab10").colors))
    for ax, scene in zip(axes.ravel(), scenes):
        pts = [p for p in points if p.scene == scene and p.ok and p.errors[metric] > 0]
        for label in METHODS:
            mine = sorted((p for p in pts if p.method == label), key=lambda p: p.h)
            if mine:
                ax.plot([p.cost for p in mine], [p.errors[metric] for p in mine], "o-", ms=4, lw=1,
                        color=colours[label], label=label)
        front = pareto_front(pts, metric)
        if front:
            ax.plot([p.cost for p in front], [p.errors[metric] for p in front], "k--", lw=1.2, zorder=0)
            ax.scatter([p.cost for p in front], [p.errors[metric] for p in front], s=80, facecolors="none",
                       edgecolors="k", label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(scene)
        ax.set_xlabel("compute per simulated second [ms/s]  (= ms/step / h)")
        ax.set_ylabel(METRICS[metric].replace(" over the run", ""))
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes.ravel()[len(scenes):]:
        ax.set_visible(False)
    axes.ravel()[0].legend(fontsize=7, loc="best")
    fig.suptitle("error against cost; along a line the step h shrinks to the left for implicit/modal")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_figure5(path: Path, extras: dict, h: float = TABLE_H) -> bool:
    """Displacement difference to the reference on the surface, clustered vs modal 30 (paper Fig. 5)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    last = extras["last_u"]
    scene = next((s for s in ("torus", "sphere", "cube", "jelly_man") if (s, "clustered", h) in last
                  and (s, "modal_30", h) in last), None)
    if scene is None:
        return False
    sc = extras["scenes"][scene]
    tri = boundary_triangles(sc.model.mesh)
    ref = last[(scene, "reference_linear")]
    diffs = {k: np.linalg.norm(last[(scene, k, h)] - ref, axis=1) * 1e3 for k in ("clustered", "modal_30")}
    vmax = max(float(np.percentile(diffs["modal_30"], 99)), 1e-9)
    norm = matplotlib.colors.Normalize(0.0, vmax)
    fig = plt.figure(figsize=(11, 5), dpi=90)
    x = sc.model.rest + ref
    centre, half = 0.5 * (x.min(0) + x.max(0)), 0.5 * np.ptp(x, axis=0).max()
    for i, (k, d) in enumerate(diffs.items()):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(x[tri], facecolors=plt.get_cmap("turbo")(norm(d[tri].mean(1))),
                                             edgecolors="none"))
        for a, axis in enumerate("xyz"):
            getattr(ax, f"set_{axis}lim")(centre[a] - half, centre[a] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=25, azim=-60)
        ax.set_axis_off()
        ax.set_title(f"{k}: max {d.max():.3g} mm")
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap="turbo"), ax=fig.axes, shrink=0.7,
                 label="|u - u_ref| [mm]")
    fig.suptitle(f"{scene}, h = {h:g} s, t = {sc.duration:g} s: displacement difference to the reference")
    fig.savefig(path)
    plt.close(fig)
    return True


def budget_examples(points) -> list[str]:
    out = []
    for scene in dict.fromkeys(p.scene for p in points):
        for budget in ((5.0, 25.0) if scene == "jelly_man" else (0.03, 0.1, 1.0)):
            try:
                c = choose(points, budget, "max_mm", scene)
                out.append(f"{scene}, max error <= {budget:g} mm: {c.point.describe()}, error "
                           f"{c.point.errors['max_mm']:.3g} mm -> {c.overrides}")
            except ValueError as e:
                out.append(f"{scene}, max error <= {budget:g} mm: {e}")
    return out


def points_destination(quick: bool, scenes, points: str | None) -> Path | None:
    """Where the run writes its measured points: ``points`` if given, the package's shipped copy after a full
    run (every scene, not quick), else None (<out>/speed_error.csv): a partial run never replaces it."""
    if points:
        return Path(points)
    return None if quick or scenes else SHIPPED_POINTS


def write_outputs(out: Path, points, extras: dict, cfg: dict, points_path: Path | None = None) -> dict:
    """The points CSV (``points_path``, default <out>/speed_error.csv), the tables and the figures."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": write_points(points_path or out / "speed_error.csv", points), "md": out / "speed_error.md",
             "png": out / "speed_error.png", "figure5": out / "figure5.png"}
    examples = budget_examples(points)
    write_markdown(paths["md"], points, cfg, extras["seconds"], examples, extras.get("peer"))
    plot_speed_error(paths["png"], points)
    if not plot_figure5(paths["figure5"], extras):
        del paths["figure5"]
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="sphere + jelly man, 0.2 s runs, 3 steps (~1-2 min)")
    ap.add_argument("--out", default=None, help="output folder (default reports/speed_error[_quick])")
    ap.add_argument("--scenes", nargs="+", choices=FULL["scenes"], help="only these scenes")
    ap.add_argument("--points", default=None, help="measured points CSV to write (default: the package's "
                    "clusterfem_ros/data/speed_error.csv for a full run, <out>/speed_error.csv for "
                    "--quick or --scenes)")
    ap.add_argument("--no-peer", action="store_true", help="skip the MuJoCo peer (benchmarks.peer_mujoco) in this run")
    args = ap.parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL, quick=args.quick)
    if args.scenes:
        cfg["scenes"] = tuple(args.scenes)
    out = Path(args.out or ("reports/speed_error_quick" if args.quick else "reports/speed_error"))
    points_path = points_destination(args.quick, args.scenes, args.points)
    print(f"speed vs error: scenes {', '.join(cfg['scenes'])}; methods {', '.join(METHODS)}; "
          f"material E={MATERIAL.E:g} Pa nu={MATERIAL.nu} xi={MATERIAL.xi} zeta={MATERIAL.zeta:g}", flush=True)
    say = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    points, extras = run_report(cfg, progress=say)
    shapes = [s for s in cfg["scenes"] if s != "jelly_man"]
    if shapes and not args.no_peer:
        from .peer_mujoco import compare
        say("peer: the same shapes in MuJoCo's flex")
        extras["peer"] = compare(shapes, TABLE_H, cfg["duration"], "Euler", progress=say) or []
    paths = write_outputs(out, points, extras, cfg, points_path)
    print(paths["md"].read_text())
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
