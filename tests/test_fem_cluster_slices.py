"""The clusters packed C rows at a time (SELL-C): the same blocks, and the same force at every width."""
import numpy as np
import pytest
import scipy.sparse as sp

from clusterfem_ros.fem.linear.assembly import assemble_stiffness, element_stiffness_blocks, lumped_mass
from clusterfem_ros.fem.kernels.cluster_force_kernel import (cluster_args, force_kernel_parallel, force_kernel_serial,
                                                             scratch)
from clusterfem_ros.fem.kernels.cluster_slices import host_slices, host_slices_nbytes, slice_clusters
from clusterfem_ros.fem.kernels.clusters import build_clusters
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
from tests.meshes import random_delaunay_mesh

MAT = Material(E=2.0e5, nu=0.35, rho=1100.0, xi=3.0, zeta=0.02)
MESHES = {"sphere": lambda: paper_mesh("sphere"), "torus": lambda: paper_mesh("torus"),
          "delaunay": random_delaunay_mesh}


def _lanes_of(sl):
    """(vertex of every lane of the shared part, of the boundary part): -1 where a lane is padding."""
    C = sl.lanes
    n_sh_slices = len(sl.shared_ptr) - 1
    owner = np.where(sl.owner < sl.n_vertices, sl.owner, -1)
    return owner[:n_sh_slices * C].reshape(-1, C), owner[n_sh_slices * C:].reshape(-1, C)


@pytest.mark.parametrize("name", MESHES)
@pytest.mark.parametrize("lanes", [2, 4, 8])
def test_slices_hold_every_block_once_and_pad_only_with_zero_blocks_on_the_own_vertex(name, lanes):
    mesh = MESHES[name]()
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    sl = slice_clusters(cl, lanes)
    sh_owner, bd_owner = _lanes_of(sl)
    entries, padding = {}, 0
    sections = [(sh_owner, sl.shared_ptr, sl.shared_cols, sl.shared_blocks),
                (bd_owner, 4 * np.arange(len(bd_owner) + 1), sl.boundary_cols, sl.boundary_blocks)]
    for owner, ptr, cols, blocks in sections:
        for s in range(len(owner)):
            for p in range(ptr[s], ptr[s + 1]):
                for lane in range(lanes):
                    i, j, b = owner[s, lane], cols[p, lane], blocks[p, :, lane].reshape(3, 3)
                    if i < 0 or not b.any():
                        assert not b.any() and (i < 0 or j == i), f"padding at slice {s}, position {p}, lane {lane}"
                        padding += 1
                        continue
                    assert (i, j) not in entries, f"block ({i}, {j}) appears twice"
                    entries[i, j] = b
    dense = cl.to_dense_rows()
    assert len(entries) == cl.n_blocks
    for (i, j), b in entries.items():
        np.testing.assert_array_equal(b, dense[i][j])
    assert padding == sl.n_padded_blocks - cl.n_blocks
    # shared rows sorted longest first keep the padding small
    assert sl.n_padded_blocks <= 1.15 * cl.n_blocks + 3 * lanes * lanes


@pytest.mark.parametrize("lanes", [2, 4, 8])
@pytest.mark.parametrize("threads", [False, True])
def test_every_lane_width_gives_the_assembled_force_to_round_off(lanes, threads):
    mesh = paper_mesh("torus")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    sl = slice_clusters(cl, lanes)
    rng = np.random.default_rng(lanes)
    u = rng.normal(scale=1e-2, size=(mesh.n_vertices, 3))
    v = rng.normal(scale=1e-1, size=(mesh.n_vertices, 3))
    K = assemble_stiffness(mesh, MAT)
    m = lumped_mass(mesh, MAT.rho)
    ref = (-(K @ u.ravel()) - (MAT.xi * sp.diags(np.repeat(m, 3)) + MAT.zeta * K) @ v.ravel()).reshape(-1, 3)
    w, kw = scratch(sl)
    f = np.empty_like(u)
    kernel = force_kernel_parallel if threads else force_kernel_serial
    kernel(*cluster_args(sl), u, v, np.repeat(m, 3), MAT.zeta, MAT.xi, w, kw, f)
    rel = np.abs(f - ref).max() / np.abs(ref).max()
    assert rel <= 1e-12, f"{lanes} lanes: relative difference {rel:.3g}"
    assert not kw[mesh.n_vertices:].any(), "a padding lane's row holds a non-zero sum"


