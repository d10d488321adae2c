"""Warm-started element rotations (fem/materials/element_rotation.py): Newton on the rotation reaches the polar factor
to round-off in a few passes, and the robust path takes over where Newton must not (saddle start, inversion)."""
import numpy as np
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.materials.element_rotation import (LANES, ROTATION_MAXPASS, _newton_rotations,
                                                           _robust_rotations, chunk_rotations)


def _polar(F):
    U, _, Vt = np.linalg.svd(F)
    return U @ Vt


def _lanes(mats):
    """(LANES, 3, 3) -> flat (9 LANES,), entry k of lane l at k LANES + l."""
    return np.ascontiguousarray(mats.reshape(LANES, 9).T.reshape(-1))


def _mats(flat):
    return flat.reshape(9, LANES).T.reshape(LANES, 3, 3)


def _chunk(rng, strain, turn):
    """Deformation gradients of a chunk (stretch up to ``strain``, random rotation) and warm starts R_old, the
    polar factor turned by up to ``turn`` rad: X = R_old^T F, as the element pass makes it."""
    Q = Rotation.random(LANES, random_state=rng).as_matrix()
    S = np.eye(3) + strain * rng.uniform(-1, 1, (LANES, 3, 3))
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    F = Q @ S
    R = _polar(F)
    R_old = R @ Rotation.from_rotvec(turn * rng.uniform(-1, 1, (LANES, 3)) / np.sqrt(3)).as_matrix()
    X = np.swapaxes(R_old, 1, 2) @ F
    return F, R, R_old, X


def _buffers():
    return [np.zeros(9 * LANES) for _ in range(4)], np.zeros(LANES, np.int8), np.zeros((3, 3, 3))


def test_newton_from_the_previous_rotation_reaches_the_polar_factor():
    seed = 3
    rng = np.random.default_rng(seed)
    for strain, turn in ((0.0, 1e-3), (0.1, 1e-2), (0.3, 0.1), (0.3, 0.5)):
        F, R, R_old, X = _chunk(rng, strain, turn)
        (M1, M2, R1, R2), how, tmp = _buffers()
        ok, out = _newton_rotations(_lanes(X), M1, M2, _lanes(R_old), R1, R2)
        assert ok, f"seed {seed}: Newton did not settle in {ROTATION_MAXPASS} passes (strain {strain}, turn {turn})"
        err = np.abs(_mats(out) - R).max()
        assert err < 1e-13, f"seed {seed}: strain {strain}, turn {turn}: |R - polar(F)| = {err:.3g}"


def test_newton_and_the_robust_path_agree():
    rng = np.random.default_rng(8)
    F, R, R_old, X = _chunk(rng, 0.2, 0.05)
    (M1, M2, R1, R2), how, tmp = _buffers()
    _, newton = _newton_rotations(_lanes(X), M1, M2, _lanes(R_old), R1, R2)
    newton = _mats(newton).copy()
    robust = np.zeros(9 * LANES)
    _robust_rotations(_lanes(X), M1, M2, how, tmp, _lanes(R_old), robust)
    assert np.abs(newton - _mats(robust)).max() < 1e-12


def test_a_warm_start_near_a_saddle_goes_to_the_robust_path_and_still_finds_the_polar_factor():
    """Started half a turn away, Newton would settle where R^T F is symmetric with two negative eigenvalues
    (H indefinite); the chunk is redone by the robust path."""
    rng = np.random.default_rng(2)
    F, R, _, _ = _chunk(rng, 0.1, 0.0)
    R_old = R @ Rotation.from_rotvec(np.full((LANES, 3), 3.0 / np.sqrt(3))).as_matrix()
    X = np.swapaxes(R_old, 1, 2) @ F
    (M1, M2, R1, R2), how, tmp = _buffers()
    ok, _ = _newton_rotations(_lanes(X), M1, M2, _lanes(R_old), R1, R2)
    assert not ok
    out = chunk_rotations(_lanes(X), M1, M2, R1, R2, how, tmp, _lanes(R_old))
    assert np.abs(_mats(out) - R).max() < 1e-11


def test_an_inverted_element_takes_the_robust_path_and_gets_a_proper_rotation():
    rng = np.random.default_rng(4)
    F, R, R_old, _ = _chunk(rng, 0.05, 0.01)
    F[7] = F[7] @ np.diag([1.0, 1.0, -0.5])            # one element pushed through itself
    X = np.swapaxes(R_old, 1, 2) @ F
    (M1, M2, R1, R2), how, tmp = _buffers()
    ok, _ = _newton_rotations(_lanes(X), M1, M2, _lanes(R_old), R1, R2)
    assert not ok
    out = _mats(chunk_rotations(_lanes(X), M1, M2, R1, R2, how, tmp, _lanes(R_old)))
    assert np.allclose(np.linalg.det(out), 1.0, atol=1e-12)
    keep = np.arange(LANES) != 7
    assert np.abs(out[keep] - R[keep]).max() < 1e-11
