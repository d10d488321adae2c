"""Scene.output_problem: nothing is shown before the body stands on its skeleton, nor a state torn from its bones."""
import numpy as np
import pytest

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.fem.stability import DivergenceError
from clusterfem_ros.motion import load_motion
from clusterfem_ros.scene import Scene

SMALL = dict(body__target_tets=700)


@pytest.fixture
def scene():
    return Scene.build(SceneConfig().with_values(**SMALL))


def _push(scene, t, k=0):
    m = load_motion()
    q, v = m.trajectory.sample(k / 120.0, loop=True)
    q = q.copy()
    q[m.trajectory.names.index(scene.skeleton.joint_names[0])] += 1.8     # the clip's root is far from the origin
    assert scene.push_joint_state(t, m.trajectory.names, q, v) == []


def test_before_the_first_joint_state_the_body_is_not_shown_and_after_it_is(scene):
    """A wall-clock node starts physics before any joint state: the body then stands at the skeleton's neutral
    pose (the clip's root may be metres away); output_problem withholds it until a sample has placed it."""
    scene.advance_to(50.0)
    scene.advance_to(50.05)
    assert scene.sim_time is not None and not scene.placed
    assert "not yet placed" in scene.output_problem()
    _push(scene, 50.06)
    scene.advance_to(50.1)
    assert scene.placed and scene.output_problem() is None
    dist, limit = scene.bone_distance()
    assert dist.max() < 0.2 and (limit >= 0.3).all()


def test_a_vertex_torn_from_its_bone_fails_the_check_and_the_step_loop_raises(scene):
    """One surface vertex 0.5 m out from its bone (volume barely changed): output_problem names it, and
    advance_to raises DivergenceError so the caller resets the body; after the reset the state passes."""
    _push(scene, 60.0)
    scene.advance_to(60.0)
    scene.advance_to(60.01)
    assert scene.output_problem() is None
    i = int(scene.surface_vertices[0])
    before = scene.volume_error()
    scene.state.u[i] += 0.5 * np.array([0.0, 0.0, 1.0])
    scene._checked = None
    assert abs(scene.volume_error() - before) < 0.05          # the volume check alone would not see it
    problem = scene.output_problem()
    assert problem is not None and f"surface vertex {i} is" in problem and "output.max_bone_distance" in problem
    with pytest.raises(DivergenceError, match=f"surface vertex {i} is .* after the start"):
        scene.advance_to(60.011)               # one step: the constraint has not pulled it back yet
    scene.reset()
    assert scene.output_problem() is None


def test_a_non_finite_state_fails_the_check(scene):
    _push(scene, 70.0)
    scene.advance_to(70.0)
    scene.advance_to(70.01)
    scene.state.v[3, 1] = np.nan
    scene._checked = None
    assert scene.output_problem() == "the state is not finite"
    scene.reset()
    assert scene.output_problem() is None


def test_the_limit_is_a_parameter_and_grows_with_a_vertex_rest_distance(scene):
    c = scene.config
    dist, limit = scene.bone_distance()
    rest = scene.binding.distance[scene.surface_vertices]
    np.testing.assert_array_equal(limit, np.maximum(c["output.max_bone_distance"], 1.5 * rest))


def test_after_dropped_time_the_body_is_withheld_until_replaced_not_reset(scene):
    """Physics behind its inputs by more than max_steps drops the gap; the skeleton has moved on and the body
    is put on it at the next step. Until then the state is not shown, and it is not a divergence."""
    _push(scene, 80.0)
    scene.advance_to(80.0)
    scene.advance_to(80.01)
    m = load_motion()
    for k in range(1, 61):
        q, v = m.trajectory.sample(k / 120.0, loop=True)
        scene.push_joint_state(80.0 + k / 120.0, m.trajectory.names, q, v)
    scene.advance_to(80.5, max_steps=10)                # 490 steps due: dropped
    assert scene.dropped_s > 0.4 and not scene.placed
    assert "waiting to be put on" in scene.output_problem()
    scene.advance_to(80.502)
    assert scene.placed and scene.output_problem() is None
