"""The mocap player: plays a BVH file, a key-frame file or the built-in walk as sensor_msgs/JointState,
and latches the matching URDF on robot_description, so the simulation needs no separate file."""
from __future__ import annotations

from dataclasses import replace

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from msg_adapters.joint_state import joint_state_cdr

from ..motion import PLAYER_PARAMS, load_motion
from .spinning import run_node

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _range(lo: float, hi: float, text: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi)])


class MocapPlayer(Node):
    def __init__(self, **node_kwargs):
        super().__init__("mocap_player", **node_kwargs)
        self.declare_parameter("source", "builtin_walk", ParameterDescriptor(
            description="builtin_walk, bvh or keyframes", additional_constraints="one of: builtin_walk, bvh, keyframes"))
        self.declare_parameter("file", "", ParameterDescriptor(description=(
            "BVH or key-frame file for those sources: a path, or a name under $CLUSTERFEM_DATA or ../shared/data")))
        self.declare_parameter("rate_hz", 120.0, _range(1.0, 2000.0, "JointState publish rate [Hz]"))
        self.declare_parameter("speed", 1.0, _range(0.01, 100.0, "playback speed factor"))
        self.declare_parameter("start_offset", 0.0, _range(0.0, 1e6, "start this far into the motion [s]"))
        self.declare_parameter("start_delay", 0.0, _range(0.0, 3600.0, (
            "wait this long before playing, the skeleton latched at once: a node that builds its body from "
            "robot_description (a new mesh takes minutes) then gets the motion from its start [s]")))
        self.declare_parameter("loop", True, ParameterDescriptor(description="loop the motion at its end"))
        self.declare_parameter("loop_blend", 0.5, _range(0.0, 60.0, (
            "looping a motion that does not end where it starts: its last seconds are blended into its start "
            "over this time, the root's horizontal position carried on (0 = jump back to the start, which the "
            "node takes as a teleport and re-places the body) [s]")))
        p = {n: self.get_parameter(n).value for n in PLAYER_PARAMS}
        self.params = p
        self.motion = load_motion(p["source"], p["file"])
        if p["loop"] and p["loop_blend"] > 0:
            self.motion = replace(self.motion, trajectory=self.motion.trajectory.with_seam(
                min(p["loop_blend"], 0.5 * self.motion.trajectory.duration), self.motion.carry))
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
    run_node(MocapPlayer, args)


if __name__ == "__main__":
    main()
