"""A static cantilever under gravity converges to the Euler-Bernoulli deflection q L^4 / (8 E I)."""
import numpy as np
import scipy.sparse.linalg as spla

from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh

L, A = 1.0, 0.05            # slender: L / a = 20, so shear (Timoshenko) corrections are ~0.1 %
MAT = Material(E=1.0e9, nu=0.0, rho=1000.0)


def tip_deflection(n_across: int) -> float:
    mesh = box_mesh((L, A, A), (20 * n_across, n_across, n_across))
    model = build_model(mesh, MAT, fixed=np.isclose(mesh.vertices[:, 0], 0.0), gravity=(0, 0, -9.81))
    free = model.free_dofs
    u = np.zeros(3 * model.n_vertices)
    u[free] = spla.spsolve(model.K[free][:, free].tocsc(), model.gravity_force().ravel()[free])
    tip = np.isclose(mesh.vertices[:, 0], L)
    return -u.reshape(-1, 3)[tip, 2].mean()


def test_cantilever_converges_to_euler_bernoulli():
    q = MAT.rho * 9.81 * A * A
    I = A ** 4 / 12.0
    exact = q * L ** 4 / (8.0 * MAT.E * I)
    ns = [2, 3, 4, 6]
    errs = [abs(tip_deflection(n) - exact) / exact for n in ns]
    h = [A / n for n in ns]
    rate = np.polyfit(np.log(h), np.log(errs), 1)[0]
    print(f"Euler-Bernoulli tip deflection {exact * 1e3:.4f} mm; relative errors {np.round(errs, 4).tolist()} "
          f"at h = {h}; observed rate {rate:.2f}")
    assert all(b < a for a, b in zip(errs, errs[1:])), "error must fall with every refinement"
    assert rate > 1.5, f"observed convergence rate {rate:.2f}, expected about 2 for linear tets"
    assert errs[-1] < 0.07
