"""Stiffness warping (eq. 10): kernel == numpy twin == assembled form; rigid rotations give no force;
a 90 deg bend keeps its volume; small deformations are linear to second order."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.kernels.cluster_force_kernel import clustered_force
from clusterfem_ros.fem.materials.corotational import ElementCorotation
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh, paper_mesh
from clusterfem_ros.fem.materials.assembled_warp import AssembledWarp
from clusterfem_ros.fem.materials.warping import VertexFrames, vertex_rotations, warped_force
from tests import naive_warping as naive
from tests.meshes import random_delaunay_mesh

MAT = Material(E=1.0e5, nu=0.3, rho=1000.0, xi=0.7, zeta=0.01)
AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


def _scale(model, x):
    """|K| |x|: the size a force would have if nothing cancelled."""
    return abs(model.K).max() * np.abs(x).max() * 30


@pytest.mark.parametrize("mesh", [box_mesh((0.3, 0.1, 0.1), (3, 1, 1)), random_delaunay_mesh(80)],
                         ids=["box", "delaunay"])
def test_kernel_matches_numpy_twin(mesh):
    seed = 3
    rng = np.random.default_rng(seed)
    model = build_model(mesh, MAT)
    u = 0.05 * rng.standard_normal((mesh.n_vertices, 3)) * np.ptp(mesh.vertices, axis=0).max()
    v = rng.standard_normal(u.shape)
    twin = naive.BlockTwin(model.K, model.rest)
    f = warped_force(model, u, v)
    f_ref = twin.force(u, v, model.mass, MAT.zeta, MAT.xi)
    err = np.abs(f - f_ref).max() / np.abs(f_ref).max()
    # the noise inverts some neighbourhoods of the Delaunay mesh: those take the iterative fallback
    assert err < 1e-10, f"seed {seed}: kernel vs numpy twin relative error {err:.3g}"
    R = vertex_rotations(model, u)
    assert np.abs(R - twin.rotations(u)).max() < 1e-10
    # the symmetrisation is not a no-op here: eq. 10 as printed differs at this strain
    eq10 = twin.force(u, v, model.mass, MAT.zeta, MAT.xi, form="eq10")
    assert np.abs(eq10 - f_ref).max() > 1e-3 * np.abs(f_ref).max()
    for threads in (False, True):        # every lane's sums in one thread, in one order: the same bits
        assert np.array_equal(warped_force(model, u, v, threads=threads), f)


def test_clustered_warp_equals_assembled_warp_over_a_run():
    """Eq. 10 on the clusters (fused kernel) and on the assembled block-sparse K agree to round-off."""
    model = build_model(paper_mesh("cube"), MAT, fixed=np.flatnonzero(paper_mesh("cube").vertices[:, 2] < -0.049))
    states = []
    for method in ("clustered", "standard_explicit"):
        integ = make_integrator(method, model, warp=True, warping_model="vertex", allow_unbounded_warping=True)
        s = State.rest(model)
        s.v[:] = Rotation.from_rotvec([0, 0, 2.0]).apply(model.rest) * 0 + [0.0, 0.5, 0.0]
        for _ in range(20):
            integ.step(s, Control(), 0.01)
        states.append(s)
    err = np.abs(states[0].u - states[1].u).max() / np.abs(states[1].u).max()
    assert err < 1e-10, f"clustered vs assembled warped run differ by {err:.3g}"


@pytest.mark.parametrize("angle_deg", [10.0, 60.0, 120.0, 179.0, 180.0])
def test_rigid_rotation_gives_no_force_with_warping(angle_deg):
    model = build_model(paper_mesh("sphere"), MAT)
    R = Rotation.from_rotvec(np.deg2rad(angle_deg) * AXIS).as_matrix()
    x = model.rest @ R.T + [0.4, -0.2, 1.0]
    u = x - model.rest
    zero = np.zeros_like(u)
    scale = abs(model.K).max() * np.abs(x).max()            # |K| |x|
    warped = np.abs(warped_force(model, u, zero)).max() / scale
    linear = np.abs(clustered_force(model.clusters, u, zero, model.mass, 0.0, 0.0)).max() / scale
    element = np.abs(ElementCorotation(model).force(u)).max() / scale
    print(f"rotation {angle_deg} deg: |f| / (|K| |x|) warped {warped:.2e}, element corotational {element:.2e}, "
          f"linear {linear:.2e} (linear / warped {linear / max(warped, 1e-300):.1e})")
    assert warped < 1e-14 and element < 1e-14
    assert linear > 1e-3 * (1 - np.cos(np.deg2rad(angle_deg)))
    assert np.abs(vertex_rotations(model, u) - R).max() < 1e-12


def test_rigid_spin_is_not_damped_by_warped_stiffness_damping():
    model = build_model(paper_mesh("sphere"), Material(E=1e5, xi=0.0, zeta=0.05))
    R = Rotation.from_rotvec(2.0 * AXIS).as_matrix()
    x = model.rest @ R.T
    v = np.cross(3.0 * AXIS, x)
    f = warped_force(model, x - model.rest, v)
    assert np.abs(f).max() < 1e-14 * _scale(model, x) * (1 + np.abs(v).max())


def test_inverted_neighbourhood_still_gets_a_proper_rotation():
    """Flatten / mirror the body: the polar factor would be a reflection; the fallback returns a rotation."""
    model = build_model(box_mesh((0.2, 0.1, 0.1), (2, 1, 1)), MAT)
    u = model.rest * [-2.0, 0.0, 0.0]                           # x -> -x: every neighbourhood inverted
    frames = VertexFrames.from_model(model)
    R = vertex_rotations(model, u, frames)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert np.isfinite(warped_force(model, u, frames=frames)).all()


def test_small_deformation_warped_equals_linear_to_second_order():
    model = build_model(paper_mesh("sphere"), MAT)
    rng = np.random.default_rng(11)
    shape = rng.standard_normal((model.n_vertices, 3)) * 0.1
    zero = np.zeros_like(shape)
    amps = np.array([1e-2, 3e-3, 1e-3, 3e-4])
    diffs = []
    for a in amps:
        u = a * shape
        fl = clustered_force(model.clusters, u, zero, model.mass, 0.0, 0.0)
        fw = warped_force(model, u, zero)
        diffs.append(np.abs(fw - fl).max() / (abs(model.K).max() * 0.1))
    rate = np.polyfit(np.log(amps), np.log(diffs), 1)[0]
    print(f"|f_warped - f_linear| for amplitudes {amps}: {np.array(diffs)}; observed order {rate:.2f}")
    assert rate == pytest.approx(2.0, abs=0.15)


def _bend(method, warp, model, end, h=0.01, steps=200, ramp=120):
    """Drive the end face of the bar into a 90 deg quarter circle (arc length kept), then hold."""
    x0 = model.rest
    L = x0[:, 0].max()

    def pose(s):
        th = s * np.pi / 2
        p = np.array([L, 0.0, 0.0]) if th == 0 else np.array([L / th * np.sin(th), 0.0, -L / th * (1 - np.cos(th))])
        return (x0[end] - [L, 0, 0]) @ Rotation.from_rotvec([0, th, 0]).as_matrix().T + p - x0[end]

    integ = make_integrator(method, model, warp=warp)
    s = State.rest(model)
    for k in range(steps):
        a, b = min(1.0, (k + 1) / ramp), min(1.0, (k + 2) / ramp)
        cu = pose(a)
        integ.step(s, Control(prescribed_index=end, prescribed_u=cu, prescribed_v=(pose(b) - cu) / h), h)
    return s


@pytest.mark.parametrize("method", ["clustered", "implicit_direct"])
def test_bar_bent_90_degrees_keeps_its_volume_with_warping(method):
    mesh = box_mesh((1.0, 0.1, 0.1), (20, 2, 2), (0.0, -0.05, -0.05))
    x0 = mesh.vertices
    model = build_model(mesh, Material(E=5e4, nu=0.3, rho=1000.0, xi=20.0, zeta=1e-3),
                        fixed=np.isclose(x0[:, 0], 0.0), gravity=(0, 0, 0))
    end = np.flatnonzero(np.isclose(x0[:, 0], 1.0))
    v0 = signed_volumes(x0, mesh.tets).sum()
    err = {}
    for warp in (False, True):
        s = _bend(method, warp, model, end)
        err[warp] = signed_volumes(x0 + s.u, mesh.tets).sum() / v0 - 1.0
        if warp:    # settled: the per-element corotational reference sees (almost) no residual force
            free = ~model.fixed
            free[end] = False
            fc = np.abs(ElementCorotation(model).force(s.u)[free]).max()
            f_lin = np.abs((model.K @ s.u.reshape(-1)).reshape(-1, 3)[free]).max()
    print(f"{method}: 90 deg bend volume error linear {err[False] * 100:+.2f} %, warped {err[True] * 100:+.3f} %; "
          f"element-corotational residual / linear force there {fc / f_lin:.2e}")
    assert abs(err[True]) < 0.01
    assert err[False] > 0.2
    assert fc < 0.01 * f_lin


def test_rotations_match_the_svd_polar_within_the_iteration_tolerance():
    """The lane-batched polar iteration stops at a squared change of 1e-12 per step, which bounds its error by
    ~1.5e-12 (polar.POLAR_TOL): checked against the SVD on strains from 0.1 % to 40 % plus a large rotation,
    with one inverted vertex inside a chunk of normal ones (that lane alone takes the Mueller fallback)."""
    model = build_model(paper_mesh("torus"), MAT)          # 656 vertices: several chunks, a partial last one
    rows = model.clusters.to_dense_rows()
    x0 = model.rest
    rng = np.random.default_rng(5)
    R = Rotation.from_rotvec(2.5 * AXIS).as_matrix()
    c = x0.mean(axis=0)
    for strain in (1e-3, 3e-2, 0.4):
        G = strain * rng.standard_normal((3, 3))
        bend = 0.5 * strain * np.sin(8 * x0[:, [1, 2, 0]])  # non-uniform: every neighbourhood its own F
        x = (c + (x0 - c) @ (np.eye(3) + G).T + bend) @ R.T
        u = x - x0
        Rk = vertex_rotations(model, u)
        Rs = naive.BlockTwin(model.K, x0).rotations(u)
        err = np.abs(Rk - Rs).max()
        print(f"strain {strain:g}: max |R - R_svd| {err:.2e}")
        assert err < 1e-11
    # one surface vertex pushed through its neighbourhood: F_i = I - u_i h_i^T, h_i = S_i^-1 sum_j (x0_j - x0_i)
    frames = VertexFrames.from_model(model)
    h = np.einsum("nab,nb->na", frames.s0inv, np.array([sum(x0[j] - x0[k] for j in rows[k]) for k in range(len(x0))]))
    i = int(np.argmax(np.linalg.norm(h, axis=1)))
    u = np.zeros_like(x0)
    u[i] = 3.0 * h[i] / (h[i] @ h[i])                       # det F_i = 1 - h_i . u_i = -2
    Rk = vertex_rotations(model, u, frames)
    assert np.allclose(Rk[i] @ Rk[i].T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(Rk[i]), 1.0)
    ok = [j for j in range(model.n_vertices) if i not in rows[j] and j != i]
    assert np.abs(Rk[ok] - np.eye(3)).max() < 1e-14


def test_rest_state_gives_exactly_zero_warped_force():
    """At rest F_i = I exactly and the hoisted rest term b_i is summed in the kernel's order: f == 0."""
    model = build_model(paper_mesh("sphere"), MAT)
    zero = np.zeros((model.n_vertices, 3))
    assert not np.any(warped_force(model, zero, zero))


