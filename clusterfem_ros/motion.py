"""Motion sources by name: the skeleton (URDF text) and the joint trajectory a player plays. No ROS.

    load_motion("builtin_walk")                     # default humanoid walking, loops without a jump
    load_motion("bvh", "walk.bvh")                  # a capture's own skeleton and its joint angles
                                                    # (files: a path, or a name under $CLUSTERFEM_DATA / ../shared/data;
                                                    # unit / up: 'auto' finds them from the skeleton)
    load_motion("keyframes", "wave.yaml")           # timed targets for the default humanoid's joints
    load_motion("joint_sweep", "package://example-robot-data/robots/panda_description/urdf/panda.urdf")
                                                    # a URDF's joints swept through their ranges (joint_sweep.py)
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .config import BVH_UP, ConfigError, Param, check_param
from .registries import Registry
from .skeleton.capture_frames import bvh_frames
from .skeleton.trajectory import JointTrajectory

WALK_CYCLES = 4          # the built-in walk is this many whole gait periods, so looping is seamless


@dataclass(frozen=True)
class Motion:
    urdf: str                      # skeleton the trajectory's joint names belong to
    trajectory: JointTrajectory
    description: str
    builtin_skeleton: bool         # True: the default humanoid (skeleton.source 'builtin' fits it)
    carry: np.ndarray | None = None    # (n,) bool: columns that continue across a loop (root's horizontal position)
    placement: str = ""                # a capture's unit, axes and floor as decided (bvh_placement), one line
    capture: object | None = None      # the BvhMotion a BVH trajectory was made from

    def looping(self, blend_s: float) -> JointTrajectory:
        """The trajectory made to loop without a jump: a capture's joints blended as rotations with its root's
        heading and position carried on (skeleton/capture_loop.py), any other trajectory's seam blended
        (``JointTrajectory.with_seam``, the ``carry`` columns carried on)."""
        if self.capture is not None:
            from .skeleton.bvh_to_urdf import bvh_loop
            return bvh_loop(self.capture, self.trajectory, blend_s)
        return self.trajectory.with_seam(blend_s, self.carry)


@dataclass(frozen=True)
class MotionSource:
    """A kind of motion a player can play, registered by name (``register_source``): the player's ``source``
    choices, ``load_motion`` and the node's fitting skeleton all read the registry."""
    name: str
    description: str                # for the player's parameter table
    load: Callable[..., Motion]     # (path or None, speed_mps=, unit=, up=) -> Motion
    file_kind: str | None = None    # what its 'file' holds ('.bvh'); None: it needs no file
    skeleton_source: str = "builtin"    # the node's skeleton.source its skeleton fits
    # its files' frames as recorded, (path, unit=, up=) -> JointTrajectory, frame 0 first: what a bind pose in a
    # capture's frame 0 reads (skeleton/capture_frames.py); None: its files give no bind pose
    bind_frames: Callable[..., JointTrajectory] | None = None


MOTION_SOURCES = Registry("motion source")


def register_source(source: MotionSource) -> MotionSource:
    """Add a motion source under its name (a name already taken is refused), and its files' frame reader for a
    bind pose (``bind_frames``) under its file kind; returns it."""
    from .skeleton.capture_frames import FRAME_READERS, register_frames
    if source.bind_frames is not None and FRAME_READERS.get(str(source.file_kind).lower()) is not source.bind_frames:
        if not source.file_kind:
            raise ValueError(f"motion source {source.name!r} gives bind_frames but no file_kind to read them from")
        register_frames(source.file_kind, source.bind_frames)
    return MOTION_SOURCES.register(source.name, source)


def _builtin_walk(path, speed_mps: float = 1.0, **_) -> Motion:
    from .skeleton.humanoid import default_humanoid
    from .skeleton.procedural_walk import gait_period, procedural_walk
    period = gait_period(speed_mps)
    traj = procedural_walk(WALK_CYCLES * period, speed=speed_mps)
    return Motion(default_humanoid().urdf, traj,
                  f"built-in walk ({WALK_CYCLES} gait periods of {period:.2f} s at {speed_mps:g} m/s)", True)


def _bvh(path, unit="auto", up: str = "auto", **_) -> Motion:
    from .skeleton.bvh import load_bvh
    from .skeleton.bvh_to_urdf import bvh_trajectory, bvh_urdf
    capture = load_bvh(path, unit, up)
    traj = bvh_trajectory(capture)
    # a position channel is horizontal when its file axis maps to a ROS axis without a vertical part
    carry = np.array([n.endswith("pos") and abs(capture.to_ros[2, "XYZ".index(n[-4])]) < 0.5 for n in traj.names])
    skipped = ", frame 0 (a prepended pose) skipped" if traj.times.size < capture.n_frames else ""
    return Motion(bvh_urdf(capture), traj, f"BVH {path.name} ({capture.n_frames} frames{skipped}, "
                  f"{traj.duration:.2f} s)", False, carry, capture.placement, capture)


