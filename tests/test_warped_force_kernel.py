"""The warped force's slice sweeps (fem/kernels/warped_force_kernel.py): with the rotations held, the force equals the
numpy twin's symmetric eq. 10 to round-off at every lane width, serial and threaded give the same bits, and the
padding lanes write exact zeros; the deformation gradients equal the twin's least-squares F_i."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.kernels.cluster_force_kernel import finish_serial, input_rows
from clusterfem_ros.fem.kernels.cluster_slices import aligned_zeros, lane_vertices, rest_offsets, slice_clusters
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
from clusterfem_ros.fem.kernels.warped_force_kernel import (ROT_ROW, gradient_sweep_parallel, gradient_sweep_serial,
                                                            warped_sweep_parallel, warped_sweep_serial)
from clusterfem_ros.fem.materials.warping import VertexFrames
from tests import naive_warping as naive
from tests.meshes import random_delaunay_mesh

MAT = Material(E=1.0e5, nu=0.3, rho=1000.0, xi=0.7, zeta=0.01)
MESHES = {"sphere": lambda: paper_mesh("sphere"), "torus": lambda: paper_mesh("torus"),
          "delaunay": lambda: random_delaunay_mesh(80)}


def _sweep(model, lanes, R, u, v, sweep=warped_sweep_serial):
    """(e rows, f = -e - xi M v) from the slice sweep with the rotations R held."""
    n = model.n_vertices
    sl = slice_clusters(model.clusters, lanes)
    sh_d, bd_d = rest_offsets(sl, model.rest)
    w = input_rows(sl)
    w[:n] = model.rest + u + MAT.zeta * v
    rot4 = aligned_zeros((n, ROT_ROW))
    rot4.reshape(n, 3, 4)[:, :, :3] = R
    e = np.full((len(sl.owner), 3), np.nan)
    sweep(sl.shared_ptr, (sl.shared_w_at, sl.shared_blocks, sh_d), (sl.boundary_w_at, sl.boundary_blocks, bd_d),
          (w, rot4, lane_vertices(sl), sl.owner, e))
    f = np.empty((n, 3))
    finish_serial(e, v, np.repeat(model.mass, 3), MAT.xi, f)
    return e, f


@pytest.mark.parametrize("lanes", [2, 4, 8])
@pytest.mark.parametrize("name", MESHES)
def test_the_sweep_equals_the_twin_with_rotations_held(name, lanes):
    """Rotations at any angle, unrelated to u (the sweep must not assume they come from it)."""
    model = build_model(MESHES[name](), MAT)
    n = model.n_vertices
    rng = np.random.default_rng(lanes)
    R = Rotation.random(n, random_state=lanes).as_matrix()
    size = np.ptp(model.rest, axis=0).max()
    u, v = 0.1 * size * rng.standard_normal((2, n, 3))
    _, f = _sweep(model, lanes, R, u, v)
    ref = naive.BlockTwin(model.K, model.rest).force(u, v, model.mass, MAT.zeta, MAT.xi, R=R)
    rel = np.abs(f - ref).max() / np.abs(ref).max()
    assert rel <= 1e-12, f"{name}, {lanes} lanes: relative difference {rel:.3g}"


@pytest.mark.parametrize("lanes", [2, 4, 8])
def test_serial_and_threaded_sweeps_agree_to_the_bit_and_padding_rows_are_zero(lanes):
    model = build_model(paper_mesh("torus"), MAT)
    n = model.n_vertices
    rng = np.random.default_rng(7)
    R = Rotation.random(n, random_state=7).as_matrix()
    u, v = 0.01 * rng.standard_normal((2, n, 3))
    e, _ = _sweep(model, lanes, R, u, v)
    e_threaded, _ = _sweep(model, lanes, R, u, v, sweep=warped_sweep_parallel)
    assert np.array_equal(e, e_threaded)
    assert np.all(e[n:] == 0.0), "a padding lane wrote something other than zero"
    assert np.isfinite(e[:n]).all()


def test_a_rigid_motion_gives_zero_elastic_force():
    """All rotations equal to the body's: the sweep's e vanishes to round-off (the force is -xi M v)."""
    model = build_model(paper_mesh("sphere"), MAT)
    n = model.n_vertices
    Q = Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix()
    x0 = model.rest
    u = x0 @ Q.T + np.array([0.3, -0.2, 0.5]) - x0
    e, _ = _sweep(model, 8, np.repeat(Q[None], n, axis=0), u, np.zeros_like(u))
    scale = abs(model.K).max() * np.abs(x0).max()
    assert np.abs(e[:n]).max() <= 1e-12 * scale


@pytest.mark.parametrize("lanes", [2, 4, 8])
@pytest.mark.parametrize("name", ["sphere", "delaunay"])
def test_the_gradient_sweep_gives_each_vertex_its_least_squares_deformation_gradient(name, lanes):
    """F_i = [sum_j (x_j - x_i) d_ij^T] S_i^-1 (the twin, from the assembled blocks' pattern), lane k of F holding
    vertex owner[k]; the padding lanes hold the identity; the threaded sweep gives the same bits."""
    model = build_model(MESHES[name](), MAT)
    n = model.n_vertices
    sl = slice_clusters(model.clusters, lanes)
    frames = VertexFrames.from_model(model, sl)
    sh_ptr, shared, boundary, lane_vertex, owner = frames.gradients
    u = 0.1 * np.ptp(model.rest, axis=0).max() * np.random.default_rng(lanes).standard_normal((n, 3))
    u_rows = input_rows(sl)
    u_rows[:n] = u
    F = np.full((9, len(owner)), np.nan)
    gradient_sweep_serial(sh_ptr, shared, boundary, (u_rows, lane_vertex, F))
    twin = naive.BlockTwin(model.K, model.rest)
    x = model.rest + u
    e = x[twin.j] - x[twin.i]
    ref = (twin._sum(e[:, :, None] * twin.d[:, None, :]) @ twin.S_inv).reshape(n, 9)
    real = owner < n
    got = np.empty((n, 9))
    got[owner[real]] = F[:, real].T
    assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.all(F[:, ~real] == np.eye(3).reshape(9, 1))
    F_threaded = np.full_like(F, np.nan)
    gradient_sweep_parallel(sh_ptr, shared, boundary, (u_rows, lane_vertex, F_threaded))
    assert np.array_equal(F, F_threaded)
