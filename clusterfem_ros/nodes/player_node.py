"""The mocap player: plays a BVH file, a key-frame file, the built-in walk or a URDF's joint sweep as
sensor_msgs/JointState, and latches the matching URDF on robot_description, so the simulation needs no separate
file.

    mocap_player --ros-args -p source:=bvh -p file:=mocap/cmu_06_01_walk.bvh

Its parameters: source (builtin_walk, bvh, keyframes or joint_sweep), file, rate_hz, speed, start_offset, loop,
loop_blend, unit, up; an unknown name is refused, naming the nearest known one.
"""
from __future__ import annotations

import difflib
from dataclasses import replace

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from msg_adapters.joint_state import joint_state_cdr

from ..motion import PLAYER_PARAMS, SOURCES, load_motion
from .params import ROS_NAMES
from .spinning import run_node

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _range(lo: float, hi: float, text: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi)])


def unknown_player_parameter(name: str) -> ValueError:
    """The error for a parameter the player does not have, naming the nearest one it has."""
    close = difflib.get_close_matches(name, PLAYER_PARAMS, n=1, cutoff=0.6)
    hint = f"did you mean {close[0]!r}?" if close else f"its parameters are {', '.join(PLAYER_PARAMS)}"
    return ValueError(f"unknown mocap_player parameter {name!r}: {hint}")


class MocapPlayer(Node):
    def __init__(self, **node_kwargs):
        super().__init__("mocap_player", **node_kwargs)
        for name in self._parameter_overrides:          # a misspelt name is refused, as the simulation node does
            if name not in PLAYER_PARAMS and name not in ROS_NAMES and not name.startswith("qos_overrides."):
                raise unknown_player_parameter(name)
        self.declare_parameter("source", "builtin_walk", ParameterDescriptor(
            description="builtin_walk, bvh, keyframes or joint_sweep (a URDF's joints through their ranges)",
            additional_constraints=f"one of: {', '.join(SOURCES)}"))
        self.declare_parameter("file", "", ParameterDescriptor(description=(
            "BVH, key-frame or URDF file for those sources: a path, package://<package>/<path> of an installed "
            "package, or a name under $CLUSTERFEM_DATA, ../shared/data or the user data folder")))
        self.declare_parameter("rate_hz", 120.0, _range(1.0, 2000.0, "JointState publish rate [Hz]"))
        self.declare_parameter("speed", 1.0, _range(0.01, 100.0, "playback speed factor"))
        self.declare_parameter("start_offset", 0.0, _range(0.0, 1e6, "start this far into the motion [s]"))
        self.declare_parameter("start_delay", 0.0, _range(0.0, 3600.0, (
            "wait this long before playing, the skeleton latched at once: a node that builds its body from "
            "robot_description (a new mesh takes minutes) then gets the motion from its start [s]")))
        self.declare_parameter("loop", True, ParameterDescriptor(description="loop the motion at its end"))
        self.declare_parameter("loop_blend", 0.5, _range(0.0, 60.0, (
            "looping a motion that does not end where it starts: its last seconds are blended into its start "
            "over this time (a capture's joints as rotations), the root's horizontal position and heading carried "
            "on (0 = jump back to the start, which the node takes as a teleport and re-places the body) [s]")))
        self.declare_parameter("unit", "auto", ParameterDescriptor(dynamic_typing=True, description=(
            "a BVH file's length unit: auto (found from the skeleton: a standing human), m, cm, mm, inch, cmu "
            "(0.056444 m) or metres per file unit as a number")))
        self.declare_parameter("up", "auto", ParameterDescriptor(description=(
            "a BVH file's up axis: auto (found from the legs of the rest pose), X, Y, Z, -X, -Y or -Z")))
        p = {n: self.get_parameter(n).value for n in PLAYER_PARAMS}
        self.params = p
        self.motion = load_motion(p["source"], p["file"], unit=p["unit"], up=p["up"])
        if self.motion.placement:
            self.get_logger().info(self.motion.placement)
        if p["loop"] and p["loop_blend"] > 0:
            self.motion = replace(self.motion, trajectory=self.motion.looping(
                min(p["loop_blend"], 0.5 * self.motion.trajectory.duration)))
        self.names = list(self.motion.trajectory.names)
        self._pub = self.create_publisher(JointState, "joint_states", 10)
        self._urdf_pub = self.create_publisher(String, "robot_description", LATCHED)
        self._urdf_pub.publish(String(data=self.motion.urdf))
        self._t0 = None
        self._created_s = self.get_clock().now().nanoseconds * 1e-9
        self.published = 0
        self.finished = False
        self.create_timer(1.0 / p["rate_hz"], self._tick)
        self.get_logger().info(f"playing {self.motion.description}: {len(self.names)} joints, "
                               f"{self.motion.trajectory.duration:.2f} s at x{p['speed']} on joint_states")

    def motion_time(self, now_s: float) -> float:
        if self._t0 is None:
            self._t0 = now_s
        return self.params["start_offset"] + (now_s - self._t0) * self.params["speed"]

    def _tick(self) -> None:
        if self.finished:
            return
        now = self.get_clock().now()
        if now.nanoseconds * 1e-9 - self._created_s < self.params["start_delay"]:
            return
        t = self.motion_time(now.nanoseconds * 1e-9)
        duration = self.motion.trajectory.duration
        if t > duration and not self.params["loop"]:
            self.finished = True
            self.get_logger().info("motion finished (loop is off)")
            return
        q, v = self.motion.trajectory.sample(t, loop=self.params["loop"])
        self._pub.publish(joint_state_cdr(self.names, q, v * self.params["speed"], stamp=now.nanoseconds))
        self.published += 1


def main(args=None) -> None:
    run_node(MocapPlayer, args, help_text=__doc__)


if __name__ == "__main__":
    main()