def _keyframes(path, **_) -> Motion:
    from .skeleton.humanoid import default_humanoid
    from .skeleton.keyframes import load_keyframes
    spec = default_humanoid()
    traj = load_keyframes(path, joint_names=spec.joint_names)
    return Motion(spec.urdf, traj, f"key frames {path.name} ({traj.duration:.2f} s)", True)


def _joint_sweep(path, **_) -> Motion:
    from .skeleton.joint_sweep import joint_sweep
    urdf = path.read_text()
    sweep = joint_sweep(urdf)
    tr = sweep.trajectory
    return Motion(urdf, tr, f"joint sweep of {path.name} ({len(tr.names)} joints, {tr.duration:.2f} s)"
                  + "".join(f"; {note}" for note in sweep.notes), False)


for _source in (MotionSource("builtin_walk", "the built-in humanoid walking", _builtin_walk),
                # a capture plays on its own skeleton, which the player latches on robot_description
                MotionSource("bvh", "a BVH capture on its own skeleton", _bvh, ".bvh", "robot_description",
                             bvh_frames),
                MotionSource("keyframes", "timed targets for the built-in humanoid's joints", _keyframes,
                             ".yaml/.csv"),
                # the URDF file the sweep reads (or the same URDF latched on robot_description)
                MotionSource("joint_sweep", "a URDF's joints through their ranges", _joint_sweep, ".urdf",
                             "urdf_file")):
    register_source(_source)
MOTION_SOURCES.seal()
SOURCES = tuple(MOTION_SOURCES)                 # the built-in ones; MOTION_SOURCES holds what is registered


PLAYER_NODE = "mocap_player"
# The player's parameters (nodes/player_node.py declares them, a scene file's mocap_player section holds them),
# typed and checked by config.check_param as the simulation node's are.
PLAYER_TABLE: tuple[Param, ...] = (
    Param("source", "builtin_walk", "; ".join(f"{m.name}: {m.description}" for m in MOTION_SOURCES.values()),
          choices=SOURCES),
    Param("file", "", "BVH, key-frame or URDF file for those sources: a path, package://<package>/<path> of an "
          "installed package, or a name under $CLUSTERFEM_DATA, ../shared/data or the user data folder"),
    Param("rate_hz", 120.0, "JointState publish rate [Hz]", 1.0, 2000.0),
    Param("speed", 1.0, "playback speed factor", 0.01, 100.0),
    Param("start_offset", 0.0, "start this far into the motion [s]", 0.0, 1e6),
    Param("start_delay", 0.0, "wait this long before playing, the skeleton latched at once: a node that builds its "
          "body from robot_description (a new mesh takes minutes) then gets the motion from its start [s]",
          0.0, 3600.0),
    Param("loop", True, "loop the motion at its end"),
    Param("loop_blend", 0.5, "looping a motion that does not end where it starts: its last seconds are blended into "
          "its start over this time (a capture's joints as rotations), the root's horizontal position and heading "
          "carried on (0 = jump back to the start, which the node takes as a teleport and re-places the body) [s]",
          0.0, 60.0),
    Param("unit", "auto", "a BVH file's length unit: auto (found from the skeleton: a standing human), m, cm, mm, "
          "inch, cmu (0.056444 m) or metres per file unit as a number", length_unit=True),
    Param("up", "auto", "a BVH file's up axis: auto (found from the legs of the rest pose), X, Y, Z, -X, -Y or -Z",
          choices=BVH_UP),
)
PLAYER_PARAMS = tuple(p.name for p in PLAYER_TABLE)
_PLAYER_BY_NAME = {p.name: p for p in PLAYER_TABLE}


def load_motion(source: str = "builtin_walk", file: str | Path = "", speed_mps: float = 1.0, unit="auto",
                up: str = "auto") -> Motion:
    """The named motion (a source of MOTION_SOURCES); raises ValueError naming the source or file and the way out.
    ``unit`` and ``up`` are a BVH file's length unit and up axis ('auto': found from its skeleton;
    skeleton/bvh_placement.py)."""
    if source not in MOTION_SOURCES:
        raise ValueError(f"motion source {source!r} is unknown: choose one of {', '.join(MOTION_SOURCES)}")
    kind = MOTION_SOURCES[source]
    path = None
    if kind.file_kind is not None:
        if not str(file):
            raise ValueError(f"motion source {source!r} needs a file: set the 'file' parameter to a "
                             f"{kind.file_kind} path")
        from .body.fit import find_data_file
        path = find_data_file(str(file), what=f"motion source {source!r}: file")
    return kind.load(path, speed_mps=speed_mps, unit=unit, up=up)


def unknown_player_parameter(name: str) -> ConfigError:
    """The error for a parameter the player does not have, naming the nearest one it has."""
    close = difflib.get_close_matches(name, PLAYER_PARAMS, n=1, cutoff=0.6)
    hint = f"did you mean {close[0]!r}?" if close else f"its parameters are {', '.join(PLAYER_PARAMS)}"
    return ConfigError(f"unknown {PLAYER_NODE} parameter {name!r}: {hint}")


