"""Bags written by Rosbag2McapWriter open in rosbags (with the bag's own schemas), mcap and mcap_ros2."""
from __future__ import annotations

import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from clusterfem_ros.recording import Rosbag2McapWriter, default_bag_path
from msg_adapters.colormap import map_scalars
from msg_adapters.diagnostics import diagnostic_array
from msg_adapters.joint_state import joint_state_cdr
from msg_adapters.marker import surface_marker, surface_marker_cdr
from msg_adapters.pointcloud import stress_cloud_cdr

T0 = 1_700_000_000_000_000_000
TOPICS = {"/joint_states": ("sensor_msgs/msg/JointState", "sensor_data"),
          "/surface": ("visualization_msgs/msg/Marker", "reliable"),
          "/stress": ("sensor_msgs/msg/PointCloud2", "reliable"),
          "/diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", "reliable"),
          "/robot_description_dummy": ("std_msgs/msg/String", "transient_local")}
N_STEPS = 20


def read_with_own_schemas(folder: Path) -> tuple[dict[str, list], Reader]:
    """Every message decoded by rosbags with types registered from the bag's msgdefs only."""
    store = get_typestore(Stores.EMPTY)
    out: dict[str, list] = {}
    with Reader(folder) as reader:
        for conn in reader.connections:
            assert conn.msgdef.format.name == "MSG"
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, store.deserialize_cdr(raw, conn.msgtype)))
        return out, reader


def write_sample_bag(folder: Path, **kw) -> None:
    rng = np.random.default_rng(3)
    v, tri = rng.normal(size=(30, 3)), rng.integers(0, 30, size=(40, 3))
    with Rosbag2McapWriter(folder, **kw) as w:
        for topic, (msg_type, qos) in TOPICS.items():
            w.add_topic(topic, msg_type, qos)
        for i in range(N_STEPS):
            t = T0 + i * 10_000_000
            vel = np.full(3, float(i)) if i % 2 else None  # alternately with and without velocities
            w.write("/joint_states", t, joint_state_cdr(["a", "b", "c"], np.arange(3.0) + i, vel, t))
            rgba = map_scalars(rng.random(30), "viridis", 0, 1)
            cdr = surface_marker_cdr(v + i, tri, rgba, "world", t, "body", 0) if i % 2 else \
                serialize_message(surface_marker(v + i, tri, rgba, "world", t, "body", 0))
            w.write("/surface", t + 1, cdr)
            w.write("/stress", t + 2, stress_cloud_cdr(v, rng.random(30), "world", t, {"s1": rng.random(30)}))
            w.write("/diagnostics", t + 3, serialize_message(diagnostic_array(t, "clusterfem", "sim", {"step": i})),
                    publish_time_ns=t)
        w.write("/robot_description_dummy", T0, b"\x00\x01\x00\x00\x06\x00\x00\x00<urdf\x00")


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bags") / "sample"
    write_sample_bag(folder)
    return folder


def test_folder_layout_and_metadata_yaml(bag):
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "sample_0.mcap"]
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert (info["version"], info["storage_identifier"], info["ros_distro"]) == (9, "mcap", "jazzy")
    assert info["relative_file_paths"] == ["sample_0.mcap"] and info["files"][0]["path"] == "sample_0.mcap"
    assert info["message_count"] == 4 * N_STEPS + 1
    assert info["starting_time"]["nanoseconds_since_epoch"] == T0
    assert info["duration"]["nanoseconds"] == (N_STEPS - 1) * 10_000_000 + 3
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert topics["/surface"]["message_count"] == N_STEPS
    assert re.fullmatch(r"RIHS01_[0-9a-f]{64}", topics["/stress"]["topic_metadata"]["type_description_hash"])
    qos = topics["/robot_description_dummy"]["topic_metadata"]["offered_qos_profiles"][0]
    assert (qos["durability"], qos["reliability"]) == ("transient_local", "reliable")


def test_rosbags_decodes_every_message_with_the_bags_own_schemas(bag):
    msgs, reader = read_with_own_schemas(bag)
    assert {k: len(v) for k, v in msgs.items()} == {"/joint_states": N_STEPS, "/surface": N_STEPS, "/stress": N_STEPS,
                                                    "/diagnostics": N_STEPS, "/robot_description_dummy": 1}
    for i, (t, js) in enumerate(msgs["/joint_states"]):
        assert t == T0 + i * 10_000_000 and list(js.name) == ["a", "b", "c"]
        np.testing.assert_array_equal(js.position, np.arange(3.0) + i)
        assert len(js.velocity) == (3 if i % 2 else 0)
    marker = msgs["/surface"][-1][1]
    assert marker.type == 11 and len(marker.points) == 120 and len(marker.colors) == 120
    cloud = msgs["/stress"][0][1]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "von_mises", "s1"] and cloud.width == 30
    assert msgs["/diagnostics"][5][1].status[0].values[0].value == "5"
    assert msgs["/robot_description_dummy"][0][1].data == "<urdf"


