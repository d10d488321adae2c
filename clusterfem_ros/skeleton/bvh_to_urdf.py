"""A BVH capture as a URDF skeleton and a ``JointTrajectory`` for it (so a node can play it by joint name).

URDF (``bvh_urdf``): every BVH joint J becomes the bone link ``J``; the channels of J become a chain of
scalar joints from J's parent link, one per channel, named ``J_Xpos``/``J_Ypos``/``J_Zpos`` (prismatic)
and ``J_Xrot``/``J_Yrot``/``J_Zrot`` (revolute), with massless helper links between them. The letters
are the *file's* axes; the joint axes are those axes expressed in ROS coordinates (``BvhMotion.to_ros``,
default file (x, y, z) -> ROS (z, x, y)), and offsets are scaled by ``BvhMotion.unit_m``, so the URDF is
in metres, Z up, X forward. The root's OFFSET is dropped along the axes it has a position channel for (the
channels are its position, as the format defines them) and its origin is moved by ``BvhMotion.root_shift``
(the floor under the feet). A joint below the root keeps its OFFSET as its origin; its position channels,
where it has them, give its whole place in the parent (some rigs repeat every OFFSET there), so its prismatic
joints take the channel less the OFFSET. The chain runs position channels first (BVH positions are in the parent
frame), then rotations in file order: "Zrotation Yrotation Xrotation" gives R = Rz Ry Rx. The root joint's
chain starts at the helper link ``bvh_world``; a 6-channel root is the 3 prismatic + 3 revolute floating
base. Each End Site becomes the tip link ``J_tip``, so leaf bones have a length. A leaf joint that is its parent's
only child and whose End Site has no length (LAFAN1 writes ``OFFSET 0 0 0`` for the head, hands and toes) or which
has none says nothing of where its bone ends: its tip continues the bone before it, along the joint's OFFSET for
``LEAF_TIP_FRACTION`` of its length, so a head, hand or toe has flesh of its own to carry (a bone of zero length
binds none: the crown followed the neck, 33 cm from it). A leaf with siblings (Mixamo's HeadTop_End and eyes
beside each other on the head) marks a point of its parent's part and keeps no length.

Trajectory (``bvh_trajectory``): one column per URDF joint, positions in metres, angles in radians. A
joint's three Euler angles are continuous over time (``continuous_euler``): of the two triples of each
frame's rotation, (a, b, c) and (a + 180, 180 - b, c + 180) deg, each shifted by whole turns, the one
nearest the previous frame's is kept, so a file wrapping at +-180 deg or flipping to the other triple of the
same rotation makes no jump (at gimbal lock a keeps its previous value); the rotations are the file's
exactly. Joints with fewer rotation channels are unwrapped per channel. ``skip_tpose="auto"``
(default) drops frame 0 when it is a pose the converter prepended (the CMU cgspeed conversions' T-pose,
``prepended_pose``): some joint turns more than ``TPOSE_JUMP_DEG`` from it to frame 1, more than
``TPOSE_RATIO`` times the captured motion's own frame-to-frame turn (the median over the frames of each
frame's largest joint turn); the time
then starts at 0 on frame 1. ``True`` always drops frame 0, ``False`` keeps every frame.

Glitches (``find_spikes``, ``despike=True`` by default): real captures have single- or few-frame
spikes, e.g. a joint flipping by ~170 deg for 3 frames near Euler gimbal lock and flipping back. A run of
at most ``max_spike_frames`` frames whose joint rotation is more than ``spike_deg`` away from the
previous good frame (the geodesic angle of R_good^T R_f: rotations compared, never channel values),
followed by a frame close to it again, is replaced by the slerp between the good frames on either side.
A jump that does not come back is kept.

Speed limit (``max_rotation_speed``, rad/s, default ``MAX_ROTATION_SPEED``, and ``max_end_speed``, m/s,
default ``MAX_END_SPEED``): glitches that last (a thumb or thigh flipping ~180 deg in one frame and staying
so for 20+ frames) are not spikes, yet no limb turns that fast: each joint's rotation is moved from frame
to frame by at most its limit per second (along the shortest arc towards the captured rotation): the
smaller of max_rotation_speed and max_end_speed over the joint's reach (the longest chain of bones below
it, at rest), so a thigh flip becomes a turn of about 0.1 s and a thumb flip one of 0.03 s. Of the clean
leap clip (fastest joint 41 deg per frame at 120 Hz = 86 rad/s, a toe) 3 arm frames are limited; frames
within the limit are untouched. Joints with a limited frame get Euler channels re-extracted from their
rotations, the representation nearest to the previous frame chosen each time (no 360 deg jumps; the
twin (a + 180, 180 - b, c + 180) when nearer), so interpolating the channels never takes the long way.

Loops (``bvh_loop``): the trajectory as a ``capture_loop.CaptureLoop``: the seam blended as rotations, the
root's heading and horizontal position carried from one loop to the next.
"""
from __future__ import annotations

