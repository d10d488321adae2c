"""The stretch bound that plans warped explicit sub-steps (fem/materials/stretch.py)."""
import numpy as np
import pytest
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.linear.assembly import shape_gradients
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.materials.element_rotation import LANES
from clusterfem_ros.fem.materials.stretch import StretchPlan, element_need, stiffening
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh


def _bar():
    mesh = box_mesh((0.4, 0.1, 0.1), (8, 2, 2))
    return build_model(mesh, Material(E=1e6))


def _g(model, u):
    tets = np.ascontiguousarray(model.mesh.tets, dtype=np.int64)
    return stiffening(tets, shape_gradients(model.rest, tets)[0], model.rest, u), tets


def test_the_bound_is_zero_at_rest_and_under_rigid_motion():
    model = _bar()
    assert _g(model, np.zeros_like(model.rest))[0] == 0.0
    R = Rotation.from_rotvec([0.4, -1.1, 2.5]).as_matrix()
    u = model.rest @ R.T + [0.3, -2.0, 1.0] - model.rest
    assert _g(model, u)[0] < 1e-12


def test_the_bound_is_above_every_elements_stretch_trace():
    """g >= max_e tr(S_e) - 3 with S_e the stretch of F_e's polar decomposition, on random large deformations."""
    model = _bar()
    rng = np.random.default_rng(3)
    tets = np.asarray(model.mesh.tets)
    g_rest, _ = shape_gradients(model.rest, tets)
    for scale in (0.01, 0.05, 0.2):
        u = scale * rng.standard_normal(model.rest.shape)
        g, _ = _g(model, u)
        x = model.rest + u
        F = np.einsum("eci,ecj->eij", x[tets], g_rest)
        traces = np.array([np.trace(polar(f)[1]) for f in F])
        assert g >= traces.max() - 3.0 - 1e-12
        assert g <= np.sqrt(3.0) * np.linalg.norm(F, axis=(1, 2)).max() - 3.0 + 1e-12


def test_the_plan_rises_at_once_and_falls_only_after_the_hold():
    model = _bar()
    plan = StretchPlan(model, hold=0.05)
    stretched = np.zeros_like(model.rest)
    stretched[:, 0] = 2.0 * model.rest[:, 0]                # every element three times as long along x
    assert plan.factor(np.zeros_like(model.rest), 0.01) == 1.0
    up = plan.factor(stretched, 0.01)
    g, _ = _g(model, stretched)
    assert 1.0 + g <= up < 2 ** 0.25 * (1.0 + g)             # rounded up to a quarter octave
    for _ in range(5):                                       # 0.05 s without need: still held
        assert plan.factor(np.zeros_like(model.rest), 0.01) == up
    assert plan.factor(np.zeros_like(model.rest), 0.01) == 1.0


def test_the_neohookean_plan_reads_the_force_passs_bound():
    """The Neo-Hookean plan takes the largest tangent bound over the rest modulus 3 lambda + 2 mu, past 4x times
    the accuracy factor (1 + g) / 4 up to 4, rounded up to a quarter octave; it holds as the corotated plan does,
    and asking it for the corotated factor is an error that names the right call."""
    model = _bar()
    lam, mu = model.material.lame
    rest = 3 * lam + 2 * mu
    plan = StretchPlan(model, hold=0.05, energy="neohookean")
    assert plan.neohookean_factor(rest, 0.01) == 1.0
    assert plan.neohookean_factor(0.5 * rest, 0.01) == 1.0             # softer than at rest: the linear plan
    assert plan.neohookean_factor(3.0 * rest, 0.01) == 2 ** (7 / 4)    # 3 rounded up to a quarter octave
    assert plan.neohookean_factor(8.0 * rest, 0.01) == 16.0            # 8 x min(4, 8 / 4)
    assert plan.neohookean_factor(32.0 * rest, 0.01) == 128.0          # the accuracy factor stops at 4
    for _ in range(5):
        assert plan.neohookean_factor(rest, 0.01) == 128.0
    assert plan.neohookean_factor(rest, 0.01) == 1.0
    fresh = StretchPlan(model, hold=0.05, energy="neohookean")
    assert fresh.neohookean_factor(rest, 0.01, inverted=True) == StretchPlan.INVERTED   # an inverted element
    assert fresh.neohookean_factor(8.0 * rest, 0.01, inverted=True) == 8.0 * StretchPlan.INVERTED
    with pytest.raises(ValueError, match="neohookean_factor"):
        plan.factor(np.zeros_like(model.rest), 0.01)


