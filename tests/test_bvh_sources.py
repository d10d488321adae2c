"""BVH files as other tools write them (tests/bvh_text.py): units, axes, the root's OFFSET, every Euler order,
representation flips and loops, each checked on the skeleton the player publishes (URDF forward kinematics)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros.skeleton.bvh import BvhError, parse_bvh
from clusterfem_ros.skeleton.bvh_placement import UNITS
from clusterfem_ros.skeleton.bvh_to_urdf import bvh_loop, bvh_trajectory, bvh_urdf, find_spikes
from clusterfem_ros.skeleton.joint_stream import JointStreamInterpolator
from clusterfem_ros.skeleton.kinematics import Skeleton
from tests.bvh_text import HEIGHT, HIP_HEIGHT, human_bvh, rest_motion, skeleton, walk_motion

ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")


def _posed(motion, traj, k):
    """(skeleton, bone starts, bone ends) [m, ROS] of trajectory frame k on the URDF the player publishes."""
    sk = Skeleton.from_urdf_string(bvh_urdf(motion))
    q = np.array([traj.positions[k][traj.names.index(n)] for n in sk.joint_names])
    s, e = sk.bone_segments(q)
    return sk, s, e


def _bone(sk, starts, name):
    return starts[sk.bone_names.index(name)]


@pytest.mark.parametrize("unit", sorted(UNITS))
def test_the_unit_is_found_from_the_skeleton_and_the_body_stands_on_the_floor(unit):
    m = parse_bvh(human_bvh(unit_m=UNITS[unit], prefix="mixamorig:"))
    assert m.unit_m == UNITS[unit] and f"unit {unit} " in m.placement, m.placement
    sk, s, e = _posed(m, bvh_trajectory(m, skip_tpose=False), 0)
    z = np.concatenate([s[:, 2], e[:, 2]])
    assert z.min() == pytest.approx(0.0, abs=1e-9) and z.max() == pytest.approx(HEIGHT, abs=1e-6)
    assert _bone(sk, s, "mixamorig:Hips")[2] == pytest.approx(HIP_HEIGHT, abs=1e-6)
    assert f"{HEIGHT:.2f} m tall" in m.placement and m.unit_name == unit and m.height_m == pytest.approx(HEIGHT)


def test_a_unit_given_is_used_and_a_skeleton_no_unit_makes_human_is_refused():
    cm = human_bvh(unit_m=0.01)
    for given in ("cm", 0.01, "0.01"):
        assert parse_bvh(cm, unit_m=given).unit_m == 0.01
    with pytest.raises(BvhError, match=r"174 m tall in unit m .*'unit' parameter \(the scene's skeleton.bvh_unit\)"):
        parse_bvh(cm, unit_m="m")
    with pytest.raises(ValueError, match="unit 'furlong': give auto, m, cm, mm, inch, cmu"):
        parse_bvh(cm, unit_m="furlong")
    # two 2-unit bones: 4 m in the likeliest unit (m), nothing human: refused, naming the parameter
    tiny = ("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Zrotation Yrotation Xrotation\n JOINT b\n {\n"
            "  OFFSET 0 -2 0\n  CHANNELS 3 Zrotation Yrotation Xrotation\n  End Site\n  {\n   OFFSET 0 -2 0\n  }\n"
            " }\n}\nMOTION\nFrames: 1\nFrame Time: 0.01\n0 0 0 0 0 0\n")
    with pytest.raises(BvhError, match=r"is 4 m tall in unit m .*skeleton.bvh_unit"):
        parse_bvh(tiny)


def test_the_roots_position_channels_are_its_position_and_its_offset_is_not_added():
    """The 22-joint inch file of the issue: root OFFSET at hip height beside position channels that say the
    same; adding both put the feet 0.95 m up. Kept at the file's own height (floor off) the feet are at 0."""
    text = human_bvh(unit_m=0.0254, order="XYZ", root_offset=(0.0, HIP_HEIGHT, 0.0))
    m = parse_bvh(text, floor=False)
    assert m.unit_m == UNITS["inch"] and m.joints[0].offset[1] == pytest.approx(HIP_HEIGHT / 0.0254)
    sk, s, e = _posed(m, bvh_trajectory(m, skip_tpose=False), 0)
    assert min(s[:, 2].min(), e[:, 2].min()) == pytest.approx(0.0, abs=1e-6)
    assert _bone(sk, s, "Hips")[2] == pytest.approx(HIP_HEIGHT, abs=1e-6)
    # a root without position channels stands at its OFFSET
    m = parse_bvh(human_bvh(unit_m=0.01, root_offset=(0.5, HIP_HEIGHT, 0.0), root_channels=False), floor=False)
    sk, s, e = _posed(m, bvh_trajectory(m, skip_tpose=False), 0)
    np.testing.assert_allclose(_bone(sk, s, "Hips"), [0.0, 0.5, HIP_HEIGHT], atol=1e-9)


