"""A BVH capture as a URDF skeleton and a ``JointTrajectory`` for it (so a node can play it by joint name).

URDF (``bvh_urdf``): every BVH joint J becomes the bone link ``J``; the channels of J become a chain of
scalar joints from J's parent link, one per channel, named ``J_Xpos``/``J_Ypos``/``J_Zpos`` (prismatic)
and ``J_Xrot``/``J_Yrot``/``J_Zrot`` (revolute), with massless helper links between them. The letters
are the *file's* axes; the joint axes are those axes expressed in ROS coordinates (``BvhMotion.to_ros``,
default file (x, y, z) -> ROS (z, x, y)), and offsets are scaled by ``BvhMotion.unit_m``, so the URDF is
in metres, Z up, X forward. The chain runs position channels first (BVH positions are in the parent
frame), then rotations in file order: "Zrotation Yrotation Xrotation" gives R = Rz Ry Rx. The root joint's
chain starts at the helper link ``bvh_world``; a 6-channel root is the 3 prismatic + 3 revolute floating
base. Each End Site becomes the tip link ``J_tip``, so leaf bones have a length.

Trajectory (``bvh_trajectory``): one column per URDF joint, positions in metres, angles in radians,
unwrapped per channel over time (Euler angles in the file wrap at +-180 deg). ``skip_tpose=True``
(default, right for the CMU cgspeed conversions) drops frame 0, the T-pose the converter prepends,
and starts the time at 0 on frame 1; ``skip_tpose=False`` keeps every frame.
"""
from __future__ import annotations

import numpy as np

from .bvh import BvhMotion
from .trajectory import JointTrajectory
from .urdf_builder import UrdfBuilder

ROOT_LINK = "bvh_world"


def channel_joint_name(joint: str, channel: str) -> str:
    """URDF joint name of a BVH channel: ("LeftLeg", "Zrotation") -> "LeftLeg_Zrot"."""
    return f"{joint}_{channel[0]}{'pos' if channel.endswith('position') else 'rot'}"


def _chain_order(channels: list[str]) -> list[str]:
    return [c for c in channels if c.endswith("position")] + [c for c in channels if c.endswith("rotation")]


def bvh_joint_names(motion: BvhMotion) -> list[str]:
    """The URDF joint names of every channel, in hierarchy and chain order (the trajectory's columns)."""
    return [channel_joint_name(j.name, c) for j in motion.joints for c in _chain_order(j.channels)]


def bvh_urdf(motion: BvhMotion, robot_name: str = "bvh_skeleton") -> str:
    """URDF text of the capture's skeleton (see the module docstring)."""
    C, u = motion.to_ros, motion.unit_m
    b = UrdfBuilder(robot_name)
    b.link(ROOT_LINK, helper=True)
    names = [j.name for j in motion.joints]
    if len(set(names)) != len(names):
        raise ValueError(f"BVH joint names repeat ({sorted({n for n in names if names.count(n) > 1})}): "
                         "rename them so the URDF links are unique")
    for j in motion.joints:
        b.link(j.name, mass=1.0)
        parent = ROOT_LINK if j.parent < 0 else motion.joints[j.parent].name
        chain = []
        for c in _chain_order(j.channels):
            axis = C[:, "XYZ".index(c[0])]
            chain.append((channel_joint_name(j.name, c), "prismatic" if c.endswith("position") else "revolute", axis))
        b.chain(parent, j.name, chain, xyz=C @ j.offset * u, limit=(-1e4, 1e4))
        if j.end_site is not None:
            b.tip(j.name, C @ j.end_site * u)
    return b.to_string()


def bvh_trajectory(motion: BvhMotion, skip_tpose: bool = True, interpolation: str = "catmull_rom") -> JointTrajectory:
    """The capture as a trajectory over ``bvh_joint_names(motion)`` (see the module docstring)."""
    cols, revolute = [], []
    for j in motion.joints:
        for c in _chain_order(j.channels):
            cols.append(j.channel_start + j.channels.index(c))
            revolute.append(c.endswith("rotation"))
    frames = motion.frames[1:] if skip_tpose else motion.frames
    if frames.shape[0] == 0:
        raise ValueError(f"{motion.source}: only the T-pose frame is present: pass skip_tpose=False to keep it")
    rev = np.array(revolute, dtype=bool)
    q = frames[:, cols].copy()
    q[:, rev] = np.deg2rad(q[:, rev])
    q[:, ~rev] *= motion.unit_m
    times = np.arange(frames.shape[0]) * motion.frame_time
    return JointTrajectory(times, bvh_joint_names(motion), q, revolute=rev, interpolation=interpolation)
