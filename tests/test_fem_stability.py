"""The explicit step's stability limit is estimated tightly, honoured by sub-stepping, and divergence
is caught and raised instead of published."""
import numpy as np
import pytest

from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material, ParameterError
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.stability import (DivergenceError, StabilityError, critical_step, max_eigenvalue, plan_substeps)
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh, paper_mesh


def _kicked(model, seed=0):
    s = State.rest(model)
    s.u[:] = np.random.default_rng(seed).normal(scale=1e-4, size=s.u.shape)
    s.u[model.fixed] = 0.0
    return s


def test_max_eigenvalue_matches_dense_solver():
    mesh = box_mesh((0.1, 0.05, 0.05), (4, 2, 2))
    model = build_model(mesh, Material(E=1e5, nu=0.3), fixed=mesh.vertices[:, 0] == 0)
    free = model.free_dofs
    Minv = 1 / np.sqrt(np.repeat(model.mass, 3)[free])
    dense = np.linalg.eigvalsh(Minv[:, None] * model.K[free][:, free].toarray() * Minv[None, :])[-1]
    assert max_eigenvalue(model) == pytest.approx(dense, rel=2e-3)


@pytest.mark.parametrize("damped", [False, True])
def test_critical_step_is_tight(damped):
    """Without sub-steps, 0.97 h_crit stays bounded and 1.05 h_crit blows up."""
    mesh = paper_mesh("cube")
    mat = Material(E=1e5, nu=0.3, xi=2.0 if damped else 0.0, zeta=2e-4 if damped else 0.0)
    model = build_model(mesh, mat, fixed=mesh.vertices[:, 2] < -0.049, gravity=(0, 0, 0))
    lam = max_eigenvalue(model)
    h_crit = critical_step(lam, mat.xi, mat.zeta)
    for factor, stable in ((0.97, True), (1.05, False)):
        # tell the integrator a softer limit so it takes the step whole, without sub-steps
        integ = make_integrator("clustered", model, lam_max=0.25 * lam)
        h = factor * h_crit
        s = _kicked(model)
        u0 = np.abs(s.u).max()
        grew = False
        try:
            for _ in range(3000):
                integ.step(s, Control(), h)
            grew = np.abs(s.u).max() > 1e3 * u0
        except DivergenceError:
            grew = True
        assert grew != stable, f"h = {factor} h_crit: expected {'bounded' if stable else 'growth'}"


def test_stiff_material_at_ten_times_the_critical_step_stays_bounded_through_substeps():
    mesh = paper_mesh("sphere")
    model = build_model(mesh, Material(E=1e7, nu=0.49, rho=1000.0, xi=1.0, zeta=1e-5),
                        fixed=mesh.vertices[:, 2] < -0.085)
    integ = make_integrator("clustered", model, safety=0.8)
    h = 10.0 * integ.critical_step()
    s = State.rest(model)
    peak = 0.0
    for _ in range(300):
        info = integ.step(s, Control(), h)
        peak = max(peak, np.abs(s.u).max())
    print(f"h = {h:.3g} s = 10 h_crit: {info.substeps} sub-steps, margin {info.margin:.2f}, peak |u| {peak:.3g} m")
    assert info.substeps >= 13 and info.margin >= 1.0 / 0.8 - 1e-9
    # the static sag under gravity of a 0.2 m ball of E = 1e7 Pa is well under a millimetre
    assert np.isfinite(s.u).all() and peak < 1e-3


def test_too_many_substeps_is_refused_with_a_way_out():
    with pytest.raises(StabilityError, match=r"needs 1000 explicit sub-steps.*use a smaller step"):
        plan_substeps(1.0, 1.25e-3, safety=0.8, max_substeps=100)


def test_divergence_is_detected_and_raised_never_returned():
    mesh = paper_mesh("cube")
    model = build_model(mesh, Material(E=1e6, nu=0.3, xi=0, zeta=0), fixed=mesh.vertices[:, 2] < -0.049)
    integ = make_integrator("clustered", model, lam_max=1.0)       # a lie: the true limit is far lower
    s = _kicked(model)
    with pytest.raises(DivergenceError, match="reduce the step"):
        for _ in range(5000):
            integ.step(s, Control(), 1e-3)


@pytest.mark.parametrize("warp", [False, "element", "vertex"])
@pytest.mark.parametrize("where", ["free vertex velocity", "held vertex force", "attachment target"])
def test_a_non_finite_value_anywhere_in_a_clustered_step_is_raised(where, warp):
    """The fused step returns one flag, 'every |u| <= limit', for both builds (with and without attachments):
    a nan or inf must reach it from a velocity, from a held vertex (inverse mass 0) or from a constraint."""
    from clusterfem_ros.fem.model import Attachments
    mesh = paper_mesh("cube", 0.5)
    fixed = mesh.vertices[:, 2] < mesh.vertices[:, 2].min() + 1e-9
    model = build_model(mesh, Material(E=3e4, nu=0.3), fixed=fixed)
    integ = make_integrator("clustered", model, threads=False,
                            **({"warp": True, "warping_model": warp, "allow_unbounded_warping": True} if warp else {}))
    s, control = State.rest(model), Control()
    free, held = int(np.flatnonzero(~fixed)[0]), int(np.flatnonzero(fixed)[0])
    integ.step(s, control, 1e-3)
    if where == "free vertex velocity":
        s.v[free, 1] = np.nan
    elif where == "held vertex force":
        f = np.zeros((model.n_vertices, 3))
        f[held, 0] = np.inf
        control = Control(f_ext=f)
    else:
        z = np.zeros((1, 3))
        control = Control(attachments=Attachments(np.array([free]), np.full((1, 3), np.nan), z, z.copy(),
                                                  np.array([100.0]), np.array([10.0])))
    with pytest.raises(DivergenceError, match="non-finite"):
        integ.step(s, control, 1e-3)


@pytest.mark.parametrize("method", ["clustered", "standard_explicit"])
@pytest.mark.parametrize("safety", [10.0, 1.0001, 0.0, -0.5, float("nan"), "0.8", True])
def test_safety_outside_zero_one_is_refused_by_the_integrators(method, safety):
    """A sub-step longer than the critical one is unstable by construction: refused at set-up, naming the value."""
    model = build_model(box_mesh((0.4, 0.1, 0.1), (4, 1, 1)), Material())
    with pytest.raises(ParameterError, match=r"safety = .*\(0, 1\]"):
        make_integrator(method, model, safety=safety)
    with pytest.raises(ParameterError, match=r"safety = "):
        plan_substeps(0.01, 1e-3, safety=safety)


def test_safety_one_is_accepted_and_plans_at_the_critical_step():
    model = build_model(box_mesh((0.4, 0.1, 0.1), (4, 1, 1)), Material())
    integ = make_integrator("clustered", model, safety=1.0)
    plan = plan_substeps(0.01, 1e-3, safety=1.0)
    assert integ.safety == 1.0 and plan.substeps == 10 and plan.margin == pytest.approx(1.0)
