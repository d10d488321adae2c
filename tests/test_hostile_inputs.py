"""Hostile and careless inputs without ROS (issue 19): oversized and absurd joint states, a full disk under the
bag writer and its recovery, bad files and parameter files at start-up. The node-level findings are in
test_hostile_node.py."""
from __future__ import annotations

import errno
import os
import shutil
import threading

import numpy as np
import pytest

from clusterfem_ros.recording import rosbag2_mcap
from clusterfem_ros.recording.recover import RecoveryError, recover_bag
from clusterfem_ros.recording.rosbag2_mcap import Rosbag2McapWriter
from clusterfem_ros.skeleton.joint_map import FATAL as MAP_FATAL
from clusterfem_ros.skeleton.joint_map import MAX_REMEMBERED_UNKNOWN, JointMap
from clusterfem_ros.skeleton.joint_stream import FATAL, JointStreamInterpolator
from msg_adapters.joint_state import joint_state_cdr
from tests.test_recording_signals import rosbags_count

NAMES = ["root_x", "root_y", "yaw", "knee"]
REV = np.array([False, False, True, True])
TOPIC = "/joint_states"


class QuotaFile:
    """A file that fails with ENOSPC once ``quota`` bytes were written to it: a full disk."""

    def __init__(self, f, quota: int):
        self._f, self.quota, self.written = f, quota, 0

    def write(self, data) -> int:
        if self.written + len(data) > self.quota:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.written += len(data)
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)


def full_disk_after(monkeypatch, quota: int) -> None:
    """Every bag file opened from now on fills its disk after ``quota`` bytes."""
    real_open = open
    monkeypatch.setattr(rosbag2_mcap, "open", lambda path, mode: QuotaFile(real_open(path, mode), quota),
                        raising=False)


def joint_cdr(k: int, n: int = 4) -> bytes:
    return joint_state_cdr(NAMES[:n], np.full(n, 0.001 * k), stamp=1_000_000_000 + k * 1_000_000)


def killed_bag(folder, messages: int, compression: str = "none"):
    """A bag folder as a SIGKILL leaves it: ``messages`` flushed, no summary, no footer."""
    w = Rosbag2McapWriter(folder.with_name(folder.name + "_live"), compression=compression)
    w.add_topic(TOPIC, "sensor_msgs/msg/JointState")
    for k in range(messages):
        w.write(TOPIC, 1_000_000_000 + k, joint_cdr(k))
    w.flush()
    shutil.copytree(w.folder, folder)
    w.close()
    shutil.rmtree(w.folder)
    (folder / w.path.name).rename(folder / f"{folder.name}_0.mcap")
    return folder / f"{folder.name}_0.mcap"


# -- 1. what the node records of a joint state ---------------------------------------------------------
def test_the_recorded_extent_drops_a_senders_tail_and_the_name_count_needs_no_decoding():
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from msg_adapters.joint_state import joint_state_cdr_extent, joint_state_name_count
    for frame in ("", "abc", "world"):
        for n in (0, 1, 4):
            data = joint_state_cdr(NAMES[:n], np.arange(n, dtype=float), np.ones(n) if n % 2 else None, 7, frame)
            assert joint_state_name_count(data) == n and joint_state_cdr_extent(data + b"\xffjunk") == len(data)
            assert deserialize_message(data, JointState).name == NAMES[:n]
    for bad in (b"garbage!", b"\x00\x01\x00\x00" + b"\xff" * 40):
        with pytest.raises(ValueError):
            joint_state_name_count(bad)
        with pytest.raises(ValueError):
            joint_state_cdr_extent(bad)


# -- 3. one large message: linear, bounded, one report per message ---------------------------------------
class NoTouching(list):
    """A name list that fails if anything looks at its names (only its length is allowed)."""

    def __iter__(self):
        raise AssertionError("per-name work on a message that has too many names")


def test_too_many_names_is_refused_before_any_per_name_work():
    jm = JointMap(NAMES, max_names=100)
    r = jm.update(NoTouching(["x"] * 101), np.zeros(101))
    assert not r.accepted and r.problems[0][0] == "too_many_names" and "101 names" in r.problems[0][1]
    assert "too_many_names" in MAP_FATAL


