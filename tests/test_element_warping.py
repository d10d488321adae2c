"""Per-element warping (fem/materials/element_warping.py): kernel == numpy twin, force = -grad of the corotated energy,
no force or damping for rigid motion at any angle, linear for small deformations, energy conserved undamped."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros import config
from clusterfem_ros.fem.materials.corotational import ElementCorotation
from clusterfem_ros.fem.materials.element_warping import WARPING_MODELS, ElementFrames, element_force, element_rotations
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from tests.meshes import random_delaunay_mesh

MAT = Material(E=1.0e5, nu=0.3, rho=1000.0, xi=0.7, zeta=0.01)
UNDAMPED = Material(E=1.0e5, nu=0.3, rho=1000.0, xi=0.0, zeta=0.0)
EPS = np.finfo(float).eps


def _bent(model, rng, strain=0.05, angle=2.0):
    """A large rigid rotation of the rest shape plus a random deformation of relative size ``strain``."""
    R = Rotation.from_rotvec(angle * np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])).as_matrix()
    size = np.ptp(model.rest, axis=0).max()
    return model.rest @ R.T - model.rest + strain * size * rng.standard_normal(model.rest.shape) / 10


@pytest.mark.parametrize("mesh", [box_mesh((0.3, 0.1, 0.1), (3, 1, 1)), random_delaunay_mesh(80)],
                         ids=["box", "delaunay"])
def test_kernel_matches_numpy_twin_and_threads_give_the_same_bits(mesh):
    seed = 5
    rng = np.random.default_rng(seed)
    model = build_model(mesh, MAT)
    u, v = _bent(model, rng), rng.standard_normal(mesh.vertices.shape)
    twin = ElementCorotation(model)                    # K_e blocks, not the kernel's stress form
    frames = ElementFrames.from_model(model)
    f = element_force(model, u, v, frames)
    R = frames.rot.copy()
    err = np.abs(f - twin.force(u, v, R)).max() / np.abs(f).max()
    assert err < 1e3 * EPS, f"seed {seed}: kernel vs numpy twin relative error {err:.3g}"
    # the polar factor where F_e is not inverted (inverted elements: the fallback's branch, checked below)
    F = np.eye(3) + np.einsum("eai,eaj->eij", u[model.mesh.tets], twin.g)
    good = np.linalg.det(F) > 0
    assert np.abs(R[good] - twin.rotations(u)[good]).max() < 1e-11
    for threads in (False, True):
        assert np.array_equal(element_force(model, u, v, threads=threads), f)


def test_force_is_minus_the_gradient_of_the_corotated_energy():
    """Central differences of the energy along random directions against -f . d (zeta = xi = 0)."""
    seed = 11
    rng = np.random.default_rng(seed)
    model = build_model(random_delaunay_mesh(60), UNDAMPED)
    size = np.ptp(model.rest, axis=0).max()
    p = model.rest / size
    smooth = 0.1 * size * np.stack([np.sin(3 * p[:, 1]), p[:, 0] * p[:, 2], np.cos(2 * p[:, 0]) * p[:, 1]], axis=1)
    u = _bent(model, rng, strain=0.0) + smooth @ Rotation.from_rotvec([0.3, 1.0, 0.2]).as_matrix().T
    twin = ElementCorotation(model)
    F = np.eye(3) + np.einsum("eai,eaj->eij", u[model.mesh.tets], twin.g)
    assert (np.linalg.det(F) > 0).all()             # polar(F) is the rotation of every element (seed's state)
    print(f"strain up to {np.abs(np.linalg.svd(F, compute_uv=False) - 1).max():.2f}")
    f = element_force(model, u)
    for _ in range(5):
        d = rng.standard_normal(u.shape)
        d /= np.linalg.norm(d)
        dx = 1e-6 * np.ptp(model.rest)
        slope = (twin.energy(u + dx * d) - twin.energy(u - dx * d)) / (2 * dx)
        work = -float((f * d).sum())
        # central differences: error ~ dx^2 |E'''| + eps |E| / dx
        tol = 1e-6 * np.abs(f).sum() + 1e2 * EPS * twin.energy(u) / dx
        assert abs(slope - work) < tol, f"seed {seed}: dE/ds {slope:.12g} vs -f.d {work:.12g}"


@pytest.mark.parametrize("angle", [0.3, np.pi / 2, 2.5, np.pi])
def test_rigid_motion_has_no_elastic_or_damping_force(angle):
    model = build_model(random_delaunay_mesh(60), MAT)
    R = Rotation.from_rotvec(angle * np.array([0.6, 0.0, 0.8])).as_matrix()
    x = model.rest @ R.T + [0.3, -2.0, 1.0]
    omega = np.array([1.0, -2.0, 0.5])
    v = np.cross(omega, x) + [0.2, 0.1, -3.0]                  # a rigid spin and translation
    f = element_force(model, x - model.rest, v) + MAT.xi * model.mass[:, None] * v
    scale = abs(model.K).max() * (np.ptp(model.rest) + MAT.zeta * np.abs(v).max())
    assert np.abs(f).max() < 1e3 * EPS * scale, f"angle {angle}: |f| {np.abs(f).max():.3g}, scale {scale:.3g}"


def test_small_deformation_is_the_linear_force_to_second_order():
    rng = np.random.default_rng(2)
    model = build_model(random_delaunay_mesh(60), MAT)
    g = ElementCorotation(model).g
    u1, v1 = rng.standard_normal(model.rest.shape), rng.standard_normal(model.rest.shape) / MAT.zeta
    errs = []
    for size in (1e-5, 1e-6):
        u, v = size * u1, size * v1
        lin = (-(model.K @ (u + MAT.zeta * v).reshape(-1))).reshape(-1, 3) - MAT.xi * model.mass[:, None] * v
        err = np.abs(element_force(model, u, v) - lin).max() / np.abs(lin).max()
        strain = np.abs(np.einsum("eai,eaj->eij", u[model.mesh.tets], g)).max()
        assert err < 10 * strain, f"strain {strain:.3g}: relative difference {err:.3g}"
        errs.append(err)
    assert errs[1] < 0.2 * errs[0]                      # the difference is second order: it falls with |u|


def test_an_inverted_element_gets_a_proper_rotation_and_a_finite_restoring_force():
    model = build_model(box_mesh((0.1, 0.1, 0.1), (1, 1, 1)), UNDAMPED)
    frames = ElementFrames.from_model(model)
    u = np.zeros(model.rest.shape)
    top = model.rest[:, 2] > 0.05
    for z in np.linspace(0.0, -0.15, 16):                     # push the top through the bottom, step by step
        u[top, 2] = z
        R = element_rotations(model, u, frames)
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-12)
    f = element_force(model, u, frames=frames)
    assert np.isfinite(f).all()
    assert f[top, 2].sum() > 0                                # pushes the top back up


def test_undamped_free_body_conserves_energy():
    """A twisted, stretched free bar released with no damping or gravity: symplectic Euler keeps the corotated
    energy within its shadow-energy oscillation (no drift) over 4000 steps."""
    mesh = box_mesh((0.3, 0.1, 0.1), (6, 2, 2))
    model = build_model(mesh, UNDAMPED, gravity=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(4)
    integ = make_integrator("clustered", model, warp=True, threads=False,
                            allow_unbounded_warping=True)     # undamped: refused unless acknowledged
    state = State.rest(model)
    p = model.rest / 0.3
    state.u[:] = _bent(model, rng, strain=0.0, angle=1.0) + 0.05 * np.stack([p[:, 1] ** 2, p[:, 0] * p[:, 2],
                                                                             np.sin(3 * p[:, 0])], axis=1)
    state.v[:] = np.cross([0.0, 0.0, 3.0], model.rest) + 0.1 * rng.standard_normal(model.rest.shape)
    frames = ElementFrames.from_model(model)
    twin = ElementCorotation(model)

    def energy():
        return twin.energy(state.u, element_rotations(model, state.u, frames)) + model.kinetic_energy(state.v)
    e0 = energy()
    h = 0.05 * integ.critical_step()       # symplectic Euler's energy oscillates by O(h omega): kept small
    seen = []
    for _ in range(4000):
        integ.step(state, Control(), h)
        seen.append(energy())
    seen = np.array(seen)
    first, last = seen[:1000], seen[-1000:]
    print(f"E0 {e0:.6g} J, range {seen.min() / e0:.4f} .. {seen.max() / e0:.4f}")
    assert seen.max() < 1.03 * e0 and seen.min() > 0.97 * e0
    assert abs(last.mean() - first.mean()) < 0.002 * e0        # no drift


def test_clustered_and_standard_explicit_element_warping_agree_over_a_run():
    model = build_model(box_mesh((0.3, 0.1, 0.1), (3, 1, 1)), MAT, fixed=np.arange(4))
    out = []
    for method in ("clustered", "standard_explicit"):
        integ = make_integrator(method, model, warp=True)
        s = State.rest(model)
        s.v[:] = [0.0, 0.5, 2.0]
        for _ in range(30):
            integ.step(s, Control(), 0.01)
        out.append(s)
    scale = np.abs(out[1].u).max()
    assert np.abs(out[0].u - out[1].u).max() < 1e-10 * scale


def test_warping_model_choices_are_checked_and_shared_with_the_config():
    assert config.WARPING_MODELS == WARPING_MODELS
    assert config.check_value("warping_model", "vertex") == "vertex"
    with pytest.raises(config.ConfigError):
        config.check_value("warping_model", "cluster")
    model = build_model(box_mesh((0.1, 0.1, 0.1), (1, 1, 1)), MAT)
    for method in ("clustered", "standard_explicit", "implicit_direct"):
        with pytest.raises(ValueError, match="warping_model = 'cluster'.*'element'"):
            make_integrator(method, model, warp=True, warping_model="cluster")


def test_material_and_scene_share_one_set_of_material_defaults():
    params = {p.name: p.default for p in config.PARAMS}
    assert Material().E == params["material.young_modulus"] == 3.0e4
    assert Material().nu == params["material.poisson_ratio"]
    assert Material().rho == params["material.density"]
    assert Material().xi == params["material.mass_damping"]
    assert Material().zeta == params["material.stiffness_damping"]
