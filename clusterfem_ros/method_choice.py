"""Model only what a scene needs: the cheapest measured (method, step, modes) that meets an error budget.

Pure Python + numpy, no ROS. The measured points come from the speed-vs-error report
(``python -m benchmarks.speed_error_report`` from the repository root), which writes them as CSV; the
full run writes the copy shipped inside the package (``SHIPPED_POINTS``, installed with it). This module
reads and writes that file and chooses from it:

    points = read_points(SHIPPED_POINTS)
    choice = choose(points, budget=2.0, metric="max_mm", scene="jelly_man")
    choice.overrides   # {'method': 'clustered', 'physics.step': 0.002, 'warping': True, 'warping_model': 'neohookean'}

Cost is compute per simulated second (ms/step divided by the step h), not ms/step: a method taking
steps twice as long needs half as many of them. Ties in cost go to the smaller error.
A point whose run diverged or failed is never chosen (its errors are nan).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from .errors import ClusterFemError

# metric -> (column, what it measures); every error is "smaller is better"
METRICS = {
    "max_mm": "max vertex displacement error over the run [mm]",
    "rel_l2": "relative L2 displacement error over the run [-]",
    "von_mises_rel": "relative L2 error of the element von Mises stress over the run [-]",
    "volume_pct": "max |V - V_ref| / V0 over the run [%]",
}
REQUIRED = ("scene", "method", "h", "k", "ms_per_step") + tuple(METRICS)
# the label suffix of a warped point -> the warping_model it ran
WARPED_LABELS = {"_warp": "element", "_neohookean": "neohookean"}
# the measured points the package ships (package data: found beside this file in a wheel or a source tree)
SHIPPED_POINTS = Path(__file__).resolve().parent / "data" / "speed_error.csv"


class ChoiceError(ClusterFemError, ValueError):
    """No measured point meets the budget, or the points/budget are unusable; the message says why."""


@dataclass(frozen=True)
class MeasuredPoint:
    scene: str                  # 'sphere', 'cube', 'torus', 'jelly_man' (the scene file's body.kind)
    method: str                 # report label: clustered, clustered_warp (per-element corotation), clustered_neohookean,
                                # standard_explicit, implicit_direct, ... (benchmarks/speed_error_report.py METHODS)
    h: float                    # step [s]
    k: int                      # modes (modal only; 0 otherwise)
    ms_per_step: float          # median wall time of one step after warm-up [ms]
    errors: dict                # metric -> value (nan when the run failed)
    info: dict = field(default_factory=dict)    # extra report columns (substeps, setup_s, status, ...)

    @property
    def cost(self) -> float:
        """Compute per simulated second [ms/s] (1000 / cost is the real-time factor)."""
        return self.ms_per_step / self.h

    @property
    def ok(self) -> bool:
        return math.isfinite(self.cost) and all(math.isfinite(v) for v in self.errors.values())

    @property
    def overrides(self) -> dict:
        """The scene parameters (config.PARAMS names) that select this point: a warped point's label ends in its
        model (WARPED_LABELS), and the point sets warping_model too."""
        base, model = self.method, None
        for suffix, name in WARPED_LABELS.items():
            if base.endswith(suffix):
                base, model = base[: -len(suffix)], name
        if base.startswith("modal"):
            base = "modal"
        out = {"method": base, "physics.step": self.h, "warping": model is not None}
        if model is not None:
            out["warping_model"] = model
        if base == "modal":
            out["modal.k"] = self.k
        return out

    def describe(self) -> str:
        k = f", k = {self.k}" if self.k else ""
        return (f"{self.method}{k} at h = {self.h:g} s: {self.ms_per_step:.3g} ms/step "
                f"({self.cost:.3g} ms per simulated s)")


@dataclass(frozen=True)
class Choice:
    point: MeasuredPoint
    metric: str
    budget: float
    candidates: int             # points that met the budget

    @property
    def overrides(self) -> dict:
        return self.point.overrides


def _check_metric(metric: str) -> None:
    if metric not in METRICS:
        raise ChoiceError(f"unknown error metric {metric!r}: choose one of {', '.join(METRICS)}")


def _scene_points(points: Iterable[MeasuredPoint], scene: str | None) -> list[MeasuredPoint]:
    pts = list(points)
    if scene is not None:
        scenes = sorted({p.scene for p in pts})
        pts = [p for p in pts if p.scene == scene]
        if not pts:
            raise ChoiceError(f"no measured points for scene {scene!r} (the file has {scenes or 'none'}): "
                              "run the speed-vs-error report on this scene first")
    return pts


def pareto_front(points: Iterable[MeasuredPoint], metric: str = "rel_l2") -> list[MeasuredPoint]:
    """The points no other point beats in both cost and ``metric`` (failed runs excluded), by cost."""
    _check_metric(metric)
    pts = sorted((p for p in points if p.ok), key=lambda p: (p.cost, p.errors[metric]))
    front, best = [], math.inf
    for p in pts:
        e = p.errors[metric]
        if e < best:
            front.append(p)
            best = e
    return front


def choose(points: Iterable[MeasuredPoint], budget: float, metric: str = "max_mm",
           scene: str | None = None) -> Choice:
    """The cheapest point (compute per simulated second) whose ``metric`` error is <= ``budget``.

    Raises ChoiceError naming the best achievable error (and what achieves it) when none meets it.
    """
    _check_metric(metric)
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise ChoiceError(f"error budget {budget!r} must be a positive finite number ({METRICS[metric]})")
    pts = [p for p in _scene_points(points, scene) if p.ok]
    where = f" for scene {scene!r}" if scene else ""
    if not pts:
        raise ChoiceError(f"no successful measured point{where}: every run failed or diverged")
    good = [p for p in pts if p.errors[metric] <= budget]
    if not good:
        # errors equal to 9 digits count as equal (clustered and standard explicit differ only by round-off),
        # and then the cheaper point is named
        best = min(pts, key=lambda p: (float(f"{p.errors[metric]:.9g}"), p.cost))
        raise ChoiceError(f"no measured method meets {metric} <= {budget:g}{where}; the best achievable is "
                          f"{best.errors[metric]:.4g} ({best.describe()}): raise the budget to at least that, "
                          "or measure smaller steps / more modes")
    pick = min(good, key=lambda p: (p.cost, p.errors[metric]))
    return Choice(pick, metric, float(budget), len(good))


# -- the measured points file (CSV) ---------------------------------------------------------------
def write_points(path: str | Path, points: Iterable[MeasuredPoint]) -> Path:
    """Write points as CSV: the REQUIRED columns, then every extra ``info`` key (sorted)."""
    pts = list(points)
    extra = sorted({k for p in pts for k in p.info} - set(REQUIRED))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(REQUIRED) + extra)
        for p in pts:
            w.writerow([p.scene, p.method, repr(float(p.h)), int(p.k), f"{p.ms_per_step:.6g}"]
                       + [f"{p.errors.get(m, math.nan):.6g}" for m in METRICS]
                       + [p.info.get(k, "") for k in extra])
    return path


def read_points(path: str | Path) -> list[MeasuredPoint]:
    """Read a measured points CSV (as written by ``write_points``); errors name the file, row and column."""
    path = Path(path)
    if not path.is_file():
        raise ChoiceError(f"measured points file {str(path)!r} not found: run "
                          "`python -m benchmarks.speed_error_report` (from the repository root) to make it")
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ChoiceError(f"{path}: no measured points in the file")
    missing = [c for c in REQUIRED if c not in rows[0]]
    if missing:
        raise ChoiceError(f"{path}: missing column(s) {missing}; expected at least {list(REQUIRED)}")
    out = []
    for i, r in enumerate(rows, start=2):
        try:
            errors = {m: float(r[m]) for m in METRICS}
            p = MeasuredPoint(r["scene"], r["method"], float(r["h"]), int(r["k"]), float(r["ms_per_step"]),
                              errors, {k: v for k, v in r.items() if k not in REQUIRED})
        except (TypeError, ValueError) as e:
            raise ChoiceError(f"{path}, line {i}: unreadable value ({e})") from None
        if not (p.h > 0):
            raise ChoiceError(f"{path}, line {i}: step h = {p.h!r} must be positive")
        out.append(p)
    return out


def choose_from_file(path: str | Path, scene: str, budget_mm: float) -> Choice:
    """What the node calls: the cheapest point for ``scene`` whose max vertex error is <= budget_mm [mm]."""
    return choose(read_points(path), budget_mm, "max_mm", scene)
