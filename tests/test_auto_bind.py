"""skeleton.bind_pose 'auto' (body/auto_bind.py): the pose of a mesh found from its limbs, the skeleton's limbs turned
onto them, the bones outside left unbound by geometry, and the errors that name the wrong input.

The meshes are the default humanoid's smooth jelly body built in a known pose (T-pose, A-pose with bent elbows and
spread legs); the skeleton is the same humanoid in its zero pose (arms 30 deg out), so the angles to recover are
the mesh's own."""
import numpy as np
import pytest

from clusterfem_ros.body import auto_bind as ab
from clusterfem_ros.body.fit import FitError, bone_outside_distances, unit_mismatch
from clusterfem_ros.fem.mesh.tet_mesh import boundary_triangles
from clusterfem_ros.skeleton.bone_roles import label_skeleton
from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.kinematics import Skeleton
from clusterfem_ros.skeleton.smooth_body import smooth_jelly_man_mesh

pytest.importorskip("trimesh")

POSES = {"T-pose": {"l_shoulder_roll": 1.07, "r_shoulder_roll": -1.07},
         "A-pose": {"l_shoulder_roll": 0.35, "r_shoulder_roll": -0.35, "l_elbow_pitch": -0.5, "r_elbow_pitch": -0.5,
                    "l_hip_roll": 0.15, "r_hip_roll": -0.15}}
LIMB_BONES = ("upper_arm", "forearm", "thigh", "shin")
TOLERANCE_DEG = 10.0


@pytest.fixture(scope="module")
def skeleton():
    return Skeleton.from_urdf_string(default_humanoid().urdf)


def _q(skeleton, angles: dict) -> np.ndarray:
    q = skeleton.neutral()
    for name, a in angles.items():
        q[skeleton.joint_index(name)] = a
    return q


@pytest.fixture(scope="module")
def meshes(skeleton):
    """pose name -> (vertices [m], triangles, q the mesh was built in)."""
    out = {}
    for name, angles in POSES.items():
        q = _q(skeleton, angles)
        mesh = smooth_jelly_man_mesh(default_humanoid(), target_tets=3000, q=q)
        out[name] = (mesh.vertices, boundary_triangles(mesh), q)
    return out


def _bone_angles(skeleton, qa, qb) -> dict[str, float]:
    sa, ea = skeleton.bone_segments(qa)
    sb, eb = skeleton.bone_segments(qb)
    out = {}
    for b, n in enumerate(skeleton.bone_names):
        if n.split("_", 1)[-1] in LIMB_BONES:
            da, db = ea[b] - sa[b], eb[b] - sb[b]
            out[n] = float(np.degrees(np.arccos(np.clip(da @ db / np.linalg.norm(da) / np.linalg.norm(db), -1, 1))))
    return out


@pytest.mark.parametrize("name", list(POSES))
def test_the_limbs_of_a_t_and_an_a_pose_mesh_are_found_and_the_skeleton_turned_onto_them(skeleton, meshes, name):
    vertices, triangles, q_mesh = meshes[name]
    rest = skeleton.neutral()
    roles = label_skeleton(skeleton, rest)
    limbs = ab.skeleton_limbs(roles, *skeleton.bone_segments(rest))
    pose = ab.mesh_pose(vertices, triangles, limbs, declared_forward=np.array([1.0, 0.0, 0.0]))
    assert pose.describe().startswith(f"the mesh stands in {'a' if name == 'T-pose' else 'an'} {name}: arms"), \
        pose.describe()
    assert pose.forward_by == "the feet" and pose.forward @ [1.0, 0.0, 0.0] > np.cos(np.radians(10))
    A = ab.facing_rotation(pose, roles)
    q = ab.turn_limbs(skeleton, rest, limbs, {k: (A @ pose.limbs[k].upper_dir, A @ pose.limbs[k].lower_dir)
                                              for k in ab.LIMBS})
    before, after = _bone_angles(skeleton, rest, q_mesh), _bone_angles(skeleton, q, q_mesh)
    assert max(after.values()) < TOLERANCE_DEG, after
    if name == "T-pose":                            # the rest's arms hang 60 deg below the T-pose's
        assert min(before[n] for n in ("l_upper_arm", "r_upper_arm")) > 50, before


