"""Jelly bodies: capsules of bones far apart in the skeleton are never glued by the voxelization."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.bvh import parse_bvh
from clusterfem_ros.skeleton.bvh_to_urdf import bvh_urdf
from clusterfem_ros.skeleton.humanoid import HumanoidSpec, default_humanoid
from clusterfem_ros.skeleton.jelly_body import (bone_hops, humanoid_capsules, jelly_man_mesh, nearest_capsule,
                                                separate_limbs)
from clusterfem_ros.skeleton.kinematics import Skeleton

# Arms down in the rest pose, in metres, Y up: the left hand hangs 7.9 cm from the left thigh's axis, so
# their 5 cm capsules overlap (as in the 3dsMax-friendly CMU captures).
ARMS_DOWN = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT LeftUpLeg
  {
    OFFSET 0.1 -0.05 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT LeftLeg
    {
      OFFSET 0 -0.45 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      End Site
      {
        OFFSET 0 -0.45 0
      }
    }
  }
  JOINT Spine
  {
    OFFSET 0 0.1 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT LeftArm
    {
      OFFSET 0.179 0.4 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT LeftForeArm
      {
        OFFSET 0 -0.3 0
        CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT LeftHand
        {
          OFFSET 0 -0.25 0
          CHANNELS 3 Zrotation Yrotation Xrotation
          End Site
          {
            OFFSET 0 -0.12 0
          }
        }
      }
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.01
""" + " ".join(["0"] * 24) + "\n"

ARM, LEG = {"LeftArm", "LeftForeArm", "LeftHand"}, {"LeftUpLeg", "LeftLeg"}


def _arms_down_spec() -> HumanoidSpec:
    urdf = bvh_urdf(parse_bvh(ARMS_DOWN, unit_m=1.0))
    return HumanoidSpec(urdf, {n: 0.05 for n in Skeleton.from_urdf_string(urdf).bone_names})


def _arm_leg_vertices(spec, mesh) -> int:
    """Vertices shared by a tet of the arm and a tet of the leg (tets labelled by the capsule their centroid is
    deepest in)."""
    sk = Skeleton.from_urdf_string(spec.urdf)
    s, e, r = humanoid_capsules(spec)
    names = [n for n in sk.bone_names if n in spec.bone_radius]
    label = nearest_capsule(mesh.vertices[mesh.tets].mean(axis=1), s, e, r)
    arm = np.isin(label, [names.index(n) for n in ARM])
    leg = np.isin(label, [names.index(n) for n in LEG])
    return np.intersect1d(mesh.tets[arm].ravel(), mesh.tets[leg].ravel()).size


def test_hands_hanging_against_the_thighs_are_not_glued_to_them():
    """The issue's case: voxelizing the union of capsules joined hand and thigh (tets spanning them stretch
    into webs as soon as the arm swings). With the default glue_hops the two share no vertex, while the arm
    stays whole and attached to the trunk."""
    spec = _arms_down_spec()
    glued = jelly_man_mesh(spec, target_tets=3000, glue_hops=None)
    assert _arm_leg_vertices(spec, glued) > 0                 # the old voxelization glues them
    mesh = jelly_man_mesh(spec, target_tets=3000)
    assert _arm_leg_vertices(spec, mesh) == 0
    s, e, r = humanoid_capsules(spec)
    names = [n for n in Skeleton.from_urdf_string(spec.urdf).bone_names if n in spec.bone_radius]
    label = nearest_capsule(mesh.vertices, s, e, r)
    for bone in ARM | LEG:
        assert (label == names.index(bone)).sum() > 20, bone   # every limb is still there
    assert abs(mesh.n_tets - 3000) < 600


def test_the_default_humanoid_is_unchanged_at_the_default_size():
    """The built-in humanoid's capsules of far-apart bones do not touch at rest: its default jelly man (4800
    tets) is the same mesh with or without the separation (the sample bag's physics stays the same)."""
    a = jelly_man_mesh(default_humanoid(), 4800, glue_hops=None)
    b = jelly_man_mesh(default_humanoid(), 4800)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.tets, b.tets)


