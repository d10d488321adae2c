"""Hostile URDFs on robot_description sent to the node, launch-free (issue 37): a latched bad one does not stop
a starting node, each is refused with one line and counted on /diagnostics, the body goes on, memory stays
small."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message

from benchmarks.hostile_urdf import hostile_set, self_loop
from tests.test_node_skeleton import SMALL_MAN, _params, world  # noqa: F401  (world: the fixture)

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[1]


def _latched(world):
    from std_msgs.msg import String

    from clusterfem_ros.nodes.clusterfem_node import LATCHED
    pub = world.node("description_publisher").create_publisher(String, "robot_description", LATCHED)
    return lambda text: pub.publish(String(data=text))


def _sim(world):
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    return world.add(ClusterFemNode(context=world.context, parameter_overrides=_params(
        {**SMALL_MAN, "skeleton.source": "robot_description", "body.bone_radius": 0.04})))


def test_a_latched_bad_description_is_refused_then_a_good_one_builds_and_later_bad_ones_leave_it_running(world):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from visualization_msgs.msg import Marker

    from tests.test_joint_limits import ARM
    publish = _latched(world)
    publish(self_loop())                                   # latched before the node starts (a restart)
    sim = _sim(world)
    diags = world.collect(DiagnosticArray, "/diagnostics")
    world.wait_for(lambda: sim.descriptions_refused.get("self_loop") == 1, 30, "the latched self-loop refused")
    world.wait_for(lambda: len(diags) >= 2, 10, "diagnostics while waiting for a good description")
    status = deserialize_message(diags[-1], DiagnosticArray).status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == b"\x01" and "'loop'" in status.message          # WARN, naming the joint
    assert values["robot_description_refused_self_loop"] == "1"
    assert sim.scene is None

    publish(ARM)                                           # a fixed-base arm whose joints have limits
    world.wait_for(lambda: sim.scene is not None, 120, "the scene built from the good description")
    scene = sim.scene
    markers = world.collect(Marker, "clusterfem/surface")
    joints = world.node("joints").create_publisher(JointState, "joint_states", 10)
    names = scene.skeleton.joint_names

    def send():
        msg = JointState(name=names, position=[0.0] * len(names))
        msg.header.stamp = world.nodes[-1].get_clock().now().to_msg()
        joints.publish(msg)

    for name, text in hostile_set(small=True):
        before = sum(sim.descriptions_refused.values())
        publish(text)
        world.wait_for(lambda: (send(), sum(sim.descriptions_refused.values()) > before)[1], 30, f"{name} refused")
    assert sim.descriptions_refused == {"self_loop": 2, "too_deep": 1, "too_many_links": 1, "cycle": 1,
                                        "two_parents": 1, "missing_link": 1, "doctype": 1}
    assert sim.scene is scene                              # the body built on the good one runs on
    seen = len(markers)
    world.wait_for(lambda: (send(), len(markers) > seen + 3)[1], 30, "markers after the hostile descriptions")
    assert scene.inputs.accepted > 0 and sim.divergences == 0
    q = np.zeros(len(names))
    q[names.index("elbow")] = 1e308                        # a revolute joint far past its URDF limits

    def send_far():
        msg = JointState(name=names, position=q.tolist())
        msg.header.stamp = world.nodes[-1].get_clock().now().to_msg()
        joints.publish(msg)
    world.wait_for(lambda: (send_far(), sim.diagnostics().get("rejected_joint_range", 0) > 0)[1], 30,
                   "a joint value out of range counted on diagnostics")
    assert sim.diagnostics()["robot_description_refused"] == 8


_CHILD = """
import os
from benchmarks.hostile_urdf import hostile_set, memory_kb
from clusterfem_ros.nodes.testing import RosWorld
from tests.test_hostile_urdf_node import _latched, _sim
with RosWorld() as world:
    sim = _sim(world)
    publish = _latched(world)
    for name, text in hostile_set(small=False):
        before = sum(sim.descriptions_refused.values())
        publish(text)
        world.wait_for(lambda: sum(sim.descriptions_refused.values()) > before, 120, name)
        print(name, sim.build_error.replace(chr(10), " ")[:120], flush=True)
    print("refused", sum(sim.descriptions_refused.values()), sorted(sim.descriptions_refused))
    print("peak_rss_mb", memory_kb(os.getpid())[1] / 1024)
"""


def test_the_issue_s_full_size_descriptions_are_refused_by_a_node_that_stays_small():
    """In a process of its own (its peak memory is the node path's): the self-loop, chains of 1,000 and 10,000
    links, a star of 10,000, a cycle, two parents, a missing link, billion laughs and 5 MB, each refused with one
    line; the process's peak resident memory stays below 1 GB (the 1,000-link chain took 22 GB). The peak is the
    child's VmHWM: its ru_maxrss would count the resident size of the pytest process it was forked from."""
    out = subprocess.run([sys.executable, "-c", _CHILD], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert lines[-2].startswith(f"refused {len(hostile_set(small=False))} ")
    peak = float(lines[-1].split()[-1])
    assert peak < 1024, f"peak resident memory {peak:.0f} MB"
    refusals = [x for x in out.stderr.splitlines() if "robot_description refused" in x]
    assert len(refusals) == len(hostile_set(small=False))            # one line each


@pytest.mark.soak
def test_hostile_urdf_benchmark_on_a_running_node():
    """benchmarks/hostile_urdf.py: the node in its own process, on a body, takes every full-size description."""
    out = subprocess.run([sys.executable, "-m", "benchmarks.hostile_urdf"], cwd=ROOT, capture_output=True,
                         text=True, timeout=1200)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "NOT REFUSED" not in out.stdout and "node alive: True" in out.stdout
    lines = out.stdout.splitlines()
    start = next(k for k, x in enumerate(lines) if x.startswith("URDF ")) + 1
    rows = [x.split() for x in lines[start:lines.index("", start)]]
    assert len(rows) == len(hostile_set(small=False)), out.stdout
    assert all(float(r[-2]) < 1024 for r in rows), out.stdout
    assert np.all([int(r[-3]) > 0 for r in rows]), out.stdout          # markers kept coming after each