def test_the_whole_fit_places_the_bones_in_the_middle_of_the_limbs_and_reports_it(skeleton, meshes):
    vertices, triangles, q_mesh = meshes["A-pose"]
    lines = []
    found = ab.auto_bind_pose(skeleton, skeleton.neutral(), vertices, triangles, 1.0, "Z", "X", say=lines.append)
    assert max(_bone_angles(skeleton, found.q, q_mesh).values()) < TOLERANCE_DEG
    assert found.report.startswith("bones from the middle of the mesh's limbs (mean / max): left arm ")
    assert all(mean < 0.06 for mean, _ in found.distances.values()), found.report
    assert abs(found.fit.scale - 1.0) < 0.05 and np.abs(found.fit.offset).max() < 0.05, found.fit.describe()
    assert any("A-pose" in line for line in lines), lines


def test_a_rest_whose_trunk_leans_is_stood_up_before_its_limbs_are_turned(skeleton, meshes, monkeypatch):
    """A rest taken from a capture's frame leans as the motion does there (Bandai Namco's dash: 33 deg). Bound on
    an upright mesh, the trunk is stood up first (straighten_trunk), one line saying so, and the limbs land in the
    middle of the mesh's; left leaning, the shoulders and hips stand off the mesh's and so do the limbs turned
    from them."""
    vertices, triangles, q_mesh = meshes["A-pose"]
    rest = _q(skeleton, {"abdomen_pitch": 0.45, "chest_pitch": 0.45})            # bent forward, as in a run
    roles = label_skeleton(skeleton, rest)
    assert min(ab.trunk_lean(skeleton, rest, roles)) > 20.0
    lines = []
    found = ab.auto_bind_pose(skeleton, rest, vertices, triangles, 1.0, "Z", "X", say=lines.append)
    assert max(ab.trunk_lean(skeleton, found.q, roles)) < 3.0
    assert any(line.startswith("the skeleton's trunk leans ") and "stood up as the mesh stands" in line
               for line in lines), lines
    assert max(_bone_angles(skeleton, found.q, q_mesh).values()) < TOLERANCE_DEG
    assert all(mean < 0.06 for mean, _ in found.distances.values()), found.report
    monkeypatch.setattr(ab, "straighten_trunk", lambda sk, q, roles: q.copy())
    leaning = ab.auto_bind_pose(skeleton, rest, vertices, triangles, 1.0, "Z", "X")
    assert max(mean for mean, _ in leaning.distances.values()) > 0.08, leaning.report


def test_a_rest_that_stands_keeps_its_trunk(skeleton, meshes):
    """A rig's zero pose (upright within TRUNK_LEAN) keeps its trunk's joints as they are, and no line is said."""
    vertices, triangles, _ = meshes["A-pose"]
    rest = _q(skeleton, {"abdomen_pitch": 0.1})
    roles = label_skeleton(skeleton, rest)
    assert 3.0 < ab.trunk_lean(skeleton, rest, roles)[0] < ab.TRUNK_LEAN
    lines = []
    found = ab.auto_bind_pose(skeleton, rest, vertices, triangles, 1.0, "Z", "X", say=lines.append)
    trunk = [skeleton.joint_index(n) for n in ("root_yaw", "root_pitch", "root_roll", "abdomen_yaw", "abdomen_pitch",
                                               "abdomen_roll", "chest_yaw", "chest_pitch", "chest_roll")]
    assert np.array_equal(found.q[trunk], rest[trunk])
    assert not any("trunk leans" in line for line in lines), lines


