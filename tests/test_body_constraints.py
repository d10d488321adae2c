"""Constraint targets (eqs. 7-9): kinematic consistency, the finite-difference order, point and line
constraints, the kinematic mode, and bad input."""
import numpy as np
import pytest

from clusterfem_ros.body import (LevelGains, LineConstraint, PointConstraint, SkeletonDriver, bind_to_skeleton,
                                 rigid_point_motion)
from clusterfem_ros.body.constraints import point_targets
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import State, build_model
from tests.test_body_support import LEVELS, ChainSkeleton, Motion, box_body

SK = ChainSkeleton()
MESH = box_body()


def _binding():
    q, v = Motion().qv(0.0)
    s, e = SK.bone_segments(q)
    P = SK.forward(q, v)
    return bind_to_skeleton(MESH.vertices, s, e, LEVELS, rest_rotation=P.rotation, rest_translation=P.translation)


BINDING = _binding()


def test_rigid_motion_kernel_matches_the_numpy_formula():
    rng = np.random.default_rng(11)
    nb, k = 4, 50
    R = np.array([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(nb)])
    p, tw, dtw = rng.normal(size=(nb, 3)), rng.normal(size=(nb, 6)), rng.normal(size=(nb, 6))
    bone, local = rng.integers(0, nb, k), rng.normal(size=(k, 3))
    x, v, a = rigid_point_motion(R, p, tw, dtw, bone, local)
    r = np.einsum("kij,kj->ki", R[bone], local)
    w = tw[bone, :3]
    np.testing.assert_allclose(x, r + p[bone], atol=1e-14)
    np.testing.assert_allclose(v, np.cross(w, r) + tw[bone, 3:], atol=1e-14)
    np.testing.assert_allclose(a, np.cross(dtw[bone, :3], r) + dtw[bone, 3:] + np.cross(w, np.cross(w, r)), atol=1e-13)


def _spin(omega: float) -> Motion:
    """Joint j1 (at x = 0.2) turning at constant omega; the root and j2 still."""
    return Motion(theta=lambda t: np.array([omega * t, 0.0]), dtheta=lambda t: np.array([omega, 0.0]))


def _drive(driver, motion, t, h, steps_before=2, central=False):
    """Feed the driver the poses at t - k h, ..., t; return the last control."""
    for k in range(steps_before, -1, -1):
        tk = t - k * h
        nxt = SK.forward(*motion.qv(tk + h)) if central else None
        c = driver.control(SK.forward(*motion.qv(tk)), h, next_poses=nxt)
    return c


@pytest.mark.parametrize("difference", ["backward", "central"])
def test_target_acceleration_is_centripetal_to_second_order(difference):
    """b2's origin circles j1, so its twist changes although omega is constant: the differenced Phi plus
    the centripetal term must give omega x (omega x (x - j1)) with an O(h^2) error."""
    omega, t = 6.0, 0.37
    x = SK.forward(*_spin(omega).qv(t))
    on_b2 = np.flatnonzero(BINDING.bone == 2)
    errs, hs = [], np.array([4e-3, 2e-3, 1e-3, 5e-4])
    for h in hs:
        drv = SkeletonDriver(BINDING, MESH.vertices, difference=difference)
        _drive(drv, _spin(omega), t, h, central=difference == "central")
        sel = np.isin(drv.bound, on_b2)
        xw = MESH.vertices[drv.bound[sel]] + drv.target_u[sel]
        w = np.array([0.0, 0.0, omega])
        exact = np.cross(w, np.cross(w, xw - x.translation[1]))
        errs.append(np.abs(drv.target_a[sel] - exact).max() / np.abs(exact).max())
    rate = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    print(f"{difference}: relative acceleration error {errs} for h = {hs}; observed order {rate:.2f}")
    assert rate == pytest.approx(2.0, abs=0.15)
    assert errs[2] < 1e-3