import numpy as np

from .bvh import BvhMotion, elementary_rotations, joint_rotations
from .euler import continuous_euler, euler_nearest
from .trajectory import JointTrajectory
from .urdf_builder import UrdfBuilder

ROOT_LINK = "bvh_world"
MAX_ROTATION_SPEED = 100.0      # rad/s: no captured limb turns faster (see the module docstring)
MAX_END_SPEED = 25.0            # m/s: nor does the end of a limb move faster
LEAF_TIP_FRACTION = 0.5         # a leaf bone with no End Site length: half as long as the bone before it


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
    children = np.bincount([c.parent for c in motion.joints if c.parent >= 0], minlength=len(motion.joints))
    scale = max((float(np.linalg.norm(c.offset)) for c in motion.joints), default=0.0)
    for k, j in enumerate(motion.joints):
        b.link(j.name, mass=1.0)
        parent = ROOT_LINK if j.parent < 0 else motion.joints[j.parent].name
        chain = []
        for c in _chain_order(j.channels):
            axis = C[:, "XYZ".index(c[0])]
            chain.append((channel_joint_name(j.name, c), "prismatic" if c.endswith("position") else "revolute", axis))
        offset = j.offset
        if j.parent < 0:                      # the root's position channels are its position (bvh.py)
            offset = np.array([0.0 if f"{a}position" in j.channels else x for a, x in zip("XYZ", j.offset)])
        xyz = C @ offset * u + (motion.root_shift if j.parent < 0 else 0.0)
        b.chain(parent, j.name, chain, xyz=xyz, limit=(-1e4, 1e4))
        tip = leaf_tip(motion, k, children, scale)
        if tip is not None:
            b.tip(j.name, C @ tip * u)
    return b.to_string()


def leaf_tip(motion: BvhMotion, k: int, children: np.ndarray, scale: float) -> np.ndarray | None:
    """The tip (file units, in joint k's frame) that ends joint k's bone: its End Site, or for a leaf joint whose
    End Site has no length (or which has none) and which is its parent's only child its OFFSET times
    LEAF_TIP_FRACTION (the bone before it, continued); None for an inner joint without End Site (its children end
    it) and a leaf root. ``children`` (joints,) counts each joint's children; lengths under 1e-9 ``scale`` (the
    longest OFFSET) are none."""
    j = motion.joints[k]
    leaf = children[k] == 0 and (j.parent < 0 or children[j.parent] == 1)   # beside siblings: a point of the parent
    if j.end_site is not None and (not leaf or float(np.linalg.norm(j.end_site)) > 1e-9 * scale):
        return np.asarray(j.end_site, dtype=np.float64)
    if not leaf or j.parent < 0 or not float(np.linalg.norm(j.offset)) > 1e-9 * scale:
        return None if j.end_site is None else np.asarray(j.end_site, dtype=np.float64)
    return LEAF_TIP_FRACTION * np.asarray(j.offset, dtype=np.float64)


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


def _euler_nearest(R: np.ndarray, order: str, previous: np.ndarray) -> np.ndarray:
    """Angles [rad] (3,) about the file axes ``order`` of rotation R, the triple nearest ``previous`` (3,)."""
    return euler_nearest(R[None], order, previous)[0]


def joint_reach(motion: BvhMotion) -> np.ndarray:
    """(J,) the longest chain of bone offsets (and end sites) below each joint [m]: how far its rotation reaches."""
    reach = np.zeros(len(motion.joints))
    for k in range(len(motion.joints) - 1, -1, -1):             # children come after their parents
        j = motion.joints[k]
        if j.end_site is not None:
            reach[k] = max(reach[k], float(np.linalg.norm(j.end_site)) * motion.unit_m)
        if j.parent >= 0:
            reach[j.parent] = max(reach[j.parent], reach[k] + float(np.linalg.norm(j.offset)) * motion.unit_m)
    return reach


