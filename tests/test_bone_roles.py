"""Bone roles from the tree and the rest shape (skeleton/bone_roles.py): the same roles whatever the names, the
order, the scale or the up axis; names decide the sides only when the shape cannot."""
import re
from pathlib import Path

import numpy as np
import pytest

from clusterfem_ros.skeleton.bone_roles import NotHumanoid, flesh_radii, label_bones, label_skeleton, name_side
from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.kinematics import Skeleton
from tests.shared_data import manifest_clip

HUMANOID_ROLE = {"pelvis": "pelvis", "abdomen": "spine", "chest": "spine", "neck": "neck", "head": "head",
                 "clavicle": "clavicle", "upper_arm": "upper_arm", "forearm": "forearm", "hand": "hand",
                 "thigh": "thigh", "shin": "shin", "foot": "foot", "toes": "toe"}
MAJOR = ("pelvis", "spine", "head", "thigh", "shin", "foot", "upper_arm", "forearm", "hand")


def _humanoid():
    sk = Skeleton.from_urdf_string(default_humanoid().urdf)
    s, e = sk.bone_segments(sk.neutral())
    return sk.bone_names, sk.bone_parent, s, e


def _expected(name: str) -> str:
    side, _, part = name.partition("_") if name[:2] in ("l_", "r_") else ("", "", name)
    return (side + "_" if side else "") + HUMANOID_ROLE[part]


def test_the_default_humanoid_is_labelled_as_its_names_say():
    """The built-in humanoid's names are the ground truth: every bone's role and side comes out as named, left
    (+Y, the humanoid's l_ side) told by the feet's reach (+X)."""
    names, parent, s, e = _humanoid()
    roles = label_bones(names, parent, s, e)
    assert roles.sided_by == "geometry"
    assert {n: roles.role_of(n) for n in names} == {n: _expected(n) for n in names}
    np.testing.assert_allclose(roles.up, [0, 0, 1], atol=0.05)
    np.testing.assert_allclose(roles.left, [0, 1, 0], atol=0.05)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_renamed_shuffled_scaled_and_turned_skeletons_get_the_same_roles(seed):
    """Names replaced by meaningless ones, bones in another order, lengths in other units (x 100, x 39.37) and
    the whole skeleton turned (Y up instead of Z): the same role per bone, radii scaled with the lengths."""
    names, parent, s, e = _humanoid()
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(names))              # new bone k is old bone perm[k]
    inv = np.argsort(perm)
    new_parent = np.array([inv[parent[p]] if parent[p] >= 0 else -1 for p in perm])
    scale = [1.0, 100.0, 39.37][seed]
    turn = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=float)     # Z up -> Y up
    new_names = [f"joint{rng.integers(1_000_000)}_{k}" for k in range(len(names))]
    got = label_bones(new_names, new_parent, scale * s[perm] @ turn.T, scale * e[perm] @ turn.T)
    want = label_bones(names, parent, s, e)
    assert [got.role_of(new_names[k]) for k in inv] == [want.role_of(n) for n in names]
    r_got, bare_got = flesh_radii(got)
    r_want, bare_want = flesh_radii(want)
    assert len(bare_got) == len(bare_want)
    for k, n in enumerate(names):
        assert r_got[new_names[inv[k]]] == pytest.approx(scale * r_want[n], rel=1e-9)


def test_names_that_lie_about_the_side_lose_to_the_shape():
    """Left and right names swapped: the feet still point forward, so the sides follow the geometry."""
    names, parent, s, e = _humanoid()
    swapped = [("r_" + n[2:]) if n.startswith("l_") else ("l_" + n[2:]) if n.startswith("r_") else n for n in names]
    roles = label_bones(swapped, parent, s, e)
    assert roles.sided_by == "geometry"
    assert all(roles.sides[k] == names[k][0] for k in range(len(names)) if names[k][:2] in ("l_", "r_"))


@pytest.mark.parametrize("style", ["{L}_{part}", "Bip01 {LR} {Part}", "mixamorig:{Left}{Part}", "{Part}_{LR}",
                                   "{lr}{Part}"])
def test_names_tell_the_sides_when_the_shape_cannot(style):
    """Feet with no forward reach (every point flattened onto the body's side plane, so a mirror image looks the
    same): the names decide, whatever the convention, and the log line says so."""
    names, parent, s, e = _humanoid()
    s, e = s.copy(), e.copy()
    s[:, 0] = e[:, 0] = 0.0
    styled = []
    for n in names:
        if n[:2] in ("l_", "r_"):
            side, part = n[0], n[2:]
            styled.append(style.format(L=side, LR=side.upper(), lr=side, Left={"l": "Left", "r": "Right"}[side],
                                       part=part, Part=part.title().replace("_", "")))
        else:
            styled.append(n)
    roles = label_bones(styled, parent, s, e)
    assert roles.sided_by == "names"
    assert all(roles.sides[k] == names[k][0] for k in range(len(names)) if names[k][:2] in ("l_", "r_"))


