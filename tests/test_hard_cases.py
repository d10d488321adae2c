"""Hard cases x methods (the stability table, small): every run stays bounded or refuses at set-up."""
import numpy as np
import pytest

from benchmarks import stability_table as st
from clusterfem_ros.fem.materials.corotational import ElementCorotation
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.model import Control, State
from clusterfem_ros.fem.materials.stretch import StretchPlan
from clusterfem_ros.fem.mesh.tet_quality import mesh_quality
from clusterfem_ros.fem.materials.assembled_warp import AssembledWarp
from clusterfem_ros.fem.materials.warping import vertex_rotations
from tests import naive_warping as naive

STEPS = 40


# The clamped face teleported 1 m: its implicit warped runs sub-step 64x for minutes; it is in the table, and
# the default model runs it below (test_the_default_model_undamped_keeps_the_tolerance_where_accepted).
SLOW = ("teleport clamp 1 m",)


@pytest.fixture(scope="module")
def results():
    """Every case x method at the scene's default damping, at the step where the method is accepted."""
    out = {(c.name, m): st.run_accepted(m, c, scale=1.0, steps=STEPS, max_substeps=1000)[-1]
           for c in st.CASES if c.name not in SLOW for m in st.METHODS}
    print("\n" + st.table(st.HEADERS, [st.row(r) for r in out.values()]))
    return out


def test_every_run_is_bounded_or_refused_at_set_up(results):
    """The per-vertex warping (the paper's, kept for comparison) is left out: see the tests below."""
    for (case, method), r in results.items():
        if method.endswith("+warp vertex"):
            continue
        where = f"{case} / {method}: {r.outcome} {r.message}"
        if r.outcome == "refused":
            if method in st.EXPLICIT:
                assert "sub-steps" in r.message and "implicit" in r.message, where  # names the limit and the way out
            continue
        assert r.outcome != "diverged", where
        assert np.isfinite(r.energy_ratio) and np.isfinite(r.volume_error), where
        assert r.outcome == "bounded" and r.energy_ratio <= st.ENERGY_SLACK, where


def test_unconditionally_stable_methods_never_refuse(results):
    for (case, method), r in results.items():
        if method not in st.EXPLICIT and "+warp" not in method:
            assert r.outcome == "bounded" and r.substeps == 1, f"{case} / {method}: {r.outcome}"


def test_warped_implicit_sub_steps_where_rotations_turn_fast_and_only_there(results):
    """The implicit step holds the vertex rotations: on the released 180 deg twist and the torn vertex it
    sub-steps (and stays bounded, checked above); on the gentle cases it takes one step."""
    for method in ("implicit direct+warp", "implicit cg+warp", "implicit direct+warp vertex"):
        for case in ("twist 180", "teleport 0.5 m"):
            assert results[(case, method)].substeps > 1, (case, method)
        for case in ("stiff E=1e7", "nu=0.49", "h=1/30", "free fall"):
            assert results[(case, method)].substeps == 1, (case, method)


def test_warped_implicit_without_sub_steps_gains_energy_on_the_released_twist():
    """What the sub-steps are for: one held-rotation step per 10 ms on the released 180 deg twist feeds energy in."""
    case = next(c for c in st.CASES if c.name == "twist 180")
    st.METHODS["implicit direct+warp, 1 step"] = ("implicit_direct", {"warp": True, "max_substeps": 1})
    try:
        one = st.run("implicit direct+warp, 1 step", case, steps=STEPS)
    finally:
        del st.METHODS["implicit direct+warp, 1 step"]
    sub = st.run("implicit direct+warp", case, steps=STEPS)
    print(f"released twist, implicit + warping: max E / budget {one.energy_ratio:.2f} with 1 step per 10 ms, "
          f"{sub.energy_ratio:.3f} with up to {sub.substeps} sub-steps")
    assert one.energy_ratio > 2 * st.ENERGY_SLACK
    assert sub.energy_ratio <= st.ENERGY_SLACK