def test_toes_out_of_the_foot_are_left_unbound_and_a_leg_swung_out_is_not(skeleton, meshes):
    vertices, triangles, q_mesh = meshes["T-pose"]
    q = q_mesh.copy()
    q[skeleton.joint_index("l_toe_pitch")] = -1.4            # the left toes bent up, out of the foot's flesh
    q[skeleton.joint_index("r_hip_roll")] = -0.6             # the right leg swung out of its flesh
    starts, ends = skeleton.bone_segments(q)
    outside = dict(zip(skeleton.bone_names, bone_outside_distances(vertices, triangles, starts, ends)))
    assert outside["l_toes"] > ab.UNBIND_MARGIN and outside["r_thigh"] > 0.05, outside
    # the swung leg's toes are out with it; its thigh, shin and foot are out too but carry the leg's flesh
    assert ab.bones_to_unbind(label_skeleton(skeleton, q), outside) == ["l_toes", "r_toes"]
    assert min(outside[n] for n in ("r_thigh", "r_shin", "r_foot")) > ab.UNBIND_MARGIN, outside
    at_rest = dict(zip(skeleton.bone_names, bone_outside_distances(vertices, triangles,
                                                                    *skeleton.bone_segments(q_mesh))))
    assert ab.bones_to_unbind(label_skeleton(skeleton, q_mesh), at_rest) == [], at_rest


def test_a_skeleton_whose_head_ends_short_has_its_limbs_traced_on_a_mesh_sized_by_its_hips(skeleton, meshes):
    """The mesh sized by a skeleton that ends at its shoulders (as a rig whose head end site stops short of the crown
    looks) is too small for the skeleton's legs: grown about its centre until the hips stand HIP_RATIO of its
    height above the soles; a mesh sized by the whole skeleton is left as it is (its hips stand lower)."""
    from clusterfem_ros.body.fit import fit_mesh
    vertices, _, _ = meshes["A-pose"]
    rest = skeleton.neutral()
    starts, ends = skeleton.bone_segments(rest)
    roles = label_skeleton(skeleton, rest)
    limbs = ab.skeleton_limbs(roles, starts, ends)
    whole = fit_mesh(vertices, starts, ends, "auto", 1.0, "Z", "X")
    assert ab._trace_size(whole, vertices, starts, ends, limbs) == (whole, "")
    body = [b for b, r in enumerate(roles.roles) if r not in ("head", "neck")]
    short = fit_mesh(vertices, starts[body], ends[body], "auto", 1.0, "Z", "X")
    grown, why = ab._trace_size(short, vertices, starts, ends, limbs)
    x = grown.apply(vertices)
    hips = np.mean([limbs[(side, "leg")].root[2] for side in "lr"]) - np.vstack([starts, ends])[:, 2].min()
    assert hips / np.ptp(x[:, 2]) == pytest.approx(ab.HIP_RATIO, rel=1e-9)
    assert grown.scale > 1.05 * short.scale and "times larger" in why, why
    centre = short.inverse(0.5 * (short.apply(vertices).min(axis=0) + short.apply(vertices).max(axis=0)))
    assert grown.apply(centre[None]) == pytest.approx(short.apply(centre[None]))


def test_a_hand_that_ends_at_the_palm_is_traced_at_a_humans_hand_length(skeleton):
    """The wrist ring is sought the hand's length from the fingertip: a rig whose hand bone ends at the palm
    (Bandai Namco's: 5 cm, a fifth of its forearm) would put it in the fingers; a hand is taken at least
    HAND_FOREARM of the forearm, the feet as they are."""
    rest = skeleton.neutral()
    starts, ends = skeleton.bone_segments(rest)
    roles = label_skeleton(skeleton, rest)
    hands = [b for b, r in enumerate(roles.roles) if r == "hand"]
    palm = ends.copy()
    palm[hands] = starts[hands] + 0.2 * (ends[hands] - starts[hands])      # the hand bones end a fifth of the way
    limbs = ab.skeleton_limbs(roles, starts, palm)
    full = ab.skeleton_limbs(roles, starts, ends)
    for key, limb in limbs.items():
        forearm = np.linalg.norm(limb.end - limb.middle)
        if key[1] == "arm":
            assert limb.tip_length == pytest.approx(ab.HAND_FOREARM * forearm)
        else:
            assert limb.tip_length == full[key].tip_length


