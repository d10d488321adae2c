"""body/limb_bridges.py: the tets a mesher puts across the gap between a character's left and right limbs."""
from types import SimpleNamespace

import numpy as np

from clusterfem_ros.body.limb_bridges import bridge_tets, cut_bridges
from clusterfem_ros.fem.mesh.tet_mesh import TetMesh, signed_volumes


def _oriented(v: np.ndarray, tets: np.ndarray) -> np.ndarray:
    tets = tets.copy()
    flip = signed_volumes(v, tets) < 0
    tets[flip, 0], tets[flip, 1] = tets[flip, 1], tets[flip, 0].copy()
    return tets


def _legs():
    """Two shins 0.2 m apart along x and a pelvis above them; a tet on each shin, one across the gap between them,
    one from the pelvis down to both."""
    starts = np.array([[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.5]])
    ends = np.array([[-0.1, 0.0, 0.45], [0.1, 0.0, 0.45], [0.0, 0.0, 0.7]])
    roles = SimpleNamespace(roles=["shin", "shin", "pelvis"], sides=["l", "r", ""])
    v = np.array([[-0.12, 0.0, 0.1], [-0.08, 0.02, 0.1], [-0.1, -0.02, 0.12], [-0.1, 0.0, 0.15],     # left shin
                  [0.12, 0.0, 0.1], [0.08, 0.02, 0.1], [0.1, -0.02, 0.12], [0.1, 0.0, 0.15],         # right shin
                  [0.0, 0.0, 0.6], [0.0, 0.05, 0.62]])                                                # pelvis
    tets = _oriented(v, np.array([[0, 1, 2, 3], [4, 5, 6, 7], [1, 5, 2, 3], [8, 9, 3, 7]]))
    return TetMesh(v, tets).validate(), starts, ends, roles


def test_only_a_tet_joining_the_left_and_right_limbs_is_a_bridge():
    mesh, starts, ends, roles = _legs()
    binds = np.ones(3, dtype=bool)
    # the pelvis tet reaches both shins' flesh too, through the trunk: a human's flesh joins them there
    assert bridge_tets(mesh.vertices, mesh.tets, starts, ends, roles, binds).tolist() == [False, False, True, False]
    # a bone that binds no flesh is no corner's nearest: without the right shin its flesh is measured to the left one
    assert not bridge_tets(mesh.vertices, mesh.tets, starts, ends, roles, np.array([True, False, True])).any()


def test_cutting_the_bridges_keeps_the_rest_and_drops_the_vertices_left_in_no_tet():
    mesh, starts, ends, roles = _legs()
    bridges = bridge_tets(mesh.vertices, mesh.tets, starts, ends, roles, np.ones(3, dtype=bool))
    cut = cut_bridges(mesh, bridges)
    assert cut.n_tets == 3 and cut.n_vertices == 10            # every vertex is still in a tet
    assert np.allclose(cut.vertices[cut.tets], mesh.vertices[mesh.tets[~bridges]])
    one = TetMesh(mesh.vertices, mesh.tets[[0, 2]])
    alone = cut_bridges(one, np.array([False, True]))
    assert alone.n_vertices == 4 and np.allclose(alone.vertices, mesh.vertices[:4])
