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

Glitches (``find_spikes``, ``despike=True`` by default): real captures have single- or few-frame
spikes, e.g. a joint flipping by ~170 deg for 3 frames near Euler gimbal lock and flipping back. A run of
at most ``max_spike_frames`` frames whose joint rotation is more than ``spike_deg`` away from the
previous good frame, followed by a frame close to it again, is replaced by linear interpolation of the
unwrapped channels between the good frames on either side. A jump that does not come back is kept.
"""
from __future__ import annotations

import numpy as np

from .bvh import BvhMotion, joint_rotations
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


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))


def find_spikes(motion: BvhMotion, first_frame: int = 1, spike_deg: float = 90.0,
                max_spike_frames: int = 5) -> list[tuple[str, int, int, float]]:
    """Glitches as (joint name, first bad frame, number of bad frames, jump in degrees), frames from ``first_frame``."""
    found = []
    for ji, j in enumerate(motion.joints):
        if not any(c.endswith("rotation") for c in j.channels):
            continue
        R = joint_rotations(motion, ji)
        good, f = first_frame, first_frame + 1
        while f < motion.n_frames:
            jump = _angle_deg(R[good], R[f])
            if jump > spike_deg:
                back = next((g for g in range(f + 1, min(f + 1 + max_spike_frames, motion.n_frames))
                             if _angle_deg(R[good], R[g]) <= spike_deg), None)
                if back is not None:
                    found.append((j.name, f, back - f, jump))
                    good, f = back, back + 1
                    continue
            good, f = f, f + 1
    return found


def bvh_trajectory(motion: BvhMotion, skip_tpose: bool = True, interpolation: str = "catmull_rom",
                   despike: bool = True, spike_deg: float = 90.0, max_spike_frames: int = 5) -> JointTrajectory:
    """The capture as a trajectory over ``bvh_joint_names(motion)`` (see the module docstring)."""
    cols, revolute = [], []
    for j in motion.joints:
        for c in _chain_order(j.channels):
            cols.append(j.channel_start + j.channels.index(c))
            revolute.append(c.endswith("rotation"))
    first = 1 if skip_tpose else 0
    if motion.n_frames <= first:
        raise ValueError(f"{motion.source}: only the T-pose frame is present: pass skip_tpose=False to keep it")
    frames = motion.frames[first:].copy()
    rot_cols = [j.channel_start + k for j in motion.joints for k, c in enumerate(j.channels) if c.endswith("rotation")]
    frames[:, rot_cols] = np.rad2deg(np.unwrap(np.deg2rad(frames[:, rot_cols]), axis=0))
    if despike:
        for name, f, n, _ in find_spikes(motion, first, spike_deg, max_spike_frames):
            j = next(jj for jj in motion.joints if jj.name == name)
            a, b = f - 1 - first, f + n - first                    # good frames around the spike
            for k, c in enumerate(j.channels):
                if c.endswith("rotation"):
                    col = j.channel_start + k
                    w = (np.arange(a + 1, b) - a) / (b - a)
                    frames[a + 1:b, col] = (1 - w) * frames[a, col] + w * frames[b, col]
    rev = np.array(revolute, dtype=bool)
    q = frames[:, cols].copy()
    q[:, rev] = np.deg2rad(q[:, rev])
    q[:, ~rev] *= motion.unit_m
    times = np.arange(frames.shape[0]) * motion.frame_time
    return JointTrajectory(times, bvh_joint_names(motion), q, revolute=rev, interpolation=interpolation)
