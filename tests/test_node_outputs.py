"""The clusterfem node, launch-free: outputs, parameters, and a recording read back by rosbags."""
import numpy as np
import pytest
from rclpy.parameter import Parameter

from clusterfem_ros.nodes.testing import RosWorld

pytestmark = pytest.mark.ros

SPHERE = {"body.kind": "sphere", "skeleton.source": "none", "warping": False,
          "output.marker_rate_hz": 50.0, "output.stress_rate_hz": 50.0, "output.diagnostics_rate_hz": 20.0}


def _overrides(values):
    return [Parameter(k, value=v) for k, v in values.items()]


@pytest.fixture
def world():
    with RosWorld() as w:
        yield w


def _node(world, **values):
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    return world.add(ClusterFemNode(context=world.context, parameter_overrides=_overrides({**SPHERE, **values})))


def _last(got, msg_type):
    from rclpy.serialization import deserialize_message
    return deserialize_message(got[-1], msg_type)


def test_marker_stress_and_diagnostics_arrive_and_are_finite(world):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import Marker

    from msg_adapters.diagnostics import diagnostic_values
    from msg_adapters.pointcloud import read_points
    node = _node(world)
    markers = world.collect(Marker, "clusterfem/surface")
    clouds = world.collect(PointCloud2, "clusterfem/stress")
    diags = world.collect(DiagnosticArray, "/diagnostics")
    world.wait_for(lambda: len(markers) >= 3 and len(clouds) >= 3 and len(diags) >= 2, 20, "outputs")
    m = _last(markers, Marker)
    assert m.type == Marker.TRIANGLE_LIST and m.header.frame_id == "world" and m.ns == "clusterfem"
    pts = np.array([[p.x, p.y, p.z] for p in m.points])
    assert len(pts) % 3 == 0 and len(pts) > 0 and np.isfinite(pts).all()
    assert len(m.colors) == len(m.points)
    cloud = read_points(_last(clouds, PointCloud2))
    assert cloud.dtype.names[:4] == ("x", "y", "z", "von_mises")
    assert len(cloud) == node.scene.model.n_vertices and np.isfinite(cloud["von_mises"]).all()
    # the sphere sags under gravity: stress is not zero everywhere
    assert cloud["von_mises"].max() > 0
    values = diagnostic_values(_last(diags, DiagnosticArray))
    for key in ("step_ms", "real_time_factor", "substeps", "stability_margin", "energy_J", "volume_error",
                "inputs_rejected"):
        assert key in values
    assert values["steps"] > 0
    # the mesh's shape quality measured at set-up travels with every diagnostic
    quality = node.scene.model.quality
    assert values["tet_quality_worst"] == pytest.approx(quality.worst, rel=1e-6) and 0 < quality.worst <= 1
    assert values["tet_slivers"] == quality.slivers


def test_the_colour_table_is_made_before_the_first_marker_and_on_a_colour_map_change(world, monkeypatch):
    """Made on the first marker, the table's matplotlib import held the executor 0.2 s: joint states then came
    late, in a burst, and re-placed the body at the start of every run. The node makes it when it sets up its
    outputs, before any timer fires, and again when output.colormap changes."""
    from msg_adapters import colormap
    made = []
    real = colormap.colormap_lut
    monkeypatch.setattr(colormap, "colormap_lut", lambda name: made.append(name) or real(name))
    node = _node(world)
    assert made == ["turbo"]                                # before the world spun once
    assert node.set_parameters([Parameter("output.colormap", value="viridis")])[0].successful
    assert made[-1] == "viridis"


def test_nothing_is_computed_without_a_consumer(world, monkeypatch):
    from clusterfem_ros import sim_loop
    calls = []
    original = sim_loop.Snapshot.stress             # where every output's stress is made
    monkeypatch.setattr(sim_loop.Snapshot, "stress", lambda *a, **k: calls.append(1) or original(*a, **k))
    node = _node(world)
    world.wait_for(lambda: node.scene.steps_done > 50 and node.physics.snapshot is not None, 20, "physics steps")
    assert calls == [], "stress was computed with no subscriber and no recording"
    from visualization_msgs.msg import Marker
    markers = world.collect(Marker, "clusterfem/surface")          # a consumer: now it is computed
    world.wait_for(lambda: len(markers) >= 2, 20, "markers")
    assert calls


def test_invalid_parameter_updates_are_refused_with_reasons(world):
    node = _node(world)
    bad = [Parameter("output.colormap", value="rainbow"), Parameter("material.young_modulus", value=1e6),
           Parameter("output.marker_rate_hz", value=-3.0)]
    results = [node.set_parameters([p])[0] for p in bad]
    assert not any(r.successful for r in results)
    assert "choose one of turbo" in results[0].reason
    assert "restart the node" in results[1].reason
    ok = node.set_parameters([Parameter("output.stress_rate_hz", value=5.0)])[0]
    assert ok.successful and node.config["output.stress_rate_hz"] == 5.0


