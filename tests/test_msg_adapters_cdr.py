"""The CDR fast paths against rclpy's serialize_message and an independent CDR coder (rosbags).

rclpy (Fast DDS) leaves CDR padding bytes uninitialised (heap garbage that changes from call to
call) and, after an empty float64[] at an 8-misaligned offset, reports 4 bytes too many per such
sequence (JointState: tail of 4-8 garbage bytes). So "byte-identical" is checked as: same length
(bar that documented tail), every byte equal except where rclpy has garbage, and each such byte is
zero in ours and provably padding (overwriting it changes nothing on decode). rosbags, which
zero-fills padding, must re-encode our bytes to exactly the same bytes.
"""
from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from clusterfem_ros.recording.msgdef import message_definition
from msg_adapters.colormap import map_scalars
from msg_adapters.joint_state import arrays_to_joint_state, joint_state_cdr
from msg_adapters.marker import surface_marker, surface_marker_cdr
from msg_adapters.pointcloud import stress_cloud, stress_cloud_cdr


@cache
def typestore():
    store = get_typestore(Stores.EMPTY)
    for t in ("visualization_msgs/msg/Marker", "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/JointState"):
        store.register(get_types_from_msg(message_definition(t), t))
    return store


def assert_same_cdr(ours: bytes, msg, max_rclpy_tail: int = 0) -> None:
    ref = serialize_message(msg)
    assert isinstance(ours, bytes)
    tail = len(ref) - len(ours)
    assert 0 <= tail <= max_rclpy_tail, f"rclpy {len(ref)} B, ours {len(ours)} B"
    a, b = np.frombuffer(ours, np.uint8), np.frombuffer(ref[:len(ours)], np.uint8)
    diff = np.flatnonzero(a != b)
    assert (a[diff] == 0).all(), f"bytes {diff[a[diff] != 0][:10]} differ and are not zero padding in ours"
    poisoned = a.copy()
    poisoned[diff] = 0xAA
    assert deserialize_message(poisoned.tobytes(), type(msg)) == msg, f"differing bytes {diff[:10]} are not padding"
    assert deserialize_message(ours, type(msg)) == msg
    store, name = typestore(), type(msg).__module__.split(".")[0] + "/msg/" + type(msg).__name__
    assert bytes(store.serialize_cdr(store.deserialize_cdr(ours, name), name)) == ours


@pytest.mark.parametrize("t", [0, 1, 2, 5, 3000])
@pytest.mark.parametrize("frame_id,ns", [("", ""), ("w", "ab"), ("world", "surface"), ("map12", "abc")])
def test_marker_cdr_matches_rclpy(t, frame_id, ns):
    rng = np.random.default_rng(t)
    n = max(t, 3)
    v, tri = rng.normal(size=(n, 3)), rng.integers(0, n, size=(t, 3))
    rgba = map_scalars(rng.random(n), "turbo", 0.0, 1.0)
    args = (v, tri, rgba, frame_id, 1_700_000_000_987_654_321, ns, 3)
    assert_same_cdr(surface_marker_cdr(*args), surface_marker(*args))


def test_marker_cdr_refuses_nan():
    with pytest.raises(ValueError, match="vertex 1 "):
        surface_marker_cdr(np.array([[0, 0, 0], [np.nan, 0, 0], [1, 1, 1.0]]), np.array([[0, 1, 2]]),
                           np.ones((3, 4)), "w", 0)


@pytest.mark.parametrize("n", [0, 1, 5, 1000])
@pytest.mark.parametrize("extra", [None, {"s1": None}, {"s1": None, "s2": None, "s3": None}])
@pytest.mark.parametrize("frame_id", ["", "abc", "world"])
def test_stress_cloud_cdr_matches_rclpy(n, extra, frame_id):
    rng = np.random.default_rng(n)
    p, vm = rng.normal(size=(n, 3)), rng.random(n)
    fields = {k: rng.normal(size=n) for k in extra} if extra else None
    args = (p, vm, frame_id, 123_456_789_000, fields)
    assert_same_cdr(stress_cloud_cdr(*args), stress_cloud(*args))


@pytest.mark.parametrize("n", [0, 1, 2, 3, 7])
@pytest.mark.parametrize("with_velocity", [True, False])
@pytest.mark.parametrize("frame_id", ["", "base"])
def test_joint_state_cdr_is_exact(n, with_velocity, frame_id):
    rng = np.random.default_rng(n)
    names = [f"joint_{i}" * (i % 3 + 1) for i in range(n)]
    q, dq = rng.normal(size=n), (rng.normal(size=n) if with_velocity else None)
    ours = joint_state_cdr(names, q, dq, 5_000_000_001, frame_id)
    # rclpy's tail: up to 4 garbage bytes per empty float64[] (position, velocity, effort)
    assert_same_cdr(ours, arrays_to_joint_state(names, q, dq, 5_000_000_001, frame_id), max_rclpy_tail=12)


def test_empty_joint_state_is_36_bytes():
    """The notes' figure: 36 B on the wire, 44 B from serialize_message."""
    assert len(joint_state_cdr([], np.zeros(0))) == 36
    assert len(serialize_message(arrays_to_joint_state([], np.zeros(0)))) == 44
