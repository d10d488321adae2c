"""The node in real time: physics on its own thread (a failure is reported as ERROR on /diagnostics and the
node goes on); several bodies on one ROS graph, as node instances in one executor, each in its own namespace
with its own joint_states, outputs and scene (their outputs do not mix), and as one process per body
(scripts/run --bodies N --process-per-body); the node's own latency and stage measurements."""
import json
import subprocess
import sys

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from clusterfem_ros.nodes.testing import RosWorld
from tests.ros_env import child_env

pytestmark = pytest.mark.ros

SMALL_MAN = {"body.kind": "jelly_man", "body.target_tets": 700, "skeleton.source": "builtin", "warping": False,
             "output.marker_rate_hz": 20.0, "output.stress_rate_hz": 10.0, "output.diagnostics_rate_hz": 5.0}
# two walks: the built-in one from its start at normal speed, and 3 s into it (3 m on) at 1.5x
WALKS = {"alice": {"speed": 1.0, "start_offset": 0.0}, "bob": {"speed": 1.5, "start_offset": 3.0}}


def _params(values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _marker(raw):
    from visualization_msgs.msg import Marker
    m = deserialize_message(raw, Marker)
    return m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, np.array([[p.x, p.y, p.z] for p in m.points])


def _root_x(sim, t):
    q, _ = sim.scene.stream.sample(t)
    return q[sim.scene.skeleton.joint_names.index("root_x")]


def test_two_bodies_in_one_executor_follow_their_own_walks_and_never_mix():
    from diagnostic_msgs.msg import DiagnosticArray
    from visualization_msgs.msg import Marker

    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    from clusterfem_ros.nodes.player_node import MocapPlayer
    from msg_adapters.diagnostics import diagnostic_values
    with RosWorld() as world:
        sims, players, markers = {}, {}, {}
        for ns, walk in WALKS.items():
            markers[ns] = world.collect(Marker, f"/{ns}/clusterfem/surface")
            sims[ns] = world.add(ClusterFemNode(context=world.context, namespace=ns, parameter_overrides=_params(
                {**SMALL_MAN, "material.young_modulus": 3e4 if ns == "alice" else 6e4})))   # a scene each
        diags = world.collect(DiagnosticArray, "/diagnostics")
        for ns, walk in WALKS.items():
            players[ns] = world.add(MocapPlayer(context=world.context, namespace=ns,
                                                parameter_overrides=_params({"rate_hz": 100.0, **walk})))
        world.wait_for(lambda: all(len(m) >= 15 for m in markers.values()), 60, "15 markers from each body")
        world.wait_for(lambda: {s.status[0].name for s in map(lambda r: deserialize_message(r, DiagnosticArray), diags)}
                       >= {"alice/clusterfem: simulation", "bob/clusterfem: simulation"}, 20, "both diagnostics")
        topics = {name for name, _ in world.nodes[0].get_topic_names_and_types()}
        ends = {}
        for ns, sim in sims.items():
            other = sims["bob" if ns == "alice" else "alice"]
            t, x = _marker(markers[ns][-1])
            centroid = x[:, 0].mean()
            ends[ns] = centroid
            assert abs(centroid - _root_x(sim, t)) < 0.3, ns          # on its own skeleton ...
            assert abs(centroid - _root_x(other, t)) > 1.5, ns        # ... far from the other one
            received, published = sim.counts["joint_states"], players[ns].published
            assert 0 < received <= published, (ns, received, published)   # no sample of the other walk
            assert sim.scene.inputs.total_rejected == 0 and sim.divergences == 0
            assert sim.scene.config["material.young_modulus"] == (3e4 if ns == "alice" else 6e4)
            lat = sim.physics.latency.percentiles()
            assert sim.physics.latency.count > 0 and 0 < lat["latency_p50_ms"] <= lat["latency_max_ms"]
            totals = sim.physics.stages.totals
            assert all(totals[k] > 0 for k in ("inputs", "skeleton", "physics", "checks", "snapshot", "stress",
                                                "markers"))
        assert ends["bob"] - ends["alice"] > 2.0                        # 3 m on, at 1.5x: ahead all the time
        assert {"/alice/clusterfem/surface", "/bob/clusterfem/surface", "/alice/joint_states",
                "/bob/joint_states"} <= topics
        assert not {"/clusterfem/surface", "/joint_states"} & topics
        named = {}
        for raw in diags:
            status = deserialize_message(raw, DiagnosticArray).status[0]
            named[status.name] = diagnostic_values(deserialize_message(raw, DiagnosticArray))
        for ns in WALKS:
            values = named[f"{ns}/clusterfem: simulation"]
            assert values["inputs_accepted"] > 0 and "latency_p99_ms" in values and "share_physics" in values


def test_a_failing_step_is_an_error_on_diagnostics_and_the_node_goes_on():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from visualization_msgs.msg import Marker

    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    with RosWorld() as world:
        sim = world.add(ClusterFemNode(context=world.context, parameter_overrides=_params(
            {"body.kind": "sphere", "skeleton.source": "none", "warping": False, "output.marker_rate_hz": 50.0,
             "output.diagnostics_rate_hz": 20.0})))
        real_step = sim.scene.integrator.step
        failures = {"left": 1}

        def step(*args):
            if failures["left"] and sim.scene.steps_done >= 100:
                failures["left"] -= 1
                raise RuntimeError("injected failure")
            return real_step(*args)

        sim.scene.integrator.step = step
        diags = world.collect(DiagnosticArray, "/diagnostics")
        markers = world.collect(Marker, "clusterfem/surface")
        world.wait_for(lambda: sim.physics.crashes == 1, 20, "the injected failure")
        n, steps = len(markers), sim.scene.steps_done
        world.wait_for(lambda: len(markers) > n + 5 and sim.scene.steps_done > steps + 100, 20, "physics going on")
        world.wait_for(lambda: any(deserialize_message(r, DiagnosticArray).status[0].level == DiagnosticStatus.ERROR
                                   for r in diags), 20, "an ERROR status")
        status = next(s for s in (deserialize_message(r, DiagnosticArray).status[0] for r in diags)
                      if s.level == DiagnosticStatus.ERROR)
        assert "injected failure" in status.message and sim.physics.running and not sim.physics.stopped
    assert not sim.physics.running                      # the world's teardown joined the thread


def test_body_namespaces_and_rss_growth():
    from clusterfem_ros.nodes.bodies import body_namespaces, rss_growth
    assert body_namespaces(1) == [""] and body_namespaces(1, "/lab/") == ["lab"]
    assert body_namespaces(3) == ["body1", "body2", "body3"]
    assert body_namespaces(2, "lab") == ["lab/body1", "lab/body2"]
    with pytest.raises(ValueError, match="--bodies 0"):
        body_namespaces(0)
    g = rss_growth([(0.0, 50.0), (1.0, 100.0), (2.0, 104.0), (3.0, 102.0)], warm_up_s=1.0)
    assert (g["rss_warm_mb"], g["rss_end_mb"], g["rss_peak_mb"]) == (100.0, 102.0, 104.0)
    assert g["rss_growth_pct"] == pytest.approx(4.0)


def test_the_demo_runs_two_bodies_as_two_processes(tmp_path):
    """scripts/run --bodies 2 --process-per-body, small bodies: both run in their own namespaces and processes."""
    scenes = []
    for k, young in enumerate((3e4, 6e4)):
        f = tmp_path / f"body{k + 1}.yaml"
        f.write_text("clusterfem:\n  ros__parameters:\n    body.target_tets: 700\n    warping: false\n"
                     f"    material.young_modulus: {young}\n")
        scenes += ["--scene", str(f)]
    out = tmp_path / "summary.json"
    run = subprocess.run([sys.executable, "-m", "clusterfem_ros.nodes.demo", "--bodies", "2", "--process-per-body",
                          "--duration", "3", "--no-png", "--bags", str(tmp_path), "--summary-json", str(out), *scenes],
                         env=child_env(180), capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    bodies = json.loads(out.read_text())["bodies"]
    assert [b["namespace"] for b in bodies] == ["/body1", "/body2"]
    assert all(b["tets"] < 1500 and b["steps"] > 0 and b["inputs_used"] > 0 and b["inputs_rejected"] == 0
               for b in bodies)
    bags = sorted(p.name.rsplit("_", 2)[0] for p in tmp_path.iterdir() if p.is_dir())
    assert bags == ["clusterfem_body1", "clusterfem_body2"]          # a recording each


def test_the_demo_s_summary_of_two_bodies_in_one_process_tells_each_body_s_own_numbers(tmp_path):
    """scripts/run --bodies 2 in one process: each body's printed summary reports the same timed run as the
    summary table (its JSON): the real-time factor and steps of that body, not of the other or of the wall."""
    import re
    out = tmp_path / "summary.json"
    run = subprocess.run([sys.executable, "-m", "clusterfem_ros.nodes.demo", "--bodies", "2", "--duration", "3",
                          "--no-png", "--no-record", "--summary-json", str(out)],
                         env=child_env(180), capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    bodies = {b["namespace"].strip("/"): b for b in json.loads(out.read_text())["bodies"]}
    assert sorted(bodies) == ["body1", "body2"], run.stdout[-3000:]
    for ns, b in bodies.items():
        found = re.search(rf"summary of /?{ns}\n(?:.*\n)*?  physics steps   (\d+) of .*real-time factor ([\d.]+)",
                          run.stdout)
        assert found, (ns, run.stdout[-3000:])
        steps, rtf = found.groups()
        assert int(steps) == b["steps"] and float(rtf) == pytest.approx(b["real_time_factor"], abs=0.006), ns
