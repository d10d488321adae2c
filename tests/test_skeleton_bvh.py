"""BVH reader and BVH -> URDF on the real CMU walk: FK of the URDF equals an independent BVH FK."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.bvh import BvhError, load_bvh, parse_bvh
from clusterfem_ros.skeleton.bvh_to_urdf import bvh_trajectory, bvh_urdf, find_spikes
from clusterfem_ros.skeleton.kinematics import Skeleton
from tests.shared_data import walk_clip

UNIT = 0.056444


@pytest.fixture(scope="module")
def cmu():
    motion = load_bvh(walk_clip())
    return motion, Skeleton.from_urdf_string(bvh_urdf(motion))


def elementary(axis, deg):
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def reference_fk(motion, frame):
    """Straight from the BVH definition, in file units and axes: p_j = p_parent + R_parent offset_j
    (+ position channels at the root), R_j = R_parent * product of the rotation channels in file order."""
    row = motion.frames[frame]
    Rw, pw = [], []
    for j in motion.joints:
        R, t = np.eye(3), j.offset.copy()
        for k, ch in enumerate(j.channels):
            val = row[j.channel_start + k]
            if ch.endswith("position"):
                t["XYZ".index(ch[0])] += val
            else:
                R = R @ elementary(ch[0], val)
        if j.parent < 0:
            Rw.append(R), pw.append(t)
        else:
            Rw.append(Rw[j.parent] @ R), pw.append(pw[j.parent] + Rw[j.parent] @ t)
    return np.array(pw)


def q_at(skeleton, traj, k):
    idx = [traj.names.index(n) for n in skeleton.joint_names]
    return traj.positions[k][idx]


def test_file_facts(cmu):
    motion, sk = cmu
    assert motion.unit_m == UNIT and "unit cmu" in motion.placement          # found from the skeleton
    np.testing.assert_allclose(motion.to_ros, [[0, 0, 1], [1, 0, 0], [0, 1, 0]])   # Y up, walking along +Z
    assert (len(motion.joints), motion.n_channels, motion.n_frames) == (31, 96, 495)
    assert abs(1.0 / motion.frame_time - 120.0) < 0.01
    assert motion.joints[0].channels == ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]
    assert motion.joints[5].end_site is not None                          # LeftToeBase
    assert sk.nq == 96 and set(sk.bone_names) == set(motion.joint_names)


def test_urdf_fk_reproduces_bvh_fk_on_real_frames(cmu):
    motion, sk = cmu
    traj = bvh_trajectory(motion, skip_tpose=False, despike=False, max_rotation_speed=None)   # the file's frames
    C = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]])              # file (x, y, z) -> ROS (z, x, y)
    order = [sk.bone_names.index(n) for n in motion.joint_names]
    for k in (0, 1, 137, 300, 458, 494):                          # incl. the T-pose and a glitch frame
        ref = reference_fk(motion, k) @ C.T * UNIT + motion.root_shift     # the floor under the feet
        got = sk.forward(q_at(sk, traj, k)).translation[order]
        np.testing.assert_allclose(got, ref, atol=1e-9, err_msg=f"frame {k}")


def test_walk_is_plausible_in_ros_axes(cmu):
    motion, sk = cmu
    traj = bvh_trajectory(motion)                                 # T-pose skipped, despiked
    assert traj.positions.shape[0] == motion.n_frames - 1 and traj.times[0] == 0.0
    hips = sk.bone_names.index("Hips")
    p = np.array([sk.forward(q_at(sk, traj, k)).translation[hips] for k in range(0, traj.positions.shape[0], 20)])
    assert np.all(np.abs(p[:, 2] - 1.0) < 0.1), p[:, 2]           # hip height about 1 m
    assert p[-1, 0] - p[0, 0] > 2.0 and np.all(np.diff(p[:, 0]) > 0)   # walks forward along +X
    assert abs(p[-1, 1] - p[0, 1]) < 0.5 * (p[-1, 0] - p[0, 0])
    s, e = sk.bone_segments(q_at(sk, traj, 0))
    foot = sk.bone_names.index("LeftToeBase")
    assert np.linalg.norm(e[foot] - s[foot]) > 0.03 and min(s[:, 2].min(), e[:, 2].min()) < 0.15


def test_unwrapping_and_despiking_leave_no_jump_over_90_degrees(cmu):
    motion, _ = cmu
    spikes = find_spikes(motion)
    assert [(name, f, n) for name, f, n, _ in spikes] == [("LThumb", 458, 3)] and spikes[0][3] > 150
    traj = bvh_trajectory(motion)
    jumps = np.abs(np.diff(traj.positions[:, traj.revolute], axis=0))
    assert np.rad2deg(jumps.max()) < 90.0
    raw = bvh_trajectory(motion, despike=False, max_rotation_speed=None)
    assert np.rad2deg(np.abs(np.diff(raw.positions[:, raw.revolute], axis=0)).max()) > 90.0


MINI = """HIERARCHY\r\nROOT Hips\r\n{\r\n OFFSET 0 0 0\r\n CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\r
 JOINT Leg\r\n {\r\n  OFFSET 0 -2 0\r\n  CHANNELS 3 Zrotation Yrotation Xrotation\r\n  End Site\r\n  {\r\n   OFFSET 0 -3 0\r\n  }\r
 }\r\n}\r\nMOTION\r\nFrames: 2\r\nFrame Time: 0.01\r\n0 10 0 0 0 0 0 0 0\r\n1 10 0 0 0 0 0 0 90\r\n"""


def test_mini_file_crlf_and_malformed_files_name_the_line():
    m = parse_bvh(MINI, unit_m=0.2, floor=False)                 # 5 units: a 1 m skeleton
    assert m.joint_names == ["Hips", "Leg"] and m.n_frames == 2 and m.joints[1].end_site[1] == -3
    with pytest.raises(BvhError, match=r":9: .*'Leg'.*unknown channel 'Zrot'"):
        parse_bvh(MINI.replace("CHANNELS 3 Zrotation", "CHANNELS 3 Zrot"))
    with pytest.raises(BvhError, match=r":20: frame 1 has 8 values, the hierarchy has 9"):
        parse_bvh(MINI.replace("1 10 0 0 0 0 0 0 90", "1 10 0 170 0 0 0 0"))
    with pytest.raises(BvhError, match=r"truncated"):
        parse_bvh(MINI.replace("Frames: 2", "Frames: 3"))
    with pytest.raises(BvhError, match=r":4: expected a number for the OFFSET of 'Hips'"):
        parse_bvh(MINI.replace("OFFSET 0 0 0", "OFFSET 0 x 0"))
    with pytest.raises(BvhError, match="no MOTION"):
        parse_bvh("HIERARCHY\nROOT a\n{\n")
    sk = Skeleton.from_urdf_string(bvh_urdf(m))
    traj = bvh_trajectory(m, skip_tpose=False, max_rotation_speed=None)     # 90 deg in 10 ms, as written
    leg = sk.bone_names.index("Leg")
    s, e = sk.bone_segments(q_at(sk, traj, 1))
    # leg origin: file (1, 10, 0) + (0, -2, 0) -> ROS (0, 1, 8); its end site (0, -3, 0) turned 90 deg about
    # file X is file (0, 0, -3) -> ROS (-3, 0, 0)
    np.testing.assert_allclose(s[leg], np.array([0, 1, 8]) * 0.2, atol=1e-12)
    np.testing.assert_allclose(e[leg] - s[leg], np.array([-3, 0, 0]) * 0.2, atol=1e-12)


# a head whose End Site has no length (LAFAN1 writes OFFSET 0 0 0) and a hand with no End Site at all
LEAVES = """HIERARCHY
ROOT Hips
{
 OFFSET 0 0 0
 CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
 JOINT Neck
 {
  OFFSET 0 50 0
  CHANNELS 3 Zrotation Yrotation Xrotation
  JOINT Head
  {
   OFFSET 0 12 0
   CHANNELS 3 Zrotation Yrotation Xrotation
   End Site
   {
    OFFSET 0 0 0
   }
  }
 }
 JOINT Arm
 {
  OFFSET 20 45 0
  CHANNELS 3 Zrotation Yrotation Xrotation
  JOINT Hand
  {
   OFFSET 25 0 0
   CHANNELS 3 Zrotation Yrotation Xrotation
  }
 }
}
MOTION
Frames: 1
Frame Time: 0.01
0 90 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
"""


def test_a_leaf_bone_without_end_site_length_continues_the_bone_before_it():
    from clusterfem_ros.skeleton.bvh_to_urdf import LEAF_TIP_FRACTION
    m = parse_bvh(LEAVES, unit_m=0.01, floor=False)
    sk = Skeleton.from_urdf_string(bvh_urdf(m))
    s, e = sk.bone_segments(sk.neutral())
    head, hand = sk.bone_names.index("Head"), sk.bone_names.index("Hand")
    neck, arm = sk.bone_names.index("Neck"), sk.bone_names.index("Arm")
    # the neck (12 cm) and the arm (25 cm), each continued for the fraction of its length
    np.testing.assert_allclose(e[head] - s[head], LEAF_TIP_FRACTION * (e[neck] - s[neck]), atol=1e-12)
    np.testing.assert_allclose(e[hand] - s[hand], LEAF_TIP_FRACTION * (e[arm] - s[arm]), atol=1e-12)
    assert np.linalg.norm(e[neck] - s[neck]) == pytest.approx(0.12) and LEAF_TIP_FRACTION > 0
    # an End Site with a length is the tip, as written
    m2 = parse_bvh(LEAVES.replace("    OFFSET 0 0 0", "    OFFSET 0 9 0"), unit_m=0.01, floor=False)
    s2, e2 = Skeleton.from_urdf_string(bvh_urdf(m2)).bone_segments(sk.neutral())
    np.testing.assert_allclose(e2[head] - s2[head], 0.09 / 0.12 * (e[neck] - s[neck]), atol=1e-12)
    # leaves beside each other (Mixamo's HeadTop_End and eyes on the head) mark points of their parent's part
    eyes = LEAVES.replace("   End Site\n   {\n    OFFSET 0 0 0\n   }\n", "   JOINT Top\n   {\n    OFFSET 0 18 0\n"
                          "    CHANNELS 3 Zrotation Yrotation Xrotation\n    End Site\n    {\n     OFFSET 0 0 0\n    }\n   }\n"
                          "   JOINT Eye\n   {\n    OFFSET 3 8 9\n    CHANNELS 3 Zrotation Yrotation Xrotation\n"
                          "    End Site\n    {\n     OFFSET 0 0 0\n    }\n   }\n")
    m3 = parse_bvh(eyes.replace("0 90 0 0 0 0 0 0 0 0 0 0", "0 90 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0"), unit_m=0.01,
                   floor=False)
    sk3 = Skeleton.from_urdf_string(bvh_urdf(m3))
    s3, e3 = sk3.bone_segments(sk3.neutral())
    for name in ("Top", "Eye"):
        b = sk3.bone_names.index(name)
        np.testing.assert_allclose(e3[b], s3[b], atol=1e-12)