def test_implicit_velocity_matrix_is_the_held_rotation_jacobian_and_translation_invariant():
    """AssembledWarp.jacobian, standard_implicit's velocity matrix H: H dx = -(f(u + dx) - f(u)) with the rotations of u held (the force is affine in x
    then), and H t = 0 for a translation t, where R K R^T (the system matrix) is not."""
    model = build_model(box_mesh((0.3, 0.1, 0.1), (3, 1, 1)), MAT)
    rng = np.random.default_rng(4)
    u = 0.3 * rng.standard_normal((model.n_vertices, 3)) * 0.1          # large, rough: rotations differ
    assembled = AssembledWarp(model)
    Rk = vertex_rotations(model, u)
    Kw, H = assembled.rotated(Rk), assembled.jacobian(Rk)
    twin = naive.BlockTwin(model.K, model.rest)
    R = twin.rotations(u)
    zero = np.zeros_like(u)
    dx = rng.standard_normal(u.shape)
    df = twin.force(u + dx, zero, model.mass, 0.0, 0.0, R=R) - twin.force(u, zero, model.mass, 0.0, 0.0, R=R)
    assert np.abs(H @ dx.reshape(-1) + df.reshape(-1)).max() < 1e-9 * np.abs(df).max()
    t = np.tile([0.3, -1.0, 2.0], model.n_vertices)
    scale = abs(model.K).max() * np.abs(t).max()
    assert np.abs(H @ t).max() < 1e-12 * scale
    assert np.abs(Kw @ t).max() > 1e-3 * scale