def test_z_up_and_y_up_files_stand_up_and_walk_forward():
    """A 3ds-Max biped file (Z up, facing -Y, ZXY channels, cm, thighs on the spine) and a Mixamo-like one (Y up)
    walking: both stand along ROS z (head over hips over feet) and walk along ROS +x."""
    for kw in (dict(rig="max", up="Z", order="ZXY"), dict(prefix="mixamorig:")):
        rig = kw.get("rig", "human")
        m = parse_bvh(human_bvh(walk_motion(rig=rig), unit_m=0.01, **kw))
        tr = bvh_trajectory(m, skip_tpose=False)
        names = [j[0] for j in skeleton(rig)]
        head, hips, foot = (kw.get("prefix", "") + names[i] for i in (
            names.index("Bip01_Head" if rig == "max" else "Head"), 0,
            names.index("Bip01_L_Foot" if rig == "max" else "LeftFoot")))
        sk, s0, _ = _posed(m, tr, 0)
        _, s1, _ = _posed(m, tr, tr.times.size - 1)
        assert _bone(sk, s0, head)[2] > _bone(sk, s0, hips)[2] + 0.4 > _bone(sk, s0, foot)[2] + 0.8, m.placement
        walked = _bone(sk, s1, hips) - _bone(sk, s0, hips)
        assert walked[0] > 2.0 and abs(walked[1]) < 0.1 * walked[0], (walked, m.placement)
    m = parse_bvh(human_bvh(rig="max", up="Z"), up="Y")           # an axis given is used as it is
    np.testing.assert_allclose(m.to_ros[2], [0, 1, 0])


@pytest.mark.parametrize("order", ORDERS)
def test_every_channel_order_gives_scipys_rotation_on_the_published_skeleton(order):
    """Random joint rotations written in ``order`` (scipy's intrinsic convention, the BVH one): the URDF's forward
    kinematics equals the composition of the rotations themselves, for every bone."""
    rng = np.random.default_rng(ORDERS.index(order))
    root, rot = rest_motion(frames=4)
    rot = {name: Rotation.random(4, random_state=rng) for name in rot}
    m = parse_bvh(human_bvh((root, rot), unit_m=0.01, order=order), floor=False)
    assert all(j.channels[-3:] == [f"{a}rotation" for a in order] for j in m.joints)
    tr = bvh_trajectory(m, skip_tpose=False, despike=False, max_rotation_speed=None)
    C = m.to_ros
    for k in range(4):
        world, pos = {}, {}
        for name, parent, off, _ in skeleton():
            if parent is None:
                world[name], pos[name] = rot[name][k], root[k]
            else:
                world[name] = world[parent] * rot[name][k]
                pos[name] = pos[parent] + world[parent].apply(off)
        sk, s, _ = _posed(m, tr, k)
        for name in pos:
            np.testing.assert_allclose(_bone(sk, s, name), C @ pos[name], atol=1e-9, err_msg=f"{order} {name} {k}")


def _flipping_clip(flip: bool):
    motion = walk_motion(frames=60, fps=120.0)
    twin = np.zeros((60, len(skeleton())), bool)
    if flip:
        twin[10:14] = twin[30:31] = twin[40:] = True            # every joint's triple flips, back and for good
    return parse_bvh(human_bvh(motion, unit_m=0.01, twin=twin, fps=120.0))


def test_a_flip_between_equivalent_euler_triples_is_no_jump_and_no_glitch():
    """Style captures whose channels flip to the other triple of the same rotation (the issue: 'moved 3.12 in
    0.00823 s ... dropped as a capture glitch'): the joint stream stays continuous and exact."""
    flipped, plain = _flipping_clip(True), _flipping_clip(False)
    assert np.abs(np.diff(flipped.frames, axis=0)).max() > 170               # the file jumps
    assert find_spikes(flipped) == find_spikes(plain) == []                   # rotations compared, not channels
    tf = bvh_trajectory(flipped, skip_tpose=False)
    tp = bvh_trajectory(plain, skip_tpose=False)
    rev = tf.revolute
    assert np.rad2deg(np.abs(np.diff(tf.positions[:, rev], axis=0)).max()) < 5       # a 120 fps walk's own steps
    for k in range(60):                                                           # the same skeleton poses
        _, s_f, e_f = _posed(flipped, tf, k)
        _, s_p, e_p = _posed(plain, tp, k)
        np.testing.assert_allclose(np.hstack([s_f, e_f]), np.hstack([s_p, e_p]), atol=1e-9)
    stream = JointStreamInterpolator(tf.names, tf.revolute, max_joint_speed=300.0)
    problems = [kind for k in range(60) for kind, _ in stream.push(k / 120, tf.positions[k])]
    assert problems == []
    raw = JointStreamInterpolator(tf.names, tf.revolute, max_joint_speed=300.0)    # the channels as written
    cols = [j.channel_start + c for j in flipped.joints for c in range(len(j.channels))]
    written = np.where(rev, np.deg2rad(flipped.frames[:, cols]), flipped.frames[:, cols] * 0.01)
    assert any(kind == "joint_speed" for k in range(60) for kind, _ in raw.push(k / 120, written[k]))
    # the node's stream knows the skeleton's ball joints: it compares rotations and stores the nearest triple
    sk = Skeleton.from_urdf_string(bvh_urdf(flipped))
    order = [tf.names.index(n) for n in sk.joint_names]
    node = JointStreamInterpolator(sk.joint_names, sk.revolute_mask(), max_joint_speed=300.0, balls=sk.ball_joints())
    assert len(sk.ball_joints()[0]) == len(flipped.joints)
    assert [kind for k in range(60) for kind, _ in node.push(k / 120, written[k][order])] == []
    np.testing.assert_allclose(node.sample(59 / 120)[0], tf.positions[59][order], atol=1e-9)


