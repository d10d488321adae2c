"""The shipped character scene (config/character_walk.yaml) on real data: the MakeHuman body on CMU captures.

Skipped, naming config/character_data.md, where the mesh is not in $CLUSTERFEM_DATA/meshes or
../shared/data/meshes; the other clips likewise, naming tests/data/mocap_clips.yaml. The tets come from the
user's mesh cache (the first run meshes them: about two minutes on 2 cores under load).
"""
import pytest

from tests.shared_data import CHARACTER_SCENE, character_mesh, walk_clip

TARGET_TETS = 5000      # the scene's body.target_tets


@pytest.fixture(scope="module")
def walk():
    character_mesh()
    return walk_clip()


def _clip(name: str):
    from benchmarks.clips import find_clip, load_manifest, missing_message
    clip = next(c for c in load_manifest() if c.name == name)
    path = find_clip(clip)
    if path is None:
        pytest.skip(missing_message(clip))
    return path


def _surface_body(bvh):
    """The character's surface body on the skeleton of capture ``bvh``, as the node builds it."""
    from benchmarks.clips import clip_config
    from clusterfem_ros.body.surface_body import build_surface_body
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.skeleton.kinematics import Skeleton
    config = clip_config(scene=CHARACTER_SCENE)
    skeleton = Skeleton.from_urdf_string(load_motion("bvh", bvh).urdf)
    return build_surface_body(config, skeleton), skeleton, config


def test_the_character_is_meshed_to_its_target_and_every_bone_is_inside(walk):
    from clusterfem_ros.body.fit import bones_outside
    from clusterfem_ros.fem.mesh.tet_mesh import boundary_triangles
    body, skeleton, config = _surface_body(walk)
    assert config["body.target_tets"] == TARGET_TETS
    assert abs(body.mesh.n_tets / TARGET_TETS - 1) <= 0.2
    assert (body.mesh.volumes() > 0).all() and body.tets.min_dihedral_deg > 1.0
    # decimetres, auto-fitted: the skeleton's height sets the scale near the declared 0.1 m per unit
    assert 0.08 < body.fit.scale < 0.12
    starts, ends = skeleton.bone_segments(body.bind_q)
    out = bones_outside(body.mesh.vertices, boundary_triangles(body.mesh), starts, ends, skeleton.bone_names,
                        config["skeleton.fit_tolerance"])
    assert out == []


def test_a_capture_of_another_subject_with_the_same_joint_names_fits_the_character(walk):
    leaps = _clip("cmu_05_02_leaps")                     # CMU subject 05: other bone lengths, the walk's names
    body, skeleton, _ = _surface_body(leaps)
    assert abs(body.mesh.n_tets / TARGET_TETS - 1) <= 0.2 and len(skeleton.bone_names) == 31


@pytest.mark.parametrize("name", ["cmu_131_03_hop_3dsmax", "mixamo_rig_freebvh"])
def test_a_capture_with_other_joint_names_and_rest_pose_fits_the_character(walk, name):
    """The 3ds-Max conversion (LeftHip, LeftKnee, ...; arms down at rest) and the Mixamo rig (prefixed names,
    fingers, eyes): the bind pose is found from the mesh, every bone that binds lies inside, and only finger, toe and
    root-helper bones (by role) and the head's side parts are left without flesh."""
    from clusterfem_ros.body.auto_bind import head_parts
    from clusterfem_ros.skeleton.bone_roles import label_skeleton
    body, skeleton, config = _surface_body(_clip(name))
    roles = label_skeleton(skeleton)
    ends = skeleton.bone_segments(body.bind_q)[1]
    parts = {skeleton.bone_names[b] for b in head_parts(roles, skeleton.bone_parent, ends)}
    assert all(roles.role_of(n).split("_")[-1] in ("finger", "toe", "root") or n in parts for n in body.unbound), \
        body.unbound
    assert (name == "mixamo_rig_freebvh") == bool(parts) and parts <= set(body.unbound), parts
    assert config["body.surface_unit"] == "auto" and 0.05 < body.fit.scale < 0.2    # decimetres, read from its height


def test_the_character_walks_a_second_bounded_with_nothing_withheld(walk):
    from benchmarks.clip_soak import headless_soak
    r = headless_soak(walk, seconds=1.0, scene_file=CHARACTER_SCENE)
    print(r)
    assert r.resets == 0, r.first_problem
    assert r.withheld == 0 and r.shown >= 100
    assert r.worst_volume < 0.1 and r.worst_distance < 0.3


@pytest.mark.soak
@pytest.mark.parametrize("name", ["cmu_05_02_leaps", "cmu_05_06_cartwheel_dance", "cmu_05_16_dance_glitches",
                                  "cmu_06_04_basketball_run", "cmu_backflip", "cmu_falling_over"])
def test_every_clip_of_the_walks_skeleton_plays_on_the_character_without_reset(walk, name):
    from benchmarks.clip_soak import headless_soak
    r = headless_soak(_clip(name), scene_file=CHARACTER_SCENE)
    print(r)
    assert r.resets == 0, r.first_problem
    assert r.worst_distance <= 0.3 and r.worst_volume < 0.5


@pytest.mark.soak
def test_the_60_s_walk_stays_bounded_without_reset(walk):
    from benchmarks.character_report import bvh_skeleton, drive
    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.scene import Scene
    urdf, traj = bvh_skeleton(walk)
    scene = Scene.build(load_scene_file(CHARACTER_SCENE), urdf_xml=urdf)
    r = drive(scene, traj, 60.0)
    print(r)
    assert r["resets"] == 0 and r["finite"]
    assert r["volume_error"] < 0.1