def test_explicit_sub_steps_grow_with_stiffness_and_a_refused_step_is_run_where_accepted(results):
    for method in st.EXPLICIT:
        assert results[("nu=0.49", method)].substeps > results[("h=1/30", method)].substeps / (10 / 3) > 1
    case = next(c for c in st.CASES if c.name == "nu=0.499")
    refused, accepted = st.run_accepted("clustered+warp", case, steps=5, max_substeps=100)
    assert refused.outcome == "refused" and "sub-steps" in refused.message and "implicit" in refused.message
    assert accepted.outcome == "bounded" and accepted.h == pytest.approx(case.h / 10)


def test_clustered_equals_standard_explicit_on_every_case(results):
    for case in st.CASES:
        if case.name in SLOW:
            continue
        a, b = results[(case.name, "clustered")], results[(case.name, "standard explicit")]
        assert a.outcome == b.outcome
        if a.outcome == "bounded":
            assert a.volume_error == pytest.approx(b.volume_error, rel=1e-8, abs=1e-12)
            assert a.energy_ratio == pytest.approx(b.energy_ratio, rel=1e-8)


def test_warping_removes_the_linear_volume_error_under_large_rotation(results):
    for case in ("twist 180", "teleport 0.5 m", "h=1/30"):
        lin, warp = results[(case, "clustered")].volume_error, results[(case, "clustered+warp")].volume_error
        print(f"{case}: volume error linear {lin * 100:.2f} %, warped {warp * 100:.2f} %")
        assert warp < 0.5 * lin


def test_free_fall_keeps_shape_and_follows_gravity():
    case = next(c for c in st.CASES if c.name == "free fall")
    for method in ("clustered", "modal 30"):
        r = st.run(method, case, steps=10)
        assert r.outcome == "bounded" and r.volume_error < 1e-9


# the damping at which the symmetrised per-vertex warping was tuned (the former Material() defaults); at the
# scene's (xi = 2, zeta = 1e-4) it gains energy on this case too, which is why per-element warping is the default
VERTEX_TUNED = (1.0, 1.0e-3)


def _twin_teleport_energy(form: str, scale: float = 1.0, steps: int = STEPS) -> float:
    """Max E / budget of the teleport case run with the numpy twin's warped force (``form``), the table's
    accounting and sub-steps: symplectic Euler, end vertex jumped 0.5 m at step 1 and held."""
    case = next(c for c in st.CASES if c.name == "teleport 0.5 m")
    model = case.model(scale, "vertex tuned")
    twin = naive.BlockTwin(model.K, model.rest)
    corot = ElementCorotation(model)
    integ = make_integrator("clustered", model, warp=True, warping_model="vertex", allow_unbounded_warping=True)
    nsub = integ.step(State.rest(model), Control(), case.h).substeps
    dt = case.h / nsub
    end = np.flatnonzero(np.isclose(model.rest[:, 0], st.LENGTH))[:1]
    held = model.fixed.copy()
    held[end] = True
    g, m, mat = model.gravity_force(), model.mass[:, None], model.material
    u, v = np.zeros((model.n_vertices, 3)), np.zeros((model.n_vertices, 3))

    def energy():
        return corot.energy(u) + model.kinetic_energy(v)
    budget, ratio = energy(), 0.0
    for k in range(steps):
        before = energy()
        u[end], v[end] = [0.0, 0.0, case.teleport if k >= 1 else 0.0], 0.0
        budget += energy() - before
        u_before = u.copy()
        for _ in range(nsub):
            v += dt * (twin.force(u, v, model.mass, mat.zeta, mat.xi, form) + g) / m
            v[held] = 0.0
            u += dt * v
        budget += float((g * (u - u_before)).sum())
        ratio = max(ratio, energy() / budget)
    return ratio


