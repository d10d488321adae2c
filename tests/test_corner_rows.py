"""The vector corner rows (fem/materials/corner_rows.py) against what they stand for, bit for bit: the corner
differences against their numpy twin (tests/naive.py), the sums by vertex against the threaded pass's gather,
on a mesh with vertices and tets in random order, a vertex count that is no multiple of the 4-lane groups and
a last chunk with padding lanes."""
import numba
import numpy as np

from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.materials.corner_rows import (GROUP, ROW, add_corner_rows, corner_row_differences,
                                                      corner_row_differences_of_two)
from clusterfem_ros.fem.materials.element_rotation import LANES
from clusterfem_ros.fem.materials.element_warping import ElementFrames, gather_serial
from clusterfem_ros.fem.mesh.tet_mesh import TetMesh
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.fem.model import build_model
from tests import naive


@numba.njit
def _differences_of_two(corner, u, w, D, DW):
    corner_row_differences_of_two(corner, u, w, D, DW)


@numba.njit
def _differences(corner, u, D):
    corner_row_differences(corner, u, D)


@numba.njit
def _sums(corner, fe, m, rows):
    for c in range(corner.shape[0]):
        add_corner_rows(corner[c], fe[c], min(LANES, m - c * LANES), rows)


def _shuffled_frames(rng):
    """ElementFrames of a box mesh with its vertices renumbered and its tets reordered at random."""
    box = box_mesh((0.5, 0.1, 0.15), (6, 2, 4))
    n = box.n_vertices
    new = rng.permutation(n)
    vertices = np.empty_like(box.vertices)
    vertices[new] = box.vertices
    mesh = TetMesh(vertices, new[box.tets][rng.permutation(box.n_tets)])
    frames = ElementFrames.from_model(build_model(mesh, Material(E=1e6, nu=0.3)))
    assert n % GROUP and frames.m % LANES                 # a partial 4-lane group of rows, a padding chunk
    return frames, n


def test_the_vector_differences_are_the_scalar_ones_bit_for_bit():
    rng = np.random.default_rng(11)
    frames, n = _shuffled_frames(rng)
    corner = frames.elems[0]
    u = rng.normal(size=(n, 3))                           # no row past the last vertex's
    w = rng.normal(size=(n + 1, 3)) * 1e3
    for c in range(corner.shape[0]):
        D, DW, D1 = (np.full(9 * LANES, np.nan) for _ in range(3))
        _differences_of_two(corner[c], u, w, D, DW)
        _differences(corner[c], u, D1)
        ref = naive.corner_differences(corner[c], u)
        assert np.array_equal(D, ref) and np.array_equal(D1, ref)
        assert np.array_equal(DW, naive.corner_differences(corner[c], w))


def test_the_vector_sums_by_vertex_are_the_gather_bit_for_bit():
    rng = np.random.default_rng(12)
    frames, n = _shuffled_frames(rng)
    fe = rng.normal(size=frames.fe.shape)
    fe.reshape(-1, 12, LANES)[-1, :, frames.m % LANES:] = np.nan        # padding lanes: left out
    e = np.full((n + 1, 3), np.nan)
    gather_serial(frames.gather, fe, e)                   # ascending element order, vertex by vertex
    rows = np.zeros((n + 1, ROW))
    _sums(frames.elems[0], fe, frames.m, rows)
    assert np.array_equal(rows[:n, :3], e[:n])
    assert not rows[n].any() and not rows[:, 3].any()     # the row after the last vertex's and the padding
