"""Joint values against the URDF (skeleton/joint_limits.py through JointMap, then a scene): limited joints
within their range and margin, angles wrapped, mimic joints following their master, refusals counted."""
from __future__ import annotations

import numpy as np
import pytest

from clusterfem_ros.skeleton.joint_limits import LIMIT_FLOOR, JointLimits, joint_limits
from clusterfem_ros.skeleton.joint_map import JointMap
from clusterfem_ros.skeleton.kinematics import Skeleton

_INERTIAL = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
             '</inertial>')


def _joint(name, kind, parent, child, limit="", extra=""):
    lim = f'<limit lower="{limit[0]}" upper="{limit[1]}" effort="1" velocity="1"/>' if limit else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>{lim}{extra}</joint>')


ARM = ('<robot name="arm">' + "".join(f'<link name="{n}">{_INERTIAL}</link>' for n in
                                      ("base", "upper", "fore", "wheel", "disc", "finger1", "finger2", "tool")) +
       _joint("elbow", "revolute", "base", "upper", (-1.0, 2.0)) +
       _joint("spin", "revolute", "upper", "fore", (-np.pi, np.pi)) +
       _joint("wheel", "continuous", "fore", "wheel") +
       _joint("disc", "revolute", "wheel", "disc", (-1e4, 1e4)) +
       _joint("finger1", "prismatic", "fore", "finger1", (0.0, 0.04)) +
       _joint("finger2", "prismatic", "fore", "finger2", (-0.04, 0.0),
              '<mimic joint="finger1" multiplier="-1" offset="0"/>') +
       _joint("tool", "fixed", "fore", "tool") + "</robot>")
MARGIN = 0.05


@pytest.fixture(scope="module")
def arm():
    sk = Skeleton.from_urdf_string(ARM)
    return sk, joint_limits(ARM, sk.joint_names, MARGIN)


def test_limits_read_from_the_urdf(arm):
    sk, lim = arm
    assert "tool" not in sk.joint_names                       # fixed: no value to check
    i = {n: k for k, n in enumerate(sk.joint_names)}
    assert (lim.lower[i["elbow"]], lim.upper[i["elbow"]]) == pytest.approx((-1.0 - 0.15, 2.0 + 0.15))
    assert (lim.lower[i["finger1"]], lim.upper[i["finger1"]]) == pytest.approx((-0.002, 0.042))
    assert lim.wrap[[i["spin"], i["wheel"], i["disc"]]].all() and not lim.wrap[i["elbow"]]
    assert lim.mimic == ((i["finger2"], i["finger1"], -1.0, 0.0),)


def test_out_of_range_values_are_refused_and_keep_the_last_value(arm):
    sk, lim = arm
    jm = JointMap(sk.joint_names, limits=lim)
    r = jm.update(["elbow", "finger1"], [1.5, 0.03])
    assert r.accepted and r.problems == []
    for bad in (2.0 + 0.15 * 1.01, -1e308, 1e308):
        r = jm.update(["elbow", "finger1"], [bad, 0.02])
        (kind, text), = r.problems
        assert kind == "joint_range" and "'elbow'" in text and "input.joint_limit_margin" in text
        assert r.q[sk.joint_index("elbow")] == 1.5 and r.q[sk.joint_index("finger1")] == 0.02
    r = jm.update(["elbow"], [2.0 + 0.15 * 0.99])                 # within the margin: taken
    assert r.accepted and r.problems == []
    r = jm.update(["finger1"], [1.0])                            # the only joint refused: nothing taken
    assert not r.accepted and r.problems[0][0] == "joint_range"
    r = jm.update(["elbow"], [np.nan])                           # non-finite: its own kind, as before
    assert r.problems[0][0] == "non_finite"


def test_angles_of_full_turn_and_continuous_joints_are_wrapped(arm):
    sk, lim = arm
    jm = JointMap(sk.joint_names, limits=lim)
    for value in (1e15, -7.0, 1e308, 3.5, 1234.5):
        r = jm.update(["spin", "wheel", "disc"], [value] * 3)
        assert r.accepted and r.problems == []
        got = r.q[[sk.joint_index(n) for n in ("spin", "wheel", "disc")]]
        assert ((got >= -np.pi) & (got < np.pi)).all()
        # the same rotation, up to the float 2 pi's own error (4e-17 of the angle): a 1e15 rad yaw has no
        # meaningful direction, only a bounded one
        tol = 1e-12 + 1e-16 * abs(value)
        np.testing.assert_allclose(np.cos(got), np.cos(value), atol=tol) if abs(value) < 1e6 else None
        np.testing.assert_allclose(np.sin(got), np.sin(value), atol=tol) if abs(value) < 1e6 else None