def test_eq10_as_printed_gains_energy_where_the_symmetric_warping_does_not():
    """Why warping.py symmetrises eq. 10's blocks: a vertex torn 0.5 m from its neighbours and held makes
    neighbouring rotations differ a lot; eq. 10's non-symmetric blocks then feed energy in (flutter). Run at
    VERTEX_TUNED damping."""
    st.DAMPING["vertex tuned"] = VERTEX_TUNED
    try:
        eq10, ours = _twin_teleport_energy("eq10"), _twin_teleport_energy("symmetric")
        kernel = st.run("clustered+warp vertex", _case("teleport 0.5 m"), steps=STEPS, damping="vertex tuned")
    finally:
        del st.DAMPING["vertex tuned"]
    print(f"teleport 0.5 m, max E / budget: eq. 10 as printed {eq10:.2f}, symmetric twin {ours:.3f}, "
          f"kernel {kernel.energy_ratio:.3f}")
    assert eq10 > 1.3 * st.ENERGY_SLACK
    assert ours <= st.ENERGY_SLACK
    # the table takes the explicit kinetic energy at the synchronised velocity, the twin at symplectic Euler's own
    assert kernel.energy_ratio == pytest.approx(ours, rel=0.05)


@pytest.mark.parametrize("method", ["implicit_direct", "implicit_cg"])
def test_a_falling_body_stays_rigid_with_warped_implicit(method):
    """Gravity on a free body: no deformation may grow. The implicit step's velocity term must be translation
    invariant: with R K R^T there (blocks R_i K_ij R_j^T), a body falling at metres per second picked up
    forces ~ |K| |R_i - R_j| |v| from round-off-sized rotation differences and grew a deformation from
    1e-15 to 0.1 m in about 1.5 s of fall."""
    case = next(c for c in st.CASES if c.name == "free fall")
    model = case.model(2.0)                 # the 1280-tet bar: the 160-tet one kept its round-off longer
    integ = make_integrator(method, model, warp=True)
    state = State.rest(model)
    m = model.mass[:, None]
    for _ in range(300):
        integ.step(state, Control(), case.h)
    x = model.rest + state.u
    p, p0 = x - (m * x).sum(0) / m.sum(), model.rest - (m * model.rest).sum(0) / m.sum()
    U, _, Vt = np.linalg.svd((m * p).T @ p0)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    speed = float(np.abs(state.v).max())
    print(f"{method} + warping after 3 s of fall at {speed:.1f} m/s: non-rigid part {np.abs(p - p0 @ R.T).max():.2e} m")
    assert speed > 4.5                     # g / xi (1 - exp(-xi t)) = 4.9 m/s at xi = 2 / s
    assert np.abs(p - p0 @ R.T).max() < 1e-9


def test_symmetric_blocks_leave_only_a_small_diagonal_skew_part_in_the_torn_state():
    """The held-rotation Jacobian, 10 steps after the teleport: eq. 10's is non-symmetric in every block pair;
    ours only in each vertex's own diagonal block, and much less (docs/method.md, "Stiffness warping, and why we depart from eq. 10")."""
    case = next(c for c in st.CASES if c.name == "teleport 0.5 m")
    model = case.model(1.0)
    integ = make_integrator("clustered", model, warp=True, warping_model="vertex", allow_unbounded_warping=True)
    state = State.rest(model)
    end = np.flatnonzero(np.isclose(model.rest[:, 0], st.LENGTH))[:1]
    for k in range(10):
        pu = np.array([[0.0, 0.0, case.teleport if k >= 1 else 0.0]])
        integ.step(state, Control(prescribed_index=end, prescribed_u=pu, prescribed_v=np.zeros((1, 3))), case.h)
    R = vertex_rotations(model, state.u)
    assembled = AssembledWarp(model)
    Ri = R[assembled.row]
    eq10 = assembled.matrix(Ri @ assembled.Kb.data @ np.swapaxes(Ri, 1, 2))
    ours = assembled.jacobian(R)
    on_diagonal = np.kron(np.eye(model.n_vertices), np.ones((3, 3))).astype(bool)
    skew = {}
    for name, matrix in (("eq10", eq10), ("ours", ours)):
        A = matrix.toarray()
        S = 0.5 * (A - A.T)
        skew[name] = (np.linalg.norm(S[on_diagonal]) / np.linalg.norm(A), np.linalg.norm(S[~on_diagonal]) / np.linalg.norm(A))
    print(f"torn state, |skew| / |Jacobian| (diagonal blocks, off-diagonal): eq. 10 {skew['eq10'][0]:.1e}, "
          f"{skew['eq10'][1]:.1e}; ours {skew['ours'][0]:.1e}, {skew['ours'][1]:.1e}")
    assert skew["ours"][1] < 1e-14 and skew["eq10"][0] < 1e-14
    assert skew["ours"][0] < 0.2 * skew["eq10"][1]


