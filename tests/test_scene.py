"""Scene: what a config builds, the walking jelly man's volume with and without warping, time keeping."""
import numpy as np
import pytest

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.motion import load_motion
from clusterfem_ros.scene import Scene
from clusterfem_ros.scene_build import apply_error_budget

SMALL = dict(body__target_tets=700)


def _walk(scene, seconds, rate=120.0):
    m = load_motion()
    worst = 0.0
    for k in range(int(seconds * rate) + 1):
        t = 1000.0 + k / rate                       # stamps far from zero, as on a ROS clock
        q, v = m.trajectory.sample(k / rate, loop=True)
        assert scene.push_joint_state(t, m.trajectory.names, q, v) == []
        scene.advance_to(t)
        worst = max(worst, abs(scene.volume_error()))
    return worst


def test_walking_jelly_man_keeps_its_volume_with_warping_and_the_linear_model_does_not():
    warped = _walk(Scene.build(SceneConfig().with_values(warping=True, **SMALL)), 2.0)
    linear = _walk(Scene.build(SceneConfig().with_values(warping=False, **SMALL)), 2.0)
    print(f"max |V/V0 - 1| over a 2 s walk: warped {warped:.4f}, linear {linear:.4f}")
    assert warped < 0.02                              # stated bound (measured ~0.9 %)
    assert linear > 3 * warped                        # the linear model's growth under rotation


def test_a_scene_without_skeleton_builds_no_skeleton_and_refuses_joint_states():
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))
    assert scene.skeleton is None and scene.driver is None and scene._stress_cache is None
    problems = scene.push_joint_state(0.0, ["a"], np.zeros(1))
    assert problems[0][0] == "no_skeleton" and scene.inputs.rejected == {"no_skeleton": 1}
    scene.advance_to(0.0)
    rep = scene.advance_to(0.05)
    assert scene.steps_done == 50 and scene._stress_cache is None     # no stress until asked
    assert scene.step_wall_s == pytest.approx(rep.wall_s, rel=1e-12) and rep.wall_s > 0   # the run's step time
    assert np.isfinite(scene.vertex_von_mises()).all()


def test_time_is_kept_without_drift_far_from_zero():
    scene = Scene.build(SceneConfig().with_values(body__kind="cube", skeleton__source="none", warping=False,
                                                  physics__step=1e-3))
    t0 = 1.795e9                                          # a ROS time stamp in seconds
    scene.advance_to(t0)
    for k in range(1, 2001):
        scene.advance_to(t0 + k * 1e-3)
    assert scene.steps_done == 2000
    assert abs(scene.sim_time - (t0 + 2.0)) < 1e-6


def test_a_teleport_puts_the_body_on_the_skeleton_instead_of_yanking_it():
    scene = Scene.build(SceneConfig().with_values(warping=False, **SMALL))
    names = scene.skeleton.joint_names
    q = scene.skeleton.neutral()
    for k in range(20):
        scene.push_joint_state(k / 100, names, q)
        scene.advance_to(k / 100)
    e0 = scene.energy()
    q2 = q.copy()
    q2[names.index("root_x")] += 5.0
    problems = scene.push_joint_state(0.2, names, q2)
    assert [k for k, _ in problems] == ["teleport"]
    scene.advance_to(0.25)
    assert scene.positions()[:, 0].mean() > 4.5
    assert scene.energy() < 10 * max(e0, 1.0)                  # no spring-loaded 5 m jump


def test_falling_behind_drops_the_gap_and_counts_it():
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))
    scene.advance_to(0.0)
    scene.advance_to(1.0, max_steps=100)
    assert scene.steps_done == 0 and scene.dropped_s == pytest.approx(1.0)
    scene.advance_to(1.05, max_steps=100)
    assert scene.steps_done == 50


