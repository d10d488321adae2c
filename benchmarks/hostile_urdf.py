"""Hostile URDFs sent to a running node on robot_description: is it alive and publishing, what did it refuse, how
much memory does it hold?

    python -m benchmarks.hostile_urdf              # the full-size descriptions of issue 37
    python -m benchmarks.hostile_urdf --small      # the small versions the tests use
    python -m benchmarks.hostile_urdf --max-urdf-bytes 10000000   # the 3-5 MB ones reach the tree checks

The node runs as a process of its own (``python -m clusterfem_ros.nodes.clusterfem_node``, skeleton.source
robot_description, a small jelly body), on a private ROS_DOMAIN_ID over shared memory. This script latches a
good URDF (the built-in humanoid's), sends joint states, then latches each hostile description in turn and
prints, per description: its size, the refusal the node counted on /diagnostics (robot_description_refused_*),
whether surface markers kept coming, and the node's resident memory (VmRSS) and peak (VmHWM) from
/proc/<pid>/status. The generators below are also the tests' (tests/test_urdf_check.py, small sizes).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

_INERTIAL = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
             '</inertial>')


def _link(name: str) -> str:
    return f'<link name="{name}">{_INERTIAL}</link>'


def _joint(name: str, parent: str, child: str, xyz: str = "0 0 0.1") -> str:
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="0 1 0"/>'
            '<limit lower="-1.5" upper="1.5" effort="10" velocity="10"/></joint>')


def robot(links: list[str], joints: list[tuple[str, str, str]], name: str = "hostile") -> str:
    """URDF text of links (names) and revolute joints (name, parent, child)."""
    parts = [_link(n) for n in links] + [_joint(*j) for j in joints]
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + "\n".join(parts) + "\n</robot>\n"


def chain(n: int) -> str:
    """n links in a line: l0 - l1 - ... (n - 1 joints deep)."""
    return robot([f"l{k}" for k in range(n)], [(f"j{k}", f"l{k - 1}", f"l{k}") for k in range(1, n)], "chain")


def star(n: int) -> str:
    """One root and n - 1 leaves on it."""
    return robot([f"l{k}" for k in range(n)], [(f"j{k}", "l0", f"l{k}") for k in range(1, n)], "star")


def self_loop() -> str:
    """A joint whose parent and child are the same link."""
    return robot(["base", "arm"], [("shoulder", "base", "arm"), ("loop", "arm", "arm")], "self_loop")


def cycle() -> str:
    """A root, and three links that are each other's children (each has one parent)."""
    return robot(["root", "a", "b", "c"], [("ab", "a", "b"), ("bc", "b", "c"), ("ca", "c", "a")], "cycle")


def two_parents() -> str:
    """A link that is the child of two joints."""
    return robot(["root", "a", "b", "c"], [("ra", "root", "a"), ("rb", "root", "b"), ("ac", "a", "c"),
                                           ("bc", "b", "c")], "two_parents")


def missing_link() -> str:
    """A joint naming a child link that is not defined."""
    return robot(["root"], [("rg", "root", "ghost")], "missing_link")


def billion_laughs() -> str:
    levels = ['<!ENTITY l0 "ha">'] + [f'<!ENTITY l{k} "{f"&l{k - 1};" * 10}">' for k in range(1, 10)]
    return f'<?xml version="1.0"?>\n<!DOCTYPE robot [{"".join(levels)}]>\n<robot name="&l9;"><link name="a"/></robot>'


def hostile_set(small: bool) -> list[tuple[str, str]]:
    """(name, URDF text) of issue 37's hostile descriptions, full size or small (still past the default limits)."""
    from clusterfem_ros.skeleton.urdf_check import DEFAULT_MAX_DEPTH, DEFAULT_MAX_LINKS
    if small:
        return [("self-loop", self_loop()), (f"chain of {DEFAULT_MAX_DEPTH + 2}", chain(DEFAULT_MAX_DEPTH + 2)),
                (f"star of {DEFAULT_MAX_LINKS + 1}", star(DEFAULT_MAX_LINKS + 1)), ("cycle", cycle()),
                ("two parents", two_parents()), ("missing link", missing_link()),
                ("billion laughs", billion_laughs())]
    return [("self-loop", self_loop()), ("chain of 1,000", chain(1000)), ("chain of 10,000", chain(10_000)),
            ("star of 10,000", star(10_000)), ("cycle", cycle()), ("two parents", two_parents()),
            ("missing link", missing_link()), ("billion laughs", billion_laughs()),
            ("5 MB", star(16_000))]