def test_a_huge_message_with_one_duplicate_is_refused_naming_it():
    names = [f"n{i}" for i in range(200_000)] + ["n17"]            # quadratic: hours; linear: well under a second
    jm = JointMap(NAMES, max_names=300_000)
    r = jm.update(names, np.zeros(len(names)))
    assert not r.accepted and r.problems == [("duplicate_joint", r.problems[0][1])] and "'n17'" in r.problems[0][1]


def test_unknown_names_give_one_report_per_message_and_a_bounded_memory():
    jm = JointMap(NAMES, max_names=100_000)
    names = [f"stranger_{i}" for i in range(20_000)] + ["knee"]
    r = jm.update(names, np.zeros(len(names)))
    assert r.accepted and [k for k, _ in r.problems] == ["unknown_joint"]
    assert "and 19995 more" in r.problems[0][1] and len(r.new_unknown) == 20_000
    assert len(jm.unknown) == MAX_REMEMBERED_UNKNOWN
    r = jm.update(names[:MAX_REMEMBERED_UNKNOWN] + ["knee"], np.zeros(MAX_REMEMBERED_UNKNOWN + 1))
    assert r.problems == []                                         # remembered ones are not reported again


# -- 5. absurd but finite inputs ------------------------------------------------------------------------
def stream(**kw):
    kw = {"max_root_distance": 100.0, "max_joint_speed": 40.0, **kw}
    return JointStreamInterpolator(NAMES, revolute=REV, **kw)


def test_root_far_away_is_rejected_and_never_accepted_later():
    s = stream(max_age=0.1)
    assert s.push(0.0, np.zeros(4)) == []
    for k in range(1, 40):                                          # 0.39 s of it: far beyond max_age
        (kind, text), = s.push(0.01 * k, np.array([1e9, 0, 0, 0]))
        assert kind == "root_range" and "1e+09 m" in text and "input.max_root_distance" in text
    assert s.newest == 0.0 and {"root_range", "joint_speed"} <= FATAL
    (kind, _), = s.push(0.4, np.array([1e300, 0, 0, 0]))
    assert kind == "root_range"
    assert [k for k, _ in s.push(0.41, np.array([50.0, 0, 0, 0]))] == ["teleport"]    # within range: a teleport


def test_joint_speed_glitches_and_absurd_velocities_are_rejected():
    s = stream()
    assert s.push(0.0, np.zeros(4)) == []
    assert s.push(0.01, np.array([0, 0, 0.3, 0])) == []             # 30 rad/s: a fast kick
    (kind, text), = s.push(0.02, np.array([0, 0, 0.3 + np.deg2rad(175), 0]))   # a thigh flipping in one frame
    assert kind == "joint_speed" and "'yaw'" in text and "capture glitch" in text
    assert s.push(0.03, np.array([0, 0, 0.35, 0])) == []            # the glitch ends: accepted at once
    for v in (1e12, 1e300, -1e12):
        (kind, text), = s.push(0.04, np.array([0, 0, 0.35, 0]), v=np.array([0, 0, 0, v]))
        assert kind == "joint_speed" and "'knee' reports velocity" in text
    assert s.push(0.05, np.array([0.2, 0, 0.35, 0])) == []          # root 20 m/s: a sprint is allowed
    assert s.push(0.06, np.array([0.7, 0, 0.35, 0]))[0][0] == "joint_speed"   # 50 m/s is not


def test_split_publishers_microseconds_apart_are_not_too_fast():
    s = stream()
    for k in range(5):                                              # legs at 100 Hz, arms 10 us later
        t = 0.01 * k
        assert s.push(t, np.array([0, 0, 0.2 * k, 0.3 * (k - 1) if k else 0.0])) == []
        assert s.push(t + 1e-5, np.array([0, 0, 0.2 * k, 0.3 * k])) == []       # knee: 30 rad/s over 10 ms
    (kind, text), = s.push(0.05, np.array([0, 0, 0.8, 1.7]))        # knee: 0.5 rad in 10 ms is 50 rad/s
    assert kind == "joint_speed" and "'knee' moved 0.5 in 0.00999 s" in text