def test_a_mimic_joint_follows_its_master_unless_named(arm):
    sk, lim = arm
    jm = JointMap(sk.joint_names, limits=lim)
    f1, f2 = sk.joint_index("finger1"), sk.joint_index("finger2")
    r = jm.update(["finger1", "elbow"], [0.03, 0.1], [0.2, 0.5])
    assert r.q[f2] == pytest.approx(-0.03) and r.updated[f2]
    r = jm.update(sk.joint_names[:f2] + sk.joint_names[f2 + 1:], np.zeros(sk.nq - 1), np.r_[np.zeros(f1), 0.2,
                                                                                           np.zeros(sk.nq - 2 - f1)])
    assert r.v is not None and r.v[f2] == pytest.approx(-0.2)   # every joint set: velocities, the mimic's too
    r = jm.update(["finger1", "finger2"], [0.01, -0.02])          # named: taken as sent, checked on its own range
    assert r.q[f2] == -0.02
    r = jm.update(["finger2"], [0.5])
    assert r.problems[0][0] == "joint_range" and "'finger2'" in r.problems[0][1]


def test_the_root_s_joints_are_wrapped_and_left_to_max_root_distance():
    """Decided from the tree: the joints with no bone above them move the root (here the free root the mounting
    adds); their angles wrap whatever their URDF limits, their translations have no URDF range (the joint
    stream's input.max_root_distance bounds them, a limit users raise)."""
    from clusterfem_ros.skeleton.mounting import FREE_ROOT, mount_urdf
    sk = Skeleton.from_urdf_string(mount_urdf(ARM, root_joint="free").urdf)
    root = sk.root_joint_mask()
    assert sorted(np.asarray(sk.joint_names)[root]) == sorted(n for n, _, _ in FREE_ROOT)
    lim = joint_limits(sk.urdf, sk.joint_names, MARGIN, root)
    r = JointMap(sk.joint_names, limits=lim).update(["root_x", "root_yaw", "elbow"], [5e3, 1e15, 0.5])
    assert r.accepted and r.problems == []
    assert r.q[sk.joint_index("root_x")] == 5e3 and -np.pi <= r.q[sk.joint_index("root_yaw")] < np.pi


def test_without_limits_the_map_takes_values_as_before():
    jm = JointMap(["a", "b"], limits=JointLimits.none(2))
    r = jm.update(["a", "b"], [1e300, -5.0])
    assert r.accepted and r.q.tolist() == [1e300, -5.0]
    assert LIMIT_FLOOR < 1e-6


def test_a_scene_counts_refused_joint_values_and_never_diverges_on_them():
    """Issue 37: a root yaw of 1e15 rad or 1e308 rad on a revolute joint drove the body into repeated divergence
    resets. Now the limited joint's value is refused (joint_range) and the yaw wrapped, then refused as a jump."""
    from clusterfem_ros.config import from_mapping
    from clusterfem_ros.scene import Scene
    scene = Scene.build(from_mapping({"skeleton.source": "robot_description", "skeleton.root_joint": "free",
                                      "body.target_tets": 300, "warping": False, "body.bone_radius": 0.03}),
                        urdf_xml=ARM)
    names = scene.skeleton.joint_names
    t = 1.0
    q = np.zeros(len(names))
    for k in range(200):
        t += 0.005
        q[names.index("elbow")] = 0.3 * np.sin(4 * t)
        sent = q.copy()
        if k % 20 == 5:
            sent[names.index("root_yaw")] = 1e15
        if k % 20 == 10:
            sent[names.index("elbow")] = 1e308
        scene.push_joint_state(t, names, sent, now=t)
        scene.advance_to(t)                     # raises DivergenceError on a diverged state
    # the elbow's 1e308 refused by its range; the yaw's 1e15, wrapped to a bounded angle, is then a jump no
    # body turns in 5 ms: the stream refuses it as a glitch (joint_speed)
    assert scene.inputs.rejected == {"joint_range": 10, "joint_speed": 10}
    assert scene.inputs.accepted == 190
    assert np.isfinite(scene.positions()).all()
