"""Helper process for test_hostile_soak.py (no tests here): floods joint_states from its own process.

usage: python tests/test_hostile_flood_child.py <domain id> <seconds> <rate Hz> <joint names, comma-separated>
Sends, in turn, 48 good joint states (stamped now), one with too many names and one of garbage bytes, at
``rate`` messages a second in all; prints 'ready' once matched, then one JSON line of what it sent per kind.
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np

import rclpy
from rclpy.context import Context
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from msg_adapters.joint_state import joint_state_cdr

OVERSIZED_NAMES = 5000


def main(domain: int, seconds: float, rate: float, names: list[str]) -> None:
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("flood", context=ctx)
    pub = node.create_publisher(JointState, "joint_states", qos_profile_sensor_data)
    while pub.get_subscription_count() == 0:
        time.sleep(0.01)
    print("ready", flush=True)
    q = np.zeros(len(names))
    big_names = [f"x{i}" for i in range(OVERSIZED_NAMES)]
    oversized = joint_state_cdr(big_names, np.zeros(OVERSIZED_NAMES), stamp=1)
    sent = {"good": 0, "too_many_names": 0, "malformed": 0}
    t0 = time.perf_counter()
    k = 0
    while time.perf_counter() - t0 < seconds:
        kind = "good" if k % 50 < 48 else "too_many_names" if k % 50 == 48 else "malformed"
        data = (joint_state_cdr(names, q, stamp=time.time_ns()) if kind == "good" else
                oversized if kind == "too_many_names" else b"garbage!")
        pub.publish(data)
        sent[kind] += 1
        k += 1
        ahead = k / rate - (time.perf_counter() - t0)
        if ahead > 0:
            time.sleep(ahead)
    sent["seconds"] = time.perf_counter() - t0
    print(json.dumps(sent), flush=True)
    node.destroy_node()
    ctx.try_shutdown()


if __name__ == "__main__":
    main(int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4].split(","))