def limit_rotation_speed(motion: BvhMotion, frames: np.ndarray, frame_time: float,
                         max_rad_s: float = MAX_ROTATION_SPEED,
                         max_end_speed: float = MAX_END_SPEED) -> list[tuple[str, int]]:
    """Limit every joint's rotation speed in ``frames`` (F, C) [deg, unwrapped] in place (see the module
    docstring); returns (joint name, frames limited) for each joint changed."""
    from scipy.spatial.transform import Rotation
    reach = joint_reach(motion)
    changed = []
    for ji, j in enumerate(motion.joints):
        step = min(max_rad_s, max_end_speed / max(reach[ji], 1e-9)) * frame_time
        rot = [k for k, c in enumerate(j.channels) if c.endswith("rotation")]
        order = "".join(j.channels[k][0] for k in rot)
        if len(rot) != 3 or len(set(order)) != 3:
            continue
        cols = [j.channel_start + k for k in rot]
        ang = np.deg2rad(frames[:, cols])
        R = np.einsum("fij,fjk,fkl->fil", *(elementary_rotations(order[i], frames[:, cols[i]]) for i in range(3)))
        cos = (np.einsum("fij,fij->f", R[:-1], R[1:]) - 1.0) / 2.0
        if (np.arccos(np.clip(cos, -1.0, 1.0)) <= step).all():       # most joints: nothing to limit
            continue
        out = R.copy()
        limited = 0
        for f in range(1, R.shape[0]):
            rel = Rotation.from_matrix(out[f - 1].T @ R[f]).as_rotvec()
            angle = float(np.linalg.norm(rel))
            if angle > step:
                out[f] = out[f - 1] @ Rotation.from_rotvec(rel * (step / angle)).as_matrix()
                limited += 1
        if limited:
            new = np.empty_like(ang)
            new[0] = ang[0]
            for f in range(1, R.shape[0]):
                new[f] = _euler_nearest(out[f], order, new[f - 1])
            frames[:, cols] = np.rad2deg(new)
            changed.append((j.name, limited))
    return changed


def _rotation_columns(motion: BvhMotion, ji: int) -> tuple[list[int], str]:
    """(frame columns, axes in order) of joint ``ji``'s rotation channels."""
    j = motion.joints[ji]
    rot = [k for k, c in enumerate(j.channels) if c.endswith("rotation")]
    return [j.channel_start + k for k in rot], "".join(j.channels[k][0] for k in rot)


def make_continuous(motion: BvhMotion, frames: np.ndarray) -> None:
    """Every joint's rotation channels in ``frames`` (F, C) [deg] made continuous in place: ``continuous_euler`` for
    a joint with three rotation axes, whole turns unwrapped per channel otherwise. The rotations are unchanged."""
    for ji in range(len(motion.joints)):
        cols, order = _rotation_columns(motion, ji)
        if not cols:
            continue
        rad = np.deg2rad(frames[:, cols])
        if len(cols) == 3 and len(set(order)) == 3:
            frames[:, cols] = np.rad2deg(continuous_euler(rad, order))
        else:
            frames[:, cols] = np.rad2deg(np.unwrap(rad, axis=0))


def _frame_rotations(frames: np.ndarray, cols: list[int], order: str) -> np.ndarray:
    R = np.broadcast_to(np.eye(3), (frames.shape[0], 3, 3)).copy()
    for c, axis in zip(cols, order):
        R = R @ elementary_rotations(axis, frames[:, c])
    return R


def _bridge(motion: BvhMotion, ji: int, frames: np.ndarray, a: int, b: int) -> None:
    """Frames a+1 .. b-1 of joint ``ji`` replaced in place by the rotation slerped from frame a's to frame b's
    (the channels linearly for a joint without three rotation axes)."""
    from scipy.spatial.transform import Rotation
    cols, order = _rotation_columns(motion, ji)
    inner = np.arange(a + 1, b)
    if not cols or inner.size == 0:
        return
    w = (inner - a) / (b - a)
    if len(cols) != 3 or len(set(order)) != 3:
        for c in cols:
            frames[inner, c] = (1 - w) * frames[a, c] + w * frames[b, c]
        return
    Ra, Rb = _frame_rotations(frames[[a, b]], cols, order)
    rel = Rotation.from_matrix(Ra.T @ Rb).as_rotvec()
    for f, wf in zip(inner, w):
        R = Ra @ Rotation.from_rotvec(wf * rel).as_matrix()
        frames[f, cols] = np.rad2deg(_euler_nearest(R, order, np.deg2rad(frames[f - 1, cols])))
    frames[b:, cols] = np.rad2deg(continuous_euler(np.deg2rad(frames[b - 1:, cols]), order)[1:])