@pytest.mark.parametrize("name, side", [("LeftUpLeg", "l"), ("mixamorig:RightHand", "r"), ("Bip01 L Thigh", "l"),
                                        ("l_knee", "l"), ("Hand_R", "r"), ("thigh.L", "l"), ("LHipJoint", "l"),
                                        ("lShldr", "l"), ("rcollar", "r"), ("RIGHTFOOT", "r"), ("leftupleg", "l"),
                                        ("ROOT", ""), ("LOWERBACK", ""), ("Hips", ""),
                                        ("Spine1", ""), ("LowerBack", ""), ("Head", ""), ("lowerneck", "")])
def test_name_side_reads_the_common_conventions(name, side):
    assert name_side(name) == side


def test_a_chain_is_not_a_human():
    """A robot arm (one chain) has fewer than five limb ends: NotHumanoid names what is missing."""
    pts = np.cumsum(np.full((6, 3), 0.2), axis=0)
    with pytest.raises(NotHumanoid, match="leaf bones"):
        label_bones([f"link{k}" for k in range(5)], np.arange(-1, 4), pts[:-1], pts[1:])


def _bvh_files():
    from tests.shared_data import manifest_clips
    return manifest_clips()


def _bvh_skeleton(path: Path, rename: dict | None = None) -> Skeleton:
    from clusterfem_ros.skeleton.bvh import load_bvh
    from clusterfem_ros.skeleton.bvh_to_urdf import bvh_urdf
    motion = load_bvh(path)
    if rename:
        for j in motion.joints:
            j.name = rename[j.name]
    return Skeleton.from_urdf_string(bvh_urdf(motion))


CLIP_FILES = _bvh_files()


@pytest.mark.parametrize("path", CLIP_FILES, ids=[p.stem for p in CLIP_FILES])
def test_captures_of_every_source_get_both_limbs_of_every_major_role(path):
    """Each fetched clip and each CMU clip present, in the rest the bind turns its limbs from (its zero pose, or
    frame 0 where no human stands in the zero pose: the Bandai Namco and LAFAN1 rigs lay their bones along their
    parents' X axes and only the captured frames pose them): every major role on both sides (one trunk), sides
    agreeing with the joint names wherever a name tells a side, and no major bone bare."""
    from clusterfem_ros.body.auto_bind import rest_configuration
    sk = _bvh_skeleton(path)
    roles = label_skeleton(sk, rest_configuration(sk, str(path))[0])
    have = {roles.role_of(n) for n in sk.bone_names}
    for role in MAJOR:
        assert (role in have) if role in ("pelvis", "spine", "head") else {f"l_{role}", f"r_{role}"} <= have, role
    wrong = [n for k, n in enumerate(sk.bone_names) if name_side(n) and roles.sides[k] and name_side(n) != roles.sides[k]]
    assert not wrong, f"sides against the names: {wrong}"
    radii, bare = flesh_radii(roles)
    major_with_length = [n for k, n in enumerate(sk.bone_names) if roles.roles[k] in MAJOR and roles.lengths[k] > 0]
    assert major_with_length and all(n in radii for n in major_with_length)


def test_a_capture_with_meaningless_names_gets_the_same_roles():
    """The Mixamo rig with every joint renamed (j0, j1, ...): the same role for every bone as with its own names."""
    path = manifest_clip("mixamo_rig_freebvh")
    from clusterfem_ros.skeleton.bvh import load_bvh
    names = [j.name for j in load_bvh(path).joints]
    rename = {n: f"j{k}" for k, n in enumerate(names)}
    plain = label_skeleton(_bvh_skeleton(path))
    renamed = label_skeleton(_bvh_skeleton(path, rename))
    assert [renamed.role_of(rename[n]) for n in plain.names] == [plain.role_of(n) for n in plain.names]


