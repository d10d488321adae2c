"""The SPD factorization the implicit and modal baselines share: exact solves, less fill, clear refusals."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.integrators.spd_factor import factorize_spd
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh

from .meshes import random_delaunay_mesh

MAT = Material(E=5e4, nu=0.35, rho=1000.0, xi=2.0, zeta=1e-3)


def _system(mesh, h=1e-3):
    z = mesh.vertices[:, 2]
    model = build_model(mesh, MAT, fixed=z < z.min() + 0.2 * np.ptp(z))
    A = sp.diags(np.repeat(model.mass, 3)) + h * model.damping_matrix() + h * h * model.K
    free = np.flatnonzero(np.repeat(~model.fixed, 3))
    return sp.csc_matrix(A.tocsr()[free][:, free])


@pytest.mark.parametrize("mesh", [paper_mesh("sphere"), paper_mesh("torus"), random_delaunay_mesh()],
                         ids=["sphere", "torus", "delaunay"])
def test_solve_is_exact_to_round_off_and_fills_less_than_the_default_ordering(mesh):
    A = _system(mesh, h=1e-2)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    fac = factorize_spd(A)
    x = fac.solve(b)
    assert np.linalg.norm(A @ x - b) <= 1e-13 * np.linalg.norm(b)
    assert np.allclose(x, spla.spsolve(A, b), rtol=0, atol=1e-12 * np.abs(x).max())
    default = spla.splu(A)                                # COLAMD, symmetry ignored
    print(f"{mesh.n_tets} tets: nnz(L+U) symmetric {fac.nnz}, default {default.L.nnz + default.U.nnz}")
    assert fac.nnz < 0.8 * (default.L.nnz + default.U.nnz)
    y = fac.operator() @ b
    assert np.array_equal(y, x)


def test_a_matrix_that_is_not_positive_definite_is_refused_by_name():
    A = sp.csc_matrix(np.diag([2.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="diagonal entry 1 is 0.0.*not positive definite"):
        factorize_spd(A)
    with pytest.raises(ValueError, match="not square"):
        factorize_spd(sp.csc_matrix(np.ones((2, 3))))
