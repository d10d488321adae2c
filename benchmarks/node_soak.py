"""A clip played through the node: the mocap player and the clusterfem node in one process (nodes/testing.py's
RosWorld: own context and domain, shared-memory DDS), physics on the input clock, markers at 30 Hz.

Every published marker is checked on the receiving side, independently of the node's own checks: its points'
distance to the nearest bone segment of the skeleton at the joint state the marker's stamp belongs to (the
newest joint state sent at or before it, forward kinematics of the clip's URDF). ``worst_distance`` is the
largest over all markers [m]; ``markers_far`` counts markers with a point beyond ``output.max_bone_distance``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .clips import clip_config, played_seconds


@dataclass
class NodeSoakResult:
    clip: str
    seconds: float
    resets: int = 0
    withheld: int = 0
    markers: int = 0
    markers_far: int = 0
    worst_distance: float = 0.0
    rejected: int = 0
    dropped_s: float = 0.0


def _marker_distance(raw: bytes, states: list[tuple[int, np.ndarray]], skeleton, columns) -> float:
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import Marker
    from clusterfem_ros.body.binding import segment_distance
    m = deserialize_message(raw, Marker)
    stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
    k = max(0, int(np.searchsorted([s for s, _ in states], stamp + 1_000_000, side="right")) - 1)   # within 1 ms
    q = states[k][1][columns]
    starts, ends = skeleton.bone_segments(q)
    pts = np.unique(np.array([[p.x, p.y, p.z] for p in m.points]), axis=0)
    return float(segment_distance(pts, starts, ends).min(axis=1).max())


def _played(player) -> float:
    """How far into the motion the player is [s]: its motion time runs on the clock, so a player whose timer
    falls behind under load still stops after ``length`` of motion (its sample count would run on for several
    times that on a loaded host)."""
    return player.motion_time(player.get_clock().now().nanoseconds * 1e-9) if player.published else 0.0


def node_soak(path: Path, overrides: dict | None = None, seconds: float | None = None,
              timeout_factor: float = 6.0, scene_file: Path | None = None) -> NodeSoakResult:
    """Play the clip at ``path``, looped by the player, for ``played_seconds`` (its length or MIN_SECONDS, or
    ``seconds``) through the node (on the default scene, or ``scene_file``'s body
    fitted to the clip's skeleton); see the module docstring."""
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from visualization_msgs.msg import Marker
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.skeleton.kinematics import Skeleton
    from clusterfem_ros.nodes.testing import RosWorld
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    from clusterfem_ros.nodes.player_node import MocapPlayer
    from clusterfem_ros import topics
    motion = load_motion("bvh", path)
    length = played_seconds(motion.trajectory.duration, seconds)
    config = clip_config({"physics.clock": "input", "output.marker_rate_hz": 30.0, "output.stress_rate_hz": 0.0,
                          "output.diagnostics_rate_hz": 0.0, **(overrides or {})}, scene_file, path)
    res = NodeSoakResult(path.stem, length)
    with RosWorld() as world:
        sim = world.add(ClusterFemNode(context=world.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in config.values.items()]))
        markers = world.collect(Marker, topics.SURFACE.name, qos=1000)
        sent = world.collect(JointState, topics.JOINT_STATES.name, qos=1000)
        player = world.add(MocapPlayer(context=world.context, parameter_overrides=[
            Parameter("source", value="bvh"), Parameter("file", value=str(path)), Parameter("rate_hz", value=120.0),
            Parameter("loop", value=True)]))
        deadline = time.monotonic() + 60.0 + timeout_factor * length
        while time.monotonic() < deadline and _played(player) <= length:
            time.sleep(0.1)
        time.sleep(0.5)                                          # the last ticks' markers
        world.executor.shutdown(timeout_sec=5.0)
        res.resets, res.withheld, res.markers = sim.divergences, sim.withheld, len(markers)
        if sim.scene is not None:
            res.rejected, res.dropped_s = sim.scene.inputs.total_rejected, sim.scene.dropped_s
        states = []
        for raw in sent:
            js = deserialize_message(raw, JointState)
            states.append((js.header.stamp.sec * 10**9 + js.header.stamp.nanosec, np.array(js.position)))
        skeleton = Skeleton.from_urdf_string(motion.urdf)
        names = list(motion.trajectory.names)
        columns = np.array([names.index(n) for n in skeleton.joint_names])
        limit = config.output.max_bone_distance
        for raw in markers:
            d = _marker_distance(raw, states, skeleton, columns) if states else np.inf
            res.worst_distance = max(res.worst_distance, d)
            res.markers_far += int(d > limit)
    return res