def test_motion_faster_than_the_limit_restarts_the_stream_after_max_age():
    s = stream(max_age=0.495)
    s.push(0.0, np.zeros(4))
    kinds = []
    for k in range(1, 100):                                         # a joint really turning at 50 rad/s, at 100 Hz
        got = s.push(0.01 * k, np.array([0, 0, 0, 0.5 * k]), v=np.array([0, 0, 0, 50.0]), now=0.01 * k)
        kinds.append([kind for kind, _ in got])
        if "restart" in kinds[-1]:
            break
    assert kinds[:50] == [["joint_speed"]] * 50 and kinds[50] == ["joint_speed", "restart"]
    assert s.newest == pytest.approx(0.51) and len(s) == 1          # 0.5 s after the first rejection
    assert s.push(0.52, np.array([0, 0, 0, 25.6])) == []            # slower again: plain acceptance


def test_the_limits_are_scene_parameters_with_ranges():
    from clusterfem_ros.config import ConfigError, SceneConfig
    c = SceneConfig()
    assert (c["input.max_joint_speed"], c["input.max_root_distance"], c["input.max_names"]) == (300.0, 1000.0, 1000)
    with pytest.raises(ConfigError, match=r"input.max_names = 0 is outside \[1, 1e\+06\]"):
        c.with_values({"input.max_names": 0})
    with pytest.raises(ConfigError, match="input.max_joint_speed"):
        c.with_values({"input.max_joint_speed": 0.0})


# -- 2 and 4. the bag writer: write failures and the byte budget -----------------------------------------
def test_a_full_disk_stops_the_writer_with_the_error_and_recovery_keeps_what_was_flushed(tmp_path, monkeypatch):
    full_disk_after(monkeypatch, 40_000)
    w = Rosbag2McapWriter(tmp_path / "b", flush_interval_s=0.05, compression="none", chunk_size=4096)
    w.add_topic(TOPIC, "sensor_msgs/msg/JointState")
    sent = 0
    while w.error is None and sent < 10_000:
        try:
            w.write(TOPIC, 1_000_000_000 + sent, joint_cdr(sent))
        except RuntimeError:
            break
        sent += 1
    assert isinstance(w.error, OSError) and w.error.errno == errno.ENOSPC
    with pytest.raises(RuntimeError, match="is closed"):
        w.write(TOPIC, 1, joint_cdr(0))
    with pytest.raises(RuntimeError, match="No space left"):
        w.close()
    assert w.close() is True                                        # reported once; closing again is quiet
    monkeypatch.undo()
    report = recover_bag(tmp_path / "b")
    assert 0 < report.messages < sent and not list(tmp_path.glob("*.recovering"))
    assert rosbags_count(tmp_path / "b") == {TOPIC: report.messages}


def test_a_bag_folder_deleted_mid_run_stops_the_writer_with_the_error(tmp_path):
    w = Rosbag2McapWriter(tmp_path / "b", flush_interval_s=0.01)
    w.add_topic(TOPIC, "sensor_msgs/msg/JointState")
    (tmp_path / "b").rename(tmp_path / "gone")                      # as rm -r does to the path, atomically
    for k in range(100_000):                                        # the next flush rewrites metadata.yaml: fails
        if w.error is not None:
            break
        w.write(TOPIC, 1_000_000_000 + k, joint_cdr(k))
        w._thread.join(0.001)
    assert isinstance(w.error, FileNotFoundError) and "metadata.yaml" in str(w.error)
    with pytest.raises(RuntimeError, match="the I/O thread failed"):
        w.close()


