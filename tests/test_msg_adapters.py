"""Round trips of every adapter, through rclpy serialize/deserialize too."""
from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, PointCloud2
from visualization_msgs.msg import Marker

from msg_adapters.colormap import COLORMAP_NAMES, NONFINITE_RGBA, colormap_lut, map_scalars
from msg_adapters.diagnostics import diagnostic_array, diagnostic_values
from msg_adapters.joint_state import arrays_to_joint_state, joint_state_to_arrays
from msg_adapters.marker import surface_marker
from msg_adapters.pointcloud import read_points, stress_cloud
from msg_adapters.time import as_ns, ns_to_stamp, seconds_to_ns, split_ns, stamp_to_ns, stamp_to_seconds


def roundtrip(msg):
    return deserialize_message(serialize_message(msg), type(msg))


# -- time ------------------------------------------------------------------------------------
@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 1_700_000_000_123_456_789, -1, -1_500_000_000])
def test_stamp_round_trip(ns):
    stamp = ns_to_stamp(ns)
    assert 0 <= stamp.nanosec < 10**9
    assert stamp_to_ns(stamp) == ns == as_ns(stamp)
    assert stamp_to_seconds(stamp) == pytest.approx(ns * 1e-9)


def test_stamp_refuses_float_and_out_of_range():
    with pytest.raises(TypeError, match="seconds_to_ns"):
        as_ns(1.5)
    with pytest.raises(ValueError, match="int32"):
        split_ns(2**31 * 10**9)
    assert seconds_to_ns(1.25) == 1_250_000_000


# -- colour maps -----------------------------------------------------------------------------
def test_colormaps_are_256_rgba_luts():
    for name in ("viridis", "turbo", "coolwarm"):
        lut = colormap_lut(name)
        assert lut.shape == (256, 4) and lut.dtype == np.float32
        assert np.all((lut >= 0) & (lut <= 1)) and np.all(lut[:, 3] == 1)


def test_map_scalars_ends_clip_and_nonfinite():
    v = np.array([-5.0, 0.0, 0.5, 1.0, 7.0, np.nan, np.inf, -np.inf])
    rgba = map_scalars(v, "viridis", 0.0, 1.0)
    lut = colormap_lut("viridis")
    assert rgba.shape == (8, 4) and rgba.dtype == np.float32 and np.isfinite(rgba).all()
    np.testing.assert_array_equal(rgba[[0, 1]], lut[[0, 0]])
    np.testing.assert_array_equal(rgba[[3, 4]], lut[[255, 255]])
    np.testing.assert_array_equal(rgba[5:], np.tile(NONFINITE_RGBA, (3, 1)))


def test_map_scalars_uniform_field_and_errors():
    assert np.isfinite(map_scalars(np.zeros(4), "turbo", 0.0, 0.0)).all()
    with pytest.raises(ValueError, match="viridis"):
        map_scalars(np.zeros(3), "nope", 0, 1)
    with pytest.raises(ValueError, match="reversed"):
        map_scalars(np.zeros(3), "viridis", 1, 0)
    assert set(COLORMAP_NAMES) >= {"viridis", "turbo", "coolwarm"}


# -- marker ----------------------------------------------------------------------------------
def _mesh(seed=0, t=20, n=15):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    tri = rng.integers(0, n, size=(t, 3))
    rgba = map_scalars(rng.random(n), "coolwarm", 0.0, 1.0)
    return v, tri, rgba


def test_surface_marker_round_trip():
    v, tri, rgba = _mesh()
    msg = roundtrip(surface_marker(v, tri, rgba, "world", 1_000_000_123, "body", 7))
    assert (msg.type, msg.action, msg.ns, msg.id, msg.header.frame_id) == (Marker.TRIANGLE_LIST, 0, "body", 7, "world")
    assert stamp_to_ns(msg.header.stamp) == 1_000_000_123
    assert (msg.pose.orientation.w, msg.scale.x, msg.scale.y, msg.scale.z, msg.color.a) == (1, 1, 1, 1, 1)
    pts = np.array([[p.x, p.y, p.z] for p in msg.points])
    cols = np.array([[c.r, c.g, c.b, c.a] for c in msg.colors], dtype=np.float32)
    np.testing.assert_array_equal(pts, v[tri.reshape(-1)])
    np.testing.assert_array_equal(cols, rgba[tri.reshape(-1)])