def check_player_value(name: str, value):
    """One player parameter's value typed and checked (config.check_param); ConfigError naming it otherwise."""
    if name not in _PLAYER_BY_NAME:
        raise unknown_player_parameter(name)
    return check_param(_PLAYER_BY_NAME[name], value)


def load_player_section(path: str | Path) -> dict | None:
    """The player's parameters from a scene file's ``mocap_player: ros__parameters:`` section (the standard ROS 2
    params-file layout, beside the ``clusterfem:`` section), typed as the player types them (an integer for a
    float, a choice in any case), or None when the file has none. Raises ValueError naming an unknown key or a bad
    value; relative file paths stay relative (to the current directory)."""
    import yaml
    doc = yaml.safe_load(Path(path).read_text()) or {}
    section = doc.get(PLAYER_NODE)
    if section is None:
        return None
    params = (section or {}).get("ros__parameters")
    if not isinstance(params, dict):
        raise ValueError(f"{str(path)!r}: the '{PLAYER_NODE}:' section needs 'ros__parameters:' with the player's "
                         f"parameters ({', '.join(PLAYER_PARAMS)})")
    unknown = sorted(set(params) - set(PLAYER_PARAMS))
    if unknown:
        raise ValueError(f"{str(path)!r}: {PLAYER_NODE} has no parameter {unknown[0]!r}: use "
                         f"{', '.join(PLAYER_PARAMS)}")
    try:
        return {name: check_player_value(name, value) for name, value in params.items()}
    except ConfigError as exc:
        raise ConfigError(f"{str(path)!r}: {PLAYER_NODE}.{exc}") from None


def on_capture_skeleton(config, bvh_file: str | Path | None = None, progress=None):
    """The scene ``config`` made to play a BVH on the capture's own skeleton (skeleton.source robot_description): a
    character's surface (body.kind surface) is fitted to that skeleton in the scene's bind pose (with bind_pose
    'auto', found from the mesh and the skeleton in its rest: the zero pose, or frame 0 of ``bvh_file``); any other body
    becomes the jelly man built around it, in the pose ``capture_bind_pose`` chooses when ``bvh_file`` is given
    and skeleton.bind_pose is left 'neutral' or 'auto' (``progress`` gets the line saying which)."""
    kind = "surface" if config.body.kind == "surface" else "jelly_man"
    values = {"skeleton.source": "robot_description", "body.kind": kind}
    if bvh_file is not None and kind == "surface" and config.skeleton.bind_pose == "auto":
        values["skeleton.bind_bvh"] = str(bvh_file)     # its frame 0, should no human stand in the zero pose
    if bvh_file is not None and kind == "jelly_man" and config.skeleton.bind_pose in ("neutral", "auto"):
        pose, why = capture_bind_pose(bvh_file)
        if progress is not None:
            progress(why)
        if pose == "first_frame":
            values.update({"skeleton.bind_pose": "first_frame", "skeleton.bind_bvh": str(bvh_file)})
    return config.with_values(values)


def capture_bind_pose(bvh_file: str | Path) -> tuple[str, str]:
    """('neutral' or 'first_frame', the line saying why): the pose to build a jelly body in on a capture's skeleton.
    The zero pose when a human stands in it (skeleton/bone_roles.py: feet to head within 45 deg of up); frame 0
    when only there (a rig whose bones lie along their parents' axes until the frames pose them)."""
    from .body.fit import bind_configuration
    from .skeleton.bone_roles import stands_in
    from .skeleton.kinematics import Skeleton
    path = Path(bvh_file)
    capture = load_motion("bvh", path)
    skeleton = Skeleton.from_urdf_string(capture.urdf)

    zero, zero_why = stands_in(skeleton)
    if zero:
        return "neutral", f"jelly body built in the capture's zero pose (a human stands in it: {zero_why})"
    first, first_why = stands_in(skeleton, bind_configuration(skeleton, "first_frame", bvh_file=str(path)))
    if first:
        return "first_frame", (f"jelly body built in frame 0 of {path.name}: no human stands in its zero pose "
                               f"({zero_why}), one does in frame 0 ({first_why}); skeleton.bind_pose 'neutral' "
                               "with bind_joints / bind_angles overrides")
    return "neutral", (f"warning: no human stands in the zero pose of {path.name} ({zero_why}) nor in its frame 0 "
                       f"({first_why}): the jelly body is built in the zero pose; check the file's up axis")


def skeleton_source_for(source: str) -> str:
    """The node's skeleton.source that fits a player source (MotionSource.skeleton_source): the built-in humanoid
    for the walk and key frames, the URDF the player latches on robot_description for a BVH (its own skeleton),
    the URDF file the joint sweep reads for the joint sweep."""
    return MOTION_SOURCES[source].skeleton_source if source in MOTION_SOURCES else "builtin"