def _case(name):
    return next(c for c in st.CASES if c.name == name)


@pytest.mark.parametrize("method", ["clustered+warp", "implicit direct+warp"])
def test_element_warping_keeps_an_undamped_sliver_bounded_where_vertex_warping_diverges(method):
    """One tet at 1e-5 of its volume, the bar sagging under gravity at h = 1 ms, no damping: the per-element
    force is the gradient of an energy and stays bounded; the paper's per-vertex warping does not on the same
    run (deterministic): it diverges within 0.05 s, or stretches the sliver until its step would need more
    sub-steps than allowed and is refused."""
    case = _case("sliver 1e-5, h=1ms")
    r = st.run(method, case, steps=60, damping="undamped")
    vertex = st.run(method + " vertex", case, steps=60, damping="undamped")
    print(f"{method}: element {r.outcome} {r.energy_ratio:.3f}, vertex {vertex.outcome} ({vertex.message[:60]})")
    assert r.outcome == "bounded" and r.energy_ratio <= st.ENERGY_SLACK
    assert vertex.outcome in ("diverged", "refused"), vertex.message


def test_element_warping_keeps_a_torn_vertex_bounded_at_the_default_damping_where_vertex_warping_does_not():
    case = _case("teleport 0.5 m")
    r = st.run("clustered+warp", case, steps=STEPS)
    vertex = st.run("clustered+warp vertex", case, steps=STEPS)
    print(f"torn vertex, default damping: element {r.energy_ratio:.3f}, vertex {vertex.outcome} "
          f"{vertex.energy_ratio:.3f} {vertex.message[:60]}")
    assert r.outcome == "bounded" and r.energy_ratio < 1.0
    # the per-vertex force blows the bar up until its planned step needs more sub-steps than allowed: a divergence
    assert vertex.outcome == "diverged" and "blew up" in vertex.message and "sub-steps" in vertex.message, vertex


def test_torn_vertex_undamped_with_element_warping_stays_finite_explicit_and_bounded_implicit():
    """Undamped, the corotated force stiffens under the 10x stretch (its tangent exceeds the linear K, whose
    largest eigenvalue sets the explicit step): the explicit step plans for the stretch (fem/materials/stretch.py) and
    does not diverge; planned from the linear K alone it diverges. Its shadow energy still gains ~1 % at the
    tear and drifts while elements stay inverted (benchmarks/stability_table.py's docstring: the one accepted
    run over the tolerance), which the table must show; implicit stays bounded."""
    case = _case("teleport 0.5 m")
    explicit = st.run("clustered+warp", case, steps=STEPS, damping="undamped")
    assert explicit.substeps >= 3 * st.run("clustered", case, steps=2, damping="undamped").substeps
    assert explicit.outcome == "energy grew" and 1.0 + 0.5 * (st.ENERGY_SLACK - 1.0) < explicit.energy_ratio < 1.05
    st.METHODS["clustered+warp, linear plan"] = ("clustered", {"warp": True, "plan_stretch": False})
    try:
        unplanned = st.run("clustered+warp, linear plan", case, steps=2 * STEPS, damping="undamped")
    finally:
        del st.METHODS["clustered+warp, linear plan"]
    assert unplanned.outcome == "diverged", (unplanned.outcome, unplanned.energy_ratio)
    implicit = st.run("implicit direct+warp", case, steps=STEPS, damping="undamped")
    assert implicit.outcome == "bounded" and implicit.energy_ratio <= st.ENERGY_SLACK, implicit


