"""Trajectories, key-frame files and the built-in walk: interpolation, unwrapping, periodicity, errors."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.keyframes import (KeyframeError, example_path, load_keyframes, parse_keyframes_csv,
                                               parse_keyframes_yaml)
from clusterfem_ros.skeleton.kinematics import Skeleton
from clusterfem_ros.skeleton.procedural_walk import gait_period, procedural_walk
from clusterfem_ros.skeleton.trajectory import JointTrajectory


def test_trajectory_unwraps_and_interpolates_through_pi():
    a = np.deg2rad([170.0, -170.0, -150.0])
    tr = JointTrajectory([0.0, 1.0, 2.0], ["yaw", "x"], np.column_stack([a, [0.0, 1.0, 3.0]]),
                         revolute=[True, False], interpolation="linear")
    q, v = tr.sample(0.5)
    np.testing.assert_allclose(np.cos(q[0]), -1.0, atol=1e-12)               # via 180 deg
    np.testing.assert_allclose(v, [np.deg2rad(20.0), 1.0])
    np.testing.assert_allclose(tr.sample(1.5)[0][1], 2.0)
    np.testing.assert_array_equal(tr.sample(5.0)[1], 0.0)                    # held after the end
    np.testing.assert_allclose(tr.sample(5.0)[0][1], 3.0)


def test_catmull_rom_passes_through_samples_and_its_velocity_is_the_derivative():
    t = np.linspace(0, 2, 21)
    tr = JointTrajectory(t, ["a"], np.sin(3 * t)[:, None])
    np.testing.assert_allclose([tr.sample(x)[0][0] for x in t[:-1]], np.sin(3 * t[:-1]), atol=1e-14)
    for x in (0.33, 1.01, 1.77):
        eps = 1e-6
        fd = (tr.sample(x + eps)[0] - tr.sample(x - eps)[0]) / (2 * eps)
        np.testing.assert_allclose(tr.sample(x)[1], fd, atol=1e-6)
        assert abs(tr.sample(x)[0][0] - np.sin(3 * x)) < 2e-3                 # a good interpolant of sin
    r = tr.resample(50.0)
    assert r.times.size == 101 and abs(r.duration - tr.duration) < 1e-12
    with pytest.raises(ValueError, match="times must increase: sample 2"):
        JointTrajectory([0.0, 1.0, 1.0], ["a"], np.zeros((3, 1)))


@pytest.fixture(scope="module")
def humanoid():
    return Skeleton.from_urdf_string(default_humanoid().urdf)


def test_walk_is_periodic_continuous_and_moves_forward(humanoid):
    speed = 1.2
    T = gait_period(speed)
    tr = procedural_walk(2 * T, rate_hz=200, speed=speed)
    assert tr.names == humanoid.joint_names and abs(tr.duration - 2 * T) < 1e-12
    ix = tr.names.index("root_x")
    for t in (0.05, 0.31, 0.77):
        q0, v0 = tr.sample(t)
        q1, v1 = tr.sample(t + T)
        shift = np.zeros(tr.n_joints)
        shift[ix] = speed * T
        np.testing.assert_allclose(q1, q0 + shift, atol=1e-9)               # one gait cycle later: same pose
        np.testing.assert_allclose(v1, v0, atol=1e-6)
    # looping past the end continues seamlessly
    np.testing.assert_allclose(tr.sample(2 * T + 0.1, loop=True)[0], tr.sample(0.1)[0] + 2 * shift, atol=1e-9)
    # continuity: no jump in q or v between fine samples, and v is the derivative of q
    ts = np.linspace(0, 2 * T, 2001)
    Q = np.array([tr.sample(t)[0] for t in ts])
    V = np.array([tr.sample(t)[1] for t in ts[1:-1]])
    dt = ts[1] - ts[0]
    assert np.abs(np.diff(Q, axis=0)).max() < 20 * dt
    np.testing.assert_allclose(V, (Q[2:] - Q[:-2]) / (2 * dt), atol=0.05)
    assert np.abs(np.diff(V, axis=0)).max() < 0.2                            # C1: no velocity jumps
    # the walker advances at the requested speed and keeps a foot near the ground
    P0, P1 = humanoid.forward(*tr.sample(0.0)), humanoid.forward(*tr.sample(T))
    assert abs((P1.translation[0, 0] - P0.translation[0, 0]) - speed * T) < 1e-9
    feet = [humanoid.bone_names.index(n) for n in ("l_foot", "r_foot", "l_toes", "r_toes")]
    lowest = [min(humanoid.bone_segments(q)[0][feet, 2].min(), humanoid.bone_segments(q)[1][feet, 2].min())
              for q in Q[::100]]
    assert max(lowest) < 0.05 and min(lowest) > -0.01


def test_wave_example_loads_and_moves_the_right_hand(humanoid):
    tr = load_keyframes(example_path("wave.yaml"), humanoid.joint_names)
    assert tr.duration > 1.0 and "r_shoulder_roll" in tr.names
    q = humanoid.neutral()
    for name, val in zip(tr.names, tr.sample(1.2)[0]):
        q[humanoid.joint_index(name)] = val
    hand = humanoid.bone_names.index("r_hand")
    assert humanoid.bone_segments(q)[1][hand, 2] > 1.5 > humanoid.bone_segments(humanoid.neutral())[1][hand, 2]


GOOD = """joints: [a, b]
angle_unit: deg
frames:
  - {t: 0.0, q: [0, 0]}
  - {t: 1.0, q: [90, 10]}
  - {t: 2.0, q: [0, 0]}
"""


def test_keyframe_errors_name_the_bad_frame_and_line():
    tr = parse_keyframes_yaml(GOOD, "g.yaml")
    np.testing.assert_allclose(tr.sample(1.0)[0], np.deg2rad([90, 10]))
    with pytest.raises(KeyframeError, match=r"g.yaml:5: frame 1: t = 0.0 does not come after"):
        parse_keyframes_yaml(GOOD.replace("t: 1.0", "t: 0.0"), "g.yaml")
    with pytest.raises(KeyframeError, match=r"g.yaml:6: frame 2: q has 3 values, expected 2"):
        parse_keyframes_yaml(GOOD.replace("t: 2.0, q: [0, 0]", "t: 2.0, q: [0, 0, 1]"), "g.yaml")
    with pytest.raises(KeyframeError, match=r"g.yaml:5: frame 1: joint 'b' value 'x' is not a finite number"):
        parse_keyframes_yaml(GOOD.replace("[90, 10]", "[90, x]"), "g.yaml")
    with pytest.raises(KeyframeError, match=r"joints \['b'\] are not in the skeleton"):
        parse_keyframes_yaml(GOOD, "g.yaml", joint_names=["a"])
    with pytest.raises(KeyframeError, match="not valid YAML"):
        parse_keyframes_yaml("joints: [a\nframes: ]", "g.yaml")
    csv = "# a comment\nt,a,b\n0,0,0\n0.5,1,nan\n"
    with pytest.raises(KeyframeError, match=r"c.csv:4: frame 1: joint 'b' value nan"):
        parse_keyframes_csv(csv, "c.csv")
    tr = parse_keyframes_csv(csv.replace("nan", "2"), "c.csv")
    np.testing.assert_allclose(tr.sample(0.5)[0], [1.0, 2.0])
