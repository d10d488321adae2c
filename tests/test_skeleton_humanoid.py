"""The default humanoid (proportions, DOF, pose conventions) and the jelly body voxelized around it."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.jelly_body import capsule_inside, humanoid_capsules, jelly_man_mesh
from clusterfem_ros.skeleton.kinematics import Skeleton
from tests import naive


@pytest.fixture(scope="module")
def spec():
    return default_humanoid()


def test_humanoid_has_48_dof_a_scalar_floating_root_and_human_proportions(spec):
    sk = Skeleton.from_urdf_string(spec.urdf)
    assert sk.nq == sk.nv == 48
    assert sk.joint_names[:6] == ["root_x", "root_y", "root_z", "root_yaw", "root_pitch", "root_roll"]
    assert (~sk.revolute_mask()).sum() == 3
    assert set(spec.bone_radius) == set(sk.bone_names) and sk.bone_parent[0] == -1
    s, e, r = humanoid_capsules(spec)
    low = np.minimum(s[:, 2], e[:, 2]) - r
    high = np.maximum(s[:, 2], e[:, 2]) + r
    assert abs(low.min()) < 1e-9 and abs(high.max() - 1.75) < 0.02 and abs(spec.height - high.max()) < 1e-9
    foot = sk.bone_names.index("l_foot")
    assert e[foot, 0] > s[foot, 0]                                          # facing +X
    assert s[sk.bone_names.index("l_thigh"), 1] > 0 > s[sk.bone_names.index("r_thigh"), 1]   # left is +Y


def test_pitch_conventions_of_the_docstring(spec):
    sk = Skeleton.from_urdf_string(spec.urdf)
    q = sk.neutral()
    q[sk.joint_index("l_hip_pitch")] = -0.5                                 # hip flexion: knee forward
    q[sk.joint_index("root_x")] = 2.0
    s, _ = sk.bone_segments(q)
    knee = s[sk.bone_names.index("l_shin")]
    assert knee[0] > 2.0 + 0.1 and np.isclose(s[0, 0], 2.0)


def test_capsule_inside_matches_a_direct_distance_check():
    rng = np.random.default_rng(3)
    s, e = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    r = rng.uniform(0.2, 0.5, 4)
    p = rng.normal(size=(3000, 3))
    inside = capsule_inside(p, s, e, r)
    u = np.linspace(0, 1, 2001)[:, None]
    # distance to a densely sampled segment overestimates the true one by < |e - s| / 4000
    d = np.stack([np.linalg.norm(p[:, None] - (s[b] + u * (e[b] - s[b]))[None], axis=2).min(axis=1) for b in range(4)], 1)
    surely_in, surely_out = (d <= r - 1e-3).any(axis=1), (d > r + 1e-3).all(axis=1)
    assert inside[surely_in].all() and not inside[surely_out].any()
    assert 0.1 < inside.mean() < 0.9
    with pytest.raises(ValueError, match="radii"):
        capsule_inside(p, s, e, -r)


def test_capsule_inside_equals_its_numpy_twin_on_a_voxel_grid_around_the_humanoid(spec):
    """The compiled test gives the einsum form's answer for every point of two grids around the body; a point
    exactly on a capsule's surface is inside; a zero-length bone is a ball."""
    s, e, r = humanoid_capsules(spec)
    lo = np.minimum(s, e).min(axis=0) - r.max()
    hi = np.maximum(s, e).max(axis=0) + r.max()
    for h in (0.01, 0.0137):
        g = [np.arange(lo[a], hi[a] + h, h) for a in range(3)]
        p = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
        inside = capsule_inside(p, s, e, r)
        assert 0.005 < inside.mean() < 0.5
        assert np.array_equal(inside, naive.capsule_inside(p, s, e, r)), h
    zero_length = capsule_inside(np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.3]]), np.zeros((1, 3)), np.zeros((1, 3)),
                                 np.array([0.2]))
    assert zero_length.tolist() == [True, False]                            # a ball
    axis = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([0.25])
    on_surface = np.array([[0.25, 0.0, 0.5], [0.0, -0.25, 0.75], [0.0, 0.0, 1.25], [0.25, 0.0, 1.25]])
    assert capsule_inside(on_surface, *axis).tolist() == [True, True, True, False]   # distances exact in binary


def test_jelly_man_mesh_is_near_the_target_and_wraps_the_bones(spec):
    mesh = jelly_man_mesh(spec, target_tets=1500)
    assert abs(mesh.n_tets - 1500) < 0.1 * 1500
    sk = Skeleton.from_urdf_string(spec.urdf)
    s, e = sk.bone_segments(sk.neutral())
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    assert lo[2] > -0.05 and 1.65 < hi[2] < 1.85                            # stands on the floor, ~1.75 m
    # every bone's midpoint is inside the body: some vertex lies near it
    mid = 0.5 * (s + e)
    spacing = np.linalg.norm(mesh.vertices[mesh.tets[:, 1]] - mesh.vertices[mesh.tets[:, 0]], axis=1).max()
    d = np.linalg.norm(mesh.vertices[:, None] - mid[None], axis=2).min(axis=0)
    assert (d < spacing).all(), [sk.bone_names[b] for b in np.flatnonzero(d >= spacing)]
    with pytest.raises(ValueError, match="target_tets"):
        jelly_man_mesh(spec, target_tets=3)