def test_invalid_values_at_start_are_refused_naming_the_value(world):
    from rclpy.exceptions import InvalidParameterValueException
    with pytest.raises((InvalidParameterValueException, ValueError), match="poisson_ratio"):
        _node(world, **{"material.poisson_ratio": 0.7})


def test_anchors_come_in_as_ros_parameters_and_hold_the_body(world):
    """List parameters with an empty default take doubles, strings and booleans from overrides or a file (rclpy
    would type an empty default as bytes and refuse them): a sphere anchored at its top cap hangs there."""
    from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
    x = paper_mesh("sphere").vertices
    cap = [float(x[:, 0].mean()), float(x[:, 1].mean()), float(x[:, 2].max())]
    node = _node(world, **{"anchors.points": cap, "anchors.bones": [""], "anchors.sliding": [False],
                           "anchors.radius": 0.05, "body.fix_bottom": False})
    assert node.config["anchors.points"] == cap and node.config["anchors.bones"] == [""]
    assert node.config["anchors.sliding"] == [False]
    held = np.array([a.vertex for a in node.scene.anchors])
    assert held.size > 10
    world.wait_for(lambda: node.scene.sim_time is not None and node.scene.sim_time - node.scene.start_time > 1.0,
                   30, "a second of physics")
    u = node.scene.state.u.copy()
    assert np.abs(u[held]).max() < 0.02 and u[:, 2].mean() < -1e-3     # hangs by the cap, sags below it


def test_the_default_scene_file_starts_the_node_with_its_empty_lists(world, tmp_path):
    """`clusterfem_node --ros-args --params-file config/default_scene.yaml` (the README's command): the file's
    empty lists (anchors.points: []) reach rclpy as parameters without a value; they are the empty lists they
    were written as, not a crash at start. Shown on the default file made a sphere scene (to build fast)."""
    import yaml
    from clusterfem_ros.config import default_scene_path
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    doc = yaml.safe_load(default_scene_path().read_text())
    params = doc["clusterfem"]["ros__parameters"]
    assert params["anchors.points"] == [] and params["anchors.bones"] == []
    params.update(SPHERE)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(doc))
    node = world.add(ClusterFemNode(context=world.context, cli_args=["--ros-args", "--params-file", str(path)]))
    assert node.config["anchors.points"] == [] and node.config["anchors.sliding"] == []
    assert node.scene is not None and node.scene.anchors == []


def _volume_error(node, snap):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64
    return serialize_message(Float64(data=node.scene.volume_error_of(node.scene.model.rest + snap.u)))


def decode_float64(data: bytes) -> float:
    """A std_msgs/Float64's CDR bytes (4-byte header, then the double) -> its value: the toy stream's decoder."""
    import struct
    return struct.unpack_from("<d", data, 4)[0]


def _toy_encoder():
    from std_msgs.msg import Float64

    from clusterfem_ros.nodes.outputs import Encoder
    return Encoder(Float64, _volume_error)


VOLUME_ERROR = None     # the toy stream's Encoder, made by the test (its message class needs ROS)


def test_an_output_stream_of_ones_own_is_published_recorded_and_read_back_by_being_declared(world, tmp_path):
    """A stream declared once (topics.declare_output: the volume error as a std_msgs/Float64 at the diagnostics'
    20 Hz, its encoder and decoder in this module) gets a publisher, a timer and a channel in the bag from that
    declaration alone, and the bag's reader decodes it; the node's own streams go on beside it."""
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64

    from clusterfem_ros import topics
    from clusterfem_ros.bag_frames import read_bag_frames
    from rosbags.highlevel import AnyReader
    global VOLUME_ERROR
    VOLUME_ERROR = _toy_encoder()
    declaration = topics.declare_output(topics.OutputDeclaration(
        topics.Topic("clusterfem/volume_error", "std_msgs/msg/Float64", "reliable"), "output.diagnostics_rate_hz",
        f"{__name__}:VOLUME_ERROR", f"{__name__}:decode_float64"))
    try:
        node = _node(world, **{"recording.enabled": True, "recording.dir": str(tmp_path)})
        got = world.collect(Float64, "clusterfem/volume_error")
        world.wait_for(lambda: len(got) >= 5, 20, "the declared stream's messages")
        errors = [deserialize_message(m, Float64).data for m in got]
        assert all(np.isfinite(errors)) and max(abs(e) for e in errors) < 0.5
        with pytest.raises(ValueError, match="taken"):
            topics.declare_output(declaration)
        node.close()
        with AnyReader([node.recording_path]) as bag:
            recorded = {c.topic: c for c in bag.connections}
            assert recorded["/clusterfem/volume_error"].msgtype == "std_msgs/msg/Float64"
            kept = [bag.deserialize(raw, c.msgtype).data
                    for c, _, raw in bag.messages(connections=[recorded["/clusterfem/volume_error"]])]
            assert len(kept) >= 5
            assert {"/clusterfem/surface", "/clusterfem/stress", "/diagnostics"} <= set(recorded)
        assert read_bag_frames(node.recording_path).streams["clusterfem/volume_error"] == kept
    finally:
        topics.OUTPUT_DECLARATIONS.unregister(declaration.topic.name)
