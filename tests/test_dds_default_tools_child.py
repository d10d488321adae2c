"""Helper process for test_dds_default_tools.py (no tests here), run inside a network namespace with only
loopback: starts the main job (scripts/run's clusterfem_ros.nodes.demo) as its own process, and subscribes here,
in this process's plain environment (no DDS variable: ROS 2's defaults, as a user's `ros2 topic echo`), to the
surface, the stress cloud and the diagnostics; prints one JSON line: messages received per topic, the DDS setting
the main job reported, and its exit code.

usage: python tests/test_dds_default_tools_child.py SECONDS
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOPICS = {"/clusterfem/surface": "visualization_msgs.msg.Marker", "/clusterfem/stress": "sensor_msgs.msg.PointCloud2",
          "/diagnostics": "diagnostic_msgs.msg.DiagnosticArray"}


def main() -> int:
    seconds = float(sys.argv[1])
    job = subprocess.Popen([sys.executable, "-m", "clusterfem_ros.nodes.demo", "--duration", f"{seconds:g}",
                            "--no-record", "--no-png", "--no-video"], cwd=ROOT, env=os.environ,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    import importlib

    import rclpy
    rclpy.init()
    node = rclpy.create_node("default_tools_probe")
    got = {t: 0 for t in TOPICS}

    def counter(topic):
        def count(_data):
            got[topic] += 1
        return count
    for topic, type_path in TOPICS.items():
        module, name = type_path.rsplit(".", 1)
        node.create_subscription(getattr(importlib.import_module(module), name), topic, counter(topic), 10, raw=True)
    try:
        while job.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.1)
        out = job.stdout.read()
    finally:
        if job.poll() is None:
            job.kill()
        node.destroy_node()
        rclpy.try_shutdown()
    dds = [line for line in out.splitlines() if "ROS_DOMAIN_ID=" in line]
    print(json.dumps({"received": got, "job_exit": job.returncode, "job_dds": dds[:1], "job_tail": out[-3000:]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
