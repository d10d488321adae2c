"""Synthetic BVH files of a standing human (1.74 m, head top to toe tips), written the way other tools write them.

``human_bvh(motion, ...)`` writes BVH text: the skeleton in ``unit_m`` metres per file unit, joint names with a
``prefix`` (``mixamorig:``) or the 3ds-Max biped's names and topology (``rig="max"``: the thighs hang from the
spine), every joint's rotation channels in ``order`` (e.g. "ZXY"), the file's up axis ``up`` ("Y": facing +Z;
"Z": facing -Y, as 3ds Max), the root's OFFSET ``root_offset`` [m] written beside its position channels (which
are its position). ``motion`` gives, in a canonical frame (metres, Y up, facing +Z, X the character's left),
the root's position (F, 3) and each joint's local rotation (scipy ``Rotation`` of F); the writer turns them into
the file's axes and Euler order with scipy. ``twin`` (F, J) bool writes those frames' triples as the other
representation of the same rotation, (a + 180, 180 - b, c + 180) shifted by a whole turn (a flip, not a motion).
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

# name, parent, offset [m] (canonical: Y up, facing +Z, X left), end site or None
HUMAN = [
    ("Hips", None, (0.0, 0.0, 0.0), None),
    ("LeftUpLeg", "Hips", (0.09, -0.05, 0.0), None),
    ("LeftLeg", "LeftUpLeg", (0.0, -0.42, 0.0), None),
    ("LeftFoot", "LeftLeg", (0.0, -0.42, 0.0), None),
    ("LeftToeBase", "LeftFoot", (0.0, -0.06, 0.12), (0.0, 0.0, 0.06)),
    ("RightUpLeg", "Hips", (-0.09, -0.05, 0.0), None),
    ("RightLeg", "RightUpLeg", (0.0, -0.42, 0.0), None),
    ("RightFoot", "RightLeg", (0.0, -0.42, 0.0), None),
    ("RightToeBase", "RightFoot", (0.0, -0.06, 0.12), (0.0, 0.0, 0.06)),
    ("Spine", "Hips", (0.0, 0.12, 0.0), None),
    ("Spine1", "Spine", (0.0, 0.15, 0.0), None),
    ("Neck", "Spine1", (0.0, 0.25, 0.0), None),
    ("Head", "Neck", (0.0, 0.12, 0.0), (0.0, 0.15, 0.0)),
    ("LeftShoulder", "Spine1", (0.05, 0.2, 0.0), None),
    ("LeftArm", "LeftShoulder", (0.13, 0.0, 0.0), None),
    ("LeftForeArm", "LeftArm", (0.28, 0.0, 0.0), None),
    ("LeftHand", "LeftForeArm", (0.25, 0.0, 0.0), (0.08, 0.0, 0.0)),
    ("RightShoulder", "Spine1", (-0.05, 0.2, 0.0), None),
    ("RightArm", "RightShoulder", (-0.13, 0.0, 0.0), None),
    ("RightForeArm", "RightArm", (-0.28, 0.0, 0.0), None),
    ("RightHand", "RightForeArm", (-0.25, 0.0, 0.0), (-0.08, 0.0, 0.0)),
]
HIP_HEIGHT = 0.95          # the root above the toe tips in the rest pose [m]
HEIGHT = 1.74              # toe tips to head top [m]

# the 3ds-Max biped: Bip01 (root) > Pelvis > Spine > thighs and Spine1 (names with '_' for the spaces)
_MAX_NAMES = {"Hips": "Bip01", "Spine": "Bip01_Spine", "Spine1": "Bip01_Spine1", "Neck": "Bip01_Neck",
              "Head": "Bip01_Head", "LeftUpLeg": "Bip01_L_Thigh", "LeftLeg": "Bip01_L_Calf",
              "LeftFoot": "Bip01_L_Foot", "LeftToeBase": "Bip01_L_Toe0", "LeftShoulder": "Bip01_L_Clavicle",
              "LeftArm": "Bip01_L_UpperArm", "LeftForeArm": "Bip01_L_Forearm", "LeftHand": "Bip01_L_Hand"}


def skeleton(rig: str = "human") -> list[tuple[str, str | None, tuple, tuple | None]]:
    """The joints (name, parent, offset, end site) of ``rig``: 'human' (Mixamo / CMU-like) or 'max' (biped)."""
    if rig == "human":
        return list(HUMAN)
    names = dict(_MAX_NAMES)
    names.update({k.replace("Left", "Right"): v.replace("_L_", "_R_") for k, v in _MAX_NAMES.items() if "Left" in k})
    human = {j[0]: j for j in HUMAN}
    out = [("Bip01", None, (0.0, 0.0, 0.0), None), ("Bip01_Pelvis", "Bip01", (0.0, 0.0, 0.0), None),
           ("Bip01_Spine", "Bip01_Pelvis", human["Spine"][2], None)]
    for name, parent, off, end in HUMAN[1:]:
        if name.endswith("UpLeg"):          # hangs from the spine, 0.12 m below it
            out.append((names[name], "Bip01_Spine", (off[0], off[1] - 0.12, off[2]), end))
        elif name != "Spine":
            out.append((names[name], names[parent], off, end))
    order = ["Bip01", "Bip01_Pelvis", "Bip01_Spine"]           # depth first: legs, then the upper body
    rest = [j for j in out if j[0] not in order]
    legs = [j for j in rest if "Thigh" in j[0] or "Calf" in j[0] or "Foot" in j[0] or "Toe" in j[0]]
    by_name = {j[0]: j for j in out}
    return [by_name[n] for n in order] + legs + [j for j in rest if j not in legs]


def to_file_axes(up: str) -> np.ndarray:
    """(3, 3) taking canonical (Y up, facing +Z) coordinates to the file's: Y up as they are, Z up facing -Y."""
    return np.eye(3) if up == "Y" else np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def rest_motion(frames: int = 3, rig: str = "human") -> tuple[np.ndarray, dict]:
    """The rest pose held: the root at hip height, every rotation identity."""
    root = np.tile([0.0, HIP_HEIGHT, 0.0], (frames, 1))
    return root, {j[0]: Rotation.identity(frames) for j in skeleton(rig)}