def _graded():
    """The graded cantilever of tests/test_mass_scaling.py: a thin tip layer (5 mm against 50 mm) whose light, stiff
    elements set the step, at the scene's default damping."""
    from tests.test_mass_scaling import graded_bar
    return graded_bar()[0]


def _tangent_lam(model, u):
    """The largest eigenvalue of M^-1 K_t on the free DOFs, K_t = -df/du the Neo-Hookean tangent at u (central
    differences of the numpy force, which is a polynomial in u)."""
    from clusterfem_ros.fem.materials.neohookean import reference_force
    free = model.free_dofs
    K = np.empty((free.size, free.size))
    eps = 1e-7
    for k, j in enumerate(free):
        d = np.zeros(u.size)
        d[j] = eps
        d = d.reshape(u.shape)
        K[:, k] = -(reference_force(model, u + d) - reference_force(model, u - d)).reshape(-1)[free] / (2 * eps)
    s = 1.0 / np.sqrt(np.repeat(model.mass, 3)[free])
    return float(np.linalg.eigvalsh(0.5 * (K + K.T) * s[:, None] * s[None, :])[-1])


def _plans(model, u, lam):
    """(the element-by-element factor, the body-wide one) of a damped body at u, fresh plans (no hold)."""
    from clusterfem_ros.fem.materials.element_warping import ElementFrames
    from clusterfem_ros.fem.materials.neohookean import tangent_bounds
    frames = ElementFrames.from_model(model)
    tangent_bounds(model, u, frames)
    each = StretchPlan(model, energy="neohookean", lam_max=lam).element_factor(frames.rot_lanes, 0.001)
    whole = StretchPlan(model, energy="neohookean").element_factor(frames.rot_lanes, 0.001)
    return each, whole


def test_each_elements_weight_is_its_own_rest_eigenvalue_over_the_bodys():
    """r_e = lambda_max(K_e, M_e) / lambda_max with the element's vertices' whole masses: at most 1 (the body's
    Rayleigh quotient on one element's vertices), near 1 on the thin tip layer that sets the step, a small share on
    the thick layers."""
    from scipy.linalg import eigh
    from clusterfem_ros.fem.linear.assembly import element_stiffness_blocks
    from clusterfem_ros.fem.materials.stretch import element_weights
    from clusterfem_ros.fem.stability import max_eigenvalue
    model = _graded()
    lam = max_eigenvalue(model)
    r = element_weights(model, lam)
    tets = model.mesh.tets
    thin = model.rest[tets][:, :, 0].min(axis=1) > 0.349
    assert (r <= 1.0).all() and r[thin].max() > 0.5, r[thin].max()
    assert r[~thin].max() < 0.2 * r[thin].max(), (r[thin].max(), r[~thin].max())
    K = element_stiffness_blocks(model.mesh, model.material)
    for e in (0, int(np.flatnonzero(thin)[0])):
        Ke = np.transpose(K[e], (0, 2, 1, 3)).reshape(12, 12)
        Me = np.diag(np.repeat(model.mass[tets[e]], 3))
        assert r[e] == pytest.approx(min(1.0, eigh(Ke, Me, eigvals_only=True)[-1] / lam), rel=1e-9)


def test_stretched_heavy_elements_leave_the_step_to_the_light_ones():
    """The graded bar's thick layers stretched 1.6x along x, its thin tip layer carried rigidly: the body-wide plan
    takes their stiffening for the whole body (more than 2 sub-steps' worth); element by element the factor stays 1,
    and the true tangent's largest eigenvalue is within the step's stability margin of the linear one."""
    from clusterfem_ros.fem.stability import max_eigenvalue
    model = _graded()
    lam = max_eigenvalue(model)
    u = np.zeros_like(model.rest)
    u[:, 0] = 0.6 * np.minimum(model.rest[:, 0], 0.35)
    each, whole = _plans(model, u, lam)
    true = _tangent_lam(model, u) / lam
    print(f"thick layers stretched 1.6x: true largest eigenvalue {true:.3f} lambda_max, plans {each:.3g} element by "
          f"element, {whole:.3g} body-wide")
    assert whole > 2.0 and each == 1.0
    assert true <= 1.05