def test_bone_hops_counts_steps_through_the_tree():
    #        0
    #      /   \
    #     1     3
    #     |     |
    #     2     4
    hops = bone_hops(np.array([-1, 0, 1, 0, 3]))
    assert hops[2, 4] == 4 and hops[1, 3] == 2 and hops[0, 2] == 2 and hops[3, 3] == 0
    np.testing.assert_array_equal(hops, hops.T)
    assert bone_hops(np.array([-1, -1]))[0, 1] == 2          # two roots: farther than any path


def test_separate_limbs_drops_both_sides_of_a_forbidden_contact_and_the_pieces_cut_off():
    mask = np.zeros((8, 3, 3), bool)
    mask[:, 1, 1] = True                              # a rod of 8 voxels: bones 0 0 0 1 1 2 2 2
    label = np.zeros(mask.shape, np.int64)
    label[3:5, 1, 1], label[5:, 1, 1] = 1, 2
    may = np.eye(3, dtype=bool)
    may[0, 1] = may[1, 0] = may[1, 2] = may[2, 1] = True     # 0-1 and 1-2 glue, 0-2 not (they do not touch)
    np.testing.assert_array_equal(separate_limbs(mask, label, may), mask)
    may[1, 2] = may[2, 1] = False                     # 1-2 may not touch: voxels 4 and 5 go, 6-7 are cut off
    kept = separate_limbs(mask, label, may)[:, 1, 1]
    np.testing.assert_array_equal(kept, [True, True, True, True, False, False, False, False])


def test_a_capsule_body_on_another_skeleton_leaves_no_vertex_free_and_the_built_in_one_is_as_configured():
    """The jelly body of equal capsules on a BVH skeleton had voxel corners just beyond the outermost binding
    level (0.06 m; capsules 0.05 m plus half a voxel): one-tet flaps, free, that fluttered at ~80 m/s while
    their bones moved at 6 m/s and tore the body on the cartwheel clip (9 resets; 1 with them bound). The
    scene binds every vertex of such a body; the built-in humanoid's free flesh (torso beyond 0.06 m) stays."""
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.scene import Scene
    urdf = _arms_down_spec().urdf
    c = SceneConfig().with_values({"skeleton.source": "robot_description", "body.target_tets": 1500})
    scene = Scene.build(c, urdf_xml=urdf)
    assert scene.bind_all and (scene.binding.level >= 0).all()
    assert scene.binding.level_radii[-1] > c["binding.level_radii"][-1]
    built_in = Scene.build(SceneConfig().with_values(body__target_tets=700))
    assert not built_in.bind_all and (built_in.binding.level < 0).any()
    np.testing.assert_array_equal(built_in.binding.level_radii, c["binding.level_radii"])


def test_a_vertex_binds_only_bones_its_voxels_were_kept_for():
    """Flesh sized by role (a thick pelvis and thigh beside a thin hanging arm, as on the 3ds-Max and Bandai
    Namco rigs): the voxels of bones that may not touch share no vertex, so the bones a vertex may bind to
    (voxel_bones) must be bones that may touch one another. Read at the tets' centroids rather than at their
    voxels' centres, a forearm voxel's tets came out in the pelvis's capsule, and a vertex of the forearm
    followed the pelvis until the raised arm tore it 0.3 m from its bone."""
    from clusterfem_ros.skeleton.jelly_body import voxel_bones
    urdf = bvh_urdf(parse_bvh(ARMS_DOWN, unit_m=1.0))
    sk = Skeleton.from_urdf_string(urdf)
    radius = {"Hips": 0.16, "LeftUpLeg": 0.09, "LeftLeg": 0.06, "Spine": 0.12, "LeftArm": 0.045,
              "LeftForeArm": 0.04, "LeftHand": 0.035}
    spec = HumanoidSpec(urdf, {n: radius[n] for n in sk.bone_names if n in radius})
    mesh = jelly_man_mesh(spec, target_tets=3000, axis_consistent=True)
    hops = bone_hops(np.asarray(sk.bone_parent))
    allowed = voxel_bones(spec, mesh)
    assert allowed.any(axis=1).all()                      # every vertex has a bone
    worst = max(int(hops[np.ix_(np.flatnonzero(row), np.flatnonzero(row))].max()) for row in allowed)
    assert worst <= 2, f"a vertex may bind bones {worst} hops apart"