def walk_motion(frames: int = 90, fps: float = 30.0, speed: float = 1.2, turn_deg: float = 0.0,
                rig: str = "human") -> tuple[np.ndarray, dict]:
    """A walk of 1 s steps: legs and arms swing, the root advances along its heading, which turns by
    ``turn_deg`` about up over the clip."""
    t = np.arange(frames) / fps
    phase = 2 * np.pi * t
    yaw = np.deg2rad(turn_deg) * t / t[-1]
    heading = np.column_stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)])
    dist = speed * t
    step = np.gradient(dist)
    root = np.cumsum(heading * step[:, None], axis=0)
    root[:, 1] = HIP_HEIGHT - 0.03 + 0.02 * np.cos(2 * phase)
    rot = {j[0]: Rotation.identity(frames) for j in skeleton(rig)}
    names = {j[0] for j in skeleton(rig)}

    def about(axis, deg):
        return Rotation.from_rotvec(np.outer(np.deg2rad(deg), axis))

    root_name = skeleton(rig)[0][0]
    rot[root_name] = about([0, 1, 0], np.rad2deg(yaw)) * about([1, 0, 0], 5 * np.sin(2 * phase))
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        thigh = next(n for n in names if n in (f"{side}UpLeg", f"Bip01_{side[0]}_Thigh"))
        calf = next(n for n in names if n in (f"{side}Leg", f"Bip01_{side[0]}_Calf"))
        arm = next(n for n in names if n in (f"{side}Arm", f"Bip01_{side[0]}_UpperArm"))
        rot[thigh] = about([1, 0, 0], -25 * sign * np.sin(phase))
        rot[calf] = about([1, 0, 0], 30 * (1 + np.sin(phase + sign * np.pi / 2)))
        rot[arm] = about([0, 0, 1], -sign * 70.0) * about([1, 0, 0], 20 * sign * np.sin(phase))
    return root, rot


def human_bvh(motion: tuple[np.ndarray, dict] | None = None, *, unit_m: float = 0.01, order: str = "ZYX",
              up: str = "Y", prefix: str = "", rig: str = "human", root_offset=(0.0, 0.0, 0.0),
              fps: float = 30.0, twin: np.ndarray | None = None, root_channels: bool = True) -> str:
    """BVH text of ``motion`` (default: the rest pose) written as the module docstring says."""
    root_pos, rotations = rest_motion(rig=rig) if motion is None else motion
    joints = skeleton(rig)
    M = to_file_axes(up)
    F = root_pos.shape[0]
    rot_channels = " ".join(f"{a}rotation" for a in order)
    lines = ["HIERARCHY"]
    depth = {None: -1}
    stack: list[str] = []

    def close_to(level: int) -> None:
        while len(stack) > level:
            stack.pop()
            lines.append("  " * len(stack) + "}")

    columns = []
    for name, parent, off, end in joints:
        d = depth[parent] + 1
        depth[name] = d
        close_to(d)
        ind = "  " * d
        lines.append(f"{ind}{'ROOT' if parent is None else 'JOINT'} {prefix}{name}")
        lines.append(f"{ind}{{")
        o = np.array(root_offset if parent is None else off) @ M.T / unit_m
        lines.append(f"{ind}  OFFSET {o[0]:.6f} {o[1]:.6f} {o[2]:.6f}")
        if parent is None and root_channels:
            lines.append(f"{ind}  CHANNELS 6 Xposition Yposition Zposition {rot_channels}")
        else:
            lines.append(f"{ind}  CHANNELS 3 {rot_channels}")
        columns.append(name)
        if end is not None:
            e = np.array(end) @ M.T / unit_m
            lines += [f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET {e[0]:.6f} {e[1]:.6f} {e[2]:.6f}", f"{ind}  }}"]
        stack.append(name)
    close_to(0)
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / fps:.8f}"]
    conj = Rotation.from_matrix(M)
    table = []
    for k, name in enumerate(columns):
        R = conj * rotations[name] * conj.inv()
        with warnings.catch_warnings():          # a walk turning through gimbal lock: any split is the rotation
            warnings.simplefilter("ignore", UserWarning)
            ang = R.as_euler(order, degrees=True)
        if twin is not None:
            flip = twin[:, k]
            ang[flip] = np.column_stack([ang[flip, 0] + 180.0, 180.0 - ang[flip, 1], ang[flip, 2] - 180.0]) + \
                np.array([-360.0, 0.0, 360.0])
        if k == 0 and root_channels:
            table.append(root_pos @ M.T / unit_m)
        table.append(ang)
    data = np.hstack(table)
    lines += [" ".join(f"{x:.10f}" for x in row) for row in data]
    return "\n".join(lines) + "\n"
