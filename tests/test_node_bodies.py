"""Several bodies on one ROS graph: node instances in one executor, each in its own namespace with its own
joint_states, outputs and scene; their outputs do not mix. The node's own latency and stage measurements."""
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from clusterfem_ros.nodes.testing import RosWorld

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
            assert all(totals[k] > 0 for k in ("inputs", "skeleton", "physics", "snapshot", "stress", "markers"))
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