def test_an_error_budget_picks_the_cheapest_measured_method_and_refuses_an_impossible_one(tmp_path):
    from clusterfem_ros.method_choice import ChoiceError, MeasuredPoint, write_points
    def err(mm):
        return {"max_mm": mm, "rel_l2": mm / 10, "von_mises_rel": mm / 10, "volume_pct": 0.1}
    pts = [MeasuredPoint("sphere", "implicit_direct", 1e-3, 0, 0.6, err(0.5)),
           MeasuredPoint("sphere", "clustered", 1e-3, 0, 0.03, err(0.8)),
           MeasuredPoint("sphere", "clustered", 5e-4, 0, 0.03, err(0.3)),
           MeasuredPoint("sphere", "modal30", 1e-3, 30, 0.2, err(2.0))]
    f = write_points(tmp_path / "points.csv", pts)
    base = SceneConfig().with_values(body__kind="sphere", skeleton__source="none", budget__measured_points=str(f))
    said = []
    c = apply_error_budget(base.with_values(budget__max_error_mm=1.0), said.append)
    assert (c["method"], c["physics.step"]) == ("clustered", 1e-3) and "clustered" in said[0]
    c = apply_error_budget(base.with_values(budget__max_error_mm=0.4))
    assert (c["method"], c["physics.step"]) == ("clustered", 5e-4)
    with pytest.raises(ChoiceError, match="0.3"):
        apply_error_budget(base.with_values(budget__max_error_mm=0.1))
    scene = Scene.build(base.with_values(budget__max_error_mm=0.4, warping=True))
    assert scene.h == 5e-4 and scene.integrator.name == "clustered"       # warping off: the measured point's


@pytest.mark.parametrize("warping", [False, True])
def test_a_crushed_body_is_reported_with_the_time_since_start_and_a_way_out_that_applies(warping):
    """The volume check names the time on the scene's own clock (not a 1.8e9 s ROS stamp) and suggests
    turning warping on only when it is off."""
    from clusterfem_ros.fem.stability import DivergenceError
    scene = Scene.build(SceneConfig().with_values(body__kind="cube", skeleton__source="none", warping=warping,
                                                  physics__step=1e-3))
    t0 = 1.795e9
    scene.advance_to(t0)
    scene.advance_to(t0 + 0.01)
    with pytest.raises(DivergenceError, match=r"volume is off by [-+][0-9.e+]+ % at t = 0\.[0-9]+ s after the start") as err:
        for k in range(11, 200):
            scene.state.u[:] = -0.9 * (scene.model.rest - scene.model.rest.mean(axis=0))    # held crushed
            scene.advance_to(t0 + k * 1e-3)
    assert ("turn warping on" in str(err.value)) != warping


def _stalled_walk(scene, stall_at=0.5, stall=0.08, seconds=1.4, rate=120.0):
    """The node's wall-clock loop on a virtual clock: joint states of the built-in walk at ``rate``, all held
    back during [stall_at, stall_at + stall) and delivered in a burst after it; a physics tick every 10 ms
    advancing to 'now'. Returns the times of the divergences the scene raised (the node resets on each)."""
    from clusterfem_ros.fem.stability import DivergenceError
    m = load_motion()
    t0 = 1000.0
    events = []
    for k in range(int(seconds * rate) + 1):
        stamp = k / rate
        held = stall_at <= stamp < stall_at + stall
        events.append((t0 + (stall_at + stall if held else stamp + 0.001), 0, k))
    events += [(t0 + j * 0.01, 1, None) for j in range(int(seconds * 100) + 1)]
    diverged = []
    for now, kind, k in sorted(events, key=lambda e: (e[0], e[1])):
        if kind == 0:
            q, v = m.trajectory.sample(k / rate, loop=True)
            scene.push_joint_state(t0 + k / rate, m.trajectory.names, q, v, now=now)
            continue
        try:
            scene.advance_to(now, max_steps=250)
        except DivergenceError:
            diverged.append(round(now - t0, 3))
            scene.reset()
    return diverged