TPOSE_JUMP_DEG = 30.0
TPOSE_RATIO = 5.0


def prepended_pose(motion: BvhMotion) -> bool:
    """True when frame 0 is a pose prepended to the capture (see the module docstring)."""
    if motion.n_frames < 3:
        return False
    steps = np.zeros(motion.n_frames - 1)
    for ji in range(len(motion.joints)):
        R = joint_rotations(motion, ji)
        cos = (np.einsum("fij,fij->f", R[:-1], R[1:]) - 1.0) / 2.0
        steps = np.maximum(steps, np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0))))
    own = float(np.median(steps[1:]))
    return bool(steps[0] > TPOSE_JUMP_DEG and steps[0] > TPOSE_RATIO * own)


def bvh_trajectory(motion: BvhMotion, skip_tpose: bool | str = "auto", interpolation: str = "catmull_rom",
                   despike: bool = True, spike_deg: float = 90.0, max_spike_frames: int = 5,
                   max_rotation_speed: float | None = MAX_ROTATION_SPEED) -> JointTrajectory:
    """The capture as a trajectory over ``bvh_joint_names(motion)`` (see the module docstring)."""
    cols, revolute, rest = [], [], []
    for j in motion.joints:
        for c in _chain_order(j.channels):
            cols.append(j.channel_start + j.channels.index(c))
            revolute.append(c.endswith("rotation"))
            # a joint below the root whose position channels give its whole place in the parent (a rig that
            # repeats every OFFSET there) moves by the channel less its OFFSET, which the URDF's origin holds
            rest.append(j.offset["XYZ".index(c[0])] if j.parent >= 0 and c.endswith("position") else 0.0)
    if skip_tpose == "auto":
        skip_tpose = prepended_pose(motion)
    first = 1 if skip_tpose else 0
    if motion.n_frames <= first:
        raise ValueError(f"{motion.source}: only the T-pose frame is present: pass skip_tpose=False to keep it")
    frames = motion.frames[first:].copy()
    make_continuous(motion, frames)
    if despike:
        for name, f, n, _ in find_spikes(motion, first, spike_deg, max_spike_frames):
            ji = motion.joint_names.index(name)
            _bridge(motion, ji, frames, f - 1 - first, f + n - first)    # good frames around the spike
    if max_rotation_speed is not None:
        limit_rotation_speed(motion, frames, motion.frame_time, max_rotation_speed)
    rev = np.array(revolute, dtype=bool)
    q = frames[:, cols].copy()
    q[:, rev] = np.deg2rad(q[:, rev])
    q[:, ~rev] = (q[:, ~rev] - np.array(rest)[~rev]) * motion.unit_m
    times = np.arange(frames.shape[0]) * motion.frame_time
    return JointTrajectory(times, bvh_joint_names(motion), q, revolute=rev, interpolation=interpolation)


def bvh_loop(motion: BvhMotion, trajectory: JointTrajectory, blend_s: float) -> JointTrajectory:
    """``trajectory`` (``bvh_trajectory(motion)``) made to loop (``capture_loop.CaptureLoop``): every joint with
    three rotation channels blended as a rotation over the last ``blend_s`` seconds (at most half the clip), the
    root's heading about the file's up axis and its horizontal position carried from one loop to the next."""
    from .capture_loop import Ball, CaptureLoop
    if trajectory.times.size < 3:
        return trajectory
    names = trajectory.names
    balls, root_ball = [], None
    for ji, j in enumerate(motion.joints):
        rot = [c for c in j.channels if c.endswith("rotation")]
        order = "".join(c[0] for c in rot)
        if len(rot) == 3 and len(set(order)) == 3 and all(channel_joint_name(j.name, c) in names for c in rot):
            root_ball = len(balls) if j.parent < 0 else root_ball
            balls.append(Ball(tuple(names.index(channel_joint_name(j.name, c)) for c in rot), order))
    root = motion.joints[0]
    pos = [c for c in root.channels if c.endswith("position") and channel_joint_name(root.name, c) in names]
    position = ([names.index(channel_joint_name(root.name, c)) for c in pos], "".join(c[0] for c in pos))
    return CaptureLoop(trajectory, balls, root_ball, position, motion.to_ros[2],
                       min(blend_s, 0.5 * trajectory.duration))
