"""The node driven by a skeleton, launch-free: player -> node -> markers; bad inputs; recording; replay."""
import math

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from clusterfem_ros.nodes.testing import RosWorld
from tests.shared_data import walk_clip

pytestmark = pytest.mark.ros

SMALL_MAN = {"body.kind": "jelly_man", "body.target_tets": 700, "skeleton.source": "builtin", "warping": False,
             "output.marker_rate_hz": 20.0, "output.stress_rate_hz": 10.0, "output.diagnostics_rate_hz": 5.0}


@pytest.fixture
def world():
    with RosWorld() as w:
        yield w


def _params(values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _sim(world, **values):
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    return world.add(ClusterFemNode(context=world.context, parameter_overrides=_params({**SMALL_MAN, **values})))


def _player(world, **values):
    from clusterfem_ros.nodes.player_node import MocapPlayer
    return world.add(MocapPlayer(context=world.context, parameter_overrides=_params({"rate_hz": 100.0, **values})))


def _points(raw):
    from visualization_msgs.msg import Marker
    m = deserialize_message(raw, Marker)
    return np.array([[p.x, p.y, p.z] for p in m.points])


def test_markers_arrive_and_deform_as_the_skeleton_walks(world):
    from visualization_msgs.msg import Marker
    sim = _sim(world)
    markers = world.collect(Marker, "clusterfem/surface")
    _player(world)
    world.wait_for(lambda: sim.scene.inputs.accepted > 5 and len(markers) > 0, 30, "first joint states and marker")
    n0 = len(markers)
    world.wait_for(lambda: len(markers) >= n0 + 20, 30, "20 more markers")
    first, last = _points(markers[n0]), _points(markers[-1])
    assert first.shape == last.shape and np.isfinite(last).all()
    # the body walks along +x ...
    assert last[:, 0].mean() - first[:, 0].mean() > 0.3
    # ... and deforms: distances between points change (a rigid motion keeps them)
    idx = np.random.default_rng(0).choice(len(first), 200, replace=False)
    d0 = np.linalg.norm(first[idx, None] - first[None, idx], axis=-1)
    d1 = np.linalg.norm(last[idx, None] - last[None, idx], axis=-1)
    assert np.abs(d1 - d0).max() > 0.05
    assert sim.scene.inputs.total_rejected == 0


def test_every_bad_input_is_counted_and_outputs_stay_finite(world):
    from sensor_msgs.msg import JointState
    from visualization_msgs.msg import Marker
    sim = _sim(world)
    markers = world.collect(Marker, "clusterfem/surface")
    pub_node = world.node("bad_publisher")
    pub = pub_node.create_publisher(JointState, "joint_states", 10)
    names = sim.scene.skeleton.joint_names
    q0 = sim.scene.skeleton.neutral()
    clock = pub_node.get_clock()

    def now_ns(offset_s=0.0):
        return clock.now().nanoseconds + int(offset_s * 1e9)

    def arrays_to_joint_state(names, q, stamp):      # by hand: the adapter refuses what we want to send
        m = JointState(name=list(names), position=[float(x) for x in q])
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        return m

    def good():
        pub.publish(arrays_to_joint_state(names, q0, stamp=now_ns()))

    def send(msg):
        pub.publish(msg)

    def after(kind, fn, timeout=10.0):
        before = sim.scene.inputs.rejected.get(kind, 0)
        for _ in range(3):                       # best-effort transport: send until it is counted
            fn()
            try:
                world.wait_for(lambda: sim.scene.inputs.rejected.get(kind, 0) > before, timeout / 3, kind)
                return
            except AssertionError:
                continue
        raise AssertionError(f"{kind} was never counted")

    world.wait_for(lambda: sim._pubs["clusterfem/surface"].get_subscription_count() > 0, 10, "probe matched")
    for _ in range(5):
        good()
    world.wait_for(lambda: sim.scene.inputs.accepted >= 3, 10, "good samples")
    nan_q = q0.copy()
    nan_q[3] = math.nan
    after("non_finite", lambda: send(arrays_to_joint_state(names, nan_q, stamp=now_ns())))
    m = JointState(name=names[:3], position=[0.0, 0.1])
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(now_ns(), 1_000_000_000)
    after("length_mismatch", lambda: send(m))
    after("no_known_joint", lambda: send(arrays_to_joint_state(["no_such_joint"], np.zeros(1), stamp=now_ns())))
    after("stale", lambda: send(arrays_to_joint_state(names, q0, stamp=now_ns(-100.0))))
    after("future", lambda: send(arrays_to_joint_state(names, q0, stamp=now_ns(+100.0))))
    good()
    jump = q0.copy()
    jump[names.index("root_x")] += 5.0
    after("teleport", lambda: send(arrays_to_joint_state(names, jump, stamp=now_ns())))
    n = len(markers)
    world.wait_for(lambda: len(markers) >= n + 5, 20, "markers after the bad inputs")
    for raw in markers[n:]:
        assert np.isfinite(_points(raw)).all()
    # the teleport put the body onto the skeleton 5 m on, without a divergence
    assert _points(markers[-1])[:, 0].mean() > 4.0
    assert sim.divergences == 0
    d = sim.diagnostics()
    assert d["inputs_rejected"] >= 5 and all(np.isfinite(v) for v in d.values() if isinstance(v, float))


def test_recording_opens_in_rosbags_with_the_published_counts(world, tmp_path):
    from rosbags.highlevel import AnyReader
    sim = _sim(world, **{"recording.enabled": True, "recording.dir": str(tmp_path)})
    _player(world)
    world.wait_for(lambda: sim.counts.get("clusterfem/surface", 0) >= 10 and sim.counts.get("/diagnostics", 0) >= 2,
                   40, "recorded outputs")
    world.executor.shutdown(timeout_sec=5.0)
    counts = dict(sim.counts)
    sim.close()
    with AnyReader([sim.recording_path]) as r:
        got = {}
        for c, _, raw in r.messages():
            msg = r.deserialize(raw, c.msgtype)              # with the bag's own schemas
            assert msg is not None
            got[c.topic] = got.get(c.topic, 0) + 1
    assert got == {"/joint_states": counts["joint_states"], "/clusterfem/surface": counts["clusterfem/surface"],
                   "/clusterfem/stress": counts["clusterfem/stress"], "/diagnostics": counts["/diagnostics"]}


def test_replaying_the_recorded_joint_states_reproduces_the_recorded_surfaces(world, tmp_path):
    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.recording.bag_reader import PARAMS_FILE, read_joint_states, read_surfaces
    from clusterfem_ros.replay import replay
    from clusterfem_ros.scene import Scene
    sim = _sim(world, **{"recording.enabled": True, "recording.dir": str(tmp_path), "physics.clock": "input",
                         "warping": True})
    _player(world)
    world.wait_for(lambda: sim.counts.get("clusterfem/surface", 0) >= 15, 40, "recorded surfaces")
    world.executor.shutdown(timeout_sec=5.0)
    sim.close()
    bag = sim.recording_path
    surfaces = read_surfaces(bag)
    got = replay(Scene.build(load_scene_file(bag / PARAMS_FILE)), read_joint_states(bag), [t for t, _ in surfaces])
    assert len(surfaces) >= 10 and all(t in got for t, _ in surfaces)      # the replay passes every recorded time
    matched = [(got[t], p) for t, p in surfaces]
    assert all(np.array_equal(a, b) for a, b in matched), "the replay differs from the recording"   # bit for bit
    moved = np.abs(matched[-1][1] - matched[0][1]).max()
    assert moved > 0.1                         # the compared surfaces are not all the same picture


def test_bvh_player_latches_its_urdf_and_the_node_builds_a_jelly_body_on_it(world):
    from visualization_msgs.msg import Marker
    walk = walk_clip()
    markers = world.collect(Marker, "clusterfem/surface")
    player = _player(world, source="bvh", file=str(walk))
    sim = _sim(world, **{"skeleton.source": "robot_description", "body.bone_radius": 0.04})
    world.wait_for(lambda: sim.scene is not None, 60, "the scene built from robot_description")
    assert sorted(sim.scene.skeleton.joint_names) == sorted(player.names)      # mapped by name, any order
    world.wait_for(lambda: sim.scene.inputs.accepted > 20 and len(markers) > 5, 30, "joint states and markers")
    assert np.isfinite(_points(markers[-1])).all()
    assert sim.scene.inputs.rejected.get("unknown_joint", 0) == 0


def test_a_recording_on_a_latched_skeleton_carries_it_and_the_renderer_poses_it(world, tmp_path):
    walk = walk_clip()
    from clusterfem_ros.bag_frames import read_bag_frames
    from clusterfem_ros.motion import load_motion
    _player(world, source="bvh", file=str(walk))
    sim = _sim(world, **{"skeleton.source": "robot_description", "body.bone_radius": 0.04, "recording.enabled": True,
                         "recording.dir": str(tmp_path)})
    world.wait_for(lambda: sim.counts.get("clusterfem/surface", 0) >= 3, 60, "markers on the BVH's skeleton")
    world.executor.shutdown(timeout_sec=5.0)
    assert sim.counts["robot_description"] == 1
    sim.close()
    frames = read_bag_frames(sim.recording_path)
    assert frames.urdf == load_motion("bvh", walk).urdf          # the latched text, byte for byte


def test_keyframe_player_drives_the_builtin_humanoid(world):
    from clusterfem_ros.skeleton.keyframes import example_path
    sim = _sim(world)
    player = _player(world, source="keyframes", file=str(example_path("wave.yaml")))
    world.wait_for(lambda: sim.scene.inputs.accepted > 20, 30, "key-frame joint states")
    assert set(player.names) <= set(sim.scene.skeleton.joint_names)
    assert sim.scene.inputs.total_rejected == 0


def test_nothing_is_published_before_the_first_joint_state_places_the_body(world):
    """Wall clock: physics runs before any joint state, with the body at the skeleton's neutral pose (a clip's
    root may be metres away). No marker or stress cloud leaves the node until a sample has placed the body;
    the withheld outputs are counted on diagnostics."""
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import Marker
    sim = _sim(world)
    markers = world.collect(Marker, "clusterfem/surface")
    clouds = world.collect(PointCloud2, "clusterfem/stress")
    world.wait_for(lambda: sim.withheld >= 10 and sim.scene.steps_done > 100, 30, "outputs withheld while unplaced")
    assert markers == [] and clouds == [] and not sim.scene.placed
    assert sim.diagnostics()["outputs_withheld"] >= 10 and sim.divergences == 0
    _player(world)
    world.wait_for(lambda: len(markers) > 0 and len(clouds) > 0, 30, "outputs after the first joint state")
    assert sim.scene.placed and sim.divergences == 0