def test_surface_marker_refuses_nan_and_bad_indices():
    v, tri, rgba = _mesh()
    v[4] = np.nan
    with pytest.raises(ValueError, match="vertex 4"):
        surface_marker(v, tri, rgba, "world", 0)
    v, tri, rgba = _mesh()
    tri[0, 0] = len(v)
    with pytest.raises(ValueError, match="indices"):
        surface_marker(v, tri, rgba, "world", 0)
    with pytest.raises(ValueError, match="vertex_rgba"):
        surface_marker(v, tri[1:], rgba[:-1], "world", 0)


# -- point cloud -----------------------------------------------------------------------------
def test_stress_cloud_round_trip_with_extra_fields():
    rng = np.random.default_rng(1)
    p, vm = rng.normal(size=(50, 3)), rng.random(50) * 1e6
    s1, s3 = rng.normal(size=50), rng.normal(size=50)
    msg = roundtrip(stress_cloud(p, vm, "world", 42, {"s1": s1, "s3": s3}))
    assert [f.name for f in msg.fields] == ["x", "y", "z", "von_mises", "s1", "s3"]
    assert (msg.height, msg.width, msg.point_step, msg.is_dense, msg.header.frame_id) == (1, 50, 24, True, "world")
    pts = read_points(msg)
    assert pts.shape == (50,)
    for name, ref in [("x", p[:, 0]), ("y", p[:, 1]), ("z", p[:, 2]), ("von_mises", vm), ("s1", s1), ("s3", s3)]:
        np.testing.assert_array_equal(pts[name], ref.astype(np.float32))


def test_stress_cloud_errors_and_empty():
    with pytest.raises(ValueError, match="point 2"):
        stress_cloud(np.ones((3, 3)), np.array([0.0, 1.0, np.nan]), "w", 0)
    with pytest.raises(ValueError, match="already used"):
        stress_cloud(np.ones((3, 3)), np.ones(3), "w", 0, {"x": np.ones(3)})
    with pytest.raises(ValueError, match="one value per point"):
        stress_cloud(np.ones((3, 3)), np.ones(3), "w", 0, {"s1": np.ones(2)})
    assert read_points(roundtrip(stress_cloud(np.zeros((0, 3)), np.zeros(0), "w", 0))).shape == (0,)


# -- joint state -----------------------------------------------------------------------------
@pytest.mark.parametrize("with_velocity", [True, False])
def test_joint_state_round_trip(with_velocity):
    names, q = ["hip", "knee", "ankle"], np.array([0.1, -0.2, 0.3])
    dq = np.array([1.0, 2.0, 3.0]) if with_velocity else None
    t, n2, q2, dq2 = joint_state_to_arrays(roundtrip(arrays_to_joint_state(names, q, dq, 2_500_000_000)))
    assert t == 2.5 and n2 == names
    np.testing.assert_array_equal(q2, q)
    if with_velocity:
        np.testing.assert_array_equal(dq2, dq)
    else:
        assert dq2 is None


def test_joint_state_errors():
    with pytest.raises(ValueError, match="one per joint"):
        arrays_to_joint_state(["a"], np.zeros(2))
    with pytest.raises(ValueError, match="2 names but 1 positions"):
        joint_state_to_arrays(JointState(name=["a", "b"], position=[1.0]))


# -- diagnostics -----------------------------------------------------------------------------
def test_diagnostics_round_trip():
    values = {"steps": 1200, "ms_per_step": 0.3125, "method": "clustered", "stable": True, "energy": -1e-12}
    msg = roundtrip(diagnostic_array(5, "clusterfem", "sim0", values, "WARN", "slow"))
    assert isinstance(msg, DiagnosticArray) and msg.status[0].level == b"\x01"
    assert (msg.status[0].name, msg.status[0].hardware_id, msg.status[0].message) == ("clusterfem", "sim0", "slow")
    assert diagnostic_values(msg) == values
    with pytest.raises(ValueError, match="level"):
        diagnostic_array(0, "n", "h", {}, "LOUD")


def test_read_points_after_cdr_decode_has_array_data():
    msg = roundtrip(stress_cloud(np.ones((2, 3)), np.ones(2), "w", 0))
    assert isinstance(msg, PointCloud2) and read_points(msg)["von_mises"].tolist() == [1.0, 1.0]