def test_recovery_on_a_full_disk_says_where_it_needs_space_or_uses_a_work_dir(tmp_path, monkeypatch, capsys):
    (tmp_path / "disk").mkdir()
    folder = tmp_path / "disk" / "bag"
    path = killed_bag(folder, 500)
    size = path.stat().st_size
    real_usage = shutil.disk_usage

    def usage(where):                                               # the bag's disk is full, others are not
        u = real_usage(where)
        return u._replace(free=0) if str(where).startswith(str(tmp_path / "disk")) else u
    monkeypatch.setattr(shutil, "disk_usage", usage)
    with pytest.raises(RecoveryError, match=rf"needs about .* MB free in {tmp_path / 'disk'} .*work_dir"):
        recover_bag(folder)
    assert path.stat().st_size == size and not list((tmp_path / "disk").glob("*.recovering"))
    from clusterfem_ros.recording.recover import main
    assert main([str(folder)]) == 2 and "needs about" in capsys.readouterr().err
    (tmp_path / "spare").mkdir()
    assert main([str(folder), "--work-dir", str(tmp_path / "spare")]) == 0
    assert "500 messages kept" in capsys.readouterr().out and rosbags_count(folder) == {TOPIC: 500}
    assert list((tmp_path / "spare").iterdir()) == []


def test_a_recovered_copy_too_large_for_the_full_disk_leaves_the_bag_as_it_was(tmp_path, monkeypatch):
    """The bag filled its disk and the work dir is on another one: the complete copy, larger than the killed file
    by its summary, does not fit back. The original is not deleted first and the copy stays a readable bag."""
    (tmp_path / "disk").mkdir()
    (tmp_path / "spare").mkdir()
    folder = tmp_path / "disk" / "bag"
    path = killed_bag(folder, 500, compression="zstd")
    before = path.read_bytes()
    real_usage, real_replace = shutil.disk_usage, os.replace

    def usage(where):                                               # the bag's disk is full, the spare one is not
        u = real_usage(where)
        return u._replace(free=0) if str(where).startswith(str(tmp_path / "disk")) else u

    def replace(src, dst):                                          # the spare folder is another file system
        if str(src).startswith(str(tmp_path / "spare")) and str(dst).startswith(str(tmp_path / "disk")):
            raise OSError(errno.EXDEV, "Invalid cross-device link")
        return real_replace(src, dst)
    monkeypatch.setattr(shutil, "disk_usage", usage)
    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(RecoveryError, match=r"does not fit in place of .*bag_0\.mcap.* the bag is unchanged"):
        recover_bag(folder, work_dir=tmp_path / "spare")
    assert path.read_bytes() == before
    assert rosbags_count(tmp_path / "spare" / "bag.recovering") == {TOPIC: 500}


def test_recovery_that_runs_out_of_space_leaves_no_recovering_folder(tmp_path, monkeypatch):
    killed_bag(tmp_path / "bag", 2000)
    full_disk_after(monkeypatch, 20_000)
    with pytest.raises(RecoveryError, match="ran out of space while writing the copy"):
        recover_bag(tmp_path / "bag")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_the_byte_budget_drops_and_counts_instead_of_waiting_or_growing(tmp_path, monkeypatch):
    gate = threading.Event()
    w = Rosbag2McapWriter(tmp_path / "b", max_queue_bytes=20_000)
    w.add_topic(TOPIC, "sensor_msgs/msg/JointState")
    real_add = w._mcap.add_message
    monkeypatch.setattr(w._mcap, "add_message", lambda **kw: gate.wait() and real_add(**kw))   # a stalled disk
    msg = joint_cdr(0)
    kept = [w.write(TOPIC, 1_000_000_000 + k, msg) for k in range(1000)]
    assert w.queued_bytes <= 20_000
    assert w.dropped == kept.count(False) and w.dropped_bytes == w.dropped * len(msg)
    assert kept.count(True) >= 20_000 // len(msg) - 1 and kept.count(False) > 800
    gate.set()
    w.close()
    assert rosbags_count(tmp_path / "b") == {TOPIC: kept.count(True)}
    with pytest.raises(ValueError, match="max_queue_bytes 0"):
        Rosbag2McapWriter(tmp_path / "c", max_queue_bytes=0)