def test_a_stalled_then_bursting_joint_stream_does_not_make_the_warped_jelly_man_diverge():
    """An 80 ms stall of the joint states and the burst after it (as seen in live runs under load) made the
    default scene's one- and two-tet flaps flutter and diverge within a second at the old stiffness damping
    (1e-5 s) with the paper's per-vertex warping; the default 1e-4 s damps those modes. The per-element warping
    (the default model) is the gradient of an energy and stays bounded even at 1e-5 s. All three are checked,
    so the test shows the cause. The burst's jump is taken as it comes here (input.max_late_jump without limit);
    by default a jump that large re-places the body (tests/test_late_inputs.py), and then even the light
    per-vertex case stays whole. The flaps are the voxel skin's (body.skin voxel); the smooth skin (the default)
    is checked too."""
    assert _stalled_walk(Scene.build(SceneConfig().with_values(body__skin="smooth"))) == []
    assert _stalled_walk(Scene.build(SceneConfig().with_values(body__skin="voxel"))) == []
    light = SceneConfig().with_values(body__skin="voxel", material__stiffness_damping=1e-5,
                                      input__max_late_jump=100.0)
    vertex = light.with_values(warping_model="vertex", physics__allow_unbounded_warping=True)
    assert _stalled_walk(Scene.build(vertex)) != []
    assert _stalled_walk(Scene.build(light)) == []
    assert _stalled_walk(Scene.build(vertex.with_values(input__max_late_jump=0.1))) == []


def _slide_along_bones(scene) -> np.ndarray:
    """|(u - u*) . axis| of the outermost level's vertices [m]: how far they are off their rest point along
    their bone's axis (u*: the point target of the last control)."""
    d, b = scene.driver, scene.binding
    outer = b.level[d.bound] == b.n_levels - 1
    axis = b.axis_local[:, 1] - b.axis_local[:, 0]
    bones = b.bone[d.bound][outer]
    R = scene._poses(scene.sim_time).rotation[bones]
    along = np.einsum("kij,kj->ki", R, axis[bones] / np.linalg.norm(axis[bones], axis=1)[:, None])
    return np.abs(np.einsum("ki,ki->k", (scene.state.u[d.bound] - d.target_u)[outer], along))


def test_sliding_levels_are_built_only_when_asked_and_let_the_flesh_slide_along_the_bones():
    """binding.sliding_levels = 1: the outer level follows line constraints (free along the bone's axis), so
    in a walk it moves along the bones far more than under the point hold, while the body keeps its volume.
    At the default (0) no line constraint exists."""
    held = Scene.build(SceneConfig().with_values(**SMALL))
    sliding = Scene.build(SceneConfig().with_values(binding__sliding_levels=1, **SMALL))
    assert held.driver._line_set is None
    assert len(sliding.driver._line_set) == int((sliding.binding.level == 1).sum()) > 0
    vol_held, vol_sliding = _walk(held, 1.0), _walk(sliding, 1.0)
    slide_held, slide = _slide_along_bones(held), _slide_along_bones(sliding)
    print(f"outer level along the bones after a 1 s walk: mean {slide_held.mean() * 1e3:.1f} mm held, "
          f"{slide.mean() * 1e3:.1f} mm sliding; volume error {vol_held:.4f} / {vol_sliding:.4f}")
    assert slide.mean() > 3 * slide_held.mean()
    assert vol_sliding < 0.02 and np.isfinite(sliding.state.u).all()