def test_a_mesh_lying_along_another_axis_is_refused_naming_its_up_axis(skeleton, meshes):
    vertices, triangles, _ = meshes["T-pose"]
    lying = vertices @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T       # head along -y
    rest = skeleton.neutral()
    limbs = ab.skeleton_limbs(label_skeleton(skeleton, rest), *skeleton.bone_segments(rest))
    with pytest.raises(FitError, match="does not stand along the declared up axis; check skeleton.fit_up"):
        ab.mesh_pose(lying, triangles, limbs, declared_forward=np.array([1.0, 0.0, 0.0]))


def test_a_size_mismatch_names_the_input_whose_height_is_no_humans():
    mesh_wrong = unit_mismatch(mesh_height=17.5, skeleton_height=1.7, unit=0.1)
    assert "the mesh's unit is wrong; set body.surface_unit 0.01 (cm: the mesh 1.75 m tall)" in mesh_wrong
    capture_wrong = unit_mismatch(mesh_height=1.75, skeleton_height=0.068, unit=0.01)
    assert "the capture's unit is wrong; set the player's 'unit' (skeleton.bvh_unit)" in capture_wrong
    both = unit_mismatch(mesh_height=1.75, skeleton_height=0.7, unit=0.01)
    assert "body.surface_unit" in both and "skeleton.bvh_unit" in both


def test_a_skeleton_no_human_stands_in_needs_a_capture_for_its_rest():
    from clusterfem_ros.skeleton.urdf_builder import UrdfBuilder
    b = UrdfBuilder("stick")
    b.link("world", helper=True)
    b.link("lower")
    b.chain("world", "lower", [("lift", "prismatic", (0, 0, 1))])
    b.tip("lower", (0, 0, 0.25))
    with pytest.raises(FitError, match="no human stands in the skeleton's zero pose .* play the capture with --bvh"):
        ab.rest_configuration(Skeleton.from_urdf_string(b.to_string()))


def test_each_bone_knows_the_joints_that_turn_it(skeleton):
    joints = skeleton.bone_joints()
    names = [[skeleton.joint_names[j] for j in js] for js in joints]
    by_bone = dict(zip(skeleton.bone_names, names))
    assert by_bone["l_forearm"] == ["l_elbow_pitch", "l_elbow_yaw"]
    assert by_bone["r_shin"] == ["r_knee_pitch"]
    assert by_bone["l_upper_arm"] == ["l_shoulder_pitch", "l_shoulder_roll", "l_shoulder_yaw"]


def test_bind_pose_auto_builds_any_other_body_in_the_zero_pose(skeleton):
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.scene_build import jelly_bind_pose
    config = SceneConfig().with_values({"skeleton.bind_pose": "auto", "skeleton.source": "robot_description"})
    assert jelly_bind_pose(config, skeleton) is None


def test_a_leaning_rest_traces_the_ankle_at_the_foot_of_the_straighter_shin():
    """_standing_feet: each leg's ankle height (tip_rise) comes from the pose whose shin stands nearer the vertical,
    the arms' and the rest of each limb from the rest."""
    def limb(shin_dir, rise):
        knee = np.array([0.0, 0.0, 0.5])
        return ab.SkeletonLimb(0, 1, np.array([0.0, 0.0, 0.9]), knee, knee + 0.4 * np.asarray(shin_dir), 0.2, 2, rise)
    slanted, vertical = [0.6, 0.0, -0.8], [0.0, 0.0, -1.0]
    rest = {("l", "leg"): limb(slanted, 0.02), ("r", "leg"): limb(vertical, 0.08), ("l", "arm"): limb(slanted, 0.3)}
    upright = {("l", "leg"): limb(vertical, 0.07), ("r", "leg"): limb(slanted, 0.01), ("l", "arm"): limb(vertical, 0.5)}
    out = ab._standing_feet(rest, upright)
    assert out[("l", "leg")].tip_rise == 0.07 and out[("r", "leg")].tip_rise == 0.08
    assert out[("l", "arm")] is rest[("l", "arm")]
    assert np.array_equal(out[("l", "leg")].end, rest[("l", "leg")].end)
