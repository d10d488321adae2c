"""Selective mass scaling (fem/mass_scaling.py): the Gershgorin rates bound the stiffest mode, the cap raises only
the vertices above it, and a mesh moved off its grid gets its grid's critical step back for a little mass."""
import numpy as np
import pytest

from clusterfem_ros.fem.linear.material import Material, ParameterError
from clusterfem_ros.fem.mass_scaling import cap_rates, reference_rate, scale_to_reference, vertex_rates
from clusterfem_ros.fem.mesh.tet_mesh import TetMesh
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.fem.model import build_model
from clusterfem_ros.fem.stability import max_eigenvalue

MATERIAL = Material(E=3e4, nu=0.3, rho=1000.0, xi=2.0, zeta=1e-4)


def _thinned(seed: int = 3) -> tuple[TetMesh, TetMesh]:
    """(a 4x4x4 box, the same tets with its top face's inner vertices pushed down 0.45 of an edge and jittered)."""
    grid = box_mesh((0.4, 0.4, 0.4), (4, 4, 4))
    x = grid.vertices.copy()
    top = np.flatnonzero((x[:, 2] > 0.4 - 1e-9) & (np.abs(x[:, :2] - 0.2).max(axis=1) < 0.2 - 1e-9))
    x[top, 2] -= 0.045
    x[top, :2] += np.random.default_rng(seed).uniform(-0.01, 0.01, (top.size, 2))
    return grid, TetMesh(x, grid.tets.copy()).validate()


def _dense_lam(K, mass) -> float:
    s = 1.0 / np.sqrt(np.repeat(mass, 3))
    return float(np.linalg.eigvalsh((s[:, None] * K.toarray()) * s[None, :])[-1])


def test_the_rates_are_gershgorin_row_sums_and_bound_the_largest_eigenvalue():
    grid, thin = _thinned()
    model = build_model(thin, MATERIAL)
    rates = vertex_rates(model.K, model.mass)
    dense = np.abs(model.K.toarray()).sum(axis=1).reshape(-1, 3).max(axis=1) / model.mass
    assert rates == pytest.approx(dense, rel=1e-13)
    lam = _dense_lam(model.K, model.mass)
    assert lam <= rates.max() * (1 + 1e-12)
    assert lam > 0.3 * rates.max()             # a bound, not a far one


def test_the_cap_raises_only_the_vertices_above_it_to_exactly_the_cap():
    grid, thin = _thinned()
    model = build_model(thin, MATERIAL)
    rates = vertex_rates(model.K, model.mass)
    cap = float(np.percentile(rates, 80))
    s = cap_rates(model.K, model.mass, cap)
    above = rates > cap
    assert np.array_equal(s.raised, np.flatnonzero(above))
    assert np.array_equal(s.mass[~above], model.mass[~above])
    assert (s.mass[above] > model.mass[above]).all()
    assert vertex_rates(model.K, s.mass)[above] == pytest.approx(cap, rel=1e-12)
    assert s.added_share == pytest.approx(s.mass.sum() / model.mass.sum() - 1, rel=1e-12)
    assert _dense_lam(model.K, s.mass) <= cap * (1 + 1e-12)


def test_a_moved_mesh_gets_its_grids_critical_step_back():
    """The box's top pushed in makes thinner tets: a larger eigenvalue; scaled to the box, its largest eigenvalue
    is the box's for a few per cent of mass, most of it on the vertices that moved or share a tet with one (the
    cap, lowered until the eigenvalues match, also reaches the grid's own stiffest vertices: its corners)."""
    grid, thin = _thinned()
    lam_grid = max_eigenvalue(build_model(grid, MATERIAL))
    own = build_model(thin, MATERIAL)
    lam_own = max_eigenvalue(own)
    scaled, s = scale_to_reference(own, grid)
    lam_scaled = max_eigenvalue(scaled)
    print(f"lambda: grid {lam_grid:.4g}, moved {lam_own:.4g}, scaled {lam_scaled:.4g}; {s.summary(grid.n_vertices)}")
    assert lam_own > 1.5 * lam_grid
    assert lam_scaled <= lam_grid * 1.003 and lam_scaled > 0.9 * lam_grid
    assert s.eigenvalues[0] == pytest.approx(lam_own, rel=1e-6) and s.eigenvalues[2] == pytest.approx(lam_grid, rel=1e-6)
    assert 0 < s.added_share < 0.05
    moved = np.flatnonzero(np.abs(thin.vertices - grid.vertices).max(axis=1) > 0)
    near = np.unique(grid.tets[np.isin(grid.tets, moved).any(axis=1)])
    added = scaled.mass - own.mass
    assert added[near].sum() > 0.6 * added.sum() and (added >= 0).all()
    assert scaled.mass.sum() == pytest.approx(own.mass.sum() * (1 + s.added_share), rel=1e-12)
    # the reference itself is unchanged by its own cap
    assert cap_rates(build_model(grid, MATERIAL).K, build_model(grid, MATERIAL).mass,
                     reference_rate(grid, MATERIAL)).raised.size == 0


def test_bad_input_is_refused_with_the_value():
    grid, thin = _thinned()
    model = build_model(thin, MATERIAL)
    with pytest.raises(ParameterError, match="rate cap = 0"):
        cap_rates(model.K, model.mass, 0.0)
    with pytest.raises(ParameterError, match="vertex 2 has mass 0.0"):
        vertex_rates(model.K, np.where(np.arange(model.n_vertices) == 2, 0.0, model.mass))
    other = box_mesh((0.4, 0.4, 0.4), (3, 4, 4))
    with pytest.raises(ParameterError, match="same tets"):
        scale_to_reference(model, other)
