"""A joint folded hard: the rigid targets of its two bones overlap, and the flesh's compressibility decides how much
of the volume the body gives up (python -m benchmarks.volume_where finds the same in the character's hips, knees and
spine on the fast clips)."""
from pathlib import Path

import numpy as np
import pytest

from clusterfem_ros.body import LevelGains, SkeletonDriver, bind_to_skeleton
from clusterfem_ros.config import load_scene_file
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import DEFAULT_POISSON_RATIO, Material
from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from clusterfem_ros.fem.model import build_model
from tests.test_body_support import ChainSkeleton, Motion, box_body

SK = ChainSkeleton()
MESH = box_body()                       # 0.66 x 0.12 x 0.12 m around the chain, 0.03 m voxels
ANGLE, RAMP, HOLD, H = 2.1, 0.3, 0.2, 1.0e-3     # j1 folds 120 deg in 0.3 s, then holds 0.2 s
CHARACTER = Path(__file__).resolve().parents[1] / "config" / "character_walk.yaml"


def _fold() -> Motion:
    def angle(t):
        s = min(t / RAMP, 1.0)
        return ANGLE * s * s * (3.0 - 2.0 * s)

    def rate(t):
        s = min(t / RAMP, 1.0)
        return ANGLE * 6.0 * s * (1.0 - s) / RAMP
    return Motion(theta=lambda t: np.array([angle(t), 0.0]), dtheta=lambda t: np.array([rate(t), 0.0]))


def _folded(nu: float) -> tuple[float, float]:
    """(V/V0 - 1 of the target field, of the body) after the fold, the box bound whole to the chain with the scene's
    default gains, on the scene's default method (Neo-Hookean elements, stretch-planned explicit steps)."""
    motion = _fold()
    q, v = motion.qv(0.0)
    s, e = SK.bone_segments(q)
    P = SK.forward(q, v)
    binding = bind_to_skeleton(MESH.vertices, s, e, (0.031, 0.09), rest_rotation=P.rotation,
                               rest_translation=P.translation)
    assert (binding.level >= 0).all()
    model = build_model(MESH, Material(E=3.0e4, nu=nu, rho=1000.0, xi=2.0, zeta=1.0e-4))
    integrator = make_integrator("clustered", model, warp=True, warping_model="neohookean", plan_stretch=True,
                                 safety=0.8, max_substeps=64)
    driver = SkeletonDriver(binding, MESH.vertices, LevelGains((4.0e4, 4.0e3), (400.0, 120.0)))
    state = driver.rigid_state(P)
    for k in range(int(round((RAMP + HOLD) / H))):
        integrator.step(state, driver.control(SK.forward(*motion.qv(k * H)), H), H)
    v0 = signed_volumes(MESH.vertices, MESH.tets).sum()
    targets = driver.rigid_state(SK.forward(*motion.qv(RAMP + HOLD)))
    return (signed_volumes(MESH.vertices + targets.u, MESH.tets).sum() / v0 - 1.0,
            signed_volumes(MESH.vertices + state.u, MESH.tets).sum() / v0 - 1.0)


@pytest.fixture(scope="module")
def default_flesh():
    return _folded(DEFAULT_POISSON_RATIO)


def test_the_folded_joints_targets_crush_the_flesh_and_the_body_follows_them(default_flesh):
    """Every vertex on its own bone's rigid target: the two bones' targets overlap inside the fold and the target
    field loses volume; the body, bound whole, loses most of it too."""
    targets, body = default_flesh
    print(f"nu {DEFAULT_POISSON_RATIO}: targets {targets:+.2%}, body {body:+.2%}")
    assert targets < -0.02
    assert targets < body < 0.5 * targets


def test_the_shipped_characters_flesh_keeps_more_of_a_folded_joints_volume(default_flesh):
    """config/character_walk.yaml's Poisson ratio against the default one, on the same fold: its loss is at most
    0.85 of the default flesh's (0.73 measured at 0.4)."""
    nu = load_scene_file(CHARACTER).material.poisson_ratio
    targets, body = _folded(nu)
    print(f"nu {nu}: targets {targets:+.2%}, body {body:+.2%} (nu {DEFAULT_POISSON_RATIO}: {default_flesh[1]:+.2%})")
    assert nu > DEFAULT_POISSON_RATIO
    assert targets == pytest.approx(default_flesh[0], abs=1e-12)      # the targets are the binding's, not the flesh's
    assert 0.85 * default_flesh[1] < body < 0         # losses are negative: |body| < 0.85 |default|
