"""Modal baseline: eigenpairs against dense eigh, all modes == standard implicit, convergence in k."""
import numpy as np
import pytest
import scipy.linalg as sla

from clusterfem_ros.fem.integrators import modal
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.material import Material, ParameterError
from clusterfem_ros.fem.integrators.modal import ModalIntegrator, modal_basis
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.voxel_mesh import box_mesh

MAT = Material(E=5.0e4, nu=0.3, rho=1000.0, xi=1.0, zeta=2e-3)


def _bar(div=(4, 1, 1), fixed=True):
    mesh = box_mesh((0.4, 0.1, 0.1), div)
    return build_model(mesh, MAT, fixed=np.isclose(mesh.vertices[:, 0], 0.0) if fixed else None)


def _dense_eigenvalues(model):
    free = model.free_dofs
    K = model.K[free][:, free].toarray()
    return sla.eigh(K, np.diag(np.repeat(model.mass, 3)[free]), eigvals_only=True)


@pytest.mark.parametrize("fixed", [True, False], ids=["clamped", "free"])
def test_eigsh_modes_match_dense_eigh(monkeypatch, fixed):
    model = _bar((6, 2, 2), fixed)
    monkeypatch.setattr(modal, "DENSE_MAX_DOFS", 0)             # force the shift-invert eigsh path
    b = modal_basis(model, 16)
    ref = _dense_eigenvalues(model)[:16]
    scale = ref[-1]
    assert np.abs(b.lam - np.maximum(ref, 0)).max() <= 1e-9 * scale
    if not fixed:
        assert np.abs(b.lam[:6]).max() <= 1e-9 * scale and b.lam[6] > 1e-3 * scale     # six rigid modes
    assert np.allclose(b.phi.T @ (b.mass[:, None] * b.phi), np.eye(16), atol=1e-10)
    K = model.K[b.free][:, b.free]
    assert np.allclose(b.phi.T @ (K @ b.phi), np.diag(b.lam), atol=1e-9 * scale)


def _run(integ, model, steps=40, h=0.01, prescribed=None):
    s = State.rest(model)
    rng = np.random.default_rng(5)
    s.v[:] = 0.05 * rng.standard_normal(s.v.shape)
    f_ext = np.zeros((model.n_vertices, 3))
    f_ext[-1] = [0.0, 0.3, 0.1]
    for k in range(steps):
        c = Control(f_ext=f_ext)
        if prescribed is not None:
            c = Control(f_ext=f_ext, prescribed_index=prescribed, prescribed_u=np.full((len(prescribed), 3), 1e-3 * k),
                        prescribed_v=np.full((len(prescribed), 3), 0.1))
        info = integ.step(s, c, h)
    return s, info


@pytest.mark.parametrize("case", ["clamped", "free", "prescribed"])
def test_all_modes_reproduce_standard_implicit(case):
    model = _bar(fixed=case != "free")
    prescribed = np.array([model.n_vertices - 1]) if case == "prescribed" else None
    full = 3 * model.n_vertices
    s_modal, info = _run(make_integrator("modal", model, k=full), model, prescribed=prescribed)
    s_ref, _ = _run(make_integrator("implicit_direct", model), model, prescribed=prescribed)
    err = np.abs(s_modal.u - s_ref.u).max() / np.abs(s_ref.u).max()
    print(f"{case}: all modes vs implicit direct, relative error {err:.2e}")
    assert err < 1e-9
    assert np.abs(s_modal.v - s_ref.v).max() < 1e-9 * np.abs(s_ref.v).max()
    assert info.substeps == 1 and info.iterations == 0


def test_error_falls_as_modes_are_added():
    model = _bar((8, 2, 2))
    ref, _ = _run(make_integrator("implicit_direct", model), model, steps=30)
    ks = [5, 10, 20, 40]
    errs = [np.abs(_run(ModalIntegrator(model, k=k), model, steps=30)[0].u - ref.u).max() / np.abs(ref.u).max()
            for k in ks]
    print("modal error vs full implicit for k = " + ", ".join(f"{k}: {e:.3e}" for k, e in zip(ks, errs)))
    assert all(b < a for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 0.3 * errs[0]


def test_bad_k_is_named():
    with pytest.raises(ParameterError, match="modal k"):
        ModalIntegrator(_bar(), k=0)
