"""bind_to_skeleton: nearest bone, nested levels, local frames, and the errors a user meets."""
import numpy as np
import pytest

from clusterfem_ros.body import bind_to_skeleton, segment_distance
from tests.test_body_support import LEVELS, ChainSkeleton, Motion, box_body


def _chain_binding(theta=(0.0, 0.0), **kw):
    sk = ChainSkeleton()
    q, v = Motion(theta=lambda t: np.array(theta)).qv(0.0)
    s, e = sk.bone_segments(q)
    P = sk.forward(q, v)
    mesh = box_body()
    return mesh, s, e, P, bind_to_skeleton(mesh.vertices, s, e, kw.pop("radii", LEVELS), rest_rotation=P.rotation,
                                           rest_translation=P.translation, bone_names=sk.bone_names, **kw)


def test_segment_distance_against_brute_force():
    rng = np.random.default_rng(3)
    pts, s, e = rng.normal(size=(50, 3)), rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    e[2] = s[2]                                                     # a zero-length bone is a point
    t = np.linspace(0, 1, 20001)
    brute = np.array([[np.linalg.norm(p - (s[b] + t[:, None] * (e[b] - s[b])), axis=1).min() for b in range(4)]
                      for p in pts])
    np.testing.assert_allclose(segment_distance(pts, s, e), brute, atol=1e-6)


def test_nearest_bone_levels_and_local_frames():
    mesh, s, e, P, b = _chain_binding(theta=(0.3, -0.5))
    x = mesh.vertices
    assert b.warnings == []
    d = segment_distance(x, s, e)
    np.testing.assert_allclose(b.distance, d.min(axis=1))
    assert (d[np.arange(len(x)), b.bone] == d.min(axis=1)).all()
    # levels: d <= r0 -> 0, r0 < d <= r1 -> 1, else free; the paper's sets are nested
    expect = np.where(b.distance <= LEVELS[0], 0, np.where(b.distance <= LEVELS[1], 1, -1))
    np.testing.assert_array_equal(b.level, expect)
    assert set(b.level_set(0)) < set(b.level_set(1))
    assert (b.level == 0).sum() > 0 and (b.level == 1).sum() > 0 and (b.level == -1).sum() > 0
    # local coordinates put every vertex back where it was through its bone's rest placement
    back = np.einsum("nij,nj->ni", P.rotation[b.bone], b.local) + P.translation[b.bone]
    np.testing.assert_allclose(back, x, atol=1e-14)
    np.testing.assert_allclose(np.einsum("bij,bkj->bki", P.rotation, b.axis_local) + P.translation[:, None],
                               np.stack([s, e], 1), atol=1e-14)


def test_bone_mask_keeps_flesh_off_excluded_bones():
    mesh, s, e, P, b = _chain_binding(bone_mask=np.array([True, False, True]))
    assert not (b.bone == 1).any()


def test_radii_must_increase_and_be_positive():
    mesh, s, e, _, _ = _chain_binding()
    with pytest.raises(ValueError, match=r"radius 1 = 0.02 m is not larger than radius 0 = 0.03"):
        bind_to_skeleton(mesh.vertices, s, e, (0.03, 0.02))
    with pytest.raises(ValueError, match="empty"):
        bind_to_skeleton(mesh.vertices, s, e, ())
    with pytest.raises(ValueError, match="positive finite"):
        bind_to_skeleton(mesh.vertices, s, e, (-0.01, 0.02))


def test_no_vertex_in_reach_is_an_error_naming_the_distance():
    mesh, s, e, _, _ = _chain_binding()
    with pytest.raises(ValueError, match="outermost level radius 0.1 m"):
        bind_to_skeleton(mesh.vertices, s + 5.0, e + 5.0, (0.05, 0.1))


def test_bone_without_inner_flesh_and_empty_level_are_warnings():
    mesh, s, e, _, _ = _chain_binding()
    s2 = np.vstack([s, [[0.3, 0.3, 0.0]]])                           # a bone floating beside the body
    e2 = np.vstack([e, [[0.3, 0.3, 0.01]]])
    with pytest.warns(UserWarning, match="bone 3 has no vertex within the innermost radius"):
        bind_to_skeleton(mesh.vertices, s2, e2, LEVELS)
    b = bind_to_skeleton(mesh.vertices, s2, e2, (0.031, 0.032, 0.045), warn=False)
    assert any("bone 3" in w for w in b.warnings)
    assert any("level 1 (radius 0.032 m) holds no vertex" in w for w in b.warnings)


def test_shape_errors_name_the_array():
    mesh, s, e, _, _ = _chain_binding()
    with pytest.raises(ValueError, match="bone ends has shape"):
        bind_to_skeleton(mesh.vertices, s, e[:2], LEVELS)
    bad = mesh.vertices.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"rest_vertices has a non-finite entry at index \(7, 1\)"):
        bind_to_skeleton(bad, s, e, LEVELS)
