"""Stress: exact constant-strain states (uniaxial, shear), von Mises, principal values, rotation invariance."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.materials.stress import compute_stress, von_mises
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh, paper_mesh
from tests import naive
from tests.meshes import random_delaunay_mesh

MAT = Material(E=2.0e5, nu=0.3, rho=1000.0)
TOL = 1e-10


@pytest.fixture(scope="module")
def cube():
    return build_model(box_mesh((0.1, 0.1, 0.1), (3, 3, 3)), MAT)


@pytest.mark.parametrize("corotated", [False, True])
def test_uniaxial_stretch_free_to_contract(cube, corotated):
    eps = 1e-4
    x = cube.rest
    u = np.column_stack([eps * x[:, 0], -MAT.nu * eps * x[:, 1], -MAT.nu * eps * x[:, 2]])
    s = compute_stress(cube, u, corotated=corotated)
    expected = np.zeros((3, 3))
    expected[0, 0] = MAT.E * eps
    # F is symmetric positive definite, so polar(F) = I: the corotated stress is the same (SVD round-off)
    tol = TOL if not corotated else 1e-8
    for field in (s.element_stress, s.vertex_stress):
        assert np.abs(field - expected).max() <= tol * MAT.E * eps
    assert np.allclose(s.element_von_mises, MAT.E * eps, rtol=tol)
    assert np.allclose(s.element_principal, [0.0, 0.0, MAT.E * eps], atol=tol * MAT.E * eps)


def test_pure_shear_gives_g_gamma_and_von_mises_sqrt3_tau(cube):
    gamma = 2e-4
    x = cube.rest
    u = np.column_stack([0.5 * gamma * x[:, 1], 0.5 * gamma * x[:, 0], np.zeros(len(x))])   # symmetric shear
    s = compute_stress(cube, u)
    G = MAT.E / (2 * (1 + MAT.nu))
    tau = G * gamma
    assert np.abs(s.element_stress[:, 0, 1] - tau).max() <= TOL * tau
    assert np.abs(s.element_stress[:, 1, 0] - tau).max() <= TOL * tau
    assert np.abs(s.element_stress[:, [0, 1, 2], [0, 1, 2]]).max() <= TOL * tau
    assert np.allclose(s.element_von_mises, np.sqrt(3) * tau, rtol=TOL)
    assert np.allclose(s.vertex_von_mises, np.sqrt(3) * tau, rtol=TOL)
    assert np.allclose(s.element_principal, [-tau, 0.0, tau], atol=TOL * tau)


@pytest.mark.parametrize("angle_deg", [30.0, 120.0, 180.0])
def test_rigid_rotation_is_stress_free_only_when_corotated(angle_deg):
    model = build_model(random_delaunay_mesh(120), MAT)
    R = Rotation.from_rotvec(np.deg2rad(angle_deg) * np.array([0.2, 0.9, -0.4]) / np.linalg.norm([0.2, 0.9, -0.4]))
    u = R.apply(model.rest) - model.rest + [0.1, 0.0, -0.3]
    co = compute_stress(model, u, corotated=True)
    lin = compute_stress(model, u, corotated=False)
    print(f"{angle_deg} deg: max von Mises corotated {co.element_von_mises.max():.2e} Pa, "
          f"linear {lin.element_von_mises.max():.2e} Pa (E = {MAT.E:.0e} Pa)")
    assert co.element_von_mises.max() < 1e-10 * MAT.E and co.vertex_von_mises.max() < 1e-10 * MAT.E
    assert lin.element_von_mises.max() > 1e-3 * MAT.E * (1 - np.cos(np.deg2rad(angle_deg)))


def test_corotated_stress_rotates_with_the_body():
    """Stretch, then rotate rigidly: the corotated stress tensor is the rotated tensor, invariants equal."""
    model = build_model(paper_mesh("cube"), MAT)
    x = model.rest
    G = np.array([[1.0, 0.2, 0.0], [0.0, -0.5, 0.3], [0.1, 0.0, 0.4]]) * 1e-3
    F0 = np.eye(3) + 0.5 * (G + G.T)                                       # symmetric: no rotation inside
    Q = Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix()
    s0 = compute_stress(model, x @ F0.T - x, corotated=True)
    s1 = compute_stress(model, x @ (Q @ F0).T - x, corotated=True)
    assert np.allclose(s1.element_stress, Q @ s0.element_stress @ Q.T, atol=1e-9 * MAT.E * 1e-3)
    assert np.allclose(s1.element_von_mises, s0.element_von_mises, rtol=1e-9)


def test_von_mises_of_known_states():
    assert von_mises(np.diag([1.0, 0.0, 0.0])) == pytest.approx(1.0)
    assert von_mises(np.diag([5.0, 5.0, 5.0])) == pytest.approx(0.0, abs=1e-12)    # hydrostatic


def test_von_mises_of_a_model_state_is_corotated_by_default():
    model = build_model(paper_mesh("cube"), MAT)
    u = Rotation.from_rotvec([0.0, 1.5, 0.0]).apply(model.rest) - model.rest
    assert von_mises(model, u).max() < 1e-10 * MAT.E
    assert von_mises(model, u, corotated=False).max() > 1e-2 * MAT.E


def test_bad_input_is_named(cube):
    with pytest.raises(ValueError, match="expected"):
        compute_stress(cube, np.zeros((3, 3)))
    u = np.zeros((cube.n_vertices, 3))
    u[0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        compute_stress(cube, u)


def test_batched_newton_polar_equals_the_svd_polar_including_inverted_and_flat_elements():
    from clusterfem_ros.fem.materials.corotational import polar_rotations
    rng = np.random.default_rng(7)
    F = np.eye(3) + 0.6 * rng.standard_normal((400, 3, 3))
    F[:20, :, 0] *= -1.0                                   # inverted
    F[20:25, :, 2] = 0.0                                   # flat
    U, _, Vt = np.linalg.svd(F)
    d = np.sign(np.linalg.det(U @ Vt))
    d[d == 0] = 1.0
    U[..., :, 2] *= d[..., None]
    R_svd = U @ Vt
    R = polar_rotations(F)
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert np.abs(R - R_svd)[25:].max() < 1e-12            # the Newton path
    assert np.abs(np.einsum("eji,ejk->eik", R, R) - np.eye(3)).max() < 1e-12


@pytest.mark.parametrize("corotated", [True, False])
def test_stress_equals_the_numpy_twin_on_a_twisted_stretched_sphere(corotated):
    """The paper's sphere (1085 tets: several chunks of the polar iteration's lanes) twisted by up to 25 deg
    and stretched 5 %: element and vertex tensors and their von Mises values equal the numpy twin's (SVD
    polar, np.add.at averages) to round-off."""
    model = build_model(paper_mesh("sphere"), MAT)
    x = model.rest
    angle = 0.44 * x[:, 0] / np.ptp(x[:, 0])
    c, s = np.cos(angle), np.sin(angle)
    bent = np.stack([1.05 * x[:, 0], c * x[:, 1] - s * x[:, 2], s * x[:, 1] + c * x[:, 2]], axis=1)
    u = bent - x
    assert model.mesh.n_tets > 3 * 128
    assert (np.linalg.det(_gradients(model, u)) > 0).all()                     # nothing inverted
    lam, mu = MAT.lame
    sigma, vs = naive.stress(x, model.mesh.tets, u, lam, mu, corotated)
    got = compute_stress(model, u, corotated=corotated)
    scale = np.abs(sigma).max()
    assert np.abs(got.element_stress - sigma).max() < 1e-9 * scale
    assert np.abs(got.vertex_stress - vs).max() < 1e-9 * scale
    assert np.allclose(got.element_von_mises, von_mises(sigma), rtol=1e-8, atol=1e-9 * scale)
    assert np.allclose(got.vertex_von_mises, von_mises(vs), rtol=1e-8, atol=1e-9 * scale)


def _gradients(model, u):
    e0, e = model.rest[model.mesh.tets], (model.rest + u)[model.mesh.tets]
    edges = lambda x: np.stack([x[:, k] - x[:, 0] for k in (1, 2, 3)], axis=2)    # noqa: E731
    return edges(e) @ np.linalg.inv(edges(e0))


def test_inverted_elements_get_a_proper_rotation_and_a_finite_stress():
    """Tets pushed through themselves take the scalar fallback (the nearest proper rotation from I): the
    stress stays finite and the others' equal the twin's."""
    model = build_model(random_delaunay_mesh(200), MAT)
    rng = np.random.default_rng(4)
    u = 0.001 * rng.standard_normal(model.rest.shape)
    flip = model.mesh.tets[:5, 0]
    u[flip] = 2.0 * (model.rest[model.mesh.tets[:5, 1:]].mean(axis=1) - model.rest[flip])     # through the face
    got = compute_stress(model, u, corotated=True)
    x = model.rest + u
    e = x[model.mesh.tets]
    det = np.linalg.det(np.stack([e[:, 1] - e[:, 0], e[:, 2] - e[:, 0], e[:, 3] - e[:, 0]], axis=1))
    inverted = det * np.linalg.det(np.stack([model.rest[model.mesh.tets][:, k] - model.rest[model.mesh.tets][:, 0]
                                              for k in (1, 2, 3)], axis=1)) < 0
    assert inverted.sum() >= 5
    assert np.isfinite(got.element_stress).all() and np.isfinite(got.vertex_von_mises).all()
    lam, mu = MAT.lame
    sigma, _ = naive.stress(model.rest, model.mesh.tets, u, lam, mu, True)
    ok = ~inverted
    assert np.abs(got.element_stress[ok] - sigma[ok]).max() < 1e-9 * np.abs(sigma[ok]).max()