def test_mcap_reader_sees_summary_statistics_chunk_indexes_and_rosbag2_metadata(bag):
    with open(bag / "sample_0.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == 4 * N_STEPS + 1
        assert summary.statistics.channel_count == len(TOPICS) and len(summary.chunk_indexes) >= 1
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert {s.name: s.encoding for s in summary.schemas.values()}["sensor_msgs/msg/JointState"] == "ros2msg"
        marker_schema = next(s for s in summary.schemas.values() if s.name == "visualization_msgs/msg/Marker")
        text = marker_schema.data.decode()
        assert text.count("=" * 80 + "\nMSG: std_msgs/Header\n") == 1 and "MSG: visualization_msgs/MeshFile" in text
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr" and set(ch.metadata) == {"offered_qos_profiles", "topic_type_hash"}
        meta = list(reader.iter_metadata())
        assert [m.name for m in meta] == ["rosbag2"]
        assert yaml.safe_load(meta[0].metadata["serialized_metadata"])["message_count"] == 4 * N_STEPS + 1
    with open(bag / "sample_0.mcap", "rb") as f:  # mcap_ros2's own decoder accepts the schemas too
        n = sum(1 for _ in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    assert n == 4 * N_STEPS + 1


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_chunk_compressions_open_in_rosbags(tmp_path, compression):
    write_sample_bag(tmp_path / "c", compression=compression, chunk_size=4096)
    msgs, _ = read_with_own_schemas(tmp_path / "c")
    assert sum(len(v) for v in msgs.values()) == 4 * N_STEPS + 1


def test_writer_api_errors_and_idempotent_close(tmp_path):
    w = Rosbag2McapWriter(tmp_path / "b")
    assert w.add_topic("/js", "sensor_msgs/JointState") == w.add_topic("/js", "sensor_msgs/msg/JointState")
    with pytest.raises(ValueError, match="already added"):
        w.add_topic("/js", "std_msgs/msg/String")
    with pytest.raises(ValueError, match="add_topic"):
        w.write("/nope", T0, b"\x00\x01\x00\x00")
    with pytest.raises(ValueError, match="not CDR"):
        w.write("/js", T0, b"hello")
    with pytest.raises(ValueError, match="qos|QoS"):
        w.add_topic("/x", "std_msgs/msg/String", qos="fast")
    with pytest.raises(FileNotFoundError, match="no nope_msgs/msg/Foo.msg"):
        w.add_topic("/y", "nope_msgs/msg/Foo")
    assert w.close() is True and w.close() is True and w.closed
    with pytest.raises(RuntimeError, match="closed"):
        w.write("/js", T0, joint_state_cdr([], np.zeros(0)))
    with pytest.raises(FileExistsError, match="not empty"):
        Rosbag2McapWriter(tmp_path / "b")
    _, reader = read_with_own_schemas(tmp_path / "b")  # an empty bag still opens


def test_an_idle_writer_wakes_only_at_its_drain_interval_and_a_flush_does_not_wait_for_it(tmp_path):
    """The I/O thread sleeps between drains (each wake takes the GIL from the physics thread) and wakes at once
    for a flush: an idle second costs about 1 / DRAIN_INTERVAL_S wakes, and the message flushed is in the
    bag."""
    from clusterfem_ros.recording import rosbag2_mcap
    w = Rosbag2McapWriter(tmp_path / "b")
    w.add_topic("/js", "sensor_msgs/msg/JointState")
    wakes = []
    wait = w._wake.wait
    w._wake.wait = lambda timeout=None: (wakes.append(timeout), wait(timeout))[1]
    w.flush()                                           # the topic is in; count from here
    wakes.clear()
    t0 = time.monotonic()
    time.sleep(0.5)
    idle = len(wakes) / (time.monotonic() - t0)
    assert idle <= 1.5 / rosbag2_mcap.DRAIN_INTERVAL_S, f"{idle:.0f} wakes per second while idle"
    w.write("/js", T0, joint_state_cdr(["a"], np.zeros(1)))
    w.flush()
    assert w.close()
    msgs, _ = read_with_own_schemas(tmp_path / "b")
    assert sum(len(v) for v in msgs.values()) == 1


class _Stop(Exception):
    pass


def test_close_from_a_signal_handler_that_raises_mid_write_leaves_a_consistent_bag(tmp_path):
    """A real signal (SIGALRM, 2 ms) lands anywhere in a tight write loop; its handler closes the
    writer and raises. No deadlock, and every queued message is in the bag, summary and yaml."""
    w = Rosbag2McapWriter(tmp_path / "b")
    w.add_topic("/js", "sensor_msgs/msg/JointState")
    cdr = joint_state_cdr(["a"], np.ones(1))

    def handler(signum, frame):
        w.close()
        raise _Stop

    accepted = 0
    old = signal.signal(signal.SIGALRM, handler)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        while True:
            w.write("/js", T0 + accepted, cdr)
            accepted += 1
    except _Stop:
        pass
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert w.closed and w.close() is True
    msgs, reader = read_with_own_schemas(tmp_path / "b")
    assert len(msgs["/js"]) in (accepted, accepted + 1)  # +1: interrupted after the enqueue
    info = yaml.safe_load((tmp_path / "b" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == len(msgs["/js"]) > 100


def test_default_bag_path(tmp_path):
    p = default_bag_path("clusterfem", root=tmp_path)
    assert p.parent == tmp_path and re.fullmatch(r"clusterfem_\d{8}_\d{6}", p.name)
    p.mkdir()
    q = default_bag_path("clusterfem", root=tmp_path)
    assert q != p and not q.exists()  # same second: p.name + "_1"; else a later timestamp
    with pytest.raises(ValueError, match="prefix"):
        default_bag_path("a/b")


def test_recording_layer_imports_no_rclpy_and_no_msgs():
    import subprocess
    import sys
    code = ("import sys, clusterfem_ros.recording; "
            "bad = [m for m in sys.modules if m.split('.')[0] == 'rclpy' or m.split('.')[0].endswith('_msgs')]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[1])


SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample_default_scene"


def test_the_sample_recording_replays_to_round_off_and_a_changed_physics_is_reported(tmp_path, capsys):
    """bags/sample_default_scene was recorded with physics.clock = input, so the replay command reproduces
    every recorded surface. By default it compares bit for bit (--tolerance 0): exit 0 on a CPU like the one that
    recorded it; on a CPU with other vector instructions (numba compiles for the host: an AVX2 host read 1.07e-14 m
    from an AVX-512 host's recording) exit 1 naming round-off and --tolerance 1e-9, which then passes. The same-host
    replay of a fresh recording is tested bit for bit in test_node_skeleton.py and test_hostile_node.py. A failure
    here means the physics changed since it was recorded: record it again (bags/README.md). The same bag with a
    stiffer material must fail with exit 1, naming the way out."""
    from clusterfem_ros.recording.bag_reader import PARAMS_FILE, read_surfaces
    from clusterfem_ros.replay import main
    code = main([str(SAMPLE)])
    out, err = capsys.readouterr()
    got = re.search(r"compared (\d+) of (\d+) surfaces: (\d+) identical bit for bit; max vertex difference (\S+) m", out)
    assert got and int(got[1]) == int(got[2]) == len(read_surfaces(SAMPLE)) > 50, out
    if code == 0:                                            # the CPU that recorded it, or one like it
        assert int(got[3]) == int(got[1]) and float(got[4]) == 0.0, out
    else:                                                    # another CPU: round-off, and the way to say so
        assert code == 1 and "round-off size" in err and "--tolerance 1e-9" in err, err
        # round-off only: a 1e-14 perturbation of every joint angle grew to 1.7e-13 m over the bag's 6.6 s
        assert 0.0 < float(got[4]) <= 1e-10, out
        assert main([str(SAMPLE), "--tolerance", "1e-9"]) == 0
        capsys.readouterr()
    stiffer = tmp_path / "stiffer"
    stiffer.mkdir()
    for f in SAMPLE.iterdir():
        (stiffer / f.name).write_bytes(f.read_bytes())
    text = (SAMPLE / PARAMS_FILE).read_text()
    assert "young_modulus: 30000.0" in text
    (stiffer / PARAMS_FILE).write_text(text.replace("young_modulus: 30000.0", "young_modulus: 60000.0"))
    assert main([str(stiffer), "--tolerance", "1e-9"]) == 1
    err = capsys.readouterr().err
    assert "the physics changed since it was recorded" in err and "record it again" in err


def test_replay_never_passes_having_compared_nothing(tmp_path, capsys):
    """A bag recorded on the wall clock (its states depend on when each step ran) and a bag without a surface
    cannot be compared: exit 2, saying why and that physics.clock: input records a bag that replays."""
    from clusterfem_ros.config import SceneConfig, scene_file_text
    from clusterfem_ros.recording.bag_reader import PARAMS_FILE
    from clusterfem_ros.replay import main
    wall = tmp_path / "wall"
    wall.mkdir()
    for f in SAMPLE.iterdir():
        (wall / f.name).write_bytes(f.read_bytes())
    text = (SAMPLE / PARAMS_FILE).read_text()
    assert "clock: input" in text
    (wall / PARAMS_FILE).write_text(text.replace("clock: input", "clock: wall"))
    assert main([str(wall)]) == 2
    out, err = capsys.readouterr()
    assert "physics.clock = wall" in err and "nothing was compared" in err and "physics.clock: input" in err, err
    bare = tmp_path / "joint_states_only"
    with Rosbag2McapWriter(bare) as w:
        w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        w.write("/joint_states", T0, joint_state_cdr(["root_x"], np.zeros(1), stamp=T0))
    (bare / PARAMS_FILE).write_text(scene_file_text(SceneConfig().with_values(physics__clock="input")))
    assert main([str(bare)]) == 2
    err = capsys.readouterr().err
    assert "no surface Marker" in err and "nothing was compared" in err and "physics.clock: input" in err, err
    assert main([str(SAMPLE), "--tolerance", "-1"]) == 2


def _input_clock_bag(folder: Path, surfaces: int = 2, joint_states: bool = True, topic: bool = True) -> Path:
    """A bag as the node records on the input clock: ``surfaces`` triangle surfaces (stamped T0, T0 + 1 ms, ...),
    a joint state before them (unless not ``joint_states``; its topic is still declared when ``topic``), and the
    scene parameter file."""
    from clusterfem_ros.config import SceneConfig, scene_file_text
    from clusterfem_ros.recording.bag_reader import PARAMS_FILE
    v, tri, rgba = np.eye(3), np.array([[0, 1, 2]]), np.ones((3, 4), np.float32)
    with Rosbag2McapWriter(folder) as w:
        if topic:
            w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        w.add_topic("/clusterfem/surface", "visualization_msgs/msg/Marker")
        if joint_states:
            w.write("/joint_states", T0, joint_state_cdr(["root_x"], np.zeros(1), stamp=T0))
        for k in range(surfaces):
            w.write("/clusterfem/surface", T0 + k * 1_000_000, surface_marker_cdr(v, tri, rgba, "world",
                                                                                  T0 + k * 1_000_000))
    (folder / PARAMS_FILE).write_text(scene_file_text(SceneConfig().with_values(physics__clock="input")))
    return folder


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_replay_with_a_non_finite_vertex_fails_at_every_tolerance(tmp_path, capsys, monkeypatch, bad):
    """A NaN difference is not > 0: compared by `worst > tolerance` alone, a replay gone NaN would pass bit for
    bit. Here the replay (its physics stubbed: the comparison is under test) gives the recorded surfaces with one
    vertex of the first surface non-finite."""
    import clusterfem_ros.replay as replay_module
    from clusterfem_ros.recording.bag_reader import read_surfaces
    from clusterfem_ros.scene import Scene
    bag = _input_clock_bag(tmp_path / "b")
    recorded = dict(read_surfaces(bag))

    def replayed(scene, samples, at_ns):
        got = {t: p.copy() for t, p in recorded.items()}
        got[min(got)][1, 2] = bad
        return got

    monkeypatch.setattr(Scene, "build", staticmethod(lambda config: None))
    monkeypatch.setattr(replay_module, "replay", replayed)
    for tolerance in ("0", "1e-9", "1e9"):
        assert replay_module.main([str(bag), "--tolerance", tolerance]) == 1, tolerance
        err = capsys.readouterr().err
        assert "non-finite vertex (NaN or inf)" in err and "no --tolerance accepts" in err, err
    monkeypatch.setattr(replay_module, "replay", lambda scene, samples, at_ns: dict(recorded))
    assert replay_module.main([str(bag)]) == 0                       # the same bag, replayed finite: passes


@pytest.mark.parametrize("topic", [True, False], ids=["topic_without_messages", "no_topic"])
def test_a_bag_without_joint_states_is_not_replayed_saying_why(tmp_path, capsys, topic):
    from clusterfem_ros.replay import main
    bag = _input_clock_bag(tmp_path / "b", joint_states=False, topic=topic)
    assert main([str(bag)]) == 2
    err = capsys.readouterr().err
    assert "holds no joint state" in err and "nothing was compared" in err and "joint states coming in" in err, err


def test_a_bag_topic_is_found_under_a_namespace_and_two_namespaces_are_refused():
    from clusterfem_ros.recording.bag_reader import topic_in
    assert topic_in({"/joint_states", "/body1/joint_states"}, "/joint_states") == "/joint_states"
    assert topic_in({"/body1/clusterfem/surface", "/diagnostics"}, "/clusterfem/surface") == "/body1/clusterfem/surface"
    assert topic_in({"/diagnostics"}, "/joint_states") is None
    assert topic_in({"/my_joint_states"}, "/joint_states") is None          # a suffix of a name is not a namespace
    with pytest.raises(ValueError, match="/a/joint_states, /b/joint_states"):
        topic_in({"/a/joint_states", "/b/joint_states"}, "/joint_states")
