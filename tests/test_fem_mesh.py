"""Meshes: voxel generation near the paper's sizes, validation errors, shape quality, surface, vertex classes, I/O."""
import meshio
import numpy as np
import pytest

from clusterfem_ros.fem.mesh.mesh_io import read_mesh, write_mesh
from clusterfem_ros.fem.mesh.tet_mesh import (MeshError, TetMesh, boundary_triangles, elements_per_vertex,
                                              vertex_classes)
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.mesh.tet_quality import mesh_quality, tet_quality
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh, cells_mesh, grid_mesh, paper_mesh

from . import naive

PAPER = {"sphere": (376, 1091), "cube": (453, 1198), "torus": (609, 1823)}


@pytest.mark.parametrize("name", PAPER)
def test_paper_meshes_are_valid_and_near_the_papers_size(name):
    mesh = paper_mesh(name).validate()
    nv, nt = PAPER[name]
    print(f"{name}: {mesh.n_vertices} vertices / {mesh.n_tets} tets (paper {nv} / {nt})")
    assert abs(mesh.n_tets - nt) / nt < 0.15
    assert abs(mesh.n_vertices - nv) / nv < 0.25


def test_refined_mesh_scales_as_the_cube_of_the_resolution():
    a, b = paper_mesh("cube", 1.0), paper_mesh("cube", 2.0)
    assert b.n_tets == 8 * a.n_tets


def test_box_volume_is_exact():
    mesh = box_mesh((0.3, 0.2, 0.1), (3, 4, 5))
    assert mesh.volumes().sum() == pytest.approx(0.3 * 0.2 * 0.1, rel=1e-13)
    assert (mesh.volumes() > 0).all()



def test_voxel_meshes_equal_the_dense_grid_twin_vertex_for_vertex():
    """grid_mesh (through cells_mesh, which numbers only the corners its cells use) gives the mesh of the dense
    corner grid, vertex for vertex and tet for tet, on random masks of random shapes."""
    rng = np.random.default_rng(7)
    for trial in range(20):
        mask = rng.random(tuple(rng.integers(1, 9, 3))) < rng.uniform(0.1, 0.9)
        mask.flat[rng.integers(mask.size)] = True
        lo, h = rng.normal(size=3), rng.uniform(0.001, 0.3, 3)
        vertices, tets = naive.grid_mesh(mask, lo, h)
        mesh = grid_mesh(mask, lo, h)
        assert np.array_equal(mesh.vertices, vertices) and np.array_equal(mesh.tets, tets), f"trial {trial}"


def test_cells_far_apart_cost_their_own_corners_only():
    """Two voxels 10,000 voxels apart on every axis: 10 tets on their 16 corners (a dense grid of their corners
    would be 10^12 vertices), each at lo + its index * spacing."""
    far = 10_000
    mesh = cells_mesh(np.array([[0, 0, 0], [far, far + 1, far]]), np.array([1.0, 2.0, 3.0]), np.full(3, 0.01))
    assert (mesh.n_tets, mesh.n_vertices) == (10, 16)
    assert mesh.volumes().sum() == pytest.approx(2e-6, rel=1e-6)
    corner = np.round((mesh.vertices - [1.0, 2.0, 3.0]) / 0.01).astype(np.int64)
    assert {tuple(c) for c in corner[8:]} == {(far + i, far + 1 + j, far + k) for i in (0, 1) for j in (0, 1)
                                               for k in (0, 1)}
    with pytest.raises(MeshError, match=r"indices >= 0"):
        cells_mesh(np.array([[0, -1, 0]]), np.zeros(3), np.full(3, 0.01))


@pytest.mark.parametrize("name", PAPER)
def test_boundary_surface_is_closed_and_outward(name):
    mesh = paper_mesh(name)
    tri = boundary_triangles(mesh)
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all(), "every surface edge borders exactly two triangles"
    x = mesh.vertices[tri]
    n2 = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])     # 2 * area * outward normal
    # divergence theorem: integral of x.n over the surface = 3 V (outward normals)
    flux = np.einsum("ij,ij->", x.mean(axis=1), n2) / 2.0
    assert flux == pytest.approx(3.0 * mesh.volumes().sum(), rel=1e-12)


def test_vertex_classes_follow_the_paper():
    mesh = paper_mesh("sphere")
    shared, boundary = vertex_classes(mesh)
    count = elements_per_vertex(mesh)
    assert len(shared) + len(boundary) == mesh.n_vertices
    assert (count[boundary] == 1).all() and (count[shared] >= 2).all()
    assert len(boundary) > 0


def _tiny():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    t = np.array([[0, 1, 2, 3], [1, 3, 2, 4]])    # the second is inverted
    return v, t


def test_inverted_tet_is_named_with_its_signed_volume():
    v, t = _tiny()
    with pytest.raises(MeshError, match=r"tet 1 has signed volume -0\.\d+"):
        TetMesh(v, t).validate()


def test_zero_volume_tet_is_refused():
    v, t = _tiny()
    v[4] = [0.5, 0.5, 0.0]                       # coplanar with 1, 2 and on the z = 0 plane
    t = np.array([[0, 1, 2, 3], [1, 2, 4, 0]])
    with pytest.raises(MeshError, match="tet 1 has signed volume"):
        TetMesh(v, t).validate()


