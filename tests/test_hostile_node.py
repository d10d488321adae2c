"""Hostile and careless participants on the node's ROS graph (issue 19), launch-free: garbage and absurd
joint states while recording, a disk that fills up under the recording, live parameter abuse, start-up
errors and the DDS default of a bare start."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from msg_adapters.joint_state import joint_state_cdr
from tests.test_hostile_inputs import full_disk_after
from tests.test_node_skeleton import SMALL_MAN, _points, world  # noqa: F401  (world: the fixture)
from tests.test_recording_signals import rosbags_count

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[1]


def _sim(world, **values):
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    return world.add(ClusterFemNode(context=world.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in {**SMALL_MAN, **values}.items()]))


class Sender:
    """Publishes raw bytes on joint_states and waits until the node counted what it was meant to."""

    def __init__(self, world, sim):
        from sensor_msgs.msg import JointState
        self.world, self.sim = world, sim
        self.node = world.node("hostile_publisher")
        self.pub = self.node.create_publisher(JointState, "joint_states", 10)
        self.names = sim.scene.skeleton.joint_names
        self.q0 = sim.scene.skeleton.neutral()
        world.wait_for(lambda: self.pub.get_subscription_count() > 0, 10, "joint_states matched")

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def cdr(self, q=None, v=None, names=None) -> bytes:
        return joint_state_cdr(self.names if names is None else names, self.q0 if q is None else q, v,
                               stamp=self.now_ns())

    def until(self, counted, make, what: str) -> None:
        """Send ``make()`` until ``counted()`` grows (best-effort transport)."""
        before = counted()
        for _ in range(5):
            self.pub.publish(make())
            try:
                self.world.wait_for(lambda: counted() > before, 4.0, what)
                return
            except AssertionError:
                continue
        raise AssertionError(f"{what} was never counted")

    def rejected(self, kind: str, make) -> None:
        self.until(lambda: self.sim.scene.inputs.rejected.get(kind, 0), make, kind)

    def good(self) -> None:
        self.until(lambda: self.sim.scene.inputs.accepted, self.cdr, "an accepted joint state")


def test_garbage_huge_and_absurd_joint_states_are_counted_never_recorded_and_never_kill_the_node(world, tmp_path):
    from visualization_msgs.msg import Marker
    sim = _sim(world, **{"recording.enabled": True, "recording.dir": str(tmp_path), "input.max_names": 30_000})
    markers = world.collect(Marker, "clusterfem/surface")
    s = Sender(world, sim)
    s.good()
    s.rejected("malformed", lambda: b"garbage!")                               # killed a recording node
    s.rejected("malformed", lambda: b"\x00\x01\x00\x00" + b"\xff" * 40)        # a valid CDR header
    s.rejected("too_many_names", lambda: s.cdr(names=[f"x{i}" for i in range(30_001)], q=np.zeros(30_001)))
    strangers = [f"stranger_{i}" for i in range(20_000)]
    s.rejected("unknown_joint", lambda: s.cdr(names=s.names + strangers,
                                              q=np.concatenate([s.q0, np.zeros(len(strangers))])))
    assert sim.scene.inputs.rejected["unknown_joint"] == 1                     # one report for 20,000 names
    far = s.q0.copy()
    far[s.names.index("root_x")] = 1e9
    s.rejected("root_range", lambda: s.cdr(q=far))
    s.rejected("joint_speed", lambda: s.cdr(v=np.full(len(s.names), 1e12)))
    s.good()
    n = len(markers)
    world.wait_for(lambda: len(markers) >= n + 5, 20, "markers after the hostile inputs")
    for raw in markers[n:]:
        pts = _points(raw)
        assert np.isfinite(pts).all() and np.abs(pts).max() < 10.0             # never at x = 1e9
    assert sim.divergences == 0 and sim.recorder is not None and not sim.recording_error
    world.executor.shutdown(timeout_sec=5.0)
    recorded = sim.counts["joint_states"]
    sim.close()
    counts = rosbags_count(sim.recording_path)                                 # every record decodes
    assert counts["/joint_states"] == recorded
    from clusterfem_ros.recording.bag_reader import read_joint_states
    samples = read_joint_states(sim.recording_path)
    assert len(samples) == recorded and max(len(x.names) for x in samples) <= 30_000
    assert sim.received >= recorded + 3       # garbage, headed garbage and the oversized one were not recorded



def _bag_joint_states(folder) -> list[tuple[int, np.ndarray, np.ndarray, list]]:
    """(stamp ns, exact as sent; positions; velocities; names) of every recorded joint state."""
    from rosbags.highlevel import AnyReader
    out = []
    with AnyReader([Path(folder)]) as r:
        for c, _, raw in r.messages(connections=[c for c in r.connections if c.topic == "/joint_states"]):
            m = r.deserialize(raw, c.msgtype)
            out.append((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, np.asarray(m.position),
                        np.asarray(m.velocity), list(m.name)))
    return out


def test_refused_joint_states_are_counted_never_recorded_and_the_bag_replays_bit_for_bit(world, tmp_path):
    """The README's promise on a running node: samples that decode and name the skeleton's joints but that the
    joint stream refuses (a root 1e9 m away, a reported velocity of 1e12, a knee turning 3 rad in 1 ms,
    stale, future and out-of-order stamps) are counted per kind on /diagnostics and none reaches the bag; what
    the bag keeps (the samples taken in) replays every recorded surface bit for bit."""
    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.recording.bag_reader import PARAMS_FILE, read_joint_states, read_surfaces
    from clusterfem_ros.replay import main as replay_main
    from clusterfem_ros.replay import replay
    from clusterfem_ros.scene import Scene
    from msg_adapters.diagnostics import diagnostic_values
    sim = _sim(world, **{"recording.enabled": True, "recording.dir": str(tmp_path), "physics.clock": "input",
                         "warping": True, "output.diagnostics_rate_hz": 10.0})
    s = Sender(world, sim)
    walk = load_motion().trajectory
    names, t0 = walk.names, s.now_ns()
    sent_refused: list[int] = []
    last_good = [t0]

    def pose(stamp_ns):
        return walk.sample((stamp_ns - t0) * 1e-9, loop=True)[0]

    def good(n):
        for _ in range(n):
            last_good[0] = stamp = s.now_ns()
            s.pub.publish(joint_state_cdr(names, pose(stamp), stamp=stamp))
            time.sleep(0.01)

    def refused(offset_s=0.0, change=lambda q: q, v=None, after_good=False):
        """Stamped now + offset_s, or offset_s after the last good sample (after_good)."""
        def make():
            stamp = (last_good[0] if after_good else s.now_ns()) + int(offset_s * 1e9)
            sent_refused.append(stamp)
            return joint_state_cdr(names, change(pose(stamp).copy()), v, stamp=stamp)
        return make

    def set_to(k, value):
        def change(q):
            q[k] = value
            return q
        return change

    knee = names.index("l_knee_pitch")                    # a joint the walk moves in every frame
    good(60)
    world.wait_for(lambda: sim.scene.inputs.accepted >= 20, 20, "good samples")
    s.rejected("root_range", refused(change=set_to(names.index("root_x"), 1e9)))
    good(10)
    s.rejected("joint_speed", refused(v=np.full(len(names), 1e12)))
    good(10)
    s.rejected("joint_speed", refused(0.001, change=lambda q: q + 3.0 * (np.arange(len(q)) == knee),
                                      after_good=True))              # 3 rad in 1 ms
    good(3)                             # between time refusals: three in a row would restart the stream on them
    s.rejected("stale", refused(offset_s=-100.0))
    good(3)
    s.rejected("future", refused(offset_s=+100.0))
    good(3)
    s.rejected("out_of_order", refused(-0.005, after_good=True))
    good(60)
    world.wait_for(lambda: sim.counts.get("clusterfem/surface", 0) >= 15 and sim.counts.get("/diagnostics", 0) >= 3,
                   40, "recorded surfaces and diagnostics")
    rejected = dict(sim.scene.inputs.rejected)
    time.sleep(0.3)                                   # a diagnostics message carrying the last counts
    world.executor.shutdown(timeout_sec=5.0)
    sim.close()
    bag = sim.recording_path
    recorded = _bag_joint_states(bag)
    assert len(recorded) == sim.counts["joint_states"] >= 60
    assert not set(sent_refused) & {stamp for stamp, *_ in recorded}, "a refused joint state was recorded"
    stamps = [stamp for stamp, *_ in recorded]
    assert stamps == sorted(set(stamps))                               # no stale or out-of-order stamp
    assert max(np.abs(q[names.index("root_x")]).max() for _, q, _, n in recorded if n == names) < 1000.0
    assert max((np.abs(v).max() for _, _, v, _ in recorded if v.size), default=0.0) <= 300.0
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(bag)]) as r:
        last = [r.deserialize(raw, c.msgtype) for c, _, raw in
                r.messages(connections=[c for c in r.connections if c.topic == "/diagnostics"])][-1]
    values = {kv.key: kv.value for kv in last.status[0].values}
    for kind in ("root_range", "joint_speed", "stale", "future", "out_of_order"):
        assert int(values[f"rejected_{kind}"]) >= 1 and rejected[kind] >= 1, (kind, values)
    surfaces = read_surfaces(bag)
    got = replay(Scene.build(load_scene_file(bag / PARAMS_FILE)), read_joint_states(bag), [t for t, _ in surfaces])
    assert len(surfaces) >= 15 and all(t in got for t, _ in surfaces)
    assert all(np.array_equal(got[t], p) for t, p in surfaces), "the replay differs from the recording"
    assert np.abs(surfaces[-1][1] - surfaces[0][1]).max() > 0.1        # the body walked: not one picture
    assert replay_main([str(bag)]) == 0


def _bag_raw(folder, topic: str) -> list[bytes]:
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(folder)]) as r:
        return [raw for _, _, raw in r.messages(connections=[c for c in r.connections if c.topic == topic])]


def test_a_state_not_finite_without_its_volume_or_off_its_bones_reaches_no_topic_and_no_bag(world, tmp_path):
    """The output gate on a running, recording node: after three joint states the scene's state is replaced by
    one that is not finite, one shrunk to 0.3 % of its volume and one with a surface vertex 5 m from its bone
    (what a diverging step leaves). Each is handed over to the outputs and refused there: no Marker or stress
    cloud on the topics or in the bag shows it, the refusals are counted, and the body goes on walking."""
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import Marker

    from clusterfem_ros.motion import load_motion
    from msg_adapters.pointcloud import read_points
    sim = _sim(world, **{"recording.enabled": True, "recording.dir": str(tmp_path), "physics.clock": "input",
                         "output.marker_rate_hz": 60.0, "output.stress_rate_hz": 30.0})
    markers = world.collect(Marker, "clusterfem/surface")
    clouds = world.collect(PointCloud2, "clusterfem/stress")
    scene = sim.scene
    i = int(scene.surface_vertices[0])

    def not_finite(u):
        u[3, 1] = np.nan

    def shrunk(u):                                       # every vertex 85 % of the way to the centroid
        x = scene.model.rest + u
        u[:] = x.mean(axis=0) + 0.15 * (x - x.mean(axis=0)) - scene.model.rest

    def torn(u):
        u[i, 2] += 5.0
    corruptions = {40: not_finite, 100: shrunk, 160: torn}
    problems, taken = [], [0]
    real_take = scene.take_joint_state

    def take(*args, **kwargs):                           # on the physics thread: right before its hand-over
        out = real_take(*args, **kwargs)
        taken[0] += 1
        corrupt = corruptions.get(taken[0])
        if corrupt is not None:
            corrupt(scene.state.u)
            problems.append(scene.problem_of(scene.state.u, scene.state.v, scene._poses(scene.sim_time)))
        return out
    scene.take_joint_state = take
    s = Sender(world, sim)
    walk = load_motion().trajectory
    t0 = s.now_ns()
    for _ in range(260):
        stamp = s.now_ns()
        s.pub.publish(joint_state_cdr(walk.names, walk.sample((stamp - t0) * 1e-9, loop=True)[0], stamp=stamp))
        time.sleep(0.01)
    world.wait_for(lambda: taken[0] >= 200 and len(problems) == 3, 30, "the three corrupted states")
    n = len(markers)
    world.wait_for(lambda: len(markers) >= n + 3, 20, "markers after them")
    world.executor.shutdown(timeout_sec=5.0)
    sim.close()
    assert "not finite" in problems[0] and "volume is off" in problems[1] and f"surface vertex {i} is" in problems[2]
    assert sim.physics.refused >= 3 and sim.diagnostics()["outputs_withheld"] >= 3
    bag_markers, bag_clouds = _bag_raw(sim.recording_path, "/clusterfem/surface"), _bag_raw(sim.recording_path,
                                                                                        "/clusterfem/stress")
    assert len(bag_markers) >= 20 and len(bag_clouds) >= 10 and len(markers) >= 20 and len(clouds) >= 10
    for raw in markers + bag_markers:
        x = _points(raw)
        assert np.isfinite(x).all()
        assert np.linalg.norm(x - np.median(x, axis=0), axis=1).max() < 2.5          # no vertex 5 m out
        assert np.ptp(x[:, 2]) > 1.0                                                 # standing, not shrunk
    for raw in clouds + bag_clouds:
        c = read_points(deserialize_message(raw, PointCloud2))
        x = np.column_stack([c["x"], c["y"], c["z"]])
        assert np.isfinite(x).all() and np.isfinite(c["von_mises"]).all()
        assert np.linalg.norm(x - np.median(x, axis=0), axis=1).max() < 2.5 and np.ptp(x[:, 2]) > 1.0

def test_a_full_disk_stops_recording_with_an_error_and_the_simulation_goes_on(world, tmp_path, monkeypatch):
    from diagnostic_msgs.msg import DiagnosticArray
    from visualization_msgs.msg import Marker

    from msg_adapters.diagnostics import diagnostic_values
    full_disk_after(monkeypatch, 150_000)
    sim = _sim(world, **{"recording.enabled": True, "recording.dir": str(tmp_path)})
    markers = world.collect(Marker, "clusterfem/surface")
    diags = world.collect(DiagnosticArray, "/diagnostics")
    s = Sender(world, sim)
    s.good()
    world.wait_for(lambda: sim.recording_error != "", 60, "the disk to fill up")
    assert "No space left on device" in sim.recording_error and sim.recorder is None
    n, d = len(markers), len(diags)
    world.wait_for(lambda: len(markers) >= n + 10 and len(diags) >= d + 2, 30, "outputs after the failure")
    status = deserialize_message(diags[-1], DiagnosticArray).status[0]
    values = diagnostic_values(deserialize_message(diags[-1], DiagnosticArray))
    assert status.level == b"\x02" and values["recording"] == "stopped"
    assert "No space left" in values["recording_error"]
    s.good()                                                                    # inputs still taken
    monkeypatch.undo()
    world.executor.shutdown(timeout_sec=5.0)
    sim.close()
    from clusterfem_ros.recording.recover import recover_bag
    report = recover_bag(sim.recording_path)
    assert report.messages > 0 and sum(rosbags_count(sim.recording_path).values()) == report.messages


def test_live_parameters_are_bounded(world):
    sim = _sim(world)
    bad = {"output.diagnostics_rate_hz": 0.0, "output.marker_rate_hz": 1000.0, "output.stress_rate_hz": 500.0,
           "output.frame_id": "x" * 1_000_000}
    for name, value in bad.items():
        (result,) = sim.set_parameters([Parameter(name, value=value)])
        assert not result.successful, name
        assert name in result.reason and ("a running node takes" in result.reason or "at most 256" in result.reason)
    assert sim.config["output.diagnostics_rate_hz"] == 5.0 and sim.config["output.frame_id"] == "world"
    ok = [Parameter("output.marker_rate_hz", value=30.0), Parameter("output.frame_id", value="map")]
    assert all(r.successful for r in sim.set_parameters(ok))
    assert sim.config["output.marker_rate_hz"] == 30.0 and sim.config["output.frame_id"] == "map"


def _start(args: list[str], tmp_path: Path, **env) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k != "FASTDDS_BUILTIN_TRANSPORTS"}
    environ.update(PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(150 + os.getpid() % 40), **env)
    return subprocess.run([sys.executable, "-m", "clusterfem_ros.nodes.clusterfem_node", *args], cwd=tmp_path,
                          env=environ, capture_output=True, text=True, timeout=300)


def test_start_up_errors_are_one_line_and_exit_2_with_the_traceback_on_debug(tmp_path):
    params = tmp_path / "scene.yaml"
    params.write_text("clusterfem:\n  ros__parameters:\n    material:\n      youngs_modulus: 1.0e5\n")
    run = _start(["--ros-args", "--params-file", str(params)], tmp_path)
    assert run.returncode == 2, run.stderr
    lines = [x for x in run.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert "unknown scene parameter 'material.youngs_modulus': did you mean 'material.young_modulus'?" in lines[0]
    run = _start(["--ros-args", "-p", "physics.step:=5.0"], tmp_path)
    assert run.returncode == 2 and "physics.step" in run.stderr and "Traceback" not in run.stderr, run.stderr
    for text in ("just a string\n", "clusterfem:\n  youngs_modulus: 3\n"):
        params.write_text(text)
        run = _start(["--ros-args", "--params-file", str(params)], tmp_path)
        assert run.returncode == 2 and "ros__parameters" in run.stderr and "Traceback" not in run.stderr, run.stderr
    run = _start(["--ros-args", "--params-file", str(tmp_path / "missing.yaml")], tmp_path)
    assert run.returncode == 2 and "missing.yaml" in run.stderr and "Traceback" not in run.stderr, run.stderr
    run = _start(["--debug", "--ros-args", "-p", "physics.step:=5.0"], tmp_path)
    assert run.returncode != 0 and "Traceback" in run.stderr and "physics.step" in run.stderr


def test_a_bare_start_keeps_dds_discovery_on_this_host_unless_told_otherwise():
    from clusterfem_ros.nodes.spinning import default_discovery
    env: dict = {}
    note = default_discovery(env)
    assert env == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"} and "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET" in note
    for chosen in ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, {"FASTDDS_BUILTIN_TRANSPORTS": "SHM"},
                   {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml"}, {"ROS_DISCOVERY_SERVER": "127.0.0.1:11811"}):
        env = dict(chosen)
        assert default_discovery(env) is None and env == chosen
    env = {"ROS_STATIC_PEERS": "192.0.2.7"}              # static peers add to the range: LOCALHOST keeps them
    assert default_discovery(env) and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_a_bare_node_says_its_discovery_stays_on_this_host_and_how_to_reach_a_network(tmp_path):
    """Started without scripts/env.sh (no DDS variable set), as a console script would be; what it then sends where
    is measured by tests/test_dds_default_tools.py (and docs/usage.md, Network)."""
    environ = {k: v for k, v in os.environ.items() if k not in ("FASTDDS_BUILTIN_TRANSPORTS", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    environ.update(PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(190 + os.getpid() % 10))
    proc = subprocess.Popen([sys.executable, "-m", "clusterfem_ros.nodes.clusterfem_node", "--ros-args",
                             "-p", "body.kind:=sphere", "-p", "skeleton.source:=none"],
                            cwd=tmp_path, env=environ, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "DDS: discovery on this host only" in line:
                break
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in lines[-1], "".join(lines)
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET" in lines[-1], "".join(lines)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
