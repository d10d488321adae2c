"""The jelly report's run loop on the test chain (the humanoid scene needs clusterfem_ros.skeleton)."""
import pytest
import numpy as np

from benchmarks.jelly_report import run, scene_default
from clusterfem_ros.body import LevelGains, bind_to_skeleton
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import build_model
from tests.test_body_support import LEVELS, ChainSkeleton, Motion, box_body


class _Trajectory:
    def __init__(self, motion):
        self.sample = motion.qv


def test_report_run_measures_speed_substeps_volume_and_tracking():
    sk = ChainSkeleton()
    model = build_model(box_body(), Material(E=5e4, nu=0.3, rho=1000.0, xi=1.0, zeta=1e-3))
    q, v = Motion().qv(0.0)
    s, e = sk.bone_segments(q)
    P = sk.forward(q, v)
    b = bind_to_skeleton(model.rest, s, e, LEVELS, rest_rotation=P.rotation, rest_translation=P.translation)
    walk = Motion(T=lambda t: np.array([0.5 * t, 0, 0]), dT=lambda t: np.array([0.5, 0, 0]),
                  theta=lambda t: 0.1 * np.array([np.sin(6 * t), 0]), dtheta=lambda t: np.array([0.6 * np.cos(6 * t), 0]))
    r = run(sk, _Trajectory(walk), model, b, LevelGains.default(2), False, 0.1, 1e-3)
    print(r)
    assert r["steps/s"] > 0 and r["rtf"] == pytest.approx(r["steps/s"] * 1e-3, rel=1e-12)
    assert r["substeps"][0] >= 1 and 0 <= r["volume"] < 0.01 and 0 <= r["track"] < 3e-3


def test_report_reads_the_scene_defaults():
    assert len(scene_default("binding.kp")) == len(scene_default("binding.level_radii"))