def test_replaying_a_bag_with_an_undecodable_joint_state_is_one_error_line(tmp_path, capsys):
    from clusterfem_ros.config import SceneConfig, scene_file_text
    from clusterfem_ros.recording.bag_reader import PARAMS_FILE, BagReadError, read_joint_states
    from clusterfem_ros.replay import main
    with Rosbag2McapWriter(tmp_path / "b") as w:                    # written by something other than the node
        w.add_topic(TOPIC, "sensor_msgs/msg/JointState")
        w.write(TOPIC, 1_000_000_000, joint_cdr(0))
        w.write(TOPIC, 1_000_000_001, b"\x00\x01\x00\x00" + b"\xff" * 40)
    (tmp_path / "b" / PARAMS_FILE).write_text(scene_file_text(SceneConfig().with_values(physics__clock="input")))
    with pytest.raises(BagReadError, match=r"/joint_states record 1 \(log time 1000000001 ns, 44 bytes\) does not"):
        read_joint_states(tmp_path / "b")
    assert main([str(tmp_path / "b")]) == 2
    errors = [x for x in capsys.readouterr().err.splitlines() if x.startswith("error")]
    assert len(errors) == 1 and "record 1" in errors[0]


# -- 6. start-up errors from files -----------------------------------------------------------------------
def test_a_garbage_msh_is_a_mesh_error_naming_the_file_not_an_exit(tmp_path):
    from clusterfem_ros.fem.mesh.mesh_io import read_mesh
    from clusterfem_ros.fem.mesh.tet_mesh import MeshError
    for text in ("garbage!\n", "$MeshFormat\n1.0 0 8\n$EndMeshFormat\n"):
        bad = tmp_path / "bad.msh"
        bad.write_text(text)
        with pytest.raises(MeshError, match=rf"cannot read mesh file '{bad}' as .msh: .*export it again"):
            read_mesh(bad)


def test_a_urdf_number_that_is_not_one_names_the_element():
    from clusterfem_ros.skeleton.humanoid import default_humanoid
    from clusterfem_ros.skeleton.kinematics import Skeleton, UrdfError
    xml = default_humanoid().urdf
    value = xml.split('<mass value="', 1)[1].split('"', 1)[0]
    link = xml.split('<mass value="', 1)[0].rsplit('<link name="', 1)[1].split('"', 1)[0]
    with pytest.raises(UrdfError, match=rf"URDF link '{link}' <mass value> = 'heavy': give 1 finite number"):
        Skeleton.from_urdf_string(xml.replace(f'<mass value="{value}"', '<mass value="heavy"', 1))
    with pytest.raises(UrdfError, match=r"<origin xyz> = '0 0': give 3 finite numbers"):
        Skeleton.from_urdf_string(xml.replace('xyz="', 'xyz="0 0" old="', 1))


def test_a_bvh_declaring_more_frames_than_its_lines_is_refused_before_allocating():
    from clusterfem_ros.skeleton.bvh import BvhError, parse_bvh
    text = ("HIERARCHY\nROOT hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
            " End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 99999999\nFrame Time: 0.01\n0 0 0\n1 1 1\n")
    with pytest.raises(BvhError, match=r"'Frames: 99999999' but only \d lines follow"):
        parse_bvh(text, "big.bvh")
    assert parse_bvh(text.replace("99999999", "2"), "ok.bvh").n_frames == 2


def test_scene_files_refuse_unknown_names_with_the_nearest_and_non_mappings(tmp_path):
    from clusterfem_ros.config import ConfigError, load_scene_file
    f = tmp_path / "s.yaml"
    f.write_text("clusterfem:\n  ros__parameters:\n    material:\n      youngs_modulus: 1.0e5\n")
    with pytest.raises(ConfigError, match=r"unknown scene parameter 'material.youngs_modulus': did you mean "
                                          r"'material.young_modulus'\?"):
        load_scene_file(f)
    for text, what in (("just a string\n", "str"), ("- 1\n- 2\n", "list"), ("", "NoneType")):
        f.write_text(text)
        with pytest.raises(ConfigError, match=rf"holds a {what}, not a mapping"):
            load_scene_file(f)
    f.write_text("clusterfem:\n  ros__parameters: 3\n")
    with pytest.raises(ConfigError, match="no 'clusterfem: ros__parameters:' mapping"):
        load_scene_file(f)


def test_frame_id_is_bounded_everywhere():
    from clusterfem_ros.config import ConfigError, check_value
    assert check_value("output.frame_id", "map/base_link") == "map/base_link"
    for bad in ("x" * 1_000_000, "", "has space", "9lives"):
        with pytest.raises(ConfigError, match="output.frame_id = .*at most 256"):
            check_value("output.frame_id", bad)