def test_printed_eq9_with_1_over_h_would_double_the_tangential_acceleration():
    """The root turning with uniform angular acceleration alpha about its origin: the central (2h) difference
    gives alpha x r + omega x (omega x r) exactly; the printed 1/h form adds a second alpha x r."""
    alpha, t, h = 3.0, 0.5, 1e-3
    m = Motion(phi=lambda t: 0.5 * alpha * t * t, dphi=lambda t: alpha * t)
    drv = SkeletonDriver(BINDING, MESH.vertices, difference="central")
    _drive(drv, m, t, h, central=True)
    P = SK.forward(*m.qv(t))
    on_b0 = BINDING.bone[drv.bound] == 0
    r = MESH.vertices[drv.bound] + drv.target_u - P.translation[0]
    w = np.array([0, 0, alpha * t])
    tangential = np.cross([0, 0, alpha], r)
    exact = tangential + np.cross(w, np.cross(w, r))
    scale = np.abs(exact[on_b0]).max()
    np.testing.assert_allclose(drv.target_a[on_b0], exact[on_b0], atol=1e-9 * scale)
    tw = [SK.forward(*m.qv(tk)).twist for tk in (t - h, t + h)]
    bone, local = BINDING.bone[drv.bound], BINDING.local[drv.bound]
    a_printed = rigid_point_motion(P.rotation, P.translation, P.twist, (tw[1] - tw[0]) / h, bone, local)[2]
    np.testing.assert_allclose(a_printed[on_b0] - exact[on_b0], tangential[on_b0], atol=1e-9 * scale)


def test_target_velocity_is_the_time_derivative_of_the_target_position():
    m = Motion(T=lambda t: np.array([0.2 * t, np.sin(t), 0]), dT=lambda t: np.array([0.2, np.cos(t), 0]),
               phi=lambda t: 0.8 * t, dphi=lambda t: 0.8, axis=(0.6, 0.0, 0.8),
               theta=lambda t: np.array([np.sin(3 * t), 0.4 * t]), dtheta=lambda t: np.array([3 * np.cos(3 * t), 0.4]))
    t, e = 0.6, 1e-6
    drv = SkeletonDriver(BINDING, MESH.vertices)
    u = []
    for tk in (t - e, t + e, t):
        drv.reset()
        drv.control(SK.forward(*m.qv(tk)), 1e-3)
        u.append(drv.target_u.copy())
    np.testing.assert_allclose(drv.target_v, (u[1] - u[0]) / (2 * e), atol=1e-7)


def test_nan_bone_pose_is_refused_naming_the_bone():
    drv = SkeletonDriver(BINDING, MESH.vertices, bone_names=SK.bone_names)
    P = SK.forward(*Motion().qv(0.0))
    P.translation[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"translation of b1 \(index 1\) is not finite"):
        drv.control(P, 1e-3)
    P = SK.forward(*Motion().qv(0.0))
    P.twist[2, 0] = np.inf
    with pytest.raises(ValueError, match=r"twist of b2"):
        drv.control(P, 1e-3)
    with pytest.raises(ValueError, match="rotation has shape"):
        drv.control(type(P)(rotation=P.rotation[:2], translation=P.translation, twist=P.twist), 1e-3)
    with pytest.raises(ValueError, match="dt = 0"):
        drv.control(SK.forward(*Motion().qv(0.0)), 0)