def test_unreferenced_vertex_and_out_of_range_and_nan_are_named():
    v, t = _tiny()
    t = t[:1]
    assert TetMesh(v[:4], t).validate().n_tets == 1
    with pytest.raises(MeshError, match="vertex 4 is not used"):
        TetMesh(v, t).validate()
    with pytest.raises(MeshError, match=r"tet 0 has vertex indices \[0, 1, 2, 9\] outside \[0, 4\]"):
        TetMesh(v, np.array([[0, 1, 2, 9]])).validate()
    v[2, 1] = np.nan
    with pytest.raises(MeshError, match="vertex 2 has non-finite coordinates"):
        TetMesh(v, t).validate()


@pytest.mark.parametrize("ext", [".msh", ".vtk", ".vtu", ".mesh"])
def test_meshio_round_trip(tmp_path, ext):
    mesh = paper_mesh("torus")
    path = tmp_path / f"torus{ext}"
    write_mesh(path, mesh)
    back = read_mesh(path)
    np.testing.assert_allclose(back.vertices, mesh.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.tets, mesh.tets)


def test_reading_a_surface_only_file_says_what_is_missing(tmp_path):
    path = tmp_path / "surface.vtu"
    meshio.write_points_cells(str(path), np.eye(3), [("triangle", np.array([[0, 1, 2]]))])
    with pytest.raises(MeshError, match="no tetrahedra"):
        read_mesh(path)


def test_reading_flips_inverted_tets_only_when_asked(tmp_path):
    mesh = box_mesh((1, 1, 1), (2, 2, 2))
    t = mesh.tets.copy()
    t[3, [2, 3]] = t[3, [3, 2]]
    path = tmp_path / "flipped.vtu"
    meshio.write_points_cells(str(path), mesh.vertices, [("tetra", t)])
    with pytest.raises(MeshError, match="tet 3 has signed volume"):
        read_mesh(path)
    assert (read_mesh(path, orient=True).volumes() > 0).all()


def test_total_volume_equals_the_sum_of_the_signed_volumes_to_round_off():
    from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes, total_volume
    rng = np.random.default_rng(7)
    mesh = box_mesh((0.3, 0.2, 0.2), (3, 2, 2))
    moved = mesh.vertices + 0.02 * rng.standard_normal(mesh.vertices.shape) + 1e3      # far from the origin
    want = signed_volumes(moved, mesh.tets).sum()
    got = total_volume(moved, np.ascontiguousarray(mesh.tets.T))
    assert abs(got - want) <= 1e-9 * abs(want), (got, want)
    flipped = moved.copy()
    flipped[:, 0] *= -1.0                                       # a mirrored body: every tet inverted
    assert total_volume(flipped, np.ascontiguousarray(mesh.tets.T)) == -got


def _sliver(height: float) -> TetMesh:
    """A regular-based tet whose apex sits ``height`` (of the edge) above its base: flat for small heights."""
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0]])
    apex = np.array([[0.5, np.sqrt(3) / 6, height]])
    return TetMesh(np.vstack([base, apex]), np.array([[0, 1, 2, 3]]))


def test_tet_quality_is_one_for_a_regular_tet_and_falls_with_flatness():
    regular = _sliver(np.sqrt(2.0 / 3.0))
    assert tet_quality(regular.vertices, regular.tets)[0] == pytest.approx(1.0, rel=1e-12)
    box = box_mesh((1.0, 1.0, 1.0), (1, 1, 1))                     # 4 corner tets and a regular one
    q = np.sort(tet_quality(box.vertices, box.tets))
    assert q[:4] == pytest.approx(np.full(4, 6 * np.sqrt(2) / 6 / 1.5 ** 1.5), rel=1e-12) and q[4] == pytest.approx(1.0)
    heights = np.array([1e-2, 1e-4, 1e-6])
    flat = np.array([tet_quality(_sliver(t).vertices, _sliver(t).tets)[0] for t in heights])
    assert np.all(np.diff(flat) < 0) and np.allclose(flat / heights, flat[-1] / heights[-1], rtol=1e-3)   # q ~ height
    scaled = _sliver(1e-2)
    assert tet_quality(1e-3 * scaled.vertices, scaled.tets)[0] == pytest.approx(flat[0], rel=1e-12)       # scale free


def test_mesh_quality_counts_slivers_and_names_the_worst():
    mesh = box_mesh((0.4, 0.1, 0.1), (4, 1, 1))
    x = mesh.vertices.copy()
    q0 = mesh_quality(x, mesh.tets)
    assert q0.slivers == 0 and q0.worst > 0.7
    x[:, 0] = np.where(np.isclose(x[:, 0], 0.2), 0.1 + 1e-4, x[:, 0])      # squash the second layer
    q = mesh_quality(x, mesh.tets)
    layer = np.isclose(np.sort(x[mesh.tets][:, :, 0], axis=1)[:, -1] - np.sort(x[mesh.tets][:, :, 0], axis=1)[:, 0],
                       1e-4)
    assert q.slivers == int(layer.sum()) > 0 and q.worst < 1e-2 and layer[q.worst_tet]
    assert f"tet {q.worst_tet}" in q.summary() and f"{q.slivers} slivers" in q.summary()


def test_degenerate_tet_is_refused_at_set_up_with_the_way_out():
    mesh = _sliver(1e-9)
    mesh.validate()                                                 # its volume passes
    with pytest.raises(MeshError, match=r"tet 0 has quality .* degenerate.*remesh.*body.min_tet_quality"):
        build_model(mesh, Material())
    model = build_model(mesh, Material(), min_quality=0.0)          # the override accepts it
    assert model.quality.worst < 1e-8 and model.quality.slivers == 1
    assert build_model(box_mesh(), Material()).quality.slivers == 0
