"""BVH captures whose joints flip for longer than a spike: the loader limits every joint's rotation speed."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.bvh import elementary_rotations, joint_rotations, parse_bvh
from clusterfem_ros.skeleton.bvh_to_urdf import MAX_END_SPEED, MAX_ROTATION_SPEED, bvh_trajectory, joint_reach

FPS = 120
N = 60


def _flip_bvh(flip_from: int = 20, flip_frames: int = 25) -> str:
    """A root and a two-bone leg at 120 Hz: the knee bends smoothly (20 deg/s), the hip's channels jump to a
    170 deg flipped rotation at ``flip_from`` and stay there ``flip_frames`` frames (not a spike: longer than
    max_spike_frames), as a thigh does in the CMU cartwheel clip."""
    rows = []
    for f in range(N + 1):
        hip = [0.0, 0.0, 0.0]
        if flip_from <= f < flip_from + flip_frames:
            hip = [170.0, 10.0, -20.0]
        rows.append([0, 0, 0, 0, 0, 0] + hip + [0.0, 0.0, 20.0 * f / FPS])
    head = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Thigh
  {
    OFFSET 0.1 -0.05 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT Shin
    {
      OFFSET 0 -0.45 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      End Site
      {
        OFFSET 0 -0.45 0
      }
    }
  }
}
MOTION
"""
    return head + f"Frames: {N + 1}\nFrame Time: {1 / FPS}\n" + "\n".join(" ".join(map(str, r)) for r in rows) + "\n"


def _rotations(tr, joint: str, times) -> np.ndarray:
    q = np.array([tr.sample(t)[0] for t in times])
    cols = [tr.names.index(f"{joint}_{a}rot") for a in "ZYX"]
    return np.einsum("fij,fjk,fkl->fil", *(elementary_rotations(a, np.rad2deg(q[:, c])) for a, c in zip("ZYX", cols)))


def _angles(R: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip((np.einsum("fij,fij->f", R[:-1], R[1:]) - 1) / 2, -1, 1))


def test_a_lasting_flip_is_turned_at_the_speed_limit_and_everything_else_is_untouched():
    m = parse_bvh(_flip_bvh(), unit_m=1.0)
    raw = bvh_trajectory(m, despike=False, max_rotation_speed=None, skip_tpose=True)
    tr = bvh_trajectory(m, despike=False, skip_tpose=True)
    t_frames = tr.times
    assert _angles(_rotations(raw, "Thigh", t_frames)).max() > np.deg2rad(160)     # the glitch, as captured
    reach = joint_reach(m)[m.joint_names.index("Thigh")]
    assert reach == pytest.approx(0.9)                                            # shin + end site
    limit = min(MAX_ROTATION_SPEED, MAX_END_SPEED / reach)                        # the foot at MAX_END_SPEED
    R = _rotations(tr, "Thigh", t_frames)
    assert _angles(R).max() <= limit / FPS + 1e-9                                 # limited, frame to frame
    assert _angles(R).max() > 0.99 * limit / FPS
    fine = np.linspace(0.0, tr.duration, 20 * N)                                  # and between the frames
    speed = _angles(_rotations(tr, "Thigh", fine)) / np.diff(fine)
    assert speed.max() < 2.0 * limit, speed.max()
    # it does reach the captured rotation when that lasts: 170 deg takes 170 deg / limit of time
    R_raw = _rotations(raw, "Thigh", t_frames)
    k = 19 + int(np.ceil(np.deg2rad(170.0) / limit * FPS)) + 1      # raw frame 20 is trajectory frame 19
    np.testing.assert_allclose(R[k], R_raw[k], atol=1e-9)
    # the shin, within the limit, keeps its captured channels exactly
    shin = [tr.names.index(f"Shin_{a}rot") for a in "ZYX"]
    np.testing.assert_array_equal(tr.positions[:, shin], raw.positions[:, shin])


def test_the_limit_can_be_turned_off_and_refuses_nothing_of_a_smooth_capture():
    m = parse_bvh(_flip_bvh(flip_frames=0), unit_m=1.0)
    np.testing.assert_array_equal(bvh_trajectory(m).positions, bvh_trajectory(m, max_rotation_speed=None).positions)


def _resets(tr, urdf) -> int:
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.fem.stability import DivergenceError
    from clusterfem_ros.scene import Scene
    scene = Scene.build(SceneConfig().with_values({"skeleton.source": "robot_description", "body.target_tets": 1500}),
                        urdf_xml=urdf)
    resets = 0
    for k in range(int(tr.duration * FPS) + 1):
        q, v = tr.sample(k / FPS)
        scene.push_joint_state(10.0 + k / FPS, tr.names, q, v)
        try:
            scene.advance_to(10.0 + k / FPS)
        except DivergenceError:
            resets += 1
            scene.reset()
    return resets


def test_the_flip_played_raw_tears_the_body_and_limited_it_does_not():
    """The physics of the glitch: a thigh flipping 170 deg in one frame throws the shin's flesh off its bone
    (the step loop resets the body, 6 times here), while the limited turn is followed (no reset)."""
    from clusterfem_ros.skeleton.bvh_to_urdf import bvh_urdf
    m = parse_bvh(_flip_bvh(), unit_m=1.0)
    urdf = bvh_urdf(m)
    assert _resets(bvh_trajectory(m, max_rotation_speed=None), urdf) > 0
    assert _resets(bvh_trajectory(m), urdf) == 0
