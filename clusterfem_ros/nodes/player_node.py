"""The mocap player: plays a BVH file, a key-frame file, the built-in walk or a URDF's joint sweep as
sensor_msgs/JointState, and latches the matching URDF on robot_description, so the simulation needs no separate
file.

    mocap_player --ros-args -p source:=bvh -p file:=mocap/cmu_06_01_walk.bvh

Its parameters: source (builtin_walk, bvh, keyframes or joint_sweep), file, rate_hz, speed, start_offset,
start_delay, loop, loop_blend, unit, up (motion.PLAYER_TABLE); an unknown name is refused, naming the nearest
known one, and a value is typed and checked as the simulation node's are (an integer for a float, a choice in any
case).
"""
from __future__ import annotations

from dataclasses import replace

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from msg_adapters.joint_state import joint_state_cdr

from ..motion import PLAYER_NODE, PLAYER_TABLE, check_player_value, load_motion, unknown_player_parameter
from .params import declare_checked
from .spinning import run_node

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _read_at_start(changes: dict) -> str:
    """The player reads its parameters once, at start: a change while it plays is refused, saying so."""
    name, value = next(iter(changes.items()))
    return f"{PLAYER_NODE} reads {name} at start only: restart the player with -p {name}:={value}"


class MocapPlayer(Node):
    def __init__(self, **node_kwargs):
        super().__init__(PLAYER_NODE, **node_kwargs)
        # typed and checked as the simulation node's parameters are (nodes/params.py): a misspelt name is refused,
        # an integer taken for a float, a choice in any case or spelt as a YAML 1.1 boolean (up:=y)
        p = declare_checked(self, PLAYER_TABLE, check_player_value, unknown_player_parameter, _read_at_start)
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