def test_a_real_spike_is_still_found_by_its_rotation():
    motion = walk_motion(frames=60)
    root, rot = motion
    rot = dict(rot)
    bad = rot["LeftLeg"].as_rotvec()
    bad[20:22] = [np.pi * 0.9, 0, 0]
    rot["LeftLeg"] = Rotation.from_rotvec(bad)
    m = parse_bvh(human_bvh((root, rot), unit_m=0.01))
    assert [(name, f, n) for name, f, n, _ in find_spikes(m)] == [("LeftLeg", 20, 2)]


def _root_frame(tr, m, t, loop=True):
    """(hips position [m, file axes], hips rotation in file axes) at time t of a trajectory."""
    q = tr.sample(t, loop=loop)[0]
    root = m.joints[0]
    rot = [c for c in root.channels if c.endswith("rotation")]
    R = Rotation.from_euler("".join(c[0] for c in rot), [q[tr.names.index(f"{root.name}_{c[0]}rot")] for c in rot])
    p = np.array([q[tr.names.index(f"{root.name}_{a}pos")] for a in "XYZ"])
    return p, R


def _pose_steps(tr, m, times, loop):
    """Per BVH joint, the largest rotation step [rad] between consecutive times; last, the root's largest step [m]."""
    q = np.array([tr.sample(t, loop=loop)[0] for t in times])
    out = []
    for j in m.joints:
        rot = [c for c in j.channels if c.endswith("rotation")]
        R = Rotation.from_euler("".join(c[0] for c in rot), q[:, [tr.names.index(f"{j.name}_{c[0]}rot") for c in rot]])
        out.append((R[:-1].inv() * R[1:]).magnitude().max())
    p = q[:, [tr.names.index(f"{m.joints[0].name}_{a}pos") for a in "XYZ"]]
    return np.array(out + [np.linalg.norm(np.diff(p, axis=0), axis=1).max()])


def test_a_clip_that_ends_facing_away_loops_on_facing_away_upright_and_walking():
    """A walk turning 180 deg about up over its 3 s (the issue's CMU clip ending turned round): looped, each loop
    starts where and as the last ended (turned on by another 180 deg, further along), every joint crosses the
    seam no faster than it moves in the clip, and the body stays upright (never laid flat)."""
    m = parse_bvh(human_bvh(walk_motion(frames=91, turn_deg=180.0), unit_m=0.01))
    tr = bvh_loop(m, bvh_trajectory(m, skip_tpose=False), 0.5)
    T, dt = tr.duration, 1 / 240
    up = np.array([0.0, 1.0, 0.0])
    for k in (1, 2, 3):
        (p0, R0), (p1, R1) = _root_frame(tr, m, k * T - 1e-9), _root_frame(tr, m, k * T + 1e-9)
        np.testing.assert_allclose(p1, p0, atol=1e-6)
        assert (R0.inv() * R1).magnitude() < 1e-6
    # the heading turns on: halfway through loop 1 the hips face opposite to halfway through loop 0
    _, Ra = _root_frame(tr, m, 0.5 * T)
    _, Rb = _root_frame(tr, m, 1.5 * T)
    assert np.rad2deg((Rb * Ra.inv()).magnitude()) == pytest.approx(180.0, abs=1.0)
    pa, pb, pc = (_root_frame(tr, m, t)[0] for t in (0.0, T, 2 * T))
    assert np.linalg.norm((pb - pa)[[0, 2]]) > 2.0 and np.linalg.norm((pc - pb)[[0, 2]]) > 2.0   # walks on
    # every joint's rotation step and the root's position step across three seams against the clip's own
    steps = _pose_steps(tr, m, np.arange(0.2 * T, 3.2 * T, dt), loop=True)
    own = _pose_steps(tr, m, np.arange(0.02 * T, 0.78 * T, dt), loop=False)
    assert (steps <= 1.5 * own + 1e-4).all(), (steps, own)
    tilt = [np.rad2deg(np.arccos(_root_frame(tr, m, t)[1].apply(up) @ up)) for t in np.arange(0, 3 * T, 0.02)]
    assert max(tilt) < 10.0                                  # the clip's hips rock by 5 deg; never lying down


