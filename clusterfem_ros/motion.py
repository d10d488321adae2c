"""Motion sources by name: the skeleton (URDF text) and the joint trajectory a player plays. No ROS.

    load_motion("builtin_walk")                     # default humanoid walking, loops without a jump
    load_motion("bvh", "walk.bvh")                  # a capture's own skeleton and its joint angles
                                                    # (files: a path, or a name under $CLUSTERFEM_DATA / ../shared/data)
    load_motion("keyframes", "wave.yaml")           # timed targets for the default humanoid's joints
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .skeleton.trajectory import JointTrajectory

SOURCES = ("builtin_walk", "bvh", "keyframes")
PLAYER_NODE = "mocap_player"
PLAYER_PARAMS = ("source", "file", "rate_hz", "speed", "start_offset", "start_delay", "loop", "loop_blend")
WALK_CYCLES = 4          # the built-in walk is this many whole gait periods, so looping is seamless


@dataclass(frozen=True)
class Motion:
    urdf: str                      # skeleton the trajectory's joint names belong to
    trajectory: JointTrajectory
    description: str
    builtin_skeleton: bool         # True: the default humanoid (skeleton.source 'builtin' fits it)
    carry: np.ndarray | None = None    # (n,) bool: columns that continue across a loop (root's horizontal position)


def load_motion(source: str = "builtin_walk", file: str | Path = "", speed_mps: float = 1.0) -> Motion:
    """The named motion; raises ValueError naming the source or file and the way out."""
    from .skeleton.humanoid import default_humanoid
    if source == "builtin_walk":
        from .skeleton.procedural_walk import gait_period, procedural_walk
        period = gait_period(speed_mps)
        traj = procedural_walk(WALK_CYCLES * period, speed=speed_mps)
        return Motion(default_humanoid().urdf, traj,
                      f"built-in walk ({WALK_CYCLES} gait periods of {period:.2f} s at {speed_mps:g} m/s)", True)
    if source not in SOURCES:
        raise ValueError(f"motion source {source!r} is unknown: choose one of {', '.join(SOURCES)}")
    if not str(file):
        raise ValueError(f"motion source {source!r} needs a file: set the 'file' parameter to a "
                         f"{'.bvh' if source == 'bvh' else '.yaml/.csv'} path")
    from .body.fit import find_data_file
    path = find_data_file(str(file), what=f"motion source {source!r}: file")
    if source == "bvh":
        from .skeleton.bvh import load_bvh
        from .skeleton.bvh_to_urdf import bvh_trajectory, bvh_urdf
        capture = load_bvh(path)
        traj = bvh_trajectory(capture)
        # a position channel is horizontal when its file axis maps to a ROS axis without a vertical part
        carry = np.array([n.endswith("pos") and abs(capture.to_ros[2, "XYZ".index(n[-4])]) < 0.5 for n in traj.names])
        return Motion(bvh_urdf(capture), traj, f"BVH {path.name} ({capture.n_frames} frames, "
                      f"{traj.duration:.2f} s)", False, carry)
    from .skeleton.keyframes import load_keyframes
    spec = default_humanoid()
    traj = load_keyframes(path, joint_names=spec.joint_names)
    return Motion(spec.urdf, traj, f"key frames {path.name} ({traj.duration:.2f} s)", True)


def load_player_section(path: str | Path) -> dict | None:
    """The player's parameters from a scene file's ``mocap_player: ros__parameters:`` section (the standard ROS 2
    params-file layout, beside the ``clusterfem:`` section), or None when the file has none. Raises ValueError
    naming an unknown key or an unknown source; relative file paths stay relative (to the current directory)."""
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
        raise ValueError(f"{str(path)!r}: {PLAYER_NODE} has no parameter {unknown[0]!r}: use {', '.join(PLAYER_PARAMS)}")
    source = params.get("source", "builtin_walk")
    if source not in SOURCES:
        raise ValueError(f"{str(path)!r}: {PLAYER_NODE}.source = {source!r}: choose one of {', '.join(SOURCES)}")
    return dict(params)


def on_capture_skeleton(config):
    """The scene ``config`` made to play a BVH on the capture's own skeleton (skeleton.source robot_description): a
    character's surface (body.kind surface) is fitted to that skeleton in the scene's bind pose; any other body
    becomes the jelly man built around it."""
    kind = "surface" if config.body.kind == "surface" else "jelly_man"
    return config.with_values({"skeleton.source": "robot_description", "body.kind": kind})


def skeleton_source_for(source: str) -> str:
    """The node's skeleton.source that fits a player source: the built-in humanoid for the walk and key frames,
    the URDF the player latches on robot_description for a BVH (its own skeleton)."""
    return "robot_description" if source == "bvh" else "builtin"
