"""A running scene: body, method, skeleton, inputs and outputs, built from a SceneConfig. No ROS.

``Scene`` is what the node wires to topics and what headless runs drive directly:

    scene = Scene.build(config)                      # the model, integrator, skeleton and binding
    scene.push_joint_state(stamp, names, q, v)       # inputs: checked, mapped by name, interpolated
    scene.advance_to(t)                              # fixed physics steps up to time t
    scene.surface(), scene.vertex_von_mises()        # outputs, computed only when asked for

Time is in seconds on the input clock (joint-state stamps). Physics never extrapolates inputs: it
runs on the last joint sample held when the stream stops.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .config import SceneConfig
from .fem.integrators import make_integrator
from .fem.material import Material
from .fem.mesh_io import read_mesh
from .fem.model import Control, State, build_model
from .fem.tet_mesh import TetMesh, boundary_triangles
from .fem.voxel_mesh import paper_mesh


@dataclass
class StepReport:
    steps: int = 0
    substeps: int = 0
    margin: float = float("inf")
    wall_s: float = 0.0


@dataclass
class InputCounters:
    accepted: int = 0
    rejected: dict = field(default_factory=dict)      # kind -> count

    def count(self, kind: str) -> None:
        self.rejected[kind] = self.rejected.get(kind, 0) + 1

    @property
    def total_rejected(self) -> int:
        return sum(self.rejected.values())


def _material(c: SceneConfig) -> Material:
    return Material(E=c["material.young_modulus"], nu=c["material.poisson_ratio"], rho=c["material.density"],
                    xi=c["material.mass_damping"], zeta=c["material.stiffness_damping"])


def _say(progress: Callable[[str], None] | None, text: str) -> None:
    if progress is not None:
        progress(text)


class Scene:
    def __init__(self, config: SceneConfig, mesh: TetMesh, fixed: np.ndarray, skeleton=None,
                 urdf_xml: str | None = None, progress: Callable[[str], None] | None = None):
        self.config = config
        self.h = float(config["physics.step"])
        _say(progress, f"assembling {mesh.n_tets} tets / {mesh.n_vertices} vertices")
        self.model = build_model(mesh, _material(config), fixed=fixed,
                                 gravity=(0.0, 0.0, float(config["physics.gravity"])))
        method = config["method"]
        options: dict = {}
        if method in ("clustered", "standard_explicit"):
            options.update(safety=config["physics.safety"], max_substeps=config["physics.max_substeps"])
        if method == "modal":
            options["k"] = config["modal.k"]
        if config["warping"] and method != "modal":
            options["warp"] = True
        _say(progress, f"setting up method '{method}'{' with warping' if options.get('warp') else ''}")
        self.integrator = make_integrator(method, self.model, **options)
        self.state = State.rest(self.model)
        self.triangles = boundary_triangles(mesh)
        self.surface_vertices = np.unique(self.triangles)
        remap = np.full(mesh.n_vertices, -1, dtype=np.int64)
        remap[self.surface_vertices] = np.arange(self.surface_vertices.size)
        self.surface_triangles = remap[self.triangles]
        self.rest_volume = float(mesh.volumes().sum())
        self.skeleton = skeleton
        self.urdf_xml = urdf_xml
        self.driver = None
        self.joints = None
        self.inputs = InputCounters()
        self.sim_time: float | None = None
        self.start_time: float | None = None
        self.steps_done = 0
        self.last = StepReport()
        if skeleton is not None:
            self._bind(progress)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def build(cls, config: SceneConfig, urdf_xml: str | None = None,
              progress: Callable[[str], None] | None = None) -> "Scene":
        """Build everything the config asks for (and nothing else)."""
        skeleton = None
        source = config["skeleton.source"]
        if source != "none":
            from .skeleton.kinematics import Skeleton
            if source == "builtin":
                from .skeleton.humanoid import default_humanoid
                urdf_xml = default_humanoid().urdf
            elif source == "urdf_file":
                urdf_xml = Path(config["skeleton.urdf_file"]).read_text()
            elif urdf_xml is None:
                raise ValueError("skeleton.source is 'robot_description': pass the URDF text received on that "
                                 "topic (the node waits for it)")
            skeleton = Skeleton.from_urdf_string(urdf_xml)
        kind = config["body.kind"]
        fixed = None
        if kind == "jelly_man":
            from .skeleton.humanoid import default_humanoid
            from .skeleton.jelly_body import jelly_man_mesh
            _say(progress, f"voxelizing the jelly man (~{config['body.target_tets']} tets)")
            mesh = jelly_man_mesh(default_humanoid(), target_tets=config["body.target_tets"])
        elif kind == "mesh":
            mesh = read_mesh(config["body.mesh_file"])
        else:
            mesh = paper_mesh(kind, config["body.scale"])
        if skeleton is None and kind != "mesh" and config["body.fix_bottom"]:
            z = mesh.vertices[:, 2]
            fixed = z <= z.min() + 0.2 * np.ptp(z)
        if fixed is None:
            fixed = np.zeros(mesh.n_vertices, dtype=bool)
        return cls(config, mesh, fixed, skeleton=skeleton, urdf_xml=urdf_xml, progress=progress)

    def _bind(self, progress) -> None:
        from .body.binding import bind_to_skeleton
        from .body.constraints import LevelGains
        from .body.driver import SkeletonDriver
        from .skeleton.joint_map import JointMap
        from .skeleton.joint_stream import JointStreamInterpolator
        c = self.config
        sk = self.skeleton
        q0 = sk.neutral()
        poses = sk.forward(q0, np.zeros(sk.nv))
        starts, ends = sk.bone_segments(q0)
        _say(progress, f"binding {self.model.n_vertices} vertices to {len(sk.bone_names)} bones")
        self.binding = bind_to_skeleton(self.model.rest, starts, ends, c["binding.level_radii"],
                                        rest_rotation=poses.rotation, rest_translation=poses.translation,
                                        bone_names=sk.bone_names, warn=False)
        gains = LevelGains(kp=tuple(c["binding.kp"]), kd=tuple(c["binding.kd"]))
        self.driver = SkeletonDriver(self.binding, self.model.rest, gains, kinematic=c["binding.kinematic_core"],
                                     bone_names=sk.bone_names)
        self.joints = JointMap(sk.joint_names, q0)
        self.stream = JointStreamInterpolator(sk.joint_names, revolute=sk.revolute_mask(),
                                              max_age=c["input.max_age"], max_future=c["input.max_future"],
                                              teleport_distance=c["input.teleport_distance"],
                                              prismatic=~sk.revolute_mask())

    # -- inputs ----------------------------------------------------------------------------------
    def push_joint_state(self, stamp: float, names, positions, velocities=None,
                         now: float | None = None) -> list[tuple[str, str]]:
        """Take one joint-state sample. Returns the problems found as (kind, message); a sample with
        a fatal problem is dropped, one with repairable problems is repaired (see skeleton.joint_map).
        ``now`` [s] is the receiver's clock on the stamps' time base (None: check against the newest)."""
        if self.joints is None:
            self.inputs.count("no_skeleton")
            return [("no_skeleton", "joint state received but this scene has no skeleton (skeleton.source = none)")]
        result = self.joints.update(names, positions, velocities)
        problems = list(result.problems)
        if result.accepted:
            problems += self.stream.push(stamp, result.q, result.v, now=now)
        for kind, _ in problems:
            self.inputs.count(kind)
        if result.accepted and not any(k in self.stream.FATAL for k, _ in problems):
            self.inputs.accepted += 1
        return problems

    # -- physics ---------------------------------------------------------------------------------
    def _poses(self, t: float):
        q, v = self.stream.sample(t) if self.stream.ready else (self.joints.q, np.zeros(self.skeleton.nv))
        return self.skeleton.forward(q, v)

    def _control(self, t: float) -> Control:
        if self.driver is None:
            return Control()
        return self.driver.control(self._poses(t), self.h)

    def start(self, t: float) -> None:
        """Put the body on its skeleton's pose at time t (no transient from the rest pose), and start the clock."""
        self.sim_time = float(t)
        if self.start_time is None:
            self.start_time = self.sim_time
        if self.driver is not None:
            self.driver.reset()
            self.state = self.driver.rigid_state(self._poses(t), t)

    def step(self) -> StepReport:
        """One physics step of length h."""
        if self.sim_time is None:
            self.start(0.0)
        t0 = time.perf_counter()
        info = self.integrator.step(self.state, self._control(self.sim_time), self.h)
        self.sim_time += self.h
        self.steps_done += 1
        return StepReport(1, info.substeps, info.margin, time.perf_counter() - t0)

    def advance_to(self, t: float, max_steps: int | None = None) -> StepReport:
        """Step while sim_time + h <= t (at most max_steps; the rest of the time is dropped, not owed)."""
        if self.sim_time is None:
            self.start(t)
            return StepReport()
        n = int(np.floor((t - self.sim_time) / self.h + 1e-9))
        if max_steps is not None and n > max_steps:
            self.sim_time = t - max_steps * self.h
            n = max_steps
        rep = StepReport()
        for _ in range(max(n, 0)):
            r = self.step()
            rep.steps += 1
            rep.substeps = max(rep.substeps, r.substeps)
            rep.margin = min(rep.margin, r.margin)
            rep.wall_s += r.wall_s
        if rep.steps:
            self.last = rep
        return rep

    def reset(self) -> None:
        """Back to rest (after a divergence): the body is rebuilt on the next start."""
        self.state = State.rest(self.model)
        t = self.sim_time
        self.sim_time = None
        if t is not None:
            self.start(t)

    # -- outputs ---------------------------------------------------------------------------------
    def positions(self) -> np.ndarray:
        return self.model.rest + self.state.u

    def surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(deformed surface vertices (k, 3), triangles (t, 3) into them)."""
        return self.positions()[self.surface_vertices], self.surface_triangles

    def stress(self):
        """The element and vertex stress of the current state (computed on call)."""
        from .fem.stress import compute_stress
        return compute_stress(self.model, self.state.u, corotated=bool(self.config["warping"]))

    def vertex_von_mises(self) -> np.ndarray:
        return self.stress().vertex_von_mises

    def volume_error(self) -> float:
        """Relative change of the body's volume from rest."""
        x = self.positions()[self.model.mesh.tets]
        e = x[:, 1:] - x[:, :1]
        vol = np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])).sum() / 6.0
        return vol / self.rest_volume - 1.0

    def energy(self) -> float:
        return self.model.kinetic_energy(self.state.v) + self.model.elastic_energy(self.state.u)
