"""A three-bone chain built with pinocchio and a box body around it, shared by the body tests.

The chain lies on the x axis: a free-flyer root bone b0 from x = 0 to 0.2, then revolute joints about z
at x = 0.2 (bone b1) and x = 0.4 (bone b2, ending at 0.6). ``ChainSkeleton.forward`` returns the same
contract as ``skeleton.kinematics.BonePoses``. The tests at the bottom check that contract itself.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Callable

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh

BONE = 0.2
URDF = """<?xml version="1.0"?>
<robot name="chain">
  <link name="b0"/><link name="b1"/><link name="b2"/>
  <joint name="j1" type="revolute"><parent link="b0"/><child link="b1"/>
    <origin xyz="0.2 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="10"/></joint>
  <joint name="j2" type="revolute"><parent link="b1"/><child link="b2"/>
    <origin xyz="0.2 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="10"/></joint>
</robot>"""


class ChainSkeleton:
    """Bones = pinocchio joints 1..3 (free-flyer root, j1, j2); bone origin = joint origin."""

    def __init__(self) -> None:
        self.model = pin.buildModelFromXML(URDF, pin.JointModelFreeFlyer())
        self.data = self.model.createData()
        self.bone_names = ["b0", "b1", "b2"]
        self.n_bones = 3
        self.tip = np.array([BONE, 0.0, 0.0])       # segment end of every bone in its own frame

    def forward(self, q: np.ndarray, v: np.ndarray) -> SimpleNamespace:
        pin.forwardKinematics(self.model, self.data, q, v)
        R = np.array([self.data.oMi[j].rotation for j in range(1, 4)])
        p = np.array([self.data.oMi[j].translation for j in range(1, 4)])
        tw = np.array([np.concatenate([R[j - 1] @ self.data.v[j].angular, R[j - 1] @ self.data.v[j].linear])
                       for j in range(1, 4)])
        return SimpleNamespace(rotation=R, translation=p, twist=tw)

    def bone_segments(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        poses = self.forward(q, np.zeros(self.model.nv))
        return poses.translation.copy(), poses.translation + poses.rotation @ self.tip


@dataclass
class Motion:
    """Root translation T(t), root rotation angle phi(t) about a fixed world axis, joint angles theta(t),
    each with its time derivative (so the twists are exact)."""
    T: Callable[[float], np.ndarray] = lambda t: np.zeros(3)
    dT: Callable[[float], np.ndarray] = lambda t: np.zeros(3)
    phi: Callable[[float], float] = lambda t: 0.0
    dphi: Callable[[float], float] = lambda t: 0.0
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    theta: Callable[[float], np.ndarray] = lambda t: np.zeros(2)
    dtheta: Callable[[float], np.ndarray] = lambda t: np.zeros(2)

    def root_rotation(self, t: float) -> np.ndarray:
        return Rotation.from_rotvec(self.phi(t) * np.asarray(self.axis, float)).as_matrix()

    def qv(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        Rr = self.root_rotation(t)
        q = np.concatenate([self.T(t), Rotation.from_matrix(Rr).as_quat(), self.theta(t)])
        w = self.dphi(t) * np.asarray(self.axis, float)
        v = np.concatenate([Rr.T @ self.dT(t), Rr.T @ w, self.dtheta(t)])
        return q, v


def box_body(spacing: float = 0.03):
    """A 0.66 x 0.12 x 0.12 m box around the chain (x from -0.03 to 0.63, centred on the x axis)."""
    n = int(round(0.12 / spacing))
    return box_mesh((0.66, 0.12, 0.12), (int(round(0.66 / spacing)), n, n), (-0.03, -0.06, -0.06))


LEVELS = (0.031, 0.045)       # level 0: the axis and its nearest grid ring; level 1: the diagonal ring


def test_chain_twist_matches_pose_finite_difference():
    """The twist convention (omega, velocity of the bone origin, world-aligned) is what the poses do."""
    sk = ChainSkeleton()
    m = Motion(T=lambda t: np.array([0.1 * t, 0.3 * np.sin(t), 0.0]), dT=lambda t: np.array([0.1, 0.3 * np.cos(t), 0]),
               phi=lambda t: 0.7 * t * t, dphi=lambda t: 1.4 * t, axis=(0.0, 0.6, 0.8),
               theta=lambda t: np.array([np.sin(2 * t), 0.5 * t]), dtheta=lambda t: np.array([2 * np.cos(2 * t), 0.5]))
    t, e = 0.8, 1e-6
    P = sk.forward(*m.qv(t))
    Pp, Pm = sk.forward(*m.qv(t + e)), sk.forward(*m.qv(t - e))
    dp = (Pp.translation - Pm.translation) / (2 * e)
    dR = (Pp.rotation - Pm.rotation) / (2 * e)
    W = dR @ P.rotation.transpose(0, 2, 1)                          # [omega]x
    omega = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(P.twist[:, 3:], dp, atol=1e-7)
    np.testing.assert_allclose(P.twist[:, :3], omega, atol=1e-7)


def test_chain_segments_join_at_the_joints():
    sk = ChainSkeleton()
    q, _ = Motion(theta=lambda t: np.array([0.4, -0.9])).qv(0.0)
    s, e = sk.bone_segments(q)
    np.testing.assert_allclose(e[:2], s[1:], atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(e - s, axis=1), BONE)
