"""The methods behind one interface: clustered == standard explicit, direct == CG, attachments, prescribed."""
import numpy as np
import pytest

from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import Attachments, Control, State, build_model
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh

MAT = Material(E=5e4, nu=0.35, rho=1000.0, xi=2.0, zeta=1e-3)


def _run(method, model, steps, h, control=None, **opt):
    integ = make_integrator(method, model, **opt)
    s = State.rest(model)
    for _ in range(steps):
        info = integ.step(s, control or Control(), h)
    return s, info


def _warping(warp) -> dict:
    """Integrator options: False (linear) or the warping model's name."""
    return {"warp": True, "warping_model": warp, "allow_unbounded_warping": True} if warp else {}


def test_clustered_equals_standard_explicit_over_a_run():
    mesh = paper_mesh("torus")
    model = build_model(mesh, MAT, fixed=mesh.vertices[:, 0] > 0.12)
    a, ia = _run("clustered", model, 300, 1e-3)
    b, ib = _run("standard_explicit", model, 300, 1e-3)
    assert ia.substeps == ib.substeps > 1
    assert np.abs(a.u - b.u).max() <= 1e-11 * np.abs(b.u).max()
    assert np.abs(a.v - b.v).max() <= 1e-11 * np.abs(b.v).max()


def test_implicit_cg_equals_direct():
    mesh = paper_mesh("sphere")
    model = build_model(mesh, MAT, fixed=mesh.vertices[:, 2] < -0.08)
    a, _ = _run("implicit_direct", model, 100, 2e-3)
    b, info = _run("implicit_cg", model, 100, 2e-3, cg_rtol=1e-12)
    assert info.iterations > 0
    assert np.abs(a.u - b.u).max() <= 1e-8 * np.abs(a.u).max()


def test_explicit_and_implicit_agree_on_the_static_sag():
    mesh = paper_mesh("cube")
    model = build_model(mesh, Material(E=5e4, nu=0.3, xi=20.0, zeta=1e-3), fixed=mesh.vertices[:, 2] < -0.049)
    a, _ = _run("clustered", model, 1500, 1e-3)
    b, _ = _run("implicit_direct", model, 1500, 1e-3)
    assert np.abs(a.u - b.u).max() <= 1e-3 * np.abs(b.u).max()


def test_implicit_reuses_its_factorization_while_h_is_fixed():
    mesh = paper_mesh("cube")
    model = build_model(mesh, MAT, fixed=mesh.vertices[:, 2] < -0.049)
    integ = make_integrator("implicit_direct", model)
    s = State.rest(model)
    integ.step(s, Control(), 1e-3)
    lu = integ._lu
    integ.step(s, Control(), 1e-3)
    assert integ._lu is lu
    integ.step(s, Control(), 2e-3)
    assert integ._lu is not lu


@pytest.mark.parametrize("method", ["clustered", "standard_explicit", "implicit_direct"])
def test_attachment_pulls_vertices_to_a_moving_target(method):
    mesh = paper_mesh("cube")
    # no mass-proportional damping: it would drag the free flesh against the absolute velocity
    model = build_model(mesh, Material(E=5e4, nu=0.35, xi=0.0, zeta=1e-3), gravity=(0, 0, 0))
    idx = np.flatnonzero(np.abs(mesh.vertices).max(axis=1) < 0.03)
    vel = np.array([0.1, 0.0, 0.0])
    integ = make_integrator(method, model)
    s = State.rest(model)
    h = 1e-3
    for k in range(1500):
        t = k * h
        att = Attachments(idx, np.tile(vel * t, (len(idx), 1)), np.tile(vel, (len(idx), 1)),
                          np.zeros((len(idx), 3)), np.full(len(idx), 400.0), np.full(len(idx), 40.0))
        integ.step(s, Control(attachments=att), h)
    # the whole body follows the attached core at the target velocity
    assert np.abs(s.u[idx] - vel * 1.5).max() < 2e-3
    assert np.abs(s.v.mean(axis=0) - vel).max() < 5e-3


@pytest.mark.parametrize("method", ["clustered", "implicit_direct"])
def test_prescribed_vertices_move_exactly(method):
    mesh = paper_mesh("cube")
    model = build_model(mesh, MAT, gravity=(0, 0, 0))
    idx = np.flatnonzero(mesh.vertices[:, 2] < -0.049)
    integ = make_integrator(method, model)
    s = State.rest(model)
    v = np.tile([0.0, 0.0, 0.05], (len(idx), 1))
    for k in range(100):
        integ.step(s, Control(prescribed_index=idx, prescribed_u=v * k * 1e-3, prescribed_v=v), 1e-3)
    np.testing.assert_allclose(s.u[idx], v * 0.1, rtol=0, atol=1e-15)


def test_unknown_method_is_named():
    model = build_model(paper_mesh("cube"), MAT)
    with pytest.raises(ValueError, match="unknown method 'rk4'"):
        make_integrator("rk4", model)