def memory_kb(pid: int) -> tuple[int, int]:
    """(VmRSS, VmHWM) of a process [kB]."""
    values = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            key, _, rest = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                values[key] = int(rest.split()[0])
    return values["VmRSS"], values["VmHWM"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--small", action="store_true", help="the tests' small versions")
    ap.add_argument("--wait", type=float, default=60.0, help="seconds to wait for each refusal")
    ap.add_argument("--max-urdf-bytes", type=int, default=0,
                    help="the node's skeleton.max_urdf_bytes (0: its default), e.g. 10000000 to let the 3 MB ones "
                         "reach the tree checks")
    args = ap.parse_args(argv)
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 50), FASTDDS_BUILTIN_TRANSPORTS="SHM")
    os.environ.update(env)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from visualization_msgs.msg import Marker

    from clusterfem_ros import topics
    from clusterfem_ros.nodes.clusterfem_node import LATCHED
    from clusterfem_ros.skeleton.humanoid import default_humanoid
    from clusterfem_ros.skeleton.kinematics import Skeleton
    params = {"skeleton.source": "robot_description", "body.kind": "jelly_man", "body.target_tets": 700,
              "warping": False, "output.diagnostics_rate_hz": 5.0, "output.marker_rate_hz": 20.0}
    if args.max_urdf_bytes:
        params["skeleton.max_urdf_bytes"] = args.max_urdf_bytes
    cmd = [sys.executable, "-m", "clusterfem_ros.nodes.clusterfem_node", "--ros-args"]
    for k, v in params.items():
        cmd += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
    log = open(os.path.join(os.environ.get("TMPDIR", "/tmp"), f"hostile_urdf_node_{os.getpid()}.log"), "w+")
    node_proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    rclpy.init()
    me = rclpy.create_node("hostile_urdf")
    state = {"diag": {}, "markers": 0}

    def on_diag(msg):
        for st in msg.status:
            if st.name.endswith("simulation"):
                state["diag"] = {kv.key: kv.value for kv in st.values}

    me.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name, on_diag, 10)
    me.create_subscription(Marker, topics.SURFACE.name,
                           lambda m: state.__setitem__("markers", state["markers"] + 1), 1)
    urdf_pub = me.create_publisher(String, topics.ROBOT_DESCRIPTION.name, LATCHED)
    joints_pub = me.create_publisher(JointState, topics.JOINT_STATES.name, 10)
    human = default_humanoid().urdf
    names = Skeleton.from_urdf_string(human).joint_names

    def spin_for(seconds: float, until=lambda: False) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = JointState(name=names, position=[0.0] * len(names))
            msg.header.stamp = me.get_clock().now().to_msg()
            joints_pub.publish(msg)
            rclpy.spin_once(me, timeout_sec=0.02)
            if node_proc.poll() is not None:
                raise SystemExit(f"the node exited with {node_proc.returncode}; its log: {log.name}")
            if until():
                return True
        return False

    def refused() -> int:
        return int(state["diag"].get("robot_description_refused", "0"))

    try:
        urdf_pub.publish(String(data=human))
        if not spin_for(180.0, lambda: state["markers"] > 5):
            raise SystemExit(f"no markers from the node on the humanoid within 180 s; its log: {log.name}")
        rss, hwm = memory_kb(node_proc.pid)
        print(f"node pid {node_proc.pid} running on the humanoid: VmRSS {rss / 1024:.0f} MB, VmHWM {hwm / 1024:.0f} MB")
        print(f"{'URDF':<18} {'bytes':>9} {'refused as':<18} {'markers':>8} {'VmRSS MB':>9} {'VmHWM MB':>9}")
        for name, text in hostile_set(args.small):
            before, kinds = refused(), dict(state["diag"])
            urdf_pub.publish(String(data=text))
            got = spin_for(args.wait, lambda: refused() > before)
            m0 = state["markers"]
            spin_for(1.0)
            kind = next((k[len("robot_description_refused_"):] for k, v in state["diag"].items()
                         if k.startswith("robot_description_refused_") and v != kinds.get(k, "0")), "-")
            rss, hwm = memory_kb(node_proc.pid)
            print(f"{name:<18} {len(text.encode()):>9} {kind if got else 'NOT REFUSED':<18} "
                  f"{state['markers'] - m0:>8} {rss / 1024:>9.0f} {hwm / 1024:>9.0f}", flush=True)
        log.flush()
        log.seek(0)
        lines = [x.rstrip() for x in log if "robot_description refused" in x]
        print(f"\nthe node's refusal lines ({len(lines)}):")
        for x in lines:
            print("  " + (x if len(x) <= 300 else x[:300] + "..."))
        print(f"node alive: {node_proc.poll() is None}")
    finally:
        node_proc.terminate()
        try:
            node_proc.wait(20)
        except subprocess.TimeoutExpired:
            node_proc.kill()
        me.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