@pytest.mark.parametrize("kinematic", [False, True])
def test_the_streaming_path_gives_the_general_paths_bits(kinematic):
    """From the third step on, a backward-difference driver of bound points makes its targets in one compiled
    pass (SkeletonDriver._streaming_targets); it must give the numpy path's numbers exactly, on uneven steps."""
    m = Motion(T=lambda t: np.array([0.2 * t, np.sin(t), 0]), dT=lambda t: np.array([0.2, np.cos(t), 0]),
               phi=lambda t: 0.8 * t, dphi=lambda t: 0.8, axis=(0.6, 0.0, 0.8),
               theta=lambda t: np.array([np.sin(3 * t), 0.4 * t]), dtheta=lambda t: np.array([3 * np.cos(3 * t), 0.4]))
    fast = SkeletonDriver(BINDING, MESH.vertices, kinematic=kinematic)
    slow = SkeletonDriver(BINDING, MESH.vertices, kinematic=kinematic)
    slow._streaming = False
    assert fast._streaming
    t = 0.3
    for k, dt in enumerate((1e-3, 7e-4, 1.3e-3, 1e-3, 2e-3)):
        P = SK.forward(*m.qv(t))
        a, b = fast.control(P, dt), slow.control(P, dt)
        for name in ("index", "target_u", "target_v", "target_a", "kp", "kd"):
            assert np.array_equal(getattr(a.attachments, name), getattr(b.attachments, name)), name
        for name in ("prescribed_index", "prescribed_u", "prescribed_v"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        att = a.attachments
        if k >= 2:                                          # the streaming path: its gains' maxima come along
            assert att.gain_max == (att.kp.max(), att.kd.max())
        assert att.kp.flags.writeable and att.index.flags.writeable     # the same numba types on both paths
        t += dt
    P = SK.forward(*m.qv(t))
    P.rotation[2, 1, 1] = np.nan                # past the third step: the streaming path still names the bone
    with pytest.raises(ValueError, match=r"rotation of bone 2 \(index 2\) is not finite"):
        fast.control(P, 1e-3)


def test_central_difference_needs_the_next_poses():
    drv = SkeletonDriver(BINDING, MESH.vertices, difference="central")
    with pytest.raises(ValueError, match="next_poses"):
        drv.control(SK.forward(*Motion().qv(0.0)), 1e-3)


def test_control_layout_gains_and_kinematic_mode():
    gains = LevelGains((9e4, 1e4), (600.0, 200.0))
    P = SK.forward(*_spin(2.0).qv(0.1))
    c = SkeletonDriver(BINDING, MESH.vertices, gains).control(P, 1e-3)
    a = c.attachments
    assert sorted(a.index) == sorted(BINDING.bound) and c.prescribed_index.size == 0
    lev = BINDING.level[a.index]
    np.testing.assert_array_equal(a.kp, np.where(lev == 0, 9e4, 1e4))
    np.testing.assert_array_equal(a.kd, np.where(lev == 0, 600.0, 200.0))
    k = SkeletonDriver(BINDING, MESH.vertices, gains, kinematic=True).control(P, 1e-3)
    assert set(k.prescribed_index) == set(BINDING.level_set(0))
    assert set(k.attachments.index) == set(np.flatnonzero(BINDING.level == 1))
    pos = dict(zip(a.index, a.target_u))
    np.testing.assert_array_equal(k.prescribed_u, [pos[i] for i in k.prescribed_index])
    with pytest.raises(ValueError, match="1 levels of gains for a binding with 2 levels"):
        SkeletonDriver(BINDING, MESH.vertices, LevelGains.default(1))


def test_point_on_bone_matches_the_bone_target():
    i = int(BINDING.bound[5])
    drv = SkeletonDriver(BINDING, MESH.vertices, points=[PointConstraint(i, bone=int(BINDING.bone[i]))])
    a = _drive(drv, _spin(3.0), 0.2, 1e-3).attachments
    rows = np.flatnonzero(a.index == i)
    assert rows.size == 2
    for name in ("target_u", "target_v", "target_a"):
        np.testing.assert_allclose(getattr(a, name)[rows[0]], getattr(a, name)[rows[1]], atol=1e-12)
    with pytest.raises(ValueError, match="exactly one of bone= .* or world="):
        PointConstraint(3)


def test_world_point_targets_need_no_skeleton_and_bone_points_say_what_is_missing():
    """A scene without skeleton holds its anchors by their world points alone; a point on a bone without the
    bones' poses is refused, naming its vertex."""
    rest = MESH.vertices
    world = [PointConstraint(4, world=(0.1, 0.2, 0.3), world_velocity=(0.0, 0.0, 1.0), kp=9.0, kd=3.0),
             PointConstraint(7, world=tuple(rest[7]))]
    index, x, v, a, kp, kd = point_targets(world, rest)
    np.testing.assert_array_equal(index, [4, 7])
    np.testing.assert_array_equal(x, [[0.1, 0.2, 0.3], rest[7]])
    np.testing.assert_array_equal(v, [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    assert not a.any() and list(kp) == [9.0, 4.0e4] and list(kd) == [3.0, 400.0]
    with pytest.raises(ValueError, match="vertex 5 is on a bone, but no bone poses"):
        point_targets([*world, PointConstraint(5, bone=0)], rest)


def _model(gravity, E=5e4, xi=1.0):
    return build_model(MESH, Material(E=E, nu=0.3, rho=1000.0, xi=xi, zeta=1e-3), gravity=gravity)


def test_world_point_constraints_hold_the_end_faces_of_a_sagging_beam():
    """A soft beam held by its end faces: they stay put up to about the reaction load / kp."""
    model = _model((0.0, 0.0, -9.81), E=5e5)
    ends = np.flatnonzero(np.isclose(MESH.vertices[:, 0], -0.03) | np.isclose(MESH.vertices[:, 0], 0.63))
    P = SK.forward(*Motion().qv(0.0))
    errs = []
    for kp in (1e5, 4e5):
        pts = [PointConstraint(int(i), world=tuple(MESH.vertices[i]), kp=kp, kd=2 * np.sqrt(kp)) for i in ends]
        drv = SkeletonDriver(BINDING, MESH.vertices, LevelGains((0.0, 0.0), (0.0, 0.0)), points=pts)
        integ, state = make_integrator("clustered", model), State.rest(model)
        for _ in range(400):
            integ.step(state, drv.control(P, 1e-3), 1e-3)
        sag = -state.u[:, 2].min()
        errs.append(np.abs(state.u[ends]).max())
        print(f"kp {kp:.0e}: beam sag {sag * 1e3:.1f} mm, held faces moved {errs[-1] * 1e3:.3f} mm")
    assert sag > 0.01 and errs[-1] < 0.2 * sag
    assert errs[0] / errs[1] > 2.0       # not 4: the softer hold also lets the beam sag more (a larger load)


def test_line_constraint_lets_the_body_slide_along_the_bone_only():
    """Gravity along the bone (x) and across it (z): line-constrained axis vertices slide freely in x and hold in z."""
    g = np.array([-3.0, 0.0, -9.81])
    model = _model(tuple(g), xi=0.0)         # no mass damping: it would brake the slide
    axis = np.flatnonzero(np.hypot(MESH.vertices[:, 1], MESH.vertices[:, 2]) < 1e-9)
    lines = [LineConstraint(int(i), bone=int(BINDING.bone[i]), kp=4e4, kd=400.0) for i in axis]
    drv = SkeletonDriver(BINDING, MESH.vertices, LevelGains((0.0, 0.0), (0.0, 0.0)), lines=lines)
    integ, state, P = make_integrator("clustered", model), State.rest(model), SK.forward(*Motion().qv(0.0))
    T = 0.3
    for _ in range(int(round(T / 1e-3))):
        integ.step(state, drv.control(P, 1e-3, state=state), 1e-3)
    ux = state.u[axis, 0].mean()
    perp = np.abs(state.u[axis, 1:]).max()
    print(f"axial slide {ux * 1e3:.2f} mm (free fall {0.5 * g[0] * T * T * 1e3:.2f} mm), off-axis {perp * 1e3:.3f} mm")
    assert ux == pytest.approx(0.5 * g[0] * T * T, rel=0.02)
    assert perp < 0.05 * abs(ux)
    with pytest.raises(ValueError, match="need the body's current state"):
        drv.control(P, 1e-3)


def test_a_line_within_its_bone_stops_at_the_bone_ends():
    """within_bone=True: a vertex slid past its bone's end gets the end's point as its target, held like a point
    on the bone (target velocity the bone point's, no slide velocity), while inside the segment the target is
    the free line's, bit for bit. On the spinning chain, axis vertices of b1 (x in 0.2..0.4) are displaced
    along the axis by -0.3..0.3 m."""
    motion = _spin(2.0)
    P = SK.forward(*motion.qv(0.3))
    b1 = np.flatnonzero((BINDING.bone == 1) & (np.hypot(MESH.vertices[:, 1], MESH.vertices[:, 2]) < 1e-9))
    assert b1.size >= 5
    axis_w = P.rotation[1] @ np.array([1.0, 0.0, 0.0])
    rng = np.random.default_rng(3)
    held = SkeletonDriver(BINDING, MESH.vertices, LevelGains((0.0, 0.0), (0.0, 0.0)))
    held.control(P, 1e-3)
    slide = np.linspace(-0.3, 0.3, b1.size)
    state = State(np.zeros_like(MESH.vertices), 0.1 * rng.standard_normal(MESH.vertices.shape))
    state.u[held.bound] = held.target_u
    state.u[b1] += slide[:, None] * axis_w
    targets = {}
    for within in (False, True):
        lines = [LineConstraint(int(i), bone=1, within_bone=within) for i in b1]
        drv = SkeletonDriver(BINDING, MESH.vertices, LevelGains((0.0, 0.0), (0.0, 0.0)), lines=lines)
        att = drv.control(P, 1e-3, state=state).attachments      # the bound vertices' (gains 0), then the lines'
        assert np.array_equal(att.index[-b1.size:], b1)
        targets[within] = {name: getattr(att, name)[-b1.size:] for name in ("target_u", "target_v", "target_a")}
    free, stop = targets[False], targets[True]
    x_now = MESH.vertices[b1] + state.u[b1]
    axial = lambda x: (x - P.translation[1]) @ axis_w           # noqa: E731 (coordinate along b1 from its start)
    ends = np.clip(axial(x_now), 0.0, 0.2)
    inside = (axial(x_now) >= 0.0) & (axial(x_now) <= 0.2)
    assert inside.any() and (~inside).any()
    x_free, x_stop = MESH.vertices[b1] + free["target_u"], MESH.vertices[b1] + stop["target_u"]
    np.testing.assert_allclose(axial(x_free), axial(x_now), atol=1e-12)         # the free line follows the slide
    np.testing.assert_allclose(axial(x_stop), ends, atol=1e-12)                 # the stopped one is cut at the ends
    for name in free:
        assert np.array_equal(free[name][inside], stop[name][inside])
    # past an end: the motion of the end's point fixed on b1 (a first control has no twist history: dtwist = 0)
    _, v_point, a_point = rigid_point_motion(P.rotation, P.translation, P.twist, np.zeros_like(P.twist),
                                             np.ones((~inside).sum(), np.int64),
                                             (x_stop[~inside] - P.translation[1]) @ P.rotation[1])
    np.testing.assert_allclose(stop["target_v"][~inside], v_point, atol=1e-12)
    np.testing.assert_allclose(stop["target_a"][~inside], a_point, atol=1e-12)
    assert np.abs(free["target_v"][~inside] - v_point).max() > 0.01    # the free line keeps the slide's velocity


def test_line_constraints_within_the_bone_stop_a_slide_that_free_lines_let_run():
    """Gravity along the chain (-x) pulls the axis vertices: on free lines the body slides off the bones'
    starts (as in the test above), within the bones it stops where the vertices at each bone's start meet it.
    The stopped vertices carry the whole body, so they sit past the start by about M g / (sum m kp): stiff
    gains (kp 4e6 /s^2) and a stiffer body (E 5e5 Pa) keep that and the stretch small."""
    g = np.array([-3.0, 0.0, 0.0])
    model = _model(tuple(g), E=5e5, xi=0.0)
    axis = np.flatnonzero(np.hypot(MESH.vertices[:, 1], MESH.vertices[:, 2]) < 1e-9)
    P = SK.forward(*Motion().qv(0.0))
    start = P.translation[BINDING.bone[axis], 0]
    out = {}
    for within in (False, True):
        lines = [LineConstraint(int(i), bone=int(BINDING.bone[i]), kp=4e6, kd=4e3, within_bone=within)
                 for i in axis]
        drv = SkeletonDriver(BINDING, MESH.vertices, LevelGains((0.0, 0.0), (0.0, 0.0)), lines=lines)
        integ, state = make_integrator("clustered", model), State.rest(model)
        for _ in range(300):
            integ.step(state, drv.control(P, 1e-3, state=state), 1e-3)
        x = MESH.vertices[axis, 0] + state.u[axis, 0]
        out[within] = (state.u[axis, 0].mean(), np.maximum(np.minimum(start, MESH.vertices[axis, 0]) - x, 0).max())
        print(f"within_bone={within}: mean slide {out[within][0] * 1e3:.2f} mm, "
              f"furthest past a bone's start {out[within][1] * 1e3:.3f} mm")
    assert out[False][0] < -0.05 and out[False][1] > 0.05
    assert abs(out[True][0]) < 0.05 * abs(out[False][0]) and out[True][1] < 1e-3


def test_sliding_levels_hold_across_the_bone_and_push_nothing_along_it():
    """sliding_levels=1: the outer level is held by line constraints (its level's gains), the inner by points.
    For a displaced, moving state on a spinning chain the outer level's hold kp (u* - u) + kd (v* - v) has no
    component along its bone's axis where the vertex is within its bone (the slide is free; the feed-forward a*
    is the slid point's acceleration, centripetal part included), and pushes it back where it is past an end;
    the point hold pushes along everywhere; the inner level's attachments are unchanged. The tracking error of
    the sliding level ignores the slide within the bone and counts the part past its ends."""
    gains = LevelGains((4e4, 4e3), (400.0, 120.0))
    held = SkeletonDriver(BINDING, MESH.vertices, gains)
    sliding = SkeletonDriver(BINDING, MESH.vertices, gains, sliding_levels=1)
    rng = np.random.default_rng(5)
    state = State(0.004 * rng.standard_normal(MESH.vertices.shape), 0.1 * rng.standard_normal(MESH.vertices.shape))
    motion = _spin(2.0)
    P = SK.forward(*motion.qv(0.3))
    a_held, a_slide = held.control(P, 1e-3).attachments, sliding.control(P, 1e-3, state=state).attachments

    def force(att):
        hold = att.kp[:, None] * (att.target_u - state.u[att.index]) + att.kd[:, None] * (att.target_v - state.v[att.index])
        return dict(zip(att.index.tolist(), np.hstack([hold, att.target_a])))

    f_held, f_slide = force(a_held), force(a_slide)
    assert sorted(f_held) == sorted(f_slide) == sorted(BINDING.bound.tolist())   # each bound vertex once
    outer = np.flatnonzero(BINDING.level == 1)
    inner = np.flatnonzero(BINDING.level == 0)
    assert outer.size and inner.size
    bone = BINDING.bone[outer]
    start_local, axis_local = BINDING.axis_local[bone, 0], BINDING.axis_local[bone, 1] - BINDING.axis_local[bone, 0]
    length = np.linalg.norm(axis_local, axis=1)
    axis_local /= length[:, None]
    axis = np.einsum("kij,kj->ki", P.rotation[bone], axis_local)
    at_rest = np.einsum("ki,ki->k", BINDING.local[outer] - start_local, axis_local)
    start = P.translation[bone] + np.einsum("kij,kj->ki", P.rotation[bone], start_local)
    at_now = np.einsum("ki,ki->k", MESH.vertices[outer] + state.u[outer] - start, axis)
    lo, hi = np.minimum(at_rest, 0.0), np.maximum(at_rest, length)
    within = (at_now >= lo) & (at_now <= hi)
    assert within.sum() > 10 and (~within).sum() > 2      # the rest coordinates of the end caps' vertices lie past the ends
    fs = np.array([f_slide[i][:3] for i in outer])
    fh = np.array([f_held[i][:3] for i in outer])
    along = np.einsum("ki,ki->k", fs, axis)
    across_s = fs - along[:, None] * axis
    assert np.abs(along[within]).max() < 1e-12 * np.abs(fs).max()
    back = np.clip(at_now, lo, hi) - at_now                 # the way back into the bone, past its ends
    pos = {i: (u, kp) for i, u, kp in zip(a_slide.index.tolist(), a_slide.target_u, a_slide.kp)}
    spring = np.array([pos[i][1] * (pos[i][0] - state.u[i]) for i in outer])     # kp (u* - u): the position term
    np.testing.assert_allclose(np.einsum("ki,ki->k", spring, axis), 4e3 * back, atol=1e-9)
    assert np.abs(back[~within]).min() > 0
    assert np.abs(np.einsum("ki,ki->k", fh, axis)).max() > 1e-2 * np.abs(fh).max()   # the point hold pushes along
    assert np.abs(across_s).max() > 0.1 * np.abs(fs).max()
    for i in inner:
        assert np.array_equal(f_slide[i], f_held[i])
    err_held, err_slide = held.tracking_error(state), sliding.tracking_error(state)
    assert err_slide[0] == err_held[0] and 0 < err_slide[1] < err_held[1]
    # a slide along the axes alone: no error within the bones, the excess past their ends
    along_only = State(np.zeros_like(MESH.vertices), np.zeros_like(MESH.vertices))
    along_only.u[sliding.bound] = sliding.target_u
    slide = np.linspace(-0.3, 0.3, outer.size)
    along_only.u[outer] += slide[:, None] * axis
    slid = at_rest + slide                                  # the poses are rigid: the rest coordinate moves with the bone
    excess = np.abs(slid - np.clip(slid, lo, hi))
    assert excess.max() > 0.05 and (excess == 0).any()
    err = sliding.tracking_error(along_only)
    assert err[0] == 0.0 and err[1] == pytest.approx(excess.max(), abs=1e-12)
    with pytest.raises(ValueError, match="current state"):
        sliding.control(P, 1e-3)
    with pytest.raises(ValueError, match="sliding_levels = 3"):
        SkeletonDriver(BINDING, MESH.vertices, gains, sliding_levels=3)
    with pytest.raises(ValueError, match="kinematic"):
        SkeletonDriver(BINDING, MESH.vertices, gains, sliding_levels=2, kinematic=True)