def test_the_undamped_torn_vertex_gains_less_with_a_finer_step():
    """What the undamped torn vertex gains over the work put in is the step's error through the inverted
    elements, not a force feeding energy in: a quarter of the sub-step (safety 0.2 instead of 0.8) takes four
    times the sub-steps and leaves well under half the gain after 1 s (``--torn-sweep``)."""
    case = _case("teleport 0.5 m")
    default = st.run("clustered+warp", case, steps=100, damping="undamped")
    finer = st.run("clustered+warp", case, steps=100, damping="undamped", safety=0.2)
    assert finer.substeps == 4 * default.substeps and default.energy_ratio > st.ENERGY_SLACK
    assert finer.energy_ratio - 1.0 < 0.5 * (default.energy_ratio - 1.0), (default.energy_ratio, finer.energy_ratio)


def test_the_summary_counts_every_run_once_in_its_family():
    runs = [st.Result("clustered", "a", "bounded"), st.Result("standard explicit", "a", "refused"),
            st.Result("standard explicit", "a", "bounded"), st.Result("clustered", "b", "energy grew"),
            st.Result("clustered+warp vertex", "a", "diverged"),
            st.Result("implicit direct+warp vertex", "a", "bounded"),
            st.Result("modal 30", "a", "bounded")]
    rows = {family: counts for family, *counts in st.summary(runs)}
    assert rows == {"linear explicit": ["4", "2", "1", "1"], "vertex-warped (comparison)": ["2", "1", "1", "0"],
                    "modal": ["1", "1", "0", "0"]}
    assert set(st.FAMILIES) == set(st.METHODS) and set(st.COMPARISON) == {m for m in st.METHODS if "vertex" in m}


@pytest.mark.parametrize("name", ["inverted start", "teleport clamp 1 m", "sliver 1e-6, h=1ms"])
def test_the_default_model_undamped_keeps_the_tolerance_where_accepted(name):
    """The Neo-Hookean elements without damping on the new hard cases: every run accepted (at the case's step or
    the one where the sub-steps fit) stays within the table's 1 %; the sliver's quality is about 1e-6."""
    case = _case(name)
    if name.startswith("sliver"):
        mesh = case.mesh(1.0)
        assert 1e-7 < mesh_quality(mesh.vertices, mesh.tets).worst < 1e-5
    runs = st.run_accepted("clustered+neohookean", case, 1.0, STEPS, 1000, "undamped")
    accepted = [r for r in runs if r.outcome != "refused"]
    assert accepted, [r.message for r in runs]
    for r in accepted:
        assert r.outcome == "bounded" and r.energy_ratio <= st.ENERGY_SLACK, (r.h, r.outcome, r.energy_ratio)


def test_inverted_elements_tighten_the_neohookean_plan(monkeypatch):
    """From the inverted start, undamped: the plan's factor for inverted elements (StretchPlan.INVERTED, a quarter
    of the sub-step) keeps the gain within the tolerance, where the plan for the stiffness alone gains more."""
    case = _case("inverted start")
    planned = st.run("clustered+neohookean", case, steps=STEPS, damping="undamped")
    monkeypatch.setattr(StretchPlan, "INVERTED", 1.0)
    stiffness_only = st.run("clustered+neohookean", case, steps=STEPS, damping="undamped")
    print(f"inverted start, undamped: max E / budget {planned.energy_ratio:.4f} with {planned.substeps} sub-steps, "
          f"{stiffness_only.energy_ratio:.4f} with {stiffness_only.substeps} for the stiffness alone")
    assert planned.outcome == "bounded" and planned.energy_ratio <= st.ENERGY_SLACK
    assert stiffness_only.energy_ratio > st.ENERGY_SLACK and planned.substeps > stiffness_only.substeps


def test_a_blow_up_is_reported_as_a_divergence_not_a_refusal():
    """The per-vertex model from the inverted start, undamped, grows until its stretch plan asks for more sub-steps
    than allowed: the table calls that diverged (the energy and |u| it reached in the message), not refused."""
    r = st.run("clustered+warp vertex", _case("inverted start"), steps=STEPS, damping="undamped")
    assert r.outcome == "diverged" and "blew up" in r.message, (r.outcome, r.message)
