"""The paper's 'lossless' claim: the clustered force equals the assembled sparse product to round-off."""
import numba
import numpy as np
import pytest
import scipy.sparse as sp
from numba import prange

from clusterfem_ros.fem.linear.assembly import assemble_stiffness, element_stiffness_blocks, lumped_mass
from clusterfem_ros.fem.kernels.cluster_force_kernel import (cluster_args, clustered_force, scratch,
                                                             stiffness_slices_serial)
from clusterfem_ros.fem.kernels.cluster_slices import host_slices
from clusterfem_ros.fem.kernels.clusters import build_clusters
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.numba_config import serial_and_parallel
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
from tests import naive
from tests.meshes import random_delaunay_mesh

MAT = Material(E=2.0e5, nu=0.35, rho=1100.0, xi=3.0, zeta=0.02)
MESHES = {"sphere": lambda: paper_mesh("sphere"), "cube": lambda: paper_mesh("cube"),
          "torus": lambda: paper_mesh("torus"), "delaunay": random_delaunay_mesh}


def _assembled(mesh, u, v):
    K = assemble_stiffness(mesh, MAT)
    m = lumped_mass(mesh, MAT.rho)
    D = MAT.xi * sp.diags(np.repeat(m, 3)) + MAT.zeta * K
    return -(K @ u.ravel()) - D @ v.ravel(), m


@pytest.mark.parametrize("name", MESHES)
@pytest.mark.parametrize("threads", [False, True])
def test_clustered_equals_assembled_to_round_off(name, threads):
    seed = 1234
    mesh = MESHES[name]()
    rng = np.random.default_rng(seed)
    u = rng.normal(scale=1e-2, size=(mesh.n_vertices, 3))
    v = rng.normal(scale=1e-1, size=(mesh.n_vertices, 3))
    ref, m = _assembled(mesh, u, v)
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    f = clustered_force(cl, u, v, m, MAT.zeta, MAT.xi, threads=threads)
    rel = np.abs(f.ravel() - ref).max() / np.abs(ref).max()
    assert rel <= 1e-12, f"{name}: relative difference {rel:.3g} (seed {seed})"


def test_kernel_matches_its_plain_numpy_twin():
    mesh = paper_mesh("torus")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    rng = np.random.default_rng(5)
    u, v = rng.normal(size=(2, mesh.n_vertices, 3))
    m = lumped_mass(mesh, MAT.rho)
    ref = naive.cluster_force(cl.to_dense_rows(), mesh.n_vertices, u, v, m, MAT.zeta, MAT.xi)
    np.testing.assert_allclose(clustered_force(cl, u, v, m, MAT.zeta, MAT.xi), ref, rtol=0,
                               atol=1e-12 * np.abs(ref).max())


def test_element_stiffness_matches_textbook_B_transpose_C_B():
    mesh = random_delaunay_mesh(60, seed=3)
    blocks = element_stiffness_blocks(mesh, MAT)
    for e in (0, len(mesh.tets) // 2, len(mesh.tets) - 1):
        Ke = np.transpose(blocks[e], (0, 2, 1, 3)).reshape(12, 12)
        ref = naive.element_stiffness(mesh.vertices[mesh.tets[e]], MAT.E, MAT.nu)
        np.testing.assert_allclose(Ke, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_boundary_clusters_have_four_blocks_and_cover_every_block():
    mesh = paper_mesh("sphere")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    K = assemble_stiffness(mesh, MAT).tobsr(blocksize=(3, 3))
    assert len(cl.boundary_rows) > 0
    assert cl.n_blocks == K.nnz // 9
    assert len(cl.boundary_cols) == 4 * len(cl.boundary_rows)
    assert np.intersect1d(cl.shared_rows, cl.boundary_rows).size == 0
    assert len(cl.shared_rows) + len(cl.boundary_rows) == mesh.n_vertices


def test_bad_state_shape_is_named():
    mesh = paper_mesh("cube")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    with pytest.raises(ValueError, match=r"u has shape \(3, 3\), expected \(343, 3\)"):
        clustered_force(cl, np.zeros((3, 3)), np.zeros((343, 3)), np.ones(343), 0.0, 0.0)
    with pytest.raises(ValueError, match=r"mass has shape \(342,\), expected \(343,\)"):
        clustered_force(cl, np.zeros((343, 3)), np.zeros((343, 3)), np.ones(342), 0.0, 0.0)
    with pytest.raises(ValueError, match=r"out must be a C-contiguous \(343, 3\) float64 array"):
        clustered_force(cl, np.zeros((343, 3)), np.zeros((343, 3)), np.ones(343), 0.0, 0.0, out=np.empty((3, 343)).T)



def test_slice_kernel_refuses_a_workspace_without_the_row_after_the_last():
    """The slice kernel loads w[j] as 4 doubles, one past the row: a w of just the vertices' rows would read past
    the array's end at the last vertex, and rows padded to 4 would be read at the wrong places."""
    mesh = paper_mesh("cube")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    w, kw = scratch(host_slices(cl))
    lanes = len(host_slices(cl).owner)
    assert w.shape == (lanes + 1, 3)
    for bad in (np.zeros((mesh.n_vertices, 3)), np.zeros((lanes, 3)), np.zeros((mesh.n_vertices + 8, 4))):
        with pytest.raises(ValueError, match="rows of 3 .* a row per lane of the slices and one more"):
            stiffness_slices_serial(*cluster_args(host_slices(cl)), bad, kw)
    stiffness_slices_serial(*cluster_args(host_slices(cl)), w, kw)


def test_slice_kernel_refuses_an_output_without_a_row_per_lane():
    """The sweep writes lane l's sums to row owner[l]: an (n, 3) output would miss the padding lanes' rows."""
    mesh = paper_mesh("cube")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    w, _ = scratch(host_slices(cl))
    with pytest.raises(ValueError, match="a row of 3 per lane"):
        stiffness_slices_serial(*cluster_args(host_slices(cl)), w, np.zeros((mesh.n_vertices, 3)))


def _thread_ids(out):
    for i in prange(out.shape[0]):
        out[i] = numba.get_thread_id()


def test_threaded_build_really_runs_on_threads():
    """numba's disk cache keys an entry by function name and signature, not by compile flags: built from one
    function, the parallel dispatcher loaded the serial build's cached code and never ran threaded."""
    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread")
    serial, parallel = serial_and_parallel(_thread_ids)
    out = np.full(100_000, -1, dtype=np.int64)
    serial(out)                     # compiled (and cached) first, as in the kernels' modules
    assert set(out) == {0}
    parallel(out)
    assert len(set(out)) > 1
