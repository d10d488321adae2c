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
    from clusterfem_ros.scene import BONE_CHECK_STEPS
    with pytest.raises(DivergenceError, match=f"surface vertex {i} is .* after the start"):
        for k in range(1, BONE_CHECK_STEPS + 1):    # the step loop looks every BONE_CHECK_STEPS steps; a few
            scene.advance_to(60.01 + k * scene.h)  # steps do not pull the vertex back
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


def _moved_out(scene, i, distance):
    """u with surface vertex i moved along the perpendicular from its bone's segment to ``distance`` [m] from it
    (the bone posed at sim_time; the segment and the distance written out as in _naive_segment_distances)."""
    poses = scene._poses(scene.sim_time)
    b = int(scene.binding.bone[i])
    R, p, axis = poses.rotation[b], poses.translation[b], scene.binding.axis_local[b]
    a, d = R @ axis[0] + p, R @ axis[1] + p - R @ axis[0] - p
    x = scene.model.rest[i] + scene.state.u[i]
    closest = a + min(max((x - a) @ d / (d @ d), 0.0), 1.0) * d
    u = scene.state.u.copy()
    u[i] = closest + distance * (x - closest) / np.linalg.norm(x - closest) - scene.model.rest[i]
    return u, float(np.linalg.norm(x - closest))


@pytest.mark.parametrize("limit", [0.01, 0.6])
def test_a_vertex_may_reach_the_parameter_or_one_and_a_half_times_its_rest_distance(limit):
    """The rule as docs/usage.md states it, on the body just placed: a surface vertex may go out to
    output.max_bone_distance or 1.5 times its distance from its bone at rest, the larger; 2 % short of it the
    state passes, 2 % beyond it the check names the vertex."""
    scene = Scene.build(SceneConfig().with_values(**SMALL, output__max_bone_distance=limit))
    _push(scene, 60.0)
    scene.advance_to(60.0)                                         # placed (and settled), not stepped
    assert scene.output_problem() is None
    sv = scene.surface_vertices
    rest_distance = scene.binding.distance[sv]
    for i, d0 in ((int(sv[np.argmax(rest_distance)]), rest_distance.max()),
                  (int(sv[np.argmin(rest_distance)]), rest_distance.min())):
        allowed = max(limit, 1.5 * d0)
        within, _ = _moved_out(scene, i, 0.98 * allowed)
        beyond, _ = _moved_out(scene, i, 1.02 * allowed)
        assert scene.problem_of(within, scene.state.v, scene._poses(scene.sim_time)) is None, (i, d0, allowed)
        problem = scene.problem_of(beyond, scene.state.v, scene._poses(scene.sim_time))
        assert problem is not None and f"surface vertex {i} is" in problem, (i, d0, allowed, problem)
    assert rest_distance.max() * 1.5 > 0.01 and rest_distance.min() * 1.5 < 0.6     # both branches were taken


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


def _naive_segment_distances(x, bone, R, p, axis_local):
    """The distance to the posed bone segment written out per vertex (the kernel's twin)."""
    out = []
    for i, b in enumerate(bone):
        a = R[b] @ axis_local[b, 0] + p[b]
        d = R[b] @ axis_local[b, 1] + p[b] - a
        s = 0.0 if d @ d == 0 else min(max((x[i] - a) @ d / (d @ d), 0.0), 1.0)
        out.append(np.linalg.norm(x[i] - a - s * d))
    return np.array(out)


def test_the_bone_distance_kernel_equals_its_naive_twin_to_round_off():
    """Random poses, points on both sides of both ends and beside the segment, and one zero-length bone; the
    check's kernel (any_beyond) finds a vertex 1 % beyond its limit and none when all are 1 % within."""
    from clusterfem_ros.body.bone_distance import any_beyond, segment_distances
    rng = np.random.default_rng(3)
    nb, n = 5, 400
    q, _ = np.linalg.qr(rng.standard_normal((nb, 3, 3)))
    R = q * np.sign(np.linalg.det(q))[:, None, None]               # proper rotations
    p = rng.standard_normal((nb, 3))
    axis_local = rng.standard_normal((nb, 2, 3)) * 0.3
    axis_local[2, 1] = axis_local[2, 0]                            # a bone whose segment is a point
    rest = rng.standard_normal((n, 3))
    u = 0.1 * rng.standard_normal((n, 3))
    bone = rng.integers(0, nb, n)
    vertices = np.sort(rng.choice(n, 150, replace=False))
    got = segment_distances(rest, u, vertices, bone, R, p, axis_local)
    want = _naive_segment_distances((rest + u)[vertices], bone[vertices], R, p, axis_local)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
    assert (bone[vertices] == 2).any()                             # the point bone was exercised
    # the check's question: is any vertex beyond its limit; each vertex in turn 1 % beyond, the others within
    args = (rest, u, vertices, bone, R, p, axis_local)
    assert not any_beyond(*args, (1.01 * want) ** 2)
    for k in rng.choice(vertices.size, 20, replace=False):
        limit = 1.01 * want
        limit[k] = 0.99 * want[k]
        assert any_beyond(*args, limit ** 2)


def test_the_scene_bone_distance_equals_the_naive_twin_on_a_posed_body(scene):
    _push(scene, 80.0, k=37)
    scene.advance_to(80.0)
    scene.advance_to(80.05)
    dist, _ = scene.bone_distance()
    poses = scene._poses(scene.sim_time)
    b, sv = scene.binding, scene.surface_vertices
    want = _naive_segment_distances(scene.positions()[sv], b.bone[sv], poses.rotation, poses.translation,
                                    b.axis_local)
    np.testing.assert_allclose(dist, want, rtol=1e-12, atol=1e-14)