def test_the_jelly_body_on_a_mixamo_rig_has_flesh_on_every_major_bone():
    """The default scene's jelly body on the Mixamo rig's skeleton: a vertex near every major bone, the bare bones
    (fingers, end joints, eyes) named in one start-up line, and a skeleton that is no human falls back to
    body.bone_radius with a line saying so."""
    from benchmarks.clip_soak import flesh_check
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.motion import load_motion, on_capture_skeleton
    from clusterfem_ros.scene import Scene
    from clusterfem_ros.scene_build import jelly_radii
    lines = []
    motion = load_motion("bvh", manifest_clip("mixamo_rig_freebvh"))
    scene = Scene.build(on_capture_skeleton(SceneConfig()), urdf_xml=motion.urdf, progress=lines.append)
    assert flesh_check(scene)[1] == "none"
    bare = [line for line in lines if line.startswith("bones left bare")]
    assert len(bare) == 1 and "mixamorig:LeftHandThumb1 (l_finger)" in bare[0] and "mixamorig:LeftEye" in bare[0]
    assert not re.search(r"mixamorig:(Left|Right)(UpLeg|Leg|Foot|Arm|ForeArm|Hand) ", bare[0])
    chain = "<robot name='arm'><link name='a'><inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial></link>" \
            "<link name='b'><inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial></link>" \
            "<joint name='j' type='revolute'><parent link='a'/><child link='b'/><origin xyz='0 0 0.3'/>" \
            "<axis xyz='0 1 0'/><limit lower='-1' upper='1' effort='1' velocity='1'/></joint></robot>"
    said = []
    radii, bare = jelly_radii(Skeleton.from_urdf_string(chain), {}, SceneConfig().body, said.append)
    assert radii == {"a": 0.05, "b": 0.05} and bare == [] and "not a human skeleton" in said[0]


def test_a_rig_whose_zero_pose_is_no_standing_human_gets_its_flesh_in_frame_0():
    """The Bandai Namco rig's bones lie along their parents' X axes until the frames pose them: its zero pose has
    feet to head along the side, frame 0 stands. capture_bind_pose chooses frame 0 for it (and the zero pose for
    the Mixamo rig, which stands in it); there every major role is found on both sides, as the names say, and
    the jelly body built there has flesh on every major bone."""
    from benchmarks.clip_soak import flesh_check
    from clusterfem_ros.body.fit import bind_configuration
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.motion import capture_bind_pose, load_motion, on_capture_skeleton
    from clusterfem_ros.scene import Scene
    from clusterfem_ros.skeleton.bone_roles import stands
    bandai, mixamo = manifest_clip("bandai_namco_dash"), manifest_clip("mixamo_rig_freebvh")
    assert capture_bind_pose(mixamo)[0] == "neutral"
    pose, why = capture_bind_pose(bandai)
    assert pose == "first_frame" and "no human stands in its zero pose" in why
    sk = _bvh_skeleton(bandai)
    q = bind_configuration(sk, "first_frame", bvh_file=str(bandai))
    assert not stands(label_skeleton(sk))
    roles = label_skeleton(sk, q)
    assert stands(roles)
    have = {roles.role_of(n) for n in sk.bone_names}
    assert {f"{s}_{r}" for s in "lr" for r in MAJOR[3:]} <= have and {"pelvis", "spine", "head"} <= have
    assert all(roles.sides[k] == name_side(n) for k, n in enumerate(sk.bone_names) if name_side(n))
    config = on_capture_skeleton(SceneConfig(), bandai)
    assert config.skeleton.bind_pose == "first_frame"
    scene = Scene.build(config, urdf_xml=load_motion("bvh", bandai).urdf)
    assert flesh_check(scene)[1] == "none"


def test_a_voxel_nearer_the_axis_of_a_limb_it_may_not_touch_is_a_conflict():
    """A thick trunk capsule (r 0.12) beside a thin forearm (r 0.05) hanging 0.16 m from its axis: a trunk voxel
    at 0.09 m from the trunk axis and 0.07 m from the forearm's would be bound to the forearm (nearest axis) and
    follow it: a conflict when the two may not touch, none when they may, and none for a voxel nearer its own
    axis; the margin widens the test by its value."""
    from clusterfem_ros.skeleton.jelly_body import axis_conflicts
    starts = np.array([[0.0, 0, 0], [0.16, 0, 0]])
    ends = np.array([[0.0, 0, 0.5], [0.16, 0, 0.5]])
    points = np.array([[0.09, 0, 0.25], [0.05, 0, 0.25]])
    label = np.array([0, 0])
    apart, together = np.eye(2, dtype=bool), np.ones((2, 2), dtype=bool)     # a bone always touches itself
    zero = np.zeros((2, 2))
    assert axis_conflicts(points, starts, ends, label, apart, zero).tolist() == [True, False]
    assert axis_conflicts(points, starts, ends, label, together, zero).tolist() == [False, False]
    assert axis_conflicts(points, starts, ends, label, apart, np.full((2, 2), 0.07)).tolist() == [True, True]