def test_the_node_stream_still_drops_a_real_turn_too_fast_for_a_limb():
    """A thigh turned 170 deg in one 120 Hz frame (a rotation, not another triple of it): dropped, named."""
    m = _flipping_clip(False)
    tr = bvh_trajectory(m, skip_tpose=False)
    sk = Skeleton.from_urdf_string(bvh_urdf(m))
    q0 = np.array([tr.positions[0][tr.names.index(n)] for n in sk.joint_names])
    stream = JointStreamInterpolator(sk.joint_names, sk.revolute_mask(), max_joint_speed=300.0, balls=sk.ball_joints())
    assert stream.push(0.0, q0) == []
    q1 = q0.copy()
    q1[sk.joint_names.index("LeftUpLeg_Xrot")] += np.deg2rad(170.0)
    (kind, text), = stream.push(1 / 120, q1)
    assert kind == "joint_speed" and "ball joint LeftUpLeg_Zrot/LeftUpLeg_Yrot/LeftUpLeg_Xrot turned 2.967" in text


def test_a_sender_flipping_euler_triples_neither_loses_samples_nor_tears_the_body():
    """The node's path (Scene): joint states carrying the file's flipping channels as they are (a publisher that
    does not make them continuous) are all taken, and the jelly body on the capture's skeleton never resets."""
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.fem.stability import DivergenceError
    from clusterfem_ros.scene import Scene
    m = _flipping_clip(True)
    tr = bvh_trajectory(m, skip_tpose=False)
    cols = [j.channel_start + c for j in m.joints for c in range(len(j.channels))]
    written = np.where(tr.revolute, np.deg2rad(m.frames[:, cols]), m.frames[:, cols] * m.unit_m)
    scene = Scene.build(SceneConfig().with_values({"skeleton.source": "robot_description", "body.target_tets": 1500}),
                        urdf_xml=bvh_urdf(m))
    kinds, resets = [], 0
    for k in range(60):
        kinds += [kind for kind, _ in scene.push_joint_state(10.0 + k / 120, tr.names, written[k])]
        try:
            scene.advance_to(10.0 + k / 120)
        except DivergenceError:
            resets += 1
            scene.reset()
    assert kinds == [] and resets == 0


def test_the_scenes_bvh_unit_reaches_the_player_and_the_player_says_it_was_given(tmp_path):
    from clusterfem_ros.config import SceneConfig, load_scene_file, scene_file_text
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.nodes.demo import _arguments, _player_plan
    clip = tmp_path / "clip.bvh"
    clip.write_text(human_bvh(unit_m=0.0254))
    scene = tmp_path / "s.yaml"
    scene.write_text(scene_file_text(SceneConfig().with_values({"skeleton.bvh_unit": "mm"})))
    player, _ = _player_plan(_arguments(["--bvh", str(clip), "--scene", str(scene)]), scene, load_scene_file(scene))
    assert player["unit"] == "mm" and player["up"] == "auto"
    with pytest.raises(BvhError, match="0.0685 m tall in unit mm"):      # an inch file read as mm: refused
        load_motion("bvh", player["file"], unit=player["unit"], up=player["up"])
    m = load_motion("bvh", clip, unit="inch")
    assert "unit inch (0.0254 m per file unit, given)" in m.placement and m.capture.unit_m == 0.0254
    from clusterfem_ros.config import ConfigError
    assert SceneConfig().with_values({"skeleton.bvh_unit": 0.0254})["skeleton.bvh_unit"] == "0.0254"
    with pytest.raises(ConfigError, match="skeleton.bvh_unit: unit 'furlong': give auto, m, cm"):
        SceneConfig().with_values({"skeleton.bvh_unit": "furlong"})


def test_a_prepended_t_pose_is_skipped_and_a_first_captured_frame_is_kept():
    """The CMU conversions prepend a T-pose to the capture; other files start with motion."""
    root, rot = walk_motion(frames=40)
    assert bvh_trajectory(parse_bvh(human_bvh((root, rot), unit_m=0.01))).times.size == 40
    rest_root, rest_rot = rest_motion(frames=1)
    tposed = (np.vstack([rest_root, root]), {n: Rotation.concatenate([rest_rot[n], rot[n]]) for n in rot})  # arms out
    tr = bvh_trajectory(parse_bvh(human_bvh(tposed, unit_m=0.01)))
    assert tr.times.size == 40 and tr.times[0] == 0.0
