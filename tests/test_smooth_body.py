"""The smooth jelly man: its skin on the blended capsules, tets kept above their floor, limbs never glued."""
import numpy as np
import pytest

from clusterfem_ros.fem.mesh.tet_mesh import boundary_triangles, signed_volumes
from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.jelly_body import jelly_man_mesh
from clusterfem_ros.skeleton.smooth_body import (SmoothCapsules, crease_blend, edge_length, min_altitudes,
                                                 smooth_capsules_of, smooth_min, snap_to_shape, vertex_bones)


@pytest.fixture(scope="module")
def bodies():
    spec = default_humanoid()
    voxels = jelly_man_mesh(spec, target_tets=2500)
    shape = smooth_capsules_of(spec)
    smooth, facts = snap_to_shape(voxels, shape)
    return voxels, shape, smooth, facts


def test_smooth_min_is_the_minimum_away_from_the_blend_and_below_it_within():
    a = np.array([0.0, 0.0, 0.0, 1.0])
    b = np.array([0.5, 0.01, 0.0, -1.0])
    k = 0.1
    got = smooth_min(a, b, k)
    assert got[0] == 0.0 and got[3] == -1.0                       # |a - b| >= k: exactly min
    assert got[2] == pytest.approx(-k / 4, rel=1e-15)              # equal: lowered by k / 4
    assert -k / 4 < got[1] < 0.0


def test_depth_is_a_capsule_distance_far_from_the_joints():
    """Two bones, parent and child, along z: a point beside the middle of one is at |r| from its axis."""
    shape = SmoothCapsules(np.array([[0, 0, 0.0], [0, 0, 1.0]]), np.array([[0, 0, 1.0], [0, 0, 2.0]]),
                           np.array([0.1, 0.05]), np.array([-1, 0]), np.ones((2, 2), dtype=bool))
    p = np.array([[0.3, 0, 0.5], [0, 0.2, 1.5]])
    assert shape.depth(p, np.array([0, 1])) == pytest.approx([0.2, 0.15], abs=1e-14)
    on = shape.project(np.array([[0.3, 0.1, 0.5], [0.0, -0.02, 1.6]]), np.array([0, 1]), max_move=1.0)
    assert np.abs(shape.depth(on, np.array([0, 1]))).max() < 1e-9


def test_crease_blend_grows_with_the_angle_between_the_normals():
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert crease_blend(x, x) == 0.0 and crease_blend(x, -x) == 1.0
    assert crease_blend(x, y) == pytest.approx(0.5, abs=1e-15)


def _two_bones(bend_deg: float, r: float = 0.05) -> SmoothCapsules:
    """A parent along z from the origin to (0, 0, 1), its child of the same radius from there, turned by
    ``bend_deg`` towards +x."""
    a = np.radians(bend_deg)
    joint = np.array([0, 0, 1.0])
    return SmoothCapsules(np.array([[0, 0, 0.0], joint]), np.array([joint, joint + 0.5 * np.array([np.sin(a), 0, np.cos(a)])]),
                          np.array([r, r]), np.array([-1, 0]), np.ones((2, 2), dtype=bool))


def test_a_straight_joint_does_not_swell_and_a_bent_one_is_filled_in_its_crease():
    """A smooth minimum of the two capsules' distances would swell a straight joint into a ring k / 4 thick (both
    distances are equal all round it); the crease blend leaves it the plain capsule there, and fills the inside of
    a bent joint only, not its outside."""
    r = 0.05
    straight = _two_bones(0.0, r)
    ring = np.array([[r, 0, 1.0], [0, -r, 1.0], [-r * np.sqrt(0.5), r * np.sqrt(0.5), 1.0]])
    assert np.abs(straight.depth(ring, np.zeros(3, dtype=np.int64))).max() < 1e-12
    bent = _two_bones(90.0, r)
    # the crease: inside the bend (towards +x), on the bisector of the two bones, just outside both capsules
    inner = np.array([[r * 1.2, 0, 1.0 - r * 1.2]])
    union = bent.bone_depths(inner).min(axis=1)
    assert union > 0 and bent.depth(inner, np.array([0])) < union - 0.002
    # the outside of the bend, on the joint's sphere: both capsules' normals agree there, no fillet
    outer = np.array([[-r * np.sqrt(0.5), 0, 1.0 + r * np.sqrt(0.5)]])
    assert bent.depth(outer, np.array([0])) == pytest.approx(0.0, abs=1e-12)


def test_the_fillets_add_little_to_the_capsules_volume():
    """The built-in humanoid's blended shape holds at most 2 % more than the plain union of its capsules (a smooth
    minimum of one radius at every joint, straight ones too, swells it by a sixth), so the smooth body carries
    no more flesh across its joints than the capsules give it. Monte Carlo, the same points for both."""
    shape = smooth_capsules_of(default_humanoid())
    lo = np.minimum(shape.starts, shape.ends).min(axis=0) - 0.2
    hi = np.maximum(shape.starts, shape.ends).max(axis=0) + 0.2
    p = lo + (hi - lo) * np.random.default_rng(7).random((200_000, 3))
    union = np.count_nonzero(shape.bone_depths(p).min(axis=1) < 0)
    blended = np.count_nonzero(shape.depth(p, shape.bone_of(p)) < 0)
    print(f"blended / union volume: {blended / union:.4f}")
    assert union < blended < 1.02 * union


