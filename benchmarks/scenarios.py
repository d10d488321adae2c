"""The benchmarks' scenarios and timed runs: a loaded scene (model, start state, inputs over time), one run of
it with an integrator at a step, and the converged reference a run is measured against.

Shared by the speed-vs-error report (benchmarks/speed_error_report.py, whose module docstring says how
runs are timed and why the reference is what it is) and the MuJoCo peer (benchmarks/peer_mujoco.py).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.model import Control, FemModel, State, build_model
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh

from .core_benchmark import MATERIAL

REF_SAFETY = 0.02           # reference sub-step / critical step
REF_INPUT_STEP = 2.5e-5     # reference input refresh on the skeleton scene [s]


# -- scenarios ---------------------------------------------------------------------------------
@dataclass
class Scenario:
    """One loaded run: model, start state, inputs as a function of time, and the rigid carry."""
    name: str
    model: FemModel
    duration: float
    sample_dt: float
    start: Callable[[], State]
    inputs: Callable[[float], Callable[[float], Control]]     # h -> (t -> Control for [t, t + h])
    carried: Callable[[float], np.ndarray] | None = None       # t -> (n, 3) rigid displacement

    @property
    def n_samples(self) -> int:
        return int(round(self.duration / self.sample_dt))


def shape_scenario(name: str, duration: float, sample_dt: float, scale: float = 1.0,
                   mesh=None) -> Scenario:
    """A paper shape (or ``mesh``), bottom 20 % held, gravity, from rest."""
    mesh = paper_mesh(name, scale) if mesh is None else mesh
    z = mesh.vertices[:, 2]
    model = build_model(mesh, MATERIAL, fixed=z <= z.min() + 0.2 * np.ptp(z))
    control = Control()
    return Scenario(name, model, duration, sample_dt, lambda: State.rest(model), lambda h: (lambda t: control))


def walk_scenario(duration: float, sample_dt: float, target_tets: int | None = None) -> Scenario:
    """The jelly man on the built-in walk (scene defaults), started on the skeleton at t = 0."""
    from clusterfem_ros.body import SkeletonDriver
    from .jelly_report import build_scene, scene_default
    tets = int(scene_default("body.target_tets")) if target_tets is None else target_tets
    sk, traj, model, binding, gains = build_scene(tets, duration + 0.1, 1.0 / 120.0)

    def driver():
        return SkeletonDriver(binding, model.rest, gains, bone_names=sk.bone_names)

    def poses(t):
        return sk.forward(*traj.sample(t))

    def inputs(h):
        d = driver()
        return lambda t: d.control(poses(t), h)

    carrier = driver()
    return Scenario("jelly_man", model, duration, sample_dt, lambda: carrier.rigid_state(poses(0.0)), inputs,
                    lambda t: carrier.rigid_state(poses(t)).u)


def make_scenario(name: str, cfg: dict) -> Scenario:
    if name == "jelly_man":
        return walk_scenario(cfg["walk_duration"], cfg["sample_dt"], cfg.get("walk_tets"))
    return shape_scenario(name, cfg["duration"], cfg["sample_dt"])


# -- runs ----------------------------------------------------------------------------------------
@dataclass
class Run:
    u: np.ndarray                   # (S, n, 3) displacement at the sample times sample_dt, 2 sample_dt, ...
    ms_per_step: float = math.nan
    substeps: int = 1
    setup_s: float = 0.0
    status: str = "ok"


def steps_per_sample(sc: Scenario, h: float) -> int:
    r = sc.sample_dt / h
    if not (h > 0 and abs(r - round(r)) < 1e-6 and round(r) >= 1):
        raise ValueError(f"step h = {h:g} s must divide the sample interval {sc.sample_dt:g} s")
    return int(round(r))


class RunInProgress:
    """One run of the scenario with ``integ`` at step h, advanced a few samples at a time (``advance``), so the
    report can take turns between its runs (``interleaved_runs``). Timed: three warm-up steps on a throw-away
    state first (compile, factorize), then the wall time of every step (inputs excluded)."""

    def __init__(self, sc: Scenario, integ, h: float, timed: bool = True):
        self.sc, self.integ, self.h, self.timed = sc, integ, h, timed
        self.per = steps_per_sample(sc, h)
        self._inputs = sc.inputs(h)
        if timed:
            scratch, warm = sc.start(), sc.inputs(h)
            for k in range(3):
                integ.step(scratch, warm(k * h), h)
        self.state = sc.start()
        self.u = np.empty((sc.n_samples, sc.model.n_vertices, 3))
        self.samples_done = 0
        self.times: list[float] = []
        self.substeps = 1

    @property
    def done(self) -> bool:
        return self.samples_done >= self.sc.n_samples

    def advance(self, samples: int, time_first: bool = True) -> None:
        """Up to ``samples`` more samples; ``time_first=False`` leaves the first step out of the times (its
        caches are cold after another run's turn)."""
        timed = time_first
        for _ in range(min(samples, self.sc.n_samples - self.samples_done)):
            j = self.samples_done
            for s in range(self.per):
                control = self._inputs((j * self.per + s) * self.h)
                t0 = time.perf_counter()
                info = self.integ.step(self.state, control, self.h)
                if timed:
                    self.times.append(time.perf_counter() - t0)
                timed = True
                self.substeps = max(self.substeps, info.substeps)
            self.u[j] = self.state.u
            self.samples_done += 1

    def result(self) -> Run:
        return Run(self.u, float(np.median(self.times)) * 1e3 if self.timed else math.nan, self.substeps)


def simulate(sc: Scenario, integ, h: float, timed: bool = True) -> Run:
    """Run the scenario with ``integ`` at step h, start to end."""
    run = RunInProgress(sc, integ, h, timed)
    run.advance(sc.n_samples)
    return run.result()


def reference(sc: Scenario, kind: str) -> Run:
    """The converged reference of the model kind ('linear', 'corotated' or 'neohookean'); why it is converged
    enough: speed_error_report's module docstring."""
    integ = make_integrator("clustered", sc.model, safety=REF_SAFETY, max_substeps=10 ** 6, warp=(kind != "linear"),
                            warping_model="neohookean" if kind == "neohookean" else "element")
    h = sc.sample_dt if sc.carried is None else REF_INPUT_STEP
    return simulate(sc, integ, h, timed=False)
