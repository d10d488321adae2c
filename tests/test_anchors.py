"""Anchors from a scene file: the vertices near given points held by point constraints (body/anchors.py)."""
import numpy as np
import pytest

from clusterfem_ros.body.anchors import anchor_constraints
from clusterfem_ros.config import ConfigError, SceneConfig
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
from clusterfem_ros.scene import Scene

SPHERE = paper_mesh("sphere").vertices
CAP = [float(SPHERE[:, 0].mean()), float(SPHERE[:, 1].mean()), float(SPHERE[:, 2].max())]   # the top's centre
HANGING = dict(skeleton__source="none", body__kind="sphere", body__fix_bottom=False, warping=False)


def test_anchors_hold_exactly_the_vertices_near_each_point_once():
    points = CAP + [float(SPHERE[:, 0].max()), 0.0, 0.0]
    near = [set(np.flatnonzero(np.linalg.norm(SPHERE - p, axis=1) <= 0.05).tolist())
            for p in np.reshape(points, (-1, 3))]
    got = anchor_constraints(SPHERE, points, 0.05, 4e4, 400.0, bones=["", "hip"], bone_names=["root", "hip"])
    vertices = [c.vertex for c in got]
    assert len(vertices) == len(set(vertices)) and set(vertices) == near[0] | near[1]
    for c in got:
        if c.vertex in near[0]:                     # the first point's: in the world, at their rest positions
            assert c.bone is None and np.array_equal(c.world, SPHERE[c.vertex])
        else:                                       # the second's: carried by 'hip'
            assert c.bone == 1 and c.world is None
        assert (c.kp, c.kd) == (4e4, 400.0)


@pytest.mark.parametrize("points, bones, names, message", [
    ([0.0, 0.0, 5.0], [], None, r"anchor point 0 at \[0.0, 0.0, 5.0\] has no vertex within .* nearest is"),
    (CAP, ["elbow"], ["root", "hip"], r"anchors.bones\[0\] = 'elbow' is not a bone of the skeleton \(root, hip\)"),
    (CAP, ["", ""], None, "2 names for 1 anchor points"),
    (CAP[:2], [], None, "finite x, y, z triples"),
])
def test_bad_anchors_are_refused_with_the_way_out(points, bones, names, message):
    with pytest.raises(ValueError, match=message):
        anchor_constraints(SPHERE, points, 0.02, 4e4, 400.0, bones=bones, bone_names=names)


@pytest.mark.parametrize("values, message", [
    ({"anchors.points": [0.0, 0.1]}, "give x, y, z per anchor point"),
    ({"anchors.points": [0.0, 0.1, float("nan")]}, "give finite numbers"),
    ({"anchors.points": ["top"]}, "expected a list of float"),
    ({"anchors.points": [0.0, 0.1, 0.2], "anchors.bones": ["a", "b"]}, "2 names for 1 anchor points"),
    ({"anchors.bones": [3]}, "expected a list of str"),
    ({"anchors.points": [0.0, 0.1, 0.2], "anchors.bones": ["hand"], "skeleton.source": "none", "body.kind": "sphere"},
     "skeleton.source is 'none'"),
    ({"anchors.radius": 0.0}, "outside"),
])
def test_the_config_refuses_bad_anchors(values, message):
    with pytest.raises(ConfigError, match=message):
        SceneConfig().with_values(values)


def test_a_sphere_hangs_from_its_anchored_cap_and_sags_by_the_weight_over_the_held_stiffness():
    """Without anchors the sphere falls (slowed only by the mass damping xi: u = g/xi (t - (1 - e^-xi t)/xi));
    anchored at its top cap it hangs and comes to rest, and the held vertices sit below their rest positions
    by M g / (sum of the held masses x kp) on mass-weighted average: at rest the attachment forces
    m_i kp (u*_i - u_i) carry the whole weight."""
    free = Scene.build(SceneConfig().with_values(**HANGING))
    assert free.anchors == [] and free._anchored is None
    free.start(0.0)
    free.advance_to(0.3)
    xi, t = free.config["material.mass_damping"], 0.3
    assert free.state.u[:, 2].mean() == pytest.approx(-9.81 / xi * (t - (1.0 - np.exp(-xi * t)) / xi), rel=0.01)
    for kp in (4e4, 4e5):
        said = []
        scene = Scene.build(SceneConfig().with_values(anchors__points=CAP, anchors__radius=0.05, anchors__kp=kp,
                                                      anchors__kd=2.0 * np.sqrt(kp), **HANGING), progress=said.append)
        held = np.array([a.vertex for a in scene.anchors])
        assert any(f"anchoring {held.size} vertices at 1 points" in s for s in said) and held.size > 10
        scene.start(0.0)
        scene.advance_to(5.0)
        m = scene.model.mass
        sag = -(m[held] * scene.state.u[held, 2]).sum() / m[held].sum()
        expected = m.sum() * 9.81 / (m[held].sum() * kp)
        print(f"kp {kp:.0e}: {held.size} held, cap sag {sag * 1e3:.2f} mm (M g / sum m kp = {expected * 1e3:.2f} mm)")
        assert sag == pytest.approx(expected, rel=0.03)
        assert np.abs(scene.state.v).max() < 0.05 and np.isfinite(scene.state.u).all()


