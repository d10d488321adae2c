"""Looping a capture that does not end where it starts: no jump at the seam (the player's loop_blend)."""
import numpy as np
import pytest

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.motion import load_motion
from clusterfem_ros.scene import Scene
from clusterfem_ros.skeleton.trajectory import JointTrajectory
from tests.shared_data import walk_clip


def _open_trajectory():
    """2 s: the root walks 3 m along x, rises 0.1 m; a joint turns 1.25 turns (a pirouette) plus 0.4 rad."""
    t = np.linspace(0.0, 2.0, 241)
    p = np.column_stack([1.5 * t, 0.05 * t, 2 * np.pi * 1.25 * t / 2 + 0.2 * t])
    return JointTrajectory(t, ["x", "z", "yaw"], p, revolute=np.array([False, False, True]))


def _seam_steps(tr, dt=1 / 120):
    """Largest |q(t + dt) - q(t)| for t across the loop point, and the same away from it."""
    T = tr.duration
    at = np.abs(tr.sample(T + dt / 2, loop=True)[0] - tr.sample(T - dt / 2, loop=True)[0])
    away = np.abs(tr.sample(1.0 + dt / 2)[0] - tr.sample(1.0 - dt / 2)[0])
    return at, away


def test_an_open_capture_jumps_at_its_loop_point_and_with_a_seam_it_does_not():
    tr = _open_trajectory()
    assert not tr.closed
    at, away = _seam_steps(tr)
    assert at[0] > 2.9                                   # the root jumps back 3 m: the teleport
    sealed = tr.with_seam(0.5, carry=np.array([True, False, False]))
    assert sealed.closed
    at, away = _seam_steps(sealed)
    assert (at < 3 * away + 1e-9).all(), (at, away)      # no step at the seam larger than the motion's own
    np.testing.assert_allclose(sealed.cycle_offset, [3.0, 0.0, 2 * np.pi])   # carried on; whole turns kept
    np.testing.assert_allclose(sealed.sample(2.0 + 0.3, loop=True)[0][0], 3.0 + 0.45)   # walks on, no way back
    # untouched before the blend window, and a closed trajectory is returned as it is
    np.testing.assert_array_equal(sealed.positions[:180], tr.positions[:180])
    assert sealed.with_seam(0.5) is sealed
    with pytest.raises(ValueError, match="loop blend"):
        tr.with_seam(0.0)


def test_the_cmu_walk_loops_into_the_scene_without_a_teleport():
    """The bundled walk looped through the seam, fed to the scene: no 'teleport' (the root jump of 3-4 m at
    every loop was counted as used and rejected), and the root keeps going forward."""
    m = load_motion("bvh", walk_clip())
    tr = m.looping(0.5)                                   # what the player plays (loop_blend 0.5 s)
    scene = Scene.build(SceneConfig().with_values({"skeleton.source": "robot_description", "body.target_tets": 700}),
                        urdf_xml=m.urdf)
    T = tr.duration
    kinds = []
    for k in range(-30, 30):
        t = T + k / 120
        q, v = tr.sample(t, loop=True)
        kinds += [kind for kind, _ in scene.push_joint_state(100 + t, tr.names, q, v)]
        scene.advance_to(100 + t)
    assert kinds == [] and scene.inputs.accepted == 60
    x0 = tr.sample(T - 0.25, loop=True)[0][:3]          # the root's position channels
    x1 = tr.sample(T + 0.25, loop=True)[0][:3]
    assert 0.2 < np.linalg.norm(x1 - x0) < 1.0             # walks on at about its speed across the seam
