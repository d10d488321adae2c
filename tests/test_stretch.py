"""The stretch bound that plans warped explicit sub-steps (fem/materials/stretch.py)."""
import numpy as np
import pytest
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.linear.assembly import shape_gradients
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.materials.stretch import StretchPlan, stiffening
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