@pytest.mark.parametrize("warp", [False, "element", "vertex", "neohookean"])
def test_clustered_plan_follows_h_and_gains_and_fixed_vertices_stay_at_rest(warp):
    """The sub-step plan is cached, but a new h or stiffer attachment gains re-plan it; fixed vertices moved
    from outside are put back at rest by the step (the kernel, not Python, holds them now)."""
    mesh = paper_mesh("cube")
    fixed = mesh.vertices[:, 2] < -0.049
    model = build_model(mesh, MAT, fixed=fixed)
    integ = make_integrator("clustered", model, **_warping(warp))
    s = State.rest(model)
    n1 = integ.step(s, Control(), 1e-3).substeps
    assert integ.step(s, Control(), 4e-3).substeps > n1
    assert integ.step(s, Control(), 1e-3).substeps == n1
    idx = np.flatnonzero(~fixed)[:4]
    att = Attachments(idx, np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 3)), np.full(4, 1.0), np.full(4, 1.0))
    assert integ.step(s, Control(attachments=att), 1e-3).substeps == n1
    stiff = Attachments(idx, np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 3)), np.full(4, 1e10), np.full(4, 1.0))
    assert integ.step(s, Control(attachments=stiff), 1e-3).substeps > n1
    s.u[fixed] = 0.01
    s.v[fixed] = 1.0
    integ.step(s, Control(), 1e-3)
    assert not s.u[fixed].any() and not s.v[fixed].any()


@pytest.mark.parametrize("warp", [False, "element", "vertex", "neohookean"])
def test_threaded_and_serial_clustered_steps_are_bit_identical(warp):
    """Each row / chunk is computed by one thread in the same order: switching builds changes no bit
    (what lets ThreadChoice switch mid-run without breaking deterministic replay)."""
    mesh = paper_mesh("torus")
    model = build_model(mesh, MAT, fixed=mesh.vertices[:, 0] > 0.12)
    a, _ = _run("clustered", model, 60, 2e-3, threads=False, **_warping(warp))
    b, _ = _run("clustered", model, 60, 2e-3, threads=True, **_warping(warp))
    assert np.abs(a.u).max() > 1e-4
    assert np.array_equal(a.u, b.u) and np.array_equal(a.v, b.v)


@pytest.mark.parametrize("warp", [False, "element", "vertex", "neohookean"])
def test_the_benchmarks_compiled_step_is_the_step(warp):
    """benchmarks/core_benchmark times ClusteredExplicit.compiled_step without Python: calling it must advance the
    state exactly as step() does, and it refuses what it does not cover (attachments)."""
    mesh = paper_mesh("sphere")
    model = build_model(mesh, MAT, fixed=mesh.vertices[:, 2] < mesh.vertices[:, 2].min() + 0.02)
    control = Control()                     # gravity is the model's
    a, b = State.rest(model), State.rest(model)
    stepper = make_integrator("clustered", model, threads=False, **_warping(warp))
    other = make_integrator("clustered", model, threads=False, lam_max=stepper.lam_max, **_warping(warp))
    for _ in range(20):
        stepper.step(a, control, 2e-3)
        fn, args = other.compiled_step(b, control, 2e-3)
        assert fn(*args)
    assert np.abs(a.u).max() > 1e-5
    assert np.array_equal(a.u, b.u) and np.array_equal(a.v, b.v)
    idx = np.array([0])
    att = Attachments(idx, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1), np.ones(1))
    with pytest.raises(ValueError, match="without attachments"):
        other.compiled_step(b, Control(attachments=att), 2e-3)


def test_thread_choice_keeps_the_faster_build_and_leaves_threads_when_a_core_is_taken():
    from clusterfem_ros.fem.integrators.clustered_explicit import ThreadChoice
    c = ThreadChoice()
    probe = 2 + 2 * ThreadChoice.PROBE

    def run(steps, serial_s, parallel_s):
        used = []
        for _ in range(steps):
            p = c.use_parallel()
            used.append(p)
            c.record(p, parallel_s if p else serial_s)
        return used

    used = run(probe, 1.0, 0.6)                    # idle machine: threads win the probe
    assert used[:4] == [False, True, False, True] and c.parallel and not c.probing
    run(1, 1.0, 5.0)                               # one stalled step is tolerated ...
    used = run(3, 1.0, 0.6)
    assert all(used) and c.parallel
    used = run(5, 1.0, 10.0)                       # ... but another process taking a core drops threads
    assert used == [True, True, False, False, False] and c.interval == 2 * ThreadChoice.INTERVAL
    used = run(c.interval - 3 - 1, 1.0, 10.0)      # serial until the next probe ...
    assert not any(used)
    used = run(8, 1.0, 10.0)                       # ... which two slow threaded steps end at once
    assert used == [False, False, True, False, True, False, True, False] and not c.probing and not c.parallel
    assert c.interval == 4 * ThreadChoice.INTERVAL
    run(c.interval, 1.0, 0.6)                      # the core is free again: the next probe finds it
    run(probe, 1.0, 0.6)
    assert c.parallel and c.interval == ThreadChoice.INTERVAL