def test_the_surface_vertices_lie_on_the_implicit_shape(bodies):
    """Most surface vertices are on the blended capsules (the rest are held back by the tet floor), far nearer
    than the voxel body's."""
    voxels, shape, smooth, facts = bodies
    h = edge_length(voxels)
    surface = np.unique(boundary_triangles(voxels))
    bones = vertex_bones(voxels, shape)
    before = np.abs(shape.depth(voxels.vertices[surface], bones[surface]))
    after = np.abs(shape.depth(smooth.vertices[surface], bones[surface]))
    print(f"|depth| / h before: median {np.median(before) / h:.3f}, p95 {np.percentile(before, 95) / h:.3f}; "
          f"after: median {np.median(after) / h:.3f}, p95 {np.percentile(after, 95) / h:.3f}, "
          f"max {after.max() / h:.3f}")
    assert np.median(after) < 0.15 * h and np.percentile(after, 95) < 0.5 * h and after.max() < h
    assert np.median(after) < 0.5 * np.median(before)
    assert (after < 0.05 * h).mean() > 0.3


def test_same_tets_positive_and_above_the_altitude_floor(bodies):
    voxels, shape, smooth, facts = bodies
    assert np.array_equal(smooth.tets, voxels.tets) and smooth.n_vertices == voxels.n_vertices
    assert (signed_volumes(smooth.vertices, smooth.tets) > 0).all()
    share = min_altitudes(smooth.vertices, smooth.tets) / min_altitudes(voxels.vertices, voxels.tets)
    from clusterfem_ros.skeleton.smooth_body import MIN_ALTITUDE
    assert share.min() >= MIN_ALTITUDE - 1e-12
    assert abs(smooth.volumes().sum() / voxels.volumes().sum() - 1.0) < 0.15


def test_no_tet_is_glued_across_bones_that_may_not_touch(bodies):
    """Every tet's corners belong to bones that may touch (the voxel body's rule), and the skin of a vertex is
    its own bone's: no vertex moved onto a far limb's capsule."""
    voxels, shape, smooth, facts = bodies
    bones = vertex_bones(smooth, shape)
    corner_bones = bones[smooth.tets]
    for i in range(4):
        for j in range(i + 1, 4):
            assert shape.may_touch[corner_bones[:, i], corner_bones[:, j]].all()
    # a vertex's nearest bone after snapping is one its own bone may touch
    nearest = shape.bone_of(smooth.vertices)
    assert shape.may_touch[bones, nearest].all()


def test_the_smooth_body_is_the_default_with_the_voxel_bodys_critical_step_and_the_voxel_body_an_option():
    """The default scene's jelly man is the smooth one; its thinner skin tets would raise the largest eigenvalue of
    M^-1 K well above the voxel body's, and the scene's mass scaling (fem/mass_scaling.py, against the voxels it
    was moved from) brings it back for about a per cent of mass. body.skin voxel keeps the voxel grid."""
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.fem.mass_scaling import scale_to_reference
    from clusterfem_ros.fem.model import build_model
    from clusterfem_ros.fem.stability import max_eigenvalue
    from clusterfem_ros.scene_build import material_of, scene_parts
    config = SceneConfig().with_values(body__target_tets=1500)
    assert SceneConfig().body.skin == "smooth"
    smooth = scene_parts(config)
    voxel = scene_parts(config.with_values(body__skin="voxel"))
    assert voxel.mass_reference is None
    assert np.array_equal(smooth.mesh.tets, voxel.mesh.tets)
    assert np.array_equal(smooth.mass_reference.vertices, voxel.mesh.vertices)
    assert not np.array_equal(smooth.mesh.vertices, voxel.mesh.vertices)
    h = edge_length(voxel.mesh)
    grid = (voxel.mesh.vertices - voxel.mesh.vertices.min(axis=0)) / h          # voxel corners: on the grid
    assert np.allclose(grid, np.round(grid), atol=1e-6)
    material = material_of(config)
    own = build_model(smooth.mesh, material)
    lam_voxel, lam_own = max_eigenvalue(build_model(voxel.mesh, material)), max_eigenvalue(own)
    scaled, scaling = scale_to_reference(own, smooth.mass_reference)
    lam = max_eigenvalue(scaled)
    print(f"lambda: voxel {lam_voxel:.4g}, smooth {lam_own:.4g}, scaled {lam:.4g}; {scaling.summary()}")
    assert lam_own > 1.4 * lam_voxel
    assert lam <= 1.003 * lam_voxel
    assert 0 < scaling.added_share < 0.04
    # the mass goes to the skin, where the snap thinned the tets
    from clusterfem_ros.fem.mesh.tet_mesh import boundary_triangles
    surface = np.zeros(own.n_vertices, dtype=bool)
    surface[np.unique(boundary_triangles(smooth.mesh))] = True
    added = scaled.mass - own.mass
    assert added[surface].sum() > 0.8 * added.sum()