@pytest.mark.parametrize("lanes", [2, 4, 8])
def test_every_lane_writes_a_row_of_its_own_the_vertices_first(lanes):
    """The sweep stores each lane's sums in row owner[lane]: vertex i in row i, each padding lane in a row past
    the n vertices' that no other lane writes (threads never share a row)."""
    mesh = paper_mesh("sphere")
    sl = slice_clusters(build_clusters(mesh, element_stiffness_blocks(mesh, MAT)), lanes)
    assert sorted(sl.owner) == list(range(len(sl.owner)))
    assert len(sl.owner) == sl.n_slices * lanes
    sh_owner, bd_owner = _lanes_of(sl)
    assert sorted(np.r_[sh_owner.ravel(), bd_owner.ravel()])[-mesh.n_vertices:] == list(range(mesh.n_vertices))


def test_a_lane_count_the_kernel_has_no_build_for_is_refused():
    mesh = paper_mesh("cube")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    with pytest.raises(ValueError, match="lanes = 3"):
        slice_clusters(cl, 3)


def test_equal_ranges_of_slices_carry_similar_work_for_the_threaded_sweep():
    """The threaded sweep hands each thread an equal range of slices: sorting rows by length over the whole
    mesh gave the first half of a box's slices 2.7x the positions of the second."""
    from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
    mesh = box_mesh((0.1, 0.1, 0.1), (24, 24, 24))
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    ptr = slice_clusters(cl, 8).shared_ptr
    half = (len(ptr) - 1) // 2
    first, second = ptr[half] - ptr[0], ptr[-1] - ptr[half]
    assert 0.8 < first / second < 1.25, f"positions in the two halves: {first} vs {second}"


@pytest.mark.parametrize("lanes", [2, 4, 8])
def test_the_benchmarks_held_w_control_is_the_sweep_of_a_uniform_w(lanes):
    """benchmarks/core_benchmark's control (the sweep without the gather) computes K applied to w's row 0 in every
    vertex, bit for bit as the real sweep does, and a uniform w is a rigid translation: K w = 0."""
    from benchmarks.core_benchmark import stiffness_held_w_serial
    from clusterfem_ros.fem.kernels.cluster_force_kernel import stiffness_slices_serial
    mesh = paper_mesh("sphere")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    sl = slice_clusters(cl, lanes)
    w, held = scratch(sl)
    w[:mesh.n_vertices] = np.random.default_rng(3).normal(size=(mesh.n_vertices, 3))
    stiffness_held_w_serial(*cluster_args(sl), w, held)
    uniform, swept = scratch(sl)
    uniform[:] = w[0]
    stiffness_slices_serial(*cluster_args(sl), uniform, swept)
    np.testing.assert_array_equal(held, swept)
    scale = np.abs(sl.shared_blocks).max() * np.abs(w[0]).max()
    assert np.abs(held).max() <= 1e-10 * scale


def test_the_slices_are_built_on_first_use_and_their_size_is_reported_only_then():
    """A model that never runs the linear kernel (warping has its own) holds no second copy of the blocks."""
    mesh = paper_mesh("sphere")
    cl = build_clusters(mesh, element_stiffness_blocks(mesh, MAT))
    assert host_slices_nbytes(cl) == 0
    sl = host_slices(cl)
    assert host_slices(cl) is sl
    assert host_slices_nbytes(cl) == sl.nbytes >= sl.shared_blocks.nbytes + sl.boundary_blocks.nbytes