def test_take_joint_state_is_push_then_follow_on_the_input_clock_and_push_alone_on_the_wall_clock():
    """The one entry for a joint sample (node and replay): on physics.clock = input it gives the states of
    push_joint_state then follow_inputs, bit for bit; an unstamped sample takes its receive time; on_judged sees
    the problems before the sample's steps; on the wall clock it steps nothing."""
    m = load_motion()
    config = SceneConfig().with_values(physics__clock="input", **SMALL)
    taken, reference = Scene.build(config), Scene.build(config)
    judged, steps_before = [], []
    for k in range(30):
        t = 1000.0 + k / 120.0
        q, v = m.trajectory.sample(k / 120.0, loop=True)
        stamp = 0.0 if k == 29 else t                   # the last one unstamped: it takes its receive time
        got = taken.take_joint_state(stamp, m.trajectory.names, q, v, received=t,
                                     on_judged=lambda p: judged.append((p, taken.steps_done)))
        steps_before.append(reference.steps_done)
        assert reference.push_joint_state(t, m.trajectory.names, q, v, now=t) == got == []
        reference.follow_inputs(config["physics.max_catchup_steps"])
        assert taken.steps_done == reference.steps_done
    assert taken.steps_done > 20 and taken.sim_time == reference.sim_time
    assert np.array_equal(taken.positions(), reference.positions())
    assert judged == [([], n) for n in steps_before]
    wall = Scene.build(SceneConfig().with_values(**SMALL))
    q, v = m.trajectory.sample(0.0)
    wall.take_joint_state(1000.0, m.trajectory.names, q, v, received=1000.0)
    wall.take_joint_state(1000.5, m.trajectory.names, q, v, received=1000.5)
    assert wall.steps_done == 0 and wall.sim_time is None and wall.inputs.accepted == 2



def test_the_samples_taken_in_replayed_as_taken_give_every_state_bit_for_bit():
    """What the node records and a replay gives back: on the input clock, a scene that also saw refused samples
    (a root 1e9 m away, a reported velocity of 1e12, a thigh flipping in one frame, stale and future stamps, a
    split publisher's halves, three old stamps in a row that restart the stream) and a scene given only the
    samples the first took in (taken=True) step through the same states, equal bit for bit after every sample."""
    m = load_motion()
    names = m.trajectory.names
    config = SceneConfig().with_values(physics__clock="input", **SMALL)
    live, again = Scene.build(config), Scene.build(config)
    legs = [n for n in names if n[2:].startswith(("hip", "knee", "ankle", "toe"))]
    assert 8 <= len(legs) < len(names)
    root_x = names.index("root_x")
    kept = refused = 0
    for k in range(240):
        t = 1000.0 + k / 120.0
        q, v = m.trajectory.sample(k / 120.0, loop=True)
        samples = [(t, names, q, v)]
        if k % 40 == 5:
            samples.append((t + 0.001, names, np.where(np.arange(len(q)) == root_x, 1e9, q), None))
        if k % 40 == 10:
            samples.append((t + 0.001, names, q, np.full(len(q), 1e12)))
        if k % 40 == 15:
            samples.append((t + 0.001, names, q + 3.0 * (np.arange(len(q)) == names.index("l_knee_pitch")), None))
        if k % 40 == 20:
            samples += [(t - 60.0, names, q, v), (t + 60.0, names, q, v)]
        if k % 40 == 25:                              # a split publisher: the legs alone, 1 ms later
            idx = [names.index(n) for n in legs]
            samples.append((t + 0.001, legs, q[idx] + 0.01, None))
        if k == 120:                                  # the stream played again from an older stamp
            samples += [(t - 30.0 + j / 120.0, names, q, v) for j in range(3)]
        for stamp, n, qq, vv in samples:
            live.take_joint_state(stamp, n, qq, vv, received=t)
            if not live.inputs.taken_in:
                refused += 1
                continue
            kept += 1
            again.take_joint_state(stamp, n, qq, vv, received=t, taken=True)
            assert again.inputs.taken_in and again.steps_done == live.steps_done and again.sim_time == live.sim_time
            assert np.array_equal(again.state.u, live.state.u) and np.array_equal(again.state.v, live.state.v)
    assert refused >= 20 and kept >= 240 and live.steps_done > 1000
    assert {"root_range", "joint_speed", "stale", "future", "restart"} <= set(live.inputs.rejected)
    assert live.inputs.rejected["restart"] == again.inputs.rejected["restart"] >= 1

def test_replay_refuses_a_scene_on_the_wall_clock():
    from clusterfem_ros.replay import replay
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))
    with pytest.raises(ValueError, match="physics.clock = input"):
        replay(scene, [], [])
