"""Skeleton: FK against hand-computed placements, twists against finite differences, kernel vs pinocchio, errors."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.kinematics import Skeleton, UrdfError, point_velocity

L1, L2 = 0.3, 0.2
# root link "base" (fixed), revolute about z at the origin, a second about y at L1 along x, a tip at L2
TWO_LINK = f"""<robot name="two">
  <link name="base"/>
  <link name="upper"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="lower"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="lower_tip"/>
  <joint name="a" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="b" type="continuous"><parent link="upper"/><child link="lower"/><origin xyz="{L1} 0 0"/>
    <axis xyz="0 1 0"/></joint>
  <joint name="t" type="fixed"><parent link="lower"/><child link="lower_tip"/><origin xyz="{L2} 0 0"/></joint>
</robot>"""


def rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_two_link_placements_and_twists_match_hand_computation():
    sk = Skeleton.from_urdf_string(TWO_LINK)
    assert sk.joint_names == ["a", "b"] and sk.bone_names == ["base", "upper", "lower"]
    assert sk.bone_parent.tolist() == [-1, 0, 1] and sk.revolute_mask().tolist() == [True, True]
    qa, qb, wa, wb = 0.7, -2.9, 1.3, -0.4           # qb beyond pi/2: the continuous joint's (cos, sin) pair
    P = sk.forward(np.array([qa, qb]), np.array([wa, wb]))
    origin_b = np.array([0, 0, 0.1]) + rz(qa) @ np.array([L1, 0, 0])
    np.testing.assert_allclose(P.translation[1], [0, 0, 0.1], atol=1e-15)
    np.testing.assert_allclose(P.translation[2], origin_b, atol=1e-15)
    np.testing.assert_allclose(P.rotation[2], rz(qa) @ ry(qb), atol=1e-15)
    omega_lower = np.array([0, 0, wa]) + rz(qa) @ np.array([0, wb, 0])
    np.testing.assert_allclose(P.twist[1], [0, 0, wa, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(P.twist[2, :3], omega_lower, atol=1e-14)
    np.testing.assert_allclose(P.twist[2, 3:], np.cross([0, 0, wa], origin_b - [0, 0, 0.1]), atol=1e-14)
    s, e = sk.bone_segments(np.array([qa, qb]))
    np.testing.assert_allclose(e[2], origin_b + rz(qa) @ ry(qb) @ [L2, 0, 0], atol=1e-15)   # the tip
    np.testing.assert_allclose(e[1], s[2], atol=1e-15)
    # a point on the lower bone (eq. 7)
    tip_v = point_velocity(P, np.array([2]), e[2:3])[0]
    eps = 1e-6
    e_p = sk.bone_segments(np.array([qa + wa * eps, qb + wb * eps]))[1][2]
    e_m = sk.bone_segments(np.array([qa - wa * eps, qb - wb * eps]))[1][2]
    np.testing.assert_allclose(tip_v, (e_p - e_m) / (2 * eps), atol=1e-8)


def _omega_from_rotations(Rp, Rm, R, eps):
    W = (Rp - Rm) / (2 * eps) @ R.transpose(0, 2, 1)
    return np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)


def test_humanoid_twists_are_derivatives_of_placements_and_kernel_equals_pinocchio():
    sk = Skeleton.from_urdf_string(default_humanoid().urdf)
    rng = np.random.default_rng(7)
    q, v = rng.uniform(-1.5, 1.5, sk.nq), rng.normal(size=sk.nv)
    P = sk.forward(q, v)
    ref = sk.forward_pinocchio(q, v)
    for name in ("rotation", "translation", "twist"):
        np.testing.assert_allclose(getattr(P, name), getattr(ref, name), atol=1e-13, err_msg=name)
    eps = 1e-6
    Pp, Pm = sk.forward(q + eps * v), sk.forward(q - eps * v)
    np.testing.assert_allclose(P.twist[:, 3:], (Pp.translation - Pm.translation) / (2 * eps), atol=1e-7)
    np.testing.assert_allclose(P.twist[:, :3], _omega_from_rotations(Pp.rotation, Pm.rotation, P.rotation, eps),
                               atol=1e-7)
    assert np.abs(np.einsum("bji,bjk->bik", P.rotation, P.rotation) - np.eye(3)).max() < 1e-12


def test_forward_returns_fresh_arrays():
    sk = Skeleton.from_urdf_string(TWO_LINK)
    a = sk.forward(np.array([0.1, 0.2]))
    b = sk.forward(np.array([0.5, 0.6]))
    assert not np.allclose(a.translation, b.translation)


def test_errors_name_the_problem(tmp_path):
    with pytest.raises(UrdfError, match="cannot read URDF file"):
        Skeleton.from_urdf_file(tmp_path / "missing.urdf")
    with pytest.raises(UrdfError, match="not well-formed"):
        Skeleton.from_urdf_string("<robot name='x'><link name='a'></robot>")
    with pytest.raises(UrdfError, match="empty"):
        Skeleton.from_urdf_string("  ")
    floating = TWO_LINK.replace('type="revolute"', 'type="floating"')
    with pytest.raises(NotImplementedError, match="'a' is of type 'floating'.*3 prismatic"):
        Skeleton.from_urdf_string(floating)
    sk = Skeleton.from_urdf_string(TWO_LINK)
    with pytest.raises(ValueError, match=r"joint 'b' position is nan at index 1"):
        sk.forward(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match=r"joint 'a' velocity is inf at index 0"):
        sk.forward(np.zeros(2), np.array([np.inf, 0.0]))
    with pytest.raises(ValueError, match=r"shape \(3,\), expected \(2,\)"):
        sk.forward(np.zeros(3))
    p = tmp_path / "two.urdf"
    p.write_text(TWO_LINK)
    assert Skeleton.from_urdf_file(p).nq == 2


def _pinocchio_link_frames(sk, q, links):
    """(R, p) of the links' BODY frames through pinocchio's own Data (the reference; small robots only)."""
    import pinocchio as pin
    sk._to_pin(q, None)
    data = sk.model.createData()
    pin.forwardKinematics(sk.model, data, sk._q_pin)
    pin.updateFramePlacements(sk.model, data)
    frames = [data.oMf[sk.model.getFrameId(n, pin.BODY)] for n in links]
    return np.array([f.rotation for f in frames]), np.array([f.translation for f in frames])


def _link_placement_robots():
    """(name, URDF text): the two-link arm, the humanoid, and example-robot-data's Panda mounted as a scene does
    (fixed joints to a hand and fingers, links beyond them) when it is installed."""
    from clusterfem_ros.skeleton.mounting import mount_urdf
    from clusterfem_ros.skeleton.robot_data import package_file
    out = [("two_link", TWO_LINK), ("humanoid", default_humanoid().urdf)]
    panda = package_file("package://example-robot-data/robots/panda_description/urdf/panda.urdf")
    if panda is not None:
        out.append(("panda", mount_urdf(panda.read_text()).urdf))
    return out


@pytest.mark.parametrize("name, urdf", _link_placement_robots(), ids=[n for n, _ in _link_placement_robots()])
def test_link_placements_equal_pinocchio_s_frames_on_every_link(name, urdf):
    """Every URDF link (bones, helpers, tips, links on fixed joints, the root) at the rest pose and at a random one:
    the kernel's placements equal pinocchio's oMf to round-off."""
    sk = Skeleton.from_urdf_string(urdf)
    for q in (sk.neutral(), np.random.default_rng(11).uniform(-1.5, 1.5, sk.nq)):
        R, p = sk.link_placements(q, sk.link_names)
        want_R, want_p = _pinocchio_link_frames(sk, q, sk.link_names)
        np.testing.assert_allclose(R, want_R, atol=1e-13, err_msg=name)
        np.testing.assert_allclose(p, want_p, atol=1e-13, err_msg=name)
    with pytest.raises(KeyError, match="no link 'ghost'"):
        sk.link_placements(sk.neutral(), ["ghost"])
    q = sk.neutral()
    q[-1] = np.nan
    with pytest.raises(ValueError, match=f"joint {sk.joint_names[-1]!r} position is nan"):
        sk.link_placements(q, sk.link_names)


def test_pinocchio_s_data_is_refused_past_its_limit_before_it_is_made():
    """Data's size grows with the cube of the joints: pinocchio_data refuses, with one line naming the joint
    count, the size, the limit and the parameter to raise, before anything is allocated; under the limit it is
    made once."""
    from benchmarks.hostile_urdf import star
    from clusterfem_ros.skeleton.kinematics import MAX_DATA_BYTES, data_bytes
    sk = Skeleton.from_urdf_string(star(30))
    with pytest.raises(UrdfError, match=r"pinocchio's Data for 29 joints would take 2 MB, past max_data_bytes = 1 MB"
                                        r".*raise max_data_bytes"):
        sk.forward_pinocchio(sk.neutral(), max_data_bytes=2 ** 20)
    assert sk._data is None
    assert sk.pinocchio_data() is sk.pinocchio_data() is sk.data
    # the largest star the default URDF limits accept (999 joints) would need ~60 GB; real robots stay far below
    assert data_bytes(999) > 100 * MAX_DATA_BYTES and data_bytes(101) < MAX_DATA_BYTES / 3