def test_a_bone_anchor_rides_its_bone_on_the_jelly_man():
    """An anchor carried by a bone: its vertices join the driver's point constraints, their targets move with
    the bone, and the walk stays finite."""
    from clusterfem_ros.motion import load_motion
    base = Scene.build(SceneConfig().with_values(body__target_tets=700))
    name = "r_forearm"
    hand = base.skeleton.bone_names.index(name)
    x = base.model.rest[np.flatnonzero(base.binding.bone == hand)[0]]
    scene = Scene.build(SceneConfig().with_values(body__target_tets=700, anchors__points=x.tolist(),
                                                  anchors__bones=[name], anchors__radius=0.03))
    assert scene.anchors and scene.driver.points == tuple(scene.anchors)
    assert all(a.bone == hand for a in scene.anchors)
    m = load_motion()
    for k in range(61):
        q, v = m.trajectory.sample(k / 120.0, loop=True)
        scene.push_joint_state(1000.0 + k / 120.0, m.trajectory.names, q, v)
        scene.advance_to(1000.0 + k / 120.0)
    idx = np.array([a.vertex for a in scene.anchors])
    att = scene._control(scene.sim_time, scene.state).attachments
    rows = [np.flatnonzero(att.index == i)[-1] for i in idx]                   # the anchor rows come after the levels'
    R, p = scene._poses(scene.sim_time).rotation[hand], scene._poses(scene.sim_time).translation[hand]
    local = (scene.model.rest[idx] - scene.binding.rest_translation[hand]) @ scene.binding.rest_rotation[hand]
    np.testing.assert_allclose(scene.model.rest[idx] + att.target_u[rows], local @ R.T + p, atol=1e-9)
    assert np.isfinite(scene.state.u).all()


def test_the_warm_up_steps_with_the_anchors_so_the_first_real_step_does_not_load_another_build(monkeypatch):
    """The attached and attachment-free steps are different compiled builds: warming up without the anchors left
    the first real step of an anchored sphere to load (or compile) the attached one (1.9 s in the demo)."""
    from clusterfem_ros.fem.integrators.clustered_explicit import ClusteredExplicit
    seen = []
    original = ClusteredExplicit.step
    monkeypatch.setattr(ClusteredExplicit, "step", lambda self, state, control, h: (
        seen.append(control.attachments.index.size), original(self, state, control, h))[1])
    scene = Scene.build(SceneConfig().with_values(anchors__points=CAP, anchors__radius=0.05, **HANGING))
    assert seen and all(k == len(scene.anchors) > 0 for k in seen)


@pytest.mark.parametrize("sliding", [True, False])
def test_a_sliding_anchor_follows_its_vertices_along_the_bone_and_holds_them_across(sliding):
    """anchors.sliding: the vertices near the forearm's midpoint get line constraints stopped at the bone's
    ends (the driver's lines, not its points). Slid 5 mm along the bone and pushed 5 mm across, their targets
    move the 5 mm along and none across; held (sliding false), the targets stay at rest."""
    name = "r_forearm"
    cfg = dict(body__target_tets=700, anchors__bones=[name], anchors__radius=0.05, anchors__sliding=[sliding])
    probe = Scene.build(SceneConfig().with_values(body__target_tets=700))
    bone = probe.skeleton.bone_names.index(name)
    starts, ends = probe.skeleton.bone_segments(probe.skeleton.neutral())
    middle = (starts[bone] + ends[bone]) / 2.0
    said = []
    scene = Scene.build(SceneConfig().with_values(anchors__points=middle.tolist(), **cfg), progress=said.append)
    idx = np.array([a.vertex for a in scene.anchors])
    assert idx.size > 0 and all(a.bone == bone for a in scene.anchors)
    if sliding:
        assert scene.driver.lines == tuple(scene.anchors) and scene.driver.points == ()
        assert all(a.within_bone for a in scene.anchors)
        assert any("(1 sliding along their bones)" in s for s in said)
    else:
        assert scene.driver.points == tuple(scene.anchors) and scene.driver.lines == ()
    scene.start(0.0)                                      # the rest pose: no joint state yet
    axis = (ends[bone] - starts[bone]) / np.linalg.norm(ends[bone] - starts[bone])
    across = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    scene.state.u[idx] += 0.005 * axis + 0.005 * across
    att = scene._control(scene.sim_time, scene.state).attachments
    rows = [np.flatnonzero(att.index == i)[-1] for i in idx]                   # the anchor rows come last
    expected = 0.005 * axis if sliding else np.zeros(3)
    np.testing.assert_allclose(att.target_u[rows], np.broadcast_to(expected, (idx.size, 3)), atol=1e-9)


@pytest.mark.parametrize("values, message", [
    ({"anchors.points": [0.0, 0.1, 0.2], "anchors.bones": ["hand"], "anchors.sliding": [True, False]},
     "anchors.sliding has 2 values for 1 anchor points"),
    ({"anchors.points": [0.0, 0.1, 0.2], "anchors.sliding": [True]}, r"anchors.sliding\[0\] is true but anchor point 0 "
     "has no bone"),
    ({"anchors.sliding": [1.0]}, "expected a list of bool"),
])
def test_the_config_refuses_bad_sliding_anchors(values, message):
    with pytest.raises(ConfigError, match=message):
        SceneConfig().with_values(values)


def test_anchor_constraints_refuse_a_sliding_point_without_a_bone():
    with pytest.raises(ValueError, match="anchor point 0 slides .* but has no bone"):
        anchor_constraints(SPHERE, CAP, 0.05, 4e4, 400.0, sliding=[True])
    with pytest.raises(ValueError, match="2 values for 1 anchor points"):
        anchor_constraints(SPHERE, CAP, 0.05, 4e4, 400.0, sliding=[True, True])
