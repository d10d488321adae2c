"""A running scene: body, method, skeleton, inputs and outputs, built from a SceneConfig. No ROS.

``Scene`` is what the node wires to topics and what headless runs drive directly:

    scene = Scene.build(config)                      # parts chosen (scene_build) and set up (scene_setup)
    scene.take_joint_state(stamp, names, q, v, received=t)   # an input, with the input-clock policy
    scene.advance_to(t)                              # physics.clock = wall: fixed steps up to time t
    scene.surface(), scene.vertex_von_mises()        # outputs, computed only when asked for

What to build (error budget, skeleton, mesh, material, integrator options) is chosen in scene_build.py, and the
parts are set up (model, integrator, anchors, binding, joint inputs) and warmed up in scene_setup.py; this module
only runs them. Time is in seconds on the input clock (joint-state stamps). Physics never
extrapolates inputs: it runs on the last joint sample held when the stream stops.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np

from .body.bone_distance import any_beyond, segment_distances
from .config import SceneConfig
from .fem.model import Control, State
from .fem.stability import DivergenceError, StabilityError
from .fem.mesh.tet_mesh import total_volume
from .scene_build import scene_parts
from .scene_setup import RunningParts, set_up, warm_up


MAX_VOLUME_ERROR = 0.5      # |V/V0 - 1| beyond this is a diverged state, not a deformation
REST_DISTANCE_FACTOR = 1.5  # a vertex may reach this multiple of its rest distance to its bone, if above the limit
VOLUME_CHECK_STEPS = 50     # the step loop's volume check runs at least this many steps apart (outputs: always)
BONE_CHECK_STEPS = 5        # and its surface-to-bone check this many (outputs: always)
SETTLE_MAX_STEPS = 150      # a placement settles on its skeleton's still pose for at most these steps,
SETTLE_CHECK_STEPS = 5      # checked this many apart,
SETTLE_SPEED = 0.05         # [m/s] until no vertex moves faster than this
SETTLE_SUBSTEPS = 4         # a settle may take this many times physics.max_substeps a step: it runs once, off the
                            # clock, and un-crushes elements the carry crushed (a thumb bone inside a mitten hand)


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
    taken_in: bool = False            # the joint stream took the last sample in: what the node records

    def count(self, kind: str) -> None:
        self.rejected[kind] = self.rejected.get(kind, 0) + 1

    @property
    def total_rejected(self) -> int:
        return sum(self.rejected.values())


class Scene:
    """The running scene: inputs, clock, steps, divergence and reset, output checks, outputs. ``Scene.build``
    makes one from a config; the constructor takes parts already set up (scene_setup.set_up) and builds nothing."""

    def __init__(self, parts: RunningParts):
        self.config = parts.config
        self.h = float(parts.config.physics.step)
        self.model = parts.model
        self.integrator = parts.integrator
        self.skeleton = parts.skeleton
        self.urdf_xml = parts.urdf_xml
        self.surface_body = parts.surface_body    # body.surface_body.SurfaceBody of a surface body: bind pose, depth
        self.bind_all = parts.bind_all    # the outermost level reaches every vertex (a capsule body: no free flesh)
        self.anchors = parts.anchors
        self._anchored = parts.anchored   # the anchors' attachments when no skeleton drives the body
        self.binding = parts.binding
        self.driver = parts.driver
        self.joints = parts.joints
        self.stream = parts.stream
        self.triangles = parts.triangles
        self.surface_vertices = parts.surface_vertices
        self.surface_triangles = parts.surface_triangles
        self.rest_volume = parts.rest_volume
        self.pressure = parts.pressure    # the whole volume's pressure, or None
        self.state = State.rest(self.model)
        self._corners = None            # the tets transposed (4, m), for the volume checks
        self._distance_limit = None     # (limit, its square) (k,): how far each surface vertex may be from its bone
        self.check_wall_s = 0.0         # wall seconds in state_problem's checks (the node's "checks" stage)
        self._pose_memo = None          # ((t, stream revision), bone poses) of the last _poses
        self.inputs = InputCounters()
        self._t0: float | None = None      # time of step 0 of the current run (stamps are ~1e9 s: time is
        self._k = 0                        # kept as t0 + k h, never accumulated, so it does not drift)
        self.start_time: float | None = None
        self.first_stamp: float | None = None     # stamp of the first joint state accepted
        self.steps_done = 0
        self.settle_steps = 0           # steps spent settling placements (Scene._settle), not in steps_done
        self.substeps_done = 0          # explicit sub-steps over steps_done steps (1 a step for the other methods)
        self.step_wall_s = 0.0          # wall time inside step() over steps_done steps
        self.skeleton_wall_s = 0.0      # the part of it spent on the constraints (skeleton pose, targets)
        self.dropped_s = 0.0             # simulated time skipped because physics could not keep up
        self._replace = False
        self.late_jumps = 0             # samples after physics held past the newest one that moved the skeleton by
        self._late_from = None          # more than input.max_late_jump: body re-placed; _late_from: the bone ends
                                        # at sim_time before the first such sample since the last step
        self._stress_cache = None
        self._placed = False            # the body stands on a pose from a joint sample (or needs none)
        self._checked: tuple | None = None     # (steps_done, id(state), problem) of the last output check
        self._next_volume_check = 0
        self._next_bone_check = 0
        self.last = StepReport()

    @classmethod
    def build(cls, config: SceneConfig, urdf_xml: str | None = None,
              progress: Callable[[str], None] | None = None) -> "Scene":
        """Build everything the config asks for (and nothing else): scene_build.scene_parts chooses the parts
        (error budget, skeleton, body mesh), scene_setup.set_up wires them, scene_setup.warm_up loads the compiled
        kernels with the constraints the first steps will get."""
        parts = set_up(scene_parts(config, urdf_xml, progress), progress)
        scene = cls(parts)
        warm_up(parts, lambda state: scene._control(0.0, state), scene.h, progress)
        scene.state_problem()           # and the checks' kernels: compiled in the step loop, a first start stalled 1.3 s
        scene._checked, scene.check_wall_s = None, 0.0
        return scene

    # -- inputs ----------------------------------------------------------------------------------
    def push_joint_state(self, stamp: float, names, positions, velocities=None,
                         now: float | None = None, taken: bool = False) -> list[tuple[str, str]]:
        """Take one joint-state sample. Returns the problems found as (kind, message); a sample with
        a fatal problem is dropped, one with repairable problems is repaired (see skeleton.joint_map).
        ``now`` [s] is the receiver's clock on the stamps' time base (None: check against the newest).
        ``inputs.taken_in`` says whether the joint stream took it in; a sample it refuses changes no state but
        the counters (the joint map keeps only the values of samples taken in), so the samples taken in, given
        again in order with ``taken=True`` (a recording read back), give the same states (JointStreamInterpolator).
        """
        self.inputs.taken_in = False
        if self.joints is None:
            self.inputs.count("no_skeleton")
            return [("no_skeleton", "joint state received but this scene has no skeleton (skeleton.source = none)")]
        result = self.joints.merge(names, positions, velocities)
        problems = list(result.problems)
        first = result.accepted and not self.stream.ready
        held = result.accepted and self._holding()
        if result.accepted:
            late_from = self._bone_ends(self.sim_time) if held and self._late_from is None else None
            problems += self.stream.push(stamp, result.q, result.v, now=now, taken=taken)
            if self.stream.took_last:
                self.joints.commit(result.q)
                self.inputs.taken_in = True
                if late_from is not None:               # the pose the last step left the body on
                    self._late_from = late_from
        if first and self.stream.ready:
            self._replace = True              # first sample: the body moves onto it instead of being yanked
            if self.first_stamp is None:
                self.first_stamp = self.stream.newest
        for kind, _ in problems:
            self.inputs.count(kind)
            if kind in ("teleport", "restart"):      # the skeleton jumped: put the body on it, no yank
                self._replace = True
        if result.accepted and not any(k in self.stream.FATAL for k, _ in problems):
            self.inputs.accepted += 1
            if held and not self._replace:                # late samples since that step, together
                jump = np.linalg.norm(self._bone_ends(self.sim_time) - self._late_from, axis=-1).max()
                if jump > self.config.input.max_late_jump:
                    self._replace = True
                    self.late_jumps += 1
        return problems

    def _holding(self) -> bool:
        """Physics has stepped past the newest sample (by more than half a step), on the pose held there: a new
        sample changes the skeleton at sim_time in one jump, the larger the longer it held (wall clock, inputs
        late or stalled)."""
        return (self.driver is not None and self.sim_time is not None and self.stream.ready
                and self.stream.newest < self.sim_time - 0.5 * self.h)

    def _bone_ends(self, t: float) -> np.ndarray:
        """(nb, 2, 3) [m]: both ends of every bone's segment at time t, as the joint stream gives the pose."""
        poses = self._poses(t)
        return np.einsum("bij,bej->bei", poses.rotation, self.binding.axis_local) + poses.translation[:, None]

    def take_joint_state(self, stamp: float, names, positions, velocities, received: float,
                         on_judged: Callable[[list], None] | None = None,
                         on_step: Callable[[], None] | None = None, taken: bool = False) -> list[tuple[str, str]]:
        """One joint-state sample with the whole input-clock policy: the node's physics thread (through
        sim_loop.SimLoop) and a replay (replay.py) both take their samples here, so the same samples give the
        same states.

        An unstamped sample (stamp 0) takes its receive time ``received`` [s, the stamps' time base]; the sample
        is judged and pushed (push_joint_state, checked against ``received``; ``taken``: a recorded sample, as
        there); ``on_judged(problems)`` runs next (the node records what the joint stream took in: a replay's
        input, and nothing refused); then with physics.clock = input the
        body steps up to the newest stamp (follow_inputs: at most physics.max_catchup_steps behind,
        ``on_step()`` after each step). With physics.clock = wall the caller steps (advance_to). Returns the
        problems found; DivergenceError / StabilityError from the steps reach the caller, which resets."""
        if stamp == 0.0:
            stamp = received
        problems = self.push_joint_state(stamp, names, positions, velocities, now=received, taken=taken)
        if on_judged is not None:
            on_judged(problems)
        if self.config.physics.clock == "input":
            self.follow_inputs(self.config.physics.max_catchup_steps, on_step=on_step)
        return problems

    # -- physics ---------------------------------------------------------------------------------
    def _poses(self, t: float):
        """The bone poses at time t from the joint stream (the skeleton's neutral pose before its first sample).
        The last one is kept: a step's check and the next step's control ask for the same time. Read-only."""
        if not self.stream.ready:
            return self.skeleton.forward(self.joints.q, np.zeros(self.skeleton.nv))
        key = (t, self.stream.revision)
        if self._pose_memo is None or self._pose_memo[0] != key:
            q, v = self.stream.sample(t)
            self._pose_memo = (key, self.skeleton.forward(q, v))
        return self._pose_memo[1]

    def _control(self, t: float, state: State) -> Control:
        """The constraints for the step from t, the skeleton's and the anchors' (``state``: the body at t; sliding
        levels read it)."""
        f_ext = self._pressure_force(state)
        if self.driver is None:
            return Control(f_ext=f_ext) if self._anchored is None else Control(f_ext=f_ext, attachments=self._anchored)
        return self.driver.control(self._poses(t), self.h, state=state, f_ext=f_ext)

    def _pressure_force(self, state: State | None) -> np.ndarray | None:
        """The whole volume's pressure force at ``state`` (held over the step), or None without it."""
        return None if self.pressure is None or state is None else self.pressure.force(state.u)

    def start(self, t: float) -> None:
        """Put the body on its skeleton's pose at time t (no transient from the rest pose), and start the clock."""
        self._t0, self._k = float(t), 0
        if self.start_time is None:
            self.start_time = self.sim_time
        self._place_on_skeleton()

    def _place_on_skeleton(self) -> None:
        """Every vertex carried rigidly by its bone at sim_time, then settled there (``_settle``); the bone-rate
        history restarts."""
        self._replace = False
        self._checked = None
        if self.driver is not None:
            self.driver.reset()
            self.state = self.driver.rigid_state(self._poses(self.sim_time), self.sim_time)
            if self.stream.ready:
                self._settle()
        self._placed = self.driver is None or self.stream.ready

    def _settle(self) -> None:
        """The rigid carry settled on the skeleton's pose held still, its bones' velocities given back after. A
        body bound in one pose (a character's A-pose, a jelly man's zero pose) and placed on a capture's frame in
        another has the flesh between two bones carried by both, not where their springs hold it: the first steps
        would show it springing from there (MakeHuman on Bandai Namco's walk at 5000 tets: 6.6 % of its volume
        lost in the carry, 8.1 % five steps later, 3.3 % once settled; the jelly man placed on CMU's leaps and
        basketball run: the carry inverts up to 41 elements, down to det F = -1.2, the settled body 10, -0.27;
        ``python -m benchmarks.clip_soak``). The settle takes 10-15 ms on the jelly man. Steps until no
        vertex moves faster than SETTLE_SPEED (checked every SETTLE_CHECK_STEPS steps), at most SETTLE_MAX_STEPS
        (the capsule of tests/test_character.py bent by 1.2 rad: about 90); a settle that diverges, or whose step
        plan passes SETTLE_SUBSTEPS times physics.max_substeps (elements the carry crushed flat), keeps the rigid
        carry. The settle's steps may need more sub-steps than the walk's: a carry that crushes a few elements
        (CesiumMan placed on Bandai Namco's dash: 80 against the limit of 64) would otherwise be placed again on
        every step, as every step after it would refuse the same plan."""
        q, _ = self.stream.sample(self.sim_time)
        still = self.skeleton.forward(q, np.zeros(self.skeleton.nv))
        carried = self.state
        state = carried.copy()
        k = 0
        setter = getattr(self.integrator, "set_max_substeps", None)     # the explicit methods
        limit = self.integrator.max_substeps if setter is not None else None
        if setter is not None:
            setter(SETTLE_SUBSTEPS * limit)
        try:
            for k in range(1, SETTLE_MAX_STEPS + 1):
                self.integrator.step(state, self.driver.control(still, self.h, state=state,
                                                                f_ext=self._pressure_force(state)), self.h)
                if k % SETTLE_CHECK_STEPS == 0:
                    speed = float(np.abs(state.v).max())
                    if not np.isfinite(speed):
                        return
                    if speed < SETTLE_SPEED:
                        break
        except (DivergenceError, StabilityError, FloatingPointError):
            return
        finally:
            self.driver.reset()
            if setter is not None:
                setter(limit)
        self.settle_steps += k
        self.state = State(state.u, carried.v, carried.t)

    def step(self) -> StepReport:
        """One physics step of length h."""
        if self.sim_time is None:
            self.start(0.0)
        if self._replace:
            self._place_on_skeleton()
        self._late_from = None
        t0 = time.perf_counter()
        control = self._control(self.sim_time, self.state)
        t1 = time.perf_counter()
        info = self.integrator.step(self.state, control, self.h)
        wall = time.perf_counter() - t0
        self._k += 1
        self.steps_done += 1
        self.substeps_done += info.substeps
        self.step_wall_s += wall
        self.skeleton_wall_s += t1 - t0
        return StepReport(1, info.substeps, info.margin, wall)

    @property
    def sim_time(self) -> float | None:
        """Simulated time [s] on the input clock (None before the start)."""
        return None if self._t0 is None else self._t0 + self._k * self.h

    def wall_target(self, now: float) -> float:
        """physics.clock = wall: the time to step up to at clock time ``now``. Beyond the newest joint state the
        skeleton is held, and a late sample would then move it on in one jump that yanks the flesh (a node short
        of CPU receives its inputs in bursts); so physics may wait at the newest sample while that is at most
        ``physics.input_wait`` behind the clock, and step on past it (holding the pose) only beyond. Off by
        default: waiting ties physics to the inputs' arrival, and the default scene's node ran at a real-time
        factor of 0.8 with 0.25 s of waiting (the executor delivers samples in bursts) against 1.0 without."""
        wait = self.config.physics.input_wait
        if self.driver is None or wait <= 0.0 or not self.stream.ready:
            return now
        return min(now, max(self.stream.newest, now - wait))

    def steps_due(self, t: float) -> int:
        """Whole steps from sim_time up to t (a step due within 1 us counts: stamps near 1e9 s carry
        ~0.2 us of round-off)."""
        return math.floor((t - self.sim_time) / self.h + 1e-6 / self.h)

    def advance_to(self, t: float, max_steps: int | None = None, deadline: float | None = None,
                   on_step: Callable[[], None] | None = None) -> StepReport:
        """Step while sim_time + h <= t, until ``deadline`` (time.perf_counter()) if given.

        ``on_step()`` is called after every step. Steps not done by the deadline stay owed: physics runs in
        slow motion behind its inputs. When it is more than ``max_steps`` steps behind, the gap is dropped
        (counted in ``dropped_s``) and the body is put back on the skeleton's pose, so a slow machine never
        yanks the body across the gap.

        Raises DivergenceError when a step's state is not finite (the integrator's check) or the state at the end
        fails ``state_problem`` (every ``BONE_CHECK_STEPS`` steps a surface vertex torn from its bone; every
        ``VOLUME_CHECK_STEPS`` steps the volume off by more than ``MAX_VOLUME_ERROR``); the caller resets it.
        """
        if self.sim_time is None:
            self.start(t)
            return StepReport()
        n = self.steps_due(t)
        if max_steps is not None and n > max_steps:
            self._drop(self.sim_time + n * self.h)
            n = 0
        rep = StepReport()
        for _ in range(max(n, 0)):
            r = self.step()
            if on_step is not None:
                on_step()
            rep.steps += 1
            rep.substeps = max(rep.substeps, r.substeps)
            rep.margin = min(rep.margin, r.margin)
            rep.wall_s += r.wall_s
            if deadline is not None and time.perf_counter() > deadline:
                break
        if rep.steps:
            self.last = rep
        # The volume and bone checks run every so many steps (a state shown is always checked whole:
        # output_problem). Finiteness needs no check here: every integrator's step raises DivergenceError on a
        # non-finite state (StepCommon.finish).
        volume = rep.steps > 0 and self.steps_done >= self._next_volume_check
        bones = rep.steps > 0 and self.steps_done >= self._next_bone_check
        if volume or bones:
            if volume:
                self._next_volume_check = self.steps_done + VOLUME_CHECK_STEPS
            if bones:
                self._next_bone_check = self.steps_done + BONE_CHECK_STEPS
            problem = self.state_problem(volume=volume, bones=bones)
            if problem is not None:
                if "from its bone" in problem:
                    way_out = ("the flesh could not follow its bone: look for glitches in the joint stream (a joint "
                               "turning faster than a limb can), or raise output.max_bone_distance for a body meant "
                               "to stretch that far")
                else:
                    way_out = "lower physics.step or the binding gains" + (
                        "" if self.config.warping else ", or turn warping on")
                raise DivergenceError(f"{problem} at t = {self.sim_time - self.start_time:.3f} s after the start: the "
                                      f"state has diverged; {way_out}")
        return rep

    def follow_inputs(self, max_steps: int | None = None, on_step: Callable[[], None] | None = None) -> StepReport:
        """physics.clock = input, called after every joint-state sample: start at the first accepted stamp,
        then step up to the newest (take_joint_state calls it for the node and a replay). ``on_step()`` also
        sees the state at the start."""
        if self.sim_time is None:
            if self.driver is None or not self.stream.ready:
                return StepReport()
            self.start(self.first_stamp)
            if on_step is not None:
                on_step()
        return self.advance_to(self.stream.newest, max_steps, on_step=on_step)

    def _drop(self, t_new: float) -> None:
        """Skip simulated time up to t_new and put the body back on the skeleton there."""
        if t_new > self.sim_time:
            self.dropped_s += t_new - self.sim_time
            self._t0, self._k = t_new, 0
            self._replace = True

    def reset(self) -> None:
        """Start again after a divergence: at rest, or carried rigidly by the skeleton's current pose."""
        self.state = State.rest(self.model)
        t = self.sim_time
        self._t0 = None
        if t is not None:
            self.start(t)

    # -- output checks ---------------------------------------------------------------------------
    @property
    def placed(self) -> bool:
        """True once the body stands on its skeleton's pose from a joint sample (always, without a skeleton):
        before that it is at the skeleton's neutral pose, wherever the clip's root is. False too while a re-placement
        is pending (after a teleport or dropped time the skeleton has moved on; the next step puts the body on it)."""
        return self._placed and not self._replace and self.sim_time is not None

    def bone_distance(self) -> tuple[np.ndarray, np.ndarray]:
        """(distance (k,), limit (k,)) [m] of every surface vertex to the segment of the bone it is bound to, at
        sim_time, and the distance it may reach: ``output.max_bone_distance`` or ``REST_DISTANCE_FACTOR`` times
        its distance at rest, the larger. Zeros (and infinite limits) without a skeleton."""
        return self._bone_distance(self.state.u, self._poses(self.sim_time) if self.driver is not None else None)

    def _bone_distance(self, u: np.ndarray, poses) -> tuple[np.ndarray, np.ndarray]:
        k = self.surface_vertices.size
        if poses is None:
            return np.zeros(k), np.full(k, np.inf)
        dist = segment_distances(self.model.rest, u, self.surface_vertices, self.binding.bone,
                                 poses.rotation, poses.translation, self.binding.axis_local)
        return dist, self._distance_limits()[0]

    def _distance_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(limit, limit squared) (k,) [m, m^2] of every surface vertex's distance to its bone (bone_distance)."""
        if self._distance_limit is None:
            limit = np.maximum(self.config.output.max_bone_distance,
                               REST_DISTANCE_FACTOR * self.binding.distance[self.surface_vertices])
            self._distance_limit = (limit, limit * limit)
        return self._distance_limit

    def state_problem(self, volume: bool = True, bones: bool = True) -> str | None:
        """What makes the current state unfit to show, or None (``problem_of`` of the state at sim_time;
        ``volume=False`` / ``bones=False``: that check left out). A full check is cached per state: the marker
        and the stress cloud ask about the same state."""
        key = (self.steps_done, id(self.state), self._k)
        if self._checked is not None and self._checked[0] == key:
            return self._checked[1]
        t0 = time.perf_counter()
        poses = self._poses(self.sim_time) if bones and self.driver is not None else None
        problem = self.problem_of(self.state.u, self.state.v, poses, volume=volume)
        if (volume and bones) or problem is not None:
            self._checked = (key, problem)
        self.check_wall_s += time.perf_counter() - t0
        return problem

    def problem_of(self, u: np.ndarray, v: np.ndarray, poses, volume: bool = True) -> str | None:
        """What makes the state (u, v) unfit to show, or None: a non-finite value, the volume off by more than
        ``MAX_VOLUME_ERROR`` (``volume=False``: not looked at), a surface vertex beyond its limit from its bone
        placed at ``poses`` (``bone_distance``; poses None: not looked at). Reads only the scene's constant
        data, so the outputs check a snapshot's copy with it on their own thread (sim_loop.Snapshot.problem)."""
        if not (np.isfinite(u).all() and np.isfinite(v).all()):
            return "the state is not finite"
        err = self.volume_error_of(self.model.rest + u) if volume else 0.0
        if not abs(err) <= MAX_VOLUME_ERROR:
            return f"the body's volume is off by {err * 100:+.3g} %"      # the limit: MAX_VOLUME_ERROR
        if poses is None or not any_beyond(self.model.rest, u, self.surface_vertices, self.binding.bone,
                                           poses.rotation, poses.translation, self.binding.axis_local,
                                           self._distance_limits()[1]):
            return None
        dist, limit = self._bone_distance(u, poses)
        over = dist - limit
        if not (dist.size and over.max() > 0):
            return None
        i = int(np.argmax(over))
        name = self.skeleton.bone_names[int(self.binding.bone[self.surface_vertices[i]])]
        return (f"surface vertex {int(self.surface_vertices[i])} is {dist[i]:.3g} m from its bone {name!r} "
                f"(limit {limit[i]:.3g} m, output.max_bone_distance)")

    def output_check(self) -> Callable[[np.ndarray, np.ndarray], str | None]:
        """``problem_of`` for a copy of the current state, to run later on another thread (sim_loop.Snapshot):
        the skeleton's pose at sim_time is taken now (bone poses are never written after they are made; the next
        step's constraints use the same)."""
        poses = self._poses(self.sim_time) if self.driver is not None else None
        return lambda u, v: self.problem_of(u, v, poses)

    def placement_problem(self) -> str | None:
        """Why no state is to be shown yet whatever its values, or None: physics not started, or the body not yet
        (or not again) standing on its skeleton's pose."""
        if self.sim_time is None:
            return "physics has not started"
        if not self.placed:
            return ("the body is waiting to be put on its skeleton's new pose" if self._placed else
                    "the body is not yet placed on its skeleton (no joint state used yet)")
        return None

    def output_problem(self) -> str | None:
        """Why the current state must not be published or recorded, or None: ``placement_problem``, or
        ``state_problem``. Call it before taking a state for the outputs."""
        return self.placement_problem() or self.state_problem()

    # -- outputs ---------------------------------------------------------------------------------
    def positions(self) -> np.ndarray:
        return self.model.rest + self.state.u

    def surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(deformed surface vertices (k, 3), triangles (t, 3) into them)."""
        return self.positions()[self.surface_vertices], self.surface_triangles

    def stress(self):
        """The element and vertex stress of the current state (computed on the first call after a step)."""
        key = (self.steps_done, id(self.state))
        if self._stress_cache is None or self._stress_cache[0] != key:
            self._stress_cache = (key, self.integrator.material_model.stress(self.model, self.state.u))
        return self._stress_cache[1]

    def vertex_von_mises(self) -> np.ndarray:
        return self.stress().vertex_von_mises

    def volume_error(self) -> float:
        """Relative change of the body's volume from rest."""
        return self.volume_error_of(self.model.rest + self.state.u)

    def volume_error_of(self, positions: np.ndarray) -> float:
        """Relative change of the body's volume from rest, with its vertices at ``positions``."""
        if self._corners is None:
            self._corners = np.ascontiguousarray(self.model.mesh.tets.T)
        return total_volume(positions, self._corners) / self.rest_volume - 1.0

    def energy(self) -> float:
        """Kinetic plus elastic energy [J] of the state, the elastic energy the running material model's."""
        return self.energy_of(self.state.u, self.state.v)

    def energy_of(self, u: np.ndarray, v: np.ndarray) -> float:
        """Kinetic plus elastic energy [J] of (u, v) (a snapshot's), the elastic energy the running model's."""
        return self.model.kinetic_energy(v) + self._elastic_energy(u)

    @cached_property
    def _elastic_energy(self) -> Callable[[np.ndarray], float]:
        return self.integrator.material_model.energy_function(self.model)