@pytest.mark.parametrize("case", ["thin layer stretched", "thin layer crushed", "thin layer inverted", "random"])
def test_the_element_plan_covers_the_true_tangent_and_never_exceeds_the_body_wide_one(case):
    """Where the light elements themselves deform (the tip layer stretched 1.6x, crushed to 0.4 of its thickness
    and sheared, folded through itself) or everything moves at random, the element factor times lambda_max stays
    above 0.64 of the true tangent's largest eigenvalue (a step at safety 0.8 of the planned critical step is
    stable) and at most the body-wide factor; a stretch of the light elements raises it."""
    from clusterfem_ros.fem.stability import max_eigenvalue
    model = _graded()
    lam = max_eigenvalue(model)
    u = np.zeros_like(model.rest)
    tip = model.rest[:, 0] > 0.354
    if case == "thin layer stretched":
        u[tip, 0] = 0.6 * 0.005
    elif case == "thin layer crushed":
        u[tip, 0] = -0.6 * 0.005
        u[tip, 1] = 0.004 * np.sign(model.rest[tip, 1] - 0.05)
    elif case == "thin layer inverted":
        u[tip, 0] = -1.5 * 0.005
    else:
        u = 0.01 * np.random.default_rng(5).standard_normal(u.shape)
        u[model.fixed] = 0.0
    each, whole = _plans(model, u, lam)
    true = _tangent_lam(model, u) / lam
    print(f"{case}: true largest eigenvalue {true:.3f} lambda_max, plans {each:.3g} element by element, "
          f"{whole:.3g} body-wide")
    assert true <= each / 0.64 and each <= whole
    if case in ("thin layer stretched", "random"):
        assert each > 1.0


def test_a_damped_body_plans_for_the_stiffening_alone_and_holds_it_briefly():
    """The accuracy factors (past the knee, and INVERTED for an inverted element) are an undamped body's; a damped
    one takes the stiffening alone, and falls back after DAMPED_HOLD instead of HOLD."""
    from clusterfem_ros.fem.materials.element_rotation import LANES
    bar = _bar()
    lam, mu = bar.material.lame
    rest = 3 * lam + 2 * mu
    damped = StretchPlan(bar, energy="neohookean")
    assert bar.material.xi > 0 and damped.hold == StretchPlan.DAMPED_HOLD["neohookean"] < StretchPlan.HOLD["neohookean"]
    undamped = StretchPlan(build_model(bar.mesh, Material(E=1e6, xi=0.0, zeta=0.0)), energy="neohookean")
    assert undamped.hold == StretchPlan.HOLD["neohookean"]
    kept = np.full((damped.weights.shape[0], 9 * LANES), rest)
    kept[0, 3] = 8.0 * rest
    assert damped.element_factor(kept, 0.001) == 8.0
    assert undamped.element_factor(kept, 0.001, undamped=True) == 16.0          # 8 x min(4, 8 / 4)
    kept[0, 3] = -rest                                                            # inverted
    assert StretchPlan(bar, energy="neohookean").element_factor(kept, 0.001) == 1.0
    assert StretchPlan(bar, energy="neohookean").element_factor(kept, 0.001, undamped=True) == StretchPlan.INVERTED
    for _ in range(15):
        assert damped.element_factor(kept, 0.001) == 8.0                         # held 20 ms
    assert [damped.element_factor(kept, 0.001) for _ in range(10)][-1] == 1.0


@pytest.mark.parametrize("accuracy, inverted", [(4.0, 16.0), (1.0, 0.0)])
def test_element_need_is_the_formula_element_by_element(accuracy, inverted):
    """element_need against the formula in numpy, exactly: s_e = max(1, |b_e| / rest modulus), a_e = the inverted
    factor for an inverted element (when > 0) else min(accuracy, max(1, s_e / knee)), the max of r_e s_e a_e; on
    bounds from rest to 30x stiffer, a few inverted, the last chunk's padding lanes weighing 0. The rows carry the
    rest of the force pass's workspace after the bounds (kept[:, LANES:]), which must not be read."""
    rng = np.random.default_rng(7)
    chunks, rest_modulus, knee = 5, 9.0e4, 4.0
    kept = rng.uniform(1.0e4, 3.0e6, (chunks, 9 * LANES)) * np.where(rng.random((chunks, 9 * LANES)) < 0.02, -1, 1)
    kept[:, LANES:] = 1e30                                     # the rotations' slots: never a bound
    weights = rng.uniform(0.05, 1.0, (chunks, LANES))
    weights[-1, LANES // 2:] = 0.0                             # padding lanes
    b = kept[:, :LANES]
    s = np.maximum(1.0, np.abs(b) / rest_modulus)
    a = np.minimum(accuracy, np.maximum(1.0, s / knee))
    if inverted > 0.0:
        a = np.where(b < 0.0, inverted, a)
    assert (b < 0.0).any() and (s > knee * accuracy).any()
    want = float((weights * s * a).max())
    assert element_need(kept, weights, rest_modulus, knee, accuracy, inverted, np.empty(LANES)) == want
